/*
 * Binned SAH builder for the bvh4.triangle4, bvh8.triangle4 and
 * bvh4.triangle4i layouts (object splits only).
 *
 * Builds the N-wide tree directly, as Embree's builders do: a node starts
 * with one child holding all its primitives, and the child with the largest
 * surface area is split with a binned SAH split (Wald 2007, RTK_SAH_BINS bins
 * per axis) until the node has N children or no child has more than a
 * leaf's worth of triangles.  The SAH counts leaf cost in blocks of four
 * triangles (a leaf tests four triangles for the price of one), so a range of
 * up to four triangles always becomes a leaf.
 *
 * Single-threaded and deterministic.  Past depth RTK_SAH_MEDIAN_DEPTH the
 * builder falls back to median splits, so no tree is deeper than
 * RTK_BVH4_MAX_DEPTH whatever the input.
 */
#define _DEFAULT_SOURCE /* MAP_ANONYMOUS, MAP_NORESERVE */
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "backend_common.h"
#include "kernels.h"
#include "bvh4_triangle4.h"
#include "geometry/triangle.h"
#include "simd/simd.h"

#define RTK_SAH_BINS 32
#define RTK_SAH_MEDIAN_DEPTH 30

/* A box as two vectors; lane 3 carries nothing meaningful. */
typedef struct box4 {
    vfloat4 lo, hi;
} box4;

/* A triangle reference: its box; lo[3] holds the geometry's index in the
 * build input and hi[3] the primitive index, as raw bits. */
typedef struct primref {
    _Alignas(16) float lo[4];
    float hi[4];
} primref;

typedef struct range {
    uint32_t begin, end;
    box4 geom; /* bounds of the triangles */
    box4 cent; /* bounds of the centroids */
} range;

typedef struct builder {
    const rtk_build_input *in;
    primref *refs;
    int width;         /* 4 or 8 children per node */
    size_t node_size;  /* sizeof(rtk_bvh4_node) or sizeof(rtk_bvh8_node) */
    void *nodes;
    rtk_triangle4 *tris;   /* leaf blocks, triangle4 layouts */
    rtk_triangle4i *trisi; /* leaf blocks, triangle4i */
    size_t leaf_size;      /* the size of one of those */
    uint64_t node_count, leaf_count;
    uint32_t depth;
    double sah;
} builder;

static inline box4 box_empty(void)
{
    return (box4){vf4_set1(FLT_MAX), vf4_set1(-FLT_MAX)};
}

static inline void box_grow(box4 *b, vfloat4 lo, vfloat4 hi)
{
    b->lo = vf4_min(b->lo, lo);
    b->hi = vf4_max(b->hi, hi);
}

static inline float box_half_area(const box4 *b)
{
    _Alignas(16) float d[4];
    vf4_store(d, vf4_sub(b->hi, b->lo));
    if (!(d[0] >= 0.0f))
        return 0.0f; /* empty */
    return d[0] * d[1] + d[1] * d[2] + d[2] * d[0];
}

static inline float box_lo(const box4 *b, int axis)
{
    _Alignas(16) float v[4];
    vf4_store(v, b->lo);
    return v[axis];
}

static inline float box_hi(const box4 *b, int axis)
{
    _Alignas(16) float v[4];
    vf4_store(v, b->hi);
    return v[axis];
}

/* Centroid as lo/2 + hi/2, which cannot overflow for finite boxes.  Lane 3
 * (the ids, often denormal as floats) is cleared first: arithmetic on
 * denormals costs a microcode assist per instruction on x86. */
static inline vfloat4 centroid(vfloat4 lo, vfloat4 hi)
{
    const vbool4 xyz = vb4_from_bits(7);
    const vfloat4 half = vf4_set1(0.5f);
    return vf4_madd(vf4_keep(xyz, lo), half, vf4_mul(vf4_keep(xyz, hi), half));
}

static inline uint32_t ref_geom(const primref *r)
{
    return rtk_float_bits(r->lo[3]);
}

static inline uint32_t ref_prim(const primref *r)
{
    return rtk_float_bits(r->hi[3]);
}

/* Leaf blocks of four for counts in lanes 0..2, as floats. */
static inline vfloat4 block_count(vint4 n)
{
    return vf4_from_vi4(vi4_shr(vi4_add(n, vi4_set1(3)), 2));
}

