/* API misuse and API semantics: every misuse gets an error code and a message. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "testlib.h"

/* Two triangles forming the unit square in z = 0, and one at z = 1 above. */
static const float quad_v[] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 0, 0, 1, 1, 0, 1, 0, 1, 1};
static const uint32_t quad_i[] = {0, 1, 2, 0, 2, 3, 4, 5, 6};

static rtk_rayhit down_at(float x, float y)
{
    rtk_rayhit rh;
    memset(&rh, 0, sizeof rh);
    rh.ray = test_ray(x, y, 5, 0, 0, -1, 0, INFINITY);
    rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
    return rh;
}

static void test_version(void **state)
{
    (void)state;
    assert_int_equal(rtk_version(), RTK_VERSION);
    assert_string_equal(rtk_version_string(), RTK_VERSION_STRING);
    assert_string_equal(rtk_error_name(RTK_ERROR_INVALID_ARGUMENT), "RTK_ERROR_INVALID_ARGUMENT");
    assert_string_equal(rtk_error_name((rtk_error)12345), "RTK_ERROR_UNKNOWN");
}

static void test_release_null_is_noop(void **state)
{
    (void)state;
    rtk_device_release(NULL);
    rtk_scene_release(NULL);
    rtk_geometry_release(NULL);
    rtk_device_retain(NULL);
    rtk_scene_retain(NULL);
    rtk_geometry_retain(NULL);
}

static void test_null_arguments(void **state)
{
    (void)state;
    assert_int_equal(rtk_device_new(NULL, NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_device_get_error(NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(NULL), "out is NULL"));

    assert_int_equal(rtk_scene_new(NULL, NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_intersect1(NULL, NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_occluded1(NULL, NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_scene_commit(NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_geometry_commit(NULL), RTK_ERROR_INVALID_ARGUMENT);

    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    rtk_scene scene = NULL;
    assert_int_equal(rtk_scene_new(dev, NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_scene_new(dev, &scene), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(scene, NULL, NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_intersect1(scene, NULL), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_occluded1(scene, NULL), RTK_ERROR_INVALID_ARGUMENT);
    /* Sticky: the first error stays until read, the message is the latest. */
    assert_int_equal(rtk_device_get_error(dev), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_device_get_error(dev), RTK_OK);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "rtk_occluded1"));

    rtk_geometry g = NULL;
    assert_int_equal(rtk_geometry_new(dev, (rtk_geometry_type)7, &g), RTK_ERROR_INVALID_ARGUMENT);
    assert_null(g);
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, NULL, 0, 12, 3),
                     RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, quad_v, 0, 8, 3),
                     RTK_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "byte_stride 8"));
    assert_int_equal(rtk_geometry_set_shared_buffer(g, (rtk_buffer_type)9, quad_v, 0, 12, 3),
                     RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, quad_v, 2, 12, 3),
                     RTK_ERROR_INVALID_ARGUMENT); /* misaligned */
    assert_int_equal(rtk_geometry_set_new_buffer(g, RTK_BUFFER_TYPE_INDEX, 12, 1, NULL), RTK_ERROR_INVALID_ARGUMENT);
    /* No buffers yet: commit refuses. */
    assert_int_equal(rtk_geometry_commit(g), RTK_ERROR_INVALID_OPERATION);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "no vertex buffer"));
    assert_int_equal(rtk_scene_detach_geometry(scene, 3), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_scene_set_flags(scene, 1u << 20), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_scene_set_build_quality(scene, (rtk_build_quality)5), RTK_ERROR_INVALID_ARGUMENT);
    rtk_geometry_release(g);
    rtk_scene_release(scene);
    rtk_device_release(dev);
}

