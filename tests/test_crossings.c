/*
 * Every crossing and inside/outside (rtk_count_intersections,
 * rtk_list_intersections, rtk_occupancy) on the closed meshes of
 * tools/closed_mesh.h, in robust scenes on every backend: rays aimed
 * exactly at every vertex, edge third and edge middle from outside cross
 * an odd number of times up to their point inside and an even number all
 * the way through; the lists agree with the counts, sorted, within the
 * rays' ranges; points outside and inside by a margin, and points exactly
 * on the surface (the cube's vertices, edges and faces, exact in float),
 * are told apart; instances, masks, invalid rays and points, and the
 * errors.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "closed_mesh.h"
#include "testlib.h"

static rtk_scene mesh_scene(rtk_device dev, const rtk_mesh *m, size_t nt, unsigned flags)
{
    return test_scene_flags(dev, m->vertices, m->vertex_count, m->indices, nt, flags);
}

/* The aimed rays through s: odd up to the inside point, even beyond. */
static void check_aimed(rtk_scene s, const rtk_closed_mesh *m, const char *what)
{
    rtk_aimed a;
    /* (a margin beyond the meshes' distance from their solids, as
     * tests/test_robust.c) */
    assert_int_equal(rtk_closed_aim(m, 0.04, 4.0f, 0.5f, 17, &a), 0);
    const size_t n = a.count;
    rtk_ray *rays = malloc(2 * n * sizeof *rays);
    uint32_t *counts = malloc(2 * n * sizeof *counts);
    uint64_t *offsets = malloc((2 * n + 1) * sizeof *offsets);
    assert_true(rays && counts && offsets);
    for (size_t i = 0; i < n; i++) {
        rays[i] = a.rays[i];
        rays[i].tfar = a.t_in[i];
        rays[n + i] = a.rays[i];
        rays[n + i].tfar = INFINITY;
    }
    assert_int_equal(rtk_count_intersections(s, rays, 2 * n, sizeof *rays, counts), RTK_OK);
    size_t bad_in = 0, bad_through = 0;
    offsets[0] = 0;
    for (size_t i = 0; i < 2 * n; i++) {
        if (i < n ? counts[i] % 2 != 1 : counts[i] % 2 != 0) {
            if (bad_in + bad_through < 3)
                print_message("%s: ray %zu (%s) crosses %u times\n", what, i % n, i < n ? "to inside" : "through",
                              counts[i]);
            *(i < n ? &bad_in : &bad_through) += 1;
        }
        offsets[i + 1] = offsets[i] + counts[i];
    }
    if (bad_in || bad_through)
        fail_msg("%s: of %zu rays aimed at vertices and edges, %zu cross an even number of times to the inside "
                 "point, %zu an odd number all the way through",
                 what, n, bad_in, bad_through);
    rtk_crossing *c = malloc((offsets[2 * n] + 1) * sizeof *c);
    assert_non_null(c);
    assert_int_equal(rtk_list_intersections(s, rays, 2 * n, sizeof *rays, offsets, c), RTK_OK);
    for (size_t i = 0; i < 2 * n; i++)
        for (uint64_t k = offsets[i]; k < offsets[i + 1]; k++) {
            assert_true(c[k].t >= rays[i].tnear && c[k].t <= rays[i].tfar);
            assert_true(k == offsets[i] || c[k].t >= c[k - 1].t);
            assert_true(c[k].primID < m->closed_triangles && c[k].geomID == 0);
            assert_int_equal(c[k].instID, RTK_INVALID_GEOMETRY_ID);
        }
    /* the first crossing is the closest hit */
    for (size_t i = n; i < 2 * n; i++) {
        rtk_rayhit rh = {.ray = rays[i]};
        rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
        assert_true(counts[i] == 0 ? rh.hit.geomID == RTK_INVALID_GEOMETRY_ID : rh.ray.tfar == c[offsets[i]].t);
    }
    /* occupancy: the rays' outside and inside points */
    rtk_point_query *p = calloc(2 * n, sizeof *p);
    uint8_t *inside = malloc(2 * n);
    assert_true(p && inside);
    for (size_t i = 0; i < n; i++) {
        const rtk_ray *r = &a.rays[i];
        p[i] = (rtk_point_query){.x = r->org_x, .y = r->org_y, .z = r->org_z};
        p[n + i] = (rtk_point_query){.x = (double)r->org_x + a.t_in[i] * (double)r->dir_x,
                                     .y = (double)r->org_y + a.t_in[i] * (double)r->dir_y,
                                     .z = (double)r->org_z + a.t_in[i] * (double)r->dir_z};
    }
    assert_int_equal(rtk_occupancy(s, p, 2 * n, inside), RTK_OK);
    size_t wrong = 0, checked = 0;
    for (size_t i = 0; i < 2 * n; i++) {
        const float f[3] = {(float)p[i].x, (float)p[i].y, (float)p[i].z};
        const double depth = rtk_closed_depth(m, f);
        if (fabs(depth) < 0.04)
            continue; /* (the mesh lies within 0.04 of the solid) */
        checked++;
        wrong += inside[i] != (depth > 0);
    }
    if (wrong)
        fail_msg("%s: %zu of %zu points outside or inside by 0.04 told wrong", what, wrong, checked);
    assert_true(checked > n);
    free(p);
    free(inside);
    free(c);
    free(rays);
    free(counts);
    free(offsets);
    rtk_aimed_free(&a);
}

