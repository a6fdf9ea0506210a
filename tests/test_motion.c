/*
 * Linear motion blur: triangle meshes with several time steps, checked
 * against a reference that interpolates the vertices explicitly (in double
 * precision) to each ray's time and intersects by brute force.  Rays at
 * random times and at the time steps (where the answers must be exactly
 * those of a static mesh of that step), times outside [0, 1], two and five
 * time steps, a static floor beside the moving mesh, dynamic scenes,
 * instances of a moving scene, huge coordinates, vertices that are NaN at
 * one step, triangles of zero area at one step, packets, scene info and
 * the errors; every backend.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "testlib.h"

#define R 16
static test_mesh ball;

/* two big triangles: a floor below everything */
static const float floor_v[] = {-40, -6, -40, 40, -6, -40, 40, -6, 40, -40, -6, 40};
static const uint32_t floor_idx[] = {0, 1, 2, 0, 2, 3};

static int setup(void **state)
{
    (void)state;
    ball = test_ball(R);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    free(ball.v);
    free(ball.idx);
    return 0;
}

/* ---- a moving mesh: the ball at `steps` time steps ---- */

typedef struct moving {
    int steps;
    float **v; /* per step: ball.nv vertices */
    double scale, offset;
} moving;

/* Step k: the ball turned about z by 0.9 k, grown by 0.25 k, moved along
 * a bent path and wobbled (so it deforms, not only moves), then scaled by
 * `scale` and moved by `offset` on every axis (huge coordinates). */
static moving make_moving(int steps, double scale, double offset)
{
    moving m = {.steps = steps, .v = calloc((size_t)steps, sizeof(float *)), .scale = scale, .offset = offset};
    for (int k = 0; k < steps; k++) {
        m.v[k] = malloc(ball.nv * 3 * sizeof(float));
        const double a = 0.9 * k, s = 1.0 + 0.25 * k, c = cos(a), si = sin(a);
        const double off[3] = {1.5 * k, 0.4 * sin(2.0 * k), -0.3 * k};
        for (size_t i = 0; i < ball.nv; i++) {
            const float *p = ball.v + 3 * i;
            double q[3] = {s * (c * p[0] - si * p[1]) + off[0], s * (si * p[0] + c * p[1]) + off[1],
                           s * p[2] + off[2] + 0.08 * sin(7.0 * p[0] + k)};
            for (int d = 0; d < 3; d++)
                m.v[k][3 * i + d] = (float)(q[d] * scale + offset);
        }
    }
    return m;
}

static void free_moving(moving *m)
{
    for (int k = 0; k < m->steps; k++)
        free(m->v[k]);
    free(m->v);
}

static rtk_geometry moving_geometry(rtk_device dev, const moving *m, const uint32_t *idx, size_t nt)
{
    rtk_geometry g = NULL;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_time_step_count(g, (unsigned)m->steps), RTK_OK);
    for (int k = 0; k < m->steps; k++)
        assert_int_equal(
            rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, (unsigned)k, m->v[k], 0, 12, ball.nv),
            RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, idx, 0, 12, nt), RTK_OK);
    if (rtk_geometry_commit(g) != RTK_OK)
        fail_msg("geometry commit: %s", rtk_device_get_error_message(dev));
    return g;
}

static uint32_t attach(rtk_scene s, rtk_geometry g)
{
    uint32_t id;
    assert_int_equal(rtk_scene_attach_geometry(s, g, &id), RTK_OK);
    rtk_geometry_release(g);
    return id;
}

static uint32_t attach_static(rtk_device dev, rtk_scene s, const float *v, size_t nv, const uint32_t *idx, size_t nt)
{
    rtk_geometry g = NULL;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, nv), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, idx, 0, 12, nt), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    return attach(s, g);
}

/* A device on the best backend. */
static rtk_device best_device(void)
{
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    return dev;
}

/* The configurations the tests run on: every backend with its motion
 * layout (bvh8.triangle4mb where vectors are 8 wide, else
 * bvh4.triangle4mb), and the backends with 8-wide nodes once more with
 * motion_layout=bvh4.triangle4mb; layout[k] names the layout expected. */
#define MOTION_MAX_CONFIGS (2 * TEST_MAX_BACKENDS)
typedef struct motion_configs {
    size_t n;
    char config[MOTION_MAX_CONFIGS][96];
    const char *layout[MOTION_MAX_CONFIGS];
} motion_configs;

static void motion_configs_get(motion_configs *c)
{
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    c->n = 0;
    for (size_t b = 0; b < nb; b++) {
        char cfg[96];
        snprintf(cfg, sizeof cfg, "isa=%s,motion_layout=bvh8.triangle4mb", names[b]);
        rtk_device dev = NULL;
        const int wide = rtk_device_new(cfg, &dev) == RTK_OK;
        rtk_device_release(dev);
        snprintf(c->config[c->n], sizeof c->config[c->n], "isa=%s", names[b]);
        c->layout[c->n++] = wide ? "bvh8.triangle4mb" : "bvh4.triangle4mb";
        if (wide) {
            snprintf(c->config[c->n], sizeof c->config[c->n], "isa=%s,motion_layout=bvh4.triangle4mb", names[b]);
            c->layout[c->n++] = "bvh4.triangle4mb";
        }
    }
}

static rtk_device config_device(const char *config)
{
    rtk_device dev = NULL;
    if (rtk_device_new(config, &dev) != RTK_OK)
        fail_msg("device %s: %s", config, rtk_device_get_error_message(NULL));
    return dev;
}

