/*
 * Triangle primitive: bounds, degeneracy, and the fast ray-triangle test.
 *
 * Header-only so that each backend compiles it with its own ISA flags and the
 * tests compile the very same arithmetic as their brute-force reference.
 *
 * Fast intersector (Moeller-Trumbore in the form Embree 3 computes it,
 * division-free): with the edges e1 = v1 - v0, e2 = v2 - v0, the normal
 * n = cross(e1, e2), c = v0 - o and r = cross(c, d), the unnormalised
 * barycentrics are U = dot(r, e2) and V = -dot(r, e1) and the distance
 * T = dot(n, c), each with the sign of det = dot(n, d) taken off, compared
 * against |det| so a miss costs no division.  A hit needs U >= 0, V >= 0,
 * U + V <= |det| and tnear*|det| <= T <= tfar*|det|; det == 0 (ray
 * parallel to the plane, or a degenerate triangle) never hits, and neither
 * does |det| < FLT_MIN (a triangle and ray so small, near 1e-13 and below,
 * that 1/|det| would overflow and t come out NaN or infinite); any NaN
 * makes every comparison false, so NaN input never hits.  Both faces are hit
 * (no culling).
 *
 * At shared edges: the two edge functions from v0 are r, made from v0 alone,
 * against the edge's vector.  Two triangles that share an edge and both
 * start at the same end of it (T1 = (a, b, c), T2 = (a, d, b)) hold the
 * same floats b - a for it, as T1's e1 and T2's e2, so they compute its
 * function from the same floats, exactly negated: a ray cannot pass between
 * them or hit both unless the function is exactly zero (then both take
 * the ray: a double hit, never a leak).
 * Moeller-Trumbore's usual form (U = dot(o - v0, cross(d, e2)),
 * V = dot(d, cross(o - v0, e1))) evaluates the two triple products in
 * different orders and gave twice the double hits at the shared edges of
 * the dragon and San Miguel (docs/benchmarks/accuracy.md).  Edges that the two triangles reach from
 * different corners, and the edge opposite v0 (U + V <= |det|), have no
 * such guarantee: a ray exactly through them may hit both triangles or
 * neither.  The watertight intersector below has none of these.
 *
 * Watertight intersector (Woop, Benthin and Wald 2013, "Watertight
 * Ray/Triangle Intersection"), used by the robust layouts: the vertices are
 * taken relative to the ray origin and sheared so that the ray runs along
 * +z from the origin of the xy plane; the three 2D edge functions
 * U (of edge v1 v2), V (v2 v0) and W (v0 v1) are then the barycentric
 * weights of v0, v1, v2 scaled by det = U + V + W.  A point is inside when
 * all three have one sign.  An edge shared by two triangles has the same
 * two transformed vertices in both, so its edge function is computed from
 * the same floats in both and comes out exactly negated (a*b - c*d against
 * c*d - a*b: no FMA, which rtk's build forbids with -ffp-contract=off):
 * a ray can never pass between the two, and where a float edge function is
 * exactly zero all three are recomputed in double, where the products of
 * floats are exact and the sign of each difference is too; so is a
 * triangle whose |det| comes out below FLT_MIN (edge functions that
 * underflow: a triangle of about 1e-19 or less across, as seen from the
 * origin), which the fast test never hits.  So a ray through a shared edge
 * or vertex of a closed mesh hits at least one of the triangles; it may
 * report either.  The hit needs det != 0 (a ray in the triangle's plane, or
 * a triangle of no area, never hits) and tnear <= t <= tfar.  u and v are the weights of v1 and v2,
 * as the fast intersector's.  The vertices must be the application's
 * floats exactly (not v0 + (v1 - v0)): the robust layouts store vertices,
 * not edges.
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

/* rtk's range (rtk.h, "the range rtk answers in"): vertex coordinates
 * within +-RTK_COORD_LIMIT, and triangles whose cross product of edges
 * |(v1 - v0) x (v2 - v0)| (in double, its largest component) is at least
 * RTK_CROSS_LIMIT.  Within it the fast test's products stay normal floats:
 * |T| <= |e2| |s| |e1| and the watertight test's
 * T <= 192 (2^36)^3 * 2^8 (for a direction rescaled to the core's window,
 * see query.c) stay below 2^124, and |det| = |e1 x e2| |d| cos stays above
 * FLT_MIN for all but rays within 2^-22 of the triangle's plane. */
#ifndef RTK_COORD_LIMIT
#define RTK_COORD_LIMIT 68719476736.0f /* 2^36, as rtk.h */
#endif
#define RTK_CROSS_LIMIT 0x1p-80

/* Every coordinate finite and within +-RTK_COORD_LIMIT (NaN fails). */
static inline int rtk_triangle_coords_in_range(const float v0[3], const float v1[3], const float v2[3])
{
    int in = 1;
    for (int k = 0; k < 3; k++)
        in &= (fabsf(v0[k]) <= RTK_COORD_LIMIT) & (fabsf(v1[k]) <= RTK_COORD_LIMIT) &
              (fabsf(v2[k]) <= RTK_COORD_LIMIT);
    return in;
}

