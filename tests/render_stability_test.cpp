// Numerical-stability stress, GL side (docs/stability.md), on Mesa llvmpipe or a GPU.
//
//   RenderStability.LargestAcceptedTexture...  the largest virtual texture whose packed dense page
//       table fits GL_MAX_TEXTURE_SIZE (1024-texel tiles); one more page per side takes the
//       two-level table (render_sparse_table_test.cpp) and 2^20 pages per side is a clear
//       resource_exhausted error; pages at its far corner mapped by hand at several levels
//       (0 .. the last) read back exactly at level-L texel centres.
//   RenderStability.StaticCameraDoesNotFlicker  the same camera rendered twice far from the origin:
//       identical images and identical feedback.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <string>

#include "tessera/client/gl/context.hpp"
#include "ground_ray.hpp"
#include "render_util.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "page_table.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/scene/scene.hpp"
#include "tessera/storage/types.hpp"

namespace {

namespace gl = tessera::client::gl;
namespace sc = tessera::scene;
namespace st = tessera::storage;
using tessera::Errc;
using tessera::client::FeedbackId;
using tessera::client::kNoPage;
using tessera::client::PageTable;
using tessera::test::corner_chunk;
using tessera::test::encode_texel;
using tessera::test::straight_down;

constexpr std::uint32_t kTile = 1024, kBorder = 4, kP = kTile - 2 * kBorder;  // the largest stored tile
constexpr std::uint32_t kW = 128, kH = 96;

st::StoreInfo geometry(std::uint32_t size) { return tessera::test::store_geometry(size, size, kTile, kBorder); }

// The packed page table's size (the renderer's layout: level 0, then levels 1.. in a column).
std::pair<std::uint64_t, std::uint64_t> packed_table(const st::StoreInfo& info) {
    std::uint64_t column_w = 0, column_h = 0;
    for (std::size_t l = 1; l < info.levels.size(); ++l) {
        column_w = std::max<std::uint64_t>(column_w, info.levels[l].tiles_x);
        column_h += info.levels[l].tiles_y;
    }
    return {info.levels[0].tiles_x + column_w, std::max<std::uint64_t>(info.levels[0].tiles_y, column_h)};
}

gl::RendererConfig config() { return tessera::test::exact_config(kW, kH, kTile, kBorder, 4); }

// A texture of 2^20 pages per axis (the feedback id's limit) is refused with a clear error: its
// two-level table's directory (32768^2 blocks at level 0) is over the largest shader storage block.
void expect_refused_at_feedback_limit(gl::VtRenderer& r) {
    const std::uint32_t huge = (1u << 20) * kP - 1;  // exactly 2^20 pages per axis
    const auto s = r.add_texture(9, geometry(huge));
    ASSERT_FALSE(s.ok());
    EXPECT_EQ(s.error().code, Errc::resource_exhausted);
    const std::string& m = s.error().message;
    EXPECT_NE(m.find("over the GPU's largest shader storage block"), std::string::npos) << m;
    std::printf("  2^20 pages per side: %s\n", m.c_str());
}

TEST(RenderStability, LargestAcceptedTextureIsExactAtTheFarCornerAtEveryLevel) {
    REQUIRE_GL(ctx);
    const auto cfg = config();
    auto made = gl::VtRenderer::create(cfg);
    ASSERT_TRUE(made.ok()) << made.error().message;
    gl::VtRenderer& r = **made;

    expect_refused_at_feedback_limit(r);
    // The dense path's bound: GL 4.5's smallest GL_MAX_TEXTURE_SIZE (llvmpipe's), whatever the GPU.
    const std::uint64_t max_texture = PageTable::kMaxDenseSide;
    // The largest page count per side whose packed table fits, and its texel size.
    std::uint32_t n = static_cast<std::uint32_t>(std::min<std::uint64_t>(max_texture, 1u << 20));
    auto fits = [&](std::uint32_t pages) {
        const auto [w, h] = packed_table(geometry(pages * kP));
        return w <= max_texture && h <= max_texture;
    };
    while (n > 1 && !fits(n)) --n;
    EXPECT_TRUE(PageTable::dense_packing_fits(n, n));
    const std::uint32_t size = n * kP;
    // One texel more (one more page per side): the two-level table, not a texture with wrong pixels.
    EXPECT_FALSE(PageTable::dense_packing_fits(n + 1, n + 1));
    const auto two_level = r.add_texture(1, geometry(size + 1));
    EXPECT_TRUE(two_level.ok()) << two_level.error().message;
    std::printf("  dense bound %llu: largest dense-table VT %u texels per side (2^%.2f, %u pages of %u); %u takes "
                "the two-level table\n",
                static_cast<unsigned long long>(max_texture), size, std::log2(double(size)), n, kP, size + 1);

    const st::StoreInfo info = geometry(size);
    ASSERT_TRUE(r.add_texture(0, info).ok());
    const std::uint32_t levels = info.level_count();
    std::vector<std::uint8_t> page(std::size_t(kTile) * kTile * 4);
    for (const std::uint32_t level : {0u, 1u, 4u, 9u, levels - 2, levels - 1}) {
        const auto [texels, pages, k, first_page, count] = tessera::test::corner_pages(info, level);
        std::vector<std::uint32_t> entries;
        for (std::uint32_t py = 0; py < count; ++py)
            for (std::uint32_t px = 0; px < count; ++px) {
                const std::uint32_t slot = py * 2 + px;
                tessera::test::encode_page(page, kTile, kBorder, first_page + px, first_page + py, texels);
                r.upload_page(slot, {0, std::uint8_t(level), first_page + px, first_page + py}, page, kTile);
                entries.push_back(PageTable::make_entry(slot, level));
            }
        r.upload_page_table(0, level, first_page, first_page, count, count, entries);

        const auto [checked, wrong] = tessera::test::render_corner_exactly(r, size, k, level, kW, kH);
        std::printf("  level %u (%u texels, %u pages per side): %zu pixels on texel centres at the far corner, %zu wrong\n", level,
                    texels, pages, checked, wrong);
    }
}

// A chunk far wider than 2^15 texels (a 2^24 terrain's chunks are 2^18), seen from close above
// a point deep inside it, is sampled where the pixels' rays meet the ground: a checkerboard of 0
// and 255, bilinear, compared with the bilinear value worked out in double at each pixel's ground
// point. A position error of 1/16 of a texel shows as 16 levels; addressed from the chunk's own
// origin, offsets of 2^20 kept about that much (docs/stability.md), and the frame that follows
// the camera (scene_draw.cpp) keeps a few 1/1000 of a texel.
TEST(RenderStability, PositionsDeepInsideAWideChunkAreExact) {
    REQUIRE_GL(ctx);
    auto made = gl::VtRenderer::create(config());
    ASSERT_TRUE(made.ok()) << made.error().message;
    gl::VtRenderer& r = **made;
    const std::uint32_t pages = 1100, size = pages * kP;  // about 2^20 texels per side, one chunk
    const st::StoreInfo info = geometry(size);
    ASSERT_TRUE(r.add_texture(0, info).ok());
    const auto checker = [](std::int64_t x, std::int64_t y) { return ((x + y) & 1) ? 255.0 : 0.0; };
    // The view: 8 pixels per texel around texel (cx, cy) of page `pc`, well inside that page.
    const std::uint32_t pc = pages - 3, cx = pc * kP + 411, cy = pc * kP + 517;
    std::vector<std::uint8_t> page(std::size_t(kTile) * kTile * 4);
    for (std::uint32_t j = 0; j < kTile; ++j)
        for (std::uint32_t i = 0; i < kTile; ++i) {
            const auto v = static_cast<std::uint8_t>(checker(std::int64_t(pc) * kP - kBorder + i, std::int64_t(pc) * kP - kBorder + j));
            std::uint8_t* p = page.data() + (std::size_t(j) * kTile + i) * 4;
            p[0] = p[1] = p[2] = v;
            p[3] = 255;
        }
    r.upload_page(0, {0, 0, pc, pc}, page, kTile);
    const std::vector<std::uint32_t> entry{PageTable::make_entry(0, 0)};
    r.upload_page_table(0, 0, pc, pc, 1, 1, entry);
    ASSERT_TRUE(r.set_scene(tessera::test::rect_chunk(size, 0, 0, size, size), 0).ok());
    const double height = double(kH) / 8.0 / (2.0 * std::tan(sc::Camera{}.fov_y / 2.0));
    // Fractions a float keeps at 2^20 (1/8s): the chunk-relative geometry is exact, what is
    // measured is the texel addressing alone.
    const sc::Camera cam = straight_down(cx + 0.375, cy + 0.625, height);
    r.render(cam, 0);
    r.finish(nullptr, nullptr);
    const auto rgba = r.read_color();
    int worst = 0;
    std::size_t checked = 0;
    for (std::uint32_t j = 0; j < kH; ++j)
        for (std::uint32_t i = 0; i < kW; ++i) {
            double x = 0, y = 0;
            ASSERT_TRUE(tessera::test::pixel_to_ground(cam, kW, kH, i, j, x, y));
            // Bilinear between the four texel centres around (x, y).
            const double u = x - 0.5, v = y - 0.5, fu = u - std::floor(u), fv = v - std::floor(v);
            const auto i0 = std::int64_t(std::floor(u)), j0 = std::int64_t(std::floor(v));
            const double want = (1 - fu) * (1 - fv) * checker(i0, j0) + fu * (1 - fv) * checker(i0 + 1, j0) +
                                (1 - fu) * fv * checker(i0, j0 + 1) + fu * fv * checker(i0 + 1, j0 + 1);
            const int got = rgba[(std::size_t(j) * kW + i) * 4];
            worst = std::max(worst, int(std::lround(std::abs(got - want))));
            ++checked;
        }
    EXPECT_EQ(checked, std::size_t(kW) * kH);
    EXPECT_LE(worst, 2) << "levels of 255 off the bilinear value at the pixels' ground points, " << size
                        << " texels into one chunk";
    std::printf("  %u texels into a %u-texel chunk, 8 pixels per texel: worst %d of 255 off the exact bilinear value\n", cx, size,
                worst);
}

TEST(RenderStability, StaticCameraDoesNotFlicker) {
    REQUIRE_GL(ctx);
    auto cfg = config();
    cfg.filter = gl::Filter::anisotropic;
    cfg.feedback_scale = 4;
    auto made = gl::VtRenderer::create(cfg);
    ASSERT_TRUE(made.ok()) << made.error().message;
    gl::VtRenderer& r = **made;
    const std::uint32_t size = 8192 * kP;  // 2^23 area: 8.3M texels per side, accepted on llvmpipe
    const st::StoreInfo info = geometry(size);
    ASSERT_TRUE(r.add_texture(0, info).ok());
    // Only the coarsest level (one page) is resident: every other entry is empty or falls back to
    // it, which is enough to compare two frames.
    std::vector<std::uint8_t> page(std::size_t(kTile) * kTile * 4);
    for (std::uint32_t j = 0; j < kTile; ++j)
        for (std::uint32_t i = 0; i < kTile; ++i) encode_texel(i * 7, j * 13, page.data() + (std::size_t(j) * kTile + i) * 4);
    const std::uint32_t top = info.level_count() - 1;
    r.upload_page(0, {0, std::uint8_t(top), 0, 0}, page, kTile);
    const std::vector<std::uint32_t> root{PageTable::make_entry(0, top)};
    r.upload_page_table(0, top, 0, 0, 1, 1, root);
    ASSERT_TRUE(r.set_scene(corner_chunk(size, size - 65536), 0).ok());

    for (const auto& cam_pose : {std::array<double, 5>{size - 100.5, size - 100.5, 3.0, 1.25 * std::numbers::pi, -0.05},
                                 std::array<double, 5>{size - 3000.25, size - 2000.75, 400.0, 1.2 * std::numbers::pi, -0.7}}) {
        sc::Camera cam;
        cam.position = {cam_pose[0], cam_pose[1], cam_pose[2]};
        cam.yaw = cam_pose[3];
        cam.pitch = cam_pose[4];
        cam.near_plane = 0.5;
        cam.far_plane = 1e6;
        std::vector<std::uint8_t> images[2];
        gl::FeedbackFrame feedback[2];
        for (int k = 0; k < 2; ++k) {
            r.render(cam, 0);
            r.finish(nullptr, &feedback[k]);
            images[k] = r.read_color();
        }
        EXPECT_EQ(r.stats().gl_errors, 0u);
        EXPECT_EQ(images[0], images[1]) << "the same camera gave two different images";
        EXPECT_EQ(feedback[0].ids, feedback[1].ids) << "the same camera gave two different feedback buffers";
        std::size_t vt = 0;
        for (const FeedbackId id : feedback[0].ids) {
            if (id == kNoPage) continue;
            ++vt;
            const auto key = tessera::client::unpack_feedback(id);
            ASSERT_LT(key.level, info.level_count());
            ASSERT_LT(key.x, info.levels[key.level].tiles_x);
            ASSERT_LT(key.y, info.levels[key.level].tiles_y);
        }
        EXPECT_GT(vt, feedback[0].ids.size() / 4);
        std::printf("  camera (%.2f, %.2f, %.1f): 2 frames identical, %zu feedback pixels on the VT\n", cam.position[0],
                    cam.position[1], cam.position[2], vt);
    }
}

}  // namespace
