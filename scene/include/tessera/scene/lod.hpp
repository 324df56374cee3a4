#pragma once
// The LoD rule, shared by the GLSL sampling function (client/gl/shaders/vt_sample.glsl mirrors it
// line for line), the CPU feedback and the tests. One definition, so the feedback pass, the
// sampling and the CPU visible set agree on which page a pixel wants.
//
// Inputs: the derivatives of the level-0 texel coordinate per pixel of the *main* colour target
// (the feedback pass, rendered at 1/N resolution, computes exact forward differences one main
// pixel right and one down, as cpu_feedback does; see docs/renderer.md).
//   rho_x = |(du/dx, dv/dx)|, rho_y = |(du/dy, dv/dy)|, major = max, minor = min
//   bilinear, trilinear:  lod = log2(major)
//   anisotropic:          lod = log2(max(minor, major / max_anisotropy))   (taps = ceil(major / 2^lod))
// then lod += bias. The level a pixel wants (its page is what the feedback writes):
//   bilinear:               clamp(floor(lod + 0.5), 0, levels - 1)   (the level it samples)
//   trilinear, anisotropic: clamp(floor(lod), 0, levels - 1)         (the finer of the two lookups)
// A lod that is NaN or -inf (zero derivatives) counts as level 0; +inf as the last level.
#include <cstdint>

namespace tessera::scene {

enum class SampleFilter { bilinear, trilinear, anisotropic };

struct LodRule {
    SampleFilter filter = SampleFilter::trilinear;
    std::uint32_t max_anisotropy = 8;  // 1..8; anisotropic only
};

// Unbiased lod (may be -inf for zero derivatives, NaN for NaN input).
float lod_from_derivatives(double dudx, double dvdx, double dudy, double dvdy, const LodRule& rule);
// The wanted level for lod (bias already added), clamped to [0, levels - 1]; levels >= 1.
std::uint32_t wanted_level(float lod, SampleFilter filter, std::uint32_t levels);

}  // namespace tessera::scene
