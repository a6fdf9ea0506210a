/*
 * Robust mode (RTK_SCENE_FLAG_ROBUST): the watertight intersector and padded
 * box tests, on every backend, robust layout and build quality.
 *
 * Closed meshes (a UV sphere, a torus and a cube whose faces are grids of
 * triangles, every vertex shared) and rays aimed exactly at every vertex and
 * at points on every edge (a third of the way and the midpoint), from random
 * directions on the outer side and along the axes (the other components +0.0
 * or -0.0), each from a point outside the solid toward a point inside it.
 * Each must hit the mesh before the point inside, in intersect1, occluded1
 * and packets of 8: a ray that does not has leaked through the mesh.  And
 * with a filter collecting every triangle hit before the point inside,
 * each must cross the mesh an odd number of times: an even number (a ray
 * through an edge or vertex hitting two triangles of one crossing) is a
 * double hit.  Robust scenes must have no leak and no double hit at all;
 * the default intersector's leaks and double hits on the same rays are
 * printed beside and held under bounds (it has no guarantee, but it must
 * not lose the consistency its test has: DEFAULT_*).
 *
 * - watertight_far_from_origin: the meshes of size 1 moved to 10^k,
 *   k = 0 ... 6.
 * - watertight_tiny_and_huge: meshes of size 1e-10 (near the smallest
 *   triangles rtk's range holds, rtk.h; smaller ones, down to 1e-20 where
 *   the edge functions underflow in float and once went to the double
 *   fallback, are now left out and counted: test_range.c), 1e-8 and 1e8.
 *
 * - robust_two_levels_and_motion: a robust dynamic scene, and a robust
 *   scene with a moving cube (rays aimed at it at three times).
 *
 * The robust layouts' hits against a brute-force reference running the
 * same watertight test are in test_build (chosen_builder_and_layout).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "closed_mesh.h"
#include "geometry/triangle.h"
#include "testlib.h"

typedef rtk_closed_mesh closed_mesh;
typedef rtk_aimed aimed;

/* The closed meshes (tools/closed_mesh.h), checked closed by OpenMesh. */
static closed_mesh make_sphere(const double c[3], double r, int seg, int rings)
{
    closed_mesh m;
    assert_int_equal(rtk_closed_sphere(c, r, seg, rings, &m), 0);
    assert_int_equal(rtk_mesh_is_closed(&m.mesh, m.closed_triangles, NULL, NULL), 1);
    return m;
}
static closed_mesh make_torus(const double c[3], double R, double r, int nu, int nv)
{
    closed_mesh m;
    assert_int_equal(rtk_closed_torus(c, R, r, nu, nv, &m), 0);
    assert_int_equal(rtk_mesh_is_closed(&m.mesh, m.closed_triangles, NULL, NULL), 1);
    return m;
}
static closed_mesh make_cube(const double c[3], double h, int n)
{
    closed_mesh m;
    assert_int_equal(rtk_closed_box(c, h, n, &m), 0);
    assert_int_equal(rtk_mesh_is_closed(&m.mesh, m.closed_triangles, NULL, NULL), 1);
    return m;
}

static aimed aim_at_mesh(const closed_mesh *m, double margin, float out, float in, uint64_t seed)
{
    aimed a;
    assert_int_equal(rtk_closed_aim(m, margin, out, in, seed, &a), 0);
    return a;
}

static void print_ray(const rtk_ray *r)
{
    print_message("    ray org (%.9g, %.9g, %.9g) dir (%.9g, %.9g, %.9g)\n", r->org_x, r->org_y, r->org_z, r->dir_x,
                  r->dir_y, r->dir_z);
}

/* The watertight test's axis permutation of a ray (0 ... 5), as the
 * kernels pick it. */
static int axes_key(const rtk_ray *r)
{
    const float d[3] = {r->dir_x, r->dir_y, r->dir_z};
    rtk_watertight_ray w;
    rtk_watertight_ray_init(d, &w);
    return 2 * w.kz + (w.kx > w.ky);
}

