// The OBJ side of the atlas build: materials to images, and texture coordinates into the atlas.
#include <tiny_obj_loader.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <tuple>
#include <unordered_map>

#include "tessera/client/scene/atlas.hpp"

namespace tessera::scene {
namespace fs = std::filesystem;

namespace {

constexpr std::uint8_t kDefaultGrey = 204;  // faces with no material: a light grey solid tile
// Texture coordinates this close outside a whole repeat still count as inside it (exporters write
// 1.0000001 for 1).
constexpr double kRepeatSlack = 1e-5;

struct Corner {
    int v = -1, n = -1;
    double u = 0.5, t = 0.5;  // texture coordinate shifted into [0, 1], OBJ orientation (v up)
};
struct Triangle {
    std::uint32_t image = 0;
    Corner c[3];
};
struct Shape {
    std::string name;
    std::vector<Triangle> triangles;
};

// A corner being clipped: where it is (position, normal) and its texture coordinate before any
// shift. Clipping interpolates all of them linearly along an edge.
struct ClipVertex {
    double p[3] = {0, 0, 0};
    double n[3] = {0, 0, 0};
    double uv[2] = {0, 0};
    int v = -1, vn = -1;  // indices of an original corner's position and normal (-1: made by clipping)
    // The original triangle edge (corners e0, e1 of it, 0..2) this point lies on; e0 == e1: it is
    // that corner; -1: inside the triangle, on a cut.
    int e0 = -1, e1 = -1;
};

// The part of `poly` with coordinate `axis` of uv >= bound (keep_above) or <= bound. A point where
// a cut crosses an original edge is always interpolated between that edge's two original corners,
// put in a fixed order, whatever piece of the edge is being clipped: the pieces on both sides of a
// cut, and the triangles on both sides of a shared edge, make bit-identical corners there (no
// cracks). A corner exactly on the bound is kept and makes no second point.
std::vector<ClipVertex> clip(const std::vector<ClipVertex>& poly, const ClipVertex (&corners)[3], int axis, double bound,
                             bool keep_above) {
    std::vector<ClipVertex> out;
    auto inside = [&](const ClipVertex& c) { return keep_above ? c.uv[axis] >= bound : c.uv[axis] <= bound; };
    for (std::size_t i = 0; i < poly.size(); ++i) {
        const ClipVertex& a = poly[i];
        const ClipVertex& b = poly[(i + 1) % poly.size()];
        const bool ia = inside(a), ib = inside(b);
        if (ia) out.push_back(a);
        if (ia == ib || a.uv[axis] == bound || b.uv[axis] == bound) continue;
        // The original edge holding both ends, if any: then cut it, not the piece.
        int edge[2] = {-1, -1};
        if (a.e0 >= 0 && b.e0 >= 0) {
            const int ends[4] = {a.e0, a.e1, b.e0, b.e1};
            int distinct[4], n = 0;
            for (int e : ends)
                if (std::find(distinct, distinct + n, e) == distinct + n) distinct[n++] = e;
            if (n == 2) edge[0] = distinct[0], edge[1] = distinct[1];
        }
        const ClipVertex& s0 = edge[0] >= 0 ? corners[edge[0]] : a;
        const ClipVertex& s1 = edge[0] >= 0 ? corners[edge[1]] : b;
        const bool a_first = std::tie(s0.uv[0], s0.uv[1], s0.p[0], s0.p[1], s0.p[2]) < std::tie(s1.uv[0], s1.uv[1], s1.p[0], s1.p[1], s1.p[2]);
        const ClipVertex& e0 = a_first ? s0 : s1;
        const ClipVertex& e1 = a_first ? s1 : s0;
        const double t = (bound - e0.uv[axis]) / (e1.uv[axis] - e0.uv[axis]);
        ClipVertex m;
        for (int k = 0; k < 3; ++k) {
            m.p[k] = e0.p[k] + t * (e1.p[k] - e0.p[k]);
            m.n[k] = e0.n[k] + t * (e1.n[k] - e0.n[k]);
        }
        for (int k = 0; k < 2; ++k) m.uv[k] = e0.uv[k] + t * (e1.uv[k] - e0.uv[k]);
        m.uv[axis] = bound;  // exactly on the repeat boundary
        m.e0 = edge[0];
        m.e1 = edge[1];
        out.push_back(m);
    }
    return out;
}

std::string trim_newlines(std::string s) {
    std::replace(s.begin(), s.end(), '\n', ' ');
    while (!s.empty() && s.back() == ' ') s.pop_back();
    return s;
}

std::uint8_t to_byte(double v) { return static_cast<std::uint8_t>(std::lround(std::clamp(v, 0.0, 1.0) * 255.0)); }

void append(std::string& out, const char* fmt, double a, double b, double c) {
    char buf[128];
    const int n = std::snprintf(buf, sizeof buf, fmt, a, b, c);
    out.append(buf, static_cast<std::size_t>(std::max(0, n)));
}

}  // namespace

// Triangles one face may be cut into at repeat boundaries, and in all: a texture repeated
// thousands of times across one face would otherwise make millions of triangles silently.
constexpr std::uint64_t kMaxPiecesPerTriangle = 1u << 16;
constexpr std::uint64_t kMaxTriangles = 1u << 24;

struct ObjAtlasInput::Impl {
    std::vector<float> positions, normals;
    std::vector<Shape> shapes;
    std::vector<AtlasImageRef> images;
    std::size_t triangles = 0;
    std::size_t cut_pieces = 0;  // pieces of triangles cut at texture repeats
    UpAxis up = UpAxis::y;
    std::array<double, 3> extent{0, 0, 0};
};

ObjAtlasInput::ObjAtlasInput(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ObjAtlasInput::ObjAtlasInput(ObjAtlasInput&&) noexcept = default;
ObjAtlasInput& ObjAtlasInput::operator=(ObjAtlasInput&&) noexcept = default;
ObjAtlasInput::~ObjAtlasInput() = default;
const std::vector<AtlasImageRef>& ObjAtlasInput::images() const { return impl_->images; }
std::size_t ObjAtlasInput::triangle_count() const { return impl_->triangles; }
std::size_t ObjAtlasInput::repeat_piece_count() const { return impl_->cut_pieces; }
UpAxis ObjAtlasInput::up_axis() const { return impl_->up; }
std::array<double, 3> ObjAtlasInput::extent() const { return impl_->extent; }

Result<ObjAtlasInput> ObjAtlasInput::load(const std::string& obj_path, UpAxis up) {
    std::error_code ec;
    if (!fs::exists(obj_path, ec)) return make_error(Errc::not_found, "OBJ file '" + obj_path + "' does not exist");
    if (fs::is_directory(obj_path, ec)) return make_error(Errc::invalid_argument, "OBJ file '" + obj_path + "' is a directory");
    const fs::path folder = fs::path(obj_path).parent_path();
    tinyobj::ObjReaderConfig config;
    config.triangulate = true;
    config.vertex_color = false;
    config.mtl_search_path = folder.empty() ? std::string("./") : folder.string() + "/";
    tinyobj::ObjReader reader;
    if (!reader.ParseFromFile(obj_path, config))
        return make_error(Errc::corrupt, "cannot read OBJ '" + obj_path + "': " + trim_newlines(reader.Error()));
    const std::string& warn = reader.Warning();
    // tinyobj only warns about these; for an atlas they are fatal. Report the first such line.
    for (const char* fatal : {"Material file [", "not found in .mtl", "indices out of bounds", "invalid vertex index"}) {
        const std::size_t at = warn.find(fatal);
        if (at == std::string::npos) continue;
        const std::size_t nl = warn.rfind('\n', at), b = nl == std::string::npos ? 0 : nl + 1;
        const std::size_t e = warn.find('\n', at);
        const std::string line = warn.substr(b, e == std::string::npos ? std::string::npos : e - b);
        return make_error(Errc::invalid_argument, "OBJ '" + obj_path + "': " + trim_newlines(line));
    }

    auto impl = std::make_unique<Impl>();
    const tinyobj::attrib_t& attrib = reader.GetAttrib();
    const auto& materials = reader.GetMaterials();
    impl->positions = attrib.vertices;
    impl->normals = attrib.normals;

    // Material -> image, deduplicating texture files and solid colours.
    std::map<std::string, std::uint32_t> by_texture;
    std::map<std::array<std::uint8_t, 3>, std::uint32_t> by_colour;
    std::unordered_map<int, std::uint32_t> material_image;
    auto material_name = [&](int material) -> std::string {
        return material >= 0 && static_cast<std::size_t>(material) < materials.size() ? materials[static_cast<std::size_t>(material)].name
                                                                                       : std::string("(no material)");
    };
    auto image_of = [&](int material) -> std::uint32_t {
        if (auto it = material_image.find(material); it != material_image.end()) return it->second;
        std::string name = "(no material)", tex;
        std::array<std::uint8_t, 3> colour{kDefaultGrey, kDefaultGrey, kDefaultGrey};
        if (material >= 0 && static_cast<std::size_t>(material) < materials.size()) {
            const tinyobj::material_t& m = materials[static_cast<std::size_t>(material)];
            name = m.name;
            tex = m.diffuse_texname;
            colour = {to_byte(m.diffuse[0]), to_byte(m.diffuse[1]), to_byte(m.diffuse[2])};
        }
        std::uint32_t index;
        if (!tex.empty()) {
            std::replace(tex.begin(), tex.end(), '\\', '/');  // files written on Windows
            fs::path p(tex);
            if (p.is_relative()) p = folder / p;
            const std::string key = p.lexically_normal().string();
            auto [it, inserted] = by_texture.emplace(key, static_cast<std::uint32_t>(impl->images.size()));
            if (inserted) impl->images.push_back(AtlasImageRef{key, {}, {}});
            index = it->second;
        } else {
            auto [it, inserted] = by_colour.emplace(colour, static_cast<std::uint32_t>(impl->images.size()));
            if (inserted) impl->images.push_back(AtlasImageRef{{}, colour, {}});
            index = it->second;
        }
        impl->images[index].materials.push_back(name);
        material_image.emplace(material, index);
        return index;
    };

    // Corners made by clipping: one new position (normal) per distinct value, shared by the pieces
    // on both sides of a cut.
    struct BitsHash {
        std::size_t operator()(const std::array<std::uint32_t, 3>& k) const noexcept {
            return (std::size_t(k[0]) * 0x9e3779b97f4a7c15ULL) ^ (std::size_t(k[1]) * 0xc2b2ae3d27d4eb4fULL) ^ k[2];
        }
    };
    using NewIndex = std::unordered_map<std::array<std::uint32_t, 3>, int, BitsHash>;
    NewIndex new_positions, new_normals;
    auto new_index = [](std::vector<float>& values, NewIndex& seen, const double (&x)[3], bool normalise) -> int {
        double len = normalise ? std::sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]) : 1.0;
        if (!(len > 0)) len = 1.0;
        const float f[3] = {static_cast<float>(x[0] / len), static_cast<float>(x[1] / len), static_cast<float>(x[2] / len)};
        std::array<std::uint32_t, 3> key;
        std::memcpy(key.data(), f, sizeof f);
        auto [it, inserted] = seen.emplace(key, static_cast<int>(values.size() / 3));
        if (inserted) values.insert(values.end(), f, f + 3);
        return it->second;
    };

