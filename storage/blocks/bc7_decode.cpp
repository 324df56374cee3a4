// BC7 decoding, bit for bit as the Khronos Data Format Specification (BPTC) defines it: what a GPU
// samples from a GL_COMPRESSED_RGBA_BPTC_UNORM texture.
#include <cstring>
#include <utility>

#include "bc7_tables.hpp"
#include "tessera/blocks/bc7.hpp"

namespace tessera::blocks {
namespace {

// Reads a block's bits from bit 0 (the low bit of byte 0) upwards.
class BitReader {
public:
    explicit BitReader(const std::uint8_t* b) : b_(b) {}
    unsigned read(unsigned n) {
        unsigned v = 0;
        for (unsigned i = 0; i < n; ++i, ++pos_) v |= unsigned((b_[pos_ >> 3] >> (pos_ & 7)) & 1) << i;
        return v;
    }

private:
    const std::uint8_t* b_;
    unsigned pos_ = 0;
};

}  // namespace

void decode_bc7_block(const std::uint8_t in[16], std::uint8_t rgba[64]) {
    unsigned m = 0;
    while (m < 8 && !((in[0] >> m) & 1)) ++m;
    if (m == 8) {  // reserved: no mode bit in the first byte
        std::memset(rgba, 0, 64);
        return;
    }
    const bc7::Mode& mode = bc7::kModes[m];
    BitReader r(in);
    r.read(m + 1);
    const unsigned number = r.read(mode.partition_bits);
    const unsigned rotation = r.read(mode.rotation_bits);
    const unsigned selector = r.read(mode.selector_bits);

    // Endpoints: all R (subset 0 e0, e1, subset 1 e0, ...), then all G, B, and A; then the p-bits.
    int ep[6][4] = {};
    const unsigned n = 2u * mode.subsets;
    for (unsigned c = 0; c < 3; ++c)
        for (unsigned e = 0; e < n; ++e) ep[e][c] = int(r.read(mode.color_bits));
    for (unsigned e = 0; e < n; ++e) ep[e][3] = mode.alpha_bits ? int(r.read(mode.alpha_bits)) : 255;
    int color_bits = mode.color_bits, alpha_bits = mode.alpha_bits;
    if (mode.pbits != bc7::kNoPbit) {
        for (unsigned e = 0; e < n; ++e) {
            if (mode.pbits == bc7::kUniquePbit || e % 2 == 0) {
                const int p = int(r.read(1));
                for (unsigned c = 0; c < 4; ++c) ep[e][c] = (ep[e][c] << 1) | p;
                if (mode.pbits == bc7::kSharedPbit)
                    for (unsigned c = 0; c < 4; ++c) ep[e + 1][c] = (ep[e + 1][c] << 1) | p;
            }
        }
        ++color_bits;
        ++alpha_bits;
    }
    for (unsigned e = 0; e < n; ++e) {
        for (unsigned c = 0; c < 3; ++c) ep[e][c] = bc7::expand(ep[e][c], color_bits);
        ep[e][3] = mode.alpha_bits ? bc7::expand(ep[e][3], alpha_bits) : 255;
    }

    // Indices: texel by texel, an anchor texel's without its top bit; then the secondary set.
    const std::uint8_t* subset = bc7::partition(mode.subsets, number);
    unsigned anchor[3];
    bc7::anchors(mode.subsets, number, anchor);
    auto is_anchor = [&](unsigned t) {
        return t == 0 || (mode.subsets >= 2 && t == anchor[1]) || (mode.subsets == 3 && t == anchor[2]);
    };
    unsigned idx[2][16] = {};
    for (unsigned t = 0; t < 16; ++t) idx[0][t] = r.read(mode.index_bits - (is_anchor(t) ? 1 : 0));
    if (mode.index2_bits)
        for (unsigned t = 0; t < 16; ++t) idx[1][t] = r.read(mode.index2_bits - (is_anchor(t) ? 1 : 0));

    // Colour from the primary set and alpha from the secondary one, swapped when mode 4's selector
    // bit is set; modes with one set use it for both.
    const unsigned color_set = selector, alpha_set = mode.index2_bits ? 1 - selector : 0;
    const std::uint8_t* wc = bc7::weights(color_set ? mode.index2_bits : mode.index_bits);
    const std::uint8_t* wa = bc7::weights(alpha_set ? mode.index2_bits : mode.index_bits);
    for (unsigned t = 0; t < 16; ++t) {
        const int* e0 = ep[2 * subset[t]];
        const int* e1 = ep[2 * subset[t] + 1];
        std::uint8_t* px = rgba + 4 * t;
        for (unsigned c = 0; c < 3; ++c) px[c] = std::uint8_t(bc7::interpolate(e0[c], e1[c], wc[idx[color_set][t]]));
        px[3] = std::uint8_t(bc7::interpolate(e0[3], e1[3], wa[idx[alpha_set][t]]));
        if (rotation) std::swap(px[rotation - 1], px[3]);
    }
}

void decode_bc7(const std::uint8_t* blocks, std::uint32_t size, std::uint8_t* rgba) {
    std::uint8_t texels[64];
    for (std::uint32_t by = 0; by < size; by += 4)
        for (std::uint32_t bx = 0; bx < size; bx += 4, blocks += 16) {
            decode_bc7_block(blocks, texels);
            for (unsigned y = 0; y < 4; ++y)
                std::memcpy(rgba + (std::size_t(by + y) * size + bx) * 4, texels + 16 * y, 16);
        }
}

}  // namespace tessera::blocks
