#pragma once
// The server's RAM cache of hot tiles, bounded in bytes. Policy: S3-FIFO (Yang et al., SOSP'23):
// a small probationary FIFO (10% of the budget), a main FIFO with a 2-bit frequency per entry
// (re-inserted instead of evicted while its frequency is non-zero) and a ghost FIFO of recently
// evicted keys, so one-hit wonders and scans pass through the small queue without flushing the
// hot set, where plain LRU would lose it. Sharded by key hash; thread-safe.
#include <cstddef>
#include <cstdint>
#include <memory>

#include "tessera/storage/store_reader.hpp"

namespace tessera::server {

struct CacheKey {
    std::uint64_t store_version = 0;  // StoreInfo::store_id: a replaced store never hits old tiles
    TileKey tile;
    friend bool operator==(const CacheKey&, const CacheKey&) = default;
};

struct CacheStats {
    std::uint64_t hits = 0;
    std::uint64_t misses = 0;
    std::uint64_t insertions = 0;
    std::uint64_t evictions = 0;
    std::uint64_t bytes = 0;    // charged bytes now held (payload + per-entry overhead)
    std::uint64_t entries = 0;
    std::uint64_t budget = 0;
};

class TileCache {
public:
    // byte_budget 0 disables the cache (every get misses, put does nothing).
    explicit TileCache(std::size_t byte_budget, unsigned shards = 16);
    ~TileCache();
    TileCache(const TileCache&) = delete;
    TileCache& operator=(const TileCache&) = delete;

    std::shared_ptr<const storage::Tile> get(const CacheKey& key);
    // Inserts (or replaces). A tile larger than a shard's budget is not cached.
    void put(const CacheKey& key, std::shared_ptr<const storage::Tile> tile);
    CacheStats stats() const;

    // Bytes charged for one tile: its payload plus a fixed bookkeeping overhead.
    static std::size_t charge(const storage::Tile& tile);

private:
    struct Shard;
    std::unique_ptr<Shard[]> shards_;
    unsigned shard_count_;
    std::size_t budget_;
};

}  // namespace tessera::server
