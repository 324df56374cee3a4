#pragma once
// PageTable: the CPU copy of one virtual texture's page table, the texture the VT shader reads in
// one fetch (docs/client.md, "One frame, end to end", steps 1 and 7).
//
// Geometry. Level 0 is the finest level and has pages_x × pages_y pages; level L has
// ceil(pages_x / 2^L) × ceil(pages_y / 2^L) pages, and the last level is 1×1 (exactly the store's
// tile grid: ceil(ceil(W / 2^L) / P) == ceil(ceil(W / P) / 2^L)). Page (L, x, y) has the parent
// (L+1, x/2, y/2) and up to four children (L-1, 2x..2x+1, 2y..2y+1), clipped to level L-1.
//
// Storage, dense (the default). One array of 32-bit entries per level, rows contiguous (row y of
// level L starts at y * level_width(L)), all levels in one allocation: sum_L w_L·h_L entries ≈ 4/3 ·
// pages_x · pages_y · 4 bytes (a 4096×4096-page texture, 2^20 texels per side at 256-texel pages:
// ~85 MiB). create() refuses a table larger than a bound (default 256 MiB) with a message, unless
// sparse tables are allowed.
//
// Storage, sparse (create(..., allow_sparse): chosen when the dense table is over the bound or its
// renderer packing is over kMaxDenseSide). Each level is cut into blocks of kBlockSide² entries
// (32×32, 4 KiB); block (L, bx, by) covers pages [32·bx, 32·bx + 32) × [32·by, 32·by + 32) of
// level L, i.e. the level-L descendants of the one page (L+5, bx, by). A block is allocated while
// a page of levels L .. L+4 inside that region is resident (each resident page holds at most five
// blocks), and always for the coarse levels that fit one block (w, h <= 32). Allocated blocks hold
// the exact entries, as the dense table does. An entry of an unallocated block equals the entry of
// page (L+5, x >> 5, y >> 5): nothing on the path between them is resident; entry() repeats that
// step until it meets an allocated block (at most ceil(levels / 5) steps). Memory: at most
// 5 · resident pages + the coarse levels' blocks, whatever the texture size (a 2^24-texel texture
// at P = 248, 67,651 pages per side, costs 4 KiB per resident page at most 5 times over, never its
// 22.7 GiB dense table). Dirty tracking is per block (take_dirty_blocks); the renderer mirrors the
// blocks in a two-level table (docs/renderer.md). level_entries() and take_dirty() are for dense
// tables only.
//
// Entry encoding (what the R32UI page-table texture holds, one texel per page):
//
//     bit 31       valid: some page on the path from this page to the root is resident
//     bits 29..30  reserved, always 0
//     bits 24..28  resident level R (0..31): the level of the nearest resident page on that path
//     bits  0..23  slot of that page in the physical pool (0 .. 2^24-1)
//
//   An entry with bit 31 clear is exactly 0: nothing resident on the path (the shader draws its
//   "no data" colour; with the coarsest levels pinned this only happens before they load).
//   Entry (L, x, y) is "fallback" when R > L: it points at the ancestor (R, x >> (R-L), y >> (R-L))
//   and the shader samples that page at the level-R position, so the lookup is always one fetch.
//   Page (L, x, y) is itself mapped exactly when its entry is valid and R == L.
//   In GLSL:  uint e = texelFetch(table_L, ivec2(page), 0).r;  bool valid = (e >> 31) != 0u;
//             uint level = (e >> 24) & 31u;  uint slot = e & 0xFFFFFFu;
//   Note: level sizes round up (ceil), GL's mip chain rounds down, so for page counts that are not
//   powers of two the levels cannot be the mip levels of one GL texture; upload each level to its
//   own texture (or layer / atlas region) sized level_width(L) × level_height(L).
//
// Incremental update. map(P) writes P's entry and every descendant entry whose nearest resident
// page is coarser than P (a descent that stops below resident descendants); unmap(P) re-points P
// and the descendants that pointed at P to P's nearest resident ancestor (or 0). The descent goes
// level by level over the bounding box of the children of the entries changed one level up, and
// stops at the first level where nothing changed: its cost is about the entries that change (the
// bounding boxes of changed entries, doubled), never the whole table. Mapping or unmapping a
// coarse page over a sparsely resident region rewrites its whole region (up to 4/3 · 4^L
// entries): inherent to fallback entries; that is why the coarsest levels are pinned.
//
// Dirty tracking. Every changed entry is recorded in a short per-level list of rectangles (at most
// kMaxDirtyRectsPerLevel; rectangles that overlap or abut without waste are merged, and when the
// list overflows the pair whose union wastes least is merged). take_dirty() hands them out for the
// uploader and clears them. A new table is all dirty (its entries, all 0, were never uploaded).
//
// Not thread-safe; owned by the render thread (Residency wraps it).
#include <cstddef>
#include <cstdint>
#include <utility>
#include <span>
#include <unordered_map>
#include <vector>

