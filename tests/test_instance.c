/*
 * Instances: scenes placed in other scenes by affine transforms, checked
 * against a reference that transforms the triangles explicitly (in double
 * precision) and intersects the world-space rays with them by brute force.
 * Transforms with rotation, shear, large and small scale and large
 * translation; nested instances (an instance of a scene of instances) with
 * the outermost instID; a scene's own triangles beside its instances; every
 * backend, single rays and packets; the snapshot semantics (an instanced
 * scene committed again or released) and the errors.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "testlib.h"

/* ---- a small procedural mesh (test_ball: 2 * R * R triangles) and a floor ---- */
#define R 24
typedef test_mesh mesh;
static mesh ball, slab;

/* two big triangles: a floor */
static void make_slab(mesh *m)
{
    static const float v[] = {-30, -3, -30, 30, -3, -30, 30, -3, 30, -30, -3, 30};
    static const uint32_t idx[] = {0, 1, 2, 0, 2, 3};
    m->nv = 4;
    m->nt = 2;
    m->v = malloc(sizeof v);
    m->idx = malloc(sizeof idx);
    memcpy(m->v, v, sizeof v);
    memcpy(m->idx, idx, sizeof idx);
}

static int setup(void **state)
{
    (void)state;
    ball = test_ball(R);
    make_slab(&slab);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    free(ball.v);
    free(ball.idx);
    free(slab.v);
    free(slab.idx);
    return 0;
}

/* ---- transforms (row-major 3x4, object -> world) ---- */

static void xfm_mul(const double *a, const double *b, double *out) /* out = a * b */
{
    double r[12];
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 4; j++)
            r[4 * i + j] = a[4 * i] * b[j] + a[4 * i + 1] * b[4 + j] + a[4 * i + 2] * b[8 + j];
        r[4 * i + 3] += a[4 * i + 3];
    }
    memcpy(out, r, sizeof r);
}

static void xfm_apply(const double *m, const double p[3], double out[3])
{
    for (int i = 0; i < 3; i++)
        out[i] = m[4 * i] * p[0] + m[4 * i + 1] * p[1] + m[4 * i + 2] * p[2] + m[4 * i + 3];
}

/* rotation about an axis by a, scale s (per axis), shear, then translation */
static void xfm_make(double *m, double ax, double ay, double az, double a, const double s[3], double shear,
                     const double t[3])
{
    const double n = sqrt(ax * ax + ay * ay + az * az);
    ax /= n, ay /= n, az /= n;
    const double c = cos(a), si = sin(a), C = 1 - c;
    const double rot[12] = {c + ax * ax * C,      ax * ay * C - az * si, ax * az * C + ay * si, 0,
                            ay * ax * C + az * si, c + ay * ay * C,      ay * az * C - ax * si, 0,
                            az * ax * C - ay * si, az * ay * C + ax * si, c + az * az * C,      0};
    const double sc[12] = {s[0], shear, 0, 0, 0, s[1], 0, 0, 0, 0, s[2], 0};
    xfm_mul(rot, sc, m);
    m[3] += t[0], m[7] += t[1], m[11] += t[2];
}

static void xfm_to_float(const double *m, float *f)
{
    for (int i = 0; i < 12; i++)
        f[i] = (float)m[i];
}

static void xfm_from_float(const float *f, double *m)
{
    for (int i = 0; i < 12; i++)
        m[i] = f[i];
}

/* ---- the reference: every triangle placed in world space (testlib.h) ---- */

static void ref_add_mesh(placed_ref *r, const mesh *m, const double *xfm, uint32_t inst, uint32_t geom)
{
    for (size_t k = 0; k < m->nt; k++) {
        placed *p = placed_add(r);
        double o[3][3];
        for (int c = 0; c < 3; c++) {
            const float *v = m->v + 3 * m->idx[3 * k + c];
            for (int d = 0; d < 3; d++)
                o[c][d] = v[d];
            xfm_apply(xfm, o[c], p->v[c]);
        }
        placed_normal(p, o);
        p->inst = inst;
        p->geom = geom;
        p->prim = (uint32_t)k;
    }
}

/* Rays at the scene from outside its box, towards points inside it.  A
 * disagreement with the reference is allowed only where a rounding could
 * explain it: the hit lies within `tol` (barycentric) of an edge, or two
 * triangles' distances tie within tol.  Counts those in *excused. */
static void check_rays(rtk_scene s, const placed_ref *r, int nrays, uint32_t seed, double tol, int *hits, int *excused)
{
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
    rng g = {seed};
    for (int i = 0; i < nrays; i++) {
        float o[3], d[3];
        for (int k = 0; k < 3; k++) {
            const float lo = info.bounds_lower[k], hi = info.bounds_upper[k], ext = hi - lo;
            o[k] = lo - 0.5f * ext + 2.0f * ext * rng_float(&g);
            d[k] = lo + ext * rng_float(&g) - o[k];
        }
        const rtk_ray ray = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY);
        check_ray_placed(s, r, ray, i, tol, hits, excused);
    }
}

/* ---- scenes ---- */

static rtk_geometry instance_of(rtk_device dev, rtk_scene child, const double *xfm)
{
    rtk_geometry g = NULL;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_instanced_scene(g, child), RTK_OK);
    float f[12];
    xfm_to_float(xfm, f);
    assert_int_equal(rtk_geometry_set_transform(g, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, f), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    return g;
}

static uint32_t attach(rtk_scene s, rtk_geometry g)
{
    uint32_t id;
    assert_int_equal(rtk_scene_attach_geometry(s, g, &id), RTK_OK);
    rtk_geometry_release(g);
    return id;
}

static uint32_t attach_mesh(rtk_device dev, rtk_scene s, const mesh *m)
{
    rtk_geometry g = NULL;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, m->v, 0, 12, m->nv), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, m->idx, 0, 12, m->nt), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    return attach(s, g);
}

#define NX 6
static void transforms(double xf[NX][12])
{
    static const double one[3] = {1, 1, 1}, zero[3] = {0, 0, 0};
    xfm_make(xf[0], 0, 1, 0, 0.0, one, 0.0, (const double[3]){3, 0, 0});                  /* translation */
    xfm_make(xf[1], 1, 1, 0, 0.7, one, 0.0, (const double[3]){-3, 0.5, 0});               /* rotation */
    xfm_make(xf[2], 0, 0, 1, 0.3, (const double[3]){2.5, 0.4, 1.3}, 0.8, (const double[3]){0, 3, -1}); /* shear */
    xfm_make(xf[3], 1, 0, 0, 2.0, (const double[3]){1e-3, 1e-3, 1e-3}, 0.0, (const double[3]){0, -2, 2}); /* tiny */
    xfm_make(xf[4], 0, 1, 1, -1.1, (const double[3]){8, 8, 8}, 0.0, zero);                /* large */
    xfm_make(xf[5], 0, 1, 0, 3.0, (const double[3]){-1, 1, 1}, 0.0, (const double[3]){0, 0, 5}); /* mirror */
}

