#pragma once
// PNG output for the viewer's frames, through the same encoder as the server's PNG tiles (so the
// command line needs no OpenImageIO: that lives in the builder's module, loaded on demand).
#include <cstdint>
#include <string>
#include <vector>

namespace tessera::tools {

// Writes RGBA8 rows (top to bottom) as PNG, to a temporary name renamed into place. Throws
// tools::Failure on error.
void write_png(const std::string& path, std::uint32_t width, std::uint32_t height, const std::vector<std::uint8_t>& rgba);

}  // namespace tessera::tools
