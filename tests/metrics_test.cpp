// The metrics registry (server/src/metrics.*) and the Prometheus text parser the tests check it with
// (prometheus_text.hpp), including inputs the parser must reject.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "metrics.hpp"
#include "prometheus_text.hpp"

namespace {

using tessera::server::Counter;
using tessera::server::Gauge;
using tessera::server::Histogram;
using tessera::server::Labels;
using tessera::server::latency_buckets_seconds;
using tessera::server::MetricsRegistry;
using tessera::test::parse_prometheus_text;
using tessera::test::PromLabels;

constexpr double inf = std::numeric_limits<double>::infinity();

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

// ---------------------------------------------------------------------------------------------
// Counter, Gauge, Histogram

TEST(MetricsCounter, IncrementsAndReadsBack) {
    Counter c;
    EXPECT_EQ(c.value(), 0u);
    c.inc();
    c.inc(41);
    EXPECT_EQ(c.value(), 42u);
}

TEST(MetricsGauge, SetAndAdd) {
    Gauge g;
    EXPECT_EQ(g.value(), 0.0);
    g.set(2.5);
    g.add(1.25);
    g.add(-4);
    EXPECT_EQ(g.value(), -0.25);
}

TEST(MetricsHistogram, ValueOnABoundCountsInThatBucket) {
    Histogram h({1, 2, 5});
    for (double v : {0.5, 1.0, 1.0000001, 2.0, 5.0, 5.5, inf}) h.observe(v);
    const auto s = h.snapshot();
    ASSERT_EQ(s.upper_bounds, (std::vector<double>{1, 2, 5}));
    // le=1: 0.5, 1 | le=2: +1.0000001, 2 | le=5: +5 | +Inf: +5.5, +inf
    EXPECT_EQ(s.cumulative, (std::vector<std::uint64_t>{2, 4, 5, 7}));
    EXPECT_EQ(s.count, 7u);
    EXPECT_EQ(s.sum, inf);
}

TEST(MetricsHistogram, SnapshotIsCumulativeWithSumAndCount) {
    Histogram h({0.5, 1, 2});
    for (double v : {0.25, 0.5, 1.0, 4.0}) h.observe(v);
    const auto s = h.snapshot();
    EXPECT_EQ(s.cumulative, (std::vector<std::uint64_t>{2, 3, 3, 4}));
    EXPECT_EQ(s.count, 4u);
    EXPECT_EQ(s.sum, 5.75);
}

TEST(MetricsHistogram, BoundsAreValidated) {
    EXPECT_THROW(Histogram({2, 1}), std::invalid_argument);
    EXPECT_THROW(Histogram({1, 1}), std::invalid_argument);
    EXPECT_THROW(Histogram({1, std::nan("")}), std::invalid_argument);
    // A trailing +Inf is the implicit bucket, not a second one.
    Histogram h({1, inf});
    EXPECT_EQ(h.snapshot().upper_bounds, (std::vector<double>{1}));
    EXPECT_EQ(h.snapshot().cumulative.size(), 2u);
    Histogram only_inf({});
    only_inf.observe(3);
    EXPECT_EQ(only_inf.snapshot().cumulative, (std::vector<std::uint64_t>{1}));
}

TEST(MetricsHistogram, NaNObservationsAreDropped) {
    Histogram h({1});
    h.observe(std::nan(""));
    h.observe(0.5);
    const auto s = h.snapshot();
    EXPECT_EQ(s.count, 1u);
    EXPECT_EQ(s.sum, 0.5);
}

TEST(MetricsHistogram, QuantileInterpolatesLikeHistogramQuantile) {
    Histogram h({1, 2, 4, 8});
    auto observe = [&](double v, int n) {
        for (int i = 0; i < n; ++i) h.observe(v);
    };
    observe(0.5, 10);  // cumulative 10
    observe(1.5, 10);  // 20
    observe(3, 20);    // 40
    observe(6, 40);    // 80
    observe(100, 20);  // 100 (+Inf)
    // rank = q * 100; bucket = first with cumulative >= rank; lower edge of the first bucket is 0.
    EXPECT_DOUBLE_EQ(h.quantile(0.1), 1.0);   // le=1: 0 + 1 * 10/10
    EXPECT_DOUBLE_EQ(h.quantile(0.15), 1.5);  // le=2: 1 + 1 * 5/10
    EXPECT_DOUBLE_EQ(h.quantile(0.3), 3.0);   // le=4: 2 + 2 * 10/20
    EXPECT_DOUBLE_EQ(h.quantile(0.5), 5.0);   // le=8: 4 + 4 * 10/40
    EXPECT_DOUBLE_EQ(h.quantile(0.8), 8.0);   // le=8: 4 + 4 * 40/40
    EXPECT_DOUBLE_EQ(h.quantile(0.9), 8.0);   // +Inf bucket: the highest finite bound
    EXPECT_DOUBLE_EQ(h.quantile(1.0), 8.0);
    EXPECT_DOUBLE_EQ(h.quantile(0.0), 0.0);   // lower edge of the first non-empty bucket
}

TEST(MetricsHistogram, QuantileEdgeCases) {
    Histogram empty({1, 2});
    EXPECT_EQ(empty.quantile(0.5), 0.0);

    Histogram h({1, 2, 4});
    for (int i = 0; i < 4; ++i) h.observe(3);  // all in le=4
    EXPECT_DOUBLE_EQ(h.quantile(0.0), 2.0);    // first non-empty bucket starts at 2
    EXPECT_DOUBLE_EQ(h.quantile(0.5), 3.0);
    EXPECT_DOUBLE_EQ(h.quantile(-1), 2.0);     // clamped to 0
    EXPECT_DOUBLE_EQ(h.quantile(7), 4.0);      // clamped to 1
    EXPECT_TRUE(std::isnan(h.quantile(std::nan(""))));

    Histogram negative({-1, 0, 1});
    for (int i = 0; i < 10; ++i) negative.observe(-5);
    EXPECT_EQ(negative.quantile(0.5), -1.0);  // first bucket with bound <= 0: the bound

    Histogram only_inf({});
    only_inf.observe(1);
    EXPECT_TRUE(std::isnan(only_inf.quantile(0.5)));
}

TEST(MetricsLatencyBuckets, OneTwoFiveFrom50MicrosecondsTo10Seconds) {
    const auto b = latency_buckets_seconds();
    ASSERT_GE(b.size(), 15u);
    ASSERT_LE(b.size(), 25u);
    EXPECT_DOUBLE_EQ(b.front(), 50e-6);
    EXPECT_DOUBLE_EQ(b.back(), 10.0);
    for (std::size_t i = 1; i < b.size(); ++i) {
        EXPECT_LT(b[i - 1], b[i]);
        const double ratio = b[i] / b[i - 1];
        EXPECT_TRUE(std::abs(ratio - 2) < 1e-9 || std::abs(ratio - 2.5) < 1e-9) << "bounds " << b[i - 1] << ", " << b[i];
    }
    EXPECT_NO_THROW(Histogram{b});
}

// ---------------------------------------------------------------------------------------------
// MetricsRegistry

TEST(MetricsRegistry, SameNameAndLabelsReturnSameMetric) {
    MetricsRegistry reg;
    Counter& a = reg.counter("t_requests_total", "Requests", {{"method", "GET"}, {"code", "200"}});
    Counter& b = reg.counter("t_requests_total", "Requests", {{"code", "200"}, {"method", "GET"}});
    Counter& c = reg.counter("t_requests_total", "Requests", {{"code", "404"}, {"method", "GET"}});
    EXPECT_EQ(&a, &b);  // label order does not matter
    EXPECT_NE(&a, &c);
    EXPECT_EQ(&reg.gauge("t_g", "G"), &reg.gauge("t_g", "G"));
    Histogram& h = reg.histogram("t_h", "H", {{"s", "x"}}, {1, 2});
    EXPECT_EQ(&h, &reg.histogram("t_h", "H", {{"s", "x"}}, {1, 2}));
    EXPECT_EQ(&h, &reg.histogram("t_h", "H", {{"s", "x"}}, {1, 2, inf}));  // same bounds, +Inf implicit
}

TEST(MetricsRegistry, TypeConflictThrows) {
    MetricsRegistry reg;
    reg.counter("t_x_total", "X");
    EXPECT_THROW(reg.gauge("t_x_total", "X"), std::invalid_argument);
    EXPECT_THROW(reg.histogram("t_x_total", "X", {}, {1}), std::invalid_argument);
    EXPECT_THROW(reg.gauge_callback("t_x_total", "X", {}, [] { return 1.0; }), std::invalid_argument);
    reg.gauge("t_y", "Y");
    EXPECT_THROW(reg.counter("t_y", "Y"), std::invalid_argument);
    // A conflict leaves the registry as it was.
    const auto r = parse_prometheus_text(reg.render());
    ASSERT_TRUE(r.ok()) << r.error;
    EXPECT_EQ(r.types, (std::map<std::string, std::string>{{"t_x_total", "counter"}, {"t_y", "gauge"}}));
}

TEST(MetricsRegistry, InvalidNamesThrow) {
    MetricsRegistry reg;
    for (const char* bad : {"", "1abc", "a-b", "a b", "a.b", "é", "a{b}"}) {
        EXPECT_THROW(reg.counter(bad, "h"), std::invalid_argument) << bad;
        EXPECT_THROW(reg.gauge(bad, "h"), std::invalid_argument) << bad;
        EXPECT_THROW(reg.histogram(bad, "h", {}, {1}), std::invalid_argument) << bad;
        EXPECT_THROW(reg.gauge_callback(bad, "h", {}, [] { return 0.0; }), std::invalid_argument) << bad;
    }
    for (const char* bad : {"", "1a", "a:b", "a-b", "__reserved"}) {
        EXPECT_THROW(reg.counter("t_ok_total", "h", {{bad, "v"}}), std::invalid_argument) << bad;
    }
    EXPECT_THROW(reg.counter("t_ok_total", "h", {{"a", "1"}, {"a", "2"}}), std::invalid_argument);
    EXPECT_THROW(reg.histogram("t_h", "h", {{"le", "1"}}, {1}), std::invalid_argument);
    EXPECT_THROW(reg.histogram("t_h", "h", {}, {2, 1}), std::invalid_argument);
    // Valid ones, including le on a non-histogram and colons in metric names.
    EXPECT_NO_THROW(reg.counter("a:b_c:total", "h", {{"_x9", "v"}, {"le", "1"}}));
    EXPECT_NO_THROW(reg.gauge("_", "h", {{"A", ""}}));
    // Nothing half-registered by the failures.
    const auto r = parse_prometheus_text(reg.render());
    ASSERT_TRUE(r.ok()) << r.error;
    EXPECT_EQ(r.samples.size(), 2u);
}

TEST(MetricsRegistry, HistogramFamilyHasOneSetOfBoundsAndOwnsItsSuffixes) {
    MetricsRegistry reg;
    reg.histogram("t_h", "H", {{"s", "a"}}, {1, 2});
    EXPECT_THROW(reg.histogram("t_h", "H", {{"s", "b"}}, {1, 3}), std::invalid_argument);
    EXPECT_NO_THROW(reg.histogram("t_h", "H", {{"s", "b"}}, {1, 2}));
    EXPECT_THROW(reg.counter("t_h_count", "C"), std::invalid_argument);
    EXPECT_THROW(reg.gauge("t_h_sum", "S"), std::invalid_argument);
    EXPECT_THROW(reg.gauge("t_h_bucket", "B"), std::invalid_argument);
    reg.gauge("t_g_sum", "S");
    EXPECT_THROW(reg.histogram("t_g", "H", {}, {1}), std::invalid_argument);
}

TEST(MetricsRegistry, EmptyRegistryRendersNothing) {
    MetricsRegistry reg;
    EXPECT_EQ(reg.render(), "");
    EXPECT_TRUE(parse_prometheus_text(reg.render()).ok());
}

TEST(MetricsRegistry, RenderIsExactExpositionText) {
    MetricsRegistry reg;
    reg.counter("tessera_requests_total", "Requests served.", {{"method", "GET"}, {"code", "200"}}).inc(3);
    reg.counter("tessera_requests_total", "Requests served.", {{"code", "404"}, {"method", "GET"}}).inc();
    reg.gauge("tessera_cache_bytes", "Bytes in the tile cache.").set(1.5e9);
    Histogram& h = reg.histogram("tessera_tile_seconds", "Tile latency.", {}, {0.5, 1, 2});
    for (double v : {0.25, 0.5, 1.0, 4.0}) h.observe(v);
    const std::string expected =
        "# HELP tessera_cache_bytes Bytes in the tile cache.\n"
        "# TYPE tessera_cache_bytes gauge\n"
        "tessera_cache_bytes 1500000000\n"
        "# HELP tessera_requests_total Requests served.\n"
        "# TYPE tessera_requests_total counter\n"
        "tessera_requests_total{code=\"200\",method=\"GET\"} 3\n"
        "tessera_requests_total{code=\"404\",method=\"GET\"} 1\n"
        "# HELP tessera_tile_seconds Tile latency.\n"
        "# TYPE tessera_tile_seconds histogram\n"
        "tessera_tile_seconds_bucket{le=\"0.5\"} 2\n"
        "tessera_tile_seconds_bucket{le=\"1\"} 3\n"
        "tessera_tile_seconds_bucket{le=\"2\"} 3\n"
        "tessera_tile_seconds_bucket{le=\"+Inf\"} 4\n"
        "tessera_tile_seconds_sum 5.75\n"
        "tessera_tile_seconds_count 4\n";
    EXPECT_EQ(reg.render(), expected);
    const auto r = parse_prometheus_text(expected);
    EXPECT_TRUE(r.ok()) << r.error;
}

TEST(MetricsRegistry, RenderParsesWithTheExpectedSamples) {
    MetricsRegistry reg;
    reg.counter("t_tiles_total", "Tiles", {{"store", "b"}}).inc(7);
    reg.counter("t_tiles_total", "Tiles", {{"store", "a"}}).inc(2);
    reg.gauge("t_temperature", "Temp", {{"room", "x"}}).set(-3.5);
    Histogram& ha = reg.histogram("t_latency_seconds", "Latency", {{"store", "a"}}, latency_buckets_seconds());
    Histogram& hb = reg.histogram("t_latency_seconds", "Latency", {{"store", "b"}}, latency_buckets_seconds());
    ha.observe(0.003);
    ha.observe(0.0005);
    hb.observe(20);
    double depth = 5;
    reg.gauge_callback("t_queue_depth", "Depth", {}, [&depth] { return depth; });

    const std::string text = reg.render();
    const auto r = parse_prometheus_text(text);
    ASSERT_TRUE(r.ok()) << r.error << "\n" << text;
    EXPECT_EQ(r.value("t_tiles_total", {{"store", "a"}}), 2.0);
    EXPECT_EQ(r.value("t_tiles_total", {{"store", "b"}}), 7.0);
    EXPECT_EQ(r.value("t_temperature", {{"room", "x"}}), -3.5);
    EXPECT_EQ(r.value("t_queue_depth"), 5.0);
    EXPECT_EQ(r.value("t_latency_seconds_bucket", {{"store", "a"}, {"le", "0.0005"}}), 1.0);
    EXPECT_EQ(r.value("t_latency_seconds_bucket", {{"store", "a"}, {"le", "0.002"}}), 1.0);
    EXPECT_EQ(r.value("t_latency_seconds_bucket", {{"store", "a"}, {"le", "0.005"}}), 2.0);
    EXPECT_EQ(r.value("t_latency_seconds_bucket", {{"store", "a"}, {"le", "+Inf"}}), 2.0);
    EXPECT_EQ(r.value("t_latency_seconds_bucket", {{"store", "b"}, {"le", "10"}}), 0.0);
    EXPECT_EQ(r.value("t_latency_seconds_bucket", {{"store", "b"}, {"le", "+Inf"}}), 1.0);
    EXPECT_EQ(r.value("t_latency_seconds_sum", {{"store", "a"}}), 0.003 + 0.0005);
    EXPECT_EQ(r.value("t_latency_seconds_count", {{"store", "b"}}), 1.0);
    EXPECT_EQ(r.types.at("t_latency_seconds"), "histogram");
    EXPECT_EQ(r.types.at("t_tiles_total"), "counter");
    EXPECT_EQ(r.types.at("t_queue_depth"), "gauge");
    EXPECT_EQ(r.helps.at("t_latency_seconds"), "Latency");
    // Smallest latency bound printed as Go would (and as Prometheus' own clients do).
    EXPECT_TRUE(contains(text, "t_latency_seconds_bucket{store=\"a\",le=\"5e-05\"} 0\n")) << text;
    EXPECT_EQ(r.all("t_latency_seconds_bucket").size(), 2 * (latency_buckets_seconds().size() + 1));
}

TEST(MetricsRegistry, FamiliesSortedByNameAndSeriesByLabels) {
    MetricsRegistry reg;
    reg.gauge("t_b", "B", {{"k", "2"}});
    reg.counter("t_c_total", "C");
    reg.gauge("t_b", "B", {{"k", "10"}});
    reg.gauge("t_a", "A");
    reg.gauge_callback("t_b", "B", {{"k", "1"}}, [] { return 1.0; });
    const auto r = parse_prometheus_text(reg.render());
    ASSERT_TRUE(r.ok()) << r.error;
    std::vector<std::string> order;
    for (const auto& s : r.samples) order.push_back(s.name + (s.labels.empty() ? "" : "/" + s.labels.begin()->second));
    EXPECT_EQ(order, (std::vector<std::string>{"t_a", "t_b/1", "t_b/10", "t_b/2", "t_c_total"}));
}

TEST(MetricsRegistry, LabelValueEscapingRoundTrips) {
    MetricsRegistry reg;
    const std::vector<std::string> values = {
        "plain", "with \"quotes\"", "back\\slash", "new\nline", "all \\\" \n \\n \"\\", "", "tab\tand é ünïcode", "}", ",x=\"y\"",
    };
    for (std::size_t i = 0; i < values.size(); ++i)
        reg.counter("t_escape_total", "E", {{"v", values[i]}}).inc(i + 1);
    const std::string text = reg.render();
    EXPECT_TRUE(contains(text, "t_escape_total{v=\"with \\\"quotes\\\"\"}")) << text;
    EXPECT_TRUE(contains(text, "t_escape_total{v=\"back\\\\slash\"}")) << text;
    EXPECT_TRUE(contains(text, "t_escape_total{v=\"new\\nline\"}")) << text;
    const auto r = parse_prometheus_text(text);
    ASSERT_TRUE(r.ok()) << r.error << "\n" << text;
    ASSERT_EQ(r.samples.size(), values.size());
    for (std::size_t i = 0; i < values.size(); ++i)
        EXPECT_EQ(r.value("t_escape_total", {{"v", values[i]}}), double(i + 1)) << values[i];
}

TEST(MetricsRegistry, HelpEscapingRoundTrips) {
    MetricsRegistry reg;
    const std::string help = "Line one\nline \"two\" with a \\ backslash";
    reg.gauge("t_help", help);
    reg.gauge("t_nohelp", "");
    reg.gauge("t_spaces", "  two leading, one trailing ");
    const std::string text = reg.render();
    EXPECT_TRUE(contains(text, "# HELP t_help Line one\\nline \"two\" with a \\\\ backslash\n")) << text;
    EXPECT_TRUE(contains(text, "# HELP t_nohelp\n# TYPE t_nohelp gauge\n")) << text;
    const auto r = parse_prometheus_text(text);
    ASSERT_TRUE(r.ok()) << r.error << "\n" << text;
    EXPECT_EQ(r.helps.at("t_help"), help);
    EXPECT_EQ(r.helps.at("t_nohelp"), "");
    EXPECT_EQ(r.helps.at("t_spaces"), "  two leading, one trailing ");
}

TEST(MetricsRegistry, InvalidUtf8LabelValuesBecomeReplacementCharacters) {
    MetricsRegistry reg;
    Counter& a = reg.counter("t_utf8_total", "U", {{"store", "caf\xe9"}});
    EXPECT_EQ(&a, &reg.counter("t_utf8_total", "U", {{"store", "caf\xe9"}}));
    reg.counter("t_utf8_total", "U", {{"store", "ok \xc3\xa9"}});
    const auto r = parse_prometheus_text(reg.render());
    ASSERT_TRUE(r.ok()) << r.error;
    EXPECT_TRUE(r.find("t_utf8_total", {{"store", "caf\xef\xbf\xbd"}}));
    EXPECT_TRUE(r.find("t_utf8_total", {{"store", "ok \xc3\xa9"}}));
}

TEST(MetricsRegistry, FloatsRoundTripThroughTheText) {
    const std::vector<double> values = {
        0.0, -0.0, 0.1, 1.0 / 3, -2.5, 1e-7, 123456789.0, 1e20, 1e21, 1.7976931348623157e308, 5e-324,
        2.2250738585072014e-308, 9007199254740993.0, 0.000123, inf, -inf, std::nan(""),
    };
    MetricsRegistry reg;
    for (std::size_t i = 0; i < values.size(); ++i)
        reg.gauge("t_float", "F", {{"i", std::to_string(100 + i)}}).set(values[i]);
    const std::string text = reg.render();
    const auto r = parse_prometheus_text(text);
    ASSERT_TRUE(r.ok()) << r.error << "\n" << text;
    for (std::size_t i = 0; i < values.size(); ++i) {
        const auto v = r.value("t_float", {{"i", std::to_string(100 + i)}});
        ASSERT_TRUE(v) << i;
        if (std::isnan(values[i])) {
            EXPECT_TRUE(std::isnan(*v));
        } else {
            EXPECT_EQ(std::memcmp(&*v, &values[i], sizeof(double)), 0) << values[i] << " came back as " << *v;
        }
    }
    for (const char* line : {"t_float{i=\"102\"} 0.1\n", "t_float{i=\"106\"} 123456789\n",
                             "t_float{i=\"107\"} 100000000000000000000\n", "t_float{i=\"108\"} 1e+21\n",
                             "t_float{i=\"105\"} 1e-07\n", "t_float{i=\"113\"} 0.000123\n", "t_float{i=\"114\"} +Inf\n",
                             "t_float{i=\"115\"} -Inf\n", "t_float{i=\"116\"} NaN\n"})
        EXPECT_TRUE(contains(text, line)) << line << "in\n" << text;
    // Counters are exact integers, beyond 2^53.
    reg.counter("t_big_total", "B").inc(18446744073709551615ull);
    EXPECT_TRUE(contains(reg.render(), "t_big_total 18446744073709551615\n"));
}

TEST(MetricsRegistry, CallbacksAreReadAtRenderTimeAndRemoved) {
    MetricsRegistry reg;
    std::atomic<int> reads{0};
    double depth = 1;
    reg.gauge_callback("t_depth", "D", {{"q", "a"}}, [&] { ++reads; return depth; });
    reg.gauge_callback("t_depth", "D", {{"q", "b"}}, [&] { ++reads; return depth * 10; });
    reg.gauge("t_depth", "D", {{"q", "plain"}}).set(7);
    EXPECT_EQ(reads, 0);
    depth = 2;
    auto r = parse_prometheus_text(reg.render());
    ASSERT_TRUE(r.ok()) << r.error;
    EXPECT_EQ(reads, 2);
    EXPECT_EQ(r.value("t_depth", {{"q", "a"}}), 2.0);
    EXPECT_EQ(r.value("t_depth", {{"q", "b"}}), 20.0);
    // Registering again replaces the callback.
    reg.gauge_callback("t_depth", "D", {{"q", "a"}}, [] { return 42.0; });
    r = parse_prometheus_text(reg.render());
    EXPECT_EQ(r.value("t_depth", {{"q", "a"}}), 42.0);

    reg.remove_callbacks("t_depth");
    reads = 0;
    r = parse_prometheus_text(reg.render());
    ASSERT_TRUE(r.ok()) << r.error;
    EXPECT_EQ(reads, 0);
    EXPECT_FALSE(r.find("t_depth", {{"q", "a"}}));
    EXPECT_EQ(r.value("t_depth", {{"q", "plain"}}), 7.0);  // plain gauges stay

    // A family of callbacks only disappears entirely, and the name is free again.
    reg.gauge_callback("t_only_cb", "O", {}, [] { return 1.0; });
    reg.remove_callbacks("t_only_cb");
    reg.remove_callbacks("t_never_registered");
    EXPECT_FALSE(contains(reg.render(), "t_only_cb"));
    EXPECT_NO_THROW(reg.counter("t_only_cb", "now a counter"));
}

TEST(MetricsRegistry, CallbackAndPlainGaugeCannotShareALabelSet) {
    MetricsRegistry reg;
    reg.gauge("t_g", "G");
    EXPECT_THROW(reg.gauge_callback("t_g", "G", {}, [] { return 1.0; }), std::invalid_argument);
    reg.gauge_callback("t_g", "G", {{"k", "v"}}, [] { return 1.0; });
    EXPECT_THROW(reg.gauge("t_g", "G", {{"k", "v"}}), std::invalid_argument);
    EXPECT_THROW(reg.gauge_callback("t_g", "G", {{"k", "w"}}, nullptr), std::invalid_argument);
}

TEST(MetricsRegistry, ThrowingCallbackRendersNaN) {
    MetricsRegistry reg;
    reg.gauge_callback("t_bad", "B", {}, []() -> double { throw std::runtime_error("boom"); });
    const auto r = parse_prometheus_text(reg.render());
    ASSERT_TRUE(r.ok()) << r.error;
    ASSERT_TRUE(r.value("t_bad"));
    EXPECT_TRUE(std::isnan(*r.value("t_bad")));
}

// ---------------------------------------------------------------------------------------------
// Concurrency (run under -fsanitize=thread too)

constexpr int kThreads = 4;
constexpr int kPerThread = 100000;

TEST(MetricsConcurrency, CounterIncrementsFromFourThreadsSumExactly) {
    MetricsRegistry reg;
    Counter& c = reg.counter("t_conc_total", "C");
    std::vector<std::thread> threads;
    for (int t = 0; t < kThreads; ++t)
        threads.emplace_back([&c] {
            for (int i = 0; i < kPerThread; ++i) c.inc();
        });
    for (auto& t : threads) t.join();
    EXPECT_EQ(c.value(), std::uint64_t(kThreads) * kPerThread);
}

TEST(MetricsConcurrency, GaugeAddAndHistogramObserveFromFourThreadsSumExactly) {
    Gauge g;
    Histogram h({0.5, 1, 2});
    std::vector<std::thread> threads;
    for (int t = 0; t < kThreads; ++t)
        threads.emplace_back([&g, &h, t] {
            for (int i = 0; i < kPerThread; ++i) {
                g.add(1.0);
                h.observe(t % 2 ? 1.0 : 2.0);  // integral values: the sum is exact
            }
        });
    for (auto& t : threads) t.join();
    EXPECT_EQ(g.value(), double(kThreads) * kPerThread);
    const auto s = h.snapshot();
    EXPECT_EQ(s.count, std::uint64_t(kThreads) * kPerThread);
    EXPECT_EQ(s.cumulative, (std::vector<std::uint64_t>{0, 2 * kPerThread, 4 * kPerThread, 4 * kPerThread}));
    EXPECT_EQ(s.sum, 3.0 * 2 * kPerThread);
}

TEST(MetricsConcurrency, RegistrationFromFourThreadsGivesOneMetric) {
    MetricsRegistry reg;
    std::vector<Counter*> got(kThreads);
    std::vector<std::thread> threads;
    for (int t = 0; t < kThreads; ++t)
        threads.emplace_back([&reg, &got, t] {
            for (int i = 0; i < 1000; ++i) {
                Counter& c = reg.counter("t_reg_total", "R", {{"store", "s"}});
                c.inc();
                got[t] = &c;
            }
        });
    for (auto& t : threads) t.join();
    for (Counter* c : got) EXPECT_EQ(c, got[0]);
    EXPECT_EQ(got[0]->value(), std::uint64_t(kThreads) * 1000);
}

TEST(MetricsConcurrency, RenderWhileUpdatingAlwaysParses) {
    MetricsRegistry reg;
    Histogram& h = reg.histogram("t_live_seconds", "L", {}, latency_buckets_seconds());
    Counter& c = reg.counter("t_live_total", "L");
    Gauge& g = reg.gauge("t_live_gauge", "L");
    std::atomic<bool> stop{false};
    std::vector<std::thread> threads;
    for (int t = 0; t < kThreads; ++t)
        threads.emplace_back([&, t] {
            for (int i = 0; !stop.load(std::memory_order_relaxed); ++i) {
                h.observe(1e-5 * ((i * 7 + t) % 2000));
                c.inc();
                g.add(0.5);
                if (i % 64 == 0) reg.counter("t_live_series_total", "S", {{"n", std::to_string(i % 50)}}).inc();
            }
        });
    for (int round = 0; round < 200; ++round) {
        const std::string text = reg.render();
        const auto r = parse_prometheus_text(text);
        ASSERT_TRUE(r.ok()) << r.error;
    }
    stop = true;
    for (auto& t : threads) t.join();
    const auto r = parse_prometheus_text(reg.render());
    ASSERT_TRUE(r.ok()) << r.error;
    EXPECT_EQ(r.value("t_live_seconds_count"), double(h.snapshot().count));
    EXPECT_EQ(r.value("t_live_total"), double(c.value()));
}

// ---------------------------------------------------------------------------------------------
// The parser

TEST(PrometheusText, AcceptsValidExposition) {
    const std::string text =
        "# A free comment\n"
        "#\n"
        "# HELP http_requests_total The total number of HTTP requests.\n"
        "# TYPE http_requests_total counter\n"
        "http_requests_total{method=\"post\",code=\"200\"} 1027 1395066363000\n"
        "http_requests_total{method=\"post\",code=\"400\"}    3 -1395066363000\n"
        "# HELP msdos_file_access_time_seconds Escaped \\\\ and \\n here\n"
        "msdos_file_access_time_seconds{path=\"C:\\\\DIR\\\\FILE.TXT\",error=\"Cannot find file:\\n\\\"FILE.TXT\\\"\"} 1.458255915e9\n"
        "metric_without_timestamp_and_labels 12.47\n"
        "something_weird{problem=\"division by zero\"} +Inf -3982045\n"
        "blanks_in_labels{ a = \"1\" , b=\"2\", } -Inf\n"
        "empty_braces{} NaN\n"
        "# TYPE http_request_duration_seconds histogram\n"
        "http_request_duration_seconds_bucket{le=\"0.05\"} 24054\n"
        "http_request_duration_seconds_bucket{le=\"0.1\"} 33444\n"
        "http_request_duration_seconds_bucket{le=\"5e-1\"} 129389\n"
        "http_request_duration_seconds_bucket{le=\"+Inf\"} 144320\n"
        "http_request_duration_seconds_sum 53423\n"
        "http_request_duration_seconds_count 144320\n"
        "# TYPE rpc_duration_seconds summary\n"
        "rpc_duration_seconds{quantile=\"0.01\"} 3102\n"
        "rpc_duration_seconds{quantile=\"0.5\"} 4773\n"
        "rpc_duration_seconds_sum 1.7560473e+07\n"
        "rpc_duration_seconds_count 2693\n"
        "# HELP empty_help\n"
        "# TYPE empty_help gauge\n"
        "empty_help .5e-3\n"
        "colons:in:name 1E+2\n";
    const auto r = parse_prometheus_text(text);
    ASSERT_TRUE(r.ok()) << r.error;
    EXPECT_EQ(r.samples.size(), 19u);
    EXPECT_EQ(r.value("http_requests_total", {{"method", "post"}, {"code", "400"}}), 3.0);
    EXPECT_EQ(r.find("http_requests_total", {{"method", "post"}, {"code", "200"}})->timestamp_ms, 1395066363000);
    EXPECT_EQ(r.value("msdos_file_access_time_seconds", {{"path", "C:\\DIR\\FILE.TXT"}, {"error", "Cannot find file:\n\"FILE.TXT\""}}),
              1.458255915e9);
    EXPECT_EQ(r.value("something_weird", {{"problem", "division by zero"}}), inf);
    EXPECT_EQ(r.value("blanks_in_labels", {{"a", "1"}, {"b", "2"}}), -inf);
    EXPECT_TRUE(std::isnan(*r.value("empty_braces")));
    EXPECT_EQ(r.value("empty_help"), 0.5e-3);
    EXPECT_EQ(r.value("colons:in:name"), 100.0);
    EXPECT_EQ(r.helps.at("msdos_file_access_time_seconds"), "Escaped \\ and \n here");
    EXPECT_EQ(r.helps.at("empty_help"), "");
    EXPECT_EQ(r.types.at("http_request_duration_seconds"), "histogram");
    EXPECT_EQ(r.types.at("rpc_duration_seconds"), "summary");
    EXPECT_EQ(r.types.at("metric_without_timestamp_and_labels"), "untyped");
    EXPECT_EQ(r.find("http_request_duration_seconds_count")->family, "http_request_duration_seconds");
}

TEST(PrometheusText, EmptyTextIsValid) {
    const auto r = parse_prometheus_text("");
    EXPECT_TRUE(r.ok());
    EXPECT_TRUE(r.samples.empty());
}

TEST(PrometheusText, ErrorNamesTheLineAndDropsTheSamples) {
    const auto r = parse_prometheus_text("a 1\nb 2\nc{x=\"1} 3\nd 4\n");
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error_line, 3u);
    EXPECT_TRUE(r.error.starts_with("line 3: ")) << r.error;
    EXPECT_TRUE(contains(r.error, "unterminated")) << r.error;
    EXPECT_TRUE(r.samples.empty());
}

