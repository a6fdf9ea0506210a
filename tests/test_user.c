/*
 * User geometry (rtk.h): spheres defined by callbacks, mixed with triangles
 * in one scene, on every backend, through intersect1, occluded1 and packets
 * of 4, 8 and 16 rays; checked against a reference that intersects the
 * same spheres (the callback's own arithmetic) and brute-forces the
 * triangles.  Also: packets reach the callbacks whole (N > 1), masks,
 * a primitive with a non-finite box left out, instances of a scene of
 * spheres, and callbacks that answer out of range taken as misses.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "testlib.h"

enum { SPHERES = 300, TRIS = 400, RAYS = 2000, BAD_SPHERE = 17 };

typedef struct spheres {
    float c[SPHERES][3], r[SPHERES];
    unsigned calls_n1, calls_packet; /* callback calls with N = 1 and N > 1 */
    unsigned bad_lanes;              /* callback asked about an invalid lane's ray (never) */
} spheres;

static void sphere_bounds(const rtk_bounds_args *a)
{
    const spheres *s = a->geometry_user;
    if (a->prim_id == BAD_SPHERE) { /* left out: never hit */
        a->lower[0] = NAN;
        return;
    }
    for (int k = 0; k < 3; k++) {
        a->lower[k] = s->c[a->prim_id][k] - s->r[a->prim_id];
        a->upper[k] = s->c[a->prim_id][k] + s->r[a->prim_id];
    }
}

static int sphere_hit(const spheres *s, uint32_t p, const float o[3], const float d[3], float tnear, float tfar,
                      float *t_out)
{
    return test_sphere_hit(s->c[p], s->r[p], o, d, tnear, tfar, t_out);
}

#define LANE TEST_LANE

static void sphere_query(const rtk_user_query_args *a, int occluded)
{
    spheres *s = a->geometry_user;
    if (a->N == 1)
        s->calls_n1++;
    else
        s->calls_packet++;
    for (uint32_t i = 0; i < a->N; i++) {
        if (!a->valid[i])
            continue;
        const float o[3] = {LANE(a->rays, a->N, 0, i), LANE(a->rays, a->N, 1, i), LANE(a->rays, a->N, 2, i)};
        const float d[3] = {LANE(a->rays, a->N, 4, i), LANE(a->rays, a->N, 5, i), LANE(a->rays, a->N, 6, i)};
        const float tnear = LANE(a->rays, a->N, 3, i), tfar = LANE(a->rays, a->N, 8, i);
        if (!(tnear <= tfar))
            s->bad_lanes++;
        float t;
        if (!sphere_hit(s, a->prim_id, o, d, tnear, tfar, &t))
            continue;
        if (occluded) {
            LANE(a->rays, a->N, 8, i) = -INFINITY;
            continue;
        }
        LANE(a->rays, a->N, 8, i) = t;
        for (int k = 0; k < 3; k++) /* Ng: 12 + k; u, v: 15, 16 */
            LANE(a->rays, a->N, 12 + k, i) = o[k] + t * d[k] - s->c[a->prim_id][k];
        LANE(a->rays, a->N, 15, i) = 0.0f;
        LANE(a->rays, a->N, 16, i) = 0.0f;
    }
}
static void sphere_intersect(const rtk_user_query_args *a) { sphere_query(a, 0); }
static void sphere_occluded(const rtk_user_query_args *a) { sphere_query(a, 1); }

typedef struct world {
    spheres sp;
    float *v;
    uint32_t *idx;
    ref_mesh ref;
} world;

static void world_make(world *w)
{
    rng r = {11};
    for (int p = 0; p < SPHERES; p++) {
        for (int k = 0; k < 3; k++)
            w->sp.c[p][k] = rng_float(&r);
        w->sp.r[p] = 0.01f + 0.04f * rng_float(&r);
    }
    test_soup_mesh(&r, TRIS, 0.1f, &w->v, &w->idx);
    w->ref = ref_prepare(w->v, w->idx, TRIS);
}

static void world_free(world *w)
{
    ref_free(&w->ref);
    free(w->v);
    free(w->idx);
}

