// tessera demo: the README's first command. Builds the procedural default store if it is missing
// and verifies it, starts a server on loopback, runs the headless viewer over the `flyover` path
// against it, and prints a summary (frames, frame time, fallback rate, PSNR against the reference,
// tile latency, bytes, cache hits) with the PNG frames and the fallback/bias plot it wrote.
#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>

#include "cli_options.hpp"
#include "commands.hpp"
#include "interrupt.hpp"
#include "path_option.hpp"
#include "progress.hpp"
#include "store_summary.hpp"
#include "tessera/client/page.hpp"
#include "tessera/scene/path.hpp"
#include "tessera/server/server.hpp"
#include "viewer_session.hpp"
#include "tessera/storage/builder.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/verify.hpp"

namespace tessera::tools {

Command add_demo(CLI::App& app) {
    struct Args {
        std::string dir = "tessera-demo";
        std::uint32_t texels = 16384;
        bool rebuild = false;
        std::string resolution = "1280x720";
        std::string path = "flyover";
        std::uint32_t frames = 0;
        std::uint32_t psnr_every = 60;
        std::uint32_t pool = 2048;
        float prefetch_lod = 0.15f;
        float guard_band = 0.1f;
        float fade_ms = kDefaultFadeMs;
        double motion_prefetch_ms = kDefaultMotionPrefetchMs;
        bool no_pace = false;
        std::string page_format = "auto";
        bool layers = false;
    };
    auto a = std::make_shared<Args>();
    CLI::App* c = app.add_subcommand(
        "demo", "Build the procedural terrain store (if missing) and verify it, serve it on loopback, view it headless "
                "along a camera path and report frame time, fallback, PSNR against the reference and popping");
    c->add_option("--dir", a->dir, "Directory for the demo's files")->capture_default_str();
    add_texels_option(*c, a->texels, "Texels per side of the procedural terrain",
                      CLI::Range(1u, std::uint32_t(storage::kMaxProceduralSize)));
    c->add_flag("--rebuild", a->rebuild, "Build the store even if it exists");
    // Checked as parsed, so that a mistyped value fails before the store is built (seconds).
    c->add_option("--resolution", a->resolution, "WIDTHxHEIGHT of the viewer")
        ->capture_default_str()
        ->check(CLI::Validator(
            [](std::string& v) -> std::string {
                unsigned w = 0, h = 0;
                char x = 0, extra = 0;
                // The viewer's bounds (tessera view --size): each side 16 to 8192.
                if (std::sscanf(v.c_str(), "%u%c%u%c", &w, &x, &h, &extra) != 3 || (x != 'x' && x != 'X') || w < 16 || h < 16 ||
                    w > 8192 || h > 8192)
                    return "'" + v + "': expected WIDTHxHEIGHT, each side 16 to 8192";
                return {};
            },
            "WIDTHxHEIGHT", "resolution"));
    c->add_option("--path", a->path, camera_path_help())
        ->capture_default_str()
        ->check(CLI::Validator(
            [](std::string& v) -> std::string {
                const auto names = scene::CameraPath::builtin_names();
                if (std::find(names.begin(), names.end(), v) != names.end()) return {};
                std::error_code ec;
                return std::filesystem::is_regular_file(v, ec) ? std::string()
                                                               : "'" + v + "' is neither a built-in path nor a path file";
            },
            "PATH", "camera path"));
    c->add_option("--frames", a->frames, "frames to render (0: the whole path at 60 frames per second)")->capture_default_str();
    c->add_option("--psnr-every", a->psnr_every, "compare with the reference renderer every N frames (0: never; off by default when --texels is not a power of two)")
        ->capture_default_str();
    c->add_option("--pool", a->pool, "physical pages in the GPU pool (at least 16)")->capture_default_str()->check(CLI::Range(16u, 1u << 24));
    c->add_option("--page-format", a->page_format, "auto, rgba8, bc1, bc4, bc5, bc7, r16, r16f or r32f (tessera view --help)")
        ->capture_default_str()
        ->check(CLI::Validator(
            [](std::string& v) -> std::string {
                return v == "auto" || client::parse_page_format(v) ? std::string() : "'" + v + "' is not a page format";
            },
            "FORMAT", "page format"));
    add_feedback_reach_options(*c, a->prefetch_lod, a->guard_band);
    c->add_option("--fade-ms", a->fade_ms, "arriving pages blend in, and evicted pages in view fade out, over this many milliseconds, 0..10000 (0: off)")
        ->capture_default_str()
        ->check(CLI::Range(0.0f, 10000.0f));
    c->add_option("--motion-prefetch-ms", a->motion_prefetch_ms,
                  "every other frame's feedback sees the view this far ahead, from the camera's motion (0: off)")
        ->capture_default_str();
    c->add_flag("--layers", a->layers,
                "a multi-layer store: colour (JPEG), normals (BC5) and heights (16-bit); the ground displaced by the heights "
                "and lit by the normals");
    c->add_flag("--no-pace", a->no_pace,
                "render as fast as the GPU can (default: each frame held to 1/60 s of wall time, as a display would)");
    return [a, c]() -> int {
        // The reference renderer samples GL mips, which halve rounding down: PSNR needs a store
        // whose levels halve exactly. Asked for, that is an error now (not after the build); by
        // default PSNR is left off, and the run says so.
        if (a->psnr_every > 0 && (a->texels & (a->texels - 1)) != 0) {
            if (c->count("--psnr-every") > 0)
                throw Failure(fmt::format("--psnr-every: the reference renderer needs --texels a power of two, not {} "
                                          "(or --psnr-every 0)", a->texels), 2);
            fmt::print("PSNR off: the reference renderer needs --texels a power of two, not {}\n", a->texels);
            a->psnr_every = 0;
        }
        remove_temp_files_on_interrupt();  // before any thread is started
        namespace fs = std::filesystem;
        std::error_code ec;
        fs::create_directories(a->dir, ec);
        if (ec) throw Failure(fmt::format("cannot create '{}': {}", a->dir, ec.message()));
        const std::string name = a->layers ? "terrain_layers" : "terrain";
        const std::string store = (fs::path(a->dir) / (name + ".tsr")).string();
        const std::string input = fmt::format("procedural:terrain:{}", a->texels);
        const storage::LayerInput layers[] = {{"colour", input, std::nullopt},
                                              {"normal", fmt::format("procedural:terrain-normal:{}", a->texels), Codec::bc5},
                                              {"height", fmt::format("procedural:terrain-height:{}", a->texels), Codec::zstd}};
        bool build = a->rebuild;
        if (!build) {
            auto existing = storage::StoreReader::open(store);
            build = !existing || existing.value()->info().width != a->texels || existing.value()->info().layered() != a->layers;
        }
        if (build) {
            fmt::print("building {} from {}{} ...\n", store, input, a->layers ? " (colour, normal and height layers)" : "");
            std::fflush(stdout);
            ProgressBar bar("build", true);
            const auto progress = [&](const storage::BuildProgress& p) {
                if (p.writing) bar.update(p.bytes_total ? double(p.bytes_written) / double(p.bytes_total) : 1.0, "writing");
                else bar.update(double(p.rows_done) / double(p.rows_total), fmt::format("tiles {}/{}", p.tiles_done, p.tiles_total));
            };
            auto r = a->layers ? storage::build_layered_store(layers, store, storage::BuildOptions{}, progress)
                               : storage::build_store(input, store, storage::BuildOptions{}, progress);
            bar.finish();
            if (!r) throw Failure(r.error().message);
            fmt::print("built in {} ({:.1f} MP/s)\n", human_seconds(r->seconds), double(r->source_texels) / 1e6 / r->seconds);
        } else {
            fmt::print("using existing {} (--rebuild to build it again)\n", store);
        }
        auto reader = storage::StoreReader::open(store);
        if (!reader) throw Failure(reader.error().message);
        print_store_summary(store, (*reader)->info());
        const auto rep = storage::verify_store(**reader);
        if (!rep.ok()) throw Failure(fmt::format("{} failed verification: {}", store, rep.problems.front()));
        fmt::print("verify     OK: {} tiles, {} payloads, {} checked\n", rep.tiles_checked, rep.payloads_checked,
                   human_bytes(rep.bytes_checked));

        // A server on loopback (an ephemeral port), serving the demo directory.
        unsigned w = 0, h = 0;
        char x = 0;
        if (std::sscanf(a->resolution.c_str(), "%u%c%u", &w, &x, &h) != 3 || (x != 'x' && x != 'X'))
            throw Failure(fmt::format("--resolution '{}': expected WIDTHxHEIGHT", a->resolution));
        server::ServerConfig sc;
        sc.store_files = {store};
        sc.grpc_address = "127.0.0.1:0";
        sc.http_address = "";
        sc.watch_interval = std::chrono::milliseconds(0);
        sc.io_threads = 2;
        sc.log_json = false;
        sc.log_quiet = true;  // its warnings and errors still show
        auto srv = server::Server::start(sc);
        if (!srv) throw Failure(fmt::format("cannot start the demo server: {}", srv.error().message));
        const std::string url = fmt::format("grpc://127.0.0.1:{}/{}", (*srv)->grpc_port(), name);
        fmt::print("\nserver     {} (gRPC on loopback)\n", url);

        ViewerOptions vo;
        vo.store = url;
        vo.reference_store = store;
        vo.path = a->path;
        vo.width = w;
        vo.height = h;
        vo.frames = a->frames;
        vo.pool = a->pool;
        vo.page_format = a->page_format;
        vo.psnr_every = a->psnr_every;
        vo.prefetch_lod = a->prefetch_lod;
        vo.guard_band = a->guard_band;
        vo.fade_ms = a->fade_ms;
        vo.motion_prefetch_ms = a->motion_prefetch_ms;
        // With layers, the ground is the height layer's, at the relief its normals were made for.
        if (a->layers) vo.displacement = 2.0 * a->texels * storage::kTerrainReliefPerSize;
        // Paced like a 60 Hz display: unpaced, a GPU renders the 60-frames-per-second path many
        // times faster than tiles can arrive, which no viewer on a screen would do.
        vo.pace = !a->no_pace;
        vo.out_dir = (fs::path(a->dir) / "frames").string();
        vo.stats_file = (fs::path(a->dir) / "frames.csv").string();
        vo.trace_file = (fs::path(a->dir) / (fs::path(a->path).filename().string() + ".trace")).string();
        fmt::print("viewer     headless {}x{}, path {}, pool {} pages, {}\n", w, h, a->path, a->pool,
                   vo.pace ? "paced to 60 Hz" : "unpaced");
        std::fflush(stdout);
        const auto view = run_viewer(vo);
        (*srv)->shutdown();
        write_frame_stats(view, vo.stats_file);
        const std::string plot = (fs::path(a->dir) / "fallback.svg").string();
        write_fallback_plot(view, plot, fmt::format("tessera demo: {} over {}x{} ({})", a->path, w, h, view.renderer));

        fmt::print("\n{}", summary_text(view));
        fmt::print("\nwrote\n");
        for (const auto& p : view.pngs) fmt::print("  {}\n", p);
        fmt::print("  {}   (fallback rate and LoD bias per frame)\n  {}   (per-frame stats)\n  {}   (feedback trace for "
                   "tessera loadtest)\n",
                   plot, vo.stats_file, vo.trace_file);
        fmt::print("\nmore: tessera view --store {} (a window)    tessera inspect {} --json\n", store, store);
        std::fflush(stdout);
        // The server is in this process: an outage here means the stream broke, not a server gone.
        check_outage(view, kDefaultMaxOutageSeconds, "the demo's limit of");
        check_tiles_arrived(view);
        return 0;
    };
}

}  // namespace tessera::tools
