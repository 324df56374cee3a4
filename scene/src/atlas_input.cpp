// What both atlas readers share (atlas_input_data.hpp): cutting textured triangles where their
// textures repeat, the input's accessors, and the rewritten OBJ.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <tuple>

#include "atlas_input_data.hpp"

namespace tessera::scene {
namespace detail {
namespace {

// Texture coordinates this close outside a whole repeat still count as inside it (exporters write
// 1.0000001 for 1).
constexpr double kRepeatSlack = 1e-5;
// Triangles one face may be cut into at repeat boundaries, and in all: a texture repeated
// thousands of times across one face would otherwise make millions of triangles silently.
constexpr std::uint64_t kMaxPiecesPerTriangle = 1u << 16;
constexpr std::uint64_t kMaxTriangles = 1u << 24;

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

void append(std::string& out, const char* fmt, double a, double b, double c) {
    char buf[128];
    const int n = std::snprintf(buf, sizeof buf, fmt, a, b, c);
    out.append(buf, static_cast<std::size_t>(std::max(0, n)));
}


int new_index(std::vector<float>& values, std::unordered_map<std::array<std::uint32_t, 3>, int, AtlasInputData::BitsHash>& seen,
              const double (&x)[3], bool normalise) {
    double len = normalise ? std::sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]) : 1.0;
    if (!(len > 0)) len = 1.0;
    const float f[3] = {static_cast<float>(x[0] / len), static_cast<float>(x[1] / len), static_cast<float>(x[2] / len)};
    std::array<std::uint32_t, 3> key;
    std::memcpy(key.data(), f, sizeof f);
    auto [it, inserted] = seen.emplace(key, static_cast<int>(values.size() / 3));
    if (inserted) values.insert(values.end(), f, f + 3);
    return it->second;
}

// A coordinate of cell `k` on an axis (the cell spans [k, k + 1]; for clamp_to_edge the cells are
// -1: below 0, 0: [0, 1], 1: above 1) mapped into [0, 1]: exact, since within one cell each wrap
// mode is a linear function of the coordinate.
double map_into_cell(double x, std::int64_t k, Wrap wrap) {
    switch (wrap) {
        case Wrap::repeat: return std::clamp(x - double(k), 0.0, 1.0);
        case Wrap::mirrored_repeat:
            return std::clamp(k % 2 == 0 ? x - double(k) : double(k + 1) - x, 0.0, 1.0);
        case Wrap::clamp_to_edge: return k < 0 ? 0.0 : k > 0 ? 1.0 : std::clamp(x, 0.0, 1.0);
    }
    return 0.0;
}

std::string range_text(const double (&lo)[2], const double (&hi)[2]) {
    char range[160];
    std::snprintf(range, sizeof range, "u from %.6g to %.6g, v from %.6g to %.6g (v up, OBJ's way)", lo[0], hi[0], lo[1], hi[1]);
    return range;
}

}  // namespace

