#pragma once
// The loader (docs/client.md, "Inside Runtime::frame", steps 2-4): a wanted page's way from the
// RAM cache, the disk cache and the sources to a page decoded into the pool's format, ready to
// upload. Every stage is cancelled when the page stops being wanted. Which slot a page goes to,
// and everything after, is the page cache's (residency.hpp).
//
// Render thread only. Owns the disk loader thread and the transcode pool, and the staging
// buffers decoded pages wait in; its queues are bounded by max_requests_in_flight (work),
// kStagingBuffers (decoded pages) and the upload budget (what one frame takes).
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "tessera/client/page.hpp"
#include "tessera/client/runtime.hpp"
#include "tessera/client/stats.hpp"
#include "tessera/client/tile_source.hpp"
#include "tessera/client/upload.hpp"
#include "disk_cache.hpp"
#include "ram_cache.hpp"
#include "transcode.hpp"

namespace tessera::client {

class DiskLoader;

// Pages wanted this frame, by priority (higher first).
using WantedPages = std::unordered_map<PageKey, float, PageKeyHash>;

class PageLoader {
public:
    using Clock = std::chrono::steady_clock;
    static constexpr std::size_t kStagingBuffers = 64;  // decoded pages waiting for upload, at most
    // Absent pages remembered, at most (a few MiB): past it they are forgotten at once, and each is
    // asked for once more if it is wanted again. A view roaming a 2^24 sparse store meets
    // absent pages without end.
    static constexpr std::size_t kMaxAbsentPages = std::size_t(1) << 18;
    // A texture whose source delivered another version of its store (replaced_by) asks for its
    // missing pages only every this many frames (5 s at 60 Hz; an unchanged request set is sent
    // again every 30 frames otherwise): each answer would be refused again if the store was
    // replaced for good, but a replica or a rollback may still serve the bound version.
    static constexpr std::uint64_t kReplacedRetryFrames = 300;
    // A page whose request ended in an error (a server's "retry later", a deadline, a tile it
    // could not read) is asked for again this many frames later (about 130 ms at 60 Hz), not on
    // the next frame, and not at the next 30-frame resend of an unchanged set.
    static constexpr std::uint64_t kErrorRetryFrames = 8;

    // Uses config's request, cache, transcode and upload-budget settings. `lender`, when not
    // null, lends the staging memory pages are decoded into (else the loader's own buffers).
    PageLoader(const RuntimeConfig& config, PagePoolFormat pool, PageStaging* lender = nullptr);
    ~PageLoader();
    PageLoader(const PageLoader&) = delete;
    PageLoader& operator=(const PageLoader&) = delete;

    Status open_disk_cache();
    // The disk cache's stats; nothing without one.
    std::optional<DiskCacheStats> disk_stats() const { return disk_ ? std::optional<DiskCacheStats>(disk_->stats()) : std::nullopt; }

    // Binds store `store` of `source` as texture `id` (the next one: 0, 1, ...) and checks that
    // its pages can be transcoded to the pool's format. Returns its geometry; add_texture then
    // registers it (once the page cache has taken it too).
    static Result<storage::StoreInfo> bind(TextureId id, TileSource& source, const std::string& store, const PagePoolFormat& pool);
    void add_texture(TileSource& source, const std::string& store, const storage::StoreInfo& info);
    const storage::StoreInfo* info(TextureId texture) const {
        return texture < textures_.size() ? textures_[texture].info.get() : nullptr;
    }
    // The version of the texture's store its source delivers instead of the bound one (the store
    // was rebuilt and reloaded); 0 while none has come.
    std::uint64_t replaced_by(TextureId texture) const { return texture < textures_.size() ? textures_[texture].replaced_by : 0; }
    // A page the store says has no data (sparse stores): never requested again.
    bool is_absent(const PageKey& page) const { return absent_.contains(page); }

    // Each frame, in this order: takes what arrived (disk lookups, sources; `resident` tells a
    // stale delivery from a duplicate) ...
    void collect_arrivals(FrameStats& stats, const std::function<bool(const PageKey&)>& resident);
    // ... drops the work on pages no longer in `wanted`, at every stage, and gives the rest their
    // new priority (not in frames without feedback: the wanted set is the last one's) ...
    void cancel_unwanted(const WantedPages& wanted, FrameStats& stats);
    // ... issues requests for wanted pages not yet in work (highest priority first, within the
    // in-flight bound), sends each source its request set, and decodes what arrived into staging.
    void request_and_decode(std::uint64_t frame, const WantedPages& wanted, Clock::time_point now, FrameStats& stats);

