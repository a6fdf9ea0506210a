#include "testlib.h"
#include "mesh_import.h"

#include <dirent.h>
#include <sys/stat.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifndef RTK_TEST_UNINSTRUMENTED
#define RTK_TEST_UNINSTRUMENTED ",,"
#endif

static int left_out(const char *name)
{
    char key[40];
    snprintf(key, sizeof key, ",%s,", name);
    return strstr(RTK_TEST_UNINSTRUMENTED, key) != NULL;
}

size_t test_backends_left_out(void)
{
    size_t n = 0; /* names: ",a,b," */
    for (const char *c = RTK_TEST_UNINSTRUMENTED; *c; c++)
        n += c[0] == ',' && c[1] && c[1] != ',';
    return n;
}

size_t test_backend_names(char names[][32], size_t max)
{
    rtk_device dev = NULL;
    if (rtk_device_new(NULL, &dev) != RTK_OK) {
        fail_msg("no device: %s", rtk_device_get_error_message(NULL));
        return 0;
    }
    /* the device lists them in file-name order (avx, avx2, scalar, sse41);
     * sorted here by the CPU features each needs, which grow from one
     * backend to the next, so that the best comes last */
    size_t n = 0;
    int needs[64];
    for (size_t i = 0; i < rtk_device_get_backend_count(dev) && n < max && n < 64; i++) {
        rtk_backend_info bi = {.struct_size = sizeof bi};
        assert_int_equal(rtk_device_get_backend_info(dev, i, &bi), RTK_OK);
        if (bi.status == RTK_BACKEND_STATUS_REJECTED || left_out(bi.name))
            continue;
        const int k = __builtin_popcountll(bi.cpu_requires);
        size_t j = n++;
        for (; j > 0 && needs[j - 1] > k; j--) {
            needs[j] = needs[j - 1];
            memcpy(names[j], names[j - 1], 32);
        }
        needs[j] = k;
        snprintf(names[j], 32, "%s", bi.name);
    }
    rtk_device_release(dev);
    return n;
}

rtk_device test_device(const char *isa)
{
    char config[64];
    snprintf(config, sizeof config, "isa=%s", isa);
    rtk_device dev = NULL;
    rtk_error err = rtk_device_new(config, &dev);
    if (err != RTK_OK)
        fail_msg("device isa=%s: %s", isa, rtk_device_get_error_message(NULL));
    assert_string_equal(rtk_device_get_backend_name(dev), isa);
    return dev;
}

rtk_device test_device_threads(const char *isa, int threads)
{
    char config[64];
    snprintf(config, sizeof config, "isa=%s,threads=%d", isa, threads);
    rtk_device dev = NULL;
    if (rtk_device_new(config, &dev) != RTK_OK)
        fail_msg("device %s: %s", config, rtk_device_get_error_message(NULL));
    return dev;
}

int test_ray_vs_reference(rtk_scene s, const ref_mesh *ref, rtk_ray ray)
{
    rtk_rayhit rh = {.ray = ray};
    rh.hit.geomID = rh.hit.primID = RTK_INVALID_GEOMETRY_ID;
    assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
    rtk_ray shadow = ray;
    assert_int_equal(rtk_occluded1(s, &shadow), RTK_OK);
    rtk_tri_hit want;
    uint32_t prim;
    const int hit = ref->count ? ref_closest(ref, &ray, &want, &prim) : 0;
    assert_int_equal(rh.hit.geomID != RTK_INVALID_GEOMETRY_ID, hit);
    assert_int_equal(shadow.tfar == -INFINITY, hit);
    if (hit) {
        assert_true(rh.ray.tfar == want.t);
        rtk_tri_hit other; /* a tie in t: the other triangle must give the same t */
        assert_true(rh.hit.primID == prim || (ref_one(ref, rh.hit.primID, &ray, &other) && other.t == want.t));
    }
    return hit;
}

