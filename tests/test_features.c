/*
 * Masks, face culling and filter callbacks (rtk.h), on every backend and
 * layout, through intersect1, occluded1 and packets of 4, 8 and 16 rays:
 * each answer checked against brute force over the triangles with the same
 * rules applied (a triangle counts for a ray when the masks share a bit,
 * culling lets it through and its geometry's filter accepts it).
 *
 * The filters decide from the candidate (geometry, primitive) and the ray's
 * id, so the reference can tell what they will say; they also check what
 * they are handed (the geometry's user data, the query's context, the hit
 * as the query would report it, t within the ray's interval and no farther
 * than its closest hit so far) and count violations in the context.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "testlib.h"

enum { GEOMS = 4, PER_GEOM = 600, RAYS = 3000 };

/* geometry g: its mask, and which filters it has */
static const uint32_t geom_mask[GEOMS] = {1u, 2u, 3u, 4u};
/* A bit every geometry's mask also has (0: none), as a renderer's
 * "visible to everything" bit: rays with it pass every mask, and the
 * kernels take their usual path for them (rtk_accel.mask_pass_all); the
 * other rays still have their candidates tested. */
static uint32_t shared_bit;
static uint32_t mask_of(uint32_t g)
{
    return geom_mask[g] | shared_bit;
}
static const int has_ifilter[GEOMS] = {0, 1, 0, 1};
static const int has_ofilter[GEOMS] = {0, 1, 1, 0};
static const uint32_t ray_masks[] = {~0u, 1u, 2u, 4u, 5u, 6u, 0x80000000u, 0u, 8u, 9u};
static const uint32_t ray_flags[] = {0u, RTK_RAY_FLAG_CULL_BACK, RTK_RAY_FLAG_CULL_FRONT, 0u};

/* What a filter says: depends on the candidate and the ray only. */
static int filter_rule(uint32_t geom, uint32_t prim, uint32_t ray_id, int occluded)
{
    return (prim * 7u + ray_id + geom + (occluded ? 1u : 0u)) % 3u != 0u;
}

typedef struct geom_user {
    uint32_t geom;
} geom_user;

/* The query's context: what the filters saw. */
typedef struct filter_log {
    rtk_query_context ctx; /* first, so the filter finds the log from the context */
    unsigned calls, bad;
    char why[160];
    /* collect mode: every candidate recorded and rejected */
    int collect;
    uint32_t inst; /* the instID the filter must see */
    uint32_t seen[256];
    unsigned seen_count;
} filter_log;

static void bad(filter_log *log, const char *why)
{
    if (!log->bad++)
        snprintf(log->why, sizeof log->why, "%s", why);
}

static int filter(const rtk_filter_args *a, int occluded)
{
    filter_log *log = (filter_log *)a->context;
    if (!log)
        return filter_rule(a->hit->geomID, a->hit->primID, a->ray->id, occluded);
    log->calls++;
    const geom_user *u = a->geometry_user;
    if (!u || u->geom != a->hit->geomID)
        bad(log, "geometry_user is not the geometry's user data");
    if (!(a->t >= a->ray->tnear && a->t <= a->ray->tfar))
        bad(log, "t outside [tnear, tfar]");
    if (!(a->hit->u >= 0.0f && a->hit->v >= 0.0f && a->hit->u + a->hit->v <= 1.0001f))
        bad(log, "barycentrics out of range");
    if (!log->collect && !(a->ray->mask & mask_of(a->hit->geomID)))
        bad(log, "a filter called for a masked-out geometry");
    if (a->hit->instID != log->inst)
        bad(log, "the hit's instID is not the instance's");
    if (log->collect) {
        if (log->seen_count < 256)
            log->seen[log->seen_count++] = a->hit->geomID * PER_GEOM + a->hit->primID;
        return 0;
    }
    return filter_rule(a->hit->geomID, a->hit->primID, a->ray->id, occluded);
}
static int ifilter(const rtk_filter_args *a) { return filter(a, 0); }
static int ofilter(const rtk_filter_args *a) { return filter(a, 1); }