static void test_bad_config(void **state)
{
    (void)state;
    static const struct {
        const char *config, *expect;
    } cases[] = {
        {"colour=blue", "unknown config key 'colour'"},
        {"threads=many", "threads='many'"},
        {"threads=-1", "threads='-1'"},
        {"verbose=9", "verbose='9'"},
        {"isa=AVX2!", "expected a backend name"},
        {"isa", "not key=value"},
        {"max_isa=pentium", "max_isa=pentium: not a known ISA level"},
        {"isa=avx9", "isa=avx9: no such usable backend; usable: "},
        {"builder=Morton", "config builder='Morton': expected a name such as morton"},
        {"builder=", "config builder='': expected a name"},
        {"layout=bvh4 triangle4", "config layout='bvh4 triangle4': expected a name"},
        {"builder=sweep", "config builder='sweep': backend "},
        {"layout=bvh16.triangle4", "config layout='bvh16.triangle4': backend "},
        {"isa=scalar,layout=bvh8.triangle4", "backend scalar has no such layout"},
        {"motion_layout=bvh4 triangle4mb", "config motion_layout='bvh4 triangle4mb': expected a name such as "
                                           "bvh4.triangle4mb"},
        {"isa=scalar,motion_layout=bvh8.triangle4mb", "backend scalar has no such motion-blur layout (it has: "
                                                      "bvh4.triangle4mb, bvh4.triangle4mb.robust)"},
        {"motion_layout=bvh8.triangle4", "config motion_layout='bvh8.triangle4': backend "},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        rtk_device dev = (rtk_device)0x1;
        rtk_error err = rtk_device_new(cases[i].config, &dev);
        assert_true(err != RTK_OK);
        assert_null(dev);
        const char *msg = rtk_device_get_error_message(NULL);
        if (!strstr(msg, cases[i].expect))
            fail_msg("config '%s': message '%s' lacks '%s'", cases[i].config, msg, cases[i].expect);
    }
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new("threads=2,verbose=0,,", &dev), RTK_OK);
    rtk_device_release(dev);
}

static int callback_calls;
static rtk_error callback_code;
static void on_error(void *user, rtk_error code, const char *message)
{
    assert_ptr_equal(user, &callback_calls);
    assert_non_null(message);
    callback_calls++;
    callback_code = code;
}

static void test_error_callback(void **state)
{
    (void)state;
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    assert_int_equal(rtk_device_set_error_callback(dev, on_error, &callback_calls), RTK_OK);
    rtk_scene scene = NULL;
    assert_int_equal(rtk_scene_new(dev, &scene), RTK_OK);
    rtk_rayhit rh = down_at(0.5f, 0.5f);
    assert_int_equal(rtk_intersect1(scene, &rh), RTK_ERROR_INVALID_OPERATION); /* never committed */
    assert_int_equal(callback_calls, 1);
    assert_int_equal(callback_code, RTK_ERROR_INVALID_OPERATION);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "never committed"));
    rtk_scene_release(scene);
    rtk_device_release(dev);
}

static void test_index_out_of_range(void **state)
{
    (void)state;
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    const uint32_t bad[] = {0, 1, 2, 0, 2, 3, 1, 2, 7};
    rtk_scene scene = NULL;
    rtk_geometry g = NULL;
    uint32_t id = 99;
    assert_int_equal(rtk_scene_new(dev, &scene), RTK_OK);
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, quad_v, 0, 12, 7), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, bad, 0, 12, 3), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(scene, g, &id), RTK_OK);
    assert_int_equal(id, 0);
    /* Attached but not committed. */
    assert_int_equal(rtk_scene_commit(scene), RTK_ERROR_INVALID_OPERATION);
    assert_non_null(strstr(rtk_device_get_error_message(dev), "not committed"));
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_commit(scene), RTK_ERROR_INVALID_GEOMETRY);
    const char *msg = rtk_device_get_error_message(dev);
    if (!strstr(msg, "geometry 0, triangle 2: vertex index 7 out of range (7 vertices)"))
        fail_msg("message: %s", msg);
    /* The scene stays unusable until a commit succeeds. */
    rtk_rayhit rh = down_at(0.5f, 0.5f);
    assert_int_equal(rtk_intersect1(scene, &rh), RTK_ERROR_INVALID_OPERATION);
    rtk_geometry_release(g);
    rtk_scene_release(scene);
    rtk_device_release(dev);
}

