/*
 * rtktool bench: rtk beside Embree 3 on the same meshes and the same rays,
 * in one process run.  Compiled into rtktool only when Embree's development
 * package is present (RTK_HAVE_EMBREE).
 *
 * For each mesh:
 *   trace     primary rays (a camera framing the mesh tightly, so most hit),
 *             one cosine-weighted diffuse bounce and one shadow ray per
 *             primary hit; single rays and packets of 4, 8, 16; 1 and 2
 *             threads; Embree at isa=avx2 and at its default, every rtk
 *             backend.  Ratios are to Embree isa=avx2 on the same rays.
 *   render    the paper's Table 2/3: rays per second of the complete
 *             diffuse path tracer of rtktool trace (shading and sampling
 *             included), the same renderer code driving each library.
 *   build     the paper's Table 4: start time, from the first scene call
 *             to a committed scene (API calls, allocation, build), at
 *             every build quality, with what the tree then costs to trace.
 *   refit     a deforming mesh (quality REFIT): the time to refit after
 *             the vertices move, and the trace speed of the refitted tree
 *             beside a tree built afresh over the same shape.
 *   twolevel  instances of the mesh and a dynamic scene of its pieces:
 *             commit times and the path tracer's speed through them.
 *   motion    linear motion blur (the mesh turning and moving, at 2 and 5
 *             time steps): start time, memory, and rays at random times.
 *   accuracy  rays aimed at points on edges shared by two triangles, from
 *             the side both face: in exact arithmetic each hits one of the
 *             two (or something nearer), so a miss, or a hit beyond the
 *             edge, is a ray that leaked through the mesh.  Per
 *             intersector and mode, beside its speed.
 * Output: tables on stdout, DIR/bench.csv, and charts DIR/MESH-SECTION.png
 * drawn by gnuplot (the scripts are kept beside them).
 */
#include "bench.h"

#include <embree3/rtcore.h>
#include <errno.h>
#include <malloc.h>
#include <math.h>
#include <pthread.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "closed_mesh.h"
#include "mesh_import.h"
#include "mesh_tools.h"
#include "progress.h"
#include "render.h"
#include "rtk/rtk.h"

/* rtk's rays and hits have Embree's layout, so the renderer's tables can
 * hand them over as they are. */
_Static_assert(sizeof(rtk_rayhit) == sizeof(struct RTCRayHit), "RTCRayHit layout");
_Static_assert(offsetof(rtk_rayhit, hit) == offsetof(struct RTCRayHit, hit), "RTCRayHit layout");
_Static_assert(offsetof(rtk_ray, tfar) == offsetof(struct RTCRay, tfar), "RTCRay layout");
_Static_assert(offsetof(rtk_ray, flags) == offsetof(struct RTCRay, flags), "RTCRay layout");
_Static_assert(offsetof(rtk_hit, geomID) == offsetof(struct RTCHit, geomID), "RTCHit layout");
_Static_assert(sizeof(rtk_rayhit4) == sizeof(struct RTCRayHit4), "RTCRayHit4 layout");
_Static_assert(sizeof(rtk_rayhit8) == sizeof(struct RTCRayHit8), "RTCRayHit8 layout");
_Static_assert(sizeof(rtk_rayhit16) == sizeof(struct RTCRayHit16), "RTCRayHit16 layout");
_Static_assert(offsetof(rtk_rayhit16, hit) == offsetof(struct RTCRayHit16, hit), "RTCRayHit16 layout");
_Static_assert(sizeof(rtk_ray8) == sizeof(struct RTCRay8), "RTCRay8 layout");

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ---- Embree as a render_tracer ---- */

typedef struct embree_target {
    RTCScene scene;
    enum RTCIntersectContextFlags flags; /* coherent for camera-ray packets */
} embree_target;

static void e_i1(void *s, rtk_rayhit *rh)
{
    const embree_target *e = s;
    struct RTCIntersectContext c;
    rtcInitIntersectContext(&c);
    c.flags = e->flags;
    rtcIntersect1(e->scene, &c, (struct RTCRayHit *)rh);
}
static void e_o1(void *s, rtk_ray *r)
{
    const embree_target *e = s;
    struct RTCIntersectContext c;
    rtcInitIntersectContext(&c);
    c.flags = e->flags;
    rtcOccluded1(e->scene, &c, (struct RTCRay *)r);
}
#define EMBREE_PACKET_(N)                                                                                              \
    static void e_i##N(void *s, const int *valid, rtk_rayhit##N *rh)                                                   \
    {                                                                                                                  \
        const embree_target *e = s;                                                                                    \
        struct RTCIntersectContext c;                                                                                  \
        rtcInitIntersectContext(&c);                                                                                   \
        c.flags = e->flags;                                                                                            \
        rtcIntersect##N(valid, e->scene, &c, (struct RTCRayHit##N *)rh);                                               \
    }                                                                                                                  \
    static void e_o##N(void *s, const int *valid, rtk_ray##N *r)                                                       \
    {                                                                                                                  \
        const embree_target *e = s;                                                                                    \
        struct RTCIntersectContext c;                                                                                  \
        rtcInitIntersectContext(&c);                                                                                   \
        c.flags = e->flags;                                                                                            \
        rtcOccluded##N(valid, e->scene, &c, (struct RTCRay##N *)r);                                                    \
    }
EMBREE_PACKET_(4)
EMBREE_PACKET_(8)
EMBREE_PACKET_(16)

static render_tracer embree_tracer(embree_target *e)
{
    return (render_tracer){e, e_i1, e_o1, e_i4, e_o4, e_i8, e_o8, e_i16, e_o16};
}

/* ---- the libraries under test ---- */

/* MODE_REFIT: a geometry that deforms (quality REFIT): rtk's scene at the
 * given quality, Embree's at low quality and flagged dynamic, the two-level
 * mode in which alone Embree refits. */
enum { MODE_DEFAULT, MODE_COMPACT, MODE_ROBUST, MODE_REFIT, MODE_MASK, MODE_FILTER, MODE_QUAD, MODE_MASKS2, MODE_REBUILD };
/* MODE_REBUILD: a scene built again every frame: Embree's flagged dynamic
 * (its documented setting for that: better build performance), rtk's the
 * default (one tree, built again in its old memory). */
/* MODE_MASK: the geometry's mask set to 1 (the rays' is all ones, so every
 * hit passes); MODE_MASKS2: the mesh as two geometries, its first half of
 * triangles with mask 1 and the rest with mask 2 (the rays pass both, but
 * no bit is in every geometry's mask, so rtk tests each candidate's);
 * MODE_FILTER: intersection and occlusion filters that accept every
 * candidate.  The same hits as the default, so what they cost. */
static const char *const mode_names[] = {"default", "compact", "robust", "refit",  "mask",
                                         "filter",  "quad",    "masks2", "rebuild"};

/* MODE_QUAD: the mesh's triangles as quads, each paired with a neighbour
 * across an edge where one is free (the shared edge the diagonal), the
 * rest as quads with v3 == v2 (Embree's way of giving a triangle as a
 * quad): the same triangles, as quad geometry. */
typedef struct quad_list {
    uint32_t *q; /* 4 per quad */
    size_t n;
    size_t paired; /* quads made of two triangles */
} quad_list;

static quad_list bench_quads; /* of the mesh section_features measures */

static void e_accept(const struct RTCFilterFunctionNArguments *args)
{
    (void)args; /* valid[] left as it is: accepted */
}
static int rtk_accept(const rtk_filter_args *args)
{
    (void)args;
    return 1;
}

/* The accuracy section's double hits: with bench_collect set, scene_build
 * gives the geometry filters that note each candidate's triangle in
 * bench_seen (those up to t = 1 + 1e-4: an edge ray's point is at t = 1)
 * and reject it, so a query collects every triangle the ray meets up to
 * its edge point.  Single rays on one thread only. */
static int bench_collect;
static struct {
    uint32_t prim[64];
    unsigned n;
} bench_seen;

static float bench_t_limit = 1.0f + 1e-4f; /* the closed section: each ray's distance to its point inside */

static void seen_add(uint32_t prim, float t)
{
    if (!(t <= bench_t_limit))
        return;
    for (unsigned k = 0; k < bench_seen.n; k++)
        if (bench_seen.prim[k] == prim)
            return;
    if (bench_seen.n < 64)
        bench_seen.prim[bench_seen.n++] = prim;
}

static void e_collect(const struct RTCFilterFunctionNArguments *args)
{
    /* RTCRayN / RTCHitN: tfar is the ray's field 8, primID the hit's 5 */
    for (unsigned i = 0; i < args->N; i++) {
        if (!args->valid[i])
            continue;
        seen_add(((const uint32_t *)args->hit)[5 * args->N + i], ((const float *)args->ray)[8 * args->N + i]);
        args->valid[i] = 0;
    }
}
static int rtk_collect(const rtk_filter_args *args)
{
    seen_add(args->hit->primID, args->t);
    return 0;
}

typedef struct lib {
    char name[40];   /* "embree isa=avx2", "embree default", "rtk avx2" */
    char config[320]; /* what lib_open was given besides threads: "isa=avx2", "" */
    int embree;
    RTCDevice edev;
    rtk_device rdev;
    double device_seconds; /* creating the device */
} lib;

typedef struct scene {
    lib *lib;
    RTCScene escene;
    rtk_scene rscene;
    embree_target target[2]; /* incoherent, coherent */
    double seconds;          /* start time: first scene call to committed scene */
    double bytes_per_tri;
    double sah; /* rtk: rtk_scene_info.sah_cost; Embree: -1 (its API reports none) */
    char layout[48];
    char builder[32]; /* rtk: rtk_scene_info.builder; Embree: its builder for the quality */
} scene;

static long long embree_bytes; /* Embree's memory monitor: allocations minus frees */
static bool embree_monitor(void *user, ssize_t bytes, bool post)
{
    (void)user;
    (void)post;
    __atomic_add_fetch(&embree_bytes, (long long)bytes, __ATOMIC_RELAXED);
    return true;
}

static int lib_open(lib *l, const char *name, int embree, const char *config, int threads, char *err,
                    size_t err_size)
{
    memset(l, 0, sizeof *l);
    snprintf(l->name, sizeof l->name, "%s", name);
    snprintf(l->config, sizeof l->config, "%s", config);
    l->embree = embree;
    char cfg[400];
    const double t0 = now();
    if (embree) {
        snprintf(cfg, sizeof cfg, "threads=%d%s%s", threads, config[0] ? "," : "", config);
        l->edev = rtcNewDevice(cfg);
        if (!l->edev) {
            snprintf(err, err_size, "embree: no device for '%s'", cfg);
            return 1;
        }
        rtcSetDeviceMemoryMonitorFunction(l->edev, embree_monitor, NULL);
    } else {
        snprintf(cfg, sizeof cfg, "%s,threads=%d", config, threads);
        if (rtk_device_new(cfg, &l->rdev)) {
            snprintf(err, err_size, "rtk %s: %s", config, rtk_device_get_error_message(NULL));
            return 1;
        }
    }
    l->device_seconds = now() - t0;
    return 0;
}

static void lib_close(lib *l)
{
    if (l->edev)
        rtcReleaseDevice(l->edev);
    rtk_device_release(l->rdev);
    memset(l, 0, sizeof *l);
}

/* Commits Embree's scene s into sc, timed from t0 (the first scene call);
 * when the device reports an error, releases it and says `what` failed. */
static int embree_commit(scene *sc, RTCScene s, double t0, const char *what, char *err, size_t err_size)
{
    rtcCommitScene(s);
    sc->seconds = now() - t0;
    if (rtcGetDeviceError(sc->lib->edev) != RTC_ERROR_NONE) {
        rtcReleaseScene(s);
        snprintf(err, err_size, "embree: %s did not commit", what);
        return 1;
    }
    sc->escene = s;
    for (int c = 0; c < 2; c++)
        sc->target[c] = (embree_target){s, c ? RTC_INTERSECT_CONTEXT_FLAG_COHERENT
                                             : RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT};
    return 0;
}

/* The same for rtk's scene s, unless `bad` (an earlier call failed). */
static int rtk_commit(scene *sc, rtk_scene s, int bad, double t0, char *err, size_t err_size)
{
    bad = bad || rtk_scene_commit(s);
    sc->seconds = now() - t0;
    if (bad) {
        snprintf(err, err_size, "rtk: %s", rtk_device_get_error_message(sc->lib->rdev));
        rtk_scene_release(s);
        return 1;
    }
    sc->rscene = s;
    return 0;
}

/* What a one-mesh scene of either library ends with, once g has its
 * vertex buffers: the mesh's indices (quads: bench_quads'), g committed
 * and attached to s, s committed into sc (timed from t0), and the memory
 * it took. */
static int embree_mesh_commit(scene *sc, RTCScene s, RTCGeometry g, const rtk_mesh *m, int quads, double t0,
                              long long bytes0, const char *what, char *err, size_t err_size)
{
    if (quads)
        rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT4, bench_quads.q, 0, 16, bench_quads.n);
    else
        rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, m->indices, 0, 12,
                                   m->triangle_count);
    rtcCommitGeometry(g);
    rtcAttachGeometry(s, g);
    rtcReleaseGeometry(g);
    if (embree_commit(sc, s, t0, what, err, err_size))
        return 1;
    sc->bytes_per_tri = (double)(embree_bytes - bytes0) / (double)m->triangle_count;
    sc->sah = -1.0;
    return 0;
}

/* The same for rtk, unless `bad` (an earlier call failed); also the
 * layout and builder it chose. */
static int rtk_mesh_commit(scene *sc, rtk_scene s, rtk_geometry g, const rtk_mesh *m, int quads, int bad, double t0,
                           char *err, size_t err_size)
{
    bad = bad ||
          (quads ? rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, bench_quads.q, 0, 16, bench_quads.n)
                 : rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, m->indices, 0, 12, m->triangle_count)) ||
          rtk_geometry_commit(g) || rtk_scene_attach_geometry(s, g, NULL);
    rtk_geometry_release(g);
    if (rtk_commit(sc, s, bad, t0, err, err_size))
        return 1;
    rtk_scene_info info = {.struct_size = sizeof info};
    rtk_scene_get_info(s, &info);
    sc->bytes_per_tri = (double)info.bytes / (double)m->triangle_count;
    sc->sah = info.sah_cost;
    snprintf(sc->layout, sizeof sc->layout, "%s", info.layout);
    snprintf(sc->builder, sizeof sc->builder, "%s", info.builder);
    return 0;
}

/* A scene over the mesh, timed from the first call to the commit's end. */
static int scene_build(scene *sc, lib *l, const rtk_mesh *m, const float *padded, int mode, int quality, char *err,
                       size_t err_size)
{
    memset(sc, 0, sizeof *sc);
    sc->lib = l;
    if (l->embree) {
        static const enum RTCBuildQuality q[3] = {RTC_BUILD_QUALITY_LOW, RTC_BUILD_QUALITY_MEDIUM,
                                                  RTC_BUILD_QUALITY_HIGH};
        const long long bytes0 = embree_bytes;
        const double t0 = now();
        RTCScene s = rtcNewScene(l->edev);
        rtcSetSceneFlags(s, mode == MODE_COMPACT ? RTC_SCENE_FLAG_COMPACT
                            : mode == MODE_ROBUST ? RTC_SCENE_FLAG_ROBUST
                            : mode == MODE_REBUILD ? RTC_SCENE_FLAG_DYNAMIC
                                                  : RTC_SCENE_FLAG_NONE);
        rtcSetSceneBuildQuality(s, q[quality]);
        RTCGeometry g = rtcNewGeometry(l->edev, mode == MODE_QUAD ? RTC_GEOMETRY_TYPE_QUAD : RTC_GEOMETRY_TYPE_TRIANGLE);
        rtcSetGeometryBuildQuality(g, q[quality]);
        rtk_mesh half = *m; /* MODE_MASKS2: g's triangles, the first half */
        if (mode == MODE_MASK || mode == MODE_MASKS2)
            rtcSetGeometryMask(g, 1);
        if (mode == MODE_MASKS2) {
            half.triangle_count = m->triangle_count / 2;
            RTCGeometry g2 = rtcNewGeometry(l->edev, RTC_GEOMETRY_TYPE_TRIANGLE);
            rtcSetGeometryBuildQuality(g2, q[quality]);
            rtcSetGeometryMask(g2, 2);
            rtcSetSharedGeometryBuffer(g2, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, padded, 0, 12,
                                       m->vertex_count);
            rtcSetSharedGeometryBuffer(g2, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, m->indices + 3 * half.triangle_count,
                                       0, 12, m->triangle_count - half.triangle_count);
            rtcCommitGeometry(g2);
            rtcAttachGeometry(s, g2);
            rtcReleaseGeometry(g2);
        }
        if (mode == MODE_FILTER) {
            rtcSetGeometryIntersectFilterFunction(g, e_accept);
            rtcSetGeometryOccludedFilterFunction(g, e_accept);
        }
        if (bench_collect)
            rtcSetGeometryIntersectFilterFunction(g, e_collect);
        if (mode == MODE_REFIT) {
            rtcSetSceneFlags(s, RTC_SCENE_FLAG_DYNAMIC);
            rtcSetSceneBuildQuality(s, RTC_BUILD_QUALITY_LOW);
            rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_REFIT);
        }
        rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, padded, 0, 12, m->vertex_count);
        if (embree_mesh_commit(sc, s, g, &half, mode == MODE_QUAD, t0, bytes0, "the scene", err, err_size))
            return 1;
        sc->bytes_per_tri *= (double)half.triangle_count / (double)m->triangle_count;
        snprintf(sc->layout, sizeof sc->layout, "embree %s", mode_names[mode]);
        /* Embree 3 (rtcSetSceneBuildQuality(3)): low builds a two-level
         * structure, each mesh by the Morton builder; medium is its binned
         * SAH builder, high the SAH builder with fast spatial splits. */
        static const char *const builders[3] = {"morton-2level", "sah", "sah-spatial"};
        snprintf(sc->builder, sizeof sc->builder, "%s", mode == MODE_REFIT ? "refit-2level" : builders[quality]);
        return 0;
    }
    static const rtk_build_quality q[3] = {RTK_BUILD_QUALITY_LOW, RTK_BUILD_QUALITY_MEDIUM, RTK_BUILD_QUALITY_HIGH};
    const double t0 = now();
    rtk_scene s = NULL;
    rtk_geometry g = NULL, g2 = NULL;
    rtk_mesh half = *m; /* MODE_MASKS2: g's triangles, the first half */
    if (mode == MODE_MASKS2)
        half.triangle_count = m->triangle_count / 2;
    const int bad =
        rtk_scene_new(l->rdev, &s) ||
        rtk_scene_set_flags(s, mode == MODE_COMPACT ? RTK_SCENE_FLAG_COMPACT
                               : mode == MODE_ROBUST ? RTK_SCENE_FLAG_ROBUST
                                                     : RTK_SCENE_FLAG_NONE) ||
        rtk_scene_set_build_quality(s, q[quality]) ||
        rtk_geometry_new(l->rdev, mode == MODE_QUAD ? RTK_GEOMETRY_TYPE_QUAD : RTK_GEOMETRY_TYPE_TRIANGLE, &g) ||
        rtk_geometry_set_build_quality(g, mode == MODE_REFIT ? RTK_BUILD_QUALITY_REFIT : q[quality]) ||
        rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, m->vertices, 0, 12, m->vertex_count) ||
        ((mode == MODE_MASK || mode == MODE_MASKS2) && rtk_geometry_set_mask(g, 1)) ||
        (mode == MODE_MASKS2 &&
         (rtk_geometry_new(l->rdev, RTK_GEOMETRY_TYPE_TRIANGLE, &g2) ||
          rtk_geometry_set_build_quality(g2, q[quality]) || rtk_geometry_set_mask(g2, 2) ||
          rtk_geometry_set_shared_buffer(g2, RTK_BUFFER_TYPE_VERTEX, m->vertices, 0, 12, m->vertex_count) ||
          rtk_geometry_set_shared_buffer(g2, RTK_BUFFER_TYPE_INDEX, m->indices + 3 * half.triangle_count, 0, 12,
                                         m->triangle_count - half.triangle_count) ||
          rtk_geometry_commit(g2) || rtk_scene_attach_geometry(s, g2, NULL))) ||
        (mode == MODE_FILTER &&
         (rtk_geometry_set_intersect_filter(g, rtk_accept) || rtk_geometry_set_occluded_filter(g, rtk_accept))) ||
        (bench_collect && rtk_geometry_set_intersect_filter(g, rtk_collect));
    rtk_geometry_release(g2);
    if (rtk_mesh_commit(sc, s, g, &half, mode == MODE_QUAD, bad, t0, err, err_size))
        return 1;
    sc->bytes_per_tri *= (double)half.triangle_count / (double)m->triangle_count;
    return 0;
}

