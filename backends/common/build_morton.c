/*
 * Morton builder (low quality) for the bvh4.triangle4, bvh8.triangle4 and
 * bvh4.triangle4i layouts: the fastest builder, for geometry that changes
 * every frame.  As Embree's (and Lauterbach et al. 2009's LBVH):
 *
 *  1. The triangles' centroids are quantised to 2^10 cells per axis of the
 *     centroid bounds, and the cell coordinates interleaved into a 30-bit
 *     Morton code.  Each triangle becomes a 64-bit item, code above and the
 *     triangle's index below.
 *  2. The items are sorted with a parallel radix sort: by code, and equal
 *     codes by triangle index, so the order is a function of the input
 *     alone.
 *  3. The hierarchy is read off the sorted codes: a range splits where its
 *     highest differing code bit changes (a binary search), or in the middle
 *     when all its codes are equal; in a range of RTK_MORTON_FILL or fewer
 *     moved, where needed, to keep the blocks full (fill_split).  An N-wide
 *     node starts with one child over its range and splits the child with
 *     the most triangles until it has N children or none has more than four
 *     (one leaf block).  Boxes are computed bottom-up from the triangles as
 *     the leaves are written.
 *
 * The hierarchy is a function of the sorted codes alone, so it is walked
 * twice: once to count each subtree's nodes and blocks, then, with every
 * subtree's place in the final arrays known, to write it there directly.
 * Ranges of RTK_MORTON_TOP or more triangles are the top nodes, walked on
 * one thread (a split costs a binary search); smaller ones are subtree
 * tasks.  Neither the chunks nor the tasks change the tree, so it is the
 * same, byte for byte, on any number of threads.
 *
 * Depth: along any path each split either lowers the highest differing bit
 * of the range's codes (at most 30 times) or halves a range of equal codes
 * (at most 29 times), so no tree is deeper than 61 levels, leaves included.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "build_common.h"
#include "kernels.h"

#define RTK_MORTON_BITS 10 /* per axis */
/* Triangles per task when the codes are made; items per task of the sort. */
#define RTK_MORTON_CHUNK 16384u
#define RTK_SORT_CHUNKS_MAX 64u
/* The radix sort's digits: the top one over all items, then three smaller
 * ones within each bucket of the top one (in cache). */
#define RTK_RADIX_BITS 10
#define RTK_LOCAL_BITS 7
#define RTK_RADIX_SIZE (1u << RTK_RADIX_BITS)
/* Prefetch distances of the leaf writer, in items (prefetch_items). */
#define PREFETCH_FAR 48u
#define PREFETCH_NEAR 24u
/* Ranges of at most this many triangles split so that their blocks stay
 * full (fill_split). */
#ifndef RTK_MORTON_FILL
#define RTK_MORTON_FILL 16u
#endif
/* Ranges of at least this many triangles are top nodes. */
#define RTK_MORTON_TOP 8192u

typedef struct morton {
    build bd;
    const uint64_t *geom_first; /* global index of each geometry's first triangle; [count] = total */
    uint64_t total;
    uint32_t chunks;
    /* per chunk of triangles */
    uint32_t *kept;
    uint64_t *first;      /* where its kept items go */
    build_counts *counts; /* what it left out */
    box4 *cent;                            /* its centroids' bounds */
    uint32_t spread[1u << RTK_MORTON_BITS]; /* spread3 of every cell coordinate */
    /* the quantisation (lanes 0..2) */
    vfloat4 cmin, scale, top;
    float *rec;              /* per triangle from pass 1: centroid x, y, z and the index's bits */
    uint64_t *items, *other; /* the sort's two arrays */
    uint32_t n;              /* items kept */
    /* the sort */
    uint32_t sort_chunks;
    uint32_t *hist;                          /* sort_chunks x RTK_RADIX_SIZE */
    uint32_t bucket[RTK_RADIX_SIZE + 1];     /* where each top digit's items start */
} morton;

