// tessera bench, the application: run time against error (docs/bench.md). A one-factor-at-a-time sweep around a
// baseline over the procedural terrain store: tile size, border, codec and quality, feedback scale,
// pool size, LoD-bias policy, upload budget, network latency (emulated) and prefetch. Each point is
// one headless viewer run over a camera path, paced at 60 frames per second of wall time, measured
// as run time (build time, frame time, time to full detail, bytes moved) against error (PSNR and
// max error against a lossless reference, fallback rate). Writes bench.csv, bench.json and
// pareto_*.svg, prints the table and a recommended default (docs/bench.md).
//
// Error is against the true source: the reference renderer draws from a lossless (zstd) store of
// the same source with the same tile size and border (the same mip chain as the viewed store,
// decoded exactly), so a lossy codec's loss and streaming's fallback both count.
#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "bench.hpp"
#include "failure.hpp"
#include "progress.hpp"
#include "svg_plot.hpp"
#include "tessera/scene/path.hpp"
#include "tessera/storage/builder.hpp"
#include "viewer_session.hpp"

namespace tessera::tools {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

// One point's settings.
struct Settings {
    std::uint32_t tile = 256, border = 4;
    Codec codec = Codec::jpeg;
    int quality = 90;
    std::uint32_t feedback_scale = 8;
    std::uint32_t pool = 2048;
    std::string bias = "default";
    std::uint32_t upload = 32;
    double latency_ms = 0;
    float prefetch = 0.3f;
    std::string page_format = "rgba8";  // the GPU pool's (ViewerOptions::page_format)

