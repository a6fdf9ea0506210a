/*
 * Quad geometry (rtk.h: quads), on every backend and layout, through
 * intersect1, occluded1 and packets of 4, 8 and 16 rays, with filters,
 * masks, instances, motion blur, refit, dynamic scenes and exported trees.
 *
 * The reference for each answer is a triangle scene of the same backend
 * and layout over the quads' halves (2q = v0 v1 v3, 2q + 1 = v2 v3 v1):
 * the quad scene must answer bit for bit as it does, with primID q and
 * u, v carried over to the quad (the second half's 1 - u, 1 - v).  That
 * convention is checked on its own too: the point the quad's u, v name
 * (on the half they fall in) is where the ray is at t.  With Embree 3
 * present, its quads (RTC_GEOMETRY_TYPE_QUAD) answer the same rays.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifdef RTK_HAVE_EMBREE
#include <embree3/rtcore.h>
#endif

#include "testlib.h"

enum { RAYS = 2000 };

/* A bumpy ball of quads: (r + 1) x (r + 1) vertices on a latitude and
 * longitude grid, r x r quads, not planar (the radius varies), the rows
 * at the poles each with two corners in one point (a triangle given as a
 * quad, one half of zero area). */
typedef struct qmesh {
    float *v;
    uint32_t *q;   /* 4 per quad */
    uint32_t *tri; /* the halves: 3 per triangle, 2 per quad */
    size_t nv, nq;
} qmesh;

static qmesh quad_ball(int r, float shift)
{
    qmesh m = {.nv = (size_t)(r + 1) * (r + 1), .nq = (size_t)r * r};
    m.v = malloc(m.nv * 3 * sizeof *m.v);
    m.q = malloc(m.nq * 4 * sizeof *m.q);
    m.tri = malloc(m.nq * 6 * sizeof *m.tri);
    assert_non_null(m.v);
    assert_non_null(m.q);
    assert_non_null(m.tri);
    for (int i = 0; i <= r; i++)
        for (int j = 0; j <= r; j++) {
            const double th = M_PI * i / r, ph = 2.0 * M_PI * (j % r) / r;
            const double rad = 1.0 + 0.15 * sin(5.0 * th) * cos(3.0 * ph) + shift;
            float *p = &m.v[3 * ((size_t)i * (r + 1) + j)];
            /* the poles exactly on the axis: every vertex of a pole row one point */
            const double s = (i == 0 || i == r) ? 0.0 : sin(th);
            p[0] = (float)(rad * s * cos(ph));
            p[1] = (float)(rad * s * sin(ph));
            p[2] = (float)(rad * cos(th));
        }
    for (int i = 0; i < r; i++)
        for (int j = 0; j < r; j++) {
            uint32_t *q = &m.q[4 * ((size_t)i * r + j)];
            const uint32_t a = (uint32_t)(i * (r + 1) + j);
            q[0] = a, q[1] = a + 1, q[2] = a + (uint32_t)r + 2, q[3] = a + (uint32_t)r + 1;
        }
    for (size_t k = 0; k < m.nq; k++) {
        const uint32_t *q = &m.q[4 * k];
        uint32_t *t = &m.tri[6 * k];
        t[0] = q[0], t[1] = q[1], t[2] = q[3];
        t[3] = q[2], t[4] = q[3], t[5] = q[1];
    }
    return m;
}

static void qmesh_free(qmesh *m)
{
    free(m->v);
    free(m->q);
    free(m->tri);
}

/* A committed scene of one geometry: quads (quads != 0) or their halves. */
typedef struct scene_opts {
    unsigned flags;
    rtk_build_quality quality;
    const float *v_step1; /* a second time step, or NULL */
    rtk_filter_fn ifilter, ofilter;
    uint32_t mask;
    void *user; /* user data for quads, user_tri for their halves */
    void *user_tri;
} scene_opts;

