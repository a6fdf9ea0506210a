/*
 * Every crossing of user geometry (rtk_user_offer_hit): spheres whose
 * callbacks offer both of a ray's hits, nearest first, listed and counted
 * (rtk_count_intersections, rtk_list_intersections) against their roots in
 * double, and inside or outside (rtk_occupancy) against the parity of the
 * spheres holding the point, on every backend: alone, beside a closed
 * triangle mesh in a robust scene, and through a rotated, scaled and moved
 * instance.  The same callbacks answer closest and any hits as before
 * (single rays and packets); a callback that reports a hit without
 * offering it fails the crossing calls rather than lose crossings; and the
 * misuses of rtk_user_offer_hit are errors.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "closed_mesh.h"
#include "geometry/affine.h"
#include "testlib.h"
#include "user_spheres.h"

enum { RAYS = 1500, POINTS = 1500, MAX_CROSSINGS = 2 * SPHERES + 64 };

/* One crossing of the reference. */
typedef struct ref_crossing {
    double t;
    uint32_t geom, prim, inst;
} ref_crossing;

/* The spheres as they stand in the scene's space: through xfm (row-major
 * 3x4, a rotation times a uniform scale plus a move; NULL: as they are). */
typedef struct placed_spheres {
    sphere_set s;
    uint32_t geom, inst;
} placed_spheres;

static void place(const sphere_set *in, const float *xf, double scale, uint32_t geom, uint32_t inst,
                  placed_spheres *out)
{
    out->s = *in;
    out->geom = geom;
    out->inst = inst;
    double m[12];
    for (int k = 0; xf && k < 12; k++)
        m[k] = xf[k];
    for (int i = 0; xf && i < SPHERES; i++) {
        rtk_affine_apply(m, in->c[i], out->s.c[i]);
        out->s.r[i] = in->r[i] * scale;
    }
}

static int by_t(const void *x, const void *y)
{
    const ref_crossing *a = x, *b = y;
    return a->t < b->t ? -1 : a->t > b->t;
}

/* The spheres' crossings of ray r within its range, sorted, into c (the
 * count); -1 when one lies too near the range's ends, another crossing or
 * a tangent for float to tell (the ray is then not checked). */
static int sphere_crossings(const placed_spheres *p, const rtk_ray *r, ref_crossing *c)
{
    const float o[3] = {r->org_x, r->org_y, r->org_z}, d[3] = {r->dir_x, r->dir_y, r->dir_z};
    int n = 0;
    for (uint32_t i = 0; i < SPHERES; i++) {
        double t[2];
        if (!sphere_roots(&p->s, i, o, d, t))
            continue;
        if (t[1] - t[0] < 1e-3)
            return -1;
        for (int j = 0; j < 2; j++) {
            if (fabs(t[j] - r->tnear) < 1e-3 || fabs(t[j] - r->tfar) < 1e-3)
                return -1;
            if (t[j] >= r->tnear && t[j] <= r->tfar)
                c[n++] = (ref_crossing){.t = t[j], .geom = p->geom, .prim = i, .inst = p->inst};
        }
    }
    return n;
}

/* Merge the crossings rtk lists in `extra` (triangles, from a scene of
 * them alone) into c[0 .. n); sorted; -1 when two lie too near to order. */
static int merge_sorted(ref_crossing *c, int n, const rtk_crossing *extra, uint32_t ne)
{
    for (uint32_t i = 0; i < ne; i++)
        c[n++] = (ref_crossing){.t = extra[i].t, .geom = extra[i].geomID, .prim = extra[i].primID,
                                .inst = extra[i].instID};
    qsort(c, (size_t)n, sizeof *c, by_t);
    for (int i = 1; i < n; i++)
        if (c[i].t - c[i - 1].t < 1e-3 * (1.0 + fabs(c[i].t)))
            return -1;
    return n;
}

/* A random unit direction into d. */
static void random_direction(rng *r, double d[3])
{
    double len;
    do {
        for (int k = 0; k < 3; k++)
            d[k] = 2.0 * rng_float(r) - 1.0;
        len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    } while (len < 0.1 || len > 1.0);
    for (int k = 0; k < 3; k++)
        d[k] /= len;
}

/* Rays from the cube [-extent, extent]^3, each aimed at a random point
 * within 1.2 radii of a sphere of `aim`'s centre (most cross one). */
