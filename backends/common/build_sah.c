/*
 * Binned SAH builder for the bvh4.triangle4 layout (object splits only).
 *
 * Builds the 4-wide tree directly, as Embree's builders do: a node starts
 * with one child holding all its primitives, and the child with the largest
 * surface area is split with a binned SAH split (Wald 2007, RTK_SAH_BINS bins
 * per axis) until the node has four children or no child has more than a
 * leaf's worth of triangles.  The SAH counts leaf cost in blocks of four
 * triangles (a leaf tests four triangles for the price of one), so a range of
 * up to four triangles always becomes a leaf.
 *
 * Single-threaded and deterministic.  Past depth RTK_SAH_MEDIAN_DEPTH the
 * builder falls back to median splits, so no tree is deeper than
 * RTK_BVH4_MAX_DEPTH whatever the input.
 */
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "backend_common.h"
#include "kernels.h"
#include "bvh4_triangle4.h"
#include "geometry/triangle.h"

#define RTK_SAH_BINS 32
#define RTK_SAH_MEDIAN_DEPTH 30

/* Bounds with a fourth lane so the compiler can keep a box in one vector;
 * lane 3 carries nothing meaningful. */
typedef struct box4 {
    float lo[4], hi[4];
} box4;

/* A triangle reference: its box; lo[3] holds the geometry's index in the
 * build input and hi[3] the primitive index, as raw bits. */
typedef struct primref {
    float lo[4], hi[4];
} primref;

typedef struct range {
    uint32_t begin, end;
    box4 geom; /* bounds of the triangles */
    box4 cent; /* bounds of lo + hi (twice the centroids) */
} range;

typedef struct builder {
    const rtk_build_input *in;
    primref *refs;
    rtk_bvh4_node *nodes;
    rtk_triangle4 *tris;
    uint64_t node_count, leaf_count;
    uint32_t depth;
    double sah;
} builder;

static inline void box_empty(box4 *b)
{
    for (int k = 0; k < 4; k++) {
        b->lo[k] = FLT_MAX;
        b->hi[k] = -FLT_MAX;
    }
}

static inline void box_grow(box4 *b, const float lo[4], const float hi[4])
{
    for (int k = 0; k < 4; k++) {
        b->lo[k] = lo[k] < b->lo[k] ? lo[k] : b->lo[k];
        b->hi[k] = hi[k] > b->hi[k] ? hi[k] : b->hi[k];
    }
}

static inline void box_grow_point(box4 *b, const float p[4])
{
    box_grow(b, p, p);
}

static inline float box_half_area(const box4 *b)
{
    float dx = b->hi[0] - b->lo[0], dy = b->hi[1] - b->lo[1], dz = b->hi[2] - b->lo[2];
    if (!(dx >= 0.0f))
        return 0.0f; /* empty */
    return dx * dy + dy * dz + dz * dx;
}

static inline void ref_centroid2(const primref *r, float c[4])
{
    for (int k = 0; k < 4; k++)
        c[k] = r->lo[k] + r->hi[k];
}

static inline uint32_t ref_geom(const primref *r)
{
    return rtk_float_bits(r->lo[3]);
}

static inline uint32_t ref_prim(const primref *r)
{
    return rtk_float_bits(r->hi[3]);
}

static inline uint32_t blocks(uint32_t n)
{
    return (n + 3) >> 2;
}

/* The bin of a centroid coordinate; the partition uses the same function, so
 * binning and partitioning always agree. */
static inline int bin_of(float c, float cmin, float scale)
{
    int b = (int)((c - cmin) * scale);
    return b < 0 ? 0 : (b > RTK_SAH_BINS - 1 ? RTK_SAH_BINS - 1 : b);
}

typedef struct split {
    int axis; /* -1: no object split possible */
    int pos;  /* left = bins [0, pos) */
    float cmin, scale;
} split;

