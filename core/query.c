/* The ray queries: single rays and packets. */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <string.h>

#include "scene_internal.h"

/* ---- queries ---- */

/* The query of a call without a context: one constant, so the entry
 * points without _ctx pass its address and build nothing on the stack (a
 * query built per call was five of rtk_occluded1's 38 instructions).  The
 * checks below are inlined into each entry point, so that those without
 * _ctx (ctx a constant NULL) keep no test of it and build no query
 * either. */
static const rtk_query query_plain = {.context = NULL, .inst_id = RTK_INVALID_GEOMETRY_ID};

static inline __attribute__((always_inline)) rtk_error intersect1(rtk_scene s, rtk_rayhit *rh,
                                                                  const rtk_query_context *ctx, const char *fn)
{
    if (!s)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "%s: scene is NULL", fn);
    if (!rh)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: rayhit is NULL", fn);
    if (__builtin_expect(atomic_load_explicit(&s->committing, memory_order_relaxed) != COMMIT_IDLE, 0))
        return scene_not_committing(s, fn);
    if (!s->accel)
        return rtk_fail(s->device, RTK_ERROR_INVALID_OPERATION, "%s: the scene was never committed", fn);
    const rtk_query q = {.context = ctx, .inst_id = RTK_INVALID_GEOMETRY_ID};
    const int kind = ray_check(&rh->ray);
    if (__builtin_expect(kind == RAY_PLAIN, 1))
        s->intersect1(s->accel, rh, ctx ? &q : &query_plain);
    else if (kind == RAY_RANGE)
        range_intersect1(s, rh, ctx ? &q : &query_plain);
    return RTK_OK;
}

static inline __attribute__((always_inline)) rtk_error occluded1(rtk_scene s, rtk_ray *ray,
                                                                 const rtk_query_context *ctx, const char *fn)
{
    if (!s)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "%s: scene is NULL", fn);
    if (!ray)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: ray is NULL", fn);
    if (__builtin_expect(atomic_load_explicit(&s->committing, memory_order_relaxed) != COMMIT_IDLE, 0))
        return scene_not_committing(s, fn);
    if (!s->accel)
        return rtk_fail(s->device, RTK_ERROR_INVALID_OPERATION, "%s: the scene was never committed", fn);
    const rtk_query q = {.context = ctx, .inst_id = RTK_INVALID_GEOMETRY_ID};
    const int kind = ray_check(ray);
    if (__builtin_expect(kind == RAY_PLAIN, 1))
        s->occluded1(s->accel, ray, ctx ? &q : &query_plain);
    else if (kind == RAY_RANGE)
        range_occluded1(s, ray, ctx ? &q : &query_plain);
    return RTK_OK;
}

rtk_error rtk_intersect1(rtk_scene s, rtk_rayhit *rh)
{
    return intersect1(s, rh, NULL, "rtk_intersect1");
}

rtk_error rtk_occluded1(rtk_scene s, rtk_ray *ray)
{
    return occluded1(s, ray, NULL, "rtk_occluded1");
}

rtk_error rtk_intersect1_ctx(rtk_scene s, rtk_rayhit *rh, const rtk_query_context *ctx)
{
    return intersect1(s, rh, ctx, "rtk_intersect1_ctx");
}

rtk_error rtk_occluded1_ctx(rtk_scene s, rtk_ray *ray, const rtk_query_context *ctx)
{
    return occluded1(s, ray, ctx, "rtk_occluded1_ctx");
}

/* ---- packets ----
 * Every ray type is an array of 4-byte fields in the order of rtk_rayhit's:
 * rtk_rayhit is a packet of one, and field f of lane i of an N-packet is
 * element f * N + i.  So lanes move between widths with one copy per field. */
enum { RAY_FIELDS = sizeof(rtk_ray) / 4, RAYHIT_FIELDS = sizeof(rtk_rayhit) / 4 };
/* a field's row in a packet (rtk.h: field f of lane j is 4-byte word f * N + j) */
#define RAY_ROW(field) (offsetof(rtk_ray, field) / 4)
_Static_assert(sizeof(rtk_ray) == 12 * 4 && sizeof(rtk_rayhit) == 20 * 4, "4-byte fields");
_Static_assert(sizeof(rtk_ray4) == 4 * sizeof(rtk_ray) && sizeof(rtk_rayhit4) == 4 * sizeof(rtk_rayhit), "SoA 4");
_Static_assert(sizeof(rtk_ray8) == 8 * sizeof(rtk_ray) && sizeof(rtk_rayhit8) == 8 * sizeof(rtk_rayhit), "SoA 8");
_Static_assert(sizeof(rtk_ray16) == 16 * sizeof(rtk_ray) && sizeof(rtk_rayhit16) == 16 * sizeof(rtk_rayhit),
               "SoA 16");
