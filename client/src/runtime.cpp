#include "tessera/client/runtime.hpp"

#include <algorithm>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <optional>
#include <thread>
#include <unordered_map>
#include <unordered_set>

#include "disk_cache.hpp"
#include "feedback_analysis.hpp"
#include "ram_cache.hpp"
#include "residency.hpp"
#include "transcode.hpp"

namespace tessera::client {

namespace {

using Clock = std::chrono::steady_clock;

// Looks up tiles in the disk cache off the render thread. Owner: the runtime. Queues: lookups
// (bounded by the runtime's in-flight bound) and results (drained every frame).
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
    void poll(std::vector<Found>& out) {
        std::lock_guard lock(mu_);
        for (auto& f : done_) out.push_back(std::move(f));
        done_.clear();
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
    std::thread thread_;
};

class ResidencyAdapter final : public ResidencyView {
public:
    explicit ResidencyAdapter(const Residency& r) : r_(r) {}
    std::uint8_t resident_level(const PageKey& page) const override { return r_.resident_level(page); }

private:
    const Residency& r_;
};

class RuntimeImpl final : public Runtime {
public:
    RuntimeImpl(const RuntimeConfig& config, PageUploader& uploader, Residency residency)
        : config_(config),
          pool_format_(uploader.pool_format()),
          uploader_(uploader),
          residency_(std::move(residency)),
          view_(residency_),
          analyzer_(config.max_feedback_pages),
          ram_(config.ram_cache_bytes),
          uploads_(config.upload_pages_per_frame, config.upload_bytes_per_frame, kStagingBuffers),
          bias_(config.bias) {
        if (config.transcode_threads > 0) {
            TranscodePoolOptions o;
            o.threads = config.transcode_threads;
            o.capacity = kStagingBuffers;
            pool_ = std::make_unique<TranscodePool>(o);
        }
    }
    ~RuntimeImpl() override {
        if (pool_) pool_->shutdown();
        loader_.reset();
    }

    Status open_disk_cache() {
        if (config_.disk_cache_dir.empty()) return Status();
        auto d = DiskTileCache::open(config_.disk_cache_dir, config_.disk_cache_bytes);
        if (!d) return d.error();
        disk_ = std::move(*d);
        loader_ = std::make_unique<DiskLoader>(*disk_);
        return Status();
    }

    Result<TextureId> add_texture(TileSource& source, const std::string& store) override {
        if (textures_.size() >= 0xFFFF) return Error{Errc::resource_exhausted, "too many textures"};
        const auto id = static_cast<TextureId>(textures_.size());
        auto info = source.bind(id, store);
        if (!info) return info.error();
        if (info->levels.empty()) return Error{Errc::invalid_argument, "store " + store + " has no levels"};
        // Every page is transcoded to the pool's format: a store that cannot take it is refused
        // here, with the reason, rather than failing page by page.
        if (Status st = check_pool_format(*info, pool_format_); !st)
            return Error{st.error().code, "store " + store + ": " + st.error().message};
        const auto& l0 = info->levels[0];
        TESSERA_TRY(residency_.add_texture(id, l0.tiles_x, l0.tiles_y, info->level_count()));
        analyzer_.set_texture_levels(id, static_cast<std::uint8_t>(info->level_count()));
        analyzer_.set_texture_extent(id, l0.tiles_x, l0.tiles_y);
        Texture t;
        t.source = &source;
        t.store = store;
        t.info = std::make_shared<const storage::StoreInfo>(*info);
        textures_.push_back(std::move(t));
        if (disk_) disk_->drop_other_versions(store, info->store_id);
        page_bytes_ = std::max(page_bytes_, upload_bytes(*info));
        return id;
    }

    const storage::StoreInfo* texture_info(TextureId texture) const override {
        return texture < textures_.size() ? textures_[texture].info.get() : nullptr;
    }

