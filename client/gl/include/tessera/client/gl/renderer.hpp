#pragma once
// The GL side of the client (docs/client.md, "One frame, end to end", steps 1-3 and 7; details in
// docs/renderer.md): a physical page atlas, page-table textures, page and page-table uploads
// through staging rings (fences, never glFinish), the VT pass, the feedback pass at 1/N resolution
// read back through a PBO ring (polled, never waited on), and the per-frame fallback counters
// reduced on the GPU.
//
// VtRenderer is the runtime's PageUploader: Runtime::frame() calls upload_page, write_page_table
// and set_slot_weights on the render thread; the renderer copies into its staging ring and issues
// the GL uploads. Every decision about a page (which slot, when it fades) is the runtime's.
//
// Sampling (shaders/vt_sample.glsl, one include any shader can use): LoD from the virtual-texel
// derivatives plus the bias; one page-table fetch per lookup (fallback entries point at the
// nearest resident ancestor); physical coordinates from integer page math (exact far from the
// origin) plus the border; bilinear, trilinear (one lookup: the atlas holds each page's next
// coarser level) or anisotropic (explicit trilinear taps along the major axis, up to 8, looked up
// in the 2x2 pages around the centre: four fetches per pixel) filtering.
// Levels (the rule is tessera/scene/lod.hpp; the GLSL mirrors it): `lod` = log2 of the level-0
// texels per main-target pixel (anisotropic: of max(minor, major / max_anisotropy)) + bias;
// bilinear samples level clamp(floor(lod + 0.5), 0, levels - 1); trilinear and anisotropic look up
// floor(lod) and floor(lod) + 1 of the lod clamped to [0, levels - 1], blended by its fraction.
// The feedback requests the page of that level (bilinear) or of floor(lod) (the finer one).
// An empty page-table entry (nothing resident) samples kNoDataColour. See docs/renderer.md.
// The reference renderer, which draws the same scene from a plain mipmapped texture, is in
// reference_renderer.hpp; the measures that compare the two in tessera/client/measures.hpp.
#include <cstdint>
#include <memory>
#include <optional>
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
    std::uint32_t max_anisotropy = 8;  // 1..8 (anisotropic filter only; the page payload must be >= 2x it)
    std::uint32_t pool_slots = 1024;   // physical pages; the atlas is a grid of tile_size squares
    std::uint32_t tile_size = 256;     // stored tile size (payload + 2 * border)
    std::uint32_t border = 4;
    bool srgb = true;                  // atlas and target are sRGB: filtering in linear light
    // How the atlas holds pages (docs/renderer.md, "Page formats"): rgba8, or block-compressed
    // bc1 (colour), bc4 (one channel), bc5 (two channels), which the runtime transcodes to
    // (pool_format()). Block formats need a tile size that is a multiple of 4 (8 with two levels)
    // and the GPU's support for them, checked at creation.
    PageFormat page_format = PageFormat::rgba8;
    // A multi-layer pool (docs/renderer.md, "Layers"): layers 1, 2, ... of every page, each in an
    // atlas of its own format with layer 0's grid, so one page-table entry places a page in all of
    // them. Empty: one layer.
    struct Layer {
        PageFormat page_format = PageFormat::rgba8;
        bool srgb = false;  // colour with the sRGB curve (data layers: false)
    };
    std::vector<Layer> more_layers;
    // What the VT pass draws: layer `show_layer`'s texels as they are (0: the colour layer); with
    // `normal_layer` set and show_layer 0, layer 0 lit by the unit normals in that layer (x in red,
    // y in alpha, each mapped from [0, 1] to [-1, 1]: a 2-channel store's two samples; z implied).
    std::uint32_t show_layer = 0;
    std::optional<std::uint32_t> normal_layer;
    // A glTF scene's material layers (docs/renderer.md, "Materials"): with show_layer 0 and any of
    // these set, layer 0 is the base colour of a metallic-roughness material lit by one sun and an
    // ambient term, with the maps in these layers (a tangent-space normal map in RGB; G roughness
    // and B metallic; R occlusion; an emissive colour). Not with normal_layer.
    struct MaterialLayers {
        std::optional<std::uint32_t> normal, metallic_roughness, occlusion, emissive;
        bool any() const { return normal || metallic_roughness || occlusion || emissive; }
    };
    MaterialLayers material;
    // The layers drawn beside layer 0, in the order the shaders sample them: the normal layer, or
    // the material's maps in the order above (those set). Empty: none, or a layer other than 0 shown.
    std::vector<std::uint32_t> sampled_layers() const;
    std::size_t staging_bytes = 32u << 20;  // page + page-table staging ring (bounded; when full, uploads go
                                            // straight from client memory: RendererStats::direct_uploads)
    // Page-sized buffers of mapped GPU memory lent to the runtime to decode pages into
    // (page_staging()), made 32 at a time as needed, at most this many: enough for every page
    // the runtime stages (64) and two frames of uploads the GPU has not read yet. 0: none (pages
    // are copied through the staging ring).
    std::uint32_t staging_pages = 192;
    std::uint32_t readback_ring = 3;   // feedback readbacks in flight (counters: 4x as many; 1..64)
    // Frames the GPU may be behind: render() waits for the frame this many back to finish, as a
    // swap chain's frame latency does. Headless rendering has no swap to throttle it, and on a
    // fast GPU the CPU would otherwise queue thousands of frames, so feedback and counters came
    // back seconds late. 1..16; at most readback_ring keeps a feedback readback every frame.
    std::uint32_t frames_in_flight = 3;
    // Feedback jitter: each frame the feedback pass samples a different sub-pixel position of its
    // N x N block of main pixels (a fixed permutation of the N*N positions), so a page visible in
    // only a few main pixels is requested within N*N frames instead of never. Off: every frame
    // samples the block centre (what scene::cpu_feedback computes; the exactness tests use that).
    bool feedback_jitter = true;
    // Prefetch (docs/renderer.md, "Prefetch"): the feedback asks for pages `feedback_prefetch_lod`
    // levels finer than the sampling wants (a camera moving closer needs them a few frames later),
    // and sees `feedback_guard_band` (a fraction) more of the scene on every side than the image
    // (pages about to turn into view). Both 0: the feedback is exactly what the image samples.
    float feedback_prefetch_lod = 0.0f;  // 0..2
    float feedback_guard_band = 0.0f;    // 0..1
    // Cut-outs (docs/renderer.md, "Cut-outs"): pixels whose filtered texel has alpha below 0.5
    // are discarded, in the depth pre-pass, the VT pass and the feedback pass alike, so what lies
    // behind shows, keeps its depth and has its pages requested. For stores with alpha (straight,
    // as docs/store-format.md's "Alpha"); the frame is drawn opaque. Off: alpha is ignored.
    bool alpha_test = false;
    // Whether the atlas holds each page's next coarser level under it: the trilinear and
    // anisotropic filters read it.
    bool has_second_level() const { return filter != Filter::bilinear; }
};

