/*
 * Layout "bvh4.object": the top level of a two-level scene (a scene with
 * instances).  A 4-wide BVH of rtk_bvh4_node over objects (rtk_backend.h,
 * rtk_build_object): other accels of this backend, each placed by an affine
 * map.  A leaf reference (rtk_leaf_ref) names up to four consecutive
 * objects, as it names up to four triangle blocks elsewhere.
 *
 * The builder is a binned SAH builder over the objects' boxes, on the
 * calling thread (scenes hold a few objects to some hundred thousands; the
 * objects' own trees are where the triangles are), after opening the
 * upper nodes of world-space trees into references of their own
 * (open_objects).  The single-ray traversal (traverse_objects.h) tests a
 * node's four boxes, visits the children nearest first, walks the trees
 * of the layout most objects have in the same loop and calls every other
 * object's own kernel with the ray taken into the object's space; the
 * packets here do the same lane by lane, or hand user primitives their
 * packets whole.  The builder is deterministic: the same objects give the
 * same tree, byte for byte.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "backend_common.h"
#include "build_common.h"
#include "bvh4_triangle4.h"
#include "kernels.h"
#include "objects_ray.h"

#define OBJ_BINS 16
#define OBJ_LEAF_MAX RTK_LEAF_MAX_BLOCKS
/* Below this depth splits are by SAH; past it by the median, which halves
 * the objects at least once per level, so no tree is deeper than
 * 32 + 29 < RTK_BVH4_MAX_DEPTH levels (fewer than 2^29 objects). */
#define OBJ_SAH_DEPTH 32

/* A reference of the top level: 32 bytes, its box's corners each loaded 4
 * wide (lane 3 the field after them, never used).  The centre is computed
 * where it is needed (ref_c, ref_centre), not kept: with it the references
 * were 44 bytes, and the build's passes over 10^5 of them (4.4 MB) waited
 * on memory. */
typedef struct obj_ref {
    float lo[3];
    uint32_t index; /* into in->objects */
    float hi[3];
    uint32_t root; /* the node of the object's tree the walk starts at (open_objects) */
} obj_ref;

_Static_assert(sizeof(obj_ref) == 32, "obj_ref: 32 bytes");

/* The centre of r's box along axis k: the same float as ref_c's lane k. */
static inline float ref_centre(const obj_ref *r, int k)
{
    return 0.5f * r->lo[k] + 0.5f * r->hi[k]; /* finite for any finite box */
}

typedef struct obj_build {
    obj_ref *refs;
    void *nodes;      /* rtk_bvh4_node, or rtk_bvh8_node for width 8 */
    size_t node_size;
    int width;        /* 4, or 8 (top_width) */
    uint64_t node_count, node_cap;
    rtk_object_item *items;    /* in leaf order, object_count of them */
    uint64_t object_count;
    rtk_object_src *src; /* parallel to items when built for refitting, else NULL */
    /* each object once, in the order the leaves first name it: the records
     * of those not walked inline, the transforms of the instances that are;
     * slot[i]: where in->objects[i] went (UINT32_MAX: not yet) */
    rtk_build_object *objects;
    float (*xfms)[12];
    uint32_t *slot;
    uint32_t record_count, xfm_count;
    /* the objects with these kernels are walked inline (pick_merged) */
    rtk_intersect1_fn inline_kernel;
    rtk_occluded1_fn inline_occluded;
    const rtk_build_input *in;
    const rtk_memory *mem; /* the top level's memory accounting */
    uint32_t max_depth;
} obj_build;

