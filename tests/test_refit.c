/*
 * Refit (RTK_BUILD_QUALITY_REFIT on a geometry): after vertices move, a
 * commit keeps the tree and refits it.  Checked here: the hits of a refitted
 * tree against brute force over the moved triangles, on every backend,
 * builder and layout; boxes exactly as tight as the tree allows, and the
 * SAH cost an import of the tree finds; the same
 * tree on any number of threads; a tree that loads back through
 * rtk_scene_commit_bvh (whose check proves every triangle inside its
 * boxes); and every change that must make the commit build afresh instead.
 */
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh_import.h"
#include "testlib.h"

static rtk_mesh bunny;
static float bunny_lo[3], bunny_hi[3];

static int setup(void **state)
{
    (void)state;
    if (test_load_shared_mesh("bunny.ply", &bunny))
        return -1;
    rtk_mesh_bounds(&bunny, bunny_lo, bunny_hi);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    rtk_mesh_free(&bunny);
    return 0;
}

/* The bunny twisted about its vertical axis (more towards the top) and
 * waved up and down, by an amount t: the motion of an animation, which
 * keeps neighbours together. */
static void deform(float *dst, float t)
{
    const float cx = 0.5f * (bunny_lo[0] + bunny_hi[0]), cz = 0.5f * (bunny_lo[2] + bunny_hi[2]);
    const float height = bunny_hi[1] - bunny_lo[1], width = bunny_hi[0] - bunny_lo[0];
    for (size_t i = 0; i < bunny.vertex_count; i++) {
        const float *p = bunny.vertices + 3 * i;
        float *q = dst + 3 * i;
        const float a = 0.8f * t * (p[1] - bunny_lo[1]) / height;
        const float dx = p[0] - cx, dz = p[2] - cz;
        q[0] = cx + cosf(a) * dx - sinf(a) * dz;
        q[2] = cz + sinf(a) * dx + cosf(a) * dz;
        q[1] = p[1] + 0.05f * t * height * sinf(12.0f * dx / width);
    }
}

/* A scene of one REFIT geometry over the shared arrays v and idx. */
static rtk_scene refit_scene(rtk_device dev, float *v, const uint32_t *idx, size_t nv, size_t nt, unsigned flags,
                             rtk_build_quality quality, rtk_geometry *geom)
{
    rtk_scene s;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    assert_int_equal(rtk_scene_set_flags(s, flags), RTK_OK);
    assert_int_equal(rtk_scene_set_build_quality(s, quality), RTK_OK);
    rtk_geometry g;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, nv), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, idx, 0, 12, nt), RTK_OK);
    assert_int_equal(rtk_geometry_set_build_quality(g, RTK_BUILD_QUALITY_REFIT), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
    rtk_geometry_release(g);
    if (rtk_scene_commit(s) != RTK_OK)
        fail_msg("commit: %s", rtk_device_get_error_message(dev));
    *geom = g;
    return s;
}

static rtk_scene_info info_of(rtk_scene s)
{
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
    return info;
}

/* Every slot's box is exactly the box of the vertices of the triangles
 * below it (geometry 0 over v and idx); the box of subtree `ref` is
 * returned in lo, hi. */
static void check_tight(const rtk_bvh *t, uint32_t ref, const float *v, const uint32_t *idx, float lo[3],
                        float hi[3])
{
    for (int k = 0; k < 3; k++) {
        lo[k] = INFINITY;
        hi[k] = -INFINITY;
    }
    if (ref & RTK_BVH_LEAF_BIT) {
        const uint32_t j = ref & ~RTK_BVH_LEAF_BIT;
        for (uint64_t p = t->leaf_first[j]; p < t->leaf_first[j + 1]; p++) {
            assert_int_equal(t->prims[p].geom_id, 0);
            for (int c = 0; c < 3; c++)
                for (int k = 0; k < 3; k++) {
                    const float x = v[3 * (size_t)idx[3 * (size_t)t->prims[p].prim_id + c] + k];
                    lo[k] = fminf(lo[k], x);
                    hi[k] = fmaxf(hi[k], x);
                }
        }
        return;
    }
    for (uint32_t c = 0; c < t->width; c++) {
        const uint64_t slot = (uint64_t)ref * t->width + c;
        if (t->children[slot] == RTK_BVH_EMPTY)
            continue;
        float clo[3], chi[3];
        check_tight(t, t->children[slot], v, idx, clo, chi);
        for (int k = 0; k < 3; k++) {
            assert_true(t->child_lower[3 * slot + k] == clo[k]);
            assert_true(t->child_upper[3 * slot + k] == chi[k]);
            lo[k] = fminf(lo[k], clo[k]);
            hi[k] = fmaxf(hi[k], chi[k]);
        }
    }
}