static void test_closed_meshes(void **state)
{
    (void)state;
    char names[8][32];
    const size_t nb = test_backend_names(names, 8);
    const double c0[3] = {0.25, -0.5, 0.125};
    rtk_closed_mesh meshes[4];
    assert_int_equal(rtk_closed_sphere(c0, 1.0, 24, 12, &meshes[0]), 0);
    assert_int_equal(rtk_closed_torus(c0, 1.0, 0.3, 24, 12, &meshes[1]), 0);
    assert_int_equal(rtk_closed_box(c0, 0.5, 4, &meshes[2]), 0);
    assert_int_equal(rtk_closed_cylinder(c0, 0.5, 1.0, 48, 1, &meshes[3]), 0);
    const unsigned flags[] = {RTK_SCENE_FLAG_ROBUST, RTK_SCENE_FLAG_ROBUST | RTK_SCENE_FLAG_COMPACT};
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        for (int f = 0; f < 2; f++)
            for (int k = 0; k < 4; k++) {
                rtk_scene s = mesh_scene(dev, &meshes[k].mesh, meshes[k].mesh.triangle_count, flags[f]);
                char what[96];
                snprintf(what, sizeof what, "%s, %s, flags %u", names[b], meshes[k].name, flags[f]);
                check_aimed(s, &meshes[k], what);
                rtk_scene_release(s);
            }
        rtk_device_release(dev);
    }
    for (int k = 0; k < 4; k++)
        rtk_closed_free(&meshes[k]);
}

/* Points exactly on the cube's surface (its vertices, its grid's edge
 * middles and face centres: exact in float) are inside; one ulp out, out. */
