/*
 * The float lower bounds of closest-point queries, compiled in directly.
 *
 * The leaf blocks' oriented boxes (backends/common/block_bounds.h): the float lower
 * bound a box gives must never exceed the block's true squared distance
 * (brute force over its triangles in double, geometry/closest_point.h, the
 * vertices as the kernels see them), for blocks of one to four triangles,
 * tilted, coplanar or not, needles and points among them, both leaf
 * formats (v0 + e1, e2 and three vertices), at coordinates from 2^-60 to
 * 2^60 and 10^5 off the origin, for float points and double points (the
 * float of the point and its rounding dp, as the walk has them), on the
 * surface, at vertices, and near and far.  And it must be tight where it is
 * meant to be: a point straight above a flat block is bounded by nearly its
 * distance, which an axis-aligned box of a tilted block is not.
 *
 * The triangles' own bounds (backends/common/tri_lower.h), the same way,
 * triangle by triangle, with slivers at the angle the bound still takes and
 * points on and beside edges: never above the distance, and within 2^-11 of
 * it for points far off, where most of a query's triangles are bounded.
 */
#include <float.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#include <cmocka.h>

#include "block_bounds.h"
#include "tri_lower.h"
#include "geometry/closest_point.h"

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static double rnd(void) /* [0, 1) */
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (double)(rng_state >> 11) * 0x1p-53;
}

typedef struct block {
    union {
        rtk_triangle4 t;   /* v0, e1, e2 */
        rtk_triangle4v tv; /* when vertices */
    };
    int vertices;
    int count;
} block;

/* Triangle k of the block as the kernels see it. */
static void corners(const block *b, int k, double v[3][3])
{
    const rtk_triangle4v *tv = &b->tv;
    v[0][0] = b->t.v0x[k], v[0][1] = b->t.v0y[k], v[0][2] = b->t.v0z[k];
    if (b->vertices) {
        v[1][0] = tv->v1x[k], v[1][1] = tv->v1y[k], v[1][2] = tv->v1z[k];
        v[2][0] = tv->v2x[k], v[2][1] = tv->v2y[k], v[2][2] = tv->v2z[k];
    } else {
        v[1][0] = v[0][0] + b->t.e1x[k], v[1][1] = v[0][1] + b->t.e1y[k], v[1][2] = v[0][2] + b->t.e1z[k];
        v[2][0] = v[0][0] + b->t.e2x[k], v[2][1] = v[0][1] + b->t.e2y[k], v[2][2] = v[0][2] + b->t.e2z[k];
    }
}

static void set_lane(block *b, int k, const double v[3][3])
{
    rtk_triangle4v *tv = &b->tv;
    float f[3][3];
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++)
            f[i][a] = (float)v[i][a];
    b->t.v0x[k] = f[0][0], b->t.v0y[k] = f[0][1], b->t.v0z[k] = f[0][2];
    if (b->vertices) {
        tv->v1x[k] = f[1][0], tv->v1y[k] = f[1][1], tv->v1z[k] = f[1][2];
        tv->v2x[k] = f[2][0], tv->v2y[k] = f[2][1], tv->v2z[k] = f[2][2];
    } else {
        b->t.e1x[k] = f[1][0] - f[0][0], b->t.e1y[k] = f[1][1] - f[0][1], b->t.e1z[k] = f[1][2] - f[0][2];
        b->t.e2x[k] = f[2][0] - f[0][0], b->t.e2y[k] = f[2][1] - f[0][1], b->t.e2z[k] = f[2][2] - f[0][2];
    }
    b->t.geom[k] = 0;
    b->t.prim[k] = (uint32_t)k;
}

/* A block around c of size s: a patch of a tilted plane (flat), or
 * anything (with needles and points among its triangles). */
