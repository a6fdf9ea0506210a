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

/* Block t's vertices into v (three per triangle); their count. */
static int block_vertices(const rtk_triangle4 *t, int vertices, double v[12][3])
{
    const rtk_triangle4v *tv = (const rtk_triangle4v *)t;
    int nv = 0;
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
    }
    return nv;
}

/* The box's axes, as floats: the third along n, the first along e made
 * perpendicular to it (both rounded from double), the second their cross
 * product in float (rtk_obb_axis1: what the nodes' boxes do not store);
 * the coordinate axes where n has no length or e lies along it, or
 * anything is not finite. */
static void obb_axes(rtk_block_obb *o, const double *n, const double *e)
{
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
    }
    if (!ok) {
        memset(ax, 0, sizeof ax);
        ax[0][0] = ax[2][2] = 1.0;
    }
    for (int k = 0; k < 3; k++) {
        o->axis[0][k] = (float)ax[0][k];
        o->axis[2][k] = (float)ax[2][k];
    }
    rtk_obb_axis1(o->axis[2], o->axis[0], o->axis[1]);
}

/* The vertices' extents along the float axes, lo and hi (in double), and
 * vmag, the largest |v|_1 of a vertex: the centre and the half extents
 * about the centre as stored. */
static void obb_extents(rtk_block_obb *o, const double *lo, const double *hi, double vmag, int any)
{
    double c[3] = {0.0, 0.0, 0.0};
    for (int r = 0; r < 3; r++)
        for (int k = 0; k < 3; k++)
            c[k] += 0.5 * (lo[r] + hi[r]) * o->axis[r][k];
    /* (no finite extents: a centre of 0, and the half extents below are
     * infinite, so no NaN reaches the boxes made from this one) */
    for (int k = 0; k < 3; k++)
        o->c[k] = fabs(c[k]) < INFINITY ? (float)c[k] : 0.0f;
    /* the largest |x|_1 of the vertices and the centre */
    const double cm = fabs(o->c[0]) + fabs(o->c[1]) + fabs(o->c[2]);
    const double mag = cm > vmag ? cm : vmag;
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
        /* a box with nothing finite (never the case: the builders keep
         * finite triangles only) is a box no query leaves out */
        o->h[r] = any && h == h ? hf : INFINITY;
    }
    o->pad = 0.0f;
}

/* The vertices' extents along o's axes, grown into lo, hi and vmag. */
static void obb_grow(const rtk_block_obb *o, double v[][3], int nv, double *lo, double *hi, double *vmag)
{
    for (int i = 0; i < nv; i++) {
        for (int r = 0; r < 3; r++) {
            const double x = o->axis[r][0] * v[i][0] + o->axis[r][1] * v[i][1] + o->axis[r][2] * v[i][2];
            lo[r] = x < lo[r] ? x : lo[r];
            hi[r] = x > hi[r] ? x : hi[r];
        }
        const double m = fabs(v[i][0]) + fabs(v[i][1]) + fabs(v[i][2]);
        *vmag = m > *vmag ? m : *vmag;
    }
}

/* The summed normal (area weighted) of the triangles v[3i..3i+2] into n,
 * and their longest first edge into e (unchanged when there are none). */
static void normal_and_edge(double v[][3], int nv, double *n, double *e)
{
    double elen = -1.0;
    for (int i = 0; i < nv; i += 3) {
        const double *a = v[i], *b = v[i + 1], *c = v[i + 2];
        const double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        const double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        n[0] += e1[1] * e2[2] - e1[2] * e2[1];
        n[1] += e1[2] * e2[0] - e1[0] * e2[2];
        n[2] += e1[0] * e2[1] - e1[1] * e2[0];
        const double l1 = e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2];
        if (l1 > elen) {
            elen = l1;
            memcpy(e, e1, sizeof e1);
        }
    }
}

/* The box of block t; returns whether it is worth a test (rtk_block_bounds). */
static int obb_make(rtk_block_obb *o, const rtk_triangle4 *t, int vertices)
{
    double v[12][3];
    const int nv = block_vertices(t, vertices, v);
    double n[3] = {0.0, 0.0, 0.0}, e[3] = {1.0, 0.0, 0.0};
    normal_and_edge(v, nv, n, e);
    obb_axes(o, n, e);
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY}, vmag = 0.0;
    obb_grow(o, v, nv, lo, hi, &vmag);
    obb_extents(o, lo, hi, vmag, nv > 0);
    /* the axis-aligned box's thinnest side, against the box's thickness */
    double thin = INFINITY;
    for (int k = 0; k < 3; k++) {
        double l = INFINITY, h = -INFINITY;
        for (int i = 0; i < nv; i++)
            l = v[i][k] < l ? v[i][k] : l, h = v[i][k] > h ? v[i][k] : h;
        thin = h - l < thin ? h - l : thin;
    }
    return (double)o->h[2] < 0.25 * thin;
}

