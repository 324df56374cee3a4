#pragma once
// Client statistics: per-frame counters (FrameStats), a latency histogram (LatencyHistogram, also
// meant for the load tester) and a summary across frames (StatsSummary), as JSON lines or CSV.
// Definitions follow docs/viewer.md, "Measures": tile latency is request issued -> page mapped.
#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <string>

#include "tessera/client/page.hpp"
#include "tessera/log_linear_histogram.hpp"

namespace tessera::client {

// Durations in a log-linear histogram at microsecond resolution: exact below 16 us, then 16
// linear buckets per power of two, so a bucket is at most 1/16 (6.25%) of its values wide.
// Values from 2^40 us (about 12 days) up land in the last bucket. 592 buckets, fixed size.
class LatencyHistogram : private LogLinearHistogram<4, 40> {
    using Counts = LogLinearHistogram<4, 40>;

public:
    static constexpr unsigned kSubBits = 4;
    static constexpr unsigned kMaxExp = 40;
    using Counts::kBuckets;
    using Counts::kSub;

    void record_us(std::uint64_t us) { Counts::record(us); }
    void record(std::chrono::nanoseconds d);  // rounded to the nearest microsecond; negative: 0
    void record_ms(double ms);                // negative or NaN: 0
    void merge(const LatencyHistogram& other) { Counts::merge(other); }
    void reset();

    using Counts::count;
    double mean_ms() const;  // exact (from the sum), 0 when empty
    double min_ms() const;   // exact, 0 when empty
    double max_ms() const;   // exact, 0 when empty
    // The q-quantile in milliseconds (q clamped to [0, 1]; nearest rank): the middle of the bucket
    // holding that sample, clamped to [min, max]; so within 3.2% of the true sample. 0 when empty.
    double quantile(double q) const;

    // Bucket arithmetic (public for tests and for exporting), in microseconds.
    using Counts::bucket_count;
    using Counts::bucket_low;
    using Counts::bucket_of;
    using Counts::bucket_width;
};

using LevelCounts = std::array<std::uint32_t, kMaxLevels>;

// One frame of the client runtime. Filled by the runtime once a frame.
struct FrameStats {
    std::uint64_t frame = 0;
    std::uint32_t pages_wanted = 0;     // unique pages in the frame's feedback, ancestors included
    std::uint32_t pages_resident = 0;   // mapped pages in the pool, pinned included
    std::uint32_t pages_requested = 0;  // new requests issued this frame (any source)
    std::uint32_t pages_arrived = 0;    // pages whose data arrived (RAM, disk or network)
    std::uint32_t pages_uploaded = 0;   // pages uploaded and mapped
    std::uint32_t pages_evicted = 0;    // pages unmapped to make room
    std::uint32_t pages_rescued = 0;    // pages fading out that the view wanted again: kept
    // Where requested pages were found, per level: RAM cache, disk cache, the network (a fetch
    // from the server; a "hit" of the last tier).
    LevelCounts ram_hits{};
    LevelCounts disk_hits{};
    LevelCounts network{};
    std::uint64_t bytes_received = 0;  // from the network (payload)
    std::uint64_t bytes_uploaded = 0;  // to the GPU
    float lod_bias = 0.0f;
    // Fraction of feedback pixels whose desired page is not resident: the runtime's estimate of
    // the fallback rate (the renderer counts the real one; docs/viewer.md, "Measures").
    float fallback_estimate = 0.0f;
    // Work skipped because a request stopped being wanted (docs/client.md, "Inside Runtime::frame",
    // step 3). Requests cancelled before their data arrived (waiting on the disk cache or the
    // source: if the source had not read it yet, its I/O is saved), after it arrived but before
    // decoding (never decoded), and after decoding but before upload; decode jobs the transcode
    // pool dropped unrun (stale by their turn); source deliveries for requests already cancelled
    // (I/O the cancellation came too late to save); deliveries of a page already arrived or
    // resident (a source that read it twice). Not in to_json/csv_row (their columns are fixed);
    // StatsSummary::to_json has them under "skipped".
    std::uint32_t cancelled_waiting = 0;
    std::uint32_t cancelled_arrived = 0;
    std::uint32_t cancelled_decoded = 0;
    std::uint32_t decodes_dropped = 0;
    std::uint32_t stale_arrivals = 0;
    std::uint32_t duplicate_arrivals = 0;
    // Tiles of another version of a texture's store (rebuilt and reloaded on its server): refused,
    // never mixed in (Runtime::texture_replaced).
    std::uint32_t other_version_arrivals = 0;
    // Tiles that arrived whole but did not decode (a payload its codec refuses): the page stands
    // absent, its parent shown, and is not asked for again.
    std::uint32_t decode_failures = 0;
    // Tiles the source answered with an error (data loss, not found, overloaded ...): each is
    // asked for again after a pause while still wanted. The first one's page and message.
    std::uint32_t source_errors = 0;
    std::string first_source_error;

    std::uint32_t total_ram_hits() const;
    std::uint32_t total_disk_hits() const;
    std::uint32_t total_network() const;

