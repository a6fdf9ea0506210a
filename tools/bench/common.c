/* The libraries under test and their scenes, the ray sets, tracing a set on
 * threads, and the output: what every section of rtktool bench uses. */
#include <math.h>
#include <pthread.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bench_internal.h"

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

double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ---- Embree as a render_tracer ---- */

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

/* Embree 3's streams, with the target's context flags (incoherent but for
 * the coherent target the bench never gives them) */
static void e_i1M(void *s, rtk_rayhit *rh, unsigned n, size_t stride)
{
    const embree_target *e = s;
    struct RTCIntersectContext c;
    rtcInitIntersectContext(&c);
    c.flags = e->flags;
    rtcIntersect1M(e->scene, &c, (struct RTCRayHit *)rh, n, stride);
}
static void e_o1M(void *s, rtk_ray *r, unsigned n, size_t stride)
{
    const embree_target *e = s;
    struct RTCIntersectContext c;
    rtcInitIntersectContext(&c);
    c.flags = e->flags;
    rtcOccluded1M(e->scene, &c, (struct RTCRay *)r, n, stride);
}

static render_tracer embree_tracer(embree_target *e)
{
    return (render_tracer){e, e_i1, e_o1, e_i4, e_o4, e_i8, e_o8, e_i16, e_o16, e_i1M, e_o1M};
}

/* ---- the libraries under test ---- */

/* MODE_REBUILD: a scene built again every frame: Embree's flagged dynamic
 * (its documented setting for that: better build performance), rtk's the
 * default (one tree, built again in its old memory). */
/* MODE_MASK: the geometry's mask set to 1 (the rays' is all ones, so every
 * hit passes); MODE_MASKS2: the mesh as two geometries, its first half of
 * triangles with mask 1 and the rest with mask 2 (the rays pass both, but
 * no bit is in every geometry's mask, so rtk tests each candidate's);
 * MODE_FILTER: intersection and occlusion filters that accept every
 * candidate.  The same hits as the default, so what they cost. */
const char *const mode_names[] = {"default", "compact", "robust", "refit",  "mask",
                                         "filter",  "quad",    "masks2", "rebuild"};

quad_list bench_quads; /* of the mesh section_features measures */

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
int bench_collect;

seen_list bench_seen;

float bench_t_limit = 1.0f + 1e-4f; /* the closed section: each ray's distance to its point inside */

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

long long embree_bytes; /* Embree's memory monitor: allocations minus frees */

static bool embree_monitor(void *user, ssize_t bytes, bool post)
{
    (void)user;
    (void)post;
    __atomic_add_fetch(&embree_bytes, (long long)bytes, __ATOMIC_RELAXED);
    return true;
}