/* ---- the boxes of the nodes' children ---- */

/* A node of a tree of width w (rtk_bvh4_node or rtk_bvh8_node): its
 * children and their axis-aligned boxes' sides, read the same way for
 * both. */
typedef struct node_view {
    const uint32_t *child;
    const float *lower[3], *upper[3];
} node_view;

static node_view node_at(const rtk_accel *a, uint32_t i, int w)
{
    node_view v;
    if (w == 8) {
        const rtk_bvh8_node *n = &((const rtk_bvh8_node *)a->nodes)[i];
        v = (node_view){n->child, {n->lower_x, n->lower_y, n->lower_z}, {n->upper_x, n->upper_y, n->upper_z}};
    } else {
        const rtk_bvh4_node *n = &((const rtk_bvh4_node *)a->nodes)[i];
        v = (node_view){n->child, {n->lower_x, n->lower_y, n->lower_z}, {n->upper_x, n->upper_y, n->upper_z}};
    }
    return v;
}

/* Row r of node i's children's boxes (rtk_block_bounds.node_obb). */
static inline float *obb_row(float *rows, uint32_t i, int w, int r)
{
    return rows + ((size_t)i * RTK_NODE_OBB_ROWS + (size_t)r) * (size_t)w;
}

/* A child's box from the boxes of its own children (lanes of node m,
 * made first): along each axis u, lane j's vertices lie within
 * c_j . u +- sum_k h_jk |a_jk . u|, the axes being orthonormal; the float
 * axes are within 2^-22 of orthonormal entry by entry, which moves that
 * by under 2^-19 of sum_k h_jk (2^-16 is added), and the double products'
 * rounding is within the 2^-40 mag that obb_extents adds. */
static void obb_from_lanes(const rtk_block_obb *o, float *rows, uint32_t m, const node_view *mv, int w, double *lo,
                           double *hi, double *vmag)
{
    for (int j = 0; j < w; j++) {
        if (mv->child[j] == RTK_BVH4_EMPTY)
            continue;
        double c[3], h[3];
        float ax[3][3];
        for (int k = 0; k < 3; k++) {
            c[k] = obb_row(rows, m, w, k)[j];
            h[k] = obb_row(rows, m, w, 3 + k)[j];
            ax[0][k] = obb_row(rows, m, w, 6 + k)[j];
            ax[2][k] = obb_row(rows, m, w, 9 + k)[j];
        }
        rtk_obb_axis1(ax[2], ax[0], ax[1]);
        const double hs = h[0] + h[1] + h[2];
        if (!(hs < INFINITY)) {
            /* a lane that leaves nothing out: neither does this box (its
             * support would be infinity times a zero, NaN, and the
             * comparisons below would pass it over) */
            for (int r = 0; r < 3; r++)
                lo[r] = -INFINITY, hi[r] = INFINITY;
            continue;
        }
        for (int r = 0; r < 3; r++) {
            const double cu = o->axis[r][0] * c[0] + o->axis[r][1] * c[1] + o->axis[r][2] * c[2];
            double ext = hs * 0x1p-16;
            for (int k = 0; k < 3; k++)
                ext += h[k] * fabs((double)o->axis[r][0] * ax[k][0] + (double)o->axis[r][1] * ax[k][1] +
                                   (double)o->axis[r][2] * ax[k][2]);
            lo[r] = cu - ext < lo[r] ? cu - ext : lo[r];
            hi[r] = cu + ext > hi[r] ? cu + ext : hi[r];
        }
        /* |v|_1 <= |c|_1 + sqrt(3) |v - c|, and |v - c| under 1.01 |h| */
        const double m1 = fabs(c[0]) + fabs(c[1]) + fabs(c[2]) + 2.0 * hs;
        *vmag = m1 > *vmag ? m1 : *vmag;
    }
}

/* A leaf's box: as a block's (obb_make), from all its blocks' vertices.
 * Its triangles' summed normal into n. */
static void leaf_obb(rtk_block_obb *o, double *n, const rtk_accel *a, uint32_t ref, int vertices)
{
    double v[48][3], e[3] = {1.0, 0.0, 0.0};
    int nv = 0;
    for (uint32_t b = rtk_leaf_first(ref), end = b + rtk_leaf_blocks(ref); b < end; b++)
        nv += block_vertices(&a->tris[b], vertices, (double(*)[3])v[nv]);
    normal_and_edge(v, nv, n, e);
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY}, vmag = 0.0;
    obb_axes(o, n, e);
    obb_grow(o, v, nv, lo, hi, &vmag);
    obb_extents(o, lo, hi, vmag, nv > 0);
}

