/* Every crossing along a ray, and inside or outside (rtk.h:
 * rtk_count_intersections, rtk_list_intersections, rtk_occupancy,
 * rtk_occupancy_arrays): each
 * ray traced once through the width-1 kernels with the query's filter
 * (rtk_query.filter) collecting every candidate and rejecting it, so the
 * walk goes on to the ray's tfar; then the crossings sorted by t, and a
 * triangle met twice at the same t (spatial splits put one in several
 * leaves) kept once.  User geometry's callbacks offer their hits
 * (rtk_user_offer_hit, geometry.c) to the same filter.  Over the device's
 * threads, as the batches of rays. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "scene_internal.h"

/* One ray's crossings, as the filter finds them. */
typedef struct collector {
    rtk_query_context ctx; /* ctx.user = the collector: what the filter sees */
    rtk_crossing *c;
    size_t n, cap;
    int oom;
    uint32_t unoffered; /* a user geometry whose callback reported a hit it had not offered: its geomID + 1 */
} collector;

static int collect(const rtk_filter_args *a)
{
    collector *k = a->context->user;
    if (k->n == k->cap) {
        const size_t cap = k->cap ? 2 * k->cap : 64;
        rtk_crossing *c = realloc(k->c, cap * sizeof *c);
        if (!c) {
            k->oom = 1;
            return 0;
        }
        k->c = c;
        k->cap = cap;
    }
    const rtk_hit *h = a->hit;
    k->c[k->n++] = (rtk_crossing){.t = a->t, .u = h->u, .v = h->v, .Ng_x = h->Ng_x, .Ng_y = h->Ng_y,
                                  .Ng_z = h->Ng_z, .primID = h->primID, .geomID = h->geomID, .instID = h->instID};
    return 0; /* rejected: the walk goes on */
}

void crossings_unoffered(const rtk_query *q, uint32_t geom_id)
{
    if ((q->flags & RTK_QUERY_FLAG_FILTER) && q->filter == collect && q->context) {
        collector *k = q->context->user;
        k->unoffered = geom_id + 1;
    }
}

static int by_t(const void *x, const void *y)
{
    const rtk_crossing *a = x, *b = y;
    if (a->t != b->t)
        return a->t < b->t ? -1 : 1;
    if (a->instID != b->instID)
        return a->instID < b->instID ? -1 : 1;
    if (a->geomID != b->geomID)
        return a->geomID < b->geomID ? -1 : 1;
    return a->primID < b->primID ? -1 : a->primID > b->primID;
}

/* Ray r's crossings within [tnear, tfar] into k (sorted, each once); 0
 * for a ray that is not valid (none then). */
static int crossings1(rtk_scene s, const rtk_ray *r, collector *k)
{
    k->n = 0;
    rtk_rayhit rh = {.ray = *r};
    rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
    const int cls = ray_check(&rh.ray);
    if (cls == RAY_INVALID)
        return 0;
    const rtk_query q = {.context = &k->ctx, .inst_id = RTK_INVALID_GEOMETRY_ID, .flags = RTK_QUERY_FLAG_FILTER,
                         .filter = collect};
    double shift = 0.0, scale = 1.0;
    if (cls == RAY_PLAIN)
        s->intersect1(s->accel, &rh, &q);
    else
        range_intersect1_map(s, &rh, &q, &shift, &scale);
    if (cls != RAY_PLAIN)
        for (size_t i = 0; i < k->n; i++) { /* the traced ray's t back to the given one's */
            const float t = (float)((double)k->c[i].t / scale + shift);
            k->c[i].t = t < r->tnear ? r->tnear : t > r->tfar ? r->tfar : t;
        }
    if (k->n > 1)
        qsort(k->c, k->n, sizeof *k->c, by_t);
    size_t m = 0;
    for (size_t i = 0; i < k->n; i++)
        if (!m || by_t(&k->c[i], &k->c[m - 1]))
            k->c[m++] = k->c[i];
    k->n = m;
    return 1;
}

/* ---- the checks ---- */