rtk_scene test_scene(rtk_device dev, const float *v, size_t nv, const uint32_t *idx, size_t nt)
{
    return test_scene_flags(dev, v, nv, idx, nt, RTK_SCENE_FLAG_NONE);
}

rtk_scene test_scene_uncommitted(rtk_device dev, const float *v, size_t nv, const uint32_t *idx, size_t nt,
                                 unsigned flags)
{
    rtk_scene scene = NULL;
    rtk_geometry g = NULL;
    assert_int_equal(rtk_scene_new(dev, &scene), RTK_OK);
    assert_int_equal(rtk_scene_set_flags(scene, flags), RTK_OK);
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, nv), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, idx, 0, 12, nt), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(scene, g, NULL), RTK_OK);
    rtk_geometry_release(g);
    return scene;
}

uint32_t test_attach_instance(rtk_device dev, rtk_scene outer, rtk_scene inner, const float *xfm)
{
    rtk_geometry inst;
    uint32_t id;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &inst), RTK_OK);
    assert_int_equal(rtk_geometry_set_instanced_scene(inst, inner), RTK_OK);
    if (xfm)
        assert_int_equal(rtk_geometry_set_transform(inst, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, xfm), RTK_OK);
    assert_int_equal(rtk_geometry_commit(inst), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(outer, inst, &id), RTK_OK);
    rtk_geometry_release(inst);
    return id;
}

rtk_scene test_instancing_scene(rtk_device dev, rtk_scene inner)
{
    rtk_scene outer;
    assert_int_equal(rtk_scene_new(dev, &outer), RTK_OK);
    test_attach_instance(dev, outer, inner, NULL);
    return outer;
}

static void user_box_bounds(const rtk_bounds_args *a)
{
    for (int k = 0; k < 3; k++) {
        a->lower[k] = 0;
        a->upper[k] = 1;
    }
}

static void user_nothing(const rtk_user_query_args *a) { (void)a; }

rtk_geometry test_user_geometry(rtk_device dev, uint32_t count, void *user, rtk_bounds_fn bounds,
                                rtk_user_query_fn intersect, rtk_user_query_fn occluded)
{
    rtk_geometry g;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_USER, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_user_primitive_count(g, count), RTK_OK);
    assert_int_equal(rtk_geometry_set_user_data(g, user), RTK_OK);
    assert_int_equal(rtk_geometry_set_bounds_function(g, bounds), RTK_OK);
    assert_int_equal(rtk_geometry_set_intersect_function(g, intersect), RTK_OK);
    assert_int_equal(rtk_geometry_set_occluded_function(g, occluded), RTK_OK);
    return g;
}

rtk_scene test_user_geometry_scene(rtk_device dev, uint32_t count, rtk_bounds_fn bounds, rtk_user_query_fn intersect,
                                   rtk_user_query_fn occluded)
{
    rtk_scene s;
    assert_int_equal(rtk_scene_new(dev, &s), RTK_OK);
    rtk_geometry g = test_user_geometry(dev, count, NULL, bounds, intersect, occluded);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(s, g, NULL), RTK_OK);
    rtk_geometry_release(g);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    return s;
}

rtk_scene test_user_scene(rtk_device dev)
{
    return test_user_geometry_scene(dev, 1, user_box_bounds, user_nothing, user_nothing);
}

void test_commit_moved(rtk_scene s, rtk_geometry g)
{
    assert_int_equal(rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_VERTEX), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
}

int test_rays_vs_brute_force(rtk_scene s, const float *v, const uint32_t *idx, size_t nt, int count, uint64_t seed)
{
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
    ref_mesh ref = ref_prepare(v, idx, nt);
    rng r = {seed};
    int hits = 0;
    for (int i = 0; i < count; i++) {
        float o[3], d[3];
        for (int k = 0; k < 3; k++) {
            const float mid = 0.5f * (info.bounds_lower[k] + info.bounds_upper[k]);
            const float size = info.bounds_upper[k] - info.bounds_lower[k];
            o[k] = mid + size * (2.0f * rng_float(&r) - 1.0f);
            d[k] = mid + 0.3f * size * (rng_float(&r) - 0.5f) - o[k];
        }
        hits += test_ray_vs_reference(s, &ref, test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY));
    }
    ref_free(&ref);
    return hits;
}

