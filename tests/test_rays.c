/* Rays that break naive code, on every backend: zero and -0.0 direction
 * components, NaN and Inf, tnear > tfar, rays starting on a surface, hits at
 * the ends of the interval. */
#include <float.h>
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>

#include "testlib.h"

/* A unit square at z = 0 (two triangles), an axis-aligned box face at
 * x = 2 (two triangles, a flat box in x), a far wall at z = -10, and a
 * rectangle at z = 0 far out in x, at the edge of rtk's range (rtk.h):
 * [2^35, 2^35 + 2^14] x [0, 1] (prims 6, 7; floats there are 2^12 apart).
 * (It lay at 2^67 once, beyond the range rtk now answers in: such
 * triangles are left out and counted, test_range.c.) */
static const float V[] = {
    0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0,          /* square, 0..3 */
    2, -1, -1, 2, 1, -1, 2, 1, 1, 2, -1, 1,      /* wall x = 2, 4..7 */
    -5, -5, -10, 5, -5, -10, 5, 5, -10, -5, 5, -10, /* floor z = -10, 8..11 */
    0x1p35f, 0, 0, 0x1.000008p35f, 0, 0, 0x1.000008p35f, 1, 0, 0x1p35f, 1, 0, /* far rectangle, 12..15 */
};
static const uint32_t I[] = {0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7, 8, 9, 10, 8, 10, 11, 12, 13, 14, 12, 14, 15};
#define NV 16
#define NT 8

typedef struct backend_scene {
    char name[32];
    rtk_device dev;
    rtk_scene scene;
} backend_scene;

/* every backend, with its default layout, compact, robust and both: the
 * defined answers hold in every mode */
static backend_scene scenes[4 * TEST_MAX_BACKENDS];
static size_t nscenes;

/* scenes[] over the given triangles, on every backend in every layout */
static void build_scenes(const float *v, size_t nv, const uint32_t *idx, size_t nt)
{
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    static const unsigned flags[4] = {RTK_SCENE_FLAG_NONE, RTK_SCENE_FLAG_COMPACT, RTK_SCENE_FLAG_ROBUST,
                                      RTK_SCENE_FLAG_ROBUST | RTK_SCENE_FLAG_COMPACT};
    static const char *const suffix[4] = {"", " compact", " robust", " robust compact"};
    nscenes = 4 * nb;
    for (size_t i = 0; i < nscenes; i++) {
        snprintf(scenes[i].name, sizeof scenes[i].name, "%s%s", names[i % nb], suffix[i / nb]);
        scenes[i].dev = test_device(names[i % nb]);
        scenes[i].scene = test_scene_flags(scenes[i].dev, v, nv, idx, nt, flags[i / nb]);
    }
}

static int setup(void **state)
{
    (void)state;
    build_scenes(V, NV, I, NT);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    for (size_t i = 0; i < nscenes; i++) {
        rtk_scene_release(scenes[i].scene);
        rtk_device_release(scenes[i].dev);
    }
    return 0;
}

static void expect_packets(const char *what, rtk_ray r, const rtk_rayhit *single, const rtk_ray *single_occ);
static size_t current; /* the backend expect_packets works on */

/* Traces r on every backend; expects a hit on prim at t (prim == -1: no hit),
 * and the same answer from occluded1 and from every packet call. */
static void expect(const char *what, rtk_ray r, int prim, float t)
{
    for (size_t i = 0; i < nscenes; i++) {
        rtk_rayhit rh;
        memset(&rh, 0x5a, sizeof rh);
        rh.ray = r;
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        const rtk_hit before = rh.hit;
        assert_int_equal(rtk_intersect1(scenes[i].scene, &rh), RTK_OK);
        rtk_ray o = r;
        assert_int_equal(rtk_occluded1(scenes[i].scene, &o), RTK_OK);
        if (prim < 0) {
            if (rh.hit.geomID != RTK_INVALID_GEOMETRY_ID)
                fail_msg("%s [%s]: expected no hit, got prim %u at t=%g", what, scenes[i].name, rh.hit.primID,
                         rh.ray.tfar);
            /* A miss leaves ray and hit untouched, bit for bit. */
            assert_memory_equal(&rh.ray, &r, sizeof r);
            assert_memory_equal(&rh.hit, &before, sizeof before);
            assert_memory_equal(&o, &r, sizeof r);
            continue;
        }
        if (rh.hit.geomID != 0 || rh.hit.primID != (uint32_t)prim)
            fail_msg("%s [%s]: expected prim %d, got geom %u prim %u", what, scenes[i].name, prim, rh.hit.geomID,
                     rh.hit.primID);
        if (!(fabsf(rh.ray.tfar - t) <= 1e-6f * fmaxf(1.0f, fabsf(t))))
            fail_msg("%s [%s]: expected t=%.9g, got %.9g", what, scenes[i].name, t, rh.ray.tfar);
        if (!(rh.ray.tfar >= r.tnear && rh.ray.tfar <= r.tfar))
            fail_msg("%s [%s]: t=%.9g outside [%.9g, %.9g]", what, scenes[i].name, rh.ray.tfar, r.tnear, r.tfar);
        if (!(o.tfar == -INFINITY))
            fail_msg("%s [%s]: occluded1 missed", what, scenes[i].name);
    }
    for (size_t i = 0; i < nscenes; i++) {
        rtk_rayhit rh;
        memset(&rh, 0x5a, sizeof rh);
        rh.ray = r;
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1(scenes[i].scene, &rh), RTK_OK);
        rtk_ray o = r;
        assert_int_equal(rtk_occluded1(scenes[i].scene, &o), RTK_OK);
        current = i;
        expect_packets(what, r, &rh, &o);
    }
}

/* The ray in the first or last lane of a packet of each width, the other
 * lanes either switched off or busy with a ray onto the square (so the
 * packet both travels together and finishes rays alone): its lane must come
 * back exactly as the single-ray call left it, the others as they were. */
