// `tessera build --atlas` on the generated gallery scene: the store and the rewritten OBJ exist and
// load, every sampled texel of the atlas at a rewritten texture coordinate equals the original
// texture's texel at the original coordinate (lossless zstd tiles), padding repeats the edges, the
// build is deterministic, and bad input fails cleanly leaving nothing behind.
#include <gtest/gtest.h>
#include <tiny_obj_loader.h>

#include <array>
#include <cmath>
#include <filesystem>
#include <map>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "tessera/scene/scene.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/store_reader.hpp"
#include "atlas_test_util.hpp"
#include "test_util.hpp"

namespace {

namespace fs = std::filesystem;
namespace storage = tessera::storage;
using tessera::test::read_file;
using tessera::test::run_tessera;
using tessera::test::RunResult;
using tessera::test::ScratchDir;
using tessera::test::write_file;
using tessera::test::AtlasTexels;
using tessera::test::entries;
using tessera::test::expect_one_line_error;
using tessera::test::q;
using tessera::test::read_png;
using tessera::test::Rgb8Image;

tinyobj::ObjReader read_obj(const std::string& path) {
    tinyobj::ObjReader r;
    tinyobj::ObjReaderConfig config;
    config.triangulate = true;
    EXPECT_TRUE(r.ParseFromFile(path, config)) << r.Error();
    return r;
}

class AtlasBuild : public ::testing::Test {
protected:
    void SetUp() override {
        gallery_ = dir_.file("gallery");
        const RunResult src = run_tessera("source scene:gallery -q -o " + q(gallery_));
        ASSERT_EQ(src.exit_code, 0) << src.out;
        fs::create_directory(dir_.file("out"));
    }
    ScratchDir dir_;
    std::string gallery_;
};

TEST_F(AtlasBuild, GalleryTexelsSurviveThePacking) {
    const std::string store = dir_.file("out/atlas.tsr"), obj = dir_.file("out/atlas.obj");
    const RunResult r = run_tessera("build -q --codec zstd --atlas " + q(gallery_ + "/gallery.obj") + " -o " + q(store) +
                                    " --obj-out " + q(obj));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_EQ(entries(dir_.file("out")), (std::set<std::string>{"atlas.tsr", "atlas.obj"}));
    auto reader = storage::StoreReader::open(store);
    ASSERT_TRUE(reader.ok()) << reader.error().message;
    const storage::StoreInfo info = (*reader)->info();
    EXPECT_EQ(info.codec, tessera::Codec::zstd);
    EXPECT_EQ(info.channels, 3u);

    // The rewritten OBJ loads as the atlas scene: one chunk per object, every texel inside the atlas.
    auto scene = tessera::scene::load_obj_scene(obj, info.width, info.height);
    ASSERT_TRUE(scene.ok()) << scene.error().message;
    EXPECT_EQ(scene->name, "atlas");
    EXPECT_EQ(scene->chunks.size(), 9u);  // floor, four walls, three boxes, the plinth
    std::size_t triangles = 0;
    for (const auto& c : scene->chunks) {
        triangles += c.indices.size() / 3;
        for (const auto& v : c.vertices) {
            EXPECT_GE(c.texel_origin[0] + double(v.texel[0]), 0.0);
            EXPECT_LE(c.texel_origin[0] + double(v.texel[0]), double(info.width));
            EXPECT_LE(c.texel_origin[1] + double(v.texel[1]), double(info.height));
        }
    }
    EXPECT_EQ(triangles, 50u);
    // Z up: the floor at z = 0, the walls up to 4; x and y span the room.
    EXPECT_NEAR(scene->bounds_min[2], 0.0, 1e-6);
    EXPECT_NEAR(scene->bounds_max[2], 4.0, 1e-6);
    EXPECT_NEAR(scene->bounds_max[0] - scene->bounds_min[0], 20.0, 1e-6);
    EXPECT_NEAR(scene->bounds_max[1] - scene->bounds_min[1], 12.0, 1e-6);
    // A store of another size is refused (the OBJ names its atlas size).
    EXPECT_FALSE(tessera::scene::load_obj_scene(obj, info.width + 1, info.height).ok());

    // Texel by texel: original (texture, uv with v up) against atlas (rewritten uv, v down).
    const tinyobj::ObjReader orig = read_obj(gallery_ + "/gallery.obj");
    const tinyobj::ObjReader packed = read_obj(obj);
    ASSERT_EQ(orig.GetShapes().size(), packed.GetShapes().size());
    AtlasTexels atlas(*reader);
    std::map<std::string, Rgb8Image> textures;
    std::set<std::string> repeating;  // textures with coordinates outside [0, 1]
    for (const auto& sh : orig.GetShapes())
        for (std::size_t i = 0; i < sh.mesh.indices.size(); ++i) {
            const int t = sh.mesh.indices[i].texcoord_index, m = sh.mesh.material_ids[i / 3];
            if (t < 0 || m < 0) continue;
            for (int a = 0; a < 2; ++a) {
                const double c = orig.GetAttrib().texcoords[2 * std::size_t(t) + a];
                if (c < -1e-5 || c > 1 + 1e-5) repeating.insert(orig.GetMaterials()[std::size_t(m)].diffuse_texname);
            }
        }
    EXPECT_EQ(repeating.size(), 1u);  // the box a whole repeat away
    std::size_t compared = 0, solid = 0, edges = 0;
    for (std::size_t s = 0; s < orig.GetShapes().size(); ++s) {
        const auto& om = orig.GetShapes()[s].mesh;
        const auto& pm = packed.GetShapes()[s].mesh;
        ASSERT_EQ(om.indices.size(), pm.indices.size()) << s;
        for (std::size_t f = 0; f < om.num_face_vertices.size(); ++f) {
            const auto& mat = orig.GetMaterials()[static_cast<std::size_t>(om.material_ids[f])];
            const Rgb8Image* tex = nullptr;
            if (!mat.diffuse_texname.empty()) {
                auto& t = textures[mat.diffuse_texname];
                if (t.width == 0) t = read_png(gallery_ + "/" + mat.diffuse_texname);
                ASSERT_GT(t.width, 0);
                tex = &t;
            }
            double ouv[3][2], puv[3][2];
            for (int k = 0; k < 3; ++k) {
                const auto oi = om.indices[3 * f + k], pi = pm.indices[3 * f + k];
                for (int a = 0; a < 2; ++a) {
                    ouv[k][a] = orig.GetAttrib().texcoords[2 * std::size_t(oi.texcoord_index) + a];
                    puv[k][a] = packed.GetAttrib().texcoords[2 * std::size_t(pi.texcoord_index) + a];
                }
            }
            // The triangle's repeat (the gallery has one box a whole repeat away from [0, 1]).
            const double ru = std::floor(std::min({ouv[0][0], ouv[1][0], ouv[2][0]}) + 1e-9);
            const double rv = std::floor(std::min({ouv[0][1], ouv[1][1], ouv[2][1]}) + 1e-9);
            // Interior points by barycentric weights.
            for (const auto& w : {std::array<double, 3>{0.3137, 0.3331, 0.3532}, {0.6123, 0.1771, 0.2106}, {0.1913, 0.6247, 0.184},
                                  {0.2209, 0.1688, 0.6103}, {0.4471, 0.4391, 0.1138}, {0.0917, 0.4626, 0.4457},
                                  {0.8013, 0.1039, 0.0948}, {0.1219, 0.0811, 0.797}}) {
                double ou = 0, ov = 0, pu = 0, pv = 0;
                for (int k = 0; k < 3; ++k) {
                    ou += w[k] * ouv[k][0];
                    ov += w[k] * ouv[k][1];
                    pu += w[k] * puv[k][0];
                    pv += w[k] * puv[k][1];
                }
                const double ax = pu * info.width, ay = pv * info.height;
                if (ax - std::floor(ax) < 0.02 || std::ceil(ax) - ax < 0.02 || ay - std::floor(ay) < 0.02 || std::ceil(ay) - ay < 0.02)
                    continue;  // on a texel edge: either texel is right
                const auto got = atlas.at(static_cast<std::uint32_t>(ax), static_cast<std::uint32_t>(ay));
                if (!tex) {
                    const std::array<std::uint8_t, 3> kd = {
                        static_cast<std::uint8_t>(std::lround(std::clamp(double(mat.diffuse[0]), 0.0, 1.0) * 255)),
                        static_cast<std::uint8_t>(std::lround(std::clamp(double(mat.diffuse[1]), 0.0, 1.0) * 255)),
                        static_cast<std::uint8_t>(std::lround(std::clamp(double(mat.diffuse[2]), 0.0, 1.0) * 255))};
                    EXPECT_EQ(got, kd) << mat.name;
                    ++solid;
                    continue;
                }
                // Original texel: OBJ's v is up, the image's row 0 is its top.
                const double tx = (ou - ru) * tex->width, ty = (1.0 - (ov - rv)) * tex->height;
                const int ix = static_cast<int>(std::floor(tx)), iy = static_cast<int>(std::floor(ty));
                ASSERT_GE(ix, 0);
                ASSERT_LT(ix, tex->width);
                ASSERT_GE(iy, 0);
                ASSERT_LT(iy, tex->height);
                EXPECT_EQ(got, tex->at(ix, iy)) << mat.name << " face " << f << " texel " << ix << "," << iy;
                ++compared;
            }
            // Padding: left of a texture's u = 0 edge, the atlas repeats the edge column (16 texels);
            // a texture used outside [0, 1] (a repeating one) continues around instead.
            if (tex && repeating.count(mat.diffuse_texname) == 0) {
                const double cy = (puv[0][1] + puv[1][1] + puv[2][1]) / 3 * info.height;
                for (int k = 0; k < 3; ++k) {
                    if (ouv[k][0] - ru != 0.0) continue;
                    const auto x_edge = static_cast<std::uint32_t>(std::lround(puv[k][0] * info.width));
                    const auto y_row = static_cast<std::uint32_t>(std::floor(cy));
                    ASSERT_GE(x_edge, 16u);
                    const auto edge = atlas.at(x_edge, y_row);
                    for (std::uint32_t d = 1; d <= 16; ++d) EXPECT_EQ(atlas.at(x_edge - d, y_row), edge) << mat.name;
                    ++edges;
                    break;
                }
            }
        }
    }
    EXPECT_GT(compared, 200u);
    EXPECT_GT(solid, 10u);
    EXPECT_GT(edges, 10u);

    // Deterministic: the same input gives the same bytes.
    fs::create_directory(dir_.file("again"));
    const std::string store2 = dir_.file("again/atlas.tsr"), obj2 = dir_.file("again/atlas.obj");
    const RunResult r2 = run_tessera("build -q --codec zstd --atlas " + q(gallery_ + "/gallery.obj") + " -o " + q(store2) +
                                     " --obj-out " + q(obj2));
    ASSERT_EQ(r2.exit_code, 0) << r2.out;
    EXPECT_TRUE(read_file(store) == read_file(store2));
    EXPECT_TRUE(read_file(obj) == read_file(obj2));
}

TEST_F(AtlasBuild, DefaultsAndSummary) {
    // --obj-out defaults to the store's name with .obj; the default codec (JPEG) works too.
    const RunResult r = run_tessera("build --atlas " + q(gallery_ + "/gallery.obj") + " -o " + q(dir_.file("out/a.tsr")));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_NE(r.out.find("9 images"), std::string::npos) << r.out;
    EXPECT_EQ(entries(dir_.file("out")), (std::set<std::string>{"a.tsr", "a.obj"}));
    EXPECT_EQ(run_tessera("verify " + q(dir_.file("out/a.tsr"))).exit_code, 0);
}

TEST_F(AtlasBuild, BadInputFailsAndLeavesNothing) {
    const std::string out = dir_.file("out");
    const std::string args = " -o " + q(out + "/atlas.tsr") + " --obj-out " + q(out + "/atlas.obj");
    auto expect_fails = [&](const std::string& cmd, const std::string& mention) {
        const RunResult r = run_tessera(cmd);
        expect_one_line_error(r);
        EXPECT_NE(r.out.find(mention), std::string::npos) << r.out;
        EXPECT_TRUE(entries(out).empty()) << cmd;
    };
    // A missing OBJ.
    expect_fails("build --atlas " + q(dir_.file("nosuch.obj")) + args, "nosuch.obj");
    // A missing texture: the message names the material and the file.
    fs::copy(gallery_, dir_.file("g2"), fs::copy_options::recursive);
    fs::remove(dir_.file("g2/textures/box_1.png"));
    expect_fails("build --atlas " + q(dir_.file("g2/gallery.obj")) + args, "box_1");
    // An unreadable image.
    write_file(dir_.file("g2/textures/box_1.png"), std::vector<std::uint8_t>(100, 0x42));
    expect_fails("build --atlas " + q(dir_.file("g2/gallery.obj")) + args, "box_1");
    // A truncated image: readable header, broken data (fails while the store is being built).
    const auto png = read_file(gallery_ + "/textures/floor.png");
    write_file(dir_.file("g2/textures/box_1.png"), read_file(gallery_ + "/textures/box_1.png"));
    write_file(dir_.file("g2/textures/floor.png"), std::vector<std::uint8_t>(png.begin(), png.begin() + png.size() / 3));
    expect_fails("build --atlas " + q(dir_.file("g2/gallery.obj")) + args, "floor");
    // A missing material library.
    fs::remove(dir_.file("g2/gallery.mtl"));
    expect_fails("build --atlas " + q(dir_.file("g2/gallery.obj")) + args, "gallery.obj");
    // Flags: both an input and --atlas, --obj-out without --atlas, the same file twice, a bad alignment.
    EXPECT_EQ(run_tessera("build procedural:terrain:64 --atlas " + q(gallery_ + "/gallery.obj") + args).exit_code, 2);
    EXPECT_EQ(run_tessera("build procedural:terrain:64 -o " + q(out + "/a.tsr") + " --obj-out " + q(out + "/a.obj")).exit_code, 2);
    expect_one_line_error(run_tessera("build --atlas " + q(gallery_ + "/gallery.obj") + " -o " + q(out + "/x") + " --obj-out " + q(out + "/x")));
    expect_one_line_error(run_tessera("build --atlas " + q(gallery_ + "/gallery.obj") + " -o " + q(out + "/x.tsr") + " --obj-out " +
                                      q(gallery_ + "/gallery.obj")));
    EXPECT_EQ(run_tessera("build --atlas " + q(gallery_ + "/gallery.obj") + args + " --atlas-align 48").exit_code, 2);
    EXPECT_TRUE(entries(out).empty());
    // The gallery generator refuses a folder that is not empty.
    expect_one_line_error(run_tessera("source scene:gallery -o " + q(gallery_)));
    expect_one_line_error(run_tessera("source scene:nosuch -o " + q(dir_.file("x"))));
    EXPECT_FALSE(fs::exists(dir_.file("x")));
    // "DIR/" is the folder DIR, as docs/atlas.md writes it, new or empty.
    EXPECT_EQ(run_tessera("source scene:gallery -q -o " + q(dir_.file("g3") + "/")).exit_code, 0);
    EXPECT_TRUE(fs::is_regular_file(dir_.file("g3/gallery.obj")));
    fs::create_directory(dir_.file("g4"));
    EXPECT_EQ(run_tessera("source scene:gallery -q -o " + q(dir_.file("g4") + "//")).exit_code, 0);
    EXPECT_TRUE(fs::is_regular_file(dir_.file("g4/gallery.mtl")));
}

}  // namespace