    for (const tinyobj::shape_t& s : reader.GetShapes()) {
        Shape shape;
        shape.name = s.name;
        std::size_t offset = 0;
        for (std::size_t f = 0; f < s.mesh.num_face_vertices.size(); ++f) {
            const std::size_t nv = s.mesh.num_face_vertices[f];
            const int material = f < s.mesh.material_ids.size() ? s.mesh.material_ids[f] : -1;
            const std::uint32_t image = image_of(material);
            const bool textured = !impl->images[image].texture.empty();
            // Fan-triangulate whatever tinyobj left (it already triangulates; this keeps polygons safe).
            for (std::size_t k = 1; k + 1 < nv; ++k) {
                Triangle tri;
                tri.image = image;
                const tinyobj::index_t idx[3] = {s.mesh.indices[offset], s.mesh.indices[offset + k], s.mesh.indices[offset + k + 1]};
                bool has_uv = textured;
                for (int c = 0; c < 3; ++c) {
                    tri.c[c].v = idx[c].vertex_index;
                    tri.c[c].n = idx[c].normal_index;
                    if (idx[c].texcoord_index < 0) has_uv = false;
                }
                if (!has_uv) {
                    shape.triangles.push_back(tri);
                    continue;
                }
                // Where the texture repeats across the triangle, cut it at every whole repeat (u = k,
                // v = j) and shift each piece by its repeat into [0, 1]: exact, since the texture
                // repeats, and each piece samples one copy of the image in its atlas cell, whose
                // padding wraps around (docs/atlas.md, "Repeating textures").
                std::vector<ClipVertex> poly(3);
                double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
                for (int c = 0; c < 3; ++c) {
                    ClipVertex& cv = poly[static_cast<std::size_t>(c)];
                    cv.e0 = cv.e1 = c;
                    cv.v = idx[c].vertex_index;
                    cv.vn = idx[c].normal_index;
                    for (int d = 0; d < 3; ++d) cv.p[d] = attrib.vertices[3 * static_cast<std::size_t>(cv.v) + d];
                    if (cv.vn >= 0)
                        for (int d = 0; d < 3; ++d) cv.n[d] = attrib.normals[3 * static_cast<std::size_t>(cv.vn) + d];
                    for (int axis = 0; axis < 2; ++axis) {
                        cv.uv[axis] = attrib.texcoords[2 * static_cast<std::size_t>(idx[c].texcoord_index) + axis];
                        lo[axis] = std::min(lo[axis], cv.uv[axis]);
                        hi[axis] = std::max(hi[axis], cv.uv[axis]);
                    }
                }
                if (!std::isfinite(lo[0]) || !std::isfinite(hi[0]) || !std::isfinite(lo[1]) || !std::isfinite(hi[1]))
                    return make_error(Errc::invalid_argument, "material '" + material_name(material) + "' (shape '" + s.name +
                                                                  "'): a texture coordinate is not a finite number");
                // Repeats the triangle touches on each axis: [first, last] (slack: 1.0000001 is 1).
                // Spans and magnitudes are checked as doubles first: no overflow, no undefined cast.
                for (int axis = 0; axis < 2; ++axis)
                    if (!(hi[axis] - lo[axis] <= double(kMaxPiecesPerTriangle)) || std::abs(lo[axis]) > 1e12 || std::abs(hi[axis]) > 1e12) {
                        char range[160];
                        std::snprintf(range, sizeof range, "u from %.6g to %.6g, v from %.6g to %.6g", lo[0], hi[0], lo[1], hi[1]);
                        return make_error(Errc::unsupported, "material '" + material_name(material) + "' (shape '" + s.name +
                                                                 "'): texture repeats too often across one triangle (" + range +
                                                                 "); at most " + std::to_string(kMaxPiecesPerTriangle) + " pieces per triangle");
                    }
                const ClipVertex original[3] = {poly[0], poly[1], poly[2]};
                std::int64_t first[2], last[2];
                for (int axis = 0; axis < 2; ++axis) {
                    first[axis] = static_cast<std::int64_t>(std::floor(lo[axis] + kRepeatSlack));
                    last[axis] = std::max(first[axis], static_cast<std::int64_t>(std::ceil(hi[axis] - kRepeatSlack)) - 1);
                    if (lo[axis] < -kRepeatSlack || hi[axis] > 1.0 + kRepeatSlack) impl->images[image].repeats = true;
                }
                const std::uint64_t pieces = std::uint64_t(last[0] - first[0] + 1) * std::uint64_t(last[1] - first[1] + 1);
                if (pieces > kMaxPiecesPerTriangle) {
                    char range[160];
                    std::snprintf(range, sizeof range, "u from %.6g to %.6g, v from %.6g to %.6g", lo[0], hi[0], lo[1], hi[1]);
                    return make_error(Errc::unsupported, "material '" + material_name(material) + "' (shape '" + s.name +
                                                             "'): texture repeats " + std::to_string(pieces) +
                                                             " times across one triangle (" + range + "); at most " +
                                                             std::to_string(kMaxPiecesPerTriangle) + " are cut into pieces");
                }
                for (std::int64_t ru = first[0]; ru <= last[0]; ++ru) {
                    std::vector<ClipVertex> column = poly;
                    if (ru > first[0]) column = clip(column, original, 0, double(ru), true);
                    if (ru < last[0]) column = clip(column, original, 0, double(ru + 1), false);
                    if (column.size() < 3) continue;
                    for (std::int64_t rv = first[1]; rv <= last[1]; ++rv) {
                        std::vector<ClipVertex> piece = column;
                        if (rv > first[1]) piece = clip(piece, original, 1, double(rv), true);
                        if (rv < last[1]) piece = clip(piece, original, 1, double(rv + 1), false);
                        if (piece.size() < 3) continue;
                        // Corners made by clipping become new positions (and normals) of the OBJ.
                        std::vector<Corner> corners(piece.size());
                        for (std::size_t c = 0; c < piece.size(); ++c) {
                            const ClipVertex& cv = piece[c];
                            Corner& out = corners[c];
                            out.v = cv.v;
                            out.n = cv.vn;
                            if (cv.v < 0) {
                                out.v = new_index(impl->positions, new_positions, cv.p, false);
                                if (poly[0].vn >= 0 && poly[1].vn >= 0 && poly[2].vn >= 0)
                                    out.n = new_index(impl->normals, new_normals, cv.n, true);
                            }
                            out.u = std::clamp(cv.uv[0] - double(ru), 0.0, 1.0);
                            out.t = std::clamp(cv.uv[1] - double(rv), 0.0, 1.0);
                        }
                        for (std::size_t c = 1; c + 1 < corners.size(); ++c) {
                            // A fan triangle of no area in space (two of its corners one point) is left out.
                            if (corners[c].v == corners[0].v || corners[c + 1].v == corners[0].v || corners[c].v == corners[c + 1].v)
                                continue;
                            Triangle piece_tri;
                            piece_tri.image = image;
                            piece_tri.c[0] = corners[0];
                            piece_tri.c[1] = corners[c];
                            piece_tri.c[2] = corners[c + 1];
                            shape.triangles.push_back(piece_tri);
                        }
                        if (pieces > 1) ++impl->cut_pieces;
                        if (impl->triangles + shape.triangles.size() > kMaxTriangles)
                            return make_error(Errc::unsupported, "OBJ '" + obj_path + "': more than " + std::to_string(kMaxTriangles) +
                                                                     " triangles once repeating textures are cut at their repeats");
                    }
                }
                if (impl->triangles + shape.triangles.size() > kMaxTriangles)
                    return make_error(Errc::unsupported, "OBJ '" + obj_path + "': more than " + std::to_string(kMaxTriangles) +
                                                             " triangles once repeating textures are cut at their repeats");
            }
            offset += nv;
        }
        impl->triangles += shape.triangles.size();
        if (!shape.triangles.empty()) impl->shapes.push_back(std::move(shape));
    }
    if (impl->triangles == 0) return make_error(Errc::invalid_argument, "OBJ '" + obj_path + "' has no triangles");
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (std::size_t i = 0; i + 2 < impl->positions.size(); i += 3)
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], double(impl->positions[i + static_cast<std::size_t>(k)]));
            hi[k] = std::max(hi[k], double(impl->positions[i + static_cast<std::size_t>(k)]));
        }
    for (int k = 0; k < 3; ++k) impl->extent[static_cast<std::size_t>(k)] = hi[k] > lo[k] ? hi[k] - lo[k] : 0.0;
    impl->up = up != UpAxis::automatic ? up : impl->extent[2] < impl->extent[1] ? UpAxis::z : UpAxis::y;
    return ObjAtlasInput(std::move(impl));
}

