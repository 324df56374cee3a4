// BC7 blocks (tessera::blocks). The decoder: against an independent decoder, Mesa's (llvmpipe
// decodes BPTC textures itself: blocks uploaded with glCompressedTexImage2D, read back with
// glGetTexImage) on tens of thousands of random blocks of every mode and partition, the reserved
// mode included; and against hand-made blocks whose texels follow from the format's definition.
// The tables: anchors inside their subsets, the two-subset partitions typed in a second time as
// bit masks. The encoder: PSNR floors per effort level on a smooth terrain-like image and a
// hard-edged one, uniform blocks exact, opaque blocks opaque, alpha kept, the page layout, and its
// blocks decoding the same on the GL path as with decode_bc7.
#include <epoxy/gl.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "bc7_tables.hpp"
#include "render_util.hpp"
#include "tessera/blocks/bc7.hpp"

namespace {

using namespace tessera::blocks;
using Image = std::vector<std::uint8_t>;  // size x size RGBA8, row-major

// Deterministic everywhere: raw mt19937 outputs (the standard distributions differ between
// standard libraries).
class Rng {
public:
    explicit Rng(std::uint32_t seed) : g_(seed) {}
    std::uint32_t next() { return std::uint32_t(g_()); }
    int below(int n) { return int(next() % std::uint32_t(n)); }

private:
    std::mt19937 g_;
};

// ---- Images -----------------------------------------------------------------------------------

float lattice(int x, int y, std::uint32_t seed) {
    std::uint32_t h = std::uint32_t(x) * 0x8da6b343u ^ std::uint32_t(y) * 0xd8163841u ^ seed * 0xcb1ab31fu;
    h ^= h >> 13;
    h *= 0x5bd1e995u;
    h ^= h >> 15;
    return float(h & 0xFFFF) / 65535.f;
}

float value_noise(float x, float y, std::uint32_t seed) {
    const int xi = int(std::floor(x)), yi = int(std::floor(y));
    float fx = x - float(xi), fy = y - float(yi);
    fx = fx * fx * (3 - 2 * fx);
    fy = fy * fy * (3 - 2 * fy);
    const float a = lattice(xi, yi, seed), b = lattice(xi + 1, yi, seed);
    const float c = lattice(xi, yi + 1, seed), d = lattice(xi + 1, yi + 1, seed);
    const float top = a + (b - a) * fx, bottom = c + (d - c) * fx;
    return top + (bottom - top) * fy;
}

// Smooth, terrain-like: fractal value-noise heights through a colour ramp (water, grass, rock,
// snow), hill-shaded. Opaque.
Image smooth_image(std::uint32_t size) {
    std::vector<float> h(std::size_t(size) * size);
    for (std::uint32_t y = 0; y < size; ++y)
        for (std::uint32_t x = 0; x < size; ++x) {
            float v = 0, amp = 0.5f, f = 1.f / 128;
            for (std::uint32_t o = 0; o < 6; ++o, amp *= 0.5f, f *= 2) v += amp * value_noise(float(x) * f, float(y) * f, o);
            h[std::size_t(y) * size + x] = v;
        }
    Image img(std::size_t(size) * size * 4);
    for (std::uint32_t y = 0; y < size; ++y)
        for (std::uint32_t x = 0; x < size; ++x) {
            const float v = h[std::size_t(y) * size + x];
            const float dx = h[std::size_t(y) * size + std::min(x + 1, size - 1)] - v;
            const float dy = h[std::size_t(std::min(y + 1, size - 1)) * size + x] - v;
            const float shade = std::clamp(1.f + 40.f * (dx + dy), 0.4f, 1.4f);
            float r, g, b;
            if (v < 0.4f) r = 40, g = 80, b = 160 + 150 * v;
            else if (v < 0.55f) r = 90 + 200 * (v - 0.4f), g = 140, b = 60;
            else if (v < 0.7f) r = 120, g = 100 - 100 * (v - 0.55f), b = 70;
            else r = g = b = 200 + 50 * (v - 0.7f);
            std::uint8_t* p = &img[(std::size_t(y) * size + x) * 4];
            p[0] = std::uint8_t(std::clamp(r * shade, 0.f, 255.f));
            p[1] = std::uint8_t(std::clamp(g * shade, 0.f, 255.f));
            p[2] = std::uint8_t(std::clamp(b * shade, 0.f, 255.f));
            p[3] = 255;
        }
    return img;
}

// Hard-edged: flat rectangles of random colours, thin lines, a fine checkerboard and a few noisy
// patches; most blocks hold two or three colours. Opaque.
Image hard_edged_image(std::uint32_t size) {
    Rng rng(7);
    Image img(std::size_t(size) * size * 4, 255);
    auto put = [&](int x, int y, const std::uint8_t c[3]) {
        if (x < 0 || y < 0 || x >= int(size) || y >= int(size)) return;
        std::memcpy(&img[(std::size_t(y) * size + std::size_t(x)) * 4], c, 3);
    };
    auto colour = [&](std::uint8_t c[3]) {
        for (int i = 0; i < 3; ++i) c[i] = std::uint8_t(rng.below(256));
    };
    std::uint8_t c[3];
    colour(c);
    for (std::uint32_t y = 0; y < size; ++y)
        for (std::uint32_t x = 0; x < size; ++x) put(int(x), int(y), c);
    const int s = int(size);
    for (int i = 0; i < 60; ++i) {  // rectangles
        colour(c);
        const int x0 = rng.below(s), y0 = rng.below(s), w = 3 + rng.below(s / 4), h = 3 + rng.below(s / 4);
        for (int y = y0; y < y0 + h; ++y)
            for (int x = x0; x < x0 + w; ++x) put(x, y, c);
    }
    for (int i = 0; i < 30; ++i) {  // lines, any angle, 1 texel wide
        colour(c);
        const float x0 = float(rng.below(s)), y0 = float(rng.below(s)), x1 = float(rng.below(s)), y1 = float(rng.below(s));
        for (int t = 0; t <= 2 * s; ++t) {
            const float f = float(t) / float(2 * s);
            put(int(x0 + (x1 - x0) * f), int(y0 + (y1 - y0) * f), c);
        }
    }
    std::uint8_t c2[3];
    colour(c);
    colour(c2);
    for (int y = s / 8; y < s / 4; ++y)  // checkerboard of 2-texel cells
        for (int x = s / 2; x < s / 2 + s / 8; ++x) put(x, y, ((x / 2 + y / 2) & 1) ? c : c2);
    for (int i = 0; i < 4; ++i) {  // noise
        const int x0 = rng.below(s - 16), y0 = rng.below(s - 16);
        for (int y = y0; y < y0 + 16; ++y)
            for (int x = x0; x < x0 + 16; ++x) colour(c), put(x, y, c);
    }
    return img;
}

// Colour from the smooth image; alpha: a smooth gradient, a sharp-edged disc cut out (alpha 0)
// and a band of random alpha.
Image alpha_image(std::uint32_t size) {
    Image img = smooth_image(size);
    Rng rng(11);
    const float r = float(size) / 4, cx = float(size) / 2, cy = float(size) / 2;
    for (std::uint32_t y = 0; y < size; ++y)
        for (std::uint32_t x = 0; x < size; ++x) {
            std::uint8_t& a = img[(std::size_t(y) * size + x) * 4 + 3];
            a = std::uint8_t((x * 255) / (size - 1));
            const float dx = float(x) - cx, dy = float(y) - cy;
            if (dx * dx + dy * dy < r * r) a = 0;
            if (y >= size - size / 8) a = std::uint8_t(rng.below(256));
        }
    return img;
}

// ---- Measures ---------------------------------------------------------------------------------

double psnr(double squared_error, double samples) {
    return squared_error == 0 ? 99.0 : 10.0 * std::log10(255.0 * 255.0 * samples / squared_error);
}

// PSNR over R, G, B (8-bit), or over alpha.
double psnr_rgb(const Image& want, const Image& got) {
    double se = 0;
    for (std::size_t i = 0; i < want.size(); ++i)
        if (i % 4 != 3) se += (double(want[i]) - double(got[i])) * (double(want[i]) - double(got[i]));
    return psnr(se, double(want.size()) * 3 / 4);
}
double psnr_alpha(const Image& want, const Image& got) {
    double se = 0;
    for (std::size_t i = 3; i < want.size(); i += 4) se += (double(want[i]) - double(got[i])) * (double(want[i]) - double(got[i]));
    return psnr(se, double(want.size()) / 4);
}

Image encode(const Image& img, std::uint32_t size, const Bc7Options& opt) {
    Image blocks(std::size_t(size) * size);
    encode_bc7(img.data(), size, blocks.data(), opt);
    return blocks;
}

Image decode(const Image& blocks, std::uint32_t size) {
    Image rgba(std::size_t(size) * size * 4);
    decode_bc7(blocks.data(), size, rgba.data());
    return rgba;
}

int mode_of(const std::uint8_t* block) {
    int m = 0;
    while (m < 8 && !((block[0] >> m) & 1)) ++m;
    return m;
}

// ---- The GL path: Mesa's decoder --------------------------------------------------------------

// Blocks of a size x size texture decoded by the GL implementation.
Image gl_decode(const Image& blocks, std::uint32_t size) {
    GLuint tex = 0;
    glGenTextures(1, &tex);
    glBindTexture(GL_TEXTURE_2D, tex);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAX_LEVEL, 0);
    glCompressedTexImage2D(GL_TEXTURE_2D, 0, GL_COMPRESSED_RGBA_BPTC_UNORM, GLsizei(size), GLsizei(size), 0,
                           GLsizei(blocks.size()), blocks.data());
    Image rgba(std::size_t(size) * size * 4, 0xCD);
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    glGetTexImage(GL_TEXTURE_2D, 0, GL_RGBA, GL_UNSIGNED_BYTE, rgba.data());
    const GLenum err = glGetError();
    glDeleteTextures(1, &tex);
    EXPECT_EQ(err, GLenum(GL_NO_ERROR));
    return rgba;
}

