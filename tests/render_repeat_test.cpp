// Repeating textures of an OBJ scene through the atlas (docs/atlas.md, "Repeating textures"):
// `tessera build --atlas` cuts triangles at every repeat and pads each repeating texture's cell
// toroidally; the VT then draws the scene from one store. The reference draws the original OBJ,
// one material at a time, from each original texture with GL_REPEAT and its own mip chain, with
// the same LoD rule and filter. Every view: PSNR over the scene, and the error on the pixels that
// a repeat line crosses (where a wrong padding would show as a seam) no worse than elsewhere.
// Also cut-outs (docs/atlas.md, "Alpha"): a texture's alpha kept by the atlas and tested by the VT.
#include <gtest/gtest.h>
#include <tiny_obj_loader.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include "cpu_reference.hpp"
#include "ground_ray.hpp"
#include "reference_pyramid.hpp"
#include "render_util.hpp"
#include "render_vt.hpp"
#include "tessera/client/gl/reference_renderer.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "tessera/client/measures.hpp"
#include "tessera/scene/scene.hpp"
#include "tessera/storage/png_encode.hpp"
#include "tessera/storage/store_reader.hpp"
#include "test_util.hpp"

namespace {

namespace gl = tessera::client::gl;
namespace sc = tessera::scene;
namespace st = tessera::storage;
namespace cpu = tessera::test::cpu_reference;
using tessera::test::ScratchDir;
using tessera::test::looking;

// An RGBA8 texture, rows top to bottom.
struct Texture {
    std::uint32_t width = 0, height = 0;
    std::vector<std::uint8_t> rgba;
};

// Structure a wrong padding cannot hide: red ramps across the width (so the left and right
// edges differ by ~250, and a clamped copy would show a seam at every repeat), green mortar
// lines, blue a hash of the texel.
Texture pattern(std::uint32_t w, std::uint32_t h, std::uint32_t seed) {
    Texture t{w, h, std::vector<std::uint8_t>(std::size_t(w) * h * 4)};
    for (std::uint32_t y = 0; y < h; ++y)
        for (std::uint32_t x = 0; x < w; ++x) {
            std::uint8_t* p = &t.rgba[(std::size_t(y) * w + x) * 4];
            const std::uint32_t brick_x = (x + ((y / 8) % 2) * 8) % 16;
            p[0] = std::uint8_t(x * 255 / (w - 1));
            p[1] = (y % 8 == 0 || brick_x == 0) ? 230 : std::uint8_t(60 + (y * 150) / h);
            std::uint32_t v = (x * 73856093u) ^ (y * 19349663u) ^ (seed * 83492791u);
            v ^= v >> 13;
            v *= 0x5bd1e995u;
            p[2] = std::uint8_t(40 + (v >> 24) % 150);
            p[3] = 255;
        }
    return t;
}

void write_png(const std::string& path, const Texture& t) {
    auto png = st::encode_png({t.width, t.height, 4, st::SampleType::u8, st::ColourSpace::srgb, t.rgba});
    ASSERT_TRUE(png.ok()) << png.error().message;
    std::ofstream(path, std::ios::binary).write(reinterpret_cast<const char*>(png->data()), std::streamsize(png->size()));
}

// The scene (Z up, all on z = 0, materials side by side so that no material hides another): a
// brick floor repeating ten times each way around u = 1000, v = -1000; a striped metal floor
// repeating 4 x 3 times across the origin (its texels are 3x longer one way than the other:
// anisotropic); a terrace of 80x48 tiles (not a power of two either way) repeating 5 x 3.5 times
// around u = -1000, v = 1000, one quad; a colour-only pentagon and a colour-only quad in their
// own object and groups.
constexpr const char* kObj = R"(# repeating textures, colour-only materials, several objects and groups
mtllib scene.mtl
v 0 0 0
v 40 0 0
v 40 40 0
v 0 40 0
v 45 0 0
v 85 0 0
v 85 40 0
v 45 40 0
v 95 10 0
v 100 14 0
v 98 20 0
v 92 20 0
v 90 14 0
v 90 25 0
v 100 25 0
v 100 35 0
v 90 35 0
v 0 45 0
v 40 45 0
v 40 85 0
v 0 85 0
vt 990 -1000
vt 1000 -1000
vt 1000 -990
vt 990 -990
vt -3.25 0.5
vt 0.75 0.5
vt 0.75 3.5
vt -3.25 3.5
vt 0 0
vt -1000 996.5
vt -995 996.5
vt -995 1000
vt -1000 1000
o floor
g bricks
usemtl brick
f 1/1 2/2 3/3
f 1/1 3/3 4/4
o metal_floor
g metal
usemtl metal
f 5/5 6/6 7/7 8/8
o terrace
g tiles
usemtl tiles
f 18/10 19/11 20/12 21/13
o plaques
g pentagon
usemtl red
f 9/9 10/9 11/9 12/9 13/9
g square
usemtl blue
f 14/9 15/9 16/9 17/9
)";

