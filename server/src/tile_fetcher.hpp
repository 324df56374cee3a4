#pragma once
// Reads tiles for both front ends (gRPC scheduler workers, HTTP handlers): RAM cache first, then
// one batch read per store for the misses (the reader coalesces payloads adjacent in the file).
// A miss whose tile is already being read for another request joins that read instead of reading
// it again (single flight), so however many viewers miss a tile at once it is read once.
// Every payload is checksum-verified by the reader; one that fails is answered DATA_LOSS and
// logged, never served.
#include <memory>
#include <mutex>
#include <span>
#include <unordered_map>
#include <string>
#include <vector>

#include "log.hpp"
#include "metrics.hpp"
#include "store_registry.hpp"
#include "tile_cache.hpp"

namespace tessera::server {

struct FetchedTile {
    TileStatus status = TileStatus::ok;
    std::string message;                        // when status != ok
    std::shared_ptr<const storage::Tile> tile;  // when status == ok (kind may be absent)
};

class TileFetcher {
public:
    // decoded_bytes: the budget of a second RAM cache, of tiles decoded for web images (0: none).
    TileFetcher(TileCache& cache, MetricsRegistry& metrics, Logger& log, std::size_t decoded_bytes = 0);
    ~TileFetcher();  // removes its gauge callbacks from the registry
    TileFetcher(const TileFetcher&) = delete;
    TileFetcher& operator=(const TileFetcher&) = delete;
    // Tiles of one store, results in the order of keys (out is resized to keys.size()).
    void fetch(const StoreHandle& store, std::span<const TileKey> keys, std::vector<FetchedTile>& out);
    FetchedTile fetch_one(const StoreHandle& store, const TileKey& key);
    // The tile when the RAM cache holds it (counted as a hit), else null and nothing counted:
    // what an event loop may answer at once, without waiting for a read.
    std::shared_ptr<const storage::Tile> cached(const StoreHandle& store, const TileKey& key);

    TileCache& cache() { return cache_; }
    // Tiles decoded for web images (http/web_image.cpp), keyed by the store's version, the tile
    // and the view of it (`look`: a layered store's layer): a web tile cut from a decoded tile
    // costs one encode instead of a decode and an encode, as IIPImage keeps decoded tiles too.
    // null when not held (or the cache is off); counted as a hit or miss.
    std::shared_ptr<const storage::Tile> decoded(const StoreHandle& store, const TileKey& key, std::uint32_t look);
    void keep_decoded(const StoreHandle& store, const TileKey& key, std::uint32_t look, std::vector<std::uint8_t> texels);
    bool keeps_decoded() const { return decoded_budget_ > 0; }
    std::uint64_t decoded_hits() const { return decoded_hits_->value(); }
    std::uint64_t reads() const { return reads_->value(); }
    std::uint64_t tiles_read() const { return tiles_read_->value(); }
    std::uint64_t reads_saved() const { return reads_saved_->value(); }

private:
    struct Flight;  // one tile's read in progress, and its result once done
    struct CacheKeyHash {
        std::size_t operator()(const CacheKey& k) const noexcept;
    };
    // Reads `keys` (cache misses this call leads) into out[index[j]].
    void read_misses(const StoreHandle& store, const std::vector<TileKey>& keys, const std::vector<std::size_t>& index,
                     std::vector<FetchedTile>& out);

    TileCache& cache_;
    std::size_t decoded_budget_;
    TileCache decoded_;
    MetricsRegistry& metrics_;
    Logger& log_;
    Counter* reads_;       // file reads after coalescing
    Counter* tiles_read_;  // tiles those reads returned
    Counter* read_bytes_;
    Counter* cache_hits_;
    Counter* cache_misses_;
    Counter* reads_saved_;  // misses that joined a read already in flight
    Counter* decoded_hits_;
    Counter* decoded_misses_;
    std::mutex flights_mutex_;
    std::unordered_map<CacheKey, std::shared_ptr<Flight>, CacheKeyHash> flights_;  // bounded by reads in progress
};

}  // namespace tessera::server
