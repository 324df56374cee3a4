// Sparse PageTable (docs/stability.md, "Reaching 2^24 end to end"): every lookup equals the nearest resident
// ancestor, checked against a brute-force reference of resident pages (a map, so 2^24-texel
// geometries cost nothing), against the dense table where both fit, and through a mirror that
// applies take_dirty_blocks() the way the renderer's two-level table does; memory follows the
// resident pages, not the texture size.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <map>
#include <random>
#include <tuple>
#include <vector>

#include "page_table.hpp"
#include "residency.hpp"

namespace tessera::client {
namespace {

using Key = std::tuple<std::uint32_t, std::uint32_t, std::uint32_t>;  // level, x, y

// Resident pages only; an entry is found by walking up to the nearest resident ancestor.
struct SparseReference {
    std::vector<std::uint32_t> w, h;
    std::map<Key, SlotId> resident;

    SparseReference(std::uint32_t px, std::uint32_t py) {
        for (std::uint32_t x = px, y = py;; x = (x + 1) / 2, y = (y + 1) / 2) {
            w.push_back(x);
            h.push_back(y);
            if (x == 1 && y == 1) break;
        }
    }
    std::uint32_t levels() const { return std::uint32_t(w.size()); }
    PageEntry entry(std::uint32_t level, std::uint32_t x, std::uint32_t y) const {
        for (std::uint32_t l = level; l < levels(); ++l, x >>= 1, y >>= 1)
            if (const auto it = resident.find({l, x, y}); it != resident.end()) return PageTable::make_entry(it->second, l);
        return PageTable::kEmptyEntry;
    }
};

// What the renderer's two-level table holds: the blocks uploaded so far (take_dirty_blocks applied
// in order), resolved with the same walk as the shader: an unallocated block defers to level + 5.
struct BlockMirror {
    std::map<Key, std::vector<PageEntry>> blocks;
    std::size_t peak = 0;