static void expect_packets(const char *what, rtk_ray r, const rtk_rayhit *single, const rtk_ray *single_occ)
{
    static const unsigned widths[3] = {4, 8, 16};
    const rtk_ray filler = test_ray(0.5f, 0.5f, 2, 0.01f, -0.02f, -1, 0, INFINITY);
    for (int wi = 0; wi < 3; wi++)
        for (int occluded = 0; occluded < 2; occluded++)
            for (int others_on = 0; others_on < 2; others_on++)
                for (int end = 0; end < 2; end++) {
                    const unsigned w = widths[wi], lane = end ? w - 1 : 0;
                    _Alignas(64) uint32_t pk[20 * 16], before[20 * 16];
                    int valid[16];
                    for (unsigned j = 0; j < w; j++) {
                        rtk_rayhit rh;
                        memset(&rh, 0x5a, sizeof rh);
                        rh.ray = j == lane ? r : filler;
                        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
                        test_packet_put(pk, w, j, &rh, occluded);
                        valid[j] = j == lane ? -1 : others_on;
                    }
                    memcpy(before, pk, sizeof pk);
                    assert_int_equal(test_trace_packet(scenes[current].scene, w, occluded, valid, pk), RTK_OK);
                    rtk_rayhit got, other;
                    test_packet_get(pk, w, lane, &got, occluded);
                    const int same = occluded ? !memcmp(&got.ray, single_occ, sizeof got.ray)
                                              : !memcmp(&got, single, sizeof got);
                    if (!same)
                        fail_msg("%s [%s]: %s%u lane %u (other lanes %s) differs from the single-ray call: tfar %a "
                                 "prim %u, single %a prim %u",
                                 what, scenes[current].name, occluded ? "occluded" : "intersect", w, lane,
                                 others_on ? "on" : "off", got.ray.tfar, got.hit.primID,
                                 occluded ? single_occ->tfar : single->ray.tfar, single->hit.primID);
                    for (unsigned j = 0; j < w; j++) {
                        if (j == lane)
                            continue;
                        test_packet_get(pk, w, j, &other, occluded);
                        if (others_on) {
                            /* the filler hits the square (prim 0 or 1) at about t = 2 */
                            const int hit = occluded ? other.ray.tfar == -INFINITY
                                                     : other.hit.geomID == 0 && fabsf(other.ray.tfar - 2) < 1e-3f;
                            if (!hit)
                                fail_msg("%s [%s]: %s%u filler lane %u missed", what, scenes[current].name,
                                         occluded ? "occluded" : "intersect", w, j);
                        } else {
                            rtk_rayhit was;
                            test_packet_get(before, w, j, &was, occluded);
                            if (memcmp(&was, &other, occluded ? sizeof was.ray : sizeof was))
                                fail_msg("%s [%s]: %s%u inactive lane %u was written", what, scenes[current].name,
                                         occluded ? "occluded" : "intersect", w, j);
                        }
                    }
                }
}

static void test_axis_parallel_zero_and_negative_zero(void **state)
{
    (void)state;
    /* Straight down the z axis, with +0 and -0 in x and y. */
    expect("down +0 +0", test_ray(0.75f, 0.25f, 5, 0.0f, 0.0f, -1, 0, INFINITY), 0, 5);
    expect("down -0 -0", test_ray(0.75f, 0.25f, 5, -0.0f, -0.0f, -1, 0, INFINITY), 0, 5);
    expect("down -0 +0", test_ray(0.25f, 0.75f, 5, -0.0f, 0.0f, -1, 0, INFINITY), 1, 5);
    /* Up from below, -0 components: hits the square from behind. */
    expect("up -0", test_ray(0.25f, 0.75f, -5, -0.0f, -0.0f, 1, 0, INFINITY), 1, 5);
    /* Along +x onto the flat wall at x = 2 (a box of zero width in x). */
    expect("along +x", test_ray(-3, 0.25f, 0.5f, 1, 0.0f, -0.0f, 0, INFINITY), 3, 5);
    expect("along +x -0", test_ray(-3, -0.25f, -0.5f, 1, -0.0f, -0.0f, 0, INFINITY), 2, 5);
    /* In the plane of the square (parallel to it): passes, hits the wall. */
    expect("in plane", test_ray(-3, 0.5f, 0.0f, 1, 0, 0, 0, INFINITY), 2, 5);
    /* Outside every box along an axis: no hit. */
    expect("parallel miss", test_ray(-3, 7, 0.5f, 1, -0.0f, 0, 0, INFINITY), -1, 0);
}

static void test_nan_and_inf(void **state)
{
    (void)state;
    const float nan = NAN, inf = INFINITY;
    expect("NaN origin", test_ray(nan, 0.25f, 5, 0, 0, -1, 0, inf), -1, 0);
    expect("NaN direction", test_ray(0.75f, 0.25f, 5, 0, nan, -1, 0, inf), -1, 0);
    expect("Inf origin", test_ray(0.75f, 0.25f, inf, 0, 0, -1, 0, inf), -1, 0);
    expect("-Inf direction", test_ray(0.75f, 0.25f, 5, 0, 0, -inf, 0, inf), -1, 0);
    expect("NaN tnear", test_ray(0.75f, 0.25f, 5, 0, 0, -1, nan, inf), -1, 0);
    expect("NaN tfar", test_ray(0.75f, 0.25f, 5, 0, 0, -1, 0, nan), -1, 0);
    expect("Inf tnear", test_ray(0.75f, 0.25f, 5, 0, 0, -1, inf, inf), -1, 0);
    expect("zero direction", test_ray(0.75f, 0.25f, 5, 0, 0, 0, 0, inf), -1, 0);
    /* Huge but finite direction components still work. */
    expect("huge direction", test_ray(0.75f, 0.25f, 5, 0, 0, -1e30f, 0, inf), 0, 5e-30f);
    /* Denormal direction components next to a normal one. */
    expect("denormal direction", test_ray(0.75f, 0.25f, 5, 1e-40f, -1e-40f, -1, 0, inf), 0, 5);
}

/* A scene without motion blur ignores the ray's time, whatever it holds:
 * negative, -0.0, NaN, infinite or beyond 1 (the single-ray kernels load
 * it beside the direction, and once took its sign for a fourth axis'), from
 * all eight octants of directions. */
static void test_time_without_motion(void **state)
{
    (void)state;
    const float times[] = {-1.0f, -0.0f, NAN, INFINITY, -INFINITY, 2.0f, 0.5f};
    for (int octant = 0; octant < 8; octant++) {
        /* toward (0.75, 0.25, 0) on the square, from the octant's side */
        const float dx = octant & 1 ? -1.0f : 1.0f, dy = octant & 2 ? -0.5f : 0.5f, dz = octant & 4 ? -5.0f : 5.0f;
        for (size_t k = 0; k < sizeof times / sizeof *times; k++) {
            rtk_ray r = test_ray(0.75f - dx, 0.25f - dy, -dz, dx, dy, dz, 0, INFINITY);
            r.time = times[k];
            char what[64];
            snprintf(what, sizeof what, "octant %d, time %g", octant, times[k]);
            expect(what, r, 0, 1);
        }
    }
}

