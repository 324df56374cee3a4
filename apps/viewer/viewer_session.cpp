// The viewer loop: render (feedback + VT pass) -> poll feedback -> runtime frame (requests,
// arrivals, decoding, uploads) -> poll the GPU's fallback counters. The render thread never waits
// on I/O: the runtime's sources and transcode pool own the slow work; readbacks are polled.
#include "viewer_session.hpp"

#include <GLFW/glfw3.h>
#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>
#include <thread>
#include <utility>

#include "atomic_file.hpp"
#include "failure.hpp"
#include "height_layer.hpp"
#include "png_write.hpp"
#include "progress.hpp"
#include "server_credentials.hpp"
#include "svg_plot.hpp"
#include "tessera/client/emulated_source.hpp"
#include "tessera/client/feedback_trace.hpp"
#include "tessera/client/gl/context.hpp"
#include "tessera/client/gl/frame_loop.hpp"
#include "tessera/client/gl/hud.hpp"
#include "tessera/client/gl/reference_renderer.hpp"
#include "tessera/client/measures.hpp"
#include "tessera/client/open_source.hpp"
#include "tessera/client/runtime.hpp"
#include "tessera/client/tile_source.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/scene/path.hpp"
#include "tessera/scene/scene.hpp"

namespace tessera::tools {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

// Free-flying camera for the windowed viewer: WASD move, Q/E down/up, left-drag looks, scroll
// changes speed, Space returns to the path, Esc quits.
struct FreeCamera {
    bool active = false;
    scene::Camera camera;
    double speed = 200;  // world units per second
    double last_x = 0, last_y = 0;
    bool dragging = false;
};

void scroll_callback(GLFWwindow* w, double, double dy) {
    auto* fc = static_cast<FreeCamera*>(glfwGetWindowUserPointer(w));
    fc->speed = std::clamp(fc->speed * std::pow(1.25, dy), 1.0, 1e7);
}

// The HUD's lines (windowed): frame time, bias and fallback, pages, tile latency, camera mode.
// server_line: the link to the server ("" for a local store); it goes first while the server is unreachable.
std::vector<std::string> hud_text(const FrameRecord& rec, float bias, std::uint32_t pool, const client::LatencyHistogram& lat,
                                  std::size_t in_flight, bool free_camera, const std::string& server_line, bool link_down) {
    const double fr = rec.fallback_rate();
    std::vector<std::string> lines{
        fmt::format("{:.1f} ms ({:.0f} fps)", rec.frame_ms, rec.frame_ms > 0 ? 1000.0 / rec.frame_ms : 0.0),
        fmt::format("bias {:.2f}  fallback {}", bias, std::isnan(fr) ? std::string("-") : fmt::format("{:.3f}%", 100 * fr)),
        fmt::format("pages {} wanted, {}/{} resident", rec.pages_wanted, rec.pages_resident, pool),
        fmt::format("uploaded {}  requested {}  in flight {}", rec.pages_uploaded, rec.pages_requested, in_flight),
        fmt::format("tile latency p50 {:.1f} ms  p99 {:.1f} ms", lat.quantile(0.5), lat.quantile(0.99)),
        free_camera ? std::string("free camera: WASD Q/E, drag, scroll; Space: path") : std::string("path (WASD: fly)"),
    };
    if (!server_line.empty()) lines.insert(link_down ? lines.begin() : lines.end() - 1, server_line);
    return lines;
}

void update_free_camera(GLFWwindow* win, FreeCamera& fc, const scene::Camera& path_camera, double dt) {
    const auto key = [&](int k) { return glfwGetKey(win, k) == GLFW_PRESS; };
    if (key(GLFW_KEY_SPACE)) fc.active = false;
    double mx = 0, my = 0;
    glfwGetCursorPos(win, &mx, &my);
    const bool drag = glfwGetMouseButton(win, GLFW_MOUSE_BUTTON_LEFT) == GLFW_PRESS;
    const bool moving = key(GLFW_KEY_W) || key(GLFW_KEY_A) || key(GLFW_KEY_S) || key(GLFW_KEY_D) || key(GLFW_KEY_Q) ||
                        key(GLFW_KEY_E);
    if (!fc.active && (moving || drag)) {
        fc.active = true;
        fc.camera = path_camera;
    }
    if (!fc.active) return;
    if (drag && fc.dragging) {
        fc.camera.yaw -= (mx - fc.last_x) * 0.004;
        fc.camera.pitch = std::clamp(fc.camera.pitch - (my - fc.last_y) * 0.004, -1.55, 1.55);
    }
    fc.dragging = drag;
    fc.last_x = mx;
    fc.last_y = my;
    const auto f = fc.camera.forward(), r = fc.camera.right();
    const double step = fc.speed * dt;
    auto move = [&](const scene::Vec3d& d, double s) {
        for (int i = 0; i < 3; ++i) fc.camera.position[i] += d[i] * s;
    };
    if (key(GLFW_KEY_W)) move(f, step);
    if (key(GLFW_KEY_S)) move(f, -step);
    if (key(GLFW_KEY_D)) move(r, step);
    if (key(GLFW_KEY_A)) move(r, -step);
    if (key(GLFW_KEY_E)) fc.camera.position[2] += step;
    if (key(GLFW_KEY_Q)) fc.camera.position[2] -= step;
}

// Watches the tile source's link once per frame. Time with the link down is counted as it passes;
// a change of state is reported (stderr, HUD) once it has held for kLinkDebounce, so a link that
// flaps (a server refusing the stream while the client retries) gives one line, not one per try.
constexpr std::chrono::milliseconds kLinkDebounce{500};

class LinkMonitor {
public:
    LinkMonitor(const client::TileSource& source, std::string server, Clock::time_point start)
        : source_(source), server_(std::move(server)), start_(start), last_(start), changed_(start) {}

    // Samples the link at `now`; returns the line to print when the reported state changes.
    std::string sample(Clock::time_point now) {
        link_ = source_.link();
        if (!link_.connected) unserved_ += now - last_;
        last_ = now;
        if (link_.connected != up_) {
            up_ = link_.connected;
            changed_ = now;
        }
        if (up_ == reported_up_ || now - changed_ < kLinkDebounce) return {};
        reported_up_ = up_;
        const double at = seconds(changed_ - start_);
        if (!up_) {
            ++outages_;
            down_since_ = changed_;
            return fmt::format("view: server {} unreachable at {:.1f} s ({}); drawing what is resident", server_, at,
                               link_.last_error.empty() ? "no stream" : link_.last_error);
        }
        return fmt::format("view: server {} back at {:.1f} s after {:.1f} s unreachable ({:.1f} s unserved so far)",
                           server_, at, seconds(changed_ - down_since_), unserved_s());
    }

    bool connected() const { return link_.connected; }  // as last sampled
    bool reported_down() const { return !reported_up_; }
    double outage_s(Clock::time_point now) const { return reported_up_ ? 0.0 : seconds(now - down_since_); }
    double unserved_s() const { return seconds(unserved_); }
    double watched_s() const { return seconds(last_ - start_); }
    std::uint32_t outages() const { return outages_; }
    const std::string& last_error() const { return link_.last_error; }

private:
    static double seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }
    const client::TileSource& source_;
    std::string server_;
    Clock::time_point start_, last_, changed_, down_since_;
    client::SourceLink link_;
    bool up_ = true, reported_up_ = true;
    Clock::duration unserved_{};
    std::uint32_t outages_ = 0;
};

