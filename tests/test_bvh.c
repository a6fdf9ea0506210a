/*
 * The BVH as data: rtk_scene_get_bvh, rtk_bvh_check, rtk_scene_commit_bvh.
 *
 * A tree exported and committed again must trace exactly like the scene it
 * came from, on every backend and layout, and export to the same arrays; a
 * tree that breaks any rule must be refused with a message, leave the scene
 * as it was, and never crash (a fuzz loop mutates valid trees at random).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh_import.h"
#include "testlib.h"

/* ---- helpers ---- */

static rtk_device best_device(void)
{
    rtk_device dev = NULL;
    if (rtk_device_new("", &dev) != RTK_OK)
        fail_msg("device: %s", rtk_device_get_error_message(NULL));
    return dev;
}

static rtk_ray random_ray(rng *r, const float lo[3], const float hi[3])
{
    float o[3], d[3];
    for (int k = 0; k < 3; k++) {
        const float e = hi[k] - lo[k];
        o[k] = lo[k] - 0.25f * e + 1.5f * e * rng_float(r);
        d[k] = 2.0f * rng_float(r) - 1.0f;
    }
    /* aim half the rays at a point inside the box, so they hit */
    if (rng_u32(r) & 1)
        for (int k = 0; k < 3; k++)
            d[k] = lo[k] + (hi[k] - lo[k]) * rng_float(r) - o[k];
    return test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY);
}

/* Traces n rays through both scenes; every field of every answer equal. */
static void assert_same_hits(rtk_scene a, rtk_scene b, const float lo[3], const float hi[3], int n, uint64_t seed)
{
    rng r = {seed};
    for (int i = 0; i < n; i++) {
        rtk_rayhit x = {.ray = random_ray(&r, lo, hi)};
        x.hit.geomID = x.hit.primID = RTK_INVALID_GEOMETRY_ID;
        rtk_rayhit y = x;
        assert_int_equal(rtk_intersect1(a, &x), RTK_OK);
        assert_int_equal(rtk_intersect1(b, &y), RTK_OK);
        if (memcmp(&x, &y, sizeof x)) {
            print_error("ray %d: org (%a %a %a) dir (%a %a %a): t %a/%a prim %u/%u geom %u/%u\n", i, x.ray.org_x,
                        x.ray.org_y, x.ray.org_z, x.ray.dir_x, x.ray.dir_y, x.ray.dir_z, x.ray.tfar, y.ray.tfar,
                        x.hit.primID, y.hit.primID, x.hit.geomID, y.hit.geomID);
            fail();
        }
        rtk_ray p = x.ray, q = x.ray;
        p.tfar = q.tfar = INFINITY;
        assert_int_equal(rtk_occluded1(a, &p), RTK_OK);
        assert_int_equal(rtk_occluded1(b, &q), RTK_OK);
        assert_memory_equal(&p, &q, sizeof p);
    }
}

static void assert_same_info(rtk_scene a, rtk_scene b)
{
    rtk_scene_info x = {.struct_size = sizeof x}, y = {.struct_size = sizeof y};
    assert_int_equal(rtk_scene_get_info(a, &x), RTK_OK);
    assert_int_equal(rtk_scene_get_info(b, &y), RTK_OK);
    assert_string_equal(x.layout, y.layout);
    assert_string_equal(y.builder, "tree");
    assert_int_equal(x.triangles, y.triangles);
    assert_int_equal(x.triangles_skipped, y.triangles_skipped);
    assert_int_equal(x.triangles_degenerate, y.triangles_degenerate);
    assert_int_equal(x.nodes, y.nodes);
    assert_int_equal(x.leaves, y.leaves);
    assert_int_equal(x.depth, y.depth);
    assert_int_equal(x.bytes, y.bytes);
    assert_true(x.sah_cost == y.sah_cost);
    assert_memory_equal(x.bounds_lower, y.bounds_lower, sizeof x.bounds_lower);
    assert_memory_equal(x.bounds_upper, y.bounds_upper, sizeof x.bounds_upper);
}

/* A scene of one geometry over the arrays, committed from `tree`. */
static rtk_error commit_tree(rtk_device dev, const float *v, size_t nv, const uint32_t *idx, size_t nt, unsigned flags,
                             const rtk_bvh *tree, rtk_scene *out)
{
    rtk_scene s = test_scene_uncommitted(dev, v, nv, idx, nt, flags);
    rtk_error err = rtk_scene_commit_bvh(s, tree);
    *out = s;
    return err;
}

