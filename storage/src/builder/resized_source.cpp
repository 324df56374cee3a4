// make_resized_source() (atlas.hpp): a map resampled to the size of the cell it shares with a
// colour texture. Separable: rows first into a float buffer of the output's width, then columns.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "samples.hpp"
#include "tessera/storage/atlas.hpp"

namespace tessera::storage {
namespace {

constexpr std::uint64_t kMaxResizedTexels = std::uint64_t(1) << 24;  // 256 MiB of float RGBA rows at most

// One axis: for output texel o of `out` texels over `in`, the input texels it reads and their
// weights. Shrinking: the input texels under the output texel's footprint, each by its overlap.
// Growing: the two nearest texel centres, bilinear, clamped at the edges.
struct Taps {
    std::vector<std::uint32_t> first, count;  // per output texel
    std::vector<float> weights;               // count[o] weights from offset[o]
    std::vector<std::size_t> offset;
};

Taps make_taps(std::uint32_t in, std::uint32_t out) {
    Taps t;
    t.first.resize(out);
    t.count.resize(out);
    t.offset.resize(out);
    const double scale = double(in) / out;
    for (std::uint32_t o = 0; o < out; ++o) {
        t.offset[o] = t.weights.size();
        if (in > out) {
            const double a = o * scale, b = (o + 1) * scale;
            const auto i0 = static_cast<std::uint32_t>(std::floor(a));
            const auto i1 = std::min(in, static_cast<std::uint32_t>(std::ceil(b)));
            t.first[o] = i0;
            t.count[o] = i1 - i0;
            for (std::uint32_t i = i0; i < i1; ++i)
                t.weights.push_back(static_cast<float>((std::min(b, double(i + 1)) - std::max(a, double(i))) / scale));
        } else {
            const double c = (o + 0.5) * scale - 0.5;
            const double f = std::floor(c);
            const double w = c - f;
            const auto lo = static_cast<std::int64_t>(f);
            const auto i0 = static_cast<std::uint32_t>(std::clamp<std::int64_t>(lo, 0, in - 1));
            const auto i1 = static_cast<std::uint32_t>(std::clamp<std::int64_t>(lo + 1, 0, in - 1));
            t.first[o] = i0;
            if (i1 == i0) {
                t.count[o] = 1;
                t.weights.push_back(1.0f);
            } else {
                t.count[o] = 2;
                t.weights.push_back(static_cast<float>(1 - w));
                t.weights.push_back(static_cast<float>(w));
            }
        }
    }
    return t;
}

class ResizedSource final : public ImageSource {
public:
    ResizedSource(std::unique_ptr<ImageSource> source, std::uint32_t width, std::uint32_t height) : source_(std::move(source)) {
        const SourceInfo& si = source_->info();
        info_ = si;
        info_.width = width;
        info_.height = height;
        info_.sample_type = SampleType::f32;
        info_.description = si.description + " resized to " + std::to_string(width) + "x" + std::to_string(height);
    }
    const SourceInfo& info() const override { return info_; }

    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const ParallelFor& parallel) override {
        if (rows_.empty()) TESSERA_TRY(resample_rows(parallel));
        const std::uint32_t c = info_.channels;
        const Taps& ty = taps_y_;
        for (std::uint32_t k = 0; k < count; ++k) {
            const std::uint32_t y = y0 + k;
            float* out = reinterpret_cast<float*>(dst) + std::size_t(k) * info_.width * c;
            std::fill(out, out + std::size_t(info_.width) * c, 0.0f);
            for (std::uint32_t j = 0; j < ty.count[y]; ++j) {
                const float w = ty.weights[ty.offset[y] + j];
                const float* row = rows_.data() + std::size_t(ty.first[y] + j) * info_.width * c;
                for (std::size_t i = 0; i < std::size_t(info_.width) * c; ++i) out[i] += w * row[i];
            }
        }
        return {};
    }

private:
    // The whole source, each row resampled to the output's width.
    Status resample_rows(const ParallelFor& parallel) {
        const SourceInfo& si = source_->info();
        const std::uint32_t c = si.channels;
        const std::size_t sb = sample_bytes(si.sample_type), in_row = std::size_t(si.width) * c * sb;
        const Taps tx = make_taps(si.width, info_.width);
        taps_y_ = make_taps(si.height, info_.height);
        rows_.assign(std::size_t(si.height) * info_.width * c, 0.0f);
        std::vector<std::uint8_t> strip;
        constexpr std::uint32_t kStrip = 64;
        for (std::uint32_t y0 = 0; y0 < si.height; y0 += kStrip) {
            const std::uint32_t n = std::min(kStrip, si.height - y0);
            strip.resize(in_row * n);
            TESSERA_TRY(source_->read_rows(y0, n, strip.data(), parallel));
            for (std::uint32_t y = 0; y < n; ++y) {
                const std::uint8_t* in = strip.data() + y * in_row;
                float* out = rows_.data() + std::size_t(y0 + y) * info_.width * c;
                for (std::uint32_t o = 0; o < info_.width; ++o)
                    for (std::uint32_t j = 0; j < tx.count[o]; ++j) {
                        const float w = tx.weights[tx.offset[o] + j];
                        const std::uint8_t* texel = in + std::size_t(tx.first[o] + j) * c * sb;
                        for (std::uint32_t ch = 0; ch < c; ++ch) out[std::size_t(o) * c + ch] += w * build::sample_value(texel + ch * sb, si.sample_type);
                    }
            }
        }
        source_.reset();
        return {};
    }

    std::unique_ptr<ImageSource> source_;
    SourceInfo info_;
    Taps taps_y_;
    std::vector<float> rows_;  // source height x output width x channels
};

}  // namespace

Result<std::unique_ptr<ImageSource>> make_resized_source(std::unique_ptr<ImageSource> source, std::uint32_t width,
                                                         std::uint32_t height) {
    if (!source) return make_error(Errc::invalid_argument, "resize: no source");
    const SourceInfo& si = source->info();
    if (width == 0 || height == 0 || si.width == 0 || si.height == 0)
        return make_error(Errc::invalid_argument, "resize: " + si.description + ": a size of zero");
    if (std::uint64_t(si.height) * std::max(width, si.width) > kMaxResizedTexels ||
        std::uint64_t(width) * height > kMaxResizedTexels)
        return make_error(Errc::unsupported, "resize: " + si.description + " (" + std::to_string(si.width) + "x" +
                                                 std::to_string(si.height) + " to " + std::to_string(width) + "x" +
                                                 std::to_string(height) + ") is beyond 2^24 texels");
    return std::unique_ptr<ImageSource>(new ResizedSource(std::move(source), width, height));
}

}  // namespace tessera::storage
