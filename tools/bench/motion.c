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

/* A stream pass over the set as 8 streams one after the other (as the
 * trace section cuts its passes): the seconds.  One stream of the whole set
 * would write and read back a 50 MB array between the node reads, which
 * pushes the tree out of the caches (every library's stream of the
 * dragon's diffuse rays measured a third slower than its single rays that
 * way); an application tracing a wavefront keeps a tile's. */
static double stream_pass(const render_tracer *t, const rayset *set, int threads, unsigned char *hits)
{
    enum { PIECES = 8 };
    const size_t piece = (set->n / PIECES + 15) / 16 * 16;
    double el = 0.0;
    for (size_t b = 0; b < set->n; b += piece) {
        const rayset part = {.rays = set->rays + b, .n = set->n - b < piece ? set->n - b : piece};
        const double e = trace_pass(t, &part, RENDER_API_STREAM, 0, threads, hits + b);
        if (e < 0.0)
            return e;
        el += e;
    }
    return el;
}

/* Linear motion blur: the mesh at 2 and at 5 time steps; build (best of
 * the builds, 1 thread), memory, and the primary and diffuse rays at random
 * times (the same times for every library) through it on each of --threads,
 * beside the same rays through the static mesh in the same library, the
 * passes taken in turns; and the update of a REFIT geometry (motion_update,
 * 1 thread). */
