#pragma once
// The reference renderer (docs/viewer.md, "Measures"): what the VT should look like, drawn from an
// ordinary mipmapped GL texture, for PSNR and max error against VtRenderer's frames
// (tessera/client/measures.hpp compares them).
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "tessera/client/gl/renderer.hpp"
#include "tessera/client/measures.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/scene/scene.hpp"
#include "tessera/result.hpp"

namespace tessera::client::gl {

// The reference renderer (docs/viewer.md, "Measures"): the same scene and camera drawn from an
// ordinary mipmapped GL texture with the same filter and LoD rule, no bias, for PSNR and max error.
// Levels: RGBA8 texels of each level of the virtual texture, level 0 first, rows top to bottom,
// e.g. decoded from a store's tile interiors; as many levels as the store has (the LoD clamp). Uses
// config's width, height, filter, max_anisotropy and srgb.
class ReferenceRenderer {
public:
    using Level = ImageLevel;  // tessera/client/measures.hpp
    // Errors: a level 0 larger than GL_MAX_TEXTURE_SIZE ("does not fit": use the VT with every page
    // resident instead), levels not halving: each level must be max(1, previous / 2) per side (GL's
    // mip chain rounds down, the store's rounds up: they agree for power-of-two sides).
    // `layers`: the levels of each layer the config lights layer 0 with (the normal layer, or a
    // material's maps), in the order the VT samples them (normal, metallic-roughness, occlusion,
    // emissive: those named), each as many and as large as `levels`; the reference lights its
    // colour as the VT pass does.
    // `second_levels` (optional; and then `layer_second_levels`, one list per layer): what a
    // block-format atlas holds under each page of level L as its coarser level
    // (client::decode_store_second_levels), one per level but the last, the size of level L + 1.
    // Given, trilinear and anisotropic lookups blend level L with it, as the VT does, instead of
    // with level L + 1.
    using Levels = std::vector<Level>;
    static Result<std::unique_ptr<ReferenceRenderer>> create(const RendererConfig& config, std::span<const Level> levels,
                                                             std::span<const Levels> layers = {},
                                                             std::span<const Level> second_levels = {},
                                                             std::span<const Levels> layer_second_levels = {});
    virtual ~ReferenceRenderer() = default;
    virtual Status set_scene(const scene::Scene& scene) = 0;
    // The texture repeats past its edges (GL_REPEAT) instead of clamping (the default): one
    // repeating texture of an OBJ scene, sampled as a GPU samples it, against which the atlas's
    // cut and wrapped copy is checked.
    virtual void set_repeat(bool repeat) = 0;
    virtual void render(const scene::Camera& camera) = 0;
    virtual std::vector<std::uint8_t> read_color() = 0;  // as VtRenderer::read_color
};

}  // namespace tessera::client::gl
