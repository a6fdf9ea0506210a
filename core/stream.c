/* Streams of single rays (rtk_intersect1M, rtk_occluded1M) and their
 * threaded form over a whole batch (rtk_intersect_batch, rtk_occluded_batch). */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "scene_internal.h"

/* Rays handed to a stream kernel per call: the valid ones of up to this
 * many consecutive rays, as pointers.  The kernel keeps several in flight
 * and measures how to trace them fastest as it goes (traverse_stream.h,
 * tls_stream below), and each call ends with its last rays finishing
 * alone, so the list is long, from the heap; a short stream's list (or,
 * out of memory, a chunk at a time) is on the stack. */
enum { STREAM_CHUNK = 65536, STREAM_STACK_CHUNK = 512 };

/* What the stream kernels learnt (traverse_stream.h: which way the rays
 * go fastest) about the last tree this thread traced streams through, one
 * for closest and one for any hits: renderers hand over streams of a tile's
 * rays, a thousand or so, and a kernel that began every one of them
 * measuring would spend much of each stream measuring.  Only ever a
 * choice of speed: every way gives every ray the same answer.  Kept by
 * the tree's serial, not its address, which a new tree may reuse. */
static _Thread_local struct {
    uint64_t serial;
    _Alignas(64) unsigned char state[2][RTK_STREAM_STATE_SIZE];
} tls_stream;

/* Rays per task of a batch: enough that a task's set-up and its drain are
 * a small share, few enough that the threads share the work evenly. */
enum { BATCH_PIECE = 4096 };

rtk_error array_check(rtk_scene s, const void *p, size_t count, size_t stride, size_t size, const char *what,
                      const char *fn)
{
    if (!count)
        return RTK_OK;
    if (!p)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: %s is NULL (count %zu)", fn, what, count);
    if ((uintptr_t)p % 4)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: the %s at %p are not aligned to 4 bytes", fn, what,
                        p);
    if (stride < size || stride % 4)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT,
                        "%s: byte_stride %zu of the %s is below their struct's %zu bytes or not a multiple of 4", fn,
                        stride, what, size);
    if ((count - 1) > (UINTPTR_MAX - (uintptr_t)p - size) / stride)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT,
                        "%s: %zu %s %zu bytes apart from %p run past the end of the address space", fn, count, what,
                        stride, p);
    return RTK_OK;
}

/* The checks of every stream call; RTK_OK when the stream may be traced. */
static rtk_error stream_check(rtk_scene s, const void *rays, size_t count, size_t stride, size_t size, const char *fn)
{
    if (!s)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "%s: scene is NULL", fn);
    if (!count)
        return RTK_OK;
    const rtk_error err = array_check(s, rays, count, stride, size, "rays", fn);
    if (err)
        return err;
    if (scene_not_committing(s, fn))
        return RTK_ERROR_INVALID_OPERATION;
    if (!s->accel)
        return rtk_fail(s->device, RTK_ERROR_INVALID_OPERATION, "%s: the scene was never committed", fn);
    return RTK_OK;
}

/* Traces rays [0, count) of the (checked) stream: the valid ones, a chunk
 * at a time, through the stream kernel, or ray by ray without one. */
void stream_trace(rtk_scene s, char *rays, size_t count, size_t stride, int occluded, const rtk_query *q)
{
    if (!(occluded ? (void (*)(void))s->occluded_stream : (void (*)(void))s->intersect_stream)) {
        for (size_t i = 0; i < count; i++) {
            rtk_rayhit *r = (rtk_rayhit *)(void *)(rays + i * stride);
            const int kind = ray_check(&r->ray);
            if (kind == RAY_RANGE)
                range_trace1(s, r, occluded, q);
            else if (kind == RAY_PLAIN && occluded)
                s->occluded1(s->accel, &r->ray, q);
            else if (kind == RAY_PLAIN)
                s->intersect1(s->accel, r, q);
        }
        return;
    }
    if (tls_stream.serial != s->ref->serial) {
        memset(tls_stream.state, 0, sizeof tls_stream.state);
        tls_stream.serial = s->ref->serial;
    }
    rtk_query sq = *q;
    sq.flags |= RTK_QUERY_FLAG_STREAM_STATE;
    sq.stream_state = tls_stream.state[occluded != 0];
    void *stack_list[STREAM_STACK_CHUNK], **list = stack_list;
    size_t chunk = STREAM_STACK_CHUNK;
    if (count > STREAM_STACK_CHUNK) {
        void **heap = malloc((count < STREAM_CHUNK ? count : STREAM_CHUNK) * sizeof *heap);
        if (heap) {
            list = heap;
            chunk = count < STREAM_CHUNK ? count : STREAM_CHUNK;
        }
    }
    for (size_t i = 0; i < count;) {
        uint32_t n = 0;
        for (; i < count && n < chunk; i++) {
            void *r = rays + i * stride;
            const int kind = ray_check(r);
            if (__builtin_expect(kind == RAY_PLAIN, 1))
                list[n++] = r;
            else if (kind == RAY_RANGE) /* alone, in order with the rest: a stream's rays are independent */
                range_trace1(s, r, occluded, q);
        }
        if (!n)
            continue;
        if (occluded)
            s->occluded_stream(s->accel, (rtk_ray *const *)list, n, &sq);
        else
            s->intersect_stream(s->accel, (rtk_rayhit *const *)list, n, &sq);
    }
    if (list != stack_list)
        free(list);
}

