#include "page_table.hpp"

#include <algorithm>
#include <string>

namespace tessera::client {
namespace {

std::uint32_t shrink(std::uint32_t n, std::uint32_t level) {
    return static_cast<std::uint32_t>((std::uint64_t(n) + (std::uint64_t(1) << level) - 1) >> level);
}

DirtyRect unite(const DirtyRect& a, const DirtyRect& b) {
    return DirtyRect{a.level, std::min(a.x0, b.x0), std::min(a.y0, b.y0), std::max(a.x1, b.x1), std::max(a.y1, b.y1)};
}

bool covers(const DirtyRect& outer, const DirtyRect& inner) {
    return outer.x0 <= inner.x0 && outer.y0 <= inner.y0 && outer.x1 >= inner.x1 && outer.y1 >= inner.y1;
}

// The entry points at a resident page finer than `level`: valid and entry level < level. With
// the reserved bits 0, valid entries are [kValidBit, kValidBit | 31 << 24]; invalid ones (below
// kValidBit) wrap around to huge values.
bool shadowed(PageEntry e, std::uint32_t level) {
    return e - PageTable::kValidBit < (level << PageTable::kLevelShift);
}

std::string page_name(std::uint32_t level, std::uint32_t x, std::uint32_t y) {
    return "page (" + std::to_string(level) + ", " + std::to_string(x) + ", " + std::to_string(y) + ")";
}

}  // namespace

std::uint32_t PageTableLayout::levels_for(std::uint32_t pages_x, std::uint32_t pages_y) {
    if (pages_x == 0 || pages_y == 0) return 0;
    std::uint32_t levels = 1;
    while (shrink(pages_x, levels - 1) > 1 || shrink(pages_y, levels - 1) > 1) ++levels;
    return levels;
}

std::uint64_t PageTable::table_bytes(std::uint32_t pages_x, std::uint32_t pages_y, std::uint32_t levels) {
    std::uint64_t entries = 0;
    for (std::uint32_t l = 0; l < levels && l < 64; ++l) entries += std::uint64_t(shrink(pages_x, l)) * shrink(pages_y, l);
    return entries * sizeof(PageEntry);
}

std::pair<std::uint32_t, std::uint32_t> PageTableLayout::dense_level_origin(std::uint32_t pages_x, std::uint32_t pages_y,
                                                                       std::uint32_t level) {
    if (level == 0 || pages_y == 0) return {0, 0};
    const std::uint32_t u = pages_y - 1, up = std::min(level - 1, 31u);
    return {pages_x, up + u - (u >> up)};
}

std::pair<std::uint64_t, std::uint64_t> PageTableLayout::dense_packed_size(std::uint32_t pages_x, std::uint32_t pages_y) {
    const std::uint32_t levels = levels_for(pages_x, pages_y);
    std::uint64_t width = pages_x, height = pages_y;
    for (std::uint32_t l = 1; l < levels; ++l) {
        const auto [x, y] = dense_level_origin(pages_x, pages_y, l);
        width = std::max<std::uint64_t>(width, std::uint64_t(x) + shrink(pages_x, l));
        height = std::max<std::uint64_t>(height, std::uint64_t(y) + shrink(pages_y, l));
    }
    return {width, height};
}

bool PageTableLayout::dense_packing_fits(std::uint32_t pages_x, std::uint32_t pages_y) {
    const auto [width, height] = dense_packed_size(pages_x, pages_y);
    return width <= kMaxDenseSide && height <= kMaxDenseSide;
}

Result<PageTable> PageTable::create(TextureId texture, std::uint32_t pages_x, std::uint32_t pages_y,
                                    std::uint32_t levels, std::size_t max_bytes, bool allow_sparse) {
    const std::string what = "page table for texture " + std::to_string(texture) + " (" + std::to_string(pages_x) +
                             "x" + std::to_string(pages_y) + " pages, " + std::to_string(levels) + " levels)";
    if (pages_x == 0 || pages_y == 0 || pages_x > kMaxPagesPerAxis || pages_y > kMaxPagesPerAxis)
        return make_error(Errc::invalid_argument,
                          what + ": level-0 page counts must be 1.." + std::to_string(kMaxPagesPerAxis));
    const std::uint32_t expected = levels_for(pages_x, pages_y);
    if (levels != expected)
        return make_error(Errc::invalid_argument, what + ": expected " + std::to_string(expected) +
                                                      " levels (halving, rounding up, down to 1x1)");
    const std::uint64_t bytes = table_bytes(pages_x, pages_y, levels);
    const bool sparse = allow_sparse && (bytes > max_bytes || !dense_packing_fits(pages_x, pages_y));
    if (bytes > max_bytes && !sparse) {
        const auto mib = [](std::uint64_t b) { return std::to_string((b + (std::uint64_t(1) << 20) - 1) >> 20); };
        return make_error(Errc::resource_exhausted,
                          what + " needs " + mib(bytes) + " MiB, over the " + mib(max_bytes) +
                              " MiB bound for dense page tables (4 bytes per page, all levels); "
                              "use larger pages, raise the bound or allow sparse tables "
                              "(ResidencyConfig::sparse_tables)");
    }
    PageTable t;
    t.texture_ = texture;
    t.levels_.resize(levels);
    std::size_t offset = 0;
    for (std::uint32_t l = 0; l < levels; ++l) {
        t.levels_[l] = Level{shrink(pages_x, l), shrink(pages_y, l), offset};
        offset += std::size_t(t.levels_[l].width) * t.levels_[l].height;
    }
    t.dirty_.resize(levels);
    if (sparse) {
        t.init_sparse();
    } else {
        t.entries_.assign(offset, kEmptyEntry);
        t.mark_all_dirty();
    }
    return t;
}

std::uint8_t PageTable::resident_level(std::uint32_t level, std::uint32_t x, std::uint32_t y) const {
    if (!contains(level, x, y)) return kNotResident;
    const PageEntry e = entry(level, x, y);
    return entry_valid(e) ? static_cast<std::uint8_t>(entry_level(e)) : kNotResident;
}

std::size_t PageTable::memory_bytes() const {
    if (!sparse_) return entries_.size() * sizeof(PageEntry);
    // The index: a node (key, value, next, cached hash) per block plus a bucket array.
    return block_data_.capacity() * sizeof(PageEntry) + blocks_.capacity() * sizeof(Block) +
           free_blocks_.capacity() * sizeof(std::uint32_t) + block_index_.size() * 32 +
           block_index_.bucket_count() * sizeof(void*);
}

Status PageTable::map(std::uint32_t level, std::uint32_t x, std::uint32_t y, SlotId slot) {
    if (!contains(level, x, y))
        return make_error(Errc::invalid_argument, "map: " + page_name(level, x, y) + " is outside the page table");
    if (slot >= kMaxSlots)
        return make_error(Errc::invalid_argument, "map: slot " + std::to_string(slot) + " does not fit an entry");
    if (is_mapped(level, x, y))
        return make_error(Errc::invalid_argument, "map: " + page_name(level, x, y) + " is already mapped");
    if (sparse_) {
        hold_blocks(level, x, y);
        fill_sparse(level, x, y, make_entry(slot, level));
        ++mapped_;
        return {};
    }
    fill(level, x, y, make_entry(slot, level));
    ++mapped_;
    return {};
}

Status PageTable::unmap(std::uint32_t level, std::uint32_t x, std::uint32_t y) {
    if (!contains(level, x, y))
        return make_error(Errc::invalid_argument, "unmap: " + page_name(level, x, y) + " is outside the page table");
    if (!is_mapped(level, x, y))
        return make_error(Errc::invalid_argument, "unmap: " + page_name(level, x, y) + " is not mapped");
    // The parent's entry already names the nearest resident page above this one.
    const PageEntry above = level + 1 < levels() ? entry(level + 1, x >> 1, y >> 1) : kEmptyEntry;
    if (sparse_) {
        fill_sparse(level, x, y, above);
        release_blocks(level, x, y);
        --mapped_;
        return {};
    }
    fill(level, x, y, above);
    --mapped_;
    return {};
}

// Level by level below the changed page, scanning only the children of the previous level's
// changed entries (their bounding box, doubled): an entry takes `e` unless it points at a resident
// page finer than `level` (a resident page between it and the changed page, itself included),
// which then shadows its whole subtree. Before map(), no descendant points at the page; before
// unmap(), none points above it; so the entries taking `e` are exactly those whose nearest
// resident page changes. A child of a shadowed entry is shadowed too (its nearest resident page
// is at most as coarse), so scanning a box rather than following children one by one changes
// nothing but the speed, and the scan stops at the first level where nothing changed.
void PageTable::fill(std::uint32_t level, std::uint32_t x, std::uint32_t y, PageEntry e) {
    at(level, x, y) = e;
    add_dirty(DirtyRect{level, x, y, x + 1, y + 1});
    DirtyRect box{level, x, y, x + 1, y + 1};  // entries changed at the level above
    for (std::uint32_t l = level; l-- > 0;) {
        const Level& L = levels_[l];
        const std::uint32_t sx0 = 2 * box.x0, sy0 = 2 * box.y0;
        const std::uint32_t sx1 = std::min(2 * box.x1, L.width), sy1 = std::min(2 * box.y1, L.height);
        DirtyRect changed{l, ~0u, ~0u, 0, 0};
        for (std::uint32_t cy = sy0; cy < sy1; ++cy) {
            PageEntry* row = entries_.data() + L.offset + std::size_t(cy) * L.width;
            std::uint32_t first = sx0;
            while (first < sx1 && shadowed(row[first], level)) ++first;
            if (first == sx1) continue;
            std::uint32_t last = sx1 - 1;
            while (shadowed(row[last], level)) --last;
            for (std::uint32_t cx = first; cx <= last; ++cx) row[cx] = shadowed(row[cx], level) ? row[cx] : e;
            changed.x0 = std::min(changed.x0, first);
            changed.x1 = std::max(changed.x1, last + 1);
            changed.y0 = std::min(changed.y0, cy);
            changed.y1 = cy + 1;
        }
        if (changed.x1 == 0) break;
        add_dirty(changed);
        box = changed;
    }
}

void PageTable::add_dirty(DirtyRect r) {
    std::vector<DirtyRect>& list = dirty_[r.level];
    for (const DirtyRect& d : list)
        if (covers(d, r)) return;
    // Absorb every rectangle whose union with r wastes nothing (overlapping or abutting ones that
    // line up); repeat, since the grown r may now line up with others.
    for (bool merged = true; merged;) {
        merged = false;
        for (std::size_t i = 0; i < list.size(); ++i) {
            const DirtyRect u = unite(list[i], r);
            if (u.area() <= list[i].area() + r.area()) {
                r = u;
                list[i] = list.back();
                list.pop_back();
                merged = true;
                break;
            }
        }
    }
    list.push_back(r);
    while (list.size() > kMaxDirtyRectsPerLevel) {
        std::size_t bi = 0, bj = 1;
        std::uint64_t best = ~std::uint64_t{0};
        for (std::size_t i = 0; i < list.size(); ++i)
            for (std::size_t j = i + 1; j < list.size(); ++j) {
                const std::uint64_t u = unite(list[i], list[j]).area(), sum = list[i].area() + list[j].area();
                const std::uint64_t waste = u > sum ? u - sum : 0;
                if (waste < best) best = waste, bi = i, bj = j;
            }
        list[bi] = unite(list[bi], list[bj]);
        list[bj] = list.back();
        list.pop_back();
    }
}

void PageTable::take_dirty(std::vector<DirtyRect>& out) {
    for (auto& list : dirty_) {
        out.insert(out.end(), list.begin(), list.end());
        list.clear();
    }
}

bool PageTable::has_dirty() const {
    if (sparse_)
        return !freed_blocks_.empty() ||
               std::any_of(dirty_blocks_.begin(), dirty_blocks_.end(), [&](std::uint32_t i) { return blocks_[i].dirty; });
    return std::any_of(dirty_.begin(), dirty_.end(), [](const auto& l) { return !l.empty(); });
}

void PageTable::mark_all_dirty() {
    if (sparse_) {
        for (std::uint32_t i = 0; i < blocks_.size(); ++i)
            if (blocks_[i].live) mark_block_dirty(i);
        return;
    }
    for (std::uint32_t l = 0; l < levels(); ++l) {
        dirty_[l].clear();
        dirty_[l].push_back(DirtyRect{l, 0, 0, levels_[l].width, levels_[l].height});
    }
}

}  // namespace tessera::client