/* The centre of a triangle's box, as lo/2 + hi/2 (no overflow for finite boxes). */
static inline vfloat4 centroid3(const vfloat4 p[3])
{
    const vfloat4 lo = vf4_min(vf4_min(p[0], p[1]), p[2]), hi = vf4_max(vf4_max(p[0], p[1]), p[2]);
    const vfloat4 half = vf4_set1(0.5f);
    return vf4_madd(lo, half, vf4_mul(hi, half));
}

/* The geometry holding global triangle i: the last one starting at or before it. */
static uint32_t geometry_of(const morton *m, uint64_t i)
{
    return build_geometry_of(m->geom_first, m->bd.in->geometry_count, i);
}

/* Item i's triangle: its geometry's index in the input (*gi) and primitive index. */
static inline uint32_t item_prim(const morton *m, uint32_t i, uint32_t *gi)
{
    const uint64_t x = m->items[i] & UINT32_MAX;
    *gi = geometry_of(m, x);
    return (uint32_t)(x - m->geom_first[*gi]);
}

/* ---- 1. codes ---- */

/* Chunk k of the triangles: the hittable ones (finite, with area; the
 * others can never be hit and are left out) are counted, and their
 * centroids bounded and written with their indices from the chunk's first
 * record on.  The codes are made from the records, not from the index and
 * vertex buffers again: on dragon that pass took 16 ms reading the buffers
 * and takes 7 reading the records (1 thread, with the table of spread3). */
static void scan_chunk(void *data, uint32_t k)
{
    morton *m = data;
    const rtk_build_input *in = m->bd.in;
    const uint64_t begin = (uint64_t)k * RTK_MORTON_CHUNK;
    const uint64_t end = begin + RTK_MORTON_CHUNK < m->total ? begin + RTK_MORTON_CHUNK : m->total;
    uint32_t gi = geometry_of(m, begin), n = 0;
    build_counts counts = {0, 0, 0};
    box4 cent = box_empty();
    float *out = m->rec + 4 * begin;
    for (uint64_t i = begin; i < end; i++) {
        while (i >= m->geom_first[gi + 1])
            gi++;
        vfloat4 p[3];
        if (!build_hittable(&in->geometries[gi], (size_t)(i - m->geom_first[gi]), p, &counts))
            continue;
        const vfloat4 c = centroid3(p);
        box_grow(&cent, c, c);
        vf4_store(out + 4 * (size_t)n++, c);
        out[4 * (size_t)n - 1] = rtk_bits_float((uint32_t)i);
    }
    m->kept[k] = n;
    m->counts[k] = counts;
    m->cent[k] = cent;
}

/* 10 bits spread to every third bit. */
static inline uint32_t spread3(uint32_t x)
{
    x &= 0x3ff;
    x = (x | x << 16) & 0x030000ff;
    x = (x | x << 8) & 0x0300f00f;
    x = (x | x << 4) & 0x030c30c3;
    x = (x | x << 2) & 0x09249249;
    return x;
}

/* Chunk k: its items get their codes, moved to their place in m->items. */
static void code_chunk(void *data, uint32_t k)
{
    morton *m = data;
    const float *src = m->rec + 4 * (uint64_t)k * RTK_MORTON_CHUNK;
    uint64_t *dst = m->items + m->first[k];
    const uint32_t n = m->kept[k];
    const vbool4 xyz = vb4_from_bits(7);
    const vfloat4 half = vf4_set1(0.5f), zero = vf4_set1(0.0f), cmin_half = vf4_mul(m->cmin, half);
    for (uint32_t j = 0; j < n; j++) {
        /* lane 3 (the index's bits, often a denormal as a float) cleared:
         * arithmetic on denormals costs a microcode assist on x86 */
        const vfloat4 c = vf4_keep(xyz, vf4_load(src + 4 * (size_t)j));
        /* (c/2 - min/2) * scale: no overflow for finite coordinates; the
         * clamp in float also catches rounding at the top cell */
        const vfloat4 x = vf4_mul(vf4_sub(vf4_mul(c, half), cmin_half), m->scale);
        const vint4 q = vi4_from_vf4_trunc(vf4_min(vf4_max(x, zero), m->top));
        const uint32_t code = m->spread[vi4_lane(q, 0)] << 2 | m->spread[vi4_lane(q, 1)] << 1 | m->spread[vi4_lane(q, 2)];
        dst[j] = (uint64_t)code << 32 | rtk_float_bits(src[4 * (size_t)j + 3]);
    }
}