namespace {

// The triangle of `mesh` (rewritten OBJ, Z up after load) whose XZ projection holds (x, z), and
// the point's barycentric weights in it.
bool find_piece(const tinyobj::ObjReader& r, double x, double z, std::array<double, 2>& uv) {
    const auto& at = r.GetAttrib();
    for (const auto& sh : r.GetShapes()) {
        const auto& idx = sh.mesh.indices;
        for (std::size_t f = 0; f + 2 < idx.size(); f += 3) {
            double px[3], pz[3];
            for (int k = 0; k < 3; ++k) {
                px[k] = at.vertices[3 * std::size_t(idx[f + k].vertex_index)];
                pz[k] = at.vertices[3 * std::size_t(idx[f + k].vertex_index) + 2];
            }
            const double d = (pz[1] - pz[2]) * (px[0] - px[2]) + (px[2] - px[1]) * (pz[0] - pz[2]);
            if (std::abs(d) < 1e-12) continue;
            const double w0 = ((pz[1] - pz[2]) * (x - px[2]) + (px[2] - px[1]) * (z - pz[2])) / d;
            const double w1 = ((pz[2] - pz[0]) * (x - px[2]) + (px[0] - px[2]) * (z - pz[2])) / d;
            const double w2 = 1 - w0 - w1;
            if (w0 < 1e-9 || w1 < 1e-9 || w2 < 1e-9) continue;
            uv = {0, 0};
            const double w[3] = {w0, w1, w2};
            for (int k = 0; k < 3; ++k)
                for (int a = 0; a < 2; ++a) uv[a] += w[k] * at.texcoords[2 * std::size_t(idx[f + k].texcoord_index) + a];
            return true;
        }
    }
    return false;
}

}  // namespace

