// The scene beside a store file (store_scene.hpp).
#include "tessera/storage/store_scene.hpp"

#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>

namespace tessera::storage {
namespace fs = std::filesystem;

std::string scene_path_beside(const std::string& store_path) { return fs::path(store_path).replace_extension(".obj").string(); }

std::optional<std::uint64_t> scene_store_id(std::string_view text) {
    std::size_t at = 0;
    for (int line = 0; line < 16 && at < text.size() && text[at] == '#'; ++line) {
        std::size_t nl = text.find('\n', at);
        if (nl == std::string_view::npos) nl = text.size();
        const std::string_view l = text.substr(at, nl - at);
        constexpr std::string_view kTag = "# tessera-store ";
        if (l.substr(0, kTag.size()) == kTag && l.size() >= kTag.size() + 16) {
            const std::string hex(l.substr(kTag.size(), 16));
            if (hex.find_first_not_of("0123456789abcdef") == std::string::npos) return std::strtoull(hex.c_str(), nullptr, 16);
        }
        at = nl + 1;
    }
    return std::nullopt;
}

std::optional<std::string> find_scene_beside(const std::string& store_path, std::uint64_t store_id) {
    const std::string path = scene_path_beside(store_path);
    if (path == store_path) return std::nullopt;
    std::ifstream f(path, std::ios::binary);
    if (!f) return std::nullopt;
    std::string head(4096, '\0');
    f.read(head.data(), static_cast<std::streamsize>(head.size()));
    head.resize(static_cast<std::size_t>(f.gcount()));
    const auto id = scene_store_id(head);
    if (!id || *id != store_id) return std::nullopt;
    return path;
}

Result<SceneBytes> read_scene_bytes(const std::string& path, std::uint64_t offset, std::uint64_t length) {
    std::error_code ec;
    const auto size = fs::file_size(path, ec);
    if (ec) return make_error(Errc::not_found, "scene '" + path + "': " + ec.message());
    SceneBytes out;
    out.total = size;
    if (offset >= size) return out;
    std::ifstream f(path, std::ios::binary);
    if (!f) return make_error(Errc::io_error, "cannot read scene '" + path + "'");
    f.seekg(static_cast<std::streamoff>(offset));
    out.data.resize(static_cast<std::size_t>(std::min<std::uint64_t>(length, size - offset)));
    f.read(out.data.data(), static_cast<std::streamsize>(out.data.size()));
    if (static_cast<std::size_t>(f.gcount()) != out.data.size()) return make_error(Errc::io_error, "cannot read scene '" + path + "'");
    return out;
}

}  // namespace tessera::storage
