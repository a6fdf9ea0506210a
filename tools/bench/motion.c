/* The motion section: linear motion blur at 2 and 5 time steps. */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_internal.h"

/* ---- motion blur ---- */

/* Step k of `steps`: the mesh twisted by up to 0.6 k / (steps - 1) radians
 * at the top and moved sideways by 5% of its diagonal as far (a turning,
 * travelling object); dst holds vertex_count * 3 floats and 4 more
 * (Embree reads 16 bytes at the last vertex). */
static void motion_step(const rtk_mesh *m, int k, int steps, float diag, float *dst)
{
    const float f = (float)k / (float)(steps - 1);
    twist(m, 0.6f * f, dst);
    for (size_t i = 0; i < m->vertex_count; i++)
        dst[3 * i] += 0.05f * diag * f;
    dst[3 * m->vertex_count] = dst[3 * m->vertex_count + 1] = dst[3 * m->vertex_count + 2] = 0.0f;
    dst[3 * m->vertex_count + 3] = 0.0f;
}

/* The mesh with `steps` time steps of vertices v[k], at medium quality
 * (the geometry's quality REFIT with `refit`), timed from the first scene
 * call to the committed scene. */
static int motion_scene(scene *sc, lib *l, const rtk_mesh *m, float *const *v, int steps, int refit, char *err,
                        size_t err_size)
{
    memset(sc, 0, sizeof *sc);
    sc->lib = l;
    if (l->embree) {
        const long long bytes0 = embree_bytes;
        const double t0 = now();
        RTCScene s = rtcNewScene(l->edev);
        rtcSetSceneBuildQuality(s, RTC_BUILD_QUALITY_MEDIUM);
        RTCGeometry g = rtcNewGeometry(l->edev, RTC_GEOMETRY_TYPE_TRIANGLE);
        rtcSetGeometryTimeStepCount(g, (unsigned)steps);
        if (refit)
            rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_REFIT);
        for (int k = 0; k < steps; k++)
            rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, (unsigned)k, RTC_FORMAT_FLOAT3, v[k], 0, 12,
                                       m->vertex_count);
        if (embree_mesh_commit(sc, s, g, m, 0, t0, bytes0, "the motion-blur scene", err, err_size))
            return 1;
        snprintf(sc->layout, sizeof sc->layout, "embree motion blur");
        return 0;
    }
    const double t0 = now();
    rtk_scene s = NULL;
    rtk_geometry g = NULL;
    int bad = rtk_scene_new(l->rdev, &s) || rtk_geometry_new(l->rdev, RTK_GEOMETRY_TYPE_TRIANGLE, &g) ||
              rtk_geometry_set_time_step_count(g, (unsigned)steps) ||
              (refit && rtk_geometry_set_build_quality(g, RTK_BUILD_QUALITY_REFIT));
    for (int k = 0; k < steps && !bad; k++)
        bad = rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, (unsigned)k, v[k], 0, 12,
                                                  m->vertex_count) != RTK_OK;
    return rtk_mesh_commit(sc, s, g, m, 0, bad, t0, err, err_size);
}

/* Deforming motion blur: the scene of motion_scene at quality REFIT, then
 * in each of `frames` frames every step's vertices moved on by 1% of the
 * diagonal (x) and the new vertices committed (each slot's update, the
 * geometry's and the scene's commit): the best frame's time, *built 1
 * when rtk built instead of refitting (an older build, --alt); -1 with err
 * when a call failed.  v[k] is as it was after. */
