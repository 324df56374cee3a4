#pragma once
// The GLSL sources of client/gl/shaders/, embedded at build time (cmake/embed_shaders.cmake).
#include <span>
#include <string>
#include <string_view>

namespace tessera::client::gl::detail {

struct EmbeddedShader {
    const char* name;    // file name, e.g. "vt_sample.glsl"
    const char* source;  // its text
};

std::span<const EmbeddedShader> embedded_shaders();

}  // namespace tessera::client::gl::detail