/* ---- 2. the sort ----
 * One pass over all items by the top RTK_RADIX_BITS of the code (a stable
 * counting sort, in parallel chunks), then each bucket by itself, in cache,
 * by the lower digits (LSD, three passes).  Every item is unique (the index
 * is in its low bits), so the result is the one order of the items as
 * 64-bit numbers whatever the chunks or the tasks. */

static uint32_t sort_chunk_begin(const morton *m, uint32_t c)
{
    return (uint32_t)((uint64_t)m->n * c / m->sort_chunks);
}

static inline uint32_t digit(uint64_t x, uint32_t shift)
{
    return (uint32_t)(x >> shift) & (RTK_RADIX_SIZE - 1);
}

#define TOP_SHIFT (32 + 3 * RTK_MORTON_BITS - RTK_RADIX_BITS)

static void radix_count(void *data, uint32_t c)
{
    morton *m = data;
    uint32_t *h = m->hist + (size_t)c * RTK_RADIX_SIZE;
    memset(h, 0, RTK_RADIX_SIZE * sizeof *h);
    const uint32_t e = sort_chunk_begin(m, c + 1);
    for (uint32_t i = sort_chunk_begin(m, c); i < e; i++)
        h[digit(m->items[i], TOP_SHIFT)]++;
}

/* Chunk c's items to their places in m->other: hist now holds, per digit,
 * where chunk c's first item of that digit goes. */
static void radix_scatter(void *data, uint32_t c)
{
    morton *m = data;
    uint32_t *h = m->hist + (size_t)c * RTK_RADIX_SIZE;
    const uint32_t e = sort_chunk_begin(m, c + 1);
    for (uint32_t i = sort_chunk_begin(m, c); i < e; i++) {
        const uint64_t x = m->items[i];
        m->other[h[digit(x, TOP_SHIFT)]++] = x;
    }
}

/* One stable counting pass of n items from `from` to `to` by the
 * RTK_LOCAL_BITS digit at `shift`. */
static void local_pass(const uint64_t *from, uint64_t *to, uint32_t n, uint32_t shift)
{
    uint32_t h[1u << RTK_LOCAL_BITS] = {0};
    const uint32_t mask = (1u << RTK_LOCAL_BITS) - 1;
    for (uint32_t i = 0; i < n; i++)
        h[from[i] >> shift & mask]++;
    for (uint32_t d = 0, at = 0; d <= mask; d++) {
        const uint32_t count = h[d];
        h[d] = at;
        at += count;
    }
    for (uint32_t i = 0; i < n; i++)
        to[h[from[i] >> shift & mask]++] = from[i];
}

/* Bucket d, in m->other, sorted into m->items: three passes of
 * RTK_LOCAL_BITS over the code bits below the top digit. */
static void sort_bucket(void *data, uint32_t d)
{
    morton *m = data;
    const uint32_t b = m->bucket[d], n = m->bucket[d + 1] - b;
    uint64_t *x = m->other + b, *y = m->items + b;
    if (n <= 32) { /* insertion sort */
        for (uint32_t i = 0; i < n; i++) {
            const uint64_t v = x[i];
            uint32_t k = i;
            for (; k > 0 && y[k - 1] > v; k--)
                y[k] = y[k - 1];
            y[k] = v;
        }
        return;
    }
    local_pass(x, y, n, 32);
    local_pass(y, x, n, 32 + RTK_LOCAL_BITS);
    local_pass(x, y, n, 32 + 2 * RTK_LOCAL_BITS);
}