constexpr const char* kMtl = R"(newmtl brick
Kd 1 1 1
map_Kd brick.png
newmtl metal
Kd 1 1 1
map_Kd metal.png
newmtl tiles
Kd 1 1 1
map_Kd tiles.png
newmtl red
Kd 0.8 0.2 0.1
newmtl blue
Kd 0.1 0.3 0.9
)";

// One material of the original OBJ as the reference draws it: its texture's levels and its
// faces as a scene whose texel coordinates are the OBJ's own (u, v) in texels of that texture,
// shifted by whole repeats to be positive (GL_REPEAT samples them alike).
struct Material {
    std::vector<gl::ReferenceRenderer::Level> levels;
    sc::Scene scene;
};

// The texture's levels as 2x2 means in linear light (the store's rule, from an implementation
// independent of the builder's). A non-power-of-two chain stops at the first level with an odd
// side: halving it is no longer a 2x2 mean of whole texels, and GL sizes the next level rounding
// down while the store rounds up. The views below stay finer than that level.
std::vector<gl::ReferenceRenderer::Level> mip_chain(const Texture& t) {
    tessera::test::RefImage base{t.width, t.height, 4, st::SampleType::u8, t.rgba};
    bool alpha = false;
    for (std::size_t i = 3; i < t.rgba.size(); i += 4) alpha = alpha || t.rgba[i] != 255;
    std::vector<gl::ReferenceRenderer::Level> levels;
    for (const auto& l : tessera::test::reference_pyramid(base, st::ColourSpace::srgb, alpha, 1)) {
        levels.push_back({l.width, l.height, l.bytes});
        if ((l.width > 1 && l.width % 2) || (l.height > 1 && l.height % 2)) break;
    }
    return levels;
}

std::map<std::string, Material> original_materials(const std::string& obj, const std::map<std::string, Texture>& textures,
                                                   double repeats = 4096) {
    tinyobj::ObjReader reader;
    tinyobj::ObjReaderConfig rc;
    rc.triangulate = true;
    EXPECT_TRUE(reader.ParseFromFile(obj, rc)) << reader.Error();
    const auto& attrib = reader.GetAttrib();
    std::map<std::string, Material> out;
    for (const auto& m : reader.GetMaterials()) {
        Material mat;
        if (!m.diffuse_texname.empty()) {
            mat.levels = mip_chain(textures.at(m.diffuse_texname));
        } else {
            std::vector<std::uint8_t> texel(4, 255);
            for (int c = 0; c < 3; ++c) texel[std::size_t(c)] = std::uint8_t(std::lround(std::clamp(double(m.diffuse[c]), 0.0, 1.0) * 255));
            mat.levels.push_back({1, 1, texel});
        }
        mat.scene.name = m.name;
        mat.scene.vt_width = mat.levels[0].width;
        mat.scene.vt_height = mat.levels[0].height;
        out[m.name] = std::move(mat);
    }
    for (const auto& shape : reader.GetShapes())
        for (std::size_t f = 0; f < shape.mesh.num_face_vertices.size(); ++f) {
            Material& mat = out.at(reader.GetMaterials().at(std::size_t(shape.mesh.material_ids[f])).name);
            const double w = mat.levels[0].width, h = mat.levels[0].height;
            double texel[3][2], pos[3][3];
            for (int c = 0; c < 3; ++c) {
                const auto& idx = shape.mesh.indices[f * 3 + std::size_t(c)];
                for (int d = 0; d < 3; ++d) pos[c][d] = attrib.vertices[3 * std::size_t(idx.vertex_index) + std::size_t(d)];
                const double u = attrib.texcoords[2 * std::size_t(idx.texcoord_index)];
                const double v = attrib.texcoords[2 * std::size_t(idx.texcoord_index) + 1];
                texel[c][0] = (u + repeats) * w;          // OBJ's v runs up the image; texel rows run down
                texel[c][1] = (repeats + 1 - v) * h;
            }
            sc::Chunk chunk;
            chunk.origin = {pos[0][0], pos[0][1], pos[0][2]};
            chunk.texel_origin[0] = std::uint32_t(std::floor(std::min({texel[0][0], texel[1][0], texel[2][0]})));
            chunk.texel_origin[1] = std::uint32_t(std::floor(std::min({texel[0][1], texel[1][1], texel[2][1]})));
            for (int c = 0; c < 3; ++c) {
                sc::Vertex vx{};
                for (int d = 0; d < 3; ++d) vx.position[d] = float(pos[c][d] - pos[0][d]);
                vx.texel[0] = float(texel[c][0] - chunk.texel_origin[0]);
                vx.texel[1] = float(texel[c][1] - chunk.texel_origin[1]);
                chunk.vertices.push_back(vx);
                chunk.indices.push_back(std::uint32_t(c));
                for (int d = 0; d < 3; ++d) {
                    chunk.bounds_min[d] = c == 0 ? pos[c][d] : std::min(chunk.bounds_min[d], pos[c][d]);
                    chunk.bounds_max[d] = c == 0 ? pos[c][d] : std::max(chunk.bounds_max[d], pos[c][d]);
                }
            }
            for (int d = 0; d < 3; ++d) {
                const bool first = mat.scene.chunks.empty();
                mat.scene.bounds_min[d] = first ? chunk.bounds_min[d] : std::min(mat.scene.bounds_min[d], chunk.bounds_min[d]);
                mat.scene.bounds_max[d] = first ? chunk.bounds_max[d] : std::max(mat.scene.bounds_max[d], chunk.bounds_max[d]);
            }
            mat.scene.chunks.push_back(std::move(chunk));
        }
    return out;
}