static void test_on_surface(void **state)
{
    (void)state;
    const double c0[3] = {0.5, 0.25, -0.75};
    rtk_closed_mesh m;
    assert_int_equal(rtk_closed_box(c0, 0.5, 4, &m), 0);
    rtk_device dev = test_device_threads("avx2", 2);
    rtk_scene s = mesh_scene(dev, &m.mesh, m.mesh.triangle_count, RTK_SCENE_FLAG_ROBUST);
    const size_t nt = m.mesh.triangle_count;
    rtk_point_query *p = calloc(4 * nt, sizeof *p);
    uint8_t *inside = malloc(4 * nt);
    assert_true(p && inside);
    size_t n = 0;
    for (size_t t = 0; t < nt; t++) {
        const uint32_t *ix = &m.mesh.indices[3 * t];
        const float *v0 = &m.mesh.vertices[3 * ix[0]], *v1 = &m.mesh.vertices[3 * ix[1]];
        const float *v2 = &m.mesh.vertices[3 * ix[2]];
        p[n++] = (rtk_point_query){.x = v0[0], .y = v0[1], .z = v0[2]};
        p[n++] = (rtk_point_query){.x = 0.5 * (v0[0] + v1[0]), .y = 0.5 * (v0[1] + v1[1]), .z = 0.5 * (v0[2] + v1[2])};
        p[n++] = (rtk_point_query){.x = (v0[0] + v1[0] + v2[0]) / 4 + v0[0] / 4, .y = (v0[1] + v1[1] + v2[1]) / 4 + v0[1] / 4,
                                   .z = (v0[2] + v1[2] + v2[2]) / 4 + v0[2] / 4};
        /* just outside: the face's point moved out by an ulp along its axis */
        rtk_point_query o = p[n - 3];
        double *x = &o.x;
        for (int a = 0; a < 3; a++)
            if (fabs(x[a] - c0[a]) == 0.5)
                x[a] = nextafterf((float)x[a], x[a] > c0[a] ? INFINITY : -INFINITY);
        p[n++] = o;
    }
    assert_int_equal(rtk_occupancy(s, p, n, inside), RTK_OK);
    for (size_t i = 0; i < n; i++)
        if (inside[i] != (i % 4 != 3))
            fail_msg("point %zu (%.9g %.9g %.9g): inside %u", i, p[i].x, p[i].y, p[i].z, inside[i]);
    free(p);
    free(inside);
    rtk_scene_release(s);
    rtk_device_release(dev);
    rtk_closed_free(&m);
}

/* The winding number of the mesh's closed surface around p, in double
 * (Van Oosterom and Strackee's solid angle per triangle): +-1 inside, 0
 * outside, whichever way the mesh faces. */
static double winding(const rtk_closed_mesh *m, const double p[3])
{
    double sum = 0.0;
    for (size_t t = 0; t < m->closed_triangles; t++) {
        double v[3][3], l[3];
        for (int k = 0; k < 3; k++) {
            const float *x = &m->mesh.vertices[3 * m->mesh.indices[3 * t + (size_t)k]];
            for (int a = 0; a < 3; a++)
                v[k][a] = x[a] - p[a];
            l[k] = sqrt(v[k][0] * v[k][0] + v[k][1] * v[k][1] + v[k][2] * v[k][2]);
        }
#define DOT_(a, b) ((a)[0] * (b)[0] + (a)[1] * (b)[1] + (a)[2] * (b)[2])
        const double bc[3] = {v[1][1] * v[2][2] - v[1][2] * v[2][1], v[1][2] * v[2][0] - v[1][0] * v[2][2],
                              v[1][0] * v[2][1] - v[1][1] * v[2][0]};
        sum += 2.0 * atan2(DOT_(v[0], bc), l[0] * l[1] * l[2] + DOT_(v[0], v[1]) * l[2] + DOT_(v[0], v[2]) * l[1] +
                                               DOT_(v[1], v[2]) * l[0]);
#undef DOT_
    }
    return sum / (4.0 * M_PI);
}

/* Points in double near closed meshes moved 10^3..10^5 from the origin,
 * where float's grid is 2^-14..2^-7 and cannot hold them: on vertices and
 * edge middles (inside: on the surface), and 1e-3 and 1e-4 off vertices,
 * edge middles and face centres either way, against the winding number in
 * double.  Rounding the points to float (rtk before this test) put 710 of
 * the sphere's 6,634 at 10^4 on the wrong side. */
