/*
 * Closest points (rtk_closest_point, rtk_closest_point_batch) against brute
 * force over every triangle in double precision (geometry/closest_point.h,
 * itself checked against dense sampling), on every backend and every
 * triangle layout (default, compact, robust, both): points all around and
 * far away, points exactly on vertices, edges and faces, radii just short
 * of and just past the answer, a point 1e-12 from a face (double precision
 * kept), huge and tiny coordinates, zero-area triangles (never the answer),
 * quads, instances (scaled, rotated, sheared, nested) and motion blur; the
 * batch against the single call on two threads; empty scenes, user
 * geometry without a point query function (refused; test_user_points has
 * user geometry with one) and every bad argument.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "geometry/closest_point.h"
#include "testlib.h"

static test_mesh ball;

/* the backend rtk picks for this CPU */
static rtk_device default_device(void)
{
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    return dev;
}

static int setup(void **state)
{
    (void)state;
    ball = test_ball(16);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    free(ball.v);
    free(ball.idx);
    return 0;
}

/* ---- the reference ---- */

typedef struct tri_d {
    double v[3][3];
    uint32_t geom, prim, inst;
} tri_d;

/* Whether a's ids come before b's: the tie rule of rtk_point_hit (rtk.h). */
static int ids_before(const tri_d *a, const tri_d *b)
{
    if (a->inst != b->inst)
        return a->inst < b->inst;
    return a->geom != b->geom ? a->geom < b->geom : a->prim < b->prim;
}

/* The nearest of n triangles to q (those with area), by brute force; of
 * those at exactly the same distance, the least ids. */
static double brute(const tri_d *t, size_t n, const double *q, size_t *which)
{
    double best = INFINITY;
    *which = (size_t)-1;
    for (size_t i = 0; i < n; i++) {
        const double *a = t[i].v[0], *b = t[i].v[1], *c = t[i].v[2];
        const double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        const double nx = e1[1] * e2[2] - e1[2] * e2[1], ny = e1[2] * e2[0] - e1[0] * e2[2],
                     nz = e1[0] * e2[1] - e1[1] * e2[0];
        if (nx == 0.0 && ny == 0.0 && nz == 0.0)
            continue;
        rtk_tri_closest r;
        rtk_closest_point_triangle(&r, q, a, b, c);
        if (r.d2 < best || (r.d2 == best && *which != (size_t)-1 && ids_before(&t[i], &t[*which]))) {
            best = r.d2;
            *which = i;
        }
    }
    return sqrt(best);
}

static tri_d *mesh_tris(const float *v, const uint32_t *idx, size_t nt)
{
    tri_d *t = malloc(nt * sizeof *t);
    assert_non_null(t);
    for (size_t i = 0; i < nt; i++) {
        for (int k = 0; k < 3; k++)
            for (int a = 0; a < 3; a++)
                t[i].v[k][a] = v[3 * idx[3 * i + k] + a];
        t[i].geom = 0;
        t[i].prim = (uint32_t)i;
        t[i].inst = RTK_INVALID_GEOMETRY_ID;
    }
    return t;
}

/* ---- the triangle routine against dense sampling ---- */

static void test_triangle_routine(void **state)
{
    (void)state;
    rng r = {7};
    for (int it = 0; it < 300; it++) {
        double a[3], b[3], c[3], q[3];
        for (int k = 0; k < 3; k++) {
            a[k] = rng_float(&r) * 2 - 1;
            b[k] = rng_float(&r) * 2 - 1;
            /* some needles (a, b, c on a line), some slivers (c off the line by 1e-9) */
            c[k] = it % 10 == 0   ? a[k] + (b[k] - a[k]) * 0.25
                   : it % 10 == 1 ? a[k] + (b[k] - a[k]) * 0.7 + (k == 0 ? 1e-9 : 0.0)
                                  : rng_float(&r) * 2 - 1;
            q[k] = rng_float(&r) * 4 - 2;
        }
        rtk_tri_closest res;
        rtk_closest_point_triangle(&res, q, a, b, c);
        assert_true(res.u >= 0 && res.v >= 0 && res.u + res.v <= 1 + 1e-12);
        /* the point is where u, v say, at the distance said */
        double d2 = 0;
        for (int k = 0; k < 3; k++) {
            const double p = (1 - res.u - res.v) * a[k] + res.u * b[k] + res.v * c[k];
            assert_true(fabs(p - res.p[k]) <= 1e-12);
            d2 += (res.p[k] - q[k]) * (res.p[k] - q[k]);
        }
        assert_true(fabs(d2 - res.d2) <= 1e-12);
        /* never farther than the nearest point of the edges */
        rtk_tri_closest e;
        rtk_cp_edges(&e, q, a, b, c);
        assert_true(res.d2 <= e.d2);
        /* no sample of the triangle is nearer */
        const int N = 60;
        for (int i = 0; i <= N; i++)
            for (int j = 0; i + j <= N; j++) {
                const double u = (double)i / N, v = (double)j / N;
                double s2 = 0;
                for (int k = 0; k < 3; k++) {
                    const double p = (1 - u - v) * a[k] + u * b[k] + v * c[k] - q[k];
                    s2 += p * p;
                }
                assert_true(res.d2 <= s2 + 1e-12);
            }
    }
    /* exact answers: a vertex, an edge's middle, the face */
    const double a[3] = {0, 0, 0}, b[3] = {1, 0, 0}, c[3] = {0, 1, 0};
    rtk_tri_closest res;
    rtk_closest_point_triangle(&res, (const double[3]){-1, -1, 0}, a, b, c);
    assert_true(res.d2 == 2.0 && res.u == 0.0 && res.v == 0.0);
    rtk_closest_point_triangle(&res, (const double[3]){1, 1, 0}, a, b, c);
    assert_true(res.p[0] == 0.5 && res.p[1] == 0.5 && res.d2 == 0.5);
    rtk_closest_point_triangle(&res, (const double[3]){0.25, 0.25, 3}, a, b, c);
    assert_true(res.d2 == 9.0 && res.u == 0.25 && res.v == 0.25);
    /* a point triangle: its vertex */
    rtk_closest_point_triangle(&res, (const double[3]){0, 0, 2}, b, b, b);
    assert_true(res.p[0] == 1.0 && res.p[1] == 0.0 && res.d2 == 5.0);
}

