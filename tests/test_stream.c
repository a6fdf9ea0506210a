/*
 * Streams and batches (rtk_intersect1M, rtk_occluded1M, their _ctx forms,
 * rtk_intersect_batch, rtk_occluded_batch): bad arguments refused with
 * nothing written, invalid rays in the middle of a stream left as the
 * single call leaves them, filters that reject every hit, empty scenes,
 * instances, the application's task system, and several application
 * threads streaming through one scene at once (run under ThreadSanitizer
 * by scripts/test).  The conformance suite compares every backend's and
 * layout's streams with its single rays on the shared meshes.
 */
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "testlib.h"

/* A ball of 2 * 24^2 triangles and rays from around it: half towards its
 * middle (most hit), half in random directions from random points in its
 * box (scattered: the interleaved traversal's). */
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

static void make_rays(rtk_rayhit *rh, size_t n, uint64_t seed)
{
    rng r = {seed};
    for (size_t i = 0; i < n; i++) {
        float o[3], d[3];
        for (int k = 0; k < 3; k++) {
            o[k] = 4.0f * rng_float(&r) - 2.0f;
            d[k] = i % 2 ? 2.0f * rng_float(&r) - 1.0f : 0.3f * rng_float(&r) - 0.15f - o[k];
        }
        rh[i] = (rtk_rayhit){.ray = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY)};
        rh[i].hit.geomID = rh[i].hit.primID = rh[i].hit.instID = RTK_INVALID_GEOMETRY_ID;
    }
}

/* rh[0 .. n) through the single calls into one, as streams into many: the
 * same records, to the bit (many: n records `stride` bytes apart). */
static void expect_same(rtk_scene s, const rtk_rayhit *rh, size_t n, int occluded, const rtk_query_context *ctx)
{
    const size_t size = occluded ? sizeof(rtk_ray) : sizeof(rtk_rayhit), stride = size + 8;
    rtk_rayhit *one = malloc(n * sizeof *one);
    unsigned char *many = malloc(n * stride);
    assert_true(one && many);
    memset(many, 0x5a, n * stride);
    for (size_t i = 0; i < n; i++) {
        one[i] = rh[i];
        memcpy(many + i * stride, &rh[i], size);
        assert_int_equal(occluded ? rtk_occluded1_ctx(s, &one[i].ray, ctx) : rtk_intersect1_ctx(s, &one[i], ctx),
                         RTK_OK);
    }
    assert_int_equal(occluded ? rtk_occluded1M_ctx(s, (rtk_ray *)(void *)many, (uint32_t)n, stride, ctx)
                              : rtk_intersect1M_ctx(s, (rtk_rayhit *)(void *)many, (uint32_t)n, stride, ctx),
                     RTK_OK);
    for (size_t i = 0; i < n; i++) {
        assert_memory_equal(many + i * stride, &one[i], size);
        for (size_t k = size; k < stride; k++)
            assert_int_equal(many[i * stride + k], 0x5a);
    }
    free(one);
    free(many);
}

static rtk_scene ball_scene(rtk_device dev)
{
    return test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
}

/* expect_same for both queries on the ball, on every backend. */
static void expect_same_everywhere(const rtk_rayhit *rh, size_t n)
{
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene s = ball_scene(dev);
        expect_same(s, rh, n, 0, NULL);
        expect_same(s, rh, n, 1, NULL);
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
}

