// Rendering tests of tessera::client_gl on Mesa llvmpipe through EGL (headless; a test fails,
// saying why, when no OpenGL 4.5 context can be made). Small targets: they run on two CPU cores without a GPU.
//
//   RenderVsReference   every page resident (the real runtime + local store, lossless tiles): the
//                       VT frame matches the ordinary mipmapped reference (PSNR >= 50 dB) in every
//                       filter, over a perspective view spanning several levels; also with a tiny
//                       staging ring (uploads straight from client memory).
//   RenderSeams         a smooth pattern with page borders everywhere, at levels 0..4 and at a
//                       grazing angle, in every filter (anisotropic up to 8): no seams (the VT
//                       matches the reference within a few 8-bit steps everywhere).
//   RenderFeedback      the GPU feedback pass requests exactly the pages scene::cpu_feedback does.
//   RenderAddressing    a 2^20-texel VT: texels near 2^20 come back exactly, coordinates encoded
//                       in their colours.
//   RenderCounters      fallback counters: coarsest level only, everything, with a bias, nothing.
//   RenderFeedbackLoop  render -> feedback -> Runtime -> uploads converges to full detail.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <cmath>
#include <functional>
#include <map>
#include <numbers>
#include <ostream>
#include <set>
#include <span>
#include <thread>

#include "tessera/client/gl/context.hpp"
#include "ground_ray.hpp"
#include "render_util.hpp"
#include "cpu_reference.hpp"
#include "render_vt.hpp"
#include "tessera/client/gl/reference_renderer.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "tessera/client/measures.hpp"
#include "page_table.hpp"
#include "tessera/client/runtime.hpp"
#include "fades.hpp"
#include "runtime_internal.hpp"
#include "tessera/client/tile_source.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/scene/cpu_feedback.hpp"
#include "tessera/scene/lod.hpp"
#include "tessera/scene/scene.hpp"
#include "tessera/storage/builder.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/layers.hpp"
#include "tessera/storage/image_source.hpp"
#include "tessera/storage/store_reader.hpp"
#include "transcode.hpp"
#include "test_util.hpp"

namespace tessera::client::gl {
// Readable parameter names in the test list.
void PrintTo(Filter f, std::ostream* os) {
    *os << (f == Filter::bilinear ? "bilinear" : f == Filter::trilinear ? "trilinear" : "anisotropic");
}
}  // namespace tessera::client::gl

namespace {

using namespace std::chrono_literals;
namespace gl = tessera::client::gl;
namespace sc = tessera::scene;
namespace st = tessera::storage;
namespace cpu = tessera::test::cpu_reference;
using tessera::client::FeedbackId;
using tessera::client::kNoPage;
using tessera::client::PageKey;
using tessera::client::PageTable;
using tessera::test::ScratchDir;
using tessera::test::looking;
using tessera::test::encode_texel;
using tessera::test::store_geometry;
using tessera::test::Vt;
using tessera::test::Frame;
using tessera::test::make_vt;
using tessera::test::page_count;
using tessera::test::load_everything;
using tessera::test::render_vt;
using tessera::test::coverage;
using tessera::test::count;

constexpr double kPi = std::numbers::pi;

sc::Camera straight_down(double x, double y, double height) {
    sc::Camera c;
    c.position = {x, y, height};
    c.yaw = kPi / 2;  // screen up = +y
    c.pitch = -kPi / 2;
    c.near_plane = 0.5;
    c.far_plane = 1e6;
    return c;
}

// Height at which a straight-down camera sees `texels_per_pixel` level-0 texels per pixel.
double height_for(double texels_per_pixel, const sc::Camera& c, std::uint32_t height_px) {
    return texels_per_pixel * height_px / (2.0 * std::tan(c.fov_y / 2.0));
}


using tessera::test::pixel_to_ground;

gl::RendererConfig config(gl::Filter filter, std::uint32_t tile_size, std::uint32_t pool, bool srgb, std::uint32_t w = 256,
                          std::uint32_t h = 192) {
    gl::RendererConfig c;
    c.width = w;
    c.height = h;
    c.filter = filter;
    c.max_anisotropy = 8;
    c.tile_size = tile_size;
    c.border = 4;
    c.pool_slots = pool;
    c.srgb = srgb;
    c.staging_bytes = 8u << 20;
    c.feedback_jitter = false;  // feedback at block centres, as cpu_feedback computes it
    return c;
}

sc::SampleFilter scene_filter(gl::Filter f) {
    return f == gl::Filter::bilinear ? sc::SampleFilter::bilinear
           : f == gl::Filter::trilinear ? sc::SampleFilter::trilinear
                                        : sc::SampleFilter::anisotropic;
}

const char* filter_name(gl::Filter f) {
    return f == gl::Filter::bilinear ? "bilinear" : f == gl::Filter::trilinear ? "trilinear" : "anisotropic";
}

sc::Scene terrain(std::uint32_t w, std::uint32_t h, std::uint32_t chunk_texels, double displacement = 0) {
    sc::TerrainOptions o;
    o.vt_width = w;
    o.vt_height = h;
    o.chunk_texels = chunk_texels;
    o.quads_per_chunk = 8;
    o.displacement = displacement;
    auto s = sc::make_terrain(o);
    EXPECT_TRUE(s.ok()) << s.error().message;
    return s.ok() ? std::move(*s) : sc::Scene{};
}

// An image source whose texels a function writes (texel x, y into `out`, texel_bytes of them).
class FunctionSource final : public st::ImageSource {
public:
    using Texel = std::function<void(std::uint32_t x, std::uint32_t y, std::uint8_t* out)>;
    FunctionSource(st::SourceInfo info, Texel texel) : info_(std::move(info)), texel_(std::move(texel)) {}
    const st::SourceInfo& info() const override { return info_; }
    tessera::Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const st::ParallelFor&) override {
        const std::size_t texel_bytes = std::size_t(info_.channels) * st::sample_bytes(info_.sample_type);
        for (std::uint32_t y = y0; y < y0 + count; ++y)
            for (std::uint32_t x = 0; x < info_.width; ++x) texel_(x, y, dst + (std::size_t(y - y0) * info_.width + x) * texel_bytes);
        return tessera::Status();
    }

private:
    st::SourceInfo info_;
    Texel texel_;
};

st::SourceInfo source_info(std::uint32_t w, std::uint32_t h, std::uint32_t channels, st::SampleType type, const char* what) {
    st::SourceInfo info;
    info.width = w;
    info.height = h;
    info.channels = channels;
    info.sample_type = type;
    info.colour_space = st::ColourSpace::linear;
    info.description = what;
    return info;
}

// A smooth RGB pattern: sines of periods 37, 290 and 2300 texels, so neighbouring texels are
// close everywhere (page borders included) at every level, and a seam (a wrong texel, a border
// off by one) shows as an error of several 8-bit steps.
FunctionSource pattern_source(std::uint32_t w, std::uint32_t h) {
    const auto value = [](double v) { return static_cast<std::uint8_t>(std::lround(128 + 100 * v)); };
    return FunctionSource(source_info(w, h, 3, st::SampleType::u8, "smooth pattern"),
                          [value](std::uint32_t x, std::uint32_t y, std::uint8_t* p) {
                              p[0] = value(std::sin(2 * kPi * (x + 0.7 * y) / 37.0));
                              p[1] = value(std::sin(2 * kPi * (0.6 * x - y) / 290.0));
                              p[2] = value(std::cos(2 * kPi * (x + y) / 2300.0));
                          });
}

std::string build_store(const std::string& path, const std::string& input, std::uint32_t tile_size, st::ImageSource* source = nullptr,
                        tessera::Codec codec = tessera::Codec::zstd, std::uint32_t border = 4) {
    st::BuildOptions o;
    o.tile_size = tile_size;
    o.border = border;
    o.codec = codec;  // zstd: lossless
    o.threads = 2;
    // A BC7 store's blocks are drawn as stored and the reference decodes the same blocks, so the
    // encoder's search depth changes nothing checked here (bc7_test checks its quality): the
    // fastest, a quarter of the default's build time.
    o.bc7_effort = 0;
    auto r = source ? st::build_store(*source, path, o) : st::build_store(input, path, o);
    EXPECT_TRUE(r.ok()) << r.error().message;
    return path;
}


// Distinct wanted levels of a view according to the CPU feedback (full resolution).
std::set<std::uint32_t> levels_in_view(const sc::Camera& cam, const st::StoreInfo& info, const gl::RendererConfig& cfg) {
    sc::CpuFeedbackParams p;
    p.main_width = p.fb_width = cfg.width;
    p.main_height = p.fb_height = cfg.height;
    p.rule.filter = scene_filter(cfg.filter);
    std::vector<FeedbackId> ids;
    sc::cpu_feedback(cam, sc::VtGeometry{info.width, info.height, info.tile_payload, info.level_count()}, p, ids);
    std::set<std::uint32_t> levels;
    for (const auto id : ids)
        if (id != kNoPage) levels.insert(tessera::client::unpack_feedback(id).level);
    return levels;
}

// ---------------------------------------------------------------------------------------------

// The VT (runtime + local store, every page resident) against the reference renderer: the
// procedural 2048^2 store on `scene`, each of `cameras`. The same pixels covered, PSNR >= 50 dB
// and max error <= 3 over at least a third of the view, every textured pixel counted once
// (textured = covered pixels), no fallback. Returns the VT for further checks (null on failure).
// Block formats: the reference holds the same decoded blocks (decode_store_levels' format), or
// with `lossless_reference` the store's own texels; at most `max_off_fraction` of the pixels may
// be off by more than 3.
// The format a layer's reference levels are decoded in: the atlas's own block format (its texels
// exactly), else RGBA8.
tessera::client::PageFormat reference_format(const gl::RendererConfig& cfg, std::uint32_t layer, bool lossless) {
    const auto f = layer == 0 ? cfg.page_format : cfg.more_layers.at(layer - 1).page_format;
    return lossless || !tessera::client::is_block_compressed(f) ? tessera::client::PageFormat::rgba8 : f;
}