// What `auto` picks for a store or layer: a block store's own blocks; for a data layer (`exact`),
// 1-channel 16-bit and float samples exactly; anything else RGBA8, and RGBA8 too for sRGB colour
// in a format the GPU would not decode from sRGB (a grey photo built as bc4, 16-bit grey).
client::PageFormat auto_page_format(Codec codec, std::uint32_t channels, storage::SampleType sample,
                                    storage::ColourSpace colour, bool exact) {
    std::optional<client::PageFormat> f = client::page_format_of(codec);
    if (!f && exact && channels == 1) {
        if (sample == storage::SampleType::u16) f = client::PageFormat::r16;
        if (sample == storage::SampleType::f16) f = client::PageFormat::r16f;
        if (sample == storage::SampleType::f32) f = client::PageFormat::r32f;
    }
    if (!f || (colour == storage::ColourSpace::srgb && !client::page_format_decodes_srgb(*f))) return client::PageFormat::rgba8;
    return *f;
}

client::PageFormat layer_page_format(const storage::LayerInfo& l) {
    return auto_page_format(l.codec, l.channels, l.sample_type, l.colour_space, true);
}

// A multi-layer store's pool: the layers after the first, the layer drawn, and lighting by a
// layer named "normal" (two channels).
void configure_layers(const storage::StoreInfo& info, const ViewerOptions& o, client::gl::RendererConfig& rc) {
    if (!info.layered()) {
        if (!o.show_layer.empty()) throw Failure(fmt::format("--show-layer '{}': the store has one layer", o.show_layer));
        if (!o.layer_formats.empty()) throw Failure(fmt::format("--layer-format '{}': the store has one layer", o.layer_formats[0]));
        return;
    }
    for (std::size_t i = 1; i < info.layers.size(); ++i)
        rc.more_layers.push_back({layer_page_format(info.layers[i]), info.layers[i].colour_space == storage::ColourSpace::srgb});
    std::string names;
    for (std::size_t i = 0; i < info.layers.size(); ++i) {
        names += (i ? ", " : "") + info.layers[i].name;
        if (info.layers[i].name == o.show_layer) rc.show_layer = std::uint32_t(i);
        if (i == 0 || o.unlit) continue;
        // A terrain's normals (two channels) light it; a glTF scene's material maps (the build's
        // layer names, docs/atlas.md, "Material layers") light its base colour.
        const std::string& name = info.layers[i].name;
        const auto layer = std::uint32_t(i);
        if (name == "normal" && info.layers[i].channels == 2) rc.normal_layer = layer;
        else if (name == "normal") rc.material.normal = layer;
        else if (name == "metallic_roughness") rc.material.metallic_roughness = layer;
        else if (name == "occlusion") rc.material.occlusion = layer;
        else if (name == "emissive") rc.material.emissive = layer;
    }
    if (rc.normal_layer) rc.material = {};  // a terrain: its normals light it
    if (!o.show_layer.empty() && info.layers[rc.show_layer].name != o.show_layer)
        throw Failure(fmt::format("--show-layer '{}': the store's layers are {}", o.show_layer, names));
    // Chosen formats; whether each fits its layer is checked with the pool (the error names it).
    for (const auto& spec : o.layer_formats) {
        const auto eq = spec.find('=');
        const std::string name = spec.substr(0, eq), format = eq == std::string::npos ? "" : spec.substr(eq + 1);
        const auto it = std::find_if(info.layers.begin(), info.layers.end(), [&](const auto& l) { return l.name == name; });
        if (eq == std::string::npos || it == info.layers.end())
            throw Failure(fmt::format("--layer-format '{}': expected NAME=FORMAT with NAME one of {}", spec, names));
        const auto i = std::size_t(it - info.layers.begin());
        client::PageFormat& f = i == 0 ? rc.page_format : rc.more_layers[i - 1].page_format;
        if (format == "auto") {  // as --page-format auto for the first layer
            f = i == 0 ? auto_page_format(it->codec, it->channels, it->sample_type, it->colour_space, false)
                       : layer_page_format(*it);
        } else if (const auto parsed = client::parse_page_format(format)) {
            f = *parsed;
        } else {
            throw Failure(fmt::format("--layer-format '{}': expected auto, rgba8, bc1, bc4, bc5, bc7, r16, r16f or r32f", spec));
        }
    }
    // The drawn layer's colour space decides the target's: data layers are shown as they are.
    rc.srgb = info.layers[rc.show_layer].colour_space == storage::ColourSpace::srgb;
}

double quantile(std::vector<double> v, double q) {
    if (v.empty()) return kNaN;
    std::sort(v.begin(), v.end());
    const auto i = static_cast<std::size_t>(std::clamp(q, 0.0, 1.0) * double(v.size() - 1) + 0.5);
    return v[std::min(i, v.size() - 1)];
}

// One run of the viewer: what run_viewer used to do in one function, by phase. Built in the
// constructor (source, GL, renderer, runtime, scene, reference, outputs), then run(): the
// loading screen, the path frame by frame, the settled view, the report.
class ViewerRun {
public:
    explicit ViewerRun(const ViewerOptions& o) : o_(o) {
        check_options();
        open_store();
        make_renderer();
        make_runtime();
        make_scene();
        make_reference();
        open_outputs();
        start_report();
    }
    ViewerReport run();

private:
    void check_options() const;
    void open_store();
    void make_renderer();
    void make_runtime();
    void make_scene();
    void make_reference();
    void open_outputs();
    void start_report();
    void wait_for_link();
    void watch_link(Clock::time_point now);
    bool settle(const scene::Camera& cam, std::uint32_t& settle_frames);
    void open_window();
    void path_frame(std::uint32_t f, ProgressBar& bar);
    FrameRecord& record(std::uint32_t f, double t, float bias, const client::FrameStats& s);
    void measure(std::uint32_t f, const scene::Camera& cam, FrameRecord& rec);
    void present(Clock::time_point t0, const FrameRecord& rec, float bias);
    void take_counters();
    void finish_report(std::uint32_t done);
    bool compared(std::uint32_t i) const {
        return reference_ && o_.psnr_every && (i % o_.psnr_every == o_.psnr_every - 1 || i + 1 == frames_);
    }
    client::gl::VtRenderer& r() { return *renderer_; }
    client::Runtime& rt() { return *runtime_; }

    const ViewerOptions& o_;
    // Declared in the order they are made: destroyed in reverse (the runtime before the renderer it
    // uploads into, GL objects before the context, the source last).
    client::SourceUrl loc_;
    std::unique_ptr<client::TileSource> source_;
    std::string store_name_;
    bool errors_only_ = false;  // the last settle() gave up: its view's reads only failed
    std::unique_ptr<client::gl::GlContext> ctx_;
    GLFWwindow* win_ = nullptr;
    storage::StoreInfo info_;
    std::uint32_t pool_ = 0;  // pages in the GPU pool (ViewerOptions::pool, resolved once the store is open)
    client::gl::RendererConfig rc_;
    std::unique_ptr<client::gl::VtRenderer> renderer_;
    std::unique_ptr<client::Runtime> runtime_;
    client::TextureId texture_ = 0;
    std::optional<client::gl::FrameLoop> loop_;
    std::optional<scene::Scene> scene_;
    std::optional<scene::CameraPath> path_;
    std::string displaced_by_;  // the layer the terrain follows, for the summary
    std::optional<std::string> store_scene_;  // the scene that travels with the store (--scene auto)
    bool atlas_scene_ = false;                // an atlas OBJ scene (from the store or --scene FILE)
    std::string scene_label_;                 // for the summary
    std::unique_ptr<client::gl::ReferenceRenderer> reference_;
    std::unique_ptr<client::TraceWriter> trace_;
    std::unique_ptr<client::gl::Hud> hud_;

