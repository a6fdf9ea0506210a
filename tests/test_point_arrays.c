/*
 * Closest points and occupancy over arrays (rtk_closest_point_arrays,
 * rtk_occupancy_arrays) against the same queries as records
 * (rtk_closest_point_batch, rtk_occupancy): float and double points,
 * packed and strided, points on vertices and edges (where triangles tie),
 * points not valid, a finite radius, a motion-blurred scene at a time
 * between its steps, a batch past the ordering's window of 2^20 points,
 * answers left NULL not written, and every bad argument with nothing
 * written.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "testlib.h"

static test_mesh ball;

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

/* n query points around the ball: in its box and beyond, on its vertices
 * and edges' midpoints, and (some of the last ones) not valid: NaN,
 * infinite, beyond +-2^64 */
static double *make_points(size_t n, uint64_t seed)
{
    double *p = malloc(3 * n * sizeof *p);
    assert_non_null(p);
    rng r = {seed};
    for (size_t i = 0; i < n; i++) {
        double *q = p + 3 * i;
        for (int a = 0; a < 3; a++)
            q[a] = (double)rng_float(&r) * 4 - 2 + (double)rng_float(&r) * 0x1p-30;
        const uint32_t *t = &ball.idx[3 * (rng_u32(&r) % ball.nt)];
        const float *va = &ball.v[3 * t[0]], *vb = &ball.v[3 * t[1]];
        for (int a = 0; a < 3; a++) {
            if (i % 5 == 4)
                q[a] = va[a];
            else if (i % 5 == 3)
                q[a] = 0.5 * va[a] + 0.5 * vb[a];
        }
    }
    if (n > 400) {
        p[3 * 100] = NAN;
        p[3 * 200 + 1] = INFINITY;
        p[3 * 300 + 2] = -0x1p65;
    }
    return p;
}

/* The layout of a test's points: float or double, packed or strided. */
typedef struct layout {
    int is_double;
    size_t stride; /* 0: packed */
} layout;

static const layout layouts[] = {{0, 0}, {1, 0}, {0, 20}, {1, 36}};

/* The points p (double, packed) in layout l: a buffer to free */
static void *lay_out(const double *p, size_t n, layout l)
{
    const size_t size = l.is_double ? 3 * sizeof(double) : 3 * sizeof(float), stride = l.stride ? l.stride : size;
    char *buf = malloc(n * stride + 8);
    assert_non_null(buf);
    memset(buf, 0x7f, n * stride + 8);
    for (size_t i = 0; i < n; i++)
        for (int a = 0; a < 3; a++) {
            if (l.is_double)
                memcpy(buf + i * stride + a * sizeof(double), &p[3 * i + a], sizeof(double));
            else {
                const float f = (float)p[3 * i + a];
                memcpy(buf + i * stride + a * sizeof(float), &f, sizeof f);
            }
        }
    return buf;
}

/* The point as the arrays hold it, read back as a double */
static void laid(const void *buf, size_t i, layout l, double out[3])
{
    const size_t size = l.is_double ? 3 * sizeof(double) : 3 * sizeof(float), stride = l.stride ? l.stride : size;
    const char *at = (const char *)buf + i * stride;
    for (int a = 0; a < 3; a++) {
        if (l.is_double)
            memcpy(&out[a], at + a * sizeof(double), sizeof(double));
        else {
            float f;
            memcpy(&f, at + a * sizeof(float), sizeof f);
            out[a] = f;
        }
    }
}

static int same_bits_d(double a, double b) { return memcmp(&a, &b, sizeof a) == 0; }
static int same_bits_f(float a, float b) { return memcmp(&a, &b, sizeof a) == 0; }

/* Every answer of the arrays against the records' for the same queries
 * (radius and time those of a) */
