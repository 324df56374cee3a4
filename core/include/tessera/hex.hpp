#pragma once
// 64-bit values as 16 lower-case hex digits: store versions and checksums in URLs, headers and
// cache paths.
#include <cstdint>
#include <string>

namespace tessera {

// By hand: the HTTP server writes three of these per tile response (snprintf showed up in its
// profile). hex16_to writes the 16 digits to `out` (no terminator) and returns the end.
inline char* hex16_to(char* out, std::uint64_t v) {
    static constexpr char kDigits[] = "0123456789abcdef";
    for (int i = 15; i >= 0; --i, v >>= 4) out[i] = kDigits[v & 0xF];
    return out + 16;
}
inline std::string hex16(std::uint64_t v) {
    std::string s(16, '0');
    hex16_to(s.data(), v);
    return s;
}

}  // namespace tessera
