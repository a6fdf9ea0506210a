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
 *  1. Nodes over RTK_TOP_MIN or more triangles are built one at a time by
 *     all threads: the references are binned and partitioned in chunks.
 *  2. Every child under that size is a subtree task, built by one thread
 *     into arrays of its own (nodes with local references, leaves as
 *     ranges of references).
 *  3. Once the sizes are known, each subtree is copied to its place in the
 *     final arrays (the top nodes first, then the subtrees in order) and its
 *     leaf blocks written, again in parallel.
 * The chunks, the stage a node falls in and the place of every subtree depend
 * on the triangle counts alone, and chunk results are combined in chunk
 * order, so the tree is the same, byte for byte, on any number of threads.
 *
 * Past depth RTK_SAH_MEDIAN_DEPTH the builder falls back to median splits,
 * so no tree is deeper than RTK_BVH4_MAX_DEPTH whatever the input.
 */
#include <math.h>
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
 * at most RTK_CHUNKS_MAX of them per split. */
#define RTK_TOP_MIN 16384u
#define RTK_CHUNK_MIN 4096u
#define RTK_CHUNKS_MAX 64u
/* Triangles per task when the references are made. */
#define RTK_REF_CHUNK 16384u

typedef struct range {
    uint32_t begin, end;
    box4 geom; /* bounds of the triangles */
    box4 cent; /* bounds of the centroids */
} range;

/* References inside a part's own node array: an inner node of the same part
 * (its index there), or one of the part's external children (EXT | k): for
 * a subtree its k-th leaf, for the top nodes the k-th subtree. */
#define EXT 0x80000000u

typedef struct leafrange {
    uint32_t begin, end; /* references; stage 3 overwrites begin with the final leaf reference */
} leafrange;

/* A part of the tree in arrays of its own: the top nodes, or one subtree. */
typedef struct part {
    const build *bd;
    range r;         /* a subtree's references */
    uint32_t depth0; /* the depth of its root */
    char *nodes;     /* node_count nodes of bd->node_size bytes */
    uint32_t node_count, node_cap;
    leafrange *leaves;
    uint32_t leaf_count, leaf_cap;
    uint64_t blocks;
    uint32_t depth; /* the deepest level reached */
    uint32_t root;  /* part-local reference */
    int oom;
    uint64_t node_base, block_base; /* where stage 3 puts it */
} part;

/* Centroid as lo/2 + hi/2, which cannot overflow for finite boxes.  Lane 3
 * (the ids, often denormal as floats) is cleared first: arithmetic on
 * denormals costs a microcode assist per instruction on x86. */
