/*
 * Closest points (rtk.h: rtk_closest_point): the triangle of an accel
 * nearest to a query point, one kernel for every layout of this backend.
 *
 * The walk visits the box nearest to the point first: at a node the
 * children's squared distances from the point come from one SIMD step
 * (4 or 8 lanes, the node's width), of the children within the best
 * distance so far the nearest is entered and the others pushed with their
 * distances (in slot order), and a popped entry is dropped when the best
 * distance has fallen below it since.  At a leaf block the four
 * triangles' distances are bounded from below in float in one SIMD step
 * (tri_lower.h; the indexed layouts' vertices gathered first), and they
 * are measured in double (geometry/closest_point.h, from the vertices the
 * layout keeps), nearest bound first, while that bound is within the best
 * distance.  Once that distance is finite, the children's boxes along
 * their own axes (block_bounds.h, node_obb) are tested beside their
 * axis-aligned ones, in one more SIMD step (a tree of one leaf has its
 * blocks' boxes tested before their triangles instead, once the distance
 * is a few blocks' sizes).
 *
 * Boxes are tested in float against the point rounded to float: a box is
 * left out only when even its distance lowered by the rounding (the
 * point's, dp, and a relative 2^-22 of each gap) exceeds the best distance
 * raised by 2^-20, so the walk never leaves out a box that holds a nearer
 * triangle, and the answer is the double-precision one.
 *
 * Through the objects of a top level (instances, a dynamic scene's trees)
 * the walk goes on in each object's space: the point taken there by its
 * world_to_object map M, boxes compared with the best distance scaled by a
 * bound of M's largest singular value (a surface point within d of the
 * point in the level's space is within |M| d in the object's), and each
 * triangle's vertices taken back to the scene's space (through the
 * inverse, composed down the levels), where every distance is measured.
 */
#include <float.h>
#include <math.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "backend_common.h"
#include "block_bounds.h"
#include "tri_lower.h"
#include "bvh4_triangle4.h"
#include "geometry/affine.h"
#include "geometry/closest_point.h"
#include "kernels.h"
#include "objects_ray.h"
#include "simd/simd.h"

/* The query as one level of the scene sees it. */
typedef struct pq_level {
    rtk_point_state *st;  /* the query, in the scene's space: best2 and the result */
    double p[3];          /* the point in this level's space */
    float pf[3];          /* rounded to float */
    float dp;             /* the largest |p - pf| of the three */
    double scale2;        /* a bound of the squared largest singular value of scene -> level (1: the scene's) */
    int transformed;      /* o2w holds level -> scene */
    double o2w[12];       /* row-major 3x4 */
    uint32_t inst_id;     /* the outermost instance entered, else the query's */
    uint32_t start;       /* the node the next walk starts at, RTK_BVH4_EMPTY: the tree's root */
    float bound;          /* level_bound: set where the walk starts, and wherever this level lowers best2 */
    const rtk_query *q;   /* the query's (user primitives: user_point) */
} pq_level;

/* The next float up from a finite x >= 0 (nextafterf, without the call). */
static inline float float_up(float x)
{
    uint32_t u;
    memcpy(&u, &x, sizeof u);
    u++;
    memcpy(&x, &u, sizeof x);
    return x;
}

static void level_point(pq_level *l)
{
    float dp = 0.0f;
    for (int k = 0; k < 3; k++) {
        l->pf[k] = (float)l->p[k];
        const float d = (float)fabs(l->p[k] - (double)l->pf[k]);
        dp = d > dp ? d : dp;
    }
    /* rounding up: the float of a double may be below it */
    l->dp = dp > 0.0f ? float_up(dp) : 0.0f;
}

/* The best squared distance in this level's space, rounded up and raised
 * by 2^-20 for the float box test's own rounding. */
static inline float level_bound(const pq_level *l)
{
    const double b = l->st->best2 * l->scale2 * (1.0 + 0x1p-20);
    return b >= (double)FLT_MAX ? INFINITY : float_up((float)b);
}

/* A box's distance from the point on one axis, lowered for rounding (see
 * the top): 0 inside. */
#define GAP_(V, lo, hi, p)                                                                                             \
    V##_max(V##_sub(V##_mul(V##_max(V##_sub(lo, p), V##_sub(p, hi)), V##_set1(1.0f - 0x1p-22f)), dp), zero)

/* Whether a candidate at exactly the best distance so far takes the
 * place of the answer kept: of candidates at the same distance the least
 * instID (the outermost instance entered), geomID and prim (a triangle's
 * index in its geometry, so a quad's first half before its second: the
 * state's reserved word keeps the answer's), whatever order the walk
 * meets them in.  A distance that is only the radius or a batch's hint
 * has no answer yet. */