/* Export, check, re-commit, compare: trees, statistics and hits. */
static void round_trip(rtk_device dev, const float *v, size_t nv, const uint32_t *idx, size_t nt, unsigned flags,
                       int rays)
{
    rtk_scene a = test_scene_flags(dev, v, nv, idx, nt, flags);
    rtk_bvh t = {.struct_size = sizeof t};
    assert_int_equal(rtk_scene_get_bvh(a, &t), RTK_OK);
    char msg[256] = "";
    if (rtk_bvh_check(&t, msg, sizeof msg) != RTK_OK) {
        print_error("exported tree fails the check: %s\n", msg);
        fail();
    }
    rtk_scene b = NULL;
    if (commit_tree(dev, v, nv, idx, nt, flags, &t, &b) != RTK_OK) {
        print_error("commit_bvh: %s\n", rtk_device_get_error_message(dev));
        fail();
    }
    assert_same_info(a, b);
    rtk_bvh u = {.struct_size = sizeof u};
    assert_int_equal(rtk_scene_get_bvh(b, &u), RTK_OK);
    test_assert_same_tree(&t, &u);
    rtk_scene_info info = {.struct_size = sizeof info};
    rtk_scene_get_info(a, &info);
    assert_same_hits(a, b, info.bounds_lower, info.bounds_upper, rays, 7);
    rtk_bvh_free(&t);
    rtk_bvh_free(&u);
    rtk_scene_release(a);
    rtk_scene_release(b);
}

/* ---- round trips ---- */

static rtk_mesh bunny;

static int load_bunny(void **state)
{
    (void)state;
    return test_load_shared_mesh("bunny.ply", &bunny);
}

static int free_bunny(void **state)
{
    (void)state;
    rtk_mesh_free(&bunny);
    return 0;
}

static void test_round_trip_bunny(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t i = 0; i < nb; i++) {
        rtk_device dev = test_device(names[i]);
        round_trip(dev, bunny.vertices, bunny.vertex_count, bunny.indices, bunny.triangle_count, 0, 20000);
        round_trip(dev, bunny.vertices, bunny.vertex_count, bunny.indices, bunny.triangle_count,
                   RTK_SCENE_FLAG_COMPACT, 20000);
        rtk_device_release(dev);
    }
}

/* Random triangles in a unit cube, with a few that can never be hit. */
static void random_mesh(rng *r, size_t nt, float **v, uint32_t **idx)
{
    *v = malloc(nt * 9 * sizeof(float));
    *idx = malloc(nt * 3 * sizeof(uint32_t));
    for (size_t t = 0; t < nt; t++) {
        float c[3] = {rng_float(r), rng_float(r), rng_float(r)};
        for (int k = 0; k < 9; k++)
            (*v)[9 * t + k] = c[k % 3] + 0.05f * (rng_float(r) - 0.5f);
        for (int k = 0; k < 3; k++)
            (*idx)[3 * t + k] = (uint32_t)(3 * t + k);
    }
    if (nt > 10) {
        (*v)[9 * 3 + 4] = NAN;                         /* triangle 3: a NaN vertex */
        memcpy(&(*v)[9 * 7 + 3], &(*v)[9 * 7], 12);    /* triangle 7: two equal vertices */
    }
}

/* Sizes around the leaf and node limits: empty, a root leaf, one node,
 * several levels. */
static void test_round_trip_sizes(void **state)
{
    (void)state;
    static const size_t sizes[] = {0, 1, 3, 4, 5, 16, 17, 100, 3000};
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t s = 0; s < sizeof sizes / sizeof *sizes; s++) {
        rng r = {1000 + s};
        float *v;
        uint32_t *idx;
        random_mesh(&r, sizes[s], &v, &idx);
        for (size_t i = 0; i < nb; i++) {
            rtk_device dev = test_device(names[i]);
            round_trip(dev, v, 3 * sizes[s], idx, sizes[s], 0, 2000);
            round_trip(dev, v, 3 * sizes[s], idx, sizes[s], RTK_SCENE_FLAG_COMPACT, 2000);
            rtk_device_release(dev);
        }
        free(v);
        free(idx);
    }
}

/* Several geometries with gaps in their ids and a disabled one: prims keep
 * the application's geometry ids. */
