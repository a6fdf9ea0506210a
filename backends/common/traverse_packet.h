/*
 * Packet traversal of the bvhN.triangle4 layouts, bvh4.triangle4i and the
 * robust ones (bvhN.triangle4v, bvh4.triangle4i.robust: the watertight test
 * and padded boxes of traverse_bvhn.h's RTK_ROBUST): K rays (K = 4 or 8) through
 * N-wide nodes, closest hit and any hit, in the hybrid scheme of Embree
 * (Benthin, Wald, Woop, Ernst, Mark: "Combining Single and Packet-Ray
 * Tracing for Arbitrary Ray Distributions on the Intel MIC Architecture",
 * 2012): the packet descends together while enough of its rays agree, and
 * once a popped subtree is wanted by few rays, each of those finishes it
 * alone with the single-ray kernel.
 *
 * A template included after traverse_bvhn.h (whose single-ray routines it
 * reuses) with RTK_PACKET set to K; it defines the kernels
 * rtk_bvhN_intersectK / rtk_bvhN_occludedK.  One child box is tested against
 * all K rays at a time; the triangles of a leaf are tested one at a time
 * against all K rays.  The arithmetic is that of the single-ray kernels lane
 * by lane (slabs with the conservative far scale, the same Moeller-Trumbore
 * operations in the same order, the same clamp of t), so a ray gets the same
 * answer in a packet as alone, except which of two triangles hit at exactly
 * the same t is reported.
 *
 * When the packet's rays agree on the signs of their direction components
 * (camera rays nearly always do), a node's N boxes are first tested at once
 * against the packet's frustum, as in Embree's path for coherent rays: per
 * axis the extreme reciprocals and origins over the rays give a near
 * distance no greater and a far distance no smaller than any ray's, since
 * rounding is monotone.  Only the boxes the frustum lets through are tested
 * ray by ray, then with exactly the single-ray kernel's slab arithmetic.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#if !defined(RTK_BVHN)
#error "include traverse_bvhn.h first"
#endif

#if RTK_PACKET == 4
#define vk vfloat4
#define vkb vbool4
#define rayhitK rtk_rayhit4
#define rayK rtk_ray4
#define VK(op) vf4_##op
#define VKB(op) vb4_##op
/* Embree's switch thresholds: go single-ray at this many active rays or fewer */
#define PK_SWITCH 3
#elif RTK_PACKET == 8
#define vk vfloat8
#define vkb vbool8
#define rayhitK rtk_rayhit8
#define rayK rtk_ray8
#define VK(op) vf8_##op
#define VKB(op) vb8_##op
#define PK_SWITCH (RTK_BVHN == 4 ? 5 : 7)
#else
#error "define RTK_PACKET to 4 or 8"
#endif
/* With the frustum test a packet pays less per node, and on 8-wide nodes or
 * with 8 rays it measures best staying together until at most 2 rays are
 * left (bench primary8 on dragon.ply, avx2: 10.9 Mrays/s at 0 or 2, 10.5 at
 * 4, 10.0 at 7; compact scenes, 4-wide nodes: 9.0 at 2, 8.9 at 3, 8.2 at
 * 5); 4 rays on 4-wide nodes (compact scenes, and sse41's default tree when
 * this was measured) keep the usual threshold. */
#define PK_SWITCH_FRUSTUM (RTK_BVHN == 8 || RTK_PACKET == 8 ? 2 : PK_SWITCH)

#define PK_NAME_(n, k, what) rtk_bvh##n##_##what##k
#define PK_NAME(n, k, what) PK_NAME_(n, k, what)
#define PK_INTERSECT RTK_SYM(PK_NAME(BVHN_TAG, RTK_PACKET, intersect))
#define PK_INTERSECT_EXACT RTK_SYM(RTK_CAT(PK_NAME(BVHN_TAG, RTK_PACKET, intersect), _exact))
#define PK_OCCLUDED RTK_SYM(PK_NAME(BVHN_TAG, RTK_PACKET, occluded))
/* static helpers, one set per packet width */
#define PK_(name) RTK_CAT(RTK_CAT(name, _k), RTK_PACKET)

/* The packet, loaded once.  rinv_lo / rinv_hi are the reciprocal direction
 * for the lower and upper planes, the one of the far plane (by the sign of
 * the direction) scaled by RTK_BOX_FAR_SCALE, as inv_far in ray_pre. */
typedef struct PK_(packet_pre) {
    vk org[3], dir[3], rinv_lo[3], rinv_hi[3];
    vk rinv_exact[3]; /* 1 / dir (tiny components raised as in ray_pre_init), before the scales */
    /* the origins for the lower and upper planes: org, or in robust layouts
     * org moved by the padding (ray_pre_init): + for the lower, - for the
     * upper */
    vk org_lo[3], org_hi[3];
#if RTK_ROBUST
    /* the watertight test per ray: the permuted axes as selection masks
     * (axis k of permuted axis j is x where is_x[j], y where is_y[j], else
     * z), the permuted origin and the shear */
    vkb is_x[3], is_y[3];
    vk worg[3], sx, sy, sz;
#endif
#if RTK_SIMD_HAS_FMA
    vk c_lo[3], c_hi[3]; /* org * rinv moved toward the near side, as c_near / c_far in ray_pre */
#endif
    vk tnear;
    /* Packets whose active rays agree on the sign of each direction
     * component (camera rays nearly always do) get a frustum test first:
     * one N-wide test of a node's boxes bounding what every ray of the
     * packet can see (see frustum_intersect), after which only the children
     * it lets through are tested ray by ray, with the single-ray kernel's
     * arithmetic (near and far planes by the shared signs). */
    int frustum;
    size_t near_off[3], far_off[3]; /* as in ray_pre */
    /* The frustum's bounds are kept as floats and broadcast where
     * frustum_intersect reads them (one load either way): stored as
     * vectors they cost the set-up a broadcast and a store each. */
#if RTK_FUSED_FAR_ULPS
    /* (fused: both planes' reciprocals are rinv_exact, and the bounds are
     * the reductions' lanes as they come, see PK_FR) */
    vk cn[3], cf[3]; /* per ray: c_near and c_far of ray_pre */
    _Alignas(32) float fr_lo[8], fr_hi[8];
#elif RTK_SIMD_HAS_FMA
    vk rn[3], rf[3]; /* per ray: the near and far planes' reciprocals */
    vk cn[3], cf[3]; /* per ray: c_near and c_far of ray_pre */
    float fr_cn_max[3], fr_cf_min[3];
#else
    vk rn[3], rf[3];          /* per ray: the near and far planes' reciprocals */
    vk on[3], of[3];          /* per ray: the near and far planes' origins */
    float fr_on[3], fr_of[3]; /* the origins giving the least near and greatest far distance */
#endif
#if !RTK_FUSED_FAR_ULPS
    float fr_rn_min[3], fr_rn_max[3], fr_rf_min[3], fr_rf_max[3];
    float fr_tnear;
#endif
} PK_(packet_pre);

/* Whether the subtract-then-multiply box tests give the zero directions
 * +-inf reciprocals (packet_pre_init), as ray_pre_init does: without FMA
 * (with it, packets with such rays go as a stream, PK_(scattered)).  The
 * robust layouts too: their padded origins keep a far distance of 0 off a
 * ray along a face, but with +-1e18 not far enough for a tree some 1e-7
 * across. */
#define PK_ZERO_DIR_INF (!RTK_SIMD_HAS_FMA)

/* The lanes of d below 1e-18 in magnitude: a zero direction component, as
 * ray_pre_init treats it. */
static inline vkb PK_(zero_dir)(vk d)
{
    return VK(lt)(VK(abs)(d), VK(set1)(RTK_ZERO_DIR));
}

/* The per-ray reciprocals of the near and far planes on axis k, and the
 * frustum's bounds, wherever the configuration keeps them. */
#if RTK_FUSED_FAR_ULPS
#define PK_RN(p, k) ((p)->rinv_exact[k])
#define PK_RF(p, k) ((p)->rinv_exact[k])
/* the reductions' lanes (frustum_init): least 0-2 the reciprocals, 3-5
 * the far planes' c, 6 tnear; greatest 0-2 the reciprocals, 3-5 the near
 * planes' c */
#define PK_FR_RN_MIN(p, k) ((p)->fr_lo[k])
#define PK_FR_RN_MAX(p, k) ((p)->fr_hi[k])
#define PK_FR_RF_MIN(p, k) ((p)->fr_lo[k])
#define PK_FR_RF_MAX(p, k) ((p)->fr_hi[k])
#define PK_FR_CN_MAX(p, k) ((p)->fr_hi[3 + (k)])
#define PK_FR_CF_MIN(p, k) ((p)->fr_lo[3 + (k)])
#define PK_FR_TNEAR(p) ((p)->fr_lo[6])
#else
#define PK_RN(p, k) ((p)->rn[k])
#define PK_RF(p, k) ((p)->rf[k])
#define PK_FR_RN_MIN(p, k) ((p)->fr_rn_min[k])
#define PK_FR_RN_MAX(p, k) ((p)->fr_rn_max[k])
#define PK_FR_RF_MIN(p, k) ((p)->fr_rf_min[k])
#define PK_FR_RF_MAX(p, k) ((p)->fr_rf_max[k])
#define PK_FR_CN_MAX(p, k) ((p)->fr_cn_max[k])
#define PK_FR_CF_MIN(p, k) ((p)->fr_cf_min[k])
#define PK_FR_TNEAR(p) ((p)->fr_tnear)
#endif

/* Sets up the frustum of a packet whose active rays share their direction
 * signs (else leaves p->frustum 0).  For each axis the bounds are over the
 * active rays: the least and greatest near- and far-plane reciprocals, and
 * the extreme c (or origin) that gives the least near and the greatest far
 * distance.  frustum_intersect combines them so that its near distance is
 * never above and its far distance never below what any of the rays computes
 * (rounding is monotone), so the frustum never drops a box a ray enters.
 * The bounds are lane reductions with the inactive lanes set to the
 * reduction's identity (none of the active lanes is NaN: the core passes
 * only valid rays). */
