// Mesh import through OpenMesh's readers into a triangle soup.  See mesh_import.h.
#include "mesh_import.h"
#include "rtkm.h"

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <new>
#include <sstream>
#include <string>
#include <sys/stat.h>
#include <vector>

#include <OpenMesh/Core/IO/MeshIO.hh> // registers the readers
#include <OpenMesh/Core/IO/IOManager.hh>
#include <OpenMesh/Core/IO/Options.hh>
#include <OpenMesh/Core/IO/importer/BaseImporter.hh>
#include <OpenMesh/Core/Mesh/PolyMesh_ArrayKernelT.hh>
#include <OpenMesh/Core/System/omstream.hh>

namespace {

using namespace OpenMesh;

// Receives what OpenMesh's readers parse; keeps positions and faces only.
class SoupImporter : public IO::BaseImporter {
public:
    std::vector<float> points;
    std::vector<uint32_t> tris;
    size_t faces = 0, polygons = 0, repeated = 0, bad_faces = 0;
    std::string first_bad;

    VertexHandle add_vertex(const Vec3f &p) override
    {
        points.push_back(p[0]);
        points.push_back(p[1]);
        points.push_back(p[2]);
        return VertexHandle(int(points.size() / 3 - 1));
    }
    VertexHandle add_vertex() override { return add_vertex(Vec3f(0.0f, 0.0f, 0.0f)); }

    FaceHandle add_face(const VHandles &idx) override
    {
        faces++;
        add_polygon(idx, faces - 1);
        return FaceHandle(int(faces - 1));
    }

    // Splits one face (vertex handles in order) into a fan of triangles.
    void add_polygon(const VHandles &idx, size_t face)
    {
        const size_t nv = points.size() / 3;
        if (idx.size() < 3) {
            note_bad(face, "a face with fewer than three vertices");
            return;
        }
        for (const VertexHandle &v : idx)
            if (v.idx() < 0 || size_t(v.idx()) >= nv) {
                note_bad(face, "a face refers to vertex " + std::to_string(v.idx()) + " of " + std::to_string(nv));
                return;
            }
        if (idx.size() > 3)
            polygons++;
        for (size_t i = 0; i < idx.size(); i++)
            for (size_t j = i + 1; j < idx.size(); j++)
                if (idx[i] == idx[j]) {
                    repeated++;
                    i = j = idx.size();
                }
        for (size_t k = 1; k + 1 < idx.size(); k++) {
            tris.push_back(uint32_t(idx[0].idx()));
            tris.push_back(uint32_t(idx[k].idx()));
            tris.push_back(uint32_t(idx[k + 1].idx()));
        }
    }

    void note_bad(size_t face, const std::string &what)
    {
        if (!bad_faces++)
            first_bad = "face " + std::to_string(face) + ": " + what;
    }

    // Topology-based input is OpenMesh's own OM format, read through a
    // PolyMesh instead (read_om): refused here.
    HalfedgeHandle add_edge(VertexHandle, VertexHandle) override { return HalfedgeHandle(); }
    FaceHandle add_face(HalfedgeHandle) override { return FaceHandle(); }
    void set_next(HalfedgeHandle, HalfedgeHandle) override {}