static float half_area(const float lo[3], const float hi[3])
{
    const float d[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
    return d[0] >= 0.0f ? d[0] * d[1] + d[1] * d[2] + d[2] * d[0] : 0.0f;
}

/* half_area of three boxes at once: lane a of lo[k] and hi[k] is box a's
 * side along axis k (each lane half_area's operations in its order). */
static inline vfloat4 half_area_axes(const vfloat4 lo[3], const vfloat4 hi[3])
{
    const vfloat4 d0 = vf4_sub(hi[0], lo[0]), d1 = vf4_sub(hi[1], lo[1]), d2 = vf4_sub(hi[2], lo[2]);
    const vfloat4 a = vf4_add(vf4_add(vf4_mul(d0, d1), vf4_mul(d1, d2)), vf4_mul(d2, d0));
    return vf4_select(vf4_ge(d0, vf4_set1(0.0f)), a, vf4_set1(0.0f));
}

/* A reference's box corners and centre 4 wide (lane 3 is the next field,
 * never used).  Boxes grow by vf4_min(new, box) and vf4_max(new, box): a <
 * b ? a : b lane by lane, the comparisons of the scalar code these
 * replaced, so the same floats. */
static inline vfloat4 ref_lo(const obj_ref *r) { return vf4_loadu(r->lo); }
static inline vfloat4 ref_hi(const obj_ref *r) { return vf4_loadu(r->hi); }
static inline vfloat4 ref_c(const obj_ref *r)
{
    const vfloat4 half = vf4_set1(0.5f);
    return vf4_add(vf4_mul(half, ref_lo(r)), vf4_mul(half, ref_hi(r))); /* (nothing contracted: ref_centre) */
}

/* A range of references' bounds: their boxes' (lo, hi) and their centres'
 * (clo, chi), 4 wide (lanes 0..2). */
typedef struct obj_range {
    vfloat4 lo, hi, clo, chi;
} obj_range;

static inline void range_empty(obj_range *b)
{
    b->lo = b->clo = vf4_set1(INFINITY);
    b->hi = b->chi = vf4_set1(-INFINITY);
}

static inline void range_grow(obj_range *b, const obj_ref *r)
{
    b->lo = vf4_min(ref_lo(r), b->lo);
    b->hi = vf4_max(ref_hi(r), b->hi);
    const vfloat4 c = ref_c(r);
    b->clo = vf4_min(c, b->clo);
    b->chi = vf4_max(c, b->chi);
}

static void range_bounds(const obj_ref *r, size_t n, obj_range *b)
{
    range_empty(b);
    for (size_t i = 0; i < n; i++)
        range_grow(b, &r[i]);
}

static int by_centre(const obj_ref *x, const obj_ref *y, int axis)
{
    const float p = ref_centre(x, axis), q = ref_centre(y, axis);
    return p < q ? -1 : p > q ? 1 : (x->index > y->index) - (x->index < y->index);
}
static int by_centre_x(const void *a, const void *b) { return by_centre(a, b, 0); }
static int by_centre_y(const void *a, const void *b) { return by_centre(a, b, 1); }
static int by_centre_z(const void *a, const void *b) { return by_centre(a, b, 2); }

/* The bins of r's centre along x, y and z (lanes 0..2) for bins from lo
 * of 1 / scale each: (centre - lo) * scale truncated, at most OBJ_BINS -
 * 1, NaN and below 0 in bin 0 (vf4_max(NaN, 0) is 0). */
static inline vint4 ref_bins(const obj_ref *r, vfloat4 lo, vfloat4 scale)
{
    const vfloat4 f = vf4_mul(vf4_sub(ref_c(r), lo), scale);
    /* (OBJ_BINS - 0.5: what truncates to OBJ_BINS - 1, as every f at or
     * above OBJ_BINS - 1 does) */
    return vi4_from_vf4_trunc(vf4_min(vf4_max(f, vf4_set1(0.0f)), vf4_set1((float)OBJ_BINS - 0.5f)));
}

static inline int ref_bin(const obj_ref *r, int axis, vfloat4 lo, vfloat4 scale)
{
    _Alignas(16) int32_t bin[4];
    vi4_store(bin, ref_bins(r, lo, scale));
    return bin[axis];
}

/* Splits r[0, n) (bounds *all) in two non-empty parts; returns the size of
 * the first, with the parts' bounds in *left and *right.  The partition
 * grows the parts' bounds as it places each reference (a reference is
 * placed once), so no pass over a range only to bound it: those passes
 * and the binning, per axis and scalar, took 60% of the instructions of a
 * frame's commit of the bunny's dynamic scene, its top level of about
 * 1,000 references rebuilt (callgrind, rtktool bench --only twolevel). */
static size_t split(obj_ref *r, size_t n, uint32_t depth, const obj_range *all, obj_range *left, obj_range *right)
{
    _Alignas(16) float clo[4], chi[4];
    vf4_store(clo, all->clo);
    vf4_store(chi, all->chi);
    int axis = 0;
    for (int k = 1; k < 3; k++)
        if (chi[k] - clo[k] > chi[axis] - clo[axis])
            axis = k;
    const float extent = chi[axis] - clo[axis];
    if (depth < OBJ_SAH_DEPTH && extent > 0.0f) {
        /* Binned SAH along every axis with an extent; the cheapest wins.
         * The three axes are binned in one pass, their boxes grown 4 wide:
         * the same bins and floats as a scalar pass per axis would give. */
        float best_cost = INFINITY;
        int best_axis = -1, best_bin = 0;
        _Alignas(16) float sc[4] = {0.0f, 0.0f, 0.0f, 0.0f};
        int binned[3];
        for (int a = 0; a < 3; a++) {
            const float ext = chi[a] - clo[a];
            /* (centres across the whole float range: no bins) */
            binned[a] = ext > 0.0f && ext != INFINITY;
            sc[a] = binned[a] ? (float)OBJ_BINS / ext * 0.99999f : 0.0f;
        }
        const vfloat4 scale4 = vf4_load(sc);
        _Alignas(16) int32_t count[OBJ_BINS][4]; /* count[b][a]: bin b of axis a */
        memset(count, 0, sizeof count);
        vfloat4 blo[3][OBJ_BINS], bhi[3][OBJ_BINS];
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < OBJ_BINS; b++) {
                blo[a][b] = vf4_set1(INFINITY);
                bhi[a][b] = vf4_set1(-INFINITY);
            }
        for (size_t i = 0; i < n; i++) {
            _Alignas(16) int32_t bin[4];
            vi4_store(bin, ref_bins(&r[i], all->clo, scale4));
            const vfloat4 rl = ref_lo(&r[i]), rh = ref_hi(&r[i]);
            for (int a = 0; a < 3; a++) {
                const int b = bin[a];
                count[b][a]++;
                blo[a][b] = vf4_min(rl, blo[a][b]);
                bhi[a][b] = vf4_max(rh, bhi[a][b]);
            }
        }
        /* The sweeps, the three axes at once: lane a of each vector below is
         * axis a (the bins' boxes transposed), each lane the scalar sweep's
         * operations in its order, so the same costs.  Most ranges a frame
         * of the bunny's dynamic scene splits are a few dozen references,
         * and there the sweeps of the 16 bins, axis by axis and scalar, took
         * most of a split's instructions. */
        vfloat4 tlo[OBJ_BINS][3], thi[OBJ_BINS][3];
        for (int b = 0; b < OBJ_BINS; b++) {
            vfloat4 x = blo[0][b], y = blo[1][b], z = blo[2][b], w = vf4_set1(0.0f);
            vf4_transpose(&x, &y, &z, &w);
            tlo[b][0] = x, tlo[b][1] = y, tlo[b][2] = z;
            x = bhi[0][b], y = bhi[1][b], z = bhi[2][b], w = vf4_set1(0.0f);
            vf4_transpose(&x, &y, &z, &w);
            thi[b][0] = x, thi[b][1] = y, thi[b][2] = z;
        }
        vfloat4 rlo[3], rhi[3], right_area[OBJ_BINS];
        vint4 right_count[OBJ_BINS], acc = vi4_set1(0);
        for (int k = 0; k < 3; k++) {
            rlo[k] = vf4_set1(INFINITY);
            rhi[k] = vf4_set1(-INFINITY);
        }
        for (int b = OBJ_BINS - 1; b > 0; b--) {
            for (int k = 0; k < 3; k++) {
                rlo[k] = vf4_min(tlo[b][k], rlo[k]);
                rhi[k] = vf4_max(thi[b][k], rhi[k]);
            }
            acc = vi4_add(acc, vi4_load(count[b]));
            right_area[b] = half_area_axes(rlo, rhi);
            right_count[b] = acc;
        }
        const vbool4 axes = vb4_from_bits(binned[0] | binned[1] << 1 | binned[2] << 2);
        const vint4 none = vi4_set1(0);
        vfloat4 llo[3], lhi[3];
        vint4 nleft = vi4_set1(0);
        for (int k = 0; k < 3; k++) {
            llo[k] = vf4_set1(INFINITY);
            lhi[k] = vf4_set1(-INFINITY);
        }
        _Alignas(16) float cost[OBJ_BINS][4];
        for (int b = 1; b < OBJ_BINS; b++) {
            for (int k = 0; k < 3; k++) {
                llo[k] = vf4_min(tlo[b - 1][k], llo[k]);
                lhi[k] = vf4_max(thi[b - 1][k], lhi[k]);
            }
            nleft = vi4_add(nleft, vi4_load(count[b - 1]));
            const vfloat4 c = vf4_add(vf4_mul(half_area_axes(llo, lhi), vf4_from_vi4(nleft)),
                                      vf4_mul(right_area[b], vf4_from_vi4(right_count[b])));
            /* (no split with an empty side, none along an axis not binned) */
            const vbool4 valid = vb4_andnot(vb4_andnot(axes, vi4_eq(nleft, none)), vi4_eq(right_count[b], none));
            vf4_store(cost[b], vf4_select(valid, c, vf4_set1(INFINITY)));
        }
        for (int a = 0; a < 3; a++) /* (axis by axis, bin by bin: the first of equal costs, as before) */
            for (int b = 1; b < OBJ_BINS; b++)
                if (cost[b][a] < best_cost) {
                    best_cost = cost[b][a];
                    best_axis = a;
                    best_bin = b;
                }
        if (best_axis >= 0) {
            /* the same bin mapping as above decides the side */
            /* (the parts' bounds in locals, kept in registers) */
            obj_range lb, rb;
            range_empty(&lb);
            range_empty(&rb);
            /* Each reference is read where it lay before the partition
             * moved anything: a reference read back from where a swap has
             * just written it was loaded across the copy's stores, and the
             * loads waited on them. */
            size_t i = 0, j = n;
            for (;;) {
                while (i < j && ref_bin(&r[i], best_axis, all->clo, scale4) < best_bin)
                    range_grow(&lb, &r[i++]);
                while (i < j && ref_bin(&r[j - 1], best_axis, all->clo, scale4) >= best_bin)
                    range_grow(&rb, &r[--j]);
                if (i >= j)
                    break;
                const obj_ref a = r[i], z = r[j - 1]; /* a goes right, z left */
                range_grow(&lb, &z);
                range_grow(&rb, &a);
                r[i++] = z;
                r[--j] = a;
            }
            *left = lb;
            *right = rb;
            if (i > 0 && i < n)
                return i;
        }
    }
    /* the median along the widest axis (equal centres: by index) */
    qsort(r, n, sizeof *r, axis == 0 ? by_centre_x : axis == 1 ? by_centre_y : by_centre_z);
    range_bounds(r, n / 2, left);
    range_bounds(r + n / 2, n - n / 2, right);
    return n / 2;
}