static double motion_update(lib *l, const rtk_mesh *m, float *const *v, int steps, float diag, int frames,
                            int *built, char *err, size_t err_size)
{
    *built = 0;
    scene sc;
    if (motion_scene(&sc, l, m, v, steps, 1, err, err_size))
        return -1;
    double best = 1e30;
    for (int f = 1; f <= frames; f++) {
        for (int k = 0; k < steps; k++)
            for (size_t i = 0; i < m->vertex_count; i++)
                v[k][3 * i] += 0.01f * diag;
        const double t0 = now();
        if (sc.escene) {
            RTCGeometry g = rtcGetGeometry(sc.escene, 0);
            for (int k = 0; k < steps; k++)
                rtcUpdateGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, (unsigned)k);
            rtcCommitGeometry(g);
            rtcCommitScene(sc.escene);
        } else {
            rtk_geometry g = rtk_scene_get_geometry(sc.rscene, 0);
            if (rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_VERTEX) || rtk_geometry_commit(g) ||
                rtk_scene_commit(sc.rscene))
                best = -1e30;
        }
        const double dt = now() - t0;
        best = dt < best ? dt : best;
    }
    for (int k = 0; k < steps; k++)
        motion_step(m, k, steps, diag, v[k]);
    int bad = best < 0;
    if (sc.rscene) {
        rtk_scene_info info = {.struct_size = sizeof info};
        bad = bad || rtk_scene_get_info(sc.rscene, &info);
        *built = info.refits != (uint32_t)frames;
    } else {
        bad = rtcGetDeviceError(l->edev) != RTC_ERROR_NONE;
    }
    if (bad)
        snprintf(err, err_size, "%.40s: a motion-blur update frame failed", l->name);
    scene_release(&sc);
    return bad ? -1 : best;
}

/* Linear motion blur: the mesh at 2 and at 5 time steps; build (best of
 * the builds), memory, and the primary and diffuse rays at random times
 * (the same times for every library) through it, beside the same rays
 * through the static mesh in the same library. */