static void commit_ok(rtk_device dev, rtk_scene s)
{
    if (rtk_scene_commit(s) != RTK_OK)
        fail_msg("scene commit: %s", rtk_device_get_error_message(dev));
}

/* ---- the reference at one time ---- */

/* p = xfm (row-major 3x4, NULL: identity) applied to q */
static void apply(const double *xfm, const double q[3], double p[3])
{
    for (int i = 0; i < 3; i++)
        p[i] = xfm ? xfm[4 * i] * q[0] + xfm[4 * i + 1] * q[1] + xfm[4 * i + 2] * q[2] + xfm[4 * i + 3] : q[i];
}

/* The moving ball's triangles at `time` (interpolated in double between
 * the two steps around it), placed by xfm. */
static void ref_add_moving(placed_ref *r, const moving *m, double time, const double *xfm, uint32_t inst,
                           uint32_t geom)
{
    const int segs = m->steps - 1;
    int s = (int)floor(time * segs);
    s = s < segs ? s : segs - 1;
    const double f = time * segs - s;
    for (size_t k = 0; k < ball.nt; k++) {
        placed *p = placed_add(r);
        double o[3][3];
        for (int c = 0; c < 3; c++) {
            const uint32_t vi = ball.idx[3 * k + c];
            for (int d = 0; d < 3; d++)
                o[c][d] = (1.0 - f) * m->v[s][3 * vi + d] + f * m->v[s + 1][3 * vi + d];
            apply(xfm, o[c], p->v[c]);
        }
        placed_normal(p, o);
        p->inst = inst;
        p->geom = geom;
        p->prim = (uint32_t)k;
    }
}

static void ref_add_floor(placed_ref *r, const double *xfm, uint32_t inst, uint32_t geom)
{
    for (size_t k = 0; k < 2; k++) {
        placed *p = placed_add(r);
        double o[3][3];
        for (int c = 0; c < 3; c++) {
            for (int d = 0; d < 3; d++)
                o[c][d] = floor_v[3 * floor_idx[3 * k + c] + d];
            apply(xfm, o[c], p->v[c]);
        }
        placed_normal(p, o);
        p->inst = inst;
        p->geom = geom;
        p->prim = (uint32_t)k;
    }
}

/* The box of the moving ball over all its steps (placed by xfm). */
static void moving_box(const moving *m, const double *xfm, double lo[3], double hi[3])
{
    for (int d = 0; d < 3; d++)
        lo[d] = INFINITY, hi[d] = -INFINITY;
    for (int k = 0; k < m->steps; k++)
        for (size_t i = 0; i < ball.nv; i++) {
            const double q[3] = {m->v[k][3 * i], m->v[k][3 * i + 1], m->v[k][3 * i + 2]};
            double p[3];
            apply(xfm, q, p);
            for (int d = 0; d < 3; d++)
                lo[d] = fmin(lo[d], p[d]), hi[d] = fmax(hi[d], p[d]);
        }
}

/* The kinds of scene motion_vs_reference builds. */
enum { PLAIN, DYNAMIC, INSTANCED, KINDS };
static const char *const kind_name[KINDS] = {"plain", "dynamic", "instanced"};

/* Rays at random times (a tenth at the steps and at the ends) from around
 * the moving ball's box towards points in it, against the reference
 * rebuilt at each ray's time. */
static void check_moving(rtk_scene s, const moving *m, int with_floor, uint32_t floor_id, uint32_t ball_id,
                         const double *xfm, uint32_t inst, int nrays, uint32_t seed, int *hits, int *excused)
{
    double lo[3], hi[3];
    moving_box(m, xfm, lo, hi);
    rng g = {seed};
    placed_ref ref = {0};
    for (int i = 0; i < nrays; i++) {
        float o[3], d[3];
        for (int k = 0; k < 3; k++) {
            const double ext = hi[k] - lo[k];
            o[k] = (float)(lo[k] - 0.5 * ext + 2.0 * ext * rng_float(&g));
            d[k] = (float)(lo[k] + ext * rng_float(&g) - o[k]);
        }
        float time = rng_float(&g);
        if (i % 10 == 0) /* exactly at a step: 0, 1, or between segments */
            time = (float)(rng_u32(&g) % (uint32_t)m->steps) / (float)(m->steps - 1);
        rtk_ray ray = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY);
        ray.time = time;
        ref.n = 0;
        if (with_floor)
            ref_add_floor(&ref, xfm, inst, floor_id);
        ref_add_moving(&ref, m, time, xfm, inst, ball_id);
        check_ray_placed(s, &ref, ray, i, 1e-4, hits, excused);
    }
    free(ref.t);
}

