/* Rays in array form (rtk.h: rtk_intersect_arrays, rtk_occluded_arrays):
 * six numbers a ray in, an array per answer out.  Each task turns its
 * piece of the rays into records a block at a time, traces the block (its
 * coherent groups of eight as packets, the rest as a stream, stream.c) and
 * writes its answers out, so that the records stay in cache between the
 * steps.  Rays given as an image's rows (row_length) go in 4x2 blocks of
 * pixels: a packet's frustum then spans four pixels by two, not eight by
 * one. */
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
    size_t rows; /* rows a piece (even), with a->row_length; else 0 */
    int occluded;
} arrays_job;

/* A record from its ray's six numbers, hit fields as a miss's. */
static inline void record(rtk_rayhit *r, const rtk_ray_arrays *a, float ox, float oy, float oz, float dx, float dy,
                          float dz)
{
    *r = (rtk_rayhit){.ray = {.org_x = ox, .org_y = oy, .org_z = oz, .tnear = a->tnear, .dir_x = dx, .dir_y = dy,
                              .dir_z = dz, .tfar = a->tfar, .mask = 0xFFFFFFFFu},
                      .hit = {.primID = RTK_INVALID_GEOMETRY_ID, .geomID = RTK_INVALID_GEOMETRY_ID,
                              .instID = RTK_INVALID_GEOMETRY_ID}};
}

/* Rays idx[0..n) as records.  The numbers are read where they are
 * (aligned: the checks) straight into the record: copied into a local
 * array first, as they were, its wide stores and the narrow loads after
 * them stalled on store forwarding, a third of this file's time (perf,
 * camera rays through the bunny). */
static void load(const arrays_job *j, const size_t *idx, size_t n, rtk_rayhit *rh)
{
    const rtk_ray_arrays *a = j->a;
    for (size_t i = 0; i < n; i++) {
        const char *p = (const char *)a->rays + idx[i] * j->stride;
        if (a->rays_double) {
            /* (each double read as unaligned: a stride that is a multiple
             * of 4 but not of 8 leaves them so) */
            record(&rh[i], a, (float)load_f64(p), (float)load_f64(p + 8), (float)load_f64(p + 16),
                   (float)load_f64(p + 24), (float)load_f64(p + 32), (float)load_f64(p + 40));
        } else {
            const float *f = (const float *)(const void *)p;
            record(&rh[i], a, f[0], f[1], f[2], f[3], f[4], f[5]);
        }
    }
}

/* Ray k's answers written (hit: whether it has one; Ng as the kernels
 * give it, made unit length here). */
static inline void store_one(const rtk_ray_arrays *a, size_t k, int hit, float t, float u, float v, float nx,
                             float ny, float nz, uint32_t geom, uint32_t prim, uint32_t inst)
{
    if (a->t_hit)
        a->t_hit[k] = hit ? t : INFINITY;
    if (a->geom_ids)
        a->geom_ids[k] = geom;
    if (a->prim_ids)
        a->prim_ids[k] = prim;
    if (a->inst_ids)
        a->inst_ids[k] = inst;
    if (a->uvs) {
        a->uvs[2 * k] = hit ? u : 0.0f;
        a->uvs[2 * k + 1] = hit ? v : 0.0f;
    }
    if (a->normals) {
        /* (a miss's Ng is not read: a packet leaves it undefined) */
        const float len = hit ? sqrtf(nx * nx + ny * ny + nz * nz) : 0.0f;
        const float s = len > 0.0f ? 1.0f / len : 0.0f;
        a->normals[3 * k] = hit ? nx * s : 0.0f;
        a->normals[3 * k + 1] = hit ? ny * s : 0.0f;
        a->normals[3 * k + 2] = hit ? nz * s : 0.0f;
    }
}

/* Records' answers written out (idx: their rays). */
static void store(const arrays_job *j, const size_t *idx, size_t n, const rtk_rayhit *rh)
{
    for (size_t i = 0; i < n; i++) {
        const rtk_hit *h = &rh[i].hit;
        if (j->occluded)
            j->a->occluded[idx[i]] = rh[i].ray.tfar == -INFINITY;
        else
            store_one(j->a, idx[i], h->geomID != RTK_INVALID_GEOMETRY_ID, rh[i].ray.tfar, h->u, h->v, h->Ng_x,
                      h->Ng_y, h->Ng_z, h->geomID, h->primID, h->instID);
    }
}

