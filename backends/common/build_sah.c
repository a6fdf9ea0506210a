/*
 * Binned SAH builder for the bvh4.triangle4, bvh8.triangle4 and
 * bvh4.triangle4i layouts (object splits only), parallel and deterministic.
 *
 * Builds the N-wide tree directly, as Embree's builders do: a node starts
 * with one child holding all its primitives, and the child with the largest
 * surface area is split with a binned SAH split (Wald 2007, RTK_SAH_BINS bins
 * per axis) until the node has N children or no child has more than a
 * leaf's worth of triangles.  The SAH counts leaf cost in blocks of four
 * triangles (a leaf tests four triangles for the price of one), so a range of
 * up to four triangles always becomes a leaf.
 *
 * The three stages of the Embree paper, on in->tasks (rtk_task_system):
 *  1. Nodes over RTK_TOP_MIN or more triangles (top nodes) are split with
 *     the references binned and partitioned in chunks.  While fewer top
 *     nodes are waiting than there are threads (the root, on two threads),
 *     all threads run the chunks of one; the rest are tasks of a queue
 *     (build_queue), each split by one thread, largest first.
 *  2. Every child under that size is a subtree task in the same queue,
 *     built by one thread into arrays of its own (nodes with local
 *     references, leaves as ranges of references), while other threads
 *     still split top nodes.
 *  3. Once the sizes are known, each subtree is copied to its place in the
 *     final arrays (the top nodes first, in the order of a depth-first walk,
 *     then the subtrees in the order that walk meets them) and its leaf
 *     blocks written, again in parallel.
 * The chunks, the stage a node falls in and the place of every subtree depend
 * on the triangle counts alone, and chunk results are combined in chunk
 * order whichever threads ran them, so the tree is the same, byte for byte,
 * on any number of threads.
 *
 * Past depth RTK_SAH_MEDIAN_DEPTH the builder falls back to median splits,
 * so no tree is deeper than RTK_BVH4_MAX_DEPTH whatever the input.
 */
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "build_common.h"
#include "kernels.h"
#include "geometry/triangle.h"

#define RTK_SAH_BINS 32
#define RTK_SAH_MEDIAN_DEPTH 30
/* Stage 1 takes nodes of at least this many references; smaller ones are
 * subtree tasks.  Chunks of stage 1 hold at least RTK_CHUNK_MIN references,
 * at most RTK_CHUNKS_MAX of them per split.  Stage 1's passes stream the
 * references from memory, where two threads slow each other down (San
 * Miguel's chunks: 53 ms of partitioning on one thread, 68 ms between two);
 * a subtree task's fit the caches.  So stage 1 ends at 64K references, not
 * 16K: rtktool build, 2 threads, best of 8 interleaved rounds: San Miguel
 * 123 -> 114 ms, dragon 85 -> 82 (1 thread: 222 -> 216).  Those meshes
 * still make 71 and 50 subtrees of up to 59K references, work for more
 * threads than two. */
#define RTK_TOP_MIN 65536u
#define RTK_CHUNK_MIN 4096u
#define RTK_CHUNKS_MAX 64u
/* Triangles per task when the references are made. */
#define RTK_REF_CHUNK 16384u

typedef struct range {
    uint32_t begin, end;
    uint32_t ext; /* [end, ext): room for references spatial splits add */
    box4 geom; /* bounds of the triangles */
    box4 cent; /* bounds of the centroids */
    struct binned *bn; /* NULL, or its references' bins, made while its parent was partitioned */
} range;

/* Bins for ranges (struct binned, below), reused: `free` ones, and `all`
 * of them, freed with the pool.  A pool is used by one thread at a time. */
typedef struct binpool {
    struct binned *free, *all;
} binpool;

/* References inside a part's own node array: an inner node of the same part
 * (its index there), or one of the part's external children (EXT | k): for
 * a subtree its k-th leaf, for the top nodes the k-th subtree. */
#define EXT 0x80000000u

typedef struct leafrange {
    uint32_t begin, end; /* references */
    uint32_t placed;     /* stage 3: the final leaf reference */
} leafrange;

/* The references' huge pages, and per page the subtrees over it that stage
 * 3 has not placed yet (see release_refs). */
typedef struct refpages {
    _Atomic uint32_t *users;
    size_t bytes; /* of the reservation */
} refpages;

/* A thread's node arrays of stage 2 (see build_subtree): the subtrees it
 * builds write their nodes one after another into chunks, reservations on
 * huge pages; `base` is the last chunk, `bytes` long, `used` of them taken.
 * A chunk starts with the previous chunk's address and its own size. */
typedef struct arena {
    char *base;
    size_t bytes, used;
} arena;
typedef struct arena_chunk {
    char *prev;
    size_t bytes;
} arena_chunk;
#define RTK_ARENA_CHUNK ((size_t)32 << 20)
#define RTK_ARENA_HEAD ((size_t)64) /* (a cache line, for the chunk's arena_chunk) */

/* A part of the tree in arrays of its own: the top nodes, or one subtree. */
typedef struct part {
    const build *bd;
    range r;         /* a subtree's references */
    uint32_t depth0; /* the depth of its root */
    char *nodes;     /* node_count nodes of bd->node_size bytes */
    uint32_t node_count, node_cap;
    size_t nodes_mapped; /* nodes is a reservation of this many bytes (a subtree's), else 0: malloc'd */
    int in_arena;        /* a subtree's nodes lie in its thread's arena (see build_subtree) */
    leafrange *leaves;
    uint32_t leaf_count, leaf_cap;
    uint64_t blocks;
    uint64_t refs;  /* references in the leaves */
    uint32_t depth; /* the deepest level reached */
    uint32_t root;  /* part-local reference */
    binpool pool;   /* its ranges' bins */
    const refpages *pages; /* a subtree's, in stage 3; NULL: its references' pages go back alone */
    int oom;
    uint64_t node_base, block_base; /* where stage 3 puts it */
} part;

/* Centroid as lo/2 + hi/2, which cannot overflow for finite boxes.  Lane 3
 * (the ids, often denormal as floats) is cleared first: arithmetic on
 * denormals costs a microcode assist per instruction on x86. */
static inline vfloat4 centroid(vfloat4 lo, vfloat4 hi)
{
    const vfloat4 half = vf4_set1(0.5f);
    return vf4_madd(vf4_clear3(lo), half, vf4_mul(vf4_clear3(hi), half));
}

/* Leaf blocks of four for counts in lanes 0..2, as floats. */
static inline vfloat4 block_count(vint4 n)
{
    return vf4_from_vi4(vi4_shr(vi4_add(n, vi4_set1(3)), 2));
}

/* The mapping from centroids to bins, per axis in lanes 0..2.  Binning and
 * partitioning both go through bin_of, so they always agree. */
typedef struct binmap {
    vfloat4 cmin, scale;
} binmap;

/* The bin of c, a point inside the box the map was made over (make_binmap:
 * a range's centroid bounds, or bounds known to hold them).  On an axis
 * that can be split, c - cmin is at least 0 and at most the extent as
 * rounded, and the scale (finite: make_binmap) takes that to at most
 * nb * 0.99999 * (1 + 2^-24)^2 < nb, so no bin above the last comes out.
 * On the others the scale is 0, and x is 0, or NaN where c - cmin
 * overflowed (a mesh spanning more than the float range), which the
 * maximum (its second operand on NaN) takes to bin 0. */
static inline vint4 bin_of(const binmap *m, vfloat4 c)
{
    vfloat4 x = vf4_mul(vf4_sub(c, m->cmin), m->scale);
    return vi4_from_vf4_trunc(vf4_max(x, vf4_set1(0.0f)));
}

typedef struct split {
    int axis;   /* -1: no object split possible */
    int pos;    /* left = bins [0, pos) */
    float cost; /* the two halves' areas times their blocks of four */
    binmap map;
    box4 left, right; /* the halves' boxes */
    uint32_t n_left;  /* references in the left half */
} split;

/* Fewer bins for small ranges, as Embree counts them (4 + n / 20): clearing
 * and sweeping 32 bins would cost more than binning the triangles.  Measured
 * on dragon against n + 4 (rtktool build, 1 thread): build 292 -> 269 ms,
 * SAH cost 16.19 -> 16.24, memory 64.3 -> 67.0 bytes per triangle. */
static inline int bin_count(uint32_t n)
{
    uint32_t b = 4 + n / 20;
    return b < RTK_SAH_BINS ? (int)b : RTK_SAH_BINS;
}

/* ---- splitting a range ---- */

/* The bins of one chunk of references: per axis and bin the box of the
 * references in it, kept as lo and -hi so that growing it is a min on both
 * halves (one 8-wide min where the backend has AVX2; -max(a, b) is
 * min(-a, -b) exactly, NaN and signed zeros included, so every backend
 * bins to the same floats), and the number of references in it in lane 3
 * of lo (lane 3 of a box is never a coordinate), as the bits of -0.0 plus
 * the count: a negative float (or -0.0) which a min with the reference's
 * +0.0 there leaves as it is (vminps returns its second operand, the bin,
 * on a tie), then an integer + 1.  So adding a reference to a bin takes one
 * line, not an increment elsewhere. */
typedef struct bin {
    _Alignas(32) vfloat4 lo; /* lane 3: the count, see above */
    vfloat4 nhi;             /* -hi */
} bin;

typedef struct bins {
    bin box[3][RTK_SAH_BINS];
} bins;

#define BIN_COUNT_ZERO 0x80000000u /* -0.0 */

/* A bin with nothing in it: an empty box, a count of 0. */
static inline bin bin_empty(void)
{
    const box4 e = box_empty();
    return (bin){vf4_select(vb4_from_bits(7), e.lo, vf4_set1(-0.0f)), vf4_xor_sign(e.hi, vf4_set1(-1.0f))};
}

static inline uint32_t bin_size(const bin *b)
{
    uint32_t n;
    memcpy(&n, (const char *)&b->lo + 3 * sizeof(float), sizeof n);
    return n - BIN_COUNT_ZERO;
}

/* The bin's box, lane 3 cleared: the count there is a negative subnormal
 * as a float, and these boxes become ranges' boxes, which the spatial
 * splits compute with in all four lanes; a subnormal operand costs a
 * microcode assist per instruction (high quality on the dragon took 20%
 * longer with the count left in). */
static inline box4 bin_box(const bin *b)
{
    return (box4){vf4_clear3(b->lo), vf4_clear3(vf4_xor_sign(b->nhi, vf4_set1(-1.0f)))};
}

/* The byte offsets in a bins of a reference's bin on each axis, from its
 * bin indices k (lanes 0..2), so that adding it takes no address
 * arithmetic but three lane extracts. */
static inline vint4 bin_offsets(vint4 k)
{
    _Static_assert(sizeof(bin) == 32, "bin_offsets shifts by 5");
    static const _Alignas(16) int32_t axis[4] = {0, RTK_SAH_BINS * 32, 2 * RTK_SAH_BINS * 32, 0};
    return vi4_add(vi4_shl(k, 5), vi4_load(axis));
}

/* Adds one reference's box to its bins at offsets off (bin_offsets): lo0
 * is its lo with lane 3 cleared (centroid computes it), hi its hi. */
static inline void bin_add(bins *b, vint4 off, vfloat4 lo0, vfloat4 hi)
{
    const vfloat4 nhi = vf4_xor_sign(hi, vf4_set1(-1.0f));
    char *base = (char *)b->box;
    /* (as unsigned: no sign extension) */
    bin *x = (bin *)(base + (uint32_t)vi4_lane(off, 0)), *y = (bin *)(base + (uint32_t)vi4_lane(off, 1)),
        *z = (bin *)(base + (uint32_t)vi4_lane(off, 2));
    /* the bin second: it wins ties (see struct bin) */
#if RTK_SIMD_HAS_8 && defined(__AVX2__)
    const vfloat8 r = vf8_from4(lo0, nhi);
    static const _Alignas(32) int32_t one[8] = {0, 0, 0, 1, 0, 0, 0, 0};
    const vfloat8 inc = vf8_load((const float *)one);
    vf8_store((float *)x, vf8_add_bits(vf8_min(r, vf8_load((const float *)x)), inc));
    vf8_store((float *)y, vf8_add_bits(vf8_min(r, vf8_load((const float *)y)), inc));
    vf8_store((float *)z, vf8_add_bits(vf8_min(r, vf8_load((const float *)z)), inc));
#else
    static const _Alignas(16) int32_t one[4] = {0, 0, 0, 1};
    const vint4 inc = vi4_load(one);
    x->lo = vf4_from_bits(vi4_add(vf4_bits(vf4_min(lo0, x->lo)), inc));
    x->nhi = vf4_min(nhi, x->nhi);
    y->lo = vf4_from_bits(vi4_add(vf4_bits(vf4_min(lo0, y->lo)), inc));
    y->nhi = vf4_min(nhi, y->nhi);
    z->lo = vf4_from_bits(vi4_add(vf4_bits(vf4_min(lo0, z->lo)), inc));
    z->nhi = vf4_min(nhi, z->nhi);
#endif
}