/* Bad arguments: an error naming the problem, nothing written. */
static void test_bad_arguments(void **state)
{
    (void)state;
    rtk_device dev = test_device_threads("scalar", 1);
    rtk_scene s = ball_scene(dev);
    rtk_rayhit rh[4];
    make_rays(rh, 4, 1);
    rtk_rayhit before[4];
    memcpy(before, rh, sizeof rh);

    /* a count of 0 does nothing, whatever the array */
    assert_int_equal(rtk_intersect1M(s, NULL, 0, sizeof(rtk_rayhit)), RTK_OK);
    assert_int_equal(rtk_occluded1M(s, NULL, 0, 0), RTK_OK);
    assert_int_equal(rtk_intersect_batch(s, NULL, 0, 0, NULL), RTK_OK);

    assert_int_equal(rtk_intersect1M(NULL, rh, 4, sizeof(rtk_rayhit)), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_intersect1M(s, NULL, 4, sizeof(rtk_rayhit)), RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "rays is NULL"));
    assert_int_equal(rtk_intersect1M(s, rh, 4, sizeof(rtk_rayhit) - 4), RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "byte_stride"));
    assert_int_equal(rtk_occluded1M(s, &rh[0].ray, 4, sizeof(rtk_ray) - 4), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_intersect1M(s, rh, 4, sizeof(rtk_rayhit) + 2), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_intersect1M(s, (rtk_rayhit *)(void *)((char *)rh + 2), 2, sizeof(rtk_rayhit)),
                     RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "aligned"));
    assert_int_equal(rtk_occluded_batch(s, &rh[0].ray, 4, 3, NULL), RTK_ERROR_INVALID_ARGUMENT);
    /* an array that would run past the end of the address space */
    assert_int_equal(rtk_intersect1M(s, (rtk_rayhit *)(uintptr_t)(UINTPTR_MAX - 1023), 100, sizeof(rtk_rayhit)),
                     RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "address space"));
    assert_int_equal(rtk_intersect_batch(s, rh, SIZE_MAX / 2, SIZE_MAX / 4, NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_memory_equal(rh, before, sizeof rh);

    /* a scene never committed */
    rtk_scene fresh;
    assert_int_equal(rtk_scene_new(dev, &fresh), RTK_OK);
    assert_int_equal(rtk_intersect1M(fresh, rh, 4, sizeof(rtk_rayhit)), RTK_ERROR_INVALID_OPERATION);
    assert_int_equal(rtk_occluded_batch(fresh, &rh[0].ray, 4, sizeof(rtk_rayhit), NULL), RTK_ERROR_INVALID_OPERATION);
    assert_memory_equal(rh, before, sizeof rh);
    rtk_scene_release(fresh);
    rtk_scene_release(s);
    rtk_device_release(dev);
}

/* Invalid rays in the middle of a stream: each left untouched, as the
 * single call leaves it; the others get their single-ray answers.  On
 * every backend, long streams (past the kernels' measuring windows). */
static void test_invalid_rays_in_the_middle(void **state)
{
    (void)state;
    const size_t n = test_sanitized() ? 1000 : 5000;
    rtk_rayhit *rh = malloc(n * sizeof *rh);
    assert_non_null(rh);
    make_rays(rh, n, 2);
    for (size_t i = 0; i < n; i += 7) {
        rtk_ray *r = &rh[i].ray;
        switch (i / 7 % 8) {
        case 0: r->org_x = NAN; break;
        case 1: r->dir_z = INFINITY; break;
        case 2: r->tnear = 2.0f, r->tfar = 1.0f; break;
        case 3: r->tnear = -1.0f; break;
        case 4: r->tfar = NAN; break;
        case 5: r->mask = 0; break;
        case 6: r->dir_x = r->dir_y = r->dir_z = 0.0f; break;
        default: r->dir_y = -0.0f; break; /* valid */
        }
    }
    expect_same_everywhere(rh, n);
    free(rh);
}

static int reject_all(const rtk_filter_args *a)
{
    (void)a;
    return 0;
}

static int reject_odd_prims(const rtk_filter_args *a)
{
    int *calls = a->context ? a->context->user : NULL;
    if (calls)
        __atomic_add_fetch(calls, 1, __ATOMIC_RELAXED);
    return a->hit->primID % 2 == 0;
}

/* The ball with fn as its triangles' intersect and occluded filter,
 * committed. */
static rtk_scene filtered_ball(rtk_device dev, rtk_filter_fn fn)
{
    rtk_scene s = test_scene_uncommitted(dev, ball.v, ball.nv, ball.idx, ball.nt, 0);
    rtk_geometry g = rtk_scene_get_geometry(s, 0);
    assert_int_equal(rtk_geometry_set_intersect_filter(g, fn), RTK_OK);
    assert_int_equal(rtk_geometry_set_occluded_filter(g, fn), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    return s;
}

/* Filters: one that rejects every hit (every ray misses), and one that
 * rejects every odd triangle and counts its calls through the query's
 * context: the same answers, and as many calls, as the single calls. */
static void test_filters(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    const size_t n = 2000;
    rtk_rayhit *rh = malloc(n * sizeof *rh), *copy = malloc(n * sizeof *rh);
    assert_true(rh && copy);
    make_rays(rh, n, 3);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (int f = 0; f < 2; f++) {
            rtk_scene s = filtered_ball(dev, f ? reject_odd_prims : reject_all);
            int calls_one = 0, calls_many = 0;
            rtk_query_context c1 = {&calls_one}, cm = {&calls_many};
            for (int occluded = 0; occluded < 2; occluded++) {
                expect_same(s, rh, n, occluded, NULL);
                /* the calls, counted apart */
                memcpy(copy, rh, n * sizeof *rh);
                for (size_t i = 0; i < n; i++)
                    occluded ? rtk_occluded1_ctx(s, &copy[i].ray, &c1) : rtk_intersect1_ctx(s, &copy[i], &c1);
                memcpy(copy, rh, n * sizeof *rh);
                assert_int_equal(occluded ? rtk_occluded1M_ctx(s, &copy[0].ray, (uint32_t)n, sizeof *copy, &cm)
                                          : rtk_intersect1M_ctx(s, copy, (uint32_t)n, sizeof *copy, &cm),
                                 RTK_OK);
                assert_int_equal(calls_one, calls_many);
                if (!f)
                    for (size_t i = 0; i < n; i++)
                        assert_true(occluded ? copy[i].ray.tfar != -INFINITY
                                             : copy[i].hit.geomID == RTK_INVALID_GEOMETRY_ID);
            }
            if (f)
                assert_true(calls_one > 0);
            rtk_scene_release(s);
        }
        rtk_device_release(dev);
    }
    free(rh);
    free(copy);
}

/* An empty scene, instances of the ball (two levels, test_objects_stream),
 * and the stream kernels' report in rtk_scene_info. */
static void test_scenes(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    const size_t n = 1500;
    rtk_rayhit *rh = malloc(n * sizeof *rh);
    assert_non_null(rh);
    make_rays(rh, n, 4);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene empty;
        assert_int_equal(rtk_scene_new(dev, &empty), RTK_OK);
        assert_int_equal(rtk_scene_commit(empty), RTK_OK);
        expect_same(empty, rh, n, 0, NULL);
        expect_same(empty, rh, n, 1, NULL);
        rtk_scene inner = ball_scene(dev), outer = test_instancing_scene(dev, inner);
        assert_int_equal(rtk_scene_commit(outer), RTK_OK);
        expect_same(outer, rh, n, 0, NULL);
        expect_same(outer, rh, n, 1, NULL);
        rtk_scene_info info = {.struct_size = sizeof info};
        assert_int_equal(rtk_scene_get_info(inner, &info), RTK_OK);
        assert_true(info.stream_in_flight >= 4); /* every backend's triangle layouts have stream kernels */
        assert_int_equal(rtk_scene_get_info(outer, &info), RTK_OK);
        assert_true(info.stream_in_flight >= 4); /* through both levels */
        rtk_scene_release(outer);
        rtk_scene_release(inner);
        rtk_scene_release(empty);
        rtk_device_release(dev);
    }
    free(rh);
}

