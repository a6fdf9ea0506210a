/*
 * bench_vs_embree MESH [--rays N] [--repeat N] [--builds N] [--build-only]
 *
 * Builds MESH once per rtk backend and with Embree 3 (medium quality, at
 * isa=avx2 and at its default), in this one process, and traces the same
 * three ray sets through every one of them on one thread:
 *   primary   1024x768 camera rays framing the mesh (coherent), intersect1
 *   random    origins in the grown bounding box, uniform directions, intersect1
 *   shadow    random segments of up to a third of the diagonal, occluded1
 * Prints Mtris/s for builds (best of --builds builds, each from the shared
 * buffers to a committed scene) and Mrays/s for traces (best of --repeat
 * passes), each also as a ratio to Embree (isa=avx2), and counts hit/miss
 * disagreements with Embree.  --build-only skips the traces.
 * A benchmark, not a test: run it and read it.
 */
#define _POSIX_C_SOURCE 200809L
#include <embree3/rtcore.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "mesh_import.h"
#include "rtk/rtk.h"

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

typedef struct rayset {
    const char *name;
    rtk_ray *rays;
    size_t n;
    int occluded;
} rayset;

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static float rnd(void)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (float)(rng_state >> 40) * 0x1p-24f;
}

static void make_rays(const rtk_mesh *m, rayset sets[3], size_t nrand)
{
    float lo[3], hi[3], c[3];
    const float diag = rtk_mesh_bounds(m, lo, hi);
    for (int k = 0; k < 3; k++)
        c[k] = 0.5f * (lo[k] + hi[k]);
    const int W = 1024, H = 768;
    sets[0] = (rayset){"primary", calloc((size_t)W * H, sizeof(rtk_ray)), (size_t)W * H, 0};
    const float eye[3] = {c[0] + 0.35f * diag, c[1] + 0.3f * diag, c[2] + 1.0f * diag};
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            float t[3] = {c[0] + diag * 0.6f * ((x + 0.5f) / W - 0.5f), c[1] - diag * 0.45f * ((y + 0.5f) / H - 0.5f),
                          c[2]};
            rtk_ray *r = &sets[0].rays[(size_t)y * W + x];
            *r = (rtk_ray){.org_x = eye[0], .org_y = eye[1], .org_z = eye[2], .dir_x = t[0] - eye[0],
                           .dir_y = t[1] - eye[1], .dir_z = t[2] - eye[2], .tfar = INFINITY, .mask = ~0u};
        }
    for (int s = 1; s < 3; s++) {
        sets[s] = (rayset){s == 1 ? "random" : "shadow", calloc(nrand, sizeof(rtk_ray)), nrand, s == 2};
        for (size_t i = 0; i < nrand; i++) {
            float z = 2 * rnd() - 1, phi = 6.2831853f * rnd(), rr = sqrtf(1 - z * z);
            rtk_ray *r = &sets[s].rays[i];
            *r = (rtk_ray){.dir_x = rr * cosf(phi), .dir_y = rr * sinf(phi), .dir_z = z, .mask = ~0u,
                           .tfar = s == 1 ? INFINITY : diag * rnd() / 3};
            r->org_x = lo[0] + (hi[0] - lo[0]) * (1.2f * rnd() - 0.1f);
            r->org_y = lo[1] + (hi[1] - lo[1]) * (1.2f * rnd() - 0.1f);
            r->org_z = lo[2] + (hi[2] - lo[2]) * (1.2f * rnd() - 0.1f);
        }
    }
}

