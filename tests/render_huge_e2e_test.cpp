// A 2^24-texel virtual texture end to end (docs/stability.md, "Reaching 2^24 end to end"), on Mesa
// llvmpipe or a GPU, through the real client runtime: the renderer's feedback goes to
// Runtime::frame (analysis, residency, the sparse page table, requests), the on-demand procedural
// source makes the tiles (procedural:coords, no store file), the transcode pool and upload queue
// bring them to the renderer, and the two-level page table is fed by the runtime.
// A straight-down camera at exactly 2^L texels per pixel looks at the far corner of the texture
// (the last page corner of level L, over a chunk with an odd texel origin); frames run until the
// counters say nothing falls back, then the image is read back and every pixel on a level-L
// texel centre must be coords_texel(L, x, y) exactly.
//
//   RenderHugeEndToEnd.Size2e24           2^24 texels, 256-texel tiles (67,651 pages per side)
//   RenderHugeEndToEnd.Size2e24Minus1     2^24 - 1, 512-texel tiles (33,289 pages per side)
//   RenderHugeEndToEnd.NonPowerOfTwoSize  12,345,679, 1024-texel tiles (12,152 pages per side)
// Levels 0, 1, 6 and the second coarsest; the table stays sparse (memory follows the resident pages).
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <numbers>
#include <string>
#include <thread>
#include <vector>

#include "ground_ray.hpp"
#include "render_util.hpp"
#include "render_vt.hpp"
#include "tessera/client/gl/context.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "page_table.hpp"
#include "procedural_source.hpp"
#include "tessera/client/runtime.hpp"
#include "runtime_internal.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/scene/scene.hpp"
#include "tessera/storage/types.hpp"