static void motion_vs_reference(void **state)
{
    (void)state;
    motion_configs mc;
    motion_configs_get(&mc);
    const size_t nb = mc.n;
    static const int step_counts[2] = {2, 5};
    /* scale, offset: around the origin, and huge coordinates */
    static const double places[2][2] = {{1.0, 0.0}, {1e4, 3e6}};
    /* the instance's transform: rotation about y by 0.5, scale 2, moved */
    const double c = cos(0.5), si = sin(0.5);
    const double xfm[12] = {2 * c, 0, 2 * si, 4, 0, 2, 0, -1, -2 * si, 0, 2 * c, 3};
    for (size_t b = 0; b < nb; b++)
        for (int sc = 0; sc < 2; sc++)
            for (int pl = 0; pl < 2; pl++)
                for (int kind = 0; kind < KINDS; kind++) {
                    if (pl && kind != PLAIN)
                        continue;
                    moving m = make_moving(step_counts[sc], places[pl][0], places[pl][1]);
                    rtk_device dev = config_device(mc.config[b]);
                    rtk_scene s = NULL;
                    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
                    if (kind == DYNAMIC)
                        assert_int_equal(rtk_scene_set_flags(s, RTK_SCENE_FLAG_DYNAMIC), RTK_OK);
                    const int with_floor = !pl;
                    const uint32_t floor_id = with_floor ? attach_static(dev, s, floor_v, 4, floor_idx, 2) : 0;
                    const uint32_t ball_id = attach(s, moving_geometry(dev, &m, ball.idx, ball.nt));
                    commit_ok(dev, s);
                    rtk_scene_info info = {.struct_size = sizeof info};
                    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
                    assert_int_equal(info.triangles, ball.nt + (with_floor ? 2 : 0));
                    assert_int_equal(info.triangles_motion, ball.nt);
                    rtk_scene traced = s;
                    uint32_t inst = RTK_INVALID_GEOMETRY_ID;
                    if (kind == INSTANCED) {
                        assert_int_equal(rtk_scene_new(dev, &traced), RTK_OK);
                        rtk_geometry g = NULL;
                        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &g), RTK_OK);
                        assert_int_equal(rtk_geometry_set_instanced_scene(g, s), RTK_OK);
                        float f[12];
                        for (int k = 0; k < 12; k++)
                            f[k] = (float)xfm[k];
                        assert_int_equal(rtk_geometry_set_transform(g, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, f), RTK_OK);
                        assert_int_equal(rtk_geometry_commit(g), RTK_OK);
                        inst = attach(traced, g);
                        commit_ok(dev, traced);
                    }
                    double fx[12];
                    for (int k = 0; k < 12; k++)
                        fx[k] = (float)xfm[k];
                    int hits = 0, excused = 0;
                    const int nrays = 1500;
                    check_moving(traced, &m, with_floor, floor_id, ball_id, kind == INSTANCED ? fx : NULL, inst,
                                 nrays, 100 * (uint32_t)b + 10 * (uint32_t)sc + (uint32_t)kind, &hits, &excused);
                    if (hits < nrays / 5 || excused > nrays / 50)
                        fail_msg("%s, %d steps, %s%s: %d hits, %d excused of %d rays", mc.config[b], m.steps,
                                 kind_name[kind], pl ? ", huge coordinates" : "", hits, excused, nrays);
                    if (traced != s)
                        rtk_scene_release(traced);
                    rtk_scene_release(s);
                    rtk_device_release(dev);
                    free_moving(&m);
                }
}

/* At a time step the triangles are the step's vertices exactly: the
 * answers (t, the triangle) are those of a static mesh of that step, bit
 * for bit, as the brute-force reference over it gives them. */
static void motion_steps_exact(void **state)
{
    (void)state;
    motion_configs mc;
    motion_configs_get(&mc);
    const size_t nb = mc.n;
    moving m = make_moving(3, 1.0, 0.0);
    static const float times[3] = {0.0f, 0.5f, 1.0f};
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = config_device(mc.config[b]);
        rtk_scene s = NULL;
        assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
        attach(s, moving_geometry(dev, &m, ball.idx, ball.nt));
        commit_ok(dev, s);
        rtk_scene_info info = {.struct_size = sizeof info};
        assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
        assert_string_equal(info.layout, mc.layout[b]);
        for (int k = 0; k < 3; k++) {
            ref_mesh ref = ref_prepare(m.v[k], ball.idx, ball.nt);
            double lo[3], hi[3];
            moving_box(&m, NULL, lo, hi);
            rng g = {7 + (uint32_t)k};
            int hits = 0;
            for (int i = 0; i < 800; i++) {
                float o[3], d[3];
                for (int a = 0; a < 3; a++) {
                    const double ext = hi[a] - lo[a];
                    o[a] = (float)(lo[a] - 0.5 * ext + 2.0 * ext * rng_float(&g));
                    d[a] = (float)(lo[a] + ext * rng_float(&g) - o[a]);
                }
                rtk_ray ray = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY);
                ray.time = times[k];
                hits += test_ray_vs_reference(s, &ref, ray);
            }
            assert_true(hits > 100);
            ref_free(&ref);
        }
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
    free_moving(&m);
}

/* Times outside [0, 1], NaN and infinite times miss the moving mesh and
 * still hit the static floor; the other rays are unaffected. */
static void motion_time_outside(void **state)
{
    (void)state;
    motion_configs mc;
    motion_configs_get(&mc);
    const size_t nb = mc.n;
    moving m = make_moving(2, 1.0, 0.0);
    for (size_t b = 0; b < nb; b++)
        for (int with_floor = 0; with_floor < 2; with_floor++) {
            rtk_device dev = config_device(mc.config[b]);
            rtk_scene s = NULL;
            assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
            const uint32_t floor_id = with_floor ? attach_static(dev, s, floor_v, 4, floor_idx, 2) : 0;
            const uint32_t ball_id = attach(s, moving_geometry(dev, &m, ball.idx, ball.nt));
            commit_ok(dev, s);
            const float times[] = {-0.25f, 1.0001f, 2.0f, NAN, INFINITY, -INFINITY, -0.0f, 0.0f, 1.0f};
            for (size_t k = 0; k < sizeof times / sizeof *times; k++) {
                const float t = times[k];
                const int inside = t >= 0.0f && t <= 1.0f;
                /* straight down (-y) through the ball's centre at t (when inside),
                 * (1.5 t, 0.4 sin(2 t), -0.3 t), onto the floor at y = -6 */
                const float tt = inside ? t : 0.0f;
                rtk_rayhit rh = {
                    .ray = test_ray(1.5f * tt + 0.01f, 20.0f, -0.3f * tt + 0.01f, 0.0f, -1.0f, 0.0f, 0.0f, INFINITY)};
                rh.ray.time = t;
                rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
                rtk_ray oc = rh.ray;
                assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
                assert_int_equal(rtk_occluded1(s, &oc), RTK_OK);
                const uint32_t want = inside ? ball_id : with_floor ? floor_id : RTK_INVALID_GEOMETRY_ID;
                if (rh.hit.geomID != want)
                    fail_msg("%s, time %g: geometry %u hit, expected %u", mc.config[b], t, rh.hit.geomID, want);
                assert_int_equal(oc.tfar == -INFINITY, want != RTK_INVALID_GEOMETRY_ID);
            }
            rtk_scene_release(s);
            rtk_device_release(dev);
        }
    free_moving(&m);
}