static void scene_release(scene *sc)
{
    if (sc->escene)
        rtcReleaseScene(sc->escene);
    rtk_scene_release(sc->rscene);
    memset(sc, 0, sizeof *sc);
}

static render_tracer scene_tracer(scene *sc, int coherent)
{
    return sc->lib->embree ? embree_tracer(&sc->target[coherent]) : render_tracer_rtk(sc->rscene);
}

/* ---- ray sets ---- */

enum { SET_PRIMARY, SET_DIFFUSE, SET_SHADOW, SET_INCOHERENT, SET_SUN, NSETS };
static const char *const set_names[NSETS] = {"primary", "diffuse", "shadow", "incoherent", "sun"};
static const int apis[4] = {1, 4, 8, 16};

typedef struct rayset {
    rtk_ray *rays;
    size_t n; /* a multiple of 16 */
    uint32_t (*pair)[2]; /* edge rays: the two triangles of the ray's edge; else NULL */
} rayset;

static uint64_t xs_state = 0x9e3779b97f4a7c15ull;
static float rnd(void)
{
    xs_state ^= xs_state << 13;
    xs_state ^= xs_state >> 7;
    xs_state ^= xs_state << 17;
    return (float)(xs_state >> 40) * 0x1p-24f;
}

/* Camera rays in 4x4 pixel blocks, ordered so that every 4 consecutive
 * rays are a 2x2 block, every 8 a 4x2 and every 16 a 4x4: packets of any
 * width are compact.  The camera looks at the bounding box's centre from
 * the front-right-above, framing the box's middle so that most rays hit. */
static void make_primary(const rtk_mesh *m, int w, int h, rayset *set)
{
    float lo[3], hi[3], c[3];
    const float diag = rtk_mesh_bounds(m, lo, hi);
    for (int k = 0; k < 3; k++)
        c[k] = 0.5f * (lo[k] + hi[k]);
    set->n = (size_t)w * (size_t)h;
    set->rays = calloc(set->n, sizeof(rtk_ray));
    const float eye[3] = {c[0] + 0.35f * diag, c[1] + 0.3f * diag, c[2] + 1.0f * diag};
    size_t i = 0;
    for (int by = 0; by < h; by += 4)
        for (int bx = 0; bx < w; bx += 4)
            for (int k = 0; k < 16; k++) {
                const int x = bx + (k & 1) + ((k >> 2) & 1) * 2, y = by + ((k >> 1) & 1) + (k >> 3) * 2;
                const float t[3] = {c[0] + diag * 0.5f * ((x + 0.5f) / w - 0.5f),
                                    c[1] - diag * 0.5f * (float)h / (float)w * ((y + 0.5f) / h - 0.5f), c[2]};
                set->rays[i++] = (rtk_ray){.org_x = eye[0], .org_y = eye[1], .org_z = eye[2],
                                           .dir_x = t[0] - eye[0], .dir_y = t[1] - eye[1], .dir_z = t[2] - eye[2],
                                           .tfar = INFINITY, .mask = ~0u};
            }
}

/* From each primary hit (found by `sc`, so every library gets the same
 * rays): a cosine-weighted bounce about the normal facing the camera, and
 * a shadow ray to a point light above and behind the camera.  Each set is
 * cut to a multiple of 16 rays. */