static void check_closest(rtk_scene s, const double *p, size_t n, layout l, double radius, float time)
{
    void *pts = lay_out(p, n, l);
    rtk_point_query *q = calloc(n, sizeof *q);
    rtk_point_hit *h = malloc(n * sizeof *h);
    const size_t fs = l.is_double ? sizeof(double) : sizeof(float);
    char *dist = malloc(n * fs), *cl = malloc(3 * n * fs);
    uint32_t *ids = malloc(3 * n * sizeof *ids);
    float *uv = malloc(2 * n * sizeof *uv), *nrm = malloc(3 * n * sizeof *nrm);
    assert_true(q && h && dist && cl && ids && uv && nrm);
    for (size_t i = 0; i < n; i++) {
        double x[3];
        laid(pts, i, l, x);
        q[i] = (rtk_point_query){.x = x[0], .y = x[1], .z = x[2], .radius = radius, .time = time};
    }
    assert_int_equal(rtk_closest_point_batch(s, q, h, n), RTK_OK);
    const rtk_point_arrays a = {.points = pts, .points_double = l.is_double, .point_stride = l.stride,
                                .radius = radius, .time = time, .distances = dist, .closest = cl,
                                .geom_ids = ids, .prim_ids = ids + n, .inst_ids = ids + 2 * n, .uvs = uv,
                                .normals = nrm};
    assert_int_equal(rtk_closest_point_arrays(s, &a, n), RTK_OK);
    size_t found = 0;
    for (size_t i = 0; i < n; i++) {
        const rtk_point_hit *r = &h[i];
        found += r->geomID != RTK_INVALID_GEOMETRY_ID;
        const double c[3] = {r->x, r->y, r->z};
        if (l.is_double) {
            const double *d = (const double *)(void *)dist, *cc = (const double *)(void *)cl;
            if (!same_bits_d(d[i], r->distance))
                fail_msg("point %zu (double, stride %zu): distance %.17g, the batch's %.17g", i, l.stride, d[i],
                         r->distance);
            for (int k = 0; k < 3; k++)
                assert_true(same_bits_d(cc[3 * i + k], c[k]));
        } else {
            const float *d = (const float *)(void *)dist, *cc = (const float *)(void *)cl;
            if (!same_bits_f(d[i], (float)r->distance))
                fail_msg("point %zu (float, stride %zu): distance %.9g, the batch's %.9g", i, l.stride,
                         (double)d[i], r->distance);
            for (int k = 0; k < 3; k++)
                assert_true(same_bits_f(cc[3 * i + k], (float)c[k]));
        }
        assert_int_equal(ids[i], r->geomID);
        assert_int_equal(ids[n + i], r->primID);
        assert_int_equal(ids[2 * n + i], r->instID);
        assert_true(same_bits_f(uv[2 * i], r->u) && same_bits_f(uv[2 * i + 1], r->v));
        assert_true(same_bits_f(nrm[3 * i], r->n_x) && same_bits_f(nrm[3 * i + 1], r->n_y) &&
                    same_bits_f(nrm[3 * i + 2], r->n_z));
    }
    /* (the test means something: the points on vertices and edges, two
     * in five, and others found the surface; with no radius, all valid) */
    assert_true(found >= (radius == INFINITY ? n - 3 : 2 * n / 5));
    free(pts);
    free(q);
    free(h);
    free(dist);
    free(cl);
    free(ids);
    free(uv);
    free(nrm);
}

static void test_closest_matches_records(void **state)
{
    (void)state;
    rtk_device dev = test_device_threads("avx2", 2);
    const size_t n = 5000;
    double *p = make_points(n, 5);
    for (int robust = 0; robust < 2; robust++) {
        rtk_scene s = test_scene_flags(dev, ball.v, ball.nv, ball.idx, ball.nt, robust ? RTK_SCENE_FLAG_ROBUST : 0);
        for (size_t k = 0; k < sizeof layouts / sizeof *layouts; k++) {
            check_closest(s, p, n, layouts[k], INFINITY, 0.0f);
            check_closest(s, p, n, layouts[k], 0.3, 0.0f);
        }
        /* the invalid points: NaN distance, the invalid ids */
        float d[400], xyz[3 * 400];
        uint32_t g[400];
        for (size_t i = 0; i < 400; i++)
            for (int a = 0; a < 3; a++)
                xyz[3 * i + a] = (float)p[3 * i + a];
        const rtk_point_arrays a = {.points = xyz, .radius = INFINITY, .distances = d, .geom_ids = g};
        assert_int_equal(rtk_closest_point_arrays(s, &a, 400), RTK_OK);
        assert_true(isnan(d[100]) && isnan(d[200]) && isnan(d[300]) && g[100] == RTK_INVALID_GEOMETRY_ID &&
                    g[200] == RTK_INVALID_GEOMETRY_ID && g[300] == RTK_INVALID_GEOMETRY_ID);
        assert_true(d[0] >= 0.0f && d[0] < INFINITY && g[0] == 0);
        rtk_scene_release(s);
    }
    free(p);
    rtk_device_release(dev);
}

/* The time reaches the walk: a ball moving along x, at times between its
 * steps */
