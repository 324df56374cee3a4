// tessera loadtest, the application: N simulated viewers in one process, no GL (docs/loadtest.md).
//
// Each viewer is a real client runtime (residency, caches, scheduling, cancellation) over its own
// gRPC stream, optionally through an emulated link, fed with feedback from a recorded trace or
// computed on the CPU along a camera path. Viewers tick at a fixed frame rate on a fixed schedule
// whatever the server does (open model): a frame that starts late is counted late, a frame whose
// whole slot has passed is skipped and counted, and tile latency runs from the scheduled time of
// the frame that first asked for the tile, so a slow load generator cannot hide latency.
//
// Threads: a pool of --threads drivers (default min(viewers, cores)), each owning a fixed subset
// of viewers and running their frames in schedule order. Nothing else is created here; the
// sources and the runtime (transcode_threads 0: decoding happens inside frame()) own theirs.
#include <sys/resource.h>
#include <unistd.h>

#include <cmath>
#include <sstream>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <optional>
#include <random>
#include <regex>
#include <thread>
#include <unordered_map>
#include <vector>

#include "atomic_file.hpp"
#include "failure.hpp"
#include "loadtest.hpp"
#include "server_credentials.hpp"
#include "svg_plot.hpp"
#include "tessera/client/emulated_source.hpp"
#include "tessera/client/open_source.hpp"
#include "tessera/client/fakes/uploaders.hpp"
#include "tessera/client/feedback_trace.hpp"
#include "tessera/client/runtime.hpp"
#include "tessera/client/stats.hpp"
#include "tessera/client/tile_source.hpp"
#include "tessera/client/net/tile_stream_client.hpp"
#include "tessera/scene/cpu_feedback.hpp"
#include "tessera/scene/path.hpp"
#include "tessera/scene/scene.hpp"

namespace tessera::tools {

namespace {

using Clock = std::chrono::steady_clock;
using client::LatencyHistogram;

using Options = LoadTestOptions;


// CPU seconds (user + system) a process has used, from /proc/PID/stat; nullopt when unreadable.
std::optional<double> process_cpu_s(int pid) {
    std::ifstream f("/proc/" + std::to_string(pid) + "/stat");
    std::string line;
    if (!std::getline(f, line)) return std::nullopt;
    const auto close = line.rfind(')');  // the command name may hold spaces
    if (close == std::string::npos) return std::nullopt;
    std::istringstream rest(line.substr(close + 2));
    std::string field;
    double utime = 0, stime = 0;
    for (int i = 3; i <= 15 && rest >> field; ++i) {
        if (i == 14) utime = std::stod(field);
        if (i == 15) stime = std::stod(field);
    }
    return (utime + stime) / double(sysconf(_SC_CLK_TCK));
}

// This process's CPU seconds: the load generator's own cost.
double self_cpu_s() {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + double(u.ru_utime.tv_usec + u.ru_stime.tv_usec) * 1e-6;
}

// How every connection to the server is made: address, timeout, token, TLS roots (o.tls_ca holds
// the PEM text once the command has read it).
client::TileStreamOptions stream_options(const Options& o) {
    client::TileStreamOptions so;
    so.target = o.server;
    so.connect_timeout = std::chrono::milliseconds(static_cast<long>(o.connect_timeout * 1000));
    so.auth_token = o.token;
    if (o.tls) so.tls_root_certs_pem = o.tls_ca;
    return so;
}

// Per-second series, indexed by seconds since the measured window began.
struct Buckets {
    std::vector<double> fallback_px, pixels;  // pixel-weighted fallback
    std::vector<LatencyHistogram> latency;
    void grow(std::size_t n) {
        if (fallback_px.size() < n) {
            fallback_px.resize(n, 0.0);
            pixels.resize(n, 0.0);
            latency.resize(n);
        }
    }
};

// The outermost source of a viewer: counts what comes back and measures tile latency, request
// issued (the scheduled time of the frame that first asked) -> tile received by the client.
class MeasuringSource final : public client::TileSource {
public:
    explicit MeasuringSource(std::unique_ptr<client::TileSource> inner) : inner_(std::move(inner)) {}

    // Set by the viewer's driver before each frame.
    Clock::time_point frame_time{};
    Clock::time_point window_start{}, window_end{};
    bool measuring = false;
    std::uint64_t tiles = 0, bytes = 0, refused = 0, failed = 0, stale = 0, cancelled = 0;
    LatencyHistogram latency;
    Buckets* buckets = nullptr;