int lib_open(lib *l, const char *name, int embree, const char *config, int threads, char *err,
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

void lib_close(lib *l)
{
    if (l->edev)
        rtcReleaseDevice(l->edev);
    rtk_device_release(l->rdev);
    memset(l, 0, sizeof *l);
}

/* Commits Embree's scene s into sc, timed from t0 (the first scene call);
 * when the device reports an error, releases it and says `what` failed. */
int embree_commit(scene *sc, RTCScene s, double t0, const char *what, char *err, size_t err_size)
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
int rtk_commit(scene *sc, rtk_scene s, int bad, double t0, char *err, size_t err_size)
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
int embree_mesh_commit(scene *sc, RTCScene s, RTCGeometry g, const rtk_mesh *m, int quads, double t0,
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
int rtk_mesh_commit(scene *sc, rtk_scene s, rtk_geometry g, const rtk_mesh *m, int quads, int bad, double t0,
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
int scene_build(scene *sc, lib *l, const rtk_mesh *m, const float *padded, int mode, int quality, char *err,
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

void scene_release(scene *sc)
{
    if (sc->escene)
        rtcReleaseScene(sc->escene);
    rtk_scene_release(sc->rscene);
    memset(sc, 0, sizeof *sc);
}

render_tracer scene_tracer(scene *sc, int coherent)
{
    return sc->lib->embree ? embree_tracer(&sc->target[coherent]) : render_tracer_rtk(sc->rscene);
}

/* ---- ray sets ---- */

const char *const set_names[NSETS] = {"primary", "diffuse", "shadow", "incoherent", "sun"};

const int apis[NAPIS] = {1, 4, 8, 16, RENDER_API_STREAM};

int api_on(const bench_opts *o, int api)
{
    for (int k = 0; k < NAPIS; k++)
        if (apis[k] == api)
            return o->api_on[k];
    return 0;
}

static uint64_t xs_state = 0x9e3779b97f4a7c15ull;

float rnd_from(uint64_t *state)
{
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    return (float)(*state >> 40) * 0x1p-24f;
}

float rnd(void)
{
    return rnd_from(&xs_state);
}

/* Camera rays in 4x4 pixel blocks, ordered so that every 4 consecutive
 * rays are a 2x2 block, every 8 a 4x2 and every 16 a 4x4: packets of any
 * width are compact.  The camera looks at the bounding box's centre from
 * the front-right-above, framing the box's middle so that most rays hit. */
void make_primary(const rtk_mesh *m, int w, int h, rayset *set)
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
void tri_normal(const rtk_mesh *m, uint32_t t, double n[3])
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
    rtk_rayhit *stream; /* the stream API: room for the job's rays */
} job;

/* The job's rays as one stream: written into the array, traced in one
 * call, read back (as an application would). */
static void run_stream(const job *j)
{
    const size_t n = j->end - j->begin;
    for (size_t i = 0; i < n; i++)
        j->stream[i] = (rtk_rayhit){.ray = j->set->rays[j->begin + i],
                                    .hit = {.geomID = RTK_INVALID_GEOMETRY_ID, .instID = RTK_INVALID_GEOMETRY_ID}};
    if (j->occluded)
        j->t.occluded1M(j->t.scene, &j->stream[0].ray, (unsigned)n, sizeof *j->stream);
    else
        j->t.intersect1M(j->t.scene, j->stream, (unsigned)n, sizeof *j->stream);
    for (size_t i = 0; i < n; i++)
        j->hits[j->begin + i] = j->occluded ? j->stream[i].ray.tfar == -INFINITY
                                            : j->stream[i].hit.geomID != RTK_INVALID_GEOMETRY_ID;
}

static void *run_job(void *arg)
{
    const job *j = arg;
    if (j->api == RENDER_API_STREAM) {
        run_stream(j);
        return NULL;
    }
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
double trace_pass(const render_tracer *t, const rayset *set, int api, int occluded, int threads,
                  unsigned char *hits)
{
    job jobs[16];
    pthread_t tid[16];
    const size_t share = (set->n / 16 + (size_t)threads - 1) / (size_t)threads * 16;
    /* the stream API's arrays, made before the clock starts (the rays
     * are written into them on it) */
    rtk_rayhit *stream = api == RENDER_API_STREAM ? malloc((share ? share : 1) * (size_t)threads * sizeof *stream) : NULL;
    if (api == RENDER_API_STREAM && !stream)
        return -1.0;
    for (int k = 0; k < threads; k++) {
        const size_t b = (size_t)k * share, e = b + share;
        jobs[k] = (job){*t, set, api, occluded, hits, b < set->n ? b : set->n, e < set->n ? e : set->n,
                        stream ? stream + (size_t)k * share : NULL};
    }
    const double t0 = now();
    int started = 1;
    for (; started < threads; started++)
        if (pthread_create(&tid[started], NULL, run_job, &jobs[started]))
            break;
    run_job(&jobs[0]);
    for (int k = 1; k < started; k++)
        pthread_join(tid[k], NULL);
    for (int k = started; k < threads; k++)
        run_job(&jobs[k]);
    const double el = now() - t0;
    free(stream);
    return el;
}

/* Mrays/s, best of `repeat` passes; hits[i]: ray i hit. */
double trace_set(const render_tracer *t, const rayset *set, int api, int occluded, int threads, int repeat,
                 unsigned char *hits)
{
    double best = 1e30;
    for (int r = 0; r < repeat; r++) {
        const double el = trace_pass(t, set, api, occluded, threads, hits);
        best = el < best ? el : best;
    }
    return (double)set->n / best * 1e-6;
}

/* ---- output ---- */

void csv_row(const out *o, const char *section, const char *library, const char *variant, const char *set,
             const char *api, int threads, double value, const char *unit, double ratio)
{
    fprintf(o->csv, "%s,%s,%s,%s,%s,%s,%d,%.6g,%s,", o->mesh, section, library, variant, set, api, threads, value,
            unit);
    if (ratio > 0)
        fprintf(o->csv, "%.4f", ratio);
    fprintf(o->csv, "\n");
}

const char *base_name(const char *path)
{
    const char *s = strrchr(path, '/');
    return s ? s + 1 : path;
}

/* The mesh's name without directory and extension, for file names. */
void mesh_stem(const char *path, char *stem, size_t size)
{
    snprintf(stem, size, "%s", base_name(path));
    char *dot = strrchr(stem, '.');
    if (dot && dot != stem && strncmp(stem, "procedural:", 11))
        *dot = 0;
    for (char *c = stem; *c; c++)
        if (*c == ':' || *c == '.')
            *c = '-';
}

/* ---- settings ---- */

/* ---- the sections ---- */

/* The ray sets of a mesh: camera rays, then the secondary rays from the
 * hits Embree isa=avx2 (the first library) finds. */
int make_sets(ctx *c, char *err, size_t err_size)
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

void free_sets(ctx *c)
{
    for (int s = 0; s < NSETS; s++) {
        free(c->sets[s].rays);
        c->sets[s] = (rayset){NULL, 0, NULL};
    }
}

double ratio(double v, double ref)
{
    return ref > 0 ? v / ref : 0.0;
}

void print_row_label(const char *label)
{
    printf("  %-20s", label);
}

void print_cell(double v, double ref, int is_ref)
{
    if (is_ref)
        printf(" %8.2f        ", v);
    else
        printf(" %8.2f (%4.2fx)", v, ratio(v, ref));
}

void print_header(const ctx *c)
{
    print_row_label("");
    for (int l = 0; l < c->nlibs; l++)
        printf(" %-16s", c->libs[l].name);
    printf("\n");
}

/* The mesh twisted about its vertical (y) axis, by up to t radians at the
 * top: the smooth motion of an animation.  dst has the mesh's layout. */
void twist(const rtk_mesh *m, float t, float *dst)
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
void vertices_commit(scene *sc)
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

int cmp_double(const void *x, const void *y)
{
    const double a = *(const double *)x, b = *(const double *)y;
    return a < b ? -1 : a > b;
}

int attach_instance(const lib *l, RTCScene es, rtk_scene rs, const scene *child, const float xfm[12])
{
    if (l->embree) {
        RTCGeometry g = rtcNewGeometry(l->edev, RTC_GEOMETRY_TYPE_INSTANCE);
        rtcSetGeometryInstancedScene(g, child->escene);
        rtcSetGeometryTransform(g, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, xfm);
        rtcCommitGeometry(g);
        rtcAttachGeometry(es, g);
        rtcReleaseGeometry(g);
        return 0;
    }
    rtk_geometry g = NULL;
    const int bad = rtk_geometry_new(l->rdev, RTK_GEOMETRY_TYPE_INSTANCE, &g) ||
                    rtk_geometry_set_instanced_scene(g, child->rscene) ||
                    rtk_geometry_set_transform(g, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, xfm) || rtk_geometry_commit(g) ||
                    rtk_scene_attach_geometry(rs, g, NULL);
    rtk_geometry_release(g);
    return bad;
}

void diffuse_settings(render_settings *rs, const bench_opts *o, const float lo[3], const float hi[3], int threads)
{
    render_defaults(rs, lo, hi, o->render_w, o->render_h);
    rs->mode = RENDER_DIFFUSE;
    rs->spp = o->render_spp;
    rs->threads = threads;
    rs->api = 1;
}

double diffuse_pass(const render_tracer *t, const render_settings *rs, float *rgb, double *hit_share, char *err,
                    size_t err_size)
{
    render_stats st;
    if (render_image(t, rs, rgb, &st, err, err_size))
        return -1;
    if (hit_share)
        *hit_share = st.primary ? (double)st.primary_hits / (double)st.primary : 0;
    return (double)render_stats_rays(&st) / st.seconds * 1e-6;
}