typedef struct world {
    float *v;
    uint32_t *idx;
    ref_mesh ref;
    geom_user users[GEOMS];
    /* 1: the geometries have the filters of has_ifilter / has_ofilter; 0:
     * masks alone (no filter anywhere: the kernels' masks-only path for rays
     * without culling) */
    int filters;
    /* the reference's answers to run_scene's rays, per rule set
     * (answers_of): the same for every backend and layout */
    struct answer *answers[8];
} world;

typedef struct answer {
    int hit, any; /* closest counting hit; whether any counts (occluded) */
    uint32_t p; /* its triangle (global index) */
    rtk_tri_hit want;
} answer;

/* GEOMS * PER_GEOM random triangles of about a tenth of the unit cube,
 * facing every way. */
static void world_make(world *w, uint64_t seed)
{
    rng r = {seed};
    test_soup_mesh(&r, GEOMS * PER_GEOM, 0.15f, &w->v, &w->idx);
    w->ref = ref_prepare(w->v, w->idx, GEOMS * PER_GEOM);
    for (uint32_t g = 0; g < GEOMS; g++)
        w->users[g].geom = g;
    w->filters = 1;
    for (int k = 0; k < 8; k++)
        w->answers[k] = NULL;
}

static void world_free(world *w)
{
    for (int k = 0; k < 8; k++)
        free(w->answers[k]);
    ref_free(&w->ref);
    free(w->v);
    free(w->idx);
}

/* A scene of the GEOMS geometries (flags: the scene's), each a slice of
 * the index buffer over the shared vertices. */
static rtk_scene world_scene(rtk_device dev, world *w, unsigned flags, int motion)
{
    rtk_scene s;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    assert_int_equal(rtk_scene_set_flags(s, flags), RTK_OK);
    for (uint32_t g = 0; g < GEOMS; g++) {
        rtk_geometry geo;
        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &geo), RTK_OK);
        if (motion && g == 2) { /* two time steps at the same place */
            assert_int_equal(rtk_geometry_set_time_step_count(geo, 2), RTK_OK);
            assert_int_equal(rtk_geometry_set_shared_buffer_slot(geo, RTK_BUFFER_TYPE_VERTEX, 1, w->v, 0, 12,
                                                                 GEOMS * PER_GEOM * 3),
                             RTK_OK);
        }
        assert_int_equal(rtk_geometry_set_shared_buffer(geo, RTK_BUFFER_TYPE_VERTEX, w->v, 0, 12, GEOMS * PER_GEOM * 3),
                         RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer(geo, RTK_BUFFER_TYPE_INDEX, w->idx,
                                                        (size_t)g * PER_GEOM * 12, 12, PER_GEOM),
                         RTK_OK);
        assert_int_equal(rtk_geometry_set_mask(geo, mask_of(g)), RTK_OK);
        assert_int_equal(rtk_geometry_set_user_data(geo, &w->users[g]), RTK_OK);
        if (w->filters && has_ifilter[g])
            assert_int_equal(rtk_geometry_set_intersect_filter(geo, ifilter), RTK_OK);
        if (w->filters && has_ofilter[g])
            assert_int_equal(rtk_geometry_set_occluded_filter(geo, ofilter), RTK_OK);
        assert_int_equal(rtk_geometry_commit(geo), RTK_OK);
        uint32_t id;
        assert_int_equal(rtk_scene_attach_geometry(s, geo, &id), RTK_OK);
        assert_int_equal(id, g);
        rtk_geometry_release(geo);
    }
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    return s;
}

