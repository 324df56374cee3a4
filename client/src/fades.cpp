#include "fades.hpp"

#include <algorithm>
#include <cmath>

namespace tessera::client {

SlotFades::SlotFades(std::uint32_t slots, double fade_s)
    : fade_s_(fade_s), weights_(slots, 255), fading_index_(slots, 0), changed_flag_(slots, 0) {}

void SlotFades::set(SlotId slot, std::uint8_t w) {
    if (weights_[slot] == w) return;
    weights_[slot] = w;
    if (!changed_flag_[slot]) {
        changed_flag_[slot] = 1;
        changed_.push_back(slot);
    }
}

void SlotFades::stop(SlotId slot) {
    const std::uint32_t i = fading_index_[slot];
    if (i == 0) return;
    fading_index_[slot] = 0;
    if (i != fading_.size()) {
        fading_[i - 1] = fading_.back();
        fading_index_[fading_[i - 1].slot] = i;
    }
    fading_.pop_back();
}

void SlotFades::start(SlotId slot, double from, bool out) {
    const Fading f{slot, now_, from, out};
    if (const std::uint32_t i = fading_index_[slot]; i != 0) {
        fading_[i - 1] = f;
        return;
    }
    fading_.push_back(f);
    fading_index_[slot] = std::uint32_t(fading_.size());
}

bool SlotFades::falling(SlotId slot) const {
    const std::uint32_t i = fading_index_[slot];
    return i != 0 && fading_[i - 1].out;
}

void SlotFades::arrive(SlotId slot) {
    if (!enabled()) return;
    set(slot, 0);
    start(slot, 0.0, /*out=*/false);
}

void SlotFades::leave(SlotId slot) {
    if (!enabled()) return;
    start(slot, weights_[slot] / 255.0, /*out=*/true);
}

void SlotFades::keep(SlotId slot) {
    if (!enabled()) return;
    if (weights_[slot] == 255) {
        stop(slot);
        return;
    }
    start(slot, weights_[slot] / 255.0, /*out=*/false);
}

void SlotFades::release(SlotId slot) {
    if (!enabled()) return;
    stop(slot);
    set(slot, 255);
}

void SlotFades::advance(double now, std::vector<SlotId>& gone) {
    now_ = std::max(now, now_);
    if (!enabled()) return;
    for (std::size_t i = 0; i < fading_.size();) {
        const Fading f = fading_[i];
        const double moved = (now_ - f.start) / fade_s_;
        const double w = std::clamp(f.out ? f.from - moved : f.from + moved, 0.0, 1.0);
        const auto weight = std::uint8_t(std::lround(w * 255.0));
        set(f.slot, weight);
        if (weight == (f.out ? 0 : 255)) {
            if (f.out) gone.push_back(f.slot);
            stop(f.slot);  // the last moves into place i: look at it next
        } else {
            ++i;
        }
    }
}

void SlotFades::take_changes(std::vector<SlotWeight>& out) {
    for (const SlotId s : changed_) {
        out.push_back(SlotWeight{s, weights_[s]});
        changed_flag_[s] = 0;
    }
    changed_.clear();
}

float BiasGlide::advance(double now, float requested) {
    if (!(fade_s_ > 0) || !started_) {
        bias_ = requested;
        started_ = true;
        last_ = now;
        return bias_;
    }
    const float step = float(std::max(now - last_, 0.0) / fade_s_);
    last_ = std::max(now, last_);
    bias_ = requested > bias_ ? std::min(requested, bias_ + step) : std::max(requested, bias_ - step);
    return bias_;
}

}  // namespace tessera::client