// The repeating faces' (u, v) as affine functions of the ground position (x, y) over their
// rectangles: where the pixel rays meet them, and where a repeat line passes.
struct RepeatingRect {
    double x0, y0, x1, y1;  // world
    double u0, v0, u1, v1;  // at (x0, y0) and (x1, y1)
};
constexpr RepeatingRect kRepeating[] = {
    {0, 0, 40, 40, 990, -1000, 1000, -990}, {45, 0, 85, 40, -3.25, 0.5, 0.75, 3.5}, {0, 45, 40, 85, -1000, 996.5, -995, 1000}};

bool uv_at(double x, double y, double& u, double& v) {
    for (const auto& r : kRepeating)
        if (x >= r.x0 && x <= r.x1 && y >= r.y0 && y <= r.y1) {
            u = r.u0 + (x - r.x0) / (r.x1 - r.x0) * (r.u1 - r.u0);
            v = r.v0 + (y - r.y0) / (r.y1 - r.y0) * (r.v1 - r.v0);
            return true;
        }
    return false;
}

// Pixels that a repeat line (u or v whole) crosses within a pixel's footprint.
std::vector<std::uint8_t> seam_pixels(const sc::Camera& cam, std::uint32_t w, std::uint32_t h) {
    std::vector<std::uint8_t> seam(std::size_t(w) * h, 0);
    for (std::uint32_t j = 0; j < h; ++j)
        for (std::uint32_t i = 0; i < w; ++i) {
            double x, y, u, v, xr, yr, ur, vr, xd, yd, ud, vd;
            if (!tessera::test::pixel_to_ground(cam, w, h, i, j, x, y) || !uv_at(x, y, u, v)) continue;
            if (!tessera::test::pixel_to_ground(cam, w, h, i + 1.0, j, xr, yr) || !uv_at(xr, yr, ur, vr)) continue;
            if (!tessera::test::pixel_to_ground(cam, w, h, i, j + 1.0, xd, yd) || !uv_at(xd, yd, ud, vd)) continue;
            const double fu = std::max(std::abs(ur - u), std::abs(ud - u)), fv = std::max(std::abs(vr - v), std::abs(vd - v));
            const bool near_u = std::abs(u - std::round(u)) <= fu, near_v = std::abs(v - std::round(v)) <= fv;
            seam[std::size_t(j) * w + i] = (near_u && fu < 0.25) || (near_v && fv < 0.25);  // a line, not a blur of many
        }
    return seam;
}


struct ErrorStats {
    double psnr = 0;  // dB over RGB
    int max_error = 0;
    std::size_t pixels = 0;
    double mean_error = 0;  // mean absolute error per channel
    std::size_t over_16 = 0;  // pixels with a channel off by more than 16
};

ErrorStats errors(const std::vector<std::uint8_t>& a, const std::vector<std::uint8_t>& b, const std::vector<std::uint8_t>& mask) {
    ErrorStats e;
    double sq = 0, abs_sum = 0;
    for (std::size_t i = 0; i < mask.size(); ++i) {
        if (!mask[i]) continue;
        ++e.pixels;
        int worst = 0;
        for (std::size_t c = 0; c < 3; ++c) {
            const int d = std::abs(int(a[i * 4 + c]) - int(b[i * 4 + c]));
            worst = std::max(worst, d);
            e.max_error = std::max(e.max_error, d);
            sq += double(d) * d;
            abs_sum += d;
        }
        e.over_16 += worst > 16;
    }
    const double n = 3.0 * double(std::max<std::size_t>(e.pixels, 1));
    e.mean_error = abs_sum / n;
    e.psnr = sq == 0 ? 99.0 : 10 * std::log10(255.0 * 255.0 / (sq / n));
    return e;
}