// Loads every page of `store` and renders `cameras` with the VT and with the reference renderer
// (the drawn layer, lit by the normal layer where cfg says so), expecting the frames to match.
std::unique_ptr<Vt> expect_store_matches_reference(const gl::RendererConfig& cfg, const std::string& store, const sc::Scene& scene,
                                                   std::span<const sc::Camera> cameras, double min_psnr, int max_error,
                                                   bool lossless_reference, double max_off_fraction) {
    auto vt = make_vt(cfg, store, scene);
    if (!vt) {
        ADD_FAILURE() << "no VT";
        return nullptr;
    }
    if (!load_everything(*vt)) {
        ADD_FAILURE() << "resident " << residency_of(*vt->runtime).stats().resident_pages << " of " << page_count(vt->info);
        return nullptr;
    }
    auto levels = tessera::client::decode_store_levels(store, 16384, reference_format(cfg, cfg.show_layer, lossless_reference), cfg.show_layer);
    if (!levels) {
        ADD_FAILURE() << levels.error().message;
        return nullptr;
    }
    std::vector<gl::ReferenceRenderer::Level> normals;
    if (cfg.normal_layer && cfg.show_layer == 0) {
        auto n = tessera::client::decode_store_levels(store, 16384, reference_format(cfg, *cfg.normal_layer, lossless_reference), *cfg.normal_layer);
        if (!n) {
            ADD_FAILURE() << n.error().message;
            return nullptr;
        }
        normals = std::move(*n);
    }
    // Trilinear and anisotropic block pages blend with the atlas's second level, so the reference
    // holds those blocks too; an RGBA8 layer beside them blends with its next level (its second
    // level is made from it: the page-mip pass).
    using Levels = std::vector<gl::ReferenceRenderer::Level>;
    const auto block = [&](std::uint32_t layer) {
        return tessera::client::is_block_compressed(reference_format(cfg, layer, lossless_reference));
    };
    const bool lit = !normals.empty();
    Levels second, normal_second;
    const auto second_of = [&](std::uint32_t layer, const Levels& own) {
        if (!block(layer)) return Levels(own.begin() + 1, own.end());
        auto s = tessera::client::decode_store_second_levels(store, 16384, reference_format(cfg, layer, lossless_reference), layer);
        if (!s) ADD_FAILURE() << s.error().message;
        return s ? std::move(*s) : Levels();
    };
    if (cfg.filter != gl::Filter::bilinear && (block(cfg.show_layer) || (lit && block(*cfg.normal_layer)))) {
        second = second_of(cfg.show_layer, *levels);
        if (lit) normal_second = second_of(*cfg.normal_layer, normals);
    }
    std::vector<Levels> layers, layer_seconds;
    if (lit) layers.push_back(normals);
    if (!second.empty()) layer_seconds.resize(layers.size());
    if (!second.empty() && lit) layer_seconds[0] = normal_second;
    auto ref = gl::ReferenceRenderer::create(cfg, *levels, layers, second, layer_seconds);
    if (!ref) {
        ADD_FAILURE() << ref.error().message;
        return nullptr;
    }
    if (const auto st = (*ref)->set_scene(scene); !st.ok()) {
        ADD_FAILURE() << st.error().message;
        return nullptr;
    }
    // The independent reference: the same levels sampled on the CPU (cpu_reference.hpp).
    std::vector<cpu::Material> cpu_materials(1);
    cpu_materials[0].scene = &scene;
    cpu_materials[0].colour = cpu::make_texture(*levels, cfg.srgb, second);
    if (lit) cpu_materials[0].normals = cpu::make_texture(normals, false, normal_second);
    for (const auto& cam : cameras) {
        const Frame f = render_vt(*vt->renderer, cam);
        const auto independent = cpu::render(cfg, cpu_materials, cam);
        if (!independent) {
            ADD_FAILURE() << independent.error().message;
            return nullptr;
        }
        // The same bounds as against the GL reference below (measured: 52.1-63.4 dB, max error 2,
        // no pixel off by more than 3, against the same texels). Lit, 52.5 dB (measured 53.9-55.1):
        // the terrain's normals lean little, so a wrong lighting formula moves pixels by a few
        // steps only (an ambient of 0.30 instead of 0.35: 49.0-50.0 dB).
        const auto vs_cpu = cpu::compare(f.rgba, *independent);
        std::printf("  %s\n", cpu::describe(vs_cpu).c_str());
        EXPECT_EQ(vs_cpu.coverage_differs, 0u) << cpu::describe(vs_cpu);
        EXPECT_GT(vs_cpu.compared, cfg.width * cfg.height / 3);
        EXPECT_GE(vs_cpu.psnr, lit ? std::max(min_psnr, 52.5) : min_psnr) << filter_name(cfg.filter) << " " << cpu::describe(vs_cpu);
        EXPECT_LE(vs_cpu.max_error, max_error) << filter_name(cfg.filter) << " " << cpu::describe(vs_cpu);
        EXPECT_LE(double(vs_cpu.over_3), max_off_fraction * double(vs_cpu.compared)) << cpu::describe(vs_cpu);
        (*ref)->render(cam);
        const auto want = (*ref)->read_color();
        const auto mask = coverage(want);
        EXPECT_EQ(coverage(f.rgba), mask) << "the VT and the reference cover different pixels";
        const auto e = tessera::client::compare_images(f.rgba, want, cfg.width, cfg.height, mask);
        EXPECT_GT(e.pixels, cfg.width * cfg.height / 3);
        EXPECT_GE(e.psnr, min_psnr) << filter_name(cfg.filter) << ": max error " << e.max_error << " over " << e.pixels << " pixels";
        EXPECT_LE(e.max_error, max_error) << filter_name(cfg.filter) << ": a seam or a wrong texel somewhere";
        std::size_t off_by_more_than_3 = 0;  // pixels of the mask with any RGB channel off by > 3
        for (std::size_t i = 0; i < mask.size(); ++i)
            for (int ch = 0; mask[i] && ch < 3; ++ch)
                if (std::abs(int(f.rgba[i * 4 + std::size_t(ch)]) - int(want[i * 4 + std::size_t(ch)])) > 3) {
                    ++off_by_more_than_3;
                    break;
                }
        EXPECT_LE(double(off_by_more_than_3), max_off_fraction * double(count(mask)))
            << "more than " << 100 * max_off_fraction << "% of the pixels are off by more than 3";
        EXPECT_EQ(f.counters.textured_pixels, count(mask)) << "a hidden fragment was counted, or a visible one was not";
        EXPECT_EQ(f.counters.fallback_unbiased, 0u);
        EXPECT_EQ(f.counters.fallback_biased, 0u);
        const auto wanted = levels_in_view(cam, vt->info, cfg);
        std::printf("  layer %u%s %s %s camera (%.0f, %.0f, %.0f): levels %zu (%u..%u), %zu textured pixels, PSNR %.1f dB, max error %d "
                    "(%zu pixels off by more than 3)\n",
                    cfg.show_layer, cfg.normal_layer && cfg.show_layer == 0 ? " lit" : "",
                    std::string(tessera::client::to_string(reference_format(cfg, cfg.show_layer, false))).c_str(),
                    filter_name(cfg.filter), cam.position[0],
                    cam.position[1], cam.position[2], wanted.size(), *wanted.begin(), *wanted.rbegin(), count(mask), e.psnr,
                    e.max_error, off_by_more_than_3);
    }
    return vt;
}

std::unique_ptr<Vt> expect_matches_reference(const gl::RendererConfig& cfg, const sc::Scene& scene,
                                             std::span<const sc::Camera> cameras, double min_psnr = 50.0,
                                             int max_error = 3, bool lossless_reference = false,
                                             double max_off_fraction = 0.001, tessera::Codec codec = tessera::Codec::zstd,
                                             std::uint32_t border = 4, const std::string& input = "procedural:terrain:2048") {
    ScratchDir dir;
    const std::string store = build_store(dir.file("terrain.tsr"), input, 128, nullptr, codec, border);
    return expect_store_matches_reference(cfg, store, scene, cameras, min_psnr, max_error, lossless_reference, max_off_fraction);
}

class RenderVsReference : public ::testing::TestWithParam<gl::Filter> {};

TEST_P(RenderVsReference, MatchesTheMipmappedReferenceWithEveryPageResident) {
    REQUIRE_GL(ctx);
    const auto cfg = config(GetParam(), 128, 512, /*srgb=*/true);
    const sc::Camera cameras[] = {
        looking(1024, -120, 160, kPi / 2, -0.42),   // over the near edge, towards the far one
        looking(300, 400, 60, 0.6, -0.25),          // low and grazing, turned
        straight_down(700.5, 900.25, height_for(1.7, straight_down(0, 0, 1), cfg.height)),
    };
    const auto vt = expect_matches_reference(cfg, terrain(2048, 2048, 512), cameras);
    ASSERT_TRUE(vt);
    // The first view spans several levels.
    EXPECT_GE(levels_in_view(cameras[0], vt->info, cfg).size(), 3u);
}

INSTANTIATE_TEST_SUITE_P(Filters, RenderVsReference,
                         ::testing::Values(gl::Filter::bilinear, gl::Filter::trilinear, gl::Filter::anisotropic),
                         [](const auto& p) { return std::string(filter_name(p.param)); });

// Block-compressed pages, transcoded from the store's tiles on the client or, with a block-codec
// store, the builder's blocks as stored (second level included), against a reference holding the
// same decoded blocks: the VT's addressing and filtering do not depend on the format (>= 50 dB;
// BC1: a few pixels on level boundaries, where the VT's LoD rule and the reference's sampler pick
// different levels, show the two levels' different block errors). Trilinear and anisotropic blend
// with the atlas's second level, each page's 2x2 means encoded again, which the reference holds
// too (decode_store_second_levels); with a border of 8 its blocks start on the page's edge, so a
// page's second-level border blocks are its neighbour's edge blocks (docs/renderer.md, "Page
// formats"). One case against the store's lossless texels holds BC1 to its quality bar.
struct BlockCase {
    tessera::client::PageFormat format;
    gl::Filter filter;
    bool srgb;                // bc4/bc5 hold data: never sRGB
    bool lossless_reference;  // against the store's texels, not the same blocks
    double min_psnr;
    int max_error;
    double max_off_fraction;  // of pixels off by more than 3
    tessera::Codec store_codec = tessera::Codec::zstd;  // a block codec: the builder's blocks, uploaded as stored
    std::uint32_t border = 4;
    // bc4: the terrain's 16-bit heights (one channel); bc5: its normals (two): data, not sRGB colour
    const char* input = "procedural:terrain:2048";
};
class RenderBlockPages : public ::testing::TestWithParam<BlockCase> {};

TEST_P(RenderBlockPages, MatchTheReference) {
    REQUIRE_GL(ctx);
    const BlockCase& b = GetParam();
    auto cfg = config(b.filter, 128, 512, b.srgb);
    cfg.page_format = b.format;
    cfg.border = b.border;
    const sc::Camera cameras[] = {
        looking(1024, -120, 160, kPi / 2, -0.42),
        straight_down(700.5, 900.25, height_for(1.7, straight_down(0, 0, 1), cfg.height)),
    };
    const auto vt = expect_matches_reference(cfg, terrain(2048, 2048, 512), cameras, b.min_psnr, b.max_error,
                                             b.lossless_reference, b.max_off_fraction, b.store_codec, b.border, b.input);
    ASSERT_TRUE(vt);
    EXPECT_EQ(vt->renderer->pool_format().format, b.format);
    EXPECT_EQ(vt->renderer->pool_format().second_level, b.filter != gl::Filter::bilinear);
}

using tessera::client::PageFormat;
INSTANTIATE_TEST_SUITE_P(
    Formats, RenderBlockPages,
    ::testing::Values(BlockCase{PageFormat::bc1, gl::Filter::bilinear, true, false, 50.0, 32, 0.001},
                      BlockCase{PageFormat::bc5, gl::Filter::bilinear, false, false, 50.0, 3, 0.0, tessera::Codec::zstd, 4,
                                "procedural:terrain-normal:2048"},
                      BlockCase{PageFormat::bc1, gl::Filter::trilinear, true, false, 50.0, 32, 0.001, tessera::Codec::zstd, 8},
                      BlockCase{PageFormat::bc1, gl::Filter::anisotropic, true, false, 50.0, 32, 0.001, tessera::Codec::zstd, 8},
                      BlockCase{PageFormat::bc5, gl::Filter::trilinear, false, false, 50.0, 3, 0.0, tessera::Codec::zstd, 8,
                                "procedural:terrain-normal:2048"},
                      BlockCase{PageFormat::bc4, gl::Filter::bilinear, false, false, 50.0, 3, 0.0, tessera::Codec::zstd, 4,
                                "procedural:terrain-height:2048"},
                      BlockCase{PageFormat::bc4, gl::Filter::trilinear, false, false, 50.0, 3, 0.0, tessera::Codec::zstd, 8,
                                "procedural:terrain-height:2048"},
                      BlockCase{PageFormat::bc1, gl::Filter::trilinear, true, true, 32.0, 255, 1.0},
                      BlockCase{PageFormat::bc1, gl::Filter::bilinear, true, false, 50.0, 32, 0.001, tessera::Codec::bc1},
                      BlockCase{PageFormat::bc7, gl::Filter::bilinear, true, false, 50.0, 32, 0.001, tessera::Codec::bc7},
                      BlockCase{PageFormat::bc1, gl::Filter::trilinear, true, false, 50.0, 32, 0.001, tessera::Codec::bc1, 8},
                      BlockCase{PageFormat::bc7, gl::Filter::anisotropic, true, false, 50.0, 32, 0.001, tessera::Codec::bc7, 8}),
    [](const auto& p) {
        return std::string(tessera::client::to_string(p.param.format)) + "_" + filter_name(p.param.filter) +
               (p.param.store_codec == tessera::Codec::zstd ? "" : "_" + std::string(tessera::to_string(p.param.store_codec)) + "_store") +
               (p.param.lossless_reference ? "_vs_lossless" : "") + (p.param.border == 4 ? "" : "_border" + std::to_string(p.param.border));
    });

// A height layer: one channel of u16 (or f32) samples spread over their whole range, so that
// any rounding to 8 bits or clamping shows.
FunctionSource height_source(std::uint32_t side, st::SampleType type) {
    return FunctionSource(source_info(side, side, 1, type, "height layer"), [type](std::uint32_t x, std::uint32_t y, std::uint8_t* p) {
        if (type == st::SampleType::u16) {
            const auto v = static_cast<std::uint16_t>(x * 131u + y * 977u + (x * y) % 4099u);
            std::memcpy(p, &v, 2);
        } else {
            const float v = float(x) * 0.37f - float(y) * 1.31f + 1e-3f * float((x * y) % 1009u);
            std::memcpy(p, &v, 4);
        }
    });
}

