/*
 * Single-ray traversal of the bvhN.triangle4 layouts (N = 4 or 8) and of
 * bvh4.triangle4i: closest hit and any hit.  A template: traverse_bvh4.c,
 * traverse_bvh8.c and traverse_bvh4i.c define RTK_BVHN (and
 * RTK_LEAF_INDEXED) and include it, so all share this one source.
 *
 * Written once with the types of simd/ (4-wide: SSE4.1 in the sse41, avx
 * and avx2 backends, the width-1 version in the scalar one; 8-wide AVX, or
 * two SSE4.1 halves in sse41, for the bvh8 nodes).  A node's N children are tested at once against slabs whose
 * near and far planes are picked once per ray from the signs of the
 * direction (so -0.0 behaves as a negative direction, consistently with its
 * reciprocal), visited nearest
 * first by the closest-hit query and skipped when their entry distance is
 * already beyond the closest hit; the any-hit query takes them without
 * sorting (any hit ends it; on dragon.ply shadow rays that measured about 8%
 * faster than nearest first), last slot first, as Embree's does (see
 * next_leaf).  Direction
 * components smaller than 1e-18 in magnitude (RTK_ZERO_DIR) are replaced by
 * +-1e-18 before taking the reciprocal for the near planes (as Embree
 * does); the far planes take +-inf there (ray_pre_init_v), and the NaN of
 * an origin on such a plane is dropped (node_intersect).  The far slab distance is scaled by 1 + 2*gamma(4) (Ize 2013), which makes the box test conservative against the rounding of
 * the slab arithmetic: a triangle whose hit lies on a box face or edge (rays
 * aimed at vertices do that) is not culled by its box.  A leaf's four
 * triangles are tested at once with the arithmetic of rtk_triangle_intersect.
 * The leaf tests (the triangles, the hit floor, the features' accept) are
 * traverse_leaf.h, a part of this template in a file of its own.
 *
 * The core checks ray validity before calling in: org/dir finite, 0 <= tnear <= tfar.
 */
#include <math.h>
#include <stddef.h>

#include "backend_common.h"
#include "bvh4_triangle4.h"
#include "geometry/triangle.h"
#include "kernels.h"
#include "simd/simd.h"

/* RTK_MOTION 1: bvh4/bvh8.triangle4mb (motion blur): nodes whose planes
 * are interpolated to the ray's time in its segment, and leaves whose
 * vertices are; the entry points are traverse_motion.h's. */
#ifndef RTK_MOTION
#define RTK_MOTION 0
#endif

#if RTK_BVHN == 4
#if RTK_MOTION
typedef rtk_bvh4mb_node node_t;
#define BVHN_NODES(accel) ((const rtk_bvh4mb_node *)(accel)->nodes)
#define BVHN_MB_DELTA RTK_MB_DELTA
#else
typedef rtk_bvh4_node node_t;
#define BVHN_NODES(accel) ((const rtk_bvh4_node *)(accel)->nodes)
#endif
typedef vfloat4 vnode;
#define vn_load vf4_load
#define vn_set1 vf4_set1
#define vn_set1_at vf4_set1_at
#define vn_add vf4_add
#define vn_sub vf4_sub
#define vn_mul vf4_mul
#define vn_msub vf4_msub
#define vn_min vf4_min
#define vn_max vf4_max
#define vn_le vf4_le
#define vn_ge vf4_ge
#define vn_select vf4_select
#define vn_mask vb4_mask
#define vn_store vf4_store
#define vn_maxi vf4_maxi
#define vn_mini vf4_mini
#define vn_gti vf4_gti
#define vn_madd vf4_madd
#define vn_low4(a) (a)
#define vn_add_ulps vf4_add_ulps
/* (see node_intersect) the integer order only with FMA: the unfused test
 * would pay three additions for it */
#if RTK_SIMD_HAS_FMA
#define RTK_NODE_INT_ORDER RTK_SIMD_INT_ORDER_4
#else
#define RTK_NODE_INT_ORDER 0
#endif
#elif RTK_BVHN == 8
#if RTK_MOTION
typedef rtk_bvh8mb_node node_t;
#define BVHN_MB_DELTA RTK_MB8_DELTA
#else
typedef rtk_bvh8_node node_t;
#endif
typedef vfloat8 vnode;
#define vn_load vf8_load
#define vn_set1 vf8_set1
#define vn_set1_at vf8_set1_at
#define vn_add vf8_add
#define vn_sub vf8_sub
#define vn_mul vf8_mul
#define vn_msub vf8_msub
#define vn_min vf8_min
#define vn_max vf8_max
#define vn_le vf8_le
#define vn_ge vf8_ge
#define vn_select vf8_select
#define vn_mask vb8_mask
#define vn_store vf8_store
#define vn_maxi vf8_maxi
#define vn_mini vf8_mini
#define vn_gti vf8_gti
#define vn_low4 vf8_low
#define vn_add_ulps vf8_add_ulps
#define vn_madd vf8_madd
#define BVHN_NODES(accel) ((const node_t *)(accel)->nodes)
#define RTK_NODE_INT_ORDER RTK_SIMD_INT_ORDER_8
#else
#error "define RTK_BVHN to 4 or 8 before including traverse_bvhn.h"
#endif

/* RTK_LEAF_INDEXED 1: triangle4i leaves (vertex indices), else triangle4.
 * RTK_ROBUST 1: the robust layouts (bvhN.triangle4v, or with
 * RTK_LEAF_INDEXED bvh4.triangle4i.robust): the watertight intersector
 * (geometry/triangle.h) on the triangles' vertices, and every box padded
 * (see ray_pre_init).
 * The kernels are named rtk_bvh<N>[i|mb|v|ir]_<query><width>. */
#ifndef RTK_LEAF_INDEXED
#define RTK_LEAF_INDEXED 0
#endif
#ifndef RTK_ROBUST
#define RTK_ROBUST 0
#endif
#if RTK_ROBUST
typedef rtk_triangle4v block_t;
#else
typedef rtk_triangle4 block_t;
#endif
#if RTK_ROBUST && RTK_MOTION
#define BVHN_TAG RTK_CAT(RTK_BVHN, mbr)
#elif RTK_ROBUST && RTK_LEAF_INDEXED
#define BVHN_TAG RTK_CAT(RTK_BVHN, ir)
#elif RTK_ROBUST
#define BVHN_TAG RTK_CAT(RTK_BVHN, v)
#elif RTK_LEAF_INDEXED
#define BVHN_TAG RTK_CAT(RTK_BVHN, i)
#elif RTK_MOTION
#define BVHN_TAG RTK_CAT(RTK_BVHN, mb)
#else
#define BVHN_TAG RTK_BVHN
#endif
#define BVHN_NAME_(tag, what) rtk_bvh##tag##_##what
#define BVHN_NAME(tag, what) BVHN_NAME_(tag, what)
#define BVHN_INTERSECT1 RTK_SYM(BVHN_NAME(BVHN_TAG, intersect1))
#define BVHN_OCCLUDED1 RTK_SYM(BVHN_NAME(BVHN_TAG, occluded1))

/* 1 + 2 * gamma(4), gamma(n) = n * u / (1 - n * u), u = 2^-24: the far
 * slab distances are computed with a reciprocal direction scaled by this, so
 * they come out no smaller than the exact ones however the near and far
 * distances round (at most four roundings between them; Ize 2013). */
#define RTK_BOX_FAR_SCALE (1.0f + 2.0f * (4.0f * 0x1p-24f) / (1.0f - 4.0f * 0x1p-24f))