static void make_rays(rtk_ray *rays, size_t n, uint64_t seed, float extent, const sphere_set *aim)
{
    rng r = {seed};
    for (size_t i = 0; i < n; i++) {
        const float o[3] = {extent * (2.0f * rng_float(&r) - 1.0f), extent * (2.0f * rng_float(&r) - 1.0f),
                            extent * (2.0f * rng_float(&r) - 1.0f)};
        const uint32_t j = rng_u32(&r) % SPHERES;
        double off[3], d[3];
        random_direction(&r, off);
        const double reach = 1.2 * aim->r[j] * rng_float(&r);
        for (int k = 0; k < 3; k++)
            d[k] = aim->c[j][k] + off[k] * reach - o[k];
        const double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        /* every third ray within [0.5, 4] only */
        rays[i] = test_ray(o[0], o[1], o[2], (float)(d[0] / len), (float)(d[1] / len), (float)(d[2] / len),
                           i % 3 ? 0.0f : 0.5f, i % 3 ? INFINITY : 4.0f);
    }
}

/* Every crossing of the rays through s against the spheres' roots (and
 * the crossings `tri` lists for the same rays, when not NULL); t within
 * tol of the reference's. */
static void check_crossings(const char *what, rtk_scene s, rtk_scene tri, const placed_spheres *p, double tol,
                            uint64_t seed)
{
    rtk_ray *rays = malloc(RAYS * sizeof *rays);
    uint32_t *counts = malloc(RAYS * sizeof *counts), *tcounts = malloc(RAYS * sizeof *tcounts);
    uint64_t *off = malloc((RAYS + 1) * sizeof *off), *toff = malloc((RAYS + 1) * sizeof *toff);
    make_rays(rays, RAYS, seed, 5.0f, &p->s);
    assert_int_equal(rtk_count_intersections(s, rays, RAYS, sizeof *rays, counts), RTK_OK);
    off[0] = toff[0] = 0;
    if (tri)
        assert_int_equal(rtk_count_intersections(tri, rays, RAYS, sizeof *rays, tcounts), RTK_OK);
    for (size_t i = 0; i < RAYS; i++) {
        off[i + 1] = off[i] + counts[i];
        toff[i + 1] = toff[i] + (tri ? tcounts[i] : 0);
    }
    rtk_crossing *c = malloc((off[RAYS] + 1) * sizeof *c), *tc = malloc((toff[RAYS] + 1) * sizeof *tc);
    assert_int_equal(rtk_list_intersections(s, rays, RAYS, sizeof *rays, off, c), RTK_OK);
    if (tri)
        assert_int_equal(rtk_list_intersections(tri, rays, RAYS, sizeof *rays, toff, tc), RTK_OK);
    size_t checked = 0, crossings = 0;
    for (size_t i = 0; i < RAYS; i++) {
        ref_crossing ref[MAX_CROSSINGS];
        int n = sphere_crossings(p, &rays[i], ref);
        const uint32_t ne = (uint32_t)(toff[i + 1] - toff[i]);
        if (n < 0 || n + ne > MAX_CROSSINGS || (n = merge_sorted(ref, n, tc + toff[i], ne)) < 0)
            continue;
        checked++;
        if (counts[i] != (uint32_t)n)
            fail_msg("%s: ray %zu: %u crossings, the reference %d", what, i, counts[i], n);
        for (int j = 0; j < n; j++) {
            const rtk_crossing *x = &c[off[i] + (size_t)j];
            if (!(fabs(x->t - ref[j].t) <= tol * (1.0 + fabs(ref[j].t))) || x->geomID != ref[j].geom ||
                x->primID != ref[j].prim || x->instID != ref[j].inst)
                fail_msg("%s: ray %zu, crossing %d: t %.9g geom %u prim %u inst %u, the reference t %.9g geom %u "
                         "prim %u inst %u",
                         what, i, j, (double)x->t, x->geomID, x->primID, x->instID, ref[j].t, ref[j].geom,
                         ref[j].prim, ref[j].inst);
        }
        crossings += (size_t)n;
    }
    print_message("%s: %zu of %d rays checked, %zu crossings\n", what, checked, RAYS, crossings);
    assert_true(checked > RAYS * 3 / 4 && crossings > checked);
    free(c);
    free(tc);
    free(rays);
    free(counts);
    free(tcounts);
    free(off);
    free(toff);
}

/* Points through the spheres' space: random ones in the box, and points
 * 1e-4 and `fine` inside and outside each sphere's surface (3e-8 lies
 * within float's rounding of it: such a point's float may lie on the other
 * side), against the parity of the spheres holding them (points within
 * 1e-6 of another sphere's surface left out). */