/* A scene of NX instances of the ball (and, with own, the slab beside
 * them), against the reference, on every backend. */
static void instances_vs_reference(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    double xf[NX][12];
    transforms(xf);
    for (size_t b = 0; b < nb; b++)
        for (int own = 0; own < 2; own++) {
            rtk_device dev = test_device(names[b]);
            rtk_scene child = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
            rtk_scene top = NULL;
            assert_int_equal(rtk_scene_new(dev, &top), RTK_OK);
            placed_ref ref = {0};
            const double identity[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
            if (own) {
                const uint32_t id = attach_mesh(dev, top, &slab);
                ref_add_mesh(&ref, &slab, identity, RTK_INVALID_GEOMETRY_ID, id);
            }
            for (int k = 0; k < NX; k++) {
                const uint32_t id = attach(top, instance_of(dev, child, xf[k]));
                /* the reference takes the transform as rtk has it: in floats */
                float f[12];
                double back[12];
                xfm_to_float(xf[k], f);
                xfm_from_float(f, back);
                ref_add_mesh(&ref, &ball, back, id, 0);
            }
            assert_int_equal(rtk_scene_commit(top), RTK_OK);
            rtk_scene_info info = {.struct_size = sizeof info};
            assert_int_equal(rtk_scene_get_info(top, &info), RTK_OK);
            assert_int_equal(info.instances, NX);
            assert_string_equal(info.layout, "bvh4.object");
            assert_int_equal(info.triangles, own ? slab.nt : 0);
            /* the child may go: the top level holds its tree */
            rtk_scene_release(child);
            int hits = 0, excused = 0;
            check_rays(top, &ref, 3000, 11 + (uint32_t)b, 1e-4, &hits, &excused);
            assert_true(hits > 600);
            assert_true(excused < 30);
            /* packets agree with single rays (the core traces them ray by ray here) */
            rng g = {5};
            for (int i = 0; i < 64; i++) {
                rtk_rayhit16 p16;
                memset(&p16, 0, sizeof p16);
                int valid[16];
                rtk_rayhit single[16];
                for (int l = 0; l < 16; l++) {
                    valid[l] = -1;
                    float o[3], d[3];
                    for (int k = 0; k < 3; k++) {
                        o[k] = -20.0f + 40.0f * rng_float(&g);
                        d[k] = 4.0f * rng_float(&g) - 2.0f - o[k];
                    }
                    single[l] = (rtk_rayhit){.ray = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY)};
                    single[l].hit.geomID = RTK_INVALID_GEOMETRY_ID;
                    p16.ray.org_x[l] = o[0], p16.ray.org_y[l] = o[1], p16.ray.org_z[l] = o[2];
                    p16.ray.dir_x[l] = d[0], p16.ray.dir_y[l] = d[1], p16.ray.dir_z[l] = d[2];
                    p16.ray.tnear[l] = 0.0f, p16.ray.tfar[l] = INFINITY, p16.ray.mask[l] = ~0u;
                    p16.hit.geomID[l] = RTK_INVALID_GEOMETRY_ID;
                    assert_int_equal(rtk_intersect1(top, &single[l]), RTK_OK);
                }
                assert_int_equal(rtk_intersect16(top, valid, &p16), RTK_OK);
                for (int l = 0; l < 16; l++) {
                    assert_int_equal(p16.hit.geomID[l], single[l].hit.geomID);
                    assert_int_equal(p16.hit.instID[l], single[l].hit.instID);
                    assert_int_equal(p16.hit.primID[l], single[l].hit.primID);
                    assert_true(p16.ray.tfar[l] == single[l].ray.tfar);
                }
            }
            free(ref.t);
            rtk_scene_release(top);
            rtk_device_release(dev);
        }
}

/* A -> B -> ball: B holds two instances of the ball, A two of B and the
 * slab; hits report A's instance (the outermost) and the ball's triangle. */
static void nested_instances(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    double xf[NX][12];
    transforms(xf);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene c = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
        rtk_scene mid = NULL, top = NULL;
        assert_int_equal(rtk_scene_new(dev, &mid), RTK_OK);
        assert_int_equal(rtk_scene_new(dev, &top), RTK_OK);
        attach(mid, instance_of(dev, c, xf[0]));
        attach(mid, instance_of(dev, c, xf[2]));
        assert_int_equal(rtk_scene_commit(mid), RTK_OK);
        placed_ref ref = {0};
        const double identity[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
        const uint32_t slab_id = attach_mesh(dev, top, &slab);
        ref_add_mesh(&ref, &slab, identity, RTK_INVALID_GEOMETRY_ID, slab_id);
        const int outer[2] = {1, 5}, inner[2] = {0, 2};
        for (int a = 0; a < 2; a++) {
            const uint32_t id = attach(top, instance_of(dev, mid, xf[outer[a]]));
            for (int m = 0; m < 2; m++) {
                float fo[12], fi[12];
                double o[12], in[12], both[12];
                xfm_to_float(xf[outer[a]], fo);
                xfm_to_float(xf[inner[m]], fi);
                xfm_from_float(fo, o);
                xfm_from_float(fi, in);
                xfm_mul(o, in, both);
                ref_add_mesh(&ref, &ball, both, id, 0);
            }
        }
        assert_int_equal(rtk_scene_commit(top), RTK_OK);
        int hits = 0, excused = 0;
        check_rays(top, &ref, 3000, 77 + (uint32_t)b, 1e-4, &hits, &excused);
        assert_true(hits > 600);
        assert_true(excused < 30);
        free(ref.t);
        rtk_scene_release(top);
        rtk_scene_release(mid);
        rtk_scene_release(c);
        rtk_device_release(dev);
    }
}

static int ball_hit(rtk_scene s, float x)
{
    rtk_rayhit rh = {.ray = test_ray(x, 0, -10, 0, 0, 1, 0, INFINITY)};
    rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
    assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
    return rh.hit.geomID != RTK_INVALID_GEOMETRY_ID;
}

/* The top level keeps the tree it was committed with: the instanced scene
 * changed and committed again shows only after the top level's commit. */
