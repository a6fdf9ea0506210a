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
 * printed beside (it has no such guarantee).
 *
 * - watertight_far_from_origin: the meshes of size 1 moved to 10^k,
 *   k = 0 ... 6.
 * - watertight_tiny_and_huge: meshes of size 1e-20 (edge functions that
 *   underflow in float, decided in double: without that fallback every ray
 *   misses), 1e-8 and 1e8.
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

#include "testlib.h"

/* A closed mesh and the solid it approximates: sphere (radius a), torus
 * (radii a, b about the z axis) or cube (half side a), around c. */
enum shape { SPHERE, TORUS, CUBE };
typedef struct closed_mesh {
    const char *name;
    float *v;
    uint32_t *idx;
    size_t nv, nt;
    float (*normal)[3]; /* per vertex: a direction pointing out of the mesh */
    enum shape shape;
    double c[3], a, b;
} closed_mesh;

/* The signed distance-like depth of p inside the solid (> 0 inside), in
 * double precision. */
static double solid_depth(const closed_mesh *m, const float p[3])
{
    const double x = p[0] - m->c[0], y = p[1] - m->c[1], z = p[2] - m->c[2];
    switch (m->shape) {
    case SPHERE: return m->a - sqrt(x * x + y * y + z * z);
    case TORUS: {
        const double q = sqrt(x * x + y * y) - m->a;
        return m->b - sqrt(q * q + z * z);
    }
    default: return m->a - fmax(fabs(x), fmax(fabs(y), fabs(z)));
    }
}

static void mesh_alloc(closed_mesh *m, size_t nv, size_t nt)
{
    m->v = calloc(3 * nv, sizeof *m->v);
    m->idx = calloc(3 * nt, sizeof *m->idx);
    m->normal = calloc(nv, sizeof *m->normal);
    assert_non_null(m->v);
    assert_non_null(m->idx);
    assert_non_null(m->normal);
    m->nv = nv;
    m->nt = 0;
}

static void add_tri(closed_mesh *m, uint32_t a, uint32_t b, uint32_t c)
{
    uint32_t *t = m->idx + 3 * m->nt++;
    t[0] = a, t[1] = b, t[2] = c;
}

static void add_vertex(closed_mesh *m, size_t i, double x, double y, double z, double nx, double ny, double nz)
{
    m->v[3 * i] = (float)x, m->v[3 * i + 1] = (float)y, m->v[3 * i + 2] = (float)z;
    const double l = sqrt(nx * nx + ny * ny + nz * nz);
    m->normal[i][0] = (float)(nx / l), m->normal[i][1] = (float)(ny / l), m->normal[i][2] = (float)(nz / l);
}

/* A UV sphere of radius r around c: `rings` rings of `seg` vertices and two
 * poles. */
static closed_mesh make_sphere(const double c[3], double r, int seg, int rings)
{
    closed_mesh m = {.name = "sphere", .shape = SPHERE, .c = {c[0], c[1], c[2]}, .a = r};
    mesh_alloc(&m, (size_t)seg * (size_t)rings + 2, 2 * (size_t)seg * (size_t)rings);
    const double pi = 3.14159265358979323846;
    for (int i = 0; i < rings; i++)
        for (int j = 0; j < seg; j++) {
            const double th = pi * (i + 1) / (rings + 1), ph = 2 * pi * j / seg;
            const double n[3] = {sin(th) * cos(ph), sin(th) * sin(ph), cos(th)};
            add_vertex(&m, (size_t)i * seg + j, c[0] + r * n[0], c[1] + r * n[1], c[2] + r * n[2], n[0], n[1], n[2]);
        }
    const uint32_t top = (uint32_t)(seg * rings), bottom = top + 1;
    add_vertex(&m, top, c[0], c[1], c[2] + r, 0, 0, 1);
    add_vertex(&m, bottom, c[0], c[1], c[2] - r, 0, 0, -1);
    for (int j = 0; j < seg; j++) {
        const uint32_t j1 = (uint32_t)((j + 1) % seg);
        add_tri(&m, top, (uint32_t)j, j1);
        const uint32_t last = (uint32_t)((rings - 1) * seg);
        add_tri(&m, bottom, last + j1, last + (uint32_t)j);
        for (int i = 0; i + 1 < rings; i++) {
            const uint32_t a = (uint32_t)(i * seg + j), b = (uint32_t)(i * seg) + j1;
            add_tri(&m, a, a + (uint32_t)seg, b);
            add_tri(&m, b, a + (uint32_t)seg, b + (uint32_t)seg);
        }
    }
    return m;
}

