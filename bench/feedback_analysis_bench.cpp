// Feedback analysis time (target: <= 30 us median at 160x90 on one core; van Waveren reported
// 0.5 ms for 80x60). Single thread.
//
// Buffers:
//   terrain   what a terrain camera writes: a pinhole camera 300 texels above a ground plane
//             (60 deg vertical field of view, 20 deg below the horizon, yawed 30 deg) carrying one
//             2^20-texel virtual texture (256-texel pages, 13 levels). The feedback buffer is 1/8
//             of the screen (160x90 of 1280x720, 320x180 of 2560x1440); per feedback pixel the
//             ray through its block centre hits the plane, the level is log2 of one screen pixel's
//             texel footprint under the GPU's 8x anisotropic rule; sky is kNoPage.
//   shuffled  the terrain buffer with its pixels randomly permuted: the same pages, no runs.
//   noise     every pixel a uniformly random page (random level, random x/y): the worst case.
// Residency comes from a page-table-like view (one array read per call): the 6 coarsest levels
// resident, plus two thirds of the terrain view's pages at levels >= 2 (so gaps vary).
//
// Each configuration is timed per call, interleaved in rounds against the others (the machine is
// shared and noisy), >= 2000 calls each; prints median / p90 / min in microseconds, then JSON.
// Usage: feedback_analysis_bench [--rounds N] [--per-round N] [--filter SUBSTRING] [--json FILE]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <numbers>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "feedback_analysis.hpp"

using namespace tessera::client;
using Clock = std::chrono::steady_clock;

namespace {

constexpr std::uint32_t kPageTexels = 256;
constexpr std::uint32_t kLevels = 13;  // 4096 pages per axis at level 0 .. 1 page at level 12
constexpr double kTexels = double(kPageTexels) * (1u << (kLevels - 1));
constexpr TextureId kTexture = 3;

struct Camera {
    double pos[3] = {kTexels * 0.37, kTexels * 0.41, 180.0};  // in level-0 texels; z up
    double fwd[3], right[3], up[3];
    double tan_half_fov = std::tan(30.0 * std::numbers::pi / 180.0);
    double screen_w = 1280, screen_h = 720;