    // A decoded page taken for upload.
    struct Loaded {
        PageKey key;
        std::span<const std::uint8_t> data;  // the page in the pool's format, valid until done(key)
        std::uint32_t bytes = 0;
        Clock::time_point requested{};
    };
    // This frame's decoded pages within the upload budget, highest priority first. Each must be
    // given back with done() in the same frame.
    void take_frame(std::vector<Loaded>& out);
    // The page is uploaded or dropped: its work and staging buffer are free.
    void done(const PageKey& key);

    std::size_t in_flight() const { return work_.size(); }

private:
    struct Texture {
        TileSource* source = nullptr;
        std::string store;
        std::shared_ptr<const storage::StoreInfo> info;
        std::uint64_t replaced_by = 0;  // the store version a source delivered last instead (0: none since the bound one came)
        // The disk cache keys by store name (DiskTileCache::valid_store_name): a server's stores.
        // A local file named by a path with a directory, or a procedural source's spec, is no
        // such name (a bare file name is, and is cached like a server's store).
        bool disk_cached = false;
    };
    enum class Stage { disk, source, arrived, decoding, ready };
    struct Work {
        Stage stage = Stage::source;
        float priority = 0;
        Clock::time_point requested{};
        std::uint64_t ticket = 0;              // tells a re-request from the one a result answers
        std::shared_ptr<const TileData> tile;  // arrived and later
        int staging = -1;                      // decoding, ready
    };

    TileId tile_id(const PageKey& p) const;
    // A page that stands absent (a tile the store lacks, a bundle without a layer, a payload that
    // does not decode): not asked for again while remembered (kMaxAbsentPages).
    void remember_absent(const PageKey& page);
    void arrived(const PageKey& page, Work& w, std::shared_ptr<const TileData> tile, FrameStats& stats);
    void issue_requests(const WantedPages& wanted, Clock::time_point now, FrameStats& stats);
    void send_request_sets(std::uint64_t frame);
    void decode(const WantedPages& wanted, FrameStats& stats);
    void finish_decode(const PageKey& key, bool ok, const WantedPages& wanted, FrameStats& stats);
    int take_staging();
    void free_staging(Work& w);

    RuntimeConfig config_;
    PagePoolFormat pool_format_;
    PageStaging* lender_ = nullptr;  // null: decode into the loader's own buffers
    RamTileCache ram_;
    std::unique_ptr<DiskTileCache> disk_;
    std::unique_ptr<DiskLoader> disk_loader_;
    std::unique_ptr<TranscodePool> pool_;  // null: decode on the render thread (transcode_threads 0)
    Scratch scratch_;
    UploadQueue uploads_;
    std::vector<Texture> textures_;
    std::vector<TileSource*> sources_;  // each texture's source, once
    std::size_t page_bytes_ = 0;  // staging buffer size: the largest upload of any texture
    std::uint64_t next_ticket_ = 1;
    std::uint64_t frame_ = 0;  // of the latest request_and_decode
    std::unordered_map<PageKey, Work, PageKeyHash> work_;
    std::unordered_set<PageKey, PageKeyHash> absent_;
    std::unordered_map<TileSource*, std::vector<SourceRequest>> last_sent_;
    // Pages a source answered with an error: the frame from which they are asked again.
    std::unordered_map<PageKey, std::uint64_t, PageKeyHash> retry_at_;
    // A decoded page's memory: lent by the uploader (one copy fewer) or the loader's own.
    struct Staging {
        std::span<std::uint8_t> bytes;     // while taken
        std::optional<std::uint32_t> lent;  // the lender's id, while lent
        std::vector<std::uint8_t> own;      // used when nothing is lent
    };
    std::vector<Staging> staging_;  // kStagingBuffers of them
    std::vector<int> free_staging_;

    // Per-frame scratch (kept to avoid reallocating).
    std::vector<std::pair<float, PageKey>> order_;
    std::vector<SourceRequest> requests_;
    std::vector<SourceTile> received_;
    std::vector<TranscodeResult> results_;
    std::vector<ReadyPage> ready_;
};

}  // namespace tessera::client
