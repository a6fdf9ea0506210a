/* Geometries: triangle and quad meshes, user geometry, instances. */
#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "geometry/affine.h"
#include "scene_internal.h"
/* ---- geometry ---- */

static atomic_uint_fast64_t version_clock;

/* A buffer of g was set or its contents changed: a new version, and the
 * geometry must be committed again. */
static void buffer_changed(rtk_geometry g, rtk_buffer_type type)
{
    *(type == RTK_BUFFER_TYPE_VERTEX ? &g->vertex_version : &g->index_version) =
        (uint64_t)atomic_fetch_add(&version_clock, 1) + 1;
    g->committed = 0;
}

rtk_error rtk_geometry_new(rtk_device device, rtk_geometry_type type, rtk_geometry *out)
{
    CHECK_HANDLE(device, "rtk_geometry_new");
    if (!out)
        return rtk_fail(device, RTK_ERROR_INVALID_ARGUMENT, "rtk_geometry_new: out is NULL");
    *out = NULL;
    if (type != RTK_GEOMETRY_TYPE_TRIANGLE && type != RTK_GEOMETRY_TYPE_INSTANCE && type != RTK_GEOMETRY_TYPE_USER &&
        type != RTK_GEOMETRY_TYPE_QUAD)
        return rtk_fail(device, RTK_ERROR_INVALID_ARGUMENT, "rtk_geometry_new: unknown geometry type %d", (int)type);
    rtk_geometry g = calloc(1, sizeof *g);
    if (!g)
        return rtk_fail(device, RTK_ERROR_OUT_OF_MEMORY, "rtk_geometry_new: out of memory");
    atomic_init(&g->refs, 1);
    g->device = device;
    g->type = type;
    if (type == RTK_GEOMETRY_TYPE_INSTANCE) {
        memcpy(g->xfm, identity_3x4, sizeof g->xfm);
    }
    g->owners = &g->owner_one;
    g->owner_cap = 1;
    g->quality = RTK_BUILD_QUALITY_MEDIUM;
    g->enabled = 1;
    g->time_steps = 1;
    g->mask = ~0u;
    rtk_device_retain(device);
    *out = g;
    return RTK_OK;
}

void rtk_geometry_retain(rtk_geometry g)
{
    if (g)
        atomic_fetch_add(&g->refs, 1);
}

static void buffer_free(buffer *b)
{
    blob_release(b->owned);
    memset(b, 0, sizeof *b);
}

void rtk_geometry_release(rtk_geometry g)
{
    if (!g || atomic_fetch_sub(&g->refs, 1) != 1)
        return;
    if (is_mesh(g)) {
        buffer_free(&g->vertex);
        buffer_free(&g->index);
        for (unsigned k = 1; k < g->time_steps; k++)
            buffer_free(&g->steps[k - 1]);
        free(g->steps);
    }
    if (g->type == RTK_GEOMETRY_TYPE_INSTANCE)
        rtk_scene_release(g->instanced);
    if (g->owners != &g->owner_one)
        free(g->owners);
    rtk_device dev = g->device;
    free(g);
    rtk_device_release(dev);
}

/* The buffer of a type and slot (checked by check_buffer_args). */
static buffer *slot_buffer(rtk_geometry g, rtk_buffer_type type, unsigned slot)
{
    if (type == RTK_BUFFER_TYPE_INDEX)
        return &g->index;
    return slot ? &g->steps[slot - 1] : &g->vertex;
}