/* Rays idx[0..8) as a packet, read from the arrays straight into its
 * lanes, traced if they are a coherent group (one origin, bit for bit,
 * directions of one octant, every ray plain: valid and within the
 * kernels' range, ray_check's rules in lanes) and their answers written
 * out from the lanes: 1; else 0, nothing traced.  Camera rays through
 * neighbouring pixels are such groups, and go without records: made,
 * checked, copied into the packet and back and read out, the records
 * took about 15% of cast_rays (perf, camera rays through the bunny). */
static int trace_group(const arrays_job *j, const size_t *idx, rtk_rayhit8 *p)
{
    const rtk_ray_arrays *a = j->a;
    float *lane[6] = {p->ray.org_x, p->ray.org_y, p->ray.org_z, p->ray.dir_x, p->ray.dir_y, p->ray.dir_z};
    for (int i = 0; i < 8; i++) {
        const char *r = (const char *)a->rays + idx[i] * j->stride;
        if (a->rays_double) {
            for (int k = 0; k < 6; k++)
                lane[k][i] = (float)load_f64(r + 8 * k); /* (as in load) */
        } else {
            const float *f = (const float *)(const void *)r;
            for (int k = 0; k < 6; k++)
                lane[k][i] = f[k];
        }
    }
    /* the lanes' bits: every origin must be lane 0's, every direction's
     * signs lane 0's */
    uint32_t bits[6][8];
    for (int k = 0; k < 6; k++)
        memcpy(bits[k], lane[k], sizeof bits[k]);
    uint32_t bad = 0;
    for (int i = 0; i < 8; i++) {
        const float ox = lane[0][i], oy = lane[1][i], oz = lane[2][i], dx = lane[3][i], dy = lane[4][i], dz = lane[5][i];
        /* plain (ray_check's rules; tnear and tfar checked by the call):
         * finite (0 * x is NaN otherwise) and within the window */
        const float z = 0.0f * ox + 0.0f * oy + 0.0f * oz + 0.0f * dx + 0.0f * dy + 0.0f * dz;
        bad |= (uint32_t)!(z == 0.0f) | (uint32_t)ray_out_of_window(ox, oy, oz, dx, dy, dz);
        bad |= (bits[0][i] ^ bits[0][0]) | (bits[1][i] ^ bits[1][0]) | (bits[2][i] ^ bits[2][0]);
        bad |= ((bits[3][i] ^ bits[3][0]) | (bits[4][i] ^ bits[4][0]) | (bits[5][i] ^ bits[5][0])) >> 31;
    }
    if (bad)
        return 0;
    for (int i = 0; i < 8; i++) {
        p->ray.tnear[i] = a->tnear, p->ray.time[i] = 0.0f, p->ray.tfar[i] = a->tfar;
        p->ray.mask[i] = 0xFFFFFFFFu, p->ray.id[i] = 0, p->ray.flags[i] = 0;
        p->hit.primID[i] = p->hit.geomID[i] = p->hit.instID[i] = RTK_INVALID_GEOMETRY_ID;
    }
    if (j->occluded ? rtk_occluded8(j->scene, NULL, &p->ray) : rtk_intersect8(j->scene, NULL, p))
        return 0; /* (cannot fail on a checked scene) the stream traces them */
    for (int i = 0; i < 8; i++) {
        if (j->occluded)
            a->occluded[idx[i]] = p->ray.tfar[i] == -INFINITY;
        else
            store_one(a, idx[i], p->hit.geomID[i] != RTK_INVALID_GEOMETRY_ID, p->ray.tfar[i], p->hit.u[i],
                      p->hit.v[i], p->hit.Ng_x[i], p->hit.Ng_y[i], p->hit.Ng_z[i], p->hit.geomID[i],
                      p->hit.primID[i], p->hit.instID[i]);
    }
    return 1;
}

/* Rays idx[0..n) (n <= ARRAYS_BLOCK) traced and their answers written:
 * each group of eight that is coherent as a packet (trace_group, where
 * the scene's packets of eight do not go ray by ray anyway), the rest as
 * records through the stream. */