Result<std::string> ObjAtlasInput::rewrite(std::span<const AtlasRect> rects, std::uint32_t atlas_width,
                                           std::uint32_t atlas_height, const std::string& source_note) const {
    const Impl& m = *impl_;
    if (rects.size() != m.images.size())
        return make_error(Errc::invalid_argument, "atlas rewrite: " + std::to_string(rects.size()) + " rectangles for " +
                                                      std::to_string(m.images.size()) + " images");
    if (atlas_width == 0 || atlas_height == 0) return make_error(Errc::invalid_argument, "atlas rewrite: the atlas has zero size");
    for (std::size_t i = 0; i < rects.size(); ++i)
        if (rects[i].width == 0 || rects[i].height == 0 || std::uint64_t(rects[i].x) + rects[i].width > atlas_width ||
            std::uint64_t(rects[i].y) + rects[i].height > atlas_height)
            return make_error(Errc::invalid_argument, "atlas rewrite: rectangle " + std::to_string(i) + " lies outside the atlas");

    std::string out;
    out.reserve(64 * (m.positions.size() / 3 + m.normals.size() / 3 + 3 * m.triangles));
    out += "# tessera-atlas " + std::to_string(atlas_width) + " " + std::to_string(atlas_height) + "\n";
    out += std::string("# tessera-up ") + (m.up == UpAxis::z ? "z" : "y") + "\n";
    out += "# Written by `tessera build --atlas`" + (source_note.empty() ? std::string() : " from " + source_note) + ".\n";
    out += "# Texture coordinates address the whole atlas (" + std::to_string(atlas_width) + "x" + std::to_string(atlas_height) +
           " texels): u right, v DOWN (v = 0 is the atlas's top row), unlike the usual OBJ convention.\n";
    for (std::size_t i = 0; i + 2 < m.positions.size(); i += 3)
        append(out, "v %.9g %.9g %.9g\n", m.positions[i], m.positions[i + 1], m.positions[i + 2]);
    for (std::size_t i = 0; i + 2 < m.normals.size(); i += 3)
        append(out, "vn %.9g %.9g %.9g\n", m.normals[i], m.normals[i + 1], m.normals[i + 2]);

    // Atlas texture coordinates, deduplicated by value; faces written after them.
    std::unordered_map<std::uint64_t, std::uint32_t> vt_index;
    std::string faces, vts;
    const double W = atlas_width, H = atlas_height;
    for (const Shape& s : m.shapes) {
        faces += "o " + (s.name.empty() ? std::string("shape") : s.name) + "\n";
        for (const Triangle& t : s.triangles) {
            const AtlasRect& r = rects[t.image];
            const bool solid = m.images[t.image].texture.empty();
            faces += "f";
            for (const Corner& c : t.c) {
                // Texel position in the atlas; OBJ's v points up, the atlas's rows down: flip.
                // A solid tile: the centre of its middle texel (no sample lands on a texel edge).
                const double ax = solid ? r.x + r.width / 2 + 0.5 : r.x + c.u * r.width;
                const double ay = solid ? r.y + r.height / 2 + 0.5 : r.y + (1.0 - c.t) * r.height;
                const float au = static_cast<float>(ax / W), av = static_cast<float>(ay / H);
                std::uint32_t bu, bv;
                std::memcpy(&bu, &au, 4);
                std::memcpy(&bv, &av, 4);
                auto [it, inserted] = vt_index.emplace((std::uint64_t(bu) << 32) | bv, static_cast<std::uint32_t>(vt_index.size() + 1));
                if (inserted) {
                    char vt[64];
                    const int n = std::snprintf(vt, sizeof vt, "vt %.9g %.9g\n", double(au), double(av));
                    vts.append(vt, static_cast<std::size_t>(std::max(0, n)));
                }
                char buf[64];
                const int n = c.n >= 0 ? std::snprintf(buf, sizeof buf, " %d/%u/%d", c.v + 1, it->second, c.n + 1)
                                       : std::snprintf(buf, sizeof buf, " %d/%u", c.v + 1, it->second);
                faces.append(buf, static_cast<std::size_t>(std::max(0, n)));
            }
            faces += "\n";
        }
    }
    out += vts;
    out += faces;
    return out;
}

}  // namespace tessera::scene
