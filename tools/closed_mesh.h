/*
 * Closed procedural meshes and rays aimed exactly at their vertices and
 * edges: what the accuracy harness (rtktool bench --only closed) and
 * tests/test_robust measure watertightness with.
 *
 * Each mesh approximates a solid (a sphere, a torus, a box whose faces are
 * grids, a cylinder whose sides and caps are needles), every vertex shared
 * by the triangles around it, and knows the solid in double precision, so
 * that a point can be told to lie outside or inside it by a margin.  A ray
 * from a point outside the solid to a point inside it crosses the closed
 * mesh an odd number of times, whatever the rounding: a ray that reaches
 * its inside point without a hit has leaked through the mesh, and one whose
 * crossings number even has hit one crossing twice.
 */
#ifndef RTK_TOOLS_CLOSED_MESH_H
#define RTK_TOOLS_CLOSED_MESH_H

#include <stdint.h>

#include "mesh_import.h"
#include "rtk/rtk.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef enum rtk_solid { RTK_SOLID_SPHERE, RTK_SOLID_TORUS, RTK_SOLID_BOX, RTK_SOLID_CYLINDER } rtk_solid;

typedef struct rtk_closed_mesh {
    const char *name;
    rtk_mesh mesh;
    float (*normal)[3]; /* per vertex: a direction pointing out of the solid */
    rtk_solid shape;
    double c[3], a, b; /* centre; radius (torus: major radius; box: half side), b: torus minor radius,
                        * cylinder half height */
    size_t closed_triangles; /* the closed surface: triangles [0, closed_triangles); any after have no area */
} rtk_closed_mesh;

/* Each returns 0, or non-zero when out of memory (the mesh then empty). */
/* A UV sphere of radius r around c: `rings` rings of `seg` vertices, and two poles. */
int rtk_closed_sphere(const double c[3], double r, int seg, int rings, rtk_closed_mesh *m);
/* A torus around c in the xy plane: major radius R, minor r, nu x nv vertices. */
int rtk_closed_torus(const double c[3], double R, double r, int nu, int nv, rtk_closed_mesh *m);
/* The box [c - h, c + h]^3, each face an n x n grid of squares split into two triangles (the diagonal
 * alternating, so vertices have 4 and 8 triangles); with c and h exact and n a power of two, every
 * vertex is exact. */
int rtk_closed_box(const double c[3], double h, int n, rtk_closed_mesh *m);
/* A cylinder of radius r and half height h about the z axis through c, of `seg` sides: each side
 * two triangles running the whole height, each cap a fan from its centre, so that with many sides
 * every triangle is a needle.  With `degenerate`, zero-area triangles follow the closed surface:
 * along every side line a triangle of its bottom, top and middle points (collinear: exactly, as the
 * three share x and y) and one repeating a vertex of each cap triangle. */
int rtk_closed_cylinder(const double c[3], double r, double h, int seg, int degenerate, rtk_closed_mesh *m);
void rtk_closed_free(rtk_closed_mesh *m);

/* How deep p lies inside the solid (negative outside), in double precision. */
double rtk_closed_depth(const rtk_closed_mesh *m, const float p[3]);

/* Rays aimed at a mesh: each from a point outside the solid by more than
 * `margin` through the aimed-at point toward one inside it by more than
 * `margin`; the direction of unit length, t_in the distance to the point
 * inside. */
typedef struct rtk_aimed {
    rtk_ray *rays;
    float *t_in;
    size_t count, cap;
} rtk_aimed;

/* Rays at every vertex of the closed surface and at a third of the way
 * along and the midpoint of every edge (each edge is seen from both of its
 * triangles): from a random direction on the outer side (distances `out`
 * and `in` from the point) and, at vertices and third points, along each
 * axis where that goes from outside to inside, the other components +0.0
 * or -0.0.  Returns 0, or non-zero when out of memory. */
int rtk_closed_aim(const rtk_closed_mesh *m, double margin, float out, float in, uint64_t seed, rtk_aimed *a);
/* Appends the ray from o toward i (if both are outside and inside by the
 * margin); zero_sign: zero direction components are -0.0.  Returns 0, or
 * non-zero when out of memory. */
int rtk_aimed_add(rtk_aimed *a, const float o[3], const float i[3], int zero_sign);
void rtk_aimed_free(rtk_aimed *a);

/* `count` rays grazing the top face (z = c + h) of a box made by
 * rtk_closed_box(c, h, n) at `deg` degrees: each aimed at a random point of
 * the face within 7/8 of its half side of the centre (on_lines: on a line
 * of its grid, every other one at a vertex), from a random azimuth, from
 * h/2 before the point to h/20 past it; those whose rounded ends are not
 * strictly outside and inside (margin 0: with c and h exact and n a power
 * of two the mesh is the solid) are left out.  Returns 0, or non-zero when
 * out of memory. */
int rtk_closed_graze(const rtk_closed_mesh *box, int n, double deg, size_t count, int on_lines, uint64_t seed,
                     rtk_aimed *a);

#ifdef __cplusplus
}
#endif
#endif