static void test_interval(void **state)
{
    (void)state;
    expect("tnear > tfar", test_ray(0.75f, 0.25f, 5, 0, 0, -1, 6, 4), -1, 0);
    expect("negative tnear", test_ray(0.75f, 0.25f, 5, 0, 0, -1, -1, 10), -1, 0);
    /* Both ends are included. */
    expect("hit exactly at tfar", test_ray(0.75f, 0.25f, 5, 0, 0, -1, 0, 5), 0, 5);
    expect("hit exactly at tnear", test_ray(0.75f, 0.25f, 5, 0, 0, -1, 5, 100), 0, 5);
    expect("tnear == tfar == t", test_ray(0.75f, 0.25f, 5, 0, 0, -1, 5, 5), 0, 5);
    expect("just short", test_ray(0.75f, 0.25f, 5, 0, 0, -1, 0, 4.999f), -1, 0);
    expect("just past", test_ray(0.75f, 0.25f, 5, 0, 0, -1, 5.001f, 14.999f), -1, 0);
    /* Past the square, the floor. */
    expect("floor", test_ray(0.75f, 0.25f, 5, 0, 0, -1, 5.001f, INFINITY), 4, 15);
}

static void test_origin_on_surface(void **state)
{
    (void)state;
    /* Starting exactly on the square with tnear = 0: a hit at t = 0. */
    expect("on surface, leaving", test_ray(0.75f, 0.25f, 0, 0, 0, 1, 0, INFINITY), 0, 0);
    expect("on surface, entering", test_ray(0.75f, 0.25f, 0, 0, 0, -1, 0, INFINITY), 0, 0);
    /* The same with -0.0 as tnear and tfar (valid: -0.0 >= 0), which must
     * not upset a box test that orders floats by their bits. */
    expect("on surface, [-0, -0]", test_ray(0.75f, 0.25f, 0, 0, 0, 1, -0.0f, -0.0f), 0, 0);
    expect("on surface, [-0, inf]", test_ray(0.75f, 0.25f, 0, 0, 0, -1, -0.0f, INFINITY), 0, 0);
    /* A small tnear steps off it: the next surface is the floor. */
    expect("on surface, tnear 1e-4", test_ray(0.75f, 0.25f, 0, 0, 0, -1, 1e-4f, INFINITY), 4, 10);
    expect("on surface, away", test_ray(0.75f, 0.25f, 0, 0, 0, 1, 1e-4f, INFINITY), -1, 0);
}

/* Rays starting on a triangle that lies in its boxes' far plane (every box
 * of this scene is flat in z, the triangles all at z = 0), leaving through
 * that plane: the far distance of every box on the way is (0 - 0) times a
 * negative reciprocal, -0.0, and the boxes must still be entered, to give the
 * hit at t = 0 that a ray leaving any other way gets.  A box test ordering
 * floats by their bits rejects them unless it turns -0.0 into +0.0. */
static int setup_flat_squares(void **state)
{
    enum { squares = 16 };
    static float v[squares * 12]; /* static: compact scenes keep using them */
    static uint32_t idx[squares * 6];
    for (int k = 0; k < squares; k++) {
        const float x = 3.0f * (float)k, sq[12] = {x, 0, 0, x + 1, 0, 0, x + 1, 1, 0, x, 1, 0};
        static const uint32_t two[6] = {0, 1, 2, 0, 2, 3};
        memcpy(&v[12 * k], sq, sizeof sq);
        for (int j = 0; j < 6; j++)
            idx[6 * k + j] = (uint32_t)(4 * k) + two[j];
    }
    teardown(state);
    build_scenes(v, squares * 4, idx, squares * 2);
    return 0;
}

static int restore_fixture(void **state)
{
    teardown(state);
    return setup(state);
}

static void test_origin_on_box_far_plane(void **state)
{
    (void)state;
    expect("far plane, -z", test_ray(0.75f, 0.25f, 0, 0, 0, -1, 0, INFINITY), 0, 0);
    expect("far plane, -z, -0.0 x y", test_ray(0.75f, 0.25f, 0, -0.0f, -0.0f, -1, 0, INFINITY), 0, 0);
    expect("far plane, oblique", test_ray(0.75f, 0.25f, 0, 0.3f, 0.2f, -1, 0, INFINITY), 0, 0);
    expect("far plane, square 11", test_ray(33.25f, 0.75f, 0, -0.1f, 0, -1, 0, INFINITY), 23, 0);
    expect("far plane, +z", test_ray(0.75f, 0.25f, 0, 0, 0, 1, 0, INFINITY), 0, 0);
}

static void test_closest_of_several(void **state)
{
    (void)state;
    /* Through the square to the floor: the square is closer. */
    expect("closest", test_ray(0.3f, 0.6f, 3, 0, 0, -1, 0, INFINITY), 1, 3);
    /* From x = 5 going -x: the wall at t = 3, the square (x <= 1) behind it. */
    expect("from +x", test_ray(5, 0.5f, 0.25f, -1, 0, 0, 0, INFINITY), 2, 3);
}

/* Coordinates far from the origin.  With FMA the node test computes
 * plane * inv - org * inv; a ray there parallel to x has org * inv near
 * 2^95 (2^35 * 1e18), where the products' rounding is far larger than the
 * boxes. */
static void test_huge_coordinates(void **state)
{
    (void)state;
    const float mid = 0x1.000004p35f; /* 2^35 + 2^13, halfway along the rectangle */
    expect("huge x, axis-parallel", test_ray(mid, 0.25f, 5, 0, 0, -1, 0, INFINITY), 6, 5);
    expect("huge x, axis-parallel -0", test_ray(mid, 0.75f, 5, -0.0f, -0.0f, -1, 0, INFINITY), 7, 5);
    expect("huge x, up from below", test_ray(mid, 0.75f, -5, 0, 0, 1, 0, INFINITY), 7, 5);
    /* org * inv large (2^35 / 1e-3): the fused test, whose error bound is
     * then far larger than the box's extent in t */
    expect("huge x, tilted", test_ray(mid, 0.25f, 5, 1e-3f, 1e-3f, -1, 0, INFINITY), 6, 5);
    expect("huge x, beside", test_ray(mid, 1.25f, 5, 0, 0, -1, 0, INFINITY), -1, 0);
    /* Origins beyond the range (org * inv would overflow on all three axes,
     * 2^70 * 1e18, leaving a fused node test no slab to reject a box with):
     * the core moves them to the scene's bounds (ray_range.c).  The scene
     * lies beyond tfar (and beyond the float range of t: 2^70 / 1e-30 and
     * 2^128). */
    expect("huge origin, tiny direction",
           test_ray(0x1p70f, 0x1p70f, 0x1p70f, -1e-30f, -1e-30f, -1e-30f, 0, 1e38f), -1, 0);
    expect("huge origin, unit direction",
           test_ray(0x1p127f, 0x1p127f, 0x1p127f, -0.5f, -0.5f, -0.5f, 0, 1e38f), -1, 0);
}

