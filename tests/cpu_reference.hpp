#pragma once
// An independent reference for the rendering tests: the documented sampling (docs/renderer.md,
// "Sampling", "Layers", "Cut-outs") written again in C++ on the CPU, sharing no GLSL and no LoD
// code with the renderer. GL only says where each pixel lands: a pass of its own writes each
// pixel's texel coordinate and its screen derivatives (peeled in depth, so cut-outs can show what
// lies behind), and everything from there on (level selection, bilinear, trilinear, the
// anisotropic taps, sRGB decode and encode, the lighting formula, the alpha test) is computed here
// in double precision from the texture's levels.
//
// Pixels on a knife edge (a level or tap count chosen by a lod within 1e-3 of a boundary, two
// derivatives of equal length choosing the taps' axis, a filtered alpha within 2/255 of the
// cut-off) have two legitimate outcomes, since float arithmetic on the GPU may round them either
// way: the reference renders each outcome, and a comparison takes the one nearest to the pixel.
#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "tessera/client/gl/reference_renderer.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/scene/scene.hpp"
#include "tessera/result.hpp"

namespace tessera::test::cpu_reference {

// One level in linear light, RGBA as floats in [0, 1].
struct Image {
    std::uint32_t width = 0, height = 0;
    std::vector<float> rgba;
};

// A texture as the reference samples it. Level L of a W x H texture is ceil(W / 2^L) texels wide
// (the store's rule); `second`, when given (block formats), holds one image per level but the
// last, the size of level L + 1, which trilinear blends level L with instead of level L + 1.
struct Texture {
    std::vector<Image> levels, second;
    bool repeat = false;  // wrap at the edges (GL_REPEAT) instead of clamping to them
};
// sRGB-decodes RGB when `srgb` (alpha stays linear).
Texture make_texture(std::span<const client::gl::ReferenceRenderer::Level> levels, bool srgb,
                     std::span<const client::gl::ReferenceRenderer::Level> second = {});

// What is drawn: a scene textured by a colour texture, lit by `normals` when that has levels.
struct Material {
    const scene::Scene* scene = nullptr;
    Texture colour;
    Texture normals;
};

// One outcome of a pixel: its RGBA8 colour, or nothing drawn.
struct Outcome {
    std::array<std::uint8_t, 4> rgba{};
    bool covered = false;
};
struct Frame {
    std::vector<std::uint8_t> rgba;     // RGBA8 rows top to bottom, as VtRenderer::read_color
    std::vector<std::uint8_t> covered;  // 1 where some surface is drawn
    std::vector<std::uint8_t> knife;    // 1 where the pixel's result turns on a rounding (see above)
    std::vector<std::vector<Outcome>> outcomes;  // there: the outcomes of the other roundings
    std::size_t layers_peeled = 0;      // depth layers the coordinate pass needed
};

// Renders `materials` seen by `camera` with the renderer configuration's filter, max anisotropy,
// sRGB target, alpha test and frame size, each pixel showing the nearest surface that survives the
// alpha test. Needs the current GL context (the coordinate pass). Errors: GL failures.
Result<Frame> render(const client::gl::RendererConfig& config, std::span<const Material> materials, const scene::Camera& camera);

// The per-pixel comparison the tests make, over the pixels both cover (on a knife edge: against
// the nearest of its outcomes).
struct Comparison {
    std::size_t compared = 0, knife = 0, alternative = 0, coverage_differs = 0;
    double psnr = 0;       // over RGB, dB (99 when equal)
    int max_error = 0;
    std::size_t over_3 = 0, over_16 = 0;  // pixels with an RGB channel off by more than 3 / 16
};
Comparison compare(std::span<const std::uint8_t> have, const Frame& want);
std::string describe(const Comparison& c);

}  // namespace tessera::test::cpu_reference
