/*
 * rtk_offset_ray_origin (rtk.h): secondary rays that leave a surface.
 *
 * Self-intersection: rays leave a closed convex mesh (a UV sphere) outward
 * from points on its triangles; any hit is the surface hitting itself.
 * Lost geometry: rays leave a square toward a parallel one d above it; a
 * miss of the second square is geometry lost.  Both for three ways of
 * starting the ray: at the point with tnear = 0, at the point with a fixed
 * tnear (1e-4 of the scene's size, a common choice), and at
 * rtk_offset_ray_origin's point with tnear = 0; the mesh moved from the
 * origin to 1e5, where a fixed epsilon stops scaling with the rounding.
 * The offset method must never self-intersect and must keep geometry more
 * than 1024 ulps of the coordinate away; the others' rates are printed.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "testlib.h"

enum { METHOD_NAIVE, METHOD_EPSILON, METHOD_OFFSET, METHODS };
static const char *const method_names[METHODS] = {"p, tnear 0", "p, tnear 1e-4 size", "offset, tnear 0"};

/* The best backend of this build (test_backend_names lists it last). */
static rtk_device best_device(void)
{
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    assert_true(nb > 0);
    return test_device(names[nb - 1]);
}

static rtk_ray start(int method, const float p[3], const float n[3], const float d[3], float size)
{
    float o[3] = {p[0], p[1], p[2]};
    if (method == METHOD_OFFSET)
        rtk_offset_ray_origin(p, n, o);
    return test_ray(o[0], o[1], o[2], d[0], d[1], d[2], method == METHOD_EPSILON ? 1e-4f * size : 0.0f, INFINITY);
}