static void check_occupancy(const char *what, rtk_scene s, const placed_spheres *p, double fine, uint64_t seed)
{
    rng r = {seed};
    rtk_point_query *q = calloc(POINTS, sizeof *q);
    uint8_t *in = malloc(POINTS);
    int *from = malloc(POINTS * sizeof *from); /* the sphere a point was put near, or -1 */
    for (size_t i = 0; i < POINTS; i++) {
        double x[3];
        from[i] = -1;
        if (i % 3 == 0) {
            for (int k = 0; k < 3; k++)
                x[k] = 6.0 * rng_float(&r) - 3.0;
        } else {
            from[i] = (int)(i / 3 % SPHERES);
            double d[3];
            random_direction(&r, d);
            const double off = (i % 3 == 1 ? 1e-4 : fine) * (i / 3 % 2 ? 1.0 : -1.0);
            for (int k = 0; k < 3; k++)
                x[k] = p->s.c[from[i]][k] + d[k] * (p->s.r[from[i]] + off);
        }
        q[i] = (rtk_point_query){.x = x[0], .y = x[1], .z = x[2]};
    }
    assert_int_equal(rtk_occupancy(s, q, POINTS, in), RTK_OK);
    size_t checked = 0, inside = 0;
    for (size_t i = 0; i < POINTS; i++) {
        const double x[3] = {q[i].x, q[i].y, q[i].z};
        int holders = 0, near = 0;
        for (int j = 0; j < SPHERES; j++) {
            const double d = sqrt((x[0] - p->s.c[j][0]) * (x[0] - p->s.c[j][0]) +
                                  (x[1] - p->s.c[j][1]) * (x[1] - p->s.c[j][1]) +
                                  (x[2] - p->s.c[j][2]) * (x[2] - p->s.c[j][2]));
            holders += d < p->s.r[j];
            near |= j != from[i] && fabs(d - p->s.r[j]) < 1e-6;
        }
        if (near)
            continue;
        checked++;
        inside += (size_t)(holders & 1);
        if (in[i] != (holders & 1))
            fail_msg("%s: point %zu (%.17g %.17g %.17g): %u, the reference %d (inside %d spheres)", what, i, x[0],
                     x[1], x[2], in[i], holders & 1, holders);
    }
    print_message("%s: %zu points checked, %zu inside\n", what, checked, inside);
    assert_true(checked > POINTS * 9 / 10 && inside > POINTS / 8);
    free(q);
    free(in);
    free(from);
}

static void test_crossings(void **state)
{
    (void)state;
    static sphere_set sp;
    spheres_make(&sp, 21);
    /* (test_user_points' similarity: x -> y -> z -> x, scaled by 2, moved) */
    const float xf[12] = {0, 0, 2, 0.5f, 2, 0, 0, -1, 0, 2, 0, 0.25f};
    const double c0[3] = {0.25, -0.5, 0.125};
    rtk_closed_mesh box;
    assert_int_equal(rtk_closed_box(c0, 1.5, 6, &box), 0);
    const rtk_mesh *bm = &box.mesh;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        char what[96];
        placed_spheres p;
        /* the spheres alone */
        rtk_scene alone = spheres_scene(dev, &sp, sphere_point);
        place(&sp, NULL, 1.0, 0, RTK_INVALID_GEOMETRY_ID, &p);
        snprintf(what, sizeof what, "%s, spheres", names[b]);
        check_crossings(what, alone, NULL, &p, 1e-6, 31);
        check_occupancy(what, alone, &p, 3e-8, 32);
        /* beside a closed box of triangles, robust */
        const unsigned robust = RTK_SCENE_FLAG_ROBUST;
        rtk_scene mixed = test_scene_uncommitted(dev, bm->vertices, bm->vertex_count, bm->indices,
                                                 bm->triangle_count, robust);
        rtk_geometry g = spheres_geometry(dev, &sp, sphere_point);
        uint32_t id;
        assert_int_equal(rtk_scene_attach_geometry(mixed, g, &id), RTK_OK);
        rtk_geometry_release(g);
        assert_int_equal(rtk_scene_commit(mixed), RTK_OK);
        rtk_scene tri = test_scene_flags(dev, bm->vertices, bm->vertex_count, bm->indices, bm->triangle_count,
                                         robust);
        place(&sp, NULL, 1.0, id, RTK_INVALID_GEOMETRY_ID, &p);
        snprintf(what, sizeof what, "%s, spheres and a closed box", names[b]);
        check_crossings(what, mixed, tri, &p, 1e-6, 33);
        /* through an instance */
        rtk_scene outer;
        assert_int_equal(rtk_scene_new(dev, &outer), RTK_OK);
        id = test_attach_instance(dev, outer, alone, xf);
        assert_int_equal(rtk_scene_commit(outer), RTK_OK);
        place(&sp, xf, 2.0, 0, id, &p);
        snprintf(what, sizeof what, "%s, an instance of the spheres", names[b]);
        check_crossings(what, outer, NULL, &p, 1e-5, 34);
        /* (the rays go through the instance's float transform, which
         * places the spheres within a few ulps of float of where double
         * puts them) */
        check_occupancy(what, outer, &p, 1e-5, 35);
        rtk_scene_release(outer);
        rtk_scene_release(tri);
        rtk_scene_release(mixed);
        rtk_scene_release(alone);
        rtk_device_release(dev);
    }
    rtk_closed_free(&box);
}