    std::string store_key() const {
        return codec == Codec::jpeg ? fmt::format("t{}_b{}_jpeg{}", tile, border, quality)
                                             : fmt::format("t{}_b{}_{}", tile, border, tessera::to_string(codec));
    }
    std::string codec_label() const {
        return codec == Codec::jpeg ? fmt::format("jpeg q{}", quality) : std::string(tessera::to_string(codec));
    }
};

struct Point {
    std::string sweep, label;
    Settings s;
    bool baseline = false;
    // Results.
    double build_s = kNaN;
    std::uint64_t store_bytes = 0;
    double frame_ms_mean = kNaN, frame_ms_p99 = kNaN, full_detail_ms = kNaN;
    bool full_detail_reached = false;
    std::uint64_t bytes_received = 0, pages_requested = 0;
    double fallback = kNaN, fallback_biased = kNaN, psnr_mean = kNaN, psnr_min = kNaN, mean_bias = kNaN;
    int max_error = -1;
    double pop_rate = kNaN, time_to_detail_p50 = kNaN;  // temporal quality (docs/viewer.md, "Measures")
    double wall_s = 0;
    std::uint64_t gpu_page_bytes = 0;  // the pool's bytes per page, second level included
};

// Named LoD-bias policies (client/lod_bias.hpp).
client::LodBiasConfig bias_policy(const std::string& name) {
    client::LodBiasConfig c;
    if (name == "default") return c;
    if (name == "off") {
        c.max_bias = 0;  // never coarsen: an overfull pool thrashes instead
        return c;
    }
    if (name == "eager") {  // coarsen early, come back late
        c.high_water = 0.7f;
        c.low_water = 0.5f;
        c.rise_frames = 1;
        c.fall_frames = 60;
        return c;
    }
    if (name == "backlog") {  // also coarsen while the request backlog is long (slow links)
        c.backlog_high_frames = 8;
        return c;
    }
    throw Failure(fmt::format("unknown bias policy '{}'", name));
}


std::vector<Point> make_points(const std::set<std::string>& only, bool quick) {
    std::vector<Point> pts;
    const Settings base;
    pts.push_back({"baseline", "baseline", base, true});
    auto add = [&](const std::string& sweep, const std::string& label, auto&& change) {
        if (!only.empty() && !only.count(sweep)) return;
        Settings s = base;
        change(s);
        pts.push_back({sweep, label, s, false});
    };
    if (quick) {
        add("codec", "zstd", [](Settings& s) { s.codec = Codec::zstd; });
        add("latency", "latency 20 ms", [](Settings& s) { s.latency_ms = 20; });
        return pts;
    }
    // The pool keeps its texel budget (2048 slots of 256^2): 8192 slots of 128^2, 512 of 512^2.
    for (std::uint32_t t : {128u, 512u})
        add("tile", fmt::format("tile {} (pool {})", t, base.pool * 256 / t * 256 / t), [t, &base](Settings& s) {
            s.tile = t;
            s.pool = base.pool * 256 / t * 256 / t;
        });
    for (std::uint32_t b : {2u, 8u}) add("border", fmt::format("border {}", b), [b](Settings& s) { s.border = b; });
    for (int q : {50, 75, 95}) add("codec", fmt::format("jpeg q{}", q), [q](Settings& s) { s.quality = q; });
    add("codec", "zstd", [](Settings& s) { s.codec = Codec::zstd; });
    // GPU page formats: BC1 at the baseline's pool, and at the GPU bytes of an RGBA8 pool of 16
    // (8x the pages), which the pool sweep's "pool 16" point shows in RGBA8.
    add("format", "bc1", [](Settings& s) { s.page_format = "bc1"; });
    add("format", "bc1 pool 128", [](Settings& s) {
        s.page_format = "bc1";
        s.pool = 128;
    });
    // Build-time blocks: the store holds the pool's blocks (slow encoders, once); the client unpacks.
    add("format", "bc1 store", [](Settings& s) {
        s.codec = Codec::bc1;
        s.page_format = "bc1";
    });
    add("format", "bc7 store pool 64", [](Settings& s) {  // the GPU bytes of an RGBA8 pool of 16
        s.codec = Codec::bc7;
        s.page_format = "bc7";
        s.pool = 64;
    });
    for (std::uint32_t f : {4u, 16u})
        add("feedback", fmt::format("feedback 1/{}", f), [f](Settings& s) { s.feedback_scale = f; });
    // A 320x180 view of the flyover wants about 20-30 pages: the small pools are the tight ones.
    for (std::uint32_t p : {16u, 24u, 32u, 128u, 512u})
        add("pool", fmt::format("pool {}", p), [p](Settings& s) { s.pool = p; });
    // Bias policies matter only when the pool is tight: at pool 16, the smallest allowed.
    for (const char* b : {"default", "off", "eager", "backlog"})
        add("bias", fmt::format("bias {} @pool 16", b), [b](Settings& s) {
            s.bias = b;
            s.pool = 16;
        });
    for (std::uint32_t u : {4u, 16u, 64u})
        add("upload", fmt::format("upload {}/frame", u), [u](Settings& s) { s.upload = u; });
    for (double l : {20.0, 80.0}) add("latency", fmt::format("latency {} ms", l), [l](Settings& s) { s.latency_ms = l; });
    add("prefetch", "prefetch 0", [](Settings& s) { s.prefetch = 0; });
    return pts;
}

std::string num(double v, int prec = 4) { return std::isfinite(v) ? fmt::format("{:.{}g}", v, prec) : std::string(); }

// Indices of the Pareto front for (x minimised, y maximised or minimised), sorted by x.
std::vector<std::size_t> pareto_front(const std::vector<double>& x, const std::vector<double>& y, bool maximise_y) {
    std::vector<std::size_t> idx;
    for (std::size_t i = 0; i < x.size(); ++i)
        if (std::isfinite(x[i]) && std::isfinite(y[i])) idx.push_back(i);
    const auto better = [&](double a, double b) { return maximise_y ? a > b : a < b; };
    std::sort(idx.begin(), idx.end(), [&](std::size_t a, std::size_t b) {
        return x[a] != x[b] ? x[a] < x[b] : better(y[a], y[b]);
    });
    std::vector<std::size_t> front;
    for (std::size_t i : idx)
        if (front.empty() || better(y[i], y[front.back()])) front.push_back(i);
    return front;
}

const char* kColours[] = {"#000000", "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
                          "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"};

void pareto_plot(const std::vector<Point>& pts, const std::string& file, const std::string& title,
                 const std::string& x_label, const std::string& y_label, bool maximise_y,
                 double (*fx)(const Point&), double (*fy)(const Point&)) {
    Plot p;
    p.title = title;
    p.x_label = x_label;
    p.y_label = y_label;
    std::vector<std::string> sweeps;
    for (const auto& pt : pts)
        if (std::find(sweeps.begin(), sweeps.end(), pt.sweep) == sweeps.end()) sweeps.push_back(pt.sweep);
    for (std::size_t k = 0; k < sweeps.size(); ++k) {
        PlotSeries s{sweeps[k], {}, {}, kColours[k % std::size(kColours)], true};
        for (const auto& pt : pts)
            if (pt.sweep == sweeps[k]) s.x.push_back(fx(pt)), s.y.push_back(fy(pt));
        p.series.push_back(std::move(s));
    }
    std::vector<double> x, y;
    for (const auto& pt : pts) x.push_back(fx(pt)), y.push_back(fy(pt));
    PlotSeries front{"Pareto front", {}, {}, "#555555"};
    for (std::size_t i : pareto_front(x, y, maximise_y)) front.x.push_back(x[i]), front.y.push_back(y[i]);
    p.series.push_back(std::move(front));
    write_svg(p, file);
}

// The recommended default: among the points whose fallback rate is at most 0.01% (full detail
// but for a few pixels), whose first view reached full detail and which move at most twice the
// baseline's bytes, those with a mean frame time within 20% of the fastest of them; of these the
// highest mean PSNR; PSNR ties (within 0.1 dB) go to fewer bytes received.
const Point* recommend(const std::vector<Point>& pts) {
    std::vector<const Point*> ok;
    const double max_bytes = 2.0 * double(pts.front().bytes_received);  // pts.front(): the baseline
    for (const auto& p : pts)
        if (std::isfinite(p.fallback) && p.fallback <= 1e-4 && p.full_detail_reached && std::isfinite(p.psnr_mean) &&
            double(p.bytes_received) <= max_bytes)
            ok.push_back(&p);
    if (ok.empty()) return nullptr;
    double fastest = ok.front()->frame_ms_mean;
    for (const auto* p : ok) fastest = std::min(fastest, p->frame_ms_mean);
    const Point* best = nullptr;
    for (const auto* p : ok) {
        if (p->frame_ms_mean > 1.2 * fastest) continue;
        if (!best || p->psnr_mean > best->psnr_mean + 0.1 ||
            (std::abs(p->psnr_mean - best->psnr_mean) <= 0.1 && p->bytes_received < best->bytes_received))
            best = p;
    }
    return best;
}

// What a sweep measured, for its outputs.
struct SweepResult {
    std::vector<Point> pts;
    const Point* best = nullptr;  // the recommended default, if any
    unsigned w = 0, h = 0;
    std::uint32_t frames = 0;
    double total_s = 0;
};

std::string write_csv(const BenchOptions& o, const SweepResult& r) {
    const std::vector<Point>& pts = r.pts;
    [[maybe_unused]] const Point* best = r.best;
    [[maybe_unused]] const unsigned w = r.w, h = r.h;
    [[maybe_unused]] const std::uint32_t frames = r.frames;
    // bench.csv
    const std::string csv_file = (fs::path(o.out) / "bench.csv").string();
    {
        std::ofstream out(csv_file, std::ios::trunc);
        out << "sweep,label,tile_size,border,codec,quality,page_format,gpu_page_bytes,feedback_scale,pool,bias_policy,"
               "upload_pages_per_frame,latency_ms,prefetch_lod,build_s,store_bytes,frame_ms_mean,frame_ms_p99,"
               "full_detail_ms,full_detail_reached,bytes_received,pages_requested,fallback_rate,"
               "fallback_rate_biased,mean_lod_bias,psnr_mean_db,psnr_min_db,max_error,wall_s,recommended,pop_rate,"
               "time_to_detail_p50_frames\n";
        for (const auto& p : pts)
            out << fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
                               p.sweep, p.label, p.s.tile, p.s.border, tessera::to_string(p.s.codec),
                               p.s.codec == Codec::jpeg ? std::to_string(p.s.quality) : std::string(),
                               p.s.page_format, p.gpu_page_bytes, p.s.feedback_scale, p.s.pool, p.s.bias, p.s.upload,
                               p.s.latency_ms, p.s.prefetch, num(p.build_s, 6), p.store_bytes, num(p.frame_ms_mean, 6),
                               num(p.frame_ms_p99, 6), num(p.full_detail_ms, 6), p.full_detail_reached ? 1 : 0,
                               p.bytes_received, p.pages_requested, num(p.fallback, 6), num(p.fallback_biased, 6),
                               num(p.mean_bias, 4), num(std::min(p.psnr_mean, 99.0), 6),
                               num(std::min(p.psnr_min, 99.0), 6), p.max_error, num(p.wall_s, 4),
                               &p == best ? 1 : 0, num(p.pop_rate, 6), num(p.time_to_detail_p50, 4));
        if (!out) throw Failure(fmt::format("cannot write '{}'", csv_file));
    }
    return csv_file;
}