Status add_textured_triangle(AtlasInputData& data, Shape& shape, std::uint32_t image, const int (&v)[3], const int (&vn)[3],
                             const double (&uv)[3][2], const Wrap (&wrap)[2], const std::string& context) {
    // Where the texture repeats across the triangle, cut it at every whole repeat (u = k, v = j)
    // and map each piece into [0, 1]: exact, since the texture repeats (mirrors, clamps), and each
    // piece samples one copy of the image in its atlas cell, whose padding wraps around for
    // repeats (docs/atlas.md, "Repeating textures").
    std::vector<ClipVertex> poly(3);
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    const bool has_normals = vn[0] >= 0 && vn[1] >= 0 && vn[2] >= 0;
    for (int c = 0; c < 3; ++c) {
        ClipVertex& cv = poly[static_cast<std::size_t>(c)];
        cv.e0 = cv.e1 = c;
        cv.v = v[c];
        cv.vn = vn[c];
        for (int d = 0; d < 3; ++d) cv.p[d] = data.positions[3 * static_cast<std::size_t>(cv.v) + static_cast<std::size_t>(d)];
        if (cv.vn >= 0)
            for (int d = 0; d < 3; ++d) cv.n[d] = data.normals[3 * static_cast<std::size_t>(cv.vn) + static_cast<std::size_t>(d)];
        for (int axis = 0; axis < 2; ++axis) {
            cv.uv[axis] = uv[c][axis];
            lo[axis] = std::min(lo[axis], cv.uv[axis]);
            hi[axis] = std::max(hi[axis], cv.uv[axis]);
        }
    }
    if (!std::isfinite(lo[0]) || !std::isfinite(hi[0]) || !std::isfinite(lo[1]) || !std::isfinite(hi[1]))
        return make_error(Errc::invalid_argument, context + ": a texture coordinate is not a finite number");
    // Spans and magnitudes are checked as doubles first: no overflow, no undefined cast.
    for (int axis = 0; axis < 2; ++axis)
        if (!(hi[axis] - lo[axis] <= double(kMaxPiecesPerTriangle)) || std::abs(lo[axis]) > 1e12 || std::abs(hi[axis]) > 1e12)
            return make_error(Errc::unsupported, context + ": texture repeats too often across one triangle (" + range_text(lo, hi) +
                                                     "); at most " + std::to_string(kMaxPiecesPerTriangle) + " pieces per triangle");
    const ClipVertex original[3] = {poly[0], poly[1], poly[2]};
    // The cells the triangle touches on each axis: [first, last] (slack: 1.0000001 is 1).
    std::int64_t first[2], last[2];
    for (int axis = 0; axis < 2; ++axis) {
        if (wrap[axis] == Wrap::clamp_to_edge) {
            auto cell = [](double x) -> std::int64_t { return x < -kRepeatSlack ? -1 : x > 1.0 + kRepeatSlack ? 1 : 0; };
            first[axis] = cell(lo[axis]);
            last[axis] = cell(hi[axis]);
        } else {
            first[axis] = static_cast<std::int64_t>(std::floor(lo[axis] + kRepeatSlack));
            last[axis] = std::max(first[axis], static_cast<std::int64_t>(std::ceil(hi[axis] - kRepeatSlack)) - 1);
        }
        if (wrap[axis] == Wrap::repeat && (lo[axis] < -kRepeatSlack || hi[axis] > 1.0 + kRepeatSlack)) data.images[image].repeats = true;
    }
    const std::uint64_t pieces = std::uint64_t(last[0] - first[0] + 1) * std::uint64_t(last[1] - first[1] + 1);
    if (pieces > kMaxPiecesPerTriangle)
        return make_error(Errc::unsupported, context + ": texture repeats " + std::to_string(pieces) + " times across one triangle (" +
                                                 range_text(lo, hi) + "); at most " + std::to_string(kMaxPiecesPerTriangle) +
                                                 " are cut into pieces");
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
            // Corners made by clipping become new positions (and normals).
            std::vector<Corner> corners(piece.size());
            for (std::size_t c = 0; c < piece.size(); ++c) {
                const ClipVertex& cv = piece[c];
                Corner& out = corners[c];
                out.v = cv.v;
                out.n = cv.vn;
                if (cv.v < 0) {
                    out.v = new_index(data.positions, data.cut_positions, cv.p, false);
                    if (has_normals) out.n = new_index(data.normals, data.cut_normals, cv.n, true);
                }
                out.u = map_into_cell(cv.uv[0], ru, wrap[0]);
                out.t = map_into_cell(cv.uv[1], rv, wrap[1]);
            }
            for (std::size_t c = 1; c + 1 < corners.size(); ++c) {
                // A fan triangle of no area in space (two of its corners one point) is left out.
                if (corners[c].v == corners[0].v || corners[c + 1].v == corners[0].v || corners[c].v == corners[c + 1].v) continue;
                Triangle piece_tri;
                piece_tri.image = image;
                piece_tri.c[0] = corners[0];
                piece_tri.c[1] = corners[c];
                piece_tri.c[2] = corners[c + 1];
                shape.triangles.push_back(piece_tri);
            }
            if (pieces > 1) ++data.cut_pieces;
            if (data.triangles + shape.triangles.size() > kMaxTriangles)
                return make_error(Errc::unsupported, context + ": more than " + std::to_string(kMaxTriangles) +
                                                         " triangles once repeating textures are cut at their repeats");
        }
    }
    return {};
}

std::string trim_newlines(std::string s) {
    std::replace(s.begin(), s.end(), '\n', ' ');
    while (!s.empty() && s.back() == ' ') s.pop_back();
    return s;
}

Status finish_atlas_input(AtlasInputData& data, UpAxis up, const std::string& what) {
    if (data.triangles == 0) return make_error(Errc::invalid_argument, what + " has no triangles");
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (std::size_t i = 0; i + 2 < data.positions.size(); i += 3)
        for (std::size_t k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], double(data.positions[i + k]));
            hi[k] = std::max(hi[k], double(data.positions[i + k]));
        }
    for (std::size_t k = 0; k < 3; ++k) data.extent[k] = hi[k] > lo[k] ? hi[k] - lo[k] : 0.0;
    data.up = up != UpAxis::automatic ? up : data.extent[2] < data.extent[1] ? UpAxis::z : UpAxis::y;
    return {};
}

}  // namespace detail

