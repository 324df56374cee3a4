// The sparse storage of PageTable: blocks of 32×32 entries, allocated where a page of their
// region (five levels deep) is resident; see page_table.hpp, "Storage, sparse".
#include <algorithm>
#include <cassert>

#include "page_table.hpp"

namespace tessera::client {
namespace {

constexpr std::uint32_t kBlockMask = PageTable::kBlockSide - 1;

// As in page_table.cpp: the entry points at a resident page finer than `level`.
bool shadowed(PageEntry e, std::uint32_t level) {
    return e - PageTable::kValidBit < (level << PageTable::kLevelShift);
}

std::uint32_t blocks_for(std::uint32_t pages) { return (pages + PageTable::kBlockSide - 1) >> PageTable::kBlockShift; }

}  // namespace

// The coarse levels that fit one block are allocated for good: every walk ends there (a level
// wider than a block has a level 5 above it, since ceil(w / 32) >= 2 is not the 1×1 level).
// Coarsest first: a new block reads the level 5 above it.
void PageTable::init_sparse() {
    sparse_ = true;
    for (std::uint32_t l = levels(); l-- > 0 && level_width(l) <= kBlockSide && level_height(l) <= kBlockSide;)
        blocks_[ensure_block(l, 0, 0)].pinned = true;
}

const PageEntry* PageTable::find_block(std::uint32_t level, std::uint32_t bx, std::uint32_t by) const {
    const auto it = block_index_.find(block_key(level, bx, by));
    return it == block_index_.end() ? nullptr : block_data_.data() + std::size_t(it->second) * kBlockEntries;
}

PageEntry PageTable::sparse_entry(std::uint32_t level, std::uint32_t x, std::uint32_t y) const {
    for (;;) {
        if (const PageEntry* b = find_block(level, x >> kBlockShift, y >> kBlockShift))
            return b[(y & kBlockMask) * kBlockSide + (x & kBlockMask)];
        // Nothing of levels level .. level+4 is resident here: the page 5 levels up decides.
        assert(level + kBlockShift < levels());
        level += kBlockShift;
        x >>= kBlockShift;
        y >>= kBlockShift;
    }
}

std::span<const PageEntry> PageTable::block_entries(std::uint32_t level, std::uint32_t bx, std::uint32_t by) const {
    const PageEntry* b = sparse_ ? find_block(level, bx, by) : nullptr;
    return b ? std::span<const PageEntry>(b, kBlockEntries) : std::span<const PageEntry>();
}

// A new block starts as what its entries resolved to while it was unallocated: the entry of the
// page (level+5, bx, by), which no map or unmap in progress below level+5 has changed.
std::uint32_t PageTable::ensure_block(std::uint32_t level, std::uint32_t bx, std::uint32_t by) {
    const auto [it, inserted] = block_index_.try_emplace(block_key(level, bx, by), 0);
    if (!inserted) return it->second;
    const PageEntry init = level + kBlockShift < levels() ? sparse_entry(level + kBlockShift, bx, by) : kEmptyEntry;
    std::uint32_t index;
    if (!free_blocks_.empty()) {
        index = free_blocks_.back();
        free_blocks_.pop_back();
    } else {
        index = static_cast<std::uint32_t>(blocks_.size());
        blocks_.emplace_back();
        block_data_.resize(block_data_.size() + kBlockEntries);
    }
    it->second = index;
    blocks_[index] = Block{level, bx, by, 0, true, false, false};
    std::fill_n(block_data_.begin() + std::ptrdiff_t(std::size_t(index) * kBlockEntries), kBlockEntries, init);
    mark_block_dirty(index);
    return index;
}

void PageTable::mark_block_dirty(std::uint32_t index) {
    if (blocks_[index].dirty) return;
    blocks_[index].dirty = true;
    dirty_blocks_.push_back(index);
}

void PageTable::free_block(std::uint32_t index) {
    Block& b = blocks_[index];
    block_index_.erase(block_key(b.level, b.bx, b.by));
    freed_blocks_.push_back(DirtyBlock{b.level, b.bx, b.by, false});
    b.live = b.dirty = false;
    free_blocks_.push_back(index);
}

// Page (level, x, y)'s level-(level-k) descendants start at x << k: block x >> (5 - k).
void PageTable::hold_blocks(std::uint32_t level, std::uint32_t x, std::uint32_t y) {
    for (std::uint32_t k = 0; k < kBlockShift && k <= level; ++k)
        ++blocks_[ensure_block(level - k, x >> (kBlockShift - k), y >> (kBlockShift - k))].residents;
}

void PageTable::release_blocks(std::uint32_t level, std::uint32_t x, std::uint32_t y) {
    for (std::uint32_t k = 0; k < kBlockShift && k <= level; ++k) {
        const auto it = block_index_.find(block_key(level - k, x >> (kBlockShift - k), y >> (kBlockShift - k)));
        assert(it != block_index_.end());
        Block& b = blocks_[it->second];
        if (--b.residents == 0 && !b.pinned) free_block(it->second);
    }
}

void PageTable::fill_block(std::uint32_t index, std::uint32_t x0, std::uint32_t y0, std::uint32_t x1, std::uint32_t y1,
                           std::uint32_t level, PageEntry e) {
    const Block& b = blocks_[index];
    const std::uint32_t bx0 = b.bx << kBlockShift, by0 = b.by << kBlockShift;
    x0 = std::max(x0, bx0), y0 = std::max(y0, by0);
    x1 = std::min(x1, bx0 + kBlockSide), y1 = std::min(y1, by0 + kBlockSide);
    PageEntry* data = block_data_.data() + std::size_t(index) * kBlockEntries;
    bool changed = false;
    for (std::uint32_t y = y0; y < y1; ++y) {
        PageEntry* row = data + (y - by0) * kBlockSide - bx0;
        for (std::uint32_t x = x0; x < x1; ++x)
            if (!shadowed(row[x], level) && row[x] != e) row[x] = e, changed = true;
    }
    if (changed) mark_block_dirty(index);
}

// The dense fill's rule (page_table.cpp) applied to the allocated blocks only: in the subtree of
// the changed page every entry not shadowed by a finer resident page takes `e`. Unallocated
// blocks need nothing: they resolve through the blocks five levels up, which hold_blocks keeps
// allocated down to level - 4 and which this loop updates. Per level the allocated blocks of the
// subtree are found by lookups, or by a scan of all blocks when the subtree has more blocks than
// the table (a coarse page): the cost follows the allocated blocks, never the texture size.
void PageTable::fill_sparse(std::uint32_t level, std::uint32_t x, std::uint32_t y, PageEntry e) {
    {
        const auto it = block_index_.find(block_key(level, x >> kBlockShift, y >> kBlockShift));
        assert(it != block_index_.end());
        block_data_[std::size_t(it->second) * kBlockEntries + (y & kBlockMask) * kBlockSide + (x & kBlockMask)] = e;
        mark_block_dirty(it->second);
    }
    for (std::uint32_t l = level; l-- > 0;) {
        const std::uint32_t k = level - l;
        const auto x0 = std::uint32_t(std::min<std::uint64_t>(std::uint64_t(x) << k, level_width(l)));
        const auto y0 = std::uint32_t(std::min<std::uint64_t>(std::uint64_t(y) << k, level_height(l)));
        const auto x1 = std::uint32_t(std::min<std::uint64_t>(std::uint64_t(x + 1) << k, level_width(l)));
        const auto y1 = std::uint32_t(std::min<std::uint64_t>(std::uint64_t(y + 1) << k, level_height(l)));
        if (x0 >= x1 || y0 >= y1) continue;
        const std::uint32_t bx0 = x0 >> kBlockShift, by0 = y0 >> kBlockShift;
        const std::uint32_t bx1 = blocks_for(x1), by1 = blocks_for(y1);
        if (std::uint64_t(bx1 - bx0) * (by1 - by0) <= block_index_.size()) {
            for (std::uint32_t by = by0; by < by1; ++by)
                for (std::uint32_t bx = bx0; bx < bx1; ++bx)
                    if (const auto it = block_index_.find(block_key(l, bx, by)); it != block_index_.end())
                        fill_block(it->second, x0, y0, x1, y1, level, e);
        } else {
            for (std::uint32_t i = 0; i < blocks_.size(); ++i) {
                const Block& b = blocks_[i];
                if (b.live && b.level == l && b.bx >= bx0 && b.bx < bx1 && b.by >= by0 && b.by < by1)
                    fill_block(i, x0, y0, x1, y1, level, e);
            }
        }
    }
}

void PageTable::take_dirty_blocks(std::vector<DirtyBlock>& out) {
    out.insert(out.end(), freed_blocks_.begin(), freed_blocks_.end());
    freed_blocks_.clear();
    for (const std::uint32_t i : dirty_blocks_) {
        Block& b = blocks_[i];
        if (!b.live || !b.dirty) continue;
        b.dirty = false;
        out.push_back(DirtyBlock{b.level, b.bx, b.by, true});
    }
    dirty_blocks_.clear();
}

}  // namespace tessera::client
