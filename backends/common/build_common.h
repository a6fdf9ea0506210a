/*
 * What the BVH builders of backends/common share (build_sah.c, build_morton.c):
 * the layouts' node and leaf geometry, the final node and leaf arrays, the
 * leaf block writer and the description of a finished accel.  Compiled per
 * backend like the rest of backends/common; the functions carry the
 * backend's suffix through the macros below.
 */
#ifndef RTK_BUILD_COMMON_H
#define RTK_BUILD_COMMON_H

#include <float.h>
#include <math.h>
#include <string.h>
#include <stdatomic.h>
#include <stddef.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>

#include "backend_common.h"
#include "bvh4_triangle4.h"
#include "geometry/triangle.h"
#include "rtk/rtk_backend.h"
#include "simd/simd.h"

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

/* What every task of one build shares (read-only once the tasks run). */
/* A build's progress (rtk_build_input.progress), shared by its threads:
 * the builder's own, on its stack (build_progress_init). */
typedef struct build_progress {
    int (*fn)(void *user, double done);
    void *user;
    atomic_int stopped;       /* the callback said to stop */
    atomic_ullong work_done;  /* of work_total units (a builder's choice) */
    uint64_t work_total;
} build_progress;

typedef struct build {
    const rtk_build_input *in;
    build_progress *progress; /* NULL: no callback */
    const rtk_memory *mem;    /* the monitor's accounting (memory.h), or NULL */
    const rtk_task_system *tasks; /* NULL: everything on this thread */
    primref *refs;
    int width;        /* 4 or 8 children per node */
    size_t node_size; /* sizeof(rtk_bvh4_node) or sizeof(rtk_bvh8_node) */
    size_t leaf_size; /* sizeof(rtk_triangle4) (= rtk_triangle4v) or sizeof(rtk_triangle4i) */
    int indexed;      /* triangle4i leaves */
    int vertex_leaves; /* triangle4v leaves (the robust layouts) */
    /* SAH builder, high quality: spatial splits are tried where the halves
     * of the best object split overlap by more than spatial_overlap (a
     * half-area); 0 = none. */
    int spatial;
    float spatial_overlap;
    /* SAH builder: what descending through an inner node costs against a
     * leaf's blocks of four triangles (build_sah.c, leaf_range): 1, or 2
     * for the motion builder's trees */
    float node_cost;
    void *nodes;      /* the final arrays (stage 3) */
    void *leaves;
    const double *node_sah; /* NULL, or each node's build_node_sah (a refit's) */
    int ids_kept;           /* a refit: the leaf blocks hold their ids already, and only their vertex data is written */
    /* in->recycle when its memory can serve this build (the same layout,
     * arrays from build_accel_alloc), else NULL: build_recycle_take hands
     * out its arrays */
    struct rtk_accel *recycle;
    /* Leaf memory a builder has used for scratch and read (mapped in
     * already), or NULL: build_accel_alloc takes it for the new leaves
     * before the recycled tree's or fresh pages, spare_mapped bytes of
     * mapping from build_reserve_huge or build_recycle_take. */
    void *spare_leaves;
    size_t spare_mapped;
    rtk_build_output *out;
} build;

/* The input's memory accounting (rtk_build_input.memory), or NULL. */
static inline const rtk_memory *build_input_memory(const rtk_build_input *in)
{
    return in->struct_size >= offsetof(rtk_build_input, memory) + sizeof in->memory ? in->memory : NULL;
}

/* The build's progress through p (on the caller's stack, living as long
 * as the build), when in has a callback; work_total units of work. */
void build_progress_init(build *bd, build_progress *p, uint64_t work_total);

/* Reports that the build is `done` through (0 to 1) at a point where it
 * can stop; 1 when it must: the callback said so, now or before.  Any
 * thread.  Without a callback, 0. */