/* Half surface areas of three boxes, one per lane (lane 3 unspecified). */
static inline vfloat4 half_areas3(const box4 box[3])
{
    vfloat4 dx = vf4_sub(box[0].hi, box[0].lo), dy = vf4_sub(box[1].hi, box[1].lo);
    vfloat4 dz = vf4_sub(box[2].hi, box[2].lo), dw = dz;
    vf4_transpose(&dx, &dy, &dz, &dw); /* now dx = the three boxes' x extents */
    vfloat4 area = vf4_madd(dx, dy, vf4_madd(dy, dz, vf4_mul(dz, dx)));
    /* an empty box (lo > hi) has no area; its extents are negative */
    return vf4_keep(vf4_ge(dx, vf4_set1(0.0f)), area);
}

/* The mapping from centroids to bins, per axis in lanes 0..2.  Binning and
 * partitioning both go through bin_of, so they always agree. */
typedef struct binmap {
    vfloat4 cmin, scale;
    vfloat4 top; /* bins - 1 */
} binmap;

/* Clamped in float before the conversion, so NaN (0 * inf from a denormal
 * extent) and overflow land in a bin too. */
static inline vint4 bin_of(const binmap *m, vfloat4 c)
{
    vfloat4 x = vf4_mul(vf4_sub(c, m->cmin), m->scale);
    return vi4_from_vf4_trunc(vf4_min(vf4_max(x, vf4_set1(0.0f)), m->top));
}

typedef struct split {
    int axis;   /* -1: no object split possible */
    int pos;    /* left = bins [0, pos) */
    float cost; /* the two halves' areas times their blocks of four */
    binmap map;
} split;

/* Fewer bins for small ranges: a range of n triangles has at most n distinct
 * split positions, and clearing and sweeping 32 bins would cost more than
 * binning the triangles. */
static inline int bin_count(uint32_t n)
{
    uint32_t b = n + 4;
    return b < RTK_SAH_BINS ? (int)b : RTK_SAH_BINS;
}

/* Adds one reference's box to its bin on each axis (bin indices in lanes 0..2 of k). */
static inline void bin_add(box4 bins[3][RTK_SAH_BINS], int32_t counts[RTK_SAH_BINS][4], vint4 k, vfloat4 lo,
                           vfloat4 hi)
{
    const int x = vi4_lane(k, 0), y = vi4_lane(k, 1), z = vi4_lane(k, 2);
    box_grow(&bins[0][x], lo, hi);
    counts[x][0]++;
    box_grow(&bins[1][y], lo, hi);
    counts[y][1]++;
    box_grow(&bins[2][z], lo, hi);
    counts[z][2]++;
}

