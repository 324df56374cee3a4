// The terrain's height and normal layers. Like the colour, the samples must be bit-identical on
// every machine: no a*b+c may be fused into an FMA (see procedural_terrain.cpp). The pragma goes
// before every include.
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif

#include "procedural_layers.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "procedural_terrain.hpp"

namespace tessera::storage::build {

std::uint16_t terrain_height_sample(float h) {
    const float v = std::clamp(h, -1.0f, 1.0f);
    return static_cast<std::uint16_t>(std::floor((v + 1.0f) * 32767.5f + 0.5f));
}

std::uint8_t terrain_normal_sample(float c) {
    const float v = std::clamp(c, -1.0f, 1.0f);
    return static_cast<std::uint8_t>(std::floor((v + 1.0f) * 127.5f + 0.5f));
}

namespace {

SourceInfo layer_info(std::uint32_t size, std::uint32_t channels, SampleType type, const char* what) {
    SourceInfo info;
    info.width = info.height = size;
    info.channels = channels;
    info.sample_type = type;
    info.colour_space = ColourSpace::linear;  // data, not colour: mips average the values as they are
    info.description = std::string("procedural terrain ") + what + " " + std::to_string(size) + "x" + std::to_string(size);
    return info;
}

class HeightSource final : public ImageSource {
public:
    explicit HeightSource(std::uint32_t size) : terrain_(size), info_(layer_info(size, 1, SampleType::u16, "height")) {}
    const SourceInfo& info() const override { return info_; }
    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const ParallelFor& parallel) override {
        const std::size_t w = info_.width;
        parallel(count, [&](std::size_t b, std::size_t e) {
            std::vector<float> h(w);
            for (std::size_t i = b; i < e; ++i) {
                terrain_.height_row(y0 + i, h.data());
                std::uint8_t* row = dst + i * w * 2;
                for (std::size_t x = 0; x < w; ++x) {
                    const std::uint16_t v = terrain_height_sample(h[x]);
                    std::memcpy(row + 2 * x, &v, 2);  // little-endian, as the format is
                }
            }
        });
        return {};
    }

private:
    ProceduralTerrain terrain_;
    SourceInfo info_;
};

// Normals by central differences of the height field at the level-0 texel spacing (one-sided at
// the image's edges). A row needs the heights of its neighbours above and below: rows are made in
// bands, each band's heights computed once and the last two kept for the next band.
class NormalSource final : public ImageSource {
public:
    explicit NormalSource(std::uint32_t size)
        : terrain_(size), info_(layer_info(size, 2, SampleType::u8, "normal")),
          scale_(static_cast<float>(size) * kTerrainReliefPerSize) {}
    const SourceInfo& info() const override { return info_; }

    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const ParallelFor& parallel) override {
        const std::uint32_t size = info_.height;
        const std::size_t w = info_.width;
        for (std::uint32_t band = y0; band < y0 + count; band += kBand) {
            const std::uint32_t n = std::min(kBand, y0 + count - band);
            hold(band > 0 ? band - 1 : 0, std::min(band + n, size - 1), parallel);
            parallel(n, [&](std::size_t b, std::size_t e) {
                for (std::size_t i = b; i < e; ++i) {
                    const std::uint32_t y = band + static_cast<std::uint32_t>(i);
                    const std::uint32_t up = y > 0 ? y - 1 : 0, down = std::min(y + 1, size - 1);
                    normal_row(held(up), held(y), held(down), static_cast<float>(down - up),
                               dst + std::size_t(y - y0) * w * 2);
                }
            });
        }
        return {};
    }

private:
    static constexpr std::uint32_t kBand = 16;

    const float* held(std::uint32_t y) const { return rows_.data() + std::size_t(y - first_) * info_.width; }

    // Makes the heights of rows [a, b] held, keeping those already held.
    void hold(std::uint32_t a, std::uint32_t b, const ParallelFor& parallel) {
        const std::size_t w = info_.width;
        rows_.resize(std::size_t(kBand + 2) * w);
        std::uint32_t kept = 0;
        if (held_ > 0 && a >= first_ && a < first_ + held_) {
            kept = std::min(first_ + held_ - a, b - a + 1);
            std::memmove(rows_.data(), rows_.data() + std::size_t(a - first_) * w, std::size_t(kept) * w * sizeof(float));
        }
        first_ = a;
        held_ = b - a + 1;
        parallel(held_ - kept, [&](std::size_t i0, std::size_t i1) {
            for (std::size_t i = i0; i < i1; ++i)
                terrain_.height_row(a + kept + i, rows_.data() + (kept + i) * w);
        });
    }

    void normal_row(const float* above, const float* row, const float* below, float dy, std::uint8_t* out) const {
        const std::size_t w = info_.width;
        for (std::size_t x = 0; x < w; ++x) {
            const std::size_t l = x > 0 ? x - 1 : 0, r = std::min(x + 1, w - 1);
            // Slopes in level-0 texels of height per texel; 0 across a one-texel image.
            const float sx = r > l ? (row[r] - row[l]) * scale_ / static_cast<float>(r - l) : 0.0f;
            const float sy = dy > 0 ? (below[x] - above[x]) * scale_ / dy : 0.0f;
            const float inv = 1.0f / std::sqrt(sx * sx + sy * sy + 1.0f);
            out[2 * x] = terrain_normal_sample(-sx * inv);
            out[2 * x + 1] = terrain_normal_sample(-sy * inv);
        }
    }

    ProceduralTerrain terrain_;
    SourceInfo info_;
    float scale_;
    std::vector<float> rows_;  // heights of rows [first_, first_ + held_), allocated on first use
    std::uint32_t first_ = 0, held_ = 0;
};

}  // namespace

std::unique_ptr<ImageSource> make_terrain_height_source(std::uint32_t size) { return std::make_unique<HeightSource>(size); }
std::unique_ptr<ImageSource> make_terrain_normal_source(std::uint32_t size) { return std::make_unique<NormalSource>(size); }

}  // namespace tessera::storage::build
