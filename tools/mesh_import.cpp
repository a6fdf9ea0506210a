// Mesh import through OpenMesh's readers into a triangle soup.  See mesh_import.h.
#include "mesh_import.h"
#include "rtkm.h"

#include <algorithm>
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
                note_bad(face, "a face refers to vertex index " + std::to_string(v.idx()) + ", out of range (" +
                                   std::to_string(nv) + " vertices)");
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

// The whole file into data; false with why set when it cannot be read.
bool read_whole(const char *path, std::string &data, std::string &why)
{
    FILE *f = std::fopen(path, "rb");
    if (!f) {
        why = std::strerror(errno);
        return false;
    }
    char buf[1 << 16];
    size_t n;
    while ((n = std::fread(buf, 1, sizeof buf, f)) > 0)
        data.append(buf, n);
    std::fclose(f);
    return true;
}

// OpenMesh's OFF reader trusts the file.  It reads the counts after the
// keyword line with >> (a comment there leaves them uninitialised), then as
// many vertices and faces as they say, past the end of the file; a face
// declaring billions of vertices pushes that many indices even at the end of
// the file, and once a read fails, the counts it reuses keep their last value
// (found by fuzz/fuzz_mesh: memory exhausted, or billions of empty faces).
// So the whole file is checked here first, as OpenMesh will read it, and
// anything it would misread is refused with a reason:
//  - the keyword line: [ST][C][N]OFF, optionally BINARY (4OFF and nOFF
//    OpenMesh refuses itself); it ignores the rest of that line;
//  - ASCII: a line of exactly three counts (no comment: OpenMesh cannot skip
//    it); then, skipping blank lines, a line per vertex starting with its
//    three coordinates (six with N), which must parse as floats (OpenMesh's
//    stream fails on nan, inf and values out of float range, and everything
//    after would be misread); then a line per face: its vertex count n and n
//    indices, whole numbers, and nothing more unless the keyword has C (a
//    colour: OpenMesh reads the rest of the line only then);
//  - binary: three counts, the vertex records (12 bytes, and 12 for N, 12 for
//    C, 8 for ST), and for each face its count and indices, all within the
//    file.
bool is_count(const std::string &t, unsigned long &v)
{
    if (t.empty() || t.size() > 10)
        return false;
    for (char ch : t)
        if (ch < '0' || ch > '9')
            return false;
    v = std::strtoul(t.c_str(), nullptr, 10);
    return v <= 0xffffffffu;
}

bool fail_keyword(std::string &why)
{
    why = "malformed OFF: the first line must be [ST][C][N]OFF, optionally followed by one space and BINARY";
    return false;
}