static void test_nonfinite_vertices(void **state)
{
    (void)state;
    float v[sizeof quad_v / sizeof quad_v[0]];
    memcpy(v, quad_v, sizeof v);
    v[3 * 4 + 2] = NAN;      /* vertex 4: the upper triangle */
    v[3 * 3 + 0] = INFINITY; /* vertex 3: the second square triangle */
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    rtk_scene scene = test_scene(dev, v, 7, quad_i, 3);
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(scene, &info), RTK_OK);
    assert_int_equal(info.triangles, 1);
    assert_int_equal(info.triangles_skipped, 2);
    /* The finite triangle is still hit; the skipped ones never are. */
    rtk_rayhit rh = down_at(0.75f, 0.25f);
    assert_int_equal(rtk_intersect1(scene, &rh), RTK_OK);
    assert_int_equal(rh.hit.primID, 0);
    assert_float_equal(rh.ray.tfar, 5.0f, 0.0f);
    rh = down_at(0.25f, 0.75f);
    rtk_intersect1(scene, &rh);
    assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID);
    rtk_scene_release(scene);
    rtk_device_release(dev);
}

static void test_empty_scene(void **state)
{
    (void)state;
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    rtk_scene scene = NULL;
    assert_int_equal(rtk_scene_new(dev, &scene), RTK_OK);
    assert_int_equal(rtk_scene_commit(scene), RTK_OK);
    rtk_rayhit rh = down_at(0.5f, 0.5f);
    assert_int_equal(rtk_intersect1(scene, &rh), RTK_OK);
    assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID);
    assert_true(isinf(rh.ray.tfar));
    assert_int_equal(rtk_occluded1(scene, &rh.ray), RTK_OK);
    assert_true(rh.ray.tfar > 0);
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(scene, &info), RTK_OK);
    assert_int_equal(info.triangles, 0);

    /* A geometry with zero triangles is as empty. */
    rtk_geometry g = NULL;
    void *mem = NULL;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    assert_int_equal(rtk_geometry_set_new_buffer(g, RTK_BUFFER_TYPE_VERTEX, 12, 0, &mem), RTK_OK);
    assert_int_equal(rtk_geometry_set_new_buffer(g, RTK_BUFFER_TYPE_INDEX, 12, 0, &mem), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(scene, g, NULL), RTK_OK);
    assert_int_equal(rtk_scene_commit(scene), RTK_OK);
    rtk_intersect1(scene, &rh);
    assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID);
    rtk_geometry_release(g);
    rtk_scene_release(scene);
    rtk_device_release(dev);
}

