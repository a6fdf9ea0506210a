/*
 * Streams and packets through two-level scenes (traverse_objects_stream.h):
 * every ray of rtk_intersect1M / rtk_occluded1M and of the packet calls
 * gets rtk_intersect1's and rtk_occluded1's answer, to the bit, on every
 * backend, in scenes of instances (rotated, scaled, overlapping, beside a
 * world-space mesh), a dynamic scene whose overlapping geometries' trees
 * the top level opens, a top level wide enough for 8-wide nodes, instances
 * of instances with user geometry, robust and compact scenes, and with
 * ray masks, an instance's mask and a filter (the rays that need them go
 * the single-ray way in the middle of a stream).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "testlib.h"
#include "user_spheres.h"

/* The ball the scenes are made of (test_two_level_streams makes it). */
static test_mesh ball;

/* Rays from [-3, 3]^3: a third towards the middle, the others in random
 * directions; every fourth with a ray mask of 1, 2 or all ones. */
static rtk_rayhit *make_rays(size_t n, uint64_t seed)
{
    static const uint32_t masks[3] = {1u, 2u, ~0u};
    rtk_rayhit *rh = malloc(n * sizeof *rh);
    assert_non_null(rh);
    rng r = {seed};
    for (size_t i = 0; i < n; i++) {
        float o[3], d[3];
        for (int k = 0; k < 3; k++) {
            o[k] = 6.0f * rng_float(&r) - 3.0f;
            d[k] = i % 3 ? 2.0f * rng_float(&r) - 1.0f : 0.5f * rng_float(&r) - 0.25f - o[k];
        }
        rh[i] = (rtk_rayhit){.ray = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY)};
        if (i % 4 == 1)
            rh[i].ray.mask = masks[i / 4 % 3];
        if (i % 7 == 3) /* a ray that starts on its way */
            rh[i].ray.tnear = 0.5f;
        rh[i].hit.geomID = rh[i].hit.primID = rh[i].hit.instID = RTK_INVALID_GEOMETRY_ID;
    }
    return rh;
}

/* The single calls' answers against the stream's (n rays, records `stride`
 * bytes apart) and the packets' (4, 8 and 16 wide, some lanes off), to the
 * bit. */
static void expect_same(rtk_scene s, const rtk_rayhit *rh, size_t n, int occluded, const char *what)
{
    const size_t size = occluded ? sizeof(rtk_ray) : sizeof(rtk_rayhit), stride = size + 12;
    rtk_rayhit *one = malloc(n * sizeof *one);
    unsigned char *many = malloc(n * stride);
    assert_true(one && many);
    for (size_t i = 0; i < n; i++) {
        one[i] = rh[i];
        memcpy(many + i * stride, &rh[i], size);
        assert_int_equal(occluded ? rtk_occluded1(s, &one[i].ray) : rtk_intersect1(s, &one[i]), RTK_OK);
    }
    assert_int_equal(occluded ? rtk_occluded1M(s, (rtk_ray *)(void *)many, (uint32_t)n, stride)
                              : rtk_intersect1M(s, (rtk_rayhit *)(void *)many, (uint32_t)n, stride),
                     RTK_OK);
    size_t hits = 0;
    for (size_t i = 0; i < n; i++) {
        if (memcmp(many + i * stride, &one[i], size))
            fail_msg("%s: ray %zu's %s answer differs as a stream", what, i, occluded ? "any-hit" : "closest-hit");
        hits += occluded ? one[i].ray.tfar == -INFINITY : one[i].hit.geomID != RTK_INVALID_GEOMETRY_ID;
    }
    assert_true(hits > n / 20 && hits < n); /* (rays that hit and rays that miss) */
    static const unsigned widths[3] = {4, 8, 16};
    for (int w = 0; w < 3; w++) {
        const unsigned k = widths[w];
        _Alignas(64) uint32_t packet[20 * 16];
        _Alignas(64) int valid[16];
        for (size_t i0 = 0; i0 + k <= n; i0 += k) {
            for (unsigned l = 0; l < k; l++) {
                valid[l] = (i0 / k + l) % 5 ? -1 : 0;
                test_packet_put(packet, k, l, &rh[i0 + l], occluded);
            }
            assert_int_equal(test_trace_packet(s, k, occluded, valid, packet), RTK_OK);
            for (unsigned l = 0; l < k; l++) {
                rtk_rayhit got;
                test_packet_get(packet, k, l, &got, occluded);
                if (memcmp(&got, valid[l] ? &one[i0 + l] : &rh[i0 + l], occluded ? sizeof(rtk_ray) : sizeof got))
                    fail_msg("%s: ray %zu's %s answer differs in a packet of %u", what, i0 + l,
                             occluded ? "any-hit" : "closest-hit", k);
            }
        }
    }
    free(one);
    free(many);
}