static inline int build_report(const build *bd, double done)
{
    build_progress *p = bd->progress;
    if (!p)
        return 0;
    if (atomic_load_explicit(&p->stopped, memory_order_relaxed))
        return 1;
    if (!p->fn(p->user, done < 0.0 ? 0.0 : done > 1.0 ? 1.0 : done)) {
        atomic_store(&p->stopped, 1);
        return 1;
    }
    return 0;
}

/* build_report of the share between from and to that units more of the
 * work_total units make. */
static inline int build_report_work(const build *bd, uint64_t units, double from, double to)
{
    build_progress *p = bd->progress;
    if (!p)
        return 0;
    const uint64_t done = atomic_fetch_add_explicit(&p->work_done, units, memory_order_relaxed) + units;
    const double share = p->work_total ? (double)done / (double)p->work_total : 1.0;
    return build_report(bd, from + (to - from) * (share < 1.0 ? share : 1.0));
}

/* Whether the build has been told to stop (no call). */
static inline int build_stopped(const build *bd)
{
    return bd->progress && atomic_load_explicit(&bd->progress->stopped, memory_order_relaxed);
}

/* Runs fn(data, i) for i in [0, count) on the build's threads. */
static inline void run_parallel(const build *bd, uint32_t count, rtk_task_fn fn, void *data)
{
    if (bd->tasks && count > 1) {
        bd->tasks->parallel_for(bd->tasks->user, count, fn, data);
        return;
    }
    for (uint32_t i = 0; i < count; i++)
        fn(data, i);
}

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

/* The same in double: what the reported SAH cost sums, so that it stays
 * finite for boxes whose float area would overflow (sides near 2^64). */