static rtk_error check_buffer_args(rtk_geometry g, rtk_buffer_type type, unsigned slot, size_t stride, size_t count,
                                   const char *fn)
{
    if (!is_mesh(g))
        return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION, "%s: only triangle and quad geometry has buffers", fn);
    if (type != RTK_BUFFER_TYPE_VERTEX && type != RTK_BUFFER_TYPE_INDEX)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT, "%s: unknown buffer type %d", fn, (int)type);
    if (type == RTK_BUFFER_TYPE_INDEX && slot)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT, "%s: slot %u: the index buffer has slot 0 only", fn,
                        slot);
    if (slot >= g->time_steps)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT,
                        "%s: vertex slot %u: the geometry has %u time step%s (rtk_geometry_set_time_step_count)", fn,
                        slot, g->time_steps, g->time_steps == 1 ? "" : "s");
    const size_t least = type == RTK_BUFFER_TYPE_INDEX && g->type == RTK_GEOMETRY_TYPE_QUAD ? 16 : 12;
    if (stride < least || stride % 4)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT,
                        "%s: byte_stride %zu: must be at least %zu and a multiple of 4", fn, stride, least);
    if (count > ((size_t)1 << 32) - 1)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT, "%s: count %zu exceeds 2^32 - 1", fn, count);
    /* a quad's halves are triangles 2q and 2q + 1 to the kernels */
    if (type == RTK_BUFFER_TYPE_INDEX && g->type == RTK_GEOMETRY_TYPE_QUAD && count > ((size_t)1 << 31) - 1)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT, "%s: %zu quads exceed 2^31 - 1", fn, count);
    if (count && stride > SIZE_MAX / count)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT, "%s: count * byte_stride overflows", fn);
    return RTK_OK;
}

static rtk_error set_shared_buffer(rtk_geometry g, rtk_buffer_type type, unsigned slot, const void *ptr,
                                   size_t byte_offset, size_t byte_stride, size_t count, const char *fn)
{
    rtk_error err = check_buffer_args(g, type, slot, byte_stride, count, fn);
    if (err)
        return err;
    if (!ptr && count)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT, "%s: ptr is NULL", fn);
    const char *data = (const char *)ptr + (ptr ? byte_offset : 0);
    if ((uintptr_t)data % 4)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT, "%s: data is not 4-byte aligned", fn);
    buffer *b = slot_buffer(g, type, slot);
    buffer_changed(g, type);
    buffer_free(b);
    b->data = data;
    b->stride = byte_stride;
    b->count = count;
    return RTK_OK;
}

rtk_error rtk_geometry_set_shared_buffer(rtk_geometry g, rtk_buffer_type type, const void *ptr, size_t byte_offset,
                                         size_t byte_stride, size_t count)
{
    CHECK_HANDLE(g, "rtk_geometry_set_shared_buffer");
    return set_shared_buffer(g, type, 0, ptr, byte_offset, byte_stride, count, "rtk_geometry_set_shared_buffer");
}

rtk_error rtk_geometry_set_shared_buffer_slot(rtk_geometry g, rtk_buffer_type type, unsigned slot, const void *ptr,
                                              size_t byte_offset, size_t byte_stride, size_t count)
{
    CHECK_HANDLE(g, "rtk_geometry_set_shared_buffer_slot");
    return set_shared_buffer(g, type, slot, ptr, byte_offset, byte_stride, count,
                             "rtk_geometry_set_shared_buffer_slot");
}

static rtk_error set_new_buffer(rtk_geometry g, rtk_buffer_type type, unsigned slot, size_t byte_stride, size_t count,
                                void **out, const char *fn)
{
    if (!out)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT, "%s: out is NULL", fn);
    *out = NULL;
    rtk_error err = check_buffer_args(g, type, slot, byte_stride, count, fn);
    if (err)
        return err;
    const size_t bytes = (count ? count : 1) * byte_stride; /* no overflow: checked above */
    const rtk_memory *monitor = rtk_device_memory(g->device);
    if (bytes > SIZE_MAX - sizeof(blob))
        return rtk_fail(g->device, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory for %zu bytes", fn, bytes);
    if (monitor && !monitor->account(monitor->user, (int64_t)(sizeof(blob) + bytes)))
        return rtk_fail(g->device, RTK_ERROR_MEMORY_REFUSED, "%s: the memory monitor refused %zu bytes", fn,
                        sizeof(blob) + bytes);
    blob *mem = calloc(1, sizeof(blob) + bytes);
    if (!mem) {
        if (monitor)
            monitor->account(monitor->user, -(int64_t)(sizeof(blob) + bytes));
        return rtk_fail(g->device, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory for %zu bytes", fn,
                        count * byte_stride);
    }
    atomic_init(&mem->refs, 1);
    mem->mem = monitor;
    mem->bytes = monitor ? sizeof(blob) + bytes : 0;
    buffer *b = slot_buffer(g, type, slot);
    buffer_changed(g, type);
    buffer_free(b);
    b->owned = mem;
    b->data = (const char *)mem->data;
    b->stride = byte_stride;
    b->count = count;
    *out = mem->data;
    return RTK_OK;
}