std::string write_json(const BenchOptions& o, const SweepResult& r) {
    const std::vector<Point>& pts = r.pts;
    [[maybe_unused]] const Point* best = r.best;
    [[maybe_unused]] const unsigned w = r.w, h = r.h;
    [[maybe_unused]] const std::uint32_t frames = r.frames;
    const double total_s = r.total_s;
    // bench.json
    const std::string json_file = (fs::path(o.out) / "bench.json").string();
    {
        using nlohmann::json;
        const auto jn = [](double v) { return std::isfinite(v) ? json(v) : json(nullptr); };
        json j;
        j["size"] = o.texels;
        j["frames"] = frames;
        j["resolution"] = fmt::format("{}x{}", w, h);
        j["path"] = o.path;
        j["psnr_every"] = o.psnr_every;
        j["reference"] = "lossless zstd store of the same source, tile size and border";
        j["total_s"] = total_s;
        j["recommended"] = best ? json(best->label) : json(nullptr);
        json arr = json::array();
        for (const auto& p : pts) {
            json e;
            e["sweep"] = p.sweep;
            e["label"] = p.label;
            e["settings"] = {{"tile_size", p.s.tile},
                             {"border", p.s.border},
                             {"codec", std::string(tessera::to_string(p.s.codec))},
                             {"quality", p.s.codec == Codec::jpeg ? json(p.s.quality) : json(nullptr)},
                             {"page_format", p.s.page_format},
                             {"feedback_scale", p.s.feedback_scale},
                             {"pool", p.s.pool},
                             {"bias_policy", p.s.bias},
                             {"upload_pages_per_frame", p.s.upload},
                             {"latency_ms", p.s.latency_ms},
                             {"prefetch_lod", p.s.prefetch}};
            e["build_s"] = jn(p.build_s);
            e["store_bytes"] = p.store_bytes;
            e["frame_ms_mean"] = jn(p.frame_ms_mean);
            e["frame_ms_p99"] = jn(p.frame_ms_p99);
            e["full_detail_ms"] = jn(p.full_detail_ms);
            e["full_detail_reached"] = p.full_detail_reached;
            e["bytes_received"] = p.bytes_received;
            e["pages_requested"] = p.pages_requested;
            e["gpu_page_bytes"] = p.gpu_page_bytes;
            e["fallback_rate"] = jn(p.fallback);
            e["fallback_rate_biased"] = jn(p.fallback_biased);
            e["mean_lod_bias"] = jn(p.mean_bias);
            e["psnr_mean_db"] = jn(std::min(p.psnr_mean, 99.0));
            e["psnr_min_db"] = jn(std::min(p.psnr_min, 99.0));
            e["max_error"] = p.max_error;
            e["pop_rate"] = jn(p.pop_rate);
            e["time_to_detail_p50_frames"] = jn(p.time_to_detail_p50);
            e["wall_s"] = p.wall_s;
            e["recommended"] = &p == best;
            arr.push_back(std::move(e));
        }
        j["points"] = std::move(arr);
        std::ofstream out(json_file, std::ios::trunc);
        out << j.dump(2) << "\n";
        if (!out) throw Failure(fmt::format("cannot write '{}'", json_file));
    }
    return json_file;
}