static void test_far_double_points(void **state)
{
    (void)state;
    const double offsets[] = {1e3, 1e4, 1e5}, deltas[] = {1e-3, -1e-3, 1e-4, -1e-4};
    rtk_device dev = test_device_threads("avx2", 2);
    for (int o = 0; o < 3; o++)
        for (int kind = 0; kind < 3; kind++) {
            const double c0[3] = {offsets[o], -0.5 * offsets[o], 0.25 * offsets[o]};
            rtk_closed_mesh m;
            assert_int_equal(kind == 0   ? rtk_closed_sphere(c0, 1.0, 24, 12, &m)
                             : kind == 1 ? rtk_closed_torus(c0, 1.0, 0.3, 24, 12, &m)
                                         : rtk_closed_box(c0, 0.5, 4, &m),
                             0);
            rtk_scene s = mesh_scene(dev, &m.mesh, m.closed_triangles, RTK_SCENE_FLAG_ROBUST);
            const size_t nv = m.mesh.vertex_count, nt = m.closed_triangles;
            const size_t cap = nv * 5 + nt * 9;
            rtk_point_query *p = calloc(cap, sizeof *p);
            uint8_t *want = malloc(cap), *got = malloc(cap);
            assert_true(p && want && got);
            size_t n = 0;
            /* (base point, unit direction): vertices along their normals,
             * edge middles along their ends' normals' sum, face centres
             * along the face's normal */
            for (size_t i = 0; i < nv + 2 * nt; i++) {
                double b[3], d[3];
                if (i < nv) {
                    for (int a = 0; a < 3; a++)
                        b[a] = m.mesh.vertices[3 * i + (size_t)a], d[a] = m.normal[i][a];
                } else {
                    const size_t t = (i - nv) / 2;
                    const uint32_t *ix = &m.mesh.indices[3 * t];
                    const float *x0 = &m.mesh.vertices[3 * ix[0]], *x1 = &m.mesh.vertices[3 * ix[1]],
                                *x2 = &m.mesh.vertices[3 * ix[2]];
                    if ((i - nv) % 2 == 0)
                        for (int a = 0; a < 3; a++)
                            b[a] = 0.5 * ((double)x0[a] + x1[a]), d[a] = m.normal[ix[0]][a] + m.normal[ix[1]][a];
                    else {
                        const double e1[3] = {(double)x1[0] - x0[0], (double)x1[1] - x0[1], (double)x1[2] - x0[2]};
                        const double e2[3] = {(double)x2[0] - x0[0], (double)x2[1] - x0[1], (double)x2[2] - x0[2]};
                        d[0] = e1[1] * e2[2] - e1[2] * e2[1], d[1] = e1[2] * e2[0] - e1[0] * e2[2];
                        d[2] = e1[0] * e2[1] - e1[1] * e2[0];
                        for (int a = 0; a < 3; a++)
                            b[a] = ((double)x0[a] + x1[a] + x2[a]) / 3.0;
                    }
                }
                const double l = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                if (!(l > 0.0))
                    continue;
                if (i < nv + nt * 2 && (i < nv || (i - nv) % 2 == 0)) { /* on the surface itself */
                    p[n] = (rtk_point_query){.x = b[0], .y = b[1], .z = b[2]};
                    want[n++] = 1;
                }
                for (int k = 0; k < 4; k++) {
                    double x[3];
                    for (int a = 0; a < 3; a++)
                        x[a] = b[a] + deltas[k] * d[a] / l;
                    p[n] = (rtk_point_query){.x = x[0], .y = x[1], .z = x[2]};
                    want[n++] = fabs(winding(&m, x)) > 0.5;
                }
            }
            assert_true(n <= cap);
            assert_int_equal(rtk_occupancy(s, p, n, got), RTK_OK);
            size_t wrong = 0, in = 0;
            for (size_t i = 0; i < n; i++) {
                in += want[i];
                if (got[i] != want[i] && wrong++ < 5)
                    print_message("%s at %g: point (%.17g %.17g %.17g): %u, the winding number says %u\n", m.name,
                                  offsets[o], p[i].x, p[i].y, p[i].z, got[i], want[i]);
            }
            if (wrong)
                fail_msg("%s at %g: %zu of %zu points on the wrong side", m.name, offsets[o], wrong, n);
            assert_true(in > n / 4 && in < n); /* both sides there */
            free(p);
            free(want);
            free(got);
            rtk_scene_release(s);
            rtk_closed_free(&m);
        }
    rtk_device_release(dev);
}