rtk_error rtk_geometry_set_new_buffer(rtk_geometry g, rtk_buffer_type type, size_t byte_stride, size_t count,
                                      void **out)
{
    CHECK_HANDLE(g, "rtk_geometry_set_new_buffer");
    return set_new_buffer(g, type, 0, byte_stride, count, out, "rtk_geometry_set_new_buffer");
}

rtk_error rtk_geometry_set_new_buffer_slot(rtk_geometry g, rtk_buffer_type type, unsigned slot, size_t byte_stride,
                                           size_t count, void **out)
{
    CHECK_HANDLE(g, "rtk_geometry_set_new_buffer_slot");
    return set_new_buffer(g, type, slot, byte_stride, count, out, "rtk_geometry_set_new_buffer_slot");
}

rtk_error rtk_geometry_set_time_step_count(rtk_geometry g, unsigned count)
{
    CHECK_HANDLE(g, "rtk_geometry_set_time_step_count");
    if (!is_mesh(g))
        return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION,
                        "rtk_geometry_set_time_step_count: only triangle and quad geometry has time steps");
    if (count < 1 || count > RTK_MAX_TIME_STEPS)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT,
                        "rtk_geometry_set_time_step_count: %u time steps: must be 1 to %d", count, RTK_MAX_TIME_STEPS);
    if (count == g->time_steps)
        return RTK_OK;
    for (unsigned k = count; k < g->time_steps; k++)
        buffer_free(&g->steps[k - 1]);
    buffer *steps = NULL;
    if (count > 1) {
        steps = calloc(count - 1, sizeof *steps);
        if (!steps)
            return rtk_fail(g->device, RTK_ERROR_OUT_OF_MEMORY, "rtk_geometry_set_time_step_count: out of memory");
        const unsigned keep = count < g->time_steps ? count : g->time_steps;
        if (keep > 1)
            memcpy(steps, g->steps, (keep - 1) * sizeof *steps);
    }
    free(g->steps);
    g->steps = steps;
    g->time_steps = count;
    buffer_changed(g, RTK_BUFFER_TYPE_VERTEX);
    return RTK_OK;
}

rtk_error rtk_geometry_update_buffer(rtk_geometry g, rtk_buffer_type type)
{
    CHECK_HANDLE(g, "rtk_geometry_update_buffer");
    if (type != RTK_BUFFER_TYPE_VERTEX && type != RTK_BUFFER_TYPE_INDEX)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT, "rtk_geometry_update_buffer: unknown buffer type %d",
                        (int)type);
    if (!is_mesh(g))
        return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION,
                        "rtk_geometry_update_buffer: only triangle and quad geometry has buffers");
    const buffer *b = type == RTK_BUFFER_TYPE_VERTEX ? &g->vertex : &g->index;
    if (!b->stride)
        return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION, "rtk_geometry_update_buffer: no %s buffer set",
                        type == RTK_BUFFER_TYPE_VERTEX ? "vertex" : "index");
    buffer_changed(g, type);
    return RTK_OK;
}

rtk_error rtk_geometry_set_build_quality(rtk_geometry g, rtk_build_quality q)
{
    CHECK_HANDLE(g, "rtk_geometry_set_build_quality");
    if (q != RTK_BUILD_QUALITY_LOW && q != RTK_BUILD_QUALITY_MEDIUM && q != RTK_BUILD_QUALITY_HIGH &&
        q != RTK_BUILD_QUALITY_REFIT)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT, "rtk_geometry_set_build_quality: unknown quality %d",
                        (int)q);
    g->quality = q;
    return RTK_OK;
}

rtk_error rtk_geometry_enable(rtk_geometry g)
{
    CHECK_HANDLE(g, "rtk_geometry_enable");
    g->enabled = 1;
    return RTK_OK;
}

rtk_error rtk_geometry_disable(rtk_geometry g)
{
    CHECK_HANDLE(g, "rtk_geometry_disable");
    g->enabled = 0;
    return RTK_OK;
}

