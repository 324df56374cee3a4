#include "tile_cache.hpp"

#include <absl/container/flat_hash_map.h>

#include <deque>
#include <iterator>
#include <list>
#include <mutex>
#include <unordered_map>
#include <utility>

namespace tessera::server {

namespace {

// Charged per entry besides the payload: list and map nodes, the Tile object, its control block.
// Without it, many tiny (uniform) tiles could hold far more memory than the budget says.
constexpr std::size_t kEntryOverhead = 128;
// The small (probationary) queue's share of a shard's budget, in percent: the paper's 10%.
constexpr std::size_t kSmallPercent = 10;
// Frequency is a 2-bit saturating counter: a hot entry survives at most three main-queue passes
// without a new hit.
constexpr std::uint8_t kMaxFreq = 3;

// splitmix64's finaliser: a bijection with full avalanche.
std::uint64_t mix64(std::uint64_t z) {
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

// Chains the fields through the mixer so that neighbouring tiles (x, y differ by one) and the same
// tile in two store versions land on unrelated hashes, hence on unrelated shards.
std::uint64_t hash_key(const CacheKey& k) {
    constexpr std::uint64_t kGolden = 0x9e3779b97f4a7c15ULL;
    std::uint64_t h = mix64(k.store_version + kGolden);
    h = mix64((h ^ ((std::uint64_t{k.tile.level} << 32) | k.tile.x)) + kGolden);
    return mix64((h ^ k.tile.y) + kGolden);
}

struct KeyHash {
    std::size_t operator()(const CacheKey& k) const noexcept { return static_cast<std::size_t>(hash_key(k)); }
};

// Takes the high bits: the map's buckets use the whole hash, so shards and buckets stay independent.
std::size_t shard_index(std::uint64_t hash, unsigned shard_count) {
    return static_cast<std::size_t>(((hash >> 32) * shard_count) >> 32);
}

// An entry's place in the queues. What a hit reads and writes (the tile, its frequency) lives
// in the index's slot instead, so that a hit touches one slot and not a list node elsewhere in
// memory as well.
struct Entry {
    CacheKey key;
    std::size_t charge = 0;
    bool in_main = false;
};

// Front = oldest. std::list so that moving an entry between queues (splice) keeps the index's
// iterators valid and costs no allocation.
using Queue = std::list<Entry>;

struct Slot {
    Queue::iterator entry;
    std::shared_ptr<const storage::Tile> tile;
    std::uint8_t freq = 0;  // hits since insertion or the last main-queue pass, saturating
};

// Keys recently evicted from the small queue, by hash only (no data). Bounded by the bytes the
// remembered tiles would occupy, so it covers about as many entries as the main queue holds.
class Ghost {
public:
    void set_capacity(std::size_t bytes) { capacity_ = bytes; }

    void add(std::uint64_t hash, std::size_t charge) {
        if (charge > capacity_) return;
        const std::uint64_t seq = next_seq_++;
        live_[hash] = seq;
        fifo_.push_back({hash, seq, charge});
        bytes_ += charge;
        while (bytes_ > capacity_) pop();
    }

    // True, and forgets the key, when it was remembered. Its record stays in the FIFO (removal
    // from the middle is costly) and is skipped when it ages out.
    bool take(std::uint64_t hash) { return live_.erase(hash) > 0; }

private:
    struct Record {
        std::uint64_t hash;
        std::uint64_t seq;
        std::size_t charge;
    };

    void pop() {
        const Record& r = fifo_.front();
        // Only the newest record of a hash owns its live_ entry.
        if (auto it = live_.find(r.hash); it != live_.end() && it->second == r.seq) live_.erase(it);
        bytes_ -= r.charge;
        fifo_.pop_front();
    }

    std::deque<Record> fifo_;
    std::unordered_map<std::uint64_t, std::uint64_t> live_;  // hash -> seq of its newest record
    std::size_t capacity_ = 0;
    std::size_t bytes_ = 0;  // charges of every record in fifo_, stale ones included
    std::uint64_t next_seq_ = 0;
};

}  // namespace

// Padded to a cache line so that neighbouring shards' mutexes do not share one.
struct alignas(64) TileCache::Shard {
    std::mutex mutex;
    // Written by every get, as the mutex is: on the mutex's cache line, so that a get from the
    // other core's loop moves one line here, not two.
    std::uint64_t hits = 0;
    std::uint64_t misses = 0;
    std::size_t budget = 0;
    std::size_t small_budget = 0;
    std::size_t main_budget = 0;
    Queue small;
    Queue main;
    std::size_t small_bytes = 0;
    std::size_t main_bytes = 0;
    absl::flat_hash_map<CacheKey, Slot, KeyHash> index;  // flat: one probe, no node per entry
    Ghost ghost;
    std::uint64_t insertions = 0;
    std::uint64_t evictions = 0;

    void set_budget(std::size_t bytes) {
        budget = bytes;
        small_budget = bytes * kSmallPercent / 100;
        main_budget = bytes - small_budget;
        ghost.set_capacity(main_budget);
    }

    std::size_t bytes() const { return small_bytes + main_bytes; }
    std::size_t& queue_bytes(const Entry& e) { return e.in_main ? main_bytes : small_bytes; }

