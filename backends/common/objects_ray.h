/*
 * The top level of a two-level scene (layout bvh4.object, objects.c) as a
 * ray walks it: the ray set up for its 4-wide nodes, the node test, and
 * the ray taken into an object's space.  objects.c's traversals and the
 * merged ones of the triangle layouts (traverse_objects.h) share these, so
 * both visit the same boxes in the same order and answer alike.
 */
#ifndef RTK_OBJECTS_RAY_H
#define RTK_OBJECTS_RAY_H
#include <math.h>
#include <stddef.h>
#include <string.h>

#include "backend_common.h"
#include "bvh4_triangle4.h"
#include "simd/simd.h"

/* The ray, broadcast for 4-wide node tests: planes picked once per ray by
 * the signs of the direction (near: lower where the direction is positive,
 * upper where negative), as the triangle kernels do. */
typedef struct obj_ray {
    vfloat4 org[3], inv[3], inv_far[3];
    size_t near_off[3], far_off[3];
} obj_ray;

/* 1 + 2 * gamma(3): the far distances no smaller than the exact ones. */
#define OBJ_FAR_SCALE (1.0f + 2.0f * (3.0f * 0x1p-24f) / (1.0f - 3.0f * 0x1p-24f))

/* What both top-level set-ups (obj_ray_init here, the 8-wide top_ray_init
 * of traverse_objects.h) broadcast: the origin, the reciprocals and the far
 * planes' reciprocals in o, in and inf; returns the direction's sign bits
 * (x, y, z in bits 0..2).  x, y and z at once in lanes 0..2 (lane 3 holds
 * tnear or time and is not used): one division for the three reciprocals
 * instead of three, as the triangle kernels' ray_pre_init does. */
static inline unsigned obj_ray_scalars(const rtk_ray *r, float o[4], float in[4], float inf[4])
{
    const vfloat4 org = vf4_loadu(&r->org_x), dir = vf4_loadu(&r->dir_x);
    /* as the triangle kernels do: no 0 * inf NaN in a near slab, and the
     * reciprocals with the direction's signs (-0.0 included); the far
     * planes' +-inf for a zero direction (vf4_inf_below: NaN for an origin
     * on such a plane, which the node tests drop) */
    const vfloat4 inv = vf4_rcp_clamped(dir, RTK_ZERO_DIR);
    vf4_storeu(o, org);
    vf4_storeu(in, inv);
    vf4_storeu(inf, vf4_mul(vf4_inf_below(inv, dir, RTK_ZERO_DIR), vf4_set1(OBJ_FAR_SCALE)));
    return (unsigned)vf4_signs(dir) & 7;
}

/* The byte offsets of a 4-wide node's near and far planes by the signs of
 * the direction (RTK_PLANE_OFFSET_TABLE, bvh4_triangle4.h).  Chosen per
 * axis and ray instead, they took 40 of a ray's 1,173 instructions in the
 * bunny's 16 instances (callgrind, the avx2 backend alone). */
static const size_t obj_plane_offsets[8][2][3] = RTK_PLANE_OFFSET_TABLE(rtk_bvh4_node);

static inline void obj_ray_init(obj_ray *p, const rtk_ray *r)
{
    _Alignas(16) float o[4], in[4], inf[4];
    const unsigned neg = obj_ray_scalars(r, o, in, inf);
    for (int k = 0; k < 3; k++) {
        p->org[k] = vf4_set1(o[k]);
        p->inv[k] = vf4_set1(in[k]);
        p->inv_far[k] = vf4_set1(inf[k]);
    }
    memcpy(p->near_off, obj_plane_offsets[neg][0], sizeof p->near_off);
    memcpy(p->far_off, obj_plane_offsets[neg][1], sizeof p->far_off);
}

static inline vfloat4 obj_plane(const rtk_bvh4_node *n, size_t off)
{
    return vf4_load((const float *)((const char *)n + off));
}

/* The mask of n's child slots the ray enters within [tnear, tfar], their
 * entry distances in t[].  The four boxes at once (an empty slot's
 * inverted box is never entered). */
static inline unsigned node_entered(const rtk_bvh4_node *n, const obj_ray *p, float tnear, float tfar, float t[4])
{
    /* a far slab's NaN (obj_ray_scalars) dropped: min returns its second
     * operand, the bound so far, where either is NaN */
    vfloat4 tmin = vf4_set1(tnear), tmax = vf4_set1(tfar);
    for (int k = 0; k < 3; k++) {
        tmin = vf4_max(vf4_mul(vf4_sub(obj_plane(n, p->near_off[k]), p->org[k]), p->inv[k]), tmin);
        tmax = vf4_min(vf4_mul(vf4_sub(obj_plane(n, p->far_off[k]), p->org[k]), p->inv_far[k]), tmax);
    }
    vf4_store(t, tmin);
    return (unsigned)vb4_mask(vf4_le(tmin, tmax));
}

/* The children of n the ray enters within [tnear, tfar], nearest first, in
 * ref[] and dist[]; returns how many. */
