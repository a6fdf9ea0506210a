/*
 * Affine maps as row-major 3x4 matrices [M | t] (x' = M x + t), in double
 * precision: shared by the core (an instance's world-to-object map, from
 * the application's transform) and the backends (closest points, which
 * take a point into an instance and its triangles back out).
 */
#ifndef RTK_GEOMETRY_AFFINE_H
#define RTK_GEOMETRY_AFFINE_H

#include <math.h>

/* inv = the inverse of m by cofactors over the determinant; 0 when m is
 * singular or its determinant not finite (inv then unwritten). */
static inline int rtk_affine_invert(const double *m, double *inv)
{
    const double a = m[0], b = m[1], c = m[2], d = m[4], e = m[5], f = m[6], g = m[8], h = m[9], i = m[10];
    const double A = e * i - f * h, B = f * g - d * i, C = d * h - e * g;
    const double det = a * A + b * B + c * C;
    if (!(fabs(det) > 0.0) || !isfinite(det))
        return 0;
    const double r[9] = {A / det, (c * h - b * i) / det, (b * f - c * e) / det,
                         B / det, (a * i - c * g) / det, (c * d - a * f) / det,
                         C / det, (b * g - a * h) / det, (a * e - b * d) / det};
    const double t[3] = {m[3], m[7], m[11]};
    for (int row = 0; row < 3; row++) {
        for (int col = 0; col < 3; col++)
            inv[4 * row + col] = r[3 * row + col];
        inv[4 * row + 3] = -(r[3 * row] * t[0] + r[3 * row + 1] * t[1] + r[3 * row + 2] * t[2]);
    }
    return 1;
}

/* x = m p (x may not alias p). */
static inline void rtk_affine_apply(const double *m, const double p[3], double x[3])
{
    for (int r = 0; r < 3; r++)
        x[r] = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
}

#endif
