#pragma once
// Vocabulary of the client runtime: pages and their feedback ids (shared with scene/ and the
// builder, so defined in tessera/page_key.hpp), page formats, physical slots.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <string_view>

#include "tessera/page_key.hpp"
#include "tessera/tile.hpp"

namespace tessera::client {

// The page vocabulary (tessera/page_key.hpp), by its client names.
using tessera::TextureId;
using tessera::kMaxPagesPerAxis;
using tessera::kMaxLevels;
using tessera::PageKey;
using tessera::FeedbackId;
using tessera::kNoPage;
using tessera::pack_feedback;
using tessera::unpack_feedback;
using tessera::page_hash_key;
using tessera::PageKeyHash;

// Default bound on one texture's dense page table; larger textures get a two-level table.
constexpr std::size_t kDefaultPageTableBytes = std::size_t(256) << 20;

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
// Whether the GPU decodes the format's samples from sRGB when its store's samples are sRGB colour:
// rgba8, bc1 and bc7 have sRGB variants; the others hold data, sampled as stored, so sRGB colour
// in them would be encoded a second time on its way to the screen (check_page_format refuses it).
constexpr bool page_format_decodes_srgb(PageFormat f) {
    return f == PageFormat::rgba8 || f == PageFormat::bc1 || f == PageFormat::bc7;
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
