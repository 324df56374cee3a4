// `tessera build --atlas` on glTF 2.0 scenes (docs/atlas.md, "glTF scenes"): Khronos's sample
// scenes as Debian's assimp-testmodels ships them (external, binary and embedded forms of one
// scene must give the same atlas), every point of a quad mapped to the texel glTF's sampling rules
// give (KHR_texture_transform, MIRRORED_REPEAT, CLAMP_TO_EDGE, computed here from the
// specification, not by the build's code), scenes the build cannot read failing cleanly, and the
// scene travelling with its store to `tessera view` (a file, and over gRPC from a server).
#include <gtest/gtest.h>
#include <tiny_obj_loader.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <optional>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "atlas_test_util.hpp"
#include "server_process.hpp"
#include "tessera/scene/scene.hpp"
#include "tessera/storage/png_encode.hpp"
#include "tessera/storage/store_reader.hpp"
#include "test_util.hpp"

namespace {

namespace fs = std::filesystem;
namespace storage = tessera::storage;
using tessera::Codec;
using tessera::test::AtlasTexels;
using tessera::test::entries;
using tessera::test::expect_one_line_error;
using tessera::test::q;
using tessera::test::read_file;
using tessera::test::run_tessera;
using tessera::test::RunResult;
using tessera::test::ScratchDir;
using tessera::test::ServerProcess;
using tessera::test::write_file;

// Khronos's glTF 2.0 samples in Debian's assimp-testmodels (tools/setup.sh --tests installs it).
const fs::path kSamples = "/usr/share/assimp/models/glTF2";

std::string base64(const std::vector<std::uint8_t>& in) {
    static const char* abc = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    std::string out;
    for (std::size_t i = 0; i < in.size(); i += 3) {
        const std::uint32_t n = (std::uint32_t(in[i]) << 16) | (i + 1 < in.size() ? std::uint32_t(in[i + 1]) << 8 : 0) |
                                (i + 2 < in.size() ? in[i + 2] : 0);
        out += abc[(n >> 18) & 63];
        out += abc[(n >> 12) & 63];
        out += i + 1 < in.size() ? abc[(n >> 6) & 63] : '=';
        out += i + 2 < in.size() ? abc[n & 63] : '=';
    }
    return out;
}

// The rewritten OBJ's triangles as sorted (position, atlas coordinate) corner triples, each
// starting at its smallest corner: equal for scenes that differ only in vertex order.
std::vector<std::array<std::array<float, 5>, 3>> triangle_set(const std::string& path) {
    tinyobj::ObjReader obj;
    tinyobj::ObjReaderConfig config;
    config.triangulate = true;
    EXPECT_TRUE(obj.ParseFromFile(path, config)) << obj.Error();
    const auto& at = obj.GetAttrib();
    std::vector<std::array<std::array<float, 5>, 3>> out;
    for (const auto& sh : obj.GetShapes())
        for (std::size_t f = 0; f + 2 < sh.mesh.indices.size(); f += 3) {
            std::array<std::array<float, 5>, 3> t;
            for (std::size_t k = 0; k < 3; ++k) {
                const auto& ix = sh.mesh.indices[f + k];
                for (std::size_t d = 0; d < 3; ++d) t[k][d] = at.vertices[3 * std::size_t(ix.vertex_index) + d];
                for (std::size_t d = 0; d < 2; ++d) t[k][3 + d] = at.texcoords[2 * std::size_t(ix.texcoord_index) + d];
            }
            std::rotate(t.begin(), std::min_element(t.begin(), t.end()), t.end());
            out.push_back(t);
        }
    std::sort(out.begin(), out.end());
    return out;
}

// The rewritten OBJ of a scene lying in the plane z = 0 (x, y as the glTF wrote them), and the
// atlas texel each point of it samples: the piece holding the point, its atlas coordinate there by
// barycentric interpolation, the store's level-0 texel under it.
class PlanarAtlasLookup {
public:
    PlanarAtlasLookup(const std::string& obj_path, AtlasTexels& atlas) : atlas_(atlas) {
        tinyobj::ObjReader obj;
        tinyobj::ObjReaderConfig config;
        config.triangulate = true;
        EXPECT_TRUE(obj.ParseFromFile(obj_path, config)) << obj.Error();
        const auto& attrib = obj.GetAttrib();
        for (const auto& sh : obj.GetShapes())
            for (std::size_t f = 0; f + 2 < sh.mesh.indices.size(); f += 3) {
                Piece pc;
                for (std::size_t k = 0; k < 3; ++k) {
                    const auto& ix = sh.mesh.indices[f + k];
                    for (std::size_t a = 0; a < 2; ++a) {
                        pc.p[k][a] = attrib.vertices[3 * std::size_t(ix.vertex_index) + a];
                        pc.t[k][a] = attrib.texcoords[2 * std::size_t(ix.texcoord_index) + a];
                    }
                }
                pieces_.push_back(pc);
            }
    }
    std::size_t pieces() const { return pieces_.size(); }
    // nullopt on a cut between pieces (or off the scene).
    std::optional<std::array<std::uint8_t, 3>> at(double x, double y) {
        for (const Piece& pc : pieces_) {
            const double d = (pc.p[1][1] - pc.p[2][1]) * (pc.p[0][0] - pc.p[2][0]) + (pc.p[2][0] - pc.p[1][0]) * (pc.p[0][1] - pc.p[2][1]);
            if (std::abs(d) < 1e-12) continue;
            const double a = ((pc.p[1][1] - pc.p[2][1]) * (x - pc.p[2][0]) + (pc.p[2][0] - pc.p[1][0]) * (y - pc.p[2][1])) / d;
            const double b = ((pc.p[2][1] - pc.p[0][1]) * (x - pc.p[2][0]) + (pc.p[0][0] - pc.p[2][0]) * (y - pc.p[2][1])) / d;
            const double c = 1 - a - b;
            if (a < 1e-6 || b < 1e-6 || c < 1e-6) continue;  // strictly inside one piece
            const double au = a * pc.t[0][0] + b * pc.t[1][0] + c * pc.t[2][0];
            const double av = a * pc.t[0][1] + b * pc.t[1][1] + c * pc.t[2][1];
            return atlas_.at(std::uint32_t(std::floor(au * atlas_.info().width)), std::uint32_t(std::floor(av * atlas_.info().height)));
        }
        return std::nullopt;
    }

private:
    struct Piece {
        double p[3][2], t[3][2];
    };
    AtlasTexels& atlas_;
    std::vector<Piece> pieces_;
};

// The buffer of the tests' quads as glTF "buffers" and "bufferViews": positions (VEC3 floats),
// texture coordinates (VEC2 floats) and 16-bit indices one after the other in one data URI, the
// indices split into `index_views` equal views (one per primitive). Views 0 and 1 are the
// positions and coordinates, 2.. the indices.
template <std::size_t V, std::size_t I>
nlohmann::json quad_buffers(const float (&pos)[V][3], const float (&uv)[V][2], const std::uint16_t (&idx)[I], std::size_t index_views = 1) {
    std::vector<std::uint8_t> buffer(sizeof pos + sizeof uv + sizeof idx);
    std::memcpy(buffer.data(), pos, sizeof pos);
    std::memcpy(buffer.data() + sizeof pos, uv, sizeof uv);
    std::memcpy(buffer.data() + sizeof pos + sizeof uv, idx, sizeof idx);
    nlohmann::json views = {{{"buffer", 0}, {"byteOffset", 0}, {"byteLength", sizeof pos}},
                            {{"buffer", 0}, {"byteOffset", sizeof pos}, {"byteLength", sizeof uv}}};
    const std::size_t part = sizeof idx / index_views;
    for (std::size_t k = 0; k < index_views; ++k)
        views.push_back({{"buffer", 0}, {"byteOffset", sizeof pos + sizeof uv + k * part}, {"byteLength", part}});
    return {{"buffers", {{{"byteLength", buffer.size()}, {"uri", "data:application/octet-stream;base64," + base64(buffer)}}}},
            {"bufferViews", views}};
}

// The viewer's PSNR summary line in `out` says at least `db` (min over the compared frames), or
// that every compared frame was identical to the reference ("lossless").
::testing::AssertionResult psnr_at_least(const std::string& out, double db) {
    const auto at = out.find("\nPSNR ");
    if (at == std::string::npos) return ::testing::AssertionFailure() << "no PSNR line in\n" << out;
    const std::string line = out.substr(at + 1, out.find('\n', at + 1) - at - 1);
    if (line.find("lossless") != std::string::npos) return ::testing::AssertionSuccess();
    const auto m = line.find("min ");
    if (m == std::string::npos) return ::testing::AssertionFailure() << "no minimum in: " << line;
    if (std::stod(line.substr(m + 4)) < db) return ::testing::AssertionFailure() << "under " << db << " dB: " << line;
    return ::testing::AssertionSuccess();
}

// An 8x8 PNG of one colour (RGB, or RGBA with `alpha`), as a data URI.
std::string solid_png_uri(std::array<std::uint8_t, 3> c, std::optional<std::uint8_t> alpha = std::nullopt) {
    const std::uint32_t W = 8, H = 8, channels = alpha ? 4 : 3;
    std::vector<std::uint8_t> px(std::size_t(W) * H * channels);
    for (std::size_t i = 0; i < px.size(); i += channels) {
        std::copy(c.begin(), c.end(), px.begin() + std::ptrdiff_t(i));
        if (alpha) px[i + 3] = *alpha;
    }
    auto png = storage::encode_png({W, H, channels, storage::SampleType::u8, storage::ColourSpace::srgb, px});
    EXPECT_TRUE(png.ok());
    return png.ok() ? "data:image/png;base64," + base64(*png) : std::string();
}

// The camera of the still views below: 3 units from the origin, looking at it along +y, 60
// degrees down (the library is Z up), so the centre pixel of an odd-sized frame sees the origin.
constexpr double kStillPitch = 60.0 * 3.14159265358979323846 / 180.0;
const std::array<double, 3> kStillEye{0, -3 * std::cos(kStillPitch), 3 * std::sin(kStillPitch)};

// sRGB-encoded byte of linear x (clamped), and the linear value of an sRGB byte.
double encode_srgb(double x) {
    x = std::clamp(x, 0.0, 1.0);
    return 255.0 * (x <= 0.0031308 ? x * 12.92 : 1.055 * std::pow(x, 1 / 2.4) - 0.055);
}
double linear_of(std::uint8_t c) {
    const double x = c / 255.0;
    return x <= 0.04045 ? x / 12.92 : std::pow((x + 0.055) / 1.055, 2.4);
}

class GltfAtlas : public ::testing::Test {
protected:
    void SetUp() override {
        ASSERT_TRUE(fs::is_directory(kSamples)) << kSamples << " is missing: tools/setup.sh --tests installs assimp-testmodels";
        fs::create_directory(dir_.file("out"));
    }
    // Builds `scene` into out/NAME.tsr and out/NAME.obj.
    RunResult build(const std::string& scene, const std::string& name, const std::string& extra = "") {
        return run_tessera("build -q --codec zstd " + extra + " --atlas " + q(scene) + " -o " + q(dir_.file("out/" + name + ".tsr")) +
                           " --obj-out " + q(dir_.file("out/" + name + ".obj")));
    }
    // Writes `scene` (glTF JSON) as NAME.gltf, then builds it as build() does.
    RunResult build_json(const nlohmann::json& scene, const std::string& name) {
        const std::string file = dir_.file(name + ".gltf");
        const std::string text = scene.dump();
        write_file(file, std::vector<std::uint8_t>(text.begin(), text.end()));
        return build(file, name);
    }
    // Views out/NAME.tsr headless at 65x65 from the still camera (kStillEye), 40 frames, and
    // writes frame 20 to frames/ (past the first view and its fades).
    RunResult still_view(const std::string& name, const std::string& extra = "") {
        char path[256];
        std::snprintf(path, sizeof path, "fov 40\n0 0 %.17g %.17g 90 -60\n1 0 %.17g %.17g 90 -60\n", kStillEye[1], kStillEye[2],
                      kStillEye[1], kStillEye[2]);
        write_file(dir_.file("still.path"), std::vector<std::uint8_t>(path, path + std::strlen(path)));
        return run_tessera("view --store " + q(dir_.file("out/" + name + ".tsr")) + " --headless --size 65x65 --frames 40 --path " +
                           q(dir_.file("still.path")) + " --out " + q(dir_.file("frames")) + " --png-count 1 " + extra);
    }
    ScratchDir dir_;
};

// Khronos's BoxTextured as a .glb and as a .gltf with its buffer and image in data URIs (the same
// scene); the external-file version's sampler mirrors and clamps, so it only has to build.
TEST_F(GltfAtlas, OneSceneBinaryOrEmbeddedGivesOneAtlas) {
    const std::string forms[3] = {(kSamples / "BoxTextured-glTF/BoxTextured.gltf").string(),
                                  (kSamples / "BoxTextured-glTF-Binary/BoxTextured.glb").string(),
                                  (kSamples / "BoxTextured-glTF-Embedded/BoxTextured.gltf").string()};
    for (int i = 0; i < 3; ++i) {
        const RunResult r = build(forms[i], "box" + std::to_string(i));
        ASSERT_EQ(r.exit_code, 0) << forms[i] << "\n" << r.out;
    }
    // Nothing but the stores and OBJs (the embedded images' temporary folder is gone).
    EXPECT_EQ(entries(dir_.file("out")),
              (std::set<std::string>{"box0.tsr", "box0.obj", "box1.tsr", "box1.obj", "box2.tsr", "box2.obj"}));
    const auto triangles1 = triangle_set(dir_.file("out/box1.obj"));
    EXPECT_EQ(triangles1.size(), 12u);
    EXPECT_EQ(triangle_set(dir_.file("out/box2.obj")), triangles1);
    std::vector<std::unique_ptr<AtlasTexels>> atlases;
    for (int i = 0; i < 3; ++i) {
        auto reader = storage::StoreReader::open(dir_.file("out/box" + std::to_string(i) + ".tsr"));
        ASSERT_TRUE(reader.ok()) << reader.error().message;
        atlases.push_back(std::make_unique<AtlasTexels>(*reader));
    }
    const auto& info = atlases[0]->info();
    ASSERT_EQ(atlases[1]->info().width, info.width);
    ASSERT_EQ(atlases[2]->info().height, info.height);
    for (std::uint32_t y = 0; y < info.height; y += 7)
        for (std::uint32_t x = 0; x < info.width; x += 5) {
            ASSERT_EQ(atlases[2]->at(x, y), atlases[1]->at(x, y)) << x << "," << y;
        }
    // The scene loads as the atlas scene: a unit cube, 12 triangles, glTF's Y up made Z up.
    auto scene = tessera::scene::load_obj_scene(dir_.file("out/box0.obj"), info.width, info.height);
    ASSERT_TRUE(scene.ok()) << scene.error().message;
    std::size_t triangles = 0;
    for (const auto& c : scene->chunks) triangles += c.indices.size() / 3;
    EXPECT_EQ(triangles, 12u);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(scene->bounds_max[k] - scene->bounds_min[k], 1.0, 1e-5) << k;
}

TEST_F(GltfAtlas, KhronosSamplesBuildAndLoad) {
    // A texture transform test card, a scene of many nodes and colour-only materials, a scene with
    // normal, metallic-roughness and emissive maps (packed into layers; its clear-coat maps and
    // BLEND are not kept: the build says so), two coordinate sets (the map on the second is not
    // packed: the build says so).
    struct Case {
        std::string file;
        std::size_t min_triangles;
        bool warns;
    };
    const Case cases[] = {{"textureTransform/TextureTransformTest.gltf", 18, false},
                          {"2CylinderEngine-glTF-Binary/2CylinderEngine.glb", 100000, false},
                          {"ClearCoat-glTF/ClearCoatTest.gltf", 1000, true},
                          {"BoxTexcoords-glTF/boxTexcoords.gltf", 12, true}};
    int n = 0;
    for (const Case& c : cases) {
        const std::string name = "s" + std::to_string(n++);
        const RunResult r = build((kSamples / c.file).string(), name);
        ASSERT_EQ(r.exit_code, 0) << c.file << "\n" << r.out;
        EXPECT_EQ(r.out.find("warning: ") != std::string::npos, c.warns) << c.file << "\n" << r.out;
        auto reader = storage::StoreReader::open(dir_.file("out/" + name + ".tsr"));
        ASSERT_TRUE(reader.ok()) << reader.error().message;
        auto scene = tessera::scene::load_obj_scene(dir_.file("out/" + name + ".obj"), (*reader)->info().width, (*reader)->info().height);
        ASSERT_TRUE(scene.ok()) << c.file << ": " << scene.error().message;
        std::size_t triangles = 0;
        for (const auto& ch : scene->chunks) triangles += ch.indices.size() / 3;
        EXPECT_GE(triangles, c.min_triangles) << c.file;
    }
}

// The texel glTF's sampling gives at texture coordinate (u, v) (v down), nearest texel: the
// transform's translation * rotation * scale, then each axis's wrap mode (the OpenGL definitions).
std::array<int, 2> expected_texel(double u, double v, int w, int h) {
    const double sx = 1.25, sy = 0.8, rot = 0.3, ox = 0.1, oy = -0.2;
    const double su = u * sx, sv = v * sy;
    const double tu = std::cos(rot) * su + std::sin(rot) * sv + ox;
    const double tv = -std::sin(rot) * su + std::cos(rot) * sv + oy;
    // MIRRORED_REPEAT on u: mirror(f) = f - 2 floor(f / 2), then 2 - that past 1.
    double m = tu - 2.0 * std::floor(tu / 2.0);
    if (m > 1.0) m = 2.0 - m;
    // CLAMP_TO_EDGE on v.
    const double c = std::clamp(tv, 0.0, 1.0);
    return {std::clamp(int(std::floor(m * w)), 0, w - 1), std::clamp(int(std::floor(c * h)), 0, h - 1)};
}

TEST_F(GltfAtlas, EveryPointGetsTheTexelGltfSamplingGives) {
    // A 40x24 texture of distinct texels, a quad whose coordinates run well outside [0, 1] on both
    // axes, mirrored across u, clamped along v, through KHR_texture_transform.
    const int W = 40, H = 24;
    std::vector<std::uint8_t> rgb(std::size_t(W) * H * 3);
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            std::uint8_t* p = &rgb[(std::size_t(y) * W + x) * 3];
            p[0] = std::uint8_t(x * 6);
            p[1] = std::uint8_t(y * 10);
            p[2] = std::uint8_t((x * 37 + y * 101) % 251);
        }
    auto png = storage::encode_png({W, H, 3, storage::SampleType::u8, storage::ColourSpace::srgb, rgb});
    ASSERT_TRUE(png.ok());
    // Quad corners (x, y, 0) and their texture coordinates (u, v): u = -1.3 + 3.9 x, v = 2.2 - 3.1 y.
    const float pos[4][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
    const float uv[4][2] = {{-1.3f, 2.2f}, {2.6f, 2.2f}, {2.6f, -0.9f}, {-1.3f, -0.9f}};
    const std::uint16_t idx[6] = {0, 1, 2, 0, 2, 3};
    nlohmann::json j = {
        {"asset", {{"version", "2.0"}}},
        {"extensionsUsed", {"KHR_texture_transform"}},
        {"extensionsRequired", {"KHR_texture_transform"}},
        {"scene", 0},
        {"scenes", {{{"nodes", {0}}}}},
        {"nodes", {{{"mesh", 0}}}},
        {"meshes", {{{"primitives", {{{"attributes", {{"POSITION", 0}, {"TEXCOORD_0", 1}}}, {"indices", 2}, {"material", 0}}}}}}},
        {"materials",
         {{{"name", "card"},
           {"pbrMetallicRoughness",
            {{"baseColorTexture",
              {{"index", 0},
               {"extensions", {{"KHR_texture_transform", {{"offset", {0.1, -0.2}}, {"rotation", 0.3}, {"scale", {1.25, 0.8}}}}}}}}}}}}},
        {"textures", {{{"source", 0}, {"sampler", 0}}}},
        {"samplers", {{{"wrapS", 33648}, {"wrapT", 33071}}}},
        {"images", {{{"uri", "data:image/png;base64," + base64(*png)}}}},
        {"accessors",
         {{{"bufferView", 0}, {"componentType", 5126}, {"count", 4}, {"type", "VEC3"}, {"min", {0, 0, 0}}, {"max", {1, 1, 0}}},
          {{"bufferView", 1}, {"componentType", 5126}, {"count", 4}, {"type", "VEC2"}},
          {{"bufferView", 2}, {"componentType", 5123}, {"count", 6}, {"type", "SCALAR"}}}}};
    j.update(quad_buffers(pos, uv, idx));
    const RunResult r = build_json(j, "card");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_EQ(r.out.find("warning"), std::string::npos) << r.out;

    auto reader = storage::StoreReader::open(dir_.file("out/card.tsr"));
    ASSERT_TRUE(reader.ok()) << reader.error().message;
    AtlasTexels atlas(*reader);
    PlanarAtlasLookup lookup(dir_.file("out/card.obj"), atlas);
    // The mirrored and clamped axes cut the quad: u spans 3.9 * 1.25 repeats, v is cut at 0 and 1.
    EXPECT_GT(lookup.pieces(), 8u);

    std::mt19937 rng(7);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    int compared = 0;
    for (int i = 0; i < 4000 && compared < 1500; ++i) {
        const double x = unit(rng), y = unit(rng);
        const double u = -1.3 + 3.9 * x, v = 2.2 - 3.1 * y;
        // Away from texel edges, so float rounding in the OBJ cannot pick a neighbour.
        const double sx = 1.25, sy = 0.8, rot = 0.3;
        const double tu = std::cos(rot) * u * sx + std::sin(rot) * v * sy + 0.1;
        const double tv = -std::sin(rot) * u * sx + std::cos(rot) * v * sy - 0.2;
        auto frac_ok = [](double f) { return std::abs(f - std::round(f)) > 0.02; };
        if (!frac_ok(tu * W) || !(frac_ok(tv * H) || tv < 0 || tv > 1)) continue;
        const auto want = expected_texel(u, v, W, H);
        const auto got = lookup.at(x, y);
        if (!got) continue;  // on a cut between pieces
        const std::uint8_t* e = &rgb[(std::size_t(want[1]) * W + std::size_t(want[0])) * 3];
        ASSERT_EQ(*got, (std::array<std::uint8_t, 3>{e[0], e[1], e[2]}))
            << "at (" << x << ", " << y << "), uv (" << u << ", " << v << "): want texel " << want[0] << "," << want[1];
        ++compared;
    }
    EXPECT_GE(compared, 1000);
}

// A material's maps go into layers of their own (docs/atlas.md, "Material layers"), in the cell its
// base colour has: two quads side by side, one with a base colour, a normal map of the same size, a
// metallic-roughness map of half the size (resampled), a grey occlusion map and an emissive map;
// the other with a base colour only, whose cells in the other layers hold its factors. Every sampled point of each
// layer is checked against the texel glTF's sampling gives, computed here from the images.
TEST_F(GltfAtlas, MaterialMapsGoToLayersOfTheirOwn) {
    const int W = 40, H = 24;
    auto image = [](int w, int h, auto fn) {
        std::vector<std::uint8_t> rgb(std::size_t(w) * h * 3);
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const std::array<std::uint8_t, 3> t = fn(x, y);
                std::memcpy(&rgb[(std::size_t(y) * w + x) * 3], t.data(), 3);
            }
        return rgb;
    };
    auto distinct = [](int salt) {
        return [salt](int x, int y) {
            return std::array<std::uint8_t, 3>{std::uint8_t(x * 6 + salt), std::uint8_t(y * 10 + salt),
                                               std::uint8_t((x * 37 + y * 101 + salt) % 251)};
        };
    };
    const auto base = image(W, H, distinct(0)), normal = image(W, H, distinct(3)), base2 = image(W, H, distinct(5));
    const auto mr = image(W / 2, H / 2, [](int x, int y) { return std::array<std::uint8_t, 3>{0, std::uint8_t(x * 12), std::uint8_t(y * 20)}; });
    std::vector<std::uint8_t> occlusion(std::size_t(W) * H);  // grey: one channel
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) occlusion[std::size_t(y) * W + x] = std::uint8_t(255 - x * 3 - y * 2);
    // Smooth, so that the emissive layer's JPEG stays close.
    const auto emissive = image(W, H, [](int x, int y) { return std::array<std::uint8_t, 3>{std::uint8_t(40 + x * 4), std::uint8_t(60 + y * 5), 90}; });
    auto png = [](const std::vector<std::uint8_t>& rgb, int w, int h) {
        auto p = storage::encode_png({std::uint32_t(w), std::uint32_t(h), 3, storage::SampleType::u8, storage::ColourSpace::srgb, rgb});
        EXPECT_TRUE(p.ok());
        return "data:image/png;base64," + base64(*p);
    };
    auto grey = storage::encode_png({std::uint32_t(W), std::uint32_t(H), 1, storage::SampleType::u8, storage::ColourSpace::srgb, occlusion});
    ASSERT_TRUE(grey.ok());
    const std::string grey_png = "data:image/png;base64," + base64(*grey);
    // Quad A at x in [0, 1], quad B at x in [2, 3]; (u, v) = (x - x0, y) with glTF's v down.
    const float pos[8][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {2, 0, 0}, {3, 0, 0}, {3, 1, 0}, {2, 1, 0}};
    const float uv[8][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}, {0, 0}, {1, 0}, {1, 1}, {0, 1}};
    const std::uint16_t idx[12] = {0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7};
    nlohmann::json j = {
        {"asset", {{"version", "2.0"}}},
        {"scene", 0},
        {"scenes", {{{"nodes", {0}}}}},
        {"nodes", {{{"mesh", 0}}}},
        {"meshes",
         {{{"primitives",
            {{{"attributes", {{"POSITION", 0}, {"TEXCOORD_0", 1}}}, {"indices", 2}, {"material", 0}},
             {{"attributes", {{"POSITION", 0}, {"TEXCOORD_0", 1}}}, {"indices", 3}, {"material", 1}}}}}}},
        {"materials",
         {{{"name", "mapped"},
           {"normalTexture", {{"index", 1}}},
           {"emissiveTexture", {{"index", 3}}},
           {"occlusionTexture", {{"index", 5}}},
           {"emissiveFactor", {1, 1, 1}},
           {"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 0}}}, {"metallicRoughnessTexture", {{"index", 2}}}}}},
          {{"name", "plain"},
           {"emissiveFactor", {0.2, 0.4, 0.6}},
           {"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 4}}}, {"metallicFactor", 0.25}, {"roughnessFactor", 0.75}}}}}},
        {"textures", {{{"source", 0}}, {{"source", 1}}, {{"source", 2}}, {{"source", 3}}, {{"source", 4}}, {{"source", 5}}}},
        {"images",
         {{{"uri", png(base, W, H)}},
          {{"uri", png(normal, W, H)}},
          {{"uri", png(mr, W / 2, H / 2)}},
          {{"uri", png(emissive, W, H)}},
          {{"uri", png(base2, W, H)}},
          {{"uri", grey_png}}}},
        {"accessors",
         {{{"bufferView", 0}, {"componentType", 5126}, {"count", 8}, {"type", "VEC3"}, {"min", {0, 0, 0}}, {"max", {3, 1, 0}}},
          {{"bufferView", 1}, {"componentType", 5126}, {"count", 8}, {"type", "VEC2"}},
          {{"bufferView", 2}, {"componentType", 5123}, {"count", 6}, {"type", "SCALAR"}},
          {{"bufferView", 3}, {"componentType", 5123}, {"count", 6}, {"type", "SCALAR"}}}}};
    j.update(quad_buffers(pos, uv, idx, 2));
    const RunResult r = build_json(j, "maps");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_EQ(r.out.find("warning"), std::string::npos) << r.out;

    auto reader = storage::StoreReader::open(dir_.file("out/maps.tsr"));
    ASSERT_TRUE(reader.ok()) << reader.error().message;
    const storage::StoreInfo& info = (*reader)->info();
    ASSERT_EQ(info.layers.size(), 5u);
    const char* names[] = {"base", "normal", "metallic_roughness", "occlusion", "emissive"};
    for (std::size_t l = 0; l < 5; ++l) EXPECT_EQ(info.layers[l].name, names[l]);
    for (std::size_t l = 1; l <= 3; ++l) {  // data: values as they are, lossless
        EXPECT_EQ(info.layers[l].colour_space, storage::ColourSpace::linear) << names[l];
        EXPECT_EQ(info.layers[l].codec, Codec::zstd) << names[l];
    }
    EXPECT_EQ(info.layers[4].colour_space, storage::ColourSpace::srgb);

    // Bilinear upsampling by 2 of the half-size map, edges clamped: what the cell must hold.
    auto upsampled = [&](int x, int y, int c) {
        auto axis = [](int o, int n, int& i0, int& i1, double& w) {
            const double s = (o + 0.5) / 2 - 0.5;
            const double f = std::floor(s);
            w = s - f;
            i0 = std::clamp(int(f), 0, n - 1);
            i1 = std::clamp(int(f) + 1, 0, n - 1);
        };
        int x0, x1, y0, y1;
        double wx, wy;
        axis(x, W / 2, x0, x1, wx);
        axis(y, H / 2, y0, y1, wy);
        auto at = [&](int xx, int yy) { return double(mr[(std::size_t(yy) * (W / 2) + xx) * 3 + c]); };
        return (1 - wy) * ((1 - wx) * at(x0, y0) + wx * at(x1, y0)) + wy * ((1 - wx) * at(x0, y1) + wx * at(x1, y1));
    };
    auto srgb_byte = [](double v) {
        v = v <= 0.0031308 ? v * 12.92 : 1.055 * std::pow(v, 1 / 2.4) - 0.055;
        return int(std::lround(v * 255));
    };
    std::vector<std::unique_ptr<AtlasTexels>> layers;
    std::vector<std::unique_ptr<PlanarAtlasLookup>> lookups;
    for (std::size_t l = 0; l < 5; ++l) {
        layers.push_back(std::make_unique<AtlasTexels>(*reader, l));
        lookups.push_back(std::make_unique<PlanarAtlasLookup>(dir_.file("out/maps.obj"), *layers.back()));
    }
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    int compared = 0, emissive_max_error = 0;
    for (int i = 0; i < 3000 && compared < 1200; ++i) {
        const bool second = i % 2 == 1;
        const double u = unit(rng), v = unit(rng);
        auto frac_ok = [](double f) { return std::abs(f - std::round(f)) > 0.02; };
        if (!frac_ok(u * W) || !frac_ok(v * H)) continue;
        const int tx = int(u * W), ty = int(v * H);
        const std::size_t t = (std::size_t(ty) * W + tx) * 3;
        std::array<std::optional<std::array<std::uint8_t, 3>>, 5> got;
        for (std::size_t l = 0; l < 5; ++l) got[l] = lookups[l]->at((second ? 2 : 0) + u, v);
        if (!got[0] || !got[1] || !got[2] || !got[3] || !got[4]) continue;
        const auto& b = second ? base2 : base;
        ASSERT_EQ(*got[0], (std::array<std::uint8_t, 3>{b[t], b[t + 1], b[t + 2]})) << "base at " << tx << "," << ty;
        if (!second) {
            ASSERT_EQ(*got[1], (std::array<std::uint8_t, 3>{normal[t], normal[t + 1], normal[t + 2]})) << "normal at " << tx << "," << ty;
            for (int c = 0; c < 3; ++c)
                ASSERT_NEAR((*got[2])[std::size_t(c)], upsampled(tx, ty, c), 1.0) << "metallic_roughness at " << tx << "," << ty << " channel " << c;
            const std::uint8_t o = occlusion[std::size_t(ty) * W + tx];  // grey, replicated
            ASSERT_EQ(*got[3], (std::array<std::uint8_t, 3>{o, o, o})) << "occlusion at " << tx << "," << ty;
            for (int c = 0; c < 3; ++c)
                emissive_max_error = std::max(emissive_max_error, std::abs(int((*got[4])[std::size_t(c)]) - int(emissive[t + std::size_t(c)])));
        } else {  // no maps: the flat normal, the factors
            ASSERT_EQ(*got[1], (std::array<std::uint8_t, 3>{128, 128, 255}));
            ASSERT_EQ(*got[2], (std::array<std::uint8_t, 3>{0, 191, 64}));  // roughness 0.75, metallic 0.25
            ASSERT_EQ(*got[3], (std::array<std::uint8_t, 3>{255, 255, 255}));
            const std::array<std::uint8_t, 3> e = {std::uint8_t(srgb_byte(0.2)), std::uint8_t(srgb_byte(0.4)), std::uint8_t(srgb_byte(0.6))};
            for (std::size_t c = 0; c < 3; ++c) ASSERT_NEAR((*got[4])[c], e[c], 2) << "emissive factor";
        }
        ++compared;
    }
    EXPECT_GE(compared, 800);
    EXPECT_LE(emissive_max_error, 8);  // JPEG, the emissive layer's default codec
}

// Khronos's ClearCoatTest, viewed over gRPC with the scene that travels with its store, one
// material layer at a time: each matches the reference renderer (which decodes the same layer from
// the store file) at 50 dB or better (docs/atlas.md, "Material layers").
TEST_F(GltfAtlas, EveryMaterialLayerMatchesTheReferenceOverGrpc) {
    ASSERT_EQ(build((kSamples / "ClearCoat-glTF/ClearCoatTest.gltf").string(), "coat").exit_code, 0);
    ServerProcess server({"--store-dir", dir_.file("out")}, dir_.file("server.log"));
    ASSERT_TRUE(server.running()) << server.log();
    for (const char* layer : {"base", "normal", "metallic_roughness", "emissive"}) {
        const RunResult r = run_tessera("view --store grpc://" + server.grpc_address() + "/coat --headless --size 192x128 --frames 24 --pool 128 " +
                                        "--psnr-every 8 --reference-store " + q(dir_.file("out/coat.tsr")) + " --show-layer " + layer);
        ASSERT_EQ(r.exit_code, 0) << layer << "\n" << r.out << server.log();
        EXPECT_NE(r.out.find("scene         atlas, travelling with the store"), std::string::npos) << r.out;
        EXPECT_TRUE(psnr_at_least(r.out, 50.0)) << layer;
    }
}

// A garden exported by Blender 3.4's own glTF exporter (tests/assets/garden: textures made by
// ImageMagick, the scene by tests/assets/garden/make_garden.py): a lawn repeating 4 x 4 times, a
// lattice fence and a hedge whose materials are alphaMode MASK (Blender's Alpha Clip at 0.5).
// Viewed over gRPC with the scene that travels with its store, framed by the default orbit, cut-out
// edges and the lawn seen through them included: 50 dB or better against the reference renderer
// in every compared frame (docs/atlas.md, "Alpha").
TEST_F(GltfAtlas, ABlenderGardenWithCutOutsMatchesTheReferenceOverGrpc) {
    const fs::path garden = fs::path(TESSERA_TEST_ASSETS) / "garden" / "garden.glb";
    ASSERT_TRUE(fs::is_regular_file(garden)) << garden;
    const RunResult b = build(garden.string(), "garden");
    ASSERT_EQ(b.exit_code, 0) << b.out;
    ServerProcess server({"--store-dir", dir_.file("out")}, dir_.file("server.log"));
    ASSERT_TRUE(server.running()) << server.log();
    const RunResult r = run_tessera("view --store grpc://" + server.grpc_address() + "/garden --headless --size 192x128 --frames 48 " +
                                    "--psnr-every 6 --reference-store " + q(dir_.file("out/garden.tsr")));
    ASSERT_EQ(r.exit_code, 0) << r.out << server.log();
    EXPECT_NE(r.out.find("scene         atlas, travelling with the store (132 triangles, 6 objects)"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find(", cut-outs at alpha 0.5\n"), std::string::npos) << r.out;
    EXPECT_TRUE(psnr_at_least(r.out, 50.0));
}

// A Blender-exported courtyard whose materials have every map (tests/assets/courtyard): a normal
// map, metallic-roughness, occlusion and an emissive map become layers, and the viewer lights the
// base colour with them, over gRPC with the scene that travels with the store, as the reference
// lights its own textures of the same layers.
TEST_F(GltfAtlas, ABlenderCourtyardLitByItsMapsMatchesTheReferenceOverGrpc) {
    const fs::path courtyard = fs::path(TESSERA_TEST_ASSETS) / "courtyard" / "courtyard.glb";
    ASSERT_TRUE(fs::is_regular_file(courtyard)) << courtyard;
    const RunResult b = build(courtyard.string(), "courtyard");
    ASSERT_EQ(b.exit_code, 0) << b.out;
    {
        auto reader = storage::StoreReader::open(dir_.file("out/courtyard.tsr"));
        ASSERT_TRUE(reader.ok()) << reader.error().message;
        const auto& layers = (*reader)->info().layers;
        std::vector<std::string> names;
        for (const auto& l : layers) names.push_back(l.name);
        EXPECT_EQ(names, (std::vector<std::string>{"base", "normal", "metallic_roughness", "occlusion", "emissive"}));
    }
    ServerProcess server({"--store-dir", dir_.file("out")}, dir_.file("server.log"));
    ASSERT_TRUE(server.running()) << server.log();
    const std::string view = "view --store grpc://" + server.grpc_address() + "/courtyard --headless --size 192x128 --frames 48 ";
    const RunResult r = run_tessera(view + "--psnr-every 6 --reference-store " + q(dir_.file("out/courtyard.tsr")) + " --out " +
                                    q(dir_.file("lit")) + " --png-count 1");
    ASSERT_EQ(r.exit_code, 0) << r.out << server.log();
    EXPECT_NE(r.out.find("scene         atlas, travelling with the store (1120 triangles, 4 objects), lit by its material maps "
                         "(normal, metallic_roughness, occlusion, emissive)\n"),
              std::string::npos)
        << r.out;
    EXPECT_TRUE(psnr_at_least(r.out, 50.0));
    // --unlit draws the base colour as it is: the lighting changes what is seen.
    const RunResult u = run_tessera(view + "--unlit --out " + q(dir_.file("unlit")) + " --png-count 1");
    ASSERT_EQ(u.exit_code, 0) << u.out;
    EXPECT_EQ(u.out.find("lit by its material maps"), std::string::npos) << u.out;
    const auto lit = tessera::test::read_png(dir_.file("lit/frame_00024.png")).rgb;
    const auto unlit = tessera::test::read_png(dir_.file("unlit/frame_00024.png")).rgb;
    ASSERT_EQ(lit.size(), std::size_t(192) * 128 * 3);
    ASSERT_EQ(unlit.size(), lit.size());
    std::size_t differ = 0;
    for (std::size_t i = 0; i < lit.size(); i += 3)
        if (std::abs(int(lit[i]) - int(unlit[i])) + std::abs(int(lit[i + 1]) - int(unlit[i + 1])) > 16) ++differ;
    EXPECT_GT(differ, lit.size() / 3 / 10) << "the lit and unlit frames differ in only " << differ << " pixels";
}

// The lighting itself, against glTF 2.0's BRDF (its specification, appendix B) written out here in
// double precision, not the shader's code: one quad of constant maps seen from a fixed camera, whose
// centre ray meets the quad's centre, so the view vector there is known. Its normal map tilts the
// normal towards +u (the tangent: +x here) and its bitangent (up the image: +y), so a wrong
// tangent frame, a swapped channel or a lost map moves the centre pixel's colour.
TEST_F(GltfAtlas, MaterialLightingMatchesTheGltfBrdfWrittenOutIndependently) {
    const auto solid = [](std::array<std::uint8_t, 3> c) { return solid_png_uri(c); };
    const std::array<std::uint8_t, 3> base{180, 120, 60}, normal{204, 159, 220}, orm{150, 110, 40}, emissive{30, 20, 10};
    // glTF is Y up: the quad lies in y = 0 facing +Y, u along +x, v (down the image) along +z.
    const float pos[4][3] = {{-1, 0, 1}, {1, 0, 1}, {1, 0, -1}, {-1, 0, -1}};
    const float nrm[4][3] = {{0, 1, 0}, {0, 1, 0}, {0, 1, 0}, {0, 1, 0}};
    const float uv[4][2] = {{0, 1}, {1, 1}, {1, 0}, {0, 0}};
    const std::uint16_t idx[6] = {0, 1, 2, 0, 2, 3};
    std::vector<std::uint8_t> buffer(sizeof pos + sizeof nrm + sizeof uv + sizeof idx);
    std::memcpy(buffer.data(), pos, sizeof pos);
    std::memcpy(buffer.data() + sizeof pos, nrm, sizeof nrm);
    std::memcpy(buffer.data() + sizeof pos + sizeof nrm, uv, sizeof uv);
    std::memcpy(buffer.data() + sizeof pos + sizeof nrm + sizeof uv, idx, sizeof idx);
    const std::size_t o_nrm = sizeof pos, o_uv = o_nrm + sizeof nrm, o_idx = o_uv + sizeof uv;
    const nlohmann::json j = {
        {"asset", {{"version", "2.0"}}},
        {"scene", 0},
        {"scenes", {{{"nodes", {0}}}}},
        {"nodes", {{{"mesh", 0}}}},
        {"meshes", {{{"primitives", {{{"attributes", {{"POSITION", 0}, {"NORMAL", 1}, {"TEXCOORD_0", 2}}}, {"indices", 3}, {"material", 0}}}}}}},
        {"materials",
         {{{"name", "lit"},
           {"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 0}}}, {"metallicRoughnessTexture", {{"index", 2}}}}},
           {"normalTexture", {{"index", 1}}},
           {"occlusionTexture", {{"index", 2}}},
           {"emissiveTexture", {{"index", 3}}},
           {"emissiveFactor", {1, 1, 1}}}}},
        {"textures", {{{"source", 0}}, {{"source", 1}}, {{"source", 2}}, {{"source", 3}}}},
        {"images", {{{"uri", solid(base)}}, {{"uri", solid(normal)}}, {{"uri", solid(orm)}}, {{"uri", solid(emissive)}}}},
        {"buffers", {{{"byteLength", buffer.size()}, {"uri", "data:application/octet-stream;base64," + base64(buffer)}}}},
        {"bufferViews",
         {{{"buffer", 0}, {"byteOffset", 0}, {"byteLength", sizeof pos}},
          {{"buffer", 0}, {"byteOffset", o_nrm}, {"byteLength", sizeof nrm}},
          {{"buffer", 0}, {"byteOffset", o_uv}, {"byteLength", sizeof uv}},
          {{"buffer", 0}, {"byteOffset", o_idx}, {"byteLength", sizeof idx}}}},
        {"accessors",
         {{{"bufferView", 0}, {"componentType", 5126}, {"count", 4}, {"type", "VEC3"}, {"min", {-1, 0, -1}}, {"max", {1, 0, 1}}},
          {{"bufferView", 1}, {"componentType", 5126}, {"count", 4}, {"type", "VEC3"}},
          {{"bufferView", 2}, {"componentType", 5126}, {"count", 4}, {"type", "VEC2"}},
          {{"bufferView", 3}, {"componentType", 5123}, {"count", 6}, {"type", "SCALAR"}}}}};
    const RunResult b = build_json(j, "lit");
    ASSERT_EQ(b.exit_code, 0) << b.out;
    // The quad is z = 0 in the library's Z up, u along +x, up the image +y.
    const RunResult r = still_view("lit");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    ASSERT_NE(r.out.find("lit by its material maps (normal, metallic_roughness, occlusion, emissive)"), std::string::npos) << r.out;
    const auto frame = tessera::test::read_png(dir_.file("frames/frame_00020.png"));
    ASSERT_EQ(frame.width, 65);
    const std::array<double, 3> eye = kStillEye;

    // The BRDF at the centre: n from the normal map in the frame (t, b, n) = (+x, +y, +z).
    using V3 = std::array<double, 3>;
    auto dot = [](V3 a, V3 c) { return a[0] * c[0] + a[1] * c[1] + a[2] * c[2]; };
    auto unit = [&](V3 a) {
        const double l = std::sqrt(dot(a, a));
        return V3{a[0] / l, a[1] / l, a[2] / l};
    };
    const auto linear = linear_of;
    const V3 n = unit({normal[0] / 255.0 * 2 - 1, normal[1] / 255.0 * 2 - 1, normal[2] / 255.0 * 2 - 1});
    const V3 l = unit({-0.5, -0.4, 0.75});  // the sun (docs/renderer.md, "Materials")
    const V3 v = unit(eye);
    const V3 h = unit({l[0] + v[0], l[1] + v[1], l[2] + v[2]});
    const double occlusion = orm[0] / 255.0, roughness = orm[1] / 255.0, metallic = orm[2] / 255.0;
    const double alpha = roughness * roughness, a2 = alpha * alpha;
    const double nl = std::max(dot(n, l), 0.0), nv = dot(n, v), nh = dot(n, h), vh = dot(v, h);
    const double d = a2 / (std::acos(-1.0) * std::pow(nh * nh * (a2 - 1) + 1, 2));
    const double vis = 0.5 / (nl * std::sqrt(nv * nv * (1 - a2) + a2) + nv * std::sqrt(nl * nl * (1 - a2) + a2));
    for (int c = 0; c < 3; ++c) {
        const double colour = linear(base[std::size_t(c)]);
        const double f0 = 0.04 * (1 - metallic) + colour * metallic, diffuse = colour * (1 - metallic);
        const double fresnel = f0 + (1 - f0) * std::pow(1 - vh, 5);
        const double out = ((1 - fresnel) * diffuse / std::acos(-1.0) + fresnel * d * vis) * 2.4 * nl + 0.3 * occlusion * (diffuse + f0) +
                           linear(emissive[std::size_t(c)]);
        EXPECT_NEAR(frame.at(32, 32)[std::size_t(c)], encode_srgb(out), 2.0) << "channel " << c << "\n" << r.out;
    }
}

// alphaMode BLEND: a half-transparent blue quad half a unit above an opaque red one. Both
// renderers draw it over what lies behind, after the rest; the centre pixel must be the two
// colours mixed by the alpha in linear light, computed here, and the VT must match the reference.
TEST_F(GltfAtlas, BlendedMaterialsMixWithWhatLiesBehind) {
    const std::array<std::uint8_t, 3> back{200, 40, 30}, front{20, 60, 220};
    const std::uint8_t alpha = 100;
    const float pos[4][3] = {{-1, 0, 1}, {1, 0, 1}, {1, 0, -1}, {-1, 0, -1}};
    const float uv[4][2] = {{0, 1}, {1, 1}, {1, 0}, {0, 0}};
    const std::uint16_t idx[6] = {0, 1, 2, 0, 2, 3};
    const auto primitive = [](int material) {
        return nlohmann::json{{"primitives", {{{"attributes", {{"POSITION", 0}, {"TEXCOORD_0", 1}}}, {"indices", 2}, {"material", material}}}}};
    };
    nlohmann::json j = {
        {"asset", {{"version", "2.0"}}},
        {"scene", 0},
        {"scenes", {{{"nodes", {0, 1}}}}},
        {"nodes", {{{"mesh", 0}, {"name", "floor"}}, {{"mesh", 1}, {"name", "glass"}, {"translation", {0, 0.5, 0}}}}},
        {"meshes", {primitive(0), primitive(1)}},
        {"materials",
         {{{"name", "red"}, {"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 0}}}}}},
          {{"name", "glass"}, {"alphaMode", "BLEND"}, {"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 1}}}}}}}},
        {"textures", {{{"source", 0}}, {{"source", 1}}}},
        {"images", {{{"uri", solid_png_uri(back)}}, {{"uri", solid_png_uri(front, alpha)}}}},
        {"accessors",
         {{{"bufferView", 0}, {"componentType", 5126}, {"count", 4}, {"type", "VEC3"}, {"min", {-1, 0, -1}}, {"max", {1, 0, 1}}},
          {{"bufferView", 1}, {"componentType", 5126}, {"count", 4}, {"type", "VEC2"}},
          {{"bufferView", 2}, {"componentType", 5123}, {"count", 6}, {"type", "SCALAR"}}}}};
    j.update(quad_buffers(pos, uv, idx));
    const RunResult b = build_json(j, "glass");
    ASSERT_EQ(b.exit_code, 0) << b.out;
    EXPECT_EQ(b.out.find("warning"), std::string::npos) << b.out;
    // The rewritten OBJ marks the blended object.
    const auto obj = read_file(dir_.file("out/glass.obj"));
    const std::string text(obj.begin(), obj.end());
    EXPECT_NE(text.find("# tessera-blend\no glass\n"), std::string::npos) << text;
    EXPECT_EQ(text.find("# tessera-blend\no floor\n"), std::string::npos) << text;

    const RunResult r = still_view("glass", "--psnr-every 5 --reference-store " + q(dir_.file("out/glass.tsr")));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    const auto frame = tessera::test::read_png(dir_.file("frames/frame_00020.png"));
    ASSERT_EQ(frame.width, 65);
    const double a = alpha / 255.0;
    for (std::size_t c = 0; c < 3; ++c) {
        const double mixed = a * linear_of(front[c]) + (1 - a) * linear_of(back[c]);
        EXPECT_NEAR(frame.at(32, 32)[c], encode_srgb(mixed), 1.5) << "channel " << c << "\n" << r.out;
    }
    EXPECT_TRUE(psnr_at_least(r.out, 50.0));
}

// Sixty textures through gltfpack (Debian's meshoptimizer tool, as engines' pipelines use it): it
// rewrites the scene with quantised positions and texture coordinates (KHR_mesh_quantization,
// undone by node transforms and KHR_texture_transform) and puts the images inside the GLB. Every
// sampled point of every quad, repeating ones included, gets its own texture's texel.
TEST_F(GltfAtlas, SixtyTexturesThroughGltfpackKeepEveryTexel) {
    const int n = 60, W = 64, H = 48;
    auto texel = [](int i, int x, int y) {
        return std::array<std::uint8_t, 3>{std::uint8_t(x * 4), std::uint8_t(y * 5), std::uint8_t(i * 4)};
    };
    fs::create_directory(dir_.file("tex"));
    nlohmann::json nodes = nlohmann::json::array(), meshes = nlohmann::json::array(), materials = nlohmann::json::array(),
                   textures = nlohmann::json::array(), images = nlohmann::json::array(), accessors = nlohmann::json::array();
    std::vector<float> pos, uv;
    auto repeats = [](int i) { return i % 7 == 0 ? 2.0 : 1.0; };
    for (int i = 0; i < n; ++i) {
        std::vector<std::uint8_t> rgb(std::size_t(W) * H * 3);
        for (int y = 0; y < H; ++y)
            for (int x = 0; x < W; ++x) {
                const auto c = texel(i, x, y);
                std::copy(c.begin(), c.end(), &rgb[(std::size_t(y) * W + x) * 3]);
            }
        auto png = storage::encode_png({W, H, 3, storage::SampleType::u8, storage::ColourSpace::srgb, rgb});
        ASSERT_TRUE(png.ok());
        write_file(dir_.file("tex/t" + std::to_string(i) + ".png"), *png);
        const float x = float(i % 10) * 1.25f, y = float(i / 10) * 1.25f, r = float(repeats(i));
        pos.insert(pos.end(), {x, y, 0, x + 1, y, 0, x + 1, y + 1, 0, x, y + 1, 0});
        uv.insert(uv.end(), {0, r, r, r, r, 0, 0, 0});
        accessors.push_back({{"bufferView", 0}, {"byteOffset", 48 * i}, {"componentType", 5126}, {"count", 4}, {"type", "VEC3"},
                             {"min", {x, y, 0}}, {"max", {x + 1, y + 1, 0}}});
        accessors.push_back({{"bufferView", 1}, {"byteOffset", 32 * i}, {"componentType", 5126}, {"count", 4}, {"type", "VEC2"}});
        meshes.push_back({{"primitives", {{{"attributes", {{"POSITION", 2 * i}, {"TEXCOORD_0", 2 * i + 1}}}, {"indices", 2 * n}, {"material", i}}}}});
        nodes.push_back({{"mesh", i}});
        materials.push_back({{"name", "m" + std::to_string(i)}, {"pbrMetallicRoughness", {{"baseColorTexture", {{"index", i}}}}}});
        textures.push_back({{"source", i}, {"sampler", 0}});
        images.push_back({{"uri", "tex/t" + std::to_string(i) + ".png"}});
    }
    accessors.push_back({{"bufferView", 2}, {"componentType", 5123}, {"count", 6}, {"type", "SCALAR"}});
    const std::uint16_t idx[6] = {0, 1, 2, 0, 2, 3};
    std::vector<std::uint8_t> buffer(pos.size() * 4 + uv.size() * 4 + sizeof idx);
    std::memcpy(buffer.data(), pos.data(), pos.size() * 4);
    std::memcpy(buffer.data() + pos.size() * 4, uv.data(), uv.size() * 4);
    std::memcpy(buffer.data() + pos.size() * 4 + uv.size() * 4, idx, sizeof idx);
    write_file(dir_.file("scene.bin"), buffer);
    nlohmann::json nodes_list = nlohmann::json::array();
    for (int i = 0; i < n; ++i) nodes_list.push_back(i);
    const nlohmann::json j = {{"asset", {{"version", "2.0"}}}, {"scene", 0}, {"scenes", {{{"nodes", nodes_list}}}}, {"nodes", nodes},
                              {"meshes", meshes}, {"materials", materials}, {"textures", textures}, {"images", images},
                              {"samplers", {{{"wrapS", 10497}, {"wrapT", 10497}}}},
                              {"buffers", {{{"uri", "scene.bin"}, {"byteLength", buffer.size()}}}},
                              {"bufferViews", {{{"buffer", 0}, {"byteOffset", 0}, {"byteLength", pos.size() * 4}},
                                               {{"buffer", 0}, {"byteOffset", pos.size() * 4}, {"byteLength", uv.size() * 4}},
                                               {{"buffer", 0}, {"byteOffset", pos.size() * 4 + uv.size() * 4}, {"byteLength", sizeof idx}}}},
                              {"accessors", accessors}};
    const std::string text = j.dump();
    write_file(dir_.file("scene.gltf"), std::vector<std::uint8_t>(text.begin(), text.end()));
    const RunResult packed = tessera::test::run_program("gltfpack", "-i " + q(dir_.file("scene.gltf")) + " -o " + q(dir_.file("packed.glb")));
    ASSERT_EQ(packed.exit_code, 0) << "gltfpack (tools/setup.sh --tests installs it): " << packed.out;
    {
        // What gltfpack wrote: quantised, transformed, the images inside.
        const auto glb = read_file(dir_.file("packed.glb"));
        const std::string head(glb.begin(), glb.begin() + std::min<std::size_t>(glb.size(), 4096));
        EXPECT_NE(head.find("KHR_mesh_quantization"), std::string::npos);
        EXPECT_NE(head.find("KHR_texture_transform"), std::string::npos);
        EXPECT_EQ(head.find("tex/t0.png"), std::string::npos);
    }
    const RunResult r = build(dir_.file("packed.glb"), "many");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_EQ(r.out.find("warning"), std::string::npos) << r.out;
    auto reader = storage::StoreReader::open(dir_.file("out/many.tsr"));
    ASSERT_TRUE(reader.ok()) << reader.error().message;
    AtlasTexels atlas(*reader);
    PlanarAtlasLookup lookup(dir_.file("out/many.obj"), atlas);
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> unit(0.02, 0.98);  // clear of the quads' (quantised) edges
    int compared = 0;
    for (int i = 0; i < n; ++i)
        for (int k = 0; k < 40; ++k) {
            const double fx = unit(rng), fy = unit(rng), rep = repeats(i);
            const double u = fx * rep, v = (1 - fy) * rep;  // glTF's v points down: y up is v down
            const double tx = (u - std::floor(u)) * W, ty = (v - std::floor(v)) * H;
            if (std::abs(tx - std::round(tx)) < 0.1 || std::abs(ty - std::round(ty)) < 0.1) continue;  // quantised coordinates
            const auto got = lookup.at(double(i % 10) * 1.25 + fx, double(i / 10) * 1.25 + fy);
            if (!got) continue;
            ASSERT_EQ(*got, texel(i, int(tx), int(ty))) << "texture " << i << " at (" << fx << ", " << fy << ")";
            ++compared;
        }
    EXPECT_GE(compared, 1500);
}

TEST_F(GltfAtlas, ScenesItCannotReadFailAndLeaveNothing) {
    const std::string out = dir_.file("out");
    auto expect_fails = [&](const std::string& scene, const std::string& says) {
        const RunResult r = build(scene, "bad");
        expect_one_line_error(r);
        EXPECT_NE(r.out.find(says), std::string::npos) << scene << "\n" << r.out;
        EXPECT_TRUE(entries(out).empty()) << scene;
    };
    // A required extension the build does not read, named.
    expect_fails((kSamples / "draco/2CylinderEngine.gltf").string(), "requires the extension KHR_draco_mesh_compression");
    // A buffer file that is not there, a node that is its own ancestor, an index out of range.
    expect_fails((kSamples / "MissingBin/BoxTextured.gltf").string(), "BoxTextured0.bin");
    expect_fails((kSamples / "RecursiveNodes/RecursiveNodes.gltf").string(), "its own ancestor");
    expect_fails((kSamples / "IndexOutOfRange/IndexOutOfRange.gltf").string(), "out of range");
    // A GLB cut short.
    auto glb = read_file((kSamples / "BoxTextured-glTF-Binary/BoxTextured.glb").string());
    glb.resize(glb.size() / 2);
    write_file(dir_.file("cut.glb"), glb);
    expect_fails(dir_.file("cut.glb"), "cannot read glTF");
    // A texture that is missing, and one OpenImageIO cannot read: the material is named.
    fs::copy(kSamples / "BoxTextured-glTF", dir_.file("box"));
    fs::remove(dir_.file("box/CesiumLogoFlat.png"));
    expect_fails(dir_.file("box/BoxTextured.gltf"), "material 'Texture': texture");
    write_file(dir_.file("box/CesiumLogoFlat.png"), std::vector<std::uint8_t>(300, 0x5a));
    expect_fails(dir_.file("box/BoxTextured.gltf"), "material 'Texture'");
    // A material map (a layer's image) that is missing, and one OpenImageIO cannot read.
    fs::copy(kSamples / "ClearCoat-glTF", dir_.file("coat"));
    fs::remove(dir_.file("coat/RibsNormal.png"));
    expect_fails(dir_.file("coat/ClearCoatTest.gltf"), "RibsNormal.png' does not exist");
    write_file(dir_.file("coat/RibsNormal.png"), std::vector<std::uint8_t>(300, 0x5a));
    expect_fails(dir_.file("coat/ClearCoatTest.gltf"), "RibsNormal.png");
    // An embedded image that is not an image: named as the scene's image, not a temporary file.
    auto text = read_file((kSamples / "BoxTextured-glTF-Embedded/BoxTextured.gltf").string());
    nlohmann::json j = nlohmann::json::parse(std::string(text.begin(), text.end()));
    j["images"][0]["uri"] = "data:image/png;base64," + base64(std::vector<std::uint8_t>(200, 0x33));
    const std::string bad = j.dump();
    write_file(dir_.file("badimage.gltf"), std::vector<std::uint8_t>(bad.begin(), bad.end()));
    expect_fails(dir_.file("badimage.gltf"), "badimage.gltf image 0");
    // An image damaged past its header, found only while the store is built: still the material.
    auto logo = read_file((kSamples / "BoxTextured-glTF/CesiumLogoFlat.png").string());
    logo.resize(logo.size() / 2);
    write_file(dir_.file("box/CesiumLogoFlat.png"), logo);
    expect_fails(dir_.file("box/BoxTextured.gltf"), "material 'Texture': ");
    // An image or buffer uri that names a folder (tinygltf read it as a file: std::bad_alloc).
    fs::create_directory(dir_.file("sub"));
    for (const char* field : {"images", "buffers"}) {
        nlohmann::json k = j;
        k[field][0]["uri"] = "sub";
        const std::string body = k.dump();
        write_file(dir_.file("folder.gltf"), std::vector<std::uint8_t>(body.begin(), body.end()));
        expect_fails(dir_.file("folder.gltf"), field == std::string("images") ? "is not an image file" : "cannot read glTF");
    }
    // A sampler that is not there, and positions that are not finite numbers.
    {
        nlohmann::json k = j;
        k["textures"][0]["sampler"] = 7;
        const std::string body = k.dump();
        write_file(dir_.file("sampler.gltf"), std::vector<std::uint8_t>(body.begin(), body.end()));
        expect_fails(dir_.file("sampler.gltf"), "sampler 7 does not exist");
    }
    expect_fails((kSamples / "BoxWithInfinites-glTF-Binary/BoxWithInfinites.glb").string(), "position is not a finite number");
    // Not a scene file at all.
    write_file(dir_.file("scene.fbx"), std::vector<std::uint8_t>(10, 1));
    expect_fails(dir_.file("scene.fbx"), "not an OBJ (.obj) or glTF 2.0");
}

// One image under two samplers: where one repeats (its cell's padding wraps around) and the other
// clamps, each gets a cell of its own, or the clamped one would show the opposite edge at its rim;
// under the same sampler they share one. Material extensions and vertex colours the atlas does not
// keep are named.
TEST_F(GltfAtlas, AnImageRepeatedAndClampedGetsTwoCells) {
    const float pos[4][3] = {{-1, 0, 1}, {1, 0, 1}, {1, 0, -1}, {-1, 0, -1}};
    const float uv[4][2] = {{0, 2}, {2, 2}, {2, 0}, {0, 0}};
    const std::uint16_t idx[6] = {0, 1, 2, 0, 2, 3};
    const auto primitive = [](int material) {
        return nlohmann::json{{"primitives", {{{"attributes", {{"POSITION", 0}, {"TEXCOORD_0", 1}}}, {"indices", 2}, {"material", material}}}}};
    };
    auto scene = [&](int second_wrap) {
        nlohmann::json j = {
            {"asset", {{"version", "2.0"}}},
            {"scene", 0},
            {"scenes", {{{"nodes", {0, 1}}}}},
            {"nodes", {{{"mesh", 0}}, {{"mesh", 1}, {"translation", {3, 0, 0}}}}},
            {"meshes", {primitive(0), primitive(1)}},
            {"materials",
             {{{"name", "tiled"}, {"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 0}}}}}},
              {{"name", "edge"}, {"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 1}}}}}}}},
            {"samplers", {{{"wrapS", 10497}, {"wrapT", 10497}}, {{"wrapS", second_wrap}, {"wrapT", second_wrap}}}},
            {"textures", {{{"source", 0}, {"sampler", 0}}, {{"source", 0}, {"sampler", 1}}}},
            {"images", {{{"uri", solid_png_uri({200, 40, 30})}}}},
            {"accessors",
             {{{"bufferView", 0}, {"componentType", 5126}, {"count", 4}, {"type", "VEC3"}, {"min", {-1, 0, -1}}, {"max", {1, 0, 1}}},
              {{"bufferView", 1}, {"componentType", 5126}, {"count", 4}, {"type", "VEC2"}},
              {{"bufferView", 2}, {"componentType", 5123}, {"count", 6}, {"type", "SCALAR"}}}}};
        j.update(quad_buffers(pos, uv, idx));
        return j;
    };
    // Built without -q: the summary says how many images (cells) were packed.
    auto build_loud = [&](const nlohmann::json& j, const std::string& name) {
        const std::string file = dir_.file(name + ".gltf"), text = j.dump();
        write_file(file, std::vector<std::uint8_t>(text.begin(), text.end()));
        return run_tessera("build --codec zstd --atlas " + q(file) + " -o " + q(dir_.file("out/" + name + ".tsr")) + " --obj-out " +
                           q(dir_.file("out/" + name + ".obj")));
    };
    const RunResult clamped = build_loud(scene(33071), "clamped");
    ASSERT_EQ(clamped.exit_code, 0) << clamped.out;
    EXPECT_NE(clamped.out.find(" from 2 images "), std::string::npos) << clamped.out;
    const RunResult repeated = build_loud(scene(10497), "repeated");
    ASSERT_EQ(repeated.exit_code, 0) << repeated.out;
    EXPECT_NE(repeated.out.find(" from 1 images "), std::string::npos) << repeated.out;
    EXPECT_EQ(repeated.out.find("warning"), std::string::npos) << repeated.out;

    nlohmann::json extras = scene(10497);
    extras["materials"][1]["extensions"] = {{"KHR_materials_sheen", {{"sheenColorFactor", {1, 1, 1}}}}};
    extras["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"] = 0;
    const RunResult warned = build_json(extras, "extras");
    ASSERT_EQ(warned.exit_code, 0) << warned.out;
    EXPECT_NE(warned.out.find("warning: material 'edge': KHR_materials_sheen is not kept"), std::string::npos) << warned.out;
    EXPECT_NE(warned.out.find("warning: 1 primitives' vertex colours (COLOR_0) are not kept"), std::string::npos) << warned.out;
}

// glTF's alpha modes: an image only OPAQUE materials draw loses its alpha (glTF ignores it there,
// and the viewer would cut holes); MASK keeps it for cut-outs. The scene: BoxTextured with its image
// replaced by one with a transparent half.
TEST_F(GltfAtlas, OpaqueMaterialsDropTheirTexturesAlpha) {
    const int W = 16, H = 16;
    std::vector<std::uint8_t> rgba(std::size_t(W) * H * 4);
    for (int i = 0; i < W * H; ++i) {
        rgba[std::size_t(i) * 4] = 200;
        rgba[std::size_t(i) * 4 + 3] = (i % W) < W / 2 ? 0 : 255;
    }
    auto png = storage::encode_png({W, H, 4, storage::SampleType::u8, storage::ColourSpace::srgb, rgba});
    ASSERT_TRUE(png.ok());
    auto text = read_file((kSamples / "BoxTextured-glTF-Embedded/BoxTextured.gltf").string());
    nlohmann::json j = nlohmann::json::parse(std::string(text.begin(), text.end()));
    j["images"][0]["uri"] = "data:image/png;base64," + base64(*png);
    for (const std::string mode : {"OPAQUE", "MASK"}) {
        j["materials"][0]["alphaMode"] = mode;
        const std::string scene = dir_.file(mode + ".gltf"), body = j.dump();
        write_file(scene, std::vector<std::uint8_t>(body.begin(), body.end()));
        const RunResult r = build(scene, mode);
        ASSERT_EQ(r.exit_code, 0) << r.out;
        auto reader = storage::StoreReader::open(dir_.file("out/" + mode + ".tsr"));
        ASSERT_TRUE(reader.ok()) << reader.error().message;
        EXPECT_EQ((*reader)->info().channels, mode == "OPAQUE" ? 3u : 4u) << mode;
        EXPECT_EQ((*reader)->info().has_alpha, mode == "MASK") << mode;
    }
}

// `tessera view --store` with no --scene draws the atlas scene that travels with the store: the OBJ
// beside the store file, and over gRPC the one the server reads beside its file; a rebuilt store
// whose OBJ was not rewritten has no scene (the OBJ names the store's id), and the terrain is drawn.
TEST_F(GltfAtlas, TheSceneTravelsWithItsStore) {
    const std::string store = dir_.file("out/card.tsr");
    ASSERT_EQ(build((kSamples / "textureTransform/TextureTransformTest.gltf").string(), "card").exit_code, 0);
    auto scene_line = [](const std::string& out) {
        const auto at = out.find("\nscene ");
        return at == std::string::npos ? std::string("(no scene line)") : out.substr(at + 1, out.find('\n', at + 1) - at - 1);
    };
    auto view = [&](const std::string& what, const std::string& extra = "") {
        const RunResult r = run_tessera("view --store " + q(what) + " --headless --size 96x64 --frames 6 --no-warmup " + extra);
        EXPECT_EQ(r.exit_code, 0) << r.out;
        return scene_line(r.out);
    };
    const std::string travelling = "scene         atlas, travelling with the store (57 triangles, 12 objects)";
    // `tessera inspect` names it too.
    const RunResult inspected = run_tessera("inspect " + q(store));
    EXPECT_NE(inspected.out.find("scene      " + dir_.file("out/card.obj")), std::string::npos) << inspected.out;
    EXPECT_EQ(view(store), travelling);
    EXPECT_EQ(view(store, "--scene terrain"), "scene         terrain");
    {
        ServerProcess server({"--store-dir", dir_.file("out")}, dir_.file("server.log"));
        ASSERT_TRUE(server.running()) << server.log();
        EXPECT_EQ(view("grpc://" + server.grpc_address() + "/card"), travelling) << server.log();
    }
    // The store rebuilt (another codec: another id) without its OBJ: the old OBJ is not its scene.
    const RunResult r = run_tessera("build -q --codec jpeg --atlas " + q((kSamples / "textureTransform/TextureTransformTest.gltf").string()) +
                                    " -o " + q(store) + " --obj-out " + q(dir_.file("other.obj")));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_EQ(view(store), "scene         terrain");
    EXPECT_EQ(run_tessera("inspect " + q(store)).out.find("scene "), std::string::npos);
    ServerProcess server({"--store-dir", dir_.file("out")}, dir_.file("server2.log"));
    ASSERT_TRUE(server.running()) << server.log();
    EXPECT_EQ(view("grpc://" + server.grpc_address() + "/card"), "scene         terrain") << server.log();
}

}  // namespace