/* The attributes a scene's tree copies (mask, filters, the user data the
 * filters see) changed: like the triangles, they need the geometry
 * committed again and the tree built afresh, so they count as a new index
 * buffer (refit and a dynamic scene's kept trees compare its version). */
static void attrs_changed(rtk_geometry g)
{
    buffer_changed(g, RTK_BUFFER_TYPE_INDEX);
}

rtk_error rtk_geometry_set_user_data(rtk_geometry g, void *user)
{
    CHECK_HANDLE(g, "rtk_geometry_set_user_data");
    if (user != g->user && (g->intersect_filter || g->occluded_filter))
        attrs_changed(g);
    g->user = user;
    return RTK_OK;
}

rtk_error rtk_geometry_set_mask(rtk_geometry g, uint32_t mask)
{
    CHECK_HANDLE(g, "rtk_geometry_set_mask");
    if (mask != g->mask)
        attrs_changed(g);
    g->mask = mask;
    return RTK_OK;
}

static rtk_error set_filter(rtk_geometry g, int occluded, rtk_filter_fn filter, const char *fn)
{
    if (!g)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "%s: geometry is NULL", fn);
    if (!is_mesh(g))
        return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION,
                        "%s: only triangle and quad geometry has filters (set them on the instanced scene's "
                        "geometries)", fn);
    rtk_filter_fn *slot = occluded ? &g->occluded_filter : &g->intersect_filter;
    if (*slot != filter)
        attrs_changed(g);
    *slot = filter;
    return RTK_OK;
}

/* ---- user geometry ---- */

static rtk_error user_only(rtk_geometry g, const char *fn)
{
    if (!g)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "%s: geometry is NULL", fn);
    if (g->type != RTK_GEOMETRY_TYPE_USER)
        return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION, "%s: the geometry is not of type RTK_GEOMETRY_TYPE_USER",
                        fn);
    g->committed = 0;
    return RTK_OK;
}

rtk_error rtk_geometry_set_user_primitive_count(rtk_geometry g, uint32_t count)
{
    rtk_error err = user_only(g, "rtk_geometry_set_user_primitive_count");
    if (!err)
        g->user_count = count;
    return err;
}

rtk_error rtk_geometry_set_bounds_function(rtk_geometry g, rtk_bounds_fn bounds)
{
    rtk_error err = user_only(g, "rtk_geometry_set_bounds_function");
    if (!err)
        g->bounds = bounds;
    return err;
}

rtk_error rtk_geometry_set_intersect_function(rtk_geometry g, rtk_user_query_fn intersect)
{
    rtk_error err = user_only(g, "rtk_geometry_set_intersect_function");
    if (!err)
        g->user_intersect = intersect;
    return err;
}

rtk_error rtk_geometry_set_occluded_function(rtk_geometry g, rtk_user_query_fn occluded)
{
    rtk_error err = user_only(g, "rtk_geometry_set_occluded_function");
    if (!err)
        g->user_occluded = occluded;
    return err;
}

rtk_error rtk_geometry_set_point_query_function(rtk_geometry g, rtk_point_query_fn fn)
{
    rtk_error err = user_only(g, "rtk_geometry_set_point_query_function");
    if (!err)
        g->user_point = fn;
    return err;
}

/* Word f of lane i of a K-packet (K = 1: an rtk_rayhit or rtk_ray, whose
 * fields are 4-byte words in the packets' order). */
#define WORD_AT(p, f, k, i) ((char *)(p) + 4 * ((size_t)(f) * (k) + (i)))
enum { WORD_TNEAR = 3, WORD_TFAR = 8, RAY_WORDS = 12, WORD_PRIM = 17, RAYHIT_WORDS = 20 };

static float lane_float(const void *rays, uint32_t f, uint32_t k, uint32_t i)
{
    float x;
    memcpy(&x, WORD_AT(rays, f, k, i), 4);
    return x;
}

/* Whether the callback reported a hit for lane i of a K-packet: tfar set
 * within the lane's interval (occluded: to -inf); `before` is the lane as
 * the callback got it. */
static int user_reported(const void *rays, const void *before, uint32_t k, uint32_t i, int occluded)
{
    const float t = lane_float(rays, WORD_TFAR, k, i), tnear = lane_float(before, WORD_TNEAR, k, i),
                old = lane_float(before, WORD_TFAR, k, i);
    return occluded ? t == -INFINITY : t != old && t >= tnear && t <= old;
}

