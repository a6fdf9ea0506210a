/* The two-level section: instances and dynamic scenes. */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_internal.h"

/* ---- two levels: instances and dynamic scenes ---- */

#define GRID 4    /* instances: a GRID x GRID floor of the mesh */

#define PIECES 16 /* dynamic: the mesh cut in this many geometries */

/* A scene of GRID * GRID instances of `child` (translated only, so the
 * object-space normals the libraries report are world-space ones and the
 * path tracer's bounces are right), timed from the first call to the
 * committed scene. */
static int grid_scene(scene *sc, lib *l, const scene *child, float spacing, char *err, size_t err_size)
{
    memset(sc, 0, sizeof *sc);
    sc->lib = l;
    const double t0 = now();
    if (l->embree) {
        RTCScene s = rtcNewScene(l->edev);
        for (int i = 0; i < GRID * GRID; i++) {
            const float x[12] = {1, 0, 0, spacing * (float)(i % GRID), 0, 1, 0, 0, 0, 0, 1, -spacing * (float)(i / GRID)};
            attach_instance(l, s, NULL, child, x);
        }
        return embree_commit(sc, s, t0, "the instances", err, err_size);
    }
    rtk_scene s = NULL;
    int bad = rtk_scene_new(l->rdev, &s) != RTK_OK;
    for (int i = 0; i < GRID * GRID && !bad; i++) {
        const float x[12] = {1, 0, 0, spacing * (float)(i % GRID), 0, 1, 0, 0, 0, 0, 1, -spacing * (float)(i / GRID)};
        bad = attach_instance(l, NULL, s, child, x);
    }
    return rtk_commit(sc, s, bad, t0, err, err_size);
}

/* The mesh cut in PIECES runs of triangles, each with its own vertices
 * (so one can move alone), padded for Embree. */
typedef struct pieces {
    float *v[PIECES];
    uint32_t *idx[PIECES];
    size_t nv[PIECES], nt[PIECES];
} pieces;

static void pieces_free(pieces *p)
{
    for (int k = 0; k < PIECES; k++) {
        free(p->v[k]);
        free(p->idx[k]);
    }
}

static int pieces_make(const rtk_mesh *m, pieces *p)
{
    memset(p, 0, sizeof *p);
    uint32_t *map = malloc(m->vertex_count * sizeof *map);
    if (!map)
        return 1;
    for (int k = 0; k < PIECES; k++) {
        const size_t t0 = m->triangle_count * (size_t)k / PIECES, t1 = m->triangle_count * (size_t)(k + 1) / PIECES;
        memset(map, 0xff, m->vertex_count * sizeof *map);
        p->nt[k] = t1 - t0;
        p->idx[k] = malloc((p->nt[k] ? p->nt[k] : 1) * 3 * sizeof(uint32_t));
        p->v[k] = malloc((3 * p->nt[k] + 1) * 3 * sizeof(float) + 16);
        if (!p->idx[k] || !p->v[k]) {
            free(map);
            return 1;
        }
        size_t nv = 0;
        for (size_t t = t0; t < t1; t++)
            for (int c = 0; c < 3; c++) {
                const uint32_t vi = m->indices[3 * t + c];
                if (map[vi] == UINT32_MAX) {
                    map[vi] = (uint32_t)nv;
                    memcpy(p->v[k] + 3 * nv++, m->vertices + 3 * (size_t)vi, 3 * sizeof(float));
                }
                p->idx[k][3 * (t - t0) + c] = map[vi];
            }
        p->nv[k] = nv;
    }
    free(map);
    return 0;
}

/* A dynamic scene of the pieces: piece 0 deforms (REFIT), the others are
 * static (medium).  Embree: flagged dynamic at low quality, its two-level
 * mode. */
