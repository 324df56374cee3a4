#pragma once
// Server metrics, exposed on /metrics in the Prometheus text format (version 0.0.4).
// Registration takes a lock and returns a reference that stays valid for the registry's life;
// updates are lock-free atomics, cheap enough for every tile.
#include <array>
#include <atomic>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

namespace tessera::server {

using Labels = std::vector<std::pair<std::string, std::string>>;

// Counters and histograms are striped: each thread updates its own stripe (threads take
// stripes in turn), so the event loops and workers that count every tile do not pass one cache
// line back and forth between cores; a read sums the stripes.
inline constexpr std::size_t kMetricStripes = 8;
std::size_t next_metric_stripe();
inline std::size_t metric_stripe() {
    thread_local const std::size_t stripe = next_metric_stripe();
    return stripe;
}

class Counter {
public:
    void inc(std::uint64_t n = 1) { stripes_[metric_stripe()].value.fetch_add(n, std::memory_order_relaxed); }
    std::uint64_t value() const {
        std::uint64_t total = 0;
        for (const Stripe& s : stripes_) total += s.value.load(std::memory_order_relaxed);
        return total;
    }

private:
    struct alignas(64) Stripe {
        std::atomic<std::uint64_t> value{0};
    };
    std::array<Stripe, kMetricStripes> stripes_{};
};

class Gauge {
public:
    void set(double v) { value_.store(v, std::memory_order_relaxed); }
    void add(double d);
    double value() const { return value_.load(std::memory_order_relaxed); }

private:
    std::atomic<double> value_{0};
};

// Cumulative histogram with fixed upper bounds (the +Inf bucket is implicit).
class Histogram {
public:
    explicit Histogram(std::vector<double> upper_bounds);
    void observe(double v);
    struct Snapshot {
        std::vector<double> upper_bounds;
        std::vector<std::uint64_t> cumulative;  // one per bound, then +Inf (== count)
        double sum = 0;
        std::uint64_t count = 0;
    };
    Snapshot snapshot() const;
    // Linear interpolation inside the bucket that holds quantile q (0..1); 0 when empty.
    double quantile(double q) const;

private:
    struct alignas(64) Sum {
        std::atomic<double> value{0};
    };
    std::vector<double> bounds_;
    // Non-cumulative, bounds_.size()+1 per stripe; rows are whole multiples of 64 bytes apart,
    // so two stripes share at most the line where one row ends and the next begins.
    std::size_t row_ = 0;
    std::unique_ptr<std::atomic<std::uint64_t>[]> buckets_;
    std::unique_ptr<Sum[]> sums_;  // one per stripe
};

// Latency buckets in seconds, 50 µs .. 10 s.
std::vector<double> latency_buckets_seconds();

class MetricsRegistry {
public:
    MetricsRegistry();
    ~MetricsRegistry();  // out of line: Family is defined in metrics.cpp
    MetricsRegistry(const MetricsRegistry&) = delete;
    MetricsRegistry& operator=(const MetricsRegistry&) = delete;

    // Same name + labels returns the same metric. A name is one type with one help text;
    // names and label names must match [a-zA-Z_:][a-zA-Z0-9_:]* / [a-zA-Z_][a-zA-Z0-9_]*
    // (programming errors otherwise: std::invalid_argument).
    Counter& counter(const std::string& name, const std::string& help, const Labels& labels = {});
    Gauge& gauge(const std::string& name, const std::string& help, const Labels& labels = {});
    Histogram& histogram(const std::string& name, const std::string& help, const Labels& labels,
                         std::vector<double> upper_bounds);
    // A gauge read at render time (queue depths, cache sizes). The callback must stay valid
    // until the registry is destroyed or the gauge is removed.
    void gauge_callback(const std::string& name, const std::string& help, const Labels& labels,
                        std::function<double()> read);
    void remove_callbacks(const std::string& name);

    // The whole registry in Prometheus text format 0.0.4: families sorted by name, each with
    // # HELP and # TYPE, label values escaped, histograms as _bucket{le=...}/_sum/_count.
    std::string render() const;

private:
    enum class Type { counter, gauge, histogram };
    struct Family;
    Family& family(const std::string& name, const std::string& help, Type type);
    mutable std::mutex mutex_;
    std::map<std::string, std::unique_ptr<Family>> families_;
};

}  // namespace tessera::server