/* Whether triangle p (global index) counts for the ray under the rules. */
static int counts(const world *w, uint32_t p, const rtk_ray *ray, const rtk_tri_hit *h, int occluded)
{
    const uint32_t g = p / PER_GEOM, prim = p % PER_GEOM;
    if (!(ray->mask & mask_of(g)))
        return 0;
    const float *t = w->ref.tri[p]; /* v0, e1, e2 */
    const float ng[3] = {t[4] * t[8] - t[5] * t[7], t[5] * t[6] - t[3] * t[8], t[3] * t[7] - t[4] * t[6]};
    const double dn = (double)ray->dir_x * ng[0] + (double)ray->dir_y * ng[1] + (double)ray->dir_z * ng[2];
    if ((ray->flags & RTK_RAY_FLAG_CULL_BACK) && dn > 0.0f)
        return 0;
    if ((ray->flags & RTK_RAY_FLAG_CULL_FRONT) && dn < 0.0f)
        return 0;
    (void)h;
    if (w->filters && (occluded ? has_ofilter[g] : has_ifilter[g]))
        return filter_rule(g, prim, ray->id, occluded);
    return 1;
}

/* The reference: closest counting hit (prim = global index) and whether any counts. */
static int ref_query(const world *w, const rtk_ray *ray, rtk_tri_hit *best, uint32_t *best_p, int *any)
{
    int hit = 0;
    *any = 0;
    for (uint32_t p = 0; p < GEOMS * PER_GEOM; p++) {
        rtk_tri_hit h;
        if (!w->ref.keep[p] || !ref_one(&w->ref, p, ray, &h))
            continue;
        if (counts(w, p, ray, &h, 1))
            *any = 1;
        if (counts(w, p, ray, &h, 0) && (!hit || h.t < best->t)) {
            hit = 1;
            *best = h;
            *best_p = p;
        }
    }
    return hit;
}

static rtk_ray random_ray(rng *r, uint32_t id)
{
    rtk_ray ray = test_ray_through_cube(r);
    if (id % 5 == 0)
        ray.tfar = 1.0f;
    ray.mask = ray_masks[rng_u32(r) % (sizeof ray_masks / sizeof ray_masks[0])];
    ray.flags = ray_flags[rng_u32(r) % 4];
    ray.id = id;
    return ray;
}

/* The reference's answers to rays[0, RAYS) under the rules of now (the
 * filters, the shared mask bit, watertight or not), computed once for
 * each rule set: the brute force took most of this test's time. */
static const answer *answers_of(world *w, const rtk_ray *rays)
{
    answer **a = &w->answers[(w->filters ? 4 : 0) | (shared_bit ? 2 : 0) | (w->ref.watertight ? 1 : 0)];
    if (!*a) {
        *a = calloc(RAYS, sizeof **a);
        assert_non_null(*a);
        for (uint32_t i = 0; i < RAYS; i++)
            (*a)[i].hit = ref_query(w, &rays[i], &(*a)[i].want, &(*a)[i].p, &(*a)[i].any);
    }
    return *a;
}

/* One ray's answers (single or in a packet lane) against the reference's
 * (ref): exact t where the layout is the reference's arithmetic, else
 * within tol (motion blur interpolates). */
static void check(const world *w, const rtk_ray *ray, const answer *ref, const rtk_rayhit *got, int occluded_hit,
                  double tol, const char *what)
{
    const rtk_tri_hit want = ref->want;
    const uint32_t p = ref->p;
    const int hit = ref->hit, any = ref->any;
    if ((got->hit.geomID != RTK_INVALID_GEOMETRY_ID) != hit || occluded_hit != any)
        fail_msg("%s ray %u (mask 0x%x flags %u): intersect %s (ref %s), occluded %d (ref %d)", what, ray->id,
                 ray->mask, ray->flags, got->hit.geomID != RTK_INVALID_GEOMETRY_ID ? "hit" : "miss",
                 hit ? "hit" : "miss", occluded_hit, any);
    if (!hit)
        return;
    const uint32_t gp = got->hit.geomID * PER_GEOM + got->hit.primID;
    const int t_ok = tol == 0.0 ? got->ray.tfar == want.t : fabs(got->ray.tfar - want.t) <= tol * want.t;
    rtk_tri_hit other;
    const int same = gp == p || (ref_one(&w->ref, gp, ray, &other) && other.t == want.t && counts(w, gp, ray, &other, 0));
    if (!t_ok || !same)
        fail_msg("%s ray %u: hit geom %u prim %u t %.9g, reference geom %u prim %u t %.9g", what, ray->id,
                 got->hit.geomID, got->hit.primID, got->ray.tfar, p / PER_GEOM, p % PER_GEOM, want.t);
    if (got->hit.instID != RTK_INVALID_GEOMETRY_ID)
        fail_msg("%s ray %u: instID %u in a scene without instances", what, ray->id, got->hit.instID);
}

