#include "mip_reducer.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "samples.hpp"

namespace tessera::storage::build {
namespace {
constexpr std::size_t kBuckets8 = 4096;

float load_float(float v) { return v; }
float load_float(std::uint16_t h) { return half_to_float(h); }
template <class T>
T store_float(float v);
template <>
float store_float<float>(float v) { return v; }
template <>
std::uint16_t store_float<std::uint16_t>(float v) { return float_to_half(v); }
}  // namespace

MipReducer::MipReducer(std::uint32_t channels, SampleType type, ColourSpace colour_space, bool has_alpha)
    : channels_(channels), type_(type), srgb_(colour_space == ColourSpace::srgb), has_alpha_(has_alpha) {
    if (srgb_ && (type == SampleType::u8 || type == SampleType::u16)) {
        const std::uint32_t maxv = type == SampleType::u8 ? 255u : 65535u;
        decode_lut_.resize(maxv + 1);
        for (std::uint32_t i = 0; i <= maxv; ++i) decode_lut_[i] = static_cast<float>(srgb_to_linear(double(i) / maxv));
    }
    if (srgb_ && type == SampleType::u8) {
        for (int i = 0; i < 255; ++i) thresholds8_[i] = srgb_to_linear((i + 0.5) / 255.0);
        bucket8_.resize(kBuckets8);
        for (std::size_t j = 0; j < kBuckets8; ++j) {
            const double lo = double(j) / kBuckets8;
            bucket8_[j] = static_cast<std::uint8_t>(std::upper_bound(thresholds8_.begin(), thresholds8_.end(), lo) - thresholds8_.begin());
        }
    }
}

// round(255 * linear_to_srgb(v)) without a pow per texel: the first code whose threshold is above v.
std::uint8_t MipReducer::encode_srgb8(float v) const {
    if (!(v > 0.0f)) return 0;  // also NaN
    if (v >= 1.0f) return 255;
    std::uint32_t code = bucket8_[static_cast<std::size_t>(v * float(kBuckets8))];
    const double dv = v;
    while (code < 255 && dv >= thresholds8_[code]) ++code;
    return static_cast<std::uint8_t>(code);
}

template <class T>
void MipReducer::reduce_int(const T* r0, const T* r1, std::uint32_t w, T* out) const {
    const std::uint32_t c = channels_;
    const std::uint32_t ow = (w + 1) / 2;
    const std::uint32_t alpha = has_alpha_ ? c - 1 : c;  // index of the alpha channel, or c if none
    const float maxv = type_ == SampleType::u8 ? 255.0f : 65535.0f;
    for (std::uint32_t x = 0; x < ow; ++x) {
        const std::size_t i0 = std::size_t(2 * x) * c;
        const std::size_t i1 = std::size_t(std::min(2 * x + 1, w - 1)) * c;
        const T* t[4] = {r0 + i0, r0 + i1, r1 + i0, r1 + i1};
        T* o = out + std::size_t(x) * c;
        std::uint64_t A[4] = {1, 1, 1, 1};
        std::uint64_t W = 0;
        float fa[4] = {1, 1, 1, 1};
        float fw = 0;
        if (alpha < c) {
            for (int k = 0; k < 4; ++k) {
                A[k] = t[k][alpha];
                fa[k] = static_cast<float>(A[k]) / maxv;
            }
            W = A[0] + A[1] + A[2] + A[3];
            fw = (fa[0] + fa[1]) + (fa[2] + fa[3]);
            o[alpha] = static_cast<T>((W + 2) >> 2);
        }
        for (std::uint32_t ch = 0; ch < c; ++ch) {
            if (ch == alpha) continue;
            if (!srgb_) {
                const std::uint64_t s0 = t[0][ch], s1 = t[1][ch], s2 = t[2][ch], s3 = t[3][ch];
                if (alpha < c && W > 0)
                    o[ch] = static_cast<T>((s0 * A[0] + s1 * A[1] + s2 * A[2] + s3 * A[3] + W / 2) / W);
                else
                    o[ch] = static_cast<T>((s0 + s1 + s2 + s3 + 2) >> 2);
                continue;
            }
            const float l0 = decode_lut_[t[0][ch]], l1 = decode_lut_[t[1][ch]], l2 = decode_lut_[t[2][ch]], l3 = decode_lut_[t[3][ch]];
            float v;
            if (alpha < c && fw > 0.0f)
                v = ((l0 * fa[0] + l1 * fa[1]) + (l2 * fa[2] + l3 * fa[3])) / fw;
            else
                v = ((l0 + l1) + (l2 + l3)) * 0.25f;
            if constexpr (sizeof(T) == 1) {
                o[ch] = encode_srgb8(v);
            } else {
                const double e = linear_to_srgb(std::clamp(double(v), 0.0, 1.0));
                o[ch] = static_cast<T>(std::lround(e * 65535.0));
            }
        }
    }
}

template <class T>
void MipReducer::reduce_float(const T* r0, const T* r1, std::uint32_t w, T* out) const {
    const std::uint32_t c = channels_;
    const std::uint32_t ow = (w + 1) / 2;
    const std::uint32_t alpha = has_alpha_ ? c - 1 : c;
    for (std::uint32_t x = 0; x < ow; ++x) {
        const std::size_t i0 = std::size_t(2 * x) * c;
        const std::size_t i1 = std::size_t(std::min(2 * x + 1, w - 1)) * c;
        const T* t[4] = {r0 + i0, r0 + i1, r1 + i0, r1 + i1};
        T* o = out + std::size_t(x) * c;
        float a[4] = {1, 1, 1, 1};
        float fw = 0;
        if (alpha < c) {
            for (int k = 0; k < 4; ++k) a[k] = load_float(t[k][alpha]);
            o[alpha] = store_float<T>(((a[0] + a[1]) + (a[2] + a[3])) * 0.25f);
            for (float& ak : a) ak = std::max(ak, 0.0f);  // a negative alpha carries no weight
            fw = (a[0] + a[1]) + (a[2] + a[3]);
        }
        for (std::uint32_t ch = 0; ch < c; ++ch) {
            if (ch == alpha) continue;
            float l[4];
            for (int k = 0; k < 4; ++k) {
                const float s = load_float(t[k][ch]);
                l[k] = srgb_ ? static_cast<float>(srgb_to_linear(s)) : s;
            }
            float v;
            if (alpha < c && fw > 0.0f)
                v = ((l[0] * a[0] + l[1] * a[1]) + (l[2] * a[2] + l[3] * a[3])) / fw;
            else
                v = ((l[0] + l[1]) + (l[2] + l[3])) * 0.25f;
            o[ch] = store_float<T>(srgb_ ? static_cast<float>(linear_to_srgb(v)) : v);
        }
    }
}

void MipReducer::reduce(const std::uint8_t* row0, const std::uint8_t* row1, std::uint32_t in_width, std::uint8_t* out) const {
    switch (type_) {
        case SampleType::u8:
            reduce_int(row0, row1, in_width, out);
            break;
        case SampleType::u16:
            reduce_int(reinterpret_cast<const std::uint16_t*>(row0), reinterpret_cast<const std::uint16_t*>(row1), in_width,
                       reinterpret_cast<std::uint16_t*>(out));
            break;
        case SampleType::f16:
            reduce_float(reinterpret_cast<const std::uint16_t*>(row0), reinterpret_cast<const std::uint16_t*>(row1), in_width,
                         reinterpret_cast<std::uint16_t*>(out));
            break;
        case SampleType::f32:
            reduce_float(reinterpret_cast<const float*>(row0), reinterpret_cast<const float*>(row1), in_width,
                         reinterpret_cast<float*>(out));
            break;
    }
}

}  // namespace tessera::storage::build