static split find_split(const builder *b, const range *r)
{
    float scale[3], cmin[3];
    box4 bins[3][RTK_SAH_BINS];
    uint32_t counts[3][RTK_SAH_BINS];
    split best = {.axis = -1};

    for (int a = 0; a < 3; a++) {
        float extent = r->cent.hi[a] - r->cent.lo[a];
        cmin[a] = r->cent.lo[a];
        scale[a] = extent > 0.0f ? (float)RTK_SAH_BINS * 0.99999f / extent : 0.0f;
        for (int i = 0; i < RTK_SAH_BINS; i++) {
            box_empty(&bins[a][i]);
            counts[a][i] = 0;
        }
    }
    if (scale[0] == 0.0f && scale[1] == 0.0f && scale[2] == 0.0f)
        return best;

    const primref *refs = b->refs;
    for (uint32_t i = r->begin; i < r->end; i++) {
        float c[4];
        ref_centroid2(&refs[i], c);
        for (int a = 0; a < 3; a++) {
            int k = bin_of(c[a], cmin[a], scale[a]);
            box_grow(&bins[a][k], refs[i].lo, refs[i].hi);
            counts[a][k]++;
        }
    }

    float best_cost = INFINITY;
    for (int a = 0; a < 3; a++) {
        if (scale[a] == 0.0f)
            continue;
        /* right_cost[k]: cost of bins [k, BINS) as one child */
        float right_cost[RTK_SAH_BINS];
        box4 acc;
        box_empty(&acc);
        uint32_t n = 0;
        for (int k = RTK_SAH_BINS - 1; k > 0; k--) {
            if (counts[a][k])
                box_grow(&acc, bins[a][k].lo, bins[a][k].hi);
            n += counts[a][k];
            right_cost[k] = box_half_area(&acc) * (float)blocks(n);
        }
        box_empty(&acc);
        n = 0;
        for (int k = 1; k < RTK_SAH_BINS; k++) {
            if (counts[a][k - 1])
                box_grow(&acc, bins[a][k - 1].lo, bins[a][k - 1].hi);
            n += counts[a][k - 1];
            if (n == 0 || n == r->end - r->begin)
                continue;
            float cost = box_half_area(&acc) * (float)blocks(n) + right_cost[k];
            if (cost < best_cost) {
                best_cost = cost;
                best.axis = a;
                best.pos = k;
                best.cmin = cmin[a];
                best.scale = scale[a];
            }
        }
    }
    return best;
}

static void range_init(range *r, uint32_t begin, uint32_t end)
{
    r->begin = begin;
    r->end = end;
    box_empty(&r->geom);
    box_empty(&r->cent);
}

static inline void range_add(range *r, const primref *p)
{
    float c[4];
    ref_centroid2(p, c);
    box_grow(&r->geom, p->lo, p->hi);
    box_grow_point(&r->cent, c);
}

static void range_recompute(const builder *b, range *r)
{
    range_init(r, r->begin, r->end);
    for (uint32_t i = r->begin; i < r->end; i++)
        range_add(r, &b->refs[i]);
}

/* Splits r into two non-empty halves. */
static void split_range(builder *b, const range *r, int median, range *left, range *right)
{
    split s = {.axis = -1};
    if (!median)
        s = find_split(b, r);
    if (s.axis < 0) {
        /* All centroids coincide, or the tree is deep: any even split is as good. */
        uint32_t mid = r->begin + (r->end - r->begin) / 2;
        range_init(left, r->begin, mid);
        range_init(right, mid, r->end);
        range_recompute(b, left);
        range_recompute(b, right);
        return;
    }
    primref *refs = b->refs;
    const int a = s.axis;
    uint32_t i = r->begin, j = r->end;
    range_init(left, 0, 0);
    range_init(right, 0, 0);
    for (;;) {
        while (i < j && bin_of(refs[i].lo[a] + refs[i].hi[a], s.cmin, s.scale) < s.pos)
            range_add(left, &refs[i++]);
        while (i < j && bin_of(refs[j - 1].lo[a] + refs[j - 1].hi[a], s.cmin, s.scale) >= s.pos)
            range_add(right, &refs[--j]);
        if (i >= j)
            break;
        primref tmp = refs[i];
        refs[i] = refs[j - 1];
        refs[j - 1] = tmp;
        range_add(left, &refs[i++]);
        range_add(right, &refs[--j]);
    }
    left->begin = r->begin;
    left->end = i;
    right->begin = i;
    right->end = r->end;
}

static const float *vertex_at(const rtk_build_geometry *g, uint32_t index)
{
    return (const float *)((const char *)g->vertices + (size_t)index * g->vertex_stride);
}

static const uint32_t *triangle_at(const rtk_build_geometry *g, size_t prim)
{
    return (const uint32_t *)((const char *)g->indices + prim * g->index_stride);
}

