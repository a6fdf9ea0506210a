/* Mesh import: every input triangle kept, polygons triangulated, malformed
 * files rejected with a clear error (and never a crash); rtk's .rtkm file
 * (round trip, damage detected) and the clean-ups of rtktool convert; the
 * .rtkb BVH dump (round trip to the same hits, every damaged byte refused)
 * and the tree statistics against what the library reports. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bvh_stats.h"
#include "mesh_import.h"
#include "mesh_tools.h"
#include "rtkb.h"
#include "rtkm.h"
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

/* OBJ numbers: a vertex line OpenMesh cannot read all three coordinates
 * of was dropped, so every later index named the next vertex (the file
 * below converted to the triangle (0,0,0), (0,1,0), (9,9,9)); now such a
 * file is refused, naming the line and the word.  Vertex references are
 * checked against the vertices (an index beyond int range was read as
 * -2), and bytes of a binary file are shown escaped in messages. */
static void test_obj_numbers(void **state)
{
    (void)state;
    const char *bad[] = {"1e39", "-1e39", "nan", "NaN", "inf", "-inf", "1x", "0x1p3", "1e", "--1", ".", "1..2", "1,5"};
    char text[256];
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        snprintf(text, sizeof text, "v 0 0 0\nv %s 0 0\nv 1 0 0\nv 0 1 0\nv 9 9 9\nf 1 3 4\n", bad[i]);
        char needle[96];
        snprintf(needle, sizeof needle, "malformed OBJ: line 2: vertex coordinate '%s' is not a decimal number", bad[i]);
        expect_error(write_text("num.obj", text), needle);
    }
    expect_error(write_text("two.obj", "v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"), "line 1: a vertex needs three coordinates");
    expect_error(write_text("big.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999\n"),
                 "line 4: the face refers to vertex 99999999999, but the file has 3 vertices");
    expect_error(write_text("neg.obj", "v 0 0 0\nv 1 0 0\nf 1 2 -3\nv 0 1 0\n"),
                 "line 3: the face refers to vertex -3, but only 2 vertices come before it");
    expect_error(write_text("bin.obj", "v 0 0 \x01\xfe\n"), "vertex coordinate '\\x01\\xfe'");
    /* what the reader takes: signs, exponents, leading or trailing points,
     * values below the smallest float (read as 0, as OpenMesh reads them),
     * a fourth coordinate, faces before their vertices, negative references */
    rtk_mesh m;
    char err[512];
    const char *good = "v +1.5e+2 -0 .5\nv 5. 1E-3 -2e-50\nv 0 1 0 1\nf 1 2 3\nf -3 -2 -1\nf 1 2 4\nv 1 1 1\n";
    assert_int_equal(rtk_mesh_load(write_text("good.obj", good), &m, err, sizeof err), 0);
    assert_int_equal(m.vertex_count, 4);
    assert_int_equal(m.triangle_count, 3);
    assert_true(m.vertices[0] == 150.0f && m.vertices[2] == 0.5f && m.vertices[3] == 5.0f && m.vertices[5] == 0.0f);
    assert_int_equal(m.indices[6], 0);
    assert_int_equal(m.indices[8], 3);
    rtk_mesh_free(&m);
}

/* STL: OpenMesh takes a .stl for binary when its size is 84 + 50 n bytes
 * (n at byte 80), else for ASCII, and checked nothing more: half a binary
 * file and a header claiming 2^32 - 1 triangles loaded as 0 triangles, an
 * ASCII file without endsolid loaded what it had.  Each is refused now,
 * with the reason, and so are non-finite or unreadable coordinates and
 * every mutation of the ASCII structure below. */
static size_t stl_binary(unsigned char *out, uint32_t claimed, uint32_t tris, float bad)
{
    memset(out, 'x', 80);
    memcpy(out + 80, &claimed, 4);
    size_t n = 84;
    for (uint32_t t = 0; t < tris; t++) {
        const float f[12] = {0, 0, 1, 0, 0, 0, t ? bad : 1.0f, 0, 0, 0, 1, (float)t};
        memcpy(out + n, f, sizeof f);
        memset(out + n + 48, 0, 2);
        n += 50;
    }
    return n;
}