#if RTK_ROBUST
#define PK_NEAR_SCALE (1.0f - RTK_ROBUST_REL)
#define PK_FAR_SCALE (RTK_BOX_FAR_SCALE + RTK_ROBUST_REL)
#else
#define PK_NEAR_SCALE 1.0f
#define PK_FAR_SCALE RTK_BOX_FAR_SCALE
#endif
static inline void PK_(frustum_init)(PK_(packet_pre) *p, vkb active)
{
    static const size_t lower[3] = {offsetof(node_t, lower_x), offsetof(node_t, lower_y), offsetof(node_t, lower_z)};
    static const size_t upper[3] = {offsetof(node_t, upper_x), offsetof(node_t, upper_y), offsetof(node_t, upper_z)};
    const vk zero = VK(set1)(0.0f), pinf = VK(set1)(INFINITY), ninf = VK(set1)(-INFINITY);
    const unsigned all = (unsigned)VKB(mask)(active);
    p->frustum = 0;
    if (!all)
        return;
    for (int k = 0; k < 3; k++) {
        /* (the exact reciprocal has the sign of rinv_lo and rinv_hi) */
        const unsigned neg = (unsigned)VKB(mask)(VK(lt)(p->rinv_exact[k], zero)) & all;
        if (neg && neg != all)
            return;
        const int n = neg != 0;
        p->near_off[k] = n ? upper[k] : lower[k];
        p->far_off[k] = n ? lower[k] : upper[k];
#if RTK_FUSED_FAR_ULPS
        /* the single-ray kernel's fused distances (ray_pre_init): both
         * planes take the exact reciprocal (the near scale is 1: rn and rf
         * are rinv_exact itself, PK_RN and PK_RF), c moved
         * by the padding up for the near plane and down for the far one,
         * whose comparison is then RTK_FAR_ULPS up (box_intersect_octant);
         * packet_pre_init's c_lo and c_hi, whichever is near, are c + e
         * to the bit, so they are not made for a packet with a frustum */
        {
            const vk c = VK(mul)(p->org[k], p->rinv_exact[k]);
            const vk e = VK(add)(VK(mul)(VK(abs)(c), VK(set1)(0x1p-22f)), VK(set1)(0x1p-126f));
            p->cn[k] = VK(add)(c, e);
            p->cf[k] = VK(sub)(c, e);
        }
#else
        p->rn[k] = n ? p->rinv_hi[k] : p->rinv_lo[k];
        p->rf[k] = n ? p->rinv_lo[k] : p->rinv_hi[k];
#endif
#if RTK_SIMD_HAS_FMA
#if !RTK_FUSED_FAR_ULPS
        p->cn[k] = n ? p->c_hi[k] : p->c_lo[k];
        p->cf[k] = n ? p->c_lo[k] : p->c_hi[k];
#endif
        /* out of range products: the single-ray kernel would not use FMA */
        const vk big = VK(set1)(0x1p126f);
        const unsigned ok = (unsigned)VKB(mask)(VKB(and)(VK(le)(VK(abs)(p->cn[k]), big), VK(le)(VK(abs)(p->cf[k]), big)));
        if ((ok & all) != all)
            return;
#else
        p->on[k] = n ? p->org_hi[k] : p->org_lo[k];
        p->of[k] = n ? p->org_lo[k] : p->org_hi[k];
#endif
    }
    /* The bounds are lane reductions, done several at a time (lane j of a
     * batch's result: the reduction of its j-th vector): least, the exact
     * reciprocals, then per axis the c (or origin) whose least value counts,
     * then tnear; greatest, the exact reciprocals, then the other c. */
    vk mn[8], mx[8];
    for (int k = 0; k < 3; k++) {
        mn[k] = VK(select)(active, p->rinv_exact[k], pinf);
        mx[k] = VK(select)(active, p->rinv_exact[k], ninf);
#if RTK_SIMD_HAS_FMA
        /* near = plane * rn - cn: least with the greatest cn; far the other way */
        mn[3 + k] = VK(select)(active, p->cf[k], pinf);
        mx[3 + k] = VK(select)(active, p->cn[k], ninf);
#else
        /* near = (plane - org) * rn: least with the origin farthest along
         * the direction (the greatest where it is positive); far the other
         * way */
        const int n = p->near_off[k] == upper[k];
        mn[3 + k] = VK(select)(active, n ? p->on[k] : p->of[k], pinf);
        mx[3 + k] = VK(select)(active, n ? p->of[k] : p->on[k], ninf);
#endif
    }
    mn[6] = p->tnear; /* +inf in the inactive lanes */
    mn[7] = pinf;
    mx[6] = mx[7] = ninf;
#if RTK_FUSED_FAR_ULPS
    /* the reductions' lanes are the bounds as they are (PK_FR_*: the far
     * planes take the near planes' reciprocals, see rn above), stored
     * where frustum_intersect reads them */
    float *const lo = p->fr_lo, *const hi = p->fr_hi;
#else
    _Alignas(64) float lo[8], hi[8];
#endif
#if RTK_PACKET == 8
    VK(store)(lo, vf8_reduce8_min(mn));
    VK(store)(hi, vf8_reduce8_max(mx));
#else
    for (int b = 0; b < 8; b += 4) {
        VK(store)(lo + b, vf4_reduce4_min(mn[b], mn[b + 1], mn[b + 2], mn[b + 3]));
        VK(store)(hi + b, vf4_reduce4_max(mx[b], mx[b + 1], mx[b + 2], mx[b + 3]));
    }
#endif
#if !RTK_FUSED_FAR_ULPS
    for (int k = 0; k < 3; k++) {
        /* rn and rf are the exact reciprocal times the near and the far
         * scale (positive constants) in every active lane, whatever its
         * sign, and rounding is monotone: their extremes are the exact
         * reciprocal's times the scales */
        p->fr_rn_min[k] = lo[k] * PK_NEAR_SCALE;
        p->fr_rn_max[k] = hi[k] * PK_NEAR_SCALE;
        p->fr_rf_min[k] = lo[k] * PK_FAR_SCALE;
        p->fr_rf_max[k] = hi[k] * PK_FAR_SCALE;
#if PK_ZERO_DIR_INF
        /* a ray's far reciprocal +-inf (box_consts): the greatest far
         * distance +inf wherever one of them is inside the slab (its origin
         * moved, the frustum's far plane minus origin is then not 0; it
         * can be where another ray's origin lies on the plane, and that
         * NaN is dropped in frustum_intersect) */
        if ((unsigned)VKB(mask)(PK_(zero_dir)(p->dir[k])) & all) {
            if (p->near_off[k] == upper[k])
                p->fr_rf_min[k] = -INFINITY;
            else
                p->fr_rf_max[k] = INFINITY;
        }
#endif
#if RTK_SIMD_HAS_FMA
        p->fr_cn_max[k] = hi[3 + k];
        p->fr_cf_min[k] = lo[3 + k];
#else
        const int n = p->near_off[k] == upper[k];
        p->fr_on[k] = n ? lo[3 + k] : hi[3 + k];
        p->fr_of[k] = n ? hi[3 + k] : lo[3 + k];
#endif
    }
    p->fr_tnear = lo[6];
#endif
    p->frustum = 1;
}

/* The frustum against a node's N boxes: the mask of those some active ray
 * of the packet may enter within [its tnear, tfar_max].  Which end of a
 * reciprocal range gives the least product depends on the sign of the other
 * factor, so it is chosen per box: the least near distance takes the least
 * reciprocal where the plane (or plane - origin) is positive, the greatest
 * where it is negative; the greatest far distance the other way. */
static inline unsigned PK_(frustum_intersect)(const node_t *n, const PK_(packet_pre) *p, vnode tfar_max)
{
    const vnode zero = vn_set1(0.0f);
    vnode tmin = vn_set1(PK_FR_TNEAR(p)), tmax = tfar_max;
    for (int k = 0; k < 3; k++) {
        const vnode pn = plane(n, p->near_off[k]), pf = plane(n, p->far_off[k]);
#if RTK_SIMD_HAS_FMA
        const vnode tn = vn_msub(pn, vn_select(vn_ge(pn, zero), vn_set1(PK_FR_RN_MIN(p, k)), vn_set1(PK_FR_RN_MAX(p, k))),
                                 vn_set1(PK_FR_CN_MAX(p, k)));
        const vnode tf = vn_msub(pf, vn_select(vn_ge(pf, zero), vn_set1(PK_FR_RF_MAX(p, k)), vn_set1(PK_FR_RF_MIN(p, k))),
                                 vn_set1(PK_FR_CF_MIN(p, k)));
#else
        const vnode xn = vn_sub(pn, vn_set1(p->fr_on[k])), xf = vn_sub(pf, vn_set1(p->fr_of[k]));
        const vnode tn = vn_mul(xn, vn_select(vn_ge(xn, zero), vn_set1(PK_FR_RN_MIN(p, k)), vn_set1(PK_FR_RN_MAX(p, k))));
        const vnode tf = vn_mul(xf, vn_select(vn_ge(xf, zero), vn_set1(PK_FR_RF_MAX(p, k)), vn_set1(PK_FR_RF_MIN(p, k))));
#endif
        tmin = vn_max(tmin, tn);
#if PK_ZERO_DIR_INF
        /* (0 * inf = NaN where a ray's origin lies on the plane and another
         * ray's far reciprocal is infinite: dropped, the bound so far kept
         * as min's second operand) */
        tmax = vn_min(tf, tmax);
#else
        tmax = vn_min(tmax, tf);
#endif
    }
#if RTK_SIMD_HAS_FMA
    /* the rays' far ends are compared RTK_FUSED_FAR_ULPS * RTK_FAR_ULPS + 1
     * ulps up, as integers (box_intersect_octant: +inf and those ulps are a
     * NaN's bits, above every distance) */
    return (unsigned)vn_mask(vn_gti(vn_add_ulps(tmax, RTK_FUSED_FAR_ULPS * RTK_FAR_ULPS + 1), tmin));
#else
    return (unsigned)vn_mask(vn_le(tmin, tmax));
#endif
}

