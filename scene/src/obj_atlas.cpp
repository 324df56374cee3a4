// The OBJ reader of the atlas build: materials to images, faces to textured triangles
// (atlas_input_data.hpp).
#include <tiny_obj_loader.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string_view>
#include <unordered_map>

#include "atlas_input_data.hpp"

namespace tessera::scene::detail {
namespace fs = std::filesystem;

namespace {

constexpr std::uint8_t kDefaultGrey = 204;  // faces with no material: a light grey solid tile

std::uint8_t to_byte(double v) { return static_cast<std::uint8_t>(std::lround(std::clamp(v, 0.0, 1.0) * 255.0)); }

// tinyobj's reader of material libraries, noting each file it reads: the build must not write
// over them.
class RecordingMaterialReader : public tinyobj::MaterialFileReader {
public:
    explicit RecordingMaterialReader(const std::string& folder) : tinyobj::MaterialFileReader(folder), folder_(folder) {}
    bool operator()(const std::string& name, std::vector<tinyobj::material_t>* materials, std::map<std::string, int>* by_name,
                    std::string* warn, std::string* err) override {
        const bool read = tinyobj::MaterialFileReader::operator()(name, materials, by_name, warn, err);
        if (read) files.push_back(folder_ + name);  // the path tinyobj opened (folder_ ends in '/')
        return read;
    }
    std::vector<std::string> files;

private:
    std::string folder_;
};

bool equals_ignoring_case(std::string_view a, std::string_view b) {
    return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
               return std::tolower(static_cast<unsigned char>(x)) == std::tolower(static_cast<unsigned char>(y));
           });
}

// tinyobj matches MTL keywords case-sensitively; other readers (Assimp) take any case, and some
// exporters write "map_kd". tinyobj keeps such a line as an unknown parameter: it is read here.
std::string diffuse_texture(const tinyobj::material_t& m) {
    if (!m.diffuse_texname.empty()) return m.diffuse_texname;
    for (const auto& [key, value] : m.unknown_parameter) {
        if (!equals_ignoring_case(key, "map_kd")) continue;
        std::string name;
        tinyobj::texture_option_t option;
        if (tinyobj::ParseTextureNameAndOption(&name, &option, value.c_str()) && !name.empty()) return name;
    }
    return {};
}

// A map_Kd line (any case) that names no file: tinyobj drops it, and the material would become
// a solid tile without a word. The first such line of a material library, as an error message.
std::string empty_diffuse_map(const std::string& mtl_path) {
    std::ifstream in(mtl_path);
    std::string line, material = "(before any newmtl)";
    for (int number = 1; std::getline(in, line); ++number) {
        std::istringstream words(line);
        std::string keyword;
        if (!(words >> keyword)) continue;
        if (keyword == "newmtl") {
            std::getline(words >> std::ws, material);
            continue;
        }
        if (!equals_ignoring_case(keyword, "map_kd")) continue;
        std::string rest;
        std::getline(words >> std::ws, rest);
        while (!rest.empty() && (rest.back() == '\r' || rest.back() == ' ' || rest.back() == '\t')) rest.pop_back();
        std::string name;
        tinyobj::texture_option_t option;
        if (rest.empty() || !tinyobj::ParseTextureNameAndOption(&name, &option, rest.c_str()) || name.empty())
            return "material library '" + mtl_path + "' line " + std::to_string(number) + ": material '" + material +
                   "' has a " + keyword + " that names no texture file";
    }
    return {};
}

}  // namespace