    // Attributes rtk does not use.
    void add_face_texcoords(FaceHandle, VertexHandle, const std::vector<Vec2f> &) override {}
    void add_face_texcoords(FaceHandle, VertexHandle, const std::vector<Vec3f> &) override {}
    void set_face_texindex(FaceHandle, int) override {}
    void set_point(VertexHandle v, const Vec3f &p) override
    {
        if (v.idx() >= 0 && size_t(v.idx()) < points.size() / 3)
            for (int k = 0; k < 3; k++)
                points[size_t(v.idx()) * 3 + size_t(k)] = p[k];
    }
    void set_halfedge(VertexHandle, HalfedgeHandle) override {}
    void set_normal(VertexHandle, const Vec3f &) override {}
    void set_normal(VertexHandle, const Vec3d &) override {}
    void set_color(VertexHandle, const Vec3uc &) override {}
    void set_color(VertexHandle, const Vec4uc &) override {}
    void set_color(VertexHandle, const Vec3f &) override {}
    void set_color(VertexHandle, const Vec4f &) override {}
    void set_texcoord(VertexHandle, const Vec2f &) override {}
    void set_status(VertexHandle, const Attributes::StatusInfo &) override {}
    void set_face(HalfedgeHandle, FaceHandle) override {}
    void request_face_texcoords2D() override {}
    void set_texcoord(HalfedgeHandle, const Vec2f &) override {}
    void set_texcoord(VertexHandle, const Vec3f &) override {}
    void set_texcoord(HalfedgeHandle, const Vec3f &) override {}
    void set_status(HalfedgeHandle, const Attributes::StatusInfo &) override {}
    void set_color(EdgeHandle, const Vec3uc &) override {}
    void set_color(EdgeHandle, const Vec4uc &) override {}
    void set_color(EdgeHandle, const Vec3f &) override {}
    void set_color(EdgeHandle, const Vec4f &) override {}
    void set_status(EdgeHandle, const Attributes::StatusInfo &) override {}
    void set_normal(FaceHandle, const Vec3f &) override {}
    void set_normal(FaceHandle, const Vec3d &) override {}
    void set_color(FaceHandle, const Vec3uc &) override {}
    void set_color(FaceHandle, const Vec4uc &) override {}
    void set_color(FaceHandle, const Vec3f &) override {}
    void set_color(FaceHandle, const Vec4f &) override {}
    void set_status(FaceHandle, const Attributes::StatusInfo &) override {}
    void add_texture_information(int, std::string) override {}