static void test_stl_checked(void **state)
{
    (void)state;
    rtk_mesh m;
    char err[512];
    unsigned char bin[84 + 50 * 8];
    size_t n = stl_binary(bin, 4, 4, 1.0f);
    assert_int_equal(rtk_mesh_load(write_file("b.stl", bin, n), &m, err, sizeof err), 0);
    assert_int_equal(m.triangle_count, 4);
    rtk_mesh_free(&m);
    assert_int_equal(rtk_mesh_load(write_file("b.stlb", bin, n), &m, err, sizeof err), 0);
    rtk_mesh_free(&m);
    expect_error(write_file("half.stl", bin, n / 2), "neither binary (the header's 4 triangles need 284 bytes, the file has 142)");
    expect_error(write_file("half.stlb", bin, n / 2), "the header says 4 triangles, which take 284 bytes; the file has 142");
    expect_error(write_file("short.stlb", bin, 40), "a binary STL needs an 84-byte header");
    n = stl_binary(bin, 0xffffffffu, 0, 0.0f);
    memset(bin + n, 'y', 16);
    expect_error(write_file("huge.stl", bin, n + 16), "the header's 4294967295 triangles need 214748364834 bytes");
    n = stl_binary(bin, 2, 2, NAN);
    expect_error(write_file("nan.stl", bin, n), "triangle 1 has a vertex coordinate that is not finite");
    n = stl_binary(bin, 2, 2, INFINITY);
    expect_error(write_file("inf.stl", bin, n), "triangle 1 has a vertex coordinate that is not finite");

    const char *facet = "facet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\n";
    char text[1024];
    snprintf(text, sizeof text, "solid a\n%s%sendsolid a\nsolid b\n%sendsolid b\n", facet, facet, facet);
    assert_int_equal(rtk_mesh_load(write_text("multi.stl", text), &m, err, sizeof err), 0);
    assert_int_equal(m.triangle_count, 3);
    rtk_mesh_free(&m);
    snprintf(text, sizeof text, "SOLID a\n%sENDSOLID\n", facet);
    assert_int_equal(rtk_mesh_load(write_text("upper.stla", text), &m, err, sizeof err), 0);
    rtk_mesh_free(&m);
    snprintf(text, sizeof text, "solid a\n%s", facet);
    expect_error(write_text("noend.stl", text), "the file ends inside a solid, before 'endsolid'");
    /* every line of a facet in turn dropped, doubled or garbled */
    const char *lines[] = {"facet normal 0 0 1", "outer loop", "vertex 0 0 0", "vertex 1 0 0", "vertex 0 1 0",
                           "endloop", "endfacet"};
    for (int drop = 0; drop < 7; drop++)
        for (int how = 0; how < 3; how++) {
            size_t at = (size_t)snprintf(text, sizeof text, "solid m\n");
            for (int l = 0; l < 7; l++) {
                if (l == drop && how == 0)
                    continue;
                at += (size_t)snprintf(text + at, sizeof text - at, "%s\n", l == drop && how == 2 ? "vertex 1x 0 0" : lines[l]);
                if (l == drop && how == 1)
                    at += (size_t)snprintf(text + at, sizeof text - at, "%s\n", lines[l]);
            }
            snprintf(text + at, sizeof text - at, "endsolid m\n");
            expect_error(write_text("mut.stl", text), "malformed STL: line");
        }
    snprintf(text, sizeof text, "solid a\n%sendsolid a\ntrailing words\n", facet);
    expect_error(write_text("trail.stl", text), "expected another 'solid' or the end after 'endsolid'");
    expect_error(write_text("notsolid.stl", "this is not an stl file at all, and it is long enough to hold the eighty bytes of a binary header\n"),
                 "nor ASCII (it does not begin with 'solid')");
}