static void run_scene(world *w, rtk_scene s, double tol, const char *what)
{
    rng r = {77};
    rtk_ray rays[RAYS];
    for (uint32_t i = 0; i < RAYS; i++)
        rays[i] = random_ray(&r, i);
    const answer *ref = answers_of(w, rays);
    filter_log log = {.inst = RTK_INVALID_GEOMETRY_ID};
    /* single rays, with and without a context */
    for (uint32_t i = 0; i < RAYS; i++) {
        rtk_rayhit rh = {.ray = rays[i]};
        rh.hit.geomID = rh.hit.primID = rh.hit.instID = RTK_INVALID_GEOMETRY_ID;
        rtk_ray o = rays[i];
        if (i % 2) {
            assert_int_equal(rtk_intersect1_ctx(s, &rh, &log.ctx), RTK_OK);
            assert_int_equal(rtk_occluded1_ctx(s, &o, &log.ctx), RTK_OK);
        } else {
            assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
            assert_int_equal(rtk_occluded1(s, &o), RTK_OK);
        }
        check(w, &rays[i], &ref[i], &rh, o.tfar == -INFINITY, tol, what);
    }
    /* packets of every width, some lanes invalid */
    static const unsigned widths[] = {4, 8, 16};
    for (int wi = 0; wi < 3; wi++) {
        const unsigned n = widths[wi];
        _Alignas(64) uint32_t ip[20 * 16], op[12 * 16];
        int valid[16];
        for (uint32_t base = 0; base + n <= RAYS; base += n) {
            for (unsigned l = 0; l < n; l++) {
                rtk_rayhit rh = {.ray = rays[base + l]};
                rh.hit.geomID = rh.hit.primID = rh.hit.instID = RTK_INVALID_GEOMETRY_ID;
                test_packet_put(ip, n, l, &rh, 0);
                test_packet_put(op, n, l, &rh, 1);
                valid[l] = (base + l) % 11 != 3;
            }
            if ((base / n) % 2) {
                rtk_error e1 = n == 4 ? rtk_intersect4_ctx(s, valid, (rtk_rayhit4 *)ip, &log.ctx)
                               : n == 8 ? rtk_intersect8_ctx(s, valid, (rtk_rayhit8 *)ip, &log.ctx)
                                        : rtk_intersect16_ctx(s, valid, (rtk_rayhit16 *)ip, &log.ctx);
                rtk_error e2 = n == 4 ? rtk_occluded4_ctx(s, valid, (rtk_ray4 *)op, &log.ctx)
                               : n == 8 ? rtk_occluded8_ctx(s, valid, (rtk_ray8 *)op, &log.ctx)
                                        : rtk_occluded16_ctx(s, valid, (rtk_ray16 *)op, &log.ctx);
                assert_int_equal(e1, RTK_OK);
                assert_int_equal(e2, RTK_OK);
            } else {
                assert_int_equal(test_trace_packet(s, n, 0, valid, ip), RTK_OK);
                assert_int_equal(test_trace_packet(s, n, 1, valid, op), RTK_OK);
            }
            for (unsigned l = 0; l < n; l++) {
                rtk_rayhit got, o;
                test_packet_get(ip, n, l, &got, 0);
                test_packet_get(op, n, l, &o, 1);
                if (!valid[l]) {
                    assert_int_equal(got.hit.geomID, RTK_INVALID_GEOMETRY_ID);
                    assert_true(o.ray.tfar == rays[base + l].tfar);
                    continue;
                }
                char name[96];
                snprintf(name, sizeof name, "%s packet%u", what, n);
                check(w, &rays[base + l], &ref[base + l], &got, o.ray.tfar == -INFINITY, tol, name);
            }
        }
    }
    if (log.bad)
        fail_msg("%s: %u of %u filter calls were handed something wrong, first: %s", what, log.bad, log.calls,
                 log.why);
    if (w->filters)
        assert_true(log.calls > 0);
    else
        assert_int_equal(log.calls, 0);
}