_Static_assert(offsetof(rtk_rayhit8, hit) == sizeof(rtk_ray8) && offsetof(rtk_ray8, tfar) == 8 * 8 * 4, "order");

static inline __attribute__((always_inline)) void copy_lanes(void *dst, size_t dst_n, size_t dst_lane,
                                                             const void *src, size_t src_n, size_t src_lane,
                                                             size_t lanes, size_t fields)
{
    for (size_t f = 0; f < fields; f++)
        memcpy((uint32_t *)dst + f * dst_n + dst_lane, (const uint32_t *)src + f * src_n + src_lane, lanes * 4);
}

/* A packet of n rays through a kernel of w < n, w rays at a time, each
 * group through an aligned copy.  Inlined with n and w constants, so the
 * copies are a few vector moves, not calls. */
static inline __attribute__((always_inline)) void trace_split(rtk_scene s, const int32_t *active, void *packet,
                                                              uint32_t n, uint32_t w, size_t fields,
                                                              const struct packet_kernel *k, const rtk_query *query)
{
    _Alignas(64) uint32_t sub[RAYHIT_FIELDS * 16];
    for (uint32_t base = 0; base < n; base += w) {
        uint32_t on = 0;
        for (uint32_t i = 0; i < w; i++)
            on += active[base + i] != 0;
        if (!on)
            continue;
        copy_lanes(sub, w, 0, packet, n, base, w, fields);
        k->fn(s->accel, active + base, sub, query);
        /* back: the fields a query writes (tfar, and the hit), whole
         * rows when every lane is on, else the lanes that are */
        for (size_t f = RAY_ROW(tfar); f < fields; f = f == RAY_ROW(tfar) ? RAY_FIELDS : f + 1) {
            if (on == w) {
                copy_lanes((uint32_t *)packet + f * n, n, base, sub + f * w, w, 0, w, 1);
                continue;
            }
            for (uint32_t i = 0; i < w; i++)
                if (active[base + i])
                    copy_lanes((uint32_t *)packet + f * n, n, base + i, sub + f * w, w, i, 1, 1);
        }
    }
}

/* The lanes of a packet of n rays that are on (valid, or valid NULL) and
 * pass ray_check, as -1 / 0 into active; whether any does; and in *range
 * the mask of those that ray_check sends through ray_range.c.  Read
 * straight from the structure of arrays, lane by lane with no branches,
 * so the compiler does all lanes at once (inlined where n is a constant). */
static inline __attribute__((always_inline)) int packet_active(const void *packet, uint32_t n, const int *valid,
                                                               int32_t *active, uint32_t *range)
{
    const float *f = packet;
    const uint32_t *u = packet;
#define LANE(field) f[RAY_ROW(field) * n + i]
    int32_t any = 0, far[16];
    for (uint32_t i = 0; i < n; i++) {
        const float z = 0.0f * LANE(org_x) + 0.0f * LANE(org_y) + 0.0f * LANE(org_z) + 0.0f * LANE(dir_x) +
                        0.0f * LANE(dir_y) + 0.0f * LANE(dir_z) + 0.0f * LANE(tnear);
        const float tnear = LANE(tnear);
        active[i] = -((z == 0.0f) & (tnear >= 0.0f) & (tnear <= LANE(tfar)) & (u[RAY_ROW(mask) * n + i] != 0));
        any |= active[i];
        far[i] = -ray_out_of_window(LANE(org_x), LANE(org_y), LANE(org_z), LANE(dir_x), LANE(dir_y), LANE(dir_z));
    }
#undef LANE
    if (valid) {
        any = 0;
        for (uint32_t i = 0; i < n; i++) {
            active[i] &= -(valid[i] != 0);
            any |= active[i];
        }
    }
    int32_t any_far = 0;
    for (uint32_t i = 0; i < n; i++)
        any_far |= far[i] & active[i];
    *range = 0;
    for (uint32_t i = 0; any_far && i < n; i++) /* (rare) the lanes that are on and outside */
        *range |= (uint32_t)(far[i] & active[i] & 1) << i;
    return any != 0;
}