rtk_scene test_scene_flags(rtk_device dev, const float *v, size_t nv, const uint32_t *idx, size_t nt, unsigned flags)
{
    rtk_scene scene = test_scene_uncommitted(dev, v, nv, idx, nt, flags);
    if (rtk_scene_commit(scene) != RTK_OK)
        fail_msg("commit: %s", rtk_device_get_error_message(dev));
    return scene;
}

/* ref_closest's answers: an open-addressed table keyed by the ray's bits. */
typedef struct ref_answer {
    uint32_t key[9]; /* org, dir, tnear, tfar, watertight */
    int used, found;
    uint32_t prim;
    rtk_tri_hit hit;
} ref_answer;

struct ref_memo {
    ref_answer *slot;
    size_t cap, count; /* cap: a power of two, or 0 */
};

static size_t ref_key_hash(const uint32_t key[9])
{
    uint64_t h = 1469598103934665603ull;
    for (int i = 0; i < 9; i++)
        h = (h ^ key[i]) * 1099511628211ull;
    return (size_t)(h ^ (h >> 29));
}

/* key's slot in the table: its answer, or the empty one it would take */
static ref_answer *ref_memo_find(struct ref_memo *memo, const uint32_t key[9])
{
    size_t i = ref_key_hash(key) & (memo->cap - 1);
    while (memo->slot[i].used && memcmp(memo->slot[i].key, key, sizeof memo->slot[i].key))
        i = (i + 1) & (memo->cap - 1);
    return &memo->slot[i];
}

static void ref_memo_grow(struct ref_memo *memo)
{
    struct ref_memo bigger = {.cap = memo->cap ? 2 * memo->cap : 1024, .count = memo->count};
    bigger.slot = calloc(bigger.cap, sizeof *bigger.slot);
    assert_non_null(bigger.slot);
    for (size_t i = 0; i < memo->cap; i++)
        if (memo->slot[i].used)
            *ref_memo_find(&bigger, memo->slot[i].key) = memo->slot[i];
    free(memo->slot);
    *memo = bigger;
}

ref_mesh ref_prepare(const float *v, const uint32_t *idx, size_t nt)
{
    ref_mesh m = {.tri = malloc((nt ? nt : 1) * sizeof *m.tri), .keep = malloc(nt ? nt : 1), .count = nt,
                  .vtx = malloc((nt ? nt : 1) * sizeof *m.vtx), .memo = calloc(1, sizeof *m.memo)};
    assert_non_null(m.tri);
    assert_non_null(m.keep);
    assert_non_null(m.vtx);
    assert_non_null(m.memo);
    for (size_t i = 0; i < nt; i++) {
        const uint32_t *t = idx + 3 * i;
        const float *a = v + 3 * (size_t)t[0], *b = v + 3 * (size_t)t[1], *c = v + 3 * (size_t)t[2];
        m.keep[i] = rtk_triangle_classify(a, b, c) == RTK_TRIANGLE_HITTABLE; /* (what a build keeps) */
        for (int k = 0; k < 3; k++) {
            m.tri[i][k] = a[k];
            m.tri[i][3 + k] = b[k] - a[k];
            m.tri[i][6 + k] = c[k] - a[k];
            m.vtx[i][k] = a[k];
            m.vtx[i][3 + k] = b[k];
            m.vtx[i][6 + k] = c[k];
        }
    }
    return m;
}

void ref_free(ref_mesh *m)
{
    free(m->tri);
    free(m->keep);
    free(m->vtx);
    if (m->memo)
        free(m->memo->slot);
    free(m->memo);
    memset(m, 0, sizeof *m);
}