    static_assert(sizeof(std::mutex) + 2 * sizeof(std::uint64_t) <= 64);

    std::shared_ptr<const storage::Tile> get(const CacheKey& key) {
        const auto it = index.find(key);
        if (it == index.end()) {
            ++misses;
            return {};
        }
        // A hit only bumps the counter: no queue movement, so hits stay cheap (lazy promotion).
        Slot& slot = it->second;
        if (slot.freq < kMaxFreq) ++slot.freq;
        ++hits;
        return slot.tile;
    }

    void put(const CacheKey& key, std::uint64_t hash, std::shared_ptr<const storage::Tile> tile,
             std::size_t charge) {
        const auto found = index.find(key);
        if (charge > budget) {  // also the disabled cache (budget 0)
            // A replacement that does not fit must not leave the old value to be served.
            if (found != index.end()) {
                drop(found->second.entry);
                ++evictions;
            }
            return;
        }
        if (found != index.end()) {
            Entry& e = *found->second.entry;
            std::size_t& held = queue_bytes(e);
            held = held - e.charge + charge;
            e.charge = charge;
            found->second.tile = std::move(tile);  // keeps its frequency: a put is not an access
            make_room(0);
            return;
        }
        make_room(charge);
        // A key evicted from small recently and asked for again has proven reuse: straight to main.
        const bool to_main = ghost.take(hash);
        Queue& q = to_main ? main : small;
        q.push_back(Entry{key, charge, to_main});
        queue_bytes(q.back()) += charge;
        index.emplace(key, Slot{std::prev(q.end()), std::move(tile), 0});
        ++insertions;
    }

    // Evicts until `need` more bytes fit. Small is evicted while it holds at least its share,
    // so a scan of one-hit tiles cycles through small and the ghost, never reaching main.
    void make_room(std::size_t need) {
        while (bytes() + need > budget) {
            if (!small.empty() && (small_bytes >= small_budget || main.empty())) evict_small();
            else evict_main();
        }
    }

    // Entries hit while in small move to main (their hits cleared: they paid for admission);
    // the first one not hit is evicted and remembered in the ghost.
    void evict_small() {
        while (!small.empty()) {
            const auto it = small.begin();
            std::uint8_t& freq = index.find(it->key)->second.freq;
            if (freq == 0) {
                ghost.add(hash_key(it->key), it->charge);
                drop(it);
                ++evictions;
                return;
            }
            freq = 0;
            small_bytes -= it->charge;
            main_bytes += it->charge;
            it->in_main = true;
            main.splice(main.end(), small, it);
            while (main_bytes > main_budget) evict_main();
        }
    }

    // FIFO with reinsertion: an entry hit since its last pass goes round again with one hit
    // spent; the first one without hits is evicted. Ends within kMaxFreq + 1 passes.
    void evict_main() {
        while (!main.empty()) {
            const auto it = main.begin();
            std::uint8_t& freq = index.find(it->key)->second.freq;
            if (freq == 0) {
                drop(it);
                ++evictions;
                return;
            }
            --freq;
            main.splice(main.end(), main, it);
        }
    }

    void drop(Queue::iterator it) {
        queue_bytes(*it) -= it->charge;
        index.erase(it->key);
        (it->in_main ? main : small).erase(it);
    }
};

TileCache::TileCache(std::size_t byte_budget, unsigned shards)
    : shard_count_(shards == 0 ? 1 : shards), budget_(byte_budget) {
    shards_ = std::make_unique<Shard[]>(shard_count_);
    // The remainder goes to the first shards, so the shard budgets add up to exactly the budget.
    const std::size_t base = budget_ / shard_count_;
    const std::size_t extra = budget_ % shard_count_;
    for (unsigned i = 0; i < shard_count_; ++i) shards_[i].set_budget(base + (i < extra ? 1 : 0));
}

TileCache::~TileCache() = default;

std::shared_ptr<const storage::Tile> TileCache::get(const CacheKey& key) {
    Shard& shard = shards_[shard_index(hash_key(key), shard_count_)];
    std::lock_guard lock(shard.mutex);
    return shard.get(key);
}

void TileCache::put(const CacheKey& key, std::shared_ptr<const storage::Tile> tile) {
    if (!tile) return;
    const std::size_t bytes = charge(*tile);
    const std::uint64_t hash = hash_key(key);
    Shard& shard = shards_[shard_index(hash, shard_count_)];
    std::lock_guard lock(shard.mutex);
    shard.put(key, hash, std::move(tile), bytes);
}

CacheStats TileCache::stats() const {
    CacheStats s;
    for (unsigned i = 0; i < shard_count_; ++i) {
        Shard& shard = shards_[i];
        std::lock_guard lock(shard.mutex);
        s.hits += shard.hits;
        s.misses += shard.misses;
        s.insertions += shard.insertions;
        s.evictions += shard.evictions;
        s.bytes += shard.bytes();
        s.entries += shard.index.size();
        s.budget += shard.budget;
    }
    return s;
}

std::size_t TileCache::charge(const storage::Tile& tile) { return tile.bytes.size() + kEntryOverhead; }

}  // namespace tessera::server