/* Coherent groups of rays grazing triangles' planes, which the stream
 * traces as packets: still rtk_intersect1's and rtk_occluded1's answers.
 * A ray nearly in a triangle's plane can get a rounded hit distance far
 * from the triangle (the ball's needle-thin pole triangles gave t = 32768
 * to a ray that reaches the ball at 54000), and such a hit must not depend
 * on the order in which a kernel visits the boxes (the hit floor,
 * traverse_bvhn.h), nor may the packet enter a box the ray alone would not
 * (box_intersect_octant).  Before both (rtk at 37cfadc), 68 to 88 of these
 * rays per backend got another closest hit as a stream than alone, and
 * with another seed 1 another any hit (avx2).  Each group: eight rays along one direction in one
 * triangle's plane through points on its edges and inside it, their
 * origins and directions a little off the plane; from the ball's needles
 * the origins lie thousands of units away. */
static void grazing_groups(rtk_rayhit *rh, size_t n, uint64_t seed)
{
    rng r = {seed};
    for (size_t g = 0; g + 8 <= n; g += 8) {
        const uint32_t t = (uint32_t)(rng_float(&r) * (float)ball.nt) % (uint32_t)ball.nt;
        float v[3][3], e1[3], e2[3], nrm[3];
        for (int c = 0; c < 3; c++)
            for (int k = 0; k < 3; k++)
                v[c][k] = ball.v[3 * ball.idx[3 * t + c] + k];
        for (int k = 0; k < 3; k++) {
            e1[k] = v[1][k] - v[0][k];
            e2[k] = v[2][k] - v[0][k];
        }
        nrm[0] = e1[1] * e2[2] - e1[2] * e2[1];
        nrm[1] = e1[2] * e2[0] - e1[0] * e2[2];
        nrm[2] = e1[0] * e2[1] - e1[1] * e2[0];
        const float area2 = sqrtf(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
        const float to_unit = area2 > 0.0f ? 1.0f / sqrtf(area2) : 1.0f; /* about 1 / the edges' length */
        const float to_normal = area2 > 0.0f ? 1.0f / area2 : 1.0f;
        /* a direction in the plane: a mix of the two edges */
        const float a = 2.0f * rng_float(&r) - 1.0f, b = 2.0f * rng_float(&r) - 1.0f;
        float d[3];
        for (int k = 0; k < 3; k++)
            d[k] = a * e1[k] + b * e2[k];
        const float back = 8.0f * (0.05f + 0.5f * rng_float(&r)); /* the origins this far back along -d */
        for (size_t i = g; i < g + 8; i++) {
            /* a point on an edge (every other ray) or inside */
            float w1 = rng_float(&r), w2 = rng_float(&r);
            if (w1 + w2 > 1.0f) {
                w1 = 1.0f - w1;
                w2 = 1.0f - w2;
            }
            if (i % 4 == 1)
                w1 = 0.0f;
            else if (i % 4 == 3)
                w2 = 0.0f;
            const float off = (rng_float(&r) - 0.5f) * 0x1p-12f, tilt = (rng_float(&r) - 0.5f) * 0x1p-14f;
            float o[3], dd[3];
            for (int k = 0; k < 3; k++) {
                const float p = v[0][k] + w1 * e1[k] + w2 * e2[k];
                o[k] = p - back * d[k] * to_unit + off * nrm[k] * to_normal;
                dd[k] = d[k] + tilt * nrm[k] * to_unit;
            }
            rh[i] = (rtk_rayhit){.ray = test_ray(o[0], o[1], o[2], dd[0], dd[1], dd[2], 0.0f, INFINITY)};
            rh[i].hit.geomID = rh[i].hit.primID = rh[i].hit.instID = RTK_INVALID_GEOMETRY_ID;
        }
    }
}

static void test_grazing_groups(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    const size_t n = test_sanitized() ? 8 * 1024 : 8 * 16384;
    rtk_rayhit *rh = malloc(n * sizeof *rh), *one = malloc(n * sizeof *one);
    assert_true(rh && one);
    grazing_groups(rh, n, 7);
    size_t failures = 0;
    static const unsigned layouts[] = {RTK_SCENE_FLAG_NONE, RTK_SCENE_FLAG_COMPACT, RTK_SCENE_FLAG_ROBUST};
    static const char *const layout_names[] = {"", " compact", " robust"};
    for (size_t b = 0; b < nb; b++) {
        for (size_t l = 0; l < 3; l++) {
            rtk_device dev = test_device(names[b]);
            rtk_scene s = test_scene_flags(dev, ball.v, ball.nv, ball.idx, ball.nt, layouts[l]);
            size_t nearer = 0, farther = 0, other = 0, hits = 0;
            memcpy(one, rh, n * sizeof *rh);
            for (size_t i = 0; i < n; i++)
                assert_int_equal(rtk_intersect1(s, &one[i]), RTK_OK);
            rtk_rayhit *many = malloc(n * sizeof *many);
            assert_non_null(many);
            memcpy(many, rh, n * sizeof *rh);
            assert_int_equal(rtk_intersect1M(s, many, (uint32_t)n, sizeof *many), RTK_OK);
            for (size_t i = 0; i < n; i++) {
                hits += one[i].hit.geomID != RTK_INVALID_GEOMETRY_ID;
                if (!memcmp(&many[i], &one[i], sizeof *many))
                    continue;
                if (many[i].ray.tfar < one[i].ray.tfar)
                    nearer++;
                else if (many[i].ray.tfar > one[i].ray.tfar)
                    farther++;
                else
                    other++;
                if (nearer + farther + other <= 4)
                    print_message("[%s%s] grazing ray %zu: t %a / %a, prim %u / %u (stream / single)\n", names[b],
                                  layout_names[l], i, many[i].ray.tfar, one[i].ray.tfar, many[i].hit.primID,
                                  one[i].hit.primID);
            }
            /* any hit: the same rays */
            size_t occ_differ = 0;
            rtk_ray *r1 = malloc(n * sizeof *r1), *rm = malloc(n * sizeof *rm);
            assert_true(r1 && rm);
            for (size_t i = 0; i < n; i++)
                r1[i] = rm[i] = rh[i].ray;
            for (size_t i = 0; i < n; i++)
                assert_int_equal(rtk_occluded1(s, &r1[i]), RTK_OK);
            assert_int_equal(rtk_occluded1M(s, rm, (uint32_t)n, sizeof *rm), RTK_OK);
            for (size_t i = 0; i < n; i++)
                if (memcmp(&r1[i], &rm[i], sizeof *rm)) {
                    if (occ_differ++ < 4)
                        print_message("[%s%s] grazing ray %zu occluded: tfar %a / %a (stream / single)\n", names[b],
                                      layout_names[l], i, rm[i].tfar, r1[i].tfar);
                }
            free(r1);
            free(rm);
            failures += occ_differ;
            print_message("[%s%s] %zu grazing rays in groups of 8, %zu hits: the stream's answer nearer than the "
                          "single call's in %zu, farther in %zu, otherwise different in %zu; any hit different "
                          "in %zu\n",
                          names[b], layout_names[l], n, hits, nearer, farther, other, occ_differ);
            failures += nearer + farther + other;
            free(many);
            rtk_scene_release(s);
            rtk_device_release(dev);
        }
    }
    free(rh);
    free(one);
    assert_int_equal(failures, 0);
}

/* n rays of one octant (every 16th with a -0.0 x direction). */
static void octant_rays(rtk_rayhit *rh, size_t n, uint64_t seed)
{
    rng r = {seed};
    for (size_t i = 0; i < n; i++) {
        float o[3], d[3];
        for (int k = 0; k < 3; k++) {
            o[k] = 4.0f * rng_float(&r) - 3.0f;
            d[k] = rng_float(&r) + 0x1p-8f;
        }
        if (i % 16 == 5)
            d[0] = -0.0f;
        rh[i] = (rtk_rayhit){.ray = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY)};
        rh[i].hit.geomID = rh[i].hit.primID = rh[i].hit.instID = RTK_INVALID_GEOMETRY_ID;
    }
}