static void snapshot_until_commit(void **state)
{
    (void)state;
    rtk_device dev = test_device("scalar");
    float *v = malloc(ball.nv * 3 * sizeof *v);
    memcpy(v, ball.v, ball.nv * 3 * sizeof *v);
    rtk_scene child = test_scene(dev, v, ball.nv, ball.idx, ball.nt);
    rtk_scene top = NULL;
    assert_int_equal(rtk_scene_new(dev, &top), RTK_OK);
    const double ident[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    attach(top, instance_of(dev, child, ident));
    assert_int_equal(rtk_scene_commit(top), RTK_OK);
    assert_true(ball_hit(top, 0.0f));
    assert_false(ball_hit(top, 5.0f));
    /* the child's mesh moves 5 along x */
    for (size_t i = 0; i < ball.nv; i++)
        v[3 * i] += 5.0f;
    rtk_geometry g = rtk_scene_get_geometry(child, 0);
    assert_int_equal(rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_VERTEX), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_commit(child), RTK_OK);
    assert_true(ball_hit(child, 5.0f));
    /* the top level still traces the tree it was committed with */
    assert_true(ball_hit(top, 0.0f));
    assert_false(ball_hit(top, 5.0f));
    assert_int_equal(rtk_scene_commit(top), RTK_OK);
    assert_true(ball_hit(top, 5.0f));
    assert_false(ball_hit(top, 0.0f));
    rtk_scene_release(top);
    rtk_scene_release(child);
    rtk_device_release(dev);
    free(v);
}

static void instance_errors(void **state)
{
    (void)state;
    rtk_device dev = test_device("scalar"), other = test_device("scalar");
    rtk_scene child = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt), foreign = NULL, fresh = NULL;
    assert_int_equal(rtk_scene_new(other, &foreign), RTK_OK);
    assert_int_equal(rtk_scene_new(dev, &fresh), RTK_OK);
    rtk_geometry inst = NULL, tri = NULL;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &inst), RTK_OK);
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &tri), RTK_OK);
    const float xf[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    /* what is not an instance, and buffers on an instance */
    assert_int_equal(rtk_geometry_set_instanced_scene(tri, child), RTK_ERROR_INVALID_OPERATION);
    assert_int_equal(rtk_geometry_set_transform(tri, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, xf), RTK_ERROR_INVALID_OPERATION);
    assert_int_equal(rtk_geometry_set_shared_buffer(inst, RTK_BUFFER_TYPE_VERTEX, ball.v, 0, 12, ball.nv),
                     RTK_ERROR_INVALID_OPERATION);
    /* no scene yet; another device's scene */
    assert_int_equal(rtk_geometry_commit(inst), RTK_ERROR_INVALID_OPERATION);
    assert_int_equal(rtk_geometry_set_instanced_scene(inst, foreign), RTK_ERROR_INVALID_ARGUMENT);
    /* bad transforms */
    const float nan_xf[12] = {1, 0, 0, NAN, 0, 1, 0, 0, 0, 0, 1, 0};
    const float flat[12] = {1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0};
    assert_int_equal(rtk_geometry_set_transform(inst, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, nan_xf),
                     RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_geometry_set_transform(inst, (rtk_format)99, xf), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_geometry_set_transform(inst, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, NULL),
                     RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_geometry_set_instanced_scene(inst, fresh), RTK_OK);
    assert_int_equal(rtk_geometry_set_transform(inst, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, flat), RTK_OK);
    assert_int_equal(rtk_geometry_commit(inst), RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "singular"));
    /* an instance of a scene never committed */
    assert_int_equal(rtk_geometry_set_transform(inst, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, xf), RTK_OK);
    assert_int_equal(rtk_geometry_commit(inst), RTK_OK);
    rtk_scene top = NULL;
    assert_int_equal(rtk_scene_new(dev, &top), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(top, inst, NULL), RTK_OK);
    assert_int_equal(rtk_scene_commit(top), RTK_ERROR_INVALID_OPERATION);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "never committed"));
    /* an empty scene instanced: never hit; the formats agree */
    assert_int_equal(rtk_scene_commit(fresh), RTK_OK);
    assert_int_equal(rtk_scene_commit(top), RTK_OK);
    assert_false(ball_hit(top, 0.0f));
    const float cm[12] = {1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0}, m4[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    assert_int_equal(rtk_geometry_set_transform(inst, RTK_FORMAT_FLOAT3X4_COLUMN_MAJOR, cm), RTK_OK);
    assert_int_equal(rtk_geometry_set_transform(inst, RTK_FORMAT_FLOAT4X4_COLUMN_MAJOR, m4), RTK_OK);
    /* cycles of instances are refused when they would form (their
     * references would never be freed; fuzz_api found the leak): top
     * places fresh through inst */
    {
        rtk_geometry self = NULL, deep = NULL;
        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &self), RTK_OK);
        assert_int_equal(rtk_geometry_set_instanced_scene(self, top), RTK_OK);
        assert_int_equal(rtk_geometry_commit(self), RTK_OK);
        assert_int_equal(rtk_scene_attach_geometry(top, self, NULL), RTK_ERROR_INVALID_OPERATION);
        assert_non_null(strstr(rtk_device_get_error_message(dev), "cycle"));
        assert_int_equal(rtk_scene_attach_geometry(fresh, self, NULL), RTK_ERROR_INVALID_OPERATION); /* via inst */
        /* the other order: attached first, then pointed at a scene that holds it */
        assert_int_equal(rtk_geometry_set_instanced_scene(inst, top), RTK_ERROR_INVALID_OPERATION);
        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &deep), RTK_OK);
        assert_int_equal(rtk_geometry_set_instanced_scene(deep, child), RTK_OK);
        assert_int_equal(rtk_scene_attach_geometry(fresh, deep, NULL), RTK_OK);
        assert_int_equal(rtk_geometry_set_instanced_scene(deep, top), RTK_ERROR_INVALID_OPERATION);
        /* not a cycle: an instance attached twice, once detached */
        uint32_t id = 0;
        assert_int_equal(rtk_scene_attach_geometry(top, inst, &id), RTK_OK);
        assert_int_equal(rtk_scene_detach_geometry(top, id), RTK_OK);
        assert_int_equal(rtk_scene_detach_geometry(fresh, 0), RTK_OK);
        assert_int_equal(rtk_geometry_set_instanced_scene(deep, top), RTK_OK); /* fresh no longer holds it */
        rtk_geometry_release(self);
        rtk_geometry_release(deep);
        assert_int_equal(rtk_scene_commit(fresh), RTK_OK);
    }
    /* nesting deeper than RTK_MAX_INSTANCE_DEPTH */
    rtk_scene level = child;
    rtk_scene_retain(level);
    rtk_error last = RTK_OK;
    for (int d = 0; d <= RTK_MAX_INSTANCE_DEPTH && last == RTK_OK; d++) {
        rtk_scene up = NULL;
        assert_int_equal(rtk_scene_new(dev, &up), RTK_OK);
        attach(up, instance_of(dev, level, (const double[12]){1, 0, 0, 0.1, 0, 1, 0, 0, 0, 0, 1, 0}));
        last = rtk_scene_commit(up);
        rtk_scene_release(level);
        level = up;
        if (last == RTK_OK)
            assert_true(ball_hit(level, 0.0f));
        else
            assert_int_equal(d, RTK_MAX_INSTANCE_DEPTH);
    }
    assert_int_equal(last, RTK_ERROR_INVALID_OPERATION);
    rtk_scene_release(level);
    /* a tree cannot be loaded into a scene with instances */
    rtk_bvh bvh = {.struct_size = sizeof bvh};
    assert_int_equal(rtk_scene_get_bvh(child, &bvh), RTK_OK);
    assert_int_equal(rtk_scene_commit_bvh(top, &bvh), RTK_ERROR_INVALID_OPERATION);
    assert_int_equal(rtk_scene_get_bvh(top, &bvh), RTK_ERROR_INVALID_OPERATION); /* (bvh stays the child's) */
    rtk_bvh_free(&bvh);
    rtk_geometry_release(inst);
    rtk_geometry_release(tri);
    rtk_scene_release(top);
    rtk_scene_release(fresh);
    rtk_scene_release(foreign);
    rtk_scene_release(child);
    rtk_device_release(other);
    rtk_device_release(dev);
}

