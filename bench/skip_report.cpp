// Skip what a scene doesn't need, measured (docs/benchmarks.md, docs/visibility.md): for a store
// and a camera path over the flat terrain,
//  1. the share of the store's tiles the path touches (every page cpu_feedback wants along the
//     path, sampled at --fps; all levels and level 0), and of its stored (non-absent) tiles;
//  2. a client runtime run along the path in real time (no GL: a null uploader; a local store
//     source behind an emulated link with latency), counting the work skipped because a request
//     stopped being wanted: requests cancelled before their data arrived, source deliveries that
//     came for cancelled requests (I/O not saved), requests cancelled after arrival (never
//     decoded), decode jobs dropped unrun, decoded pages never uploaded.
//
//   skip_report STORE.tsr PATHS [--view 1280x720] [--fps 30] [--speed 1] [--pool 2048]
//               [--latency-ms 40] [--jitter-ms 10] [--read-threads 2] [--transcode-threads 1] [--json]
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "tessera/client/emulated_source.hpp"
#include "tessera/client/fakes/uploaders.hpp"
#include "tessera/client/runtime.hpp"
#include "tessera/client/tile_source.hpp"
#include "tessera/scene/cpu_feedback.hpp"
#include "tessera/scene/visibility.hpp"
#include "tessera/storage/store_reader.hpp"

namespace {

using namespace tessera;
using Clock = std::chrono::steady_clock;

[[noreturn]] void die(const std::string& msg) {
    std::fprintf(stderr, "skip_report: %s\n", msg.c_str());
    std::exit(2);
}

double pct(std::uint64_t a, std::uint64_t b) { return b ? 100.0 * double(a) / double(b) : 0.0; }

}  // namespace