    Camera(double pitch_deg, double yaw_deg) {
        const double p = pitch_deg * std::numbers::pi / 180.0, y = yaw_deg * std::numbers::pi / 180.0;
        fwd[0] = std::cos(p) * std::cos(y);
        fwd[1] = std::cos(p) * std::sin(y);
        fwd[2] = std::sin(p);
        right[0] = std::sin(y);
        right[1] = -std::cos(y);
        right[2] = 0;
        up[0] = right[1] * fwd[2] - right[2] * fwd[1];  // right x fwd
        up[1] = right[2] * fwd[0] - right[0] * fwd[2];
        up[2] = right[0] * fwd[1] - right[1] * fwd[0];
    }
    // Ground hit (z = 0) of the ray through screen point (sx, sy) (pixels, y down); false for sky.
    bool hit(double sx, double sy, double& u, double& v) const {
        const double aspect = screen_w / screen_h;
        const double nx = (2 * sx / screen_w - 1) * tan_half_fov * aspect;
        const double ny = (1 - 2 * sy / screen_h) * tan_half_fov;
        double d[3];
        for (int i = 0; i < 3; ++i) d[i] = fwd[i] + nx * right[i] + ny * up[i];
        if (d[2] >= -1e-9) return false;
        const double t = -pos[2] / d[2];
        u = pos[0] + t * d[0];
        v = pos[1] + t * d[1];
        return true;
    }
};

std::vector<FeedbackId> terrain_buffer(std::uint32_t w, std::uint32_t h, double pitch = -20.0, double height = 300.0,
                                      double max_aniso = 8.0) {
    Camera cam(pitch, 30.0);
    cam.pos[2] = height;
    cam.screen_w = 8.0 * w;  // feedback at 1/8 of the screen resolution
    cam.screen_h = 8.0 * h;
    std::vector<FeedbackId> ids(std::size_t{w} * h, kNoPage);
    const double bx = cam.screen_w / w, by = cam.screen_h / h;  // screen pixels per feedback pixel
    for (std::uint32_t y = 0; y < h; ++y)
        for (std::uint32_t x = 0; x < w; ++x) {
            const double sx = (x + 0.5) * bx, sy = (y + 0.5) * by;
            double u, v, ux, vx, uy, vy;
            if (!cam.hit(sx, sy, u, v) || !cam.hit(sx + 1, sy, ux, vx) || !cam.hit(sx, sy + 1, uy, vy)) continue;
            if (u < 0 || v < 0 || u >= kTexels || v >= kTexels) continue;
            // The GPU's anisotropic rule: up to max_aniso samples along the major axis of the footprint.
            const double px = std::hypot(ux - u, vx - v), py = std::hypot(uy - u, vy - v);
            const double rho = std::max(std::max(px, py) / max_aniso, std::min(px, py));
            const int level = std::clamp(int(std::floor(std::log2(std::max(rho, 1e-9)))), 0, int(kLevels) - 1);
            const double page = double(kPageTexels) * double(1u << level);
            ids[std::size_t{y} * w + x] =
                pack_feedback(PageKey{kTexture, std::uint8_t(level), std::uint32_t(u / page), std::uint32_t(v / page)});
        }
    return ids;
}

std::vector<FeedbackId> noise_buffer(std::uint32_t w, std::uint32_t h, std::mt19937& rng) {
    std::vector<FeedbackId> ids(std::size_t{w} * h);
    for (auto& id : ids) {
        const std::uint32_t level = rng() % kLevels, side = 1u << (kLevels - 1 - level);
        id = pack_feedback(PageKey{kTexture, std::uint8_t(level), std::uint32_t(rng() % side), std::uint32_t(rng() % side)});
    }
    return ids;
}

// A page table's answer: per level, per page, the level of the nearest resident ancestor-or-self.
class PageTableView final : public ResidencyView {
public:
    explicit PageTableView(const std::vector<FeedbackId>& wanted_view) : resident_(kLevels), fallback_(kLevels) {
        for (std::uint32_t l = 0; l < kLevels; ++l) {
            const std::size_t side = std::size_t{1} << (kLevels - 1 - l);
            resident_[l].assign(side * side, l >= kLevels - 6);
            fallback_[l].assign(side * side, ResidencyView::kNothingResident);
        }
        for (FeedbackId id : wanted_view) {
            if (id == kNoPage) continue;
            for (PageKey k = unpack_feedback(id); k.level < kLevels; k = k.parent())
                if (k.level >= 2 && (page_hash_key(k) * 0x9E3779B97F4A7C15ull) % 3 != 0) resident_[k.level][index(k)] = 1;
        }
        for (std::uint32_t l = kLevels; l-- > 0;) {
            const std::uint32_t side = 1u << (kLevels - 1 - l);
            for (std::uint32_t y = 0; y < side; ++y)
                for (std::uint32_t x = 0; x < side; ++x) {
                    const PageKey k{kTexture, std::uint8_t(l), x, y};
                    fallback_[l][index(k)] = resident_[l][index(k)] ? std::uint8_t(l)
                                             : l + 1 < kLevels      ? fallback_[l + 1][index(k.parent())]
                                                                    : ResidencyView::kNothingResident;
                }
        }
    }
    std::uint8_t resident_level(const PageKey& page) const override {
        if (page.texture != kTexture || page.level >= kLevels) return kNothingResident;
        return fallback_[page.level][index(page)];
    }

private:
    static std::size_t index(const PageKey& k) { return (std::size_t{k.y} << (kLevels - 1 - k.level)) + k.x; }
    std::vector<std::vector<std::uint8_t>> resident_, fallback_;
};

struct Config {
    Config(std::string n, std::uint32_t width, std::uint32_t height, std::vector<FeedbackId> buffer)
        : name(std::move(n)), w(width), h(height), ids(std::move(buffer)) {}
    std::string name;
    std::uint32_t w, h;
    std::vector<FeedbackId> ids;
    std::uint32_t runs = 0;  // runs of identical ids within rows
    FeedbackAnalyzer::Stats stats{};
    std::size_t out = 0;
    std::vector<double> us;
};

double percentile(std::vector<double> v, double p) {
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, std::size_t(p * double(v.size() - 1) + 0.5))];
}

}  // namespace

