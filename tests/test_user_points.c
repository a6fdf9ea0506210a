/*
 * Closest points on user geometry (rtk_geometry_set_point_query_function):
 * spheres whose point query function gives their nearest surface point,
 * against brute force in double, on every backend: alone, beside a
 * triangle mesh, through a rotated, scaled and moved instance (the answer
 * and its normal in the scene's space), within a radius, in batches; the
 * function is asked only for the primitives whose box is within the best
 * distance; and the scenes that must still be refused are (a user
 * geometry without the function, and the setter on other geometry).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "geometry/affine.h"
#include "geometry/closest_point.h"
#include "testlib.h"
#include "user_spheres.h"

enum { POINTS = 400 };

/* The floor: two triangles of the square [-3, 3]^2 at z = -2.5. */
static const float floor_v[] = {-3, -3, -2.5f, 3, -3, -2.5f, 3, 3, -2.5f, -3, 3, -2.5f};
static const uint32_t floor_idx[] = {0, 1, 2, 0, 2, 3};

/* The reference in the scene's space: the spheres through xfm (a rotation,
 * a uniform scale and a move; NULL: as they are), and the floor when asked.
 * Returns the distance; *prim the nearest sphere, or SPHERES + t for floor
 * triangle t. */
static double reference(const sphere_set *s, const double *xfm, double scale, int with_floor, const double *q,
                        size_t *prim)
{
    double best = INFINITY;
    for (size_t i = 0; i < SPHERES; i++) {
        double c[3];
        if (xfm)
            rtk_affine_apply(xfm, s->c[i], c);
        else
            memcpy(c, s->c[i], sizeof c);
        const double d[3] = {q[0] - c[0], q[1] - c[1], q[2] - c[2]};
        const double dist = fabs(sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) - s->r[i] * scale);
        if (dist < best)
            best = dist, *prim = i;
    }
    for (size_t t = 0; with_floor && t < 2; t++) {
        double v[3][3];
        for (int j = 0; j < 3; j++)
            for (int k = 0; k < 3; k++)
                v[j][k] = floor_v[3 * floor_idx[3 * t + (size_t)j] + (size_t)k];
        rtk_tri_closest c;
        rtk_closest_point_triangle(&c, q, v[0], v[1], v[2]);
        if (sqrt(c.d2) < best)
            best = sqrt(c.d2), *prim = SPHERES + t;
    }
    return best;
}

static void query_points(double (*q)[3], uint64_t seed)
{
    rng r = {seed};
    for (int i = 0; i < POINTS; i++)
        for (int k = 0; k < 3; k++)
            q[i][k] = 7.0 * rng_float(&r) - 3.5;
}

/* Each point's answer against the reference (near ties: either sphere). */
static void check_scene(const char *what, rtk_scene s, const sphere_set *sp, const double *xfm, double scale,
                        int with_floor, uint32_t sphere_geom, uint32_t sphere_inst, double (*q)[3])
{
    rtk_point_query qs[POINTS];
    rtk_point_hit one[POINTS], batch[POINTS];
    for (int i = 0; i < POINTS; i++) {
        qs[i] = (rtk_point_query){.x = q[i][0], .y = q[i][1], .z = q[i][2], .radius = INFINITY};
        assert_int_equal(rtk_closest_point(s, &qs[i], &one[i]), RTK_OK);
    }
    assert_int_equal(rtk_closest_point_batch(s, qs, batch, POINTS), RTK_OK);
    for (int i = 0; i < POINTS; i++) {
        size_t prim = 0;
        const double want = reference(sp, xfm, scale, with_floor, q[i], &prim);
        const rtk_point_hit *h = &one[i];
        if (!(fabs(h->distance - want) <= 1e-12 * (1.0 + want)))
            fail_msg("%s: point %d (%g %g %g): distance %.17g, the reference %.17g (prim %zu)", what, i, q[i][0],
                     q[i][1], q[i][2], h->distance, want, prim);
        /* the point reported is at that distance */
        const double d[3] = {h->x - q[i][0], h->y - q[i][1], h->z - q[i][2]};
        assert_true(fabs(sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) - h->distance) <= 1e-12 * (1.0 + want));
        if (prim < SPHERES) {
            /* (a tie: another sphere at the same distance to 1e-12 is as right) */
            if (h->geomID != sphere_geom || h->instID != sphere_inst || h->primID >= SPHERES)
                fail_msg("%s: point %d: geom %u inst %u prim %u, the reference's sphere %zu", what, i, h->geomID,
                         h->instID, h->primID, prim);
            /* the normal: unit, along the centre-to-point direction in the scene's space */
            double c[3];
            if (xfm)
                rtk_affine_apply(xfm, sp->c[h->primID], c);
            else
                memcpy(c, sp->c[h->primID], sizeof c);
            const double o[3] = {h->x - c[0], h->y - c[1], h->z - c[2]};
            const double ol = sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2]);
            const double dot = (o[0] * h->n_x + o[1] * h->n_y + o[2] * h->n_z) / ol;
            if (!(dot > 1.0 - 1e-6))
                fail_msg("%s: point %d: normal (%g %g %g) against the radius' direction: cos %g", what, i,
                         (double)h->n_x, (double)h->n_y, (double)h->n_z, dot);
        } else {
            /* (either floor triangle: a point nearest their shared corner is a tie) */
            assert_true((h->geomID != sphere_geom || h->instID != sphere_inst) && h->primID < 2);
        }
        assert_memory_equal(&batch[i], h, sizeof *h);
    }
}

