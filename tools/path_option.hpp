#pragma once
// The --path option of `view`, `bench`, `demo` and `loadtest`: the scene library's built-in camera
// paths or a path file, resolved by scene::CameraPath::builtin_or_file.
#include <fmt/format.h>

#include <string>

#include "tessera/scene/path.hpp"

namespace tessera::tools {

// The option's help: the built-in names as the scene library lists them.
inline std::string camera_path_help() {
    return fmt::format("camera path: {}, or a path file (docs/paths.md); auto: flyover over the terrain, orbit around an "
                       "OBJ scene",
                       fmt::join(scene::CameraPath::builtin_names(), ", "));
}

}  // namespace tessera::tools