    std::uint32_t frames_ = 0;
    std::vector<std::uint32_t> png_frames_;
    ViewerReport rep_;
    std::map<std::uint64_t, std::size_t> by_render_frame_;  // renderer frame number -> record
    std::vector<client::gl::FrameCounters> counters_;
    std::unique_ptr<LinkMonitor> link_monitor_;
    bool replaced_reported_ = false;  // the store was rebuilt on its server: said once
    ProgressBar* shown_bar_ = nullptr;  // cleared before a link line, redrawn by its next update
    double clock_s_ = 0;                // the runtime's clock: path time plus the settling frames before it
    double path_clock_start_ = 0;
    FreeCamera free_cam_;
    std::vector<std::string> hud_lines_;
    Clock::time_point start_, last_title_;
    double lat_count_ = 0, lat_sum_ms_ = 0;
    scene::Camera prev_cam_;  // the last frame's camera and time, for motion prefetch
    double prev_t_ = 0;
    // Popping: before the runtime's uploads for a compared frame, what that frame would show
    // without them (VtRenderer::render_preview); set for the next frame only.
    std::vector<std::uint8_t> preview_, next_preview_;
    std::uint32_t preview_frame_ = UINT32_MAX, next_preview_frame_ = UINT32_MAX;
};

void ViewerRun::check_options() const {
    const ViewerOptions& o = o_;
    if (o.width < 16 || o.height < 16 || o.width > 8192 || o.height > 8192)
        throw Failure(fmt::format("--size {}x{}: each side must be 16..8192", o.width, o.height));
    if (o.feedback_scale < 1 || o.feedback_scale > 64) throw Failure("--feedback-scale must be 1..64");
    if (o.pool != 0 && o.pool < 16) throw Failure("--pool must be at least 16 pages");
    if (!(o.fps > 0) || o.fps > 1000) throw Failure("--fps must be in (0, 1000]");
    if (o.anisotropy < 1 || o.anisotropy > 8) throw Failure("--anisotropy must be 1..8");
}

void ViewerRun::open_store() {
    const ViewerOptions& o = o_;
    // Where tiles come from (client::open_source: a store file, or grpc[s]://TARGET/NAME).
    auto parsed = client::parse_source_url(o.store);
    if (!parsed) throw Failure(fmt::format("--store {}", parsed.error().message));
    loc_ = *parsed;
    client::SourceOptions source_options;
    source_options.auth_token = o.auth_token;
    if (loc_.tls) source_options.tls_roots_pem = tls_roots_pem(o.tls_ca_file);
    source_options.link.latency = std::chrono::microseconds(std::llround(o.link_latency_ms * 1000));
    source_options.link.jitter = std::chrono::microseconds(std::llround(o.link_jitter_ms * 1000));
    source_options.link.bandwidth_bits_per_s = o.link_bandwidth_bits_per_s;
    source_options.link_seed = o.link_seed;
    auto opened = client::open_source(loc_, source_options);
    if (!opened) throw Failure(opened.error().message);
    source_ = std::move(opened->source);
    store_name_ = opened->store;

    // GL first: the renderer needs the store's geometry, the runtime needs the renderer.
    auto ctx = o.headless ? client::gl::GlContext::create_headless()
                          : client::gl::GlContext::create_window(int(o.width), int(o.height), "tessera view");
    if (!ctx) throw Failure(ctx.error().message);
    ctx_ = std::move(*ctx);
    ctx_->make_current();
    win_ = ctx_->window();

    // The store's geometry: bind through the source (a remote store is asked for its metadata;
    // a server that is down is an error here, before anything is drawn).
    auto info = source_->bind(0, store_name_);
    if (!info) throw Failure(fmt::format("--store '{}': {}", o.store, info.error().message));
    if (info->channels < 1 || info->channels > 4) throw Failure("the store has an unsupported channel count");
    info_ = *info;

    // The scene: with --scene auto, the one that travels with the store, if it has one.
    if (o.scene == "auto") {
        auto sc = source_->scene(store_name_);
        if (!sc) throw Failure(fmt::format("--store '{}': its scene: {}", o.store, sc.error().message));
        store_scene_ = std::move(*sc);
    }
    atlas_scene_ = store_scene_.has_value() || (o.scene != "auto" && o.scene != "terrain");
}

void ViewerRun::make_renderer() {
    const ViewerOptions& o = o_;
    client::gl::RendererConfig& rc = rc_;
    rc.width = o.width;
    rc.height = o.height;
    rc.feedback_scale = o.feedback_scale;
    rc.filter = o.filter;
    rc.max_anisotropy = o.anisotropy;
    rc.feedback_prefetch_lod = o.prefetch_lod;
    rc.feedback_guard_band = o.guard_band;
    if (o.pool != 0) {
        pool_ = o.pool;
    } else {
        std::uint64_t pages = 0;
        for (const auto& level : info_.levels) pages += std::uint64_t(level.tiles_x) * level.tiles_y;
        pool_ = static_cast<std::uint32_t>(std::clamp<std::uint64_t>(pages, 16, kDefaultPoolPages));
    }
    rc.pool_slots = pool_;
    rc.tile_size = info_.tile_size();
    rc.border = info_.border;
    rc.srgb = info_.colour_space == storage::ColourSpace::srgb;
    // An OBJ scene's store with alpha holds cut-outs (an atlas of leaves, fences): discard their
    // backgrounds. A terrain's alpha stays what the image shows.
    rc.alpha_test = atlas_scene_ && info_.has_alpha;
    if (o.page_format == "auto") {
        // A block-codec store's own blocks go to the GPU as they are (unless they would lose the
        // sRGB decode); anything else as RGBA8.
        rc.page_format = auto_page_format(info_.codec, info_.channels, info_.sample_type, info_.colour_space, false);
    } else {
        const auto f = client::parse_page_format(o.page_format);
        if (!f) throw Failure(fmt::format("--page-format '{}': expected auto, rgba8, bc1, bc4, bc5, bc7, r16, r16f or r32f", o.page_format));
        rc.page_format = *f;
    }
    configure_layers(info_, o, rc);
    auto renderer = client::gl::VtRenderer::create(rc);
    if (!renderer) throw Failure(renderer.error().message);
    renderer_ = std::move(*renderer);
}

void ViewerRun::make_runtime() {
    const ViewerOptions& o = o_;
    client::RuntimeConfig cfg;
    cfg.residency.pool_slots = pool_;
    // Motion prefetch: one feedback in motion_prefetch_every sees the view itself; its pages stay.
    if (o.motion_prefetch_ms > 0) cfg.residency.kept_frames = std::clamp<std::uint32_t>(o.motion_prefetch_every, 1, 64);
    cfg.bias = o.bias;
    cfg.fade_ms = o.fade_ms;
    cfg.ram_cache_bytes = o.ram_cache_bytes;
    cfg.disk_cache_dir = o.disk_cache_dir;
    cfg.disk_cache_bytes = o.disk_cache_bytes;
    cfg.transcode_threads = o.transcode_threads;
    cfg.upload_pages_per_frame = o.upload_pages_per_frame;
    cfg.upload_bytes_per_frame = std::size_t(o.upload_pages_per_frame) * r().pool_format().upload_bytes(info_.tile_size());
    auto runtime = client::Runtime::create(cfg, r(), &r().page_staging());
    if (!runtime) throw Failure(runtime.error().message);
    runtime_ = std::move(*runtime);
    auto texture = rt().add_texture(*source_, store_name_);
    if (!texture) throw Failure(fmt::format("--store '{}': {}", o.store, texture.error().message));
    // The disk cache keys tiles by store name (docs/client.md, "Arrivals and decoding"): a store
    // file named by a path, or a procedural spec, has none, and is read from where it is.
    const bool cacheable_name = !store_name_.empty() && store_name_[0] != '.' && store_name_.find("..") == std::string::npos &&
                                store_name_.find_first_not_of("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_.-") ==
                                    std::string::npos;  // DiskTileCache::valid_store_name
    if (!o.disk_cache_dir.empty() && !cacheable_name)
        fmt::print(stderr, "note: --disk-cache is not used for '{}': a store named by a path or a procedural spec is read from "
                           "where it is (the cache keys a server's stores by name)\n",
                   store_name_);
    texture_ = *texture;
    if (auto st = r().add_texture(texture_, *rt().texture_info(texture_)); !st.ok()) throw Failure(st.error().message);
    loop_.emplace(r(), rt());
}