/* The fused node test of the default layouts (FMA, not robust) scales
 * differently, and with no vectors of its own: the far distances use the
 * near planes' reciprocals, and the interval's far end moves up by
 * RTK_FAR_ULPS ulps (an integer addition to its bits) before the
 * comparison.  There each distance is off by at most two roundings of
 * relative size u = 2^-24 (the reciprocal's and the fused operation's; the
 * error of org * inv is absolute, covered by the padding of c_near and
 * c_far, see ray_pre_init), so an entry distance can come out (1 + u)^2
 * times too far and an exit distance (1 - u)^2 times too near; an ulp of a
 * positive normal float is more than u times it, so 8 ulps (a factor over
 * 1 + 8u) cover both with room to spare, and subnormal or zero exit
 * distances are covered by the padding's absolute part.  Three vectors
 * fewer for the single-ray loop to keep in registers (a multiplication
 * of the far reciprocals would cost the same but keep them). */
#define RTK_FAR_ULPS 8
#if RTK_SIMD_HAS_FMA && !RTK_ROBUST
#define RTK_FUSED_FAR_ULPS 1
#else
#define RTK_FUSED_FAR_ULPS 0
#endif

/* Robust traversal pads every box, on top of the conservative slab test
 * above, for the rounding of the watertight triangle test: that test
 * decides inside or outside from vertices taken relative to the ray origin
 * and sheared, so the point it finds inside may lie outside the triangle,
 * and so outside its box, by a few ulps of the vertices' distances from the
 * origin (distances along each axis, and the shear adds the ray's travel
 * along the major axis scaled by the minor components, the same distances
 * again) plus a few ulps of the triangle's size from the products of the
 * edge functions.  The first part is a relative error of the slab distances
 * themselves: the near distances are scaled down and the far ones up by
 * RTK_ROBUST_REL (16 ulps, several times the error bound).  The second is
 * absolute: every box grows by RTK_ROBUST_REL times the tree's largest
 * side (rtk_accel.extent) on each side, which moves the origin for the
 * near planes forward and for the far planes back (so it costs nothing per
 * node). */
#define RTK_ROBUST_REL 0x1p-20f

/* The parts of the ray that the single-ray loops of the fused (FMA) node
 * test read from memory at every use (vn_set1_at), not from registers:
 * the node test's c_near and c_far, and the origin and direction for the
 * triangle tests.  Kept out of ray_pre, whose other vectors the compiler
 * keeps in registers (were they in it, it would write the whole of ray_pre
 * to memory in every ray's set-up).  With them in registers the node loop
 * had 12 vectors of the ray to keep, the triangle test needs most of the
 * 16 registers itself, and GCC stored eight 256-bit vectors at each leaf
 * and loaded them after it (about 35 instructions per leaf visit); now
 * four.  callgrind on the dragon's diffuse rays (rtktool bench --size
 * 256x192, 40,192 rays): 1088 -> 1045 instructions per ray in the kernel
 * (Embree isa=avx2's: 1048), shadow rays 4% fewer; rtktool bench beside
 * the parent (--alt, five runs): diffuse single rays 0.5% (dragon) and
 * 1.5% (San Miguel) faster, San Miguel's shadow rays about 1% slower
 * (they mostly test the root and leave: the set-up's stores), packets
 * within the runs' spread.
 * (A version that kept them in registers for the any-hit loop, in
 * ray_pre as well, made GCC compile the out-of-line single-ray traversal
 * the packet kernels call for their last rays with 300 more stack
 * accesses: San Miguel's camera packets of 8 10% slower.) */
typedef struct ray_mem {
#if RTK_SIMD_HAS_FMA
    /* c_near x, y, z, -, c_far x, y, z, -: org * inv moved down and up
     * (see ray_pre_init) */
    _Alignas(16) float c[8];
    _Alignas(16) float o[4], d[4]; /* origin, direction (lanes 0..2) */
#else
    char unused;
#endif
} ray_mem;

/* The ray, broadcast: everything the inner loops need, computed once. */
typedef struct ray_pre {
    const ray_mem *m; /* (see ray_mem) */
    _Alignas(16) float os[4], ds[4]; /* the origin and direction (lanes 0..2), for the triangle tests' leaf_ray */
    _Alignas(16) float rs[4]; /* 1 / dir, tiny components raised (lanes 0..2), for block_hit_floor */
    vnode norg[3], ninv[3], ninv_far[3]; /* for the node tests */
#if RTK_ROBUST
    vnode norg_far[3];        /* the origin for the far planes (norg: for the near ones) */
#endif
#if RTK_SIMD_HAS_FMA
    int fma;                   /* 0: org * inv is out of range, use the sub-mul test */
#endif
    size_t near_off[3], far_off[3]; /* byte offsets of the near/far planes in a node */
#if RTK_MOTION
    vnode ftime;          /* the ray's time in its segment, for the planes */
    vfloat4 f4, one_f4;   /* the same and 1 - it, for the vertices */
#endif
} ray_pre;

/* The ray broadcast for the triangle tests, made when the ray first
 * reaches a leaf: most of San Miguel's diffuse and shadow rays test the
 * root and leave (1.3 node tests per diffuse ray, callgrind), and made in
 * the set-up these six vectors were six broadcasts and six stores to the
 * stack per ray.  A scratch driver beside Embree (passes in turns): San
 * Miguel's diffuse and shadow rays about 1.8% faster; the dragon's diffuse
 * rays within 1%, its shadow rays about 0.8% slower (there the broadcasts
 * now lie on the way to the first triangle test). */
#if RTK_ROBUST
/* For the watertight test (rtk_watertight_ray_init): the axis kz of the
 * direction's largest component, the origin along kx, ky, kz and the shear
 * d[kx] / d[kz], d[ky] / d[kz], 1 / d[kz], kept in memory and broadcast at
 * each block as the fused test's ray (ray_mem); made at the first leaf,
 * one division for the three quotients. */
typedef struct leaf_ray {
    _Alignas(16) float wo[4], s[4];
    int kz;
} leaf_ray;

static inline __attribute__((always_inline)) void leaf_ray_init(leaf_ray *l, const ray_pre *p)
{
    const float *d = p->ds, *o = p->os;
    int kx, ky, kz;
    rtk_watertight_axes(d, &kx, &ky, &kz);
    l->kz = kz;
    vf4_store(l->s, vf4_div(vf4_set(d[kx], d[ky], 1.0f, 1.0f), vf4_set1(d[kz])));
    vf4_store(l->wo, vf4_set(o[kx], o[ky], o[kz], 0.0f));
}
#if defined(__AVX__)
#define LR_SET1(x) vf4_set1_at(&(x))
#else
#define LR_SET1(x) vf4_set1(x)
#endif
#else
typedef struct leaf_ray {
    vfloat4 org[3], dir[3];
} leaf_ray;

static inline void leaf_ray_init(leaf_ray *l, const ray_pre *p)
{
    for (int k = 0; k < 3; k++) {
        l->org[k] = vf4_set1(p->os[k]);
        l->dir[k] = vf4_set1(p->ds[k]);
    }
}
#endif

/* Masks, culling and filters (rtk.h), for a ray that asks for culling in
 * a tree that holds geometry attributes: its candidate hits go through
 * accept_lane one by one, in traversals of their own (closest_from_feat,
 * any_from_feat).  Kept out of ray_pre, so the usual path's ray and code
 * are those of a library without these features. */
typedef struct feat_ctx {
    unsigned feat; /* RTK_FEAT_* */
    const rtk_geometry_attrs *attrs;
    const rtk_ray *ray;
    const rtk_query *q;
} feat_ctx;
#define RTK_FEAT_CULL (RTK_RAY_FLAG_CULL_BACK | RTK_RAY_FLAG_CULL_FRONT)
#define RTK_FEAT_ATTRS (1u << 8)
#define RTK_FEAT_QUERY_FILTER (1u << 9) /* the query's filter (rtk_query.filter) */

