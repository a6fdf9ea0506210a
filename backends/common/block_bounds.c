/* Oriented boxes of the leaf blocks (block_bounds.h). */
#include <math.h>
#include <stdatomic.h>
#include <string.h>

#include "block_bounds.h"
#include "memory.h"

#ifndef RTK_OBB_FROM
#define RTK_OBB_FROM 16.0
#endif

/* The float just above a finite x >= 0. */
static float up(float x) { return nextafterf(x, INFINITY); }

/* The box of block t; returns whether it is worth a test (rtk_block_bounds). */
static int obb_make(rtk_block_obb *o, const rtk_triangle4 *t, int vertices)
{
    const rtk_triangle4v *tv = (const rtk_triangle4v *)t;
    double v[12][3];
    int nv = 0;
    double n[3] = {0.0, 0.0, 0.0}, e[3] = {1.0, 0.0, 0.0}, elen = -1.0;
    for (int k = 0; k < 4; k++) {
        if (t->prim[k] == RTK_BVH4_EMPTY)
            continue;
        double *a = v[nv], *b = v[nv + 1], *c = v[nv + 2];
        nv += 3;
        a[0] = t->v0x[k], a[1] = t->v0y[k], a[2] = t->v0z[k];
        if (vertices) {
            b[0] = tv->v1x[k], b[1] = tv->v1y[k], b[2] = tv->v1z[k];
            c[0] = tv->v2x[k], c[1] = tv->v2y[k], c[2] = tv->v2z[k];
        } else { /* v0 + e in double: exact, the triangle the kernels see */
            b[0] = a[0] + t->e1x[k], b[1] = a[1] + t->e1y[k], b[2] = a[2] + t->e1z[k];
            c[0] = a[0] + t->e2x[k], c[1] = a[1] + t->e2y[k], c[2] = a[2] + t->e2z[k];
        }
        const double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        const double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        n[0] += e1[1] * e2[2] - e1[2] * e2[1];
        n[1] += e1[2] * e2[0] - e1[0] * e2[2];
        n[2] += e1[0] * e2[1] - e1[1] * e2[0];
        const double l1 = e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2];
        if (l1 > elen) {
            elen = l1;
            memcpy(e, e1, sizeof e);
        }
    }
    /* the axes in double, then as floats: no area, or anything not
     * finite, and they are the coordinate axes */
    double ax[3][3];
    const double nn = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    int ok = nn > 0.0 && isfinite(nn);
    if (ok) {
        for (int k = 0; k < 3; k++)
            ax[2][k] = n[k] / nn;
        const double d = e[0] * ax[2][0] + e[1] * ax[2][1] + e[2] * ax[2][2];
        for (int k = 0; k < 3; k++)
            ax[0][k] = e[k] - d * ax[2][k];
        const double l = sqrt(ax[0][0] * ax[0][0] + ax[0][1] * ax[0][1] + ax[0][2] * ax[0][2]);
        ok = l > 0.0 && isfinite(l);
        for (int k = 0; ok && k < 3; k++)
            ax[0][k] /= l;
        ax[1][0] = ax[2][1] * ax[0][2] - ax[2][2] * ax[0][1];
        ax[1][1] = ax[2][2] * ax[0][0] - ax[2][0] * ax[0][2];
        ax[1][2] = ax[2][0] * ax[0][1] - ax[2][1] * ax[0][0];
    }
    if (!ok) {
        memset(ax, 0, sizeof ax);
        ax[0][0] = ax[1][1] = ax[2][2] = 1.0;
    }
    for (int r = 0; r < 3; r++)
        for (int k = 0; k < 3; k++)
            o->axis[r][k] = (float)ax[r][k];
    /* the extents along the float axes, then the centre and the half
     * extents about the centre as stored */
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int i = 0; i < nv; i++)
        for (int r = 0; r < 3; r++) {
            const double x = o->axis[r][0] * v[i][0] + o->axis[r][1] * v[i][1] + o->axis[r][2] * v[i][2];
            lo[r] = x < lo[r] ? x : lo[r];
            hi[r] = x > hi[r] ? x : hi[r];
        }
    double c[3] = {0.0, 0.0, 0.0};
    for (int r = 0; r < 3; r++)
        for (int k = 0; k < 3; k++)
            c[k] += 0.5 * (lo[r] + hi[r]) * o->axis[r][k];
    double mag = 0.0; /* the largest |x|_1 of the vertices and the centre */
    for (int k = 0; k < 3; k++)
        o->c[k] = (float)c[k];
    for (int i = 0; i <= nv; i++) {
        const float *cf = o->c;
        const double m = i < nv ? fabs(v[i][0]) + fabs(v[i][1]) + fabs(v[i][2]) : fabs(cf[0]) + fabs(cf[1]) + fabs(cf[2]);
        mag = m > mag ? m : mag;
    }
    for (int r = 0; r < 3; r++) {
        const double cc =
            o->axis[r][0] * (double)o->c[0] + o->axis[r][1] * (double)o->c[1] + o->axis[r][2] * (double)o->c[2];
        /* raised past the double dot products' rounding: a few ulps of
         * their terms, each at most mag (the axes' entries are under 1 +
         * 2^-20) */
        double h = fmax(hi[r] - cc, cc - lo[r]);
        h = h * (1.0 + 0x1p-30) + 0x1p-40 * mag;
        float hf = (float)h;
        if (!((double)hf >= h))
            hf = up(hf);
        /* a block with nothing finite (never the case: the builders keep
         * finite triangles only) is a box no query leaves out */
        o->h[r] = nv && h == h ? hf : INFINITY;
    }
    o->pad = 0.0f;
    /* the axis-aligned box's thinnest side, against the box's thickness */
    double thin = INFINITY;
    for (int k = 0; k < 3; k++) {
        double lo = INFINITY, hi = -INFINITY;
        for (int i = 0; i < nv; i++)
            lo = v[i][k] < lo ? v[i][k] : lo, hi = v[i][k] > hi ? v[i][k] : hi;
        thin = hi - lo < thin ? hi - lo : thin;
    }
    return (double)o->h[2] < 0.25 * thin;
}