/* ---- refitted trees answer as brute force does, on every backend,
 * builder and layout, and their boxes are tight ---- */

static void refit_matches_brute_force(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    static const rtk_build_quality qualities[] = {RTK_BUILD_QUALITY_LOW, RTK_BUILD_QUALITY_MEDIUM,
                                                  RTK_BUILD_QUALITY_HIGH};
    float *v = malloc(bunny.vertex_count * 3 * sizeof *v);
    assert_non_null(v);
    for (size_t b = 0; b < nb; b++)
        for (size_t q = 0; q < 3; q++)
            for (int f = 0; f < 2; f++) {
                rtk_device dev = test_device_threads(names[b], 2);
                memcpy(v, bunny.vertices, bunny.vertex_count * 3 * sizeof *v);
                rtk_geometry g;
                rtk_scene s = refit_scene(dev, v, bunny.indices, bunny.vertex_count, bunny.triangle_count,
                                          f ? RTK_SCENE_FLAG_COMPACT : 0, qualities[q], &g);
                const rtk_scene_info built = info_of(s);
                assert_int_equal(built.refits, 0);
                for (int step = 1; step <= 2; step++) {
                    deform(v, (float)step);
                    test_commit_moved(s, g);
                    const rtk_scene_info info = info_of(s);
                    assert_int_equal(info.refits, step);
                    assert_string_equal(info.builder, built.builder);
                    assert_int_equal(info.triangles, built.triangles);
                    assert_int_equal(info.nodes, built.nodes);
                    assert_int_equal(info.leaves, built.leaves);
                    assert_int_equal(info.references, built.references);
                    /* the box moved with the bunny's twist */
                    assert_true(info.bounds_lower[0] != built.bounds_lower[0] ||
                                info.bounds_upper[0] != built.bounds_upper[0]);
                    const int hits = test_rays_vs_brute_force(s, v, bunny.indices, bunny.triangle_count, 300, 7 + step);
                    assert_true(hits > 60);
                }
                /* exact boxes, and a tree that loads back over the same vertices */
                rtk_bvh t = {.struct_size = sizeof t};
                assert_int_equal(rtk_scene_get_bvh(s, &t), RTK_OK);
                char msg[256];
                assert_int_equal(rtk_bvh_check(&t, msg, sizeof msg), RTK_OK);
                float lo[3], hi[3];
                check_tight(&t, t.root, v, bunny.indices, lo, hi);
                const rtk_scene_info info = info_of(s);
                for (int k = 0; k < 3; k++) {
                    assert_true(info.bounds_lower[k] == lo[k]);
                    assert_true(info.bounds_upper[k] == hi[k]);
                }
                rtk_scene loaded = test_scene_uncommitted(dev, v, bunny.vertex_count, bunny.indices,
                                                          bunny.triangle_count, f ? RTK_SCENE_FLAG_COMPACT : 0);
                if (rtk_scene_commit_bvh(loaded, &t) != RTK_OK)
                    fail_msg("%s: %s", names[b], rtk_device_get_error_message(dev));
                /* the refit summed its SAH as it went; the import sums the
                 * same tree's after: the same figure to the bit */
                if (info_of(loaded).sah_cost != info.sah_cost)
                    fail_msg("%s: SAH %.17g refitted, %.17g loaded", names[b], info.sah_cost,
                             info_of(loaded).sah_cost);
                rtk_bvh_free(&t);
                rtk_scene_release(loaded);
                rtk_scene_release(s);
                rtk_device_release(dev);
            }
    free(v);
}

/* ---- the same refitted tree on any number of threads ---- */

static void refit_same_tree_any_threads(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    float *v = malloc(bunny.vertex_count * 3 * sizeof *v);
    assert_non_null(v);
    for (size_t b = 0; b < nb; b++) {
        rtk_bvh want = {0};
        static const int threads[] = {1, 2, 3};
        for (int k = 0; k < 3; k++) {
            rtk_device dev = test_device_threads(names[b], threads[k]);
            memcpy(v, bunny.vertices, bunny.vertex_count * 3 * sizeof *v);
            rtk_geometry g;
            rtk_scene s = refit_scene(dev, v, bunny.indices, bunny.vertex_count, bunny.triangle_count, 0,
                                      RTK_BUILD_QUALITY_MEDIUM, &g);
            deform(v, 1.5f);
            test_commit_moved(s, g);
            assert_int_equal(info_of(s).refits, 1);
            rtk_bvh t = {.struct_size = sizeof t};
            assert_int_equal(rtk_scene_get_bvh(s, &t), RTK_OK);
            if (k == 0)
                want = t;
            else {
                test_assert_same_tree(&t, &want);
                rtk_bvh_free(&t);
            }
            rtk_scene_release(s);
            rtk_device_release(dev);
        }
        rtk_bvh_free(&want);
    }
    free(v);
}