// 16-bit and float pages on the GPU are the store's samples exactly (no 8-bit clamp): every page
// of every level read back from the atlas equals the stored tile, bilinear (one level) and
// trilinear (two: the page-mip pass draws into R16 and R32F too).
// Every page of every level of `store` is resident in `vt`, and layer `layer` of its atlas slot
// reads back as `want_page` says the page should be (`want_page` fills its buffer from the stored
// tile, or fails the test). Returns the pages compared.
std::size_t expect_pages_read_back(Vt& vt, const st::StoreReader& reader, std::uint32_t layer,
                                   const std::function<bool(const st::Tile&, std::vector<std::uint8_t>&)>& want_page) {
    const auto& info = reader.info();
    const auto* table = residency_of(*vt.runtime).table(vt.texture);
    EXPECT_NE(table, nullptr);
    if (!table) return 0;
    std::vector<std::uint8_t> want;
    std::size_t pages = 0;
    for (std::uint32_t l = 0; l < info.level_count(); ++l)
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                auto tile = reader.read_tile({l, x, y});
                EXPECT_TRUE(tile.ok());
                if (!tile || !want_page(*tile, want)) return pages;
                const auto e = table->entry(l, x, y);
                EXPECT_TRUE(tessera::client::PageTable::entry_valid(e));
                EXPECT_EQ(tessera::client::PageTable::entry_level(e), l);
                EXPECT_EQ(vt.renderer->read_page(tessera::client::PageTable::entry_slot(e), layer), want)
                    << "layer " << layer << " page " << l << "/" << x << "/" << y << " differs on the GPU";
                ++pages;
            }
    return pages;
}

TEST(RenderDataPages, SixteenBitAndFloatLayersOnTheGpuEqualTheStoreExactly) {
    REQUIRE_GL(ctx);
    using tessera::client::PageFormat;
    for (const auto& [type, format] : {std::pair{st::SampleType::u16, PageFormat::r16}, std::pair{st::SampleType::f32, PageFormat::r32f}})
        for (const auto filter : {gl::Filter::bilinear, gl::Filter::trilinear}) {
            SCOPED_TRACE(std::string(tessera::client::to_string(format)) + " " + filter_name(filter));
            ScratchDir dir;
            auto src = height_source(512, type);
            const std::string store = build_store(dir.file("height.tsr"), "", 128, &src);
            auto cfg = config(filter, 128, 64, /*srgb=*/false);
            cfg.page_format = format;
            auto vt = make_vt(cfg, store, terrain(512, 512, 512));
            ASSERT_TRUE(vt);
            ASSERT_TRUE(load_everything(*vt));
            render_vt(*vt->renderer, straight_down(256, 256, height_for(1.0, straight_down(0, 0, 1), cfg.height)));
            auto reader = st::StoreReader::open(store);
            ASSERT_TRUE(reader.ok());
            const auto& info = (*reader)->info();
            tessera::client::Scratch scratch;
            const std::size_t pages = expect_pages_read_back(*vt, **reader, 0, [&](const st::Tile& tile, std::vector<std::uint8_t>& want) {
                want.resize(page_bytes(format, info.tile_size()));
                const bool ok = tessera::client::transcode_page(info, tile.kind, info.codec, tile.bytes, format, want, scratch).ok();
                EXPECT_TRUE(ok);
                return ok;
            });
            EXPECT_EQ(pages, page_count(info));
            EXPECT_EQ(vt->renderer->stats().gl_errors, 0u);
        }
}

// A three-layer store of the procedural terrain: colour (lossless), normals (`normal_codec`) and
// heights (16-bit, lossless), 1024² in 128-texel tiles.
std::string build_layered_terrain(const std::string& path, tessera::Codec normal_codec) {
    const st::LayerInput layers[] = {{"colour", "procedural:terrain:1024", tessera::Codec::zstd},
                                     {"normal", "procedural:terrain-normal:1024", normal_codec},
                                     {"height", "procedural:terrain-height:1024", tessera::Codec::zstd}};
    st::BuildOptions o;
    o.tile_size = 128;
    o.border = 4;
    o.threads = 2;
    auto r = st::build_layered_store(layers, path, o);
    EXPECT_TRUE(r.ok()) << r.error().message;
    return path;
}

// The pool of that store: colour rgba8 (sRGB), normals rgba8 or bc5, heights r16 exactly.
gl::RendererConfig layered_config(gl::Filter filter, tessera::client::PageFormat normal_format) {
    auto cfg = config(filter, 128, 128, /*srgb=*/true);  // every page of the 1024² store: 120
    cfg.more_layers = {{normal_format, false}, {tessera::client::PageFormat::r16, false}};
    return cfg;
}

// Every layer of a multi-layer store renders as the reference renders that layer alone (one page
// table, one residency, an atlas per layer), and the colour lit by the normal layer as the
// reference lights it; with the normals in bc5 too. No pixel falls back in any layer.
TEST(RenderLayers, EveryLayerMatchesTheReference) {
    REQUIRE_GL(ctx);
    using tessera::client::PageFormat;
    const sc::Camera cameras[] = {
        looking(512, -60, 90, kPi / 2, -0.42),
        straight_down(350.5, 450.25, height_for(1.7, straight_down(0, 0, 1), 192)),
    };
    for (const auto normal_format : {PageFormat::rgba8, PageFormat::bc5}) {
        ScratchDir dir;
        const std::string store = build_layered_terrain(
            dir.file("layers.tsr"), normal_format == PageFormat::bc5 ? tessera::Codec::bc5 : tessera::Codec::zstd);
        for (const auto filter : {gl::Filter::bilinear, gl::Filter::trilinear}) {
            // BC5 as RenderBlockPages holds block pages: against the same blocks (trilinear: the
            // atlas's second level too), where a few pixels on level boundaries show two levels'
            // block errors.
            const bool bc5 = normal_format == PageFormat::bc5;
            const double min_psnr = 50.0;
            const int max_error = bc5 ? 8 : 3;
            const double off_fraction = 0.001;
            for (std::uint32_t show = 0; show < 3; ++show) {
                SCOPED_TRACE("normals " + std::string(tessera::client::to_string(normal_format)) + " " + filter_name(filter) + " layer " +
                             std::to_string(show));
                auto cfg = layered_config(filter, normal_format);
                cfg.show_layer = show;
                cfg.srgb = show == 0;  // data layers are shown as they are
                const auto vt =
                    expect_store_matches_reference(cfg, store, terrain(1024, 1024, 512), cameras, min_psnr, max_error, false, off_fraction);
                ASSERT_TRUE(vt);
                EXPECT_EQ(vt->renderer->pool_format().layer_count(), 3u);
                EXPECT_EQ(vt->renderer->stats().malformed_uploads, 0u);
            }
            SCOPED_TRACE("normals " + std::string(tessera::client::to_string(normal_format)) + " " + filter_name(filter) + " lit");
            auto cfg = layered_config(filter, normal_format);
            cfg.normal_layer = 1;
            ASSERT_TRUE(expect_store_matches_reference(cfg, store, terrain(1024, 1024, 512), cameras, min_psnr, max_error, false, off_fraction));
        }
    }
}

// A 16-bit height layer's texels on the GPU are the store's exactly, page by page, in a pool
// whose other layers are colour and normals; a pool that does not fit the store's layers is
// refused with the layer named.
TEST(RenderLayers, SixteenBitHeightLayerReadsBackExactly) {
    REQUIRE_GL(ctx);
    using tessera::client::PageFormat;
    ScratchDir dir;
    const std::string store = build_layered_terrain(dir.file("layers.tsr"), tessera::Codec::bc5);
    auto cfg = layered_config(gl::Filter::trilinear, PageFormat::bc5);
    auto vt = make_vt(cfg, store, terrain(1024, 1024, 512));
    ASSERT_TRUE(vt);
    ASSERT_TRUE(load_everything(*vt));
    render_vt(*vt->renderer, straight_down(512, 512, height_for(1.0, straight_down(0, 0, 1), cfg.height)));
    auto reader = st::StoreReader::open(store);
    ASSERT_TRUE(reader.ok());
    const auto& info = (*reader)->info();
    ASSERT_EQ(info.layers.size(), 3u);
    const st::StoreInfo height = st::layer_store_info(info, 2);
    ASSERT_EQ(height.sample_type, st::SampleType::u16);
    const std::size_t pages = expect_pages_read_back(*vt, **reader, 2, [&](const st::Tile& tile, std::vector<std::uint8_t>& want) {
        auto parts = st::split_layers(info, tile.bytes);
        EXPECT_TRUE(parts.ok()) << (parts ? "" : parts.error().message);
        const bool ok = parts && st::decode_tile(height, st::layer_tile(tile.key, (*parts)[2]), want).ok();
        EXPECT_TRUE(ok);
        return ok;
    });
    EXPECT_EQ(pages, page_count(info));
    EXPECT_TRUE(vt->renderer->read_page(0, 3).empty()) << "there is no layer 3";

    // A pool of two layers, or with bc4 where the normals have two channels: refused, named.
    auto wrong = layered_config(gl::Filter::bilinear, PageFormat::bc4);
    auto r = gl::VtRenderer::create(wrong);
    ASSERT_TRUE(r.ok());
    tessera::client::RuntimeConfig rc;
    rc.residency.pool_slots = wrong.pool_slots;
    auto rt = tessera::client::Runtime::create(rc, **r);
    ASSERT_TRUE(rt.ok());
    auto source = tessera::client::make_local_store_source(1);
    auto tex = (*rt)->add_texture(*source, store);
    ASSERT_FALSE(tex.ok());
    EXPECT_NE(tex.error().message.find("layer normal"), std::string::npos) << tex.error().message;
    wrong.more_layers.pop_back();
    auto r2 = gl::VtRenderer::create(wrong);
    ASSERT_TRUE(r2.ok());
    auto rt2 = tessera::client::Runtime::create(rc, **r2);
    ASSERT_TRUE(rt2.ok());
    auto tex2 = (*rt2)->add_texture(*source, store);
    ASSERT_FALSE(tex2.ok());
    EXPECT_NE(tex2.error().message.find("3 layers"), std::string::npos) << tex2.error().message;
}

// Displaced terrain (hills hide other hills) drawn front to back instead of with a depth
// pre-pass: every textured pixel is still counted once (textured = covered pixels) and shaded
// with what it sees (the reference's image), and no frame needed the pre-pass. Drawn in any
// other order, hidden fragments would be counted too.
TEST(RenderDisplaced, FrontToBackCountsEachVisiblePixelOnceWithoutAPrePass) {
    REQUIRE_GL(ctx);
    const auto scene = terrain(2048, 2048, 512, 300);
    ASSERT_FALSE(sc::overdraw_free(scene));
    const sc::Camera cameras[] = {
        looking(1024, -200, 420, kPi / 2, -0.30),  // over the near edge: rows of hills behind each other
        looking(300, 400, 180, 0.6, -0.12),        // low and grazing, between the hills
        looking(1900, 1800, 350, -2.4, -0.35),     // from the far corner, looking back
    };
    const auto vt = expect_matches_reference(config(gl::Filter::bilinear, 128, 512, /*srgb=*/true), scene, cameras);
    ASSERT_TRUE(vt);
    EXPECT_EQ(vt->renderer->stats().depth_prepasses, 0u) << "the displaced terrain was drawn with a pre-pass";
}

// A staging ring too small for one page: every upload goes straight from client memory, and the
// frame is still right.
TEST(RenderVsReferenceSmallRing, UploadsStillLandWhenTheStagingRingIsFull) {
    REQUIRE_GL(ctx);
    ScratchDir dir;
    const std::string store = build_store(dir.file("terrain.tsr"), "procedural:terrain:1024", 128);
    auto cfg = config(gl::Filter::trilinear, 128, 128, /*srgb=*/false, 160, 120);
    cfg.staging_bytes = 48 * 1024;  // a page is 64 KiB
    cfg.staging_pages = 0;          // and none is decoded into lent memory: every page takes the ring
    const auto scene = terrain(1024, 1024, 512);
    auto vt = make_vt(cfg, store, scene);
    ASSERT_TRUE(vt);
    ASSERT_TRUE(load_everything(*vt));
    EXPECT_GT(vt->renderer->stats().direct_uploads, 0u);
    EXPECT_EQ(vt->renderer->stats().malformed_uploads, 0u);
    auto levels = tessera::client::decode_store_levels(store);
    ASSERT_TRUE(levels.ok()) << levels.error().message;
    auto ref = gl::ReferenceRenderer::create(cfg, *levels);
    ASSERT_TRUE(ref.ok()) << ref.error().message;
    ASSERT_TRUE((*ref)->set_scene(scene).ok());
    const auto cam = looking(512, -60, 90, kPi / 2, -0.4);
    const Frame f = render_vt(*vt->renderer, cam);
    (*ref)->render(cam);
    const auto want = (*ref)->read_color();
    const auto e = tessera::client::compare_images(f.rgba, want, cfg.width, cfg.height, coverage(want));
    EXPECT_GE(e.psnr, 50.0) << "max error " << e.max_error;
    EXPECT_EQ(f.counters.fallback_unbiased, 0u);
}