int main(int argc, char** argv) {
    if (argc < 3) die("usage: skip_report STORE.tsr PATHS [--view WxH] [--fps F] [--speed S] [--pool N] [--latency-ms MS] "
                      "[--jitter-ms MS] [--read-threads N] [--transcode-threads N]");
    const std::string store_path = argv[1], paths_arg = argv[2];
    unsigned vw = 1280, vh = 720, pool = 2048, read_threads = 2, transcode_threads = 1;
    double fps = 30, speed = 1, latency_ms = 40, jitter_ms = 10;
    for (int i = 3; i < argc; ++i) {
        const std::string a = argv[i];
        if (i + 1 >= argc) die("missing value after " + a);
        const char* v = argv[++i];
        if (a == "--view") {
            if (std::sscanf(v, "%ux%u", &vw, &vh) != 2 || !vw || !vh) die("--view must be WxH");
        } else if (a == "--fps") fps = std::atof(v);
        else if (a == "--speed") speed = std::atof(v);
        else if (a == "--pool") pool = static_cast<unsigned>(std::atoi(v));
        else if (a == "--latency-ms") latency_ms = std::atof(v);
        else if (a == "--jitter-ms") jitter_ms = std::atof(v);
        else if (a == "--read-threads") read_threads = static_cast<unsigned>(std::atoi(v));
        else if (a == "--transcode-threads") transcode_threads = static_cast<unsigned>(std::atoi(v));
        else die("unknown option " + a);
    }
    if (!(fps > 0) || !(speed > 0) || pool == 0) die("--fps, --speed and --pool must be positive");

    auto reader = storage::StoreReader::open(store_path);
    if (!reader) die(store_path + ": " + reader.error().message);
    const storage::StoreInfo info = (*reader)->info();
    auto terrain = scene::visibility_terrain(info.width, info.height);
    if (!terrain) die(terrain.error().message);
    auto paths = scene::parse_path_list(paths_arg, *terrain);
    if (!paths) die(paths.error().message);
    const scene::VtGeometry geo{info.width, info.height, info.tile_payload, info.level_count()};

    // 1. Share of the store touched.
    scene::VisibilityOptions vo;
    vo.view_width = vw;
    vo.view_height = vh;
    vo.fps = fps;
    const scene::PageSet touched = scene::pages_wanted(*paths, geo, vo);
    std::uint64_t all_total = 0, all_touched = 0, all_stored = 0, all_touched_stored = 0;
    std::printf("store %s: %ux%u, %u levels, tile payload %u\npaths %s, view %ux%u (feedback %ux%u), sampled at %g fps\n",
                store_path.c_str(), info.width, info.height, info.level_count(), info.tile_payload, paths_arg.c_str(), vw,
                vh, (vw + 7) / 8, (vh + 7) / 8, fps);
    std::printf("level   tiles  stored  touched  touched%%  touched-stored  of-stored%%\n");
    for (std::uint32_t l = 0; l < info.level_count(); ++l) {
        const auto& L = info.levels[l];
        std::uint64_t stored = 0, touched_stored = 0, n_touched = 0;
        for (std::uint32_t y = 0; y < L.tiles_y; ++y)
            for (std::uint32_t x = 0; x < L.tiles_x; ++x) {
                auto e = (*reader)->locate(tessera::TileKey{l, x, y});
                const bool present = e && e->kind != tessera::TileKind::absent;
                const bool t = touched.contains(l, x, y);
                stored += present;
                n_touched += t;
                touched_stored += present && t;
            }
        const std::uint64_t total = std::uint64_t(L.tiles_x) * L.tiles_y;
        std::printf("%5u %7llu %7llu %8llu %8.2f%% %15llu %10.2f%%\n", l, (unsigned long long)total,
                    (unsigned long long)stored, (unsigned long long)n_touched, pct(n_touched, total),
                    (unsigned long long)touched_stored, pct(touched_stored, stored));
        all_total += total;
        all_touched += n_touched;
        all_stored += stored;
        all_touched_stored += touched_stored;
    }
    std::printf("  all %7llu %7llu %8llu %8.2f%% %15llu %10.2f%%\n", (unsigned long long)all_total,
                (unsigned long long)all_stored, (unsigned long long)all_touched, pct(all_touched, all_total),
                (unsigned long long)all_touched_stored, pct(all_touched_stored, all_stored));

    // 2. The runtime along the path, in real time.
    client::NullUploader uploader;
    client::RuntimeConfig cfg;
    cfg.residency.pool_slots = pool;
    cfg.transcode_threads = transcode_threads;
    cfg.upload_bytes_per_frame = std::size_t(cfg.upload_pages_per_frame) * info.tile_size() * info.tile_size() * 4;
    auto runtime = client::Runtime::create(cfg, uploader);
    if (!runtime) die(runtime.error().message);
    client::EmulatedLink link;
    link.latency = std::chrono::microseconds(static_cast<long long>(latency_ms * 1000));
    link.jitter = std::chrono::microseconds(static_cast<long long>(jitter_ms * 1000));
    auto source = client::make_emulated_source(client::make_local_store_source(read_threads), link, 1);
    auto tex = (*runtime)->add_texture(*source, store_path);
    if (!tex) die(tex.error().message);
    scene::CpuFeedbackParams params;
    params.main_width = vw;
    params.main_height = vh;
    params.fb_width = (vw + 7) / 8;
    params.fb_height = (vh + 7) / 8;
    params.texture = *tex;
    std::vector<client::FeedbackId> ids;
    std::uint64_t frames = 0;
    double fallback_sum = 0;
    const auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / fps));
    const auto t0 = Clock::now();
    for (const auto& path : *paths) {
        const double d = path.duration();
        for (std::uint64_t k = 0;; ++k) {
            const double t = double(k) * speed / fps;
            if (t > d + 1e-9) break;
            std::this_thread::sleep_until(t0 + period * static_cast<long>(frames));
            params.bias = (*runtime)->lod_bias();
            scene::cpu_feedback(path.at(t), geo, params, ids);
            fallback_sum += (*runtime)->frame(ids, params.fb_width, params.fb_height, params.bias).fallback_estimate;
            ++frames;
        }
    }
    const auto& s = (*runtime)->summary();
    std::printf("\nruntime: %llu frames at %g fps (path speed x%g), pool %u, link %g +- %g ms, %u read threads\n",
                (unsigned long long)frames, fps, speed, pool, latency_ms, jitter_ms, read_threads);
    std::printf("  requested %llu, arrived %llu, uploaded %llu, evicted %llu; mean fallback estimate %.4f\n",
                (unsigned long long)s.pages_requested(), (unsigned long long)s.pages_arrived(),
                (unsigned long long)s.pages_uploaded(), (unsigned long long)s.pages_evicted(),
                frames ? fallback_sum / double(frames) : 0.0);
    // A delivery for a page no longer in flight was read by the source anyway; with a source
    // that reads before its latency (the emulated link), most cancellations come too late.
    const std::uint64_t saved_io =
        s.cancelled_waiting() > s.stale_arrivals() ? s.cancelled_waiting() - s.stale_arrivals() : 0;
    std::printf("  cancelled before arrival %llu (%.1f%% of requests); deliveries for pages no longer in flight %llu"
                " -> I/O saved for at most %llu\n",
                (unsigned long long)s.cancelled_waiting(), pct(s.cancelled_waiting(), s.pages_requested()),
                (unsigned long long)s.stale_arrivals(), (unsigned long long)saved_io);
    std::printf("  never decoded (stale): cancelled after arrival %llu + decode jobs dropped %llu = %llu (%.1f%% of arrivals)\n",
                (unsigned long long)s.cancelled_arrived(), (unsigned long long)s.decodes_dropped(),
                (unsigned long long)(s.cancelled_arrived() + s.decodes_dropped()),
                pct(s.cancelled_arrived() + s.decodes_dropped(), s.pages_arrived()));
    std::printf("  decoded, never uploaded %llu; duplicate deliveries (read twice by the source) %llu\n",
                (unsigned long long)s.cancelled_decoded(), (unsigned long long)s.duplicate_arrivals());
    std::printf("summary %s\n", s.to_json().c_str());
    return 0;
}