/* ---- dynamic scenes: a tree per geometry, rebuilt only where it changed ---- */

typedef struct moving {
    float *v; /* the ball moved to (x, 0, 0) */
    mesh m;
} moving;

static void place_ball(moving *b, float x, float twist)
{
    for (size_t i = 0; i < ball.nv; i++) {
        const float *p = ball.v + 3 * i;
        const float a = twist * p[1];
        b->v[3 * i] = x + cosf(a) * p[0] - sinf(a) * p[2];
        b->v[3 * i + 1] = p[1];
        b->v[3 * i + 2] = sinf(a) * p[0] + cosf(a) * p[2];
    }
}

/* The reference of a dynamic scene: every geometry as it is now. */
static placed_ref dynamic_reference(const moving *balls, const uint32_t *ids, int nballs, uint32_t slab_id)
{
    placed_ref ref = {0};
    const double identity[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    ref_add_mesh(&ref, &slab, identity, RTK_INVALID_GEOMETRY_ID, slab_id);
    for (int k = 0; k < nballs; k++)
        ref_add_mesh(&ref, &balls[k].m, identity, RTK_INVALID_GEOMETRY_ID, ids[k]);
    return ref;
}

static void check_dynamic(rtk_scene s, const moving *balls, const uint32_t *ids, int nballs, uint32_t slab_id,
                          uint32_t seed)
{
    placed_ref ref = dynamic_reference(balls, ids, nballs, slab_id);
    int hits = 0, excused = 0;
    check_rays(s, &ref, 1500, seed, 1e-4, &hits, &excused);
    assert_true(hits > 300);
    assert_true(excused < 15);
    free(ref.t);
}

static void expect_trees(rtk_scene s, uint32_t built, uint32_t refitted)
{
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
    if (info.trees_built != built || info.refits != refitted)
        fail_msg("the commit built %u trees and refitted %u; expected %u and %u", info.trees_built, info.refits, built,
                 refitted);
    assert_string_equal(info.layout, "bvh4.object");
    assert_int_equal(info.flags_not_honoured & RTK_SCENE_FLAG_DYNAMIC, 0);
}

/* A dynamic scene (compact or not) of the slab and n balls, ball k at
 * (x0 + k dx, 0, 0) with quality q[k]; not committed.  The slab's id in
 * *slab_id. */
static rtk_scene dynamic_balls(rtk_device dev, int compact, int n, const rtk_build_quality *q, float x0, float dx,
                               moving *balls, uint32_t *ids, rtk_geometry *geo, uint32_t *slab_id)
{
    rtk_scene s = NULL;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    assert_int_equal(rtk_scene_set_flags(s, RTK_SCENE_FLAG_DYNAMIC | (compact ? RTK_SCENE_FLAG_COMPACT : 0)), RTK_OK);
    *slab_id = attach_mesh(dev, s, &slab);
    for (int k = 0; k < n; k++) {
        balls[k].v = malloc(ball.nv * 3 * sizeof(float));
        balls[k].m = (mesh){balls[k].v, ball.idx, ball.nv, ball.nt};
        place_ball(&balls[k], x0 + dx * (float)k, 0.0f);
        ids[k] = attach_mesh(dev, s, &balls[k].m);
        geo[k] = rtk_scene_get_geometry(s, ids[k]);
        assert_int_equal(rtk_geometry_set_build_quality(geo[k], q[k]), RTK_OK);
    }
    return s;
}

/* Three balls (low, medium and REFIT quality) and the slab in a dynamic
 * scene, on every backend and in both layouts: each commit builds only the
 * trees of the geometries that changed, refits the REFIT one when only its
 * vertices moved, and the hits always match the reference. */
static void dynamic_scene(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    static const rtk_build_quality q[3] = {RTK_BUILD_QUALITY_LOW, RTK_BUILD_QUALITY_MEDIUM, RTK_BUILD_QUALITY_REFIT};
    for (size_t b = 0; b < nb; b++)
        for (int compact = 0; compact < 2; compact++) {
            rtk_device dev = test_device(names[b]);
            moving balls[3];
            uint32_t ids[3], slab_id;
            rtk_geometry geo[3];
            rtk_scene s = dynamic_balls(dev, compact, 3, q, -3.0f, 3.0f, balls, ids, geo, &slab_id);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            expect_trees(s, 4, 0);
            check_dynamic(s, balls, ids, 3, slab_id, 1);
            rtk_scene_info info = {.struct_size = sizeof info};
            assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
            /* each ball has R zero-area triangles at its north pole; the
             * REFIT one keeps its own in the tree (rtk_scene_info) */
            assert_int_equal(info.triangles_degenerate, 3 * R);
            assert_int_equal(info.triangles, slab.nt + 3 * ball.nt - 2 * R);
            assert_int_equal(info.flags_not_honoured, 0);

            /* nothing changed: nothing built */
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            expect_trees(s, 0, 0);
            /* the REFIT ball twists: refitted, the others kept */
            for (int frame = 1; frame <= 3; frame++) {
                place_ball(&balls[2], 3.0f, 0.3f * (float)frame);
                assert_int_equal(rtk_geometry_update_buffer(geo[2], RTK_BUFFER_TYPE_VERTEX), RTK_OK);
                assert_int_equal(rtk_geometry_commit(geo[2]), RTK_OK);
                assert_int_equal(rtk_scene_commit(s), RTK_OK);
                expect_trees(s, 0, 1);
                check_dynamic(s, balls, ids, 3, slab_id, 10 + (uint32_t)frame);
            }
            /* the low-quality ball moves: rebuilt alone */
            place_ball(&balls[0], -4.0f, 0.5f);
            assert_int_equal(rtk_geometry_update_buffer(geo[0], RTK_BUFFER_TYPE_VERTEX), RTK_OK);
            assert_int_equal(rtk_geometry_commit(geo[0]), RTK_OK);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            expect_trees(s, 1, 0);
            check_dynamic(s, balls, ids, 3, slab_id, 20);
            /* disabled, then enabled again: nothing built either time */
            assert_int_equal(rtk_geometry_disable(geo[1]), RTK_OK);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            expect_trees(s, 0, 0);
            check_dynamic(s, (const moving[2]){balls[0], balls[2]}, (const uint32_t[2]){ids[0], ids[2]}, 2, slab_id, 21);
            assert_int_equal(rtk_geometry_enable(geo[1]), RTK_OK);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
            assert_int_equal(info.trees_built, 1); /* the disabled geometry's tree was let go */
            check_dynamic(s, balls, ids, 3, slab_id, 22);
            /* an index out of range in a changed geometry is refused */
            uint32_t *bad = malloc(ball.nt * 3 * sizeof *bad);
            memcpy(bad, ball.idx, ball.nt * 3 * sizeof *bad);
            bad[7] = (uint32_t)ball.nv;
            assert_int_equal(rtk_geometry_set_shared_buffer(geo[1], RTK_BUFFER_TYPE_INDEX, bad, 0, 12, ball.nt),
                             RTK_OK);
            assert_int_equal(rtk_geometry_commit(geo[1]), RTK_OK);
            assert_int_equal(rtk_scene_commit(s), RTK_ERROR_INVALID_GEOMETRY);
            assert_int_equal(rtk_geometry_set_shared_buffer(geo[1], RTK_BUFFER_TYPE_INDEX, ball.idx, 0, 12, ball.nt),
                             RTK_OK);
            assert_int_equal(rtk_geometry_commit(geo[1]), RTK_OK);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            expect_trees(s, 1, 0);
            check_dynamic(s, balls, ids, 3, slab_id, 23);
            /* an instance of this scene holds its tree: the next twist
             * builds the REFIT ball afresh instead of refitting a tree the
             * instance still traces */
            rtk_scene top = NULL;
            assert_int_equal(rtk_scene_new(dev, &top), RTK_OK);
            const double ident[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
            attach(top, instance_of(dev, s, ident));
            assert_int_equal(rtk_scene_commit(top), RTK_OK);
            place_ball(&balls[2], 3.0f, 1.5f);
            assert_int_equal(rtk_geometry_update_buffer(geo[2], RTK_BUFFER_TYPE_VERTEX), RTK_OK);
            assert_int_equal(rtk_geometry_commit(geo[2]), RTK_OK);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            expect_trees(s, 1, 0);
            check_dynamic(s, balls, ids, 3, slab_id, 24);
            rtk_scene_release(top);
            rtk_scene_release(s);
            free(bad);
            for (int k = 0; k < 3; k++)
                free(balls[k].v);
            rtk_device_release(dev);
        }
}

/* ---- a dynamic scene's top level refitted ---- */

static uint32_t top_refits(rtk_scene s)
{
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
    return info.top_level_refits;
}

/* Against the reference: the two balls, the slab and the ball instanced
 * by xfm as inst_id. */
static void check_with_instance(rtk_scene s, const moving *balls, const uint32_t *ids, uint32_t slab_id,
                                const double *xfm, uint32_t inst_id, uint32_t seed)
{
    placed_ref ref = dynamic_reference(balls, ids, 2, slab_id);
    ref_add_mesh(&ref, &ball, xfm, inst_id, 0);
    int hits = 0, excused = 0;
    check_rays(s, &ref, 1500, seed, 1e-4, &hits, &excused);
    assert_true(hits > 300);
    assert_true(excused < 15);
    free(ref.t);
}

/* The ball at (x, 0, 0), its geometry committed. */
static void move_ball(moving *b, rtk_geometry g, float x)
{
    place_ball(b, x, 0.0f);
    assert_int_equal(rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_VERTEX), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
}

/* The slab, two balls (one REFIT) and an instance of a third in a dynamic
 * scene, on every backend and in both layouts: a commit that only refits
 * the REFIT ball refits the top level too (the balls' trees are opened
 * into it, so its items start inside them), and its hits match the
 * reference; a move that grows the top level's SAH cost past 1.1 times its
 * build's, a new transform, a disabled geometry and a scene that instances
 * this one each have the top level built afresh. */
static void dynamic_top_level_refit(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    double xf[NX][12];
    transforms(xf);
    for (size_t b = 0; b < nb; b++)
        for (int compact = 0; compact < 2; compact++) {
            rtk_device dev = test_device(names[b]);
            rtk_scene child = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
            static const rtk_build_quality q[2] = {RTK_BUILD_QUALITY_MEDIUM, RTK_BUILD_QUALITY_REFIT};
            moving balls[2];
            uint32_t ids[2], slab_id;
            rtk_geometry geo[2];
            rtk_scene s = dynamic_balls(dev, compact, 2, q, -1.0f, 2.5f, balls, ids, geo, &slab_id);
            rtk_geometry inst = instance_of(dev, child, xf[0]);
            const uint32_t inst_id = attach(s, inst);
            float x = 1.5f;
            const double *place = xf[0];
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            assert_int_equal(top_refits(s), 0);
            check_with_instance(s, balls, ids, slab_id, place, inst_id, 1);
            /* small moves: the REFIT ball's tree and the top level refitted */
            for (int frame = 1; frame <= 3; frame++) {
                x += 0.01f;
                move_ball(&balls[1], geo[1], x);
                assert_int_equal(rtk_scene_commit(s), RTK_OK);
                expect_trees(s, 0, 1);
                assert_int_equal(top_refits(s), frame);
                check_with_instance(s, balls, ids, slab_id, place, inst_id, 10 + (uint32_t)frame);
            }
            /* scrambled and stretched (each vertex takes another's x,
             * eight times as far out): the items opened from the ball's
             * tree overlap across the slab, and the top level's SAH cost
             * grows past 1.1 times its build's: built afresh */
            for (size_t i = 0; i < ball.nv; i++)
                balls[1].v[3 * i] = x + 8.0f * ball.v[3 * ((i * 7919) % ball.nv)];
            assert_int_equal(rtk_geometry_update_buffer(geo[1], RTK_BUFFER_TYPE_VERTEX), RTK_OK);
            assert_int_equal(rtk_geometry_commit(geo[1]), RTK_OK);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            expect_trees(s, 0, 1);
            assert_int_equal(top_refits(s), 0);
            check_with_instance(s, balls, ids, slab_id, place, inst_id, 20);
            x -= 0.02f;
            move_ball(&balls[1], geo[1], x);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            assert_int_equal(top_refits(s), 1);
            check_with_instance(s, balls, ids, slab_id, place, inst_id, 21);
            /* the instance moves: the top level built afresh, no tree */
            float f[12];
            xfm_to_float(xf[1], f);
            place = xf[1];
            assert_int_equal(rtk_geometry_set_transform(inst, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, f), RTK_OK);
            assert_int_equal(rtk_geometry_commit(inst), RTK_OK);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            expect_trees(s, 0, 0);
            assert_int_equal(top_refits(s), 0);
            check_with_instance(s, balls, ids, slab_id, place, inst_id, 30);
            /* the other ball disabled, with the REFIT one moved: built afresh */
            assert_int_equal(rtk_geometry_disable(geo[0]), RTK_OK);
            x += 0.01f;
            move_ball(&balls[1], geo[1], x);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            assert_int_equal(top_refits(s), 0);
            assert_int_equal(rtk_geometry_enable(geo[0]), RTK_OK);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            x += 0.01f;
            move_ball(&balls[1], geo[1], x);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            assert_int_equal(top_refits(s), 1);
            check_with_instance(s, balls, ids, slab_id, place, inst_id, 40);
            /* a scene instancing this one holds its top level: built afresh */
            rtk_scene top = NULL;
            assert_int_equal(rtk_scene_new(dev, &top), RTK_OK);
            const double ident[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
            attach(top, instance_of(dev, s, ident));
            assert_int_equal(rtk_scene_commit(top), RTK_OK);
            x += 0.01f;
            move_ball(&balls[1], geo[1], x);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            assert_int_equal(top_refits(s), 0);
            check_with_instance(s, balls, ids, slab_id, place, inst_id, 50);
            rtk_scene_release(top);
            rtk_scene_release(s);
            rtk_scene_release(child);
            for (int k = 0; k < 2; k++)
                free(balls[k].v);
            rtk_device_release(dev);
        }
}

/* A dynamic scene without REFIT geometry keeps nothing for a refit: its
 * top level is built at every commit. */
static void dynamic_top_level_built(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    rtk_device dev = test_device(names[nb - 1]);
    rtk_scene s = NULL;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    assert_int_equal(rtk_scene_set_flags(s, RTK_SCENE_FLAG_DYNAMIC), RTK_OK);
    attach_mesh(dev, s, &slab);
    attach_mesh(dev, s, &ball);
    for (int c = 0; c < 3; c++) {
        assert_int_equal(rtk_scene_commit(s), RTK_OK);
        assert_int_equal(top_refits(s), 0);
    }
    rtk_scene_release(s);
    rtk_device_release(dev);
}

/* ---- the merged traversal against each object alone ----
 * A top level whose objects are trees of the triangle layouts is walked in
 * one loop with one set-up of the ray (traverse_objects.h); objects of
 * other kinds, and rays that need an object's masks or filters, go through
 * that object's own kernel.  Its answer must be, bit for bit, the nearest
 * of the answers each object gives alone (ties between objects at the same
 * distance may go to either).  Each object alone: the scene with every
 * other geometry disabled (its tree built again, deterministically). */

#define MERGED_PIECES 4
#define MERGED_RAYS 1500

/* rejects hits on odd triangles */
static int odd_filter(const rtk_filter_args *a)
{
    return !(a->hit->primID & 1);
}

#define MERGED_POINTS 300

/* closest points of random points about the ball (with a radius: far
 * points find nothing) */
static void merged_points(rtk_scene s, rtk_point_hit *out)
{
    rng g = {78};
    for (int i = 0; i < MERGED_POINTS; i++) {
        const rtk_point_query pq = {.x = 8.0 * rng_float(&g) - 4.0, .y = 8.0 * rng_float(&g) - 4.0,
                                    .z = 8.0 * rng_float(&g) - 4.0, .radius = 2.5};
        assert_int_equal(rtk_closest_point(s, &pq, &out[i]), RTK_OK);
    }
}

static void merged_trace(rtk_scene s, rtk_rayhit *hits, int *occluded)
{
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
    rng g = {77};
    for (int i = 0; i < MERGED_RAYS; i++) {
        float o[3], d[3];
        for (int k = 0; k < 3; k++) {
            /* the box of every geometry, enabled or not: the same rays each time */
            const float lo = -4.0f, ext = 8.0f;
            o[k] = lo - 0.5f * ext + 2.0f * ext * rng_float(&g);
            d[k] = lo + ext * rng_float(&g) - o[k];
        }
        rtk_ray r = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY);
        r.mask = i % 3 == 0 ? 1u : ~0u; /* a third of the rays miss the masked piece */
        hits[i] = (rtk_rayhit){.ray = r};
        hits[i].hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1(s, &hits[i]), RTK_OK);
        assert_int_equal(rtk_occluded1(s, &r), RTK_OK);
        occluded[i] = r.tfar == -INFINITY;
    }
    (void)info;
}

static int same_hit(const rtk_rayhit *a, const rtk_rayhit *b)
{
    return a->ray.tfar == b->ray.tfar && a->hit.geomID == b->hit.geomID && a->hit.primID == b->hit.primID &&
           a->hit.instID == b->hit.instID && a->hit.u == b->hit.u && a->hit.v == b->hit.v &&
           a->hit.Ng_x == b->hit.Ng_x && a->hit.Ng_y == b->hit.Ng_y && a->hit.Ng_z == b->hit.Ng_z;
}

static void merged_vs_each_object(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    static const unsigned flags[3] = {0, RTK_SCENE_FLAG_COMPACT, RTK_SCENE_FLAG_ROBUST};
    /* the ball's triangles dealt round the pieces: every piece's box is
     * the ball's, and neighbouring triangles (shared edges: ties) lie in
     * different pieces */
    uint32_t *idx[MERGED_PIECES];
    size_t nt[MERGED_PIECES] = {0};
    for (int k = 0; k < MERGED_PIECES; k++)
        idx[k] = malloc(ball.nt * 3 * sizeof(uint32_t));
    for (size_t t = 0; t < ball.nt; t++) {
        const int k = (int)(t % MERGED_PIECES);
        memcpy(idx[k] + 3 * nt[k]++, ball.idx + 3 * t, 3 * sizeof(uint32_t));
    }
    double xf[NX][12];
    transforms(xf);
    rtk_rayhit *all = malloc(MERGED_RAYS * sizeof *all), *alone = malloc(MERGED_RAYS * sizeof *alone);
    int *all_occ = malloc(MERGED_RAYS * sizeof(int)), *alone_occ = malloc(MERGED_RAYS * sizeof(int));
    rtk_rayhit *nearest = malloc(MERGED_RAYS * sizeof *nearest);
    int *any_occ = malloc(MERGED_RAYS * sizeof(int)), *tie_ok = malloc(MERGED_RAYS * sizeof(int));
    for (size_t b = 0; b < nb; b++)
        for (int f = 0; f < 3; f++) {
            rtk_device dev = test_device(names[b]);
            rtk_scene s = NULL;
            assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
            assert_int_equal(rtk_scene_set_flags(s, RTK_SCENE_FLAG_DYNAMIC | flags[f]), RTK_OK);
            rtk_geometry geo[MERGED_PIECES + 4];
            int ng = 0;
            for (int k = 0; k < MERGED_PIECES; k++) {
                rtk_geometry g = NULL;
                assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
                assert_int_equal(
                    rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, ball.v, 0, 12, ball.nv), RTK_OK);
                assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, idx[k], 0, 12, nt[k]),
                                 RTK_OK);
                if (k == 1)
                    assert_int_equal(rtk_geometry_set_mask(g, 2u), RTK_OK);
                if (k == 2) {
                    assert_int_equal(rtk_geometry_set_intersect_filter(g, odd_filter), RTK_OK);
                    assert_int_equal(rtk_geometry_set_occluded_filter(g, odd_filter), RTK_OK);
                }
                assert_int_equal(rtk_geometry_commit(g), RTK_OK);
                geo[ng++] = g;
                attach(s, g);
            }
            /* instances of the ball (translated, sheared), and of a scene
             * of instances (another kind: through its own kernel) */
            rtk_scene child = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
            rtk_scene inner = NULL;
            assert_int_equal(rtk_scene_new(dev, &inner), RTK_OK);
            attach(inner, instance_of(dev, child, xf[1]));
            assert_int_equal(rtk_scene_commit(inner), RTK_OK);
            const double *places[3] = {xf[0], xf[2], xf[5]};
            for (int k = 0; k < 3; k++) {
                rtk_geometry g = instance_of(dev, k == 2 ? inner : child, places[k]);
                geo[ng++] = g;
                attach(s, g);
            }
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            merged_trace(s, all, all_occ);
            rtk_point_hit all_pts[MERGED_POINTS], alone_pts[MERGED_POINTS];
            double nearest_pt[MERGED_POINTS];
            merged_points(s, all_pts);
            for (int i = 0; i < MERGED_POINTS; i++)
                nearest_pt[i] = INFINITY;
            /* packets of 8 give what single rays give (the top level's
             * packets go lane by lane through the merged traversal) */
            for (int i = 0; i + 8 <= MERGED_RAYS; i += 8) {
                rtk_rayhit8 p8;
                memset(&p8, 0, sizeof p8);
                int valid[8];
                for (int l = 0; l < 8; l++) {
                    rtk_rayhit rh = {.ray = all[i + l].ray};
                    rh.ray.tfar = INFINITY;
                    rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
                    valid[l] = -1;
                    test_packet_put(&p8, 8, (unsigned)l, &rh, 0);
                }
                assert_int_equal(rtk_intersect8(s, valid, &p8), RTK_OK);
                for (int l = 0; l < 8; l++) {
                    rtk_rayhit got;
                    test_packet_get(&p8, 8, (unsigned)l, &got, 0);
                    if (!same_hit(&got, &all[i + l]) && !(got.hit.geomID == RTK_INVALID_GEOMETRY_ID &&
                                                          all[i + l].hit.geomID == RTK_INVALID_GEOMETRY_ID))
                        fail_msg("%s, flags %u, ray %d: the packet's answer differs from the single ray's", names[b],
                                 flags[f], i + l);
                }
            }
            for (int i = 0; i < MERGED_RAYS; i++) {
                nearest[i].ray.tfar = INFINITY;
                nearest[i].hit.geomID = RTK_INVALID_GEOMETRY_ID;
                any_occ[i] = 0;
                tie_ok[i] = 0;
            }
            /* each object alone */
            for (int k = 0; k < ng; k++) {
                for (int j = 0; j < ng; j++)
                    assert_int_equal(j == k ? rtk_geometry_enable(geo[j]) : rtk_geometry_disable(geo[j]), RTK_OK);
                assert_int_equal(rtk_scene_commit(s), RTK_OK);
                merged_trace(s, alone, alone_occ);
                merged_points(s, alone_pts);
                for (int i = 0; i < MERGED_POINTS; i++)
                    if (alone_pts[i].distance < nearest_pt[i])
                        nearest_pt[i] = alone_pts[i].distance;
                for (int i = 0; i < MERGED_RAYS; i++) {
                    any_occ[i] |= alone_occ[i];
                    if (alone[i].hit.geomID == RTK_INVALID_GEOMETRY_ID)
                        continue;
                    if (alone[i].ray.tfar < nearest[i].ray.tfar)
                        tie_ok[i] = 0;
                    if (alone[i].ray.tfar <= nearest[i].ray.tfar)
                        nearest[i] = alone[i];
                    /* the merged answer may be any of the objects' at the nearest distance */
                    if (alone[i].ray.tfar == nearest[i].ray.tfar && same_hit(&alone[i], &all[i]))
                        tie_ok[i] = 1;
                }
            }
            int hits = 0, occ = 0;
            for (int i = 0; i < MERGED_RAYS; i++) {
                if (all_occ[i] != any_occ[i])
                    fail_msg("%s, flags %u, ray %d: occluded %d, by the objects alone %d", names[b], flags[f], i,
                             all_occ[i], any_occ[i]);
                if (all[i].hit.geomID != RTK_INVALID_GEOMETRY_ID || nearest[i].hit.geomID != RTK_INVALID_GEOMETRY_ID) {
                    if (!tie_ok[i] || all[i].ray.tfar != nearest[i].ray.tfar)
                        fail_msg("%s, flags %u, ray %d: geom %u prim %u inst %u t %a; alone: geom %u prim %u inst %u t %a",
                                 names[b], flags[f], i, all[i].hit.geomID, all[i].hit.primID, all[i].hit.instID,
                                 all[i].ray.tfar, nearest[i].hit.geomID, nearest[i].hit.primID,
                                 nearest[i].hit.instID, nearest[i].ray.tfar);
                    hits++;
                }
                occ += all_occ[i];
            }
            if (hits <= MERGED_RAYS / 4)
                fail_msg("%d hits of %d rays", hits, MERGED_RAYS);
            assert_true(occ == hits);
            int found = 0;
            for (int i = 0; i < MERGED_POINTS; i++) {
                if (all_pts[i].distance != nearest_pt[i])
                    fail_msg("%s, flags %u, point %d: distance %a, by the objects alone %a", names[b], flags[f], i,
                             all_pts[i].distance, nearest_pt[i]);
                found += all_pts[i].distance < INFINITY;
            }
            assert_true(found > MERGED_POINTS / 3);
            for (int k = 0; k < ng; k++)
                rtk_geometry_enable(geo[k]);
            rtk_scene_release(s);
            rtk_scene_release(inner);
            rtk_scene_release(child);
            rtk_device_release(dev);
        }
    for (int k = 0; k < MERGED_PIECES; k++)
        free(idx[k]);
    free(all);
    free(alone);
    free(all_occ);
    free(alone_occ);
    free(nearest);
    free(any_occ);
    free(tie_ok);
}

