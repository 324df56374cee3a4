#include "store_summary.hpp"

#include <fmt/format.h>

#include "progress.hpp"
#include "tessera/storage/store_json.hpp"
#include "tessera/storage/store_scene.hpp"

namespace tessera::tools {

using storage::bits_per_texel;

void print_store_summary(const std::string& name, const storage::StoreInfo& info) {
    const storage::StoreTotals t = storage::store_totals(info);
    fmt::print("store      {}  (format {}.{}, id {:016x}, {})\n", name, info.version_major, info.version_minor, info.store_id,
               human_bytes(info.file_size));
    if (info.layered())
        fmt::print("image      {} x {}, {} layers (below), codec layers\n", info.width, info.height, info.layers.size());
    else
        fmt::print("image      {} x {}, {} x {} ({}{}), codec {}\n", info.width, info.height, info.channels,
                   storage::to_string(info.sample_type), storage::to_string(info.colour_space), info.has_alpha ? ", alpha" : "",
                   tessera::to_string(info.codec));
    fmt::print("tiles      {} texels ({} payload + 2 x {} border), {} levels\n", info.tile_size(), info.tile_payload, info.border,
               info.level_count());
    if (const auto scene = storage::find_scene_beside(name, info.store_id))
        fmt::print("scene      {} (the atlas scene that travels with this store: docs/atlas.md)\n", *scene);
    // "index": the level's block table and entry blocks; an "s" marks a sparse block table.
    fmt::print("{:>5} {:>13} {:>11} {:>9} {:>8} {:>8} {:>7} {:>11} {:>10} {:>12}\n", "level", "texels", "tiles", "present", "uniform",
               "absent", "dedup", "bytes", "bits/texel", "index");
    for (std::size_t i = 0; i < info.levels.size(); ++i) {
        const auto& l = info.levels[i];
        fmt::print("{:>5} {:>13} {:>11} {:>9} {:>8} {:>8} {:>7} {:>11} {:>10.2f} {:>12}\n", i, fmt::format("{}x{}", l.width, l.height),
                   fmt::format("{}x{}", l.tiles_x, l.tiles_y), l.present, l.uniform, l.absent, l.deduplicated,
                   human_bytes(l.payload_bytes), bits_per_texel(l.payload_bytes, std::uint64_t(l.width) * l.height),
                   human_bytes(l.index_bytes) + (l.sparse_block_table ? " s" : "  "));
    }
    fmt::print("{:>5} {:>13} {:>11} {:>9} {:>8} {:>8} {:>7} {:>11} {:>10.2f} {:>12}\n", "all", "", t.tiles, t.present, t.uniform, t.absent,
               t.deduplicated, human_bytes(t.payload_bytes), bits_per_texel(t.payload_bytes, t.texels), human_bytes(t.index_bytes) + "  ");
    if (info.layered()) {
        // Each layer's bytes come from the layer table (no tile is read); the rest of the payload is
        // the bundles' tables.
        fmt::print("{:>5} {:<31} {:>8} {:>4} {:>7} {:>6} {:>11} {:>6}\n", "layer", "name", "channels", "type", "colour",
                   "codec", "bytes", "share");
        std::uint64_t parts = 0;
        for (std::size_t i = 0; i < info.layers.size(); ++i) {
            const auto& l = info.layers[i];
            parts += l.payload_bytes;
            fmt::print("{:>5} {:<31} {:>8} {:>4} {:>7} {:>6} {:>11} {:>5.1f}%\n", i, l.name,
                       fmt::format("{}{}", l.channels, l.has_alpha ? "+a" : ""), storage::to_string(l.sample_type),
                       storage::to_string(l.colour_space), tessera::to_string(l.codec), human_bytes(l.payload_bytes),
                       100.0 * storage::payload_share(l.payload_bytes, t.payload_bytes));
        }
        const std::uint64_t tables = t.payload_bytes >= parts ? t.payload_bytes - parts : 0;
        fmt::print("{:>5} {:<31} {:>8} {:>4} {:>7} {:>6} {:>11} {:>5.1f}%\n", "", "(bundle tables)", "", "", "", "",
                   human_bytes(tables), 100.0 * storage::payload_share(tables, t.payload_bytes));
    }
    fmt::print("compression {:.1f}:1 (raw texels of all levels {} / file {})\n",
               t.compression_ratio, human_bytes(t.raw_bytes), human_bytes(info.file_size));
}

}  // namespace tessera::tools