static const aimed *sort_aimed;
static int by_axes(const void *x, const void *y)
{
    const size_t i = *(const size_t *)x, j = *(const size_t *)y;
    const int ki = axes_key(&sort_aimed->rays[i]), kj = axes_key(&sort_aimed->rays[j]);
    return ki != kj ? ki - kj : (i > j) - (i < j);
}

/* Leaks of the aimed rays through one scene: no hit before the point
 * inside; checked through intersect1, occluded1 (tfar at that point), and
 * packets of 8 (with packets = 2 also packets of rays grouped by their
 * axis permutation, as coherent packets are, besides the mixed ones). */
static size_t leaks(rtk_scene s, const aimed *a, size_t *first, int packets)
{
    size_t n = 0;
    *first = SIZE_MAX;
    for (size_t i = 0; i < a->count; i++) {
        rtk_rayhit rh = {.ray = a->rays[i]};
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
        rtk_ray sh = a->rays[i];
        sh.tfar = a->t_in[i];
        assert_int_equal(rtk_occluded1(s, &sh), RTK_OK);
        const int leak =
            rh.hit.geomID == RTK_INVALID_GEOMETRY_ID || rh.ray.tfar > a->t_in[i] || sh.tfar != -INFINITY;
        if (leak && *first == SIZE_MAX) {
            *first = i;
        }
        n += (size_t)leak;
    }
    /* packets of 8: the same distances as single rays (robust scenes only:
     * the default packet kernels may round t differently for rays through
     * edges), every ray with packets = 2, a sample with 1 */
    size_t *order = malloc((2 * a->count + 1) * sizeof *order);
    assert_non_null(order);
    for (size_t i = 0; i < a->count; i++)
        order[i] = order[a->count + i] = i;
    sort_aimed = a;
    qsort(order + a->count, a->count, sizeof *order, by_axes);
    const size_t total = packets == 2 ? 2 * a->count : a->count;
    for (size_t base = 0; packets && base + 8 <= total; base += packets == 2 ? 8 : 8 * 37) {
        rtk_rayhit8 p8;
        for (unsigned l = 0; l < 8; l++) {
            rtk_rayhit rh = {.ray = a->rays[order[base + l]]};
            rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
            test_packet_put(&p8, 8, l, &rh, 0);
        }
        assert_int_equal(test_trace_packet(s, 8, 0, NULL, &p8), RTK_OK);
        for (unsigned l = 0; l < 8; l++) {
            rtk_rayhit one = {.ray = a->rays[order[base + l]]}, got;
            one.hit.geomID = RTK_INVALID_GEOMETRY_ID;
            assert_int_equal(rtk_intersect1(s, &one), RTK_OK);
            test_packet_get(&p8, 8, l, &got, 0);
            assert_int_equal(got.hit.geomID, one.hit.geomID);
            /* the same distance; the triangle may differ where two tie
             * (the packet kernels of the default layouts visit in another
             * order) */
            assert_true(got.ray.tfar == one.ray.tfar);
        }
    }
    free(order);
    return n;
}

/* Every triangle a ray crosses before the point inside, collected by a
 * filter that rejects each (the distinct primitives: a spatial split
 * may show one twice). */
typedef struct crossing_log {
    uint32_t prim[64];
    unsigned n;
    float t_in;
    uint32_t closed; /* triangles from here on have no area */
    unsigned flat;   /* candidates among those: must stay 0 */
} crossing_log;

static int collect_crossing(const rtk_filter_args *f)
{
    crossing_log *log = f->context->user;
    log->flat += f->hit->primID >= log->closed;
    if (f->t > log->t_in || f->hit->primID >= log->closed)
        return 0;
    for (unsigned k = 0; k < log->n; k++)
        if (log->prim[k] == f->hit->primID)
            return 0;
    if (log->n < 64)
        log->prim[log->n++] = f->hit->primID;
    return 0;
}

