/*
 * Commit times of two-level scenes, rtk alone: for comparing two builds of
 * rtk's backends on this noisy VM, run in turns (RTK_BACKEND_PATH=DIR for
 * each), where rtktool bench's two-level and forest sections (beside
 * Embree) time a frame only a few dozen times per library, one library
 * after the other.  docs/benchmarks/two-levels.md.
 *
 *   top_level_commit instances N REPS   the top level of N instances of an
 *       octahedron at random positions, turns and scales: the best of REPS
 *       commits (the scene re-committed after a geometry's commit), with
 *       the top level's node count and SAH cost (equal for two builds that
 *       split alike) and a hash of 100,000 rays' hits
 *   top_level_commit frames RES FRAMES  a dynamic scene of 16 pieces of a
 *       bumpy UV sphere of 2 RES^2 triangles, piece 0 of quality REFIT
 *       moved in each frame: the first commit, and the best and mean of
 *       FRAMES frames (vertices written, geometry and scene committed)
 *
 * Builds on 1 thread (the device's threads=1).
 */
#define _POSIX_C_SOURCE 199309L /* clock_gettime */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "rtk/rtk.h"

#define PIECES 16

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + (double)t.tv_nsec * 1e-9;
}

static rtk_device dev;

static int fail(const char *what)
{
    const char *msg = rtk_device_get_error_message(dev);
    fprintf(stderr, "top_level_commit: %s failed%s%s\n", what, msg ? ": " : "", msg ? msg : "");
    return 1;
}

static int instances(rtk_device d, int n, int reps)
{
    static const float v[] = {1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1};
    static const unsigned idx[] = {0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5};
    rtk_scene child = NULL, top = NULL;
    rtk_geometry g = NULL;
    if (rtk_scene_new(d, &child) || rtk_geometry_new(d, RTK_GEOMETRY_TYPE_TRIANGLE, &g) ||
        rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, 6) ||
        rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, idx, 0, 12, 8) || rtk_geometry_commit(g) ||
        rtk_scene_attach_geometry(child, g, NULL) || rtk_scene_commit(child) || rtk_scene_new(d, &top))
        return fail("the instanced scene");
    rtk_geometry_release(g);
    srand(7);
    for (int i = 0; i < n; i++) {
        rtk_geometry in = NULL;
        const float s = 0.5f + (float)(rand() % 1000) / 1000.0f, a = (float)(rand() % 6283) / 1000.0f;
        const float x = (float)(rand() % 100000) / 100.0f, z = (float)(rand() % 100000) / 100.0f;
        const float y = (float)(rand() % 1000) / 100.0f;
        const float m[12] = {s * cosf(a), 0, s * sinf(a), x, 0, s, 0, y, -s * sinf(a), 0, s * cosf(a), z};
        if (rtk_geometry_new(d, RTK_GEOMETRY_TYPE_INSTANCE, &in) || rtk_geometry_set_instanced_scene(in, child) ||
            rtk_geometry_set_transform(in, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, m) || rtk_geometry_commit(in) ||
            rtk_scene_attach_geometry(top, in, NULL))
            return fail("an instance");
        rtk_geometry_release(in);
    }
    double best = INFINITY;
    for (int r = 0; r < reps; r++) {
        const double t0 = now();
        if (rtk_scene_commit(top))
            return fail("the commit");
        const double t = now() - t0;
        best = t < best ? t : best;
        if (n && rtk_geometry_commit(rtk_scene_get_geometry(top, 0))) /* (so the next commit builds again) */
            return fail("the geometry's commit");
    }
    rtk_scene_info info = {.struct_size = sizeof info};
    if (rtk_scene_get_info(top, &info))
        return fail("rtk_scene_get_info");
    unsigned long h = 0;
    for (int i = 0; i < 100000; i++) {
        rtk_rayhit rh;
        memset(&rh, 0, sizeof rh);
        rh.ray = (rtk_ray){.org_x = -10, .org_y = 5, .org_z = -10, .dir_x = 1 + (float)(i / 317) * 0.003f,
                           .dir_y = -0.01f + 0.02f * (float)(i % 317) / 317.0f, .dir_z = 1, .tfar = INFINITY,
                           .mask = ~0u};
        rh.hit.geomID = rh.hit.instID = RTK_INVALID_GEOMETRY_ID;
        rtk_intersect1(top, &rh);
        h = h * 31 + rh.hit.instID + (unsigned)(rh.ray.tfar * 1000.0f);
    }
    printf("instances %d: commit best %.3f ms; nodes %llu, leaves %llu, depth %u, SAH cost %.17g; hits hash %lu\n", n,
           best * 1e3, (unsigned long long)info.nodes, (unsigned long long)info.leaves, info.depth, info.sah_cost, h);
    rtk_scene_release(top);
    rtk_scene_release(child);
    return 0;
}

