/* Closest points (rtk.h: rtk_closest_point, rtk_closest_point_batch,
 * rtk_closest_point_arrays): the checks, the result's defaults, and
 * batches over the device's threads, of records or of an application's
 * arrays; the walk itself is the backend's (backends/common/point_query.c). */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "scene_internal.h"

rtk_error geometry_query_check(rtk_scene s, const char *fn)
{
    if (!s)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "%s: scene is NULL", fn);
    if (scene_not_committing(s, fn))
        return RTK_ERROR_INVALID_OPERATION;
    if (!s->accel)
        return rtk_fail(s->device, RTK_ERROR_INVALID_OPERATION, "%s: the scene was never committed", fn);
    return RTK_OK;
}

rtk_error closest_point_check(rtk_scene s, const char *fn)
{
    const rtk_error err = geometry_query_check(s, fn);
    if (err)
        return err;
    const rtk_backend_desc *bk = s->device->backend;
    if (s->ref->user_pointless_deep)
        return rtk_fail(s->device, RTK_ERROR_UNSUPPORTED,
                        "%s: the scene has user geometry without a point query function (%llu primitives, in it or "
                        "in the scenes it instances; rtk_geometry_set_point_query_function)",
                        fn, (unsigned long long)s->ref->user_pointless_deep);
    if (s->ref->user_deep && !(RTK_DESC_HAS(bk, caps) && (bk->caps & RTK_BACKEND_CAP_USER_POINTS)))
        return rtk_fail(s->device, RTK_ERROR_UNSUPPORTED,
                        "%s: the scene has user geometry, and backend %s predates closest points on it", fn,
                        bk->name);
    if (!s->closest_point)
        return rtk_fail(s->device, RTK_ERROR_UNSUPPORTED,
                        "%s: backend %s has no closest-point kernel for layout %s (it predates them)", fn,
                        s->device->backend->name, s->layout->name);
    return RTK_OK;
}

const char *point_fault(const rtk_point_query *q)
{
    if (!point_in_range(q))
        return "the point is not finite or lies beyond +-2^64";
    if (!(q->time >= 0.0f && q->time <= 1.0f))
        return "the time is outside [0, 1]";
    return NULL;
}

/* Why a closest-point query is not valid (rtk.h), or NULL. */
static const char *query_fault(const rtk_point_query *q)
{
    const char *fault = point_fault(q);
    if (fault)
        return fault;
    if (!(q->radius >= 0.0))
        return "the radius is negative or NaN";
    if (q->reserved)
        return "reserved is not 0";
    return NULL;
}

static void no_result(rtk_point_hit *r, double distance)
{
    *r = (rtk_point_hit){.x = NAN, .y = NAN, .z = NAN, .distance = distance, .u = NAN, .v = NAN,
                             .primID = RTK_INVALID_GEOMETRY_ID, .geomID = RTK_INVALID_GEOMETRY_ID,
                             .instID = RTK_INVALID_GEOMETRY_ID};
}

/* One checked query into *r, given a point of the surface at the query's
 * time (hint, or NULL): its distance, raised by far more than its
 * rounding, bounds the answer's from above, and the walk starts with that
 * bound instead of the radius.  The answer is the same either way: no
 * box holding a triangle at the least distance is left out with either
 * bound, and of those triangles the kernel keeps the one of least ids
 * whatever order it meets them in.  Should the raised bound still fall
 * short, the query runs again from the radius. */
static void closest_hinted(rtk_scene s, const rtk_point_query *q, rtk_point_hit *r, const double *hint)
{
    no_result(r, INFINITY);
    rtk_point_state st = {.p = {q->x, q->y, q->z}, .best2 = q->radius * q->radius, .time = q->time, .result = r};
    if (q->radius == INFINITY)
        st.best2 = INFINITY;
    const double radius2 = st.best2;
    if (hint) {
        /* (everything finite here: comparisons, where fmax and fmin were
         * library calls) */
        double d2 = 0.0, mag = 0.0;
        for (int a = 0; a < 3; a++) {
            const double g = hint[a] - st.p[a], h = fabs(hint[a]), p = fabs(st.p[a]);
            d2 += g * g;
            mag = h > mag ? h : mag;
            mag = p > mag ? p : mag;
        }
        const double up = sqrt(d2) * (1.0 + 0x1p-30) + mag * 0x1p-30;
        st.best2 = up * up < st.best2 ? up * up : st.best2;
    }
    const rtk_query rq = {.context = NULL, .inst_id = RTK_INVALID_GEOMETRY_ID,
                          .flags = s->ref->user_deep ? RTK_QUERY_FLAG_USER_POINT : 0u,
                          .user_point = s->ref->user_deep ? user_point : NULL};
    s->closest_point(s->accel, &st, &rq);
    if (r->geomID == RTK_INVALID_GEOMETRY_ID && st.best2 < radius2) {
        st.best2 = radius2;
        s->closest_point(s->accel, &st, &rq);
    }
    if (r->geomID != RTK_INVALID_GEOMETRY_ID)
        r->distance = sqrt(st.best2);
}