void ViewerRun::make_scene() {
    const ViewerOptions& o = o_;
    const storage::StoreInfo& info = info_;
    Result<scene::Scene> sc = [&]() -> Result<scene::Scene> {
        if (store_scene_) return scene::parse_obj_scene(*store_scene_, "the store's scene", info.width, info.height);
        if (atlas_scene_) return scene::load_obj_scene(o.scene, info.width, info.height);
        scene::TerrainOptions t;
        t.vt_width = info.width;
        t.vt_height = info.height;
        t.displacement = o.displacement;
        // Keep the vertex count sane for huge textures: at most 64 chunks per side.
        while (std::max(info.width, info.height) / t.chunk_texels > 64) t.chunk_texels *= 2;
        // A store with a height layer: the ground follows it, one quad per height sample up to
        // 128 quads per chunk and about 4 M vertices (the normal layer lights the detail between).
        if (const auto layer = height_layer(info); layer && o.displacement > 0) {
            const std::uint64_t chunks = (std::max(info.width, info.height) + t.chunk_texels - 1) / t.chunk_texels;
            // At most about 4 M vertices in all (64 chunks a side get 31 quads each).
            t.quads_per_chunk = std::uint32_t(std::clamp<double>(std::floor(2048.0 / double(chunks)) - 1, 16, 128));
            auto h = read_height_layer(*source_, 0, info, *layer,
                                       std::uint32_t(std::min<std::uint64_t>(chunks * t.quads_per_chunk, 1u << 16)));
            if (!h) return h.error();
            t.heights = h->field;
            displaced_by_ = fmt::format("layer {} (level {}, {}x{} samples, {} tiles)", info.layers[*layer].name, h->level,
                                        h->field->width, h->field->height, h->tiles);
        }
        return scene::make_terrain(t);
    }();
    if (!sc) throw Failure(fmt::format("--scene '{}': {}", o.scene, sc.error().message));
    scene_.emplace(std::move(*sc));
    std::size_t triangles = 0;
    for (const auto& c : scene_->chunks) triangles += c.indices.size() / 3;
    scene_label_ = !atlas_scene_ ? std::string("terrain")
                   : store_scene_ ? fmt::format("atlas, travelling with the store ({} triangles, {} objects)", triangles, scene_->chunks.size())
                                  : fmt::format("atlas {} ({} triangles, {} objects)", o.scene, triangles, scene_->chunks.size());
    if (atlas_scene_ && info_.has_alpha) scene_label_ += ", cut-outs at alpha 0.5";
    if (rc_.material.any() && rc_.show_layer == 0) {  // the maps that light it (docs/renderer.md, "Materials")
        std::string maps;
        for (const std::uint32_t layer : rc_.sampled_layers()) maps += (maps.empty() ? "" : ", ") + info_.layers[layer].name;
        scene_label_ += ", lit by its material maps (" + maps + ")";
    }
    if (auto st = r().set_scene(*scene_, texture_); !st.ok()) throw Failure(st.error().message);
    auto path = scene::CameraPath::builtin_or_file(o.path, *scene_);
    if (!path) throw Failure(fmt::format("--path: {}", path.error().message));
    path_.emplace(std::move(*path));
}

// The reference renderer, for PSNR.
void ViewerRun::make_reference() {
    const ViewerOptions& o = o_;
    if (o.psnr_every == 0) return;
    const std::string ref_store = !o.reference_store.empty() ? o.reference_store : loc_.remote ? std::string() : loc_.store;
    if (ref_store.empty()) throw Failure("PSNR needs a local copy of the store: --reference-store FILE (the store is remote)");
    // The reference samples GL mip levels, which halve rounding down; a store's levels round up
    // (257 -> 129): said before the reference is decoded, with what to do instead.
    for (std::size_t l = 1; l < info_.levels.size(); ++l) {
        const auto& up = info_.levels[l - 1];
        const auto& lv = info_.levels[l];
        if (lv.width != std::max(1u, up.width / 2) || lv.height != std::max(1u, up.height / 2))
            throw Failure(fmt::format("--psnr-every: the reference renderer needs levels that halve exactly (power-of-two "
                                      "sides); this store is {}x{} (level {} is {}x{}): view it without --psnr-every",
                                      info_.width, info_.height, l, lv.width, lv.height));
    }
    if (!o.reference_store.empty()) {
        // Any build of the same image will do (a lossless one measures the codec's error too),
        // but another image gives a PSNR of nothing: its size must be the store's.
        auto reader = storage::StoreReader::open(ref_store);
        if (!reader) throw Failure(fmt::format("--reference-store: {}", reader.error().message));
        const storage::StoreInfo& ri = (*reader)->info();
        if (ri.width != info_.width || ri.height != info_.height)
            throw Failure(fmt::format("--reference-store {} is {}x{}, the store viewed {}x{}: not a copy of it", ref_store, ri.width,
                                      ri.height, info_.width, info_.height));
    }
    if (o.progress) fmt::print("reference: decoding {} ...\n", ref_store);
    std::fflush(stdout);
    auto levels = client::decode_store_levels(ref_store, 16384, client::PageFormat::rgba8, rc_.show_layer);
    if (!levels) throw Failure(fmt::format("reference: {}", levels.error().message));
    // The layers that light the colour, decoded the same way.
    std::vector<client::gl::ReferenceRenderer::Levels> layers;
    for (const std::uint32_t layer : rc_.sampled_layers()) {
        auto n = client::decode_store_levels(ref_store, 16384, client::PageFormat::rgba8, layer);
        if (!n) throw Failure(fmt::format("reference: {}", n.error().message));
        layers.push_back(std::move(*n));
    }
    auto ref = client::gl::ReferenceRenderer::create(rc_, *levels, layers);
    if (!ref) throw Failure(ref.error().message);  // "reference: ..." already
    reference_ = std::move(*ref);
    if (auto st = reference_->set_scene(*scene_); !st.ok()) throw Failure(st.error().message);
}

void ViewerRun::open_outputs() {
    const ViewerOptions& o = o_;
    std::error_code ec;
    if (!o.out_dir.empty()) {
        fs::create_directories(o.out_dir, ec);
        if (ec || !fs::is_directory(o.out_dir)) throw Failure(fmt::format("--out '{}': cannot create the directory", o.out_dir));
    }
    if (!o.trace_file.empty()) {
        auto t = client::TraceWriter::create(o.trace_file);
        if (!t) throw Failure(t.error().message);
        trace_ = std::move(*t);
    }
    frames_ = o.frames ? o.frames : static_cast<std::uint32_t>(std::ceil(path_->duration() * o.fps)) + 1;
    if (!o.out_dir.empty() && o.png_count > 0)
        for (std::uint32_t i = 1; i <= o.png_count; ++i) png_frames_.push_back(frames_ * i / (o.png_count + 1));
}

void ViewerRun::start_report() {
    const client::gl::RendererConfig& rc = rc_;
    rep_.displaced_by = displaced_by_;
    rep_.scene = scene_label_;
    rep_.renderer = ctx_->renderer();
    rep_.page_format = rc.page_format;
    rep_.pool_pages = rc.pool_slots;
    // Every layer's page, with its second level where the atlas has one.
    rep_.gpu_page_bytes = 0;
    for (std::size_t i = 0; i <= rc.more_layers.size(); ++i) {
        const client::PageFormat f = i == 0 ? rc.page_format : rc.more_layers[i - 1].page_format;
        rep_.gpu_page_bytes +=
            client::page_bytes(f, rc.tile_size) + (rc.has_second_level() ? client::page_bytes(f, rc.tile_size / 2) : 0);
        if (info_.layered()) rep_.layers.push_back(info_.layers[i].name + " " + std::string(client::to_string(f)));
    }
    rep_.pool_texels = std::uint64_t(rc.pool_slots) * rc.tile_size * rc.tile_size;
    rep_.source = source_->describe();
    rep_.frames.resize(frames_);
    rep_.remote = loc_.remote;
}

