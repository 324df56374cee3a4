#include "readback_ring.hpp"

#include <algorithm>
#include <utility>

namespace tessera::client::gl::detail {

ReadbackRing::~ReadbackRing() {
    if (map_) glUnmapNamedBuffer(buffer_.get());
}

Status ReadbackRing::init(std::size_t slots, std::size_t slot_bytes, const std::string& what) {
    const GLbitfield flags = GL_MAP_READ_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
    const auto bytes = GLsizeiptr(slots * slot_bytes);
    slot_bytes_ = slot_bytes;
    slots_.resize(slots);
    buffer_ = make_buffer();
    glNamedBufferStorage(buffer_.get(), bytes, nullptr, flags);
    map_ = static_cast<const std::uint8_t*>(glMapNamedBufferRange(buffer_.get(), 0, bytes, flags));
    if (!map_) return Error{Errc::resource_exhausted, "renderer: cannot map the " + what + " readback ring"};
    return Status();
}

void ReadbackRing::submit(std::size_t slot, std::uint64_t frame) {
    Slot& s = slots_[slot];
    s.fence.insert();
    s.busy = true;
    s.frame = frame;
}

const std::vector<std::size_t>& ReadbackRing::finished(bool all) {
    finished_.clear();
    for (std::size_t i = 0; i < slots_.size(); ++i) {
        Slot& s = slots_[i];
        if (!s.busy || !(all || s.fence.poll())) continue;
        s.busy = false;
        s.fence.reset();
        finished_.push_back(i);
    }
    std::sort(finished_.begin(), finished_.end(),
              [&](std::size_t a, std::size_t b) { return slots_[a].frame < slots_[b].frame; });
    return finished_;
}

// ---- Feedback ---------------------------------------------------------------------------------

Status FeedbackReadback::init(std::size_t slots, std::uint32_t width, std::uint32_t height) {
    width_ = width;
    height_ = height;
    bias_.assign(slots, 0.0f);
    return ring_.init(slots, std::size_t(width) * height * 8, "feedback");
}

std::optional<std::size_t> FeedbackReadback::acquire() {
    return ring_.acquire([&] { collect(false); });
}

void FeedbackReadback::read(std::size_t slot, GLuint framebuffer, std::uint64_t frame, float bias) {
    glBindFramebuffer(GL_READ_FRAMEBUFFER, framebuffer);
    glBindBuffer(GL_PIXEL_PACK_BUFFER, ring_.buffer());
    glPixelStorei(GL_PACK_ALIGNMENT, 4);
    glReadPixels(0, 0, GLsizei(width_), GLsizei(height_), GL_RG_INTEGER, GL_UNSIGNED_INT,
                 reinterpret_cast<void*>(ring_.offset(slot)));
    glBindBuffer(GL_PIXEL_PACK_BUFFER, 0);
    ring_.submit(slot, frame);
    bias_[slot] = bias;
}

void FeedbackReadback::collect(bool all) {
    const auto& done = ring_.finished(all);
    if (done.empty()) return;
    const std::size_t newest = done.back();
    if (has_ready_ && ready_.frame >= ring_.frame(newest)) return;
    ready_.frame = ring_.frame(newest);
    ready_.bias = bias_[newest];
    ready_.width = width_;
    ready_.height = height_;
    ready_.ids.resize(std::size_t(width_) * height_);
    // GL's row 0 is the bottom; FeedbackFrame's row 0 is the top. RG32UI: low word first.
    const auto* texels = reinterpret_cast<const std::uint32_t*>(ring_.data(newest));
    for (std::uint32_t y = 0; y < height_; ++y) {
        const std::uint32_t* row = texels + std::size_t(height_ - 1 - y) * width_ * 2;
        FeedbackId* dst = ready_.ids.data() + std::size_t(y) * width_;
        for (std::uint32_t x = 0; x < width_; ++x) dst[x] = FeedbackId(row[2 * x]) | (FeedbackId(row[2 * x + 1]) << 32);
    }
    has_ready_ = true;
}

bool FeedbackReadback::take(FeedbackFrame& out) {
    if (!has_ready_) return false;
    std::swap(out, ready_);
    has_ready_ = false;
    return true;
}

// ---- Counters ---------------------------------------------------------------------------------

Status CounterReadback::init(std::size_t slots) {
    queries_.clear();
    for (std::size_t i = 0; i < slots; ++i) queries_.push_back(make_query(GL_SAMPLES_PASSED));
    has_query_.assign(slots, false);
    counters_ = make_buffer();
    glNamedBufferStorage(counters_.get(), kBytes, nullptr, GL_DYNAMIC_STORAGE_BIT);
    return ring_.init(slots, kBytes, "counter");
}

std::optional<std::size_t> CounterReadback::begin_frame() {
    const std::uint32_t zero = 0;
    glClearNamedBufferData(counters_.get(), GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
    return ring_.acquire([&] { collect(false); });
}

void CounterReadback::read(std::size_t slot, std::uint64_t frame, bool textured) {
    glCopyNamedBufferSubData(counters_.get(), ring_.buffer(), 0, GLintptr(ring_.offset(slot)), kBytes);
    ring_.submit(slot, frame);
    has_query_[slot] = textured;
}

void CounterReadback::collect(bool all) {
    for (const std::size_t i : ring_.finished(all)) {
        const auto* v = reinterpret_cast<const std::uint32_t*>(ring_.data(i));
        // The query ended before the fence, so its result is there once the fence is.
        GLuint textured = 0;
        if (has_query_[i]) glGetQueryObjectuiv(queries_[i].get(), GL_QUERY_RESULT, &textured);
        finished_.push_back(FrameCounters{ring_.frame(i), textured, v[1] + v[3], v[2] + v[3]});
    }
    while (finished_.size() > kMaxUnpolled) finished_.pop_front();
}

std::size_t CounterReadback::take(std::vector<FrameCounters>& out) {
    const std::size_t n = finished_.size();
    out.insert(out.end(), finished_.begin(), finished_.end());
    finished_.clear();
    return n;
}

}  // namespace tessera::client::gl::detail