/* Bin a grows by bin b: boxes joined, counts added. */
static inline void bin_join(bin *a, const bin *b)
{
    const vbool4 xyz = vb4_from_bits(7);
    const vint4 n = vf4_bits(vf4_select(xyz, vf4_set1(0.0f), vf4_from_bits(vi4_set1((int32_t)bin_size(b)))));
    a->lo = vf4_from_bits(vi4_add(vf4_bits(vf4_min(vf4_clear3(b->lo), a->lo)), n));
    a->nhi = vf4_min(b->nhi, a->nhi);
}

static void bins_clear(bins *b, int nb)
{
    const bin e = bin_empty();
    for (int a = 0; a < 3; a++)
        for (int k = 0; k < nb; k++)
            b->box[a][k] = e;
}

static void bins_merge(bins *into, const bins *b, int nb)
{
    for (int a = 0; a < 3; a++)
        for (int k = 0; k < nb; k++)
            bin_join(&into->box[a][k], &b->box[a][k]);
}

/* nb bins over box b (a range's centroids, or for spatial splits its
 * triangles); 0 when no axis can be split: the box is flat in all three,
 * or its extents are so small (denormal) that the scale overflows. */
static int make_binmap(const box4 *b, int nb, binmap *map)
{
    const vfloat4 ext = vf4_sub(b->hi, b->lo);
    vbool4 ok = vb4_and(vb4_from_bits(7), vb4_and(vf4_gt(ext, vf4_set1(0.0f)), vf4_le(ext, vf4_set1(FLT_MAX))));
    /* the division in lanes without an extent gives what the mask drops */
    const vfloat4 scale = vf4_div(vf4_set1((float)nb * 0.99999f), vf4_select(ok, ext, vf4_set1(1.0f)));
    ok = vb4_and(ok, vf4_le(scale, vf4_set1(FLT_MAX)));
    *map = (binmap){.cmin = b->lo, .scale = vf4_keep(ok, scale)};
    return vb4_mask(ok) != 0;
}

/* Adds references [begin, end) to the bins (cleared by the caller).  Two
 * references per step: both bin indices first, so the two sets of bin
 * updates can overlap.  Neighbouring references of a mesh mostly fall in
 * the same bins, and each bin update is a load, min/max and store that the
 * next update of that bin must wait for; over many references the odd ones
 * go to a second set of bins, merged at the end, which halves that chain. */
#define RTK_BIN_TWO_SETS 256u
static void bin_refs(const primref *refs, uint32_t begin, uint32_t end, const binmap *map, bins *b, int nb)
{
    bins odd_bins;
    bins *odd = b;
    if (end - begin >= RTK_BIN_TWO_SETS) {
        odd = &odd_bins;
        bins_clear(odd, nb);
    }
    uint32_t i = begin;
    for (; i + 1 < end; i += 2) {
        vfloat4 lo0 = vf4_load(refs[i].lo), hi0 = vf4_load(refs[i].hi);
        vfloat4 lo1 = vf4_load(refs[i + 1].lo), hi1 = vf4_load(refs[i + 1].hi);
        vint4 k0 = bin_offsets(bin_of(map, centroid(lo0, hi0)));
        vint4 k1 = bin_offsets(bin_of(map, centroid(lo1, hi1)));
        bin_add(b, k0, vf4_clear3(lo0), hi0);
        bin_add(odd, k1, vf4_clear3(lo1), hi1);
    }
    if (i < end) {
        vfloat4 lo0 = vf4_load(refs[i].lo), hi0 = vf4_load(refs[i].hi);
        bin_add(b, bin_offsets(bin_of(map, centroid(lo0, hi0))), vf4_clear3(lo0), hi0);
    }
    if (odd != b)
        bins_merge(b, odd, nb);
}

/* Half surface areas of three boxes given as lo and -hi (the bins' form), one
 * per lane (lane 3 unspecified): lo + -hi is -(hi - lo) exactly (0 for a
 * flat side, not -0), and the products of two negated extents are those of
 * the extents, so the areas are those of the extents hi - lo.  Lane 3 of
 * the boxes (the bins' counts and ids, denormal as floats) goes to the
 * fourth row of the transposition, which no arithmetic reads: only the
 * addition sees it. */
static inline vfloat4 half_areas3_neg(const vfloat4 lo[3], const vfloat4 nhi[3])
{
    vfloat4 dx = vf4_add(lo[0], nhi[0]), dy = vf4_add(lo[1], nhi[1]), dz = vf4_add(lo[2], nhi[2]), dw = dz;
    vf4_transpose(&dx, &dy, &dz, &dw); /* now dx = the three boxes' negated x extents */
    vfloat4 area = vf4_madd(dx, dy, vf4_madd(dy, dz, vf4_mul(dz, dx)));
    /* an empty box (lo > hi) has no area; its negated extents are positive */
    return vf4_keep(vf4_le(dx, vf4_set1(0.0f)), area);
}

/* The best split of n references from their bins: the three axes at once in
 * lanes 0..2.  right_cost[k] is the cost of bins [k, nb) as one child.  The
 * bins are swept as they are, lo and -hi grown by minima. */