void ViewerRun::take_counters() {
    for (const auto& c : counters_) {
        auto it = by_render_frame_.find(c.frame);
        if (it == by_render_frame_.end()) continue;
        auto& rec = rep_.frames[it->second];
        rec.counted = true;
        rec.textured_pixels = c.textured_pixels;
        rec.fallback_unbiased = c.fallback_unbiased;
        rec.fallback_biased = c.fallback_biased;
        by_render_frame_.erase(it);
    }
    counters_.clear();
}

// The stream opens in the background once bind() has reached the server: start with it open, so
// that a healthy run has no unserved time. If it does not open, the wait counts as unserved.
void ViewerRun::wait_for_link() {
    const auto link_start = Clock::now();
    while (!source_->available() && std::chrono::duration<double>(Clock::now() - link_start).count() < o_.connect_wait_s)
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    link_monitor_ = std::make_unique<LinkMonitor>(*source_, loc_.remote ? loc_.target : loc_.store, link_start);
}

void ViewerRun::watch_link(Clock::time_point now) {
    std::string line = link_monitor_->sample(now);
    if (const std::uint64_t v = rt().texture_replaced(texture_); v != 0 && !replaced_reported_) {
        replaced_reported_ = true;
        line += fmt::format("{}view: store {} was replaced by version {:016x} (this view has {:016x}); drawing what is "
                            "resident, restart the viewer to see the new version",
                            line.empty() ? "" : "\n", store_name_, v, rt().texture_info(texture_)->store_id);
    }
    if (line.empty()) return;
    if (shown_bar_) shown_bar_->finish();
    std::fflush(stdout);
    fmt::print(stderr, "{}\n", line);
    std::fflush(stderr);
}

// Renders `cam` until it is fully resident and faded in (or o.warmup_timeout_s passes): the
// loading screen before the path, and the settled view after it (FrameLoop::settle). Counts its
// frames in `settle_frames`; the runtime's clock moves 1/fps a frame.
bool ViewerRun::settle(const scene::Camera& cam, std::uint32_t& settle_frames) {
    // A view whose reads only fail never settles: once errors keep coming and no page has
    // arrived for kErrorsOnly, waiting out the whole timeout shows nothing more.
    constexpr std::chrono::seconds kErrorsOnly{2};
    std::uint64_t arrived = rt().summary().pages_arrived(), errors = rt().summary().source_errors();
    Clock::time_point progress = Clock::now();
    const auto held = loop_->settle(
        cam, std::chrono::duration<double>(o_.warmup_timeout_s),
        [&] {
            watch_link(Clock::now());
            rt().set_time(clock_s_);
            clock_s_ += 1.0 / o_.fps;
        },
        [&] {
            const auto& s = rt().summary();
            const auto now = Clock::now();
            if (s.pages_arrived() != arrived) {
                arrived = s.pages_arrived();
                errors = s.source_errors();
                progress = now;
                return false;
            }
            errors_only_ = now - progress >= kErrorsOnly && s.source_errors() >= errors + 2;  // errors, again and again
            return errors_only_;
        });
    settle_frames += held.frames;
    rt().frame_without_feedback();
    return held.settled;
}

void ViewerRun::open_window() {
    glfwSetWindowUserPointer(win_, &free_cam_);
    glfwSetScrollCallback(win_, scroll_callback);
    auto made = client::gl::Hud::create();
    if (!made) throw Failure(made.error().message);
    hud_ = std::move(*made);
}

ViewerReport ViewerRun::run() {
    wait_for_link();
    if (o_.warmup && !win_) {
        // The loading screen: the path's first view until it is fully resident.
        const auto w0 = Clock::now();
        rep_.warmup_complete = settle(path_->at(0), rep_.warmup_frames);
        rep_.warmup_errors_only = errors_only_;
        rep_.warmup_ms = std::chrono::duration<double, std::milli>(Clock::now() - w0).count();
    }
    path_clock_start_ = clock_s_;
    if (win_) open_window();
    ProgressBar bar("view", o_.progress && o_.headless);
    shown_bar_ = &bar;
    start_ = last_title_ = Clock::now();
    std::uint32_t done = 0;
    for (std::uint32_t f = 0; f < frames_ || (win_ && o_.frames == 0); ++f) {
        if (win_) {
            glfwPollEvents();
            if (glfwWindowShouldClose(win_) || glfwGetKey(win_, GLFW_KEY_ESCAPE) == GLFW_PRESS) break;
        }
        path_frame(f, bar);
        done = f + 1;
    }
    bar.finish();
    shown_bar_ = nullptr;
    finish_report(done);
    return std::move(rep_);
}

// One frame of the path: draw, hand the runtime its feedback, record, measure, show.
void ViewerRun::path_frame(std::uint32_t f, ProgressBar& bar) {
    const ViewerOptions& o = o_;
    const auto t0 = Clock::now();
    watch_link(t0);
    // Headless: path time advances 1/fps per frame. Windowed: wall time, looping the path.
    const double t = win_ ? std::chrono::duration<double>(t0 - start_).count() : double(f) / o.fps;
    scene::Camera cam = win_ ? path_->at(std::fmod(t, std::max(path_->duration(), 1e-9))) : path_->at(t);
    if (win_) {
        update_free_camera(win_, free_cam_, cam, 1.0 / 60.0);
        if (free_cam_.active) cam = free_cam_.camera;
    }
    const float bias = rt().lod_bias();
    rt().set_time(path_clock_start_ + t);  // after the warm-up's frames
    if (o.motion_prefetch_ms > 0 && f > 0 && f % std::max<std::uint32_t>(o.motion_prefetch_every, 1) == 0 && t > prev_t_)
        if (const auto ahead = scene::extrapolate(prev_cam_, prev_t_, cam, t, o.motion_prefetch_ms / 1000.0))
            r().set_feedback_camera(*ahead);
    prev_cam_ = cam;
    prev_t_ = t;
    // Measured, not timed: the next frame's camera drawn before this frame's uploads.
    double preview_ms = 0;
    const auto step = loop_->step(cam, [&](std::uint64_t) {
        if (win_ || f + 1 >= frames_ || !compared(f + 1)) return;
        const auto p0 = Clock::now();
        next_preview_ = r().render_preview(path_->at(double(f + 1) / o.fps));
        next_preview_frame_ = f + 1;
        preview_ms = std::chrono::duration<double, std::milli>(Clock::now() - p0).count();
    });
    if (const auto* fb = step.feedback; fb && trace_) {
        client::TraceFrame tf{fb->frame, t, fb->bias, fb->width, fb->height, fb->ids};
        if (auto st = trace_->write(tf); !st.ok()) throw Failure(st.error().message);
    }
    counters_.assign(loop_->counters().begin(), loop_->counters().end());
    FrameRecord& rec = record(f, t, bias, *step.stats);
    by_render_frame_[step.frame] = f;
    take_counters();
    rec.frame_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count() - preview_ms;
    measure(f, cam, rec);  // outside the timed part of the frame: it waits for the GPU
    if (win_) present(t0, rec, bias);
    std::swap(preview_, next_preview_);
    preview_frame_ = std::exchange(next_preview_frame_, UINT32_MAX);
    if (o.pace && !win_) std::this_thread::sleep_until(t0 + std::chrono::duration<double>(1.0 / o.fps));
    bar.update(double(f + 1) / frames_, fmt::format("frame {}/{}", f + 1, frames_));
}