/* ---- what refits and what builds afresh ---- */

/* A quad grid of n x n cells (2 n^2 triangles) in the plane y = 0 over
 * [0, 1]^2, malloc'd. */
static void grid(int n, float **v, uint32_t **idx)
{
    *v = malloc((size_t)(n + 1) * (n + 1) * 3 * sizeof **v);
    *idx = malloc((size_t)2 * n * n * 3 * sizeof **idx);
    assert_non_null(*v);
    assert_non_null(*idx);
    for (int j = 0; j <= n; j++)
        for (int i = 0; i <= n; i++) {
            float *p = *v + 3 * ((size_t)j * (n + 1) + i);
            p[0] = (float)i / (float)n;
            p[1] = 0.0f;
            p[2] = (float)j / (float)n;
        }
    uint32_t *q = *idx;
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) {
            const uint32_t a = (uint32_t)(j * (n + 1) + i), b = a + 1, c = a + (uint32_t)n + 1, d = c + 1;
            q[0] = a, q[1] = c, q[2] = b, q[3] = b, q[4] = c, q[5] = d;
            q += 6;
        }
}

/* A wave over the grid at time t. */
static void wave(float *v, int n, float t)
{
    for (int j = 0; j <= n; j++)
        for (int i = 0; i <= n; i++) {
            float *p = v + 3 * ((size_t)j * (n + 1) + i);
            p[1] = 0.1f * sinf(6.0f * p[0] + t) * cosf(4.0f * p[2] - t);
        }
}

static void check_grid_hits(rtk_scene s, const float *v, const uint32_t *idx, size_t nt)
{
    assert_true(test_rays_vs_brute_force(s, v, idx, nt, 200, 3) > 20);
}