    Result<storage::StoreInfo> bind(client::TextureId texture, const std::string& store) override {
        return inner_->bind(texture, store);
    }
    void set_requests(std::uint64_t frame, std::span<const client::SourceRequest> requests) override {
        next_.clear();
        for (const auto& r : requests) {
            auto it = pending_.find(r.page);
            next_.emplace(r.page, it != pending_.end() ? it->second : frame_time);
        }
        if (measuring)
            for (const auto& [k, t] : pending_)
                if (!next_.contains(k)) ++cancelled;
        pending_.swap(next_);
        inner_->set_requests(frame, requests);
    }
    std::size_t poll(std::vector<client::SourceTile>& out, std::size_t max) override {
        const std::size_t first = out.size();
        const std::size_t n = inner_->poll(out, max);
        const auto now = Clock::now();
        for (std::size_t i = first; i < out.size(); ++i) {
            const auto& t = out[i];
            const auto received = t.received != Clock::time_point{} ? t.received : now;
            auto it = pending_.find(t.page);
            const bool counted = measuring && received >= window_start && received < window_end;
            if (counted) {
                if (t.status == TileStatus::resource_exhausted) ++refused;
                else if (t.status != TileStatus::ok) ++failed;
                else {
                    ++tiles;
                    bytes += t.data.payload.size();
                }
            }
            if (it == pending_.end()) {
                if (counted) ++stale;
                continue;
            }
            if (counted && t.status == TileStatus::ok) {
                latency.record(received - it->second);
                if (buckets) {
                    const auto sec = static_cast<std::size_t>(
                        std::chrono::duration<double>(received - window_start).count());
                    buckets->grow(sec + 1);
                    buckets->latency[sec].record(received - it->second);
                }
            }
            pending_.erase(it);  // refused or failed: asked again (a new request) next frame if still wanted
        }
        return n;
    }
    bool available() const override { return inner_->available(); }
    client::SourceLink link() const override { return inner_->link(); }
    std::string describe() const override { return inner_->describe(); }

private:
    struct KeyHash {
        std::size_t operator()(const client::PageKey& k) const {
            return std::hash<std::uint64_t>{}((std::uint64_t(k.texture) << 48) ^ (std::uint64_t(k.level) << 40) ^
                                              (std::uint64_t(k.x) << 20) ^ k.y);
        }
    };
    std::unique_ptr<client::TileSource> inner_;
    std::unordered_map<client::PageKey, Clock::time_point, KeyHash> pending_, next_;
};

struct Feedback {
    scene::VtGeometry geo;
    scene::CpuFeedbackParams params;
};

struct Viewer {
    unsigned id = 0;
    MeasuringSource* source = nullptr;  // owned by `owned_source`
    std::unique_ptr<client::TileSource> owned_source;
    client::NullUploader uploader;
    std::unique_ptr<client::Runtime> runtime;
    Clock::duration phase{};
    std::size_t trace_offset = 0;
    double path_offset = 0;
    std::vector<client::FeedbackId> ids;
    // Schedule and counters (touched only by the owning driver thread).
    std::uint64_t next_frame = 0;
    std::uint64_t frames = 0, late = 0, skipped = 0, unavailable = 0;
    // The source's count of refused streams at the first and the latest measured frame.
    std::optional<std::uint64_t> streams_refused_first;
    std::uint64_t streams_refused_last = 0;
    double fallback_px = 0, pixels = 0;
    LatencyHistogram lateness;
    Buckets buckets;
};

struct RunResult {
    unsigned viewers = 0, threads = 0;
    double seconds = 0;
    std::uint64_t frames = 0, late = 0, skipped = 0, unavailable = 0, streams_refused = 0;
    std::uint64_t tiles = 0, bytes = 0, refused = 0, failed = 0, stale = 0, cancelled = 0;
    LatencyHistogram latency, lateness;
    double fallback = 0;  // pixel-weighted
    std::vector<double> fallback_by_second, p99_by_second;
    std::vector<nlohmann::json> per_viewer;
    bool pass = false;
    // CPU over the measured window: the server's (--server-pid; negative when unknown) and this
    // generator's own. generator_bound: the generator could not keep its schedule (over 1% of
    // frames late or any skipped), so the step measures it, not the server.
    double server_cpu_s = -1, generator_cpu_s = 0;
    bool generator_bound = false;
    // Server CPU seconds per viewer-second; NaN without --server-pid.
    double server_cpu_per_viewer_s() const {
        return server_cpu_s < 0 || viewers == 0 ? std::nan("") : server_cpu_s / (double(viewers) * seconds);
    }
};

std::pair<std::uint32_t, std::uint32_t> parse_size(const std::string& s, const char* flag) {
    static const std::regex re(R"((\d+)x(\d+))");
    std::smatch m;
    if (!std::regex_match(s, m, re)) throw Failure(fmt::format("{} '{}': expected WIDTHxHEIGHT", flag, s), 2);
    const auto w = std::stoul(m[1].str()), h = std::stoul(m[2].str());
    if (w == 0 || h == 0 || w > 8192 || h > 8192) throw Failure(fmt::format("{} '{}': out of range", flag, s), 2);
    return {static_cast<std::uint32_t>(w), static_cast<std::uint32_t>(h)};
}

// With no tile received there is no latency: null, never 0 (which would read as instant).
nlohmann::json latency_json(const LatencyHistogram& h) {
    const auto ms = [&](double v) { return h.count() ? nlohmann::json(v) : nlohmann::json(nullptr); };
    return {{"count", h.count()},          {"mean", ms(h.mean_ms())},        {"p50", ms(h.quantile(0.5))},
            {"p90", ms(h.quantile(0.9))},  {"p99", ms(h.quantile(0.99))},    {"p999", ms(h.quantile(0.999))},
            {"max", ms(h.max_ms())}};
}

// A latency column's text: "-" when no tile was received.
std::string latency_cell(const LatencyHistogram& h, double ms) { return h.count() ? fmt::format("{:.2f}", ms) : "-"; }

class LoadTest {
public:
    LoadTest(const Options& o, const storage::StoreInfo& info, const std::vector<client::TraceFrame>* trace,
             const scene::CameraPath* path)
        : o_(o), info_(info), trace_(trace), path_(path) {}

