#pragma once
// Block pages decoded on the CPU exactly as a GPU samples them (tessera/blocks/blocks.hpp), for
// reference images that hold the same texels as a block-compressed atlas.
#include <cstdint>

#include "tessera/client/page.hpp"

namespace tessera::client {

// `blocks`: one page of `format` (bc1, bc4, bc5 or bc7), size x size texels (size a multiple of
// 4). `rgba` gets size*size RGBA8 texels as the GPU returns them: bc1 (r, g, b, 255) (a
// three-colour block's index 3 is (0, 0, 0, 0)), bc4 (r, 0, 0, 255), bc5 (r, g, 0, 255), bc7
// (r, g, b, a). False for any other format.
bool decode_block_page(PageFormat format, const std::uint8_t* blocks, std::uint32_t size, std::uint8_t* rgba);

}  // namespace tessera::client