// Compares two decodes of the same blocks; describes the first few differing blocks.
::testing::AssertionResult same_texels(const Image& blocks, std::uint32_t size, const Image& want, const Image& got) {
    const std::uint32_t per_row = size / 4;
    int bad = 0;
    std::string what;
    for (std::uint32_t b = 0; b < per_row * per_row; ++b) {
        const std::uint32_t bx = b % per_row * 4, by = b / per_row * 4;
        for (std::uint32_t t = 0; t < 16; ++t) {
            const std::size_t at = (std::size_t(by + t / 4) * size + bx + t % 4) * 4;
            if (std::memcmp(&want[at], &got[at], 4) == 0) continue;
            if (++bad <= 5) {
                what += "\n  block " + std::to_string(b) + " (mode " + std::to_string(mode_of(&blocks[std::size_t(b) * 16])) +
                        ") texel " + std::to_string(t) + ": GL " + std::to_string(want[at]) + "," +
                        std::to_string(want[at + 1]) + "," + std::to_string(want[at + 2]) + "," + std::to_string(want[at + 3]) +
                        " decode_bc7 " + std::to_string(got[at]) + "," + std::to_string(got[at + 1]) + "," +
                        std::to_string(got[at + 2]) + "," + std::to_string(got[at + 3]);
            }
            break;
        }
    }
    if (bad == 0) return ::testing::AssertionSuccess();
    return ::testing::AssertionFailure() << bad << " blocks differ" << what;
}