/* The aimed rays' crossings of the closed mesh before the point inside,
 * through a scene whose geometry has the collect_crossing filter: the ray
 * goes from outside to inside, so it crosses an odd number of times.
 * Returns the rays that cross an even number of times, more than none (a
 * ray through an edge or vertex hitting two triangles of one crossing: a
 * double hit); *missed: those that cross none (a leak). */
static size_t double_hits(rtk_scene s, const aimed *a, uint32_t closed, size_t *missed, size_t *first)
{
    size_t n = 0;
    *missed = 0;
    *first = SIZE_MAX;
    for (size_t i = 0; i < a->count; i++) {
        crossing_log log = {.t_in = a->t_in[i], .closed = closed};
        const rtk_query_context ctx = {&log};
        rtk_rayhit rh = {.ray = a->rays[i]};
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1_ctx(s, &rh, &ctx), RTK_OK);
        assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID); /* every candidate rejected */
        assert_int_equal(log.flat, 0);                            /* zero-area triangles never hit */
        if (log.n % 2 == 0 && *first == SIZE_MAX)
            *first = i;
        *missed += log.n == 0;
        n += log.n && log.n % 2 == 0;
    }
    return n;
}

static rtk_scene filtered_scene(rtk_device dev, const closed_mesh *m, unsigned flags, rtk_build_quality q)
{
    rtk_scene s = test_scene_uncommitted(dev, m->mesh.vertices, m->mesh.vertex_count, m->mesh.indices, m->mesh.triangle_count, flags);
    rtk_geometry g = rtk_scene_get_geometry(s, 0);
    assert_int_equal(rtk_geometry_set_intersect_filter(g, collect_crossing), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_set_build_quality(s, q), RTK_OK);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    return s;
}

/* Bounds on the default mode, per million rays, every backend's together.
 * It has no guarantee at shared edges, but a change that loses the
 * consistency its test has had since it took Embree's form (91ca0d2)
 * fails here.  Measured then, in brackets the usual form before it:
 * leaks 3,459 (6,396) far from the origin, 59,614 (79,596) on the
 * needles, 1,143 (12,839) grazing; double hits 157,727 (163,999),
 * 303,576 (313,384), 254,839 (233,768).  Since the backends without FMA
 * stopped skipping boxes that an axis ray runs along a face of (their far
 * planes' reciprocals +-inf, ray_pre_init), they count what avx2 counted
 * all along, ray for ray: far from the origin 2,910 leaks and 248,480
 * double hits (were 3,320 and 157,882 with their misses), on the needles
 * 338,527 double hits (were 303,576); avx2's own were above the old bound
 * of 200,000, hidden in the sum by the others' lost rays. */
#define DEFAULT_FAR_LEAKS 5000.0
#define DEFAULT_FAR_TWICE 260000.0
#define DEFAULT_NEEDLE_LEAKS 70000.0
#define DEFAULT_NEEDLE_TWICE 360000.0
#define DEFAULT_GRAZING_LEAKS 5000.0
#define DEFAULT_GRAZING_TWICE 300000.0

/* The default layouts' rays, leaks and double hits, every backend's added
 * (check_mesh): the tests that bound them reset them first. */
static size_t default_rays, default_leaks, default_twice;

static void default_counts_reset(void)
{
    default_rays = default_leaks = default_twice = 0;
}

/* The default mode's leaks and double hits per million rays, printed, and
 * checked against bounds (per million, every backend's rays together). */
static void default_counts_check(const char *what, double max_leaks, double max_twice)
{
    const double per = default_rays ? 1e6 / (double)default_rays : 0.0;
    print_message("default mode, %s: %zu rays, %.0f leaks and %.0f double hits per million (at most %.0f and %.0f)\n",
                  what, default_rays, (double)default_leaks * per, (double)default_twice * per, max_leaks, max_twice);
    assert_true(default_rays > 0);
    assert_true((double)default_leaks * per <= max_leaks);
    assert_true((double)default_twice * per <= max_twice);
}