bool off_ok(const char *path, std::string &why)
{
    std::string data;
    if (!read_whole(path, data, why))
        return false;
    size_t pos = data.find('\n');
    const std::string first = data.substr(0, pos);
    pos = pos == std::string::npos ? data.size() : pos + 1;
    std::istringstream head(first);
    std::string keyword, second;
    head >> keyword >> second;
    if (keyword.size() < 3 || keyword.compare(keyword.size() - 3, 3, "OFF") != 0) {
        why = "malformed OFF: the file does not start with OFF";
        return false;
    }
    const std::string prefix = keyword.substr(0, keyword.size() - 3);
    if (prefix.find_first_not_of("STCN4n") != std::string::npos)
        return fail_keyword(why);
    // OpenMesh reads the body as binary when BINARY follows OFF and one
    // separator, whatever comes after it; refuse a line where that and the
    // words read here could disagree (fuzz/fuzz_mesh: "OFF\fBINARY\xf6..."
    // passed as text and was read as binary counts of billions, a hang)
    if (first.find("BINARY") != std::string::npos &&
        (second != "BINARY" || first.compare(0, keyword.size() + 7, keyword + " BINARY") != 0 ||
         first.find_first_not_of(" \t\r", keyword.size() + 7) != std::string::npos))
        return fail_keyword(why);
    const bool st = prefix.compare(0, 2, "ST") == 0;
    const bool color = prefix.find('C') != std::string::npos, normal = prefix.find('N') != std::string::npos;
    const auto fail = [&why](const std::string &text) {
        why = "malformed OFF: " + text;
        return false;
    };
    if (second == "BINARY") {
        const auto u32 = [&data](size_t at) {
            return (uint32_t)(unsigned char)data[at] | (uint32_t)(unsigned char)data[at + 1] << 8 |
                   (uint32_t)(unsigned char)data[at + 2] << 16 | (uint32_t)(unsigned char)data[at + 3] << 24;
        };
        if (data.size() - pos < 12)
            return fail("the binary counts are cut short");
        const uint64_t nv = u32(pos), nf = u32(pos + 4);
        const uint64_t record = 12 + (normal ? 12 : 0) + (color ? 12 : 0) + (st ? 8 : 0);
        uint64_t at = pos + 12 + nv * record;
        if (at > data.size())
            return fail(std::to_string(nv) + " binary vertices need " + std::to_string(nv * record) +
                        " bytes, the file has " + std::to_string(data.size() - pos - 12) + " after the counts");
        for (uint64_t f = 0; f < nf; f++) {
            if (at + 4 > data.size())
                return fail("the file ends after " + std::to_string(f) + " of " + std::to_string(nf) + " faces");
            const uint64_t n = u32(at);
            at += 4 + 4 * n;
            if (at > data.size())
                return fail("face " + std::to_string(f) + " declares " + std::to_string(n) +
                            " vertices, more than the rest of the file holds");
        }
        return true;
    }
    // the next non-blank line, as text and split into words; false at the end
    std::vector<std::string> words;
    std::string text;
    size_t line_no = 1;
    const auto next_line = [&]() {
        while (pos < data.size()) {
            size_t end = data.find('\n', pos);
            if (end == std::string::npos)
                end = data.size();
            text.assign(data, pos, end - pos);
            std::istringstream in(text);
            pos = end + 1;
            line_no++;
            words.clear();
            for (std::string w; in >> w;)
                words.push_back(w);
            if (!words.empty())
                return true;
        }
        return false;
    };
    unsigned long counts[3];
    if (!next_line() || words.size() != 3 || !is_count(words[0], counts[0]) || !is_count(words[1], counts[1]) ||
        !is_count(words[2], counts[2]))
        return fail(!words.empty() && words[0][0] == '#'
                        ? "a comment after the keyword line (line " + std::to_string(line_no) +
                              "), where OpenMesh's reader expects the counts"
                        : "expected vertex, face and edge counts after the keyword");
    // each needs at least "0 0 0" or "3 0 0 0" with a separator
    const double need = 6.0 * (double)counts[0] + 8.0 * (double)counts[1];
    if (need > (double)data.size())
        return fail(std::to_string(counts[0]) + " vertices and " + std::to_string(counts[1]) +
                    " faces need at least " + std::to_string((long long)need) + " bytes, the file has " +
                    std::to_string(data.size()));
    const size_t coords = normal ? 6 : 3;
    for (unsigned long v = 0; v < counts[0]; v++) {
        if (!next_line())
            return fail("the file ends after " + std::to_string(v) + " of " + std::to_string(counts[0]) +
                        " vertices");
        bool ok = words.size() >= coords && words[0][0] != '#';
        std::istringstream in(text);
        float x;
        for (size_t k = 0; ok && k < coords; k++)
            ok = static_cast<bool>(in >> x);
        if (!ok)
            return fail("line " + std::to_string(line_no) + ": vertex " + std::to_string(v) + " needs " +
                        std::to_string(coords) + " numbers in float range first");
    }
    for (unsigned long f = 0; f < counts[1]; f++) {
        if (!next_line())
            return fail("the file ends after " + std::to_string(f) + " of " + std::to_string(counts[1]) + " faces");
        unsigned long n = 0, idx;
        bool ok = is_count(words[0], n) && words.size() - 1 >= n && (color || words.size() - 1 == n);
        for (size_t k = 1; ok && k <= n; k++)
            ok = is_count(words[k], idx);
        if (!ok)
            return fail("line " + std::to_string(line_no) + ": face " + std::to_string(f) +
                        " needs its vertex count and that many vertex indices" +
                        (color ? "" : ", and nothing after them (the keyword has no C for colours)"));
    }
    return true;
}