void write_plots(const BenchOptions& o, const SweepResult& r) {
    const std::vector<Point>& pts = r.pts;
    [[maybe_unused]] const Point* best = r.best;
    [[maybe_unused]] const unsigned w = r.w, h = r.h;
    [[maybe_unused]] const std::uint32_t frames = r.frames;
    // Plots.
    const std::string where = fmt::format("{}x{}, {} frames of {}, terrain {}^2", w, h, frames, o.path, o.texels);
    const auto svg = [&](const char* name) { return (fs::path(o.out) / name).string(); };
    pareto_plot(pts, svg("pareto_frame_psnr.svg"), "tessera bench: frame time against PSNR (" + where + ")",
                "mean frame time (ms)", "mean PSNR (dB)", true,
                [](const Point& p) { return p.frame_ms_mean; }, [](const Point& p) { return std::min(p.psnr_mean, 99.0); });
    pareto_plot(pts, svg("pareto_bytes_psnr.svg"), "tessera bench: bytes moved against PSNR (" + where + ")",
                "bytes received (MiB)", "mean PSNR (dB)", true,
                [](const Point& p) { return double(p.bytes_received) / (1 << 20); },
                [](const Point& p) { return std::min(p.psnr_mean, 99.0); });
    pareto_plot(pts, svg("pareto_detail_fallback.svg"),
                "tessera bench: time to full detail against fallback (" + where + ")",
                "first view's time to full detail (ms)", "fallback pixels over the path (%)", false,
                [](const Point& p) { return p.full_detail_ms; }, [](const Point& p) { return 100 * p.fallback; });

}