static int64_t new_node(obj_build *b)
{
    if (b->node_count == b->node_cap) {
        const uint64_t cap = b->node_cap ? 2 * b->node_cap : 16;
        void *p = mem_realloc(b->mem, b->nodes, cap * b->node_size);
        if (!p)
            return -1;
        b->nodes = p;
        b->node_cap = cap;
    }
    return (int64_t)b->node_count++;
}

/* Whether object o is walked inline by the merged traversal: a tree of its
 * layout, with a root. */
static int is_inline(const obj_build *b, const rtk_build_object *o)
{
    return b->inline_kernel && o->intersect1 == b->inline_kernel && o->occluded1 == b->inline_occluded &&
           !o->intersect_packet && o->accel->root != RTK_BVH4_EMPTY;
}

/* The subtree over r[0, n) (n >= 1, bounds *rb); its reference in *ref.
 * 0 when out of memory. */
static int build_range(obj_build *b, obj_ref *r, size_t n, uint32_t depth, uint32_t *ref, const obj_range *rb)
{
    if (depth + 1 > b->max_depth)
        b->max_depth = depth + 1;
    if (n <= OBJ_LEAF_MAX) {
        const uint64_t first = b->object_count;
        for (size_t i = 0; i < n; i++) {
            const rtk_build_object *o = &b->in->objects[r[i].index];
            rtk_object_item *it = &b->items[b->object_count++];
            *it = (rtk_object_item){.accel = o->accel, .root = r[i].root, .mask = o->mask, .inst_id = o->inst_id};
            if (b->src) /* (an opened item's parent: object_sources) */
                b->src[it - b->items] = (rtk_object_src){
                    .input = r[i].index, .parent = r[i].root == o->accel->root ? RTK_OBJECT_SRC_WHOLE : 0};
            it->flags = o->flags & RTK_BUILD_OBJECT_IDENTITY ? RTK_OBJECT_ITEM_WORLD : 0;
            const int walked_inline = is_inline(b, o);
            if (walked_inline) {
                it->flags |= RTK_OBJECT_ITEM_INLINE;
                it->pass_all = o->accel->mask_pass_all;
            }
            uint32_t *slot = &b->slot[r[i].index];
            if (*slot == UINT32_MAX) {
                if (!walked_inline) {
                    b->objects[b->record_count] = *o;
                    *slot = b->record_count++;
                } else if (!(it->flags & RTK_OBJECT_ITEM_WORLD)) {
                    xfm_to_columns(o->world_to_object, b->xfms[b->xfm_count]);
                    *slot = b->xfm_count++;
                } else {
                    *slot = 0; /* (nothing kept) */
                }
            }
            it->object = *slot;
        }
        *ref = rtk_leaf_ref((uint32_t)first, (uint32_t)n);
        return 1;
    }
    /* up to `width` children: split the range, then its largest parts */
    size_t start[8] = {0}, size[8] = {n};
    obj_range part[8];
    part[0] = *rb;
    int nc = 1;
    while (nc < b->width) {
        int widest = -1;
        for (int c = 0; c < nc; c++)
            if (size[c] > OBJ_LEAF_MAX && (widest < 0 || size[c] > size[widest]))
                widest = c;
        if (widest < 0)
            break;
        const obj_range whole = part[widest];
        const size_t left = split(r + start[widest], size[widest], depth, &whole, &part[widest], &part[nc]);
        start[nc] = start[widest] + left;
        size[nc] = size[widest] - left;
        size[widest] = left;
        nc++;
    }
    const int64_t index = new_node(b);
    if (index < 0)
        return 0;
    _Alignas(16) float lo[4], hi[4];
    vf4_store(lo, rb->lo);
    vf4_store(hi, rb->hi);
    box4 box[8];
    uint32_t child[8];
    const vbool4 xyz = vb4_from_bits(7);
    for (int c = 0; c < nc; c++) {
        if (!build_range(b, r + start[c], size[c], depth + 1, &child[c], &part[c]))
            return 0;
        box[c].lo = vf4_select(xyz, part[c].lo, vf4_set1(0.0f));
        box[c].hi = vf4_select(xyz, part[c].hi, vf4_set1(0.0f));
    }
    const build bd = {.width = b->width, .node_size = b->node_size};
    build_store_node(&bd, b->nodes, (uint64_t)index, box, child, nc);
    *ref = (uint32_t)index;
    return 1;
}

/* Whether the box lo-hi is finite and ordered. */
static int finite_corners(const float lo[3], const float hi[3])
{
    for (int k = 0; k < 3; k++)
        if (!isfinite(lo[k]) || !isfinite(hi[k]) || !(lo[k] <= hi[k]))
            return 0;
    return 1;
}

static int finite_box(const rtk_build_object *o)
{
    return finite_corners(o->lower, o->upper);
}

/* Whether the top level keeps object o: a finite box, a tree and its kernels. */
static int kept_object(const rtk_build_object *o)
{
    return finite_box(o) && o->accel && o->intersect1 && o->occluded1;
}

/* The layouts with a merged two-level traversal (traverse_objects.h), by
 * their single-ray kernel; the width of their nodes where the top level
 * may open their trees (open_objects: not the robust layouts, whose
 * traversal pads every box by the tree's extent); the width of the top
 * level's own nodes that their merged traversal walks with the layout's
 * node test (8: rtk_bvh8_node, traverse_objects.h), else 4. */