static int frames(rtk_device d, int res, int nframes)
{
    rtk_scene s = NULL;
    if (rtk_scene_new(d, &s) || rtk_scene_set_flags(s, RTK_SCENE_FLAG_DYNAMIC))
        return fail("the scene");
    float *keep[PIECES] = {0}, *rest = NULL;
    unsigned *ikeep[PIECES] = {0};
    size_t nv0 = 0;
    for (int k = 0; k < PIECES; k++) {
        const int r0 = res * k / PIECES, r1 = res * (k + 1) / PIECES, nr = r1 - r0;
        const size_t nv = (size_t)(nr + 1) * (size_t)(res + 1), nt = (size_t)nr * (size_t)res * 2;
        float *v = keep[k] = malloc(nv * 12 + 16);
        unsigned *ix = ikeep[k] = malloc((nt ? nt : 1) * 12);
        if (!v || !ix)
            return fail("malloc");
        for (int i = 0; i <= nr; i++)
            for (int j = 0; j <= res; j++) {
                const float th = 3.14159265f * (float)(r0 + i) / (float)res, ph = 6.2831853f * (float)j / (float)res;
                const float rr = 1.0f + 0.05f * sinf(7 * th) * cosf(5 * ph);
                float *p = v + 3 * ((size_t)i * (size_t)(res + 1) + (size_t)j);
                p[0] = rr * sinf(th) * cosf(ph);
                p[1] = rr * cosf(th);
                p[2] = rr * sinf(th) * sinf(ph);
            }
        size_t t = 0;
        for (int i = 0; i < nr; i++)
            for (int j = 0; j < res; j++) {
                const unsigned a = (unsigned)(i * (res + 1) + j), b = a + 1, c = a + (unsigned)res + 1, e = c + 1;
                const unsigned tri[6] = {a, c, b, b, c, e};
                memcpy(ix + 3 * t, tri, sizeof tri);
                t += 2;
            }
        rtk_geometry g = NULL;
        if (rtk_geometry_new(d, RTK_GEOMETRY_TYPE_TRIANGLE, &g) ||
            rtk_geometry_set_build_quality(g, k ? RTK_BUILD_QUALITY_MEDIUM : RTK_BUILD_QUALITY_REFIT) ||
            rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, nv) ||
            rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, ix, 0, 12, nt) || rtk_geometry_commit(g) ||
            rtk_scene_attach_geometry(s, g, NULL))
            return fail("a piece");
        rtk_geometry_release(g);
        if (!k) {
            nv0 = nv;
            rest = malloc(nv * 12);
            if (!rest)
                return fail("malloc");
            memcpy(rest, v, nv * 12);
        }
    }
    const double t0 = now();
    if (rtk_scene_commit(s))
        return fail("the first commit");
    const double first = now() - t0;
    double best = INFINITY, sum = 0.0;
    for (int f = 1; f <= nframes; f++) {
        const double a = now();
        for (size_t i = 0; i < nv0; i++)
            keep[0][3 * i + 1] = rest[3 * i + 1] + 0.001f * (float)f;
        rtk_geometry g = rtk_scene_get_geometry(s, 0);
        if (rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_VERTEX) || rtk_geometry_commit(g) || rtk_scene_commit(s))
            return fail("a frame");
        const double t = now() - a;
        sum += t;
        best = t < best ? t : best;
    }
    rtk_scene_info info = {.struct_size = sizeof info};
    if (rtk_scene_get_info(s, &info))
        return fail("rtk_scene_get_info");
    printf("frames: %d triangles in %d pieces, first commit %.3f ms, frame best %.4f ms, mean %.4f ms (%d frames); "
           "refits %u, top-level nodes %llu\n",
           2 * res * res, PIECES, first * 1e3, best * 1e3, sum / nframes * 1e3, nframes, info.refits,
           (unsigned long long)info.nodes);
    rtk_scene_release(s);
    for (int k = 0; k < PIECES; k++) {
        free(keep[k]);
        free(ikeep[k]);
    }
    free(rest);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc != 4 || (strcmp(argv[1], "instances") && strcmp(argv[1], "frames"))) {
        fprintf(stderr, "usage: top_level_commit instances N REPS | frames RES FRAMES\n");
        return 2;
    }
    const int a = atoi(argv[2]), b = atoi(argv[3]);
    if (a < 1 || b < 1 || (argv[1][0] == 'f' && (a < PIECES || a > 20000)) || a > 100000000) {
        fprintf(stderr, "top_level_commit: N, REPS, FRAMES at least 1, RES 16 to 20000\n");
        return 2;
    }
    if (rtk_device_new("threads=1", &dev))
        return fail("rtk_device_new");
    const int rc = argv[1][0] == 'i' ? instances(dev, a, b) : frames(dev, a, b);
    rtk_device_release(dev);
    return rc;
}
