// Writes every present tile of a store as a static file, for serving the same tiles with a plain
// web server (bench/serve_vs_nginx.sh: nginx). The layout is tessera's HTTP URL layout under a
// root directory, so one URL list serves both:
//
//   DIR/{name}/tiles/{level}/{x}/{y}      the stored payload, byte for byte (e.g. a JPEG)
//   DIR/urls.txt                          one URL path per line: /v1/stores/{name}/tiles/{level}/{x}/{y}
//
// (a web server maps /v1/stores/ to DIR/). Uniform and absent tiles have no payload and are skipped.
//
//   export_tiles STORE.tsr DIR [--name NAME]
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "tessera/storage/store_reader.hpp"

using namespace tessera;
using namespace tessera::storage;
namespace fs = std::filesystem;

int main(int argc, char** argv) {
    std::vector<std::string> args(argv + 1, argv + argc);
    std::string name;
    std::vector<std::string> positional;
    for (std::size_t i = 0; i < args.size(); ++i) {
        if (args[i] == "--name" && i + 1 < args.size()) name = args[++i];
        else positional.push_back(args[i]);
    }
    if (positional.size() != 2) {
        std::fprintf(stderr, "usage: export_tiles STORE.tsr DIR [--name NAME]\n");
        return 2;
    }
    const std::string store_path = positional[0];
    const fs::path dir = positional[1];
    if (name.empty()) name = fs::path(store_path).stem().string();  // a store is named by its file

    auto opened = StoreReader::open(store_path);
    if (!opened) {
        std::fprintf(stderr, "export_tiles: %s: %s\n", store_path.c_str(), opened.error().message.c_str());
        return 1;
    }
    const auto& reader = **opened;
    const auto& info = reader.info();

    std::error_code ec;
    fs::create_directories(dir / name / "tiles", ec);
    std::ofstream urls(dir / "urls.txt", std::ios::trunc);
    if (ec || !urls) {
        std::fprintf(stderr, "export_tiles: cannot write under %s\n", dir.c_str());
        return 1;
    }
    std::uint64_t files = 0, bytes = 0, skipped = 0;
    for (std::uint32_t l = 0; l < info.level_count(); ++l) {
        const auto& lv = info.levels[l];
        for (std::uint32_t x = 0; x < lv.tiles_x; ++x) {
            const fs::path column = dir / name / "tiles" / std::to_string(l) / std::to_string(x);
            bool made = false;
            for (std::uint32_t y = 0; y < lv.tiles_y; ++y) {
                auto tile = reader.read_tile({l, x, y});
                if (!tile) {
                    std::fprintf(stderr, "export_tiles: tile %u/%u/%u: %s\n", l, x, y, tile.error().message.c_str());
                    return 1;
                }
                if (tile->kind != TileKind::present) {
                    ++skipped;
                    continue;
                }
                if (!made) {
                    fs::create_directories(column, ec);
                    if (ec) {
                        std::fprintf(stderr, "export_tiles: %s: %s\n", column.c_str(), ec.message().c_str());
                        return 1;
                    }
                    made = true;
                }
                const fs::path file = column / std::to_string(y);
                std::ofstream out(file, std::ios::binary | std::ios::trunc);
                out.write(reinterpret_cast<const char*>(tile->bytes.data()), std::streamsize(tile->bytes.size()));
                if (!out) {
                    std::fprintf(stderr, "export_tiles: cannot write %s\n", file.c_str());
                    return 1;
                }
                urls << "/v1/stores/" << name << "/tiles/" << l << '/' << x << '/' << y << '\n';
                ++files;
                bytes += tile->bytes.size();
            }
        }
    }
    urls.close();
    if (!urls) {
        std::fprintf(stderr, "export_tiles: cannot write %s\n", (dir / "urls.txt").c_str());
        return 1;
    }
    std::printf("%llu tiles, %.1f MiB -> %s/%s/tiles (%llu uniform or absent skipped); URLs in %s\n",
                (unsigned long long)files, double(bytes) / 1048576.0, dir.c_str(), name.c_str(),
                (unsigned long long)skipped, (dir / "urls.txt").c_str());
    return 0;
}
