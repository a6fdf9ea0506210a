/*
 * Single-ray traversal of the bvh4.triangle4 layout: closest hit and any hit.
 *
 * Children are tested four at a time against slabs whose near and far planes
 * are picked once per ray from the signs of the direction (so -0.0 behaves as
 * a negative direction, consistently with its reciprocal), visited nearest
 * first, and skipped when their entry distance is already beyond the closest
 * hit.  Direction components smaller than 1e-18 in magnitude are replaced by
 * +-1e-18 before taking the reciprocal (as Embree does), so no 0 * inf NaN can
 * appear in a slab test.  The far slab distance is scaled by 1 + 2*gamma(3)
 * (Ize 2013), which makes the box test conservative against the rounding of
 * the slab arithmetic: a triangle whose hit lies on a box face or edge (rays
 * aimed at vertices do that) is not culled by its box.
 *
 * The core checks ray validity before calling in: org/dir finite, 0 <= tnear <= tfar.
 */
#include <math.h>
#include <stddef.h>

#include "backend_common.h"
#include "bvh4_triangle4.h"
#include "geometry/triangle.h"
#include "kernels.h"

/* 1 + 2 * gamma(3), gamma(n) = n * eps / (1 - n * eps), eps = 2^-24 */
#define RTK_BOX_FAR_SCALE (1.0f + 2.0f * (3.0f * 0x1p-24f) / (1.0f - 3.0f * 0x1p-24f))

typedef struct ray_pre {
    float org[3], dir[3], inv[3];
    size_t near_off[3], far_off[3]; /* byte offsets of the near/far planes in a node */
} ray_pre;

static inline float safe_rcp(float d)
{
    const float tiny = 1e-18f;
    if (fabsf(d) < tiny)
        d = copysignf(tiny, d);
    return 1.0f / d;
}

static inline void ray_pre_init(ray_pre *p, const rtk_ray *r)
{
    p->org[0] = r->org_x;
    p->org[1] = r->org_y;
    p->org[2] = r->org_z;
    p->dir[0] = r->dir_x;
    p->dir[1] = r->dir_y;
    p->dir[2] = r->dir_z;
    static const size_t lower[3] = {offsetof(rtk_bvh4_node, lower_x), offsetof(rtk_bvh4_node, lower_y),
                                    offsetof(rtk_bvh4_node, lower_z)};
    static const size_t upper[3] = {offsetof(rtk_bvh4_node, upper_x), offsetof(rtk_bvh4_node, upper_y),
                                    offsetof(rtk_bvh4_node, upper_z)};
    for (int k = 0; k < 3; k++) {
        p->inv[k] = safe_rcp(p->dir[k]);
        const int neg = signbit(p->inv[k]) != 0;
        p->near_off[k] = neg ? upper[k] : lower[k];
        p->far_off[k] = neg ? lower[k] : upper[k];
    }
}

static inline const float *plane(const rtk_bvh4_node *n, size_t off)
{
    return (const float *)((const char *)n + off);
}

/* Tests the four child boxes; returns a bit mask of those entered within
 * [tnear, tfar] and their entry distances. */
static inline unsigned node_intersect(const rtk_bvh4_node *n, const ray_pre *p, float tnear, float tfar,
                                      float dist[4])
{
    const float *nx = plane(n, p->near_off[0]), *ny = plane(n, p->near_off[1]), *nz = plane(n, p->near_off[2]);
    const float *fx = plane(n, p->far_off[0]), *fy = plane(n, p->far_off[1]), *fz = plane(n, p->far_off[2]);
    unsigned mask = 0;
    for (int i = 0; i < 4; i++) {
        float t0x = (nx[i] - p->org[0]) * p->inv[0];
        float t0y = (ny[i] - p->org[1]) * p->inv[1];
        float t0z = (nz[i] - p->org[2]) * p->inv[2];
        float t1x = (fx[i] - p->org[0]) * p->inv[0];
        float t1y = (fy[i] - p->org[1]) * p->inv[1];
        float t1z = (fz[i] - p->org[2]) * p->inv[2];
        float tmin = t0x > t0y ? t0x : t0y;
        tmin = t0z > tmin ? t0z : tmin;
        tmin = tnear > tmin ? tnear : tmin;
        float tmax = t1x < t1y ? t1x : t1y;
        tmax = t1z < tmax ? t1z : tmax;
        tmax *= RTK_BOX_FAR_SCALE;
        tmax = tfar < tmax ? tfar : tmax;
        dist[i] = tmin;
        mask |= (unsigned)(tmin <= tmax) << i;
    }
    return mask;
}

typedef struct stack_entry {
    uint32_t ref;
    float dist;
} stack_entry;

