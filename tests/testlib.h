/* Helpers shared by rtk's tests: devices per backend, scenes from arrays, a
 * brute-force reference, and a small deterministic random generator. */
#ifndef RTK_TESTLIB_H
#define RTK_TESTLIB_H

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "geometry/triangle.h"
#include "rtk/rtk.h"

#define TEST_MAX_BACKENDS 16

/* Nonzero in the sanitizer runs (scripts/test sets RTK_TEST_SANITIZED):
 * there the tests, ten times slower, check fewer variations of the same
 * paths, so that CI stays within its time. */
int test_sanitized(void);

/* Names of the usable backends of this build, best last (by the CPU
 * features each needs).  In a sanitizer build, those it left uninstrumented
 * are left out (tests/CMakeLists.txt: the optimised run checks them; here
 * they would check the tests' own code again, not theirs). */
size_t test_backend_names(char names[][32], size_t max);
/* How many backends test_backend_names leaves out in this build (by name,
 * whether or not this CPU runs them). */
size_t test_backends_left_out(void);
/* A device on exactly this backend (fails the test otherwise). */
rtk_device test_device(const char *isa);
/* A device on this backend with threads= set. */
rtk_device test_device_threads(const char *isa, int threads);
/* One committed triangle-mesh scene over the arrays (shared, not copied). */
rtk_scene test_scene(rtk_device dev, const float *v, size_t nv, const uint32_t *idx, size_t nt);
/* The same with scene flags (RTK_SCENE_FLAG_COMPACT: the index-leaf layout). */
rtk_scene test_scene_flags(rtk_device dev, const float *v, size_t nv, const uint32_t *idx, size_t nt, unsigned flags);
/* The same scene, not committed yet. */
rtk_scene test_scene_uncommitted(rtk_device dev, const float *v, size_t nv, const uint32_t *idx, size_t nt,
                                 unsigned flags);

/* A scene, not committed yet, of one instance of `inner` (identity). */
rtk_scene test_instancing_scene(rtk_device dev, rtk_scene inner);
/* An instance of `inner` through xfm (row-major 3x4; NULL: identity),
 * committed and attached to `outer` (not committed); its geometry id. */
uint32_t test_attach_instance(rtk_device dev, rtk_scene outer, rtk_scene inner, const float *xfm);
/* Geometry g of s has new vertex positions in its buffer: update it, commit
 * it and the scene. */
void test_commit_moved(rtk_scene s, rtk_geometry g);

/* A committed scene of one user primitive (the box [0, 1]^3) whose
 * callbacks report nothing: for the queries that refuse user geometry. */
rtk_scene test_user_scene(rtk_device dev);
/* A user geometry of `count` primitives with this user data and these
 * callbacks, not yet committed. */
rtk_geometry test_user_geometry(rtk_device dev, uint32_t count, void *user, rtk_bounds_fn bounds,
                                rtk_user_query_fn intersect, rtk_user_query_fn occluded);
/* A committed scene of one user geometry of `count` primitives with these
 * callbacks (the scene holds the geometry). */
rtk_scene test_user_geometry_scene(rtk_device dev, uint32_t count, rtk_bounds_fn bounds, rtk_user_query_fn intersect,
                                   rtk_user_query_fn occluded);

/* Two exported trees are the same, array for array (fails the test otherwise). */
void test_assert_same_tree(const rtk_bvh *a, const rtk_bvh *b);

/* The reference's view of a mesh: v0, e1, e2 per triangle, computed the way
 * the builders compute them, and whether the builders keep it. */
typedef struct ref_mesh {
    float (*tri)[9];
    unsigned char *keep; /* 0: non-finite or zero area, never hit */
    size_t count;
    float (*vtx)[9];     /* v0, v1, v2 as given */
    int watertight;      /* 1: the robust layouts' intersector (set by the caller) */
    struct ref_memo *memo; /* ref_closest's answers so far, by ray and intersector */
} ref_mesh;
ref_mesh ref_prepare(const float *v, const uint32_t *idx, size_t nt);
void ref_free(ref_mesh *m);

/* Brute force over every triangle, with the builders' rules and the same
 * intersector. Returns 1 on a hit with the closest t and its primitive.
 * Remembered per ray (its origin, direction, tnear and tfar, to the bit)
 * and intersector: the tests trace the same rays through many scenes of
 * one mesh (every backend, quality and layout), and brute force over a
 * large mesh was most of their time.  The mesh must not change after
 * ref_prepare. */
int ref_closest(const ref_mesh *m, const rtk_ray *ray, rtk_tri_hit *hit, uint32_t *prim);
/* The hit of one triangle alone (for tie checks). */
int ref_one(const ref_mesh *m, uint32_t prim, const rtk_ray *ray, rtk_tri_hit *hit);

/* intersect1 and occluded1 of one ray against brute force over ref (the
 * scene's triangles): the same hit or miss, the same t, and the same
 * triangle unless another gives the same t; returns 1 on a hit. */
int test_ray_vs_reference(rtk_scene s, const ref_mesh *ref, rtk_ray ray);

rtk_ray test_ray(float ox, float oy, float oz, float dx, float dy, float dz, float tnear, float tfar);