static void trace_block(const arrays_job *j, const size_t *idx, size_t n)
{
    size_t rest[ARRAYS_BLOCK], m = 0;
    size_t g = 0;
    if (j->scene->packet[j->occluded][1].width >= 4) {
        _Alignas(32) rtk_rayhit8 p;
        for (; g + 8 <= n; g += 8)
            if (!trace_group(j, &idx[g], &p))
                for (int i = 0; i < 8; i++)
                    rest[m++] = idx[g + (size_t)i];
    }
    for (; g < n; g++)
        rest[m++] = idx[g];
    if (!m)
        return;
    rtk_rayhit block[ARRAYS_BLOCK];
    const rtk_query q = {.context = NULL, .inst_id = RTK_INVALID_GEOMETRY_ID};
    load(j, rest, m, block);
    /* (each record's ray first in it: an occluded one's tfar becomes -inf) */
    stream_trace(j->scene, (char *)block, m, sizeof *block, j->occluded, &q);
    store(j, rest, m, block);
}

/* Rays gathered a block at a time, in the order they are traced. */
typedef struct gather {
    const arrays_job *j;
    size_t idx[ARRAYS_BLOCK], n;
} gather;

static void gather_put(gather *g, size_t i)
{
    g->idx[g->n++] = i;
    if (g->n == ARRAYS_BLOCK) {
        trace_block(g->j, g->idx, g->n);
        g->n = 0;
    }
}

/* Rays [begin, end) of an image's rows of w rays (begin at an even row):
 * first every full 4x2 block of pixels, a row pair at a time, eight
 * consecutive records each (ARRAYS_BLOCK is a multiple of 8, so each is
 * one coherent group), then the pixels no full block takes (the last
 * columns of a width not a multiple of 4, an odd last row, a last row
 * the array ends inside) in their own order.  Each ray's answer is the
 * same in any order; only which go through the packets changes. */
/* How many full 4x2 blocks the row pair starting at ray y has (rows of w,
 * the array ending at end): those whose last pixel is in range. */
static size_t full_blocks(size_t y, size_t w, size_t end)
{
    const size_t room = y + w < end ? (end - (y + w)) / 4 : 0;
    return room < w / 4 ? room : w / 4;
}

static void arrays_rows(const arrays_job *j, size_t begin, size_t end, size_t w)
{
    gather g = {.j = j, .n = 0};
    for (size_t y = begin; y + w < end; y += 2 * w) {
        const size_t full = full_blocks(y, w, end);
        for (size_t b = 0; b < full; b++)
            for (size_t r = 0; r < 2; r++)
                for (size_t x = 0; x < 4; x++)
                    gather_put(&g, y + r * w + 4 * b + x);
    }
    for (size_t y = begin; y < end; y += 2 * w) {
        const size_t full = full_blocks(y, w, end);
        for (size_t r = 0; r < 2; r++)
            for (size_t i = y + r * w + 4 * full; i < y + (r + 1) * w && i < end; i++)
                gather_put(&g, i);
    }
    if (g.n)
        trace_block(j, g.idx, g.n);
}

static void arrays_range(const arrays_job *j, size_t begin, size_t end)
{
    size_t idx[ARRAYS_BLOCK];
    for (size_t at = begin; at < end; at += ARRAYS_BLOCK) {
        const size_t n = end - at < ARRAYS_BLOCK ? end - at : ARRAYS_BLOCK;
        for (size_t i = 0; i < n; i++)
            idx[i] = at + i;
        trace_block(j, idx, n);
    }
}

static void arrays_piece(void *data, uint32_t index)
{
    const arrays_job *j = data;
    if (j->rows) {
        const size_t w = j->a->row_length, begin = (size_t)index * j->rows * w;
        arrays_rows(j, begin, j->count - begin < j->rows * w ? j->count : begin + j->rows * w, w);
        return;
    }
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
    /* pieces of about ARRAYS_PIECE rays, whole row pairs with row_length
     * (rows of 4 or more, two of them at least: else no 4x2 block).  A
     * piece's rows * w is at most the larger of ARRAYS_PIECE and 2 w <=
     * count: no overflow */
    const size_t w = a->row_length;
    const size_t rows = w >= 4 && w <= count / 2 ? ARRAYS_PIECE / w < 2 ? 2 : ARRAYS_PIECE / w & ~(size_t)1 : 0;
    const size_t per = rows ? rows * w : ARRAYS_PIECE;
    const size_t pieces = count / per + (count % per != 0);
    if (pieces > UINT32_MAX)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "%s: %zu rays are more than a batch takes", fn, count);
    const arrays_job job = {.scene = s, .a = a, .count = count, .stride = stride, .rows = rows, .occluded = occluded};
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