/* A vertex NaN (or infinite) at one step leaves its triangles out at
 * every time; a triangle of zero area at step 0 and of area at step 1 is
 * hit where it has area and never at time 0. */
static void motion_bad_vertices(void **state)
{
    (void)state;
    motion_configs mc;
    motion_configs_get(&mc);
    const size_t nb = mc.n;
    /* triangle 0: collinear at step 0, a right triangle at step 1 (in the
     * plane z = 0); triangle 1: its vertex 5 is NaN at step 1; triangle 2:
     * fine, away from both */
    float v0[] = {0, 0, 0, 1, 0, 0, 2, 0, 0, 5, 0, 0, 6, 0, 0, 5, 1, 0, 10, 0, 0, 11, 0, 0, 10, 1, 0};
    float v1[] = {0, 0, 0, 2, 0, 0, 0, 2, 0, 5, 0, 0, 6, 0, 0, NAN, 1, 0, 10, 0, 0, 11, 0, 0, 10, 1, 0};
    const uint32_t idx[] = {0, 1, 2, 3, 4, 5, 6, 7, 8};
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = config_device(mc.config[b]);
        rtk_scene s = NULL;
        assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
        rtk_geometry g = NULL;
        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
        assert_int_equal(rtk_geometry_set_time_step_count(g, 2), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 0, v0, 0, 12, 9), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 1, v1, 0, 12, 9), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, idx, 0, 12, 3), RTK_OK);
        assert_int_equal(rtk_geometry_commit(g), RTK_OK);
        attach(s, g);
        commit_ok(dev, s);
        rtk_scene_info info = {.struct_size = sizeof info};
        assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
        assert_int_equal(info.triangles, 2);
        assert_int_equal(info.triangles_skipped, 1);
        assert_int_equal(info.triangles_degenerate, 0);
        struct {
            float x, y, time;
            uint32_t prim; /* expected, or RTK_INVALID_GEOMETRY_ID */
        } cases[] = {
            {0.3f, 0.3f, 1.0f, 0},  {0.3f, 0.3f, 0.0f, RTK_INVALID_GEOMETRY_ID}, {0.2f, 0.1f, 0.5f, 0},
            {5.2f, 0.2f, 0.0f, RTK_INVALID_GEOMETRY_ID}, {5.2f, 0.2f, 1.0f, RTK_INVALID_GEOMETRY_ID},
            {10.2f, 0.2f, 0.0f, 2}, {10.2f, 0.2f, 0.7f, 2},
        };
        for (size_t k = 0; k < sizeof cases / sizeof *cases; k++) {
            rtk_rayhit rh = {.ray = test_ray(cases[k].x, cases[k].y, 5.0f, 0.0f, 0.0f, -1.0f, 0.0f, INFINITY)};
            rh.ray.time = cases[k].time;
            rh.hit.geomID = rh.hit.primID = RTK_INVALID_GEOMETRY_ID;
            assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
            if (rh.hit.primID != cases[k].prim)
                fail_msg("%s, case %zu: triangle %u hit, expected %u", mc.config[b], k, rh.hit.primID, cases[k].prim);
            if (rh.hit.primID != RTK_INVALID_GEOMETRY_ID)
                assert_true(rh.ray.tfar == 5.0f);
        }
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
}

/* Packets of every width give each lane the single-ray answer, lanes at
 * different times. */
static void motion_packets(void **state)
{
    (void)state;
    motion_configs mc;
    motion_configs_get(&mc);
    const size_t nb = mc.n;
    moving m = make_moving(4, 1.0, 0.0);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = config_device(mc.config[b]);
        rtk_scene s = NULL;
        assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
        attach_static(dev, s, floor_v, 4, floor_idx, 2);
        attach(s, moving_geometry(dev, &m, ball.idx, ball.nt));
        commit_ok(dev, s);
        rng g = {3};
        static const unsigned widths[3] = {4, 8, 16};
        for (int w = 0; w < 3; w++)
            for (int occluded = 0; occluded < 2; occluded++)
                for (int rep = 0; rep < 40; rep++) {
                    const unsigned n = widths[w];
                    _Alignas(64) uint32_t packet[20 * 16];
                    rtk_rayhit single[16];
                    for (unsigned l = 0; l < n; l++) {
                        float o[3], d[3];
                        for (int k = 0; k < 3; k++) {
                            o[k] = -10.0f + 20.0f * rng_float(&g);
                            d[k] = 4.0f * rng_float(&g) - 2.0f - o[k];
                        }
                        single[l] = (rtk_rayhit){.ray = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY)};
                        single[l].ray.time = rng_float(&g);
                        single[l].hit.geomID = RTK_INVALID_GEOMETRY_ID;
                        test_packet_put(packet, n, l, &single[l], occluded);
                        if (occluded)
                            assert_int_equal(rtk_occluded1(s, &single[l].ray), RTK_OK);
                        else
                            assert_int_equal(rtk_intersect1(s, &single[l]), RTK_OK);
                    }
                    assert_int_equal(test_trace_packet(s, n, occluded, NULL, packet), RTK_OK);
                    for (unsigned l = 0; l < n; l++) {
                        rtk_rayhit got;
                        test_packet_get(packet, n, l, &got, occluded);
                        assert_true(got.ray.tfar == single[l].ray.tfar);
                        if (!occluded) {
                            assert_int_equal(got.hit.geomID, single[l].hit.geomID);
                            assert_int_equal(got.hit.primID, single[l].hit.primID);
                        }
                    }
                }
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
    free_moving(&m);
}