/* ---- scenes ---- */

static const char *where = ""; /* the backend and flags under test, for messages */
static char where_buf[64];
static const unsigned layouts[] = {0, RTK_SCENE_FLAG_COMPACT, RTK_SCENE_FLAG_ROBUST,
                                   RTK_SCENE_FLAG_ROBUST | RTK_SCENE_FLAG_COMPACT};

/* Whether the scene's layout holds the application's vertices exactly. */
static int exact_vertices(unsigned flags) { return flags != 0; }

/* One query against the reference: the distance (to the bit where the
 * layout keeps the vertices, else to 1e-6 relative to the scene's size),
 * the point at that distance, on the triangle reported. */
static void check_one(rtk_scene s, const tri_d *t, size_t nt, const double *q, double radius, int exact,
                      double size)
{
    size_t which;
    const double want = brute(t, nt, q, &which);
    rtk_point_hit h;
    assert_int_equal(rtk_closest_point(s, &(rtk_point_query){.x = q[0], .y = q[1], .z = q[2], .radius = radius}, &h),
                     RTK_OK);
    if (!(want <= radius)) {
        if (h.geomID != RTK_INVALID_GEOMETRY_ID && !(exact ? 0 : fabs(want - radius) <= 1e-6 * size))
            fail_msg("point (%g %g %g) radius %g: found %g, nothing is that near (%g)", q[0], q[1], q[2], radius,
                     h.distance, want);
        if (h.geomID == RTK_INVALID_GEOMETRY_ID)
            assert_true(h.distance == INFINITY && h.primID == RTK_INVALID_GEOMETRY_ID);
        return;
    }
    if (h.geomID == RTK_INVALID_GEOMETRY_ID && !exact && want > radius - 1e-6 * size)
        return; /* (the default layouts' v0 + e1: a vertex half an ulp of an edge away) */
    if (h.geomID == RTK_INVALID_GEOMETRY_ID)
        fail_msg("point (%.17g %.17g %.17g) radius %g: nothing found, reference %.17g", q[0], q[1], q[2], radius, want);
    if (exact ? h.distance != want : fabs(h.distance - want) > 1e-6 * size)
        fail_msg("point (%.17g %.17g %.17g): distance %.17g, reference %.17g (prim %u, reference %u)", q[0], q[1], q[2],
                 h.distance, want, h.primID, t[which].prim);
    const double d = sqrt((h.x - q[0]) * (h.x - q[0]) + (h.y - q[1]) * (h.y - q[1]) + (h.z - q[2]) * (h.z - q[2]));
    assert_true(fabs(d - h.distance) <= 1e-9 * (size + h.distance));
    /* of triangles at the same distance, the least ids (where the layout
     * keeps the vertices, the reference measures what the walk does) */
    if (exact && !(h.primID == t[which].prim && h.geomID == t[which].geom && h.instID == t[which].inst))
        fail_msg("%s: point (%.17g %.17g %.17g): prim %u of the triangles at distance %.17g, the least is %u", where,
                 q[0], q[1], q[2], h.primID, h.distance, t[which].prim);
    /* the reported triangle is at that distance too */
    size_t k = 0;
    while (k < nt && !(t[k].prim == h.primID && t[k].geom == h.geomID && t[k].inst == h.instID))
        k++;
    assert_true(k < nt);
    rtk_tri_closest r;
    rtk_closest_point_triangle(&r, q, t[k].v[0], t[k].v[1], t[k].v[2]);
    if (!(fabs(sqrt(r.d2) - h.distance) <= (exact ? 0.0 : 1e-6 * size)))
        fail_msg("%s: point (%.17g %.17g %.17g): distance %.17g to prim %u, which is %.17g away", where, q[0], q[1],
                 q[2], h.distance, h.primID, sqrt(r.d2));
    const double nl = sqrt((double)h.n_x * h.n_x + (double)h.n_y * h.n_y + (double)h.n_z * h.n_z);
    assert_true(fabs(nl - 1.0) < 1e-5);
    assert_true(h.u >= 0.0f && h.v >= 0.0f && h.u + h.v <= 1.0f + 1e-6f);
}

