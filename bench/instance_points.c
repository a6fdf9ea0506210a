/*
 * Closest points through instances, rtk alone: for comparing two builds
 * of rtk's backends in turns (RTK_BACKEND_PATH=DIR for each; rtktool
 * bench's points section measures plain meshes beside Embree).
 * docs/benchmarks/points-and-python.md.
 *
 *   instance_points N [REPS]   N instances of the tools' procedural mesh
 *       of 1,024 triangles (a bumpy sphere of radius about 1,
 *       procedural:1024) at random positions in a cube of side 4 N^(1/3), each
 *       turned about z and scaled by 0.5-1.5 (a similarity), and 100,000
 *       points uniform in that cube: the best of REPS (default 5)
 *       rtk_closest_point_batch calls, ns per point, and a hash of the
 *       answers' ids (equal for two builds that answer alike)
 *
 * On 1 thread (the device's threads=1).
 */
#define _POSIX_C_SOURCE 199309L /* clock_gettime */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "mesh_import.h"
#include "mesh_tools.h"
#include "rtk/rtk.h"

#define PI 3.14159265358979323846

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static uint64_t rng_state = 1;
static double rnd(void) /* [0, 1) */
{
    rng_state = rng_state * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(rng_state >> 11) * 0x1p-53;
}

#define CHECK(call)                                                                                                    \
    do {                                                                                                               \
        if ((call) != RTK_OK) {                                                                                        \
            fprintf(stderr, "instance_points: %s failed: %s\n", #call, rtk_device_get_error_message(NULL));            \
            return 1;                                                                                                  \
        }                                                                                                              \
    } while (0)

int main(int argc, char **argv)
{
    const long count = argc > 1 ? strtol(argv[1], NULL, 10) : 0;
    const int reps = argc > 2 ? atoi(argv[2]) : 5;
    if (count < 1 || count > 10000000 || reps < 1) {
        fprintf(stderr, "usage: instance_points N [REPS]  (1 <= N <= 10^7)\n");
        return 2;
    }
    rtk_mesh mesh;
    if (rtk_mesh_procedural(1024, &mesh)) {
        fprintf(stderr, "instance_points: out of memory\n");
        return 1;
    }
    rtk_device dev;
    CHECK(rtk_device_new("threads=1", &dev));
    rtk_scene inner, top;
    CHECK(rtk_scene_new(dev, &inner));
    CHECK(rtk_scene_new(dev, &top));
    rtk_geometry g;
    CHECK(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g));
    CHECK(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, mesh.vertices, 0, 12, mesh.vertex_count));
    CHECK(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, mesh.indices, 0, 12, mesh.triangle_count));
    CHECK(rtk_geometry_commit(g));
    CHECK(rtk_scene_attach_geometry(inner, g, NULL));
    rtk_geometry_release(g);
    CHECK(rtk_scene_commit(inner));
    const double side = 4.0 * cbrt((double)count);
    for (long i = 0; i < count; i++) {
        const double a = rnd() * 2 * PI, s = 0.5 + rnd();
        const float xf[12] = {(float)(s * cos(a)), (float)(-s * sin(a)), 0.0f, (float)(rnd() * side),
                              (float)(s * sin(a)), (float)(s * cos(a)),  0.0f, (float)(rnd() * side),
                              0.0f,                0.0f,                 (float)s, (float)(rnd() * side)};
        rtk_geometry ig;
        CHECK(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &ig));
        CHECK(rtk_geometry_set_instanced_scene(ig, inner));
        CHECK(rtk_geometry_set_transform(ig, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, xf));
        CHECK(rtk_geometry_commit(ig));
        CHECK(rtk_scene_attach_geometry(top, ig, NULL));
        rtk_geometry_release(ig);
    }
    CHECK(rtk_scene_commit(top));
    const size_t n = 100000;
    rtk_point_query *q = calloc(n, sizeof *q);
    rtk_point_hit *h = malloc(n * sizeof *h);
    if (!q || !h)
        return 1;
    for (size_t i = 0; i < n; i++)
        q[i] = (rtk_point_query){.x = rnd() * side, .y = rnd() * side, .z = rnd() * side, .radius = INFINITY};
    double best = INFINITY;
    for (int r = 0; r < reps; r++) {
        const double t0 = now();
        CHECK(rtk_closest_point_batch(top, q, h, n));
        const double t = now() - t0;
        best = t < best ? t : best;
    }
    uint64_t hash = 1469598103934665603ull;
    for (size_t i = 0; i < n; i++)
        hash = (hash ^ ((uint64_t)h[i].instID << 32 | h[i].primID)) * 1099511628211ull;
    printf("%ld instances: %.1f ns per point (best of %d), answers' hash %016llx\n", count, best * 1e9 / (double)n, reps,
           (unsigned long long)hash);
    free(q);
    free(h);
    rtk_scene_release(top);
    rtk_scene_release(inner);
    rtk_device_release(dev);
    rtk_mesh_free(&mesh);
    return 0;
}