// MTL keywords in another case ("map_kd", as some exporters write) name the texture as
// "map_Kd" does; a map_Kd that names no file is an error, not a silently solid tile.
TEST_F(AtlasBuild, MapKdInAnyCaseIsTheTextureAndAnEmptyOneIsAnError) {
    const std::string obj =
        "mtllib s.mtl\nv 0 0 0\nv 4 0 0\nv 4 0 -4\nv 0 0 -4\nvt -1.25 -0.5\nvt 2.5 -0.5\nvt 2.5 1.75\nvt -1.25 1.75\n"
        "usemtl tiles\nf 1/1 2/2 3/3 4/4\n";
    auto scene = [&](const std::string& name, const std::string& mtl) {
        fs::create_directory(dir_.file(name));
        fs::copy_file(gallery_ + "/textures/box_2.png", dir_.file(name + "/tile.png"));
        write_file(dir_.file(name + "/s.mtl"), std::vector<std::uint8_t>(mtl.begin(), mtl.end()));
        write_file(dir_.file(name + "/s.obj"), std::vector<std::uint8_t>(obj.begin(), obj.end()));
        return run_tessera("build --codec zstd --atlas " + q(dir_.file(name + "/s.obj")) + " -o " + q(dir_.file(name + "/out.tsr")) +
                           " --obj-out " + q(dir_.file(name + "/out.obj")));
    };
    const RunResult lower = scene("lower", "newmtl tiles\nmap_kd -s 1 1 1 tile.png\n");
    ASSERT_EQ(lower.exit_code, 0) << lower.out;
    EXPECT_NE(lower.out.find("1 repeating textures"), std::string::npos) << "the texture was not used:\n" << lower.out;

    for (const char* line : {"map_Kd\n", "map_Kd   \r\n", "MAP_KD -s 1 1 1\n"}) {
        SCOPED_TRACE(line);
        fs::remove_all(dir_.file("empty"));
        const RunResult empty = scene("empty", std::string("newmtl tiles\nKd 0.5 0.5 0.5\n") + line);
        EXPECT_NE(empty.exit_code, 0) << empty.out;
        EXPECT_NE(empty.out.find("material 'tiles' has a"), std::string::npos) << empty.out;
        EXPECT_NE(empty.out.find("names no texture file"), std::string::npos) << empty.out;
        EXPECT_FALSE(fs::exists(dir_.file("empty/out.tsr")));
    }
}

