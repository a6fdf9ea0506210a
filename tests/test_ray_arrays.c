/*
 * Rays in array form (rtk_intersect_arrays, rtk_occluded_arrays) against
 * rtk_intersect1 / rtk_occluded1 on the same rays, bit for bit: float and
 * double rays, packed and strided, as they come and as an image's rows
 * (row_length: 4x2 blocks through the packets, ragged edges and a last
 * row cut short included), on every backend and on two threads;
 * invalid rays (NaN, infinite, zero direction) as misses, answers left
 * NULL unwritten, tnear and tfar, and the errors.
 */
#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "testlib.h"

static test_mesh ball;

static int setup(void **state)
{
    (void)state;
    ball = test_ball(24);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    free(ball.v);
    free(ball.idx);
    return 0;
}

/* n rays: most from around the ball toward it, some missing, some invalid. */
static void make_rays(double *r, size_t n, uint64_t seed)
{
    rng g = {seed};
    for (size_t i = 0; i < n; i++) {
        double *x = &r[6 * i];
        for (int k = 0; k < 3; k++) {
            x[k] = rng_float(&g) * 6 - 3;
            x[3 + k] = -x[k] * 0.5 + (rng_float(&g) - 0.5) * (i % 4 ? 0.5 : 4.0);
        }
        switch (i % 97) {
        case 5: x[0] = NAN; break;
        case 6: x[4] = INFINITY; break;
        case 7: x[3] = x[4] = x[5] = 0.0; break;
        case 8: x[5] = -0.0, x[3] = 0.0, x[4] = 1.0; break;
        default: break;
        }
    }
}

/* Camera rays: one origin, a w x h grid of directions over the ball,
 * row by row (what the packet kernels get, eight at a time), some missing;
 * every 37th ray's origin moved (its group then goes through the stream). */
static void make_camera_rays(double *r, int w, int h)
{
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            double *q = &r[6 * ((size_t)y * (size_t)w + (size_t)x)];
            q[0] = 0.3, q[1] = -0.2, q[2] = 4.0;
            q[3] = -0.3 + 2.6 * (x + 0.5) / w - 1.3, q[4] = 0.2 + 2.6 * (y + 0.5) / h - 1.3, q[5] = -4.0;
            if ((y * w + x) % 37 == 36)
                q[0] += 0.01;
        }
}

static rtk_rayhit as_rayhit(const double *x, float tnear, float tfar)
{
    return (rtk_rayhit){.ray = {.org_x = (float)x[0], .org_y = (float)x[1], .org_z = (float)x[2], .tnear = tnear,
                                .dir_x = (float)x[3], .dir_y = (float)x[4], .dir_z = (float)x[5], .tfar = tfar,
                                .mask = ~0u},
                        .hit = {.primID = RTK_INVALID_GEOMETRY_ID, .geomID = RTK_INVALID_GEOMETRY_ID,
                                .instID = RTK_INVALID_GEOMETRY_ID}};
}

/* The arrays' answers for rays r (as doubles; float_stride: 0 to pass
 * them as double, above 0 as floats that many floats apart, below 0 as
 * doubles -float_stride floats apart (so -13: 4 bytes past six doubles,
 * every other ray's doubles not aligned to 8); row: their row_length)
 * against the single-ray calls: each ray answered, and as alone. */
