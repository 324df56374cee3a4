#pragma once
// GPU block formats shared by the store builder (blocks made once, quality first) and the client's
// transcode threads (blocks made per page, in real time): BC1 (opaque colour), BC4 (one channel),
// BC5 (two channels) and BC7 (colour with or without alpha; bc7.hpp). A page is size x size texels,
// size a multiple of 4, RGBA8 row-major; its blocks go row of blocks by row of blocks, each block's
// bytes as the GPU reads them (the layout glCompressedTexSubImage2D takes).
#include <cstddef>
#include <cstdint>
#include <string_view>

namespace tessera::blocks {

enum class BlockFormat : std::uint8_t { bc1, bc4, bc5, bc7 };
std::string_view to_string(BlockFormat f);  // "bc1", "bc4", "bc5", "bc7"

constexpr std::size_t block_bytes(BlockFormat f) { return f == BlockFormat::bc1 || f == BlockFormat::bc4 ? 8 : 16; }
// Bytes of the blocks of a size x size page.
constexpr std::size_t page_block_bytes(BlockFormat f, std::uint32_t size) {
    return std::size_t(size / 4) * (size / 4) * block_bytes(f);
}

// How hard an encoder tries. realtime: BC1 by bounding box with inset (van Waveren, "Real-Time DXT
// Compression", 2006), BC7 at effort 0; best: BC1 by stb_dxt's refined mode, BC7 at the builder's
// effort. BC4 and BC5 (stb_dxt) are the same either way.
enum class Effort : std::uint8_t { realtime, best };

// Which RGBA8 channels a one- or two-channel format encodes (bc4: c0; bc5: c0 and c1).
struct Channels {
    unsigned c0 = 0;
    unsigned c1 = 1;
};

// Encodes an RGBA8 page into page_block_bytes(f, size) bytes. Thread-safe.
void encode_page(BlockFormat f, const std::uint8_t* rgba, std::uint32_t size, std::uint8_t* out,
                 Effort effort = Effort::realtime, Channels channels = {});

// Decodes blocks into size x size RGBA8 texels, exactly as a GPU samples them (the formats' own
// definitions: endpoints by bit replication, BC1's 1/3 and 2/3 points rounded to nearest):
// bc1 (r, g, b, 255) (a three-colour block's index 3 is (0, 0, 0, 0)), bc4 (r, 0, 0, 255),
// bc5 (r, g, 0, 255), bc7 (r, g, b, a).
void decode_page(BlockFormat f, const std::uint8_t* blocks, std::uint32_t size, std::uint8_t* rgba);

// The 2x2 means of a side x side RGBA8 page (side even), rounded to nearest, into (side/2)^2
// texels: the next level down of a page, as the GPU's trilinear filter reads it. With `srgb` the
// colour channels are averaged in linear light (alpha never), as the builder makes a store's
// levels.
void half_size_rgba8(const std::uint8_t* src, std::uint32_t side, bool srgb, std::uint8_t* dst);

}  // namespace tessera::blocks