/* Pushes the hit children farthest first, so the nearest is popped next. */
static inline int push_children(const rtk_bvh4_node *n, unsigned mask, const float dist[4], stack_entry *stack,
                                int sp)
{
    stack_entry hit[4];
    int count = 0;
    for (int i = 0; i < 4; i++) {
        if (!(mask >> i & 1u))
            continue;
        stack_entry e = {n->child[i], dist[i]};
        int j = count++;
        while (j > 0 && hit[j - 1].dist < e.dist) { /* sort by decreasing distance */
            hit[j] = hit[j - 1];
            j--;
        }
        hit[j] = e;
    }
    for (int i = 0; i < count; i++)
        stack[sp++] = hit[i];
    return sp;
}

static inline void lane_triangle(const rtk_triangle4 *t, int lane, float v0[3], float e1[3], float e2[3])
{
    v0[0] = t->v0x[lane];
    v0[1] = t->v0y[lane];
    v0[2] = t->v0z[lane];
    e1[0] = t->e1x[lane];
    e1[1] = t->e1y[lane];
    e1[2] = t->e1z[lane];
    e2[0] = t->e2x[lane];
    e2[1] = t->e2y[lane];
    e2[2] = t->e2z[lane];
}

void RTK_SYM(rtk_bvh4_intersect1)(const rtk_accel *accel, rtk_rayhit *rayhit)
{
    if (accel->root == RTK_BVH4_EMPTY)
        return;
    ray_pre p;
    ray_pre_init(&p, &rayhit->ray);
    const float tnear = rayhit->ray.tnear;
    float tfar = rayhit->ray.tfar;
    const rtk_triangle4 *best_leaf = NULL;
    int best_lane = 0;
    rtk_tri_hit best = {0};

    stack_entry stack[RTK_BVH4_STACK_SIZE];
    int sp = 0;
    stack[sp++] = (stack_entry){accel->root, tnear};
    while (sp > 0) {
        stack_entry e = stack[--sp];
        if (e.dist > tfar)
            continue;
        if (!(e.ref & RTK_BVH4_LEAF_BIT)) {
            const rtk_bvh4_node *n = &accel->nodes[e.ref];
            float dist[4];
            unsigned mask = node_intersect(n, &p, tnear, tfar, dist);
            sp = push_children(n, mask, dist, stack, sp);
            continue;
        }
        const rtk_triangle4 *t = &accel->tris[e.ref & ~RTK_BVH4_LEAF_BIT];
        for (int lane = 0; lane < 4 && t->prim[lane] != RTK_BVH4_EMPTY; lane++) {
            float v0[3], e1[3], e2[3];
            rtk_tri_hit h;
            lane_triangle(t, lane, v0, e1, e2);
            if (rtk_triangle_intersect(p.org, p.dir, tnear, tfar, v0, e1, e2, &h)) {
                tfar = h.t;
                best = h;
                best_leaf = t;
                best_lane = lane;
            }
        }
    }
    if (!best_leaf)
        return;
    float v0[3], e1[3], e2[3], ng[3];
    lane_triangle(best_leaf, best_lane, v0, e1, e2);
    rtk_triangle_normal(e1, e2, ng);
    rayhit->ray.tfar = best.t;
    rayhit->hit.Ng_x = ng[0];
    rayhit->hit.Ng_y = ng[1];
    rayhit->hit.Ng_z = ng[2];
    rayhit->hit.u = best.u;
    rayhit->hit.v = best.v;
    rayhit->hit.primID = best_leaf->prim[best_lane];
    rayhit->hit.geomID = best_leaf->geom[best_lane];
    rayhit->hit.instID = RTK_INVALID_GEOMETRY_ID;
}

void RTK_SYM(rtk_bvh4_occluded1)(const rtk_accel *accel, rtk_ray *ray)
{
    if (accel->root == RTK_BVH4_EMPTY)
        return;
    ray_pre p;
    ray_pre_init(&p, ray);
    const float tnear = ray->tnear, tfar = ray->tfar;

    stack_entry stack[RTK_BVH4_STACK_SIZE];
    int sp = 0;
    stack[sp++] = (stack_entry){accel->root, tnear};
    while (sp > 0) {
        stack_entry e = stack[--sp];
        if (!(e.ref & RTK_BVH4_LEAF_BIT)) {
            const rtk_bvh4_node *n = &accel->nodes[e.ref];
            float dist[4];
            unsigned mask = node_intersect(n, &p, tnear, tfar, dist);
            sp = push_children(n, mask, dist, stack, sp);
            continue;
        }
        const rtk_triangle4 *t = &accel->tris[e.ref & ~RTK_BVH4_LEAF_BIT];
        for (int lane = 0; lane < 4 && t->prim[lane] != RTK_BVH4_EMPTY; lane++) {
            float v0[3], e1[3], e2[3];
            rtk_tri_hit h;
            lane_triangle(t, lane, v0, e1, e2);
            if (rtk_triangle_intersect(p.org, p.dir, tnear, tfar, v0, e1, e2, &h)) {
                ray->tfar = -INFINITY;
                return;
            }
        }
    }
}