static void check(rtk_scene s, const double *r, size_t n, int float_stride, float tnear, float tfar, size_t row)
{
    float *fr = NULL;
    rtk_ray_arrays a = {.rays = r, .rays_double = 1, .tnear = tnear, .tfar = tfar, .row_length = row};
    if (float_stride < 0) {
        const size_t stride = (size_t)-float_stride * sizeof(float);
        fr = calloc(n, stride);
        assert_non_null(fr);
        for (size_t i = 0; i < n; i++)
            memcpy((char *)fr + i * stride, &r[6 * i], 6 * sizeof(double));
        a.rays = fr;
        a.ray_stride = stride;
    } else if (float_stride) {
        fr = calloc(n * (size_t)float_stride, sizeof *fr);
        assert_non_null(fr);
        for (size_t i = 0; i < n; i++)
            for (int k = 0; k < 6; k++)
                fr[i * (size_t)float_stride + (size_t)k] = (float)r[6 * i + (size_t)k];
        a = (rtk_ray_arrays){.rays = fr, .ray_stride = float_stride == 6 ? 0 : (size_t)float_stride * sizeof(float),
                             .tnear = tnear, .tfar = tfar, .row_length = row};
    }
    float *t = malloc(n * sizeof *t), *uv = malloc(2 * n * sizeof *uv), *ng = malloc(3 * n * sizeof *ng);
    uint32_t *g = malloc(n * sizeof *g), *p = malloc(n * sizeof *p), *in = malloc(n * sizeof *in);
    uint8_t *occ = malloc(n);
    assert_true(t && uv && ng && g && p && in && occ);
    memset(occ, 7, n);
    /* (a ray left out would keep these: NaN t, ids no answer has) */
    memset(t, 0xff, n * sizeof *t);
    memset(g, 0x5a, n * sizeof *g);
    a.t_hit = t, a.geom_ids = g, a.prim_ids = p, a.inst_ids = in, a.uvs = uv, a.normals = ng, a.occluded = occ;
    assert_int_equal(rtk_intersect_arrays(s, &a, n), RTK_OK);
    assert_int_equal(rtk_occluded_arrays(s, &a, n), RTK_OK);
    size_t hits = 0;
    for (size_t i = 0; i < n; i++) {
        rtk_rayhit rh = as_rayhit(&r[6 * i], tnear, tfar);
        rtk_ray ray = rh.ray;
        const rtk_error e1 = rtk_intersect1(s, &rh), e2 = rtk_occluded1(s, &ray);
        const int valid = e1 == RTK_OK;
        assert_int_equal(e1, e2);
        const int hit = valid && rh.hit.geomID != RTK_INVALID_GEOMETRY_ID;
        hits += (size_t)hit;
        if (!hit) {
            if (!(t[i] == INFINITY && g[i] == RTK_INVALID_GEOMETRY_ID && p[i] == RTK_INVALID_GEOMETRY_ID &&
                  uv[2 * i] == 0.0f && uv[2 * i + 1] == 0.0f && ng[3 * i] == 0.0f && ng[3 * i + 2] == 0.0f))
                fail_msg("ray %zu: a miss, the arrays say t %g geom %u", i, (double)t[i], g[i]);
        } else {
            assert_memory_equal(&t[i], &rh.ray.tfar, sizeof(float));
            assert_int_equal(g[i], rh.hit.geomID);
            assert_int_equal(p[i], rh.hit.primID);
            assert_int_equal(in[i], rh.hit.instID);
            assert_memory_equal(&uv[2 * i], &rh.hit.u, sizeof(float));
            assert_memory_equal(&uv[2 * i + 1], &rh.hit.v, sizeof(float));
            const double len = sqrt((double)rh.hit.Ng_x * rh.hit.Ng_x + (double)rh.hit.Ng_y * rh.hit.Ng_y +
                                    (double)rh.hit.Ng_z * rh.hit.Ng_z);
            assert_true(fabs(ng[3 * i] - rh.hit.Ng_x / len) < 1e-6 && fabs(ng[3 * i + 1] - rh.hit.Ng_y / len) < 1e-6 &&
                        fabs(ng[3 * i + 2] - rh.hit.Ng_z / len) < 1e-6);
        }
        assert_int_equal(occ[i], valid && ray.tfar == -INFINITY);
    }
    assert_true(hits > n / 4 && hits < n); /* the rays do hit, and miss */
    free(fr);
    free(t);
    free(uv);
    free(ng);
    free(g);
    free(p);
    free(in);
    free(occ);
}