static void test_geometry_lifecycle(void **state)
{
    (void)state;
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    rtk_scene scene = NULL;
    assert_int_equal(rtk_scene_new(dev, &scene), RTK_OK);

    /* geometry A: owned buffers with a padded vertex stride; B: shared. */
    rtk_geometry a = NULL, b = NULL;
    float *va = NULL;
    uint32_t *ia = NULL;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &a), RTK_OK);
    assert_int_equal(rtk_geometry_set_new_buffer(a, RTK_BUFFER_TYPE_VERTEX, 16, 3, (void **)&va), RTK_OK);
    assert_int_equal(rtk_geometry_set_new_buffer(a, RTK_BUFFER_TYPE_INDEX, 12, 1, (void **)&ia), RTK_OK);
    const float tri[3][3] = {{0, 0, 2}, {1, 0, 2}, {0, 1, 2}};
    for (int i = 0; i < 3; i++)
        memcpy(va + 4 * i, tri[i], sizeof tri[i]);
    ia[0] = 0, ia[1] = 1, ia[2] = 2;
    int tag = 42;
    assert_int_equal(rtk_geometry_set_user_data(a, &tag), RTK_OK);
    assert_ptr_equal(rtk_geometry_get_user_data(a), &tag);
    assert_ptr_equal(rtk_scene_get_user_data(scene), NULL);
    assert_int_equal(rtk_scene_set_user_data(scene, &tag), RTK_OK);
    assert_ptr_equal(rtk_scene_get_user_data(scene), &tag);
    assert_int_equal(rtk_scene_set_user_data(NULL, &tag), RTK_ERROR_INVALID_ARGUMENT);
    assert_ptr_equal(rtk_scene_get_user_data(NULL), NULL);
    assert_int_equal(rtk_geometry_commit(a), RTK_OK);
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &b), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(b, RTK_BUFFER_TYPE_VERTEX, quad_v, 0, 12, 7), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(b, RTK_BUFFER_TYPE_INDEX, quad_i, 0, 12, 2), RTK_OK);
    assert_int_equal(rtk_geometry_commit(b), RTK_OK);

    uint32_t ida = 9, idb = 9;
    assert_int_equal(rtk_scene_attach_geometry(scene, a, &ida), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(scene, b, &idb), RTK_OK);
    assert_int_equal(ida, 0);
    assert_int_equal(idb, 1);
    assert_ptr_equal(rtk_scene_get_geometry(scene, 1), b);
    rtk_geometry_release(a); /* the scene holds its own references */
    rtk_geometry_release(b);
    assert_int_equal(rtk_scene_commit(scene), RTK_OK);

    rtk_rayhit rh = down_at(0.2f, 0.2f);
    rtk_intersect1(scene, &rh);
    assert_int_equal(rh.hit.geomID, ida);
    assert_float_equal(rh.ray.tfar, 3.0f, 0.0f);
    assert_ptr_equal(rtk_geometry_get_user_data(rtk_scene_get_geometry(scene, rh.hit.geomID)), &tag);
    /* Geometric normal: cross(v1 - v0, v2 - v0) = (0, 0, 1). */
    assert_float_equal(rh.hit.Ng_z, 1.0f, 0.0f);
    assert_float_equal(rh.hit.u, 0.2f, 1e-6f);
    assert_float_equal(rh.hit.v, 0.2f, 1e-6f);

    /* Disable A: the ray reaches B. */
    assert_int_equal(rtk_geometry_disable(rtk_scene_get_geometry(scene, ida)), RTK_OK);
    assert_int_equal(rtk_scene_commit(scene), RTK_OK);
    rh = down_at(0.2f, 0.2f);
    rtk_intersect1(scene, &rh);
    assert_int_equal(rh.hit.geomID, idb);
    assert_float_equal(rh.ray.tfar, 5.0f, 0.0f);
    /* Detach B: nothing left enabled. */
    assert_int_equal(rtk_scene_detach_geometry(scene, idb), RTK_OK);
    assert_null(rtk_scene_get_geometry(scene, idb));
    assert_int_equal(rtk_device_get_error(dev), RTK_ERROR_INVALID_ARGUMENT);
    assert_int_equal(rtk_scene_commit(scene), RTK_OK);
    rh = down_at(0.2f, 0.2f);
    rtk_intersect1(scene, &rh);
    assert_int_equal(rh.hit.geomID, RTK_INVALID_GEOMETRY_ID);
    /* Re-enable A: it is hit again; a new geometry takes the freed id. */
    assert_int_equal(rtk_geometry_enable(rtk_scene_get_geometry(scene, ida)), RTK_OK);
    assert_int_equal(rtk_scene_commit(scene), RTK_OK);
    rh = down_at(0.2f, 0.2f);
    rtk_intersect1(scene, &rh);
    assert_int_equal(rh.hit.geomID, ida);
    rtk_scene_release(scene);
    rtk_device_release(dev);
}

/* A new geometry takes the lowest free geomID: ids freed by detach are
 * taken again lowest first, then the table grows; over many attachments
 * (rtk_scene_attach_geometry keeps where the lowest free slot may be). */
/* A geometry keeps only its own type's state (rtk_geometry_s lays the
 * types' members over one another): another type's calls are refused and
 * change nothing it traces with, and each type releases what it holds
 * (ASan and valgrind runs check the release). */
