/*
 * The point of a triangle nearest to a point, in double precision: the
 * one routine behind rtk's closest-point queries (backends/common/
 * point_query.c) and the tests' brute-force reference.
 *
 * The method is Ericson's ("Real-Time Collision Detection", 5.1.5): the
 * query point's region among the triangle's Voronoi regions (three
 * vertices, three edges, the face) is found from six dot products, and the
 * point is projected onto that feature.  Coordinates are floats of a mesh
 * (at most 2^36 in magnitude, rtk's range) and the query point a double,
 * so the products have ~40 bits of headroom.  A triangle without area (a
 * needle or a point), which only deforming geometries keep, has no face
 * region: its nearest point is on one of its three edges, taken as
 * segments.
 */
#ifndef RTK_GEOMETRY_CLOSEST_POINT_H
#define RTK_GEOMETRY_CLOSEST_POINT_H

typedef struct rtk_tri_closest {
    double p[3];  /* the nearest point */
    double d2;    /* its squared distance from the query point */
    double u, v;  /* p = (1 - u - v) a + u b + v c */
} rtk_tri_closest;

static inline double rtk_cp_dot(const double *x, const double *y) { return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]; }

static inline void rtk_cp_finish(rtk_tri_closest *r, const double *q, const double *a, const double *b,
                                 const double *c, double u, double v)
{
    const double w = 1.0 - u - v;
    double d2 = 0.0;
    for (int k = 0; k < 3; k++) {
        r->p[k] = w * a[k] + u * b[k] + v * c[k];
        /* a vertex exactly where it is (w, u or v is 1 there) */
        if (u == 0.0 && v == 0.0)
            r->p[k] = a[k];
        else if (u == 1.0)
            r->p[k] = b[k];
        else if (v == 1.0)
            r->p[k] = c[k];
        const double d = r->p[k] - q[k];
        d2 += d * d;
    }
    r->d2 = d2;
    r->u = u;
    r->v = v;
}

/* The nearest point of segment a-b to q as a parameter in [0, 1]. */
static inline double rtk_cp_segment(const double *q, const double *a, const double *b)
{
    const double ab[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    const double aq[3] = {q[0] - a[0], q[1] - a[1], q[2] - a[2]};
    const double len2 = rtk_cp_dot(ab, ab);
    if (!(len2 > 0.0))
        return 0.0;
    const double t = rtk_cp_dot(aq, ab) / len2;
    return t <= 0.0 ? 0.0 : t >= 1.0 ? 1.0 : t;
}

/* A triangle without area: the nearest of its three edges' points. */
static inline void rtk_cp_edges(rtk_tri_closest *r, const double *q, const double *a, const double *b,
                                const double *c)
{
    const double tab = rtk_cp_segment(q, a, b), tac = rtk_cp_segment(q, a, c), tbc = rtk_cp_segment(q, b, c);
    rtk_tri_closest e;
    rtk_cp_finish(r, q, a, b, c, tab, 0.0);
    rtk_cp_finish(&e, q, a, b, c, 0.0, tac);
    if (e.d2 < r->d2)
        *r = e;
    rtk_cp_finish(&e, q, a, b, c, 1.0 - tbc, tbc);
    if (e.d2 < r->d2)
        *r = e;
}

static inline void rtk_closest_point_regions(rtk_tri_closest *r, const double *q, const double *a, const double *b,
                                             const double *c)
{
    const double ab[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    const double ac[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    const double aq[3] = {q[0] - a[0], q[1] - a[1], q[2] - a[2]};
    const double d1 = rtk_cp_dot(ab, aq), d2 = rtk_cp_dot(ac, aq);
    if (d1 <= 0.0 && d2 <= 0.0) { /* vertex a */
        rtk_cp_finish(r, q, a, b, c, 0.0, 0.0);
        return;
    }
    const double bq[3] = {q[0] - b[0], q[1] - b[1], q[2] - b[2]};
    const double d3 = rtk_cp_dot(ab, bq), d4 = rtk_cp_dot(ac, bq);
    if (d3 >= 0.0 && d4 <= d3) { /* vertex b */
        rtk_cp_finish(r, q, a, b, c, 1.0, 0.0);
        return;
    }
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) { /* edge ab */
        const double den = d1 - d3;
        if (!(den > 0.0)) {
            rtk_cp_edges(r, q, a, b, c);
            return;
        }
        rtk_cp_finish(r, q, a, b, c, d1 / den, 0.0);
        return;
    }
    const double cq[3] = {q[0] - c[0], q[1] - c[1], q[2] - c[2]};
    const double d5 = rtk_cp_dot(ab, cq), d6 = rtk_cp_dot(ac, cq);
    if (d6 >= 0.0 && d5 <= d6) { /* vertex c */
        rtk_cp_finish(r, q, a, b, c, 0.0, 1.0);
        return;
    }
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) { /* edge ac */
        const double den = d2 - d6;
        if (!(den > 0.0)) {
            rtk_cp_edges(r, q, a, b, c);
            return;
        }
        rtk_cp_finish(r, q, a, b, c, 0.0, d2 / den);
        return;
    }
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0) { /* edge bc */
        const double den = (d4 - d3) + (d5 - d6);
        if (!(den > 0.0)) {
            rtk_cp_edges(r, q, a, b, c);
            return;
        }
        const double t = (d4 - d3) / den;
        rtk_cp_finish(r, q, a, b, c, 1.0 - t, t);
        return;
    }
    /* the face: q projected onto the plane */
    const double sum = va + vb + vc;
    if (!(sum > 0.0)) {
        rtk_cp_edges(r, q, a, b, c);
        return;
    }
    const double v = vb / sum, w = vc / sum;
    rtk_cp_finish(r, q, a, b, c, v, w);
}

/* The nearest point.  Ericson's regions come from differences of products
 * (va, vb, vc), which cancel on a sliver (a triangle whose edges from a
 * are nearly parallel): there the region can come out wrong, and the point,
 * though on the triangle, not the nearest (a 3e-8-wide sliver of a
 * sphere's pole gave 1.9e-5 where the nearest edge was 2.3e-8 away).  So
 * where the squared area |ab x ac|^2 = |ab|^2 |ac|^2 - (ab.ac)^2 is below
 * 2^-20 of the longest edge's fourth power the edges are measured too
 * (their segments have no such cancellation) and the nearer taken: the
 * face's interior can then be nearer than the edges only by the sliver's
 * width.  Every answer is a point of the triangle at the distance given. */
static inline void rtk_closest_point_triangle(rtk_tri_closest *r, const double *q, const double *a, const double *b,
                                              const double *c)
{
    rtk_closest_point_regions(r, q, a, b, c);
    const double ab[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    const double ac[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    const double bc[3] = {c[0] - b[0], c[1] - b[1], c[2] - b[2]};
    const double d00 = rtk_cp_dot(ab, ab), d11 = rtk_cp_dot(ac, ac), d01 = rtk_cp_dot(ab, ac), d22 = rtk_cp_dot(bc, bc);
    double m = d00 > d11 ? d00 : d11;
    m = m > d22 ? m : d22;
    if (d00 * d11 - d01 * d01 <= 0x1p-20 * (m * m)) {
        rtk_tri_closest e;
        rtk_cp_edges(&e, q, a, b, c);
        if (e.d2 < r->d2)
            *r = e;
    }
}

#endif