static void test_spheres(void **state)
{
    (void)state;
    static sphere_set sp;
    spheres_make(&sp, 7);
    double q[POINTS][3];
    query_points(q, 8);
    /* turned a third about (1, 1, 1) (x -> y -> z -> x), scaled by 2 and
     * moved: a similarity that floats hold exactly, so that the nearest
     * point in the spheres' space is the nearest in the scene's */
    const float xf[12] = {0, 0, 2, 0.5f, 2, 0, 0, -1, 0, 2, 0, 0.25f};
    double xfm[12];
    for (int k = 0; k < 12; k++)
        xfm[k] = xf[k];
    const double scale = 2.0;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        char what[64];
        /* the spheres alone */
        rtk_scene alone = spheres_scene(dev, &sp, sphere_point);
        sp.calls = 0;
        snprintf(what, sizeof what, "%s, spheres", names[b]);
        check_scene(what, alone, &sp, NULL, 1.0, 0, 0, RTK_INVALID_GEOMETRY_ID, q);
        /* asked only for the spheres whose box is within reach: far fewer
         * than every sphere for every query (2 * POINTS queries above) */
        print_message("%s: %lu point query calls for %d queries of %d spheres\n", what, sp.calls, 2 * POINTS,
                      SPHERES);
        assert_true(sp.calls < 2ul * POINTS * SPHERES / 4);
        /* beside the floor's triangles */
        rtk_scene mixed = test_scene_uncommitted(dev, floor_v, 4, floor_idx, 2, 0); /* (geometry 0) */
        rtk_geometry g = spheres_geometry(dev, &sp, sphere_point);
        uint32_t id;
        assert_int_equal(rtk_scene_attach_geometry(mixed, g, &id), RTK_OK);
        rtk_geometry_release(g);
        assert_int_equal(rtk_scene_commit(mixed), RTK_OK);
        snprintf(what, sizeof what, "%s, spheres and floor", names[b]);
        check_scene(what, mixed, &sp, NULL, 1.0, 1, id, RTK_INVALID_GEOMETRY_ID, q);
        /* the spheres through an instance, beside the floor */
        rtk_scene outer = test_scene_uncommitted(dev, floor_v, 4, floor_idx, 2, 0);
        id = test_attach_instance(dev, outer, alone, xf);
        assert_int_equal(rtk_scene_commit(outer), RTK_OK);
        snprintf(what, sizeof what, "%s, an instance of the spheres and floor", names[b]);
        check_scene(what, outer, &sp, xfm, scale, 1, 0, id, q);
        /* a radius short of the nearest sphere: nothing; just past it: it */
        size_t prim;
        const double want = reference(&sp, NULL, 1.0, 0, q[0], &prim);
        rtk_point_hit h;
        rtk_point_query pq = {.x = q[0][0], .y = q[0][1], .z = q[0][2], .radius = want * (1.0 - 1e-9)};
        assert_int_equal(rtk_closest_point(alone, &pq, &h), RTK_OK);
        assert_true(h.geomID == RTK_INVALID_GEOMETRY_ID && h.distance == INFINITY);
        pq.radius = want * (1.0 + 1e-9);
        assert_int_equal(rtk_closest_point(alone, &pq, &h), RTK_OK);
        assert_true(h.primID == prim && fabs(h.distance - want) <= 1e-12 * (1.0 + want));
        rtk_scene_release(outer);
        rtk_scene_release(mixed);
        rtk_scene_release(alone);
        rtk_device_release(dev);
    }
}

/* A point query function that answers with a point that is not finite for
 * sphere 0, and for the others as sphere_point: sphere 0 is left out. */
static int sphere_point_nan0(rtk_point_query_args *a)
{
    const int r = sphere_point(a);
    if (a->prim_id == 0)
        a->closest[1] = NAN;
    return r;
}

static void test_refusals_and_bad_answers(void **state)
{
    (void)state;
    static sphere_set sp;
    spheres_make(&sp, 9);
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    /* the setter on triangles: refused */
    rtk_geometry tri;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &tri), RTK_OK);
    assert_int_equal(rtk_geometry_set_point_query_function(tri, sphere_point), RTK_ERROR_INVALID_OPERATION);
    rtk_geometry_release(tri);
    /* a user geometry without the function (removed with NULL): refused,
     * and so is an instance of it */
    rtk_scene s = spheres_scene(dev, &sp, NULL);
    const rtk_point_query q = {.x = 0.1, .y = 0.2, .z = 0.3, .radius = INFINITY};
    rtk_point_hit h;
    assert_int_equal(rtk_closest_point(s, &q, &h), RTK_ERROR_UNSUPPORTED);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "point query function"));
    rtk_scene outer = test_instancing_scene(dev, s);
    assert_int_equal(rtk_scene_commit(outer), RTK_OK);
    assert_int_equal(rtk_closest_point_batch(outer, &q, &h, 1), RTK_ERROR_UNSUPPORTED);
    rtk_scene_release(outer);
    rtk_scene_release(s);
    /* a point that is not finite is no answer: sphere 0 left out */
    s = spheres_scene(dev, &sp, sphere_point_nan0);
    const rtk_point_query at0 = {.x = sp.c[0][0], .y = sp.c[0][1], .z = sp.c[0][2] + sp.r[0], .radius = INFINITY};
    assert_int_equal(rtk_closest_point(s, &at0, &h), RTK_OK);
    assert_true(h.primID != 0 && h.primID < SPHERES && h.distance > 0.0);
    rtk_scene_release(s);
    rtk_device_release(dev);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_spheres),
        cmocka_unit_test(test_refusals_and_bad_answers),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
