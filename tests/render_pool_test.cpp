// The whole client path under Mesa llvmpipe: a real store read by the local source, the runtime,
// and the GL renderer's feedback and counters. With a pool far too small for the view the image
// blurs gracefully (every textured pixel has data; the bias rises until what is wanted fits), the
// bias settles and nothing thrashes; with the pool large enough detail comes back in full.
#include <gtest/gtest.h>

#include <cmath>

#include "tessera/client/gl/context.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "tessera/client/runtime.hpp"
#include "tessera/client/tile_source.hpp"
#include "tessera/scene/scene.hpp"
#include "render_util.hpp"
#include "test_util.hpp"

namespace {

using namespace tessera;
using tessera::test::ScratchDir;

struct Frame {
    float bias = 0;
    std::uint32_t evicted = 0, wanted = 0;
};

struct PoolRun {
    std::vector<Frame> frames;
    std::vector<client::gl::FrameCounters> counters;
};

class RenderPool : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        dir_ = new ScratchDir();
        store_ = dir_->file("terrain.tsr");
        auto r = tessera::test::run_tessera("build procedural:terrain:2048 --tile-size 64 --codec zstd --quiet -o " + store_);
        ASSERT_EQ(r.exit_code, 0) << r.out;
    }
    static void TearDownTestSuite() { delete dir_; }

    void SetUp() override {
        auto ctx = client::gl::GlContext::create_headless();
        if (!ctx) GTEST_FAIL() << tessera::test::no_gl_message(ctx.error().message);
        ctx_ = std::move(*ctx);
        ctx_->make_current();
    }

    // A low camera looking across the terrain: near pages want level 0, far ones coarse levels.
    static scene::Camera camera() {
        scene::Camera c;
        c.position = {1200, 1500, 25};  // inside the 2048-unit terrain, low
        c.yaw = 0.6;
        c.pitch = -0.5;  // ~29 degrees down: level 0 near, coarse levels far
        return c;
    }

    PoolRun run(std::uint32_t pool, unsigned frames) {
        client::gl::RendererConfig rc;
        rc.width = 256;
        rc.height = 160;
        rc.feedback_scale = 4;
        rc.pool_slots = pool;
        rc.tile_size = 64;
        rc.border = 4;
        auto renderer = client::gl::VtRenderer::create(rc);
        EXPECT_TRUE(renderer.ok()) << renderer.error().message;
        auto source = client::make_local_store_source(1);
        client::RuntimeConfig cfg;
        cfg.residency.pool_slots = pool;
        cfg.transcode_threads = 0;
        cfg.upload_pages_per_frame = 16;
        auto rt = client::Runtime::create(cfg, **renderer, &(*renderer)->page_staging());
        EXPECT_TRUE(rt.ok());
        auto tex = (*rt)->add_texture(*source, store_);
        EXPECT_TRUE(tex.ok());
        const auto& info = *(*rt)->texture_info(*tex);
        EXPECT_TRUE((*renderer)->add_texture(*tex, info).ok());
        scene::TerrainOptions t;
        t.vt_width = info.width;
        t.vt_height = info.height;
        auto sc = scene::make_terrain(t);
        EXPECT_TRUE(sc.ok());
        EXPECT_TRUE((*renderer)->set_scene(*sc, *tex).ok());

        PoolRun out;
        client::gl::FeedbackFrame fb;
        for (unsigned f = 0; f < frames; ++f) {
            (*renderer)->render(camera(), (*rt)->lod_bias());
            const client::FrameStats* s = nullptr;
            if ((*renderer)->poll_feedback(fb)) s = &(*rt)->frame(fb.ids, fb.width, fb.height, fb.bias);
            else s = &(*rt)->frame_without_feedback();
            out.frames.push_back({s->lod_bias, s->pages_evicted, s->pages_wanted});
            (*renderer)->poll_counters(out.counters);
        }
        (*renderer)->finish(&out.counters, nullptr);
        return out;
    }

    std::unique_ptr<client::gl::GlContext> ctx_;
    static ScratchDir* dir_;
    static std::string store_;
};
ScratchDir* RenderPool::dir_ = nullptr;
std::string RenderPool::store_;