/* 1 when a ray of mask `mask` needs the attributes of a tree whose
 * rtk_accel.mask_pass_all is pass_all: some geometry in it has a filter, or
 * a mask the ray's does not share a bit with.  A ray that passes every mask
 * takes the usual path: a scene whose geometries all share a visibility bit
 * with the rays pays nothing for its masks.  (Plain arithmetic on values,
 * so the packets' loop over the lanes stays in vectors.) */
static inline uint32_t mask_needs_attrs(uint32_t pass_all, uint32_t mask)
{
    return (mask & pass_all) == 0;
}

static inline unsigned feat_attrs(const rtk_accel *accel, uint32_t mask)
{
    return mask_needs_attrs(accel->mask_pass_all, mask) ? RTK_FEAT_ATTRS : 0u;
}

/* The features (RTK_FEAT_*) ray r needs in the tree: 0 for the usual path. */
static inline unsigned ray_feat(const rtk_accel *accel, const rtk_ray *r)
{
    return (r->flags & RTK_FEAT_CULL) | feat_attrs(accel, r->mask);
}

/* The features the query asks for: its filter. */
static inline unsigned query_feat(const rtk_query *q)
{
    return q->flags & RTK_QUERY_FLAG_FILTER ? RTK_FEAT_QUERY_FILTER : 0u;
}

/* f filled for the ray, or NULL when it needs none of the features. */
static inline const feat_ctx *feat_init(feat_ctx *f, const rtk_ray *r, const rtk_accel *accel, const rtk_query *q)
{
    const unsigned feat = ray_feat(accel, r) | query_feat(q);
    if (__builtin_expect(!feat, 1))
        return NULL;
    *f = (feat_ctx){feat, accel->attrs, r, q};
    return f;
}

/* The byte offsets of a node's near and far planes by the signs of the
 * direction (RTK_PLANE_OFFSET_TABLE, bvh4_triangle4.h). */
static const size_t plane_offsets[8][2][3] = RTK_PLANE_OFFSET_TABLE(node_t);

/* Everything per axis is computed for x, y, z at once in lanes 0..2 of
 * 4-wide vectors (lane 3 carries tnear or time and is never used), then
 * broadcast: one division instead of three, and no scalar shuffling
 * (still, with it the entry of intersect1 is about a tenth of a diffuse
 * ray's instructions on dragon.ply: 176 of 1648, callgrind).  The values
 * are those of per-axis arithmetic bit for bit (the same IEEE operations
 * lane by lane). */
static inline __attribute__((always_inline)) void ray_pre_init_v(ray_pre *p, ray_mem *pm, vfloat4 org, vfloat4 dir,
                                                                  const rtk_accel *accel)
{
    (void)accel;
    p->m = pm;
    /* a component below 1e-18 in magnitude becomes +-1e-18, its sign kept */
    const vfloat4 inv_exact = vf4_rcp_clamped(dir, RTK_ZERO_DIR);
#if RTK_ROBUST
    /* (see RTK_ROBUST_REL) the reciprocals for the near planes scaled
     * down, for the far ones up, and the origin moved toward the near
     * planes and away from the far ones by the absolute padding, plus 4 ulps
     * of the origin so the rounding of the sum cannot undo the move */
    const vfloat4 inv = vf4_mul(inv_exact, vf4_set1(1.0f - RTK_ROBUST_REL));
    /* (the far planes of a zero direction at +-inf, as below: with +-1e18
     * the origin's move, 2^-20 of a tree some 1e-7 across, made a far
     * distance of about 1e5 for a ray along a face, and rays from farther
     * away missed: test_rays axis_rays_through_vertices_tiny) */
    const vfloat4 inv_far = vf4_mul(vf4_inf_below(inv_exact, dir, RTK_ZERO_DIR), vf4_set1(RTK_BOX_FAR_SCALE + RTK_ROBUST_REL));
    const vfloat4 shift = vf4_add(vf4_set1(accel->extent * RTK_ROBUST_REL), vf4_mul(vf4_abs(org), vf4_set1(0x1p-22f)));
    const vfloat4 org_near = vf4_add(org, vf4_xor_sign(shift, inv_exact));
    const vfloat4 org_far = vf4_sub(org, vf4_xor_sign(shift, inv_exact));
    _Alignas(16) float of[4];
    vf4_store(of, org_far);
#else
    const vfloat4 inv = inv_exact;
    /* the subtract-then-multiply test's far planes: +-inf where the
     * direction is below 1e-18 (vf4_inf_below; node_intersect drops the
     * NaN of an origin on such a plane).  With +-1e18 an axis ray along a
     * box's far face got a far distance of 0 and missed the triangles
     * there (test_rays axis_rays_through_vertices).  The fused test pads
     * c instead, by 2^-22 of org * inv, which is not enough where the
     * origin is near 0 (an axis ray along x = 0 missed a grid's edge
     * there, t = 10 against a far distance of 1e-20): with FMA such rays
     * take this test (ray_pre.fma = 0, below), whose far planes are the
     * only reader of inv_far in the FMA layouts (RTK_FUSED_FAR_ULPS). */
    const vfloat4 inv_far = vf4_mul(vf4_inf_below(inv, dir, RTK_ZERO_DIR), vf4_set1(RTK_BOX_FAR_SCALE));
#if RTK_SIMD_HAS_FMA && !RTK_FUSED_FAR_ULPS
#error "with FMA, the default layouts' fused test must not read inv_far (its zero directions are infinite)"
#endif
    const vfloat4 org_near = org, org_far = org;
#endif
#if RTK_FUSED_FAR_ULPS
    const vfloat4 fused_inv_far = inv; /* (see RTK_FAR_ULPS) */
#else
    const vfloat4 fused_inv_far = inv_far;
#endif
    (void)fused_inv_far;
    (void)org_far; /* (unused without FMA or robustness) */
    /* inv has dir's sign (d keeps it, -0.0 becoming -1e-18, and inv is never
     * +-0), so the planes are chosen from dir's sign bits as loaded: one
     * movmskps, no comparison with a zero vector */
    const unsigned neg = (unsigned)vf4_signs(dir) & 7; /* (lane 3: time or tnear) */
    _Alignas(16) float on[4], in[4], inf[4];
    vf4_store(p->os, org);
    vf4_store(p->ds, dir);
    vf4_store(p->rs, inv_exact);
    vf4_store(on, org_near);
    vf4_store(in, inv);
    vf4_store(inf, inv_far);
#if RTK_SIMD_HAS_FMA
    /* c = org * inv rounded: the product can be off by u|c|, and the
     * fused plane * inv - c subtracts it exactly, so the error is
     * absolute, not relative to the distance.  Moving c by 4u|c| (plus
     * the smallest normal, for products in the subnormal range) away on
     * each side keeps the near distances no larger and the far ones no
     * smaller than the exact ones.  Where org * inv is near the float
     * range (a huge origin, a direction component near zero) c_near and
     * c_far could become infinite or NaN, the slab would drop out of
     * the test, and with all three gone the empty child slots would be
     * entered; such rays take the subtract-then-multiply test. */
    const vfloat4 c = vf4_mul(org_near, inv), cf = vf4_mul(org_far, fused_inv_far);
    const vfloat4 ulp4 = vf4_set1(0x1p-22f), min_normal = vf4_set1(0x1p-126f);
    const vfloat4 e = vf4_add(vf4_mul(vf4_abs(c), ulp4), min_normal);
    const vfloat4 ef = vf4_add(vf4_mul(vf4_abs(cf), ulp4), min_normal);
    vf4_store(pm->c, vf4_add(c, e)); /* c_near */
    vf4_store(pm->c + 4, vf4_sub(cf, ef)); /* c_far */
    vf4_store(pm->o, org);
    vf4_store(pm->d, dir);
    p->fma = (vb4_mask(vf4_le(vf4_abs(cf), vf4_set1(0x1p126f))) & 7) == 7;
    /* (a zero direction: the subtract-then-multiply test, see inv_far;
     * in robust layouts cf is then infinite already) */
    p->fma &= (vb4_mask(vf4_lt(vf4_abs(dir), vf4_set1(RTK_ZERO_DIR))) & 7) == 0;
#endif
    for (int k = 0; k < 3; k++) {
        p->ninv[k] = vn_set1(in[k]);
        p->ninv_far[k] = vn_set1(inf[k]);
#if RTK_SIMD_HAS_FMA
        if (!p->fma)
#endif
        {
            p->norg[k] = vn_set1(on[k]);
#if RTK_ROBUST
            p->norg_far[k] = vn_set1(of[k]);
#endif
        }
    }
    memcpy(p->near_off, plane_offsets[neg][0], sizeof p->near_off);
    memcpy(p->far_off, plane_offsets[neg][1], sizeof p->far_off);
}