static void make_secondary(const rtk_mesh *m, scene *sc, const rayset *primary, rayset *diffuse, rayset *shadow)
{
    float lo[3], hi[3];
    const float diag = rtk_mesh_bounds(m, lo, hi);
    const float light[3] = {0.5f * (lo[0] + hi[0]) + 0.2f * diag, hi[1] + 1.0f * diag, hi[2] + 0.8f * diag};
    diffuse->rays = calloc(primary->n, sizeof(rtk_ray));
    shadow->rays = calloc(primary->n, sizeof(rtk_ray));
    diffuse->n = shadow->n = 0;
    const render_tracer t = scene_tracer(sc, 0);
    for (size_t i = 0; i < primary->n; i++) {
        const rtk_ray *q = &primary->rays[i];
        _Alignas(16) rtk_rayhit rh = {.ray = *q, .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
        t.intersect1(t.scene, &rh);
        if (rh.hit.geomID == RTK_INVALID_GEOMETRY_ID)
            continue;
        float n[3] = {rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z};
        float len = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (!(len > 0))
            continue;
        if (n[0] * q->dir_x + n[1] * q->dir_y + n[2] * q->dir_z > 0)
            len = -len;
        for (int k = 0; k < 3; k++)
            n[k] /= len;
        const float eps = 1e-4f * diag;
        float p[3] = {q->org_x + rh.ray.tfar * q->dir_x, q->org_y + rh.ray.tfar * q->dir_y,
                      q->org_z + rh.ray.tfar * q->dir_z};
        for (int k = 0; k < 3; k++)
            p[k] += eps * n[k];
        const float u1 = rnd();
        float d[3];
        render_cosine_dir(n, u1, rnd(), d);
        diffuse->rays[diffuse->n++] = (rtk_ray){.org_x = p[0], .org_y = p[1], .org_z = p[2], .dir_x = d[0],
                                                .dir_y = d[1], .dir_z = d[2], .tfar = INFINITY, .mask = ~0u};
        shadow->rays[shadow->n++] =
            (rtk_ray){.org_x = p[0], .org_y = p[1], .org_z = p[2], .dir_x = light[0] - p[0],
                      .dir_y = light[1] - p[1], .dir_z = light[2] - p[2], .tfar = 1.0f, .mask = ~0u};
    }
    diffuse->n &= ~(size_t)15;
    shadow->n &= ~(size_t)15;
}

/* The unit normal of triangle t, in double (zero for no area). */
static void tri_normal(const rtk_mesh *m, uint32_t t, double n[3])
{
    const float *v0 = &m->vertices[3 * m->indices[3 * t]], *v1 = &m->vertices[3 * m->indices[3 * t + 1]],
                *v2 = &m->vertices[3 * m->indices[3 * t + 2]];
    const double e1[3] = {v1[0] - (double)v0[0], v1[1] - (double)v0[1], v1[2] - (double)v0[2]};
    const double e2[3] = {v2[0] - (double)v0[0], v2[1] - (double)v0[1], v2[2] - (double)v0[2]};
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    const double l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (int k = 0; k < 3; k++)
        n[k] = l > 0 ? n[k] / l : 0.0;
}

/* n bounce rays from random points of the whole mesh (a random triangle,
 * a random point on it), cosine-weighted about either side's normal at
 * random: the rays of a path tracer's later bounces, from all over the
 * scene one after the other, where the diffuse set's neighbouring pixels
 * share most of their path through the tree.  Cut to a multiple of 16. */
static void make_incoherent(const rtk_mesh *m, size_t n, rayset *set)
{
    float lo[3], hi[3];
    const float eps = 1e-4f * rtk_mesh_bounds(m, lo, hi);
    set->rays = calloc(n ? n : 1, sizeof(rtk_ray));
    set->n = 0;
    for (size_t tries = 0; set->rays && set->n < n && m->triangle_count && tries < 4 * n; tries++) {
        const size_t t = (size_t)(rnd() * (float)m->triangle_count) % m->triangle_count;
        const uint32_t *ix = m->indices + 3 * t;
        const float *a = m->vertices + 3 * (size_t)ix[0], *b = m->vertices + 3 * (size_t)ix[1],
                    *c = m->vertices + 3 * (size_t)ix[2];
        double unit[3];
        tri_normal(m, (uint32_t)t, unit);
        if (!(unit[0] * unit[0] + unit[1] * unit[1] + unit[2] * unit[2] > 0.5)) /* no area, or not finite */
            continue;
        const double side = rnd() < 0.5f ? -1.0 : 1.0;
        float u = rnd(), v = rnd();
        if (u + v > 1.0f) {
            u = 1.0f - u;
            v = 1.0f - v;
        }
        float nrm[3], d[3], p[3];
        for (int k = 0; k < 3; k++) {
            nrm[k] = (float)(side * unit[k]);
            p[k] = a[k] + u * (b[k] - a[k]) + v * (c[k] - a[k]) + eps * nrm[k];
        }
        const float u1 = rnd();
        render_cosine_dir(nrm, u1, rnd(), d);
        set->rays[set->n++] = (rtk_ray){.org_x = p[0], .org_y = p[1], .org_z = p[2], .dir_x = d[0], .dir_y = d[1],
                                        .dir_z = d[2], .tfar = INFINITY, .mask = ~0u};
    }
    set->n &= ~(size_t)15;
}

/* n shadow rays to the sun (a directional light, as rtktool trace's
 * path tracer has) from random points of the whole mesh, on the side of
 * their triangle that faces it (the other side is in shadow without a
 * ray), one after the other as a path tracer's later bounces ask for
 * them: any-hit queries whose order of visiting children decides their
 * cost, where the point light's set mostly leaves the mesh's top.  Cut
 * to a multiple of 16. */
static void make_sun(const rtk_mesh *m, size_t n, rayset *set)
{
    float lo[3], hi[3];
    const float eps = 1e-4f * rtk_mesh_bounds(m, lo, hi);
    const double len = sqrt(0.3 * 0.3 + 0.8 * 0.8 + 0.5 * 0.5);
    const double sun[3] = {0.3 / len, 0.8 / len, 0.5 / len};
    set->rays = calloc(n ? n : 1, sizeof(rtk_ray));
    set->n = 0;
    for (size_t tries = 0; set->rays && set->n < n && m->triangle_count && tries < 4 * n; tries++) {
        const size_t t = (size_t)(rnd() * (float)m->triangle_count) % m->triangle_count;
        const uint32_t *ix = m->indices + 3 * t;
        const float *a = m->vertices + 3 * (size_t)ix[0], *b = m->vertices + 3 * (size_t)ix[1],
                    *c = m->vertices + 3 * (size_t)ix[2];
        double unit[3];
        tri_normal(m, (uint32_t)t, unit);
        const double facing = unit[0] * sun[0] + unit[1] * sun[1] + unit[2] * sun[2];
        if (!(facing * facing > 1e-6)) /* no area, not finite, or edge-on to the sun */
            continue;
        const double side = facing > 0 ? 1.0 : -1.0;
        float u = rnd(), v = rnd();
        if (u + v > 1.0f) {
            u = 1.0f - u;
            v = 1.0f - v;
        }
        float p[3];
        for (int k = 0; k < 3; k++)
            p[k] = a[k] + u * (b[k] - a[k]) + v * (c[k] - a[k]) + eps * (float)(side * unit[k]);
        set->rays[set->n++] = (rtk_ray){.org_x = p[0], .org_y = p[1], .org_z = p[2], .dir_x = (float)sun[0],
                                        .dir_y = (float)sun[1], .dir_z = (float)sun[2], .tfar = INFINITY, .mask = ~0u};
    }
    set->n &= ~(size_t)15;
}

/* ---- tracing a set on 1..n threads ---- */

typedef struct job {
    render_tracer t;
    const rayset *set;
    int api, occluded;
    unsigned char *hits;
    size_t begin, end;
} job;

static void *run_job(void *arg)
{
    const job *j = arg;
    const int n = j->api;
    static _Alignas(64) const int all[16] = {-1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1};
    _Alignas(16) rtk_rayhit rh[16];
    for (size_t i = j->begin; i < j->end; i += (size_t)n) {
        for (int k = 0; k < n; k++)
            rh[k] = (rtk_rayhit){.ray = j->set->rays[i + (size_t)k],
                                 .hit = {.geomID = RTK_INVALID_GEOMETRY_ID, .instID = RTK_INVALID_GEOMETRY_ID}};
        render_trace(&j->t, n, all, rh, j->occluded);
        for (int k = 0; k < n; k++)
            j->hits[i + (size_t)k] = j->occluded ? rh[k].ray.tfar == -INFINITY
                                                 : rh[k].hit.geomID != RTK_INVALID_GEOMETRY_ID;
    }
    return NULL;
}

/* Seconds of one pass over the set on `threads` threads; hits[i]: ray i hit. */
static double trace_pass(const render_tracer *t, const rayset *set, int api, int occluded, int threads,
                         unsigned char *hits)
{
    job jobs[16];
    pthread_t tid[16];
    const size_t share = (set->n / 16 + (size_t)threads - 1) / (size_t)threads * 16;
    const double t0 = now();
    int started = 1;
    for (int k = 0; k < threads; k++) {
        const size_t b = (size_t)k * share, e = b + share;
        jobs[k] = (job){*t, set, api, occluded, hits, b < set->n ? b : set->n, e < set->n ? e : set->n};
    }
    for (; started < threads; started++)
        if (pthread_create(&tid[started], NULL, run_job, &jobs[started]))
            break;
    run_job(&jobs[0]);
    for (int k = 1; k < started; k++)
        pthread_join(tid[k], NULL);
    for (int k = started; k < threads; k++)
        run_job(&jobs[k]);
    return now() - t0;
}

/* Mrays/s, best of `repeat` passes; hits[i]: ray i hit. */
static double trace_set(const render_tracer *t, const rayset *set, int api, int occluded, int threads, int repeat,
                        unsigned char *hits)
{
    double best = 1e30;
    for (int r = 0; r < repeat; r++) {
        const double el = trace_pass(t, set, api, occluded, threads, hits);
        best = el < best ? el : best;
    }
    return (double)set->n / best * 1e-6;
}

/* ---- edge rays (accuracy) ---- */

typedef struct edge {
    uint32_t a, b; /* vertex indices, a < b */
    uint32_t tri;
} edge;

static int edge_cmp(const void *x, const void *y)
{
    const edge *p = x, *q = y;
    if (p->a != q->a)
        return p->a < q->a ? -1 : 1;
    if (p->b != q->b)
        return p->b < q->b ? -1 : 1;
    return p->tri < q->tri ? -1 : p->tri > q->tri;
}

/* The edges of exactly two triangles (distinct: only those of two distinct
 * vertices), sorted: entries 2k and 2k + 1 of *out are edge k in its two
 * triangles; returns the number of entries.  *out is malloc'd (NULL when
 * out of memory). */
static size_t shared_edges(const rtk_mesh *m, int distinct, edge **out)
{
    const size_t nt = m->triangle_count;
    edge *e = *out = malloc(3 * nt * sizeof *e + 1);
    if (!e)
        return 0;
    for (size_t t = 0; t < nt; t++)
        for (int k = 0; k < 3; k++) {
            const uint32_t a = m->indices[3 * t + (size_t)k], b = m->indices[3 * t + (size_t)(k + 1) % 3];
            e[3 * t + (size_t)k] = (edge){a < b ? a : b, a < b ? b : a, (uint32_t)t};
        }
    qsort(e, 3 * nt, sizeof *e, edge_cmp);
    size_t pairs = 0;
    for (size_t i = 0; i + 1 < 3 * nt; i++) {
        const int starts = i == 0 || e[i - 1].a != e[i].a || e[i - 1].b != e[i].b;
        const int two = e[i + 1].a == e[i].a && e[i + 1].b == e[i].b &&
                        (i + 2 >= 3 * nt || e[i + 2].a != e[i].a || e[i + 2].b != e[i].b);
        if (starts && two && (!distinct || e[i].a != e[i].b))
            e[pairs++] = e[i], e[pairs++] = e[i + 1];
    }
    return pairs;
}

/* The corner k of triangle t whose edge to corner k + 1 joins a and b
 * (either way round), or -1. */
static int edge_corner(const rtk_mesh *m, uint32_t t, uint32_t a, uint32_t b)
{
    for (int k = 0; k < 3; k++) {
        const uint32_t x = m->indices[3 * t + k], y = m->indices[3 * t + (k + 1) % 3];
        if ((x == a && y == b) || (x == b && y == a))
            return k;
    }
    return -1;
}

static int quads_make(const rtk_mesh *m, quad_list *out)
{
    const size_t nt = m->triangle_count;
    edge *e;
    const size_t pairs = shared_edges(m, 0, &e);
    uint64_t *across = malloc((nt ? 3 * nt : 1) * sizeof *across); /* the edge 3 t + k's other side, or ~0 */
    unsigned char *used = calloc(nt ? nt : 1, 1);
    out->q = malloc((nt ? nt : 1) * 4 * sizeof *out->q);
    out->n = out->paired = 0;
    if (!e || !across || !used || !out->q) {
        free(e), free(across), free(used), free(out->q);
        out->q = NULL;
        return 1;
    }
    for (size_t h = 0; h < 3 * nt; h++)
        across[h] = ~0ull;
    for (size_t i = 0; i < pairs; i += 2) {
        const uint32_t t1 = e[i].tri, t2 = e[i + 1].tri;
        const uint64_t h1 = 3ull * t1 + (uint64_t)edge_corner(m, t1, e[i].a, e[i].b),
                       h2 = 3ull * t2 + (uint64_t)edge_corner(m, t2, e[i].a, e[i].b);
        across[h1] = h2;
        across[h2] = h1;
    }
    for (size_t t = 0; t < nt; t++) {
        if (used[t])
            continue;
        const uint32_t *x = &m->indices[3 * t];
        uint32_t *q = &out->q[4 * out->n++];
        used[t] = 1;
        q[0] = x[0], q[1] = x[1], q[2] = x[2], q[3] = x[2];
        for (int k = 0; k < 3; k++) {
            const uint64_t o = across[3 * t + (size_t)k];
            if (o == ~0ull || used[o / 3])
                continue;
            /* the edge x[k] -> x[k+1] is the other's x[k+1] -> x[k] (if
             * the two face the same way): the quad x[k+2] x[k] y x[k+1] */
            const uint32_t *y = &m->indices[o - o % 3];
            const uint32_t ok = (uint32_t)(o % 3);
            if (y[ok] != x[(k + 1) % 3])
                continue;
            q[0] = x[(k + 2) % 3], q[1] = x[k], q[2] = y[(ok + 2) % 3], q[3] = x[(k + 1) % 3];
            used[o / 3] = 1;
            out->paired++;
            break;
        }
    }
    free(e), free(across), free(used);
    return 0;
}

/* Whether triangle t runs along its edge a -> b (else b -> a). */
static int runs_forward(const rtk_mesh *m, uint32_t t, uint32_t a, uint32_t b)
{
    for (int k = 0; k < 3; k++)
        if (m->indices[3 * t + k] == a && m->indices[3 * t + (k + 1) % 3] == b)
            return 1;
    return 0;
}

/* Up to `want` rays, each aimed at a random point of an edge shared by
 * exactly two triangles of non-zero area, from a distance of a fifth of
 * the mesh's size, in a direction that meets both triangles' planes from
 * their front (cosine at least 0.3 with each normal, taken consistently
 * across the edge).  Each ray's direction is its point minus its origin:
 * the point is at t = 1. */
static size_t make_edge_rays(const rtk_mesh *m, size_t want, rayset *set)
{
    set->rays = NULL;
    set->pair = NULL;
    set->n = 0;
    edge *e;
    const size_t pairs = shared_edges(m, 1, &e);
    if (!e)
        return 0;
    float lo[3], hi[3];
    const float diag = rtk_mesh_bounds(m, lo, hi);
    set->rays = calloc(want ? want : 1, sizeof(rtk_ray));
    set->pair = calloc(want ? want : 1, sizeof *set->pair);
    set->n = 0;
    for (size_t tries = 0; set->rays && set->pair && pairs >= 2 && set->n < want && tries < 20 * want; tries++) {
        const size_t p = (size_t)(rnd() * (float)(pairs / 2)) % (pairs / 2) * 2;
        const uint32_t a = e[p].a, b = e[p].b, t1 = e[p].tri, t2 = e[p + 1].tri;
        double n1[3], n2[3];
        tri_normal(m, t1, n1);
        tri_normal(m, t2, n2);
        /* consistently oriented neighbours run along the edge in opposite
         * directions; otherwise turn the second normal round */
        const double s2 = runs_forward(m, t1, a, b) != runs_forward(m, t2, a, b) ? 1.0 : -1.0;
        double d[3], dl = 0;
        for (int k = 0; k < 3; k++) {
            n2[k] *= s2;
            d[k] = -(n1[k] + n2[k]) + 0.8 * (2.0 * rnd() - 1.0);
            dl += d[k] * d[k];
        }
        dl = sqrt(dl);
        if (!(dl > 0))
            continue;
        double c1 = 0, c2 = 0;
        for (int k = 0; k < 3; k++) {
            d[k] /= dl;
            c1 += d[k] * n1[k];
            c2 += d[k] * n2[k];
        }
        if (!(c1 <= -0.3 && c2 <= -0.3))
            continue;
        const float u = rnd();
        const float *va = &m->vertices[3 * a], *vb = &m->vertices[3 * b];
        float target[3], org[3], dir[3];
        for (int k = 0; k < 3; k++) {
            target[k] = va[k] + u * (vb[k] - va[k]);
            org[k] = target[k] - (float)d[k] * 0.2f * diag;
            dir[k] = target[k] - org[k];
        }
        set->rays[set->n] = (rtk_ray){.org_x = org[0], .org_y = org[1], .org_z = org[2], .dir_x = dir[0],
                                      .dir_y = dir[1], .dir_z = dir[2], .tfar = INFINITY, .mask = ~0u};
        set->pair[set->n][0] = t1;
        set->pair[set->n][1] = t2;
        set->n++;
    }
    free(e);
    set->n &= ~(size_t)15;
    return set->n;
}

/* Rays that leaked: missed, or hit beyond their edge point (t > 1 + 1e-4). */
static size_t count_leaks(const render_tracer *t, const rayset *set)
{
    size_t leaks = 0;
    for (size_t i = 0; i < set->n; i++) {
        _Alignas(16) rtk_rayhit rh = {.ray = set->rays[i], .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
        t->intersect1(t->scene, &rh);
        leaks += rh.hit.geomID == RTK_INVALID_GEOMETRY_ID || rh.ray.tfar > 1.0f + 1e-4f;
    }
    return leaks;
}

/* Rays that hit both triangles of their edge, through a scene built with
 * bench_collect. */
static size_t count_double_hits(const render_tracer *t, const rayset *set)
{
    size_t twice = 0;
    for (size_t i = 0; i < set->n; i++) {
        _Alignas(16) rtk_rayhit rh = {.ray = set->rays[i], .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
        bench_seen.n = 0;
        t->intersect1(t->scene, &rh);
        int both = 0;
        for (unsigned k = 0; k < bench_seen.n; k++)
            both += bench_seen.prim[k] == set->pair[i][0] || bench_seen.prim[k] == set->pair[i][1];
        twice += both == 2;
    }
    return twice;
}

/* ---- output ---- */

typedef struct out {
    FILE *csv;
    const char *mesh;
} out;

static void csv_row(const out *o, const char *section, const char *library, const char *variant, const char *set,
                    const char *api, int threads, double value, const char *unit, double ratio)
{
    fprintf(o->csv, "%s,%s,%s,%s,%s,%s,%d,%.6g,%s,", o->mesh, section, library, variant, set, api, threads, value,
            unit);
    if (ratio > 0)
        fprintf(o->csv, "%.4f", ratio);
    fprintf(o->csv, "\n");
}

static const char *base_name(const char *path)
{
    const char *s = strrchr(path, '/');
    return s ? s + 1 : path;
}

/* The mesh's name without directory and extension, for file names. */
static void mesh_stem(const char *path, char *stem, size_t size)
{
    snprintf(stem, size, "%s", base_name(path));
    char *dot = strrchr(stem, '.');
    if (dot && dot != stem && strncmp(stem, "procedural:", 11))
        *dot = 0;
    for (char *c = stem; *c; c++)
        if (*c == ':' || *c == '.')
            *c = '-';
}

static int have_gnuplot(void)
{
    return system("command -v gnuplot >/dev/null 2>&1") == 0;
}

/* Runs gnuplot on DIR/NAME.gp (written by the caller); 1 on success. */
static int run_gnuplot(const char *dir, const char *name)
{
    char cmd[1200];
    snprintf(cmd, sizeof cmd, "cd '%s' && gnuplot '%s.gp' 2>'%s.gp.log'", dir, name, name);
    return system(cmd) == 0;
}

/* ---- settings ---- */

typedef struct bench_opts {
    const char *outdir;
    int w, h, repeat, builds, edge_rays;
    int threads[4], nthreads;
    char isa[4][16];
    int nisa;
    int api_on[4];
    int set_on[NSETS]; /* --rays: the trace section's ray sets */
    int do_trace, do_render, do_build, do_refit, do_twolevel, do_motion, do_accuracy, do_features, do_closed;
    int render_w, render_h, render_spp;
    int trace_mode; /* MODE_DEFAULT, or MODE_ROBUST with --robust (trace and render) */
    int quick;      /* --quick: the closed section's meshes coarser and fewer grazing rays */
    const char *alt; /* --alt DIR: one more rtk library, the backends of DIR (backend_path=) */
} bench_opts;

static int parse_list(const char *s, char items[][16], int max)
{
    int n = 0;
    for (const char *p = s; *p && n < max;) {
        const char *end = strchr(p, ',');
        const size_t len = end ? (size_t)(end - p) : strlen(p);
        if (!len || len >= 16)
            return -1;
        memcpy(items[n], p, len);
        items[n++][len] = 0;
        p += len + (end != NULL);
    }
    return n;
}

static void bench_usage(FILE *f)
{
    fprintf(f,
            "usage: rtktool bench MESH... [options]\n"
            "  rtk beside Embree 3 (at isa=avx2 and at its default) on the same meshes and rays, in one run:\n"
            "  trace (primary, diffuse, shadow, incoherent and sun rays; single rays and packets; 1 and 2\n"
            "  threads), render (the diffuse path tracer of rtktool trace, as in the Embree paper's Tables 2\n"
            "  and 3), build (start time at every quality, as in its Table 4, against the time to trace the\n"
            "  tree), refit (a deforming mesh: refit time, and the trace speed of the refitted tree), two\n"
            "  levels (instances and a dynamic scene: commit times and trace speed), motion blur (2 and 5\n"
            "  time steps: start time, memory, trace speed at random ray times), accuracy (rays aimed at\n"
            "  shared edges that leak through, beside speed) and, once per run, closed (the accuracy\n"
            "  harness: rays aimed at the vertices and edges of closed procedural meshes moved to\n"
            "  10^0..10^8 and sized 1e-8..1e8, needles and zero-area triangles, grazing rays; false misses,\n"
            "  double hits, t error in ulps, each library's default and robust mode; no MESH needed for\n"
            "  --only closed).\n"
            "  Ratios are to Embree isa=avx2.  A MESH named\n"
            "  procedural:N (e.g. procedural:10M) is a bumpy sphere of about N triangles made on the spot.\n"
            "  -o, --output DIR  bench.csv, the charts (PNG, drawn by gnuplot when installed) and their\n"
            "                    gnuplot scripts (default: bench-out)\n"
            "  --threads LIST    thread counts (default: 1,2)\n"
            "  --isa LIST        rtk backends (default: every usable one)\n"
            "  --api LIST        single,packet4,packet8,packet16 (default: all)\n"
            "  --rays LIST       the trace section's ray sets: primary,diffuse,shadow,incoherent (bounces from\n"
            "                    random points of the whole mesh),sun (shadow rays along one direction from\n"
            "                    random points of the whole mesh) (default: all)\n"
            "  --only LIST       trace,render,build,refit,twolevel,motion,accuracy,features,closed\n"
            "                    (default: all)\n"
            "  --size WxH        camera rays for the trace sets (default: 1024x768)\n"
            "  --repeat N        passes per measurement (default: 3); trace: every pass cut into 8 pieces\n"
            "                    traced by each library in turn, the ratio the median over the pieces\n"
            "  --builds N        best of N builds per start time (default: 3)\n"
            "  --edge-rays N     rays aimed at edges per mesh (default: 200000)\n"
            "  --render WxHxS    path tracer image and samples per pixel (default: 512x384x1)\n"
            "  --alt DIR         one more library, \"rtk ISA alt\": the last --isa (default avx2) loaded from\n"
            "                    the backends in DIR (another build's lib/rtk), to compare two builds\n"
            "  --robust          trace and render with every library's scene in robust mode (watertight)\n"
            "  --quick           a smoke run: 256x192 rays, 1 pass, 1 build, 1 thread, 20000 edge rays,\n"
            "                    128x96x1 render, closed meshes of a quarter of the triangles\n"
            "examples:\n"
            "  rtktool bench ../shared/meshes/dragon.ply ../shared/meshes/sanmiguel_building.ply -o bench-out\n"
            "  rtktool bench dragon.ply --only trace --isa avx2 --api single,packet8 --threads 1\n"
            "  rtktool bench procedural:100k procedural:1M procedural:16M --only build --isa avx2\n"
            "  rtktool bench --only closed --isa avx2,sse41\n");
}

/* ---- the sections ---- */

enum { MAXLIBS = 8 };

typedef struct ctx {
    const bench_opts *o;
    const rtk_mesh *m;
    const float *padded;
    lib libs[MAXLIBS];
    int nlibs;
    out csv;
    char stem[128];
    rayset sets[NSETS]; /* the mesh's ray sets, shared by the sections */
} ctx;

/* The ray sets of a mesh: camera rays, then the secondary rays from the
 * hits Embree isa=avx2 (the first library) finds. */
static int make_sets(ctx *c, char *err, size_t err_size)
{
    rayset *sets = c->sets;
    make_primary(c->m, c->o->w, c->o->h, &sets[SET_PRIMARY]);
    scene ref;
    if (scene_build(&ref, &c->libs[0], c->m, c->padded, MODE_DEFAULT, 1, err, err_size))
        return 1;
    make_secondary(c->m, &ref, &sets[SET_PRIMARY], &sets[SET_DIFFUSE], &sets[SET_SHADOW]);
    scene_release(&ref);
    make_incoherent(c->m, sets[SET_DIFFUSE].n, &sets[SET_INCOHERENT]);
    make_sun(c->m, sets[SET_DIFFUSE].n, &sets[SET_SUN]);
    return 0;
}

static void free_sets(ctx *c)
{
    for (int s = 0; s < NSETS; s++) {
        free(c->sets[s].rays);
        c->sets[s] = (rayset){NULL, 0, NULL};
    }
}

static double ratio(double v, double ref)
{
    return ref > 0 ? v / ref : 0.0;
}

static void print_row_label(const char *label)
{
    printf("  %-20s", label);
}

static void print_cell(double v, double ref, int is_ref)
{
    if (is_ref)
        printf(" %8.2f        ", v);
    else
        printf(" %8.2f (%4.2fx)", v, ratio(v, ref));
}

static void print_header(const ctx *c)
{
    print_row_label("");
    for (int l = 0; l < c->nlibs; l++)
        printf(" %-16s", c->libs[l].name);
    printf("\n");
}

/* The pieces each pass over a ray set is cut into (section_trace). */
enum { TRACE_CHUNKS = 8 };

static int cmp_double(const void *x, const void *y);

/* The order the libraries trace piece `piece` in: a shuffle seeded by the
 * piece's number, so that every library follows every other about equally
 * often (with a rotation each one always came right after the same one,
 * and the caches the previous library leaves count for rays that mostly
 * test the top of the tree, as San Miguel's do). */
static void piece_order(int *order, int n, uint64_t piece)
{
    uint64_t x = piece * 0x9e3779b97f4a7c15ull + 0x2545f4914f6cdd1dull;
    for (int i = 0; i < n; i++)
        order[i] = i;
    for (int i = n - 1; i > 0; i--) {
        x ^= x >> 29;
        x *= 0xbf58476d1ce4e5b9ull;
        x ^= x >> 32;
        const int j = (int)(x % (uint64_t)(i + 1));
        const int t = order[i];
        order[i] = order[j];
        order[j] = t;
    }
}

static int section_trace(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    const rayset *sets = c->sets;
    printf("\ntrace%s: %zu primary rays (%.1f%% hit), %zu diffuse, %zu shadow, %zu incoherent, %zu sun; %d "
           "passes, each cut into %d pieces that every library traces in turn; Mrays/s (best pass), then the\n"
           "  ratio to %s: the median of the %d pieces' time ratios [and their quartiles]\n",
           o->trace_mode == MODE_ROBUST ? " (every library in robust mode)" : "", sets[0].n,
           100.0 * (double)sets[1].n / (double)sets[0].n, sets[1].n, sets[2].n, sets[3].n, sets[4].n, o->repeat,
           TRACE_CHUNKS, c->libs[0].name, o->repeat * TRACE_CHUNKS);
    printf("  packets of primary rays are 2x2, 4x2, 4x4 pixel blocks, given Embree's coherent flag; packets of\n"
           "  diffuse and shadow rays are those of neighbouring pixels, traced without it; incoherent rays bounce\n"
           "  from random points of the whole mesh, one after the other; sun rays are shadow rays to a\n"
           "  directional light from random points of the whole mesh\n");
    unsigned char *lhits[MAXLIBS], *ref_hits[NSETS];
    double rate[MAXLIBS][4][NSETS][4] = {{{{0}}}}; /* lib, threads index, set, api: the best pass */
    double med[MAXLIBS][4][NSETS][4] = {{{{0}}}}, lo[MAXLIBS][4][NSETS][4] = {{{{0}}}},
           hi[MAXLIBS][4][NSETS][4] = {{{{0}}}}; /* the paired ratios' median and quartiles */
    const int npairs = o->repeat * TRACE_CHUNKS;
    double *pairs = malloc(sizeof(double) * (size_t)(npairs * c->nlibs));
    size_t disagree[MAXLIBS] = {0};
    int oom = !pairs;
    for (int l = 0; l < c->nlibs; l++)
        oom |= !(lhits[l] = malloc(sets[0].n ? sets[0].n : 1));
    for (int s = 0; s < NSETS; s++)
        oom |= !(ref_hits[s] = calloc(sets[s].n ? sets[s].n : 1, 1));
    if (oom) {
        free(pairs);
        for (int l = 0; l < c->nlibs; l++)
            free(lhits[l]);
        for (int s = 0; s < NSETS; s++)
            free(ref_hits[s]);
        snprintf(err, err_size, "trace: out of memory for the hit records");
        return 1;
    }
    char plot_data[512];
    snprintf(plot_data, sizeof plot_data, "%s/%s-trace.dat", o->outdir, c->stem);
    FILE *dat = fopen(plot_data, "w");
    progress bar;
    progress_begin(&bar, "rtktool bench: trace");
    const int work = c->nlibs * o->nthreads * NSETS * 4;
    int done = 0, ref_api = 0; /* the reference hits: the first library's first API asked for */
    while (ref_api < 3 && !o->api_on[ref_api])
        ref_api++;
    /* Every library's scene at once.  Each pass over a set is cut into
     * TRACE_CHUNKS pieces, and each piece is traced by every library in
     * turn (in an order shuffled from piece to piece), so that what slows the
     * machine for a while (other guests of a VM) falls on all of them
     * alike: the ratio of two libraries is the median of the pieces' time
     * ratios, with their quartiles; the rate is the best pass. */
    scene sc[MAXLIBS];
    int built = 0;
    for (; built < c->nlibs; built++)
        if (scene_build(&sc[built], &c->libs[built], c->m, c->padded, o->trace_mode, 1, err, err_size))
            break;
    for (int ti = 0; built == c->nlibs && ti < o->nthreads; ti++)
        for (int s = 0; s < NSETS; s++)
            for (int a = 0; a < 4; a++, done += c->nlibs) {
                if (!o->api_on[a] || !o->set_on[s] || !sets[s].n)
                    continue;
                const int occluded = s == SET_SHADOW || s == SET_SUN;
                const size_t blocks = sets[s].n / 16;
                int np = 0;
                for (int r = 0; r < o->repeat; r++) {
                    double pass[MAXLIBS] = {0};
                    for (int k = 0; k < TRACE_CHUNKS; k++) {
                        const size_t b = blocks * (size_t)k / TRACE_CHUNKS * 16,
                                     e = blocks * (size_t)(k + 1) / TRACE_CHUNKS * 16;
                        if (e == b)
                            continue;
                        const rayset part = {sets[s].rays + b, e - b, NULL};
                        double secs[MAXLIBS];
                        int order[MAXLIBS];
                        piece_order(order, c->nlibs, (uint64_t)(r * TRACE_CHUNKS + k));
                        for (int j = 0; j < c->nlibs; j++) {
                            const int l = order[j];
                            const render_tracer t = scene_tracer(&sc[l], s == SET_PRIMARY && a > 0);
                            unsigned char *h = l == 0 && ti == 0 && a == ref_api ? ref_hits[s] : lhits[l];
                            secs[l] = trace_pass(&t, &part, apis[a], occluded, o->threads[ti], h + b);
                            pass[l] += secs[l];
                        }
                        for (int l = 0; l < c->nlibs; l++) {
                            pairs[l * npairs + np] = secs[l] > 0 ? secs[0] / secs[l] : 0.0;
                            if (r == o->repeat - 1 && !(l == 0 && ti == 0 && a == ref_api))
                                for (size_t i = b; i < e; i++)
                                    disagree[l] += lhits[l][i] != ref_hits[s][i];
                        }
                        np++;
                    }
                    for (int l = 0; l < c->nlibs; l++) {
                        const double v = pass[l] > 0 ? (double)sets[s].n / pass[l] * 1e-6 : 0.0;
                        if (v > rate[l][ti][s][a])
                            rate[l][ti][s][a] = v;
                    }
                }
                for (int l = 0; l < c->nlibs; l++) {
                    double *pl = pairs + l * npairs;
                    qsort(pl, (size_t)np, sizeof *pl, cmp_double);
                    med[l][ti][s][a] = np ? 0.5 * (pl[(np - 1) / 2] + pl[np / 2]) : 0.0;
                    lo[l][ti][s][a] = np ? pl[(np - 1) / 4] : 0.0;
                    hi[l][ti][s][a] = np ? pl[np - 1 - (np - 1) / 4] : 0.0;
                }
                progress_update(&bar, (double)(done + c->nlibs) / work);
            }
    progress_end(&bar);
    free(pairs);
    for (int l = 0; l < c->nlibs; l++)
        free(lhits[l]);
    for (int l = 0; l < built; l++)
        scene_release(&sc[l]);
    if (built < c->nlibs) {
        for (int s = 0; s < NSETS; s++)
            free(ref_hits[s]);
        if (dat)
            fclose(dat);
        return 1;
    }
    for (int ti = 0; ti < o->nthreads; ti++) {
        printf("  %d thread%s\n", o->threads[ti], o->threads[ti] > 1 ? "s" : "");
        print_row_label("");
        for (int l = 0; l < c->nlibs; l++)
            printf(" %-30s", c->libs[l].name);
        printf("\n");
        for (int s = 0; s < NSETS; s++)
            for (int a = 0; a < 4; a++) {
                if (!o->api_on[a] || !o->set_on[s])
                    continue;
                char label[48];
                snprintf(label, sizeof label, "%s %s", set_names[s], render_api_name(apis[a]));
                print_row_label(label);
                for (int l = 0; l < c->nlibs; l++) {
                    const double v = rate[l][ti][s][a], m = med[l][ti][s][a];
                    if (l == 0)
                        printf(" %8.2f%22s", v, "");
                    else
                        printf(" %8.2f %5.3fx [%5.3f-%5.3f]", v, m, lo[l][ti][s][a], hi[l][ti][s][a]);
                    csv_row(&c->csv, "trace", c->libs[l].name, mode_names[o->trace_mode], set_names[s],
                            render_api_name(apis[a]), o->threads[ti], v, "Mrays/s", l ? m : 1.0);
                }
                printf("\n");
                if (dat && ti == 0) {
                    fprintf(dat, "\"%s\"", label);
                    for (int l = 0; l < c->nlibs; l++)
                        fprintf(dat, " %.4f", rate[l][ti][s][a]);
                    fprintf(dat, "\n");
                }
            }
    }
    printf("  hit/miss differs from %s on:", c->libs[0].name);
    for (int l = 1; l < c->nlibs; l++)
        printf(" %s %zu%s", c->libs[l].name, disagree[l], l + 1 < c->nlibs ? "," : "");
    printf(" rays (over every pass compared)\n");
    if (dat) {
        fclose(dat);
        char path[600];
        snprintf(path, sizeof path, "%s/%s-trace.gp", o->outdir, c->stem);
        FILE *gp = fopen(path, "w");
        if (gp) {
            fprintf(gp,
                    "set terminal pngcairo noenhanced size 1200,520 font 'sans,10'\nset output '%s-trace.png'\n"
                    "set title '%s: trace rate, %d thread%s (higher is better)'\nset ylabel 'Mrays/s'\n"
                    "set style data histogram\nset style histogram clustered gap 1\nset style fill solid 0.85 border -1\n"
                    "set boxwidth 0.9\nset xtics rotate by -30 scale 0\nset key outside top center horizontal\nset grid ytics\n"
                    "set yrange [0:*]\nplot ",
                    c->stem, base_name(c->csv.mesh), o->threads[0], o->threads[0] > 1 ? "s" : "");
            for (int l = 0; l < c->nlibs; l++)
                fprintf(gp, "%s'%s-trace.dat' using %d:xtic(1) title '%s'", l ? ", " : "", c->stem, l + 2,
                        c->libs[l].name);
            fprintf(gp, "\n");
            fclose(gp);
        }
    }
    for (int s = 0; s < NSETS; s++)
        free(ref_hits[s]);
    return 0;
}

/* A render of the diffuse path tracer per library, API and thread count. */
static int section_render(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    render_settings rs;
    float lo[3], hi[3];
    rtk_mesh_bounds(c->m, lo, hi);
    render_defaults(&rs, lo, hi, o->render_w, o->render_h);
    {
        /* the trace sets' tight framing (make_primary), so most paths hit */
        const float diag = rtk_mesh_bounds(c->m, lo, hi);
        const float ctr[3] = {0.5f * (lo[0] + hi[0]), 0.5f * (lo[1] + hi[1]), 0.5f * (lo[2] + hi[2])};
        const float eye[3] = {ctr[0] + 0.35f * diag, ctr[1] + 0.3f * diag, ctr[2] + 1.0f * diag};
        const float dist = sqrtf(0.35f * 0.35f + 0.3f * 0.3f + 1.0f) * diag;
        const float fov = 2.0f * atanf(0.25f * diag * (float)o->render_h / (float)o->render_w / dist) * 57.29578f;
        render_camera_look(&rs.camera, eye, ctr, (const float[3]){0, 1, 0}, fov, o->render_w, o->render_h, err,
                           err_size);
    }
    rs.mode = RENDER_DIFFUSE;
    rs.spp = o->render_spp;
    float *rgb = malloc((size_t)o->render_w * (size_t)o->render_h * 3 * sizeof *rgb);
    if (!rgb) {
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    printf("\nrender (Tables 2/3 of the Embree paper)%s: rtktool trace's diffuse path tracer, %dx%d, %d spp, up to %d "
           "bounces, shading and sampling included; Mrays/s of all rays traced, best of %d (ratio to %s)\n",
           o->trace_mode == MODE_ROBUST ? " (every library in robust mode)" : "", o->render_w, o->render_h, rs.spp,
           rs.max_bounces, o->repeat, c->libs[0].name);
    double best[MAXLIBS][4][4] = {{{0}}}; /* lib, threads index, api */
    render_stats first = {0};
    for (int l = 0; l < c->nlibs; l++) {
        scene sc;
        if (scene_build(&sc, &c->libs[l], c->m, c->padded, o->trace_mode, 1, err, err_size)) {
            free(rgb);
            return 1;
        }
        const render_tracer t = scene_tracer(&sc, 0);
        for (int ti = 0; ti < o->nthreads; ti++)
            for (int a = 0; a < 4; a++) {
                if (!o->api_on[a])
                    continue;
                rs.api = apis[a];
                rs.threads = o->threads[ti];
                render_stats st;
                for (int r = 0; r < o->repeat; r++) {
                    if (render_image(&t, &rs, rgb, &st, err, err_size)) {
                        scene_release(&sc);
                        free(rgb);
                        return 1;
                    }
                    const double v = (double)render_stats_rays(&st) / st.seconds * 1e-6;
                    best[l][ti][a] = v > best[l][ti][a] ? v : best[l][ti][a];
                }
                if (!first.primary)
                    first = st;
            }
        scene_release(&sc);
    }
    print_header(c);
    for (int ti = 0; ti < o->nthreads; ti++)
        for (int a = 0; a < 4; a++) {
            if (!o->api_on[a])
                continue;
            char label[48];
            snprintf(label, sizeof label, "%s, %d thread%s", render_api_name(apis[a]), o->threads[ti], o->threads[ti] > 1 ? "s" : "");
            print_row_label(label);
            for (int l = 0; l < c->nlibs; l++) {
                const double v = best[l][ti][a], r = best[0][ti][a];
                print_cell(v, r, l == 0);
                csv_row(&c->csv, "render", c->libs[l].name, mode_names[o->trace_mode], "diffuse path tracer",
                        render_api_name(apis[a]),
                        o->threads[ti], v, "Mrays/s", ratio(v, r));
            }
            printf("\n");
        }
    printf("  rays per image: %llu primary (%.1f%% hit), %llu bounce, %llu shadow\n",
           (unsigned long long)first.primary, first.primary ? 100.0 * (double)first.primary_hits / first.primary : 0.0,
           (unsigned long long)first.bounce, (unsigned long long)first.shadow);
    free(rgb);
    return 0;
}

/* ---- peak memory of a build ----
 * The growth of the process's resident memory during one commit: freed
 * heap memory is returned to the system first (malloc_trim), the kernel's
 * high-water mark is reset to the resident size (clear_refs 5), and after
 * the commit the high-water mark is read back.  The same measure for both
 * libraries, whatever they allocate with. */

/* A "VmRSS:"-style field of /proc/self/status in kB, or -1. */
static long status_kb(const char *key)
{
    FILE *f = fopen("/proc/self/status", "r");
    if (!f)
        return -1;
    char line[256];
    long v = -1;
    const size_t n = strlen(key);
    while (fgets(line, sizeof line, f))
        if (!strncmp(line, key, n)) {
            v = atol(line + n);
            break;
        }
    fclose(f);
    return v;
}

/* Starts a measurement: the resident size in kB, or -1 when the kernel
 * offers no resettable high-water mark. */
static long peak_begin(void)
{
    malloc_trim(0);
    FILE *f = fopen("/proc/self/clear_refs", "w");
    if (!f)
        return -1;
    const int ok = fputs("5", f) >= 0;
    if (fclose(f) || !ok)
        return -1;
    return status_kb("VmRSS:");
}

/* Seconds of system time the process has used, all its threads: for a
 * build, mostly the kernel giving it fresh pages (zeroing them, and on a
 * VM whose host backs memory at first touch, waiting for the host). */
static double system_seconds(void)
{
    struct rusage u;
    if (getrusage(RUSAGE_SELF, &u))
        return 0.0;
    return (double)u.ru_stime.tv_sec + (double)u.ru_stime.tv_usec * 1e-6;
}

/* Bytes the resident memory grew by at most since peak_begin, or -1. */
static double peak_end(long base_kb)
{
    const long hwm = status_kb("VmHWM:");
    return base_kb < 0 || hwm < 0 ? -1.0 : (double)(hwm - base_kb) * 1024.0;
}

static void twist(const rtk_mesh *m, float t, float *dst);
static void vertices_commit(scene *sc);

/* A scene over the mesh's moving copy v (refilled from the mesh first) in
 * `mode` at quality q, then `frames` frames of it twisted a little more
 * each and committed again: the best frame's time, from the update calls
 * to the committed scene; -1 (err set) when the scene could not be built. */
static double moving_frames(scene *sc, lib *bl, const ctx *c, float *v, int mode, int q, int frames, char *err,
                            size_t err_size)
{
    rtk_mesh moved = *c->m;
    moved.vertices = v;
    memcpy(v, c->padded, (c->m->vertex_count * 3 + 4) * sizeof *v);
    if (scene_build(sc, bl, &moved, v, mode, q, err, err_size))
        return -1;
    double best = 1e30;
    for (int f = 1; f <= frames; f++) {
        twist(c->m, 0.6f * (float)f / (float)frames, v);
        const double t0 = now();
        vertices_commit(sc);
        const double dt = now() - t0;
        best = dt < best ? dt : best;
    }
    return best;
}

/* The same scene built again in each frame (MODE_REBUILD): the best
 * frame's time; -1 with err on a failure. */
static double rebuild_time(lib *bl, const ctx *c, float *v, int q, int frames, char *err, size_t err_size)
{
    scene sc;
    const double best = moving_frames(&sc, bl, c, v, MODE_REBUILD, q, frames, err, err_size);
    if (best < 0)
        return -1;
    int bad = 0;
    if (sc.rscene) {
        rtk_scene_info info = {.struct_size = sizeof info};
        bad = rtk_scene_get_info(sc.rscene, &info) || info.refits != 0 || info.trees_built != 1;
    } else {
        bad = rtcGetDeviceError(bl->edev) != RTC_ERROR_NONE;
    }
    if (bad)
        snprintf(err, err_size, "%.40s: a frame did not build its tree again", bl->name);
    scene_release(&sc);
    return bad ? -1 : best;
}

/* What the build section measured of one library at one quality and
 * thread count. */
typedef struct build_result {
    double best, bytes, peak, trace_rate, rebuild; /* seconds; bytes and peak per triangle */
    double sys; /* seconds of system time (every thread) during the best start build */
    double sah; /* the tree's SAH cost (scene.sah) */
    char builder[32];
} build_result;

/* Quality q on o->threads[ti] threads, every library on a fresh device:
 * the builds in turns (each round builds every library once, so a machine
 * whose speed drifts over the minutes of the section moves every library's
 * best alike; with each library's builds in a block, Embree's own times
 * moved by a quarter between two runs on one VM), then each library's
 * rebuild frames.  res[l] for library l; 0, or 1 with err set. */
static int build_turns(ctx *c, int q, int ti, float *moving, unsigned char *hits, build_result *res, char *err,
                       size_t err_size)
{
    const bench_opts *o = c->o;
    lib bl[MAXLIBS];
    int opened = 0, rc = 0;
    for (; opened < c->nlibs; opened++)
        if (lib_open(&bl[opened], c->libs[opened].name, c->libs[opened].embree, c->libs[opened].config,
                     o->threads[ti], err, err_size)) {
            rc = 1;
            break;
        }
    for (int l = 0; l < c->nlibs; l++)
        res[l] = (build_result){.best = 1e30, .peak = -1.0, .sah = -1.0};
    for (int b = 0; !rc && b < o->builds; b++)
        for (int l = 0; !rc && l < c->nlibs; l++) {
            scene sc;
            const long base = b == 0 ? peak_begin() : -1;
            const double sys0 = system_seconds();
            if (scene_build(&sc, &bl[l], c->m, c->padded, MODE_DEFAULT, q, err, err_size)) {
                rc = 1;
                break;
            }
            const double sys = system_seconds() - sys0;
            if (b == 0)
                res[l].peak = peak_end(base) / (double)c->m->triangle_count;
            if (sc.seconds < res[l].best) {
                res[l].best = sc.seconds;
                res[l].sys = sys;
            }
            res[l].bytes = sc.bytes_per_tri;
            res[l].sah = sc.sah;
            memcpy(res[l].builder, sc.builder, sizeof res[l].builder);
            if (b == o->builds - 1 && ti == 0) {
                const render_tracer t = scene_tracer(&sc, 0);
                res[l].trace_rate = trace_set(&t, &c->sets[SET_DIFFUSE], 1, 0, 1, o->repeat, hits);
            }
            scene_release(&sc);
        }
    for (int l = 0; !rc && l < c->nlibs; l++) {
        res[l].rebuild = rebuild_time(&bl[l], c, moving, q, o->builds + 1, err, err_size);
        rc = res[l].rebuild < 0;
    }
    for (int l = 0; l < opened; l++)
        lib_close(&bl[l]);
    return rc;
}

/* The results of quality q on o->threads[ti] threads, one per library. */
static build_result *build_row(const ctx *c, build_result *res, int q, int ti)
{
    return &res[((size_t)q * (size_t)c->o->nthreads + (size_t)ti) * (size_t)c->nlibs];
}

static int section_build(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    static const char *const qn[3] = {"low", "medium", "high"};
    const int frames = o->builds + 1;
    printf("\nbuild (Table 4 of the Embree paper): start time from the first scene call to a committed scene (API "
           "calls, allocation, build), best of %d, the libraries' builds in turns, at each quality; rebuild: a "
           "scene built again after its "
           "vertices move (the mesh twisted a little more in each of %d frames; Embree's flagged dynamic), best of "
           "the frames, from the update calls to the committed scene; sys: the system time of the best start build (all "
           "threads; mostly the kernel giving the build fresh pages); scaling: the library's own speed-up over its "
           "%d-thread times, start / rebuild; bytes per triangle of the tree and at the peak of the first build "
           "(the growth of resident memory during it, a fresh device each time); SAH: the tree's SAH cost in rtk's "
           "model (rtk_scene_info.sah_cost: a traversal step 1, a block of four triangles 1, relative to the root; "
           "Embree's API reports none); then the diffuse rays of the trace section through that tree, single rays, "
           "1 thread\n",
           o->builds, frames, o->threads[0]);
    printf("  %-20s %-8s %-14s %7s %9s %8s %7s %10s %8s %13s %9s %7s %7s %7s  %s\n", "library", "quality",
           "builder", "threads", "start ms", "ratio", "sys ms", "rebuild ms", "ratio", "scaling", "Mtris/s", "B/tri",
           "peak", "SAH", "diffuse Mrays/s");
    const rayset diff = c->sets[SET_DIFFUSE];
    unsigned char *hits = malloc(diff.n + 1);
    float *moving = calloc(c->m->vertex_count * 3 + 4, sizeof *moving);
    /* row (q * nthreads + ti) of nlibs results: quality q on threads[ti], a result per library */
    build_result *res = calloc((size_t)3 * (size_t)o->nthreads * (size_t)c->nlibs, sizeof *res);
    if (!hits || !moving || !res) {
        free(hits);
        free(moving);
        free(res);
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    progress bar;
    progress_begin(&bar, "rtktool bench: build");
    for (int q = 0; q < 3; q++)
        for (int ti = 0; ti < o->nthreads; ti++) {
            if (build_turns(c, q, ti, moving, hits, build_row(c, res, q, ti), err, err_size)) {
                progress_end(&bar);
                free(hits);
                free(moving);
                free(res);
                return 1;
            }
            progress_update(&bar, (double)(q * o->nthreads + ti + 1) / (3 * o->nthreads));
        }
    progress_end(&bar);
    char path[600];
    snprintf(path, sizeof path, "%s/%s-build.dat", o->outdir, c->stem);
    FILE *dat = fopen(path, "w");
    for (int l = 0; l < c->nlibs; l++) {
        for (int q = 0; q < 3; q++) {
            for (int ti = 0; ti < o->nthreads; ti++) {
                const build_result *ref = build_row(c, res, q, ti), *r = &ref[l], *first = &build_row(c, res, q, 0)[l];
                const double best = r->best, rebuild = r->rebuild, trace_rate = r->trace_rate;
                char scaling[32] = "-";
                if (ti > 0)
                    snprintf(scaling, sizeof scaling, "%.2fx/%.2fx", ratio(first->best, best),
                             ratio(first->rebuild, rebuild));
                printf("  %-20s %-8s %-14s %7d %9.1f %7.2fx %7.1f %10.1f %7.2fx %13s %9.2f %7.1f %7.1f", c->libs[l].name,
                       qn[q], r->builder, o->threads[ti], best * 1e3, ratio(ref->best, best), r->sys * 1e3,
                       rebuild * 1e3, ratio(ref->rebuild, rebuild), scaling,
                       (double)c->m->triangle_count / best * 1e-6, r->bytes, r->peak);
                if (r->sah >= 0)
                    printf(" %7.3f", r->sah);
                else
                    printf(" %7s", "-");
                if (ti == 0)
                    printf("  %.2f", trace_rate);
                printf("\n");
                char variant[48]; /* quality:builder */
                snprintf(variant, sizeof variant, "%s:%s", qn[q], r->builder);
                csv_row(&c->csv, "build", c->libs[l].name, variant, "start", "", o->threads[ti], best * 1e3, "ms",
                        ratio(ref->best, best));
                csv_row(&c->csv, "build", c->libs[l].name, variant, "rebuild", "", o->threads[ti], rebuild * 1e3,
                        "ms", ratio(ref->rebuild, rebuild));
                csv_row(&c->csv, "build", c->libs[l].name, variant, "start system time", "", o->threads[ti],
                        r->sys * 1e3, "ms", 0);
                if (ti > 0) {
                    csv_row(&c->csv, "build", c->libs[l].name, variant, "start scaling", "", o->threads[ti],
                            ratio(first->best, best), "x", 0);
                    csv_row(&c->csv, "build", c->libs[l].name, variant, "rebuild scaling", "", o->threads[ti],
                            ratio(first->rebuild, rebuild), "x", 0);
                }
                if (r->peak >= 0)
                    csv_row(&c->csv, "build", c->libs[l].name, variant, "peak memory", "", o->threads[ti], r->peak,
                            "bytes per triangle", 0);
                if (r->sah >= 0)
                    csv_row(&c->csv, "build", c->libs[l].name, variant, "sah cost", "", o->threads[ti], r->sah,
                            "relative to the root", 0);
                if (ti == 0) {
                    csv_row(&c->csv, "build", c->libs[l].name, variant, "diffuse", "single", 1, trace_rate, "Mrays/s",
                            0);
                    if (dat)
                        fprintf(dat, "%.3f %.4f %s%s", best * 1e3,
                                trace_rate > 0 ? (double)diff.n / trace_rate * 1e-3 : 0.0, variant,
                                q == 2 ? "\n\n\n" : "\n");
                }
            }
        }
    }
    free(res);
    if (dat) {
        fclose(dat);
        snprintf(path, sizeof path, "%s/%s-build.gp", o->outdir, c->stem);
        FILE *gp = fopen(path, "w");
        if (gp) {
            fprintf(gp,
                    "set terminal pngcairo noenhanced size 900,600 font 'sans,10'\nset output '%s-build.png'\n"
                    "set title '%s: start time against the time to trace %zu diffuse rays, per builder, 1 thread'\n"
                    "set xlabel 'start time, ms (lower is better)'\nset ylabel 'trace time, ms (lower is better)'\n"
                    "set grid\nset key outside right\nset offsets graph 0.05, graph 0.1, graph 0.1, graph 0.1\n"
                    "set xrange [0:*]\nset yrange [0:*]\nplot ",
                    c->stem, base_name(c->csv.mesh), diff.n);
            for (int l = 0; l < c->nlibs; l++) {
                fprintf(gp, "%s'%s-build.dat' index %d using 1:2 with linespoints pt 7 ps 1.2 lw 1.5 lc %d title '%s'",
                        l ? ", " : "", c->stem, l, l + 1, c->libs[l].name);
                if (!c->libs[l].embree || l == 0) /* Embree's other ISA has the same builders */
                    fprintf(gp, ", '' index %d using 1:2:3 with labels offset 0.8,0.5 left font 'sans,7' tc lt -1 "
                            "notitle", l);
            }
            fprintf(gp, "\n");
            fclose(gp);
        }
    }
    free(hits);
    free(moving);
    return 0;
}

/* The mesh twisted about its vertical (y) axis, by up to t radians at the
 * top: the smooth motion of an animation.  dst has the mesh's layout. */
static void twist(const rtk_mesh *m, float t, float *dst)
{
    float lo[3], hi[3];
    rtk_mesh_bounds(m, lo, hi);
    const float cx = 0.5f * (lo[0] + hi[0]), cz = 0.5f * (lo[2] + hi[2]), height = hi[1] - lo[1];
    for (size_t i = 0; i < m->vertex_count; i++) {
        const float *p = m->vertices + 3 * i;
        const float a = height > 0 ? t * (p[1] - lo[1]) / height : 0.0f, dx = p[0] - cx, dz = p[2] - cz;
        dst[3 * i] = cx + cosf(a) * dx - sinf(a) * dz;
        dst[3 * i + 1] = p[1];
        dst[3 * i + 2] = cz + sinf(a) * dx + cosf(a) * dz;
    }
}

/* The vertices changed in place: the calls that tell the library, and the
 * commit (a refit for a REFIT geometry, else a build). */
static void vertices_commit(scene *sc)
{
    if (sc->escene) {
        RTCGeometry g = rtcGetGeometry(sc->escene, 0);
        rtcUpdateGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0);
        rtcCommitGeometry(g);
        rtcCommitScene(sc->escene);
        return;
    }
    rtk_geometry g = rtk_scene_get_geometry(sc->rscene, 0);
    rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_VERTEX);
    rtk_geometry_commit(g);
    rtk_scene_commit(sc->rscene);
}

/* Deforming geometry: the mesh built once with quality REFIT, then twisted
 * a little more each frame and refitted (the time from the update calls to
 * the committed scene, best of the frames); then the diffuse rays through
 * the refitted tree, and through a tree built afresh over the final shape
 * (at medium quality), to show what keeping the tree costs in trace speed. */
static int section_refit(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    const int frames = o->builds + 1;
    printf("\nrefit: the mesh twisted a little more in each of %d frames (up to 0.6 radians at the top) and "
           "refitted; refit time from the update calls to the committed scene, best of the frames; then the diffuse "
           "rays through the refitted tree and through one built afresh over the last frame (medium quality), "
           "single rays, 1 thread\n",
           frames);
    printf("  %-20s %7s %9s %8s %9s  %s\n", "library", "threads", "refit ms", "ratio", "Mtris/s",
           "diffuse Mrays/s refitted / built");
    const size_t floats = c->m->vertex_count * 3 + 4; /* Embree reads 16 bytes at the last vertex */
    float *v = calloc(floats, sizeof *v);
    const rayset diff = c->sets[SET_DIFFUSE];
    unsigned char *hits = malloc(diff.n + 1);
    if (!v || !hits) {
        free(v);
        free(hits);
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    rtk_mesh moved = *c->m;
    moved.vertices = v;
    double ref_ms[4] = {0};
    int rc = 0;
    for (int l = 0; l < c->nlibs && !rc; l++)
        for (int ti = 0; ti < o->nthreads && !rc; ti++) {
            lib bl;
            rc = lib_open(&bl, c->libs[l].name, c->libs[l].embree, c->libs[l].config, o->threads[ti], err, err_size);
            if (rc)
                break;
            scene sc;
            const double best = moving_frames(&sc, &bl, c, v, MODE_REFIT, 1, frames, err, err_size);
            rc = best < 0;
            if (!rc && sc.rscene) {
                rtk_scene_info info = {.struct_size = sizeof info};
                if (rtk_scene_get_info(sc.rscene, &info) || info.refits != (uint32_t)frames) {
                    snprintf(err, err_size, "%s did not refit: %s", bl.name, rtk_device_get_error_message(bl.rdev));
                    rc = 1;
                }
            }
            if (!rc && sc.escene && rtcGetDeviceError(bl.edev) != RTC_ERROR_NONE) {
                snprintf(err, err_size, "%s: a refit commit failed", bl.name);
                rc = 1;
            }
            double refitted = 0, built = 0;
            if (!rc && ti == 0) {
                const render_tracer t = scene_tracer(&sc, 0);
                refitted = trace_set(&t, &diff, 1, 0, 1, o->repeat, hits);
                scene fresh;
                rc = scene_build(&fresh, &bl, &moved, v, MODE_DEFAULT, 1, err, err_size);
                if (!rc) {
                    const render_tracer tf = scene_tracer(&fresh, 0);
                    built = trace_set(&tf, &diff, 1, 0, 1, o->repeat, hits);
                    scene_release(&fresh);
                }
            }
            if (sc.lib)
                scene_release(&sc);
            lib_close(&bl);
            if (rc)
                break;
            if (l == 0)
                ref_ms[ti] = best;
            printf("  %-20s %7d %9.2f %7.2fx %9.2f", c->libs[l].name, o->threads[ti], best * 1e3,
                   ratio(ref_ms[ti], best), (double)c->m->triangle_count / best * 1e-6);
            if (ti == 0)
                printf("  %.2f / %.2f", refitted, built);
            printf("\n");
            csv_row(&c->csv, "refit", c->libs[l].name, "refit", "refit", "", o->threads[ti], best * 1e3, "ms",
                    ratio(ref_ms[ti], best));
            if (ti == 0) {
                csv_row(&c->csv, "refit", c->libs[l].name, "refitted", "diffuse", "single", 1, refitted, "Mrays/s", 0);
                csv_row(&c->csv, "refit", c->libs[l].name, "built", "diffuse", "single", 1, built, "Mrays/s", 0);
            }
        }
    free(v);
    free(hits);
    return rc;
}

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
            RTCGeometry g = rtcNewGeometry(l->edev, RTC_GEOMETRY_TYPE_INSTANCE);
            rtcSetGeometryInstancedScene(g, child->escene);
            rtcSetGeometryTransform(g, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, x);
            rtcCommitGeometry(g);
            rtcAttachGeometry(s, g);
            rtcReleaseGeometry(g);
        }
        return embree_commit(sc, s, t0, "the instances", err, err_size);
    }
    rtk_scene s = NULL;
    int bad = rtk_scene_new(l->rdev, &s) != RTK_OK;
    for (int i = 0; i < GRID * GRID && !bad; i++) {
        const float x[12] = {1, 0, 0, spacing * (float)(i % GRID), 0, 1, 0, 0, 0, 0, 1, -spacing * (float)(i / GRID)};
        rtk_geometry g = NULL;
        bad = rtk_geometry_new(l->rdev, RTK_GEOMETRY_TYPE_INSTANCE, &g) ||
              rtk_geometry_set_instanced_scene(g, child->rscene) ||
              rtk_geometry_set_transform(g, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, x) || rtk_geometry_commit(g) ||
              rtk_scene_attach_geometry(s, g, NULL);
        rtk_geometry_release(g);
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

/* The path tracer's rate through a scene framed by lo/hi, 1 thread. */
static double render_rate(const bench_opts *o, scene *sc, const float lo[3], const float hi[3], float *rgb, char *err,
                          size_t err_size)
{
    render_settings rs;
    render_defaults(&rs, lo, hi, o->render_w, o->render_h);
    rs.mode = RENDER_DIFFUSE;
    rs.spp = o->render_spp;
    rs.threads = 1;
    rs.api = 1;
    const render_tracer t = scene_tracer(sc, 0);
    double best = 0;
    for (int r = 0; r < o->repeat; r++) {
        render_stats st;
        if (render_image(&t, &rs, rgb, &st, err, err_size))
            return -1;
        const double v = (double)render_stats_rays(&st) / st.seconds * 1e-6;
        best = v > best ? v : best;
    }
    return best;
}

static int section_twolevel(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    float lo[3], hi[3];
    const float diag = rtk_mesh_bounds(c->m, lo, hi), spacing = 1.05f * (hi[0] - lo[0] > hi[2] - lo[2] ? hi[0] - lo[0]
                                                                                                    : hi[2] - lo[2]);
    const float glo[3] = {lo[0], lo[1], lo[2] - spacing * (GRID - 1)};
    const float ghi[3] = {hi[0] + spacing * (GRID - 1), hi[1], hi[2]};
    printf("\ntwo levels, 1 thread: %d instances of the mesh on a %dx%d floor (commit of the top level, best of %d; "
           "the path tracer's rate through it, %dx%d, %d spp, Mrays/s); the mesh cut in %d geometries of a dynamic "
           "scene, one of them deforming (REFIT) and moved in each of %d frames (first commit, then the commit of a "
           "frame, best of the frames; the path tracer's rate after the last frame)\n",
           GRID * GRID, GRID, GRID, o->builds, o->render_w, o->render_h, o->render_spp, PIECES, o->builds + 1);
    printf("  %-20s %12s %8s %10s %8s %12s %10s %8s %10s %8s\n", "library", "instances ms", "ratio", "Mrays/s", "ratio",
           "dynamic ms", "frame ms", "ratio", "Mrays/s", "ratio");
    float *rgb = malloc((size_t)o->render_w * (size_t)o->render_h * 3 * sizeof *rgb);
    pieces p;
    if (!rgb || pieces_make(c->m, &p)) {
        free(rgb);
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    float *rest = malloc((p.nv[0] ? p.nv[0] : 1) * 3 * sizeof *rest);
    int rc = !rest;
    if (rest)
        memcpy(rest, p.v[0], p.nv[0] * 3 * sizeof *rest);
    double ref[4] = {0};
    for (int l = 0; l < c->nlibs && !rc; l++) {
        lib *lb = &c->libs[l];
        scene child, grid, dyn;
        double inst_ms = 1e30, frame_ms = 1e30, inst_rate = 0, dyn_rate = 0, dyn_first = 0;
        rc = scene_build(&child, lb, c->m, c->padded, MODE_DEFAULT, 1, err, err_size);
        for (int b = 0; b < o->builds && !rc; b++) {
            rc = grid_scene(&grid, lb, &child, spacing, err, err_size);
            if (!rc) {
                inst_ms = grid.seconds * 1e3 < inst_ms ? grid.seconds * 1e3 : inst_ms;
                if (b == o->builds - 1) {
                    inst_rate = render_rate(o, &grid, glo, ghi, rgb, err, err_size);
                    rc = inst_rate < 0;
                }
            }
            if (grid.lib)
                scene_release(&grid);
        }
        if (child.lib)
            scene_release(&child);
        if (!rc)
            rc = pieces_scene(&dyn, lb, &p, err, err_size);
        if (!rc) {
            dyn_first = dyn.seconds * 1e3;
            for (int f = 1; f <= o->builds + 1; f++) {
                const double t0 = now();
                pieces_move(&dyn, &p, rest, 0.002f * diag * (float)f);
                const double ms = (now() - t0) * 1e3;
                frame_ms = ms < frame_ms ? ms : frame_ms;
            }
            if (dyn.rscene) {
                rtk_scene_info info = {.struct_size = sizeof info};
                if (rtk_scene_get_info(dyn.rscene, &info) || info.trees_built != 0 || info.refits != 1) {
                    snprintf(err, err_size, "%s: a frame did not refit the one geometry alone", lb->name);
                    rc = 1;
                }
            }
            if (dyn.escene && rtcGetDeviceError(lb->edev) != RTC_ERROR_NONE) {
                snprintf(err, err_size, "%s: a frame's commit failed", lb->name);
                rc = 1;
            }
            if (!rc) {
                dyn_rate = render_rate(o, &dyn, lo, hi, rgb, err, err_size);
                rc = dyn_rate < 0;
            }
            scene_release(&dyn);
        }
        if (rc)
            break;
        if (l == 0) {
            ref[0] = inst_ms, ref[1] = inst_rate, ref[2] = frame_ms, ref[3] = dyn_rate;
        }
        printf("  %-20s %12.3f %7.2fx %10.2f %7.2fx %12.1f %10.3f %7.2fx %10.2f %7.2fx\n", lb->name, inst_ms,
               ratio(ref[0], inst_ms), inst_rate, ratio(inst_rate, ref[1]), dyn_first, frame_ms, ratio(ref[2], frame_ms),
               dyn_rate, ratio(dyn_rate, ref[3]));
        csv_row(&c->csv, "twolevel", lb->name, "instances", "commit", "", 1, inst_ms, "ms", ratio(ref[0], inst_ms));
        csv_row(&c->csv, "twolevel", lb->name, "instances", "diffuse path tracer", "single", 1, inst_rate, "Mrays/s",
                ratio(inst_rate, ref[1]));
        csv_row(&c->csv, "twolevel", lb->name, "dynamic", "first commit", "", 1, dyn_first, "ms", 0);
        csv_row(&c->csv, "twolevel", lb->name, "dynamic", "frame commit", "", 1, frame_ms, "ms",
                ratio(ref[2], frame_ms));
        csv_row(&c->csv, "twolevel", lb->name, "dynamic", "diffuse path tracer", "single", 1, dyn_rate, "Mrays/s",
                ratio(dyn_rate, ref[3]));
    }
    free(rest);
    pieces_free(&p);
    free(rgb);
    return rc;
}

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

/* The mesh with `steps` time steps of vertices v[k], at medium quality,
 * timed from the first scene call to the committed scene. */
static int motion_scene(scene *sc, lib *l, const rtk_mesh *m, float *const *v, int steps, char *err, size_t err_size)
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
              rtk_geometry_set_time_step_count(g, (unsigned)steps);
    for (int k = 0; k < steps && !bad; k++)
        bad = rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, (unsigned)k, v[k], 0, 12,
                                                  m->vertex_count) != RTK_OK;
    return rtk_mesh_commit(sc, s, g, m, 0, bad, t0, err, err_size);
}

/* Linear motion blur: the mesh at 2 and at 5 time steps; build (best of
 * the builds), memory, and the primary and diffuse rays at random times
 * (the same times for every library) through it, beside the same rays
 * through the static mesh in the same library. */
static int section_motion(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    static const int step_counts[2] = {2, 5};
    float lo[3], hi[3];
    const float diag = rtk_mesh_bounds(c->m, lo, hi);
    printf("\nmotion blur, 1 thread: the mesh turning (up to 0.6 radians at the top) and moving sideways (5%% of its "
           "diagonal) over the shutter, at 2 and 5 time steps, medium quality; start time (best of %d), bytes per "
           "triangle, and the primary and diffuse rays at random times, single rays and packets of 8 primary rays "
           "(Mrays/s, best of %d passes; static: the diffuse rays through the static mesh in the same library)\n",
           o->builds, o->repeat);
    printf("  %-20s %5s %9s %7s %8s %10s %7s %10s %7s %10s %7s %9s %8s\n", "library", "steps", "build ms", "ratio",
           "B/tri", "primary", "ratio", "diffuse", "ratio", "primary8", "ratio", "static", "differ");
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
                rc = motion_scene(&sc, lb, c->m, v, steps, err, err_size);
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
            if (l == 0) {
                ref[0] = best;
                for (int k = 0; k < 3; k++)
                    ref[1 + k] = rate[k];
            }
            printf("  %-20s %5d %9.1f %6.2fx %8.1f %10.2f %6.2fx %10.2f %6.2fx %10.2f %6.2fx %9.2f %8zu\n", lb->name,
                   steps, best * 1e3, ratio(ref[0], best), bytes, rate[0], ratio(rate[0], ref[1]), rate[1],
                   ratio(rate[1], ref[2]), rate[2], ratio(rate[2], ref[3]), static_rate, differ);
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

static int section_accuracy(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    rayset edges;
    make_edge_rays(c->m, (size_t)o->edge_rays, &edges);
    const rayset diff = c->sets[SET_DIFFUSE];
    printf("\naccuracy: %zu rays aimed at points of edges shared by two triangles, from the side both face; a ray "
           "that misses or hits beyond its edge point leaked through the mesh, and one that hits both triangles "
           "(every hit collected by a filter) hit twice; beside the diffuse rays' rate (single rays, 1 thread)\n",
           edges.n);
    printf("  %-20s %-8s %10s %12s %10s %12s %16s %8s\n", "library", "mode", "leaks", "per million", "twice",
           "per million", "diffuse Mrays/s", "B/tri");
    char path[600];
    snprintf(path, sizeof path, "%s/%s-accuracy.dat", o->outdir, c->stem);
    FILE *dat = fopen(path, "w");
    unsigned char *hits = malloc(diff.n + 1);
    for (int l = 0; l < c->nlibs; l++) {
        for (int mode = 0; mode < 3; mode++) {
            scene sc;
            if (scene_build(&sc, &c->libs[l], c->m, c->padded, mode, 1, err, err_size))
                return 1;
            const render_tracer t = scene_tracer(&sc, 0);
            const size_t leaks = count_leaks(&t, &edges);
            const double rate = trace_set(&t, &diff, 1, 0, 1, o->repeat, hits), bytes = sc.bytes_per_tri;
            scene_release(&sc);
            bench_collect = 1;
            const int bad = scene_build(&sc, &c->libs[l], c->m, c->padded, mode, 1, err, err_size);
            bench_collect = 0;
            if (bad)
                return 1;
            const render_tracer tc = scene_tracer(&sc, 0);
            const size_t twice = count_double_hits(&tc, &edges);
            scene_release(&sc);
            const double ppm = edges.n ? 1e6 * (double)leaks / (double)edges.n : 0.0;
            const double ppm2 = edges.n ? 1e6 * (double)twice / (double)edges.n : 0.0;
            printf("  %-20s %-8s %10zu %12.1f %10zu %12.1f %16.2f %8.1f\n", c->libs[l].name, mode_names[mode], leaks,
                   ppm, twice, ppm2, rate, bytes);
            csv_row(&c->csv, "accuracy", c->libs[l].name, mode_names[mode], "edge", "single", 1, ppm,
                    "leaks per million", 0);
            csv_row(&c->csv, "accuracy", c->libs[l].name, mode_names[mode], "edge", "single", 1, ppm2,
                    "double hits per million", 0);
            csv_row(&c->csv, "accuracy", c->libs[l].name, mode_names[mode], "diffuse", "single", 1, rate, "Mrays/s",
                    0);
            if (dat)
                fprintf(dat, "%.3f %.4f %s\n", ppm, rate, mode_names[mode]);
        }
        if (dat)
            fprintf(dat, "\n\n"); /* one gnuplot index per library */
    }
    if (dat) {
        fclose(dat);
        snprintf(path, sizeof path, "%s/%s-accuracy.gp", o->outdir, c->stem);
        FILE *gp = fopen(path, "w");
        if (gp) {
            fprintf(gp,
                    "set terminal pngcairo noenhanced size 900,600 font 'sans,10'\nset output '%s-accuracy.png'\n"
                    "set title '%s: speed against accuracy per intersector and mode'\n"
                    "set xlabel 'rays leaking through shared edges, per million (lower is better)'\n"
                    "set ylabel 'diffuse rays, Mrays/s, 1 thread (higher is better)'\n"
                    "set grid\nset key outside right\nset xrange [0:*]\nset yrange [0:*]\n"
                    "set offsets graph 0.05, graph 0.1, graph 0.1, graph 0\nplot ",
                    c->stem, base_name(c->csv.mesh));
            for (int l = 0; l < c->nlibs; l++)
                fprintf(gp, "%s'%s-accuracy.dat' index %d using 1:2 with points pt %d ps 1.5 lc %d title '%s', "
                        "'' index %d using 1:2:3 with labels offset 0.8,0.5 left font 'sans,7' tc lt -1 notitle",
                        l ? ", " : "", c->stem, l, 5 + 2 * (l % 3), l + 1, c->libs[l].name, l);
            fprintf(gp, "\n");
            fclose(gp);
        }
    }
    free(edges.rays);
    free(edges.pair);
    free(hits);
    return 0;
}

/* ---- closed meshes: the accuracy harness ---- */

/* What one library and mode did with a group of aimed rays. */
typedef struct closed_tally {
    size_t rays, misses, twice, zero_area;
    double *ulps; /* each hit's t error, in ulps of the reference t */
    size_t nulps, cap;
    double point_err; /* the largest |t - t_ref| over the mesh's diagonal */
    double seconds;   /* intersect1 over the timed groups' rays, best of --repeat */
    size_t timed;
} closed_tally;

static void tally_free(closed_tally *t)
{
    free(t->ulps);
    memset(t, 0, sizeof *t);
}

static int tally_ulps(closed_tally *t, double u)
{
    if (t->nulps == t->cap) {
        const size_t cap = t->cap ? 2 * t->cap : 4096;
        double *p = realloc(t->ulps, cap * sizeof *p);
        if (!p)
            return 1;
        t->ulps = p, t->cap = cap;
    }
    t->ulps[t->nulps++] = u;
    return 0;
}

static int cmp_double(const void *x, const void *y)
{
    const double a = *(const double *)x, b = *(const double *)y;
    return a < b ? -1 : a > b;
}

static void tally_sort(closed_tally *t)
{
    if (t->nulps)
        qsort(t->ulps, t->nulps, sizeof *t->ulps, cmp_double);
}

/* The q-quantile of the tally's t errors (sorted by tally_sort); -1 for none. */
static double tally_quantile(const closed_tally *t, double q)
{
    if (!t->nulps)
        return -1.0;
    size_t i = (size_t)(q * (double)(t->nulps - 1) + 0.5);
    return t->ulps[i < t->nulps ? i : t->nulps - 1];
}

/* Where the ray meets the plane of triangle prim, in long double from the
 * float vertices and ray: the reference t. */
static long double plane_t(const rtk_mesh *m, uint32_t prim, const rtk_ray *r)
{
    const uint32_t *x = m->indices + 3 * (size_t)prim;
    long double v[3][3], e1[3], e2[3], n[3];
    for (int j = 0; j < 3; j++)
        for (int k = 0; k < 3; k++)
            v[j][k] = m->vertices[3 * x[j] + k];
    for (int k = 0; k < 3; k++)
        e1[k] = v[1][k] - v[0][k], e2[k] = v[2][k] - v[0][k];
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    const long double o[3] = {r->org_x, r->org_y, r->org_z}, d[3] = {r->dir_x, r->dir_y, r->dir_z};
    long double num = 0, den = 0;
    for (int k = 0; k < 3; k++)
        num += n[k] * (v[0][k] - o[k]), den += n[k] * d[k];
    return num / den;
}

/* Ways a ray is made invalid, to time what a renderer handing over broken
 * rays pays (rtk only: Embree 3 as Debian builds it asserts ray.valid()
 * and aborts the process). */
enum { NINVALID = 4 };
static const char *const invalid_names[NINVALID] = {"NaN origin", "NaN direction", "inf direction", "NaN tnear"};

/* Seconds of intersect1 over the aimed rays, best of `repeat`; with
 * invalid >= 0 each ray broken the way invalid_names[invalid] says. */
static double time_aimed(const render_tracer *tr, const rtk_aimed *a, int invalid, int repeat)
{
    double best = 1e30;
    for (int r = 0; r < repeat; r++) {
        const double t0 = now();
        for (size_t i = 0; i < a->count; i++) {
            _Alignas(16) rtk_rayhit rh = {.ray = a->rays[i], .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
            if (invalid >= 0)
                *(invalid == 0   ? &rh.ray.org_x
                  : invalid == 1 ? &rh.ray.dir_y
                  : invalid == 2 ? &rh.ray.dir_z
                                 : &rh.ray.tnear) = invalid == 2 ? INFINITY : NAN;
            tr->intersect1(tr->scene, &rh);
        }
        best = fmin(best, now() - t0);
    }
    return best;
}

/* The aimed rays through one library's scene of the mesh in one mode:
 * closest hits (a miss, or a first hit beyond the point inside, is a false
 * miss; a hit's t against the reference), then every crossing before the
 * point inside collected by a filter (an even number, more than none, is a
 * double hit); hits on the triangles after the closed surface (zero area)
 * counted in both.  With `timed`, intersect1 over the rays is timed too,
 * and with `invalid` also over the rays made invalid each way (seconds
 * added to invalid[]). */
static int closed_run(lib *l, int mode, const rtk_closed_mesh *cm, const rtk_aimed *a, int timed, int repeat,
                      closed_tally *t, double *invalid, char *err, size_t err_size)
{
    const rtk_mesh *m = &cm->mesh;
    float lo[3], hi[3];
    const double diag = rtk_mesh_bounds(m, lo, hi);
    scene sc;
    if (scene_build(&sc, l, m, m->vertices, mode, 1, err, err_size))
        return 1;
    render_tracer tr = scene_tracer(&sc, 0);
    int bad = 0;
    for (size_t i = 0; i < a->count; i++) {
        _Alignas(16) rtk_rayhit rh = {.ray = a->rays[i], .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
        tr.intersect1(tr.scene, &rh);
        const int hit = rh.hit.geomID != RTK_INVALID_GEOMETRY_ID;
        t->misses += !hit || rh.ray.tfar > a->t_in[i];
        if (hit && rh.hit.primID >= cm->closed_triangles) {
            t->zero_area++;
        } else if (hit) {
            const long double tr_ = plane_t(m, rh.hit.primID, &a->rays[i]);
            const float tf = fabsf((float)tr_);
            const double ulp = (double)(nextafterf(tf, INFINITY) - tf);
            const double e = (double)fabsl((long double)rh.ray.tfar - tr_);
            bad |= tally_ulps(t, e / ulp);
            t->point_err = fmax(t->point_err, diag > 0 ? e / diag : 0.0);
        }
    }
    if (timed) {
        t->seconds += time_aimed(&tr, a, -1, repeat);
        t->timed += a->count;
        for (int v = 0; invalid && v < NINVALID; v++)
            invalid[v] += time_aimed(&tr, a, v, repeat);
    }
    scene_release(&sc);
    bench_collect = 1;
    bad |= scene_build(&sc, l, m, m->vertices, mode, 1, err, err_size);
    bench_collect = 0;
    if (bad) {
        if (!err[0])
            snprintf(err, err_size, "out of memory");
        return 1;
    }
    tr = scene_tracer(&sc, 0);
    for (size_t i = 0; i < a->count; i++) {
        _Alignas(16) rtk_rayhit rh = {.ray = a->rays[i], .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
        bench_seen.n = 0;
        bench_t_limit = a->t_in[i];
        tr.intersect1(tr.scene, &rh);
        unsigned n = 0, flat = 0;
        for (unsigned k = 0; k < bench_seen.n; k++) {
            n += bench_seen.prim[k] < cm->closed_triangles;
            flat += bench_seen.prim[k] >= cm->closed_triangles;
        }
        t->twice += n && n % 2 == 0;
        t->zero_area += flat != 0;
    }
    bench_t_limit = 1.0f + 1e-4f;
    t->rays += a->count;
    scene_release(&sc);
    return 0;
}

/* The closed meshes of the offset and size sweeps: a sphere, a torus and a
 * box of radius `size` around c, checked closed by OpenMesh, and the rays
 * aimed at them.  The mesh lies within its faceting (under 4% of its size)
 * and the rounding of its vertices of the solid's surface: the margin. */
/* Non-zero, with err saying why, unless OpenMesh finds the mesh's closed
 * surface closed. */
static int closed_check(const rtk_closed_mesh *cm, char *err, size_t err_size)
{
    size_t boundary = 0, rejected = 0;
    if (rtk_mesh_is_closed(&cm->mesh, cm->closed_triangles, &boundary, &rejected) == 1)
        return 0;
    snprintf(err, err_size, "the %s is not closed: %zu boundary edges, %zu faces OpenMesh rejected", cm->name,
             boundary, rejected);
    return 1;
}

static int closed_group(const double c[3], double size, int quick, uint64_t seed, rtk_closed_mesh cm[3],
                        rtk_aimed a[3], char *err, size_t err_size)
{
    memset(cm, 0, 3 * sizeof *cm);
    memset(a, 0, 3 * sizeof *a);
    const double mag = fmax(fabs(c[0]), fmax(fabs(c[1]), fabs(c[2]))) + 2.0 * size;
    const double margin = 0.04 * size + mag * 0x1p-23;
    const int f = quick ? 1 : 2; /* --quick: a quarter of the triangles */
    int bad = rtk_closed_sphere(c, size, 24 * f, 12 * f - 1, &cm[0]) ||
              rtk_closed_torus(c, size, 0.4 * size, 24 * f, 12 * f, &cm[1]) || rtk_closed_box(c, size, 4 * f, &cm[2]);
    for (int i = 0; !bad && i < 3; i++) {
        if (closed_check(&cm[i], err, err_size))
            return 1;
        const float out = (float)((i == 1 ? 0.3 : 1.5) * size), in = (float)((i == 1 ? 0.25 : 0.5) * size);
        bad = rtk_closed_aim(&cm[i], margin, out, in, seed + (uint64_t)i, &a[i]);
    }
    if (bad)
        snprintf(err, err_size, "out of memory");
    return bad;
}

static void closed_group_free(rtk_closed_mesh cm[3], rtk_aimed a[3])
{
    for (int i = 0; i < 3; i++)
        rtk_closed_free(&cm[i]), rtk_aimed_free(&a[i]);
}

enum { NOFF = 9, NSIZE = 9, NGRAZE = 7, CLOSED_MODES = 2 };

typedef struct closed_results {
    closed_tally off[NOFF], size[NSIZE], needle, graze[NGRAZE][2]; /* graze: inside faces, on lines */
    double invalid_seconds[NINVALID]; /* the offset sweep's rays at 10^0 made invalid, intersect1 */
} closed_results;

/* Library-and-mode lm's mode: each library's default, then robust. */
static int closed_mode(int lm)
{
    return lm % CLOSED_MODES ? MODE_ROBUST : MODE_DEFAULT;
}

/* Step k of the offset sweep (sizes: of the size sweep): the three closed
 * meshes of radius `size` around c through every library and mode, into
 * each library-and-mode's tally for that step; `timed`: intersect1 timed
 * too, and for rtk the invalid rays. */
static int closed_sweep_step(ctx *c, closed_results *res, int sizes, int k, const double cc[3], double size,
                             uint64_t seed, int timed, size_t *rays, char *err, size_t err_size)
{
    rtk_closed_mesh cm[3];
    rtk_aimed a[3];
    int bad = closed_group(cc, size, c->o->quick, seed, cm, a, err, err_size);
    for (int i = 0; i < 3; i++)
        *rays += a[i].count;
    for (int lm = 0; !bad && lm < c->nlibs * CLOSED_MODES; lm++) {
        lib *l = &c->libs[lm / CLOSED_MODES];
        closed_tally *t = sizes ? &res[lm].size[k] : &res[lm].off[k];
        for (int i = 0; !bad && i < 3; i++)
            bad = closed_run(l, closed_mode(lm), &cm[i], &a[i], timed, timed ? c->o->repeat : 1, t,
                             timed && !l->embree ? res[lm].invalid_seconds : NULL, err, err_size);
    }
    closed_group_free(cm, a);
    return bad;
}

static double per_million(size_t n, size_t of)
{
    return of ? 1e6 * (double)n / (double)of : 0.0;
}

static void closed_print_row(const char *lib_name, int mode, closed_tally *t, int n, int twice)
{
    printf("  %-18s %-7s", lib_name, mode_names[mode]);
    for (int k = 0; k < n; k++)
        printf(" %8.0f", per_million(twice ? t[k].twice : t[k].misses, t[k].rays));
    printf("\n");
}

/* The accuracy harness: closed meshes (OpenMesh checks them closed) and
 * rays aimed exactly at their vertices and edges, through every library in
 * its default and robust modes:
 *   - the meshes moved to 10^k, k = 0 ... 8 (of radius 1, and from 10^7 on
 *     of radius 10^(k-6), so that their vertices keep 2^-4 of the radius
 *     or better apart after rounding): false misses and double hits, and
 *     the failure envelope, the largest offset before the first false miss;
 *   - meshes of radius 1e-8 ... 1e8 near the origin;
 *   - a cylinder of 4096 needle sides and needle caps, with zero-area
 *     triangles on its side lines (collinear) and caps (a repeated vertex),
 *     which must never be hit;
 *   - rays grazing a flat face at 10^-k degrees, k = 0 ... 6;
 *   - the t error of every hit in ulps against the reference (the ray
 *     against the hit triangle's plane in long double), and the hit point's
 *     error over the mesh's diagonal;
 *   - ns per ray (intersect1, 1 thread) over the offset sweep's rays at
 *     10^0, beside the false-miss rate over every aimed ray: the chart. */
static int section_closed(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    const int nlm = c->nlibs * CLOSED_MODES;
    closed_results *res = calloc((size_t)nlm, sizeof *res);
    if (!res) {
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    int bad = 0;
    size_t off_rays[NOFF] = {0}, size_rays[NSIZE] = {0}, needle_rays = 0, graze_n[NGRAZE] = {0};
    printf("\nclosed meshes: rays aimed exactly at every vertex and edge of closed meshes (a sphere, a torus and a box "
           "of %s triangles, OpenMesh checking each closed), from outside the solid to a point "
           "inside it (random directions, and along the axes with the other components +0.0 and -0.0): a ray that "
           "reaches its point inside without a hit is a false miss; one that crosses the mesh an even number of "
           "times (every crossing collected by a filter) has hit one crossing twice.  Per million rays.\n",
           o->quick ? "528, 576 and 192" : "2208, 2304 and 768");
    for (int k = 0; !bad && k < NOFF; k++) {
        const double off = pow(10.0, k);
        const double cc[3] = {off, 0.5 * off, -0.25 * off};
        bad = closed_sweep_step(c, res, 0, k, cc, fmax(1.0, off * 1e-6),
                                17u + 3u * (uint64_t)k, k == 0, &off_rays[k], err, err_size);
    }
    for (int k = 0; !bad && k < NSIZE; k++) {
        const double size = pow(10.0, 2 * k - 8);
        const double cc[3] = {0.3 * size, -0.2 * size, 0.1 * size};
        bad = closed_sweep_step(c, res, 1, k, cc, size, 99u + 3u * (uint64_t)k, 0,
                                &size_rays[k], err, err_size);
    }
    if (!bad) {
        const double cc[3] = {0.25, -0.5, 0.125};
        rtk_closed_mesh cyl;
        rtk_aimed a = {0};
        bad = rtk_closed_cylinder(cc, 1.0, 10.0, o->quick ? 1024 : 4096, 1, &cyl) || closed_check(&cyl, err, err_size) ||
              rtk_closed_aim(&cyl, 1e-5, 1.5f, 0.5f, 4242, &a);
        needle_rays = a.count;
        for (int lm = 0; !bad && lm < nlm; lm++)
            bad = closed_run(&c->libs[lm / CLOSED_MODES], closed_mode(lm), &cyl, &a, 0, 1, &res[lm].needle, NULL, err,
                             err_size);
        rtk_aimed_free(&a);
        rtk_closed_free(&cyl);
    }
    if (!bad) {
        const double cc[3] = {0.0, 0.0, -1.0};
        rtk_closed_mesh box;
        bad = rtk_closed_box(cc, 1.0, 16, &box) || closed_check(&box, err, err_size); /* exact vertices: the mesh is the solid */
        for (int k = 0; !bad && k < 2 * NGRAZE; k++) {
            rtk_aimed a;
            bad = rtk_closed_graze(&box, 16, pow(10.0, -(k / 2)), o->quick ? 1000 : 10000, k % 2, 31u + (uint64_t)k, &a);
            graze_n[k / 2] += a.count;
            for (int lm = 0; !bad && lm < nlm; lm++)
                bad = closed_run(&c->libs[lm / CLOSED_MODES], closed_mode(lm), &box, &a, 0, 1,
                                 &res[lm].graze[k / 2][k % 2], NULL, err, err_size);
            rtk_aimed_free(&a);
        }
        rtk_closed_free(&box);
    }
    if (bad) {
        if (!err[0])
            snprintf(err, err_size, "out of memory");
        goto done;
    }
    for (int lm = 0; lm < nlm; lm++) {
        for (int k = 0; k < NOFF; k++)
            tally_sort(&res[lm].off[k]);
        for (int k = 0; k < NGRAZE; k++)
            tally_sort(&res[lm].graze[k][0]), tally_sort(&res[lm].graze[k][1]);
    }

    printf("\n  moved to 10^k (radius max(1, 10^(k-6))); rays per offset:");
    for (int k = 0; k < NOFF; k++)
        printf(" %zu", off_rays[k]);
    printf("\n  false misses       mode   ");
    for (int k = 0; k < NOFF; k++)
        printf("   10^%-3d", k);
    printf(" envelope\n");
    for (int lm = 0; lm < nlm; lm++) {
        closed_tally *t = res[lm].off;
        printf("  %-18s %-7s", c->libs[lm / CLOSED_MODES].name, mode_names[closed_mode(lm)]);
        int env = -1, gap = 0;
        for (int k = 0; k < NOFF; k++) {
            printf(" %8.0f", per_million(t[k].misses, t[k].rays));
            if (!t[k].misses)
                gap |= env < k - 1, env = k;
        }
        if (env < 0)
            printf("     none\n");
        else
            printf("   1e%d%s\n", env, gap ? " (not below)" : "");
    }
    printf("  double hits\n");
    for (int lm = 0; lm < nlm; lm++)
        closed_print_row(c->libs[lm / CLOSED_MODES].name, closed_mode(lm), res[lm].off, NOFF, 1);

    printf("\n  of radius 10^k near the origin; rays per size:");
    for (int k = 0; k < NSIZE; k++)
        printf(" %zu", size_rays[k]);
    printf("\n  false misses       mode   ");
    for (int k = 0; k < NSIZE; k++)
        printf("  10^%-4d", 2 * k - 8);
    printf("\n");
    for (int lm = 0; lm < nlm; lm++)
        closed_print_row(c->libs[lm / CLOSED_MODES].name, closed_mode(lm), res[lm].size, NSIZE, 0);
    printf("  double hits\n");
    for (int lm = 0; lm < nlm; lm++)
        closed_print_row(c->libs[lm / CLOSED_MODES].name, closed_mode(lm), res[lm].size, NSIZE, 1);

    const int sides = o->quick ? 1024 : 4096;
    printf("\n  needles: a cylinder of radius 1 and height 20 with %d sides (side triangles 20 x %.4f, caps fans of "
           "1 x %.4f) and %d zero-area triangles on its side lines and caps; %zu rays\n",
           sides, 6.2832 / sides, 6.2832 / sides, 2 * sides, needle_rays);
    printf("  %-18s %-7s %14s %14s %16s\n", "library", "mode", "false misses", "double hits", "zero-area hits");
    for (int lm = 0; lm < nlm; lm++) {
        const closed_tally *t = &res[lm].needle;
        printf("  %-18s %-7s %14zu %14zu %16zu\n", c->libs[lm / CLOSED_MODES].name,
               mode_names[closed_mode(lm)], t->misses, t->twice, t->zero_area);
    }

    printf("\n  grazing a flat face at 10^-k degrees (%zu rays each, half at points inside its triangles, half on "
           "their edges or at vertices): false misses per million (inside / on edges), and the t error in ulps "
           "(median / max)\n  %-18s %-7s",
           graze_n[0], "library", "mode");
    for (int k = 0; k < NGRAZE; k++) {
        char head[16];
        snprintf(head, sizeof head, "10^-%d deg", k);
        printf(" %18s", head);
    }
    printf("\n");
    for (int lm = 0; lm < nlm; lm++) {
        printf("  %-18s %-7s", c->libs[lm / CLOSED_MODES].name, mode_names[closed_mode(lm)]);
        for (int k = 0; k < NGRAZE; k++) {
            const closed_tally *t = res[lm].graze[k];
            char cell[40];
            snprintf(cell, sizeof cell, "%.0f/%.0f %.1f/%.0f", per_million(t[0].misses, t[0].rays),
                     per_million(t[1].misses, t[1].rays), fmax(tally_quantile(&t[0], 0.5), tally_quantile(&t[1], 0.5)),
                     fmax(tally_quantile(&t[0], 1.0), tally_quantile(&t[1], 1.0)));
            printf(" %18s", cell);
        }
        printf("\n");
    }

    printf("\n  t error of the hits, in ulps of the reference t (median / 99th percentile / max), and the largest hit "
           "point error over the mesh's diagonal, at 10^0 and 10^6; ns per ray (intersect1, 1 thread, the rays at "
           "10^0)\n");
    printf("  %-18s %-7s %22s %10s %22s %10s %8s\n", "library", "mode", "t ulps at 10^0", "point", "t ulps at 10^6",
           "point", "ns/ray");
    char path[600];
    snprintf(path, sizeof path, "%s/closed-accuracy.dat", o->outdir);
    FILE *dat = fopen(path, "w");
    for (int lm = 0; lm < nlm; lm++) {
        closed_results *r = &res[lm];
        const char *name = c->libs[lm / CLOSED_MODES].name, *mode = mode_names[closed_mode(lm)];
        closed_tally *t0 = &r->off[0], *t6 = &r->off[6];
        const double ns = t0->timed ? 1e9 * t0->seconds / (double)t0->timed : 0.0;
        printf("  %-18s %-7s %6.1f / %5.1f / %6.0f %10.1e %6.1f / %5.1f / %6.0f %10.1e %8.1f\n", name, mode,
               tally_quantile(t0, 0.5), tally_quantile(t0, 0.99), tally_quantile(t0, 1.0), t0->point_err,
               tally_quantile(t6, 0.5), tally_quantile(t6, 0.99), tally_quantile(t6, 1.0), t6->point_err,
               ns);
        size_t all = 0, missed = 0, twice = 0, flat = r->needle.zero_area;
        const closed_tally *groups[3] = {r->off, r->size, r->graze[0]};
        const int counts[3] = {NOFF, NSIZE, 2 * NGRAZE};
        for (int g = 0; g < 3; g++)
            for (int k = 0; k < counts[g]; k++)
                all += groups[g][k].rays, missed += groups[g][k].misses, twice += groups[g][k].twice;
        all += r->needle.rays, missed += r->needle.misses, twice += r->needle.twice;
        char variant[48];
        for (int k = 0; k < NOFF; k++) {
            snprintf(variant, sizeof variant, "%s, at 1e%d", mode, k);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(r->off[k].misses, r->off[k].rays),
                    "false misses per million", 0);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(r->off[k].twice, r->off[k].rays),
                    "double hits per million", 0);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, tally_quantile(&r->off[k], 0.5),
                    "median t error, ulps", 0);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, tally_quantile(&r->off[k], 1.0),
                    "max t error, ulps", 0);
        }
        for (int k = 0; k < NSIZE; k++) {
            snprintf(variant, sizeof variant, "%s, size 1e%d", mode, 2 * k - 8);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(r->size[k].misses, r->size[k].rays),
                    "false misses per million", 0);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(r->size[k].twice, r->size[k].rays),
                    "double hits per million", 0);
        }
        for (int k = 0; k < 2 * NGRAZE; k++) {
            const closed_tally *t = &r->graze[k / 2][k % 2];
            snprintf(variant, sizeof variant, "%s, grazing 1e-%d deg%s", mode, k / 2, k % 2 ? ", edges" : "");
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(t->misses, t->rays),
                    "false misses per million", 0);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, tally_quantile(t, 1.0),
                    "max t error, ulps", 0);
        }
        snprintf(variant, sizeof variant, "%s, needles", mode);
        csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, (double)flat, "zero-area hits", 0);
        csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(r->needle.misses, r->needle.rays),
                "false misses per million", 0);
        snprintf(variant, sizeof variant, "%s, all", mode);
        csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(missed, all),
                "false misses per million", 0);
        csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(twice, all),
                "double hits per million", 0);
        csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, ns, "ns per ray", 0);
        if (dat) {
            fprintf(dat, "%.2f %.3f %s\n", ns, per_million(missed, all), mode);
            if (lm % CLOSED_MODES == CLOSED_MODES - 1)
                fprintf(dat, "\n\n"); /* one gnuplot index per library */
        }
    }
    printf("\n  invalid rays (the rays at 10^0 with one field broken; rtk answers them as misses without tracing): "
           "ns per ray, intersect1, 1 thread, and against the valid rays\n  %-18s %-7s %8s", "library", "mode",
           "valid");
    for (int v = 0; v < NINVALID; v++)
        printf(" %20s", invalid_names[v]);
    printf("\n");
    for (int lm = 0; lm < nlm; lm++) {
        const closed_tally *t0 = &res[lm].off[0];
        const char *name = c->libs[lm / CLOSED_MODES].name, *mode = mode_names[closed_mode(lm)];
        const double ns = t0->timed ? 1e9 * t0->seconds / (double)t0->timed : 0.0;
        printf("  %-18s %-7s %8.1f", name, mode, ns);
        if (c->libs[lm / CLOSED_MODES].embree) {
            printf("  not measured: Embree 3 (Debian's build) asserts ray.valid() and aborts\n");
            continue;
        }
        for (int v = 0; v < NINVALID; v++) {
            const double bad_ns = t0->timed ? 1e9 * res[lm].invalid_seconds[v] / (double)t0->timed : 0.0;
            char cell[40], variant[48];
            snprintf(cell, sizeof cell, "%.1f (%.2fx)", bad_ns, ns > 0 ? bad_ns / ns : 0.0);
            printf(" %20s", cell);
            snprintf(variant, sizeof variant, "%s, %s", mode, invalid_names[v]);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, bad_ns, "ns per ray", 0);
        }
        printf("\n");
    }
    if (dat) {
        fclose(dat);
        snprintf(path, sizeof path, "%s/closed-accuracy.gp", o->outdir);
        FILE *gp = fopen(path, "w");
        if (gp) {
            fprintf(gp,
                    "set terminal pngcairo noenhanced size 900,600 font 'sans,10'\nset output 'closed-accuracy.png'\n"
                    "set title 'closed meshes: speed against accuracy per (library, backend, mode)'\n"
                    "set xlabel 'ns per ray, intersect1, 1 thread (lower is better)'\n"
                    "set ylabel 'false misses per million rays aimed at vertices and edges (lower is better)'\n"
                    "set grid\nset key outside right\nset xrange [0:*]\nset logscale y\nset yrange [0.05:2e5]\n"
                    "set ytics add ('0' 0.1)\nset offsets graph 0.05, graph 0.1, 0, 0\nplot ");
            /* no false miss at all is drawn at 0.1 on the log scale, labelled 0 */
            for (int l = 0; l < c->nlibs; l++)
                fprintf(gp, "%s'closed-accuracy.dat' index %d using 1:($2 > 0 ? $2 : 0.1) with points pt %d ps 1.5 "
                        "lc %d title '%s', '' index %d using 1:($2 > 0 ? $2 : 0.1):3 with labels offset 0.8,0.5 left "
                        "font 'sans,7' tc lt -1 notitle",
                        l ? ", " : "", l, 5 + 2 * (l % 3), l + 1, c->libs[l].name, l);
            fprintf(gp, "\n");
            fclose(gp);
        }
    }