/* The aimed rays through one closed mesh, on every backend and robust
 * layout at every build quality (robust leaks and double hits added to
 * *rays and *leaked), and through the default layouts (their leaks and
 * double hits printed).  Zero-area triangles after the closed surface must
 * never be hit, in either mode. */
static void check_mesh(const closed_mesh *m, const aimed *a, const char *where, size_t *rays, size_t *leaked)
{
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    static const rtk_build_quality qualities[] = {RTK_BUILD_QUALITY_LOW, RTK_BUILD_QUALITY_MEDIUM,
                                                  RTK_BUILD_QUALITY_HIGH};
    const size_t flat = m->mesh.triangle_count - m->closed_triangles;
    char defaults[256] = "";
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (int q = 0; q < 3; q++)
            for (int compact = 0; compact < 2; compact++) {
                /* (under the sanitizers medium quality only: the builders'
                 * memory is checked by test_build there) */
                if (test_sanitized() && qualities[q] != RTK_BUILD_QUALITY_MEDIUM)
                    continue;
                rtk_scene s = test_scene_uncommitted(dev, m->mesh.vertices, m->mesh.vertex_count, m->mesh.indices,
                                                     m->mesh.triangle_count,
                                                     RTK_SCENE_FLAG_ROBUST | (compact ? RTK_SCENE_FLAG_COMPACT : 0));
                assert_int_equal(rtk_scene_set_build_quality(s, qualities[q]), RTK_OK);
                assert_int_equal(rtk_scene_commit(s), RTK_OK);
                rtk_scene_info info = {.struct_size = sizeof info};
                assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
                assert_int_equal(info.flags_not_honoured, 0);
                assert_int_equal(info.triangles, m->closed_triangles);
                assert_int_equal(info.triangles_degenerate, flat);
                size_t first;
                const size_t n = leaks(s, a, &first, 2);
                *rays += a->count;
                *leaked += n;
                if (n) {
                    print_message("%s %s, %s, %s, quality %d: %zu of %zu rays leak\n", m->name, where, names[b],
                                  info.layout, (int)qualities[q], n, a->count);
                    print_ray(&a->rays[first]);
                }
                rtk_scene_release(s);
                /* the same with every crossing collected */
                s = filtered_scene(dev, m, RTK_SCENE_FLAG_ROBUST | (compact ? RTK_SCENE_FLAG_COMPACT : 0),
                                   qualities[q]);
                size_t missed;
                const size_t twice = double_hits(s, a, (uint32_t)m->closed_triangles, &missed, &first);
                *leaked += twice + missed;
                if (twice + missed) {
                    print_message("%s %s, %s, %s, quality %d: %zu of %zu rays hit twice, %zu none (all "
                                  "crossings collected)\n",
                                  m->name, where, names[b], info.layout, (int)qualities[q], twice, a->count, missed);
                    print_ray(&a->rays[first]);
                }
                rtk_scene_release(s);
            }
        rtk_scene s = test_scene(dev, m->mesh.vertices, m->mesh.vertex_count, m->mesh.indices,
                                 m->mesh.triangle_count);
        size_t first, missed;
        const size_t n = leaks(s, a, &first, 0);
        rtk_scene_release(s);
        s = filtered_scene(dev, m, 0, RTK_BUILD_QUALITY_MEDIUM);
        const size_t twice = double_hits(s, a, (uint32_t)m->closed_triangles, &missed, &first);
        snprintf(defaults + strlen(defaults), sizeof defaults - strlen(defaults), " %s %zu/%zu", names[b], n, twice);
        default_rays += a->count;
        default_leaks += n;
        default_twice += twice;
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
    print_message("%-8s %s: %zu rays; the default mode leaks / hits twice:%s\n", m->name, where, a->count, defaults);
}