static rtk_geometry mesh_geometry(rtk_device dev, const qmesh *m, int quads, const scene_opts *o)
{
    rtk_geometry g;
    assert_int_equal(rtk_geometry_new(dev, quads ? RTK_GEOMETRY_TYPE_QUAD : RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    if (o->v_step1) {
        assert_int_equal(rtk_geometry_set_time_step_count(g, 2), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 1, o->v_step1, 0, 12, m->nv),
                         RTK_OK);
    }
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, m->v, 0, 12, m->nv), RTK_OK);
    if (quads)
        assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, m->q, 0, 16, m->nq), RTK_OK);
    else
        assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, m->tri, 0, 12, 2 * m->nq), RTK_OK);
    if (o->quality)
        assert_int_equal(rtk_geometry_set_build_quality(g, o->quality), RTK_OK);
    if (o->ifilter)
        assert_int_equal(rtk_geometry_set_intersect_filter(g, o->ifilter), RTK_OK);
    if (o->ofilter)
        assert_int_equal(rtk_geometry_set_occluded_filter(g, o->ofilter), RTK_OK);
    if (o->mask)
        assert_int_equal(rtk_geometry_set_mask(g, o->mask), RTK_OK);
    assert_int_equal(rtk_geometry_set_user_data(g, quads ? o->user : o->user_tri), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    return g;
}

static rtk_scene mesh_scene(rtk_device dev, const qmesh *m, int quads, const scene_opts *o)
{
    rtk_scene s;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    assert_int_equal(rtk_scene_set_flags(s, o->flags), RTK_OK);
    rtk_geometry g = mesh_geometry(dev, m, quads, o);
    assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
    rtk_geometry_release(g);
    if (rtk_scene_commit(s) != RTK_OK)
        fail_msg("commit: %s", rtk_device_get_error_message(dev));
    return s;
}

/* RAYS rays (malloc'd) from a sphere of radius 3 toward random points of [-1, 1]^3, and
 * (every third) toward vertices and the midpoints of the quads' diagonals
 * (where the halves meet) and of their edges: those points into
 * targets[i] (if not NULL). */
static rtk_ray *make_rays(const qmesh *m, uint64_t seed, float (*targets)[3])
{
    const size_t n = RAYS;
    rtk_ray *rays = malloc(n * sizeof *rays);
    assert_non_null(rays);
    rng r = {seed};
    for (size_t i = 0; i < n; i++) {
        float o[3], t[3], len = 0.0f;
        for (int k = 0; k < 3; k++) {
            o[k] = 2.0f * rng_float(&r) - 1.0f;
            len += o[k] * o[k];
        }
        len = sqrtf(len) + 1e-6f;
        for (int k = 0; k < 3; k++)
            o[k] *= 3.0f / len;
        if (i % 3 == 0) { /* at a corner, a diagonal's midpoint or an edge's */
            const uint32_t *q = &m->q[4 * (rng_u32(&r) % m->nq)];
            const int kind = (int)(rng_u32(&r) % 3);
            for (int k = 0; k < 3; k++) {
                const float a = m->v[3 * q[0] + k], b = m->v[3 * q[1] + k], c = m->v[3 * q[2] + k],
                            d = m->v[3 * q[3] + k];
                t[k] = kind == 0 ? a : kind == 1 ? 0.5f * (b + d) : 0.5f * (a + b);
                (void)c;
            }
        } else {
            for (int k = 0; k < 3; k++)
                t[k] = 2.0f * rng_float(&r) - 1.0f;
        }
        if (targets)
            memcpy(targets[i], t, sizeof t);
        rays[i] = test_ray(o[0], o[1], o[2], t[0] - o[0], t[1] - o[1], t[2] - o[2], 0.0f, INFINITY);
        rays[i].id = (uint32_t)i;
        if (i % 7 == 0)
            rays[i].tfar = 0.8f; /* short of most of the ball */
        if (i % 11 == 0)
            rays[i].flags = RTK_RAY_FLAG_CULL_BACK;
    }
    return rays;
}

