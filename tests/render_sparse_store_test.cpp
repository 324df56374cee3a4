// A sparse 2^24 x 2^24 store end to end (docs/store-format.md, "Sparse stores"): `tessera build
// procedural:coords-sparse:16777216` writes only the tiles around each level's corners and centre,
// `tessera serve` serves it over gRPC, and the client runtime with the GL renderer (llvmpipe or a
// GPU) views it straight down at the four corners and the centre at levels 0, 1 and 13, each at
// exactly 2^L texels per pixel: every pixel on a level-L texel centre must be coords_texel(L, x, y)
// exactly, and no pixel may fall back. The store opens in milliseconds however large it is.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "render_util.hpp"
#include "render_vt.hpp"
#include "server_process.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "tessera/client/runtime.hpp"
#include "tessera/client/tile_source.hpp"
#include "tessera/storage/coords_pattern.hpp"
#include "tessera/storage/store_reader.hpp"
#include "test_util.hpp"

namespace {

using namespace std::chrono_literals;
namespace gl = tessera::client::gl;
namespace sc = tessera::scene;
namespace st = tessera::storage;
using tessera::test::ScratchDir;
using tessera::test::ServerProcess;

constexpr std::uint32_t kSize = 1u << 24;
constexpr std::uint32_t kW = 128, kH = 96;

TEST(SparseStore, TwoToTheTwentyFourServedAndViewedAtItsCornersAndCentre) {
    REQUIRE_GL(ctx);
    ScratchDir dir;
    const std::string store = dir.file("sparse.tsr");
    const auto built = tessera::test::run_tessera("build procedural:coords-sparse:" + std::to_string(kSize) + " -o " + store);
    ASSERT_EQ(built.exit_code, 0) << built.out;
    std::printf("%s", built.out.c_str());

    // Opening reads the header, level table and block tables only (best of three: a cold cache
    // or a busy machine is not the store's cost).
    double open_ms = 1e9, first_ms = 0;
    std::uint64_t present = 0, index_bytes = 0, entry_blocks = 0;
    for (int i = 0; i < 3; ++i) {
        const auto t0 = std::chrono::steady_clock::now();
        auto r = st::StoreReader::open(store);
        const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
        if (i == 0) first_ms = ms;
        open_ms = std::min(open_ms, ms);
        ASSERT_TRUE(r.ok()) << r.error().message;
        present = index_bytes = entry_blocks = 0;
        for (const auto& l : (*r)->info().levels) {
            present += l.present;
            index_bytes += l.index_bytes;
            // A sparse level's index: 24 bytes and one 96 KiB entry block per non-empty block.
            EXPECT_TRUE(l.sparse_block_table);
            EXPECT_EQ(l.index_bytes % (98304 + 24), 0u);
            entry_blocks += l.index_bytes / (98304 + 24);
        }
    }
    std::printf("  opened in %.2f ms (best of 3; the first %.2f ms); %llu present tiles; index %llu bytes, %llu entry blocks\n", open_ms,
                first_ms, static_cast<unsigned long long>(present), static_cast<unsigned long long>(index_bytes),
                static_cast<unsigned long long>(entry_blocks));
    EXPECT_LT(open_ms, 100.0);
    EXPECT_LT(present, 1000u) << "only the regions' tiles are present";
    {
        auto r = st::StoreReader::open(store);
        ASSERT_TRUE(r.ok());
        EXPECT_EQ((*r)->info().version_minor, 2u) << "a sparse index";
        EXPECT_LT((*r)->info().file_size, std::uint64_t(64) << 20) << "the index follows the present tiles";
    }
    // The index follows the present blocks (at most one per present tile), far below level 0's
    // dense block table alone (1058 x 1058 records, 18 MB).
    EXPECT_GE(entry_blocks, 5u);
    EXPECT_LE(entry_blocks, present);
    EXPECT_EQ(index_bytes, entry_blocks * (98304 + 24));

    ServerProcess srv({"--store", store}, dir.file("log"));
    ASSERT_TRUE(srv.running()) << srv.log();
    tessera::client::TileStreamOptions net;
    net.target = srv.grpc_address();
    auto source = tessera::client::make_grpc_source(net);

    gl::RendererConfig cfg = tessera::test::exact_config(kW, kH, 256, 4, 96);
    cfg.feedback_scale = 1;  // every pixel's page is asked for: nothing is left to fall back
    auto made = gl::VtRenderer::create(cfg);
    ASSERT_TRUE(made.ok()) << made.error().message;
    gl::VtRenderer& renderer = **made;
    tessera::client::RuntimeConfig rc;
    rc.residency.pool_slots = cfg.pool_slots;
    rc.transcode_threads = 1;
    rc.ram_cache_bytes = 16u << 20;
    auto rt_made = tessera::client::Runtime::create(rc, renderer, &renderer.page_staging());
    ASSERT_TRUE(rt_made.ok()) << rt_made.error().message;
    tessera::client::Runtime& rt = **rt_made;
    auto tex = rt.add_texture(*source, "sparse");
    ASSERT_TRUE(tex.ok()) << tex.error().message;
    const st::StoreInfo info = *rt.texture_info(*tex);
    ASSERT_EQ(info.width, kSize);
    ASSERT_TRUE(renderer.add_texture(*tex, info).ok());

    for (const std::uint32_t level : {0u, 1u, 13u}) {
        const std::int64_t lw = info.levels[level].width, lh = info.levels[level].height;
        // View centres (level-L texel corners): 64 texels in from each corner, and the centre.
        const std::pair<std::int64_t, std::int64_t> centres[] = {{64, 64}, {lw - 64, 64}, {64, lh - 64}, {lw - 64, lh - 64}, {lw / 2, lh / 2}};
        for (const auto& [cx, cy] : centres) {
            SCOPED_TRACE(testing::Message() << "level " << level << " at (" << cx << ", " << cy << ")");
            const auto t0 = std::chrono::steady_clock::now();
            const double scale = std::ldexp(1.0, int(level));
            // The chunk: 80 level texels around the view centre, clamped to the texture; an odd
            // origin (low bits set) where the texture allows.
            const auto lo = [&](std::int64_t c) { return std::uint32_t(std::max<double>(0.0, double(c - 80) * scale)) | 1u; };
            const auto hi = [&](std::int64_t c) { return std::uint32_t(std::min<double>(kSize, double(c + 80) * scale)); };
            const std::uint32_t x0 = lo(cx), y0 = lo(cy), x1 = hi(cx), y1 = hi(cy);
            ASSERT_TRUE(renderer.set_scene(tessera::test::rect_chunk(kSize, x0, y0, x1, y1), *tex).ok());
            const double height = scale * kH / (2.0 * std::tan(sc::Camera{}.fov_y / 2.0));
            const sc::Camera cam = tessera::test::straight_down(double(cx) * scale, double(cy) * scale, height);

            const auto run = tessera::test::render_until_resident(renderer, rt, cam);
            ASSERT_TRUE(run.converged) << "after " << run.frames << " frames, " << run.latest.fallback_unbiased << " of "
                                       << run.latest.textured_pixels << " pixels fall back, " << rt.in_flight() << " pages in flight";
            std::vector<gl::FrameCounters> counters;
            const auto frame = renderer.render(cam, 0.0f);
            counters.clear();
            renderer.finish(&counters, nullptr);
            const auto rgba = renderer.read_color();
            bool counted = false;
            for (const auto& c : counters)
                if (c.frame == frame) {
                    counted = true;
                    EXPECT_EQ(c.fallback_unbiased, 0u);
                }
            EXPECT_TRUE(counted);
            const auto check = tessera::test::check_texel_centres_in(rgba, cam, kW, kH, level, x0, y0, x1, y1, [&](std::uint32_t gx, std::uint32_t gy) {
                return st::coords_texel(level, gx, gy);
            });
            EXPECT_EQ(check.wrong, 0u) << "of " << check.checked;
            EXPECT_GE(check.checked, std::size_t(kW * kH / 4));
            std::printf("  level %u at (%lld, %lld): %d frames, %.2f s, %zu texel centres, %zu wrong\n", level, static_cast<long long>(cx),
                        static_cast<long long>(cy), run.frames, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
                        check.checked, check.wrong);
        }
    }
    EXPECT_EQ(renderer.stats().malformed_uploads, 0u);
    EXPECT_EQ(renderer.stats().gl_errors, 0u);
}

}  // namespace