FrameRecord& ViewerRun::record(std::uint32_t f, double t, float bias, const client::FrameStats& s) {
    if (f >= rep_.frames.size()) rep_.frames.emplace_back();  // windowed, unbounded
    auto& rec = rep_.frames[f];
    rec.frame = f;
    rec.time_s = t;
    rec.pages_wanted = s.pages_wanted;
    rec.pages_resident = s.pages_resident;
    rec.pages_requested = s.pages_requested;
    rec.pages_uploaded = s.pages_uploaded;
    rec.pages_evicted = s.pages_evicted;
    rec.pages_rescued = s.pages_rescued;
    rec.bias = bias;
    rec.bytes_received = s.bytes_received;
    rec.connected = link_monitor_->connected();
    rec.unserved_s = link_monitor_->unserved_s();
    const auto& lat = rt().summary().latency();
    const double n = double(lat.count()), sum = lat.mean_ms() * n;
    if (n > lat_count_) rec.tile_latency_ms = (sum - lat_sum_ms_) / (n - lat_count_);
    lat_count_ = n;
    lat_sum_ms_ = sum;
    return rec;
}

// PNGs and PSNR/popping against the reference, for the frames asked for.
void ViewerRun::measure(std::uint32_t f, const scene::Camera& cam, FrameRecord& rec) {
    const ViewerOptions& o = o_;
    const bool png = std::find(png_frames_.begin(), png_frames_.end(), f) != png_frames_.end();
    const bool psnr = compared(f);
    if (!png && !psnr) return;
    const auto color = r().read_color();
    if (png) {
        const std::string file = (fs::path(o.out_dir) / fmt::format("frame_{:05}.png", f)).string();
        write_png(file, o.width, o.height, color);
        rep_.pngs.push_back(file);
    }
    if (!psnr) return;
    reference_->render(cam);
    const auto ref = reference_->read_color();
    const auto err = client::compare_images(color, ref, o.width, o.height);
    rec.psnr = err.psnr;
    rec.max_error = err.max_error;
    if (preview_frame_ == f) {
        // The same camera before and after: the reference's change is none.
        const auto pops = client::count_pops(preview_, color, ref, ref, o.width, o.height);
        if (pops.pixels > 0) {
            rec.pop_rate = pops.rate();
            rec.pop_largest = pops.largest;
        }
    }
    if (png) {
        const std::string file = (fs::path(o.out_dir) / fmt::format("reference_{:05}.png", f)).string();
        write_png(file, o.width, o.height, ref);
        rep_.pngs.push_back(file);
    }
}

// Windowed: the frame on screen, the HUD and the title.
void ViewerRun::present(Clock::time_point t0, const FrameRecord& rec, float bias) {
    const ViewerOptions& o = o_;
    const auto& lat = rt().summary().latency();
    LinkMonitor& link = *link_monitor_;
    int ww = 0, wh = 0;
    glfwGetFramebufferSize(win_, &ww, &wh);
    r().present(ww, wh);
    if (o.hud) {
        // Refreshed four times a second, like the title: readable, and no per-frame formatting.
        if (hud_lines_.empty() || t0 - last_title_ > std::chrono::milliseconds(250)) {
            std::string server;
            if (loc_.remote)
                server = link.reported_down() ? fmt::format("SERVER UNREACHABLE for {:.0f} s  (unserved {:.1f} s)",
                                                            link.outage_s(t0), link.unserved_s())
                                              : fmt::format("server connected  (unserved {:.1f} s)", link.unserved_s());
            hud_lines_ = hud_text(rec, bias, pool_, lat, rt().in_flight(), free_cam_.active, server, link.reported_down());
        }
        hud_->draw(hud_lines_, ww, wh, ww >= 1800 ? 3 : 2);
    }
    ctx_->swap_buffers();
    if (t0 - last_title_ > std::chrono::milliseconds(250)) {
        last_title_ = t0;
        const double fr = rec.fallback_rate();
        glfwSetWindowTitle(win_, fmt::format("tessera view{} | {:.1f} ms | bias {:.2f} | fallback {} | pages {}/{} | "
                                             "latency p50 {:.1f} ms | {}",
                                             link.reported_down() ? " | SERVER UNREACHABLE" : "", rec.frame_ms, bias,
                                             std::isnan(fr) ? std::string("-") : fmt::format("{:.2f}%", 100 * fr),
                                             rec.pages_resident, pool_, lat.quantile(0.5),
                                             free_cam_.active ? "free camera (Space: path)" : "path (WASD: fly)")
                                     .c_str());
    }
}

// The run's totals, and the PSNR of the path's last view once it has settled.
void ViewerRun::finish_report(std::uint32_t done) {
    const ViewerOptions& o = o_;
    rep_.frames.resize(done);
    r().finish(&counters_, nullptr);
    take_counters();
    const auto end = Clock::now();
    rep_.wall_s = std::chrono::duration<double>(end - start_).count();
    watch_link(end);
    rep_.run_s = link_monitor_->watched_s();
    rep_.unserved_s = link_monitor_->unserved_s();
    rep_.outages = link_monitor_->outages();
    rep_.down_at_end = !link_monitor_->connected();
    rep_.last_link_error = link_monitor_->last_error();
    rep_.summary = rt().summary();
    rep_.disk_cache = rt().disk_cache();
    rep_.fade_frames = std::uint32_t(std::ceil(double(o.fade_ms) / 1000.0 * o.fps));
    rep_.predicted_feedback_frames = r().stats().predicted_feedback;
    rep_.page_bytes_copied = r().stats().page_bytes_copied;
    // PSNR once settled: the path's last view held until it is resident and faded in.
    if (reference_ && !win_ && done == frames_ && done > 0) {
        const scene::Camera last = path_->at(double(done - 1) / o.fps);
        clock_s_ = path_clock_start_ + double(done) / o.fps;  // the renderer's clock after the path
        rep_.settled_complete = settle(last, rep_.settled_frames);
        const auto color = r().read_color();
        reference_->render(last);
        const auto err = client::compare_images(color, reference_->read_color(), o.width, o.height);
        rep_.settled_psnr = err.psnr;
        rep_.settled_max_error = err.max_error;
    }
    if (trace_) {
        if (auto st = trace_->close(); !st.ok()) throw Failure(st.error().message);
    }
}

}  // namespace

ViewerReport run_viewer(const ViewerOptions& o) {
    ViewerRun run(o);
    return run.run();
}

double ViewerReport::fallback_rate() const {
    std::uint64_t fb = 0, px = 0;
    for (const auto& f : frames) fb += f.fallback_unbiased, px += f.textured_pixels;
    return px ? double(fb) / double(px) : kNaN;
}
double ViewerReport::fallback_rate_biased() const {
    std::uint64_t fb = 0, px = 0;
    for (const auto& f : frames) fb += f.fallback_biased, px += f.textured_pixels;
    return px ? double(fb) / double(px) : kNaN;
}
double ViewerReport::mean_psnr() const {
    double s = 0;
    int n = 0;
    for (const auto& f : frames)
        if (!std::isnan(f.psnr)) s += std::min(f.psnr, 99.0), ++n;  // identical frames count as 99 dB
    return n ? s / n : kNaN;
}
namespace {
// The smallest (or largest) of a per-frame measure over the frames that have it (NaN: none).
double extreme(const std::vector<FrameRecord>& frames, double FrameRecord::*measure, bool largest) {
    double m = kNaN;
    for (const auto& f : frames) {
        const double v = f.*measure;
        if (!std::isnan(v)) m = std::isnan(m) ? v : largest ? std::max(m, v) : std::min(m, v);
    }
    return m;
}
}  // namespace