static void test_geometry_types_apart(void **state)
{
    (void)state;
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    static const float v[] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    static const uint32_t idx[] = {0, 1, 2};
    const float xfm[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 3}; /* moved up by 3 */
    rtk_scene child = test_scene(dev, v, 3, idx, 1);
    rtk_geometry inst = NULL, mesh = NULL, user = NULL;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, &inst), RTK_OK);
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &mesh), RTK_OK);
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_USER, &user), RTK_OK);
    assert_int_equal(rtk_geometry_set_instanced_scene(inst, child), RTK_OK);
    assert_int_equal(rtk_geometry_set_transform(inst, RTK_FORMAT_FLOAT3X4_ROW_MAJOR, xfm), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(mesh, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, 3), RTK_OK);
    assert_int_equal(rtk_geometry_set_shared_buffer(mesh, RTK_BUFFER_TYPE_INDEX, idx, 0, 12, 1), RTK_OK);
    /* the others' calls */
    rtk_geometry not_mesh[2] = {inst, user};
    for (int k = 0; k < 2; k++) {
        rtk_geometry g = not_mesh[k];
        assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, 3),
                         RTK_ERROR_INVALID_OPERATION);
        assert_int_equal(rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_VERTEX), RTK_ERROR_INVALID_OPERATION);
        assert_int_equal(rtk_geometry_update_buffer(g, RTK_BUFFER_TYPE_INDEX), RTK_ERROR_INVALID_OPERATION);
        assert_int_equal(rtk_geometry_set_time_step_count(g, 2), RTK_ERROR_INVALID_OPERATION);
    }
    rtk_geometry not_user[2] = {inst, mesh}, not_inst[2] = {mesh, user};
    for (int k = 0; k < 2; k++) {
        assert_int_equal(rtk_geometry_set_user_primitive_count(not_user[k], 7), RTK_ERROR_INVALID_OPERATION);
        assert_int_equal(rtk_geometry_set_transform(not_inst[k], RTK_FORMAT_FLOAT3X4_ROW_MAJOR, xfm),
                         RTK_ERROR_INVALID_OPERATION);
        assert_int_equal(rtk_geometry_set_instanced_scene(not_inst[k], child), RTK_ERROR_INVALID_OPERATION);
    }
    assert_int_equal(rtk_geometry_commit(inst), RTK_OK);
    assert_int_equal(rtk_geometry_commit(mesh), RTK_OK);
    assert_int_equal(rtk_geometry_commit(user), RTK_ERROR_INVALID_OPERATION); /* no callbacks set */
    /* the instance places the child 3 up, the mesh lies at 0 */
    rtk_scene top = NULL;
    assert_int_equal(rtk_scene_new(dev, &top), RTK_OK);
    uint32_t inst_id = 0, mesh_id = 0;
    assert_int_equal(rtk_scene_attach_geometry(top, inst, &inst_id), RTK_OK);
    assert_int_equal(rtk_scene_attach_geometry(top, mesh, &mesh_id), RTK_OK);
    assert_int_equal(rtk_scene_commit(top), RTK_OK);
    rtk_rayhit rh = down_at(0.25f, 0.25f);
    assert_int_equal(rtk_intersect1(top, &rh), RTK_OK);
    assert_float_equal(rh.ray.tfar, 2.0f, 1e-6f);
    assert_int_equal(rh.hit.instID, inst_id);
    assert_int_equal(rh.hit.geomID, 0);
    assert_int_equal(rtk_scene_detach_geometry(top, inst_id), RTK_OK);
    assert_int_equal(rtk_scene_commit(top), RTK_OK);
    rh = down_at(0.25f, 0.25f);
    assert_int_equal(rtk_intersect1(top, &rh), RTK_OK);
    assert_float_equal(rh.ray.tfar, 5.0f, 1e-6f);
    assert_int_equal(rh.hit.geomID, mesh_id);
    assert_int_equal(rh.hit.instID, RTK_INVALID_GEOMETRY_ID);
    rtk_scene_release(top);
    rtk_geometry_release(inst);
    rtk_geometry_release(mesh);
    rtk_geometry_release(user);
    rtk_scene_release(child);
    rtk_device_release(dev);
}