static split find_split(const builder *b, const range *r)
{
    split best = {.axis = -1};
    const uint32_t n = r->end - r->begin;
    const int nb = bin_count(n);
    _Alignas(16) float ext[4], scale[4] = {0, 0, 0, 0};
    vf4_store(ext, vf4_sub(r->cent.hi, r->cent.lo));
    int splittable = 0;
    for (int a = 0; a < 3; a++)
        if (ext[a] > 0.0f && ext[a] <= FLT_MAX) {
            scale[a] = (float)nb * 0.99999f / ext[a];
            splittable = 1;
        }
    if (!splittable)
        return best;
    binmap map = {.cmin = r->cent.lo, .scale = vf4_load(scale), .top = vf4_set1((float)(nb - 1))};

    /* Bins: one box per axis and bin, counts per bin with one lane per axis. */
    box4 bins[3][RTK_SAH_BINS];
    _Alignas(16) int32_t counts[RTK_SAH_BINS][4];
    for (int a = 0; a < 3; a++)
        for (int k = 0; k < nb; k++)
            bins[a][k] = box_empty();
    memset(counts, 0, sizeof counts);

    /* Two references per step: both bin indices first, so the two sets of
     * bin updates can overlap. */
    const primref *refs = b->refs;
    uint32_t i = r->begin;
    for (; i + 1 < r->end; i += 2) {
        vfloat4 lo0 = vf4_load(refs[i].lo), hi0 = vf4_load(refs[i].hi);
        vfloat4 lo1 = vf4_load(refs[i + 1].lo), hi1 = vf4_load(refs[i + 1].hi);
        vint4 k0 = bin_of(&map, centroid(lo0, hi0));
        vint4 k1 = bin_of(&map, centroid(lo1, hi1));
        bin_add(bins, counts, k0, lo0, hi0);
        bin_add(bins, counts, k1, lo1, hi1);
    }
    if (i < r->end) {
        vfloat4 lo0 = vf4_load(refs[i].lo), hi0 = vf4_load(refs[i].hi);
        bin_add(bins, counts, bin_of(&map, centroid(lo0, hi0)), lo0, hi0);
    }

    /* Sweep, the three axes at once in lanes 0..2: right_cost[k] is the cost
     * of bins [k, nb) as one child. */
    vfloat4 right_cost[RTK_SAH_BINS];
    box4 acc[3] = {box_empty(), box_empty(), box_empty()};
    vint4 cnt = vi4_set1(0);
    for (int k = nb - 1; k > 0; k--) {
        for (int a = 0; a < 3; a++)
            box_grow(&acc[a], bins[a][k].lo, bins[a][k].hi);
        cnt = vi4_add(cnt, vi4_load(counts[k]));
        right_cost[k] = vf4_mul(half_areas3(acc), block_count(cnt));
    }
    const vint4 zero = vi4_set1(0), all = vi4_set1((int32_t)n);
    const vbool4 usable = vf4_gt(map.scale, vf4_set1(0.0f)); /* lane 3: scale 0 */
    vfloat4 best_cost = vf4_set1(INFINITY);
    vint4 best_pos = zero;
    acc[0] = acc[1] = acc[2] = box_empty();
    cnt = zero;
    for (int k = 1; k < nb; k++) {
        for (int a = 0; a < 3; a++)
            box_grow(&acc[a], bins[a][k - 1].lo, bins[a][k - 1].hi);
        cnt = vi4_add(cnt, vi4_load(counts[k - 1]));
        vfloat4 cost = vf4_madd(half_areas3(acc), block_count(cnt), right_cost[k]);
        vbool4 ok = vb4_andnot(vb4_andnot(usable, vi4_eq(cnt, zero)), vi4_eq(cnt, all));
        vbool4 better = vb4_and(ok, vf4_lt(cost, best_cost));
        best_cost = vf4_select(better, cost, best_cost);
        best_pos = vi4_select(better, vi4_set1(k), best_pos);
    }
    _Alignas(16) float costs[4];
    _Alignas(16) int32_t pos[4];
    vf4_store(costs, best_cost);
    vi4_store(pos, best_pos);
    float c = INFINITY;
    for (int a = 0; a < 3; a++)
        if (costs[a] < c) {
            c = costs[a];
            best.axis = a;
            best.pos = pos[a];
        }
    best.cost = c;
    best.map = map;
    return best;
}

static void range_init(range *r, uint32_t begin, uint32_t end)
{
    r->begin = begin;
    r->end = end;
    r->geom = box_empty();
    r->cent = box_empty();
}

static inline void range_add(range *r, vfloat4 lo, vfloat4 hi)
{
    vfloat4 c = centroid(lo, hi);
    box_grow(&r->geom, lo, hi);
    box_grow(&r->cent, c, c);
}

static void range_recompute(const builder *b, range *r)
{
    range_init(r, r->begin, r->end);
    for (uint32_t i = r->begin; i < r->end; i++)
        range_add(r, vf4_load(b->refs[i].lo), vf4_load(b->refs[i].hi));
}

/* Splits r into two non-empty halves, along *given if not NULL (a split
 * find_split made for r), else along the best one (median: halves). */
