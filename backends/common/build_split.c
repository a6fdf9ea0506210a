/*
 * How the SAH builder (build_sah.c) splits a range of references in two:
 * binned object splits (Wald 2007, RTK_SAH_BINS bins per axis, fewer for
 * small ranges), with the bins of both sides made while the references are
 * partitioned, so that the next split needs no pass of its own; spatial
 * splits (high quality), which clip the triangles at slab boundaries; and
 * a large range split with every thread, in chunks merged in chunk order,
 * so that the result depends on the range's size alone.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "build_split.h"
#include "kernels.h"
#include "geometry/triangle.h"

/* Leaf blocks of four for counts in lanes 0..2, as floats. */
static inline vfloat4 block_count(vint4 n)
{
    return vf4_from_vi4(vi4_shr(vi4_add(n, vi4_set1(3)), 2));
}

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
void pool_put(binpool *p, binned *b)
{
    if (b) {
        b->next_free = p->free;
        p->free = b;
    }
}

void pool_release(binpool *p)
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

split find_split(const build *bd, const range *r)
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

/* Slabs: per axis, bin k spans [plane[a][k], plane[a][k + 1]). */
typedef struct slabs {
    binmap map; /* over the range's box */
    int nb;
    _Alignas(16) float scale[4];
    float plane[3][RTK_SPATIAL_BINS + 1];
} slabs;

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
void share_room(primref *refs, const range *r, range *left, range *right)
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
void split_range(const build *bd, binpool *pool, const range *r, int median, const split *given,
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
void split_parallel(const build *bd, binpool *pool, bins *scratch, sbins *sscratch, const range *r,
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