    RunResult run(unsigned n) {
        const auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / o_.fps));
        // Viewers.
        std::vector<std::unique_ptr<Viewer>> viewers;
        const auto [fw, fh] = parse_size(o_.feedback_size, "--feedback-size");
        const auto [vw, vh] = parse_size(o_.view_size, "--view-size");
        for (unsigned i = 0; i < n; ++i) {
            auto v = std::make_unique<Viewer>();
            v->id = i;
            std::mt19937_64 rng(o_.seed * 0x9E3779B97F4A7C15ull + i);
            v->phase = std::chrono::duration_cast<Clock::duration>(
                std::uniform_real_distribution<double>(0, 1)(rng) * std::chrono::duration<double>(period));
            client::TileStreamOptions so = stream_options(o_);
            so.seed = o_.seed * 1000003 + i + 1;
            std::unique_ptr<client::TileSource> src = client::make_grpc_source(so);
            if (o_.latency_ms > 0 || o_.jitter_ms > 0 || o_.bandwidth_mbit > 0) {
                client::EmulatedLink link;
                link.latency = std::chrono::microseconds(static_cast<long>(o_.latency_ms * 1000));
                link.jitter = std::chrono::microseconds(static_cast<long>(o_.jitter_ms * 1000));
                link.bandwidth_bits_per_s = o_.bandwidth_mbit * 1e6;
                src = client::make_emulated_source(std::move(src), link, o_.seed * 7919 + i);
            }
            auto measuring = std::make_unique<MeasuringSource>(std::move(src));
            v->source = measuring.get();
            v->owned_source = std::move(measuring);
            client::RuntimeConfig cfg;
            cfg.residency.pool_slots = o_.pool;
            cfg.ram_cache_bytes = o_.ram_cache;
            cfg.transcode_threads = 0;  // decode on the driver thread: the thread count stays bounded
            cfg.upload_bytes_per_frame = cfg.upload_pages_per_frame * std::size_t(info_.tile_size()) * info_.tile_size() * 4;
            auto rt = client::Runtime::create(cfg, v->uploader);
            if (!rt) throw Failure(rt.error().message);
            v->runtime = std::move(*rt);
            auto tex = v->runtime->add_texture(*v->owned_source, o_.store);
            if (!tex) throw Failure(fmt::format("viewer {}: --store '{}': {}", i, o_.store, tex.error().message));
            if (trace_) {
                v->trace_offset = std::uniform_int_distribution<std::size_t>(0, 2 * trace_->size() - 1)(rng);
            } else {
                const double d = path_->duration();
                v->path_offset = (i + std::uniform_real_distribution<double>(0, 1)(rng)) * 2 * d / n;
                feedback_.params.main_width = vw;
                feedback_.params.main_height = vh;
                feedback_.params.fb_width = fw;
                feedback_.params.fb_height = fh;
                feedback_.params.texture = *tex;
                feedback_.geo = scene::VtGeometry{info_.width, info_.height, info_.tile_payload, info_.level_count()};
            }
            viewers.push_back(std::move(v));
        }