    // One JSON object. Per-level arrays run up to the highest level with any count (all three the
    // same length; empty when none).
    std::string to_json() const;
    // CSV: a header line and rows of the same columns (no newline at the end of either). The
    // per-level hits are summed per tier (ram_hits, disk_hits, network); to_json has them per level.
    static std::string csv_header();
    std::string csv_row() const;
};

// A summary across frames since construction or reset() (reset it to start a new window).
class StatsSummary {
public:
    void add_frame(const FrameStats& f);
    // One page mapped: its latency, request issued -> page mapped.
    void record_latency(std::chrono::nanoseconds request_to_mapped) { latency_.record(request_to_mapped); }
    // One page mapped: its time to detail in frames, from the first frame whose feedback wanted it
    // to the first frame drawn with it (docs/viewer.md, "Measures").
    void record_time_to_detail(std::uint64_t frames) { time_to_detail_.record(frames); }
    void reset();

    std::uint64_t frames() const { return frames_; }
    const LatencyHistogram& latency() const { return latency_; }
    // Time to detail, frames: count, mean, the q-quantile (nearest rank: the middle of its bucket,
    // exact below 16 frames, within 1/32 above, clamped to [min, max]; 0 when empty), max.
    std::uint64_t time_to_detail_count() const { return time_to_detail_.count(); }
    double time_to_detail_mean() const { return time_to_detail_.mean(); }
    double time_to_detail_quantile(double q) const;
    std::uint64_t time_to_detail_max() const { return time_to_detail_.max(); }
    std::uint64_t pages_requested() const { return requested_; }
    std::uint64_t pages_arrived() const { return arrived_; }
    std::uint64_t pages_uploaded() const { return uploaded_; }
    std::uint64_t pages_evicted() const { return evicted_; }
    std::uint64_t pages_rescued() const { return rescued_; }
    std::uint64_t bytes_received() const { return bytes_received_; }
    std::uint64_t bytes_uploaded() const { return bytes_uploaded_; }
    double mean_pages_wanted() const;
    double mean_pages_resident() const;
    double mean_lod_bias() const;
    float max_lod_bias() const { return bias_max_; }
    float last_lod_bias() const { return bias_last_; }
    double mean_fallback_estimate() const;
    std::uint64_t cancelled_waiting() const { return cancelled_waiting_; }
    std::uint64_t cancelled_arrived() const { return cancelled_arrived_; }
    std::uint64_t cancelled_decoded() const { return cancelled_decoded_; }
    std::uint64_t decodes_dropped() const { return decodes_dropped_; }
    std::uint64_t stale_arrivals() const { return stale_arrivals_; }
    std::uint64_t duplicate_arrivals() const { return duplicate_arrivals_; }
    std::uint64_t other_version_arrivals() const { return other_version_arrivals_; }
    std::uint64_t decode_failures() const { return decode_failures_; }
    std::uint64_t source_errors() const { return source_errors_; }
    // The first source error of the run ("level 3 (0, 0): DATA_LOSS <message>"), empty when none.
    const std::string& first_source_error() const { return first_source_error_; }
    const std::array<std::uint64_t, kMaxLevels>& ram_hits() const { return ram_hits_; }
    const std::array<std::uint64_t, kMaxLevels>& disk_hits() const { return disk_hits_; }
    const std::array<std::uint64_t, kMaxLevels>& network() const { return network_; }

    // One JSON object: frames, page totals and means, hits per level, bytes, latency (count, mean,
    // p50, p90, p99, max in ms), LoD bias (last, mean, max), mean fallback estimate, skipped work,
    // errors (tiles that did not decode).
    std::string to_json() const;

private:
    std::uint64_t frames_ = 0;
    std::uint64_t wanted_sum_ = 0, resident_sum_ = 0;
    std::uint64_t requested_ = 0, arrived_ = 0, uploaded_ = 0, evicted_ = 0, rescued_ = 0;
    std::array<std::uint64_t, kMaxLevels> ram_hits_{}, disk_hits_{}, network_{};
    std::uint64_t bytes_received_ = 0, bytes_uploaded_ = 0;
    double bias_sum_ = 0.0;
    float bias_max_ = 0.0f, bias_last_ = 0.0f;
    double fallback_sum_ = 0.0;
    std::uint64_t cancelled_waiting_ = 0, cancelled_arrived_ = 0, cancelled_decoded_ = 0, decodes_dropped_ = 0,
                  stale_arrivals_ = 0, duplicate_arrivals_ = 0, other_version_arrivals_ = 0, decode_failures_ = 0,
                  source_errors_ = 0;
    std::string first_source_error_;
    LatencyHistogram latency_;
    LogLinearHistogram<4, 32> time_to_detail_;
};

// The disk cache's own counts (Runtime::disk_cache): what it holds, and what it found or could not
// do (a full disk, a damaged entry), which per-level hits alone do not show.
struct DiskCacheCounts {
    std::uint64_t entries = 0, bytes = 0;  // held now; bytes of disk space (each entry's blocks)
    std::uint64_t hits = 0, writes = 0;
    std::uint64_t corrupt = 0;       // entries that failed verification: deleted, fetched again
    std::uint64_t write_errors = 0;  // writes the OS refused (a full disk, a folder gone, permissions)
    std::uint64_t write_drops = 0;   // writes dropped: the write queue was full
    std::uint64_t evictions = 0;     // entries deleted to keep within the size
};

}  // namespace tessera::client