/* The ray set up from r's origin and direction as loaded (lane 3: tnear,
 * time); ray_pre_init_v takes them in vectors, as an instance's ray is made
 * (traverse_objects.h). */
static inline __attribute__((always_inline)) void ray_pre_init(ray_pre *p, ray_mem *pm, const rtk_ray *r,
                                                                const rtk_accel *accel)
{
    ray_pre_init_v(p, pm, vf4_loadu(&r->org_x), vf4_loadu(&r->dir_x), accel);
}

static inline vnode plane(const node_t *n, size_t off)
{
    return vn_load((const float *)((const char *)n + off));
}
#if RTK_MOTION
/* a plane at the ray's time: start + f * change */
#define PLANE(n, off) vn_madd(p->ftime, plane(n, (off) + BVHN_MB_DELTA), plane(n, off))
#else
#define PLANE(n, off) plane(n, off)
#endif

/* Tests the N child boxes at once; returns a bit mask of those entered
 * within [tnear, tfar] and their entry distances.  Single-ray traversal is
 * one chain of dependent node tests, so the test is kept short: with FMA one
 * fused plane * inv - c per plane (as Embree does), without it one
 * subtraction and one multiplication, the far scale folded into inv_far.
 *
 * Where the ISA has them cheap (RTK_SIMD_INT_ORDER_N: SSE4.1 for 4 wide,
 * AVX2 for 8) and the test is fused, the maxima, minima and the comparison
 * are done on the floats' bits as integers (as Embree does): one cycle each
 * instead of four on Intel cores, on the critical path of every node visit
 * (measured on dragon.ply, avx2, on an Intel VM: camera, diffuse and shadow
 * rays 8-10% faster).  The unfused test (sse41) would need three additions
 * for it (below), and on the AMD cores of the later development VM, where
 * the float minima and maxima take one cycle too, sse41 measured 3-10%
 * faster in the float order (rtktool bench, dragon and San Miguel, single
 * rays, three interleaved rounds), so it uses that.  That is the float order
 * for non-negative values; tnear and tfar are at least +0.0 (ray_pre_init
 * and its callers add +0.0, so -0.0 never appears), so tmin is exactly the
 * float maximum, and a negative far distance, which the integer minimum
 * passes on, rejects the box as it would as a float.  The one difference is
 * a far distance of exactly -0.0 with tmin = +0: the integer order rejects
 * the box, the float order enters it.  The fused form gives -0.0 only as
 * (-0) - (+0): a plane at zero and c_far exactly +0, which takes org * inv
 * within about 2^-125 of zero, and then the exact far distance is -org * inv
 * < 0: the box lies behind the origin, and rejecting it is exact.  The
 * sub-mul form gives -0.0 for an origin exactly on a far plane (x - x is
 * +0, times a negative reciprocal), a box touched at t = 0 that must be
 * entered, so there the far distances get + 0.0 first. */
#if RTK_SIMD_HAS_FMA && !RTK_NODE_INT_ORDER
#error "the fused node test orders by bits: an FMA backend needs the integer ops at this node width"
#endif
#if !RTK_SIMD_HAS_FMA && RTK_NODE_INT_ORDER
#error "a backend without FMA gives its node test NaN distances (ray_pre_init), which only the float order drops"
#endif
static inline __attribute__((always_inline)) unsigned node_intersect(const node_t *n, const ray_pre *p, vnode tnear,
                                                                     vnode tfar, vnode *dist, int fused)
{
    vnode t0x, t0y, t0z, t1x, t1y, t1z;
    (void)fused;
#if RTK_SIMD_HAS_FMA
    if (fused) {
        /* c_near and c_far from memory at every node (see ray_mem) */
        t0x = vn_msub(PLANE(n, p->near_off[0]), p->ninv[0], vn_set1_at(&p->m->c[0]));
        t0y = vn_msub(PLANE(n, p->near_off[1]), p->ninv[1], vn_set1_at(&p->m->c[1]));
        t0z = vn_msub(PLANE(n, p->near_off[2]), p->ninv[2], vn_set1_at(&p->m->c[2]));
#if RTK_FUSED_FAR_ULPS
#define FUSED_INV_FAR p->ninv
#else
#define FUSED_INV_FAR p->ninv_far
#endif
        t1x = vn_msub(PLANE(n, p->far_off[0]), FUSED_INV_FAR[0], vn_set1_at(&p->m->c[4]));
        t1y = vn_msub(PLANE(n, p->far_off[1]), FUSED_INV_FAR[1], vn_set1_at(&p->m->c[5]));
        t1z = vn_msub(PLANE(n, p->far_off[2]), FUSED_INV_FAR[2], vn_set1_at(&p->m->c[6]));
#undef FUSED_INV_FAR
    } else
#endif
    {
        t0x = vn_mul(vn_sub(PLANE(n, p->near_off[0]), p->norg[0]), p->ninv[0]);
        t0y = vn_mul(vn_sub(PLANE(n, p->near_off[1]), p->norg[1]), p->ninv[1]);
        t0z = vn_mul(vn_sub(PLANE(n, p->near_off[2]), p->norg[2]), p->ninv[2]);
#if RTK_ROBUST
#define NORG_FAR p->norg_far
#else
#define NORG_FAR p->norg
#endif
        t1x = vn_mul(vn_sub(PLANE(n, p->far_off[0]), NORG_FAR[0]), p->ninv_far[0]);
        t1y = vn_mul(vn_sub(PLANE(n, p->far_off[1]), NORG_FAR[1]), p->ninv_far[1]);
        t1z = vn_mul(vn_sub(PLANE(n, p->far_off[2]), NORG_FAR[2]), p->ninv_far[2]);
#undef NORG_FAR
#if RTK_NODE_INT_ORDER
        /* + 0.0 turns the far distances' -0.0 into +0.0, the one value where
         * the integer order and the float order disagree here, and changes
         * nothing else: three additions beside the critical path buy integer
         * ops on it */
        const vnode zero = vn_set1(0.0f);
        /* and first a NaN far distance (0 * inf: a zero direction's origin
         * on the plane, ray_pre_init; robust layouts move their origins
         * off the planes, unless by exactly the move) becomes +inf, as the
         * float order drops it: min returns its second operand where
         * either is NaN */
        const vnode pinf = vn_set1(__builtin_inff());
        t1x = vn_min(t1x, pinf);
        t1y = vn_min(t1y, pinf);
        t1z = vn_min(t1z, pinf);
        t1x = vn_add(t1x, zero);
        t1y = vn_add(t1y, zero);
        t1z = vn_add(t1z, zero);
#endif
    }
#if RTK_NODE_INT_ORDER
    /* tmin <= tmax as integers is tmax + 1 > tmin: the mask of the boxes
     * entered in one comparison, with no inversion after it on the path
     * every node visit waits for (the one addition also takes the far
     * padding; the bits of tmax, at most those of +inf, cannot overflow). */
    const vnode tmin = vn_maxi(vn_maxi(t0x, t0y), vn_maxi(t0z, tnear));
    const vnode tmax = vn_mini(vn_mini(t1x, t1y), vn_mini(t1z, tfar));
    *dist = tmin;
    return (unsigned)vn_mask(vn_gti(vn_add_ulps(tmax, fused ? RTK_FUSED_FAR_ULPS * RTK_FAR_ULPS + 1 : 1), tmin));
#else
    /* A NaN far distance (a zero direction's slab with the origin on its
     * far plane, ray_pre_init) is dropped: the SSE min returns its second
     * operand where either is NaN, and tfar, never NaN, comes in as a
     * second operand last.  A NaN first operand leaves the other; a NaN
     * second one (y) takes x's bound along with it: a box more to visit,
     * never one fewer. */
    const vnode tmin = vn_max(vn_max(t0x, t0y), vn_max(t0z, tnear));
    const vnode tmax = vn_min(vn_min(t1x, t1y), vn_min(t1z, tfar));
    *dist = tmin;
    return (unsigned)vn_mask(vn_le(tmin, tmax));
#endif
}

