#include "tile_fetcher.hpp"

#include <algorithm>
#include <condition_variable>
#include <cstdio>
#include <functional>

#include "tessera/storage/byte_source.hpp"

namespace tessera::server {

TileFetcher::TileFetcher(TileCache& cache, MetricsRegistry& metrics, Logger& log, std::size_t decoded_bytes)
    : cache_(cache), decoded_budget_(decoded_bytes), decoded_(decoded_bytes), metrics_(metrics), log_(log) {
    decoded_hits_ = &metrics.counter("tessera_web_decoded_hits_total", "Web image tiles found decoded in RAM");
    decoded_misses_ = &metrics.counter("tessera_web_decoded_misses_total", "Web image tiles decoded (not found decoded in RAM)");
    metrics.gauge_callback("tessera_web_decoded_bytes", "Bytes held by the RAM cache of tiles decoded for web images", {},
                           [this] { return double(decoded_.stats().bytes); });
    reads_ = &metrics.counter("tessera_store_reads_total", "File reads issued, after coalescing adjacent tiles");
    tiles_read_ = &metrics.counter("tessera_store_tiles_read_total", "Tiles returned by file reads");
    read_bytes_ = &metrics.counter("tessera_store_read_bytes_total", "Bytes read from store files, gaps included");
    cache_hits_ = &metrics.counter("tessera_cache_hits_total", "Tile lookups served from the RAM cache");
    cache_misses_ = &metrics.counter("tessera_cache_misses_total", "Tile lookups that went to the store file");
    reads_saved_ = &metrics.counter("tessera_store_reads_saved_total",
                                    "Cache misses answered by a read of the same tile already in flight for another request");
    metrics.gauge_callback("tessera_cache_bytes", "Bytes held by the RAM tile cache", {},
                           [this] { return double(cache_.stats().bytes); });
    metrics.gauge_callback("tessera_cache_budget_bytes", "Byte budget of the RAM tile cache", {},
                           [this] { return double(cache_.stats().budget); });
    metrics.gauge_callback("tessera_cache_hit_ratio", "Hits / lookups of the RAM tile cache since start", {}, [this] {
        const double h = double(cache_hits_->value()), m = double(cache_misses_->value());
        return h + m > 0 ? h / (h + m) : 0.0;
    });
}

TileFetcher::~TileFetcher() {
    for (const char* name : {"tessera_cache_bytes", "tessera_cache_budget_bytes", "tessera_cache_hit_ratio", "tessera_web_decoded_bytes"})
        metrics_.remove_callbacks(name);
}

namespace {

FetchedTile error_tile(TileStatus status, std::string message) {
    FetchedTile f;
    f.status = status;
    f.message = std::move(message);
    return f;
}

std::string key_text(const StoreHandle& store, const TileKey& k) {
    char buf[96];
    std::snprintf(buf, sizeof buf, "/%u/%u/%u", k.level, k.x, k.y);
    return store.name + buf;
}

FetchedTile stale_tile(const StoreHandle& store) {
    return error_tile(TileStatus::unavailable, "store " + store.name + " changed on disk and is being reopened; retry");
}

}  // namespace

struct TileFetcher::Flight {
    std::mutex m;
    std::condition_variable cv;
    bool done = false;
    FetchedTile result;
};

std::size_t TileFetcher::CacheKeyHash::operator()(const CacheKey& k) const noexcept {
    std::uint64_t h = k.store_version ^ (std::uint64_t(k.tile.level) << 58) ^ (std::uint64_t(k.tile.x) << 29) ^ k.tile.y;
    h ^= h >> 33;  // splitmix64's finaliser: neighbouring tiles land far apart
    h *= 0xff51afd7ed558ccdULL;
    h ^= h >> 33;
    h *= 0xc4ceb9fe1a85ec53ULL;
    return static_cast<std::size_t>(h ^ (h >> 33));
}

namespace {
// The decoded cache's key: the store's version and the view (a layer) folded together, so a
// replaced store, or another layer of it, never finds these texels.
CacheKey decoded_key(const StoreHandle& store, const TileKey& key, std::uint32_t look) {
    return CacheKey{store.info().store_id ^ ((std::uint64_t(look) + 1) * 0x9E3779B97F4A7C15ULL), key};
}
}  // namespace

std::shared_ptr<const storage::Tile> TileFetcher::decoded(const StoreHandle& store, const TileKey& key, std::uint32_t look) {
    if (!decoded_budget_) return nullptr;
    auto t = decoded_.get(decoded_key(store, key, look));
    (t ? decoded_hits_ : decoded_misses_)->inc();
    return t;
}

void TileFetcher::keep_decoded(const StoreHandle& store, const TileKey& key, std::uint32_t look, std::vector<std::uint8_t> texels) {
    if (!decoded_budget_) return;
    auto t = std::make_shared<storage::Tile>();
    t->key = key;
    t->kind = TileKind::present;
    t->bytes = std::move(texels);
    decoded_.put(decoded_key(store, key, look), std::move(t));
}

void TileFetcher::fetch(const StoreHandle& store, std::span<const TileKey> keys,
                        std::vector<FetchedTile>& out) {
    if (store.stale.load(std::memory_order_relaxed)) {
        out.assign(keys.size(), stale_tile(store));
        return;
    }
    out.assign(keys.size(), FetchedTile{});
    std::vector<TileKey> misses;
    std::vector<std::size_t> miss_index;
    const auto& info = store.info();
    for (std::size_t i = 0; i < keys.size(); ++i) {
        const auto& k = keys[i];
        if (!info.contains(k)) {
            char buf[160];
            if (k.level >= info.level_count())
                std::snprintf(buf, sizeof buf, "level %u is out of range (the store has levels 0..%u)", k.level,
                              info.level_count() - 1);
            else
                std::snprintf(buf, sizeof buf, "tile (%u,%u) is out of range at level %u (%u x %u tiles)", k.x, k.y,
                              k.level, info.levels[k.level].tiles_x, info.levels[k.level].tiles_y);
            out[i] = error_tile(TileStatus::out_of_range, buf);
            continue;
        }
        if (auto hit = cache_.get(CacheKey{store.version, k})) {
            cache_hits_->inc();
            out[i].tile = std::move(hit);
            continue;
        }
        cache_misses_->inc();
        misses.push_back(k);
        miss_index.push_back(i);
    }
    if (misses.empty()) return;

    // Lead the reads nobody is doing; join the others.
    std::vector<TileKey> lead_keys;
    std::vector<std::size_t> lead_index;
    std::vector<std::shared_ptr<Flight>> led;
    std::vector<std::pair<std::size_t, std::shared_ptr<Flight>>> joined;
    {
        std::lock_guard lock(flights_mutex_);
        for (std::size_t j = 0; j < misses.size(); ++j) {
            auto [it, inserted] = flights_.try_emplace(CacheKey{store.version, misses[j]});
            if (!inserted) {
                joined.emplace_back(miss_index[j], it->second);
                continue;
            }
            // A read that finished between the cache lookup above and here has filled the cache
            // (a leader puts before it leaves the table): no second read.
            if (auto hit = cache_.get(CacheKey{store.version, misses[j]})) {
                flights_.erase(it);
                out[miss_index[j]].tile = std::move(hit);
                reads_saved_->inc();
                continue;
            }
            it->second = std::make_shared<Flight>();
            led.push_back(it->second);
            lead_keys.push_back(misses[j]);
            lead_index.push_back(miss_index[j]);
        }
    }
    // Answer every led flight and take it out of the table; on any exit, an exception included,
    // so that no joiner waits forever.
    bool published = false;
    auto publish = [&](bool read_done) noexcept {
        {
            std::lock_guard lock(flights_mutex_);
            for (const TileKey& k : lead_keys) flights_.erase(CacheKey{store.version, k});
        }
        for (std::size_t j = 0; j < led.size(); ++j) {
            {
                std::lock_guard lock(led[j]->m);
                // A copy that cannot be made (no memory) still answers: the joiner must not wait forever.
                try {
                    led[j]->result = read_done ? out[lead_index[j]] : error_tile(TileStatus::internal, "the tile read failed");
                } catch (...) {
                    led[j]->result.status = TileStatus::internal;
                }
                led[j]->done = true;
            }
            led[j]->cv.notify_all();
        }
        published = true;
    };
    struct OnExit {
        std::function<void()> fn;
        ~OnExit() { fn(); }
    } on_exit{[&] {
        if (!published) publish(false);
    }};
    if (!lead_keys.empty()) read_misses(store, lead_keys, lead_index, out);
    publish(true);
    // Then the reads other requests lead (each of ours is done, so no two fetches wait on each other).
    // A request with a deadline (storage::read_deadline) stops waiting at it: the read it joined
    // may be a slow origin's, and a waiter must not outlive its request.
    const auto deadline = storage::read_deadline();
    std::vector<std::size_t> again;  // joined a read that the leader's own deadline cut short
    for (auto& [i, flight] : joined) {
        std::unique_lock lock(flight->m);
        const auto done = [&f = *flight] { return f.done; };
        if (deadline == std::chrono::steady_clock::time_point::max()) {
            flight->cv.wait(lock, done);
        } else if (!flight->cv.wait_until(lock, deadline, done)) {
            out[i] = error_tile(TileStatus::deadline_exceeded, "the request's deadline passed waiting for a read in flight");
            continue;
        }
        if (flight->result.status == TileStatus::deadline_exceeded && std::chrono::steady_clock::now() < deadline) {
            again.push_back(i);
            continue;
        }
        out[i] = flight->result;
        reads_saved_->inc();
    }
    // Each try ends by this request's deadline, so this ends too.
    for (std::size_t i : again) out[i] = fetch_one(store, keys[i]);
}

void TileFetcher::read_misses(const StoreHandle& store, const std::vector<TileKey>& misses,
                              const std::vector<std::size_t>& miss_index, std::vector<FetchedTile>& out) {
    storage::BatchStats stats;
    auto results = store.reader->read_tiles(misses, &stats);
    reads_->inc(stats.reads);
    read_bytes_->inc(stats.bytes);
    tiles_read_->inc(misses.size());
    // A failure may be the file's fault: changed in place since it was opened. Then this version
    // is stale (every answer UNAVAILABLE until a rescan reopens the file), not data loss.
    if (std::any_of(results.begin(), results.end(), [](const auto& r) { return !r; }) && store.reader->file_changed()) {
        if (!store.stale.exchange(true))
            log_.error("store file changed in place; not serving it until it opens as a new version",
                       {{"store", store.name}, {"path", store.path}});
        for (std::size_t i : miss_index) out[i] = stale_tile(store);
        return;
    }
    for (std::size_t j = 0; j < results.size(); ++j) {
        auto& r = results[j];
        const std::size_t i = miss_index[j];
        if (!r) {
            const auto& e = r.error();
            if (e.code == Errc::corrupt) {
                store.metrics.data_loss->inc();
                log_.error("tile failed its checksum; not served",
                           {{"store", store.name}, {"tile", key_text(store, misses[j])}, {"error", e.message}});
                out[i] = error_tile(TileStatus::data_loss, "tile " + key_text(store, misses[j]) + " failed its checksum");
            } else if (e.code == Errc::out_of_range) {
                out[i] = error_tile(TileStatus::out_of_range, e.message);
            } else if (std::chrono::steady_clock::now() >= storage::read_deadline()) {
                // Cut short by the request's deadline (a slow origin), not a fault of the store;
                // requests that joined this read get the same answer.
                out[i] = error_tile(TileStatus::deadline_exceeded, "the read of tile " + key_text(store, misses[j]) +
                                                                       " did not finish before the request's deadline");
            } else if (store.remote()) {
                // The origin failed this read (an error answer after the retries, a dropped
                // connection, an object being replaced whose new version the probe has not seen
                // yet): the origin's fault, not ours, and likely to pass. UNAVAILABLE, so the
                // client retries (HTTP 503 with Retry-After), rather than INTERNAL (500).
                log_.warn("remote tile read failed", {{"store", store.name}, {"tile", key_text(store, misses[j])},
                                                      {"error", e.message}});
                out[i] = error_tile(TileStatus::unavailable, "the origin failed the read of tile " + key_text(store, misses[j]) +
                                                                 "; retry");
            } else {
                log_.error("tile read failed", {{"store", store.name}, {"tile", key_text(store, misses[j])},
                                                {"error", e.message}});
                out[i] = error_tile(TileStatus::internal, "reading tile " + key_text(store, misses[j]) + " failed");
            }
            continue;
        }
        auto tile = std::make_shared<const storage::Tile>(std::move(*r));
        cache_.put(CacheKey{store.version, misses[j]}, tile);
        out[i].tile = std::move(tile);
    }
}

FetchedTile TileFetcher::fetch_one(const StoreHandle& store, const TileKey& key) {
    std::vector<FetchedTile> out;
    fetch(store, std::span<const TileKey>(&key, 1), out);
    return std::move(out[0]);
}

std::shared_ptr<const storage::Tile> TileFetcher::cached(const StoreHandle& store, const TileKey& key) {
    if (store.stale.load(std::memory_order_relaxed) || !store.info().contains(key)) return nullptr;
    auto hit = cache_.get(CacheKey{store.version, key});
    if (hit) cache_hits_->inc();
    return hit;
}

}  // namespace tessera::server