/* geometry 0: the triangles, 1: the spheres (mask sphere_mask) */
static rtk_scene world_scene(rtk_device dev, world *w, unsigned flags, uint32_t sphere_mask)
{
    rtk_scene s;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    assert_int_equal(rtk_scene_set_flags(s, flags), RTK_OK);
    rtk_geometry tri, sph;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &tri), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(tri, RTK_BUFFER_TYPE_VERTEX, w->v, 0, 12, TRIS * 3), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(tri, RTK_BUFFER_TYPE_INDEX, w->idx, 0, 12, TRIS), RTK_OK);
    assert_int_equal(rtk_geometry_commit(tri), RTK_OK);
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_USER, &sph), RTK_OK);
    assert_int_equal(rtk_geometry_commit(sph), RTK_ERROR_INVALID_OPERATION); /* no callbacks yet */
    assert_int_equal(rtk_geometry_set_user_primitive_count(sph, SPHERES), RTK_OK);
    assert_int_equal(rtk_geometry_set_bounds_function(sph, sphere_bounds), RTK_OK);
    assert_int_equal(rtk_geometry_set_intersect_function(sph, sphere_intersect), RTK_OK);
    assert_int_equal(rtk_geometry_set_occluded_function(sph, sphere_occluded), RTK_OK);
    assert_int_equal(rtk_geometry_set_user_data(sph, &w->sp), RTK_OK);
    assert_int_equal(rtk_geometry_set_mask(sph, sphere_mask), RTK_OK);
    assert_int_equal(rtk_geometry_commit(sph), RTK_OK);
    uint32_t id;
    assert_int_equal(rtk_scene_attach_geometry(s, tri, &id), RTK_OK);
    assert_int_equal(id, 0);
    assert_int_equal(rtk_scene_attach_geometry(s, sph, &id), RTK_OK);
    assert_int_equal(id, 1);
    rtk_geometry_release(tri);
    rtk_geometry_release(sph);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
    assert_int_equal(info.user_primitives, SPHERES - 1);
    assert_int_equal(info.user_primitives_skipped, 1);
    return s;
}

/* The reference: the closest of the spheres (but BAD_SPHERE, and only when
 * the masks meet) and the triangles. */
typedef struct answer {
    int hit;
    uint32_t geom, prim;
    float t;
} answer;

static answer reference(const world *w, const rtk_ray *ray, uint32_t sphere_mask)
{
    answer a = {0};
    const float o[3] = {ray->org_x, ray->org_y, ray->org_z}, d[3] = {ray->dir_x, ray->dir_y, ray->dir_z};
    rtk_tri_hit h;
    uint32_t prim;
    if (ref_closest(&w->ref, ray, &h, &prim))
        a = (answer){1, 0, prim, h.t};
    for (uint32_t p = 0; p < SPHERES && (ray->mask & sphere_mask); p++) {
        float t;
        if (p != BAD_SPHERE && sphere_hit(&w->sp, p, o, d, ray->tnear, a.hit ? a.t : ray->tfar, &t) &&
            (!a.hit || t < a.t))
            a = (answer){1, 1, p, t};
    }
    return a;
}

static void check(const world *w, const rtk_ray *ray, const rtk_rayhit *got, int occ, uint32_t inst,
                  uint32_t sphere_mask, const char *what)
{
    const answer want = reference(w, ray, sphere_mask);
    const int hit = got->hit.geomID != RTK_INVALID_GEOMETRY_ID;
    if (hit != want.hit || occ != want.hit)
        fail_msg("%s ray %u: %s / occluded %d, reference %s", what, ray->id, hit ? "hit" : "miss", occ,
                 want.hit ? "hit" : "miss");
    if (!hit)
        return;
    if (got->hit.geomID != want.geom || got->hit.primID != want.prim || got->ray.tfar != want.t) {
        /* a sphere and a triangle (or two spheres) at nearly the same t */
        if (fabsf(got->ray.tfar - want.t) > 1e-6f * want.t)
            fail_msg("%s ray %u: geom %u prim %u t %.9g, reference geom %u prim %u t %.9g", what, ray->id,
                     got->hit.geomID, got->hit.primID, got->ray.tfar, want.geom, want.prim, want.t);
    }
    assert_int_equal(got->hit.instID, inst);
    if (got->hit.geomID == 1) { /* the callback's normal came through */
        const float *c = w->sp.c[got->hit.primID];
        const float n = (ray->org_x + got->ray.tfar * ray->dir_x - c[0]) * got->hit.Ng_x +
                        (ray->org_y + got->ray.tfar * ray->dir_y - c[1]) * got->hit.Ng_y +
                        (ray->org_z + got->ray.tfar * ray->dir_z - c[2]) * got->hit.Ng_z;
        assert_true(n > 0.0f);
    }
}

