#pragma once
// An independent, deliberately plain implementation of the store's mip and tile definitions
// (docs/store-format.md, "Mip levels" and "Tiles"): whole levels in memory, one texel at a time,
// straight from the formulas. Tests compare the builder's tiles against it.
#include <cstdint>
#include <vector>

#include "tessera/storage/types.hpp"

namespace tessera::test {

struct RefImage {
    std::uint32_t width = 0, height = 0, channels = 0;
    storage::SampleType type = storage::SampleType::u8;
    std::vector<std::uint8_t> bytes;  // row-major, interleaved, native samples
    std::size_t texel_bytes() const { return channels * storage::sample_bytes(type); }
};

// Plain IEEE half conversions, independent of the builder's (round to nearest, ties to even).
float from_half(std::uint16_t h);
std::uint16_t to_half(float f);

// Level 0 is `base`; each next level halves (rounding up) until it fits in one tile of `payload`.
std::vector<RefImage> reference_pyramid(const RefImage& base, storage::ColourSpace cs, bool has_alpha, std::uint32_t payload);

// The stored texels of tile (x, y) of `level`: [x*P - B, (x+1)*P + B) squared, edge-clamped.
std::vector<std::uint8_t> reference_tile(const RefImage& level, std::uint32_t payload, std::uint32_t border, std::uint32_t x,
                                         std::uint32_t y);

}  // namespace tessera::test
