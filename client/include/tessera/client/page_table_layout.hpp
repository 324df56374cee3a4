#pragma once
// The page table as the renderer receives it: the entry encoding, the sparse tables' blocks and
// the dense tables' packing into one texture. The runtime's PageTable (docs/client.md, "Page
// table") writes entries in this form; the renderer and the VT shader (vt_sample.glsl) read them.
//
// Entry (one 32-bit texel per page):
//     bit 31       valid: some page on the path from this page to the root is resident
//     bits 29..30  reserved, always 0
//     bits 24..28  resident level R (0..31): the level of the nearest resident page on that path
//     bits  0..23  slot of that page in the physical pool (0 .. 2^24-1)
// An entry with bit 31 clear is exactly 0: nothing resident on the path. R > L: a fallback to the
// ancestor at level R.
#include <cstdint>
#include <utility>

#include "tessera/client/page.hpp"

namespace tessera::client {

using PageEntry = std::uint32_t;

struct PageTableLayout {
    // Entry encoding (see the top of this file).
    static constexpr PageEntry kValidBit = 1u << 31;
    static constexpr unsigned kLevelShift = 24;
    static constexpr PageEntry kLevelMask = 0x1Fu;       // after shifting
    static constexpr PageEntry kSlotMask = 0xFFFFFFu;
    static constexpr SlotId kMaxSlots = kSlotMask + 1;  // slots 0 .. 2^24-1 fit an entry
    static constexpr PageEntry kEmptyEntry = 0;         // nothing resident on the path
    // Sparse tables: blocks of kBlockSide × kBlockSide entries.
    static constexpr unsigned kBlockShift = 5;
    static constexpr std::uint32_t kBlockSide = 1u << kBlockShift;
    static constexpr std::uint32_t kBlockEntries = kBlockSide * kBlockSide;
    // A dense table is at most this many entries per side in the renderer's packing (level 0 and
    // a column of levels 1..: dense_packed_size): GL 4.5's smallest allowed
    // GL_MAX_TEXTURE_SIZE, so a dense table always fits the renderer's dense path.
    static constexpr std::uint32_t kMaxDenseSide = 16384;

    static constexpr PageEntry make_entry(SlotId slot, std::uint32_t level) {
        return kValidBit | ((level & kLevelMask) << kLevelShift) | (slot & kSlotMask);
    }
    static constexpr bool entry_valid(PageEntry e) { return (e & kValidBit) != 0; }
    static constexpr std::uint32_t entry_level(PageEntry e) { return (e >> kLevelShift) & kLevelMask; }
    static constexpr SlotId entry_slot(PageEntry e) { return e & kSlotMask; }

    // The level count of a pyramid whose level 0 has pages_x × pages_y pages (last level 1×1);
    // 0 when either is 0.
    static std::uint32_t levels_for(std::uint32_t pages_x, std::uint32_t pages_y);

    // The renderer's packing of a dense table into one 2D texture: level 0 at (0, 0), levels 1..
    // in a column to its right at x = pages_x, level L >= 1 from row (L - 1) + U - (U >> (L - 1)),
    // U = pages_y - 1. That leaves level L 1 + (U >> L) + bit L-1 of U >= ceil(pages_y / 2^L)
    // rows, and it is closed-form, so the shader computes a level's origin with a shift and two
    // adds instead of indexing a per-level uniform array per pixel (which a software
    // rasterizer gathers lane by lane). A few rows over the tight packing (at most levels - 1).
    static std::pair<std::uint32_t, std::uint32_t> dense_level_origin(std::uint32_t pages_x, std::uint32_t pages_y,
                                                                      std::uint32_t level);
    // The texture size of that packing (width, height), entries.
    static std::pair<std::uint64_t, std::uint64_t> dense_packed_size(std::uint32_t pages_x, std::uint32_t pages_y);
    // Whether a dense table of this geometry fits the renderer's packing (kMaxDenseSide).
    static bool dense_packing_fits(std::uint32_t pages_x, std::uint32_t pages_y);
};

}  // namespace tessera::client