static void test_round_trip_geometries(void **state)
{
    (void)state;
    rng r = {99};
    float *v[3];
    uint32_t *idx[3];
    for (int g = 0; g < 3; g++)
        random_mesh(&r, 200, &v[g], &idx[g]);
    rtk_device dev = best_device();
    rtk_scene a, b;
    assert_int_equal(rtk_scene_new(dev, &a), RTK_OK);
    assert_int_equal(rtk_scene_new(dev, &b), RTK_OK);
    rtk_geometry gs[4];
    for (int g = 0; g < 4; g++) {
        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &gs[g]), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer(gs[g], RTK_BUFFER_TYPE_VERTEX, v[g % 3], 0, 12, 600), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer(gs[g], RTK_BUFFER_TYPE_INDEX, idx[g % 3], 0, 12, 200), RTK_OK);
        assert_int_equal(rtk_geometry_commit(gs[g]), RTK_OK);
        uint32_t id;
        assert_int_equal(rtk_scene_attach_geometry(a, gs[g], &id), RTK_OK);
        assert_int_equal(rtk_scene_attach_geometry(b, gs[g], &id), RTK_OK);
    }
    assert_int_equal(rtk_scene_detach_geometry(a, 1), RTK_OK);
    assert_int_equal(rtk_scene_detach_geometry(b, 1), RTK_OK);
    assert_int_equal(rtk_geometry_disable(gs[2]), RTK_OK);
    assert_int_equal(rtk_scene_commit(a), RTK_OK);
    rtk_bvh t = {.struct_size = sizeof t};
    assert_int_equal(rtk_scene_get_bvh(a, &t), RTK_OK);
    int seen[4] = {0};
    for (uint64_t k = 0; k < t.prim_count; k++)
        seen[t.prims[k].geom_id]++;
    assert_int_equal(seen[1], 0);
    assert_int_equal(seen[2], 0);
    assert_int_equal(seen[0], 198);
    assert_int_equal(seen[3], 198);
    assert_int_equal(rtk_scene_commit_bvh(b, &t), RTK_OK);
    assert_same_info(a, b);
    const float lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1};
    assert_same_hits(a, b, lo, hi, 5000, 3);

    /* Enabling geometry 2 makes the tree miss its triangles. */
    assert_int_equal(rtk_geometry_enable(gs[2]), RTK_OK);
    assert_int_equal(rtk_scene_commit_bvh(b, &t), RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "of geometry 2 can be hit but is not in the tree"));
    rtk_bvh_free(&t);
    for (int g = 0; g < 4; g++)
        rtk_geometry_release(gs[g]);
    rtk_scene_release(a);
    rtk_scene_release(b);
    rtk_device_release(dev);
    for (int g = 0; g < 3; g++) {
        free(v[g]);
        free(idx[g]);
    }
}

/* ---- refusals ---- */

typedef struct fixture {
    rtk_device dev;
    float *v;
    uint32_t *idx;
    size_t nt;
    rtk_scene good; /* committed normally */
    rtk_bvh tree;   /* its tree */
} fixture;

static fixture fx;

static int setup_fixture(void **state)
{
    (void)state;
    rng r = {5};
    fx.nt = 300;
    random_mesh(&r, fx.nt, &fx.v, &fx.idx);
    fx.dev = best_device();
    fx.good = test_scene(fx.dev, fx.v, 3 * fx.nt, fx.idx, fx.nt);
    fx.tree = (rtk_bvh){.struct_size = sizeof fx.tree};
    return rtk_scene_get_bvh(fx.good, &fx.tree) == RTK_OK && fx.tree.node_count > 2 ? 0 : -1;
}

static int teardown_fixture(void **state)
{
    (void)state;
    rtk_bvh_free(&fx.tree);
    rtk_scene_release(fx.good);
    rtk_device_release(fx.dev);
    free(fx.v);
    free(fx.idx);
    return 0;
}