/* Streams and packets through the motion layouts alone (no static
 * geometry beside them, so no top level): rtk_intersect1M /
 * rtk_occluded1M, whose kernel interleaves the rays, each in its time
 * segment's tree, and packets of 8, which the core hands to that kernel
 * (no packet kernels for motion blur), give every ray rtk_intersect1's and
 * rtk_occluded1's record to the bit: scattered rays and coherent groups,
 * times in every segment, at the time steps, outside [0, 1] and NaN
 * (no hit), default and robust layouts, every configuration. */
static void motion_streams(void **state)
{
    (void)state;
    motion_configs mc;
    motion_configs_get(&mc);
    moving m = make_moving(4, 1.0, 0.0);
    enum { N = 2400 };
    rtk_rayhit *rays = malloc(N * sizeof *rays), *one = malloc(N * sizeof *one), *many = malloc(N * sizeof *many);
    assert_true(rays && one && many);
    rng g = {11};
    static const float odd_times[5] = {-0.25f, 1.5f, NAN, 0.0f, 1.0f};
    float o[3];
    for (size_t i = 0; i < N; i++) {
        float d[3];
        const int group = (i / 8) % 2; /* every other eight: one origin, nearby directions */
        for (int k = 0; k < 3; k++) {
            if (!group || i % 8 == 0)
                o[k] = -10.0f + 20.0f * rng_float(&g);
            d[k] = (group ? 0.2f : 4.0f) * rng_float(&g) - (group ? 0.1f : 2.0f) - o[k];
        }
        rays[i] = (rtk_rayhit){.ray = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY)};
        rays[i].ray.time = i % 50 < 5 ? odd_times[i % 50] : rng_float(&g);
        rays[i].hit.geomID = rays[i].hit.primID = rays[i].hit.instID = RTK_INVALID_GEOMETRY_ID;
    }
    for (size_t b = 0; b < mc.n; b++)
        for (int robust = 0; robust < 2; robust++) {
            rtk_device dev = config_device(mc.config[b]);
            rtk_scene s = NULL;
            assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
            assert_int_equal(rtk_scene_set_flags(s, robust ? RTK_SCENE_FLAG_ROBUST : RTK_SCENE_FLAG_NONE), RTK_OK);
            attach(s, moving_geometry(dev, &m, ball.idx, ball.nt));
            commit_ok(dev, s);
            rtk_scene_info info = {.struct_size = sizeof info};
            assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
            if (info.stream_in_flight < 4)
                fail_msg("%s%s: %s has no stream kernel (%u in flight)", mc.config[b], robust ? " robust" : "",
                         info.layout, info.stream_in_flight);
            size_t hits = 0;
            for (int occluded = 0; occluded < 2; occluded++) {
                memcpy(one, rays, N * sizeof *rays);
                memcpy(many, rays, N * sizeof *rays);
                for (size_t i = 0; i < N; i++)
                    assert_int_equal(occluded ? rtk_occluded1(s, &one[i].ray) : rtk_intersect1(s, &one[i]), RTK_OK);
                assert_int_equal(occluded ? rtk_occluded1M(s, &many[0].ray, N, sizeof *many)
                                          : rtk_intersect1M(s, many, N, sizeof *many),
                                 RTK_OK);
                for (size_t i = 0; i < N; i++) {
                    if (memcmp(&many[i], &one[i], sizeof one[i]))
                        fail_msg("%s%s: stream ray %zu (time %a): t %a / %a, prim %u / %u, occluded %d",
                                 mc.config[b], robust ? " robust" : "", i, rays[i].ray.time, many[i].ray.tfar,
                                 one[i].ray.tfar, many[i].hit.primID, one[i].hit.primID, occluded);
                    hits += one[i].ray.tfar < INFINITY;
                }
                for (size_t i = 0; i < N; i += 8) {
                    _Alignas(64) uint32_t packet[20 * 8];
                    for (unsigned l = 0; l < 8; l++)
                        test_packet_put(packet, 8, l, &rays[i + l], occluded);
                    assert_int_equal(test_trace_packet(s, 8, occluded, NULL, packet), RTK_OK);
                    for (unsigned l = 0; l < 8; l++) {
                        rtk_rayhit got = rays[i + l];
                        test_packet_get(packet, 8, l, &got, occluded);
                        if (memcmp(&got, &one[i + l], occluded ? sizeof got.ray : sizeof got))
                            fail_msg("%s%s: packet ray %zu: t %a / %a, occluded %d", mc.config[b],
                                     robust ? " robust" : "", i + l, got.ray.tfar, one[i + l].ray.tfar, occluded);
                    }
                }
                for (size_t i = 0; i < N; i++) /* outside [0, 1] or NaN: no hit */
                    if (!(rays[i].ray.time >= 0.0f && rays[i].ray.time <= 1.0f))
                        assert_true(one[i].ray.tfar == INFINITY);
            }
            assert_true(hits > N / 4 && hits < 2 * N - N / 4); /* the rays do hit, and not all of them */
            rtk_scene_release(s);
            rtk_device_release(dev);
        }
    free_moving(&m);
    free(rays);
    free(one);
    free(many);
}

