#include "ram_cache.hpp"

#include <xxhash.h>

#include <utility>

namespace tessera::client {

std::size_t TileIdHash::operator()(const TileId& id) const noexcept {
    std::uint64_t h = XXH3_64bits(id.store.data(), id.store.size());
    auto mix = [&h](std::uint64_t v) {
        h ^= v + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2);
        h *= 0xBF58476D1CE4E5B9ull;
        h ^= h >> 31;
    };
    mix(id.version);
    mix((std::uint64_t{id.tile.x} << 32) | id.tile.y);
    mix(id.tile.level);
    return static_cast<std::size_t>(h);
}

std::uint64_t tile_checksum(std::span<const std::uint8_t> bytes) { return XXH3_64bits(bytes.data(), bytes.size()); }

// ---- RamTileCache ------------------------------------------------------------------------------

namespace {
// List node, map node, key copies and the TileData itself, rounded up.
constexpr std::uint64_t kEntryOverhead = 192;
}  // namespace

std::uint64_t RamTileCache::charge(const TileId& id, const TileData& tile) {
    return kEntryOverhead + 2 * id.store.size() + tile.payload.size();
}

RamTileCache::RamTileCache(std::uint64_t byte_budget) : budget_(byte_budget) {}

std::shared_ptr<const TileData> RamTileCache::get(const TileId& id) {
    std::lock_guard lock(mu_);
    auto it = map_.find(id);
    if (it == map_.end()) {
        ++misses_;
        return nullptr;
    }
    ++hits_;
    lru_.splice(lru_.begin(), lru_, it->second);
    return it->second->tile;
}

bool RamTileCache::contains(const TileId& id) const {
    std::lock_guard lock(mu_);
    return map_.count(id) != 0;
}

bool RamTileCache::put(const TileId& id, TileData tile) {
    return put(id, std::make_shared<const TileData>(std::move(tile)));
}

bool RamTileCache::put(const TileId& id, std::shared_ptr<const TileData> tile) {
    const std::uint64_t c = tile ? charge(id, *tile) : 0;
    std::lock_guard lock(mu_);
    if (!tile || c > budget_) {
        ++rejected_;
        return false;
    }
    if (auto it = map_.find(id); it != map_.end()) {
        Node& node = *it->second;
        bytes_ -= node.charge;
        node.tile = std::move(tile);
        node.charge = c;
        bytes_ += c;
        lru_.splice(lru_.begin(), lru_, it->second);
    } else {
        lru_.push_front(Node{id, std::move(tile), c});
        try {
            map_.emplace(id, lru_.begin());
        } catch (...) {
            lru_.pop_front();
            throw;
        }
        bytes_ += c;
    }
    // The new entry is at the front and fits the budget by itself, so this stops before it.
    while (bytes_ > budget_) {
        erase_locked(std::prev(lru_.end()));
        ++evictions_;
    }
    return true;
}

void RamTileCache::erase_locked(List::iterator it) {
    bytes_ -= it->charge;
    map_.erase(it->id);
    lru_.erase(it);
}

bool RamTileCache::erase(const TileId& id) {
    std::lock_guard lock(mu_);
    auto it = map_.find(id);
    if (it == map_.end()) return false;
    erase_locked(it->second);
    return true;
}

std::size_t RamTileCache::erase_store_versions_except(std::string_view store, std::uint64_t version) {
    std::lock_guard lock(mu_);
    std::size_t n = 0;
    for (auto it = lru_.begin(); it != lru_.end();) {
        auto next = std::next(it);
        if (it->id.store == store && it->id.version != version) {
            erase_locked(it);
            ++n;
        }
        it = next;
    }
    return n;
}

void RamTileCache::clear() {
    std::lock_guard lock(mu_);
    map_.clear();
    lru_.clear();
    bytes_ = 0;
}

RamCacheStats RamTileCache::stats() const {
    std::lock_guard lock(mu_);
    RamCacheStats s;
    s.hits = hits_;
    s.misses = misses_;
    s.bytes = bytes_;
    s.entries = map_.size();
    s.evictions = evictions_;
    s.rejected = rejected_;
    s.byte_budget = budget_;
    return s;
}

}  // namespace tessera::client
