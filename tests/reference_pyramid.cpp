#include "reference_pyramid.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>

namespace tessera::test {

// Plain IEEE half conversions (independent of the builder's bit-twiddling ones).
float from_half(std::uint16_t h) {
    const int sign = (h >> 15) ? -1 : 1;
    const int exp = (h >> 10) & 31;
    const int mant = h & 1023;
    if (exp == 0) return static_cast<float>(sign * std::ldexp(double(mant), -24));
    if (exp == 31) return mant ? std::nanf("") : sign * INFINITY;
    return static_cast<float>(sign * std::ldexp(1.0 + mant / 1024.0, exp - 15));
}
std::uint16_t to_half(float f) {
    // Search the nearest representable half (ties to even) by brute force over the two neighbours.
    if (std::isnan(f)) return 0x7e00;
    const std::uint16_t sign = std::signbit(f) ? 0x8000 : 0;
    const double a = std::fabs(double(f));
    if (a >= 65520.0) return sign | 0x7c00;
    std::uint16_t lo = 0;  // largest magnitude code with value <= a
    std::uint16_t lo_b = 0, hi_b = 0x7c00;
    while (hi_b - lo_b > 1) {
        const std::uint16_t mid = static_cast<std::uint16_t>((lo_b + hi_b) / 2);
        if (double(from_half(mid)) <= a) lo_b = mid;
        else hi_b = mid;
    }
    lo = lo_b;
    const std::uint16_t hi = static_cast<std::uint16_t>(lo + 1);
    const double dlo = a - from_half(lo), dhi = double(from_half(hi)) - a;
    std::uint16_t pick = dlo < dhi ? lo : (dhi < dlo ? hi : ((lo & 1) ? hi : lo));
    return sign | pick;
}

namespace {

using storage::SampleType;

double to_linear(double v) { return v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4); }
double to_srgb(double v) { return v <= 0.0031308 ? v * 12.92 : 1.055 * std::pow(v, 1.0 / 2.4) - 0.055; }

double get(const RefImage& im, std::size_t i) {
    switch (im.type) {
        case SampleType::u8: return im.bytes[i];
        case SampleType::u16: { std::uint16_t v; std::memcpy(&v, &im.bytes[i * 2], 2); return v; }
        case SampleType::f16: { std::uint16_t v; std::memcpy(&v, &im.bytes[i * 2], 2); return from_half(v); }
        case SampleType::f32: { float v; std::memcpy(&v, &im.bytes[i * 4], 4); return v; }
    }
    return 0;
}

void put_int(RefImage& im, std::size_t i, std::uint64_t v) {
    if (im.type == SampleType::u8) im.bytes[i] = static_cast<std::uint8_t>(v);
    else { const std::uint16_t s = static_cast<std::uint16_t>(v); std::memcpy(&im.bytes[i * 2], &s, 2); }
}
void put_float(RefImage& im, std::size_t i, float v) {
    if (im.type == SampleType::f32) std::memcpy(&im.bytes[i * 4], &v, 4);
    else { const std::uint16_t h = to_half(v); std::memcpy(&im.bytes[i * 2], &h, 2); }
}

RefImage halve(const RefImage& in, storage::ColourSpace cs, bool has_alpha) {
    RefImage out;
    out.width = (in.width + 1) / 2;
    out.height = (in.height + 1) / 2;
    out.channels = in.channels;
    out.type = in.type;
    out.bytes.resize(std::size_t(out.width) * out.height * out.texel_bytes());
    const bool integer = in.type == SampleType::u8 || in.type == SampleType::u16;
    const double maxv = in.type == SampleType::u8 ? 255.0 : 65535.0;
    const bool srgb = cs == storage::ColourSpace::srgb;
    const std::uint32_t C = in.channels, A = has_alpha ? C - 1 : C;
    for (std::uint32_t y = 0; y < out.height; ++y)
        for (std::uint32_t x = 0; x < out.width; ++x) {
            const std::uint32_t xs[2] = {2 * x, std::min(2 * x + 1, in.width - 1)};
            const std::uint32_t ys[2] = {2 * y, std::min(2 * y + 1, in.height - 1)};
            // Texel order: (x0,y0), (x1,y0), (x0,y1), (x1,y1).
            std::size_t idx[4];
            for (int k = 0; k < 4; ++k) idx[k] = (std::size_t(ys[k / 2]) * in.width + xs[k % 2]) * C;
            const std::size_t o = (std::size_t(y) * out.width + x) * C;
            for (std::uint32_t c = 0; c < C; ++c) {
                double s[4];
                for (int k = 0; k < 4; ++k) s[k] = get(in, idx[k] + c);
                double al[4] = {1, 1, 1, 1};
                if (A < C)
                    for (int k = 0; k < 4; ++k) al[k] = get(in, idx[k] + A);
                const bool is_alpha = c == A;
                if (integer && (is_alpha || !srgb)) {
                    std::uint64_t si[4], ai[4];
                    for (int k = 0; k < 4; ++k) { si[k] = std::uint64_t(s[k]); ai[k] = std::uint64_t(al[k]); }
                    const std::uint64_t W = ai[0] + ai[1] + ai[2] + ai[3];
                    if (!is_alpha && A < C && W > 0)
                        put_int(out, o + c, (si[0] * ai[0] + si[1] * ai[1] + si[2] * ai[2] + si[3] * ai[3] + W / 2) / W);
                    else
                        put_int(out, o + c, (si[0] + si[1] + si[2] + si[3] + 2) / 4);
                    continue;
                }
                // Float arithmetic, in the documented order.
                float l[4], w[4];
                for (int k = 0; k < 4; ++k) {
                    if (integer) {
                        l[k] = static_cast<float>(to_linear(s[k] / maxv));
                        w[k] = static_cast<float>(al[k]) / static_cast<float>(maxv);
                    } else {
                        l[k] = static_cast<float>(s[k]);
                        if (srgb && !is_alpha) l[k] = static_cast<float>(to_linear(double(l[k])));
                        w[k] = std::max(static_cast<float>(al[k]), 0.0f);
                    }
                }
                if (is_alpha) {  // float alpha: a plain average
                    put_float(out, o + c, ((l[0] + l[1]) + (l[2] + l[3])) * 0.25f);
                    continue;
                }
                const float W = (w[0] + w[1]) + (w[2] + w[3]);
                float v;
                if (A < C && W > 0.0f) v = ((l[0] * w[0] + l[1] * w[1]) + (l[2] * w[2] + l[3] * w[3])) / W;
                else v = ((l[0] + l[1]) + (l[2] + l[3])) * 0.25f;
                if (integer) {
                    const double e = to_srgb(std::clamp(double(v), 0.0, 1.0));
                    put_int(out, o + c, static_cast<std::uint64_t>(std::lround(e * maxv)));
                } else {
                    put_float(out, o + c, srgb ? static_cast<float>(to_srgb(double(v))) : v);
                }
            }
        }
    return out;
}

}  // namespace