/* Lane i settled: a hit keeps tfar (and the hit's u, v, Ng; then rtk's ids
 * are written), but not changes to the rest of the ray; a miss restores
 * everything from `before`. */
static void user_settle(void *rays, const void *before, uint32_t k, uint32_t i, int occluded, int hit,
                        const user_prim *u)
{
    /* (4-byte words moved with memcpy: the fields are floats and uint32s) */
    const int fields = hit ? RAY_WORDS : occluded ? RAY_WORDS : RAYHIT_WORDS;
    for (int f = 0; f < fields; f++)
        if (!hit || f != WORD_TFAR)
            memcpy(WORD_AT(rays, f, k, i), WORD_AT(before, f, k, i), 4);
    if (hit && !occluded) {
        const uint32_t ids[3] = {u->prim_id, u->geom_id, RTK_INVALID_GEOMETRY_ID}; /* an instance above writes its own instID */
        for (int f = 0; f < 3; f++)
            memcpy(WORD_AT(rays, WORD_PRIM + f, k, i), &ids[f], 4);
    }
}

/* A callback's call, as rtk_user_offer_hit finds it: the arguments the
 * callback got first. */
typedef struct user_frame {
    rtk_user_query_args args;
    const rtk_query *q;
    const user_prim *u;
    const void *before;            /* the rays as the callback got them */
    uint32_t taken;                /* the lanes with an offered hit the query took */
    struct user_frame *outer;      /* a callback's own query's callbacks nest */
} user_frame;

/* The callback running on this thread, innermost. */
static _Thread_local user_frame *tls_frame;

/* The query's own filter (rtk_query.filter), or NULL. */
static rtk_filter_fn query_filter(const rtk_query *q)
{
    return q->flags & RTK_QUERY_FLAG_FILTER ? q->filter : NULL;
}

int rtk_user_offer_hit(const rtk_user_query_args *args, uint32_t lane, const rtk_user_hit *hit)
{
    static const char fn[] = "rtk_user_offer_hit";
    user_frame *f = tls_frame;
    if (!f || !args || args != &f->args) {
        rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT,
                 "%s: args are not those of the user geometry callback running on this thread", fn);
        return 0;
    }
    if (!hit || lane >= args->N || !args->valid[lane]) {
        rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, hit ? "%s: lane %u is not one the callback is to test (N %u)"
                                                       : "%s: hit is NULL",
                 fn, lane, args->N);
        return 0;
    }
    const uint32_t k = args->N;
    if (!(hit->t >= lane_float(f->before, WORD_TNEAR, k, lane) && hit->t <= lane_float(f->before, WORD_TFAR, k, lane)))
        return 0;
    const rtk_query *q = f->q;
    const rtk_filter_fn filter = query_filter(q);
    if (filter) {
        /* (the query filters serve the width-1 kernels only) */
        rtk_ray ray;
        for (uint32_t w = 0; w < RAY_WORDS; w++)
            memcpy((char *)&ray + 4 * w, WORD_AT(f->before, w, k, lane), 4);
        const rtk_hit h = {.Ng_x = hit->Ng_x, .Ng_y = hit->Ng_y, .Ng_z = hit->Ng_z, .u = hit->u, .v = hit->v,
                           .primID = f->u->prim_id, .geomID = f->u->geom_id, .instID = q->inst_id};
        const rtk_filter_args fa = {.geometry_user = args->geometry_user, .context = q->context, .ray = &ray,
                                    .hit = &h, .t = hit->t};
        if (!filter(&fa))
            return 0;
    }
    f->taken |= 1u << lane;
    return 1;
}