static void test_geometry_ids(void **state)
{
    (void)state;
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    rtk_scene scene = NULL;
    assert_int_equal(rtk_scene_new(dev, &scene), RTK_OK);
    enum { MANY = 20000 };
    rtk_geometry g = NULL;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    for (uint32_t i = 0; i < MANY; i++) {
        uint32_t id = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_scene_attach_geometry(scene, g, &id), RTK_OK);
        assert_int_equal(id, i);
    }
    static const uint32_t freed[] = {7, 3, 19999, 12000, 0};
    for (size_t k = 0; k < sizeof freed / sizeof freed[0]; k++)
        assert_int_equal(rtk_scene_detach_geometry(scene, freed[k]), RTK_OK);
    static const uint32_t want[] = {0, 3, 7, 12000, 19999, MANY, MANY + 1};
    for (size_t k = 0; k < sizeof want / sizeof want[0]; k++) {
        uint32_t id = RTK_INVALID_GEOMETRY_ID;
        assert_int_equal(rtk_scene_attach_geometry(scene, g, &id), RTK_OK);
        assert_int_equal(id, want[k]);
        assert_ptr_equal(rtk_scene_get_geometry(scene, id), g);
    }
    /* the last one detached and attached again: the same id */
    assert_int_equal(rtk_scene_detach_geometry(scene, MANY + 1), RTK_OK);
    uint32_t id = RTK_INVALID_GEOMETRY_ID;
    assert_int_equal(rtk_scene_attach_geometry(scene, g, &id), RTK_OK);
    assert_int_equal(id, MANY + 1);
    rtk_geometry_release(g);
    rtk_scene_release(scene);
    rtk_device_release(dev);
}

static void test_flags_reported(void **state)
{
    (void)state;
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    rtk_scene scene = NULL;
    assert_int_equal(rtk_scene_new(dev, &scene), RTK_OK);
    assert_int_equal(rtk_scene_set_flags(scene, RTK_SCENE_FLAG_ROBUST | RTK_SCENE_FLAG_COMPACT), RTK_OK);
    assert_int_equal(rtk_scene_set_build_quality(scene, RTK_BUILD_QUALITY_HIGH), RTK_OK);
    assert_int_equal(rtk_scene_commit(scene), RTK_OK);
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(scene, &info), RTK_OK);
    assert_int_equal(info.flags, RTK_SCENE_FLAG_ROBUST | RTK_SCENE_FLAG_COMPACT);
    /* both honoured: index leaves and the watertight intersector */
    assert_int_equal(info.flags_not_honoured, 0);
    assert_int_equal(info.quality, RTK_BUILD_QUALITY_HIGH);
    assert_string_equal(info.builder, "sah-spatial");
    assert_string_equal(info.layout, "bvh4.triangle4i.robust");
    const char *backend = rtk_device_get_backend_name(dev);
    const int wide = !strcmp(backend, "avx") || !strcmp(backend, "avx2");
    /* robust alone: vertex leaves, as wide as the default */
    assert_int_equal(rtk_scene_set_flags(scene, RTK_SCENE_FLAG_ROBUST), RTK_OK);
    assert_int_equal(rtk_scene_commit(scene), RTK_OK);
    assert_int_equal(rtk_scene_get_info(scene, &info), RTK_OK);
    assert_int_equal(info.flags_not_honoured, 0);
    assert_string_equal(info.layout, wide ? "bvh8.triangle4v" : "bvh4.triangle4v");
    /* Default: 8-wide nodes where the backend has 8-wide vectors, 4-wide
     * elsewhere, and vertex-copy leaves. */
    assert_int_equal(rtk_scene_set_flags(scene, RTK_SCENE_FLAG_NONE), RTK_OK);
    assert_int_equal(rtk_scene_commit(scene), RTK_OK);
    assert_int_equal(rtk_scene_get_info(scene, &info), RTK_OK);
    assert_int_equal(info.flags_not_honoured, 0);
    assert_string_equal(info.layout, wide ? "bvh8.triangle4" : "bvh4.triangle4");
    rtk_scene_info small = {.struct_size = 8};
    assert_int_equal(rtk_scene_get_info(scene, &small), RTK_ERROR_INVALID_ARGUMENT);
    rtk_scene_release(scene);
    rtk_device_release(dev);
}

/* Packet calls: arguments checked like the single-ray ones, misaligned
 * packets refused with a message, the empty scene, and the packet widths
 * each backend reports. */
