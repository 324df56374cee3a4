#pragma once
// The sample `atlas` scene: a small gallery (floor, four walls, three boxes and a plinth) as an OBJ
// with its MTL and one procedurally generated PNG texture per surface, each a labelled pattern (its
// name and cell coordinates on a grid), so a rendered view shows which texture, where and which way
// up. Used by the tests and by the `walk` camera path; `tessera source scene:gallery -o DIR`.
#include <string>

#include "tessera/result.hpp"

namespace tessera::tools {

// Writes DIR/gallery.obj, DIR/gallery.mtl and DIR/textures/*.png. DIR must not exist or be empty;
// the files are made in a temporary folder beside it and renamed into place, so a failure leaves
// nothing behind. Units are metres, Y up (OBJ's convention): the room spans x -10..10, z -6..6,
// walls 4 high. One box's texture coordinates lie in [1, 2] x [-1, 0] (a whole repeat away from
// [0, 1], which the atlas build shifts back); the plinth's material has a colour and no texture.
Status write_gallery_scene(const std::string& dir);

}  // namespace tessera::tools