/* What the scene reports: the motion layout alone, or a top level over
 * the static tree and one tree per time step count; bytes; trees built;
 * a geometry back to one time step is static again. */
static void motion_scene_info(void **state)
{
    (void)state;
    moving m2 = make_moving(2, 1.0, 0.0), m3 = make_moving(3, 1.0, 0.0);
    motion_configs mc;
    motion_configs_get(&mc);
    /* the best backend's own layout: the last configuration's, or the one
     * before it when the last names the 4-wide layout */
    const char *layout = mc.layout[strstr(mc.config[mc.n - 1], "motion_layout") ? mc.n - 2 : mc.n - 1];
    rtk_device dev = best_device();
    rtk_scene s = NULL;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    rtk_geometry g2 = moving_geometry(dev, &m2, ball.idx, ball.nt);
    rtk_geometry_retain(g2);
    attach(s, g2);
    commit_ok(dev, s);
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
    assert_string_equal(info.layout, layout);
    assert_string_equal(info.builder, "sah-binned");
    assert_int_equal(info.trees_built, 1);
    assert_int_equal(info.triangles_motion, ball.nt);
    const uint64_t one_segment = info.bytes;
    /* (the leaves' vertex indices and the copy of both steps alone come to
     * over 30 bytes a triangle; this ball takes 47 since the SAH prices a
     * motion node at two blocks of triangles) */
    assert_true(info.bytes_per_triangle > 30.0 && info.bytes_per_triangle < 400.0);
    /* low quality: the Morton builder shapes the tree */
    assert_int_equal(rtk_scene_set_build_quality(s, RTK_BUILD_QUALITY_LOW), RTK_OK);
    commit_ok(dev, s);
    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
    assert_string_equal(info.builder, "morton");
    assert_int_equal(rtk_scene_set_build_quality(s, RTK_BUILD_QUALITY_MEDIUM), RTK_OK);
    /* no export or import of a motion tree */
    rtk_bvh tree = {.struct_size = sizeof tree};
    assert_int_equal(rtk_scene_get_bvh(s, &tree), RTK_ERROR_INVALID_OPERATION);
    /* a floor and a ball of three steps beside it: three trees */
    attach_static(dev, s, floor_v, 4, floor_idx, 2);
    attach(s, moving_geometry(dev, &m3, ball.idx, ball.nt));
    commit_ok(dev, s);
    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
    assert_string_equal(info.layout, "bvh4.object");
    assert_int_equal(info.trees_built, 3);
    assert_int_equal(info.triangles, 2 * ball.nt + 2);
    assert_int_equal(info.triangles_motion, 2 * ball.nt);
    /* two segments hold about twice one segment's bytes */
    assert_true(info.bytes > 2 * one_segment + one_segment / 2);
    rtk_bvh empty = {.struct_size = sizeof empty};
    assert_int_equal(rtk_scene_commit_bvh(s, &empty), RTK_ERROR_INVALID_OPERATION);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "motion blur"));
    /* one step again: g2 is static (slot 1 released), and traced as such */
    assert_int_equal(rtk_geometry_set_time_step_count(g2, 1), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g2), RTK_OK);
    commit_ok(dev, s);
    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
    assert_int_equal(info.triangles_motion, ball.nt);
    assert_int_equal(info.trees_built, 2);
    rtk_rayhit rh = {.ray = test_ray(0.0f, 0.01f, 20.0f, 0.0f, 0.0f, -1.0f, 0.0f, INFINITY)};
    rh.ray.time = 1.0f; /* g2 stays where step 0 has it */
    rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
    assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
    assert_int_equal(rh.hit.geomID, 0);
    rtk_geometry_release(g2);
    rtk_scene_release(s);
    rtk_device_release(dev);
    free_moving(&m2);
    free_moving(&m3);
}

/* The same input gives the same trees for any thread count: the same
 * counts and SAH cost, and the same answers to the bit (ties included). */