/* Through an instance (moved and scaled): the same counts as the mesh's
 * own for the rays moved with it; a mask no ray shares: nothing; invalid
 * rays and points. */
static void test_instances_masks(void **state)
{
    (void)state;
    const double c0[3] = {0, 0, 0};
    rtk_closed_mesh m;
    assert_int_equal(rtk_closed_sphere(c0, 1.0, 16, 8, &m), 0);
    rtk_device dev = test_device("avx2");
    rtk_scene inner = mesh_scene(dev, &m.mesh, m.mesh.triangle_count, RTK_SCENE_FLAG_ROBUST);
    rtk_scene outer;
    rtk_geometry g;
    assert_int_equal(rtk_scene_new(dev, &outer), RTK_OK);
    assert_int_equal(rtk_scene_set_flags(outer, RTK_SCENE_FLAG_ROBUST), RTK_OK);
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_instanced_scene(g, inner), RTK_OK);
    const float xf[12] = {2, 0, 0, 10, 0, 2, 0, 0, 0, 0, 2, 0};
    assert_int_equal(rtk_geometry_set_transform(g, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, xf), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    uint32_t id;
    assert_int_equal(rtk_scene_attach_geometry(outer, g, &id), RTK_OK);
    rtk_geometry_release(g);
    assert_int_equal(rtk_scene_commit(outer), RTK_OK);
    enum { N = 200 };
    rtk_ray a[N], b[N];
    uint32_t ca[N], cb[N];
    rng r = {5};
    for (int i = 0; i < N; i++) {
        const float o[3] = {rng_float(&r) * 2.4f - 1.2f, rng_float(&r) * 2.4f - 1.2f, -3};
        a[i] = test_ray(o[0], o[1], o[2], rng_float(&r) * 0.2f - 0.1f, rng_float(&r) * 0.2f - 0.1f, 1, 0, INFINITY);
        b[i] = test_ray(2 * o[0] + 10, 2 * o[1], 2 * o[2], a[i].dir_x, a[i].dir_y, a[i].dir_z, 0, INFINITY);
    }
    a[7].org_x = NAN; /* invalid: crosses nothing */
    b[7].org_x = NAN;
    assert_int_equal(rtk_count_intersections(inner, a, N, sizeof *a, ca), RTK_OK);
    assert_int_equal(rtk_count_intersections(outer, b, N, sizeof *b, cb), RTK_OK);
    int hit = 0;
    for (int i = 0; i < N; i++) {
        assert_int_equal(ca[i], cb[i]);
        assert_true(ca[i] % 2 == 0);
        hit += ca[i] > 0;
    }
    assert_int_equal(ca[7], 0);
    assert_true(hit > N / 4);
    uint64_t off[N + 1] = {0};
    for (int i = 0; i < N; i++)
        off[i + 1] = off[i] + cb[i];
    rtk_crossing *c = malloc((off[N] + 1) * sizeof *c);
    assert_non_null(c);
    assert_int_equal(rtk_list_intersections(outer, b, N, sizeof *b, off, c), RTK_OK);
    for (uint64_t k = 0; k < off[N]; k++)
        assert_int_equal(c[k].instID, id);
    /* room for one crossing less: what fits, and the ray named */
    off[N] -= 1;
    for (int i = N - 1; i >= 0 && off[i] > off[N]; i--)
        off[i] = off[N];
    assert_int_equal(rtk_list_intersections(outer, b, N, sizeof *b, off, c), RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "more crossings than"));
    free(c);
    /* a ray mask the geometry does not share: nothing */
    for (int i = 0; i < N; i++)
        a[i].mask = 2;
    rtk_scene_release(inner);
    rtk_geometry gm;
    rtk_scene masked;
    assert_int_equal(rtk_scene_new(dev, &masked), RTK_OK);
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &gm), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(gm, RTK_BUFFER_TYPE_VERTEX, m.mesh.vertices, 0, 12,
                                                    m.mesh.vertex_count), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(gm, RTK_BUFFER_TYPE_INDEX, m.mesh.indices, 0, 12,
                                                    m.mesh.triangle_count), RTK_OK);
    assert_int_equal(rtk_geometry_set_mask(gm, 1), RTK_OK);
    assert_int_equal(rtk_geometry_commit(gm), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(masked, gm, NULL), RTK_OK);
    rtk_geometry_release(gm);
    assert_int_equal(rtk_scene_commit(masked), RTK_OK);
    assert_int_equal(rtk_count_intersections(masked, a, N, sizeof *a, ca), RTK_OK);
    for (int i = 0; i < N; i++)
        assert_int_equal(ca[i], 0);
    /* invalid points */
    const rtk_point_query bad[3] = {{.x = NAN}, {.y = INFINITY}, {.time = 2.0f}};
    uint8_t in[3];
    assert_int_equal(rtk_occupancy(masked, bad, 3, in), RTK_OK);
    for (int i = 0; i < 3; i++)
        assert_int_equal(in[i], RTK_OCCUPANCY_INVALID);
    rtk_scene_release(masked);
    rtk_scene_release(outer);
    rtk_device_release(dev);
    rtk_closed_free(&m);
}