/* Best of `repeat` passes over a ray set; hit flags into hits[]. */
static double trace_rtk(rtk_scene scene, const rayset *s, unsigned char *hits, int repeat)
{
    double best = 1e30;
    for (int rep = 0; rep < repeat; rep++) {
        double t0 = now();
        for (size_t i = 0; i < s->n; i++) {
            if (s->occluded) {
                rtk_ray r = s->rays[i];
                rtk_occluded1(scene, &r);
                hits[i] = r.tfar == -INFINITY;
            } else {
                rtk_rayhit rh = {.ray = s->rays[i], .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
                rtk_intersect1(scene, &rh);
                hits[i] = rh.hit.geomID != RTK_INVALID_GEOMETRY_ID;
            }
        }
        double t = now() - t0;
        best = t < best ? t : best;
    }
    return (double)s->n / best * 1e-6;
}

static double trace_embree(RTCScene scene, const rayset *s, unsigned char *hits, int repeat)
{
    double best = 1e30;
    for (int rep = 0; rep < repeat; rep++) {
        double t0 = now();
        for (size_t i = 0; i < s->n; i++) {
            const rtk_ray *q = &s->rays[i];
            struct RTCIntersectContext ctx;
            rtcInitIntersectContext(&ctx);
            struct RTCRayHit rh __attribute__((aligned(16)));
            rh.ray.org_x = q->org_x, rh.ray.org_y = q->org_y, rh.ray.org_z = q->org_z, rh.ray.tnear = q->tnear;
            rh.ray.dir_x = q->dir_x, rh.ray.dir_y = q->dir_y, rh.ray.dir_z = q->dir_z, rh.ray.time = 0;
            rh.ray.tfar = q->tfar, rh.ray.mask = ~0u, rh.ray.id = 0, rh.ray.flags = 0;
            if (s->occluded) {
                rtcOccluded1(scene, &ctx, &rh.ray);
                hits[i] = rh.ray.tfar == -INFINITY;
            } else {
                rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
                rtcIntersect1(scene, &ctx, &rh);
                hits[i] = rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
            }
        }
        double t = now() - t0;
        best = t < best ? t : best;
    }
    return (double)s->n / best * 1e-6;
}

int main(int argc, char **argv)
{
    const char *path = NULL;
    size_t nrand = 1u << 20;
    int repeat = 3, builds = 1, build_only = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--rays") && i + 1 < argc)
            nrand = strtoul(argv[++i], NULL, 10);
        else if (!strcmp(argv[i], "--repeat") && i + 1 < argc)
            repeat = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--builds") && i + 1 < argc)
            builds = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--build-only"))
            build_only = 1;
        else
            path = argv[i];
    }
    if (!path || repeat < 1 || builds < 1) {
        fprintf(stderr, "usage: bench_vs_embree MESH [--rays N] [--repeat N] [--builds N] [--build-only]\n");
        return 2;
    }
    rtk_mesh m;
    char err[1024];
    if (rtk_mesh_load(path, &m, err, sizeof err)) {
        fprintf(stderr, "%s\n", err);
        return 1;
    }
    rayset sets[3];
    make_rays(&m, sets, nrand);
    printf("%s: %zu triangles; rays: primary %zu, random %zu, shadow %zu; best of %d builds and %d passes, 1 thread\n",
           path, m.triangle_count, sets[0].n, sets[1].n, sets[2].n, builds, repeat);

    /* Embree needs 16 readable bytes at the last vertex: a padded copy. */
    float *ev = calloc(m.vertex_count * 3 + 4, sizeof(float));
    memcpy(ev, m.vertices, m.vertex_count * 3 * sizeof(float));
    unsigned char *ref_hits[3], *hits = malloc(sets[0].n > nrand ? sets[0].n : nrand);
    double ref_rate[3] = {0}, ref_build = 0;

    const char *embree_cfg[2] = {"threads=1,isa=avx2", "threads=1"};
    for (int e = 0; e < 2; e++) {
        RTCDevice dev = rtcNewDevice(embree_cfg[e]);
        if (!dev) {
            fprintf(stderr, "embree: no device for %s\n", embree_cfg[e]);
            return 1;
        }
        RTCScene scene = NULL;
        double build = 1e30;
        for (int k = 0; k < builds; k++) {
            if (scene)
                rtcReleaseScene(scene);
            double t0 = now();
            scene = rtcNewScene(dev);
            rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_MEDIUM);
            RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
            rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, ev, 0, 12, m.vertex_count);
            rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, m.indices, 0, 12,
                                       m.triangle_count);
            rtcCommitGeometry(g);
            rtcAttachGeometry(scene, g);
            rtcReleaseGeometry(g);
            rtcCommitScene(scene);
            double t = now() - t0;
            build = t < build ? t : build;
        }
        printf("embree %-18s build %.3f s %6.2f Mtris/s", embree_cfg[e], build, m.triangle_count / build * 1e-6);
        if (e == 0)
            ref_build = build;
        else
            printf(" (%.2fx)", ref_build / build);
        for (int s = 0; s < 3 && !build_only; s++) {
            double rate = trace_embree(scene, &sets[s], e == 0 ? (ref_hits[s] = malloc(sets[s].n)) : hits, repeat);
            printf("  %s %6.2f Mrays/s", sets[s].name, rate);
            if (e == 0)
                ref_rate[s] = rate;
            else
                printf(" (%.2fx)", rate / ref_rate[s]);
        }
        printf("\n");
        rtcReleaseScene(scene);
        rtcReleaseDevice(dev);
    }

    static const char *isas[] = {"scalar", "sse41", "avx", "avx2"};
    for (int b = 0; b < 4; b++) {
        char cfg[32];
        snprintf(cfg, sizeof cfg, "isa=%s", isas[b]);
        rtk_device dev = NULL;
        if (rtk_device_new(cfg, &dev)) {
            printf("rtk    %-18s unavailable: %s\n", isas[b], rtk_device_get_error_message(NULL));
            continue;
        }
        rtk_scene scene = NULL;
        double build = 1e30;
        for (int k = 0; k < builds; k++) {
            rtk_scene_release(scene);
            double t0 = now();
            rtk_geometry g = NULL;
            rtk_scene_new(dev, &scene);
            rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g);
            rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, m.vertices, 0, 12, m.vertex_count);
            rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, m.indices, 0, 12, m.triangle_count);
            rtk_geometry_commit(g);
            rtk_scene_attach_geometry(scene, g, NULL);
            rtk_geometry_release(g);
            if (rtk_scene_commit(scene)) {
                fprintf(stderr, "rtk: %s\n", rtk_device_get_error_message(dev));
                return 1;
            }
            double t = now() - t0;
            build = t < build ? t : build;
        }
        rtk_scene_info info = {.struct_size = sizeof info};
        rtk_scene_get_info(scene, &info);
        printf("rtk    %-18s build %.3f s %6.2f Mtris/s (%.2fx)", isas[b], build, m.triangle_count / build * 1e-6,
               ref_build / build);
        size_t disagree = 0;
        for (int s = 0; s < 3 && !build_only; s++) {
            double rate = trace_rtk(scene, &sets[s], hits, repeat);
            printf("  %s %6.2f Mrays/s (%.2fx)", sets[s].name, rate, rate / ref_rate[s]);
            for (size_t i = 0; i < sets[s].n; i++)
                disagree += hits[i] != ref_hits[s][i];
        }
        printf("  [%.1f B/tri", info.bytes_per_triangle);
        if (!build_only)
            printf(", hit/miss differs from embree on %zu rays", disagree);
        printf("]\n");
        rtk_scene_release(scene);
        rtk_device_release(dev);
    }
    return 0;
}