// The renderer both tests draw an atlas store with: 256x192, sRGB, every page fits the pool.
gl::RendererConfig atlas_view_config(gl::Filter filter, const st::StoreInfo& info) {
    gl::RendererConfig cfg;
    cfg.width = 256;
    cfg.height = 192;
    cfg.filter = filter;
    cfg.max_anisotropy = 8;
    cfg.tile_size = info.tile_size();
    cfg.border = info.border;
    cfg.pool_slots = std::uint32_t(tessera::test::page_count(info)) + 8;
    cfg.srgb = true;
    cfg.staging_bytes = 8u << 20;
    cfg.feedback_jitter = false;
    return cfg;
}

// The atlas store's own levels for the independent reference: the VT's texels sampled on the
// CPU, so that what differs is the sampling alone (against the original textures, the atlas's
// mip chain differs too: a texture at an odd atlas offset averages other 2x2 groups).
cpu::Material atlas_material(const std::string& store, const sc::Scene& scene, const gl::RendererConfig& cfg) {
    cpu::Material m;
    m.scene = &scene;
    auto levels = tessera::client::decode_store_levels(store, 16384);
    EXPECT_TRUE(levels.ok()) << levels.error().message;
    if (levels) m.colour = cpu::make_texture(*levels, cfg.srgb);
    return m;
}

// The VT against the independent reference over the atlas store's texels: every pixel covered
// alike (knife edges aside), and within two steps everywhere (measured: 54.9-56.5 dB, max error 1).
void expect_matches_atlas_reference(const std::vector<std::uint8_t>& have, const gl::RendererConfig& cfg, const cpu::Material& atlas,
                                    const sc::Camera& camera, const char* what) {
    const auto independent = cpu::render(cfg, std::span(&atlas, 1), camera);
    ASSERT_TRUE(independent.ok()) << independent.error().message;
    const auto c = cpu::compare(have, *independent);
    std::printf("  %s, atlas texels: %s\n", what, cpu::describe(c).c_str());
    EXPECT_EQ(c.coverage_differs, 0u) << what << " " << cpu::describe(c);
    EXPECT_GT(c.compared, std::size_t(cfg.width * cfg.height / 8)) << what;
    EXPECT_GE(c.psnr, 53.0) << what << " " << cpu::describe(c);
    EXPECT_LE(c.max_error, 2) << what << " " << cpu::describe(c);
}

const char* filter_name(gl::Filter f) {
    return f == gl::Filter::bilinear ? "bilinear" : f == gl::Filter::trilinear ? "trilinear" : "anisotropic";
}

class RenderRepeats : public ::testing::TestWithParam<gl::Filter> {};

