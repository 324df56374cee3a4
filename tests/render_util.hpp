#pragma once
// Helpers shared by the rendering tests (render_*_test.cpp): a headless context or a failure, store
// geometry, a straight-down camera, a flat chunk over a texture's far corner, and a texel
// encoding that lets a read-back pixel say which texel it came from.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <string>
#include <utility>
#include <vector>

#include "ground_ray.hpp"
#include "tessera/client/gl/context.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/scene/scene.hpp"
#include "tessera/storage/types.hpp"

// A current headless GL 4.5 context named `ctx`, or the test fails with the reason.
#define REQUIRE_GL(ctx)                                                                                            \
    auto ctx##_made = ::tessera::client::gl::GlContext::create_headless();                                        \
    if (!ctx##_made) GTEST_FAIL() << ::tessera::test::no_gl_message(ctx##_made.error().message);                 \
    auto& ctx = *ctx##_made;                                                                                       \
    (void)ctx

namespace tessera::test {

// Why a GL test cannot run, as its failure message. tools/setup.sh installs what the headless
// context needs, so a machine without one is broken, not exempt: a skip would let ctest pass with
// the rendering tests unrun.
inline std::string no_gl_message(const std::string& why) {
    return "no headless OpenGL 4.5 context (EGL with Mesa's llvmpipe: libegl-mesa0 and libgl1-mesa-dri, "
           "which tools/setup.sh installs): " + why;
}

// The geometry of a store of width x height texels in tiles of tile_size (border included).
inline storage::StoreInfo store_geometry(std::uint32_t width, std::uint32_t height, std::uint32_t tile_size,
                                         std::uint32_t border = 4) {
    storage::StoreInfo info;
    info.width = width;
    info.height = height;
    info.tile_payload = tile_size - 2 * border;
    info.border = border;
    info.channels = 4;
    info.levels = storage::level_geometry(width, height, info.tile_payload);
    return info;
}

// A renderer configuration for exactness tests: bilinear, linear colour, no feedback jitter.
inline client::gl::RendererConfig exact_config(std::uint32_t w, std::uint32_t h, std::uint32_t tile_size,
                                               std::uint32_t border, std::uint32_t pool_slots) {
    client::gl::RendererConfig c;
    c.width = w;
    c.height = h;
    c.filter = client::gl::Filter::bilinear;
    c.tile_size = tile_size;
    c.border = border;
    c.pool_slots = pool_slots;
    c.srgb = false;
    c.staging_bytes = 8u << 20;
    c.feedback_jitter = false;
    return c;
}

// At (x, y, z) looking along heading `yaw` (0 = +x, counter-clockwise) and `pitch` (negative:
// down); near 0.5, far `far_plane`.
inline scene::Camera looking(double x, double y, double z, double yaw, double pitch, double far_plane = 1e6) {
    scene::Camera c;
    c.position = {x, y, z};
    c.yaw = yaw;
    c.pitch = pitch;
    c.near_plane = 0.5;
    c.far_plane = far_plane;
    return c;
}

// Looking straight down from `height` over (x, y), screen up = +y; near and far bracket the ground.
inline scene::Camera straight_down(double x, double y, double height) {
    scene::Camera c;
    c.position = {x, y, height};
    c.yaw = std::numbers::pi / 2;
    c.pitch = -std::numbers::pi / 2;
    c.near_plane = height * 0.5;
    c.far_plane = height * 2;
    return c;
}

// A flat chunk over level-0 texels [x0, x1) x [y0, y1) of a size^2 texture (one world unit per
// texel, texel origin (x0, y0)).
inline scene::Scene rect_chunk(std::uint32_t size, std::uint32_t x0, std::uint32_t y0, std::uint32_t x1, std::uint32_t y1) {
    scene::Scene s;
    s.name = "rect";
    s.vt_width = s.vt_height = size;
    scene::Chunk c;
    c.origin = {double(x0), double(y0), 0};
    c.texel_origin[0] = x0;
    c.texel_origin[1] = y0;
    const float w = float(x1 - x0), h = float(y1 - y0);
    for (const auto& [x, y] : {std::pair{0.f, 0.f}, {w, 0.f}, {w, h}, {0.f, h}}) c.vertices.push_back({{x, y, 0}, {x, y}});
    c.indices = {0, 1, 2, 0, 2, 3};
    c.bounds_min[0] = s.bounds_min[0] = x0;
    c.bounds_min[1] = s.bounds_min[1] = y0;
    c.bounds_max[0] = s.bounds_max[0] = x1;
    c.bounds_max[1] = s.bounds_max[1] = y1;
    s.chunks.push_back(std::move(c));
    return s;
}

// One flat chunk from (o, o) to the far corner (size, size); an odd o puts low bits in its texel
// origin at every level.
inline scene::Scene corner_chunk(std::uint32_t size, std::uint32_t o) { return rect_chunk(size, o, o, size, size); }

// The low 12 bits of a texel's coordinates in RGB (A opaque): a read-back pixel names its texel.
inline void encode_texel(std::uint32_t x, std::uint32_t y, std::uint8_t* p) {
    p[0] = std::uint8_t(x & 255);
    p[1] = std::uint8_t(y & 255);
    p[2] = std::uint8_t(((x >> 8) & 15) | (((y >> 8) & 15) << 4));
    p[3] = 255;
}

// `page` (tile x tile RGBA8) filled with encode_texel values: page (px, py) of a level with
// `texels` texels per side, border included, clamped to [0, texels) as the builder replicates edges.
inline void encode_page(std::vector<std::uint8_t>& page, std::uint32_t tile, std::uint32_t border, std::uint32_t px,
                        std::uint32_t py, std::uint32_t texels) {
    const std::int64_t payload = tile - 2 * border;
    page.resize(std::size_t(tile) * tile * 4);
    for (std::uint32_t j = 0; j < tile; ++j)
        for (std::uint32_t i = 0; i < tile; ++i) {
            const auto gx = std::clamp<std::int64_t>(std::int64_t(px) * payload - border + i, 0, std::int64_t(texels) - 1);
            const auto gy = std::clamp<std::int64_t>(std::int64_t(py) * payload - border + j, 0, std::int64_t(texels) - 1);
            encode_texel(std::uint32_t(gx), std::uint32_t(gy), page.data() + (std::size_t(j) * tile + i) * 4);
        }
}

// The pages the far-corner tests map at `level`: the last 2 x 2 (or the one page of a 1-page
// level), and the view centre k, a level-L texel corner: where those pages meet, or near the end.
struct CornerPages {
    std::uint32_t texels = 0, pages = 0;      // of the level, per side
    std::uint32_t k = 0;                      // view centre, level-L texels
    std::uint32_t first_page = 0, count = 0;  // pages first_page .. first_page + count - 1 per axis
};
inline CornerPages corner_pages(const storage::StoreInfo& info, std::uint32_t level) {
    CornerPages c;
    c.texels = info.levels[level].width;
    c.pages = info.levels[level].tiles_x;
    const std::uint32_t last = c.pages - 1;
    c.k = c.pages >= 2 ? last * info.tile_payload : c.texels - 40;
    c.first_page = c.pages >= 2 ? last - 1 : 0;
    c.count = c.pages >= 2 ? 2 : 1;
    return c;
}

// The far-corner view: a chunk from an odd origin `o` (low bits set at every level) to the far
// edge of a size^2 texture, seen straight down at exactly 2^level level-0 texels per pixel (an
// image height_px pixels high), centred on level-`level` texel corner (k, k).
struct CornerView {
    std::uint32_t o = 0;
    scene::Camera cam;
};
inline CornerView corner_view(std::uint32_t size, std::uint32_t k, std::uint32_t level, std::uint32_t height_px) {
    const double scale = std::ldexp(1.0, int(level));
    const std::uint64_t span = std::uint64_t((double(size) - (double(k) - 80) * scale)) + 3;
    CornerView v;
    v.o = span >= size ? 0 : std::uint32_t(size - span) | 1u;
    const double height = scale * height_px / (2.0 * std::tan(scene::Camera{}.fov_y / 2.0));
    v.cam = straight_down(double(k) * scale, double(k) * scale, height);
    return v;
}

struct TexelCheck {
    std::size_t checked = 0, wrong = 0;
};

// Every pixel of `rgba` (w x h, rows top to bottom) of a straight-down view `cam` of a chunk over
// level-0 texels [x0, x1) x [y0, y1) whose ray meets the ground on a level-`level` texel centre
// (within 1e-3 texel) must be exactly expected(gx, gy): an std::array<std::uint8_t, 4> for
// level-`level` texel (gx, gy). The first five mismatches are reported as failures.
template <class Expected>
TexelCheck check_texel_centres_in(const std::vector<std::uint8_t>& rgba, const scene::Camera& cam, std::uint32_t w,
                                  std::uint32_t h, std::uint32_t level, double x0, double y0, double x1, double y1,
                                  Expected expected) {
    TexelCheck r;
    const double scale = std::ldexp(1.0, int(level));
    for (std::uint32_t j = 0; j < h; ++j)
        for (std::uint32_t i = 0; i < w; ++i) {
            double x, y;
            if (!pixel_to_ground(cam, w, h, i, j, x, y)) {
                ADD_FAILURE() << "pixel (" << i << ", " << j << ") does not see the ground";
                return r;
            }
            const double lx = x / scale, ly = y / scale;
            if (std::abs(lx - std::floor(lx) - 0.5) > 1e-3 || std::abs(ly - std::floor(ly) - 0.5) > 1e-3) continue;
            if (x < x0 || y < y0 || x >= x1 || y >= y1) continue;  // no geometry (a level's last texel may overhang)
            const auto gx = std::uint32_t(std::floor(lx)), gy = std::uint32_t(std::floor(ly));
            const std::array<std::uint8_t, 4> want = expected(gx, gy);
            const std::uint8_t* got = rgba.data() + (std::size_t(j) * w + i) * 4;
            ++r.checked;
            if (std::equal(want.begin(), want.end(), got)) continue;
            if (++r.wrong <= 5)
                ADD_FAILURE() << "level " << level << " pixel (" << i << ", " << j << ") texel (" << gx << ", " << gy << "): got "
                              << int(got[0]) << " " << int(got[1]) << " " << int(got[2]) << " " << int(got[3]) << ", want "
                              << int(want[0]) << " " << int(want[1]) << " " << int(want[2]) << " " << int(want[3]);
        }
    return r;
}

// check_texel_centres_in over a chunk from `o` to the far corner: level-0 texels [o, size)^2.
template <class Expected>
TexelCheck check_texel_centres(const std::vector<std::uint8_t>& rgba, const scene::Camera& cam, std::uint32_t w,
                               std::uint32_t h, std::uint32_t level, std::uint32_t o, std::uint32_t size, Expected expected) {
    return check_texel_centres_in(rgba, cam, w, h, level, o, o, size, size, expected);
}

// encode_texel as the expectation of check_texel_centres.
inline std::array<std::uint8_t, 4> encoded_texel(std::uint32_t x, std::uint32_t y) {
    std::array<std::uint8_t, 4> p{};
    encode_texel(x, y, p.data());
    return p;
}

// Renders the far-corner view (corner_view) of `level` with `r` (w x h; the texture the scene uses
// is 0, its pages already mapped) and checks it: no GL error, no malformed upload, every texel
// centre exactly encode_texel's value, at least a quarter of the pixels checked, and (unless
// `check_fallback` is false) the frame's counters say no pixel fell back.
inline TexelCheck render_corner_exactly(client::gl::VtRenderer& r, std::uint32_t size, std::uint32_t k,
                                        std::uint32_t level, std::uint32_t w, std::uint32_t h,
                                        bool check_fallback = true) {
    const auto [o, cam] = corner_view(size, k, level, h);
    EXPECT_TRUE(r.set_scene(corner_chunk(size, o), 0).ok());
    const auto frame = r.render(cam, 0);
    std::vector<client::gl::FrameCounters> counters;
    r.finish(&counters, nullptr);
    const auto rgba = r.read_color();
    EXPECT_EQ(r.stats().gl_errors, 0u);
    EXPECT_EQ(r.stats().malformed_uploads, 0u);
    const TexelCheck check = check_texel_centres(rgba, cam, w, h, level, o, size, encoded_texel);
    EXPECT_EQ(check.wrong, 0u) << "level " << level << " of " << check.checked;
    EXPECT_GE(check.checked, std::size_t(w) * h / 4) << "level " << level;
    bool counted = false;
    for (const auto& c : counters)
        if (c.frame == frame) {
            counted = true;
            if (check_fallback) {
                EXPECT_EQ(c.fallback_unbiased, 0u) << "level " << level << ": a pixel sampled a coarser page";
            }
        }
    EXPECT_TRUE(counted) << "level " << level;
    return check;
}

}  // namespace tessera::test
