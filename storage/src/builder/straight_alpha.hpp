#pragma once
// Tiles hold straight (unassociated) alpha, as PNG does (docs/store-format.md, "Alpha"). A source
// whose file holds associated (premultiplied) alpha -- OpenEXR, a TIFF with ExtraSamples = 1 --
// is made straight as it is read: colour divided by alpha in the file's own encoding, colour
// under alpha 0 cleared. Re-associating a straight u8/u16 texel gives the file's texel back
// exactly (the division rounds to nearest, so s * a / max lands within half a code of it).
#include <algorithm>
#include <cstddef>
#include <cstdint>

#include "tessera/half_float.hpp"
#include "samples.hpp"
#include "tessera/storage/image_source.hpp"

namespace tessera::storage::build {

namespace straight_alpha_detail {

template <class T>
void unassociate_int(T* s, std::size_t texels, std::uint32_t c, std::uint64_t maxv) {
    for (std::size_t i = 0; i < texels; ++i, s += c) {
        const std::uint64_t a = s[c - 1];
        for (std::uint32_t ch = 0; ch + 1 < c; ++ch)
            s[ch] = a == 0 ? T(0) : static_cast<T>(std::min<std::uint64_t>(maxv, (std::uint64_t(s[ch]) * maxv + a / 2) / a));
    }
}

inline float unassociate(float v, float a) { return a > 0.0f ? v / a : 0.0f; }

}  // namespace straight_alpha_detail

// Makes `texels` texels of associated-alpha samples straight, in place.
inline void make_alpha_straight(std::uint8_t* samples, std::size_t texels, const SourceInfo& info) {
    using namespace straight_alpha_detail;
    const std::uint32_t c = info.channels;
    if (!info.has_alpha || c < 2) return;
    switch (info.sample_type) {
        case SampleType::u8: unassociate_int(samples, texels, c, 255); break;
        case SampleType::u16: unassociate_int(reinterpret_cast<std::uint16_t*>(samples), texels, c, 65535); break;
        case SampleType::f16: {
            auto* s = reinterpret_cast<std::uint16_t*>(samples);
            for (std::size_t i = 0; i < texels; ++i, s += c) {
                const float a = half_to_float(s[c - 1]);
                for (std::uint32_t ch = 0; ch + 1 < c; ++ch) s[ch] = float_to_half(unassociate(half_to_float(s[ch]), a));
            }
            break;
        }
        case SampleType::f32: {
            auto* s = reinterpret_cast<float*>(samples);
            for (std::size_t i = 0; i < texels; ++i, s += c)
                for (std::uint32_t ch = 0; ch + 1 < c; ++ch) s[ch] = unassociate(s[ch], s[c - 1]);
            break;
        }
    }
}

}  // namespace tessera::storage::build
