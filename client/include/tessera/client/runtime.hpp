#pragma once
// The client runtime: one call per frame turns the renderer's feedback into resident pages.
//
//   frame(feedback) ──► clock: every fade moves (page cache)
//                  ──► analysis (unique pages + ancestors, by priority)
//                  ──► resident: touch │ not, the loader: RAM cache ─► disk cache ─► source
//                  ◄── arrivals ─► caches ─► transcode pool (pool format, into staging)
//                  ──► per-frame budget: the page cache picks a slot (evicting, or a victim
//                      fading out first), upload, map; weights and page-table changes
//                  ──► LoD-bias controller (the bias drawn with moves over the fade time)
//
// frame() runs on the render thread and never waits on I/O, decoding or the network: everything
// slow happens on threads owned here (disk loader, transcode pool) or by the sources, behind
// bounded queues. Each frame's request set replaces the previous one at every stage.
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <span>
#include <string>

#include "tessera/client/lod_bias.hpp"
#include "tessera/client/page.hpp"
#include "tessera/client/stats.hpp"
#include "tessera/client/tile_source.hpp"
#include "tessera/client/upload.hpp"
#include "tessera/result.hpp"

namespace tessera::client {

struct ResidencyConfig {
    // Slots in the physical pool, 1 .. 2^24.
    std::uint32_t pool_slots = 0;
    // Coarsest levels of every texture that are pinned. kAutoPinnedLevels: as many of the coarsest
    // levels as hold at most auto_pin_max_pages pages together (at least the 1x1 level): with the
    // default 5, the top two levels (1 + 4 pages) of a square texture.
    static constexpr std::uint32_t kAutoPinnedLevels = ~0u;
    std::uint32_t pinned_levels = kAutoPinnedLevels;
    std::uint32_t auto_pin_max_pages = 5;
    // Bound on each texture's dense page table.
    std::size_t max_table_bytes = kDefaultPageTableBytes;
    // A texture whose dense table is over the bound (or over the renderer's dense packing) gets a
    // sparse (two-level) table instead of an error.
    bool sparse_tables = true;
    // Pages seen in the last `kept_frames` feedbacks (1: the current one; frames without feedback
    // do not count) are never evicted
    // for an ordinary page. When every N-th feedback sees a view ahead (motion prefetch), N keeps
    // the pages of the last feedback of the view itself, so a page on screen is not evicted for
    // one the view ahead wants. 1 .. 64.
    std::uint32_t kept_frames = 1;
    // Fading out (docs/client.md, "A slot's life"): a victim seen within `fade_out_frames`
    // feedbacks before the kept ones may still be on screen, so it leaves over a fade instead of at
    // once: it stays mapped and drawn while its weight falls, and its slot is reused once it has
    // faded out. At most `max_leaving` pages leave at once (further victims go at once). 0: evict
    // at once. The runtime sets it from RuntimeConfig::fade_out_frames when RuntimeConfig::fade_ms
    // > 0, and to 0 otherwise.
    std::uint32_t fade_out_frames = 0;
    std::uint32_t max_leaving = 32;
};

struct RuntimeConfig {
    ResidencyConfig residency;                     // pool_slots is required
    // Pages in the loader at once: disk lookups and source requests, and pages arrived, decoding
    // or decoded and waiting for their upload.
    std::size_t max_requests_in_flight = 512;
    std::uint64_t ram_cache_bytes = 128ull << 20;  // 0: no RAM cache
    std::string disk_cache_dir;                    // empty: no disk cache
    std::uint64_t disk_cache_bytes = 1ull << 30;
    // Transcode threads. 0: decode on the calling thread inside frame() — deterministic, for
    // simulations and tools; a renderer wants >= 1.
    unsigned transcode_threads = 1;
    std::size_t upload_pages_per_frame = 32;
    std::size_t upload_bytes_per_frame = 16u << 20;
    LodBiasConfig bias;
    std::size_t max_feedback_pages = 1 << 16;
    // A page the feedback stops seeing stays wanted (its request alive) until it was unseen for
    // more than this many frames: jittered feedback sees small pages only in some frames
    // (docs/client.md, "Inside `Runtime::frame`", Cancellation). Counted in frames, not time:
    // an unpaced run moves its camera per frame, however fast the frames come.
    std::uint32_t keep_unwanted_frames = 8;
    // Fades (docs/client.md, "A slot's life"; docs/renderer.md, "Blending in"), on the runtime's
    // clock (set_time): an arriving page blends from what was drawn before it (its nearest
    // resident ancestor) to itself over fade_ms, a page leaving while maybe in view blends back
    // to its ancestor before its slot is reused, and the LoD bias drawn with (lod_bias()) moves
    // by at most one level per fade_ms. The uploader gets the weights (set_slot_weights). 0: off.
    float fade_ms = 0.0f;  // 0..10000
    // Victims seen within this many frames before the kept ones (ResidencyConfig::kept_frames)
    // fade out before their slot is reused, when fade_ms > 0. 0: never.
    std::uint32_t fade_out_frames = 8;
};

class Runtime {
public:
    // `staging`, when given, lends the memory pages are decoded into (PageStaging: the GL
    // renderer's page_staging()); it must outlive the runtime, as the uploader must.
    static Result<std::unique_ptr<Runtime>> create(const RuntimeConfig& config, PageUploader& uploader,
                                                   PageStaging* staging = nullptr);
    virtual ~Runtime() = default;