        // Schedule: frame k of viewer v at start + phase + k * period.
        const unsigned threads =
            o_.threads ? std::min(o_.threads, n) : std::min(n, std::max(1u, std::thread::hardware_concurrency()));
        const auto start = Clock::now() + std::chrono::milliseconds(100);
        const auto window_start = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(o_.warmup));
        const auto end = window_start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(o_.duration));
        for (auto& v : viewers) {
            v->source->window_start = window_start;
            v->source->window_end = end;
            v->source->buckets = &v->buckets;
        }
        std::vector<std::thread> pool;
        pool.reserve(threads);
        for (unsigned t = 0; t < threads; ++t)
            pool.emplace_back([&, t] {
                std::vector<Viewer*> mine;
                for (unsigned i = t; i < n; i += threads) mine.push_back(viewers[i].get());
                drive(mine, start, period, window_start, end);
            });
        // The CPU both sides used over the measured window.
        double server_cpu0 = -1, server_cpu1 = -1, gen_cpu0 = 0, gen_cpu1 = 0;
        std::thread sampler([&] {
            const auto sample = [&](double& server, double& gen) {
                gen = self_cpu_s();
                if (o_.server_pid > 0) server = process_cpu_s(o_.server_pid).value_or(-1);
            };
            std::this_thread::sleep_until(window_start);
            sample(server_cpu0, gen_cpu0);
            std::this_thread::sleep_until(end);
            sample(server_cpu1, gen_cpu1);
        });
        for (auto& th : pool) th.join();
        sampler.join();

        // Results.
        RunResult r;
        if (server_cpu0 >= 0 && server_cpu1 >= server_cpu0) r.server_cpu_s = server_cpu1 - server_cpu0;
        r.generator_cpu_s = gen_cpu1 - gen_cpu0;
        r.viewers = n;
        r.threads = threads;
        r.seconds = o_.duration;
        Buckets all;
        for (auto& v : viewers) {
            auto& s = *v->source;
            r.frames += v->frames;
            r.late += v->late;
            r.skipped += v->skipped;
            r.unavailable += v->unavailable;
            const std::uint64_t streams_refused =
                v->streams_refused_first ? v->streams_refused_last - *v->streams_refused_first : 0;
            r.streams_refused += streams_refused;
            r.tiles += s.tiles;
            r.bytes += s.bytes;
            r.refused += s.refused;
            r.failed += s.failed;
            r.stale += s.stale;
            r.cancelled += s.cancelled;
            r.latency.merge(s.latency);
            r.lateness.merge(v->lateness);
            all.grow(v->buckets.pixels.size());
            nlohmann::json fb = nlohmann::json::array();
            for (std::size_t b = 0; b < v->buckets.pixels.size(); ++b) {
                all.fallback_px[b] += v->buckets.fallback_px[b];
                all.pixels[b] += v->buckets.pixels[b];
                all.latency[b].merge(v->buckets.latency[b]);
                fb.push_back(v->buckets.pixels[b] > 0 ? v->buckets.fallback_px[b] / v->buckets.pixels[b] : 0.0);
            }
            r.per_viewer.push_back({{"viewer", v->id},
                                    {"frames", v->frames},
                                    {"late", v->late},
                                    {"skipped", v->skipped},
                                    {"disconnected", v->unavailable},
                                    {"streams_refused", streams_refused},
                                    {"tiles", s.tiles},
                                    {"refused", s.refused},
                                    {"failed", s.failed},
                                    {"latency_p99_ms", s.latency.quantile(0.99)},
                                    {"fallback", v->pixels > 0 ? v->fallback_px / v->pixels : 0.0},
                                    {"fallback_by_second", fb}});
        }
        double fpx = 0, px = 0;
        for (std::size_t b = 0; b < all.pixels.size(); ++b) {
            fpx += all.fallback_px[b];
            px += all.pixels[b];
            r.fallback_by_second.push_back(all.pixels[b] > 0 ? all.fallback_px[b] / all.pixels[b] : 0.0);
            r.p99_by_second.push_back(all.latency[b].count() ? all.latency[b].quantile(0.99) : std::nan(""));
        }
        r.fallback = px > 0 ? fpx / px : 0.0;
        r.generator_bound = r.skipped > 0 || double(r.late) > std::max(5.0, 0.01 * double(r.frames));
        // A step where the server turned viewers away does not hold, whatever the others saw.
        r.pass = r.latency.quantile(0.99) <= o_.ramp_p99_ms && r.fallback <= o_.ramp_fallback && r.tiles > 0 &&
                 r.failed == 0 && r.streams_refused == 0;
        // Runtimes go before their sources (Viewer member order); both before the next run starts.
        viewers.clear();
        return r;
    }