/* `count` random rays from around the scene's box towards its middle,
 * test_ray_vs_reference against brute force over the triangles now in v
 * (idx, nt); returns the hits. */
int test_rays_vs_brute_force(rtk_scene s, const float *v, const uint32_t *idx, size_t nt, int count, uint64_t seed);

/* A sphere, the tests' user geometry: the nearest root of |o + t d - c| = r
 * in [tnear, tfar], computed in double and rounded to float; 0 when none.
 * The callbacks and the references share it, so they agree to the bit. */
int test_sphere_hit(const float c[3], float r, const float o[3], const float d[3], float tnear, float tfar,
                    float *t_out);
/* Field f of lane i of the rays a user-geometry callback gets (rtk.h: N
 * lanes of rtk_rayhitN / rtk_rayN, or the rtk_rayhit / rtk_ray for N = 1).
 * Fields: org 0-2, tnear 3, dir 4-6, time 7, tfar 8, ..., Ng 12-14, u 15, v 16. */
#define TEST_LANE(rays, n, f, i) (((float *)(rays))[(size_t)(f) * (n) + (i)])

/* Packets of `width` rays (rtk.h's layout: field f of lane j is 4-byte word
 * f * width + j; an occluded packet has only the 12 ray fields).  One lane
 * in or out as an rtk_rayhit, and the call of that width. */
void test_packet_put(void *packet, unsigned width, unsigned lane, const rtk_rayhit *rh, int occluded);
void test_packet_get(const void *packet, unsigned width, unsigned lane, rtk_rayhit *rh, int occluded);
rtk_error test_trace_packet(rtk_scene scene, unsigned width, int occluded, const int *valid, void *packet);
/* The closest hits of in[0 .. 8) as one packet of 8 (every lane active), in out. */
void test_intersect8_rows(rtk_scene scene, const rtk_rayhit in[8], rtk_rayhit out[8]);

/* The .ply files of the shared mesh directory (only == NULL or "": all;
 * else just that file name), full paths sorted by name, malloc'd: the
 * caller frees each.  Fails the test when the directory cannot be read.
 * Under the sanitizers "all" leaves out the files over 5 MB (motorbike,
 * dragon, San Miguel: their builds took 3/4 of the sanitized conformance
 * run) and says so. */
size_t test_mesh_files(char *files[], size_t max, const char *only);

struct rtk_mesh;
/* Loads a mesh of the shared directory by file name (for a group setup:
 * 0, or -1 when it cannot be read). */
int test_load_shared_mesh(const char *name, struct rtk_mesh *mesh);

/* A small procedural mesh: a bumpy sphere of radius about 1 around the
 * origin, with (r + 1)^2 vertices and 2 r^2 triangles (malloc'd). */
typedef struct test_mesh {
    float *v;
    uint32_t *idx;
    size_t nv, nt;
} test_mesh;
test_mesh test_ball(int r);

/* A reference in double precision for scenes whose triangles are placed
 * (instances) or moved (motion blur): each triangle as the ray sees it. */
typedef struct placed {
    double v[3][3];  /* where the ray meets it */
    double n_obj[3]; /* the normal rtk reports (unnormalised): in the innermost object space */
    uint32_t inst, geom, prim;
} placed;
typedef struct placed_ref {
    placed *t;
    size_t n, cap;
} placed_ref;
/* A new triangle at the end (grown as needed). */
placed *placed_add(placed_ref *r);
/* n_obj from the triangle's vertices in object space. */
void placed_normal(placed *p, const double o[3][3]);
/* intersect1 and occluded1 of one ray (number i, for messages) against the
 * reference, failing the test on a disagreement that rounding cannot
 * explain: a hit or miss or a triangle that differs where the reference's
 * hit is within `tol` (barycentric) of an edge, or two triangles' distances
 * tie within tol, is counted in *excused; hits in *hits.  t must agree to
 * tol (relative) and Ng point along n_obj. */
void check_ray_placed(rtk_scene s, const placed_ref *r, rtk_ray ray, int i, double tol, int *hits, int *excused);

typedef struct rng {
    uint64_t s;
} rng;
uint32_t rng_u32(rng *r);
float rng_float(rng *r); /* [0, 1) */

/* nt separate triangles in the cube offset + scale * [0, 1]^3 where spatial
 * splits pay: long thin sticks between random points (two ends far apart,
 * the third near the first), after four large ones, two of them in the
 * planes z = 1/2 and x = 1/2 (where split planes fall) and one diagonal.
 * malloc'd arrays of 3 * nt vertices and nt triangles. */
void test_sticks_mesh(rng *r, size_t nt, float scale, float offset, float **v, uint32_t **idx);

/* nt separate triangles facing every way: each a random centre in the unit
 * cube with its three vertices within size / 2 of it on every axis.
 * malloc'd arrays of 3 * nt vertices and nt triangles. */
void test_soup_mesh(rng *r, size_t nt, float size, float **v, uint32_t **idx);
/* A ray from a random point of the plane z = -0.5 (x, y in [-0.2, 1.2))
 * through a random point of [0, 1) x [0, 1) x [0, 1.4), over [0, inf):
 * through test_soup_mesh's cube from below. */
rtk_ray test_ray_through_cube(rng *r);

#endif