    // A virtual texture: the store `store` of `source` (which must outlive the runtime).
    virtual Result<TextureId> add_texture(TileSource& source, const std::string& store) = 0;
    virtual const storage::StoreInfo* texture_info(TextureId texture) const = 0;
    // Non-zero while the texture's source delivers tiles of another version of its store (rebuilt
    // and reloaded on its server): that version; 0 again once the bound version comes (a replica,
    // a rollback). Such tiles are refused, never mixed with the bound version's, and the
    // texture's missing pages are asked for only every 300 frames (each answer would likely be
    // refused again); what is resident stays. To see the new version, open a new runtime on it.
    virtual std::uint64_t texture_replaced(TextureId texture) const = 0;

    // One frame: the feedback buffer of a frame rendered (width*height ids, kNoPage where no
    // virtual texture is) and the LoD bias it was rendered with (NaN: unknown; then the bias
    // controller waits a few frames after each change instead). Returns this frame's counters.
    virtual const FrameStats& frame(std::span<const FeedbackId> feedback, std::uint32_t width, std::uint32_t height,
                                    float feedback_bias = std::numeric_limits<float>::quiet_NaN()) = 0;

    // A frame whose feedback has not come back yet (GPU readbacks arrive frames late): the wanted
    // set stays the last feedback's (nothing is cancelled or newly protected), while arrivals,
    // decoding and uploads go on. The bias controller waits for real feedback.
    virtual const FrameStats& frame_without_feedback() = 0;

    // The runtime's clock: the time, in seconds, of the frame whose feedback the next frame() (or
    // frame_without_feedback()) call gets; never decreasing. Fades move on it. Without a call
    // before a frame, the clock moves by 1/60 s per frame.
    virtual void set_time(double seconds) = 0;

    // The LoD bias to draw the next frame (and its feedback) with: the controller's, moving by at
    // most one level per fade time (RuntimeConfig::fade_ms).
    virtual float lod_bias() const = 0;
    virtual const StatsSummary& summary() const = 0;
    // The disk cache's counts; nothing without one (RuntimeConfig::disk_cache_dir empty).
    virtual std::optional<DiskCacheCounts> disk_cache() const = 0;
    virtual std::size_t in_flight() const = 0;  // pages requested and not yet mapped or dropped
};

}  // namespace tessera::client