static void test_against_single(void **state)
{
    (void)state;
    char names[8][32];
    const size_t nb = test_backend_names(names, 8);
    const size_t n = 3000;
    double *r = malloc(6 * n * sizeof *r);
    assert_non_null(r);
    make_rays(r, n, 3);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene s = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
        check(s, r, n, 0, 0.0f, INFINITY, 0);
        check(s, r, n, 6, 0.0f, INFINITY, 0);
        check(s, r, n, 7, 0.5f, 3.0f, 0); /* strided, and a window along the rays */
        check(s, r, n, -13, 0.0f, INFINITY, 0); /* doubles strided */
        check(s, r, n, 6, 0.0f, INFINITY, 3);        /* rows too narrow for a block: as they come */
        check(s, r, n, 6, 0.0f, INFINITY, n / 2 + 1); /* not two rows: as they come */
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
    free(r);
}

/* Coherent rays (eight of one origin and octant at a time go through the
 * packet kernels): the single-ray answers all the same, on every backend,
 * robust and not. */
static void test_camera_rays(void **state)
{
    (void)state;
    char names[8][32];
    const size_t nb = test_backend_names(names, 8);
    const int w = 64, h = 48;
    double *r = malloc(6 * (size_t)(w * h) * sizeof *r);
    assert_non_null(r);
    make_camera_rays(r, w, h);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (int robust = 0; robust < 2; robust++) {
            rtk_scene s =
                test_scene_flags(dev, ball.v, ball.nv, ball.idx, ball.nt, robust ? RTK_SCENE_FLAG_ROBUST : 0);
            check(s, r, (size_t)(w * h), 6, 0.0f, INFINITY, 0);
            check(s, r, (size_t)(w * h), 0, 0.0f, 4.2f, 0); /* as doubles; a window that cuts the ball */
            check(s, r, (size_t)(w * h), 6, 0.0f, INFINITY, (size_t)w); /* as rows: 4x2 blocks */
            check(s, r, (size_t)(w * h), 7, 0.0f, 4.2f, (size_t)w);
            check(s, r, (size_t)(w * h), -13, 0.0f, 4.2f, (size_t)w); /* doubles strided, as rows */
            /* a width not a multiple of 4, an odd number of rows, the last
             * one cut short: the blocks' leftovers */
            check(s, r, (size_t)(61 * 47 - 5), 6, 0.0f, INFINITY, 61);
            check(s, r, (size_t)(61 * 47 - 5), 0, 0.0f, INFINITY, 61);
            rtk_scene_release(s);
        }
        rtk_device_release(dev);
    }
    free(r);
}

/* Two threads over more rays than a task's piece, robust and not. */
static void test_threads(void **state)
{
    (void)state;
    const size_t n = 20000;
    double *r = malloc(6 * n * sizeof *r);
    assert_non_null(r);
    make_rays(r, n, 9);
    rtk_device dev = test_device_threads("avx2", 2);
    for (int robust = 0; robust < 2; robust++) {
        rtk_scene s =
            test_scene_flags(dev, ball.v, ball.nv, ball.idx, ball.nt, robust ? RTK_SCENE_FLAG_ROBUST : 0);
        check(s, r, n, 6, 0.0f, INFINITY, 0);
        rtk_scene_release(s);
    }
    /* rows over several pieces (12 rows of 300 a piece), the last cut short */
    const int w = 300, h = 41;
    double *c = malloc(6 * (size_t)(w * h) * sizeof *c);
    assert_non_null(c);
    make_camera_rays(c, w, h);
    for (int robust = 0; robust < 2; robust++) {
        rtk_scene s =
            test_scene_flags(dev, ball.v, ball.nv, ball.idx, ball.nt, robust ? RTK_SCENE_FLAG_ROBUST : 0);
        check(s, c, (size_t)(w * h) - 7, 6, 0.0f, INFINITY, (size_t)w);
        rtk_scene_release(s);
    }
    free(c);
    rtk_device_release(dev);
    free(r);
}