/* The quad scene's answer equals the triangle scene's, translated. */
static void expect_translated(const rtk_rayhit *q, const rtk_rayhit *t, const char *what, size_t i)
{
    if (t->hit.geomID == RTK_INVALID_GEOMETRY_ID) {
        if (q->hit.geomID != RTK_INVALID_GEOMETRY_ID)
            fail_msg("%s ray %zu: the quads hit (prim %u), their halves miss", what, i, q->hit.primID);
        return;
    }
    const int second = (int)(t->hit.primID & 1u);
    const float u = second ? 1.0f - t->hit.u : t->hit.u, v = second ? 1.0f - t->hit.v : t->hit.v;
    if (q->hit.geomID != t->hit.geomID || q->hit.primID != t->hit.primID / 2 || q->ray.tfar != t->ray.tfar ||
        q->hit.u != u || q->hit.v != v || q->hit.Ng_x != t->hit.Ng_x || q->hit.Ng_y != t->hit.Ng_y ||
        q->hit.Ng_z != t->hit.Ng_z || q->hit.instID != t->hit.instID)
        fail_msg("%s ray %zu: quad geom %u prim %u t %.9g uv %.9g %.9g inst %u; halves: geom %u prim %u t %.9g uv "
                 "%.9g %.9g inst %u",
                 what, i, q->hit.geomID, q->hit.primID, q->ray.tfar, q->hit.u, q->hit.v, q->hit.instID,
                 t->hit.geomID, t->hit.primID, t->ray.tfar, t->hit.u, t->hit.v, t->hit.instID);
}

/* Where quad `prim`'s u, v are (on the half they fall in), against the
 * ray's point at t: the convention of rtk.h, independent of the kernels. */
static double quad_point_error(const qmesh *m, uint32_t quad, double u, double v, const rtk_ray *r, double t,
                               const float *offset)
{
    const uint32_t *q = &m->q[4 * quad];
    double err = 0.0;
    for (int k = 0; k < 3; k++) {
        const double a = m->v[3 * q[0] + k], b = m->v[3 * q[1] + k], c = m->v[3 * q[2] + k], d = m->v[3 * q[3] + k];
        const double p = u + v <= 1.0 ? a + u * (b - a) + v * (d - a) : c + (1.0 - u) * (d - c) + (1.0 - v) * (b - c);
        const double o = (&r->org_x)[k] - (offset ? offset[k] : 0.0f);
        err = fmax(err, fabs(p - (o + t * (&r->dir_x)[k])));
    }
    return err;
}

static void expect_uv_point(const qmesh *m, const rtk_rayhit *h, const float *offset, const char *what, size_t i)
{
    if (h->hit.geomID == RTK_INVALID_GEOMETRY_ID)
        return;
    const double u = h->hit.u, v = h->hit.v;
    if (!(u >= -1e-6 && u <= 1.0 + 1e-6 && v >= -1e-6 && v <= 1.0 + 1e-6))
        fail_msg("%s ray %zu: quad u, v %.9g %.9g outside [0, 1]", what, i, u, v);
    const double err = quad_point_error(m, h->hit.primID, u, v, &h->ray, h->ray.tfar, offset);
    if (err > 1e-4)
        fail_msg("%s ray %zu: quad %u at u, v %.9g %.9g is %.3g from the ray's point at t", what, i, h->hit.primID,
                 u, v, err);
}

static rtk_rayhit fresh(const rtk_ray *r)
{
    rtk_rayhit rh = {.ray = *r};
    rh.hit.geomID = rh.hit.primID = rh.hit.instID = RTK_INVALID_GEOMETRY_ID;
    return rh;
}