// Pages decoded into the renderer's lent staging memory (the default) are uploaded from where
// the transcoder wrote them: none is copied on the CPU. Without it, every page is. The frames are
// the same (up to where the pages' slots fall) either way.
TEST(RenderVsReferenceStaging, PagesDecodedIntoLentMemoryAreUploadedWithoutACopy) {
    REQUIRE_GL(ctx);
    ScratchDir dir;
    const std::string store = build_store(dir.file("terrain.tsr"), "procedural:terrain:1024", 128);
    const auto scene = terrain(1024, 1024, 512);
    const auto cam = looking(512, -60, 90, kPi / 2, -0.4);
    std::vector<std::uint8_t> frames[2];
    for (const std::uint32_t lent : {192u, 0u}) {
        auto cfg = config(gl::Filter::trilinear, 128, 128, /*srgb=*/false, 160, 120);
        cfg.staging_pages = lent;
        auto vt = make_vt(cfg, store, scene);
        ASSERT_TRUE(vt);
        ASSERT_TRUE(load_everything(*vt));
        const auto stats = vt->renderer->stats();
        ASSERT_GT(stats.pages_uploaded, 0u);
        EXPECT_EQ(stats.malformed_uploads, 0u);
        if (lent > 0) {
            EXPECT_EQ(stats.pages_copied, 0u) << "of " << stats.pages_uploaded << " pages";
            EXPECT_EQ(stats.page_bytes_copied, 0u);
        } else {
            EXPECT_EQ(stats.pages_copied, stats.pages_uploaded);
            EXPECT_EQ(stats.page_bytes_copied, stats.pages_uploaded * 128u * 128u * 4u);
        }
        const Frame f = render_vt(*vt->renderer, cam);
        EXPECT_EQ(f.counters.fallback_unbiased, 0u);
        frames[lent > 0 ? 0 : 1] = f.rgba;
    }
    std::size_t differing = 0;
    int largest = 0;
    for (std::size_t i = 0; i < std::min(frames[0].size(), frames[1].size()); ++i)
        if (frames[0][i] != frames[1][i]) {
            ++differing;
            largest = std::max(largest, std::abs(int(frames[0][i]) - int(frames[1][i])));
        }
    // Pages land in whichever slots free up first, so on a busy machine the two runs may place
    // them differently, and a filtered sample's rounding can move by one (seen: 1-10 bytes of
    // 76 800, by 1). A page uploaded from memory not yet written, or reused too early, differs
    // by far more.
    EXPECT_LE(largest, 1) << "the same pages drew a different frame: " << differing << " bytes differ, by up to " << largest;
    EXPECT_LE(differing, frames[0].size() / 1000) << differing << " bytes differ, by up to " << largest;
}

// ---------------------------------------------------------------------------------------------

// RGBA8 pages, and block pages (BC1 transcoded on the client, BC7 as the builder stored it) with a
// border of 8, so that the atlas's second level is seamless too (docs/renderer.md, "Page
// formats"): their reference holds the same decoded blocks, both levels.
struct SeamCase {
    gl::Filter filter;
    tessera::client::PageFormat format = tessera::client::PageFormat::rgba8;
    tessera::Codec codec = tessera::Codec::zstd;
    std::uint32_t border = 4;
};
class RenderSeams : public ::testing::TestWithParam<SeamCase> {};

TEST_P(RenderSeams, NoDiscontinuitiesAtPageBordersAtAnyLevel) {
    REQUIRE_GL(ctx);
    ScratchDir dir;
    const SeamCase& c = GetParam();
    auto pattern = pattern_source(1024, 1024);
    // Tiles of 64: P = 56 (48 with a border of 8), borders everywhere.
    const std::string store = build_store(dir.file("pattern.tsr"), "", 64, &pattern, c.codec, c.border);
    auto cfg = config(c.filter, 64, 1024, /*srgb=*/false, 192, 144);  // every page resident (685 with P = 48)
    cfg.border = c.border;
    cfg.page_format = c.format;
    const double P = 64.0 - 2.0 * c.border;
    const auto scene = terrain(1024, 1024, 256);
    auto vt = make_vt(cfg, store, scene);
    ASSERT_TRUE(vt);
    ASSERT_TRUE(load_everything(*vt));
    auto levels = tessera::client::decode_store_levels(store, 16384, c.format);
    ASSERT_TRUE(levels.ok()) << levels.error().message;
    std::vector<gl::ReferenceRenderer::Level> second;
    if (tessera::client::is_block_compressed(c.format) && c.filter != gl::Filter::bilinear) {
        auto s = tessera::client::decode_store_second_levels(store, 16384, c.format);
        ASSERT_TRUE(s.ok()) << s.error().message;
        second = std::move(*s);
    }
    auto ref = gl::ReferenceRenderer::create(cfg, *levels, {}, second);
    ASSERT_TRUE(ref.ok()) << ref.error().message;
    ASSERT_TRUE((*ref)->set_scene(scene).ok());

    // min_pixels: the pixels the terrain must cover (an empty or mostly empty frame would compare
    // perfectly): the whole frame straight down up to lod 1.5; measured 22 680-24 336, 9 409 and 2 704
    // at 2.6, 3.4 and 4.3 (the texture smaller than the frame), 9 793-22 680 for the grazing views.
    struct View {
        sc::Camera camera;
        const char* what;
        std::uint64_t min_pixels;
    };
    const std::uint64_t frame_pixels = std::uint64_t(cfg.width) * cfg.height;
    std::vector<View> views;
    // Straight down at lod -1.3 (magnified), 0.4, 1.5, 2.6, 3.4 and 4.3: each level sampled (and, for
    // trilinear, blended with the next), the view centred near a page corner.
    for (const double lod : {-1.3, 0.4, 1.5, 2.6, 3.4, 4.3}) {
        const double tpp = std::exp2(lod);
        const double h = height_for(tpp, straight_down(0, 0, 1), cfg.height);
        const std::uint64_t min_pixels = lod <= 1.5 ? frame_pixels : lod <= 2.6 ? 22000 : lod <= 3.4 ? 9000 : 2500;
        views.push_back({straight_down(P * 9 + 3.3, P * 8 - 2.6, h), "straight down", min_pixels});
    }
    views.push_back({looking(500, -30, 14, kPi / 2 + 0.3, -0.16), "grazing", 9000});  // anisotropy up to the limit
    views.push_back({looking(-40, 520, 30, 0.05, -0.3), "grazing 2", 9000});
    std::vector<cpu::Material> cpu_materials(1);
    cpu_materials[0].scene = &scene;
    cpu_materials[0].colour = cpu::make_texture(*levels, cfg.srgb, second);
    for (const auto& v : views) {
        const Frame f = render_vt(*vt->renderer, v.camera);
        // Against the independent reference too (measured: 52.1-57.6 dB, max error 2).
        const auto independent = cpu::render(cfg, cpu_materials, v.camera);
        ASSERT_TRUE(independent.ok()) << independent.error().message;
        const auto vs_cpu = cpu::compare(f.rgba, *independent);
        std::printf("  %s\n", cpu::describe(vs_cpu).c_str());
        EXPECT_EQ(vs_cpu.coverage_differs, 0u) << v.what << " " << cpu::describe(vs_cpu);
        EXPECT_GE(vs_cpu.compared, v.min_pixels) << v.what;
        EXPECT_GE(vs_cpu.psnr, 51.0) << v.what << " at z " << v.camera.position[2] << " " << cpu::describe(vs_cpu);
        EXPECT_LE(vs_cpu.max_error, 3) << v.what << " at z " << v.camera.position[2] << " " << cpu::describe(vs_cpu);
        (*ref)->render(v.camera);
        const auto want = (*ref)->read_color();
        const auto mask = coverage(want);
        const auto e = tessera::client::compare_images(f.rgba, want, cfg.width, cfg.height, mask);
        const auto lv = levels_in_view(v.camera, vt->info, cfg);
        EXPECT_GE(e.psnr, 50.0) << v.what << " at z " << v.camera.position[2] << ": max error " << e.max_error;
        EXPECT_LE(e.max_error, 3) << v.what << " at z " << v.camera.position[2];
        EXPECT_GE(e.pixels, v.min_pixels) << v.what << " at z " << v.camera.position[2] << ": too little of the frame covered";
        EXPECT_EQ(count(coverage(f.rgba)), count(mask)) << v.what << ": the VT and the reference cover different pixels";
        EXPECT_EQ(f.counters.fallback_unbiased, 0u);
        std::printf("  %s %s %s z=%.1f levels %u..%u: PSNR %.1f dB, max error %d over %llu px\n",
                    std::string(tessera::client::to_string(c.format)).c_str(), filter_name(c.filter), v.what,
                    v.camera.position[2], lv.empty() ? 0 : *lv.begin(), lv.empty() ? 0 : *lv.rbegin(), e.psnr, e.max_error,
                    static_cast<unsigned long long>(e.pixels));
    }
}

INSTANTIATE_TEST_SUITE_P(
    Formats, RenderSeams,
    ::testing::Values(SeamCase{gl::Filter::bilinear}, SeamCase{gl::Filter::trilinear}, SeamCase{gl::Filter::anisotropic},
                      SeamCase{gl::Filter::bilinear, PageFormat::bc1, tessera::Codec::zstd, 8},
                      SeamCase{gl::Filter::trilinear, PageFormat::bc1, tessera::Codec::zstd, 8},
                      SeamCase{gl::Filter::anisotropic, PageFormat::bc1, tessera::Codec::zstd, 8},
                      SeamCase{gl::Filter::anisotropic, PageFormat::bc7, tessera::Codec::bc7, 8}),
    [](const auto& p) {
        return std::string(tessera::client::to_string(p.param.format)) + "_" + filter_name(p.param.filter) +
               (p.param.codec == tessera::Codec::zstd ? "" : "_" + std::string(tessera::to_string(p.param.codec)) + "_store");
    });

// ---------------------------------------------------------------------------------------------

struct FeedbackCase {
    gl::Filter filter;
    float bias;
};

void PrintTo(const FeedbackCase& c, std::ostream* os) {
    gl::PrintTo(c.filter, os);
    *os << " bias " << c.bias;
}

class RenderFeedback : public ::testing::TestWithParam<FeedbackCase> {};

TEST_P(RenderFeedback, GpuFeedbackRequestsTheCpuFeedbackPages) {
    REQUIRE_GL(ctx);
    const auto [filter, bias] = GetParam();
    // Geometry only: the feedback pass needs no resident page.
    const auto info = store_geometry(1u << 16, 1u << 16, 256);
    auto cfg = config(filter, 256, 16, /*srgb=*/false, 256, 192);
    cfg.feedback_scale = 8;
    auto r = gl::VtRenderer::create(cfg);
    ASSERT_TRUE(r.ok()) << r.error().message;
    auto& renderer = **r;
    ASSERT_TRUE(renderer.add_texture(3, info).ok());
    ASSERT_TRUE(renderer.set_scene(terrain(info.width, info.height, 4096), 3).ok());

    sc::CpuFeedbackParams p;
    p.main_width = cfg.width;
    p.main_height = cfg.height;
    p.fb_width = cfg.width / 8;
    p.fb_height = cfg.height / 8;
    p.bias = bias;
    p.rule = sc::LodRule{scene_filter(filter), cfg.max_anisotropy};
    p.texture = 3;
    const sc::VtGeometry geo{info.width, info.height, info.tile_payload, info.level_count()};

    struct View {
        sc::Camera camera;
        bool exact;  // straight down: every pixel must agree
    };
    const View views[] = {
        {straight_down(30000.3, 20000.7, height_for(std::exp2(2.3), straight_down(0, 0, 1), cfg.height)), true},
        {straight_down(1000.6, 64000.2, height_for(std::exp2(0.7), straight_down(0, 0, 1), cfg.height)), true},
        {looking(30000, 20000, 300, 0.7, -0.5), false},
        {looking(12345.6, 54321.2, 1500, 4.0, -0.9), false},
    };
    for (const auto& v : views) {
        const auto frame = renderer.render(v.camera, bias);
        gl::FeedbackFrame fb;
        renderer.finish(nullptr, &fb);
        ASSERT_EQ(fb.frame, frame);
        ASSERT_EQ(fb.width, p.fb_width);
        ASSERT_EQ(fb.height, p.fb_height);
        EXPECT_EQ(fb.bias, bias);
        std::vector<FeedbackId> cpu;
        sc::cpu_feedback(v.camera, geo, p, cpu);
        ASSERT_EQ(cpu.size(), fb.ids.size());
        std::set<FeedbackId> gpu_set, cpu_set;
        std::size_t differ = 0, vt_pixels = 0;
        for (std::size_t i = 0; i < cpu.size(); ++i) {
            if (fb.ids[i] != kNoPage) gpu_set.insert(fb.ids[i]);
            if (cpu[i] != kNoPage) cpu_set.insert(cpu[i]), ++vt_pixels;
            if (fb.ids[i] == cpu[i]) continue;
            ++differ;
            // Only neighbours may differ: a level or a page boundary passes through the pixel.
            ASSERT_NE(fb.ids[i], kNoPage) << "pixel " << i;
            ASSERT_NE(cpu[i], kNoPage) << "pixel " << i;
            const auto a = tessera::client::unpack_feedback(fb.ids[i]), b = tessera::client::unpack_feedback(cpu[i]);
            EXPECT_EQ(a.texture, 3);
            EXPECT_LE(std::abs(int(a.level) - int(b.level)), 1) << "pixel " << i << ": GPU level " << int(a.level) << " page (" << a.x << ", " << a.y << "), CPU level " << int(b.level) << " page (" << b.x << ", " << b.y << ")";
            if (a.level == b.level) {
                EXPECT_LE(std::abs(int(a.x) - int(b.x)), 1);
                EXPECT_LE(std::abs(int(a.y) - int(b.y)), 1);
            }
        }
        EXPECT_GT(vt_pixels, cpu.size() / 3);
        if (v.exact) {
            EXPECT_EQ(differ, 0u);
        }
        EXPECT_EQ(gpu_set, cpu_set) << differ << " of " << cpu.size() << " pixels differ";
        std::printf("  %s bias %.1f camera z=%.0f pitch %.2f: %zu pages, %zu of %zu pixels differ\n", filter_name(filter), bias,
                    v.camera.position[2], v.camera.pitch, cpu_set.size(), differ, cpu.size());
    }
}

