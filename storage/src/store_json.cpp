#include "tessera/storage/store_json.hpp"

#include <string>

#include "tessera/hex.hpp"

namespace tessera::storage {

StoreTotals store_totals(const StoreInfo& info) {
    StoreTotals t;
    // A layered store's texels hold every layer's samples.
    std::uint64_t texel_bytes = info.texel_bytes();
    if (info.layered()) {
        texel_bytes = 0;
        for (const LayerInfo& l : info.layers) texel_bytes += l.channels * sample_bytes(l.sample_type);
    }
    for (const auto& l : info.levels) {
        const std::uint64_t texels = std::uint64_t(l.width) * l.height;
        t.tiles += std::uint64_t(l.tiles_x) * l.tiles_y;
        t.present += l.present;
        t.uniform += l.uniform;
        t.absent += l.absent;
        t.deduplicated += l.deduplicated;
        t.payload_bytes += l.payload_bytes;
        t.index_bytes += l.index_bytes;
        t.texels += texels;
        t.raw_bytes += texels * texel_bytes;
    }
    t.compression_ratio = info.file_size ? double(t.raw_bytes) / double(info.file_size) : 0.0;
    return t;
}

double bits_per_texel(std::uint64_t bytes, std::uint64_t texels) {
    return texels ? 8.0 * double(bytes) / double(texels) : 0.0;
}

double payload_share(std::uint64_t bytes, std::uint64_t total) { return total ? double(bytes) / double(total) : 0.0; }

nlohmann::json store_json(std::string_view name, const StoreInfo& info) {
    nlohmann::json levels = nlohmann::json::array();
    for (std::size_t i = 0; i < info.levels.size(); ++i) {
        const LevelInfo& l = info.levels[i];
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
                          {"bits_per_texel", bits_per_texel(l.payload_bytes, std::uint64_t(l.width) * l.height)},
                          {"index_bytes", l.index_bytes},
                          {"block_table", l.sparse_block_table ? "sparse" : "dense"}});
    }
    const StoreTotals t = store_totals(info);
    nlohmann::json layers = nlohmann::json::array();
    for (const LayerInfo& l : info.layers)
        layers.push_back({{"name", l.name},
                          {"channels", l.channels},
                          {"sample_type", to_string(l.sample_type)},
                          {"colour_space", to_string(l.colour_space)},
                          {"has_alpha", l.has_alpha},
                          {"codec", to_string(l.codec)},
                          {"payload_bytes", l.payload_bytes},
                          {"payload_share", payload_share(l.payload_bytes, t.payload_bytes)}});
    return {
        {"name", name},
        {"version", hex16(info.store_id)},
        {"format_version", std::to_string(info.version_major) + "." + std::to_string(info.version_minor)},
        {"file_size", info.file_size},
        {"width", info.width},
        {"height", info.height},
        {"channels", info.channels},
        {"sample_type", to_string(info.sample_type)},
        {"colour_space", to_string(info.colour_space)},
        {"has_alpha", info.has_alpha},
        {"codec", to_string(info.codec)},
        {"tile_size", info.tile_size()},
        {"tile_payload", info.tile_payload},
        {"border", info.border},
        {"levels", info.level_count()},
        {"level_info", std::move(levels)},
        {"layers", std::move(layers)},
        {"totals",
         {{"tiles", t.tiles},
          {"present", t.present},
          {"uniform", t.uniform},
          {"absent", t.absent},
          {"deduplicated", t.deduplicated},
          {"payload_bytes", t.payload_bytes},
          {"index_bytes", t.index_bytes},
          {"raw_bytes", t.raw_bytes},
          {"bits_per_texel", bits_per_texel(t.payload_bytes, t.texels)},
          {"compression_ratio", t.compression_ratio}}},
    };
}

}  // namespace tessera::storage
