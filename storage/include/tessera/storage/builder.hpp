#pragma once
// `tessera build`: an image source (or several, as layers) becomes a store. The source is streamed
// top to bottom in strips; every level keeps only the rows its next tile row and next mip row
// need, so memory is bounded by the image width, not its area. Tiles are encoded on all cores.
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "tessera/result.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/image_source.hpp"
#include "tessera/storage/sparse_source.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::storage {

struct BuildOptions {
    std::uint32_t tile_size = 256;       // stored texels per side: payload + 2 * border; power of two, 64..1024
    std::uint32_t border = 4;            // even
    std::optional<Codec> codec;          // default: jpeg for 8-bit grey/RGB, zstd otherwise
    int quality = 90;                    // JPEG quality 1..100
    std::optional<Chroma> chroma;        // default: 4:4:4 at quality >= 90, else 4:2:0 (as libvips)
    int zstd_level = 3;                  // 1..19
    int bc7_effort = 2;                  // 0..3: BC7 encoder search (time against quality; bc7.hpp)
    unsigned threads = 0;                // 0: all cores
    bool sparse = false;                 // tiles whose alpha is 0 everywhere are absent
    std::optional<ColourSpace> colour_space;  // default: from the source
    // Tiles for which `keep` returns false are written as absent, whatever their content (`tessera
    // build --visibility`, docs/visibility.md: level-0 tiles no camera path wants). Called from the
    // worker threads, concurrently: it must only read. Empty: every tile is kept. Dropped tiles are
    // still encoded, to report exactly what they would have cost (BuildSummary::bytes_dropped).
    std::function<bool(std::uint32_t level, std::uint32_t x, std::uint32_t y)> keep;
};

struct BuildProgress {
    std::uint64_t rows_done = 0, rows_total = 0;     // source rows consumed
    std::uint64_t tiles_done = 0, tiles_total = 0;   // tiles encoded (all levels)
    std::uint64_t bytes_written = 0, bytes_total = 0; // final layout phase
    bool writing = false;                            // true during the final layout phase
};

struct BuildSummary {
    StoreInfo info;
    std::uint64_t source_texels = 0;
    double seconds = 0;
    // BuildOptions::keep: tiles it dropped (per level), and the bytes their payloads would have
    // taken (uniform tiles cost none). Zero without `keep`.
    std::vector<std::uint64_t> tiles_dropped;  // indexed by level; empty without `keep`
    std::uint64_t bytes_dropped = 0;
};

using BuildProgressFn = std::function<void(const BuildProgress&)>;

// Sparse sources (docs/store-format.md, "Sparse stores"): a texture with data in a few regions
// only, too large to stream row by row. Only the tiles that meet the data are made and written;
// every other tile is absent, and build time, memory and the store's index follow the data.
//  - A SparseSource (tessera/storage/sparse_source.hpp), such as a mosaic manifest "FILE.json":
//    level 0 from the source, region by region, each coarser level reduced from the one below as
//    the dense builder reduces; the tiles are those a dense build with `sparse` would make.
//  - "procedural:coords-sparse:SIZE" (SIZE up to 2^24): the coords pattern
//    (tessera/storage/coords_pattern.hpp) at every level, in windows reaching 256 level texels
//    to each side of each level's four corners and its centre (RGBA8, linear, zstd unless --codec
//    says otherwise).
bool is_sparse_input(const std::string& input);
// Errors: not a sparse source, a bad size or manifest, --visibility or --sparse
// (BuildOptions::keep, sparse), a codec that does not fit the samples, those of validate(), of
// the source and of writing.
Result<BuildSummary> build_sparse_store(const std::string& input, const std::string& output, const BuildOptions& options,
                                        const BuildProgressFn& progress = {});
Result<BuildSummary> build_sparse_store(const SparseSource& source, const std::string& output, const BuildOptions& options,
                                        const BuildProgressFn& progress = {});

// Checks options on their own (before any input is opened): the message names the flag.
Status validate(const BuildOptions& options);
// invalid_argument when `output` is the file `input` names, under any name: a store replaces its
// output only when complete, so a build over its input would read it whole and then destroy it.
// The builds from paths check every input; a caller that opens its own source checks it here.
Status check_output_is_not_input(const std::string& input, const std::string& output);

// Builds `output` from `input` ("procedural:terrain:SIZE" or an image file). On any error
// nothing is left at `output` (an existing file there is untouched).
Result<BuildSummary> build_store(const std::string& input, const std::string& output, const BuildOptions& options,
                                 const BuildProgressFn& progress = {});
// Same, from a source the caller made.
Result<BuildSummary> build_store(ImageSource& source, const std::string& output, const BuildOptions& options,
                                 const BuildProgressFn& progress = {});

// The procedural terrain's relief (procedural:terrain-height:SIZE, procedural:terrain-normal:SIZE):
// a height h in [-1, 1] (stored as 0..65535) stands h * size * kTerrainReliefPerSize level-0 texels
// above the sea, so the height layer's full range spans 2 * size * kTerrainReliefPerSize texels,
// the relief its normal layer is lit for. Relative to the size, so that the terrain's slopes look
// the same at any size (its coarse octaves scale with the size).
inline constexpr float kTerrainReliefPerSize = 0.0625f;

// One layer of a multi-layer build (`tessera build --layer NAME[:CODEC]=INPUT`).
struct LayerInput {
    std::string name;            // 1..31 bytes of [a-z0-9_-], unique in the store
    std::string input;           // as for build_store: an image file or a procedural source
    std::optional<Codec> codec;  // default: jpeg for 8-bit grey/RGB, zstd otherwise
};

// Builds a multi-layer store (docs/store-format.md, "Layers"): 2 to 16 inputs of the same width
// and height, each tile one bundle of every layer's part in its layer's codec. The sources stream
// in step through one pyramid each, on one pool, and each tile's parts are joined as they are
// encoded: memory is the single-layer build's times the layer count, and nothing is written twice.
// `options` apply to every layer, except `codec` (per layer here: it must be unset) and `sparse`
// (layers with an alpha channel make absent parts; a tile absent in every layer is absent). On
// any error nothing is left at `output`; the message names the layer at fault.
Result<BuildSummary> build_layered_store(std::span<const LayerInput> layers, const std::string& output,
                                         const BuildOptions& options, const BuildProgressFn& progress = {});

// One layer given as an open source (the atlas build's layers are composed, not files).
struct LayerSource {
    std::string name;
    std::unique_ptr<ImageSource> source;
    std::optional<Codec> codec;  // default: jpeg for 8-bit grey/RGB, zstd otherwise
};
// The same over open sources; `options.codec` must be unset.
Result<BuildSummary> build_layered_store(std::vector<LayerSource> layers, const std::string& output,
                                         const BuildOptions& options, const BuildProgressFn& progress = {});

}  // namespace tessera::storage
