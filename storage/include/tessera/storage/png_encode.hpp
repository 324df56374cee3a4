#pragma once
// PNG encoding of texels: the server's `?format=png` tiles and the viewer's frames. One IDAT
// chunk, deflate at a fast level, every row with filter type 1 (Sub); no library beyond zlib.
#include <cstdint>
#include <span>
#include <vector>

#include "tessera/result.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::storage {

struct PngImage {
    std::uint32_t width = 0, height = 0;
    std::uint32_t channels = 0;  // 1..4: grey, grey + alpha, RGB, RGBA (alpha straight)
    SampleType sample_type = SampleType::u8;
    ColourSpace colour_space = ColourSpace::srgb;
    std::span<const std::uint8_t> texels;  // rows top to bottom, interleaved, native byte order
};

// u8 samples give bit depth 8, u16 bit depth 16 (big endian in the file, as PNG requires). sRGB
// gets an sRGB chunk, linear a gAMA of 1.0. Errors: unsupported (f16/f32: PNG has no float
// type), invalid_argument (texels of the wrong size, channels outside 1..4, a zero or
// over-large size).
Result<std::vector<std::uint8_t>> encode_png(const PngImage& image);

// A decoded tile (info.tile_size()^2 texels, as decode_tile gives it) as PNG.
Result<std::vector<std::uint8_t>> encode_tile_png(const StoreInfo& info, std::span<const std::uint8_t> texels);

}  // namespace tessera::storage