static inline int tie_takes(const pq_level *l, uint32_t geom, uint32_t prim)
{
    const rtk_point_hit *r = l->st->result;
    if (r->geomID == RTK_INVALID_GEOMETRY_ID)
        return 1;
    if (l->inst_id != r->instID)
        return l->inst_id < r->instID;
    if (geom != r->geomID)
        return geom < r->geomID;
    return prim < l->st->reserved;
}

/* The answer so far: point p of the surface (in the scene's space) at
 * squared distance d2, with normal n of length len (0: none), u, v and
 * the ids (key: the prim tie_takes compares, before a quad's is mapped). */
static void keep(pq_level *l, const double p[3], double d2, const double n[3], double len, float u, float v,
                 uint32_t prim, uint32_t geom, uint32_t key)
{
    l->st->best2 = d2;
    l->st->reserved = key;
    l->bound = level_bound(l);
    rtk_point_hit *r = l->st->result;
    r->x = p[0];
    r->y = p[1];
    r->z = p[2];
    r->n_x = len > 0.0 ? (float)(n[0] / len) : 0.0f;
    r->n_y = len > 0.0 ? (float)(n[1] / len) : 0.0f;
    r->n_z = len > 0.0 ? (float)(n[2] / len) : 0.0f;
    r->u = u;
    r->v = v;
    r->primID = prim;
    r->geomID = geom;
    r->instID = l->inst_id;
}

/* ---- triangles ---- */

/* One triangle's vertices in this level's space: its nearest point to the
 * query, kept when nearer than the best so far. */
static void consider(pq_level *l, const double *a0, const double *b0, const double *c0, uint32_t geom,
                     uint32_t prim, const rtk_geometry_attrs *attrs)
{
    double a[3], b[3], c[3];
    const double *va = a0, *vb = b0, *vc = c0;
    if (l->transformed) {
        rtk_affine_apply(l->o2w, a0, a);
        rtk_affine_apply(l->o2w, b0, b);
        rtk_affine_apply(l->o2w, c0, c);
        va = a, vb = b, vc = c;
    }
    rtk_point_state *st = l->st;
    rtk_tri_closest t;
    rtk_closest_point_triangle(&t, st->p, va, vb, vc);
    if (!(t.d2 <= st->best2) || (t.d2 == st->best2 && !tie_takes(l, geom, prim)))
        return;
    const double e1[3] = {vb[0] - va[0], vb[1] - va[1], vb[2] - va[2]};
    const double e2[3] = {vc[0] - va[0], vc[1] - va[1], vc[2] - va[2]};
    const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
    const double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    if (!(len > 0.0))
        return; /* no area: rays never hit it, and it is no surface here either */
    float u = (float)t.u, v = (float)t.v;
    uint32_t id = prim;
    if (attrs)
        rtk_quad_hit(attrs, geom, &id, &u, &v);
    keep(l, t.p, t.d2, n, len, u, v, id, geom, prim);
}

enum leaf_kind { LEAF_TRI4, LEAF_TRI4V, LEAF_TRI4I, LEAF_MB };

/* The motion-blur segment at the query's time (traverse_motion.h:
 * segment_at, the same floats). */
typedef struct mb_time {
    float f;
    vfloat4 f4;
} mb_time;

/* A block's four float bounds (tri_lower.h) from its vertices a and
 * edges e1, e2 (per axis, four lanes each, unused lanes NaN): into lo, and
 * the mask of the lanes within the best distance (never an unused one). */
static inline unsigned block_lower(const pq_level *l, const vfloat4 *a, const vfloat4 *e1, const vfloat4 *e2, float *lo)
{
    const vfloat4 lo4 = rtk_tri4_lower(a[0], a[1], a[2], e1[0], e1[1], e1[2], e2[0], e2[1], e2[2], l->pf, l->dp);
    vf4_storeu(lo, lo4);
    return (unsigned)vb4_mask(vb4_and(vf4_le(vf4_mul(lo4, lo4), vf4_set1(l->bound)), vf4_eq(a[0], a[0])));
}

/* The next lane of a block to measure: of the lanes left in *live, the one
 * of least float bound (the lowest of equals), taken out; -1 once that
 * bound is beyond the best distance (measuring the nearest first lowers it
 * soonest). */
static inline int nearest_live(unsigned *live, const float *lo, const pq_level *l)
{
    if (!*live)
        return -1;
    int k = __builtin_ctz(*live);
    for (unsigned m = *live & (*live - 1); m; m &= m - 1)
        k = lo[__builtin_ctz(m)] < lo[k] ? __builtin_ctz(m) : k;
    *live &= ~(1u << k);
    if (!(lo[k] * lo[k] <= l->bound)) {
        *live = 0;
        return -1;
    }
    return k;
}

