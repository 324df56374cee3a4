#pragma once
// The feedback buffer computed on the CPU, without GL: for the `terrain` scene with a flat plane
// (displacement 0), every feedback pixel's ray is intersected with the plane and its page is
// found with the shared LoD rule (lod.hpp). Used by the rendering tests (the GPU feedback pass
// must request exactly these pages) and by `tessera loadtest` (viewers with no GL).
//
// Pixel (i, j) of a fb_width x fb_height feedback target (row 0 at the top) covers main-target
// pixels; its sample point is its centre, NDC ((i + 0.5) / fb_width * 2 - 1, 1 - (j + 0.5) /
// fb_height * 2). Derivatives are per main-target pixel (main_width x main_height): forward
// differences of the texel coordinate one main pixel right and one main pixel down, matching the
// GPU's dFdx/dFdy closely (they differ only where a pixel straddles a level or page boundary).
#include <cstdint>
#include <vector>

#include "tessera/page_key.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/scene/lod.hpp"
#include "tessera/scene/scene.hpp"

namespace tessera::scene {

struct VtGeometry {
    std::uint32_t width = 0, height = 0;  // level-0 texels
    std::uint32_t tile_payload = 0;       // P
    std::uint32_t levels = 0;             // store levels (last one is a single tile)
};

struct CpuFeedbackParams {
    std::uint32_t main_width = 0, main_height = 0;
    std::uint32_t fb_width = 0, fb_height = 0;
    float bias = 0;
    LodRule rule;
    TextureId texture = 0;
};

// Per pixel: the page wanted (kNoPage where the ray misses the plane or lands outside the
// texture [0, width) x [0, height), or hits it from below). `out` is resized to fb_width*fb_height.
void cpu_feedback(const Camera& camera, const VtGeometry& vt, const CpuFeedbackParams& params,
                  std::vector<FeedbackId>& out);

}  // namespace tessera::scene