// The colour drawn where nothing is resident on a page's path (an empty entry): opaque magenta,
// linear RGBA. Pixels without geometry are cleared to transparent black.
inline constexpr float kNoDataColour[4] = {1.0f, 0.0f, 1.0f, 1.0f};

// Fallback counters of one rendered frame (docs/viewer.md, "Measures"), read back some frames
// later. textured_pixels: pixels the VT pass shaded (each visible pixel once: depth pre-pass, then
// early fragment tests). An empty entry counts as fallback.
struct FrameCounters {
    std::uint64_t frame = 0;           // the render() call they belong to
    std::uint64_t textured_pixels = 0;
    std::uint64_t fallback_unbiased = 0;  // sampled level coarser than the level wanted without bias
    std::uint64_t fallback_biased = 0;    // ... coarser than the level wanted with the bias
};

// What the renderer did since it was created (for logs, tests and the viewer's overlay).
struct RendererStats {
    std::uint64_t frames = 0;
    std::uint64_t pages_uploaded = 0;
    std::uint64_t table_uploads = 0;          // page-table rectangles and blocks
    std::uint64_t direct_uploads = 0;         // uploads made from client memory: the staging ring was full
    std::uint64_t pages_copied = 0;           // pages not in lent memory (page_staging()): copied on the CPU
    std::uint64_t page_bytes_copied = 0;      // their bytes
    std::uint64_t malformed_uploads = 0;      // ignored: bad slot, size, texture, level or rectangle
    std::uint64_t feedback_skipped = 0;       // frames without a feedback readback: every ring slot in flight
    std::uint64_t counters_skipped = 0;       // frames without counters: every counter slot in flight
    std::uint64_t gl_errors = 0;              // glGetError reports, checked in finish() (never per frame)
    std::uint64_t depth_prepasses = 0;        // frames drawn with a depth pre-pass (scenes that need one
                                              // and cannot be drawn front to back)
    std::size_t visible_chunks = 0;           // last frame
    std::size_t fading_pages = 0;             // last frame: cells below full weight (set_slot_weights):
                                              // blending in, fading out or kept (RuntimeConfig::fade_ms)
    std::uint64_t predicted_feedback = 0;     // feedback passes drawn from set_feedback_camera's camera
    std::uint64_t gpu_waits = 0;              // frames whose render() waited for the GPU to finish the
                                              // frame RendererConfig::frames_in_flight back
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
    virtual ~VtRenderer() = default;