/* Child box i against the packet with the single-ray kernel's arithmetic
 * (frustum packets only): the entry distance where entered within
 * [tnear, tfar], NaN elsewhere; the mask of rays that enter. */
static inline int PK_(box_intersect_octant)(const node_t *n, int i, const PK_(packet_pre) *p, vk tfar, vk *dist)
{
    vk t0[3], t1[3];
    for (int k = 0; k < 3; k++) {
        const vk pn = VK(set1)(((const float *)((const char *)n + p->near_off[k]))[i]);
        const vk pf = VK(set1)(((const float *)((const char *)n + p->far_off[k]))[i]);
#if RTK_SIMD_HAS_FMA
        t0[k] = VK(msub)(pn, PK_RN(p, k), p->cn[k]);
        t1[k] = VK(msub)(pf, PK_RF(p, k), p->cf[k]);
#else
        t0[k] = VK(mul)(VK(sub)(pn, p->on[k]), PK_RN(p, k));
        t1[k] = VK(mul)(VK(sub)(pf, p->of[k]), PK_RF(p, k));
#endif
    }
#if RTK_SIMD_HAS_FMA
    /* node_intersect's fused comparison: the distances' bits as integers,
     * tnear and tfar + 0.0 (no -0.0), the far end RTK_FUSED_FAR_ULPS *
     * RTK_FAR_ULPS + 1 up, so that a ray enters the boxes it enters alone */
    const vk zero = VK(set1)(0.0f);
    const vk tmin = VK(maxi)(VK(maxi)(t0[0], t0[1]), VK(maxi)(t0[2], VK(add)(p->tnear, zero)));
    const vk tmax = VK(mini)(VK(mini)(t1[0], t1[1]), VK(mini)(t1[2], VK(add)(tfar, zero)));
    const vkb hit = VK(gti)(VK(add_ulps)(tmax, RTK_FUSED_FAR_ULPS * RTK_FAR_ULPS + 1), tmin);
#else
    const vk tmin = VK(max)(VK(max)(t0[0], t0[1]), VK(max)(t0[2], p->tnear));
    const vk tmax = VK(min)(VK(min)(t1[0], t1[1]), VK(min)(t1[2], tfar));
    const vkb hit = VK(le)(tmin, tmax);
#endif
    *dist = VK(select)(hit, tmin, VK(set1)(NAN));
    return VKB(mask)(hit);
}

/* The constants of the ray-by-ray box test box_intersect: per axis the
 * lower and upper planes' reciprocals (and c), by each ray's own signs. */
static inline void PK_(box_consts)(PK_(packet_pre) *p)
{
    const vk zero = VK(set1)(0.0f), scale = VK(set1)(PK_FAR_SCALE), near_scale = VK(set1)(PK_NEAR_SCALE);
    for (int k = 0; k < 3; k++) {
        const vk rinv = VK(mul)(p->rinv_exact[k], near_scale);
#if PK_ZERO_DIR_INF
        /* the far planes' +-inf for a zero direction (ray_pre_init), with
         * the origins moved off the planes (packet_pre_init) */
        const vk rinv_far = VK(select)(PK_(zero_dir)(p->dir[k]), VK(xor_sign)(VK(set1)(INFINITY), p->rinv_exact[k]),
                                       VK(mul)(p->rinv_exact[k], scale));
#else
        const vk rinv_far = VK(mul)(p->rinv_exact[k], scale);
#endif
        const vkb neg = VK(lt)(rinv, zero);
        p->rinv_lo[k] = VK(select)(neg, rinv_far, rinv);
        p->rinv_hi[k] = VK(select)(neg, rinv, rinv_far);
#if RTK_SIMD_HAS_FMA
        /* As in ray_pre_init, moved by 4u|c| toward the near side: up for
         * the near plane, down for the far one.  A product out of range
         * makes its slab drop out (NaN and infinite distances lose in the
         * min/max of box_intersect, which ends with tnear and tfar, never
         * NaN); unlike the single-ray test that is harmless here, as the
         * packet loop never visits empty child slots. */
        const vk c_lo = VK(mul)(p->org_lo[k], p->rinv_lo[k]), c_hi = VK(mul)(p->org_hi[k], p->rinv_hi[k]);
        const vk e_lo = VK(add)(VK(mul)(VK(abs)(c_lo), VK(set1)(0x1p-22f)), VK(set1)(0x1p-126f));
        const vk e_hi = VK(add)(VK(mul)(VK(abs)(c_hi), VK(set1)(0x1p-22f)), VK(set1)(0x1p-126f));
        p->c_lo[k] = VK(add)(c_lo, VK(xor_sign)(e_lo, rinv)); /* lower is near where rinv > 0 */
        p->c_hi[k] = VK(sub)(c_hi, VK(xor_sign)(e_hi, rinv));
#endif
    }
}

static inline void PK_(packet_pre_init)(PK_(packet_pre) *p, const rayK *r, vkb active, const rtk_accel *accel)
{
    (void)accel;
    const float *org[3] = {r->org_x, r->org_y, r->org_z}, *dir[3] = {r->dir_x, r->dir_y, r->dir_z};
    const vk tiny = VK(set1)(RTK_ZERO_DIR), one = VK(set1)(1.0f);
    for (int k = 0; k < 3; k++) {
        p->org[k] = VK(load)(org[k]);
        p->dir[k] = VK(load)(dir[k]);
#if RTK_ROBUST
        /* as in ray_pre_init */
        const vk shift = VK(add)(VK(set1)(accel->extent * RTK_ROBUST_REL), VK(mul)(VK(abs)(p->org[k]), VK(set1)(0x1p-22f)));
        p->org_lo[k] = VK(add)(p->org[k], shift);
        p->org_hi[k] = VK(sub)(p->org[k], shift);
#elif PK_ZERO_DIR_INF
        /* Where a direction component is below 1e-18 in magnitude, the
         * subtract-then-multiply tests take +-inf for its far planes'
         * reciprocal, as the single-ray kernel does (ray_pre_init), and the
         * origins of the lower and upper planes move up and down by an ulp
         * or two: lower - org_lo < 0 for every lower <= org, upper - org_hi
         * > 0 for every upper >= org, so a far distance is +inf wherever
         * the origin is on the slab, with no 0 * inf (but for an origin
         * just outside it, where a NaN is dropped and the ray may enter a
         * box it does not: a box more to visit, never one fewer; the near
         * distances only move down). */
        {
            const vk s = VK(select)(PK_(zero_dir)(p->dir[k]),
                                    VK(add)(VK(mul)(VK(abs)(p->org[k]), VK(set1)(0x1p-22f)), VK(set1)(0x1p-126f)),
                                    VK(set1)(0.0f));
            p->org_lo[k] = VK(add)(p->org[k], s);
            p->org_hi[k] = VK(sub)(p->org[k], s);
        }
#else
        p->org_lo[k] = p->org_hi[k] = p->org[k];
#endif
        /* as in ray_pre_init: components below 1e-18 in magnitude become +-1e-18 */
        const vk d = VK(select)(PK_(zero_dir)(p->dir[k]), VK(xor_sign)(tiny, p->dir[k]), p->dir[k]);
        p->rinv_exact[k] = VK(div)(one, d);
    }
#if !RTK_FUSED_FAR_ULPS
    PK_(box_consts)(p); /* (fused: only for a packet without a frustum, made by traverse) */
#endif
    /* inactive lanes start beyond everything: they never enter a box */
    p->tnear = VK(select)(active, VK(load)(r->tnear), VK(set1)(INFINITY));
#if RTK_ROBUST
    /* the axes as rtk_watertight_ray_init picks them, for all lanes at once
     * (the same comparisons and IEEE divisions, so the same values): kz the
     * largest |d| component, kx and ky the next two cyclically */
    const vk ax = VK(abs)(p->dir[0]), ay = VK(abs)(p->dir[1]), az = VK(abs)(p->dir[2]);
    const vkb xy = VK(gt)(ax, ay);
    const vkb z0 = VKB(and)(xy, VK(gt)(ax, az));       /* kz = x */
    const vkb z1 = VKB(andnot)(VK(gt)(ay, az), xy);    /* kz = y */
    const vkb z2 = VKB(andnot)(VKB(andnot)(VK(eq)(ax, ax), z0), z1); /* kz = z (NaN lanes: none; inactive) */
    /* kx is x where kz = z, y where kz = x; ky is x where kz = y, y where kz = z */
    p->is_x[0] = z2, p->is_y[0] = z0;
    p->is_x[1] = z1, p->is_y[1] = z2;
    p->is_x[2] = z0, p->is_y[2] = z1;
    vk dk[3];
    for (int j = 0; j < 3; j++) {
        dk[j] = VK(select)(p->is_x[j], p->dir[0], VK(select)(p->is_y[j], p->dir[1], p->dir[2]));
        p->worg[j] = VK(select)(p->is_x[j], p->org[0], VK(select)(p->is_y[j], p->org[1], p->org[2]));
    }
    p->sx = VK(div)(dk[0], dk[2]);
    p->sy = VK(div)(dk[1], dk[2]);
    p->sz = VK(div)(VK(set1)(1.0f), dk[2]);
#endif
}

/* One child box against the packet: the entry distance where entered within
 * [tnear, tfar], NaN elsewhere; the mask of rays that enter.  NaN, not +inf:
 * `dist <= tfar` says which rays want a subtree, and with +inf a ray whose
 * tfar is +inf would want every box its packet enters, and test triangles
 * it would never reach alone. */