static void test_closest_motion(void **state)
{
    (void)state;
    rtk_device dev = test_device_threads("avx2", 2);
    float *vs = malloc(2 * ball.nv * 3 * sizeof *vs);
    assert_non_null(vs);
    for (size_t i = 0; i < 3 * ball.nv; i++) {
        vs[i] = ball.v[i];
        vs[3 * ball.nv + i] = ball.v[i] + (i % 3 == 0 ? 3.0f : 0.0f);
    }
    rtk_scene s;
    rtk_geometry g;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_time_step_count(g, 2), RTK_OK);
    for (unsigned k = 0; k < 2; k++)
        assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, k, vs + k * ball.nv * 3, 0,
                                                             12, ball.nv),
                         RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, ball.idx, 0, 12, ball.nt), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
    rtk_geometry_release(g);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    const size_t n = 2000;
    double *p = make_points(n, 9);
    check_closest(s, p, n, layouts[0], INFINITY, 0.37f);
    check_closest(s, p, n, layouts[1], INFINITY, 1.0f);
    /* the ball's centre at time 0.5 lies 1.5 along x: a point there is
     * inside it, 0.9-1.1 (its bumps) from its surface less its facets'
     * depth; at time 0 the ball reaches x = 1.1 */
    const float c[3] = {1.5f, 0.0f, 0.0f};
    float d0, d5;
    rtk_point_arrays a = {.points = c, .radius = INFINITY, .time = 0.5f, .distances = &d5};
    assert_int_equal(rtk_closest_point_arrays(s, &a, 1), RTK_OK);
    a.time = 0.0f;
    a.distances = &d0;
    assert_int_equal(rtk_closest_point_arrays(s, &a, 1), RTK_OK);
    assert_true(d5 > 0.7f && d5 < 1.2f && d0 > 0.3f && d0 < 0.6f);
    free(p);
    free(vs);
    rtk_scene_release(s);
    rtk_device_release(dev);
}

/* Past the ordering's window (2^20 points, core/point_query.c): every
 * window's answers go to its own points */
static void test_closest_windows(void **state)
{
    (void)state;
    if (test_sanitized())
        skip(); /* (two million queries; the plain build runs the same code) */
    rtk_device dev = test_device_threads("avx2", 2);
    rtk_scene s = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
    const size_t n = ((size_t)1 << 20) + 3001;
    double *p = make_points(n, 13);
    check_closest(s, p, n, layouts[0], INFINITY, 0.0f);
    free(p);
    rtk_scene_release(s);
    rtk_device_release(dev);
}

/* Answers left NULL are not written; the others are */
static void test_closest_some_answers(void **state)
{
    (void)state;
    rtk_device dev = test_device_threads("avx2", 1);
    rtk_scene s = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
    const float pts[2][3] = {{3, 0, 0}, {0, 0.1f, 2}};
    uint32_t prim[2] = {7, 7};
    float nrm[6];
    memset(nrm, 0x5a, sizeof nrm);
    const rtk_point_arrays a = {.points = pts, .radius = INFINITY, .prim_ids = prim};
    assert_int_equal(rtk_closest_point_arrays(s, &a, 2), RTK_OK);
    rtk_point_query q = {.x = 3, .radius = INFINITY};
    rtk_point_hit h;
    assert_int_equal(rtk_closest_point(s, &q, &h), RTK_OK);
    assert_int_equal(prim[0], h.primID);
    assert_true(prim[1] != 7 && prim[1] < ball.nt);
    for (int k = 0; k < 6; k++) {
        float f;
        memset(&f, 0x5a, sizeof f);
        assert_true(same_bits_f(nrm[k], f));
    }
    rtk_scene_release(s);
    rtk_device_release(dev);
}

/* Occupancy: the arrays against the records, on a closed robust ball */
static void test_occupancy_matches_records(void **state)
{
    (void)state;
    rtk_device dev = test_device_threads("avx2", 2);
    rtk_scene s = test_scene_flags(dev, ball.v, ball.nv, ball.idx, ball.nt, RTK_SCENE_FLAG_ROBUST);
    const size_t n = 5000;
    double *p = make_points(n, 21);
    uint8_t *want = malloc(n), *got = malloc(n);
    rtk_point_query *q = calloc(n, sizeof *q);
    assert_true(want && got && q);
    for (size_t k = 0; k < sizeof layouts / sizeof *layouts; k++) {
        const layout l = layouts[k];
        void *pts = lay_out(p, n, l);
        for (size_t i = 0; i < n; i++) {
            double x[3];
            laid(pts, i, l, x);
            q[i] = (rtk_point_query){.x = x[0], .y = x[1], .z = x[2], .time = 0.0f};
        }
        assert_int_equal(rtk_occupancy(s, q, n, want), RTK_OK);
        memset(got, 7, n);
        /* (radius plays no part: NaN is not refused here) */
        const rtk_point_arrays a = {.points = pts, .points_double = l.is_double, .point_stride = l.stride,
                                    .radius = NAN, .inside = got};
        assert_int_equal(rtk_occupancy_arrays(s, &a, n), RTK_OK);
        size_t in = 0;
        for (size_t i = 0; i < n; i++) {
            if (got[i] != want[i])
                fail_msg("point %zu (%s, stride %zu): inside %u, the records' %u", i, l.is_double ? "double" : "float",
                         l.stride, got[i], want[i]);
            in += got[i] == 1;
        }
        assert_int_equal(got[100], RTK_OCCUPANCY_INVALID);
        assert_int_equal(got[300], RTK_OCCUPANCY_INVALID);
        /* (inside and outside both met: the vertices' points are on it) */
        assert_true(in > n / 5 && in < n);
        free(pts);
    }
    free(p);
    free(want);
    free(got);
    free(q);
    rtk_scene_release(s);
    rtk_device_release(dev);
}