Status read_obj(const std::string& obj_path, UpAxis up, AtlasInputData& data) {
    const fs::path folder = fs::path(obj_path).parent_path();
    std::ifstream file(obj_path, std::ios::binary);
    if (!file) return make_error(Errc::io_error, "cannot read OBJ '" + obj_path + "': cannot open the file");
    RecordingMaterialReader mtl_reader(folder.empty() ? std::string("./") : folder.string() + "/");
    tinyobj::attrib_t attrib;
    std::vector<tinyobj::shape_t> obj_shapes;
    std::vector<tinyobj::material_t> materials;
    std::string warn, err;
    if (!tinyobj::LoadObj(&attrib, &obj_shapes, &materials, &warn, &err, &file, &mtl_reader, /*triangulate=*/true,
                          /*default_vcols_fallback=*/false))
        return make_error(Errc::corrupt, "cannot read OBJ '" + obj_path + "': " + trim_newlines(err));
    for (const std::string& mtl : mtl_reader.files) {
        data.input_files.push_back({mtl, "material library"});
        if (std::string e = empty_diffuse_map(mtl); !e.empty()) return make_error(Errc::invalid_argument, e);
    }
    // tinyobj only warns about these; for an atlas they are fatal. Report the first such line.
    for (const char* fatal : {"Material file [", "not found in .mtl", "indices out of bounds", "invalid vertex index"}) {
        const std::size_t at = warn.find(fatal);
        if (at == std::string::npos) continue;
        const std::size_t nl = warn.rfind('\n', at), b = nl == std::string::npos ? 0 : nl + 1;
        const std::size_t e = warn.find('\n', at);
        const std::string line = warn.substr(b, e == std::string::npos ? std::string::npos : e - b);
        return make_error(Errc::invalid_argument, "OBJ '" + obj_path + "': " + trim_newlines(line));
    }

    data.positions = attrib.vertices;
    data.normals = attrib.normals;

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
            tex = diffuse_texture(m);
            colour = {to_byte(m.diffuse[0]), to_byte(m.diffuse[1]), to_byte(m.diffuse[2])};
        }
        std::uint32_t index;
        if (!tex.empty()) {
            std::replace(tex.begin(), tex.end(), '\\', '/');  // files written on Windows
            fs::path p(tex);
            if (p.is_relative()) p = folder / p;
            const std::string key = p.lexically_normal().string();
            auto [it, inserted] = by_texture.emplace(key, static_cast<std::uint32_t>(data.images.size()));
            if (inserted) data.images.emplace_back().texture = key;
            index = it->second;
        } else {
            auto [it, inserted] = by_colour.emplace(colour, static_cast<std::uint32_t>(data.images.size()));
            if (inserted) data.images.emplace_back().colour = colour;
            index = it->second;
        }
        data.images[index].materials.push_back(name);
        material_image.emplace(material, index);
        return index;
    };

    for (const tinyobj::shape_t& s : obj_shapes) {
        Shape shape;
        shape.name = s.name;
        std::size_t offset = 0;
        for (std::size_t f = 0; f < s.mesh.num_face_vertices.size(); ++f) {
            const std::size_t nv = s.mesh.num_face_vertices[f];
            const int material = f < s.mesh.material_ids.size() ? s.mesh.material_ids[f] : -1;
            const std::uint32_t image = image_of(material);
            const bool textured = !data.images[image].texture.empty();
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
                int v[3], vn[3];
                double uv[3][2];
                for (int c = 0; c < 3; ++c) {
                    v[c] = idx[c].vertex_index;
                    vn[c] = idx[c].normal_index;
                    for (std::size_t axis = 0; axis < 2; ++axis)
                        uv[c][axis] = attrib.texcoords[2 * static_cast<std::size_t>(idx[c].texcoord_index) + axis];
                }
                const Wrap wrap[2] = {Wrap::repeat, Wrap::repeat};  // OBJ textures repeat
                TESSERA_TRY(add_textured_triangle(data, shape, image, v, vn, uv, wrap,
                                                  "material '" + material_name(material) + "' (shape '" + s.name + "')"));
            }
            offset += nv;
        }
        data.triangles += shape.triangles.size();
        if (!shape.triangles.empty()) data.shapes.push_back(std::move(shape));
    }
    return finish_atlas_input(data, up, "OBJ '" + obj_path + "'");
}

}  // namespace tessera::scene::detail