/* A deep copy of the fixture's tree, to damage. */
static rtk_bvh copy_tree(const rtk_bvh *t)
{
    rtk_bvh c = *t;
    const size_t slots = (size_t)t->node_count * t->width;
    c.children = malloc(slots * sizeof *c.children + 1);
    c.child_lower = malloc(slots * 12 + 1);
    c.child_upper = malloc(slots * 12 + 1);
    c.leaf_first = malloc((t->leaf_count + 1) * sizeof *c.leaf_first);
    c.prims = malloc(t->prim_count * sizeof *c.prims + 1);
    memcpy(c.children, t->children, slots * sizeof *c.children);
    memcpy(c.child_lower, t->child_lower, slots * 12);
    memcpy(c.child_upper, t->child_upper, slots * 12);
    memcpy(c.leaf_first, t->leaf_first, (t->leaf_count + 1) * sizeof *c.leaf_first);
    memcpy(c.prims, t->prims, t->prim_count * sizeof *c.prims);
    return c;
}

static void free_copy(rtk_bvh *c)
{
    free(c->children);
    free(c->child_lower);
    free(c->child_upper);
    free(c->leaf_first);
    free(c->prims);
}

/* The first slot of `node` holding a leaf (or an inner node), or -1. */
static int64_t find_slot(const rtk_bvh *t, uint64_t node, int leaf)
{
    for (uint32_t c = 0; c < t->width; c++) {
        const uint32_t ref = t->children[node * t->width + c];
        if (ref != RTK_BVH_EMPTY && !!(ref & RTK_BVH_LEAF_BIT) == leaf)
            return (int64_t)(node * t->width + c);
    }
    return -1;
}

enum damage {
    D_WIDTH,
    D_STRUCT_SIZE,
    D_ROOT,
    D_NODE_OUT_OF_RANGE,
    D_NODE_BACKWARDS,
    D_NODE_TWICE,
    D_LEAF_OUT_OF_RANGE,
    D_LEAF_TWICE,
    D_BOX_NAN,
    D_BOX_INVERTED,
    D_BOX_NOT_CONTAINING,
    D_LEAF_BOX_TOO_SMALL,
    D_LEAF_RANGE,
    D_PRIM_GEOM,
    D_PRIM_RANGE,
    D_PRIM_MISSING,
    D_PRIM_UNHITTABLE,
    D_NODE_NO_CHILDREN,
    D_COUNT
};

static const char *const damage_text[D_COUNT] = {
    "width 5", "struct_size", "root 1", "does not exist", "does not come after its parent", "is referenced twice",
    "does not exist", "is referenced twice", "not finite or not ordered", "not finite or not ordered",
    "does not contain slot", "do not cover it", "empty or its range runs backwards", "not attached",
    "has no triangle", "can be hit but is not in the tree", "can never be hit", "has no children",
};

static void apply_damage(rtk_bvh *t, enum damage d)
{
    const int64_t leaf_slot = find_slot(t, 1, 1), node_slot = find_slot(t, 0, 0);
    assert_true(leaf_slot >= 0 && node_slot >= 0);
    switch (d) {
    case D_WIDTH: t->width = 5; break;
    case D_STRUCT_SIZE: t->struct_size = 8; break;
    case D_ROOT: t->root = 1; break;
    case D_NODE_OUT_OF_RANGE: t->children[node_slot] = (uint32_t)t->node_count; break;
    case D_NODE_BACKWARDS: t->children[find_slot(t, 1, 0) >= 0 ? find_slot(t, 1, 0) : leaf_slot] = 0; break;
    case D_NODE_TWICE: {
        const int64_t other = find_slot(t, 0, 1) >= 0 ? find_slot(t, 0, 1) : (int64_t)(node_slot + 1);
        t->children[other] = t->children[node_slot];
        break;
    }
    case D_LEAF_OUT_OF_RANGE: t->children[leaf_slot] = RTK_BVH_LEAF_BIT | (uint32_t)t->leaf_count; break;
    case D_LEAF_TWICE: { /* the second leaf slot of the tree points at the first one's leaf */
        int64_t first = -1;
        for (uint64_t k = 0; k < t->node_count * t->width; k++)
            if (t->children[k] != RTK_BVH_EMPTY && (t->children[k] & RTK_BVH_LEAF_BIT)) {
                if (first < 0) {
                    first = (int64_t)k;
                } else {
                    t->children[k] = t->children[first];
                    break;
                }
            }
        break;
    }
    case D_BOX_NAN: t->child_lower[3 * leaf_slot + 1] = NAN; break;
    case D_BOX_INVERTED: t->child_lower[3 * leaf_slot] = t->child_upper[3 * leaf_slot] + 1.0f; break;
    case D_BOX_NOT_CONTAINING: t->child_upper[3 * node_slot + 2] = -10.0f; t->child_lower[3 * node_slot + 2] = -11.0f;
        break;
    case D_LEAF_BOX_TOO_SMALL: {
        /* shrink the leaf's box to a point at its lower corner (still inside its parent's box) */
        for (int k = 0; k < 3; k++)
            t->child_upper[3 * leaf_slot + k] = t->child_lower[3 * leaf_slot + k];
        break;
    }
    case D_LEAF_RANGE: t->leaf_first[1] = t->leaf_first[2]; break;
    case D_PRIM_GEOM: t->prims[0].geom_id = 7; break;
    case D_PRIM_RANGE: t->prims[0].prim_id = 1000; break;
    case D_PRIM_MISSING: t->prims[1] = t->prims[0]; break; /* twice is allowed, missing is not */
    case D_PRIM_UNHITTABLE: {
        for (uint64_t k = 0; k < t->prim_count; k++)
            if (t->prims[k].prim_id == 5)
                t->prims[k].prim_id = 3; /* the NaN triangle, in 5's place */
        break;
    }
    case D_NODE_NO_CHILDREN: {
        const uint32_t n = t->children[node_slot];
        for (uint32_t c = 0; c < t->width; c++)
            t->children[(uint64_t)n * t->width + c] = RTK_BVH_EMPTY;
        break;
    }
    case D_COUNT: break;
    }
}