/* A triangle of some area (not rtk_triangle_is_degenerate) too small for
 * rtk's range: its cross product of edges below RTK_CROSS_LIMIT. */
static inline int rtk_triangle_is_tiny(const float v0[3], const float v1[3], const float v2[3])
{
    double a[3] = {(double)v1[0] - v0[0], (double)v1[1] - v0[1], (double)v1[2] - v0[2]};
    double b[3] = {(double)v2[0] - v0[0], (double)v2[1] - v0[1], (double)v2[2] - v0[2]};
    const double c[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    return fabs(c[0]) < RTK_CROSS_LIMIT && fabs(c[1]) < RTK_CROSS_LIMIT && fabs(c[2]) < RTK_CROSS_LIMIT;
}

/* What a build does with a triangle, the same in every builder: */
enum rtk_triangle_class {
    RTK_TRIANGLE_HITTABLE,
    RTK_TRIANGLE_NON_FINITE,   /* a NaN or infinite vertex: left out */
    RTK_TRIANGLE_FAR,          /* a coordinate beyond RTK_COORD_LIMIT: left out */
    RTK_TRIANGLE_DEGENERATE,   /* no area: left out (kept, never hit, where the geometry deforms) */
    RTK_TRIANGLE_TINY,         /* area below the range: like a degenerate one */
};

static inline enum rtk_triangle_class rtk_triangle_classify(const float v0[3], const float v1[3], const float v2[3])
{
    if (!rtk_triangle_is_finite(v0, v1, v2))
        return RTK_TRIANGLE_NON_FINITE;
    if (!rtk_triangle_coords_in_range(v0, v1, v2))
        return RTK_TRIANGLE_FAR;
    if (rtk_triangle_is_degenerate(v0, v1, v2))
        return RTK_TRIANGLE_DEGENERATE;
    return rtk_triangle_is_tiny(v0, v1, v2) ? RTK_TRIANGLE_TINY : RTK_TRIANGLE_HITTABLE;
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
    /* c = v0 - o, r = cross(c, d), n = cross(e1, e2) */
    const float cx = v0[0] - o[0], cy = v0[1] - o[1], cz = v0[2] - o[2];
    const float rx = cy * d[2] - cz * d[1];
    const float ry = cz * d[0] - cx * d[2];
    const float rz = cx * d[1] - cy * d[0];
    const float nx = e1[1] * e2[2] - e1[2] * e2[1];
    const float ny = e1[2] * e2[0] - e1[0] * e2[2];
    const float nz = e1[0] * e2[1] - e1[1] * e2[0];
    const float det = nx * d[0] + ny * d[1] + nz * d[2];
    const float absdet = fabsf(det);
    const float U = rtk_xor_sign(rx * e2[0] + ry * e2[1] + rz * e2[2], det);
    const float V = rtk_xor_sign(rx * e1[0] + ry * e1[1] + rz * e1[2], -det);
    if (!(U >= 0.0f && V >= 0.0f && U + V <= absdet && absdet >= FLT_MIN))
        return 0;
    const float T = rtk_xor_sign(nx * cx + ny * cy + nz * cz, det);
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

/* The per-ray part of the watertight test: the axis of the largest
 * direction component becomes z (kz), the next two cyclically x and y, and
 * the shear constants sx = d[kx]/d[kz], sy = d[ky]/d[kz], sz = 1/d[kz].
 * Where d[kz] < 0 this mirrors the plane and turns every edge function's
 * sign round (Woop et al. swap kx and ky there to keep the winding): the
 * test takes either sign, u, v and t are quotients of two of them, and
 * culling reads the normal, so nothing changes but the signs; the kernels
 * then need three permutations, not six (traverse_bvhn.h). */
typedef struct rtk_watertight_ray {
    int kx, ky, kz;
    float sx, sy, sz;
} rtk_watertight_ray;

/* The axes alone: kz of the largest |d| component, kx and ky the next two
 * cyclically (the kernels' set-up takes these and divides its own way,
 * traverse_bvhn.h's leaf_ray_init). */
static inline void rtk_watertight_axes(const float d[3], int *kx, int *ky, int *kz)
{
    const float ax = fabsf(d[0]), ay = fabsf(d[1]), az = fabsf(d[2]);
    *kz = ax > ay ? (ax > az ? 0 : 2) : (ay > az ? 1 : 2);
    *kx = *kz == 2 ? 0 : *kz + 1;
    *ky = *kx == 2 ? 0 : *kx + 1;
}

static inline void rtk_watertight_ray_init(const float d[3], rtk_watertight_ray *w)
{
    rtk_watertight_axes(d, &w->kx, &w->ky, &w->kz);
    w->sx = d[w->kx] / d[w->kz];
    w->sy = d[w->ky] / d[w->kz];
    w->sz = 1.0f / d[w->kz];
}

/* An edge function's sign at the ray moved by (e, e^2) in the sheared
 * plane, e -> +0: f itself unless it is exactly 0, else the sign of its
 * gradient's x, else of its y (0 only for an edge seen end-on). */
static inline double rtk_edge_tiebreak(double f, double gx, double gy)
{
    return f != 0.0 ? f : gx != 0.0 ? gx : gy;
}

/* The watertight test decided in double precision, from the transformed
 * vertices a, b, c (x and y, sheared) and their scaled z (z[k] = sz times
 * vertex k's z): every product of two floats is exact there, so each edge
 * function has the exact sign.  Returns 1 and fills *hit (t not clamped to
 * [tnear, tfar] after its rounding to float: the caller's) on a hit within
 * [tnear, tfar].  The fallback of every watertight kernel, single rays and
 * packets, so all decide such rays alike.
 *
 * A ray exactly through an edge or a vertex (edge functions exactly 0) is
 * decided as if moved by (e, e^2) in the sheared plane (simulation of
 * simplicity): of the two triangles that share an edge, and of a fan of
 * triangles around a vertex, exactly one is hit where the mesh crosses
 * the ray once, so rays through edges and vertices neither leak nor hit
 * twice (a silhouette, where the mesh folds over in the ray's view, is
 * hit by both or neither of its triangles, the crossings' true parity).
 * The edge functions of a shared edge are the same products in both
 * triangles, negated, so the two agree on it exactly.  A triangle's own
 * boundary is half open, as in a rasteriser's fill rule: a ray through
 * an edge or vertex of a lone triangle hits it or not by the edge's
 * direction. */
static inline int rtk_watertight_double(const float a[2], const float b[2], const float c[2], const float z[3],
                                        float tnear, float tfar, rtk_tri_hit *hit)
{
    const double u = (double)c[0] * b[1] - (double)c[1] * b[0];
    const double v = (double)a[0] * c[1] - (double)a[1] * c[0];
    const double w = (double)b[0] * a[1] - (double)b[1] * a[0];
    /* the gradients: u's is (c.y - b.y, b.x - c.x), and so on round */
    const double su = rtk_edge_tiebreak(u, (double)c[1] - b[1], (double)b[0] - c[0]);
    const double sv = rtk_edge_tiebreak(v, (double)a[1] - c[1], (double)c[0] - a[0]);
    const double sw = rtk_edge_tiebreak(w, (double)b[1] - a[1], (double)a[0] - b[0]);
    if (!((su > 0.0 && sv > 0.0 && sw > 0.0) || (su < 0.0 && sv < 0.0 && sw < 0.0)))
        return 0;
    const double det = u + v + w;
    if (det == 0.0)
        return 0;
    const double t = (u * z[0] + v * z[1] + w * z[2]) / det;
    if (!(t >= tnear && t <= tfar))
        return 0;
    hit->t = (float)t;
    hit->u = (float)(v / det);
    hit->v = (float)(w / det);
    return 1;
}

/*
 * One ray against one triangle given by its three vertices, watertight.
 * Returns 1 and fills *hit when the ray hits within [tnear, tfar].
 */
static inline int rtk_triangle_intersect_watertight(const float o[3], const rtk_watertight_ray *w, float tnear,
                                                    float tfar, const float v0[3], const float v1[3],
                                                    const float v2[3], rtk_tri_hit *hit)
{
    const int kx = w->kx, ky = w->ky, kz = w->kz;
    const float az = v0[kz] - o[kz], bz = v1[kz] - o[kz], cz = v2[kz] - o[kz];
    const float a[2] = {(v0[kx] - o[kx]) - w->sx * az, (v0[ky] - o[ky]) - w->sy * az};
    const float b[2] = {(v1[kx] - o[kx]) - w->sx * bz, (v1[ky] - o[ky]) - w->sy * bz};
    const float c[2] = {(v2[kx] - o[kx]) - w->sx * cz, (v2[ky] - o[ky]) - w->sy * cz};
    float U = c[0] * b[1] - c[1] * b[0];
    float V = a[0] * c[1] - a[1] * c[0];
    float W = b[0] * a[1] - b[1] * a[0];
    const float det = U + V + W;
    const float absdet = fabsf(det);
    /* a zero among U, V, W makes the product zero (so does an underflow,
     * decided exactly too), in every kernel the same way */
    if ((U * V) * W == 0.0f || absdet < FLT_MIN) {
        const float z[3] = {w->sz * az, w->sz * bz, w->sz * cz};
        if (!rtk_watertight_double(a, b, c, z, tnear, tfar, hit))
            return 0;
        if (hit->t < tnear)
            hit->t = tnear;
        if (hit->t > tfar)
            hit->t = tfar;
        return 1;
    }
    if ((U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f))
        return 0;
    if (!(absdet >= FLT_MIN))
        return 0; /* NaN */
    const float T = rtk_xor_sign(U * (w->sz * az) + V * (w->sz * bz) + W * (w->sz * cz), det);
    if (!(T >= tnear * absdet && T <= tfar * absdet))
        return 0;
    const float inv = 1.0f / absdet;
    hit->t = T * inv;
    hit->u = rtk_xor_sign(V, det) * inv;
    hit->v = rtk_xor_sign(W, det) * inv;
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