/* One checked query into *r (scene_internal.h). */
void closest_point1(rtk_scene s, const rtk_point_query *q, rtk_point_hit *r) { closest_hinted(s, q, r, NULL); }

rtk_error rtk_closest_point(rtk_scene s, const rtk_point_query *query, rtk_point_hit *result)
{
    static const char fn[] = "rtk_closest_point";
    if (!query || !result)
        return rtk_fail(s ? s->device : NULL, RTK_ERROR_INVALID_ARGUMENT, "%s: %s is NULL", fn,
                        query ? "result" : "query");
    const rtk_error err = closest_point_check(s, fn);
    if (err)
        return err;
    const char *fault = query_fault(query);
    if (fault)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: %s", fn, fault);
    closest_point1(s, query, result);
    return RTK_OK;
}

/* ---- batches over the device's threads ---- */

/* Queries per task: enough to pay for a task's hand-over many times over,
 * few enough that two threads share a batch of a few thousand. */
#define POINT_PIECE 1024
/* Queries put in order at a time (point_order.c): 16 MB of ordering, and
 * neighbours along the curve close enough to share what is in cache. */
#define POINT_WINDOW ((size_t)1 << 20)
/* Batches smaller than this are walked as they come. */
#define POINT_ORDER_MIN 64

typedef struct point_job {
    rtk_scene scene;
    point_src src;              /* the window's points: records (src.q) or arrays */
    rtk_point_hit *results;     /* the window's results, with records */
    const rtk_point_arrays *a;  /* with arrays: where the answers go (rtk_closest_point_arrays) */
    size_t first;               /* the window's first point in a's arrays */
    const uint32_t *order; /* the walk's order of queries [0, count), or NULL: as they come */
    size_t count;
} point_job;

/* Answers kept as hints: the nearest of the last few to each query. */
#define POINT_HINTS 16

/* Point k's answer into the arrays (rtk.h: rtk_point_arrays). */
static void point_store(const rtk_point_arrays *a, size_t k, const rtk_point_hit *r)
{
    if (a->points_double) {
        if (a->distances)
            ((double *)a->distances)[k] = r->distance;
        if (a->closest) {
            double *c = (double *)a->closest + 3 * k;
            c[0] = r->x, c[1] = r->y, c[2] = r->z;
        }
    } else {
        if (a->distances)
            ((float *)a->distances)[k] = (float)r->distance;
        if (a->closest) {
            float *c = (float *)a->closest + 3 * k;
            c[0] = (float)r->x, c[1] = (float)r->y, c[2] = (float)r->z;
        }
    }
    if (a->geom_ids)
        a->geom_ids[k] = r->geomID;
    if (a->prim_ids)
        a->prim_ids[k] = r->primID;
    if (a->inst_ids)
        a->inst_ids[k] = r->instID;
    if (a->uvs)
        a->uvs[2 * k] = r->u, a->uvs[2 * k + 1] = r->v;
    if (a->normals)
        a->normals[3 * k] = r->n_x, a->normals[3 * k + 1] = r->n_y, a->normals[3 * k + 2] = r->n_z;
}