static inline vfloat4 centroid(vfloat4 lo, vfloat4 hi)
{
    const vbool4 xyz = vb4_from_bits(7);
    const vfloat4 half = vf4_set1(0.5f);
    return vf4_madd(vf4_keep(xyz, lo), half, vf4_mul(vf4_keep(xyz, hi), half));
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

/* Fewer bins for small ranges, as Embree counts them (4 + n / 20): clearing
 * and sweeping 32 bins would cost more than binning the triangles.  Measured
 * on dragon against n + 4 (rtktool build, 1 thread): build 292 -> 269 ms,
 * SAH cost 16.19 -> 16.24, memory 64.3 -> 67.0 bytes per triangle. */
static inline int bin_count(uint32_t n)
{
    uint32_t b = 4 + n / 20;
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


/* ---- splitting a range ---- */

/* The bins of one chunk of references. */
typedef struct bins {
    box4 box[3][RTK_SAH_BINS];
    _Alignas(16) int32_t counts[RTK_SAH_BINS][4];
} bins;

static void bins_clear(bins *b, int nb)
{
    for (int a = 0; a < 3; a++)
        for (int k = 0; k < nb; k++)
            b->box[a][k] = box_empty();
    memset(b->counts, 0, sizeof b->counts);
}

static void bins_merge(bins *into, const bins *b, int nb)
{
    for (int a = 0; a < 3; a++)
        for (int k = 0; k < nb; k++)
            box_grow(&into->box[a][k], b->box[a][k].lo, b->box[a][k].hi);
    for (int k = 0; k < nb; k++)
        vi4_store(into->counts[k], vi4_add(vi4_load(into->counts[k]), vi4_load(b->counts[k])));
}

/* The bin mapping of a range; 0 when no axis can be split (all centroids
 * coincide). */
static int make_binmap(const range *r, int nb, binmap *map)
{
    _Alignas(16) float ext[4], scale[4] = {0, 0, 0, 0};
    vf4_store(ext, vf4_sub(r->cent.hi, r->cent.lo));
    int splittable = 0;
    for (int a = 0; a < 3; a++)
        if (ext[a] > 0.0f && ext[a] <= FLT_MAX) {
            scale[a] = (float)nb * 0.99999f / ext[a];
            splittable = 1;
        }
    *map = (binmap){.cmin = r->cent.lo, .scale = vf4_load(scale), .top = vf4_set1((float)(nb - 1))};
    return splittable;
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
        vint4 k0 = bin_of(map, centroid(lo0, hi0));
        vint4 k1 = bin_of(map, centroid(lo1, hi1));
        bin_add(b->box, b->counts, k0, lo0, hi0);
        bin_add(odd->box, odd->counts, k1, lo1, hi1);
    }
    if (i < end) {
        vfloat4 lo0 = vf4_load(refs[i].lo), hi0 = vf4_load(refs[i].hi);
        bin_add(b->box, b->counts, bin_of(map, centroid(lo0, hi0)), lo0, hi0);
    }
    if (odd != b)
        bins_merge(b, odd, nb);
}

/* The best split of n references from their bins: the three axes at once in
 * lanes 0..2.  right_cost[k] is the cost of bins [k, nb) as one child. */
static split sweep(const bins *b, int nb, uint32_t n, const binmap *map)
{
    split best = {.axis = -1};
    vfloat4 right_cost[RTK_SAH_BINS];
    box4 acc[3] = {box_empty(), box_empty(), box_empty()};
    vint4 cnt = vi4_set1(0);
    for (int k = nb - 1; k > 0; k--) {
        for (int a = 0; a < 3; a++)
            box_grow(&acc[a], b->box[a][k].lo, b->box[a][k].hi);
        cnt = vi4_add(cnt, vi4_load(b->counts[k]));
        right_cost[k] = vf4_mul(half_areas3(acc), block_count(cnt));
    }
    const vint4 zero = vi4_set1(0), all = vi4_set1((int32_t)n);
    const vbool4 usable = vf4_gt(map->scale, vf4_set1(0.0f)); /* lane 3: scale 0 */
    vfloat4 best_cost = vf4_set1(INFINITY);
    vint4 best_pos = zero;
    acc[0] = acc[1] = acc[2] = box_empty();
    cnt = zero;
    for (int k = 1; k < nb; k++) {
        for (int a = 0; a < 3; a++)
            box_grow(&acc[a], b->box[a][k - 1].lo, b->box[a][k - 1].hi);
        cnt = vi4_add(cnt, vi4_load(b->counts[k - 1]));
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
    best.map = *map;
    return best;
}

static split find_split(const primref *refs, const range *r)
{
    const uint32_t n = r->end - r->begin;
    const int nb = bin_count(n);
    binmap map;
    if (!make_binmap(r, nb, &map))
        return (split){.axis = -1};
    bins b;
    bins_clear(&b, nb);
    bin_refs(refs, r->begin, r->end, &map, &b, nb);
    return sweep(&b, nb, n, &map);
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

/* Hoare partition of [begin, end) by split s: a reference goes left when
 * its bin on the split axis is below the split position.  Returns the first
 * reference of the right side; left and right get the two sides' bounds
 * (their begin and end are the caller's to set). */
static uint32_t partition(primref *refs, uint32_t begin, uint32_t end, const split *s, range *left, range *right)
{
    const vint4 pos = vi4_set1(s->pos);
    const int bit = 1 << s->axis;
    uint32_t i = begin, j = end;
    range_init(left, 0, 0);
    range_init(right, 0, 0);
    vfloat4 lo_i, hi_i, lo_j, hi_j;
    for (;;) {
        for (; i < j; i++) {
            lo_i = vf4_load(refs[i].lo);
            hi_i = vf4_load(refs[i].hi);
            if (!(vb4_mask(vi4_lt(bin_of(&s->map, centroid(lo_i, hi_i)), pos)) & bit))
                break;
            range_add(left, lo_i, hi_i);
        }
        for (; i < j; j--) {
            lo_j = vf4_load(refs[j - 1].lo);
            hi_j = vf4_load(refs[j - 1].hi);
            if (vb4_mask(vi4_lt(bin_of(&s->map, centroid(lo_j, hi_j)), pos)) & bit)
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
    return i;
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

/* Splits r into two non-empty halves on this thread, along *given if not
 * NULL (a split find_split made for r), else along the best one (median:
 * halves). */
static void split_range(primref *refs, const range *r, int median, const split *given, range *left, range *right)
{
    split s = {.axis = -1};
    if (given)
        s = *given;
    else if (!median)
        s = find_split(refs, r);
    if (s.axis < 0) {
        split_middle(refs, r, left, right);
        return;
    }
    const uint32_t mid = partition(refs, r->begin, r->end, &s, left, right);
    left->begin = r->begin;
    left->end = mid;
    right->begin = mid;
    right->end = r->end;
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
    bins *bins;                  /* one per chunk */
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
    const uint32_t n = p->r->end - p->r->begin;
    return p->r->begin + (uint32_t)((uint64_t)n * k / p->chunks);
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
    p->mid[k] = partition(p->refs, chunk_begin(p, k), chunk_begin(p, k + 1), &p->s, &left, &right);
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

/* As split_range without `given`, on every thread: bins per chunk, merged
 * in chunk order; a Hoare partition per chunk; then the rights left of the
 * split point and the lefts right of it swapped pairwise, in order.  The
 * result depends on the chunks alone, which depend on the size alone. */
static void split_parallel(const build *bd, bins *scratch, const range *r, range *left, range *right)
{
    const uint32_t n = r->end - r->begin;
    psplit *p = malloc(sizeof *p);
    if (!p) {
        /* the same split, on this thread */
        split_range(bd->refs, r, 0, NULL, left, right);
        return;
    }
    p->refs = bd->refs;
    p->r = r;
    p->chunks = n / RTK_CHUNK_MIN;
    p->chunks = p->chunks > RTK_CHUNKS_MAX ? RTK_CHUNKS_MAX : p->chunks < 1 ? 1 : p->chunks;
    p->nb = bin_count(n);
    p->bins = scratch;
    if (!make_binmap(r, p->nb, &p->map)) {
        free(p);
        split_middle(bd->refs, r, left, right);
        return;
    }
    run_parallel(bd, p->chunks, psplit_bin, p);
    for (uint32_t k = 1; k < p->chunks; k++)
        bins_merge(&p->bins[0], &p->bins[k], p->nb);
    p->s = sweep(&p->bins[0], p->nb, n, &p->map);
    if (p->s.axis < 0) {
        free(p);
        split_middle(bd->refs, r, left, right);
        return;
    }
    run_parallel(bd, p->chunks, psplit_partition, p);

    range_init(left, 0, 0);
    range_init(right, 0, 0);
    uint32_t split_at = r->begin;
    for (uint32_t k = 0; k < p->chunks; k++) {
        range_merge(left, &p->left[k]);
        range_merge(right, &p->right[k]);
        split_at += p->mid[k] - chunk_begin(p, k);
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
    free(p);
}

/* ---- a part's own arrays ---- */

/* A new node of part p; UINT32_MAX (and p->oom) when out of memory. */
static uint32_t part_node(part *p)
{
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
    p->leaves[p->leaf_count] = (leafrange){begin, end};
    p->blocks += (end - begin + 3) / 4;
    return EXT | p->leaf_count++;
}

static void part_free(part *p)
{
    free(p->nodes);
    free(p->leaves);
    p->nodes = NULL;
    p->leaves = NULL;
}

/* Writes node `index` of part p with the boxes of its nc children; empty
 * slots get inverted boxes and RTK_BVH4_EMPTY.  The references are set by
 * set_child. */
static void write_node(part *p, uint32_t index, const range *child, int nc)
{
    if (index == UINT32_MAX)
        return;
    box4 box[8];
    for (int i = 0; i < nc; i++)
        box[i] = child[i].geom;
    build_store_node(p->bd, p->nodes, index, box, NULL, nc);
}

static void set_child(part *p, uint32_t index, int i, uint32_t ref)
{
    if (index != UINT32_MAX)
        view_node(p->bd, p->nodes, index).child[i] = ref;
}

/* The children of a node over r: the child with the largest area (median:
 * the most references) is split until there are N or none has more than
 * four references.  `first`, if not NULL, is find_split's split of r.
 * Stage 1 (`parallel`) splits its large ranges with every thread. */
static int split_children(const build *bd, bins *scratch, const range *r, int median, const split *first,
                          int parallel, range child[8])
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
            split_parallel(bd, scratch, &child[pick], &l, &rr);
        else
            split_range(bd->refs, &child[pick], median, nc == 1 ? first : NULL, &l, &rr);
        child[pick] = l;
        child[nc++] = rr;
    }
    return nc;
}

/* ---- stage 2: a subtree on one thread ---- */

static uint32_t build_node(part *p, const range *r, uint32_t depth)
{
    const build *bd = p->bd;
    if (depth > p->depth)
        p->depth = depth;
    const uint32_t n = r->end - r->begin;
    if (n <= 4)
        return part_leaf(p, r->begin, r->end);

    const int median = depth >= RTK_SAH_MEDIAN_DEPTH;
    /* A small range becomes one leaf of several blocks where the SAH says
     * an inner node over its best split would cost more (one box test, at
     * the price of one block of triangles, as in Embree): an inner node
     * over a handful of triangles would mostly hold empty slots. */
    split first = {.axis = -1};
    int have_first = 0;
    if (n <= 4 * RTK_LEAF_MAX_BLOCKS && !median) {
        first = find_split(bd->refs, r);
        const float area = box_half_area(&r->geom);
        if (first.axis < 0 || (float)((n + 3) / 4) * area <= area + first.cost)
            return part_leaf(p, r->begin, r->end);
        have_first = 1;
    }
    range child[8];
    const int nc = split_children(bd, NULL, r, median, have_first ? &first : NULL, 0, child);
    const uint32_t index = part_node(p);
    write_node(p, index, child, nc);
    for (int i = 0; i < nc; i++)
        set_child(p, index, i, build_node(p, &child[i], depth + 1));
    return index;
}

static void build_subtree(void *data, uint32_t i)
{
    part *p = (part *)data + i;
    const uint32_t n = p->r.end - p->r.begin;
    /* about one node per 12 references and one leaf per 3 */
    build_grow((void **)&p->nodes, &p->node_cap, n / 12 + 1, p->bd->node_size);
    build_grow((void **)&p->leaves, &p->leaf_cap, n / 3 + 1, sizeof *p->leaves);
    p->root = build_node(p, &p->r, p->depth0);
}

/* ---- stage 1: the top nodes, on every thread ---- */

typedef struct top {
    part nodes; /* the top nodes; EXT | k is subtree k */
    part *subtrees;
    uint32_t subtree_count, subtree_cap;
    bins *scratch; /* RTK_CHUNKS_MAX of them */
} top;

static uint32_t add_subtree(top *t, const range *r, uint32_t depth)
{
    if (t->nodes.oom || !build_grow((void **)&t->subtrees, &t->subtree_cap, t->subtree_count + 1, sizeof *t->subtrees)) {
        t->nodes.oom = 1;
        return EXT;
    }
    t->subtrees[t->subtree_count] = (part){.bd = t->nodes.bd, .r = *r, .depth0 = depth};
    return EXT | t->subtree_count++;
}

static uint32_t top_node(top *t, const range *r, uint32_t depth)
{
    part *p = &t->nodes;
    if (depth > p->depth)
        p->depth = depth;
    range child[8];
    const int nc = split_children(p->bd, t->scratch, r, depth >= RTK_SAH_MEDIAN_DEPTH, NULL, 1, child);
    const uint32_t index = part_node(p);
    write_node(p, index, child, nc);
    for (int i = 0; i < nc; i++) {
        const uint32_t ref = child[i].end - child[i].begin >= RTK_TOP_MIN ? top_node(t, &child[i], depth + 1)
                                                                           : add_subtree(t, &child[i], depth + 1);
        set_child(p, index, i, ref);
    }
    return index;
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
    build_write_block(bd, index, geom, prim, count, NULL);
}

/* Copies part p's nodes to the final array at p->node_base, turning its
 * references into final ones: ext[k * stride] is the final reference of
 * external child k. */
static void place_nodes(const part *p, const uint32_t *ext, size_t stride)
{
    const build *bd = p->bd;
    if (!p->node_count)
        return;
    char *to = (char *)bd->nodes + p->node_base * bd->node_size;
    memcpy(to, p->nodes, (size_t)p->node_count * bd->node_size);
    for (uint32_t i = 0; i < p->node_count; i++) {
        uint32_t *child = view_node(bd, to, i).child;
        for (int c = 0; c < bd->width; c++) {
            const uint32_t ref = child[c];
            if (ref != RTK_BVH4_EMPTY)
                child[c] = ref & EXT ? ext[(size_t)(ref & ~EXT) * stride] : (uint32_t)(p->node_base + ref);
        }
    }
}

/* A subtree's final root reference (after place_subtree). */
static uint32_t subtree_root(const part *p)
{
    return p->root & EXT ? p->leaves[p->root & ~EXT].begin : (uint32_t)(p->node_base + p->root);
}

static void place_subtree(void *data, uint32_t i)
{
    part *p = (part *)data + i;
    uint64_t block = p->block_base;
    for (uint32_t k = 0; k < p->leaf_count; k++) {
        leafrange *l = &p->leaves[k];
        const uint32_t blocks = (l->end - l->begin + 3) / 4;
        for (uint32_t b = 0; b < blocks; b++)
            write_block(p->bd, l->begin + 4 * b, l->end, block + b);
        l->begin = rtk_leaf_ref((uint32_t)block, blocks);
        block += blocks;
    }
    place_nodes(p, p->leaves ? &p->leaves[0].begin : NULL, sizeof *p->leaves / sizeof(uint32_t));
}

/* ---- the references ---- */

typedef struct refgen {
    const build *bd;
    const uint64_t *geom_first; /* global index of each geometry's first triangle; [count] = total */
    uint64_t total;
    uint32_t chunks;
    uint32_t *kept;  /* per chunk: references written from the chunk's start */
    uint64_t *skipped, *degenerate;
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
    uint32_t gi = 0, lo = 0, hi = in->geometry_count; /* the last geometry starting at or before begin */
    while (lo < hi) {
        const uint32_t mid = lo + (hi - lo) / 2;
        if (g->geom_first[mid] <= begin) {
            gi = mid;
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    range *r = &g->bounds[k];
    range_init(r, 0, 0);
    primref *out = g->bd->refs + begin;
    uint32_t n = 0;
    uint64_t skipped = 0, degenerate = 0;
    for (uint64_t i = begin; i < end; i++) {
        while (i >= g->geom_first[gi + 1])
            gi++;
        const rtk_build_geometry *geo = &in->geometries[gi];
        const size_t prim = (size_t)(i - g->geom_first[gi]);
        const uint32_t *tri = triangle_at(geo, prim);
        const float *v0 = vertex_at(geo, tri[0]), *v1 = vertex_at(geo, tri[1]), *v2 = vertex_at(geo, tri[2]);
        if (!rtk_triangle_is_finite(v0, v1, v2)) {
            skipped++;
            continue;
        }
        if (rtk_triangle_is_degenerate(v0, v1, v2)) {
            degenerate++;
            continue;
        }
        primref *ref = &out[n++];
        vfloat4 p0 = vf4_set(v0[0], v0[1], v0[2], 0.0f);
        vfloat4 p1 = vf4_set(v1[0], v1[1], v1[2], 0.0f);
        vfloat4 p2 = vf4_set(v2[0], v2[1], v2[2], 0.0f);
        vfloat4 blo = vf4_min(vf4_min(p0, p1), p2), bhi = vf4_max(vf4_max(p0, p1), p2);
        range_add(r, blo, bhi);
        vf4_store(ref->lo, blo);
        vf4_store(ref->hi, bhi);
        ref->lo[3] = rtk_bits_float(gi);
        ref->hi[3] = rtk_bits_float((uint32_t)prim);
    }
    g->kept[k] = n;
    g->skipped[k] = skipped;
    g->degenerate[k] = degenerate;
}

/* ---- the builder ---- */

static void free_parts(top *t)
{
    part_free(&t->nodes);
    for (uint32_t i = 0; i < t->subtree_count; i++)
        part_free(&t->subtrees[i]);
    free(t->subtrees);
    free(t->scratch);
}

int RTK_SYM(rtk_build_sah)(const rtk_build_input *in, rtk_build_output *out)
{
    uint64_t total;
    build bd;
    int rc = build_begin(&bd, in, out, &total);
    if (rc)
        return rc;
    const size_t ref_bytes = (total ? total : 1) * sizeof *bd.refs;
    bd.refs = build_reserve(ref_bytes);
    refgen g = {.bd = &bd, .total = total, .chunks = (uint32_t)((total + RTK_REF_CHUNK - 1) / RTK_REF_CHUNK)};
    const size_t nc = g.chunks ? g.chunks : 1;
    uint64_t *geom_first = build_geom_first(in);
    g.geom_first = geom_first;
    g.kept = malloc(nc * sizeof *g.kept);
    g.skipped = malloc(nc * sizeof *g.skipped);
    g.degenerate = malloc(nc * sizeof *g.degenerate);
    g.bounds = malloc(nc * sizeof *g.bounds);
    top t = {.nodes = {.bd = &bd}, .scratch = malloc(RTK_CHUNKS_MAX * sizeof *t.scratch)};
    if (!bd.refs || !geom_first || !g.kept || !g.skipped || !g.degenerate || !g.bounds || !t.scratch) {
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
    uint64_t skipped = 0, degenerate = 0;
    for (uint32_t k = 0; k < g.chunks; k++) {
        const uint64_t from = (uint64_t)k * RTK_REF_CHUNK;
        if (n != from && g.kept[k])
            memmove(bd.refs + n, bd.refs + from, (size_t)g.kept[k] * sizeof *bd.refs);
        n += g.kept[k];
        skipped += g.skipped[k];
        degenerate += g.degenerate[k];
        range_merge(&root, &g.bounds[k]);
    }
    root.end = n;

    /* Stage 1, then the subtrees (largest first, for the balance). */
    uint32_t root_local = RTK_BVH4_EMPTY;
    if (n >= RTK_TOP_MIN)
        root_local = top_node(&t, &root, 1);
    else if (n)
        root_local = add_subtree(&t, &root, 1);
    uint64_t *order = malloc((t.subtree_count ? t.subtree_count : 1) * sizeof *order);
    if (!order || t.nodes.oom) {
        free(order);
        rc = RTK_ERROR_OUT_OF_MEMORY;
        build_set_message(out, "out of memory for the BVH");
        goto done;
    }
    for (uint32_t i = 0; i < t.subtree_count; i++)
        order[i] = t.subtrees[i].r.end - t.subtrees[i].r.begin;
    build_largest_first(order, t.subtree_count);
    build_run_ordered(&bd, order, t.subtree_count, build_subtree, t.subtrees);

    /* Places: the top nodes, then the subtrees in the order stage 1 found them. */
    uint64_t nodes = t.nodes.node_count, blocks = 0;
    uint32_t depth = t.nodes.depth;
    int oom = 0;
    for (uint32_t i = 0; i < t.subtree_count; i++) {
        part *p = &t.subtrees[i];
        p->node_base = nodes;
        p->block_base = blocks;
        nodes += p->node_count;
        blocks += p->blocks;
        depth = p->depth > depth ? p->depth : depth;
        oom |= p->oom;
    }
    struct rtk_accel *accel = oom ? NULL : build_accel_alloc(&bd, nodes, blocks);
    if (!accel) {
        free(order);
        rc = RTK_ERROR_OUT_OF_MEMORY;
        build_set_message(out, "out of memory for the BVH");
        goto done;
    }
    build_run_ordered(&bd, order, t.subtree_count, place_subtree, t.subtrees);
    free(order);
    uint32_t *roots = malloc((t.subtree_count ? t.subtree_count : 1) * sizeof *roots);
    if (!roots) {
        RTK_SYM(rtk_bvh4_release)(accel);
        rc = RTK_ERROR_OUT_OF_MEMORY;
        build_set_message(out, "out of memory for the BVH");
        goto done;
    }
    for (uint32_t i = 0; i < t.subtree_count; i++)
        roots[i] = subtree_root(&t.subtrees[i]);
    place_nodes(&t.nodes, roots, 1);
    const uint32_t root_ref = root_local == RTK_BVH4_EMPTY ? RTK_BVH4_EMPTY
                              : root_local & EXT            ? roots[root_local & ~EXT]
                                                            : root_local;
    free(roots);
    build_accel_finish(&bd, accel, root_ref, n, depth, &root.geom, out);
    out->prims_skipped = skipped;
    out->prims_degenerate = degenerate;
    rc = RTK_OK;
done:
    free_parts(&t);
    free(geom_first);
    free(g.kept);
    free(g.skipped);
    free(g.degenerate);
    free(g.bounds);
    build_unreserve(bd.refs, ref_bytes);
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
    uint32_t max_id = 0;
    for (uint32_t gi = 0; gi < in->geometry_count; gi++)
        max_id = in->geometries[gi].geom_id > max_id ? in->geometries[gi].geom_id : max_id;
    uint32_t *index_of = malloc(((size_t)max_id + 1) * sizeof *index_of);
    const size_t ref_bytes = (t->prim_count ? t->prim_count : 1) * sizeof *bd.refs;
    bd.refs = build_reserve(ref_bytes);
    part p = {.bd = &bd, .node_count = (uint32_t)t->node_count, .leaf_count = (uint32_t)t->leaf_count};
    p.nodes = malloc((t->node_count ? t->node_count : 1) * bd.node_size);
    p.leaves = malloc((t->leaf_count ? t->leaf_count : 1) * sizeof *p.leaves);
    struct rtk_accel *accel =
        index_of && bd.refs && p.nodes && p.leaves ? build_accel_alloc(&bd, t->node_count, blocks) : NULL;
    if (!accel) {
        free(index_of);
        part_free(&p);
        build_unreserve(bd.refs, ref_bytes);
        build_set_message(out, "out of memory for the BVH");
        return RTK_ERROR_OUT_OF_MEMORY;
    }
    for (uint32_t gi = 0; gi < in->geometry_count; gi++)
        index_of[in->geometries[gi].geom_id] = gi;
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
        write_node(&p, i, child, nc);
        for (int c = 0; c < nc; c++)
            set_child(&p, i, c, refs[c]);
    }
    for (uint32_t j = 0; j < p.leaf_count; j++)
        p.leaves[j] = (leafrange){(uint32_t)t->leaf_first[j], (uint32_t)t->leaf_first[j + 1]};
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
                          : t->root & RTK_BVH_LEAF_BIT ? p.leaves[t->root & ~RTK_BVH_LEAF_BIT].begin
                                                       : t->root;
    const uint32_t depth = t->root == RTK_BVH_EMPTY ? 0 : tree_depth(t, t->root, 1);
    part_free(&p);
    build_unreserve(bd.refs, ref_bytes);
    build_accel_finish(&bd, accel, root, t->prim_count, depth, &bounds, out);
    return RTK_OK;
}