static inline int PK_(box_intersect)(const node_t *n, int i, const PK_(packet_pre) *p, vk tfar, vk *dist)
{
#if RTK_SIMD_HAS_FMA
    const vk t0x = VK(msub)(VK(set1)(n->lower_x[i]), p->rinv_lo[0], p->c_lo[0]);
    const vk t1x = VK(msub)(VK(set1)(n->upper_x[i]), p->rinv_hi[0], p->c_hi[0]);
    const vk t0y = VK(msub)(VK(set1)(n->lower_y[i]), p->rinv_lo[1], p->c_lo[1]);
    const vk t1y = VK(msub)(VK(set1)(n->upper_y[i]), p->rinv_hi[1], p->c_hi[1]);
    const vk t0z = VK(msub)(VK(set1)(n->lower_z[i]), p->rinv_lo[2], p->c_lo[2]);
    const vk t1z = VK(msub)(VK(set1)(n->upper_z[i]), p->rinv_hi[2], p->c_hi[2]);
#else
    const vk t0x = VK(mul)(VK(sub)(VK(set1)(n->lower_x[i]), p->org_lo[0]), p->rinv_lo[0]);
    const vk t1x = VK(mul)(VK(sub)(VK(set1)(n->upper_x[i]), p->org_hi[0]), p->rinv_hi[0]);
    const vk t0y = VK(mul)(VK(sub)(VK(set1)(n->lower_y[i]), p->org_lo[1]), p->rinv_lo[1]);
    const vk t1y = VK(mul)(VK(sub)(VK(set1)(n->upper_y[i]), p->org_hi[1]), p->rinv_hi[1]);
    const vk t0z = VK(mul)(VK(sub)(VK(set1)(n->lower_z[i]), p->org_lo[2]), p->rinv_lo[2]);
    const vk t1z = VK(mul)(VK(sub)(VK(set1)(n->upper_z[i]), p->org_hi[2]), p->rinv_hi[2]);
#endif
    const vk tmin = VK(max)(VK(max)(VK(min)(t0x, t1x), VK(min)(t0y, t1y)), VK(max)(VK(min)(t0z, t1z), p->tnear));
    const vk tmax = VK(min)(VK(min)(VK(max)(t0x, t1x), VK(max)(t0y, t1y)), VK(min)(VK(max)(t0z, t1z), tfar));
    const vkb hit = VK(le)(tmin, tmax);
    *dist = VK(select)(hit, tmin, VK(set1)(NAN));
    return VKB(mask)(hit);
}

#if RTK_ROBUST
/* Lane j of a leaf block against the packet with the watertight test, the
 * arithmetic of the single-ray triangle4_intersect with the ray and
 * triangle roles of the lanes swapped: each ray's permuted coordinates are
 * picked by selection, and a ray whose edge function comes out exactly zero
 * (or |det| below FLT_MIN) is decided again alone in double precision. */
static inline vk PK_(permuted)(const PK_(packet_pre) *p, int axis, float x, float y, float z)
{
    return VK(select)(p->is_x[axis], VK(set1)(x), VK(select)(p->is_y[axis], VK(set1)(y), VK(set1)(z)));
}

static inline vkb PK_(triangle_intersect)(const block_t *t, int j, const PK_(packet_pre) *p, vk tfar, vk *U_out,
                                          vk *V_out, vk *T_out, vk *absdet_out, unsigned *in_double)
{
    vk tx[3], ty[3], tz[3]; /* per vertex: permuted x and y sheared, and z, relative to the origin */
    const float *f = (const float *)t;
    for (int v = 0; v < 3; v++) {
        const float vx = f[12 * v + j], vy = f[12 * v + 4 + j], vz = f[12 * v + 8 + j];
        const vk z = VK(sub)(PK_(permuted)(p, 2, vx, vy, vz), p->worg[2]);
        tx[v] = VK(sub)(VK(sub)(PK_(permuted)(p, 0, vx, vy, vz), p->worg[0]), VK(mul)(p->sx, z));
        ty[v] = VK(sub)(VK(sub)(PK_(permuted)(p, 1, vx, vy, vz), p->worg[1]), VK(mul)(p->sy, z));
        tz[v] = VK(mul)(p->sz, z);
    }
    const vk U = VK(sub)(VK(mul)(tx[2], ty[1]), VK(mul)(ty[2], tx[1]));
    const vk V = VK(sub)(VK(mul)(tx[0], ty[2]), VK(mul)(ty[0], tx[2]));
    const vk W = VK(sub)(VK(mul)(tx[1], ty[0]), VK(mul)(ty[1], tx[0]));
    const vk zero = VK(set1)(0.0f);
    const vkb pos = VKB(and)(VKB(and)(VK(ge)(U, zero), VK(ge)(V, zero)), VK(ge)(W, zero));
    const vkb neg = VKB(and)(VKB(and)(VK(le)(U, zero), VK(le)(V, zero)), VK(le)(W, zero));
    const vk det = VK(add)(VK(add)(U, V), W);
    const vk absdet = VK(abs)(det);
    const vk T = VK(xor_sign)(VK(add)(VK(add)(VK(mul)(U, tz[0]), VK(mul)(V, tz[1])), VK(mul)(W, tz[2])), det);
    vkb ok = VKB(or)(pos, neg);
    ok = VKB(and)(ok, VK(ge)(absdet, VK(set1)(FLT_MIN)));
    ok = VKB(and)(ok, VK(ge)(T, VK(mul)(p->tnear, absdet)));
    ok = VKB(and)(ok, VK(le)(T, VK(mul)(tfar, absdet)));
    *U_out = VK(xor_sign)(V, det);
    *V_out = VK(xor_sign)(W, det);
    *T_out = T;
    *absdet_out = absdet;
    /* a zero among U, V, W (or a product that underflows), as the single-ray test */
    unsigned zeros = (unsigned)VKB(mask)(
        VKB(or)(VK(eq)(VK(mul)(VK(mul)(U, V), W), zero), VK(lt)(absdet, VK(set1)(FLT_MIN))));
    *in_double = zeros;
    if (__builtin_expect(zeros == 0, 1))
        return ok;
    _Alignas(64) float lx[3][RTK_PACKET], ly[3][RTK_PACKET], lz[3][RTK_PACKET];
    _Alignas(64) float hu[RTK_PACKET], hv[RTK_PACKET], ht[RTK_PACKET], hd[RTK_PACKET], tn[RTK_PACKET],
        tf[RTK_PACKET];
    _Alignas(64) int32_t okl[RTK_PACKET];
    for (int v = 0; v < 3; v++) {
        VK(store)(lx[v], tx[v]);
        VK(store)(ly[v], ty[v]);
        VK(store)(lz[v], tz[v]);
    }
    VK(store)(hu, *U_out), VK(store)(hv, *V_out), VK(store)(ht, T), VK(store)(hd, absdet);
    VK(store)(tn, p->tnear), VK(store)(tf, tfar);
    const unsigned okm = (unsigned)VKB(mask)(ok);
    for (int i = 0; i < RTK_PACKET; i++)
        okl[i] = okm >> i & 1 ? -1 : 0;
    for (; zeros; zeros &= zeros - 1) {
        const int i = __builtin_ctz(zeros);
        const float a2[2] = {lx[0][i], ly[0][i]}, b2[2] = {lx[1][i], ly[1][i]}, c2[2] = {lx[2][i], ly[2][i]};
        const float z[3] = {lz[0][i], lz[1][i], lz[2][i]};
        rtk_tri_hit hit;
        okl[i] = 0;
        if (!rtk_watertight_double(a2, b2, c2, z, tn[i], tf[i], &hit))
            continue;
        okl[i] = -1;
        hu[i] = hit.u;
        hv[i] = hit.v;
        ht[i] = hit.t;
        hd[i] = 1.0f;
    }
    *U_out = VK(load)(hu);
    *V_out = VK(load)(hv);
    *T_out = VK(load)(ht);
    *absdet_out = VK(load)(hd);
    return VKB(load)(okl);
}
#else
/* Lane j of a leaf block against the packet, the arithmetic of
 * triangle4_intersect with the ray and triangle roles of the lanes swapped. */
static inline vkb PK_(triangle_intersect)(const block_t *t, int j, const PK_(packet_pre) *p, vk tfar, vk *U_out,
                                          vk *V_out, vk *T_out, vk *absdet_out, unsigned *in_double)
{
    *in_double = 0;
    const vk e1x = VK(set1)(t->e1x[j]), e1y = VK(set1)(t->e1y[j]), e1z = VK(set1)(t->e1z[j]);
    const vk e2x = VK(set1)(t->e2x[j]), e2y = VK(set1)(t->e2y[j]), e2z = VK(set1)(t->e2z[j]);
    const vk dx = p->dir[0], dy = p->dir[1], dz = p->dir[2];
    /* c = v0 - o, r = cross(c, d), n = cross(e1, e2) */
    const vk cx = VK(sub)(VK(set1)(t->v0x[j]), p->org[0]);
    const vk cy = VK(sub)(VK(set1)(t->v0y[j]), p->org[1]);
    const vk cz = VK(sub)(VK(set1)(t->v0z[j]), p->org[2]);
    const vk rx = VK(sub)(VK(mul)(cy, dz), VK(mul)(cz, dy));
    const vk ry = VK(sub)(VK(mul)(cz, dx), VK(mul)(cx, dz));
    const vk rz = VK(sub)(VK(mul)(cx, dy), VK(mul)(cy, dx));
    const vk nx = VK(sub)(VK(mul)(e1y, e2z), VK(mul)(e1z, e2y));
    const vk ny = VK(sub)(VK(mul)(e1z, e2x), VK(mul)(e1x, e2z));
    const vk nz = VK(sub)(VK(mul)(e1x, e2y), VK(mul)(e1y, e2x));
    const vk det = VK(add)(VK(add)(VK(mul)(nx, dx), VK(mul)(ny, dy)), VK(mul)(nz, dz));
    const vk absdet = VK(abs)(det);
    const vk U = VK(xor_sign)(VK(add)(VK(add)(VK(mul)(rx, e2x), VK(mul)(ry, e2y)), VK(mul)(rz, e2z)), det);
    const vk V = VK(xor_sign)(VK(add)(VK(add)(VK(mul)(rx, e1x), VK(mul)(ry, e1y)), VK(mul)(rz, e1z)),
                              VK(sub)(VK(set1)(0.0f), det));
    const vk T = VK(xor_sign)(VK(add)(VK(add)(VK(mul)(nx, cx), VK(mul)(ny, cy)), VK(mul)(nz, cz)), det);
    const vk zero = VK(set1)(0.0f);
    vkb ok = VKB(and)(VK(ge)(U, zero), VK(ge)(V, zero));
    ok = VKB(and)(ok, VK(le)(VK(add)(U, V), absdet));
    ok = VKB(and)(ok, VK(ge)(absdet, VK(set1)(FLT_MIN))); /* 1 / absdet finite (geometry/triangle.h) */
    ok = VKB(and)(ok, VK(ge)(T, VK(mul)(p->tnear, absdet)));
    ok = VKB(and)(ok, VK(le)(T, VK(mul)(tfar, absdet)));
    *U_out = U;
    *V_out = V;
    *T_out = T;
    *absdet_out = absdet;
    return ok;
}
#endif