// The size in bytes of a PLY property type, 0 for none.
int ply_type_size(const std::string &t)
{
    static const std::pair<const char *, int> types[] = {
        {"char", 1},  {"uchar", 1},  {"short", 2},   {"ushort", 2},  {"int", 4},     {"uint", 4},
        {"float", 4}, {"double", 8}, {"int8", 1},    {"uint8", 1},   {"int16", 2},   {"uint16", 2},
        {"int32", 4}, {"uint32", 4}, {"float32", 4}, {"float64", 8}};
    for (const auto &k : types)
        if (t == k.first)
            return k.second;
    return 0;
}

struct ply_property {
    bool list;
    std::string count_type, type; // a scalar's type in both
};
struct ply_element {
    unsigned long long count;
    std::vector<ply_property> props;
};

// Whether an ascii PLY word reads as a value of the type for OpenMesh's
// stream: integers (no sign for unsigned types), and decimal numbers in
// float or double range for floats (the stream fails on nan, inf and
// values out of range, and every read after a failure goes astray).
bool ply_word_ok(const std::string &w, const std::string &type)
{
    const bool is_float = type.compare(0, 5, "float") == 0 || type.compare(0, 6, "double") == 0;
    const bool is_unsigned = type[0] == 'u';
    if (w.empty() || w.size() > 64)
        return false;
    if (!is_float) {
        size_t k = (w[0] == '-' && !is_unsigned) || w[0] == '+' ? 1 : 0;
        if (k == w.size() || w.size() - k > 10)
            return false;
        for (; k < w.size(); k++)
            if (w[k] < '0' || w[k] > '9')
                return false;
        const long long v = std::strtoll(w.c_str(), nullptr, 10);
        return v >= -2147483648ll && v <= 4294967295ll;
    }
    for (char ch : w)
        if (!std::isdigit((unsigned char)ch) && ch != '.' && ch != '-' && ch != '+' && ch != 'e' && ch != 'E')
            return false;
    char *end;
    errno = 0;
    const double v = std::strtod(w.c_str(), &end);
    const double limit = type == "double" || type == "float64" ? 1.7976931348623157e308 : 3.4028234663852886e38;
    return *end == '\0' && errno == 0 && std::fabs(v) <= limit;
}