static rtk_ray random_ray(rng *r, uint32_t id, int masks)
{
    rtk_ray ray = test_ray_through_cube(r);
    if (id % 7 == 0)
        ray.tfar = 0.8f;
    ray.id = id;
    ray.mask = masks && id % 3 == 0 ? 1u : ~0u;
    return ray;
}

static void run(world *w, rtk_scene s, uint32_t inst, uint32_t sphere_mask, const char *what)
{
    rng r = {5};
    static rtk_ray rays[RAYS];
    for (uint32_t i = 0; i < RAYS; i++)
        rays[i] = random_ray(&r, i, 1);
    w->sp.calls_n1 = w->sp.calls_packet = w->sp.bad_lanes = 0;
    for (uint32_t i = 0; i < RAYS; i++) {
        rtk_rayhit rh = {.ray = rays[i]};
        rh.hit.geomID = rh.hit.instID = RTK_INVALID_GEOMETRY_ID;
        rtk_ray o = rays[i];
        assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
        assert_int_equal(rtk_occluded1(s, &o), RTK_OK);
        check(w, &rays[i], &rh, o.tfar == -INFINITY, inst, sphere_mask, what);
    }
    assert_true(w->sp.calls_n1 > 0);
    const unsigned packet_calls_before = w->sp.calls_packet;
    static const unsigned widths[] = {4, 8, 16};
    for (int wi = 0; wi < 3; wi++) {
        const unsigned n = widths[wi];
        _Alignas(64) uint32_t ip[20 * 16], op[12 * 16];
        int valid[16];
        for (uint32_t base = 0; base + n <= RAYS; base += n) {
            for (unsigned l = 0; l < n; l++) {
                rtk_rayhit rh = {.ray = rays[base + l]};
                rh.hit.geomID = rh.hit.instID = RTK_INVALID_GEOMETRY_ID;
                valid[l] = (base + l) % 13 != 5;
                if (!valid[l]) /* an invalid lane holds a ray the callback must never see */
                    rh.ray.tnear = 2.0f, rh.ray.tfar = 1.0f;
                test_packet_put(ip, n, l, &rh, 0);
                test_packet_put(op, n, l, &rh, 1);
            }
            assert_int_equal(test_trace_packet(s, n, 0, valid, ip), RTK_OK);
            assert_int_equal(test_trace_packet(s, n, 1, valid, op), RTK_OK);
            for (unsigned l = 0; l < n; l++) {
                if (!valid[l])
                    continue;
                rtk_rayhit got, o;
                test_packet_get(ip, n, l, &got, 0);
                test_packet_get(op, n, l, &o, 1);
                char name[96];
                snprintf(name, sizeof name, "%s packet%u", what, n);
                check(w, &rays[base + l], &got, o.ray.tfar == -INFINITY, inst, sphere_mask, name);
            }
        }
    }
    assert_int_equal(w->sp.bad_lanes, 0);
    /* packets reach the callbacks whole in a scene whose top level holds
     * the spheres (inside an instance they come ray by ray) */
    if (inst == RTK_INVALID_GEOMETRY_ID && w->sp.calls_packet == packet_calls_before)
        fail_msg("%s: no callback call with N > 1 from packet queries", what);
}

