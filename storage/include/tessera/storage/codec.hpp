#pragma once
// Tile payload codecs: JPEG (libjpeg-turbo), zstd, raw and GPU blocks (bc1, bc4, bc5, bc7). A decoded tile is always the full
// stored tile, (P + 2B)^2 texels, row-major, channels interleaved, samples little-endian.
#include <cstdint>
#include <span>
#include <vector>

#include "tessera/result.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::storage {

enum class Chroma : std::uint8_t { s420, s444 };

struct EncodeOptions {
    int jpeg_quality = 90;        // 1..100
    Chroma chroma = Chroma::s444;
    int zstd_level = 3;
    int bc7_effort = 2;  // 0..3, the BC7 encoder's search effort (tessera/blocks/bc7.hpp)
};

// Encodes one tile's texels (tile_bytes() bytes) in the store's codec. Thread-safe.
Result<std::vector<std::uint8_t>> encode_tile(const StoreInfo& info, std::span<const std::uint8_t> texels,
                                              const EncodeOptions& options);

// A block-codec tile's payload unpacked (zstd) into `out`: the tile's 4x4 blocks, then its
// half-size level's blocks, as a GPU takes them (tessera/blocks/blocks.hpp). Thread-safe.
Status unpack_block_tile(const StoreInfo& info, std::span<const std::uint8_t> payload, std::vector<std::uint8_t>& out);

// The one JPEG tile decoder (the server's web images, `verify --decode`, the client's transcode
// threads): a JPEG tile of `info` (8-bit samples, 1 or 3 channels, tile_size() texels a side)
// into `out`, which holds exactly one tile: in the store's own channels (tile_bytes()), or, with
// `rgba`, as RGBA8 with alpha 255 and grey expanded to (v, v, v). Accurate IDCT. Each thread
// keeps one libjpeg-turbo handle, renewed after any failure. Thread-safe.
Status decode_jpeg_tile(const StoreInfo& info, std::span<const std::uint8_t> payload, std::span<std::uint8_t> out,
                        bool rgba = false);

// A zstd tile decompressed into `out` (exactly tile_bytes()), with one context per thread.
// Thread-safe.
Status decompress_zstd_tile(const StoreInfo& info, std::span<const std::uint8_t> payload, std::span<std::uint8_t> out);

// Decodes a present or uniform tile into `out` (resized to tile_bytes()). An absent tile is an
// error (not_found); a payload that does not decode to exactly one tile is corrupt. Thread-safe.
Status decode_tile(const StoreInfo& info, const Tile& tile, std::vector<std::uint8_t>& out);

}  // namespace tessera::storage