/* Node i's children's boxes into its rows, its subtree's first, and the
 * summed normals of each child's triangles (area weighted) into nsum:
 * an inner child's box lies along its summed normal and the longest side
 * of its axis-aligned box (the next where that lies near the normal). */
static void node_obbs(float *rows, const rtk_accel *a, uint32_t i, int w, int vertices, double nsum[][3])
{
    const node_view nv = node_at(a, i, w);
    for (int c = 0; c < w; c++) {
        const uint32_t ref = nv.child[c];
        rtk_block_obb o = {{0.0f, 0.0f, 0.0f}, {INFINITY, INFINITY, INFINITY}, {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}, 0.0f};
        double *n = nsum[c];
        n[0] = n[1] = n[2] = 0.0;
        if (ref == RTK_BVH4_EMPTY) {
            /* (its box leaves nothing out) */
        } else if (ref & RTK_BVH4_LEAF_BIT) {
            leaf_obb(&o, n, a, ref, vertices);
        } else {
            double sub[8][3];
            node_obbs(rows, a, ref, w, vertices, sub);
            for (int j = 0; j < w; j++)
                for (int k = 0; k < 3; k++)
                    n[k] += sub[j][k];
            int order[3] = {0, 1, 2};
            for (int x = 0; x < 3; x++)
                for (int y = x + 1; y < 3; y++)
                    if ((double)nv.upper[order[y]][c] - nv.lower[order[y]][c] >
                        (double)nv.upper[order[x]][c] - nv.lower[order[x]][c]) {
                        const int t = order[x];
                        order[x] = order[y];
                        order[y] = t;
                    }
            const double nn = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
            double e[3] = {0.0, 0.0, 0.0};
            e[nn > 0.0 && fabs(n[order[0]]) > 0.9 * nn ? order[1] : order[0]] = 1.0;
            obb_axes(&o, n, e);
            const node_view mv = node_at(a, ref, w);
            double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY}, vmag = 0.0;
            obb_from_lanes(&o, rows, ref, &mv, w, lo, hi, &vmag);
            obb_extents(&o, lo, hi, vmag, lo[0] <= hi[0]);
        }
        for (int k = 0; k < 3; k++) {
            obb_row(rows, i, w, k)[c] = o.c[k];
            obb_row(rows, i, w, 3 + k)[c] = o.h[k];
            obb_row(rows, i, w, 6 + k)[c] = o.axis[0][k];
            obb_row(rows, i, w, 9 + k)[c] = o.axis[2][k];
        }
    }
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
    /* A tree of nodes gets its nodes' children's boxes, a leaf's made
     * from its blocks' triangles, and its blocks none of their own (tested
     * at the leaves as well, they measured no faster: docs/benchmarks/
     * points-and-python.md); a tree of one leaf gets its blocks' boxes.
     * The header, then the boxes (and the blocks' bits): one allocation. */
    const int w = a->layout == RTK_LAYOUT_BVH8_TRIANGLE4 || a->layout == RTK_LAYOUT_BVH8_TRIANGLE4V ? 8 : 4;
    const int nodes = a->node_count && a->root != RTK_BVH4_EMPTY && !(a->root & RTK_BVH4_LEAF_BIT);
    const size_t words = (a->leaf_count + 63) / 64;
    const size_t size = nodes ? a->node_count * RTK_NODE_OBB_ROWS * w * sizeof(float)
                              : a->leaf_count * sizeof(rtk_block_obb) + words * 8;
    unsigned char *mem = mem_alloc(&a->memory, sizeof(rtk_block_obb) + size, 1);
    if (!mem)
        return NULL;
    b = (rtk_block_bounds *)mem;
    if (nodes) {
        float *rows = (float *)(mem + sizeof(rtk_block_obb));
        double nsum[8][3];
        node_obbs(rows, a, a->root, w, vertices, nsum);
        b->node_obb = rows;
    } else {
        rtk_block_obb *o = (rtk_block_obb *)(mem + sizeof(rtk_block_obb));
        uint64_t *worth = (uint64_t *)(o + a->leaf_count);
        double sum = 0.0;
        for (uint64_t i = 0; i < a->leaf_count; i++) {
            if (obb_make(&o[i], &a->tris[i], vertices))
                worth[i >> 6] |= (uint64_t)1 << (i & 63);
            const double r2 =
                (double)o[i].h[0] * o[i].h[0] + (double)o[i].h[1] * o[i].h[1] + (double)o[i].h[2] * o[i].h[2];
            sum += r2 < INFINITY ? r2 : 0.0;
        }
        b->obb = o;
        b->worth = worth;
        /* RTK_OBB_FROM times the blocks' mean squared half-diagonal: 4
         * half-diagonals */
        b->from = (float)(RTK_OBB_FROM * sum / (double)a->leaf_count);
    }
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