/* Packets of rays that spread out on purpose (origins on both sides of the
 * boxes' planes, half of them aimed at corners of the boxes, direction
 * components from 1e-20 to 1, all eight octants, lanes switched off): every
 * lane must get exactly the single-ray answer.  A lane that visits a box it
 * does not enter alone can hit a triangle edge it grazes in float arithmetic
 * (a packet lane with tfar = +inf once did); one that skips a box it enters
 * misses or hits farther, which is what a packet frustum (rays sharing their
 * direction signs) one rounding too tight does: with the far bound taken
 * from the near planes' constants, this test failed on avx2 occluded4. */
static uint32_t rng_state = 12345;
static float rnd01(void)
{
    rng_state = rng_state * 1664525u + 1013904223u;
    return (float)(rng_state >> 8) * 0x1p-24f;
}

static void test_spread_packets(void **state)
{
    (void)state;
    static const unsigned widths[3] = {4, 8, 16};
    for (size_t i = 0; i < nscenes; i++)
        for (int round = 0; round < 2000; round++) {
            const unsigned w = widths[round % 3], octant = (unsigned)round / 3 % 8;
            const int occluded = round / 24 % 2;
            _Alignas(64) uint32_t pk[20 * 16];
            rtk_rayhit single[16];
            int valid[16];
            for (unsigned j = 0; j < w; j++) {
                float d[3];
                for (int k = 0; k < 3; k++) {
                    const float mag = rnd01() < 0.1f ? 1e-20f : powf(10.0f, -3.0f * rnd01());
                    d[k] = octant >> k & 1 ? -mag : mag;
                }
                /* Half the rays start anywhere around the scene; the others
                 * are aimed at a corner of the square, the wall or the floor
                 * (corners of the boxes too), where a frustum a rounding too
                 * tight would lose them. */
                float o[3];
                const float *aim = &V[3 * (rng_state % 12)];
                const int at_corner = rnd01() < 0.5f;
                for (int k = 0; k < 3; k++)
                    o[k] = at_corner ? aim[k] - (1 + rnd01()) * 4 * d[k] / fmaxf(fabsf(d[k]), 0.1f)
                                     : 1 - 6 * (float)(octant >> k & 1) + 3 * rnd01();
                const rtk_ray r = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], rnd01() < 0.2f ? rnd01() : 0,
                                           rnd01() < 0.2f ? 5 * rnd01() : INFINITY);
                valid[j] = rnd01() < 0.9f ? -1 : 0;
                memset(&single[j], 0x5a, sizeof single[j]);
                single[j].ray = r;
                single[j].hit.geomID = RTK_INVALID_GEOMETRY_ID;
                test_packet_put(pk, w, j, &single[j], occluded);
                if (!valid[j])
                    continue;
                if (occluded)
                    assert_int_equal(rtk_occluded1(scenes[i].scene, &single[j].ray), RTK_OK);
                else
                    assert_int_equal(rtk_intersect1(scenes[i].scene, &single[j]), RTK_OK);
            }
            assert_int_equal(test_trace_packet(scenes[i].scene, w, occluded, valid, pk), RTK_OK);
            for (unsigned j = 0; j < w; j++) {
                rtk_rayhit got;
                test_packet_get(pk, w, j, &got, occluded);
                /* the same distance to the bit; the primitive may differ
                 * only where two are hit at that same distance (the
                 * square's diagonal) */
                const int hit = !occluded && got.hit.geomID != RTK_INVALID_GEOMETRY_ID;
                const int single_hit = !occluded && single[j].hit.geomID != RTK_INVALID_GEOMETRY_ID;
                const rtk_ray *r = &got.ray;
                if (memcmp(&got.ray.tfar, &single[j].ray.tfar, sizeof(float)) || hit != single_hit)
                    fail_msg("[%s] %s%u round %d lane %u%s: org %a %a %a dir %a %a %a tnear %a: tfar %a prim %u, "
                             "single-ray %a prim %u",
                             scenes[i].name, occluded ? "occluded" : "intersect", w, round, j,
                             valid[j] ? "" : " (inactive)", r->org_x, r->org_y, r->org_z, r->dir_x, r->dir_y,
                             r->dir_z, r->tnear, got.ray.tfar, got.hit.primID, single[j].ray.tfar,
                             single[j].hit.primID);
            }
        }
}

/* Teeth in the plane z = TEETH_Z, each with its base on y = TEETH_Y, so
 * every box of the tree is flat in z and has its lower y face on that line:
 * a ray aimed at a point of a base enters a box through its y face and
 * leaves it through its z face at one and the same distance, in exact
 * arithmetic.  Far from the coordinate origin, and coordinates that are not
 * round in binary, so the slab arithmetic rounds. */
#define TEETH 64
#define TEETH_X 150.3f
#define TEETH_Y 300.3f
#define TEETH_Z (-500.7f)
#define TEETH_W 1.37f
static float teeth_v[TEETH * 9]; /* static: compact scenes keep using them */

static int setup_teeth(void **state)
{
    static uint32_t idx[TEETH * 3];
    for (int i = 0; i < TEETH; i++) {
        const float x = TEETH_X + 2.11f * (float)i;
        const float tri[9] = {x, TEETH_Y, TEETH_Z, x + TEETH_W, TEETH_Y, TEETH_Z, x + 0.5f * TEETH_W, TEETH_Y + 1.13f,
                              TEETH_Z};
        memcpy(&teeth_v[9 * i], tri, sizeof tri);
        for (int k = 0; k < 3; k++)
            idx[3 * i + k] = (uint32_t)(3 * i + k);
    }
    teardown(state);
    build_scenes(teeth_v, 3 * TEETH, idx, TEETH);
    return 0;
}

/* The box tests are conservative against their own rounding: a ray that
 * meets a box in exact arithmetic, even only on one of its edges, enters
 * it.  On the teeth, rays from near the coordinate origin (where the
 * padding of a slab test's origin term is small against its distances)
 * aimed at points of the bases, their directions rounded, so each passes a
 * little above or below the base line: where the exact ray crosses the
 * plane on or above the line (decided in double, away from the tie), every
 * box on the way must let it through, so the answer must be the triangle
 * test's on the tooth aimed at, which every backend's kernels compute to
 * the same bits (geometry/triangle.h).  A box test that rounds an entry
 * distance up or an exit distance down by an ulp culls some of these
 * rays. */
