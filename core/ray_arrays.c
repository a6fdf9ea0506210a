/* Rays in array form (rtk.h: rtk_intersect_arrays, rtk_occluded_arrays):
 * six numbers a ray in, an array per answer out.  Each task turns its
 * piece of the rays into records a block at a time, traces the block (its
 * coherent groups of eight as packets, the rest as a stream, stream.c) and
 * writes its answers out, so that the records stay in cache between the
 * steps. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "scene_internal.h"

/* Rays per task (as a batch's pieces), and per block of records, on the
 * stack: 256 rtk_rayhit are 20 KB, and nothing to allocate or fail. */
enum { ARRAYS_PIECE = 4096, ARRAYS_BLOCK = 256 };

typedef struct arrays_job {
    rtk_scene scene;
    const rtk_ray_arrays *a;
    size_t count, stride;
    int occluded;
} arrays_job;

/* Rays [begin, begin + n) as records, hit fields as a miss's. */
static void load(const arrays_job *j, size_t begin, size_t n, rtk_rayhit *rh)
{
    const rtk_ray_arrays *a = j->a;
    for (size_t i = 0; i < n; i++) {
        const char *p = (const char *)a->rays + (begin + i) * j->stride;
        float v[6];
        if (a->rays_double) {
            double d[6];
            memcpy(d, p, sizeof d);
            for (int k = 0; k < 6; k++)
                v[k] = (float)d[k];
        } else
            memcpy(v, p, sizeof v);
        rh[i] = (rtk_rayhit){.ray = {.org_x = v[0], .org_y = v[1], .org_z = v[2], .tnear = a->tnear, .dir_x = v[3],
                                     .dir_y = v[4], .dir_z = v[5], .tfar = a->tfar, .mask = 0xFFFFFFFFu},
                             .hit = {.primID = RTK_INVALID_GEOMETRY_ID, .geomID = RTK_INVALID_GEOMETRY_ID,
                                     .instID = RTK_INVALID_GEOMETRY_ID}};
    }
}

static void store(const arrays_job *j, size_t begin, size_t n, const rtk_rayhit *rh)
{
    const rtk_ray_arrays *a = j->a;
    for (size_t i = 0; i < n; i++) {
        const rtk_hit *h = &rh[i].hit;
        const size_t k = begin + i;
        const int hit = h->geomID != RTK_INVALID_GEOMETRY_ID;
        if (a->t_hit)
            a->t_hit[k] = hit ? rh[i].ray.tfar : INFINITY;
        if (a->geom_ids)
            a->geom_ids[k] = h->geomID;
        if (a->prim_ids)
            a->prim_ids[k] = h->primID;
        if (a->inst_ids)
            a->inst_ids[k] = h->instID;
        if (a->uvs) {
            a->uvs[2 * k] = hit ? h->u : 0.0f;
            a->uvs[2 * k + 1] = hit ? h->v : 0.0f;
        }
        if (a->normals) {
            /* (a miss's Ng is not read: a packet leaves it undefined) */
            const float len = hit ? sqrtf(h->Ng_x * h->Ng_x + h->Ng_y * h->Ng_y + h->Ng_z * h->Ng_z) : 0.0f;
            const float s = len > 0.0f ? 1.0f / len : 0.0f;
            a->normals[3 * k] = hit ? h->Ng_x * s : 0.0f;
            a->normals[3 * k + 1] = hit ? h->Ng_y * s : 0.0f;
            a->normals[3 * k + 2] = hit ? h->Ng_z * s : 0.0f;
        }
    }
}

/* Whether records r[0..8) are a coherent group: one origin (bit for bit),
 * directions of one octant, every ray plain (valid, in the kernels'
 * range).  Camera rays through neighbouring pixels are; a packet kernel
 * traces such a group with one walk. */
static int coherent8(const rtk_rayhit *r)
{
    uint32_t signs = 0, any = 0;
    for (int i = 0; i < 8; i++) {
        const rtk_ray *x = &r[i].ray;
        if (ray_check(x) != RAY_PLAIN || memcmp(&x->org_x, &r[0].ray.org_x, 3 * sizeof(float)))
            return 0;
        uint32_t d[3];
        memcpy(d, &x->dir_x, sizeof d);
        const uint32_t sg = (d[0] >> 31) | (d[1] >> 31) << 1 | (d[2] >> 31) << 2;
        signs |= i ? sg ^ any : 0;
        any = i ? any : sg;
    }
    return signs == 0;
}

/* The coherent groups of eight among records [0, n) through the packet
 * kernel (rtk_intersect8 / rtk_occluded8), each traced ray's mask then set
 * to 0 so that the stream passes over it.  Nothing where the scene's
 * packets of eight go ray by ray anyway. */