static void test_spheres_and_triangles(void **state)
{
    (void)state;
    static world w;
    world_make(&w);
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    static const unsigned flag_sets[] = {0, RTK_SCENE_FLAG_DYNAMIC, RTK_SCENE_FLAG_ROBUST};
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (size_t f = 0; f < 3; f++) {
            w.ref.watertight = (flag_sets[f] & RTK_SCENE_FLAG_ROBUST) != 0;
            rtk_scene s = world_scene(dev, &w, flag_sets[f], 2u);
            char what[96];
            snprintf(what, sizeof what, "%s flags %u", names[b], flag_sets[f]);
            run(&w, s, RTK_INVALID_GEOMETRY_ID, 2u, what);
            /* the same scene as an instance (identity): instID, and the same answers */
            rtk_scene top;
            rtk_geometry inst;
            assert_int_equal(rtk_scene_new(dev, &top), RTK_OK);
            assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &inst), RTK_OK);
            assert_int_equal(rtk_geometry_set_instanced_scene(inst, s), RTK_OK);
            assert_int_equal(rtk_geometry_commit(inst), RTK_OK);
            uint32_t inst_id;
            assert_int_equal(rtk_scene_attach_geometry(top, inst, NULL), RTK_OK);
            assert_int_equal(rtk_scene_attach_geometry(top, inst, &inst_id), RTK_OK); /* twice: ids 0 and 1 */
            assert_int_equal(rtk_geometry_disable(inst), RTK_OK); /* (disables both attachments) */
            assert_int_equal(rtk_geometry_enable(inst), RTK_OK);
            assert_int_equal(rtk_scene_detach_geometry(top, 0), RTK_OK);
            assert_int_equal(rtk_scene_commit(top), RTK_OK);
            snprintf(what, sizeof what, "%s flags %u instanced", names[b], flag_sets[f]);
            run(&w, top, inst_id, 2u, what);
            rtk_geometry_release(inst);
            rtk_scene_release(top);
            rtk_scene_release(s);
        }
        rtk_device_release(dev);
    }
    world_free(&w);
}

/* Callbacks that answer out of range: each is taken as a miss, the ray
 * left as it was. */
static void wrong_answer(const rtk_user_query_args *a)
{
    const int kind = (int)(uintptr_t)a->geometry_user;
    for (uint32_t i = 0; i < a->N; i++) {
        if (!a->valid[i])
            continue;
        float *tfar = &LANE(a->rays, a->N, 8, i);
        const float tnear = LANE(a->rays, a->N, 3, i);
        *tfar = kind == 0 ? NAN : kind == 1 ? tnear - 1.0f : *tfar * 2.0f + 1.0f;
        LANE(a->rays, a->N, 15, i) = 42.0f; /* u: must not stick */
        LANE(a->rays, a->N, 0, i) = 1e9f;   /* org: must not stick */
    }
}

static void box_bounds(const rtk_bounds_args *a)
{
    for (int k = 0; k < 3; k++) {
        a->lower[k] = -1.0f;
        a->upper[k] = 1.0f;
    }
}

static void test_wrong_answers_are_misses(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (uintptr_t kind = 0; kind < 3; kind++) {
            rtk_scene s;
            rtk_geometry g;
            assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
            assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_USER, &g), RTK_OK);
            assert_int_equal(rtk_geometry_set_intersect_filter(g, NULL), RTK_ERROR_INVALID_OPERATION);
            assert_int_equal(rtk_geometry_set_user_primitive_count(g, 1), RTK_OK);
            assert_int_equal(rtk_geometry_set_bounds_function(g, box_bounds), RTK_OK);
            assert_int_equal(rtk_geometry_set_intersect_function(g, wrong_answer), RTK_OK);
            assert_int_equal(rtk_geometry_set_occluded_function(g, wrong_answer), RTK_OK);
            assert_int_equal(rtk_geometry_set_user_data(g, (void *)kind), RTK_OK);
            assert_int_equal(rtk_geometry_commit(g), RTK_OK);
            assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            rtk_rayhit rh = {.ray = test_ray(0, 0, -5, 0, 0, 1, 0, 100.0f)};
            rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
            const rtk_rayhit before = rh;
            assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
            assert_memory_equal(&rh, &before, sizeof rh);
            _Alignas(64) uint32_t ip[20 * 8];
            for (unsigned l = 0; l < 8; l++)
                test_packet_put(ip, 8, l, &before, 0);
            uint32_t copy[20 * 8];
            memcpy(copy, ip, sizeof copy);
            assert_int_equal(test_trace_packet(s, 8, 0, NULL, ip), RTK_OK);
            assert_memory_equal(ip, copy, sizeof copy);
            rtk_geometry_release(g);
            rtk_scene_release(s);
        }
        rtk_device_release(dev);
    }
}

