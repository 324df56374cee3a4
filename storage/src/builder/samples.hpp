#pragma once
// Sample conversions used by the mip computation: IEEE half floats and the sRGB transfer curve;
// and one sample of any type as a float (8- and 16-bit integers scaled to [0, 1]).
// The formulas are normative (docs/store-format.md, "Mip levels"): tests recompute the pyramid
// independently from them and expect identical bytes.
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "tessera/half_float.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::storage::build {

inline double srgb_to_linear(double v) { return v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4); }
inline double linear_to_srgb(double v) { return v <= 0.0031308 ? v * 12.92 : 1.055 * std::pow(v, 1.0 / 2.4) - 0.055; }

using tessera::half_to_float;  // shared with the client's transcoder

// The sample at `p` (native byte order, any alignment) as a float: u8 / 255, u16 / 65535, halves
// and floats as they are.
inline float sample_value(const std::uint8_t* p, SampleType t) {
    switch (t) {
        case SampleType::u8: return p[0] / 255.0f;
        case SampleType::u16: {
            std::uint16_t v;
            std::memcpy(&v, p, 2);
            return v / 65535.0f;
        }
        case SampleType::f16: {
            std::uint16_t v;
            std::memcpy(&v, p, 2);
            return half_to_float(v);
        }
        case SampleType::f32: {
            float v;
            std::memcpy(&v, p, 4);
            return v;
        }
    }
    return 0;
}

// Round to nearest, ties to even; overflow gives infinity; NaN stays NaN.
inline std::uint16_t float_to_half(float f) {
    const std::uint32_t x = std::bit_cast<std::uint32_t>(f);
    const std::uint16_t sign = static_cast<std::uint16_t>((x >> 16) & 0x8000u);
    const std::uint32_t a = x & 0x7fffffffu;
    if (a > 0x7f800000u) return static_cast<std::uint16_t>(sign | 0x7e00u);
    if (a >= 0x47800000u) return static_cast<std::uint16_t>(sign | 0x7c00u);  // >= 65536, or inf
    if (a < 0x38800000u) {  // below the smallest normal half: subnormal, exact scaling then rounding
        const float scaled = std::bit_cast<float>(a) * 16777216.0f;
        return static_cast<std::uint16_t>(sign | static_cast<std::uint16_t>(std::nearbyint(scaled)));
    }
    const std::uint32_t r = a - 0x38000000u;  // rebias exponent 127 -> 15
    std::uint32_t h = r >> 13;
    const std::uint32_t rem = r & 0x1fffu;
    if (rem > 0x1000u || (rem == 0x1000u && (h & 1u))) ++h;
    return static_cast<std::uint16_t>(sign | h);
}

}  // namespace tessera::storage::build