static int pieces_scene(scene *sc, lib *l, const pieces *p, char *err, size_t err_size)
{
    memset(sc, 0, sizeof *sc);
    sc->lib = l;
    const double t0 = now();
    if (l->embree) {
        RTCScene s = rtcNewScene(l->edev);
        rtcSetSceneFlags(s, RTC_SCENE_FLAG_DYNAMIC);
        rtcSetSceneBuildQuality(s, RTC_BUILD_QUALITY_LOW);
        for (int k = 0; k < PIECES; k++) {
            RTCGeometry g = rtcNewGeometry(l->edev, RTC_GEOMETRY_TYPE_TRIANGLE);
            rtcSetGeometryBuildQuality(g, k ? RTC_BUILD_QUALITY_MEDIUM : RTC_BUILD_QUALITY_REFIT);
            rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, p->v[k], 0, 12, p->nv[k]);
            rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, p->idx[k], 0, 12, p->nt[k]);
            rtcCommitGeometry(g);
            rtcAttachGeometry(s, g);
            rtcReleaseGeometry(g);
        }
        return embree_commit(sc, s, t0, "the dynamic scene", err, err_size);
    }
    rtk_scene s = NULL;
    int bad = rtk_scene_new(l->rdev, &s) || rtk_scene_set_flags(s, RTK_SCENE_FLAG_DYNAMIC);
    for (int k = 0; k < PIECES && !bad; k++) {
        rtk_geometry g = NULL;
        bad = rtk_geometry_new(l->rdev, RTK_GEOMETRY_TYPE_TRIANGLE, &g) ||
              rtk_geometry_set_build_quality(g, k ? RTK_BUILD_QUALITY_MEDIUM : RTK_BUILD_QUALITY_REFIT) ||
              rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, p->v[k], 0, 12, p->nv[k]) ||
              rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, p->idx[k], 0, 12, p->nt[k]) ||
              rtk_geometry_commit(g) || rtk_scene_attach_geometry(s, g, NULL);
        rtk_geometry_release(g);
    }
    return rtk_commit(sc, s, bad, t0, err, err_size);
}

/* Piece 0 moved up by dy: its buffer updated, geometry and scene committed. */
static void pieces_move(scene *sc, pieces *p, const float *rest, float dy)
{
    for (size_t i = 0; i < p->nv[0]; i++)
        p->v[0][3 * i + 1] = rest[3 * i + 1] + dy;
    if (sc->escene) {
        RTCGeometry g = rtcGetGeometry(sc->escene, 0);
        rtcUpdateGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0);
        rtcCommitGeometry(g);
        rtcCommitScene(sc->escene);
    } else {
        rtk_geometry g = rtk_scene_get_geometry(sc->rscene, 0);
        rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_VERTEX);
        rtk_geometry_commit(g);
        rtk_scene_commit(sc->rscene);
    }
}

/* The path tracer's APIs here: single rays, packets of 8 (rtk's go
 * through its two-level stream kernel, core/query.c) and streams, each
 * where --api names it. */
#define TWO_APIS 3
static const int two_apis[TWO_APIS] = {1, 8, RENDER_API_STREAM};

/* One pass of the path tracer through a scene framed by lo/hi on
 * `threads` threads with API `api`: its rate (Mrays/s), or -1. */
static double render_pass(const bench_opts *o, scene *sc, const float lo[3], const float hi[3], int threads, int api,
                          float *rgb, char *err, size_t err_size)
{
    render_settings rs;
    diffuse_settings(&rs, o, lo, hi, threads);
    rs.api = api;
    const render_tracer t = scene_tracer(sc, 0);
    return diffuse_pass(&t, &rs, rgb, NULL, err, err_size);
}