    void apply(PageTable& t) {
        std::vector<DirtyBlock> dirty;
        t.take_dirty_blocks(dirty);
        for (const DirtyBlock& b : dirty) {
            if (!b.allocated) {
                blocks.erase({b.level, b.bx, b.by});
                continue;
            }
            const auto e = t.block_entries(b.level, b.bx, b.by);
            ASSERT_EQ(e.size(), PageTable::kBlockEntries);
            blocks[{b.level, b.bx, b.by}].assign(e.begin(), e.end());
            peak = std::max(peak, blocks.size());
        }
    }
    PageEntry entry(std::uint32_t level, std::uint32_t x, std::uint32_t y, std::uint32_t levels) const {
        for (int step = 0; step < 8 && level < levels; ++step) {
            const auto it = blocks.find({level, x >> PageTable::kBlockShift, y >> PageTable::kBlockShift});
            if (it != blocks.end())
                return it->second[(y & (PageTable::kBlockSide - 1)) * PageTable::kBlockSide + (x & (PageTable::kBlockSide - 1))];
            level += PageTable::kBlockShift;
            x >>= PageTable::kBlockShift;
            y >>= PageTable::kBlockShift;
        }
        return 0xDEADBEEFu;  // the walk fell off the top: a missing coarse block
    }
};

PageTable make_sparse(std::uint32_t px, std::uint32_t py) {
    auto t = PageTable::create(1, px, py, PageTable::levels_for(px, py), 0, true);  // a 0-byte bound: always sparse
    EXPECT_TRUE(t.ok()) << t.error().message;
    EXPECT_TRUE(t->sparse());
    return std::move(*t);
}

std::size_t coarse_blocks(const PageTable& t) {
    std::size_t n = 0;
    for (std::uint32_t l = 0; l < t.levels(); ++l)
        n += t.level_width(l) <= PageTable::kBlockSide && t.level_height(l) <= PageTable::kBlockSide;
    return n;
}

// Random map/unmap near the far corner (and anywhere), at every level, with the lookups of the
// touched pages, their descendants' corners, neighbours and random pages compared after each step.
void run_random(std::uint32_t px, std::uint32_t py, int ops, std::uint32_t seed) {
    SCOPED_TRACE(testing::Message() << px << "x" << py << " pages, seed " << seed);
    PageTable t = make_sparse(px, py);
    SparseReference ref(px, py);
    BlockMirror mirror;
    const std::uint32_t L = t.levels();
    ASSERT_EQ(L, ref.levels());
    std::mt19937 rng(seed);
    auto pick = [&](std::uint32_t level) -> std::pair<std::uint32_t, std::uint32_t> {
        const std::uint32_t w = ref.w[level], h = ref.h[level];
        if (rng() % 4 != 0) {  // near the far corner: within 80 pages of it
            const std::uint32_t span_x = std::min(w, 80u), span_y = std::min(h, 80u);
            return {w - 1 - rng() % span_x, h - 1 - rng() % span_y};
        }
        return {std::uint32_t(rng() % w), std::uint32_t(rng() % h)};
    };
    std::vector<Key> mapped;
    std::size_t checks = 0;
    auto check = [&](std::uint32_t level, std::uint32_t x, std::uint32_t y) {
        ++checks;
        const PageEntry want = ref.entry(level, x, y);
        ASSERT_EQ(t.entry(level, x, y), want) << "page (" << level << ", " << x << ", " << y << ")";
        ASSERT_EQ(mirror.entry(level, x, y, L), want) << "mirror, page (" << level << ", " << x << ", " << y << ")";
    };
    SlotId next_slot = 0;
    for (int op = 0; op < ops; ++op) {
        // Finer levels more often, like a real view; unmap when many are mapped.
        const bool do_unmap = !mapped.empty() && (mapped.size() > 600 || rng() % 3 == 0);
        std::uint32_t level, x, y;
        if (do_unmap) {
            const std::size_t i = rng() % mapped.size();
            std::tie(level, x, y) = mapped[i];
            mapped[i] = mapped.back();
            mapped.pop_back();
            ASSERT_TRUE(t.unmap(level, x, y).ok());
            ref.resident.erase({level, x, y});
        } else {
            level = std::min<std::uint32_t>(L - 1, std::uint32_t(std::geometric_distribution<int>(0.35)(rng)));
            std::tie(x, y) = pick(level);
            if (ref.resident.count({level, x, y})) {
                EXPECT_FALSE(t.map(level, x, y, 7).ok());
                continue;
            }
            const SlotId slot = next_slot++ % PageTable::kMaxSlots;
            ASSERT_TRUE(t.map(level, x, y, slot).ok());
            ref.resident[{level, x, y}] = slot;
            mapped.push_back({level, x, y});
        }
        mirror.apply(t);
        ASSERT_EQ(t.mapped_pages(), ref.resident.size());
        ASSERT_LE(t.allocated_blocks(), 5 * t.mapped_pages() + coarse_blocks(t));
        // The changed page, its ancestors, the corners of its level-0 region, its neighbours.
        for (std::uint32_t l = level, ax = x, ay = y; l < L; ++l, ax >>= 1, ay >>= 1) check(l, ax, ay);
        for (std::uint32_t l = 0; l <= level; ++l) {
            const std::uint32_t k = level - l;
            const auto x0 = std::uint32_t(std::min<std::uint64_t>(std::uint64_t(x) << k, ref.w[l] - 1));
            const auto y0 = std::uint32_t(std::min<std::uint64_t>(std::uint64_t(y) << k, ref.h[l] - 1));
            const auto x1 = std::uint32_t(std::min<std::uint64_t>((std::uint64_t(x + 1) << k) - 1, ref.w[l] - 1));
            const auto y1 = std::uint32_t(std::min<std::uint64_t>((std::uint64_t(y + 1) << k) - 1, ref.h[l] - 1));
            check(l, x0, y0);
            check(l, x1, y1);
            check(l, x0 + (x1 - x0) / 2, y1);
            if (x1 + 1 < ref.w[l]) check(l, x1 + 1, y0);
            if (x0 > 0) check(l, x0 - 1, y1);
        }
        for (int i = 0; i < 16; ++i) {
            const auto l = std::uint32_t(rng() % L);
            const auto [px2, py2] = pick(l);
            check(l, px2, py2);
        }
        if (testing::Test::HasFatalFailure()) return;
    }
    // Every resident page and its children.
    for (const auto& [k, s] : ref.resident) {
        const auto [l, x, y] = k;
        check(l, x, y);
        if (l > 0 && 2 * x < ref.w[l - 1] && 2 * y < ref.h[l - 1]) check(l - 1, 2 * x, 2 * y);
    }
    // Unmapping everything leaves the coarse blocks only, all empty.
    for (const auto& [l, x, y] : mapped) ASSERT_TRUE(t.unmap(l, x, y).ok());
    ref.resident.clear();
    mirror.apply(t);
    EXPECT_EQ(t.allocated_blocks(), coarse_blocks(t));
    EXPECT_EQ(mirror.blocks.size(), coarse_blocks(t));
    check(0, px - 1, py - 1);
    check(L - 1, 0, 0);
    std::printf("  %ux%u pages, %u levels: %d ops, %zu lookups checked, peak %zu blocks mirrored\n", px, py, L, ops, checks,
                mirror.peak);
}

TEST(SparsePageTable, RandomMapUnmapMatchesBruteForce2To24) {
    // 2^24 texels per side at P = 248 (and 2^24 - 1: the same page count) and at P = 1016.
    run_random(67651, 67651, 3000, 1);
    run_random(16514, 16514, 2000, 2);
}

TEST(SparsePageTable, RandomMapUnmapMatchesBruteForceOtherGeometries) {
    run_random(12689, 3, 1500, 3);   // 3·2^20 + 5 texels wide at P = 248, very flat
    run_random(1000, 37, 1500, 4);   // non-power-of-two, non-square
    run_random(33, 33, 1500, 5);     // one block past the coarse bound
    run_random(32, 32, 500, 6);      // level 0 fits one block: every level pinned
    run_random(1, 1, 20, 7);
    run_random(65, 1, 500, 8);
}

// Where both fit, the sparse table agrees with the dense one entry for entry, after every step.
TEST(SparsePageTable, EqualsDenseTableEverywhere) {
    for (const auto& [px, py] : {std::pair{100u, 70u}, {300u, 200u}, {64u, 64u}, {129u, 31u}}) {
        SCOPED_TRACE(testing::Message() << px << "x" << py);
        auto dense = PageTable::create(1, px, py, PageTable::levels_for(px, py));
        ASSERT_TRUE(dense.ok());
        ASSERT_FALSE(dense->sparse());
        PageTable sparse = make_sparse(px, py);
        std::mt19937 rng(px * 31 + py);
        std::vector<Key> mapped;
        for (int op = 0; op < 300; ++op) {
            if (!mapped.empty() && rng() % 3 == 0) {
                const std::size_t i = rng() % mapped.size();
                const auto [l, x, y] = mapped[i];
                mapped[i] = mapped.back();
                mapped.pop_back();
                ASSERT_TRUE(dense->unmap(l, x, y).ok());
                ASSERT_TRUE(sparse.unmap(l, x, y).ok());
            } else {
                const auto l = std::uint32_t(rng() % dense->levels());
                const auto x = std::uint32_t(rng() % dense->level_width(l)), y = std::uint32_t(rng() % dense->level_height(l));
                if (dense->is_mapped(l, x, y)) continue;
                ASSERT_TRUE(dense->map(l, x, y, SlotId(op)).ok());
                ASSERT_TRUE(sparse.map(l, x, y, SlotId(op)).ok());
                mapped.push_back({l, x, y});
            }
            if (op % 10 != 9) continue;
            for (std::uint32_t l = 0; l < dense->levels(); ++l)
                for (std::uint32_t y = 0; y < dense->level_height(l); ++y)
                    for (std::uint32_t x = 0; x < dense->level_width(l); ++x)
                        ASSERT_EQ(sparse.entry(l, x, y), dense->entry(l, x, y)) << "op " << op << " page (" << l << ", " << x << ", " << y << ")";
        }
    }
}

TEST(SparsePageTable, ChosenOnlyWhenTheDenseTableDoesNotFit) {
    // Fits the bound and the packing: dense, as before, with or without allow_sparse.
    auto small = PageTable::create(1, 4096, 4096, PageTable::levels_for(4096, 4096), PageTable::kDefaultMaxBytes, true);
    ASSERT_TRUE(small.ok());
    EXPECT_FALSE(small->sparse());
    // 2^24 texels at P = 248: refused dense (22.7 GiB), sparse when allowed.
    const std::uint32_t n = 67651, levels = PageTable::levels_for(n, n);
    EXPECT_EQ(levels, 18u);
    auto refused = PageTable::create(1, n, n, levels);
    ASSERT_FALSE(refused.ok());
    EXPECT_EQ(refused.error().code, Errc::resource_exhausted);
    auto huge = PageTable::create(1, n, n, levels, PageTable::kDefaultMaxBytes, true);
    ASSERT_TRUE(huge.ok()) << huge.error().message;
    EXPECT_TRUE(huge->sparse());
    // Under the byte bound but over the renderer's dense packing (10923 + 5462 > 16384): sparse.
    EXPECT_TRUE(PageTable::dense_packing_fits(10922, 10922));
    EXPECT_FALSE(PageTable::dense_packing_fits(10923, 10923));
    auto wide = PageTable::create(1, 10923, 10923, PageTable::levels_for(10923, 10923), std::size_t(1) << 30, true);
    ASSERT_TRUE(wide.ok());
    EXPECT_TRUE(wide->sparse());
    // Residency picks it by default.
    auto r = Residency::create(ResidencyConfig{.pool_slots = 64});
    ASSERT_TRUE(r.ok());
    ASSERT_TRUE(r->add_texture(0, n, n, levels).ok());
    EXPECT_TRUE(r->table(0)->sparse());
}

// Memory follows the resident pages: 4096 pages scattered over a 2^24-texel texture (the worst
// case: no two share a block) cost at most 5 blocks each; unmapping them gives the blocks back to
// the free list, and the next 4096 reuse it.
TEST(SparsePageTable, MemoryIsBoundedByResidentPages) {
    const std::uint32_t n = 67651;
    PageTable t = make_sparse(n, n);
    const std::size_t empty_bytes = t.memory_bytes();
    EXPECT_LT(empty_bytes, std::size_t(64) << 10);
    std::mt19937 rng(11);
    std::vector<Key> mapped;
    std::size_t peak = 0;
    const auto t0 = std::chrono::steady_clock::now();
    for (int round = 0; round < 2; ++round) {
        for (SlotId s = 0; s < 4096; ++s) {
            const std::uint32_t level = s % 3 == 0 ? 0 : s % 5;  // mostly fine levels, scattered
            const auto x = std::uint32_t(rng() % t.level_width(level)), y = std::uint32_t(rng() % t.level_height(level));
            if (t.is_mapped(level, x, y)) continue;
            ASSERT_TRUE(t.map(level, x, y, s).ok());
            mapped.push_back({level, x, y});
        }
        EXPECT_LE(t.allocated_blocks(), 5 * t.mapped_pages() + coarse_blocks(t));
        peak = std::max(peak, t.memory_bytes());
        for (const auto& [l, x, y] : mapped) ASSERT_TRUE(t.unmap(l, x, y).ok());
        mapped.clear();
        EXPECT_EQ(t.allocated_blocks(), coarse_blocks(t));
    }
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    // 5 blocks of 4 KiB per resident page at most, plus the index.
    const std::size_t bound = (5 * 4096 + coarse_blocks(t)) * (PageTable::kBlockEntries * 4 + 128) + (std::size_t(1) << 20);
    EXPECT_LE(peak, bound);
    std::printf("  2^24 texels (67,651 pages per side): empty %zu KiB, peak %.1f MiB with 4096 scattered pages "
                "(bound %.1f MiB; dense: %.2f GiB); 2 x 4096 maps + unmaps in %.0f ms\n",
                empty_bytes >> 10, double(peak) / (1 << 20), double(bound) / (1 << 20),
                double(PageTable::table_bytes(n, n, t.levels())) / (1u << 30), ms);
}

}  // namespace
}  // namespace tessera::client