    void reserve(unsigned int nv, unsigned int, unsigned int nf) override
    {
        // Sizes come from untrusted headers: reserve only what is plausible.
        if (nv < (1u << 26))
            points.reserve(size_t(nv) * 3);
        if (nf < (1u << 26))
            tris.reserve(size_t(nf) * 3);
    }
    size_t n_vertices() const override { return points.size() / 3; }
    size_t n_faces() const override { return faces; }
    size_t n_edges() const override { return 0; }
};

std::mutex import_lock;

// OpenMesh's diagnostics go to a capture stream of ours, redirected once per
// process: OpenMesh's mostream::disconnect drops its target without deleting
// it, so redirecting per call would leak each time.  Emptied on each call;
// import_lock held.
std::ostringstream &openmesh_messages()
{
    static std::ostringstream messages;
    static bool redirected = false;
    if (!redirected) {
        omerr().disconnect(std::cerr);
        omlog().disconnect(std::clog);
        omerr().connect(messages);
        redirected = true;
    }
    messages.str(std::string());
    return messages;
}

// OM files hold OpenMesh's halfedge structure, so they can only ever contain
// what OpenMesh's mesh accepted: reading them into a PolyMesh loses nothing.
// Its faces are then passed to the soup in order.
bool read_om(const char *path, SoupImporter &soup)
{
    PolyMesh_ArrayKernelT<> mesh;
    if (!IO::read_mesh(mesh, path))
        return false;
    for (auto v : mesh.vertices())
        soup.add_vertex(mesh.point(v));
    IO::BaseImporter::VHandles idx;
    for (auto f : mesh.faces()) {
        idx.clear();
        for (auto v : mesh.fv_range(f))
            idx.push_back(VertexHandle(v.idx()));
        soup.add_face(idx);
    }
    return true;
}

// OpenMesh's OFF reader goes on with uninitialised counts when the header
// does not parse, so the header is checked here first: the keyword
// ([ST][C][N][4][n]OFF, optionally BINARY), then three counts.
bool off_header_ok(const char *path, std::string &why)
{
    FILE *f = std::fopen(path, "rb");
    if (!f) {
        why = std::strerror(errno);
        return false;
    }
    char buf[4096];
    size_t n = std::fread(buf, 1, sizeof buf - 1, f);
    std::fseek(f, 0, SEEK_END);
    const double size = (double)std::ftell(f);
    std::fclose(f);
    buf[n] = '\0';
    std::istringstream in(std::string(buf, n));
    std::string keyword;
    in >> keyword;
    if (keyword.size() < 3 || keyword.compare(keyword.size() - 3, 3, "OFF") != 0) {
        why = "malformed OFF: the file does not start with OFF";
        return false;
    }
    std::string token;
    std::streampos mark = in.tellg();
    if ((in >> token) && token == "BINARY")
        return true; // binary counts follow; OpenMesh reads them as data
    in.clear();
    in.seekg(mark);
    long counts[3];
    for (long &c : counts) {
        while (in >> std::ws && in.peek() == '#')
            in.ignore(1 << 20, '\n');
        if (!(in >> c) || c < 0) {
            why = "malformed OFF: expected vertex, face and edge counts after the keyword";
            return false;
        }
    }
    // OpenMesh reads as many vertices and faces as the header says, past
    // the end of the file (millions of empty ones for a bad count, found by
    // fuzz/fuzz_mesh): they must fit in the file, at least "0 0 0" and
    // "3 0 0 0" with a separator each.
    const double need = 6.0 * (double)counts[0] + 8.0 * (double)counts[1];
    if (need > size) {
        why = "malformed OFF: " + std::to_string(counts[0]) + " vertices and " + std::to_string(counts[1]) +
              " faces need at least " + std::to_string((long long)need) + " bytes, the file has " +
              std::to_string((long long)size);
        return false;
    }
    return true;
}

// OpenMesh's PLY reader loops forever on a header without end_header (it
// reads keywords until it sees that one, past the end of the file; found by
// fuzz/fuzz_mesh) and reserves whatever counts the header declares, so the
// header is checked here first: "ply", a format line, then only comment,
// obj_info, element NAME COUNT, property TYPE NAME and property list TYPE
// TYPE NAME lines with the types PLY defines, up to end_header; and the
// elements must fit in the rest of the file (at least two bytes per ascii
// value, each binary value's size).
bool ply_header_ok(const char *path, std::string &why)
{
    FILE *f = std::fopen(path, "rb");
    if (!f) {
        why = std::strerror(errno);
        return false;
    }
    // up to a line that is exactly end_header (OpenMesh looks for the word:
    // "xend_header" on a line does not end its header)
    std::string header;
    int c;
    auto ends = [&header](const char *tail) {
        const size_t n = std::strlen(tail);
        return header.size() >= n && header.compare(header.size() - n, n, tail) == 0;
    };
    while (header.size() < (1u << 20) && (c = std::fgetc(f)) != EOF) {
        header.push_back(char(c));
        if (ends("\nend_header\n") || ends("\nend_header\r\n"))
            break;
    }
    std::fseek(f, 0, SEEK_END);
    const long file_size = std::ftell(f);
    std::fclose(f);
    auto bad = [&why](const std::string &what) {
        why = "malformed PLY header: " + what;
        return false;
    };
    if (!ends("\nend_header\n") && !ends("\nend_header\r\n"))
        return bad("no end_header line");
    static const std::pair<const char *, int> types[] = {
        {"char", 1},  {"uchar", 1},  {"short", 2},   {"ushort", 2},  {"int", 4},     {"uint", 4},
        {"float", 4}, {"double", 8}, {"int8", 1},    {"uint8", 1},   {"int16", 2},   {"uint16", 2},
        {"int32", 4}, {"uint32", 4}, {"float32", 4}, {"float64", 8}};
    auto type_size = [](const std::string &t) {
        for (const auto &k : types)
            if (t == k.first)
                return k.second;
        return 0;
    };
    std::istringstream in(header);
    std::string line;
    std::getline(in, line);
    if (line != "ply" && line != "ply\r")
        return bad("the file does not start with ply");
    bool ascii = false, have_format = false;
    double need = 0.0;    // bytes the declared elements take at least
    double count = 0.0;   // items of the current element
    double per_item = 0.0; // bytes per item of the current element, at least
    bool in_element = false;
    while (std::getline(in, line)) {
        std::istringstream w(line);
        std::string key, extra;
        w >> key;
        // OpenMesh reads the header word by word, not line by line: a word
        // too many on a line would be taken for the next keyword
        auto done = [&w, &extra]() { return !(w >> extra); };
        if (line.find('\0') != std::string::npos)
            return bad("a NUL byte in the header");
        if (key == "end_header") {
            break;
        } else if (key == "comment" || key == "obj_info" || key.empty()) {
            continue;
        } else if (key == "format") {
            std::string kind, version;
            w >> kind >> version;
            if (kind != "ascii" && kind != "binary_little_endian" && kind != "binary_big_endian")
                return bad("unknown format '" + kind + "'");
            if (version != "1.0" || !done())
                return bad("expected format TYPE 1.0, got '" + line + "'");
            ascii = kind == "ascii";
            have_format = true;
        } else if (key == "element") {
            std::string name;
            long long n = -1;
            if (!(w >> name >> n) || n < 0 || !done())
                return bad("expected element NAME COUNT, got '" + line + "'");
            need += count * per_item;
            count = (double)n;
            per_item = 0.0;
            in_element = true;
        } else if (key == "property") {
            std::string type, name;
            if (!in_element || !(w >> type))
                return bad("a property outside an element: '" + line + "'");
            if (type == "list") {
                std::string count_type, item_type;
                if (!(w >> count_type >> item_type >> name) || !type_size(count_type) || !type_size(item_type) ||
                    !done())
                    return bad("expected property list TYPE TYPE NAME, got '" + line + "'");
                per_item += ascii ? 2 : type_size(count_type);
            } else {
                if (!(w >> name) || !type_size(type) || !done())
                    return bad("expected property TYPE NAME, got '" + line + "'");
                per_item += ascii ? 2 : type_size(type);
            }
        } else {
            return bad("unknown line '" + line + "'");
        }
    }
    if (!have_format)
        return bad("no format line");
    need += count * per_item;
    const double rest = (double)file_size - (double)header.size();
    if (need > rest + 1.0) // (an ascii file's last value needs no separator)
        return bad("its elements need at least " + std::to_string((long long)need) + " bytes, the file has " +
                   std::to_string((long long)rest) + " after the header");
    return true;
}

// OpenMesh's OBJ reader asserts (aborting the process, as Debian builds
// it) on a face line none of whose words reads as a vertex (found by
// fuzz/fuzz_mesh), so face lines are checked here first: "f" then at least
// three words v, v/t, v//n or v/t/n of non-zero integers.
bool obj_faces_ok(const char *path, std::string &why)
{
    FILE *f = std::fopen(path, "rb");
    if (!f) {
        why = std::strerror(errno);
        return false;
    }
    std::string line;
    long number = 0;
    bool ok = true;
    auto word_ok = [](const std::string &w) {
        // up to three '/'-separated integers, the first one present and non-zero
        size_t i = 0, part = 0;
        while (true) {
            const size_t start = i;
            if (i < w.size() && (w[i] == '-' || w[i] == '+'))
                i++;
            const size_t digits = i;
            long long v = 0;
            while (i < w.size() && std::isdigit((unsigned char)w[i]) && v < (1ll << 40))
                v = 10 * v + (w[i++] - '0');
            if (i == digits && !(part > 0 && i == start)) // a number, or an empty t or n
                return false;
            if (part == 0 && v == 0)
                return false;
            if (i == w.size())
                return true;
            if (w[i] != '/' || ++part > 2)
                return false;
            i++;
        }
    };
    for (int c = 0; ok && c != EOF;) {
        line.clear();
        while ((c = std::fgetc(f)) != EOF && c != '\n')
            line.push_back(char(c));
        number++;
        if (line.size() < 2 || line[0] != 'f' || !std::isspace((unsigned char)line[1]))
            continue;
        std::istringstream w(line.substr(1));
        std::string word;
        int words = 0;
        while (ok && w >> word) {
            ok = word_ok(word);
            words++;
        }
        if (!ok || words < 3) {
            why = "malformed OBJ: line " + std::to_string(number) + ": expected f and three or more vertex references, got '" +
                  line.substr(0, 60) + "'";
            ok = false;
        }
    }
    std::fclose(f);
    return ok;
}

void set_err(char *err, size_t size, const std::string &text)
{
    if (err && size)
        std::snprintf(err, size, "%s", text.c_str());
}

// OpenMesh's messages, minus blank lines, on one line.
std::string one_line(const std::string &s)
{
    std::string out;
    for (char c : s) {
        if (c == '\n' || c == '\r') {
            if (!out.empty() && out.back() != ' ')
                out += "; ";
        } else {
            out += c;
        }
    }
    while (!out.empty() && (out.back() == ' ' || out.back() == ';'))
        out.pop_back();
    return out;
}

} // namespace