/* Triangle j of block t's hit floor (block_hit_floor) for each ray of the
 * packet: lane by lane the same operations on the same values. */
static inline vk PK_(hit_floor)(const block_t *t, int j, const PK_(packet_pre) *p)
{
    vk entry = VK(set1)(0.0f);
    for (int k = 0; k < 3; k++) {
        float lo, hi;
        lane_axis_range(t, j, k, &lo, &hi);
        const vk inv = p->rinv_exact[k];
        const vk near = VK(select)(VK(lt)(inv, VK(set1)(0.0f)), VK(set1)(hi), VK(set1)(lo));
        const vk tk = VK(mul)(VK(sub)(near, p->org[k]), inv);
        entry = k ? VK(max)(entry, tk) : tk;
    }
    entry = VK(add)(entry, VK(set1)(0.0f));
    return VK(sub)(entry, VK(mul)(VK(abs)(entry), VK(set1)(0x1p-20f)));
}

typedef struct PK_(pstack_entry) {
    vk dist; /* per ray: entry distance, NaN for rays that do not enter */
    uint32_t ref;
} PK_(pstack_entry);

/* Lane i of the packet as a single ray. */
static inline rtk_ray PK_(lane_ray)(const rayK *r, int i)
{
    return (rtk_ray){.org_x = r->org_x[i], .org_y = r->org_y[i], .org_z = r->org_z[i], .tnear = r->tnear[i],
                     .dir_x = r->dir_x[i], .dir_y = r->dir_y[i], .dir_z = r->dir_z[i], .time = r->time[i],
                     .tfar = r->tfar[i], .mask = r->mask[i], .id = r->id[i], .flags = r->flags[i]};
}

/* Lane i as a single ray in *out for a single-ray entry point, org and
 * tnear, dir and time each written as one vector: the entry point reads
 * them as vectors, and a 16-byte load of four 4-byte stores would stall on
 * store forwarding. */
static inline void PK_(lane_ray_to)(const rayK *r, int i, rtk_ray *out)
{
    *out = PK_(lane_ray)(r, i);
    vf4_storeu(&out->org_x, vf4_set(r->org_x[i], r->org_y[i], r->org_z[i], r->tnear[i]));
    vf4_storeu(&out->dir_x, vf4_set(r->dir_x[i], r->dir_y[i], r->dir_z[i], r->time[i]));
}

/* A lane as a single ray, for finishing a subtree alone: *one holds the
 * ray, and the features' context (if it needs them) is made in *fc. */
static inline const feat_ctx *PK_(lane_ray_pre)(ray_pre *p, ray_mem *pm, rtk_ray *one, feat_ctx *fc, const rayK *r, int i,
                                                const rtk_accel *accel, const rtk_query *q)
{
    PK_(lane_ray_to)(r, i, one);
    ray_pre_init(p, pm, one, accel);
    return feat_init(fc, one, accel, q);
}

/* The candidates `hit` (lanes: rays) of triangle j of block t through
 * accept_lane (masks, culling, filters); the lanes accepted. */
static __attribute__((noinline)) unsigned PK_(accept)(const rtk_accel *accel, const block_t *t, int j, const rayK *r,
                                                      unsigned hit, vk U, vk V, vk T, vk absdet, vk floor, vk tnear,
                                                      vk tfar, int occluded, const rtk_query *q)
{
    _Alignas(64) float u[RTK_PACKET], v[RTK_PACKET], tt[RTK_PACKET], tf[RTK_PACKET];
    const vk rcp = VK(div)(VK(set1)(1.0f), absdet);
    VK(store)(u, VK(mul)(U, rcp));
    VK(store)(v, VK(mul)(V, rcp));
    const vk tr = VK(mul)(T, rcp);
    VK(store)(tt, VK(min)(VK(max)(VK(select)(VK(lt)(tr, floor), floor, tr), tnear), tfar));
    VK(store)(tf, tfar);
    unsigned accepted = 0;
    for (unsigned m = hit; m; m &= m - 1) {
        const int i = __builtin_ctz(m);
        const rtk_ray one = PK_(lane_ray)(r, i);
        feat_ctx fc;
        const feat_ctx *f = feat_init(&fc, &one, accel, q);
        if (!f || accept_lane(t, j, f, tt[i], u[i], v[i], tf[i], occluded))
            accepted |= 1u << i;
    }
    return accepted;
}

static inline vkb PK_(lanes_mask)(unsigned bits)
{
    return VKB(from_bits)((int)bits);
}

/* What a packet query found, per ray: the distance (tfar), and for the
 * closest hit the barycentrics, geometric normal and ids, the ids' bits in
 * float lanes (so that one blend records a triangle for all the rays that
 * hit it); `hit` the rays with a closest hit, or the rays occluded. */
typedef struct PK_(hits) {
    _Alignas(64) float t[RTK_PACKET];
    _Alignas(64) float u[RTK_PACKET];
    _Alignas(64) float v[RTK_PACKET];
    _Alignas(64) float ng[3][RTK_PACKET];
    _Alignas(64) float prim[RTK_PACKET];
    _Alignas(64) float geom[RTK_PACKET];
    unsigned hit;
} PK_(hits);

static inline float PK_(bits_float)(uint32_t x)
{
    float f;
    memcpy(&f, &x, sizeof f);
    return f;
}

/* Rays `ok` (lanes) take lane j of block t as their closest hit so far: its
 * normal (as closest_hit_record computes it, to the bit) and ids. */
static inline void PK_(record_triangle)(PK_(hits) *h, vkb ok, const block_t *t, int j)
{
    float v0[3], e1[3], e2[3], ng[3];
    lane_triangle(t, j, v0, e1, e2);
    rtk_triangle_normal(e1, e2, ng);
    for (int c = 0; c < 3; c++)
        VK(store)(h->ng[c], VK(select)(ok, VK(set1)(ng[c]), VK(load)(h->ng[c])));
    VK(store)(h->prim, VK(select)(ok, VK(set1)(PK_(bits_float)(t->prim[j])), VK(load)(h->prim)));
    VK(store)(h->geom, VK(select)(ok, VK(set1)(PK_(bits_float)(t->geom[j])), VK(load)(h->geom)));
}

/* The packet traversal both queries share; `closest` selects the query and
 * is a constant in each kernel (the function is inlined there).  The
 * results go to *h (for the occluded query only t and hit). */
/* The near ties of the closest-hit query for the stream kernel
 * (PK_INTERSECT_EXACT): a ray whose hit so far and another triangle lie
 * within this much of each other (relative to the distance) may get a
 * different one of the two in a packet than alone, where the order of the
 * tests decides; much more than the few ulps by which the two distances,
 * the clamp of t and the tests of T against tfar * |det| can disagree. */
#define PK_TIE_REL 0x1p-16f

/* tfar widened by the tie band (exact: a constant), or tfar as it is. */
static inline vk PK_(loose)(vk tfar, int exact)
{
    return exact ? VK(add)(tfar, VK(mul)(VK(abs)(tfar), VK(set1)(PK_TIE_REL))) : tfar;
}

/* ties: NULL, or (closest hit only) where the rays whose answer the packet
 * order may have changed go (see PK_INTERSECT_EXACT); the traversal then
 * descends by tfar widened by the tie band, so that it meets every
 * triangle a ray alone could have taken in place of its answer. */
