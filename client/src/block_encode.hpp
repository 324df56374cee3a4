#pragma once
// Block compression of decoded pages on the transcode threads (the client-transcode route of
// docs/client.md, "Page formats"): an RGBA8 page becomes BC1, BC4 or BC5 blocks (BC1 by a
// published real-time encoder, BC4/BC5 with stb_dxt). Blocks are written row of blocks by row of blocks, each block's
// bytes as the GPU reads them (the layout glCompressedTexSubImage2D takes).
#include <cstdint>

namespace tessera::client {

// `rgba` holds size x size RGBA8 texels (size a multiple of 4); `out` size*size/2 bytes. Real time:
// bounding box with inset (van Waveren 2006); stb_dxt's high-quality mode is 2x slower per page
// (docs/benchmarks.md, "JPEG -> BC1 pages").
void encode_bc1(const std::uint8_t* rgba, std::uint32_t size, std::uint8_t* out);
// One channel (`channel` of each RGBA8 texel): size*size/2 bytes.
void encode_bc4(const std::uint8_t* rgba, std::uint32_t size, unsigned channel, std::uint8_t* out);
// Two channels (`c0`, `c1` of each RGBA8 texel): size*size bytes.
void encode_bc5(const std::uint8_t* rgba, std::uint32_t size, unsigned c0, unsigned c1, std::uint8_t* out);

}  // namespace tessera::client