int section_motion(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    static const int step_counts[2] = {2, 5};
    float lo[3], hi[3];
    const float diag = rtk_mesh_bounds(c->m, lo, hi);
    printf("\nmotion blur, 1 thread: the mesh turning (up to 0.6 radians at the top) and moving sideways (5%% of its "
           "diagonal) over the shutter, at 2 and 5 time steps, medium quality; start time (best of %d), bytes per "
           "triangle, and the primary and diffuse rays at random times, single rays and packets of 8 primary rays "
           "(Mrays/s, best of %d passes; static: the diffuse rays through the static mesh in the same library); "
           "update: the geometry at quality REFIT, every step moved on and committed again (best of %d frames)\n",
           o->builds, o->repeat, o->builds + 1);
    printf("  %-20s %5s %9s %7s %8s %10s %7s %10s %7s %10s %7s %9s %8s %10s %7s\n", "library", "steps", "build ms",
           "ratio", "B/tri", "primary", "ratio", "diffuse", "ratio", "primary8", "ratio", "static", "differ",
           "update ms", "ratio");
    rayset timed[2] = {c->sets[SET_PRIMARY], c->sets[SET_DIFFUSE]};
    float *v[5] = {0};
    unsigned char *hits = malloc(timed[0].n + 1), *ref_hits = malloc(timed[0].n + 1);
    int rc = !hits || !ref_hits;
    for (int k = 0; k < 2 && !rc; k++) {
        timed[k].rays = malloc((timed[k].n ? timed[k].n : 1) * sizeof *timed[k].rays);
        rc = !timed[k].rays;
        for (size_t i = 0; !rc && i < timed[k].n; i++) {
            timed[k].rays[i] = c->sets[k ? SET_DIFFUSE : SET_PRIMARY].rays[i];
            timed[k].rays[i].time = rnd();
        }
    }
    for (int k = 0; k < 5 && !rc; k++)
        rc = !(v[k] = malloc((c->m->vertex_count * 3 + 4) * sizeof *v[k]));
    if (rc)
        snprintf(err, err_size, "out of memory");
    for (int sv = 0; sv < 2 && !rc; sv++) {
        const int steps = step_counts[sv];
        for (int k = 0; k < steps; k++)
            motion_step(c->m, k, steps, diag, v[k]);
        double ref[5] = {0};
        for (int l = 0; l < c->nlibs && !rc; l++) {
            lib *lb = &c->libs[l];
            scene sc;
            double best = 1e30, bytes = 0;
            for (int b = 0; b < o->builds && !rc; b++) {
                rc = motion_scene(&sc, lb, c->m, v, steps, 0, err, err_size);
                if (rc)
                    break;
                best = sc.seconds < best ? sc.seconds : best;
                bytes = sc.bytes_per_tri;
                if (b + 1 < o->builds)
                    scene_release(&sc);
            }
            if (rc)
                break;
            double rate[3];
            const render_tracer t = scene_tracer(&sc, 0), tc = scene_tracer(&sc, 1);
            rate[0] = trace_set(&t, &timed[0], 1, 0, 1, o->repeat, hits);
            size_t differ = 0;
            if (l == 0)
                memcpy(ref_hits, hits, timed[0].n);
            for (size_t i = 0; i < timed[0].n; i++)
                differ += hits[i] != ref_hits[i];
            rate[1] = trace_set(&t, &timed[1], 1, 0, 1, o->repeat, hits);
            rate[2] = trace_set(&tc, &timed[0], 8, 0, 1, o->repeat, hits);
            scene_release(&sc);
            scene st;
            rc = scene_build(&st, lb, c->m, c->padded, MODE_DEFAULT, 1, err, err_size);
            if (rc)
                break;
            const render_tracer ts = scene_tracer(&st, 0);
            const double static_rate = trace_set(&ts, &timed[1], 1, 0, 1, o->repeat, hits);
            scene_release(&st);
            int built = 0;
            const double update = motion_update(lb, c->m, v, steps, diag, o->builds + 1, &built, err, err_size);
            if ((rc = update < 0))
                break;
            if (l == 0) {
                ref[0] = best;
                for (int k = 0; k < 3; k++)
                    ref[1 + k] = rate[k];
                ref[4] = update;
            }
            printf("  %-20s %5d %9.1f %6.2fx %8.1f %10.2f %6.2fx %10.2f %6.2fx %10.2f %6.2fx %9.2f %8zu %10.1f %6.2fx%s\n",
                   lb->name, steps, best * 1e3, ratio(ref[0], best), bytes, rate[0], ratio(rate[0], ref[1]), rate[1],
                   ratio(rate[1], ref[2]), rate[2], ratio(rate[2], ref[3]), static_rate, differ, update * 1e3,
                   ratio(ref[4], update), built ? " (built, no refit)" : "");
            char variant[32];
            snprintf(variant, sizeof variant, "%d steps", steps);
            csv_row(&c->csv, "motion", lb->name, variant, "start time", "", 1, best * 1e3, "ms", ratio(ref[0], best));
            csv_row(&c->csv, "motion", lb->name, variant, "memory", "", 1, bytes, "bytes per triangle", 0);
            csv_row(&c->csv, "motion", lb->name, variant, "primary", "single", 1, rate[0], "Mrays/s",
                    ratio(rate[0], ref[1]));
            csv_row(&c->csv, "motion", lb->name, variant, "diffuse", "single", 1, rate[1], "Mrays/s",
                    ratio(rate[1], ref[2]));
            csv_row(&c->csv, "motion", lb->name, variant, "primary", "packet8", 1, rate[2], "Mrays/s",
                    ratio(rate[2], ref[3]));
            csv_row(&c->csv, "motion", lb->name, "static", "diffuse", "single", 1, static_rate, "Mrays/s", 0);
            csv_row(&c->csv, "motion", lb->name, variant, "update", "", 1, update * 1e3, "ms", ratio(ref[4], update));
        }
    }
    printf("  (differ: primary rays that hit where %s misses or the other way round)\n", c->libs[0].name);
    for (int k = 0; k < 5; k++)
        free(v[k]);
    for (int k = 0; k < 2; k++)
        free(timed[k].rays);
    free(hits);
    free(ref_hits);
    return rc;
}
