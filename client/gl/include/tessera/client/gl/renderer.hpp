#pragma once
// The GL side of the client (design.md, "One frame, end to end", steps 1-3 and 7): a physical page
// atlas, page-table textures, page and page-table uploads through staging rings (fences, never
// glFinish), the VT pass, the feedback pass at 1/N resolution read back through a PBO ring
// (polled, never waited on), and the per-frame fallback counters reduced on the GPU.
//
// VtRenderer is the runtime's PageUploader: Runtime::frame() calls upload_page/upload_page_table
// on the render thread; the renderer copies into its staging ring and issues the GL uploads.
//
// Sampling (shaders/vt_sample.glsl, one include any shader can use): LoD from the virtual-texel
// derivatives plus the bias; one page-table fetch (fallback entries point at the nearest resident
// ancestor); physical coordinates from integer page math (exact far from the origin); bilinear,
// trilinear (two lookups) or anisotropic (explicit taps along the major axis, up to 8, inside the
// 4-texel border) filtering. Levels: `lod` = log2(texels per pixel at level 0) + bias, clamped to
// [0, levels-1]; bilinear samples level floor(lod + 0.5)... see docs/renderer.md for the exact rule.
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "tessera/client/upload.hpp"
#include "tessera/result.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/scene/scene.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::client::gl {

enum class Filter { bilinear, trilinear, anisotropic };

struct RendererConfig {
    std::uint32_t width = 1280;   // colour target
    std::uint32_t height = 720;
    std::uint32_t feedback_scale = 8;  // feedback target is ceil(width/N) x ceil(height/N)
    Filter filter = Filter::trilinear;
    std::uint32_t max_anisotropy = 8;  // 1..8 (anisotropic filter only)
    std::uint32_t pool_slots = 1024;   // physical pages; the atlas is a grid of tile_size squares
    std::uint32_t tile_size = 256;     // stored tile size (payload + 2 * border)
    std::uint32_t border = 4;
    bool srgb = true;                  // atlas and target are sRGB: filtering in linear light
    std::size_t staging_bytes = 32u << 20;  // page staging ring (bounded; a full ring defers uploads)
    std::uint32_t readback_ring = 3;   // feedback/counter readbacks in flight
};

// Fallback counters of one rendered frame (design.md "Measures"), read back some frames later.
struct FrameCounters {
    std::uint64_t frame = 0;           // the render() call they belong to
    std::uint64_t textured_pixels = 0;
    std::uint64_t fallback_unbiased = 0;  // sampled level coarser than the level wanted without bias
    std::uint64_t fallback_biased = 0;    // ... coarser than the level wanted with the bias
};

// A feedback buffer read back from the GPU.
struct FeedbackFrame {
    std::uint64_t frame = 0;
    std::uint32_t width = 0, height = 0;
    float bias = 0;                 // the bias it was rendered with
    std::vector<FeedbackId> ids;    // width*height, row 0 at the top, kNoPage where no VT
};

class VtRenderer : public PageUploader {
public:
    // Needs a current GL 4.5 context. Errors: a pool that does not fit the GPU's largest texture,
    // bad sizes, shader compile/link errors (with the log).
    static Result<std::unique_ptr<VtRenderer>> create(const RendererConfig& config);
    ~VtRenderer() override = default;

    // The virtual texture `texture` has the geometry of `info` (a store); one texture per scene
    // for now. Creates its page-table texture (all levels packed in one R32UI texture).
    virtual Status add_texture(TextureId texture, const storage::StoreInfo& info) = 0;
    // Uploads the scene's chunks (vertex/index buffers); the scene is drawn with `texture`.
    virtual Status set_scene(const scene::Scene& scene, TextureId texture) = 0;

    // Renders one frame: feedback pass (at 1/N, depth-tested, same LoD math) and the VT pass with
    // the fallback counters. Returns the frame number. Never waits on the GPU.
    virtual std::uint64_t render(const scene::Camera& camera, float lod_bias) = 0;
    // A finished feedback readback, if any (the newest; older finished ones are dropped). Never waits.
    virtual bool poll_feedback(FeedbackFrame& out) = 0;
    // Finished counter readbacks, oldest first, appended. Never waits.
    virtual std::size_t poll_counters(std::vector<FrameCounters>& out) = 0;
    // Waits for the GPU and returns every outstanding readback (end of a run; tests).
    virtual void finish(std::vector<FrameCounters>* counters, FeedbackFrame* feedback) = 0;

    // The last frame's colour, RGBA8 (sRGB-encoded when config.srgb), rows top to bottom. Waits:
    // for tools and tests, not the render loop.
    virtual std::vector<std::uint8_t> read_color() = 0;
    // Blits the last frame to the default framebuffer (windowed mode).
    virtual void present(int window_width, int window_height) = 0;

    virtual const RendererConfig& config() const = 0;
};

// The reference renderer (design.md "Measures"): the same scene and camera drawn from an ordinary
// mipmapped GL texture with the same filter and LoD rule, no bias, for PSNR and max error.
// Levels: RGBA8 texels of each level of the virtual texture, level 0 first (sizes as in the store:
// ceil(size / 2^L)), e.g. decoded from a store's tile interiors.
class ReferenceRenderer {
public:
    struct Level {
        std::uint32_t width = 0, height = 0;
        std::vector<std::uint8_t> rgba8;
    };
    // Errors: a level 0 larger than GL_MAX_TEXTURE_SIZE ("does not fit": use the VT with every page
    // resident instead), levels not halving.
    static Result<std::unique_ptr<ReferenceRenderer>> create(const RendererConfig& config, std::span<const Level> levels);
    virtual ~ReferenceRenderer() = default;
    virtual Status set_scene(const scene::Scene& scene) = 0;
    virtual void render(const scene::Camera& camera) = 0;
    virtual std::vector<std::uint8_t> read_color() = 0;  // as VtRenderer::read_color
};

// Decodes every tile interior of a store into RGBA8 levels (for ReferenceRenderer). Errors: a
// store too large (level 0 over max_texels per side), unreadable or undecodable tiles.
Result<std::vector<ReferenceRenderer::Level>> decode_store_levels(const std::string& store_path, std::uint32_t max_side = 16384);

// PSNR (dB, over RGB, 8-bit) and max absolute error of two RGBA8 images of equal size, over the
// pixels where `mask` (optional, same size, non-zero = count) is set. PSNR is +inf when equal.
struct ImageError {
    double psnr = 0;
    int max_error = 0;
    std::uint64_t pixels = 0;
};
ImageError compare_images(std::span<const std::uint8_t> a, std::span<const std::uint8_t> b, std::uint32_t width,
                          std::uint32_t height);

}  // namespace tessera::client::gl
