// LodBiasController: unit behaviour, then an analytic simulation over a table of scenarios. The
// simulated view wants W0 / 4^bias pages (the 2D page count scales by 4 per level), or, for a
// flat head-on view, a count that jumps by 4 only where the biased level crosses a whole level.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <deque>
#include <ostream>
#include <stdexcept>
#include <string>
#include <vector>

#include "tessera/client/lod_bias.hpp"
#include "tessera/client/stats.hpp"

namespace tc = tessera::client;

namespace {

tc::LodBiasInputs inputs(std::uint32_t wanted, std::uint32_t pool) {
    tc::LodBiasInputs in;
    in.pages_wanted = wanted;
    in.pool_slots = pool;
    return in;
}

// --- unit behaviour ---

TEST(LodBias, StaysAtZeroWhenThePoolFits) {
    tc::LodBiasController c;
    for (int i = 0; i < 200; ++i) EXPECT_EQ(c.update(inputs(900, 1000)), 0.0f);
    EXPECT_EQ(c.changes(), 0u);
    EXPECT_FLOAT_EQ(c.pressure(), 0.9f);
}

TEST(LodBias, RisesOnlyAfterRiseFramesConsecutiveFrames) {
    tc::LodBiasConfig cfg;
    cfg.rise_frames = 3;
    tc::LodBiasController c(cfg);
    EXPECT_EQ(c.update(inputs(1200, 1000)), 0.0f);
    EXPECT_EQ(c.update(inputs(1200, 1000)), 0.0f);
    EXPECT_EQ(c.update(inputs(900, 1000)), 0.0f);  // the run breaks
    EXPECT_EQ(c.update(inputs(1200, 1000)), 0.0f);
    EXPECT_EQ(c.update(inputs(1200, 1000)), 0.0f);
    EXPECT_EQ(c.update(inputs(1200, 1000)), 0.25f);
    EXPECT_EQ(c.last_reason(), tc::LodBiasReason::pressure);
}

TEST(LodBias, PressureRiseTakesTheStepsTheModelNeeds) {
    tc::LodBiasController c;  // step 0.25, max_change_steps 4
    c.update(inputs(3000, 1000));
    // p = 3: log4(3 / 0.95) = 0.83 levels -> 4 steps (1.0), capped at max_change_steps = 4.
    EXPECT_EQ(c.update(inputs(3000, 1000)), 1.0f);
    tc::LodBiasController d;
    d.update(inputs(1500, 1000));
    EXPECT_EQ(d.update(inputs(1500, 1000)), 0.5f);  // log4(1.58) = 0.33 -> 2 steps
}

TEST(LodBias, SettleFramesIgnoreStaleFeedback) {
    tc::LodBiasConfig cfg;
    cfg.settle_frames = 5;
    tc::LodBiasController c(cfg);
    c.update(inputs(1200, 1000));
    ASSERT_EQ(c.update(inputs(1200, 1000)), 0.25f);
    // Still the old count (the readback lags): no second rise while settling.
    for (int i = 0; i < 5; ++i) EXPECT_EQ(c.update(inputs(1200, 1000)), 0.25f);
    c.update(inputs(1200, 1000));
    EXPECT_EQ(c.update(inputs(1200, 1000)), 0.5f);
}

TEST(LodBias, ClampedToMaxAndZero) {
    tc::LodBiasConfig cfg;
    cfg.max_bias = 1.0f;
    cfg.settle_frames = 0;
    tc::LodBiasController c(cfg);
    for (int i = 0; i < 100; ++i) c.update(inputs(1000000, 1000));
    EXPECT_EQ(c.bias(), 1.0f);
    EXPECT_EQ(c.changes(), 1u);  // one rise of 4 steps, then clamped
    for (int i = 0; i < 1000; ++i) c.update(inputs(10, 1000));
    EXPECT_EQ(c.bias(), 0.0f);
    EXPECT_EQ(c.changes(), 2u);  // and one fall of 4 steps (0.01 * 1.41^4 is still < low_water)
}

TEST(LodBias, FallsOnlyAfterFallFramesOfLowPredictedPressure) {
    tc::LodBiasConfig cfg;
    cfg.fall_frames = 10;
    cfg.settle_frames = 0;
    tc::LodBiasController c(cfg);
    c.update(inputs(1200, 1000));
    ASSERT_EQ(c.update(inputs(1200, 1000)), 0.25f);
    c.update(inputs(1200 / std::sqrt(2.0), 1000));  // measures the rise: growth 1.41
    // p = 0.5: predicted 0.5 * 1.41 = 0.71 < 0.75. Nine frames, a break, then ten.
    for (int i = 0; i < 9; ++i) EXPECT_EQ(c.update(inputs(500, 1000)), 0.25f);
    EXPECT_EQ(c.update(inputs(540, 1000)), 0.25f);  // 0.54 * 1.41 = 0.76: not low
    for (int i = 0; i < 9; ++i) EXPECT_EQ(c.update(inputs(500, 1000)), 0.25f);
    EXPECT_EQ(c.update(inputs(500, 1000)), 0.0f);
    EXPECT_EQ(c.last_reason(), tc::LodBiasReason::fall);
}

TEST(LodBias, ThrashCountsAsPressure) {
    tc::LodBiasController c;
    auto in = inputs(800, 1000);  // the count fits...
    in.evicted_wanted_last_frame = 50;  // ...but wanted pages are being evicted (5% > 2%)
    c.update(in);
    EXPECT_EQ(c.update(in), 0.25f);
    EXPECT_EQ(c.last_reason(), tc::LodBiasReason::thrash);
}

TEST(LodBias, EmptyPoolIsFullPressure) {
    tc::LodBiasController c;
    c.update(inputs(10, 0));
    EXPECT_EQ(c.update(inputs(10, 0)), 1.0f);
    EXPECT_TRUE(std::isinf(c.pressure()));
}

TEST(LodBias, BacklogIsOptionalPressure) {
    tc::LodBiasConfig cfg;
    cfg.backlog_high_frames = 20;
    tc::LodBiasController c(cfg);
    tc::LodBiasController off;  // default: backlog ignored
    tc::LodBiasInputs in = inputs(500, 1000);
    in.pending = 400;
    in.delivered_last_frame = 10;  // 40 frames of work at 10 a frame
    c.update(in);
    off.update(in);
    EXPECT_EQ(c.update(in), 0.25f);
    EXPECT_EQ(c.last_reason(), tc::LodBiasReason::backlog);
    EXPECT_EQ(off.update(in), 0.0f);
    // Drained: with the pool far from full, it comes back.
    in.pending = 0;
    in.delivered_last_frame = 0;
    in.pages_wanted = 300;
    for (int i = 0; i < 200; ++i) c.update(in);
    EXPECT_EQ(c.bias(), 0.0f);
}

TEST(LodBias, ResetForgetsEverything) {
    tc::LodBiasController c;
    for (int i = 0; i < 20; ++i) c.update(inputs(5000, 1000));
    ASSERT_GT(c.bias(), 0.0f);
    c.reset();
    EXPECT_EQ(c.bias(), 0.0f);
    EXPECT_EQ(c.changes(), 0u);
    EXPECT_EQ(c.update(inputs(100, 1000)), 0.0f);
}

TEST(LodBias, BadConfigIsSanitized) {
    tc::LodBiasConfig cfg;
    cfg.step = -1.0f;
    cfg.max_bias = std::nanf("");
    cfg.low_water = 2.0f;  // above high_water: pulled down to it
    cfg.rise_frames = 0;
    tc::LodBiasController c(cfg);
    EXPECT_EQ(c.config().max_bias, 0.0f);
    EXPECT_GT(c.config().step, 0.0f);
    EXPECT_LE(c.config().low_water, c.config().high_water);
    for (int i = 0; i < 10; ++i) EXPECT_EQ(c.update(inputs(5000, 1000)), 0.0f);
}

// --- simulation ---

// Deterministic noise: splitmix64, uniform in [-1, 1].
struct Noise {
    std::uint64_t state;
    double next() {
        std::uint64_t z = (state += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        z ^= z >> 31;
        return static_cast<double>(z >> 11) / static_cast<double>(1ull << 52) - 1.0;
    }
};

struct Scenario {
    std::string name;
    double w0;              // pages the view wants at bias 0
    double pool;            // pool slots
    double pool_later = 0;  // > 0: the pool becomes this at frame `change_at`
    double noise = 0.0;     // relative, uniform +-noise on the wanted count
    unsigned lag = 0;       // feedback latency in frames (the count reflects the bias `lag` frames ago)
    bool tagged = false;    // the inputs say which bias the feedback used (LodBiasInputs::feedback_bias)
    double flat_lod = -1;   // >= 0: a flat head-on view at this fractional LoD (the count jumps by 4)
    double working_set = 1.0;  // the pages actually needed are this times the count (thrash when > pool)
    float step = 0.25f;
    // Expectations.
    float expect_bias = -1;  // final bias, if exact (< 0: not checked)
    unsigned max_direction_changes = 0;
};

void PrintTo(const Scenario& s, std::ostream* os) { *os << s.name; }

struct SimResult {
    std::vector<float> bias;     // per frame, after the update
    std::vector<double> churn;   // per frame: wanted pages the pool could not hold
    std::vector<double> model_p;  // per frame: noise-free pressure at the current bias
    std::uint64_t last_change_frame = 0;
    tc::StatsSummary summary;
};

double wanted_at(const Scenario& s, double bias) {
    if (s.flat_lod >= 0) return s.w0 / std::pow(4.0, std::floor(s.flat_lod + bias) - std::floor(s.flat_lod));
    return s.w0 / std::pow(4.0, bias);
}

constexpr unsigned kFrames = 1500;
constexpr unsigned kChangeAt = 500;

SimResult simulate(const Scenario& s) {
    tc::LodBiasConfig cfg;
    cfg.step = s.step;
    tc::LodBiasController c(cfg);
    Noise noise{0x1234 + static_cast<std::uint64_t>(s.w0)};
    std::deque<float> bias_seen(s.lag + 1, 0.0f);  // bias_seen.front(): the bias the feedback used
    SimResult r;
    double thrash_last = 0;
    for (unsigned f = 0; f < kFrames; ++f) {
        const double pool = (s.pool_later > 0 && f >= kChangeAt) ? s.pool_later : s.pool;
        const double exact = wanted_at(s, bias_seen.front());
        const double noisy = exact * (1.0 + s.noise * noise.next());
        tc::LodBiasInputs in;
        in.pages_wanted = static_cast<std::uint32_t>(std::lround(noisy));
        in.pool_slots = static_cast<std::uint32_t>(pool);
        in.evicted_wanted_last_frame = static_cast<std::uint32_t>(std::lround(thrash_last));
        in.evicted_last_frame = in.evicted_wanted_last_frame;
        if (s.tagged) in.feedback_bias = bias_seen.front();
        const float before = c.bias();
        const float b = c.update(in);
        if (b != before) r.last_change_frame = f;
        bias_seen.push_back(b);
        bias_seen.pop_front();
        // The pool cannot hold what the view really needs beyond its size: that many wanted pages
        // are evicted and fetched again each frame (bounded by a delivery of 100 a frame).
        const double need = noisy * s.working_set;
        thrash_last = std::min(std::max(0.0, need - pool), 100.0);
        r.bias.push_back(b);
        r.churn.push_back(std::max(0.0, need - pool));
        r.model_p.push_back(wanted_at(s, b) / pool);
        tc::FrameStats fs;
        fs.frame = f;
        fs.pages_wanted = in.pages_wanted;
        fs.pages_evicted = static_cast<std::uint32_t>(thrash_last);
        fs.lod_bias = b;
        r.summary.add_frame(fs);
    }
    return r;
}

unsigned direction_changes(const std::vector<float>& bias) {
    unsigned n = 0;
    int last_dir = 0;
    for (std::size_t i = 1; i < bias.size(); ++i) {
        const int dir = bias[i] > bias[i - 1] ? 1 : bias[i] < bias[i - 1] ? -1 : 0;
        if (dir == 0) continue;
        if (last_dir != 0 && dir != last_dir) ++n;
        last_dir = dir;
    }
    return n;
}

const Scenario kScenarios[] = {
    // name, w0, pool, pool_later, noise, lag, tagged, flat_lod, working_set, step, expect_bias, max_dir
    {"fits", 800, 1000, 0, 0, 0, false, -1, 1, 0.25f, 0.0f, 0},
    {"fits_noisy", 850, 1000, 0, 0.05, 2, false, -1, 1, 0.25f, 0.0f, 0},
    {"slightly_over", 1200, 1000, 0, 0, 0, false, -1, 1, 0.25f, 0.25f, 0},
    {"much_over", 20000, 1000, 0, 0, 0, false, -1, 1, 0.25f, 2.25f, 0},
    {"much_over_lag3", 20000, 1000, 0, 0, 3, false, -1, 1, 0.25f, 2.25f, 0},
    {"much_over_lag8_tagged", 20000, 1000, 0, 0.05, 8, true, -1, 1, 0.25f, 2.25f, 0},
    {"much_over_noisy", 20000, 1000, 0, 0.05, 2, false, -1, 1, 0.25f, 2.25f, 0},
    {"near_high_water_noisy", 930, 1000, 0, 0.05, 2, false, -1, 1, 0.25f, -1, 0},
    {"beyond_max", 2e6, 1000, 0, 0, 0, false, -1, 1, 0.25f, 4.0f, 0},
    {"step_half", 20000, 1000, 0, 0, 2, false, -1, 1, 0.5f, 2.5f, 0},
    {"flat_view_crosses_a_level", 1200, 1000, 0, 0, 2, false, 0.9, 1, 0.25f, 0.25f, 0},
    {"flat_view_noisy", 1200, 1000, 0, 0.05, 2, false, 0.6, 1, 0.25f, 0.5f, 0},
    // The pool grows: a multi-step fall by the 4^d model overshoots a flat view once, then comes
    // back up (one reversal after the change, two direction changes in all) and stays.
    {"flat_view_pool_grows", 3000, 1000, 2500, 0.05, 2, false, 0.5, 1, 0.25f, 0.5f, 2},
    {"working_set_exceeds_count", 700, 1000, 0, 0, 2, false, -1, 1.5, 0.25f, 0.25f, 0},
    {"pool_grows_large", 5000, 1000, 8000, 0, 2, false, -1, 1, 0.25f, 0.0f, 1},
    {"pool_grows_large_noisy", 5000, 1000, 8000, 0.05, 2, false, -1, 1, 0.25f, 0.0f, 1},
    {"pool_grows_some", 5000, 1000, 3000, 0.05, 2, false, -1, 1, 0.25f, -1, 1},
    {"pool_shrinks", 3000, 8000, 1000, 0.05, 2, false, -1, 1, 0.25f, -1, 0},
    {"back_from_max", 2e6, 1000, 4e6, 0, 2, false, -1, 1, 0.25f, 0.0f, 1},
};

class LodBiasSim : public ::testing::TestWithParam<Scenario> {};

TEST_P(LodBiasSim, SettlesWithoutOscillation) {
    const Scenario& s = GetParam();
    const SimResult r = simulate(s);
    const tc::LodBiasConfig cfg;
    const float final_bias = r.bias.back();

    // Converges: no change in the last 800 frames (static since frame kChangeAt at the latest).
    EXPECT_LT(r.last_change_frame, kFrames - 800) << "still changing at frame " << r.last_change_frame;
    // Never oscillates.
    EXPECT_LE(direction_changes(r.bias), s.max_direction_changes);
    if (s.expect_bias >= 0) {
        EXPECT_EQ(final_bias, s.expect_bias);
    }
    EXPECT_GE(final_bias, 0.0f);
    EXPECT_LE(final_bias, cfg.max_bias);

    const double p = r.model_p.back();
    if (final_bias < cfg.max_bias) {
        // Settled in the band: the pool holds the view...
        EXPECT_LE(p, cfg.high_water) << "final pressure " << p;
        // ...and no page churn once settled.
        for (unsigned f = kFrames - 800; f < kFrames; ++f) ASSERT_EQ(r.churn[f], 0.0) << "frame " << f;
    }
    // Not more blur than needed (smooth views): one step less would overfill the low-water mark.
    if (final_bias > 0 && s.flat_lod < 0 && s.working_set == 1.0) {
        const double pool = s.pool_later > 0 ? s.pool_later : s.pool;
        EXPECT_GT(wanted_at(s, final_bias - s.step) / pool, cfg.low_water * (1 - s.noise) - 1e-6);
    }
    // Churn bounded overall: the pool only thrashed while the bias was still finding its level.
    double total_churn = 0;
    for (double c : r.churn) total_churn += c;
    if (final_bias < cfg.max_bias) {
        EXPECT_LT(total_churn, 60 * s.w0 * s.working_set) << total_churn;
    }

    // The summary agrees with the run.
    EXPECT_EQ(r.summary.frames(), kFrames);
    EXPECT_EQ(r.summary.last_lod_bias(), final_bias);
}

INSTANTIATE_TEST_SUITE_P(Scenarios, LodBiasSim, ::testing::ValuesIn(kScenarios),
                         [](const ::testing::TestParamInfo<Scenario>& p) { return p.param.name; });

const Scenario& scenario(const std::string& name) {
    for (const Scenario& s : kScenarios)
        if (s.name == name) return s;
    throw std::runtime_error("no scenario " + name);
}

TEST(LodBiasSimulation, DeterministicForTheSameInputs) {
    const SimResult a = simulate(scenario("much_over_noisy"));
    const SimResult b = simulate(scenario("much_over_noisy"));
    EXPECT_EQ(a.bias, b.bias);
}

TEST(LodBiasSimulation, TaggedFeedbackMakesLagIrrelevant) {
    // Tagged feedback makes the lag irrelevant: the same result as no lag at all.
    Scenario s = scenario("much_over");
    s.lag = 8;
    s.tagged = true;
    EXPECT_EQ(simulate(s).bias.back(), 2.25f);
    EXPECT_EQ(direction_changes(simulate(s).bias), 0u);
}

// Sweep the view's page count across 1.5 levels of pressure, with noise and a pool that doubles
// half way: never more than the one reversal the pool change calls for, settled in the band.
TEST(LodBiasSimulation, SweepNeverFlipFlops) {
    const tc::LodBiasConfig cfg;
    for (double w = 900; w < 30000; w *= 1.07) {
        for (double later : {0.0, 2000.0}) {
            Scenario s{"sweep", w, 1000, later, 0.05, 2, false, -1, 1, 0.25f, -1, 1};
            const SimResult r = simulate(s);
            SCOPED_TRACE("w0 " + std::to_string(w) + " pool later " + std::to_string(later));
            EXPECT_LE(direction_changes(r.bias), later > 0 ? 1u : 0u);
            EXPECT_LE(r.model_p.back(), cfg.high_water);
            for (unsigned f = kFrames - 200; f < kFrames; ++f) ASSERT_EQ(r.churn[f], 0.0);
            if (later > 0 && w / later < cfg.low_water) {
                EXPECT_EQ(r.bias.back(), 0.0f);
            }
        }
    }
}

TEST(LodBiasSimulation, FlatViewDoesNotRetryAFallThatCannotFit) {
    // At bias 0 the flat view at LoD 0.9 wants 1200 pages (p 1.2); one step up crosses to the next
    // level: 300 pages (p 0.3). By the 4^step model a fall would land at p 0.42, but the rise showed
    // growth 4: the controller stays at 0.25 and never tries.
    const SimResult r = simulate(scenario("flat_view_crosses_a_level"));
    EXPECT_EQ(direction_changes(r.bias), 0u);
    unsigned changes = 0;
    for (std::size_t i = 1; i < r.bias.size(); ++i) changes += r.bias[i] != r.bias[i - 1];
    EXPECT_EQ(changes, 1u);
}

}  // namespace
