// The feedback buffer of a flat terrain view, on the CPU: one ray per feedback pixel, intersected
// with the plane z = 0 in double precision, and the shared LoD rule. Allocation-free once `out`
// has its size: the load tester calls it every frame for every simulated viewer.
#include "tessera/scene/cpu_feedback.hpp"

#include <algorithm>
#include <array>
#include <cmath>

namespace tessera::scene {

namespace {

// Instead of a log2 per pixel, the level comes from comparing the squared footprint q (major^2, or
// the anisotropic max(minor^2, major^2 / N^2)) with per-level thresholds: the rule "level >= k"
// is "lod + bias >= k - offset" (offset 0.5 for bilinear's rounding), i.e. q >= 2^(2(k - offset - bias)).
// Where q lies within a hair of a threshold (float rounding of the reference formula could go either
// way) the pixel takes the reference path, lod_from_derivatives + wanted_level, so the result is
// always exactly what the shared rule gives.
constexpr double kThresholdBand = 1e-5;

}  // namespace

void cpu_feedback(const Camera& camera, const VtGeometry& vt, const CpuFeedbackParams& params,
                  std::vector<FeedbackId>& out) {
    const std::uint32_t fbw = params.fb_width, fbh = params.fb_height;
    out.resize(std::size_t(fbw) * fbh);
    std::fill(out.begin(), out.end(), kNoPage);
    const double pz = camera.position[2];
    // From below (or on) the plane the terrain is back-facing: nothing is requested.
    if (fbw == 0 || fbh == 0 || params.main_width == 0 || params.main_height == 0 || vt.width == 0 || vt.height == 0 ||
        vt.tile_payload == 0 || !(pz > 0))
        return;

    // Per level: pages per axis (level L is ceil(size / 2^L) texels wide), the page's side in
    // level-0 texels, and the threshold on q from which the level is wanted.
    const std::uint32_t levels = std::clamp<std::uint32_t>(vt.levels, 1, kMaxLevels);
    std::array<std::uint64_t, kMaxLevels> pages_x{}, pages_y{};
    std::array<double, kMaxLevels> page_texels{}, inv_page_texels{}, threshold{};
    const SampleFilter filter = params.rule.filter;
    const double offset = filter == SampleFilter::bilinear ? 0.5 : 0.0;
    for (std::uint32_t l = 0; l < levels; ++l) {
        const std::uint64_t w = (std::uint64_t(vt.width) + (std::uint64_t(1) << l) - 1) >> l;
        const std::uint64_t h = (std::uint64_t(vt.height) + (std::uint64_t(1) << l) - 1) >> l;
        pages_x[l] = std::max<std::uint64_t>(1, (w + vt.tile_payload - 1) / vt.tile_payload);
        pages_y[l] = std::max<std::uint64_t>(1, (h + vt.tile_payload - 1) / vt.tile_payload);
        page_texels[l] = std::ldexp(double(vt.tile_payload), static_cast<int>(l));
        inv_page_texels[l] = 1.0 / page_texels[l];
        threshold[l] = std::exp2(2.0 * (double(l) - offset - double(params.bias)));
    }
    const double max_aniso = static_cast<double>(std::clamp<std::uint32_t>(params.rule.max_anisotropy, 1, 8));
    const double inv_aniso2 = 1.0 / (max_aniso * max_aniso);
    // The page (along one axis) of level-0 texel coordinate t at level l: floor(floor(t / 2^l) / P),
    // which is floor(t / (P 2^l)); the multiply is corrected with exact products.
    // (t >= 0 here, so truncation is floor, without a libm call.)
    auto page_of = [&](double t, std::uint32_t l, std::uint64_t count) {
        std::uint64_t p = static_cast<std::uint64_t>(t * inv_page_texels[l]);
        if (double(p) * page_texels[l] > t) --p;
        else if (double(p + 1) * page_texels[l] <= t) ++p;
        return std::min<std::uint64_t>(p, count - 1);
    };

    const Vec3d f = camera.forward(), r = camera.right(), u = camera.up();
    const double aspect = double(params.main_width) / double(params.main_height);
    const double sy = std::tan(camera.fov_y / 2.0), sx = sy * aspect;
    // One main-target pixel in NDC: the forward-difference steps of the derivatives.
    const double step_x = 2.0 / params.main_width, step_y = 2.0 / params.main_height;
    const double W = vt.width, H = vt.height, px = camera.position[0], py = camera.position[1];
    const double nx_step = 2.0 / fbw;

    for (std::uint32_t j = 0; j < fbh; ++j) {
        const double ny = 1.0 - (j + 0.5) / fbh * 2.0, ny_down = ny - step_y;
        // Ray direction d = f + nx sx r + ny sy u, with d . f = 1, so t is also the eye depth. r is
        // horizontal, so the hit distance depends on the row only.
        const double dz0 = f[2] + ny * sy * u[2], dz1 = f[2] + ny_down * sy * u[2];
        if (!(dz0 < 0)) continue;  // at or above the horizon
        const double t0 = -pz / dz0;
        if (t0 < camera.near_plane || t0 > camera.far_plane) continue;  // clipped on the GPU
        const double t1 = dz1 < 0 ? -pz / dz1 : t0;  // dz1 <= dz0 < 0 unless pitch is +-90 degrees
        const double ax0 = f[0] + ny * sy * u[0], ay0 = f[1] + ny * sy * u[1];
        const double ax1 = f[0] + ny_down * sy * u[0], ay1 = f[1] + ny_down * sy * u[1];
        // Along a row t is constant, so the forward difference to the right is exact: t0 * step.
        const double dudx = t0 * step_x * sx * r[0], dvdx = t0 * step_x * sx * r[1];
        const double rho_x2 = dudx * dudx + dvdx * dvdx;
        // The difference one main pixel down, linear in nx: (t1 a1 - t0 a0) + (t1 - t0) nx sx r.
        const double dudy0 = t1 * ax1 - t0 * ax0, dvdy0 = t1 * ay1 - t0 * ay0;
        const double dudy1 = (t1 - t0) * sx * r[0], dvdy1 = (t1 - t0) * sx * r[1];
        FeedbackId* row = out.data() + std::size_t(j) * fbw;
        std::uint32_t level = 0;
        for (std::uint32_t i = 0; i < fbw; ++i) {
            const double nx = (i + 0.5) * nx_step - 1.0;
            // Offsets from the camera first, so nothing cancels against 2^24-sized coordinates.
            const double tu = px + t0 * (ax0 + nx * sx * r[0]), tv = py + t0 * (ay0 + nx * sx * r[1]);
            if (!(tu >= 0 && tu < W && tv >= 0 && tv < H)) continue;
            const double dudy = dudy0 + nx * dudy1, dvdy = dvdy0 + nx * dvdy1;
            const double rho_y2 = dudy * dudy + dvdy * dvdy;
            const double major2 = std::max(rho_x2, rho_y2), minor2 = std::min(rho_x2, rho_y2);
            const double q = filter == SampleFilter::anisotropic ? std::max(minor2, major2 * inv_aniso2) : major2;
            // Neighbouring pixels mostly want the same level: walk from the last one.
            while (level + 1 < levels && q >= threshold[level + 1]) ++level;
            while (level > 0 && q < threshold[level]) --level;
            const bool near_lower = level > 0 && q < threshold[level] * (1 + kThresholdBand);
            const bool near_upper = level + 1 < levels && q >= threshold[level + 1] * (1 - kThresholdBand);
            std::uint32_t wanted = level;
            if (near_lower || near_upper)
                wanted = wanted_level(lod_from_derivatives(dudx, dvdx, dudy, dvdy, params.rule) + params.bias, filter, levels);
            const std::uint64_t x = page_of(tu, wanted, pages_x[wanted]);
            const std::uint64_t y = page_of(tv, wanted, pages_y[wanted]);
            row[i] = pack_feedback(PageKey{params.texture, static_cast<std::uint8_t>(wanted),
                                                           static_cast<std::uint32_t>(x), static_cast<std::uint32_t>(y)});
        }
    }
}

}  // namespace tessera::scene
