/*
 * bench_vs_embree MESH [--repeat N] [--builds N] [--threads LIST] [--build-only] [--compact] [--isa LIST]
 *
 * Builds MESH once per rtk backend and with Embree 3 (medium quality, at
 * isa=avx2 and at its default), in this one process, and traces the same
 * ray sets through every one of them:
 *   primary    1024x768 camera rays framing the mesh tightly (coherent), intersect1
 *   primary8   the same rays as 4x2-pixel packets, intersect8 (Embree is given
 *              its coherent-rays context flag)
 *   diffuse    one bounce from each primary hit: origin at the hit, direction
 *              cosine-weighted around the geometric normal (facing the
 *              camera), intersect1 (incoherent)
 *   shadow     from each primary hit to a point light above the camera, occluded1
 * with 1 thread and with 2 (the rays split in halves; --threads "1,2").
 * Prints Mtris/s for builds (best of --builds builds, each from the shared
 * buffers to a committed scene, single-threaded) and Mrays/s for traces (best
 * of --repeat passes), each also as a ratio to Embree (isa=avx2), and counts
 * hit/miss disagreements with Embree.  --build-only skips the traces;
 * --compact builds both libraries' scenes with their compact flag;
 * --isa limits the rtk backends run (e.g. "avx2" or "sse41,avx2", for
 * profiling).  Memory
 * is reported per input triangle: rtk's from rtk_scene_info.bytes, Embree's
 * from its memory monitor callback (what the scene commit kept allocated).
 * A benchmark, not a test: run it and read it.
 */
#define _POSIX_C_SOURCE 200809L
#include <embree3/rtcore.h>
#include <pthread.h>
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
    int packet; /* 8: traced as packets of 8 consecutive rays */
} rayset;

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static float rnd(void)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (float)(rng_state >> 40) * 0x1p-24f;
}

enum { W = 1024, H = 768, NSETS = 4 };

/* Primary rays in 4x2 tiles (ray i..i+7 is one tile), framing the mesh's
 * bounding box from the front-right-above, tightly so most pixels hit. */
static void make_primary(const rtk_mesh *m, rayset *set)
{
    float lo[3], hi[3], c[3];
    const float diag = rtk_mesh_bounds(m, lo, hi);
    for (int k = 0; k < 3; k++)
        c[k] = 0.5f * (lo[k] + hi[k]);
    *set = (rayset){"primary", calloc((size_t)W * H, sizeof(rtk_ray)), (size_t)W * H, 0, 0};
    const float eye[3] = {c[0] + 0.35f * diag, c[1] + 0.3f * diag, c[2] + 1.0f * diag};
    size_t i = 0;
    for (int ty = 0; ty < H; ty += 2)
        for (int tx = 0; tx < W; tx += 4)
            for (int p = 0; p < 8; p++) {
                const int x = tx + p % 4, y = ty + p / 4;
                float t[3] = {c[0] + diag * 0.5f * ((x + 0.5f) / W - 0.5f),
                              c[1] - diag * 0.375f * ((y + 0.5f) / H - 0.5f), c[2]};
                set->rays[i++] = (rtk_ray){.org_x = eye[0], .org_y = eye[1], .org_z = eye[2],
                                           .dir_x = t[0] - eye[0], .dir_y = t[1] - eye[1], .dir_z = t[2] - eye[2],
                                           .tfar = INFINITY, .mask = ~0u};
            }
}

/* Diffuse bounces and shadow rays from the primary hits (found with Embree,
 * so every library gets the same rays). */