/* ---- a large top level ----
 * From 4,096 references on, the top level of a scene whose trees are
 * bvh8.triangle4 (avx2) has 8-wide nodes walked with that layout's node
 * test (objects.c, OBJ_WIDE_REFS; traverse_objects.h); a top level that
 * holds a user primitive keeps 4-wide nodes.  The same 5,000 turned and
 * scaled instances of the ball both ways, every backend: each ray's
 * closest hit and occlusion the same, bit for bit; and closest points in
 * the large top level against each instance's alone (the point taken into
 * the ball's space by hand). */
#define MANY_X 100
#define MANY_Z 50
#define MANY_RAYS 3000

static void far_bounds(const rtk_bounds_args *a)
{
    for (int k = 0; k < 3; k++)
        a->lower[k] = 1e6f, a->upper[k] = 1e6f + 1.0f;
}

static void no_hit(const rtk_user_query_args *a)
{
    (void)a;
}

static rtk_scene many_instances_scene(rtk_device dev, rtk_scene child, int with_user, double (*xf)[13])
{
    rtk_scene s = NULL;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    rng g = {91};
    for (int i = 0; i < MANY_X * MANY_Z; i++) {
        const double sc = 0.5 + 0.5 * rng_float(&g), sv[3] = {sc, sc, sc};
        const double t[3] = {3.0 * (i % MANY_X), 0.0, 3.0 * (i / MANY_X)};
        double m[12];
        xfm_make(m, rng_float(&g) - 0.5, 1.0, rng_float(&g) - 0.5, 6.28 * rng_float(&g), sv, 0.0, t);
        /* (rounded to floats, as the instance holds it) */
        float f[12];
        xfm_to_float(m, f);
        xfm_from_float(f, xf[i]);
        xf[i][12] = sc;
        attach(s, instance_of(dev, child, m));
    }
    if (with_user) {
        rtk_geometry u = test_user_geometry(dev, 1, NULL, far_bounds, no_hit, no_hit);
        assert_int_equal(rtk_geometry_commit(u), RTK_OK);
        attach(s, u);
    }
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    return s;
}

