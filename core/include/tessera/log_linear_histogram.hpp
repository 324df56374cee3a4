#pragma once
// Counts of unsigned values (latencies in some unit) in log-linear buckets, HdrHistogram style:
// exact below 2^SubBits, then 2^SubBits linear buckets per power of two, so a bucket is at most
// 2^-SubBits of its lowest value wide. Values from 2^MaxExp up land in the last bucket. Fixed
// size, no allocation, not thread-safe (one per thread, merged). The client's LatencyHistogram
// and the load generator (bench/serve_load) each read quantiles from it in their own way.
#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>

namespace tessera {

template <unsigned SubBits, unsigned MaxExp>
class LogLinearHistogram {
public:
    static_assert(SubBits >= 1 && SubBits < MaxExp && MaxExp <= 64);
    static constexpr std::uint64_t kSub = std::uint64_t{1} << SubBits;
    static constexpr std::size_t kBuckets = kSub + (MaxExp - SubBits) * kSub;

    static std::size_t bucket_of(std::uint64_t v) {
        if (v < kSub) return static_cast<std::size_t>(v);
        if constexpr (MaxExp < 64) v = std::min(v, (std::uint64_t{1} << MaxExp) - 1);
        const unsigned shift = static_cast<unsigned>(std::bit_width(v)) - 1 - SubBits;
        return static_cast<std::size_t>(shift * kSub + (v >> shift));
    }
    static std::uint64_t bucket_low(std::size_t bucket) {  // the smallest value in the bucket
        if (bucket < kSub) return bucket;
        return (kSub + (bucket - kSub) % kSub) << ((bucket - kSub) / kSub);
    }
    static std::uint64_t bucket_width(std::size_t bucket) {
        return bucket < kSub ? 1 : std::uint64_t{1} << ((bucket - kSub) / kSub);
    }
    static std::uint64_t bucket_high(std::size_t bucket) {  // the largest value in the bucket
        return bucket_low(bucket) + (bucket_width(bucket) - 1);
    }

    void record(std::uint64_t v) {
        ++counts_[bucket_of(v)];
        if (count_ == 0) {
            min_ = max_ = v;
        } else {
            min_ = std::min(min_, v);
            max_ = std::max(max_, v);
        }
        ++count_;
        sum_ += v;
    }
    void merge(const LogLinearHistogram& other) {
        if (other.count_ == 0) return;
        for (std::size_t i = 0; i < kBuckets; ++i) counts_[i] += other.counts_[i];
        if (count_ == 0) {
            min_ = other.min_;
            max_ = other.max_;
        } else {
            min_ = std::min(min_, other.min_);
            max_ = std::max(max_, other.max_);
        }
        count_ += other.count_;
        sum_ += other.sum_;
    }

    std::uint64_t count() const { return count_; }
    std::uint64_t sum() const { return sum_; }
    std::uint64_t min() const { return min_; }  // exact; 0 when empty
    std::uint64_t max() const { return max_; }  // exact; 0 when empty
    double mean() const { return count_ == 0 ? 0.0 : static_cast<double>(sum_) / static_cast<double>(count_); }
    std::uint64_t bucket_count(std::size_t bucket) const { return counts_[bucket]; }

    // The bucket holding the nearest-rank q-quantile: the k-th smallest value, k = ceil(q * count),
    // at least 1 (the last bucket for k past the count). Meaningful when count() > 0.
    std::size_t quantile_bucket(double q) const {
        const auto k = std::max<std::uint64_t>(1, static_cast<std::uint64_t>(std::ceil(q * static_cast<double>(count_))));
        std::uint64_t seen = 0;
        for (std::size_t b = 0; b < kBuckets; ++b) {
            seen += counts_[b];
            if (seen >= k) return b;
        }
        return kBuckets - 1;
    }

    // The nearest-rank q-quantile as a value: the middle of the bucket holding it (exact below
    // kSub), clamped to [min, max]; q <= 0 gives min, q >= 1 max; 0 when empty.
    double quantile_value(double q) const {
        if (count_ == 0) return 0.0;
        if (!(q > 0.0)) return static_cast<double>(min_);
        if (q >= 1.0) return static_cast<double>(max_);
        const std::size_t b = quantile_bucket(q);
        double mid = static_cast<double>(bucket_low(b));
        if (b >= kSub) mid += 0.5 * static_cast<double>(bucket_width(b));
        return std::clamp(mid, static_cast<double>(min_), static_cast<double>(max_));
    }

private:
    std::array<std::uint64_t, kBuckets> counts_{};
    std::uint64_t count_ = 0;
    std::uint64_t sum_ = 0;
    std::uint64_t min_ = 0;
    std::uint64_t max_ = 0;
};

}  // namespace tessera