/* The three closed meshes of size `size` around c. */
static void closed_meshes_at(const double c[3], double size, const char *where, uint64_t seed, size_t *rays,
                             size_t *leaked)
{
    closed_mesh meshes[3] = {make_sphere(c, size, 24, 11), make_torus(c, size, 0.4 * size, 24, 12),
                             make_cube(c, size, 6)};
    const double mag = fmax(fabs(c[0]), fmax(fabs(c[1]), fabs(c[2]))) + 2.0 * size;
    for (int mi = 0; mi < 3; mi++) {
        const closed_mesh *m = &meshes[mi];
        /* the mesh lies within its faceting and the rounding of its
         * vertices of the solid's surface */
        const double margin = 0.04 * size + mag * 0x1p-23;
        const float out = (float)((mi == 1 ? 0.3 : 1.5) * size), in = (float)((mi == 1 ? 0.25 : 0.5) * size);
        aimed a = aim_at_mesh(m, margin, out, in, seed + (uint64_t)mi);
        assert_true(a.count > 1000);
        check_mesh(m, &a, where, rays, leaked);
        rtk_aimed_free(&a);
    }
    for (int mi = 0; mi < 3; mi++)
        rtk_closed_free(&meshes[mi]);
}

/* Meshes of size 1 moved to 10^k, k = 0 ... 8; from 10^7 on of size
 * 10^(k-6), so that rounding keeps their vertices 2^-4 of the size or
 * better apart (at 10^8 a float's step is 8). */
static void watertight_far_from_origin(void **state)
{
    (void)state;
    size_t rays = 0, leaked = 0;
    default_counts_reset();
    /* (under the sanitizers 1, 1e4 and 1e8 only: the same code paths) */
    const int step = test_sanitized() ? 4 : 1;
    for (int k = 0; k <= 8; k += step) {
        const double off = pow(10.0, k);
        const double c[3] = {off, 0.5 * off, -0.25 * off};
        char where[32];
        snprintf(where, sizeof where, "at 1e%d", k);
        closed_meshes_at(c, fmax(1.0, off * 1e-6), where, 17u + 3u * (uint64_t)k, &rays, &leaked);
    }
    print_message("robust: %zu leaks or double hits in %zu rays\n", leaked, rays);
    assert_int_equal(leaked, 0);
    if (!test_sanitized()) /* (there 1, 1e4 and 1e8 only: another mix, most leaks being at 1) */
        default_counts_check("closed meshes at 1e0 ... 1e8", DEFAULT_FAR_LEAKS, DEFAULT_FAR_TWICE);
}

/* Meshes of size 1e-10 (triangles near the smallest in rtk's range), 1e-8
 * and 1e8, near the origin. */
static void watertight_tiny_and_huge(void **state)
{
    (void)state;
    size_t rays = 0, leaked = 0;
    static const double sizes[] = {1e-10, 1e-8, 1e8};
    for (int k = 0; k < 3; k++) {
        const double c[3] = {0.3 * sizes[k], -0.2 * sizes[k], 0.1 * sizes[k]};
        char where[32];
        snprintf(where, sizeof where, "of size %g", sizes[k]);
        closed_meshes_at(c, sizes[k], where, 99u + 3u * (uint64_t)k, &rays, &leaked);
    }
    print_message("robust: %zu leaks or double hits in %zu rays\n", leaked, rays);
    assert_int_equal(leaked, 0);
}

/* A cylinder whose sides and caps are needles (1024 sides: side triangles
 * 20 x 0.006, cap triangles 1 x 0.006), with zero-area triangles along its
 * side lines (three collinear points) and on its caps (a repeated vertex),
 * which the rays aimed at the side lines pass exactly through. */