static inline __attribute__((always_inline)) void PK_(traverse)(const rtk_accel *accel, const int32_t *valid,
                                                                const rayK *ray, int closest, PK_(hits) *h,
                                                                const rtk_query *q, unsigned *ties)
{
    const int exact = closest && ties != NULL;
    const vkb active = VKB(load)(valid);
    /* masks, culling, filters (feat_init): some ray asks for culling, or
     * for the tree's attributes (a loop of ands and ors over the lanes,
     * which the compiler does in vectors; through feat_attrs, reloading the
     * tree in every lane, it did not) */
    const uint32_t pass_all = accel->mask_pass_all;
    uint32_t cull = 0, attrs = 0;
    for (int i = 0; i < RTK_PACKET; i++) {
        const uint32_t on = valid[i] ? ~0u : 0u;
        cull |= ray->flags[i] & on;
        attrs |= mask_needs_attrs(pass_all, ray->mask[i]) & on;
    }
    const unsigned feat = (cull & RTK_FEAT_CULL) | (attrs ? RTK_FEAT_ATTRS : 0u);
    PK_(packet_pre) p;
    PK_(packet_pre_init)(&p, ray, active, accel);
    vk tfar = VK(select)(active, VK(load)(ray->tfar), VK(set1)(-INFINITY));
    vk tfar_n = PK_(loose)(tfar, exact); /* the node tests' */
    PK_(frustum_init)(&p, active);
#if RTK_FUSED_FAR_ULPS
    if (!p.frustum)
        PK_(box_consts)(&p);
#endif
    vnode fr_tfar = vn_set1(p.frustum ? VK(reduce_max)(tfar_n) : 0.0f);
    vk hu = VK(set1)(0.0f), hv = hu;
    const unsigned all = VKB(mask)(active);
    unsigned done = 0; /* occluded: rays that found a hit; closest: rays with a hit */
    if (exact) {
        /* rays whose origin and direction put org / dir near the float
         * range take the subtract-then-multiply node test alone
         * (ray_pre.fma), not the fused one the packet takes: alone */
        unsigned fits = all;
        const vk limit = VK(set1)(0x1p125f);
        for (int k = 0; k < 3; k++) /* (the origins of both planes: robust layouts pad them) */
            fits &= (unsigned)VKB(mask)(VK(le)(VK(abs)(VK(mul)(p.org_lo[k], p.rinv_exact[k])), limit)) &
                    (unsigned)VKB(mask)(VK(le)(VK(abs)(VK(mul)(p.org_hi[k], p.rinv_exact[k])), limit));
        /* (a zero direction takes that test too, but never comes here: the
         * stream's coherent groups leave such rays out, stream_zero_dir) */
        *ties = all & ~fits;
    }
    if (closest) { /* defined lanes throughout, for the blends (and memory checkers) */
        const vk zero = VK(set1)(0.0f);
        for (int c = 0; c < 3; c++)
            VK(store)(h->ng[c], zero);
        VK(store)(h->prim, zero);
        VK(store)(h->geom, zero);
    }

    /* each lane as a single ray, made the first time it finishes a
     * subtree alone and kept for the next ones (lanes_ready): a diffuse
     * packet of neighbouring pixels parts at the root, and made per
     * subtree its rays were set up once per child of the root they
     * entered (dragon.ply's diffuse packets of 8: intersect8's
     * instructions -3.4%, callgrind) */
    ray_pre lane_p[RTK_PACKET];
    ray_mem lane_m[RTK_PACKET];
    rtk_ray lane_one[RTK_PACKET];
    feat_ctx lane_fc[RTK_PACKET];
    const feat_ctx *lane_f[RTK_PACKET];
    unsigned lanes_ready = 0;

    PK_(pstack_entry) stack[RTK_BVHN_STACK_SIZE(RTK_BVHN) + 1];
    int sp = 0;
    stack[sp++] = (PK_(pstack_entry)){.dist = p.tnear, .ref = accel->root};
    while (sp > 0) {
        sp--;
        uint32_t cur = stack[sp].ref;
        vk cur_dist = stack[sp].dist;
        const unsigned want = (unsigned)VKB(mask)(VK(le)(cur_dist, tfar_n));
        if (!want)
            continue;
        /* (exact: never; the packet goes on with one ray, where the leaf
         * test below sees each hit and the box it was found in) */
        if (!exact && __builtin_popcount(want) <= (p.frustum ? PK_SWITCH_FRUSTUM : PK_SWITCH)) {
            /* few rays want this subtree: each finishes it alone.  Its
             * results go back into the vectors by blends: lane stores and a
             * vector load of them would stall on store forwarding */
            _Alignas(64) float tf[RTK_PACKET];
            VK(store)(tf, tfar);
            for (unsigned m = want; m; m &= m - 1) {
                const int i = __builtin_ctz(m);
                const vkb lane = PK_(lanes_mask)(1u << i);
                if (!(lanes_ready >> i & 1)) {
                    lane_f[i] = PK_(lane_ray_pre)(&lane_p[i], &lane_m[i], &lane_one[i], &lane_fc[i], ray, i, accel, q);
                    lanes_ready |= 1u << i;
                }
                const ray_pre *rp = &lane_p[i];
                const feat_ctx *f = lane_f[i];
                if (closest) {
                    closest_hit best = CLOSEST_HIT_NONE;
                    const int had = exact && (done >> i & 1);
                    /* a ray with a hit looks into the tie band too */
                    float ti = had ? tf[i] + fabsf(tf[i]) * PK_TIE_REL : tf[i];
                    closest_from(accel, cur, rp, ray->tnear[i], &ti, &best, f);
                    if (best.lane >= 0) {
                        block_t scratch;
                        if (had && ti >= tf[i] - fabsf(tf[i]) * PK_TIE_REL)
                            *ties |= 1u << i;
                        tfar = VK(select)(lane, VK(set1)(ti), tfar);
                        hu = VK(select)(lane, VK(set1)(best.u), hu);
                        hv = VK(select)(lane, VK(set1)(best.v), hv);
                        PK_(record_triangle)(h, lane, leaf_block(accel, best.leaf, &scratch), best.lane);
                        done |= 1u << i;
                    }
                } else if (any_from(accel, cur, rp, ray->tnear[i], tf[i], f)) {
                    tfar = VK(select)(lane, VK(set1)(-INFINITY), tfar);
                    done |= 1u << i;
                }
            }
            if (!closest && done == all)
                break;
            tfar_n = PK_(loose)(tfar, exact);
            if (p.frustum)
                fr_tfar = vn_set1(VK(reduce_max)(tfar_n));
            continue;
        }
        /* descend together, the others pushed: for the closest hit the
         * nearest child first (by any ray); for any hit the last child hit
         * first, as occluded1 does (San Miguel's shadow packets of 8:
         * 0.60x -> 0.72x of Embree's, rtktool bench, 1 thread) */
        while (!(cur & RTK_BVH4_LEAF_BIT)) {
            const node_t *n = &BVHN_NODES(accel)[cur];
            uint32_t next = RTK_BVH4_EMPTY;
            vk next_dist = cur_dist;
            unsigned cand = 0; /* the children worth testing ray by ray */
            if (p.frustum)
                cand = PK_(frustum_intersect)(n, &p, fr_tfar);
            else
                for (int i = 0; i < RTK_BVHN && n->child[i] != RTK_BVH4_EMPTY; i++)
                    cand |= 1u << i;
            for (; cand; cand &= cand - 1) {
                const int i = __builtin_ctz(cand);
                vk dist;
                if (!(p.frustum ? PK_(box_intersect_octant)(n, i, &p, tfar_n, &dist)
                                : PK_(box_intersect)(n, i, &p, tfar_n, &dist)))
                    continue;
                /* its memory asked for now, as the single-ray kernel does:
                 * the other children's tests hide some of the wait (rtktool
                 * bench, avx2 against the build before, packets of 8:
                 * dragon.ply +2-5%, San Miguel 0-3%; asked for every child
                 * the frustum lets through instead: 1-4% behind this) */
                prefetch_child(accel, n, i);
                if (next == RTK_BVH4_EMPTY) {
                    next = n->child[i];
                    next_dist = dist;
                } else if (!closest || VKB(mask)(VK(lt)(dist, next_dist))) {
                    stack[sp++] = (PK_(pstack_entry)){.dist = next_dist, .ref = next};
                    next = n->child[i];
                    next_dist = dist;
                } else {
                    stack[sp++] = (PK_(pstack_entry)){.dist = dist, .ref = n->child[i]};
                }
            }
            if (next == RTK_BVH4_EMPTY)
                break;
            cur = next;
            cur_dist = next_dist;
        }
        if (!(cur & RTK_BVH4_LEAF_BIT))
            continue;
        /* Only the rays that entered the leaf's box test its triangles, as
         * alone: a ray grazing a triangle's plane can get a hit whose
         * rounded position lies outside the triangle's box, and it must not
         * get it here when it would not alone. */
        const vkb entered = VK(le)(cur_dist, tfar);
        const vkb entered_n = VK(le)(cur_dist, tfar_n); /* (exact) */
        int any = 0;
        const uint32_t first = rtk_leaf_first(cur), end = first + rtk_leaf_blocks(cur);
        for (uint32_t leaf = first; leaf < end; leaf++) {
            block_t scratch;
            const block_t *t = leaf_block(accel, leaf, &scratch);
            for (int j = 0; j < 4 && t->prim[j] != RTK_BVH4_EMPTY; j++) {
                vk U, V, T, absdet, floor = VK(set1)(-INFINITY);
                vkb ok;
                unsigned in_double;
                if (exact) {
                    /* tested up to the loose tfar; hit by the single-ray
                     * kernel's test against tfar; a near tie where a ray
                     * with a hit meets another triangle within the band.
                     * (A lane the watertight test decided in double, hit
                     * within the loose tfar, is traced alone as well: its
                     * distance was compared with tfar in double.) */
                    const vkb okl = PK_(triangle_intersect)(t, j, &p, tfar_n, &U, &V, &T, &absdet, &in_double);
                    if (!VKB(mask)(okl))
                        continue;
                    /* (distances raised to the hit floor, as alone) */
                    floor = PK_(hit_floor)(t, j, &p);
                    const vk tr = VK(mul)(T, VK(div)(VK(set1)(1.0f), absdet));
                    const vk te = VK(select)(VK(lt)(tr, floor), floor, tr);
                    ok = VKB(and)(VKB(and)(okl, entered), VK(le)(T, VK(mul)(tfar, absdet)));
                    ok = VKB(andnot)(ok, VK(gt)(floor, tfar));
                    const vk low = VK(sub)(tfar, VK(mul)(VK(abs)(tfar), VK(set1)(PK_TIE_REL)));
                    const vkb near = VKB(andnot)(VKB(and)(VKB(and)(okl, entered_n), VK(ge)(te, low)), VK(gt)(floor, tfar_n));
                    *ties |= ((unsigned)VKB(mask)(near) & done) |
                             (in_double & (unsigned)VKB(mask)(VKB(and)(okl, entered_n)));
                } else {
                    ok = VKB(and)(PK_(triangle_intersect)(t, j, &p, tfar, &U, &V, &T, &absdet, &in_double), entered);
                    if (closest && VKB(mask)(ok)) {
                        floor = PK_(hit_floor)(t, j, &p);
                        ok = VKB(andnot)(ok, VK(gt)(floor, tfar));
                    }
                }
                unsigned hit = (unsigned)VKB(mask)(ok);
                if (hit && __builtin_expect(feat != 0, 0)) {
                    const unsigned acc =
                        PK_(accept)(accel, t, j, ray, hit, U, V, T, absdet, floor, p.tnear, tfar, !closest, q);
                    if (acc != hit) {
                        hit = acc;
                        ok = VKB(and)(ok, PK_(lanes_mask)(acc));
                    }
                }
                if (!hit)
                    continue;
                any = 1;
                /* blends, not lane stores: a vector load of just-stored lanes
                 * would stall on store forwarding */
                if (closest) {
                    const vk rcp = VK(div)(VK(set1)(1.0f), absdet);
                    vk tt = VK(mul)(T, rcp);
                    tt = VK(select)(VK(lt)(tt, floor), floor, tt); /* the hit floor */
                    tt = VK(min)(VK(max)(tt, p.tnear), tfar); /* the clamp of the single-ray kernel */
                    /* A hit nearer than its leaf's entry distance (a ray
                     * grazing a triangle's plane: the rounded hit lies
                     * outside the box; with the hit floor by no more than
                     * about 2^-20 of it, unless the vertices lie much
                     * farther from the world's origin than from the ray's)
                     * is found only where the leaf is visited before a hit
                     * beyond that hit prunes it: alone. */
                    if (exact)
                        *ties |= (unsigned)VKB(mask)(VKB(and)(ok, VK(lt)(tt, cur_dist)));
                    tfar = VK(select)(ok, tt, tfar);
                    tfar_n = PK_(loose)(tfar, exact);
                    hu = VK(select)(ok, VK(mul)(U, rcp), hu);
                    hv = VK(select)(ok, VK(mul)(V, rcp), hv);
                    PK_(record_triangle)(h, ok, t, j);
                } else
                    tfar = VK(select)(ok, VK(set1)(-INFINITY), tfar);
                done |= hit;
            }
        }
        if (any)
            tfar_n = PK_(loose)(tfar, exact);
        if (any && p.frustum)
            fr_tfar = vn_set1(VK(reduce_max)(tfar_n));
        if (!closest && done == all)
            break;
    }
    VK(store)(h->t, tfar);
    VK(store)(h->u, hu);
    VK(store)(h->v, hv);
    h->hit = done;
}