static uint32_t make_leaf(builder *b, const range *r)
{
    uint64_t index = b->leaf_count++;
    rtk_triangle4 *t = &b->tris[index];
    const float nan = NAN;
    for (uint32_t lane = 0; lane < 4; lane++) {
        if (r->begin + lane >= r->end) {
            t->v0x[lane] = t->v0y[lane] = t->v0z[lane] = nan;
            t->e1x[lane] = t->e1y[lane] = t->e1z[lane] = 0.0f;
            t->e2x[lane] = t->e2y[lane] = t->e2z[lane] = 0.0f;
            t->geom[lane] = t->prim[lane] = RTK_BVH4_EMPTY;
            continue;
        }
        const primref *p = &b->refs[r->begin + lane];
        const rtk_build_geometry *g = &b->in->geometries[ref_geom(p)];
        const uint32_t *tri = triangle_at(g, ref_prim(p));
        const float *v0 = vertex_at(g, tri[0]), *v1 = vertex_at(g, tri[1]), *v2 = vertex_at(g, tri[2]);
        t->v0x[lane] = v0[0];
        t->v0y[lane] = v0[1];
        t->v0z[lane] = v0[2];
        t->e1x[lane] = v1[0] - v0[0];
        t->e1y[lane] = v1[1] - v0[1];
        t->e1z[lane] = v1[2] - v0[2];
        t->e2x[lane] = v2[0] - v0[0];
        t->e2y[lane] = v2[1] - v0[1];
        t->e2z[lane] = v2[2] - v0[2];
        t->geom[lane] = g->geom_id;
        t->prim[lane] = ref_prim(p);
    }
    b->sah += box_half_area(&r->geom);
    return (uint32_t)index | RTK_BVH4_LEAF_BIT;
}

static uint32_t build_node(builder *b, const range *r, uint32_t depth)
{
    if (depth > b->depth)
        b->depth = depth;
    if (r->end - r->begin <= 4)
        return make_leaf(b, r);

    const int median = depth >= RTK_SAH_MEDIAN_DEPTH;
    range child[4];
    int nc = 1;
    child[0] = *r;
    while (nc < 4) {
        int pick = -1;
        float key = -1.0f;
        for (int i = 0; i < nc; i++) {
            uint32_t n = child[i].end - child[i].begin;
            if (n <= 4)
                continue;
            float k = median ? (float)n : box_half_area(&child[i].geom);
            if (k > key) {
                key = k;
                pick = i;
            }
        }
        if (pick < 0)
            break;
        range l, rr;
        split_range(b, &child[pick], median, &l, &rr);
        child[pick] = l;
        child[nc++] = rr;
    }

    uint64_t index = b->node_count++;
    rtk_bvh4_node *node = &b->nodes[index];
    memset(node, 0, sizeof *node);
    for (int i = 0; i < 4; i++) {
        const int used = i < nc;
        node->lower_x[i] = used ? child[i].geom.lo[0] : INFINITY;
        node->lower_y[i] = used ? child[i].geom.lo[1] : INFINITY;
        node->lower_z[i] = used ? child[i].geom.lo[2] : INFINITY;
        node->upper_x[i] = used ? child[i].geom.hi[0] : -INFINITY;
        node->upper_y[i] = used ? child[i].geom.hi[1] : -INFINITY;
        node->upper_z[i] = used ? child[i].geom.hi[2] : -INFINITY;
        node->child[i] = RTK_BVH4_EMPTY;
    }
    b->sah += box_half_area(&r->geom);
    for (int i = 0; i < nc; i++)
        b->nodes[index].child[i] = build_node(b, &child[i], depth + 1);
    return (uint32_t)index;
}

/* 64-byte aligned memory; C11 aligned_alloc wants the size rounded up to a
 * multiple of the alignment. */
static void *alloc64(size_t size)
{
    return aligned_alloc(64, (size + 63) & ~(size_t)63);
}

static void set_message(rtk_build_output *out, const char *text)
{
    snprintf(out->message, sizeof out->message, "%s", text);
}