/* Asks for the memory of child i of node n, hit, as Embree does for every
 * child it is about to visit or push: the four cache lines from the node,
 * or from the leaf's first block (for index leaves, their indices).  On
 * rays from random points of San Miguel's surface, 6-10% faster (scratch
 * program beside Embree, alternating passes); within the noise on rtktool
 * bench's sets, whose neighbouring rays find the tree in the caches.  The
 * address is the node's own prefetch[i] away (set by the builders): found
 * from the reference it took a dozen instructions, the node or the leaf
 * array's base and index, picked without a branch, which on the bunny's
 * bounce rays were 11% of the instructions per ray (callgrind).  Motion
 * blur nodes have no room for it and still do that. */
static inline __attribute__((always_inline)) void prefetch_child(const rtk_accel *accel, const node_t *n, int i)
{
#if RTK_MOTION
    const uint32_t ref = n->child[i];
    const uintptr_t leaf = (uintptr_t)accel->trisi + rtk_leaf_first(ref) * (uintptr_t)sizeof *accel->trisi;
    const uintptr_t node = (uintptr_t)accel->nodes + (ref & ~RTK_BVH4_LEAF_BIT) * (uintptr_t)sizeof(node_t);
    const uintptr_t is_leaf = -(uintptr_t)(ref >> 31); /* all ones for a leaf */
    const char *a = (const char *)((leaf & is_leaf) | (node & ~is_leaf));
    rtk_prefetch4(a);
#else
    (void)accel;
    rtk_prefetch_slot(n, n->prefetch[i]);
#endif
#if RTK_MOTION && RTK_BVHN == 8
    /* an 8-wide motion node's other three lines (for a leaf, the blocks
     * after its first, or its neighbour's) */
    __builtin_prefetch(a + 256);
    __builtin_prefetch(a + 320);
    __builtin_prefetch(a + 384);
#endif
}

typedef struct stack_entry {
    uint32_t ref;
    float dist;
} stack_entry;

/* Pushes the hit children farthest first, so the nearest is popped next:
 * an insertion sort straight onto the stack (at most N entries); each is
 * prefetched. */
static inline int push_children(const rtk_accel *accel, const node_t *n, unsigned mask, vnode dists,
                                stack_entry *stack, int sp)
{
    const uint32_t *child = n->child;
    _Alignas(32) float dist[RTK_BVHN];
    vn_store(dist, dists);
    const int base = sp;
    for (; mask; mask &= mask - 1) {
        const int i = __builtin_ctz(mask);
        const stack_entry e = {child[i], dist[i]};
        prefetch_child(accel, n, i);
        int j = sp++;
        while (j > base && stack[j - 1].dist < e.dist) { /* decreasing distance */
            stack[j] = stack[j - 1];
            j--;
        }
        stack[j] = e;
    }
    return sp;
}

/* Leaf block `index` as triangle4: the block itself, or for triangle4i
 * leaves a copy made in *scratch from the geometries' vertex buffers, with
 * the edges computed exactly as the triangle4 builder computes them (so both
 * layouts give the same answers to the bit).  An unused lane's three
 * vertices are one point: no area, never hit. */
#if RTK_MOTION
/* Motion blur: the block's vertices from the accel's copy of the time
 * steps around the ray's time, interpolated as (1 - f) * a + f * b (a at
 * f = 0 and b at f = 1 exactly; not fused, so every backend computes the
 * same floats, FMA or not), then the edges as the triangle4 builder
 * computes them.  An unused lane is NaN: never hit. */
static inline const block_t *leaf_block(const rtk_accel *accel, uint32_t index, block_t *scratch,
                                        const ray_pre *p)
{
    const rtk_triangle4i *t = &accel->trisi[index];
    vfloat4 v[3][4]; /* vertex, lane: x, y, z (and a float beyond), then transposed to vertex, axis */
    for (int lane = 0; lane < 4; lane++) {
        if (t->prim[lane] == RTK_BVH4_EMPTY) {
            v[0][lane] = v[1][lane] = v[2][lane] = vf4_set1(NAN);
            scratch->geom[lane] = RTK_BVH4_EMPTY;
            continue;
        }
        const rtk_mb_geometry *g = &accel->mb_geoms[t->geom[lane]];
        const float *a = g->vertices + 3 * (size_t)accel->segment;
        const size_t step = 3 * (size_t)g->steps;
        const uint32_t idx[3] = {t->v0[lane], t->v1[lane], t->v2[lane]};
        for (int k = 0; k < 3; k++) {
            const float *q = a + step * idx[k];
            v[k][lane] = vf4_add(vf4_mul(p->f4, vf4_loadu(q + 3)), vf4_mul(p->one_f4, vf4_loadu(q)));
        }
        scratch->geom[lane] = g->geom_id;
    }
    for (int k = 0; k < 3; k++)
        vf4_transpose(&v[k][0], &v[k][1], &v[k][2], &v[k][3]);
#if RTK_ROBUST
    /* the vertices themselves, for the watertight test */
    float *f = (float *)scratch;
    for (int k = 0; k < 3; k++)
        for (int a = 0; a < 3; a++)
            vf4_store(f + 12 * k + 4 * a, v[k][a]);
#else
    vf4_store(scratch->v0x, v[0][0]);
    vf4_store(scratch->v0y, v[0][1]);
    vf4_store(scratch->v0z, v[0][2]);
    vf4_store(scratch->e1x, vf4_sub(v[1][0], v[0][0]));
    vf4_store(scratch->e1y, vf4_sub(v[1][1], v[0][1]));
    vf4_store(scratch->e1z, vf4_sub(v[1][2], v[0][2]));
    vf4_store(scratch->e2x, vf4_sub(v[2][0], v[0][0]));
    vf4_store(scratch->e2y, vf4_sub(v[2][1], v[0][1]));
    vf4_store(scratch->e2z, vf4_sub(v[2][2], v[0][2]));
#endif
    memcpy(scratch->prim, t->prim, sizeof t->prim);
    return scratch;
}
#define LEAF_BLOCK(accel, index, scratch) leaf_block(accel, index, scratch, p)
#else
#define LEAF_BLOCK(accel, index, scratch) leaf_block(accel, index, scratch)
static inline const block_t *leaf_block(const rtk_accel *accel, uint32_t index, block_t *scratch)
{
#if RTK_LEAF_INDEXED
    const rtk_triangle4i *t = &accel->trisi[index];
    for (int lane = 0; lane < 4; lane++) {
        const rtk_leaf_geometry *g = &accel->geoms[t->geom[lane]];
        const float *v0 = (const float *)(g->vertices + (size_t)t->v0[lane] * g->stride);
        const float *v1 = (const float *)(g->vertices + (size_t)t->v1[lane] * g->stride);
        const float *v2 = (const float *)(g->vertices + (size_t)t->v2[lane] * g->stride);
#if RTK_ROBUST
        /* an unused lane's three vertices are one point: det = 0, never hit */
        rtk_triangle4v_set_lane(scratch, lane, v0, v1, v2, g->geom_id, t->prim[lane]);
#else
        rtk_triangle4_set_lane(scratch, lane, v0, v1, v2, g->geom_id, t->prim[lane]);
#endif
    }
    return scratch;
#else
    (void)scratch;
    return (const block_t *)&accel->tris[index];
#endif
}
#endif