static void test_rules_every_backend_and_layout(void **state)
{
    (void)state;
    world w;
    world_make(&w, 5);
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    static const unsigned flag_sets[] = {0, RTK_SCENE_FLAG_COMPACT, RTK_SCENE_FLAG_ROBUST,
                                         RTK_SCENE_FLAG_ROBUST | RTK_SCENE_FLAG_COMPACT, RTK_SCENE_FLAG_DYNAMIC};
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (size_t f = 0; f < sizeof flag_sets / sizeof flag_sets[0]; f++) {
            w.ref.watertight = (flag_sets[f] & RTK_SCENE_FLAG_ROBUST) != 0;
            rtk_scene s = world_scene(dev, &w, flag_sets[f], 0);
            rtk_scene_info info = {.struct_size = sizeof info};
            assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
            char what[96];
            snprintf(what, sizeof what, "%s %s", names[b], info.layout);
            run_scene(&w, s, 0.0, what);
            rtk_scene_release(s);
            /* masks alone; then with a bit all the masks share, which
             * rays of masks ~0u, 8 and 9 have (filters or not) */
            w.filters = 0;
            s = world_scene(dev, &w, flag_sets[f], 0);
            snprintf(what, sizeof what, "%s %s, masks alone", names[b], info.layout);
            run_scene(&w, s, 0.0, what);
            rtk_scene_release(s);
            shared_bit = 8u;
            for (w.filters = 0; w.filters <= 1; w.filters++) {
                s = world_scene(dev, &w, flag_sets[f], 0);
                snprintf(what, sizeof what, "%s %s, a shared mask bit%s", names[b], info.layout,
                         w.filters ? ", filters" : "");
                run_scene(&w, s, 0.0, what);
                rtk_scene_release(s);
            }
            shared_bit = 0;
            w.filters = 1;
        }
        /* motion blur: one geometry in a tree of its own, below a top level */
        w.ref.watertight = 0;
        rtk_scene s = world_scene(dev, &w, 0, 1);
        char what[96];
        snprintf(what, sizeof what, "%s motion", names[b]);
        run_scene(&w, s, 1e-5, what);
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
    world_free(&w);
}

/* A filter that records every candidate and rejects it sees every triangle
 * the ray passes through (the "all hits" use), and the query misses. */