/* A direction around n, cosine-weighted, sometimes grazing (within 1 degree of the tangent plane). */
static void hemisphere(rng *g, const float n[3], float d[3])
{
    float t[3], b[3];
    const float a[3] = {fabsf(n[0]) < 0.9f ? 1.0f : 0.0f, fabsf(n[0]) < 0.9f ? 0.0f : 1.0f, 0.0f};
    t[0] = a[1] * n[2] - a[2] * n[1], t[1] = a[2] * n[0] - a[0] * n[2], t[2] = a[0] * n[1] - a[1] * n[0];
    const float tl = sqrtf(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
    for (int k = 0; k < 3; k++)
        t[k] /= tl;
    b[0] = n[1] * t[2] - n[2] * t[1], b[1] = n[2] * t[0] - n[0] * t[2], b[2] = n[0] * t[1] - n[1] * t[0];
    const float phi = 6.2831853f * rng_float(g);
    float ct = sqrtf(rng_float(g));
    if (rng_u32(g) % 8 == 0)
        ct = 0.0175f * rng_float(g) + 1e-4f; /* grazing */
    const float st = sqrtf(1.0f - ct * ct);
    for (int k = 0; k < 3; k++)
        d[k] = st * cosf(phi) * t[k] + st * sinf(phi) * b[k] + ct * n[k];
}

static void test_self_intersection(void **state)
{
    (void)state;
    rtk_device dev = best_device();
    enum { RINGS = 60, SEGS = 120 };
    const size_t nv = (RINGS + 1) * SEGS, nt = 2 * RINGS * SEGS;
    float *v0 = malloc(nv * 3 * sizeof *v0), *v = malloc(nv * 3 * sizeof *v);
    uint32_t *idx = malloc(nt * 3 * sizeof *idx);
    for (int r = 0; r <= RINGS; r++)
        for (int s = 0; s < SEGS; s++) {
            const double th = M_PI * r / RINGS, ph = 2 * M_PI * s / SEGS;
            float *q = v0 + 3 * (r * SEGS + s);
            q[0] = (float)(sin(th) * cos(ph)), q[1] = (float)(sin(th) * sin(ph)), q[2] = (float)cos(th);
        }
    size_t t = 0;
    for (int r = 0; r < RINGS; r++)
        for (int s = 0; s < SEGS; s++) {
            const uint32_t a = (uint32_t)(r * SEGS + s), b = (uint32_t)(r * SEGS + (s + 1) % SEGS);
            const uint32_t c = a + SEGS, d = b + SEGS;
            const uint32_t tri[2][3] = {{a, c, b}, {b, c, d}};
            for (int k = 0; k < 2; k++)
                memcpy(idx + 3 * t++, tri[k], sizeof tri[k]);
        }
    static const float offsets[] = {0.0f, 100.0f, 1e4f, 1e5f};
    print_message("self-intersections of rays leaving a closed sphere (radius 1) outward, per method:\n");
    for (size_t oi = 0; oi < sizeof offsets / sizeof offsets[0]; oi++) {
        const float off = offsets[oi];
        for (size_t i = 0; i < nv; i++)
            for (int k = 0; k < 3; k++)
                v[3 * i + k] = v0[3 * i + k] + off;
        rtk_scene scene = test_scene(dev, v, nv, idx, nt);
        rng g = {oi + 1};
        size_t self[METHODS] = {0}, rays = 0;
        for (size_t tr = 0; tr < nt; tr++) {
            const float *a = v + 3 * idx[3 * tr], *b = v + 3 * idx[3 * tr + 1], *c = v + 3 * idx[3 * tr + 2];
            double e1[3], e2[3], nd[3];
            for (int k = 0; k < 3; k++)
                e1[k] = (double)b[k] - a[k], e2[k] = (double)c[k] - a[k];
            nd[0] = e1[1] * e2[2] - e1[2] * e2[1], nd[1] = e1[2] * e2[0] - e1[0] * e2[2],
            nd[2] = e1[0] * e2[1] - e1[1] * e2[0];
            const double nl = sqrt(nd[0] * nd[0] + nd[1] * nd[1] + nd[2] * nd[2]);
            if (!(nl > 0))
                continue; /* the poles' degenerate triangles */
            for (int rep = 0; rep < 2; rep++) {
                float u = rng_float(&g), w = rng_float(&g);
                if (u + w > 1.0f)
                    u = 1.0f - u, w = 1.0f - w;
                float p[3], n[3], d[3];
                for (int k = 0; k < 3; k++) {
                    p[k] = a[k] + u * (b[k] - a[k]) + w * (c[k] - a[k]); /* as a renderer computes it, in float */
                    n[k] = (float)(nd[k] / nl);
                }
                /* outward: away from the centre */
                const float out = (p[0] - off) * n[0] + (p[1] - off) * n[1] + (p[2] - off) * n[2];
                if (out < 0.0f)
                    for (int k = 0; k < 3; k++)
                        n[k] = -n[k];
                hemisphere(&g, n, d);
                rays++;
                for (int m = 0; m < METHODS; m++) {
                    rtk_ray ray = start(m, p, n, d, 2.0f);
                    assert_int_equal(rtk_occluded1(scene, &ray), RTK_OK);
                    self[m] += ray.tfar == -INFINITY;
                }
            }
        }
        print_message("  sphere at %g: %zu rays; %s %zu (%.3f%%), %s %zu (%.3f%%), %s %zu\n", (double)off, rays,
                      method_names[0], self[0], 100.0 * (double)self[0] / (double)rays, method_names[1], self[1],
                      100.0 * (double)self[1] / (double)rays, method_names[2], self[2]);
        if (self[METHOD_OFFSET])
            fail_msg("rtk_offset_ray_origin: %zu of %zu rays leaving the sphere at %g hit it", self[METHOD_OFFSET],
                     rays, (double)off);
        assert_true(off == 0.0f || self[METHOD_NAIVE] > 0); /* the test can tell */
        rtk_scene_release(scene);
    }
    free(v0);
    free(v);
    free(idx);
    rtk_device_release(dev);
}

/* Two squares, A at z = z0 and B at z0 + d (d in ulps of z0), rays from A
 * up toward B: the fraction that misses B. */
static double lost_fraction(rtk_device dev, float z0, int ulps, int method, float size)
{
    float zB = z0;
    for (int i = 0; i < ulps; i++)
        zB = nextafterf(zB, INFINITY);
    /* rays start within |x|, |y| < size / 2 and go up at least 30 degrees
     * from the plane, so B is wide enough to be met by every one */
    const float h = size, hb = size + 2.0f * (zB - z0);
    const float v[] = {-h, -h, z0, h, -h, z0, h, h, z0, -h, h, z0, -hb, -hb, zB, hb, -hb, zB, hb, hb, zB, -hb, hb, zB};
    const uint32_t idx[] = {0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7};
    rtk_scene scene = test_scene(dev, v, 8, idx, 4);
    rng g = {(uint64_t)ulps * 31 + (uint64_t)method};
    int lost = 0;
    const int rays = 2000;
    for (int i = 0; i < rays; i++) {
        const float p[3] = {(rng_float(&g) - 0.5f) * h, (rng_float(&g) - 0.5f) * h, z0};
        const float n[3] = {0.0f, 0.0f, 1.0f};
        float d[3];
        rtk_rayhit rh;
        do { /* steep enough to meet B inside the square */
            hemisphere(&g, n, d);
        } while (d[2] < 0.5f);
        rh.ray = start(method, p, n, d, size);
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1(scene, &rh), RTK_OK);
        /* B's triangles are primitives 2 and 3; a hit on A (0, 1) is a self-intersection */
        lost += rh.hit.geomID == RTK_INVALID_GEOMETRY_ID || rh.hit.primID < 2;
    }
    rtk_scene_release(scene);
    return (double)lost / rays;
}