/* Answers left NULL are not written; the rest are. */
static void test_some_answers(void **state)
{
    (void)state;
    rtk_device dev = test_device("avx2");
    rtk_scene s = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
    const float rays[2][6] = {{0, 0, 5, 0, 0, -1}, {0, 0, 5, 0, 0, 1}};
    uint32_t prim[2] = {7, 7};
    rtk_ray_arrays a = {.rays = rays, .tfar = INFINITY, .prim_ids = prim};
    assert_int_equal(rtk_intersect_arrays(s, &a, 2), RTK_OK);
    assert_true(prim[0] != RTK_INVALID_GEOMETRY_ID && prim[1] == RTK_INVALID_GEOMETRY_ID);
    /* nothing asked for: nothing written, and no failure */
    a.prim_ids = NULL;
    assert_int_equal(rtk_intersect_arrays(s, &a, 2), RTK_OK);
    rtk_scene_release(s);
    rtk_device_release(dev);
}

static void test_errors(void **state)
{
    (void)state;
    rtk_device dev = test_device("avx2");
    rtk_scene s = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
    double rays[2][6] = {{0, 0, 5, 0, 0, -1}, {0, 0, 5, 0, 0, 1}};
    float t[2] = {1, 2};
    uint8_t occ[2] = {3, 3};
    rtk_ray_arrays a = {.rays = rays, .rays_double = 1, .tfar = INFINITY, .t_hit = t};
    assert_int_equal(rtk_intersect_arrays(NULL, &a, 2), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_intersect_arrays(s, NULL, 2), RTK_ERROR_INVALID_ARGUMENT);
    a.rays = NULL;
    assert_int_equal(rtk_intersect_arrays(s, &a, 2), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_intersect_arrays(s, &a, 0), RTK_OK); /* nothing to do */
    a.rays = (const char *)rays + 4; /* doubles aligned to 4, not 8 */
    assert_int_equal(rtk_intersect_arrays(s, &a, 1), RTK_ERROR_INVALID_ARGUMENT);
    a.rays = rays;
    a.ray_stride = 40; /* below six doubles */
    assert_int_equal(rtk_intersect_arrays(s, &a, 2), RTK_ERROR_INVALID_ARGUMENT);
    a.ray_stride = 50; /* not a multiple of 4 */
    assert_int_equal(rtk_intersect_arrays(s, &a, 2), RTK_ERROR_INVALID_ARGUMENT);
    a.ray_stride = 0;
    a.tnear = 2.0f, a.tfar = 1.0f;
    assert_int_equal(rtk_intersect_arrays(s, &a, 2), RTK_ERROR_INVALID_ARGUMENT);
    a.tnear = -1.0f, a.tfar = 1.0f;
    assert_int_equal(rtk_intersect_arrays(s, &a, 2), RTK_ERROR_INVALID_ARGUMENT);
    a.tnear = 0.0f, a.tfar = NAN;
    assert_int_equal(rtk_intersect_arrays(s, &a, 2), RTK_ERROR_INVALID_ARGUMENT);
    assert_true(t[0] == 1 && t[1] == 2); /* nothing written */
    a.tfar = INFINITY;
    assert_int_equal(rtk_occluded_arrays(s, &a, 2), RTK_ERROR_INVALID_ARGUMENT); /* occluded NULL */
    a.occluded = occ;
    assert_int_equal(rtk_occluded_arrays(s, &a, 2), RTK_OK);
    assert_true(occ[0] == 1 && occ[1] == 0);
    rtk_scene_release(s);
    /* a scene never committed */
    rtk_scene empty;
    assert_int_equal(rtk_scene_new(dev, &empty), RTK_OK);
    assert_int_equal(rtk_intersect_arrays(empty, &a, 2), RTK_ERROR_INVALID_OPERATION);
    /* committed with nothing in it: every ray misses */
    assert_int_equal(rtk_scene_commit(empty), RTK_OK);
    assert_int_equal(rtk_intersect_arrays(empty, &a, 2), RTK_OK);
    assert_true(t[0] == INFINITY && t[1] == INFINITY);
    rtk_scene_release(empty);
    rtk_device_release(dev);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_against_single),
        cmocka_unit_test(test_camera_rays),
        cmocka_unit_test(test_threads),
        cmocka_unit_test(test_some_answers),
        cmocka_unit_test(test_errors),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