// Real exports tile brick and concrete across faces (SketchUp writes u from -721 to 316): such
// triangles are cut where the texture repeats, each piece samples one copy, and the texture's
// atlas padding continues it around (docs/atlas.md, "Repeating textures"). Also: a colour-only
// material, an n-gon, several objects and groups.
TEST_F(AtlasBuild, RepeatingTexturesAreCutAtTheirRepeats) {
    fs::create_directory(dir_.file("rep"));
    fs::copy_file(gallery_ + "/textures/box_2.png", dir_.file("rep/tile.png"));
    const std::string mtl = "newmtl tiles\nmap_Kd tile.png\nnewmtl paint\nKd 0.8 0.2 0.1\n";
    // A 4 x 4 floor quad whose texture repeats from u -1.25 to 2.5 and v -0.5 to 1.75; a pentagon
    // (an n-gon) of paint beside it, in another object and group.
    const std::string obj =
        "mtllib rep.mtl\n"
        "o floor\ng floor\nv 0 0 0\nv 4 0 0\nv 4 0 -4\nv 0 0 -4\nvt -1.25 -0.5\nvt 2.5 -0.5\nvt 2.5 1.75\nvt -1.25 1.75\n"
        "usemtl tiles\nf 1/1 2/2 3/3 4/4\n"
        "o sign\ng sign\nv 5 0 0\nv 7 0 0\nv 7.5 1 -1\nv 6 2 -2\nv 4.5 1 -1\nusemtl paint\nf 5 6 7 8 9\n";
    write_file(dir_.file("rep/rep.mtl"), std::vector<std::uint8_t>(mtl.begin(), mtl.end()));
    write_file(dir_.file("rep/rep.obj"), std::vector<std::uint8_t>(obj.begin(), obj.end()));
    const std::string store = dir_.file("out/rep.tsr"), out_obj = dir_.file("out/rep.obj");
    const RunResult r = run_tessera("build --codec zstd --atlas " + q(dir_.file("rep/rep.obj")) + " -o " + q(store) +
                                    " --obj-out " + q(out_obj));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_NE(r.out.find("1 repeating textures"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("up axis y (auto"), std::string::npos) << r.out;

    auto reader = storage::StoreReader::open(store);
    ASSERT_TRUE(reader.ok());
    const storage::StoreInfo info = (*reader)->info();
    auto scene = tessera::scene::load_obj_scene(out_obj, info.width, info.height);
    ASSERT_TRUE(scene.ok()) << scene.error().message;
    std::size_t triangles = 0;
    for (const auto& c : scene->chunks) triangles += c.indices.size() / 3;
    // The quad's two triangles over 4 x 3 repeats, cut into pieces; the pentagon as 3 triangles.
    EXPECT_GT(triangles, 20u);

    // Every point of the floor samples the texel GL_REPEAT would: texture texel (frac(u), 1 - frac(v)).
    const Rgb8Image tex = read_png(dir_.file("rep/tile.png"));
    ASSERT_GT(tex.width, 0);
    const tinyobj::ObjReader packed = read_obj(out_obj);
    AtlasTexels atlas(*reader);
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> pos(0.0, 4.0);
    std::size_t compared = 0;
    for (int i = 0; i < 2000; ++i) {
        const double x = pos(rng), z = -pos(rng);
        const double u = -1.25 + 3.75 * (x / 4.0), v = -0.5 + 2.25 * (-z / 4.0);
        const double tx = (u - std::floor(u)) * tex.width, ty = (1.0 - (v - std::floor(v))) * tex.height;
        if (tx - std::floor(tx) < 0.02 || std::ceil(tx) - tx < 0.02 || ty - std::floor(ty) < 0.02 || std::ceil(ty) - ty < 0.02)
            continue;  // on a texel edge
        std::array<double, 2> puv{};
        ASSERT_TRUE(find_piece(packed, x, z, puv)) << x << "," << z;
        const double ax = puv[0] * info.width, ay = puv[1] * info.height;
        if (ax - std::floor(ax) < 0.02 || std::ceil(ax) - ax < 0.02 || ay - std::floor(ay) < 0.02 || std::ceil(ay) - ay < 0.02)
            continue;
        EXPECT_EQ(atlas.at(std::uint32_t(ax), std::uint32_t(ay)), tex.at(int(tx), int(ty))) << "at " << x << "," << z;
        ++compared;
    }
    EXPECT_GT(compared, 1500u);

    // Watertight: every edge of the floor's pieces inside the quad is shared by two pieces with
    // the same two corners (a crack or a T-junction would leave an interior edge used once).
    {
        std::map<std::pair<int, int>, int> edges;
        const auto& at = packed.GetAttrib();
        for (const auto& sh : packed.GetShapes()) {
            if (sh.name != "floor") continue;
            const auto& ix = sh.mesh.indices;
            for (std::size_t f = 0; f + 2 < ix.size(); f += 3)
                for (int k = 0; k < 3; ++k) {
                    const int a = ix[f + k].vertex_index, b = ix[f + (k + 1) % 3].vertex_index;
                    ++edges[{std::min(a, b), std::max(a, b)}];
                }
        }
        auto on_rim = [&](int v) {
            const double x = at.vertices[3 * std::size_t(v)], z = at.vertices[3 * std::size_t(v) + 2];
            return std::abs(x) < 1e-6 || std::abs(x - 4) < 1e-6 || std::abs(z) < 1e-6 || std::abs(z + 4) < 1e-6;
        };
        std::size_t interior_once = 0;
        for (const auto& [e, n] : edges) {
            EXPECT_LE(n, 2) << "edge used by " << n << " pieces";
            if (n == 1 && !(on_rim(e.first) && on_rim(e.second))) ++interior_once;
        }
        EXPECT_EQ(interior_once, 0u) << "cracks or T-junctions inside the floor";
        EXPECT_GT(edges.size(), 40u);
    }

    // The padding wraps: left of the image, its right columns; above it, its bottom rows.
    std::uint32_t left = info.width, top = info.height;  // the image's top-left texel: the smallest packed texel
    for (const auto& sh : packed.GetShapes())
        if (sh.name == "floor")
            for (const auto& ix : sh.mesh.indices) {
                left = std::min(left, std::uint32_t(std::lround(packed.GetAttrib().texcoords[2 * std::size_t(ix.texcoord_index)] * info.width)));
                top = std::min(top, std::uint32_t(std::lround(packed.GetAttrib().texcoords[2 * std::size_t(ix.texcoord_index) + 1] * info.height)));
            }
    ASSERT_GE(left, 16u);
    ASSERT_GE(top, 16u);
    for (std::uint32_t d = 1; d <= 16; ++d)
        for (std::uint32_t k : {0u, 7u, 31u}) {
            EXPECT_EQ(atlas.at(left - d, top + k), tex.at(tex.width - int(d), int(k))) << "left padding " << d;
            EXPECT_EQ(atlas.at(left + k, top - d), tex.at(int(k), tex.height - int(d))) << "top padding " << d;
        }
    // The paint: its Kd everywhere the sign samples.
    for (const auto& sh : packed.GetShapes())
        if (sh.name == "sign") {
            EXPECT_EQ(sh.mesh.indices.size(), 9u);  // the pentagon as three triangles
            const auto t = sh.mesh.indices[0].texcoord_index;
            const auto got = atlas.at(std::uint32_t(packed.GetAttrib().texcoords[2 * std::size_t(t)] * info.width),
                                      std::uint32_t(packed.GetAttrib().texcoords[2 * std::size_t(t) + 1] * info.height));
            EXPECT_EQ(got, (std::array<std::uint8_t, 3>{204, 51, 26}));
        }
}

// Z-up exports (SketchUp, CAD) are detected by their shape or named with --up, and the rewritten
// OBJ says so; the scene comes out with the right side up either way.
TEST_F(AtlasBuild, UpAxisIsDetectedOrGiven) {
    fs::create_directory(dir_.file("site"));
    fs::copy_file(gallery_ + "/textures/box_2.png", dir_.file("site/t.png"));
    const std::string mtl = "newmtl t\nmap_Kd t.png\n";
    // A flat 100 x 80 site (z up) with a 3-unit post standing on it.
    const std::string obj = "mtllib s.mtl\nv 0 0 0\nv 100 0 0\nv 100 80 0\nv 0 80 0\nv 50 40 0\nv 51 40 0\nv 50 40 3\n"
                            "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl t\nf 1/1 2/2 3/3 4/4\nf 5/1 6/2 7/3\n";
    write_file(dir_.file("site/s.mtl"), std::vector<std::uint8_t>(mtl.begin(), mtl.end()));
    write_file(dir_.file("site/s.obj"), std::vector<std::uint8_t>(obj.begin(), obj.end()));
    for (const std::string up : {"", " --up z", " --up y"}) {
        SCOPED_TRACE(up);
        const std::string store = dir_.file("out/s.tsr"), out_obj = dir_.file("out/s.obj");
        const RunResult r = run_tessera("build -q --atlas " + q(dir_.file("site/s.obj")) + " -o " + q(store) + " --obj-out " + q(out_obj) + up);
        ASSERT_EQ(r.exit_code, 0) << r.out;
        auto reader = storage::StoreReader::open(store);
        ASSERT_TRUE(reader.ok());
        auto scene = tessera::scene::load_obj_scene(out_obj, (*reader)->info().width, (*reader)->info().height);
        ASSERT_TRUE(scene.ok());
        const double height = scene->bounds_max[2] - scene->bounds_min[2];
        if (up == " --up y") {
            EXPECT_NEAR(height, 80.0, 1e-3);  // told y: the site stands on its edge
        } else {
            EXPECT_NEAR(height, 3.0, 1e-3);  // the post stands up
            EXPECT_NEAR(scene->bounds_max[0] - scene->bounds_min[0], 100.0, 1e-3);
            EXPECT_NEAR(scene->bounds_max[1] - scene->bounds_min[1], 80.0, 1e-3);
        }
    }
    expect_one_line_error(run_tessera("build --atlas " + q(dir_.file("site/s.obj")) + " -o " + q(dir_.file("out/x.tsr")) + " --up x"));
}