/* Sorts m->items[0, n) by their codes; the result is in m->items. */
static void radix_sort(morton *m)
{
    run_parallel(&m->bd, m->sort_chunks, radix_count, m);
    /* digit-major, chunk-minor: the pass is stable */
    uint32_t at = 0;
    for (uint32_t d = 0; d < RTK_RADIX_SIZE; d++) {
        m->bucket[d] = at;
        for (uint32_t c = 0; c < m->sort_chunks; c++) {
            uint32_t *h = &m->hist[(size_t)c * RTK_RADIX_SIZE + d];
            const uint32_t count = *h;
            *h = at;
            at += count;
        }
    }
    m->bucket[RTK_RADIX_SIZE] = at;
    run_parallel(&m->bd, m->sort_chunks, radix_scatter, m);
    run_parallel(&m->bd, RTK_RADIX_SIZE, sort_bucket, m);
}

/* ---- 3. the hierarchy ---- */

static inline uint32_t code_at(const uint64_t *items, uint32_t i)
{
    return (uint32_t)(items[i] >> 32);
}

/* Where [b, e) (more than one item) splits: at the first item with the
 * highest differing bit set, or in the middle if all codes are equal. */
static uint32_t split_at(const uint64_t *items, uint32_t b, uint32_t e)
{
    const uint32_t c0 = code_at(items, b), c1 = code_at(items, e - 1);
    if (c0 == c1)
        return b + (e - b) / 2;
    const uint32_t bit = 1u << (31 - __builtin_clz(c0 ^ c1));
    /* Branch-free: items[base] has the bit clear and the answer is in
     * (base, base + len]; a branch here would be mispredicted half the time. */
    uint32_t base = b, len = e - b;
    while (len > 1) {
        const uint32_t half = len / 2;
        base = code_at(items, base + half) & bit ? base : base + half;
        len -= half;
    }
    return base + 1;
}

/* The blocks of four that `count` triangles take as one leaf, or as leaves below it. */
static inline uint32_t blocks_of(uint32_t count)
{
    return (count + 3) / 4;
}

/* A split of a small range [b, e) moved, where it has to, so that its two
 * sides take no more blocks between them than the range needs.  Split only
 * where their codes part, 6 triangles can become 5 and 1, and leaves of 3, 2
 * and 1 below: three blocks where two would do, and every block written and
 * every leaf entered costs the same however few triangles it holds.  The
 * split moves to the nearest count that is a multiple of four on one side
 * (at most two items along the curve, which in a range this small stay near
 * each other).  On the dragon 277,936 blocks become 220,804 (81.7 -> 65.8
 * bytes per triangle), the SAH cost 19.58 -> 19.96, and its diffuse rays
 * trace as fast (rtktool trace --quality low, four rounds in turns); ranges
 * of up to 64 gave 199,223 blocks, SAH 21.05 and 2% slower rays. */
static uint32_t fill_split(uint32_t b, uint32_t e, uint32_t at)
{
    const uint32_t n = e - b, left = at - b;
    if (n > RTK_MORTON_FILL || blocks_of(left) + blocks_of(n - left) == blocks_of(n))
        return at;
    uint32_t best = 0, dist = UINT32_MAX;
    for (uint32_t l = 4; l < n; l += 4) {
        const uint32_t cands[2] = {l, n - l};
        for (int k = 0; k < 2; k++) {
            const uint32_t d = cands[k] > left ? cands[k] - left : left - cands[k];
            if (d < dist) {
                dist = d;
                best = cands[k];
            }
        }
    }
    return b + best;
}