double ViewerReport::min_psnr() const { return extreme(frames, &FrameRecord::psnr, false); }
double ViewerReport::mean_pop_rate() const {
    double s = 0;
    std::size_t n = 0;
    for (const auto& f : frames)
        if (!std::isnan(f.pop_rate)) s += f.pop_rate, ++n;
    return n ? s / double(n) : kNaN;
}
double ViewerReport::max_pop_rate() const { return extreme(frames, &FrameRecord::pop_rate, true); }
int ViewerReport::largest_pop() const {
    int m = -1;
    for (const auto& f : frames) m = std::max(m, f.pop_largest);
    return m;
}
std::size_t ViewerReport::pop_pairs() const {
    return std::size_t(std::count_if(frames.begin(), frames.end(), [](const auto& f) { return !std::isnan(f.pop_rate); }));
}
int ViewerReport::max_error() const {
    int m = -1;
    for (const auto& f : frames) m = std::max(m, f.max_error);
    return m;
}
double ViewerReport::frame_ms_quantile(double q) const {
    std::vector<double> v;
    for (const auto& f : frames) v.push_back(f.frame_ms);
    return quantile(std::move(v), q);
}
double ViewerReport::mean_frame_ms() const {
    double s = 0;
    for (const auto& f : frames) s += f.frame_ms;
    return frames.empty() ? kNaN : s / double(frames.size());
}
double ViewerReport::cache_hit_ratio() const {
    std::uint64_t hits = 0, all = 0;
    for (std::size_t l = 0; l < client::kMaxLevels; ++l) {
        hits += summary.ram_hits()[l] + summary.disk_hits()[l];
        all += summary.ram_hits()[l] + summary.disk_hits()[l] + summary.network()[l];
    }
    return all ? double(hits) / double(all) : kNaN;
}

void write_frame_stats(const ViewerReport& rep, const std::string& path) {
    const bool json = fs::path(path).extension() == ".json";
    const auto num = [](double v) { return std::isfinite(v) ? fmt::format("{:.6g}", v) : std::string(""); };
    const auto jnum = [](double v) { return std::isfinite(v) ? fmt::format("{:.6g}", v) : std::string("null"); };
    write_file_atomically(path, [&](std::ostream& out) {
        if (json)
            out << "{\"renderer\": \"" << rep.renderer << "\", "
                << fmt::format("\"gpu_pool\": {{\"page_format\": \"{}\", \"page_bytes\": {}, \"pages\": {}, \"texels\": {}, "
                               "\"layers\": [{}]}}, ",
                               client::to_string(rep.page_format), rep.gpu_page_bytes, rep.pool_pages, rep.pool_texels,
                               [&] {
                                   std::string l;
                                   for (const auto& x : rep.layers) l += (l.empty() ? "\"" : ", \"") + x + "\"";
                                   return l;
                               }())
                << "\"frames\": [\n";
        else
            out << "frame,time_s,frame_ms,pages_wanted,pages_resident,pages_requested,pages_uploaded,pages_evicted,"
                   "lod_bias,textured_pixels,fallback_pixels,fallback_pixels_biased,fallback_rate,fallback_rate_biased,"
                   "tile_latency_ms,bytes_received,psnr_db,max_error,connected,unserved_s,pop_rate,pop_largest,pages_rescued\n";
        for (std::size_t i = 0; i < rep.frames.size(); ++i) {
            const auto& f = rep.frames[i];
            if (json)
                out << fmt::format(
                    "{{\"frame\": {}, \"time_s\": {}, \"frame_ms\": {}, \"pages_wanted\": {}, \"pages_resident\": {}, "
                    "\"pages_requested\": {}, \"pages_uploaded\": {}, \"pages_evicted\": {}, \"lod_bias\": {}, "
                    "\"textured_pixels\": {}, \"fallback_pixels\": {}, \"fallback_pixels_biased\": {}, "
                    "\"fallback_rate\": {}, \"fallback_rate_biased\": {}, \"tile_latency_ms\": {}, "
                    "\"bytes_received\": {}, \"psnr_db\": {}, \"max_error\": {}, \"connected\": {}, \"unserved_s\": {}, "
                    "\"pop_rate\": {}, \"pop_largest\": {}, \"pages_rescued\": {}}}{}\n",
                    f.frame, jnum(f.time_s), jnum(f.frame_ms), f.pages_wanted, f.pages_resident, f.pages_requested,
                    f.pages_uploaded, f.pages_evicted, jnum(f.bias), f.textured_pixels, f.fallback_unbiased,
                    f.fallback_biased, jnum(f.fallback_rate()), jnum(f.fallback_rate_biased()), jnum(f.tile_latency_ms),
                    f.bytes_received, jnum(std::min(f.psnr, 999.0)), f.max_error < 0 ? "null" : std::to_string(f.max_error),
                    f.connected, jnum(f.unserved_s), jnum(f.pop_rate), f.pop_largest < 0 ? "null" : std::to_string(f.pop_largest),
                    f.pages_rescued, i + 1 < rep.frames.size() ? "," : "");
            else
                out << fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", f.frame, num(f.time_s),
                                   num(f.frame_ms), f.pages_wanted, f.pages_resident, f.pages_requested,
                                   f.pages_uploaded, f.pages_evicted, num(f.bias), f.textured_pixels,
                                   f.fallback_unbiased, f.fallback_biased, num(f.fallback_rate()),
                                   num(f.fallback_rate_biased()), num(f.tile_latency_ms), f.bytes_received,
                                   num(std::min(f.psnr, 999.0)), f.max_error < 0 ? "" : std::to_string(f.max_error),
                                   f.connected ? 1 : 0, num(f.unserved_s), num(f.pop_rate),
                                   f.pop_largest < 0 ? "" : std::to_string(f.pop_largest), f.pages_rescued);
        }
        if (json)
            out << "], "
                << fmt::format("\"popping\": {{\"mean_rate\": {}, \"max_rate\": {}, \"largest\": {}, \"pairs\": {}}}, ",
                               jnum(rep.mean_pop_rate()), jnum(rep.max_pop_rate()),
                               rep.largest_pop() < 0 ? "null" : std::to_string(rep.largest_pop()), rep.pop_pairs())
                << fmt::format("\"settled\": {{\"psnr_db\": {}, \"max_error\": {}, \"frames\": {}, \"complete\": {}}}, ",
                               jnum(std::min(rep.settled_psnr, 999.0)),
                               rep.settled_max_error < 0 ? "null" : std::to_string(rep.settled_max_error), rep.settled_frames,
                               rep.settled_complete ? "true" : "false")
                << fmt::format("\"fade_frames\": {}, ", rep.fade_frames)
                << "\"disk_cache\": "
                << (rep.disk_cache ? fmt::format("{{\"entries\": {}, \"bytes\": {}, \"hits\": {}, \"writes\": {}, \"corrupt\": {}, "
                                                 "\"write_errors\": {}, \"write_drops\": {}, \"evictions\": {}}}",
                                                 rep.disk_cache->entries, rep.disk_cache->bytes, rep.disk_cache->hits,
                                                 rep.disk_cache->writes, rep.disk_cache->corrupt, rep.disk_cache->write_errors,
                                                 rep.disk_cache->write_drops, rep.disk_cache->evictions)
                                   : std::string("null"))
                << ", "
                << "\"summary\": " << rep.summary.to_json() << "}\n";
    });
}

void write_fallback_plot(const ViewerReport& rep, const std::string& path, const std::string& title) {
    Plot p;
    p.title = title;
    p.x_label = "frame";
    p.y_label = "fallback pixels (%)";
    p.y2_label = "LoD bias (levels)";
    PlotSeries unbiased{"fallback vs the unbiased level", {}, {}, "#d62728"};
    PlotSeries biased{"fallback vs the biased level", {}, {}, "#ff9896"};
    PlotSeries bias{"LoD bias", {}, {}, "#1f77b4", false, true};
    for (const auto& f : rep.frames) {
        if (f.counted) {
            unbiased.x.push_back(double(f.frame));
            unbiased.y.push_back(100 * f.fallback_rate());
            biased.x.push_back(double(f.frame));
            biased.y.push_back(100 * f.fallback_rate_biased());
        }
        bias.x.push_back(double(f.frame));
        bias.y.push_back(f.bias);
    }
    p.series = {unbiased, biased, bias};
    write_svg(p, path);
}

std::string psnr_text(double db) {
    return std::isinf(db) && db > 0 ? std::string("lossless") : fmt::format("{:.2f} dB", db);
}

