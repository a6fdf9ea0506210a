/*
 * Packet traversal of the bvhN.triangle4 layouts and bvh4.triangle4i: K rays (K = 4 or 8) through
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
 */
#include <math.h>
#include <stdint.h>

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

#define PK_NAME_(n, k, what) rtk_bvh##n##_##what##k
#define PK_NAME(n, k, what) PK_NAME_(n, k, what)
#define PK_INTERSECT RTK_SYM(PK_NAME(BVHN_TAG, RTK_PACKET, intersect))
#define PK_OCCLUDED RTK_SYM(PK_NAME(BVHN_TAG, RTK_PACKET, occluded))
/* static helpers, one set per packet width */
#define PK_(name) RTK_CAT(RTK_CAT(name, _k), RTK_PACKET)

/* The packet, loaded once.  rinv_lo / rinv_hi are the reciprocal direction
 * for the lower and upper planes, the one of the far plane (by the sign of
 * the direction) scaled by RTK_BOX_FAR_SCALE, as inv_far in ray_pre. */
typedef struct PK_(packet_pre) {
    vk org[3], dir[3], rinv_lo[3], rinv_hi[3];
#if RTK_SIMD_HAS_FMA
    vk c_lo[3], c_hi[3]; /* org * rinv moved toward the near side, as c_near / c_far in ray_pre */
#endif
    vk tnear;
} PK_(packet_pre);

static inline void PK_(packet_pre_init)(PK_(packet_pre) *p, const rayK *r, vkb active)
{
    const float *org[3] = {r->org_x, r->org_y, r->org_z}, *dir[3] = {r->dir_x, r->dir_y, r->dir_z};
    const vk tiny = VK(set1)(1e-18f), one = VK(set1)(1.0f), zero = VK(set1)(0.0f);
    const vk scale = VK(set1)(RTK_BOX_FAR_SCALE);
    for (int k = 0; k < 3; k++) {
        p->org[k] = VK(load)(org[k]);
        p->dir[k] = VK(load)(dir[k]);
        /* as safe_rcp: components below 1e-18 in magnitude become +-1e-18 */
        const vk d = VK(select)(VK(lt)(VK(abs)(p->dir[k]), tiny), VK(xor_sign)(tiny, p->dir[k]), p->dir[k]);
        const vk rinv = VK(div)(one, d), rinv_far = VK(mul)(rinv, scale);
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
        const vk c_lo = VK(mul)(p->org[k], p->rinv_lo[k]), c_hi = VK(mul)(p->org[k], p->rinv_hi[k]);
        const vk e_lo = VK(add)(VK(mul)(VK(abs)(c_lo), VK(set1)(0x1p-22f)), VK(set1)(0x1p-126f));
        const vk e_hi = VK(add)(VK(mul)(VK(abs)(c_hi), VK(set1)(0x1p-22f)), VK(set1)(0x1p-126f));
        p->c_lo[k] = VK(add)(c_lo, VK(xor_sign)(e_lo, rinv)); /* lower is near where rinv > 0 */
        p->c_hi[k] = VK(sub)(c_hi, VK(xor_sign)(e_hi, rinv));
#endif
    }
    /* inactive lanes start beyond everything: they never enter a box */
    p->tnear = VK(select)(active, VK(load)(r->tnear), VK(set1)(INFINITY));
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
    const vk t0x = VK(mul)(VK(sub)(VK(set1)(n->lower_x[i]), p->org[0]), p->rinv_lo[0]);
    const vk t1x = VK(mul)(VK(sub)(VK(set1)(n->upper_x[i]), p->org[0]), p->rinv_hi[0]);
    const vk t0y = VK(mul)(VK(sub)(VK(set1)(n->lower_y[i]), p->org[1]), p->rinv_lo[1]);
    const vk t1y = VK(mul)(VK(sub)(VK(set1)(n->upper_y[i]), p->org[1]), p->rinv_hi[1]);
    const vk t0z = VK(mul)(VK(sub)(VK(set1)(n->lower_z[i]), p->org[2]), p->rinv_lo[2]);
    const vk t1z = VK(mul)(VK(sub)(VK(set1)(n->upper_z[i]), p->org[2]), p->rinv_hi[2]);
#endif
    const vk tmin = VK(max)(VK(max)(VK(min)(t0x, t1x), VK(min)(t0y, t1y)), VK(max)(VK(min)(t0z, t1z), p->tnear));
    const vk tmax = VK(min)(VK(min)(VK(max)(t0x, t1x), VK(max)(t0y, t1y)), VK(min)(VK(max)(t0z, t1z), tfar));
    const vkb hit = VK(le)(tmin, tmax);
    *dist = VK(select)(hit, tmin, VK(set1)(NAN));
    return VKB(mask)(hit);
}