static split sweep(const bins *b, int nb, uint32_t n, const binmap *map)
{
    split best; /* (not zeroed whole: a store loop per sweep) */
    best.axis = -1;
    best.pos = 0;
    best.n_left = 0;
    _Alignas(16) int32_t counts[RTK_SAH_BINS][4];
    for (int k = 0; k < nb; k++) {
        for (int a = 0; a < 3; a++)
            counts[k][a] = (int32_t)bin_size(&b->box[a][k]);
        counts[k][3] = 0;
    }
    vfloat4 right_cost[RTK_SAH_BINS];
    const vfloat4 empty = vf4_set1(FLT_MAX); /* lo and -hi of an empty box */
    vfloat4 lo[3] = {empty, empty, empty}, nhi[3] = {empty, empty, empty};
    vint4 cnt = vi4_set1(0);
    for (int k = nb - 1; k > 0; k--) {
        for (int a = 0; a < 3; a++) {
            lo[a] = vf4_min(lo[a], b->box[a][k].lo); /* the bin on a tie, as box_grow */
            nhi[a] = vf4_min(nhi[a], b->box[a][k].nhi);
        }
        cnt = vi4_add(cnt, vi4_load(counts[k]));
        right_cost[k] = vf4_mul(half_areas3_neg(lo, nhi), block_count(cnt));
    }
    const vint4 zero = vi4_set1(0), all = vi4_set1((int32_t)n);
    const vbool4 usable = vf4_gt(map->scale, vf4_set1(0.0f)); /* lane 3: scale 0 */
    vfloat4 best_cost = vf4_set1(INFINITY);
    vint4 best_pos = zero;
    for (int a = 0; a < 3; a++)
        lo[a] = nhi[a] = empty;
    cnt = zero;
    for (int k = 1; k < nb; k++) {
        for (int a = 0; a < 3; a++) {
            lo[a] = vf4_min(lo[a], b->box[a][k - 1].lo); /* the bin on a tie, as box_grow */
            nhi[a] = vf4_min(nhi[a], b->box[a][k - 1].nhi);
        }
        cnt = vi4_add(cnt, vi4_load(counts[k - 1]));
        vfloat4 cost = vf4_madd(half_areas3_neg(lo, nhi), block_count(cnt), right_cost[k]);
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
    best.map = *map;
    if (best.axis >= 0) {
        const int a = best.axis;
        box4 l = box_empty(), r = box_empty();
        uint32_t nl = 0;
        for (int k = 0; k < best.pos; k++) {
            const box4 bx = bin_box(&b->box[a][k]);
            box_grow(&l, bx.lo, bx.hi);
            nl += (uint32_t)counts[k][a];
        }
        for (int k = best.pos; k < nb; k++) {
            const box4 bx = bin_box(&b->box[a][k]);
            box_grow(&r, bx.lo, bx.hi);
        }
        best.left = l;
        best.right = r;
        best.n_left = nl;
    } else {
        best.left = best.right = box_empty();
    }
    return best;
}

/* ---- bins made ahead ----
 * A split is found from the bins of the range's references (find_split),
 * and the references are then partitioned by it, another pass over them.
 * So that the next split needs no pass of its own, the partition also adds
 * each reference to its side's bins.  A side's centroid bounds, which its
 * bins should span, are only known after that pass: its bins span the box
 * known before it, the parent's centroid bounds cut to the side's bounds
 * (the boxes of its bins on the split axis).  Its exact centroid bounds,
 * gathered by the partition, are what its own sides' bins start from. */
typedef struct binned {
    bins b;
    binmap map;
    int nb;
    struct binned *next_free, *next_all;
} binned;

/* Bins from pool p; NULL when out of memory (the range is then binned by
 * find_split). */
static binned *pool_get(binpool *p)
{
    binned *b = p->free;
    if (b) {
        p->free = b->next_free;
        return b;
    }
    b = aligned_alloc(_Alignof(binned), sizeof *b);
    if (b) {
        b->next_all = p->all;
        p->all = b;
    }
    return b;
}

/* Back to p, to be reused by p's thread (the bins may come from another
 * pool, which still frees them). */
static void pool_put(binpool *p, binned *b)
{
    if (b) {
        b->next_free = p->free;
        p->free = b;
    }
}

static void pool_release(binpool *p)
{
    while (p->all) {
        binned *next = p->all->next_all;
        free(p->all);
        p->all = next;
    }
    p->free = NULL;
}

/* Sets up b for a side of n references of split s of r (see above). */
static void side_bins(const range *r, const box4 *side, uint32_t n, binned *b)
{
    const vbool4 xyz = vb4_from_bits(7); /* lane 3 of a box holds ids: see centroid */
    const box4 c = {vf4_keep(xyz, vf4_max(r->cent.lo, side->lo)), vf4_keep(xyz, vf4_min(r->cent.hi, side->hi))};
    b->nb = bin_count(n);
    make_binmap(&c, b->nb, &b->map); /* a flat box gives no usable axis, and sweep no split */
    bins_clear(&b->b, b->nb);
}

static split find_split(const build *bd, const range *r)
{
    const uint32_t n = r->end - r->begin;
    if (r->bn)
        return sweep(&r->bn->b, r->bn->nb, n, &r->bn->map);
    const int nb = bin_count(n);
    binmap map;
    if (!make_binmap(&r->cent, nb, &map))
        return (split){.axis = -1};
    bins b;
    bins_clear(&b, nb);
    bin_refs(bd->refs, r->begin, r->end, &map, &b, nb);
    return sweep(&b, nb, n, &map);
}

static void range_init(range *r, uint32_t begin, uint32_t end)
{
    r->begin = begin;
    r->end = end;
    r->ext = end;
    r->geom = box_empty();
    r->cent = box_empty();
    r->bn = NULL;
}

/* The end of r's references and of the room behind them, whichever is last. */
static inline uint32_t range_room_end(const range *r)
{
    return r->ext > r->end ? r->ext : r->end;
}

static inline void range_add(range *r, vfloat4 lo, vfloat4 hi)
{
    vfloat4 c = centroid(lo, hi);
    box_grow(&r->geom, lo, hi);
    box_grow(&r->cent, c, c);
}

/* Centroid bounds gathered by a partition: on avx2 as lo and -hi in one
 * 8-wide vector, grown by one min (as the bins are; -max(a, b) is
 * min(-a, -b) exactly), so each side's bounds take one register. */
#if RTK_SIMD_HAS_8 && defined(__AVX2__)
typedef vfloat8 cbox;
static inline cbox cbox_empty(void)
{
    return vf8_set1(FLT_MAX);
}
static inline cbox cbox_grow(cbox b, vfloat4 c)
{
    return vf8_min(vf8_from4(c, vf4_xor_sign(c, vf4_set1(-1.0f))), b);
}
static inline box4 cbox_box(cbox b)
{
    return (box4){vf8_low(b), vf4_xor_sign(vf8_high(b), vf4_set1(-1.0f))};
}
#else
typedef box4 cbox;
static inline cbox cbox_empty(void)
{
    return box_empty();
}
static inline cbox cbox_grow(cbox b, vfloat4 c)
{
    box_grow(&b, c, c);
    return b;
}
static inline box4 cbox_box(cbox b)
{
    return b;
}
#endif

static void range_merge(range *into, const range *r)
{
    box_grow(&into->geom, r->geom.lo, r->geom.hi);
    box_grow(&into->cent, r->cent.lo, r->cent.hi);
}

static void range_recompute(const primref *refs, range *r)
{
    range_init(r, r->begin, r->end);
    for (uint32_t i = r->begin; i < r->end; i++)
        range_add(r, vf4_load(refs[i].lo), vf4_load(refs[i].hi));
}

/* The bins the two sides of a partition are added to (see "bins made
 * ahead"), or none. */
typedef struct side_bins_to {
    bins *left, *right;
    const binmap *left_map, *right_map;
} side_bins_to;

/* Floats in order as unsigned integers (NaN excepted): -inf, ..., -0, +0,
 * ..., +inf map to increasing keys. */
static inline uint32_t float_key(float x)
{
    uint32_t b;
    memcpy(&b, &x, sizeof b);
    return b & 0x80000000u ? ~b : b | 0x80000000u;
}

static inline float key_float(uint32_t k)
{
    const uint32_t b = k & 0x80000000u ? k & 0x7fffffffu : ~k;
    float x;
    memcpy(&x, &b, sizeof x);
    return x;
}

/* Whether centroid coordinate x lies right of split s (axis a, lane a of
 * its map): the partition's test, x = (c - cmin) * scale at or above the
 * split position, in the same IEEE operations as the vector lanes. */
static inline int split_right(float x, float cmin, float scale, float pos)
{
    return (x - cmin) * scale >= pos;
}

/* The split of s as a plane: the least float t that lies right of it, so
 * that c >= t is split_right(c) for every c (split_right is monotone in c,
 * and NaN fails both).  Found from cmin + pos / scale, which is within a
 * few ulps of it, by doubling steps and then halving them. */
static float split_plane(const split *s)
{
    _Alignas(16) float cmin[4], scale[4];
    vf4_store(cmin, s->map.cmin);
    vf4_store(scale, s->map.scale);
    const float m = cmin[s->axis], k = scale[s->axis], pos = (float)s->pos;
    /* the split axis has a finite cmin and scale > 0: -inf lies left,
     * +inf right */
    const uint32_t key_min = float_key(-INFINITY), key_max = float_key(INFINITY);
    float guess = m + pos / k;
    if (guess != guess)
        guess = INFINITY;
    uint32_t left, right; /* keys of a float left of the split and one right of it */
    uint32_t step = 1;
    if (split_right(guess, m, k, pos)) {
        right = float_key(guess);
        for (;;) {
            left = right - key_min > step ? right - step : key_min;
            if (left == key_min || !split_right(key_float(left), m, k, pos))
                break;
            right = left;
            step *= 2;
        }
    } else {
        left = float_key(guess);
        for (;;) {
            right = key_max - left > step ? left + step : key_max;
            if (right == key_max || split_right(key_float(right), m, k, pos))
                break;
            left = right;
            step *= 2;
        }
    }
    while (right - left > 1) {
        const uint32_t mid = left + (right - left) / 2;
        if (split_right(key_float(mid), m, k, pos))
            right = mid;
        else
            left = mid;
    }
    return key_float(right);
}

/* Hoare partition of [begin, end) by split s: a reference goes left when
 * its bin on the split axis is below the split position.  Returns the first
 * reference of the right side; left and right get the two sides' bounds
 * (their begin and end are the caller's to set): their boxes are the
 * split's halves (the bins' boxes of each side, exactly the union of its
 * references' boxes), their centroid bounds gathered here.  With_bins (a
 * constant: the two uses are compiled apart), each reference is also
 * added to its side's bins in *to. */
static inline uint32_t partition_with(primref *refs, uint32_t begin, uint32_t end, const split *s, range *left,
                                      range *right, const side_bins_to *to, const int with_bins)
{
    /* All in locals: the stores below could alias *s, *to, *left and *right
     * for all the compiler knows. */
    /* bin_of(c) < pos on the split axis is x = (c - cmin) * scale below pos
     * (or NaN, which bin_of puts in bin 0), and that is c below the split's
     * plane (split_plane): one comparison on the path the loops' branches
     * wait for, instead of three operations and a conversion. */
    const vfloat4 plane = vf4_set1(split_plane(s));
    const binmap map = s->map;
    bins *lb = with_bins ? to->left : NULL, *rb = with_bins ? to->right : NULL;
    const binmap lm = with_bins ? *to->left_map : map, rm = with_bins ? *to->right_map : map;
    const int bit = 1 << s->axis;
    uint32_t i = begin, j = end;
    cbox lc = cbox_empty(), rc = cbox_empty();
    vfloat4 lo_i, hi_i, lo_j, hi_j;
    for (;;) {
        for (; i < j; i++) {
            lo_i = vf4_load(refs[i].lo);
            hi_i = vf4_load(refs[i].hi);
            const vfloat4 c = centroid(lo_i, hi_i);
            if (vb4_mask(vf4_ge(c, plane)) & bit)
                break;
            lc = cbox_grow(lc, c);
            if (with_bins)
                bin_add(lb, bin_offsets(bin_of(&lm, c)), vf4_clear3(lo_i), hi_i);
        }
        for (; i < j; j--) {
            lo_j = vf4_load(refs[j - 1].lo);
            hi_j = vf4_load(refs[j - 1].hi);
            const vfloat4 c = centroid(lo_j, hi_j);
            if (!(vb4_mask(vf4_ge(c, plane)) & bit))
                break;
            rc = cbox_grow(rc, c);
            if (with_bins)
                bin_add(rb, bin_offsets(bin_of(&rm, c)), vf4_clear3(lo_j), hi_j);
        }
        if (i >= j)
            break;
        /* refs[i] belongs right and refs[j - 1] left: swap them. */
        vf4_store(refs[i].lo, lo_j);
        vf4_store(refs[i].hi, hi_j);
        vf4_store(refs[j - 1].lo, lo_i);
        vf4_store(refs[j - 1].hi, hi_i);
        const vfloat4 cj = centroid(lo_j, hi_j), ci = centroid(lo_i, hi_i);
        lc = cbox_grow(lc, cj);
        rc = cbox_grow(rc, ci);
        if (with_bins) {
            bin_add(lb, bin_offsets(bin_of(&lm, cj)), vf4_clear3(lo_j), hi_j);
            bin_add(rb, bin_offsets(bin_of(&rm, ci)), vf4_clear3(lo_i), hi_i);
        }
        i++;
        j--;
    }
    range_init(left, 0, 0);
    range_init(right, 0, 0);
    left->geom = s->left;
    left->cent = cbox_box(lc);
    right->geom = s->right;
    right->cent = cbox_box(rc);
    return i;
}

/* partition, adding the sides' references to bins `to` if not NULL. */
static uint32_t partition(primref *refs, uint32_t begin, uint32_t end, const split *s, range *left, range *right,
                          const side_bins_to *to)
{
    if (to)
        return partition_with(refs, begin, end, s, left, right, to, 1);
    return partition_with(refs, begin, end, s, left, right, NULL, 0);
}

/* Halves at the middle reference: for coinciding centroids, and past the
 * median depth. */
static void split_middle(const primref *refs, const range *r, range *left, range *right)
{
    const uint32_t mid = r->begin + (r->end - r->begin) / 2;
    range_init(left, r->begin, mid);
    range_init(right, mid, r->end);
    range_recompute(refs, left);
    range_recompute(refs, right);
}

/* ---- spatial splits (high quality) ----
 * As in Stich et al. 2009 (SBVH) and Embree's high-quality builder: a range
 * whose best object split leaves two overlapping halves is also binned in
 * RTK_SPATIAL_BINS slabs of its box per axis.  A reference spanning several
 * slabs is cut at each slab boundary, the triangle itself clipped (not only
 * its box), and a split at a boundary sends the references crossing it to
 * both sides with the clipped boxes.  The cheaper of the two splits by the
 * SAH wins.  The extra references live in room the build reserves behind
 * the references (a fifth of their count, as Embree's default 1.2x), which
 * every split shares out between its halves in proportion to their sizes:
 * a range whose share is used up splits by objects only. */
#define RTK_SPATIAL_BINS 16
#define RTK_SPATIAL_ROOM_DIV 5
/* Spatial splits are tried only where the object split's halves overlap by
 * more than this fraction of the scene's surface area (Stich's alpha) and
 * by at least this fraction of the range's own (as Embree does): binning
 * in slabs costs several times what object binning does, and where the
 * halves barely overlap it seldom wins.  Measured with rtktool build
 * --quality high, 1 thread, against no second threshold: dragon build
 * 1.06 -> 0.87 s, SAH cost 15.975 -> 15.987; apartment 0.169 -> 0.133 s,
 * 8.328 -> 8.323; San Miguel 4.404 -> 4.384. */
#define RTK_SPATIAL_ALPHA 1e-5f
#define RTK_SPATIAL_NODE_OVERLAP 0.1f

/* Slabs: per axis, bin k spans [plane[a][k], plane[a][k + 1]). */
typedef struct slabs {
    binmap map; /* over the range's box */
    int nb;
    _Alignas(16) float scale[4];
    float plane[3][RTK_SPATIAL_BINS + 1];
} slabs;

typedef struct sbins {
    box4 box[3][RTK_SPATIAL_BINS]; /* the clipped parts in each slab */
    _Alignas(16) int32_t enter[RTK_SPATIAL_BINS][4], leave[RTK_SPATIAL_BINS][4];
} sbins;

typedef struct spatial_split {
    int axis;
    float plane; /* left: x[axis] <= plane, right: x[axis] >= plane */
    float cost;
} spatial_split;

static int make_slabs(const range *r, slabs *s)
{
    const int nb = bin_count(r->end - r->begin);
    s->nb = nb < RTK_SPATIAL_BINS ? nb : RTK_SPATIAL_BINS;
    const int splittable = make_binmap(&r->geom, s->nb, &s->map);
    _Alignas(16) float lo[4];
    vf4_store(lo, r->geom.lo);
    vf4_store(s->scale, s->map.scale);
    for (int a = 0; a < 3; a++)
        for (int k = 0; k <= s->nb; k++)
            s->plane[a][k] = s->scale[a] > 0.0f ? lo[a] + (float)k / s->scale[a] : lo[a];
    return splittable;
}

/* The vertices of a reference's triangle (lane 3 zero), and their
 * coordinates as scalars. */
typedef struct tri3 {
    vfloat4 v[3];
    _Alignas(16) float c[3][4];
} tri3;

static void ref_triangle(const build *bd, const primref *ref, tri3 *t)
{
    const rtk_build_geometry *g = &bd->in->geometries[ref_geom(ref)];
    const uint32_t *tri = triangle_at(g, ref_prim(ref));
    for (int i = 0; i < 3; i++) {
        const float *p = vertex_at(g, tri[i]);
        t->v[i] = vf4_set(p[0], p[1], p[2], 0.0f);
        vf4_store(t->c[i], t->v[i]);
    }
}

static inline int box_is_empty3(const box4 *b)
{
    return (vb4_mask(vf4_ge(b->hi, b->lo)) & 7) != 7;
}

/* The boxes of the parts of triangle t inside *cur on either side of the
 * plane x[a] = plane; an empty side gets an empty box.  The points where
 * edges cross the plane are rounded, so their boxes are widened by a few
 * ulps of the edge's ends: the two boxes together always cover the part of
 * the triangle inside *cur. */
static void split_triangle(const tri3 *t, const box4 *cur, int a, float plane, box4 *left, box4 *right)
{
    const vbool4 on_axis = vb4_from_bits(1 << a);
    const vfloat4 eps = vf4_keep(vb4_andnot(vb4_from_bits(7), on_axis), vf4_set1(0x1p-21f));
    box4 l = box_empty(), r = box_empty();
    for (int i = 0; i < 3; i++) {
        const int j = i == 2 ? 0 : i + 1;
        const float p = t->c[i][a], q = t->c[j][a];
        if (p <= plane)
            box_grow(&l, t->v[i], t->v[i]);
        if (p >= plane)
            box_grow(&r, t->v[i], t->v[i]);
        if ((p < plane && q > plane) || (p > plane && q < plane)) {
            const vfloat4 d = vf4_sub(t->v[j], t->v[i]);
            vfloat4 x = vf4_add(t->v[i], vf4_mul(vf4_set1((plane - p) / (q - p)), d));
            x = vf4_select(on_axis, vf4_set1(plane), x);
            const vfloat4 m = vf4_mul(vf4_add(vf4_abs(t->v[i]), vf4_abs(t->v[j])), eps);
            const vfloat4 xlo = vf4_sub(x, m), xhi = vf4_add(x, m);
            box_grow(&l, xlo, xhi);
            box_grow(&r, xlo, xhi);
        }
    }
    left->lo = vf4_max(l.lo, cur->lo);
    left->hi = vf4_min(l.hi, cur->hi);
    right->lo = vf4_max(r.lo, cur->lo);
    right->hi = vf4_min(r.hi, cur->hi);
    if (box_is_empty3(left))
        *left = box_empty();
    if (box_is_empty3(right))
        *right = box_empty();
}

static void sbins_clear(sbins *b, int nb)
{
    for (int a = 0; a < 3; a++)
        for (int k = 0; k < nb; k++)
            b->box[a][k] = box_empty();
    memset(b->enter, 0, sizeof b->enter);
    memset(b->leave, 0, sizeof b->leave);
}

static void sbins_merge(sbins *into, const sbins *b, int nb)
{
    for (int a = 0; a < 3; a++)
        for (int k = 0; k < nb; k++)
            box_grow(&into->box[a][k], b->box[a][k].lo, b->box[a][k].hi);
    for (int k = 0; k < nb; k++) {
        vi4_store(into->enter[k], vi4_add(vi4_load(into->enter[k]), vi4_load(b->enter[k])));
        vi4_store(into->leave[k], vi4_add(vi4_load(into->leave[k]), vi4_load(b->leave[k])));
    }
}

/* Adds references [begin, end) to the slabs (cleared by the caller): a
 * reference counts as entering its first slab and leaving its last, and
 * its parts grow the slabs they lie in. */
static void sbin_refs(const build *bd, const slabs *s, uint32_t begin, uint32_t end, sbins *b)
{
    for (uint32_t i = begin; i < end; i++) {
        const primref *ref = &bd->refs[i];
        const vbool4 xyz = vb4_from_bits(7); /* the ids in lane 3: no denormal arithmetic */
        const vfloat4 lo = vf4_keep(xyz, vf4_load(ref->lo)), hi = vf4_keep(xyz, vf4_load(ref->hi));
        _Alignas(16) int32_t first[4], last[4];
        vi4_store(first, bin_of(&s->map, lo));
        vi4_store(last, bin_of(&s->map, hi));
        tri3 v;
        int loaded = 0;
        for (int a = 0; a < 3; a++) {
            b->enter[first[a]][a]++;
            b->leave[last[a]][a]++;
            if (first[a] == last[a] || s->scale[a] == 0.0f) {
                box_grow(&b->box[a][first[a]], lo, hi);
                continue;
            }
            if (!loaded) {
                ref_triangle(bd, ref, &v);
                loaded = 1;
            }
            box4 cur = {lo, hi};
            for (int k = first[a]; k < last[a] && !box_is_empty3(&cur); k++) {
                box4 l, r;
                split_triangle(&v, &cur, a, s->plane[a][k + 1], &l, &r);
                box_grow(&b->box[a][k], l.lo, l.hi);
                cur = r;
            }
            box_grow(&b->box[a][last[a]], cur.lo, cur.hi);
        }
    }
}

/* The cheapest spatial split of n references that needs at most `room`
 * new ones; axis -1 when there is none. */
static spatial_split spatial_sweep(const sbins *b, const slabs *s, uint32_t n, uint32_t room)
{
    spatial_split best = {.axis = -1, .cost = INFINITY};
    const int nb = s->nb;
    for (int a = 0; a < 3; a++) {
        if (s->scale[a] == 0.0f)
            continue;
        float right_cost[RTK_SPATIAL_BINS];
        uint32_t right_count[RTK_SPATIAL_BINS];
        box4 acc = box_empty();
        uint32_t count = 0;
        for (int k = nb - 1; k > 0; k--) {
            box_grow(&acc, b->box[a][k].lo, b->box[a][k].hi);
            count += (uint32_t)b->leave[k][a];
            right_cost[k] = box_half_area(&acc) * (float)((count + 3) / 4);
            right_count[k] = count;
        }
        acc = box_empty();
        count = 0;
        for (int k = 1; k < nb; k++) {
            box_grow(&acc, b->box[a][k - 1].lo, b->box[a][k - 1].hi);
            count += (uint32_t)b->enter[k - 1][a];
            const uint32_t nl = count, nr = right_count[k];
            /* every reference is on one side at least, so nl + nr >= n */
            if (!nl || !nr || (nl >= n && nr >= n) || (uint64_t)nl + nr - n > room)
                continue;
            const float cost = box_half_area(&acc) * (float)((nl + 3) / 4) + right_cost[k];
            if (cost < best.cost)
                best = (spatial_split){.axis = a, .plane = s->plane[a][k], .cost = cost};
        }
    }
    return best;
}

/* The chunks stage 1 cuts a range of n references into: one per
 * RTK_CHUNK_MIN, 1 to RTK_CHUNKS_MAX. */
static uint32_t chunk_count(uint32_t n)
{
    const uint32_t c = n / RTK_CHUNK_MIN;
    return c > RTK_CHUNKS_MAX ? RTK_CHUNKS_MAX : c < 1 ? 1 : c;
}

static uint32_t chunk_at(const range *r, uint32_t chunks, uint32_t k)
{
    return r->begin + (uint32_t)((uint64_t)(r->end - r->begin) * k / chunks);
}

typedef struct pspatial {
    const build *bd;
    const range *r;
    const slabs *s;
    sbins *bins; /* one per chunk */
    uint32_t chunks;
} pspatial;

static void pspatial_bin(void *data, uint32_t k)
{
    pspatial *p = data;
    sbins_clear(&p->bins[k], p->s->nb);
    sbin_refs(p->bd, p->s, chunk_at(p->r, p->chunks, k), chunk_at(p->r, p->chunks, k + 1), &p->bins[k]);
}

/* A spatial split of r cheaper than the object split s, in *out: 1, or 0
 * when there is none or none is tried (no room left, no overlap).  With
 * `scratch` (RTK_CHUNKS_MAX bins) a large range is binned on every thread,
 * in chunks merged in order. */
static int find_spatial(const build *bd, sbins *scratch, const range *r, const split *s, spatial_split *out)
{
    const uint32_t n = r->end - r->begin, room = r->ext - r->end;
    if (!room)
        return 0;
    if (s->axis >= 0) {
        box4 overlap = {vf4_max(s->left.lo, s->right.lo), vf4_min(s->left.hi, s->right.hi)};
        const float o = box_is_empty3(&overlap) ? 0.0f : box_half_area(&overlap);
        if (!(o > bd->spatial_overlap) || !(o >= RTK_SPATIAL_NODE_OVERLAP * box_half_area(&r->geom)))
            return 0;
    }
    slabs sl;
    if (!make_slabs(r, &sl))
        return 0;
    sbins local, *b = &local;
    if (scratch && n >= 2 * RTK_CHUNK_MIN) {
        pspatial p = {.bd = bd, .r = r, .s = &sl, .bins = scratch, .chunks = chunk_count(n)};
        run_parallel(bd, p.chunks, pspatial_bin, &p);
        for (uint32_t k = 1; k < p.chunks; k++)
            sbins_merge(&scratch[0], &scratch[k], sl.nb);
        b = &scratch[0];
    } else {
        sbins_clear(b, sl.nb);
        sbin_refs(bd, &sl, r->begin, r->end, b);
    }
    const spatial_split sp = spatial_sweep(b, &sl, n, room);
    if (sp.axis < 0 || (s->axis >= 0 && !(sp.cost < s->cost)))
        return 0;
    *out = sp;
    return 1;
}

static void store_ref(primref *ref, const box4 *b, float geom, float prim)
{
    vf4_store(ref->lo, b->lo);
    vf4_store(ref->hi, b->hi);
    ref->lo[3] = geom;
    ref->hi[3] = prim;
}

/* Splits r at sp's plane: each reference crossing it is clipped, its left
 * part kept in place and its right part added at the end of r (while r's
 * room lasts; past that it stays whole), then [begin, end) is partitioned
 * by the boxes' centres.  Returns 0 (the references still valid, maybe
 * clipped) if a side came out empty, which rounding can cause. */
static int spatial_partition(const build *bd, const range *r, const spatial_split *sp, range *left, range *right)
{
    primref *refs = bd->refs;
    const int a = sp->axis;
    const float plane = sp->plane;
    uint32_t at = r->end;
    for (uint32_t i = r->begin; i < r->end; i++) {
        primref *ref = &refs[i];
        if (!(ref->lo[a] < plane && ref->hi[a] > plane))
            continue;
        tri3 v;
        ref_triangle(bd, ref, &v);
        const box4 cur = {vf4_load(ref->lo), vf4_load(ref->hi)};
        box4 l, rr;
        split_triangle(&v, &cur, a, plane, &l, &rr);
        const int has_l = !box_is_empty3(&l), has_r = !box_is_empty3(&rr);
        const float geom = ref->lo[3], prim = ref->hi[3];
        if (has_l && has_r) {
            if (at == r->ext)
                continue;
            store_ref(&refs[at++], &rr, geom, prim);
            store_ref(ref, &l, geom, prim);
        } else if (has_l || has_r) {
            store_ref(ref, has_l ? &l : &rr, geom, prim);
        }
    }
    uint32_t i = r->begin, j = r->end;
    while (i < j) {
        const float c = refs[i].lo[a] * 0.5f + refs[i].hi[a] * 0.5f;
        if (c < plane) {
            i++;
        } else {
            const primref t = refs[i];
            refs[i] = refs[--j];
            refs[j] = t;
        }
    }
    if (i == r->begin || i == at)
        return 0;
    range_init(left, r->begin, i);
    range_init(right, i, at);
    range_recompute(refs, left);
    range_recompute(refs, right);
    return 1;
}

/* After r split into left = [begin, mid) and right = [mid, end): the room
 * behind the right side, [end, r->ext), is shared in proportion to the
 * sides' sizes; the right side moves up by the left's share (its first
 * references go to its end: order inside a range means nothing). */
static void share_room(primref *refs, const range *r, range *left, range *right)
{
    const uint32_t room = r->ext - right->end;
    const uint32_t nl = left->end - left->begin, nr = right->end - right->begin;
    const uint32_t d = (uint32_t)((uint64_t)room * nl / ((uint64_t)nl + nr));
    if (d) {
        const uint32_t m = d < nr ? d : nr;
        memcpy(refs + (d >= nr ? right->begin + d : right->end), refs + right->begin, (size_t)m * sizeof *refs);
        right->begin += d;
        right->end += d;
    }
    left->ext = left->end + d;
    right->ext = r->ext;
}

/* Bins from pool for the sides of object split s of r, to be filled by
 * the partition: 0 (none) when neither side will be split again (four
 * references or fewer), or without a pool. */
static int sides_get(binpool *pool, const range *r, const split *s, binned **lb, binned **rb)
{
    const uint32_t nl = s->n_left, nr = r->end - r->begin - s->n_left;
    *lb = *rb = NULL;
    if (!pool || (nl <= 4 && nr <= 4))
        return 0;
    *lb = pool_get(pool);
    *rb = pool_get(pool);
    if (!*lb || !*rb) {
        pool_put(pool, *lb);
        pool_put(pool, *rb);
        *lb = *rb = NULL;
        return 0;
    }
    side_bins(r, &s->left, nl, *lb);
    side_bins(r, &s->right, nr, *rb);
    return 1;
}

/* The partitioned sides take their bins, but for a side of four or fewer. */
static void sides_keep(binpool *pool, range *left, binned *lb, range *right, binned *rb)
{
    if (left->end - left->begin > 4)
        left->bn = lb;
    else
        pool_put(pool, lb);
    if (right->end - right->begin > 4)
        right->bn = rb;
    else
        pool_put(pool, rb);
}

/* Splits r into two non-empty halves on this thread, along *given if not
 * NULL (a split find_split made for r), else along the best one (median:
 * halves); with spatial splits on, along a spatial split where one is
 * cheaper.  With a pool, an object split also bins the halves. */
static void split_range(const build *bd, binpool *pool, const range *r, int median, const split *given,
                        range *left, range *right)
{
    primref *refs = bd->refs;
    split s = {.axis = -1};
    if (given)
        s = *given;
    else if (!median)
        s = find_split(bd, r);
    spatial_split sp;
    if (bd->spatial && !median && find_spatial(bd, NULL, r, &s, &sp)) {
        if (!spatial_partition(bd, r, &sp, left, right))
            split_middle(refs, r, left, right);
        return;
    }
    if (s.axis < 0) {
        split_middle(refs, r, left, right);
        return;
    }
    binned *lb, *rb;
    const int binning = !median && sides_get(pool, r, &s, &lb, &rb);
    side_bins_to to = {0};
    if (binning)
        to = (side_bins_to){&lb->b, &rb->b, &lb->map, &rb->map};
    const uint32_t mid = partition(refs, r->begin, r->end, &s, left, right, binning ? &to : NULL);
    left->begin = r->begin;
    left->end = mid;
    right->begin = mid;
    right->end = r->end;
    if (binning)
        sides_keep(pool, left, lb, right, rb);
}

/* ---- splitting a large range with every thread (stage 1) ---- */

typedef struct interval {
    uint32_t begin, end;
} interval;

typedef struct psplit {
    primref *refs;
    const range *r;
    uint32_t chunks;
    int nb;
    binmap map;
    split s;
    bins *bins;                  /* two per chunk: its references', then its sides' */
    binned *lb, *rb;             /* the sides' bins, or NULL */
    uint32_t mid[RTK_CHUNKS_MAX]; /* each chunk's first right reference after its partition */
    range left[RTK_CHUNKS_MAX], right[RTK_CHUNKS_MAX];
    /* The misplaced references: rights below the split point and lefts at
     * or above it, as intervals in order; the i-th of one swaps with the
     * i-th of the other. */
    interval wrong_right[RTK_CHUNKS_MAX], wrong_left[RTK_CHUNKS_MAX];
    uint32_t n_wrong_right, n_wrong_left;
    uint32_t misplaced;
} psplit;

static uint32_t chunk_begin(const psplit *p, uint32_t k)
{
    return chunk_at(p->r, p->chunks, k);
}

static void psplit_bin(void *data, uint32_t k)
{
    psplit *p = data;
    bins_clear(&p->bins[k], p->nb);
    bin_refs(p->refs, chunk_begin(p, k), chunk_begin(p, k + 1), &p->map, &p->bins[k], p->nb);
}

/* The bounds are gathered on the stack: chunks' entries in *p share cache
 * lines, and updating them there for every reference made two threads
 * slower than one (2 threads: 26 ms against 20 for this pass on dragon). */
static void psplit_partition(void *data, uint32_t k)
{
    psplit *p = data;
    range left, right;
    side_bins_to to = {0};
    if (p->lb) {
        to = (side_bins_to){&p->bins[2 * k], &p->bins[2 * k + 1], &p->lb->map, &p->rb->map};
        bins_clear(to.left, p->lb->nb);
        bins_clear(to.right, p->rb->nb);
    }
    p->mid[k] =
        partition(p->refs, chunk_begin(p, k), chunk_begin(p, k + 1), &p->s, &left, &right, p->lb ? &to : NULL);
    p->left[k] = left;
    p->right[k] = right;
}

/* Pair `at` of the misplaced ones: interval and offset in it. */
static void locate(const interval *iv, uint32_t count, uint32_t at, uint32_t *which, uint32_t *offset)
{
    uint32_t k = 0;
    while (k + 1 < count && at >= iv[k].end - iv[k].begin) {
        at -= iv[k].end - iv[k].begin;
        k++;
    }
    *which = k;
    *offset = at;
}

static void psplit_swap(void *data, uint32_t q)
{
    psplit *p = data;
    uint32_t first = (uint32_t)((uint64_t)p->misplaced * q / p->chunks);
    uint32_t last = (uint32_t)((uint64_t)p->misplaced * (q + 1) / p->chunks);
    if (first == last)
        return;
    uint32_t a, ao, b, bo;
    locate(p->wrong_right, p->n_wrong_right, first, &a, &ao);
    locate(p->wrong_left, p->n_wrong_left, first, &b, &bo);
    uint32_t i = p->wrong_right[a].begin + ao, j = p->wrong_left[b].begin + bo;
    for (uint32_t n = first; n < last; n++) {
        while (i == p->wrong_right[a].end)
            i = p->wrong_right[++a].begin;
        while (j == p->wrong_left[b].end)
            j = p->wrong_left[++b].begin;
        primref t = p->refs[i];
        p->refs[i] = p->refs[j];
        p->refs[j] = t;
        i++;
        j++;
    }
}

/* As split_range without `given`, on every thread: bins per chunk (unless
 * r has its bins), merged in chunk order; a Hoare partition per chunk,
 * binning its sides as it goes; then the rights left of the split point
 * and the lefts right of it swapped pairwise, in order.  The result depends
 * on the chunks alone, which depend on the size alone. */
static void split_parallel(const build *bd, binpool *pool, bins *scratch, sbins *sscratch, const range *r,
                           range *left, range *right)
{
    const uint32_t n = r->end - r->begin;
    psplit *p = malloc(sizeof *p);
    if (!p) {
        /* the same split, on this thread */
        split_range(bd, pool, r, 0, NULL, left, right);
        return;
    }
    p->refs = bd->refs;
    p->r = r;
    p->chunks = chunk_count(n);
    p->nb = bin_count(n);
    p->bins = scratch;
    p->s = (split){.axis = -1};
    if (r->bn) {
        p->s = find_split(bd, r);
    } else if (make_binmap(&r->cent, p->nb, &p->map)) {
        run_parallel(bd, p->chunks, psplit_bin, p);
        for (uint32_t k = 1; k < p->chunks; k++)
            bins_merge(&p->bins[0], &p->bins[k], p->nb);
        p->s = sweep(&p->bins[0], p->nb, n, &p->map);
    }
    spatial_split sp;
    if (bd->spatial && find_spatial(bd, sscratch, r, &p->s, &sp)) {
        free(p);
        if (!spatial_partition(bd, r, &sp, left, right))
            split_middle(bd->refs, r, left, right);
        return;
    }
    if (p->s.axis < 0) {
        free(p);
        split_middle(bd->refs, r, left, right);
        return;
    }
    sides_get(pool, r, &p->s, &p->lb, &p->rb);
    run_parallel(bd, p->chunks, psplit_partition, p);

    range_init(left, 0, 0);
    range_init(right, 0, 0);
    uint32_t split_at = r->begin;
    for (uint32_t k = 0; k < p->chunks; k++) {
        range_merge(left, &p->left[k]);
        range_merge(right, &p->right[k]);
        split_at += p->mid[k] - chunk_begin(p, k);
        if (p->lb) {
            bins_merge(&p->lb->b, &p->bins[2 * k], p->lb->nb);
            bins_merge(&p->rb->b, &p->bins[2 * k + 1], p->rb->nb);
        }
    }
    p->n_wrong_right = p->n_wrong_left = 0;
    p->misplaced = 0;
    for (uint32_t k = 0; k < p->chunks; k++) {
        const uint32_t b = chunk_begin(p, k), m = p->mid[k], e = chunk_begin(p, k + 1);
        if (m < split_at && m < e) /* rights of chunk k below split_at */
            p->wrong_right[p->n_wrong_right++] = (interval){m, e < split_at ? e : split_at};
        if (m > split_at && b < m) { /* lefts of chunk k at or above split_at */
            p->wrong_left[p->n_wrong_left++] = (interval){b > split_at ? b : split_at, m};
            p->misplaced += p->wrong_left[p->n_wrong_left - 1].end - p->wrong_left[p->n_wrong_left - 1].begin;
        }
    }
    if (p->misplaced)
        run_parallel(bd, p->chunks, psplit_swap, p);
    left->begin = r->begin;
    left->end = split_at;
    right->begin = split_at;
    right->end = r->end;
    if (p->lb)
        sides_keep(pool, left, p->lb, right, p->rb);
    free(p);
}

/* ---- a part's own arrays ---- */

/* A new node of part p; UINT32_MAX (and p->oom) when out of memory. */
static uint32_t part_node(part *p)
{
    if ((p->nodes_mapped || p->in_arena) && p->node_count == p->node_cap) { /* (not expected: see build_subtree) */
        char *n = malloc((size_t)p->node_cap * p->bd->node_size);
        if (n)
            memcpy(n, p->nodes, (size_t)p->node_cap * p->bd->node_size);
        if (p->nodes_mapped)
            build_unreserve(p->bd->mem, p->nodes, p->nodes_mapped);
        p->nodes = n;
        p->nodes_mapped = 0;
        p->in_arena = 0;
        p->oom |= !n;
    }
    if (p->oom || !build_grow((void **)&p->nodes, &p->node_cap, p->node_count + 1, p->bd->node_size)) {
        p->oom = 1;
        return UINT32_MAX;
    }
    return p->node_count++;
}

static uint32_t part_leaf(part *p, uint32_t begin, uint32_t end)
{
    if (p->oom || !build_grow((void **)&p->leaves, &p->leaf_cap, p->leaf_count + 1, sizeof *p->leaves)) {
        p->oom = 1;
        return EXT;
    }
    p->leaves[p->leaf_count] = (leafrange){begin, end, 0};
    p->blocks += (end - begin + 3) / 4;
    p->refs += end - begin;
    return EXT | p->leaf_count++;
}

/* (an arena's nodes go with the arena: arenas_free) */
static void part_free_nodes(part *p)
{
    if (p->nodes_mapped)
        build_unreserve(p->bd->mem, p->nodes, p->nodes_mapped);
    else if (!p->in_arena)
        free(p->nodes);
    p->nodes = NULL;
    p->nodes_mapped = 0;
    p->in_arena = 0;
}

static void part_free(part *p)
{
    part_free_nodes(p);
    pool_release(&p->pool);
    free(p->leaves);
    p->leaves = NULL;
}

/* Writes node `index` of part p with the boxes of its nc children, child i
 * in slot slot[i]; empty slots get inverted boxes and RTK_BVH4_EMPTY.  The
 * references are set by set_child. */
static void write_node(part *p, uint32_t index, const range *child, int nc, const int *slot)
{
    if (index == UINT32_MAX)
        return;
    box4 box[8];
    for (int i = 0; i < nc; i++)
        box[slot[i]] = child[i].geom;
    build_store_node(p->bd, p->nodes, index, box, NULL, nc);
}

static void set_child(part *p, uint32_t index, int i, uint32_t ref)
{
    if (index != UINT32_MAX)
        view_node(p->bd, p->nodes, index).child[i] = ref;
}

/* The slot of each of a node's nc children (build_child_slots). */
static void child_slots(const build *bd, const range *child, int nc, int slot[8])
{
    box4 box[8];
    uint32_t count[8];
    for (int i = 0; i < nc; i++) {
        box[i] = child[i].geom;
        count[i] = child[i].end - child[i].begin;
    }
    build_child_slots(bd, box, count, nc, slot);
}

/* The children of a node over r: the child with the largest area (median:
 * the most references) is split until there are N or none has more than
 * four references.  `first`, if not NULL, is find_split's split of r.
 * Stage 1 (`parallel`) splits its large ranges with every thread.  The
 * bins of a range split go back to pool (r's among them); the children
 * keep theirs. */
static int split_children(const build *bd, binpool *pool, bins *scratch, sbins *sscratch, const range *r,
                          int median, const split *first, int parallel, range child[8])
{
    int nc = 1;
    child[0] = *r;
    while (nc < bd->width) {
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
        if (parallel && !median && child[pick].end - child[pick].begin >= 2 * RTK_CHUNK_MIN)
            split_parallel(bd, pool, scratch, sscratch, &child[pick], &l, &rr);
        else
            split_range(bd, pool, &child[pick], median, nc == 1 ? first : NULL, &l, &rr);
        pool_put(pool, child[pick].bn);
        share_room(bd->refs, &child[pick], &l, &rr);
        child[pick] = l;
        child[nc++] = rr;
    }
    return nc;
}

/* ---- stage 2: a subtree on one thread ---- */

/* Whether r becomes one leaf: up to four references, or a small range
 * where the SAH says an inner node over its best split would cost more
 * than one leaf of several blocks (one box test, at the price of one block
 * of triangles, as in Embree: an inner node over a handful of triangles
 * would mostly hold empty slots).  Otherwise *first is that best split
 * when it was computed, else its axis is -1.
 *
 * The motion builder's trees (build_motion.c) price a box test at two
 * blocks (bd->node_cost).  Their nodes hold each box at a segment's start
 * and its change (416 bytes 8 wide, 208 four wide: every box twice),
 * interpolated in every test.  At one block, dragon.ply's tree at 2 time
 * steps had 55,269 nodes, at two 28,638 (leaves of more blocks, 3.50
 * triangles a block against 3.44): 48.5 bytes a triangle against 61.6
 * (Embree's 57.0), 176 against 228 at 5 steps (Embree's 195), San
 * Miguel's 47.5 and 172 against 56.9 and 208, builds up to a fifth
 * faster, and the rays traced as fast within this VM's noise (dragon at 5
 * steps: diffuse 0-20% faster over three runs; rtktool bench --only
 * motion, the two builds side by side, AMD EPYC).  Three blocks gave about
 * the same tree as two (26,985 nodes).  Static trees were tried the same
 * way (docs/benchmarks/history.md): smaller, no faster. */
static int leaf_range(part *p, const range *r, uint32_t depth, split *first)
{
    const uint32_t n = r->end - r->begin;
    first->axis = -1;
    if (n <= 4)
        return 1;
    if (n <= 4 * RTK_LEAF_MAX_BLOCKS && depth < RTK_SAH_MEDIAN_DEPTH) {
        *first = find_split(p->bd, r);
        const float area = box_half_area(&r->geom);
        if (first->axis < 0 || (float)((n + 3) / 4) * area <= p->bd->node_cost * area + first->cost) {
            pool_put(&p->pool, r->bn);
            return 1;
        }
    }
    return 0;
}

/* A node or leaf at `depth`: the subtree's depth is at least that. */
static void part_reach(part *p, uint32_t depth)
{
    if (depth > p->depth)
        p->depth = depth;
}

/* The leaf over r at `depth`. */
static uint32_t depth_leaf(part *p, const range *r, uint32_t depth)
{
    part_reach(p, depth);
    return part_leaf(p, r->begin, r->end);
}

/* The inner node over r (not a leaf by leaf_range, which gave `first`) and
 * its subtree.  Its leaf children are placed first, slot by slot, and only
 * then its inner children's subtrees, so the blocks of a node's leaves lie
 * side by side, ahead of its descendants', and the nodes follow in the same
 * depth-first order (the plain recursion strewed a node's leaves among its
 * descendants').  The same tree otherwise.  On rays from random points of
 * the mesh (a scratch driver, rtk avx2 and Embree isa=avx2 in turns) this
 * order alone measured within the noise (+0.5% on average over nine paired
 * runs on the dragon and on San Miguel); with the nodes' offset
 * (build_common.c, node_offset) 4-5% on both, which is the order that was
 * measured and kept. */
static uint32_t build_inner(part *p, const range *r, uint32_t depth, const split *first)
{
    const build *bd = p->bd;
    part_reach(p, depth);
    range child[8];
    const int nc = split_children(bd, &p->pool, NULL, NULL, r, depth >= RTK_SAH_MEDIAN_DEPTH,
                                  first->axis >= 0 ? first : NULL, 0, child);
    const uint32_t index = part_node(p);
    int slot[8] = {0, 1, 2, 3, 4, 5, 6, 7}, in_slot[8];
    child_slots(bd, child, nc, slot);
    write_node(p, index, child, nc, slot);
    for (int i = 0; i < nc; i++)
        in_slot[slot[i]] = i;
    split firsts[8];
    unsigned inner = 0;
    for (int s = 0; s < nc; s++) {
        const int i = in_slot[s];
        if (!leaf_range(p, &child[i], depth + 1, &firsts[i])) {
            inner |= 1u << s;
            continue;
        }
        set_child(p, index, s, depth_leaf(p, &child[i], depth + 1));
    }
    for (; inner; inner &= inner - 1) {
        const int s = __builtin_ctz(inner), i = in_slot[s];
        set_child(p, index, s, build_inner(p, &child[i], depth + 1, &firsts[i]));
    }
    return index;
}

static uint32_t build_node(part *p, const range *r, uint32_t depth)
{
    split first;
    return leaf_range(p, r, depth, &first) ? depth_leaf(p, r, depth) : build_inner(p, r, depth, &first);
}

/* Subtree p, built by the thread whose arena is a.  Its nodes go where
 * there is room for as many as it can have (fewer than its references, the
 * room for spatial splits included: every inner node has two children or
 * more, every leaf a reference), of which only the pages written are ever
 * memory.  That room is in the thread's arena, right behind the nodes of
 * the subtrees it built before (a new chunk when the last has too little
 * left), so the nodes of stage 2 are written on huge pages, a few subtrees
 * to a page, and stage 3 copies them all to their places before the leaves
 * (place_subtree_nodes), then gives the arenas back.  In a reservation of
 * 4 KiB pages per subtree, as before, a medium build of the 10M-triangle
 * mesh took 36,000 page faults for them, of the 49,000 it took in all
 * (perf record -e page-faults): now 12,400 in all; medium builds 3-8%
 * faster on the dragon and San Miguel, about 3% on that mesh, with the
 * same peak memory (docs/benchmarks/notes.md, session 44).  Without
 * an arena or its memory the subtree reserves its own. */
static void build_subtree(part *p, arena *a)
{
    const uint32_t n = p->r.end - p->r.begin;
    const uint32_t bound = range_room_end(&p->r) - p->r.begin + 1;
    const size_t room = (size_t)bound * p->bd->node_size;
    if (a && (!a->base || a->bytes - a->used < room)) { /* a new chunk */
        const size_t bytes = room + RTK_ARENA_HEAD > RTK_ARENA_CHUNK ? room + RTK_ARENA_HEAD : RTK_ARENA_CHUNK;
        char *chunk = build_reserve_huge(p->bd->mem, bytes);
        if (chunk) {
            *(arena_chunk *)chunk = (arena_chunk){a->base, a->bytes};
            *a = (arena){chunk, bytes, RTK_ARENA_HEAD};
        }
    }
    if (a && a->base && a->bytes - a->used >= room) {
        p->nodes = a->base + a->used;
        p->node_cap = bound;
        p->in_arena = 1;
    } else {
        p->nodes = build_reserve(p->bd->mem, room);
        if (p->nodes) {
            p->nodes_mapped = room;
            p->node_cap = bound;
        }
    }
    build_grow((void **)&p->leaves, &p->leaf_cap, n / 3 + 1, sizeof *p->leaves);
    p->root = build_node(p, &p->r, p->depth0);
    if (p->in_arena) /* the next subtree's nodes on the next cache line */
        a->used += ((size_t)p->node_count * p->bd->node_size + 63) & ~(size_t)63;
    pool_release(&p->pool); /* (its root's bins are the top's, which frees them) */
}

/* ---- stage 1: the top nodes, as tasks ---- */

/* A top node: its references, and once split its children, each another
 * top node or a subtree (kid[i], a tnode where bit i of tops is set, else
 * a part). */
typedef struct tnode {
    range r;
    uint32_t depth;
    int nc;
    unsigned tops;
    range child[8];
    int slot[8];
    void *kid[8];
    binpool pool; /* its ranges' bins (its subtrees' roots take some): freed after stage 2 */
} tnode;

/* A worker's scratch for stage 1's splits. */
typedef struct scratch {
    bins *bins;    /* 2 * RTK_CHUNKS_MAX of them */
    sbins *sbins;  /* the same, for spatial splits */
} scratch;

typedef struct top {
    part nodes; /* the top nodes; EXT | k is subtree k */
    part *subtrees;
    uint32_t subtree_count, subtree_cap;
    build serial;     /* the build, without its threads: a task's splits run on its own */
    build_queue queue;
    int queue_ready;
    scratch *scratch; /* one per thread, and the main thread's (all threads) last */
    arena *arenas;    /* one per thread */
} top;

/* Bit 0 of a queued task's key: a top node (else a subtree). */
static uint64_t task_key(const range *r, int is_top)
{
    return (uint64_t)(r->end - r->begin) << 1 | (uint64_t)is_top;
}

static int scratch_get(top *t, scratch *s)
{
    if (!s->bins)
        s->bins = aligned_alloc(_Alignof(bins), 2 * RTK_CHUNKS_MAX * sizeof *s->bins);
    if (t->nodes.bd->spatial && !s->sbins)
        s->sbins = malloc(RTK_CHUNKS_MAX * sizeof *s->sbins);
    return s->bins && (s->sbins || !t->nodes.bd->spatial);
}

/* A task over r at `depth`: a top node to split, or a subtree to build;
 * NULL when out of memory. */
static void *new_task(const build *bd, const range *r, uint32_t depth, int is_top)
{
    if (is_top) {
        tnode *n = malloc(sizeof *n);
        if (n)
            *n = (tnode){.r = *r, .depth = depth};
        return n;
    }
    part *p = malloc(sizeof *p);
    if (p)
        *p = (part){.bd = bd, .r = *r, .depth0 = depth};
    return p;
}

/* Splits top node n into its children (on bd's threads) and queues them:
 * each a top node of its own while it has RTK_TOP_MIN references or more,
 * else a subtree task.  The chunks of a split, and so the split, are the
 * same whichever threads run them. */
static void top_split(top *t, const build *bd, scratch *s, tnode *n)
{
    build_queue *q = &t->queue;
    if (!scratch_get(t, s)) {
        build_queue_fail(q);
        return;
    }
    n->nc = split_children(bd, &n->pool, s->bins, s->sbins, &n->r, n->depth >= RTK_SAH_MEDIAN_DEPTH, NULL, 1, n->child);
    for (int i = 0; i < 8; i++)
        n->slot[i] = i;
    child_slots(bd, n->child, n->nc, n->slot);
    for (int i = 0; i < n->nc; i++) {
        const int is_top = n->child[i].end - n->child[i].begin >= RTK_TOP_MIN;
        void *kid = new_task(t->nodes.bd, &n->child[i], n->depth + 1, is_top);
        if (!kid) {
            build_queue_fail(q);
            continue;
        }
        if (!build_queue_push(q, task_key(&n->child[i], is_top), kid)) { /* (which marks q out of memory) */
            free(kid);
            continue;
        }
        n->kid[i] = kid;
        n->tops |= (unsigned)is_top << i;
    }
}

static void top_task(build_queue *q, uint64_t key, void *item, uint32_t worker)
{
    top *t = q->data;
    /* once the build is told to stop, the tasks left do nothing: a top
     * node stays unsplit, a subtree unbuilt, and the build frees them */
    if (build_stopped(&t->serial))
        return;
    if (key & 1) {
        top_split(t, &t->serial, &t->scratch[worker], item);
    } else {
        part *p = item;
        build_subtree(p, t->arenas ? &t->arenas[worker] : NULL);
        build_report_work(&t->serial, p->r.end - p->r.begin, 0.1, 0.9); /* (a subtree's refs: its share) */
    }
}

/* Subtree p (built) as the next of t's subtrees; frees p. */
static uint32_t add_subtree(top *t, part *p)
{
    if (!p || t->nodes.oom ||
        !build_grow((void **)&t->subtrees, &t->subtree_cap, t->subtree_count + 1, sizeof *t->subtrees)) {
        t->nodes.oom = 1;
        if (p)
            part_free(p);
        free(p);
        return EXT;
    }
    t->subtrees[t->subtree_count] = *p;
    free(p);
    return EXT | t->subtree_count++;
}

/* The top nodes in the order of a depth-first walk (a node before its
 * children, in split order), and the subtrees in the order it meets them:
 * the order of one thread splitting them one after another.  Frees the
 * tnodes. */
static uint32_t top_place(top *t, tnode *n)
{
    part *p = &t->nodes;
    part_reach(p, n->depth);
    const uint32_t index = part_node(p);
    write_node(p, index, n->child, n->nc, n->slot);
    for (int i = 0; i < n->nc; i++) {
        const uint32_t ref = (n->tops >> i & 1) ? top_place(t, n->kid[i]) : add_subtree(t, n->kid[i]);
        set_child(p, index, n->slot[i], ref);
    }
    pool_release(&n->pool);
    free(n);
    return index;
}

/* Stages 1 and 2 of the tree over root: the top nodes split with every
 * thread while fewer of them are left than threads (the root, on two
 * threads), then the rest as tasks, each on one thread, beside the
 * subtrees as they come.  Returns the root's part-local reference. */
static uint32_t top_build(top *t, const build *bd, const range *root)
{
    const uint32_t threads = build_threads(bd);
    const int is_top = root->end - root->begin >= RTK_TOP_MIN;
    void *item = new_task(bd, root, 1, is_top);
    if (!item || !build_queue_push(&t->queue, task_key(root, is_top), item)) {
        free(item);
        t->nodes.oom = 1;
        return EXT;
    }
    for (;;) {
        uint32_t tops = 0;
        for (uint32_t i = 0; i < t->queue.count; i++)
            tops += (uint32_t)(t->queue.heap[i].key & 1);
        if (!tops || tops >= threads)
            break;
        /* the largest task is a top node: those have RTK_TOP_MIN references or more, subtrees fewer */
        top_split(t, bd, &t->scratch[threads], build_queue_pop_top(&t->queue, 1));
    }
    build_queue_run(bd, &t->queue);
    if (t->queue.oom)
        t->nodes.oom = 1;
    return is_top ? top_place(t, item) : add_subtree(t, item);
}

/* ---- stage 3: the final arrays ---- */

/* The leaf block of the (up to) four references from `first` below `end`. */
static void write_block(const build *bd, uint32_t first, uint32_t end, uint64_t index)
{
    uint32_t geom[4], prim[4], count = 0;
    for (uint32_t k = first; k < end && count < 4; k++, count++) {
        geom[count] = ref_geom(&bd->refs[k]);
        prim[count] = ref_prim(&bd->refs[k]);
    }
    build_write_block(bd, index, geom, prim, count, NULL, NULL);
}

/* Copies part p's nodes to the final array at p->node_base, turning its
 * references into final ones (and setting the nodes' prefetch[]): ext[k *
 * stride] is the final reference of external child k. */
static void place_nodes(const part *p, const uint32_t *ext, size_t stride)
{
    const build *bd = p->bd;
    if (!p->node_count)
        return;
    char *to = (char *)bd->nodes + p->node_base * bd->node_size;
    memcpy(to, p->nodes, (size_t)p->node_count * bd->node_size);
    for (uint32_t i = 0; i < p->node_count; i++) {
        const node_view v = view_node(bd, to, i);
        const char *node = to + (size_t)i * bd->node_size;
        for (int c = 0; c < bd->width; c++) {
            const uint32_t ref = v.child[c];
            if (ref != RTK_BVH4_EMPTY)
                v.child[c] = ref & EXT ? ext[(size_t)(ref & ~EXT) * stride] : (uint32_t)(p->node_base + ref);
            v.prefetch[c] = build_prefetch(bd, node, v.child[c]);
        }
    }
}

/* A subtree's final root reference (after place_subtree_nodes). */
static uint32_t subtree_root(const part *p)
{
    return p->root & EXT ? p->leaves[p->root & ~EXT].placed : (uint32_t)(p->node_base + p->root);
}

/* Prefetches the triangles of a leaf for write_block, which otherwise
 * waits on the application's arrays (perf: a quarter of its time on the
 * load of the indices): their indices, or (once those have come) their
 * vertices.  place_subtree asks for the indices eight leaves ahead, the
 * vertices four, and before both for the leaf's references themselves
 * (prefetch_refs).  An earlier try with the indices alone made no
 * difference. */
static void prefetch_leaf(const build *bd, const leafrange *l, int vertices)
{
    for (uint32_t k = l->begin; k < l->end; k++) {
        const rtk_build_geometry *g = &bd->in->geometries[ref_geom(&bd->refs[k])];
        const uint32_t *tri = triangle_at(g, ref_prim(&bd->refs[k]));
        if (!vertices) {
            __builtin_prefetch(tri);
            continue;
        }
        for (int j = 0; j < 3; j++)
            __builtin_prefetch(vertex_at(g, tri[j]));
    }
}

/* Prefetches the references of a leaf, sixteen leaves ahead of the one
 * written: written in stage 2, they have mostly left the caches by the time
 * their subtree is placed, and prefetch_leaf's loads of their ids waited on
 * memory (perf: half of place_subtree's own samples on that load, the
 * hardware's prefetcher not keeping up with a stream read between the
 * gathers of indices and vertices).  With it and the indices and vertices
 * asked for twice as far ahead as before (4 and 2 leaves), San Miguel's
 * stage 3 took 74 -> 57 million TSC cycles on one thread, 42 -> 33 on two
 * (a scratch timer around it, 8 builds per run, three rounds in turns). */
static void prefetch_refs(const build *bd, const leafrange *l)
{
    const char *at = (const char *)((uintptr_t)&bd->refs[l->begin] & ~(uintptr_t)63);
    for (const char *end = (const char *)&bd->refs[l->end]; at < end; at += 64)
        __builtin_prefetch(at);
}

/* Stage 3, first half, subtree i: its leaves' final references, and its
 * nodes copied to their place with those; its own node array then goes
 * (an arena's, with the arena after this pass). */
static void place_subtree_nodes(void *data, uint32_t i)
{
    part *p = (part *)data + i;
    uint64_t block = p->block_base;
    for (uint32_t k = 0; k < p->leaf_count; k++) {
        leafrange *l = &p->leaves[k];
        const uint32_t blocks = (l->end - l->begin + 3) / 4;
        l->placed = rtk_leaf_ref((uint32_t)block, blocks);
        block += blocks;
    }
    place_nodes(p, p->leaves ? &p->leaves[0].placed : NULL, sizeof *p->leaves / sizeof(uint32_t));
    part_free_nodes(p);
}

/* Stage 3, second half, subtree i: its leaf blocks. */
static void place_subtree_leaves(void *data, uint32_t i)
{
    part *p = (part *)data + i;
    uint64_t block = p->block_base;
    for (uint32_t k = 0; k < p->leaf_count; k++) {
        const leafrange *l = &p->leaves[k];
        if (k + 16 < p->leaf_count)
            prefetch_refs(p->bd, &p->leaves[k + 16]);
        if (k + 8 < p->leaf_count)
            prefetch_leaf(p->bd, &p->leaves[k + 8], 0);
        if (k + 4 < p->leaf_count)
            prefetch_leaf(p->bd, &p->leaves[k + 4], 1);
        const uint32_t blocks = (l->end - l->begin + 3) / 4;
        for (uint32_t b = 0; b < blocks; b++)
            write_block(p->bd, l->begin + 4 * b, l->end, block + b);
        block += blocks;
    }
}

static void place_subtree(void *data, uint32_t i)
{
    place_subtree_nodes(data, i);
    place_subtree_leaves(data, i);
}

typedef struct refspan {
    size_t lo, hi;                /* bytes into the references */
    size_t first_page, end_page; /* the huge pages they lie on */
} refspan;

/* Where subtree p's references (and the room behind them) lie. */
static refspan subtree_refs(const part *p)
{
    const size_t lo = (size_t)p->r.begin * sizeof *p->bd->refs, hi = (size_t)range_room_end(&p->r) * sizeof *p->bd->refs;
    return (refspan){.lo = lo, .hi = hi, .first_page = lo / RTK_HUGE_PAGE,
                     .end_page = hi > lo ? (hi - 1) / RTK_HUGE_PAGE + 1 : lo / RTK_HUGE_PAGE};
}

/* Gives back the pages of references only subtree p used, now placed.  On
 * huge pages, one given back in part would be split by the kernel (which
 * made stage 3 of San Miguel take 35 to 170 ms on one thread, rtktool
 * build): each huge page goes back whole, when the last subtree over it
 * has been placed. */
static void release_refs(const part *p)
{
    char *base = (char *)p->bd->refs;
    const refspan span = subtree_refs(p);
    if (!p->pages) {
        build_release_pages(base + span.lo, span.hi - span.lo);
        return;
    }
    for (size_t k = span.first_page; k < span.end_page; k++)
        if (atomic_fetch_sub_explicit(&p->pages->users[k], 1, memory_order_acq_rel) == 1) {
            const size_t at = k * RTK_HUGE_PAGE;
            build_release_pages(base + at, p->pages->bytes - at < RTK_HUGE_PAGE ? p->pages->bytes - at : RTK_HUGE_PAGE);
        }
}

/* Counts each huge page's subtrees into pages (refs reserved with
 * build_reserve_huge, `bytes` of them), for release_refs; with too few
 * references for huge pages, or no memory for the counts, the pages go
 * back per subtree. */
static void count_page_users(top *t, refpages *pages, size_t bytes)
{
    pages->users = NULL;
    pages->bytes = bytes;
    if (bytes < RTK_HUGE_PAGE)
        return;
    const size_t count = (bytes + RTK_HUGE_PAGE - 1) / RTK_HUGE_PAGE;
    pages->users = malloc(count * sizeof *pages->users);
    if (!pages->users)
        return;
    for (size_t k = 0; k < count; k++)
        atomic_init(&pages->users[k], 0);
    for (uint32_t i = 0; i < t->subtree_count; i++) {
        part *p = &t->subtrees[i];
        const refspan span = subtree_refs(p);
        for (size_t k = span.first_page; k < span.end_page; k++)
            atomic_fetch_add_explicit(&pages->users[k], 1, memory_order_relaxed);
        p->pages = pages;
    }
}

/* Gives back the arenas' memory (once stage 3 has copied their nodes). */
static void arenas_free(top *t)
{
    for (uint32_t w = 0; t->arenas && w < build_threads(t->nodes.bd); w++) {
        arena *a = &t->arenas[w];
        while (a->base) {
            const arena_chunk c = *(const arena_chunk *)a->base;
            build_unreserve(t->nodes.bd->mem, a->base, a->bytes);
            a->base = c.prev;
            a->bytes = c.bytes;
        }
        a->used = 0;
    }
}

/* Stage 3 of a build, one subtree's leaves (its nodes were placed first,
 * all subtrees' in one pass, and the arenas given back): its leaf blocks
 * written, then its references' pages given back.  The final arrays grow
 * as these shrink, so the
 * peak of a build stays near the references and the tree (dragon, medium:
 * 108 bytes per triangle when both were held to the end, against Embree's
 * 104).  The subtrees are placed in the order of their references (not
 * largest first as they were built), so that the huge pages of references
 * are given back as the placing goes: San Miguel's peak 108.5 -> 73.2
 * bytes per triangle, Embree's 99.5 (rtktool bench --only build). */
static void place_and_release(void *data, uint32_t i)
{
    place_subtree_leaves(data, i);
    release_refs((part *)data + i);
}

/* ---- the references ---- */

typedef struct refgen {
    const build *bd;
    const uint64_t *geom_first; /* global index of each geometry's first triangle; [count] = total */
    uint64_t total;
    uint32_t chunks;
    uint32_t *kept;  /* per chunk: references written from the chunk's start */
    build_counts *counts; /* what it left out */
    range *bounds;
} refgen;

/* Chunk k: triangles [k, k + 1) * RTK_REF_CHUNK of the concatenated
 * geometries; the hittable ones become references from the chunk's first
 * slot on.  Triangles with a non-finite vertex or no area cannot be hit and
 * are left out. */
static void make_refs(void *data, uint32_t k)
{
    refgen *g = data;
    const rtk_build_input *in = g->bd->in;
    const uint64_t begin = (uint64_t)k * RTK_REF_CHUNK;
    const uint64_t end = begin + RTK_REF_CHUNK < g->total ? begin + RTK_REF_CHUNK : g->total;
    uint32_t gi = build_geometry_of(g->geom_first, in->geometry_count, begin);
    range bounds; /* on the stack: chunks' entries in g->bounds share cache lines */
    range_init(&bounds, 0, 0);
    primref *out = g->bd->refs + begin;
    uint32_t n = 0;
    build_counts counts = {0, 0, 0};
    for (uint64_t i = begin; i < end; i++) {
        while (i >= g->geom_first[gi + 1])
            gi++;
        const size_t prim = (size_t)(i - g->geom_first[gi]);
        vfloat4 p[3];
        if (!build_hittable(&in->geometries[gi], prim, p, &counts))
            continue;
        primref *ref = &out[n++];
        const vfloat4 blo = vf4_min(vf4_min(p[0], p[1]), p[2]), bhi = vf4_max(vf4_max(p[0], p[1]), p[2]);
        range_add(&bounds, blo, bhi);
        vf4_store(ref->lo, blo);
        vf4_store(ref->hi, bhi);
        ref->lo[3] = rtk_bits_float(gi);
        ref->hi[3] = rtk_bits_float((uint32_t)prim);
    }
    g->bounds[k] = bounds;
    g->kept[k] = n;
    g->counts[k] = counts;
}

/* ---- the builder ---- */

static void free_parts(top *t)
{
    part_free(&t->nodes);
    for (uint32_t i = 0; i < t->subtree_count; i++)
        part_free(&t->subtrees[i]);
    free(t->subtrees);
    if (t->scratch)
        for (uint32_t i = 0; i <= build_threads(t->nodes.bd); i++) {
            free(t->scratch[i].bins);
            free(t->scratch[i].sbins);
        }
    free(t->scratch);
    arenas_free(t);
    free(t->arenas);
    if (t->queue_ready)
        build_queue_free(&t->queue);
}

static int build_sah(const rtk_build_input *in, rtk_build_output *out, int spatial, float node_cost)
{
    uint64_t total;
    build bd;
    int rc = build_begin(&bd, in, out, &total);
    if (rc)
        return rc;
    bd.node_cost = node_cost;
    build_progress progress;
    build_progress_init(&bd, &progress, total);
    /* Room for the references spatial splits add, while every leaf block
     * (at least one reference each) stays addressable. */
    uint64_t room = spatial ? total / RTK_SPATIAL_ROOM_DIV : 0;
    if (total + room >= RTK_LEAF_INDEX_LIMIT)
        room = RTK_LEAF_INDEX_LIMIT - 1 - total;
    bd.spatial = room > 0;
    const size_t ref_bytes = (total + room ? total + room : 1) * sizeof *bd.refs;
    bd.refs = build_reserve_huge(bd.mem, ref_bytes);
    refgen g = {.bd = &bd, .total = total, .chunks = (uint32_t)((total + RTK_REF_CHUNK - 1) / RTK_REF_CHUNK)};
    const size_t nc = g.chunks ? g.chunks : 1;
    uint64_t *geom_first = build_geom_first(in);
    g.geom_first = geom_first;
    g.kept = malloc(nc * sizeof *g.kept);
    g.counts = malloc(nc * sizeof *g.counts);
    g.bounds = malloc(nc * sizeof *g.bounds);
    refpages pages = {0};
    top t = {.nodes = {.bd = &bd}, .scratch = calloc(build_threads(&bd) + 1, sizeof *t.scratch)};
    t.queue_ready = build_queue_init(&t.queue, top_task, &t);
    if (!bd.refs || !geom_first || !g.kept || !g.counts || !g.bounds || !t.scratch ||
        !t.queue_ready) {
        rc = RTK_ERROR_OUT_OF_MEMORY;
        build_set_message(out, "out of memory for the build's primitive references");
        goto done;
    }

    /* The references, in input order: each chunk's kept ones are moved
     * down behind the previous chunk's. */
    run_parallel(&bd, g.chunks, make_refs, &g);
    range root;
    range_init(&root, 0, 0);
    uint32_t n = 0;
    build_counts counts = {0, 0, 0};
    for (uint32_t k = 0; k < g.chunks; k++) {
        const uint64_t from = (uint64_t)k * RTK_REF_CHUNK;
        if (n != from && g.kept[k])
            memmove(bd.refs + n, bd.refs + from, (size_t)g.kept[k] * sizeof *bd.refs);
        n += g.kept[k];
        build_counts_add(&counts, &g.counts[k]);
        range_merge(&root, &g.bounds[k]);
    }
    root.end = n;
    if (build_report(&bd, 0.1)) {
        rc = RTK_ERROR_CANCELLED;
        build_set_message(out, "cancelled by the progress callback");
        goto done;
    }
    /* the room, from the triangles kept */
    root.ext = n + (uint32_t)(room * n / (total ? total : 1));
    bd.spatial_overlap = RTK_SPATIAL_ALPHA * box_half_area(&root.geom);

    /* The arenas (see build_subtree; without them every subtree reserves
     * its own node array). */
    t.arenas = calloc(build_threads(&bd), sizeof *t.arenas);

    /* Stages 1 and 2. */
    uint32_t root_local = RTK_BVH4_EMPTY;
    t.serial = bd;
    t.serial.tasks = NULL;
    if (n)
        root_local = top_build(&t, &bd, &root);
    if (build_stopped(&bd)) {
        rc = RTK_ERROR_CANCELLED;
        build_set_message(out, "cancelled by the progress callback");
        goto done;
    }
    if (t.nodes.oom) {
        rc = RTK_ERROR_OUT_OF_MEMORY;
        build_set_message(out, "out of memory for the BVH");
        goto done;
    }

    /* Places: the top nodes, then the subtrees in the order stage 1 found them. */
    uint64_t nodes = t.nodes.node_count, blocks = 0, refs = 0;
    uint32_t depth = t.nodes.depth;
    int oom = 0;
    for (uint32_t i = 0; i < t.subtree_count; i++) {
        part *p = &t.subtrees[i];
        p->node_base = nodes;
        p->block_base = blocks;
        nodes += p->node_count;
        blocks += p->blocks;
        refs += p->refs;
        depth = p->depth > depth ? p->depth : depth;
        oom |= p->oom;
    }
    /* (the last point where the build may stop, or fail for memory, with
     * nothing written into a recycled tree: roots is allocated first) */
    uint32_t *roots = oom ? NULL : malloc((t.subtree_count ? t.subtree_count : 1) * sizeof *roots);
    if (roots && build_report(&bd, 0.95)) {
        free(roots);
        rc = RTK_ERROR_CANCELLED;
        build_set_message(out, "cancelled by the progress callback");
        goto done;
    }
    struct rtk_accel *accel = roots ? build_accel_alloc(&bd, nodes, blocks) : NULL;
    if (!accel) {
        free(roots);
        rc = RTK_ERROR_OUT_OF_MEMORY;
        build_set_message(out, "out of memory for the BVH");
        goto done;
    }
    accel->leaves_first = 1; /* (build_inner) */
    count_page_users(&t, &pages, ref_bytes);
    run_parallel(&bd, t.subtree_count, place_subtree_nodes, t.subtrees);
    arenas_free(&t);
    run_parallel(&bd, t.subtree_count, place_and_release, t.subtrees);
    for (uint32_t i = 0; i < t.subtree_count; i++)
        roots[i] = subtree_root(&t.subtrees[i]);
    place_nodes(&t.nodes, roots, 1);
    const uint32_t root_ref = root_local == RTK_BVH4_EMPTY ? RTK_BVH4_EMPTY
                              : root_local & EXT            ? roots[root_local & ~EXT]
                                                            : root_local;
    free(roots);
    build_accel_finish(&bd, accel, root_ref, n, depth, &root.geom, out);
    if (out->struct_size >= offsetof(rtk_build_output, refs) + sizeof out->refs)
        out->refs = refs;
    build_counts_store(out, &counts);
    rc = RTK_OK;
done:
    free_parts(&t);
    free(pages.users);
    free(geom_first);
    free(g.kept);
    free(g.counts);
    free(g.bounds);
    build_unreserve(bd.mem, bd.refs, ref_bytes);
    return rc;
}

/* ---- a tree given as data (rtk_bvh) ----
 * Node i of the tree becomes node i and leaf j the j-th run of blocks, through
 * the same writers as a build, so a tree exported from an accel imports to
 * the same bytes and the same statistics. */

static uint32_t tree_depth(const rtk_bvh *t, uint32_t ref, uint32_t depth)
{
    if (ref & RTK_BVH_LEAF_BIT)
        return depth;
    uint32_t deepest = depth;
    for (uint32_t c = 0; c < t->width; c++) {
        const uint32_t child = t->children[(uint64_t)ref * t->width + c];
        if (child != RTK_BVH_EMPTY) {
            const uint32_t d = tree_depth(t, child, depth + 1);
            deepest = d > deepest ? d : deepest;
        }
    }
    return deepest;
}

static box4 slot_box(const rtk_bvh *t, uint64_t slot)
{
    const float *lo = t->child_lower + 3 * slot, *hi = t->child_upper + 3 * slot;
    return (box4){vf4_set(lo[0], lo[1], lo[2], 0.0f), vf4_set(hi[0], hi[1], hi[2], 0.0f)};
}

int RTK_SYM(rtk_bvh_import)(const rtk_build_input *in, const rtk_bvh *t, rtk_build_output *out)
{
    build bd;
    int rc = build_layout_setup(&bd, in, out);
    if (rc)
        return rc;
    bd.tasks = NULL;
    if (t->width != (uint32_t)bd.width) {
        snprintf(out->message, sizeof out->message, "the tree has %u-wide nodes, the layout %d-wide ones", t->width,
                 bd.width);
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
    if (blocks >= RTK_LEAF_INDEX_LIMIT || t->node_count >= RTK_BVH4_LEAF_BIT || t->leaf_count >= EXT) {
        build_set_message(out, "too many leaf blocks or nodes for the layout");
        return RTK_ERROR_INVALID_ARGUMENT;
    }

    /* The triangles as primitive references in tree order: the leaf
     * writers read them from there.  geom_id -> index in the input. */
    uint32_t max_id;
    uint32_t *index_of = build_geometry_index(in, &max_id);
    const size_t ref_bytes = (t->prim_count ? t->prim_count : 1) * sizeof *bd.refs;
    bd.refs = build_reserve_huge(bd.mem, ref_bytes);
    part p = {.bd = &bd, .node_count = (uint32_t)t->node_count, .leaf_count = (uint32_t)t->leaf_count};
    p.nodes = malloc((t->node_count ? t->node_count : 1) * bd.node_size);
    p.leaves = malloc((t->leaf_count ? t->leaf_count : 1) * sizeof *p.leaves);
    struct rtk_accel *accel =
        index_of && bd.refs && p.nodes && p.leaves ? build_accel_alloc(&bd, t->node_count, blocks) : NULL;
    if (!accel) {
        free(index_of);
        part_free(&p);
        build_unreserve(bd.mem, bd.refs, ref_bytes);
        build_set_message(out, "out of memory for the BVH");
        return RTK_ERROR_OUT_OF_MEMORY;
    }
    for (uint64_t k = 0; k < t->prim_count; k++) {
        bd.refs[k].lo[3] = rtk_bits_float(index_of[t->prims[k].geom_id]);
        bd.refs[k].hi[3] = rtk_bits_float(t->prims[k].prim_id);
    }
    free(index_of);

    /* The nodes with their used slots first, as a build writes them. */
    for (uint32_t i = 0; i < p.node_count; i++) {
        range child[8];
        memset(child, 0, sizeof child);
        uint32_t refs[8];
        int nc = 0;
        for (uint32_t c = 0; c < t->width; c++) {
            const uint64_t slot = (uint64_t)i * t->width + c;
            const uint32_t ref = t->children[slot];
            if (ref == RTK_BVH_EMPTY)
                continue;
            child[nc].geom = slot_box(t, slot);
            refs[nc++] = ref & RTK_BVH_LEAF_BIT ? EXT | (ref & ~RTK_BVH_LEAF_BIT) : ref;
        }
        static const int keep[8] = {0, 1, 2, 3, 4, 5, 6, 7}; /* the tree's own order */
        write_node(&p, i, child, nc, keep);
        for (int c = 0; c < nc; c++)
            set_child(&p, i, c, refs[c]);
    }
    for (uint32_t j = 0; j < p.leaf_count; j++)
        p.leaves[j] = (leafrange){(uint32_t)t->leaf_first[j], (uint32_t)t->leaf_first[j + 1], 0};
    place_subtree(&p, 0);

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
            const rtk_build_geometry *g = &in->geometries[ref_geom(&bd.refs[k])];
            const uint32_t *tri = triangle_at(g, ref_prim(&bd.refs[k]));
            for (int v = 0; v < 3; v++) {
                const float *q = vertex_at(g, tri[v]);
                const vfloat4 x = vf4_set(q[0], q[1], q[2], 0.0f);
                box_grow(&bounds, x, x);
            }
        }
    }
    const uint32_t root = t->root == RTK_BVH_EMPTY        ? RTK_BVH4_EMPTY
                          : t->root & RTK_BVH_LEAF_BIT ? p.leaves[t->root & ~RTK_BVH_LEAF_BIT].placed
                                                       : t->root;
    const uint32_t depth = t->root == RTK_BVH_EMPTY ? 0 : tree_depth(t, t->root, 1);
    part_free(&p);
    build_unreserve(bd.mem, bd.refs, ref_bytes);
    build_accel_finish(&bd, accel, root, t->prim_count, depth, &bounds, out);
    return RTK_OK;
}


int RTK_SYM(rtk_build_sah)(const rtk_build_input *in, rtk_build_output *out)
{
    return build_sah(in, out, 0, 1.0f);
}

int RTK_SYM(rtk_build_sah_spatial)(const rtk_build_input *in, rtk_build_output *out)
{
    return build_sah(in, out, 1, 1.0f);
}

int RTK_SYM(rtk_build_sah_motion)(const rtk_build_input *in, rtk_build_output *out)
{
    return build_sah(in, out, 0, 2.0f);
}