static rtk_error scene_check(rtk_scene s, const char *fn)
{
    const rtk_error err = geometry_query_check(s, fn);
    if (err)
        return err;
    const rtk_backend_desc *bk = s->device->backend;
    if (!RTK_DESC_HAS(bk, caps) || !(bk->caps & RTK_BACKEND_CAP_QUERY_FILTER))
        return rtk_fail(s->device, RTK_ERROR_UNSUPPORTED,
                        "%s: backend %s cannot collect every crossing (it predates query filters)", fn, bk->name);
    return RTK_OK;
}

/* ---- over the device's threads ---- */

#define CROSSING_PIECE 1024

enum { JOB_COUNT, JOB_LIST, JOB_OCCUPANCY };

typedef struct crossing_job {
    rtk_scene scene;
    int kind;
    const char *rays; /* JOB_COUNT, JOB_LIST */
    size_t stride;
    point_src src; /* JOB_OCCUPANCY: the points, records or arrays */
    size_t count;
    uint32_t *counts;
    const uint64_t *offsets;
    rtk_crossing *out;
    uint8_t *inside;
    atomic_int oom;
    atomic_size_t short_ray; /* JOB_LIST: the first ray with more crossings than room, + 1 */
    atomic_uint unoffered;   /* collector.unoffered, of any range */
} crossing_job;

/* The direction occupancy's rays take: none of a mesh's usual planes
 * (axis-aligned, diagonal) holds it. */
static const float occupancy_dir[3] = {0.80178373f, 0.53452248f, 0.26726124f};

/* The crossings of occupancy's ray from the float point o into k. */
static void occupancy_ray(rtk_scene s, const float o[3], float time, collector *k)
{
    const rtk_ray r = {.org_x = o[0], .org_y = o[1], .org_z = o[2], .tnear = 0.0f, .dir_x = occupancy_dir[0],
                       .dir_y = occupancy_dir[1], .dir_z = occupancy_dir[2], .time = time, .tfar = INFINITY,
                       .mask = ~0u};
    crossings1(s, &r, k);
}

/* The surface's nearest point to p within radius, at time, into *h: 1, or
 * 0 for none. */
static int surface_within(rtk_scene s, const double p[3], double radius, float time, rtk_point_hit *h)
{
    const rtk_point_query q = {.x = p[0], .y = p[1], .z = p[2], .radius = radius, .time = time};
    closest_point1(s, &q, h);
    return h->geomID != RTK_INVALID_GEOMETRY_ID;
}

/* The most steps away from the surface (each at least ~1.8x further from
 * it, where it is not thinner than that): from 2^-44 of a coordinate's
 * magnitude to float's ulps takes about 40. */
#define OCCUPANCY_STEPS 64

/* Whether point p lies inside the surface or on it (rtk.h: rtk_occupancy).
 *
 * The parity of a ray's crossings from the point as a float, pf, is exact
 * for pf (robust mode, a closed mesh).  It is p's answer too unless the
 * surface passes between them: when p is not pf (a double between
 * floats), p's distance from the surface is measured, and only when that
 * is within |p - pf| is more needed.  Then (and when pf's ray meets the
 * surface at t = 0 without p lying on it) the answer is found further
 * from the surface: the ball around a point with its distance as radius
 * holds no surface, so a step within it (0.9 of the distance, straight
 * away from the nearest point, which makes the distance grow) stays on
 * the same side; steps are taken until a point's float lies within its
 * ball, and that float gets the parity.  A surface thinner than a few
 * ulps of float there (the steps do not get away) leaves pf's answer; a
 * point within 2^-44 of its coordinates' magnitude from the surface (the
 * double routine's own rounding) is on it. */
