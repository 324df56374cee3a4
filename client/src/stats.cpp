#include "tessera/client/stats.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <type_traits>
#include <vector>

#include <nlohmann/json.hpp>

namespace tessera::client {

// --- LatencyHistogram ---

void LatencyHistogram::record(std::chrono::nanoseconds d) {
    const auto ns = d.count();
    record_us(ns <= 0 ? 0 : static_cast<std::uint64_t>((ns + 500) / 1000));
}

void LatencyHistogram::record_ms(double ms) {
    if (!(ms > 0.0)) {
        record_us(0);
        return;
    }
    const double us = std::round(ms * 1000.0);
    record_us(us >= 1.8e19 ? ~std::uint64_t{0} : static_cast<std::uint64_t>(us));
}

void LatencyHistogram::reset() { *this = LatencyHistogram{}; }

double LatencyHistogram::mean_ms() const { return mean() / 1000.0; }
double LatencyHistogram::min_ms() const { return static_cast<double>(min()) / 1000.0; }
double LatencyHistogram::max_ms() const { return static_cast<double>(max()) / 1000.0; }

double LatencyHistogram::quantile(double q) const { return Counts::quantile_value(q) / 1000.0; }

double StatsSummary::time_to_detail_quantile(double q) const { return time_to_detail_.quantile_value(q); }

// --- JSON / CSV helpers ---

namespace {

void put_uint(std::string& s, std::uint64_t v) {
    char buf[24];
    auto r = std::to_chars(buf, buf + sizeof buf, v);
    s.append(buf, r.ptr);
}

// CSV numbers: the shortest round-trip form (of the value's own type); NaN or infinity: null, as
// in the JSON.
template <class T>
void put_num(std::string& s, T v) {
    if (!std::isfinite(v)) {
        s += "null";
        return;
    }
    char buf[32];
    auto r = std::to_chars(buf, buf + sizeof buf, v);
    s.append(buf, r.ptr);
}

// Levels up to the highest one with any count in any of the three arrays.
template <class Array>
std::size_t used_levels(const Array& a, const Array& b, const Array& c) {
    std::size_t n = 0;
    for (std::size_t i = 0; i < kMaxLevels; ++i)
        if (a[i] || b[i] || c[i]) n = i + 1;
    return n;
}

// Keys in the order written (frame, pages, hits...), not sorted as nlohmann::json would.
using Json = nlohmann::ordered_json;

// A number as the CSV writes it: whole values without ".0", a float in its own shortest form
// (0.1f is 0.1, not 0.10000000149011612); JSON has no NaN or infinity: null.
template <class T>
Json json_num(T v) {
    if (!std::isfinite(v)) return nullptr;
    double d = v;
    if constexpr (std::is_same_v<T, float>) {
        char buf[32];
        const auto r = std::to_chars(buf, buf + sizeof buf, v);
        std::from_chars(buf, r.ptr, d);
    }
    if (std::trunc(d) == d && std::abs(d) < 0x1p53) return static_cast<std::int64_t>(d);
    return d;
}

template <class Array>
Json hits_json(const Array& ram, const Array& disk, const Array& net) {
    const auto n = static_cast<std::ptrdiff_t>(used_levels(ram, disk, net));
    const auto levels = [n](const Array& a) { return std::vector<std::uint64_t>(a.begin(), a.begin() + n); };
    return Json{{"ram", levels(ram)}, {"disk", levels(disk)}, {"network", levels(net)}};
}

std::uint32_t sum(const LevelCounts& a) {
    std::uint64_t t = 0;
    for (auto v : a) t += v;
    return static_cast<std::uint32_t>(std::min<std::uint64_t>(t, ~std::uint32_t{0}));
}

}  // namespace

// --- FrameStats ---

std::uint32_t FrameStats::total_ram_hits() const { return sum(ram_hits); }
std::uint32_t FrameStats::total_disk_hits() const { return sum(disk_hits); }
std::uint32_t FrameStats::total_network() const { return sum(network); }

std::string FrameStats::to_json() const {
    Json j;
    j["frame"] = frame;
    j["pages"] = Json{{"wanted", pages_wanted},     {"resident", pages_resident}, {"requested", pages_requested},
                      {"arrived", pages_arrived},   {"uploaded", pages_uploaded}, {"evicted", pages_evicted},
                      {"rescued", pages_rescued}};
    j["hits"] = hits_json(ram_hits, disk_hits, network);
    j["bytes"] = Json{{"received", bytes_received}, {"uploaded", bytes_uploaded}};
    j["lod_bias"] = json_num(lod_bias);
    j["fallback_estimate"] = json_num(fallback_estimate);
    return j.dump();
}

std::string FrameStats::csv_header() {
    return "frame,pages_wanted,pages_resident,pages_requested,pages_arrived,pages_uploaded,pages_evicted,"
           "ram_hits,disk_hits,network,bytes_received,bytes_uploaded,lod_bias,fallback_estimate,pages_rescued";
}

std::string FrameStats::csv_row() const {
    std::string s;
    const std::uint64_t ints[] = {frame,          pages_wanted,     pages_resident,    pages_requested,
                                  pages_arrived,  pages_uploaded,   pages_evicted,     total_ram_hits(),
                                  total_disk_hits(), total_network(), bytes_received, bytes_uploaded};
    for (auto v : ints) {
        put_uint(s, v);
        s += ',';
    }
    put_num(s, lod_bias);
    s += ',';
    put_num(s, fallback_estimate);
    s += ',';
    put_uint(s, pages_rescued);
    return s;
}

// --- StatsSummary ---

void StatsSummary::add_frame(const FrameStats& f) {
    ++frames_;
    wanted_sum_ += f.pages_wanted;
    resident_sum_ += f.pages_resident;
    requested_ += f.pages_requested;
    arrived_ += f.pages_arrived;
    uploaded_ += f.pages_uploaded;
    evicted_ += f.pages_evicted;
    rescued_ += f.pages_rescued;
    for (std::size_t i = 0; i < kMaxLevels; ++i) {
        ram_hits_[i] += f.ram_hits[i];
        disk_hits_[i] += f.disk_hits[i];
        network_[i] += f.network[i];
    }
    bytes_received_ += f.bytes_received;
    bytes_uploaded_ += f.bytes_uploaded;
    bias_sum_ += f.lod_bias;
    bias_max_ = frames_ == 1 ? f.lod_bias : std::max(bias_max_, f.lod_bias);
    bias_last_ = f.lod_bias;
    fallback_sum_ += f.fallback_estimate;
    cancelled_waiting_ += f.cancelled_waiting;
    cancelled_arrived_ += f.cancelled_arrived;
    cancelled_decoded_ += f.cancelled_decoded;
    decodes_dropped_ += f.decodes_dropped;
    stale_arrivals_ += f.stale_arrivals;
    other_version_arrivals_ += f.other_version_arrivals;
    duplicate_arrivals_ += f.duplicate_arrivals;
    decode_failures_ += f.decode_failures;
    source_errors_ += f.source_errors;
    if (first_source_error_.empty()) first_source_error_ = f.first_source_error;
}

void StatsSummary::reset() { *this = StatsSummary{}; }

namespace {
double mean_of(double sum_, std::uint64_t n) { return n == 0 ? 0.0 : sum_ / static_cast<double>(n); }
}  // namespace

double StatsSummary::mean_pages_wanted() const { return mean_of(static_cast<double>(wanted_sum_), frames_); }
double StatsSummary::mean_pages_resident() const { return mean_of(static_cast<double>(resident_sum_), frames_); }
double StatsSummary::mean_lod_bias() const { return mean_of(bias_sum_, frames_); }
double StatsSummary::mean_fallback_estimate() const { return mean_of(fallback_sum_, frames_); }

std::string StatsSummary::to_json() const {
    Json j;
    j["frames"] = frames_;
    j["pages"] = Json{{"wanted_mean", json_num(mean_pages_wanted())},
                      {"resident_mean", json_num(mean_pages_resident())},
                      {"requested", requested_},
                      {"arrived", arrived_},
                      {"uploaded", uploaded_},
                      {"evicted", evicted_},
                      {"rescued", rescued_}};
    j["hits"] = hits_json(ram_hits_, disk_hits_, network_);
    j["bytes"] = Json{{"received", bytes_received_}, {"uploaded", bytes_uploaded_}};
    j["latency_ms"] = Json{{"count", latency_.count()},
                           {"mean", json_num(latency_.mean_ms())},
                           {"p50", json_num(latency_.quantile(0.5))},
                           {"p90", json_num(latency_.quantile(0.9))},
                           {"p99", json_num(latency_.quantile(0.99))},
                           {"max", json_num(latency_.max_ms())}};
    j["time_to_detail_frames"] = Json{{"count", time_to_detail_.count()},
                                      {"mean", json_num(time_to_detail_.mean())},
                                      {"p50", json_num(time_to_detail_.quantile_value(0.5))},
                                      {"p90", json_num(time_to_detail_.quantile_value(0.9))},
                                      {"max", time_to_detail_.max()}};
    j["lod_bias"] = Json{{"last", json_num(bias_last_)}, {"mean", json_num(mean_lod_bias())}, {"max", json_num(bias_max_)}};
    j["fallback_estimate_mean"] = json_num(mean_fallback_estimate());
    j["skipped"] = Json{{"cancelled_waiting", cancelled_waiting_}, {"cancelled_arrived", cancelled_arrived_},
                        {"cancelled_decoded", cancelled_decoded_}, {"decodes_dropped", decodes_dropped_},
                        {"stale_arrivals", stale_arrivals_},       {"duplicate_arrivals", duplicate_arrivals_},
                        {"other_version_arrivals", other_version_arrivals_}};
    j["errors"] = Json{{"decode_failures", decode_failures_}, {"source_errors", source_errors_}};
    return j.dump();
}

}  // namespace tessera::client
