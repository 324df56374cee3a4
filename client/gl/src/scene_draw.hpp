#pragma once
// What both renderers share: the scene's chunks in GL buffers, drawn camera-relative with
// frustum culling, and an offscreen colour + depth target.
#include <cstdint>
#include <string>
#include <vector>

#include "gl_util.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "tessera/result.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/scene/scene.hpp"

namespace tessera::client::gl::detail {

// The #defines of a program drawn with scene.vert that includes vt_sample.glsl: the filter and the
// renderer-wide constants compiled in (vt_sample.glsl, "Inputs"). `atlas_width` x `atlas_height`:
// the page atlas's texels (the reference renderer has none: 1 x 1).
std::string vt_shader_defines(const RendererConfig& c, std::uint32_t atlas_width, std::uint32_t atlas_height);

// Uniform locations (scene.vert's) the scene's draw calls set per chunk.
struct ChunkUniforms {
    GLint chunk_offset = -1;  // vec3: float(chunk.origin - camera.position)
    GLint texel_origin = -1;  // uvec2: the texel frame's origin (the chunk's, or near the camera)
    GLint texel_shift = -1;   // vec2: the chunk's texel origin minus the frame's (scene.vert adds it)
    // The chunk's page frame (vt_sample.glsl, "Addressing"): ivec2, vec2, vec4. Set when the
    // program uses them, once set_page_layout was called.
    GLint chunk_page = -1, chunk_base = -1, chunk_bounds = -1;
    GLint blend = -1;  // int: 1 for a blended chunk (scene::Chunk::blend), where the program reads it
};

class SceneGeometry {
public:
    SceneGeometry();
    // Uploads every chunk (one vertex and one index buffer; per-chunk base vertex and offset).
    // Bounds for culling are recomputed from the vertices. Errors: indices out of range.
    Status upload(const scene::Scene& scene);
    bool empty() const { return chunks_.empty(); }
    // Picks the chunks inside the camera's frustum (in double, camera-relative).
    void cull(const scene::Camera& camera, double aspect);
    // Each chunk's page frame for a virtual texture of width x height texels with `payload`
    // texels per page: what the VT shaders address pages with.
    void set_page_layout(std::uint32_t payload, std::uint32_t width, std::uint32_t height);
    // Heightfield scenes (every chunk a grid of one chunk grid: scene::Chunk::grid_quads): puts
    // the chunks `cull` kept, and each one's triangles, in front-to-back order for `camera`, which
    // `draw` then follows until the next `cull`. Drawn so with GL_LESS, each pixel's first
    // fragment is the one it sees and every later one fails the depth test: each visible pixel is
    // shaded once without a depth pre-pass. False (and the stored order kept) for other scenes,
    // or when more than kMaxOrderedQuads quads are in view.
    bool order_front_to_back(const scene::Camera& camera);
    static constexpr std::size_t kMaxOrderedQuads = 1u << 16;
    // Which of the chunks `cull` kept a draw covers: the opaque ones (cut-outs included) in their
    // order, the blended ones (scene::Chunk::blend) from the farthest to the nearest, or both in
    // that order.
    enum class Chunks { opaque, blended, all };
    // Draws the chunks `cull` kept with the bound program.
    void draw(const Program& program, const ChunkUniforms& u, const scene::Camera& camera, Chunks which = Chunks::all) const;
    // Whether `cull` kept any blended chunk.
    bool blended_visible() const { return blend_begin_ < visible_.size(); }
    std::size_t visible_chunks() const { return visible_.size(); }

    // The widest chunk whose offsets from its own texel origin keep 1/256 of a texel
    // (docs/stability.md); wider terrain chunks are addressed from a frame near the camera.
    static constexpr double kExactChunkTexels = 32768;

private:
    // A texel frame's page frame: the level-0 page holding its origin, the origin's position in
    // it, and the texture's texels relative to that page's start (min, max).
    struct PageFrame {
        std::int32_t page[2] = {0, 0};
        float base[2] = {0, 0}, bounds[4] = {0, 0, 0, 0};
        void set(const std::uint32_t origin[2], std::uint32_t payload, const std::uint32_t size[2]);
    };
    struct ChunkDraw {
        scene::Vec3d origin{0, 0, 0};
        std::uint32_t texel_origin[2] = {0, 0};
        GLsizei index_count = 0;
        std::size_t index_offset = 0;  // bytes
        GLint base_vertex = 0;
        double bmin[3] = {0, 0, 0}, bmax[3] = {0, 0, 0};
        // set_page_layout: the page frame of the chunk's texel origin.
        bool has_frame = false;
        PageFrame frame;
        // Texels are ground positions (the terrain): draw may move the frame to the camera.
        bool texel_is_ground = false;
        double texel_extent[2] = {0, 0};  // the largest texel offset of a vertex
        // The heightfield grid (scene::Chunk's), and where order_front_to_back put its indices.
        std::uint32_t grid_quads = 0;
        double quad_size[2] = {0, 0};
        std::int64_t grid_chunk[2] = {0, 0};
        std::size_t ordered_offset = 0;  // bytes
        bool blend = false;             // scene::Chunk::blend
    };
    VertexArray vao_;
    Buffer vertices_, indices_;
    Buffer normals_;  // three floats per vertex, when the scene has normals
    std::vector<ChunkDraw> chunks_;
    std::vector<std::uint32_t> visible_;  // opaque chunks, then blended ones from blend_begin_, far to near
    std::size_t blend_begin_ = 0;
    bool any_blend_ = false;  // the scene has a blended chunk
    double chunk_pitch_ = 0;  // > 0: a heightfield scene
    std::uint32_t payload_ = 0, size_[2] = {0, 0};  // set_page_layout's
    // This frame's front-to-back indices (orphaned and refilled each frame: the GPU may still be
    // reading the last frame's).
    Buffer ordered_indices_;
    bool ordered_ = false;
    std::vector<std::uint32_t> order_scratch_, order_count_;
};

// The view-projection matrix without translation: projection * view_rotation.
scene::Mat4f view_projection(const scene::Camera& camera, double aspect);

// An offscreen colour (RGBA8 or SRGB8_ALPHA8) + depth (32F) framebuffer.
struct ColourTarget {
    Texture colour;
    Renderbuffer depth;
    Framebuffer fbo;
    std::uint32_t width = 0, height = 0;
    bool srgb = false;
};
Result<ColourTarget> make_colour_target(std::uint32_t width, std::uint32_t height, bool srgb);
// RGBA8 (the stored bytes: sRGB-encoded for an sRGB target), rows top to bottom. Waits.
std::vector<std::uint8_t> read_colour(const ColourTarget& t);

// Clear colour of pixels without geometry (linear RGBA; black, alpha 0).
inline constexpr float kBackground[4] = {0.0f, 0.0f, 0.0f, 0.0f};

// Binds `t` for drawing over all of it (sRGB encoding on for an sRGB target, colour and depth
// writes on) and clears it to kBackground and the far depth.
void begin_colour_pass(const ColourTarget& t);

}  // namespace tessera::client::gl::detail