void print_table(const SweepResult& r) {
    const std::vector<Point>& pts = r.pts;
    [[maybe_unused]] const Point* best = r.best;
    [[maybe_unused]] const unsigned w = r.w, h = r.h;
    [[maybe_unused]] const std::uint32_t frames = r.frames;
    // The table.
    fmt::print("\n{:<10} {:<24} {:>7} {:>9} {:>8} {:>8} {:>9} {:>10} {:>9} {:>7} {:>7} {:>4}\n", "sweep", "point",
               "build s", "store", "frame ms", "p99 ms", "detail ms", "received", "fallback", "PSNR", "min", "err");
    for (const auto& p : pts)
        fmt::print("{:<10} {:<24} {:>7.2f} {:>9} {:>8.2f} {:>8.2f} {:>8.0f}{} {:>10} {:>8.4f}% {:>7.2f} {:>7.2f} {:>4}{}\n",
                   p.sweep, p.label, p.build_s, human_bytes(p.store_bytes), p.frame_ms_mean, p.frame_ms_p99,
                   p.full_detail_ms, p.full_detail_reached ? " " : "!", human_bytes(p.bytes_received),
                   100 * p.fallback, std::min(p.psnr_mean, 99.0), std::min(p.psnr_min, 99.0), p.max_error,
                   &p == best ? "  <- recommended" : "");
    fmt::print("\n(!: the first view did not reach full detail within 10 s; error against a lossless zstd store "
               "of the same source)\n");
    if (best)
        fmt::print("recommended default: {} (fallback <= 0.01%, at most 2x the baseline's bytes, mean frame time "
                   "within 20% of the fastest such point, then the highest mean PSNR)\n",
                   best->label);
    else
        fmt::print("recommended default: none (no point kept the fallback rate at or under 0.01%)\n");
}

}  // namespace

const std::vector<std::string>& bench_sweeps() {
    static const std::vector<std::string> sweeps = {"tile", "border", "codec", "format", "feedback", "pool", "bias", "upload",
                                          "latency", "prefetch"};
    return sweeps;
}

