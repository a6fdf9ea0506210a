/* Mesh import: every input triangle kept, polygons triangulated, malformed
 * files rejected with a clear error (and never a crash). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "mesh_import.h"
#include "testlib.h"

static char dir[256];

static int setup(void **state)
{
    (void)state;
    snprintf(dir, sizeof dir, "/tmp/rtk_test_import_XXXXXX");
    return mkdtemp(dir) ? 0 : -1;
}

static int teardown(void **state)
{
    (void)state;
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    return system(cmd) == 0 ? 0 : -1;
}

static const char *write_file(const char *name, const void *data, size_t size)
{
    static char path[512];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite(data, 1, size, f), size);
    fclose(f);
    return path;
}

static const char *write_text(const char *name, const char *text)
{
    return write_file(name, text, strlen(text));
}

static void expect_error(const char *path, const char *needle)
{
    rtk_mesh m;
    char err[1024] = "";
    if (rtk_mesh_load(path, &m, err, sizeof err) == 0)
        fail_msg("%s loaded (%zu triangles) but should have been rejected", path, m.triangle_count);
    assert_null(m.vertices);
    assert_int_equal(m.triangle_count, 0);
    if (!strstr(err, needle))
        fail_msg("error '%s' lacks '%s'", err, needle);
}

static void test_obj_polygons_and_nonmanifold(void **state)
{
    (void)state;
    /* A quad (two triangles), and three triangles on one edge (1-2): a
     * non-manifold fan OpenMesh's mesh importer would split off.  (OpenMesh's
     * OBJ reader itself drops faces that repeat a vertex, so the last face
     * never arrives; PLY and OFF keep it, see test_ply_off_stl.) */
    const char *obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 1 0 1\nv 1 0 -1\nv 2 0 0\n"
                      "f 1 2 3 4\n"
                      "f 2 3 5\n"
                      "f 2 3 6\n"
                      "f 2 3 7\n"
                      "f 1 1 2\n";
    rtk_mesh m;
    char err[512];
    assert_int_equal(rtk_mesh_load(write_text("a.obj", obj), &m, err, sizeof err), 0);
    assert_int_equal(m.vertex_count, 7);
    assert_int_equal(m.faces_read, 4);
    assert_int_equal(m.triangle_count, 5);
    assert_int_equal(m.polygons_triangulated, 1);
    assert_int_equal(m.vertices_duplicated, 0);
    const uint32_t want[] = {0, 1, 2, 0, 2, 3, 1, 2, 4, 1, 2, 5, 1, 2, 6};
    assert_memory_equal(m.indices, want, sizeof want);
    assert_float_equal(m.vertices[3 * 6], 2.0f, 0.0f);
    rtk_mesh_free(&m);
}

static void test_ply_off_stl(void **state)
{
    (void)state;
    rtk_mesh m;
    char err[512];
    const char *ply = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                      "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
                      "0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n";
    assert_int_equal(rtk_mesh_load(write_text("a.ply", ply), &m, err, sizeof err), 0);
    assert_int_equal(m.triangle_count, 2);
    rtk_mesh_free(&m);
    /* A face that repeats a vertex has no area but is kept, and counted. */
    const char *rep = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                      "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
                      "0 0 0\n1 0 0\n0 1 0\n3 0 0 1\n3 0 1 2\n";
    assert_int_equal(rtk_mesh_load(write_text("rep.ply", rep), &m, err, sizeof err), 0);
    assert_int_equal(m.triangle_count, 2);
    assert_int_equal(m.faces_repeated_vertex, 1);
    rtk_mesh_free(&m);
    const char *off = "OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n";
    assert_int_equal(rtk_mesh_load(write_text("a.off", off), &m, err, sizeof err), 0);
    assert_int_equal(m.triangle_count, 2);
    rtk_mesh_free(&m);
    const char *stl = "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 1 1 0\nendloop\n"
                      "endfacet\nendsolid t\n";
    assert_int_equal(rtk_mesh_load(write_text("a.stl", stl), &m, err, sizeof err), 0);
    assert_int_equal(m.triangle_count, 1);
    rtk_mesh_free(&m);
    /* The bundled and shared meshes load whole. */
    assert_int_equal(rtk_mesh_load(RTK_TEST_DATA "/bunny.ply", &m, err, sizeof err), 0);
    assert_int_equal(m.triangle_count, 69451);
    assert_int_equal(m.vertex_count, 35947);
    rtk_mesh_free(&m);
}

static void test_malformed(void **state)
{
    (void)state;
    expect_error("/nonexistent/mesh.ply", "No such file");
    expect_error(dir, "not a regular file");
    expect_error(write_text("a.xyz", "1 2 3\n"), "unknown mesh format");
    expect_error(write_text("noext", "1 2 3\n"), "unknown mesh format");
    /* Index out of range. */
    expect_error(write_text("bad.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"), "refers to vertex 8 of 3");
    const char *ply_bad_index = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                                "0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n";
    expect_error(write_text("bad.ply", ply_bad_index), "face 0: a face refers to vertex 7 of 3");
    /* Garbage where a header should be. */
    expect_error(write_text("garbage.ply", "this is not a ply file\n\x01\x02\x03"), "OpenMesh could not read it");
    expect_error(write_text("garbage.off", "OFF\nlots of words\n"), "malformed OFF: expected vertex, face and edge counts");
    expect_error(write_text("garbage2.off", "NOT AN OFF\n3 1 0\n"), "malformed OFF: the file does not start with OFF");
    /* A binary PLY cut short, and one whose header promises absurd counts. */
    FILE *f = fopen(RTK_TEST_DATA "/bunny.ply", "rb");
    assert_non_null(f);
    static char buf[4096];
    size_t n = fread(buf, 1, sizeof buf, f);
    fclose(f);
    expect_error(write_file("cut.ply", buf, n), "Unexpected end of file");
    const char *huge = "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\n"
                       "property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                       "end_header\n";
    expect_error(write_text("huge.ply", huge), "Unexpected end of file");
    expect_error(write_text("empty.stl", ""), "empty file");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_obj_polygons_and_nonmanifold),
        cmocka_unit_test(test_ply_off_stl),
        cmocka_unit_test(test_malformed),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
