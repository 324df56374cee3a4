// The glTF 2.0 reader of the atlas build (tinygltf, Debian's libtinygltf): the default scene's
// node tree flattened, each material's base colour texture (or colour) and its normal,
// metallic-roughness, occlusion and emissive maps one atlas cell (the maps for the material
// layers, docs/atlas.md), texture coordinates through KHR_texture_transform and the samplers' wrap
// modes (atlas_input_data.hpp).
#include <tiny_gltf.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <set>
#include <tuple>

#include "atlas_input_data.hpp"

namespace tessera::scene::detail {
namespace fs = std::filesystem;

namespace {

// Extensions a scene may require that this reader honours: texture transforms, quantised
// attributes (normalised integers, read below), and material extensions that only change shading
// (KHR_materials_emissive_strength scales the emissive layer's colour where there is no map).
const std::set<std::string> kHonouredRequired = {"KHR_texture_transform", "KHR_mesh_quantization", "KHR_materials_unlit",
                                                 "KHR_materials_emissive_strength"};

using Mat4 = std::array<double, 16>;  // column-major, as glTF writes matrices
constexpr Mat4 kIdentity = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};

Mat4 multiply(const Mat4& a, const Mat4& b) {
    Mat4 r{};
    for (int c = 0; c < 4; ++c)
        for (int row = 0; row < 4; ++row) {
            double s = 0;
            for (int k = 0; k < 4; ++k) s += a[static_cast<std::size_t>(k * 4 + row)] * b[static_cast<std::size_t>(c * 4 + k)];
            r[static_cast<std::size_t>(c * 4 + row)] = s;
        }
    return r;
}

// A node's local transform: its matrix, or translation * rotation * scale.
Mat4 local_transform(const tinygltf::Node& node) {
    if (node.matrix.size() == 16) {
        Mat4 m;
        std::copy(node.matrix.begin(), node.matrix.end(), m.begin());
        return m;
    }
    const double t[3] = {node.translation.size() == 3 ? node.translation[0] : 0, node.translation.size() == 3 ? node.translation[1] : 0,
                         node.translation.size() == 3 ? node.translation[2] : 0};
    const double s[3] = {node.scale.size() == 3 ? node.scale[0] : 1, node.scale.size() == 3 ? node.scale[1] : 1,
                         node.scale.size() == 3 ? node.scale[2] : 1};
    double x = 0, y = 0, z = 0, w = 1;
    if (node.rotation.size() == 4) x = node.rotation[0], y = node.rotation[1], z = node.rotation[2], w = node.rotation[3];
    const double r[9] = {1 - 2 * (y * y + z * z), 2 * (x * y + z * w),     2 * (x * z - y * w),  // column 0
                         2 * (x * y - z * w),     1 - 2 * (x * x + z * z), 2 * (y * z + x * w),  // column 1
                         2 * (x * z + y * w),     2 * (y * z - x * w),     1 - 2 * (x * x + y * y)};
    Mat4 m = kIdentity;
    for (int c = 0; c < 3; ++c)
        for (int row = 0; row < 3; ++row) m[static_cast<std::size_t>(c * 4 + row)] = r[c * 3 + row] * s[c];
    m[12] = t[0], m[13] = t[1], m[14] = t[2];
    return m;
}

// Normals go through the inverse transpose of the upper 3x3 (its cofactor matrix, up to a scale
// the normalisation removes).
std::array<double, 9> normal_matrix(const Mat4& m) {
    auto a = [&](int row, int col) { return m[static_cast<std::size_t>(col * 4 + row)]; };
    std::array<double, 9> n{};  // row-major
    for (int row = 0; row < 3; ++row)
        for (int col = 0; col < 3; ++col) {
            const int r0 = (row + 1) % 3, r1 = (row + 2) % 3, c0 = (col + 1) % 3, c1 = (col + 2) % 3;
            n[static_cast<std::size_t>(row * 3 + col)] = a(r0, c0) * a(r1, c1) - a(r0, c1) * a(r1, c0);
        }
    return n;
}

double determinant3(const Mat4& m) {
    return m[0] * (m[5] * m[10] - m[9] * m[6]) - m[4] * (m[1] * m[10] - m[9] * m[2]) + m[8] * (m[1] * m[6] - m[5] * m[2]);
}

// An accessor's elements as doubles (normalised integers scaled to [0, 1] or [-1, 1]).
Result<std::vector<double>> read_accessor(const tinygltf::Model& model, int index, int components, const std::string& what) {
    if (index < 0 || static_cast<std::size_t>(index) >= model.accessors.size())
        return make_error(Errc::corrupt, what + ": accessor " + std::to_string(index) + " does not exist");
    const tinygltf::Accessor& acc = model.accessors[static_cast<std::size_t>(index)];
    if (acc.sparse.isSparse) return make_error(Errc::unsupported, what + ": sparse accessors are not read");
    const int n = tinygltf::GetNumComponentsInType(static_cast<std::uint32_t>(acc.type));
    if (n != components)
        return make_error(Errc::corrupt, what + ": accessor " + std::to_string(index) + " has " + std::to_string(n) + " components, not " +
                                             std::to_string(components));
    const int size = tinygltf::GetComponentSizeInBytes(static_cast<std::uint32_t>(acc.componentType));
    if (size <= 0) return make_error(Errc::corrupt, what + ": accessor " + std::to_string(index) + " has an unknown component type");
    std::vector<double> out(acc.count * static_cast<std::size_t>(components), 0.0);
    if (acc.bufferView < 0) return out;  // no data: zeros, as the specification says
    if (static_cast<std::size_t>(acc.bufferView) >= model.bufferViews.size())
        return make_error(Errc::corrupt, what + ": buffer view " + std::to_string(acc.bufferView) + " does not exist");
    const tinygltf::BufferView& view = model.bufferViews[static_cast<std::size_t>(acc.bufferView)];
    if (view.buffer < 0 || static_cast<std::size_t>(view.buffer) >= model.buffers.size())
        return make_error(Errc::corrupt, what + ": buffer " + std::to_string(view.buffer) + " does not exist");
    const std::vector<unsigned char>& data = model.buffers[static_cast<std::size_t>(view.buffer)].data;
    const std::size_t element = static_cast<std::size_t>(size) * static_cast<std::size_t>(components);
    const std::size_t stride = view.byteStride ? view.byteStride : element;
    const std::size_t begin = view.byteOffset + acc.byteOffset;
    if (acc.count > 0 && (acc.byteOffset + (acc.count - 1) * stride + element > view.byteLength || view.byteOffset + view.byteLength > data.size()))
        return make_error(Errc::corrupt, what + ": accessor " + std::to_string(index) + " reaches past the end of its buffer");
    for (std::size_t i = 0; i < acc.count; ++i) {
        const unsigned char* p = data.data() + begin + i * stride;
        for (int c = 0; c < components; ++c, p += size) {
            double v = 0;
            switch (acc.componentType) {
                case TINYGLTF_COMPONENT_TYPE_FLOAT: { float f; std::memcpy(&f, p, 4); v = f; break; }
                case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: v = acc.normalized ? *p / 255.0 : *p; break;
                case TINYGLTF_COMPONENT_TYPE_BYTE: {
                    const auto b = static_cast<std::int8_t>(*p);
                    v = acc.normalized ? std::max(b / 127.0, -1.0) : b;
                    break;
                }
                case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
                    std::uint16_t u; std::memcpy(&u, p, 2);
                    v = acc.normalized ? u / 65535.0 : u;
                    break;
                }
                case TINYGLTF_COMPONENT_TYPE_SHORT: {
                    std::int16_t s; std::memcpy(&s, p, 2);
                    v = acc.normalized ? std::max(s / 32767.0, -1.0) : s;
                    break;
                }
                case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: { std::uint32_t u; std::memcpy(&u, p, 4); v = u; break; }
                default: return make_error(Errc::corrupt, what + ": accessor " + std::to_string(index) + " has an unknown component type");
            }
            out[i * static_cast<std::size_t>(components) + static_cast<std::size_t>(c)] = v;
        }
    }
    return out;
}

