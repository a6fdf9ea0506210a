/*
 * Triangle primitive: bounds, degeneracy, and the fast ray-triangle test.
 *
 * Header-only so that each backend compiles it with its own ISA flags and the
 * tests compile the very same arithmetic as their brute-force reference.
 *
 * Fast intersector (Moeller-Trumbore, division-free form): with the edges
 * e1 = v1 - v0, e2 = v2 - v0 and the determinant det = dot(e1, cross(d, e2)),
 * the unnormalised barycentrics U, V and distance T are compared against |det|
 * so a miss costs no division.  A hit needs U >= 0, V >= 0, U + V <= |det|
 * and tnear*|det| <= T <= tfar*|det|; det == 0 (ray parallel to the plane, or
 * a degenerate triangle) never hits, and neither does |det| < FLT_MIN (a
 * triangle and ray so small, near 1e-13 and below, that 1/|det| would
 * overflow and t come out NaN or infinite); any NaN makes every comparison
 * false, so NaN input never hits.  Both faces are hit (no culling).
 *
 * Guarantees: none at shared edges and vertices (a ray exactly through an edge
 * may hit both triangles or neither).  The watertight variant is a later
 * addition.
 */
#ifndef RTK_GEOMETRY_TRIANGLE_H
#define RTK_GEOMETRY_TRIANGLE_H

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

static inline uint32_t rtk_float_bits(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

static inline float rtk_bits_float(uint32_t u)
{
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

/* x with the sign of s flipped when s is negative (xor of the sign bit). */
static inline float rtk_xor_sign(float x, float s)
{
    return rtk_bits_float(rtk_float_bits(x) ^ (rtk_float_bits(s) & 0x80000000u));
}

/* A triangle whose vertices are collinear or coincide (exactly zero normal in
 * double precision) has no area and is never hit; builders leave it out. */
static inline int rtk_triangle_is_degenerate(const float v0[3], const float v1[3], const float v2[3])
{
    double a[3] = {(double)v1[0] - v0[0], (double)v1[1] - v0[1], (double)v1[2] - v0[2]};
    double b[3] = {(double)v2[0] - v0[0], (double)v2[1] - v0[1], (double)v2[2] - v0[2]};
    return a[1] * b[2] == a[2] * b[1] && a[2] * b[0] == a[0] * b[2] && a[0] * b[1] == a[1] * b[0];
}

static inline int rtk_triangle_is_finite(const float v0[3], const float v1[3], const float v2[3])
{
    float s = 0.0f * v0[0] + 0.0f * v0[1] + 0.0f * v0[2] + 0.0f * v1[0] + 0.0f * v1[1] + 0.0f * v1[2] +
              0.0f * v2[0] + 0.0f * v2[1] + 0.0f * v2[2];
    return s == 0.0f; /* NaN for any NaN or infinity */
}

typedef struct rtk_tri_hit {
    float t, u, v;
} rtk_tri_hit;

/*
 * One ray against one triangle given as v0, e1 = v1 - v0, e2 = v2 - v0.
 * Returns 1 and fills *hit when tnear <= t <= tfar.
 */
static inline int rtk_triangle_intersect(const float o[3], const float d[3], float tnear, float tfar,
                                         const float v0[3], const float e1[3], const float e2[3],
                                         rtk_tri_hit *hit)
{
    /* p = cross(d, e2) */
    const float px = d[1] * e2[2] - d[2] * e2[1];
    const float py = d[2] * e2[0] - d[0] * e2[2];
    const float pz = d[0] * e2[1] - d[1] * e2[0];
    const float det = e1[0] * px + e1[1] * py + e1[2] * pz;
    const float absdet = fabsf(det);
    /* s = o - v0 */
    const float sx = o[0] - v0[0], sy = o[1] - v0[1], sz = o[2] - v0[2];
    const float U = rtk_xor_sign(sx * px + sy * py + sz * pz, det);
    if (!(U >= 0.0f && absdet >= FLT_MIN))
        return 0;
    /* q = cross(s, e1) */
    const float qx = sy * e1[2] - sz * e1[1];
    const float qy = sz * e1[0] - sx * e1[2];
    const float qz = sx * e1[1] - sy * e1[0];
    const float V = rtk_xor_sign(d[0] * qx + d[1] * qy + d[2] * qz, det);
    if (!(V >= 0.0f && U + V <= absdet))
        return 0;
    const float T = rtk_xor_sign(e2[0] * qx + e2[1] * qy + e2[2] * qz, det);
    if (!(T >= tnear * absdet && T <= tfar * absdet))
        return 0;
    const float inv = 1.0f / absdet;
    hit->t = T * inv;
    hit->u = U * inv;
    hit->v = V * inv;
    /* The product may round past an end of the interval the unscaled test
     * accepted; clamp so the reported t always satisfies tnear <= t <= tfar. */
    if (hit->t < tnear)
        hit->t = tnear;
    if (hit->t > tfar)
        hit->t = tfar;
    return 1;
}

/* Unnormalised geometric normal cross(e1, e2). */
static inline void rtk_triangle_normal(const float e1[3], const float e2[3], float n[3])
{
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
}

#endif
