/*
 * The range rtk answers in (rtk.h): triangles of every size from 1e-30 to
 * 1e30, on both sides of each limit (coordinates of 2^36, cross products of
 * 2^-80), counted and left out beyond them; rays along tiny and huge
 * directions and from origins far outside the scene, whose answers must
 * match the exact ones computed in double here, through single rays,
 * packets and streams alike; refits and motion blur that carry triangles
 * out of the range; and a SAH cost that stays finite.  On every backend,
 * in the default, compact and robust layouts.
 */
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "testlib.h"

#define MODES 3
static const unsigned mode_flags[MODES] = {RTK_SCENE_FLAG_NONE, RTK_SCENE_FLAG_COMPACT, RTK_SCENE_FLAG_ROBUST};
static const char *const mode_names[MODES] = {"default", "compact", "robust"};

static char backends[TEST_MAX_BACKENDS][32];
static size_t backend_count;

static int setup(void **state)
{
    (void)state;
    backend_count = test_backend_names(backends, TEST_MAX_BACKENDS);
    return 0;
}

static rtk_scene_info info_of(rtk_scene s)
{
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
    return info;
}

/* An octahedron of radius r around c: |x - c|_1 = r. */
static const uint32_t OCTA_IDX[8 * 3] = {0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5};
static void octahedron(double r, double c, float v[18])
{
    const double p[6][3] = {{c + r, c, c}, {c - r, c, c}, {c, c + r, c}, {c, c - r, c}, {c, c, c + r}, {c, c, c - r}};
    for (int i = 0; i < 6; i++)
        for (int k = 0; k < 3; k++)
            v[3 * i + k] = (float)p[i][k];
}

/* Where the float ray (o, d) first meets the octahedron's surface, in
 * double: |x|_1 along the ray is convex and piecewise linear, least where
 * a coordinate crosses zero, and the entry lies between the origin and
 * that point (bisection); -1 when it passes by.  Close to the edges the
 * float triangles and the exact surface differ: *edge is set where the
 * ray passes within 1e-4 of the radius of a silhouette or an edge. */
static double octa_exact(double r, double c, const float of[3], const float df[3], int *edge)
{
    const double o[3] = {of[0] - c, of[1] - c, of[2] - c}, d[3] = {df[0], df[1], df[2]};
#define L1(t) (fabs(o[0] + (t) * d[0]) + fabs(o[1] + (t) * d[1]) + fabs(o[2] + (t) * d[2]))
    double tmin = 0.0, least = L1(0.0);
    for (int k = 0; k < 3; k++) {
        const double t = d[k] != 0.0 ? -o[k] / d[k] : -1.0;
        if (t > 0.0 && L1(t) < least) {
            least = L1(t);
            tmin = t;
        }
    }
    *edge = fabs(least - r) < 1e-4 * r;
    if (!(least < r) || !(L1(0.0) > r))
        return -1.0;
    double lo = 0.0, hi = tmin;
    for (int it = 0; it < 200; it++) {
        const double m = 0.5 * (lo + hi);
        if (L1(m) > r)
            lo = m;
        else
            hi = m;
    }
    /* near an edge of the octahedron: one coordinate near zero */
    for (int k = 0; k < 3; k++)
        *edge |= fabs(o[k] + hi * d[k]) < 1e-4 * r;
#undef L1
    return hi;
}

typedef struct ray_case {
    float o[3], d[3];
    double exact; /* -1: a miss */
    int edge;     /* too close to an edge to insist */
} ray_case;

/* n rays from `dist` away toward points near the centre (unit directions
 * times 2^dscale), with their exact answers. */
static void octa_rays(double r, double c, double dist, int dscale, int n, uint64_t seed, ray_case *out)
{
    rng g = {seed};
    for (int i = 0; i < n; i++) {
        const double a = 6.283185307179586 * rng_float(&g), b = 1.6 * rng_float(&g) - 0.8;
        const double u[3] = {-cos(a) * sqrt(1 - b * b), -sin(a) * sqrt(1 - b * b), -b};
        /* aimed a little off the centre, so some rays pass by */
        const double aim[3] = {c + 0.6 * r * (rng_float(&g) - 0.5), c + 0.6 * r * (rng_float(&g) - 0.5), c};
        for (int k = 0; k < 3; k++) {
            out[i].o[k] = (float)(aim[k] - dist * u[k]);
            out[i].d[k] = (float)ldexp(u[k], dscale);
        }
        out[i].exact = octa_exact(r, c, out[i].o, out[i].d, &out[i].edge);
    }
}