static void make_block(block *b, const double *c, double s, int flat, int vertices)
{
    memset(b, 0, sizeof *b);
    b->vertices = vertices;
    b->count = 1 + (int)(rnd() * 4);
    for (int k = 0; k < 4; k++) {
        float *lanes = (float *)&b->t;
        for (int w = 0; w < 9; w++)
            lanes[4 * w + k] = NAN;
        b->t.prim[k] = RTK_BVH4_EMPTY;
    }
    const double n[3] = {rnd() - 0.5, rnd() - 0.5, rnd() - 0.5};
    for (int k = 0; k < b->count; k++) {
        double v[3][3];
        for (int i = 0; i < 3; i++) {
            for (int a = 0; a < 3; a++)
                v[i][a] = c[a] + s * (rnd() - 0.5);
            if (flat) { /* onto the plane through c with normal n */
                const double d = ((v[i][0] - c[0]) * n[0] + (v[i][1] - c[1]) * n[1] + (v[i][2] - c[2]) * n[2]) /
                                 (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
                for (int a = 0; a < 3; a++)
                    v[i][a] -= d * n[a];
            }
        }
        const double kind = rnd();
        if (kind < 0.1) /* a needle */
            for (int a = 0; a < 3; a++)
                v[2][a] = v[0][a] + 0.37 * (v[1][a] - v[0][a]);
        else if (kind < 0.15) /* a point */
            for (int a = 0; a < 3; a++)
                v[1][a] = v[2][a] = v[0][a];
        set_lane(b, k, v);
    }
}

static double true_d2(const block *b, const double *p)
{
    double best = INFINITY;
    for (int k = 0; k < b->count; k++) {
        double v[3][3];
        corners(b, k, v);
        rtk_tri_closest t;
        rtk_closest_point_triangle(&t, p, v[0], v[1], v[2]);
        best = t.d2 < best ? t.d2 : best;
    }
    return best;
}

/* The blocks the brute-force tests try: five scales, each at the origin,
 * a thousand sizes off it and 10^8 sizes off it, flat or not, sharing
 * vertices or not.  Returns the scale; c gets the block's centre. */
static const double scales[] = {0x1p-60, 1e-6, 1.0, 1e3, 0x1p60};
static const double offsets[] = {0.0, 1.0, 1e5};
static double trial_block(int si, int oi, int trial, block *b, double *c)
{
    const double s = scales[si];
    c[0] = offsets[oi] * s * 1e3 * (rnd() + 0.5);
    c[1] = offsets[oi] * s * 1e3 * (rnd() - 0.5);
    c[2] = s * (rnd() - 0.5);
    make_block(b, c, s, trial % 2, trial % 4 >= 2);
    return s;
}

/* Where the brute-force tests put their points, about lane k of a block
 * of size s centred at c. */
enum { AT_VERTEX, ON_EDGE, BESIDE_EDGE, ON_FACE, NEAR, FARTHER, FAR };
static void trial_point(const block *b, int lane, const double *c, double s, int kind, double *p)
{
    double v[3][3];
    corners(b, lane, v);
    if (kind == AT_VERTEX) {
        memcpy(p, v[(int)(rnd() * 3)], 3 * sizeof *p);
    } else if (kind == ON_EDGE || kind == BESIDE_EDGE) { /* beside: in the plane, out or in */
        const int i = (int)(rnd() * 3), j = (i + 1) % 3, o = (i + 2) % 3;
        const double t = rnd(), off = kind == ON_EDGE ? 0.0 : (rnd() - 0.5) * 1e-3;
        for (int k = 0; k < 3; k++)
            p[k] = v[i][k] + t * (v[j][k] - v[i][k]) + off * (v[o][k] - v[i][k]);
    } else if (kind == ON_FACE) { /* uniform over the triangle, in double */
        double u = rnd(), w = rnd();
        if (u + w > 1.0)
            u = 1.0 - u, w = 1.0 - w;
        for (int k = 0; k < 3; k++)
            p[k] = v[0][k] + u * (v[1][k] - v[0][k]) + w * (v[2][k] - v[0][k]);
    } else { /* in the cube of side 0.01 s, s or 10^4 s about c */
        const double r = s * (kind == NEAR ? 0.01 : kind == FARTHER ? 1.0 : 1e4);
        for (int k = 0; k < 3; k++)
            p[k] = c[k] + r * (rnd() - 0.5);
    }
}

/* The point moved to the nearest floats, as a float query would be. */
static void round_to_float(double *p)
{
    for (int k = 0; k < 3; k++)
        p[k] = (float)p[k];
}

/* The query's float and rounding as point_query.c's level_point has them. */
static void float_point(const double *p, float *pf, float *dp)
{
    float d = 0.0f;
    for (int k = 0; k < 3; k++) {
        pf[k] = (float)p[k];
        const float e = (float)fabs(p[k] - (double)pf[k]);
        d = e > d ? e : d;
    }
    *dp = d > 0.0f ? nextafterf(d, INFINITY) : 0.0f;
}

/* A tree of one block, and its bounds made. */
static const rtk_block_bounds *bounds_of(rtk_accel *a, block *b)
{
    memset(a, 0, sizeof *a);
    a->layout = b->vertices ? RTK_LAYOUT_BVH8_TRIANGLE4V : RTK_LAYOUT_BVH4_TRIANGLE4;
    a->tris = &b->t;
    a->leaf_count = 1;
    const rtk_block_bounds *bb = rtk_block_bounds_of(a);
    assert_non_null(bb);
    return bb;
}

static const rtk_block_obb *box_of(rtk_accel *a, block *b) { return &bounds_of(a, b)->obb[0]; }

static void test_never_above(void **state)
{
    (void)state;
    long checked = 0;
    for (int si = 0; si < 5; si++)
        for (int oi = 0; oi < 3; oi++)
            for (int trial = 0; trial < 400; trial++) {
                block b;
                double c[3];
                const double s = trial_block(si, oi, trial, &b, c);
                rtk_accel a;
                const rtk_block_obb *o = box_of(&a, &b);
                for (int q = 0; q < 40; q++) {
                    static const int kinds[5] = {AT_VERTEX, ON_FACE, NEAR, FARTHER, FAR};
                    double p[3];
                    trial_point(&b, (int)(rnd() * b.count), c, s, kinds[q % 5], p);
                    for (int pass = 0; pass < 2; pass++) { /* a double point, then its float */
                        if (pass)
                            round_to_float(p);
                        float pf[3], dp;
                        float_point(p, pf, &dp);
                        const double want = true_d2(&b, p);
                        const float got = rtk_block_obb_lower2(o, pf, dp);
                        /* (beyond float's range the walk's bound is infinite too) */
                        if (!((double)got <= want || (want > FLT_MAX && got == INFINITY)))
                            fail_msg("scale %g, offset %g, trial %d, point %d (%s): bound %.9g above %.17g", s,
                                     offsets[oi], trial, q, pass ? "float" : "double", got, want);
                        checked++;
                    }
                }
                rtk_block_bounds_drop(&a);
                assert_null(a.block_bounds);
            }
    assert_true(checked == 5L * 3 * 400 * 40 * 2);
}

/* Straight above a flat tilted block, the box bounds nearly the distance;
 * the block's axis-aligned box, not nearly. */
static void test_tight(void **state)
{
    (void)state;
    double worst = 1.0, aabb_best = 0.0;
    for (int trial = 0; trial < 200; trial++) {
        const double c[3] = {rnd(), rnd(), rnd()};
        block b;
        make_block(&b, c, 1.0, 1, trial % 2);
        double v[3][3], n[3];
        corners(&b, 0, v);
        const double e1[3] = {v[1][0] - v[0][0], v[1][1] - v[0][1], v[1][2] - v[0][2]};
        const double e2[3] = {v[2][0] - v[0][0], v[2][1] - v[0][1], v[2][2] - v[0][2]};
        n[0] = e1[1] * e2[2] - e1[2] * e2[1], n[1] = e1[2] * e2[0] - e1[0] * e2[2], n[2] = e1[0] * e2[1] - e1[1] * e2[0];
        const double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (!(len > 1e-3))
            continue; /* a needle or point first: no normal to stand on */
        double p[3], lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        for (int k = 0; k < 3; k++)
            p[k] = (v[0][k] + v[1][k] + v[2][k]) / 3.0 + 10.0 * n[k] / len;
        for (int t = 0; t < b.count; t++) {
            double w[3][3];
            corners(&b, t, w);
            for (int i = 0; i < 3; i++)
                for (int k = 0; k < 3; k++)
                    lo[k] = fmin(lo[k], w[i][k]), hi[k] = fmax(hi[k], w[i][k]);
        }
        double g2 = 0.0;
        for (int k = 0; k < 3; k++) {
            const double g = fmax(fmax(lo[k] - p[k], p[k] - hi[k]), 0.0);
            g2 += g * g;
        }
        rtk_accel a;
        const rtk_block_obb *o = box_of(&a, &b);
        float pf[3], dp;
        float_point(p, pf, &dp);
        const double want = true_d2(&b, p);
        const double r = rtk_block_obb_lower2(o, pf, dp) / want;
        worst = r < worst ? r : worst;
        aabb_best = g2 / want > aabb_best ? g2 / want : aabb_best;
        rtk_block_bounds_drop(&a);
    }
    /* the oriented box: within 1% of the distance squared; the axis-aligned
     * one short of it for some tilted block */
    if (!(worst > 0.99))
        fail_msg("oriented box bounds only %.4f of the squared distance", worst);
    assert_true(aabb_best > 0.0);
}

/* Which boxes the walk tests: a tilted flat block's, not an axis-aligned
 * one's (its axis-aligned box is as thin). */
static void test_worth(void **state)
{
    (void)state;
    int tilted = 0, tilted_worth = 0;
    for (int trial = 0; trial < 100; trial++) {
        const double c[3] = {rnd(), rnd(), rnd()};
        block b;
        make_block(&b, c, 1.0, 1, trial % 2);
        rtk_accel a;
        const rtk_block_bounds *bb = bounds_of(&a, &b);
        tilted++;
        tilted_worth += rtk_block_worth(bb, 0);
        rtk_block_bounds_drop(&a);
        /* the same block flattened onto z = c[2]: nothing to gain */
        for (int k = 0; k < 4; k++)
            if (b.t.prim[k] != RTK_BVH4_EMPTY) {
                b.t.v0z[k] = (float)c[2];
                if (b.vertices) {
                    b.tv.v1z[k] = (float)c[2];
                    b.tv.v2z[k] = (float)c[2];
                } else
                    b.t.e1z[k] = b.t.e2z[k] = 0.0f;
            }
        bb = bounds_of(&a, &b);
        assert_false(rtk_block_worth(bb, 0));
        rtk_block_bounds_drop(&a);
    }
    /* (a block of needles or points has no normal to lean on) */
    if (!(tilted_worth * 10 >= tilted * 8))
        fail_msg("%d of %d tilted flat blocks worth their box", tilted_worth, tilted);
}

/* ---- the triangles' own bounds (tri_lower.h) ---- */

/* The four lanes' bounds, from the block as the leaf walk reads it. */
static void tri_bounds(const block *b, const double *p, float *lo)
{
    float pf[3], dp;
    float_point(p, pf, &dp);
    const float *f = (const float *)&b->t;
    vfloat4 a[3], e1[3], e2[3];
    for (int ax = 0; ax < 3; ax++) {
        a[ax] = vf4_load(f + 4 * ax);
        e1[ax] = b->vertices ? vf4_sub(vf4_load(f + 12 + 4 * ax), a[ax]) : vf4_load(f + 12 + 4 * ax);
        e2[ax] = b->vertices ? vf4_sub(vf4_load(f + 24 + 4 * ax), a[ax]) : vf4_load(f + 24 + 4 * ax);
    }
    vf4_storeu(lo, rtk_tri4_lower(a[0], a[1], a[2], e1[0], e1[1], e1[2], e2[0], e2[1], e2[2], pf, dp));
}

static double tri_distance(const block *b, int k, const double *p)
{
    double v[3][3];
    corners(b, k, v);
    rtk_tri_closest t;
    rtk_closest_point_triangle(&t, p, v[0], v[1], v[2]);
    return sqrt(t.d2);
}

/* Lane k turned into a sliver: its third vertex moved to a point whose
 * angle at v0 has a sine of about 2^-4 (the least the bound takes), on
 * either side of the long edge. */
static void make_sliver(block *b, int k)
{
    double v[3][3];
    corners(b, k, v);
    const double e[3] = {v[1][0] - v[0][0], v[1][1] - v[0][1], v[1][2] - v[0][2]};
    const double w[3] = {v[2][0] - v[0][0], v[2][1] - v[0][1], v[2][2] - v[0][2]};
    /* the part of w perpendicular to e, scaled to 0.07 |e| (sine ~0.07) */
    const double ee = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
    const double t = (w[0] * e[0] + w[1] * e[1] + w[2] * e[2]) / ee;
    double q[3] = {w[0] - t * e[0], w[1] - t * e[1], w[2] - t * e[2]};
    const double qn = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
    if (!(qn > 0.0) || !(ee > 0.0))
        return;
    const double along = 0.2 + 0.6 * rnd(), side = (0.065 + 0.02 * rnd()) * sqrt(ee) * along / qn;
    for (int a = 0; a < 3; a++)
        v[2][a] = v[0][a] + along * e[a] + side * q[a];
    set_lane(b, k, v);
}

static void test_tri_never_above(void **state)
{
    (void)state;
    long checked = 0, bounded = 0, away = 0;
    for (int si = 0; si < 5; si++)
        for (int oi = 0; oi < 3; oi++)
            for (int trial = 0; trial < 400; trial++) {
                block b;
                double c[3];
                const double s = trial_block(si, oi, trial, &b, c);
                if (trial % 3 == 0)
                    for (int k = 0; k < b.count; k++)
                        make_sliver(&b, k);
                for (int q = 0; q < 40; q++) {
                    double p[3];
                    const int lane = (int)(rnd() * b.count), where = q % 7;
                    trial_point(&b, lane, c, s, where, p);
                    for (int pass = 0; pass < 2; pass++) { /* a double point, then its float */
                        if (pass)
                            round_to_float(p);
                        float lo[4];
                        tri_bounds(&b, p, lo);
                        for (int k = 0; k < b.count; k++) {
                            const double want = tri_distance(&b, k, p);
                            /* (beyond float's range the bound is never taken) */
                            if (!((double)lo[k] <= want || want > FLT_MAX))
                                fail_msg("scale %g, offset %g, trial %d, point %d (%s), lane %d: bound %.9g above "
                                         "%.17g",
                                         s, offsets[oi], trial, q, pass ? "float" : "double", k, lo[k], want);
                            if (where >= FARTHER) { /* (on and near the surface the bound is 0) */
                                bounded += lo[k] > 0.0f;
                                away++;
                            }
                            checked++;
                        }
                        for (int k = b.count; k < 4; k++) /* unused lanes: no bound */
                            assert_true(lo[k] == 0.0f);
                    }
                }
            }
    /* away from the surface most triangles are bounded at all (needles,
     * points and, far off, tiny triangles are not) */
    if (!(bounded * 2 > away))
        fail_msg("%ld of %ld triangles away from the surface bounded", bounded, away);
    assert_true(checked > 5L * 3 * 400 * 40 * 2);
}

/* Far off, the bound is within 2^-11 of the distance: there a query meets
 * many triangles at nearly its distance, and each one bounded above it is
 * one not measured in double. */
static void test_tri_tight(void **state)
{
    (void)state;
    double worst = 1.0;
    for (int trial = 0; trial < 2000; trial++) {
        const double c[3] = {rnd(), rnd(), rnd()};
        block b;
        make_block(&b, c, 1.0, trial % 2, trial % 4 >= 2);
        /* 10 to 1000 block sizes off, in a random direction */
        double p[3], dir[3], n2 = 0.0;
        for (int k = 0; k < 3; k++)
            dir[k] = rnd() - 0.5, n2 += dir[k] * dir[k];
        const double r = (10.0 + 990.0 * rnd()) / sqrt(n2);
        for (int k = 0; k < 3; k++)
            p[k] = c[k] + r * dir[k];
        float lo[4];
        tri_bounds(&b, p, lo);
        for (int k = 0; k < b.count; k++) {
            if (!(lo[k] > 0.0f))
                continue; /* (a needle, a point or a sliver: not bounded) */
            const double q = lo[k] / tri_distance(&b, k, p);
            worst = q < worst ? q : worst;
        }
    }
    if (!(worst > 1.0 - 0x1p-11))
        fail_msg("far off, the bound is only %.7f of the distance", worst);
}

/* ---- the boxes of the nodes' children (node_obb) ---- */

/* A tree of width w made by hand over blocks on a curved patch (a
 * sphere's cap of radius 20 s about c, tilted blocks of size s, flat or
 * not): the root's children are inner nodes (one of them with an inner
 * node below it), a leaf of three blocks, a leaf of one, and an empty
 * slot; the inner nodes' children leaves of one or two blocks. */
enum { TREE_BLOCKS = 40 };
typedef struct hand_tree {
    block blocks[TREE_BLOCKS];
    rtk_triangle4 tris[TREE_BLOCKS];
    rtk_bvh8_node n8[4];
    rtk_bvh4_node n4[4];
    int used;
} hand_tree;

static uint32_t hand_leaf(hand_tree *t, int blocks, const double *c, double s, int vertices)
{
    const uint32_t first = (uint32_t)t->used;
    for (int i = 0; i < blocks; i++, t->used++) {
        const double th = 0.6 * rnd(), ph = 6.283 * rnd();
        const double at[3] = {c[0] + 20.0 * s * sin(th) * cos(ph), c[1] + 20.0 * s * sin(th) * sin(ph),
                              c[2] + 20.0 * s * cos(th)};
        make_block(&t->blocks[t->used], at, s, rnd() < 0.5, vertices);
        t->tris[t->used] = t->blocks[t->used].t;
    }
    return rtk_leaf_ref(first, (uint32_t)blocks);
}

/* The vertices' float box under ref (lanes of the node arrays). */
static void hand_box(const hand_tree *t, const rtk_accel *a, uint32_t ref, int w, float *lo, float *hi)
{
    if (ref == RTK_BVH4_EMPTY)
        return;
    if (ref & RTK_BVH4_LEAF_BIT) {
        for (uint32_t b = rtk_leaf_first(ref); b < rtk_leaf_first(ref) + rtk_leaf_blocks(ref); b++)
            for (int k = 0; k < t->blocks[b].count; k++) {
                double v[3][3];
                corners(&t->blocks[b], k, v);
                for (int i = 0; i < 3; i++)
                    for (int x = 0; x < 3; x++) {
                        lo[x] = fminf(lo[x], (float)v[i][x]);
                        hi[x] = fmaxf(hi[x], (float)v[i][x]);
                    }
            }
        return;
    }
    for (int c = 0; c < w; c++)
        hand_box(t, a, w == 8 ? t->n8[ref].child[c] : t->n4[ref].child[c], w, lo, hi);
}

static void hand_node(hand_tree *t, uint32_t i, int w, const uint32_t *child)
{
    for (int c = 0; c < w; c++) {
        float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        hand_box(t, NULL, child[c], w, lo, hi);
        if (w == 8) {
            rtk_bvh8_node *n = &t->n8[i];
            n->child[c] = child[c];
            n->lower_x[c] = lo[0], n->lower_y[c] = lo[1], n->lower_z[c] = lo[2];
            n->upper_x[c] = hi[0], n->upper_y[c] = hi[1], n->upper_z[c] = hi[2];
        } else {
            rtk_bvh4_node *n = &t->n4[i];
            n->child[c] = child[c];
            n->lower_x[c] = lo[0], n->lower_y[c] = lo[1], n->lower_z[c] = lo[2];
            n->upper_x[c] = hi[0], n->upper_y[c] = hi[1], n->upper_z[c] = hi[2];
        }
    }
}

/* The least squared distance from p to the triangles under ref. */
static double hand_d2(const hand_tree *t, uint32_t ref, int w, const double *p)
{
    if (ref == RTK_BVH4_EMPTY)
        return INFINITY;
    double best = INFINITY;
    if (ref & RTK_BVH4_LEAF_BIT) {
        for (uint32_t b = rtk_leaf_first(ref); b < rtk_leaf_first(ref) + rtk_leaf_blocks(ref); b++)
            best = fmin(best, true_d2(&t->blocks[b], p));
        return best;
    }
    for (int c = 0; c < w; c++)
        best = fmin(best, hand_d2(t, w == 8 ? t->n8[ref].child[c] : t->n4[ref].child[c], w, p));
    return best;
}

/* Every child's box of every node, at every scale and offset, as the walk
 * tests it (rtk_block_obb_lower2 on its lane): never above the true
 * distance to the triangles below it, for points at their vertices, near
 * and far, double and float; and it leaves out more of the points far
 * off than the axis-aligned boxes do. */
static void test_node_boxes(void **state)
{
    (void)state;
    long checked = 0, inner = 0, tighter = 0;
    static hand_tree t;
    for (int w = 4; w <= 8; w += 4)
        for (int si = 0; si < 5; si++)
            for (int oi = 0; oi < 3; oi++)
                for (int trial = 0; trial < 20; trial++) {
                    const double s = scales[si];
                    const int vertices = trial % 2;
                    const double c[3] = {offsets[oi] * s * 1e3 * (rnd() + 0.5), offsets[oi] * s * 1e3 * (rnd() - 0.5),
                                         s * (rnd() - 0.5)};
                    memset(&t, 0, sizeof t);
                    /* node 3 under node 2, nodes 1 and 2 under the root */
                    uint32_t kids[8];
                    for (int k = 0; k < 8; k++)
                        kids[k] = k < w - 1 ? hand_leaf(&t, 1 + (k & 1), c, s, vertices) : RTK_BVH4_EMPTY;
                    hand_node(&t, 3, w, kids);
                    for (int k = 0; k < 8; k++)
                        kids[k] = k == 0 ? 3 : k < w - 2 ? hand_leaf(&t, 1, c, s, vertices) : RTK_BVH4_EMPTY;
                    hand_node(&t, 2, w, kids);
                    for (int k = 0; k < 8; k++)
                        kids[k] = k < w ? hand_leaf(&t, 1 + (k % 3 == 0), c, s, vertices) : RTK_BVH4_EMPTY;
                    hand_node(&t, 1, w, kids);
                    for (int k = 0; k < 8; k++)
                        kids[k] = k == 0 ? 1 : k == 1 ? 2 : k == 2 ? hand_leaf(&t, 3, c, s, vertices)
                                                      : k == 3 ? hand_leaf(&t, 1, c, s, vertices) : RTK_BVH4_EMPTY;
                    hand_node(&t, 0, w, kids);
                    assert_true(t.used <= TREE_BLOCKS);
                    rtk_accel a;
                    memset(&a, 0, sizeof a);
                    a.layout = w == 8 ? (vertices ? RTK_LAYOUT_BVH8_TRIANGLE4V : RTK_LAYOUT_BVH8_TRIANGLE4)
                                      : (vertices ? RTK_LAYOUT_BVH4_TRIANGLE4V : RTK_LAYOUT_BVH4_TRIANGLE4);
                    a.tris = t.tris;
                    a.leaf_count = (uint64_t)t.used;
                    a.nodes = w == 8 ? (void *)t.n8 : (void *)t.n4;
                    a.node_count = 4;
                    a.root = 0;
                    const rtk_block_bounds *bb = rtk_block_bounds_of(&a);
                    assert_non_null(bb);
                    for (uint32_t i = 0; i < 4; i++)
                        for (int lane = 0; lane < w; lane++) {
                            const uint32_t ref = w == 8 ? t.n8[i].child[lane] : t.n4[i].child[lane];
                            if (ref == RTK_BVH4_EMPTY)
                                continue;
                            rtk_block_obb o;
                            const float *row = bb->node_obb + (size_t)i * RTK_NODE_OBB_ROWS * w;
                            for (int k = 0; k < 3; k++) {
                                o.c[k] = row[k * w + lane];
                                o.h[k] = row[(3 + k) * w + lane];
                                o.axis[0][k] = row[(6 + k) * w + lane];
                                o.axis[2][k] = row[(9 + k) * w + lane];
                            }
                            rtk_obb_axis1(o.axis[2], o.axis[0], o.axis[1]);
                            float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
                            hand_box(&t, &a, ref, w, lo, hi);
                            for (int q = 0; q < 30; q++) {
                                double p[3];
                                const int kind = q % 3;
                                if (kind == 0) { /* a vertex below */
                                    uint32_t r = ref;
                                    while (!(r & RTK_BVH4_LEAF_BIT))
                                        r = w == 8 ? t.n8[r].child[0] : t.n4[r].child[0];
                                    const block *b = &t.blocks[rtk_leaf_first(r)];
                                    trial_point(b, (int)(rnd() * b->count), c, s, AT_VERTEX, p);
                                } else { /* about the cap, near or far */
                                    const double r = s * (kind == 1 ? 20.0 : 400.0);
                                    for (int k = 0; k < 3; k++)
                                        p[k] = c[k] + r * (2.0 * rnd() - 1.0);
                                }
                                for (int pass = 0; pass < 2; pass++) {
                                    if (pass)
                                        round_to_float(p);
                                    float pf[3], dp;
                                    float_point(p, pf, &dp);
                                    const double want = hand_d2(&t, ref, w, p);
                                    const float got = rtk_block_obb_lower2(&o, pf, dp);
                                    if (!((double)got <= want || (want > FLT_MAX && got == INFINITY)))
                                        fail_msg("width %d, scale %g, offset %g, node %u lane %d: bound %.9g above %.17g",
                                                 w, s, offsets[oi], i, lane, got, want);
                                    if (kind && pass && !(ref & RTK_BVH4_LEAF_BIT)) {
                                        double g2 = 0.0;
                                        for (int k = 0; k < 3; k++) {
                                            const double g = fmax(fmax(lo[k] - p[k], p[k] - hi[k]), 0.0);
                                            g2 += g * g;
                                        }
                                        inner++;
                                        tighter += (double)got > g2;
                                    }
                                    checked++;
                                }
                            }
                        }
                    rtk_block_bounds_drop(&a);
                }
    assert_true(checked > 100000);
    /* an inner node's box bounds many points off the cap tighter than its
     * axis-aligned box */
    if (!(tighter * 8 > inner))
        fail_msg("an inner node's oriented box tighter for %ld of %ld points", tighter, inner);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_never_above),
        cmocka_unit_test(test_tight),
        cmocka_unit_test(test_worth),
        cmocka_unit_test(test_node_boxes),
        cmocka_unit_test(test_tri_never_above),
        cmocka_unit_test(test_tri_tight),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
