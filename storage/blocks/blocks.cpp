#include "tessera/blocks/blocks.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <vector>

#include "block_codecs.hpp"
#include "tessera/blocks/bc7.hpp"

namespace tessera::blocks {

std::string_view to_string(BlockFormat f) {
    switch (f) {
        case BlockFormat::bc1: return "bc1";
        case BlockFormat::bc4: return "bc4";
        case BlockFormat::bc5: return "bc5";
        case BlockFormat::bc7: return "bc7";
    }
    return "unknown";
}

void encode_page(BlockFormat f, const std::uint8_t* rgba, std::uint32_t size, std::uint8_t* out, Effort effort,
                 Channels channels) {
    switch (f) {
        case BlockFormat::bc1: return encode_bc1(rgba, size, out, effort);
        case BlockFormat::bc4: return encode_bc4(rgba, size, channels.c0, out);
        case BlockFormat::bc5: return encode_bc5(rgba, size, channels.c0, channels.c1, out);
        case BlockFormat::bc7: {
            Bc7Options options;
            if (effort == Effort::realtime) options.effort = 0;
            return encode_bc7(rgba, size, out, options);
        }
    }
}

void decode_page(BlockFormat f, const std::uint8_t* blocks, std::uint32_t size, std::uint8_t* rgba) {
    switch (f) {
        case BlockFormat::bc1: return decode_bc1(blocks, size, rgba);
        case BlockFormat::bc4: return decode_bc4(blocks, size, rgba);
        case BlockFormat::bc5: return decode_bc5(blocks, size, rgba);
        case BlockFormat::bc7: return decode_bc7(blocks, size, rgba);
    }
}

namespace {

// sRGB-encoded 8-bit values to linear light in 16 bits, and back (every 16-bit linear value to
// the nearest sRGB code): tables made once.
const std::array<std::uint16_t, 256>& srgb8_to_linear16() {
    static const auto table = [] {
        std::array<std::uint16_t, 256> t{};
        for (int i = 0; i < 256; ++i) {
            const double v = i / 255.0;
            const double l = v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4);
            t[std::size_t(i)] = static_cast<std::uint16_t>(std::lround(l * 65535.0));
        }
        return t;
    }();
    return table;
}
const std::vector<std::uint8_t>& linear16_to_srgb8() {
    static const auto table = [] {
        std::vector<std::uint8_t> t(65536);
        for (std::size_t i = 0; i < t.size(); ++i) {
            const double l = double(i) / 65535.0;
            const double v = l <= 0.0031308 ? l * 12.92 : 1.055 * std::pow(l, 1.0 / 2.4) - 0.055;
            t[i] = static_cast<std::uint8_t>(std::lround(std::clamp(v, 0.0, 1.0) * 255.0));
        }
        return t;
    }();
    return table;
}

}  // namespace

// Colour of an sRGB page is averaged in linear light, as the builder makes the store's next level
// (storage's MipReducer) and the GPU page-mip pass averages RGBA8 pages; data and alpha in their
// stored values.
void half_size_rgba8(const std::uint8_t* src, std::uint32_t side, bool srgb, std::uint8_t* dst) {
    const std::uint32_t half = side / 2;
    const std::size_t row = std::size_t(side) * 4;
    const auto& to_linear = srgb8_to_linear16();
    const auto& to_srgb = linear16_to_srgb8();
    for (std::uint32_t y = 0; y < half; ++y) {
        const std::uint8_t* a = src + std::size_t(2 * y) * row;
        const std::uint8_t* b = a + row;
        std::uint8_t* d = dst + std::size_t(y) * half * 4;
        for (std::uint32_t x = 0; x < half; ++x)
            for (std::size_t c = 0; c < 4; ++c) {
                const std::size_t i = std::size_t(8) * x + c;
                if (srgb && c < 3) {
                    const unsigned sum = unsigned(to_linear[a[i]]) + to_linear[a[i + 4]] + to_linear[b[i]] + to_linear[b[i + 4]];
                    d[4 * x + c] = to_srgb[(sum + 2) / 4];
                } else {
                    d[4 * x + c] = static_cast<std::uint8_t>((unsigned(a[i]) + a[i + 4] + b[i] + b[i + 4] + 2) / 4);
                }
            }
    }
}


}  // namespace tessera::blocks