/* Points all around the mesh (in and beyond its box, some far), on its
 * vertices, edge middles and face centres, and radii around the answer. */
static void check_points(rtk_scene s, const tri_d *t, size_t nt, int exact, double size, uint64_t seed, int count)
{
    rng r = {seed};
    for (int i = 0; i < count; i++) {
        double q[3];
        const int kind = i % 6;
        const tri_d *x = &t[rng_u32(&r) % nt];
        for (int k = 0; k < 3; k++) {
            switch (kind) {
            case 0: q[k] = (rng_float(&r) * 3 - 1.5) * size; break;
            case 1: q[k] = (rng_float(&r) * 40 - 20) * size; break;
            case 2: q[k] = x->v[i / 6 % 3][k]; break;                            /* a vertex */
            case 3: q[k] = 0.5 * x->v[0][k] + 0.5 * x->v[1][k]; break;           /* an edge's middle */
            case 4: q[k] = (x->v[0][k] + x->v[1][k] + x->v[2][k]) / 3.0; break;  /* the face */
            default: q[k] = x->v[0][k] + (rng_float(&r) - 0.5) * 0.05 * size; break; /* near a vertex */
            }
        }
        check_one(s, t, nt, q, INFINITY, exact, size);
        if (kind == 2 && exact) {
            rtk_point_hit h;
            assert_int_equal(rtk_closest_point(s, &(rtk_point_query){.x = q[0], .y = q[1], .z = q[2]}, &h), RTK_OK);
            if (h.distance != 0.0) /* on a vertex, radius 0 */
                fail_msg("point (%.17g %.17g %.17g) on a vertex: distance %.17g, prim %u", q[0], q[1], q[2],
                         h.distance, h.primID);
        }
        size_t which;
        const double d = brute(t, nt, q, &which);
        if (d > 0) {
            check_one(s, t, nt, q, d * 0.999, exact, size);
            check_one(s, t, nt, q, d * 1.001, exact, size);
        }
    }
}

/* Points on the ball's vertices and edges (where triangles tie) and
 * around it: every field of each answer, for a scene of the given flags. */
#define SAME_POINTS 600
static void same_points(rtk_scene s, rtk_point_hit *h)
{
    rng r = {41};
    for (int i = 0; i < SAME_POINTS; i++) {
        const uint32_t *t = &ball.idx[3 * (rng_u32(&r) % ball.nt)];
        const float *a = &ball.v[3 * t[0]], *b = &ball.v[3 * t[1]];
        double q[3];
        for (int k = 0; k < 3; k++)
            q[k] = i % 3 == 0 ? a[k] : i % 3 == 1 ? 0.5 * a[k] + 0.5 * b[k] : rng_float(&r) * 6 - 3;
        memset(&h[i], 0, sizeof h[i]);
        assert_int_equal(rtk_closest_point(s, &(rtk_point_query){.x = q[0], .y = q[1], .z = q[2], .radius = INFINITY},
                                           &h[i]),
                         RTK_OK);
    }
}

static void test_mesh_layouts(void **state)
{
    (void)state;
    char names[8][32];
    const size_t nb = test_backend_names(names, 8);
    tri_d *t = mesh_tris(ball.v, ball.idx, ball.nt);
    const size_t nl = sizeof layouts / sizeof *layouts;
    rtk_point_hit(*first)[SAME_POINTS] = calloc(nl, sizeof *first), *h = calloc(SAME_POINTS, sizeof *h);
    assert_true(first && h);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (size_t l = 0; l < nl; l++) {
            rtk_scene s = test_scene_flags(dev, ball.v, ball.nv, ball.idx, ball.nt, layouts[l]);
            snprintf(where_buf, sizeof where_buf, "%s, flags %u", names[b], layouts[l]);
            where = where_buf;
            check_points(s, t, ball.nt, exact_vertices(layouts[l]), 1.0, 11 + l, test_sanitized() ? 120 : 600);
            /* every backend the first's answers, to the bit, ties included
             * (each layout's backends keep the same floats) */
            same_points(s, b ? h : first[l]);
            for (int i = 0; b && i < SAME_POINTS; i++)
                if (memcmp(&h[i], &first[l][i], sizeof h[i]))
                    fail_msg("%s: point %d: prim %u at %.17g, %s gave prim %u at %.17g", where, i, h[i].primID,
                             h[i].distance, names[0], first[l][i].primID, first[l][i].distance);
            rtk_scene_release(s);
        }
        rtk_device_release(dev);
    }
    free(first);
    free(h);
    free(t);
}

/* Separate triangles facing every way, and the shared meshes' smallest. */
static void test_soup(void **state)
{
    (void)state;
    char names[8][32];
    const size_t nb = test_backend_names(names, 8);
    rng r = {3};
    float *v;
    uint32_t *idx;
    const size_t nt = 3000;
    test_soup_mesh(&r, nt, 0.1f, &v, &idx);
    tri_d *t = mesh_tris(v, idx, nt);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (size_t l = 0; l < sizeof layouts / sizeof *layouts; l++) {
            rtk_scene s = test_scene_flags(dev, v, 3 * nt, idx, nt, layouts[l]);
            check_points(s, t, nt, exact_vertices(layouts[l]), 1.0, 21 + l, test_sanitized() ? 60 : 300);
            rtk_scene_release(s);
        }
        rtk_device_release(dev);
    }
    free(t);
    free(v);
    free(idx);
}

