#pragma once
// Sparse sources (docs/store-format.md, "Sparse stores"): a texture whose data lies in a few
// rectangles of a canvas far too large to stream row by row (up to 2^32 - 1 texels per side;
// planet-scale imagery is mostly ocean or no data). The builder asks only for the present
// rectangles' tiles, so build time, memory and the store's index follow the present data, not the
// canvas's area.
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "tessera/result.hpp"
#include "tessera/storage/image_source.hpp"

namespace tessera::storage {

// A rectangle of level-0 texels: [x, x + width) x [y, y + height), inside the canvas.
struct SparseRect {
    std::uint32_t x = 0, y = 0, width = 0, height = 0;
};

class SparseSource {
public:
    virtual ~SparseSource() = default;
    // The canvas: width and height, samples, colour space. Always with alpha (the last channel):
    // texels outside every present rectangle are transparent, all zero.
    virtual const SourceInfo& info() const = 0;
    // Where the data is (rectangles may overlap); every texel outside them is all zero.
    virtual const std::vector<SparseRect>& present() const = 0;
    // Fills `dst` with the level-0 texels of `r` (inside the canvas), rows top to bottom,
    // r.width * texel bytes per row, tightly packed. Called from several threads at once, in any
    // order, any region any number of times.
    virtual Status read_region(const SparseRect& r, std::span<std::uint8_t> dst) const = 0;
};

// A mosaic manifest (docs/store-format.md, "Sparse stores"): JSON naming the canvas and the images
// placed on it, like a GDAL VRT:
//   {"width": 16777216, "height": 16777216,
//    "images": [{"path": "tile_0_0.tif", "x": 0, "y": 0}, ...]}
// Paths are relative to the manifest's directory. Images are any image open_image_source() reads,
// all with the same channels, sample type and colour space; each lies inside the canvas; a later
// image covers an earlier one where they overlap; images without alpha get alpha (opaque). Each
// image is read whole the first time a tile needs it and kept while `cache_bytes` allows.
// Errors: invalid_argument (the manifest, naming the field or image), those of the images.
Result<std::unique_ptr<SparseSource>> open_mosaic_source(const std::string& manifest_path,
                                                         std::uint64_t cache_bytes = std::uint64_t(1) << 30);

}  // namespace tessera::storage
