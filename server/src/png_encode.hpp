#pragma once
// PNG encoding of a decoded tile, for HTTP `?format=png` (browsers, debugging, map viewers).
// One IDAT chunk, deflate at a fast level, every row with filter type 1 (Sub).
#include <cstdint>
#include <span>
#include <vector>

#include "tessera/result.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::server {

// Encodes a decoded tile (info.tile_size()^2 texels, as storage::decode_tile gives it) as PNG.
// Channels 1..4 become grey, grey + alpha, RGB and RGBA (2 channels are always written as grey +
// alpha: PNG has no other two-channel type). u8 samples give bit depth 8, u16 bit depth 16 (big
// endian in the file, as PNG requires). An sRGB store gets an sRGB chunk, a linear one gAMA 1.0.
// Errors: unsupported (f16/f32 samples: PNG has no float type), invalid_argument (texels of the
// wrong size, channels outside 1..4).
Result<std::vector<std::uint8_t>> encode_png(const storage::StoreInfo& info, std::span<const std::uint8_t> texels);

}  // namespace tessera::server