/* Boxes across the whole float range (the fuzzer's find: the top level's
 * binning took centres that overflowed to infinity and binned NaN):
 * primitive p's box is [-3e38, 3e38]^3 when p % 3 == 0, else reaches
 * from 1e38 or -3.4e38 to 3.4e38 or -1e38 in x only; the callback hits
 * at t = 1 + p, so the ray along z through the origin hits primitive 0. */
static void huge_bounds(const rtk_bounds_args *a)
{
    const uint32_t p = a->prim_id;
    for (int k = 0; k < 3; k++) {
        a->lower[k] = -3e38f;
        a->upper[k] = 3e38f;
    }
    if (p % 3 == 1)
        a->lower[0] = 1e38f, a->upper[0] = 3.4e38f;
    if (p % 3 == 2)
        a->lower[0] = -3.4e38f, a->upper[0] = -1e38f;
}

static void huge_query(const rtk_user_query_args *a)
{
    for (uint32_t i = 0; i < a->N; i++) {
        float *tfar = &LANE(a->rays, a->N, 8, i);
        const float t = 1.0f + (float)a->prim_id;
        if (a->valid[i] && t >= LANE(a->rays, a->N, 3, i) && t <= *tfar)
            *tfar = t;
    }
}

static void test_boxes_across_the_float_range(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene s = test_user_geometry_scene(dev, 40, huge_bounds, huge_query, huge_query);
        rtk_scene_info info = {.struct_size = sizeof info};
        assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
        assert_int_equal(info.user_primitives, 40);
        rtk_rayhit rh = {.ray = test_ray(0, 0, -5, 0, 0, 1, 0, INFINITY)};
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
        assert_int_equal(rh.hit.primID, 0);
        assert_float_equal(rh.ray.tfar, 1.0f, 0.0);
        /* from x = 2e38 the primitives 1, 4, ... are in the way too: the first is 1 */
        rh = (rtk_rayhit){.ray = test_ray(2e38f, 0, -5, 0, 0, 1, 1.5f, INFINITY)};
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
        assert_int_equal(rh.hit.primID, 1);
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
}

/* Rays along a face, an edge or a corner of their primitives' boxes (the
 * boxes [p, p + 1] x [0, 1] x [0, 1], p = 0 ... 7; the callback hits at
 * t = 1 + p): a ray in a box's plane with its component there +0.0 or
 * -0.0 touches the closed box, and each gets the first primitive whose box
 * it touches (face_query), alone, in packets of 8 and in a stream.  The top level's
 * node test took such a ray's far distance as 0 * 1e18 = 0 and skipped
 * the box when it lay on the box's far plane (obj_ray_scalars). */
static void unit_box_bounds(const rtk_bounds_args *a)
{
    a->lower[0] = (float)a->prim_id;
    a->upper[0] = (float)a->prim_id + 1.0f;
    a->lower[1] = a->lower[2] = 0.0f;
    a->upper[1] = a->upper[2] = 1.0f;
}

/* The primitive's box as unit_box_bounds gives it is touched by the ray
 * (lane i), whose direction components are 0 but along one axis that
 * crosses every box's span: it hits at t = 1 + p (-inf for occluded). */