/* Every ray through both scenes: single rays and packets of every width. */
static void compare_scenes(const qmesh *m, rtk_scene qs, rtk_scene ts, const rtk_ray *rays, size_t n,
                           const rtk_query_context *ctx, const float *offset, const char *what)
{
    for (size_t i = 0; i < n; i++) {
        rtk_rayhit a = fresh(&rays[i]), b = fresh(&rays[i]);
        rtk_ray oa = rays[i], ob = rays[i];
        assert_int_equal(rtk_intersect1_ctx(qs, &a, ctx), RTK_OK);
        assert_int_equal(rtk_intersect1_ctx(ts, &b, ctx), RTK_OK);
        assert_int_equal(rtk_occluded1_ctx(qs, &oa, ctx), RTK_OK);
        assert_int_equal(rtk_occluded1_ctx(ts, &ob, ctx), RTK_OK);
        expect_translated(&a, &b, what, i);
        expect_uv_point(m, &a, offset, what, i);
        if ((oa.tfar == -INFINITY) != (ob.tfar == -INFINITY))
            fail_msg("%s ray %zu: occluded1 %d on the quads, %d on their halves", what, i, oa.tfar == -INFINITY,
                     ob.tfar == -INFINITY);
    }
    static const unsigned widths[] = {4, 8, 16};
    for (int wi = 0; wi < 3; wi++) {
        const unsigned w = widths[wi];
        _Alignas(64) uint32_t pq[20 * 16], pt[20 * 16], oq[12 * 16], ot[12 * 16];
        int valid[16];
        for (size_t base = 0; base + w <= n; base += w) {
            for (unsigned l = 0; l < w; l++) {
                const rtk_rayhit rh = fresh(&rays[base + l]);
                test_packet_put(pq, w, l, &rh, 0);
                test_packet_put(pt, w, l, &rh, 0);
                test_packet_put(oq, w, l, &rh, 1);
                test_packet_put(ot, w, l, &rh, 1);
                valid[l] = (base + l) % 13 != 5;
            }
            assert_int_equal(test_trace_packet(qs, w, 0, valid, pq), RTK_OK);
            assert_int_equal(test_trace_packet(ts, w, 0, valid, pt), RTK_OK);
            assert_int_equal(test_trace_packet(qs, w, 1, valid, oq), RTK_OK);
            assert_int_equal(test_trace_packet(ts, w, 1, valid, ot), RTK_OK);
            for (unsigned l = 0; l < w; l++) {
                rtk_rayhit a, b, c, d;
                test_packet_get(pq, w, l, &a, 0);
                test_packet_get(pt, w, l, &b, 0);
                test_packet_get(oq, w, l, &c, 1);
                test_packet_get(ot, w, l, &d, 1);
                char name[96];
                snprintf(name, sizeof name, "%s, packet of %u", what, w);
                if (!valid[l] && (a.hit.geomID != RTK_INVALID_GEOMETRY_ID || c.ray.tfar != rays[base + l].tfar))
                    fail_msg("%s ray %zu: an invalid lane was changed", name, base + l);
                expect_translated(&a, &b, name, base + l);
                expect_uv_point(m, &a, offset, name, base + l);
                if ((c.ray.tfar == -INFINITY) != (d.ray.tfar == -INFINITY))
                    fail_msg("%s ray %zu: occluded %d on the quads, %d on their halves", name, base + l,
                             c.ray.tfar == -INFINITY, d.ray.tfar == -INFINITY);
            }
        }
    }
}

static const unsigned layout_flags[] = {0, RTK_SCENE_FLAG_COMPACT, RTK_SCENE_FLAG_ROBUST,
                                        RTK_SCENE_FLAG_ROBUST | RTK_SCENE_FLAG_COMPACT, RTK_SCENE_FLAG_DYNAMIC};

/* Quads and their halves, every backend, every layout; the robust layouts
 * have no hole where a quad's halves meet. */
static void test_every_backend_and_layout(void **state)
{
    (void)state;
    qmesh m = quad_ball(24, 0.0f);
    float(*targets)[3] = malloc(RAYS * sizeof *targets);
    assert_non_null(targets);
    rtk_ray *rays = make_rays(&m, 5, targets);
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (size_t f = 0; f < sizeof layout_flags / sizeof layout_flags[0]; f++) {
            const scene_opts o = {.flags = layout_flags[f]};
            rtk_scene qs = mesh_scene(dev, &m, 1, &o), ts = mesh_scene(dev, &m, 0, &o);
            rtk_scene_info qi = {.struct_size = sizeof qi}, ti = {.struct_size = sizeof ti};
            assert_int_equal(rtk_scene_get_info(qs, &qi), RTK_OK);
            assert_int_equal(rtk_scene_get_info(ts, &ti), RTK_OK);
            assert_int_equal(qi.quads, m.nq);
            assert_int_equal(ti.quads, 0);
            assert_string_equal(qi.layout, ti.layout);
            assert_int_equal(qi.triangles, ti.triangles);
            /* the pole rows' quads have a half of zero area */
            assert_int_equal(qi.triangles_degenerate, 2 * 24);
            assert_int_equal(qi.triangles + qi.triangles_degenerate, 2 * m.nq);
            char what[96];
            snprintf(what, sizeof what, "%s %s", names[b], qi.layout);
            compare_scenes(&m, qs, ts, rays, RAYS, NULL, NULL, what);
            if (layout_flags[f] & RTK_SCENE_FLAG_ROBUST) {
                /* from the centre, inside the closed ball, exactly through
                 * a vertex or the midpoint of a diagonal or an edge: the
                 * ray leaves the ball, so it must hit (no hole where the
                 * halves or the quads meet) */
                for (size_t i = 0; i < RAYS; i += 3) {
                    const float *p = targets[i];
                    const rtk_ray r = test_ray(0.0f, 0.0f, 0.0f, p[0], p[1], p[2], 0.0f, INFINITY);
                    rtk_rayhit h = fresh(&r);
                    rtk_ray o = r;
                    assert_int_equal(rtk_intersect1(qs, &h), RTK_OK);
                    assert_int_equal(rtk_occluded1(qs, &o), RTK_OK);
                    if (h.hit.geomID == RTK_INVALID_GEOMETRY_ID || o.tfar != -INFINITY)
                        fail_msg("%s: the ray from the centre through %g %g %g misses the closed ball", what,
                                 p[0], p[1], p[2]);
                }
            }
            rtk_scene_release(qs);
            rtk_scene_release(ts);
        }
        rtk_device_release(dev);
    }
    free(rays);
    free(targets);
    qmesh_free(&m);
}

