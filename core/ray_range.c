/* Rays outside the window the kernels answer in (ray_check: an origin
 * beyond +-2^36, or a direction whose largest component is below 2^-8 or
 * above 2^16), traced with the answer they would get inside it.
 *
 * The kernels' float products stay in range for vertices and origins
 * within +-2^36 and such directions (geometry/triangle.h,
 * RTK_COORD_LIMIT).  Outside it a direction of (0, 0, -1e-38) made the
 * fast test's determinant underflow and every triangle missed, and an
 * origin 1e20 away overflowed the distances.  Here, in double:
 *  - an origin beyond the limit moves along the ray to just before where
 *    the ray enters the scene's bounds (grown by 2^-10 of their size, so
 *    that the move's rounding to float cannot carry it past a surface);
 *    a ray that misses the bounds, or meets them only outside
 *    [tnear, tfar], misses;
 *  - the direction is scaled by a power of two to a largest component in
 *    [1, 2), tnear and tfar by its inverse (exact, but where they
 *    overflow or underflow), so every distance the kernel computes is the
 *    unscaled one times an exact power of two;
 *  - the hit distance comes back scaled and moved back, clamped into the
 *    ray's [tnear, tfar].
 * The ray is changed in place while it is traced (filters and user
 * geometry see the moved, rescaled ray, at its own address) and restored
 * after: org, dir and tnear as given, tfar the hit distance (or -inf for
 * an occluded ray) or as given. */
#include <float.h>
#include <math.h>
#include <stddef.h>

#include "scene_internal.h"

typedef struct range_ray {
    float org[3], dir[3], tnear, tfar; /* as given */
    double shift, scale;               /* traced t' = (t - shift) * scale */
    float tfar_traced;                 /* tfar as handed to the kernel */
} range_ray;

/* Moves and rescales r (see above); 0 when it cannot hit anything. */
static int range_enter(rtk_scene s, rtk_ray *r, range_ray *k)
{
    memcpy(k->org, &r->org_x, sizeof k->org);
    memcpy(k->dir, &r->dir_x, sizeof k->dir);
    k->tnear = r->tnear;
    k->tfar = r->tfar;
    k->shift = 0.0;
    k->scale = 1.0;
    k->tfar_traced = r->tfar;
    /* a hit beyond FLT_MAX could not be reported: no further than that */
    double tnear = r->tnear, tfar = fmin(r->tfar, FLT_MAX);
    const float md = fmaxf(fmaxf(fabsf(k->dir[0]), fabsf(k->dir[1])), fabsf(k->dir[2]));
    if (md == 0.0f)
        return 1; /* no direction: the kernel's miss, as for any such ray */
    if (fmaxf(fmaxf(fabsf(k->org[0]), fabsf(k->org[1])), fabsf(k->org[2])) > RAY_ORG_MAX) {
        const float *lo = s->stats.lower, *hi = s->stats.upper;
        double size = 0.0, mag = 0.0;
        for (int a = 0; a < 3; a++) {
            size = fmax(size, (double)hi[a] - lo[a]);
            mag = fmax(mag, fmax(fabs(lo[a]), fabs(hi[a])));
        }
        const double pad = 0x1p-10 * (size + mag) + 0x1p-126;
        double t0 = 0.0, t1 = INFINITY;
        for (int a = 0; a < 3; a++) {
            const double o = k->org[a], d = k->dir[a], l = lo[a] - pad, h = hi[a] + pad;
            if (d == 0.0) {
                if (o < l || o > h)
                    return 0;
                continue;
            }
            double ta = (l - o) / d, tb = (h - o) / d;
            if (ta > tb) {
                const double x = ta;
                ta = tb;
                tb = x;
            }
            t0 = fmax(t0, ta);
            t1 = fmin(t1, tb);
        }
        if (!(t0 <= t1) || t1 < tnear || t0 > tfar)
            return 0;
        k->shift = t0;
        for (int a = 0; a < 3; a++)
            (&r->org_x)[a] = (float)(k->org[a] + t0 * k->dir[a]);
        tnear = fmax(tnear - t0, 0.0);
        tfar -= t0;
    }
    int e;
    /* md = m * 2^e, m in [0.5, 1): the direction times 2^(1 - e) has its
     * largest component in [1, 2), and its distances are times 2^(e - 1) */
    frexpf(md, &e);
    k->scale = ldexp(1.0, e - 1);
    for (int a = 0; a < 3; a++)
        (&r->dir_x)[a] = (float)ldexp(k->dir[a], 1 - e);
    r->tnear = (float)(tnear * k->scale);
    if (isinf(r->tnear))
        return 0; /* starts beyond every float distance */
    /* tfar rounded down, so no hit lies past the given one */
    const double tf = tfar * k->scale;
    float f = (float)tf;
    if ((double)f > tf)
        f = nextafterf(f, 0.0f);
    r->tfar = f < r->tnear ? r->tnear : f;
    k->tfar_traced = r->tfar;
    return 1;
}

/* org, dir and tnear as given; tfar from the hit (t' moved back), if any. */
static void range_leave(rtk_ray *r, const range_ray *k, int occluded)
{
    const float t = r->tfar;
    memcpy(&r->org_x, k->org, sizeof k->org);
    memcpy(&r->dir_x, k->dir, sizeof k->dir);
    r->tnear = k->tnear;
    if (occluded) {
        r->tfar = t == -INFINITY ? -INFINITY : k->tfar;
        return;
    }
    if (t == k->tfar_traced) {
        r->tfar = k->tfar; /* no hit (or one at tfar itself) */
        return;
    }
    const float back = (float)((double)t / k->scale + k->shift);
    r->tfar = back < k->tnear ? k->tnear : back > k->tfar ? k->tfar : back;
}

void range_intersect1(rtk_scene s, rtk_rayhit *rh, const rtk_query *q)
{
    range_ray k;
    if (range_enter(s, &rh->ray, &k))
        s->intersect1(s->accel, rh, q);
    else
        k.tfar_traced = rh->ray.tfar; /* untouched but for the move: as a miss */
    range_leave(&rh->ray, &k, 0);
}

void range_intersect1_map(rtk_scene s, rtk_rayhit *rh, const rtk_query *q, double *shift, double *scale)
{
    range_ray k;
    *shift = 0.0;
    *scale = 1.0;
    if (range_enter(s, &rh->ray, &k)) {
        *shift = k.shift;
        *scale = k.scale;
        s->intersect1(s->accel, rh, q);
    } else
        k.tfar_traced = rh->ray.tfar;
    range_leave(&rh->ray, &k, 0);
}

void range_occluded1(rtk_scene s, rtk_ray *ray, const rtk_query *q)
{
    range_ray k;
    if (range_enter(s, ray, &k))
        s->occluded1(s->accel, ray, q);
    range_leave(ray, &k, 1);
}

void range_trace1(rtk_scene s, void *ray, int occluded, const rtk_query *q)
{
    if (occluded)
        range_occluded1(s, ray, q);
    else
        range_intersect1(s, ray, q);
}