done:
    for (int lm = 0; lm < nlm; lm++) {
        for (int k = 0; k < NOFF; k++)
            tally_free(&res[lm].off[k]);
        for (int k = 0; k < NSIZE; k++)
            tally_free(&res[lm].size[k]);
        for (int k = 0; k < NGRAZE; k++)
            tally_free(&res[lm].graze[k][0]), tally_free(&res[lm].graze[k][1]);
        tally_free(&res[lm].needle);
    }
    free(res);
    return bad;
}

/* What masks, filters and quads cost when a scene uses them: the default
 * scene, one whose geometry has a mask every ray passes (MODE_MASK), the
 * mesh as two geometries of different masks (MODE_MASKS2: each candidate's
 * mask tested), one with filters that accept every candidate (the same
 * hits), and the same triangles as quads (MODE_QUAD),
 * each library against its own default and rtk against Embree in the same
 * mode; 1 thread. */
enum { NFEAT = 5 };
static int section_features(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    static const int modes[NFEAT] = {MODE_DEFAULT, MODE_MASK, MODE_MASKS2, MODE_FILTER, MODE_QUAD};
    static const int sets[2] = {SET_DIFFUSE, SET_SHADOW};
    if (quads_make(c->m, &bench_quads)) {
        snprintf(err, err_size, "out of memory for the quads");
        return 1;
    }
    printf("\nfeatures: a geometry mask (mask: one geometry of mask 1; masks2: the mesh's two halves, masks 1 and 2; "
           "the rays' all ones), filters accepting every hit, and the triangles as quads (%zu, %zu of them "
           "two triangles; the same surfaces as default); Mrays/s, 1 thread (ratio to the same library's default) "
           "[ratio to %s in the same mode]\n",
           bench_quads.n, bench_quads.paired, c->libs[0].name);
    printf("  %-20s %-8s %-28s %-28s %-28s %-28s\n", "library", "mode", "diffuse single", "diffuse packet8",
           "shadow single", "shadow packet8");
    /* Every scene built first, then the passes interleaved (one pass of
     * every cell per round, the best of the rounds kept), so that drift in
     * the machine's speed falls on all cells alike. */
    enum { MAXL = 8 };
    const int nl = c->nlibs < MAXL ? c->nlibs : MAXL;
    scene sc[MAXL][NFEAT];
    memset(sc, 0, sizeof sc);
    double rate[MAXL][NFEAT][2][2] = {{{{0}}}}; /* lib, mode, set, api */
    unsigned char *hits = malloc(c->sets[SET_DIFFUSE].n + c->sets[SET_SHADOW].n + 1);
    int bad = !hits;
    for (int l = 0; l < nl && !bad; l++)
        for (int mi = 0; mi < NFEAT && !bad; mi++)
            bad = scene_build(&sc[l][mi], &c->libs[l], c->m, c->padded, modes[mi], 1, err, err_size);
    for (int round = 0; round < o->repeat && !bad; round++)
        for (int l = 0; l < nl; l++)
            for (int mi = 0; mi < NFEAT; mi++)
                for (int k = 0; k < 2; k++)
                    for (int a = 0; a < 2; a++) {
                        const render_tracer t = scene_tracer(&sc[l][mi], 0);
                        const double r =
                            trace_set(&t, &c->sets[sets[k]], a ? 8 : 1, sets[k] == SET_SHADOW, 1, 1, hits);
                        rate[l][mi][k][a] = r > rate[l][mi][k][a] ? r : rate[l][mi][k][a];
                    }
    for (int l = 0; l < nl && !bad; l++)
        for (int mi = 0; mi < NFEAT; mi++) {
            printf("  %-20s %-8s", c->libs[l].name, mode_names[modes[mi]]);
            for (int k = 0; k < 2; k++)
                for (int a = 0; a < 2; a++) {
                    const double r = rate[l][mi][k][a];
                    char cell[64];
                    snprintf(cell, sizeof cell, "%.2f (%.2fx)", r, ratio(r, rate[l][0][k][a]));
                    if (l > 0)
                        snprintf(cell + strlen(cell), sizeof cell - strlen(cell), " [%.2fx]",
                                 ratio(r, rate[0][mi][k][a]));
                    printf(" %-28s", cell);
                    csv_row(&c->csv, "features", c->libs[l].name, mode_names[modes[mi]], set_names[sets[k]],
                            a ? "packet8" : "single", 1, r, "Mrays/s", 0);
                }
            printf("\n");
        }
    for (int l = 0; l < nl; l++)
        for (int mi = 0; mi < NFEAT; mi++)
            if (sc[l][mi].lib)
                scene_release(&sc[l][mi]);
    free(hits);
    free(bench_quads.q);
    bench_quads = (quad_list){0};
    return bad;
}