int main(int argc, char** argv) {
    int rounds = 20, per_round = 100;
    std::string json_path, filter;
    for (int i = 1; i + 1 < argc; ++i) {
        if (!std::strcmp(argv[i], "--filter")) filter = argv[i + 1];
        if (!std::strcmp(argv[i], "--rounds")) rounds = std::atoi(argv[i + 1]);
        if (!std::strcmp(argv[i], "--per-round")) per_round = std::atoi(argv[i + 1]);
        if (!std::strcmp(argv[i], "--json")) json_path = argv[i + 1];
    }
    std::mt19937 rng(2024);
    std::vector<Config> configs;
    for (auto [w, h] : {std::pair{160u, 90u}, std::pair{320u, 180u}}) {
        const std::string size = std::to_string(w) + "x" + std::to_string(h);
        auto terrain = terrain_buffer(w, h);
        auto shuffled = terrain;
        std::shuffle(shuffled.begin(), shuffled.end(), rng);
        configs.emplace_back("terrain " + size, w, h, terrain);
        configs.emplace_back("shuffled " + size, w, h, shuffled);
        configs.emplace_back("noise " + size, w, h, noise_buffer(w, h, rng));
    }
    std::erase_if(configs, [&](const Config& c) { return c.name.find(filter) == std::string::npos; });
    auto both = terrain_buffer(160, 90);
    const auto large = terrain_buffer(320, 180);
    both.insert(both.end(), large.begin(), large.end());
    const PageTableView residency(both);
    FeedbackAnalyzer analyzer;  // defaults: 65536 output pages, 131072 work pages
    analyzer.set_texture_levels(kTexture, kLevels);
    analyzer.set_texture_extent(kTexture, 1u << (kLevels - 1), 1u << (kLevels - 1));

    for (auto& c : configs) {
        for (std::uint32_t y = 0; y < c.h; ++y)
            for (std::uint32_t x = 0; x < c.w; ++x)
                c.runs += (x == 0 || c.ids[std::size_t{y} * c.w + x] != c.ids[std::size_t{y} * c.w + x - 1]);
        c.us.reserve(std::size_t(rounds) * per_round);
        for (int i = 0; i < 50; ++i) c.out = analyzer.analyse(c.ids, c.w, c.h, residency).size();  // warm up
        c.stats = analyzer.stats();
    }
    std::size_t sink = 0;
    for (int r = 0; r < rounds; ++r)
        for (auto& c : configs) {
            for (int i = 0; i < 5; ++i) sink += analyzer.analyse(c.ids, c.w, c.h, residency).size();  // re-warm
            for (int i = 0; i < per_round; ++i) {
                const auto t0 = Clock::now();
                sink += analyzer.analyse(c.ids, c.w, c.h, residency).size();
                const auto t1 = Clock::now();
                c.us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
            }
        }

    std::printf("%-18s %7s %7s %7s %8s %8s %10s %9s %9s %9s\n", "buffer", "vt px", "runs", "unique", "ancestor",
                "output", "calls", "median us", "p90 us", "min us");
    std::string json = "{\"bench\":\"feedback_analysis\",\"unit\":\"us\",\"results\":[";
    for (std::size_t i = 0; i < configs.size(); ++i) {
        const auto& c = configs[i];
        const double med = percentile(c.us, 0.5), p90 = percentile(c.us, 0.9), mn = percentile(c.us, 0.0);
        std::printf("%-18s %7u %7u %7u %8u %8zu %10zu %9.2f %9.2f %9.2f\n", c.name.c_str(), c.stats.vt_pixels, c.runs,
                    c.stats.unique_pages, c.stats.ancestor_pages, c.out, c.us.size(), med, p90, mn);
        char buf[512];
        std::snprintf(buf, sizeof buf,
                      "%s{\"buffer\":\"%s\",\"width\":%u,\"height\":%u,\"vt_pixels\":%u,\"runs\":%u,\"unique_pages\":%u,"
                      "\"ancestor_pages\":%u,\"output_pages\":%zu,\"calls\":%zu,\"median_us\":%.3f,\"p90_us\":%.3f,"
                      "\"min_us\":%.3f}",
                      i ? "," : "", c.name.c_str(), c.w, c.h, c.stats.vt_pixels, c.runs, c.stats.unique_pages,
                      c.stats.ancestor_pages, c.out, c.us.size(), med, p90, mn);
        json += buf;
    }
    json += "]}";
    std::printf("%s\n", json.c_str());
    if (!json_path.empty()) std::ofstream(json_path) << json << "\n";
    return sink == 0;  // keeps the calls observable
}