static const struct {
    rtk_intersect1_fn kernel, merged;
    rtk_occluded1_fn merged_occluded;
    rtk_intersect_stream_fn merged_stream; /* (traverse_objects_stream.h) */
    rtk_occluded_stream_fn merged_occluded_stream;
    int open_width, top_width;
} merged_layouts[] = {
#define MERGED_(tag) RTK_SYM(rtk_bvh##tag##_intersect1), RTK_SYM(rtk_bvh##tag##_objects_intersect1),                    \
        RTK_SYM(rtk_bvh##tag##_objects_occluded1), RTK_SYM(rtk_bvh##tag##_objects_intersect_stream),                   \
        RTK_SYM(rtk_bvh##tag##_objects_occluded_stream)
    {MERGED_(4), 4, 4},
#ifdef RTK_SIMD_HAS_8
    {MERGED_(8), 8, 8},
    {MERGED_(8v), 0, 4},
#endif
    {MERGED_(4i), 4, 4},
    {MERGED_(4v), 0, 4},
    {MERGED_(4ir), 0, 4},
#undef MERGED_
};
#define MERGED_LAYOUTS ((int)(sizeof merged_layouts / sizeof merged_layouts[0]))

/* The merged traversal of the layout most of the objects r[0, n) have
 * (the first in the table on a tie): its index in merged_layouts, or -1
 * if no object's tree has one (then the first's serves: it walks the top
 * level and calls every object's own kernel). */
static int pick_merged(const rtk_build_input *in, const obj_ref *r, size_t n)
{
    uint64_t count[MERGED_LAYOUTS] = {0};
    for (size_t i = 0; i < n; i++)
        for (int k = 0; k < MERGED_LAYOUTS; k++)
            count[k] += in->objects[r[i].index].intersect1 == merged_layouts[k].kernel;
    int best = 0;
    for (int k = 1; k < MERGED_LAYOUTS; k++)
        if (count[k] > count[best])
            best = k;
    return count[best] ? best : -1;
}

/* ---- opening the objects' trees into the top level ----
 * Where objects overlap (a dynamic scene's pieces, meshes cut in runs of
 * their triangles), a ray enters every one whose box it crosses and
 * descends each from its root.  As Embree's two-level builder does
 * (Benthin, Woop, Wald, Afra, "Improved Two-Level BVHs using Partial
 * Re-Braiding", HPG 2017), the largest references are replaced by their
 * trees' children before the top level is built over them: its leaves
 * then name an object and the node its walk starts at (rtk_object_item.
 * root), and the merged traversal goes straight there.  Opened:
 * world-space trees (no transform) of the merged layout, in a top level
 * with no user primitives (whose packets objects_packet hands over whole),
 * largest half area first, until the largest is a leaf or the references
 * number OBJ_OPEN_PER_OBJECT per object (OBJ_OPEN_MAX in all).  On the
 * bunny cut in 16 pieces (bench/work_per_ray.py --section twolevel, the
 * path tracer's rays, per ray): unopened 2,819 instructions, 23.6 node
 * tests of the pieces' trees and 47 first-level misses; 16 per object
 * 3,413, 18.9 and 19.5; 64 per object 2,523, 9.2 and 11.5 (Embree: 1,357,
 * 15.8 and 9.8), and 128 or 256 no different (the largest is a leaf by
 * then).  Building the top level over the dragon's 1,037 references takes
 * about 0.35 ms of a frame's commit; refitting it (rtk_objects_refit), in
 * a frame that only refits a deforming piece, about 0.05 ms. */
#define OBJ_OPEN_PER_OBJECT 64
#define OBJ_OPEN_MAX 4096

/* From this many references on, the top level's nodes are 8 wide where
 * the merged traversal has an 8-wide node test (merged_layouts.top_width,
 * traverse_objects.h).  rtktool bench, avx2, 1 thread, passes in turns
 * against the 4-wide top level: the forest of 10,000 instances 6% faster,
 * of 10^6 9%; but 16 instances of San Miguel 8% slower, where the top
 * level is two levels deep either way and the wider node test costs more
 * than it saves (callgrind: +134 instructions a ray through the
 * instances).  The dynamic scenes of the two-level section (about 1,000
 * references once opened) were 9% slower too when the 4-wide walk zeroed
 * its 1 KB state per ray as the 8-wide one did; once neither did (131a98e),
 * 8 wide from 512 references on measured (--alt, 1 and 2 threads, passes
 * in turns): the path tracer through the dragon's dynamic scene 5-6%
 * faster, the bunny's 8-9%, San Miguel's equal; callgrind on the bunny's,
 * 2,141 instructions a ray against 2,302.  So 512, not 4096. */
#define OBJ_WIDE_REFS 512

static int openable(const rtk_build_input *in, const obj_ref *r, int layout)
{
    const rtk_build_object *o = &in->objects[r->index];
    return !(r->root & RTK_BVH4_LEAF_BIT) && r->root != RTK_BVH4_EMPTY && (o->flags & RTK_BUILD_OBJECT_IDENTITY) &&
           o->intersect1 == merged_layouts[layout].kernel;
}

/* heap order: the larger half area first, then the lower object and node */
static int open_before(const obj_ref *x, const obj_ref *y)
{
    const float ax = half_area(x->lo, x->hi), ay = half_area(y->lo, y->hi);
    if (ax != ay)
        return ax > ay;
    return x->index != y->index ? x->index < y->index : x->root < y->root;
}

static void heap_sift(obj_ref *h, size_t n, size_t i)
{
    for (;;) {
        size_t m = i;
        const size_t l = 2 * i + 1, r = l + 1;
        if (l < n && open_before(&h[l], &h[m]))
            m = l;
        if (r < n && open_before(&h[r], &h[m]))
            m = r;
        if (m == i)
            return;
        const obj_ref t = h[i];
        h[i] = h[m];
        h[m] = t;
        i = m;
    }
}

/* Opens the openable references among r[0, n) (room for cap); returns
 * their number after.  The references not opened keep their place ahead of
 * the opened ones' children; the result depends on the objects alone. */
static size_t open_objects(const rtk_build_input *in, obj_ref *r, size_t n, size_t cap, int layout)
{
    const int width = merged_layouts[layout].open_width;
    /* the openable ones moved to the end, as a heap */
    size_t fixed = 0;
    for (size_t i = 0; i < n; i++)
        if (!openable(in, &r[i], layout)) {
            const obj_ref t = r[fixed];
            r[fixed++] = r[i];
            r[i] = t;
        }
    obj_ref *h = r + fixed;
    size_t hn = n - fixed;
    for (size_t i = hn / 2; i-- > 0;)
        heap_sift(h, hn, i);
    const build view = {.width = width};
    while (hn && fixed + hn + (size_t)width - 1 <= cap && openable(in, &h[0], layout)) {
        const obj_ref top = h[0];
        h[0] = h[--hn];
        heap_sift(h, hn, 0);
        const node_view v = view_node(&view, in->objects[top.index].accel->nodes, top.root);
        for (int c = 0; c < width; c++) {
            if (v.child[c] == RTK_BVH4_EMPTY)
                continue;
            const obj_ref child = {.lo = {v.lx[c], v.ly[c], v.lz[c]}, .hi = {v.ux[c], v.uy[c], v.uz[c]},
                                   .index = top.index, .root = v.child[c]};
            /* sifted up into the heap */
            size_t i = hn++;
            h[i] = child;
            while (i > 0 && open_before(&h[i], &h[(i - 1) / 2])) {
                const obj_ref t = h[i];
                h[i] = h[(i - 1) / 2];
                h[(i - 1) / 2] = t;
                i = (i - 1) / 2;
            }
        }
    }
    return fixed + hn;
}

static int object_sources(const rtk_build_input *in, const rtk_object_item *items, rtk_object_src *src,
                          uint64_t count, int width, const rtk_memory *mem);

int RTK_SYM(rtk_build_objects)(const rtk_build_input *in, rtk_build_output *out)
{
    if (in->struct_size < offsetof(rtk_build_input, objects) + sizeof in->objects ||
        in->layout != RTK_LAYOUT_BVH4_OBJECT) {
        build_set_message(out, "the objects builder needs a build input with objects, for layout bvh4.object");
        return RTK_ERROR_INVALID_ARGUMENT;
    }
    if (in->object_count >= RTK_LEAF_INDEX_LIMIT) {
        build_set_message(out, "too many objects for one top level");
        return RTK_ERROR_INVALID_ARGUMENT;
    }
    obj_build b = {.in = in};
    /* the objects kept, and the references opening may add */
    size_t kept = 0, opened_room = 0;
    int packets = 0;
    for (uint32_t i = 0; i < in->object_count; i++) {
        const rtk_build_object *o = &in->objects[i];
        if (kept_object(o)) {
            kept++;
            packets |= o->intersect_packet != NULL;
            opened_room += (o->flags & RTK_BUILD_OBJECT_IDENTITY) ? OBJ_OPEN_PER_OBJECT : 0;
        }
    }
    if (packets)
        opened_room = 0;
    opened_room = opened_room < OBJ_OPEN_MAX ? opened_room : OBJ_OPEN_MAX;
    const size_t cap = kept + opened_room;
    rtk_accel *accel = calloc(1, sizeof *accel);
    if (accel && build_input_memory(in))
        accel->memory = *build_input_memory(in);
    b.mem = accel ? &accel->memory : NULL;
    b.refs = accel ? mem_alloc(b.mem, (cap ? cap : 1) * sizeof *b.refs, 0) : NULL;
    b.items = accel ? mem_alloc(b.mem, (cap ? cap : 1) * sizeof *b.items, 0) : NULL;
    b.slot = accel ? mem_alloc(b.mem, (in->object_count ? in->object_count : 1) * sizeof *b.slot, 0) : NULL;
    size_t n = 0;
    if (b.refs)
        for (uint32_t i = 0; i < in->object_count; i++) {
            const rtk_build_object *o = &in->objects[i];
            if (!kept_object(o))
                continue;
            obj_ref *r = &b.refs[n++];
            for (int k = 0; k < 3; k++) {
                r->lo[k] = o->lower[k];
                r->hi[k] = o->upper[k];
            }
            r->index = i;
            r->root = o->accel->root;
        }
    const int merged = b.refs ? pick_merged(in, b.refs, n) : -1;
    if (merged >= 0) {
        b.inline_kernel = merged_layouts[merged].kernel;
        for (size_t i = 0; i < n && !b.inline_occluded; i++)
            if (in->objects[b.refs[i].index].intersect1 == b.inline_kernel)
                b.inline_occluded = in->objects[b.refs[i].index].occluded1;
    }
    /* what is kept of each object: a record, a transform or nothing */
    size_t records = 0, xfms = 0;
    for (size_t i = 0; i < n; i++) {
        const rtk_build_object *o = &in->objects[b.refs[i].index];
        if (!is_inline(&b, o))
            records++;
        else if (!(o->flags & RTK_BUILD_OBJECT_IDENTITY))
            xfms++;
    }
    b.objects = b.refs ? mem_alloc(b.mem, (records ? records : 1) * sizeof *b.objects, 0) : NULL;
    /* (one more: the walk loads the last column 4 wide, xfm_to_columns) */
    b.xfms = b.refs ? mem_alloc(b.mem, (xfms + 1) * sizeof *b.xfms, 0) : NULL;
    const int for_refit = in->quality == RTK_BUILD_QUALITY_REFIT;
    b.src = b.refs && for_refit ? mem_alloc(b.mem, (cap ? cap : 1) * sizeof *b.src, 0) : NULL;
    if (!accel || !b.refs || !b.items || !b.slot || !b.objects || !b.xfms || (for_refit && !b.src)) {
        if (accel) {
            mem_free(b.mem, b.refs);
            mem_free(b.mem, b.items);
            mem_free(b.mem, b.slot);
            mem_free(b.mem, b.objects);
            mem_free(b.mem, b.xfms);
            mem_free(b.mem, b.src);
        }
        free(accel);
        build_set_message(out, "out of memory");
        return RTK_ERROR_OUT_OF_MEMORY;
    }
    memset(b.slot, 0xff, (in->object_count ? in->object_count : 1) * sizeof *b.slot);
    memset(b.xfms[xfms], 0, sizeof *b.xfms); /* (the pad past the last, read and not used) */
    if (merged >= 0 && merged_layouts[merged].open_width && opened_room)
        n = open_objects(in, b.refs, n, cap, merged);
    /* 8-wide nodes for a large top level whose merged traversal walks them
     * (OBJ_WIDE_REFS); 4-wide where packets of user primitives
     * (objects_packet) or another layout's traversal read them */
    b.width = merged >= 0 && !packets && n >= OBJ_WIDE_REFS ? merged_layouts[merged].top_width : 4;
    b.node_size = b.width == 8 ? sizeof(rtk_bvh8_node) : sizeof(rtk_bvh4_node);
    obj_range all;
    range_bounds(b.refs, n, &all);
    _Alignas(16) float lo[4], hi[4];
    vf4_store(lo, all.lo);
    vf4_store(hi, all.hi);
    accel->layout = RTK_LAYOUT_BVH4_OBJECT;
    accel->root = RTK_BVH4_EMPTY;
    int built = !n || build_range(&b, b.refs, n, 0, &accel->root, &all);
    if (built && b.node_count && b.node_count < b.node_cap) {
        /* (the doubling's room given back) */
        void *fit = mem_realloc(b.mem, b.nodes, b.node_count * b.node_size);
        if (fit)
            b.nodes = fit;
    }
    mem_free(b.mem, b.refs);
    mem_free(b.mem, b.slot);
    const int open_width = merged >= 0 ? merged_layouts[merged].open_width : 0;
    if (built && b.src && !object_sources(in, b.items, b.src, b.object_count, open_width, b.mem)) {
        mem_free(b.mem, b.src); /* (a tree too large to name its nodes' slots: no refit, builds instead) */
        b.src = NULL;
    }
    if (!built) {
        mem_free(b.mem, b.nodes);
        mem_free(b.mem, b.items);
        mem_free(b.mem, b.objects);
        mem_free(b.mem, b.xfms);
        mem_free(b.mem, b.src);
        free(accel);
        build_set_message(out, "out of memory");
        return RTK_ERROR_OUT_OF_MEMORY;
    }
    accel->nodes = b.nodes;
    accel->node_count = b.node_count;
    accel->object_items = b.items;
    accel->object_count = b.object_count;
    accel->objects = b.objects;
    accel->object_xfms = b.xfms;
    accel->objects_opened = n > kept;
    accel->object_src = b.src;
    accel->objects_input_count = b.src ? in->object_count : 0;
    accel->objects_kept = b.src ? (uint32_t)kept : 0;
    accel->objects_open_width = b.src ? (uint32_t)open_width : 0;
    accel->objects_intersect1 = merged_layouts[merged >= 0 ? merged : 0].merged;
    accel->objects_occluded1 = merged_layouts[merged >= 0 ? merged : 0].merged_occluded;
    accel->objects_intersect_stream = merged_layouts[merged >= 0 ? merged : 0].merged_stream;
    accel->objects_occluded_stream = merged_layouts[merged >= 0 ? merged : 0].merged_occluded_stream;
    accel->inline_intersect1 = b.inline_kernel;
    accel->inline_occluded1 = b.inline_occluded;
    accel->leaf_count = 0;
    out->accel = accel;
    out->prims = kept;
    out->refs = b.object_count;
    out->prims_skipped = in->object_count - kept;
    out->prims_degenerate = 0;
    out->nodes = b.node_count;
    accel->objects_width = (uint32_t)b.width;
    const build view = {.width = b.width, .node_size = b.node_size, .nodes = b.nodes};
    uint64_t leaves = 0;
    for (uint64_t i = 0; i < b.node_count; i++) {
        const node_view v = view_node(&view, b.nodes, i);
        for (int c = 0; c < b.width; c++) {
            leaves += v.child[c] != RTK_BVH4_EMPTY && (v.child[c] & RTK_BVH4_LEAF_BIT);
            /* what the traversal prefetches of each child: its node, or its
             * leaf's items */
            v.prefetch[c] = rtk_prefetch_distance((uintptr_t)b.nodes + i * b.node_size, v.child[c],
                                                  (uintptr_t)b.nodes, b.node_size, (uintptr_t)b.items,
                                                  sizeof *b.items);
        }
    }
    out->leaves = n && !b.node_count ? 1 : leaves;
    out->depth = b.max_depth;
    out->bytes = b.node_count * b.node_size + b.object_count * sizeof *b.items +
                 b.record_count * sizeof *b.objects + b.xfm_count * sizeof *b.xfms +
                 (b.src ? b.object_count * sizeof *b.src : 0);
    /* (as the triangle trees count it: a leaf's items weighted by its box) */
    const box4 bounds = {all.lo, all.hi};
    const double root_area = box_half_area_d(&bounds);
    out->sah_cost = root_area > 0.0 ? build_tree_sah(&view, b.node_count, accel->root, &bounds) / root_area : 0.0;
    memcpy(out->lower, lo, sizeof out->lower);
    memcpy(out->upper, hi, sizeof out->upper);
    if (out->struct_size >= offsetof(rtk_build_output, threads) + sizeof out->threads)
        out->threads = 1;
    return 0;
}

void RTK_SYM(rtk_objects_release)(rtk_accel *accel)
{
    if (!accel)
        return;
    mem_free(&accel->memory, accel->nodes);
    mem_free(&accel->memory, accel->object_items);
    mem_free(&accel->memory, accel->objects);
    mem_free(&accel->memory, accel->object_xfms);
    mem_free(&accel->memory, accel->object_src);
    free(accel);
}

/* ---- refitting: the same objects, new boxes ----
 * A dynamic scene whose geometries' trees were all kept or refitted in
 * place (commit.c) has the same objects as at its top level's build, with
 * new boxes: the top level keeps its tree and takes them, every box
 * recomputed bottom-up, as the triangle trees' refit does (refit.c).  Its
 * items name the same trees and nodes (a refit moves no node), so an
 * opened item's box is its parent's child box in its object's refitted
 * tree.  The builder records those parents (object_sources) when asked to
 * build for refitting. */

/* Opened items sorted by object and root: the parent search's keys. */
typedef struct opened_key {
    uint32_t input, root;
    uint64_t item;
} opened_key;

static int by_opened(const void *a, const void *b)
{
    const opened_key *x = a, *y = b;
    if (x->input != y->input)
        return x->input < y->input ? -1 : 1;
    return x->root < y->root ? -1 : x->root > y->root;
}

/* Fills in the parent slot (rtk_object_src.parent) of every opened item
 * of src[0, count) (those whose parent is 0 on entry): a walk down each
 * opened object's tree from its root through the nodes opening split
 * (every child of one is an item or was itself opened).  0 when out of
 * memory or a node index too large to name with its slot. */
static int object_sources(const rtk_build_input *in, const rtk_object_item *items, rtk_object_src *src,
                          uint64_t count, int width, const rtk_memory *mem)
{
    uint64_t n = 0;
    for (uint64_t i = 0; i < count; i++)
        n += src[i].parent != RTK_OBJECT_SRC_WHOLE;
    if (!n)
        return 1;
    if (!width)
        return 0;
    const uint64_t stack_cap = 2 * n + 8;
    opened_key *keys = mem_alloc(mem, n * sizeof *keys, 0);
    uint32_t *stack = mem_alloc(mem, stack_cap * sizeof *stack, 0);
    int ok = keys && stack;
    uint64_t k = 0;
    for (uint64_t i = 0; i < count && ok; i++)
        if (src[i].parent != RTK_OBJECT_SRC_WHOLE)
            keys[k++] = (opened_key){.input = src[i].input, .root = items[i].root, .item = i};
    if (ok)
        qsort(keys, n, sizeof *keys, by_opened);
    const build view = {.width = width};
    for (uint64_t a = 0; a < n && ok;) {
        uint64_t e = a;
        while (e < n && keys[e].input == keys[a].input)
            e++;
        const rtk_accel *t = in->objects[keys[a].input].accel;
        uint64_t sp = 0, found = 0;
        stack[sp++] = t->root;
        while (sp && ok) {
            const uint32_t node = stack[--sp];
            ok = node < (1u << 29);
            const node_view v = view_node(&view, (void *)t->nodes, node);
            for (int c = 0; c < width && ok; c++) {
                const uint32_t child = v.child[c];
                if (child == RTK_BVH4_EMPTY)
                    continue;
                const opened_key want = {.input = keys[a].input, .root = child};
                opened_key *hit = bsearch(&want, keys + a, e - a, sizeof *keys, by_opened);
                if (hit) {
                    src[hit->item].parent = node << 3 | (uint32_t)c;
                    found++;
                } else {
                    ok = !(child & RTK_BVH4_LEAF_BIT) && sp < stack_cap;
                    if (ok)
                        stack[sp++] = child;
                }
            }
        }
        ok = ok && found == e - a;
        a = e;
    }
    mem_free(mem, keys);
    mem_free(mem, stack);
    return ok;
}

/* Item i's box now, from its source, in *box; 0 when not finite and
 * ordered. */
static int item_box(const rtk_accel *top, const rtk_build_input *in, uint64_t i, box4 *box)
{
    const rtk_object_src *sr = &top->object_src[i];
    const rtk_build_object *o = &in->objects[sr->input];
    float lo[3], hi[3];
    if (sr->parent == RTK_OBJECT_SRC_WHOLE) {
        memcpy(lo, o->lower, sizeof lo);
        memcpy(hi, o->upper, sizeof hi);
    } else {
        const build view = {.width = (int)top->objects_open_width};
        const node_view v = view_node(&view, o->accel->nodes, sr->parent >> 3);
        const int c = (int)(sr->parent & 7);
        lo[0] = v.lx[c], lo[1] = v.ly[c], lo[2] = v.lz[c];
        hi[0] = v.ux[c], hi[1] = v.uy[c], hi[2] = v.uz[c];
    }
    *box = (box4){vf4_set(lo[0], lo[1], lo[2], 0.0f), vf4_set(hi[0], hi[1], hi[2], 0.0f)};
    return finite_corners(lo, hi);
}

/* The box around node `index`'s children. */
static box4 node_box(const build *view, uint64_t index)
{
    const node_view v = view_node(view, view->nodes, index);
    box4 box = box_empty();
    for (int c = 0; c < view->width; c++)
        if (v.child[c] != RTK_BVH4_EMPTY)
            box_grow(&box, vf4_set(v.lx[c], v.ly[c], v.lz[c], 0.0f), vf4_set(v.ux[c], v.uy[c], v.uz[c], 0.0f));
    return box;
}

/* The box around the items of leaf `ref`. */
static box4 leaf_box(const rtk_accel *top, const rtk_build_input *in, uint32_t ref)
{
    box4 box = box_empty();
    const uint32_t first = rtk_leaf_first(ref);
    for (uint32_t i = first; i < first + rtk_leaf_blocks(ref); i++) {
        box4 b;
        item_box(top, in, i, &b);
        box_grow(&box, b.lo, b.hi);
    }
    return box;
}

/* Whether in->objects are the ones the top level was built over (the
 * same trees, kernels, masks, ids and transforms, kept alike), their
 * boxes aside; the reason why not in *why. */
static int same_objects(const rtk_accel *top, const rtk_build_input *in, const char **why)
{
    if (in->object_count != top->objects_input_count) {
        *why = "another number of objects";
        return 0;
    }
    uint64_t kept = 0;
    for (uint32_t i = 0; i < in->object_count; i++)
        kept += kept_object(&in->objects[i]);
    if (kept != top->objects_kept) {
        *why = "other objects kept";
        return 0;
    }
    for (uint64_t i = 0; i < top->object_count; i++) {
        const rtk_object_item *it = &top->object_items[i];
        const uint32_t input = top->object_src[i].input;
        const rtk_build_object *o = input < in->object_count ? &in->objects[input] : NULL;
        const int world = it->flags & RTK_OBJECT_ITEM_WORLD;
        if (!o || !kept_object(o) || o->accel != it->accel || o->mask != it->mask || o->inst_id != it->inst_id ||
            !world != !(o->flags & RTK_BUILD_OBJECT_IDENTITY)) {
            *why = "another object";
            return 0;
        }
        if (it->flags & RTK_OBJECT_ITEM_INLINE) {
            _Alignas(16) float c[12];
            xfm_to_columns(o->world_to_object, c);
            if (o->intersect1 != top->inline_intersect1 || o->occluded1 != top->inline_occluded1 ||
                o->intersect_packet || it->pass_all != o->accel->mask_pass_all ||
                (!world && memcmp(c, top->object_xfms[it->object], sizeof c))) {
                *why = "an object with other kernels, masks or transform";
                return 0;
            }
        } else {
            const rtk_build_object *r = &top->objects[it->object];
            if (o->intersect1 != r->intersect1 || o->occluded1 != r->occluded1 ||
                o->intersect_packet != r->intersect_packet || o->occluded_packet != r->occluded_packet ||
                o->flags != r->flags || memcmp(o->world_to_object, r->world_to_object, sizeof r->world_to_object)) {
                *why = "an object with other kernels or transform";
                return 0;
            }
        }
    }
    return 1;
}

int RTK_SYM(rtk_objects_refit)(rtk_accel *accel, const rtk_build_input *in, rtk_build_output *out)
{
    if (in->struct_size < offsetof(rtk_build_input, objects) + sizeof in->objects ||
        in->layout != RTK_LAYOUT_BVH4_OBJECT || accel->layout != RTK_LAYOUT_BVH4_OBJECT) {
        build_set_message(out, "the objects refit needs a build input with objects, for layout bvh4.object");
        return RTK_ERROR_INVALID_ARGUMENT;
    }
    const char *why = NULL;
    if (!accel->object_src) {
        build_set_message(out, "the top level was not built for refitting");
        return RTK_REFIT_NEEDS_BUILD;
    }
    if (!same_objects(accel, in, &why)) {
        build_set_message(out, why);
        return RTK_REFIT_NEEDS_BUILD;
    }
    for (uint64_t i = 0; i < accel->object_count; i++) {
        box4 b;
        if (!item_box(accel, in, i, &b)) {
            build_set_message(out, "an object's box is no longer finite");
            return RTK_REFIT_NEEDS_BUILD;
        }
    }
    /* children after their parents (build_range numbers a node before its
     * subtrees): backwards is bottom-up */
    const build view = {.width = (int)accel->objects_width,
                        .node_size = accel->objects_width == 8 ? sizeof(rtk_bvh8_node) : sizeof(rtk_bvh4_node),
                        .nodes = accel->nodes};
    for (uint64_t n = accel->node_count; n-- > 0;) {
        const node_view v = view_node(&view, accel->nodes, n);
        for (int c = 0; c < view.width; c++) {
            const uint32_t child = v.child[c];
            if (child == RTK_BVH4_EMPTY)
                continue;
            const box4 b = child & RTK_BVH4_LEAF_BIT ? leaf_box(accel, in, child) : node_box(&view, child);
            _Alignas(16) float lo[4], hi[4];
            vf4_store(lo, b.lo);
            vf4_store(hi, b.hi);
            v.lx[c] = lo[0], v.ly[c] = lo[1], v.lz[c] = lo[2];
            v.ux[c] = hi[0], v.uy[c] = hi[1], v.uz[c] = hi[2];
        }
    }
    const box4 root = accel->node_count ? node_box(&view, 0)
                      : accel->object_count ? leaf_box(accel, in, accel->root) /* (a root leaf) */
                                            : box_empty();
    const double root_area = accel->object_count ? box_half_area_d(&root) : 0.0;
    out->sah_cost =
        root_area > 0.0 ? build_tree_sah(&view, accel->node_count, accel->root, &root) / root_area : 0.0;
    _Alignas(16) float lo[4], hi[4];
    vf4_store(lo, root.lo);
    vf4_store(hi, root.hi);
    memcpy(out->lower, lo, sizeof out->lower);
    memcpy(out->upper, hi, sizeof out->upper);
    if (out->struct_size >= offsetof(rtk_build_output, threads) + sizeof out->threads)
        out->threads = 1;
    return 0;
}

/* ---- traversal (the ray and the node test: objects_ray.h) ---- */

/* The single-ray queries: the merged traversal the builder picked
 * (traverse_objects.h), which calls objects of every other kind through
 * their own kernels (objects_ray.h, object_intersect1). */
void RTK_SYM(rtk_objects_intersect1)(const rtk_accel *accel, rtk_rayhit *rh, const rtk_query *q)
{
    accel->objects_intersect1(accel, rh, q);
}

void RTK_SYM(rtk_objects_occluded1)(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q)
{
    accel->objects_occluded1(accel, ray, q);
}

/* Streams: the merged traversal's rays interleaved (traverse_objects_stream.h). */
void RTK_SYM(rtk_objects_intersect_stream)(const rtk_accel *accel, rtk_rayhit *const *rays, uint32_t count,
                                           const rtk_query *q)
{
    accel->objects_intersect_stream(accel, rays, count, q);
}

void RTK_SYM(rtk_objects_occluded_stream)(const rtk_accel *accel, rtk_ray *const *rays, uint32_t count,
                                          const rtk_query *q)
{
    accel->objects_occluded_stream(accel, rays, count, q);
}

/* ---- packets ----
 * The top level traced with a whole packet of K rays (4, 8 or 16): so that
 * user primitives (rtk_build_object.intersect_packet) get packets, as the
 * application's callbacks are written for.  Boxes are tested lane by lane
 * (the top level is small); an object that takes packets gets the lanes
 * that entered its leaf's box, the others are traced lane by lane. */

/* Field f of lane i of a K-packet is word f * K + i (rtk.h). */
static inline float *lane_f(void *packet, uint32_t k, int field, uint32_t i)
{
    return (float *)packet + (size_t)field * k + i;
}
static inline uint32_t lane_u32(const void *packet, uint32_t k, int field, uint32_t i)
{
    uint32_t w;
    memcpy(&w, (const char *)packet + 4 * ((size_t)field * k + i), 4);
    return w;
}
enum { F_TNEAR = 3, F_TFAR = 8, F_MASK = 9, RAY_FIELDS = 12, RAYHIT_FIELDS = 20 };

/* (memcpy: the packet's and rtk_rayhit's fields are floats and uint32s,
 * moved here as 4-byte words without breaking type-based aliasing) */
static void lane_get(const void *packet, uint32_t k, uint32_t i, void *words, int fields)
{
    for (int f = 0; f < fields; f++)
        memcpy((char *)words + 4 * f, (const char *)packet + 4 * ((size_t)f * k + i), 4);
}

static void lane_put(void *packet, uint32_t k, uint32_t i, const void *words, int fields)
{
    for (int f = 0; f < fields; f++)
        memcpy((char *)packet + 4 * ((size_t)f * k + i), (const char *)words + 4 * f, 4);
}

static void objects_packet(const rtk_accel *accel, const int32_t *active, void *packet, uint32_t k,
                           const rtk_query *q, int occluded)
{
    if (accel->root == RTK_BVH4_EMPTY)
        return;
    if (accel->objects_opened || accel->objects_width != 4) {
        /* trees opened into the top level, or 8-wide nodes (so no user
         * primitive that takes packets whole): each lane through the merged
         * traversal */
        for (uint32_t i = 0; i < k; i++) {
            if (!active[i])
                continue;
            rtk_rayhit rh;
            lane_get(packet, k, i, &rh, occluded ? RAY_FIELDS : RAYHIT_FIELDS);
            if (occluded)
                accel->objects_occluded1(accel, &rh.ray, q);
            else
                accel->objects_intersect1(accel, &rh, q);
            lane_put(packet, k, i, &rh, occluded ? RAY_FIELDS : RAYHIT_FIELDS);
        }
        return;
    }
    obj_ray pr[16];
    unsigned live = 0;
    for (uint32_t i = 0; i < k; i++) {
        if (!active[i])
            continue;
        rtk_ray r = {0};
        lane_get(packet, k, i, &r, RAY_FIELDS);
        obj_ray_init(&pr[i], &r);
        live |= 1u << i;
    }
    const rtk_bvh4_node *nodes = accel->nodes;
    uint32_t stack[OBJ_STACK];
    int sp = 0;
    stack[sp++] = accel->root;
    while (sp && live) {
        const uint32_t cur = stack[--sp];
        if (!(cur & RTK_BVH4_LEAF_BIT)) {
            unsigned want[4] = {0, 0, 0, 0};
            const rtk_bvh4_node *n = &nodes[cur];
            for (unsigned m = live; m; m &= m - 1) {
                const int i = __builtin_ctz(m);
                _Alignas(16) float dist[4];
                for (unsigned e = node_entered(n, &pr[i], *lane_f(packet, k, F_TNEAR, (uint32_t)i),
                                               *lane_f(packet, k, F_TFAR, (uint32_t)i), dist);
                     e; e &= e - 1)
                    want[__builtin_ctz(e)] |= 1u << i;
            }
            for (int slot = 3; slot >= 0; slot--)
                if (want[slot])
                    stack[sp++] = n->child[slot];
            continue;
        }
        /* the lanes that reach this leaf are those still live whose
         * tfar the leaf's objects can shorten; each object re-tests */
        const uint32_t first = rtk_leaf_first(cur), end = first + rtk_leaf_blocks(cur);
        for (uint32_t o_i = first; o_i < end; o_i++) {
            rtk_build_object tmp;
            const rtk_build_object *o = object_at(accel, o_i, &tmp);
            _Alignas(64) int32_t lanes[16];
            unsigned any = 0;
            for (uint32_t i = 0; i < k; i++) {
                lanes[i] = 0;
                if (!(live >> i & 1) || !(o->mask & lane_u32(packet, k, F_MASK, i)))
                    continue;
                /* the object's own box: a user primitive's callback is
                 * called only for the lanes that enter it */
                const float tn = *lane_f(packet, k, F_TNEAR, i), tf = *lane_f(packet, k, F_TFAR, i);
                float t0 = tn, t1 = tf;
                const obj_ray *p = &pr[i];
                for (int a = 0; a < 3; a++) {
                    const float org = vf4_lane0(p->org[a]), inv = vf4_lane0(p->inv[a]);
                    const float inv_far = vf4_lane0(p->inv_far[a]);
                    /* the planes by the direction's sign (inv has it), and
                     * a NaN slab (an origin on a plane of a zero
                     * direction's, obj_ray_scalars) dropped by the
                     * comparisons */
                    const float lo = o->lower[a] - org, hi = o->upper[a] - org;
                    const float near_a = (inv < 0.0f ? hi : lo) * inv, far_a = (inv < 0.0f ? lo : hi) * inv_far;
                    t0 = near_a > t0 ? near_a : t0;
                    t1 = far_a < t1 ? far_a : t1;
                }
                if (t0 <= t1) {
                    lanes[i] = -1;
                    any = 1;
                }
            }
            if (!any)
                continue;
            rtk_object_packet_fn whole = occluded ? o->occluded_packet : o->intersect_packet;
            const rtk_query cq = object_query(o, q);
            if (whole) {
                whole(o->accel, lanes, packet, k, &cq);
            } else {
                for (uint32_t i = 0; i < k; i++) {
                    if (!lanes[i])
                        continue;
                    /* as the single-ray traversal calls it (objects_ray.h) */
                    rtk_rayhit rh = {0};
                    lane_get(packet, k, i, &rh, occluded ? RAY_FIELDS : RAYHIT_FIELDS);
                    if (occluded) {
                        if (object_occluded1(o, &rh.ray, q))
                            *lane_f(packet, k, F_TFAR, i) = -INFINITY;
                        continue;
                    }
                    object_intersect1(o, &rh, q);
                    lane_put(packet, k, i, &rh, RAYHIT_FIELDS);
                }
            }
            if (occluded)
                for (uint32_t i = 0; i < k; i++)
                    if (*lane_f(packet, k, F_TFAR, i) == -INFINITY)
                        live &= ~(1u << i);
        }
    }
}

#define OBJECTS_PACKET_ENTRIES_(K)                                                                                     \
    void RTK_SYM(rtk_objects_intersect##K)(const rtk_accel *accel, const int32_t *active, void *packet,              \
                                           const rtk_query *q)                                                         \
    {                                                                                                                  \
        objects_packet(accel, active, packet, K, q, 0);                                                                \
    }                                                                                                                  \
    void RTK_SYM(rtk_objects_occluded##K)(const rtk_accel *accel, const int32_t *active, void *packet,               \
                                          const rtk_query *q)                                                          \
    {                                                                                                                  \
        objects_packet(accel, active, packet, K, q, 1);                                                                \
    }
OBJECTS_PACKET_ENTRIES_(4)
OBJECTS_PACKET_ENTRIES_(8)
OBJECTS_PACKET_ENTRIES_(16)