const rtk_block_bounds *rtk_block_bounds_of(const rtk_accel *ac)
{
    rtk_accel *a = (rtk_accel *)ac; /* the boxes are the one thing a query adds to a tree */
    rtk_block_bounds *b = atomic_load_explicit(&a->block_bounds, memory_order_acquire);
    if (b || !a->tris || !a->leaf_count)
        return b;
    int vertices;
    switch (a->layout) {
    case RTK_LAYOUT_BVH4_TRIANGLE4:
    case RTK_LAYOUT_BVH8_TRIANGLE4: vertices = 0; break;
    case RTK_LAYOUT_BVH4_TRIANGLE4V:
    case RTK_LAYOUT_BVH8_TRIANGLE4V: vertices = 1; break;
    default: return NULL;
    }
    /* the header, the boxes, the bits: one allocation */
    const size_t words = (a->leaf_count + 63) / 64;
    unsigned char *mem =
        mem_alloc(&a->memory, sizeof(rtk_block_obb) + a->leaf_count * sizeof(rtk_block_obb) + words * 8, 1);
    if (!mem)
        return NULL;
    b = (rtk_block_bounds *)mem;
    rtk_block_obb *o = (rtk_block_obb *)(mem + sizeof(rtk_block_obb));
    uint64_t *worth = (uint64_t *)(o + a->leaf_count);
    double sum = 0.0;
    for (uint64_t i = 0; i < a->leaf_count; i++) {
        if (obb_make(&o[i], &a->tris[i], vertices))
            worth[i >> 6] |= (uint64_t)1 << (i & 63);
        const double r2 = (double)o[i].h[0] * o[i].h[0] + (double)o[i].h[1] * o[i].h[1] + (double)o[i].h[2] * o[i].h[2];
        sum += r2 < INFINITY ? r2 : 0.0;
    }
    b->obb = o;
    b->worth = worth;
    /* RTK_OBB_FROM times the blocks' mean squared half-diagonal: 4
     * half-diagonals */
    b->from = (float)(RTK_OBB_FROM * sum / (double)a->leaf_count);
    rtk_block_bounds *seen = NULL;
    if (!atomic_compare_exchange_strong_explicit(&a->block_bounds, &seen, b, memory_order_acq_rel,
                                                 memory_order_acquire)) {
        mem_free(&a->memory, b); /* another query's came first */
        return seen;
    }
    return b;
}

void rtk_block_bounds_drop(rtk_accel *a)
{
    mem_free(&a->memory, atomic_exchange_explicit(&a->block_bounds, NULL, memory_order_acq_rel));
}