static void expect_same_both(rtk_scene s, const rtk_rayhit *rh, size_t n, const char *what)
{
    expect_same(s, rh, n, 0, what);
    expect_same(s, rh, n, 1, what);
}

/* Ball triangles [t0, t1) as a geometry of scene s, its vertices moved by
 * `shift` along x (so some pieces overlap their neighbours), mask `mask`. */
static rtk_geometry attach_piece(rtk_device dev, rtk_scene s, size_t t0, size_t t1, float *v, float shift,
                                 uint32_t mask)
{
    for (size_t i = 0; i < ball.nv; i++) {
        memcpy(v + 3 * i, ball.v + 3 * i, 3 * sizeof(float));
        v[3 * i] += shift;
    }
    rtk_geometry g;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, ball.nv), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, ball.idx + 3 * t0, 0, 12, t1 - t0),
                     RTK_OK);
    assert_int_equal(rtk_geometry_set_mask(g, mask), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
    return g;
}

/* A rotation about axis (1, 1, 1)-ish by angle a, scale sc, then a move to c. */
static void place(float m[12], float a, float sc, float cx, float cy, float cz)
{
    const float c = cosf(a), s = sinf(a), k = 0.57735027f, t = 1.0f - c;
    const float r[3][3] = {{t * k * k + c, t * k * k - s * k, t * k * k + s * k},
                           {t * k * k + s * k, t * k * k + c, t * k * k - s * k},
                           {t * k * k - s * k, t * k * k + s * k, t * k * k + c}};
    const float at[3] = {cx, cy, cz};
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++)
            m[4 * i + j] = sc * r[i][j];
        m[4 * i + 3] = at[i];
    }
}

/* Every odd primitive rejected: a filter on an instanced geometry. */
static int reject_odd(const rtk_filter_args *a)
{
    return a->hit->primID % 2 == 0;
}