/* A torus around c in the xy plane: major radius R, minor r. */
static closed_mesh make_torus(const double c[3], double R, double r, int nu, int nv)
{
    closed_mesh m = {.name = "torus", .shape = TORUS, .c = {c[0], c[1], c[2]}, .a = R, .b = r};
    mesh_alloc(&m, (size_t)nu * (size_t)nv, 2 * (size_t)nu * (size_t)nv);
    const double pi = 3.14159265358979323846;
    for (int i = 0; i < nu; i++)
        for (int j = 0; j < nv; j++) {
            const double u = 2 * pi * i / nu, w = 2 * pi * j / nv;
            const double n[3] = {cos(w) * cos(u), cos(w) * sin(u), sin(w)};
            add_vertex(&m, (size_t)i * nv + j, c[0] + (R + r * cos(w)) * cos(u), c[1] + (R + r * cos(w)) * sin(u),
                       c[2] + r * sin(w), n[0], n[1], n[2]);
        }
    for (int i = 0; i < nu; i++)
        for (int j = 0; j < nv; j++) {
            const uint32_t a = (uint32_t)(i * nv + j), b = (uint32_t)(((i + 1) % nu) * nv + j);
            const uint32_t a1 = (uint32_t)(i * nv + (j + 1) % nv), b1 = (uint32_t)(((i + 1) % nu) * nv + (j + 1) % nv);
            add_tri(&m, a, b, a1);
            add_tri(&m, a1, b, b1);
        }
    return m;
}

/* The cube [c - h, c + h]^3 with each face an n x n grid of quads split
 * into two triangles; the vertices on the cube's edges and corners are
 * shared by the faces that meet there. */
static closed_mesh make_cube(const double c[3], double h, int n)
{
    closed_mesh m = {.name = "cube", .shape = CUBE, .c = {c[0], c[1], c[2]}, .a = h};
    const size_t side = (size_t)n + 1;
    mesh_alloc(&m, side * side * side, 12 * (size_t)n * (size_t)n);
    /* every lattice point gets an index; only the surface ones are used */
    for (size_t i = 0; i < side; i++)
        for (size_t j = 0; j < side; j++)
            for (size_t k = 0; k < side; k++) {
                const double p[3] = {-1 + 2.0 * i / n, -1 + 2.0 * j / n, -1 + 2.0 * k / n};
                add_vertex(&m, (i * side + j) * side + k, c[0] + h * p[0], c[1] + h * p[1], c[2] + h * p[2], p[0],
                           p[1], p[2]);
            }
#define LAT(i, j, k) ((uint32_t)(((size_t)(i) * side + (size_t)(j)) * side + (size_t)(k)))
    for (int axis = 0; axis < 3; axis++)
        for (int s = 0; s < 2; s++)
            for (int a = 0; a < n; a++)
                for (int b = 0; b < n; b++) {
                    uint32_t q[4];
                    const int corner[4][2] = {{a, b}, {a + 1, b}, {a + 1, b + 1}, {a, b + 1}};
                    for (int k = 0; k < 4; k++) {
                        int p[3];
                        p[axis] = s * n;
                        p[(axis + 1) % 3] = corner[k][0];
                        p[(axis + 2) % 3] = corner[k][1];
                        q[k] = LAT(p[0], p[1], p[2]);
                    }
                    /* alternate the diagonal, so vertices have 4 and 8 triangles */
                    if ((a + b) % 2) {
                        add_tri(&m, q[0], q[1], q[2]);
                        add_tri(&m, q[0], q[2], q[3]);
                    } else {
                        add_tri(&m, q[0], q[1], q[3]);
                        add_tri(&m, q[1], q[2], q[3]);
                    }
                }
#undef LAT
    return m;
}

