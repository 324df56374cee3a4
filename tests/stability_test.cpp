// Numerical-stability stress: huge virtual textures, CPU side. docs/stability.md reports
// the method and the numbers these tests print.
//
//   StabilityAddressing  the shader's texel addressing (vt_sample.glsl, vt_level_position) mirrored
//                        in float32 as the GPU runs it, against exact integer math, at every level
//                        near the far corner of 2^10 .. 2^24-texel textures (and odd sizes); where
//                        the float local offset stops being exact (chunk size); no texel index, so
//                        no wrap below the uint32 chunk origin's 2^32.
//   StabilityLod         the LoD rule at extreme, degenerate and grazing derivatives; the GPU's
//                        float evaluation agrees with the double rule; a static camera is
//                        deterministic and tiny jitter only moves pixels on a boundary.
//   StabilityFeedbackId  the 64-bit id and the shader's two-word encoding at their limits.
//   StabilityPageTable   dense page-table math for 2^20 pages per axis: sizes without overflow,
//                        the byte bound as a clear error, map/unmap at the far corner of the
//                        largest table under the bound.
//   StabilityPriority    feedback analysis of 10^6 distinct pages: strictly ordered, identical
//                        across runs, analysers and distance-preserving permutations of the buffer.
#include <gtest/gtest.h>
#include <time.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <vector>

#include "feedback_analysis.hpp"
#include "tessera/client/page.hpp"
#include "page_table.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/scene/cpu_feedback.hpp"
#include "tessera/scene/lod.hpp"
#include "tessera/storage/types.hpp"