#include "traverse_leaf.h"

/* Pops the nearest pending entry whose entry distance is within tfar into
 * *cur, dropping those beyond it; 0 when the stack runs out. */
static inline int pop_in_range(const stack_entry *stack, int *sp, float tfar_s, uint32_t *cur)
{
    while (*sp > 0) {
        const stack_entry e = stack[--*sp];
        if (e.dist <= tfar_s) {
            *cur = e.ref;
            return 1;
        }
    }
    return 0;
}

/* Descends from `cur` through inner nodes until it reaches a leaf, following
 * the nearest child hit and pushing the others (farthest first; with anyhit,
 * a constant, the first child hit and the others unsorted).  Returns 0 when
 * no child is hit on the way and the stack is empty, else 1 with the leaf in
 * *leaf.  Entries popped whose distance is beyond tfar are dropped. */
static inline __attribute__((always_inline)) int next_leaf(const rtk_accel *accel, const ray_pre *p, vnode tnear,
                                                           float tfar_s, vnode tfar, stack_entry *stack, int *sp_io,
                                                           uint32_t *cur_io, int anyhit, int fused)
{
    int sp = *sp_io;
    uint32_t cur = *cur_io;
    for (;;) {
        if (cur & RTK_BVH4_LEAF_BIT) {
            *sp_io = sp;
            *cur_io = cur;
            return 1;
        }
        const node_t *n = &BVHN_NODES(accel)[cur];
        /* The child references' cache line is asked for now, beside the
         * planes', not first once the box test is done. */
        const uint32_t *child = n->child;
        __builtin_prefetch(child);
        vnode dists;
        unsigned mask = node_intersect(n, p, tnear, tfar, &dists, fused);
        if (mask && !(mask & (mask - 1))) { /* one child: no stack traffic */
            cur = child[__builtin_ctz(mask)];
            continue;
        }
        if (mask && anyhit) {
            /* any hit ends the ray wherever it is: no sorting (tfar never
             * shrinks, so nothing pushed is ever out of range).  The last
             * child hit goes first, then the others from the second last
             * down, Embree's order.  The SAH builder's 8-wide nodes end with
             * the children with the fewest triangles per box area
             * (build_sah.c, child_slots), its 4-wide ones with the upper
             * half of each split.  First-slot-first (in 4-wide and 8-wide
             * nodes then both in split order) took twice the instructions
             * and ten times the L1 misses of Embree per ray on San Miguel's
             * shadow rays (callgrind, 20,000 rays along (0.3, 0.8, 0.5)
             * from points on the surface: 1266 against 594; last first:
             * 751), and 1.15 times them on the dragon's. */
            const int last = 31 - __builtin_clz(mask);
            cur = child[last];
            for (mask ^= 1u << last; mask; mask &= mask - 1) {
                const int i = __builtin_ctz(mask);
                stack[sp++] = (stack_entry){child[i], 0.0f};
                prefetch_child(accel, n, i);
            }
            continue;
        }
        if (mask) {
            _Alignas(32) float dist[RTK_BVHN];
            vn_store(dist, dists);
            const int i0 = __builtin_ctz(mask);
            mask &= mask - 1;
            const int i1 = __builtin_ctz(mask);
            mask &= mask - 1;
            if (!mask) { /* two children: push the far one, go to the near one */
                const int near = dist[i1] < dist[i0] ? i1 : i0, far = i0 + i1 - near;
                prefetch_child(accel, n, far);
                prefetch_child(accel, n, near);
                stack[sp++] = (stack_entry){child[far], dist[far]};
                cur = child[near];
                continue;
            }
            sp = push_children(accel, n, (1u << i0) | (1u << i1) | mask, dists, stack, sp);
        }
        if (!pop_in_range(stack, &sp, tfar_s, &cur))
            return 0;
    }
}

/* The closest hit found so far by one ray: the leaf block's index, the lane
 * in it (-1: no hit yet), and the barycentrics (the distance is the ray's
 * tfar). */
typedef struct closest_hit {
    uint32_t leaf;
    int lane;
    float u, v;
} closest_hit;
#define CLOSEST_HIT_NONE ((closest_hit){.lane = -1})

/* Closest hit below `root` within [tnear, *tfar]: on a hit closer than *tfar,
 * updates *tfar and *best.  The packet kernels call this too, for rays they
 * finish alone. */
static inline __attribute__((always_inline)) void closest_from_(const rtk_accel *accel, uint32_t root,
                                                                  const ray_pre *p, float tnear_s, float *tfar_io,
                                                                  closest_hit *best, int fused, const feat_ctx *f,
                                                                  int masks_only)
{
    /* The triangle tests take the lower lanes of the node tests' interval
     * (-0.0 made +0.0 there, which compares the same): two vectors fewer
     * to keep in registers. */
    const vnode ntnear = vn_set1(tnear_s + 0.0f); /* -0.0 -> +0.0 for node_intersect */
    const vfloat4 tnear = vn_low4(ntnear);
    float tfar_s = *tfar_io;
    vnode ntfar = vn_set1(tfar_s + 0.0f);
    vfloat4 tfar = vn_low4(ntfar);

    stack_entry stack[RTK_BVHN_STACK_SIZE(RTK_BVHN)];
    int sp = 0;
    uint32_t cur = root;
    leaf_ray lr;
    if (!next_leaf(accel, p, ntnear, tfar_s, ntfar, stack, &sp, &cur, 0, fused))
        return; /* no leaf entered: *tfar_io and *best as they were */
    leaf_ray_init(&lr, p);
    for (;;) {
        const uint32_t first = rtk_leaf_first(cur), end = first + rtk_leaf_blocks(cur);
        for (uint32_t block = first; block < end; block++) {
            block_t scratch;
            const block_t *t = LEAF_BLOCK(accel, block, &scratch);
            tri4_hit h;
            unsigned mask = triangle4_intersect(t, p, &lr, tnear, tfar, &h);
            if (f && mask)
                mask = masks_only ? mask_lanes(t, mask, f) : accept_closest(t, f, &h, block_hit_floor(t, p), mask, tnear_s, tfar_s);
            float t_lane;
            int lane;
            if (mask && (lane = block_nearest(t, p, &h, mask, tnear_s, tfar_s, &t_lane, &best->u, &best->v)) >= 0) {
                best->leaf = block;
                best->lane = lane;
                tfar_s = t_lane;
                ntfar = vn_set1(tfar_s + 0.0f);
                tfar = vn_low4(ntfar);
            }
        }
        if (!pop_in_range(stack, &sp, tfar_s, &cur))
            break;
        if (!next_leaf(accel, p, ntnear, tfar_s, ntfar, stack, &sp, &cur, 0, fused))
            break;
    }
    *tfar_io = tfar_s;
}

/* Any hit below `root` within [tnear, tfar]: 1 when there is one.  Spelled
 * once and made twice by the preprocessor, ACCEPT deciding a block's lanes
 * hit (mask, h): 1 in the usual traversal, accept_any in the features'.
 * (With the features' test in its source, even under a constant-NULL f
 * that removes it, GCC 12 kept three more vectors of the usual loop in
 * memory: a 96-byte bigger frame and 31 more instructions per shadow ray
 * on dragon.ply, bench/occluded_instructions.c.) */