/* Filters on quads see the quad's id and u, v; the rule rejects by the
 * quad, so the halves' scene gets the same rule by primID / 2.  The
 * geometry's user data says which it is; the query's context, if any,
 * counts the calls. */
typedef struct quser {
    const qmesh *m;
    int quads;
} quser;
typedef struct qlog {
    rtk_query_context ctx;
    unsigned calls, bad;
} qlog;

static int rule(uint32_t quad, uint32_t ray_id)
{
    return (quad * 5u + ray_id) % 3u != 0u;
}

static int qfilter(const rtk_filter_args *a)
{
    qlog none = {0}, *log = a->context ? (qlog *)a->context : &none;
    const quser *user = a->geometry_user;
    const uint32_t quad = user->quads ? a->hit->primID : a->hit->primID / 2;
    log->calls++;
    if (user->quads) {
        if (a->hit->primID >= user->m->nq || !(a->hit->u >= 0.0f && a->hit->u <= 1.0f && a->hit->v >= 0.0f &&
                                               a->hit->v <= 1.0f))
            log->bad++;
        else /* the point u, v name is the ray's at t */
            log->bad += quad_point_error(user->m, quad, a->hit->u, a->hit->v, a->ray, a->t, NULL) > 1e-4;
    }
    return rule(quad, a->ray->id);
}

static void test_filters_and_masks(void **state)
{
    (void)state;
    qmesh m = quad_ball(16, 0.0f);
    rtk_ray *rays = make_rays(&m, 9, NULL);
    for (size_t i = 0; i < RAYS; i++)
        rays[i].mask = i % 4 == 1 ? 2u : 5u;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (size_t f = 0; f < 3; f++) {
            quser uq = {&m, 1}, ut = {&m, 0};
            const scene_opts o = {.flags = layout_flags[f], .ifilter = qfilter, .ofilter = qfilter, .mask = 1u,
                                  .user = &uq, .user_tri = &ut};
            rtk_scene qs = mesh_scene(dev, &m, 1, &o), ts = mesh_scene(dev, &m, 0, &o);
            qlog lq = {0}, lt = {0};
            /* each scene's filter calls counted in its own log */
            for (size_t i = 0; i < RAYS; i++) {
                rtk_rayhit a = fresh(&rays[i]), c = fresh(&rays[i]);
                rtk_ray oa = rays[i], oc = rays[i];
                assert_int_equal(rtk_intersect1_ctx(qs, &a, &lq.ctx), RTK_OK);
                assert_int_equal(rtk_intersect1_ctx(ts, &c, &lt.ctx), RTK_OK);
                assert_int_equal(rtk_occluded1_ctx(qs, &oa, &lq.ctx), RTK_OK);
                assert_int_equal(rtk_occluded1_ctx(ts, &oc, &lt.ctx), RTK_OK);
                expect_translated(&a, &c, names[b], i);
                if (a.hit.geomID != RTK_INVALID_GEOMETRY_ID && !rule(a.hit.primID, rays[i].id))
                    fail_msg("%s ray %zu: a hit on quad %u, which the filter rejects", names[b], i, a.hit.primID);
                if ((oa.tfar == -INFINITY) != (oc.tfar == -INFINITY))
                    fail_msg("%s ray %zu: occluded differs", names[b], i);
                if (rays[i].mask == 2u && (a.hit.geomID != RTK_INVALID_GEOMETRY_ID || oa.tfar == -INFINITY))
                    fail_msg("%s ray %zu: a masked-out quad geometry is hit", names[b], i);
            }
            assert_true(lq.calls > RAYS / 4);
            assert_int_equal(lq.calls, lt.calls);
            if (lq.bad)
                fail_msg("%s: %u filter calls saw a quad hit out of range or off the ray", names[b], lq.bad);
            /* packets too (the filters see single rays) */
            compare_scenes(&m, qs, ts, rays, 256, NULL, NULL, names[b]);
            rtk_scene_release(qs);
            rtk_scene_release(ts);
        }
        rtk_device_release(dev);
    }
    free(rays);
    qmesh_free(&m);
}