// OpenMesh's PLY reader reads as many values as each list's count says,
// past the end of the file, pushing each (a count of billions exhausts
// memory: fuzz/fuzz_mesh), and goes on after a value that does not read.
// So the body is walked here as it will read it: every value must read as
// its type, every list count be at most what is left of the file.
bool ply_body_ok(const std::string &data, size_t header_size, const std::vector<ply_element> &elements, bool ascii,
                 bool big_endian, std::string &why)
{
    size_t pos = header_size;
    // the message is made only for the item that fails (making it for every
    // value cost more than reading the file)
    const auto bad = [&why](size_t element, unsigned long long item, const std::string &what) {
        why = "malformed PLY: element " + std::to_string(element) + " item " + std::to_string(item) + ": " + what;
        return false;
    };
    if (ascii) {
        const auto word = [&data, &pos](std::string &w) {
            while (pos < data.size() && std::isspace((unsigned char)data[pos]))
                pos++;
            const size_t start = pos;
            while (pos < data.size() && !std::isspace((unsigned char)data[pos]))
                pos++;
            w.assign(data, start, pos - start);
            return !w.empty();
        };
        std::string w;
        for (size_t e = 0; e < elements.size(); e++)
            for (unsigned long long i = 0; i < elements[e].count; i++)
                for (const ply_property &p : elements[e].props) {
                    if (!word(w))
                        return bad(e, i, "the file ends");
                    unsigned long long n = 1;
                    if (p.list) {
                        if (!ply_word_ok(w, "uint") || (n = std::strtoull(w.c_str(), nullptr, 10)) > data.size() - pos)
                            return bad(e, i, "a list count '" + w + "' the rest of the file cannot hold");
                        if (n && !word(w))
                            return bad(e, i, "the file ends");
                    }
                    for (unsigned long long k = 0; k < n; k++) {
                        if (!ply_word_ok(w, p.type))
                            return bad(e, i, "'" + w + "' is not a " + p.type);
                        if (k + 1 < n && !word(w))
                            return bad(e, i, "the file ends");
                    }
                }
        return true;
    }
    struct sizes {
        size_t count, type; // bytes of a list's count (0: not a list) and of a value
        bool count_signed;
    };
    for (size_t e = 0; e < elements.size(); e++) {
        std::vector<sizes> props;
        size_t fixed = 0; // bytes of an item without lists
        bool lists = false;
        for (const ply_property &p : elements[e].props) {
            props.push_back({p.list ? (size_t)ply_type_size(p.count_type) : 0, (size_t)ply_type_size(p.type),
                             p.list && p.count_type[0] != 'u'});
            lists |= p.list;
            fixed += p.list ? 0 : props.back().type;
        }
        if (!lists) { // items of one size: only whether they fit
            const unsigned long long fit = fixed ? (data.size() - pos) / fixed : elements[e].count;
            if (fit < elements[e].count)
                return bad(e, fit, "the file ends");
            pos += (size_t)elements[e].count * fixed;
            continue;
        }
        for (unsigned long long i = 0; i < elements[e].count; i++)
            for (const sizes &p : props) {
                const size_t cs = p.count, ts = p.type;
                unsigned long long n = 1;
                if (cs) {
                    if (data.size() - pos < cs)
                        return bad(e, i, "the file ends");
                    unsigned long long v = 0;
                    for (size_t k = 0; k < cs; k++)
                        v |= (unsigned long long)(unsigned char)data[pos + (big_endian ? k : cs - 1 - k)]
                             << (8 * (cs - 1 - k));
                    const bool negative = p.count_signed && (v >> (8 * cs - 1)) & 1;
                    pos += cs;
                    n = v;
                    if (negative || n > (data.size() - pos) / ts)
                        return bad(e, i,
                                   "a list count of " + (negative ? std::string("a negative number") : std::to_string(n)) +
                                       " the rest of the file cannot hold");
                }
                if ((data.size() - pos) / ts < n)
                    return bad(e, i, "the file ends");
                pos += (size_t)n * ts;
            }
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
    std::string data;
    if (!read_whole(path, data, why))
        return false;
    auto bad = [&why](const std::string &what) {
        why = "malformed PLY header: " + what;
        return false;
    };
    // up to the first line that is exactly end_header, within 1 MiB
    // (OpenMesh looks for the word: "xend_header" on a line does not end
    // its header)
    const size_t lf = data.find("\nend_header\n"), crlf = data.find("\nend_header\r\n");
    const size_t end = std::min(lf == std::string::npos ? lf : lf + 12, crlf == std::string::npos ? crlf : crlf + 13);
    if (end > (1u << 20))
        return bad("no end_header line");
    const std::string header = data.substr(0, end);
    const size_t file_size = data.size();
    std::istringstream in(header);
    std::string line;
    std::getline(in, line);
    if (line != "ply" && line != "ply\r")
        return bad("the file does not start with ply");
    bool ascii = false, have_format = false, big_endian = false;
    std::vector<ply_element> elements;
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
        } else if (key == "comment" || key.empty()) {
            continue;
        } else if (key == "obj_info") {
            // OpenMesh skips a comment line but not an obj_info line: it
            // reads on word by word, so an element, property or end_header
            // there declares one, or ends the header (fuzz_mesh: "obj_info
            // element face" made it log without end until memory ran out;
            // "obj_info element vertex 4" read 8 vertices, "obj_info
            // property" no faces).  Other words it passes over.
            std::string word;
            while (w >> word)
                if (word == "element" || word == "property" || word == "end_header")
                    return bad("an obj_info line holding '" + word +
                               "', which the PLY reader would take for a header line: '" + line + "'");
            continue;
        } else if (key == "format") {
            std::string kind, version;
            w >> kind >> version;
            if (kind != "ascii" && kind != "binary_little_endian" && kind != "binary_big_endian")
                return bad("unknown format '" + kind + "'");
            if (version != "1.0" || !done())
                return bad("expected format TYPE 1.0, got '" + line + "'");
            ascii = kind == "ascii";
            big_endian = kind == "binary_big_endian";
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
            elements.push_back(ply_element{(unsigned long long)n, {}});
        } else if (key == "property") {
            std::string type, name;
            if (!in_element || !(w >> type))
                return bad("a property outside an element: '" + line + "'");
            if (type == "list") {
                std::string count_type, item_type;
                if (!(w >> count_type >> item_type >> name) || !ply_type_size(count_type) || !ply_type_size(item_type) ||
                    !done())
                    return bad("expected property list TYPE TYPE NAME, got '" + line + "'");
                per_item += ascii ? 2 : ply_type_size(count_type);
                elements.back().props.push_back(ply_property{true, count_type, item_type});
            } else {
                if (!(w >> name) || !ply_type_size(type) || !done())
                    return bad("expected property TYPE NAME, got '" + line + "'");
                per_item += ascii ? 2 : ply_type_size(type);
                elements.back().props.push_back(ply_property{false, type, type});
            }
        } else {
            return bad("unknown line '" + line + "'");
        }
    }
    if (!have_format)
        return bad("no format line");
    need += count * per_item;
    const double rest = (double)file_size - (double)header.size();
    if (need > rest + 1.0) { // (an ascii file's last value needs no separator)
        char need_text[64];  // (need can pass the range of long long: fuzz_mesh)
        std::snprintf(need_text, sizeof need_text, "%.0f", need);
        return bad(std::string("its elements need at least ") + need_text + " bytes, the file has " +
                   std::to_string((long long)rest) + " after the header");
    }
    return ply_body_ok(data, header.size(), elements, ascii, big_endian, why);
}

