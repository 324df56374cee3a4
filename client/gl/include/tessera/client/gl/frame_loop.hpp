#pragma once
// The frame every program that draws a virtual texture runs (docs/client.md, "The frame loop"):
// render at the runtime's LoD bias, hand the runtime the newest finished feedback readback (a
// frame without one still decodes and uploads what arrived), and collect the counter readbacks
// that came back. And holding one view until it has settled: everything it needs resident and at
// full weight, nothing in flight, no fallback in a frame rendered after the pipeline went idle.
// Never waits on the GPU in step(); settle() drains the readbacks when it ends.
#include <chrono>
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "tessera/client/gl/renderer.hpp"
#include "tessera/client/runtime.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/client/stats.hpp"

namespace tessera::client::gl {

struct FrameStep {
    std::uint64_t frame = 0;                  // the renderer's number for the frame rendered
    const FrameStats* stats = nullptr;        // the runtime's frame (valid until the next step)
    const FeedbackFrame* feedback = nullptr;  // the feedback handed to it, if any (likewise)
};

struct Settled {
    bool settled = false;   // false: the timeout came first
    std::uint32_t frames = 0;
    FrameCounters counters{};  // the newest counters of a frame of the view held
};

class FrameLoop {
public:
    // Both must outlive the loop; the renderer is the runtime's uploader.
    FrameLoop(VtRenderer& renderer, Runtime& runtime) : renderer_(renderer), runtime_(runtime) {}

    // One frame at `camera`, drawn with the runtime's bias. `after_render` (optional) runs between
    // the draw and the runtime's frame: before this frame's uploads (a preview of the next view,
    // for the pop measure).
    FrameStep step(const scene::Camera& camera, const std::function<void(std::uint64_t frame)>& after_render = {});
    // The counter readbacks the last step collected, oldest first.
    std::span<const FrameCounters> counters() const { return counters_; }

    // Renders `camera` until settled, or until `timeout` has passed. `before_frame` (optional)
    // runs before each frame: the runtime's clock, a link monitor. Counters come back frames
    // late (more of them the faster the GPU), so settled means clean counters (no fallback at
    // either level; a view that shows no texture at all is clean) of a frame rendered once nothing
    // was in flight, with no page fading and the bias at 0. `give_up` (optional), asked after each frame, ends the wait early
    // (unsettled): a caller that sees the view can never settle (every read an error).
    // While pages are awaited and the last frame changed nothing, it pauses kAwaitPause between
    // frames instead of spinning.
    Settled settle(const scene::Camera& camera, std::chrono::duration<double> timeout,
                   const std::function<void()>& before_frame = {}, const std::function<bool()>& give_up = {});

    static constexpr std::chrono::microseconds kAwaitPause{1000};

private:
    VtRenderer& renderer_;
    Runtime& runtime_;
    FeedbackFrame feedback_;
    std::vector<FrameCounters> counters_;
};

}  // namespace tessera::client::gl
