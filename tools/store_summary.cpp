#include "store_summary.hpp"

#include <fmt/format.h>

#include "progress.hpp"

namespace tessera::tools {
namespace {

struct Totals {
    std::uint64_t tiles = 0, present = 0, uniform = 0, absent = 0, dedup = 0, payload = 0, raw = 0, texels = 0;
};

Totals totals(const storage::StoreInfo& info) {
    Totals t;
    for (const auto& l : info.levels) {
        t.tiles += std::uint64_t(l.tiles_x) * l.tiles_y;
        t.present += l.present;
        t.uniform += l.uniform;
        t.absent += l.absent;
        t.dedup += l.deduplicated;
        t.payload += l.payload_bytes;
        t.texels += std::uint64_t(l.width) * l.height;
        t.raw += std::uint64_t(l.width) * l.height * info.texel_bytes();
    }
    return t;
}

double bits_per_texel(std::uint64_t bytes, std::uint64_t texels) { return texels ? 8.0 * double(bytes) / double(texels) : 0.0; }

}  // namespace

void print_store_summary(const std::string& name, const storage::StoreInfo& info) {
    const Totals t = totals(info);
    fmt::print("store      {}  (format {}.{}, id {:016x}, {})\n", name, info.version_major, info.version_minor, info.store_id,
               human_bytes(info.file_size));
    fmt::print("image      {} x {}, {} x {} ({}{}), codec {}\n", info.width, info.height, info.channels,
               storage::to_string(info.sample_type), storage::to_string(info.colour_space), info.has_alpha ? ", alpha" : "",
               tessera::to_string(info.codec));
    fmt::print("tiles      {} texels ({} payload + 2 x {} border), {} levels\n", info.tile_size(), info.tile_payload, info.border,
               info.level_count());
    fmt::print("{:>5} {:>13} {:>11} {:>9} {:>8} {:>8} {:>7} {:>11} {:>10}\n", "level", "texels", "tiles", "present", "uniform",
               "absent", "dedup", "bytes", "bits/texel");
    for (std::size_t i = 0; i < info.levels.size(); ++i) {
        const auto& l = info.levels[i];
        fmt::print("{:>5} {:>13} {:>11} {:>9} {:>8} {:>8} {:>7} {:>11} {:>10.2f}\n", i, fmt::format("{}x{}", l.width, l.height),
                   fmt::format("{}x{}", l.tiles_x, l.tiles_y), l.present, l.uniform, l.absent, l.deduplicated,
                   human_bytes(l.payload_bytes), bits_per_texel(l.payload_bytes, std::uint64_t(l.width) * l.height));
    }
    fmt::print("{:>5} {:>13} {:>11} {:>9} {:>8} {:>8} {:>7} {:>11} {:>10.2f}\n", "all", "", t.tiles, t.present, t.uniform, t.absent,
               t.dedup, human_bytes(t.payload), bits_per_texel(t.payload, t.texels));
    fmt::print("compression {:.1f}:1 (raw texels of all levels {} / file {})\n",
               info.file_size ? double(t.raw) / double(info.file_size) : 0.0, human_bytes(t.raw), human_bytes(info.file_size));
}

nlohmann::json store_summary_json(const std::string& name, const storage::StoreInfo& info) {
    const Totals t = totals(info);
    nlohmann::json j;
    j["store"] = name;
    j["format_version"] = fmt::format("{}.{}", info.version_major, info.version_minor);
    j["store_id"] = fmt::format("{:016x}", info.store_id);
    j["file_bytes"] = info.file_size;
    j["width"] = info.width;
    j["height"] = info.height;
    j["channels"] = info.channels;
    j["sample_type"] = storage::to_string(info.sample_type);
    j["colour_space"] = storage::to_string(info.colour_space);
    j["has_alpha"] = info.has_alpha;
    j["codec"] = tessera::to_string(info.codec);
    j["tile_size"] = info.tile_size();
    j["tile_payload"] = info.tile_payload;
    j["border"] = info.border;
    j["level_count"] = info.level_count();
    auto& levels = j["levels"] = nlohmann::json::array();
    for (std::size_t i = 0; i < info.levels.size(); ++i) {
        const auto& l = info.levels[i];
        levels.push_back({{"level", i},
                          {"width", l.width},
                          {"height", l.height},
                          {"tiles_x", l.tiles_x},
                          {"tiles_y", l.tiles_y},
                          {"present", l.present},
                          {"uniform", l.uniform},
                          {"absent", l.absent},
                          {"deduplicated", l.deduplicated},
                          {"payload_bytes", l.payload_bytes},
                          {"bits_per_texel", bits_per_texel(l.payload_bytes, std::uint64_t(l.width) * l.height)}});
    }
    j["totals"] = {{"tiles", t.tiles},
                   {"present", t.present},
                   {"uniform", t.uniform},
                   {"absent", t.absent},
                   {"deduplicated", t.dedup},
                   {"payload_bytes", t.payload},
                   {"raw_bytes", t.raw},
                   {"bits_per_texel", bits_per_texel(t.payload, t.texels)},
                   {"compression_ratio", info.file_size ? double(t.raw) / double(info.file_size) : 0.0}};
    return j;
}

}  // namespace tessera::tools
