// The CPU feedback of a flat terrain view: exact page sets for straight-down views (computed
// independently from the visible rectangle), no page where nothing is seen, exact integer pages
// far from the origin of 2^20- and 2^24-texel textures, sane levels at grazing angles.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <set>
#include <tuple>

#include "tessera/scene/cpu_feedback.hpp"

namespace {

using namespace tessera::scene;
using tessera::FeedbackId;
using tessera::kNoPage;
using tessera::PageKey;
using tessera::unpack_feedback;
constexpr double kPi = std::numbers::pi;

using PageSet = std::set<std::tuple<int, std::uint32_t, std::uint32_t>>;  // level, x, y

PageSet pages_of(const std::vector<FeedbackId>& fb, std::size_t* none = nullptr) {
    PageSet out;
    std::size_t n = 0;
    for (FeedbackId id : fb) {
        if (id == kNoPage) {
            ++n;
            continue;
        }
        const PageKey k = unpack_feedback(id);
        out.insert({k.level, k.x, k.y});
    }
    if (none) *none = n;
    return out;
}

// Levels of a texture: level L is ceil(size / 2^L) texels; the last one fits one page.
std::uint32_t level_count(std::uint64_t size, std::uint32_t P) {
    std::uint32_t l = 0;
    while (((size + (1ull << l) - 1) >> l) > P) ++l;
    return l + 1;
}

// A camera straight above (cx, cy) at height h: screen right is +x, screen up is +y.
Camera straight_down(double cx, double cy, double h) {
    Camera c;
    c.position = {cx, cy, h};
    c.yaw = kPi / 2;
    c.pitch = -kPi / 2;
    return c;
}

CpuFeedbackParams params_1280x720(SampleFilter f = SampleFilter::trilinear) {
    CpuFeedbackParams p;
    p.main_width = 1280;
    p.main_height = 720;
    p.fb_width = 160;
    p.fb_height = 90;
    p.rule.filter = f;
    p.texture = 7;
    return p;
}

// The expected pages of a straight-down view, from the rectangle the feedback samples cover:
// sample centres lie on a grid from (cx - hw * (1 - 1/fbw)) to (cx + hw * (1 - 1/fbw)) (likewise
// in y); with samples much closer than a page, every page the rectangle touches is hit.
PageSet expected_rectangle(double cx, double cy, double hw, double hh, const CpuFeedbackParams& p, std::uint32_t level,
                           std::uint64_t W, std::uint64_t H, std::uint32_t P) {
    const double ux0 = cx - hw * (1 - 1.0 / p.fb_width), ux1 = cx + hw * (1 - 1.0 / p.fb_width);
    const double vy0 = cy - hh * (1 - 1.0 / p.fb_height), vy1 = cy + hh * (1 - 1.0 / p.fb_height);
    const double lo_u = std::max(0.0, ux0), hi_u = std::min(double(W) - 1e-9, ux1);
    const double lo_v = std::max(0.0, vy0), hi_v = std::min(double(H) - 1e-9, vy1);
    PageSet out;
    const auto page = [&](double t) { return static_cast<std::uint32_t>(static_cast<std::uint64_t>(std::floor(t)) >> level) / P; };
    for (std::uint32_t y = page(lo_v); y <= page(hi_v); ++y)
        for (std::uint32_t x = page(lo_u); x <= page(hi_u); ++x) out.insert({int(level), x, y});
    return out;
}

TEST(CpuFeedback, StraightDownGivesExactlyTheVisibleRectangle) {
    const std::uint32_t P = 248, W = 16384;
    const VtGeometry vt{W, W, P, level_count(W, P)};
    ASSERT_EQ(vt.levels, 8u);
    const double t = std::tan(Camera{}.fov_y / 2);
    // rho = 3 texels per main pixel: trilinear and anisotropic want level 1, bilinear level 2.
    const double h = 3.0 * 720 / (2 * t);
    const double cx = 5000.3, cy = 7000.7, hh = h * t, hw = hh * 1280.0 / 720.0;
    for (auto [filter, level] : {std::pair{SampleFilter::trilinear, 1u}, std::pair{SampleFilter::anisotropic, 1u},
                                 std::pair{SampleFilter::bilinear, 2u}}) {
        const CpuFeedbackParams p = params_1280x720(filter);
        std::vector<FeedbackId> fb;
        cpu_feedback(straight_down(cx, cy, h), vt, p, fb);
        ASSERT_EQ(fb.size(), 160u * 90u);
        std::size_t none = 0;
        const PageSet got = pages_of(fb, &none);
        EXPECT_EQ(none, 0u);
        EXPECT_EQ(got, expected_rectangle(cx, cy, hw, hh, p, level, W, W, P)) << "filter " << int(filter);
        for (FeedbackId id : fb) EXPECT_EQ(unpack_feedback(id).texture, 7);
        // Row 0 is the top of the view: +y (larger v) is up.
        EXPECT_GT(unpack_feedback(fb.front()).y, unpack_feedback(fb.back()).y);
        EXPECT_LT(unpack_feedback(fb.front()).x, unpack_feedback(fb.back()).x);
    }
    // A positive bias of one level coarsens by one.
    CpuFeedbackParams p = params_1280x720();
    p.bias = 1.0f;
    std::vector<FeedbackId> fb;
    cpu_feedback(straight_down(cx, cy, h), vt, p, fb);
    EXPECT_EQ(pages_of(fb), expected_rectangle(cx, cy, hw, hh, p, 2, W, W, P));
}

TEST(CpuFeedback, NothingOutsideTheTextureBehindOrBelow) {
    const std::uint32_t P = 120, W = 4096;
    const VtGeometry vt{W, W / 2, P, level_count(W, P)};
    const CpuFeedbackParams p = params_1280x720();
    const double t = std::tan(Camera{}.fov_y / 2);
    const double h = 0.5 * 720 / (2 * t);  // rho 0.5: level 0
    const double hh = h * t, hw = hh * 1280.0 / 720.0;
    // Over the corner (100, 100): samples with u < 0 or v < 0 see no texture.
    std::vector<FeedbackId> fb;
    cpu_feedback(straight_down(100.5, 100.5, h), vt, p, fb);
    std::size_t none = 0;
    const PageSet got = pages_of(fb, &none);
    std::size_t outside = 0;
    for (std::uint32_t j = 0; j < p.fb_height; ++j)
        for (std::uint32_t i = 0; i < p.fb_width; ++i) {
            const double u = 100.5 + ((i + 0.5) / p.fb_width * 2 - 1) * hw;
            const double v = 100.5 + (1 - (j + 0.5) / p.fb_height * 2) * hh;
            const bool out = u < 0 || v < 0;
            outside += out;
            EXPECT_EQ(fb[j * p.fb_width + i] == kNoPage, out) << i << "," << j;
        }
    EXPECT_GT(outside, 0u);
    EXPECT_EQ(none, outside);
    EXPECT_EQ(got, expected_rectangle(100.5, 100.5, hw, hh, p, 0, W, W / 2, P));
    // Past the far edge of a non-square texture too (v >= height).
    cpu_feedback(straight_down(2000.5, W / 2 - 50.25, h), vt, p, fb);
    pages_of(fb, &none);
    EXPECT_GT(none, 0u);
    for (FeedbackId id : fb) {
        if (id != kNoPage) {
            EXPECT_LT(unpack_feedback(id).y, (W / 2 + P - 1) / P);
        }
    }

    // Looking up: every ray misses the plane.
    Camera up = straight_down(1000, 1000, 50);
    up.pitch = 0.6;
    cpu_feedback(up, vt, p, fb);
    pages_of(fb, &none);
    EXPECT_EQ(none, fb.size());
    // Below the plane (looking at its back): nothing.
    cpu_feedback(straight_down(1000, 1000, -10), vt, p, fb);
    pages_of(fb, &none);
    EXPECT_EQ(none, fb.size());
    // Horizontal: the upper half (above the horizon) sees nothing, the lower half sees ground.
    Camera level = straight_down(1000, 1000, 20);
    level.pitch = 0;
    level.yaw = 0.3;
    cpu_feedback(level, vt, p, fb);
    for (std::uint32_t j = 0; j < p.fb_height; ++j) {
        const FeedbackId mid = fb[j * p.fb_width + p.fb_width / 2];
        if (j < p.fb_height / 2) {
            EXPECT_EQ(mid, kNoPage) << j;
        }
        if (j >= p.fb_height / 2 + 2) {
            EXPECT_NE(mid, kNoPage) << j;
        }
    }
    // Nothing beyond the far plane.
    level.far_plane = 100;
    cpu_feedback(level, vt, p, fb);
    EXPECT_EQ(fb[(p.fb_height / 2 + 1) * p.fb_width + p.fb_width / 2], kNoPage);  // just below the horizon: far away
    // A zero-size target gives an empty buffer.
    CpuFeedbackParams empty = p;
    empty.fb_width = 0;
    cpu_feedback(level, vt, empty, fb);
    EXPECT_TRUE(fb.empty());
}

// Far from the origin of huge textures every page coordinate is exact: compare each pixel with
// floor(u) / P computed in long double from the sample's own position.
void exact_far_from_origin(std::uint32_t W) {
    const std::uint32_t P = 248;
    const VtGeometry vt{W, W, P, level_count(W, P)};
    const CpuFeedbackParams p = params_1280x720();
    const double t = std::tan(Camera{}.fov_y / 2);
    const double h = 0.5 * 720 / (2 * t);  // rho 0.5: level 0
    const double cx = W - 3000.37, cy = W - 5000.61;
    std::vector<FeedbackId> fb;
    cpu_feedback(straight_down(cx, cy, h), vt, p, fb);
    const long double hh = static_cast<long double>(h) * static_cast<long double>(t), hw = hh * 1280.0L / 720.0L;
    std::size_t checked = 0;
    for (std::uint32_t j = 0; j < p.fb_height; ++j)
        for (std::uint32_t i = 0; i < p.fb_width; ++i) {
            const long double u = cx + ((i + 0.5L) / p.fb_width * 2 - 1) * hw;
            const long double v = cy + (1 - (j + 0.5L) / p.fb_height * 2) * hh;
            const long double fu = u - std::floor(u), fv = v - std::floor(v);
            if (fu < 1e-6L || fu > 1 - 1e-6L || fv < 1e-6L || fv > 1 - 1e-6L) continue;  // on a texel edge: either is right
            const FeedbackId id = fb[j * p.fb_width + i];
            ASSERT_NE(id, kNoPage);
            const PageKey k = unpack_feedback(id);
            EXPECT_EQ(k.level, 0);
            EXPECT_EQ(k.x, static_cast<std::uint64_t>(std::floor(u)) / P) << i << "," << j;
            EXPECT_EQ(k.y, static_cast<std::uint64_t>(std::floor(v)) / P) << i << "," << j;
            ++checked;
        }
    EXPECT_GT(checked, 10000u);
    const double hhd = h * t;
    EXPECT_EQ(pages_of(fb), expected_rectangle(cx, cy, hhd * 1280.0 / 720.0, hhd, p, 0, W, W, P));
}

TEST(CpuFeedback, ExactPagesFarFromTheOriginOf2To20) { exact_far_from_origin(1u << 20); }
TEST(CpuFeedback, ExactPagesFarFromTheOriginOf2To24) { exact_far_from_origin(1u << 24); }

TEST(CpuFeedback, GrazingAnglesGiveValidLevels) {
    const std::uint32_t P = 248, W = 1u << 20;
    const VtGeometry vt{W, W, P, level_count(W, P)};
    std::vector<FeedbackId> fb;
    for (SampleFilter f : {SampleFilter::bilinear, SampleFilter::trilinear, SampleFilter::anisotropic}) {
        for (double pitch : {-1e-6, -0.001, -0.02, -0.3}) {
            Camera c;
            c.position = {W / 2.0 + 0.3, W / 2.0 + 0.7, 2.0};
            c.yaw = 0.4;
            c.pitch = pitch;
            c.far_plane = 1e9;
            cpu_feedback(c, vt, params_1280x720(f), fb);
            std::set<int> levels;
            for (FeedbackId id : fb) {
                if (id == kNoPage) continue;
                const PageKey k = unpack_feedback(id);
                ASSERT_LT(k.level, vt.levels);
                const std::uint64_t pages = ((std::uint64_t(W) >> k.level) + P - 1) / P;
                EXPECT_LT(k.x, pages);
                EXPECT_LT(k.y, pages);
                levels.insert(k.level);
            }
            EXPECT_FALSE(levels.empty()) << pitch;
            // Near the camera fine levels, towards the horizon coarse ones.
            if (pitch > -0.1) {
                EXPECT_GE(levels.size(), 3u) << pitch;
                EXPECT_EQ(*levels.begin(), 0) << pitch;
                EXPECT_GE(*levels.rbegin(), 2) << pitch;
            }
        }
    }
}

// A plain per-pixel implementation of the documented rule (ray through the sample centre, forward
// differences to the rays one main pixel right and down, lod_from_derivatives, wanted_level,
// floor(texel / 2^L) / P): cpu_feedback must agree with it for arbitrary views, except where the
// lod lies within a hair of a level boundary (there either level is right).
TEST(CpuFeedback, AgreesWithAPlainImplementationOfTheRule) {
    const std::uint32_t P = 248, W = 1u << 20;
    const VtGeometry vt{W, W - 12345, P, level_count(W, P)};
    std::uint64_t state = 12345;
    auto rnd = [&state] {  // deterministic, uniform in [0, 1)
        state = state * 6364136223846793005ull + 1442695040888963407ull;
        return double(state >> 11) * 0x1p-53;
    };
    std::size_t compared = 0, boundary = 0;
    std::vector<FeedbackId> fb;
    for (int view = 0; view < 120; ++view) {
        Camera c;
        c.position = {rnd() * W, rnd() * W, std::exp(rnd() * 12)};
        c.yaw = rnd() * 2 * kPi;
        c.pitch = -rnd() * kPi / 2;
        CpuFeedbackParams p = params_1280x720(static_cast<SampleFilter>(view % 3));
        p.bias = view % 4 == 0 ? 0.0f : static_cast<float>(rnd() * 3 - 1);
        p.rule.max_anisotropy = 1 + view % 8;
        cpu_feedback(c, vt, p, fb);
        const Vec3d f = c.forward(), r = c.right(), u = c.up();
        const double sy = std::tan(c.fov_y / 2), sx = sy * 1280.0 / 720.0;
        auto hit = [&](double nx, double ny, double& hu, double& hv, double& t) {
            const Vec3d d{f[0] + nx * sx * r[0] + ny * sy * u[0], f[1] + nx * sx * r[1] + ny * sy * u[1],
                          f[2] + nx * sx * r[2] + ny * sy * u[2]};
            if (!(d[2] < 0)) return false;
            t = -c.position[2] / d[2];
            hu = c.position[0] + t * d[0];
            hv = c.position[1] + t * d[1];
            return true;
        };
        for (std::uint32_t j = 0; j < p.fb_height; ++j)
            for (std::uint32_t i = 0; i < p.fb_width; ++i) {
                const double nx = (i + 0.5) / p.fb_width * 2 - 1, ny = 1 - (j + 0.5) / p.fb_height * 2;
                double hu = 0, hv = 0, t = 0, ru = 0, rv = 0, rt = 0, du = 0, dv = 0, dt = 0;
                FeedbackId want = kNoPage;
                float lod = 0;
                if (hit(nx, ny, hu, hv, t) && t >= c.near_plane && t <= c.far_plane && hu >= 0 && hu < vt.width && hv >= 0 &&
                    hv < vt.height) {
                    hit(nx + 2.0 / 1280, ny, ru, rv, rt);
                    if (!hit(nx, ny - 2.0 / 720, du, dv, dt)) du = hu, dv = hv;
                    lod = lod_from_derivatives(ru - hu, rv - hv, du - hu, dv - hv, p.rule) + p.bias;
                    const std::uint32_t L = wanted_level(lod, p.rule.filter, vt.levels);
                    const auto px = static_cast<std::uint64_t>(std::floor(std::ldexp(hu, -int(L)))) / P;
                    const auto py = static_cast<std::uint64_t>(std::floor(std::ldexp(hv, -int(L)))) / P;
                    want = tessera::pack_feedback(PageKey{p.texture, static_cast<std::uint8_t>(L), static_cast<std::uint32_t>(px),
                                                                  static_cast<std::uint32_t>(py)});
                }
                const FeedbackId got = fb[j * p.fb_width + i];
                if ((got == kNoPage) != (want == kNoPage)) {
                    ADD_FAILURE() << "view " << view << " pixel " << i << "," << j << ": hit/miss differ";
                    continue;
                }
                if (got == want) {
                    compared += got != kNoPage;
                    continue;
                }
                // Only where the lod (or bilinear's rounding point) is within a hair of a boundary.
                const float frac = p.rule.filter == SampleFilter::bilinear ? lod + 0.5f - std::floor(lod + 0.5f) : lod - std::floor(lod);
                if (std::min(frac, 1 - frac) < 1e-4f) {
                    ++boundary;
                    continue;
                }
                const PageKey a = unpack_feedback(got), b = unpack_feedback(want);
                ADD_FAILURE() << "view " << view << " pixel " << i << "," << j << ": got L" << int(a.level) << " " << a.x << "," << a.y
                              << ", want L" << int(b.level) << " " << b.x << "," << b.y << " (lod " << lod << ")";
            }
    }
    EXPECT_GT(compared, 100000u);
    EXPECT_LT(boundary, compared / 1000);
}

TEST(CpuFeedback, ReusesTheOutputBuffer) {
    const VtGeometry vt{8192, 8192, 248, level_count(8192, 248)};
    std::vector<FeedbackId> fb;
    cpu_feedback(straight_down(4000, 4000, 300), vt, params_1280x720(), fb);
    const FeedbackId* data = fb.data();
    const std::size_t cap = fb.capacity();
    for (int i = 0; i < 10; ++i) cpu_feedback(straight_down(4000 + i, 4000, 300), vt, params_1280x720(), fb);
    EXPECT_EQ(fb.data(), data);
    EXPECT_EQ(fb.capacity(), cap);
}

}  // namespace