INSTANTIATE_TEST_SUITE_P(Cases, RenderFeedback,
                         ::testing::Values(FeedbackCase{gl::Filter::bilinear, 0.0f}, FeedbackCase{gl::Filter::trilinear, 0.0f},
                                           FeedbackCase{gl::Filter::trilinear, 1.5f}, FeedbackCase{gl::Filter::anisotropic, 0.0f}),
                         [](const auto& p) {
                             return std::string(filter_name(p.param.filter)) + (p.param.bias != 0 ? "_biased" : "");
                         });

// ---------------------------------------------------------------------------------------------

TEST(RenderAddressing, TexelsNearTwoToTheTwentyComeBackExactly) {
    REQUIRE_GL(ctx);
    constexpr std::uint32_t kSize = 1u << 20;
    const auto info = store_geometry(kSize, kSize, 512);  // P = 504
    const std::uint32_t P = info.tile_payload, B = info.border, ts = info.tile_size();
    auto cfg = config(gl::Filter::bilinear, ts, 4, /*srgb=*/false, 128, 96);
    auto r = gl::VtRenderer::create(cfg);
    ASSERT_TRUE(r.ok()) << r.error().message;
    auto& renderer = **r;
    ASSERT_TRUE(renderer.add_texture(0, info).ok());

    // One chunk: the texture's last 576 x 576 texels, a world unit per texel.
    const std::uint32_t o = kSize - 576;
    sc::Scene s;
    s.vt_width = s.vt_height = kSize;
    sc::Chunk c;
    c.origin = {double(o), double(o), 0};
    c.texel_origin[0] = c.texel_origin[1] = o;
    for (const auto& [x, y] : {std::pair{0.f, 0.f}, {576.f, 0.f}, {576.f, 576.f}, {0.f, 576.f}}) c.vertices.push_back({{x, y, 0}, {x, y}});
    c.indices = {0, 1, 2, 0, 2, 3};
    s.chunks.push_back(c);
    ASSERT_TRUE(renderer.set_scene(s, 0).ok());

    // Pages (2079..2080, 2079..2080) of level 0, the texture's last: page 2080 holds texels
    // [1048320, 1048576).
    const std::uint32_t p0 = (kSize - 300) / P;
    std::vector<std::uint32_t> entries;
    std::vector<std::uint8_t> page(std::size_t(ts) * ts * 4);
    for (std::uint32_t py = 0; py < 2; ++py)
        for (std::uint32_t px = 0; px < 2; ++px) {
            const std::uint32_t slot = py * 2 + px;
            for (std::uint32_t j = 0; j < ts; ++j)
                for (std::uint32_t i = 0; i < ts; ++i) {
                    const auto gx = std::clamp<std::int64_t>(std::int64_t(p0 + px) * P - B + i, 0, kSize - 1);
                    const auto gy = std::clamp<std::int64_t>(std::int64_t(p0 + py) * P - B + j, 0, kSize - 1);
                    encode_texel(std::uint32_t(gx), std::uint32_t(gy), page.data() + (std::size_t(j) * ts + i) * 4);
                }
            renderer.upload_page(slot, {0, 0, p0 + px, p0 + py}, page, ts);
            entries.push_back(PageTable::make_entry(slot, 0));
        }
    renderer.upload_page_table(0, 0, p0, p0, 2, 2, entries);
    EXPECT_EQ(renderer.stats().malformed_uploads, 0u);

    // One texel per pixel, pixel centres on texel centres (the image centre on a texel corner),
    // and 4x magnified (every fourth pixel centre on a texel centre). Both views straddle the
    // page corner (1048320, 1048320).
    for (const double tpp : {1.0, 0.25}) {
        const double cx = 1048330 + (tpp < 1 ? 0.125 : 0.0), cy = 1048313 + (tpp < 1 ? 0.125 : 0.0);
        const auto cam = straight_down(cx, cy, height_for(tpp, straight_down(0, 0, 1), cfg.height));
        const Frame f = render_vt(renderer, cam);
        EXPECT_EQ(f.counters.textured_pixels, std::uint64_t(cfg.width) * cfg.height);
        std::size_t checked = 0, wrong = 0;
        std::set<std::uint32_t> pages_seen;
        for (std::uint32_t j = 0; j < cfg.height; ++j)
            for (std::uint32_t i = 0; i < cfg.width; ++i) {
                double x, y;
                ASSERT_TRUE(pixel_to_ground(cam, cfg.width, cfg.height, i, j, x, y));
                if (std::abs(x - std::floor(x) - 0.5) > 1e-3 || std::abs(y - std::floor(y) - 0.5) > 1e-3) continue;
                const auto gx = std::uint32_t(std::floor(x)), gy = std::uint32_t(std::floor(y));
                std::uint8_t want[4];
                encode_texel(gx, gy, want);
                const std::uint8_t* got = f.rgba.data() + (std::size_t(j) * cfg.width + i) * 4;
                ++checked;
                pages_seen.insert((gx / P) * 4096 + gy / P);
                if (std::equal(want, want + 4, got)) continue;
                if (++wrong <= 5)
                    ADD_FAILURE() << "pixel (" << i << ", " << j << ") texel (" << gx << ", " << gy << "): got " << int(got[0]) << " "
                                  << int(got[1]) << " " << int(got[2]) << ", want " << int(want[0]) << " " << int(want[1]) << " "
                                  << int(want[2]);
            }
        EXPECT_EQ(wrong, 0u) << "of " << checked;
        EXPECT_GE(checked, tpp < 1 ? std::size_t(cfg.width * cfg.height / 16) : std::size_t(cfg.width * cfg.height));
        EXPECT_EQ(pages_seen.size(), 4u);
        std::printf("  %.2f texels per pixel: %zu pixels checked on texel centres near 2^20, %zu wrong\n", tpp, checked, wrong);
    }
}

// ---------------------------------------------------------------------------------------------

// Maps pages through a client::PageTable (as the runtime does) and uploads its dirty rectangles.
void upload_dirty(PageTable& table, gl::VtRenderer& r) {
    std::vector<tessera::client::DirtyRect> dirty;
    table.take_dirty(dirty);
    for (const auto& d : dirty) {
        const auto entries = table.level_entries(d.level);
        std::vector<std::uint32_t> rect;
        for (std::uint32_t y = d.y0; y < d.y1; ++y)
            for (std::uint32_t x = d.x0; x < d.x1; ++x) rect.push_back(entries[std::size_t(y) * table.level_width(d.level) + x]);
        r.upload_page_table(table.texture(), std::uint8_t(d.level), d.x0, d.y0, d.x1 - d.x0, d.y1 - d.y0, rect);
    }
}

// Page (px, py) of a decoded level as the builder cuts it: ts x ts RGBA8 texels, a payload of P and
// a border of B, clamped at the level's edges.
void cut_page(const gl::ReferenceRenderer::Level& L, std::uint32_t px, std::uint32_t py, std::uint32_t ts, std::uint32_t P,
              std::uint32_t B, std::vector<std::uint8_t>& page) {
    page.resize(std::size_t(ts) * ts * 4);
    for (std::uint32_t j = 0; j < ts; ++j)
        for (std::uint32_t i = 0; i < ts; ++i) {
            const auto x = std::clamp<std::int64_t>(std::int64_t(px) * P - B + i, 0, L.width - 1);
            const auto y = std::clamp<std::int64_t>(std::int64_t(py) * P - B + j, 0, L.height - 1);
            std::copy_n(&L.rgba8[(std::size_t(y) * L.width + std::size_t(x)) * 4], 4, &page[(std::size_t(j) * ts + i) * 4]);
        }
}

// Trilinear takes the coarser of its two levels from the atlas's second level, not from a second
// page-table lookup: the parent page's texels when the parent is in the atlas, else the page's 2x2
// means. A view at lod 2.5 over the whole texture (its edges included), level 2 and the root
// resident, and level 3 too when `parents`, uploaded after level 2 (so the children's second
// levels are redone). `inverted_parents`: level 3 holds other texels than level 2's means (as a
// lossy codec's separately encoded level does), in the store the reference draws and in the
// uploaded pages alike. The VT must match the reference: PSNR >= 50 dB, max error <= 3.
void expect_trilinear_matches(bool parents, bool inverted_parents) {
    ScratchDir dir;
    auto pattern = pattern_source(1024, 1024);
    const std::string store = build_store(dir.file("pattern.tsr"), "", 64, &pattern);  // P = 56
    auto levels = tessera::client::decode_store_levels(store);
    ASSERT_TRUE(levels.ok()) << levels.error().message;
    const auto info = store_geometry(1024, 1024, 64);
    const std::uint32_t ts = info.tile_size(), P = info.tile_payload, B = info.border, fine = 2;
    if (inverted_parents)
        for (std::size_t i = 0; i < (*levels)[fine + 1].rgba8.size(); ++i)
            if (i % 4 != 3) (*levels)[fine + 1].rgba8[i] = std::uint8_t(255 - (*levels)[fine + 1].rgba8[i]);
    const auto cfg = config(gl::Filter::trilinear, ts, 64, /*srgb=*/false, 192, 144);
    auto made = gl::VtRenderer::create(cfg);
    ASSERT_TRUE(made.ok()) << made.error().message;
    auto& renderer = **made;
    ASSERT_TRUE(renderer.add_texture(0, info).ok());
    const auto scene = terrain(1024, 1024, 256);
    ASSERT_TRUE(renderer.set_scene(scene, 0).ok());
    auto table = PageTable::create(0, info.levels[0].tiles_x, info.levels[0].tiles_y, info.level_count());
    ASSERT_TRUE(table.ok()) << table.error().message;
    // A page cut from the decoded level, its border clamped at the edges (as the builder cuts it).
    std::vector<std::uint8_t> page(std::size_t(ts) * ts * 4);
    tessera::client::SlotId next = 0;
    const auto upload_level = [&](std::uint32_t l) {
        for (std::uint32_t py = 0; py < info.levels[l].tiles_y; ++py)
            for (std::uint32_t px = 0; px < info.levels[l].tiles_x; ++px) {
                cut_page((*levels)[l], px, py, ts, P, B, page);
                renderer.upload_page(next, {0, std::uint8_t(l), px, py}, page, ts);
                ASSERT_TRUE(table->map(l, px, py, next++).ok());
            }
    };
    upload_level(fine);
    if (parents) upload_level(fine + 1);
    upload_level(info.level_count() - 1);
    upload_dirty(*table, renderer);

    auto ref = gl::ReferenceRenderer::create(cfg, *levels);
    ASSERT_TRUE(ref.ok()) << ref.error().message;
    ASSERT_TRUE((*ref)->set_scene(scene).ok());
    const auto cam = straight_down(512, 512, height_for(std::exp2(fine + 0.5), straight_down(0, 0, 1), cfg.height));
    const Frame f = render_vt(renderer, cam);
    (*ref)->render(cam);
    const auto want = (*ref)->read_color();
    const auto e = tessera::client::compare_images(f.rgba, want, cfg.width, cfg.height, coverage(want));
    EXPECT_GT(e.pixels, 1000u);
    EXPECT_GE(e.psnr, 50.0) << "max error " << e.max_error;
    EXPECT_LE(e.max_error, 3);
    EXPECT_EQ(f.counters.fallback_unbiased, 0u);
    std::printf("  level %u resident, level %u %s%s: PSNR %.1f dB, max error %d over %llu px\n", fine, fine + 1,
                parents ? "resident" : "not", inverted_parents ? " (inverted)" : "", e.psnr, e.max_error,
                static_cast<unsigned long long>(e.pixels));
}

