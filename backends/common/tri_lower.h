/*
 * Float lower bounds of triangles' distances from a closest-point query
 * (point_query.c): four triangles in one SIMD step, before any is measured
 * in double.  tests/test_block_bounds.c checks them against brute force.
 */
#ifndef RTK_TRI_LOWER_H
#define RTK_TRI_LOWER_H

#include "simd/simd.h"

/* Lower bounds of four triangles' distances from the point (vertex a,
 * edges e1 = b - a and e2 = c - a, per axis), in float, before any is
 * measured in double (point_query.c).  pf is the query point in float,
 * dp the largest distance of the query's coordinates from it.
 *
 * Each is the float distance, lowered for rounding: where the point's
 * projection falls inside the triangle, its distance from the plane;
 * elsewhere, from the nearest of the three edges as segments.  Everything
 * is computed with lengths divided by R = |p - a|_1 + |e1|_1 + |e2|_1, so
 * that nothing overflows or underflows, and the result is lowered by
 * 2^-14 R (a triangle whose angle at a has a sine of at least 2^-4 costs a
 * few hundred ulps of R, and a point taken for inside or outside wrongly
 * lies within that of an edge, where both answers agree) and by twice the
 * point's own rounding dp.  Triangles that do not qualify get 0: angles
 * under that (needles and zero-area triangles), edges under 2^-20 R (the
 * point far off), and anything NaN (unused lanes).
 *
 * The margin is measured: tests/test_block_bounds.c finds bounds above
 * the distance at 2^-23 R and none at 2^-20 R over ten million triangles
 * and points (slivers at that sine, points on and beside edges, 2^-60 to
 * 2^60).  The 2^-10 R taken before it was measured sent a far point's
 * neighbouring triangles, within 0.2% of its distance, to be measured in
 * double: on the bunny's box points 2^-14 cuts the instructions of those
 * tests by 41% (callgrind). */
static inline vfloat4 rtk_tri4_lower(vfloat4 ax, vfloat4 ay, vfloat4 az, vfloat4 e1x, vfloat4 e1y, vfloat4 e1z,
                                     vfloat4 e2x, vfloat4 e2y, vfloat4 e2z, const float *pf, float dp)
{
    vfloat4 xx = vf4_sub(vf4_set1(pf[0]), ax), xy = vf4_sub(vf4_set1(pf[1]), ay),
            xz = vf4_sub(vf4_set1(pf[2]), az);
    const vfloat4 r = vf4_add(vf4_add(vf4_add(vf4_abs(xx), vf4_abs(xy)), vf4_abs(xz)),
                              vf4_add(vf4_add(vf4_add(vf4_abs(e1x), vf4_abs(e1y)), vf4_abs(e1z)),
                                      vf4_add(vf4_add(vf4_abs(e2x), vf4_abs(e2y)), vf4_abs(e2z))));
    const vfloat4 inv = vf4_div(vf4_set1(1.0f), r);
#define DOT_(ax_, ay_, az_, bx_, by_, bz_) vf4_add(vf4_add(vf4_mul(ax_, bx_), vf4_mul(ay_, by_)), vf4_mul(az_, bz_))
    xx = vf4_mul(xx, inv), xy = vf4_mul(xy, inv), xz = vf4_mul(xz, inv);
    e1x = vf4_mul(e1x, inv), e1y = vf4_mul(e1y, inv), e1z = vf4_mul(e1z, inv);
    e2x = vf4_mul(e2x, inv), e2y = vf4_mul(e2y, inv), e2z = vf4_mul(e2z, inv);
    const vfloat4 nx = vf4_sub(vf4_mul(e1y, e2z), vf4_mul(e1z, e2y));
    const vfloat4 ny = vf4_sub(vf4_mul(e1z, e2x), vf4_mul(e1x, e2z));
    const vfloat4 nz = vf4_sub(vf4_mul(e1x, e2y), vf4_mul(e1y, e2x));
    const vfloat4 nn = DOT_(nx, ny, nz, nx, ny, nz);
    const vfloat4 ee1 = DOT_(e1x, e1y, e1z, e1x, e1y, e1z), ee2 = DOT_(e2x, e2y, e2z, e2x, e2y, e2z);
    const vfloat4 zero = vf4_set1(0.0f), one = vf4_set1(1.0f);
    vfloat4 seg = vf4_set1(INFINITY); /* the nearest edge's squared distance */
    vfloat4 out = zero;               /* the largest outward measure: > 0 outside an edge */
    /* an edge from its start (the point at x from there) */
#define EDGE_(x, y, z, ex, ey, ez, ee)                                                                                 \
    do {                                                                                                               \
        /* n . ((p - start) x edge): positive outside */                                                              \
        const vfloat4 cx = vf4_sub(vf4_mul(y, ez), vf4_mul(z, ey)), cy = vf4_sub(vf4_mul(z, ex), vf4_mul(x, ez)),      \
                      cz = vf4_sub(vf4_mul(x, ey), vf4_mul(y, ex));                                                    \
        out = vf4_max(out, DOT_(nx, ny, nz, cx, cy, cz));                                                              \
        const vfloat4 t = vf4_min(vf4_max(vf4_div(DOT_(x, y, z, ex, ey, ez), ee), zero), one);                         \
        const vfloat4 gx = vf4_sub(x, vf4_mul(t, ex)), gy = vf4_sub(y, vf4_mul(t, ey)),                                \
                      gz = vf4_sub(z, vf4_mul(t, ez));                                                                 \
        seg = vf4_min(seg, DOT_(gx, gy, gz, gx, gy, gz));                                                              \
    } while (0)
    const vfloat4 fx = vf4_sub(e2x, e1x), fy = vf4_sub(e2y, e1y), fz = vf4_sub(e2z, e1z);
    EDGE_(xx, xy, xz, e1x, e1y, e1z, ee1);
    EDGE_(vf4_sub(xx, e1x), vf4_sub(xy, e1y), vf4_sub(xz, e1z), fx, fy, fz, DOT_(fx, fy, fz, fx, fy, fz));
    EDGE_(vf4_sub(xx, e2x), vf4_sub(xy, e2y), vf4_sub(xz, e2z), vf4_sub(zero, e2x), vf4_sub(zero, e2y),
          vf4_sub(zero, e2z), ee2);
#undef EDGE_
    const vfloat4 h = DOT_(nx, ny, nz, xx, xy, xz);
#undef DOT_
    const vfloat4 d2 = vf4_select(vf4_gt(out, zero), seg, vf4_div(vf4_mul(h, h), nn)); /* (distance / R)^2 */
    const vfloat4 edge_min = vf4_set1(0x1p-40f);
    const vbool4 fit = vb4_and(vb4_and(vf4_gt(nn, vf4_mul(vf4_set1(0x1p-8f), vf4_mul(ee1, ee2))),
                                       vf4_ge(ee1, edge_min)),
                               vf4_ge(ee2, edge_min));
    const vfloat4 lo = vf4_sub(vf4_mul(vf4_sub(vf4_sqrt(d2), vf4_set1(0x1p-14f)), r), vf4_set1(2.0f * dp));
    /* NaN lanes fail the comparison: 0 */
    return vf4_select(vb4_and(fit, vf4_gt(lo, zero)), lo, zero);
}

#endif
