#pragma once
// Geometry the VT renderer draws, GL-free (the load tester and the CPU feedback use it too).
//
// Precision (docs/stability.md): texture coordinates are never one float UV over the whole virtual
// texture. Each chunk carries an integer texel origin (level-0 texels of the virtual texture) and
// its vertices carry float texel offsets relative to it, small enough to be exact to a fraction of
// a texel; likewise positions are float offsets from a double-precision chunk origin.
#include <cstdint>
#include <memory>
#include <string_view>
#include <string>
#include <vector>

#include "tessera/result.hpp"
#include "tessera/scene/camera.hpp"

namespace tessera::scene {

struct Vertex {
    float position[3];  // world units, relative to Chunk::origin
    float texel[2];     // level-0 texels of the virtual texture, relative to Chunk::texel_origin
};

struct Chunk {
    Vec3d origin{0, 0, 0};                 // world position of local (0, 0, 0)
    std::uint32_t texel_origin[2] = {0, 0};  // level-0 texel of local texel (0, 0)
    std::vector<Vertex> vertices;
    std::vector<std::uint32_t> indices;  // triangles, counter-clockwise seen from the front
    // Vertex normals, world frame, three floats per vertex (an OBJ's `vn`, for lighting a
    // material: docs/renderer.md, "Materials"); empty where the scene has none.
    std::vector<float> normals;
    // Drawn blended over what lies behind (a glTF BLEND material: docs/renderer.md, "Blended
    // surfaces"): after every other chunk, back to front, writing no depth.
    bool blend = false;
    double bounds_min[3] = {0, 0, 0};    // world-space box of the chunk (for culling)
    double bounds_max[3] = {0, 0, 0};
    // A heightfield over a regular grid (make_terrain's chunks; 0: not one): grid_quads quads per
    // side, vertex (i, j) at j * (grid_quads + 1) + i and at (i, j) * grid_quad_size from the
    // origin in x and y, quad (i, j)'s triangles at indices 6 * (j * grid_quads + i): (i, j)
    // (i+1, j) (i+1, j+1), then (i, j) (i+1, j+1) (i, j+1). grid_chunk: the chunk's column and row
    // in the scene's chunk grid (Scene::chunk_pitch). Such scenes can be drawn front to back.
    std::uint32_t grid_quads = 0;
    double grid_quad_size[2] = {0, 0};
    std::int64_t grid_chunk[2] = {0, 0};
};

struct Scene {
    std::string name;                  // "terrain", "atlas", ...
    std::uint32_t vt_width = 0;        // the virtual texture the scene is textured with (texels)
    std::uint32_t vt_height = 0;
    std::vector<Chunk> chunks;
    double bounds_min[3] = {0, 0, 0};  // the whole scene
    double bounds_max[3] = {0, 0, 0};
    // Heightfield scenes: chunk (c, r) of the grid (Chunk::grid_chunk) has its origin at
    // (c, r) * chunk_pitch in x and y. 0: the chunks are not one grid.
    double chunk_pitch = 0;
};

// Heights over the whole virtual texture, e.g. a level of a store's height layer: width x height
// samples in [0, 1], row-major from (0, 0), sample (i, j) covering level-0 texels
// [i * t, (i + 1) * t) x [j * t, (j + 1) * t) with t = texels_per_sample (a store level L: 2^L,
// its last samples possibly overhanging the texture, as store levels round up), read at their
// centres; 0: the samples divide the texture evenly. Read bilinearly, clamped at the edges.
struct HeightField {
    std::uint32_t width = 0, height = 0;
    std::vector<float> samples;
    double texels_per_sample = 0;
};

struct TerrainOptions {
    std::uint32_t vt_width = 0;   // the virtual texture's size: the plane is vt_width x vt_height
    std::uint32_t vt_height = 0;  // world units (one unit per level-0 texel), from (0,0) to (w,h)
    std::uint32_t chunk_texels = 4096;  // chunk side in level-0 texels (the last row/column may be smaller)
    std::uint32_t quads_per_chunk = 16;  // grid resolution per chunk side
    double displacement = 0;  // peak height in world units; 0: a flat plane (z = 0)
    // Where the heights come from: this field (height = displacement * sample), or when null a
    // smooth deterministic function of the position.
    std::shared_ptr<const HeightField> heights;
};
// The `terrain` scene: one virtual texture on a ground plane, optionally displaced (by `heights`
// or the height function). Errors: zero sizes, chunk_texels or quads_per_chunk 0, a height field
// with no samples or a wrong number of them.
Result<Scene> make_terrain(const TerrainOptions& options);

// True when no triangle of the scene can hide another: all lie in one plane and face the same way
// (so with back faces culled a pixel sees at most triangles that overlap in that plane, which a
// depth pre-pass would not separate either). The flat terrain is; displaced terrain and OBJ scenes
// are not. The VT renderer skips its depth pre-pass for such scenes, and for heightfields
// (Chunk::grid_quads), which it draws front to back.
bool overdraw_free(const Scene& scene);

// Height of the displaced terrain at world (x, y) (0 when displacement is 0); what make_terrain uses
// (options.heights read bilinearly, or the height function).
double terrain_height(const TerrainOptions& options, double x, double y);

// The `atlas` scene: an OBJ file whose texture coordinates address the packed atlas virtual
// texture (written by `tessera build --atlas`, see atlas.hpp): u, v in [0, 1] of the atlas, v down.
// Positions are taken as they are: Y up (OBJ's convention), or Z up when the file's header says
// "# tessera-up z"; converted to this library's Z up.
Result<Scene> load_obj_scene(const std::string& obj_path, std::uint32_t vt_width, std::uint32_t vt_height);
// The same from the OBJ's text (say, a scene a server sends with its store); `obj_path` names it
// in messages.
Result<Scene> parse_obj_scene(const std::string& text, const std::string& obj_path, std::uint32_t vt_width, std::uint32_t vt_height);

// What the comment lines at the top of an atlas OBJ say: "# tessera-atlas W H" (the atlas size)
// and "# tessera-up y|z". (Its "# tessera-store ID" line: storage/store_scene.hpp.)
struct AtlasObjHeader {
    bool atlas = false;  // has "# tessera-atlas W H"
    std::uint64_t width = 0, height = 0;
    bool z_up = false;
};
AtlasObjHeader read_atlas_obj_header(std::string_view text);

}  // namespace tessera::scene