static void leaf(const rtk_accel *a, uint32_t ref, pq_level *l, enum leaf_kind kind, const mb_time *mt)
{
    const rtk_geometry_attrs *attrs = a->quads ? a->attrs : NULL;
    const uint32_t first = rtk_leaf_first(ref), end = first + rtk_leaf_blocks(ref);
    /* (made by closest_in before the walk, or NULL) */
    const rtk_block_bounds *bb =
        kind == LEAF_TRI4 || kind == LEAF_TRI4V ? atomic_load_explicit(&a->block_bounds, memory_order_relaxed) : NULL;
    for (uint32_t i = first; i < end; i++) {
        double v0[3], v1[3], v2[3];
        if (kind == LEAF_TRI4 || kind == LEAF_TRI4V) {
            const rtk_triangle4 *t = &a->tris[i];
            const rtk_triangle4v *tv = (const rtk_triangle4v *)t;
            /* in a tree of one leaf, the block's oriented box first, once
             * the best distance is a few blocks' sizes (block_bounds.h; a
             * tree of nodes tested its leaves' as its nodes' children) */
            const float bound = l->bound;
            if (bb && bb->obb && bound > bb->from && rtk_block_worth(bb, i) &&
                rtk_block_obb_lower2(&bb->obb[i], l->pf, l->dp) > bound)
                continue;
            /* the four triangles' float bounds (tri_lower.h) at once: only
             * the lanes within the best distance go on to the
             * double-precision test (unused lanes are NaN: never).  The
             * triangles' boxes were tested first once; they left out a
             * whole block in 3-5% of the blocks (the bunny's near and box
             * points), and the bounds are needed for the rest anyway. */
            vfloat4 a[3], e1[3], e2[3];
            const float *f = (const float *)t; /* v0 x, y, z, then e1 (or v1), then e2 (or v2): 4 lanes each */
            for (int ax = 0; ax < 3; ax++) {
                const vfloat4 x0 = vf4_load(f + 4 * ax), y1 = vf4_load(f + 12 + 4 * ax), y2 = vf4_load(f + 24 + 4 * ax);
                a[ax] = x0;
                e1[ax] = kind == LEAF_TRI4V ? vf4_sub(y1, x0) : y1;
                e2[ax] = kind == LEAF_TRI4V ? vf4_sub(y2, x0) : y2;
            }
            float lo[4];
            unsigned live = block_lower(l, a, e1, e2, lo);
            for (int k; (k = nearest_live(&live, lo, l)) >= 0;) {
                if (t->prim[k] == RTK_BVH4_EMPTY)
                    continue;
                if (kind == LEAF_TRI4V) {
                    v0[0] = tv->v0x[k], v0[1] = tv->v0y[k], v0[2] = tv->v0z[k];
                    v1[0] = tv->v1x[k], v1[1] = tv->v1y[k], v1[2] = tv->v1z[k];
                    v2[0] = tv->v2x[k], v2[1] = tv->v2y[k], v2[2] = tv->v2z[k];
                } else {
                    /* v0 + e in double: exact, the stored edge as it is */
                    v0[0] = t->v0x[k], v0[1] = t->v0y[k], v0[2] = t->v0z[k];
                    v1[0] = v0[0] + t->e1x[k], v1[1] = v0[1] + t->e1y[k], v1[2] = v0[2] + t->e1z[k];
                    v2[0] = v0[0] + t->e2x[k], v2[1] = v0[1] + t->e2y[k], v2[2] = v0[2] + t->e2z[k];
                }
                consider(l, v0, v1, v2, t->geom[k], t->prim[k], attrs);
            }
        } else {
            /* the four triangles' vertices gathered through their indices
             * (lane by lane: vertex, axis, lane), then their float bounds
             * and the nearest first, as above */
            const rtk_triangle4i *t = &a->trisi[i];
            _Alignas(16) float x[3][3][4];
            uint32_t geom[4];
            for (int k = 0; k < 4; k++) {
                if (t->prim[k] == RTK_BVH4_EMPTY) {
                    for (int j = 0; j < 3; j++)
                        x[j][0][k] = x[j][1][k] = x[j][2][k] = NAN;
                    continue;
                }
                const uint32_t idx[3] = {t->v0[k], t->v1[k], t->v2[k]};
                if (kind == LEAF_MB) {
                    /* interpolated as the traversal does: (1 - f) a + f b,
                     * not fused, in float */
                    const rtk_mb_geometry *g = &a->mb_geoms[t->geom[k]];
                    const float *base = g->vertices + 3 * (size_t)a->segment;
                    const size_t step = 3 * (size_t)g->steps;
                    const vfloat4 one_f = vf4_set1(1.0f - mt->f);
                    for (int j = 0; j < 3; j++) {
                        const float *q = base + step * idx[j];
                        float at[4];
                        vf4_storeu(at, vf4_add(vf4_mul(mt->f4, vf4_loadu(q + 3)), vf4_mul(one_f, vf4_loadu(q))));
                        x[j][0][k] = at[0], x[j][1][k] = at[1], x[j][2][k] = at[2];
                    }
                    geom[k] = g->geom_id;
                } else {
                    const rtk_leaf_geometry *g = &a->geoms[t->geom[k]];
                    for (int j = 0; j < 3; j++) {
                        const float *q = (const float *)(g->vertices + (size_t)idx[j] * g->stride);
                        x[j][0][k] = q[0], x[j][1][k] = q[1], x[j][2][k] = q[2];
                    }
                    geom[k] = g->geom_id;
                }
            }
            vfloat4 va[3], e1[3], e2[3];
            for (int ax = 0; ax < 3; ax++) {
                va[ax] = vf4_load(x[0][ax]);
                e1[ax] = vf4_sub(vf4_load(x[1][ax]), va[ax]);
                e2[ax] = vf4_sub(vf4_load(x[2][ax]), va[ax]);
            }
            float lo[4];
            unsigned live = block_lower(l, va, e1, e2, lo);
            for (int k; (k = nearest_live(&live, lo, l)) >= 0;) {
                double *v[3] = {v0, v1, v2};
                for (int j = 0; j < 3; j++)
                    v[j][0] = x[j][0][k], v[j][1] = x[j][1][k], v[j][2] = x[j][2][k];
                consider(l, v0, v1, v2, geom[k], t->prim[k], attrs);
            }
        }
    }
}