namespace {

using namespace std::chrono_literals;
namespace gl = tessera::client::gl;
namespace sc = tessera::scene;
namespace st = tessera::storage;
using tessera::client::PageKey;
using tessera::client::PageTable;
using tessera::test::corner_chunk;
using tessera::test::straight_down;

constexpr std::uint32_t kW = 128, kH = 96;

struct LevelRun {
    int frames = 0;
    std::size_t checked = 0, wrong = 0;
    double seconds = 0;
};

void far_corner_end_to_end(std::uint32_t size, std::uint32_t tile, std::uint32_t pool) {
    SCOPED_TRACE(testing::Message() << "size " << size << ", tile " << tile);
    gl::RendererConfig cfg = tessera::test::exact_config(kW, kH, tile, 4, pool);
    cfg.feedback_scale = 1;  // every pixel's page is asked for: nothing is left to fall back
    auto made = gl::VtRenderer::create(cfg);
    ASSERT_TRUE(made.ok()) << made.error().message;
    gl::VtRenderer& renderer = **made;

    auto source = tessera::client::make_procedural_source(2);
    tessera::client::RuntimeConfig rc;
    rc.residency.pool_slots = pool;
    rc.transcode_threads = 1;
    rc.ram_cache_bytes = 32u << 20;  // a few 1024-texel raw tiles: CI memory
    auto rt_made = tessera::client::Runtime::create(rc, renderer, &renderer.page_staging());
    ASSERT_TRUE(rt_made.ok()) << rt_made.error().message;
    tessera::client::Runtime& rt = **rt_made;
    const std::string spec = "procedural:coords:" + std::to_string(size) + ":" + std::to_string(tile) + ":4";
    auto tex = rt.add_texture(*source, spec);
    ASSERT_TRUE(tex.ok()) << tex.error().message;
    const st::StoreInfo info = *rt.texture_info(*tex);
    const std::uint32_t n = info.levels[0].tiles_x, levels = info.level_count(), P = info.tile_payload;
    ASSERT_FALSE(PageTable::dense_packing_fits(n, n)) << "should need the two-level table";
    auto added = renderer.add_texture(*tex, info);
    ASSERT_TRUE(added.ok()) << added.error().message;
    const PageTable* table = residency_of(rt).table(*tex);
    ASSERT_NE(table, nullptr);
    ASSERT_TRUE(table->sparse());

    for (const std::uint32_t level : {0u, 1u, 6u, levels - 2}) {
        const auto t0 = std::chrono::steady_clock::now();
        LevelRun run;
        const std::uint32_t texels = info.levels[level].width, last = info.levels[level].tiles_x - 1;
        ASSERT_GE(last, 1u);
        const std::uint32_t k = last * P;  // the last page corner, in level-L texels
        const double scale = std::ldexp(1.0, int(level));
        const std::uint64_t span = std::uint64_t(double(size) - (double(k) - 80) * scale) + 3;
        const std::uint32_t o = std::uint32_t(size - span) | 1u;
        ASSERT_TRUE(renderer.set_scene(corner_chunk(size, o), *tex).ok());
        const double height = scale * kH / (2.0 * std::tan(sc::Camera{}.fov_y / 2.0));
        const sc::Camera cam = straight_down(double(k) * scale, double(k) * scale, height);

        const auto converge = tessera::test::render_until_resident(renderer, rt, cam);
        run.frames = converge.frames;
        ASSERT_TRUE(converge.converged) << "level " << level << ": after " << run.frames << " frames, " << converge.latest.fallback_unbiased
                                        << " of " << converge.latest.textured_pixels << " pixels fall back, " << rt.in_flight()
                                        << " pages in flight, bias " << rt.lod_bias();

        // The checked frame.
        const auto frame = renderer.render(cam, 0.0f);
        std::vector<gl::FrameCounters> counters;
        renderer.finish(&counters, nullptr);
        const auto rgba = renderer.read_color();
        EXPECT_EQ(renderer.stats().gl_errors, 0u);
        EXPECT_EQ(renderer.stats().malformed_uploads, 0u);
        bool counted = false;
        for (const auto& c : counters)
            if (c.frame == frame) {
                counted = true;
                EXPECT_EQ(c.fallback_unbiased, 0u) << "level " << level;
                EXPECT_EQ(c.fallback_biased, 0u) << "level " << level;
                EXPECT_GT(c.textured_pixels, std::uint64_t(kW * kH / 4)) << "level " << level;
            }
        EXPECT_TRUE(counted) << "level " << level;
        const auto check = tessera::test::check_texel_centres(rgba, cam, kW, kH, level, o, size, [&](std::uint32_t gx, std::uint32_t gy) {
            EXPECT_LT(gx, texels);
            return tessera::client::coords_texel(level, gx, gy);
        });
        run.checked = check.checked;
        run.wrong = check.wrong;
        EXPECT_EQ(run.wrong, 0u) << "level " << level << " of " << run.checked;
        EXPECT_GE(run.checked, std::size_t(kW * kH / 4)) << "level " << level;
        // The 2 x 2 pages around the corner are what the runtime made resident.
        for (const std::uint32_t py : {last - 1, last})
            for (const std::uint32_t px : {last - 1, last})
                EXPECT_TRUE(residency_of(rt).is_resident(PageKey{*tex, std::uint8_t(level), px, py}))
                    << "level " << level << " page (" << px << ", " << py << ")";
        run.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        const auto rs = residency_of(rt).stats();
        std::printf("  %u texels (2^%.4f), tile %u: level %u (%u pages per side): %d frames, %.2f s; %u pages resident, "
                    "%zu pixels on texel centres, %zu wrong\n",
                    size, std::log2(double(size)), tile, level, last + 1, run.frames, run.seconds, rs.resident_pages,
                    run.checked, run.wrong);
    }

    // Memory follows the resident pages: at most 5 blocks each, plus the coarse levels' blocks.
    std::size_t coarse = 0;
    for (std::uint32_t l = 0; l < levels; ++l)
        coarse += info.levels[l].tiles_x <= PageTable::kBlockSide && info.levels[l].tiles_y <= PageTable::kBlockSide;
    EXPECT_TRUE(table->sparse());
    EXPECT_LE(table->allocated_blocks(), 5 * table->mapped_pages() + coarse);
    EXPECT_LT(table->memory_bytes(), std::size_t(8) << 20);
    EXPECT_EQ(renderer.stats().malformed_uploads, 0u);
    std::printf("  sparse table: %zu pages mapped, %zu blocks, %.2f MiB (dense: %.1f MiB); %llu pages uploaded, %llu "
                "table uploads\n",
                table->mapped_pages(), table->allocated_blocks(), double(table->memory_bytes()) / (1 << 20),
                double(PageTable::table_bytes(n, n, levels)) / (1 << 20),
                static_cast<unsigned long long>(renderer.stats().pages_uploaded),
                static_cast<unsigned long long>(renderer.stats().table_uploads));
}

TEST(RenderHugeEndToEnd, Size2e24) {
    REQUIRE_GL(ctx);
    far_corner_end_to_end(1u << 24, 256, 128);
}

TEST(RenderHugeEndToEnd, Size2e24Minus1) {
    REQUIRE_GL(ctx);
    far_corner_end_to_end((1u << 24) - 1, 512, 64);
}

TEST(RenderHugeEndToEnd, NonPowerOfTwoSize) {
    REQUIRE_GL(ctx);
    far_corner_end_to_end(12'345'679, 1024, 32);
}

}  // namespace