TEST(RenderTrilinear, CoarserLevelIsExactWithoutTheParentPage) {
    REQUIRE_GL(ctx);
    expect_trilinear_matches(/*parents=*/false, /*inverted_parents=*/false);
}

TEST(RenderTrilinear, CoarserLevelIsTheStoredParentWhenItIsResident) {
    REQUIRE_GL(ctx);
    expect_trilinear_matches(/*parents=*/true, /*inverted_parents=*/true);
}

// What is drawn when level `fine` arrives in expect_fades_in: its parent level, faded in or half-way
// through its own fade, or only the root.
enum class FadeFrom { parent, fading_parent, root };

// What the blending tests draw: the 1024² pattern at 64-texel tiles with level fine + 1 inverted (a
// change no fade could hide; in the pages and the reference alike), two renderers on it, one
// given blend weights that move over fade_s and one not, and a page table both follow (upload()
// maps a level in both). The weights come from the runtime's SlotFades, driven as the page cache
// drives them (docs/client.md, "A slot's life"): arrive, leave, keep; a slot that has faded out
// is given back by take_faded_out.
struct FadeRig {
    static constexpr std::uint32_t fine = 2;
    static constexpr double fade_s = 0.2;
    ScratchDir dir;
    st::StoreInfo info = store_geometry(1024, 1024, 64);
    std::vector<gl::ReferenceRenderer::Level> levels;
    gl::RendererConfig cfg;
    std::unique_ptr<gl::VtRenderer> fading, plain;
    std::optional<tessera::client::SlotFades> fades;
    std::vector<tessera::client::SlotId> gone;  // faded out, not yet taken
    std::optional<PageTable> table;
    tessera::client::SlotId next = 0;
    sc::Camera cam;

    // Empty when made; else what failed.
    std::string make(gl::Filter filter, bool srgb) {
        auto pattern = pattern_source(1024, 1024);
        const std::string store = build_store(dir.file("pattern.tsr"), "", 64, &pattern);
        auto decoded = tessera::client::decode_store_levels(store);
        if (!decoded.ok()) return decoded.error().message;
        levels = std::move(*decoded);
        for (std::size_t i = 0; i < levels[fine + 1].rgba8.size(); ++i)
            if (i % 4 != 3) levels[fine + 1].rgba8[i] = std::uint8_t(255 - levels[fine + 1].rgba8[i]);
        cfg = config(filter, info.tile_size(), 64, srgb, 192, 144);
        fades.emplace(cfg.pool_slots, fade_s);
        auto f = gl::VtRenderer::create(cfg);
        if (!f.ok()) return f.error().message;
        auto p = gl::VtRenderer::create(cfg);
        if (!p.ok()) return p.error().message;
        fading = std::move(*f);
        plain = std::move(*p);
        const auto scene = terrain(1024, 1024, 256);
        for (gl::VtRenderer* r : {fading.get(), plain.get()}) {
            if (!r->add_texture(0, info).ok() || !r->set_scene(scene, 0).ok()) return "renderer setup";
        }
        auto t = PageTable::create(0, info.levels[0].tiles_x, info.levels[0].tiles_y, info.level_count());
        if (!t.ok()) return t.error().message;
        table = std::move(*t);
        const double lod = fine + (filter == gl::Filter::bilinear ? 0.0 : 0.5);
        cam = straight_down(512, 512, height_for(std::exp2(lod), straight_down(0, 0, 1), cfg.height));
        return {};
    }
    // Uploads every page of level l into both renderers and maps it; `slots` gets (page, slot).
    void upload(std::uint32_t l, std::vector<std::pair<PageKey, tessera::client::SlotId>>* slots = nullptr) {
        const std::uint32_t ts = info.tile_size();
        std::vector<std::uint8_t> page(std::size_t(ts) * ts * 4);
        for (std::uint32_t py = 0; py < info.levels[l].tiles_y; ++py)
            for (std::uint32_t px = 0; px < info.levels[l].tiles_x; ++px) {
                cut_page(levels[l], px, py, ts, info.tile_payload, info.border, page);
                const PageKey key{0, std::uint8_t(l), px, py};
                fading->upload_page(next, key, page, ts);
                fades->arrive(next);
                plain->upload_page(next, key, page, ts);
                ASSERT_TRUE(table->map(l, px, py, next).ok());
                if (slots) slots->emplace_back(key, next);
                ++next;
            }
        upload_tables();
    }
    void upload_tables() {
        table->mark_all_dirty();
        upload_dirty(*table, *fading);
        table->mark_all_dirty();
        upload_dirty(*table, *plain);
    }
    Frame frame_at(double t) {
        fades->advance(t, gone);
        std::vector<tessera::client::SlotWeight> changes;
        fades->take_changes(changes);
        fading->set_slot_weights(changes);
        return render_vt(*fading, cam);
    }
    void fade_out(tessera::client::SlotId slot) { fades->leave(slot); }
    // A leaving page kept: from where it is, or from 0 when it has faded out and was not taken.
    void cancel_fade_out(tessera::client::SlotId slot) {
        std::erase(gone, slot);
        fades->keep(slot);
    }
    void take_faded_out(std::vector<tessera::client::SlotId>& out) {
        out.insert(out.end(), gone.begin(), gone.end());
        gone.clear();
    }
    // Slots given back (unmapped): full weight again, as the page cache does.
    void release(const std::vector<tessera::client::SlotId>& slots) {
        for (const auto s : slots) fades->release(s);
    }
    // The largest difference in R, G or B over the pixels of `mask`.
    static int max_diff(const std::vector<std::uint8_t>& a, const std::vector<std::uint8_t>& b, const std::vector<std::uint8_t>& mask) {
        int m = 0;
        for (std::size_t i = 0; i < mask.size(); ++i)
            for (std::size_t ch = 0; mask[i] && ch < 3; ++ch) m = std::max(m, std::abs(int(a[i * 4 + ch]) - int(b[i * 4 + ch])));
        return m;
    }
};

// Blending in (docs/renderer.md, "Blending in"). A static camera at lod `fine` (trilinear and
// anisotropic: fine + 0.5) over the whole pattern, level fine + 1 (FadeFrom::parent; else only the
// root: the pixels draw the root until level `fine` arrives) and the root resident and faded in;
// with FadeFrom::fading_parent level fine + 1 arrives after the root and level `fine` half-way
// through its fade. Then level `fine` arrives. With fade_ms F, in frames F/8 apart the image moves
// from what was drawn to the view of level fine gradually: the first frame after the arrival is
// the frame before it (however the pixels were drawn: a fading ancestor is blended as it was),
// each frame changes by at most an eighth of the whole change (plus rounding; with a fading
// parent, plus an eighth of the parent's own change), and after F the frame is the one a renderer
// without blending draws from the same pages (max error <= 1), which matches the reference.
// `srgb`: an sRGB atlas and target, and the step bound holds pixel by pixel (each pixel moves by at
// most an eighth of its own change per frame: what is seen fades evenly, dark texels included).
void expect_fades_in(gl::Filter filter, FadeFrom from, bool srgb = false) {
    const bool parent_resident = from != FadeFrom::root;
    FadeRig rig;
    const std::string failed = rig.make(filter, srgb);
    ASSERT_TRUE(failed.empty()) << failed;
    if (!parent_resident)  // only the root before level `fine`: its parent level as stored
        for (std::size_t i = 0; i < rig.levels[FadeRig::fine + 1].rgba8.size(); ++i)
            if (i % 4 != 3) rig.levels[FadeRig::fine + 1].rgba8[i] = std::uint8_t(255 - rig.levels[FadeRig::fine + 1].rgba8[i]);
    const std::uint32_t fine = FadeRig::fine;
    const double fade_s = FadeRig::fade_s;
    const auto& cfg = rig.cfg;
    gl::VtRenderer& fading = *rig.fading;
    gl::VtRenderer& plain = *rig.plain;
    const auto frame_at = [&](double t) { return rig.frame_at(t); };
    if (from == FadeFrom::parent) rig.upload(fine + 1);
    rig.upload(rig.info.level_count() - 1);
    double t = 0;
    for (; t <= fade_s + 1e-9; t += fade_s / 4) frame_at(t);
    EXPECT_EQ(fading.stats().fading_pages, 0u) << "the coarse levels have faded in";
    int parent_change = 0;  // FadeFrom::fading_parent: how far the parent's own fade moves the image
    if (from == FadeFrom::fading_parent) {
        const Frame root_only = frame_at(t);
        rig.upload(fine + 1);
        const Frame parent_full = render_vt(plain, rig.cam);
        for (std::size_t i = 0; i < root_only.rgba.size(); ++i)
            if (i % 4 != 3 && parent_full.rgba[i / 4 * 4 + 3])
                parent_change = std::max(parent_change, std::abs(int(root_only.rgba[i]) - int(parent_full.rgba[i])));
        for (int k = 1; k <= 4; ++k) frame_at(t + k * fade_s / 8);
        t += 4 * fade_s / 8;
        EXPECT_GT(fading.stats().fading_pages, 0u) << "level " << fine + 1 << " is half-way through its fade";
    }
    const Frame before = frame_at(t);
    EXPECT_GT(before.counters.fallback_unbiased, 0u) << "level " << fine << " is not resident yet";

    rig.upload(fine);
    const Frame after = render_vt(plain, rig.cam);  // the pages at full weight, at once
    EXPECT_EQ(after.counters.fallback_unbiased, 0u);
    const auto mask = coverage(after.rgba);
    ASSERT_GT(count(mask), std::size_t(cfg.width * cfg.height / 2));
    const auto max_diff = [&](const std::vector<std::uint8_t>& x, const std::vector<std::uint8_t>& y) {
        return FadeRig::max_diff(x, y, mask);
    };
    const int whole = max_diff(before.rgba, after.rgba);
    EXPECT_GE(whole + parent_change, 64) << "the levels must differ for the test to see a fade";
    const int step_bound = (whole + parent_change + 7) / 8 + 2;
    // Pixel by pixel (srgb): the largest step over a pixel's own bound, and where.
    const auto uneven_step = [&](const std::vector<std::uint8_t>& a, const std::vector<std::uint8_t>& b) {
        int worst = 0;
        for (std::size_t i = 0; i < mask.size(); ++i)
            for (std::size_t ch = 0; mask[i] && ch < 3; ++ch) {
                const std::size_t j = i * 4 + ch;
                const int own = (std::abs(int(before.rgba[j]) - int(after.rgba[j])) + 7) / 8 + 2;
                worst = std::max(worst, std::abs(int(a[j]) - int(b[j])) - own);
            }
        return worst;
    };
    std::vector<std::uint8_t> last = before.rgba;
    int largest_step = 0, most_uneven = 0;
    for (int k = 0; k <= 8; ++k) {
        const Frame f = frame_at(t + k * fade_s / 8);
        const int step = max_diff(last, f.rgba);
        if (srgb && k > 0) {
            const int over = uneven_step(last, f.rgba);
            most_uneven = std::max(most_uneven, over);
            EXPECT_LE(over, 0) << "frame " << k << ": a pixel moves " << over << " more than an eighth of its own change";
        }
        if (k == 0) {
            EXPECT_LE(step, 2) << "the arriving pages first show their parent level";
            EXPECT_GT(fading.stats().fading_pages, 0u);
        } else {
            EXPECT_LE(step, step_bound) << "frame " << k << " of the fade changes by more than an eighth of " << whole;
        }
        EXPECT_EQ(f.counters.fallback_unbiased, 0u) << "a fading page counts as resident";
        largest_step = std::max(largest_step, step);
        last = f.rgba;
    }
    EXPECT_GT(largest_step, 0);
    EXPECT_EQ(fading.stats().fading_pages, 0u);
    const auto e = tessera::client::compare_images(last, after.rgba, cfg.width, cfg.height, mask);
    EXPECT_LE(e.max_error, 1) << "after the fade, the frame is the one drawn without blending";

    auto ref = gl::ReferenceRenderer::create(cfg, rig.levels);
    ASSERT_TRUE(ref.ok()) << ref.error().message;
    ASSERT_TRUE((*ref)->set_scene(terrain(1024, 1024, 256)).ok());
    (*ref)->render(rig.cam);
    const auto want = (*ref)->read_color();
    const auto r = tessera::client::compare_images(last, want, cfg.width, cfg.height, coverage(want));
    EXPECT_GE(r.psnr, 50.0) << "max error " << r.max_error;
    EXPECT_LE(r.max_error, 3);
    if (srgb) std::printf("  sRGB, pixel by pixel: the largest step %d over the pixel's own eighth\n", most_uneven);
    std::printf("  %s, %s: the whole change %d, largest step %d (bound %d), after the fade max error %d against no "
                "blending, %.1f dB against the reference\n",
                filter_name(filter),
                from == FadeFrom::parent ? "from the parent" : from == FadeFrom::root ? "from the root" : "from a fading parent", whole,
                largest_step, step_bound,
                e.max_error, r.psnr);
}