static void test_collect_all_hits(void **state)
{
    (void)state;
    world w;
    world_make(&w, 9);
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene s;
        assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
        assert_int_equal(rtk_scene_set_build_quality(s, RTK_BUILD_QUALITY_HIGH), RTK_OK); /* spatial splits */
        rtk_geometry geo;
        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &geo), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer(geo, RTK_BUFFER_TYPE_VERTEX, w.v, 0, 12, GEOMS * PER_GEOM * 3),
                         RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer(geo, RTK_BUFFER_TYPE_INDEX, w.idx, 0, 12, GEOMS * PER_GEOM),
                         RTK_OK);
        geom_user u = {0};
        assert_int_equal(rtk_geometry_set_user_data(geo, &u), RTK_OK);
        assert_int_equal(rtk_geometry_set_intersect_filter(geo, ifilter), RTK_OK);
        assert_int_equal(rtk_geometry_commit(geo), RTK_OK);
        assert_int_equal(rtk_scene_attach_geometry(s, geo, NULL), RTK_OK);
        assert_int_equal(rtk_scene_commit(s), RTK_OK);
        rng r = {3};
        unsigned total = 0;
        for (uint32_t i = 0; i < 500; i++) {
            rtk_ray ray = random_ray(&r, i);
            ray.mask = ~0u;
            ray.flags = 0;
            filter_log log = {.collect = 1, .inst = RTK_INVALID_GEOMETRY_ID};
            rtk_rayhit rh = {.ray = ray};
            rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
            assert_int_equal(rtk_intersect1_ctx(s, &rh, &log.ctx), RTK_OK);
            assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID);
            assert_true(rh.ray.tfar == ray.tfar);
            if (log.bad)
                fail_msg("%s: %s", names[b], log.why);
            /* the same set as brute force (a triangle may come more than once) */
            unsigned want = 0;
            for (uint32_t p = 0; p < GEOMS * PER_GEOM; p++) {
                rtk_tri_hit h;
                if (!w.ref.keep[p] || !ref_one(&w.ref, p, &ray, &h))
                    continue;
                want++;
                int found = 0;
                for (unsigned k = 0; k < log.seen_count && !found; k++)
                    found = log.seen[k] == p;
                if (!found)
                    fail_msg("%s ray %u: the filter never saw triangle %u", names[b], i, p);
            }
            for (unsigned k = 0; k < log.seen_count; k++) {
                rtk_tri_hit h;
                if (!ref_one(&w.ref, log.seen[k], &ray, &h))
                    fail_msg("%s ray %u: the filter saw triangle %u, which the ray misses", names[b], i,
                             log.seen[k]);
            }
            total += want;
        }
        assert_true(total > 500); /* rays pass through several triangles each */
        rtk_geometry_release(geo);
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
    world_free(&w);
}

static int reject_all(const rtk_filter_args *a)
{
    (void)a;
    return 0;
}

/* Instances: the instance's mask is tested first, then the instanced
 * geometry's; a filter inside sees the instance's id; the attributes are
 * read at commit; a ray of mask 0 hits nothing even where nothing has a
 * mask; a filter on an instance is refused. */