/* Scaled far up and far down (rtk's range: 2^36 and areas above its
 * floor), and moved far from the origin: the same answers relative to the
 * size.  The last: the unit ball moved 2^20 away, its vertices on float's
 * grid of 1/16 there, and points in double between float's (what a float
 * bound must allow for: the point's rounding, far more than the ball's
 * own). */
static void test_scales(void **state)
{
    (void)state;
    const double scales[] = {1e-4, 1e8, 1.0};
    const double offsets[] = {0.0, 100.0, 0x1p20}; /* (at 1e8: 1e10, within rtk's 2^36) */
    rtk_device dev = default_device();
    for (int i = 0; i < 3; i++)
        for (int o = 0; o < 3; o++) {
            if ((i == 2) != (o == 2))
                continue;
            float *v = malloc(ball.nv * 3 * sizeof *v);
            assert_non_null(v);
            for (size_t k = 0; k < ball.nv * 3; k++)
                v[k] = (float)(ball.v[k] * scales[i] + offsets[o] * scales[i]);
            tri_d *t = mesh_tris(v, ball.idx, ball.nt);
            for (size_t l = 0; l < sizeof layouts / sizeof *layouts; l++) {
                rtk_scene s = test_scene_flags(dev, v, ball.nv, ball.idx, ball.nt, layouts[l]);
                rtk_scene_info info = {.struct_size = sizeof info};
                assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
                /* (at 1e-4 the slivers at the ball's poles are below rtk's
                 * range of areas: left out, within 1e-6 of their neighbours) */
                assert_int_equal(info.triangles + info.triangles_out_of_range + info.triangles_degenerate, ball.nt);
                rng r = {5};
                for (int n = 0; n < 200; n++) {
                    double q[3];
                    for (int k = 0; k < 3; k++)
                        q[k] = (offsets[o] + rng_float(&r) * 3 - 1.5) * scales[i];
                    check_one(s, t, ball.nt, q, INFINITY, exact_vertices(layouts[l]),
                              scales[i] * (1 + offsets[o]));
                }
                rtk_scene_release(s);
            }
            free(t);
            free(v);
        }
    rtk_device_release(dev);
}

/* Double precision kept: a point 1e-12 above a face at distance 1e-12
 * (a float could not tell it from the face), and a point beyond float's
 * range of the scene (1e30 away). */
static void test_double_precision(void **state)
{
    (void)state;
    static const float v[] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    static const uint32_t idx[] = {0, 1, 2};
    rtk_device dev = default_device();
    for (size_t l = 0; l < sizeof layouts / sizeof *layouts; l++) {
        rtk_scene s = test_scene_flags(dev, v, 3, idx, 1, layouts[l]);
        rtk_point_hit h;
        const double z = 1e-12;
        assert_int_equal(rtk_closest_point(s, &(rtk_point_query){.x = 0.3, .y = 0.3, .z = 1.0 + z, .radius = INFINITY},
                                           &h), RTK_OK);
        assert_true(h.distance == 1.0 + z);
        assert_int_equal(rtk_closest_point(s, &(rtk_point_query){.x = 0.3, .y = 0.3, .z = z, .radius = INFINITY}, &h),
                         RTK_OK);
        assert_true(h.distance == z && h.x == 0.3 && h.y == 0.3 && h.z == 0.0);
        assert_true(h.n_z == 1.0f && h.geomID == 0 && h.primID == 0);
        /* within the radius 1e-12 exactly, not within just below it */
        assert_int_equal(rtk_closest_point(s, &(rtk_point_query){.x = 0.3, .y = 0.3, .z = z, .radius = z}, &h), RTK_OK);
        assert_int_equal(h.geomID, 0);
        assert_int_equal(rtk_closest_point(s, &(rtk_point_query){.x = 0.3, .y = 0.3, .z = z, .radius = z * 0.999}, &h),
                         RTK_OK);
        assert_int_equal(h.geomID, RTK_INVALID_GEOMETRY_ID);
        /* far away, where float squares of the distance are out of range */
        assert_int_equal(rtk_closest_point(s, &(rtk_point_query){.x = 0, .y = 0, .z = -1e19, .radius = INFINITY}, &h),
                         RTK_OK);
        assert_true(h.distance == 1e19 && h.geomID == 0);
        assert_int_equal(rtk_closest_point(s, &(rtk_point_query){.x = 1e19, .y = -1e19, .z = 1e19, .radius = 1e20}, &h),
                         RTK_OK);
        assert_true(fabs(h.distance - sqrt(3.0) * 1e19) < 1e5 && h.geomID == 0);
        /* -0.0 is 0 */
        assert_int_equal(rtk_closest_point(s, &(rtk_point_query){.x = -0.0, .y = -0.0, .z = -0.0, .radius = 0}, &h),
                         RTK_OK);
        assert_true(h.distance == 0.0 && h.u == 0.0f && h.v == 0.0f);
        rtk_scene_release(s);
    }
    rtk_device_release(dev);
}