static void mesh_free(closed_mesh *m)
{
    free(m->v);
    free(m->idx);
    free(m->normal);
}

/* Rays aimed at a mesh's vertices and edge points, each from a point
 * outside the solid through the aimed-at point P toward a point inside it:
 * whatever the rounding of P, the ray goes from outside to inside, so it
 * must cross the closed mesh before it reaches the point inside.
 * "Outside" and "inside" are by a margin of the faceting (the mesh lies
 * within `margin` of the solid's surface, its vertices rounded to floats),
 * checked in double precision against the solid. */
typedef struct aimed {
    rtk_ray *rays;
    float *t_in; /* the distance along the ray to the point inside */
    size_t count, cap;
} aimed;

/* The ray from o toward i, its direction of unit length (so that tiny
 * meshes do not get tiny directions, which the traversal takes as at least
 * 1e-18), and the distance to i. */
static void add_ray(aimed *a, const float o[3], const float i[3], int zero_sign)
{
    if (a->count == a->cap) {
        a->cap = a->cap ? 2 * a->cap : 1024;
        a->rays = realloc(a->rays, a->cap * sizeof *a->rays);
        a->t_in = realloc(a->t_in, a->cap * sizeof *a->t_in);
        assert_non_null(a->rays);
        assert_non_null(a->t_in);
    }
    double dd[3], l = 0.0;
    for (int k = 0; k < 3; k++) {
        dd[k] = (double)i[k] - o[k];
        l += dd[k] * dd[k];
    }
    l = sqrt(l);
    float d[3];
    for (int k = 0; k < 3; k++) {
        d[k] = (float)(dd[k] / l);
        if (d[k] == 0.0f)
            d[k] = zero_sign ? -0.0f : 0.0f;
    }
    a->t_in[a->count] = (float)l;
    a->rays[a->count++] = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY);
}