static void make_secondary(const rtk_mesh *m, RTCScene scene, const rayset *primary, rayset *diffuse,
                           rayset *shadow)
{
    float lo[3], hi[3];
    const float diag = rtk_mesh_bounds(m, lo, hi);
    const float light[3] = {0.5f * (lo[0] + hi[0]) + 0.2f * diag, hi[1] + 1.0f * diag, hi[2] + 0.8f * diag};
    *diffuse = (rayset){"diffuse", calloc(primary->n, sizeof(rtk_ray)), 0, 0, 0};
    *shadow = (rayset){"shadow", calloc(primary->n, sizeof(rtk_ray)), 0, 1, 0};
    for (size_t i = 0; i < primary->n; i++) {
        const rtk_ray *q = &primary->rays[i];
        struct RTCIntersectContext ctx;
        rtcInitIntersectContext(&ctx);
        struct RTCRayHit rh __attribute__((aligned(16)));
        memset(&rh, 0, sizeof rh);
        rh.ray.org_x = q->org_x, rh.ray.org_y = q->org_y, rh.ray.org_z = q->org_z;
        rh.ray.dir_x = q->dir_x, rh.ray.dir_y = q->dir_y, rh.ray.dir_z = q->dir_z;
        rh.ray.tfar = q->tfar, rh.ray.mask = ~0u, rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(scene, &ctx, &rh);
        if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID)
            continue;
        float n[3] = {rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z};
        float len = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (!(len > 0))
            continue;
        if (n[0] * q->dir_x + n[1] * q->dir_y + n[2] * q->dir_z > 0)
            len = -len; /* face the camera */
        for (int k = 0; k < 3; k++)
            n[k] /= len;
        const float eps = 1e-4f * diag;
        float p[3] = {q->org_x + rh.ray.tfar * q->dir_x, q->org_y + rh.ray.tfar * q->dir_y,
                      q->org_z + rh.ray.tfar * q->dir_z};
        for (int k = 0; k < 3; k++)
            p[k] += eps * n[k];
        /* cosine-weighted: a uniform disk point lifted onto the hemisphere */
        float a[3] = {fabsf(n[0]) > 0.9f ? 0.0f : 1.0f, fabsf(n[0]) > 0.9f ? 1.0f : 0.0f, 0.0f}, b[3], t[3];
        t[0] = a[1] * n[2] - a[2] * n[1], t[1] = a[2] * n[0] - a[0] * n[2], t[2] = a[0] * n[1] - a[1] * n[0];
        const float tl = sqrtf(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
        for (int k = 0; k < 3; k++)
            t[k] /= tl;
        b[0] = n[1] * t[2] - n[2] * t[1], b[1] = n[2] * t[0] - n[0] * t[2], b[2] = n[0] * t[1] - n[1] * t[0];
        const float r = sqrtf(rnd()), phi = 6.2831853f * rnd(), x = r * cosf(phi), y = r * sinf(phi),
                    z = sqrtf(fmaxf(0.0f, 1.0f - x * x - y * y));
        diffuse->rays[diffuse->n++] =
            (rtk_ray){.org_x = p[0], .org_y = p[1], .org_z = p[2], .dir_x = x * t[0] + y * b[0] + z * n[0],
                      .dir_y = x * t[1] + y * b[1] + z * n[1], .dir_z = x * t[2] + y * b[2] + z * n[2],
                      .tfar = INFINITY, .mask = ~0u};
        shadow->rays[shadow->n++] =
            (rtk_ray){.org_x = p[0], .org_y = p[1], .org_z = p[2], .dir_x = light[0] - p[0],
                      .dir_y = light[1] - p[1], .dir_z = light[2] - p[2], .tfar = 1.0f, .mask = ~0u};
    }
}

/* ---- tracing, on 1..n threads ---- */
typedef struct job {
    int embree;
    void *scene; /* rtk_scene or RTCScene */
    const rayset *set;
    unsigned char *hits;
    size_t begin, end;
} job;

/* Rays q[0..7] into the packet p, an rtk_rayhit8 or an RTCRayHit8 (whose
 * fields have the same names), no hit yet. */
#define PACKET8_LOAD(p, q, invalid_id)                                                                            \
    for (int k = 0; k < 8; k++) {                                                                                  \
        const rtk_ray *r_ = &(q)[k];                                                                               \
        (p).ray.org_x[k] = r_->org_x, (p).ray.org_y[k] = r_->org_y, (p).ray.org_z[k] = r_->org_z;                   \
        (p).ray.dir_x[k] = r_->dir_x, (p).ray.dir_y[k] = r_->dir_y, (p).ray.dir_z[k] = r_->dir_z;                   \
        (p).ray.tnear[k] = r_->tnear, (p).ray.tfar[k] = r_->tfar, (p).ray.time[k] = 0, (p).ray.mask[k] = ~0u;       \
        (p).ray.id[k] = 0, (p).ray.flags[k] = 0, (p).hit.geomID[k] = (invalid_id);                                  \
    }