// Random blocks: block i has mode i % 9 (8: the reserved mode, a first byte of 0) and, in the
// partitioned modes, partition number (i / 9) % 64 (mode 0: % 16), so that every partition of
// every mode appears; every other bit is random.
Image random_blocks(std::uint32_t count, std::uint32_t seed) {
    Rng rng(seed);
    Image blocks(std::size_t(count) * 16);
    for (std::uint32_t i = 0; i < count; ++i) {
        std::uint8_t* b = &blocks[std::size_t(i) * 16];
        for (int k = 0; k < 16; ++k) b[k] = std::uint8_t(rng.next() >> 24);
        const unsigned m = i % 9;
        if (m == 8) {
            b[0] = 0;
            continue;
        }
        // Mode m: bits 0..m-1 zero, bit m one; then the partition bits.
        std::uint32_t low = b[0] | (unsigned(b[1]) << 8);
        low &= ~((1u << (m + 1)) - 1);
        low |= 1u << m;
        const unsigned pbits = tessera::blocks::bc7::kModes[m].partition_bits;
        if (pbits) {
            const unsigned part = (i / 9) % (1u << pbits);
            low &= ~(((1u << pbits) - 1) << (m + 1));
            low |= part << (m + 1);
        }
        b[0] = std::uint8_t(low);
        b[1] = std::uint8_t(low >> 8);
    }
    return blocks;
}

