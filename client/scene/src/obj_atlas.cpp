// The OBJ side of the atlas build: materials to images, and texture coordinates into the atlas.
#include <tiny_obj_loader.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
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

struct ObjAtlasInput::Impl {
    std::vector<float> positions, normals;
    std::vector<Shape> shapes;
    std::vector<AtlasImageRef> images;
    std::size_t triangles = 0;
};

ObjAtlasInput::ObjAtlasInput(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ObjAtlasInput::ObjAtlasInput(ObjAtlasInput&&) noexcept = default;
ObjAtlasInput& ObjAtlasInput::operator=(ObjAtlasInput&&) noexcept = default;
ObjAtlasInput::~ObjAtlasInput() = default;
const std::vector<AtlasImageRef>& ObjAtlasInput::images() const { return impl_->images; }
std::size_t ObjAtlasInput::triangle_count() const { return impl_->triangles; }

Result<ObjAtlasInput> ObjAtlasInput::load(const std::string& obj_path) {
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
                if (has_uv) {
                    // Shift the triangle by whole repeats so that it lies in [0, 1] on each axis.
                    for (int axis = 0; axis < 2; ++axis) {
                        double val[3], lo = INFINITY, hi = -INFINITY;
                        for (int c = 0; c < 3; ++c) {
                            val[c] = attrib.texcoords[2 * static_cast<std::size_t>(idx[c].texcoord_index) + axis];
                            lo = std::min(lo, val[c]);
                            hi = std::max(hi, val[c]);
                        }
                        const double shift = std::floor(lo + kRepeatSlack);
                        if (!std::isfinite(lo) || !std::isfinite(hi) || hi - shift > 1.0 + kRepeatSlack) {
                            char range[96];
                            std::snprintf(range, sizeof range, "%s from %.6g to %.6g", axis == 0 ? "u" : "v", lo, hi);
                            return make_error(Errc::unsupported,
                                              "material '" + material_name(material) + "' (shape '" + s.name +
                                                  "'): texture repeats across a triangle (" + range +
                                                  "); atlas mode cannot pack repeating textures");
                        }
                        for (int c = 0; c < 3; ++c) {
                            const double shifted = std::clamp(val[c] - shift, 0.0, 1.0);
                            (axis == 0 ? tri.c[c].u : tri.c[c].t) = shifted;
                        }
                    }
                }
                shape.triangles.push_back(tri);
            }
            offset += nv;
        }
        impl->triangles += shape.triangles.size();
        if (!shape.triangles.empty()) impl->shapes.push_back(std::move(shape));
    }
    if (impl->triangles == 0) return make_error(Errc::invalid_argument, "OBJ '" + obj_path + "' has no triangles");
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
