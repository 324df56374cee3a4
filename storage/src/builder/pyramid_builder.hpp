#pragma once
// The builder's core, shared by single-layer and layered builds: a source's rows go in top to
// bottom; every level keeps only the rows its next tile row and next mip row need; each tile is
// cut (borders clamped at the image's edges), classified (absent, uniform, present), encoded on
// the pool and handed to a TileSink.
#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <optional>
#include <span>
#include <vector>

#include "mip_reducer.hpp"
#include "tessera/storage/builder.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/store_writer.hpp"
#include "thread_pool.hpp"

namespace tessera::storage::build {

// The first error any thread hit; later ones are dropped.
class FirstError {
public:
    void set(Error e);
    bool failed() const { return failed_.load(std::memory_order_relaxed); }
    Error get() const;

private:
    mutable std::mutex mu_;
    std::optional<Error> error_;
    std::atomic<bool> failed_{false};
};

// Where a pyramid's finished tiles go (a store writer, or a layered build's bundle joiner). Every
// tile of the pyramid arrives exactly once, by one of the three calls, from the pool's threads.
class TileSink {
public:
    virtual ~TileSink() = default;
    virtual Status present(const TileKey& key, std::vector<std::uint8_t> payload) = 0;
    virtual Status uniform(const TileKey& key, std::span<const std::uint8_t> value) = 0;
    virtual Status absent(const TileKey& key) = 0;
};

// A run of consecutive rows of one level, in one buffer.
struct Chunk {
    std::uint32_t first = 0;
    std::uint32_t count = 0;
    std::vector<std::uint8_t> data;
};

class PyramidBuilder {
public:
    // `store` gives the geometry, samples and codec of the tiles (a layer's, in a layered build).
    PyramidBuilder(const StoreInfo& store, const BuildOptions& opt, const EncodeOptions& enc, TileSink& sink,
                   ThreadPool& pool, FirstError& error);

    std::size_t row_bytes0() const { return levels_[0].row_bytes; }
    std::uint64_t tiles_done() const { return tiles_done_.load(std::memory_order_relaxed); }
    std::uint64_t tiles_dropped(std::size_t level) const { return dropped_[level].load(); }
    std::uint64_t bytes_dropped() const { return bytes_dropped_.load(); }

    // Rows of level l arrive top to bottom in chunks; everything a chunk makes possible is done at once.
    void push(std::uint32_t l, Chunk chunk);
    // Every row received and every tile row emitted.
    bool complete() const;

private:
    struct Level {
        std::uint32_t index = 0;
        LevelInfo geo;
        std::size_t row_bytes = 0;
        std::deque<Chunk> chunks;  // rows still needed, oldest first
        std::uint32_t received = 0;
        std::uint32_t next_tile_row = 0;
        std::uint32_t next_down_row = 0;  // next row of the level below to compute
        const std::uint8_t* row(std::uint32_t y) const;
    };

    void downsample(Level& L);
    void emit_tile_row(const Level& L, std::uint32_t ty);
    void finish_tile(const TileKey& key, const std::vector<std::uint8_t>& t);
    static bool all_equal(const std::vector<std::uint8_t>& t, std::size_t tb);
    bool alpha_all_zero(const std::vector<std::uint8_t>& t) const;

    const StoreInfo& store_;
    const BuildOptions& opt_;
    const EncodeOptions& enc_;
    TileSink& sink_;
    ThreadPool& pool_;
    FirstError& error_;
    MipReducer reducer_;
    std::vector<Level> levels_;
    std::atomic<std::uint64_t> tiles_done_{0};
    std::vector<std::atomic<std::uint64_t>> dropped_;  // per level
    std::atomic<std::uint64_t> bytes_dropped_{0};
};

// How every builder classifies a cut tile (tile_size()^2 texels): absent when a store with alpha
// has alpha 0 (+0) in every texel and the build is sparse; uniform when every texel is the same.
bool tile_alpha_all_zero(const StoreInfo& store, std::span<const std::uint8_t> tile);
bool tile_all_equal(std::span<const std::uint8_t> tile, std::size_t texel_bytes);

// The encoder settings a build's options ask for.
EncodeOptions encode_options(const BuildOptions& opt);

// The codec a source's tiles get when none is asked for: JPEG for 8-bit grey or RGB, else zstd.
Codec default_codec(const SourceInfo& source);

// The store a build of `source` with `opt` writes (geometry, samples, colour space, alpha, codec),
// checked: a codec that cannot hold the source's samples, or an invalid spec, is an error.
Result<StoreSpec> store_spec(const SourceInfo& source, const BuildOptions& opt, bool sparse_index = false);

// Streams the sources top to bottom, strip by strip and in step (strip k of every source before
// strip k+1 of any), each into its pyramid, until all rows are in or `error` is set; then waits for
// the pool. `on_strip` gets the rows read so far, summed over the sources.
void stream_sources(std::span<ImageSource* const> sources, std::span<PyramidBuilder* const> pyramids, ThreadPool& pool,
                    FirstError& error, const std::function<void(std::uint64_t rows_done)>& on_strip);

// The end of every build: the writer lays the store out (reporting bytes written through
// `progress`), the store is opened back, and the summary says what was built.
Result<BuildSummary> finish_build(StoreWriter& writer, const std::string& output, BuildProgress& prog,
                                  const BuildProgressFn& progress, std::uint64_t source_texels,
                                  std::vector<std::uint64_t> tiles_dropped, std::uint64_t bytes_dropped,
                                  std::chrono::steady_clock::time_point started);

}  // namespace tessera::storage::build