Wrap wrap_of(int gl) {
    switch (gl) {
        case TINYGLTF_TEXTURE_WRAP_MIRRORED_REPEAT: return Wrap::mirrored_repeat;
        case TINYGLTF_TEXTURE_WRAP_CLAMP_TO_EDGE: return Wrap::clamp_to_edge;
        default: return Wrap::repeat;
    }
}

std::uint8_t linear_to_srgb_byte(double v) {
    v = std::clamp(v, 0.0, 1.0);
    const double s = v <= 0.0031308 ? 12.92 * v : 1.055 * std::pow(v, 1.0 / 2.4) - 0.055;
    return static_cast<std::uint8_t>(std::lround(s * 255.0));
}

std::string extension_of_mime(const std::string& mime) {
    if (mime == "image/jpeg") return ".jpg";
    if (mime == "image/webp") return ".webp";
    if (mime == "image/ktx2") return ".ktx2";
    return ".png";
}

// The image bytes tinygltf hands over: kept for images inside the scene (buffer views, data
// URIs); an external file is opened from its path by the build instead.
struct EmbeddedImages {
    std::map<int, std::shared_ptr<std::vector<std::uint8_t>>> bytes;
};
bool keep_embedded_image(tinygltf::Image* image, const int index, std::string*, std::string*, int, int, const unsigned char* bytes,
                         int size, void* user) {
    if (!image->uri.empty()) return true;  // an external file (tinygltf keeps the uri only for those)
    static_cast<EmbeddedImages*>(user)->bytes[index] =
        std::make_shared<std::vector<std::uint8_t>>(bytes, bytes + std::max(size, 0));
    return true;
}