static void aim(aimed *a, const closed_mesh *m, const float p[3], const float n[3], double margin, float out,
                float in, rng *r, int axis_too)
{
    /* from a random direction on the outer side */
    for (int tries = 0; tries < 32; tries++) {
        float w[3], o[3], i[3];
        for (int k = 0; k < 3; k++)
            w[k] = n[k] + 1.6f * (rng_float(r) - 0.5f);
        const float l = sqrtf(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
        for (int k = 0; k < 3; k++) {
            o[k] = p[k] + out * w[k] / l;
            i[k] = p[k] - in * w[k] / l;
        }
        if (solid_depth(m, o) < -margin && solid_depth(m, i) > margin) {
            add_ray(a, o, i, tries & 1);
            break;
        }
    }
    if (!axis_too)
        return;
    /* along the axis nearest the outward direction, the other components
     * +0.0 or -0.0 */
    for (int k = 0; k < 3; k++) {
        float o[3] = {p[0], p[1], p[2]}, i[3] = {p[0], p[1], p[2]};
        o[k] = p[k] + (n[k] > 0 ? out : -out);
        i[k] = p[k] - (n[k] > 0 ? in : -in);
        if (solid_depth(m, o) < -margin && solid_depth(m, i) > margin)
            add_ray(a, o, i, (int)(rng_u32(r) & 1));
    }
}

static aimed aim_at_mesh(const closed_mesh *m, double margin, float out, float in, uint64_t seed)
{
    aimed a = {0};
    rng r = {seed};
    unsigned char *used = calloc(m->nv, 1);
    assert_non_null(used);
    for (size_t i = 0; i < 3 * m->nt; i++)
        used[m->idx[i]] = 1;
    for (size_t i = 0; i < m->nv; i++)
        if (used[i]) /* (the cube's lattice has points inside) */
            aim(&a, m, m->v + 3 * i, m->normal[i], margin, out, in, &r, 1);
    free(used);
    /* points on every edge (each edge is seen from both triangles: twice) */
    for (size_t t = 0; t < m->nt; t++)
        for (int e = 0; e < 3; e++) {
            const uint32_t i0 = m->idx[3 * t + e], i1 = m->idx[3 * t + (e + 1) % 3];
            const float *p0 = m->v + 3 * i0, *p1 = m->v + 3 * i1;
            for (int f = 0; f < 2; f++) {
                const float s = f ? 0.5f : 1.0f / 3.0f;
                float p[3], n[3];
                for (int k = 0; k < 3; k++) {
                    p[k] = p0[k] + s * (p1[k] - p0[k]);
                    n[k] = m->normal[i0][k] + m->normal[i1][k];
                }
                aim(&a, m, p, n, margin, out, in, &r, f == 0);
            }
        }
    return a;
}

static void print_ray(const rtk_ray *r)
{
    print_message("    ray org (%.9g, %.9g, %.9g) dir (%.9g, %.9g, %.9g)\n", r->org_x, r->org_y, r->org_z, r->dir_x,
                  r->dir_y, r->dir_z);
}

/* Leaks of the aimed rays through one scene: no hit before the point
 * inside; checked through intersect1, occluded1 (tfar at that point), and
 * packets of 8. */
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
    for (size_t base = 0; packets && base + 8 <= a->count; base += packets == 2 ? 8 : 8 * 37) {
        rtk_rayhit8 p8;
        for (unsigned l = 0; l < 8; l++) {
            rtk_rayhit rh = {.ray = a->rays[base + l]};
            rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
            test_packet_put(&p8, 8, l, &rh, 0);
        }
        assert_int_equal(test_trace_packet(s, 8, 0, NULL, &p8), RTK_OK);
        for (unsigned l = 0; l < 8; l++) {
            rtk_rayhit one = {.ray = a->rays[base + l]}, got;
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
    return n;
}

/* Every triangle a ray crosses before the point inside, collected by a
 * filter that rejects each (the distinct primitives: a spatial split
 * may show one twice). */
typedef struct crossing_log {
    uint32_t prim[64];
    unsigned n;
    float t_in;
} crossing_log;

static int collect_crossing(const rtk_filter_args *f)
{
    crossing_log *log = f->context->user;
    if (f->t > log->t_in)
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
static size_t double_hits(rtk_scene s, const aimed *a, size_t *missed, size_t *first)
{
    size_t n = 0;
    *missed = 0;
    *first = SIZE_MAX;
    for (size_t i = 0; i < a->count; i++) {
        crossing_log log = {.t_in = a->t_in[i]};
        const rtk_query_context ctx = {&log};
        rtk_rayhit rh = {.ray = a->rays[i]};
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1_ctx(s, &rh, &ctx), RTK_OK);
        assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID); /* every candidate rejected */
        if (log.n % 2 == 0 && *first == SIZE_MAX)
            *first = i;
        *missed += log.n == 0;
        n += log.n && log.n % 2 == 0;
    }
    return n;
}

static rtk_scene filtered_scene(rtk_device dev, const closed_mesh *m, unsigned flags, rtk_build_quality q)
{
    rtk_scene s = test_scene_uncommitted(dev, m->v, m->nv, m->idx, m->nt, flags);
    rtk_geometry g = rtk_scene_get_geometry(s, 0);
    assert_int_equal(rtk_geometry_set_intersect_filter(g, collect_crossing), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_set_build_quality(s, q), RTK_OK);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    return s;
}

/* The three closed meshes of size `size` around c, through every backend
 * and robust layout at every build quality (robust leaks and double hits
 * added to *rays and *leaked), and through the default layouts (their
 * leaks and double hits printed). */
static void closed_meshes_at(const double c[3], double size, const char *where, uint64_t seed, size_t *rays,
                             size_t *leaked)
{
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    static const rtk_build_quality qualities[] = {RTK_BUILD_QUALITY_LOW, RTK_BUILD_QUALITY_MEDIUM,
                                                  RTK_BUILD_QUALITY_HIGH};
    closed_mesh meshes[3] = {make_sphere(c, size, 24, 11), make_torus(c, size, 0.4 * size, 24, 12),
                             make_cube(c, size, 6)};
    const double mag = fmax(fabs(c[0]), fmax(fabs(c[1]), fabs(c[2]))) + 2.0 * size;
    for (int mi = 0; mi < 3; mi++) {
        const closed_mesh *m = &meshes[mi];
        /* the mesh lies within its faceting and the rounding of its
         * vertices of the solid's surface */
        const double margin = 0.04 * size + mag * 0x1p-23;
        const float out = (float)((mi == 1 ? 0.3 : 1.5) * size), in = (float)((mi == 1 ? 0.25 : 0.5) * size);
        const aimed a = aim_at_mesh(m, margin, out, in, seed + (uint64_t)mi);
        assert_true(a.count > 1000);
        char defaults[256] = "";
        for (size_t b = 0; b < nb; b++) {
            rtk_device dev = test_device(names[b]);
            for (int q = 0; q < 3; q++)
                for (int compact = 0; compact < 2; compact++) {
                    rtk_scene s = test_scene_uncommitted(dev, m->v, m->nv, m->idx, m->nt,
                                                         RTK_SCENE_FLAG_ROBUST | (compact ? RTK_SCENE_FLAG_COMPACT : 0));
                    assert_int_equal(rtk_scene_set_build_quality(s, qualities[q]), RTK_OK);
                    assert_int_equal(rtk_scene_commit(s), RTK_OK);
                    rtk_scene_info info = {.struct_size = sizeof info};
                    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
                    assert_int_equal(info.flags_not_honoured, 0);
                    assert_int_equal(info.triangles, m->nt); /* none degenerate */
                    size_t first;
                    const size_t n = leaks(s, &a, &first, 2);
                    *rays += a.count;
                    *leaked += n;
                    if (n) {
                        print_message("%s %s, %s, %s, quality %d: %zu of %zu rays leak\n", m->name, where, names[b],
                                      info.layout, (int)qualities[q], n, a.count);
                        print_ray(&a.rays[first]);
                    }
                    rtk_scene_release(s);
                    /* the same with every crossing collected (under the
                     * sanitizers, scripts/test, at medium quality only) */
                    if (getenv("RTK_TEST_SANITIZED") && qualities[q] != RTK_BUILD_QUALITY_MEDIUM)
                        continue;
                    s = filtered_scene(dev, m, RTK_SCENE_FLAG_ROBUST | (compact ? RTK_SCENE_FLAG_COMPACT : 0),
                                       qualities[q]);
                    size_t missed;
                    const size_t twice = double_hits(s, &a, &missed, &first);
                    *leaked += twice + missed;
                    if (twice + missed) {
                        print_message("%s %s, %s, %s, quality %d: %zu of %zu rays hit twice, %zu none (all "
                                      "crossings collected)\n",
                                      m->name, where, names[b], info.layout, (int)qualities[q], twice, a.count, missed);
                        print_ray(&a.rays[first]);
                    }
                    rtk_scene_release(s);
                }
            rtk_scene s = test_scene(dev, m->v, m->nv, m->idx, m->nt);
            size_t first, missed;
            const size_t n = leaks(s, &a, &first, 0);
            rtk_scene_release(s);
            s = filtered_scene(dev, m, 0, RTK_BUILD_QUALITY_MEDIUM);
            const size_t twice = double_hits(s, &a, &missed, &first);
            snprintf(defaults + strlen(defaults), sizeof defaults - strlen(defaults), " %s %zu/%zu", names[b], n,
                     twice);
            rtk_scene_release(s);
            rtk_device_release(dev);
        }
        print_message("%-6s %s: %zu rays; the default mode leaks / hits twice:%s\n", m->name, where, a.count,
                      defaults);
        free(a.rays);
        free(a.t_in);
    }
    for (int mi = 0; mi < 3; mi++)
        mesh_free(&meshes[mi]);
}

/* Meshes of size 1 moved to 10^k, k = 0 ... 6. */
static void watertight_far_from_origin(void **state)
{
    (void)state;
    size_t rays = 0, leaked = 0;
    for (int k = 0; k <= 6; k++) {
        const double off = pow(10.0, k);
        const double c[3] = {off, 0.5 * off, -0.25 * off};
        char where[32];
        snprintf(where, sizeof where, "at 1e%d", k);
        closed_meshes_at(c, 1.0, where, 17u + 3u * (uint64_t)k, &rays, &leaked);
    }
    print_message("robust: %zu leaks or double hits in %zu rays\n", leaked, rays);
    assert_int_equal(leaked, 0);
}

/* Meshes of size 1e-20 (whose edge functions underflow in float: the
 * double-precision fallback decides them), 1e-8 and 1e8, near the origin. */
static void watertight_tiny_and_huge(void **state)
{
    (void)state;
    size_t rays = 0, leaked = 0;
    static const double sizes[] = {1e-20, 1e-8, 1e8};
    for (int k = 0; k < 3; k++) {
        const double c[3] = {0.3 * sizes[k], -0.2 * sizes[k], 0.1 * sizes[k]};
        char where[32];
        snprintf(where, sizeof where, "of size %g", sizes[k]);
        closed_meshes_at(c, sizes[k], where, 99u + 3u * (uint64_t)k, &rays, &leaked);
    }
    print_message("robust: %zu leaks or double hits in %zu rays\n", leaked, rays);
    assert_int_equal(leaked, 0);
}

/* Attaches m; with `moved` a second time step with those vertices. */
static void attach_mesh(rtk_device dev, rtk_scene scene, const closed_mesh *m, const float *moved)
{
    rtk_geometry g = NULL;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    if (moved)
        assert_int_equal(rtk_geometry_set_time_step_count(g, 2), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 0, m->v, 0, 12, m->nv), RTK_OK);
    if (moved)
        assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 1, moved, 0, 12, m->nv),
                         RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, m->idx, 0, 12, m->nt), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(scene, g, NULL), RTK_OK);
    rtk_geometry_release(g);
}