static inline int node_children(const rtk_bvh4_node *n, const obj_ray *p, float tnear, float tfar, uint32_t ref[4],
                         float dist[4])
{
    _Alignas(16) float t[4];
    unsigned mask = node_entered(n, p, tnear, tfar, t);
    if (!mask)
        return 0;
    /* one or two children, the usual cases, without the sorting loop (the
     * same order: on equal distances the lower slot first).  Callgrind on
     * the bunny's dynamic scene (bench/work_per_ray.py --section twolevel,
     * the backend alone): 2,302 instructions a ray against 2,455. */
    const int c0 = __builtin_ctz(mask);
    if (!(mask & (mask - 1))) {
        ref[0] = n->child[c0];
        dist[0] = t[c0];
        return 1;
    }
    if (__builtin_popcount(mask) == 2) {
        const int c1 = 31 - __builtin_clz(mask), near = t[c1] < t[c0] ? c1 : c0, far = c0 + c1 - near;
        ref[0] = n->child[near];
        dist[0] = t[near];
        ref[1] = n->child[far];
        dist[1] = t[far];
        return 2;
    }
    int count = 0;
    for (; mask; mask &= mask - 1) {
        const int c = __builtin_ctz(mask);
        int i = count++;
        for (; i > 0 && dist[i - 1] > t[c]; i--) {
            dist[i] = dist[i - 1];
            ref[i] = ref[i - 1];
        }
        dist[i] = t[c];
        ref[i] = n->child[c];
    }
    return count;
}

/* The ray's origin and direction taken by the transform whose columns are
 * c0, c1, c2 (the linear part) and c3 (the translation), in lanes 0..2 (lane
 * 3 is not read), into *org and *dir with the ray's tnear and time in lane
 * 3, as the kernels load an rtk_ray; 0 when they are not finite (a
 * transform that overflows the ray): the object is then missed.  Each lane
 * the scalar ((m0 x + m1 y) + m2 z) + m3 of its row in that order, so the
 * same floats (nothing here is contracted into a fused multiply-add).
 * Callgrind on the path tracer's rays through the bunny's 16 instances, the
 * avx2 backend alone: 1,173 instructions a ray against 1,246 with six
 * scalar dot products. */
static inline __attribute__((always_inline)) int xfm_ray(vfloat4 c0, vfloat4 c1, vfloat4 c2, vfloat4 c3,
                                                          const rtk_ray *r, vfloat4 *org, vfloat4 *dir)
{
    const vfloat4 o = vf4_add(
        vf4_add(vf4_add(vf4_mul(c0, vf4_set1(r->org_x)), vf4_mul(c1, vf4_set1(r->org_y))),
                vf4_mul(c2, vf4_set1(r->org_z))),
        c3);
    const vfloat4 d = vf4_add(vf4_add(vf4_mul(c0, vf4_set1(r->dir_x)), vf4_mul(c1, vf4_set1(r->dir_y))),
                              vf4_mul(c2, vf4_set1(r->dir_z)));
    const vbool4 w = vb4_from_bits(8);
    *org = vf4_select(w, vf4_loadu(&r->org_x), o);
    *dir = vf4_select(w, vf4_loadu(&r->dir_x), d);
    const vfloat4 zero = vf4_set1(0.0f); /* 0 * x is 0 where x is finite, else NaN */
    return (vb4_mask(vf4_eq(vf4_add(vf4_mul(zero, o), vf4_mul(zero, d)), zero)) & 7) == 7;
}

/* The ray taken by the world-to-object transform m (3 rows of 4), in
 * `local` (xfm_ray, after one transposition of m); 0 when it is not finite
 * there. */
static inline int to_object_m(const float *m, const rtk_ray *r, rtk_ray *local)
{
    *local = *r;
    vfloat4 c0 = vf4_loadu(m), c1 = vf4_loadu(m + 4), c2 = vf4_loadu(m + 8), c3 = vf4_set1(0.0f);
    vf4_transpose(&c0, &c1, &c2, &c3); /* now c_j = (m[j], m[4 + j], m[8 + j], 0) */
    vfloat4 o, d;
    const int ok = xfm_ray(c0, c1, c2, c3, r, &o, &d);
    /* org and tnear, dir and time each stored as one vector: the kernels
     * load them so, and a 16-byte load over four 4-byte stores would stall
     * on store forwarding */
    vf4_storeu(&local->org_x, o);
    vf4_storeu(&local->dir_x, d);
    return ok;
}

/* A world-to-object transform as the merged walk keeps it
 * (rtk_accel.object_xfms): the columns of m (3 rows of 4), (m[j], m[4 + j],
 * m[8 + j]) at c + 3 j, so that the walk loads them as they are, with no
 * transposition per instance entered (callgrind, the bunny's 16 instances:
 * 22 of a ray's 1,173 instructions).  Each column is loaded 4 wide, so the
 * array holds one float more than its transforms. */
static inline void xfm_to_columns(const float m[12], float c[12])
{
    for (int j = 0; j < 4; j++)
        for (int i = 0; i < 3; i++)
            c[3 * j + i] = m[4 * i + j];
}