/* ---- nodes ---- */

/* The squared distances of a node's child boxes from the point, lowered
 * for rounding (see the top); the mask of those within bound. */

/* Four boxes, their planes given (lo*, hi*), the node's width-4 step. */
static inline unsigned boxes4_dist(vfloat4 lx, vfloat4 hx, vfloat4 ly, vfloat4 hy, vfloat4 lz, vfloat4 hz,
                                   const pq_level *l, float bound, float *d)
{
    const vfloat4 zero = vf4_set1(0.0f), dp = vf4_set1(l->dp);
    const vfloat4 gx = GAP_(vf4, lx, hx, vf4_set1(l->pf[0]));
    const vfloat4 gy = GAP_(vf4, ly, hy, vf4_set1(l->pf[1]));
    const vfloat4 gz = GAP_(vf4, lz, hz, vf4_set1(l->pf[2]));
    const vfloat4 d2 = vf4_add(vf4_add(vf4_mul(gx, gx), vf4_mul(gy, gy)), vf4_mul(gz, gz));
    vf4_storeu(d, d2);
    return (unsigned)vb4_mask(vf4_le(d2, vf4_set1(bound)));
}

static inline unsigned node4_dist(const rtk_bvh4_node *n, const pq_level *l, float bound, float *d)
{
    return boxes4_dist(vf4_load(n->lower_x), vf4_load(n->upper_x), vf4_load(n->lower_y), vf4_load(n->upper_y),
                       vf4_load(n->lower_z), vf4_load(n->upper_z), l, bound, d);
}

/* A motion node's planes at the query's time: start + f * change. */
static inline unsigned node_mb_dist(const rtk_bvh4mb_node *n, const pq_level *l, float bound, float *d,
                                    const mb_time *mt)
{
    const vfloat4 f = mt->f4;
#define AT_(plane) vf4_add(vf4_load(n->plane), vf4_mul(f, vf4_load(n->d##plane)))
    return boxes4_dist(AT_(lower_x), AT_(upper_x), AT_(lower_y), AT_(upper_y), AT_(lower_z), AT_(upper_z), l, bound,
                       d);
#undef AT_
}

#ifdef RTK_SIMD_HAS_8
static inline unsigned boxes8_dist(vfloat8 lx, vfloat8 ux, vfloat8 ly, vfloat8 uy, vfloat8 lz, vfloat8 uz,
                                   const pq_level *l, float bound, float *d)
{
    const vfloat8 zero = vf8_set1(0.0f), dp = vf8_set1(l->dp);
    const vfloat8 gx = GAP_(vf8, lx, ux, vf8_set1(l->pf[0]));
    const vfloat8 gy = GAP_(vf8, ly, uy, vf8_set1(l->pf[1]));
    const vfloat8 gz = GAP_(vf8, lz, uz, vf8_set1(l->pf[2]));
    const vfloat8 d2 = vf8_add(vf8_add(vf8_mul(gx, gx), vf8_mul(gy, gy)), vf8_mul(gz, gz));
    _Alignas(32) float tmp[8];
    vf8_store(tmp, d2);
    memcpy(d, tmp, sizeof tmp);
    return (unsigned)vb8_mask(vf8_le(d2, vf8_set1(bound)));
}

static inline unsigned node8_dist(const rtk_bvh8_node *n, const pq_level *l, float bound, float *d)
{
    return boxes8_dist(vf8_load(n->lower_x), vf8_load(n->upper_x), vf8_load(n->lower_y), vf8_load(n->upper_y),
                       vf8_load(n->lower_z), vf8_load(n->upper_z), l, bound, d);
}