static void trace_coherent(rtk_scene s, rtk_rayhit *block, size_t n, int occluded)
{
    if (s->packet[occluded][1].width < 4)
        return;
    _Alignas(32) rtk_rayhit8 p;
    for (size_t g = 0; g + 8 <= n; g += 8) {
        const rtk_rayhit *r = &block[g];
        if (!coherent8(r))
            continue;
        /* into the packet: the directions lane by lane, the rest shared by
         * the group (one origin; load()'s tnear, tfar, time, mask) */
        for (int i = 0; i < 8; i++) {
            p.ray.org_x[i] = r[0].ray.org_x, p.ray.org_y[i] = r[0].ray.org_y, p.ray.org_z[i] = r[0].ray.org_z;
            p.ray.tnear[i] = r[0].ray.tnear, p.ray.time[i] = 0.0f, p.ray.tfar[i] = r[0].ray.tfar;
            p.ray.dir_x[i] = r[i].ray.dir_x, p.ray.dir_y[i] = r[i].ray.dir_y, p.ray.dir_z[i] = r[i].ray.dir_z;
            p.ray.mask[i] = 0xFFFFFFFFu, p.ray.id[i] = 0, p.ray.flags[i] = 0;
            p.hit.primID[i] = p.hit.geomID[i] = p.hit.instID[i] = RTK_INVALID_GEOMETRY_ID;
        }
        if (occluded ? rtk_occluded8(s, NULL, &p.ray) : rtk_intersect8(s, NULL, &p))
            continue; /* (cannot fail on a checked scene) the stream traces them */
        /* back: what the answers are read from (tfar, the hit) */
        for (int i = 0; i < 8; i++) {
            rtk_rayhit *x = &block[g + (size_t)i];
            x->ray.tfar = p.ray.tfar[i];
            x->ray.mask = 0; /* traced: the stream passes over it */
            if (occluded)
                continue;
            x->hit = (rtk_hit){.Ng_x = p.hit.Ng_x[i], .Ng_y = p.hit.Ng_y[i], .Ng_z = p.hit.Ng_z[i], .u = p.hit.u[i],
                               .v = p.hit.v[i], .primID = p.hit.primID[i], .geomID = p.hit.geomID[i],
                               .instID = p.hit.instID[i]};
        }
    }
}

static void arrays_range(const arrays_job *j, size_t begin, size_t end)
{
    rtk_rayhit block[ARRAYS_BLOCK];
    const size_t room = ARRAYS_BLOCK;
    const rtk_query q = {.context = NULL, .inst_id = RTK_INVALID_GEOMETRY_ID};
    for (size_t at = begin; at < end; at += room) {
        const size_t n = end - at < room ? end - at : room;
        load(j, at, n, block);
        trace_coherent(j->scene, block, n, j->occluded);
        if (j->occluded) {
            /* each record's ray (first in it): an occluded one's tfar becomes -inf */
            stream_trace(j->scene, (char *)block, n, sizeof *block, 1, &q);
            for (size_t i = 0; i < n; i++)
                j->a->occluded[at + i] = block[i].ray.tfar == -INFINITY;
        } else {
            stream_trace(j->scene, (char *)block, n, sizeof *block, 0, &q);
            store(j, at, n, block);
        }
    }
}

static void arrays_piece(void *data, uint32_t index)
{
    const arrays_job *j = data;
    const size_t begin = (size_t)index * ARRAYS_PIECE;
    arrays_range(j, begin, j->count - begin < ARRAYS_PIECE ? j->count : begin + ARRAYS_PIECE);
}

static rtk_error arrays(rtk_scene s, const rtk_ray_arrays *a, size_t count, int occluded, const char *fn)
{
    if (!s)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "%s: scene is NULL", fn);
    if (!a)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: arrays is NULL", fn);
    const size_t size = a->rays_double ? 6 * sizeof(double) : 6 * sizeof(float);
    const size_t stride = a->ray_stride ? a->ray_stride : size;
    rtk_error err = array_check(s, a->rays, count, stride, size, "rays", fn);
    if (err)
        return err;
    if (count && a->rays_double && (uintptr_t)a->rays % 8)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: the rays (double) at %p are not aligned to 8 bytes",
                        fn, a->rays);
    if (!(a->tnear >= 0.0f && a->tnear <= a->tfar))
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT,
                        "%s: tnear %g and tfar %g: tnear must be at least 0 and at most tfar, neither NaN", fn,
                        (double)a->tnear, (double)a->tfar);
    if (scene_not_committing(s, fn))
        return RTK_ERROR_INVALID_OPERATION;
    if (!s->accel)
        return rtk_fail(s->device, RTK_ERROR_INVALID_OPERATION, "%s: the scene was never committed", fn);
    if (!count)
        return RTK_OK;
    const size_t pieces = (count + ARRAYS_PIECE - 1) / ARRAYS_PIECE;
    if (pieces > UINT32_MAX)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: %zu rays are more than a batch takes", fn, count);
    const arrays_job job = {.scene = s, .a = a, .count = count, .stride = stride, .occluded = occluded};
    rtk_device_for(s->device, (uint32_t)pieces, arrays_piece, (void *)&job);
    return RTK_OK;
}

rtk_error rtk_intersect_arrays(rtk_scene s, const rtk_ray_arrays *a, size_t count)
{
    return arrays(s, a, count, 0, "rtk_intersect_arrays");
}

rtk_error rtk_occluded_arrays(rtk_scene s, const rtk_ray_arrays *a, size_t count)
{
    static const char fn[] = "rtk_occluded_arrays";
    if (s && a && count && !a->occluded)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: occluded is NULL (count %zu)", fn, count);
    return arrays(s, a, count, 1, fn);
}