namespace {

namespace sc = tessera::scene;
namespace st = tessera::storage;
using tessera::Errc;
using tessera::client::FeedbackAnalyzer;
using tessera::client::FeedbackId;
using tessera::client::kMaxPagesPerAxis;
using tessera::client::kNoPage;
using tessera::client::PageKey;
using tessera::client::PageTable;
using tessera::client::ResidencyView;
using tessera::client::WantedPage;

constexpr std::uint32_t kPayload = 248;  // the default 256-texel tile with a 4-texel border

// CPU time of the calling thread: unlike wall time it does not grow when the machine is busy
// (other processes, a parallel ctest), so ratios of it measure the work done.
double thread_cpu_seconds() {
    timespec ts{};
    ::clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + double(ts.tv_nsec) * 1e-9;
}

// ---------------------------------------------------------------------------------------------
// Addressing. vt_level_position in float32, as the GPU evaluates it (one axis). The chunk's page
// frame (SceneGeometry::set_page_layout): page0 = origin / P, base = origin - page0 * P. Then
//     q0 = base + local;  b = page0 & (2^L - 1);  q = (float(b) * P + q0) * 2^-L
//     k = floor(q / P) (float), r = q - k * P, corrected into [0, P);  page = (page0 >> L) + k
// `local` is the interpolated float offset from the chunk's integer texel origin. The GPU may fuse
// float(b) * P + q0 into one rounding; this mirror rounds twice, the worse case.
struct GpuPos {
    std::int64_t texel;  // page * P + floor(in_page): the texel the position lies in
    float frac;          // in_page - floor(in_page)
};

GpuPos gpu_level_position(std::uint32_t origin, float local, std::uint32_t level) {
    const std::uint32_t page0 = origin / kPayload;
    const float base = static_cast<float>(origin - page0 * kPayload);  // below P: exact
    const float payload = static_cast<float>(kPayload);
    const float q0 = base + local;
    const float b = static_cast<float>(static_cast<std::int32_t>(page0 & ((std::uint64_t{1} << level) - 1)));
    const float scaled = b * payload;
    const float q = std::ldexp(scaled + q0, -static_cast<int>(level));  // exact: a power-of-two scale
    const float k = std::floor(q * (1.0f / payload));
    const float r = q - k * payload;
    const float fix = static_cast<float>(r >= payload) - static_cast<float>(r < 0.0f);
    const float in_page = r - fix * payload;
    const std::int64_t page = static_cast<std::int64_t>(page0 >> level) + static_cast<std::int64_t>(k + fix);
    const float whole = std::floor(in_page);
    return GpuPos{page * kPayload + static_cast<std::int64_t>(whole), in_page - whole};
}

// Exact: level-L texel and fraction of level-0 coordinate t = num / 2^sub (integers).
struct ExactPos {
    std::int64_t texel;
    long double frac;
};
ExactPos exact_level_position(std::int64_t num, std::uint32_t sub, std::uint32_t level) {
    const std::int64_t den = std::int64_t{1} << (sub + level);
    const std::int64_t texel = num >= 0 ? num / den : -((-num + den - 1) / den);
    return ExactPos{texel, static_cast<long double>(num - texel * den) / static_cast<long double>(den)};
}

struct AddressingResult {
    std::uint64_t checked = 0;
    std::uint64_t wrong_texel = 0;
    std::uint64_t wrong_frac = 0;
    int first_bad_level = -1;
};

// Level-L texels near the far corner of a `size`-texel axis (and at its last page boundaries), at
// sub-texel positions f / 256 of a level-L texel (f = 1, 128 (the centre), 255); the chunk that holds
// the point has side `chunk` (make_terrain's chunking: origin = floor(t / chunk) * chunk), so the
// local offset is below `chunk`. Checks the float mirror against exact integer math.
AddressingResult check_addressing(std::uint32_t size, std::uint32_t chunk, std::uint32_t levels) {
    AddressingResult r;
    constexpr std::uint32_t kSub = 8;  // positions in 1/256 of a level-L texel
    for (std::uint32_t level = 0; level < levels; ++level) {
        const std::uint64_t n = (std::uint64_t(size) + (std::uint64_t(1) << level) - 1) >> level;  // level texels
        std::vector<std::uint64_t> texels;
        for (std::uint64_t d = 1; d <= 4 && d <= n; ++d) texels.push_back(n - d);
        const std::uint64_t last_page = (n - 1) / kPayload;
        for (std::uint64_t p = last_page; p + 3 > last_page && p > 0; --p)
            for (const std::uint64_t t : {p * kPayload - 1, p * kPayload})
                if (t < n) texels.push_back(t);
        for (const std::uint64_t i : texels)
            for (const std::uint32_t f : {1u, 128u, 255u}) {
                // Level-0 coordinate t = (i + f/256) * 2^L = num / 2^kSub.
                const std::int64_t num = static_cast<std::int64_t>(((i << kSub) + f) << level);
                const std::uint64_t t0 = static_cast<std::uint64_t>(num >> kSub);  // floor(t)
                const std::uint64_t origin = t0 / chunk * chunk;
                // The local offset as the vertex stage hands it over: t - origin rounded to float.
                const long double local_exact = static_cast<long double>(num) / (1 << kSub) - static_cast<long double>(origin);
                const float local = static_cast<float>(local_exact);
                const GpuPos g = gpu_level_position(static_cast<std::uint32_t>(origin), local, level);
                const ExactPos e = exact_level_position(num, kSub, level);
                ++r.checked;
                const bool texel_ok = g.texel == e.texel;
                const bool frac_ok = texel_ok && static_cast<long double>(g.frac) == e.frac;
                if (!texel_ok) ++r.wrong_texel;
                if (texel_ok && !frac_ok) ++r.wrong_frac;
                if ((!texel_ok || !frac_ok) && r.first_bad_level < 0) r.first_bad_level = static_cast<int>(level);
            }
    }
    return r;
}

std::vector<std::uint32_t> stress_sizes() {
    std::vector<std::uint32_t> s;
    for (std::uint32_t e = 10; e <= 24; e += 2) s.push_back(1u << e);
    s.push_back((1u << 24) - 1);
    s.push_back(3u * (1u << 20) + 5);
    return s;
}

TEST(StabilityAddressing, ExactAtEveryLevelNearTheFarCornerUpTo2To24) {
    std::printf("  size        levels  chunk 4096 (default)    chunk 2^15    chunk 2^16      chunk 2^18      one chunk (= size)\n");
    for (const std::uint32_t size : stress_sizes()) {
        const std::uint32_t levels = static_cast<std::uint32_t>(st::level_geometry(size, size, kPayload).size());
        const AddressingResult def = check_addressing(size, 4096, levels);
        EXPECT_GT(def.checked, 50u);
        // The default chunking (make_terrain's 4096) is exact everywhere, every level, 1/256 texel.
        EXPECT_EQ(def.wrong_texel, 0u) << size;
        EXPECT_EQ(def.wrong_frac, 0u) << size;
        // Chunks up to 2^15 texels keep 1/256 of a level-0 texel: base + local < P + 2^15 < 2^16
        // leaves 8 fraction bits of the float's 24. A 2^16 chunk may lose the last one at level 0.
        const AddressingResult c15 = check_addressing(size, 1u << 15, levels);
        EXPECT_EQ(c15.wrong_texel + c15.wrong_frac, 0u) << size;
        const AddressingResult c16 = check_addressing(size, 1u << 16, levels);
        const AddressingResult c18 = check_addressing(size, 1u << 18, levels);
        const AddressingResult one = check_addressing(size, size, levels);
        // Up to 2^16 texels one chunk is exact (its origin 0 has base 0); a 2^18 chunk loses the
        // 1/256 fraction at level 0 (the float's 24 bits: 18 integer + 6 fraction), texel centres
        // stay right.
        if (size <= (1u << 16)) {
            EXPECT_EQ(one.wrong_texel + one.wrong_frac, 0u) << size;
        }
        if (size >= (1u << 18)) {
            EXPECT_GT(c18.wrong_texel + c18.wrong_frac, 0u) << size;
        }
        auto cell = [](const AddressingResult& a) {
            static char buf[8][64];
            static int k = 0;
            char* b = buf[k++ & 7];
            if (a.wrong_texel + a.wrong_frac == 0)
                std::snprintf(b, 64, "exact");
            else
                std::snprintf(b, 64, "%llu/%llu bad, L%d", static_cast<unsigned long long>(a.wrong_texel + a.wrong_frac),
                              static_cast<unsigned long long>(a.checked), a.first_bad_level);
            return b;
        };
        std::printf("  %-10u  %6u  %-22s  %-12s  %-14s  %-14s  %s (texels wrong: %llu)\n", size, levels, cell(def), cell(c15),
                    cell(c16), cell(c18), cell(one), static_cast<unsigned long long>(one.wrong_texel));
    }
}

// The local offset alone: which chunk sides keep a texel centre (x.5) and a 1/256 position exact
// at level 0, and where bilinear weights start to move (the float's 24-bit significand).
TEST(StabilityAddressing, LocalOffsetPrecisionByChunkSide) {
    for (std::uint32_t e = 10; e <= 25; ++e) {
        const double side = std::ldexp(1.0, static_cast<int>(e));
        const double centre = side - 0.5, fine = side - 1.0 / 256;
        const bool centre_exact = static_cast<double>(static_cast<float>(centre)) == centre;
        const bool fine_exact = static_cast<double>(static_cast<float>(fine)) == fine;
        // A float holds 24 significant bits: x.5 below 2^23, x/256 below 2^16.
        EXPECT_EQ(centre_exact, e <= 23) << e;
        EXPECT_EQ(fine_exact, e <= 16) << e;
    }
}

// The shader holds no texel index, only pages (int32: page0 < 2^32 / P) and the position in the
// page: exact across the whole range of the uint32 chunk origin, past 2^31 without a wrap.
TEST(StabilityAddressing, PageFrameCoversTheWholeUint32Origin) {
    const GpuPos last = gpu_level_position(0xFFFFFFFFu - 4095u, 4095.5f, 0);
    EXPECT_EQ(last.texel, (std::int64_t{1} << 32) - 1);
    EXPECT_EQ(last.frac, 0.5f);
    const GpuPos past31 = gpu_level_position(1u << 31, 0.5f, 0);
    EXPECT_EQ(past31.texel, std::int64_t{1} << 31);
    EXPECT_EQ(past31.frac, 0.5f);
    const GpuPos far = gpu_level_position((1u << 24) - 4096, 4095.5f, 0);
    EXPECT_EQ(far.texel, (std::int64_t{1} << 24) - 1);
    // The centre of the last texel of every level of a 2^32 - 1 texture, from its 4096-texel chunk.
    for (std::uint32_t level = 1; level < 32; ++level) {
        const std::uint64_t final_texel = ((std::uint64_t{1} << 32) - 2) >> level;  // level-L texels of 2^32 - 1, less one
        const double t = (double(final_texel) + 0.5) * std::ldexp(1.0, int(level));   // level-0 coordinate, exact
        const auto origin = static_cast<std::uint32_t>(std::uint64_t(t) / 4096 * 4096);
        const GpuPos g = gpu_level_position(origin, static_cast<float>(t - origin), level);
        EXPECT_EQ(g.texel, std::int64_t(final_texel)) << level;
        EXPECT_EQ(g.frac, 0.5f) << level;
    }
}

// ---------------------------------------------------------------------------------------------
// LoD.

// The GLSL evaluation (vt_lod + vt_wanted_level) in float32.
std::uint32_t gpu_wanted_level(float dux, float dvx, float duy, float dvy, sc::LodRule rule, float bias, std::uint32_t levels) {
    const float rho_x = std::sqrt(dux * dux + dvx * dvx), rho_y = std::sqrt(duy * duy + dvy * dvy);
    const float major = std::max(rho_x, rho_y), minor = std::min(rho_x, rho_y);
    float lod = rule.filter == sc::SampleFilter::anisotropic
                    ? std::log2(std::max(minor, major / static_cast<float>(rule.max_anisotropy)))
                    : std::log2(major);
    if (std::isnan(rho_x) || std::isnan(rho_y)) lod = std::numeric_limits<float>::quiet_NaN();
    return sc::wanted_level(lod + bias, rule.filter, levels);
}

TEST(StabilityLod, ExtremeDegenerateAndGrazingDerivatives) {
    const float inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
    std::vector<double> mags = {0.0, 4.9e-324, 1e-310, 1.17e-38, 1e-45, 1e-30, 1e-20, 1e20, 1e30, 3.4e38, 1e300, inf, nan};
    for (int e = -40; e <= 40; ++e) mags.push_back(std::ldexp(1.0, e) * 1.3);
    std::uint64_t cases = 0, float_disagree = 0;
    for (const auto filter : {sc::SampleFilter::bilinear, sc::SampleFilter::trilinear, sc::SampleFilter::anisotropic})
        for (const std::uint32_t levels : {1u, 5u, 17u, 32u})
            for (const double a : mags)
                for (const double ratio : {1.0, 3.0, 1e3, 1e7, 1e-7, 0.0})
                    for (const double sign : {1.0, -1.0}) {
                        const sc::LodRule rule{filter, 8};
                        const double b = a * ratio;
                        // Grazing: the y footprint `ratio` times the x one, along a skewed axis.
                        const double dux = sign * a, dvx = 0.25 * a, duy = -0.5 * b, dvy = b;
                        const float lod = sc::lod_from_derivatives(dux, dvx, duy, dvy, rule);
                        const std::uint32_t lv = sc::wanted_level(lod, filter, levels);
                        ++cases;
                        ASSERT_LT(lv, levels);
                        if (!std::isnan(a) && !std::isnan(b)) {
                            EXPECT_FALSE(std::isnan(lod)) << a << " " << ratio;
                        }
                        // Deterministic: the same input gives the same level.
                        EXPECT_EQ(sc::wanted_level(sc::lod_from_derivatives(dux, dvx, duy, dvy, rule), filter, levels), lv);
                        // The GPU's float evaluation wants the same level, except within a hair of
                        // a level boundary (float rounding of log2 may fall either way).
                        const std::uint32_t g = gpu_wanted_level(float(dux), float(dvx), float(duy), float(dvy), rule, 0, levels);
                        ASSERT_LT(g, levels);
                        if (g != lv) {
                            const double off = filter == sc::SampleFilter::bilinear ? 0.5 : 0.0;
                            const double d = std::abs(static_cast<double>(lod) + off - std::round(static_cast<double>(lod) + off));
                            // Float overflow/underflow of the squares (|d| > 1.8e19 or < 1e-19) gives
                            // +-inf, i.e. the same clamped level as the double rule for levels <= 32.
                            EXPECT_LT(d, 1e-5) << "a " << a << " ratio " << ratio << ": double " << lv << ", float " << g;
                            ++float_disagree;
                        }
                    }
    std::printf("  %llu derivative cases, all levels in range; float/double disagree on %llu (at level boundaries)\n",
                static_cast<unsigned long long>(cases), static_cast<unsigned long long>(float_disagree));
}

// Biases and derivatives that push the lod far outside the levels still clamp.
TEST(StabilityLod, ExtremeBiasStaysInRange) {
    for (const float bias : {-1e30f, -100.0f, -0.5f, 0.0f, 0.5f, 31.5f, 100.0f, 1e30f})
        for (const float lod : {-std::numeric_limits<float>::infinity(), -1e30f, -0.0f, 0.0f, 15.49f, 1e30f,
                                std::numeric_limits<float>::infinity(), std::numeric_limits<float>::quiet_NaN()})
            for (const auto filter : {sc::SampleFilter::bilinear, sc::SampleFilter::trilinear})
                for (const std::uint32_t levels : {1u, 2u, 15u, 32u}) EXPECT_LT(sc::wanted_level(lod + bias, filter, levels), levels);
}

sc::Camera camera_at(double x, double y, double z, double yaw, double pitch) {
    sc::Camera c;
    c.position = {x, y, z};
    c.yaw = yaw;
    c.pitch = pitch;
    c.near_plane = 0.5;
    c.far_plane = 1e9;
    return c;
}

std::uint32_t level_count(std::uint32_t size) { return static_cast<std::uint32_t>(st::level_geometry(size, size, kPayload).size()); }

// Static cameras far from the origin (grazing, oblique, straight down at a coarse level) of 2^20
// and 2^24-texel terrains: every id valid and in range, identical on every evaluation, and a jitter
// of the camera far below a texel (1e-6 world units: well above the double ulp at 2^24, 3.7e-9)
// changes only pixels that sit on a level or page boundary: at most one level or one page apart,
// and very few of them.
TEST(StabilityLod, StaticCameraFarFromTheOriginDoesNotFlicker) {
    const double pi = std::numbers::pi;
    for (const std::uint32_t size : {1u << 20, 1u << 24}) {
        const sc::VtGeometry vt{size, size, kPayload, level_count(size)};
        const double far = size - 1000.37;
        const sc::Camera cams[] = {
            camera_at(far, far, 3.0, 1.25 * pi, -0.002),   // grazing: 0.1 degree below the horizon
            camera_at(far, far, 40.0, 1.2 * pi, -0.35),    // oblique
            camera_at(far - 2e5, far - 2e5, 9e4, 0.3, -pi / 2 + 1e-9),  // straight down, coarse levels
        };
        for (const auto filter : {sc::SampleFilter::bilinear, sc::SampleFilter::trilinear, sc::SampleFilter::anisotropic})
            for (const sc::Camera& cam : cams) {
                sc::CpuFeedbackParams p;
                p.main_width = 640;
                p.main_height = 360;
                p.fb_width = 160;
                p.fb_height = 90;
                p.rule = sc::LodRule{filter, 8};
                std::vector<FeedbackId> a, b, c;
                sc::cpu_feedback(cam, vt, p, a);
                sc::cpu_feedback(cam, vt, p, b);
                ASSERT_EQ(a, b) << "the same camera twice gave different feedback";
                std::size_t vt_pixels = 0;
                for (const FeedbackId id : a) {
                    if (id == kNoPage) continue;
                    ++vt_pixels;
                    const PageKey k = tessera::client::unpack_feedback(id);
                    ASSERT_LT(k.level, vt.levels);
                    const std::uint64_t n = (std::uint64_t(size) + (std::uint64_t(1) << k.level) - 1) >> k.level;
                    ASSERT_LT(k.x, (n + kPayload - 1) / kPayload);
                    ASSERT_LT(k.y, (n + kPayload - 1) / kPayload);
                }
                EXPECT_GT(vt_pixels, std::size_t(p.fb_width) * p.fb_height / 4);
                sc::Camera j = cam;
                j.position[0] += 1e-6;
                j.position[1] -= 1e-6;
                j.position[2] += 1e-7;
                sc::cpu_feedback(j, vt, p, c);
                std::size_t changed = 0;
                for (std::size_t i = 0; i < a.size(); ++i) {
                    if (a[i] == c[i]) continue;
                    ++changed;
                    ASSERT_NE(a[i], kNoPage);
                    ASSERT_NE(c[i], kNoPage);
                    const PageKey u = tessera::client::unpack_feedback(a[i]), v = tessera::client::unpack_feedback(c[i]);
                    if (u.level != v.level) {
                        EXPECT_EQ(std::abs(int(u.level) - int(v.level)), 1);
                    } else {
                        EXPECT_LE(std::abs(std::int64_t(u.x) - std::int64_t(v.x)), 1);
                        EXPECT_LE(std::abs(std::int64_t(u.y) - std::int64_t(v.y)), 1);
                    }
                }
                EXPECT_LE(changed, vt_pixels / 200 + 2) << "size " << size;
            }
    }
}

// Far from the origin at coarse levels (existing tests check level 0): straight-down views at
// about 2^L texels per pixel; every page equals floor(floor(u / 2^L) / P) from the exact position.
TEST(StabilityLod, ExactPagesAtEveryLevelFarFromTheOrigin) {
    for (const std::uint32_t size : {1u << 20, 1u << 24}) {
        const std::uint32_t levels = level_count(size);
        const sc::VtGeometry vt{size, size, kPayload, levels};
        sc::CpuFeedbackParams p;
        p.main_width = p.fb_width = 160;
        p.main_height = p.fb_height = 120;
        p.rule = sc::LodRule{sc::SampleFilter::trilinear, 8};
        for (std::uint32_t level = 0; level < levels; ++level) {
            const double tpp = std::ldexp(1.3, static_cast<int>(level));  // lod = L + 0.38: trilinear wants L
            const double half_fov = std::tan(sc::Camera{}.fov_y / 2);
            const double h = tpp * p.main_height / (2 * half_fov);
            const double cx = size - 70.0 * tpp - 0.37, cy = size - 50.0 * tpp - 0.61;
            const sc::Camera cam = camera_at(cx, cy, h, std::numbers::pi / 2, -std::numbers::pi / 2);
            std::vector<FeedbackId> fb;
            sc::cpu_feedback(cam, vt, p, fb);
            const std::uint64_t n = (std::uint64_t(size) + (std::uint64_t(1) << level) - 1) >> level;
            std::size_t checked = 0;
            const long double hh = static_cast<long double>(h) * static_cast<long double>(half_fov), hw = hh * p.main_width / p.main_height;
            for (std::uint32_t jj = 0; jj < p.fb_height; ++jj)
                for (std::uint32_t ii = 0; ii < p.fb_width; ++ii) {
                    const long double u = cx + ((ii + 0.5L) / p.fb_width * 2 - 1) * hw;
                    const long double v = cy + (1 - (jj + 0.5L) / p.fb_height * 2) * hh;
                    const FeedbackId id = fb[std::size_t(jj) * p.fb_width + ii];
                    if (u < 0 || v < 0 || u >= size || v >= size) continue;
                    const long double su = u / std::ldexp(1.0L, int(level)) / kPayload, sv = v / std::ldexp(1.0L, int(level)) / kPayload;
                    if (su - std::floor(su) < 1e-9L || sv - std::floor(sv) < 1e-9L) continue;  // on a page edge
                    ASSERT_NE(id, kNoPage);
                    const PageKey k = tessera::client::unpack_feedback(id);
                    // A straight-down camera has a slight perspective spread: a row can sit a hair
                    // across the level boundary; the level is then L (lod L+0.38 is well inside).
                    ASSERT_EQ(k.level, std::min(level, levels - 1)) << size << " " << ii << "," << jj;
                    EXPECT_EQ(k.x, std::min<std::uint64_t>(std::uint64_t(std::floor(su)), (n + kPayload - 1) / kPayload - 1));
                    EXPECT_EQ(k.y, std::min<std::uint64_t>(std::uint64_t(std::floor(sv)), (n + kPayload - 1) / kPayload - 1));
                    ++checked;
                }
            EXPECT_GT(checked, 1000u) << size << " level " << level;
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Feedback ids.

// The shader's encoding (vt_feedback_id): two 32-bit words, low first.
FeedbackId shader_feedback_id(std::uint32_t px, std::uint32_t py, std::uint32_t level, std::uint32_t texture) {
    const std::uint32_t lo = (px & 0xFFFFFu) | ((py & 0xFFFu) << 20);
    const std::uint32_t hi = ((py >> 12) & 0xFFu) | ((level & 31u) << 8) | ((texture & 0xFFFFu) << 13);
    return FeedbackId(lo) | (FeedbackId(hi) << 32);
}

TEST(StabilityFeedbackId, LimitsRoundTripAndNeverCollideWithNoPage) {
    const std::uint32_t xs[] = {0, 1, 4095, 4096, (1u << 19), kMaxPagesPerAxis - 2, kMaxPagesPerAxis - 1};
    const std::uint32_t levels[] = {0, 1, 15, 30, 31};
    const std::uint32_t textures[] = {0, 1, 32767, 32768, 65534, 65535};
    std::size_t n = 0;
    for (const auto x : xs)
        for (const auto y : xs)
            for (const auto l : levels)
                for (const auto t : textures) {
                    const PageKey k{static_cast<std::uint16_t>(t), static_cast<std::uint8_t>(l), x, y};
                    const FeedbackId id = tessera::client::pack_feedback(k);
                    ASSERT_NE(id, kNoPage);
                    ASSERT_EQ(id >> 61, 0u);
                    ASSERT_EQ(tessera::client::unpack_feedback(id), k);
                    ASSERT_EQ(shader_feedback_id(x, y, l, t), id);
                    ++n;
                }
    // The largest id a valid key makes is far below kNoPage (bits 61..63 are always 0).
    const FeedbackId top = tessera::client::pack_feedback(PageKey{65535, 31, kMaxPagesPerAxis - 1, kMaxPagesPerAxis - 1});
    EXPECT_EQ(top, (FeedbackId{1} << 61) - 1);
    // Beyond the limits the fields wrap (x = 2^20 reads as 0): the limits must be checked before
    // packing. The renderer and PageTable refuse textures with more than 2^20 pages per axis.
    EXPECT_EQ(tessera::client::unpack_feedback(tessera::client::pack_feedback(PageKey{0, 0, kMaxPagesPerAxis, 0})).x, 0u);
    std::printf("  %zu keys at the limits round-trip (CPU and shader encodings agree)\n", n);
}

// ---------------------------------------------------------------------------------------------
// Page tables.

TEST(StabilityPageTable, SizesForTheLargestGeometryDoNotOverflow) {
    const std::uint32_t m = kMaxPagesPerAxis;  // 2^20 pages: 2^20 * 248 texels ~ 2^28
    EXPECT_EQ(PageTable::levels_for(m, m), 21u);
    EXPECT_EQ(PageTable::levels_for(m - 1, m), 21u);
    EXPECT_EQ(PageTable::levels_for(m, 1), 21u);
    EXPECT_EQ(PageTable::levels_for(1, 1), 1u);
    // sum over L of (2^(20-L))^2 = (4^21 - 1) / 3 entries, 4 bytes each: about 5.3 TiB, in 64 bits.
    const std::uint64_t entries = ((std::uint64_t{1} << 42) - 1) / 3;
    EXPECT_EQ(PageTable::table_bytes(m, m, 21), entries * 4);
    // A 2^24-texel texture: 67651 pages per side at 248-texel pages.
    const std::uint32_t p24 = ((1u << 24) + kPayload - 1) / kPayload;
    EXPECT_EQ(p24, 67651u);
    const std::uint64_t b24 = PageTable::table_bytes(p24, p24, PageTable::levels_for(p24, p24));
    EXPECT_GT(b24, std::uint64_t{22} << 30);  // ~22.7 GiB dense
    std::printf("  dense table of a 2^24-texel texture (P = 248, %u pages per side): %.2f GiB\n", p24, double(b24) / (1 << 30));
}

TEST(StabilityPageTable, BeyondTheBoundIsAClearError) {
    const std::uint32_t m = kMaxPagesPerAxis;
    for (const std::uint32_t pages : {m, 67651u, 8193u}) {
        auto t = PageTable::create(7, pages, pages, PageTable::levels_for(pages, pages));
        ASSERT_FALSE(t.ok()) << pages;
        EXPECT_EQ(t.error().code, Errc::resource_exhausted);
        EXPECT_NE(t.error().message.find("MiB"), std::string::npos) << t.error().message;
        EXPECT_NE(t.error().message.find("bound"), std::string::npos) << t.error().message;
    }
    // A bound of size_t's maximum does not overflow anything either (the check is in 64 bits) --
    // only over 2^20 pages per axis is refused before any size is computed.
    auto over = PageTable::create(0, m + 1, 1, PageTable::levels_for(m + 1, 1), std::numeric_limits<std::size_t>::max());
    ASSERT_FALSE(over.ok());
    EXPECT_EQ(over.error().code, Errc::invalid_argument);
}

// The largest square dense table under the default bound: created (256 MiB), mapped at the far
// corner at several levels; entries, fallbacks and unmap are exact there, and each map or unmap
// below the root touches only its own subtree (the dirty entries, not the 2^26-entry table).
TEST(StabilityPageTable, LargestTableUnderTheBoundWorksAtTheFarCorner) {
    std::uint32_t lo = 1, hi = kMaxPagesPerAxis;
    while (lo < hi) {  // largest n with table_bytes(n, n) <= bound
        const std::uint32_t mid = lo + (hi - lo + 1) / 2;
        if (PageTable::table_bytes(mid, mid, PageTable::levels_for(mid, mid)) <= PageTable::kDefaultMaxBytes)
            lo = mid;
        else
            hi = mid - 1;
    }
    const std::uint32_t n = lo;
    std::printf("  largest square dense table under %zu MiB: %u pages per side (%.1f MiB; %llu texels at P = 248, %llu at P = 1016)\n",
                PageTable::kDefaultMaxBytes >> 20, n,
                double(PageTable::table_bytes(n, n, PageTable::levels_for(n, n))) / (1 << 20),
                static_cast<unsigned long long>(std::uint64_t(n) * 248), static_cast<unsigned long long>(std::uint64_t(n) * 1016));
    EXPECT_FALSE(PageTable::create(0, n + 1, n + 1, PageTable::levels_for(n + 1, n + 1)).ok());
    auto made = PageTable::create(3, n, n, PageTable::levels_for(n, n));
    ASSERT_TRUE(made.ok()) << made.error().message;
    PageTable& t = *made;
    const std::uint32_t L = t.levels();
    EXPECT_GT(t.memory_bytes(), std::size_t{255} << 20);  // offsets past 2^28 bytes, 2^26 entries
    std::vector<tessera::client::DirtyRect> dirty;
    const auto dirty_entries = [&] {  // entries changed since the last call
        dirty.clear();
        t.take_dirty(dirty);
        std::uint64_t sum = 0;
        for (const auto& r : dirty) sum += r.area();
        return sum;
    };
    // A level-4 page's subtree: itself and 4 + 16 + 64 + 256 descendants at most.
    constexpr std::uint64_t kLevel4Subtree = 1 + 4 + 16 + 64 + 256;
    // The root (it rewrites every entry), then a level-4 page and a level-0 page at the far corner.
    ASSERT_TRUE(t.map(L - 1, 0, 0, 1).ok());
    EXPECT_GE(dirty_entries(), std::uint64_t(n) * n);
    const std::uint32_t x4 = t.level_width(4) - 1, y4 = t.level_height(4) - 1;
    ASSERT_TRUE(t.map(4, x4, y4, 2).ok());
    const std::uint64_t mapped4 = dirty_entries();
    EXPECT_GT(mapped4, 0u);
    EXPECT_LE(mapped4, kLevel4Subtree);
    ASSERT_TRUE(t.map(0, n - 1, n - 1, PageTable::kMaxSlots - 1).ok());
    EXPECT_EQ(dirty_entries(), 1u);
    EXPECT_EQ(t.entry(0, n - 1, n - 1), PageTable::make_entry(PageTable::kMaxSlots - 1, 0));
    // Neighbours of the far-corner page fall back to the level-4 page; far from it, to the root.
    EXPECT_EQ(t.entry(0, n - 2, n - 1), PageTable::make_entry(2, 4));
    EXPECT_EQ(t.entry(0, (n - 1) & ~15u, (n - 1) & ~15u), PageTable::make_entry(2, 4));
    EXPECT_EQ(t.entry(0, 0, n - 1), PageTable::make_entry(1, L - 1));
    EXPECT_EQ(t.entry(2, (n - 1) >> 2, (n - 1) >> 2), PageTable::make_entry(2, 4));
    EXPECT_EQ(t.resident_level(1, (n - 1) >> 1, (n - 1) >> 1), 4);
    // The last entry of the allocation is level L-1's only entry; the level-0 one sits at offset
    // (n - 1) * n + n - 1 entries.
    EXPECT_EQ(t.level_entries(0).back(), PageTable::make_entry(PageTable::kMaxSlots - 1, 0));
    EXPECT_EQ(t.level_entries(L - 1).size(), 1u);
    ASSERT_TRUE(t.unmap(0, n - 1, n - 1).ok());
    EXPECT_EQ(dirty_entries(), 1u);
    EXPECT_EQ(t.entry(0, n - 1, n - 1), PageTable::make_entry(2, 4));
    ASSERT_TRUE(t.unmap(4, x4, y4).ok());
    EXPECT_EQ(dirty_entries(), mapped4);
    EXPECT_EQ(t.entry(0, n - 1, n - 1), PageTable::make_entry(1, L - 1));
    EXPECT_FALSE(t.map(0, n, 0, 5).ok());
    EXPECT_FALSE(t.map(0, 0, 0, PageTable::kMaxSlots).ok());
    EXPECT_EQ(dirty_entries(), 0u);
}

// ---------------------------------------------------------------------------------------------
// Priority ordering with 10^6 distinct pages.

class HashedResidency : public ResidencyView {
public:
    std::uint8_t resident_level(const PageKey& k) const override {
        const std::uint32_t h = (k.x * 2654435761u) ^ (k.y * 40503u) ^ k.level;
        if (h % 7 == 0) return kNothingResident;
        return static_cast<std::uint8_t>(std::min<std::uint32_t>(k.level + h % 4, 20));
    }
};

bool before(const WantedPage& a, const WantedPage& b) {  // the documented order, strict
    if (a.level_gap != b.level_gap) return a.level_gap > b.level_gap;
    if (a.subtree_pixels != b.subtree_pixels) return a.subtree_pixels > b.subtree_pixels;
    if (a.centre_distance != b.centre_distance) return a.centre_distance < b.centre_distance;
    return tessera::client::pack_feedback(a.key) < tessera::client::pack_feedback(b.key);
}

// A w x h feedback buffer in which every pixel asks for its own level-0 page near the far corner:
// a scrambled but distance-symmetric layout (the page depends on the pixel, every page once; the
// multipliers are primes, so coprime to w and h).
std::vector<FeedbackId> distinct_pages(std::uint32_t w, std::uint32_t h) {
    const std::uint32_t base = kMaxPagesPerAxis - 1000;
    std::vector<FeedbackId> ids(std::size_t(w) * h);
    for (std::uint32_t y = 0; y < h; ++y)
        for (std::uint32_t x = 0; x < w; ++x)
            ids[std::size_t(y) * w + x] = tessera::client::pack_feedback(PageKey{2, 0, base + (x * 7919u) % w, base + (y * 104729u) % h});
    return ids;
}

TEST(StabilityPriority, MillionDistinctPagesOrderedDeterministically) {
    constexpr std::uint32_t W = 1000, H = 1000;  // 10^6 pixels, each a distinct level-0 page
    const std::vector<FeedbackId> ids = distinct_pages(W, H);
    const std::size_t max_pages = 1u << 21;
    FeedbackAnalyzer a(max_pages, max_pages), b(max_pages, max_pages);
    for (FeedbackAnalyzer* f : {&a, &b}) {
        f->set_texture_levels(2, 21);
        f->set_texture_extent(2, kMaxPagesPerAxis, kMaxPagesPerAxis);
    }
    HashedResidency residency;
    const auto first = a.analyse(ids, W, H, residency);
    const std::vector<WantedPage> r1(first.begin(), first.end());
    const auto s = a.stats();
    EXPECT_EQ(s.unique_pages, W * H);
    EXPECT_GT(s.ancestor_pages, W * H / 3);
    EXPECT_EQ(s.dropped_pages + s.untracked_pixels + s.untracked_ancestors + s.invalid_pixels, 0u);
    ASSERT_EQ(r1.size(), std::size_t(s.unique_pages) + s.ancestor_pages);
    for (std::size_t i = 1; i < r1.size(); ++i) ASSERT_TRUE(before(r1[i - 1], r1[i])) << "not strictly ordered at " << i;

    // Again on the same analyser, on a second one, and on buffers mirrored left-right, top-bottom
    // and transposed: every pixel keeps its distance to the centre, so the output must not change.
    auto same = [&](std::span<const WantedPage> r, const char* what) {
        ASSERT_EQ(r.size(), r1.size()) << what;
        EXPECT_TRUE(std::equal(r.begin(), r.end(), r1.begin())) << what;
    };
    // These runs are timed too (thread CPU time, the best of them), for the growth check below.
    double cpu_all = 1e30;
    auto analyse_timed = [&](FeedbackAnalyzer& f, const std::vector<FeedbackId>& buf, std::uint32_t w, std::uint32_t h,
                             double& best) {
        const double t = thread_cpu_seconds();
        const auto r = f.analyse(buf, w, h, residency);
        best = std::min(best, thread_cpu_seconds() - t);
        return r;
    };
    same(analyse_timed(a, ids, W, H, cpu_all), "second run");
    same(analyse_timed(b, ids, W, H, cpu_all), "second analyser");
    std::vector<FeedbackId> m(ids.size());
    for (std::uint32_t y = 0; y < H; ++y)
        for (std::uint32_t x = 0; x < W; ++x) m[std::size_t(y) * W + (W - 1 - x)] = ids[std::size_t(y) * W + x];
    same(analyse_timed(b, m, W, H, cpu_all), "mirrored left-right");
    for (std::uint32_t y = 0; y < H; ++y)
        for (std::uint32_t x = 0; x < W; ++x) m[std::size_t(H - 1 - y) * W + x] = ids[std::size_t(y) * W + x];
    same(analyse_timed(b, m, W, H, cpu_all), "mirrored top-bottom");
    for (std::uint32_t y = 0; y < H; ++y)
        for (std::uint32_t x = 0; x < W; ++x) m[std::size_t(x) * W + y] = ids[std::size_t(y) * W + x];
    same(analyse_timed(b, m, W, H, cpu_all), "transposed");

    // Cut to the runtime's default output (max_feedback_pages = 2^16): the cut keeps exactly the
    // first 2^16 of the full order.
    FeedbackAnalyzer c(1u << 16, max_pages);
    c.set_texture_levels(2, 21);
    const auto cut = c.analyse(ids, W, H, residency);
    ASSERT_EQ(cut.size(), 1u << 16);
    EXPECT_TRUE(std::equal(cut.begin(), cut.end(), r1.begin()));
    EXPECT_EQ(c.stats().dropped_pages, r1.size() - (1u << 16));

    // The cost grows with the pages, not faster: a quarter of the pages takes about a quarter of
    // the time (hashing and a radix sort are linear; measured 4.1 - 5.9, the larger work set
    // missing the caches more); a step quadratic in the pages would make the ratio 16. Thread CPU
    // time, the best of several runs of each size on warm analysers, so a busy machine or a
    // sanitizer build slows both sizes alike.
    const std::vector<FeedbackId> quarter = distinct_pages(W / 2, H / 2);
    double cpu_quarter = 1e30;
    for (int run = 0; run < 3; ++run) {
        ASSERT_GT(analyse_timed(b, quarter, W / 2, H / 2, cpu_quarter).size(), W * H / 4);
        ASSERT_EQ(b.stats().unique_pages, W * H / 4);
    }
    std::printf("  %zu wanted pages (10^6 distinct + ancestors): %.3f s CPU; a quarter of the pages: %.3f s (ratio %.2f)\n",
                r1.size(), cpu_all, cpu_quarter, cpu_all / cpu_quarter);
    EXPECT_LT(cpu_all / cpu_quarter, 10.0) << "analysis cost grows faster than the pages";
}

}  // namespace