// A line of a file as a message shows it: at most 60 bytes, and any byte
// that is not printable ASCII as \xNN (a binary file's bytes went into
// messages as they were).
std::string shown(const std::string &line)
{
    std::string out;
    for (size_t i = 0; i < line.size() && i < 60; i++) {
        const unsigned char c = (unsigned char)line[i];
        if (c >= 32 && c < 127) {
            out += char(c);
        } else {
            char hex[8];
            std::snprintf(hex, sizeof hex, "\\x%02x", c);
            out += hex;
        }
    }
    return line.size() > 60 ? out + "..." : out;
}

// A coordinate as OpenMesh's readers take it (a stream's >> float): a
// decimal number ([+-] digits [. digits] [e [+-] digits]) within float
// range.  They fail on nan, inf and values beyond float range, and read a
// prefix of "1x" or "0x1p3"; the OBJ reader then drops the whole vertex
// line, so every later index points at the wrong vertex.  (Values below
// the smallest float read as 0 or a subnormal, as OpenMesh reads them.)
bool decimal_float(const std::string &t)
{
    size_t i = 0, digits = 0;
    if (i < t.size() && (t[i] == '+' || t[i] == '-'))
        i++;
    while (i < t.size() && std::isdigit((unsigned char)t[i]))
        i++, digits++;
    if (i < t.size() && t[i] == '.')
        for (i++; i < t.size() && std::isdigit((unsigned char)t[i]);)
            i++, digits++;
    if (!digits)
        return false;
    if (i < t.size() && (t[i] == 'e' || t[i] == 'E')) {
        i++;
        if (i < t.size() && (t[i] == '+' || t[i] == '-'))
            i++;
        const size_t e = i;
        while (i < t.size() && std::isdigit((unsigned char)t[i]))
            i++;
        if (i == e)
            return false;
    }
    if (i != t.size())
        return false;
    errno = 0;
    const float v = std::strtof(t.c_str(), nullptr);
    return std::isfinite(v) && !(errno == ERANGE && std::fabs(v) > 1.0f);
}