static void refit_or_build(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    const int n = 40;
    const size_t nv = (size_t)(n + 1) * (n + 1), nt = (size_t)2 * n * n;
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device_threads(names[b], 2);
        float *v;
        uint32_t *idx;
        grid(n, &v, &idx);
        rtk_geometry g;
        rtk_scene s = refit_scene(dev, v, idx, nv, nt, 0, RTK_BUILD_QUALITY_MEDIUM, &g);

        wave(v, n, 0.5f);
        test_commit_moved(s, g);
        assert_int_equal(info_of(s).refits, 1);
        check_grid_hits(s, v, idx, nt);

        /* two triangles lose their area (a vertex moved onto its neighbour
         * across the edge they share): they stay in the tree, never hit */
        const float keep[3] = {v[3 * idx[5]], v[3 * idx[5] + 1], v[3 * idx[5] + 2]};
        memcpy(v + 3 * idx[5], v + 3 * idx[4], 3 * sizeof *v);
        test_commit_moved(s, g);
        rtk_scene_info info = info_of(s);
        assert_int_equal(info.refits, 2);
        assert_int_equal(info.triangles_degenerate, 2);
        assert_int_equal(info.triangles, nt);
        check_grid_hits(s, v, idx, nt);

        /* and get it back */
        memcpy(v + 3 * idx[5], keep, sizeof keep);
        test_commit_moved(s, g);
        info = info_of(s);
        assert_int_equal(info.refits, 3);
        assert_int_equal(info.triangles_degenerate, 0);
        check_grid_hits(s, v, idx, nt);

        /* a NaN vertex: built afresh, its triangles left out and counted */
        const float y = v[3 * 7 + 1];
        v[3 * 7 + 1] = NAN;
        test_commit_moved(s, g);
        info = info_of(s);
        assert_int_equal(info.refits, 0);
        assert_true(info.triangles_skipped > 0);
        check_grid_hits(s, v, idx, nt);
        v[3 * 7 + 1] = y;
        test_commit_moved(s, g);
        info = info_of(s);
        assert_int_equal(info.refits, 0);
        assert_int_equal(info.triangles, nt);

        /* refits again while the valid triangles stay the same */
        wave(v, n, 1.0f);
        test_commit_moved(s, g);
        assert_int_equal(info_of(s).refits, 1);

        /* a commit with nothing updated builds (the application may have
         * changed a shared buffer without saying so) */
        assert_int_equal(rtk_scene_commit(s), RTK_OK);
        assert_int_equal(info_of(s).refits, 0);

        /* new indices: built afresh */
        for (size_t t = 0; t < nt; t++) { /* flip every triangle */
            const uint32_t x = idx[3 * t + 1];
            idx[3 * t + 1] = idx[3 * t + 2];
            idx[3 * t + 2] = x;
        }
        assert_int_equal(rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_INDEX), RTK_OK);
        wave(v, n, 1.5f);
        test_commit_moved(s, g);
        assert_int_equal(info_of(s).refits, 0);
        check_grid_hits(s, v, idx, nt);

        /* the scene's flags or quality changed: built afresh */
        wave(v, n, 2.0f);
        assert_int_equal(rtk_scene_set_build_quality(s, RTK_BUILD_QUALITY_LOW), RTK_OK);
        test_commit_moved(s, g);
        info = info_of(s);
        assert_int_equal(info.refits, 0);
        assert_string_equal(info.builder, "morton");
        wave(v, n, 2.5f);
        test_commit_moved(s, g);
        assert_int_equal(info_of(s).refits, 1);
        check_grid_hits(s, v, idx, nt);
        assert_int_equal(rtk_scene_set_flags(s, RTK_SCENE_FLAG_COMPACT), RTK_OK);
        wave(v, n, 3.0f);
        test_commit_moved(s, g);
        assert_int_equal(info_of(s).refits, 0);

        /* a geometry that is not REFIT builds on any change */
        assert_int_equal(rtk_geometry_set_build_quality(g, RTK_BUILD_QUALITY_MEDIUM), RTK_OK);
        wave(v, n, 3.5f);
        test_commit_moved(s, g);
        assert_int_equal(info_of(s).refits, 0);
        assert_int_equal(rtk_geometry_set_build_quality(g, RTK_BUILD_QUALITY_REFIT), RTK_OK);

        /* a second geometry that stays put (a copy of the grid below) */
        float *v2 = malloc(nv * 3 * sizeof *v2);
        assert_non_null(v2);
        for (size_t i = 0; i < nv; i++) {
            v2[3 * i] = v[3 * i];
            v2[3 * i + 1] = -1.0f;
            v2[3 * i + 2] = v[3 * i + 2];
        }
        rtk_geometry g2;
        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g2), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer(g2, RTK_BUFFER_TYPE_VERTEX, v2, 0, 12, nv), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer(g2, RTK_BUFFER_TYPE_INDEX, idx, 0, 12, nt), RTK_OK);
        assert_int_equal(rtk_geometry_commit(g2), RTK_OK);
        uint32_t id2;
        assert_int_equal(rtk_scene_attach_geometry(s, g2, &id2), RTK_OK);
        assert_int_equal(rtk_scene_commit(s), RTK_OK); /* attached: built */
        wave(v, n, 4.0f);
        test_commit_moved(s, g);
        assert_int_equal(info_of(s).refits, 1);
        assert_int_equal(info_of(s).triangles, 2 * nt);
        /* straight down at a cell's middle: the wave, not the copy below */
        for (int i = 0; i < n; i += 5) {
            const float x = ((float)i + 0.5f) / (float)n, z = 0.37f;
            rtk_rayhit rh = {.ray = test_ray(x, 2.0f, z, 0.0f, -1.0f, 0.0f, 0.0f, INFINITY)};
            rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
            assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
            assert_int_equal(rh.hit.geomID, 0);
            const float want = 2.0f - 0.1f * sinf(6.0f * x + 4.0f) * cosf(4.0f * z - 4.0f);
            assert_true(fabsf(rh.ray.tfar - want) < 2e-3f);
        }
        /* disabled, then enabled again: built both times */
        assert_int_equal(rtk_geometry_disable(g2), RTK_OK);
        wave(v, n, 4.5f);
        test_commit_moved(s, g);
        assert_int_equal(info_of(s).refits, 0);
        assert_int_equal(info_of(s).triangles, nt);
        assert_int_equal(rtk_geometry_enable(g2), RTK_OK);
        wave(v, n, 5.0f);
        test_commit_moved(s, g);
        assert_int_equal(info_of(s).refits, 0);
        assert_int_equal(info_of(s).triangles, 2 * nt);
        /* detached: built */
        assert_int_equal(rtk_scene_detach_geometry(s, id2), RTK_OK);
        wave(v, n, 5.5f);
        test_commit_moved(s, g);
        assert_int_equal(info_of(s).refits, 0);
        rtk_geometry_release(g2);
        free(v2);

        rtk_scene_release(s);
        rtk_device_release(dev);
        free(v);
        free(idx);
    }
}

/* A compact scene reads the vertex buffer while tracing: a refit onto a
 * new buffer of rtk's (the old one freed once the scene lets it go) must
 * trace from the new one.  Run under ASan, a read of the old one fails. */
