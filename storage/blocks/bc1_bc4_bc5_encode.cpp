#include "block_codecs.hpp"

#include <stb_dxt.h>

#include <algorithm>
#include <cstddef>
#include <cstring>

namespace tessera::blocks {

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

// One BC1 block the real-time way (J.M.P. van Waveren, "Real-Time DXT Compression", id Software,
// 2006, the encoder behind RAGE's transcoding): the endpoints are the corners of the block's RGB
// bounding box, inset by 1/16 of its extent; each texel takes the palette entry nearest to its
// projection on the endpoint axis.
[[gnu::always_inline]] inline void bc1_block(const std::uint8_t* src, std::size_t row_bytes, std::uint8_t* out) {
    // One pass: the channels split out (so the loops below vectorize), the box, and the sums the
    // channels' covariances need.
    int r[16], g[16], b[16];
    int lo[3] = {255, 255, 255}, hi[3] = {0, 0, 0};
    int sr = 0, sg = 0, sb = 0, srg = 0, srb = 0, sgb = 0;
    for (int y = 0; y < 4; ++y)  // straight from the page's rows: no gathered copy
        for (int x = 0; x < 4; ++x) {
            const std::uint8_t* t = src + y * row_bytes + x * 4;
            r[y * 4 + x] = t[0];
            g[y * 4 + x] = t[1];
            b[y * 4 + x] = t[2];
        }
    for (int i = 0; i < 16; ++i) {
        lo[0] = std::min(lo[0], r[i]), hi[0] = std::max(hi[0], r[i]);
        lo[1] = std::min(lo[1], g[i]), hi[1] = std::max(hi[1], g[i]);
        lo[2] = std::min(lo[2], b[i]), hi[2] = std::max(hi[2], b[i]);
        sr += r[i], sg += g[i], sb += b[i];
        srg += r[i] * g[i], srb += r[i] * b[i], sgb += g[i] * b[i];
    }
    // The box's diagonal that follows the colours (I. Castano's refinement): a channel that falls
    // while red rises (or, with red flat, while green rises) runs the other way. 16 x covariance:
    const int cov_rg = 16 * srg - sr * sg, cov_rb = 16 * srb - sr * sb, cov_gb = 16 * sgb - sg * sb;
    const bool red_flat = hi[0] == lo[0];
    if (!red_flat && cov_rg < 0) std::swap(lo[1], hi[1]);
    if ((red_flat ? cov_gb : cov_rb) < 0) std::swap(lo[2], hi[2]);
    for (int c = 0; c < 3; ++c) {
        const int inset = (hi[c] - lo[c]) / 16;  // signed: toward the middle either way
        lo[c] += inset;
        hi[c] -= inset;
    }
    const auto to565 = [](const int* v) {
        return static_cast<std::uint16_t>(((v[0] >> 3) << 11) | ((v[1] >> 2) << 5) | (v[2] >> 3));
    };
    std::uint16_t c0 = to565(hi), c1 = to565(lo);
    if (c0 < c1) std::swap(c0, c1);  // c0 > c1 selects BC1's four-colour mode
    out[0] = static_cast<std::uint8_t>(c0);
    out[1] = static_cast<std::uint8_t>(c0 >> 8);
    out[2] = static_cast<std::uint8_t>(c1);
    out[3] = static_cast<std::uint8_t>(c1 >> 8);
    std::uint32_t indices = 0;
    if (c0 != c1) {  // c0 > c1: the four-colour mode; equal endpoints keep every index 0
        // The endpoints as the GPU expands them, and the axis from c1 to c0.
        const int e0[3] = {(c0 >> 11) * 255 / 31, ((c0 >> 5) & 63) * 255 / 63, (c0 & 31) * 255 / 31};
        const int e1[3] = {(c1 >> 11) * 255 / 31, ((c1 >> 5) & 63) * 255 / 63, (c1 & 31) * 255 / 31};
        const int axis[3] = {e0[0] - e1[0], e0[1] - e1[1], e0[2] - e1[2]};
        const int len2 = axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2];
        const float scale = len2 > 0 ? 3.0f / float(len2) : 0.0f;
        const int base = e1[0] * axis[0] + e1[1] * axis[1] + e1[2] * axis[2];
        // Position 0..3 along the axis from c1 to c0, then the BC1 index of that position
        // (c1 = 1, 1/3 = 3, 2/3 = 2, c0 = 0).
        int q[16];
        for (int i = 0; i < 16; ++i) {
            const int d = r[i] * axis[0] + g[i] * axis[1] + b[i] * axis[2] - base;
            q[i] = std::min(3, std::max(0, static_cast<int>(float(d) * scale + 0.5f)));
        }
        constexpr std::uint32_t kIndexOf[4] = {1, 3, 2, 0};
        for (int i = 0; i < 16; ++i) indices |= kIndexOf[q[i]] << (2 * i);
    }
    for (int i = 0; i < 4; ++i) out[4 + i] = static_cast<std::uint8_t>(indices >> (8 * i));
}

}  // namespace

namespace {
// The real-time encoder's loop, compiled twice on x86-64: for AVX2 (its 16-texel loops in two
// 8-lane steps) and for the baseline, picked once by the CPU on first use. An explicit choice, not
// GCC's target_clones: a clone resolver runs while the dynamic loader relocates, before a
// sanitizer's runtime is up, and crashes sanitized builds.
[[gnu::always_inline]] inline void encode_bc1_loop(const std::uint8_t* rgba, std::uint32_t size, std::uint8_t* out) {
    const std::size_t row_bytes = std::size_t(size) * 4;
    for (std::uint32_t by = 0; by < size; by += 4)
        for (std::uint32_t bx = 0; bx < size; bx += 4, out += 8)
            bc1_block(rgba + by * row_bytes + std::size_t(bx) * 4, row_bytes, out);
}

void encode_bc1_baseline(const std::uint8_t* rgba, std::uint32_t size, std::uint8_t* out) { encode_bc1_loop(rgba, size, out); }

#if defined(__x86_64__) && defined(__GNUC__)
[[gnu::target("avx2"), gnu::flatten]] void encode_bc1_avx2(const std::uint8_t* rgba, std::uint32_t size, std::uint8_t* out) {
    encode_bc1_loop(rgba, size, out);
}
#endif

void encode_bc1_fast(const std::uint8_t* rgba, std::uint32_t size, std::uint8_t* out) {
#if defined(__x86_64__) && defined(__GNUC__)
    static const auto encode = __builtin_cpu_supports("avx2") ? encode_bc1_avx2 : encode_bc1_baseline;
#else
    constexpr auto encode = encode_bc1_baseline;
#endif
    encode(rgba, size, out);
}
}  // namespace

void encode_bc1(const std::uint8_t* rgba, std::uint32_t size, std::uint8_t* out, Effort effort) {
    if (effort == Effort::best) {  // stb_dxt's refined endpoints: about 2x the time per page
        for_each_block(rgba, size, [&](const std::uint8_t* block) {
            stb_compress_dxt_block(out, block, 0, STB_DXT_HIGHQUAL);
            out += 8;
        });
        return;
    }
    encode_bc1_fast(rgba, size, out);
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

}  // namespace tessera::blocks