static void test_box_edges(void **state)
{
    (void)state;
    rng seed = {12345};
    const size_t nb = nscenes / 4;
    size_t checked = 0, hits = 0;
    for (int n = 0; n < 20000; n++) {
        const int i = (int)(rng_u32(&seed) % TEETH);
        const float *v0 = &teeth_v[9 * i];
        const float px = v0[0] + TEETH_W * (0.1f + 0.8f * rng_float(&seed));
        float o[3], d[3];
        for (int k = 0; k < 3; k++)
            o[k] = 2.0f * rng_float(&seed) - 1.0f;
        d[0] = px - o[0];
        d[1] = TEETH_Y - o[1];
        d[2] = TEETH_Z - o[2];
        if (n & 1) /* and from beyond the plane, toward the origin */
            for (int k = 0; k < 3; k++) {
                o[k] += 2.0f * d[k];
                d[k] = -d[k];
            }
        /* where the exact ray crosses the plane */
        const double tz = ((double)TEETH_Z - o[2]) / d[2];
        const double y = o[1] + tz * d[1];
        if (y - (double)TEETH_Y < 1e-12)
            continue; /* below the line, or too close to it to tell in double */
        const float e1[3] = {v0[3] - v0[0], v0[4] - v0[1], v0[5] - v0[2]};
        const float e2[3] = {v0[6] - v0[0], v0[7] - v0[1], v0[8] - v0[2]};
        rtk_tri_hit th;
        const int want = rtk_triangle_intersect(o, d, 0.0f, INFINITY, v0, e1, e2, &th);
        checked++;
        hits += (size_t)want;
        const rtk_ray r = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY);
        for (size_t b = 0; b < 2 * nb; b++) { /* the default and compact layouts (robust ones test another way) */
            rtk_rayhit rh = {.ray = r};
            rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
            rtk_ray oc = r;
            assert_int_equal(rtk_intersect1(scenes[b].scene, &rh), RTK_OK);
            assert_int_equal(rtk_occluded1(scenes[b].scene, &oc), RTK_OK);
            const int got = rh.hit.geomID != RTK_INVALID_GEOMETRY_ID;
            if (got != want || (got && rh.hit.primID != (uint32_t)i) || (oc.tfar == -INFINITY) != want)
                fail_msg("[%s] ray %a %a %a  %a %a %a at tooth %d: the triangle test %s, intersect1 %s (prim %u), "
                         "occluded1 %s",
                         scenes[b].name, o[0], o[1], o[2], d[0], d[1], d[2], i, want ? "hits" : "misses",
                         got ? "hits" : "misses", rh.hit.primID, oc.tfar == -INFINITY ? "hits" : "misses");
            if (n % 16 == 0) /* the packet kernels' box tests too */
                for (unsigned w = 4; w <= 16; w *= 2)
                    for (int occluded = 0; occluded < 2; occluded++) {
                        _Alignas(64) uint32_t pk[20 * 16];
                        int valid[16];
                        for (unsigned j = 0; j < w; j++) {
                            rtk_rayhit in = {.ray = r};
                            in.hit.geomID = RTK_INVALID_GEOMETRY_ID;
                            test_packet_put(pk, w, j, &in, occluded);
                            valid[j] = -1;
                        }
                        assert_int_equal(test_trace_packet(scenes[b].scene, w, occluded, valid, pk), RTK_OK);
                        for (unsigned j = 0; j < w; j++) {
                            rtk_rayhit out;
                            test_packet_get(pk, w, j, &out, occluded);
                            const int pgot = occluded ? out.ray.tfar == -INFINITY
                                                      : out.hit.geomID != RTK_INVALID_GEOMETRY_ID;
                            if (pgot != want || (!occluded && pgot && out.hit.primID != (uint32_t)i))
                                fail_msg("[%s] ray %a %a %a  %a %a %a at tooth %d: the triangle test %s, "
                                         "%s%u lane %u %s",
                                         scenes[b].name, o[0], o[1], o[2], d[0], d[1], d[2], i,
                                         want ? "hits" : "misses", occluded ? "occluded" : "intersect", w, j,
                                         pgot ? "hits" : "misses");
                        }
                    }
        }
    }
    print_message("box edges: %zu rays checked, %zu hit their tooth\n", checked, hits);
    /* (Moeller-Trumbore's usual form missed some of these rays, whose
     * exact crossing lies above the base line; in Embree's form, whose edge
     * functions from v0 are exact to a rounding or two, every one hits, so
     * every box on the way must let every ray through) */
    assert_true(checked > 5000 && hits > 1000);
}

/* Sixteen small triangles stacked 0.01 apart along z: splitting them buys
 * nothing (every half has the stack's footprint), so the SAH makes them one
 * leaf of four blocks, the largest there is, at the root.  Every block must
 * be searched, by single rays and packets: the nearest triangle from above
 * is the last one, from below the first. */
static int setup_stacked_triangles(void **state)
{
    static float v[16 * 9]; /* static: compact scenes keep using them */
    static uint32_t idx[16 * 3];
    for (int i = 0; i < 16; i++) {
        const float z = 0.01f * (float)i, tri[9] = {0, 0, z, 1, 0, z, 0, 1, z};
        memcpy(&v[9 * i], tri, sizeof tri);
        for (int k = 0; k < 3; k++)
            idx[3 * i + k] = (uint32_t)(3 * i + k);
    }
    teardown(state);
    build_scenes(v, 48, idx, 16);
    return 0;
}