struct BadInput {
    const char* name;
    std::string text;
    const char* reason;  // a part of the expected error message
};

void PrintTo(const BadInput& b, std::ostream* os) { *os << b.name; }

class PrometheusTextRejects : public ::testing::TestWithParam<BadInput> {};

TEST_P(PrometheusTextRejects, Input) {
    const BadInput& in = GetParam();
    const auto r = parse_prometheus_text(in.text);
    EXPECT_FALSE(r.ok()) << "accepted:\n" << in.text;
    EXPECT_TRUE(contains(r.error, in.reason)) << "error: " << r.error << "\nexpected it to mention: " << in.reason;
    EXPECT_TRUE(r.error.starts_with("line ")) << r.error;
}

const std::string H = "# TYPE h histogram\n";

INSTANTIATE_TEST_SUITE_P(
    Malformed, PrometheusTextRejects,
    ::testing::Values(
        BadInput{"BadMetricNameDigit", "1abc 1\n", "invalid metric name"},
        BadInput{"BadMetricNameDash", "foo-bar 1\n", "invalid metric name"},
        BadInput{"BadMetricNameInType", "# TYPE 1x gauge\n", "invalid metric name"},
        BadInput{"BadLabelName", "foo{1a=\"x\"} 1\n", "invalid label name"},
        BadInput{"BadLabelNameColon", "foo{a:b=\"x\"} 1\n", "invalid label name"},
        BadInput{"ReservedLabelName", "foo{__name__=\"x\"} 1\n", "reserved"},
        BadInput{"UnterminatedLabelValue", "foo{a=\"x} 1\n", "unterminated label value"},
        BadInput{"UnterminatedLabelValueBackslashAtEnd", "foo{a=\"x\\\n", "unterminated label value"},
        BadInput{"UnterminatedLabelSet", "foo{a=\"x\" 1\n", "expected ',' or '}'"},
        BadInput{"UnquotedLabelValue", "foo{a=x} 1\n", "not quoted"},
        BadInput{"BadLabelEscape", "foo{a=\"\\t\"} 1\n", "invalid escape"},
        BadInput{"EmptyLabelSetComma", "foo{,} 1\n", "invalid label name"},
        BadInput{"LabelGivenTwice", "foo{a=\"1\",a=\"2\"} 1\n", "given twice"},
        BadInput{"InvalidUtf8LabelValue", "foo{a=\"\xff\"} 1\n", "UTF-8"},
        BadInput{"DuplicateSample", "foo{a=\"1\"} 1\nfoo{a=\"1\"} 2\n", "duplicate sample"},
        BadInput{"DuplicateSampleReorderedLabels", "foo{a=\"1\",b=\"2\"} 1\nfoo{b=\"2\",a=\"1\"} 2\n", "duplicate sample"},
        BadInput{"DuplicateSampleNoLabels", "foo 1\nfoo{} 2\n", "duplicate sample"},
        BadInput{"GarbageValue", "foo 1.2.3\n", "invalid sample value"},
        BadInput{"WordValue", "foo abc\n", "invalid sample value"},
        BadInput{"HexValue", "foo 0x10\n", "invalid sample value"},
        BadInput{"SignedNaN", "foo -NaN\n", "invalid sample value"},
        BadInput{"OverflowingValue", "foo 1e999\n", "invalid sample value"},
        BadInput{"ExponentWithoutDigits", "foo 1e\n", "invalid sample value"},
        BadInput{"MissingValue", "foo\n", "no value"},
        BadInput{"MissingValueAfterLabels", "foo{a=\"1\"}\n", "no value"},
        BadInput{"NoBlankBeforeValue", "foo{a=\"1\"}1\n", "blank before the value"},
        BadInput{"BadTimestamp", "foo 1 12x\n", "invalid timestamp"},
        BadInput{"TextAfterTimestamp", "foo 1 12 13\n", "after the timestamp"},
        BadInput{"MissingFinalNewline", "foo 1", "newline"},
        BadInput{"EmptyLine", "foo 1\n\nbar 2\n", "empty line"},
        BadInput{"LeadingWhitespace", " foo 1\n", "starts with whitespace"},
        BadInput{"TrailingWhitespace", "foo 1 \n", "ends with whitespace"},
        BadInput{"CarriageReturn", "foo 1\r\n", "invalid sample value"},
        BadInput{"TypeAfterSamples", "foo 1\n# TYPE foo gauge\n", "after its samples"},
        BadInput{"DuplicateType", "# TYPE foo gauge\n# TYPE foo gauge\nfoo 1\n", "second TYPE"},
        BadInput{"DuplicateHelp", "# HELP foo a\n# HELP foo b\nfoo 1\n", "second HELP"},
        BadInput{"UnknownType", "# TYPE foo widget\n", "unknown metric type"},
        BadInput{"TypeWithoutType", "# TYPE foo\n", "unknown metric type"},
        BadInput{"TypeTrailingBlank", "# TYPE foo gauge \n", "unknown metric type"},
        BadInput{"MalformedHelpLine", "#  HELP foo x\n", "malformed HELP"},
        BadInput{"BadHelpEscape", "# HELP foo a\\tb\n", "invalid escape"},
        BadInput{"NonContiguousFamily", "a 1\nb 1\na{x=\"1\"} 1\n", "contiguous"},
        BadInput{"NegativeCounter", "# TYPE c_total counter\nc_total -1\n", "negative"},
        BadInput{"SummaryWithoutQuantile", "# TYPE s summary\ns 1\n", "quantile"},
        BadInput{"HistogramNonMonotonicLe",
                 H + "h_bucket{le=\"1\"} 1\nh_bucket{le=\"0.5\"} 1\nh_bucket{le=\"+Inf\"} 1\nh_sum 1\nh_count 1\n",
                 "increasing order"},
        BadInput{"HistogramRepeatedLe",
                 H + "h_bucket{le=\"1\"} 1\nh_bucket{le=\"1.0\"} 1\nh_bucket{le=\"+Inf\"} 1\nh_sum 1\nh_count 1\n",
                 "increasing order"},
        BadInput{"HistogramBucketAfterInf", H + "h_bucket{le=\"+Inf\"} 1\nh_bucket{le=\"5\"} 1\nh_sum 1\nh_count 1\n",
                 "increasing order"},
        BadInput{"HistogramDecreasingCounts",
                 H + "h_bucket{le=\"1\"} 5\nh_bucket{le=\"2\"} 3\nh_bucket{le=\"+Inf\"} 5\nh_sum 1\nh_count 5\n",
                 "decrease"},
        BadInput{"HistogramMissingInf", H + "h_bucket{le=\"1\"} 1\nh_bucket{le=\"2\"} 2\nh_sum 1\nh_count 2\n",
                 "+Inf"},
        BadInput{"HistogramMissingInfInOneSeries",
                 H + "h_bucket{s=\"a\",le=\"+Inf\"} 1\nh_sum{s=\"a\"} 1\nh_count{s=\"a\"} 1\n"
                     "h_bucket{s=\"b\",le=\"1\"} 1\nh_sum{s=\"b\"} 1\nh_count{s=\"b\"} 1\n",
                 "+Inf"},
        BadInput{"HistogramCountMismatch", H + "h_bucket{le=\"1\"} 1\nh_bucket{le=\"+Inf\"} 3\nh_sum 1\nh_count 4\n",
                 "_count differs"},
        BadInput{"HistogramMissingCount", H + "h_bucket{le=\"+Inf\"} 3\nh_sum 1\n", "no _count"},
        BadInput{"HistogramMissingSum", H + "h_bucket{le=\"+Inf\"} 3\nh_count 3\n", "no _sum"},
        BadInput{"HistogramBucketWithoutLe", H + "h_bucket 3\nh_sum 1\nh_count 3\n", "no le label"},
        BadInput{"HistogramBadLe", H + "h_bucket{le=\"abc\"} 3\nh_sum 1\nh_count 3\n", "invalid le"},
        BadInput{"HistogramLeOnCount", H + "h_bucket{le=\"+Inf\"} 3\nh_sum 1\nh_count{le=\"+Inf\"} 3\n", "le label on"},
        BadInput{"HistogramPlainSample", H + "h 1\n", "only _bucket, _sum and _count"},
        BadInput{"HistogramNegativeBucket", H + "h_bucket{le=\"+Inf\"} -1\nh_sum 1\nh_count -1\n", "negative"},
        BadInput{"HistogramTypeAfterBuckets", "h_bucket{le=\"+Inf\"} 1\n# TYPE h histogram\n", "after samples named"},
        BadInput{"HistogramSuffixFamilyCollision", H + "h_bucket{le=\"+Inf\"} 1\nh_sum 1\nh_count 1\n# TYPE h_count gauge\n",
                 "collides"}),
    [](const ::testing::TestParamInfo<BadInput>& p) { return std::string(p.param.name); });

}  // namespace