/* A zero-area triangle nearer than any other is never the answer: rays
 * never hit it, and it is no surface. */
static void test_degenerate(void **state)
{
    (void)state;
    static const float v[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 5, 1, 1, 5, 2, 2, 5, 3, 3, 5};
    static const uint32_t idx[] = {0, 1, 2, 3, 4, 5, 6, 6, 6};
    rtk_device dev = default_device();
    for (size_t l = 0; l < sizeof layouts / sizeof *layouts; l++) {
        rtk_scene s = test_scene_flags(dev, v, 7, idx, 3, layouts[l]);
        rtk_point_hit h;
        assert_int_equal(rtk_closest_point(s, &(rtk_point_query){.x = 1, .y = 1, .z = 5, .radius = INFINITY}, &h),
                         RTK_OK);
        assert_int_equal(h.primID, 0);
        assert_true(fabs(h.distance - sqrt(0.5 + 25.0)) < 1e-12);
        rtk_scene_release(s);
    }
    rtk_device_release(dev);
}

/* Quads: the quad's id and u, v over the quad. */
static void test_quads(void **state)
{
    (void)state;
    static const float v[] = {0, 0, 0, 2, 0, 0, 2, 2, 0, 0, 2, 0};
    static const uint32_t q[] = {0, 1, 2, 3};
    rtk_device dev = default_device();
    rtk_scene s;
    rtk_geometry g;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_QUAD, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, 4), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, q, 0, 16, 1), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
    rtk_geometry_release(g);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    /* both halves: a point over each, the hit of a ray straight down from it */
    const double pts[][2] = {{0.5, 0.3}, {1.7, 1.5}};
    for (int i = 0; i < 2; i++) {
        rtk_point_hit h;
        assert_int_equal(
            rtk_closest_point(s, &(rtk_point_query){.x = pts[i][0], .y = pts[i][1], .z = 3, .radius = INFINITY}, &h),
            RTK_OK);
        assert_int_equal(h.primID, 0);
        assert_true(h.distance == 3.0);
        rtk_rayhit rh = {.ray = test_ray((float)pts[i][0], (float)pts[i][1], 3, 0, 0, -1, 0, INFINITY)};
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
        assert_int_equal(rh.hit.primID, 0);
        assert_true(fabsf(rh.hit.u - h.u) < 1e-6f && fabsf(rh.hit.v - h.v) < 1e-6f);
    }
    rtk_scene_release(s);
    rtk_device_release(dev);
}

/* ---- instances ---- */

static void apply(const double *m, const double *p, double *out)
{
    for (int i = 0; i < 3; i++)
        out[i] = m[4 * i] * p[0] + m[4 * i + 1] * p[1] + m[4 * i + 2] * p[2] + m[4 * i + 3];
}

static rtk_geometry add_instance(rtk_device dev, rtk_scene outer, rtk_scene inner, const float *xf, uint32_t *id)
{
    rtk_geometry g;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_instanced_scene(g, inner), RTK_OK);
    assert_int_equal(rtk_geometry_set_transform(g, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, xf), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(outer, g, id), RTK_OK);
    rtk_geometry_release(g);
    return g;
}

/* Four instances of the ball (one stretched 3x along a rotated axis and
 * sheared, one shrunk, one plain, one turned about a tilted axis and grown
 * 1.3x: a similarity, whose scale the walk bounds tightly), and an
 * instance of that scene (nested):
 * distances in the scene's space against the ball's triangles placed
 * explicitly, instID the outermost instance's. */