/* The children of a node over [b, e): begin[i], begin[i + 1] bound child i. */
static int split_children(const morton *m, uint32_t b, uint32_t e, uint32_t begin[9])
{
    const int width = m->bd.width;
    int nc = 1;
    begin[0] = b;
    begin[1] = e;
    while (nc < width) {
        int pick = -1;
        uint32_t most = 4;
        for (int i = 0; i < nc; i++)
            if (begin[i + 1] - begin[i] > most) {
                most = begin[i + 1] - begin[i];
                pick = i;
            }
        if (pick < 0)
            break;
        const uint32_t at = fill_split(begin[pick], begin[pick + 1], split_at(m->items, begin[pick], begin[pick + 1]));
        for (int i = nc; i > pick; i--)
            begin[i + 1] = begin[i];
        begin[pick + 1] = at;
        nc++;
    }
    return nc;
}

/* A subtree task: its range, sizes and shape (from the count) and results
 * (from the write).  The shape is the count's splits in the order the
 * write needs them: per inner node, preorder, the number of children and
 * the nc - 1 places between them; a range of four or fewer is a leaf. */
typedef struct subtree {
    uint32_t begin, end, depth0;
    uint64_t nodes, blocks;
    uint32_t depth;
    uint32_t *shape;
    uint32_t shape_len, shape_cap;
    int oom;
    uint64_t node_base, block_base;
    uint32_t root;
    box4 bounds;
} subtree;

typedef struct walk {
    const morton *m;
    subtree *s;
    uint64_t nodes, blocks;
    uint32_t depth;
    uint32_t at; /* read position in s->shape */
} walk;

static void count_node(walk *w, uint32_t b, uint32_t e, uint32_t depth)
{
    if (depth > w->depth)
        w->depth = depth;
    if (e - b <= 4) {
        w->blocks++;
        return;
    }
    uint32_t begin[9];
    const int nc = split_children(w->m, b, e, begin);
    subtree *s = w->s;
    if (!s->oom && build_grow((void **)&s->shape, &s->shape_cap, s->shape_len + (uint32_t)nc, sizeof *s->shape)) {
        s->shape[s->shape_len++] = (uint32_t)nc;
        for (int i = 1; i < nc; i++)
            s->shape[s->shape_len++] = begin[i];
    } else {
        s->oom = 1;
    }
    w->nodes++;
    for (int i = 0; i < nc; i++)
        count_node(w, begin[i], begin[i + 1], depth + 1);
}

/* The leaves are written in item order, so the triangles of the items
 * just ahead are the next to be read: in sorted order they are all over
 * the index and vertex buffers, and nearly every read would miss the
 * cache.  Their indices are fetched PREFETCH_FAR items ahead, and their
 * vertices (through those indices, by then in cache) PREFETCH_NEAR ahead. */
static void prefetch_items(const morton *m, uint32_t b, uint32_t e)
{
    const rtk_build_geometry *geoms = m->bd.in->geometries;
    uint32_t gi;
    for (uint32_t i = b + PREFETCH_FAR; i < e + PREFETCH_FAR && i < m->n; i++) {
        const uint32_t prim = item_prim(m, i, &gi);
        __builtin_prefetch(triangle_at(&geoms[gi], prim));
    }
    for (uint32_t i = b + PREFETCH_NEAR; i < e + PREFETCH_NEAR && i < m->n; i++) {
        const uint32_t prim = item_prim(m, i, &gi);
        const uint32_t *tri = triangle_at(&geoms[gi], prim);
        for (int v = 0; v < 3; v++)
            __builtin_prefetch(vertex_at(&geoms[gi], tri[v]));
    }
}

/* Writes the subtree over [b, e) from node w->nodes and block w->blocks on;
 * returns its reference and adds its box to *bounds. */