static void face_query(const rtk_user_query_args *a, int occluded)
{
    const float lo[3] = {(float)a->prim_id, 0.0f, 0.0f}, hi[3] = {(float)a->prim_id + 1.0f, 1.0f, 1.0f};
    for (uint32_t i = 0; i < a->N; i++) {
        if (!a->valid[i])
            continue;
        int touched = 1;
        for (int k = 0; k < 3; k++) {
            const float o = LANE(a->rays, a->N, k, i), d = LANE(a->rays, a->N, 4 + k, i);
            touched &= d != 0.0f || (o >= lo[k] && o <= hi[k]);
        }
        float *tfar = &LANE(a->rays, a->N, 8, i);
        const float t = 1.0f + (float)a->prim_id;
        if (touched && t >= LANE(a->rays, a->N, 3, i) && t <= *tfar)
            *tfar = occluded ? -INFINITY : t;
    }
}
static void face_intersect(const rtk_user_query_args *a) { face_query(a, 0); }
static void face_occluded(const rtk_user_query_args *a) { face_query(a, 1); }

static void test_rays_along_box_faces(void **state)
{
    (void)state;
    enum { BOXES = 8, RAYS = (BOXES + 1) * 2 * 4 * 2 };
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene s = test_user_geometry_scene(dev, BOXES, unit_box_bounds, face_intersect, face_occluded);
        rtk_rayhit rays[RAYS];
        uint32_t want[RAYS];
        size_t n = 0;
        for (int x = 0; x <= BOXES; x++) /* on a face in x, and an edge or a corner with y */
            for (int y = 0; y < 2; y++)
                for (int sg = 0; sg < 4; sg++)
                    for (int z = 0; z < 2; z++) { /* along z from below, or along y from the side */
                        const float zx = (sg & 1) ? -0.0f : 0.0f, zy = (sg & 2) ? -0.0f : 0.0f;
                        const rtk_ray r = z ? test_ray((float)x, (float)y, -5.0f, zx, zy, 1.0f, 0.0f, INFINITY)
                                            : test_ray((float)x, -5.0f, (float)y, zx, 1.0f, zy, 0.0f, INFINITY);
                        rays[n] = (rtk_rayhit){.ray = r};
                        rays[n].hit.geomID = RTK_INVALID_GEOMETRY_ID;
                        want[n++] = x == 0 ? 0u : (uint32_t)x - 1u;
                    }
        for (size_t i = 0; i < RAYS; i++) {
            rtk_rayhit rh = rays[i];
            assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
            if (rh.hit.geomID != 0 || rh.hit.primID != want[i] || rh.ray.tfar != 1.0f + (float)want[i])
                fail_msg("%s: ray %zu from %g %g %g: primitive %u at %g, want %u", names[b], i,
                         (double)rays[i].ray.org_x, (double)rays[i].ray.org_y, (double)rays[i].ray.org_z,
                         rh.hit.primID, (double)rh.ray.tfar, want[i]);
            rtk_ray occ = rays[i].ray;
            assert_int_equal(rtk_occluded1(s, &occ), RTK_OK);
            assert_true(occ.tfar == -INFINITY);
        }
        for (size_t i = 0; i < RAYS; i += 8) {
            rtk_rayhit got[8];
            test_intersect8_rows(s, &rays[i], got);
            for (unsigned l = 0; l < 8; l++)
                if (got[l].hit.primID != want[i + l] || got[l].ray.tfar != 1.0f + (float)want[i + l])
                    fail_msg("%s: packet ray %zu: primitive %u, want %u", names[b], i + l, got[l].hit.primID,
                             want[i + l]);
        }
        rtk_rayhit st[RAYS];
        memcpy(st, rays, sizeof st);
        assert_int_equal(rtk_intersect1M(s, st, RAYS, sizeof *st), RTK_OK);
        for (size_t i = 0; i < RAYS; i++)
            if (st[i].hit.primID != want[i] || st[i].ray.tfar != 1.0f + (float)want[i])
                fail_msg("%s: stream ray %zu: primitive %u, want %u", names[b], i, st[i].hit.primID, want[i]);
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_spheres_and_triangles),
        cmocka_unit_test(test_wrong_answers_are_misses),
        cmocka_unit_test(test_boxes_across_the_float_range),
        cmocka_unit_test(test_rays_along_box_faces),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
