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

static void sphere_rays(const rtk_user_query_args *a) { (void)a; }

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
    rtk_geometry g = test_user_geometry(dev, SPHERES, s, sphere_bounds, sphere_rays, sphere_rays);
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