// "%20" and friends in a relative URI.
std::string uri_decode(const std::string& s) {
    std::string out;
    for (std::size_t i = 0; i < s.size(); ++i) {
        if (s[i] == '%' && i + 2 < s.size() && std::isxdigit(static_cast<unsigned char>(s[i + 1])) &&
            std::isxdigit(static_cast<unsigned char>(s[i + 2]))) {
            out += static_cast<char>(std::stoi(s.substr(i + 1, 2), nullptr, 16));
            i += 2;
        } else {
            out += s[i];
        }
    }
    return out;
}

// The extensions a .gltf or .glb file says it requires, read before tinygltf parses it (tinygltf
// fails on, say, a Draco-compressed mesh's accessors without naming the extension). Empty when the
// file cannot be read this way: tinygltf then reports what is wrong.
std::vector<std::string> required_extensions(const std::string& path, bool binary) {
    std::ifstream f(path, std::ios::binary);
    std::string text;
    if (binary) {
        std::uint32_t header[5] = {};  // magic, version, length; first chunk: length, type
        if (!f.read(reinterpret_cast<char*>(header), sizeof header) || header[0] != 0x46546C67u || header[4] != 0x4E4F534Au ||
            header[3] > (1u << 28))
            return {};
        text.resize(header[3]);
        if (!f.read(text.data(), static_cast<std::streamsize>(text.size()))) return {};
    } else {
        text.assign(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
    }
    const nlohmann::json j = nlohmann::json::parse(text, nullptr, false);
    std::vector<std::string> out;
    if (j.is_object() && j.contains("extensionsRequired") && j["extensionsRequired"].is_array())
        for (const auto& e : j["extensionsRequired"])
            if (e.is_string()) out.push_back(e.get<std::string>());
    return out;
}

// The base colour texture's sampling: which image, which coordinate set, the transform, the wrap.
struct ColourTexture {
    int image = -1;
    int texcoord = 0;
    double offset[2] = {0, 0}, rotation = 0, scale[2] = {1, 1};
    Wrap wrap[2] = {Wrap::repeat, Wrap::repeat};
};

}  // namespace

