#include "tessera/client/lod_bias.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace tessera::client {

namespace {

LodBiasConfig sanitized(LodBiasConfig c) {
    if (!(c.step > 0.0f)) c.step = 0.25f;
    c.step = std::clamp(c.step, 1.0f / 64.0f, 4.0f);
    if (!(c.max_bias >= 0.0f)) c.max_bias = 0.0f;
    c.max_bias = std::min(c.max_bias, 16.0f);
    if (!(c.high_water > 0.0f)) c.high_water = 0.95f;
    if (!(c.low_water > 0.0f)) c.low_water = 0.75f;
    c.low_water = std::min(c.low_water, c.high_water);
    c.rise_frames = std::max(c.rise_frames, 1u);
    c.fall_frames = std::max(c.fall_frames, 1u);
    c.max_change_steps = std::max(c.max_change_steps, 1u);
    return c;
}

}  // namespace

LodBiasController::LodBiasController(const LodBiasConfig& config) : config_(sanitized(config)) {
    step_ = config_.step;
    max_steps_ = static_cast<int>(std::floor(config_.max_bias / step_ + 1e-4f));
    model_growth_ = std::pow(4.0f, step_);
    // One step of at most a level moves each pixel at most one level finer: at most 4x the pages.
    max_growth_ = std::pow(4.0f, std::ceil(step_)) * 1.25f;
    reset();
}

void LodBiasController::reset() {
    steps_ = 0;
    pressure_ = 0.0f;
    settle_left_ = 0;
    high_run_ = 0;
    low_run_ = 0;
    run_sum_ = 0.0;
    changes_ = 0;
    last_reason_ = LodBiasReason::none;
    growth_.assign(static_cast<std::size_t>(max_steps_) + 1, model_growth_);
    measuring_ = false;
    delivery_rate_ = 0.0f;
}

void LodBiasController::change(int delta, LodBiasReason why, float before) {
    measure_from_ = steps_;
    measure_before_ = before;
    measure_rise_ = delta > 0;
    measuring_ = true;
    steps_ = std::clamp(steps_ + delta, 0, max_steps_);
    ++changes_;
    last_reason_ = why;
    settle_left_ = config_.settle_frames;
    high_run_ = 0;
    low_run_ = 0;
    run_sum_ = 0.0;
}

void LodBiasController::measure(float after) {
    measuring_ = false;
    const float before = measure_before_;
    if (!(before > 0.0f) || !(after > 0.0f) || !std::isfinite(before) || !std::isfinite(after)) return;
    if (measure_rise_) {
        // A rise from measure_from_ to steps_: the new bias's growth is what this rise achieved
        // per step (replacing older evidence: this is the view as it is now).
        const int n = steps_ - measure_from_;
        if (n <= 0) return;
        float g = std::pow(before / after, 1.0f / static_cast<float>(n));
        g = std::clamp(g, model_growth_, max_growth_);
        for (int b = measure_from_ + 1; b <= steps_; ++b) growth_[static_cast<std::size_t>(b)] = g;
    } else {
        // A fall from measure_from_: if the pressure grew more than predicted, remember it.
        const int n = measure_from_ - steps_;
        if (n <= 0) return;
        const float g = std::min(std::pow(after / before, 1.0f / static_cast<float>(n)), max_growth_);
        for (int b = steps_ + 1; b <= measure_from_; ++b) {
            float& slot = growth_[static_cast<std::size_t>(b)];
            slot = std::max(slot, g);
        }
    }
}

float LodBiasController::update(const LodBiasInputs& in) {
    float p = 0.0f;
    if (in.pool_slots > 0)
        p = static_cast<float>(in.pages_wanted) / static_cast<float>(in.pool_slots);
    else if (in.pages_wanted > 0)
        p = std::numeric_limits<float>::infinity();
    pressure_ = p;

    // Pipeline throughput: pages delivered per busy frame (exponential average, 1/8).
    if (in.pending > 0 || in.delivered_last_frame > 0) {
        const float d = static_cast<float>(in.delivered_last_frame);
        if (delivery_rate_ > 0.0f)
            delivery_rate_ += (d - delivery_rate_) * 0.125f;
        else if (d > 0.0f)
            delivery_rate_ = d;
    }

    if (settle_left_ > 0) {
        --settle_left_;
        return bias();
    }
    if (!std::isnan(in.feedback_bias) && std::fabs(in.feedback_bias - bias()) > 0.5f * step_)
        return bias();  // stale feedback: made before the last change
    if (measuring_) measure(p);

    const bool thrash = config_.thrash_high > 0.0f && in.pool_slots > 0 &&
                        static_cast<float>(in.evicted_wanted_last_frame) >
                            config_.thrash_high * static_cast<float>(in.pool_slots);
    bool backlog_high = false;
    bool backlog_low = true;
    if (config_.backlog_high_frames > 0.0f && delivery_rate_ > 0.0f) {
        const float frames = static_cast<float>(in.pending) / delivery_rate_;
        backlog_high = frames > config_.backlog_high_frames;
        backlog_low = frames < 0.5f * config_.backlog_high_frames;
    }
    const bool over = p > config_.high_water;

    if (over || thrash || backlog_high) {
        low_run_ = 0;
        if (high_run_ == 0) run_sum_ = 0.0;
        ++high_run_;
        run_sum_ += std::isfinite(p) ? p : 0.0;
        if (high_run_ >= config_.rise_frames && steps_ >= max_steps_) {
            high_run_ = 0;  // clamped: nothing to do, start counting afresh
        } else if (high_run_ >= config_.rise_frames) {
            const float mean = static_cast<float>(run_sum_ / high_run_);
            int n = 1;
            LodBiasReason why = LodBiasReason::backlog;
            float before = mean;
            if (over) {
                why = LodBiasReason::pressure;
                // Steps that bring the pressure under high_water by the 4^d model.
                if (std::isfinite(p)) {
                    const double levels = std::log(static_cast<double>(p) / config_.high_water) / std::log(4.0);
                    n = static_cast<int>(std::ceil(levels / step_ - 1e-6));
                } else {
                    n = static_cast<int>(config_.max_change_steps);
                }
                n = std::clamp(n, 1, static_cast<int>(config_.max_change_steps));
            } else if (thrash) {
                why = LodBiasReason::thrash;
            }
            // A pressure or thrash rise says the lower bias held too much: count it as at least
            // high_water, so falling back needs a real drop. A backlog rise says nothing about
            // the pool: learn only the plain ratio.
            if (why != LodBiasReason::backlog) before = std::max(before, config_.high_water);
            change(n, why, before);
        }
        return bias();
    }

    high_run_ = 0;
    const float g = growth_[static_cast<std::size_t>(steps_)];
    const bool low = steps_ > 0 && p * g < config_.low_water && backlog_low &&
                     in.evicted_wanted_last_frame == 0;
    if (!low) {
        low_run_ = 0;
        return bias();
    }
    if (low_run_ == 0) run_sum_ = 0.0;
    ++low_run_;
    run_sum_ += p;
    if (low_run_ >= config_.fall_frames) {
        // As many steps as keep the predicted pressure (the run's mean) below low_water.
        const float mean = static_cast<float>(run_sum_ / low_run_);
        float predicted = mean * g;
        int n = 1;
        while (n < static_cast<int>(config_.max_change_steps) && steps_ - n > 0) {
            const float next = predicted * growth_[static_cast<std::size_t>(steps_ - n)];
            if (!(next < config_.low_water)) break;
            predicted = next;
            ++n;
        }
        change(-n, LodBiasReason::fall, mean);
    }
    return bias();
}

}  // namespace tessera::client
