#include "page_fade.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace tessera::client::gl::detail {

Status PageFade::init(std::uint32_t columns, std::uint32_t rows, float fade_ms) {
    fade_s_ = double(fade_ms) / 1000.0;
    if (!enabled()) return Status();
    columns_ = std::max<std::uint32_t>(columns, 1);
    rows_ = rows;
    weights_.assign(std::size_t(columns_) * rows_, 255);
    fading_index_.assign(weights_.size(), 0);
    texture_ = make_texture(GL_TEXTURE_2D);
    glTextureStorage2D(texture_.get(), 1, GL_R8, GLsizei(columns_), GLsizei(std::max<std::uint32_t>(rows_, 1)));
    glTextureParameteri(texture_.get(), GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTextureParameteri(texture_.get(), GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    const std::uint8_t full = 255;
    glClearTexImage(texture_.get(), 0, GL_RED, GL_UNSIGNED_BYTE, &full);
    if (auto e = take_gl_errors("fade weights"); !e.empty())
        return Error{Errc::resource_exhausted, fmt::format("renderer: {}x{} fade weights: {}", columns_, rows_, e)};
    return Status();
}

void PageFade::arrived(SlotId slot) {
    if (!enabled() || std::size_t(slot) >= weights_.size()) return;
    std::erase(gone_, slot);  // a faded-out cell written before it was taken back: not gone any more
    if (const std::uint32_t i = fading_index_[slot]; i != 0) {
        fading_[i - 1] = {slot, -1, 0.0, false};  // overwritten while fading: the new page starts over
        return;
    }
    fading_.push_back({slot, -1, 0.0, false});
    fading_index_[slot] = std::uint32_t(fading_.size());
}

void PageFade::leaving(SlotId slot) {
    if (!enabled() || std::size_t(slot) >= weights_.size()) {
        gone_.push_back(slot);  // nothing to fade: gone at once
        return;
    }
    if (std::find(gone_.begin(), gone_.end(), slot) != gone_.end()) return;  // gone already
    start(slot, /*out=*/true);
}

void PageFade::kept(SlotId slot) {
    std::erase(gone_, slot);  // faded out (or gone at once), not yet taken: stays, from weight 0
    if (!enabled() || std::size_t(slot) >= weights_.size()) return;
    start(slot, /*out=*/false);
}

// From the next frame, `slot`'s weight moves from where it is (or, for an entry not drawn since
// it was set, from where that entry would have started: 0 for an arrival) towards 0 or 1.
void PageFade::start(SlotId slot, bool out) {
    Fading f{slot, -1, weights_[slot] / 255.0, out};
    if (const std::uint32_t i = fading_index_[slot]; i != 0) {
        if (fading_[i - 1].start < 0) f.from = fading_[i - 1].from;
        fading_[i - 1] = f;
        return;
    }
    if (!out && weights_[slot] == 255) return;  // at full weight: nothing to fade in
    fading_.push_back(f);
    fading_index_[slot] = std::uint32_t(fading_.size());
}

void PageFade::take_gone(std::vector<SlotId>& out) {
    out.insert(out.end(), gone_.begin(), gone_.end());
    gone_.clear();
}

float PageFade::frame(double now, float requested_bias) {
    if (!enabled()) return requested_bias;
    // The bias: at most one level per fade time, from the first frame's.
    const double dt = have_bias_ ? std::max(now - last_, 0.0) : 0.0;
    if (!have_bias_) bias_ = requested_bias;
    const float step = float(dt / fade_s_);
    bias_ = requested_bias > bias_ ? std::min(requested_bias, bias_ + step) : std::max(requested_bias, bias_ - step);
    have_bias_ = true;
    last_ = now;

    if (fading_.empty()) return bias_;
    std::uint32_t first_row = rows_, last_row = 0;
    for (std::size_t i = 0; i < fading_.size();) {
        Fading& f = fading_[i];
        if (f.start < 0) f.start = now;
        const double moved = (now - f.start) / fade_s_;
        const double w = std::clamp(f.out ? f.from - moved : f.from + moved, 0.0, 1.0);
        const auto weight = std::uint8_t(std::lround(w * 255.0));
        if (weights_[f.slot] != weight) {
            weights_[f.slot] = weight;
            first_row = std::min(first_row, f.slot / columns_);
            last_row = std::max(last_row, f.slot / columns_);
        }
        if (weight == (f.out ? 0 : 255)) {  // faded in or out: swap with the last
            if (f.out) gone_.push_back(f.slot);
            fading_index_[f.slot] = 0;
            if (i + 1 != fading_.size()) {
                f = fading_.back();
                fading_index_[f.slot] = std::uint32_t(i + 1);
            }
            fading_.pop_back();
        } else {
            ++i;
        }
    }
    if (first_row <= last_row) {
        // From client memory (a few rows of one byte per cell): no staging needed.
        glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);
        glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
        glPixelStorei(GL_UNPACK_ROW_LENGTH, 0);
        glTextureSubImage2D(texture_.get(), 0, 0, GLint(first_row), GLsizei(columns_), GLsizei(last_row - first_row + 1), GL_RED,
                            GL_UNSIGNED_BYTE, weights_.data() + std::size_t(first_row) * columns_);
        glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
    }
    return bias_;
}

}  // namespace tessera::client::gl::detail