static void user_call(const user_prim *u, const int32_t *active, void *rays, uint32_t k, const rtk_query *q,
                      int occluded)
{
    const size_t bytes = (occluded ? RAY_WORDS : RAYHIT_WORDS) * 4u * k;
    uint32_t before[RAYHIT_WORDS * 16];
    memcpy(before, rays, bytes);
    int valid[16];
    for (uint32_t i = 0; i < k; i++)
        valid[i] = active[i] != 0;
    user_frame f = {.args = {.valid = valid, .geometry_user = u->user, .geom_id = u->geom_id, .prim_id = u->prim_id,
                             .context = q->context, .rays = rays, .N = k},
                    .q = q, .u = u, .before = before, .outer = tls_frame};
    tls_frame = &f;
    (occluded ? u->occluded : u->intersect)(&f.args);
    tls_frame = f.outer;
    const int filtered = query_filter(q) != NULL;
    for (uint32_t i = 0; i < k; i++) {
        if (active[i]) {
            int hit = user_reported(rays, before, k, i, occluded);
            if (hit && filtered && !(f.taken & 1u << i)) {
                /* a hit the query's filter never saw: a miss, and a query
                 * collecting crossings fails rather than lose them */
                hit = 0;
                crossings_unoffered(q, u->geom_id);
            }
            user_settle(rays, before, k, i, occluded, hit, u);
        } else { /* not the callback's to touch */
            for (int w = 0; w < (occluded ? RAY_WORDS : RAYHIT_WORDS); w++)
                memcpy(WORD_AT(rays, w, k, i), WORD_AT(before, w, k, i), 4);
        }
    }
}
#undef WORD_AT

void user_intersect1(const rtk_accel *a, rtk_rayhit *rh, const rtk_query *q)
{
    const int32_t one = -1;
    user_call((const user_prim *)(const void *)a, &one, rh, 1, q, 0);
}

void user_occluded1(const rtk_accel *a, rtk_ray *ray, const rtk_query *q)
{
    const int32_t one = -1;
    user_call((const user_prim *)(const void *)a, &one, ray, 1, q, 1);
}

/* rtk_query.user_point: the primitive's point query function asked for its
 * nearest point to p; 0 when it has none within radius or gives a point
 * that is not finite. */
int user_point(const rtk_accel *a, const double p[3], double radius, float time, rtk_user_point *out)
{
    const user_prim *u = (const user_prim *)(const void *)a;
    if (!u->point)
        return 0;
    rtk_point_query_args args = {.geometry_user = u->user, .geom_id = u->geom_id, .prim_id = u->prim_id,
                                 .p = {p[0], p[1], p[2]}, .radius = radius, .time = time,
                                 .closest = {NAN, NAN, NAN}, .u = NAN, .v = NAN};
    if (!u->point(&args))
        return 0;
    for (int k = 0; k < 3; k++)
        if (!isfinite(args.closest[k]))
            return 0;
    memcpy(out->closest, args.closest, sizeof out->closest);
    out->u = args.u;
    out->v = args.v;
    for (int k = 0; k < 3; k++)
        out->normal[k] = isfinite(args.normal[k]) ? args.normal[k] : 0.0f;
    out->prim_id = u->prim_id;
    out->geom_id = u->geom_id;
    return 1;
}

void user_intersect_packet(const rtk_accel *a, const int32_t *active, void *packet, uint32_t width,
                                  const rtk_query *q)
{
    user_call((const user_prim *)(const void *)a, active, packet, width, q, 0);
}

void user_occluded_packet(const rtk_accel *a, const int32_t *active, void *packet, uint32_t width,
                                 const rtk_query *q)
{
    user_call((const user_prim *)(const void *)a, active, packet, width, q, 1);
}

rtk_error rtk_geometry_set_intersect_filter(rtk_geometry g, rtk_filter_fn filter)
{
    return set_filter(g, 0, filter, "rtk_geometry_set_intersect_filter");
}

rtk_error rtk_geometry_set_occluded_filter(rtk_geometry g, rtk_filter_fn filter)
{
    return set_filter(g, 1, filter, "rtk_geometry_set_occluded_filter");
}

void *rtk_geometry_get_user_data(rtk_geometry g)
{
    if (!g) {
        rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "rtk_geometry_get_user_data: g is NULL");
        return NULL;
    }
    return g->user;
}


