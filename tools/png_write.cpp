#include "png_write.hpp"

#include <OpenImageIO/imageio.h>
#include <fmt/format.h>

#include <filesystem>

#include "commands.hpp"

namespace tessera::tools {

void write_png(const std::string& path, std::uint32_t w, std::uint32_t h, const std::vector<std::uint8_t>& rgba) {
    namespace fs = std::filesystem;
    if (rgba.size() != std::size_t(w) * h * 4) throw Failure(fmt::format("cannot write '{}': wrong image size", path));
    const fs::path target(path);
    const std::string temp = (target.parent_path() / ("." + target.filename().string() + ".tmp.png")).string();
    auto out = OIIO::ImageOutput::create(temp);
    if (!out) throw Failure(fmt::format("cannot write '{}': {}", path, OIIO::geterror()));
    OIIO::ImageSpec spec(int(w), int(h), 4, OIIO::TypeDesc::UINT8);
    const bool ok = out->open(temp, spec) && out->write_image(OIIO::TypeDesc::UINT8, rgba.data()) && out->close();
    std::error_code ec;
    if (ok) fs::rename(temp, target, ec);
    if (!ok || ec) {
        fs::remove(temp, ec);
        throw Failure(fmt::format("cannot write '{}'", path));
    }
}

}  // namespace tessera::tools