/* Bad arguments: the error, a message naming the call, nothing written */
static void test_errors(void **state)
{
    (void)state;
    rtk_device dev = test_device_threads("avx2", 1);
    rtk_scene s = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
    _Alignas(16) double buf[16] = {0};
    float dist[4] = {9, 9, 9, 9};
    uint8_t in[4] = {9, 9, 9, 9};
    const rtk_point_arrays good = {.points = buf, .radius = INFINITY, .distances = dist, .inside = in};
    rtk_point_arrays bad[10];
    for (int k = 0; k < 10; k++)
        bad[k] = good;
    bad[0].points = NULL;
    bad[1].points = (const char *)buf + 2;     /* float, not aligned to 4 */
    bad[2].points = (const char *)buf + 4;     /* double, not aligned to 8 */
    bad[2].points_double = 1;
    bad[3].point_stride = 8;                    /* below three floats */
    bad[4].point_stride = 14;                   /* not a multiple of 4 */
    bad[5].time = 1.5f;
    bad[6].time = NAN;
    bad[7].points_double = 1, bad[7].point_stride = 16; /* below three doubles */
    bad[8].radius = -1.0;                       /* closest points only */
    bad[9].radius = NAN;
    for (int k = 0; k < 10; k++) {
        const int closest_only = k >= 8;
        assert_int_equal(rtk_closest_point_arrays(s, &bad[k], 2), RTK_ERROR_INVALID_ARGUMENT);
        assert_non_null(strstr(rtk_device_get_error_message(dev), "rtk_closest_point_arrays"));
        assert_int_equal(rtk_occupancy_arrays(s, &bad[k], 2), closest_only ? RTK_OK : RTK_ERROR_INVALID_ARGUMENT);
        if (closest_only) {
            in[0] = in[1] = 9;
            continue;
        }
        assert_non_null(strstr(rtk_device_get_error_message(dev), "rtk_occupancy_arrays"));
        assert_true(dist[0] == 9 && dist[1] == 9 && in[0] == 9 && in[1] == 9);
    }
    rtk_point_arrays no_inside = good;
    no_inside.inside = NULL;
    assert_int_equal(rtk_occupancy_arrays(s, &no_inside, 2), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_closest_point_arrays(s, NULL, 2), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_occupancy_arrays(s, NULL, 2), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_closest_point_arrays(NULL, &good, 2), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_occupancy_arrays(NULL, &good, 2), RTK_ERROR_INVALID_ARGUMENT);
    /* count 0: nothing to read */
    assert_int_equal(rtk_closest_point_arrays(s, &bad[0], 0), RTK_OK);
    assert_int_equal(rtk_occupancy_arrays(s, &bad[0], 0), RTK_OK);
    assert_true(dist[0] == 9 && in[0] == 9);
    /* a scene never committed */
    rtk_scene fresh;
    assert_int_equal(rtk_scene_new(dev, &fresh), RTK_OK);
    assert_int_equal(rtk_closest_point_arrays(fresh, &good, 2), RTK_ERROR_INVALID_OPERATION);
    assert_int_equal(rtk_occupancy_arrays(fresh, &good, 2), RTK_ERROR_INVALID_OPERATION);
    assert_true(dist[0] == 9 && in[0] == 9);
    rtk_scene_release(fresh);
    /* user geometry without a point query function: refused */
    rtk_scene us = test_user_scene(dev);
    assert_int_equal(rtk_closest_point_arrays(us, &good, 2), RTK_ERROR_UNSUPPORTED);
    assert_int_equal(rtk_occupancy_arrays(us, &good, 2), RTK_ERROR_UNSUPPORTED);
    rtk_scene_release(us);
    rtk_scene_release(s);
    rtk_device_release(dev);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_closest_matches_records), cmocka_unit_test(test_closest_motion),
        cmocka_unit_test(test_closest_windows),         cmocka_unit_test(test_closest_some_answers),
        cmocka_unit_test(test_occupancy_matches_records), cmocka_unit_test(test_errors),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