/* Quads inside an instance (moved by +2 in x), with motion blur, refitted,
 * and from an exported tree. */
static rtk_scene instancing(rtk_device dev, rtk_scene child)
{
    rtk_scene top;
    rtk_geometry inst;
    static const float xfm[12] = {1, 0, 0, 2, 0, 1, 0, 0, 0, 0, 1, 0};
    assert_int_equal(rtk_scene_new(dev, &top), RTK_OK);
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &inst), RTK_OK);
    assert_int_equal(rtk_geometry_set_instanced_scene(inst, child), RTK_OK);
    assert_int_equal(rtk_geometry_set_transform(inst, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, xfm), RTK_OK);
    assert_int_equal(rtk_geometry_commit(inst), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(top, inst, NULL), RTK_OK);
    rtk_geometry_release(inst);
    assert_int_equal(rtk_scene_commit(top), RTK_OK);
    return top;
}

static void test_instances_motion_refit_trees(void **state)
{
    (void)state;
    qmesh m = quad_ball(20, 0.0f), moved = quad_ball(20, 0.2f);
    rtk_ray *rays = make_rays(&m, 13, NULL);
    rng r = {21};
    for (size_t i = 0; i < RAYS; i++)
        rays[i].time = rng_float(&r);
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        char what[96];
        /* instances: the rays moved with the instance */
        {
            const scene_opts o = {0};
            rtk_scene qs = mesh_scene(dev, &m, 1, &o), ts = mesh_scene(dev, &m, 0, &o);
            rtk_scene qt = instancing(dev, qs), tt = instancing(dev, ts);
            rtk_ray *shifted = malloc(RAYS * sizeof *shifted);
            assert_non_null(shifted);
            for (size_t i = 0; i < RAYS; i++) {
                shifted[i] = rays[i];
                shifted[i].org_x += 2.0f;
            }
            snprintf(what, sizeof what, "%s instance", names[b]);
            const float offset[3] = {2.0f, 0.0f, 0.0f};
            compare_scenes(&m, qt, tt, shifted, RAYS, NULL, offset, what);
            free(shifted);
            rtk_scene_release(qt);
            rtk_scene_release(tt);
            rtk_scene_release(qs);
            rtk_scene_release(ts);
        }
        /* motion blur: from the ball to the grown ball (u, v checked
         * against the ball at time 0 only for rays at time 0) */
        {
            const scene_opts o = {.v_step1 = moved.v};
            rtk_scene qs = mesh_scene(dev, &m, 1, &o), ts = mesh_scene(dev, &m, 0, &o);
            snprintf(what, sizeof what, "%s motion", names[b]);
            for (size_t i = 0; i < RAYS; i++) {
                rtk_rayhit a = fresh(&rays[i]), c = fresh(&rays[i]);
                assert_int_equal(rtk_intersect1(qs, &a), RTK_OK);
                assert_int_equal(rtk_intersect1(ts, &c), RTK_OK);
                expect_translated(&a, &c, what, i);
            }
            rtk_scene_release(qs);
            rtk_scene_release(ts);
        }
        /* refit: the vertices move in place, the tree is refitted */
        {
            float *v = malloc(m.nv * 12);
            assert_non_null(v);
            memcpy(v, m.v, m.nv * 12);
            qmesh mv = m;
            mv.v = v;
            const scene_opts o = {.quality = RTK_BUILD_QUALITY_REFIT};
            rtk_scene qs = mesh_scene(dev, &mv, 1, &o), ts = mesh_scene(dev, &mv, 0, &o);
            memcpy(v, moved.v, m.nv * 12);
            for (int k = 0; k < 2; k++) {
                rtk_scene s = k ? ts : qs;
                rtk_geometry g = rtk_scene_get_geometry(s, 0);
                assert_int_equal(rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_VERTEX), RTK_OK);
                assert_int_equal(rtk_geometry_commit(g), RTK_OK);
                assert_int_equal(rtk_scene_commit(s), RTK_OK);
                rtk_scene_info info = {.struct_size = sizeof info};
                assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
                assert_int_equal(info.refits, 1);
            }
            snprintf(what, sizeof what, "%s refit", names[b]);
            for (size_t i = 0; i < RAYS; i++)
                rays[i].time = 0.0f;
            compare_scenes(&moved, qs, ts, rays, RAYS, NULL, NULL, what);
            rtk_scene_release(qs);
            rtk_scene_release(ts);
            free(v);
        }
        /* the tree exported and committed again: the halves are 2q, 2q + 1 */
        {
            const scene_opts o = {0};
            rtk_scene qs = mesh_scene(dev, &m, 1, &o), ts = mesh_scene(dev, &m, 0, &o);
            rtk_bvh t = {.struct_size = sizeof t};
            assert_int_equal(rtk_scene_get_bvh(qs, &t), RTK_OK);
            for (uint64_t k = 0; k < t.prim_count; k++)
                assert_true(t.prims[k].prim_id < 2 * m.nq);
            rtk_scene again;
            assert_int_equal(rtk_scene_new(dev, &again), RTK_OK);
            rtk_geometry g = mesh_geometry(dev, &m, 1, &o);
            assert_int_equal(rtk_scene_attach_geometry(again, g, NULL), RTK_OK);
            rtk_geometry_release(g);
            if (rtk_scene_commit_bvh(again, &t) != RTK_OK)
                fail_msg("commit_bvh: %s", rtk_device_get_error_message(dev));
            rtk_bvh_free(&t);
            snprintf(what, sizeof what, "%s loaded tree", names[b]);
            compare_scenes(&m, again, ts, rays, RAYS, NULL, NULL, what);
            rtk_scene_release(again);
            rtk_scene_release(qs);
            rtk_scene_release(ts);
        }
        rtk_device_release(dev);
    }
    free(rays);
    qmesh_free(&m);
    qmesh_free(&moved);
}