/* Whether the packet's rays are better traced one by one from the root,
 * each with the single-ray kernel's steps, interleaved as a stream
 * (traverse_stream.h): their direction signs disagree on some axis (no
 * frustum) and their origins lie further apart than a sixteenth of the
 * tree's largest side, as a path tracer's later bounces do.  Such rays
 * share hardly a node below the root, and the packet traversal paid for
 * its set-up and for each ray's own set-up when it split, with the ray
 * kept in memory where the entry point keeps it in registers.  rtktool
 * bench's incoherent set (1 thread, avx2, against Embree isa=avx2, two
 * rounds): packets of 8 0.75x-0.79x -> 0.92x-0.97x on San Miguel,
 * 0.78x-0.79x -> 0.90x-0.94x on the dragon, of 4 and 16 alike, through the
 * single-ray entry point one ray after the other; interleaved, the dragon's
 * 1.64x (packets of 8; 4: 1.43x, 16: 1.68x).  The diffuse set, whose
 * packets are neighbouring pixels' bounces (close origins), and the
 * coherent sets keep the packet traversal.  (By the signs alone, San
 * Miguel's diffuse packets lost 5%.  By the spread alone, so that sun rays
 * from scattered points went interleaved too: dragon.ply's sun packets of
 * 8 1.64x Embree's, San Miguel's 0.63x, whose rays mostly test the top of
 * the tree and leave: such any-hit packets are measured, PK_SPREAD.) */
#ifndef RTK_PK_KINDS
#define RTK_PK_KINDS /* (this header is included once per packet width) */
enum { PK_COHERENT, PK_SCATTERED, PK_SPREAD };
#endif
/* PK_SCATTERED for such a packet (or one with a zero direction component,
 * below); for an any-hit packet whose direction signs agree but whose
 * origins lie that far apart (sun rays from scattered points:
 * PK_(occluded_spread) below), PK_SPREAD; PK_COHERENT for the rest. */
static inline int PK_(scattered)(const rayK *r, const int32_t *valid, const rtk_accel *accel, int occluded)
{
    const vkb active = VKB(load)(valid);
    const unsigned all = (unsigned)VKB(mask)(active);
    const vk zero = VK(set1)(0.0f);
    const unsigned nx = (unsigned)VKB(mask)(VK(lt)(VK(load)(r->dir_x), zero)) & all;
    const unsigned ny = (unsigned)VKB(mask)(VK(lt)(VK(load)(r->dir_y), zero)) & all;
    const unsigned nz = (unsigned)VKB(mask)(VK(lt)(VK(load)(r->dir_z), zero)) & all;
#if RTK_SIMD_HAS_FMA
    /* A zero direction component: the single-ray kernel takes the
     * subtract-then-multiply test for it (ray_pre_init), whose far plane
     * is exact where the fused test's padding is not (an origin near 0):
     * the stream's steps give the ray that answer. */
    if (((unsigned)VKB(mask)(PK_(zero_dir)(VK(load)(r->dir_x))) | (unsigned)VKB(mask)(PK_(zero_dir)(VK(load)(r->dir_y))) |
         (unsigned)VKB(mask)(PK_(zero_dir)(VK(load)(r->dir_z)))) & all)
        return PK_SCATTERED;
#endif
    const float *org[3] = {r->org_x, r->org_y, r->org_z};
    if (!((nx && nx != all) || (ny && ny != all) || (nz && nz != all))) {
        if (!occluded || !all)
            return PK_COHERENT;
        /* the first and the last active ray's origins further apart than
         * the sixteenth on some axis: a few scalar steps (the spread of
         * all of them, by reductions, cost San Miguel's shadow packets of
         * 8, some 300 cycles each, 6-9%) */
        const int a = __builtin_ctz(all), b = 31 - __builtin_clz(all);
        const float limit = accel->extent * (1.0f / 16.0f);
        int far = 0;
        for (int k = 0; k < 3; k++)
            far |= fabsf(org[k][b] - org[k][a]) > limit;
        return far ? PK_SPREAD : PK_COHERENT;
    }
    const vk pinf = VK(set1)(INFINITY), ninf = VK(set1)(-INFINITY);
    float spread = 0.0f;
    for (int k = 0; k < 3; k++) {
        const vk o = VK(load)(org[k]);
        const float d = VK(reduce_max)(VK(select)(active, o, ninf)) - VK(reduce_min)(VK(select)(active, o, pinf));
        spread = d > spread ? d : spread;
    }
    return spread > accel->extent * (1.0f / 16.0f) ? PK_SCATTERED : PK_COHERENT;
}

#if !RTK_MOTION
/* Any-hit packets whose direction signs agree but whose origins lie far
 * apart (PK_SPREAD: sun rays from scattered points) have no way that serves
 * every scene: interleaved as a stream, dragon.ply's sun packets of 8 ran
 * 1.64x Embree's packets, San Miguel's 0.64x, whose rays mostly test the
 * top of the tree and leave; by the packet traversal 0.99x and 0.92x
 * (rtktool bench --only trace --api packet8 --rays sun, 1 thread, avx2).
 * So the tree keeps the way they take (rtk_accel.pk_way), and about one
 * call in 64 (picked by its first origin's bits, so that the other calls
 * neither time themselves nor look up a thread's state) takes either way
 * by turns, timed; once each way has PK_SAMPLES of them, the other way is
 * taken if it costs fewer cycles per ray by an eighth.  Only ever a choice of speed: either way gives
 * each ray rtk_occluded1's answer.  (The stream's coherent groups come back
 * to the packet kernels only with their origins within the sixteenth, so
 * never as PK_SPREAD.) */
#ifndef RTK_PK_SAMPLES
#define RTK_PK_SAMPLES
enum { PK_SAMPLES = 64 };
#endif
#endif

#if !RTK_MOTION
/* The slots a scattered packet's rays are interleaved in (traverse_stream.h):
 * one per ray, at most the stream kernels' number. */
#define PK_SLOTS (RTK_PACKET < RTK_STREAM_K ? RTK_PACKET : RTK_STREAM_K)
#endif

/* The rays of h.hit take their closest hits from h. */
static inline __attribute__((always_inline)) void PK_(store_hits)(const rtk_accel *accel, PK_(hits) *h, rayhitK *rh)
{
    if (!h->hit)
        return;
    if (__builtin_expect(accel->quads != 0, 0))
        for (unsigned m = h->hit; m; m &= m - 1) {
            const int i = __builtin_ctz(m);
            uint32_t prim, geom;
            memcpy(&prim, &h->prim[i], sizeof prim);
            memcpy(&geom, &h->geom[i], sizeof geom);
            closest_hit_quad(accel, geom, &prim, &h->u[i], &h->v[i]);
            h->prim[i] = PK_(bits_float)(prim);
        }
    /* whole rows, the rays without a hit blended back as they were */
    const vkb m = PK_(lanes_mask)(h->hit);
    VK(store)(rh->ray.tfar, VK(select)(m, VK(load)(h->t), VK(load)(rh->ray.tfar)));
    VK(store)(rh->hit.Ng_x, VK(select)(m, VK(load)(h->ng[0]), VK(load)(rh->hit.Ng_x)));
    VK(store)(rh->hit.Ng_y, VK(select)(m, VK(load)(h->ng[1]), VK(load)(rh->hit.Ng_y)));
    VK(store)(rh->hit.Ng_z, VK(select)(m, VK(load)(h->ng[2]), VK(load)(rh->hit.Ng_z)));
    VK(store)(rh->hit.u, VK(select)(m, VK(load)(h->u), VK(load)(rh->hit.u)));
    VK(store)(rh->hit.v, VK(select)(m, VK(load)(h->v), VK(load)(rh->hit.v)));
    /* the ids as the bits of floats (h->prim, h->geom hold them so): blends
     * move bits unchanged, and a row at a time, not a lane */
    VK(store)((float *)rh->hit.primID, VK(select)(m, VK(load)(h->prim), VK(load)((const float *)rh->hit.primID)));
    VK(store)((float *)rh->hit.geomID, VK(select)(m, VK(load)(h->geom), VK(load)((const float *)rh->hit.geomID)));
    VK(store)((float *)rh->hit.instID,
              VK(select)(m, VK(set1)(PK_(bits_float)(RTK_INVALID_GEOMETRY_ID)), VK(load)((const float *)rh->hit.instID)));
}