int cmd_bench(int argc, char **argv)
{
    bench_opts o = {.outdir = "bench-out", .w = 1024, .h = 768, .repeat = 3, .builds = 3, .edge_rays = 200000,
                    .threads = {1, 2}, .nthreads = 2, .api_on = {1, 1, 1, 1}, .set_on = {1, 1, 1, 1, 1},
                    .do_trace = 1, .do_render = 1, .do_build = 1, .do_refit = 1, .do_twolevel = 1, .do_motion = 1,
                    .do_accuracy = 1, .do_features = 1, .do_closed = 1, .render_w = 512, .render_h = 384,
                    .render_spp = 1};
    const char *meshes[64];
    int nmeshes = 0;
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        const int more = i + 1 < argc;
        char items[8][16];
        int n;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            bench_usage(stdout);
            return 0;
        } else if ((!strcmp(a, "-o") || !strcmp(a, "--output")) && more)
            o.outdir = argv[++i];
        else if (!strcmp(a, "--threads") && more) {
            n = parse_list(argv[++i], items, 4);
            o.nthreads = n > 0 ? n : 0;
            for (int k = 0; k < o.nthreads; k++) {
                o.threads[k] = atoi(items[k]);
                if (o.threads[k] < 1 || o.threads[k] > 16)
                    o.nthreads = 0;
            }
            if (!o.nthreads) {
                fprintf(stderr, "rtktool bench: --threads wants a list of 1..16 (got '%s')\n", argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--alt") && more) {
            o.alt = argv[++i];
            if (!o.alt[0] || strlen(o.alt) > 256 || strchr(o.alt, ',')) {
                fprintf(stderr, "rtktool bench: --alt wants a directory (no comma, at most 256 bytes)\n");
                return 2;
            }
        } else if (!strcmp(a, "--isa") && more) {
            o.nisa = parse_list(argv[++i], o.isa, 4);
            if (o.nisa < 1) {
                fprintf(stderr, "rtktool bench: --isa wants a list of backends (got '%s')\n", argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--api") && more) {
            n = parse_list(argv[++i], items, 8);
            memset(o.api_on, 0, sizeof o.api_on);
            for (int k = 0; k < n; k++) {
                int found = 0;
                for (int j = 0; j < 4; j++)
                    if (render_api_parse(items[k]) == apis[j])
                        o.api_on[j] = found = 1;
                if (!found)
                    n = -1;
            }
            if (n < 1) {
                fprintf(stderr, "rtktool bench: --api wants a list of single, packet4, packet8, packet16 (got '%s')\n",
                        argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--rays") && more) {
            n = parse_list(argv[++i], items, 8);
            memset(o.set_on, 0, sizeof o.set_on);
            for (int k = 0; k < n; k++) {
                int found = 0;
                for (int j = 0; j < NSETS; j++)
                    if (!strcmp(items[k], set_names[j]))
                        o.set_on[j] = found = 1;
                if (!found)
                    n = -1;
            }
            if (n < 1) {
                fprintf(stderr, "rtktool bench: --rays wants a list of primary, diffuse, shadow, incoherent, sun (got '%s')\n",
                        argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--only") && more) {
            n = parse_list(argv[++i], items, 8);
            o.do_trace = o.do_render = o.do_build = o.do_refit = o.do_twolevel = o.do_motion = o.do_accuracy =
                o.do_features = o.do_closed = 0;
            for (int k = 0; k < n; k++) {
                int *flag = !strcmp(items[k], "trace")      ? &o.do_trace
                            : !strcmp(items[k], "render")   ? &o.do_render
                            : !strcmp(items[k], "build")    ? &o.do_build
                            : !strcmp(items[k], "refit")    ? &o.do_refit
                            : !strcmp(items[k], "twolevel") ? &o.do_twolevel
                            : !strcmp(items[k], "motion")   ? &o.do_motion
                            : !strcmp(items[k], "accuracy") ? &o.do_accuracy
                            : !strcmp(items[k], "features") ? &o.do_features
                            : !strcmp(items[k], "closed")   ? &o.do_closed
                                                            : NULL;
                if (!flag)
                    n = -1;
                else
                    *flag = 1;
            }
            if (n < 1) {
                fprintf(stderr,
                        "rtktool bench: --only wants a list of trace, render, build, refit, twolevel, motion, "
                        "accuracy, features, closed (got '%s')\n",
                        argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--size") && more) {
            char tail;
            if (sscanf(argv[++i], "%dx%d%c", &o.w, &o.h, &tail) != 2 || o.w < 4 || o.h < 4 || o.w > 8192 ||
                o.h > 8192 || o.w % 4 || o.h % 4) {
                fprintf(stderr, "rtktool bench: --size wants WxH, multiples of 4 up to 8192 (got '%s')\n", argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--render") && more) {
            char tail;
            if (sscanf(argv[++i], "%dx%dx%d%c", &o.render_w, &o.render_h, &o.render_spp, &tail) != 3 ||
                o.render_w < 1 || o.render_h < 1 || o.render_spp < 1 || o.render_w > 8192 || o.render_h > 8192 ||
                o.render_spp > 4096) {
                fprintf(stderr, "rtktool bench: --render wants WxHxSPP (got '%s')\n", argv[i]);
                return 2;
            }
        } else if ((!strcmp(a, "--repeat") || !strcmp(a, "--builds") || !strcmp(a, "--edge-rays")) && more) {
            char *end;
            errno = 0;
            const long v = strtol(argv[++i], &end, 10);
            const long hi = !strcmp(a, "--edge-rays") ? 100000000 : 1000;
            if (end == argv[i] || *end || errno || v < (!strcmp(a, "--edge-rays") ? 0 : 1) || v > hi) {
                fprintf(stderr, "rtktool bench: %s wants a whole number up to %ld (got '%s')\n", a, hi, argv[i]);
                return 2;
            }
            *(!strcmp(a, "--repeat") ? &o.repeat : !strcmp(a, "--builds") ? &o.builds : &o.edge_rays) = (int)v;
        } else if (!strcmp(a, "--robust")) {
            o.trace_mode = MODE_ROBUST;
        } else if (!strcmp(a, "--quick")) {
            o.w = 256, o.h = 192, o.repeat = 1, o.builds = 1, o.nthreads = 1, o.threads[0] = 1;
            o.edge_rays = 20000, o.render_w = 128, o.render_h = 96, o.quick = 1;
        } else if (a[0] != '-' && nmeshes < 64)
            meshes[nmeshes++] = a;
        else {
            fprintf(stderr, "rtktool bench: unknown or incomplete argument '%s'\n", a);
            bench_usage(stderr);
            return 2;
        }
    }
    const int mesh_sections = o.do_trace || o.do_render || o.do_build || o.do_refit || o.do_twolevel ||
                              o.do_motion || o.do_accuracy || o.do_features;
    if (!nmeshes && mesh_sections) {
        bench_usage(stderr);
        return 2;
    }
    if (mkdir(o.outdir, 0777) && errno != EEXIST) {
        fprintf(stderr, "rtktool bench: %s: %s\n", o.outdir, strerror(errno));
        return 1;
    }
    char path[600], err[1024];
    snprintf(path, sizeof path, "%s/bench.csv", o.outdir);
    FILE *csv = fopen(path, "w");
    if (!csv) {
        fprintf(stderr, "rtktool bench: %s: %s\n", path, strerror(errno));
        return 1;
    }
    fprintf(csv, "mesh,section,library,variant,set,api,threads,value,unit,ratio_to_embree_avx2\n");

    /* The devices kept open for the whole run build with one thread: they
     * build the trace sets' scenes, whose build time is not measured, and
     * Embree 3 builds with the largest threads= of all its live devices (its
     * TBB limit is process-wide), so a 2-thread device kept open here would
     * make the build section's 1-thread Embree devices build on 2.  Trace
     * threads are the bench's own, whatever the device's threads=. */
    ctx c = {.o = &o};
    const int kept_threads = 1;
    int rc = 1;
    if (lib_open(&c.libs[c.nlibs++], "embree isa=avx2", 1, "isa=avx2", kept_threads, err, sizeof err) ||
        lib_open(&c.libs[c.nlibs++], "embree default", 1, "", kept_threads, err, sizeof err)) {
        fprintf(stderr, "rtktool bench: %s\n", err);
        c.nlibs--;
        goto done;
    }
    static const char *const all_isas[] = {"scalar", "sse41", "avx", "avx2"};
    for (int b = 0; b < 4; b++) {
        int wanted = o.nisa == 0;
        for (int k = 0; k < o.nisa; k++)
            wanted |= !strcmp(o.isa[k], all_isas[b]);
        if (!wanted)
            continue;
        char name[40], cfg[32];
        snprintf(name, sizeof name, "rtk %s", all_isas[b]);
        snprintf(cfg, sizeof cfg, "isa=%s", all_isas[b]);
        if (lib_open(&c.libs[c.nlibs], name, 0, cfg, kept_threads, err, sizeof err))
            printf("%s: unavailable (%s)\n", name, err);
        else
            c.nlibs++;
    }
    for (int k = 0; k < o.nisa; k++) {
        int known = 0;
        for (int b = 0; b < 4; b++)
            known |= !strcmp(o.isa[k], all_isas[b]);
        if (!known) {
            fprintf(stderr, "rtktool bench: --isa: no backend '%s' (scalar, sse41, avx, avx2)\n", o.isa[k]);
            goto done;
        }
    }
    if (o.alt) {
        /* the last rtk backend asked for, from the other directory: for
         * comparing two builds of rtk (a change and its parent) in one run */
        const char *isa = o.nisa ? o.isa[o.nisa - 1] : "avx2";
        char name[40], cfg[320];
        snprintf(name, sizeof name, "rtk %s alt", isa);
        snprintf(cfg, sizeof cfg, "isa=%s,backend_path=%s", isa, o.alt);
        if (c.nlibs == MAXLIBS || lib_open(&c.libs[c.nlibs], name, 0, cfg, kept_threads, err, sizeof err)) {
            fprintf(stderr, "rtktool bench: --alt: %s\n", c.nlibs == MAXLIBS ? "too many libraries" : err);
            goto done;
        }
        c.nlibs++;
    }
    char feat[512];
    rtk_cpu_features_string(rtk_cpu_features(), feat, sizeof feat);
    printf("rtk %s beside Embree %d.%d.%d; CPU features: %s; %ld cores online\n", rtk_version_string(),
           RTC_VERSION_MAJOR, RTC_VERSION_MINOR, RTC_VERSION_PATCH, feat, sysconf(_SC_NPROCESSORS_ONLN));
    printf("device creation:");
    for (int l = 0; l < c.nlibs; l++)
        printf(" %s %.1f ms%s", c.libs[l].name, c.libs[l].device_seconds * 1e3, l + 1 < c.nlibs ? "," : "\n");
    const int gnuplot = have_gnuplot();
    for (int mi = 0; mi < nmeshes; mi++) {
        rtk_mesh m;
        size_t want;
        if (rtk_mesh_procedural_name(meshes[mi], &want)) {
            if (rtk_mesh_procedural(want, &m)) {
                fprintf(stderr, "rtktool bench: out of memory for %s\n", meshes[mi]);
                goto done;
            }
        } else if (rtk_mesh_load(meshes[mi], &m, err, sizeof err)) {
            fprintf(stderr, "rtktool: %s\n", err);
            goto done;
        }
        /* Embree reads 16 bytes at the last vertex: a padded copy */
        float *padded = calloc(m.vertex_count * 3 + 4, sizeof(float));
        if (!padded) {
            rtk_mesh_free(&m);
            fprintf(stderr, "rtktool bench: out of memory\n");
            goto done;
        }
        memcpy(padded, m.vertices, m.vertex_count * 3 * sizeof(float));
        c.m = &m;
        c.padded = padded;
        c.csv = (out){csv, meshes[mi]};
        mesh_stem(meshes[mi], c.stem, sizeof c.stem);
        printf("\n== %s: %zu triangles, %zu vertices\n", meshes[mi], m.triangle_count, m.vertex_count);
        printf("memory (BVH and leaves per input triangle; Embree's from its memory monitor):");
        for (int l = 0; l < c.nlibs; l++) {
            scene sc;
            if (scene_build(&sc, &c.libs[l], &m, padded, MODE_DEFAULT, 1, err, sizeof err)) {
                fprintf(stderr, "rtktool bench: %s\n", err);
                free(padded);
                rtk_mesh_free(&m);
                goto done;
            }
            printf(" %s %.1f B%s", c.libs[l].name, sc.bytes_per_tri, l + 1 < c.nlibs ? "," : "\n");
            csv_row(&c.csv, "memory", c.libs[l].name, sc.layout, "", "", 1, sc.bytes_per_tri, "bytes per triangle", 0);
            scene_release(&sc);
        }
        int bad = ((o.do_trace || o.do_build || o.do_refit || o.do_motion || o.do_accuracy || o.do_features) &&
                   make_sets(&c, err, sizeof err)) ||
                  (o.do_trace && section_trace(&c, err, sizeof err)) ||
                  (o.do_render && section_render(&c, err, sizeof err)) ||
                  (o.do_build && section_build(&c, err, sizeof err)) ||
                  (o.do_refit && section_refit(&c, err, sizeof err)) ||
                  (o.do_twolevel && section_twolevel(&c, err, sizeof err)) ||
                  (o.do_motion && section_motion(&c, err, sizeof err)) ||
                  (o.do_accuracy && section_accuracy(&c, err, sizeof err)) ||
                  (o.do_features && section_features(&c, err, sizeof err));
        free_sets(&c);
        free(padded);
        rtk_mesh_free(&m);
        if (bad) {
            fprintf(stderr, "rtktool bench: %s\n", err);
            goto done;
        }
        static const char *const charts[] = {"trace", "build", "accuracy"};
        const int on[] = {o.do_trace, o.do_build, o.do_accuracy};
        for (int k = 0; k < 3; k++) {
            if (!on[k])
                continue;
            char name[200];
            snprintf(name, sizeof name, "%s-%s", c.stem, charts[k]);
            if (gnuplot && run_gnuplot(o.outdir, name))
                printf("chart: %s/%s.png\n", o.outdir, name);
            else
                printf("chart: %s/%s.gp not drawn (%s)\n", o.outdir, name,
                       gnuplot ? "gnuplot failed, see the .gp.log beside it" : "gnuplot is not installed");
        }
    }
    if (o.do_closed) {
        c.m = NULL;
        c.csv = (out){csv, "procedural:closed"};
        if (section_closed(&c, err, sizeof err)) {
            fprintf(stderr, "rtktool bench: %s\n", err);
            goto done;
        }
        if (gnuplot && run_gnuplot(o.outdir, "closed-accuracy"))
            printf("chart: %s/closed-accuracy.png\n", o.outdir);
        else
            printf("chart: %s/closed-accuracy.gp not drawn (%s)\n", o.outdir,
                   gnuplot ? "gnuplot failed, see the .gp.log beside it" : "gnuplot is not installed");
    }
    printf("\ncsv: %s/bench.csv\n", o.outdir);
    rc = 0;
done:
    fclose(csv);
    for (int l = 0; l < c.nlibs; l++)
        lib_close(&c.libs[l]);
    return rc;
}