int section_twolevel(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    float lo[3], hi[3];
    const float diag = rtk_mesh_bounds(c->m, lo, hi), spacing = 1.05f * (hi[0] - lo[0] > hi[2] - lo[2] ? hi[0] - lo[0]
                                                                                                    : hi[2] - lo[2]);
    const float glo[3] = {lo[0], lo[1], lo[2] - spacing * (GRID - 1)};
    const float ghi[3] = {hi[0] + spacing * (GRID - 1), hi[1], hi[2]};
    printf("\ntwo levels: %d instances of the mesh on a %dx%d floor (commit of the top level, 1 thread, best of %d; "
           "the path tracer's rate through it, %dx%d, %d spp, Mrays/s); the mesh cut in %d geometries of a dynamic "
           "scene, one of them deforming (REFIT) and moved in each of %d frames (first commit, then the commit of a "
           "frame, 1 thread, best of the frames; the path tracer's rate after the last frame); rates on each thread "
           "count (thr) and API (single rays, packets of 4x2 pixels, or each bounce's rays of a tile as a stream), the "
           "best of %d passes taken by the libraries in turns\n",
           GRID * GRID, GRID, GRID, o->builds, o->render_w, o->render_h, o->render_spp, PIECES, o->builds + 1,
           o->repeat);
    printf("  %-20s %3s %-6s %12s %8s %10s %8s %12s %10s %8s %10s %8s\n", "library", "thr", "api", "instances ms",
           "ratio", "Mrays/s", "ratio", "dynamic ms", "frame ms", "ratio", "Mrays/s", "ratio");
    float *rgb = malloc((size_t)o->render_w * (size_t)o->render_h * 3 * sizeof *rgb);
    /* each library's own copy of the pieces: their scenes share the
     * buffers, and all are alive until the passes are done */
    pieces pl[MAXLIBS];
    int made = 0;
    while (rgb && made < c->nlibs && !pieces_make(c->m, &pl[made]))
        made++;
    if (!rgb || made < c->nlibs) {
        for (int l = 0; rgb && l <= made && l < c->nlibs; l++)
            pieces_free(&pl[l]); /* (pieces_make cleared the one that failed) */
        free(rgb);
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    const pieces *p = &pl[0];
    float *rest = malloc((p->nv[0] ? p->nv[0] : 1) * 3 * sizeof *rest);
    int rc = !rest;
    if (rest)
        memcpy(rest, p->v[0], p->nv[0] * 3 * sizeof *rest);
    /* Each library's scenes first, then the path tracer's passes taken in
     * turns (every library's instances, then every library's dynamic
     * scene, --repeat times), the best pass of each kept: a slow spell of
     * the machine then falls on all libraries alike, not on whichever ran
     * through it. */
    scene grids[MAXLIBS], dyns[MAXLIBS];
    double inst_ms[MAXLIBS], frame_ms[MAXLIBS], dyn_first[MAXLIBS], inst_rate[MAXLIBS][4][TWO_APIS] = {{{0}}},
        dyn_rate[MAXLIBS][4][TWO_APIS] = {{{0}}};
    memset(grids, 0, sizeof grids);
    memset(dyns, 0, sizeof dyns);
    for (int l = 0; l < c->nlibs && !rc; l++) {
        lib *lb = &c->libs[l];
        scene child;
        inst_ms[l] = frame_ms[l] = 1e30;
        rc = scene_build(&child, lb, c->m, c->padded, MODE_DEFAULT, 1, err, err_size);
        for (int b = 0; b < o->builds && !rc; b++) {
            scene grid;
            rc = grid_scene(&grid, lb, &child, spacing, err, err_size);
            if (rc)
                break;
            inst_ms[l] = grid.seconds * 1e3 < inst_ms[l] ? grid.seconds * 1e3 : inst_ms[l];
            if (b == o->builds - 1)
                grids[l] = grid; /* (it holds the child) */
            else
                scene_release(&grid);
        }
        if (child.lib)
            scene_release(&child);
        if (!rc)
            rc = pieces_scene(&dyns[l], lb, &pl[l], err, err_size);
        if (rc)
            break;
        scene *dyn = &dyns[l];
        dyn_first[l] = dyn->seconds * 1e3;
        for (int f = 1; f <= o->builds + 1; f++) {
            const double t0 = now();
            pieces_move(dyn, &pl[l], rest, 0.002f * diag * (float)f);
            const double ms = (now() - t0) * 1e3;
            frame_ms[l] = ms < frame_ms[l] ? ms : frame_ms[l];
        }
        if (dyn->rscene) {
            rtk_scene_info info = {.struct_size = sizeof info};
            if (rtk_scene_get_info(dyn->rscene, &info) || info.trees_built != 0 || info.refits != 1) {
                snprintf(err, err_size, "%s: a frame did not refit the one geometry alone", lb->name);
                rc = 1;
            }
        }
        if (dyn->escene && rtcGetDeviceError(lb->edev) != RTC_ERROR_NONE) {
            snprintf(err, err_size, "%s: a frame's commit failed", lb->name);
            rc = 1;
        }
    }
    for (int r = 0; r < o->repeat && !rc; r++)
        for (int ti = 0; ti < o->nthreads && !rc; ti++)
            for (int a = 0; a < TWO_APIS && !rc; a++)
                for (int k = 0; k < 2 && !rc && api_on(o, two_apis[a]); k++)
                    for (int l = 0; l < c->nlibs && !rc; l++) {
                        scene *sc = k ? &dyns[l] : &grids[l];
                        const int th = o->threads[ti];
                        const double v = render_pass(o, sc, k ? lo : glo, k ? hi : ghi, th, two_apis[a], rgb, err,
                                                     err_size);
                        rc = v < 0;
                        double *best = k ? &dyn_rate[l][ti][a] : &inst_rate[l][ti][a];
                        *best = v > *best ? v : *best;
                    }
    for (int l = 0; l < c->nlibs; l++) {
        if (grids[l].lib)
            scene_release(&grids[l]);
        if (dyns[l].lib)
            scene_release(&dyns[l]);
    }
    for (int l = 0; l < c->nlibs && !rc; l++) {
        lib *lb = &c->libs[l];
        csv_row(&c->csv, "twolevel", lb->name, "instances", "commit", "", 1, inst_ms[l], "ms",
                ratio(inst_ms[0], inst_ms[l]));
        csv_row(&c->csv, "twolevel", lb->name, "dynamic", "first commit", "", 1, dyn_first[l], "ms", 0);
        csv_row(&c->csv, "twolevel", lb->name, "dynamic", "frame commit", "", 1, frame_ms[l], "ms",
                ratio(frame_ms[0], frame_ms[l]));
    }
    for (int ti = 0; ti < o->nthreads && !rc; ti++)
        for (int a = 0; a < TWO_APIS; a++)
            for (int l = 0; l < c->nlibs && api_on(o, two_apis[a]); l++) {
                lib *lb = &c->libs[l];
                const int th = o->threads[ti];
                const char *api = render_api_name(two_apis[a]);
                const double ir = inst_rate[l][ti][a], dr = dyn_rate[l][ti][a];
                printf("  %-20s %3d %-6s %12.3f %7.2fx %10.2f %7.2fx %12.1f %10.3f %7.2fx %10.2f %7.2fx\n", lb->name,
                       th, api, inst_ms[l], ratio(inst_ms[0], inst_ms[l]), ir, ratio(ir, inst_rate[0][ti][a]),
                       dyn_first[l], frame_ms[l], ratio(frame_ms[0], frame_ms[l]), dr, ratio(dr, dyn_rate[0][ti][a]));
                csv_row(&c->csv, "twolevel", lb->name, "instances", "diffuse path tracer", api, th, ir, "Mrays/s",
                        ratio(ir, inst_rate[0][ti][a]));
                csv_row(&c->csv, "twolevel", lb->name, "dynamic", "diffuse path tracer", api, th, dr, "Mrays/s",
                        ratio(dr, dyn_rate[0][ti][a]));
            }
    free(rest);
    for (int l = 0; l < c->nlibs; l++)
        pieces_free(&pl[l]);
    free(rgb);
    return rc;
}