TEST_P(RenderRepeats, AtlasMatchesTheOriginalTexturesRepeatedWithoutSeams) {
    REQUIRE_GL(ctx);
    const gl::Filter filter = GetParam();
    ScratchDir dir;
    const std::map<std::string, Texture> textures = {
        {"brick.png", pattern(64, 64, 1)}, {"metal.png", pattern(32, 128, 2)}, {"tiles.png", pattern(80, 48, 3)}};
    for (const auto& [name, t] : textures) write_png(dir.file(name), t);
    std::ofstream(dir.file("scene.obj")) << kObj;
    std::ofstream(dir.file("scene.mtl")) << kMtl;
    const std::string store = dir.file("scene.tsr"), atlas_obj = dir.file("atlas.obj");
    const auto built = tessera::test::run_tessera("build --atlas " + dir.file("scene.obj") + " -o " + store + " --obj-out " + atlas_obj +
                                                  " --up z --codec zstd --tile-size 64 --quiet");
    ASSERT_EQ(built.exit_code, 0) << built.out;

    auto reader = st::StoreReader::open(store);
    ASSERT_TRUE(reader.ok()) << reader.error().message;
    const st::StoreInfo info = (*reader)->info();
    std::printf("  atlas %ux%u texels, %u levels\n", info.width, info.height, info.level_count());
    auto scene = sc::load_obj_scene(atlas_obj, info.width, info.height);
    ASSERT_TRUE(scene.ok()) << scene.error().message;

    gl::RendererConfig cfg = atlas_view_config(filter, info);
    auto vt = tessera::test::make_vt(cfg, store, *scene);
    ASSERT_TRUE(vt);
    ASSERT_TRUE(tessera::test::load_everything(*vt));

    auto materials = original_materials(dir.file("scene.obj"), textures);
    ASSERT_EQ(materials.size(), 5u);
    const cpu::Material atlas = atlas_material(store, *scene, cfg);
    std::vector<std::unique_ptr<gl::ReferenceRenderer>> refs;
    std::vector<cpu::Material> cpu_materials;  // the independent reference: each texture wrapped
    for (auto& [name, m] : materials) {
        auto r = gl::ReferenceRenderer::create(cfg, m.levels);
        ASSERT_TRUE(r.ok()) << name << ": " << r.error().message;
        ASSERT_TRUE((*r)->set_scene(m.scene).ok());
        (*r)->set_repeat(true);
        refs.push_back(std::move(*r));
        cpu::Material cm;
        cm.scene = &m.scene;
        cm.colour = cpu::make_texture(m.levels, cfg.srgb);
        cm.colour.repeat = true;
        cpu_materials.push_back(std::move(cm));
    }

    // Close over the bricks (magnified: bilinear taps across the wrap), a mid view of both
    // floors, a low grazing view down their length and one over the tiles (minified,
    // anisotropic), and the whole scene from afar. The views stay within the store's levels: an
    // atlas store's mip chain ends where one tile holds the level (here level 3), while each
    // texture's own chain goes on, so a farther view would compare the last atlas level with
    // coarser texture mips. The far view looks down obliquely: seen straight down, the bricks'
    // footprint is square, and whether the anisotropic filter takes one tap or two (and along
    // which axis) turns on rounding, differently in the two renderers.
    sc::Camera grazing = looking(42, -2, 2.5, std::numbers::pi / 2, -0.22);
    grazing.far_plane = 14;  // the distance where the metal's texels reach the store's last level
    sc::Camera terrace = looking(20, 43, 2.5, std::numbers::pi / 2, -0.22);
    terrace.far_plane = 24;  // the tiles reach level 3 there, the store's last
    const sc::Camera cameras[] = {
        tessera::test::straight_down(20.3, 20.2, 6.0),
        looking(42, -6, 21, std::numbers::pi / 2, -0.95),
        grazing,
        terrace,                                       // the non-power-of-two tiles, grazing
        looking(50, 20, 60, std::numbers::pi / 2, -1.2),  // everything from afar, obliquely
    };
    for (std::size_t k = 0; k < std::size(cameras); ++k) {
        SCOPED_TRACE(std::string(filter_name(filter)) + " view " + std::to_string(k));
        const auto f = tessera::test::render_vt(*vt->renderer, cameras[k]);
        std::vector<std::uint8_t> want(f.rgba.size(), 0);
        std::vector<int> layers(f.rgba.size() / 4, 0);
        for (auto& r : refs) {
            r->render(cameras[k]);
            const auto img = r->read_color();
            for (std::size_t i = 0; i < layers.size(); ++i)
                if (img[i * 4 + 3]) {
                    ++layers[i];
                    std::copy_n(&img[i * 4], 4, &want[i * 4]);
                }
        }
        ASSERT_EQ(*std::max_element(layers.begin(), layers.end()), 1) << "materials overlap on screen: the composite is ambiguous";
        expect_matches_atlas_reference(f.rgba, cfg, atlas, cameras[k], (std::string(filter_name(filter)) + " view " + std::to_string(k)).c_str());
        // The independent reference over the original textures, wrapped: the whole frame and the
        // repeat lines, with the bounds of the GL reference above (measured: 51.9-55.3 dB over the frame,
        // at most 23 pixels off by > 16, 48.7-60.8 dB on the repeat lines).
        const auto independent = cpu::render(cfg, cpu_materials, cameras[k]);
        ASSERT_TRUE(independent.ok()) << independent.error().message;
        const auto vs_cpu = cpu::compare(f.rgba, *independent);
        {
            const auto seam_cpu = errors(f.rgba, independent->rgba, seam_pixels(cameras[k], cfg.width, cfg.height));
            std::printf("  %s view %zu %s; on repeat lines PSNR %.2f dB, %zu off by > 16\n", filter_name(filter), k,
                        cpu::describe(vs_cpu).c_str(), seam_cpu.psnr, seam_cpu.over_16);
            EXPECT_LE(vs_cpu.coverage_differs, std::size_t(cfg.width)) << cpu::describe(vs_cpu);
            EXPECT_GT(vs_cpu.compared, std::size_t(cfg.width * cfg.height / 8));
            EXPECT_GE(vs_cpu.psnr, 40.0) << cpu::describe(vs_cpu);
            EXPECT_LE(double(vs_cpu.over_16), 0.01 * double(vs_cpu.compared)) << cpu::describe(vs_cpu);
            EXPECT_GE(seam_cpu.psnr, 40.0) << "repeat lines against the independent reference";
        }
        const auto have_mask = tessera::test::coverage(f.rgba), want_mask = tessera::test::coverage(want);
        std::vector<std::uint8_t> both(have_mask.size()), seam = seam_pixels(cameras[k], cfg.width, cfg.height), rest(both.size());
        std::size_t differ = 0;
        for (std::size_t i = 0; i < both.size(); ++i) {
            both[i] = have_mask[i] && want_mask[i];
            differ += have_mask[i] != want_mask[i];
            seam[i] = seam[i] && both[i];
            rest[i] = both[i] && !seam[i];
        }
        // The cut triangles cover the original faces; their edges may round differently.
        EXPECT_LE(differ, std::size_t(cfg.width)) << "the VT and the reference cover different pixels";
        const auto all = errors(f.rgba, want, both), on_seams = errors(f.rgba, want, seam), off_seams = errors(f.rgba, want, rest);
        std::printf("  %s view %zu: %zu pixels, PSNR %.2f dB, max error %d; on repeat lines %zu pixels, PSNR %.2f dB, mean %.2f, max %d, %zu off by > 16; "
                    "elsewhere mean %.2f, max %d; coverage differs in %zu; fallback %llu\n",
                    filter_name(filter), k, all.pixels, all.psnr, all.max_error, on_seams.pixels, on_seams.psnr, on_seams.mean_error,
                    on_seams.max_error, on_seams.over_16, off_seams.mean_error, off_seams.max_error, differ, (unsigned long long)f.counters.fallback_unbiased);
        EXPECT_EQ(f.counters.fallback_unbiased, 0u);
        EXPECT_GT(all.pixels, std::size_t(cfg.width * cfg.height / 8));
        EXPECT_GE(all.psnr, 40.0);
        // No seams: a repeat line is drawn as well as anywhere else.
        EXPECT_GT(on_seams.pixels, 100u) << "the view must cross repeat lines";
        EXPECT_GE(on_seams.psnr, 40.0);
        EXPECT_LE(on_seams.mean_error, 2 * off_seams.mean_error + 1.0);
        // A seam is a line of wrong pixels, not the odd pixel a cut edge rounds differently.
        EXPECT_LE(double(on_seams.over_16), 0.01 * double(on_seams.pixels)) << "pixels on repeat lines off by more than 16";
    }
}