/* Bad quads get clear errors. */
static void test_errors(void **state)
{
    (void)state;
    rtk_device dev;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    static const float v[12] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
    static const uint32_t good[4] = {0, 1, 2, 3}, bad[4] = {0, 1, 2, 4};
    rtk_geometry g;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_QUAD, &g), RTK_OK);
    /* three indices a quad is not */
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, good, 0, 12, 1),
                     RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "at least 16"));
    /* more quads than 32-bit ids of their halves can number (not read here) */
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, good, 0, 16, (size_t)1 << 31),
                     RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "exceed 2^31 - 1"));
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, 4), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, bad, 0, 16, 1), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    rtk_scene s;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
    /* the fourth index out of range */
    assert_int_equal(rtk_scene_commit(s), RTK_ERROR_INVALID_GEOMETRY);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "quad 0: vertex index 4 out of range"));
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, good, 0, 16, 1), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    /* the unit square: u, v are x, y; both halves */
    const float xy[4][2] = {{0.25f, 0.25f}, {0.75f, 0.5f}, {0.1f, 0.8f}, {0.9f, 0.95f}};
    for (int k = 0; k < 4; k++) {
        rtk_ray r = test_ray(xy[k][0], xy[k][1], 1.0f, 0.0f, 0.0f, -1.0f, 0.0f, INFINITY);
        rtk_rayhit h = fresh(&r);
        assert_int_equal(rtk_intersect1(s, &h), RTK_OK);
        assert_int_equal(h.hit.primID, 0);
        assert_float_equal(h.hit.u, xy[k][0], 1e-6);
        assert_float_equal(h.hit.v, xy[k][1], 1e-6);
        assert_float_equal(h.ray.tfar, 1.0f, 0.0);
        assert_true(h.hit.Ng_z > 0.0f);
    }
    rtk_scene_release(s);
    rtk_geometry_release(g);
    rtk_device_release(dev);
}

#ifdef RTK_HAVE_EMBREE
/* Embree's quads on the same rays: the same quad hit, t and u, v, except
 * for rays whose hit (by either) is within 1e-4 of an edge of a half,
 * where the two intersectors' rounding may choose differently. */