static void split_range(builder *b, const range *r, int median, const split *given, range *left, range *right)
{
    split s = {.axis = -1};
    if (given)
        s = *given;
    else if (!median)
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
    /* Hoare partition: a reference goes left when its bin on the split axis
     * is below the split position. */
    primref *refs = b->refs;
    const vint4 pos = vi4_set1(s.pos);
    const int bit = 1 << s.axis;
    uint32_t i = r->begin, j = r->end;
    range_init(left, 0, 0);
    range_init(right, 0, 0);
    vfloat4 lo_i, hi_i, lo_j, hi_j;
    for (;;) {
        for (; i < j; i++) {
            lo_i = vf4_load(refs[i].lo);
            hi_i = vf4_load(refs[i].hi);
            if (!(vb4_mask(vi4_lt(bin_of(&s.map, centroid(lo_i, hi_i)), pos)) & bit))
                break;
            range_add(left, lo_i, hi_i);
        }
        for (; i < j; j--) {
            lo_j = vf4_load(refs[j - 1].lo);
            hi_j = vf4_load(refs[j - 1].hi);
            if (vb4_mask(vi4_lt(bin_of(&s.map, centroid(lo_j, hi_j)), pos)) & bit)
                break;
            range_add(right, lo_j, hi_j);
        }
        if (i >= j)
            break;
        /* refs[i] belongs right and refs[j - 1] left: swap them. */
        vf4_store(refs[i].lo, lo_j);
        vf4_store(refs[i].hi, hi_j);
        vf4_store(refs[j - 1].lo, lo_i);
        vf4_store(refs[j - 1].hi, hi_i);
        range_add(left, lo_j, hi_j);
        range_add(right, lo_i, hi_i);
        i++;
        j--;
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

/* A leaf of vertex indices: the triangles stay in the application's buffers. */
static void make_leaf_indexed(builder *b, const range *r, uint64_t index)
{
    rtk_triangle4i *t = &b->trisi[index];
    for (uint32_t lane = 0; lane < 4; lane++) {
        if (r->begin + lane >= r->end) {
            t->v0[lane] = t->v1[lane] = t->v2[lane] = t->v0[0];
            t->geom[lane] = t->geom[0];
            t->prim[lane] = RTK_BVH4_EMPTY;
            continue;
        }
        const primref *p = &b->refs[r->begin + lane];
        const uint32_t *tri = triangle_at(&b->in->geometries[ref_geom(p)], ref_prim(p));
        t->v0[lane] = tri[0];
        t->v1[lane] = tri[1];
        t->v2[lane] = tri[2];
        t->geom[lane] = ref_geom(p);
        t->prim[lane] = ref_prim(p);
    }
}

/* One leaf block: the (up to) four triangles of r from r->begin. */
static void make_block(builder *b, const range *r, uint64_t index)
{
    if (b->trisi) {
        make_leaf_indexed(b, r, index);
        return;
    }
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
        rtk_triangle4_set_lane(t, (int)lane, vertex_at(g, tri[0]), vertex_at(g, tri[1]), vertex_at(g, tri[2]),
                               g->geom_id, ref_prim(p));
    }
}

/* A leaf of ceil(n / 4) consecutive blocks (at most RTK_LEAF_MAX_BLOCKS). */
static uint32_t make_leaf(builder *b, const range *r)
{
    const uint32_t blocks = (r->end - r->begin + 3) / 4;
    const uint64_t first = b->leaf_count;
    b->leaf_count += blocks;
    b->sah += (double)box_half_area(&r->geom) * blocks;
    for (uint32_t k = 0; k < blocks; k++) {
        range part = *r;
        part.begin = r->begin + 4 * k;
        make_block(b, &part, first + k);
    }
    return rtk_leaf_ref((uint32_t)first, blocks);
}

/* Writes inner node `index` with the boxes of its nc children; empty slots
 * get inverted boxes and RTK_BVH4_EMPTY. */
static void write_node(builder *b, uint64_t index, const range *child, int nc)
{
    const int w = b->width;
    float *lx, *ly, *lz, *ux, *uy, *uz;
    uint32_t *refs;
    if (w == 8) {
        rtk_bvh8_node *n = (rtk_bvh8_node *)b->nodes + index;
        lx = n->lower_x, ly = n->lower_y, lz = n->lower_z, ux = n->upper_x, uy = n->upper_y, uz = n->upper_z;
        refs = n->child;
        memset(n->reserved, 0, sizeof n->reserved);
    } else {
        rtk_bvh4_node *n = (rtk_bvh4_node *)b->nodes + index;
        lx = n->lower_x, ly = n->lower_y, lz = n->lower_z, ux = n->upper_x, uy = n->upper_y, uz = n->upper_z;
        refs = n->child;
        memset(n->reserved, 0, sizeof n->reserved);
    }
    for (int i = 0; i < w; i++) {
        _Alignas(16) float lo[4] = {INFINITY, INFINITY, INFINITY, 0};
        _Alignas(16) float hi[4] = {-INFINITY, -INFINITY, -INFINITY, 0};
        if (i < nc) {
            vf4_store(lo, child[i].geom.lo);
            vf4_store(hi, child[i].geom.hi);
        }
        lx[i] = lo[0];
        ly[i] = lo[1];
        lz[i] = lo[2];
        ux[i] = hi[0];
        uy[i] = hi[1];
        uz[i] = hi[2];
        refs[i] = RTK_BVH4_EMPTY;
    }
}

static void set_child(builder *b, uint64_t index, int i, uint32_t ref)
{
    if (b->width == 8)
        ((rtk_bvh8_node *)b->nodes)[index].child[i] = ref;
    else
        ((rtk_bvh4_node *)b->nodes)[index].child[i] = ref;
}

static uint32_t build_node(builder *b, const range *r, uint32_t depth)
{
    if (depth > b->depth)
        b->depth = depth;
    const uint32_t n = r->end - r->begin;
    if (n <= 4)
        return make_leaf(b, r);

    const int median = depth >= RTK_SAH_MEDIAN_DEPTH;
    /* A small range becomes one leaf of several blocks where the SAH says
     * an inner node over its best split would cost more (one box test, at
     * the price of one block of triangles, as in Embree): an inner node
     * over a handful of triangles would mostly hold empty slots. */
    split first = {.axis = -1};
    int have_first = 0;
    if (n <= 4 * RTK_LEAF_MAX_BLOCKS && !median) {
        first = find_split(b, r);
        const float area = box_half_area(&r->geom);
        if (first.axis < 0 || (float)((n + 3) / 4) * area <= area + first.cost)
            return make_leaf(b, r);
        have_first = 1;
    }
    range child[8];
    int nc = 1;
    child[0] = *r;
    while (nc < b->width) {
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
        split_range(b, &child[pick], median, have_first && nc == 1 ? &first : NULL, &l, &rr);
        child[pick] = l;
        child[nc++] = rr;
    }

    uint64_t index = b->node_count++;
    write_node(b, index, child, nc);
    b->sah += box_half_area(&r->geom);
    for (int i = 0; i < nc; i++)
        set_child(b, index, i, build_node(b, &child[i], depth + 1));
    return (uint32_t)index;
}

/* The node and leaf arrays are reserved for the worst case (one leaf per
 * triangle) as anonymous mappings, so only the pages the build writes are
 * ever committed, and the unused tail is unmapped afterwards: no copy. */
static size_t page_round(size_t size)
{
    return (size + 4095) & ~(size_t)4095;
}

static void *reserve(size_t size)
{
    void *p = mmap(NULL, page_round(size), PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    return p == MAP_FAILED ? NULL : p;
}

/* A reservation for what traversal reads (nodes, leaves): large ones start
 * on a 2 MiB boundary and ask for transparent huge pages, as Embree's
 * allocator does.  Incoherent rays touch nodes and leaves all over tens of
 * megabytes; with 4 KiB pages nearly every such access also misses the TLB.
 * The advice is only a hint (the kernel may not have huge pages); the memory
 * is the same either way. */
#define HUGE_PAGE ((size_t)2 << 20)
static void *reserve_traversed(size_t size)
{
    size = page_round(size);
    if (size < HUGE_PAGE)
        return reserve(size);
    char *p = reserve(size + HUGE_PAGE);
    if (!p)
        return NULL;
    const size_t head = (HUGE_PAGE - (uintptr_t)p % HUGE_PAGE) % HUGE_PAGE;
    if (head)
        munmap(p, head);
    munmap(p + head + size, HUGE_PAGE - head);
#ifdef MADV_HUGEPAGE
    madvise(p + head, size, MADV_HUGEPAGE);
#endif
    return p + head;
}

static void unreserve(void *p, size_t size)
{
    if (p)
        munmap(p, page_round(size));
}

/* Keeps the first `used` bytes of a reservation of `size`; returns the size
 * kept (what unreserve must be given later). */
static size_t trim(void *p, size_t size, size_t used)
{
    size_t keep = page_round(used), all = page_round(size);
    if (keep < all)
        munmap((char *)p + keep, all - keep);
    return keep;
}

static void set_message(rtk_build_output *out, const char *text)
{
    snprintf(out->message, sizeof out->message, "%s", text);
}

/* The node and leaf geometry of in->layout; 0, or an error with out->message. */
static int layout_setup(builder *b, const rtk_build_input *in, rtk_build_output *out)
{
    *b = (builder){.in = in, .leaf_size = sizeof(rtk_triangle4), .width = 4, .node_size = sizeof(rtk_bvh4_node)};
    if (in->layout == RTK_LAYOUT_BVH8_TRIANGLE4) {
        b->width = 8;
        b->node_size = sizeof(rtk_bvh8_node);
    } else if (in->layout == RTK_LAYOUT_BVH4_TRIANGLE4I) {
        b->leaf_size = sizeof(rtk_triangle4i);
    } else if (in->layout != RTK_LAYOUT_BVH4_TRIANGLE4) {
        set_message(out, "this backend makes bvh4.triangle4, bvh8.triangle4 and bvh4.triangle4i only");
        return RTK_ERROR_INVALID_ARGUMENT;
    }
    return RTK_OK;
}

/* An accel with node and leaf arrays reserved for up to `nodes` and
 * `blocks` (the unused tail is trimmed by accel_finish), and the geometry
 * table of bvh4.triangle4i; NULL when out of memory. */
static struct rtk_accel *accel_reserve(builder *b, uint64_t nodes, uint64_t blocks)
{
    const rtk_build_input *in = b->in;
    struct rtk_accel *accel = calloc(1, sizeof *accel);
    if (!accel)
        return NULL;
    const int indexed = in->layout == RTK_LAYOUT_BVH4_TRIANGLE4I;
    accel->layout = in->layout;
    accel->nodes_mapped = (nodes ? nodes : 1) * b->node_size;
    accel->tris_mapped = (blocks ? blocks : 1) * b->leaf_size;
    b->nodes = reserve_traversed(accel->nodes_mapped);
    void *leaves = reserve_traversed(accel->tris_mapped);
    if (indexed) {
        b->trisi = leaves;
        accel->geoms = malloc((in->geometry_count ? in->geometry_count : 1) * sizeof *accel->geoms);
    } else {
        b->tris = leaves;
    }
    if (!b->nodes || !leaves || (indexed && !accel->geoms)) {
        unreserve(b->nodes, accel->nodes_mapped);
        unreserve(leaves, accel->tris_mapped);
        free(accel->geoms);
        free(accel);
        return NULL;
    }
    for (uint32_t gi = 0; indexed && gi < in->geometry_count; gi++) {
        const rtk_build_geometry *g = &in->geometries[gi];
        accel->geoms[gi] = (rtk_leaf_geometry){.vertices = g->vertices, .stride = g->vertex_stride,
                                               .geom_id = g->geom_id};
    }
    return accel;
}

/* Hands the arrays b wrote to accel (trimming the reservations) and
 * describes the result in out; `bounds` holds the scene's box. */
static void accel_finish(builder *b, struct rtk_accel *accel, uint32_t root, uint64_t prims, const box4 *bounds,
                         rtk_build_output *out)
{
    accel->root = root;
    accel->nodes = b->nodes;
    accel->tris = b->tris;
    accel->trisi = b->trisi;
    void *leaves = b->tris ? (void *)b->tris : (void *)b->trisi;
    accel->nodes_mapped = trim(b->nodes, accel->nodes_mapped, b->node_count * b->node_size);
    accel->tris_mapped = trim(leaves, accel->tris_mapped, b->leaf_count * b->leaf_size);
    accel->node_count = b->node_count;
    accel->leaf_count = b->leaf_count;

    const size_t geom_bytes = accel->geoms ? (b->in->geometry_count ? b->in->geometry_count : 1) * sizeof *accel->geoms : 0;
    out->accel = accel;
    out->prims = prims;
    out->nodes = b->node_count;
    out->leaves = b->leaf_count;
    out->bytes = b->node_count * b->node_size + b->leaf_count * b->leaf_size + geom_bytes;
    out->depth = prims ? b->depth : 0;
    float root_area = box_half_area(bounds);
    out->sah_cost = root_area > 0.0f ? b->sah / root_area : 0.0;
    for (int k = 0; k < 3; k++) {
        out->lower[k] = prims ? box_lo(bounds, k) : 0.0f;
        out->upper[k] = prims ? box_hi(bounds, k) : 0.0f;
    }
}

int RTK_SYM(rtk_build_sah)(const rtk_build_input *in, rtk_build_output *out)
{
    uint64_t total = 0;
    for (uint32_t g = 0; g < in->geometry_count; g++)
        total += in->geometries[g].prim_count;
    if (total >= RTK_LEAF_INDEX_LIMIT) {
        set_message(out, "too many triangles for one BVH (limit 2^29 - 1)");
        return RTK_ERROR_INVALID_ARGUMENT;
    }

    builder b;
    int rc = layout_setup(&b, in, out);
    if (rc)
        return rc;
    const size_t ref_bytes = (total ? total : 1) * sizeof *b.refs;
    b.refs = reserve(ref_bytes);
    if (!b.refs) {
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
            vfloat4 p0 = vf4_set(v0[0], v0[1], v0[2], 0.0f);
            vfloat4 p1 = vf4_set(v1[0], v1[1], v1[2], 0.0f);
            vfloat4 p2 = vf4_set(v2[0], v2[1], v2[2], 0.0f);
            vfloat4 lo = vf4_min(vf4_min(p0, p1), p2), hi = vf4_max(vf4_max(p0, p1), p2);
            range_add(&root, lo, hi);
            vf4_store(r->lo, lo);
            vf4_store(r->hi, hi);
            r->lo[3] = rtk_bits_float(gi);
            r->hi[3] = rtk_bits_float((uint32_t)p);
        }
    }
    root.end = n;

    /* Upper bounds: at most one leaf per triangle and fewer inner nodes than
     * leaves. */
    struct rtk_accel *accel = accel_reserve(&b, n, n);
    if (!accel) {
        unreserve(b.refs, ref_bytes);
        set_message(out, "out of memory for the BVH");
        return RTK_ERROR_OUT_OF_MEMORY;
    }
    const uint32_t root_ref = n ? build_node(&b, &root, 1) : RTK_BVH4_EMPTY;
    unreserve(b.refs, ref_bytes);
    accel_finish(&b, accel, root_ref, n, &root.geom, out);
    out->prims_skipped = skipped;
    out->prims_degenerate = degenerate;
    return RTK_OK;
}

/* ---- a tree given as data (rtk_bvh) ----
 * The same node and leaf writers as the build, visited in the same order,
 * so a tree exported from an accel imports to the same bytes and the same
 * statistics. */

static box4 slot_box(const rtk_bvh *t, uint64_t slot)
{
    const float *lo = t->child_lower + 3 * slot, *hi = t->child_upper + 3 * slot;
    return (box4){vf4_set(lo[0], lo[1], lo[2], 0.0f), vf4_set(hi[0], hi[1], hi[2], 0.0f)};
}

static uint32_t import_ref(builder *b, const rtk_bvh *t, uint32_t ref, const box4 *box, uint32_t depth)
{
    if (depth > b->depth)
        b->depth = depth;
    if (ref & RTK_BVH_LEAF_BIT) {
        const uint64_t j = ref & ~RTK_BVH_LEAF_BIT;
        range r = {.begin = (uint32_t)t->leaf_first[j], .end = (uint32_t)t->leaf_first[j + 1], .geom = *box};
        return make_leaf(b, &r);
    }
    range child[8];
    memset(child, 0, sizeof child);
    uint32_t refs[8];
    int nc = 0;
    for (uint32_t c = 0; c < t->width; c++) {
        const uint64_t slot = (uint64_t)ref * t->width + c;
        if (t->children[slot] == RTK_BVH_EMPTY)
            continue;
        child[nc].geom = slot_box(t, slot);
        refs[nc++] = t->children[slot];
    }
    const uint64_t index = b->node_count++;
    write_node(b, index, child, nc);
    b->sah += box_half_area(box);
    for (int i = 0; i < nc; i++)
        set_child(b, index, i, import_ref(b, t, refs[i], &child[i].geom, depth + 1));
    return (uint32_t)index;
}

int RTK_SYM(rtk_bvh_import)(const rtk_build_input *in, const rtk_bvh *t, rtk_build_output *out)
{
    builder b;
    int rc = layout_setup(&b, in, out);
    if (rc)
        return rc;
    if (t->width != (uint32_t)b.width) {
        snprintf(out->message, sizeof out->message, "the tree has %u-wide nodes, the layout %d-wide ones", t->width,
                 b.width);
        return RTK_ERROR_INVALID_ARGUMENT;
    }
    uint64_t blocks = 0;
    for (uint64_t j = 0; j < t->leaf_count; j++) {
        const uint64_t n = t->leaf_first[j + 1] - t->leaf_first[j];
        if (n > 4 * RTK_LEAF_MAX_BLOCKS) {
            snprintf(out->message, sizeof out->message, "leaf %llu holds %llu triangles; the layout's leaves hold %d",
                     (unsigned long long)j, (unsigned long long)n, 4 * RTK_LEAF_MAX_BLOCKS);
            return RTK_ERROR_INVALID_ARGUMENT;
        }
        blocks += (n + 3) / 4;
    }
    if (blocks >= RTK_LEAF_INDEX_LIMIT || t->node_count >= RTK_BVH4_LEAF_BIT) {
        set_message(out, "too many leaf blocks or nodes for the layout");
        return RTK_ERROR_INVALID_ARGUMENT;
    }

    /* The triangles as primitive references in tree order: the leaf
     * writers read them from there.  geom_id -> index in the input. */
    uint32_t max_id = 0;
    for (uint32_t gi = 0; gi < in->geometry_count; gi++)
        max_id = in->geometries[gi].geom_id > max_id ? in->geometries[gi].geom_id : max_id;
    uint32_t *index_of = malloc(((size_t)max_id + 1) * sizeof *index_of);
    const size_t ref_bytes = (t->prim_count ? t->prim_count : 1) * sizeof *b.refs;
    b.refs = reserve(ref_bytes);
    struct rtk_accel *accel = index_of && b.refs ? accel_reserve(&b, t->node_count, blocks) : NULL;
    if (!accel) {
        free(index_of);
        unreserve(b.refs, ref_bytes);
        set_message(out, "out of memory for the BVH");
        return RTK_ERROR_OUT_OF_MEMORY;
    }
    for (uint32_t gi = 0; gi < in->geometry_count; gi++)
        index_of[in->geometries[gi].geom_id] = gi;
    for (uint64_t k = 0; k < t->prim_count; k++) {
        b.refs[k].lo[3] = rtk_bits_float(index_of[t->prims[k].geom_id]);
        b.refs[k].hi[3] = rtk_bits_float(t->prims[k].prim_id);
    }
    free(index_of);

    /* The scene's box: the union of the root's slots, or of a root leaf's
     * triangles. */
    box4 bounds = box_empty();
    if (t->root != RTK_BVH_EMPTY && !(t->root & RTK_BVH_LEAF_BIT)) {
        for (uint32_t c = 0; c < t->width; c++)
            if (t->children[(uint64_t)t->root * t->width + c] != RTK_BVH_EMPTY) {
                box4 s = slot_box(t, (uint64_t)t->root * t->width + c);
                box_grow(&bounds, s.lo, s.hi);
            }
    } else if (t->root != RTK_BVH_EMPTY) {
        for (uint64_t k = 0; k < t->prim_count; k++) {
            const rtk_build_geometry *g = &in->geometries[ref_geom(&b.refs[k])];
            const uint32_t *tri = triangle_at(g, ref_prim(&b.refs[k]));
            for (int v = 0; v < 3; v++) {
                const float *p = vertex_at(g, tri[v]);
                const vfloat4 q = vf4_set(p[0], p[1], p[2], 0.0f);
                box_grow(&bounds, q, q);
            }
        }
    }
    const uint32_t root = t->root == RTK_BVH_EMPTY ? RTK_BVH4_EMPTY : import_ref(&b, t, t->root, &bounds, 1);
    unreserve(b.refs, ref_bytes);
    accel_finish(&b, accel, root, t->prim_count, &bounds, out);
    return RTK_OK;
}

void RTK_SYM(rtk_bvh4_release)(rtk_accel *accel)
{
    if (!accel)
        return;
    unreserve(accel->nodes, accel->nodes_mapped);
    unreserve(accel->tris ? (void *)accel->tris : (void *)accel->trisi, accel->tris_mapped);
    free(accel->geoms);
    free(accel);
}
