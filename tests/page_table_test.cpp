// PageTable (fallback entries, incremental updates, dirty rectangles) and Residency (the shared
// physical pool, replacement order, pinning, unmap-before-overwrite).
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <map>
#include <optional>
#include <random>
#include <tuple>
#include <vector>

#include "page_table.hpp"
#include "residency.hpp"

namespace tessera::client {
namespace {

// ---------------------------------------------------------------------------------------------
// Brute-force reference: which pages are mapped (per level, dense, -1 = not mapped), and every
// entry recomputed from scratch by walking up to the nearest mapped ancestor.

struct Reference {
    std::uint32_t levels = 0;
    std::vector<std::uint32_t> w, h;
    std::vector<std::vector<std::int64_t>> slot;  // per level, y * w + x

    Reference(std::uint32_t px, std::uint32_t py) {
        std::uint32_t x = px, y = py;
        while (true) {
            w.push_back(x);
            h.push_back(y);
            slot.emplace_back(std::size_t(x) * y, -1);
            if (x == 1 && y == 1) break;
            x = (x + 1) / 2;
            y = (y + 1) / 2;
        }
        levels = static_cast<std::uint32_t>(w.size());
    }
    std::int64_t& at(std::uint32_t l, std::uint32_t x, std::uint32_t y) { return slot[l][std::size_t(y) * w[l] + x]; }
    PageEntry expected(std::uint32_t l, std::uint32_t x, std::uint32_t y) const {
        for (std::uint32_t k = l; k < levels; ++k) {
            const std::uint32_t kx = x >> (k - l), ky = y >> (k - l);
            const std::int64_t s = slot[k][std::size_t(ky) * w[k] + kx];
            if (s >= 0)
                return PageTable::kValidBit | (k << 24) | static_cast<std::uint32_t>(s);
        }
        return 0;
    }
};

void expect_matches(const PageTable& t, const Reference& ref, const char* where) {
    ASSERT_EQ(t.levels(), ref.levels);
    for (std::uint32_t l = 0; l < ref.levels; ++l) {
        const auto row = t.level_entries(l);
        ASSERT_EQ(row.size(), std::size_t(ref.w[l]) * ref.h[l]);
        for (std::uint32_t y = 0; y < ref.h[l]; ++y)
            for (std::uint32_t x = 0; x < ref.w[l]; ++x) {
                // Plain comparisons first (this runs millions of times), the assertion on a mismatch.
                const PageEntry want = ref.expected(l, x, y);
                const bool mapped = ref.slot[l][std::size_t(y) * ref.w[l] + x] >= 0;
                const unsigned want_level = want ? PageTable::entry_level(want) : 255u;
                if (row[std::size_t(y) * ref.w[l] + x] == want && t.entry(l, x, y) == want &&
                    t.resident_level(l, x, y) == want_level && t.is_mapped(l, x, y) == mapped)
                    continue;
                ASSERT_EQ(row[std::size_t(y) * ref.w[l] + x], want) << where << ": level " << l << " (" << x << ", " << y << ")";
                ASSERT_EQ(t.entry(l, x, y), want);
                ASSERT_EQ(t.resident_level(l, x, y), want_level);
                ASSERT_EQ(t.is_mapped(l, x, y), mapped);
            }
    }
}

std::vector<std::vector<PageEntry>> snapshot(const PageTable& t) {
    std::vector<std::vector<PageEntry>> s;
    for (std::uint32_t l = 0; l < t.levels(); ++l) {
        const auto e = t.level_entries(l);
        s.emplace_back(e.begin(), e.end());
    }
    return s;
}

// Every entry that differs between `before` and now lies in a dirty rectangle of its level; the
// rectangles are inside the level and at most kMaxDirtyRectsPerLevel per level.
void expect_dirty_covers(const PageTable& t, const std::vector<std::vector<PageEntry>>& before,
                         const std::vector<DirtyRect>& dirty) {
    std::vector<std::size_t> per_level(t.levels(), 0);
    for (const DirtyRect& r : dirty) {
        ASSERT_LT(r.level, t.levels());
        ASSERT_LT(r.x0, r.x1);
        ASSERT_LT(r.y0, r.y1);
        ASSERT_LE(r.x1, t.level_width(r.level));
        ASSERT_LE(r.y1, t.level_height(r.level));
        ++per_level[r.level];
    }
    for (std::size_t n : per_level) ASSERT_LE(n, PageTable::kMaxDirtyRectsPerLevel);
    for (std::uint32_t l = 0; l < t.levels(); ++l) {
        const auto now = t.level_entries(l);
        const std::uint32_t w = t.level_width(l);
        for (std::size_t i = 0; i < now.size(); ++i) {
            if (now[i] == before[l][i]) continue;
            const std::uint32_t x = static_cast<std::uint32_t>(i % w), y = static_cast<std::uint32_t>(i / w);
            const bool covered = std::any_of(dirty.begin(), dirty.end(),
                                             [&](const DirtyRect& r) { return r.level == l && r.contains(x, y); });
            ASSERT_TRUE(covered) << "changed entry level " << l << " (" << x << ", " << y << ") not in a dirty rect";
        }
    }
}

PageTable make_table(std::uint32_t px, std::uint32_t py, TextureId id = 1) {
    auto t = PageTable::create(id, px, py, PageTable::levels_for(px, py));
    EXPECT_TRUE(t.ok()) << (t.ok() ? "" : t.error().message);
    return std::move(t).value();
}

// ---------------------------------------------------------------------------------------------
// PageTable

TEST(PageTable, GeometryAndMemory) {
    EXPECT_EQ(PageTable::levels_for(1, 1), 1u);
    EXPECT_EQ(PageTable::levels_for(2, 1), 2u);
    EXPECT_EQ(PageTable::levels_for(16, 16), 5u);
    EXPECT_EQ(PageTable::levels_for(17, 3), 6u);
    EXPECT_EQ(PageTable::levels_for(67, 43), 8u);
    PageTable t = make_table(67, 43);
    const std::uint32_t widths[] = {67, 34, 17, 9, 5, 3, 2, 1}, heights[] = {43, 22, 11, 6, 3, 2, 1, 1};
    std::size_t entries = 0;
    for (std::uint32_t l = 0; l < 8; ++l) {
        EXPECT_EQ(t.level_width(l), widths[l]);
        EXPECT_EQ(t.level_height(l), heights[l]);
        EXPECT_EQ(t.level_entries(l).size(), std::size_t(widths[l]) * heights[l]);
        entries += std::size_t(widths[l]) * heights[l];
    }
    EXPECT_EQ(t.memory_bytes(), entries * 4);
    EXPECT_EQ(PageTable::table_bytes(67, 43, 8), entries * 4);
    // ~4/3 x pages0 x 4 bytes for big power-of-two tables.
    EXPECT_EQ(PageTable::table_bytes(4096, 4096, 13), (std::uint64_t(4) * 4096 * 4096 - 1) / 3 * 4);
    EXPECT_EQ(t.texture(), 1);
    EXPECT_EQ(t.mapped_pages(), 0u);
    for (std::uint32_t l = 0; l < 8; ++l)
        for (PageEntry e : t.level_entries(l)) EXPECT_EQ(e, PageTable::kEmptyEntry);
}

TEST(PageTable, EntryEncoding) {
    const PageEntry e = PageTable::make_entry(0xABCDEF, 17);
    EXPECT_EQ(e, 0x80000000u | (17u << 24) | 0xABCDEFu);
    EXPECT_TRUE(PageTable::entry_valid(e));
    EXPECT_EQ(PageTable::entry_level(e), 17u);
    EXPECT_EQ(PageTable::entry_slot(e), 0xABCDEFu);
    EXPECT_EQ(e & 0x60000000u, 0u);  // reserved bits
    EXPECT_FALSE(PageTable::entry_valid(PageTable::kEmptyEntry));
    EXPECT_NE(PageTable::make_entry(0, 0), PageTable::kEmptyEntry);  // slot 0 at level 0 is still valid
    EXPECT_EQ(PageTable::make_entry(PageTable::kMaxSlots - 1, 31), 0x9FFFFFFFu);
}

TEST(PageTable, RejectsBadGeometry) {
    EXPECT_FALSE(PageTable::create(1, 0, 4, 1).ok());
    EXPECT_FALSE(PageTable::create(1, 4, 0, 1).ok());
    EXPECT_FALSE(PageTable::create(1, kMaxPagesPerAxis + 1, 1, 22).ok());
    auto wrong = PageTable::create(1, 16, 16, 4);
    ASSERT_FALSE(wrong.ok());
    EXPECT_EQ(wrong.error().code, Errc::invalid_argument);
    EXPECT_NE(wrong.error().message.find("expected 5 levels"), std::string::npos) << wrong.error().message;
}

TEST(PageTable, RefusesTablesOverTheSizeBound) {
    // 65536^2 pages: ~21.3 GiB of entries.
    auto huge = PageTable::create(3, 65536, 65536, 17);
    ASSERT_FALSE(huge.ok());
    EXPECT_EQ(huge.error().code, Errc::resource_exhausted);
    const std::string& m = huge.error().message;
    EXPECT_NE(m.find("texture 3"), std::string::npos) << m;
    EXPECT_NE(m.find("65536x65536 pages"), std::string::npos) << m;
    EXPECT_NE(m.find("21846 MiB"), std::string::npos) << m;
    EXPECT_NE(m.find("over the 256 MiB bound"), std::string::npos) << m;
    std::printf("size-limit message: %s\n", m.c_str());
    // The bound is configurable: 8192^2 pages (~341 MiB) fits 512 MiB but not the default.
    EXPECT_FALSE(PageTable::create(3, 8192, 8192, 14).ok());
    EXPECT_TRUE(PageTable::create(3, 100, 100, 8, 100 * 100 * 4 * 2).ok());
    EXPECT_FALSE(PageTable::create(3, 100, 100, 8, 100 * 100 * 4).ok());
    // Largest default-sized square: 4096^2 pages (~85 MiB) is accepted.
    EXPECT_TRUE(PageTable::create(3, 4096, 4096, 13).ok());
}

TEST(PageTable, MapUnmapPreconditions) {
    PageTable t = make_table(5, 3);
    EXPECT_FALSE(t.map(0, 5, 0, 1).ok());
    EXPECT_FALSE(t.map(0, 0, 3, 1).ok());
    EXPECT_FALSE(t.map(9, 0, 0, 1).ok());
    EXPECT_FALSE(t.map(0, 0, 0, PageTable::kMaxSlots).ok());
    EXPECT_FALSE(t.unmap(0, 0, 0).ok());
    ASSERT_TRUE(t.map(1, 1, 1, 7).ok());
    auto again = t.map(1, 1, 1, 8);
    ASSERT_FALSE(again.ok());
    EXPECT_NE(again.error().message.find("already mapped"), std::string::npos);
    EXPECT_EQ(t.mapped_slot(1, 1, 1), 7u);
    EXPECT_EQ(t.mapped_slot(0, 2, 2), kNoSlot);  // a child: falls back, not mapped
    EXPECT_EQ(t.resident_level(0, 2, 2), 1);
    EXPECT_EQ(t.resident_level(0, 4, 0), 255);
    EXPECT_EQ(t.resident_level(0, 99, 0), 255);  // outside
    ASSERT_TRUE(t.unmap(1, 1, 1).ok());
    EXPECT_FALSE(t.unmap(1, 1, 1).ok());
    EXPECT_EQ(t.mapped_pages(), 0u);
}

TEST(PageTable, FallbackPointsAtNearestResidentAncestor) {
    PageTable t = make_table(8, 8);  // levels 8,4,2,1
    ASSERT_TRUE(t.map(3, 0, 0, 100).ok());
    for (std::uint32_t l = 0; l < 4; ++l)
        for (PageEntry e : t.level_entries(l)) EXPECT_EQ(e, PageTable::make_entry(100, 3));
    ASSERT_TRUE(t.map(1, 1, 0, 5).ok());  // covers level-0 x 2..3, y 0..1
    EXPECT_EQ(t.entry(0, 2, 1), PageTable::make_entry(5, 1));
    EXPECT_EQ(t.entry(0, 1, 1), PageTable::make_entry(100, 3));
    EXPECT_EQ(t.entry(2, 0, 0), PageTable::make_entry(100, 3));
    ASSERT_TRUE(t.map(2, 0, 0, 9).ok());  // between: must not override the level-1 page's region
    EXPECT_EQ(t.entry(0, 2, 1), PageTable::make_entry(5, 1));
    EXPECT_EQ(t.entry(0, 1, 1), PageTable::make_entry(9, 2));
    EXPECT_EQ(t.entry(0, 4, 4), PageTable::make_entry(100, 3));
    ASSERT_TRUE(t.unmap(2, 0, 0).ok());
    EXPECT_EQ(t.entry(0, 1, 1), PageTable::make_entry(100, 3));
    EXPECT_EQ(t.entry(0, 2, 1), PageTable::make_entry(5, 1));
    ASSERT_TRUE(t.unmap(3, 0, 0).ok());  // the root: everything but the level-1 region goes empty
    EXPECT_EQ(t.entry(0, 1, 1), PageTable::kEmptyEntry);
    EXPECT_EQ(t.entry(3, 0, 0), PageTable::kEmptyEntry);
    EXPECT_EQ(t.entry(0, 3, 0), PageTable::make_entry(5, 1));
}

// Long random map/unmap sequences against the brute-force reference, with dirty-rectangle
// coverage checked after every operation and over batches of operations.
void random_sequence(std::uint32_t px, std::uint32_t py, int ops, std::uint64_t seed) {
    SCOPED_TRACE(testing::Message() << px << "x" << py << " seed " << seed);
    PageTable t = make_table(px, py);
    Reference ref(px, py);
    std::mt19937_64 rng(seed);
    std::vector<std::tuple<std::uint32_t, std::uint32_t, std::uint32_t>> mapped;
    std::vector<DirtyRect> dirty;
    t.take_dirty(dirty);  // initial all-dirty
    auto batch_before = snapshot(t);
    SlotId next_slot = 0;
    for (int i = 0; i < ops; ++i) {
        const bool single = i % 3 == 0 && i % 7 != 0;  // check this op's rectangles alone
        if (single) {  // flush what earlier ops left, checking it as a batch
            dirty.clear();
            t.take_dirty(dirty);
            ASSERT_NO_FATAL_FAILURE(expect_dirty_covers(t, batch_before, dirty));
            batch_before = snapshot(t);
        }
        const auto before = snapshot(t);
        // Mostly maps early, then a balance; levels picked uniformly so coarse pages toggle often.
        const bool do_map = mapped.empty() || std::uniform_int_distribution<int>(0, 99)(rng) < (i < ops / 4 ? 70 : 50);
        std::uint32_t l, x, y;
        if (do_map) {
            l = std::uniform_int_distribution<std::uint32_t>(0, ref.levels - 1)(rng);
            x = std::uniform_int_distribution<std::uint32_t>(0, ref.w[l] - 1)(rng);
            y = std::uniform_int_distribution<std::uint32_t>(0, ref.h[l] - 1)(rng);
            if (ref.at(l, x, y) >= 0) {
                ASSERT_FALSE(t.map(l, x, y, 1).ok());
                continue;
            }
            const SlotId s = next_slot++ % PageTable::kMaxSlots;
            ASSERT_TRUE(t.map(l, x, y, s).ok());
            ref.at(l, x, y) = s;
            mapped.emplace_back(l, x, y);
        } else {
            const std::size_t k = std::uniform_int_distribution<std::size_t>(0, mapped.size() - 1)(rng);
            std::tie(l, x, y) = mapped[k];
            mapped[k] = mapped.back();
            mapped.pop_back();
            ASSERT_TRUE(t.unmap(l, x, y).ok());
            ref.at(l, x, y) = -1;
        }
        ASSERT_EQ(t.mapped_pages(), mapped.size());
        ASSERT_NO_FATAL_FAILURE(expect_matches(t, ref, "after op"));
        if (i % 7 == 0) {  // batches of several ops
            dirty.clear();
            t.take_dirty(dirty);
            ASSERT_NO_FATAL_FAILURE(expect_dirty_covers(t, batch_before, dirty));
            batch_before = snapshot(t);
        } else if (single) {  // one op: rects stay inside the changed page's region
            std::vector<DirtyRect> one;
            t.take_dirty(one);
            ASSERT_NO_FATAL_FAILURE(expect_dirty_covers(t, before, one));
            for (const DirtyRect& r : one) {
                ASSERT_LE(r.level, l);
                const std::uint32_t d = l - r.level;
                ASSERT_GE(r.x0, x << d);
                ASSERT_GE(r.y0, y << d);
                ASSERT_LE(r.x1, (x + 1) << d);
                ASSERT_LE(r.y1, (y + 1) << d);
            }
            batch_before = snapshot(t);
        }
    }
    // Unmap everything: the table is empty again.
    for (auto [l, x, y] : mapped) {
        ASSERT_TRUE(t.unmap(l, x, y).ok());
        ref.at(l, x, y) = -1;
    }
    expect_matches(t, ref, "after unmapping all");
    for (std::uint32_t l = 0; l < t.levels(); ++l)
        for (PageEntry e : t.level_entries(l)) ASSERT_EQ(e, 0u);
}

TEST(PageTable, RandomMapUnmapMatchesBruteForce) {
    random_sequence(67, 43, 3000, 1);
    random_sequence(67, 43, 3000, 2);
    random_sequence(1, 1, 200, 3);
    random_sequence(16, 16, 3000, 4);  // 5 levels
    random_sequence(5, 1, 500, 5);
    random_sequence(1, 9, 500, 6);
    random_sequence(33, 31, 3000, 7);
    random_sequence(2, 3, 500, 8);
    random_sequence(100, 3, 2000, 9);
}

TEST(PageTable, DirtyRectsAreTight) {
    PageTable t = make_table(64, 64);
    std::vector<DirtyRect> d;
    t.take_dirty(d);  // new table: each level whole
    ASSERT_EQ(d.size(), t.levels());
    for (const DirtyRect& r : d) EXPECT_EQ(r, (DirtyRect{r.level, 0, 0, t.level_width(r.level), t.level_height(r.level)}));
    EXPECT_FALSE(t.has_dirty());

    ASSERT_TRUE(t.map(0, 5, 9, 1).ok());
    d.clear();
    t.take_dirty(d);
    ASSERT_EQ(d.size(), 1u);
    EXPECT_EQ(d[0], (DirtyRect{0, 5, 9, 6, 10}));

    // Two far-apart pages: two unit rectangles, not their bounding box.
    ASSERT_TRUE(t.map(0, 1, 1, 2).ok());
    ASSERT_TRUE(t.map(0, 60, 60, 3).ok());
    d.clear();
    t.take_dirty(d);
    ASSERT_EQ(d.size(), 2u);
    EXPECT_EQ(d[0].area() + d[1].area(), 2u);

    // A row of adjacent pages merges into one rectangle.
    for (std::uint32_t x = 10; x < 20; ++x) ASSERT_TRUE(t.map(0, x, 30, 10 + x).ok());
    d.clear();
    t.take_dirty(d);
    ASSERT_EQ(d.size(), 1u);
    EXPECT_EQ(d[0], (DirtyRect{0, 10, 30, 20, 31}));

    // A level-2 page: its own entry plus 2x2 at level 1 and 4x4 at level 0, minus resident parts.
    ASSERT_TRUE(t.map(0, 8, 8, 50).ok());  // inside the level-2 page (2, 2, 2)'s region
    d.clear();
    t.take_dirty(d);
    ASSERT_TRUE(t.map(2, 2, 2, 51).ok());
    d.clear();
    t.take_dirty(d);
    std::map<std::uint32_t, DirtyRect> by_level;
    for (const DirtyRect& r : d) by_level[r.level] = r;
    ASSERT_EQ(d.size(), 3u);
    EXPECT_EQ(by_level[2], (DirtyRect{2, 2, 2, 3, 3}));
    EXPECT_EQ(by_level[1], (DirtyRect{1, 4, 4, 6, 6}));
    EXPECT_EQ(by_level[0], (DirtyRect{0, 8, 8, 12, 12}));

    // Many scattered pages: at most kMaxDirtyRectsPerLevel rectangles, still covering them all.
    const auto before = snapshot(t);
    std::mt19937 rng(11);
    for (int i = 0; i < 200; ++i) {
        const std::uint32_t x = rng() % 64, y = rng() % 64;
        if (!t.is_mapped(0, x, y)) {
            ASSERT_TRUE(t.map(0, x, y, 1000 + i).ok());
        }
    }
    d.clear();
    t.take_dirty(d);
    EXPECT_LE(d.size(), PageTable::kMaxDirtyRectsPerLevel);
    expect_dirty_covers(t, before, d);

    t.mark_all_dirty();
    d.clear();
    t.take_dirty(d);
    EXPECT_EQ(d.size(), t.levels());
}

TEST(PageTable, PerformanceSanity) {
    // 100k random map/unmap on a 256x256-page texture. Pages are drawn uniformly over all pages
    // (so mostly fine levels, as in a running viewer, whose coarse levels are pinned). No timing
    // assertion (benchmarks live in bench/); the time is printed.
    PageTable t = make_table(256, 256);
    std::vector<std::uint32_t> level_start{0};
    for (std::uint32_t l = 0; l < t.levels(); ++l)
        level_start.push_back(level_start.back() + t.level_width(l) * t.level_height(l));
    std::mt19937_64 rng(42);
    std::vector<std::tuple<std::uint32_t, std::uint32_t, std::uint32_t>> mapped;
    const auto t0 = std::chrono::steady_clock::now();
    int maps = 0, unmaps = 0;
    for (int i = 0; i < 100000; ++i) {
        if (mapped.size() < 4096 && (mapped.empty() || rng() % 2 == 0)) {
            const std::uint32_t idx = static_cast<std::uint32_t>(rng() % level_start.back());
            const auto it = std::upper_bound(level_start.begin(), level_start.end(), idx) - 1;
            const std::uint32_t l = static_cast<std::uint32_t>(it - level_start.begin());
            const std::uint32_t off = idx - *it, x = off % t.level_width(l), y = off / t.level_width(l);
            if (t.is_mapped(l, x, y)) continue;
            ASSERT_TRUE(t.map(l, x, y, static_cast<SlotId>(i)).ok());
            mapped.emplace_back(l, x, y);
            ++maps;
        } else {
            const std::size_t k = rng() % mapped.size();
            const auto [l, x, y] = mapped[k];
            mapped[k] = mapped.back();
            mapped.pop_back();
            ASSERT_TRUE(t.unmap(l, x, y).ok());
            ++unmaps;
        }
    }
    std::vector<DirtyRect> d;
    t.take_dirty(d);
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    std::printf("100k random map/unmap on 256x256 pages: %d maps, %d unmaps, %.1f ms\n", maps, unmaps, ms);
}

// ---------------------------------------------------------------------------------------------
// Residency

Residency make_residency(std::uint32_t slots, std::uint32_t pinned_levels = 0) {
    ResidencyConfig c;
    c.pool_slots = slots;
    c.pinned_levels = pinned_levels;
    auto r = Residency::create(c);
    EXPECT_TRUE(r.ok());
    return std::move(r).value();
}

PageKey page(std::uint32_t level, std::uint32_t x, std::uint32_t y, TextureId tex = 1) {
    return PageKey{tex, static_cast<std::uint8_t>(level), x, y};
}

// acquire + complete; returns the slot.
SlotId load(Residency& r, const PageKey& p) {
    auto g = r.acquire_slot(p);
    EXPECT_TRUE(g.ok()) << (g.ok() ? "" : g.error().message);
    if (!g.ok() || g->slot == kNoSlot) return kNoSlot;
    EXPECT_TRUE(r.complete(p, g->slot).ok());
    return g->slot;
}

// Loads `p` into an evicted slot; returns the victim.
PageKey evict_for(Residency& r, const PageKey& p) {
    auto g = r.acquire_slot(p);
    EXPECT_TRUE(g.ok()) << (g.ok() ? "" : g.error().message);
    if (!g.ok()) return PageKey{0xFFFF, 0, 0, 0};
    EXPECT_NE(g->slot, kNoSlot);
    EXPECT_TRUE(g->evicted);
    if (g->slot != kNoSlot) {
        EXPECT_TRUE(r.complete(p, g->slot).ok());
    }
    return g->victim;
}

TEST(Residency, CreateAndRegister) {
    ResidencyConfig c;
    c.pool_slots = 0;
    EXPECT_FALSE(Residency::create(c).ok());
    c.pool_slots = PageTable::kMaxSlots + 1;
    EXPECT_FALSE(Residency::create(c).ok());
    Residency r = make_residency(16, ResidencyConfig::kAutoPinnedLevels);
    EXPECT_TRUE(r.add_texture(1, 8, 8, 4).ok());
    EXPECT_FALSE(r.add_texture(1, 8, 8, 4).ok());  // duplicate
    EXPECT_FALSE(r.add_texture(2, 8, 8, 3).ok());  // wrong level count
    {
        // Over the dense bound: refused without sparse tables, a sparse table with them (default).
        ResidencyConfig dense_only;
        dense_only.pool_slots = 16;
        dense_only.sparse_tables = false;
        auto r2 = Residency::create(dense_only);
        ASSERT_TRUE(r2.ok());
        auto big = r2->add_texture(3, 65536, 65536, 17);
        ASSERT_FALSE(big.ok());
        EXPECT_NE(big.error().message.find("256 MiB bound"), std::string::npos);
        Residency r3 = make_residency(16, ResidencyConfig::kAutoPinnedLevels);
        ASSERT_TRUE(r3.add_texture(3, 65536, 65536, 17).ok());
        EXPECT_TRUE(r3.table(3)->sparse());
    }
    ASSERT_NE(r.table(1), nullptr);
    EXPECT_EQ(r.table(2), nullptr);
    EXPECT_EQ(r.table(1)->levels(), 4u);
    // Auto pinning: 1 + 4 pages (top two levels of a square texture).
    EXPECT_EQ(r.pinned_levels(1), 2u);
    EXPECT_TRUE(r.is_pinned(page(3, 0, 0)));
    EXPECT_TRUE(r.is_pinned(page(2, 1, 1)));
    EXPECT_FALSE(r.is_pinned(page(1, 0, 0)));
    // 67x43 pages: 1x1 + 2x1 = 3 pages; adding 3x2 would be 9 > 5.
    ASSERT_TRUE(r.add_texture(4, 67, 43, 8).ok());
    EXPECT_EQ(r.pinned_levels(4), 2u);
    // 1x1 texture: its single level is pinned.
    ASSERT_TRUE(r.add_texture(5, 1, 1, 1).ok());
    EXPECT_EQ(r.pinned_levels(5), 1u);
    // Pinned pages of all textures must fit the pool: 5 + 3 + 1 pinned so far of 16.
    ASSERT_TRUE(r.add_texture(6, 4, 4, 3).ok());  // + 5 = 14
    auto over = r.add_texture(7, 4, 4, 3);        // + 5 = 19 > 16
    ASSERT_FALSE(over.ok());
    EXPECT_EQ(over.error().code, Errc::resource_exhausted);
    EXPECT_NE(over.error().message.find("16-slot pool"), std::string::npos) << over.error().message;
    EXPECT_TRUE(r.begin_frame(0).ok());
    ASSERT_TRUE(r.begin_frame(5).ok());
    EXPECT_FALSE(r.begin_frame(4).ok());
    EXPECT_EQ(r.frame(), 5u);
}

TEST(Residency, FreeSlotsFirstThenOlderFirst) {
    Residency r = make_residency(3);
    ASSERT_TRUE(r.add_texture(1, 8, 8, 4).ok());
    const PageKey a = page(0, 0, 0), b = page(0, 1, 0), c = page(0, 2, 0);
    ASSERT_TRUE(r.begin_frame(1).ok());
    EXPECT_EQ(load(r, a), 0u);  // free slots, lowest first
    ASSERT_TRUE(r.begin_frame(2).ok());
    EXPECT_EQ(load(r, b), 1u);
    ASSERT_TRUE(r.begin_frame(3).ok());
    EXPECT_EQ(load(r, c), 2u);
    EXPECT_EQ(r.stats().free_slots, 0u);
    ASSERT_TRUE(r.begin_frame(4).ok());
    EXPECT_TRUE(r.touch(a));  // a: seen at 4, b: 2, c: 3
    EXPECT_FALSE(r.touch(page(0, 3, 0)));
    ASSERT_TRUE(r.begin_frame(5).ok());
    EXPECT_EQ(evict_for(r, page(0, 4, 0)), b);
    EXPECT_EQ(evict_for(r, page(0, 5, 0)), c);
    EXPECT_EQ(evict_for(r, page(0, 6, 0)), a);
    // Now only pages completed this frame are left: they are protected.
    auto g = r.acquire_slot(page(0, 7, 0));
    ASSERT_TRUE(g.ok());
    EXPECT_EQ(g->slot, kNoSlot);
    EXPECT_EQ(r.stats().evictions, 3u);
}

TEST(Residency, FinerBeforeCoarserAtEqualAge) {
    Residency r = make_residency(3);
    ASSERT_TRUE(r.add_texture(1, 8, 8, 4).ok());
    ASSERT_TRUE(r.begin_frame(1).ok());
    const PageKey coarse2 = page(2, 1, 1), coarse1 = page(1, 0, 0), fine = page(0, 7, 7);
    load(r, coarse2);  // completed first: LRU alone would pick it
    load(r, coarse1);
    load(r, fine);
    ASSERT_TRUE(r.begin_frame(2).ok());
    EXPECT_EQ(evict_for(r, page(0, 0, 5)), fine);
    EXPECT_EQ(evict_for(r, page(0, 1, 5)), coarse1);
    EXPECT_EQ(evict_for(r, page(0, 2, 5)), coarse2);

    // Age dominates level: an older coarse page goes before a newer fine one.
    Residency q = make_residency(2);
    ASSERT_TRUE(q.add_texture(1, 8, 8, 4).ok());
    ASSERT_TRUE(q.begin_frame(1).ok());
    load(q, coarse1);
    ASSERT_TRUE(q.begin_frame(2).ok());
    load(q, fine);
    ASSERT_TRUE(q.begin_frame(3).ok());
    EXPECT_EQ(evict_for(q, page(0, 0, 5)), coarse1);
}

TEST(Residency, LruAmongEquals) {
    Residency r = make_residency(3);
    ASSERT_TRUE(r.add_texture(1, 8, 8, 4).ok());
    const PageKey a = page(0, 0, 0), b = page(0, 1, 0), c = page(0, 2, 0);
    ASSERT_TRUE(r.begin_frame(1).ok());
    load(r, a);
    load(r, b);
    load(r, c);
    ASSERT_TRUE(r.begin_frame(2).ok());
    r.touch(c);
    r.touch(a);
    r.touch(b);
    ASSERT_TRUE(r.begin_frame(3).ok());
    EXPECT_EQ(evict_for(r, page(0, 4, 4)), c);
    EXPECT_EQ(evict_for(r, page(0, 5, 4)), a);
    EXPECT_EQ(evict_for(r, page(0, 6, 4)), b);
}

TEST(Residency, PinnedNeverEvicted) {
    Residency r = make_residency(6, ResidencyConfig::kAutoPinnedLevels);
    ASSERT_TRUE(r.add_texture(1, 8, 8, 4).ok());  // pinned: level 3 (1) + level 2 (4)
    ASSERT_TRUE(r.begin_frame(1).ok());
    load(r, page(3, 0, 0));
    for (std::uint32_t y = 0; y < 2; ++y)
        for (std::uint32_t x = 0; x < 2; ++x) load(r, page(2, x, y));
    EXPECT_EQ(r.stats().pinned_pages, 5u);
    load(r, page(0, 0, 0));
    // Many frames, never touching the pinned pages: only the one unpinned slot turns over.
    for (std::uint64_t f = 2; f < 40; ++f) {
        ASSERT_TRUE(r.begin_frame(f).ok());
        const PageKey victim = evict_for(r, page(f % 2, static_cast<std::uint32_t>(f % 4), 1));
        EXPECT_FALSE(r.is_pinned(victim));
        EXPECT_LT(victim.level, 2);
    }
    EXPECT_EQ(r.stats().pinned_pages, 5u);
    EXPECT_EQ(r.stats().resident_pages, 6u);
    // The only unpinned slot in flight: nothing evictable, even though the pinned pages are old.
    ASSERT_TRUE(r.begin_frame(100).ok());
    auto g = r.acquire_slot(page(0, 3, 3));
    ASSERT_TRUE(g.ok());
    ASSERT_NE(g->slot, kNoSlot);
    auto none = r.acquire_slot(page(0, 4, 3));
    ASSERT_TRUE(none.ok());
    EXPECT_EQ(none->slot, kNoSlot);
    EXPECT_TRUE(r.cancel(g->slot).ok());
    for (std::uint32_t y = 0; y < 2; ++y)
        for (std::uint32_t x = 0; x < 2; ++x) EXPECT_TRUE(r.is_resident(page(2, x, y)));
}

TEST(Residency, PagesSeenThisFrameAreNotEvicted) {
    Residency r = make_residency(3, 1);  // the 1x1 level pinned
    ASSERT_TRUE(r.add_texture(1, 8, 8, 4).ok());
    const PageKey a = page(0, 0, 0), b = page(1, 3, 3);
    ASSERT_TRUE(r.begin_frame(1).ok());
    load(r, a);
    load(r, b);
    ASSERT_TRUE(r.begin_frame(2).ok());
    r.touch(a);
    r.touch(b);
    // The third slot is free: taken without eviction.
    auto g0 = r.acquire_slot(page(0, 5, 5));
    ASSERT_TRUE(g0.ok());
    EXPECT_FALSE(g0->evicted);
    ASSERT_TRUE(r.cancel(g0->slot).ok());
    load(r, page(0, 5, 5));
    // Pool full, everything seen this frame: kNoSlot, nothing unmapped.
    auto g = r.acquire_slot(page(0, 6, 6));
    ASSERT_TRUE(g.ok());
    EXPECT_EQ(g->slot, kNoSlot);
    EXPECT_FALSE(g->evicted);
    EXPECT_TRUE(r.is_resident(a));
    EXPECT_TRUE(r.is_resident(b));
    EXPECT_EQ(r.stats().evictions, 0u);
    EXPECT_EQ(r.stats().in_flight, 0u);
    // The next frame, without touching b: b (older) goes.
    ASSERT_TRUE(r.begin_frame(3).ok());
    r.touch(a);
    r.touch(page(0, 5, 5));
    EXPECT_EQ(evict_for(r, page(0, 6, 6)), b);
    // A pinned page may evict a page seen this frame (it is what every fallback ends at); the
    // finer one first.
    EXPECT_EQ(evict_for(r, page(3, 0, 0)), a);
    EXPECT_TRUE(r.is_resident(page(3, 0, 0)));
    EXPECT_EQ(r.resident_level(page(0, 0, 0)), 3);
}

// Motion prefetch: every other feedback sees the view ahead. With kept_frames 2 a page the view
// itself saw one feedback ago is not evicted for one the view ahead wants; with 1 it would be.
TEST(Residency, KeptFramesKeepThePagesOfTheLastFeedbacks) {
    for (const std::uint32_t bad : {0u, 65u}) {
        ResidencyConfig c;
        c.pool_slots = 4;
        c.kept_frames = bad;
        auto made = Residency::create(c);
        ASSERT_FALSE(made.ok()) << bad;
        EXPECT_NE(made.error().message.find("kept_frames must be 1..64"), std::string::npos) << made.error().message;
    }
    for (const std::uint32_t kept : {1u, 2u}) {
        ResidencyConfig c;
        c.pool_slots = 3;
        c.pinned_levels = 1;
        c.kept_frames = kept;
        auto made = Residency::create(c);
        ASSERT_TRUE(made.ok());
        Residency& r = *made;
        ASSERT_TRUE(r.add_texture(1, 8, 8, 4).ok());
        const PageKey on_screen = page(0, 0, 0), ahead = page(0, 7, 7), next = page(0, 6, 7);
        // The page acquire_slot(next) evicts now (a default PageKey: none); the slot is given back.
        const auto victim = [&]() -> PageKey {
            auto g = r.acquire_slot(next);
            EXPECT_TRUE(g.ok());
            if (!g.ok() || g->slot == kNoSlot) return PageKey{};
            EXPECT_TRUE(g->evicted);
            EXPECT_TRUE(r.cancel(g->slot).ok());
            return g->victim;
        };
        ASSERT_TRUE(r.begin_frame(1).ok());  // the view itself
        load(r, page(3, 0, 0));
        load(r, on_screen);
        ASSERT_TRUE(r.begin_frame(2).ok());  // the view ahead: on_screen not in it
        load(r, ahead);
        if (kept == 1) {
            EXPECT_EQ(victim(), on_screen) << "seen one feedback ago, evicted for a page of the view ahead";
            continue;
        }
        EXPECT_EQ(victim(), PageKey{}) << "seen one feedback ago: kept";
        ASSERT_TRUE(r.begin_frame(3).ok());  // the view itself
        r.touch(on_screen);
        EXPECT_EQ(victim(), PageKey{});
        ASSERT_TRUE(r.begin_frame(4).ok());  // the view ahead
        r.touch(ahead);
        EXPECT_EQ(victim(), PageKey{});
        ASSERT_TRUE(r.begin_frame(5).ok());  // neither: on_screen (frame 3) is older than ahead (4)
        EXPECT_EQ(victim(), on_screen);
        EXPECT_EQ(r.stats().evictions, 1u);
    }
}

// Leaving (fade out): a victim seen within fade_out_frames frames before the kept ones is not
// taken at once; it stays mapped while its weight falls, and its slot is free in the first frame
// whose clock is a fade time after it started leaving (or at the deadline); past max_leaving
// leaving pages, and for victims unseen for longer, evictions are at once as before.
TEST(Residency, RecentlySeenVictimsLeaveBeforeTheirSlotIsFree) {
    ResidencyConfig c;
    c.pool_slots = 4;
    c.pinned_levels = 1;
    c.fade_out_frames = 4;  // with kept_frames 1: last seen after frame - 5
    c.max_leaving = 1;
    constexpr double fade = 0.1;
    auto made = Residency::create(c, fade);
    ASSERT_TRUE(made.ok());
    Residency& r = *made;
    ASSERT_TRUE(r.add_texture(1, 8, 8, 4).ok());
    const PageKey a = page(0, 0, 0), b = page(0, 1, 0), d = page(0, 2, 0), n1 = page(0, 5, 5), n2 = page(0, 6, 6);
    ASSERT_TRUE(r.begin_frame(1, 0.0).ok());
    load(r, page(3, 0, 0));
    const SlotId slot_a = load(r, a);
    load(r, b);
    load(r, d);
    EXPECT_EQ(r.weight(slot_a), 0) << "an arriving page starts at weight 0";
    ASSERT_TRUE(r.begin_frame(2, fade).ok());  // a, b, d seen 1 frame ago, faded in
    EXPECT_EQ(r.weight(slot_a), 255);
    EXPECT_EQ(r.stats().fading, 0u);
    r.touch(d);
    auto g = r.acquire_slot(n1);
    ASSERT_TRUE(g.ok());
    EXPECT_EQ(g->slot, kNoSlot);
    EXPECT_FALSE(g->evicted);
    ASSERT_EQ(g->leaving, slot_a);
    EXPECT_EQ(g->victim, a);
    EXPECT_TRUE(r.is_resident(a)) << "a leaving page stays mapped (drawn, fading out)";
    EXPECT_EQ(r.stats().leaving, 1u);
    // max_leaving 1 reached: the next recent victim goes at once.
    EXPECT_EQ(evict_for(r, n2), b);
    ASSERT_TRUE(r.begin_frame(3, fade * 1.5).ok());
    EXPECT_NEAR(r.weight(slot_a), 128, 1) << "half-way out";
    EXPECT_TRUE(r.is_resident(a));
    EXPECT_EQ(r.take_left(), 0u);
    ASSERT_TRUE(r.begin_frame(4, fade * 2).ok());
    EXPECT_EQ(r.take_left(), 1u);
    EXPECT_EQ(r.take_left(), 0u) << "taken once";
    EXPECT_FALSE(r.is_resident(a));
    EXPECT_EQ(r.resident_level(a), 3) << "unmapped: falls back to the pinned root";
    EXPECT_EQ(r.weight(slot_a), 255) << "a free slot draws nothing: back at full weight";
    EXPECT_EQ(r.stats().evictions, 2u);
    EXPECT_EQ(r.stats().leaving, 0u);
    auto g3 = r.acquire_slot(n1);  // the freed slot
    ASSERT_TRUE(g3.ok());
    EXPECT_EQ(g3->slot, slot_a);
    EXPECT_FALSE(g3->evicted);
    ASSERT_TRUE(r.complete(n1, g3->slot).ok());
    std::vector<SlotWeight> changes;
    r.take_weight_changes(changes);
    ASSERT_FALSE(changes.empty());
    EXPECT_EQ(std::count_if(changes.begin(), changes.end(), [&](const SlotWeight& w) { return w.slot == slot_a; }), 1)
        << "one change per slot";
    changes.clear();
    r.take_weight_changes(changes);
    EXPECT_TRUE(changes.empty()) << "taken once";
    // d, last seen in frame 2, unseen for the kept frame and fade_out_frames more: at once.
    ASSERT_TRUE(r.begin_frame(8, fade * 3).ok());
    r.touch(n1);
    r.touch(n2);
    EXPECT_EQ(evict_for(r, a), d);
    // The deadline: a leaving page whose clock stands still leaves anyway, and is counted.
    ASSERT_TRUE(r.begin_frame(9, fade * 3).ok());
    auto g4 = r.acquire_slot(b);  // n1, n2 and a seen in frame 8
    ASSERT_TRUE(g4.ok());
    ASSERT_NE(g4->leaving, kNoSlot);
    const PageKey leaving_page = g4->victim;
    (void)r.take_left();
    ASSERT_TRUE(r.begin_frame(9 + Residency::kLeaveDeadlineFrames - 1, fade * 3).ok());
    EXPECT_EQ(r.stats().leaving, 1u);
    EXPECT_EQ(r.take_expired(), 0u);
    ASSERT_TRUE(r.begin_frame(9 + Residency::kLeaveDeadlineFrames, fade * 3).ok());
    EXPECT_EQ(r.stats().leaving, 0u);
    EXPECT_EQ(r.take_expired(), 1u);
    EXPECT_EQ(r.take_left(), 1u);
    EXPECT_FALSE(r.is_resident(leaving_page));
    EXPECT_EQ(r.stats().free_slots, 1u);
    EXPECT_EQ(r.stats().evictions, 4u);
    {
        ResidencyConfig bad = c;
        bad.max_leaving = 0;
        EXPECT_FALSE(Residency::create(bad).ok());
        EXPECT_FALSE(Residency::create(c, -1).ok());
        EXPECT_FALSE(Residency::create(c, 11).ok());
    }
    // Without a fade time nothing leaves over one, whatever fade_out_frames says.
    auto plain = Residency::create(c, 0);
    ASSERT_TRUE(plain.ok());
    ASSERT_TRUE(plain->add_texture(1, 8, 8, 4).ok());
    ASSERT_TRUE(plain->begin_frame(1).ok());
    load(*plain, page(3, 0, 0));
    for (std::uint32_t i = 0; i < 3; ++i) load(*plain, page(0, i, 0));
    ASSERT_TRUE(plain->begin_frame(2).ok());
    EXPECT_EQ(evict_for(*plain, n1), a);
    EXPECT_EQ(plain->stats().leaving, 0u);
    plain->take_weight_changes(changes);
    EXPECT_TRUE(changes.empty()) << "no fades: every weight stays full";
}

// A leaving page the feedback sees again is kept: it fades back in from where it is, its slot
// is never freed; once at full weight it is an ordinary resident page.
TEST(Residency, ALeavingPageSeenAgainIsKept) {
    ResidencyConfig c;
    c.pool_slots = 4;
    c.pinned_levels = 1;
    c.fade_out_frames = 4;
    constexpr double fade = 0.1;
    auto made = Residency::create(c, fade);
    ASSERT_TRUE(made.ok());
    Residency& r = *made;
    ASSERT_TRUE(r.add_texture(1, 8, 8, 4).ok());
    const PageKey a = page(0, 0, 0), b = page(0, 1, 0), d = page(0, 2, 0), n1 = page(0, 5, 5);
    ASSERT_TRUE(r.begin_frame(1, 0.0).ok());
    load(r, page(3, 0, 0));
    const SlotId slot_a = load(r, a);
    load(r, b);
    load(r, d);
    ASSERT_TRUE(r.begin_frame(2, fade).ok());
    auto g = r.acquire_slot(n1);
    ASSERT_TRUE(g.ok());
    ASSERT_EQ(g->leaving, slot_a);
    EXPECT_EQ(r.take_kept(), 0u);
    // A quarter of the way out, the view wants it again: it stays, and the slot is not freed.
    ASSERT_TRUE(r.begin_frame(3, fade * 1.25).ok());
    EXPECT_NEAR(r.weight(slot_a), 191, 1);
    EXPECT_TRUE(r.touch(a));
    EXPECT_EQ(r.stats().leaving, 0u);
    EXPECT_EQ(r.stats().rescued, 1u);
    EXPECT_EQ(r.stats().evictions, 0u);
    EXPECT_EQ(r.take_kept(), 1u);
    EXPECT_EQ(r.take_kept(), 0u) << "taken once";
    // It rises from where it was: a quarter of a fade later it is back at full weight.
    ASSERT_TRUE(r.begin_frame(4, fade * 1.375).ok());
    EXPECT_NEAR(r.weight(slot_a), 223, 1);
    ASSERT_TRUE(r.begin_frame(5, fade * 1.5).ok());
    EXPECT_EQ(r.weight(slot_a), 255);
    EXPECT_EQ(r.stats().fading, 0u);
    EXPECT_EQ(r.take_left(), 0u) << "a kept page never leaves";
    EXPECT_TRUE(r.is_resident(a));
    EXPECT_TRUE(r.touch(a)) << "touched again as an ordinary resident page";
    EXPECT_EQ(r.stats().rescued, 1u);
    // A candidate again, ordered by its new last-seen frame: b (seen in frame 1) leaves first.
    auto g2 = r.acquire_slot(n1);
    ASSERT_TRUE(g2.ok());
    EXPECT_EQ(g2->victim, b);
    EXPECT_NE(g2->leaving, kNoSlot) << "b, seen 4 frames ago, leaves over a fade";
    // Once unseen long enough it goes like any other page.
    ASSERT_TRUE(r.begin_frame(20, fade * 3).ok());
    EXPECT_EQ(r.take_left(), 1u) << "b has faded out";
    load(r, page(0, 7, 7));  // into b's slot
    std::vector<PageKey> victims;
    for (std::uint32_t i = 0; i < 2; ++i) victims.push_back(evict_for(r, page(0, 6, i)));
    EXPECT_NE(std::find(victims.begin(), victims.end(), a), victims.end()) << "a, unseen since frame 5, is evicted at once";
    EXPECT_EQ(r.stats().free_slots, 0u);
}

TEST(Residency, SeveralTexturesShareOnePool) {
    Residency r = make_residency(4);
    ASSERT_TRUE(r.add_texture(1, 8, 8, 4).ok());
    ASSERT_TRUE(r.add_texture(7, 5, 3, 4).ok());
    ASSERT_TRUE(r.begin_frame(1).ok());
    const SlotId s1 = load(r, page(0, 1, 1, 1));
    const SlotId s7 = load(r, page(0, 1, 1, 7));
    ASSERT_TRUE(r.begin_frame(2).ok());
    load(r, page(3, 0, 0, 1));
    load(r, page(2, 0, 0, 7));
    EXPECT_NE(s1, s7);
    // Tables are independent: same coordinates, different textures.
    EXPECT_EQ(r.table(1)->entry(0, 1, 1), PageTable::make_entry(s1, 0));
    EXPECT_EQ(r.table(7)->entry(0, 1, 1), PageTable::make_entry(s7, 0));
    EXPECT_EQ(r.resident_level(page(0, 0, 0, 1)), 3);
    EXPECT_EQ(r.resident_level(page(0, 0, 0, 7)), 2);
    EXPECT_EQ(r.resident_level(page(0, 0, 0, 9)), 255);  // unknown texture
    EXPECT_EQ(r.stats().resident_pages, 4u);
    // Replacement spans textures: texture 1's frame-1 page goes first (texture 7's was touched).
    ASSERT_TRUE(r.begin_frame(3).ok());
    r.touch(page(0, 1, 1, 7));
    EXPECT_EQ(evict_for(r, page(0, 2, 2, 7)), page(0, 1, 1, 1));
    EXPECT_EQ(r.table(1)->entry(0, 1, 1), r.table(1)->entry(3, 0, 0));  // falls back to texture 1's root
    EXPECT_EQ(evict_for(r, page(0, 3, 2, 7)), page(2, 0, 0, 7));          // frame 2, level 2 (texture 7)...
    EXPECT_EQ(evict_for(r, page(0, 4, 2, 7)), page(3, 0, 0, 1));          // ...before level 3 (texture 1)
}

TEST(Residency, UnmapBeforeOverwrite) {
    Residency r = make_residency(2, 1);
    ASSERT_TRUE(r.add_texture(1, 4, 4, 3).ok());
    ASSERT_TRUE(r.begin_frame(1).ok());
    const SlotId root = load(r, page(2, 0, 0));
    const PageKey victim = page(0, 1, 1);
    const SlotId vs = load(r, victim);
    const PageTable& t = *r.table(1);
    EXPECT_EQ(t.entry(0, 1, 1), PageTable::make_entry(vs, 0));
    std::vector<DirtyRect> d;
    r.table_for_upload(1)->take_dirty(d);

    ASSERT_TRUE(r.begin_frame(2).ok());
    const PageKey incoming = page(1, 1, 1);
    auto g = r.acquire_slot(incoming);
    ASSERT_TRUE(g.ok());
    ASSERT_EQ(g->slot, vs);
    ASSERT_TRUE(g->evicted);
    EXPECT_EQ(g->victim, victim);
    // Before complete(): the victim already falls back to the root, the incoming page is not
    // mapped, and no entry anywhere names the slot being overwritten.
    EXPECT_EQ(t.entry(0, 1, 1), PageTable::make_entry(root, 2));
    EXPECT_FALSE(t.is_mapped(0, 1, 1));
    EXPECT_FALSE(r.is_resident(incoming));
    EXPECT_EQ(r.resident_level(incoming), 2);
    for (std::uint32_t l = 0; l < t.levels(); ++l)
        for (PageEntry e : t.level_entries(l)) EXPECT_NE(PageTable::entry_slot(e), vs);
    d.clear();
    r.table_for_upload(1)->take_dirty(d);
    ASSERT_EQ(d.size(), 1u);  // the unmap is already dirty, to upload before the slot is written
    EXPECT_EQ(d[0], (DirtyRect{0, 1, 1, 2, 2}));
    EXPECT_EQ(r.stats().in_flight, 1u);
    EXPECT_EQ(r.stats().resident_pages, 1u);

    ASSERT_TRUE(r.complete(incoming, g->slot).ok());  // map after complete
    EXPECT_EQ(t.entry(1, 1, 1), PageTable::make_entry(vs, 1));
    EXPECT_EQ(t.entry(0, 2, 3), PageTable::make_entry(vs, 1));
    EXPECT_EQ(t.entry(0, 1, 1), PageTable::make_entry(root, 2));
}

TEST(Residency, ProtocolErrorsAndCancel) {
    Residency r = make_residency(2, 0);
    ASSERT_TRUE(r.add_texture(1, 4, 4, 3).ok());
    EXPECT_FALSE(r.acquire_slot(page(0, 0, 0, 2)).ok());  // unknown texture
    EXPECT_FALSE(r.acquire_slot(page(0, 4, 0)).ok());     // outside
    EXPECT_FALSE(r.acquire_slot(page(3, 0, 0)).ok());     // no such level
    auto g = r.acquire_slot(page(0, 0, 0));
    ASSERT_TRUE(g.ok());
    auto dup = r.acquire_slot(page(0, 0, 0));
    ASSERT_FALSE(dup.ok());
    EXPECT_NE(dup.error().message.find("in flight"), std::string::npos);
    EXPECT_FALSE(r.complete(page(0, 1, 0), g->slot).ok());  // wrong page
    EXPECT_FALSE(r.complete(page(0, 0, 0), g->slot + 1).ok());  // wrong slot
    EXPECT_EQ(r.stats().free_slots, 1u);
    ASSERT_TRUE(r.cancel(g->slot).ok());
    EXPECT_FALSE(r.cancel(g->slot).ok());
    EXPECT_FALSE(r.cancel(99).ok());
    EXPECT_FALSE(r.complete(page(0, 0, 0), g->slot).ok());  // cancelled
    EXPECT_EQ(r.stats().free_slots, 2u);
    EXPECT_EQ(r.stats().in_flight, 0u);
    load(r, page(0, 0, 0));
    auto again = r.acquire_slot(page(0, 0, 0));
    ASSERT_FALSE(again.ok());
    EXPECT_NE(again.error().message.find("already resident"), std::string::npos);
}

// Random protocol runs against a brute-force model of the replacement order.
TEST(Residency, RandomProtocolMatchesModel) {
    for (std::uint64_t seed = 1; seed <= 6; ++seed) {
        SCOPED_TRACE(testing::Message() << "seed " << seed);
        const std::uint32_t pool = 5 + static_cast<std::uint32_t>(seed * 3);
        Residency r = make_residency(pool, ResidencyConfig::kAutoPinnedLevels);
        ASSERT_TRUE(r.add_texture(1, 8, 8, 4).ok());
        ASSERT_TRUE(r.add_texture(2, 5, 3, 4).ok());
        struct Model {
            std::uint64_t last_seen;
            std::uint64_t seq;
        };
        std::map<std::tuple<TextureId, std::uint32_t, std::uint32_t, std::uint32_t>, Model> resident;
        std::map<SlotId, PageKey> in_flight;
        std::uint64_t seq = 0;
        std::mt19937_64 rng(seed);
        auto key = [](const PageKey& p) { return std::make_tuple(p.texture, std::uint32_t(p.level), p.x, p.y); };
        auto random_page = [&]() {
            const TextureId tex = static_cast<TextureId>(1 + rng() % 2);
            const PageTable& t = *r.table(tex);
            const std::uint32_t l = static_cast<std::uint32_t>(rng() % t.levels());
            return page(l, static_cast<std::uint32_t>(rng() % t.level_width(l)),
                        static_cast<std::uint32_t>(rng() % t.level_height(l)), tex);
        };
        std::uint64_t frame = 0;
        for (int step = 0; step < 4000; ++step) {
            const int op = static_cast<int>(rng() % 100);
            if (op < 5) {
                frame += 1 + rng() % 2;
                ASSERT_TRUE(r.begin_frame(frame).ok());
            } else if (op < 40) {
                const PageKey p = random_page();
                const bool res = resident.count(key(p)) != 0;
                ASSERT_EQ(r.touch(p), res);
                if (res) resident[key(p)] = Model{frame, ++seq};
            } else if (op < 90) {
                const PageKey p = random_page();
                const bool busy = resident.count(key(p)) ||
                                  std::any_of(in_flight.begin(), in_flight.end(), [&](auto& kv) { return kv.second == p; });
                auto g = r.acquire_slot(p);
                if (busy) {
                    ASSERT_FALSE(g.ok());
                    continue;
                }
                ASSERT_TRUE(g.ok());
                // Model: free slot if any; else the smallest (last_seen, level, seq) among
                // unpinned resident pages, excluding this frame's unless p is pinned.
                const bool free_left = resident.size() + in_flight.size() < pool;
                const bool p_pinned = r.is_pinned(p);
                std::optional<std::tuple<std::uint64_t, std::uint32_t, std::uint64_t>> best;
                PageKey best_page{};
                for (const auto& [k, m] : resident) {
                    const PageKey q{std::get<0>(k), static_cast<std::uint8_t>(std::get<1>(k)), std::get<2>(k), std::get<3>(k)};
                    if (r.is_pinned(q)) continue;
                    if (m.last_seen >= frame && !p_pinned) continue;
                    const auto order = std::make_tuple(m.last_seen, std::get<1>(k), m.seq);
                    if (!best || order < *best) best = order, best_page = q;
                }
                if (free_left) {
                    ASSERT_NE(g->slot, kNoSlot);
                    ASSERT_FALSE(g->evicted);
                } else if (!best) {
                    ASSERT_EQ(g->slot, kNoSlot);
                    continue;
                } else {
                    ASSERT_NE(g->slot, kNoSlot);
                    ASSERT_TRUE(g->evicted);
                    ASSERT_EQ(g->victim, best_page);
                    resident.erase(key(best_page));
                    ASSERT_FALSE(r.is_resident(best_page));  // unmapped already
                }
                in_flight[g->slot] = p;
            } else if (!in_flight.empty()) {
                auto it = in_flight.begin();
                std::advance(it, rng() % in_flight.size());
                if (op < 97) {
                    ASSERT_TRUE(r.complete(it->second, it->first).ok());
                    resident[key(it->second)] = Model{frame, ++seq};
                    ASSERT_EQ(r.table(it->second.texture)->mapped_slot(it->second.level, it->second.x, it->second.y),
                              it->first);
                } else {
                    ASSERT_TRUE(r.cancel(it->first).ok());
                }
                in_flight.erase(it);
            }
            const ResidencyStats s = r.stats();
            ASSERT_EQ(s.resident_pages, resident.size());
            ASSERT_EQ(s.in_flight, in_flight.size());
            ASSERT_EQ(s.free_slots, pool - resident.size() - in_flight.size());
        }
        // The tables agree with the model's resident set.
        for (TextureId tex : {TextureId(1), TextureId(2)}) {
            const PageTable& t = *r.table(tex);
            std::size_t n = 0;
            for (const auto& [k, m] : resident) n += std::get<0>(k) == tex;
            EXPECT_EQ(t.mapped_pages(), n);
        }
    }
}

}  // namespace
}  // namespace tessera::client