static void test_instances(void **state)
{
    (void)state;
    char names[8][32];
    const size_t nb = test_backend_names(names, 8);
    enum { NI = 4 };
    const float xf[NI][12] = {
        {2.4f, 0.8f, 0.3f, 3.0f, -0.6f, 1.8f, 0.0f, 0.5f, 0.2f, 0.1f, 1.0f, -1.0f},
        {0.2f, 0.0f, 0.0f, -2.0f, 0.0f, 0.2f, 0.0f, 1.0f, 0.0f, 0.0f, 0.2f, 0.0f},
        {1.0f, 0.0f, 0.0f, 0.0f, 0.0f, 1.0f, 0.0f, -3.0f, 0.0f, 0.0f, 1.0f, 2.0f},
        {1.096197f, -0.381619f, 0.585423f, 0.5f, 0.585423f, 1.096197f, -0.381619f, 3.5f, -0.381619f, 0.585423f,
         1.096197f, -2.0f},
    };
    const float outer_xf[12] = {0.0f, -1.0f, 0.0f, 10.0f, 1.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 1.0f, 0.0f};
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (int robust = 0; robust < 2; robust++) {
            rtk_scene inner = test_scene_flags(dev, ball.v, ball.nv, ball.idx, ball.nt,
                                               robust ? RTK_SCENE_FLAG_ROBUST : 0);
            rtk_scene mid, top;
            assert_int_equal(rtk_scene_new(dev, &mid), RTK_OK);
            assert_int_equal(rtk_scene_new(dev, &top), RTK_OK);
            tri_d *t = malloc(NI * ball.nt * sizeof *t), *tt = malloc(NI * ball.nt * sizeof *tt);
            assert_true(t && tt);
            uint32_t ids[NI], top_id;
            for (int i = 0; i < NI; i++) {
                add_instance(dev, mid, inner, xf[i], &ids[i]);
                double m[12];
                for (int k = 0; k < 12; k++)
                    m[k] = xf[i][k];
                for (size_t p = 0; p < ball.nt; p++) {
                    tri_d *x = &t[i * ball.nt + p];
                    for (int k = 0; k < 3; k++) {
                        const double o[3] = {ball.v[3 * ball.idx[3 * p + k]], ball.v[3 * ball.idx[3 * p + k] + 1],
                                             ball.v[3 * ball.idx[3 * p + k] + 2]};
                        apply(m, o, x->v[k]);
                    }
                    x->geom = 0, x->prim = (uint32_t)p, x->inst = ids[i];
                }
            }
            assert_int_equal(rtk_scene_commit(mid), RTK_OK);
            add_instance(dev, top, mid, outer_xf, &top_id);
            assert_int_equal(rtk_scene_commit(top), RTK_OK);
            double om[12];
            for (int k = 0; k < 12; k++)
                om[k] = outer_xf[k];
            for (size_t p = 0; p < NI * ball.nt; p++) {
                tt[p] = t[p];
                for (int k = 0; k < 3; k++)
                    apply(om, t[p].v[k], tt[p].v[k]);
                tt[p].inst = top_id;
            }
            /* (the instances' geometry is the inverse of the float inverse
             * of the transform: within 1e-5 of the placed triangles) */
            rng r = {9};
            for (int n = 0; n < (test_sanitized() ? 100 : 500); n++) {
                double q[3];
                for (int k = 0; k < 3; k++)
                    q[k] = rng_float(&r) * 12 - 6;
                size_t which;
                const double want = brute(t, NI * ball.nt, q, &which);
                rtk_point_hit h;
                assert_int_equal(rtk_closest_point(mid, &(rtk_point_query){.x = q[0], .y = q[1], .z = q[2],
                                                                             .radius = INFINITY}, &h), RTK_OK);
                if (fabs(h.distance - want) > 1e-5)
                    fail_msg("point (%g %g %g): distance %.9g, reference %.9g", q[0], q[1], q[2], h.distance, want);
                assert_true(h.instID == t[which].inst || fabs(h.distance - want) > 0);
                assert_int_equal(h.geomID, 0);
                double qq[3];
                apply(om, q, qq);
                const double want2 = brute(tt, NI * ball.nt, qq, &which);
                assert_int_equal(rtk_closest_point(top, &(rtk_point_query){.x = qq[0], .y = qq[1], .z = qq[2],
                                                                             .radius = INFINITY}, &h), RTK_OK);
                if (fabs(h.distance - want2) > 1e-5)
                    fail_msg("nested, point (%g %g %g): distance %.9g, reference %.9g", qq[0], qq[1], qq[2],
                             h.distance, want2);
                assert_int_equal(h.instID, top_id);
            }
            free(t);
            free(tt);
            rtk_scene_release(top);
            rtk_scene_release(mid);
            rtk_scene_release(inner);
        }
        rtk_device_release(dev);
    }
}

/* ---- motion blur ---- */

/* The ball moving by (2, 0, 1) and growing 1.5x over two steps, and over
 * five: the distance at times 0, 1 and between against the vertices
 * interpolated as rtk does ((1 - f) a + f b in float, not fused). */
static void test_motion(void **state)
{
    (void)state;
    rtk_device dev = default_device();
    for (unsigned steps = 2; steps <= 5; steps += 3) {
        float *vs = malloc(steps * ball.nv * 3 * sizeof *vs);
        assert_non_null(vs);
        for (unsigned k = 0; k < steps; k++) {
            const float s = (float)k / (float)(steps - 1);
            for (size_t i = 0; i < ball.nv; i++)
                for (int a = 0; a < 3; a++)
                    vs[(k * ball.nv + i) * 3 + a] = ball.v[3 * i + a] * (1.0f + 0.5f * s) + (a == 0 ? 2 * s : a == 2 ? s : 0);
        }
        for (int robust = 0; robust < 2; robust++) {
            rtk_scene s;
            rtk_geometry g;
            assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
            if (robust)
                assert_int_equal(rtk_scene_set_flags(s, RTK_SCENE_FLAG_ROBUST), RTK_OK);
            assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
            assert_int_equal(rtk_geometry_set_time_step_count(g, steps), RTK_OK);
            for (unsigned k = 0; k < steps; k++)
                assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, k,
                                                                     vs + k * ball.nv * 3, 0, 12, ball.nv),
                                 RTK_OK);
            assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, ball.idx, 0, 12, ball.nt), RTK_OK);
            assert_int_equal(rtk_geometry_commit(g), RTK_OK);
            assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
            rtk_geometry_release(g);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            const float times[] = {0.0f, 0.3f, 0.5f, 0.77f, 1.0f};
            tri_d *t = malloc(ball.nt * sizeof *t);
            assert_non_null(t);
            for (int ti = 0; ti < 5; ti++) {
                const float ts = times[ti] * (float)(steps - 1);
                unsigned seg = (unsigned)ts;
                seg = seg < steps - 1 ? seg : steps - 2;
                const float f = ts - (float)seg;
                for (size_t p = 0; p < ball.nt; p++) {
                    for (int k = 0; k < 3; k++)
                        for (int a = 0; a < 3; a++) {
                            const size_t vi = ball.idx[3 * p + k];
                            const float x0 = vs[(seg * ball.nv + vi) * 3 + a], x1 = vs[((seg + 1) * ball.nv + vi) * 3 + a];
                            volatile float m1 = f * x1, m0 = (1.0f - f) * x0;
                            t[p].v[k][a] = (float)(m1 + m0);
                        }
                    t[p].geom = 0, t[p].prim = (uint32_t)p, t[p].inst = RTK_INVALID_GEOMETRY_ID;
                }
                rng r = {31 + ti};
                for (int n = 0; n < 100; n++) {
                    double q[3];
                    for (int k = 0; k < 3; k++)
                        q[k] = rng_float(&r) * 6 - 2;
                    size_t which;
                    const double want = brute(t, ball.nt, q, &which);
                    rtk_point_hit h;
                    assert_int_equal(rtk_closest_point(s, &(rtk_point_query){.x = q[0], .y = q[1], .z = q[2],
                                                                               .radius = INFINITY, .time = times[ti]},
                                                       &h), RTK_OK);
                    if (h.distance != want)
                        fail_msg("%u steps, time %g, point (%g %g %g): distance %.17g, reference %.17g", steps,
                                 times[ti], q[0], q[1], q[2], h.distance, want);
                }
            }
            free(t);
            rtk_scene_release(s);
        }
        free(vs);
    }
    rtk_device_release(dev);
}

