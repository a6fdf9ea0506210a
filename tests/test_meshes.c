/* Every backend, one device each in this process, against a brute-force
 * reference on every mesh of the shared test set: coherent (camera) and
 * random rays through intersect1, and shadow segments through occluded1. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh_import.h"
#include "testlib.h"

#define GRID 20         /* GRID x GRID camera rays */
#define RANDOM_RAYS 400 /* and as many shadow segments */

typedef struct ray_set {
    rtk_ray rays[GRID * GRID + 2 * RANDOM_RAYS];
    int occluded[GRID * GRID + 2 * RANDOM_RAYS]; /* test occluded1 instead of intersect1 */
    size_t count;
} ray_set;

static void make_rays(const rtk_mesh *m, ray_set *s, uint64_t seed)
{
    float lo[3], hi[3], c[3];
    const float diag = rtk_mesh_bounds(m, lo, hi);
    for (int k = 0; k < 3; k++)
        c[k] = 0.5f * (lo[k] + hi[k]);
    s->count = 0;
    /* Coherent: a pinhole camera at 1.5 diagonals, looking at the centre. */
    const float eye[3] = {c[0] + 0.5f * diag, c[1] + 0.6f * diag, c[2] + 1.3f * diag};
    for (int y = 0; y < GRID; y++)
        for (int x = 0; x < GRID; x++) {
            float t[3] = {lo[0] + (hi[0] - lo[0]) * (x + 0.5f) / GRID, lo[1] + (hi[1] - lo[1]) * (y + 0.5f) / GRID, c[2]};
            s->occluded[s->count] = 0;
            s->rays[s->count++] =
                test_ray(eye[0], eye[1], eye[2], t[0] - eye[0], t[1] - eye[1], t[2] - eye[2], 0, INFINITY);
        }
    /* Random: origins in the box grown by 10%, uniform directions; then
     * shadow segments of random length up to a third of the diagonal. */
    rng r = {seed};
    for (int kind = 0; kind < 2; kind++)
        for (int i = 0; i < RANDOM_RAYS; i++) {
            float o[3], d[3];
            for (int k = 0; k < 3; k++)
                o[k] = lo[k] - 0.1f * (hi[k] - lo[k]) + 1.2f * (hi[k] - lo[k]) * rng_float(&r);
            float z = 2.0f * rng_float(&r) - 1.0f, phi = 6.2831853f * rng_float(&r), rr = sqrtf(1.0f - z * z);
            d[0] = rr * cosf(phi);
            d[1] = rr * sinf(phi);
            d[2] = z;
            float tfar = kind ? diag * rng_float(&r) / 3.0f : INFINITY;
            s->occluded[s->count] = kind;
            s->rays[s->count++] = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0, tfar);
        }
}

static int check_mesh(const char *path, char names[][32], size_t nb)
{
    rtk_mesh m;
    char err[1024];
    if (rtk_mesh_load(path, &m, err, sizeof err))
        fail_msg("%s", err);
    static ray_set set;
    make_rays(&m, &set, 0x1234abcdu ^ m.triangle_count);

    /* Reference answers, once. */
    static int ref_hit[sizeof set.rays / sizeof set.rays[0]];
    static rtk_tri_hit ref_h[sizeof set.rays / sizeof set.rays[0]];
    static uint32_t ref_prim[sizeof set.rays / sizeof set.rays[0]];
    size_t hits = 0;
    ref_mesh ref = ref_prepare(m.vertices, m.indices, m.triangle_count);
    for (size_t i = 0; i < set.count; i++) {
        ref_hit[i] = ref_closest(&ref, &set.rays[i], &ref_h[i], &ref_prim[i]);
        hits += (size_t)ref_hit[i];
    }

    int failures = 0;
    size_t ties = 0;
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene scene = test_scene(dev, m.vertices, m.vertex_count, m.indices, m.triangle_count);
        for (size_t i = 0; i < set.count; i++) {
            const rtk_ray *r = &set.rays[i];
            if (set.occluded[i]) {
                rtk_ray o = *r;
                assert_int_equal(rtk_occluded1(scene, &o), RTK_OK);
                int got = o.tfar == -INFINITY;
                if (got != ref_hit[i] && failures++ < 10)
                    print_message("%s [%s] shadow ray %zu: occluded %d, reference %d\n", path, names[b], i, got,
                                  ref_hit[i]);
                continue;
            }
            rtk_rayhit rh;
            memset(&rh, 0, sizeof rh);
            rh.ray = *r;
            rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
            assert_int_equal(rtk_intersect1(scene, &rh), RTK_OK);
            int got = rh.hit.geomID != RTK_INVALID_GEOMETRY_ID;
            if (got != ref_hit[i]) {
                if (failures++ < 10)
                    print_message("%s [%s] ray %zu (org %.9g %.9g %.9g dir %.9g %.9g %.9g): hit %d, reference %d\n",
                                  path, names[b], i, r->org_x, r->org_y, r->org_z, r->dir_x, r->dir_y, r->dir_z, got,
                                  ref_hit[i]);
                continue;
            }
            if (!got)
                continue;
            const float t = ref_h[i].t, tol = 1e-6f * fabsf(t);
            if (!(fabsf(rh.ray.tfar - t) <= tol)) {
                if (failures++ < 10)
                    print_message("%s [%s] ray %zu: t %.9g, reference %.9g\n", path, names[b], i, rh.ray.tfar, t);
                continue;
            }
            if (rh.hit.primID != ref_prim[i]) {
                /* A tie in t: the other triangle must be hit at the same t. */
                rtk_tri_hit other;
                if (ref_one(&ref, rh.hit.primID, r, &other) && fabsf(other.t - t) <= tol) {
                    ties++;
                } else if (failures++ < 10) {
                    print_message("%s [%s] ray %zu: prim %u, reference %u\n", path, names[b], i, rh.hit.primID,
                                  ref_prim[i]);
                }
            }
        }
        rtk_scene_release(scene);
        rtk_device_release(dev);
    }
    print_message("%s: %zu triangles, %zu rays x %zu backends, %zu reference hits, %zu ties, %d disagreements\n",
                  path, m.triangle_count, set.count, nb, hits, ties, failures);
    ref_free(&ref);
    rtk_mesh_free(&m);
    return failures;
}

static void test_all_meshes_all_backends(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    /* scalar, sse41, avx, avx2 on any CPU of this project's machines */
    assert_true(nb + test_backends_left_out() >= 4);

    char *files[64];
    const size_t n = test_mesh_files(files, 64, NULL);
    assert_true(n >= (test_sanitized() ? 5u : 8u)); /* (testlib.h: the sanitizers leave the large ones out) */
    int failures = 0;
    for (size_t i = 0; i < n; i++) {
        failures += check_mesh(files[i], names, nb);
        free(files[i]);
    }
    /* The bundled copy the README renders. */
    failures += check_mesh(RTK_TEST_DATA "/bunny.ply", names, nb);
    assert_int_equal(failures, 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_all_meshes_all_backends),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