/* High quality: spatial splits put a triangle in several leaves, each under
 * a box that holds only its part.  Such trees round-trip, and the check
 * finds a part whose box no longer covers it. */
static void test_round_trip_spatial(void **state)
{
    (void)state;
    rng r = {31};
    float *v;
    uint32_t *idx;
    const size_t nt = 3000;
    test_sticks_mesh(&r, nt, 1.0f, 0.0f, &v, &idx);
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t i = 0; i < nb; i++)
        for (int f = 0; f < 2; f++) {
            const unsigned flags = f ? RTK_SCENE_FLAG_COMPACT : 0;
            rtk_device dev = test_device(names[i]);
            rtk_scene a = test_scene_uncommitted(dev, v, 3 * nt, idx, nt, flags);
            assert_int_equal(rtk_scene_set_build_quality(a, RTK_BUILD_QUALITY_HIGH), RTK_OK);
            assert_int_equal(rtk_scene_commit(a), RTK_OK);
            rtk_scene_info info = {.struct_size = sizeof info};
            assert_int_equal(rtk_scene_get_info(a, &info), RTK_OK);
            assert_true(info.references > info.triangles);
            rtk_bvh t = {.struct_size = sizeof t};
            assert_int_equal(rtk_scene_get_bvh(a, &t), RTK_OK);
            assert_int_equal(t.prim_count, info.references);
            rtk_scene b = NULL;
            if (commit_tree(dev, v, 3 * nt, idx, nt, flags, &t, &b) != RTK_OK)
                fail_msg("commit_bvh: %s", rtk_device_get_error_message(dev));
            assert_same_info(a, b);
            rtk_scene_info binfo = {.struct_size = sizeof binfo};
            assert_int_equal(rtk_scene_get_info(b, &binfo), RTK_OK);
            assert_int_equal(binfo.references, info.references);
            const float lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1};
            assert_same_hits(a, b, lo, hi, 5000, 3);
            /* a leaf box of a triangle held in parts, shrunk to its lower
             * corner (still inside its parent's box): not covered */
            int64_t slot = -1;
            for (uint64_t k = 0; k < t.node_count * t.width && slot < 0; k++) {
                const uint32_t ref = t.children[k];
                if (ref == RTK_BVH_EMPTY || !(ref & RTK_BVH_LEAF_BIT))
                    continue;
                const uint32_t leaf = ref & ~RTK_BVH_LEAF_BIT;
                for (uint64_t p = t.leaf_first[leaf]; p < t.leaf_first[leaf + 1] && slot < 0; p++) {
                    const float *tv = v + 9 * t.prims[p].prim_id;
                    for (int m = 0; m < 3 && slot < 0; m++)
                        for (int a2 = 0; a2 < 3; a2++)
                            if (tv[3 * m + a2] < t.child_lower[3 * k + a2] || tv[3 * m + a2] > t.child_upper[3 * k + a2])
                                slot = (int64_t)k;
                }
            }
            assert_true(slot >= 0);
            rtk_bvh c = copy_tree(&t);
            for (int a2 = 0; a2 < 3; a2++)
                c.child_upper[3 * slot + a2] = c.child_lower[3 * slot + a2];
            assert_int_equal(rtk_scene_commit_bvh(b, &c), RTK_ERROR_INVALID_ARGUMENT);
            assert_non_null(strstr(rtk_device_get_error_message(dev), "do not cover it"));
            free_copy(&c);
            rtk_bvh_free(&t);
            rtk_scene_release(a);
            rtk_scene_release(b);
            rtk_device_release(dev);
        }
    free(v);
    free(idx);
}