static void test_packet_arguments(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene scene = NULL;
        assert_int_equal(rtk_scene_new(dev, &scene), RTK_OK);
        _Alignas(64) unsigned char mem[sizeof(rtk_rayhit16) + 64];
        rtk_rayhit8 *rh8 = (rtk_rayhit8 *)mem;
        memset(mem, 0, sizeof mem);
        assert_int_equal(rtk_intersect8(scene, NULL, rh8), RTK_ERROR_INVALID_OPERATION); /* not committed */
        assert_int_equal(rtk_scene_commit(scene), RTK_OK);
        assert_int_equal(rtk_intersect8(NULL, NULL, rh8), RTK_ERROR_INVALID_ARGUMENT);
        assert_int_equal(rtk_intersect8(scene, NULL, NULL), RTK_ERROR_INVALID_ARGUMENT);
        assert_int_equal(rtk_occluded16(scene, NULL, NULL), RTK_ERROR_INVALID_ARGUMENT);
        /* 16-byte aligned is enough for 4 rays, not for 8 or 16 */
        assert_int_equal(rtk_occluded4(scene, NULL, (rtk_ray4 *)(mem + 16)), RTK_OK);
        assert_int_equal(rtk_intersect8(scene, NULL, (rtk_rayhit8 *)(mem + 16)), RTK_ERROR_INVALID_ARGUMENT);
        assert_non_null(strstr(rtk_device_get_error_message(dev), "not aligned to 32 bytes"));
        assert_int_equal(rtk_occluded16(scene, NULL, (rtk_ray16 *)(mem + 32)), RTK_ERROR_INVALID_ARGUMENT);
        assert_int_equal(rtk_intersect4(scene, NULL, (rtk_rayhit4 *)(mem + 4)), RTK_ERROR_INVALID_ARGUMENT);
        /* the empty scene: valid rays, no hits, nothing written */
        rtk_rayhit16 *rh16 = (rtk_rayhit16 *)mem;
        for (int i = 0; i < 16; i++) {
            rh16->ray.dir_z[i] = -1.0f;
            rh16->ray.tfar[i] = INFINITY;
            rh16->hit.geomID[i] = RTK_INVALID_GEOMETRY_ID;
        }
        rtk_rayhit16 copy = *rh16;
        assert_int_equal(rtk_intersect16(scene, NULL, rh16), RTK_OK);
        assert_int_equal(rtk_occluded16(scene, NULL, &rh16->ray), RTK_OK);
        assert_memory_equal(rh16, &copy, sizeof copy);
        /* widths: 8-ray kernels on the SIMD backends (sse41's as two 4-wide
         * halves), wider packets split; scalar has none and goes ray by ray */
        rtk_scene_info info = {.struct_size = sizeof info};
        assert_int_equal(rtk_scene_get_info(scene, &info), RTK_OK);
        const int simd = strcmp(names[b], "scalar") != 0;
        assert_int_equal(info.packet_width[0], simd ? 4 : 1);
        assert_int_equal(info.packet_width[1], simd ? 8 : 1);
        assert_int_equal(info.packet_width[2], simd ? 8 : 1);
        rtk_scene_release(scene);
        rtk_device_release(dev);
    }
}

static void test_owned_buffer_copy_semantics(void **state)
{
    (void)state;
    /* Shared buffers are read at commit: a later change shows only after the next commit. */
    float v[sizeof quad_v / sizeof quad_v[0]];
    memcpy(v, quad_v, sizeof v);
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    rtk_scene scene = test_scene(dev, v, 7, quad_i, 2);
    for (int i = 0; i < 4; i++)
        v[3 * i + 2] = -1.0f;
    rtk_rayhit rh = down_at(0.5f, 0.25f);
    rtk_intersect1(scene, &rh);
    assert_float_equal(rh.ray.tfar, 5.0f, 0.0f);
    assert_int_equal(rtk_scene_commit(scene), RTK_OK);
    rh = down_at(0.5f, 0.25f);
    rtk_intersect1(scene, &rh);
    assert_float_equal(rh.ray.tfar, 6.0f, 0.0f);
    rtk_scene_release(scene);
    rtk_device_release(dev);
}

/* Compact scenes read vertices from the geometry's buffer after commit:
 * the same answers as the default layout, smaller, and memory rtk allocated
 * stays alive for the scene when the application replaces the buffer or
 * releases the geometry before committing again (ASan checks the reads). */