static void motion_determinism(void **state)
{
    (void)state;
    test_mesh big = test_ball(160); /* 51,200 triangles: the builders split their work */
    float *v[3];
    for (int k = 0; k < 3; k++) {
        v[k] = malloc(big.nv * 12);
        for (size_t i = 0; i < big.nv; i++)
            for (int d = 0; d < 3; d++)
                v[k][3 * i + d] = big.v[3 * i + d] * (1.0f + 0.2f * (float)k) + (d == 0 ? 0.7f * (float)k : 0.0f);
    }
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    const char *isa = names[nb - 1];
    enum { RAYS = 3000 };
    rtk_rayhit *first = malloc(RAYS * sizeof *first);
    rtk_scene_info info0 = {.struct_size = sizeof info0};
    for (int q = RTK_BUILD_QUALITY_LOW; q <= RTK_BUILD_QUALITY_MEDIUM; q++) {
        static const int threads[3] = {1, 2, 4};
        for (int ti = 0; ti < 3; ti++) {
            rtk_device dev = test_device_threads(isa, threads[ti]);
            rtk_scene s = NULL;
            assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
            assert_int_equal(rtk_scene_set_build_quality(s, (rtk_build_quality)q), RTK_OK);
            rtk_geometry g = NULL;
            assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
            assert_int_equal(rtk_geometry_set_time_step_count(g, 3), RTK_OK);
            for (unsigned k = 0; k < 3; k++)
                assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, k, v[k], 0, 12, big.nv),
                                 RTK_OK);
            assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, big.idx, 0, 12, big.nt), RTK_OK);
            assert_int_equal(rtk_geometry_commit(g), RTK_OK);
            attach(s, g);
            commit_ok(dev, s);
            rtk_scene_info info = {.struct_size = sizeof info};
            assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
            assert_int_equal(info.build_threads, threads[ti]);
            if (ti == 0) {
                info0 = info;
            } else {
                assert_int_equal(info.nodes, info0.nodes);
                assert_int_equal(info.leaves, info0.leaves);
                assert_int_equal(info.depth, info0.depth);
                assert_true(info.sah_cost == info0.sah_cost);
                assert_true(memcmp(info.bounds_lower, info0.bounds_lower, sizeof info.bounds_lower) == 0);
            }
            rng r = {99};
            for (int i = 0; i < RAYS; i++) {
                float o[3], d[3];
                for (int k = 0; k < 3; k++) {
                    o[k] = -4.0f + 8.0f * rng_float(&r);
                    d[k] = -1.0f + 2.0f * rng_float(&r) - o[k];
                }
                rtk_rayhit rh = {.ray = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY)};
                rh.ray.time = rng_float(&r);
                rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
                assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
                if (ti == 0)
                    first[i] = rh;
                else if (memcmp(&rh, &first[i], sizeof rh))
                    fail_msg("quality %d, %d threads: ray %d differs from 1 thread's", q, threads[ti], i);
            }
            rtk_scene_release(s);
            rtk_device_release(dev);
        }
    }
    free(first);
    for (int k = 0; k < 3; k++)
        free(v[k]);
    free(big.v);
    free(big.idx);
}

/* A REFIT geometry with motion blur: new vertices at every step refit
 * its trees (one-level and dynamic scenes, 2 and 5 steps, both widths),
 * and the answers are those of the new vertices; a vertex turned NaN at
 * one step, then fine again, makes the commit build afresh both times; a
 * new time step count does too. */
static void motion_refit(void **state)
{
    (void)state;
    motion_configs mc;
    motion_configs_get(&mc);
    static const int step_counts[2] = {2, 5};
    for (size_t b = 0; b < mc.n; b++)
        for (int sc = 0; sc < 2; sc++)
            for (int dynamic = 0; dynamic < 2; dynamic++) {
                moving m = make_moving(step_counts[sc], 1.0, 0.0);
                rtk_device dev = config_device(mc.config[b]);
                rtk_scene s = NULL;
                assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
                if (dynamic)
                    assert_int_equal(rtk_scene_set_flags(s, RTK_SCENE_FLAG_DYNAMIC), RTK_OK);
                rtk_geometry g = moving_geometry(dev, &m, ball.idx, ball.nt);
                assert_int_equal(rtk_geometry_set_build_quality(g, RTK_BUILD_QUALITY_REFIT), RTK_OK);
                assert_int_equal(rtk_geometry_commit(g), RTK_OK);
                rtk_geometry_retain(g);
                const uint32_t id = attach(s, g);
                commit_ok(dev, s);
                rtk_scene_info info = {.struct_size = sizeof info};
                assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
                assert_int_equal(info.trees_built, 1);
                assert_int_equal(info.refits, 0);
                /* the same ball later along its path: every step moved on
                 * by one step's motion (translated, turned, grown) */
                moving later = make_moving(step_counts[sc] + 1, 1.0, 0.0);
                for (int k = 0; k < m.steps; k++)
                    memcpy(m.v[k], later.v[k + 1], ball.nv * 3 * sizeof(float));
                free_moving(&later);
                assert_int_equal(rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_VERTEX), RTK_OK);
                assert_int_equal(rtk_geometry_commit(g), RTK_OK);
                commit_ok(dev, s);
                assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
                if (info.refits != 1 || info.trees_built != 0)
                    fail_msg("%s, %d steps%s: %u refits, %u trees built", mc.config[b], m.steps,
                             dynamic ? ", dynamic" : "", info.refits, info.trees_built);
                assert_int_equal(info.triangles_motion, ball.nt);
                int hits = 0, excused = 0;
                const int nrays = 1200;
                check_moving(s, &m, 0, 0, id, NULL, RTK_INVALID_GEOMETRY_ID, nrays, 7 + (uint32_t)b, &hits, &excused);
                if (hits < nrays / 5 || excused > nrays / 50)
                    fail_msg("%s, %d steps, refitted: %d hits, %d excused of %d rays", mc.config[b], m.steps, hits,
                             excused, nrays);
                /* vertex 0 NaN at the last step: its triangles leave the
                 * tree, so a build; and back, a build again, every
                 * triangle in */
                const float keep = m.v[m.steps - 1][0];
                for (int nan = 1; nan >= 0; nan--) {
                    m.v[m.steps - 1][0] = nan ? NAN : keep;
                    assert_int_equal(rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_VERTEX), RTK_OK);
                    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
                    commit_ok(dev, s);
                    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
                    assert_int_equal(info.trees_built, 1);
                    assert_int_equal(info.refits, 0);
                    assert_int_equal(info.triangles_skipped > 0, nan);
                }
                check_moving(s, &m, 0, 0, id, NULL, RTK_INVALID_GEOMETRY_ID, nrays / 4, 11 + (uint32_t)b, &hits,
                             &excused);
                /* one more time step: a build */
                moving more = make_moving(m.steps + 1, 1.0, 0.0);
                assert_int_equal(rtk_geometry_set_time_step_count(g, (unsigned)more.steps), RTK_OK);
                for (int k = 0; k < more.steps; k++)
                    assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, (unsigned)k,
                                                                         more.v[k], 0, 12, ball.nv),
                                     RTK_OK);
                assert_int_equal(rtk_geometry_commit(g), RTK_OK);
                commit_ok(dev, s);
                assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
                assert_int_equal(info.trees_built, 1);
                assert_int_equal(info.refits, 0);
                check_moving(s, &more, 0, 0, id, NULL, RTK_INVALID_GEOMETRY_ID, nrays / 4, 13 + (uint32_t)b, &hits,
                             &excused);
                rtk_geometry_release(g);
                rtk_scene_release(s);
                rtk_device_release(dev);
                free_moving(&more);
                free_moving(&m);
            }
}