static void test_malformed(void **state)
{
    (void)state;
    expect_error("/nonexistent/mesh.ply", "No such file");
    expect_error(dir, "not a regular file");
    expect_error(write_text("a.xyz", "1 2 3\n"), "unknown mesh format");
    expect_error(write_text("noext", "1 2 3\n"), "unknown mesh format");
    /* A face line with no vertex reference OpenMesh can read (its reader
     * asserted on it, aborting the process: fuzz_mesh) */
    expect_error(write_text("slash.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf /1 3 2\n"), "malformed OBJ: line 4");
    expect_error(write_text("two.obj", "v 0 0 0\nv 1 0 0\nf 1 2\n"), "three or more vertex references");
    /* Index out of range. */
    expect_error(write_text("bad.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"),
                 "line 4: the face refers to vertex 9, but the file has 3 vertices");
    const char *ply_bad_index = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                                "0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n";
    expect_error(write_text("bad.ply", ply_bad_index), "face 0: a face refers to vertex index 7, out of range (3 vertices)");
    /* Garbage where a header should be. */
    expect_error(write_text("garbage.ply", "this is not a ply file\n\x01\x02\x03\nend_header\n"),
                 "malformed PLY header: the file does not start with ply");
    /* A header that never ends (OpenMesh's reader looped forever on it:
     * fuzz_mesh), and header lines PLY does not have. */
    expect_error(write_text("endless.ply", "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\n"),
                 "malformed PLY header: no end_header line");
    expect_error(write_text("type.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float3 x\nend_header\n0\n"),
                 "expected property TYPE NAME");
    expect_error(write_text("word.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nwhat\n"
                                        "end_header\n0\n"),
                 "unknown line 'what'");
    /* OpenMesh reads the words of an obj_info line as header words: with
     * "element face" there it logged without end until memory ran out
     * (fuzz_mesh); "element vertex 4" gave 8 vertices, "property" and
     * "end_header" no faces.  Words it passes over still load. */
    const char *oi_head = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                          "property float z\n";
    const char *oi_tail = "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                          "0 0 0\n1 0 0\n2 1 0\n0 0 1\n3 0 1 2\n";
    const char *oi_bad[] = {"obj_info element vertex 4", "obj_info property", "obj_info end_header",
                            "obj_info x element", "obj_info element face"}; /* (the one that hung last) */
    char oi[512];
    for (size_t i = 0; i < sizeof oi_bad / sizeof *oi_bad; i++) {
        snprintf(oi, sizeof oi, "%s%s\n%s", oi_head, oi_bad[i], oi_tail);
        expect_error(write_text("objinfo.ply", oi), "malformed PLY header: an obj_info line holding");
    }
    snprintf(oi, sizeof oi, "%sobj_info num_cols 640\nobj_info vertex 3 elements\n%s", oi_head, oi_tail);
    {
        rtk_mesh m;
        char err[512];
        assert_int_equal(rtk_mesh_load(write_text("objinfo_ok.ply", oi), &m, err, sizeof err), 0);
        assert_int_equal(m.vertex_count, 4);
        assert_int_equal(m.triangle_count, 1);
        rtk_mesh_free(&m);
    }
    /* A face line after leading blanks: OpenMesh trims it, then asserted on
     * a word with no vertex (fuzz_mesh). */
    expect_error(write_text("lead.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n  f /1 2 3\n"),
                 "line 4: expected f and three or more vertex references");
    expect_error(write_text("garbage.off", "OFF\nlots of words\n"), "malformed OFF: expected vertex, face and edge counts");
    expect_error(write_text("garbage2.off", "NOT AN OFF\n3 1 0\n"), "malformed OFF: the file does not start with OFF");
    /* fuzz/fuzz_mesh: BINARY after OFF and a form feed, then more bytes, read
     * here as text but by OpenMesh as binary (counts of billions: a hang) */
    expect_error(write_text("binary_ff.off", "\x02OFF\fBINARY\xf6\xd8" "0 BINARY\n0 0 0\n0\n"),
                 "malformed OFF: the first line must be [ST][C][N]OFF");
    expect_error(write_text("binary_ff2.off", "OFF\fBINARY\n0 0 0\n0\n"), "malformed OFF: the first line must be");
    expect_error(write_text("binary_two.off", "OFF  BINARY\n0 0 0\n"), "malformed OFF: the first line must be");
    /* counts the file cannot hold (OpenMesh read millions of empty vertices: fuzz_mesh) */
    expect_error(write_text("many.off", "OFF\n25555555 4 0\n0 0 0\n"), "need at least 153333362 bytes");
    /* What OpenMesh's OFF reader misreads (fuzz_mesh): a face declaring
     * two billion vertices (it pushed that many indices, exhausting memory),
     * a comment where the counts go (left uninitialised), a vertex that does
     * not parse as floats and words after a face without C in the keyword
     * (each read after them fails or goes astray), a file cut short, and a
     * binary face whose count runs past the end. */
#define TRI "0 0 0\n1 0 0\n0 1 0\n"
    static const char *const off_cases[][3] = {
        {"bigface.off", "OFF\n3 1 0\n" TRI "2000000000 0 1 2\n", "face 0 needs its vertex count and that many"},
        {"comment.off", "OFF\n# made by hand\n3 1 0\n" TRI "3 0 1 2\n", "a comment after the keyword line (line 2)"},
        {"nan.off", "OFF\n3 1 0\n0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n", "line 4: vertex 1 needs 3 numbers in float"},
        {"range.off", "OFF\n3 1 0\n0 0 0\n1e39 0 0\n0 1 0\n3 0 1 2\n", "line 4: vertex 1 needs 3 numbers"},
        {"colour.off", "OFF\n3 2 0\n" TRI "3 0 1 2 255 0 0\n3 0 2 1\n", "(the keyword has no C for colours)"},
        {"negative.off", "OFF\n3 2 0\n" TRI "3 0 1 -2\n3 0 2 1\n", "line 6: face 0 needs its vertex count"},
        {"short.off", "OFF\n3 3 0\n" TRI "3 0 1 2\n3 0 2 1\n", "the file ends after 2 of 3 faces"},
    };
#undef TRI
    for (size_t k = 0; k < sizeof off_cases / sizeof *off_cases; k++)
        expect_error(write_text(off_cases[k][0], off_cases[k][1]), off_cases[k][2]);
    static const unsigned char bin[] = {'O', 'F', 'F', ' ', 'B', 'I', 'N', 'A', 'R', 'Y', '\n', 0, 0, 0, 0, 1, 0,
                                        0, 0, 0, 0, 0, 0, 0, 0, 0, 0x80, 0, 0, 0, 0};
    expect_error(write_file("bigface_binary.off", bin, sizeof bin), "face 0 declares 2147483648 vertices");
    /* With C, a face's colour follows its indices; blank lines anywhere. */
    rtk_mesh m;
    char err[512];
    const char *coff = "COFF\n\n3 1 0\n0 0 0 255 0 0\n\n1 0 0 0 255 0\n0 1 0 0 0 255\n3 0 1 2 9 9 9\n";
    assert_int_equal(rtk_mesh_load(write_text("c.off", coff), &m, err, sizeof err), 0);
    assert_int_equal(m.triangle_count, 1);
    assert_int_equal(m.indices[2], 2);
    rtk_mesh_free(&m);
    /* A binary PLY cut short, and one whose header promises absurd counts. */
    FILE *f = fopen(RTK_TEST_DATA "/bunny.ply", "rb");
    assert_non_null(f);
    static char buf[4096];
    size_t n = fread(buf, 1, sizeof buf, f);
    fclose(f);
    expect_error(write_file("cut.ply", buf, n), "its elements need at least");
    const char *huge = "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\n"
                       "property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                       "end_header\n";
    expect_error(write_text("huge.ply", huge), "its elements need at least 48000000001 bytes");
    expect_error(write_text("huger.ply", "ply\nformat ascii 1.0\nelement vertex 4888888888888888888\n"
                                         "property float x\nproperty float y\nend_header\n0 0\n"),
                 "its elements need at least 195555555555555");
    /* Lists whose counts the file cannot hold (OpenMesh pushed that many
     * values, exhausting memory: fuzz_mesh), and a value that does not read
     * as its type (every read after it goes astray), ascii and binary. */
    const char *ply_head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                           "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
    char ply_text[512];
    snprintf(ply_text, sizeof ply_text, "%s0 0 0\n1 0 0\n0 1 0\n4000000000 0 1 2\n", ply_head);
    expect_error(write_text("biglist.ply", ply_text), "element 1 item 0: a list count '4000000000'");
    snprintf(ply_text, sizeof ply_text, "%s0 0 0\n1 0 0\n0 1 0\n-2 0 1\n", ply_head);
    expect_error(write_text("neglist.ply", ply_text), "a list count '-2'");
    snprintf(ply_text, sizeof ply_text, "%s0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n", ply_head);
    expect_error(write_text("nanvalue.ply", ply_text), "element 0 item 1: 'nan' is not a float");
    static const char bin_head[] = "ply\nformat binary_little_endian 1.0\nelement face 1\n"
                                   "property list int int vertex_indices\nend_header\n";
    char bin_ply[sizeof bin_head + 16];
    memcpy(bin_ply, bin_head, sizeof bin_head - 1);
    const unsigned char count_le[8] = {0, 0, 0, 0x40, 1, 0, 0, 0}; /* 2^30 indices, then one */
    memcpy(bin_ply + sizeof bin_head - 1, count_le, sizeof count_le);
    expect_error(write_file("biglist_binary.ply", bin_ply, sizeof bin_head - 1 + sizeof count_le),
                 "a list count of 1073741824 the rest of the file cannot hold");
    /* the second of two binary faces cut short in its count, then in its
     * indices, and a negative count */
    static const char two_head[] = "ply\nformat binary_little_endian 1.0\nelement face 2\n"
                                   "property list int int vertex_indices\nend_header\n";
    char two_ply[sizeof two_head + 32];
    memcpy(two_ply, two_head, sizeof two_head - 1);
    const unsigned char faces_le[24] = {3, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 3, 0, 0, 0, 0, 0, 0, 0};
    memcpy(two_ply + sizeof two_head - 1, faces_le, sizeof faces_le);
    expect_error(write_file("cutcount.ply", two_ply, sizeof two_head - 1 + 18),
                 "malformed PLY: element 0 item 1: the file ends");
    expect_error(write_file("cutface.ply", two_ply, sizeof two_head - 1 + sizeof faces_le),
                 "malformed PLY: element 0 item 1: a list count of 3 the rest of the file cannot hold");
    const unsigned char minus_one[4] = {0xff, 0xff, 0xff, 0xff};
    memcpy(two_ply + sizeof two_head - 1 + 16, minus_one, sizeof minus_one);
    expect_error(write_file("negface.ply", two_ply, sizeof two_head - 1 + sizeof faces_le),
                 "element 0 item 1: a list count of a negative number");
    expect_error(write_text("empty.stl", ""), "empty file");
}