INSTANTIATE_TEST_SUITE_P(Filters, RenderRepeats, ::testing::Values(gl::Filter::bilinear, gl::Filter::trilinear, gl::Filter::anisotropic),
                         [](const auto& p) { return std::string(filter_name(p.param)); });

// Cut-outs (docs/atlas.md, "Alpha"; docs/renderer.md, "Cut-outs"): a leaf, an RGBA texture whose
// background is transparent magenta, floats 5 units over a floor. The atlas keeps the alpha, and
// the VT discards where it is below one half in every pass: the floor shows through the
// background, with its own depth, and the feedback pass asks for the floor's pages there. Against
// the reference drawing each original material with the same alpha test.
constexpr const char* kCutoutObj = R"(# a floor and a cut-out leaf over it
mtllib cutout.mtl
v 0 0 0
v 40 0 0
v 40 40 0
v 0 40 0
v 8 8 5
v 32 8 5
v 32 32 5
v 8 32 5
vt 0 0
vt 1 0
vt 1 1
vt 0 1
o ground
usemtl floor
f 1/1 2/2 3/3 4/4
o leaf
usemtl leaf
f 5/1 6/2 7/3 8/4
)";

constexpr const char* kCutoutMtl = R"(newmtl floor
Kd 1 1 1
map_Kd floor.png
newmtl leaf
Kd 1 1 1
map_Kd leaf.png
)";

// A leaf: an opaque dark red disc with a ring of round holes, on a transparent magenta background
// (the colour a cut-out's background has when alpha is lost).
Texture leaf(std::uint32_t size) {
    Texture t{size, size, std::vector<std::uint8_t>(std::size_t(size) * size * 4)};
    const double c = (size - 1) / 2.0;
    for (std::uint32_t y = 0; y < size; ++y)
        for (std::uint32_t x = 0; x < size; ++x) {
            std::uint8_t* p = &t.rgba[(std::size_t(y) * size + x) * 4];
            const double r = std::hypot(x - c, y - c) / c, a = std::atan2(y - c, x - c);
            const bool hole = std::abs(r - 0.55) < 0.15 && std::cos(6 * a) > 0.3;
            const bool in = r < 0.9 && !hole;
            p[0] = in ? 150 : 255;
            p[1] = in ? std::uint8_t(30 + (x * 40) / size) : 0;
            p[2] = in ? 40 : 255;
            p[3] = in ? 255 : 0;
        }
    return t;
}

bool magenta(const std::uint8_t* p) { return p[0] > 200 && p[1] < 60 && p[2] > 200; }

class RenderCutouts : public ::testing::TestWithParam<gl::Filter> {};