TEST(Bc7Gl, DecoderMatchesMesaOnRandomBlocks) {
    REQUIRE_GL(ctx);
    constexpr std::uint32_t kSize = 512;  // 16384 blocks per texture
    for (std::uint32_t seed : {1u, 2u, 3u}) {
        const Image blocks = random_blocks(kSize * kSize / 16, seed);
        EXPECT_TRUE(same_texels(blocks, kSize, gl_decode(blocks, kSize), decode(blocks, kSize))) << "seed " << seed;
    }
}

// Blocks at the edges of the bit space: all zero bits but the mode's, all one bits after it.
TEST(Bc7Gl, DecoderMatchesMesaOnExtremeBlocks) {
    REQUIRE_GL(ctx);
    constexpr std::uint32_t kSize = 64;
    Image blocks(kSize * kSize);
    for (std::uint32_t i = 0; i < kSize * kSize / 16; ++i) {
        std::uint8_t* b = &blocks[std::size_t(i) * 16];
        const unsigned m = i % 8;
        const bool ones = (i / 8) % 2;
        const unsigned part = (i / 16) % 64;
        std::memset(b, ones ? 0xFF : 0, 16);
        std::uint32_t low = (ones ? 0xFFFFu : 0u) & ~((1u << (m + 1)) - 1);
        low |= 1u << m;
        const unsigned pbits = tessera::blocks::bc7::kModes[m].partition_bits;
        low &= ~(((1u << pbits) - 1) << (m + 1));
        low |= (part % (1u << pbits)) << (m + 1);
        b[0] = std::uint8_t(low);
        b[1] = std::uint8_t(low >> 8);
    }
    EXPECT_TRUE(same_texels(blocks, kSize, gl_decode(blocks, kSize), decode(blocks, kSize)));
}

// The encoder's blocks: what the GPU samples is what decode_bc7 says, and close to the source.
TEST(Bc7Gl, EncodedBlocksDecodeTheSameOnTheGlPath) {
    REQUIRE_GL(ctx);
    constexpr std::uint32_t kSize = 128;
    struct Case {
        const char* name;
        Image img;
        double min_rgb, min_alpha;
    };
    // Floors: the effort-0 figures measured less 0.5 dB (99: exact).
    const Case cases[] = {{"smooth", smooth_image(kSize), 49.0, 99.0},      // 49.59, 50.31 dB at effort 2
                          {"hard-edged", hard_edged_image(kSize), 27.3, 99.0},  // 27.84, 30.17
                          {"alpha", alpha_image(kSize), 41.3, 39.1}};        // 41.87 / 39.66, 44.50 / 39.84
    for (const Case& c : cases)
        for (int effort : {0, 2}) {
            Bc7Options opt;
            opt.effort = effort;
            const Image blocks = encode(c.img, kSize, opt);
            const Image gpu = gl_decode(blocks, kSize);
            EXPECT_TRUE(same_texels(blocks, kSize, gpu, decode(blocks, kSize))) << c.name << " effort " << effort;
            std::printf("GL %s effort %d: %.2f dB RGB, %.2f dB alpha\n", c.name, effort, psnr_rgb(c.img, gpu), psnr_alpha(c.img, gpu));
            EXPECT_GE(psnr_rgb(c.img, gpu), c.min_rgb) << c.name << " effort " << effort;
            EXPECT_GE(psnr_alpha(c.img, gpu), c.min_alpha) << c.name << " effort " << effort;
        }
}

// ---- Hand-made blocks: the format's definition, without GL ------------------------------------

// Writes fields from bit 0 upwards, as the format stores them.
class Bits {
public:
    Bits& put(unsigned value, unsigned n) {
        for (unsigned i = 0; i < n; ++i, ++pos_)
            if ((value >> i) & 1) block_[pos_ / 8] |= std::uint8_t(1u << (pos_ % 8));
        return *this;
    }
    const std::uint8_t* data() const { return block_.data(); }
    unsigned size() const { return pos_; }

private:
    std::array<std::uint8_t, 16> block_{};
    unsigned pos_ = 0;
};

constexpr int kW2[4] = {0, 21, 43, 64};
constexpr int kW4[16] = {0, 4, 9, 13, 17, 21, 26, 30, 34, 38, 43, 47, 51, 55, 60, 64};
int lerp(int e0, int e1, int w) { return ((64 - w) * e0 + w * e1 + 32) >> 6; }

