#pragma once
// Reading GPU results back without waiting: a ring of readback slots in one persistently mapped,
// coherent buffer, each written by the GPU behind a fence that is polled (timeout 0), never waited
// on, so several frames' readbacks are in flight. A frame that finds every slot in flight goes
// without its readback (the renderer counts it) rather than stall the render thread.
//
// Its two users: the feedback image (FeedbackReadback) and the fallback counters (CounterReadback).
#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <vector>

#include "gl_util.hpp"
#include "tessera/client/gl/renderer.hpp"

namespace tessera::client::gl::detail {

class ReadbackRing {
public:
    ReadbackRing() = default;
    ~ReadbackRing();
    ReadbackRing(const ReadbackRing&) = delete;
    ReadbackRing& operator=(const ReadbackRing&) = delete;

    // `slots` regions of `slot_bytes`. Errors: the buffer cannot be mapped (`what` says which).
    Status init(std::size_t slots, std::size_t slot_bytes, const std::string& what);

    // A free slot; when there is none, `collect` (which should call finished()) runs and the
    // search is tried once more. Nothing when every slot is still in flight.
    template <class Collect>
    std::optional<std::size_t> acquire(Collect&& collect) {
        for (int attempt = 0; attempt < 2; ++attempt) {
            for (std::size_t i = 0; i < slots_.size(); ++i)
                if (!slots_[i].busy) return i;
            collect();
        }
        return std::nullopt;
    }
    // Where the GPU writes slot `slot`'s readback: buffer() at offset(slot).
    GLuint buffer() const { return buffer_.get(); }
    std::size_t offset(std::size_t slot) const { return slot * slot_bytes_; }
    // The GPU commands writing the slot are issued: fences them.
    void submit(std::size_t slot, std::uint64_t frame);

    // The slots whose readback has finished (`all`: every one in flight, after glFinish), oldest
    // frame first, free again; their bytes stay valid until the slot is next written. Valid until
    // the next call.
    const std::vector<std::size_t>& finished(bool all);
    const std::uint8_t* data(std::size_t slot) const { return map_ + offset(slot); }
    std::uint64_t frame(std::size_t slot) const { return slots_[slot].frame; }
    std::size_t size() const { return slots_.size(); }

private:
    struct Slot {
        Fence fence;
        bool busy = false;
        std::uint64_t frame = 0;
    };
    Buffer buffer_;
    const std::uint8_t* map_ = nullptr;
    std::size_t slot_bytes_ = 0;
    std::vector<Slot> slots_;
    std::vector<std::size_t> finished_;
};

// The feedback target (RG32UI, width x height) read back through a ring; the newest finished
// readback is kept until polled, older ones are dropped.
class FeedbackReadback {
public:
    Status init(std::size_t slots, std::uint32_t width, std::uint32_t height);
    // A slot for this frame's readback, or nothing (every one in flight).
    std::optional<std::size_t> acquire();
    // Reads `framebuffer`'s colour into `slot` (in stream order, no wait).
    void read(std::size_t slot, GLuint framebuffer, std::uint64_t frame, float bias);
    // Keeps the newest finished readback if it is newer than the one kept. `all`: after glFinish.
    void collect(bool all);
    // The one kept, if any (swapped into `out`).
    bool take(FeedbackFrame& out);

private:
    ReadbackRing ring_;
    std::vector<float> bias_;  // per slot: the LoD bias its frame was rendered with
    std::uint32_t width_ = 0, height_ = 0;
    FeedbackFrame ready_;
    bool has_ready_ = false;
};

// The VT pass's fallback counters: a small SSBO the shader counts into, copied into a ring each
// frame, and the textured pixels from an occlusion query per slot.
class CounterReadback {
public:
    Status init(std::size_t slots);
    // Zeroes the counters for this frame and picks its slot (nothing: every one in flight).
    std::optional<std::size_t> begin_frame();
    GLuint counters() const { return counters_.get(); }  // the SSBO the VT pass counts into
    GLuint query(std::size_t slot) const { return queries_[slot].get(); }  // GL_SAMPLES_PASSED of the VT pass
    // Copies this frame's counters into `slot`; `textured`: the query of the slot ran.
    void read(std::size_t slot, std::uint64_t frame, bool textured);
    // Keeps the finished frames' counters (the newest kMaxUnpolled). `all`: after glFinish.
    void collect(bool all);
    // Appends the kept counters, oldest first, and forgets them. Returns how many.
    std::size_t take(std::vector<FrameCounters>& out);

private:

    static constexpr std::size_t kBytes = 16;  // 4 uints, by kind: unused, unbiased only, biased only, both (vt.frag)
    static constexpr std::size_t kMaxUnpolled = 1024;  // finished frames kept until taken
    ReadbackRing ring_;
    Buffer counters_;
    std::vector<Query> queries_;
    std::vector<bool> has_query_;  // per slot: the VT pass ran (a frame without a texture counts nothing)
    std::deque<FrameCounters> finished_;
};

}  // namespace tessera::client::gl::detail