TEST_F(RenderPool, TooSmallAPoolBlursGracefullyAndSettles) {
    const auto r = run(20, 240);  // the view wants ~22 pages at bias 0, pinned levels included
    ASSERT_FALSE(r.counters.empty());
    std::printf("wanted first %u last %u; bias last %.2f\n", r.frames[5].wanted, r.frames.back().wanted, r.frames.back().bias);
    // The bias rose, then stopped changing; at most one reversal.
    EXPECT_GT(r.frames.back().bias, 0.0f);
    for (std::size_t f = 160; f < r.frames.size(); ++f) EXPECT_EQ(r.frames[f].bias, r.frames.back().bias) << "frame " << f;
    int reversals = 0, last = 0;
    for (std::size_t f = 1; f < r.frames.size(); ++f) {
        const int d = r.frames[f].bias > r.frames[f - 1].bias ? 1 : r.frames[f].bias < r.frames[f - 1].bias ? -1 : 0;
        if (d && last && d != last) ++reversals;
        if (d) last = d;
    }
    EXPECT_LE(reversals, 1);
    // Nothing thrashes once settled.
    std::uint32_t late = 0;
    for (std::size_t f = 160; f < r.frames.size(); ++f) late += r.frames[f].evicted;
    EXPECT_LE(late, 8u);
    // Gracefully: at the settled bias the view is fully resident (no fallback against the biased
    // level), while against the unbiased level it is blurrier than wanted.
    const auto& c = r.counters.back();
    ASSERT_GT(c.textured_pixels, 1000u);
    EXPECT_LE(c.fallback_biased, c.textured_pixels / 200) << "pipeline keeps up at the settled bias";
    EXPECT_GT(c.fallback_unbiased, 0u) << "the pool really was too small";
}

TEST_F(RenderPool, ALargePoolReachesFullDetail) {
    const auto r = run(1024, 120);
    ASSERT_FALSE(r.counters.empty());
    EXPECT_EQ(r.frames.back().bias, 0.0f);
    const auto& c = r.counters.back();
    ASSERT_GT(c.textured_pixels, 1000u);
    EXPECT_EQ(c.fallback_unbiased, 0u);
    std::uint32_t evicted = 0;
    for (const auto& f : r.frames) evicted += f.evicted;
    EXPECT_EQ(evicted, 0u);
}

}  // namespace

// Configurations the renderer cannot draw correctly are refused with a message naming the limit.
TEST(RendererConfigErrors, BadConfigsAreClearErrors) {
    auto made = client::gl::GlContext::create_headless();
    if (!made) GTEST_FAIL() << tessera::test::no_gl_message(made.error().message);
    (*made)->make_current();
    const auto error_of = [](const client::gl::RendererConfig& rc) {
        auto r = client::gl::VtRenderer::create(rc);
        return r.ok() ? std::string() : r.error().message;
    };
    client::gl::RendererConfig rc;
    rc.width = 64;
    rc.height = 32;
    rc.pool_slots = 4;
    rc.filter = client::gl::Filter::anisotropic;
    rc.tile_size = 24;
    rc.border = 4;  // payload 16: just enough for 8x
    EXPECT_EQ(error_of(rc), "");
    rc.tile_size = 22;  // payload 14: the taps at 8x may span two page edges
    EXPECT_NE(error_of(rc).find("anisotropic filter at 8x needs pages of at least 16 texels"), std::string::npos) << error_of(rc);
    rc.max_anisotropy = 4;  // 4x spans under 8 texels
    EXPECT_EQ(error_of(rc), "");
    rc.max_anisotropy = 9;
    EXPECT_NE(error_of(rc).find("max_anisotropy must be 1..8"), std::string::npos) << error_of(rc);
    rc.max_anisotropy = 8;
    rc.filter = client::gl::Filter::trilinear;
    rc.tile_size = 23;
    EXPECT_NE(error_of(rc).find("even tile size"), std::string::npos) << error_of(rc);
    rc.tile_size = 8;
    EXPECT_NE(error_of(rc).find("leave no payload"), std::string::npos) << error_of(rc);
}