    // The virtual texture `texture` has the geometry of `info` (a store); one texture per scene
    // for now. Creates its page-table texture (all levels packed in one R32UI texture), or, when
    // that is over 16384 entries per side (PageTable::dense_packing_fits), a two-level table fed
    // by upload_page_table_block (docs/renderer.md). Errors: a two-level table over the GPU's
    // largest shader storage block.
    virtual Status add_texture(TextureId texture, const storage::StoreInfo& info) = 0;
    // Uploads the scene's chunks (vertex/index buffers); the scene is drawn with `texture`.
    virtual Status set_scene(const scene::Scene& scene, TextureId texture) = 0;

    // Renders one frame: feedback pass (at 1/N, depth-tested, same LoD math) and the VT pass with
    // the fallback counters. Returns the frame number. Never waits on the GPU.
    virtual std::uint64_t render(const scene::Camera& camera, float lod_bias) = 0;
    // The camera the next render()'s feedback pass sees instead of the frame's: a view a few
    // frames ahead, predicted from the camera's motion, so that its pages are requested before
    // they come into view (docs/renderer.md, "Motion prefetch"). Applies to one frame.
    virtual void set_feedback_camera(const scene::Camera& camera) = 0;
    // What the next frame would show at `camera` if no page, page table, blending weight or bias
    // changed: the main pass drawn now, with the last frame's state, into a target of its own
    // (RGBA8 as read_color). No feedback, no counters, the frame number unchanged. Call it after
    // render() and before the runtime's next uploads: the viewer's pop rate compares it with the
    // next frame (docs/viewer.md, "Measures"). Waits: for measurement, not the render loop.
    virtual std::vector<std::uint8_t> render_preview(const scene::Camera& camera) = 0;
    // A finished feedback readback, if any (the newest; older finished ones are dropped). Never waits.
    virtual bool poll_feedback(FeedbackFrame& out) = 0;
    // Finished counter readbacks, oldest first, appended. Never waits.
    virtual std::size_t poll_counters(std::vector<FrameCounters>& out) = 0;
    // Waits for the GPU and returns every outstanding readback (end of a run; tests).
    virtual void finish(std::vector<FrameCounters>* counters, FeedbackFrame* feedback) = 0;

    // The last frame's colour, RGBA8 (sRGB-encoded when config.srgb), rows top to bottom. Waits:
    // for tools and tests, not the render loop.
    virtual std::vector<std::uint8_t> read_color() = 0;
    // The texels of physical slot `slot` as layer `layer`'s atlas holds them, in its page format
    // (level 0, tile_size^2 texels; uncompressed formats only, else empty). Waits: for tools and
    // tests.
    virtual std::vector<std::uint8_t> read_page(SlotId slot, std::uint32_t layer = 0) = 0;
    // Blits the last frame to the default framebuffer (windowed mode).
    virtual void present(int window_width, int window_height) = 0;

    // The memory to decode pages into, for Runtime::create: pages decoded there are uploaded
    // without another copy (docs/renderer.md, "Staging"). Lives as long as the renderer.
    virtual PageStaging& page_staging() = 0;

    virtual const RendererConfig& config() const = 0;
    virtual RendererStats stats() const = 0;
};

}  // namespace tessera::client::gl
