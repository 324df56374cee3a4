#pragma once
// `tessera build --atlas SCENE.obj|SCENE.gltf|SCENE.glb -o ATLAS.tsr --obj-out ATLAS.obj`: the
// materials' textures of an OBJ or glTF 2.0 scene packed into one store (storage/atlas.hpp), and the
// scene written as an OBJ that addresses it (scene/atlas.hpp). docs/atlas.md describes the layout.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include <array>

#include "tessera/scene/atlas.hpp"
#include "tessera/result.hpp"
#include "tessera/storage/atlas.hpp"
#include "tessera/storage/builder.hpp"

namespace tessera::tools {

struct AtlasBuildSummary {
    storage::BuildSummary build;
    std::size_t images = 0;     // distinct images packed (textures and solid tiles)
    std::size_t triangles = 0;  // triangles in the rewritten OBJ
    std::size_t repeat_pieces = 0;  // of them, pieces of triangles cut where their textures repeat
    std::size_t repeating_images = 0;  // images whose texture coordinates leave [0, 1] (padding wraps)
    scene::UpAxis up = scene::UpAxis::y;  // resolved
    std::array<double, 3> extent{0, 0, 0};  // the scene's extent along x, y, z
    std::vector<std::string> warnings;  // what of the scene the atlas does not keep (AtlasSceneInput::warnings)
    std::vector<std::string> layers;    // a glTF scene with material maps: the store's layers ("base", then by role); else empty
    std::size_t maps = 0;               // material maps packed into those layers
};

// A material without a texture becomes a solid tile this many texels wide (before padding).
inline constexpr std::uint32_t kSolidTileTexels = 8;

// On any error nothing is left at `store` or `obj_out` (files already there stay untouched until
// the build succeeds); images a glTF scene holds inside itself are written to a temporary folder
// beside the store while it is built, and removed. The OBJ is written to a temporary file beside `obj_out` and renamed into
// place once the store is complete.
Result<AtlasBuildSummary> build_atlas(const std::string& obj, const std::string& store, const std::string& obj_out,
                                      const storage::BuildOptions& options, const storage::AtlasPackOptions& pack,
                                      const storage::BuildProgressFn& progress = {},
                                      scene::UpAxis up = scene::UpAxis::automatic);

}  // namespace tessera::tools