TEST(Bc7Decode, ReservedModeIsTransparentBlack) {
    std::uint8_t block[16], out[64];
    for (int i = 0; i < 16; ++i) block[i] = std::uint8_t(0x5A + 17 * i);
    block[0] = 0;
    std::memset(out, 0x77, sizeof out);
    decode_bc7_block(block, out);
    for (int i = 0; i < 64; ++i) ASSERT_EQ(out[i], 0) << "byte " << i;
}

// Mode 6: RGBA 7 bits + a p-bit per endpoint (8-bit endpoints, no expansion), 4-bit indices,
// texel 0's index stored in 3 bits.
TEST(Bc7Decode, HandMadeMode6) {
    const int q[2][4] = {{10, 20, 30, 40}, {100, 110, 120, 127}};
    const int p[2] = {1, 0};
    int idx[16];
    for (int t = 0; t < 16; ++t) idx[t] = (t * 7 + 3) % 16;
    idx[0] = 5;  // an anchor: below 8
    Bits b;
    b.put(1u << 6, 7);
    for (int c = 0; c < 4; ++c) b.put(unsigned(q[0][c]), 7).put(unsigned(q[1][c]), 7);
    b.put(unsigned(p[0]), 1).put(unsigned(p[1]), 1);
    for (int t = 0; t < 16; ++t) b.put(unsigned(idx[t]), t == 0 ? 3 : 4);
    ASSERT_EQ(b.size(), 128u);
    std::uint8_t out[64];
    decode_bc7_block(b.data(), out);
    for (int t = 0; t < 16; ++t)
        for (int c = 0; c < 4; ++c)
            EXPECT_EQ(out[4 * t + c], lerp(q[0][c] * 2 + p[0], q[1][c] * 2 + p[1], kW4[idx[t]])) << "texel " << t << " channel " << c;
}

// Mode 5 with rotation 1 (R and alpha trade places after decoding): RGB 7 bits widened by
// repeating the top bit, alpha 8 bits, two 2-bit index sets.
TEST(Bc7Decode, HandMadeMode5Rotated) {
    const int q[2][3] = {{5, 64, 127}, {120, 3, 0}};
    const int a[2] = {200, 17};
    int ci[16], ai[16];
    for (int t = 0; t < 16; ++t) ci[t] = (t + 1) % 4, ai[t] = (3 * t) % 4;
    ci[0] = 1;
    ai[0] = 0;
    Bits b;
    b.put(1u << 5, 6).put(1, 2);  // rotation 1
    for (int c = 0; c < 3; ++c) b.put(unsigned(q[0][c]), 7).put(unsigned(q[1][c]), 7);
    b.put(unsigned(a[0]), 8).put(unsigned(a[1]), 8);
    for (int t = 0; t < 16; ++t) b.put(unsigned(ci[t]), t == 0 ? 1 : 2);
    for (int t = 0; t < 16; ++t) b.put(unsigned(ai[t]), t == 0 ? 1 : 2);
    ASSERT_EQ(b.size(), 128u);
    std::uint8_t out[64];
    decode_bc7_block(b.data(), out);
    auto widen7 = [](int v) { return (v << 1) | (v >> 6); };
    for (int t = 0; t < 16; ++t) {
        int px[4];
        for (int c = 0; c < 3; ++c) px[c] = lerp(widen7(q[0][c]), widen7(q[1][c]), kW2[ci[t]]);
        px[3] = lerp(a[0], a[1], kW2[ai[t]]);
        std::swap(px[0], px[3]);
        for (int c = 0; c < 4; ++c) EXPECT_EQ(out[4 * t + c], px[c]) << "texel " << t << " channel " << c;
    }
}

