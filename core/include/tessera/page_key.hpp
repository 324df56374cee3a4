#pragma once
// Pages of a virtual texture and their packed feedback ids: the client's pages, the CPU feedback
// of scene/ and the build's visibility mask all speak it (docs/client.md, "One frame, end to end").
//
// A virtual texture (one store) is cut into pages, one per store tile: page (level, x, y) of
// texture t is tile (level, x, y) of that texture's store. Several virtual textures share one
// physical pool; `texture` tells them apart.
#include <cstddef>
#include <cstdint>

#include "tessera/tile.hpp"

namespace tessera {

using TextureId = std::uint16_t;

// Limits of the feedback id (below): 2^20 pages per axis (2^28 texels at 256-texel pages), 32
// levels, 2^16 textures (at least 2^16 pages per axis and 20 levels are promised).
constexpr std::uint32_t kMaxPagesPerAxis = 1u << 20;
constexpr std::uint32_t kMaxLevels = 32;

struct PageKey {
    TextureId texture = 0;
    std::uint8_t level = 0;
    std::uint32_t x = 0;
    std::uint32_t y = 0;
    friend bool operator==(const PageKey&, const PageKey&) = default;
    PageKey parent() const { return PageKey{texture, static_cast<std::uint8_t>(level + 1), x >> 1, y >> 1}; }
    TileKey tile() const { return TileKey{level, x, y}; }  // the tile of the texture's store
};

// Feedback id: one 64-bit value per feedback pixel (written by the GL feedback pass as an RG32UI
// texel: low word first). Layout, from bit 0: x (20 bits), y (20), level (5), texture (16); bits
// 61..63 zero. kNoPage ("no virtual texture here") has every bit set, so it can never be a page.
using FeedbackId = std::uint64_t;
constexpr FeedbackId kNoPage = ~FeedbackId{0};

constexpr FeedbackId pack_feedback(const PageKey& k) {
    return FeedbackId(k.x & 0xFFFFFu) | (FeedbackId(k.y & 0xFFFFFu) << 20) | (FeedbackId(k.level & 31u) << 40) |
           (FeedbackId(k.texture) << 45);
}
constexpr PageKey unpack_feedback(FeedbackId id) {
    return PageKey{static_cast<TextureId>((id >> 45) & 0xFFFFu), static_cast<std::uint8_t>((id >> 40) & 31u),
                   static_cast<std::uint32_t>(id & 0xFFFFFu), static_cast<std::uint32_t>((id >> 20) & 0xFFFFFu)};
}
// A page key as a map key (the feedback packing: unique for keys within the limits above).
constexpr std::uint64_t page_hash_key(const PageKey& k) { return pack_feedback(k); }

struct PageKeyHash {
    std::size_t operator()(const PageKey& k) const noexcept {
        std::uint64_t h = page_hash_key(k) * 0x9E3779B97F4A7C15ull;
        return static_cast<std::size_t>(h ^ (h >> 29));
    }
};

}  // namespace tessera
