#pragma once
// A store described as JSON: the one set of fields the HTTP API (GET /v1/stores, /v1/stores/{name})
// and `tessera inspect --json` both answer with (docs/protocol.md, "HTTP"). In its own library,
// tessera::storage_json, so that only those two link nlohmann-json through it.
#include <cstdint>
#include <string_view>

#include <nlohmann/json.hpp>

#include "tessera/storage/types.hpp"

namespace tessera::storage {

// Sums over all levels.
struct StoreTotals {
    std::uint64_t tiles = 0, present = 0, uniform = 0, absent = 0, deduplicated = 0;
    std::uint64_t payload_bytes = 0;
    std::uint64_t index_bytes = 0;   // block tables and entry blocks (as a reader reports them)
    std::uint64_t texels = 0;
    std::uint64_t raw_bytes = 0;     // the texels uncompressed, borders left out
    double compression_ratio = 0.0;  // raw_bytes / the file's size; 0 for an empty file
};
StoreTotals store_totals(const StoreInfo& info);

// Payload bits per texel; 0 for no texels.
double bits_per_texel(std::uint64_t bytes, std::uint64_t texels);

// A layer's share of a store's payload bytes (the rest of a layered store's payload is the bundles'
// tables of 8 bytes per layer); 0 for an empty store.
double payload_share(std::uint64_t bytes, std::uint64_t total);

// name, version (the store id in hex: what the server calls the store's version), format_version,
// file_size, the image (width, height, channels, sample_type, colour_space, has_alpha, codec), the
// tiles (tile_size, tile_payload, border), levels (the count), level_info (per level: geometry,
// tile counts, payload_bytes, bits_per_texel), layers (a multi-layer store's: name, channels,
// sample_type, colour_space, has_alpha, codec, payload_bytes, payload_share; empty otherwise) and
// totals (the same summed, raw_bytes of every layer and compression_ratio).
nlohmann::json store_json(std::string_view name, const StoreInfo& info);

}  // namespace tessera::storage
