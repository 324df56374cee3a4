// Feedback analysis: against a brute-force std::map reference on random buffers, the ancestor
// sums, each ordering rule, invalid ids, the max_pages bound, id packing at its limits, and no
// allocation per frame (a counting global operator new below).
#include "feedback_analysis.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <map>
#include <new>
#include <random>
#include <set>
#include <vector>

namespace {
std::atomic<std::size_t> g_allocations{0};
}

// GCC 12 flags free() on memory from the (replaced) operator new once both are inlined: they are a
// matched pair here by construction.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
void* operator new(std::size_t n) {
    g_allocations.fetch_add(1, std::memory_order_relaxed);
    if (void* p = std::malloc(n ? n : 1)) return p;
    throw std::bad_alloc();
}
void* operator new[](std::size_t n) {
    g_allocations.fetch_add(1, std::memory_order_relaxed);
    if (void* p = std::malloc(n ? n : 1)) return p;
    throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
#pragma GCC diagnostic pop

namespace tessera::client {
namespace {

using Stats = FeedbackAnalyzer::Stats;

struct TextureSetup {
    TextureId id;
    std::uint8_t levels;
    std::uint32_t pages_x = 0, pages_y = 0;  // 0: no extent check
};

void configure(FeedbackAnalyzer& a, const std::vector<TextureSetup>& textures) {
    for (const auto& t : textures) {
        a.set_texture_levels(t.id, t.levels);
        if (t.pages_x || t.pages_y) a.set_texture_extent(t.id, t.pages_x, t.pages_y);
    }
}

// Nearest resident ancestor-or-self over an explicit resident set (consistent, like a page table).
class SetResidency : public ResidencyView {
public:
    std::set<std::uint64_t> resident;
    std::uint8_t resident_level(const PageKey& page) const override {
        for (PageKey k = page; k.level < kMaxLevels; k = k.parent())
            if (resident.count(pack_feedback(k))) return k.level;
        return kNothingResident;
    }
};

// A per-page answer (for the ordering tests; need not be consistent).
class MapResidency : public ResidencyView {
public:
    std::map<std::uint64_t, std::uint8_t> levels;
    std::uint8_t resident_level(const PageKey& page) const override {
        auto it = levels.find(pack_feedback(page));
        return it == levels.end() ? kNothingResident : it->second;
    }
};

// A pseudo-random resident set: every fourth page, and the two coarsest levels of texture 0.
class HashResidency : public ResidencyView {
public:
    std::uint8_t resident_level(const PageKey& page) const override {
        for (PageKey k = page; k.level < kMaxLevels; k = k.parent()) {
            std::uint64_t h = pack_feedback(k) * 0x9E3779B97F4A7C15ull;
            h ^= h >> 31;
            if (k.texture == 7) continue;  // texture 7: nothing resident
            if (h % 4 == 0 || (k.texture == 0 && k.level >= 10)) return k.level;
        }
        return kNothingResident;
    }
};

// The reference: per pixel, std::map, chains walked from every page, a comparator sort.
std::vector<WantedPage> reference(const std::vector<FeedbackId>& ids, std::uint32_t w, std::uint32_t h,
                                  const std::vector<TextureSetup>& textures, const ResidencyView& residency,
                                  std::size_t max_pages, Stats& stats) {
    std::map<TextureId, TextureSetup> tex;
    for (const auto& t : textures) tex[t.id] = t;
    struct Acc {
        std::uint32_t pixels = 0, subtree = 0;
        float distance = 2.0f;
    };
    std::map<std::uint64_t, Acc> leaves, all;
    stats = Stats{};
    stats.pixels = w * h;
    const double diag = std::sqrt(double(w) * w + double(h) * h);
    for (std::uint32_t y = 0; y < h; ++y)
        for (std::uint32_t x = 0; x < w; ++x) {
            const FeedbackId id = ids[y * w + x];
            if (id == kNoPage) continue;
            const PageKey k = unpack_feedback(id);
            auto it = tex.find(k.texture);
            bool ok = (id >> 61) == 0 && it != tex.end() && k.level < it->second.levels;
            if (ok && (it->second.pages_x || it->second.pages_y)) {
                const std::uint64_t n = std::uint64_t{1} << k.level;
                ok = k.x < (it->second.pages_x + n - 1) / n && k.y < (it->second.pages_y + n - 1) / n;
            }
            if (!ok) {
                ++stats.invalid_pixels;
                continue;
            }
            ++stats.vt_pixels;
            const double dx = 2.0 * x + 1 - w, dy = 2.0 * y + 1 - h;
            const auto d = static_cast<float>(std::sqrt(dx * dx + dy * dy) / diag);
            Acc& a = leaves[id];
            ++a.pixels;
            a.distance = std::min(a.distance, d);
        }
    for (const auto& [id, leaf] : leaves) {
        const std::uint8_t levels = tex[unpack_feedback(id).texture].levels;
        all[id].pixels = leaf.pixels;
        for (PageKey k = unpack_feedback(id);; k = k.parent()) {
            Acc& a = all[pack_feedback(k)];
            a.subtree += leaf.pixels;
            a.distance = std::min(a.distance, leaf.distance);
            if (k.level + 1 >= levels) break;
        }
    }
    stats.unique_pages = static_cast<std::uint32_t>(leaves.size());
    stats.ancestor_pages = static_cast<std::uint32_t>(all.size() - leaves.size());
    std::vector<WantedPage> out;
    for (const auto& [id, a] : all) {
        WantedPage p;
        p.key = unpack_feedback(id);
        p.pixels = a.pixels;
        p.subtree_pixels = a.subtree;
        p.centre_distance = a.distance;
        p.resident_level = residency.resident_level(p.key);
        p.level_gap = p.resident_level > p.key.level ? std::uint8_t(p.resident_level - p.key.level) : 0;
        out.push_back(p);
    }
    std::sort(out.begin(), out.end(), [](const WantedPage& u, const WantedPage& v) {
        if (u.level_gap != v.level_gap) return u.level_gap > v.level_gap;
        if (u.subtree_pixels != v.subtree_pixels) return u.subtree_pixels > v.subtree_pixels;
        if (u.centre_distance != v.centre_distance) return u.centre_distance < v.centre_distance;
        return pack_feedback(u.key) < pack_feedback(v.key);
    });
    if (out.size() > max_pages) {
        stats.dropped_pages = static_cast<std::uint32_t>(out.size() - max_pages);
        out.resize(max_pages);
    }
    return out;
}

const std::vector<TextureSetup> kRandomTextures = {
    {0, 12}, {5, 20, 700, 300}, {700, 3}, {7, 6, 40, 40}, {65535, 20}};

// Random buffers: runs within rows, rows that repeat the row above, kNoPage rectangles, several
// textures and levels, pages that are ancestors of other pages, and invalid ids.
std::vector<FeedbackId> random_buffer(std::mt19937& rng, std::uint32_t w, std::uint32_t h) {
    auto uni = [&](std::uint32_t lo, std::uint32_t hi) { return std::uniform_int_distribution<std::uint32_t>(lo, hi)(rng); };
    std::vector<FeedbackId> pool;
    const std::uint32_t pool_size = uni(3, 60);
    for (std::uint32_t i = 0; i < pool_size; ++i) {
        const TextureSetup& t = kRandomTextures[uni(0, std::uint32_t(kRandomTextures.size() - 1))];
        PageKey k;
        k.texture = t.id;
        k.level = static_cast<std::uint8_t>(uni(0, std::min<std::uint32_t>(t.levels - 1, 6)));
        const std::uint32_t base = t.pages_x ? 0 : uni(0, 5000);
        const std::uint32_t span = t.pages_x ? std::max(1u, (std::min(t.pages_x, t.pages_y) >> k.level)) : 12;
        k.x = (base >> k.level) + uni(0, span - 1);
        k.y = (base >> k.level) + uni(0, span - 1);
        pool.push_back(pack_feedback(k));
        if (uni(0, 3) == 0) pool.push_back(pack_feedback(k.parent()));  // a page that is also an ancestor
    }
    if (uni(0, 1)) {  // invalid ids
        pool.push_back(pack_feedback(PageKey{700, 5, 0, 0}));         // level >= levels
        pool.push_back(pack_feedback(PageKey{9, 0, 1, 1}));           // unknown texture
        pool.push_back(pack_feedback(PageKey{5, 1, 350, 10}));        // outside the extent at level 1
        pool.push_back(pack_feedback(PageKey{0, 0, 3, 3}) | (1ull << 62));  // reserved bits set
    }
    std::vector<FeedbackId> ids(std::size_t{w} * h, kNoPage);
    for (std::uint32_t y = 0; y < h; ++y) {
        if (y > 0 && uni(0, 2) == 0) {
            std::copy_n(ids.begin() + (y - 1) * w, w, ids.begin() + y * w);
            continue;
        }
        for (std::uint32_t x = 0; x < w;) {
            const std::uint32_t len = std::min(w - x, uni(1, 24));
            const FeedbackId id = pool[uni(0, std::uint32_t(pool.size() - 1))];
            std::fill_n(ids.begin() + y * w + x, len, id);
            x += len;
        }
    }
    for (int r = 0, n = int(uni(0, 3)); r < n; ++r) {  // "no VT here" rectangles
        const std::uint32_t x0 = uni(0, w - 1), y0 = uni(0, h - 1), x1 = uni(x0, w - 1), y1 = uni(y0, h - 1);
        for (std::uint32_t y = y0; y <= y1; ++y)
            for (std::uint32_t x = x0; x <= x1; ++x) ids[y * w + x] = kNoPage;
    }
    return ids;
}

void expect_stats_eq(const Stats& got, const Stats& want) {
    EXPECT_EQ(got.pixels, want.pixels);
    EXPECT_EQ(got.vt_pixels, want.vt_pixels);
    EXPECT_EQ(got.invalid_pixels, want.invalid_pixels);
    EXPECT_EQ(got.unique_pages, want.unique_pages);
    EXPECT_EQ(got.ancestor_pages, want.ancestor_pages);
    EXPECT_EQ(got.dropped_pages, want.dropped_pages);
    EXPECT_EQ(got.untracked_pixels, 0u);
    EXPECT_EQ(got.untracked_ancestors, 0u);
}

std::vector<WantedPage> to_vector(std::span<const WantedPage> s) { return {s.begin(), s.end()}; }

// A small frame builder for the hand-made cases.
struct Frame {
    std::uint32_t w, h;
    std::vector<FeedbackId> ids;
    Frame(std::uint32_t width, std::uint32_t height) : w(width), h(height), ids(std::size_t{width} * height, kNoPage) {}
    void set(std::uint32_t x, std::uint32_t y, const PageKey& k) { ids[y * w + x] = pack_feedback(k); }
    std::vector<WantedPage> run(FeedbackAnalyzer& a, const ResidencyView& r) const { return to_vector(a.analyse(ids, w, h, r)); }
};

TEST(FeedbackAnalysis, MatchesBruteForceOnRandomBuffers) {
    std::mt19937 rng(1234);
    const HashResidency residency;
    FeedbackAnalyzer analyzer(1 << 14);  // reused across frames: stale entries must never leak
    configure(analyzer, kRandomTextures);
    const std::pair<std::uint32_t, std::uint32_t> sizes[] = {{1, 1}, {7, 3}, {40, 25}, {160, 90}, {97, 61}};
    for (int iter = 0; iter < 300; ++iter) {
        const auto [w, h] = sizes[iter % std::size(sizes)];
        const auto ids = random_buffer(rng, w, h);
        Stats want;
        const auto expected = reference(ids, w, h, kRandomTextures, residency, analyzer.max_pages(), want);
        const auto got = to_vector(analyzer.analyse(ids, w, h, residency));
        ASSERT_EQ(got, expected) << "iteration " << iter;
        expect_stats_eq(analyzer.stats(), want);
    }
}

// Many distinct pages (the radix-sorted path, table growth) with exact key ties: pages of one
// pixel each at mirrored positions share gap, subtree and distance.
TEST(FeedbackAnalysis, MatchesBruteForceOnNoise) {
    std::mt19937 rng(77);
    const HashResidency residency;
    FeedbackAnalyzer analyzer(1 << 15);
    configure(analyzer, kRandomTextures);
    for (int iter = 0; iter < 12; ++iter) {
        const std::uint32_t w = iter % 2 ? 160 : 61, h = iter % 2 ? 90 : 40;
        std::vector<FeedbackId> ids(std::size_t{w} * h);
        for (auto& id : ids) {
            const std::uint32_t r = rng();
            if (r % 17 == 0) {
                id = kNoPage;
            } else if (r % 3 == 0) {  // texture 0, 12 levels, no extent
                const auto level = std::uint8_t(rng() % 12);
                id = pack_feedback(PageKey{0, level, std::uint32_t(rng() % (4096u >> level)), std::uint32_t(rng() % 64)});
            } else if (r % 3 == 1) {  // texture 5 within its extent, fine levels
                const auto level = std::uint8_t(rng() % 4);
                id = pack_feedback(PageKey{5, level, std::uint32_t(rng() % (700u >> level)), std::uint32_t(rng() % (300u >> level))});
            } else {  // a small set: repeated pages
                id = pack_feedback(PageKey{65535, std::uint8_t(rng() % 3), std::uint32_t(rng() % 5), std::uint32_t(rng() % 5)});
            }
        }
        for (std::uint32_t y = 0; y < h; y += 3)  // mirrored single pixels: ties down to the packed id
            ids[std::size_t{y} * w + (w - 1)] = pack_feedback(PageKey{7, 0, 39, y % 40});
        for (std::uint32_t y = 0; y < h; y += 3) ids[std::size_t{y} * w] = pack_feedback(PageKey{7, 0, 38, y % 40});
        Stats want;
        const auto expected = reference(ids, w, h, kRandomTextures, residency, analyzer.max_pages(), want);
        ASSERT_GE(expected.size(), 512u);
        const auto got = to_vector(analyzer.analyse(ids, w, h, residency));
        ASSERT_EQ(got, expected) << "iteration " << iter;
        expect_stats_eq(analyzer.stats(), want);
    }
}

TEST(FeedbackAnalysis, MaxPagesDropsLowestPriority) {
    std::mt19937 rng(99);
    const HashResidency residency;
    FeedbackAnalyzer full(1 << 14);
    configure(full, kRandomTextures);
    for (std::size_t limit : {1u, 5u, 37u}) {
        FeedbackAnalyzer bounded(limit, 1 << 14);
        configure(bounded, kRandomTextures);
        for (int iter = 0; iter < 40; ++iter) {
            const auto ids = random_buffer(rng, 64, 36);
            const auto all = to_vector(full.analyse(ids, 64, 36, residency));
            const auto cut = to_vector(bounded.analyse(ids, 64, 36, residency));
            const std::size_t keep = std::min(limit, all.size());
            ASSERT_EQ(cut, std::vector<WantedPage>(all.begin(), all.begin() + std::ptrdiff_t(keep)));
            EXPECT_EQ(bounded.stats().dropped_pages, all.size() - keep);
            EXPECT_EQ(bounded.stats().unique_pages + bounded.stats().ancestor_pages, all.size());
            Stats want;
            reference(ids, 64, 36, kRandomTextures, residency, limit, want);
            expect_stats_eq(bounded.stats(), want);
        }
    }
}

TEST(FeedbackAnalysis, AncestorsUpToTopLevelWithSubtreeSums) {
    FeedbackAnalyzer a;
    a.set_texture_levels(3, 5);
    SetResidency residency;
    residency.resident.insert(pack_feedback(PageKey{3, 4, 0, 0}));  // the top page only
    Frame f(8, 4);
    for (std::uint32_t x = 0; x < 4; ++x) f.set(x, 0, PageKey{3, 0, 5, 3});  // 4 pixels
    f.set(0, 3, PageKey{3, 0, 4, 2});                                         // sibling: 1 pixel (far corner)
    f.set(1, 3, PageKey{3, 0, 4, 2});                                         // 2 pixels
    f.set(4, 2, PageKey{3, 2, 1, 0});  // an ancestor of both that is also asked for: 1 pixel, near the centre
    const auto pages = f.run(a, residency);
    ASSERT_EQ(pages.size(), 6u);
    std::map<std::uint64_t, WantedPage> by_key;
    for (const auto& p : pages) by_key[pack_feedback(p.key)] = p;
    auto get = [&](std::uint8_t level, std::uint32_t x, std::uint32_t y) {
        auto it = by_key.find(pack_feedback(PageKey{3, level, x, y}));
        EXPECT_NE(it, by_key.end()) << int(level) << " " << x << " " << y;
        return it == by_key.end() ? WantedPage{} : it->second;
    };
    const double diag = std::sqrt(8.0 * 8 + 4.0 * 4);
    auto dist = [&](int x, int y) { return float(std::sqrt(double((2 * x + 1 - 8) * (2 * x + 1 - 8) + (2 * y + 1 - 4) * (2 * y + 1 - 4))) / diag); };
    EXPECT_EQ(get(0, 5, 3).pixels, 4u);
    EXPECT_EQ(get(0, 5, 3).subtree_pixels, 4u);
    EXPECT_EQ(get(0, 5, 3).centre_distance, dist(3, 0));
    EXPECT_EQ(get(0, 4, 2).subtree_pixels, 2u);
    EXPECT_EQ(get(0, 4, 2).centre_distance, dist(1, 3));
    EXPECT_EQ(get(1, 2, 1).pixels, 0u);  // added ancestor
    EXPECT_EQ(get(1, 2, 1).subtree_pixels, 6u);
    EXPECT_EQ(get(1, 2, 1).centre_distance, dist(3, 0));
    EXPECT_EQ(get(2, 1, 0).pixels, 1u);
    EXPECT_EQ(get(2, 1, 0).subtree_pixels, 7u);
    EXPECT_EQ(get(2, 1, 0).centre_distance, dist(4, 2));
    EXPECT_EQ(get(3, 0, 0).subtree_pixels, 7u);
    EXPECT_EQ(get(4, 0, 0).subtree_pixels, 7u);
    EXPECT_EQ(get(4, 0, 0).level_gap, 0u);  // resident: present (to be touched), last
    EXPECT_EQ(get(0, 5, 3).resident_level, 4u);
    EXPECT_EQ(get(0, 5, 3).level_gap, 4u);
    EXPECT_EQ(pages.back().key, (PageKey{3, 4, 0, 0}));
    EXPECT_EQ(a.stats().unique_pages, 3u);
    EXPECT_EQ(a.stats().ancestor_pages, 3u);
    EXPECT_EQ(a.stats().vt_pixels, 7u);
    EXPECT_EQ(a.stats().pixels, 32u);
}

TEST(FeedbackAnalysis, TwentyLevelsAndTheWholeAxis) {
    FeedbackAnalyzer a;
    a.set_texture_levels(65535, 21);  // 2^20 pages per axis at level 0 down to one page at level 20
    Frame f(1, 1);
    const PageKey leaf{65535, 0, (1u << 20) - 1, 1u << 16};
    f.set(0, 0, leaf);
    SetResidency nothing;
    const auto pages = f.run(a, nothing);
    ASSERT_EQ(pages.size(), 21u);
    for (std::uint32_t l = 0; l <= 20; ++l) {  // nothing resident: gap 255 - level, finest first
        EXPECT_EQ(pages[l].key, (PageKey{65535, std::uint8_t(l), leaf.x >> l, leaf.y >> l}));
        EXPECT_EQ(pages[l].subtree_pixels, 1u);
        EXPECT_EQ(pages[l].resident_level, 255u);
        EXPECT_EQ(pages[l].level_gap, 255u - l);
    }
}

TEST(FeedbackAnalysis, OrderByLevelGapFirst) {
    FeedbackAnalyzer a;
    a.set_texture_levels(1, 1);  // one level: no ancestors, the pages alone
    MapResidency r;
    const PageKey far_gap{1, 0, 10, 10}, near_gap{1, 0, 2, 2};
    r.levels[pack_feedback(far_gap)] = 3;   // gap 3, 1 pixel, at a corner
    r.levels[pack_feedback(near_gap)] = 1;  // gap 1, many pixels, at the centre
    Frame f(9, 9);
    f.set(0, 0, far_gap);
    for (std::uint32_t x = 2; x < 7; ++x) f.set(x, 4, near_gap);
    const auto pages = f.run(a, r);
    ASSERT_EQ(pages.size(), 2u);
    EXPECT_EQ(pages[0].key, far_gap);
    EXPECT_EQ(pages[0].level_gap, 3u);
    EXPECT_EQ(pages[1].key, near_gap);
}

TEST(FeedbackAnalysis, ThenSubtreePixels) {
    FeedbackAnalyzer a;
    a.set_texture_levels(1, 1);
    MapResidency r;
    const PageKey many{1, 0, 7, 0}, few{1, 0, 0, 0};
    r.levels[pack_feedback(many)] = 2;
    r.levels[pack_feedback(few)] = 2;
    Frame f(9, 9);
    for (std::uint32_t x = 0; x < 3; ++x) f.set(x, 8, many);  // 3 pixels on the edge
    f.set(4, 4, few);                                         // 1 pixel at the centre, lower id
    const auto pages = f.run(a, r);
    ASSERT_EQ(pages.size(), 2u);
    EXPECT_EQ(pages[0].key, many);
    EXPECT_EQ(pages[0].subtree_pixels, 3u);
    EXPECT_EQ(pages[1].key, few);
    EXPECT_EQ(pages[1].centre_distance, 0.0f);
}

TEST(FeedbackAnalysis, ThenCentreDistance) {
    FeedbackAnalyzer a;
    a.set_texture_levels(1, 1);
    MapResidency r;
    const PageKey centre{1, 0, 9, 9}, edge{1, 0, 0, 0};
    Frame f(9, 9);
    f.set(4, 5, centre);
    f.set(4, 5 + 1, centre);
    f.set(0, 4, edge);
    f.set(8, 4, edge);
    const auto pages = f.run(a, r);
    ASSERT_EQ(pages.size(), 2u);
    EXPECT_EQ(pages[0].key, centre);  // nearer the centre, higher id
    EXPECT_EQ(pages[1].key, edge);
    EXPECT_LT(pages[0].centre_distance, pages[1].centre_distance);
    EXPECT_NEAR(pages[1].centre_distance, 8.0 / std::sqrt(2.0 * 81), 1e-6);
    EXPECT_EQ(pages[0].level_gap, 255u);  // nothing resident
}

TEST(FeedbackAnalysis, ThenPackedIdOnFullTies) {
    FeedbackAnalyzer a;
    a.set_texture_levels(1, 1);
    a.set_texture_levels(2, 1);
    MapResidency r;
    const PageKey low{1, 0, 5, 0}, high{2, 0, 0, 0}, mid{1, 0, 0, 1};
    ASSERT_LT(pack_feedback(low), pack_feedback(mid));
    ASSERT_LT(pack_feedback(mid), pack_feedback(high));
    for (int flip = 0; flip < 2; ++flip) {  // the same distance at three mirrored corners
        Frame f(6, 4);
        f.set(flip ? 5 : 0, 0, high);
        f.set(flip ? 0 : 5, 3, low);
        f.set(flip ? 0 : 5, 0, mid);
        const auto pages = f.run(a, r);
        ASSERT_EQ(pages.size(), 3u);
        EXPECT_EQ(pages[0].key, low);
        EXPECT_EQ(pages[1].key, mid);
        EXPECT_EQ(pages[2].key, high);
    }
}

TEST(FeedbackAnalysis, ResidentPagesLast) {
    FeedbackAnalyzer a;
    a.set_texture_levels(1, 1);
    MapResidency r;
    const PageKey resident{1, 0, 0, 0}, wanted{1, 0, 1, 0};
    r.levels[pack_feedback(resident)] = 0;
    r.levels[pack_feedback(wanted)] = 1;
    Frame f(16, 16);
    for (std::uint32_t y = 0; y < 16; ++y)
        for (std::uint32_t x = 0; x < 16; ++x) f.set(x, y, resident);
    f.set(15, 15, wanted);
    const auto pages = f.run(a, r);
    ASSERT_EQ(pages.size(), 2u);
    EXPECT_EQ(pages[0].key, wanted);
    EXPECT_EQ(pages[1].key, resident);
    EXPECT_EQ(pages[1].level_gap, 0u);
    EXPECT_EQ(pages[1].pixels, 255u);
}

TEST(FeedbackAnalysis, InvalidIdsCountedAndIgnored) {
    FeedbackAnalyzer a;
    a.set_texture_levels(4, 3);
    a.set_texture_extent(4, 5, 3);  // level 0: 5x3 pages; level 1: 3x2; level 2: 2x1
    SetResidency r;
    Frame f(8, 2);
    f.set(0, 0, PageKey{4, 3, 0, 0});  // level == levels
    f.set(1, 0, PageKey{4, 31, 0, 0});
    f.set(2, 0, PageKey{9, 0, 0, 0});  // unknown texture
    f.set(3, 0, PageKey{4, 0, 5, 0});  // outside the extent
    f.set(4, 0, PageKey{4, 1, 0, 2});
    f.set(5, 0, PageKey{4, 2, 2, 0});
    f.ids[6] = pack_feedback(PageKey{4, 0, 0, 0}) | (1ull << 61);  // reserved bits
    f.set(7, 0, PageKey{4, 2, 1, 0});                              // valid: the last column at level 2
    f.set(0, 1, PageKey{4, 1, 2, 1});                              // valid: the last page at level 1
    const auto pages = f.run(a, r);
    EXPECT_EQ(a.stats().invalid_pixels, 7u);
    EXPECT_EQ(a.stats().vt_pixels, 2u);
    EXPECT_EQ(a.stats().unique_pages, 2u);
    ASSERT_EQ(pages.size(), 2u);  // (1,2,1) and its parent (2,1,0), which is also asked for
    EXPECT_EQ(pages[0].key, (PageKey{4, 1, 2, 1}));
    EXPECT_EQ(pages[1].key, (PageKey{4, 2, 1, 0}));
    EXPECT_EQ(pages[1].pixels, 1u);
    EXPECT_EQ(pages[1].subtree_pixels, 2u);

    FeedbackAnalyzer unknown;  // no textures configured: everything invalid
    const auto none = f.run(unknown, r);
    EXPECT_TRUE(none.empty());
    EXPECT_EQ(unknown.stats().invalid_pixels, 9u);
    EXPECT_EQ(unknown.stats().vt_pixels, 0u);
}

TEST(FeedbackAnalysis, WrongBufferSizeIsEmpty) {
    FeedbackAnalyzer a;
    a.set_texture_levels(0, 4);
    SetResidency r;
    std::vector<FeedbackId> ids(10, pack_feedback(PageKey{0, 0, 0, 0}));
    EXPECT_TRUE(a.analyse(ids, 4, 3, r).empty());
    EXPECT_EQ(a.stats().pixels, 0u);
    EXPECT_TRUE(a.analyse(ids, 5, 2, r).size() == 4u);
}

TEST(FeedbackAnalysis, FullWorkSetIsCountedNotFatal) {
    FeedbackAnalyzer a(4, 6);  // room for 6 pages with ancestors
    a.set_texture_levels(0, 3);
    SetResidency r;
    Frame f(8, 1);
    for (std::uint32_t x = 0; x < 8; ++x) f.set(x, 0, PageKey{0, 0, x * 4, 0});
    const auto pages = f.run(a, r);
    EXPECT_EQ(a.stats().unique_pages, 6u);
    EXPECT_EQ(a.stats().untracked_pixels, 2u);
    EXPECT_EQ(a.stats().untracked_ancestors, 6u);
    EXPECT_EQ(pages.size(), 4u);
    EXPECT_EQ(a.stats().dropped_pages, 2u);
}

TEST(FeedbackAnalysis, PackUnpackAtTheLimits) {
    const PageKey max{65535, 31, (1u << 20) - 1, (1u << 20) - 1};
    EXPECT_EQ(unpack_feedback(pack_feedback(max)), max);
    EXPECT_NE(pack_feedback(max), kNoPage);
    EXPECT_EQ(pack_feedback(max) >> 61, 0u);  // the reserved bits stay clear, so no page is kNoPage
    const PageKey zero{};
    EXPECT_EQ(unpack_feedback(pack_feedback(zero)), zero);
    EXPECT_EQ(pack_feedback(zero), 0u);
    std::mt19937_64 rng(7);
    for (int i = 0; i < 10000; ++i) {
        const std::uint64_t r = rng();
        const PageKey k{TextureId(r >> 48), std::uint8_t((r >> 43) & 31), std::uint32_t(r & 0xFFFFF),
                        std::uint32_t((r >> 20) & 0xFFFFF)};
        ASSERT_EQ(unpack_feedback(pack_feedback(k)), k);
        ASSERT_NE(pack_feedback(k), kNoPage);
    }
    static_assert(kMaxPagesPerAxis >= (1u << 16) && kMaxLevels >= 20);
    // An id with every field at its maximum is a valid page to the analysis, kNoPage is not.
    FeedbackAnalyzer a;
    a.set_texture_levels(65535, 32);
    SetResidency r;
    const std::vector<FeedbackId> ids = {pack_feedback(max), kNoPage};
    const auto pages = to_vector(a.analyse(ids, 2, 1, r));
    ASSERT_EQ(pages.size(), 1u);  // level 31 is the top of a 32-level texture
    EXPECT_EQ(pages[0].key, max);
    EXPECT_EQ(a.stats().vt_pixels, 1u);
    EXPECT_EQ(a.stats().invalid_pixels, 0u);
}

// 2^24 valid pixels: subtree sums no longer fit the packed 64-bit sort key, so the ranking falls
// back to the full comparator. Same rules, checked against the reference (128 MiB of ids).
TEST(FeedbackAnalysis, HugeBufferUsesTheFullComparator) {
    const std::uint32_t w = 4096, h = 4096;
    const std::vector<TextureSetup> textures = {{0, 1}, {1, 3}};
    std::vector<FeedbackId> ids(std::size_t{w} * h, pack_feedback(PageKey{0, 0, 0, 0}));
    std::mt19937 rng(3);
    for (int i = 0; i < 4000; ++i) {  // small pages scattered over the big one, some sharing ancestors
        const std::uint32_t x = rng() % w, y = rng() % h, len = 1 + rng() % 40;
        const PageKey k{1, std::uint8_t(rng() % 3), std::uint32_t(rng() % 6), std::uint32_t(rng() % 6)};
        std::fill_n(ids.begin() + std::ptrdiff_t(y) * w + x, std::min(len, w - x), pack_feedback(k));
    }
    for (std::uint32_t x : {0u, w - 1}) ids[x] = pack_feedback(PageKey{1, 0, 9, 9});  // an exact distance tie
    ids[std::size_t{h - 1} * w] = pack_feedback(PageKey{1, 0, 9, 8});
    ids[std::size_t{h - 1} * w + w - 1] = pack_feedback(PageKey{1, 0, 9, 8});
    const HashResidency residency;
    FeedbackAnalyzer a(64);
    configure(a, textures);
    const auto got = to_vector(a.analyse(ids, w, h, residency));
    ASSERT_EQ(a.stats().vt_pixels, 1u << 24);
    Stats want;
    const auto expected = reference(ids, w, h, textures, residency, 64, want);
    EXPECT_EQ(got, expected);
    expect_stats_eq(a.stats(), want);
}

TEST(FeedbackAnalysis, NoAllocationPerFrame) {
    std::mt19937 rng(5);
    std::vector<std::vector<FeedbackId>> frames;
    for (int i = 0; i < 20; ++i) frames.push_back(random_buffer(rng, 160, 90));
    std::vector<FeedbackId> noise(160 * 90);
    for (auto& id : noise)
        id = pack_feedback(PageKey{5, std::uint8_t(rng() % 10), std::uint32_t(rng() % 700), std::uint32_t(rng() % 300)});
    noise[3] = kNoPage;
    frames.push_back(noise);
    frames.push_back(std::vector<FeedbackId>(160 * 90, kNoPage));
    const HashResidency residency;
    FeedbackAnalyzer a(1 << 12);  // small enough that the noise frame overflows the work set too
    configure(a, kRandomTextures);
    std::size_t pages = 0;
    const std::size_t before = g_allocations.load();
    for (int round = 0; round < 3; ++round)
        for (const auto& f : frames) pages += a.analyse(f, 160, 90, residency).size();
    const std::size_t after = g_allocations.load();
    EXPECT_EQ(after - before, 0u);
    EXPECT_GT(pages, 0u);
}

TEST(FeedbackAnalysis, DeterministicOutput) {
    std::mt19937 rng(42);
    const HashResidency residency;
    FeedbackAnalyzer a1(300), a2(300);
    configure(a1, kRandomTextures);
    configure(a2, kRandomTextures);
    std::vector<std::vector<FeedbackId>> frames;
    for (int i = 0; i < 10; ++i) frames.push_back(random_buffer(rng, 120, 70));
    for (const auto& f : frames) a2.analyse(f, 120, 70, residency);  // a2 has seen other frames first
    for (const auto& f : frames) {
        const auto first = to_vector(a1.analyse(f, 120, 70, residency));
        const auto again = to_vector(a1.analyse(f, 120, 70, residency));
        const auto other = to_vector(a2.analyse(f, 120, 70, residency));
        EXPECT_EQ(first, again);
        EXPECT_EQ(first, other);
    }
}

}  // namespace
}  // namespace tessera::client
