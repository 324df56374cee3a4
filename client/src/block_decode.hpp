#pragma once
// Decoding of BC1, BC4 and BC5 pages on the CPU, as a GPU samples them (the block formats' own
// definitions: endpoints expanded by bit replication, BC1's 1/3 and 2/3 points rounded to
// nearest), for reference images that hold the same texels as a block-compressed atlas.
#include <cstdint>

#include "tessera/client/page.hpp"

namespace tessera::client {

// `blocks`: one page of `format` (bc1, bc4 or bc5), size x size texels (size a multiple of 4),
// rows of blocks as encode_bc* write them. `rgba` gets size*size RGBA8 texels as the GPU returns
// them: bc1 (r, g, b, 255) (four-colour blocks; a three-colour block's index 3 is (0, 0, 0, 0)),
// bc4 (r, 0, 0, 255), bc5 (r, g, 0, 255). False for any other format.
bool decode_block_page(PageFormat format, const std::uint8_t* blocks, std::uint32_t size, std::uint8_t* rgba);

}  // namespace tessera::client
