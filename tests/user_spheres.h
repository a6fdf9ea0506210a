/* Spheres as user geometry, for the tests of queries on user geometry
 * (test_user_points, test_user_crossings): the set, its bounds, its ray
 * and point query callbacks, and scenes of it. */
#ifndef RTK_TEST_USER_SPHERES_H
#define RTK_TEST_USER_SPHERES_H

#include <stdint.h>

#include "rtk/rtk.h"

enum { SPHERES = 40 };

typedef struct sphere_set {
    double c[SPHERES][3];
    double r[SPHERES];
    unsigned long calls; /* of sphere_point */
} sphere_set;

/* SPHERES spheres with centres in [-2, 2]^3 and radii in [0.05, 0.3). */
void spheres_make(sphere_set *s, uint64_t seed);
/* The bounds callback: each sphere's box, rounded outward. */
void sphere_bounds(const rtk_bounds_args *a);
/* The point query function: the sphere's surface point nearest to p (from
 * its centre, any one), the outward normal there, u and v its direction's
 * first two components; counts its calls. */
int sphere_point(rtk_point_query_args *a);
/* Sphere prim's hits along the ray o + t d (any t), computed in double:
 * 2 into t (ascending), or 0 for none (a ray that only touches it too). */
int sphere_roots(const sphere_set *s, uint32_t prim, const float o[3], const float d[3], double t[2]);
/* The intersect and occluded callbacks: each lane's hits offered nearest
 * first (rtk_user_offer_hit), the first taken reported. */
void sphere_intersect(const rtk_user_query_args *a);
void sphere_occluded(const rtk_user_query_args *a);
/* A user geometry of the spheres with those callbacks, committed (point
 * query function fn). */
rtk_geometry spheres_geometry(rtk_device dev, sphere_set *s, rtk_point_query_fn fn);
/* A committed scene of the spheres alone. */
rtk_scene spheres_scene(rtk_device dev, sphere_set *sp, rtk_point_query_fn fn);

#endif
