// The LoD rule (lod.hpp): client/gl/shaders/vt_sample.glsl mirrors these lines.
#include "tessera/scene/lod.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace tessera::scene {

float lod_from_derivatives(double dudx, double dvdx, double dudy, double dvdy, const LodRule& rule) {
    const double rho_x = std::sqrt(dudx * dudx + dvdx * dvdx);
    const double rho_y = std::sqrt(dudy * dudy + dvdy * dvdy);
    if (std::isnan(rho_x) || std::isnan(rho_y)) return std::numeric_limits<float>::quiet_NaN();
    const double major = std::max(rho_x, rho_y), minor = std::min(rho_x, rho_y);
    double lod;
    if (rule.filter == SampleFilter::anisotropic) {
        const double max_aniso = static_cast<double>(std::clamp<std::uint32_t>(rule.max_anisotropy, 1, 8));
        lod = std::log2(std::max(minor, major / max_aniso));
    } else {
        lod = std::log2(major);
    }
    return static_cast<float>(lod);
}

std::uint32_t wanted_level(float lod, SampleFilter filter, std::uint32_t levels) {
    const std::uint32_t last = levels > 0 ? levels - 1 : 0;
    if (std::isnan(lod)) return 0;
    const float l = filter == SampleFilter::bilinear ? std::floor(lod + 0.5f) : std::floor(lod);
    if (!(l > 0.0f)) return 0;  // also -inf
    if (l >= static_cast<float>(last)) return last;  // also +inf
    return static_cast<std::uint32_t>(l);
}

}  // namespace tessera::scene