/* The sum of the triangles' areas. */
static double mesh_area(const rtk_mesh *m)
{
    double sum = 0.0;
    for (size_t t = 0; t < m->triangle_count; t++) {
        const float *a = &m->vertices[3 * m->indices[3 * t]], *b = &m->vertices[3 * m->indices[3 * t + 1]],
                    *c = &m->vertices[3 * m->indices[3 * t + 2]];
        const double e[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, f[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        const double n[3] = {e[1] * f[2] - e[2] * f[1], e[2] * f[0] - e[0] * f[2], e[0] * f[1] - e[1] * f[0]};
        sum += 0.5 * sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    }
    return sum;
}

static void test_om(void **state)
{
    (void)state;
    /* OpenMesh 9's OM writer on a PolyMesh: the unit quad 0-1-2-3 and the
     * triangle 1-4-2 with v4 = (2, 0, 0). */
    static const unsigned char om[] = {
        0x4f, 0x4d, 0x50, 0x42, 0x05, 0x00, 0x00, 0x00, 0x02, 0x00, 0x00, 0x00, 0x06, 0x00, 0x00, 0x00, 0x00, 0x16,
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x80, 0x3f, 0x00, 0x00,
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x80, 0x3f, 0x00, 0x00, 0x80, 0x3f, 0x00, 0x00, 0x00, 0x00,
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x80, 0x3f, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x40, 0x00, 0x00,
        0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0xf8, 0x16, 0x02, 0x01, 0x00, 0x07, 0x00, 0xff, 0x04, 0x02, 0x00, 0x08,
        0x01, 0x01, 0x06, 0x03, 0x00, 0x0b, 0x02, 0xff, 0x00, 0x00, 0x00, 0x05, 0x03, 0xff, 0x0a, 0x04, 0x01, 0x01,
        0x01, 0xff, 0x03, 0x02, 0x01, 0x09, 0x04, 0xff, 0xe0, 0x06, 0x07, 0x01, 0x0b, 0x05, 0x09, 0xe8, 0x06, 0x06,
        0x03, 0x1c, 0x00};
    rtk_mesh m;
    char err[512];
    if (rtk_mesh_load(write_file("quad.om", om, sizeof om), &m, err, sizeof err))
        fail_msg("%s", err);
    assert_int_equal(m.vertex_count, 5);
    assert_int_equal(m.faces_read, 2);
    assert_int_equal(m.polygons_triangulated, 1);
    assert_int_equal(m.triangle_count, 3);
    assert_float_equal(mesh_area(&m), 1.5, 1e-12);
    rtk_mesh_free(&m);
    expect_error(write_file("cut.om", om, 40), "OpenMesh could not read it");
}

static void test_rtkm_round_trip(void **state)
{
    (void)state;
    rtk_mesh a, b;
    char err[512];
    assert_int_equal(rtk_mesh_load(RTK_TEST_DATA "/bunny.ply", &a, err, sizeof err), 0);
    char path[512];
    snprintf(path, sizeof path, "%s/bunny.rtkm", dir);
    if (rtkm_save(path, &a, err, sizeof err))
        fail_msg("%s", err);
    if (rtk_mesh_load(path, &b, err, sizeof err))
        fail_msg("%s", err);
    assert_int_equal(b.vertex_count, a.vertex_count);
    assert_int_equal(b.triangle_count, a.triangle_count);
    assert_memory_equal(b.vertices, a.vertices, 12 * a.vertex_count);
    assert_memory_equal(b.indices, a.indices, 12 * a.triangle_count);
    rtk_mesh_free(&b);
    /* An empty mesh is a valid file too. */
    rtk_mesh empty = {0};
    snprintf(path, sizeof path, "%s/empty.rtkm", dir);
    assert_int_equal(rtkm_save(path, &empty, err, sizeof err), 0);
    assert_int_equal(rtk_mesh_load(path, &b, err, sizeof err), 0);
    assert_int_equal(b.triangle_count, 0);
    rtk_mesh_free(&b);
    /* Out-of-range indices are never written. */
    a.indices[7] = (uint32_t)a.vertex_count;
    snprintf(path, sizeof path, "%s/bad.rtkm", dir);
    assert_int_not_equal(rtkm_save(path, &a, err, sizeof err), 0);
    assert_non_null(strstr(err, "triangle 2 refers to vertex 35947 of 35947"));
    rtk_mesh_free(&a);
}

/* A small valid file's bytes, for damaging. */
static size_t small_rtkm(unsigned char *buf, size_t cap)
{
    static float v[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0};
    static uint32_t idx[] = {0, 1, 2, 1, 3, 2};
    const rtk_mesh m = {.vertices = v, .indices = idx, .vertex_count = 4, .triangle_count = 2};
    char err[256], path[512];
    snprintf(path, sizeof path, "%s/small.rtkm", dir);
    assert_int_equal(rtkm_save(path, &m, err, sizeof err), 0);
    FILE *f = fopen(path, "rb");
    assert_non_null(f);
    const size_t n = fread(buf, 1, cap, f);
    fclose(f);
    return n;
}

static void test_rtkm_damage(void **state)
{
    (void)state;
    unsigned char good[1024], bad[1024];
    const size_t n = small_rtkm(good, sizeof good);
    assert_int_equal(n, 192 + 24); /* header, 4 vertices at 128, the indices at 192 */
    rtk_mesh m;
    char err[256];
    assert_int_equal(rtk_mesh_load(write_file("ok.rtkm", good, n), &m, err, sizeof err), 0);
    rtk_mesh_free(&m);
    memcpy(bad, good, n);
    bad[0] = 'X';
    expect_error(write_file("magic.rtkm", bad, n), "not an .rtkm file (bad magic)");
    memcpy(bad, good, n);
    bad[8] = 2;
    expect_error(write_file("v2.rtkm", bad, n), ".rtkm version 2; this build reads version 1");
    expect_error(write_file("cut.rtkm", good, n - 1), "file is 215 bytes, the header says 216");
    expect_error(write_file("hdr.rtkm", good, 100), "truncated or malformed header");
    expect_error(write_file("tiny.rtkm", good, 5), "bad magic");
    memcpy(bad, good, n);
    bad[16] = 5; /* the vertex count */
    expect_error(write_file("count.rtkm", bad, n), "header checksum mismatch");
    memcpy(bad, good, n);
    bad[130] ^= 1; /* a vertex coordinate */
    expect_error(write_file("payload.rtkm", bad, n), "checksum mismatch (damaged file)");
    memcpy(bad, good, n);
    memcpy(bad + n, "\0\0\0\0", 4);
    expect_error(write_file("long.rtkm", bad, n + 4), "file is 220 bytes, the header says 216");
    /* Every byte outside the checksums (header bytes 88..127, the padding
     * after the 48 bytes of vertices at 128) is checked to be zero: every
     * single flipped byte of the file is refused. */
    for (size_t k = 0; k < n; k++) {
        memcpy(bad, good, n);
        bad[k] ^= 0x10;
        rtk_mesh m2;
        char e2[256];
        if (rtk_mesh_load(write_file("flip.rtkm", bad, n), &m2, e2, sizeof e2) == 0)
            fail_msg("byte %zu flipped: the file still loads", k);
    }
    memcpy(bad, good, n);
    bad[100] = 1;
    expect_error(write_file("zero.rtkm", bad, n), "header byte 100 is 1 where the format has zero");
    memcpy(bad, good, n);
    bad[180] = 1;
    expect_error(write_file("pad.rtkm", bad, n), "non-zero bytes in the padding");
    /* a directory where a file should be */
    expect_error(dir, "not a regular file");
}

static void test_merge_and_drop(void **state)
{
    (void)state;
    /* v3 repeats v1 (with -0.0 for +0.0), v4 repeats v0; v5 is NaN.
     * Triangles: a good one, the same over the duplicates, one with a
     * repeated vertex, one collinear, one with the NaN vertex. */
    float v[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 1, -0.0f, 0, 0, 0, 0, NAN, 0, 0, 2, 0, 0};
    uint32_t idx[] = {0, 1, 2, 4, 3, 2, 0, 0, 1, 0, 1, 6, 0, 5, 2};
    rtk_mesh m = {.vertices = malloc(sizeof v), .indices = malloc(sizeof idx), .vertex_count = 7,
                  .triangle_count = 5};
    memcpy(m.vertices, v, sizeof v);
    memcpy(m.indices, idx, sizeof idx);
    size_t degenerate, non_finite;
    rtk_mesh_count_unhittable(&m, &degenerate, &non_finite);
    assert_int_equal(degenerate, 2);
    assert_int_equal(non_finite, 1);
    assert_int_equal(rtk_mesh_merge_vertices(&m), 2);
    assert_int_equal(m.vertex_count, 5);
    const uint32_t merged[] = {0, 1, 2, 0, 1, 2, 0, 0, 1, 0, 1, 4, 0, 3, 2};
    assert_memory_equal(m.indices, merged, sizeof merged);
    assert_true(isnan(m.vertices[9]));
    assert_float_equal(m.vertices[12], 2.0f, 0.0f);
    rtk_mesh_drop_unhittable(&m, &degenerate, &non_finite);
    assert_int_equal(degenerate, 2);
    assert_int_equal(non_finite, 1);
    assert_int_equal(m.triangle_count, 2);
    assert_memory_equal(m.indices, merged, 6 * sizeof(uint32_t));
    rtk_mesh_free(&m);
}


/* ---- the .rtkb BVH dump ---- */

static rtk_scene scene_over(rtk_device dev, const rtk_mesh *m, const rtk_bvh *tree)
{
    rtk_scene s = test_scene_uncommitted(dev, m->vertices, m->vertex_count, m->indices, m->triangle_count, 0);
    const rtk_error err = tree ? rtk_scene_commit_bvh(s, tree) : rtk_scene_commit(s);
    if (err)
        fail_msg("commit: %s", rtk_device_get_error_message(dev));
    return s;
}

static void save_dump(rtk_scene s, const rtk_mesh *m, const char *path)
{
    rtk_bvh t = {.struct_size = sizeof t};
    assert_int_equal(rtk_scene_get_bvh(s, &t), RTK_OK);
    rtkb_info info = {.mesh_triangles = m->triangle_count, .mesh_vertices = m->vertex_count,
                      .mesh_checksum = rtkm_mesh_checksum(m), .bytes = 1234, .build_seconds = 0.5, .sah_cost = 7.0};
    snprintf(info.layout, sizeof info.layout, "bvh8.triangle4");
    snprintf(info.builder, sizeof info.builder, "sah-binned");
    char err[512];
    if (rtkb_save(path, &t, &info, err, sizeof err))
        fail_msg("%s", err);
    rtk_bvh_free(&t);
}

/* Saved, loaded, committed: the same tree, statistics and hits; and the
 * statistics rtktool prints agree with the library's own. */
static void test_rtkb_round_trip(void **state)
{
    (void)state;
    rtk_mesh m;
    char err[512], path[512];
    assert_int_equal(rtk_mesh_load(RTK_TEST_DATA "/bunny.ply", &m, err, sizeof err), 0);
    rtk_device dev;
    assert_int_equal(rtk_device_new("", &dev), RTK_OK);
    rtk_scene a = scene_over(dev, &m, NULL);
    snprintf(path, sizeof path, "%s/bunny.rtkb", dir);
    save_dump(a, &m, path);
    rtkb_file f;
    if (rtkb_load(path, &f, err, sizeof err))
        fail_msg("%s", err);
    assert_string_equal(f.info.layout, "bvh8.triangle4");
    assert_string_equal(f.info.builder, "sah-binned");
    assert_int_equal(f.info.mesh_checksum, rtkm_mesh_checksum(&m));
    assert_true(f.info.build_seconds == 0.5 && f.info.sah_cost == 7.0 && f.info.bytes == 1234);
    rtk_bvh t = {.struct_size = sizeof t};
    assert_int_equal(rtk_scene_get_bvh(a, &t), RTK_OK);
    assert_int_equal(f.tree.node_count, t.node_count);
    assert_int_equal(f.tree.leaf_count, t.leaf_count);
    assert_int_equal(f.tree.prim_count, t.prim_count);
    assert_memory_equal(f.tree.children, t.children, t.node_count * t.width * 4);
    assert_memory_equal(f.tree.child_lower, t.child_lower, t.node_count * t.width * 12);
    assert_memory_equal(f.tree.child_upper, t.child_upper, t.node_count * t.width * 12);
    assert_memory_equal(f.tree.leaf_first, t.leaf_first, (t.leaf_count + 1) * 8);
    assert_memory_equal(f.tree.prims, t.prims, t.prim_count * 8);

    /* rtktool's statistics against the library's */
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(a, &info), RTK_OK);
    bvh_stats st;
    assert_int_equal(bvh_stats_compute(&f.tree, &st), 0);
    assert_int_equal(st.nodes, info.nodes);
    assert_int_equal(st.leaf_blocks, info.leaves);
    assert_int_equal(st.prims, info.triangles);
    assert_int_equal(st.depth_max, info.depth);
    assert_true(fabs(st.sah - info.sah_cost) <= 1e-4 * info.sah_cost);
    uint64_t leaves = 0, prims = 0;
    for (int b = 0; b < BVH_STATS_LEAF_BINS; b++) {
        leaves += st.leaf_prims[b];
        prims += st.leaf_prims[b] * (uint64_t)(b + 1);
    }
    assert_int_equal(leaves, st.leaves);
    assert_int_equal(prims, st.prims); /* no leaf holds more than 16 */
    assert_memory_equal(st.lower, info.bounds_lower, sizeof st.lower);
    assert_memory_equal(st.upper, info.bounds_upper, sizeof st.upper);

    /* The dump committed traces exactly like the built scene. */
    rtk_scene b = scene_over(dev, &m, &f.tree);
    rng r = {42};
    for (int i = 0; i < 20000; i++) {
        rtk_rayhit x = {.ray = test_ray(-0.2f + 0.4f * rng_float(&r), 0.3f * rng_float(&r), 0.3f,
                                        rng_float(&r) - 0.5f, rng_float(&r) - 0.5f, -1.0f, 0.0f, INFINITY)};
        x.hit.geomID = RTK_INVALID_GEOMETRY_ID;
        rtk_rayhit y = x;
        rtk_intersect1(a, &x);
        rtk_intersect1(b, &y);
        assert_memory_equal(&x, &y, sizeof x);
    }
    snprintf(path, sizeof path, "%s/boxes.png", dir);
    assert_int_equal(bvh_picture(&f.tree, &st, 8, 64, path, err, sizeof err), 0);
    rtk_bvh_free(&t);
    rtkb_free(&f);
    rtk_scene_release(a);
    rtk_scene_release(b);
    rtk_device_release(dev);
    rtk_mesh_free(&m);
}

/* A small dump damaged one byte at a time, everywhere, and cut short:
 * always refused with a message, never loaded, never a crash. */
static void test_rtkb_damage(void **state)
{
    (void)state;
    static float v[60 * 9];
    static uint32_t idx[60 * 3];
    rng r = {77};
    for (int i = 0; i < 60 * 9; i++)
        v[i] = rng_float(&r);
    for (uint32_t i = 0; i < 60 * 3; i++)
        idx[i] = i;
    const rtk_mesh m = {.vertices = v, .indices = idx, .vertex_count = 180, .triangle_count = 60};
    rtk_device dev;
    assert_int_equal(rtk_device_new("", &dev), RTK_OK);
    rtk_scene s = scene_over(dev, &m, NULL);
    char path[512], err[512];
    snprintf(path, sizeof path, "%s/small.rtkb", dir);
    save_dump(s, &m, path);
    rtk_scene_release(s);
    rtk_device_release(dev);

    FILE *fp = fopen(path, "rb");
    assert_non_null(fp);
    static unsigned char good[1 << 16], bad[1 << 16];
    const size_t n = fread(good, 1, sizeof good, fp);
    fclose(fp);
    assert_true(n > 256 && n < sizeof good);
    rtkb_file f;
    assert_int_equal(rtkb_load(write_file("ok.rtkb", good, n), &f, err, sizeof err), 0);
    rtkb_free(&f);
    /* a directory is not a dump ('bad magic' before) */
    assert_int_not_equal(rtkb_load(dir, &f, err, sizeof err), 0);
    assert_non_null(strstr(err, "not a regular file"));
    for (size_t at = 0; at < n; at++) {
        memcpy(bad, good, n);
        bad[at] ^= (unsigned char)(1u << (at % 8));
        const char *p = write_file("bad.rtkb", bad, n);
        if (rtkb_load(p, &f, err, sizeof err) == 0)
            fail_msg("byte %zu flipped: the dump still loads", at);
        assert_null(f.data);
        assert_non_null(strstr(err, "bad.rtkb: "));
    }
    for (size_t cut = 0; cut < n; cut += 1 + cut / 3) {
        if (rtkb_load(write_file("cut.rtkb", good, cut), &f, err, sizeof err) == 0)
            fail_msg("cut to %zu bytes: the dump still loads", cut);
    }
    memcpy(bad, good, n);
    bad[n] = 0;
    assert_int_not_equal(rtkb_load(write_file("long.rtkb", bad, n + 1), &f, err, sizeof err), 0);
    assert_non_null(strstr(err, "truncated or padded"));
    bad[8] = 2;
    assert_int_not_equal(rtkb_load(write_file("v2.rtkb", bad, n), &f, err, sizeof err), 0);
    assert_non_null(strstr(err, ".rtkb version 2; this build reads version 1"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_obj_polygons_and_nonmanifold),
        cmocka_unit_test(test_ply_off_stl),
        cmocka_unit_test(test_malformed),
        cmocka_unit_test(test_obj_numbers),
        cmocka_unit_test(test_stl_checked),
        cmocka_unit_test(test_om),
        cmocka_unit_test(test_rtkm_round_trip),
        cmocka_unit_test(test_rtkm_damage),
        cmocka_unit_test(test_merge_and_drop),
        cmocka_unit_test(test_rtkb_round_trip),
        cmocka_unit_test(test_rtkb_damage),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