/* The same for an 8-wide motion node at the query's time. */
static inline unsigned node_mb8_dist(const rtk_bvh8mb_node *n, const pq_level *l, float bound, float *d,
                                     const mb_time *mt)
{
    const vfloat8 f = vf8_set1(mt->f);
#define AT_(plane) vf8_add(vf8_load(n->plane), vf8_mul(f, vf8_load(n->d##plane)))
    return boxes8_dist(AT_(lower_x), AT_(upper_x), AT_(lower_y), AT_(upper_y), AT_(lower_z), AT_(upper_z), l, bound,
                       d);
#undef AT_
}
#endif
#undef GAP_

/* One axis's gap, squared, added to s: h in row r. */
#define OBB_GAP_(V, w, ax, ay, az, r)                                                                                   \
    do {                                                                                                               \
        const V##_t q = V##_add(V##_add(V##_mul(ax, dx), V##_mul(ay, dy)), V##_mul(az, dz));                           \
        const V##_t g = V##_max(V##_sub(V##_sub(V##_abs(q), V##_load(row + (r) * (w))), slack), zero);                 \
        s = V##_add(s, V##_mul(g, g));                                                                                 \
    } while (0)

/* The children of node i (width w) whose boxes along their own axes
 * (block_bounds.h, node_obb) come within bound: rtk_block_obb_lower2
 * lane by lane, the same float operations. */
#define OBB_WITHIN_(V, w)                                                                                              \
    do {                                                                                                               \
        const float *row = rows + (size_t)i * RTK_NODE_OBB_ROWS * (w);                                                 \
        const V##_t zero = V##_set1(0.0f);                                                                             \
        const V##_t dx = V##_sub(V##_set1(l->pf[0]), V##_load(row));                                                  \
        const V##_t dy = V##_sub(V##_set1(l->pf[1]), V##_load(row + (w)));                                            \
        const V##_t dz = V##_sub(V##_set1(l->pf[2]), V##_load(row + 2 * (w)));                                        \
        const V##_t slack = V##_add(V##_mul(V##_add(V##_add(V##_abs(dx), V##_abs(dy)), V##_abs(dz)),                   \
                                            V##_set1(0x1p-20f)),                                                       \
                                    V##_set1(2.0f * l->dp));                                                           \
        const V##_t a0x = V##_load(row + 6 * (w)), a0y = V##_load(row + 7 * (w)), a0z = V##_load(row + 8 * (w));       \
        const V##_t a2x = V##_load(row + 9 * (w)), a2y = V##_load(row + 10 * (w)), a2z = V##_load(row + 11 * (w));     \
        /* (the second axis as rtk_obb_axis1 makes it) */                                                              \
        const V##_t a1x = V##_sub(V##_mul(a2y, a0z), V##_mul(a2z, a0y));                                               \
        const V##_t a1y = V##_sub(V##_mul(a2z, a0x), V##_mul(a2x, a0z));                                               \
        const V##_t a1z = V##_sub(V##_mul(a2x, a0y), V##_mul(a2y, a0x));                                               \
        V##_t s = zero;                                                                                                \
        OBB_GAP_(V, w, a0x, a0y, a0z, 3);                                                                               \
        OBB_GAP_(V, w, a1x, a1y, a1z, 4);                                                                               \
        OBB_GAP_(V, w, a2x, a2y, a2z, 5);                                                                               \
        s = V##_select(V##_lt(s, V##_set1(0x1p-100f)), zero, V##_mul(s, V##_set1(1.0f - 0x1p-18f)));                   \
        return (unsigned)V##_mask_le(s, bound);                                                                        \
    } while (0)

static inline unsigned node4_obb_within(const float *rows, uint32_t i, const pq_level *l, float bound)
{
#define vf4_t vfloat4
#define vf4_mask_le(s, b) vb4_mask(vf4_le(s, vf4_set1(b)))
    OBB_WITHIN_(vf4, 4);
#undef vf4_mask_le
#undef vf4_t
}

#ifdef RTK_SIMD_HAS_8
static inline unsigned node8_obb_within(const float *rows, uint32_t i, const pq_level *l, float bound)
{
#define vf8_t vfloat8
#define vf8_mask_le(s, b) vb8_mask(vf8_le(s, vf8_set1(b)))
    OBB_WITHIN_(vf8, 8);
#undef vf8_mask_le
#undef vf8_t
}
#endif
#undef OBB_WITHIN_
#undef OBB_GAP_

static void closest_in(const rtk_accel *a, pq_level *l);

static void objects_leaf(const rtk_accel *a, uint32_t ref, pq_level *l);

#define PQ_STACK RTK_BVHN_STACK_SIZE(8)

/* The walk over one tree: width 4 or 8, its leaves of the given kind (or
 * objects); specialised by its callers' constants. */