/* The nearest root within the ray's range, or -1 (t in *t). */
static int nearest_root(const sphere_set *sp, const rtk_ray *r, float *t)
{
    const float o[3] = {r->org_x, r->org_y, r->org_z}, d[3] = {r->dir_x, r->dir_y, r->dir_z};
    int best = -1;
    for (uint32_t i = 0; i < SPHERES; i++) {
        double roots[2];
        for (int j = 0, n = sphere_roots(sp, i, o, d, roots); j < n; j++) {
            const float tf = (float)roots[j];
            if (tf >= r->tnear && tf <= r->tfar && (best < 0 || tf < *t)) {
                *t = tf;
                best = (int)i;
            }
        }
    }
    return best;
}

/* Closest and any hits, one ray at a time and in packets of 8: the hit
 * the callbacks offer first is taken, as before offering. */
static void test_hits(void **state)
{
    (void)state;
    static sphere_set sp;
    spheres_make(&sp, 22);
    rtk_ray rays[8 * 64];
    make_rays(rays, 8 * 64, 41, 4.0f, &sp);
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene s = spheres_scene(dev, &sp, sphere_point);
        int hits = 0;
        for (size_t p = 0; p < 64; p++) {
            _Alignas(64) uint32_t closest[20 * 8], any[12 * 8];
            for (unsigned l = 0; l < 8; l++) {
                rtk_rayhit rh = {.ray = rays[8 * p + l]};
                rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
                test_packet_put(closest, 8, l, &rh, 0);
                test_packet_put(any, 8, l, &rh, 1);
            }
            assert_int_equal(test_trace_packet(s, 8, 0, NULL, closest), RTK_OK);
            assert_int_equal(test_trace_packet(s, 8, 1, NULL, any), RTK_OK);
            for (unsigned l = 0; l < 8; l++) {
                const rtk_ray *r = &rays[8 * p + l];
                rtk_rayhit rh8, r8;
                test_packet_get(closest, 8, l, &rh8, 0);
                test_packet_get(any, 8, l, &r8, 1);
                float t = 0.0f;
                const int want = nearest_root(&sp, r, &t);
                rtk_rayhit rh = {.ray = *r};
                rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
                rtk_ray occ = *r;
                assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
                assert_int_equal(rtk_occluded1(s, &occ), RTK_OK);
                if (want < 0) {
                    assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID);
                    assert_int_equal(rh8.hit.geomID, RTK_INVALID_GEOMETRY_ID);
                    assert_true(occ.tfar == r->tfar && r8.ray.tfar == r->tfar);
                    continue;
                }
                hits++;
                if (rh.ray.tfar != t || rh.hit.primID != (uint32_t)want || rh.hit.geomID != 0)
                    fail_msg("%s: ray %zu: t %.9g prim %u, the reference t %.9g prim %d", names[b], 8 * p + l,
                             (double)rh.ray.tfar, rh.hit.primID, (double)t, want);
                assert_true(rh8.ray.tfar == t && rh8.hit.primID == (uint32_t)want);
                assert_true(occ.tfar == -INFINITY && r8.ray.tfar == -INFINITY);
            }
        }
        assert_true(hits > 8 * 64 / 2);
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
}

/* The sphere's nearest hit in range reported without offering it: what a
 * callback written before rtk_user_offer_hit does. */
static void sphere_unoffered(const rtk_user_query_args *a)
{
    const sphere_set *s = a->geometry_user;
    rtk_rayhit *rh = a->rays;
    const float o[3] = {rh->ray.org_x, rh->ray.org_y, rh->ray.org_z}, d[3] = {rh->ray.dir_x, rh->ray.dir_y,
                                                                               rh->ray.dir_z};
    double t[2];
    for (int j = 0, n = sphere_roots(s, a->prim_id, o, d, t); j < n; j++)
        if ((float)t[j] >= rh->ray.tnear && (float)t[j] <= rh->ray.tfar) {
            rh->ray.tfar = (float)t[j];
            return;
        }
}