private:
    void drive(std::vector<Viewer*>& mine, Clock::time_point start, Clock::duration period,
               Clock::time_point window_start, Clock::time_point end) {
        auto sched = [&](const Viewer& v, std::uint64_t k) { return start + v.phase + period * static_cast<long>(k); };
        for (;;) {
            Viewer* v = nullptr;
            for (auto* c : mine)
                if (sched(*c, c->next_frame) < end && (!v || sched(*c, c->next_frame) < sched(*v, v->next_frame))) v = c;
            if (!v) return;
            const auto at = sched(*v, v->next_frame);
            std::this_thread::sleep_until(at);
            const auto began = Clock::now();
            const bool measuring = at >= window_start;
            v->source->frame_time = at;
            v->source->measuring = measuring;
            const float fallback_rate = frame(*v, at - start);
            if (measuring) {
                ++v->frames;
                v->lateness.record(began - at);
                if (began - at > period / 4) ++v->late;
                const client::SourceLink link = v->source->link();
                if (!link.connected) ++v->unavailable;
                if (!v->streams_refused_first) v->streams_refused_first = link.streams_refused;
                v->streams_refused_last = link.streams_refused;
                std::uint64_t px = 0;
                for (const auto id : v->ids) px += id != client::kNoPage;
                const double fallback = double(fallback_rate) * double(px);
                v->fallback_px += fallback;
                v->pixels += double(px);
                const auto sec = static_cast<std::size_t>(std::chrono::duration<double>(at - window_start).count());
                v->buckets.grow(sec + 1);
                v->buckets.fallback_px[sec] += fallback;
                v->buckets.pixels[sec] += double(px);
            }
            // Open model: slots that passed entirely while this frame ran are skipped, not made up.
            ++v->next_frame;
            const auto now = Clock::now();
            while (sched(*v, v->next_frame) + period <= now && sched(*v, v->next_frame) < end) {
                if (sched(*v, v->next_frame) >= window_start) ++v->skipped;
                ++v->next_frame;
            }
        }
    }

    // Runs one frame of `v`; returns its fallback rate (FrameStats::fallback_estimate).
    float frame(Viewer& v, Clock::duration since_start) {
        if (trace_) {
            // Back and forth through the trace, like the paths: no camera cut at the end.
            const std::size_t n = trace_->size();
            std::size_t i = (v.trace_offset + v.next_frame) % (2 * n);
            if (i >= n) i = 2 * n - 1 - i;
            const auto& f = (*trace_)[i];
            v.ids = f.ids;
            return v.runtime->frame(v.ids, f.width, f.height, f.bias).fallback_estimate;
        }
        // Back and forth along the path (no camera cut where a loop would jump back to the start).
        const double d = path_->duration();
        double t = std::fmod(v.path_offset + std::chrono::duration<double>(since_start).count(), 2 * d);
        if (t > d) t = 2 * d - t;
        auto params = feedback_.params;
        params.bias = v.runtime->lod_bias();
        scene::cpu_feedback(path_->at(t), feedback_.geo, params, v.ids);
        return v.runtime->frame(v.ids, params.fb_width, params.fb_height, params.bias).fallback_estimate;
    }

    const Options& o_;
    const storage::StoreInfo& info_;
    const std::vector<client::TraceFrame>* trace_;
    const scene::CameraPath* path_;
    Feedback feedback_;
};

void print_table(const std::vector<RunResult>& runs) {
    // Two header lines: the latency columns and the refusal columns (whole streams, single tiles)
    // are grouped. 57: the width of the columns before the latency's.
    std::string groups = fmt::format("{:57} {:^39} {:^14}", "", "tile latency (ms)", "refused");
    groups.erase(groups.find_last_not_of(' ') + 1);
    fmt::print("{}\n", groups);
    fmt::print("{:>7} {:>8} {:>6} {:>7} {:>7} {:>8} {:>8} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7} {:>6} {:>6} {:>9} {:>9} {:>8} {:>9}\n",
               "viewers", "frames", "late", "skipped", "discon", "tiles/s", "MB/s", "p50", "p90", "p99", "p99.9", "max",
               "streams", "tiles", "failed", "fallback", "srv-ms/vs", "gen-CPU", "limit");
    for (const auto& r : runs) {
        const auto& h = r.latency;
        const double per_vs = r.server_cpu_per_viewer_s();
        fmt::print("{:>7} {:>8} {:>6} {:>7} {:>7} {:>8.0f} {:>8.2f} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7} "
                   "{:>6} {:>6} {:>8.3f}% {:>9} {:>7.0f}% {:>9}\n",
                   r.viewers, r.frames, r.late, r.skipped, r.unavailable, r.tiles / r.seconds, r.bytes / r.seconds / 1e6,
                   latency_cell(h, h.quantile(0.5)), latency_cell(h, h.quantile(0.9)), latency_cell(h, h.quantile(0.99)),
                   latency_cell(h, h.quantile(0.999)), latency_cell(h, h.max_ms()), r.streams_refused,
                   r.refused, r.failed, r.fallback * 100, std::isnan(per_vs) ? std::string("-") : fmt::format("{:.2f}", per_vs * 1e3),
                   100 * r.generator_cpu_s / r.seconds, r.generator_bound ? "generator" : "-");
    }
    fmt::print("latency: ms, request issued (scheduled frame time) -> tile received (\"-\": no tile received); "
               "fallback: pixel-weighted\n");
    fmt::print("discon: frames run while the viewer's stream was down; refused streams: streams the server turned "
               "away (RESOURCE_EXHAUSTED: too many viewers); refused tiles: TILE_RESOURCE_EXHAUSTED replies (queues "
               "full); failed: other non-OK replies\n");
    fmt::print("srv-ms/vs: the server's CPU ms per viewer-second (--server-pid); gen-CPU: this load generator's CPU, "
               "% of one core; limit \"generator\": over 1% of frames (and 5) late, or any skipped, so the step measures "
               "the generator, not the server\n");
}