/* A tree of 4-wide nodes over leaves [first, end), leaf j under the slab
 * x in [j, j + 1) / count of box lo..hi; nodes are numbered before their
 * children.  Returns the reference. */
static uint32_t slab_tree(rtk_bvh *t, uint32_t first, uint32_t end, uint32_t count, const float lo[3],
                          const float hi[3])
{
    if (end - first == 1)
        return RTK_BVH_LEAF_BIT | first;
    const uint32_t node = (uint32_t)t->node_count++;
    for (uint32_t c = 0; c < 4; c++) {
        const uint32_t a = first + (end - first) * c / 4, b = first + (end - first) * (c + 1) / 4;
        const uint64_t slot = (uint64_t)node * 4 + c;
        t->children[slot] = RTK_BVH_EMPTY;
        if (a == b)
            continue;
        t->children[slot] = slab_tree(t, a, b, count, lo, hi);
        for (int k = 0; k < 3; k++) {
            t->child_lower[3 * slot + k] = lo[k];
            t->child_upper[3 * slot + k] = hi[k];
        }
        t->child_lower[3 * slot] = lo[0] + (hi[0] - lo[0]) * (float)a / (float)count;
        t->child_upper[3 * slot] = lo[0] + (hi[0] - lo[0]) * (float)b / (float)count;
    }
    return node;
}

/* One triangle held in 200 leaves, each under a slab of it: the coverage
 * check has no limit of its own on the parts (San Miguel's high-quality
 * tree puts one triangle in 30 leaves), and still finds a missing slab. */
static void test_many_parts(void **state)
{
    (void)state;
    enum { SLABS = 200 };
    static const float v[9] = {0, 0, 0, 1, 0.2f, 0.1f, 0.3f, 1, 0.6f};
    static const uint32_t idx[3] = {0, 1, 2};
    const float lo[3] = {0, 0, 0}, hi[3] = {1, 1, 0.6f};
    rtk_bvh t = {.struct_size = sizeof t, .width = 4}; /* SLABS nodes are more than enough */
    t.children = malloc(SLABS * 4 * sizeof *t.children);
    t.child_lower = malloc(SLABS * 4 * 3 * sizeof(float));
    t.child_upper = malloc(SLABS * 4 * 3 * sizeof(float));
    t.leaf_first = malloc((SLABS + 1) * sizeof *t.leaf_first);
    t.prims = malloc(SLABS * sizeof *t.prims);
    assert_true(t.children && t.child_lower && t.child_upper && t.leaf_first && t.prims);
    t.root = slab_tree(&t, 0, SLABS, SLABS, lo, hi);
    t.leaf_count = t.prim_count = SLABS;
    for (uint32_t j = 0; j <= SLABS; j++)
        t.leaf_first[j] = j;
    for (uint32_t j = 0; j < SLABS; j++)
        t.prims[j] = (rtk_bvh_prim){0, 0};
    char msg[256] = "";
    if (rtk_bvh_check(&t, msg, sizeof msg) != RTK_OK)
        fail_msg("the slab tree fails the check: %s", msg);
    rtk_device dev = best_device();
    rtk_scene a = test_scene_flags(dev, v, 3, idx, 1, RTK_SCENE_FLAG_COMPACT), b = NULL;
    if (commit_tree(dev, v, 3, idx, 1, RTK_SCENE_FLAG_COMPACT, &t, &b) != RTK_OK)
        fail_msg("commit_bvh: %s", rtk_device_get_error_message(dev));
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(b, &info), RTK_OK);
    assert_int_equal(info.triangles, 1);
    assert_int_equal(info.references, SLABS);
    assert_same_hits(a, b, lo, hi, 2000, 5);
    /* slab 117 narrowed to half its width: the triangle is not covered */
    for (uint64_t s = 0; s < t.node_count * 4; s++)
        if (t.children[s] == (RTK_BVH_LEAF_BIT | 117))
            t.child_upper[3 * s] = 0.5f * (t.child_lower[3 * s] + t.child_upper[3 * s]);
    assert_int_equal(rtk_scene_commit_bvh(b, &t), RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "do not cover it"));
    free_copy(&t);
    rtk_scene_release(a);
    rtk_scene_release(b);
    rtk_device_release(dev);
}

