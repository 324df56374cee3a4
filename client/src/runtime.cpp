#include "tessera/client/runtime.hpp"

#include <algorithm>
#include <unordered_map>

#include "feedback_analysis.hpp"
#include "page_loader.hpp"
#include "residency.hpp"
#include "runtime_internal.hpp"

namespace tessera::client {

namespace {

using Clock = std::chrono::steady_clock;

class ResidencyAdapter final : public ResidencyView {
public:
    explicit ResidencyAdapter(const Residency& r) : r_(r) {}
    std::uint8_t resident_level(const PageKey& page) const override { return r_.resident_level(page); }

private:
    const Residency& r_;
};

class RuntimeImpl final : public Runtime {
public:
    RuntimeImpl(const RuntimeConfig& config, PageUploader& uploader, PageStaging* staging, Residency residency)
        : config_(config),
          uploader_(uploader),
          residency_(std::move(residency)),
          view_(residency_),
          analyzer_(config.max_feedback_pages),
          pool_format_(uploader.pool_format()),
          loader_(config, pool_format_, staging),
          bias_(config.bias),
          glide_(double(config.fade_ms) / 1000.0) {}

    Status open_disk_cache() { return loader_.open_disk_cache(); }

    Result<TextureId> add_texture(TileSource& source, const std::string& store) override {
        if (textures_ >= 0xFFFF) return Error{Errc::resource_exhausted, "too many textures"};
        const auto id = static_cast<TextureId>(textures_);
        auto info = PageLoader::bind(id, source, store, pool_format_);
        if (!info) return info.error();
        const auto& l0 = info->levels[0];
        TESSERA_TRY(residency_.add_texture(id, l0.tiles_x, l0.tiles_y, info->level_count()));
        analyzer_.set_texture_levels(id, static_cast<std::uint8_t>(info->level_count()));
        analyzer_.set_texture_extent(id, l0.tiles_x, l0.tiles_y);
        loader_.add_texture(source, store, *info);
        ++textures_;
        return id;
    }

    const storage::StoreInfo* texture_info(TextureId texture) const override { return loader_.info(texture); }
    std::uint64_t texture_replaced(TextureId texture) const override { return loader_.replaced_by(texture); }

    const FrameStats& frame(std::span<const FeedbackId> feedback, std::uint32_t width, std::uint32_t height,
                            float feedback_bias) override {
        const auto now = Clock::now();
        ++frame_no_;
        stats_ = FrameStats{};
        stats_.frame = frame_no_;
        tick_clock();
        // Residency counts feedbacks, not runtime frames: kept_frames keeps the pages of the last
        // N feedbacks (with motion prefetch, the view's own among the views ahead), and a frame
        // without feedback saw nothing.
        (void)residency_.begin_frame(++feedback_frames_, clock_);

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
                if (!loader_.is_absent(w.key) && w.key.texture < textures_) desired_.emplace(w.key, rank);
            }
            rank -= 1;
        }
        keep_recently_wanted();
        stats_.pages_wanted = static_cast<std::uint32_t>(wanted.size());
        stats_.fallback_estimate = pixels ? float(double(fallback_pixels) / double(pixels)) : 0.0f;

        loader_.collect_arrivals(stats_, resident_);
        loader_.cancel_unwanted(desired_, stats_);
        loader_.request_and_decode(frame_no_, desired_, now, stats_);
        upload(now);
        upload_page_tables();

        const auto rs = residency_.stats();
        stats_.pages_resident = rs.resident_pages;
        LodBiasInputs in;
        in.pages_wanted = stats_.pages_wanted;
        in.pool_slots = rs.pool_slots > rs.pinned_pages ? rs.pool_slots - rs.pinned_pages : 0;
        in.pending = static_cast<std::uint32_t>(loader_.in_flight());
        in.delivered_last_frame = stats_.pages_uploaded;
        in.evicted_last_frame = stats_.pages_evicted;
        in.evicted_wanted_last_frame = evicted_wanted_;
        in.feedback_bias = feedback_bias;
        stats_.lod_bias = bias_.update(in);
        glide_.advance(clock_, stats_.lod_bias);
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
        tick_clock();
        (void)residency_.begin_frame(residency_.frame(), clock_);  // the fades move on
        loader_.collect_arrivals(stats_, resident_);
        loader_.request_and_decode(frame_no_, desired_, now, stats_);
        upload(now);
        upload_page_tables();
        stats_.pages_resident = residency_.stats().resident_pages;
        stats_.lod_bias = bias_.bias();
        glide_.advance(clock_, stats_.lod_bias);
        summary_.add_frame(stats_);
        return stats_;
    }

    void set_time(double seconds) override {
        clock_ = std::max(seconds, clock_);
        clock_set_ = true;
    }

