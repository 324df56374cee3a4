#include "block_decode.hpp"

#include "tessera/blocks/blocks.hpp"
#include "transcode.hpp"

namespace tessera::client {

bool decode_block_page(PageFormat format, const std::uint8_t* blocks, std::uint32_t size, std::uint8_t* rgba) {
    const std::optional<blocks::BlockFormat> f = block_format_of(format);
    if (!f || size % 4 != 0) return false;
    blocks::decode_page(*f, blocks, size, rgba);
    return true;
}

}  // namespace tessera::client
