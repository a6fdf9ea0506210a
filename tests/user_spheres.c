/* Spheres as user geometry (user_spheres.h). */
#include "user_spheres.h"

#include <math.h>
#include <string.h>

#include "testlib.h"

void sphere_bounds(const rtk_bounds_args *a)
{
    const sphere_set *s = a->geometry_user;
    for (int k = 0; k < 3; k++) {
        a->lower[k] = nextafterf((float)(s->c[a->prim_id][k] - s->r[a->prim_id]), -INFINITY);
        a->upper[k] = nextafterf((float)(s->c[a->prim_id][k] + s->r[a->prim_id]), INFINITY);
    }
}

int sphere_roots(const sphere_set *s, uint32_t prim, const float o[3], const float d[3], double t[2])
{
    const double *c = s->c[prim];
    const double oc[3] = {o[0] - c[0], o[1] - c[1], o[2] - c[2]};
    const double a = (double)d[0] * d[0] + (double)d[1] * d[1] + (double)d[2] * d[2];
    const double b = oc[0] * d[0] + oc[1] * d[1] + oc[2] * d[2];
    const double cc = oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2] - s->r[prim] * s->r[prim];
    const double disc = b * b - a * cc;
    if (!(disc > 0.0) || !(a > 0.0))
        return 0;
    const double sq = sqrt(disc);
    t[0] = (-b - sq) / a;
    t[1] = (-b + sq) / a;
    return 2;
}

/* Word f of lane i of an N-packet of rays (N = 1: rtk_rayhit, rtk_ray). */
static float *lane_word(void *rays, uint32_t n, int f, uint32_t i) { return (float *)rays + (size_t)f * n + i; }

/* The sphere's hits for each lane the callback is to test, offered nearest
 * first; the first the query takes is reported (occluded: tfar = -inf). */
static void sphere_hits(const rtk_user_query_args *a, int occluded)
{
    const sphere_set *s = a->geometry_user;
    for (uint32_t i = 0; i < a->N; i++) {
        if (!a->valid[i])
            continue;
        float o[3], d[3];
        for (int k = 0; k < 3; k++) {
            o[k] = *lane_word(a->rays, a->N, k, i);
            d[k] = *lane_word(a->rays, a->N, 4 + k, i);
        }
        double t[2];
        const int n = sphere_roots(s, a->prim_id, o, d, t);
        for (int j = 0; j < n; j++) {
            const float tf = (float)t[j];
            if (!(tf >= *lane_word(a->rays, a->N, 3, i) && tf <= *lane_word(a->rays, a->N, 8, i)))
                continue;
            rtk_user_hit h = {.t = tf};
            for (int k = 0; k < 3; k++)
                (&h.Ng_x)[k] = (float)(o[k] + t[j] * d[k] - s->c[a->prim_id][k]);
            h.u = h.Ng_x / (float)s->r[a->prim_id];
            h.v = h.Ng_y / (float)s->r[a->prim_id];
            if (!rtk_user_offer_hit(a, i, &h))
                continue;
            *lane_word(a->rays, a->N, 8, i) = occluded ? -INFINITY : tf;
            if (!occluded) {
                for (int k = 0; k < 3; k++)
                    *lane_word(a->rays, a->N, 12 + k, i) = (&h.Ng_x)[k];
                *lane_word(a->rays, a->N, 15, i) = h.u;
                *lane_word(a->rays, a->N, 16, i) = h.v;
            }
            break;
        }
    }
}

void sphere_intersect(const rtk_user_query_args *a) { sphere_hits(a, 0); }
void sphere_occluded(const rtk_user_query_args *a) { sphere_hits(a, 1); }

int sphere_point(rtk_point_query_args *a)
{
    sphere_set *s = a->geometry_user;
    __atomic_add_fetch(&s->calls, 1, __ATOMIC_RELAXED);
    assert_int_equal(a->reserved, 0);
    const double *c = s->c[a->prim_id];
    double d[3] = {a->p[0] - c[0], a->p[1] - c[1], a->p[2] - c[2]};
    double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (len == 0.0)
        d[0] = d[1] = 0.0, d[2] = len = 1.0;
    if (fabs(len - s->r[a->prim_id]) > a->radius)
        return 0;
    for (int k = 0; k < 3; k++) {
        a->closest[k] = c[k] + d[k] / len * s->r[a->prim_id];
        a->normal[k] = (float)(d[k] / len);
    }
    a->u = (float)(d[0] / len);
    a->v = (float)(d[1] / len);
    return 1;
}

void spheres_make(sphere_set *s, uint64_t seed)
{
    rng r = {seed};
    memset(s, 0, sizeof *s);
    for (int i = 0; i < SPHERES; i++) {
        for (int k = 0; k < 3; k++)
            s->c[i][k] = 4.0 * rng_float(&r) - 2.0;
        s->r[i] = 0.05 + 0.25 * rng_float(&r);
    }
}

rtk_geometry spheres_geometry(rtk_device dev, sphere_set *s, rtk_point_query_fn fn)
{
    rtk_geometry g = test_user_geometry(dev, SPHERES, s, sphere_bounds, sphere_intersect, sphere_occluded);
    assert_int_equal(rtk_geometry_set_point_query_function(g, fn), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    return g;
}

rtk_scene spheres_scene(rtk_device dev, sphere_set *sp, rtk_point_query_fn fn)
{
    rtk_scene s;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    rtk_geometry g = spheres_geometry(dev, sp, fn);
    assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
    rtk_geometry_release(g);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    return s;
}
