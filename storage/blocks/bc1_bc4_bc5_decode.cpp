// BC1, BC4 and BC5 decoding as a GPU samples them (the formats' own definitions).
#include "block_codecs.hpp"

#include <array>
#include <cstddef>

namespace tessera::blocks {

namespace {

using Texel = std::array<std::uint8_t, 4>;

// One BC1 block's 16 texels.
void decode_bc1_block(const std::uint8_t* b, std::array<Texel, 16>& out) {
    const unsigned c0 = b[0] | (b[1] << 8), c1 = b[2] | (b[3] << 8);
    const auto expand = [](unsigned c) {
        const unsigned r = c >> 11, g = (c >> 5) & 63, bl = c & 31;
        return std::array<int, 3>{int((r << 3) | (r >> 2)), int((g << 2) | (g >> 4)), int((bl << 3) | (bl >> 2))};
    };
    const auto e0 = expand(c0), e1 = expand(c1);
    std::array<Texel, 4> palette{};
    for (int k = 0; k < 3; ++k) {
        palette[0][k] = std::uint8_t(e0[k]);
        palette[1][k] = std::uint8_t(e1[k]);
        if (c0 > c1) {
            palette[2][k] = std::uint8_t((2 * e0[k] + e1[k] + 1) / 3);
            palette[3][k] = std::uint8_t((e0[k] + 2 * e1[k] + 1) / 3);
        } else {
            palette[2][k] = std::uint8_t((e0[k] + e1[k] + 1) / 2);
            palette[3][k] = 0;
        }
    }
    palette[0][3] = palette[1][3] = palette[2][3] = 255;
    palette[3][3] = c0 > c1 ? 255 : 0;
    const std::uint32_t indices = b[4] | (b[5] << 8) | (b[6] << 16) | (std::uint32_t(b[7]) << 24);
    for (int i = 0; i < 16; ++i) out[std::size_t(i)] = palette[(indices >> (2 * i)) & 3];
}

// One BC4 block's 16 values.
void decode_bc4_block(const std::uint8_t* b, std::array<std::uint8_t, 16>& out) {
    const int a0 = b[0], a1 = b[1];
    std::array<int, 8> v{a0, a1};
    if (a0 > a1) {
        for (int k = 1; k < 7; ++k) v[std::size_t(k + 1)] = ((7 - k) * a0 + k * a1 + 3) / 7;
    } else {
        for (int k = 1; k < 5; ++k) v[std::size_t(k + 1)] = ((5 - k) * a0 + k * a1 + 2) / 5;
        v[6] = 0;
        v[7] = 255;
    }
    std::uint64_t bits = 0;
    for (int i = 0; i < 6; ++i) bits |= std::uint64_t(b[2 + i]) << (8 * i);
    for (int i = 0; i < 16; ++i) out[std::size_t(i)] = std::uint8_t(v[(bits >> (3 * i)) & 7]);
}

// Every block of a page through `decode(block, texels)`, texels written into the page.
template <class DecodeBlock>
void decode_blocks(const std::uint8_t* blocks, std::uint32_t size, std::size_t block_bytes, std::uint8_t* rgba,
                   DecodeBlock&& decode) {
    const std::uint32_t per_row = size / 4;
    for (std::uint32_t by = 0; by < per_row; ++by)
        for (std::uint32_t bx = 0; bx < per_row; ++bx) {
            std::array<Texel, 16> t{};
            decode(blocks + (std::size_t(by) * per_row + bx) * block_bytes, t);
            for (int i = 0; i < 16; ++i) {
                std::uint8_t* d = rgba + ((std::size_t(by) * 4 + std::size_t(i / 4)) * size + std::size_t(bx) * 4 +
                                          std::size_t(i % 4)) * 4;
                for (int k = 0; k < 4; ++k) d[k] = t[std::size_t(i)][std::size_t(k)];
            }
        }
}

}  // namespace

void decode_bc1(const std::uint8_t* blocks, std::uint32_t size, std::uint8_t* rgba) {
    decode_blocks(blocks, size, 8, rgba, [](const std::uint8_t* b, std::array<Texel, 16>& t) { decode_bc1_block(b, t); });
}

void decode_bc4(const std::uint8_t* blocks, std::uint32_t size, std::uint8_t* rgba) {
    decode_blocks(blocks, size, 8, rgba, [](const std::uint8_t* b, std::array<Texel, 16>& t) {
        std::array<std::uint8_t, 16> r{};
        decode_bc4_block(b, r);
        for (int i = 0; i < 16; ++i) t[std::size_t(i)] = {r[std::size_t(i)], 0, 0, 255};
    });
}

void decode_bc5(const std::uint8_t* blocks, std::uint32_t size, std::uint8_t* rgba) {
    decode_blocks(blocks, size, 16, rgba, [](const std::uint8_t* b, std::array<Texel, 16>& t) {
        std::array<std::uint8_t, 16> r{}, g{};
        decode_bc4_block(b, r);
        decode_bc4_block(b + 8, g);
        for (int i = 0; i < 16; ++i) t[std::size_t(i)] = {r[std::size_t(i)], g[std::size_t(i)], 0, 255};
    });
}

}  // namespace tessera::blocks