/* Lane j of a leaf block against the packet, the arithmetic of
 * triangle4_intersect with the ray and triangle roles of the lanes swapped. */
static inline int PK_(triangle_intersect)(const rtk_triangle4 *t, int j, const PK_(packet_pre) *p, vk tfar, vk *U_out,
                                          vk *V_out, vk *T_out, vk *absdet_out)
{
    const vk e1x = VK(set1)(t->e1x[j]), e1y = VK(set1)(t->e1y[j]), e1z = VK(set1)(t->e1z[j]);
    const vk e2x = VK(set1)(t->e2x[j]), e2y = VK(set1)(t->e2y[j]), e2z = VK(set1)(t->e2z[j]);
    const vk dx = p->dir[0], dy = p->dir[1], dz = p->dir[2];
    const vk px = VK(sub)(VK(mul)(dy, e2z), VK(mul)(dz, e2y));
    const vk py = VK(sub)(VK(mul)(dz, e2x), VK(mul)(dx, e2z));
    const vk pz = VK(sub)(VK(mul)(dx, e2y), VK(mul)(dy, e2x));
    const vk det = VK(add)(VK(add)(VK(mul)(e1x, px), VK(mul)(e1y, py)), VK(mul)(e1z, pz));
    const vk absdet = VK(abs)(det);
    const vk sx = VK(sub)(p->org[0], VK(set1)(t->v0x[j]));
    const vk sy = VK(sub)(p->org[1], VK(set1)(t->v0y[j]));
    const vk sz = VK(sub)(p->org[2], VK(set1)(t->v0z[j]));
    const vk U = VK(xor_sign)(VK(add)(VK(add)(VK(mul)(sx, px), VK(mul)(sy, py)), VK(mul)(sz, pz)), det);
    const vk qx = VK(sub)(VK(mul)(sy, e1z), VK(mul)(sz, e1y));
    const vk qy = VK(sub)(VK(mul)(sz, e1x), VK(mul)(sx, e1z));
    const vk qz = VK(sub)(VK(mul)(sx, e1y), VK(mul)(sy, e1x));
    const vk V = VK(xor_sign)(VK(add)(VK(add)(VK(mul)(dx, qx), VK(mul)(dy, qy)), VK(mul)(dz, qz)), det);
    const vk T = VK(xor_sign)(VK(add)(VK(add)(VK(mul)(e2x, qx), VK(mul)(e2y, qy)), VK(mul)(e2z, qz)), det);
    const vk zero = VK(set1)(0.0f);
    vkb ok = VKB(and)(VK(ge)(U, zero), VK(ge)(V, zero));
    ok = VKB(and)(ok, VK(le)(VK(add)(U, V), absdet));
    ok = VKB(and)(ok, VK(gt)(absdet, zero));
    ok = VKB(and)(ok, VK(ge)(T, VK(mul)(p->tnear, absdet)));
    ok = VKB(and)(ok, VK(le)(T, VK(mul)(tfar, absdet)));
    *U_out = U;
    *V_out = V;
    *T_out = T;
    *absdet_out = absdet;
    return VKB(mask)(ok);
}

typedef struct PK_(pstack_entry) {
    vk dist; /* per ray: entry distance, NaN for rays that do not enter */
    uint32_t ref;
} PK_(pstack_entry);

/* A lane as a single ray, for finishing a subtree alone. */
static inline void PK_(lane_ray_pre)(ray_pre *p, const rayK *r, int i)
{
    const rtk_ray one = {.org_x = r->org_x[i], .org_y = r->org_y[i], .org_z = r->org_z[i],
                         .dir_x = r->dir_x[i], .dir_y = r->dir_y[i], .dir_z = r->dir_z[i]};
    ray_pre_init(p, &one);
}