std::string summary_text(const ViewerReport& rep) {
    const auto& lat = rep.summary.latency();
    const auto pct = [](double v) { return std::isnan(v) ? std::string("n/a") : fmt::format("{:.4f}%", 100 * v); };
    std::string s;
    s += fmt::format("renderer      {}\n", rep.renderer);
    s += fmt::format("source        {}\n", rep.source);
    s += fmt::format("GPU pool      {} pages of {}, {} per page, {} in all; {:.1f} M texels\n", rep.pool_pages,
                     client::to_string(rep.page_format), human_bytes(rep.gpu_page_bytes),
                     human_bytes(rep.gpu_page_bytes * rep.pool_pages), double(rep.pool_texels) / 1e6);
    if (!rep.scene.empty()) s += fmt::format("scene         {}\n", rep.scene);
    if (!rep.displaced_by.empty()) s += fmt::format("terrain       displaced by {}\n", rep.displaced_by);
    if (!rep.layers.empty()) {
        std::string layers;
        for (const auto& l : rep.layers) layers += (layers.empty() ? "" : ", ") + l;
        s += fmt::format("layers        {} per page: {}\n", rep.layers.size(), layers);
    }
    s += fmt::format("frames        {} in {:.1f} s; frame time mean {:.2f} ms, p99 {:.2f} ms\n", rep.frames.size(),
                     rep.wall_s, rep.mean_frame_ms(), rep.frame_ms_quantile(0.99));
    if (!std::isnan(rep.warmup_ms))
        s += fmt::format("first view    {} in {:.0f} ms ({} frames; then the path starts)\n",
                         rep.warmup_complete       ? "full detail"
                         : rep.warmup_errors_only ? "NOT at full detail (stopped: for 2 s every read failed)"
                                                  : "NOT at full detail (timed out)", rep.warmup_ms,
                         rep.warmup_frames);
    s += fmt::format("fallback      {} of textured pixels over the path (vs the biased level: {})\n",
                     pct(rep.fallback_rate()), pct(rep.fallback_rate_biased()));
    s += fmt::format("LoD bias      mean {:.2f}, max {:.2f}, last {:.2f}\n", rep.summary.mean_lod_bias(),
                     rep.summary.max_lod_bias(), rep.summary.last_lod_bias());
    std::size_t compared = 0, identical = 0;
    for (const auto& f : rep.frames)
        if (!std::isnan(f.psnr)) ++compared, identical += std::isinf(f.psnr) ? 1 : 0;
    if (compared > 0 && identical == compared)
        s += fmt::format("PSNR          lossless: the {} compared frame{} identical to the reference (max error 0)\n",
                         compared, compared == 1 ? " is" : "s are");
    else if (compared > 0)
        s += fmt::format("PSNR          mean {:.2f} dB, min {}, max error {} (against the reference{})\n", rep.mean_psnr(),
                         psnr_text(rep.min_psnr()), rep.max_error(),
                         identical ? fmt::format("; {} of {} frames identical, counted as 99 dB", identical, compared)
                                   : std::string());
    if (!std::isnan(rep.settled_psnr))
        s += fmt::format("settled       {}, max error {} at the last view {} ({} frames after the path)\n",
                         std::isinf(rep.settled_psnr) ? std::string("lossless (identical to the reference)")
                                                      : "PSNR " + psnr_text(rep.settled_psnr),
                         rep.settled_max_error, rep.settled_complete ? "resident and faded in" : "NOT settled (timed out)",
                         rep.settled_frames);
    if (const double pop = rep.mean_pop_rate(); !std::isnan(pop))
        s += fmt::format("popping       mean {:.4f}% of covered pixels per frame, max {:.4f}%, largest jump {} ({} frame pairs)\n",
                         100 * pop, 100 * rep.max_pop_rate(), rep.largest_pop(), rep.pop_pairs());
    s += fmt::format("tile latency  p50 {:.2f} ms, p99 {:.2f} ms, max {:.2f} ms ({} pages, request -> mapped)\n",
                     lat.quantile(0.5), lat.quantile(0.99), lat.max_ms(), lat.count());
    if (rep.summary.time_to_detail_count() > 0)
        s += fmt::format("time to detail p50 {:.0f} frames, p90 {:.0f}, max {} ({} pages, first wanted -> first drawn){}\n",
                         rep.summary.time_to_detail_quantile(0.5), rep.summary.time_to_detail_quantile(0.9),
                         rep.summary.time_to_detail_max(), rep.summary.time_to_detail_count(),
                         rep.fade_frames ? fmt::format("; full weight {} frames later (the fade)", rep.fade_frames) : "");
    if (rep.predicted_feedback_frames > 0)
        s += fmt::format("prefetch      {} frames' feedback saw the view ahead (motion prefetch)\n", rep.predicted_feedback_frames);
    s += fmt::format("bytes         {} received, {} uploaded ({} of them copied after decoding)\n",
                     human_bytes(rep.summary.bytes_received()), human_bytes(rep.summary.bytes_uploaded()),
                     human_bytes(rep.page_bytes_copied));
    s += fmt::format("pages         {} requested, {} uploaded, {} evicted{}; cache hit ratio {}\n",
                     rep.summary.pages_requested(), rep.summary.pages_uploaded(), rep.summary.pages_evicted(),
                     rep.summary.pages_rescued() ? fmt::format(" ({} more fading out were wanted again and kept)",
                                                               rep.summary.pages_rescued())
                                                 : "",
                     pct(rep.cache_hit_ratio()));
    if (rep.summary.source_errors() > 0 || rep.summary.decode_failures() > 0)
        s += fmt::format("errors        {} tile answers were errors{}, {} tiles did not decode\n", rep.summary.source_errors(),
                         rep.summary.first_source_error().empty() ? "" : " (first: " + rep.summary.first_source_error() + ")",
                         rep.summary.decode_failures());
    if (rep.disk_cache) {
        const client::DiskCacheCounts& d = *rep.disk_cache;
        s += fmt::format("disk cache    {} entries, {:.1f} MiB; {} hits, {} written{}{}{}{}\n", d.entries, double(d.bytes) / (1 << 20),
                         d.hits, d.writes, d.evictions ? fmt::format(", {} evicted", d.evictions) : "",
                         d.corrupt ? fmt::format(", {} damaged (deleted, fetched again)", d.corrupt) : "",
                         d.write_errors ? fmt::format(", {} WRITES FAILED (a full disk, a folder gone, permissions)", d.write_errors) : "",
                         d.write_drops ? fmt::format(", {} writes dropped (queue full)", d.write_drops) : "");
    }
    if (rep.remote) {
        if (rep.unserved_s == 0 && rep.outages == 0)
            s += fmt::format("server        0.0 s unserved of {:.1f} s (connected throughout)\n", rep.run_s);
        else
            s += fmt::format("server        {:.1f} s unserved of {:.1f} s: {}{}{}\n", rep.unserved_s, rep.run_s,
                             rep.outages == 0 ? std::string("brief drops only, none reported")
                                              : fmt::format("unreachable {} time{}", rep.outages, rep.outages == 1 ? "" : "s"),
                             rep.down_at_end ? ", still down at the end" : "",
                             rep.last_link_error.empty() ? std::string() : " (last error: " + rep.last_link_error + ")");
    }
    return s;
}

void check_tiles_arrived(const ViewerReport& rep) {
    if (rep.summary.pages_arrived() > 0 || rep.summary.source_errors() == 0) return;
    throw Failure(fmt::format("no tile of the store could be read: all {} answers were errors{}", rep.summary.source_errors(),
                              rep.summary.first_source_error().empty() ? "" : " (first: " + rep.summary.first_source_error() + ")"),
                  1);
}

void check_outage(const ViewerReport& rep, double max_outage_s, const std::string& flag) {
    if (max_outage_s < 0 || !(rep.unserved_s > max_outage_s)) return;
    throw Failure(fmt::format("the tile server was unreachable for {:.1f} s of the run, more than {} {:g} s",
                              rep.unserved_s, flag, max_outage_s),
                  kOutageExitCode);
}

}  // namespace tessera::tools