static void needles_and_zero_area(void **state)
{
    (void)state;
    const double c[3] = {0.25, -0.5, 0.125};
    closed_mesh m;
    assert_int_equal(rtk_closed_cylinder(c, 1.0, 10.0, 1024, 1, &m), 0);
    assert_int_equal(rtk_mesh_is_closed(&m.mesh, m.closed_triangles, NULL, NULL), 1);
    assert_int_equal(m.mesh.triangle_count, m.closed_triangles + 2048);
    aimed a = aim_at_mesh(&m, 1e-5, 1.5f, 0.5f, 4242);
    assert_true(a.count > 10000);
    size_t rays = 0, leaked = 0;
    default_counts_reset();
    check_mesh(&m, &a, "of needles", &rays, &leaked);
    print_message("robust: %zu leaks or double hits in %zu rays\n", leaked, rays);
    assert_int_equal(leaked, 0);
    default_counts_check("needles", DEFAULT_NEEDLE_LEAKS, DEFAULT_NEEDLE_TWICE);
    rtk_aimed_free(&a);
    rtk_closed_free(&m);
}

/* Rays grazing a flat face of a box (exact vertices: the mesh is the
 * solid) at 10^-k degrees, k = 0 ... 6, aimed inside its triangles and at
 * its edges and vertices. */
static void grazing_rays(void **state)
{
    (void)state;
    const double c[3] = {0.0, 0.0, -1.0};
    closed_mesh box;
    assert_int_equal(rtk_closed_box(c, 1.0, 16, &box), 0);
    size_t rays = 0, leaked = 0;
    default_counts_reset();
    for (int k = 0; k <= 6; k++)
        for (int on_lines = 0; on_lines < 2; on_lines++) {
            aimed a;
            assert_int_equal(rtk_closed_graze(&box, 16, pow(10.0, -k), 1000, on_lines, 31u + 2u * (uint64_t)k +
                                              (uint64_t)on_lines, &a),
                             0);
            assert_true(a.count > 900);
            char where[48];
            snprintf(where, sizeof where, "grazed at 1e-%d degrees%s", k, on_lines ? " on edges" : "");
            check_mesh(&box, &a, where, &rays, &leaked);
            rtk_aimed_free(&a);
        }
    print_message("robust: %zu leaks or double hits in %zu rays\n", leaked, rays);
    assert_int_equal(leaked, 0);
    default_counts_check("grazing rays", DEFAULT_GRAZING_LEAKS, DEFAULT_GRAZING_TWICE);
    rtk_closed_free(&box);
}

/* Attaches m; with `moved` a second time step with those vertices. */
static void attach_mesh(rtk_device dev, rtk_scene scene, const closed_mesh *m, const float *moved)
{
    rtk_geometry g = NULL;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    if (moved)
        assert_int_equal(rtk_geometry_set_time_step_count(g, 2), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 0, m->mesh.vertices, 0, 12, m->mesh.vertex_count), RTK_OK);
    if (moved)
        assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 1, moved, 0, 12, m->mesh.vertex_count),
                         RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, m->mesh.indices, 0, 12, m->mesh.triangle_count), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(scene, g, NULL), RTK_OK);
    rtk_geometry_release(g);
}

/* A robust dynamic scene (a tree per geometry under a top level) is robust
 * in every tree and says so; so is a robust scene with a moving geometry
 * (bvh8.triangle4mb.robust, or bvh4 on the scalar backend), whose leaves interpolate the vertices to the
 * ray's time: rays aimed at the cube's vertices and edges as they are at
 * times 0, 0.37 and 1 (the same float interpolation as the traversal's) do
 * not leak either. */
