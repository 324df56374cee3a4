// How long opening a store and the first lookups take, against the number of tiles.
// Writes stores of 1k to 4M tiles (uniform tiles: cheap to write, full index), then measures
// open (header, level table, block tables), the first lookup in a cold index block, and a warm
// lookup. Prints a table; JSON with --json FILE.
// With --store FILE [--rounds N] [--cold]: opens that store N times (default 5) instead and prints
// each open's time, the first (the least warm) and the best, its index bytes and block tables;
// --cold first asks the kernel to drop the file's cached pages (posix_fadvise DONTNEED) before
// every open, so the open reads from the disk.
#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/store_writer.hpp"

using namespace tessera;
using namespace tessera::storage;
using Clock = std::chrono::steady_clock;

namespace {

void drop_cached(const std::string& path) {
    const int fd = ::open(path.c_str(), O_RDONLY);
    if (fd < 0) return;
    ::fdatasync(fd);
    ::posix_fadvise(fd, 0, 0, POSIX_FADV_DONTNEED);
    ::close(fd);
}

int open_one(const std::string& path, int rounds, bool cold) {
    double first = 0, best = 1e300;
    for (int i = 0; i < rounds; ++i) {
        if (cold) drop_cached(path);
        const auto t0 = Clock::now();
        auto r = StoreReader::open(path);
        const double ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
        if (!r) {
            std::fprintf(stderr, "store_open_bench: %s\n", r.error().message.c_str());
            return 1;
        }
        if (i == 0) {
            first = ms;
            std::uint64_t index = 0, tiles = 0, sparse = 0;
            for (const auto& l : (*r)->info().levels) {
                index += l.index_bytes;
                tiles += l.present + l.uniform;
                sparse += l.sparse_block_table ? 1 : 0;
            }
            std::printf("%s: format %u.%u, %.1f MiB, %llu tiles with data, index %llu bytes, %llu of %u levels with sparse block tables\n",
                        path.c_str(), (*r)->info().version_major, (*r)->info().version_minor,
                        double((*r)->info().file_size) / 1048576.0, (unsigned long long)tiles, (unsigned long long)index,
                        (unsigned long long)sparse, (*r)->info().level_count());
        }
        best = std::min(best, ms);
        std::printf("  open %d: %.3f ms\n", i + 1, ms);
    }
    std::printf("first %.3f ms, best %.3f ms%s\n", first, best, cold ? " (cold: the file's pages dropped before each open)" : "");
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    std::string json_path, store;
    int rounds = 5;
    bool cold = false;
    for (int i = 1; i < argc; ++i)
        if (std::string(argv[i]) == "--cold") cold = true;
    for (int i = 1; i + 1 < argc; ++i) {
        if (std::string(argv[i]) == "--json") json_path = argv[i + 1];
        if (std::string(argv[i]) == "--store") store = argv[i + 1];
        if (std::string(argv[i]) == "--rounds") rounds = std::max(1, std::atoi(argv[i + 1]));
    }
    if (!store.empty()) return open_one(store, rounds, cold);
    const auto dir = std::filesystem::temp_directory_path() / "tessera-open-bench";
    std::filesystem::create_directories(dir);
    std::string json = "[";
    std::printf("%10s %12s %12s %14s %14s\n", "tiles", "file MiB", "open ms", "cold lookup us", "warm lookup us");
    for (std::uint32_t side : {32u, 256u, 1024u, 2048u}) {
        StoreSpec s;
        s.width = s.height = side * 248;
        s.tile_payload = 248;
        s.border = 4;
        s.channels = 3;
        s.codec = Codec::jpeg;
        const std::string path = (dir / ("open-" + std::to_string(side) + ".tsr")).string();
        {
            auto w = StoreWriter::create(path, s);
            if (!w) return 1;
            const auto levels = level_geometry(s.width, s.height, s.tile_payload);
            for (std::uint32_t l = 0; l < levels.size(); ++l)
                for (std::uint32_t y = 0; y < levels[l].tiles_y; ++y)
                    for (std::uint32_t x = 0; x < levels[l].tiles_x; ++x) {
                        const std::uint8_t v[3] = {std::uint8_t(x), std::uint8_t(y), std::uint8_t(l)};
                        if (!(*w)->add_uniform({l, x, y}, v).ok()) return 1;
                    }
            if (!(*w)->finish().ok()) return 1;
        }
        const auto t0 = Clock::now();
        auto r = StoreReader::open(path);
        const auto t1 = Clock::now();
        if (!r) return 1;
        auto a = (*r)->locate({0, side / 2, side / 2});
        const auto t2 = Clock::now();
        auto b = (*r)->locate({0, side / 2 + 1, side / 2});
        const auto t3 = Clock::now();
        if (!a || !b) return 1;
        std::uint64_t tiles = 0;
        for (const auto& l : (*r)->info().levels) tiles += std::uint64_t(l.tiles_x) * l.tiles_y;
        const double open_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
        const double cold_us = std::chrono::duration<double, std::micro>(t2 - t1).count();
        const double warm_us = std::chrono::duration<double, std::micro>(t3 - t2).count();
        std::printf("%10llu %12.1f %12.3f %14.1f %14.2f\n", (unsigned long long)tiles, double((*r)->info().file_size) / 1048576.0,
                    open_ms, cold_us, warm_us);
        json += (json.size() > 1 ? "," : "") + std::string("{\"tiles\":") + std::to_string(tiles) + ",\"open_ms\":" +
                std::to_string(open_ms) + ",\"cold_lookup_us\":" + std::to_string(cold_us) + ",\"warm_lookup_us\":" +
                std::to_string(warm_us) + "}";
        std::filesystem::remove(path);
    }
    json += "]\n";
    if (!json_path.empty()) std::ofstream(json_path) << json;
    return 0;
}