static int misuse_results[4];

/* Offers with a lane out of range, with no hit, and with a hit before
 * tnear, then its hits as sphere_intersect does. */
static void sphere_misused(const rtk_user_query_args *a)
{
    const rtk_user_hit h = {.t = 1.0f}, before = {.t = -1.0f};
    misuse_results[0] = rtk_user_offer_hit(a, a->N, &h);
    misuse_results[1] = rtk_device_get_error(NULL);
    misuse_results[2] = rtk_user_offer_hit(a, 0, NULL);
    misuse_results[2] += 10 * (rtk_device_get_error(NULL) != RTK_ERROR_INVALID_ARGUMENT);
    misuse_results[3] = rtk_user_offer_hit(a, 0, &before) + 10 * (rtk_device_get_error(NULL) != RTK_OK);
    sphere_intersect(a);
}

static void test_errors(void **state)
{
    (void)state;
    static sphere_set sp;
    spheres_make(&sp, 23);
    rtk_device dev = test_device("avx2");
    rtk_ray down = test_ray((float)sp.c[0][0], (float)sp.c[0][1], 5.0f, 0, 0, -1, 0, INFINITY);
    rtk_ray away = test_ray(0, 0, 50.0f, 0, 0, 1, 0, INFINITY);
    uint32_t n = 7;
    uint8_t in;
    const rtk_point_query pt = {.x = sp.c[0][0], .y = sp.c[0][1], .z = sp.c[0][2]};
    /* a callback that reports without offering: the crossing calls fail,
     * naming it, but only where it reports a hit */
    rtk_scene s;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    rtk_geometry g = test_user_geometry(dev, SPHERES, &sp, sphere_bounds, sphere_unoffered, sphere_occluded);
    assert_int_equal(rtk_geometry_set_point_query_function(g, sphere_point), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
    rtk_geometry_release(g);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    assert_int_equal(rtk_count_intersections(s, &away, 1, sizeof away, &n), RTK_OK);
    assert_int_equal(n, 0);
    assert_int_equal(rtk_count_intersections(s, &down, 1, sizeof down, &n), RTK_ERROR_UNSUPPORTED);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "rtk_user_offer_hit"));
    assert_int_equal(rtk_occupancy(s, &pt, 1, &in), RTK_ERROR_UNSUPPORTED);
    /* its closest hits are as they were */
    rtk_rayhit rh = {.ray = down};
    rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
    assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
    assert_int_equal(rh.hit.geomID, 0);
    rtk_scene_release(s);
    /* occupancy needs the point query function; the crossings do not */
    s = spheres_scene(dev, &sp, NULL);
    assert_int_equal(rtk_count_intersections(s, &down, 1, sizeof down, &n), RTK_OK);
    assert_true(n >= 2 && n % 2 == 0);
    assert_int_equal(rtk_occupancy(s, &pt, 1, &in), RTK_ERROR_UNSUPPORTED);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "point query function"));
    rtk_scene_release(s);
    /* misuses: outside a callback, a lane out of range, no hit; a hit
     * before tnear is not taken (no error) */
    (void)rtk_device_get_error(NULL);
    const rtk_user_hit h = {.t = 1.0f};
    rtk_user_query_args fake = {.N = 1};
    assert_int_equal(rtk_user_offer_hit(&fake, 0, &h), 0);
    assert_int_equal(rtk_device_get_error(NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    g = test_user_geometry(dev, SPHERES, &sp, sphere_bounds, sphere_misused, sphere_occluded);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
    rtk_geometry_release(g);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    rh = (rtk_rayhit){.ray = down};
    rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
    assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
    assert_int_equal(rh.hit.geomID, 0); /* the misuses changed nothing */
    assert_int_equal(misuse_results[0], 0);
    assert_int_equal(misuse_results[1], RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(misuse_results[2], 0);
    assert_int_equal(misuse_results[3], 0);
    assert_int_equal(rtk_count_intersections(s, &down, 1, sizeof down, &n), RTK_OK);
    assert_true(n >= 2 && n % 2 == 0);
    rtk_scene_release(s);
    rtk_device_release(dev);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_crossings),
        cmocka_unit_test(test_hits),
        cmocka_unit_test(test_errors),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