static inline void xfm_from_columns(const float c[12], float m[12])
{
    for (int j = 0; j < 4; j++)
        for (int i = 0; i < 3; i++)
            m[4 * i + j] = c[3 * j + i];
}

static inline __attribute__((always_inline)) int to_object_columns(const float *c, const rtk_ray *r, vfloat4 *org,
                                                                    vfloat4 *dir)
{
    return xfm_ray(vf4_loadu(c), vf4_loadu(c + 3), vf4_loadu(c + 6), vf4_loadu(c + 9), r, org, dir);
}

/* The ray in object o's space (to_object_m). */
static inline int to_object(const rtk_build_object *o, const rtk_ray *r, rtk_ray *local)
{
    if (o->flags & RTK_BUILD_OBJECT_IDENTITY) {
        *local = *r;
        return 1;
    }
    return to_object_m(o->world_to_object, r, local);
}

/* Object i of top level `top` (in leaf order) as an rtk_build_object: the
 * record kept for an object not walked inline, or one made in *tmp from
 * the item and its transform for one that is (its box then infinite: the
 * top level's nodes bound it). */
static inline const rtk_build_object *object_at(const rtk_accel *top, uint64_t i, rtk_build_object *tmp)
{
    const rtk_object_item *it = &top->object_items[i];
    if (!(it->flags & RTK_OBJECT_ITEM_INLINE))
        return &top->objects[it->object];
    *tmp = (rtk_build_object){.accel = it->accel, .intersect1 = top->inline_intersect1,
                              .occluded1 = top->inline_occluded1, .inst_id = it->inst_id, .mask = it->mask,
                              .lower = {-INFINITY, -INFINITY, -INFINITY}, .upper = {INFINITY, INFINITY, INFINITY}};
    if (it->flags & RTK_OBJECT_ITEM_WORLD) {
        tmp->flags = RTK_BUILD_OBJECT_IDENTITY;
        static const float identity[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
        memcpy(tmp->world_to_object, identity, sizeof identity);
    } else {
        xfm_from_columns(top->object_xfms[it->object], tmp->world_to_object);
    }
    return tmp;
}

#define OBJ_STACK (3 * RTK_BVH4_MAX_DEPTH + 4)

/* Whether single rays go through object o as they are, on the caller's
 * ray and hit, instead of a copy: a tree of this backend in world space (a
 * dynamic scene's geometry), not an instance (whose hit gets its instID)
 * and not a user primitive (whose callback may write to what it is
 * handed).  The triangle kernels write the ray's tfar and the hit only for
 * a hit within tfar, the answer the copy's was taken for.  With this and
 * the vector set-up above, the two-level path tracer of rtktool bench
 * traced a dynamic scene 3-6% faster (docs/benchmarks/two-levels.md). */
static inline int in_place(const rtk_build_object *o)
{
    return (o->flags & RTK_BUILD_OBJECT_IDENTITY) && o->inst_id == RTK_INVALID_GEOMETRY_ID && !o->intersect_packet;
}

/* The query the tree of an object with instance id inst_id gets: the
 * outermost instance's id. */
static inline rtk_query inst_query(uint32_t inst_id, const rtk_query *q)
{
    rtk_query cq = *q;
    if (cq.inst_id == RTK_INVALID_GEOMETRY_ID)
        cq.inst_id = inst_id;
    return cq;
}

static inline rtk_query object_query(const rtk_build_object *o, const rtk_query *q)
{
    return inst_query(o->inst_id, q);
}

/* Object o's closest hit through its own kernel (the ray taken into its
 * space, or as it is where in_place), written into rh if nearer. */
static inline void object_intersect1(const rtk_build_object *o, rtk_rayhit *rh, const rtk_query *q)
{
    if (in_place(o)) {
        o->intersect1(o->accel, rh, q);
        return;
    }
    rtk_rayhit local;
    if (!to_object(o, &rh->ray, &local.ray))
        return;
    local.hit.geomID = RTK_INVALID_GEOMETRY_ID;
    const rtk_query cq = object_query(o, q);
    o->intersect1(o->accel, &local, &cq);
    if (local.hit.geomID == RTK_INVALID_GEOMETRY_ID)
        return;
    rh->ray.tfar = local.ray.tfar;
    rh->hit = local.hit;
    if (o->inst_id != RTK_INVALID_GEOMETRY_ID)
        rh->hit.instID = o->inst_id;
}

/* 1 when object o finds the ray occluded, through its own kernel. */
static inline int object_occluded1(const rtk_build_object *o, rtk_ray *ray, const rtk_query *q)
{
    if (in_place(o)) {
        o->occluded1(o->accel, ray, q);
        return ray->tfar == -INFINITY;
    }
    rtk_ray local;
    if (!to_object(o, ray, &local))
        return 0;
    const rtk_query cq = object_query(o, q);
    o->occluded1(o->accel, &local, &cq);
    return local.tfar == -INFINITY;
}

#endif