/* ---- a refitted tree ---- */

/* The walk keeps each leaf block's oriented box from the tree's first
 * query (block_bounds.h); a refit moves the blocks, so it must drop them:
 * queries before and after the ball turns inside out and moves, every
 * backend, the layouts of leaf blocks (default, robust). */
static void test_refit(void **state)
{
    (void)state;
    char names[8][32];
    const size_t nb = test_backend_names(names, 8);
    float *v = malloc(ball.nv * 3 * sizeof *v);
    assert_non_null(v);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (unsigned robust = 0; robust < 2; robust++) {
            memcpy(v, ball.v, ball.nv * 3 * sizeof *v);
            rtk_scene s;
            assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
            assert_int_equal(rtk_scene_set_flags(s, robust ? RTK_SCENE_FLAG_ROBUST : 0), RTK_OK);
            rtk_geometry g;
            assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
            assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, ball.nv), RTK_OK);
            assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, ball.idx, 0, 12, ball.nt),
                             RTK_OK);
            assert_int_equal(rtk_geometry_set_build_quality(g, RTK_BUILD_QUALITY_REFIT), RTK_OK);
            assert_int_equal(rtk_geometry_commit(g), RTK_OK);
            assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
            rtk_geometry_release(g);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            snprintf(where_buf, sizeof where_buf, "%s, refit, robust %u", names[b], robust);
            where = where_buf;
            for (int step = 0; step < 3; step++) {
                if (step) {
                    /* every vertex through the centre and out, moved by step */
                    for (size_t i = 0; i < ball.nv; i++) {
                        v[3 * i] = -0.5f * v[3 * i] + (float)step;
                        v[3 * i + 1] = -0.5f * v[3 * i + 1];
                        v[3 * i + 2] = -0.5f * v[3 * i + 2] - (float)step;
                    }
                    test_commit_moved(s, g);
                    rtk_scene_info info = {.struct_size = sizeof info};
                    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
                    assert_int_equal(info.refits, step);
                }
                tri_d *t = mesh_tris(v, ball.idx, ball.nt);
                check_points(s, t, ball.nt, robust, 1.0, 31 + step, test_sanitized() ? 60 : 300);
                free(t);
            }
            rtk_scene_release(s);
        }
        rtk_device_release(dev);
    }
    free(v);
}

/* ---- batches ---- */

