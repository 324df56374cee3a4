#pragma once
// What the OBJ and glTF readers of the atlas build make (atlas.hpp): positions, normals, triangles
// by image, and the images. The readers hand each textured triangle to add_textured_triangle, which
// cuts it where its texture repeats (or is mirrored, or clamped) and maps every piece into [0, 1].
#include <array>
#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "tessera/scene/atlas.hpp"

namespace tessera::scene::detail {

// How texture coordinates outside [0, 1] address the texture, per axis (glTF's sampler wrap
// modes; OBJ textures repeat).
enum class Wrap { repeat, mirrored_repeat, clamp_to_edge };

struct Corner {
    int v = -1, n = -1;
    double u = 0.5, t = 0.5;  // texture coordinate mapped into [0, 1], v UP (OBJ's orientation)
};
struct Triangle {
    std::uint32_t image = 0;
    Corner c[3];
    bool blend = false;  // drawn blended (a glTF BLEND material): written as an object of its own
};
struct Shape {
    std::string name;
    std::vector<Triangle> triangles;
};

struct AtlasInputData {
    std::vector<float> positions, normals;  // xyz triples
    std::vector<Shape> shapes;
    std::vector<AtlasImageRef> images;
    std::size_t triangles = 0;
    std::size_t cut_pieces = 0;  // pieces of triangles cut at texture repeats
    UpAxis up = UpAxis::y;
    std::array<double, 3> extent{0, 0, 0};
    std::vector<std::string> warnings;
    std::vector<AtlasSceneInput::InputFile> input_files;  // the scene file, material libraries, buffers

    // Positions (normals) made by cutting, one per distinct value: the pieces on both sides of a
    // cut share them.
    struct BitsHash {
        std::size_t operator()(const std::array<std::uint32_t, 3>& k) const noexcept {
            return (std::size_t(k[0]) * 0x9e3779b97f4a7c15ULL) ^ (std::size_t(k[1]) * 0xc2b2ae3d27d4eb4fULL) ^ k[2];
        }
    };
    std::unordered_map<std::array<std::uint32_t, 3>, int, BitsHash> cut_positions, cut_normals;
};

// One textured triangle of `shape`: v and vn index positions and normals (vn -1: none), uv its
// texture coordinates with v UP (OBJ's orientation). The triangle is cut at every boundary where
// the texture repeats (or mirrors, or clamps) on an axis and each piece is mapped into [0, 1].
// `context` names the material and shape in messages. Errors: a coordinate that is not finite, too
// many repeats across the triangle, too many triangles in all.
Status add_textured_triangle(AtlasInputData& data, Shape& shape, std::uint32_t image, const int (&v)[3], const int (&vn)[3],
                             const double (&uv)[3][2], const Wrap (&wrap)[2], const std::string& context);

// Extent and up axis once every triangle is in (automatic: Z when the scene is flatter along Z
// than along Y, OBJ's rule); an error naming `what` when there are no triangles.
Status finish_atlas_input(AtlasInputData& data, UpAxis up, const std::string& what);

// A reader library's message on one line (newlines become spaces, trailing ones dropped).
std::string trim_newlines(std::string s);

// The readers (obj_atlas.cpp, gltf_atlas.cpp): fill `data` from the scene at `path`.
Status read_obj(const std::string& path, UpAxis up, AtlasInputData& data);
Status read_gltf(const std::string& path, UpAxis up, AtlasInputData& data);

}  // namespace tessera::scene::detail