static void test_multi_block_leaf(void **state)
{
    (void)state;
    for (size_t b = 0; b < nscenes; b++) {
        const rtk_scene scene = scenes[b].scene;
        rtk_scene_info info = {.struct_size = sizeof info};
        assert_int_equal(rtk_scene_get_info(scene, &info), RTK_OK);
        if (info.nodes != 0 || info.leaves != 4)
            fail_msg("[%s] %llu nodes, %llu leaf blocks; expected one leaf of 4 blocks", scenes[b].name,
                     (unsigned long long)info.nodes, (unsigned long long)info.leaves);
        static const struct {
            float org[3], dir[3];
            int prim;
        } cases[] = {{{0.25f, 0.25f, 1}, {0, 0, -1}, 15}, {{0.25f, 0.25f, -1}, {0, 0, 1}, 0}};
        for (int c = 0; c < 2; c++) {
            rtk_rayhit rh = {.ray = test_ray(cases[c].org[0], cases[c].org[1], cases[c].org[2], cases[c].dir[0],
                                             cases[c].dir[1], cases[c].dir[2], 0, INFINITY),
                             .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
            assert_int_equal(rtk_intersect1(scene, &rh), RTK_OK);
            if (rh.hit.primID != (uint32_t)cases[c].prim)
                fail_msg("[%s] case %d: prim %u, expected %d", scenes[b].name, c, rh.hit.primID, cases[c].prim);
            _Alignas(64) uint32_t pk[20 * 16];
            for (unsigned w = 4; w <= 16; w *= 2) {
                rtk_rayhit lane = rh;
                lane.ray.tfar = INFINITY;
                lane.hit.geomID = RTK_INVALID_GEOMETRY_ID;
                for (unsigned j = 0; j < w; j++)
                    test_packet_put(pk, w, j, &lane, 0);
                assert_int_equal(test_trace_packet(scene, w, 0, NULL, pk), RTK_OK);
                for (unsigned j = 0; j < w; j++) {
                    test_packet_get(pk, w, j, &lane, 0);
                    if (lane.hit.primID != (uint32_t)cases[c].prim || lane.ray.tfar != rh.ray.tfar)
                        fail_msg("[%s] case %d intersect%u lane %u: prim %u", scenes[b].name, c, w, j,
                                 lane.hit.primID);
                }
            }
        }
    }
}

/* Rays along the axes (the other components +0.0 or -0.0) exactly through
 * the vertices of triangles whose coordinates mix magnitudes, so that
 * v0 + e1 and v0 + e2, as the leaf blocks give the corners back, round an
 * ulp away from them: a closest hit's distance is the reference's to the
 * bit on every backend.  The hit floor (traverse_leaf.h) took the box of
 * those rounded corners, which such a ray can miss by an ulp, times the
 * reciprocal of its zero component, 1e18: t came out near 1e9 for hits
 * at 0.3.  And a ray that lies in a box's face plane along a zero
 * component got a far distance of 0 * 1e18 there in the node tests of the
 * backends without FMA and skipped the box: 3,572-3,724 of these 21,600
 * rays missed their triangle on scalar, sse41 and avx (the top level's
 * test did the same on every backend: test_user rays_along_box_faces;
 * here the instances' boxes are padded).  Every backend must now hit
 * each of them, alone, in packets of 4 (the three vertices of a triangle,
 * one lane inactive) and in a stream, through the triangles' own tree,
 * through an instance of it, through a top level of AXIS_GROUPS instances
 * of a part each, whose boxes have vertices on their faces, through the
 * compact (index leaves) and robust (watertight) layouts' trees, and
 * through a motion-blurred mesh of two equal time steps, in the default
 * and robust motion layouts. */
enum { AXIS_N = 600, AXIS_RAYS = 3 * AXIS_N * 12, AXIS_GROUPS = 8, AXIS_PART = AXIS_N / AXIS_GROUPS };

/* A committed scene of AXIS_GROUPS instances (identity), instance g of a
 * scene of triangles AXIS_PART * g ... (kept in parts[g]). */
static rtk_scene axis_parts_scene(rtk_device dev, const float *v, const uint32_t *idx, rtk_scene parts[AXIS_GROUPS])
{
    rtk_scene outer;
    assert_int_equal(rtk_scene_new(dev, &outer), RTK_OK);
    for (int g = 0; g < AXIS_GROUPS; g++) {
        parts[g] = test_scene(dev, v, 3 * AXIS_N, idx + 3 * AXIS_PART * g, AXIS_PART);
        rtk_geometry inst;
        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &inst), RTK_OK);
        assert_int_equal(rtk_geometry_set_instanced_scene(inst, parts[g]), RTK_OK);
        assert_int_equal(rtk_geometry_commit(inst), RTK_OK);
        uint32_t id;
        assert_int_equal(rtk_scene_attach_geometry(outer, inst, &id), RTK_OK);
        assert_int_equal(id, (uint32_t)g);
        rtk_geometry_release(inst);
    }
    assert_int_equal(rtk_scene_commit(outer), RTK_OK);
    return outer;
}

/* A committed scene of the triangles as a motion-blurred mesh of two time
 * steps that do not move (the same vertices at both): the motion layouts'
 * node and leaf tests, at time 0, give the static scene's answers. */
static rtk_scene axis_motion_scene(rtk_device dev, const float *v, size_t nv, const uint32_t *idx, size_t nt,
                                   unsigned flags)
{
    rtk_scene s;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    assert_int_equal(rtk_scene_set_flags(s, flags), RTK_OK);
    rtk_geometry g;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_time_step_count(g, 2), RTK_OK);
    for (unsigned k = 0; k < 2; k++)
        assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, k, v, 0, 12, nv), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, idx, 0, 12, nt), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    uint32_t id;
    assert_int_equal(rtk_scene_attach_geometry(s, g, &id), RTK_OK);
    rtk_geometry_release(g);
    if (rtk_scene_commit(s) != RTK_OK)
        fail_msg("commit: %s", rtk_device_get_error_message(dev));
    return s;
}

/* Ray i of the set: vertex i / 12, along axis (i % 12) / 4 from 200 away,
 * the direction's sign and its zero components' signs by i % 4. */
static rtk_ray axis_ray(const float *v, size_t i, float away)
{
    const size_t vtx = i / 12;
    const int a = (int)(i % 12) / 4, sg = (int)(i % 4);
    const float *p = &v[3 * vtx];
    float o[3] = {p[0], p[1], p[2]}, d[3];
    for (int k = 0; k < 3; k++)
        d[k] = (sg & 2) ? -0.0f : 0.0f;
    d[a] = (sg & 1) ? -1.0f : 1.0f;
    o[a] -= d[a] * away;
    return test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY);
}

/* The rays of `rays` through scene s in packets of 4 (the rays of one
 * triangle's three vertices along one axis and sign) and in one stream:
 * each the answer rtk_intersect1 gave it (want). */
static void axis_rays_grouped(const char *what, rtk_scene s, const rtk_rayhit *want)
{
    rtk_rayhit *st = malloc(AXIS_RAYS * sizeof *st);
    assert_non_null(st);
    for (size_t i = 0; i < AXIS_RAYS; i++) {
        st[i] = (rtk_rayhit){.ray = want[i].ray};
        st[i].ray.tfar = INFINITY;
        st[i].hit.geomID = RTK_INVALID_GEOMETRY_ID;
    }
    assert_int_equal(rtk_intersect1M(s, st, AXIS_RAYS, sizeof *st), RTK_OK);
    for (size_t t = 0; t < AXIS_N; t++)
        for (size_t dir = 0; dir < 12; dir++) {
            _Alignas(64) uint32_t pk[20 * 4];
            const int valid[4] = {-1, -1, -1, 0};
            for (unsigned j = 0; j < 4; j++)
                test_packet_put(pk, 4, j, &st[(3 * t + (j < 3 ? j : 0)) * 12 + dir], 0);
            for (unsigned j = 0; j < 3; j++) { /* (fresh rays: the stream's hits are in st) */
                rtk_rayhit fresh = {.ray = want[(3 * t + j) * 12 + dir].ray};
                fresh.ray.tfar = INFINITY;
                fresh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
                test_packet_put(pk, 4, j, &fresh, 0);
            }
            assert_int_equal(test_trace_packet(s, 4, 0, valid, pk), RTK_OK);
            for (unsigned j = 0; j < 3; j++) {
                const size_t i = (3 * t + j) * 12 + dir;
                rtk_rayhit got;
                test_packet_get(pk, 4, j, &got, 0);
                if (memcmp(&got.ray.tfar, &want[i].ray.tfar, sizeof(float)) || got.hit.geomID != want[i].hit.geomID)
                    fail_msg("%s: packet ray %zu: t %a, alone %a", what, i, (double)got.ray.tfar,
                             (double)want[i].ray.tfar);
            }
        }
    for (size_t i = 0; i < AXIS_RAYS; i++)
        if (memcmp(&st[i].ray.tfar, &want[i].ray.tfar, sizeof(float)) || st[i].hit.geomID != want[i].hit.geomID)
            fail_msg("%s: stream ray %zu: t %a, alone %a", what, i, (double)st[i].ray.tfar, (double)want[i].ray.tfar);
    free(st);
}

