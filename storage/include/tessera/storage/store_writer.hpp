#pragma once
// Writing a .tsr store. Tiles may be added in any order from many threads; payloads are spooled
// to a temporary file beside the output, and finish() lays the store out (coarse levels first,
// Morton order within a level, identical payloads stored once), writes it to a temporary file and
// renames it into place. Until finish() succeeds nothing exists at the output path, and a writer
// destroyed without finish() removes its temporary files.
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "tessera/result.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::storage {

// Geometry and encoding of the store to write (StoreInfo's descriptive fields; levels and
// counts are derived).
struct StoreSpec {
    std::uint32_t width = 0;
    std::uint32_t height = 0;
    std::uint32_t tile_payload = 0;
    std::uint32_t border = 0;
    std::uint32_t channels = 0;
    SampleType sample_type = SampleType::u8;
    ColourSpace colour_space = ColourSpace::srgb;
    Codec codec = Codec::raw;
    bool has_alpha = false;
    // A multi-layer store (docs/store-format.md, "Layers"): 2 to 16 layers, codec Codec::layers,
    // and channels .. has_alpha repeating layer 0's, as in StoreInfo. Empty: a single-layer store.
    std::vector<LayerInfo> layers;
    // A sparse index (format 1.2, docs/store-format.md "Sparse stores"): block tables list only
    // the non-empty blocks. For stores whose tiles are mostly absent (sparse sources); a reader
    // older than format 1.2 cannot read it. Single-layer stores only.
    bool sparse_index = false;
};

// Checks a spec against the format's limits; the message names the offending field.
Status validate(const StoreSpec& spec);

// The StoreInfo a store written from `spec` will have (levels from the geometry, no counts yet).
StoreInfo store_info(const StoreSpec& spec);

class StoreWriter {
public:
    using Progress = std::function<void(std::uint64_t done_bytes, std::uint64_t total_bytes)>;

    // Creates the temporary files next to `path` at once, so an unwritable destination fails
    // before any work is done.
    static Result<std::unique_ptr<StoreWriter>> create(const std::string& path, const StoreSpec& spec);

    virtual ~StoreWriter() = default;
    // A tile with a payload in the store's codec. Thread-safe. In a layered store the payload is a
    // bundle (join_layers, tessera/storage/layers.hpp) that must split into the spec's layers and
    // hold at least one layer that is not absent (a tile with no layer's data is absent: not added).
    virtual Status add_present(const TileKey& key, std::span<const std::uint8_t> payload) = 0;
    // A tile whose every texel (border included) equals `value` (texel_bytes() bytes). Thread-safe.
    // Refused in a layered store: its uniform layers are uniform parts of a bundle.
    virtual Status add_uniform(const TileKey& key, std::span<const std::uint8_t> value) = 0;
    // Tiles never added are absent. Writes, syncs and renames into place.
    virtual Status finish(const Progress& progress = {}) = 0;
};

}  // namespace tessera::storage
