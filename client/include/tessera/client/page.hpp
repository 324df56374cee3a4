#pragma once
// Vocabulary of the client runtime: virtual pages, their packed feedback ids, physical slots.
//
// A virtual texture (one store) is cut into pages, one per store tile: page (level, x, y) of
// texture t is tile (level, x, y) of that texture's store. Several virtual textures share one
// physical pool; `texture` tells them apart. Tiles themselves are named in tessera/tile.hpp.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <string_view>

#include "tessera/tile.hpp"

namespace tessera::client {

using TextureId = std::uint16_t;

// Limits of the feedback id (below): 2^20 pages per axis (2^28 texels at 256-texel pages), 32
// levels, 2^16 textures (at least 2^16 pages per axis and 20 levels are promised).
constexpr std::uint32_t kMaxPagesPerAxis = 1u << 20;
constexpr std::uint32_t kMaxLevels = 32;
// Default bound on one texture's dense page table; larger textures get a two-level table.
constexpr std::size_t kDefaultPageTableBytes = std::size_t(256) << 20;

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

// How a page's texels sit in the physical pool (docs/client.md, "Page formats"). Block formats
// (bc*) pack 4x4 texels per block, so their pages are a multiple of 4 texels per side.
enum class PageFormat : std::uint8_t {
    rgba8 = 0,  // 4 bytes per texel; every store (samples converted to 8 bits)
    bc1 = 1,    // 0.5 byte per texel: opaque colour
    bc4 = 2,    // 0.5 byte per texel: one channel (grey, height preview)
    bc5 = 3,    // 1 byte per texel: two channels (normals' x and y, grey + alpha)
    r16 = 4,    // 2 bytes per texel: a 1-channel u16 store, exactly
    r16f = 5,   // 2 bytes per texel: a 1-channel f16 store, exactly
    r32f = 6,   // 4 bytes per texel: a 1-channel f32 store, exactly
    bc7 = 7,    // 1 byte per texel: colour with or without alpha, at higher quality than bc1
};
std::string_view to_string(PageFormat f);
std::optional<PageFormat> parse_page_format(std::string_view s);
constexpr bool is_block_compressed(PageFormat f) {
    return f == PageFormat::bc1 || f == PageFormat::bc4 || f == PageFormat::bc5 || f == PageFormat::bc7;
}
// The page format whose blocks a block-codec store holds (tiles it uploads as they are).
constexpr std::optional<PageFormat> page_format_of(Codec c) {
    switch (c) {
        case Codec::bc1: return PageFormat::bc1;
        case Codec::bc4: return PageFormat::bc4;
        case Codec::bc5: return PageFormat::bc5;
        case Codec::bc7: return PageFormat::bc7;
        default: return std::nullopt;
    }
}
// Bytes of one page `tile_size` texels on a side (block formats: tile_size a multiple of 4).
constexpr std::size_t page_bytes(PageFormat f, std::uint32_t tile_size) {
    const std::size_t texels = std::size_t(tile_size) * tile_size;
    switch (f) {
        case PageFormat::rgba8: return texels * 4;
        case PageFormat::bc1: return texels / 2;
        case PageFormat::bc4: return texels / 2;
        case PageFormat::bc5: return texels;
        case PageFormat::bc7: return texels;
        case PageFormat::r16: return texels * 2;
        case PageFormat::r16f: return texels * 2;
        case PageFormat::r32f: return texels * 4;
    }
    return 0;
}
// Bytes of one page upload: the page, and with `second_level` its half-size level after it (block
// formats, whose second level the GPU cannot render into: the transcode threads make it).
constexpr std::size_t page_upload_bytes(PageFormat f, std::uint32_t tile_size, bool second_level) {
    return page_bytes(f, tile_size) + (second_level ? page_bytes(f, tile_size / 2) : 0);
}

// A slot of the physical page pool (the GPU page atlas), 0..pool_size-1.
using SlotId = std::uint32_t;
constexpr SlotId kNoSlot = ~SlotId{0};

}  // namespace tessera::client