    float lod_bias() const override { return glide_.bias(); }
    const Residency& residency() const { return residency_; }
    const StatsSummary& summary() const override { return summary_; }
    std::optional<DiskCacheCounts> disk_cache() const override {
        const auto s = loader_.disk_stats();
        if (!s) return std::nullopt;
        return DiskCacheCounts{s->entries, s->bytes, s->hits, s->writes, s->corrupt, s->write_errors, s->write_drops, s->evictions};
    }
    std::size_t in_flight() const override { return loader_.in_flight(); }

private:
    // Moves the clock by a 60 Hz frame unless set_time() set it for this frame.
    void tick_clock() {
        if (!clock_set_ && frame_no_ > 1) clock_ += 1.0 / 60.0;
        clock_set_ = false;
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
                loader_.is_absent(it->first)) {
                it = last_seen_.erase(it);
                continue;
            }
            desired_.emplace(it->first, -static_cast<float>(unseen));
            ++it;
        }
    }

    void upload(Clock::time_point now) {
        // Leaving pages this frame's feedback saw again stay, fading back in. Each was a victim the
        // view still wanted: the bias controller counts it as such an eviction. They are the only
        // ones it can see: desired_ holds only pages not resident (a page leaves it as it is
        // uploaded), so no victim is ever in it.
        stats_.pages_rescued = residency_.take_kept();
        evicted_wanted_ = stats_.pages_rescued;
        stats_.pages_evicted += residency_.take_left();  // faded out this frame (begin_frame)
        send_weights();  // the fades moved, and slots freed by them first: then this frame's pages
        loaded_.clear();
        loader_.take_frame(loaded_);
        for (const auto& p : loaded_) {
            const PageKey key = p.key;
            auto grant = residency_.acquire_slot(key);  // a victim seen lately leaves first: its slot frees later
            if (!grant || grant->slot == kNoSlot) {
                // No slot now (everything resident is in view, or the victim fades out first):
                // drop it; the feedback asks again, and the bias controller sees the pressure.
                loader_.done(key);
                continue;
            }
            if (grant->evicted) ++stats_.pages_evicted;
            // Unmapped before it is overwritten (acquire_slot did), mapped once complete.
            uploader_.upload_page(grant->slot, key, p.data, loader_.info(key.texture)->tile_size());
            (void)residency_.complete(key, grant->slot);
            desired_.erase(key);  // resident now: frames without feedback must not ask for it again
            ++stats_.pages_uploaded;
            stats_.bytes_uploaded += p.bytes;
            summary_.record_latency(now - p.requested);
            // Drawn from the next frame on.
            if (auto seen = last_seen_.find(key); seen != last_seen_.end())
                summary_.record_time_to_detail(frame_no_ + 1 - seen->second.first);
            loader_.done(key);
        }
    }

    void send_weights() {
        weights_.clear();
        residency_.take_weight_changes(weights_);
        if (!weights_.empty()) uploader_.set_slot_weights(weights_);
    }

    void upload_page_tables() {
        send_weights();  // the pages uploaded this frame start at weight 0
        for (TextureId t = 0; t < textures_; ++t) {
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
    PageUploader& uploader_;
    Residency residency_;  // the page cache: every slot's state
    ResidencyAdapter view_;
    FeedbackAnalyzer analyzer_;
    // The uploader's format, read once: staging buffers and textures are sized by it.
    PagePoolFormat pool_format_;
    PageLoader loader_;    // wanted pages into decoded staging
    LodBiasController bias_;
    BiasGlide glide_;
    double clock_ = 0;        // seconds (set_time)
    bool clock_set_ = false;  // set for this frame
    std::size_t textures_ = 0;
    std::function<bool(const PageKey&)> resident_ = [this](const PageKey& p) { return residency_.is_resident(p); };

    std::uint64_t frame_no_ = 0;
    std::uint64_t feedback_frames_ = 0;  // frames with feedback: residency's frame numbers
    WantedPages desired_;
    // Wanted, not resident: the frames it was first and last seen wanted (first: time to detail).
    struct Seen {
        std::uint64_t first = 0, last = 0;
    };
    std::unordered_map<PageKey, Seen, PageKeyHash> last_seen_;
    std::uint32_t evicted_wanted_ = 0;

    // Per-frame scratch (kept to avoid reallocating).
    std::vector<PageLoader::Loaded> loaded_;
    std::vector<SlotWeight> weights_;
    std::vector<DirtyRect> dirty_;
    std::vector<DirtyBlock> dirty_blocks_;
    std::vector<std::uint32_t> rect_;

    FrameStats stats_;
    StatsSummary summary_;
};

}  // namespace

Result<std::unique_ptr<Runtime>> Runtime::create(const RuntimeConfig& config, PageUploader& uploader,
                                                 PageStaging* staging) {
    if (config.residency.pool_slots == 0) return Error{Errc::invalid_argument, "the page pool needs at least one slot"};
    if (config.max_requests_in_flight == 0) return Error{Errc::invalid_argument, "max_requests_in_flight must be >= 1"};
    if (!(config.fade_ms >= 0 && config.fade_ms <= 10000)) return Error{Errc::invalid_argument, "fade_ms must be 0..10000"};
    ResidencyConfig rc = config.residency;
    rc.fade_out_frames = config.fade_ms > 0 ? config.fade_out_frames : 0;
    auto residency = Residency::create(rc, double(config.fade_ms) / 1000.0);
    if (!residency) return residency.error();
    auto rt = std::make_unique<RuntimeImpl>(config, uploader, staging, std::move(*residency));
    TESSERA_TRY(rt->open_disk_cache());
    return std::unique_ptr<Runtime>(std::move(rt));
}

const Residency& residency_of(const Runtime& runtime) {
    // Runtime::create makes every runtime; another implementation would have no page cache here.
    return dynamic_cast<const RuntimeImpl&>(runtime).residency();
}

}  // namespace tessera::client