static uint32_t write_node(walk *w, uint32_t b, uint32_t e, box4 *bounds)
{
    const morton *m = w->m;
    const build *bd = &m->bd;
    if (e - b <= 4) {
        prefetch_items(m, b, e);
        uint32_t geom[4], prim[4];
        for (uint32_t k = 0; k < e - b; k++)
            prim[k] = item_prim(m, b + k, &geom[k]);
        const uint64_t block = w->blocks++;
        build_write_block(bd, block, geom, prim, e - b, bounds, NULL);
        return rtk_leaf_ref((uint32_t)block, 1);
    }
    uint32_t begin[9], ref[8];
    box4 box[8];
    const uint32_t *shape = w->s->shape + w->at;
    const int nc = (int)shape[0];
    w->at += (uint32_t)nc;
    begin[0] = b;
    for (int i = 1; i < nc; i++)
        begin[i] = shape[i];
    begin[nc] = e;
    const uint64_t index = w->nodes++;
    for (int i = 0; i < nc; i++) {
        box[i] = box_empty();
        ref[i] = write_node(w, begin[i], begin[i + 1], &box[i]);
        box_grow(bounds, box[i].lo, box[i].hi);
    }
    build_store_node(bd, bd->nodes, index, box, ref, nc);
    return (uint32_t)index;
}

/* The top nodes: child[] holds node indices among the top nodes, or
 * SUBTREE | k for subtree k. */
#define SUBTREE 0x80000000u
typedef struct top_node {
    uint32_t child[8];
    int nc;
} top_node;

typedef struct top {
    const morton *m;
    top_node *nodes;
    uint32_t node_count, node_cap;
    subtree *subtrees;
    uint32_t subtree_count, subtree_cap;
    uint32_t depth;
    int oom;
} top;

static uint32_t add_subtree(top *t, uint32_t b, uint32_t e, uint32_t depth)
{
    if (t->oom || !build_grow((void **)&t->subtrees, &t->subtree_cap, t->subtree_count + 1, sizeof *t->subtrees)) {
        t->oom = 1;
        return SUBTREE;
    }
    t->subtrees[t->subtree_count] = (subtree){.begin = b, .end = e, .depth0 = depth};
    return SUBTREE | t->subtree_count++;
}

static uint32_t add_top(top *t, uint32_t b, uint32_t e, uint32_t depth)
{
    if (depth > t->depth)
        t->depth = depth;
    if (t->oom || !build_grow((void **)&t->nodes, &t->node_cap, t->node_count + 1, sizeof *t->nodes)) {
        t->oom = 1;
        return 0;
    }
    const uint32_t index = t->node_count++;
    uint32_t begin[9];
    const int nc = split_children(t->m, b, e, begin);
    t->nodes[index].nc = nc;
    for (int i = 0; i < nc; i++) {
        const uint32_t cb = begin[i], ce = begin[i + 1];
        const uint32_t ref = ce - cb >= RTK_MORTON_TOP ? add_top(t, cb, ce, depth + 1) : add_subtree(t, cb, ce, depth + 1);
        if (!t->oom)
            t->nodes[index].child[i] = ref;
    }
    return index;
}

static void count_subtree(void *data, uint32_t i)
{
    top *t = data;
    subtree *s = &t->subtrees[i];
    /* about one inner node per 6 triangles on 4-wide nodes; 4 words each */
    build_grow((void **)&s->shape, &s->shape_cap, (s->end - s->begin) / 2 + 1, sizeof *s->shape);
    walk w = {.m = t->m, .s = s};
    count_node(&w, s->begin, s->end, s->depth0);
    s->nodes = w.nodes;
    s->blocks = w.blocks;
    s->depth = w.depth;
}

static void write_subtree(void *data, uint32_t i)
{
    top *t = data;
    subtree *s = &t->subtrees[i];
    walk w = {.m = t->m, .s = s, .nodes = s->node_base, .blocks = s->block_base};
    s->bounds = box_empty();
    s->root = write_node(&w, s->begin, s->end, &s->bounds);
    free(s->shape);
    s->shape = NULL;
}

/* Writes top node `ref` (node `ref` of the final array) bottom-up, or
 * finds subtree SUBTREE | k's root; returns the final reference and adds
 * its box to *bounds. */