#include "tessera/client/page.hpp"
#include "tessera/client/page_table_layout.hpp"
#include "tessera/result.hpp"

namespace tessera::client {

// A rectangle of changed entries of one level: x in [x0, x1), y in [y0, y1) (half-open).
struct DirtyRect {
    std::uint32_t level = 0;
    std::uint32_t x0 = 0, y0 = 0, x1 = 0, y1 = 0;
    std::uint64_t area() const { return std::uint64_t(x1 - x0) * (y1 - y0); }
    bool contains(std::uint32_t x, std::uint32_t y) const { return x >= x0 && x < x1 && y >= y0 && y < y1; }
    friend bool operator==(const DirtyRect&, const DirtyRect&) = default;
};

// A block of a sparse table that changed: allocated (upload block_entries()) or freed.
struct DirtyBlock {
    std::uint32_t level = 0;
    std::uint32_t bx = 0, by = 0;
    bool allocated = false;
    friend bool operator==(const DirtyBlock&, const DirtyBlock&) = default;
};

class PageTable : public PageTableLayout {
public:
    // The entry encoding, block and packing constants and the dense packing: PageTableLayout
    // (tessera/client/page_table_layout.hpp), shared with the renderer.
    static constexpr std::uint8_t kNotResident = 255;   // resident_level() when nothing is
    static constexpr std::size_t kDefaultMaxBytes = kDefaultPageTableBytes;
    static constexpr std::size_t kMaxDirtyRectsPerLevel = 8;

    // Bytes of the entries of such a table (all levels).
    static std::uint64_t table_bytes(std::uint32_t pages_x, std::uint32_t pages_y, std::uint32_t levels);

    // Dense when its table fits `max_bytes` (and, with allow_sparse, dense_packing_fits), else
    // sparse when allow_sparse. Errors (invalid_argument): a page count of 0 or over
    // kMaxPagesPerAxis, `levels` other than levels_for(pages_x, pages_y); (resource_exhausted): a
    // dense table over `max_bytes` without allow_sparse.
    static Result<PageTable> create(TextureId texture, std::uint32_t pages_x, std::uint32_t pages_y,
                                    std::uint32_t levels, std::size_t max_bytes = kDefaultMaxBytes,
                                    bool allow_sparse = false);

    TextureId texture() const { return texture_; }
    std::uint32_t levels() const { return static_cast<std::uint32_t>(levels_.size()); }
    std::uint32_t level_width(std::uint32_t level) const { return levels_[level].width; }
    std::uint32_t level_height(std::uint32_t level) const { return levels_[level].height; }
    bool contains(std::uint32_t level, std::uint32_t x, std::uint32_t y) const {
        return level < levels_.size() && x < levels_[level].width && y < levels_[level].height;
    }
    bool sparse() const { return sparse_; }
    // Bytes held: the dense entries, or the sparse blocks and their index.
    std::size_t memory_bytes() const;
    std::size_t mapped_pages() const { return mapped_; }
    std::size_t allocated_blocks() const { return block_index_.size(); }  // sparse tables

    // Makes page (level, x, y) resident in `slot`. Errors (invalid_argument): outside the
    // geometry, slot >= kMaxSlots, the page already mapped. On error nothing changes.
    Status map(std::uint32_t level, std::uint32_t x, std::uint32_t y, SlotId slot);
    // Makes page (level, x, y) non-resident. Errors (invalid_argument): outside, not mapped.
    Status unmap(std::uint32_t level, std::uint32_t x, std::uint32_t y);

    // Queries; the page must be inside the geometry (contains()), except resident_level(), which
    // answers kNotResident outside it.
    PageEntry entry(std::uint32_t level, std::uint32_t x, std::uint32_t y) const {
        return sparse_ ? sparse_entry(level, x, y) : at(level, x, y);
    }
    // Level of the nearest resident page among (level, x, y) and its ancestors, or kNotResident.
    std::uint8_t resident_level(std::uint32_t level, std::uint32_t x, std::uint32_t y) const;
    bool is_mapped(std::uint32_t level, std::uint32_t x, std::uint32_t y) const {
        const PageEntry e = entry(level, x, y);
        return entry_valid(e) && entry_level(e) == level;
    }
    // The slot page (level, x, y) is mapped to, or kNoSlot when it is not mapped.
    SlotId mapped_slot(std::uint32_t level, std::uint32_t x, std::uint32_t y) const {
        return is_mapped(level, x, y) ? entry_slot(entry(level, x, y)) : kNoSlot;
    }