#define RTK_ANY_FROM(name, ACCEPT)                                                                                    \
    static inline __attribute__((always_inline)) int name(const rtk_accel *accel, uint32_t root, const ray_pre *p,  \
                                                          float tnear_s, float tfar_s, int fused, const feat_ctx *f) \
    {                                                                                                                \
        const vnode ntnear = vn_set1(tnear_s + 0.0f), ntfar = vn_set1(tfar_s + 0.0f); /* no -0.0 */                  \
        const vfloat4 tnear = vn_low4(ntnear), tfar = vn_low4(ntfar); /* as in closest_from_ */                     \
        stack_entry stack[RTK_BVHN_STACK_SIZE(RTK_BVHN)];                                                            \
        int sp = 0;                                                                                                  \
        uint32_t cur = root;                                                                                         \
        leaf_ray lr;                                                                                                 \
        (void)f;                                                                                                     \
        if (!next_leaf(accel, p, ntnear, tfar_s, ntfar, stack, &sp, &cur, 1, fused))                                 \
            return 0;                                                                                                \
        leaf_ray_init(&lr, p);                                                                                       \
        for (;;) {                                                                                                   \
            const uint32_t first = rtk_leaf_first(cur), end = first + rtk_leaf_blocks(cur);                          \
            for (uint32_t block = first; block < end; block++) {                                                     \
                tri4_hit h;                                                                                          \
                block_t scratch;                                                                                     \
                const block_t *t = LEAF_BLOCK(accel, block, &scratch);                                               \
                const unsigned mask = triangle4_intersect(t, p, &lr, tnear, tfar, &h);                               \
                if (mask && (ACCEPT))                                                                                \
                    return 1;                                                                                        \
            }                                                                                                        \
            if (!pop_in_range(stack, &sp, tfar_s, &cur))                                                             \
                return 0;                                                                                            \
            if (!next_leaf(accel, p, ntnear, tfar_s, ntfar, stack, &sp, &cur, 1, fused))                             \
                return 0;                                                                                            \
        }                                                                                                            \
    }
RTK_ANY_FROM(any_from_usual_, 1)
RTK_ANY_FROM(any_from_features_, accept_any(t, f, &h, mask, tnear_s, tfar_s))
RTK_ANY_FROM(any_from_masks_, mask_lanes(t, mask, f) != 0)

/* The traversals, specialised once for the fused node test and once for
 * the subtract-then-multiply one (ray_pre.fma), so the choice is made once
 * per ray, not at every node; and once more for rays that test their
 * candidates against masks, culling and filters (ray_pre.feat), so the
 * usual path holds no call that would make the compiler keep the ray's
 * vectors in memory (with the call in it, occluded1 lost 7% on dragon's
 * shadow rays, rtktool bench). */
static __attribute__((noinline)) void closest_from_feat(const rtk_accel *accel, uint32_t root, const ray_pre *p,
                                                        float tnear_s, float *tfar_io, closest_hit *best,
                                                        const feat_ctx *f)
{
#if RTK_SIMD_HAS_FMA
    closest_from_(accel, root, p, tnear_s, tfar_io, best, p->fma, f, 0);
#else
    closest_from_(accel, root, p, tnear_s, tfar_io, best, 0, f, 0);
#endif
}

static __attribute__((noinline)) int any_from_feat(const rtk_accel *accel, uint32_t root, const ray_pre *p,
                                                   float tnear_s, float tfar_s, const feat_ctx *f)
{
#if RTK_SIMD_HAS_FMA
    return any_from_features_(accel, root, p, tnear_s, tfar_s, p->fma, f);
#else
    return any_from_features_(accel, root, p, tnear_s, tfar_s, 0, f);
#endif
}

static void closest_from_plain(const rtk_accel *accel, uint32_t root, const ray_pre *p, float tnear_s,
                               float *tfar_io, closest_hit *best)
{
#if RTK_SIMD_HAS_FMA
    if (__builtin_expect(p->fma, 1)) {
        closest_from_(accel, root, p, tnear_s, tfar_io, best, 1, NULL, 0);
        return;
    }
#endif
    closest_from_(accel, root, p, tnear_s, tfar_io, best, 0, NULL, 0);
}

static int any_from_plain(const rtk_accel *accel, uint32_t root, const ray_pre *p, float tnear_s, float tfar_s)
{
#if RTK_SIMD_HAS_FMA
    if (__builtin_expect(p->fma, 1))
        return any_from_usual_(accel, root, p, tnear_s, tfar_s, 1, NULL);
#endif
    return any_from_usual_(accel, root, p, tnear_s, tfar_s, 0, NULL);
}

/* The traversals for a ray with feat_init's f: the usual ones when it is
 * NULL.  (The choice is made here, outside them: with the branch to the
 * features' traversal inside, GCC kept more of the usual loop's vectors
 * in memory, 36 instructions more per shadow ray on dragon.ply.) */
static inline void closest_from(const rtk_accel *accel, uint32_t root, const ray_pre *p, float tnear_s,
                                float *tfar_io, closest_hit *best, const feat_ctx *f)
{
    if (__builtin_expect(f != NULL, 0))
        closest_from_feat(accel, root, p, tnear_s, tfar_io, best, f);
    else
        closest_from_plain(accel, root, p, tnear_s, tfar_io, best);
}

static inline int any_from(const rtk_accel *accel, uint32_t root, const ray_pre *p, float tnear_s, float tfar_s,
                           const feat_ctx *f)
{
    return __builtin_expect(f != NULL, 0) ? any_from_feat(accel, root, p, tnear_s, tfar_s, f)
                                          : any_from_plain(accel, root, p, tnear_s, tfar_s);
}

/* The geometric normal and ids of a closest hit (p: the ray's, for the
 * time of a moving leaf; unused, and may be NULL, elsewhere). */
static inline void closest_hit_record(const rtk_accel *accel, const closest_hit *best, const ray_pre *p, float ng[3],
                                      uint32_t *prim, uint32_t *geom)
{
    (void)p;
    float v0[3], e1[3], e2[3];
    block_t scratch;
    const block_t *t = LEAF_BLOCK(accel, best->leaf, &scratch);
    lane_triangle(t, best->lane, v0, e1, e2);
    rtk_triangle_normal(e1, e2, ng);
    *prim = t->prim[best->lane];
    *geom = t->geom[best->lane];
}

/* A single ray's closest hit (at distance tfar) into its ray and hit. */
static inline void closest_hit_store(const rtk_accel *accel, const closest_hit *best, const ray_pre *p, float tfar,
                                     rtk_rayhit *rayhit)
{
    float ng[3];
    closest_hit_record(accel, best, p, ng, &rayhit->hit.primID, &rayhit->hit.geomID);
    rayhit->ray.tfar = tfar;
    rayhit->hit.Ng_x = ng[0];
    rayhit->hit.Ng_y = ng[1];
    rayhit->hit.Ng_z = ng[2];
    rayhit->hit.u = best->u;
    rayhit->hit.v = best->v;
    rayhit->hit.instID = RTK_INVALID_GEOMETRY_ID;
}

/* After a closest hit is stored: the hit on a quad's half as on the quad
 * (attrs: the accel that holds the attributes, the top one of a moving
 * tree); for single rays and packet lanes alike. */
static inline void closest_hit_quad(const rtk_accel *attrs, uint32_t geom, uint32_t *prim, float *u, float *v)
{
    if (__builtin_expect(attrs->quads != 0, 0))
        rtk_quad_hit(attrs->attrs, geom, prim, u, v);
}