class RenderFade : public ::testing::TestWithParam<gl::Filter> {};

TEST_P(RenderFade, AnArrivingPageFadesInAndEndsExact) {
    REQUIRE_GL(ctx);
    expect_fades_in(GetParam(), FadeFrom::parent);
}

INSTANTIATE_TEST_SUITE_P(Filters, RenderFade,
                         ::testing::Values(gl::Filter::bilinear, gl::Filter::trilinear, gl::Filter::anisotropic),
                         [](const auto& p) { return std::string(filter_name(p.param)); });

// Bilinear and trilinear fade from the ancestor the pixels drew, however far up (the anisotropic
// taps fade from the page's parent level: docs/renderer.md, "Blending in").
class RenderFadeFromAncestor : public ::testing::TestWithParam<gl::Filter> {};

TEST_P(RenderFadeFromAncestor, APageWhoseParentIsAbsentFadesFromTheAncestorDrawn) {
    REQUIRE_GL(ctx);
    expect_fades_in(GetParam(), FadeFrom::root);
}

// A page arriving while its parent still fades in starts from what the pixels drew: the parent
// blended with its own ancestor (fast camera turns bring parent and child a frame or two apart).
TEST_P(RenderFadeFromAncestor, APageArrivingWhileItsParentFadesStartsFromTheBlend) {
    REQUIRE_GL(ctx);
    expect_fades_in(GetParam(), FadeFrom::fading_parent);
}

INSTANTIATE_TEST_SUITE_P(Filters, RenderFadeFromAncestor, ::testing::Values(gl::Filter::bilinear, gl::Filter::trilinear),
                         [](const auto& p) { return std::string(filter_name(p.param)); });

// On an sRGB target what is seen is the encoded colour: bilinear and trilinear blends mix encoded
// colours, so every pixel moves evenly (a blend in linear light keeps most of a fade towards a dark
// texel for its last frames: a visible pop at the end of the fade). The anisotropic taps blend in
// the filter, in linear light (docs/renderer.md, "Blending in").
class RenderFadeEncoded : public ::testing::TestWithParam<gl::Filter> {};

TEST_P(RenderFadeEncoded, EveryPixelMovesByAnEighthOfItsOwnChangePerStep) {
    REQUIRE_GL(ctx);
    expect_fades_in(GetParam(), FadeFrom::parent, /*srgb=*/true);
}

INSTANTIATE_TEST_SUITE_P(Filters, RenderFadeEncoded, ::testing::Values(gl::Filter::bilinear, gl::Filter::trilinear),
                         [](const auto& p) { return std::string(filter_name(p.param)); });

// Fading out (docs/client.md, "Replacement"; docs/renderer.md, "Blending in"): level `fine` and
// its parent level resident and faded in, at a static camera; then every page of level `fine`
// leaves (fade_out). Each frame moves by at most an eighth of the whole change (+2), the slots come
// back from take_faded_out only once the pages have faded out, and unmapping them then changes
// nothing (max difference <= 1): the frame is the parent level's, as a renderer without blending
// draws it with level `fine` absent.
void expect_fades_out(gl::Filter filter) {
    FadeRig rig;
    const std::string failed = rig.make(filter, /*srgb=*/true);
    ASSERT_TRUE(failed.empty()) << failed;
    const std::uint32_t fine = FadeRig::fine;
    const double fade_s = FadeRig::fade_s;
    const auto& cfg = rig.cfg;
    gl::VtRenderer& fading = *rig.fading;
    gl::VtRenderer& plain = *rig.plain;
    const auto frame_at = [&](double t) { return rig.frame_at(t); };
    std::vector<std::pair<PageKey, tessera::client::SlotId>> fine_pages;
    rig.upload(rig.info.level_count() - 1);
    rig.upload(fine + 1);
    rig.upload(fine, &fine_pages);
    double t = 0;
    for (; t <= fade_s + 1e-9; t += fade_s / 4) frame_at(t);
    ASSERT_EQ(fading.stats().fading_pages, 0u) << "everything has faded in";
    const Frame before = frame_at(t);
    EXPECT_EQ(before.counters.fallback_unbiased, 0u);

    std::vector<tessera::client::SlotId> gone;
    for (const auto& [key, slot] : fine_pages) rig.fade_out(slot);
    rig.take_faded_out(gone);
    EXPECT_TRUE(gone.empty()) << "nothing has faded out before a frame is drawn";
    // Where it ends: level `fine` absent, drawn without blending (the plain renderer only, for now).
    for (const auto& [key, slot] : fine_pages) ASSERT_TRUE(rig.table->unmap(key.level, key.x, key.y).ok());
    rig.table->mark_all_dirty();
    upload_dirty(*rig.table, plain);
    const Frame after = render_vt(plain, rig.cam);
    EXPECT_GT(after.counters.fallback_unbiased, 0u);
    const auto mask = coverage(after.rgba);
    ASSERT_GT(count(mask), std::size_t(cfg.width * cfg.height / 2));
    const auto max_diff = [&](const std::vector<std::uint8_t>& x, const std::vector<std::uint8_t>& y) {
        return FadeRig::max_diff(x, y, mask);
    };
    const int whole = max_diff(before.rgba, after.rgba);
    EXPECT_GE(whole, 64) << "the levels must differ for the test to see a fade";
    const int step_bound = (whole + 7) / 8 + 2;
    std::vector<std::uint8_t> last = before.rgba;
    int largest_step = 0;
    for (int k = 0; k <= 8; ++k) {
        const Frame f = frame_at(t + k * fade_s / 8);
        const int step = max_diff(last, f.rgba);
        if (k == 0) {
            EXPECT_LE(step, 2) << "the leaving pages first show as they were";
        } else {
            EXPECT_LE(step, step_bound) << "frame " << k << " of the fade out changes by more than an eighth of " << whole;
        }
        rig.take_faded_out(gone);
        if (k < 8) {
            EXPECT_TRUE(gone.empty()) << "frame " << k << ": a slot came back before its page faded out";
        }
        largest_step = std::max(largest_step, step);
        last = f.rgba;
    }
    EXPECT_GT(largest_step, 0);
    EXPECT_EQ(gone.size(), fine_pages.size()) << "every leaving page has faded out";
    EXPECT_EQ(fading.stats().fading_pages, fine_pages.size()) << "drawn at weight 0 until their slots are taken";
    const int at_weight_zero = max_diff(last, after.rgba);
    EXPECT_LE(at_weight_zero, 1) << "faded out, the pages draw what is above them";
    // Unmapped now, at full weight (what the page cache does with the slots that have faded
    // out): nothing changes.
    rig.upload_tables();
    rig.release(gone);
    const Frame unmapped = frame_at(t + 2 * fade_s);
    const int at_unmap = max_diff(last, unmapped.rgba);
    EXPECT_LE(at_unmap, 1) << "unmapping a page that has faded out is not seen";
    EXPECT_EQ(fading.stats().fading_pages, 0u);
    std::printf("  %s: the whole change %d, largest step %d (bound %d), at weight 0 max error %d against level %u absent, "
                "then at the unmap %d\n",
                filter_name(filter), whole, largest_step, step_bound, at_weight_zero, fine, at_unmap);
}

// A leaving page the view wants again (cancel_fade_out: SlotFades::keep, what the page cache does
// for a leaving page the feedback sees): one that had faded out completely but was not yet taken fades in from
// weight 0, one stopped half-way from where it is; each frame moves by at most an eighth of the
// whole change (+2) per eighth of the fade, and ends as it was before it left. Neither slot is
// ever given back by take_faded_out.
void expect_fade_out_cancelled(gl::Filter filter) {
    FadeRig rig;
    const std::string failed = rig.make(filter, /*srgb=*/true);
    ASSERT_TRUE(failed.empty()) << failed;
    const double fade_s = FadeRig::fade_s;
    gl::VtRenderer& fading = *rig.fading;
    std::vector<std::pair<PageKey, tessera::client::SlotId>> fine_pages;
    rig.upload(rig.info.level_count() - 1);
    rig.upload(FadeRig::fine + 1);
    rig.upload(FadeRig::fine, &fine_pages);
    double t = 0;
    for (; t <= fade_s + 1e-9; t += fade_s / 4) rig.frame_at(t);
    ASSERT_EQ(fading.stats().fading_pages, 0u);
    const Frame before = rig.frame_at(t);
    const auto mask = coverage(before.rgba);
    ASSERT_GT(count(mask), std::size_t(rig.cfg.width * rig.cfg.height / 2));
    std::vector<tessera::client::SlotId> gone;
    int whole = 0;
    for (const int out_eighths : {8, 4}) {  // faded out completely (the whole change), then half-way
        for (const auto& [key, slot] : fine_pages) rig.fade_out(slot);
        std::vector<std::uint8_t> last = rig.frame_at(t).rgba;
        for (int k = 1; k <= out_eighths; ++k) last = rig.frame_at(t + k * fade_s / 8).rgba;
        t += out_eighths * fade_s / 8;
        const int away = FadeRig::max_diff(before.rgba, last, mask);
        if (out_eighths == 8) {
            whole = away;
        } else {
            EXPECT_NEAR(away, whole / 2, whole / 8 + 2) << "half-way out";
        }
        if (out_eighths == 8) {
            EXPECT_EQ(fading.stats().fading_pages, fine_pages.size()) << "faded out, not yet taken";
        }
        for (const auto& [key, slot] : fine_pages) rig.cancel_fade_out(slot);
        const int step_bound = (whole + 7) / 8 + 2;
        int largest_step = 0;
        for (int k = 0; k <= 8; ++k) {
            const Frame f = rig.frame_at(t + k * fade_s / 8);
            const int step = FadeRig::max_diff(last, f.rgba, mask);
            EXPECT_LE(step, k == 0 ? 2 : step_bound) << "frame " << k << " back from " << out_eighths << "/8 out";
            largest_step = std::max(largest_step, step);
            last = f.rgba;
        }
        t += fade_s;
        rig.take_faded_out(gone);
        EXPECT_TRUE(gone.empty()) << "a kept page's slot came back";
        EXPECT_EQ(fading.stats().fading_pages, 0u) << "faded back in";
        const int back = FadeRig::max_diff(before.rgba, last, mask);
        EXPECT_LE(back, 1) << "after the fade the frame is the one before the page left";
        EXPECT_GE(whole, 64) << "the levels must differ for the test to see a return";
        std::printf("  %s, kept %d/8 of the way out: %d away from the full frame, largest step back %d (bound %d), "
                    "then max error %d\n",
                    filter_name(filter), out_eighths, away, largest_step, step_bound, back);
    }
    // Made to leave, kept and made to leave again, each before a frame was drawn: every call
    // takes the weight where it is, so nothing jumps; then half-way out, kept and leaving again
    // at once: the fade goes on from half-way and ends in the half fade left.
    for (const auto& [key, slot] : fine_pages) rig.fade_out(slot);
    for (const auto& [key, slot] : fine_pages) rig.cancel_fade_out(slot);
    std::vector<std::uint8_t> last = rig.frame_at(t).rgba;
    EXPECT_LE(FadeRig::max_diff(before.rgba, last, mask), 1) << "fade_out, cancel_fade_out, then a frame";
    EXPECT_EQ(fading.stats().fading_pages, 0u);
    for (const auto& [key, slot] : fine_pages) rig.fade_out(slot);
    for (int k = 0; k <= 4; ++k) last = rig.frame_at(t + k * fade_s / 8).rgba;  // starts at t
    t += 4 * fade_s / 8;
    for (const auto& [key, slot] : fine_pages) rig.cancel_fade_out(slot);
    for (const auto& [key, slot] : fine_pages) rig.fade_out(slot);
    const int jump = FadeRig::max_diff(last, rig.frame_at(t).rgba, mask);
    EXPECT_LE(jump, 2) << "leaving again right after being kept: the fade goes on from where it was";
    for (int k = 1; k <= 3; ++k) rig.frame_at(t + k * fade_s / 8);
    rig.take_faded_out(gone);
    EXPECT_TRUE(gone.empty()) << "out before the half fade left has passed";
    rig.frame_at(t + 4 * fade_s / 8 + 1e-6);
    rig.take_faded_out(gone);
    EXPECT_EQ(gone.size(), fine_pages.size()) << "out once the half fade left has passed";
    std::printf("  %s, kept and leaving again before a frame: largest jump %d\n", filter_name(filter), jump);
}