static inline __attribute__((always_inline)) void walk(const rtk_accel *a, const rtk_accel *leaves, pq_level *l,
                                                       int width, int objects, enum leaf_kind kind,
                                                       const mb_time *mt)
{
    (void)width;
    uint32_t stack[PQ_STACK];
    float sd[PQ_STACK];
    int sp = 0;
    uint32_t cur = l->start != RTK_BVH4_EMPTY ? l->start : a->root;
    /* (made by closest_in before the walk, or NULL) */
    const rtk_block_bounds *bb = !objects && (kind == LEAF_TRI4 || kind == LEAF_TRI4V)
                                     ? atomic_load_explicit(&leaves->block_bounds, memory_order_relaxed)
                                     : NULL;
    const float *obb_rows = bb ? bb->node_obb : NULL;
    l->start = RTK_BVH4_EMPTY; /* (the levels below start at their roots) */
    l->bound = level_bound(l);
    float bound = l->bound;
    for (;;) {
        if (cur & RTK_BVH4_LEAF_BIT) {
            if (objects)
                objects_leaf(a, cur, l);
            else
                leaf(leaves, cur, l, kind, mt);
            /* (a level below lowers best2 without telling this one) */
            if (objects)
                l->bound = level_bound(l);
            bound = l->bound;
        } else {
            float d[8];
            unsigned mask;
            const uint32_t *child;
            const int32_t *pf = NULL; /* the node's prefetch[] (rtk_bvh4_node); motion nodes have none */
            const char *node_at = NULL;
            if (kind == LEAF_MB && !objects && width == 4) {
                const rtk_bvh4mb_node *n = &((const rtk_bvh4mb_node *)a->nodes)[cur];
                mask = node_mb_dist(n, l, bound, d, mt);
                child = n->child;
            }
#ifdef RTK_SIMD_HAS_8
            else if (kind == LEAF_MB && !objects) {
                const rtk_bvh8mb_node *n = &((const rtk_bvh8mb_node *)a->nodes)[cur];
                mask = node_mb8_dist(n, l, bound, d, mt);
                child = n->child;
            } else if (width == 8) {
                const rtk_bvh8_node *n = &((const rtk_bvh8_node *)a->nodes)[cur];
                mask = node8_dist(n, l, bound, d);
                child = n->child;
                pf = n->prefetch;
                node_at = (const char *)n;
            }
#endif
            else {
                const rtk_bvh4_node *n = &((const rtk_bvh4_node *)a->nodes)[cur];
                mask = node4_dist(n, l, bound, d);
                child = n->child;
                pf = n->prefetch;
                node_at = (const char *)n;
            }
            /* the children within bound by their oriented boxes too, once
             * the best distance is finite: in one SIMD step these cost
             * about what the axis-aligned boxes do, and pay even near the
             * surface (python3 -m rtk.bench's near points, +6-10% on the
             * bunny and +15% on torus:0.3M against testing them only
             * beyond the blocks' obb_from, as those are) */
            unsigned obb_in = ~0u;
            if (obb_rows && node_at && bound < INFINITY) {
#ifdef RTK_SIMD_HAS_8
                if (width == 8)
                    obb_in = node8_obb_within(obb_rows, cur, l, bound);
                else
#endif
                    obb_in = node4_obb_within(obb_rows, cur, l, bound);
            }
            /* the children within bound: the nearest next, the others pushed */
            int near = -1;
            unsigned kept = 0;
            for (; mask; mask &= mask - 1) {
                const int c = __builtin_ctz(mask);
                if (child[c] == RTK_BVH4_EMPTY)
                    continue;
                /* (the nearest by its box, whether left out below or not) */
                if (near < 0 || d[c] < d[near])
                    near = c;
                if (!(obb_in >> c & 1))
                    continue;
                /* its node or its leaf's first block asked for now, as the
                 * ray kernels do (traverse_bvhn.h, prefetch_child) */
                if (pf)
                    rtk_prefetch_slot(node_at, pf[c]);
                kept |= 1u << c;
            }
            /* The nearest entered (the lowest slot of equals), the others
             * pushed unsorted, the lowest slot on top: sorting them all
             * took more than the order saved (rtktool bench --only points,
             * avx2, either build first: batches of near points +7-10%,
             * box points +1.5-8%).  (The order decides no answer: of
             * triangles at the same distance tie_takes keeps the least
             * ids, whichever comes first.) */
            if (kept) {
                const int first = kept >> near & 1 ? near : __builtin_ctz(kept);
                for (kept &= ~(1u << first); kept; kept &= ~(1u << (31 - __builtin_clz(kept)))) {
                    const int c = 31 - __builtin_clz(kept);
                    stack[sp] = child[c];
                    sd[sp++] = d[c];
                }
                cur = child[first];
                continue;
            }
        }
        /* the next entry still within the best distance */
        for (;;) {
            if (!sp)
                return;
            sp--;
            if (sd[sp] <= bound)
                break;
        }
        cur = stack[sp];
    }
}

