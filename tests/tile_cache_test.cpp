// The server's S3-FIFO tile cache: hits and misses by key, the byte budget, replacement, resistance
// to scans (compared with plain LRU) and consistency under concurrent use.
#include <gtest/gtest.h>

#include <cstdio>
#include <list>
#include <random>
#include <thread>
#include <unordered_map>
#include <utility>
#include <vector>

#include "tile_cache.hpp"

using namespace tessera;
using tessera::server::CacheKey;
using tessera::server::CacheStats;
using tessera::server::TileCache;
using tessera::storage::Tile;

namespace {

constexpr std::size_t kOverhead = 128;  // what TileCache::charge adds to the payload

CacheKey key(std::uint32_t x, std::uint32_t y = 0, std::uint32_t level = 0, std::uint64_t version = 1) {
    return CacheKey{version, {level, x, y}};
}

// A present tile of `payload` bytes whose contents identify the key it was made for.
std::shared_ptr<const Tile> make_tile(const CacheKey& k, std::size_t payload) {
    auto t = std::make_shared<Tile>();
    t->key = k.tile;
    t->kind = tessera::TileKind::present;
    t->bytes.assign(payload, static_cast<std::uint8_t>(k.store_version));
    return t;
}

// Every entry that went in either is still there or was counted as evicted.
void expect_consistent(const CacheStats& s) {
    EXPECT_LE(s.bytes, s.budget);
    EXPECT_EQ(s.entries, s.insertions - s.evictions);
    EXPECT_GE(s.bytes, s.entries * kOverhead);
}

struct KeyHash {
    std::size_t operator()(const CacheKey& k) const {
        std::uint64_t h = k.store_version * 0x9e3779b97f4a7c15ULL;
        h ^= (std::uint64_t{k.tile.level} << 48) ^ (std::uint64_t{k.tile.x} << 24) ^ k.tile.y;
        return std::hash<std::uint64_t>{}(h);
    }
};

// Plain LRU with the same byte budget and charge, as the baseline S3-FIFO has to beat.
class LruCache {
public:
    explicit LruCache(std::size_t budget) : budget_(budget) {}

    std::shared_ptr<const Tile> get(const CacheKey& k) {
        const auto it = index_.find(k);
        if (it == index_.end()) return {};
        order_.splice(order_.begin(), order_, it->second);
        return it->second->second;
    }