static void test_errors(void **state)
{
    (void)state;
    rtk_device dev = test_device("avx2");
    rtk_scene s;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    rtk_ray ray = test_ray(0, 0, -5, 0, 0, 1, 0, INFINITY);
    uint32_t n;
    uint8_t in;
    const rtk_point_query pt = {0};
    uint64_t off[2] = {0, 0};
    assert_int_equal(rtk_count_intersections(s, &ray, 1, sizeof ray, &n), RTK_ERROR_INVALID_OPERATION);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    /* empty: nothing crossed, outside */
    assert_int_equal(rtk_count_intersections(s, &ray, 1, sizeof ray, &n), RTK_OK);
    assert_int_equal(n, 0);
    assert_int_equal(rtk_occupancy(s, &pt, 1, &in), RTK_OK);
    assert_int_equal(in, 0);
    assert_int_equal(rtk_list_intersections(s, &ray, 1, sizeof ray, off, NULL), RTK_OK);
    /* arguments */
    assert_int_equal(rtk_count_intersections(NULL, &ray, 1, sizeof ray, &n), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_count_intersections(s, NULL, 1, sizeof ray, &n), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_count_intersections(s, &ray, 1, sizeof ray, NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_count_intersections(s, &ray, 1, sizeof ray - 4, &n), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_count_intersections(s, &ray, 1, sizeof ray + 2, &n), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_count_intersections(s, NULL, 0, 0, NULL), RTK_OK);
    assert_int_equal(rtk_list_intersections(s, &ray, 1, sizeof ray, NULL, NULL), RTK_ERROR_INVALID_ARGUMENT);
    const uint64_t down[2] = {3, 1};
    assert_int_equal(rtk_list_intersections(s, &ray, 1, sizeof ray, down, NULL), RTK_ERROR_INVALID_ARGUMENT);
    const uint64_t some[2] = {0, 2};
    assert_int_equal(rtk_list_intersections(s, &ray, 1, sizeof ray, some, NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_occupancy(s, NULL, 1, &in), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_occupancy(s, &pt, 1, NULL), RTK_ERROR_INVALID_ARGUMENT);
    rtk_scene_release(s);
    /* user geometry (test_user_crossings): crossed where its callbacks
     * offer hits (this one has none); occupancy refused without its point
     * query function */
    s = test_user_scene(dev);
    assert_int_equal(rtk_count_intersections(s, &ray, 1, sizeof ray, &n), RTK_OK);
    assert_int_equal(n, 0);
    assert_int_equal(rtk_occupancy(s, &pt, 1, &in), RTK_ERROR_UNSUPPORTED);
    rtk_scene_release(s);
    rtk_device_release(dev);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_closed_meshes),
        cmocka_unit_test(test_on_surface),
        cmocka_unit_test(test_far_double_points),
        cmocka_unit_test(test_instances_masks),
        cmocka_unit_test(test_errors),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
