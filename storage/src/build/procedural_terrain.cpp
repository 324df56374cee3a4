#include "procedural_terrain.hpp"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <stdexcept>

// The output must be bit-identical on every machine, so a*b+c must never be fused into an FMA
// (x86-64 without -march has no FMA, but e.g. AArch64 compilers fuse by default).
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif

namespace tessera::storage::build {
namespace {

// Four floats processed together: GCC/Clang vector extension, SSE2 on x86-64, NEON on ARM.
// Only IEEE add/sub/mul are used on it, so every lane computes exactly what scalar code would.
typedef float V4 __attribute__((vector_size(16)));
typedef std::int32_t V4i __attribute__((vector_size(16)));

inline V4 load4(const float* p) {
    V4 v;
    std::memcpy(&v, p, sizeof v);
    return v;
}
inline void store4(float* p, V4 v) { std::memcpy(p, &v, sizeof v); }
inline V4 splat(float f) { return V4{f, f, f, f}; }
inline V4 vmin(V4 a, V4 b) { return a < b ? a : b; }
inline V4 vmax(V4 a, V4 b) { return a > b ? a : b; }
inline V4 vclamp(V4 v, float lo, float hi) { return vmin(vmax(v, splat(lo)), splat(hi)); }

// 1/sqrt(x) for x >= 1: the classic bit-trick estimate and two Newton steps (relative error
// < 5e-6). Only integer ops, mul and sub, so unlike a hardware rsqrt it is the same everywhere.
inline V4 rsqrt_at_least_1(V4 x) {
    const V4i estimate = 0x5f3759df - (std::bit_cast<V4i>(x) >> 1);
    V4 y = std::bit_cast<V4>(estimate);
    const V4 half = x * 0.5f;
    y = y * (1.5f - half * y * y);
    y = y * (1.5f - half * y * y);
    return y;
}

constexpr std::uint64_t splitmix64(std::uint64_t z) {
    z += 0x9e3779b97f4a7c15ull;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

constexpr std::uint64_t kSeed = 0x7e55e4a7e44a1ull;

// Lattice values come from one table of random numbers; each lattice row reads it from a random
// start (hashed from the row index), so rows are independent without hashing every lattice point.
constexpr std::size_t kLatticeBits = 16;
constexpr std::size_t kLatticeSize = std::size_t(1) << kLatticeBits;
constexpr std::uint64_t kLatticeMask = kLatticeSize - 1;

// Texels of a row handled per pass; the per-chunk buffers live on the stack.
constexpr std::size_t kChunk = 256;
// Octaves add into the buffers at an offset of -3..0 texels (their 4-texel groups are aligned to
// their own lattice, not to the chunk), so the buffers have slack on both sides.
constexpr std::size_t kPad = 4;
constexpr std::size_t kBuffer = kChunk + 2 * kPad;

// Colour ramp: heights in [kRampLow, kRampHigh] map to kRampSize entries.
constexpr int kRampSize = 1024;
constexpr float kRampLow = -0.8f;
constexpr float kRampHigh = 0.8f;

// Slope (height units per texel) of the finest octave; the coarser ones follow from kRoughness.
constexpr float kRelief = 0.16f;
// Amplitude of an octave grows by this factor each time its wavelength doubles (2 = classic
// fBm with persistence 1/2, where every octave contributes equally to the slope).
constexpr float kRoughness = 2.1f;

// Light from the north-west, fairly high; scaled to unit length below.
constexpr float kLightLength = 1.98997487f;  // |(-1, -1, 1.4)|
constexpr float kLightX = -1.0f / kLightLength, kLightY = -1.0f / kLightLength, kLightZ = 1.4f / kLightLength;


// ---- Grid and labels --------------------------------------------------------------------------

struct GridScale {
    std::uint64_t spacing;
    std::uint64_t width;   // line thickness, texels
    unsigned darken;       // blend weight towards black, out of 256
};
constexpr GridScale kGrid[] = {
    {256, 1, 90},
    {2048, 2, 115},
    {16384, 4, 140},
    {131072, 8, 165},
};
constexpr int kGridScales = sizeof kGrid / sizeof kGrid[0];
constexpr std::uint64_t kMaxLabelScale = 64;  // font pixel size cap, texels

// 5x7 font for '0'..'9' (5 columns, bit 4 = left) and a 2-column ','.
constexpr std::uint8_t kDigits[10][7] = {
    {0x0e, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0e},  // 0
    {0x04, 0x0c, 0x04, 0x04, 0x04, 0x04, 0x0e},  // 1
    {0x0e, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1f},  // 2
    {0x1f, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0e},  // 3
    {0x02, 0x06, 0x0a, 0x12, 0x1f, 0x02, 0x02},  // 4
    {0x1f, 0x10, 0x1e, 0x01, 0x01, 0x11, 0x0e},  // 5
    {0x06, 0x08, 0x10, 0x1e, 0x11, 0x11, 0x0e},  // 6
    {0x1f, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08},  // 7
    {0x0e, 0x11, 0x11, 0x0e, 0x11, 0x11, 0x0e},  // 8
    {0x0e, 0x11, 0x11, 0x0f, 0x01, 0x02, 0x0c},  // 9
};
constexpr std::uint8_t kComma[7] = {0x0, 0x0, 0x0, 0x0, 0x3, 0x1, 0x2};
constexpr int kFontRows = 7;

// Text of a label: digits of X, a comma, digits of Y (glyph 10 = comma).
struct LabelText {
    std::uint8_t glyphs[16];
    int count = 0;
    int width = 0;  // font pixels, including the 1-pixel gaps between glyphs
};

void append_number(LabelText& t, std::uint64_t v) {
    std::uint8_t digits[20];
    int n = 0;
    do {
        digits[n++] = static_cast<std::uint8_t>(v % 10);
        v /= 10;
    } while (v != 0);
    while (n > 0) t.glyphs[t.count++] = digits[--n];
}

LabelText make_label(std::uint64_t x, std::uint64_t y) {
    LabelText t;
    append_number(t, x);
    t.glyphs[t.count++] = 10;
    append_number(t, y);
    for (int i = 0; i < t.count; ++i) t.width += (t.glyphs[i] == 10 ? 2 : 5) + (i > 0 ? 1 : 0);
    return t;
}

// Font row r of the label as a bit mask: bit (c + 1) is font column c, so column -1 (left
// outline) is bit 0. Labels are at most "65535,65535" = 62 columns, so 64 bits hold the outline.
std::uint64_t label_row_bits(const LabelText& t, int r) {
    if (r < 0 || r >= kFontRows) return 0;
    std::uint64_t bits = 0;
    int column = 0;
    for (int i = 0; i < t.count; ++i) {
        const int w = t.glyphs[i] == 10 ? 2 : 5;
        const std::uint64_t glyph_row = t.glyphs[i] == 10 ? kComma[r] : kDigits[t.glyphs[i]][r];
        for (int c = 0; c < w; ++c)
            if (glyph_row & (1u << (w - 1 - c))) bits |= std::uint64_t(1) << (column + c + 1);
        column += w + 1;
    }
    return bits;
}

inline void fill_span(std::uint8_t* out, std::uint64_t begin, std::uint64_t end, std::uint8_t v) {
    if (begin < end) std::memset(out + 3 * begin, v, 3 * (end - begin));
}

// Blends texels [begin, end) towards black by weight/256.
inline void darken_span(std::uint8_t* out, std::uint64_t begin, std::uint64_t end, unsigned weight) {
    const unsigned keep = 256 - weight;
    for (std::uint8_t *p = out + 3 * begin, *e = out + 3 * end; p < e; ++p)
        *p = static_cast<std::uint8_t>((*p * keep + 128) >> 8);
}

}  // namespace

ProceduralTerrain::ProceduralTerrain(std::uint64_t size) : size_(size) {
    if (size < 1 || size > kMaxSize) throw std::invalid_argument("ProceduralTerrain: size must be in [1, 2^24]");

    // Octave wavelengths: finest 4 texels, coarsest about size/4, so there is detail at every
    // zoom level. Past kMaxOctaves the exponents are spread out evenly instead of stepping by 1.
    int top = 0;
    while ((std::uint64_t(1) << (top + 1)) <= size) ++top;  // floor(log2(size))
    const int finest = 2;
    const int coarsest = std::max(finest, top - 2);
    const int needed = coarsest - finest + 1;
    octave_count_ = std::min(needed, kMaxOctaves);
    float amplitude[kMaxOctaves];
    float amplitude_sum = 0;
    for (int k = 0; k < octave_count_; ++k) {
        const int e = octave_count_ == 1 ? finest
                                         : finest + (k * (coarsest - finest) + (octave_count_ - 1) / 2) /
                                                        (octave_count_ - 1);
        // kRoughness^e by repeated multiplication: exact and identical everywhere, unlike pow.
        float a = 1;
        for (int i = 0; i < e; ++i) a *= kRoughness;
        amplitude[k] = a;
        amplitude_sum += a;

        Octave& o = octaves_[static_cast<std::size_t>(k)];
        const std::uint64_t h = splitmix64(kSeed ^ (std::uint64_t(k) * 0x632be59bd9b4e019ull));
        o.shift = static_cast<std::uint32_t>(e);
        o.inv_spacing = 1.0f / static_cast<float>(std::uint64_t(1) << e);
        // Random lattice origin (fractional in x) plus a large bias so x coordinates stay positive.
        o.x_origin16 = static_cast<std::int64_t>(((std::uint64_t(1) << 40) << 16) + (h & 0xffffffffull));
        o.y_origin = (splitmix64(h) & 0xfffff) + (std::uint64_t(1) << 40);
        // Shearing the lattices differently breaks up the axis-aligned look of value noise.
        static constexpr std::int64_t kShears16[4] = {0, 32768, -24576, 16384};
        o.x_shear16 = kShears16[k % 4];
        o.shear = static_cast<float>(o.x_shear16) * (1.0f / 65536.0f);
        o.seed = splitmix64(h ^ 0x5851f42d4c957f2dull);
    }
    for (int k = 0; k < octave_count_; ++k) octaves_[static_cast<std::size_t>(k)].weight = amplitude[k] / amplitude_sum;
    // Scale so the finest octave has slope about kRelief whatever the image size.
    const Octave& fine = octaves_[0];
    relief_scale_ = kRelief * amplitude_sum / (amplitude[0] * fine.inv_spacing);

    lattice_.resize(kLatticeSize);
    for (std::size_t i = 0; i < kLatticeSize; ++i) {
        const std::uint64_t r = splitmix64(kSeed + 0x1234567ull * (i + 1));
        // 24 random bits -> [-1, 1), exactly (integer subtract, power-of-two scale).
        lattice_[i] = static_cast<float>(static_cast<std::int32_t>(r >> 40) - (1 << 23)) * (1.0f / 8388608.0f);
    }

    // Colour ramp: linear interpolation between stops (height, sRGB colour, relief).
    struct Stop {
        float h, r, g, b, relief;
    };
    static constexpr Stop kStops[] = {
        {-0.80f, 10, 30, 80, 0.10f},      // abyss
        {-0.35f, 20, 55, 120, 0.15f},     // deep water
        {-0.08f, 40, 100, 165, 0.20f},    // shallow water
        {-0.005f, 85, 160, 190, 0.25f},   // shore water
        {0.000f, 214, 200, 148, 1.0f},    // sand
        {0.012f, 200, 190, 130, 1.0f},
        {0.030f, 112, 155, 72, 1.0f},     // grass
        {0.14f, 82, 132, 56, 1.0f},
        {0.20f, 48, 102, 46, 1.0f},       // forest
        {0.30f, 38, 84, 42, 1.0f},
        {0.37f, 110, 100, 85, 1.0f},      // rock
        {0.46f, 135, 125, 115, 1.0f},
        {0.52f, 218, 220, 228, 1.0f},     // snow (leaves headroom for sunlit slopes)
        {0.80f, 232, 234, 240, 1.0f},
    };
    ramp_.resize(kRampSize);
    std::size_t s = 0;
    for (int i = 0; i < kRampSize; ++i) {
        const float h = kRampLow + (kRampHigh - kRampLow) * (static_cast<float>(i) + 0.5f) / kRampSize;
        while (s + 2 < std::size(kStops) && h > kStops[s + 1].h) ++s;
        const Stop& a = kStops[s];
        const Stop& b = kStops[s + 1];
        const float t = std::clamp((h - a.h) / (b.h - a.h), 0.0f, 1.0f);
        auto mix = [t](float u, float v) { return u + (v - u) * t; };
        ramp_[static_cast<std::size_t>(i)] = {mix(a.r, b.r), mix(a.g, b.g), mix(a.b, b.b), mix(a.relief, b.relief)};
    }
}

void ProceduralTerrain::render_row(std::uint64_t y, std::uint8_t* out) const {
    assert(y < size_);

    // Everything about each octave that depends only on y.
    struct RowOctave {
        std::uint64_t x_cell_origin;  // integer part of the lattice x origin for this row
        float x_fraction;             // fractional part, in [0, 1)
        float sy, dsy;                // y smoothstep weight and its derivative per texel
        std::uint64_t row0, row1;     // lattice table offsets of the two lattice rows
    };
    RowOctave rows[kMaxOctaves];
    for (int k = 0; k < octave_count_; ++k) {
        const Octave& o = octaves_[static_cast<std::size_t>(k)];
        const std::uint64_t v = y + o.y_origin;
        const std::uint64_t j = v >> o.shift;
        const float ty = static_cast<float>(v & ((std::uint64_t(1) << o.shift) - 1)) * o.inv_spacing;
        RowOctave& r = rows[k];
        r.sy = ty * ty * (3.0f - 2.0f * ty);
        r.dsy = 6.0f * ty * (1.0f - ty) * o.inv_spacing;
        r.row0 = splitmix64(o.seed ^ j);
        r.row1 = splitmix64(o.seed ^ (j + 1));
        const std::int64_t origin = o.x_origin16 + static_cast<std::int64_t>(y) * o.x_shear16;
        r.x_cell_origin = static_cast<std::uint64_t>(origin >> 16);
        r.x_fraction = static_cast<float>(origin & 0xffff) * (1.0f / 65536.0f);
    }

    const float* lattice = lattice_.data();
    const RampEntry* ramp = ramp_.data();

    alignas(16) float height[kBuffer];
    alignas(16) float grad_x[kBuffer];
    alignas(16) float grad_y[kBuffer];
    std::uint8_t texels[3 * kChunk + 1];
    for (std::uint64_t x0 = 0; x0 < size_; x0 += kChunk) {
        std::fill(std::begin(height), std::end(height), 0.0f);
        std::fill(std::begin(grad_x), std::end(grad_x), 0.0f);
        std::fill(std::begin(grad_y), std::end(grad_y), 0.0f);

        // fBm: add each octave's value and gradient into the buffers, four texels at a time.
        for (int k = 0; k < octave_count_; ++k) {
            const Octave& o = octaves_[static_cast<std::size_t>(k)];
            const RowOctave& r = rows[k];
            const std::uint64_t spacing_mask = (std::uint64_t(1) << o.shift) - 1;
            // Lattice coordinate of texel x is (x + x_cell_origin + x_fraction) / spacing; groups of
            // four are aligned in that coordinate so a group never straddles two cells.
            const std::uint64_t u0 = x0 + r.x_cell_origin;
            const std::uint64_t u_end = u0 + kChunk;
            std::uint64_t g = u0 & ~std::uint64_t(3);
            std::size_t dst = kPad - static_cast<std::size_t>(u0 - g);
            const V4 lane = V4{0.0f, 1.0f, 2.0f, 3.0f} + r.x_fraction;
            const float inv = o.inv_spacing;

            std::uint64_t cell = ~std::uint64_t(0);
            float v10 = 0, v11 = 0;
            V4 h0{}, h1{}, gx1{}, gy0{}, gy1{}, gyx{};
            for (; g < u_end; g += 4, dst += 4) {
                const std::uint64_t c = g >> o.shift;
                if (c != cell) {
                    // New lattice cell: blend its corners in y once, leaving a cubic in x.
                    float v00, v01;
                    if (c == cell + 1) {
                        v00 = v10;
                        v01 = v11;
                    } else {
                        v00 = lattice[(c + r.row0) & kLatticeMask];
                        v01 = lattice[(c + r.row1) & kLatticeMask];
                    }
                    v10 = lattice[(c + 1 + r.row0) & kLatticeMask];
                    v11 = lattice[(c + 1 + r.row1) & kLatticeMask];
                    cell = c;
                    const float a0 = v00 + (v01 - v00) * r.sy;  // value along the left edge
                    const float a1 = v10 + (v11 - v10) * r.sy;  // ... and the right edge
                    const float b0 = (v01 - v00) * r.dsy;       // d/dy along the left edge
                    const float b1 = (v11 - v10) * r.dsy;
                    const float w = o.weight;
                    h0 = splat(w * a0);
                    h1 = splat(w * (a1 - a0));
                    const float gx = w * (a1 - a0) * 6.0f * inv;
                    gx1 = splat(gx);
                    gy0 = splat(w * b0);
                    gy1 = splat(w * (b1 - b0));
                    gyx = splat(gx * o.shear);  // the shear moves x with y: chain rule
                }
                const V4 t = (lane + static_cast<float>(g & spacing_mask)) * inv;
                const V4 tt = t * t;
                const V4 s = tt * (3.0f - 2.0f * t);  // smoothstep
                const V4 q = t - tt;                  // smoothstep' / 6
                store4(height + dst, load4(height + dst) + (h0 + h1 * s));
                store4(grad_x + dst, load4(grad_x + dst) + gx1 * q);
                store4(grad_y + dst, load4(grad_y + dst) + ((gy0 + gy1 * s) + gyx * q));
            }
        }

        // Colour: ramp by height, hill shading from the gradient.
        const std::uint64_t n = std::min<std::uint64_t>(kChunk, size_ - x0);
        for (std::size_t i = 0; i < kChunk; i += 4) {
            const V4 h = load4(height + kPad + i);
            const V4 gx = load4(grad_x + kPad + i) * relief_scale_;
            const V4 gy = load4(grad_y + kPad + i) * relief_scale_;
            const V4 f = vclamp((h - kRampLow) * (kRampSize / (kRampHigh - kRampLow)), 0.0f, kRampSize - 1.0f);
            const V4i index = __builtin_convertvector(f, V4i);
            const RampEntry* e[4] = {&ramp[index[0]], &ramp[index[1]], &ramp[index[2]], &ramp[index[3]]};
            const V4 slope2 = gx * gx + gy * gy;
            const V4 relief = V4{e[0]->relief, e[1]->relief, e[2]->relief, e[3]->relief};
            const V4 red = V4{e[0]->r, e[1]->r, e[2]->r, e[3]->r};
            const V4 green = V4{e[0]->g, e[1]->g, e[2]->g, e[3]->g};
            const V4 blue = V4{e[0]->b, e[1]->b, e[2]->b, e[3]->b};

            // Lambert with normal (-gx, -gy, 1), relative to flat ground (lz / |light|).
            const V4 facing = vmax(kLightZ - gx * kLightX - gy * kLightY, splat(0.0f));
            const V4 lambert = facing * rsqrt_at_least_1(1.0f + slope2) * (1.0f / kLightZ);
            const V4 shade = 1.0f + relief * (lambert - 1.0f);
            const V4i r8 = __builtin_convertvector(vclamp(red * shade + 0.5f, 0.0f, 255.0f), V4i);
            const V4i g8 = __builtin_convertvector(vclamp(green * shade + 0.5f, 0.0f, 255.0f), V4i);
            const V4i b8 = __builtin_convertvector(vclamp(blue * shade + 0.5f, 0.0f, 255.0f), V4i);
            const V4i rgb = r8 | (g8 << 8) | (b8 << 16);
            // Overlapping 4-byte stores; the byte past each texel is overwritten by the next one.
            for (int l = 0; l < 4; ++l) {
                const std::int32_t word = rgb[l];
                std::memcpy(texels + 3 * (i + static_cast<std::size_t>(l)), &word, 4);
            }
        }
        std::memcpy(out + 3 * x0, texels, 3 * n);
    }

    draw_grid(y, out);
}

void ProceduralTerrain::draw_grid(std::uint64_t y, std::uint8_t* out) const {
    int scales = 0;
    while (scales < kGridScales && kGrid[scales].spacing <= size_) ++scales;
    if (scales == 0) return;

    // Horizontal lines: if row y lies on one, the whole row is darkened once, by the coarsest.
    unsigned row_darken = 0;
    for (int i = 0; i < scales; ++i) {
        const GridScale& g = kGrid[i];
        if ((y + g.width / 2) % g.spacing < g.width) row_darken = g.darken;
    }
    if (row_darken != 0) darken_span(out, 0, size_, row_darken);

    // Vertical lines, centred on multiples of the spacing. A line that a coarser scale also draws
    // is left to the coarser one, so crossings are not darkened twice.
    for (int i = 0; i < scales; ++i) {
        const GridScale& g = kGrid[i];
        if (g.darken <= row_darken) continue;
        // Extra darkening on top of the row's so the result matches darkening by g.darken alone.
        const unsigned extra = 256 - ((256 - g.darken) * 256 + (256 - row_darken) / 2) / (256 - row_darken);
        const bool coarser = i + 1 < scales;
        const std::uint64_t step = coarser ? kGrid[i + 1].spacing / g.spacing : 0;
        for (std::uint64_t m = 0; m * g.spacing < size_ + g.width; ++m) {
            if (coarser && m % step == 0) continue;
            const std::uint64_t centre = m * g.spacing;
            const std::uint64_t begin = centre >= g.width / 2 ? centre - g.width / 2 : 0;
            const std::uint64_t end = std::min(size_, centre - g.width / 2 + g.width);
            if (begin < end) darken_span(out, begin, end, extra);
        }
    }

    // Labels "X,Y" in the top-left corner of every cell, font pixels of k x k texels at (2k, 2k),
    // white with a dark outline; coarser scales are drawn last.
    for (int i = 0; i < scales; ++i) {
        const std::uint64_t spacing = kGrid[i].spacing;
        const std::uint64_t k = std::min(spacing / 256, kMaxLabelScale);
        const std::uint64_t in_cell = y % spacing;
        // Rows k .. 10k of the cell: font rows -1 .. 7 (outline above and below the 7 text rows).
        if (in_cell < k || in_cell >= 10 * k) continue;
        const int r = static_cast<int>((in_cell - k) / k) - 1;
        const std::uint64_t cell_y = y / spacing;
        for (std::uint64_t cell_x = 0; cell_x * spacing < size_; ++cell_x) {
            const LabelText text = make_label(cell_x, cell_y);
            const std::uint64_t above = label_row_bits(text, r - 1);
            const std::uint64_t here = label_row_bits(text, r);
            const std::uint64_t below = label_row_bits(text, r + 1);
            const std::uint64_t near = above | here | below;
            const std::uint64_t outline = (near | (near << 1) | (near >> 1)) & ~here;
            // Bit b is font column b - 1; the left outline column starts at cell x + k.
            const std::uint64_t left = cell_x * spacing + k;
            for (int b = 0; b <= text.width + 1 && b < 64; ++b) {
                const std::uint64_t bit = std::uint64_t(1) << b;
                if (!((here | outline) & bit)) continue;
                const std::uint64_t begin = left + static_cast<std::uint64_t>(b) * k;
                if (begin >= size_) break;
                fill_span(out, begin, std::min(size_, begin + k), (here & bit) ? 255 : 24);
            }
        }
    }
}

}  // namespace tessera::storage::build
