#pragma once
// IEEE 754 half-precision samples (f16 stores): the builder reads them to compute mips, the client
// to transcode tiles; both must read the same values (docs/store-format.md, "Mip levels").
#include <bit>
#include <cmath>
#include <cstdint>

namespace tessera {

// Exact: every half is a float.
inline float half_to_float(std::uint16_t h) {
    const std::uint32_t sign = std::uint32_t(h & 0x8000u) << 16;
    const std::uint32_t exp = (h >> 10) & 0x1fu, mant = h & 0x3ffu;
    if (exp == 0) {
        const float f = std::ldexp(static_cast<float>(mant), -24);  // zero or subnormal, exact
        return sign ? -f : f;
    }
    const std::uint32_t bits = exp == 31 ? (sign | 0x7f800000u | (mant << 13)) : (sign | ((exp + 112) << 23) | (mant << 13));
    return std::bit_cast<float>(bits);
}

}  // namespace tessera