static void test_compact_scene(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_scene def = test_scene(dev, quad_v, 7, quad_i, 2);
        rtk_scene scene = NULL;
        rtk_geometry g = NULL;
        assert_int_equal(rtk_scene_new(dev, &scene), RTK_OK);
        assert_int_equal(rtk_scene_set_flags(scene, RTK_SCENE_FLAG_COMPACT), RTK_OK);
        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
        void *vb = NULL, *ib = NULL;
        assert_int_equal(rtk_geometry_set_new_buffer(g, RTK_BUFFER_TYPE_VERTEX, 16, 7, &vb), RTK_OK);
        assert_int_equal(rtk_geometry_set_new_buffer(g, RTK_BUFFER_TYPE_INDEX, 12, 2, &ib), RTK_OK);
        for (int i = 0; i < 7; i++)
            memcpy((char *)vb + 16 * i, &quad_v[3 * i], 12);
        memcpy(ib, quad_i, 6 * sizeof quad_i[0]);
        assert_int_equal(rtk_geometry_commit(g), RTK_OK);
        uint32_t id = 0;
        assert_int_equal(rtk_scene_attach_geometry(scene, g, &id), RTK_OK);
        assert_int_equal(rtk_scene_commit(scene), RTK_OK);

        rtk_scene_info info = {.struct_size = sizeof info}, dinfo = {.struct_size = sizeof dinfo};
        assert_int_equal(rtk_scene_get_info(scene, &info), RTK_OK);
        assert_int_equal(rtk_scene_get_info(def, &dinfo), RTK_OK);
        assert_string_equal(info.layout, "bvh4.triangle4i");
        assert_int_equal(info.flags_not_honoured, 0);
        if (!(info.bytes < dinfo.bytes))
            fail_msg("[%s] compact %llu bytes, default %llu", names[b], (unsigned long long)info.bytes,
                     (unsigned long long)dinfo.bytes);
        for (float x = 0.05f; x < 1.0f; x += 0.1f) {
            rtk_rayhit a = down_at(x, 0.3f), c = down_at(x, 0.3f);
            assert_int_equal(rtk_intersect1(def, &a), RTK_OK);
            assert_int_equal(rtk_intersect1(scene, &c), RTK_OK);
            assert_memory_equal(&a, &c, sizeof a);
        }

        /* Replace the vertex buffer and drop the geometry, without a commit:
         * the BVH still reads the old vertices, which must still be there. */
        void *vb2 = NULL;
        assert_int_equal(rtk_geometry_set_new_buffer(g, RTK_BUFFER_TYPE_VERTEX, 12, 3, &vb2), RTK_OK);
        assert_int_equal(rtk_scene_detach_geometry(scene, id), RTK_OK);
        rtk_geometry_release(g);
        rtk_rayhit a = down_at(0.5f, 0.25f), c = down_at(0.5f, 0.25f);
        assert_int_equal(rtk_intersect1(def, &a), RTK_OK);
        assert_int_equal(rtk_intersect1(scene, &c), RTK_OK);
        assert_memory_equal(&a, &c, sizeof a);
        /* the next commit lets go of it: an empty scene */
        assert_int_equal(rtk_scene_commit(scene), RTK_OK);
        c = down_at(0.5f, 0.25f);
        assert_int_equal(rtk_intersect1(scene, &c), RTK_OK);
        assert_int_equal(c.hit.geomID, RTK_INVALID_GEOMETRY_ID);
        rtk_scene_release(scene);
        rtk_scene_release(def);
        rtk_device_release(dev);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_version),
        cmocka_unit_test(test_release_null_is_noop),
        cmocka_unit_test(test_null_arguments),
        cmocka_unit_test(test_bad_config),
        cmocka_unit_test(test_error_callback),
        cmocka_unit_test(test_geometry_ids),
        cmocka_unit_test(test_geometry_types_apart),
        cmocka_unit_test(test_index_out_of_range),
        cmocka_unit_test(test_nonfinite_vertices),
        cmocka_unit_test(test_empty_scene),
        cmocka_unit_test(test_geometry_lifecycle),
        cmocka_unit_test(test_flags_reported),
        cmocka_unit_test(test_owned_buffer_copy_semantics),
        cmocka_unit_test(test_packet_arguments),
        cmocka_unit_test(test_compact_scene),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