// Viewers one server core carries, from the busiest step that held (its targets met, no stream
// turned away, nothing failed) and that the generator kept up with; NaN without --server-pid or
// such a step. A step past the server's limit would understate its cost per viewer.
std::pair<double, unsigned> viewers_per_core(const std::vector<RunResult>& runs) {
    std::pair<double, unsigned> best{std::nan(""), 0};
    for (const auto& r : runs) {
        const double per_vs = r.server_cpu_per_viewer_s();
        if (!r.pass || r.refused > 0 || r.generator_bound || std::isnan(per_vs) || per_vs <= 0) continue;
        if (r.viewers >= best.second) best = {1.0 / per_vs, r.viewers};
    }
    return best;
}

nlohmann::json run_json(const RunResult& r) {
    return {{"viewers", r.viewers},
            {"threads", r.threads},
            {"seconds", r.seconds},
            {"frames", r.frames},
            {"frames_late", r.late},
            {"frames_skipped", r.skipped},
            {"frames_disconnected", r.unavailable},
            {"streams_refused", r.streams_refused},
            {"frame_lateness_ms", latency_json(r.lateness)},
            {"tiles", r.tiles},
            {"tiles_per_s", r.tiles / r.seconds},
            {"bytes", r.bytes},
            {"bytes_per_s", r.bytes / r.seconds},
            {"refused", r.refused},
            {"failed", r.failed},
            {"stale", r.stale},
            {"cancelled", r.cancelled},
            {"latency_ms", latency_json(r.latency)},
            {"fallback", r.fallback},
            {"fallback_by_second", r.fallback_by_second},
            {"pass", r.pass},
            {"server_cpu_s", r.server_cpu_s < 0 ? nlohmann::json(nullptr) : nlohmann::json(r.server_cpu_s)},
            {"server_cpu_s_per_viewer_s",
             std::isnan(r.server_cpu_per_viewer_s()) ? nlohmann::json(nullptr) : nlohmann::json(r.server_cpu_per_viewer_s())},
            {"generator_cpu_s", r.generator_cpu_s},
            {"generator_bound", r.generator_bound},
            {"per_viewer", r.per_viewer}};
}

void write_plot(const Options& o, const std::vector<RunResult>& runs, const std::string& file) {
    Plot p;
    static const char* colours[] = {"#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2"};
    if (runs.size() == 1) {
        const auto& r = runs[0];
        p.title = fmt::format("tessera loadtest: {} viewers at {} fps", r.viewers, o.fps);
        p.x_label = "time (s, after warm-up)";
        p.y_label = "fallback (%)";
        p.y2_label = "tile latency p99 (ms)";
        for (std::size_t i = 0; i < r.per_viewer.size() && i < 8; ++i) {
            PlotSeries s{fmt::format("viewer {} fallback", i), {}, {}, colours[i % 7]};
            const auto& fb = r.per_viewer[i]["fallback_by_second"];
            for (std::size_t b = 0; b < fb.size(); ++b) {
                s.x.push_back(double(b) + 0.5);
                s.y.push_back(fb[b].get<double>() * 100);
            }
            p.series.push_back(std::move(s));
        }
        PlotSeries all{"all viewers fallback", {}, {}, "#000000"};
        PlotSeries lat{"tile latency p99", {}, {}, "#d62728", true, true};
        for (std::size_t b = 0; b < r.fallback_by_second.size(); ++b) {
            all.x.push_back(double(b) + 0.5);
            all.y.push_back(r.fallback_by_second[b] * 100);
            lat.x.push_back(double(b) + 0.5);
            lat.y.push_back(r.p99_by_second[b]);
        }
        p.series.push_back(std::move(all));
        p.series.push_back(std::move(lat));
    } else {
        p.title = fmt::format("tessera loadtest: latency and fallback vs viewers ({} fps)", o.fps);
        p.x_label = "viewers";
        p.y_label = "tile latency (ms)";
        p.y2_label = "fallback (%)";
        PlotSeries p50{"p50", {}, {}, colours[0]}, p99{"p99", {}, {}, colours[1]},
            p999{"p99.9", {}, {}, colours[2]}, fb{"fallback", {}, {}, colours[3], false, true};
        for (const auto& r : runs) {
            if (r.latency.count() > 0) {  // a step with no tile received has no latency to plot
                p50.x.push_back(r.viewers);
                p50.y.push_back(r.latency.quantile(0.5));
                p99.x.push_back(r.viewers);
                p99.y.push_back(r.latency.quantile(0.99));
                p999.x.push_back(r.viewers);
                p999.y.push_back(r.latency.quantile(0.999));
            }
            fb.x.push_back(r.viewers);
            fb.y.push_back(r.fallback * 100);
        }
        p.series = {p50, p99, p999, fb};
    }
    write_svg(p, file);
}

}  // namespace