std::vector<RefImage> reference_pyramid(const RefImage& base, storage::ColourSpace cs, bool has_alpha, std::uint32_t payload) {
    std::vector<RefImage> levels{base};
    while (levels.back().width > payload || levels.back().height > payload) levels.push_back(halve(levels.back(), cs, has_alpha));
    return levels;
}

std::vector<std::uint8_t> reference_tile(const RefImage& level, std::uint32_t payload, std::uint32_t border, std::uint32_t x,
                                         std::uint32_t y) {
    const std::uint32_t T = payload + 2 * border;
    const std::size_t tb = level.texel_bytes();
    std::vector<std::uint8_t> out(std::size_t(T) * T * tb);
    for (std::uint32_t j = 0; j < T; ++j)
        for (std::uint32_t i = 0; i < T; ++i) {
            const std::int64_t sx = std::clamp<std::int64_t>(std::int64_t(x) * payload - border + i, 0, level.width - 1);
            const std::int64_t sy = std::clamp<std::int64_t>(std::int64_t(y) * payload - border + j, 0, level.height - 1);
            std::memcpy(&out[(std::size_t(j) * T + i) * tb], &level.bytes[(std::size_t(sy) * level.width + sx) * tb], tb);
        }
    return out;
}

}  // namespace tessera::test