static void test_batch(void **state)
{
    (void)state;
    rtk_device dev = test_device_threads("avx2", 2);
    rtk_scene s = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
    /* (40 pieces of 1,024 on the two threads, every answer written) */
    const size_t n = 40000;
    rtk_point_query *q = calloc(n, sizeof *q);
    rtk_point_hit *h = malloc(n * sizeof *h), one;
    assert_true(q && h);
    memset(h, 0xa5, n * sizeof *h); /* (an answer not written differs) */
    rng r = {77};
    /* random points, and (walked along the batch's curve next to each
     * other, each answer a hint for the next) points on vertices and edges,
     * where several triangles tie: the batch must pick the single call's */
    for (size_t i = 0; i < n; i++) {
        q[i] = (rtk_point_query){.x = rng_float(&r) * 4 - 2, .y = rng_float(&r) * 4 - 2, .z = rng_float(&r) * 4 - 2,
                                 .radius = i % 3 ? INFINITY : 0.2};
        const uint32_t *t = &ball.idx[3 * (rng_u32(&r) % ball.nt)];
        const float *a = &ball.v[3 * t[0]], *b = &ball.v[3 * t[1]];
        if (i % 5 == 4)
            q[i].x = a[0], q[i].y = a[1], q[i].z = a[2];
        else if (i % 5 == 3)
            q[i].x = 0.5 * a[0] + 0.5 * b[0], q[i].y = 0.5 * a[1] + 0.5 * b[1], q[i].z = 0.5 * a[2] + 0.5 * b[2];
    }
    q[100].x = NAN;
    q[200].radius = -1;
    q[300].z = INFINITY;
    q[400].time = 2.0f;
    assert_int_equal(rtk_closest_point_batch(s, q, h, n), RTK_OK);
    for (size_t i = 0; i < n; i++) {
        if (i == 100 || i == 200 || i == 300 || i == 400) {
            assert_true(isnan(h[i].distance) && h[i].geomID == RTK_INVALID_GEOMETRY_ID);
            assert_int_equal(rtk_closest_point(s, &q[i], &one), RTK_ERROR_INVALID_ARGUMENT);
            continue;
        }
        assert_int_equal(rtk_closest_point(s, &q[i], &one), RTK_OK);
        assert_memory_equal(&one, &h[i], sizeof one);
    }
    /* count 0; NULL arrays */
    assert_int_equal(rtk_closest_point_batch(s, NULL, NULL, 0), RTK_OK);
    assert_int_equal(rtk_closest_point_batch(s, NULL, h, 5), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_closest_point_batch(s, q, NULL, 5), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_closest_point_batch(NULL, q, h, 5), RTK_ERROR_INVALID_ARGUMENT);
    free(q);
    free(h);
    rtk_scene_release(s);
    rtk_device_release(dev);
}

/* ---- errors and empty scenes ---- */

static void test_errors(void **state)
{
    (void)state;
    rtk_device dev = default_device();
    rtk_scene s;
    rtk_point_hit h, before;
    memset(&before, 0x5a, sizeof before);
    const rtk_point_query good = {.radius = INFINITY};
    /* never committed; then empty */
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    h = before;
    assert_int_equal(rtk_closest_point(s, &good, &h), RTK_ERROR_INVALID_OPERATION);
    assert_memory_equal(&h, &before, sizeof h);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    assert_int_equal(rtk_closest_point(s, &good, &h), RTK_OK);
    assert_true(h.distance == INFINITY && h.geomID == RTK_INVALID_GEOMETRY_ID && h.primID == RTK_INVALID_GEOMETRY_ID &&
                h.instID == RTK_INVALID_GEOMETRY_ID);
    rtk_scene_release(s);
    /* bad queries: nothing written */
    s = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
    const rtk_point_query bad[] = {
        {.x = NAN, .radius = 1},      {.y = INFINITY, .radius = 1}, {.z = -INFINITY, .radius = 1},
        {.x = 0x1p65, .radius = 1},   {.radius = -1},               {.radius = NAN},
        {.radius = 1, .time = -0.5f}, {.radius = 1, .time = NAN},   {.radius = 1, .reserved = 1},
    };
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        h = before;
        assert_int_equal(rtk_closest_point(s, &bad[i], &h), RTK_ERROR_INVALID_ARGUMENT);
        assert_memory_equal(&h, &before, sizeof h);
        assert_non_null(strstr(rtk_device_get_error_message(dev), "rtk_closest_point"));
    }
    assert_int_equal(rtk_closest_point(s, NULL, &h), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_closest_point(s, &good, NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_closest_point(NULL, &good, &h), RTK_ERROR_INVALID_ARGUMENT);
    /* radius 0 away from the surface: nothing */
    assert_int_equal(rtk_closest_point(s, &(rtk_point_query){.x = 5}, &h), RTK_OK);
    assert_int_equal(h.geomID, RTK_INVALID_GEOMETRY_ID);
    rtk_scene_release(s);
    /* user geometry, directly and through an instance: refused */
    rtk_scene us = test_user_scene(dev);
    assert_int_equal(rtk_closest_point(us, &good, &h), RTK_ERROR_UNSUPPORTED);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "user geometry"));
    rtk_scene outer = test_instancing_scene(dev, us);
    assert_int_equal(rtk_scene_commit(outer), RTK_OK);
    assert_int_equal(rtk_closest_point(outer, &good, &h), RTK_ERROR_UNSUPPORTED);
    rtk_point_query qs[2] = {good, good};
    rtk_point_hit hs[2];
    assert_int_equal(rtk_closest_point_batch(outer, qs, hs, 2), RTK_ERROR_UNSUPPORTED);
    rtk_scene_release(outer);
    rtk_scene_release(us);
    assert_string_equal(rtk_error_name(RTK_ERROR_UNSUPPORTED), "RTK_ERROR_UNSUPPORTED");
    rtk_device_release(dev);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_triangle_routine), cmocka_unit_test(test_mesh_layouts),
        cmocka_unit_test(test_soup),             cmocka_unit_test(test_scales),
        cmocka_unit_test(test_double_precision), cmocka_unit_test(test_degenerate),
        cmocka_unit_test(test_quads),            cmocka_unit_test(test_instances),
        cmocka_unit_test(test_motion),           cmocka_unit_test(test_refit),
        cmocka_unit_test(test_batch),
        cmocka_unit_test(test_errors),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