static rtk_scene octa_scene(rtk_device dev, const float v[18], unsigned flags)
{
    return test_scene_flags(dev, v, 6, OCTA_IDX, 8, flags);
}

/* Each ray through intersect1, occluded1, a packet of 8 (with a plain
 * ray beside it) and a stream: the single-ray answer against the exact
 * one, the others against the single one, bit for bit.  Returns the hits. */
static int check_rays(rtk_scene s, const ray_case *rc, int n, const char *what)
{
    int hits = 0;
    for (int i = 0; i < n; i++) {
        rtk_rayhit rh;
        memset(&rh, 0, sizeof rh);
        rh.ray = test_ray(rc[i].o[0], rc[i].o[1], rc[i].o[2], rc[i].d[0], rc[i].d[1], rc[i].d[2], 0.0f, INFINITY);
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        const rtk_ray given = rh.ray;
        assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
        const int hit = rh.hit.geomID != RTK_INVALID_GEOMETRY_ID;
        hits += hit;
        /* the ray comes back as given but for tfar */
        assert_memory_equal(&rh.ray, &given, offsetof(rtk_ray, tfar));
        if (!rc[i].edge) {
            if (hit != (rc[i].exact >= 0.0))
                fail_msg("%s, ray %d: %s, exact %s (t %.9g)", what, i, hit ? "hit" : "missed",
                         rc[i].exact >= 0.0 ? "a hit" : "a miss", rc[i].exact);
            if (hit && !(fabs(rh.ray.tfar - rc[i].exact) <= 1e-5 * rc[i].exact))
                fail_msg("%s, ray %d: t %.9g, exact %.9g", what, i, rh.ray.tfar, rc[i].exact);
        }
        if (!hit)
            assert_true(rh.ray.tfar == INFINITY);
        rtk_ray occ = given;
        assert_int_equal(rtk_occluded1(s, &occ), RTK_OK);
        if ((occ.tfar == -INFINITY) != hit)
            fail_msg("%s, ray %d: occluded1 says %d, intersect1 %d", what, i, occ.tfar == -INFINITY, hit);
        if (!hit)
            assert_memory_equal(&occ, &given, sizeof occ);

        /* a packet of 8: this ray in lane 3, a plain one in lane 0 */
        _Alignas(32) rtk_rayhit8 p;
        memset(&p, 0, sizeof p);
        rtk_rayhit plain;
        memset(&plain, 0, sizeof plain);
        plain.ray = test_ray(0.0f, 0.0f, 0.0f, 1.0f, 0.0f, 0.0f, 0.0f, INFINITY);
        plain.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        rtk_rayhit mine = {.ray = given, .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
        test_packet_put(&p, 8, 0, &plain, 0);
        test_packet_put(&p, 8, 3, &mine, 0);
        const int valid[8] = {-1, 0, 0, -1, 0, 0, 0, 0};
        assert_int_equal(rtk_intersect8(s, valid, &p), RTK_OK);
        rtk_rayhit back;
        test_packet_get(&p, 8, 3, &back, 0);
        assert_memory_equal(&back.ray, &rh.ray, sizeof back.ray);
        assert_int_equal(back.hit.geomID, rh.hit.geomID);
        assert_int_equal(back.hit.primID, rh.hit.primID);

        /* a stream of three: plain, this ray, plain */
        rtk_rayhit st[3] = {plain, mine, plain};
        assert_int_equal(rtk_intersect1M(s, st, 3, sizeof *st), RTK_OK);
        assert_memory_equal(&st[1].ray, &rh.ray, sizeof rh.ray);
        assert_int_equal(st[1].hit.primID, rh.hit.primID);
        assert_int_equal(st[1].hit.geomID, rh.hit.geomID);
    }
    return hits;
}

/* An octahedron of radius r around c traced with rays for e = from, from
 * + step, ... to: along directions of 2^e unit lengths from 4 r away, or
 * (far) from 10^e away along directions of 2^(e % 4 - 2); returns the hits. */
static int sweep(rtk_scene s, const char *label, double r, double c, int from, int to, int step, int far)
{
    const int n = test_sanitized() ? 8 : 32;
    ray_case rc[32];
    int hits = 0;
    for (int e = from; e <= to; e += step) {
        char what[128];
        snprintf(what, sizeof what, far ? "%s, origin 1e%d away" : "%s, direction 2^%d", label, e);
        if (far)
            octa_rays(r, c, pow(10.0, e), (e % 4) - 2, n, 5u + (uint64_t)e, rc);
        else
            octa_rays(r, c, 4.0 * r, e, n, 77u + (uint64_t)(e + 200), rc);
        hits += check_rays(s, rc, n, what);
    }
    return hits;
}

/* Octahedra of radius 1e-30 ... 1e30 (at the origin and beside it): those
 * within the range are all there and answer every ray as the exact
 * computation does; the others are counted out, never hit, and leave the
 * SAH cost finite.  Before, sizes of 1e-19 and less or 1e20 and more were
 * counted as ordinary triangles and never hit, and the SAH cost of 1e19
 * and up was NaN. */
static void test_sizes(void **state)
{
    (void)state;
    const int n = test_sanitized() ? 16 : 48;
    ray_case rc[48];
    for (size_t b = 0; b < backend_count; b++) {
        rtk_device dev = test_device(backends[b]);
        for (int m = 0; m < MODES; m++)
            for (int e = -30; e <= 30; e += 3)
                for (int off = 0; off < 2; off++) {
                    const double r = pow(10.0, e), c = off ? 3.0 * r : 0.0;
                    float v[18];
                    octahedron(r, c, v);
                    const int in = r >= 1e-12 && c + r <= RTK_COORD_LIMIT;
                    rtk_scene s = octa_scene(dev, v, mode_flags[m]);
                    const rtk_scene_info info = info_of(s);
                    char what[96];
                    snprintf(what, sizeof what, "%s %s radius 1e%d at %g", backends[b], mode_names[m], e, c);
                    if (info.triangles != (in ? 8u : 0u) || info.triangles_out_of_range != (in ? 0u : 8u))
                        fail_msg("%s: %llu triangles, %llu out of range", what, (unsigned long long)info.triangles,
                                 (unsigned long long)info.triangles_out_of_range);
                    assert_true(isfinite(info.sah_cost));
                    assert_int_equal(info.triangles_skipped, 0);
                    assert_int_equal(info.triangles_degenerate, 0);
                    octa_rays(r, c, 4.0 * r, 0, n, 1000u + (uint64_t)e, rc);
                    const int hits = check_rays(s, rc, in ? n : 0, what);
                    if (in)
                        assert_true(hits > n / 4);
                    /* out of range: nothing is hit, whatever the ray */
                    for (int i = 0; !in && i < n; i++) {
                        rtk_rayhit rh = {.ray = test_ray(rc[i].o[0], rc[i].o[1], rc[i].o[2], rc[i].d[0], rc[i].d[1],
                                                         rc[i].d[2], 0.0f, INFINITY),
                                         .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
                        assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
                        assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID);
                    }
                    rtk_scene_release(s);
                }
        rtk_device_release(dev);
    }
}

/* The limits themselves: a coordinate of exactly 2^36 is in, the next
 * float above it out (either sign, any axis); a cross product of exactly
 * 2^-80 is in, one of 2^-81 out; zero area stays degenerate.  With the
 * triangles that are in hit where they should be. */
static void test_limits(void **state)
{
    (void)state;
    const float L = RTK_COORD_LIMIT, above = nextafterf(RTK_COORD_LIMIT, INFINITY);
    const float t = 0x1p-40f, t2 = 0x1p-41f;
    const float v[] = {
        /* 0: a corner exactly at the limit (x), in (floats there are 4096 apart) */
        L, 0, 0, L - 0x1p20f, 0, 0, L, 0x1p20f, 0,
        /* 1: a corner just above it (z, negative), out */
        0, 0, -above, 1, 0, -above, 0, 1, -above,
        /* 2: cross product exactly 2^-80 (legs 2^-40), in; at z = -1 */
        0, 0, -1, t, 0, -1, 0, t, -1,
        /* 3: cross product 2^-81 (legs 2^-40 and 2^-41), out; at z = -2 */
        0, 0, -2, t, 0, -2, 0, t2, -2,
        /* 4: no area (collinear), degenerate */
        0, 0, 0, 1, 1, 1, 2, 2, 2,
        /* 5: a needle within the range (1 long, 2^-60 wide at its end) */
        0, 0, 5, 1, 0, 5, 1, 0x1p-60f, 5,
    };
    const uint32_t idx[] = {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17};
    for (size_t b = 0; b < backend_count; b++) {
        rtk_device dev = test_device(backends[b]);
        for (int m = 0; m < MODES; m++) {
            rtk_scene s = test_scene_flags(dev, v, 18, idx, 6, mode_flags[m]);
            const rtk_scene_info info = info_of(s);
            assert_int_equal(info.triangles, 3);
            assert_int_equal(info.triangles_out_of_range, 2);
            assert_int_equal(info.triangles_degenerate, 1);
            assert_int_equal(info.triangles_skipped, 0);
            assert_true(isfinite(info.sah_cost));
            /* the tiny triangle that is in, hit from above at t = 1 */
            rtk_rayhit rh = {.ray = test_ray(t / 4, t / 4, 0.0f, 0.0f, 0.0f, -1.0f, 0.0f, INFINITY),
                             .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
            assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
            assert_int_equal(rh.hit.primID, 2);
            assert_float_equal(rh.ray.tfar, 1.0f, 1e-6f);
            /* the corner at the limit, hit from above */
            rh = (rtk_rayhit){.ray = test_ray(L - 0x1p18f, 0x1p16f, 10.0f, 0.0f, 0.0f, -1.0f, 0.0f, INFINITY),
                              .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
            assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
            assert_int_equal(rh.hit.primID, 0);
            assert_float_equal(rh.ray.tfar, 10.0f, 1e-6f);
            rtk_scene_release(s);
        }
        rtk_device_release(dev);
    }
}

/* Directions from 2^-120 to 2^120 times unit length: the same answers, the
 * distances scaled.  (0, 0, -1e-38) hits a square 1 below at t = 1e38; one
 * of 2^-140 would hit it beyond FLT_MAX, so misses; tfar still bounds. */
static void test_directions(void **state)
{
    (void)state;
    const float sq[] = {-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0};
    const uint32_t sq_idx[] = {0, 1, 2, 0, 2, 3};
    for (size_t b = 0; b < backend_count; b++) {
        rtk_device dev = test_device(backends[b]);
        for (int m = 0; m < MODES; m++) {
            float v[18];
            octahedron(1.0, 0.0, v);
            rtk_scene s = octa_scene(dev, v, mode_flags[m]);
            char label[64];
            snprintf(label, sizeof label, "%.31s %s", backends[b], mode_names[m]);
            sweep(s, label, 1.0, 0.0, -120, 120, 8, 0);
            rtk_scene_release(s);

            s = test_scene_flags(dev, sq, 4, sq_idx, 2, mode_flags[m]);
            const struct {
                float dz, tfar;
                int hit;
                float t;
            } cases[] = {
                {-1e-38f, INFINITY, 1, 1e38f}, {-1e-38f, 5e37f, 0, 0},     {-0x1p-140f, INFINITY, 0, 0},
                {-1e30f, INFINITY, 1, 1e-30f}, {-1e37f, INFINITY, 1, 1e-37f},   {-1e-20f, 1e21f, 1, 1e20f},
            };
            for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
                rtk_rayhit rh = {.ray = test_ray(0.25f, 0.5f, 1.0f, 0.0f, 0.0f, cases[i].dz, 0.0f, cases[i].tfar),
                                 .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
                const rtk_ray given = rh.ray;
                assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
                if (!cases[i].hit) {
                    if (rh.hit.geomID != RTK_INVALID_GEOMETRY_ID)
                        fail_msg("%s %s dz %g: a hit at %g", backends[b], mode_names[m], cases[i].dz, rh.ray.tfar);
                    assert_memory_equal(&rh.ray, &given, sizeof given);
                    continue;
                }
                if (rh.hit.geomID != 0 || !(fabsf(rh.ray.tfar - cases[i].t) <= 1e-6f * cases[i].t))
                    fail_msg("%s %s dz %g: geom %u t %g, expected t %g", backends[b], mode_names[m], cases[i].dz,
                             rh.hit.geomID, rh.ray.tfar, cases[i].t);
            }
            rtk_scene_release(s);
        }
        rtk_device_release(dev);
    }
}

/* Origins from 1e10 to 1e30 away from an octahedron of radius 1e9 (the
 * float rays can aim no better than 1e-7 of their distance): answers as
 * the exact ones along the same float rays, and misses where the scene
 * lies beyond tfar. */
static void test_far_origins(void **state)
{
    (void)state;
    for (size_t b = 0; b < backend_count; b++) {
        rtk_device dev = test_device(backends[b]);
        for (int m = 0; m < MODES; m++) {
            float v[18];
            octahedron(1e9, 2e9, v);
            rtk_scene s = octa_scene(dev, v, mode_flags[m]);
            char label[64];
            snprintf(label, sizeof label, "%.31s %s", backends[b], mode_names[m]);
            assert_true(sweep(s, label, 1e9, 2e9, 10, 30, 2, 1) > 8); /* (the nearer ones hit) */
            /* beyond tfar: a miss, the ray untouched */
            rtk_rayhit rh = {.ray = test_ray(1e20f, 2e9f, 2e9f, -1.0f, 0.0f, 0.0f, 0.0f, 1e19f),
                             .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
            const rtk_ray given = rh.ray;
            assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
            assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID);
            assert_memory_equal(&rh.ray, &given, sizeof given);
            /* tnear past the scene: a miss */
            rh.ray = test_ray(1e20f, 2e9f, 2e9f, -1.0f, 0.0f, 0.0f, 2e20f, INFINITY);
            assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
            assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID);
            /* and within: the near face at 1e20 - 2.8e9 */
            rh.ray = test_ray(1e20f, 2.1e9f, 2.1e9f, -1.0f, 0.0f, 0.0f, 0.0f, INFINITY);
            assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
            assert_int_equal(rh.hit.geomID, 0);
            assert_float_equal(rh.ray.tfar, 1e20f - 2.8e9f, 2e13f);
            rtk_scene_release(s);
        }
        rtk_device_release(dev);
    }
}

/* A refitted geometry whose vertices move beyond the range and back, and
 * a moving one that passes beyond it at one time step: counted and left
 * out, then back in. */
static void test_refit_and_motion(void **state)
{
    (void)state;
    for (size_t b = 0; b < backend_count; b++) {
        rtk_device dev = test_device(backends[b]);
        float v[18];
        octahedron(1.0, 0.0, v);
        rtk_scene s = NULL;
        assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
        rtk_geometry g = NULL;
        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
        assert_int_equal(rtk_geometry_set_build_quality(g, RTK_BUILD_QUALITY_REFIT), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, 6), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, OCTA_IDX, 0, 12, 8), RTK_OK);
        assert_int_equal(rtk_geometry_commit(g), RTK_OK);
        assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
        assert_int_equal(rtk_scene_commit(s), RTK_OK);
        assert_int_equal(info_of(s).triangles, 8);
        v[0] = 1e20f; /* vertex 0 (+x): four triangles */
        test_commit_moved(s, g);
        rtk_scene_info info = info_of(s);
        assert_int_equal(info.triangles, 4);
        assert_int_equal(info.triangles_out_of_range, 4);
        rtk_rayhit rh = {.ray = test_ray(5.0f, 0.1f, 0.1f, -1.0f, 0.0f, 0.0f, 0.0f, INFINITY),
                         .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
        assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
        assert_int_equal(rh.hit.geomID, 0); /* the -x side, through the hole */
        assert_float_equal(rh.ray.tfar, 5.0f + 0.8f, 1e-5f);
        v[0] = 1.0f;
        test_commit_moved(s, g);
        info = info_of(s);
        assert_int_equal(info.triangles, 8);
        assert_int_equal(info.triangles_out_of_range, 0);
        rh.ray = test_ray(5.0f, 0.1f, 0.1f, -1.0f, 0.0f, 0.0f, 0.0f, INFINITY);
        assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
        assert_float_equal(rh.ray.tfar, 5.0f - 0.8f, 1e-5f);
        rtk_geometry_release(g);
        rtk_scene_release(s);

        /* motion: step 1 puts vertex 2 (+y) beyond the range */
        float v1[18];
        octahedron(1.0, 0.0, v1);
        v1[7] = -1e12f;
        assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
        assert_int_equal(rtk_geometry_set_time_step_count(g, 2), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 0, v, 0, 12, 6), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 1, v1, 0, 12, 6), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, OCTA_IDX, 0, 12, 8), RTK_OK);
        assert_int_equal(rtk_geometry_commit(g), RTK_OK);
        assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
        assert_int_equal(rtk_scene_commit(s), RTK_OK);
        info = info_of(s);
        assert_int_equal(info.triangles, 4);
        assert_int_equal(info.triangles_out_of_range, 4);
        assert_true(isfinite(info.sah_cost));
        rtk_geometry_release(g);
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_sizes),
        cmocka_unit_test(test_limits),
        cmocka_unit_test(test_directions),
        cmocka_unit_test(test_far_origins),
        cmocka_unit_test(test_refit_and_motion),
    };
    return cmocka_run_group_tests(tests, setup, NULL);
}