int run_loadtest(LoadTestOptions o) {
    if (o.server_pid > 0 && !process_cpu_s(o.server_pid))
        throw Failure(fmt::format("--server-pid {}: no such process here (/proc/{}/stat)", o.server_pid, o.server_pid), 2);
    if (o.path.empty() && o.trace.empty()) o.path = "flyover";
    // The outputs before the run, which may take minutes: a path that cannot be written fails now.
    if (!o.json.empty()) check_writable(o.json);
    if (!o.plot.empty()) check_writable(o.plot);
    // Credentials once (a bad file fails here), then reach the server first: a clear error
    // instead of N viewers timing out.
    if (o.server.rfind("grpcs://", 0) == 0) {
        o.server = o.server.substr(8);
        o.tls = true;
    } else if (o.server.rfind("grpc://", 0) == 0) {
        o.server = o.server.substr(7);
    }
    if (Status st = client::check_grpc_target(o.server); !st) throw Failure("--server " + st.error().message, 2);
    if (!o.tls_ca.empty()) o.tls = true;
    o.token = bearer_token(o.token, o.token_file);
    o.token_file.clear();
    if (o.tls) o.tls_ca = tls_roots_pem(o.tls_ca);  // from here on: the PEM text
    client::TileStreamOptions so = stream_options(o);
    auto probe = client::TileStreamClient::create(so);
    auto meta = probe->get_store(o.store, so.connect_timeout);
    if (!meta) {
        const bool maybe_tls = !o.tls && meta.error().message.find("UNAVAILABLE") != std::string::npos;
        throw Failure(fmt::format("--server {} --store {}: {}{}", o.server, o.store, meta.error().message,
                                  maybe_tls ? " (if the server is TLS-only, use grpcs://HOST:PORT or --tls)" : ""));
    }
    probe.reset();
    auto geometry_source = client::make_grpc_source(so);
    auto info = geometry_source->bind(0, o.store);
    if (!info) throw Failure(fmt::format("--store {}: {}", o.store, info.error().message));
    geometry_source.reset();
    parse_size(o.feedback_size, "--feedback-size");
    parse_size(o.view_size, "--view-size");

    // Feedback: a trace, or a camera path over the terrain scene sized to the store.
    std::vector<client::TraceFrame> trace_frames;
    std::optional<scene::CameraPath> path;
    std::string feedback_name;
    if (!o.trace.empty()) {
        auto t = client::read_trace(o.trace);
        if (!t) throw Failure(fmt::format("--trace {}: {}", o.trace, t.error().message));
        if (t->empty()) throw Failure(fmt::format("--trace {}: no frames", o.trace));
        // A trace names pages of the store it was recorded on; replayed on another, its pages
        // fall outside this one (and would be refused, never requested: a perfect-looking run).
        std::uint64_t pages = 0, outside = 0;
        for (const client::TraceFrame& f : *t)
            for (const FeedbackId id : f.ids) {
                if (id == kNoPage) continue;
                const PageKey k = unpack_feedback(id);
                ++pages;
                outside += k.level >= info->level_count() || k.x >= info->levels[k.level].tiles_x ||
                           k.y >= info->levels[k.level].tiles_y;
            }
        if (outside > 0)
            throw Failure(fmt::format("--trace {}: {} of its {} page requests are outside store {} ({}x{}, {} levels): it was "
                                      "recorded on another store",
                                      o.trace, outside, pages, o.store, info->width, info->height, info->level_count()),
                          2);
        trace_frames = std::move(*t);
        feedback_name = "trace:" + o.trace;
    } else {
        scene::TerrainOptions t;
        t.vt_width = info->width;
        t.vt_height = info->height;
        while (std::max(info->width, info->height) / t.chunk_texels > 64) t.chunk_texels *= 2;
        auto sc = scene::make_terrain(t);
        if (!sc) throw Failure(sc.error().message);
        auto p = scene::CameraPath::builtin_or_file(o.path, *sc);
        if (!p) throw Failure(fmt::format("--path: {}", p.error().message), 2);
        path = std::move(*p);
        feedback_name = "path:" + o.path;
    }

    LoadTest lt(o, *info, trace_frames.empty() ? nullptr : &trace_frames, path ? &*path : nullptr);
    std::vector<unsigned> steps = o.viewers;
    if (o.ramp) {
        steps.clear();
        for (unsigned n = 1; n <= o.max_viewers; n *= 2) steps.push_back(n);
        if (steps.back() != o.max_viewers) steps.push_back(o.max_viewers);
    }
    std::vector<RunResult> runs;
    std::optional<unsigned> best;
    struct FailedStep {
        unsigned viewers;
        std::string error;
        int code;
    };
    std::optional<FailedStep> failed_step;
    for (unsigned n : steps) {
        if (!o.quiet) {
            fmt::print(stderr, "loadtest: {} viewer{} for {:.1f} s (+{:.1f} s warm-up) ...\n", n, n == 1 ? "" : "s",
                       o.duration, o.warmup);
            std::fflush(stderr);
        }
        // A step that fails (its viewers cannot connect) ends the run; the steps before it are still
        // reported, and the exit status is the failure's.
        try {
            runs.push_back(lt.run(n));
        } catch (const Failure& f) {
            if (runs.empty()) throw;
            failed_step = {n, f.what(), f.code};
            fmt::print(stderr, "loadtest: the {}-viewer step failed: {}; the steps before it are reported\n", n, f.what());
            break;
        }
        if (o.ramp) {
            const auto& r = runs.back();
            if (!o.quiet)
                fmt::print(stderr, "loadtest: {} viewers: {}, fallback {:.4f}% -> {}\n", n,
                           r.latency.count() ? fmt::format("p99 {:.2f} ms", r.latency.quantile(0.99)) : "no tile received",
                           r.fallback * 100, r.pass ? "holds" : "does not hold");
            if (!r.pass) {  // more viewers only load the server (or the generator) more
                if (r.generator_bound && !o.quiet)
                    fmt::print(stderr, "loadtest: the generator could not keep up at {} viewers: the ramp measured "
                                       "it, not the server\n", n);
                break;
            }
            best = n;
        }
    }
    fmt::print("tessera loadtest: {} store {}, feedback {}, {} fps, {:.1f} s measured (+{:.1f} s warm-up)\n",
               o.server, o.store, feedback_name, o.fps, o.duration, o.warmup);
    print_table(runs);
    if (o.ramp) {
        if (best)
            fmt::print("ramp: {} viewers hold p99 <= {} ms and fallback <= {}%\n", *best, o.ramp_p99_ms,
                       o.ramp_fallback * 100);
        else
            fmt::print("ramp: no step holds p99 <= {} ms and fallback <= {}%\n", o.ramp_p99_ms, o.ramp_fallback * 100);
    }
    const auto [per_core, from_step] = viewers_per_core(runs);
    const unsigned cores = o.replica_cores ? o.replica_cores : std::max(1u, std::thread::hardware_concurrency());
    const double replicas = std::ceil(double(o.plan_viewers) / (per_core * cores));
    if (o.server_pid > 0) {
        if (std::isnan(per_core))
            fmt::print("capacity: no step measured the server (none held its targets with the generator keeping up)\n");
        else
            fmt::print("capacity: {:.0f} viewers per server core (server CPU {:.2f} ms per viewer-second at {} "
                       "viewers); {} viewers need {:.0f} replica{} of {} cores at full CPU (plan for headroom)\n",
                       per_core, 1e3 / per_core, from_step, o.plan_viewers, replicas, replicas == 1 ? "" : "s", cores);
    }
    if (!o.json.empty()) {
        nlohmann::json j;
        if (o.server_pid > 0)
            j["capacity"] = {{"viewers_per_core", std::isnan(per_core) ? nlohmann::json(nullptr) : nlohmann::json(per_core)},
                             {"from_step_viewers", from_step},
                             {"plan_viewers", o.plan_viewers},
                             {"replica_cores", cores},
                             {"replicas", std::isnan(per_core) ? nlohmann::json(nullptr) : nlohmann::json(replicas)}};
        j["tool"] = "tessera loadtest";
        j["server"] = o.server;
        j["store"] = o.store;
        j["feedback"] = feedback_name;
        j["fps"] = o.fps;
        j["duration_s"] = o.duration;
        j["warmup_s"] = o.warmup;
        j["seed"] = o.seed;
        j["pool_pages"] = o.pool;
        j["ram_cache_bytes"] = o.ram_cache;
        j["link"] = {{"latency_ms", o.latency_ms}, {"jitter_ms", o.jitter_ms}, {"bandwidth_mbit", o.bandwidth_mbit}};
        j["latency_definition"] = "request issued (scheduled time of the frame that first asked) -> tile received";
        j["runs"] = nlohmann::json::array();
        for (const auto& r : runs) j["runs"].push_back(run_json(r));
        if (failed_step) j["failed_step"] = {{"viewers", failed_step->viewers}, {"error", failed_step->error}};
        if (o.ramp) {
            j["ramp"] = {{"p99_target_ms", o.ramp_p99_ms},
                         {"fallback_target", o.ramp_fallback},
                         {"max_viewers", o.max_viewers},
                         {"best_viewers", best ? nlohmann::json(*best) : nlohmann::json(nullptr)}};
        }
        write_file_atomically(o.json, [&](std::ostream& f) { f << j.dump(2) << "\n"; });
    }
    if (!o.plot.empty()) write_plot(o, runs, o.plot);
    if (failed_step) {
        fmt::print(stderr, "tessera: error: the {}-viewer step: {}\n", failed_step->viewers, failed_step->error);
        return failed_step->code;
    }
    return 0;
}

}  // namespace tessera::tools