    const FrameStats& frame(std::span<const FeedbackId> feedback, std::uint32_t width, std::uint32_t height,
                            float feedback_bias) override {
        const auto now = Clock::now();
        ++frame_no_;
        stats_ = FrameStats{};
        stats_.frame = frame_no_;
        (void)residency_.begin_frame(frame_no_);

        // What the view wants, by priority; resident pages are touched.
        const auto wanted = analyzer_.analyse(feedback, width, height, view_);
        desired_.clear();
        float rank = static_cast<float>(wanted.size());
        std::uint64_t fallback_pixels = 0, pixels = 0;
        for (const auto& w : wanted) {
            pixels += w.pixels;
            if (residency_.is_resident(w.key)) {
                residency_.touch(w.key);
            } else {
                fallback_pixels += w.pixels;
                if (!absent_.contains(w.key) && w.key.texture < textures_.size()) desired_.emplace(w.key, rank);
            }
            rank -= 1;
        }
        keep_recently_wanted();
        stats_.pages_wanted = static_cast<std::uint32_t>(wanted.size());
        stats_.fallback_estimate = pixels ? float(double(fallback_pixels) / double(pixels)) : 0.0f;

        collect_arrivals(now);
        cancel_unwanted();
        issue_requests(now);
        send_request_sets();
        decode();
        upload(now);
        upload_page_tables();

        const auto rs = residency_.stats();
        stats_.pages_resident = rs.resident_pages;
        LodBiasInputs in;
        in.pages_wanted = stats_.pages_wanted;
        in.pool_slots = rs.pool_slots > rs.pinned_pages ? rs.pool_slots - rs.pinned_pages : 0;
        in.pending = static_cast<std::uint32_t>(work_.size());
        in.delivered_last_frame = stats_.pages_uploaded;
        in.evicted_last_frame = stats_.pages_evicted;
        in.evicted_wanted_last_frame = evicted_wanted_;
        in.feedback_bias = feedback_bias;
        stats_.lod_bias = bias_.update(in);
        summary_.add_frame(stats_);
        return stats_;
    }

    const FrameStats& frame_without_feedback() override {
        const auto now = Clock::now();
        ++frame_no_;
        const std::uint32_t wanted = stats_.pages_wanted;
        const float fallback = stats_.fallback_estimate;
        stats_ = FrameStats{};
        stats_.frame = frame_no_;
        stats_.pages_wanted = wanted;
        stats_.fallback_estimate = fallback;
        collect_arrivals(now);
        issue_requests(now);
        send_request_sets();
        decode();
        upload(now);
        upload_page_tables();
        stats_.pages_resident = residency_.stats().resident_pages;
        stats_.lod_bias = bias_.bias();
        summary_.add_frame(stats_);
        return stats_;
    }

    float lod_bias() const override { return bias_.bias(); }
    const Residency& residency() const override { return residency_; }
    const StatsSummary& summary() const override { return summary_; }
    std::size_t in_flight() const override { return work_.size(); }

private:
    static constexpr std::size_t kStagingBuffers = 64;  // decoded pages waiting for upload, at most

    struct Texture {
        TileSource* source = nullptr;
        std::string store;
        std::shared_ptr<const storage::StoreInfo> info;
    };
    enum class Stage { disk, source, arrived, decoding, ready };
    struct Work {
        Stage stage = Stage::source;
        float priority = 0;
        Clock::time_point requested{};
        std::uint64_t ticket = 0;
        std::shared_ptr<const TileData> tile;  // arrived and later
        int staging = -1;                        // decoding, ready
    };

    TileId tile_id(const PageKey& p) const {
        const auto& t = textures_[p.texture];
        return TileId{t.store, t.info->store_id, p.tile()};
    }

    void arrived(const PageKey& page, Work& w, std::shared_ptr<const TileData> tile) {
        ++stats_.pages_arrived;
        if (tile->kind == TileKind::absent) {  // a sparse store: nothing to fetch, ever
            absent_.insert(page);
            work_.erase(page);
            return;
        }
        w.stage = Stage::arrived;
        w.tile = std::move(tile);
    }