static void walk_tri4(const rtk_accel *a, pq_level *l) { walk(a, a, l, 4, 0, LEAF_TRI4, NULL); }
static void walk_tri4v(const rtk_accel *a, pq_level *l) { walk(a, a, l, 4, 0, LEAF_TRI4V, NULL); }
static void walk_tri4i(const rtk_accel *a, pq_level *l) { walk(a, a, l, 4, 0, LEAF_TRI4I, NULL); }
static void walk_objects(const rtk_accel *a, pq_level *l)
{
#ifdef RTK_SIMD_HAS_8
    if (a->objects_width == 8) {
        walk(a, a, l, 8, 1, LEAF_TRI4, NULL);
        return;
    }
#endif
    walk(a, a, l, 4, 1, LEAF_TRI4, NULL);
}
#ifdef RTK_SIMD_HAS_8
static void walk8_tri4(const rtk_accel *a, pq_level *l) { walk(a, a, l, 8, 0, LEAF_TRI4, NULL); }
static void walk8_tri4v(const rtk_accel *a, pq_level *l) { walk(a, a, l, 8, 0, LEAF_TRI4V, NULL); }
#endif

/* Motion blur: the tree of the time segment the query's time falls in
 * (the core has checked the time is in [0, 1]). */
static void walk_mb(const rtk_accel *a, pq_level *l)
{
    const uint32_t n = a->segment_count;
    const float ts = l->st->time * (float)n;
    uint32_t s = (uint32_t)ts;
    s = s < n ? s : n - 1;
    const mb_time mt = {.f = ts - (float)s, .f4 = vf4_set1(ts - (float)s)};
    const rtk_accel *seg = &a->segments[s];
    if (seg->root == RTK_BVH4_EMPTY)
        return;
    /* the segment's nodes and leaves, the top accel's attributes */
    rtk_accel view = *seg;
    view.attrs = a->attrs;
    view.quads = a->quads;
#ifdef RTK_SIMD_HAS_8
    if (a->layout == RTK_LAYOUT_BVH8_TRIANGLE4MB || a->layout == RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST) {
        walk(seg, &view, l, 8, 0, LEAF_MB, &mt);
        return;
    }
#endif
    walk(seg, &view, l, 4, 0, LEAF_MB, &mt);
}

/* ---- objects ---- */

/* A bound of the largest singular value of the 3x3 part of m (3x4),
 * squared: the least of the Frobenius norm's square, |m|_1 |m|_inf, and
 * the largest Gershgorin row sum of m^T m (whose largest eigenvalue it
 * is).  The last is tight for rotations with a uniform scale, where m^T m
 * is s^2 I but for rounding; the least of the other two is up to twice it
 * there, and the walk in the object's space then took a ball up to 1.4
 * times as wide (bench/instance_points: 11x the time a point). */
static double scale2_bound(const double *m)
{
    double fro = 0.0, row = 0.0, col = 0.0;
    for (int r = 0; r < 3; r++) {
        double s = 0.0;
        for (int c = 0; c < 3; c++) {
            fro += m[4 * r + c] * m[4 * r + c];
            s += fabs(m[4 * r + c]);
        }
        row = s > row ? s : row;
    }
    for (int c = 0; c < 3; c++) {
        const double s = fabs(m[c]) + fabs(m[4 + c]) + fabs(m[8 + c]);
        col = s > col ? s : col;
    }
    double b = fro < row * col ? fro : row * col;
    /* (m's entries are floats: each product is exact in double, and the
     * sums' few roundings are far within the margin below) */
    double g[3][3];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            g[i][j] = m[i] * m[j] + m[4 + i] * m[4 + j] + m[8 + i] * m[8 + j];
    double gersh = 0.0;
    for (int i = 0; i < 3; i++) {
        const double s = g[i][i] + fabs(g[i][(i + 1) % 3]) + fabs(g[i][(i + 2) % 3]);
        gersh = s > gersh ? s : gersh;
    }
    b = gersh < b ? gersh : b;
    return b * (1.0 + 0x1p-40);
}

/* x = p * q as affine maps (3x4 each): q first. */
static void compose3x4(const double *p, const double *q, double *x)
{
    for (int r = 0; r < 3; r++) {
        for (int c = 0; c < 4; c++)
            x[4 * r + c] = p[4 * r] * q[c] + p[4 * r + 1] * q[4 + c] + p[4 * r + 2] * q[8 + c];
        x[4 * r + 3] += p[4 * r + 3];
    }
}

/* A user primitive (an object of this level, in its space): its point
 * query function's nearest point, taken into the scene's space and kept
 * when nearer than the best so far, as a triangle's (consider). */