static rtk_error stream(rtk_scene s, void *rays, uint32_t count, size_t stride, int occluded,
                        const rtk_query_context *ctx, const char *fn)
{
    const rtk_error err = stream_check(s, rays, count, stride, occluded ? sizeof(rtk_ray) : sizeof(rtk_rayhit), fn);
    if (err || !count)
        return err;
    const rtk_query q = {.context = ctx, .inst_id = RTK_INVALID_GEOMETRY_ID};
    stream_trace(s, rays, count, stride, occluded, &q);
    return RTK_OK;
}

rtk_error rtk_intersect1M(rtk_scene s, rtk_rayhit *rays, uint32_t count, size_t byte_stride)
{
    return stream(s, rays, count, byte_stride, 0, NULL, "rtk_intersect1M");
}

rtk_error rtk_occluded1M(rtk_scene s, rtk_ray *rays, uint32_t count, size_t byte_stride)
{
    return stream(s, rays, count, byte_stride, 1, NULL, "rtk_occluded1M");
}

rtk_error rtk_intersect1M_ctx(rtk_scene s, rtk_rayhit *rays, uint32_t count, size_t byte_stride,
                              const rtk_query_context *ctx)
{
    return stream(s, rays, count, byte_stride, 0, ctx, "rtk_intersect1M_ctx");
}

rtk_error rtk_occluded1M_ctx(rtk_scene s, rtk_ray *rays, uint32_t count, size_t byte_stride,
                             const rtk_query_context *ctx)
{
    return stream(s, rays, count, byte_stride, 1, ctx, "rtk_occluded1M_ctx");
}

/* ---- batches over the device's threads ---- */

typedef struct batch_job {
    rtk_scene scene;
    char *rays;
    size_t count, stride;
    int occluded;
    rtk_query q;
} batch_job;

static void batch_piece(void *data, uint32_t index)
{
    const batch_job *j = data;
    const size_t begin = (size_t)index * BATCH_PIECE;
    const size_t n = j->count - begin < BATCH_PIECE ? j->count - begin : BATCH_PIECE;
    stream_trace(j->scene, j->rays + begin * j->stride, n, j->stride, j->occluded, &j->q);
}

static rtk_error batch(rtk_scene s, void *rays, size_t count, size_t stride, int occluded,
                       const rtk_query_context *ctx, const char *fn)
{
    rtk_error err = stream_check(s, rays, count, stride, occluded ? sizeof(rtk_ray) : sizeof(rtk_rayhit), fn);
    if (err || !count)
        return err;
    const size_t pieces = (count + BATCH_PIECE - 1) / BATCH_PIECE;
    if (pieces > UINT32_MAX)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: %zu rays are more than a batch takes (%llu)", fn,
                        count, (unsigned long long)UINT32_MAX * BATCH_PIECE);
    const batch_job job = {.scene = s, .rays = rays, .count = count, .stride = stride, .occluded = occluded,
                           .q = {.context = ctx, .inst_id = RTK_INVALID_GEOMETRY_ID}};
    rtk_device_for(s->device, (uint32_t)pieces, batch_piece, (void *)&job);
    return RTK_OK;
}

rtk_error rtk_intersect_batch(rtk_scene s, rtk_rayhit *rays, size_t count, size_t byte_stride,
                              const rtk_query_context *ctx)
{
    return batch(s, rays, count, byte_stride, 0, ctx, "rtk_intersect_batch");
}

rtk_error rtk_occluded_batch(rtk_scene s, rtk_ray *rays, size_t count, size_t byte_stride,
                             const rtk_query_context *ctx)
{
    return batch(s, rays, count, byte_stride, 1, ctx, "rtk_occluded_batch");
}