static int occupancy1(rtk_scene s, const rtk_point_query *pq, collector *k)
{
    const double p[3] = {pq->x, pq->y, pq->z};
    const float pf[3] = {(float)pq->x, (float)pq->y, (float)pq->z};
    double r2 = 0.0;
    for (int a = 0; a < 3; a++)
        r2 += (p[a] - pf[a]) * (p[a] - pf[a]);
    occupancy_ray(s, pf, pq->time, k);
    const int odd = (int)(k->n & 1), at_zero = k->n && k->c[0].t == 0.0f;
    const int float_rule = odd || at_zero;
    if (!s->closest_point)
        return float_rule;
    rtk_point_hit h;
    if (r2 == 0.0) {
        if (odd && !at_zero)
            return 1;
        /* On the surface counts as inside.  A ray from a vertex or an edge
         * that leaves the surface there may cross nothing at 0 (the
         * watertight test decides it as moved off the edge): a closest
         * point within radius 0, which visits only the boxes holding the
         * point. */
        if (surface_within(s, p, 0.0, pq->time, &h))
            return 1;
        if (!at_zero)
            return 0;
    } else if (!at_zero && !surface_within(s, p, sqrt(r2) * (1.0 + 0x1p-20), pq->time, &h))
        return odd;
    /* within rounding of the surface */
    if (!surface_within(s, p, INFINITY, pq->time, &h))
        return float_rule;
    const double c[3] = {h.x, h.y, h.z}, d = h.distance;
    double m = 0.0;
    for (int a = 0; a < 3; a++)
        m = fmax(m, fmax(fabs(c[a]), fabs(p[a])));
    /* on the surface as far as double can tell (a double point on an edge
     * is measured a few ulps of double off it): inside */
    if (d <= m * 0x1p-44)
        return 1;
    /* walk away from the surface, each step within the last point's empty
     * ball (0.9 of its distance, straight away from its nearest point),
     * until a point's float lies within its own ball */
    double q[3] = {p[0], p[1], p[2]}, cq[3] = {c[0], c[1], c[2]}, dq = d;
    float qf[3];
    for (int step = 0;; step++) {
        double rq2 = 0.0;
        for (int a = 0; a < 3; a++) {
            qf[a] = (float)q[a];
            rq2 += (q[a] - qf[a]) * (q[a] - qf[a]);
        }
        if (rq2 < 0.81 * dq * dq)
            break;
        if (step == OCCUPANCY_STEPS)
            return float_rule; /* a surface thinner than a few ulps of float there */
        for (int a = 0; a < 3; a++)
            q[a] += (q[a] - cq[a]) * 0.9;
        if (!surface_within(s, q, INFINITY, pq->time, &h))
            return float_rule;
        cq[0] = h.x, cq[1] = h.y, cq[2] = h.z, dq = h.distance;
        if (!(dq > 0.0))
            return float_rule;
    }
    occupancy_ray(s, qf, pq->time, k);
    return k->n && k->c[0].t == 0.0f ? float_rule : (int)(k->n & 1);
}

static void crossing_range(crossing_job *j, size_t begin, size_t end)
{
    collector k = {.c = NULL};
    k.ctx.user = &k;
    for (size_t i = begin; i < end; i++) {
        if (j->kind == JOB_OCCUPANCY) {
            rtk_point_query pa;
            const rtk_point_query *p = point_src_query(&j->src, i, &pa);
            if (point_fault(p)) {
                j->inside[i] = RTK_OCCUPANCY_INVALID;
                continue;
            }
            const int in = occupancy1(j->scene, p, &k);
            j->inside[i] = (uint8_t)in;
            continue;
        }
        const rtk_ray *r = (const rtk_ray *)(j->rays + i * j->stride);
        if (!crossings1(j->scene, r, &k))
            k.n = 0;
        if (j->kind == JOB_COUNT) {
            j->counts[i] = k.n > UINT32_MAX ? UINT32_MAX : (uint32_t)k.n;
            continue;
        }
        const uint64_t room = j->offsets[i + 1] - j->offsets[i];
        const size_t n = k.n < room ? k.n : (size_t)room;
        if (n)
            memcpy(j->out + j->offsets[i], k.c, n * sizeof *k.c);
        if (k.n > room) {
            size_t none = 0;
            atomic_compare_exchange_strong(&j->short_ray, &none, i + 1);
        }
    }
    if (k.oom)
        atomic_store(&j->oom, 1);
    if (k.unoffered)
        atomic_store(&j->unoffered, k.unoffered);
    free(k.c);
}

static void crossing_piece(void *data, uint32_t index)
{
    crossing_job *j = data;
    const size_t begin = (size_t)index * CROSSING_PIECE;
    crossing_range(j, begin, j->count - begin < CROSSING_PIECE ? j->count : begin + CROSSING_PIECE);
}

