#include "png_write.hpp"

#include <fmt/format.h>
#include <stb/stb_image_write.h>

#include <climits>
#include <ostream>

#include "atomic_file.hpp"
#include "commands.hpp"

namespace tessera::tools {

namespace {

// stb's PNG writer hands its output to a callback in pieces; this one appends them to a stream.
void append_to_stream(void* context, void* data, int size) {
    static_cast<std::ostream*>(context)->write(static_cast<const char*>(data), size);
}

}  // namespace

void write_png(const std::string& path, std::uint32_t w, std::uint32_t h, const std::vector<std::uint8_t>& rgba) {
    if (rgba.size() != std::size_t(w) * h * 4) throw Failure(fmt::format("cannot write '{}': wrong image size", path));
    if (w == 0 || h == 0 || w > INT_MAX / 4 || h > INT_MAX) throw Failure(fmt::format("cannot write '{}': image size {}x{} out of range", path, w, h));
    write_file_atomically(path, [&](std::ostream& out) {
        if (!stbi_write_png_to_func(append_to_stream, &out, int(w), int(h), 4, rgba.data(), int(w) * 4))
            throw Failure(fmt::format("cannot write '{}': PNG encoding failed", path));
    });
}

}  // namespace tessera::tools