static void refit_onto_new_buffer(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    const int n = 30;
    const size_t nv = (size_t)(n + 1) * (n + 1), nt = (size_t)2 * n * n;
    for (size_t b = 0; b < nb; b++)
        for (int f = 0; f < 2; f++) {
            rtk_device dev = test_device_threads(names[b], 1);
            float *v;
            uint32_t *idx;
            grid(n, &v, &idx);
            rtk_scene s;
            assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
            assert_int_equal(rtk_scene_set_flags(s, f ? RTK_SCENE_FLAG_COMPACT : 0), RTK_OK);
            rtk_geometry g;
            assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
            assert_int_equal(rtk_geometry_set_build_quality(g, RTK_BUILD_QUALITY_REFIT), RTK_OK);
            void *mem;
            assert_int_equal(rtk_geometry_set_new_buffer(g, RTK_BUFFER_TYPE_VERTEX, 12, nv, &mem), RTK_OK);
            memcpy(mem, v, nv * 3 * sizeof *v);
            assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, idx, 0, 12, nt), RTK_OK);
            assert_int_equal(rtk_geometry_commit(g), RTK_OK);
            assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
            assert_int_equal(rtk_scene_commit(s), RTK_OK);
            for (int step = 1; step <= 3; step++) {
                wave(v, n, (float)step);
                assert_int_equal(rtk_geometry_set_new_buffer(g, RTK_BUFFER_TYPE_VERTEX, 12, nv, &mem), RTK_OK);
                memcpy(mem, v, nv * 3 * sizeof *v);
                assert_int_equal(rtk_geometry_commit(g), RTK_OK);
                assert_int_equal(rtk_scene_commit(s), RTK_OK);
                assert_int_equal(info_of(s).refits, step);
                check_grid_hits(s, v, idx, nt);
            }
            rtk_geometry_release(g);
            rtk_scene_release(s);
            rtk_device_release(dev);
            free(v);
            free(idx);
        }
}

/* ---- zero-area triangles kept for a refit are never hit ----
 * Exactly collinear triangles (in double precision, as rtk decides zero
 * area), with coordinates that are multiples of 1/1024, and rays aimed at
 * points on them from generic directions: in float, the determinant of
 * such a test need not round to zero, so only the leaf lanes written
 * never to hit keep these rays from hitting.  Then moved by a refit, and
 * once given area, hit like any triangle. */
static void zero_area_never_hit(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    enum { NT = 3000 };
    float *v = malloc(NT * 9 * sizeof *v);
    uint32_t *idx = malloc(NT * 3 * sizeof *idx);
    rtk_ray *rays = malloc(NT * sizeof *rays);
    assert_non_null(v);
    assert_non_null(idx);
    assert_non_null(rays);
    rng r = {4242};
    for (size_t t = 0; t < NT; t++) {
        float p[3], d[3];
        for (int k = 0; k < 3; k++) {
            p[k] = (float)(rng_u32(&r) % 1024) / 1024.0f;
            d[k] = (float)((int)(rng_u32(&r) % 15) - 7) / 64.0f;
        }
        if (d[0] == 0.0f && d[1] == 0.0f && d[2] == 0.0f)
            d[0] = 1.0f / 64.0f;
        const float s1 = (float)(1 + rng_u32(&r) % 5), s2 = -(float)(1 + rng_u32(&r) % 5);
        for (int k = 0; k < 3; k++) {
            v[9 * t + k] = p[k];
            v[9 * t + 3 + k] = p[k] + s1 * d[k];
            v[9 * t + 6 + k] = p[k] + s2 * d[k];
        }
        assert_true(rtk_triangle_is_degenerate(v + 9 * t, v + 9 * t + 3, v + 9 * t + 6));
        for (int k = 0; k < 3; k++)
            idx[3 * t + k] = (uint32_t)(3 * t + (size_t)k);
        float dir[3], at[3];
        const float f = rng_float(&r); /* a point between v1 and v2 */
        for (int k = 0; k < 3; k++) {
            at[k] = v[9 * t + 3 + k] + f * (v[9 * t + 6 + k] - v[9 * t + 3 + k]);
            dir[k] = rng_float(&r) - 0.5f;
        }
        rays[t] = test_ray(at[0] - dir[0], at[1] - dir[1], at[2] - dir[2], dir[0], dir[1], dir[2], 0.0f, INFINITY);
    }
    for (size_t b = 0; b < nb; b++)
        for (int f = 0; f < 2; f++) {
            rtk_device dev = test_device_threads(names[b], 1);
            rtk_geometry g;
            rtk_scene s = refit_scene(dev, v, idx, 3 * NT, NT, f ? RTK_SCENE_FLAG_COMPACT : 0,
                                      RTK_BUILD_QUALITY_MEDIUM, &g);
            rtk_scene_info info = info_of(s);
            assert_int_equal(info.triangles, NT);
            assert_int_equal(info.triangles_degenerate, NT);
            for (int step = 0; step < 2; step++) {
                for (size_t t = 0; t < NT; t++) {
                    rtk_rayhit rh = {.ray = rays[t]};
                    rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
                    assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
                    if (rh.hit.geomID != RTK_INVALID_GEOMETRY_ID)
                        fail_msg("%s: ray %zu hit zero-area triangle %u", names[b], t, rh.hit.primID);
                    rtk_ray shadow = rays[t];
                    assert_int_equal(rtk_occluded1(s, &shadow), RTK_OK);
                    assert_true(shadow.tfar == rays[t].tfar);
                }
                /* moved along themselves: still collinear, refitted */
                for (size_t i = 0; i < 9 * (size_t)NT; i++)
                    v[i] += 1.0f;
                for (size_t t = 0; t < NT; t++) {
                    rays[t].org_x += 1.0f;
                    rays[t].org_y += 1.0f;
                    rays[t].org_z += 1.0f;
                }
                test_commit_moved(s, g);
                assert_int_equal(info_of(s).refits, step + 1);
            }
            /* given area: refitted, and hit as brute force says */
            uint64_t still_flat = 0; /* the few along the axis they moved on */
            for (size_t t = 0; t < NT; t++) {
                v[9 * t + 6 + t % 3] += 0.25f;
                still_flat += (uint64_t)rtk_triangle_is_degenerate(v + 9 * t, v + 9 * t + 3, v + 9 * t + 6);
            }
            assert_true(still_flat < NT / 50);
            test_commit_moved(s, g);
            info = info_of(s);
            assert_int_equal(info.refits, 3);
            assert_int_equal(info.triangles_degenerate, still_flat);
            assert_true(test_rays_vs_brute_force(s, v, idx, NT, 300, 11) > 30);
            rtk_scene_release(s);
            rtk_device_release(dev);
            for (size_t i = 0; i < 9 * (size_t)NT; i++) /* back to where the rays aim */
                v[i] -= 2.0f;
            for (size_t t = 0; t < NT; t++) {
                v[9 * t + 6 + t % 3] -= 0.25f;
                rays[t].org_x -= 2.0f;
                rays[t].org_y -= 2.0f;
                rays[t].org_z -= 2.0f;
            }
        }
    free(v);
    free(idx);
    free(rays);
}