static uint32_t write_top(const top *t, uint32_t ref, box4 *bounds)
{
    if (ref & SUBTREE) {
        const subtree *s = &t->subtrees[ref & ~SUBTREE];
        box_grow(bounds, s->bounds.lo, s->bounds.hi);
        return s->root;
    }
    const build *bd = &t->m->bd;
    const top_node *n = &t->nodes[ref];
    uint32_t child[8];
    box4 box[8];
    for (int i = 0; i < n->nc; i++) {
        box[i] = box_empty();
        child[i] = write_top(t, n->child[i], &box[i]);
        box_grow(bounds, box[i].lo, box[i].hi);
    }
    build_store_node(bd, bd->nodes, ref, box, child, n->nc);
    return ref;
}

int RTK_SYM(rtk_build_morton)(const rtk_build_input *in, rtk_build_output *out)
{
    uint64_t total;
    morton m = {0};
    int rc = build_begin(&m.bd, in, out, &total);
    if (rc)
        return rc;
    m.total = total;
    build_progress progress;
    build_progress_init(&m.bd, &progress, total);
    m.chunks = (uint32_t)((total + RTK_MORTON_CHUNK - 1) / RTK_MORTON_CHUNK);
    const size_t nc = m.chunks ? m.chunks : 1;
    const size_t item_bytes = (total ? total : 1) * sizeof *m.items, rec_bytes = (total ? total : 1) * 4 * sizeof(float);
    /* The records in the previous tree's leaves when the scene is rebuilt,
     * else at the start of a reservation for the most leaf blocks the tree
     * could have (one per triangle; address space only): the new leaves
     * are written over them, into pages mapped in already. */
    size_t rec_mapped = rec_bytes;
    m.rec = build_recycle_take(&m.bd, 1, rec_bytes, &rec_mapped);
    if (!m.rec) {
        const size_t most = (total ? total : 1) * m.bd.leaf_size;
        rec_mapped = most > rec_bytes ? most : rec_bytes;
        m.rec = build_reserve_huge(m.bd.mem, rec_mapped);
        if (!m.rec) {
            rec_mapped = rec_bytes;
            m.rec = build_reserve_huge(m.bd.mem, rec_bytes);
        }
    }
    m.items = build_reserve_huge(m.bd.mem, item_bytes);
    uint64_t *geom_first = build_geom_first(in);
    m.geom_first = geom_first;
    m.kept = malloc(nc * sizeof *m.kept);
    m.counts = malloc(nc * sizeof *m.counts);
    m.first = malloc(nc * sizeof *m.first);
    m.cent = malloc(nc * sizeof *m.cent);
    m.hist = malloc((size_t)RTK_SORT_CHUNKS_MAX * RTK_RADIX_SIZE * sizeof *m.hist);
    top t = {.m = &m};
    uint64_t *order = NULL;
    if (!m.rec || !m.items || !geom_first || !m.kept || !m.counts || !m.first || !m.cent ||
        !m.hist) {
        rc = RTK_ERROR_OUT_OF_MEMORY;
        build_set_message(out, "out of memory for the build's Morton codes");
        goto done;
    }

    /* 1. The hittable triangles and their centroids' bounds, then the codes. */
    run_parallel(&m.bd, m.chunks, scan_chunk, &m);
    box4 cent = box_empty();
    build_counts counts = {0, 0, 0};
    uint64_t n = 0;
    for (uint32_t k = 0; k < m.chunks; k++) {
        m.first[k] = n;
        n += m.kept[k];
        build_counts_add(&counts, &m.counts[k]);
        box_grow(&cent, m.cent[k].lo, m.cent[k].hi);
    }
    m.n = (uint32_t)n;
    {
        _Alignas(16) float lo[4], hi[4], scale[4] = {0, 0, 0, 0};
        vf4_store(lo, cent.lo);
        vf4_store(hi, cent.hi);
        for (int a = 0; a < 3 && n; a++) {
            const float ext = hi[a] * 0.5f - lo[a] * 0.5f; /* half the extent: finite */
            if (ext > 0.0f)
                scale[a] = (float)(1u << RTK_MORTON_BITS) * 0.5f * 0.99999f / ext;
        }
        m.cmin = cent.lo;
        m.scale = vf4_load(scale);
        m.top = vf4_set1((float)((1u << RTK_MORTON_BITS) - 1));
        for (uint32_t x = 0; x < 1u << RTK_MORTON_BITS; x++)
            m.spread[x] = spread3(x);
    }
    if (build_report(&m.bd, 0.1))
        goto cancelled;
    run_parallel(&m.bd, m.chunks, code_chunk, &m);
    if (build_report(&m.bd, 0.3))
        goto cancelled;
    /* the records are read: their memory (already mapped in) is the sort's other array */
    m.other = (uint64_t *)m.rec;

    /* 2. Sorted by code, in chunks of at least RTK_MORTON_CHUNK. */
    m.sort_chunks = (uint32_t)(n / RTK_MORTON_CHUNK);
    m.sort_chunks = m.sort_chunks < 1 ? 1 : m.sort_chunks > RTK_SORT_CHUNKS_MAX ? RTK_SORT_CHUNKS_MAX : m.sort_chunks;
    radix_sort(&m);
    if (build_report(&m.bd, 0.5))
        goto cancelled;

    /* 3. The top nodes, then each subtree's size. */
    uint32_t root_local = RTK_BVH4_EMPTY;
    if (n >= RTK_MORTON_TOP)
        root_local = add_top(&t, 0, m.n, 1);
    else if (n)
        root_local = add_subtree(&t, 0, m.n, 1);
    order = malloc((t.subtree_count ? t.subtree_count : 1) * sizeof *order);
    if (!order || t.oom) {
        rc = RTK_ERROR_OUT_OF_MEMORY;
        build_set_message(out, "out of memory for the BVH");
        goto done;
    }
    for (uint32_t i = 0; i < t.subtree_count; i++)
        order[i] = t.subtrees[i].end - t.subtrees[i].begin;
    build_largest_first(order, t.subtree_count);
    build_run_ordered(&m.bd, order, t.subtree_count, count_subtree, &t);
    if (build_report(&m.bd, 0.7))
        goto cancelled;

    /* Places: the top nodes, then the subtrees in the order they were found. */
    uint64_t nodes = t.node_count, blocks = 0;
    uint32_t depth = t.depth;
    int oom = 0;
    for (uint32_t i = 0; i < t.subtree_count; i++) {
        subtree *s = &t.subtrees[i];
        s->node_base = nodes;
        s->block_base = blocks;
        nodes += s->nodes;
        blocks += s->blocks;
        depth = s->depth > depth ? s->depth : depth;
        oom |= s->oom;
    }
    /* the sort's other array is free now: the new leaves' memory */
    struct rtk_accel *accel = NULL;
    if (!oom) {
        m.bd.spare_leaves = m.rec;
        m.bd.spare_mapped = rec_mapped;
        m.rec = NULL;
        accel = build_accel_alloc(&m.bd, nodes, blocks);
    }
    if (!accel) {
        rc = RTK_ERROR_OUT_OF_MEMORY;
        build_set_message(out, "out of memory for the BVH");
        goto done;
    }
    build_run_ordered(&m.bd, order, t.subtree_count, write_subtree, &t);
    box4 bounds = box_empty();
    const uint32_t root = root_local == RTK_BVH4_EMPTY ? RTK_BVH4_EMPTY : write_top(&t, root_local, &bounds);
    build_accel_finish(&m.bd, accel, root, n, depth, &bounds, out);
    build_counts_store(out, &counts);
    rc = RTK_OK;
    if (0) {
    cancelled:
        rc = RTK_ERROR_CANCELLED;
        build_set_message(out, "cancelled by the progress callback");
    }
done:
    free(order);
    free(t.nodes);
    for (uint32_t i = 0; i < t.subtree_count; i++)
        free(t.subtrees[i].shape);
    free(t.subtrees);
    free(geom_first);
    free(m.kept);
    free(m.counts);
    free(m.first);
    free(m.cent);
    free(m.hist);
    build_unreserve(m.bd.mem, m.rec, rec_mapped);
    build_unreserve(m.bd.mem, m.items, item_bytes);
    return rc;
}
