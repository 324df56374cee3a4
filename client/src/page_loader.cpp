#include "page_loader.hpp"

#include <algorithm>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <thread>

#include "tessera/storage/layers.hpp"

namespace tessera::client {

// Looks up tiles in the disk cache off the render thread. Owner: the loader. Queues: lookups
// (bounded by the loader's in-flight bound) and results (drained every frame).
class DiskLoader {
public:
    explicit DiskLoader(DiskTileCache& cache) : cache_(cache), thread_([this] { run(); }) {}
    ~DiskLoader() {
        {
            std::lock_guard lock(mu_);
            stop_ = true;
        }
        cv_.notify_all();
        thread_.join();
    }
    void lookup(const PageKey& page, TileId id) {
        std::lock_guard lock(mu_);
        queue_.emplace_back(page, std::move(id));
        cv_.notify_one();
    }
    // Lookups no longer wanted are skipped.
    void retain_only(const std::function<bool(const PageKey&)>& wanted) {
        std::lock_guard lock(mu_);
        std::erase_if(queue_, [&](const auto& q) { return !wanted(q.first); });
    }
    struct Found {
        PageKey page;
        std::shared_ptr<const TileData> tile;  // null: miss
    };
    // Calls f(Found&) for every finished lookup, outside the lock. The two lists trade places,
    // so neither allocates once both have grown to a frame's worth.
    template <class F>
    void drain(F&& f) {
        {
            std::lock_guard lock(mu_);
            taken_.swap(done_);
        }
        for (auto& found : taken_) f(found);
        taken_.clear();
    }

private:
    void run() {
        for (;;) {
            std::pair<PageKey, TileId> job;
            {
                std::unique_lock lock(mu_);
                cv_.wait(lock, [&] { return stop_ || !queue_.empty(); });
                if (stop_) return;
                job = std::move(queue_.front());
                queue_.pop_front();
            }
            auto got = cache_.get(job.second);
            Found f{job.first, nullptr};
            if (got && *got) f.tile = std::make_shared<const TileData>(std::move(**got));
            std::lock_guard lock(mu_);
            done_.push_back(std::move(f));
        }
    }
    DiskTileCache& cache_;
    std::mutex mu_;
    std::condition_variable cv_;
    bool stop_ = false;
    std::deque<std::pair<PageKey, TileId>> queue_;
    std::vector<Found> done_;
    std::vector<Found> taken_;  // render thread only
    std::thread thread_;
};

PageLoader::PageLoader(const RuntimeConfig& config, PagePoolFormat pool, PageStaging* lender)
    : config_(config),
      pool_format_(std::move(pool)),
      lender_(lender),
      ram_(config.ram_cache_bytes),
      uploads_(config.upload_pages_per_frame, config.upload_bytes_per_frame, kStagingBuffers) {
    if (config.transcode_threads > 0) {
        TranscodePoolOptions o;
        o.threads = config.transcode_threads;
        o.capacity = kStagingBuffers;
        pool_ = std::make_unique<TranscodePool>(o);
    }
}

PageLoader::~PageLoader() {
    if (pool_) pool_->shutdown();  // no transcode thread writes into staging memory after this
    disk_loader_.reset();
    for (auto& s : staging_)
        if (s.lent) lender_->release(*s.lent);
}

Status PageLoader::open_disk_cache() {
    if (config_.disk_cache_dir.empty()) return Status();
    auto d = DiskTileCache::open(config_.disk_cache_dir, config_.disk_cache_bytes);
    if (!d) return d.error();
    disk_ = std::move(*d);
    disk_loader_ = std::make_unique<DiskLoader>(*disk_);
    return Status();
}

Result<storage::StoreInfo> PageLoader::bind(TextureId id, TileSource& source, const std::string& store,
                                            const PagePoolFormat& pool) {
    auto info = source.bind(id, store);
    if (!info) return info.error();
    if (info->levels.empty()) return Error{Errc::invalid_argument, "store " + store + " has no levels"};
    // Every page is transcoded to the pool's format: a store that cannot take it is refused
    // here, with the reason, rather than failing page by page.
    if (Status st = check_pool_format(*info, pool); !st)
        return Error{st.error().code, "store " + store + ": " + st.error().message};
    return info;
}

void PageLoader::add_texture(TileSource& source, const std::string& store, const storage::StoreInfo& info) {
    Texture t;
    t.source = &source;
    t.store = store;
    t.info = std::make_shared<const storage::StoreInfo>(info);
    t.disk_cached = disk_ && DiskTileCache::valid_store_name(store);
    textures_.push_back(std::move(t));
    if (std::find(sources_.begin(), sources_.end(), &source) == sources_.end()) sources_.push_back(&source);
    if (textures_.back().disk_cached) disk_->drop_other_versions(store, info.store_id);
    page_bytes_ = std::max(page_bytes_, pool_format_.upload_bytes(info.tile_size()));
}

void PageLoader::remember_absent(const PageKey& page) {
    if (absent_.size() >= kMaxAbsentPages) absent_.clear();
    absent_.insert(page);
}

TileId PageLoader::tile_id(const PageKey& p) const {
    const auto& t = textures_[p.texture];
    return TileId{t.store, t.info->store_id, p.tile()};
}

namespace {

// A layer bundle with an absent part: no page can be made of it (a page is never resident in some
// layers only), so the page stands absent and its parent is shown, like an absent tile.
bool has_absent_layer(const storage::StoreInfo& info, const TileData& tile) {
    if (!info.layered() || tile.kind != TileKind::present || tile.codec != Codec::layers) return false;
    auto parts = storage::split_layers(info, tile.payload);
    if (!parts) return false;  // a malformed bundle fails its decode: FrameStats::decode_failures
    return std::any_of(parts->begin(), parts->end(), [](const storage::LayerPart& p) { return p.kind == TileKind::absent; });
}

}  // namespace

void PageLoader::arrived(const PageKey& page, Work& w, std::shared_ptr<const TileData> tile, FrameStats& stats) {
    ++stats.pages_arrived;
    // A sparse store: nothing to fetch, ever.
    if (tile->kind == TileKind::absent || has_absent_layer(*textures_[page.texture].info, *tile)) {
        work_.erase(page);
        remember_absent(page);
        return;
    }
    w.stage = Stage::arrived;
    w.tile = std::move(tile);
}

void PageLoader::request_and_decode(std::uint64_t frame, const WantedPages& wanted, Clock::time_point now, FrameStats& stats) {
    frame_ = frame;
    issue_requests(wanted, now, stats);
    send_request_sets(frame);
    decode(wanted, stats);
}

void PageLoader::collect_arrivals(FrameStats& stats, const std::function<bool(const PageKey&)>& resident) {
    if (disk_loader_) {
        disk_loader_->drain([&](DiskLoader::Found& f) {
            auto it = work_.find(f.page);
            if (it == work_.end() || it->second.stage != Stage::disk) return;
            if (f.tile) {
                ++stats.disk_hits[f.page.level];
                ram_.put(tile_id(f.page), f.tile);
                arrived(f.page, it->second, std::move(f.tile), stats);
            } else {
                it->second.stage = Stage::source;  // miss: ask the source
            }
        });
    }
    for (auto* source : sources_) {
        received_.clear();
        source->poll(received_, 4096);
        for (auto& r : received_) {
            auto it = work_.find(r.page);
            if (it == work_.end() || it->second.stage != Stage::source) {  // stale
                // Withdrawn (I/O the cancellation came too late to save), or a second
                // delivery of a page already arrived, resident or known absent.
                if (r.status == TileStatus::ok) {
                    if (it == work_.end() && !resident(r.page) && !absent_.contains(r.page))
                        ++stats.stale_arrivals;
                    else ++stats.duplicate_arrivals;
                }
                continue;
            }
            if (r.status != TileStatus::ok) {
                if (stats.source_errors++ == 0)
                    stats.first_source_error = "level " + std::to_string(r.page.level) + " (" + std::to_string(r.page.x) + ", " +
                                               std::to_string(r.page.y) + "): " + std::string(to_string(r.status)) +
                                               (r.message.empty() ? "" : " " + r.message);
                // The source has dropped the request. Asked again, if still wanted, after
                // kErrorRetryFrames: an overloaded server ("retry later") or a tile it cannot read
                // is not asked on every frame. Leaving the set now and rejoining it then, the page
                // changes the set both times, so each change is sent.
                work_.erase(it);
                if (retry_at_.size() >= kMaxAbsentPages) retry_at_.clear();
                retry_at_[r.page] = frame_ + kErrorRetryFrames;
                continue;
            }
            if (r.page.texture >= textures_.size()) {
                work_.erase(it);
                continue;
            }
            Texture& t = textures_[r.page.texture];
            if (r.store_version != t.info->store_id) {
                // Another version of the store (rebuilt and reloaded on the server): never mixed
                // in, and asked for again only now and then (kReplacedRetryFrames).
                ++stats.other_version_arrivals;
                t.replaced_by = r.store_version;
                work_.erase(it);
                continue;
            }
            t.replaced_by = 0;  // the bound version is served (a replica, a rollback)
            ++stats.network[r.page.level];
            stats.bytes_received += r.data.payload.size();
            std::shared_ptr<const TileData> shared = std::make_shared<TileData>(std::move(r.data));
            const TileId id = tile_id(r.page);
            ram_.put(id, shared);
            if (t.disk_cached) disk_->put(id, shared);
            arrived(r.page, it->second, std::move(shared), stats);
        }
    }
}

void PageLoader::cancel_unwanted(const WantedPages& wanted, FrameStats& stats) {
    for (auto it = work_.begin(); it != work_.end();) {
        if (const auto w = wanted.find(it->first); w != wanted.end()) {
            it->second.priority = w->second;
            ++it;
            continue;
        }
        switch (it->second.stage) {
            case Stage::decoding: ++it; continue;  // the pool drops or finishes it
            case Stage::disk:
            case Stage::source: ++stats.cancelled_waiting; break;
            case Stage::arrived: ++stats.cancelled_arrived; break;
            case Stage::ready: ++stats.cancelled_decoded; break;
        }
        free_staging(it->second);
        it = work_.erase(it);
    }
    const auto is_wanted = [&](const PageKey& k) { return wanted.contains(k); };
    if (pool_) pool_->retain_only(is_wanted);
    if (disk_loader_) disk_loader_->retain_only(is_wanted);
    uploads_.drop_if([this](const ReadyPage& p) {
        const auto it = work_.find(p.key);
        return it == work_.end() || it->second.ticket != p.ticket;
    });
}

void PageLoader::issue_requests(const WantedPages& wanted, Clock::time_point now, FrameStats& stats) {
    // Highest priority first, within the in-flight bound.
    order_.clear();
    for (const auto& [k, p] : wanted)
        if (!work_.contains(k) && !absent_.contains(k) && k.texture < textures_.size()) order_.emplace_back(p, k);
    std::sort(order_.begin(), order_.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
    for (const auto& [priority, key] : order_) {
        if (work_.size() >= config_.max_requests_in_flight) break;
        // A replaced store's missing pages are asked for only now and then (kReplacedRetryFrames);
        // those its RAM cache still holds (the bound version's) are at hand meanwhile.
        bool held_back = textures_[key.texture].replaced_by != 0 && frame_ % kReplacedRetryFrames != 0;
        if (const auto retry = retry_at_.find(key); retry != retry_at_.end()) {
            if (frame_ < retry->second) held_back = true;
            else retry_at_.erase(retry);
        }
        const TileId id = tile_id(key);
        auto hit = ram_.get(id);
        if (held_back && !hit) continue;
        Work w;
        w.priority = priority;
        w.requested = now;
        w.ticket = next_ticket_++;
        ++stats.pages_requested;
        if (hit) {
            ++stats.ram_hits[key.level];
            auto& slot = work_[key] = w;
            arrived(key, slot, std::move(hit), stats);
            continue;
        }
        const bool disk = disk_loader_ && textures_[key.texture].disk_cached;
        w.stage = disk ? Stage::disk : Stage::source;
        work_[key] = w;
        if (disk) disk_loader_->lookup(key, id);
    }
}

void PageLoader::send_request_sets(std::uint64_t frame) {
    for (auto* source : sources_) {
        requests_.clear();
        for (const auto& [k, w] : work_)
            if (w.stage == Stage::source && textures_[k.texture].source == source) requests_.push_back(SourceRequest{k, w.priority});
        std::sort(requests_.begin(), requests_.end(), [](const SourceRequest& a, const SourceRequest& b) {
            return a.priority > b.priority || (a.priority == b.priority && page_hash_key(a.page) < page_hash_key(b.page));
        });
        auto& last = last_sent_[source];
        const bool same = last.size() == requests_.size() &&
                          std::equal(last.begin(), last.end(), requests_.begin(), [](const auto& a, const auto& b) {
                              return a.page == b.page && a.priority == b.priority;
                          });
        // An unchanged set is sent again now and then: a source that reconnected or dropped a
        // request gets it back.
        if (same && frame % 30 != 0) continue;
        source->set_requests(frame, requests_);
        last = requests_;
    }
}

int PageLoader::take_staging() {
    if (staging_.empty()) {
        staging_.resize(kStagingBuffers);
        for (int i = kStagingBuffers - 1; i >= 0; --i) free_staging_.push_back(i);
    }
    if (free_staging_.empty()) return -1;
    const int i = free_staging_.back();
    free_staging_.pop_back();
    Staging& s = staging_[static_cast<std::size_t>(i)];
    if (lender_) {
        if (const StagingBuffer b = lender_->acquire(page_bytes_); b.bytes.size() >= page_bytes_) {
            s.lent = b.id;
            s.bytes = b.bytes;
            return i;
        }
    }
    if (s.own.size() < page_bytes_) s.own.resize(page_bytes_);
    s.bytes = s.own;
    return i;
}

void PageLoader::free_staging(Work& w) {
    if (w.staging < 0) return;
    Staging& s = staging_[static_cast<std::size_t>(w.staging)];
    if (s.lent) lender_->release(*s.lent);
    s.lent.reset();
    s.bytes = {};
    free_staging_.push_back(w.staging);
    w.staging = -1;
}

void PageLoader::decode(const WantedPages& wanted, FrameStats& stats) {
    order_.clear();
    for (const auto& [k, w] : work_)
        if (w.stage == Stage::arrived) order_.emplace_back(w.priority, k);
    std::sort(order_.begin(), order_.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
    for (const auto& [priority, key] : order_) {
        auto& w = work_.at(key);
        const int s = take_staging();
        if (s < 0) break;
        const auto& info = textures_[key.texture].info;
        const std::span<std::uint8_t> dst = staging_[static_cast<std::size_t>(s)].bytes.first(pool_format_.upload_bytes(info->tile_size()));
        w.staging = s;
        if (!pool_) {
            const auto st = transcode_pool_page(*info, w.tile->kind, w.tile->codec, w.tile->payload, pool_format_, dst, scratch_);
            finish_decode(key, st.ok(), wanted, stats);
            continue;
        }
        TranscodeJob job;
        job.key = key;
        job.ticket = w.ticket;
        job.info = info;
        job.kind = w.tile->kind;
        job.codec = w.tile->codec;
        job.pool = pool_format_;
        job.payload = std::shared_ptr<const std::vector<std::uint8_t>>(w.tile, &w.tile->payload);
        job.destination = dst;
        job.priority = static_cast<std::uint32_t>(std::max(0.0f, priority));
        if (!pool_->submit(std::move(job))) {
            free_staging(w);
            break;
        }
        w.stage = Stage::decoding;
    }
    if (!pool_) return;
    results_.clear();
    pool_->poll(results_);
    for (const auto& r : results_) {
        auto it = work_.find(r.key);
        if (it == work_.end() || it->second.ticket != r.ticket) continue;
        if (r.dropped) {  // no longer wanted when its turn came
            ++stats.decodes_dropped;
            free_staging(it->second);
            work_.erase(it);
            continue;
        }
        finish_decode(r.key, r.status.ok(), wanted, stats);
    }
}

void PageLoader::finish_decode(const PageKey& key, bool ok, const WantedPages& wanted, FrameStats& stats) {
    auto& w = work_.at(key);
    if (!ok) {
        // The payload is what the store holds (the source checked it): asking again brings the
        // same bytes. The page stands absent, its parent shown, like a tile the store lacks.
        ++stats.decode_failures;
        free_staging(w);
        work_.erase(key);
        remember_absent(key);
        return;
    }
    if (!wanted.contains(key)) {
        ++stats.cancelled_decoded;  // decoded, then found unwanted
        free_staging(w);
        work_.erase(key);
        return;
    }
    const auto& info = textures_[key.texture].info;
    ReadyPage p;
    p.key = key;
    p.priority = w.priority;
    p.ticket = w.ticket;
    p.data = staging_[static_cast<std::size_t>(w.staging)].bytes.first(pool_format_.upload_bytes(info->tile_size()));
    p.bytes = static_cast<std::uint32_t>(p.data.size());
    p.requested = w.requested;
    w.stage = Stage::ready;
    w.tile.reset();
    if (!uploads_.push(std::move(p))) {
        free_staging(w);
        work_.erase(key);
    }
}

void PageLoader::take_frame(std::vector<Loaded>& out) {
    ready_.clear();
    uploads_.take_frame(ready_);
    for (const ReadyPage& p : ready_) {
        const auto it = work_.find(p.key);
        if (it == work_.end() || it->second.ticket != p.ticket) continue;  // dropped since
        out.push_back(Loaded{p.key, p.data, p.bytes, p.requested});
    }
}

void PageLoader::done(const PageKey& key) {
    const auto it = work_.find(key);
    if (it == work_.end()) return;
    free_staging(it->second);
    work_.erase(it);
}

}  // namespace tessera::client