static void many_instances(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    rtk_rayhit *h[2];
    int *occ[2];
    double (*xf)[13] = malloc(MANY_X * MANY_Z * sizeof *xf);
    for (int k = 0; k < 2; k++) {
        h[k] = malloc(MANY_RAYS * sizeof *h[k]);
        occ[k] = malloc(MANY_RAYS * sizeof *occ[k]);
    }
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene child = NULL;
        assert_int_equal(rtk_scene_new(dev, &child), RTK_OK);
        attach_mesh(dev, child, &ball);
        assert_int_equal(rtk_scene_commit(child), RTK_OK);
        rtk_point_hit ph[100];
        rtk_point_query pq[100];
        int hits = 0;
        for (int k = 0; k < 2; k++) {
            rtk_scene s = many_instances_scene(dev, child, k, xf);
            rng g = {92};
            for (int i = 0; i < MANY_RAYS; i++) {
                /* low over the field and nearly level: across many
                 * instances' boxes */
                const float o[3] = {3.0f * MANY_X * rng_float(&g), 0.2f + 1.3f * rng_float(&g),
                                    3.0f * MANY_Z * rng_float(&g)};
                const float d[3] = {rng_float(&g) - 0.5f, -0.1f * rng_float(&g), rng_float(&g) - 0.5f};
                rtk_ray r = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY);
                h[k][i] = (rtk_rayhit){.ray = r};
                h[k][i].hit.geomID = RTK_INVALID_GEOMETRY_ID;
                assert_int_equal(rtk_intersect1(s, &h[k][i]), RTK_OK);
                assert_int_equal(rtk_occluded1(s, &r), RTK_OK);
                occ[k][i] = r.tfar == -INFINITY;
                hits += k == 0 && h[k][i].hit.geomID != RTK_INVALID_GEOMETRY_ID;
            }
            for (int i = 0; k == 0 && i < 100; i++) {
                pq[i] = (rtk_point_query){.x = 3.0 * MANY_X * rng_float(&g), .y = 2.0 * rng_float(&g) - 1.0,
                                          .z = 3.0 * MANY_Z * rng_float(&g), .radius = 4.0};
                assert_int_equal(rtk_closest_point(s, &pq[i], &ph[i]), RTK_OK);
            }
            rtk_scene_release(s);
        }
        /* most rays hit a ball: the comparison means something */
        if (hits <= MANY_RAYS / 2)
            fail_msg("%s: %d of %d rays hit", names[b], hits, MANY_RAYS);
        for (int i = 0; i < MANY_RAYS; i++) {
            if (!same_hit(&h[0][i], &h[1][i]))
                fail_msg("%s: ray %d: %.9g geom %u inst %u (8 wide) against %.9g geom %u inst %u (4 wide)", names[b], i,
                         (double)h[0][i].ray.tfar, h[0][i].hit.geomID, h[0][i].hit.instID, (double)h[1][i].ray.tfar,
                         h[1][i].hit.geomID, h[1][i].hit.instID);
            assert_int_equal(occ[0][i], h[0][i].hit.geomID != RTK_INVALID_GEOMETRY_ID);
            assert_int_equal(occ[1][i], occ[0][i]);
        }
        for (int i = 0; i < 100; i++) {
            /* each instance near enough alone: the point into the ball's
             * space (the transform is a rotation times a uniform scale sc,
             * so its inverse is its transpose over sc^2) */
            double best = INFINITY;
            const double p[3] = {pq[i].x, pq[i].y, pq[i].z};
            for (int j = 0; j < MANY_X * MANY_Z; j++) {
                const double *m = xf[j], sc = xf[j][12];
                const double d[3] = {p[0] - m[3], p[1] - m[7], p[2] - m[11]};
                if (sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) > pq[i].radius + 1.2 * sc)
                    continue;
                rtk_point_query lq = {.radius = pq[i].radius / sc};
                lq.x = (m[0] * d[0] + m[4] * d[1] + m[8] * d[2]) / (sc * sc);
                lq.y = (m[1] * d[0] + m[5] * d[1] + m[9] * d[2]) / (sc * sc);
                lq.z = (m[2] * d[0] + m[6] * d[1] + m[10] * d[2]) / (sc * sc);
                rtk_point_hit lh;
                assert_int_equal(rtk_closest_point(child, &lq, &lh), RTK_OK);
                if (lh.distance * sc < best)
                    best = lh.distance * sc;
            }
            /* (to within the rounding of the instances' float transforms
             * and inverses at coordinates up to 300: a few 1e-5) */
            if (!(isinf(best) ? isinf(ph[i].distance) : fabs(ph[i].distance - best) <= 2e-4))
                fail_msg("%s: point %d: %.9g, each instance alone %.9g", names[b], i, ph[i].distance, best);
        }
        rtk_scene_release(child);
        rtk_device_release(dev);
    }
    for (int k = 0; k < 2; k++) {
        free(h[k]);
        free(occ[k]);
    }
    free(xf);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(instances_vs_reference),
        cmocka_unit_test(nested_instances),
        cmocka_unit_test(snapshot_until_commit),
        cmocka_unit_test(instance_errors),
        cmocka_unit_test(dynamic_scene),
        cmocka_unit_test(dynamic_top_level_refit),
        cmocka_unit_test(dynamic_top_level_built),
        cmocka_unit_test(merged_vs_each_object),
        cmocka_unit_test(many_instances),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