class RenderFadeOut : public ::testing::TestWithParam<gl::Filter> {};

TEST_P(RenderFadeOut, ALeavingPageWantedAgainFadesBackIn) {
    REQUIRE_GL(ctx);
    expect_fade_out_cancelled(GetParam());
}

TEST_P(RenderFadeOut, ALeavingPageFadesToItsAncestorBeforeItsSlotComesBack) {
    REQUIRE_GL(ctx);
    expect_fades_out(GetParam());
}

INSTANTIATE_TEST_SUITE_P(Filters, RenderFadeOut, ::testing::Values(gl::Filter::bilinear, gl::Filter::trilinear),
                         [](const auto& p) { return std::string(filter_name(p.param)); });

TEST(RenderCounters, FallbackPixelsAgainstTheUnbiasedAndTheBiasedLevel) {
    REQUIRE_GL(ctx);
    const auto info = store_geometry(2048, 2048, 128);
    const std::uint32_t levels = info.level_count(), ts = info.tile_size();
    auto cfg = config(gl::Filter::trilinear, ts, 512, /*srgb=*/true, 192, 144);
    auto r = gl::VtRenderer::create(cfg);
    ASSERT_TRUE(r.ok()) << r.error().message;
    auto& renderer = **r;
    ASSERT_TRUE(renderer.add_texture(0, info).ok());
    ASSERT_TRUE(renderer.set_scene(terrain(2048, 2048, 512), 0).ok());
    auto table = PageTable::create(0, info.levels[0].tiles_x, info.levels[0].tiles_y, levels);
    ASSERT_TRUE(table.ok()) << table.error().message;
    // Looking down ahead: levels 0..3 in view, nothing wants the coarsest level.
    const auto cam = looking(1024, 600, 120, kPi / 2, -0.9);

    // The wanted level of every pixel (full-resolution CPU feedback), without and with a bias of 1.
    const auto wanted = [&](float bias) {
        sc::CpuFeedbackParams p;
        p.main_width = p.fb_width = cfg.width;
        p.main_height = p.fb_height = cfg.height;
        p.bias = bias;
        std::vector<FeedbackId> ids;
        sc::cpu_feedback(cam, sc::VtGeometry{info.width, info.height, info.tile_payload, levels}, p, ids);
        std::vector<int> out;
        for (const auto id : ids) out.push_back(id == kNoPage ? -1 : int(tessera::client::unpack_feedback(id).level));
        return out;
    };
    const auto unbiased = wanted(0.0f), biased = wanted(1.0f);
    const auto pixels_where = [&](const auto& pred) {
        double n = 0;
        for (std::size_t i = 0; i < unbiased.size(); ++i) n += unbiased[i] >= 0 && pred(unbiased[i], biased[i]);
        return n;
    };
    // The VT pass differentiates per 2x2 quad, the CPU per pixel: pixels on a level boundary may
    // disagree.
    const auto slack = [](double n) { return 0.01 * n + 60; };

    // Nothing resident: every textured pixel is drawn in the no-data colour and is a fallback.
    upload_dirty(*table, renderer);
    Frame f = render_vt(renderer, cam);
    const auto mask = coverage(f.rgba);
    const std::uint64_t textured = count(mask);
    ASSERT_GT(textured, std::uint64_t(cfg.width) * cfg.height / 2);
    EXPECT_NEAR(double(textured), pixels_where([](int, int) { return true; }), 0.01 * double(textured));
    EXPECT_EQ(f.counters.textured_pixels, textured);
    EXPECT_EQ(f.counters.fallback_unbiased, textured);
    EXPECT_EQ(f.counters.fallback_biased, textured);
    for (std::size_t i = 0; i < mask.size(); ++i)
        if (mask[i]) {
            ASSERT_EQ(f.rgba[i * 4 + 0], 255);
            ASSERT_EQ(f.rgba[i * 4 + 1], 0);
            ASSERT_EQ(f.rgba[i * 4 + 2], 255);
        }

    // Only the coarsest level: (almost) every pixel falls back.
    std::vector<std::uint8_t> page(std::size_t(ts) * ts * 4);
    tessera::client::SlotId next = 0;
    const auto map = [&](std::uint32_t l, std::uint32_t x, std::uint32_t y) {
        for (std::size_t i = 0; i < page.size(); i += 4) {
            page[i] = std::uint8_t(40 * l), page[i + 1] = std::uint8_t(x * 13), page[i + 2] = std::uint8_t(y * 29), page[i + 3] = 255;
        }
        renderer.upload_page(next, {0, std::uint8_t(l), x, y}, page, ts);
        ASSERT_TRUE(table->map(l, x, y, next++).ok());
    };
    map(levels - 1, 0, 0);
    upload_dirty(*table, renderer);
    f = render_vt(renderer, cam);
    EXPECT_EQ(f.counters.textured_pixels, textured);
    EXPECT_GE(f.counters.fallback_unbiased, textured * 99 / 100);
    EXPECT_NEAR(double(f.counters.fallback_unbiased), pixels_where([&](int u, int) { return u < int(levels) - 1; }),
                slack(double(textured)));
    EXPECT_EQ(f.counters.fallback_biased, f.counters.fallback_unbiased);
    // ... and every pixel shows the coarsest page (uniform (200, 0, 0): level 5's colour).
    for (std::size_t i = 0; i < mask.size(); ++i)
        if (mask[i]) {
            ASSERT_NEAR(f.rgba[i * 4 + 0], 200, 1) << "pixel " << i;
            ASSERT_EQ(f.rgba[i * 4 + 1], 0) << "pixel " << i;
            ASSERT_EQ(f.rgba[i * 4 + 2], 0) << "pixel " << i;
        }
    std::printf("  coarsest level only: %llu of %llu textured pixels fall back\n",
                static_cast<unsigned long long>(f.counters.fallback_unbiased), static_cast<unsigned long long>(textured));

    // Everything: no fallback.
    for (std::uint32_t l = 0; l + 1 < levels; ++l)
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) map(l, x, y);
    upload_dirty(*table, renderer);
    f = render_vt(renderer, cam);
    EXPECT_EQ(f.counters.textured_pixels, textured);
    EXPECT_EQ(f.counters.fallback_unbiased, 0u);
    EXPECT_EQ(f.counters.fallback_biased, 0u);

    // A bias of 1 with everything resident: the pipeline is healthy (no biased fallback) but the
    // pixels sample a coarser level than the view wants (unbiased fallback).
    f = render_vt(renderer, cam, 1.0f);
    EXPECT_EQ(f.counters.fallback_biased, 0u);
    const double coarser = pixels_where([](int u, int b) { return b > u; });
    EXPECT_NEAR(double(f.counters.fallback_unbiased), coarser, slack(coarser));
    std::printf("  bias 1: %llu unbiased fallback pixels, CPU says %.0f\n", static_cast<unsigned long long>(f.counters.fallback_unbiased),
                coarser);

    // Level 0 unmapped: the pixels that want level 0 fall back to level 1.
    for (std::uint32_t y = 0; y < info.levels[0].tiles_y; ++y)
        for (std::uint32_t x = 0; x < info.levels[0].tiles_x; ++x) ASSERT_TRUE(table->unmap(0, x, y).ok());
    upload_dirty(*table, renderer);
    f = render_vt(renderer, cam);
    const double want_level0 = pixels_where([](int u, int) { return u == 0; });
    ASSERT_GT(want_level0, 1000);
    EXPECT_NEAR(double(f.counters.fallback_unbiased), want_level0, slack(want_level0));
    EXPECT_EQ(f.counters.fallback_biased, f.counters.fallback_unbiased);
    std::printf("  level 0 unmapped: %llu fallback pixels, CPU says %.0f want level 0\n",
                static_cast<unsigned long long>(f.counters.fallback_unbiased), want_level0);

    // Counters arrive by polling too, in frame order.
    std::vector<gl::FrameCounters> polled;
    std::uint64_t last = 0;
    for (int i = 0; i < 6; ++i) last = renderer.render(cam, 0.0f);
    renderer.finish(nullptr, nullptr);  // everything finished: poll_counters must now see them all
    renderer.poll_counters(polled);
    ASSERT_FALSE(polled.empty());
    EXPECT_EQ(polled.back().frame, last);
    for (std::size_t i = 1; i < polled.size(); ++i) EXPECT_LT(polled[i - 1].frame, polled[i].frame);
}

// ---------------------------------------------------------------------------------------------

TEST(RenderFeedbackLoop, RenderFeedbackRuntimeUploadsConvergeToFullDetail) {
    REQUIRE_GL(ctx);
    ScratchDir dir;
    const std::string store = build_store(dir.file("terrain.tsr"), "procedural:terrain:2048", 128);
    const auto cfg = config(gl::Filter::trilinear, 128, 512, /*srgb=*/true, 192, 144);
    const auto scene = terrain(2048, 2048, 512);
    auto vt = make_vt(cfg, store, scene);
    ASSERT_TRUE(vt);
    const auto cam = looking(1024, -150, 180, kPi / 2, -0.45);
    const auto deadline = std::chrono::steady_clock::now() + 60s;
    gl::FeedbackFrame fb;
    std::vector<gl::FrameCounters> counters;
    gl::FrameCounters first{}, last{};
    int frames = 0;
    while (std::chrono::steady_clock::now() < deadline) {
        vt->renderer->render(cam, vt->runtime->lod_bias());
        ++frames;
        if (vt->renderer->poll_feedback(fb))
            vt->runtime->frame(fb.ids, fb.width, fb.height, fb.bias);
        else
            vt->runtime->frame_without_feedback();
        counters.clear();
        vt->renderer->poll_counters(counters);
        for (const auto& c : counters) {
            if (first.frame == 0) first = c;
            last = c;
        }
        if (last.frame > 0 && last.textured_pixels > 0 && last.fallback_biased == 0 && vt->runtime->in_flight() == 0) break;
        std::this_thread::sleep_for(1ms);
    }
    ASSERT_GT(last.textured_pixels, 0u);
    EXPECT_GT(first.fallback_unbiased, 0u) << "the first frames have nothing but the pinned levels";
    EXPECT_EQ(last.fallback_biased, 0u) << "after " << frames << " frames";
    EXPECT_EQ(vt->runtime->lod_bias(), 0.0f);
    std::printf("  %d frames; last counted frame %llu: %llu textured, %llu fallback (unbiased), %llu (biased)\n", frames,
                static_cast<unsigned long long>(last.frame), static_cast<unsigned long long>(last.textured_pixels),
                static_cast<unsigned long long>(last.fallback_unbiased), static_cast<unsigned long long>(last.fallback_biased));
}

}  // namespace

namespace {

// Without a display, a window is an error with a message (never a crash); with one, it is a GL
// 4.5 context (window_test, on Xvfb). A display of the machine running the tests is hidden here.
TEST(RenderContext, AWindowWithoutADisplayIsAnError) {
    const char* names[] = {"DISPLAY", "WAYLAND_DISPLAY"};
    std::vector<std::pair<std::string, std::string>> saved;
    for (const char* n : names)
        if (const char* v = std::getenv(n)) saved.emplace_back(n, v);
    for (const char* n : names) ::unsetenv(n);
    auto w = gl::GlContext::create_window(64, 64, "tessera test");
    for (const auto& [n, v] : saved) ::setenv(n.c_str(), v.c_str(), 1);
    ASSERT_FALSE(w.ok());
    EXPECT_FALSE(w.error().message.empty());
}

TEST(RenderContext, HeadlessContextIsGl45Core) {
    REQUIRE_GL(ctx);
    EXPECT_EQ(ctx->window(), nullptr);
    EXPECT_NE(ctx->renderer().find("4."), std::string::npos) << ctx->renderer();
    std::printf("  %s\n", ctx->renderer().c_str());
}

}  // namespace
