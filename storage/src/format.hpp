#pragma once
// The on-disk layout of a .tsr store, version 1.0, and 1.1 for multi-layer stores.
// docs/store-format.md is the normative text; this file is its C++ transcription. Everything is
// little-endian.
#include <array>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>

#include "tessera/storage/types.hpp"

namespace tessera::storage::format {

static_assert(std::endian::native == std::endian::little, "the store format is little-endian");

inline constexpr std::array<std::uint8_t, 8> kMagic = {'T', 'E', 'S', 'S', 'T', 'S', 'R', 0x1a};
inline constexpr std::uint16_t kVersionMajor = 1;
inline constexpr std::uint16_t kVersionMinor = 0;         // a single-layer store
inline constexpr std::uint16_t kVersionMinorLayers = 1;   // a multi-layer store (codec 7, a layer table)
inline constexpr std::uint16_t kVersionMinorSparseIndex = 2;  // a single-layer store whose block tables list
                                                              // only its non-empty blocks (kHeaderFlagSparseIndex)
inline constexpr std::uint16_t kVersionMinorNewest = kVersionMinorSparseIndex;
inline constexpr std::size_t kHeaderBytes = 128;
inline constexpr std::size_t kLevelRecordBytes = 96;
inline constexpr std::size_t kBlockRecordBytes = 16;
inline constexpr std::size_t kSparseBlockRecordBytes = 24;  // u32 bx, u32 by, then a block record
inline constexpr std::size_t kEntryBytes = 24;
inline constexpr std::size_t kPaletteValueBytes = 16;
inline constexpr std::size_t kLayerRecordBytes = 64;
inline constexpr std::uint32_t kBlockShift = 6;  // index blocks cover 64 x 64 tiles
inline constexpr std::uint32_t kBlockSide = 1u << kBlockShift;
inline constexpr std::size_t kEntriesPerBlock = std::size_t(kBlockSide) * kBlockSide;
inline constexpr std::size_t kEntryBlockBytes = kEntriesPerBlock * kEntryBytes;
inline constexpr std::uint32_t kMaxLevels = 32;
inline constexpr std::uint32_t kMaxTileSize = 4096;
// The most block-table bytes (all levels) a reader holds in memory from open: a block record
// stands for 64 x 64 tiles, so this covers a dense level of ~2.7e11 tiles, while a crafted or
// lying header (a remote origin may report any size) cannot make a reader allocate more.
inline constexpr std::uint64_t kMaxBlockTableBytes = std::uint64_t(1) << 30;
// The most distinct uniform values (palette entries) a store holds.
inline constexpr std::uint32_t kMaxPaletteValues = std::uint32_t(1) << 24;

inline constexpr std::uint8_t kHeaderFlagAlpha = 1;
inline constexpr std::uint8_t kHeaderFlagSparseIndex = 2;
inline constexpr std::uint8_t kEntryFlagDeduplicated = 1;

// Little-endian field access at a byte offset.
template <class T>
inline T load(const std::uint8_t* p, std::size_t off) {
    T v;
    std::memcpy(&v, p + off, sizeof(T));
    return v;
}
template <class T>
inline void store(std::uint8_t* p, std::size_t off, T v) {
    std::memcpy(p + off, &v, sizeof(T));
}

// Header field offsets.
namespace header {
inline constexpr std::size_t magic = 0;
inline constexpr std::size_t version_major = 8;     // u16
inline constexpr std::size_t version_minor = 10;    // u16
inline constexpr std::size_t header_bytes = 12;     // u32
inline constexpr std::size_t width = 16;            // u32
inline constexpr std::size_t height = 20;           // u32
inline constexpr std::size_t tile_payload = 24;     // u32
inline constexpr std::size_t border = 28;           // u16
inline constexpr std::size_t level_count = 30;      // u8
inline constexpr std::size_t channels = 31;         // u8
inline constexpr std::size_t sample_type = 32;      // u8
inline constexpr std::size_t colour_space = 33;     // u8
inline constexpr std::size_t codec = 34;            // u8
inline constexpr std::size_t flags = 35;            // u8
inline constexpr std::size_t block_shift = 36;      // u8
inline constexpr std::size_t layer_count = 37;      // u8: 2..16 in a layered store, else 0
inline constexpr std::size_t level_table_offset = 40;   // u64
inline constexpr std::size_t level_table_bytes = 48;    // u32
inline constexpr std::size_t palette_count = 52;        // u32
inline constexpr std::size_t palette_offset = 56;       // u64
inline constexpr std::size_t index_offset = 64;         // u64
inline constexpr std::size_t data_offset = 72;          // u64
inline constexpr std::size_t file_size = 80;            // u64
inline constexpr std::size_t store_id = 88;             // u64
inline constexpr std::size_t level_table_checksum = 96; // u64
inline constexpr std::size_t palette_checksum = 104;    // u64
inline constexpr std::size_t layer_table_checksum = 112; // u64: layered stores; 0 otherwise
inline constexpr std::size_t header_checksum = 120;     // u64, XXH3-64 of bytes [0, 120)
}  // namespace header

// Level record field offsets (one record per level, level 0 first).
namespace level {
inline constexpr std::size_t width = 0;                 // u32
inline constexpr std::size_t height = 4;                // u32
inline constexpr std::size_t tiles_x = 8;               // u32
inline constexpr std::size_t tiles_y = 12;              // u32
inline constexpr std::size_t blocks_x = 16;             // u32
inline constexpr std::size_t blocks_y = 20;             // u32
inline constexpr std::size_t block_table_offset = 24;   // u64
inline constexpr std::size_t block_table_checksum = 32; // u64
inline constexpr std::size_t data_offset = 40;          // u64
inline constexpr std::size_t data_bytes = 48;           // u64
inline constexpr std::size_t present = 56;              // u64
inline constexpr std::size_t uniform = 64;              // u64
inline constexpr std::size_t absent = 72;               // u64
inline constexpr std::size_t deduplicated = 80;         // u64
inline constexpr std::size_t block_records = 88;        // u64: sparse index: records in the block table; else 0
}  // namespace level

// Layer record field offsets (a layered store: one record per layer, directly after the level
// table).
namespace layer {
inline constexpr std::size_t name = 0;           // u8[32]: 1..31 bytes of [a-z0-9_-], NUL padded
inline constexpr std::size_t name_bytes = 32;
inline constexpr std::size_t channels = 32;      // u8
inline constexpr std::size_t sample_type = 33;   // u8
inline constexpr std::size_t colour_space = 34;  // u8
inline constexpr std::size_t codec = 35;         // u8: never 7
inline constexpr std::size_t flags = 36;         // u8: bit 0 alpha
inline constexpr std::size_t payload_bytes = 40; // u64: this layer's bytes in the stored bundles
}  // namespace layer

// Index entry field offsets.
namespace entry {
inline constexpr std::size_t offset = 0;     // u64: payload file offset, or palette index (uniform)
inline constexpr std::size_t length = 8;     // u32: payload bytes (present only)
inline constexpr std::size_t kind = 12;      // u8: TileKind
inline constexpr std::size_t flags = 13;     // u8: bit 0 deduplicated (present tiles only)
inline constexpr std::size_t reserved = 14;  // u16: 0
inline constexpr std::size_t checksum = 16;  // u64: XXH3-64 of the payload or of the uniform value
}  // namespace entry

inline std::uint32_t ceil_div(std::uint32_t a, std::uint32_t b) { return (a + b - 1) / b; }

// Morton (Z-order) code of a tile within a level: the order of payloads inside a level.
inline std::uint64_t morton(std::uint32_t x, std::uint32_t y) {
    auto spread = [](std::uint64_t v) {
        v &= 0xffffffffull;
        v = (v | (v << 16)) & 0x0000ffff0000ffffull;
        v = (v | (v << 8)) & 0x00ff00ff00ff00ffull;
        v = (v | (v << 4)) & 0x0f0f0f0f0f0f0f0full;
        v = (v | (v << 2)) & 0x3333333333333333ull;
        v = (v | (v << 1)) & 0x5555555555555555ull;
        return v;
    };
    return spread(x) | (spread(y) << 1);
}

}  // namespace tessera::storage::format