// The lines of an OBJ file as OpenMesh's reader splits them: trimmed,
// blank lines and comments skipped, the keyword the first word.
// OpenMesh's OBJ reader asserts (aborting the process, as Debian builds
// it) on a face line none of whose words reads as a vertex (found by
// fuzz/fuzz_mesh), drops a vertex line whose coordinates do not all read
// (shifting every later index), and reads an index beyond int range or
// beyond the vertices as whatever it comes to.  So the file is checked
// here first: every v line starts with three coordinates (decimal_float);
// every f line is "f" and at least three words v, v/t, v//n or v/t/n of
// non-zero integers, and each vertex reference lies among the file's
// vertices (a negative one among those before the line).
bool obj_ok(const char *path, std::string &why)
{
    FILE *f = std::fopen(path, "rb");
    if (!f) {
        why = std::strerror(errno);
        return false;
    }
    std::string line;
    long number = 0, vertices = 0, max_ref = 0, max_ref_line = 0;
    bool ok = true;
    const auto fail = [&](const std::string &text) {
        why = "malformed OBJ: line " + std::to_string(number) + ": " + text;
        ok = false;
    };
    // up to three '/'-separated integers, the first one present and
    // non-zero; *first the first
    auto word_ok = [](const std::string &w, long long *first) {
        size_t i = 0, part = 0;
        while (true) {
            const size_t start = i;
            const bool neg = i < w.size() && w[i] == '-';
            if (i < w.size() && (w[i] == '-' || w[i] == '+'))
                i++;
            const size_t digits = i;
            long long v = 0;
            while (i < w.size() && std::isdigit((unsigned char)w[i]) && v < (1ll << 40))
                v = 10 * v + (w[i++] - '0');
            if (i == digits && !(part > 0 && i == start)) // a number, or an empty t or n
                return false;
            if (part == 0) {
                if (v == 0)
                    return false;
                *first = neg ? -v : v; /* (then checked against the vertices) */
            }
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
        // OpenMesh trims the line first (fuzz_mesh: " f /0 ..." asserted)
        size_t lead = 0;
        while (lead < line.size() && std::isspace((unsigned char)line[lead]))
            lead++;
        line.erase(0, lead);
        std::istringstream w(line);
        std::string key;
        if (!(w >> key) || key[0] == '#')
            continue;
        if (key == "v") {
            std::string coord;
            for (int k = 0; ok && k < 3; k++) {
                if (!(w >> coord))
                    fail("a vertex needs three coordinates, got '" + shown(line) + "'");
                else if (!decimal_float(coord))
                    fail("vertex coordinate '" + shown(coord) +
                         "' is not a decimal number within float range (OpenMesh would drop the vertex and "
                         "shift every later index)");
            }
            vertices++;
        } else if (key == "f") {
            std::string word;
            int words = 0;
            while (ok && w >> word) {
                long long ref = 0;
                if (!word_ok(word, &ref)) {
                    fail("expected f and three or more vertex references, got '" + shown(line) + "'");
                } else if (ref < 0 && -ref > vertices) {
                    fail("the face refers to vertex " + std::to_string(ref) + ", but only " +
                         std::to_string(vertices) + " vertices come before it");
                } else if (ref > max_ref) {
                    max_ref = (long)ref;
                    max_ref_line = number;
                }
                words++;
            }
            if (ok && words < 3)
                fail("expected f and three or more vertex references, got '" + shown(line) + "'");
        }
    }
    std::fclose(f);
    if (ok && max_ref > vertices) {
        number = max_ref_line;
        fail("the face refers to vertex " + std::to_string(max_ref) + ", but the file has " +
             std::to_string(vertices) + " vertices");
    }
    return ok;
}

// OpenMesh's STL reader takes a .stl file for binary when its size is
// exactly 84 bytes plus 50 per triangle of the count at byte 80, and for
// ASCII otherwise, and then checks nothing: half a binary file, or a
// count the body does not hold, read as ASCII and gave no triangles; an
// ASCII file cut short loaded what it had.  So the file is checked here
// first as it will be read (.stla is always ASCII, .stlb always binary):
//  - binary: exactly 84 + 50 n bytes, and every vertex coordinate finite;
//  - ASCII: "solid [name]", then facets, each "facet normal x y z",
//    "outer loop", three "vertex x y z" lines (decimal_float), "endloop",
//    "endfacet", and "endsolid [name]" at the end (keywords in any case,
//    one per line, as OpenMesh finds them); several solids may follow one
//    another, and nothing else.
bool stl_ok(const char *path, const std::string &ext, std::string &why)
{
    std::string data;
    if (!read_whole(path, data, why))
        return false;
    const auto fail = [&why](const std::string &text) {
        why = "malformed STL: " + text;
        return false;
    };
    uint64_t count = 0;
    if (data.size() >= 84)
        for (int k = 3; k >= 0; k--)
            count = count << 8 | (unsigned char)data[80 + (size_t)k];
    const bool size_says_binary = data.size() >= 84 && data.size() == 84 + 50 * count;
    if (ext == "stlb" || (ext == "stl" && size_says_binary)) {
        if (data.size() < 84)
            return fail("a binary STL needs an 84-byte header, the file has " + std::to_string(data.size()) +
                        " bytes");
        if (data.size() != 84 + 50 * count)
            return fail("the header says " + std::to_string(count) + " triangles, which take " +
                        std::to_string(84 + 50 * count) + " bytes; the file has " + std::to_string(data.size()));
        for (uint64_t t = 0; t < count; t++)
            for (int k = 3; k < 12; k++) { // (the normal, k < 3, is not read as geometry)
                float v;
                std::memcpy(&v, data.data() + 84 + 50 * t + 4 * (size_t)k, 4);
                if (!std::isfinite(v))
                    return fail("triangle " + std::to_string(t) + " has a vertex coordinate that is not finite");
            }
        return true;
    }
    // ASCII: the words of each non-blank line
    size_t pos = 0, line_no = 0;
    std::vector<std::string> words;
    std::string text;
    const auto next_line = [&]() {
        while (pos < data.size()) {
            size_t end = data.find('\n', pos);
            if (end == std::string::npos)
                end = data.size();
            text.assign(data, pos, end - pos);
            pos = end + 1;
            line_no++;
            std::istringstream in(text);
            words.clear();
            for (std::string w; in >> w;)
                words.push_back(w);
            if (!words.empty())
                return true;
        }
        return false;
    };
    const auto is = [&words](size_t i, const char *kw) {
        if (words.size() <= i || words[i].size() != std::strlen(kw))
            return false;
        for (size_t k = 0; k < words[i].size(); k++)
            if (std::tolower((unsigned char)words[i][k]) != kw[k])
                return false;
        return true;
    };
    const auto where = [&]() { return "line " + std::to_string(line_no) + ": "; };
    if (!next_line() || !is(0, "solid"))
        return fail(ext == "stl" && data.size() >= 84
                        ? "neither binary (the header's " + std::to_string(count) + " triangles need " +
                              std::to_string(84 + 50 * count) + " bytes, the file has " +
                              std::to_string(data.size()) + ") nor ASCII (it does not begin with 'solid')"
                        : "an ASCII STL begins with 'solid'");
    while (true) { // in a solid
        if (!next_line())
            return fail("the file ends inside a solid, before 'endsolid' (cut short?)");
        if (is(0, "endsolid")) {
            if (!next_line())
                return true;
            if (!is(0, "solid"))
                return fail(where() + "expected another 'solid' or the end after 'endsolid', got '" + shown(text) +
                            "'");
            continue;
        }
        if (!is(0, "facet") || !is(1, "normal") || words.size() != 5)
            return fail(where() + "expected 'facet normal x y z' or 'endsolid', got '" + shown(text) + "'");
        if (!next_line() || !is(0, "outer") || !is(1, "loop") || words.size() != 2)
            return fail(where() + "expected 'outer loop', got '" + shown(text) + "'");
        for (int v = 0; v < 3; v++) {
            if (!next_line() || !is(0, "vertex") || words.size() != 4)
                return fail(where() + "expected 'vertex x y z', got '" + shown(text) + "'");
            for (int k = 1; k <= 3; k++)
                if (!decimal_float(words[(size_t)k]))
                    return fail(where() + "vertex coordinate '" + shown(words[(size_t)k]) +
                                "' is not a decimal number within float range");
        }
        if (!next_line() || !is(0, "endloop") || words.size() != 1)
            return fail(where() + "expected 'endloop', got '" + shown(text) + "'");
        if (!next_line() || !is(0, "endfacet") || words.size() != 1)
            return fail(where() + "expected 'endfacet', got '" + shown(text) + "'");
    }
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
        } else if (ext == "off" && !off_ok(path, failure)) {
            // failure says why
        } else if (ext == "ply" && !ply_header_ok(path, failure)) {
            // failure says why
        } else if (ext == "obj" && !obj_ok(path, failure)) {
            // failure says why
        } else if ((ext == "stl" || ext == "stla" || ext == "stlb") && !stl_ok(path, ext, failure)) {
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