// Mode 3, partition 13: the top two rows are subset 0, the bottom two subset 1, whose anchor is
// texel 15. RGB 7 bits + a p-bit per endpoint, 2-bit indices; alpha 255.
TEST(Bc7Decode, HandMadeMode3TwoSubsets) {
    const int q[4][3] = {{1, 2, 3}, {125, 126, 127}, {64, 0, 100}, {0, 64, 27}};
    const int p[4] = {0, 1, 1, 0};
    int idx[16];
    for (int t = 0; t < 16; ++t) idx[t] = (t * 5 + 2) % 4;
    idx[0] = 1;
    idx[15] = 0;
    Bits b;
    b.put(1u << 3, 4).put(13, 6);
    for (int c = 0; c < 3; ++c)
        for (int e = 0; e < 4; ++e) b.put(unsigned(q[e][c]), 7);
    for (int e = 0; e < 4; ++e) b.put(unsigned(p[e]), 1);
    for (int t = 0; t < 16; ++t) b.put(unsigned(idx[t]), (t == 0 || t == 15) ? 1 : 2);
    ASSERT_EQ(b.size(), 128u);
    std::uint8_t out[64];
    decode_bc7_block(b.data(), out);
    for (int t = 0; t < 16; ++t) {
        const int s = t < 8 ? 0 : 1;
        for (int c = 0; c < 3; ++c)
            EXPECT_EQ(out[4 * t + c], lerp(q[2 * s][c] * 2 + p[2 * s], q[2 * s + 1][c] * 2 + p[2 * s + 1], kW2[idx[t]]))
                << "texel " << t << " channel " << c;
        EXPECT_EQ(out[4 * t + 3], 255) << "texel " << t;
    }
}

// ---- Tables -----------------------------------------------------------------------------------

// Anchor texels lie in their subsets, texel 0 is always subset 0, and no subset is empty.
TEST(Bc7Tables, AnchorsLieInTheirSubsets) {
    namespace t = tessera::blocks::bc7;
    for (unsigned part = 0; part < 64; ++part) {
        const std::uint8_t* two = t::kPartitions2[part];
        const std::uint8_t* three = t::kPartitions3[part];
        EXPECT_EQ(two[0], 0) << part;
        EXPECT_EQ(three[0], 0) << part;
        EXPECT_EQ(two[t::kAnchor2[part]], 1) << part;
        EXPECT_EQ(three[t::kAnchor3Second[part]], 1) << part;
        EXPECT_EQ(three[t::kAnchor3Third[part]], 2) << part;
        for (int s = 0; s < 3; ++s) {
            EXPECT_TRUE(s == 2 || std::count(two, two + 16, s) > 0) << part;
            EXPECT_GT(std::count(three, three + 16, s), 0) << part;
        }
    }
}

// The two-subset partitions typed in a second time, as 16-bit masks (bit t: texel t is in subset
// 1), from a different printing of the same table.
TEST(Bc7Tables, TwoSubsetPartitionsMatchTheirMasks) {
    constexpr std::uint16_t kMasks[64] = {
        0xCCCC, 0x8888, 0xEEEE, 0xECC8, 0xC880, 0xFEEC, 0xFEC8, 0xEC80, 0xC800, 0xFFEC, 0xFE80, 0xE800, 0xFFE8,
        0xFF00, 0xFFF0, 0xF000, 0xF710, 0x008E, 0x7100, 0x08CE, 0x008C, 0x7310, 0x3100, 0x8CCE, 0x088C, 0x3110,
        0x6666, 0x366C, 0x17E8, 0x0FF0, 0x718E, 0x399C, 0xAAAA, 0xF0F0, 0x5A5A, 0x33CC, 0x3C3C, 0x55AA, 0x9696,
        0xA55A, 0x73CE, 0x13C8, 0x324C, 0x3BDC, 0x6996, 0xC33C, 0x9966, 0x0660, 0x0272, 0x04E4, 0x4E40, 0x2720,
        0xC936, 0x936C, 0x39C6, 0x639C, 0x9336, 0x9CC6, 0x817E, 0xE718, 0xCCF0, 0x0FCC, 0x7744, 0xEE22};
    for (unsigned part = 0; part < 64; ++part) {
        unsigned mask = 0;
        for (unsigned t = 0; t < 16; ++t) mask |= unsigned(tessera::blocks::bc7::kPartitions2[part][t] == 1) << t;
        EXPECT_EQ(mask, kMasks[part]) << "partition " << part;
    }
}

// ---- The encoder ------------------------------------------------------------------------------

struct Measured {
    double rgb = 0, alpha = 0, blocks_per_s = 0;
};

Measured measure(const Image& img, std::uint32_t size, const Bc7Options& opt) {
    const auto t0 = std::chrono::steady_clock::now();
    const Image blocks = encode(img, size, opt);
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const Image back = decode(blocks, size);
    return {psnr_rgb(img, back), psnr_alpha(img, back), double(size) * size / 16 / s};
}

constexpr std::uint32_t kSize = 256;

