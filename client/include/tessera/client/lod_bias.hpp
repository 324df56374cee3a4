#pragma once
// LodBiasController: oversubscription control (docs/client.md, "One frame, end to end", step 8).
// Once a frame, the runtime tells it how many pages the (biased) feedback wanted against the pool,
// and it returns the LoD bias the next frames' feedback (and shader) should use.
//
// The physics: raising the bias by d levels divides the pages a view wants by about 4^d (two
// axes), so pressure p = pages_wanted / pool_slots falls by about 4^d too. The rule:
//   - Rise when p > high_water (or the pool thrashes, or, if enabled, the backlog is too long) for
//     `rise_frames` consecutive frames. A pressure rise takes as many steps (up to
//     max_change_steps) as the 4^d model says bring p under high_water; the others take one.
//   - Fall only when the pressure predicted after a one-step fall, p * G, stays below low_water
//     for `fall_frames` consecutive frames; then fall as many steps (up to max_change_steps) as
//     keep the prediction below low_water. G is the growth of the pressure per step down: 4^step
//     by the model, or more where this view has shown more (below). Since low_water <
//     high_water, a fall never lands in the rise zone: the dead band absorbs noise.
//   - After any change, feedback made before it is ignored: frames whose feedback_bias is not
//     the current bias, and in any case the next `settle_frames` frames (for callers that do not
//     tag the feedback; keep it at least the readback latency). The first frame after that
//     measures the change.
//   - Learned growth, per bias value b (in steps): a rise to b sets G[b] from what it achieved,
//     (max(p before, high_water) / p after)^(1/steps), at least 4^step; a fall through b raises
//     G[b] to the growth it observed per step, if larger. So after a rise to b, falling back
//     needs the pressure to drop about 20% (1 - low_water/high_water) below where the rise left
//     it, which a static view never does: a flat head-on view that crosses a whole level at once
//     (growth 4, not 4^step), or a thrashing pool whose page count looks fine, flips at most
//     once, then stays put. G is a ratio, so a pool that grows (pressure drops) still brings the
//     bias down, to 0 eventually.
//   - The bias is held as a whole number of steps in [0, max_bias]: exact and deterministic.
#include <cstdint>
#include <limits>
#include <vector>

namespace tessera::client {

struct LodBiasConfig {
    float max_bias = 4.0f;   // levels; the bias is clamped to [0, max_bias]
    float step = 0.25f;      // levels per change (> 0); max_bias is rounded down to a multiple
    float high_water = 0.95f;  // rise above this pressure (pages wanted / pool slots)
    float low_water = 0.75f;   // fall only if the predicted pressure after the fall is below this
    unsigned rise_frames = 2;  // consecutive frames of pressure before a rise
    unsigned fall_frames = 30;  // consecutive frames of low predicted pressure before a fall
    unsigned settle_frames = 4;  // frames ignored after a change (feedback readback latency)
    // Thrash: evictions of pages the feedback still wants, per frame, as a fraction of pool_slots.
    // Above it counts as pressure (the pool cannot hold the working set, whatever the count says).
    // <= 0: off.
    float thrash_high = 0.02f;
    // Backlog (optional, off by default): pending / (pages delivered per busy frame, averaged) in
    // frames. Above backlog_high_frames counts as pressure; a fall also needs the backlog below
    // half of it. Off by default because the request priority already fetches coarse pages first,
    // and a bias held up by a slow network would delay full detail on a view that fits the pool.
    // <= 0: off.
    float backlog_high_frames = 0.0f;
    unsigned max_change_steps = 4;  // most steps one rise or fall may take (>= 1)
};

struct LodBiasInputs {
    // Unique pages the (biased) feedback asked for, ancestors included; pages that live in pinned
    // slots should be left out, as pool_slots leaves the pinned slots out.
    std::uint32_t pages_wanted = 0;
    std::uint32_t pool_slots = 0;  // physical slots, excluding pinned ones
    std::uint32_t pending = 0;     // requested, not yet mapped
    std::uint32_t delivered_last_frame = 0;  // pages mapped last frame
    std::uint32_t evicted_last_frame = 0;    // all evictions last frame (churn; reported only)
    std::uint32_t evicted_wanted_last_frame = 0;  // evictions of pages the feedback still wanted
    // The bias the feedback pass behind pages_wanted used (the readback lags a few frames). A
    // frame whose feedback predates the current bias is ignored. NaN: not known, settle_frames
    // alone decides.
    float feedback_bias = std::numeric_limits<float>::quiet_NaN();
};

// Why the last change happened (diagnostics and stats).
enum class LodBiasReason : std::uint8_t { none, pressure, thrash, backlog, fall };

class LodBiasController {
public:
    explicit LodBiasController(const LodBiasConfig& config = {});

    // Feed one frame's feedback summary; returns the bias to use from now on.
    float update(const LodBiasInputs& in);

    float bias() const { return static_cast<float>(steps_) * step_; }
    float pressure() const { return pressure_; }  // of the last update (pages_wanted / pool_slots)
    std::uint64_t changes() const { return changes_; }  // bias changes since construction/reset
    LodBiasReason last_reason() const { return last_reason_; }
    const LodBiasConfig& config() const { return config_; }

    // Forget everything (camera cut, new scene, new pool): bias back to 0.
    void reset();

private:
    void change(int delta, LodBiasReason why, float before);
    void measure(float after);

    LodBiasConfig config_;
    float step_ = 0.25f;
    int max_steps_ = 0;
    int steps_ = 0;
    float pressure_ = 0.0f;
    unsigned settle_left_ = 0;
    unsigned high_run_ = 0;  // consecutive frames wanting a rise
    unsigned low_run_ = 0;   // consecutive frames allowing a fall
    std::uint64_t changes_ = 0;
    LodBiasReason last_reason_ = LodBiasReason::none;
    double run_sum_ = 0.0;   // pressure summed over the current run (high or low)
    // Learned growth per step down, indexed by the bias (in steps) it falls from.
    std::vector<float> growth_;
    float model_growth_ = 1.0f;  // 4^step
    float max_growth_ = 1.0f;    // cap on learned growth: 4^ceil(step), plus noise room
    // The change being measured once the feedback has settled.
    bool measuring_ = false;
    int measure_from_ = 0;       // bias (steps) before the change
    float measure_before_ = 0.0f;  // effective pressure before the change
    bool measure_rise_ = false;
    // Backlog: pages delivered per busy frame (exponential average; 0 until measured).
    float delivery_rate_ = 0.0f;
};

}  // namespace tessera::client