static rtk_error run(crossing_job *j, const char *fn)
{
    const size_t pieces = (j->count + CROSSING_PIECE - 1) / CROSSING_PIECE;
    if (pieces > UINT32_MAX)
        return rtk_fail(j->scene->device, RTK_ERROR_INVALID_ARGUMENT, "%s: %zu queries are more than a batch takes",
                        fn, j->count);
    rtk_device_for(j->scene->device, (uint32_t)pieces, crossing_piece, j);
    if (atomic_load(&j->oom))
        return rtk_fail(j->scene->device, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory collecting crossings", fn);
    const unsigned unoffered = atomic_load(&j->unoffered);
    if (unoffered)
        return rtk_fail(j->scene->device, RTK_ERROR_UNSUPPORTED,
                        "%s: the intersect callback of user geometry %u reported a hit it had not offered to "
                        "rtk_user_offer_hit, so rtk cannot collect that geometry's crossings (rtk.h: user geometry)",
                        fn, unoffered - 1);
    const size_t short_ray = atomic_load(&j->short_ray);
    if (short_ray)
        return rtk_fail(j->scene->device, RTK_ERROR_INVALID_ARGUMENT,
                        "%s: ray %zu has more crossings than offsets give it room for (offsets must come from "
                        "rtk_count_intersections on the same rays)",
                        fn, short_ray - 1);
    return RTK_OK;
}

rtk_error rtk_count_intersections(rtk_scene s, const rtk_ray *rays, size_t count, size_t byte_stride,
                                  uint32_t *counts)
{
    static const char fn[] = "rtk_count_intersections";
    rtk_error err = scene_check(s, fn);
    if (!err)
        err = array_check(s, rays, count, byte_stride, sizeof *rays, "rays", fn);
    if (!err && count && !counts)
        err = rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: counts is NULL (count %zu)", fn, count);
    if (err || !count)
        return err;
    crossing_job j = {.scene = s, .kind = JOB_COUNT, .rays = (const char *)rays, .stride = byte_stride,
                      .count = count, .counts = counts};
    return run(&j, fn);
}

rtk_error rtk_list_intersections(rtk_scene s, const rtk_ray *rays, size_t count, size_t byte_stride,
                                 const uint64_t *offsets, rtk_crossing *crossings)
{
    static const char fn[] = "rtk_list_intersections";
    rtk_error err = scene_check(s, fn);
    if (!err)
        err = array_check(s, rays, count, byte_stride, sizeof *rays, "rays", fn);
    if (!err && count && !offsets)
        err = rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: offsets is NULL (count %zu)", fn, count);
    if (err || !count)
        return err;
    for (size_t i = 0; i < count; i++)
        if (offsets[i + 1] < offsets[i])
            return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: offsets[%zu] > offsets[%zu]", fn, i, i + 1);
    if (offsets[count] > offsets[0] && !crossings)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: crossings is NULL", fn);
    crossing_job j = {.scene = s, .kind = JOB_LIST, .rays = (const char *)rays, .stride = byte_stride,
                      .count = count, .offsets = offsets, .out = crossings};
    return run(&j, fn);
}

rtk_error rtk_occupancy(rtk_scene s, const rtk_point_query *points, size_t count, uint8_t *inside)
{
    static const char fn[] = "rtk_occupancy";
    rtk_error err = scene_check(s, fn);
    if (!err && s->ref->user_deep) /* its distances needed near the surface */
        err = closest_point_check(s, fn);
    if (!err)
        err = array_check(s, points, count, sizeof *points, sizeof *points, "points", fn);
    if (!err && count && !inside)
        err = rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: inside is NULL (count %zu)", fn, count);
    if (err || !count)
        return err;
    crossing_job j = {.scene = s, .kind = JOB_OCCUPANCY, .src = {.q = points}, .count = count, .inside = inside};
    return run(&j, fn);
}

rtk_error rtk_occupancy_arrays(rtk_scene s, const rtk_point_arrays *a, size_t count)
{
    static const char fn[] = "rtk_occupancy_arrays";
    point_src src;
    rtk_error err = point_arrays_check(s, a, count, &src, fn);
    if (!err)
        err = scene_check(s, fn);
    if (!err && s->ref->user_deep) /* its distances needed near the surface */
        err = closest_point_check(s, fn);
    if (!err && count && !a->inside)
        err = rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: inside is NULL (count %zu)", fn, count);
    if (err || !count)
        return err;
    crossing_job j = {.scene = s, .kind = JOB_OCCUPANCY, .src = src, .count = count, .inside = a->inside};
    return run(&j, fn);
}
