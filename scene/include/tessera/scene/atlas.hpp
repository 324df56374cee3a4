#pragma once
// The scene side of `tessera build --atlas` (the image side, packing and composing the atlas, is
// storage/atlas.hpp): read an OBJ or glTF 2.0 scene and its materials, list the images its
// materials use, and write the scene as an OBJ whose texture coordinates address the packed atlas.
// The rewritten OBJ is what load_obj_scene (scene.hpp) reads; docs/atlas.md says what of a glTF
// scene it keeps.
//
// Texture coordinates of the rewritten OBJ: u, v in [0, 1] of the whole atlas, u to the right and
// v DOWN (v = 0 is the atlas's row 0, as texel coordinates of the virtual texture) -- the opposite
// of the usual OBJ convention (v up), so every v is flipped when rewriting. Its first line names the
// atlas size ("# tessera-atlas W H"), so a mismatched store is caught by load_obj_scene.
#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "tessera/result.hpp"

namespace tessera::scene {

// A glTF material's map other than its base colour, packed into a layer of its own (docs/atlas.md,
// "Material layers"), in the same cell as the base colour.
enum class MapRole : std::uint8_t { normal = 0, metallic_roughness = 1, occlusion = 2, emissive = 3 };
inline constexpr std::size_t kMapRoles = 4;
// The layer names, by MapRole, after the first layer ("base").
inline constexpr std::array<const char*, kMapRoles> kMapLayerNames = {"normal", "metallic_roughness", "occlusion", "emissive"};

// An image of the scene: a file, or one inside the scene (a GLB buffer view, a data URI).
struct AtlasMapRef {
    // The file, resolved against the scene's folder; for an image inside the scene a name for
    // messages ("scene.glb image 2 'bark'"). Empty: no image.
    std::string texture;
    std::shared_ptr<const std::vector<std::uint8_t>> embedded;  // an image inside the scene: its file's bytes
    std::string embedded_extension;        // ".png", ".jpg", ...: the embedded bytes' format (from the MIME type)
};

// One cell of the atlas: a material's colour texture (OBJ's map_Kd, glTF's baseColorTexture), or
// a small solid tile of the material's colour (Kd, baseColorFactor) for a material without one;
// with a glTF material's other maps, which share its texture coordinates and its cell.
struct AtlasImageRef : AtlasMapRef {
    std::array<std::uint8_t, 3> colour{};  // no colour texture: the colour, 8-bit sRGB
    std::vector<std::string> materials;    // the materials that use this image (for messages)
    bool repeats = false;                  // texture coordinates leave [0, 1]: its cell's padding wraps around
    bool opaque = false;                   // its alpha is not used (every glTF material drawing it is OPAQUE)
    // The material's maps by MapRole (an empty texture: none), and what a layer holds where a map
    // is missing: the flat normal (128, 128, 255), metallic-roughness (0, roughnessFactor,
    // metallicFactor) as 8-bit values, full occlusion (255), the emissive colour (emissiveFactor
    // times KHR_materials_emissive_strength, clamped, 8-bit sRGB).
    std::array<AtlasMapRef, kMapRoles> maps;
    std::array<std::array<std::uint8_t, 3>, kMapRoles> map_values{
        {{128, 128, 255}, {0, 255, 255}, {255, 255, 255}, {0, 0, 0}}};
    // Whether the cell is one solid texel value (no colour texture and no map): its texture
    // coordinates all go to its middle.
    bool solid() const {
        if (!texture.empty()) return false;
        for (const auto& m : maps)
            if (!m.texture.empty()) return false;
        return true;
    }
};

// Which OBJ axis points up. OBJ's convention is Y, but SketchUp and many CAD and GIS exports are Z
// up. automatic: Z when the scene is flatter along Z than along Y (a site, a landscape, a room
// written Z up), else Y -- a Z-up tower taller than it is deep needs an explicit z.
enum class UpAxis { automatic, y, z };

// Where an image was placed in the atlas: its level-0 texel rectangle (row 0 at the top).
struct AtlasRect {
    std::uint32_t x = 0, y = 0, width = 0, height = 0;
};

class AtlasSceneInput {
public:
    // Reads an OBJ (.obj) and its MTL files (found beside it), or a glTF 2.0 scene (.gltf with its
    // buffers and images, or .glb; glTF is Y up, so `automatic` means y there). A triangle across
    // which its texture repeats is cut at the repeats (u = k, v = j) into pieces that each lie in
    // one copy, with new positions (and normals) where the cuts cross its edges; glTF's mirrored
    // and clamped wrap modes are cut the same way. Errors: the file missing or malformed, a
    // material library, material or texture file that cannot be found, a glTF extension the scene
    // requires and this reader does not honour (named), no triangles, a texture coordinate that is
    // not finite, more than 2^16 repeats across one triangle or 2^24 triangles in all: the message
    // names the material.
    static Result<AtlasSceneInput> load(const std::string& path, UpAxis up = UpAxis::automatic);

    AtlasSceneInput(AtlasSceneInput&&) noexcept;
    AtlasSceneInput& operator=(AtlasSceneInput&&) noexcept;
    ~AtlasSceneInput();

    // The atlas's cells, in first-use order: the same texture file used by two materials is one cell
    // (unless their glTF maps or map values differ).
    const std::vector<AtlasImageRef>& images() const;
    std::size_t triangle_count() const;     // after cutting at repeats
    std::size_t repeat_piece_count() const;  // triangles (after fan triangulation) that cutting made
    UpAxis up_axis() const;                  // y or z, resolved
    std::array<double, 3> extent() const;    // the positions' extent along x, y, z (the file's axes)
    // What of the scene the atlas does not keep, one line each (e.g. a colour factor on a
    // textured glTF material, lines and points): the build prints them.
    const std::vector<std::string>& warnings() const;
    // The files read besides the textures, each with what it is ("scene", "material library",
    // "buffer"), so that a build can refuse an output that would overwrite one of them.
    struct InputFile {
        std::string path, role;
    };
    const std::vector<InputFile>& input_files() const;

    // The rewritten OBJ text: positions and normals as they were, texture coordinates mapped into
    // rects[i] for images()[i] (a solid image's texels all map to its middle texel's centre), one
    // object per shape, triangles only, no materials. `source_note` goes into a comment; the up
    // axis into "# tessera-up y|z" on the second line (load_obj_scene reads it).
    Result<std::string> rewrite(std::span<const AtlasRect> rects, std::uint32_t atlas_width, std::uint32_t atlas_height,
                                const std::string& source_note) const;

private:
    struct Impl;
    explicit AtlasSceneInput(std::unique_ptr<Impl> impl);
    std::unique_ptr<Impl> impl_;
};

}  // namespace tessera::scene