/* The set at `scale` (every vertex multiplied by it), the rays starting
 * `away` from their vertex. */
static void axis_rays_at_scale(float scale_all, float away)
{
    enum { N = AXIS_N };
    rng r = {4242};
    float *v = malloc(9 * N * sizeof *v);
    uint32_t *idx = malloc(3 * N * sizeof *idx);
    rtk_rayhit *alone = malloc(AXIS_RAYS * sizeof *alone);
    assert_non_null(v);
    assert_non_null(idx);
    assert_non_null(alone);
    for (size_t i = 0; i < N; i++) {
        const float scale = scale_all * (i % 3 == 0 ? 1.0f : i % 3 == 1 ? 37.0f : 0.013f);
        float c[3];
        for (int k = 0; k < 3; k++)
            c[k] = scale * (4.0f * rng_float(&r) - 2.0f);
        for (int j = 0; j < 3; j++)
            for (int k = 0; k < 3; k++)
                v[9 * i + 3 * j + k] = c[k] + scale * (0.3f * rng_float(&r) - 0.15f);
        for (int j = 0; j < 3; j++)
            idx[3 * i + j] = (uint32_t)(3 * i + (size_t)j);
    }
    ref_mesh ref = ref_prepare(v, idx, N);
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene tris = test_scene(dev, v, 3 * N, idx, N);
        rtk_scene inst = test_instancing_scene(dev, tris);
        assert_int_equal(rtk_scene_commit(inst), RTK_OK);
        rtk_scene parts[AXIS_GROUPS];
        rtk_scene top = axis_parts_scene(dev, v, idx, parts);
        rtk_scene compact = test_scene_flags(dev, v, 3 * N, idx, N, RTK_SCENE_FLAG_COMPACT);
        rtk_scene robust = test_scene_flags(dev, v, 3 * N, idx, N, RTK_SCENE_FLAG_ROBUST);
        rtk_scene motion = axis_motion_scene(dev, v, 3 * N, idx, N, 0);
        rtk_scene robust_motion = axis_motion_scene(dev, v, 3 * N, idx, N, RTK_SCENE_FLAG_ROBUST);
        static const char *const form_names[7] = {"",         ", an instance", ", instances of parts", ", compact",
                                                  ", robust", ", motion",      ", robust motion"};
        for (int form = 0; form < 7; form++) {
            rtk_scene s = (rtk_scene[7]){tris, inst, top, compact, robust, motion, robust_motion}[form];
            ref.watertight = form == 4 || form == 6;
            char what[64];
            snprintf(what, sizeof what, "%s%s", names[b], form_names[form]);
            size_t hits = 0, missed = 0;
            for (size_t i = 0; i < AXIS_RAYS; i++) {
                const rtk_ray ray = axis_ray(v, i, away);
                rtk_rayhit *rh = &alone[i];
                *rh = (rtk_rayhit){.ray = ray};
                rh->hit.geomID = RTK_INVALID_GEOMETRY_ID;
                assert_int_equal(rtk_intersect1(s, rh), RTK_OK);
                if (form == 2 && rh->hit.geomID != RTK_INVALID_GEOMETRY_ID) /* (the part's triangle) */
                    rh->hit.primID += AXIS_PART * rh->hit.instID;
                rtk_tri_hit want;
                uint32_t prim = RTK_INVALID_GEOMETRY_ID;
                const int hit = ref_closest(&ref, &ray, &want, &prim);
                const int got = rh->hit.geomID != RTK_INVALID_GEOMETRY_ID;
                rtk_tri_hit same;
                hits += (size_t)hit;
                /* missed: no hit, or one on a farther triangle than the reference's */
                missed += (size_t)(hit && (!got || rh->ray.tfar > want.t));
                /* (at the tiny scale every triangle along a ray is 200 away
                 * to float precision and the closest is a tie: the t
                 * reported, clamped to tfar where another triangle came
                 * first, may be an ulp from the triangle's own) */
                if (got && (!hit || rh->ray.tfar < want.t ||
                            (ref_one(&ref, rh->hit.primID, &ray, &same) && rh->ray.tfar != same.t &&
                             (scale_all == 1.0f || rh->ray.tfar != nextafterf(same.t, 0.0f)))))
                    fail_msg("%s: ray %zu: t %a on %u, the reference's %a on %u", what, i, (double)rh->ray.tfar,
                             rh->hit.primID, hit ? (double)want.t : -1.0, prim);
            }
            print_message("%s: %zu axis rays through vertices hit, %zu of them missed\n", what, hits, missed);
            assert_true(hits > N);
            assert_int_equal(missed, 0);
            axis_rays_grouped(what, s, alone);
        }
        rtk_scene_release(robust_motion);
        rtk_scene_release(motion);
        rtk_scene_release(robust);
        rtk_scene_release(compact);
        rtk_scene_release(top);
        for (int g = 0; g < AXIS_GROUPS; g++)
            rtk_scene_release(parts[g]);
        rtk_scene_release(inst);
        rtk_scene_release(tris);
        rtk_device_release(dev);
    }
    ref_free(&ref);
    free(alone);
    free(v);
    free(idx);
}

static void test_axis_rays_through_vertices(void **state)
{
    (void)state;
    axis_rays_at_scale(1.0f, 200.0f);
}

/* The same at a scale of 1e-8 (a mesh some 7e-7 across), the rays
 * starting 1e7 away: the robust layouts' node tests move the origin away
 * from the far planes by 2^-20 of the tree's extent, which times the
 * clamped reciprocal 1e18 of a zero component was a far distance of about
 * 7e5, and 684 of the 5,508 rays the watertight reference hits missed on
 * every backend until those far planes became infinite.  (At 1e-9 some
 * triangles fall below rtk's range: the static layouts leave them out,
 * as the reference does, and the motion layouts keep them for their other
 * time steps, where they may be hit.) */
static void test_axis_rays_through_vertices_tiny(void **state)
{
    (void)state;
    axis_rays_at_scale(1e-8f, 1e7f);
}