/* The packet traversal both queries share; `closest` selects the query and
 * is a constant in each kernel (the function is inlined there).  Outputs are
 * 64-byte aligned arrays of K: tfar, u, v, and per ray the hit as
 * leaf * 4 + lane (closest; left alone where no hit), or in *ref_out the mask
 * of rays that found any hit (occluded). */
static inline __attribute__((always_inline)) void PK_(traverse)(const rtk_accel *accel, const int32_t *valid,
                                                                const rayK *ray, int closest, float *tfar_out,
                                                                float *u_out, float *v_out, uint32_t *ref_out)
{
    const vkb active = VKB(load)(valid);
    PK_(packet_pre) p;
    PK_(packet_pre_init)(&p, ray, active);
    vk tfar = VK(select)(active, VK(load)(ray->tfar), VK(set1)(-INFINITY));
    vk hu = VK(set1)(0.0f), hv = hu;
    const unsigned all = VKB(mask)(active);
    unsigned done = 0; /* occluded: rays that found a hit */
    _Alignas(64) float lane_t[RTK_PACKET], lane_u[RTK_PACKET], lane_v[RTK_PACKET];

    PK_(pstack_entry) stack[RTK_BVHN_STACK_SIZE(RTK_BVHN) + 1];
    int sp = 0;
    stack[sp++] = (PK_(pstack_entry)){.dist = p.tnear, .ref = accel->root};
    while (sp > 0) {
        sp--;
        uint32_t cur = stack[sp].ref;
        vk cur_dist = stack[sp].dist;
        const unsigned want = (unsigned)VKB(mask)(VK(le)(cur_dist, tfar));
        if (!want)
            continue;
        if (__builtin_popcount(want) <= PK_SWITCH) {
            /* few rays want this subtree: each finishes it alone */
            VK(store)(lane_t, tfar);
            VK(store)(lane_u, hu);
            VK(store)(lane_v, hv);
            for (unsigned m = want; m; m &= m - 1) {
                const int i = __builtin_ctz(m);
                ray_pre rp;
                PK_(lane_ray_pre)(&rp, ray, i);
                if (closest) {
                    closest_hit best = CLOSEST_HIT_NONE;
                    closest_from(accel, cur, &rp, ray->tnear[i], &lane_t[i], &best);
                    if (best.lane >= 0) {
                        lane_u[i] = best.u;
                        lane_v[i] = best.v;
                        ref_out[i] = best.leaf * 4u + (uint32_t)best.lane;
                    }
                } else if (any_from(accel, cur, &rp, ray->tnear[i], lane_t[i])) {
                    lane_t[i] = -INFINITY;
                    done |= 1u << i;
                }
            }
            tfar = VK(load)(lane_t);
            hu = VK(load)(lane_u);
            hv = VK(load)(lane_v);
            if (!closest && done == all)
                break;
            continue;
        }
        /* descend together, nearest child first (by any ray), the others pushed */
        while (!(cur & RTK_BVH4_LEAF_BIT)) {
            const node_t *n = &BVHN_NODES(accel)[cur];
            uint32_t next = RTK_BVH4_EMPTY;
            vk next_dist = cur_dist;
            for (int i = 0; i < RTK_BVHN && n->child[i] != RTK_BVH4_EMPTY; i++) {
                vk dist;
                if (!PK_(box_intersect)(n, i, &p, tfar, &dist))
                    continue;
                if (next == RTK_BVH4_EMPTY) {
                    next = n->child[i];
                    next_dist = dist;
                } else if (VKB(mask)(VK(lt)(dist, next_dist))) {
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
        const uint32_t leaf = cur & ~RTK_BVH4_LEAF_BIT;
        rtk_triangle4 scratch;
        const rtk_triangle4 *t = leaf_block(accel, leaf, &scratch);
        /* Only the rays that entered the leaf's box test its triangles, as
         * alone: a ray grazing a triangle's plane can get a hit whose
         * rounded position lies outside the triangle's box, and it must not
         * get it here when it would not alone. */
        const unsigned entered = (unsigned)VKB(mask)(VK(le)(cur_dist, tfar));
        for (int j = 0; j < 4 && t->prim[j] != RTK_BVH4_EMPTY; j++) {
            vk U, V, T, absdet;
            unsigned hit = (unsigned)PK_(triangle_intersect)(t, j, &p, tfar, &U, &V, &T, &absdet) & entered;
            if (!hit)
                continue;
            if (closest) {
                VK(store)(lane_t, tfar);
                const vk rcp = VK(div)(VK(set1)(1.0f), absdet);
                vk tt = VK(mul)(T, rcp);
                tt = VK(min)(VK(max)(tt, p.tnear), tfar); /* the clamp of the single-ray kernel */
                _Alignas(64) float tv[RTK_PACKET], uv[RTK_PACKET], vv[RTK_PACKET];
                VK(store)(tv, tt);
                VK(store)(uv, VK(mul)(U, rcp));
                VK(store)(vv, VK(mul)(V, rcp));
                VK(store)(lane_u, hu);
                VK(store)(lane_v, hv);
                for (unsigned m = hit; m; m &= m - 1) {
                    const int i = __builtin_ctz(m);
                    lane_t[i] = tv[i];
                    lane_u[i] = uv[i];
                    lane_v[i] = vv[i];
                    ref_out[i] = leaf * 4u + (uint32_t)j;
                }
                tfar = VK(load)(lane_t);
                hu = VK(load)(lane_u);
                hv = VK(load)(lane_v);
            } else {
                VK(store)(lane_t, tfar);
                for (unsigned m = hit; m; m &= m - 1)
                    lane_t[__builtin_ctz(m)] = -INFINITY;
                tfar = VK(load)(lane_t);
                done |= hit;
            }
        }
        if (!closest && done == all)
            break;
    }
    VK(store)(tfar_out, tfar);
    VK(store)(u_out, hu);
    VK(store)(v_out, hv);
    if (!closest)
        *ref_out = done;
}

void PK_INTERSECT(const rtk_accel *accel, const int32_t *valid, void *packet)
{
    if (accel->root == RTK_BVH4_EMPTY)
        return;
    rayhitK *rh = packet;
    _Alignas(64) float t[RTK_PACKET], u[RTK_PACKET], v[RTK_PACKET];
    uint32_t ref[RTK_PACKET];
    for (int i = 0; i < RTK_PACKET; i++)
        ref[i] = UINT32_MAX;
    PK_(traverse)(accel, valid, &rh->ray, 1, t, u, v, ref);
    for (int i = 0; i < RTK_PACKET; i++) {
        if (ref[i] == UINT32_MAX)
            continue;
        const closest_hit best = {.leaf = ref[i] / 4, .lane = (int)(ref[i] % 4)};
        float ng[3];
        closest_hit_record(accel, &best, ng, &rh->hit.primID[i], &rh->hit.geomID[i]);
        rh->ray.tfar[i] = t[i];
        rh->hit.Ng_x[i] = ng[0];
        rh->hit.Ng_y[i] = ng[1];
        rh->hit.Ng_z[i] = ng[2];
        rh->hit.u[i] = u[i];
        rh->hit.v[i] = v[i];
        rh->hit.instID[i] = RTK_INVALID_GEOMETRY_ID;
    }
}

void PK_OCCLUDED(const rtk_accel *accel, const int32_t *valid, void *packet)
{
    if (accel->root == RTK_BVH4_EMPTY)
        return;
    rayK *r = packet;
    _Alignas(64) float t[RTK_PACKET], u[RTK_PACKET], v[RTK_PACKET];
    uint32_t done = 0;
    PK_(traverse)(accel, valid, r, 0, t, u, v, &done);
    for (unsigned m = done; m; m &= m - 1)
        r->tfar[__builtin_ctz(m)] = -INFINITY;
}

#undef vk
#undef vkb
#undef rayhitK
#undef rayK
#undef VK
#undef VKB
#undef PK_SWITCH
#undef PK_NAME_
#undef PK_NAME
#undef PK_INTERSECT
#undef PK_OCCLUDED
#undef PK_
#undef RTK_PACKET