static void test_lost_geometry(void **state)
{
    (void)state;
    rtk_device dev = best_device();
    static const float heights[] = {1.0f, 1e3f, 1e5f};
    static const int ulps[] = {4, 64, 256, 512, 1024, 4096, 65536};
    print_message("rays from a square to a parallel one d ulps (of the coordinate) above: lost or self-hit, per "
                  "method\n");
    for (size_t hi = 0; hi < sizeof heights / sizeof heights[0]; hi++) {
        for (size_t ui = 0; ui < sizeof ulps / sizeof ulps[0]; ui++) {
            double f[METHODS];
            for (int m = 0; m < METHODS; m++)
                f[m] = lost_fraction(dev, heights[hi], ulps[ui], m, 1.0f);
            print_message("  z %-6g d %6d ulps (%-9.3g): %s %5.1f%%, %s %5.1f%%, %s %5.1f%%\n", (double)heights[hi],
                          ulps[ui], (double)(nextafterf(heights[hi], INFINITY) - heights[hi]) * ulps[ui],
                          method_names[0], 100 * f[0], method_names[1], 100 * f[1], method_names[2], 100 * f[2]);
            /* the offset is at most 256 ulps along z (plus the rounding of
             * the intersection): beyond 1024 ulps nothing is lost */
            if (ulps[ui] >= 1024 && f[METHOD_OFFSET] > 0.0)
                fail_msg("rtk_offset_ray_origin lost %.2f%% of the rays to a surface %d ulps away at z = %g",
                         100 * f[METHOD_OFFSET], ulps[ui], (double)heights[hi]);
        }
    }
    rtk_device_release(dev);
}

static void test_edge_values(void **state)
{
    (void)state;
    const float n[3] = {0.0f, 0.6f, -0.8f};
    float out[3];
    /* near zero: a fixed step; far: whole ulps, away from zero along n */
    rtk_offset_ray_origin((const float[3]){0.0f, 0.01f, -0.01f}, n, out);
    assert_true(out[0] == 0.0f && out[1] > 0.01f && out[2] < -0.01f);
    rtk_offset_ray_origin((const float[3]){1.0f, 1e6f, -1e6f}, n, out);
    assert_true(out[0] == 1.0f && out[1] > 1e6f && out[2] < -1e6f);
    assert_true(out[1] - 1e6f <= 256 * 0.0625f); /* at most 256 ulps (an ulp of 1e6 is 1/16) */
    /* the float range's edge: left in place rather than made infinite */
    rtk_offset_ray_origin((const float[3]){3.4e38f, -3.4e38f, 1.0f}, (const float[3]){1.0f, -1.0f, 0.0f}, out);
    assert_true(isfinite(out[0]) && isfinite(out[1]) && out[2] == 1.0f);
    /* NaN in, NaN (an invalid ray) or the point out: never a crash */
    rtk_offset_ray_origin((const float[3]){NAN, 2.0f, 2.0f}, (const float[3]){NAN, NAN, 1.0f}, out);
    assert_true(isnan(out[0]) && out[1] == 2.0f && out[2] > 2.0f);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_self_intersection),
        cmocka_unit_test(test_lost_geometry),
        cmocka_unit_test(test_edge_values),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