/* Whether some pair of terms a_i b_j, a_j b_i of the float cross product
 * of the triangle's edges a = v1 - v0, b = v2 - v0 rounds to two different
 * subnormal floats (each product rounded on its own, as the leaf writer's
 * float test computes them). */
static int subnormal_terms_differ(const float *tri)
{
    volatile float a[3], b[3], p, q;
    for (int k = 0; k < 3; k++) {
        a[k] = tri[3 + k] - tri[k];
        b[k] = tri[6 + k] - tri[k];
    }
    for (int i = 0; i < 3; i++) {
        const int j = (i + 1) % 3, k = (i + 2) % 3;
        p = a[j] * b[k];
        q = a[k] * b[j];
        if (p != q && fabsf(p) < FLT_MIN && fabsf(q) < FLT_MIN)
            return 1;
    }
    return 0;
}

/* ---- which kept triangles have zero area, at every scale ----
 * The leaf writer decides zero area four lanes at once: a float test first,
 * and rtk_triangle_is_degenerate only for the lanes it cannot clear.  Here,
 * at scales from 2^-140 (vertices below the smallest normal float) to
 * 2^120 (edge products far past FLT_MAX), triangles that are exactly
 * collinear, one ulp off collinear, 2^-20 off, collinear through a point
 * near the origin (their float edges are rounded, so their float cross
 * product is not zero, but in double it is), such triangles whose float
 * cross product terms are subnormals that round apart, and generic ones.
 * A scene built over them with each builder, and one built over generic
 * triangles, refitted onto these and back, must count the zero-area ones
 * as the exact test does (the latter in the layouts that copy vertices,
 * default and robust, and the compact one). */