void PK_INTERSECT(const rtk_accel *accel, const int32_t *valid, void *packet, const rtk_query *q)
{
    if (accel->root == RTK_BVH4_EMPTY)
        return;
    rayhitK *rh = packet;
#if !RTK_MOTION
    if (PK_(scattered)(&rh->ray, valid, accel, 0) == PK_SCATTERED) {
        /* rays that share hardly a node: interleaved as a stream, each
         * with the single-ray kernel's steps (so its answer is
         * rtk_intersect1's), their cache misses overlapped */
        _Alignas(16) rtk_rayhit one[RTK_PACKET];
        void *list[RTK_PACKET];
        uint32_t n = 0;
        for (int i = 0; i < RTK_PACKET; i++) {
            if (!valid[i])
                continue;
            one[i].hit.geomID = RTK_INVALID_GEOMETRY_ID;
            PK_(lane_ray_to)(&rh->ray, i, &one[i].ray);
            list[n++] = &one[i];
        }
        stream_slot slots[PK_SLOTS];
        stream_trace(accel, list, n, q, 1, slots, PK_SLOTS);
        for (int i = 0; i < RTK_PACKET; i++) {
            if (!valid[i] || one[i].hit.geomID == RTK_INVALID_GEOMETRY_ID)
                continue;
            rh->ray.tfar[i] = one[i].ray.tfar;
            rh->hit.Ng_x[i] = one[i].hit.Ng_x;
            rh->hit.Ng_y[i] = one[i].hit.Ng_y;
            rh->hit.Ng_z[i] = one[i].hit.Ng_z;
            rh->hit.u[i] = one[i].hit.u;
            rh->hit.v[i] = one[i].hit.v;
            rh->hit.primID[i] = one[i].hit.primID;
            rh->hit.geomID[i] = one[i].hit.geomID;
            rh->hit.instID[i] = one[i].hit.instID;
        }
        return;
    }
#endif
    PK_(hits) h;
    PK_(traverse)(accel, valid, &rh->ray, 1, &h, q, NULL);
    PK_(store_hits)(accel, &h, rh);
}

#if !RTK_MOTION
/* The closest hits of a coherent group of a stream (traverse_stream.h),
 * whose rays must each get rtk_intersect1's answer bit for bit.  The packet
 * traversal's tests are the single-ray kernel's lane by lane, so a ray's
 * answer can differ only where two triangles tie within rounding and the
 * order of the tests picks one (the packet's order is not the ray's
 * alone), where the watertight test decided a lane in double precision
 * (it compares that distance with tfar in double), or where the ray takes
 * another node test alone (ray_pre.fma).  Returns those rays' lanes, left as they were, for the caller to trace
 * alone; the others' hits are written as by PK_INTERSECT. */
unsigned PK_INTERSECT_EXACT(const rtk_accel *accel, const int32_t *valid, void *packet, const rtk_query *q)
{
    if (accel->root == RTK_BVH4_EMPTY)
        return 0;
    rayhitK *rh = packet;
    PK_(hits) h;
    unsigned ties = 0;
    PK_(traverse)(accel, valid, &rh->ray, 1, &h, q, &ties);
    h.hit &= ~ties;
    PK_(store_hits)(accel, &h, rh);
    return ties;
}
#endif

/* The packet traversal's any hits. */
static inline __attribute__((always_inline)) void PK_(occluded_packet)(const rtk_accel *accel, const int32_t *valid,
                                                                       rayK *r, const rtk_query *q)
{
    PK_(hits) h;
    PK_(traverse)(accel, valid, r, 0, &h, q, NULL);
    if (h.hit) /* a row, not lane by lane (see PK_INTERSECT) */
        VK(store)(r->tfar, VK(select)(PK_(lanes_mask)(h.hit), VK(set1)(-INFINITY), VK(load)(r->tfar)));
}

#if !RTK_MOTION
/* The any hits of the packet's rays interleaved as a stream (see
 * PK_INTERSECT); how many rays there were. */
static __attribute__((noinline)) uint32_t PK_(occluded_interleaved)(const rtk_accel *accel, const int32_t *valid,
                                                                    rayK *r, const rtk_query *q)
{
    _Alignas(16) rtk_ray one[RTK_PACKET];
    void *list[RTK_PACKET];
    uint32_t n = 0;
    for (int i = 0; i < RTK_PACKET; i++) {
        if (!valid[i])
            continue;
        PK_(lane_ray_to)(r, i, &one[i]);
        list[n++] = &one[i];
    }
    stream_slot slots[PK_SLOTS];
    stream_trace(accel, list, n, q, 0, slots, PK_SLOTS);
    for (int i = 0; i < RTK_PACKET; i++)
        if (valid[i] && one[i].tfar == -INFINITY)
            r->tfar[i] = -INFINITY;
    return n;
}

/* A PK_SPREAD packet: the tree's way, or in a sampled call either way by
 * turns, timed (out of line, so that the other packets' path stays as it
 * was). */
static __attribute__((noinline)) void PK_(occluded_spread)(const rtk_accel *accel, const int32_t *valid, rayK *r,
                                                           const rtk_query *q)
{
    rtk_accel *t = (rtk_accel *)(uintptr_t)accel; /* (its choice is the traversals' to change) */
    const unsigned all = (unsigned)VKB(mask)(VKB(load)(valid));
    uint32_t bits;
    memcpy(&bits, &r->org_x[__builtin_ctz(all)], sizeof bits);
    const uint32_t h = (bits ^ bits >> 13) * 0x9e3779b1u;
    if (h >> 26) { /* (63 calls in 64) */
        if (atomic_load_explicit(&t->pk_way, memory_order_relaxed))
            PK_(occluded_interleaved)(accel, valid, r, q);
        else
            PK_(occluded_packet)(accel, valid, r, q);
        return;
    }
    const int way = h >> 25 & 1;
    const uint64_t t0 = rtk_cycles();
    if (way)
        PK_(occluded_interleaved)(accel, valid, r, q);
    else
        PK_(occluded_packet)(accel, valid, r, q);
    const uint64_t cycles = rtk_cycles() - t0;
    atomic_fetch_add_explicit(&t->pk_cycles[way], cycles, memory_order_relaxed);
    atomic_fetch_add_explicit(&t->pk_rays[way], (uint64_t)__builtin_popcount(all), memory_order_relaxed);
    const uint32_t calls = atomic_fetch_add_explicit(&t->pk_calls[way], 1, memory_order_relaxed) + 1;
    if (calls < PK_SAMPLES || atomic_load_explicit(&t->pk_calls[!way], memory_order_relaxed) < PK_SAMPLES)
        return;
    /* both ways sampled: the other way is kept when it takes fewer cycles
     * per ray by an eighth (single packets' costs spread widely, and a
     * wrong turn on San Miguel's sun packets costs 1.4x), c_o / r_o * 9/8 <
     * c_w / r_w; another thread's samples may land between the loads: a
     * choice of speed */
    const uint64_t c0 = atomic_load_explicit(&t->pk_cycles[0], memory_order_relaxed),
                   c1 = atomic_load_explicit(&t->pk_cycles[1], memory_order_relaxed),
                   r0 = atomic_load_explicit(&t->pk_rays[0], memory_order_relaxed),
                   r1 = atomic_load_explicit(&t->pk_rays[1], memory_order_relaxed);
    const uint32_t kept = atomic_load_explicit(&t->pk_way, memory_order_relaxed) != 0;
    const uint64_t ck = kept ? c1 : c0, rk = kept ? r1 : r0, co = kept ? c0 : c1, ro = kept ? r0 : r1;
    if (co * rk * 9 < ck * ro * 8)
        atomic_store_explicit(&t->pk_way, !kept, memory_order_relaxed);
    for (int w = 0; w < 2; w++) {
        atomic_store_explicit(&t->pk_calls[w], 0, memory_order_relaxed);
        atomic_store_explicit(&t->pk_cycles[w], 0, memory_order_relaxed);
        atomic_store_explicit(&t->pk_rays[w], 0, memory_order_relaxed);
    }
}
#endif

void PK_OCCLUDED(const rtk_accel *accel, const int32_t *valid, void *packet, const rtk_query *q)
{
    if (accel->root == RTK_BVH4_EMPTY)
        return;
    rayK *r = packet;
#if !RTK_MOTION
    const int kind = PK_(scattered)(r, valid, accel, 1);
    if (kind == PK_SCATTERED) {
        PK_(occluded_interleaved)(accel, valid, r, q);
        return;
    }
    if (kind == PK_SPREAD) {
        PK_(occluded_spread)(accel, valid, r, q);
        return;
    }
#endif
    PK_(occluded_packet)(accel, valid, r, q);
}

#undef vk
#undef vkb
#undef rayhitK
#undef rayK
#undef VK
#undef VKB
#undef PK_SWITCH
#undef PK_SWITCH_FRUSTUM
#undef PK_SLOTS
#undef PK_NEAR_SCALE
#undef PK_ZERO_DIR_INF
#undef PK_FAR_SCALE
#undef PK_NAME_
#undef PK_NAME
#undef PK_INTERSECT
#undef PK_INTERSECT_EXACT
#undef PK_OCCLUDED
#undef PK_
#undef RTK_PACKET