/* A single ray's closest hit, if it found one, into its ray and hit:
 * leaves is the accel that holds the block (a moving tree's segment),
 * attrs the one that holds the attributes (its top accel). */
static inline void closest_hit_write(const rtk_accel *leaves, const rtk_accel *attrs, const closest_hit *best,
                                     const ray_pre *p, float tfar, rtk_rayhit *rayhit)
{
    if (best->lane < 0)
        return;
    closest_hit_store(leaves, best, p, tfar, rayhit);
    closest_hit_quad(attrs, rayhit->hit.geomID, &rayhit->hit.primID, &rayhit->hit.u, &rayhit->hit.v);
}

/* Whether the node test is the fused one (ray_pre.fma rays where the
 * SIMD layer has FMA): the constant of the usual ray's paths. */
#if RTK_SIMD_HAS_FMA
#define BVHN_FUSED 1
#else
#define BVHN_FUSED 0
#endif

#if !RTK_MOTION /* (traverse_bvh4mb.c has its own entry points) */
/* The entry points keep the usual ray (no features, and with FMA an
 * origin the fused node test can take) on a path where the traversal is
 * inlined and the ray's precomputed vectors are the function's own values,
 * so the compiler keeps them in registers or spills only those that do not
 * fit, instead of writing all of them to a struct for a callee to read
 * back.  A ray with masks, culling or filters takes a copy of that path
 * with the features' test (intersect1_feat, occluded1_feat); with FMA, a ray
 * the fused test cannot take goes through a function of its own that sets
 * up its ray again (the features' traversal through a pointer to the ray: a
 * San Miguel shadow ray with a geometry mask set cost 0.72x of one without,
 * then 0.85x; rtktool bench --only features).  The entry points decide
 * which before their own frame is set up, and jump to the features' copies
 * (see intersect1_masks). */
#if RTK_SIMD_HAS_FMA
static __attribute__((noinline)) void intersect1_other(const rtk_accel *accel, rtk_rayhit *rayhit,
                                                       const feat_ctx *f)
{
    ray_pre p;
    ray_mem pm;
    ray_pre_init(&p, &pm, &rayhit->ray, accel);
    closest_hit best = CLOSEST_HIT_NONE;
    float tfar = rayhit->ray.tfar;
    closest_from(accel, accel->root, &p, rayhit->ray.tnear, &tfar, &best, f);
    closest_hit_write(accel, accel, &best, &p, tfar, rayhit);
}

static __attribute__((noinline)) void occluded1_other(const rtk_accel *accel, rtk_ray *ray, const feat_ctx *f)
{
    ray_pre p;
    ray_mem pm;
    ray_pre_init(&p, &pm, ray, accel);
    if (any_from(accel, accel->root, &p, ray->tnear, ray->tfar, f))
        ray->tfar = -INFINITY;
}
#endif

/* The inlined traversal of the entry points, for the usual ray (f NULL)
 * and for a ray with masks, culling or filters (f), which is made once with
 * masks alone tested inline (masks_only: no culling, no filters in the
 * tree) and once with the test that calls out */
static inline __attribute__((always_inline)) void intersect1_feat_(const rtk_accel *accel, rtk_rayhit *rayhit,
                                                                   const feat_ctx *f, int masks_only)
{
    ray_pre p;
    ray_mem pm;
    ray_pre_init(&p, &pm, &rayhit->ray, accel);
#if RTK_SIMD_HAS_FMA
    if (__builtin_expect(!p.fma, 0)) {
        intersect1_other(accel, rayhit, f);
        return;
    }
#endif
    closest_hit best = CLOSEST_HIT_NONE;
    float tfar = rayhit->ray.tfar;
    closest_from_(accel, accel->root, &p, rayhit->ray.tnear, &tfar, &best, BVHN_FUSED, f, masks_only);
    closest_hit_write(accel, accel, &best, &p, tfar, rayhit);
}

/* A ray that needs the features (ray_feat), its context made here: the
 * entry points call these with nothing of their own to keep, as tail calls
 * (jumps) before they set up the usual path's frame.  (Called with a
 * context made in the entry point, a ray through a tree with masks paid for
 * two frames of the traversal's size: San Miguel's root-missing rays took
 * 13.4 ns per call against 8.4 ns without masks, a scratch program.) */
static __attribute__((noinline)) void intersect1_masks(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q)
{
    feat_ctx fc;
    intersect1_feat_(accel, rayhit, feat_init(&fc, &rayhit->ray, accel, q), 1);
}

static __attribute__((noinline)) void intersect1_feat(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q)
{
    feat_ctx fc;
    intersect1_feat_(accel, rayhit, feat_init(&fc, &rayhit->ray, accel, q), 0);
}

/* The usual ray: no features' test at all.  A function of its own, which
 * the entry point jumps to: inlined there, GCC set up its frame before the
 * entry point's test for the features (occluded1's it sets up after). */
static __attribute__((noinline)) void intersect1_usual(const rtk_accel *accel, rtk_rayhit *rayhit)
{
    intersect1_feat_(accel, rayhit, NULL, 0);
}

static inline __attribute__((always_inline)) void occluded1_feat_(const rtk_accel *accel, rtk_ray *ray,
                                                                  const feat_ctx *f, int masks_only)
{
    ray_pre p;
    ray_mem pm;
    ray_pre_init(&p, &pm, ray, accel);
#if RTK_SIMD_HAS_FMA
    if (__builtin_expect(!p.fma, 0)) {
        occluded1_other(accel, ray, f);
        return;
    }
#endif
    if (masks_only ? any_from_masks_(accel, accel->root, &p, ray->tnear, ray->tfar, BVHN_FUSED, f)
                   : any_from_features_(accel, accel->root, &p, ray->tnear, ray->tfar, BVHN_FUSED, f))
        ray->tfar = -INFINITY;
}

static __attribute__((noinline)) void occluded1_masks(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q)
{
    feat_ctx fc;
    occluded1_feat_(accel, ray, feat_init(&fc, ray, accel, q), 1);
}

static __attribute__((noinline)) void occluded1_feat(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q)
{
    feat_ctx fc;
    occluded1_feat_(accel, ray, feat_init(&fc, ray, accel, q), 0);
}

/* masks alone (ray_feat's feat): no culling asked by the ray, no filter in
 * the tree */
static inline int masks_alone(const rtk_accel *accel, unsigned feat)
{
    return !(feat & (RTK_FEAT_CULL | RTK_FEAT_QUERY_FILTER)) && !accel->attr_filter;
}

void BVHN_INTERSECT1(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q)
{
    if (accel->root == RTK_BVH4_EMPTY)
        return;
    const unsigned feat = ray_feat(accel, &rayhit->ray) | query_feat(q);
    if (__builtin_expect(feat != 0, 0)) {
        if (masks_alone(accel, feat))
            intersect1_masks(accel, rayhit, q);
        else
            intersect1_feat(accel, rayhit, q);
        return;
    }
    intersect1_usual(accel, rayhit);
}

void BVHN_OCCLUDED1(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q)
{
    if (accel->root == RTK_BVH4_EMPTY)
        return;
    const unsigned feat = ray_feat(accel, ray) | query_feat(q);
    if (__builtin_expect(feat != 0, 0)) {
        if (masks_alone(accel, feat))
            occluded1_masks(accel, ray, q);
        else
            occluded1_feat(accel, ray, q);
        return;
    }
    ray_pre p;
    ray_mem pm;
    ray_pre_init(&p, &pm, ray, accel);
#if RTK_SIMD_HAS_FMA
    if (__builtin_expect(!p.fma, 0)) {
        occluded1_other(accel, ray, NULL);
        return;
    }
#endif
    if (any_from_usual_(accel, accel->root, &p, ray->tnear, ray->tfar, BVHN_FUSED, NULL))
        ray->tfar = -INFINITY;
}
#endif
