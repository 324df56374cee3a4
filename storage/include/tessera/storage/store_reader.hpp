#pragma once
// Reading a .tsr store. Opening reads only the header, the level table, the block tables and the
// palette (milliseconds, whatever the store size); an index block is read and verified on first
// use and kept; every tile read verifies its checksum. All reads are checked (nothing is
// memory-mapped), so a reader returns an error, never garbage and never a signal, even when its
// file is truncated or rewritten underneath it. Thread-safe: one reader serves many threads.
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "tessera/result.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::storage {

// One tile as stored: its payload (present) or its single value (uniform), never decoded.
struct Tile {
    TileKey key;
    TileKind kind = TileKind::absent;
    bool deduplicated = false;
    std::uint64_t checksum = 0;        // XXH3-64 of bytes
    std::vector<std::uint8_t> bytes;   // present: codec payload; uniform: one texel value
};

// Where a tile lives in the file, as the index says (already validated).
struct TileLocation {
    TileKind kind = TileKind::absent;
    bool deduplicated = false;
    std::uint64_t offset = 0;   // present: file offset of the payload; uniform: palette index
    std::uint32_t length = 0;   // present: payload bytes
    std::uint64_t checksum = 0;
};

struct BatchStats {
    std::uint64_t reads = 0;  // read calls issued after coalescing
    std::uint64_t bytes = 0;  // bytes read, including gaps bridged by coalescing
};

class ByteSource;

class StoreReader {
public:
    // Opens a store file. Errors: not_found, io_error, corrupt (bad header/index, truncation),
    // unsupported (newer major version).
    static Result<std::shared_ptr<StoreReader>> open(const std::string& path);
    // Same, over bytes in memory (tests, fuzzing, stores received over the network).
    static Result<std::shared_ptr<StoreReader>> open_memory(std::vector<std::uint8_t> bytes);
    // Same, over any byte source (tessera/storage/byte_source.hpp); `name` prefixes errors.
    static Result<std::shared_ptr<StoreReader>> open_source(std::unique_ptr<ByteSource> source, const std::string& name);

    virtual ~StoreReader() = default;
    virtual const StoreInfo& info() const = 0;

    // Index lookup (verifies the index block). out_of_range for keys outside the geometry.
    virtual Result<TileLocation> locate(const TileKey& key) const = 0;
    // The index groups tiles in blocks of kIndexBlockSide^2; a block whose tiles are all absent
    // costs nothing. True when block (bx, by) of `level` holds no data (or lies outside the level).
    static constexpr std::uint32_t kIndexBlockSide = 64;
    virtual bool index_block_empty(std::uint32_t level, std::uint32_t bx, std::uint32_t by) const = 0;
    // The blocks of `level` that are not empty, as (bx, by), row by row: what a walk over every
    // tile with data visits, without a step for each empty block (a sparse store's level may
    // have 2^50 blocks). Empty for a level out of range.
    virtual std::vector<std::pair<std::uint32_t, std::uint32_t>> data_blocks(std::uint32_t level) const = 0;
    // One tile, checksum verified. An absent tile is a success with kind == absent.
    virtual Result<Tile> read_tile(const TileKey& key) const = 0;
    // Many tiles; payloads adjacent (or nearly) in the file are fetched with one read.
    // Results are in the order of keys; each one fails or succeeds on its own.
    virtual std::vector<Result<Tile>> read_tiles(std::span<const TileKey> keys,
                                                 BatchStats* stats = nullptr) const = 0;
    // True when the file was changed since it was opened (size or modification time): reads that
    // fail now may be the file's fault, not the store's. One fstat; false for stores in memory.
    virtual bool file_changed() const = 0;
    // Cancels the reads of a source that waits on a network (ByteSource::cancel): reads in
    // progress fail at once, later ones too. For a server that is stopping.
    virtual void cancel_reads() const = 0;
    // The content hash of the index as the file holds it now (every byte between the header and
    // the data section), computed the way the writer computes StoreInfo::store_id: equal to it
    // unless the index was changed after the store was written. Reads the whole index.
    virtual Result<std::uint64_t> index_hash() const = 0;
    // The uniform value at a palette index (texel_bytes() bytes).
    virtual Result<std::vector<std::uint8_t>> palette_value(std::uint64_t index) const = 0;

    // Gaps up to this many bytes between two wanted payloads are read through, not split.
    static constexpr std::uint64_t kCoalesceGapBytes = 16 * 1024;
    // A coalesced read never grows beyond this.
    static constexpr std::uint64_t kMaxCoalescedBytes = 4 * 1024 * 1024;
};

}  // namespace tessera::storage