static void user_leaf(const rtk_build_object *o, pq_level *l)
{
    if (!(l->q->flags & RTK_QUERY_FLAG_USER_POINT))
        return; /* (the core refuses such scenes without it) */
    rtk_point_state *st = l->st;
    /* the best distance in this level's space, from above */
    const double radius = st->best2 == INFINITY ? INFINITY : sqrt(st->best2 * l->scale2) * (1.0 + 0x1p-40);
    rtk_user_point u;
    if (!l->q->user_point(o->accel, l->p, radius, st->time, &u))
        return;
    double c[3] = {u.closest[0], u.closest[1], u.closest[2]};
    if (l->transformed)
        rtk_affine_apply(l->o2w, u.closest, c);
    const double d[3] = {c[0] - st->p[0], c[1] - st->p[1], c[2] - st->p[2]};
    const double d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    if (!(d2 <= st->best2) || (d2 == st->best2 && !tie_takes(l, u.geom_id, u.prim_id)))
        return;
    /* (only for a point kept) a normal goes by the inverse's transpose */
    double n[3] = {u.normal[0], u.normal[1], u.normal[2]}, minv[12];
    if (l->transformed) {
        if (rtk_affine_invert(l->o2w, minv))
            for (int r = 0; r < 3; r++)
                n[r] = minv[r] * u.normal[0] + minv[4 + r] * u.normal[1] + minv[8 + r] * u.normal[2];
        else
            n[0] = n[1] = n[2] = 0.0;
    }
    keep(l, c, d2, n, sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]), u.u, u.v, u.prim_id, u.geom_id, u.prim_id);
}

static void objects_leaf(const rtk_accel *a, uint32_t ref, pq_level *l)
{
    const uint32_t first = rtk_leaf_first(ref), end = first + rtk_leaf_blocks(ref);
    for (uint32_t i = first; i < end; i++) {
        rtk_build_object tmp;
        const rtk_build_object *o = object_at(a, i, &tmp);
        if (o->intersect_packet) { /* a user primitive (RTK_BUILD_OBJECT_IDENTITY) */
            user_leaf(o, l);
            continue;
        }
        pq_level in = *l;
        /* an object opened into the top level (objects.c, open_objects)
         * is walked from the node its reference names */
        in.start = a->objects_opened && a->object_items[i].root != o->accel->root ? a->object_items[i].root
                                                                                    : RTK_BVH4_EMPTY;
        if (in.inst_id == RTK_INVALID_GEOMETRY_ID)
            in.inst_id = o->inst_id;
        if (!(o->flags & RTK_BUILD_OBJECT_IDENTITY)) {
            double m[12], minv[12];
            for (int k = 0; k < 12; k++)
                m[k] = o->world_to_object[k];
            if (!rtk_affine_invert(m, minv))
                continue; /* flat: the object has no surface in this space */
            rtk_affine_apply(m, l->p, in.p);
            level_point(&in);
            in.scale2 = l->scale2 * scale2_bound(m);
            if (l->transformed)
                compose3x4(l->o2w, minv, in.o2w);
            else
                memcpy(in.o2w, minv, sizeof minv);
            in.transformed = 1;
        }
        closest_in(o->accel, &in);
    }
}

static void closest_in(const rtk_accel *a, pq_level *l)
{
    const int motion = a->layout == RTK_LAYOUT_BVH4_TRIANGLE4MB || a->layout == RTK_LAYOUT_BVH4_TRIANGLE4MB_ROBUST ||
                       a->layout == RTK_LAYOUT_BVH8_TRIANGLE4MB || a->layout == RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST;
    if (!motion && a->root == RTK_BVH4_EMPTY) /* (a motion accel's segments have the roots) */
        return;
    rtk_block_bounds_of(a); /* (made at the tree's first query) */
    switch (a->layout) {
    case RTK_LAYOUT_BVH4_TRIANGLE4: walk_tri4(a, l); break;
    case RTK_LAYOUT_BVH4_TRIANGLE4V: walk_tri4v(a, l); break;
    case RTK_LAYOUT_BVH4_TRIANGLE4I:
    case RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST: walk_tri4i(a, l); break;
#ifdef RTK_SIMD_HAS_8
    case RTK_LAYOUT_BVH8_TRIANGLE4: walk8_tri4(a, l); break;
    case RTK_LAYOUT_BVH8_TRIANGLE4V: walk8_tri4v(a, l); break;
#endif
    case RTK_LAYOUT_BVH4_OBJECT: walk_objects(a, l); break;
    case RTK_LAYOUT_BVH4_TRIANGLE4MB:
    case RTK_LAYOUT_BVH4_TRIANGLE4MB_ROBUST:
    case RTK_LAYOUT_BVH8_TRIANGLE4MB:
    case RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST: walk_mb(a, l); break;
    default: break;
    }
}

void RTK_SYM(rtk_closest_point)(const rtk_accel *accel, rtk_point_state *st, const rtk_query *q)
{
    pq_level l = {.st = st, .scale2 = 1.0, .inst_id = q->inst_id, .start = RTK_BVH4_EMPTY, .q = q};
    memcpy(l.p, st->p, sizeof l.p);
    level_point(&l);
    closest_in(accel, &l);
}