TEST(Bc7Encode, SmoothImagePsnrPerEffort) {
    const Image img = smooth_image(kSize);
    const double floors[4] = {48.5, 49.3, 49.4, 49.5};  // measured 49.07, 49.82, 49.96, 50.00
    for (int effort = 0; effort <= 3; ++effort) {
        Bc7Options opt;
        opt.effort = effort;
        const Measured m = measure(img, kSize, opt);
        std::printf("smooth effort %d: %.2f dB, %.0f blocks/s\n", effort, m.rgb, m.blocks_per_s);
        EXPECT_GE(m.rgb, floors[effort]) << "effort " << effort;
        EXPECT_EQ(m.alpha, 99.0) << "effort " << effort;
    }
}

TEST(Bc7Encode, HardEdgedImagePsnrPerEffort) {
    const Image img = hard_edged_image(kSize);
    const double floors[4] = {33.8, 35.8, 36.0, 36.0};  // measured 34.32, 36.36, 36.56, 36.56
    double previous = 0;
    for (int effort = 0; effort <= 3; ++effort) {
        Bc7Options opt;
        opt.effort = effort;
        const Measured m = measure(img, kSize, opt);
        std::printf("hard-edged effort %d: %.2f dB, %.0f blocks/s\n", effort, m.rgb, m.blocks_per_s);
        EXPECT_GE(m.rgb, floors[effort]) << "effort " << effort;
        EXPECT_GE(m.rgb, previous - 0.02) << "effort " << effort << " worse than effort " << effort - 1;
        EXPECT_EQ(m.alpha, 99.0) << "effort " << effort;
        previous = m.rgb;
    }
}

TEST(Bc7Encode, AlphaIsKept) {
    const Image img = alpha_image(kSize);
    for (int effort = 0; effort <= 3; ++effort) {
        Bc7Options opt;
        opt.effort = effort;
        const Image back = decode(encode(img, kSize, opt), kSize);
        // The worst alpha error outside the band of random alpha.
        int worst = 0;
        for (std::size_t i = 3; i < img.size() * 7 / 8; i += 4) worst = std::max(worst, std::abs(int(img[i]) - int(back[i])));
        std::printf("alpha effort %d: %.2f dB RGB, %.2f dB alpha, worst alpha error %d\n", effort, psnr_rgb(img, back),
                    psnr_alpha(img, back), worst);
        // Measured: alpha 39.7-40.0 dB, worst error 3-5; RGB 41.9 dB at effort 0, 44.1-44.4 above.
        EXPECT_GE(psnr_alpha(img, back), 39.0) << "effort " << effort;
        EXPECT_LE(worst, 8) << "effort " << effort;
        EXPECT_GE(psnr_rgb(img, back), effort == 0 ? 41.4 : 43.5) << "effort " << effort;
    }
}

// Every uniform block decodes exactly: each grey level at several alphas, and random colours.
TEST(Bc7Encode, UniformBlocksAreExact) {
    Rng rng(5);
    std::vector<std::array<std::uint8_t, 4>> colours;
    for (int v = 0; v < 256; ++v)
        for (int a : {255, 254, 128, 1, 0}) colours.push_back({std::uint8_t(v), std::uint8_t(v), std::uint8_t(v), std::uint8_t(a)});
    for (int i = 0; i < 4000; ++i)
        colours.push_back({std::uint8_t(rng.below(256)), std::uint8_t(rng.below(256)), std::uint8_t(rng.below(256)),
                           std::uint8_t(i % 2 ? 255 : rng.below(256))});
    for (int effort : {0, 2}) {
        Bc7Options opt;
        opt.effort = effort;
        for (const auto& c : colours) {
            std::uint8_t in[64], block[16], out[64];
            for (int t = 0; t < 16; ++t) std::memcpy(in + 4 * t, c.data(), 4);
            encode_bc7_block(in, block, opt);
            decode_bc7_block(block, out);
            ASSERT_EQ(std::memcmp(in, out, 64), 0) << "colour " << int(c[0]) << "," << int(c[1]) << "," << int(c[2]) << ","
                                                   << int(c[3]) << " effort " << effort;
        }
    }
}