TEST_P(RenderCutouts, AtlasKeepsAlphaAndTheVtDiscardsTheBackground) {
    REQUIRE_GL(ctx);
    const gl::Filter filter = GetParam();
    ScratchDir dir;
    const std::map<std::string, Texture> textures = {{"floor.png", pattern(128, 128, 4)}, {"leaf.png", leaf(64)}};
    for (const auto& [name, t] : textures) write_png(dir.file(name), t);
    std::ofstream(dir.file("scene.obj")) << kCutoutObj;
    std::ofstream(dir.file("cutout.mtl")) << kCutoutMtl;
    const std::string store = dir.file("scene.tsr"), atlas_obj = dir.file("atlas.obj");
    const auto built = tessera::test::run_tessera("build --atlas " + dir.file("scene.obj") + " -o " + store + " --obj-out " + atlas_obj +
                                                  " --up z --codec zstd --tile-size 64 --quiet");
    ASSERT_EQ(built.exit_code, 0) << built.out;
    auto reader = st::StoreReader::open(store);
    ASSERT_TRUE(reader.ok()) << reader.error().message;
    const st::StoreInfo info = (*reader)->info();
    EXPECT_EQ(info.channels, 4u) << "the atlas dropped the leaf's alpha";
    EXPECT_TRUE(info.has_alpha);
    auto scene = sc::load_obj_scene(atlas_obj, info.width, info.height);
    ASSERT_TRUE(scene.ok()) << scene.error().message;
    ASSERT_EQ(scene->chunks.size(), 2u);

    gl::RendererConfig cfg = atlas_view_config(filter, info);
    cfg.alpha_test = true;
    auto vt = tessera::test::make_vt(cfg, store, *scene);
    ASSERT_TRUE(vt);
    ASSERT_TRUE(tessera::test::load_everything(*vt));

    // In [0, 1]: no shift, and the reference clamps at the edges as the atlas's padding does.
    auto materials = original_materials(dir.file("scene.obj"), textures, 0);
    ASSERT_EQ(materials.size(), 2u);
    const cpu::Material atlas = atlas_material(store, *scene, cfg);
    std::map<std::string, std::unique_ptr<gl::ReferenceRenderer>> refs;
    std::vector<cpu::Material> cpu_materials;  // the independent reference: both materials, peeled in depth
    for (auto& [name, m] : materials) {
        auto r = gl::ReferenceRenderer::create(cfg, m.levels);
        ASSERT_TRUE(r.ok()) << name << ": " << r.error().message;
        ASSERT_TRUE((*r)->set_scene(m.scene).ok());
        refs[name] = std::move(*r);
        cpu::Material cm;
        cm.scene = &m.scene;
        cm.colour = cpu::make_texture(m.levels, cfg.srgb);
        cpu_materials.push_back(std::move(cm));
    }

    // The floor's texels in the atlas (the chunk whose corners lie lowest): a feedback pixel that
    // sees the floor through a hole must name a page over them.
    const sc::Chunk& floor_chunk = scene->chunks[0].bounds_max[2] < scene->chunks[1].bounds_max[2] ? scene->chunks[0] : scene->chunks[1];
    double floor_texels[4] = {1e30, 1e30, -1e30, -1e30};
    for (const auto& v : floor_chunk.vertices)
        for (int d = 0; d < 2; ++d) {
            floor_texels[d] = std::min(floor_texels[d], double(floor_chunk.texel_origin[d]) + v.texel[d]);
            floor_texels[d + 2] = std::max(floor_texels[d + 2], double(floor_chunk.texel_origin[d]) + v.texel[d]);
        }

    const sc::Camera cameras[] = {tessera::test::straight_down(20, 20, 30), looking(20, -8, 22, std::numbers::pi / 2, -0.9)};
    for (std::size_t k = 0; k < std::size(cameras); ++k) {
        SCOPED_TRACE(std::string(filter_name(filter)) + " view " + std::to_string(k));
        const auto n = vt->renderer->render(cameras[k], 0);
        std::vector<gl::FrameCounters> counters;
        gl::FeedbackFrame feedback;
        vt->renderer->finish(&counters, &feedback);
        const auto have = vt->renderer->read_color();
        ASSERT_EQ(feedback.frame, n);
        // The composite: the leaf where its reference keeps a pixel, the floor elsewhere.
        refs.at("floor")->render(cameras[k]);
        refs.at("leaf")->render(cameras[k]);
        const auto floor_img = refs.at("floor")->read_color(), leaf_img = refs.at("leaf")->read_color();
        std::vector<std::uint8_t> want = floor_img, mask(have.size() / 4), through(mask.size());
        std::size_t leaf_pixels = 0, magenta_pixels = 0;
        for (std::size_t i = 0; i < mask.size(); ++i) {
            if (leaf_img[i * 4 + 3]) {
                std::copy_n(&leaf_img[i * 4], 4, &want[i * 4]);
                ++leaf_pixels;
            }
            mask[i] = want[i * 4 + 3] != 0;
            magenta_pixels += have[i * 4 + 3] && magenta(&have[i * 4]);
        }
        // Pixels inside the leaf's square that show the floor: its holes and background.
        sc::Camera lifted = cameras[k];
        lifted.position[2] -= 5;  // the ray's meeting with z = 5
        for (std::uint32_t j = 0; j < cfg.height; ++j)
            for (std::uint32_t i = 0; i < cfg.width; ++i) {
                double x, y;
                const std::size_t p = std::size_t(j) * cfg.width + i;
                through[p] = tessera::test::pixel_to_ground(lifted, cfg.width, cfg.height, i, j, x, y) && x > 8.5 && x < 31.5 &&
                             y > 8.5 && y < 31.5 && !leaf_img[p * 4 + 3] && floor_img[p * 4 + 3];
            }
        const auto e = errors(have, want, mask);
        // The independent reference decides each pixel's alpha test itself: over the atlas's
        // texels, and over the original textures with the bounds of the GL reference (measured:
        // 56.5 dB for view 0 and anisotropic view 1, 47.6-47.7 dB for bilinear and trilinear view 1).
        expect_matches_atlas_reference(have, cfg, atlas, cameras[k], (std::string("cut-outs ") + filter_name(filter) + " view " + std::to_string(k)).c_str());
        const auto independent = cpu::render(cfg, cpu_materials, cameras[k]);
        ASSERT_TRUE(independent.ok()) << independent.error().message;
        const auto vs_cpu = cpu::compare(have, *independent);
        std::printf("  cut-outs %s view %zu %s (%zu layers peeled)\n", filter_name(filter), k, cpu::describe(vs_cpu).c_str(),
                    independent->layers_peeled);
        EXPECT_GE(independent->layers_peeled, 2u);
        EXPECT_LE(vs_cpu.coverage_differs, std::size_t(cfg.width)) << cpu::describe(vs_cpu);
        EXPECT_GE(vs_cpu.psnr, k == 0 || filter == gl::Filter::anisotropic ? 54.0 : 45.0) << cpu::describe(vs_cpu);
        EXPECT_LE(double(vs_cpu.over_16), 0.02 * double(leaf_pixels)) << cpu::describe(vs_cpu);
        // Feedback pixels (at their centres: no jitter) that see the floor through the leaf.
        std::size_t fb_through = 0, fb_wrong = 0;
        const std::uint32_t scale = cfg.feedback_scale;
        for (std::uint32_t fy = 0; fy < feedback.height; ++fy)
            for (std::uint32_t fx = 0; fx < feedback.width; ++fx) {
                const std::uint32_t i = std::min(fx * scale + scale / 2, cfg.width - 1), j = std::min(fy * scale + scale / 2, cfg.height - 1);
                // Two pixels clear of the leaf's rim, where the alpha of the page the feedback
                // asks for and the filtered alpha the VT pass tests may decide differently.
                bool clear = i >= 2 && j >= 2 && i + 2 < cfg.width && j + 2 < cfg.height;
                for (std::uint32_t dj = 0; clear && dj < 5; ++dj)
                    for (std::uint32_t di = 0; clear && di < 5; ++di) clear = through[std::size_t(j + dj - 2) * cfg.width + i + di - 2];
                if (!clear) continue;
                ++fb_through;
                const tessera::client::FeedbackId id = feedback.ids[std::size_t(fy) * feedback.width + fx];
                const tessera::client::PageKey page = tessera::client::unpack_feedback(id);
                const double span = double(info.tile_payload) * double(1u << page.level);
                const bool over_floor = id != tessera::client::kNoPage && (page.x + 1) * span > floor_texels[0] &&
                                        page.x * span < floor_texels[2] && (page.y + 1) * span > floor_texels[1] && page.y * span < floor_texels[3];
                fb_wrong += !over_floor;
            }
        std::printf("  cut-outs %s view %zu: %zu pixels, PSNR %.2f dB, %zu off by > 16; leaf %zu pixels, floor through it %zu; magenta %zu; "
                    "feedback through the leaf %zu, naming no floor page %zu\n",
                    filter_name(filter), k, e.pixels, e.psnr, e.over_16, leaf_pixels, tessera::test::count(through), magenta_pixels, fb_through,
                    fb_wrong);
        EXPECT_EQ(magenta_pixels, 0u) << "the leaf's background shows";
        EXPECT_GT(tessera::test::count(through), std::size_t(cfg.width * cfg.height / 20)) << "the view must see through the leaf";
        EXPECT_GT(leaf_pixels, std::size_t(cfg.width * cfg.height / 20));
        // Near the measured values: view 0 82.9-85.6 dB with every filter; view 1, whose leaf is
        // small and seen at a slant, 48.3-48.5 dB bilinear and trilinear (rim pixels the alpha
        // test decides differently), 82.0 dB anisotropic.
        EXPECT_GE(e.psnr, k == 0 || filter == gl::Filter::anisotropic ? 78.0 : 45.0) << "view " << k;
        // The alpha test may decide a pixel on the leaf's rim either way.
        EXPECT_LE(double(e.over_16), 0.02 * double(leaf_pixels)) << "pixels off by more than 16";
        EXPECT_GT(fb_through, 20u);
        EXPECT_EQ(fb_wrong, 0u) << "the feedback pass asks for the leaf's pages where the leaf is discarded";
    }
}

INSTANTIATE_TEST_SUITE_P(Filters, RenderCutouts, ::testing::Values(gl::Filter::bilinear, gl::Filter::trilinear, gl::Filter::anisotropic),
                         [](const auto& p) { return std::string(filter_name(p.param)); });

}  // namespace