/* Rays of one direction octant, which the any-hit stream may walk
 * together by masks (avx2: up to 64 rays of an octant at a time, in two
 * halves of 32): a stream long enough that every way is measured on some
 * of its windows, each window's rays filling whole bins, and every 16th
 * ray's x direction -0.0 (its sign bit puts it in another octant's bin,
 * as the node test picks that ray's planes).  Each ray gets its single
 * call's answer. */
static void test_one_octant(void **state)
{
    (void)state;
    const size_t n = 4096;
    rtk_rayhit *rh = malloc(n * sizeof *rh);
    assert_non_null(rh);
    octant_rays(rh, n, 11);
    expect_same_everywhere(rh, n);
    free(rh);
}

/* A renderer's streams: many short ones of one scene from one thread, the
 * way each traces fastest learnt in one call kept for the next (core/stream.c
 * keeps it per thread and tree), whatever the next call's rays: rays of one
 * octant (any hits by masks on avx2), then scattered ones, in turns, and
 * another scene between; every call still gets the single calls' answers. */
static void test_kept_ways(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    enum { N = 1024, CALLS = 12 };
    rtk_rayhit *octant = malloc(N * sizeof *octant), *scattered = malloc(N * sizeof *scattered);
    assert_true(octant && scattered);
    octant_rays(octant, N, 17);
    make_rays(scattered, N, 18);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene s = ball_scene(dev), other = ball_scene(dev);
        for (int c = 0; c < CALLS; c++) {
            const rtk_rayhit *rh = c / 2 % 2 ? scattered : octant;
            /* calls of 1024 rays, and of 700 (windows cut short) */
            const size_t n = c % 3 == 2 ? 700 : N;
            expect_same(c % 5 == 4 ? other : s, rh, n, c % 2, NULL);
        }
        rtk_scene_release(other);
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
    free(octant);
    free(scattered);
}