/* Errors: step counts out of range, slots beyond the count, an index
 * slot, a missing or short slot at commit, time steps on an instance. */
static void motion_errors(void **state)
{
    (void)state;
    rtk_device dev = best_device();
    rtk_geometry g = NULL;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_time_step_count(g, 0), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_geometry_set_time_step_count(g, RTK_MAX_TIME_STEPS + 1), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_geometry_set_time_step_count(NULL, 2), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 1, ball.v, 0, 12, ball.nv),
                     RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "1 time step"));
    assert_int_equal(rtk_geometry_set_time_step_count(g, 3), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_INDEX, 1, ball.idx, 0, 12, ball.nt),
                     RTK_ERROR_INVALID_ARGUMENT);
    void *mem = NULL;
    assert_int_equal(rtk_geometry_set_new_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 3, 12, ball.nv, &mem),
                     RTK_ERROR_INVALID_ARGUMENT);
    assert_null(mem);
    assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 0, ball.v, 0, 12, ball.nv), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, ball.idx, 0, 12, ball.nt), RTK_OK);
    assert_int_equal(rtk_geometry_set_new_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 2, 12, ball.nv, &mem), RTK_OK);
    memcpy(mem, ball.v, ball.nv * 12);
    assert_int_equal(rtk_geometry_commit(g), RTK_ERROR_INVALID_OPERATION); /* slot 1 missing */
    assert_non_null(strstr(rtk_device_get_error_message(dev), "slot 1"));
    assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 1, ball.v, 0, 12, ball.nv - 1),
                     RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_ERROR_INVALID_ARGUMENT); /* slot 1 short */
    assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 1, ball.v, 0, 12, ball.nv),
                     RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    /* an out-of-range index is caught for moving geometry too */
    uint32_t *bad = malloc(ball.nt * 12);
    memcpy(bad, ball.idx, ball.nt * 12);
    bad[5] = (uint32_t)ball.nv;
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, bad, 0, 12, ball.nt), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    rtk_scene s = NULL;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
    assert_int_equal(rtk_scene_commit(s), RTK_ERROR_INVALID_GEOMETRY);
    rtk_scene_release(s);
    free(bad);
    rtk_geometry_release(g);
    rtk_geometry inst = NULL;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &inst), RTK_OK);
    assert_int_equal(rtk_geometry_set_time_step_count(inst, 2), RTK_ERROR_INVALID_OPERATION);
    rtk_geometry_release(inst);
    rtk_device_release(dev);
    /* motion_layout= names a motion-blur layout of the backend, else the
     * device is refused with the list of those it has */
    static const char *const bad_layouts[] = {"isa=scalar,motion_layout=bvh4.triangle4",
                                              "isa=scalar,motion_layout=bvh8.triangle4mb", "motion_layout=bvh4mb",
                                              "motion_layout=BVH4"};
    for (size_t k = 0; k < sizeof bad_layouts / sizeof *bad_layouts; k++) {
        rtk_device d = NULL;
        assert_int_equal(rtk_device_new(bad_layouts[k], &d), RTK_ERROR_INVALID_CONFIG);
        assert_null(d);
        if (k < 3)
            assert_non_null(strstr(rtk_device_get_error_message(NULL), "bvh4.triangle4mb"));
    }
}

/* "quick": the tests whose motion builds and refits run on several
 * threads, for scripts/test's ThreadSanitizer run (the others trace on
 * the calling thread alone). */
int main(int argc, char **argv)
{
    const struct CMUnitTest quick[] = {
        cmocka_unit_test(motion_determinism),
        cmocka_unit_test(motion_refit),
    };
    if (argc > 1 && !strcmp(argv[1], "quick"))
        return cmocka_run_group_tests(quick, setup, teardown);
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(motion_vs_reference), cmocka_unit_test(motion_steps_exact),
        cmocka_unit_test(motion_time_outside), cmocka_unit_test(motion_bad_vertices),
        cmocka_unit_test(motion_packets),      cmocka_unit_test(motion_streams),
        cmocka_unit_test(motion_scene_info),
        cmocka_unit_test(motion_determinism), cmocka_unit_test(motion_refit),
        cmocka_unit_test(motion_errors),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