/* A robust dynamic scene (a tree per geometry under a top level) is robust
 * in every tree and says so; so is a robust scene with a moving geometry
 * (bvh4.triangle4mb.robust), whose leaves interpolate the vertices to the
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
    const aimed a1 = aim_at_mesh(&sphere, 0.04, 1.5f, 0.5f, 5), a2 = aim_at_mesh(&cube, 0.04, 1.5f, 0.5f, 6);
    /* the cube moves by (0.5, 0.25, 0) over the shutter */
    float *moved = malloc(3 * cube.nv * sizeof *moved);
    assert_non_null(moved);
    for (size_t i = 0; i < cube.nv; i++)
        for (int k = 0; k < 3; k++)
            moved[3 * i + k] = cube.v[3 * i + k] + (k == 0 ? 0.5f : k == 1 ? 0.25f : 0.0f);
    static const float times[] = {0.0f, 0.37f, 1.0f};
    aimed at_time[3];
    for (int t = 0; t < 3; t++) {
        const float f = times[t], g = 1.0f - f;
        closed_mesh now = cube;
        now.v = malloc(3 * cube.nv * sizeof *now.v);
        assert_non_null(now.v);
        for (size_t i = 0; i < 3 * cube.nv; i++)
            now.v[i] = f * moved[i] + g * cube.v[i];
        now.c[0] += 0.5 * f;
        now.c[1] += 0.25 * f;
        at_time[t] = aim_at_mesh(&now, 0.04, 1.5f, 0.5f, 7 + (uint64_t)t);
        for (size_t r = 0; r < at_time[t].count; r++)
            at_time[t].rays[r].time = f;
        free(now.v);
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
            assert_int_equal(info.triangles_motion, cube.nt);
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
        free(at_time[t].rays), free(at_time[t].t_in);
    free(moved);
    free(a1.rays), free(a1.t_in), free(a2.rays), free(a2.t_in);
    mesh_free(&sphere);
    mesh_free(&cube);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(watertight_far_from_origin),
        cmocka_unit_test(watertight_tiny_and_huge),
        cmocka_unit_test(robust_two_levels_and_motion),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