    // Only called after a miss, so the key is new.
    void put(const CacheKey& k, std::shared_ptr<const Tile> tile) {
        bytes_ += TileCache::charge(*tile);
        order_.emplace_front(k, std::move(tile));
        index_[k] = order_.begin();
        while (bytes_ > budget_) {
            bytes_ -= TileCache::charge(*order_.back().second);
            index_.erase(order_.back().first);
            order_.pop_back();
        }
    }

private:
    using Node = std::pair<CacheKey, std::shared_ptr<const Tile>>;
    std::size_t budget_;
    std::size_t bytes_ = 0;
    std::list<Node> order_;  // front = most recently used
    std::unordered_map<CacheKey, std::list<Node>::iterator, KeyHash> index_;
};

// A viewer's working set of hot tiles, loaded twice, then revisited (one random hot tile every
// few requests) while a one-pass scan streams tiles amounting to many times the budget.
// Returns the hit ratio of the hot requests made during the scan.
template <class Cache>
double hot_hit_ratio_under_scan(Cache& cache) {
    constexpr std::uint32_t kHot = 200;
    constexpr std::uint32_t kScan = 50'000;
    constexpr std::uint32_t kHotEvery = 6;
    constexpr std::size_t kPayload = 1000;
    const auto request = [&cache](const CacheKey& k) {
        if (cache.get(k)) return true;
        cache.put(k, make_tile(k, kPayload));
        return false;
    };
    for (int pass = 0; pass < 2; ++pass)
        for (std::uint32_t i = 0; i < kHot; ++i) request(key(i, 0, 3));

    std::mt19937 rng(7);
    std::uniform_int_distribution<std::uint32_t> pick(0, kHot - 1);
    std::uint64_t hot_requests = 0;
    std::uint64_t hot_hits = 0;
    for (std::uint32_t i = 0; i < kScan; ++i) {
        request(key(i % 1000, i / 1000, 0));
        if (i % kHotEvery == 0) {
            ++hot_requests;
            if (request(key(pick(rng), 0, 3))) ++hot_hits;
        }
    }
    return static_cast<double>(hot_hits) / static_cast<double>(hot_requests);
}

TEST(TileCacheTest, HitAfterPut) {
    TileCache cache(1 << 20);
    const auto tile = make_tile(key(3, 4, 1), 500);
    cache.put(key(3, 4, 1), tile);
    const auto got = cache.get(key(3, 4, 1));
    ASSERT_NE(got, nullptr);
    EXPECT_EQ(got, tile);
    const CacheStats s = cache.stats();
    EXPECT_EQ(s.hits, 1u);
    EXPECT_EQ(s.misses, 0u);
    EXPECT_EQ(s.insertions, 1u);
    EXPECT_EQ(s.entries, 1u);
    EXPECT_EQ(s.bytes, 500 + kOverhead);
    EXPECT_EQ(s.budget, 1u << 20);
    EXPECT_EQ(TileCache::charge(*tile), 500 + kOverhead);
}

TEST(TileCacheTest, OtherStoreVersionOrPositionMisses) {
    TileCache cache(1 << 20);
    cache.put(key(3, 4, 1, 10), make_tile(key(3, 4, 1, 10), 100));
    EXPECT_EQ(cache.get(key(3, 4, 1, 11)), nullptr);  // same tile of a replaced store
    EXPECT_EQ(cache.get(key(4, 3, 1, 10)), nullptr);  // x and y swapped
    EXPECT_EQ(cache.get(key(3, 4, 0, 10)), nullptr);  // another level
    EXPECT_NE(cache.get(key(3, 4, 1, 10)), nullptr);
    const CacheStats s = cache.stats();
    EXPECT_EQ(s.misses, 3u);
    EXPECT_EQ(s.hits, 1u);
}

TEST(TileCacheTest, DisabledWhenBudgetIsZero) {
    TileCache cache(0);
    cache.put(key(1), make_tile(key(1), 10));
    EXPECT_EQ(cache.get(key(1)), nullptr);
    const CacheStats s = cache.stats();
    EXPECT_EQ(s.budget, 0u);
    EXPECT_EQ(s.bytes, 0u);
    EXPECT_EQ(s.entries, 0u);
    EXPECT_EQ(s.insertions, 0u);
    EXPECT_EQ(s.misses, 1u);
}

TEST(TileCacheTest, NullTileIsIgnored) {
    TileCache cache(1 << 20);
    cache.put(key(1), nullptr);
    EXPECT_EQ(cache.get(key(1)), nullptr);
    EXPECT_EQ(cache.stats().entries, 0u);
}

TEST(TileCacheTest, TileLargerThanAShardIsNotCached) {
    // One shard of 10000 bytes: a charge of exactly 10000 fits, one byte more does not.
    TileCache one(10'000, 1);
    one.put(key(1), make_tile(key(1), 10'000 - kOverhead + 1));
    EXPECT_EQ(one.get(key(1)), nullptr);
    EXPECT_EQ(one.stats().bytes, 0u);
    EXPECT_EQ(one.stats().insertions, 0u);
    one.put(key(2), make_tile(key(2), 10'000 - kOverhead));
    EXPECT_NE(one.get(key(2)), nullptr);
    EXPECT_EQ(one.stats().bytes, 10'000u);

    // The limit is a shard's share, not the whole budget.
    TileCache sharded(16'000, 16);
    sharded.put(key(1), make_tile(key(1), 1000 - kOverhead + 1));
    EXPECT_EQ(sharded.get(key(1)), nullptr);
    EXPECT_EQ(sharded.stats().entries, 0u);
}

TEST(TileCacheTest, ReplaceAdjustsBytes) {
    TileCache cache(1 << 20, 4);
    cache.put(key(5), make_tile(key(5), 100));
    cache.put(key(6), make_tile(key(6), 50));
    EXPECT_EQ(cache.stats().bytes, 150 + 2 * kOverhead);

    const auto bigger = make_tile(key(5), 1000);
    cache.put(key(5), bigger);
    EXPECT_EQ(cache.get(key(5)), bigger);
    CacheStats s = cache.stats();
    EXPECT_EQ(s.bytes, 1050 + 2 * kOverhead);
    EXPECT_EQ(s.entries, 2u);
    EXPECT_EQ(s.insertions, 2u);

    cache.put(key(5), make_tile(key(5), 10));
    s = cache.stats();
    EXPECT_EQ(s.bytes, 60 + 2 * kOverhead);
    EXPECT_EQ(s.entries, 2u);
    ASSERT_NE(cache.get(key(5)), nullptr);
    EXPECT_EQ(cache.get(key(5))->bytes.size(), 10u);
}

TEST(TileCacheTest, OversizedReplacementDropsTheOldValue) {
    TileCache cache(10'000, 1);
    cache.put(key(1), make_tile(key(1), 100));
    cache.put(key(1), make_tile(key(1), 20'000));
    EXPECT_EQ(cache.get(key(1)), nullptr);
    const CacheStats s = cache.stats();
    EXPECT_EQ(s.bytes, 0u);
    expect_consistent(s);
}

TEST(TileCacheTest, ByteBudgetNeverExceeded) {
    // Sizes up to past a shard's budget (50000), a key space larger than the cache, replacements.
    constexpr std::size_t kBudget = 200'000;
    TileCache cache(kBudget, 4);
    std::mt19937 rng(1);
    std::uniform_int_distribution<std::uint32_t> pick_key(0, 499);
    std::uniform_int_distribution<std::size_t> pick_size(0, 20'000);
    std::uniform_int_distribution<int> pick_op(0, 9);
    for (int op = 0; op < 20'000; ++op) {
        const CacheKey k = key(pick_key(rng), 0, 0, pick_op(rng) < 5 ? 1 : 2);
        if (pick_op(rng) < 4) {
            if (const auto got = cache.get(k)) {
                EXPECT_EQ(got->key.x, k.tile.x);
                EXPECT_EQ(got->bytes.empty() ? k.store_version : got->bytes[0], k.store_version);
            }
        } else {
            std::size_t size = pick_size(rng);
            if (pick_op(rng) == 0) size = 60'000;
            cache.put(k, make_tile(k, size));
        }
        const CacheStats s = cache.stats();
        ASSERT_LE(s.bytes, s.budget) << "after op " << op;
        ASSERT_EQ(s.entries, s.insertions - s.evictions) << "after op " << op;
    }
    const CacheStats s = cache.stats();
    EXPECT_EQ(s.budget, kBudget);
    EXPECT_GT(s.evictions, 0u);
    EXPECT_GT(s.hits, 0u);
    // Eviction only makes the room a put needs: the cache ends up nearly full.
    EXPECT_GT(s.bytes, kBudget / 2);
}

// One shard holding ten tiles of charge 1000: the small queue's share is one tile, the main
// queue's (and the ghost's) nine.
constexpr std::size_t kSmallTestPayload = 1000 - kOverhead;

void scan(TileCache& cache, std::uint32_t first, std::uint32_t count) {
    for (std::uint32_t i = first; i < first + count; ++i)
        cache.put(key(i, 0, 1), make_tile(key(i, 0, 1), kSmallTestPayload));
}

TEST(TileCacheTest, TileHitOnProbationSurvivesScan) {
    TileCache cache(10'000, 1);
    const CacheKey hot = key(0, 0, 5);
    cache.put(hot, make_tile(hot, kSmallTestPayload));
    ASSERT_NE(cache.get(hot), nullptr);  // the hit that earns it a place in main
    scan(cache, 0, 200);
    EXPECT_NE(cache.get(hot), nullptr);
    EXPECT_EQ(cache.stats().entries, 10u);
}

TEST(TileCacheTest, TileRequestedAgainSoonAfterEvictionSurvivesScan) {
    TileCache cache(10'000, 1);
    const CacheKey hot = key(0, 0, 5);
    cache.put(hot, make_tile(hot, kSmallTestPayload));
    scan(cache, 0, 10);  // never hit, it leaves first, remembered by the ghost
    ASSERT_EQ(cache.get(hot), nullptr);
    cache.put(hot, make_tile(hot, kSmallTestPayload));  // a ghost hit: straight to main
    scan(cache, 10, 200);
    EXPECT_NE(cache.get(hot), nullptr);
}

TEST(TileCacheTest, TileHitInMainIsReinsertedNotEvicted) {
    TileCache cache(10'000, 1);
    const CacheKey hot = key(0, 0, 5);
    cache.put(hot, make_tile(hot, kSmallTestPayload));
    ASSERT_NE(cache.get(hot), nullptr);
    scan(cache, 0, 10);  // moves it to main, the oldest entry there
    // Tiles each hit once on probation fill main past its share, so main evicts in FIFO order;
    // the hot tile, at the front but hit since, goes round again each time.
    for (std::uint32_t i = 0; i < 40; ++i) {
        const CacheKey k = key(i, 0, 2);
        cache.put(k, make_tile(k, kSmallTestPayload));
        ASSERT_NE(cache.get(k), nullptr);
        if (i % 4 == 0) {
            ASSERT_NE(cache.get(hot), nullptr) << "after " << i;
        }
    }
    EXPECT_NE(cache.get(hot), nullptr);
    EXPECT_GE(cache.stats().evictions, 40u);
}

TEST(TileCacheTest, ScanDoesNotFlushHotSetUnlikeLru) {
    constexpr std::size_t kBudget = 1000 * (1000 + kOverhead);  // 1000 tiles; the scan is 50x that
    TileCache s3fifo(kBudget, 1);
    LruCache lru(kBudget);
    const double s3fifo_ratio = hot_hit_ratio_under_scan(s3fifo);
    const double lru_ratio = hot_hit_ratio_under_scan(lru);
    // Sharding splits the budget; the hot set must survive per shard too.
    TileCache sharded(kBudget, 16);
    const double sharded_ratio = hot_hit_ratio_under_scan(sharded);
    std::printf("hot hit ratio during scan: S3-FIFO %.4f (16 shards %.4f), LRU %.4f\n", s3fifo_ratio,
                sharded_ratio, lru_ratio);
    RecordProperty("s3fifo_hot_hit_permille", static_cast<int>(s3fifo_ratio * 1000));
    RecordProperty("s3fifo_16_shards_hot_hit_permille", static_cast<int>(sharded_ratio * 1000));
    RecordProperty("lru_hot_hit_permille", static_cast<int>(lru_ratio * 1000));

    EXPECT_GE(s3fifo_ratio, 0.8);
    EXPECT_GE(sharded_ratio, 0.8);
    EXPECT_GT(s3fifo_ratio, lru_ratio + 0.25);
    expect_consistent(s3fifo.stats());
    expect_consistent(sharded.stats());
}

TEST(TileCacheTest, ConcurrentGetAndPutKeepInvariants) {
    constexpr int kThreads = 4;
    constexpr int kOpsPerThread = 100'000;
    constexpr std::size_t kBudget = 256 * 1024;
    TileCache cache(kBudget, 8);
    // Each key always gets the same size and contents, so any tile served can be checked.
    const auto size_of = [](const CacheKey& k) {
        return std::size_t{(k.tile.x * 7919u + k.tile.y * 104'729u) % 4000u};
    };
    std::vector<std::thread> threads;
    std::vector<std::uint64_t> gets(kThreads, 0);
    std::vector<int> bad(kThreads, 0);
    for (int t = 0; t < kThreads; ++t) {
        threads.emplace_back([&, t] {
            std::mt19937 rng(100 + static_cast<unsigned>(t));
            std::uniform_int_distribution<std::uint32_t> coord(0, 39);
            std::uniform_int_distribution<int> pick(0, 99);
            for (int op = 0; op < kOpsPerThread; ++op) {
                const CacheKey k = key(coord(rng), coord(rng), 0, pick(rng) < 80 ? 1 : 2);
                if (pick(rng) < 70) {
                    ++gets[static_cast<std::size_t>(t)];
                    if (const auto tile = cache.get(k)) {
                        const bool ok = tile->key.x == k.tile.x && tile->key.y == k.tile.y &&
                                        tile->bytes.size() == size_of(k) &&
                                        (tile->bytes.empty() || tile->bytes.back() == k.store_version);
                        if (!ok) ++bad[static_cast<std::size_t>(t)];
                    }
                } else {
                    cache.put(k, make_tile(k, size_of(k)));
                }
                if (op % 1000 == 0 && cache.stats().bytes > kBudget) ++bad[static_cast<std::size_t>(t)];
            }
        });
    }
    for (auto& th : threads) th.join();

    std::uint64_t total_gets = 0;
    for (int t = 0; t < kThreads; ++t) {
        EXPECT_EQ(bad[static_cast<std::size_t>(t)], 0) << "thread " << t;
        total_gets += gets[static_cast<std::size_t>(t)];
    }
    const CacheStats s = cache.stats();
    EXPECT_EQ(s.hits + s.misses, total_gets);
    EXPECT_GT(s.hits, 0u);
    EXPECT_GT(s.evictions, 0u);
    expect_consistent(s);
}

}  // namespace