static int near_edge(const rtk_hit *h)
{
    const float u = h->u, v = h->v;
    const float s = u + v <= 1.0f ? 1.0f - u - v : u + v - 1.0f;
    return u < 1e-4f || v < 1e-4f || u > 1.0f - 1e-4f || v > 1.0f - 1e-4f || s < 1e-4f;
}

static void test_versus_embree(void **state)
{
    (void)state;
    qmesh m = quad_ball(24, 0.0f);
    rtk_ray *rays = make_rays(&m, 17, NULL);
    RTCDevice edev = rtcNewDevice(NULL);
    assert_non_null(edev);
    RTCScene es = rtcNewScene(edev);
    RTCGeometry eg = rtcNewGeometry(edev, RTC_GEOMETRY_TYPE_QUAD);
    rtcSetSharedGeometryBuffer(eg, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, m.v, 0, 12, m.nv);
    rtcSetSharedGeometryBuffer(eg, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT4, m.q, 0, 16, m.nq);
    rtcCommitGeometry(eg);
    rtcAttachGeometry(es, eg);
    rtcReleaseGeometry(eg);
    rtcCommitScene(es);
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        const scene_opts o = {0};
        rtk_scene qs = mesh_scene(dev, &m, 1, &o);
        size_t hits = 0, excused = 0;
        for (size_t i = 0; i < RAYS; i++) {
            if (rays[i].flags)
                continue; /* Embree 3 culls per build, not per ray */
            rtk_rayhit a = fresh(&rays[i]);
            assert_int_equal(rtk_intersect1(qs, &a), RTK_OK);
            struct RTCIntersectContext ctx;
            rtcInitIntersectContext(&ctx);
            struct RTCRayHit e = {0};
            e.ray.org_x = rays[i].org_x, e.ray.org_y = rays[i].org_y, e.ray.org_z = rays[i].org_z;
            e.ray.dir_x = rays[i].dir_x, e.ray.dir_y = rays[i].dir_y, e.ray.dir_z = rays[i].dir_z;
            e.ray.tnear = rays[i].tnear, e.ray.tfar = rays[i].tfar, e.ray.mask = ~0u;
            e.hit.geomID = RTC_INVALID_GEOMETRY_ID;
            rtcIntersect1(es, &ctx, &e);
            const int rh = a.hit.geomID != RTK_INVALID_GEOMETRY_ID, eh = e.hit.geomID != RTC_INVALID_GEOMETRY_ID;
            const rtk_hit eh_as = {.u = e.hit.u, .v = e.hit.v};
            if ((rh && near_edge(&a.hit)) || (eh && near_edge(&eh_as))) {
                excused++;
                continue;
            }
            if (rh != eh)
                fail_msg("%s ray %zu: rtk %s, Embree %s", names[b], i, rh ? "hits" : "misses", eh ? "hits" : "misses");
            if (!rh)
                continue;
            hits++;
            if (a.hit.primID != e.hit.primID || fabsf(a.ray.tfar - e.ray.tfar) > 1e-5f * e.ray.tfar ||
                fabsf(a.hit.u - e.hit.u) > 1e-4f || fabsf(a.hit.v - e.hit.v) > 1e-4f)
                fail_msg("%s ray %zu: rtk quad %u t %.9g u, v %.6f %.6f; Embree quad %u t %.9g u, v %.6f %.6f",
                         names[b], i, a.hit.primID, a.ray.tfar, a.hit.u, a.hit.v, e.hit.primID, e.ray.tfar, e.hit.u,
                         e.hit.v);
        }
        /* the rays at corners and edges are a third: the rest must decide */
        assert_true(hits > RAYS / 4);
        assert_true(excused < RAYS / 2);
        print_message("%s: %zu quad hits as Embree's, %zu rays at an edge of a half not compared\n", names[b], hits,
                      excused);
        rtk_scene_release(qs);
        rtk_device_release(dev);
    }
    rtcReleaseScene(es);
    rtcReleaseDevice(edev);
    free(rays);
    qmesh_free(&m);
}
#endif

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_errors),
        cmocka_unit_test(test_every_backend_and_layout),
        cmocka_unit_test(test_filters_and_masks),
        cmocka_unit_test(test_instances_motion_refit_trees),
#ifdef RTK_HAVE_EMBREE
        cmocka_unit_test(test_versus_embree),
#endif
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
