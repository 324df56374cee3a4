#pragma once
// Client tile caches, first level: the RAM cache (docs/client.md, "One frame, end to end", steps 4
// and 6: a page that is not resident goes RAM cache -> disk cache -> network; replies land in the
// disk and RAM caches). Also the key the caches share: TileId, a tile of one *version* of a store.
// Entries are TileData (tessera/tile.hpp): what a reply carried.
//
// The key includes the store version, so a rebuilt store (new StoreMetadata.version) can never be
// served from entries of its old content; erase_store_versions_except() drops the stale ones
// eagerly instead of waiting for them to age out.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <list>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "tessera/client/page.hpp"

namespace tessera::client {

// One tile of one version of one store.
struct TileId {
    std::string store;           // store name (server side: the file name without .tsr)
    std::uint64_t version = 0;   // StoreMetadata.version / TileReply.store_version
    TileKey tile;
    friend bool operator==(const TileId&, const TileId&) = default;
};

struct TileIdHash {
    std::size_t operator()(const TileId& id) const noexcept;
};

// XXH3-64 of `bytes`: the checksum TileReply.checksum and TileData.checksum carry. The caches keep
// it and the disk cache verifies it on every read.
std::uint64_t tile_checksum(std::span<const std::uint8_t> bytes);

struct RamCacheStats {
    std::uint64_t hits = 0;
    std::uint64_t misses = 0;
    std::uint64_t bytes = 0;      // sum of charge() over the entries; never above byte_budget
    std::uint64_t entries = 0;
    std::uint64_t evictions = 0;  // entries removed to make room (not erase/replace)
    std::uint64_t rejected = 0;   // puts refused: null tile, or one tile larger than the budget
    std::uint64_t byte_budget = 0;
};

// A byte-bounded LRU cache of tiles in memory. Thread-safe (one mutex; every operation is O(1)
// except erase_store_versions_except, which is O(entries)). Tiles are immutable and shared:
// get() hands out the same object the cache holds, so a hit copies nothing.
class RamTileCache {
public:
    explicit RamTileCache(std::uint64_t byte_budget);
    RamTileCache(const RamTileCache&) = delete;
    RamTileCache& operator=(const RamTileCache&) = delete;

    // The tile, or null on a miss. A hit makes the entry the most recently used.
    std::shared_ptr<const TileData> get(const TileId& id);
    // Like get() but changes neither the LRU order nor the stats.
    bool contains(const TileId& id) const;

    // Inserts or replaces, as most recently used, then evicts least recently used entries until
    // the charge fits the budget. False (nothing cached) when the tile is null or its charge
    // alone exceeds the budget.
    bool put(const TileId& id, std::shared_ptr<const TileData> tile);
    bool put(const TileId& id, TileData tile);

    bool erase(const TileId& id);
    // Drops every entry of `store` whose version is not `version` (the store was rebuilt).
    // Returns how many entries were dropped.
    std::size_t erase_store_versions_except(std::string_view store, std::uint64_t version);
    void clear();

    RamCacheStats stats() const;
    std::uint64_t byte_budget() const { return budget_; }

    // Bytes an entry counts against the budget: the payload plus a fixed bookkeeping overhead.
    static std::uint64_t charge(const TileId& id, const TileData& tile);

private:
    struct Node {
        TileId id;
        std::shared_ptr<const TileData> tile;
        std::uint64_t charge = 0;
    };
    using List = std::list<Node>;

    void erase_locked(List::iterator it);

    const std::uint64_t budget_;
    mutable std::mutex mu_;
    List lru_;  // front: most recently used
    std::unordered_map<TileId, List::iterator, TileIdHash> map_;
    std::uint64_t bytes_ = 0;
    std::uint64_t hits_ = 0;
    std::uint64_t misses_ = 0;
    std::uint64_t evictions_ = 0;
    std::uint64_t rejected_ = 0;
};

}  // namespace tessera::client

template <>
struct std::hash<tessera::client::TileId> {
    std::size_t operator()(const tessera::client::TileId& id) const noexcept {
        return tessera::client::TileIdHash{}(id);
    }
};