static void run_rtk(const job *j)
{
    const rayset *s = j->set;
    rtk_scene scene = j->scene;
    if (s->packet) {
        for (size_t i = j->begin; i < j->end; i += 8) {
            rtk_rayhit8 p;
            PACKET8_LOAD(p, &s->rays[i], RTK_INVALID_GEOMETRY_ID);
            rtk_intersect8(scene, NULL, &p);
            for (int k = 0; k < 8; k++)
                j->hits[i + k] = p.hit.geomID[k] != RTK_INVALID_GEOMETRY_ID;
        }
        return;
    }
    for (size_t i = j->begin; i < j->end; i++) {
        if (s->occluded) {
            rtk_ray r = s->rays[i];
            rtk_occluded1(scene, &r);
            j->hits[i] = r.tfar == -INFINITY;
        } else {
            rtk_rayhit rh = {.ray = s->rays[i], .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
            rtk_intersect1(scene, &rh);
            j->hits[i] = rh.hit.geomID != RTK_INVALID_GEOMETRY_ID;
        }
    }
}

static void run_embree(const job *j)
{
    const rayset *s = j->set;
    RTCScene scene = j->scene;
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    if (s->packet) {
        ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
        const int valid[8] = {-1, -1, -1, -1, -1, -1, -1, -1};
        for (size_t i = j->begin; i < j->end; i += 8) {
            struct RTCRayHit8 p __attribute__((aligned(32)));
            PACKET8_LOAD(p, &s->rays[i], RTC_INVALID_GEOMETRY_ID);
            rtcIntersect8(valid, scene, &ctx, &p);
            for (int k = 0; k < 8; k++)
                j->hits[i + k] = p.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID;
        }
        return;
    }
    for (size_t i = j->begin; i < j->end; i++) {
        const rtk_ray *q = &s->rays[i];
        struct RTCRayHit rh __attribute__((aligned(16)));
        rh.ray.org_x = q->org_x, rh.ray.org_y = q->org_y, rh.ray.org_z = q->org_z, rh.ray.tnear = q->tnear;
        rh.ray.dir_x = q->dir_x, rh.ray.dir_y = q->dir_y, rh.ray.dir_z = q->dir_z, rh.ray.time = 0;
        rh.ray.tfar = q->tfar, rh.ray.mask = ~0u, rh.ray.id = 0, rh.ray.flags = 0;
        if (s->occluded) {
            rtcOccluded1(scene, &ctx, &rh.ray);
            j->hits[i] = rh.ray.tfar == -INFINITY;
        } else {
            rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
            rtcIntersect1(scene, &ctx, &rh);
            j->hits[i] = rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
        }
    }
}

static void *thread_main(void *arg)
{
    const job *j = arg;
    if (j->embree)
        run_embree(j);
    else
        run_rtk(j);
    return NULL;
}

/* Best of `repeat` passes over a ray set on `threads` threads (contiguous
 * shares, multiples of 8 rays); Mrays/s. */
static double trace(int embree, void *scene, const rayset *s, unsigned char *hits, int repeat, int threads)
{
    double best = 1e30;
    for (int rep = 0; rep < repeat; rep++) {
        job jobs[16];
        pthread_t tid[16];
        const size_t share = (s->n / 8 + (size_t)threads - 1) / (size_t)threads * 8;
        double t0 = now();
        for (int t = 0; t < threads; t++) {
            size_t b = (size_t)t * share, e = b + share;
            jobs[t] = (job){embree, scene, s, hits, b < s->n ? b : s->n, e < s->n ? e : s->n};
            if (t)
                pthread_create(&tid[t], NULL, thread_main, &jobs[t]);
        }
        thread_main(&jobs[0]);
        for (int t = 1; t < threads; t++)
            pthread_join(tid[t], NULL);
        double el = now() - t0;
        best = el < best ? el : best;
    }
    return (double)s->n / best * 1e-6;
}

static int compact; /* --compact: RTC_SCENE_FLAG_COMPACT / RTK_SCENE_FLAG_COMPACT */

/* Embree's memory, as its monitor callback reports it (allocations minus
 * frees), to compare bytes per triangle. */
static long long embree_bytes;
static bool embree_monitor(void *user, ssize_t bytes, bool post)
{
    (void)user;
    (void)post;
    __atomic_add_fetch(&embree_bytes, (long long)bytes, __ATOMIC_RELAXED);
    return true;
}

static RTCScene embree_scene(RTCDevice dev, const rtk_mesh *m, const float *ev)
{
    RTCScene scene = rtcNewScene(dev);
    if (compact)
        rtcSetSceneFlags(scene, RTC_SCENE_FLAG_COMPACT);
    rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_MEDIUM);
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, ev, 0, 12, m->vertex_count);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, m->indices, 0, 12, m->triangle_count);
    rtcCommitGeometry(g);
    rtcAttachGeometry(scene, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(scene);
    return scene;
}

