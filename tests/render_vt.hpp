#pragma once
// The VT as the rendering tests drive it: the runtime over a local store uploading into a
// VtRenderer, every page made resident, one frame rendered and read back with its counters.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "runtime_internal.hpp"
#include "tessera/client/gl/frame_loop.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "tessera/client/runtime.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/scene/scene.hpp"
#include "tessera/client/tile_source.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::test {

namespace vt_detail {
namespace gl = tessera::client::gl;
namespace sc = tessera::scene;
namespace st = tessera::storage;
using tessera::client::FeedbackId;
using tessera::client::PageKey;
using namespace std::chrono_literals;
}  // namespace vt_detail

using namespace vt_detail;

// The runtime over a local store, uploading into a VtRenderer.
struct Vt {
    std::unique_ptr<tessera::client::TileSource> source;
    std::unique_ptr<gl::VtRenderer> renderer;
    std::unique_ptr<tessera::client::Runtime> runtime;
    st::StoreInfo info;
    tessera::client::TextureId texture = 0;
};

inline std::unique_ptr<Vt> make_vt(const gl::RendererConfig& cfg, const std::string& store, const sc::Scene& scene) {
    auto vt = std::make_unique<Vt>();
    vt->source = tessera::client::make_local_store_source(1);
    auto r = gl::VtRenderer::create(cfg);
    EXPECT_TRUE(r.ok()) << r.error().message;
    if (!r) return nullptr;
    vt->renderer = std::move(*r);
    tessera::client::RuntimeConfig rc;
    rc.residency.pool_slots = cfg.pool_slots;
    rc.transcode_threads = 1;
    rc.upload_pages_per_frame = 128;
    rc.upload_bytes_per_frame = 64u << 20;
    auto rt = tessera::client::Runtime::create(rc, *vt->renderer, &vt->renderer->page_staging());
    EXPECT_TRUE(rt.ok()) << rt.error().message;
    if (!rt) return nullptr;
    vt->runtime = std::move(*rt);
    auto tex = vt->runtime->add_texture(*vt->source, store);
    EXPECT_TRUE(tex.ok()) << tex.error().message;
    if (!tex) return nullptr;
    vt->texture = *tex;
    vt->info = *vt->runtime->texture_info(*tex);
    auto added = vt->renderer->add_texture(vt->texture, vt->info);
    EXPECT_TRUE(added.ok()) << added.error().message;
    auto set = vt->renderer->set_scene(scene, vt->texture);
    EXPECT_TRUE(set.ok()) << set.error().message;
    if (!added || !set) return nullptr;
    return vt;
}

inline std::uint64_t page_count(const st::StoreInfo& info) {
    std::uint64_t n = 0;
    for (const auto& l : info.levels) n += std::uint64_t(l.tiles_x) * l.tiles_y;
    return n;
}

// Drives the runtime with a feedback naming every page of every level until all are resident.
// Gives up after `timeout` without a page becoming resident (a bound on stalls, not on the whole
// load, which a sanitizer's slowdown stretches).
inline bool load_everything(Vt& vt, std::chrono::seconds timeout = 60s) {
    std::vector<FeedbackId> ids;
    for (std::uint32_t l = 0; l < vt.info.level_count(); ++l)
        for (std::uint32_t y = 0; y < vt.info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < vt.info.levels[l].tiles_x; ++x)
                ids.push_back(tessera::client::pack_feedback(PageKey{vt.texture, std::uint8_t(l), x, y}));
    const auto total = page_count(vt.info);
    auto deadline = std::chrono::steady_clock::now() + timeout;
    std::size_t resident = 0;
    while (std::chrono::steady_clock::now() < deadline) {
        vt.runtime->frame(ids, std::uint32_t(ids.size()), 1, 0.0f);
        const std::size_t now_resident = residency_of(*vt.runtime).stats().resident_pages;
        if (now_resident == total && vt.runtime->in_flight() == 0) return true;
        if (now_resident > resident) deadline = std::chrono::steady_clock::now() + timeout;
        resident = now_resident;
        std::this_thread::sleep_for(2ms);
    }
    return false;
}

struct Frame {
    std::vector<std::uint8_t> rgba;
    gl::FrameCounters counters;
};

inline Frame render_vt(gl::VtRenderer& r, const sc::Camera& cam, float bias = 0) {
    const auto n = r.render(cam, bias);
    std::vector<gl::FrameCounters> counters;
    r.finish(&counters, nullptr);
    Frame f;
    f.rgba = r.read_color();
    for (const auto& c : counters)
        if (c.frame == n) f.counters = c;
    EXPECT_EQ(f.counters.frame, n) << "no counters for frame " << n;
    EXPECT_EQ(r.stats().gl_errors, 0u);
    EXPECT_EQ(r.stats().malformed_uploads, 0u);
    return f;
}

// Pixels with geometry (alpha set: the textures are opaque, the background is transparent).
inline std::vector<std::uint8_t> coverage(const std::vector<std::uint8_t>& rgba) {
    std::vector<std::uint8_t> m(rgba.size() / 4);
    for (std::size_t i = 0; i < m.size(); ++i) m[i] = rgba[i * 4 + 3] != 0;
    return m;
}

inline std::size_t count(const std::vector<std::uint8_t>& mask) { return std::size_t(std::count(mask.begin(), mask.end(), 1)); }

// The render loop of a viewer, bounded (FrameLoop::settle): render `cam`, feed the feedback to the
// runtime, read the counters, until a frame of this view rendered once nothing was in flight has
// no pixel falling back (against either level; a view of none of the texture has none), no page
// is fading and the bias is 0; or until `timeout` has passed.
struct Convergence {
    bool converged = false;
    int frames = 0;
    gl::FrameCounters latest{};  // the newest counters of a frame of this view
};
inline Convergence render_until_resident(gl::VtRenderer& renderer, tessera::client::Runtime& rt, const sc::Camera& cam,
                                         std::chrono::seconds timeout = 60s) {
    gl::FrameLoop loop(renderer, rt);
    const gl::Settled held = loop.settle(cam, timeout);
    return Convergence{held.settled, int(held.frames), held.counters};
}

}  // namespace tessera::test
