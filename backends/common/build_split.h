/*
 * Splitting a range of references in two, for the SAH builder
 * (build_sah.c, which builds the tree from these splits): binned object
 * splits, the bins of a split's sides made while it is partitioned, spatial
 * splits that clip triangles at slab boundaries (high quality), and a large
 * range's split on every thread in chunks (the builder's stage 1).  The
 * code is in build_split.c; these are the types both files use.  Private
 * to the two files.
 */
#ifndef RTK_BUILD_SPLIT_H
#define RTK_BUILD_SPLIT_H

#include "build_common.h"

#define RTK_SAH_BINS 32
/* Chunks of stage 1 (build_sah.c) hold at least RTK_CHUNK_MIN references,
 * at most RTK_CHUNKS_MAX of them per split. */
#define RTK_CHUNK_MIN 4096u
#define RTK_CHUNKS_MAX 64u

struct binned;

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

/* Centroid as lo/2 + hi/2, which cannot overflow for finite boxes.  Lane 3
 * (the ids, often denormal as floats) is cleared first: arithmetic on
 * denormals costs a microcode assist per instruction on x86. */
static inline vfloat4 centroid(vfloat4 lo, vfloat4 hi)
{
    const vfloat4 half = vf4_set1(0.5f);
    return vf4_madd(vf4_clear3(lo), half, vf4_mul(vf4_clear3(hi), half));
}

/* The mapping from centroids to bins, per axis in lanes 0..2.  Binning and
 * partitioning both go through bin_of, so they always agree. */
typedef struct binmap {
    vfloat4 cmin, scale;
} binmap;

typedef struct split {
    int axis;   /* -1: no object split possible */
    int pos;    /* left = bins [0, pos) */
    float cost; /* the two halves' areas times their blocks of four */
    binmap map;
    box4 left, right; /* the halves' boxes */
    uint32_t n_left;  /* references in the left half */
} split;

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

typedef struct sbins {
    box4 box[3][RTK_SPATIAL_BINS]; /* the clipped parts in each slab */
    _Alignas(16) int32_t enter[RTK_SPATIAL_BINS][4], leave[RTK_SPATIAL_BINS][4];
} sbins;

static inline void range_init(range *r, uint32_t begin, uint32_t end)
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

static inline void range_merge(range *into, const range *r)
{
    box_grow(&into->geom, r->geom.lo, r->geom.hi);
    box_grow(&into->cent, r->cent.lo, r->cent.hi);
}

#define find_split RTK_SYM(rtk_build_find_split)
#define split_range RTK_SYM(rtk_build_split_range)
#define split_parallel RTK_SYM(rtk_build_split_parallel)
#define share_room RTK_SYM(rtk_build_share_room)
#define pool_put RTK_SYM(rtk_build_pool_put)
#define pool_release RTK_SYM(rtk_build_pool_release)

/* The best binned object split of r (axis -1: none). */
RTK_HIDDEN split find_split(const build *bd, const range *r);
/* Splits r into two non-empty halves on this thread (see build_split.c). */
RTK_HIDDEN void split_range(const build *bd, binpool *pool, const range *r, int median, const split *given,
                            range *left, range *right);
/* As split_range, on every thread; scratch holds 2 * RTK_CHUNKS_MAX bins,
 * sscratch RTK_CHUNKS_MAX slabs' bins. */
RTK_HIDDEN void split_parallel(const build *bd, binpool *pool, bins *scratch, sbins *sscratch, const range *r,
                               range *left, range *right);
/* Shares the room behind r between its halves (spatial splits). */
RTK_HIDDEN void share_room(primref *refs, const range *r, range *left, range *right);
/* A range's bins back to the pool of the thread that ends it, and a
 * pool's bins freed. */
RTK_HIDDEN void pool_put(binpool *p, struct binned *b);
RTK_HIDDEN void pool_release(binpool *p);

#endif