    void collect_arrivals(Clock::time_point) {
        if (loader_) {
            found_.clear();
            loader_->poll(found_);
            for (auto& f : found_) {
                auto it = work_.find(f.page);
                if (it == work_.end() || it->second.stage != Stage::disk) continue;
                if (f.tile) {
                    ++stats_.disk_hits[f.page.level];
                    ram_.put(tile_id(f.page), f.tile);
                    arrived(f.page, it->second, std::move(f.tile));
                } else {
                    it->second.stage = Stage::source;  // miss: ask the source
                }
            }
        }
        for (auto* source : sources()) {
            received_.clear();
            source->poll(received_, 4096);
            for (auto& r : received_) {
                auto it = work_.find(r.page);
                if (it == work_.end() || it->second.stage != Stage::source) {  // stale
                    // Withdrawn (I/O the cancellation came too late to save), or a second
                    // delivery of a page already arrived, resident or known absent.
                    if (r.status == TileStatus::ok) {
                        if (it == work_.end() && !residency_.is_resident(r.page) && !absent_.contains(r.page))
                            ++stats_.stale_arrivals;
                        else ++stats_.duplicate_arrivals;
                    }
                    continue;
                }
                if (r.status != TileStatus::ok) {
                    work_.erase(it);  // asked again next frame if still wanted
                    continue;
                }
                if (r.page.texture >= textures_.size() || r.store_version != textures_[r.page.texture].info->store_id) {
                    work_.erase(it);  // another version of the store: never mixed in
                    continue;
                }
                ++stats_.network[r.page.level];
                stats_.bytes_received += r.data.payload.size();
                std::shared_ptr<const TileData> shared = std::make_shared<TileData>(std::move(r.data));
                const TileId id = tile_id(r.page);
                ram_.put(id, shared);
                if (disk_) disk_->put(id, shared);
                arrived(r.page, it->second, std::move(shared));
            }
        }
    }

    // Pages the feedback saw lately but not in this frame stay wanted for a grace window of
    // frames: jittered feedback sees a small page only in some frames, and cancelling its request
    // at the first frame without it would cancel it again and again before it arrives. Carried
    // pages rank below every page of this frame's feedback, the longest unseen last.
    void keep_recently_wanted() {
        for (const auto& [key, rank] : desired_) {
            auto [seen, fresh] = last_seen_.try_emplace(key, Seen{frame_no_, frame_no_});
            if (!fresh) seen->second.last = frame_no_;
        }
        // Bounded like the feedback itself: past that many pages, only this frame's are kept.
        const bool over_bound = last_seen_.size() > config_.max_feedback_pages;
        for (auto it = last_seen_.begin(); it != last_seen_.end();) {
            const std::uint64_t unseen = frame_no_ - it->second.last;
            if (unseen == 0) {
                ++it;
                continue;
            }
            if (over_bound || unseen > config_.keep_unwanted_frames || residency_.is_resident(it->first) ||
                absent_.contains(it->first)) {
                it = last_seen_.erase(it);
                continue;
            }
            desired_.emplace(it->first, -static_cast<float>(unseen));
            ++it;
        }
    }

    void cancel_unwanted() {
        // Requests nobody wants any more are dropped at every stage.
        for (auto it = work_.begin(); it != work_.end();) {
            if (desired_.contains(it->first)) {
                it->second.priority = desired_.at(it->first);
                ++it;
                continue;
            }
            if (it->second.stage == Stage::decoding) {  // the pool drops or finishes it
                ++it;
                continue;
            }
            switch (it->second.stage) {
                case Stage::disk:
                case Stage::source: ++stats_.cancelled_waiting; break;
                case Stage::arrived: ++stats_.cancelled_arrived; break;
                case Stage::ready: ++stats_.cancelled_decoded; break;
                case Stage::decoding: break;
            }
            if (it->second.staging >= 0) free_staging_.push_back(it->second.staging);
            it = work_.erase(it);
        }
        if (pool_) pool_->retain_only([this](const PageKey& k) { return desired_.contains(k); });
        if (loader_) loader_->retain_only([this](const PageKey& k) { return desired_.contains(k); });
        uploads_.drop_if([this](const ReadyPage& p) { return !work_.contains(key_of_ticket(p.ticket)); });
    }