Status read_gltf(const std::string& path, UpAxis up, AtlasInputData& data) {
    std::error_code ec;
    const fs::path folder = fs::path(path).parent_path();
    const std::string file_name = fs::path(path).filename().string();

    tinygltf::TinyGLTF loader;
    EmbeddedImages embedded;
    loader.SetImageLoader(keep_embedded_image, &embedded);
    // tinygltf reads whatever a uri names: a folder was read as a file (std::bad_alloc). For it,
    // only regular files exist.
    tinygltf::FsCallbacks regular_files{};
    regular_files.FileExists = [](const std::string& p, void*) {
        std::error_code e;
        return fs::is_regular_file(p, e);
    };
    regular_files.ExpandFilePath = tinygltf::ExpandFilePath;
    regular_files.ReadWholeFile = [](std::vector<unsigned char>* out, std::string* err, const std::string& p, void* user) {
        std::error_code e;
        if (!fs::is_regular_file(p, e)) {
            if (err) *err += "'" + p + "' is not a file\n";
            return false;
        }
        return tinygltf::ReadWholeFile(out, err, p, user);
    };
    regular_files.WriteWholeFile = tinygltf::WriteWholeFile;
    loader.SetFsCallbacks(regular_files);
    tinygltf::Model model;
    std::string err, warn;
    std::string ext = fs::path(path).extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    for (const std::string& e : required_extensions(path, ext == ".glb"))
        if (!kHonouredRequired.count(e))
            return make_error(Errc::unsupported, "glTF '" + path + "' requires the extension " + e +
                                                     ", which tessera build does not read (write the scene without it first, "
                                                     "e.g. with gltf-transform)");
    const bool ok = ext == ".glb" ? loader.LoadBinaryFromFile(&model, &err, &warn, path) : loader.LoadASCIIFromFile(&model, &err, &warn, path);
    if (!ok) return make_error(Errc::corrupt, "cannot read glTF '" + path + "': " + trim_newlines(err.empty() ? warn : err));
    for (const tinygltf::Buffer& b : model.buffers)  // external buffer files: inputs the build must not overwrite
        if (!b.uri.empty() && b.uri.rfind("data:", 0) != 0) {
            fs::path p = uri_decode(b.uri);
            if (p.is_relative()) p = folder / p;
            data.input_files.push_back({p.lexically_normal().string(), "buffer"});
        }
    if (!model.asset.version.empty() && model.asset.version[0] != '2')
        return make_error(Errc::unsupported, "glTF '" + path + "' is version " + model.asset.version + "; only glTF 2.0 is read");
    for (const std::string& e : model.extensionsRequired)
        if (!kHonouredRequired.count(e))
            return make_error(Errc::unsupported, "glTF '" + path + "' requires the extension " + e +
                                                     ", which tessera build does not read (write the scene without it first, "
                                                     "e.g. with gltf-transform)");

    // Materials: their base colour texture (or colour), their other maps, and how they are sampled.
    std::set<std::string> warned;
    auto warn_once = [&](const std::string& w) {
        if (warned.insert(w).second) data.warnings.push_back(w);
    };
    auto material_name = [&](int m) -> std::string {
        if (m < 0 || static_cast<std::size_t>(m) >= model.materials.size()) return "(default material)";
        const std::string& n = model.materials[static_cast<std::size_t>(m)].name;
        return n.empty() ? "material " + std::to_string(m) : n;
    };
    // A material's texture reference (any of tinygltf's TextureInfo kinds): its image, texture
    // coordinate set, sampler wrap modes and KHR_texture_transform; image -1 when there is none.
    auto texture_of = [&](const auto& info, const std::string& name, const std::string& role) -> Result<ColourTexture> {
        ColourTexture t;
        if (info.index < 0) return t;
        if (static_cast<std::size_t>(info.index) >= model.textures.size())
            return make_error(Errc::corrupt, "glTF '" + path + "', material '" + name + "': texture " + std::to_string(info.index) +
                                                 " does not exist");
        const tinygltf::Texture& tex = model.textures[static_cast<std::size_t>(info.index)];
        if (tex.source < 0) {
            std::string by = tex.extensions.empty() ? std::string("no image") : "only the extension " + tex.extensions.begin()->first;
            return make_error(Errc::unsupported, "glTF '" + path + "', material '" + name + "': its " + role + " texture has " + by +
                                                     ", which tessera build does not read");
        }
        if (static_cast<std::size_t>(tex.source) >= model.images.size())
            return make_error(Errc::corrupt, "glTF '" + path + "', material '" + name + "': image " + std::to_string(tex.source) +
                                                 " does not exist");
        t.image = tex.source;
        t.texcoord = info.texCoord;
        if (tex.sampler >= 0 && static_cast<std::size_t>(tex.sampler) >= model.samplers.size())
            return make_error(Errc::corrupt, "glTF '" + path + "', material '" + name + "': sampler " + std::to_string(tex.sampler) +
                                                 " does not exist");
        if (tex.sampler >= 0) {
            t.wrap[0] = wrap_of(model.samplers[static_cast<std::size_t>(tex.sampler)].wrapS);
            t.wrap[1] = wrap_of(model.samplers[static_cast<std::size_t>(tex.sampler)].wrapT);
        }
        if (auto x = info.extensions.find("KHR_texture_transform"); x != info.extensions.end()) {
            const tinygltf::Value& v = x->second;
            if (v.Has("offset") && v.Get("offset").ArrayLen() == 2)
                for (int k = 0; k < 2; ++k) t.offset[k] = v.Get("offset").Get(k).GetNumberAsDouble();
            if (v.Has("scale") && v.Get("scale").ArrayLen() == 2)
                for (int k = 0; k < 2; ++k) t.scale[k] = v.Get("scale").Get(k).GetNumberAsDouble();
            if (v.Has("rotation")) t.rotation = v.Get("rotation").GetNumberAsDouble();
            if (v.Has("texCoord")) t.texcoord = v.Get("texCoord").GetNumberAsInt();
        }
        return t;
    };
    // A glTF image as the atlas names it: its file, or its bytes when it is inside the scene.
    auto map_ref_of = [&](int gltf_image) {
        AtlasMapRef ref;
        const tinygltf::Image& img = model.images[static_cast<std::size_t>(gltf_image)];
        if (auto e = embedded.bytes.find(gltf_image); e != embedded.bytes.end()) {
            ref.texture = file_name + " image " + std::to_string(gltf_image) + (img.name.empty() ? "" : " '" + img.name + "'");
            ref.embedded = e->second;
            ref.embedded_extension = extension_of_mime(img.mimeType);
        } else {
            fs::path p = uri_decode(img.uri);
            if (p.is_relative()) p = folder / p;
            ref.texture = p.lexically_normal().string();
        }
        return ref;
    };
    auto same_coordinates = [](const ColourTexture& a, const ColourTexture& b) {
        return a.texcoord == b.texcoord && a.offset[0] == b.offset[0] && a.offset[1] == b.offset[1] && a.scale[0] == b.scale[0] &&
               a.scale[1] == b.scale[1] && a.rotation == b.rotation;
    };
    auto byte_of = [](double v) { return static_cast<std::uint8_t>(std::lround(std::clamp(v, 0.0, 1.0) * 255.0)); };

    struct MaterialImage {
        std::uint32_t image = 0;
        ColourTexture texture;  // the texture whose coordinates the cell follows
        bool textured = false;
        bool blend = false;  // alphaMode BLEND: its triangles are drawn blended (Triangle::blend)
    };
    // One cell per distinct (colour texture or colour, maps, values where maps are missing).
    // Wrapping matters too: a cell whose texture repeats has padding that wraps around, which a
    // clamped or mirrored material of the same image must not sample at its edges.
    using CellKey = std::tuple<int, std::array<std::uint8_t, 3>, std::array<int, kMapRoles>,
                               std::array<std::array<std::uint8_t, 3>, kMapRoles>, bool>;
    std::map<CellKey, std::uint32_t> cells;
    std::map<int, MaterialImage> material_images;
    // Material extensions the atlas does not keep (clear coat, sheen, specular-glossiness ...):
    // the first material that has each, and how many do.
    std::map<std::string, std::pair<std::string, std::size_t>> unkept_extensions;
    auto material_image = [&](int m) -> Result<MaterialImage> {
        if (auto it = material_images.find(m); it != material_images.end()) return it->second;
        MaterialImage mi;
        AtlasImageRef cell;  // what this material's cell holds
        std::array<int, kMapRoles> map_images;
        map_images.fill(-1);
        std::vector<double> factor = {1, 1, 1, 1};
        const std::string name = material_name(m);
        bool opaque = true;
        if (m >= 0 && static_cast<std::size_t>(m) < model.materials.size()) {
            const tinygltf::Material& mat = model.materials[static_cast<std::size_t>(m)];
            const tinygltf::PbrMetallicRoughness& pbr = mat.pbrMetallicRoughness;
            for (const auto& extension : mat.extensions)
                if (extension.first != "KHR_materials_emissive_strength" && extension.first != "KHR_materials_unlit") {
                    auto& [first, count] = unkept_extensions[extension.first];
                    if (count++ == 0) first = name;
                }
            factor = pbr.baseColorFactor;
            auto base = texture_of(pbr.baseColorTexture, name, "base colour");
            if (!base) return base.error();
            std::array<ColourTexture, kMapRoles> maps;
            {
                auto normal = texture_of(mat.normalTexture, name, "normal");
                if (!normal) return normal.error();
                auto mr = texture_of(pbr.metallicRoughnessTexture, name, "metallic-roughness");
                if (!mr) return mr.error();
                auto occlusion = texture_of(mat.occlusionTexture, name, "occlusion");
                if (!occlusion) return occlusion.error();
                auto emissive = texture_of(mat.emissiveTexture, name, "emissive");
                if (!emissive) return emissive.error();
                maps = {*normal, *mr, *occlusion, *emissive};
            }
            // The cell follows the colour texture's coordinates, or without one the first map's; a
            // map that reads other coordinates cannot share the cell and is left out.
            if (base->image >= 0) {
                mi.textured = true;
                mi.texture = *base;
            } else {
                for (const ColourTexture& t : maps)
                    if (t.image >= 0) {
                        mi.textured = true;
                        mi.texture = t;
                        break;
                    }
            }
            for (std::size_t r = 0; r < kMapRoles; ++r) {
                if (maps[r].image < 0) continue;
                if (!same_coordinates(maps[r], mi.texture)) {
                    warn_once("material '" + name + "': its " + std::string(kMapLayerNames[r]) +
                              " map reads other texture coordinates than its base colour and is not packed");
                    continue;
                }
                map_images[r] = maps[r].image;
                cell.maps[r] = map_ref_of(maps[r].image);
            }
            // Values where a map is missing; factors a map would be multiplied by are not applied.
            const double metallic = pbr.metallicFactor, roughness = pbr.roughnessFactor;
            cell.map_values[1] = {0, byte_of(roughness), byte_of(metallic)};
            if (map_images[1] >= 0 && (metallic != 1 || roughness != 1))
                warn_once("material '" + name + "': its metallicFactor and roughnessFactor are not applied to its metallic-roughness map");
            if (map_images[2] >= 0 && mat.occlusionTexture.strength != 1)
                warn_once("material '" + name + "': its occlusion strength is not applied to its occlusion map");
            if (map_images[0] >= 0 && mat.normalTexture.scale != 1)
                warn_once("material '" + name + "': its normal scale is not applied to its normal map");
            double strength = 1;
            if (auto x = mat.extensions.find("KHR_materials_emissive_strength"); x != mat.extensions.end() && x->second.Has("emissiveStrength"))
                strength = x->second.Get("emissiveStrength").GetNumberAsDouble();
            std::array<double, 3> emissive = {0, 0, 0};
            for (std::size_t k = 0; k < 3 && k < mat.emissiveFactor.size(); ++k) emissive[k] = mat.emissiveFactor[k] * strength;
            if (map_images[3] >= 0) {
                if (emissive[0] != 1 || emissive[1] != 1 || emissive[2] != 1)
                    warn_once("material '" + name + "': its emissiveFactor is not applied to its emissive map");
                cell.map_values[3] = {0, 0, 0};
            } else {
                cell.map_values[3] = {linear_to_srgb_byte(emissive[0]), linear_to_srgb_byte(emissive[1]), linear_to_srgb_byte(emissive[2])};
            }
            // Alpha: an image only OPAQUE materials draw loses it (glTF ignores it there);
            // MASK keeps it, drawn as cut-outs at one half, and BLEND, drawn blended over what
            // lies behind (docs/atlas.md, "Alpha").
            opaque = mat.alphaMode.empty() || mat.alphaMode == "OPAQUE";
            mi.blend = mat.alphaMode == "BLEND";
            if (base->image >= 0) {
                if (mat.alphaMode == "MASK" && std::abs(mat.alphaCutoff - 0.5) > 1e-6)
                    warn_once("material '" + name + "': alphaCutoff " + std::to_string(mat.alphaCutoff) + " is drawn as 0.5");
                if (factor.size() == 4 && (factor[0] != 1 || factor[1] != 1 || factor[2] != 1))
                    warn_once("material '" + name + "': its baseColorFactor is not applied to its texture (the atlas keeps the texture's colours)");
            }
        }
        // A colour texture, or the material's colour (also behind maps without a colour texture).
        const bool has_colour_texture = m >= 0 && static_cast<std::size_t>(m) < model.materials.size() &&
                                        model.materials[static_cast<std::size_t>(m)].pbrMetallicRoughness.baseColorTexture.index >= 0;
        const int colour_image = has_colour_texture ? mi.texture.image : -1;
        if (colour_image < 0)
            cell.colour = {factor.size() >= 3 ? linear_to_srgb_byte(factor[0]) : std::uint8_t(255),
                           factor.size() >= 3 ? linear_to_srgb_byte(factor[1]) : std::uint8_t(255),
                           factor.size() >= 3 ? linear_to_srgb_byte(factor[2]) : std::uint8_t(255)};
        const bool may_repeat = mi.textured && (mi.texture.wrap[0] == Wrap::repeat || mi.texture.wrap[1] == Wrap::repeat);
        const CellKey key{colour_image, colour_image < 0 ? cell.colour : std::array<std::uint8_t, 3>{}, map_images, cell.map_values,
                          may_repeat};
        auto [it, inserted] = cells.emplace(key, static_cast<std::uint32_t>(data.images.size()));
        if (inserted) {
            if (colour_image >= 0) static_cast<AtlasMapRef&>(cell) = map_ref_of(colour_image);
            cell.opaque = opaque;
            data.images.push_back(std::move(cell));
        } else if (!opaque) {
            data.images[it->second].opaque = false;
        }
        mi.image = it->second;
        data.images[mi.image].materials.push_back(name);
        material_images.emplace(m, mi);
        return mi;
    };

    // One primitive of a mesh under `world`: its vertices transformed, its triangles added.
    std::size_t skipped_primitives = 0, coloured_primitives = 0, morphed_primitives = 0;
    auto add_primitive = [&](const tinygltf::Primitive& prim, const Mat4& world, const std::string& shape_name, Shape& shape) -> Status {
        const std::string what = "glTF '" + path + "', " + shape_name;
        const int mode = prim.mode < 0 ? TINYGLTF_MODE_TRIANGLES : prim.mode;
        if (mode != TINYGLTF_MODE_TRIANGLES && mode != TINYGLTF_MODE_TRIANGLE_STRIP && mode != TINYGLTF_MODE_TRIANGLE_FAN) {
            ++skipped_primitives;
            return {};
        }
        if (prim.attributes.count("COLOR_0")) ++coloured_primitives;
        if (!prim.targets.empty()) ++morphed_primitives;
        auto pos_it = prim.attributes.find("POSITION");
        if (pos_it == prim.attributes.end()) return make_error(Errc::corrupt, what + ": a primitive has no POSITION");
        auto positions = read_accessor(model, pos_it->second, 3, what + " POSITION");
        if (!positions) return positions.error();
        std::vector<double> normals;
        if (auto n = prim.attributes.find("NORMAL"); n != prim.attributes.end()) {
            auto r = read_accessor(model, n->second, 3, what + " NORMAL");
            if (!r) return r.error();
            normals = std::move(*r);
        }
        const std::size_t count = positions->size() / 3;
        if (!normals.empty() && normals.size() != positions->size())
            return make_error(Errc::corrupt, what + ": NORMAL and POSITION have different counts");
        auto mi = material_image(prim.material);
        if (!mi) return mi.error();
        const std::size_t first_triangle = shape.triangles.size();
        std::vector<double> uvs;
        if (mi->textured) {
            const std::string attr = "TEXCOORD_" + std::to_string(mi->texture.texcoord);
            auto t = prim.attributes.find(attr);
            if (t == prim.attributes.end())
                return make_error(Errc::corrupt, what + ", material '" + material_name(prim.material) + "': the texture reads " + attr +
                                                     ", which the primitive does not have");
            auto r = read_accessor(model, t->second, 2, what + " " + attr);
            if (!r) return r.error();
            if (r->size() / 2 != count) return make_error(Errc::corrupt, what + ": " + attr + " and POSITION have different counts");
            uvs = std::move(*r);
        }
        std::vector<std::uint32_t> indices;
        if (prim.indices >= 0) {
            auto r = read_accessor(model, prim.indices, 1, what + " indices");
            if (!r) return r.error();
            indices.reserve(r->size());
            for (double i : *r) {
                if (!(i >= 0 && i < double(count)))
                    return make_error(Errc::corrupt, what + ": an index (" + std::to_string(static_cast<long long>(i)) + ") is out of range (" +
                                                         std::to_string(count) + " vertices)");
                indices.push_back(static_cast<std::uint32_t>(i));
            }
        } else {
            indices.resize(count);
            for (std::size_t i = 0; i < count; ++i) indices[i] = static_cast<std::uint32_t>(i);
        }
        // Vertices into the scene: positions by the node's world transform, normals by its normal matrix.
        const int base_v = static_cast<int>(data.positions.size() / 3), base_n = static_cast<int>(data.normals.size() / 3);
        const auto nm = normal_matrix(world);
        for (std::size_t i = 0; i < count; ++i) {
            const double* p = &(*positions)[3 * i];
            for (int row = 0; row < 3; ++row) {
                const auto r = static_cast<std::size_t>(row);
                const float x = static_cast<float>(world[r] * p[0] + world[4 + r] * p[1] + world[8 + r] * p[2] + world[12 + r]);
                if (!std::isfinite(x))  // infinities and NaN, in the file or made by the node's transform
                    return make_error(Errc::corrupt, what + ": vertex " + std::to_string(i) + "'s position is not a finite number" +
                                                         (std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2])
                                                              ? " once its node's transform is applied"
                                                              : ""));
                data.positions.push_back(x);
            }
            if (!normals.empty()) {
                const double* n = &normals[3 * i];
                double o[3];
                for (std::size_t row = 0; row < 3; ++row) o[row] = nm[row * 3] * n[0] + nm[row * 3 + 1] * n[1] + nm[row * 3 + 2] * n[2];
                double len = std::sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2]);
                if (!(len > 0)) len = 1;
                for (double x : o) data.normals.push_back(static_cast<float>(x / len));
            }
        }
        // A double-sided material's triangles are drawn from behind too: each gets a back copy,
        // wound the other way, with the normals turned around (the renderer culls back faces).
        const bool double_sided = prim.material >= 0 && static_cast<std::size_t>(prim.material) < model.materials.size() &&
                                  model.materials[static_cast<std::size_t>(prim.material)].doubleSided;
        if (double_sided && !normals.empty()) {
            const std::size_t front = data.normals.size() - 3 * count;
            for (std::size_t i = 0; i < 3 * count; ++i) data.normals.push_back(-data.normals[front + i]);
        }
        const bool mirrored = determinant3(world) < 0;  // a mirroring transform turns the winding around
        const ColourTexture& tex = mi->texture;
        const double cr = std::cos(tex.rotation), sr = std::sin(tex.rotation);
        auto add_side = [&](std::uint32_t a, std::uint32_t b, std::uint32_t c, bool back) -> Status {
            if (a == b || b == c || a == c) return {};
            std::uint32_t corner[3] = {a, b, c};
            if (mirrored != back) std::swap(corner[1], corner[2]);
            const int normal_base = base_n + (back ? static_cast<int>(count) : 0);
            int v[3], vn[3];
            for (int k = 0; k < 3; ++k) {
                v[k] = base_v + static_cast<int>(corner[k]);
                vn[k] = normals.empty() ? -1 : normal_base + static_cast<int>(corner[k]);
            }
            if (!mi->textured) {
                Triangle tri;
                tri.image = mi->image;
                for (int k = 0; k < 3; ++k) tri.c[k].v = v[k], tri.c[k].n = vn[k];
                shape.triangles.push_back(tri);
                return {};
            }
            double uv[3][2];
            for (int k = 0; k < 3; ++k) {
                const double u = uvs[2 * corner[k]], w = uvs[2 * corner[k] + 1];
                // KHR_texture_transform: translation * rotation * scale, then glTF's v (down) to
                // the atlas input's v up.
                const double su = u * tex.scale[0], sw = w * tex.scale[1];
                const double tu = cr * su + sr * sw + tex.offset[0];
                const double tw = -sr * su + cr * sw + tex.offset[1];
                uv[k][0] = tu;
                uv[k][1] = 1.0 - tw;
            }
            return add_textured_triangle(data, shape, mi->image, v, vn, uv, tex.wrap,
                                         "material '" + material_name(prim.material) + "' (" + shape_name + ")");
        };
        auto add = [&](std::uint32_t a, std::uint32_t b, std::uint32_t c) -> Status {
            TESSERA_TRY(add_side(a, b, c, false));
            return double_sided ? add_side(a, b, c, true) : Status{};
        };
        if (mode == TINYGLTF_MODE_TRIANGLES) {
            for (std::size_t i = 0; i + 2 < indices.size(); i += 3) TESSERA_TRY(add(indices[i], indices[i + 1], indices[i + 2]));
        } else if (mode == TINYGLTF_MODE_TRIANGLE_STRIP) {
            for (std::size_t i = 0; i + 2 < indices.size(); ++i)
                TESSERA_TRY(i % 2 == 0 ? add(indices[i], indices[i + 1], indices[i + 2]) : add(indices[i + 1], indices[i], indices[i + 2]));
        } else {
            for (std::size_t i = 1; i + 1 < indices.size(); ++i) TESSERA_TRY(add(indices[0], indices[i], indices[i + 1]));
        }
        if (mi->blend)
            for (std::size_t i = first_triangle; i < shape.triangles.size(); ++i) shape.triangles[i].blend = true;
        return {};
    };

    // The node tree, depth first; a node met again on its own path is a cycle (invalid glTF).
    std::vector<int> roots;
    if (!model.scenes.empty()) {
        const int s = model.defaultScene >= 0 && static_cast<std::size_t>(model.defaultScene) < model.scenes.size() ? model.defaultScene : 0;
        roots = model.scenes[static_cast<std::size_t>(s)].nodes;
    } else {  // no scene: every node that is nobody's child
        std::vector<bool> child(model.nodes.size(), false);
        for (const auto& n : model.nodes)
            for (int c : n.children)
                if (c >= 0 && static_cast<std::size_t>(c) < child.size()) child[static_cast<std::size_t>(c)] = true;
        for (std::size_t i = 0; i < model.nodes.size(); ++i)
            if (!child[i]) roots.push_back(static_cast<int>(i));
    }
    std::vector<bool> on_path(model.nodes.size(), false);
    std::function<Status(int, const Mat4&)> visit = [&](int index, const Mat4& parent) -> Status {
        if (index < 0 || static_cast<std::size_t>(index) >= model.nodes.size())
            return make_error(Errc::corrupt, "glTF '" + path + "': node " + std::to_string(index) + " does not exist");
        if (on_path[static_cast<std::size_t>(index)])
            return make_error(Errc::corrupt, "glTF '" + path + "': node " + std::to_string(index) + " is its own ancestor");
        on_path[static_cast<std::size_t>(index)] = true;
        const tinygltf::Node& node = model.nodes[static_cast<std::size_t>(index)];
        const Mat4 world = multiply(parent, local_transform(node));
        if (node.mesh >= 0) {
            if (static_cast<std::size_t>(node.mesh) >= model.meshes.size())
                return make_error(Errc::corrupt, "glTF '" + path + "': mesh " + std::to_string(node.mesh) + " does not exist");
            const tinygltf::Mesh& mesh = model.meshes[static_cast<std::size_t>(node.mesh)];
            Shape shape;
            shape.name = !node.name.empty() ? node.name : !mesh.name.empty() ? mesh.name : "node" + std::to_string(index);
            std::replace(shape.name.begin(), shape.name.end(), ' ', '_');
            for (std::size_t p = 0; p < mesh.primitives.size(); ++p)
                TESSERA_TRY(add_primitive(mesh.primitives[p], world, "mesh '" + (mesh.name.empty() ? std::to_string(node.mesh) : mesh.name) + "'", shape));
            data.triangles += shape.triangles.size();
            if (!shape.triangles.empty()) data.shapes.push_back(std::move(shape));
        }
        for (int child : node.children) TESSERA_TRY(visit(child, world));
        on_path[static_cast<std::size_t>(index)] = false;
        return {};
    };
    for (int r : roots) TESSERA_TRY(visit(r, kIdentity));
    if (skipped_primitives)
        data.warnings.push_back(std::to_string(skipped_primitives) + " primitives of points or lines are left out (the atlas scene holds triangles)");
    for (const auto& [extension, seen] : unkept_extensions)
        data.warnings.push_back("material '" + seen.first + "'" +
                                (seen.second > 1 ? " and " + std::to_string(seen.second - 1) + " more" : std::string()) + ": " + extension +
                                " is not kept (the atlas keeps the base colour and the core maps)");
    if (coloured_primitives)
        data.warnings.push_back(std::to_string(coloured_primitives) + " primitives' vertex colours (COLOR_0) are not kept");
    if (morphed_primitives || !model.skins.empty() || !model.animations.empty())
        data.warnings.push_back("skins, morph targets and animations are not applied: the scene is built in its rest pose");

    // Every external texture (and map) must exist (tinygltf only warns).
    for (const AtlasImageRef& ref : data.images) {
        std::vector<const AtlasMapRef*> files = {&ref};
        for (const AtlasMapRef& m : ref.maps) files.push_back(&m);
        for (const AtlasMapRef* f : files)
            if (!f->texture.empty() && !f->embedded && !fs::is_regular_file(f->texture, ec)) {
                std::string mats;
                for (const auto& m : ref.materials) mats += (mats.empty() ? "'" : ", '") + m + "'";
                const bool exists = fs::exists(f->texture, ec);
                return make_error(exists ? Errc::invalid_argument : Errc::not_found,
                                  "glTF '" + path + "', material " + mats + ": texture '" + f->texture + "' " +
                                      (exists ? "is not an image file (an image's uri names a folder or is empty)" : "does not exist"));
            }
    }
    // glTF is Y up: `automatic` is y, not guessed from the shape as for OBJ.
    return finish_atlas_input(data, up == UpAxis::automatic ? UpAxis::y : up, "glTF '" + path + "'");
}

}  // namespace tessera::scene::detail