static inline double box_half_area_d(const box4 *b)
{
    _Alignas(16) float d[4];
    vf4_store(d, vf4_sub(b->hi, b->lo));
    if (!(d[0] >= 0.0f))
        return 0.0; /* empty */
    return (double)d[0] * d[1] + (double)d[1] * d[2] + (double)d[2] * d[0];
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

static inline uint32_t ref_geom(const primref *r)
{
    return rtk_float_bits(r->lo[3]);
}

static inline uint32_t ref_prim(const primref *r)
{
    return rtk_float_bits(r->hi[3]);
}

/* The six coordinate arrays and the references of node `index` of an array
 * of nodes of the build's width. */
typedef struct node_view {
    float *lx, *ly, *lz, *ux, *uy, *uz;
    uint32_t *child;
    int32_t *prefetch;
} node_view;

static inline node_view view_node(const build *bd, void *nodes, uint64_t index)
{
    if (bd->width == 8) {
        rtk_bvh8_node *n = (rtk_bvh8_node *)nodes + index;
        return (node_view){n->lower_x, n->lower_y, n->lower_z, n->upper_x, n->upper_y, n->upper_z, n->child,
                           n->prefetch};
    }
    rtk_bvh4_node *n = (rtk_bvh4_node *)nodes + index;
    return (node_view){n->lower_x, n->lower_y, n->lower_z, n->upper_x, n->upper_y, n->upper_z, n->child,
                       n->prefetch};
}

static inline const float *vertex_at(const rtk_build_geometry *g, uint32_t index)
{
    return (const float *)((const char *)g->vertices + (size_t)index * g->vertex_stride);
}

static inline const uint32_t *triangle_at(const rtk_build_geometry *g, size_t prim)
{
    return (const uint32_t *)((const char *)g->indices + prim * g->index_stride);
}

/* The geometry of global triangle i: the last g (of count) with
 * geom_first[g] <= i (geom_first as build_geom_first makes it). */
static inline uint32_t build_geometry_of(const uint64_t *geom_first, uint32_t count, uint64_t i)
{
    uint32_t g = 0, lo = 0, hi = count;
    while (lo < hi) {
        const uint32_t mid = lo + (hi - lo) / 2;
        if (geom_first[mid] <= i) {
            g = mid;
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    return g;
}

/* The lanes where p - q, a component a_i b_j - a_j b_i of the cross
 * product of float edges a = v1 - v0 and b = v2 - v0 (p = a_i b_j and
 * q = a_j b_i as float products), is surely not zero in double precision
 * either (rtk_triangle_is_degenerate): far from zero next to its rounding
 * error, which is at most 4 float ulps of |p| + |q|.  The sum must be at
 * least 2^-60, where subnormal rounding is far below the margin; a sum that
 * overflowed fails the comparison by itself.  The other lanes need the
 * exact test. */
static inline vbool4 build_cross_nonzero(vfloat4 p, vfloat4 q)
{
    const vfloat4 sum = vf4_add(vf4_abs(p), vf4_abs(q));
    const vbool4 clear = vf4_gt(vf4_abs(vf4_sub(p, q)), vf4_mul(vf4_set1(0x1p-16f), sum));
    return vb4_and(clear, vf4_gt(sum, vf4_set1(0x1p-60f)));
}

/* What builds count of the triangles they leave out (rtk_build_output). */
typedef struct build_counts {
    uint64_t skipped, degenerate, out_of_range;
} build_counts;

static inline void build_counts_add(build_counts *sum, const build_counts *c)
{
    sum->skipped += c->skipped;
    sum->degenerate += c->degenerate;
    sum->out_of_range += c->out_of_range;
}

/* The counts into the output (the newest field where it has one). */
static inline void build_counts_store(rtk_build_output *out, const build_counts *c)
{
    out->prims_skipped = c->skipped;
    out->prims_degenerate = c->degenerate;
    if (out->struct_size >= offsetof(rtk_build_output, prims_out_of_range) + sizeof out->prims_out_of_range)
        out->prims_out_of_range = c->out_of_range;
}

/* Whether triangle prim of g goes in the tree, with its vertices in p as
 * (x, y, z, 0): those that can be hit, and a deforming geometry's zero-area
 * or tiny ones (as lanes that are never hit: build_write_block).  Every
 * build counts the same way (rtk_triangle_classify): a non-finite vertex
 * in c->skipped (left out), a coordinate beyond the range in
 * c->out_of_range (left out), else no area in c->degenerate and area below
 * the range in c->out_of_range (both left out, unless the geometry
 * deforms: then both are kept, never hit, and counted in c->degenerate).  Decided in vectors: the exact tests of area run only for a
 * triangle whose float cross product cannot tell (the first pass of the
 * dragon's Morton build, which had spent most of its time in the two
 * scalar tests, took 18% less time; docs/benchmarks/notes.md); a component
 * surely nonzero there is at least 2^-61, far above RTK_CROSS_LIMIT. */
static inline int build_hittable(const rtk_build_geometry *g, size_t prim, vfloat4 p[3], build_counts *c)
{
    const uint32_t *tri = triangle_at(g, prim);
    const float *v[3];
    for (int k = 0; k < 3; k++) {
        v[k] = vertex_at(g, tri[k]);
        p[k] = vf4_set(v[k][0], v[k][1], v[k][2], 0.0f);
    }
    /* 0 * x is NaN for a NaN or infinite x, as in rtk_triangle_is_finite */
    const vfloat4 zero = vf4_set1(0.0f);
    const vfloat4 z = vf4_add(vf4_add(vf4_mul(p[0], zero), vf4_mul(p[1], zero)), vf4_mul(p[2], zero));
    if (vb4_mask(vf4_eq(z, zero)) != 15) {
        c->skipped++;
        return 0;
    }
    const vfloat4 big = vf4_max(vf4_max(vf4_abs(p[0]), vf4_abs(p[1])), vf4_abs(p[2]));
    if (vb4_mask(vf4_le(big, vf4_set1(RTK_COORD_LIMIT))) != 15) {
        c->out_of_range++;
        return 0;
    }
    /* lane i: the cross product's component i (lane 3 is 0 - 0, never sure) */
    const vfloat4 a = vf4_sub(p[1], p[0]), b = vf4_sub(p[2], p[0]);
    if (vb4_mask(build_cross_nonzero(vf4_mul(vf4_yzx(a), vf4_zxy(b)), vf4_mul(vf4_zxy(a), vf4_yzx(b)))))
        return 1;
    const int deforms = (g->flags & RTK_BUILD_GEOMETRY_DEFORMS) != 0;
    if (rtk_triangle_is_degenerate(v[0], v[1], v[2]))
        c->degenerate++;
    else if (!rtk_triangle_is_tiny(v[0], v[1], v[2]))
        return 1;
    else if (deforms) /* kept and never hit, as a zero-area one (a refit cannot tell them apart) */
        c->degenerate++;
    else
        c->out_of_range++;
    return deforms;
}

/* A deforming geometry's triangle of zero area, or tiny: in the tree, never hit. */
static inline int build_unhittable_lane(const rtk_build_geometry *g, const float *v0, const float *v1,
                                        const float *v2)
{
    return (g->flags & RTK_BUILD_GEOMETRY_DEFORMS) &&
           (rtk_triangle_is_degenerate(v0, v1, v2) || rtk_triangle_is_tiny(v0, v1, v2));
}

#define build_reserve RTK_SYM(rtk_build_reserve)
#define build_reserve_huge RTK_SYM(rtk_build_reserve_huge)
#define build_unreserve RTK_SYM(rtk_build_unreserve)
#define build_release_pages RTK_SYM(rtk_build_release_pages)
#define build_set_message RTK_SYM(rtk_build_set_message)
#define build_layout_setup RTK_SYM(rtk_build_layout_setup)
#define build_begin RTK_SYM(rtk_build_begin)
#define build_geom_first RTK_SYM(rtk_build_geom_first)
#define build_geometry_index RTK_SYM(rtk_build_geometry_index)
#define build_largest_first RTK_SYM(rtk_build_largest_first)
#define build_run_ordered RTK_SYM(rtk_build_run_ordered)
#define build_accel_alloc RTK_SYM(rtk_build_accel_alloc)
#define build_recycle_take RTK_SYM(rtk_build_recycle_take)
#define build_queue_init RTK_SYM(rtk_build_queue_init)
#define build_queue_push RTK_SYM(rtk_build_queue_push)
#define build_queue_fail RTK_SYM(rtk_build_queue_fail)
#define build_queue_pop_top RTK_SYM(rtk_build_queue_pop_top)
#define build_queue_run RTK_SYM(rtk_build_queue_run)
#define build_queue_free RTK_SYM(rtk_build_queue_free)
#define build_accel_finish RTK_SYM(rtk_build_accel_finish)
#define build_write_block RTK_SYM(rtk_build_write_block)
#define build_node_sah RTK_SYM(rtk_build_node_sah)
#define build_tree_sah RTK_SYM(rtk_build_tree_sah)

/* geom_id -> index of that geometry in in->geometries, UINT32_MAX for ids
 * not there (malloc'd, *max_id + 1 entries); NULL when out of memory. */
RTK_HIDDEN uint32_t *build_geometry_index(const rtk_build_input *in, uint32_t *max_id);

/* Makes *array (of *cap elements of `size` bytes) hold at least `need`,
 * doubling; 0 when out of memory (the array is then unchanged). */
static inline int build_grow(void **array, uint32_t *cap, uint32_t need, size_t size)
{
    if (need <= *cap)
        return 1;
    uint32_t c = *cap ? *cap : 16;
    while (c < need)
        c *= 2;
    void *p = realloc(*array, (size_t)c * size);
    if (!p)
        return 0;
    *array = p;
    *cap = c;
    return 1;
}

/* The prefetch[] value (rtk_bvh4_node) of final reference ref in the node
 * at `node` of the final array bd->nodes. */
static inline int32_t build_prefetch(const build *bd, const void *node, uint32_t ref)
{
    return rtk_prefetch_distance((uintptr_t)node, ref, (uintptr_t)bd->nodes, bd->node_size, (uintptr_t)bd->leaves,
                                 bd->leaf_size);
}

/* Writes node `index` of the array `nodes` with nc children: box[i] and
 * ref[i] (ref NULL: every slot RTK_BVH4_EMPTY, for the caller to set).
 * Empty slots get inverted boxes and RTK_BVH4_EMPTY.  With references
 * into the final arrays (nodes is bd->nodes, and leaves are there), it
 * sets the node's prefetch[] too. */
static inline void build_store_node(const build *bd, void *nodes, uint64_t index, const box4 *box,
                                    const uint32_t *ref, int nc)
{
    memset((char *)nodes + index * bd->node_size, 0, bd->node_size);
    node_view v = view_node(bd, nodes, index);
    for (int i = 0; i < bd->width; i++) {
        _Alignas(16) float lo[4] = {INFINITY, INFINITY, INFINITY, 0};
        _Alignas(16) float hi[4] = {-INFINITY, -INFINITY, -INFINITY, 0};
        if (i < nc) {
            vf4_store(lo, box[i].lo);
            vf4_store(hi, box[i].hi);
        }
        v.lx[i] = lo[0];
        v.ly[i] = lo[1];
        v.lz[i] = lo[2];
        v.ux[i] = hi[0];
        v.uy[i] = hi[1];
        v.uz[i] = hi[2];
        v.child[i] = ref && i < nc ? ref[i] : RTK_BVH4_EMPTY;
        if (ref && nodes == bd->nodes && bd->leaves)
            v.prefetch[i] = build_prefetch(bd, (const char *)nodes + index * bd->node_size, v.child[i]);
    }
}

/* The slot of each of a node's nc children (box[i] over count[i]
 * triangles or references).  The order of the slots decides nothing but
 * the any-hit query's path (closest-hit queries visit children by
 * distance): occluded1 and the shadow packets enter the last
 * child hit first.  In 8-wide nodes whose children differ in density
 * (references per unit of box area) by more than RTK_SLOT_DENSITY_SPREAD,
 * the children go in decreasing order of density (ties keep the builder's
 * order), so the child tried first is the one with the most box to stop
 * the ray per triangle to test: a wall of San Miguel made of a few large
 * triangles before a subtree of ornaments.  Elsewhere they keep the
 * builder's order (each split's lower side before its upper side), which
 * on meshes of even density keeps the ray's near half of a subtree
 * together.  (Embree's builders order every node's children by count.)
 * The nodes are allocated in the builder's order either way.  rtktool
 * bench, avx2 against Embree isa=avx2, 1 thread, single rays / packets
 * of 8, the builder's order -> every node by density -> this:
 *   - sun rays (shadow rays along one direction from random points): San
 *     Miguel 0.77x / 0.54x -> 1.03x / 0.89x -> 1.02x-1.05x / 0.88x-0.91x;
 *     apartment 0.85x / 0.67x -> 0.98x / 0.80x -> 0.97x / 0.82x; bunny
 *     1.01x / 0.79x -> 0.88x / 0.67x -> 1.00x / 0.78x; dragon 1.13x-1.27x
 *     / 0.92x-0.98x -> 1.01x-1.05x / 0.85x -> 1.02x-1.12x / 0.96x-1.01x;
 *     carriage 1.04x -> 0.97x -> 1.01x-1.09x; the others within the noise;
 *   - shadow rays to a point light: San Miguel 0.91x / 0.82x -> 0.98x /
 *     0.89x (either order by density); the others within the noise.
 * Ordering every node by count alone measured as every node by density
 * but for the bunny's sun rays (0.95x against 0.88x).  In 4-wide nodes
 * (scalar's, compact scenes', and sse41's default until it took 8-wide
 * ones) ordering every node lost 5-8% on San Miguel's and
 * carriage's shadow rays and gained nothing; they keep the builder's
 * order. */
#define RTK_SLOT_DENSITY_SPREAD 16.0f
static inline void build_child_slots(const build *bd, const box4 *box, const uint32_t *count, int nc, int slot[8])
{
    float key[8], kmin = INFINITY, kmax = 0.0f;
    for (int i = 0; i < nc; i++) {
        const float area = box_half_area(&box[i]);
        key[i] = (float)count[i] / (area > 0.0f ? area : FLT_MIN);
        kmin = key[i] < kmin ? key[i] : kmin;
        kmax = key[i] > kmax ? key[i] : kmax;
        slot[i] = i;
    }
    if (bd->width != 8 || !(kmax > RTK_SLOT_DENSITY_SPREAD * kmin))
        return;
    int order[8];
    for (int i = 0; i < nc; i++) { /* insertion sort, stable */
        int j = i;
        for (; j > 0 && key[order[j - 1]] < key[i]; j--)
            order[j] = order[j - 1];
        order[j] = i;
    }
    for (int k = 0; k < nc; k++)
        slot[order[k]] = k;
}

/* Scratch memory: an anonymous mapping, returned to the system when freed,
 * its size reported through m (memory.h; NULL: none). */
RTK_HIDDEN void *build_reserve(const rtk_memory *m, size_t size);
/* The same, on transparent huge pages where the kernel has them (large
 * arrays: one fault per 2 MiB, and fewer TLB misses).  A reservation of
 * RTK_HUGE_PAGE bytes or more starts on a multiple of RTK_HUGE_PAGE. */
#define RTK_HUGE_PAGE RTK_MEM_MAP /* (2 MiB, memory.h) */
RTK_HIDDEN void *build_reserve_huge(const rtk_memory *m, size_t size);
RTK_HIDDEN void build_unreserve(const rtk_memory *m, void *p, size_t size);
/* Gives the pages wholly inside [p, p + size) of a reservation back to the
 * system (their contents are lost; the range stays reserved). */
RTK_HIDDEN void build_release_pages(void *p, size_t size);
RTK_HIDDEN void build_set_message(rtk_build_output *out, const char *text);
/* The node and leaf geometry of in->layout, and the task system if the
 * input has one with more than one thread; 0, or an error with out->message. */
RTK_HIDDEN int build_layout_setup(build *bd, const rtk_build_input *in, rtk_build_output *out);
/* What every build does first: the triangle count (*total) checked
 * against the layouts' limit, then build_layout_setup. */
RTK_HIDDEN int build_begin(build *bd, const rtk_build_input *in, rtk_build_output *out, uint64_t *total);
/* The global index of each geometry's first triangle (malloc'd; [count] is
 * the total); NULL when out of memory. */
RTK_HIDDEN uint64_t *build_geom_first(const rtk_build_input *in);
/* Subtree tasks are run largest first, for the balance (the order the
 * threads take them in changes nothing in the result).  On entry order[i]
 * holds task i's size; on return the low 32 bits of order[0, count) list
 * the tasks largest first, equal sizes by index. */
RTK_HIDDEN void build_largest_first(uint64_t *order, uint32_t count);
/* Runs fn(data, k) for every task k, in build_largest_first's order, on the
 * build's threads. */
RTK_HIDDEN void build_run_ordered(const build *bd, const uint64_t *order, uint32_t count, rtk_task_fn fn, void *data);
/* A queue of tasks that make more tasks (the SAH builder's top nodes make
 * their children's), run on the build's threads: each thread takes the
 * largest task left, and waits while the queue is empty but another still
 * runs one that may add more.  A thread waits only on a task that is
 * running, so a task system that runs the workers one after another (or
 * fewer at once than it has threads) still gets through them all.  The
 * order the tasks run in must change nothing in the result. */
typedef struct build_task {
    uint64_t key; /* larger first */
    void *item;
} build_task;
typedef struct build_queue build_queue;
/* Runs one task (its key and item as pushed); `worker` (below the build's
 * thread count) tells the threads apart, for scratch memory of their own. */
typedef void (*build_queue_fn)(build_queue *q, uint64_t key, void *item, uint32_t worker);
struct build_queue {
    pthread_mutex_t lock;
    pthread_cond_t idle; /* a task was added, or the last running one ended */
    build_task *heap;
    uint32_t count, cap;
    uint32_t running;
    int oom; /* a push found no memory: the task was not added */
    build_queue_fn fn;
    void *data;
};
/* 0 when the lock or condition cannot be made. */
RTK_HIDDEN int build_queue_init(build_queue *q, build_queue_fn fn, void *data);
/* Adds a task; 0 (and q->oom set) when out of memory. */
RTK_HIDDEN int build_queue_push(build_queue *q, uint64_t key, void *item);
/* Marks q out of memory from inside a task (one it could not make). */
RTK_HIDDEN void build_queue_fail(build_queue *q);
/* Before build_queue_run only (no lock taken): takes the largest task if
 * its key is at least `min`; NULL otherwise. */
RTK_HIDDEN void *build_queue_pop_top(build_queue *q, uint64_t min);
/* Runs the tasks, and those they add, on the build's threads until none
 * is left. */
RTK_HIDDEN void build_queue_run(const build *bd, build_queue *q);
RTK_HIDDEN void build_queue_free(build_queue *q);
/* The threads a build runs on. */
static inline uint32_t build_threads(const build *bd)
{
    return bd->tasks && bd->tasks->threads ? bd->tasks->threads : 1;
}
/* An accel with node and leaf arrays for exactly `nodes` and `blocks` (in
 * bd->nodes and bd->leaves), and the geometry table of bvh4.triangle4i;
 * NULL when out of memory.  It takes bd->spare_leaves either way (into the
 * accel, or given back). */
RTK_HIDDEN struct rtk_accel *build_accel_alloc(build *bd, uint64_t nodes, uint64_t blocks);
/* bd->recycle's leaf (leaves 1) or node array when it holds `size` bytes:
 * the build's from now on (an unreservation of *mapped bytes), and
 * out->recycled set; else NULL.  build_accel_alloc takes them itself. */
RTK_HIDDEN void *build_recycle_take(build *bd, int leaves, size_t size, size_t *mapped);
/* The SAH terms of node `index`'s slots (each slot's half-area, times its
 * blocks for a leaf), summed in slot order; the tree's SAH cost adds them
 * in node order. */
RTK_HIDDEN double build_node_sah(const build *bd, uint64_t index);
/* The SAH cost of the tree of node_count nodes of bd->nodes at `root`
 * (its box `bounds`), not yet relative to the root's area: the root's
 * term, then every node's (build_node_sah) (build_common.c). */
RTK_HIDDEN double build_tree_sah(const build *bd, uint64_t node_count, uint32_t root, const box4 *bounds);
/* Describes the finished accel in out; `bounds` holds the scene's box. */
RTK_HIDDEN void build_accel_finish(const build *bd, struct rtk_accel *accel, uint32_t root, uint64_t prims,
                                   uint32_t depth, const box4 *bounds, rtk_build_output *out);
/* Leaf block `index` of bd->leaves: `count` (1..4) triangles, geom[k] the
 * index of triangle k's geometry in the build input and prim[k] its
 * primitive index.  If `bounds` is not NULL, the triangles' box is added
 * to it.  A deforming geometry's zero-area or tiny triangle gets a lane
 * that is never hit (NaN v0 and no edges; three equal vertex indices),
 * whatever rounding would make of its edges, and keeps its ids for a
 * refit.  If `finite` is not NULL, *finite is set to 0 when a vertex of
 * the block is NaN or infinite or beyond RTK_COORD_LIMIT (a refit's check;
 * a build's triangles are within it).
 * Returns the number of never-hit lanes. */
RTK_HIDDEN uint32_t build_write_block(const build *bd, uint64_t index, const uint32_t *geom, const uint32_t *prim,
                                      uint32_t count, box4 *bounds, int *finite);

#endif