    void issue_requests(Clock::time_point now) {
        // Highest priority first, within the in-flight bound.
        order_.clear();
        for (const auto& [k, p] : desired_)
            if (!work_.contains(k)) order_.emplace_back(p, k);
        std::sort(order_.begin(), order_.end(), [](const auto& a, const auto& b) {
            return a.first > b.first;
        });
        for (const auto& [priority, key] : order_) {
            if (work_.size() >= config_.max_requests_in_flight) break;
            Work w;
            w.priority = priority;
            w.requested = now;
            w.ticket = next_ticket_++;
            tickets_[w.ticket] = key;
            ++stats_.pages_requested;
            const TileId id = tile_id(key);
            if (auto hit = ram_.get(id)) {
                ++stats_.ram_hits[key.level];
                auto& slot = work_[key] = w;
                arrived(key, slot, std::move(hit));
                continue;
            }
            w.stage = loader_ ? Stage::disk : Stage::source;
            work_[key] = w;
            if (loader_) loader_->lookup(key, id);
        }
    }

    std::vector<TileSource*> sources() const {
        std::vector<TileSource*> out;
        for (const auto& t : textures_)
            if (std::find(out.begin(), out.end(), t.source) == out.end()) out.push_back(t.source);
        return out;
    }

    void send_request_sets() {
        for (auto* source : sources()) {
            requests_.clear();
            for (const auto& [k, w] : work_)
                if (w.stage == Stage::source && textures_[k.texture].source == source)
                    requests_.push_back(SourceRequest{k, w.priority});
            std::sort(requests_.begin(), requests_.end(), [](const SourceRequest& a, const SourceRequest& b) {
                return a.priority > b.priority || (a.priority == b.priority && page_hash_key(a.page) < page_hash_key(b.page));
            });
            auto& last = last_sent_[source];
            const bool same = last.size() == requests_.size() &&
                              std::equal(last.begin(), last.end(), requests_.begin(), [](const auto& a, const auto& b) {
                                  return a.page == b.page && a.priority == b.priority;
                              });
            // An unchanged set is sent again now and then: a source that reconnected or dropped
            // a request gets it back.
            if (same && frame_no_ % 30 != 0) continue;
            source->set_requests(frame_no_, requests_);
            last = requests_;
        }
    }

    // Bytes of one upload of `info`'s pages in the pool's format.
    std::size_t upload_bytes(const storage::StoreInfo& info) const {
        return pool_format_.upload_bytes(info.tile_size());
    }

    int take_staging() {
        if (staging_.empty()) {
            staging_.resize(kStagingBuffers);
            for (int i = kStagingBuffers - 1; i >= 0; --i) free_staging_.push_back(i);
        }
        if (free_staging_.empty()) return -1;
        const int s = free_staging_.back();
        free_staging_.pop_back();
        if (staging_[static_cast<std::size_t>(s)].size() < page_bytes_) staging_[static_cast<std::size_t>(s)].resize(page_bytes_);
        return s;
    }