static void test_instances_masks_and_api(void **state)
{
    (void)state;
    static const float v[] = {-1, -1, 0, 1, -1, 0, 0, 1, 0};
    static const uint32_t idx[] = {0, 1, 2};
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene inner = test_scene(dev, v, 3, idx, 1);
        rtk_ray ray = test_ray(0, 0, -1, 0, 0, 1, 0, INFINITY); /* Ng is +z: the back, dot(dir, Ng) > 0 */
        ray.mask = 0;
        rtk_rayhit rh = {.ray = ray};
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1(inner, &rh), RTK_OK);
        assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID); /* mask 0: nothing */
        ray.mask = ~0u;
        ray.flags = RTK_RAY_FLAG_CULL_BACK;
        rh = (rtk_rayhit){.ray = ray};
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1(inner, &rh), RTK_OK);
        assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID);
        ray.flags = RTK_RAY_FLAG_CULL_FRONT;
        rh = (rtk_rayhit){.ray = ray};
        assert_int_equal(rtk_intersect1(inner, &rh), RTK_OK);
        assert_int_equal(rh.hit.geomID, 0);
        assert_true(rh.hit.Ng_z > 0.0f);

        rtk_geometry tri = rtk_scene_get_geometry(inner, 0);
        assert_int_equal(rtk_geometry_set_mask(tri, 2), RTK_OK);
        assert_int_equal(rtk_geometry_commit(tri), RTK_OK);
        assert_int_equal(rtk_scene_commit(inner), RTK_OK);

        rtk_scene outer;
        assert_int_equal(rtk_scene_new(dev, &outer), RTK_OK);
        rtk_geometry inst;
        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &inst), RTK_OK);
        assert_int_equal(rtk_geometry_set_intersect_filter(inst, ifilter), RTK_ERROR_INVALID_OPERATION);
        assert_int_equal(rtk_geometry_set_instanced_scene(inst, inner), RTK_OK);
        assert_int_equal(rtk_geometry_set_mask(inst, 1 | 4), RTK_OK);
        assert_int_equal(rtk_geometry_commit(inst), RTK_OK);
        uint32_t inst_id;
        assert_int_equal(rtk_scene_attach_geometry(outer, inst, &inst_id), RTK_OK);
        assert_int_equal(rtk_scene_commit(outer), RTK_OK);
        const struct {
            uint32_t mask;
            int hit;
        } cases[] = {{1, 0}, {2, 0}, {3, 1}, {4, 0}, {6, 1}, {~0u, 1}};
        for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
            rh = (rtk_rayhit){.ray = test_ray(0, 0, -1, 0, 0, 1, 0, INFINITY)};
            rh.ray.mask = cases[c].mask;
            rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
            assert_int_equal(rtk_intersect1(outer, &rh), RTK_OK);
            rtk_ray o = rh.ray;
            assert_int_equal(rtk_occluded1(outer, &o), RTK_OK);
            if ((rh.hit.geomID != RTK_INVALID_GEOMETRY_ID) != cases[c].hit || (o.tfar == -INFINITY) != cases[c].hit)
                fail_msg("%s: ray mask 0x%x through instance mask 5 and geometry mask 2: %s, expected %s", names[b],
                         cases[c].mask, rh.hit.geomID != RTK_INVALID_GEOMETRY_ID ? "hit" : "miss",
                         cases[c].hit ? "hit" : "miss");
            if (cases[c].hit)
                assert_int_equal(rh.hit.instID, inst_id);
        }
        /* a filter inside the instance: it sees instID, and rejecting makes the ray miss */
        geom_user u = {0};
        filter_log log = {.inst = inst_id};
        assert_int_equal(rtk_geometry_set_user_data(tri, &u), RTK_OK);
        assert_int_equal(rtk_geometry_set_intersect_filter(tri, reject_all), RTK_OK);
        assert_int_equal(rtk_geometry_commit(tri), RTK_OK);
        assert_int_equal(rtk_scene_commit(inner), RTK_OK);
        rh = (rtk_rayhit){.ray = test_ray(0, 0, -1, 0, 0, 1, 0, INFINITY)};
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1(outer, &rh), RTK_OK); /* the outer scene still holds the old tree */
        assert_int_equal(rh.hit.geomID, 0);
        assert_int_equal(rtk_scene_commit(outer), RTK_OK);
        rh = (rtk_rayhit){.ray = test_ray(0, 0, -1, 0, 0, 1, 0, INFINITY)};
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1_ctx(outer, &rh, &log.ctx), RTK_OK);
        assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID);
        rtk_ray o = rh.ray;
        assert_int_equal(rtk_occluded1(outer, &o), RTK_OK); /* no occlusion filter: a hit */
        assert_true(o.tfar == -INFINITY);
        assert_int_equal(rtk_geometry_set_intersect_filter(tri, ifilter), RTK_OK);
        assert_int_equal(rtk_geometry_commit(tri), RTK_OK);
        assert_int_equal(rtk_scene_commit(inner), RTK_OK);
        assert_int_equal(rtk_scene_commit(outer), RTK_OK);
        rh = (rtk_rayhit){.ray = test_ray(0, 0, -1, 0, 0, 1, 0, INFINITY)};
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        log.collect = 1;
        assert_int_equal(rtk_intersect1_ctx(outer, &rh, &log.ctx), RTK_OK);
        assert_int_equal(log.seen_count, 1);
        assert_int_equal(log.bad, 0);
        rtk_geometry_release(inst);
        rtk_scene_release(outer);
        rtk_scene_release(inner);
        rtk_device_release(dev);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_rules_every_backend_and_layout),
        cmocka_unit_test(test_collect_all_hits),
        cmocka_unit_test(test_instances_masks_and_api),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