rtk_error rtk_geometry_set_instanced_scene(rtk_geometry g, rtk_scene scene)
{
    CHECK_HANDLE(g, "rtk_geometry_set_instanced_scene");
    if (g->type != RTK_GEOMETRY_TYPE_INSTANCE)
        return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION,
                        "rtk_geometry_set_instanced_scene: the geometry is not an instance");
    if (scene && scene->device != g->device)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT,
                        "rtk_geometry_set_instanced_scene: the scene belongs to another device");
    for (uint32_t i = 0; scene && i < g->owner_count; i++)
        if (scene_reaches(scene, g->owners[i]))
            return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION,
                            "rtk_geometry_set_instanced_scene: the instance is attached to a scene that the scene "
                            "it would place is or contains: a cycle");
    rtk_scene_retain(scene);
    rtk_scene_release(g->instanced);
    g->instanced = scene;
    g->committed = 0;
    return RTK_OK;
}

rtk_error rtk_geometry_set_transform(rtk_geometry g, rtk_format format, const float *xfm)
{
    CHECK_HANDLE(g, "rtk_geometry_set_transform");
    if (g->type != RTK_GEOMETRY_TYPE_INSTANCE)
        return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION,
                        "rtk_geometry_set_transform: the geometry is not an instance");
    if (!xfm)
        return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT, "rtk_geometry_set_transform: xfm is NULL");
    float m[12];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 4; c++) {
            if (format == RTK_FORMAT_FLOAT3X4_ROW_MAJOR)
                m[4 * r + c] = xfm[4 * r + c];
            else if (format == RTK_FORMAT_FLOAT3X4_COLUMN_MAJOR)
                m[4 * r + c] = xfm[3 * c + r];
            else if (format == RTK_FORMAT_FLOAT4X4_COLUMN_MAJOR)
                m[4 * r + c] = xfm[4 * c + r];
            else
                return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT, "rtk_geometry_set_transform: unknown format %d",
                                (int)format);
        }
    for (int i = 0; i < 12; i++)
        if (!isfinite(m[i]))
            return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT,
                            "rtk_geometry_set_transform: element %d of the transform is not finite", i);
    memcpy(g->xfm, m, sizeof m);
    g->committed = 0;
    return RTK_OK;
}

/* (scene_internal.h) */
int rtk_invert_3x4(const float *m, float *inv)
{
    double md[12], id[12];
    for (int k = 0; k < 12; k++)
        md[k] = m[k];
    if (!rtk_affine_invert(md, id))
        return 0;
    for (int k = 0; k < 12; k++) {
        inv[k] = (float)id[k];
        if (!isfinite(inv[k]))
            return 0;
    }
    return 1;
}

rtk_error rtk_geometry_commit(rtk_geometry g)
{
    CHECK_HANDLE(g, "rtk_geometry_commit");
    if (g->type == RTK_GEOMETRY_TYPE_INSTANCE) {
        if (!g->instanced)
            return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION, "rtk_geometry_commit: the instance has no scene");
        float inv[12]; /* (the scene's commit computes it again, the same floats, for its top level) */
        if (!rtk_invert_3x4(g->xfm, inv))
            return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT,
                            "rtk_geometry_commit: the instance's transform is singular (no inverse in floats)");
        g->committed = 1;
        return RTK_OK;
    }
    if (g->type == RTK_GEOMETRY_TYPE_USER) {
        if (!g->bounds || !g->user_intersect || !g->user_occluded)
            return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION,
                            "rtk_geometry_commit: user geometry needs its bounds, intersect and occluded functions");
        g->committed = 1;
        return RTK_OK;
    }
    if (!g->vertex.stride)
        return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION, "rtk_geometry_commit: no vertex buffer set");
    if (!g->index.stride)
        return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION, "rtk_geometry_commit: no index buffer set");
    for (unsigned k = 1; k < g->time_steps; k++) {
        if (!g->steps[k - 1].stride)
            return rtk_fail(g->device, RTK_ERROR_INVALID_OPERATION,
                            "rtk_geometry_commit: no vertex buffer set in slot %u (of %u time steps)", k,
                            g->time_steps);
        if (g->steps[k - 1].count != g->vertex.count)
            return rtk_fail(g->device, RTK_ERROR_INVALID_ARGUMENT,
                            "rtk_geometry_commit: vertex slot %u has %zu vertices, slot 0 has %zu", k,
                            g->steps[k - 1].count, g->vertex.count);
    }
    g->committed = 1;
    return RTK_OK;
}
