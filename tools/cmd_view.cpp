// tessera view: the networked viewer. A window (GLFW) with a mouse-and-keyboard camera, or
// headless (EGL) writing PNG frames, per-frame stats and a feedback trace for the load tester.
#include <fmt/format.h>

#include <cmath>
#include <cstdio>

#include "cli_options.hpp"
#include "commands.hpp"
#include "interrupt.hpp"
#include "path_option.hpp"
#include "viewer_session.hpp"

namespace tessera::tools {

Command add_view(CLI::App& app) {
    auto o = std::make_shared<ViewerOptions>();
    auto size = std::make_shared<std::string>("1280x720");
    auto filter = std::make_shared<std::string>("trilinear");
    auto quiet = std::make_shared<bool>(false);
    o->headless = false;
    CLI::App* c = app.add_subcommand("view", "View a store: windowed (mouse and keyboard camera) or headless");
    c->add_option("--store", o->store, "FILE.tsr, or a server store: grpc://HOST:PORT/NAME (grpcs:// for TLS; replicas: IP:PORT,IP:PORT,... or a name "
                                         "with several addresses)")->required();
    c->add_option("--scene", o->scene, "auto (the scene that travels with the store: the atlas OBJ `tessera build --atlas` wrote beside it, read there or sent by its server; else terrain), terrain, or an atlas OBJ file")
        ->capture_default_str();
    c->add_option("--displacement", o->displacement,
                  "terrain: peak height of the displaced ground (0: flat); with a one-channel layer named height, "
                  "the ground follows that layer, its full range spanning this height")
        ->capture_default_str();
    c->add_option("--path", o->path, camera_path_help())->capture_default_str();
    c->add_option("--size", *size, "WIDTHxHEIGHT of the image")->capture_default_str();
    c->add_flag("--headless", o->headless, "render offscreen (EGL), no window");
    c->add_flag("!--no-hud", o->hud, "windowed: no statistics overlay (the window title still shows them)");
    c->add_option("--frames", o->frames, "frames to render (0: the whole path; windowed: until closed)")->capture_default_str();
    c->add_option("--fps", o->fps, "frames per second of path time (headless: the path advances 1/fps per frame), 0.001..1000")
        ->capture_default_str()
        ->check(CLI::Range(0.001, 1000.0));
    c->add_flag("--pace", o->pace, "headless: hold each frame to at least 1/fps of wall time, like a display");
    c->add_option("--out", o->out_dir, "directory for PNG frames");
    c->add_option("--png-count", o->png_count, "PNG frames to write with --out, spread over the run")->capture_default_str();
    c->add_option("--stats", o->stats_file, "per-frame stats, .csv or .json")->check(output_file());
    c->add_option("--trace", o->trace_file, "record the feedback (per-frame request sets) for `tessera loadtest --trace`")
        ->check(output_file());
    c->add_option("--pool", o->pool, "physical pages in the GPU pool, at least 16 (0, the default: 2048, or every page of a store that has fewer)")
        ->check(CLI::IsMember({0u}) | CLI::Range(16u, 1u << 24));
    c->add_option("--page-format", o->page_format,
                  "how the GPU pool holds pages: auto (a block-codec store's own blocks, else rgba8), rgba8, or "
                  "block-compressed (a store of that codec: its blocks as they are; any other store: encoded on the transcode "
                  "threads): bc1 (colour), bc4 (one channel), bc5 (two channels), bc7 (colour with alpha); or a 1-channel "
                  "store's samples exactly: r16, r16f, r32f")
        ->capture_default_str();
    c->add_option("--show-layer", o->show_layer,
                  "a multi-layer store: the layer to draw (default: the first; a layer named \"normal\" lights it)");
    c->add_flag("--unlit", o->unlit, "a multi-layer store: draw the first layer as it is, not lit by its \"normal\" layer or a glTF material's maps");
    c->add_option("--layer-format", o->layer_formats,
                  "a multi-layer store: NAME=FORMAT, a layer's page format (as --page-format; repeatable; default: its "
                  "block format, or its 16-bit/float samples exactly, else rgba8)");
    c->add_option("--filter", *filter, "bilinear, trilinear or anisotropic")->capture_default_str();
    c->add_option("--anisotropy", o->anisotropy, "anisotropic filter: most taps, 1..8")->capture_default_str()->check(CLI::Range(1u, 8u));
    c->add_option("--feedback-scale", o->feedback_scale, "feedback buffer at 1/N of the image size, 1..64")
        ->capture_default_str()
        ->check(CLI::Range(1u, 64u));
    add_feedback_reach_options(*c, o->prefetch_lod, o->guard_band);
    c->add_option("--fade-ms", o->fade_ms,
                  "arriving pages blend in from what was drawn before them over this many milliseconds, evicted pages "
                  "still in view fade out, and LoD-bias changes spread over as long, 0..10000 (0: off, pages show and go at once)")
        ->capture_default_str()
        ->check(CLI::Range(0.0f, 10000.0f));
    c->add_option("--motion-prefetch-ms", o->motion_prefetch_ms,
                  "motion prefetch: the feedback of every --motion-prefetch-every-th frame sees the view this many "
                  "milliseconds ahead, extrapolated from the camera's motion (0: off)")
        ->capture_default_str();
    c->add_option("--motion-prefetch-every", o->motion_prefetch_every, "motion prefetch: every N-th frame's feedback (>= 1)")
        ->capture_default_str()
        ->check(CLI::Range(1u, 1000000u));
    c->add_option("--link-latency-ms", o->link_latency_ms,
                  "emulate a network link to the source: this one-way delay per request, milliseconds (0: none)")
        ->check(CLI::Range(0.0, 1e9));
    c->add_option("--link-jitter-ms", o->link_jitter_ms, "emulated link: random extra delay up to this, milliseconds")
        ->check(CLI::Range(0.0, 1e9));
    c->add_option("--link-bandwidth", o->link_bandwidth_bits_per_s, "emulated link: bits per second (0: unlimited)")
        ->check(CLI::Range(0.0, 1e15));
    c->add_option("--upload-pages", o->upload_pages_per_frame, "pages uploaded per frame at most (>= 1)")
        ->capture_default_str()
        ->check(CLI::Range(1u, 1u << 20));
    add_bytes_option(*c, "--ram-cache", o->ram_cache_bytes, "RAM tile cache, e.g. 256MiB (0: off)");
    c->add_option("--disk-cache", o->disk_cache_dir, "disk tile cache directory (persists across runs)");
    add_bytes_option(*c, "--disk-cache-size", o->disk_cache_bytes, "disk cache bound, e.g. 1GiB");
    c->add_option("--transcode-threads", o->transcode_threads,
                  "decoder threads (0: decode on the render thread, deterministic, for measurements)")
        ->capture_default_str()
        ->check(CLI::Range(0u, 256u));
    c->add_option("--psnr-every", o->psnr_every, "compare against the reference renderer every N frames (0: never; a store of power-of-two sides)")
        ->capture_default_str();
    c->add_option("--reference-store", o->reference_store, "local copy of the store for the reference (remote stores)");
    c->add_option("--token", o->auth_token, "bearer token for the server");
    c->add_option("--tls-ca", o->tls_ca_file, "PEM roots to verify a grpcs:// server (default: the system's)");
    auto max_outage = std::make_shared<double>(kDefaultMaxOutageSeconds);
    c->add_option("--max-outage", *max_outage,
                  "exit 3 when the server was unreachable for more than this many seconds of the run "
                  "(0: any outage; negative: never)")
        ->capture_default_str();
    auto no_warmup = std::make_shared<bool>(false);
    c->add_flag("--no-warmup", *no_warmup, "headless: start the path from an empty pool (default: wait until its first view is at full detail)");
    c->add_flag("-q,--quiet", *quiet, "no progress, no summary");
    return [o, size, filter, quiet, no_warmup, max_outage]() -> int {
        remove_temp_files_on_interrupt();  // before any thread is started
        o->warmup = !*no_warmup;
        unsigned w = 0, h = 0;
        char x = 0, extra = 0;
        if (std::sscanf(size->c_str(), "%u%c%u%c", &w, &x, &h, &extra) != 3 || (x != 'x' && x != 'X'))
            throw Failure(fmt::format("--size '{}': expected WIDTHxHEIGHT, e.g. 1280x720", *size));
        o->width = w;
        o->height = h;
        if (*filter == "bilinear") o->filter = client::gl::Filter::bilinear;
        else if (*filter == "trilinear") o->filter = client::gl::Filter::trilinear;
        else if (*filter == "anisotropic") o->filter = client::gl::Filter::anisotropic;
        else throw Failure(fmt::format("--filter '{}': expected bilinear, trilinear or anisotropic", *filter));
        o->progress = !*quiet;
        if (!std::isfinite(*max_outage)) throw Failure("--max-outage must be a number of seconds", 2);
        const auto rep = run_viewer(*o);
        if (!o->stats_file.empty()) write_frame_stats(rep, o->stats_file);
        if (!*quiet) {
            fmt::print("{}", summary_text(rep));
            for (const auto& p : rep.pngs) fmt::print("wrote         {}\n", p);
            if (!o->stats_file.empty()) fmt::print("wrote         {}\n", o->stats_file);
            if (!o->trace_file.empty()) fmt::print("wrote         {}\n", o->trace_file);
        }
        std::fflush(stdout);
        check_outage(rep, *max_outage, "--max-outage");
        check_tiles_arrived(rep);
        return 0;
    };
}

}  // namespace tessera::tools