static void point_range(const point_job *j, size_t begin, size_t end)
{
    /* along the curve, the previous queries' answers are near: the nearest
     * of them is the hint */
    double ring[POINT_HINTS][3];
    int kept = 0, next = 0;
    float prev_time = 0.0f;
    for (size_t n = begin; n < end; n++) {
        const size_t i = j->order ? j->order[n] : n;
        if (j->order && n + 4 < end) {
            /* along the curve the queries are scattered through the array */
            const size_t ahead = j->order[n + 4];
            if (j->src.q) {
                __builtin_prefetch(&j->src.q[ahead]);
                __builtin_prefetch(&j->results[ahead], 1);
            } else
                __builtin_prefetch(j->src.p + ahead * j->src.stride);
        }
        rtk_point_query qa;
        rtk_point_hit ra;
        const rtk_point_query *q = point_src_query(&j->src, i, &qa);
        rtk_point_hit *r = j->src.q ? &j->results[i] : &ra;
        if (query_fault(q))
            no_result(r, NAN);
        else {
            if (kept && prev_time != q->time)
                kept = 0;
            const double *hint = NULL;
            double best = INFINITY;
            for (int k = 0; k < kept; k++) {
                const double dx = ring[k][0] - q->x, dy = ring[k][1] - q->y, dz = ring[k][2] - q->z;
                const double d2 = dx * dx + dy * dy + dz * dz;
                if (d2 < best) {
                    best = d2;
                    hint = ring[k];
                }
            }
            closest_hinted(j->scene, q, r, hint);
            if (j->order && r->geomID != RTK_INVALID_GEOMETRY_ID) {
                ring[next][0] = r->x, ring[next][1] = r->y, ring[next][2] = r->z;
                next = (next + 1) % POINT_HINTS;
                kept += kept < POINT_HINTS;
                prev_time = q->time;
            }
        }
        if (!j->src.q)
            point_store(j->a, j->first + i, r);
    }
}

static void point_piece(void *data, uint32_t index)
{
    const point_job *j = data;
    const size_t begin = (size_t)index * POINT_PIECE;
    point_range(j, begin, j->count - begin < POINT_PIECE ? j->count : begin + POINT_PIECE);
}

/* The batch's points window by window, each walked along its Morton
 * curve (or as it comes, for a small batch or when memory for the order
 * runs out): job holds the records (src.q, results) or the arrays (src,
 * a) of the whole batch. */
static void point_windows(point_job job, size_t count)
{
    const size_t window = count < POINT_WINDOW ? count : POINT_WINDOW;
    uint32_t *order = count >= POINT_ORDER_MIN ? malloc(window * sizeof *order) : NULL;
    const point_job all = job;
    for (size_t at = 0; at < count; at += window) {
        const size_t n = count - at < window ? count - at : window;
        job.count = n;
        job.order = NULL;
        if (all.src.q) {
            job.src.q = all.src.q + at;
            job.results = all.results + at;
        } else {
            job.first = at;
            job.src.p = all.src.p + at * all.src.stride;
        }
        if (order && !point_order(&job.src, n, order))
            job.order = order;
        rtk_device_for(job.scene->device, (uint32_t)((n + POINT_PIECE - 1) / POINT_PIECE), point_piece, &job);
    }
    free(order);
}

rtk_error rtk_closest_point_batch(rtk_scene s, const rtk_point_query *queries, rtk_point_hit *results,
                                  size_t count)
{
    static const char fn[] = "rtk_closest_point_batch";
    if (!s)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "%s: scene is NULL", fn);
    if (count && (!queries || !results))
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: %s is NULL (count %zu)", fn,
                        queries ? "results" : "queries", count);
    const rtk_error err = closest_point_check(s, fn);
    if (err || !count)
        return err;
    point_windows((point_job){.scene = s, .src = {.q = queries}, .results = results}, count);
    return RTK_OK;
}

rtk_error point_arrays_check(rtk_scene s, const rtk_point_arrays *a, size_t count, point_src *src, const char *fn)
{
    if (!s)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "%s: scene is NULL", fn);
    if (!a)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: arrays is NULL", fn);
    const size_t size = a->points_double ? 3 * sizeof(double) : 3 * sizeof(float);
    *src = (point_src){.p = a->points, .stride = a->point_stride ? a->point_stride : size,
                       .is_double = a->points_double != 0, .radius = a->radius, .time = a->time};
    const rtk_error err = array_check(s, a->points, count, src->stride, size, "points", fn);
    if (err)
        return err;
    if (count && a->points_double && (uintptr_t)a->points % 8)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT,
                        "%s: the points (double) at %p are not aligned to 8 bytes", fn, a->points);
    if (!(a->time >= 0.0f && a->time <= 1.0f))
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: time %g is outside [0, 1]", fn, (double)a->time);
    return RTK_OK;
}

rtk_error rtk_closest_point_arrays(rtk_scene s, const rtk_point_arrays *a, size_t count)
{
    static const char fn[] = "rtk_closest_point_arrays";
    point_src src;
    rtk_error err = point_arrays_check(s, a, count, &src, fn);
    if (!err && !(a->radius >= 0.0))
        err = rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT,
                       "%s: radius %g is negative or NaN (INFINITY: the whole surface)", fn, a->radius);
    if (!err)
        err = closest_point_check(s, fn);
    if (err || !count)
        return err;
    point_windows((point_job){.scene = s, .a = a, .src = src}, count);
    return RTK_OK;
}