static void robust_two_levels_and_motion(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    const double c1[3] = {0, 0, 0}, c2[3] = {5, 0, 0};
    closed_mesh sphere = make_sphere(c1, 1.0, 24, 11), cube = make_cube(c2, 1.0, 6);
    aimed a1 = aim_at_mesh(&sphere, 0.04, 1.5f, 0.5f, 5), a2 = aim_at_mesh(&cube, 0.04, 1.5f, 0.5f, 6);
    /* the cube moves by (0.5, 0.25, 0) over the shutter */
    float *moved = malloc(3 * cube.mesh.vertex_count * sizeof *moved);
    assert_non_null(moved);
    for (size_t i = 0; i < cube.mesh.vertex_count; i++)
        for (int k = 0; k < 3; k++)
            moved[3 * i + k] = cube.mesh.vertices[3 * i + k] + (k == 0 ? 0.5f : k == 1 ? 0.25f : 0.0f);
    static const float times[] = {0.0f, 0.37f, 1.0f};
    aimed at_time[3];
    for (int t = 0; t < 3; t++) {
        const float f = times[t], g = 1.0f - f;
        closed_mesh now = cube;
        now.mesh.vertices = malloc(3 * cube.mesh.vertex_count * sizeof *now.mesh.vertices);
        assert_non_null(now.mesh.vertices);
        for (size_t i = 0; i < 3 * cube.mesh.vertex_count; i++)
            now.mesh.vertices[i] = f * moved[i] + g * cube.mesh.vertices[i];
        now.c[0] += 0.5 * f;
        now.c[1] += 0.25 * f;
        at_time[t] = aim_at_mesh(&now, 0.04, 1.5f, 0.5f, 7 + (uint64_t)t);
        for (size_t r = 0; r < at_time[t].count; r++)
            at_time[t].rays[r].time = f;
        free(now.mesh.vertices);
    }
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene s = NULL;
        assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
        assert_int_equal(rtk_scene_set_flags(s, RTK_SCENE_FLAG_ROBUST | RTK_SCENE_FLAG_DYNAMIC), RTK_OK);
        attach_mesh(dev, s, &sphere, NULL);
        attach_mesh(dev, s, &cube, NULL);
        assert_int_equal(rtk_scene_commit(s), RTK_OK);
        rtk_scene_info info = {.struct_size = sizeof info};
        assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
        assert_int_equal(info.flags_not_honoured, 0);
        assert_int_equal(info.trees_built, 2);
        size_t first;
        assert_int_equal(leaks(s, &a1, &first, 1), 0);
        assert_int_equal(leaks(s, &a2, &first, 1), 0);
        rtk_scene_release(s);

        for (int q = 0; q < 2; q++) {
            assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
            assert_int_equal(rtk_scene_set_flags(s, RTK_SCENE_FLAG_ROBUST), RTK_OK);
            assert_int_equal(rtk_scene_set_build_quality(s, q ? RTK_BUILD_QUALITY_MEDIUM : RTK_BUILD_QUALITY_LOW),
                             RTK_OK);
            attach_mesh(dev, s, &sphere, NULL);
            attach_mesh(dev, s, &cube, moved);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
            assert_int_equal(info.flags_not_honoured, 0);
            assert_int_equal(info.triangles_motion, cube.mesh.triangle_count);
            assert_int_equal(leaks(s, &a1, &first, 1), 0);
            for (int t = 0; t < 3; t++) {
                const size_t n = leaks(s, &at_time[t], &first, 1);
                if (n) {
                    print_message("%s, moving cube at time %g: %zu leaks\n", names[b], (double)times[t], n);
                    print_ray(&at_time[t].rays[first]);
                }
                assert_int_equal(n, 0);
            }
            rtk_scene_release(s);
        }
        rtk_device_release(dev);
    }
    for (int t = 0; t < 3; t++)
        rtk_aimed_free(&at_time[t]);
    free(moved);
    rtk_aimed_free(&a1), rtk_aimed_free(&a2);
    rtk_closed_free(&sphere);
    rtk_closed_free(&cube);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(watertight_far_from_origin),
        cmocka_unit_test(watertight_tiny_and_huge),
        cmocka_unit_test(needles_and_zero_area),
        cmocka_unit_test(grazing_rays),
        cmocka_unit_test(robust_two_levels_and_motion),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