/* Triangle i against the ray within [tnear, tfar], with the mesh's intersector. */
static int ref_test(const ref_mesh *m, size_t i, const float o[3], const float d[3], const rtk_watertight_ray *w,
                    float tnear, float tfar, rtk_tri_hit *hit)
{
    if (!m->keep[i])
        return 0;
    if (m->watertight) {
        const float *v = m->vtx[i];
        return rtk_triangle_intersect_watertight(o, w, tnear, tfar, v, v + 3, v + 6, hit);
    }
    const float *t = m->tri[i];
    return rtk_triangle_intersect(o, d, tnear, tfar, t, t + 3, t + 6, hit);
}

int ref_one(const ref_mesh *m, uint32_t prim, const rtk_ray *r, rtk_tri_hit *hit)
{
    float o[3] = {r->org_x, r->org_y, r->org_z}, d[3] = {r->dir_x, r->dir_y, r->dir_z};
    rtk_watertight_ray w;
    rtk_watertight_ray_init(d, &w);
    return ref_test(m, prim, o, d, &w, r->tnear, r->tfar, hit);
}

static int ref_closest_brute(const ref_mesh *m, const rtk_ray *r, rtk_tri_hit *hit, uint32_t *prim);

int ref_closest(const ref_mesh *m, const rtk_ray *r, rtk_tri_hit *hit, uint32_t *prim)
{
    const float f[8] = {r->org_x, r->org_y, r->org_z, r->dir_x, r->dir_y, r->dir_z, r->tnear, r->tfar};
    uint32_t key[9];
    memcpy(key, f, sizeof f);
    key[8] = (uint32_t)m->watertight;
    struct ref_memo *memo = m->memo;
    if (2 * (memo->count + 1) > memo->cap)
        ref_memo_grow(memo);
    ref_answer *a = ref_memo_find(memo, key);
    if (!a->used) {
        a->used = 1;
        memcpy(a->key, key, sizeof key);
        a->found = ref_closest_brute(m, r, &a->hit, &a->prim);
        memo->count++;
    }
    if (a->found) {
        *hit = a->hit;
        *prim = a->prim;
    }
    return a->found;
}

static int ref_closest_brute(const ref_mesh *m, const rtk_ray *r, rtk_tri_hit *hit, uint32_t *prim)
{
    float o[3] = {r->org_x, r->org_y, r->org_z}, d[3] = {r->dir_x, r->dir_y, r->dir_z};
    rtk_watertight_ray w;
    rtk_watertight_ray_init(d, &w);
    float tfar = r->tfar;
    int found = 0;
    for (size_t i = 0; i < m->count; i++) {
        rtk_tri_hit h;
        if (ref_test(m, i, o, d, &w, r->tnear, tfar, &h)) {
            found = 1;
            *hit = h;
            *prim = (uint32_t)i;
            tfar = h.t;
        }
    }
    return found;
}

int test_sphere_hit(const float c[3], float r, const float o[3], const float d[3], float tnear, float tfar,
                    float *t_out)
{
    double oc[3], a = 0, b = 0, cc = -(double)r * r;
    for (int k = 0; k < 3; k++) {
        oc[k] = (double)o[k] - c[k];
        a += (double)d[k] * d[k];
        b += oc[k] * d[k];
        cc += oc[k] * oc[k];
    }
    const double disc = b * b - a * cc;
    if (disc < 0 || a == 0)
        return 0;
    const double sq = sqrt(disc);
    const double roots[2] = {(-b - sq) / a, (-b + sq) / a};
    for (int i = 0; i < 2; i++) {
        const float t = (float)roots[i];
        if (t >= tnear && t <= tfar) {
            *t_out = t;
            return 1;
        }
    }
    return 0;
}

rtk_ray test_ray(float ox, float oy, float oz, float dx, float dy, float dz, float tnear, float tfar)
{
    rtk_ray r = {.org_x = ox, .org_y = oy, .org_z = oz, .tnear = tnear, .dir_x = dx, .dir_y = dy, .dir_z = dz,
                 .tfar = tfar, .mask = 0xffffffffu};
    return r;
}

