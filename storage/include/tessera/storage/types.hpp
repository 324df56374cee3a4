#pragma once
// Geometry of a tile store; its tiles are named in tessera/tile.hpp. See docs/store-format.md.
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "tessera/tile.hpp"

namespace tessera::storage {

enum class SampleType : std::uint8_t { u8 = 0, u16 = 1, f16 = 2, f32 = 3 };
enum class ColourSpace : std::uint8_t { linear = 0, srgb = 1 };

std::size_t sample_bytes(SampleType t);
std::string_view to_string(SampleType t);
std::string_view to_string(ColourSpace c);

struct LevelInfo {
    std::uint32_t width = 0;   // texels: ceil(store width / 2^level)
    std::uint32_t height = 0;
    std::uint32_t tiles_x = 0;  // ceil(width / tile_payload)
    std::uint32_t tiles_y = 0;
    // Counts recorded by the writer (verify re-derives them from the index).
    std::uint64_t present = 0;       // tiles with a payload (including deduplicated ones)
    std::uint64_t uniform = 0;       // tiles stored as one value
    std::uint64_t absent = 0;        // tiles with no data
    std::uint64_t deduplicated = 0;  // present tiles whose payload is shared with an earlier tile
    std::uint64_t payload_bytes = 0; // bytes of distinct payloads first stored in this level
    std::uint64_t payload_offset = 0; // where those bytes start in the file (a reader fills it)
    // The level's index as stored (a reader fills these; a spec leaves them 0): its block table's
    // bytes plus its entry blocks' (docs/store-format.md), and whether the block table is sparse.
    std::uint64_t index_bytes = 0;
    bool sparse_block_table = false;
};

// One layer of a multi-layer store (docs/store-format.md, "Layers"): every layer has the store's
// tile geometry and its own samples and codec.
struct LayerInfo {
    std::string name;                 // 1..31 bytes of [a-z0-9_-], unique in the store
    std::uint32_t channels = 0;       // 1..4
    SampleType sample_type = SampleType::u8;
    ColourSpace colour_space = ColourSpace::srgb;
    Codec codec = Codec::raw;         // never Codec::layers
    bool has_alpha = false;
    // Bytes of this layer's parts in the stored bundles (each distinct bundle counted once), as the
    // writer recorded it; a reader reports it without reading tiles. Not part of a spec.
    std::uint64_t payload_bytes = 0;
};

// Everything a reader needs to know about a store besides its tiles.
struct StoreInfo {
    std::uint32_t width = 0;
    std::uint32_t height = 0;
    std::uint32_t tile_payload = 0;  // P: texels per side a tile covers
    std::uint32_t border = 0;        // B: texels of neighbours stored on each side
    std::uint32_t channels = 0;      // 1..4
    SampleType sample_type = SampleType::u8;
    ColourSpace colour_space = ColourSpace::srgb;
    Codec codec = Codec::raw;
    bool has_alpha = false;          // last channel is alpha (2 or 4 channels)
    std::uint16_t version_major = 0;
    std::uint16_t version_minor = 0;
    std::uint64_t store_id = 0;      // content hash of the index: changes whenever any tile changes
    std::uint64_t file_size = 0;
    std::uint64_t data_offset = 0;  // where the payloads start, the index's end (a reader fills it)
    std::vector<LevelInfo> levels;
    // A multi-layer store's layers, in stored order; empty for a single-layer store. When present,
    // codec is Codec::layers and channels, sample_type, colour_space and has_alpha repeat layer 0's.
    std::vector<LayerInfo> layers;
    bool layered() const { return !layers.empty(); }

    std::uint32_t tile_size() const { return tile_payload + 2 * border; }  // stored texels per side
    std::size_t texel_bytes() const { return channels * sample_bytes(sample_type); }
    std::size_t tile_bytes() const { return std::size_t(tile_size()) * tile_size() * texel_bytes(); }
    std::uint32_t level_count() const { return static_cast<std::uint32_t>(levels.size()); }
    bool contains(const TileKey& k) const {
        return k.level < levels.size() && k.x < levels[k.level].tiles_x && k.y < levels[k.level].tiles_y;
    }
};

// Why `codec` cannot hold tiles with these samples and geometry; empty when it can. JPEG: 8-bit
// grey or RGB. Block codecs: 8-bit samples, bc1 RGB, bc4 one channel, bc5 two, bc7 RGB or RGBA;
// tiles a multiple of 8 texels (4x4 blocks, and the half-size level's) and borders a multiple of
// 4, so that no block straddles a tile's payload and its border.
std::string codec_misfit(Codec codec, SampleType sample_type, std::uint32_t channels, std::uint32_t tile_size,
                         std::uint32_t border);

// Level geometry shared by the writer and the reader: level L has ceil(size / 2^L) texels per side,
// and the last level is the first one that fits in a single tile.
std::vector<LevelInfo> level_geometry(std::uint32_t width, std::uint32_t height, std::uint32_t tile_payload);

}  // namespace tessera::storage