    void decode() {
        order_.clear();
        for (const auto& [k, w] : work_)
            if (w.stage == Stage::arrived) order_.emplace_back(w.priority, k);
        std::sort(order_.begin(), order_.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
        for (const auto& [priority, key] : order_) {
            auto& w = work_.at(key);
            const int s = take_staging();
            if (s < 0) break;
            const auto& info = textures_[key.texture].info;
            std::span<std::uint8_t> dst(staging_[static_cast<std::size_t>(s)].data(), upload_bytes(*info));
            w.staging = s;
            if (!pool_) {
                const auto st = transcode_pool_page(*info, w.tile->kind, w.tile->codec, w.tile->payload, pool_format_, dst,
                                                    scratch_);
                finish_decode(key, st.ok());
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
                free_staging_.push_back(s);
                w.staging = -1;
                break;
            }
            w.stage = Stage::decoding;
        }
        if (pool_) {
            results_.clear();
            pool_->poll(results_);
            for (const auto& r : results_) {
                auto it = work_.find(r.key);
                if (it == work_.end() || it->second.ticket != r.ticket) continue;
                if (r.dropped) {  // no longer wanted when its turn came
                    ++stats_.decodes_dropped;
                    free_staging_.push_back(it->second.staging);
                    work_.erase(it);
                    continue;
                }
                finish_decode(r.key, r.status.ok());
            }
        }
    }

    void finish_decode(const PageKey& key, bool ok) {
        auto& w = work_.at(key);
        if (!ok || !desired_.contains(key)) {
            if (ok) ++stats_.cancelled_decoded;  // decoded, then found unwanted
            free_staging_.push_back(w.staging);
            work_.erase(key);
            return;
        }
        const auto& info = textures_[key.texture].info;
        ReadyPage p;
        p.priority = w.priority;
        p.ticket = w.ticket;
        p.data = std::span<const std::uint8_t>(staging_[static_cast<std::size_t>(w.staging)].data(), upload_bytes(*info));
        p.bytes = static_cast<std::uint32_t>(p.data.size());
        p.requested = w.requested;
        w.stage = Stage::ready;
        w.tile.reset();
        if (!uploads_.push(std::move(p))) {
            free_staging_.push_back(w.staging);
            work_.erase(key);
        }
    }

    PageKey key_of_ticket(std::uint64_t ticket) const {
        auto it = tickets_.find(ticket);
        return it == tickets_.end() ? PageKey{0xFFFF, 31, 0, 0} : it->second;
    }

    void upload(Clock::time_point now) {
        evicted_wanted_ = 0;
        // Leaving pages this frame's feedback saw again stay, fading back in. Each was a victim the
        // view still wanted: the bias controller counts it as it counts such an eviction.
        scratch_slots_.clear();
        residency_.take_rescued(scratch_slots_);
        for (const SlotId slot : scratch_slots_) uploader_.cancel_fade_out(slot);
        stats_.pages_rescued = static_cast<std::uint32_t>(scratch_slots_.size());
        evicted_wanted_ += stats_.pages_rescued;
        // Pages that have faded out: gone now, their slots free for this frame's uploads.
        scratch_slots_.clear();
        uploader_.take_faded_out(scratch_slots_);
        for (const SlotId slot : scratch_slots_) {
            // Fails for a page the deadline finished already (Residency::begin_frame).
            if (residency_.finish_leaving(slot)) ++stats_.pages_evicted;
        }
        stats_.pages_evicted += residency_.take_expired();
        ready_.clear();
        uploads_.take_frame(ready_);
        for (auto& p : ready_) {
            const PageKey key = key_of_ticket(p.ticket);
            auto it = work_.find(key);
            tickets_.erase(p.ticket);
            if (it == work_.end()) continue;
            auto grant = residency_.acquire_slot(key);
            if (grant && grant->leaving != kNoSlot) uploader_.fade_out(grant->leaving);  // its slot frees later
            if (!grant || grant->slot == kNoSlot) {
                // No slot now (everything resident is in view, or the victim fades out first):
                // drop it; the feedback asks again, and the bias controller sees the pressure.
                free_staging_.push_back(it->second.staging);
                work_.erase(it);
                continue;
            }
            if (grant->evicted) {
                ++stats_.pages_evicted;
                if (desired_.contains(grant->victim)) ++evicted_wanted_;
            }
            // Unmapped before it is overwritten (acquire_slot did), mapped once complete.
            uploader_.upload_page(grant->slot, key, p.data, textures_[key.texture].info->tile_size());
            (void)residency_.complete(key, grant->slot);
            desired_.erase(key);  // resident now: frames without feedback must not ask for it again
            ++stats_.pages_uploaded;
            stats_.bytes_uploaded += p.bytes;
            summary_.record_latency(now - it->second.requested);
            // Drawn from the next frame on.
            if (auto seen = last_seen_.find(key); seen != last_seen_.end())
                summary_.record_time_to_detail(frame_no_ + 1 - seen->second.first);
            free_staging_.push_back(it->second.staging);
            work_.erase(it);
        }
        // Tickets of work dropped elsewhere.
        if (tickets_.size() > 4 * kStagingBuffers + work_.size()) {
            std::erase_if(tickets_, [&](const auto& t) {
                auto it = work_.find(t.second);
                return it == work_.end() || it->second.ticket != t.first;
            });
        }
    }

    void upload_page_tables() {
        for (TextureId t = 0; t < textures_.size(); ++t) {
            auto* table = residency_.table_for_upload(t);
            if (!table) continue;
            if (table->sparse()) {
                dirty_blocks_.clear();
                table->take_dirty_blocks(dirty_blocks_);
                for (const auto& b : dirty_blocks_)
                    uploader_.upload_page_table_block(
                        t, static_cast<std::uint8_t>(b.level), b.bx, b.by,
                        b.allocated ? table->block_entries(b.level, b.bx, b.by) : std::span<const PageEntry>());
                continue;
            }
            dirty_.clear();
            table->take_dirty(dirty_);
            for (const auto& r : dirty_) {
                const auto entries = table->level_entries(r.level);
                const std::uint32_t w = r.x1 - r.x0, h = r.y1 - r.y0;
                const std::uint32_t stride = table->level_width(r.level);
                rect_.resize(std::size_t(w) * h);
                for (std::uint32_t y = 0; y < h; ++y)
                    std::copy_n(entries.begin() + std::ptrdiff_t(std::size_t(r.y0 + y) * stride + r.x0), w,
                                rect_.begin() + std::ptrdiff_t(std::size_t(y) * w));
                uploader_.upload_page_table(t, static_cast<std::uint8_t>(r.level), r.x0, r.y0, w, h, rect_);
            }
        }
    }

    RuntimeConfig config_;
    // The uploader's format, read once: staging buffers and textures are sized by it.
    PagePoolFormat pool_format_;
    PageUploader& uploader_;
    Residency residency_;
    ResidencyAdapter view_;
    FeedbackAnalyzer analyzer_;
    RamTileCache ram_;
    std::unique_ptr<DiskTileCache> disk_;
    std::unique_ptr<DiskLoader> loader_;
    std::unique_ptr<TranscodePool> pool_;
    Scratch scratch_;
    UploadQueue uploads_;
    LodBiasController bias_;
    std::vector<Texture> textures_;
    std::size_t page_bytes_ = 0;

    std::uint64_t frame_no_ = 0;
    std::uint64_t next_ticket_ = 1;
    std::unordered_map<PageKey, float, PageKeyHash> desired_;
    // Wanted, not resident: the frames it was first and last seen wanted (first: time to detail).
    struct Seen {
        std::uint64_t first = 0, last = 0;
    };
    std::unordered_map<PageKey, Seen, PageKeyHash> last_seen_;
    std::unordered_map<PageKey, Work, PageKeyHash> work_;
    std::unordered_map<std::uint64_t, PageKey> tickets_;
    std::unordered_set<PageKey, PageKeyHash> absent_;
    std::unordered_map<TileSource*, std::vector<SourceRequest>> last_sent_;
    std::vector<std::vector<std::uint8_t>> staging_;
    std::vector<int> free_staging_;
    std::uint32_t evicted_wanted_ = 0;
    std::vector<SlotId> scratch_slots_;  // upload()'s: rescued, then faded-out slots

    // Per-frame scratch (kept to avoid reallocating).
    std::vector<std::pair<float, PageKey>> order_;
    std::vector<SourceRequest> requests_;
    std::vector<SourceTile> received_;
    std::vector<DiskLoader::Found> found_;
    std::vector<TranscodeResult> results_;
    std::vector<ReadyPage> ready_;
    std::vector<DirtyRect> dirty_;
    std::vector<DirtyBlock> dirty_blocks_;
    std::vector<std::uint32_t> rect_;

    FrameStats stats_;
    StatsSummary summary_;
};

}  // namespace

Result<std::unique_ptr<Runtime>> Runtime::create(const RuntimeConfig& config, PageUploader& uploader) {
    if (config.residency.pool_slots == 0) return Error{Errc::invalid_argument, "the page pool needs at least one slot"};
    if (config.max_requests_in_flight == 0) return Error{Errc::invalid_argument, "max_requests_in_flight must be >= 1"};
    ResidencyConfig rc = config.residency;
    rc.fade_out_frames = uploader.fades_out() ? config.fade_out_frames : 0;  // fading out is the uploader's to do
    auto residency = Residency::create(rc);
    if (!residency) return residency.error();
    auto rt = std::make_unique<RuntimeImpl>(config, uploader, std::move(*residency));
    TESSERA_TRY(rt->open_disk_cache());
    return std::unique_ptr<Runtime>(std::move(rt));
}

}  // namespace tessera::client
