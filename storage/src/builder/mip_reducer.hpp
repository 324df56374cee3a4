#pragma once
// One mip step: two rows of level L become one row of level L+1 (2x2 box, edge-clamped).
// Colour is averaged in linear light (sRGB decoded first) and weighted by alpha; data and alpha
// channels of integer stores are averaged exactly in integers. docs/store-format.md states the
// exact arithmetic, so an independent implementation reproduces the same bytes.
#include <array>
#include <cstdint>
#include <vector>

#include "tessera/storage/types.hpp"

namespace tessera::storage::build {

class MipReducer {
public:
    MipReducer(std::uint32_t channels, SampleType type, ColourSpace colour_space, bool has_alpha);

    // row0/row1: `in_width` texels each (row1 == row0 for the last row of an odd height).
    // out: ceil(in_width / 2) texels.
    void reduce(const std::uint8_t* row0, const std::uint8_t* row1, std::uint32_t in_width, std::uint8_t* out) const;

private:
    template <class T>
    void reduce_int(const T* r0, const T* r1, std::uint32_t w, T* out) const;
    template <class T>
    void reduce_float(const T* r0, const T* r1, std::uint32_t w, T* out) const;
    std::uint8_t encode_srgb8(float v) const;

    std::uint32_t channels_;
    SampleType type_;
    bool srgb_;
    bool has_alpha_;
    std::vector<float> decode_lut_;          // integer sRGB stores: sample value -> linear
    std::array<double, 255> thresholds8_{};  // u8 sRGB: linear value where code i+1 begins
    std::vector<std::uint8_t> bucket8_;      // u8 sRGB: first candidate code per linear bucket
};

}  // namespace tessera::storage::build
