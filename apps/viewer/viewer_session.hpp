#pragma once
// One viewer run, shared by `tessera view` and `tessera demo`: a store (local file or server),
// a scene, a camera path, the GL renderer (headless or windowed) driven by the client runtime,
// per-frame records, and the run's outputs (PNG frames, stats, trace, reference PSNR).
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "tessera/client/gl/renderer.hpp"
#include "tessera/client/lod_bias.hpp"
#include "tessera/client/stats.hpp"

namespace tessera::tools {

// Blending in: how long an arriving page takes to reach full weight, by default (docs/benchmarks.md,
// "Popping": the pop rate against the fade time).
constexpr float kDefaultFadeMs = 250.0f;
// Motion prefetch: how far ahead the predicted view is, by default (docs/benchmarks.md, "Motion
// prefetch").
constexpr double kDefaultMotionPrefetchMs = 200.0;

// The GPU pool a viewer gets unless told (ViewerOptions::pool).
inline constexpr std::uint32_t kDefaultPoolPages = 2048;

struct ViewerOptions {
    std::string store;            // FILE.tsr, grpc://HOST:PORT/NAME, grpcs://HOST:PORT/NAME or HOST:PORT/NAME
    std::string reference_store;  // local .tsr for the PSNR reference (default: `store` when it is a file)
    // "auto": the scene that travels with the store (an atlas OBJ beside the store file, or sent by
    // its server: docs/atlas.md), else the terrain; "terrain"; or an atlas OBJ file.
    std::string scene = "auto";
    double displacement = 0;      // terrain height, world units (0: flat); a store's height layer spans it
    std::string path = "auto";  // built-in name (auto: flyover over the terrain, orbit around an OBJ scene) or a path file
    std::uint32_t width = 1280, height = 720;
    bool headless = true;
    std::uint32_t frames = 0;  // 0: the whole path at `fps`
    double fps = 60;           // headless: the path advances 1/fps per frame, whatever the render speed
    std::string out_dir;       // PNG frames go here (empty: none)
    std::uint32_t png_count = 4;  // frames written, spread over the run
    std::string stats_file;    // .csv or .json per-frame records (empty: none)
    std::string trace_file;    // feedback trace for `tessera loadtest` (empty: none)
    // Pages in the GPU pool. 0: kDefaultPoolPages, or every page of the store (all levels, all
    // layers in one slot) when it has fewer: a small store's pool is not sized for a large one.
    std::uint32_t pool = 0;
    // How the GPU pool holds pages: auto (the store's block format if it has one, else rgba8),
    // rgba8, bc1, bc4 or bc5 (JPEG/zstd pages block-encoded on the transcode threads).
    std::string page_format = "auto";
    // A multi-layer store (docs/renderer.md, "Layers"): which layer to draw (empty: the first), and
    // whether a layer named "normal" lights the first one (on unless `unlit`). Layers after the
    // first keep their store's block format, or their 16-bit/float samples exactly (r16, r16f,
    // r32f), else rgba8; --page-format is the first layer's. `layer_formats`: "NAME=FORMAT" each,
    // a layer's page format chosen (FORMAT as page_format; a misfit is an error naming the layer).
    std::string show_layer;
    bool unlit = false;
    std::vector<std::string> layer_formats;
    client::gl::Filter filter = client::gl::Filter::trilinear;
    std::uint32_t anisotropy = 8;
    std::uint32_t feedback_scale = 8;
    float prefetch_lod = 0.15f;  // RendererConfig::feedback_prefetch_lod (docs/renderer.md, "Prefetch")
    float guard_band = 0.1f;    // RendererConfig::feedback_guard_band
    // RuntimeConfig::fade_ms (docs/renderer.md, "Blending in"): arriving pages blend in, and
    // evicted pages that may be in view fade out, over this long, on path time (headless) or wall
    // time (windowed); 0: off.
    float fade_ms = kDefaultFadeMs;
    // Motion prefetch (docs/renderer.md, "Motion prefetch"): every `motion_prefetch_every`-th
    // frame's feedback sees the view `motion_prefetch_ms` ahead, extrapolated from the camera's
    // velocity and angular velocity over the last frame, so its pages are requested before they
    // come into view. 0: off.
    double motion_prefetch_ms = kDefaultMotionPrefetchMs;
    std::uint32_t motion_prefetch_every = 2;
    std::uint64_t ram_cache_bytes = 256ull << 20;
    std::string disk_cache_dir;
    std::uint64_t disk_cache_bytes = 1ull << 30;
    unsigned transcode_threads = 2;
    std::uint32_t upload_pages_per_frame = 32;
    std::uint32_t psnr_every = 0;  // reference comparison every N frames (0: never)
    std::string auth_token;
    std::string tls_ca_file;  // grpcs: roots to verify the server with (default: system roots)
    // Before the path starts (headless), render its first view until it is fully resident (no
    // fallback pixel, nothing in flight) or warmup_timeout_s passes: a loading screen. The time
    // it took is reported as the first view's time to full detail; the path's fallback rate then
    // measures streaming while moving. Off: the path starts from an empty pool.
    bool warmup = true;
    double warmup_timeout_s = 20;
    bool progress = true;
    // An emulated network link between the viewer and its source (client/emulated_source.hpp):
    // used when any of these is > 0 (`tessera bench`). Defaults: no link.
    double link_latency_ms = 0, link_jitter_ms = 0, link_bandwidth_bits_per_s = 0;
    std::uint64_t link_seed = 1;
    // The LoD-bias controller's settings (RuntimeConfig::bias; default: the runtime's default).
    client::LodBiasConfig bias{};
    // Headless: hold each frame to at least 1/fps of wall time (a display's refresh), so that
    // wall-clock delays (the emulated link, decoding) compare with path time as on a real display.
    bool pace = false;
    // Windowed: draw the live statistics over the frame (the window title carries them as well).
    bool hud = true;
    // Before the first frame, wait up to this long for the tile source's stream to be connected
    // (a server store: bind() has reached the server, the stream opens in the background).
    double connect_wait_s = 5;
};

// `tessera view --max-outage` and `tessera demo`: a run whose tile source was unserved for longer
// than this (seconds) exits with kOutageExitCode.
constexpr double kDefaultMaxOutageSeconds = 5;
constexpr int kOutageExitCode = 3;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

struct FrameRecord {
    std::uint64_t frame = 0;
    double time_s = 0;   // path time
    double frame_ms = 0;  // wall time of the frame on the render thread
    std::uint32_t pages_wanted = 0, pages_resident = 0, pages_requested = 0, pages_uploaded = 0, pages_evicted = 0;
    std::uint32_t pages_rescued = 0;  // pages fading out that the view wanted again: kept
    float bias = 0;
    bool counted = false;  // the GPU's fallback counters arrived for this frame
    std::uint64_t textured_pixels = 0, fallback_unbiased = 0, fallback_biased = 0;
    double tile_latency_ms = kNaN;  // mean request -> mapped of the pages mapped this frame
    std::uint64_t bytes_received = 0;
    double psnr = kNaN;
    int max_error = -1;
    // Popping since the previous frame (docs/viewer.md, "Measures"), on the frames compared with
    // the reference whose previous frame was too: the fraction of covered pixels that popped
    // (NaN: not measured) and the largest change the reference did not make.
    double pop_rate = kNaN;
    int pop_largest = -1;
    bool connected = true;  // the tile source's link was up when the frame ran
    double unserved_s = 0;  // seconds the link has been down so far in the run (warm-up included)
    double fallback_rate() const { return textured_pixels ? double(fallback_unbiased) / double(textured_pixels) : kNaN; }
    double fallback_rate_biased() const {
        return textured_pixels ? double(fallback_biased) / double(textured_pixels) : kNaN;
    }
};

struct ViewerReport {
    std::string renderer;  // GL_RENDERER
    std::string source;    // what served the tiles
    // The GPU pool: its page format, bytes per page (the second level included where the atlas
    // has one), pages, and texels of level 0.
    client::PageFormat page_format = client::PageFormat::rgba8;
    std::vector<std::string> layers;  // a multi-layer pool's layers: "name format", in order
    std::string displaced_by;  // the layer the terrain follows ("layer height (level 4, ...)"), or empty
    std::string scene;         // what was drawn: "terrain", "atlas from the store (... triangles)", ...
    std::uint64_t gpu_page_bytes = 0;
    std::uint32_t pool_pages = 0;
    std::uint64_t pool_texels = 0;
    std::vector<FrameRecord> frames;
    client::StatsSummary summary;
    std::optional<client::DiskCacheCounts> disk_cache;  // with --disk-cache: what it held and could not do
    double wall_s = 0;
    std::vector<std::string> pngs;
    double warmup_ms = kNaN;        // first view: time to full detail (NaN: no warm-up)
    std::uint32_t warmup_frames = 0;
    bool warmup_complete = false;   // false: it timed out, or gave up on a view whose reads only failed
    bool warmup_errors_only = false;  // gave up: for 2 s no page came and the reads kept failing
    // The path's last view held until resident and faded in, against the reference (headless,
    // with --psnr-every): PSNR once settled (NaN: not measured).
    double settled_psnr = kNaN;
    int settled_max_error = -1;
    std::uint32_t settled_frames = 0;
    bool settled_complete = false;
    std::uint32_t fade_frames = 0;  // frames a page takes to reach full weight once drawn (0: no fade)
    std::uint64_t predicted_feedback_frames = 0;  // frames whose feedback saw a predicted view
    std::uint64_t page_bytes_copied = 0;          // page bytes copied on the CPU after decoding (RendererStats)
    // The tile source's link over the whole run, warm-up included (a local store: always up).
    bool remote = false;            // tiles came from a server
    double run_s = 0;               // wall time the link was watched (warm-up and path)
    double unserved_s = 0;          // of which the link was down: no tile could come
    std::uint32_t outages = 0;      // times the link was reported down (stderr, HUD)
    bool down_at_end = false;       // still down when the run ended
    std::string last_link_error;    // the source's last stream error, when it had one
    // Over the whole run.
    double fallback_rate() const;         // fallback pixels / textured pixels (unbiased)
    double fallback_rate_biased() const;
    double mean_psnr() const;             // over the compared frames (NaN: none)
    double min_psnr() const;
    int max_error() const;
    double mean_pop_rate() const;         // over the measured frame pairs (NaN: none)
    double max_pop_rate() const;
    int largest_pop() const;              // -1: none measured
    std::size_t pop_pairs() const;
    double frame_ms_quantile(double q) const;
    double mean_frame_ms() const;
    double cache_hit_ratio() const;       // (RAM + disk hits) / requests that found data anywhere
};

// Runs the viewer. Throws tools::Failure with a clear message on bad options or errors.
ViewerReport run_viewer(const ViewerOptions& options);

// Writes the per-frame records as CSV or JSON (by the file's extension), atomically.
void write_frame_stats(const ViewerReport& report, const std::string& path);
// The plot of fallback rate (unbiased and biased) and LoD bias over the run, as SVG.
void write_fallback_plot(const ViewerReport& report, const std::string& path, const std::string& title);
// A PSNR for people: "42.17 dB", or "lossless" for identical images (+inf dB).
std::string psnr_text(double db);
// A one-screen summary (frames, frame time, fallback, PSNR, latency, bytes, cache hits, and for a
// server store the seconds it was unreachable).
std::string summary_text(const ViewerReport& report);
// Throws Failure (exit kOutageExitCode) when the run was unserved for longer than max_outage_s;
// a negative max_outage_s never throws. `flag` names the setting in the message.
void check_outage(const ViewerReport& report, double max_outage_s, const std::string& flag);
// Throws Failure (exit 1) when not one tile arrived and the source answered with errors (every
// read of the store failed: a run that showed nothing of it is no success).
void check_tiles_arrived(const ViewerReport& report);

}  // namespace tessera::tools