int section_motion(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    static const int step_counts[2] = {2, 5};
    float lo[3], hi[3];
    const float diag = rtk_mesh_bounds(c->m, lo, hi);
    printf("\nmotion blur: the mesh turning (up to 0.6 radians at the top) and moving sideways (5%% of its "
           "diagonal) over the shutter, at 2 and 5 time steps, medium quality; start time (1 thread, best of %d), "
           "bytes per triangle, and on each thread count the primary and diffuse rays at random times, single rays, packets of 8 primary rays and the "
           "diffuse rays as streams (8 in turn, rtk_intersect1M / rtcIntersect1M) "
           "(Mrays/s, best of %d passes taken by the libraries in turns; static: the diffuse rays through the static "
           "mesh in the same library); "
           "update: the geometry at quality REFIT, every step moved on and committed again (1 thread, best of %d "
           "frames)\n",
           o->builds, o->repeat, o->builds + 1);
    printf("  %-20s %5s %3s %9s %7s %8s %10s %7s %10s %7s %10s %7s %10s %7s %9s %8s %10s %7s\n", "library", "steps",
           "thr", "build ms", "ratio", "B/tri", "primary", "ratio", "diffuse", "ratio", "primary8", "ratio", "diffuse1M",
           "ratio", "static", "differ", "update ms", "ratio");
    rayset timed[2] = {c->sets[SET_PRIMARY], c->sets[SET_DIFFUSE]};
    float *v[5] = {0};
    const size_t most = timed[0].n > timed[1].n ? timed[0].n : timed[1].n;
    unsigned char *hits = malloc(most + 1), *ref_hits = malloc(timed[0].n + 1), *single_hits = malloc(most + 1);
    int rc = !hits || !ref_hits || !single_hits;
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
        /* Every library's scenes first (the builds in turns, the last one
         * kept), then the passes in turns (each library's primary,
         * diffuse, packet and static pass, --repeat times), the best of
         * each kept, so that a slow spell of the machine falls on all
         * libraries alike; then each library's update frames. */
        scene ms[MAXLIBS], st[MAXLIBS];
        double best[MAXLIBS], bytes[MAXLIBS] = {0}, el[MAXLIBS][4][5], update[MAXLIBS] = {0};
        int built[MAXLIBS] = {0};
        size_t differ[MAXLIBS] = {0};
        memset(ms, 0, sizeof ms);
        memset(st, 0, sizeof st);
        for (int l = 0; l < c->nlibs; l++) {
            best[l] = 1e30;
            for (int ti = 0; ti < 4; ti++)
                for (int k = 0; k < 5; k++)
                    el[l][ti][k] = 1e30;
        }
        for (int b = 0; b < o->builds && !rc; b++)
            for (int l = 0; l < c->nlibs && !rc; l++) {
                scene sc;
                rc = motion_scene(&sc, &c->libs[l], c->m, v, steps, 0, err, err_size);
                if (rc)
                    break;
                best[l] = sc.seconds < best[l] ? sc.seconds : best[l];
                bytes[l] = sc.bytes_per_tri;
                if (b + 1 < o->builds)
                    scene_release(&sc);
                else
                    ms[l] = sc;
            }
        for (int l = 0; l < c->nlibs && !rc; l++)
            rc = scene_build(&st[l], &c->libs[l], c->m, c->padded, MODE_DEFAULT, 1, err, err_size);
        for (int r = 0; r < o->repeat && !rc; r++)
            for (int ti = 0; ti < o->nthreads; ti++)
                for (int l = 0; l < c->nlibs; l++) {
                    const render_tracer t = scene_tracer(&ms[l], 0), tc = scene_tracer(&ms[l], 1),
                                        ts = scene_tracer(&st[l], 0);
                    const int th = o->threads[ti], first = r == 0 && ti == 0;
                    double e[5];
                    e[0] = trace_pass(&t, &timed[0], 1, 0, th, hits);
                    if (first) {
                        if (l == 0)
                            memcpy(ref_hits, hits, timed[0].n);
                        for (size_t i = 0; i < timed[0].n; i++)
                            differ[l] += hits[i] != ref_hits[i];
                    }
                    e[1] = trace_pass(&t, &timed[1], 1, 0, th, single_hits);
                    e[2] = trace_pass(&tc, &timed[0], 8, 0, th, hits);
                    e[4] = stream_pass(&t, &timed[1], th, hits);
                    if (first) /* the stream's answers are the single rays' */
                        for (size_t i = 0; i < timed[1].n; i++)
                            differ[l] += hits[i] != single_hits[i];
                    e[3] = trace_pass(&ts, &timed[1], 1, 0, th, hits);
                    for (int k = 0; k < 5; k++)
                        el[l][ti][k] = e[k] < el[l][ti][k] ? e[k] : el[l][ti][k];
                }
        for (int l = 0; l < c->nlibs; l++) {
            if (ms[l].lib)
                scene_release(&ms[l]);
            if (st[l].lib)
                scene_release(&st[l]);
        }
        for (int l = 0; l < c->nlibs && !rc; l++) {
            update[l] = motion_update(&c->libs[l], c->m, v, steps, diag, o->builds + 1, &built[l], err, err_size);
            rc = update[l] < 0;
        }
        for (int ti = 0; ti < o->nthreads && !rc; ti++)
            for (int l = 0; l < c->nlibs; l++) {
                const lib *lb = &c->libs[l];
                const int th = o->threads[ti];
                /* rates (this library's, and the first library's for the
                 * ratios): primary, diffuse, primary packets of 8, static
                 * diffuse, diffuse streams */
                double rate[5], r0[5];
                for (int k = 0; k < 5; k++) {
                    rate[k] = (double)timed[k == 1 || k >= 3].n / el[l][ti][k] * 1e-6;
                    r0[k] = (double)timed[k == 1 || k >= 3].n / el[0][ti][k] * 1e-6;
                }
                printf("  %-20s %5d %3d %9.1f %6.2fx %8.1f %10.2f %6.2fx %10.2f %6.2fx %10.2f %6.2fx %10.2f %6.2fx "
                       "%9.2f %8zu %10.1f %6.2fx%s\n",
                       lb->name, steps, th, best[l] * 1e3, ratio(best[0], best[l]), bytes[l], rate[0],
                       ratio(rate[0], r0[0]), rate[1], ratio(rate[1], r0[1]), rate[2], ratio(rate[2], r0[2]), rate[4],
                       ratio(rate[4], r0[4]), rate[3], differ[l], update[l] * 1e3, ratio(update[0], update[l]),
                       built[l] ? " (built, no refit)" : "");
                char variant[32];
                snprintf(variant, sizeof variant, "%d steps", steps);
                if (ti == 0) {
                    csv_row(&c->csv, "motion", lb->name, variant, "start time", "", 1, best[l] * 1e3, "ms",
                            ratio(best[0], best[l]));
                    csv_row(&c->csv, "motion", lb->name, variant, "memory", "", 1, bytes[l], "bytes per triangle", 0);
                    csv_row(&c->csv, "motion", lb->name, variant, "update", "", 1, update[l] * 1e3, "ms",
                            ratio(update[0], update[l]));
                }
                csv_row(&c->csv, "motion", lb->name, variant, "primary", "single", th, rate[0], "Mrays/s",
                        ratio(rate[0], r0[0]));
                csv_row(&c->csv, "motion", lb->name, variant, "diffuse", "single", th, rate[1], "Mrays/s",
                        ratio(rate[1], r0[1]));
                csv_row(&c->csv, "motion", lb->name, variant, "primary", "packet8", th, rate[2], "Mrays/s",
                        ratio(rate[2], r0[2]));
                csv_row(&c->csv, "motion", lb->name, variant, "diffuse", "stream", th, rate[4], "Mrays/s",
                        ratio(rate[4], r0[4]));
                csv_row(&c->csv, "motion", lb->name, "static", "diffuse", "single", th, rate[3], "Mrays/s", 0);
            }
    }
    printf("  (differ: primary rays that hit where %s misses or the other way round, and diffuse rays whose stream "
           "answer (hit or miss) is not the library's single-ray one)\n",
           c->libs[0].name);
    for (int k = 0; k < 5; k++)
        free(v[k]);
    for (int k = 0; k < 2; k++)
        free(timed[k].rays);
    free(hits);
    free(ref_hits);
    free(single_hits);
    return rc;
}
