/* Spheres as user geometry, for the tests of queries on user geometry
 * (test_user_points, test_user_crossings): the set, its bounds, its point
 * query function, and scenes of it. */
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
/* A user geometry of the spheres, committed (point query function fn). */
rtk_geometry spheres_geometry(rtk_device dev, sphere_set *s, rtk_point_query_fn fn);
/* A committed scene of the spheres alone. */
rtk_scene spheres_scene(rtk_device dev, sphere_set *sp, rtk_point_query_fn fn);

#endif
