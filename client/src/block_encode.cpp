#include "block_encode.hpp"

#include <stb_dxt.h>

#include <cstring>

namespace tessera::client {

namespace {

// Visits every 4x4 block, row of blocks by row of blocks, with the block's 16 texels gathered
// into `block` (RGBA8, row-major).
template <class Encode>
void for_each_block(const std::uint8_t* rgba, std::uint32_t size, Encode&& encode) {
    std::uint8_t block[16 * 4];
    const std::size_t row_bytes = std::size_t(size) * 4;
    for (std::uint32_t by = 0; by < size; by += 4)
        for (std::uint32_t bx = 0; bx < size; bx += 4) {
            const std::uint8_t* src = rgba + by * row_bytes + std::size_t(bx) * 4;
            for (int r = 0; r < 4; ++r) std::memcpy(block + r * 16, src + r * row_bytes, 16);
            encode(block);
        }
}

}  // namespace

void encode_bc1(const std::uint8_t* rgba, std::uint32_t size, std::uint8_t* out) {
    for_each_block(rgba, size, [&](const std::uint8_t* block) {
        stb_compress_dxt_block(out, block, 0, STB_DXT_HIGHQUAL);
        out += 8;
    });
}

void encode_bc4(const std::uint8_t* rgba, std::uint32_t size, unsigned channel, std::uint8_t* out) {
    std::uint8_t one[16];
    for_each_block(rgba, size, [&](const std::uint8_t* block) {
        for (int i = 0; i < 16; ++i) one[i] = block[i * 4 + channel];
        stb_compress_bc4_block(out, one);
        out += 8;
    });
}

void encode_bc5(const std::uint8_t* rgba, std::uint32_t size, unsigned c0, unsigned c1, std::uint8_t* out) {
    std::uint8_t two[32];
    for_each_block(rgba, size, [&](const std::uint8_t* block) {
        for (int i = 0; i < 16; ++i) {
            two[2 * i] = block[i * 4 + c0];
            two[2 * i + 1] = block[i * 4 + c1];
        }
        stb_compress_bc5_block(out, two);
        out += 16;
    });
}

}  // namespace tessera::client