int run_bench(const BenchOptions& o) {
    unsigned w = 0, h = 0;
    char x = 0;
    std::string res = o.resolution;
    std::uint32_t frames = o.frames;
    if (o.quick) {
        if (!o.resolution_given) res = "128x72";
        if (!o.frames_given) frames = 30;
    }
    if (std::sscanf(res.c_str(), "%u%c%u", &w, &x, &h) != 3 || (x != 'x' && x != 'X') || w < 16 || h < 16 ||
        w > 8192 || h > 8192)
        throw Failure(fmt::format("--resolution '{}': expected WIDTHxHEIGHT, each 16..8192", res), 2);
    const auto names = scene::CameraPath::builtin_names();
    if (std::find(names.begin(), names.end(), o.path) == names.end() && !fs::is_regular_file(o.path))
        throw Failure(fmt::format("--path '{}': not a built-in path ({}) nor a path file", o.path,
                                  fmt::join(names, ", ")),
                      2);
    std::error_code ec;
    fs::create_directories(fs::path(o.out) / "stores", ec);
    if (ec) throw Failure(fmt::format("--out '{}': cannot create the directory: {}", o.out, ec.message()));

    const std::set<std::string> only(o.only.begin(), o.only.end());
    std::vector<Point> pts = make_points(only, o.quick);
    const std::string input = fmt::format("procedural:terrain:{}", o.texels);
    fmt::print("tessera bench: {} points, {} frames each at {}x{} over '{}' (paced at 60 fps), store {}\n",
               pts.size(), frames, w, h, o.path, input);
    std::fflush(stdout);
    const auto t_start = Clock::now();

    // Stores, built once per store setting; the lossless references once per tile size and border.
    struct Built {
        std::string file;
        double seconds = 0;
        std::uint64_t bytes = 0;
    };
    std::map<std::string, Built> stores;
    auto build = [&](const Settings& s) -> const Built& {
        const std::string key = s.store_key();
        if (auto it = stores.find(key); it != stores.end()) return it->second;
        storage::BuildOptions bo;
        bo.tile_size = s.tile;
        bo.border = s.border;
        bo.codec = s.codec;
        bo.quality = s.quality;
        Built b;
        b.file = (fs::path(o.out) / "stores" / (key + ".tsr")).string();
        auto r = storage::build_store(input, b.file, bo);
        if (!r) throw Failure(fmt::format("building {} ({}): {}", b.file, key, r.error().message));
        b.seconds = r->seconds;
        b.bytes = fs::file_size(b.file);
        return stores.emplace(key, b).first->second;
    };

    for (std::size_t i = 0; i < pts.size(); ++i) {
        Point& p = pts[i];
        const auto t0 = Clock::now();
        const Built& st = build(p.s);
        p.build_s = st.seconds;
        p.store_bytes = st.bytes;
        Settings ref = p.s;
        ref.codec = Codec::zstd;
        const Built& rs = build(ref);

        ViewerOptions vo;
        vo.store = st.file;
        vo.reference_store = rs.file;
        vo.path = o.path;
        vo.width = w;
        vo.height = h;
        vo.frames = frames;
        vo.pool = p.s.pool;
        vo.page_format = p.s.page_format;
        vo.feedback_scale = p.s.feedback_scale;
        vo.prefetch_lod = p.s.prefetch;
        vo.upload_pages_per_frame = p.s.upload;
        vo.psnr_every = o.psnr_every;
        vo.link_latency_ms = p.s.latency_ms;
        vo.link_seed = i + 1;
        vo.bias = bias_policy(p.s.bias);
        vo.pace = true;
        vo.warmup_timeout_s = 10;
        vo.progress = false;
        vo.ram_cache_bytes = 256ull << 20;
        const ViewerReport rep = run_viewer(vo);
        p.frame_ms_mean = rep.mean_frame_ms();
        p.frame_ms_p99 = rep.frame_ms_quantile(0.99);
        p.full_detail_ms = rep.warmup_ms;
        p.full_detail_reached = rep.warmup_complete;
        p.bytes_received = rep.summary.bytes_received();
        p.pages_requested = rep.summary.pages_requested();
        p.fallback = rep.fallback_rate();
        p.fallback_biased = rep.fallback_rate_biased();
        p.psnr_mean = rep.mean_psnr();
        p.psnr_min = rep.min_psnr();
        p.max_error = rep.max_error();
        p.pop_rate = rep.mean_pop_rate();
        if (rep.summary.time_to_detail_count() > 0) p.time_to_detail_p50 = rep.summary.time_to_detail_quantile(0.5);
        p.mean_bias = rep.summary.mean_lod_bias();
        p.gpu_page_bytes = rep.gpu_page_bytes;
        p.wall_s = std::chrono::duration<double>(Clock::now() - t0).count();
        fmt::print("[{:2}/{}] {:<10} {:<24} {:5.2f} ms  full detail {:6.0f} ms{}  fallback {:8.4f}%  PSNR {} "
                   "(min {})  {:>9}  ({:.1f} s)\n",
                   i + 1, pts.size(), p.sweep, p.label, p.frame_ms_mean, p.full_detail_ms,
                   p.full_detail_reached ? " " : "!", 100 * p.fallback, psnr_text(p.psnr_mean), psnr_text(p.psnr_min),
                   human_bytes(p.bytes_received), p.wall_s);
        std::fflush(stdout);
    }
    SweepResult r;
    r.total_s = std::chrono::duration<double>(Clock::now() - t_start).count();
    r.w = w;
    r.h = h;
    r.frames = frames;
    r.pts = std::move(pts);
    r.best = recommend(r.pts);
    const std::string csv_file = write_csv(o, r);
    const std::string json_file = write_json(o, r);
    write_plots(o, r);
    print_table(r);
    fmt::print("\nwrote {}, {}, {}/pareto_*.svg in {}\n", csv_file, json_file, o.out, human_seconds(r.total_s));
    return 0;
}

}  // namespace tessera::tools
