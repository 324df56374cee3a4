// The `atlas` scene: an OBJ whose texture coordinates address the packed atlas (written by
// `tessera build --atlas`, see atlas.hpp), one chunk per OBJ object.
#include <tiny_obj_loader.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <unordered_map>

#include "tessera/scene/scene.hpp"

namespace tessera::scene {
namespace {

std::string one_line(std::string s) {
    std::replace(s.begin(), s.end(), '\n', ' ');
    while (!s.empty() && s.back() == ' ') s.pop_back();
    return s;
}

// The first lines of an atlas OBJ: its comment lines up to the first other line.
std::vector<std::string> header_lines(std::string_view text) {
    std::vector<std::string> out;
    std::size_t at = 0;
    while (at < text.size() && out.size() < 16 && text[at] == '#') {
        std::size_t nl = text.find('\n', at);
        if (nl == std::string_view::npos) nl = text.size();
        out.emplace_back(text.substr(at, nl - at));
        at = nl + 1;
    }
    return out;
}

}  // namespace

AtlasObjHeader read_atlas_obj_header(std::string_view text) {
    AtlasObjHeader h;
    for (const std::string& line : header_lines(text)) {
        unsigned long long a = 0, b = 0;
        if (std::sscanf(line.c_str(), "# tessera-atlas %llu %llu", &a, &b) == 2) {
            h.atlas = true;
            h.width = a;
            h.height = b;
        } else if (line.rfind("# tessera-up ", 0) == 0) {
            h.z_up = line.size() > 13 && (line[13] == 'z' || line[13] == 'Z');
        }
    }
    return h;
}

Result<Scene> load_obj_scene(const std::string& obj_path, std::uint32_t vt_width, std::uint32_t vt_height) {
    std::error_code ec;
    if (!std::filesystem::exists(obj_path, ec)) return make_error(Errc::not_found, "OBJ file '" + obj_path + "' does not exist");
    std::ifstream f(obj_path, std::ios::binary);
    std::string text(std::istreambuf_iterator<char>(f), {});
    if (!f && !f.eof()) return make_error(Errc::io_error, "cannot read OBJ '" + obj_path + "'");
    return parse_obj_scene(text, obj_path, vt_width, vt_height);
}

namespace {
struct VertexKey {
    std::uint64_t vertex_texcoord;
    int normal;
    bool operator==(const VertexKey&) const = default;
};
struct VertexKeyHash {
    std::size_t operator()(const VertexKey& k) const noexcept {
        return std::hash<std::uint64_t>()(k.vertex_texcoord ^ (std::uint64_t(std::uint32_t(k.normal)) * 0x9E3779B97F4A7C15ull));
    }
};
}  // namespace

Result<Scene> parse_obj_scene(const std::string& text, const std::string& obj_path, std::uint32_t vt_width, std::uint32_t vt_height) {
    if (vt_width == 0 || vt_height == 0) return make_error(Errc::invalid_argument, "OBJ scene: the virtual texture has zero size");
    const AtlasObjHeader header = read_atlas_obj_header(text);
    if (header.atlas && (header.width != vt_width || header.height != vt_height))
        return make_error(Errc::invalid_argument, "OBJ '" + obj_path + "' was written for a " + std::to_string(header.width) + "x" +
                                                      std::to_string(header.height) + " atlas, but the virtual texture is " +
                                                      std::to_string(vt_width) + "x" + std::to_string(vt_height));
    tinyobj::ObjReaderConfig config;
    config.triangulate = true;
    config.vertex_color = false;
    tinyobj::ObjReader reader;
    if (!reader.ParseFromString(text, std::string(), config))
        return make_error(Errc::corrupt, "cannot read OBJ '" + obj_path + "': " + one_line(reader.Error()));
    if (reader.Warning().find("indices out of bounds") != std::string::npos ||
        reader.Warning().find("invalid vertex index") != std::string::npos)
        return make_error(Errc::corrupt, "OBJ '" + obj_path + "': " + one_line(reader.Warning()));
    const tinyobj::attrib_t& a = reader.GetAttrib();

    Scene scene;
    scene.name = "atlas";
    scene.vt_width = vt_width;
    scene.vt_height = vt_height;
    for (int k = 0; k < 3; ++k) {
        scene.bounds_min[k] = INFINITY;
        scene.bounds_max[k] = -INFINITY;
    }
    // OBJ is Y up unless the file says "# tessera-up z"; this library is Z up: a Y-up file maps
    // (x, y, z) -> (x, -z, y), a rotation (winding is kept).
    const bool file_z_up = header.z_up;
    auto world = [&](int v) -> Vec3d {
        const std::size_t i = 3 * static_cast<std::size_t>(v);
        if (file_z_up) return {double(a.vertices[i]), double(a.vertices[i + 1]), double(a.vertices[i + 2])};
        return {double(a.vertices[i]), -double(a.vertices[i + 2]), double(a.vertices[i + 1])};
    };
    // Normals turn as positions do; a corner without one gets (0, 0, 0): the renderer then lights
    // its facet. A scene with no `vn` at all keeps none.
    const bool with_normals = !a.normals.empty();
    auto normal = [&](int n) -> Vec3d {
        if (n < 0 || 3 * std::size_t(n) + 2 >= a.normals.size()) return {0.0, 0.0, 0.0};
        const std::size_t i = 3 * static_cast<std::size_t>(n);
        if (file_z_up) return {double(a.normals[i]), double(a.normals[i + 1]), double(a.normals[i + 2])};
        return {double(a.normals[i]), -double(a.normals[i + 2]), double(a.normals[i + 1])};
    };
    auto texel = [&](int t) -> std::array<double, 2> {
        if (t < 0) return {0.0, 0.0};
        const std::size_t i = 2 * static_cast<std::size_t>(t);
        return {double(a.texcoords[i]) * vt_width, double(a.texcoords[i + 1]) * vt_height};  // v is already down
    };

    // Objects written blended (an atlas OBJ's "# tessera-blend" line before their "o" line), in
    // file order; the shapes come in the same order, each named as its object.
    std::vector<std::pair<std::string, bool>> objects;
    {
        bool marked = false;
        std::size_t at = 0;
        while (at < text.size()) {
            std::size_t eol = text.find('\n', at);
            if (eol == std::string::npos) eol = text.size();
            std::string_view line(text.data() + at, eol - at);
            if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
            if (line == "# tessera-blend") {
                marked = true;
            } else if (line.rfind("o ", 0) == 0) {
                std::string_view name = line.substr(2);
                while (!name.empty() && (name.front() == ' ' || name.front() == '\t')) name.remove_prefix(1);
                while (!name.empty() && (name.back() == ' ' || name.back() == '\t')) name.remove_suffix(1);
                objects.emplace_back(std::string(name), marked);
                marked = false;
            }
            at = eol + 1;
        }
    }
    std::size_t next_object = 0;
    auto blended = [&](const std::string& name) {
        for (std::size_t i = next_object; i < objects.size(); ++i)
            if (objects[i].first == name) {
                next_object = i + 1;
                return objects[i].second;
            }
        return false;
    };

    for (const tinyobj::shape_t& s : reader.GetShapes()) {
        const bool blend = blended(s.name);
        const auto& idx = s.mesh.indices;
        if (idx.empty()) continue;
        // Bounds first: the chunk's origin is its box centre, its texel origin the floor of its
        // smallest texel, so the float offsets stay small.
        Chunk c;
        c.blend = blend;
        double tmin[2] = {INFINITY, INFINITY};
        for (int k = 0; k < 3; ++k) {
            c.bounds_min[k] = INFINITY;
            c.bounds_max[k] = -INFINITY;
        }
        for (const tinyobj::index_t& i : idx) {
            const Vec3d p = world(i.vertex_index);
            for (int k = 0; k < 3; ++k) {
                c.bounds_min[k] = std::min(c.bounds_min[k], p[k]);
                c.bounds_max[k] = std::max(c.bounds_max[k], p[k]);
            }
            const auto t = texel(i.texcoord_index);
            tmin[0] = std::min(tmin[0], t[0]);
            tmin[1] = std::min(tmin[1], t[1]);
        }
        for (int k = 0; k < 3; ++k) c.origin[k] = 0.5 * (c.bounds_min[k] + c.bounds_max[k]);
        c.texel_origin[0] = static_cast<std::uint32_t>(std::clamp(std::floor(tmin[0]), 0.0, double(vt_width)));
        c.texel_origin[1] = static_cast<std::uint32_t>(std::clamp(std::floor(tmin[1]), 0.0, double(vt_height)));

        std::unordered_map<VertexKey, std::uint32_t, VertexKeyHash> seen;  // (vertex, texcoord, normal) -> chunk vertex
        std::size_t offset = 0;
        for (std::size_t f = 0; f < s.mesh.num_face_vertices.size(); ++f) {
            const std::size_t nv = s.mesh.num_face_vertices[f];
            std::uint32_t corner[3] = {0, 0, 0};
            for (std::size_t k = 1; k + 1 < nv; ++k) {
                const tinyobj::index_t tri[3] = {idx[offset], idx[offset + k], idx[offset + k + 1]};
                for (int j = 0; j < 3; ++j) {
                    const VertexKey key{(std::uint64_t(std::uint32_t(tri[j].vertex_index)) << 32) | std::uint32_t(tri[j].texcoord_index),
                                        tri[j].normal_index};
                    auto [it, inserted] = seen.emplace(key, static_cast<std::uint32_t>(c.vertices.size()));
                    if (inserted) {
                        if (with_normals) {
                            const Vec3d n = normal(tri[j].normal_index);
                            c.normals.insert(c.normals.end(), {float(n[0]), float(n[1]), float(n[2])});
                        }
                        const Vec3d p = world(tri[j].vertex_index);
                        const auto t = texel(tri[j].texcoord_index);
                        Vertex v{};
                        for (int d = 0; d < 3; ++d) v.position[d] = static_cast<float>(p[d] - c.origin[d]);
                        v.texel[0] = static_cast<float>(t[0] - c.texel_origin[0]);
                        v.texel[1] = static_cast<float>(t[1] - c.texel_origin[1]);
                        c.vertices.push_back(v);
                    }
                    corner[j] = it->second;
                }
                c.indices.insert(c.indices.end(), {corner[0], corner[1], corner[2]});
            }
            offset += nv;
        }
        if (c.indices.empty()) continue;
        for (int k = 0; k < 3; ++k) {
            scene.bounds_min[k] = std::min(scene.bounds_min[k], c.bounds_min[k]);
            scene.bounds_max[k] = std::max(scene.bounds_max[k], c.bounds_max[k]);
        }
        scene.chunks.push_back(std::move(c));
    }
    if (scene.chunks.empty()) return make_error(Errc::invalid_argument, "OBJ '" + obj_path + "' has no triangles");
    return scene;
}

}  // namespace tessera::scene