static void test_refusals(void **state)
{
    (void)state;
    rtk_scene s = NULL;
    /* a scene committed normally first, to show a refusal keeps it */
    rtk_scene_info before = {.struct_size = sizeof before}, after = {.struct_size = sizeof after};
    for (int d = 0; d < D_COUNT; d++) {
        rtk_bvh c = copy_tree(&fx.tree);
        apply_damage(&c, (enum damage)d);
        if (!s) {
            assert_int_equal(commit_tree(fx.dev, fx.v, 3 * fx.nt, fx.idx, fx.nt, 0, &fx.tree, &s), RTK_OK);
            assert_int_equal(rtk_scene_get_info(s, &before), RTK_OK);
        }
        const rtk_error err = rtk_scene_commit_bvh(s, &c);
        const char *msg = rtk_device_get_error_message(fx.dev);
        if (err != RTK_ERROR_INVALID_ARGUMENT || !strstr(msg, damage_text[d])) {
            print_error("damage %d: error %d, message '%s', wanted '%s'\n", d, err, msg, damage_text[d]);
            fail();
        }
        assert_int_equal(rtk_scene_get_info(s, &after), RTK_OK);
        assert_memory_equal(&before, &after, sizeof before);
        free_copy(&c);
    }
    const float lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1};
    assert_same_hits(fx.good, s, lo, hi, 2000, 11);
    assert_int_equal(rtk_scene_commit_bvh(s, NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_bvh_check(NULL, NULL, 0), RTK_ERROR_INVALID_ARGUMENT);
    rtk_bvh small = {.struct_size = sizeof small};
    assert_int_equal(rtk_scene_get_bvh(NULL, &small), RTK_ERROR_INVALID_ARGUMENT);
    small.struct_size = 4;
    assert_int_equal(rtk_scene_get_bvh(s, &small), RTK_ERROR_INVALID_ARGUMENT);
    rtk_scene_release(s);

    /* Width against the layout: a bvh4 tree into a bvh8 layout or back. */
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t i = 0; i < nb; i++) {
        rtk_device dev = test_device(names[i]);
        rtk_scene a = test_scene(dev, fx.v, 3 * fx.nt, fx.idx, fx.nt);
        rtk_bvh t = {.struct_size = sizeof t};
        assert_int_equal(rtk_scene_get_bvh(a, &t), RTK_OK);
        rtk_scene b = NULL;
        const rtk_error err = commit_tree(dev, fx.v, 3 * fx.nt, fx.idx, fx.nt, RTK_SCENE_FLAG_COMPACT, &t, &b);
        if (t.width == 8) { /* compact layouts are 4 wide */
            assert_int_equal(err, RTK_ERROR_INVALID_ARGUMENT);
            assert_non_null(strstr(rtk_device_get_error_message(dev), "8-wide nodes, the layout 4-wide"));
        } else {
            assert_int_equal(err, RTK_OK);
        }
        rtk_bvh_free(&t);
        rtk_scene_release(a);
        rtk_scene_release(b);
        rtk_device_release(dev);
    }
}