static void test_two_level_streams(void **state)
{
    (void)state;
    ball = test_ball(16);
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    const size_t n = 2000;
    rtk_rayhit *rh = make_rays(n, 11);
    float *pieces = malloc(6 * ball.nv * 3 * sizeof(float)), *world = malloc(ball.nv * 3 * sizeof(float));
    assert_true(pieces && world);
    static const unsigned flags[3] = {RTK_SCENE_FLAG_NONE, RTK_SCENE_FLAG_COMPACT, RTK_SCENE_FLAG_ROBUST};
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (int fl = 0; fl < 3; fl++) {
            /* dynamic: the ball in six overlapping geometries (opened into
             * the top level), one with mask 2 */
            rtk_scene dyn;
            assert_int_equal(rtk_scene_new(dev, &dyn), RTK_OK);
            assert_int_equal(rtk_scene_set_flags(dyn, RTK_SCENE_FLAG_DYNAMIC | flags[fl]), RTK_OK);
            for (int p = 0; p < 6; p++)
                rtk_geometry_release(attach_piece(dev, dyn, ball.nt * (size_t)p / 6, ball.nt * (size_t)(p + 1) / 6,
                                                  pieces + 3 * ball.nv * (size_t)p, 0.1f * (float)p - 0.25f,
                                                  p == 2 ? 2u : ~0u));
            assert_int_equal(rtk_scene_commit(dyn), RTK_OK);
            expect_same_both(dyn, rh, n, "dynamic");

            /* instances: rotated, scaled and overlapping, of a ball whose
             * geometry has a filter, one instance with mask 2, beside a
             * world-space ball */
            rtk_scene inner;
            assert_int_equal(rtk_scene_new(dev, &inner), RTK_OK);
            assert_int_equal(rtk_scene_set_flags(inner, flags[fl]), RTK_OK);
            float *own = malloc(ball.nv * 3 * sizeof(float));
            assert_non_null(own);
            rtk_geometry g = attach_piece(dev, inner, 0, ball.nt, own, 0.0f, ~0u);
            assert_int_equal(rtk_scene_commit(inner), RTK_OK);
            rtk_scene inst;
            assert_int_equal(rtk_scene_new(dev, &inst), RTK_OK);
            assert_int_equal(rtk_scene_set_flags(inst, flags[fl]), RTK_OK);
            for (int i = 0; i < 18; i++) {
                float m[12];
                place(m, 0.4f * (float)i, 0.3f + 0.05f * (float)(i % 4), 0.9f * (float)(i % 3) - 0.9f,
                      0.9f * (float)(i / 3 % 3) - 0.9f, 0.8f * (float)(i / 9) - 0.4f);
                const uint32_t id = test_attach_instance(dev, inst, inner, m);
                if (i == 4) {
                    rtk_geometry ig = rtk_scene_get_geometry(inst, id);
                    assert_non_null(ig);
                    assert_int_equal(rtk_geometry_set_mask(ig, 2u), RTK_OK);
                    assert_int_equal(rtk_geometry_commit(ig), RTK_OK);
                }
            }
            rtk_geometry_release(attach_piece(dev, inst, 0, ball.nt, world, 1.7f, ~0u));
            assert_int_equal(rtk_scene_commit(inst), RTK_OK);
            expect_same_both(inst, rh, n, "instances");
            /* the filter: rays that hit the instances take the features' way */
            assert_int_equal(rtk_geometry_set_intersect_filter(g, reject_odd), RTK_OK);
            assert_int_equal(rtk_geometry_set_occluded_filter(g, reject_odd), RTK_OK);
            assert_int_equal(rtk_geometry_commit(g), RTK_OK);
            assert_int_equal(rtk_scene_commit(inner), RTK_OK);
            assert_int_equal(rtk_scene_commit(inst), RTK_OK);
            expect_same_both(inst, rh, n, "instances with a filter");
            rtk_geometry_release(g);

            /* instances of instances, beside user geometry */
            rtk_scene nest;
            assert_int_equal(rtk_scene_new(dev, &nest), RTK_OK);
            float m[12];
            place(m, 0.3f, 0.8f, 0.2f, -0.1f, 0.0f);
            test_attach_instance(dev, nest, inst, m);
            sphere_set sp;
            spheres_make(&sp, 5);
            rtk_geometry sg = spheres_geometry(dev, &sp, NULL);
            assert_int_equal(rtk_scene_attach_geometry(nest, sg, NULL), RTK_OK);
            rtk_geometry_release(sg);
            assert_int_equal(rtk_scene_commit(nest), RTK_OK);
            expect_same_both(nest, rh, n, "instances of instances and user geometry");
            rtk_scene_release(nest);
            rtk_scene_release(inst);
            rtk_scene_release(inner);
            rtk_scene_release(dyn);
            free(own);
        }
        /* a top level of 600 instances (8-wide nodes in the backends that
         * walk them so) */
        rtk_scene small = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt), many;
        assert_int_equal(rtk_scene_new(dev, &many), RTK_OK);
        for (int i = 0; i < 600; i++) {
            float m[12];
            place(m, 0.1f * (float)i, 0.12f, 0.25f * (float)(i % 20) - 2.4f, 0.3f * (float)(i / 20 % 15) - 2.1f,
                  0.5f * (float)(i / 300) - 0.25f);
            test_attach_instance(dev, many, small, m);
        }
        assert_int_equal(rtk_scene_commit(many), RTK_OK);
        expect_same_both(many, rh, n, "600 instances");
        rtk_scene_info info = {.struct_size = sizeof info};
        assert_int_equal(rtk_scene_get_info(many, &info), RTK_OK);
        assert_true(info.stream_in_flight >= 4); /* the two-level stream kernel */
        rtk_scene_release(many);
        rtk_scene_release(small);
        rtk_device_release(dev);
    }
    free(rh);
    free(pieces);
    free(world);
    free(ball.v);
    free(ball.idx);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_two_level_streams),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