    // Dense tables: the entries of one level, level_width(level) per row, rows in y order.
    std::span<const PageEntry> level_entries(std::uint32_t level) const {
        return {entries_.data() + levels_[level].offset,
                std::size_t(levels_[level].width) * levels_[level].height};
    }
    // Sparse tables: the kBlockEntries entries of block (level, bx, by), rows of kBlockSide
    // (entries past the level's edge are unused); empty when the block is not allocated.
    std::span<const PageEntry> block_entries(std::uint32_t level, std::uint32_t bx, std::uint32_t by) const;

    // Dense tables: appends the rectangles changed since the last call (all levels, finest first)
    // to `out` and forgets them. Every entry whose value changed lies in a rectangle of its level.
    void take_dirty(std::vector<DirtyRect>& out);
    // Sparse tables: appends the blocks freed since the last call, then those allocated or changed
    // (still allocated), and forgets them. Frees come first, so a mirror applying them in order
    // never holds more blocks than the table did.
    void take_dirty_blocks(std::vector<DirtyBlock>& out);
    bool has_dirty() const;
    // Marks every level whole (every allocated block for sparse tables), e.g. after the GPU
    // texture was recreated.
    void mark_all_dirty();

private:
    struct Level {
        std::uint32_t width = 0;
        std::uint32_t height = 0;
        std::size_t offset = 0;  // first entry in entries_
    };
    PageTable() = default;
    PageEntry& at(std::uint32_t level, std::uint32_t x, std::uint32_t y) {
        return entries_[levels_[level].offset + std::size_t(y) * levels_[level].width + x];
    }
    const PageEntry& at(std::uint32_t level, std::uint32_t x, std::uint32_t y) const {
        return entries_[levels_[level].offset + std::size_t(y) * levels_[level].width + x];
    }
    // Sets (level, x, y) to `e`, then the descendants whose entry does not point at a resident
    // page finer than `level`; records the changes in the dirty lists.
    void fill(std::uint32_t level, std::uint32_t x, std::uint32_t y, PageEntry e);
    void add_dirty(DirtyRect r);

    // Sparse tables (page_table_sparse.cpp).
    struct Block {
        std::uint32_t level = 0, bx = 0, by = 0;
        std::uint32_t residents = 0;  // resident pages of levels level .. level+4 in its region
        bool live = false, pinned = false, dirty = false;
    };
    static std::uint64_t block_key(std::uint32_t level, std::uint32_t bx, std::uint32_t by) {
        return (std::uint64_t(level) << 40) | (std::uint64_t(by) << 20) | bx;
    }
    void init_sparse();
    const PageEntry* find_block(std::uint32_t level, std::uint32_t bx, std::uint32_t by) const;
    PageEntry sparse_entry(std::uint32_t level, std::uint32_t x, std::uint32_t y) const;
    std::uint32_t ensure_block(std::uint32_t level, std::uint32_t bx, std::uint32_t by);
    void mark_block_dirty(std::uint32_t index);
    void free_block(std::uint32_t index);
    // The blocks holding page (level, x, y)'s descendants of levels level-4 .. level (one per
    // level): allocates them (map) or releases them (unmap).
    void hold_blocks(std::uint32_t level, std::uint32_t x, std::uint32_t y);
    void release_blocks(std::uint32_t level, std::uint32_t x, std::uint32_t y);
    void fill_sparse(std::uint32_t level, std::uint32_t x, std::uint32_t y, PageEntry e);
    // Sets every entry of block `index` inside [x0, x1) × [y0, y1) (level coordinates) that does
    // not point at a resident page finer than `level` to `e`.
    void fill_block(std::uint32_t index, std::uint32_t x0, std::uint32_t y0, std::uint32_t x1, std::uint32_t y1,
                    std::uint32_t level, PageEntry e);

    TextureId texture_ = 0;
    std::vector<Level> levels_;
    std::vector<PageEntry> entries_;
    std::vector<std::vector<DirtyRect>> dirty_;  // per level
    std::size_t mapped_ = 0;

    bool sparse_ = false;
    std::unordered_map<std::uint64_t, std::uint32_t> block_index_;  // block_key -> index in blocks_
    std::vector<Block> blocks_;
    std::vector<PageEntry> block_data_;  // kBlockEntries per entry of blocks_
    std::vector<std::uint32_t> free_blocks_;
    std::vector<std::uint32_t> dirty_blocks_;  // indices (may repeat or be stale: Block::dirty decides)
    std::vector<DirtyBlock> freed_blocks_;
};

}  // namespace tessera::client