/* A leaf of more than 16 triangles: a valid tree, but not for these layouts. */
static void test_leaf_too_big(void **state)
{
    (void)state;
    rng r = {8};
    float *v;
    uint32_t *idx;
    random_mesh(&r, 20, &v, &idx);
    rtk_device dev = best_device();
    float lo[3] = {-1, -1, -1}, hi[3] = {2, 2, 2};
    uint32_t children[8] = {RTK_BVH_LEAF_BIT, RTK_BVH_EMPTY, RTK_BVH_EMPTY, RTK_BVH_EMPTY,
                            RTK_BVH_EMPTY,    RTK_BVH_EMPTY, RTK_BVH_EMPTY, RTK_BVH_EMPTY};
    float los[24], his[24];
    for (int k = 0; k < 24; k++)
        los[k] = lo[k % 3], his[k] = hi[k % 3];
    rtk_bvh_prim prims[18];
    uint32_t n = 0;
    for (uint32_t p = 0; p < 20; p++)
        if (p != 3 && p != 7)
            prims[n++] = (rtk_bvh_prim){0, p};
    uint64_t first[2] = {0, n};
    rtk_scene s0 = test_scene(dev, v, 60, idx, 20);
    rtk_scene_info info = {.struct_size = sizeof info};
    rtk_scene_get_info(s0, &info);
    const uint32_t width = strstr(info.layout, "bvh8") ? 8 : 4;
    rtk_bvh t = {.struct_size = sizeof t, .width = width, .root = 0, .node_count = 1, .leaf_count = 1,
                 .prim_count = n, .child_lower = los, .child_upper = his, .children = children,
                 .leaf_first = first, .prims = prims};
    char msg[256];
    assert_int_equal(rtk_bvh_check(&t, msg, sizeof msg), RTK_OK);
    rtk_scene s = NULL;
    assert_int_equal(commit_tree(dev, v, 60, idx, 20, 0, &t, &s), RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "holds 18 triangles"));
    /* Split in two leaves of 9 it is fine, and traces like the built scene. */
    children[1] = RTK_BVH_LEAF_BIT | 1;
    uint64_t first2[3] = {0, 9, n};
    t.leaf_first = first2;
    t.leaf_count = 2;
    assert_int_equal(rtk_scene_commit_bvh(s, &t), RTK_OK);
    const float blo[3] = {0, 0, 0}, bhi[3] = {1, 1, 1};
    assert_same_hits(s0, s, blo, bhi, 3000, 5);
    rtk_scene_release(s);
    rtk_scene_release(s0);
    rtk_device_release(dev);
    free(v);
    free(idx);
}

/* Random damage: any byte of any array, many times.  The commit either
 * refuses or, when the change left a valid tree (a box grown, leaves
 * reordered), traces exactly as before, ties aside (random triangles have
 * none). */
static void test_fuzz(void **state)
{
    (void)state;
    rng r = {2024};
    rtk_scene s = NULL;
    assert_int_equal(commit_tree(fx.dev, fx.v, 3 * fx.nt, fx.idx, fx.nt, 0, &fx.tree, &s), RTK_OK);
    int accepted = 0;
    const float lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1};
    for (int iter = 0; iter < 3000; iter++) {
        rtk_bvh c = copy_tree(&fx.tree);
        const int edits = 1 + (int)(rng_u32(&r) % 3);
        for (int e = 0; e < edits; e++) {
            const uint32_t which = rng_u32(&r) % 5;
            unsigned char *base;
            size_t bytes;
            const size_t slots = (size_t)c.node_count * c.width;
            switch (which) {
            case 0: base = (unsigned char *)c.children; bytes = slots * 4; break;
            case 1: base = (unsigned char *)c.child_lower; bytes = slots * 12; break;
            case 2: base = (unsigned char *)c.child_upper; bytes = slots * 12; break;
            case 3: base = (unsigned char *)c.leaf_first; bytes = (c.leaf_count + 1) * 8; break;
            default: base = (unsigned char *)c.prims; bytes = c.prim_count * 8; break;
            }
            const size_t at = rng_u32(&r) % bytes;
            if (rng_u32(&r) & 1)
                base[at] ^= (unsigned char)(1u << (rng_u32(&r) % 8));
            else
                base[at] = (unsigned char)rng_u32(&r);
        }
        rtk_error err = rtk_scene_commit_bvh(s, &c);
        if (err == RTK_OK) {
            accepted++;
            assert_same_hits(fx.good, s, lo, hi, 200, (uint64_t)iter);
        } else {
            assert_int_equal(err, RTK_ERROR_INVALID_ARGUMENT);
        }
        free_copy(&c);
    }
    print_message("fuzz: %d of 3000 damaged trees accepted (and traced like the original)\n", accepted);
    rtk_scene_release(s);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_round_trip_bunny, load_bunny, free_bunny),
        cmocka_unit_test(test_round_trip_sizes),
        cmocka_unit_test(test_round_trip_geometries),
        cmocka_unit_test(test_round_trip_spatial),
        cmocka_unit_test(test_many_parts),
        cmocka_unit_test(test_leaf_too_big),
        cmocka_unit_test(test_refusals),
        cmocka_unit_test(test_fuzz),
    };
    return cmocka_run_group_tests(tests, setup_fixture, teardown_fixture);
}