static rtk_scene rtk_build_scene(rtk_device dev, const rtk_mesh *m)
{
    rtk_scene scene = NULL;
    rtk_geometry g = NULL;
    rtk_scene_new(dev, &scene);
    rtk_scene_set_flags(scene, compact ? RTK_SCENE_FLAG_COMPACT : RTK_SCENE_FLAG_NONE);
    rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g);
    rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, m->vertices, 0, 12, m->vertex_count);
    rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, m->indices, 0, 12, m->triangle_count);
    rtk_geometry_commit(g);
    rtk_scene_attach_geometry(scene, g, NULL);
    rtk_geometry_release(g);
    if (rtk_scene_commit(scene)) {
        fprintf(stderr, "rtk: %s\n", rtk_device_get_error_message(dev));
        exit(1);
    }
    return scene;
}

/* 1 when `name` is an item of the comma-separated `list` */
static int list_has(const char *list, const char *name)
{
    const size_t n = strlen(name);
    for (const char *p = list; *p;) {
        const char *end = strchr(p, ',');
        const size_t len = end ? (size_t)(end - p) : strlen(p);
        if (len == n && !strncmp(p, name, n))
            return 1;
        p += len + (end != NULL);
    }
    return 0;
}

int main(int argc, char **argv)
{
    const char *path = NULL;
    int repeat = 3, builds = 1, build_only = 0;
    int threads[4] = {1, 2}, nthreads = 2;
    const char *isa_list = NULL;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--repeat") && i + 1 < argc)
            repeat = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--builds") && i + 1 < argc)
            builds = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--threads") && i + 1 < argc) {
            nthreads = 0;
            for (char *t = strtok(argv[++i], ","); t && nthreads < 4; t = strtok(NULL, ","))
                threads[nthreads++] = atoi(t);
        } else if (!strcmp(argv[i], "--build-only"))
            build_only = 1;
        else if (!strcmp(argv[i], "--compact"))
            compact = 1;
        else if (!strcmp(argv[i], "--isa") && i + 1 < argc)
            isa_list = argv[++i];
        else
            path = argv[i];
    }
    int bad = !path || repeat < 1 || builds < 1 || nthreads < 1;
    for (int t = 0; t < nthreads; t++)
        bad |= threads[t] < 1 || threads[t] > 16;
    if (bad) {
        fprintf(stderr,
                "usage: bench_vs_embree MESH [--repeat N] [--builds N] [--threads 1,2] [--build-only] [--compact]\n"
                "       [--isa scalar,sse41,avx,avx2]\n");
        return 2;
    }
    rtk_mesh m;
    char err[1024];
    if (rtk_mesh_load(path, &m, err, sizeof err)) {
        fprintf(stderr, "%s\n", err);
        return 1;
    }
    /* Embree needs 16 readable bytes at the last vertex: a padded copy. */
    float *ev = calloc(m.vertex_count * 3 + 4, sizeof(float));
    memcpy(ev, m.vertices, m.vertex_count * 3 * sizeof(float));

    rayset sets[NSETS];
    make_primary(&m, &sets[0]);
    sets[1] = sets[0];
    sets[1].name = "primary8";
    sets[1].packet = 8;
    {
        RTCDevice dev = rtcNewDevice("threads=1");
        RTCScene scene = embree_scene(dev, &m, ev);
        make_secondary(&m, scene, &sets[0], &sets[2], &sets[3]);
        rtcReleaseScene(scene);
        rtcReleaseDevice(dev);
    }
    printf("%s: %zu triangles; rays: primary %zu (%.1f%% hit), diffuse %zu, shadow %zu; best of %d builds (1 thread) "
           "and %d passes\n",
           path, m.triangle_count, sets[0].n, 100.0 * (double)sets[2].n / (double)sets[0].n, sets[2].n, sets[3].n,
           builds, repeat);
    printf("primary8: packets of 8 (4x2 pixels) through rtk_intersect8 / rtcIntersect8 with "
           "RTC_INTERSECT_CONTEXT_FLAG_COHERENT\n");
    printf("scenes: %s; B/tri counts the BVH and leaves (not the application's buffers) per input triangle\n",
           compact ? "compact (RTC_SCENE_FLAG_COMPACT, RTK_SCENE_FLAG_COMPACT)" : "default flags");

    unsigned char *ref_hits[NSETS], *hits = malloc(sets[0].n);
    double ref_rate[4][NSETS] = {{0}}, ref_build = 0;
    const char *embree_cfg[2] = {"isa=avx2", ""};
    char line[4][1024];

    for (int e = 0; e < 2; e++) {
        char cfg[64];
        snprintf(cfg, sizeof cfg, "threads=%d%s%s", threads[nthreads - 1] > 1 ? threads[nthreads - 1] : 1,
                 *embree_cfg[e] ? "," : "", embree_cfg[e]);
        RTCDevice dev = rtcNewDevice(cfg);
        if (!dev) {
            fprintf(stderr, "embree: no device for %s\n", cfg);
            return 1;
        }
        RTCDevice dev1 = rtcNewDevice(*embree_cfg[e] ? "threads=1,isa=avx2" : "threads=1");
        double build = 1e30;
        for (int k = 0; k < builds; k++) {
            double t0 = now();
            RTCScene sc = embree_scene(dev1, &m, ev);
            double t = now() - t0;
            build = t < build ? t : build;
            rtcReleaseScene(sc);
        }
        rtcReleaseDevice(dev1);
        rtcSetDeviceMemoryMonitorFunction(dev, embree_monitor, NULL);
        const long long bytes0 = embree_bytes;
        RTCScene scene = embree_scene(dev, &m, ev);
        const long long bytes = embree_bytes - bytes0;
        const char *name = e ? "embree default" : "embree isa=avx2";
        printf("%-16s build %6.2f Mtris/s  [%.1f B/tri, its memory monitor]", name, m.triangle_count / build * 1e-6,
               (double)bytes / (double)m.triangle_count);
        if (e == 0)
            ref_build = build;
        else
            printf(" (%.2fx)", ref_build / build);
        printf("\n");
        for (int t = 0; t < nthreads && !build_only; t++) {
            int n = snprintf(line[t], sizeof line[t], "  %d thread%s", threads[t], threads[t] > 1 ? "s" : " ");
            for (int s = 0; s < NSETS; s++) {
                unsigned char *h = e == 0 && t == 0 ? (ref_hits[s] = malloc(sets[s].n)) : hits;
                double rate = trace(1, scene, &sets[s], h, repeat, threads[t]);
                n += snprintf(line[t] + n, sizeof line[t] - (size_t)n, "  %s %6.2f", sets[s].name, rate);
                if (e == 0)
                    ref_rate[t][s] = rate;
                else
                    n += snprintf(line[t] + n, sizeof line[t] - (size_t)n, " (%.2fx)", rate / ref_rate[t][s]);
            }
            printf("%s Mrays/s\n", line[t]);
        }
        rtcReleaseScene(scene);
        rtcReleaseDevice(dev);
    }

    static const char *isas[] = {"scalar", "sse41", "avx", "avx2"};
    for (int b = 0; b < 4; b++) {
        if (isa_list && !list_has(isa_list, isas[b]))
            continue;
        char cfg[32];
        snprintf(cfg, sizeof cfg, "isa=%s", isas[b]);
        rtk_device dev = NULL;
        if (rtk_device_new(cfg, &dev)) {
            printf("rtk %-12s unavailable: %s\n", isas[b], rtk_device_get_error_message(NULL));
            continue;
        }
        rtk_scene scene = NULL;
        double build = 1e30;
        for (int k = 0; k < builds; k++) {
            rtk_scene_release(scene);
            double t0 = now();
            scene = rtk_build_scene(dev, &m);
            double t = now() - t0;
            build = t < build ? t : build;
        }
        rtk_scene_info info = {.struct_size = sizeof info};
        rtk_scene_get_info(scene, &info);
        printf("rtk %-12s build %6.2f Mtris/s (%.2fx)  [%s, %.1f B/tri, packets of 8 as %u; %llu nodes, "
               "%llu leaves, depth %u, SAH %.1f]\n",
               isas[b], m.triangle_count / build * 1e-6, ref_build / build, info.layout,
               (double)info.bytes / (double)m.triangle_count,
               info.packet_width[1], (unsigned long long)info.nodes, (unsigned long long)info.leaves, info.depth,
               info.sah_cost);
        size_t disagree = 0;
        for (int t = 0; t < nthreads && !build_only; t++) {
            int n = snprintf(line[t], sizeof line[t], "  %d thread%s", threads[t], threads[t] > 1 ? "s" : " ");
            for (int s = 0; s < NSETS; s++) {
                double rate = trace(0, scene, &sets[s], hits, repeat, threads[t]);
                n += snprintf(line[t] + n, sizeof line[t] - (size_t)n, "  %s %6.2f (%.2fx)", sets[s].name, rate,
                              rate / ref_rate[t][s]);
                for (size_t i = 0; i < sets[s].n; i++)
                    disagree += hits[i] != ref_hits[s][i];
            }
            printf("%s Mrays/s\n", line[t]);
        }
        if (!build_only)
            printf("  hit/miss differs from embree on %zu rays (all passes)\n", disagree);
        rtk_scene_release(scene);
        rtk_device_release(dev);
    }
    return 0;
}