/* An application's task system: a batch runs its pieces through it; it
 * counts its calls and records the most indices one call was handed. */
static unsigned task_calls;
static uint32_t widest;
static void serial_for(void *user, uint32_t count, rtk_task_fn fn, void *data)
{
    (void)user;
    __atomic_add_fetch(&task_calls, 1, __ATOMIC_RELAXED);
    widest = count > widest ? count : widest;
    for (uint32_t i = count; i-- > 0;) /* backwards: the pieces' order must not matter */
        fn(data, i);
}

static void test_batches(void **state)
{
    (void)state;
    const size_t n = test_sanitized() ? 20000 : 100000;
    rtk_rayhit *rh = malloc(n * sizeof *rh), *one = malloc(n * sizeof *rh), *all = malloc(n * sizeof *rh);
    assert_true(rh && one && all);
    make_rays(rh, n, 5);
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (int mode = 0; mode < 3; mode++) { /* 1 thread, the pool of 3, the application's tasks */
        rtk_device dev = test_device_threads(names[nb - 1], mode == 1 ? 3 : 1);
        if (mode == 2) {
            const rtk_task_system ts = {.struct_size = sizeof ts, .threads = 4, .parallel_for = serial_for};
            assert_int_equal(rtk_device_set_task_system(dev, &ts), RTK_OK);
        }
        rtk_scene s = ball_scene(dev);
        task_calls = 0;
        for (int occluded = 0; occluded < 2; occluded++) {
            memcpy(one, rh, n * sizeof *rh);
            memcpy(all, rh, n * sizeof *rh);
            for (size_t i = 0; i < n; i++)
                occluded ? rtk_occluded1(s, &one[i].ray) : rtk_intersect1(s, &one[i]);
            assert_int_equal(occluded ? rtk_occluded_batch(s, &all[0].ray, n, sizeof *all, NULL)
                                      : rtk_intersect_batch(s, all, n, sizeof *all, NULL),
                             RTK_OK);
            assert_memory_equal(one, all, n * sizeof *rh);
        }
        assert_int_equal(task_calls, mode == 2 ? 2 : 0);
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
    free(rh);
    free(one);
    free(all);
}

/* A new thread's own limit: none, whatever the thread that made it set. */
static void *limit_thread(void *arg)
{
    uint32_t *got = arg;
    got[0] = rtk_set_batch_threads(3);
    got[1] = rtk_set_batch_threads(0);
    return NULL;
}

/* Hits seen by a filter on a thread other than the caller's. */
static pthread_t batch_caller;
static unsigned elsewhere;
static int count_elsewhere(const rtk_filter_args *a)
{
    (void)a;
    if (!pthread_equal(pthread_self(), batch_caller))
        __atomic_add_fetch(&elsewhere, 1, __ATOMIC_RELAXED);
    return 1;
}

/* rtk_set_batch_threads: a batch of rays and one of points run on at most
 * the calling thread's limit of threads, whatever the device has (the
 * application's task system of 4 handed that many indices at most, none
 * for a limit of 1; rtk's pool of 3 calling no filter on another thread
 * for a limit of 1), with the same answers; the limit above the device's
 * threads or 0 leaves the batch as it was; the limit is the thread's own. */
static void test_batch_threads(void **state)
{
    (void)state;
    enum { N = 6 * 4096, P = 4 * 1024 }; /* 6 pieces of rays, 4 of points */
    rtk_rayhit *rh = malloc(N * sizeof *rh), *one = malloc(N * sizeof *rh), *all = malloc(N * sizeof *rh);
    rtk_point_query *pq = malloc(P * sizeof *pq);
    rtk_point_hit *pone = malloc(P * sizeof *pone), *pall = malloc(P * sizeof *pall);
    assert_true(rh && one && all && pq && pone && pall);
    make_rays(rh, N, 21);
    for (size_t i = 0; i < P; i++)
        pq[i] = (rtk_point_query){.x = rh[i].ray.org_x, .y = rh[i].ray.org_y, .z = rh[i].ray.org_z,
                                  .radius = INFINITY};
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    rtk_device dev = test_device_threads(names[nb - 1], 1);
    const rtk_task_system ts = {.struct_size = sizeof ts, .threads = 4, .parallel_for = serial_for};
    assert_int_equal(rtk_device_set_task_system(dev, &ts), RTK_OK);
    rtk_scene s = ball_scene(dev);
    memcpy(one, rh, N * sizeof *rh);
    for (size_t i = 0; i < N; i++)
        assert_int_equal(rtk_intersect1(s, &one[i]), RTK_OK);
    for (size_t i = 0; i < P; i++)
        assert_int_equal(rtk_closest_point(s, &pq[i], &pone[i]), RTK_OK);
    static const uint32_t limits[] = {0, 1, 2, 3, 4, 9, 0};
    uint32_t was = 0;
    for (size_t k = 0; k < sizeof limits / sizeof *limits; k++) {
        const uint32_t limit = limits[k];
        assert_int_equal(rtk_set_batch_threads(limit), was);
        was = limit;
        /* (a limit of 4 or more, or none, is the task system's 4 threads) */
        const int capped = limit > 0 && limit < 4;
        task_calls = widest = 0;
        memcpy(all, rh, N * sizeof *rh);
        assert_int_equal(rtk_intersect_batch(s, all, N, sizeof *all, NULL), RTK_OK);
        assert_memory_equal(one, all, N * sizeof *rh);
        assert_int_equal(task_calls, limit == 1 ? 0 : 1);
        assert_int_equal(widest, limit == 1 ? 0 : capped ? limit : 6);
        task_calls = widest = 0;
        assert_int_equal(rtk_closest_point_batch(s, pq, pall, P), RTK_OK);
        assert_memory_equal(pone, pall, P * sizeof *pone);
        assert_int_equal(widest, limit == 1 ? 0 : capped ? limit : 4);
    }
    /* the limit is the calling thread's */
    assert_int_equal(rtk_set_batch_threads(2), 0);
    uint32_t got[2];
    pthread_t tid;
    assert_int_equal(pthread_create(&tid, NULL, limit_thread, got), 0);
    pthread_join(tid, NULL);
    assert_int_equal(got[0], 0);
    assert_int_equal(got[1], 3);
    assert_int_equal(rtk_set_batch_threads(0), 2);
    rtk_scene_release(s);
    rtk_device_release(dev);

    /* rtk's own pool of 3: a limit of 1 keeps every filter call on the
     * calling thread */
    dev = test_device_threads(names[nb - 1], 3);
    s = filtered_ball(dev, count_elsewhere);
    batch_caller = pthread_self();
    elsewhere = 0;
    assert_int_equal(rtk_set_batch_threads(1), 0);
    memcpy(all, rh, N * sizeof *rh);
    assert_int_equal(rtk_intersect_batch(s, all, N, sizeof *all, NULL), RTK_OK);
    assert_memory_equal(one, all, N * sizeof *rh);
    assert_int_equal(elsewhere, 0);
    assert_int_equal(rtk_set_batch_threads(0), 1);
    rtk_scene_release(s);
    rtk_device_release(dev);
    free(rh);
    free(one);
    free(all);
    free(pq);
    free(pone);
    free(pall);
}

/* Several application threads streaming through one committed scene at
 * once, each its own rays, each checked against the single calls. */
typedef struct stream_job {
    rtk_scene scene;
    uint64_t seed;
    int failures;
} stream_job;

static void *stream_thread(void *arg)
{
    stream_job *j = arg;
    enum { N = 700 };
    rtk_rayhit rh[N], one[N];
    make_rays(rh, N, j->seed);
    for (int round = 0; round < 4; round++) {
        const int occluded = round % 2;
        memcpy(one, rh, sizeof rh);
        for (int i = 0; i < N; i++)
            occluded ? rtk_occluded1(j->scene, &one[i].ray) : rtk_intersect1(j->scene, &one[i]);
        rtk_rayhit many[N];
        memcpy(many, rh, sizeof rh);
        const rtk_error e = occluded ? rtk_occluded1M(j->scene, &many[0].ray, N, sizeof many[0])
                                     : rtk_intersect1M(j->scene, many, N, sizeof many[0]);
        j->failures += e != RTK_OK || memcmp(one, many, sizeof one) != 0;
    }
    return NULL;
}

static void test_threads(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    rtk_device dev = test_device(names[nb - 1]);
    rtk_scene ball_s = ball_scene(dev), inst = test_instancing_scene(dev, ball_s);
    assert_int_equal(rtk_scene_commit(inst), RTK_OK);
    enum { T = 4 };
    for (int two = 0; two < 2; two++) { /* the ball, then an instance of it (two levels) */
        stream_job jobs[T];
        pthread_t tid[T];
        for (int t = 0; t < T; t++) {
            jobs[t] = (stream_job){two ? inst : ball_s, 100 + (uint64_t)t, 0};
            assert_int_equal(pthread_create(&tid[t], NULL, stream_thread, &jobs[t]), 0);
        }
        for (int t = 0; t < T; t++) {
            pthread_join(tid[t], NULL);
            assert_int_equal(jobs[t].failures, 0);
        }
    }
    rtk_scene_release(inst);
    rtk_scene_release(ball_s);
    rtk_device_release(dev);
}

/* Any-hit packets of sun rays: one direction, origins scattered through
 * the ball's box.  Each tree keeps the way such packets take and samples
 * both ways in turns (traverse_packet.h, PK_(occluded_spread)), so enough
 * calls take both, and switch; every lane must get rtk_occluded1's
 * answer whichever way its call took.  T threads share the scene and its
 * choice (run under ThreadSanitizer by scripts/test). */
typedef struct packet_job {
    rtk_scene scene;
    unsigned width;
    uint64_t seed;
    int failures, hits; /* lanes that differ; lanes with a hit (or occluded) */
} packet_job;

static void *sun_thread(void *arg)
{
    packet_job *j = arg;
    rng r = {j->seed};
    const int calls = test_sanitized() ? 1500 : 12000;
    _Alignas(64) uint32_t pk[12 * 16];
    for (int c = 0; c < calls; c++) {
        rtk_ray rays[16];
        int valid[16];
        for (unsigned l = 0; l < j->width; l++) {
            const float o[3] = {4.0f * rng_float(&r) - 2.0f, 4.0f * rng_float(&r) - 2.0f, 4.0f * rng_float(&r) - 2.0f};
            rays[l] = test_ray(o[0], o[1], o[2], 0.3f, -0.8f, 0.5f, 0.0f, INFINITY);
            valid[l] = (c + (int)l) % 11 != 3;
            rtk_rayhit rh = {.ray = rays[l]};
            test_packet_put(pk, j->width, l, &rh, 1);
        }
        assert_int_equal(test_trace_packet(j->scene, j->width, 1, valid, pk), RTK_OK);
        for (unsigned l = 0; l < j->width; l++) {
            rtk_rayhit got;
            test_packet_get(pk, j->width, l, &got, 1);
            rtk_ray one = rays[l];
            assert_int_equal(rtk_occluded1(j->scene, &one), RTK_OK);
            if (!valid[l])
                one.tfar = rays[l].tfar; /* an inactive lane comes back as it went */
            j->failures += got.ray.tfar != one.tfar;
            j->hits += one.tfar == -INFINITY;
        }
    }
    return NULL;
}

/* Closest-hit packets of diffuse bounces: the rays of a packet from about
 * one point (neighbouring pixels' hits) in random directions, so their
 * signs disagree (no frustum) and their origins lie close (not handed to
 * the stream kernel): the packet traversal goes down together and hands
 * subtrees to single rays (traverse_packet.h).  Every lane must get
 * rtk_intersect1's hit (a different triangle only where the distances
 * tie).  T threads share the scene (run under ThreadSanitizer). */
static void *diffuse_thread(void *arg)
{
    packet_job *j = arg;
    rng r = {j->seed};
    const int calls = test_sanitized() ? 1500 : 12000;
    _Alignas(64) uint32_t pk[20 * 16];
    for (int c = 0; c < calls; c++) {
        rtk_rayhit rays[16];
        int valid[16];
        /* a point of the ball's box, the lanes within 1e-3 of it */
        const float o[3] = {2.4f * rng_float(&r) - 1.2f, 2.4f * rng_float(&r) - 1.2f, 2.4f * rng_float(&r) - 1.2f};
        for (unsigned l = 0; l < j->width; l++) {
            float d[3];
            for (int k = 0; k < 3; k++)
                d[k] = 2.0f * rng_float(&r) - 1.0f;
            rays[l] = (rtk_rayhit){.ray = test_ray(o[0] + 1e-3f * rng_float(&r), o[1] + 1e-3f * rng_float(&r),
                                                   o[2] + 1e-3f * rng_float(&r), d[0], d[1], d[2], 0.0f, INFINITY)};
            rays[l].hit.geomID = RTK_INVALID_GEOMETRY_ID;
            valid[l] = (c + (int)l) % 13 != 5;
            test_packet_put(pk, j->width, l, &rays[l], 0);
        }
        assert_int_equal(test_trace_packet(j->scene, j->width, 0, valid, pk), RTK_OK);
        for (unsigned l = 0; l < j->width; l++) {
            rtk_rayhit got, one = rays[l];
            test_packet_get(pk, j->width, l, &got, 0);
            if (valid[l])
                assert_int_equal(rtk_intersect1(j->scene, &one), RTK_OK);
            /* (an inactive lane comes back as it went; the triangle may
             * differ only at a tie, at the same distance) */
            j->failures += got.hit.geomID != one.hit.geomID || got.ray.tfar != one.ray.tfar;
            j->hits += valid[l] && one.hit.geomID != RTK_INVALID_GEOMETRY_ID;
        }
    }
    return NULL;
}

/* Packets of 4, 8 and 16 rays made and checked by fn (a packet_job's
 * thread), from T threads sharing one ball scene, on every backend; what
 * names the packets in a failure, seed the jobs' first seed. */
static void packet_jobs(void *(*fn)(void *), const char *what, const char *answer, uint64_t seed)
{
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene s = ball_scene(dev);
        enum { T = 2 };
        for (unsigned width = 4; width <= 16; width *= 2) {
            packet_job jobs[T];
            pthread_t tid[T];
            for (int t = 0; t < T; t++) {
                jobs[t] = (packet_job){.scene = s, .width = width, .seed = seed + (uint64_t)t + width};
                assert_int_equal(pthread_create(&tid[t], NULL, fn, &jobs[t]), 0);
            }
            for (int t = 0; t < T; t++) {
                pthread_join(tid[t], NULL);
                if (jobs[t].failures)
                    fail_msg("%s: %s packets of %u: %d lanes differ from %s", names[b], what, width,
                             jobs[t].failures, answer);
                assert_true(jobs[t].hits > 0);
            }
        }
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
}

static void test_sun_packets(void **state)
{
    (void)state;
    packet_jobs(sun_thread, "sun", "rtk_occluded1", 200);
}

static void test_diffuse_packets(void **state)
{
    (void)state;
    packet_jobs(diffuse_thread, "diffuse", "rtk_intersect1", 300);
}

int main(int argc, char **argv)
{
    /* "quick": the thread test alone (scripts/test runs it under ThreadSanitizer) */
    const int quick = argc > 1 && !strcmp(argv[1], "quick");
    const struct CMUnitTest all[] = {
        cmocka_unit_test(test_bad_arguments),       cmocka_unit_test(test_invalid_rays_in_the_middle),
        cmocka_unit_test(test_filters),             cmocka_unit_test(test_scenes),
        cmocka_unit_test(test_batches),             cmocka_unit_test(test_threads),
        cmocka_unit_test(test_grazing_groups),      cmocka_unit_test(test_one_octant),
        cmocka_unit_test(test_kept_ways),           cmocka_unit_test(test_sun_packets),
        cmocka_unit_test(test_diffuse_packets),     cmocka_unit_test(test_batch_threads),
    };
    const struct CMUnitTest threads[] = {cmocka_unit_test(test_threads), cmocka_unit_test(test_batches),
                                         cmocka_unit_test(test_sun_packets), cmocka_unit_test(test_diffuse_packets),
                                         cmocka_unit_test(test_batch_threads)};
    return quick ? cmocka_run_group_tests(threads, setup, teardown) : cmocka_run_group_tests(all, setup, teardown);
}