static inline __attribute__((always_inline)) rtk_error trace_packet(rtk_scene s, const int *valid, void *packet,
                                                                    uint32_t n, int occluded,
                                                                    const rtk_query_context *ctx)
{
    /* The name for messages, e.g. "rtk_intersect8": formatted by rtk_fail only on an error. */
    const char *q = occluded ? "occluded" : "intersect";
    if (!s)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "rtk_%s%u: scene is NULL", q, n);
    if (!packet)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "rtk_%s%u: the packet is NULL", q, n);
    if ((uintptr_t)packet % (4 * n))
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "rtk_%s%u: the packet at %p is not aligned to %u bytes",
                        q, n, packet, 4 * n);
    if (__builtin_expect(atomic_load_explicit(&s->committing, memory_order_relaxed) != COMMIT_IDLE, 0)) {
        char fn[32];
        snprintf(fn, sizeof fn, "rtk_%s%u", q, n);
        return scene_not_committing(s, fn);
    }
    if (!s->accel)
        return rtk_fail(s->device, RTK_ERROR_INVALID_OPERATION, "rtk_%s%u: the scene was never committed", q, n);

    _Alignas(64) int32_t active[16];
    uint32_t range;
    if (!packet_active(packet, n, valid, active, &range))
        return RTK_OK;
    const rtk_query query = {.context = ctx, .inst_id = RTK_INVALID_GEOMETRY_ID};
    const size_t fields = occluded ? RAY_FIELDS : RAYHIT_FIELDS;
    if (__builtin_expect(range != 0, 0)) { /* those rays alone, through ray_range.c */
        int32_t left = 0;
        for (uint32_t i = 0; i < n; i++) {
            if (range >> i & 1) {
                rtk_rayhit rh;
                copy_lanes(&rh, 1, 0, packet, n, i, 1, fields);
                range_trace1(s, &rh, occluded, &query);
                copy_lanes(packet, n, i, &rh, 1, 0, 1, fields);
                active[i] = 0;
            }
            left |= active[i];
        }
        if (!left)
            return RTK_OK;
    }
    const struct packet_kernel *k = &s->packet[occluded][n == 4 ? 0 : n == 8 ? 1 : 2];
    if (k->width == n) {
        k->fn(s->accel, active, packet, &query);
    } else if (k->width == 8) { /* narrower packets: through an aligned copy */
        trace_split(s, active, packet, n, 8, fields, k, &query);
    } else if (k->width == 4) {
        trace_split(s, active, packet, n, 4, fields, k, &query);
    } else if (k->width > 1) {
        trace_split(s, active, packet, n, k->width, fields, k, &query);
    } else if (s->intersect_stream && s->occluded_stream) {
        /* no packet kernel (motion blur; the scalar backend): the active
         * lanes as one stream, whose kernel interleaves the rays that
         * scatter and gives each rtk_intersect1's answer */
        rtk_rayhit one[16];
        void *list[16];
        uint32_t lane[16], m = 0;
        for (uint32_t i = 0; i < n; i++) {
            if (!active[i])
                continue;
            copy_lanes(&one[m], 1, 0, packet, n, i, 1, fields);
            list[m] = &one[m];
            lane[m++] = i;
        }
        if (occluded)
            s->occluded_stream(s->accel, (rtk_ray *const *)list, m, &query);
        else
            s->intersect_stream(s->accel, (rtk_rayhit *const *)list, m, &query);
        for (uint32_t j = 0; j < m; j++)
            copy_lanes(packet, n, lane[j], &one[j], 1, 0, 1, fields);
    } else { /* ray by ray */
        for (uint32_t i = 0; i < n; i++) {
            if (!active[i])
                continue;
            rtk_rayhit rh;
            copy_lanes(&rh, 1, 0, packet, n, i, 1, fields);
            if (occluded)
                s->occluded1(s->accel, &rh.ray, &query);
            else
                s->intersect1(s->accel, &rh, &query);
            copy_lanes(packet, n, i, &rh, 1, 0, 1, fields);
        }
    }
    return RTK_OK;
}

#define RTK_PACKET_ENTRY_POINTS_(N)                                                                                    \
    rtk_error rtk_intersect##N(rtk_scene s, const int *valid, rtk_rayhit##N *rayhit)                                  \
    {                                                                                                                  \
        return trace_packet(s, valid, rayhit, N, 0, NULL);                                                             \
    }                                                                                                                  \
    rtk_error rtk_occluded##N(rtk_scene s, const int *valid, rtk_ray##N *ray)                                         \
    {                                                                                                                  \
        return trace_packet(s, valid, ray, N, 1, NULL);                                                                \
    }                                                                                                                  \
    rtk_error rtk_intersect##N##_ctx(rtk_scene s, const int *valid, rtk_rayhit##N *rayhit,                            \
                                     const rtk_query_context *ctx)                                                     \
    {                                                                                                                  \
        return trace_packet(s, valid, rayhit, N, 0, ctx);                                                              \
    }                                                                                                                  \
    rtk_error rtk_occluded##N##_ctx(rtk_scene s, const int *valid, rtk_ray##N *ray, const rtk_query_context *ctx)     \
    {                                                                                                                  \
        return trace_packet(s, valid, ray, N, 1, ctx);                                                                 \
    }
RTK_PACKET_ENTRY_POINTS_(4)
RTK_PACKET_ENTRY_POINTS_(8)
RTK_PACKET_ENTRY_POINTS_(16)
