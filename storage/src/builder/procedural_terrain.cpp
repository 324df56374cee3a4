// The output must be bit-identical on every machine, so a*b+c must never be fused into an FMA
// (x86-64 without -march has no FMA, but e.g. -march=native or AArch64 compilers fuse by
// default). GCC's pragma goes before every include: functions inlined from headers that were
// read before it would otherwise bring contraction back into the functions below.
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif

#include "procedural_terrain.hpp"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <iterator>
#include <stdexcept>
#include <type_traits>

#if defined(__SSE__)
#include <xmmintrin.h>
#endif

namespace tessera::storage::build {
namespace {

// Four floats processed together: GCC/Clang vector extension, SSE2 on x86-64, NEON on ARM.
// Only exactly rounded operations are used on it (add, sub, mul, min/max, conversions, bit ops),
// so every lane computes exactly what scalar code would, whatever the instruction set.
typedef float V4 __attribute__((vector_size(16)));
typedef std::int32_t V4i __attribute__((vector_size(16)));

inline V4 load4(const float* p) {
    V4 v;
    std::memcpy(&v, p, sizeof v);
    return v;
}
inline void store4(float* p, V4 v) { std::memcpy(p, &v, sizeof v); }
inline V4 splat(float f) { return V4{f, f, f, f}; }
#if defined(__SSE__)
// minps/maxps compute exactly a < b ? a : b (and a > b ? a : b), which GCC does not see by itself.
inline V4 vmin(V4 a, V4 b) { return std::bit_cast<V4>(_mm_min_ps(std::bit_cast<__m128>(a), std::bit_cast<__m128>(b))); }
inline V4 vmax(V4 a, V4 b) { return std::bit_cast<V4>(_mm_max_ps(std::bit_cast<__m128>(a), std::bit_cast<__m128>(b))); }
#else
inline V4 vmin(V4 a, V4 b) { return a < b ? a : b; }
inline V4 vmax(V4 a, V4 b) { return a > b ? a : b; }
#endif
inline V4 vclamp(V4 v, float lo, float hi) { return vmin(vmax(v, splat(lo)), splat(hi)); }
inline V4 vabs(V4 v) { return std::bit_cast<V4>(std::bit_cast<V4i>(v) & 0x7fffffff); }

constexpr std::uint64_t splitmix64(std::uint64_t z) {
    z += 0x9e3779b97f4a7c15ull;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

constexpr std::uint64_t kSeed = 0x7e55e4a7e44a1ull;
constexpr std::uint64_t kOctaveSalt = 0x632be59bd9b4e019ull;

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

// Cells up to this many texels wide get their x smoothstep tabulated per row.
constexpr std::uint64_t kCurveMaxSpacing = 256;

// Cubic smoothstep s and q = s' / 6 at t = (lane + p) * inv for four texels of a cell.
inline void smoothstep(V4 lane, std::uint64_t p, float inv, V4& s, V4& q) {
    const V4 t = (lane + static_cast<float>(p)) * inv;
    const V4 tt = t * t;
    s = tt * (3.0f - 2.0f * t);
    q = t - tt;
}

// Colour ramp: heights in [kRampLow, kRampHigh] map to kRampSize entries.
constexpr int kRampSize = 1024;
constexpr float kRampLow = -0.8f;
constexpr float kRampHigh = 0.8f;

// Amplitude of an octave grows by this factor each time its wavelength doubles. 2 would be
// classic fBm (persistence 1/2); a little more keeps coastlines and peaks less ragged.
constexpr float kRoughness = 2.2f;

// Hill shading. Brightness follows how much the ground faces the light (minus the height
// gradient along the direction to the light, which is in the north-west), soft-clipped into
// [-1, 1]. The octaves are shaded in groups of kGroupOctaves consecutive wavelengths, each group
// soft-clipped on its own and the results added: one clip over the whole sum would let a steep
// coarse slope saturate it and wash out the fine detail, and the fine noise would flatten the
// coarse relief once the pyramid averages it. Each group's slope is normalised (root-sum-square
// over its octaves), so the look does not depend on the image size.
constexpr float kLightX = -0.70710678f, kLightY = -0.70710678f;  // horizontal direction to the light
constexpr int kShadeGroups = 4;
constexpr std::uint32_t kGroupOctaves = 3;
// Per group, fine .. coarse: facing at the group's typical slope, and weight in the brightness.
// Coarser groups get more, as fewer of them are left to see once the view is zoomed out.
constexpr float kGroupGain[kShadeGroups] = {1.1f, 1.4f, 1.7f, 1.8f};
constexpr float kGroupShare[kShadeGroups] = {0.25f, 0.3f, 0.35f, 0.4f};
constexpr float kHighlight = 0.6f;   // sunlit slopes brighten less than shaded ones darken (no clipping)
constexpr float kLandRelief = 0.6f;  // brightness on land ranges over about 1 +- kLandRelief

// x clipped to [-2, 2], then x - x|x|/4: smooth, linear near 0, flat at +-1.
inline V4 soft_clip(V4 x) {
    const V4 c = vclamp(x, -2.0f, 2.0f);
    return c - c * vabs(c) * 0.25f;
}

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
    std::uint8_t glyphs[48];  // 11 for the largest image; room for any 64-bit pair regardless
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
        for (int c = 0; c < w && column + c + 1 < 64; ++c)
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
        // kRoughness^e by repeated multiplication: identical everywhere, unlike pow.
        float a = 1;
        for (int i = 0; i < e; ++i) a *= kRoughness;
        amplitude[k] = a;
        amplitude_sum += a;

        Octave& o = octaves_[static_cast<std::size_t>(k)];
        const std::uint64_t h = splitmix64(kSeed + static_cast<std::uint64_t>(k) * kOctaveSalt);
        o.shift = static_cast<std::uint32_t>(e);
        o.inv_spacing = 1.0f / static_cast<float>(std::uint64_t(1) << e);
        // Random lattice origin (fractional in x) plus a large bias so x coordinates stay positive.
        o.x_origin16 = static_cast<std::int64_t>(((std::uint64_t(1) << 40) << 16) + (h & 0xffffffffull));
        o.y_origin = (splitmix64(h) & 0xfffff) + (std::uint64_t(1) << 40);
        // Shearing the lattices differently breaks up the axis-aligned look of value noise.
        static constexpr std::int64_t kShears16[4] = {0, 32768, -24576, 16384};
        o.x_shear16 = kShears16[k % 4];
        o.group = std::min<std::uint32_t>(kShadeGroups - 1, (o.shift - finest) / kGroupOctaves);
        o.seed = splitmix64(h ^ 0x5851f42d4c957f2dull);
    }
    // An octave's slope goes as amplitude / wavelength; sum the squares per shading group.
    float slope2[kShadeGroups] = {};
    for (int k = 0; k < octave_count_; ++k) {
        const Octave& o = octaves_[static_cast<std::size_t>(k)];
        const float slope = amplitude[k] * o.inv_spacing;
        slope2[o.group] += slope * slope;
    }
    for (int k = 0; k < octave_count_; ++k) {
        Octave& o = octaves_[static_cast<std::size_t>(k)];
        o.weight = amplitude[k] / amplitude_sum;
        // facing = -gain * (grad . light) / group slope, for this octave's un-weighted value v:
        // dv/dx = (a1 - a0) * 6q / spacing, and dv/dy is taken along the sheared lattice, so the
        // x slope also feeds into y. sqrt is correctly rounded, so this is deterministic too.
        const float gain = kGroupGain[o.group] * amplitude[k] / std::sqrt(slope2[o.group]);
        const float shear = static_cast<float>(o.x_shear16) * (1.0f / 65536.0f);
        o.facing_x = -gain * (kLightX + kLightY * shear) * 6.0f * o.inv_spacing;
        o.facing_y = -gain * kLightY;
    }

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
        {0.000f, 214, 200, 148, kLandRelief},    // sand
        {0.012f, 200, 190, 130, kLandRelief},
        {0.030f, 112, 155, 72, kLandRelief},     // grass
        {0.14f, 82, 132, 56, kLandRelief},
        {0.20f, 48, 102, 46, kLandRelief},       // forest
        {0.30f, 38, 84, 42, kLandRelief},
        {0.37f, 110, 100, 85, kLandRelief},      // rock
        {0.46f, 135, 125, 115, kLandRelief},
        {0.52f, 218, 220, 228, kLandRelief},     // snow (leaves headroom for sunlit slopes)
        {0.80f, 232, 234, 240, kLandRelief},
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

void ProceduralTerrain::render_row(std::uint64_t y, std::uint8_t* out) const { fbm_row<true>(y, out, nullptr); }

void ProceduralTerrain::height_row(std::uint64_t y, float* out) const { fbm_row<false>(y, nullptr, out); }

// The fBm sums of row y, chunk by chunk: with kColour, the colour (ramp by height, hill shading by
// the facing sums) into `rgb`; without, only the heights into `heights`. Both paths add the same
// octaves in the same order, so the heights are exactly those the colour is made from.
template <bool kColour>
void ProceduralTerrain::fbm_row(std::uint64_t y, std::uint8_t* out, float* heights) const {
    assert(y < size_);

    // Everything about each octave that depends only on y.
    struct RowOctave {
        std::uint64_t x_cell_origin;  // integer part of the lattice x origin for this row
        float x_fraction;             // fractional part, in [0, 1)
        float sy;                     // y smoothstep weight
        float facing_dy;              // facing_y times the derivative of the y smoothstep
        std::uint64_t row0, row1;     // lattice table offsets of the two lattice rows
        const float* curve;           // s then q for each texel of a cell, or null: compute them
    };
    RowOctave rows[kMaxOctaves];
    // The x smoothstep only depends on the position inside the cell, so for small cells it is
    // tabulated once per row (octaves have distinct spacings, so 4 + 8 + ... + 256 < 512 texels).
    alignas(16) float curves[2 * 2 * kCurveMaxSpacing];
    float* next_curve = curves;
    for (int k = 0; k < octave_count_; ++k) {
        const Octave& o = octaves_[static_cast<std::size_t>(k)];
        const std::uint64_t v = y + o.y_origin;
        const std::uint64_t j = v >> o.shift;
        const float ty = static_cast<float>(v & ((std::uint64_t(1) << o.shift) - 1)) * o.inv_spacing;
        RowOctave& r = rows[k];
        r.sy = ty * ty * (3.0f - 2.0f * ty);
        r.facing_dy = o.facing_y * (6.0f * ty * (1.0f - ty) * o.inv_spacing);
        r.row0 = splitmix64(o.seed ^ j);
        r.row1 = splitmix64(o.seed ^ (j + 1));
        const std::int64_t origin = o.x_origin16 + static_cast<std::int64_t>(y) * o.x_shear16;
        r.x_cell_origin = static_cast<std::uint64_t>(origin >> 16);
        r.x_fraction = static_cast<float>(origin & 0xffff) * (1.0f / 65536.0f);
        r.curve = nullptr;
        const std::uint64_t spacing = std::uint64_t(1) << o.shift;
        if (spacing <= kCurveMaxSpacing) {
            const V4 lane = V4{0.0f, 1.0f, 2.0f, 3.0f} + r.x_fraction;
            for (std::uint64_t p = 0; p < spacing; p += 4) {
                V4 s, q;
                smoothstep(lane, p, o.inv_spacing, s, q);
                store4(next_curve + p, s);
                store4(next_curve + spacing + p, q);
            }
            r.curve = next_curve;
            next_curve += 2 * spacing;
        }
    }

    const float* lattice = lattice_.data();
    const RampEntry* ramp = ramp_.data();

    alignas(16) float height[kBuffer];
    alignas(16) float facing[kShadeGroups][kBuffer];  // per shading group
    std::uint8_t texels[3 * kChunk + 1];
    for (std::uint64_t x0 = 0; x0 < size_; x0 += kChunk) {
        std::fill(std::begin(height), std::end(height), 0.0f);
        if constexpr (kColour)
            for (auto& f : facing) std::fill(std::begin(f), std::end(f), 0.0f);

        // fBm: add each octave's height and facing into the buffers, four texels at a time.
        for (int k = 0; k < octave_count_; ++k) {
            const Octave& o = octaves_[static_cast<std::size_t>(k)];
            const RowOctave& r = rows[k];
            float* const face = facing[o.group];
            const std::uint64_t spacing_mask = (std::uint64_t(1) << o.shift) - 1;
            // Lattice coordinate of texel x is (x + x_cell_origin + x_fraction) / spacing; groups of
            // four are aligned in that coordinate so a group never straddles two cells.
            const std::uint64_t u0 = x0 + r.x_cell_origin;
            const std::uint64_t u_end = u0 + kChunk;
            const std::uint64_t g0 = u0 & ~std::uint64_t(3);
            const V4 lane = V4{0.0f, 1.0f, 2.0f, 3.0f} + r.x_fraction;

            auto accumulate = [&](auto tabulated) {
                std::size_t dst = kPad - (u0 - g0);  // u0 - g0 is 0..3
                std::uint64_t cell = ~std::uint64_t(0);
                float v10 = 0, v11 = 0;
                V4 h0{}, h1{}, f0{}, f1{}, f2{};
                for (std::uint64_t g = g0; g < u_end; g += 4, dst += 4) {
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
                        h0 = splat(o.weight * a0);
                        h1 = splat(o.weight * (a1 - a0));
                        f0 = splat(r.facing_dy * (v01 - v00));
                        f1 = splat(r.facing_dy * ((v11 - v10) - (v01 - v00)));
                        f2 = splat(o.facing_x * (a1 - a0));
                    }
                    const std::uint64_t p = g & spacing_mask;
                    V4 s, q;
                    if constexpr (decltype(tabulated)::value) {
                        s = load4(r.curve + p);
                        q = load4(r.curve + spacing_mask + 1 + p);
                    } else {
                        smoothstep(lane, p, o.inv_spacing, s, q);
                    }
                    store4(height + dst, load4(height + dst) + (h0 + h1 * s));
                    if constexpr (kColour) store4(face + dst, load4(face + dst) + ((f0 + f1 * s) + f2 * q));
                }
            };
            if (r.curve != nullptr)
                accumulate(std::true_type{});
            else
                accumulate(std::false_type{});
        }

        if constexpr (!kColour) {
            std::memcpy(heights + x0, height + kPad, sizeof(float) * std::min<std::uint64_t>(kChunk, size_ - x0));
            continue;
        } else {
        // Colour: ramp by height, hill shading from the facing sums.
        for (std::size_t i = 0; i < kChunk; i += 4) {
            const V4 h = load4(height + kPad + i);
            const V4 f = vclamp((h - kRampLow) * (kRampSize / (kRampHigh - kRampLow)), 0.0f, kRampSize - 1.0f);
            const V4i index = __builtin_convertvector(f, V4i);
            // Gather four ramp entries (one vector each) and transpose them into r, g, b, relief.
            const V4 e0 = load4(&ramp[index[0]].r), e1 = load4(&ramp[index[1]].r);
            const V4 e2 = load4(&ramp[index[2]].r), e3 = load4(&ramp[index[3]].r);
            const V4 rg01 = __builtin_shufflevector(e0, e1, 0, 4, 1, 5);
            const V4 rg23 = __builtin_shufflevector(e2, e3, 0, 4, 1, 5);
            const V4 bl01 = __builtin_shufflevector(e0, e1, 2, 6, 3, 7);
            const V4 bl23 = __builtin_shufflevector(e2, e3, 2, 6, 3, 7);
            const V4 red = __builtin_shufflevector(rg01, rg23, 0, 1, 4, 5);
            const V4 green = __builtin_shufflevector(rg01, rg23, 2, 3, 6, 7);
            const V4 blue = __builtin_shufflevector(bl01, bl23, 0, 1, 4, 5);
            const V4 relief = __builtin_shufflevector(bl01, bl23, 2, 3, 6, 7);

            V4 light = splat(0.0f);
            for (int group = 0; group < kShadeGroups; ++group)
                light += soft_clip(load4(facing[group] + kPad + i)) * kGroupShare[group];
            // light * (kHighlight if light > 0 else 1), without a select.
            const V4 scaled = light * (0.5f * (1.0f + kHighlight)) - vabs(light) * (0.5f * (1.0f - kHighlight));
            const V4 shade = 1.0f + relief * scaled;
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
        std::memcpy(out + 3 * x0, texels, 3 * std::min<std::uint64_t>(kChunk, size_ - x0));
        }
    }

    if constexpr (kColour) draw_grid(y, out);
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