uint32_t rng_u32(rng *r)
{
    /* splitmix64 */
    uint64_t z = (r->s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return (uint32_t)((z ^ (z >> 31)) >> 32);
}

float rng_float(rng *r)
{
    return (float)(rng_u32(r) >> 8) * 0x1p-24f;
}

void test_soup_mesh(rng *r, size_t nt, float size, float **v, uint32_t **idx)
{
    *v = malloc((nt ? nt : 1) * 9 * sizeof(float));
    *idx = malloc((nt ? nt : 1) * 3 * sizeof(uint32_t));
    assert_true(*v && *idx);
    for (size_t t = 0; t < nt; t++) {
        const float c[3] = {rng_float(r), rng_float(r), rng_float(r)};
        for (int k = 0; k < 3; k++) {
            for (int a = 0; a < 3; a++)
                (*v)[9 * t + 3 * k + a] = c[a] + size * (rng_float(r) - 0.5f);
            (*idx)[3 * t + k] = (uint32_t)(3 * t + k);
        }
    }
}

rtk_ray test_ray_through_cube(rng *r)
{
    const float o[3] = {rng_float(r) * 1.4f - 0.2f, rng_float(r) * 1.4f - 0.2f, -0.5f};
    const float target[3] = {rng_float(r), rng_float(r), rng_float(r) * 1.4f};
    return test_ray(o[0], o[1], o[2], target[0] - o[0], target[1] - o[1], target[2] - o[2], 0.0f, INFINITY);
}

void test_sticks_mesh(rng *r, size_t nt, float scale, float offset, float **v, uint32_t **idx)
{
    *v = malloc((nt ? nt : 1) * 9 * sizeof(float));
    *idx = malloc((nt ? nt : 1) * 3 * sizeof(uint32_t));
    assert_non_null(*v);
    assert_non_null(*idx);
    static const float big[4][9] = {
        {0, 0, 0.5f, 1, 0, 0.5f, 0, 1, 0.5f},       /* in the plane z = 1/2 */
        {1, 1, 0.5f, 0, 1, 0.5f, 1, 0, 0.5f},
        {0.5f, 0, 0, 0.5f, 1, 0, 0.5f, 0, 1},       /* in the plane x = 1/2 */
        {0.25f, 0.25f, 0.25f, 0.75f, 0.25f, 0.75f, 0.25f, 0.75f, 0.75f}, /* diagonal */
    };
    for (size_t t = 0; t < nt; t++) {
        float *p = *v + 9 * t;
        if (t < 4) {
            memcpy(p, big[t], sizeof big[t]);
        } else {
            for (int k = 0; k < 6; k++)
                p[k] = rng_float(r);
            for (int k = 0; k < 3; k++)
                p[6 + k] = p[k] + 0.01f * (rng_float(r) - 0.5f);
        }
        for (int k = 0; k < 9; k++)
            p[k] = offset + scale * p[k];
        for (int k = 0; k < 3; k++)
            (*idx)[3 * t + k] = (uint32_t)(3 * t + k);
    }
}

void test_packet_put(void *packet, unsigned width, unsigned lane, const rtk_rayhit *rh, int occluded)
{
    const size_t fields = occluded ? 12 : 20;
    for (size_t f = 0; f < fields; f++)
        memcpy((uint32_t *)packet + f * width + lane, (const uint32_t *)rh + f, 4);
}

void test_packet_get(const void *packet, unsigned width, unsigned lane, rtk_rayhit *rh, int occluded)
{
    const size_t fields = occluded ? 12 : 20;
    for (size_t f = 0; f < fields; f++)
        memcpy((uint32_t *)rh + f, (const uint32_t *)packet + f * width + lane, 4);
}

rtk_error test_trace_packet(rtk_scene scene, unsigned width, int occluded, const int *valid, void *packet)
{
    switch (width * 2 + (unsigned)!!occluded) {
    case 8: return rtk_intersect4(scene, valid, packet);
    case 9: return rtk_occluded4(scene, valid, packet);
    case 16: return rtk_intersect8(scene, valid, packet);
    case 17: return rtk_occluded8(scene, valid, packet);
    case 32: return rtk_intersect16(scene, valid, packet);
    case 33: return rtk_occluded16(scene, valid, packet);
    default: fail_msg("no packet width %u", width); return RTK_ERROR_INVALID_ARGUMENT;
    }
}

void test_intersect8_rows(rtk_scene scene, const rtk_rayhit in[8], rtk_rayhit out[8])
{
    _Alignas(64) uint32_t pk[20 * 8];
    for (unsigned l = 0; l < 8; l++)
        test_packet_put(pk, 8, l, &in[l], 0);
    assert_int_equal(test_trace_packet(scene, 8, 0, NULL, pk), RTK_OK);
    for (unsigned l = 0; l < 8; l++)
        test_packet_get(pk, 8, l, &out[l], 0);
}

static int cmp_names(const void *a, const void *b)
{
    return strcmp(*(char *const *)a, *(char *const *)b);
}

int test_sanitized(void)
{
    const char *e = getenv("RTK_TEST_SANITIZED");
    return e && *e && strcmp(e, "0");
}

size_t test_mesh_files(char *files[], size_t max, const char *only)
{
    const int all = !only || !*only;
    const off_t most = all && test_sanitized() ? (off_t)5 << 20 : -1;
    DIR *d = opendir(RTK_TEST_MESHES);
    if (!d)
        fail_msg("cannot open the shared meshes at %s", RTK_TEST_MESHES);
    size_t n = 0;
    struct dirent *e;
    while ((e = readdir(d)) && n < max) {
        size_t len = strlen(e->d_name);
        if (len > 4 && !strcmp(e->d_name + len - 4, ".ply") && (all || !strcmp(only, e->d_name))) {
            files[n] = malloc(strlen(RTK_TEST_MESHES) + len + 2);
            assert_non_null(files[n]);
            sprintf(files[n], "%s/%s", RTK_TEST_MESHES, e->d_name);
            struct stat st;
            if (most >= 0 && !stat(files[n], &st) && st.st_size > most) {
                print_message("(sanitizers: %s left out, %lld bytes)\n", e->d_name, (long long)st.st_size);
                free(files[n]);
                continue;
            }
            n++;
        }
    }
    closedir(d);
    qsort(files, n, sizeof files[0], cmp_names);
    return n;
}

void test_assert_same_tree(const rtk_bvh *a, const rtk_bvh *b)
{
    assert_int_equal(a->width, b->width);
    assert_int_equal(a->root, b->root);
    assert_int_equal(a->node_count, b->node_count);
    assert_int_equal(a->leaf_count, b->leaf_count);
    assert_int_equal(a->prim_count, b->prim_count);
    const size_t slots = (size_t)a->node_count * a->width;
    assert_memory_equal(a->children, b->children, slots * sizeof *a->children);
    assert_memory_equal(a->child_lower, b->child_lower, slots * 3 * sizeof(float));
    assert_memory_equal(a->child_upper, b->child_upper, slots * 3 * sizeof(float));
    assert_memory_equal(a->leaf_first, b->leaf_first, (a->leaf_count + 1) * sizeof *a->leaf_first);
    assert_memory_equal(a->prims, b->prims, a->prim_count * sizeof *a->prims);
}

int test_load_shared_mesh(const char *name, rtk_mesh *mesh)
{
    char *files[1];
    if (test_mesh_files(files, 1, name) != 1)
        return -1;
    char err[512];
    const int rc = rtk_mesh_load(files[0], mesh, err, sizeof err);
    free(files[0]);
    return rc ? -1 : 0;
}
