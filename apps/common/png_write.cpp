#include "png_write.hpp"

#include <fmt/format.h>

#include <ostream>

#include "atomic_file.hpp"
#include "failure.hpp"
#include "tessera/storage/png_encode.hpp"

namespace tessera::tools {

void write_png(const std::string& path, std::uint32_t w, std::uint32_t h, const std::vector<std::uint8_t>& rgba) {
    auto png = storage::encode_png(storage::PngImage{w, h, 4, storage::SampleType::u8, storage::ColourSpace::srgb, rgba});
    if (!png.ok()) throw Failure(fmt::format("cannot write '{}': {}", path, png.error().message));
    write_file_atomically(path, [&](std::ostream& out) { out.write(reinterpret_cast<const char*>(png->data()), std::streamsize(png->size())); });
}

}  // namespace tessera::tools