extern "C" int rtk_mesh_load(const char *path, rtk_mesh *mesh, char *err, size_t err_size)
{
    if (!mesh) {
        set_err(err, err_size, "rtk_mesh_load: mesh is NULL");
        return 1;
    }
    std::memset(mesh, 0, sizeof *mesh);
    if (!path) {
        set_err(err, err_size, "rtk_mesh_load: path is NULL");
        return 1;
    }
    struct stat st;
    if (stat(path, &st) != 0) {
        set_err(err, err_size, std::string(path) + ": " + std::strerror(errno));
        return 1;
    }
    if (!S_ISREG(st.st_mode)) {
        set_err(err, err_size, std::string(path) + ": not a regular file");
        return 1;
    }

    if (st.st_size == 0) {
        set_err(err, err_size, std::string(path) + ": empty file");
        return 1;
    }

    // The format is taken from the name: IOManager::can_read opens a dummy
    // file name for some formats.
    std::string ext(path);
    const size_t dot = ext.rfind('.');
    ext = dot == std::string::npos ? std::string() : ext.substr(dot + 1);
    for (char &c : ext)
        c = char(std::tolower((unsigned char)c));
    if (ext == "rtkm")
        return rtkm_load(path, mesh, err, err_size); // rtk's own format, no OpenMesh

    std::lock_guard<std::mutex> guard(import_lock);
    SoupImporter soup;
    std::ostringstream &messages = openmesh_messages();
    bool ok = false;
    std::string failure;
    try {
        IO::Options opt;
        static const char *const known[] = {"obj", "ply", "off", "stl", "stla", "stlb", "om"};
        bool readable = false;
        for (const char *k : known)
            readable = readable || ext == k;
        if (!readable) {
            failure = "unknown mesh format (rtk reads .rtkm, .obj, .ply, .off, .stl, .om)";
        } else if (ext == "off" && !off_header_ok(path, failure)) {
            // failure says why
        } else if (ext == "ply" && !ply_header_ok(path, failure)) {
            // failure says why
        } else if (ext == "obj" && !obj_faces_ok(path, failure)) {
            // failure says why
        } else {
            ok = ext == "om" ? read_om(path, soup) : IO::IOManager().read(path, soup, opt);
        }
    } catch (const std::bad_alloc &) {
        failure = "out of memory while reading";
    } catch (const std::exception &e) {
        failure = e.what();
    }
    omerr().flush();

    std::string why;
    if (!failure.empty())
        why = failure;
    else if (!ok)
        why = "OpenMesh could not read it" + (messages.str().empty() ? std::string() : ": " + one_line(messages.str()));
    else if (soup.bad_faces)
        why = "malformed: " + soup.first_bad + (soup.bad_faces > 1 ? " (and " + std::to_string(soup.bad_faces - 1) +
                                                                         " more bad faces)"
                                                                   : std::string());
    else if (soup.points.size() / 3 > UINT32_MAX)
        why = "more than 2^32 - 1 vertices";
    if (!why.empty()) {
        set_err(err, err_size, std::string(path) + ": " + why);
        return 1;
    }

    mesh->vertex_count = soup.points.size() / 3;
    mesh->triangle_count = soup.tris.size() / 3;
    mesh->vertices = static_cast<float *>(std::malloc((soup.points.size() ? soup.points.size() : 1) * sizeof(float)));
    mesh->indices = static_cast<uint32_t *>(std::malloc((soup.tris.size() ? soup.tris.size() : 1) * sizeof(uint32_t)));
    if (!mesh->vertices || !mesh->indices) {
        rtk_mesh_free(mesh);
        set_err(err, err_size, std::string(path) + ": out of memory");
        return 1;
    }
    if (!soup.points.empty())
        std::memcpy(mesh->vertices, soup.points.data(), soup.points.size() * sizeof(float));
    if (!soup.tris.empty())
        std::memcpy(mesh->indices, soup.tris.data(), soup.tris.size() * sizeof(uint32_t));
    mesh->faces_read = soup.faces;
    mesh->polygons_triangulated = soup.polygons;
    mesh->faces_repeated_vertex = soup.repeated;
    mesh->vertices_duplicated = 0;
    return 0;
}