int RTK_SYM(rtk_build_sah)(const rtk_build_input *in, rtk_build_output *out)
{
    uint64_t total = 0;
    for (uint32_t g = 0; g < in->geometry_count; g++)
        total += in->geometries[g].prim_count;
    if (total >= RTK_BVH4_LEAF_BIT) {
        set_message(out, "too many triangles for one bvh4.triangle4 structure (limit 2^31 - 1)");
        return RTK_ERROR_INVALID_ARGUMENT;
    }

    builder b = {.in = in};
    struct rtk_accel *accel = calloc(1, sizeof *accel);
    b.refs = malloc((total ? total : 1) * sizeof *b.refs);
    if (!accel || !b.refs) {
        free(accel);
        free(b.refs);
        set_message(out, "out of memory for the build's primitive references");
        return RTK_ERROR_OUT_OF_MEMORY;
    }

    /* Primitive references; triangles with a non-finite vertex or no area
     * cannot be hit and are left out. */
    range root;
    range_init(&root, 0, 0);
    uint32_t n = 0;
    uint64_t skipped = 0, degenerate = 0;
    for (uint32_t gi = 0; gi < in->geometry_count; gi++) {
        const rtk_build_geometry *g = &in->geometries[gi];
        for (size_t p = 0; p < g->prim_count; p++) {
            const uint32_t *tri = triangle_at(g, p);
            const float *v0 = vertex_at(g, tri[0]), *v1 = vertex_at(g, tri[1]), *v2 = vertex_at(g, tri[2]);
            if (!rtk_triangle_is_finite(v0, v1, v2)) {
                skipped++;
                continue;
            }
            if (rtk_triangle_is_degenerate(v0, v1, v2)) {
                degenerate++;
                continue;
            }
            primref *r = &b.refs[n++];
            for (int k = 0; k < 3; k++) {
                float lo = v0[k] < v1[k] ? v0[k] : v1[k];
                float hi = v0[k] > v1[k] ? v0[k] : v1[k];
                r->lo[k] = v2[k] < lo ? v2[k] : lo;
                r->hi[k] = v2[k] > hi ? v2[k] : hi;
            }
            r->lo[3] = rtk_bits_float(gi);
            r->hi[3] = rtk_bits_float((uint32_t)p);
            range_add(&root, r);
        }
    }
    root.end = n;

    /* Upper bounds: at most one leaf per triangle and fewer inner nodes than
     * leaves.  Untouched pages of these allocations are never committed; the
     * arrays are trimmed to size afterwards. */
    uint64_t cap = n ? n : 1;
    b.nodes = alloc64(cap * sizeof *b.nodes);
    b.tris = alloc64(cap * sizeof *b.tris);
    if (!b.nodes || !b.tris) {
        free(b.nodes);
        free(b.tris);
        free(b.refs);
        free(accel);
        set_message(out, "out of memory for the BVH");
        return RTK_ERROR_OUT_OF_MEMORY;
    }

    accel->layout = RTK_LAYOUT_BVH4_TRIANGLE4;
    accel->root = n ? build_node(&b, &root, 1) : RTK_BVH4_EMPTY;
    free(b.refs);

    /* Trim: copy into exactly sized, aligned blocks. */
    accel->nodes = b.node_count ? alloc64(b.node_count * sizeof *b.nodes) : NULL;
    accel->tris = b.leaf_count ? alloc64(b.leaf_count * sizeof *b.tris) : NULL;
    if ((b.node_count && !accel->nodes) || (b.leaf_count && !accel->tris)) {
        free(accel->nodes);
        free(accel->tris);
        free(b.nodes);
        free(b.tris);
        free(accel);
        set_message(out, "out of memory for the BVH");
        return RTK_ERROR_OUT_OF_MEMORY;
    }
    if (b.node_count)
        memcpy(accel->nodes, b.nodes, b.node_count * sizeof *b.nodes);
    if (b.leaf_count)
        memcpy(accel->tris, b.tris, b.leaf_count * sizeof *b.tris);
    free(b.nodes);
    free(b.tris);
    accel->node_count = b.node_count;
    accel->leaf_count = b.leaf_count;

    out->accel = accel;
    out->prims = n;
    out->prims_skipped = skipped;
    out->prims_degenerate = degenerate;
    out->nodes = b.node_count;
    out->leaves = b.leaf_count;
    out->bytes = b.node_count * sizeof(rtk_bvh4_node) + b.leaf_count * sizeof(rtk_triangle4);
    out->depth = n ? b.depth : 0;
    float root_area = box_half_area(&root.geom);
    out->sah_cost = root_area > 0.0f ? b.sah / root_area : 0.0;
    for (int k = 0; k < 3; k++) {
        out->lower[k] = n ? root.geom.lo[k] : 0.0f;
        out->upper[k] = n ? root.geom.hi[k] : 0.0f;
    }
    return RTK_OK;
}

void RTK_SYM(rtk_bvh4_release)(rtk_accel *accel)
{
    if (!accel)
        return;
    free(accel->nodes);
    free(accel->tris);
    free(accel);
}