static void zero_area_at_every_scale(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    enum { PER_KIND = 61, NT = 6 * PER_KIND };
    static const int exps[] = {-140, -126, -100, -72, -68, -64, -40, -20, 0, 20, 40, 64, 100, 120};
    static const unsigned layouts[] = {0, RTK_SCENE_FLAG_COMPACT, RTK_SCENE_FLAG_ROBUST};
    float *v = malloc(NT * 9 * sizeof *v), *generic = malloc(NT * 9 * sizeof *v), *odd = malloc(NT * 9 * sizeof *v);
    uint32_t *idx = malloc(NT * 3 * sizeof *idx);
    assert_non_null(v);
    assert_non_null(generic);
    assert_non_null(odd);
    assert_non_null(idx);
    for (size_t i = 0; i < 3 * (size_t)NT; i++)
        idx[i] = (uint32_t)i;
    rng r = {777};
    for (size_t e = 0; e < sizeof exps / sizeof *exps; e++) {
        const float scale = ldexpf(1.0f, exps[e]);
        uint64_t expect = 0, far = 0, tiny = 0, flat = 0, g_far = 0, g_flat = 0, moved_out = 0;
        for (size_t t = 0; t < NT; t++) {
            float *tri = odd + 9 * t;
            float p[3], d[3];
            for (int k = 0; k < 3; k++) {
                p[k] = (float)(1 + rng_u32(&r) % 1024) / 128.0f * scale;
                d[k] = (float)((int)(rng_u32(&r) % 15) - 7) / 16.0f * scale;
                for (int j = 0; j < 3; j++)
                    generic[9 * t + 3 * j + k] = (rng_float(&r) + 1.0f) * 4.0f * scale;
            }
            const float s1 = (float)(1 + rng_u32(&r) % 5), s2 = -(float)(1 + rng_u32(&r) % 5);
            for (int k = 0; k < 3; k++) {
                tri[k] = p[k];
                tri[3 + k] = p[k] + s1 * d[k];
                tri[6 + k] = p[k] + s2 * d[k];
            }
            const int kind = (int)(t / PER_KIND), axis = (int)(rng_u32(&r) % 3);
            if (kind == 1) /* one ulp off */
                tri[6 + axis] = nextafterf(tri[6 + axis], INFINITY);
            else if (kind == 2) /* 2^-20 off */
                tri[6 + axis] += ldexpf(tri[6 + axis] == 0.0f ? scale : tri[6 + axis], -20);
            else if (kind == 3) /* through f * 2^-10, f of 20 bits: s1 f - f 2^-10 needs 33 */
                for (int k = 0; k < 3; k++) {
                    const float f = (float)((int32_t)(rng_u32(&r) % (1u << 20)) - (1 << 19)) * 0x1p-20f * scale;
                    tri[k] = ldexpf(f, -10);
                    tri[3 + k] = s1 * f;
                    tri[6 + k] = s2 * f;
                }
            else if (kind == 4)
                memcpy(tri, generic + 9 * t, 9 * sizeof *tri);
            else if (kind == 5) /* as kind 3 at 2^-67, drawn until some term pair rounds apart */
                for (int tries = 0;; tries++) {
                    assert_true(tries < 1 << 20);
                    for (int k = 0; k < 3; k++) {
                        const float f = (float)((int32_t)(rng_u32(&r) % (1u << 20)) - (1 << 19)) * 0x1p-87f;
                        tri[k] = ldexpf(f, -10);
                        tri[3 + k] = s1 * f;
                        tri[6 + k] = s2 * f;
                    }
                    if (subnormal_terms_differ(tri))
                        break;
                }
            expect += (uint64_t)rtk_triangle_is_degenerate(tri, tri + 3, tri + 6);
            if (kind == 5)
                assert_true(rtk_triangle_is_degenerate(tri, tri + 3, tri + 6));
            /* and as rtk's range sorts them (rtk.h): those with a coordinate
             * beyond it and the tiny ones are counted apart */
            const enum rtk_triangle_class k = rtk_triangle_classify(tri, tri + 3, tri + 6);
            far += k == RTK_TRIANGLE_FAR;
            tiny += k == RTK_TRIANGLE_TINY;
            flat += k == RTK_TRIANGLE_DEGENERATE;
            const float *gt = generic + 9 * t;
            const enum rtk_triangle_class gk = rtk_triangle_classify(gt, gt + 3, gt + 6);
            g_far += gk == RTK_TRIANGLE_FAR;
            moved_out += (k == RTK_TRIANGLE_FAR) != (gk == RTK_TRIANGLE_FAR);
            g_flat += gk == RTK_TRIANGLE_DEGENERATE || gk == RTK_TRIANGLE_TINY;
        }
        /* the kinds are what they claim, where floats can hold them */
        if (exps[e] >= -100 && exps[e] <= 100)
            assert_true(expect >= 3 * PER_KIND && expect < 5 * PER_KIND);
        /* within the range the classes are the exact test's */
        if (!far && !tiny)
            assert_int_equal(flat, expect);
        /* a build straight over them: the builders' own pass (build_hittable)
         * leaves out the zero-area ones the exact test finds */
        for (size_t b = 0; b < nb; b++)
            for (int q = RTK_BUILD_QUALITY_LOW; q <= RTK_BUILD_QUALITY_HIGH; q++) {
                rtk_device dev = test_device_threads(names[b], 1);
                rtk_scene s = test_scene_uncommitted(dev, odd, 3 * NT, idx, NT, 0);
                assert_int_equal(rtk_scene_set_build_quality(s, (rtk_build_quality)q), RTK_OK);
                if (rtk_scene_commit(s) != RTK_OK)
                    fail_msg("commit: %s", rtk_device_get_error_message(dev));
                const rtk_scene_info info = info_of(s);
                if (info.triangles_degenerate != flat || info.triangles_out_of_range != far + tiny)
                    fail_msg("%s, quality %d, scale 2^%d: a build leaves out %llu zero-area triangles and %llu "
                             "outside the range, the exact tests say %llu and %llu",
                             names[b], q, exps[e], (unsigned long long)info.triangles_degenerate,
                             (unsigned long long)info.triangles_out_of_range, (unsigned long long)flat,
                             (unsigned long long)(far + tiny));
                rtk_scene_release(s);
                rtk_device_release(dev);
            }
        for (size_t b = 0; b < nb; b++)
            for (size_t l = 0; l < sizeof layouts / sizeof *layouts; l++) {
                rtk_device dev = test_device_threads(names[b], 1);
                memcpy(v, generic, NT * 9 * sizeof *v);
                rtk_geometry g;
                rtk_scene s = refit_scene(dev, v, idx, 3 * NT, NT, layouts[l], RTK_BUILD_QUALITY_MEDIUM, &g);
                /* (a deforming geometry keeps its tiny triangles, counted as zero-area ones; where a
                 * triangle goes beyond the range or comes back, the commit builds instead of refitting) */
                assert_int_equal(info_of(s).triangles_degenerate, g_flat);
                assert_int_equal(info_of(s).triangles_out_of_range, g_far);
                memcpy(v, odd, NT * 9 * sizeof *v);
                test_commit_moved(s, g);
                rtk_scene_info info = info_of(s);
                assert_int_equal(info.refits, moved_out ? 0 : 1);
                if (info.triangles_degenerate != flat + tiny || info.triangles_out_of_range != far)
                    fail_msg("%s, layout flags %u, scale 2^%d: %llu zero-area triangles and %llu outside the "
                             "range, the exact tests say %llu and %llu",
                             names[b], layouts[l], exps[e], (unsigned long long)info.triangles_degenerate,
                             (unsigned long long)info.triangles_out_of_range, (unsigned long long)(flat + tiny),
                             (unsigned long long)far);
                memcpy(v, generic, NT * 9 * sizeof *v);
                test_commit_moved(s, g);
                info = info_of(s);
                assert_int_equal(info.refits, moved_out ? 0 : 2);
                assert_int_equal(info.triangles_degenerate, g_flat);
                assert_int_equal(info.triangles_out_of_range, g_far);
                rtk_scene_release(s);
                rtk_device_release(dev);
            }
    }
    free(v);
    free(generic);
    free(odd);
    free(idx);
}

