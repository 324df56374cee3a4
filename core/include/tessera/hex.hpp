#pragma once
// 64-bit values as 16 lower-case hex digits: store versions and checksums in URLs, headers and
// cache paths.
#include <cstdint>
#include <string>

namespace tessera {

// By hand: the HTTP server writes three of these per tile response (snprintf showed up in its
// profile).
inline std::string hex16(std::uint64_t v) {
    static constexpr char kDigits[] = "0123456789abcdef";
    std::string s(16, '0');
    for (int i = 15; i >= 0; --i, v >>= 4) s[static_cast<std::size_t>(i)] = kDigits[v & 0xF];
    return s;
}

}  // namespace tessera