struct AtlasSceneInput::Impl : detail::AtlasInputData {};

AtlasSceneInput::AtlasSceneInput(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
AtlasSceneInput::AtlasSceneInput(AtlasSceneInput&&) noexcept = default;
AtlasSceneInput& AtlasSceneInput::operator=(AtlasSceneInput&&) noexcept = default;
AtlasSceneInput::~AtlasSceneInput() = default;
const std::vector<AtlasImageRef>& AtlasSceneInput::images() const { return impl_->images; }
std::size_t AtlasSceneInput::triangle_count() const { return impl_->triangles; }
std::size_t AtlasSceneInput::repeat_piece_count() const { return impl_->cut_pieces; }
UpAxis AtlasSceneInput::up_axis() const { return impl_->up; }
std::array<double, 3> AtlasSceneInput::extent() const { return impl_->extent; }
const std::vector<std::string>& AtlasSceneInput::warnings() const { return impl_->warnings; }
const std::vector<AtlasSceneInput::InputFile>& AtlasSceneInput::input_files() const { return impl_->input_files; }

Result<AtlasSceneInput> AtlasSceneInput::load(const std::string& path, UpAxis up) {
    std::string ext = path.size() >= 4 ? path.substr(path.size() - 4) : std::string();
    std::string ext5 = path.size() >= 5 ? path.substr(path.size() - 5) : std::string();
    for (auto* s : {&ext, &ext5})
        for (char& ch : *s) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
    const bool gltf = ext == ".glb" || ext5 == ".gltf";
    if (!gltf && ext != ".obj")
        return make_error(Errc::invalid_argument, "scene '" + path + "': not an OBJ (.obj) or glTF 2.0 (.gltf, .glb) file");
    const std::string kind = gltf ? "glTF" : "OBJ";
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) return make_error(Errc::not_found, kind + " file '" + path + "' does not exist");
    if (std::filesystem::is_directory(path, ec)) return make_error(Errc::invalid_argument, kind + " file '" + path + "' is a directory");
    auto impl = std::make_unique<Impl>();
    impl->input_files.push_back({path, "scene"});
    if (gltf) {
        TESSERA_TRY(detail::read_gltf(path, up, *impl));
    } else {
        TESSERA_TRY(detail::read_obj(path, up, *impl));
    }
    return AtlasSceneInput(std::move(impl));
}

Result<std::string> AtlasSceneInput::rewrite(std::span<const AtlasRect> rects, std::uint32_t atlas_width,
                                           std::uint32_t atlas_height, const std::string& source_note) const {
    const detail::AtlasInputData& m = *impl_;
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
        detail::append(out, "v %.9g %.9g %.9g\n", m.positions[i], m.positions[i + 1], m.positions[i + 2]);
    for (std::size_t i = 0; i + 2 < m.normals.size(); i += 3)
        detail::append(out, "vn %.9g %.9g %.9g\n", m.normals[i], m.normals[i + 1], m.normals[i + 2]);

    // Atlas texture coordinates, deduplicated by value; faces written after them.
    std::unordered_map<std::uint64_t, std::uint32_t> vt_index;
    std::string faces, vts;
    const double W = atlas_width, H = atlas_height;
    auto write_triangle = [&](const detail::Triangle& t) {
        const AtlasRect& r = rects[t.image];
        const bool solid = m.images[t.image].solid();
        faces += "f";
        for (const detail::Corner& c : t.c) {
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
    };
    // A shape's blended triangles (Triangle::blend) follow its others as an object of the same
    // name marked by a "# tessera-blend" line before it (parse_obj_scene: Chunk::blend).
    for (const detail::Shape& s : m.shapes)
        for (const bool blend : {false, true}) {
            const auto of_kind = [&](const detail::Triangle& t) { return t.blend == blend; };
            if (std::none_of(s.triangles.begin(), s.triangles.end(), of_kind)) continue;
            if (blend) faces += "# tessera-blend\n";
            faces += "o " + (s.name.empty() ? std::string("shape") : s.name) + "\n";
            for (const detail::Triangle& t : s.triangles)
                if (of_kind(t)) write_triangle(t);
        }
    out += vts;
    out += faces;
    return out;
}


}  // namespace tessera::scene