/* Rays along the boundary edges x = 0 and x = 1 of a grid of 32 x 32
 * squares on [0, 1]^2 (z = 0), straight down with the x and y components
 * +0.0 or -0.0, from z = 10 and 1000: each hits the grid, alone, in packets
 * of 8 and in a stream.  With the origin's x at 0 and its direction -0.0,
 * the far plane of the boxes at the edge is the origin's own, and the
 * fused node test's padding of org * inv (2^-22 of it, and the least
 * normal) gave a far distance of about 1e-20: avx2 missed half of these
 * rays until such rays took the subtract-then-multiply test; in any-hit
 * streams traced by masks (avx2's stream_occluded_masks) they kept the
 * fused test, and rays of a long stream along x = 0 were not occluded. */
/* An any-hit stream traced on a thread of its own.  The stream kernels
 * keep which way traced fastest per thread and tree (core/stream.c), and a
 * tree at a freed one's address resumes what the freed one learnt: on a
 * new thread a stream measures every way afresh, by masks (avx2) on its
 * fourth window of 128 rays. */
typedef struct occluded_job {
    rtk_scene s;
    rtk_ray *rays;
    unsigned n;
    rtk_error err;
} occluded_job;

static void *occluded_job_run(void *p)
{
    occluded_job *j = p;
    j->err = rtk_occluded1M(j->s, j->rays, j->n, sizeof *j->rays);
    return NULL;
}

static void occluded_fresh_thread(rtk_scene s, rtk_ray *rays, unsigned n)
{
    occluded_job j = {s, rays, n, RTK_ERROR_UNKNOWN};
    pthread_t t;
    assert_int_equal(pthread_create(&t, NULL, occluded_job_run, &j), 0);
    assert_int_equal(pthread_join(t, NULL), 0);
    assert_int_equal(j.err, RTK_OK);
}

static void test_rays_along_grid_edges(void **state)
{
    (void)state;
    enum { G = 32, RAYS = 2 * 4 * 2 * 32 };
    float *v = malloc(3 * (G + 1) * (G + 1) * sizeof *v);
    uint32_t *idx = malloc(6 * G * G * sizeof *idx);
    assert_non_null(v);
    assert_non_null(idx);
    for (int j = 0; j <= G; j++)
        for (int i = 0; i <= G; i++) {
            float *q = &v[3 * (j * (G + 1) + i)];
            q[0] = (float)i / G, q[1] = (float)j / G, q[2] = 0.0f;
        }
    for (uint32_t j = 0, n = 0; j < G; j++)
        for (uint32_t i = 0; i < G; i++) {
            const uint32_t a = j * (G + 1) + i, b = a + 1, c = a + G + 2, d = a + G + 1;
            const uint32_t tri[6] = {a, b, c, a, c, d};
            memcpy(&idx[n], tri, sizeof tri);
            n += 6;
        }
    rtk_rayhit rays[RAYS];
    size_t n = 0;
    for (int x = 0; x < 2; x++)
        for (int sg = 0; sg < 4; sg++)
            for (int z = 0; z < 2; z++)
                for (int k = 0; k < 32; k++) {
                    rays[n] = (rtk_rayhit){.ray = test_ray((float)x, (0.5f + (float)k) / 32.0f, z ? 1000.0f : 10.0f,
                                                           (sg & 1) ? -0.0f : 0.0f, (sg & 2) ? -0.0f : 0.0f, -1.0f, 0.0f,
                                                           INFINITY)};
                    rays[n++].hit.geomID = RTK_INVALID_GEOMETRY_ID;
                }
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene s = test_scene(dev, v, (G + 1) * (G + 1), idx, 2 * G * G);
        rtk_rayhit st[RAYS];
        memcpy(st, rays, sizeof st);
        assert_int_equal(rtk_intersect1M(s, st, RAYS, sizeof *st), RTK_OK);
        for (size_t i = 0; i < RAYS; i++) {
            rtk_rayhit rh = rays[i];
            assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
            if (rh.hit.geomID != 0 || rh.ray.tfar != rays[i].ray.org_z || st[i].hit.geomID != 0 ||
                st[i].ray.tfar != rh.ray.tfar)
                fail_msg("%s: ray %zu from %g %g %g (dir x %g): t %g alone, %g in the stream", names[b], i,
                         (double)rays[i].ray.org_x, (double)rays[i].ray.org_y, (double)rays[i].ray.org_z,
                         (double)rays[i].ray.dir_x, (double)rh.ray.tfar, (double)st[i].ray.tfar);
        }
        /* any hits in a stream long enough for every way of tracing it
         * to be measured on some window (traverse_stream.h stream_window:
         * by masks, on avx2, the fourth window of 128, on a fresh thread),
         * the rays mixed so that each window has some along x = 0 */
        enum { LONG = 16 * RAYS };
        rtk_ray *occ = malloc(LONG * sizeof *occ);
        assert_non_null(occ);
        for (size_t i = 0; i < LONG; i++)
            occ[i] = rays[i * 37 % RAYS].ray;
        occluded_fresh_thread(s, occ, LONG);
        for (size_t i = 0; i < LONG; i++)
            if (occ[i].tfar != -INFINITY)
                fail_msg("%s: any hit, stream ray %zu (ray %zu) missed", names[b], i, i * 37 % RAYS);
        free(occ);
        for (size_t i = 0; i < RAYS; i += 8) {
            rtk_rayhit got[8];
            test_intersect8_rows(s, &rays[i], got);
            for (unsigned l = 0; l < 8; l++)
                if (got[l].hit.geomID != 0 || got[l].ray.tfar != rays[i + l].ray.org_z)
                    fail_msg("%s: packet ray %zu: t %g", names[b], i + l, (double)got[l].ray.tfar);
        }
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
    free(v);
    free(idx);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_axis_parallel_zero_and_negative_zero),
        cmocka_unit_test(test_nan_and_inf),
        cmocka_unit_test(test_time_without_motion),
        cmocka_unit_test(test_interval),
        cmocka_unit_test(test_origin_on_surface),
        cmocka_unit_test_setup_teardown(test_origin_on_box_far_plane, setup_flat_squares, restore_fixture),
        cmocka_unit_test(test_closest_of_several),
        cmocka_unit_test(test_huge_coordinates),
        cmocka_unit_test(test_spread_packets),
        cmocka_unit_test_setup_teardown(test_multi_block_leaf, setup_stacked_triangles, restore_fixture),
        cmocka_unit_test_setup_teardown(test_box_edges, setup_teeth, restore_fixture),
        cmocka_unit_test(test_axis_rays_through_vertices),
        cmocka_unit_test(test_axis_rays_through_vertices_tiny),
        cmocka_unit_test(test_rays_along_grid_edges),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