/* ---- API misuse gets a clear error ---- */

static void refit_api_errors(void **state)
{
    (void)state;
    rtk_device dev = test_device_threads("scalar", 1);
    rtk_scene s;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    assert_int_equal(rtk_scene_set_build_quality(s, RTK_BUILD_QUALITY_REFIT), RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "geometry"));
    rtk_geometry g;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_build_quality(g, (rtk_build_quality)7), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_geometry_set_build_quality(NULL, RTK_BUILD_QUALITY_REFIT), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_VERTEX), RTK_ERROR_INVALID_OPERATION);
    assert_int_equal(rtk_geometry_update_buffer(g, (rtk_buffer_type)5), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_geometry_update_buffer(NULL, RTK_BUFFER_TYPE_VERTEX), RTK_ERROR_INVALID_ARGUMENT);
    /* updated but not committed again: the scene says so */
    static const float v[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    static const uint32_t idx[3] = {0, 1, 2};
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, 3), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, idx, 0, 12, 1), RTK_OK);
    assert_int_equal(rtk_geometry_set_build_quality(g, RTK_BUILD_QUALITY_REFIT), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    assert_int_equal(rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_VERTEX), RTK_OK);
    assert_int_equal(rtk_scene_commit(s), RTK_ERROR_INVALID_OPERATION);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "not committed"));
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    assert_int_equal(info_of(s).refits, 1);
    rtk_geometry_release(g);
    rtk_scene_release(s);
    rtk_device_release(dev);
}

/* "quick": the tests whose refits run on several threads, for
 * ThreadSanitizer (scripts/test). */
int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(refit_matches_brute_force), cmocka_unit_test(refit_same_tree_any_threads),
        cmocka_unit_test(refit_or_build),            cmocka_unit_test(refit_onto_new_buffer),
        cmocka_unit_test(zero_area_never_hit),       cmocka_unit_test(zero_area_at_every_scale),
        cmocka_unit_test(refit_api_errors),
    };
    const struct CMUnitTest quick[] = {
        cmocka_unit_test(refit_same_tree_any_threads),
        cmocka_unit_test(refit_or_build),
    };
    if (argc > 1 && !strcmp(argv[1], "quick"))
        return cmocka_run_group_tests(quick, setup, teardown);
    return cmocka_run_group_tests(tests, setup, teardown);
}