extern "C" void rtk_mesh_free(rtk_mesh *mesh)
{
    if (!mesh)
        return;
    std::free(mesh->vertices);
    std::free(mesh->indices);
    std::memset(mesh, 0, sizeof *mesh);
}

extern "C" float rtk_mesh_bounds(const rtk_mesh *mesh, float lower[3], float upper[3])
{
    for (int k = 0; k < 3; k++) {
        lower[k] = mesh->vertex_count ? mesh->vertices[k] : 0.0f;
        upper[k] = lower[k];
    }
    for (size_t i = 0; i < mesh->vertex_count; i++)
        for (size_t k = 0; k < 3; k++) {
            const float x = mesh->vertices[3 * i + k];
            lower[k] = x < lower[k] ? x : lower[k];
            upper[k] = x > upper[k] ? x : upper[k];
        }
    double d = 0.0;
    for (int k = 0; k < 3; k++)
        d += double(upper[k] - lower[k]) * double(upper[k] - lower[k]);
    return float(std::sqrt(d));
}

extern "C" int rtk_mesh_is_closed(const rtk_mesh *mesh, size_t count, size_t *boundary_edges, size_t *faces_rejected)
{
    std::lock_guard<std::mutex> guard(import_lock);
    openmesh_messages(); // add_face's complaints are counted, not printed
    size_t boundary = 0, rejected = 0;
    try {
        PolyMesh_ArrayKernelT<> om;
        std::vector<PolyMesh_ArrayKernelT<>::VertexHandle> vh(mesh->vertex_count);
        for (size_t i = 0; i < mesh->vertex_count; i++) {
            const float *p = mesh->vertices + 3 * i;
            vh[i] = om.add_vertex(PolyMesh_ArrayKernelT<>::Point(p[0], p[1], p[2]));
        }
        for (size_t t = 0; t < count; t++) {
            const uint32_t *x = mesh->indices + 3 * t;
            if (x[0] >= mesh->vertex_count || x[1] >= mesh->vertex_count || x[2] >= mesh->vertex_count ||
                !om.add_face(vh[x[0]], vh[x[1]], vh[x[2]]).is_valid())
                rejected++;
        }
        for (auto e : om.edges())
            boundary += om.is_boundary(e);
    } catch (const std::bad_alloc &) {
        omerr().flush();
        return -1;
    }
    omerr().flush();
    if (boundary_edges)
        *boundary_edges = boundary;
    if (faces_rejected)
        *faces_rejected = rejected;
    return boundary == 0 && rejected == 0;
}
