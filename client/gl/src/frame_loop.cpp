#include "tessera/client/gl/frame_loop.hpp"

#include <thread>

namespace tessera::client::gl {

FrameStep FrameLoop::step(const scene::Camera& camera, const std::function<void(std::uint64_t)>& after_render) {
    FrameStep s;
    s.frame = renderer_.render(camera, runtime_.lod_bias());
    if (after_render) after_render(s.frame);
    if (renderer_.poll_feedback(feedback_)) {
        s.stats = &runtime_.frame(feedback_.ids, feedback_.width, feedback_.height, feedback_.bias);
        s.feedback = &feedback_;
    } else {
        s.stats = &runtime_.frame_without_feedback();
    }
    counters_.clear();
    renderer_.poll_counters(counters_);
    return s;
}

Settled FrameLoop::settle(const scene::Camera& camera, std::chrono::duration<double> timeout,
                          const std::function<void()>& before_frame, const std::function<bool()>& give_up) {
    using Clock = std::chrono::steady_clock;
    const auto until = Clock::now() + std::chrono::duration_cast<Clock::duration>(timeout);
    Settled out;
    std::uint64_t first = 0;      // the first frame of this view: earlier views' counters do not count
    std::uint64_t idle_from = 0;  // the first frame rendered with nothing in flight; 0: busy
    std::size_t pending_before = 0;
    for (;;) {
        // A frame in which nothing arrived, was mapped or faded changes nothing the next one would
        // show: while pages are only awaited, wait a little rather than render thousands of
        // identical frames a second (a small view on a software renderer), which takes the CPU
        // from the threads that fetch and transcode those pages.
        const std::size_t pending = runtime_.in_flight();
        if (out.frames > 0 && pending > 0 && pending == pending_before && renderer_.stats().fading_pages == 0)
            std::this_thread::sleep_for(kAwaitPause);
        pending_before = pending;
        if (before_frame) before_frame();
        const FrameStep s = step(camera);
        ++out.frames;
        if (first == 0) first = s.frame;
        if (runtime_.in_flight() > 0) idle_from = 0;
        else if (idle_from == 0) idle_from = s.frame + 1;  // this frame's uploads show from the next one
        bool clean = false;
        for (const auto& c : counters_) {
            if (c.frame < first) continue;
            out.counters = c;
            // No textured pixel at all is clean too: a view that shows none of the texture (the camera
            // beside it, a texture under a pixel wide) wants nothing, and an empty entry would count
            // as fallback.
            clean = clean || (idle_from > 0 && c.frame >= idle_from && c.fallback_unbiased == 0 && c.fallback_biased == 0);
        }
        if (clean && renderer_.stats().fading_pages == 0 && runtime_.lod_bias() == 0.0f) {
            out.settled = true;
            break;
        }
        if (Clock::now() >= until || (give_up && give_up())) break;
    }
    renderer_.finish(&counters_, nullptr);  // drain the readbacks: what follows starts clean
    for (const auto& c : counters_)
        if (c.frame >= first) out.counters = c;
    counters_.clear();
    return out;
}

}  // namespace tessera::client::gl