// A block whose alphas are all 255 decodes with alpha 255, at every effort, whatever its colours.
TEST(Bc7Encode, OpaqueBlocksStayOpaque) {
    Rng rng(9);
    for (int effort = 0; effort <= 3; ++effort) {
        Bc7Options opt;
        opt.effort = effort;
        for (int i = 0; i < 3000; ++i) {
            std::uint8_t in[64], block[16], out[64];
            // Random colours, or two or three random colours, or a gradient.
            for (int t = 0; t < 16; ++t) {
                for (int c = 0; c < 3; ++c)
                    in[4 * t + c] = std::uint8_t(i % 3 == 0 ? rng.below(256) : i % 3 == 1 ? (t % 3) * 100 + c * 7 : t * 16 + c);
                in[4 * t + 3] = 255;
            }
            encode_bc7_block(in, block, opt);
            decode_bc7_block(block, out);
            for (int t = 0; t < 16; ++t) ASSERT_EQ(out[4 * t + 3], 255) << "block " << i << " texel " << t << " effort " << effort;
        }
    }
}

// With perceptual weights the luma-weighted error drops, and RGB stays close.
TEST(Bc7Encode, PerceptualWeightsFavourLuma) {
    const Image img = hard_edged_image(kSize);
    auto luma_error = [&](const Image& back) {
        double e = 0;
        for (std::size_t i = 0; i < img.size(); i += 4)
            for (int c = 0; c < 3; ++c) {
                const double d = double(img[i + std::size_t(c)]) - double(back[i + std::size_t(c)]);
                e += (c == 0 ? 0.30 : c == 1 ? 0.59 : 0.11) * d * d;
            }
        return e;
    };
    Bc7Options even, luma;
    luma.perceptual = true;
    const Image a = decode(encode(img, kSize, even), kSize), b = decode(encode(img, kSize, luma), kSize);
    std::printf("luma-weighted error %.0f even, %.0f perceptual; RGB %.2f dB even, %.2f dB perceptual\n", luma_error(a),
                luma_error(b), psnr_rgb(img, a), psnr_rgb(img, b));
    // Measured: 39% less luma-weighted error, 1.4 dB less RGB PSNR.
    EXPECT_LT(luma_error(b), 0.8 * luma_error(a));
    EXPECT_GT(psnr_rgb(img, b), psnr_rgb(img, a) - 2.0);
}

// encode_bc7 and decode_bc7 lay blocks out row of blocks by row of blocks, as the block
// functions make them.
TEST(Bc7Encode, PageLayout) {
    constexpr std::uint32_t size = 32;
    const Image img = hard_edged_image(size);
    Bc7Options opt;
    opt.effort = 1;
    const Image blocks = encode(img, size, opt);
    const Image page = decode(blocks, size);
    for (std::uint32_t by = 0; by < size / 4; ++by)
        for (std::uint32_t bx = 0; bx < size / 4; ++bx) {
            std::uint8_t in[64], block[16], out[64];
            for (std::uint32_t y = 0; y < 4; ++y) std::memcpy(in + 16 * y, &img[((by * 4 + y) * size + bx * 4) * 4], 16);
            encode_bc7_block(in, block, opt);
            const std::size_t b = by * (size / 4) + bx;
            ASSERT_EQ(std::memcmp(block, &blocks[b * 16], 16), 0) << "block " << bx << "," << by;
            decode_bc7_block(block, out);
            for (std::uint32_t y = 0; y < 4; ++y)
                ASSERT_EQ(std::memcmp(out + 16 * y, &page[((by * 4 + y) * size + bx * 4) * 4], 16), 0) << "block " << bx << "," << by;
        }
}

// The partitioned modes are used where they pay (two- and three-subset blocks of the hard-edged
// image), and the alpha modes where there is alpha: a partition search that never wins, or an
// alpha path never taken, shows here.
TEST(Bc7Encode, ModesFollowTheContent) {
    int opaque[8] = {}, alpha[8] = {};
    const Image hard = encode(hard_edged_image(kSize), kSize, {});
    const Image soft = encode(alpha_image(kSize), kSize, {});
    for (std::size_t b = 0; b < hard.size(); b += 16) ++opaque[mode_of(&hard[b])];
    for (std::size_t b = 0; b < soft.size(); b += 16) ++alpha[mode_of(&soft[b])];
    for (int m : {0, 1, 2, 3}) EXPECT_GT(opaque[m], 0) << "mode " << m;
    for (int m : {4, 5, 6, 7}) EXPECT_GT(alpha[m], 0) << "mode " << m;
    for (int m : {0, 1, 2, 3}) EXPECT_EQ(alpha[m], 0) << "mode " << m << " has no alpha";
}

}  // namespace
