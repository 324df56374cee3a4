#pragma once
// Many images packed into one: the image side of `tessera build --atlas` (the OBJ side is
// tessera/scene/atlas.hpp). The atlas is one more ImageSource, read top to bottom in strips like any
// other, so a build never holds more than the strips of the images the current rows cross.
//
// Layout (docs/atlas.md): every image gets a cell of (image + 2 x padding) texels rounded up to a
// multiple of `alignment` (a power of two), at a position that is a multiple of `alignment`; the
// image sits `padding` texels in from the cell's top-left corner and the rest of the cell repeats its
// edge texels (edge clamp) or, for a repeating texture, continues it around its edges (wrap). So up to level log2(alignment) no mip texel mixes two cells, and up to
// level log2(padding) a bilinear tap beside an image reads that image's own edge. Cells are packed
// on shelves (tallest first) into the width that gives the smallest atlas among a few candidates;
// texels no cell covers are black. Deterministic: the same sizes give the same layout.
#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "tessera/result.hpp"
#include "tessera/storage/image_source.hpp"

namespace tessera::storage {

struct AtlasPackOptions {
    std::uint32_t alignment = 64;  // power of two, 1..4096
    std::uint32_t padding = 16;    // texels of edge replication on each side, at least; <= 4096
};

struct AtlasImageSize {
    std::uint32_t width = 0, height = 0;
};

struct AtlasCell {
    std::uint32_t x = 0, y = 0;           // the image's top-left texel in the atlas
    std::uint32_t width = 0, height = 0;  // the image's size
    std::uint32_t cell_x = 0, cell_y = 0, cell_width = 0, cell_height = 0;  // its aligned cell
};

struct AtlasLayout {
    std::uint32_t width = 0, height = 0;
    std::vector<AtlasCell> cells;  // one per image, in the order given
};

// The largest atlas side pack_atlas makes (texels).
inline constexpr std::uint32_t kMaxAtlasSide = std::uint32_t(1) << 24;

// Errors: no images, an image of zero size, bad options, an atlas beyond kMaxAtlasSide.
Result<AtlasLayout> pack_atlas(std::span<const AtlasImageSize> sizes, const AtlasPackOptions& options = {});

// One image of the atlas: a source (any sample type and 1..4 channels; grey is replicated, 16-bit
// and float samples are scaled to 8 bits, linear colour encoded as sRGB, alpha kept as it is,
// straight), or a solid colour when `source` is null. `wrap`: a repeating texture, whose padding continues the
// image around its edges (toroidally) instead of repeating its edge texels; it is read whole when
// the atlas rows reach its cell, not strip by strip.
struct AtlasItem {
    std::unique_ptr<ImageSource> source;
    std::array<std::uint8_t, 3> colour{};
    bool wrap = false;
    bool opaque = false;  // its alpha is ignored (a glTF material whose alphaMode is OPAQUE)
};

// The atlas as an 8-bit sRGB source, RGB, or RGBA with straight alpha when any item's source has
// alpha (cut-outs; the other images and the texels no cell covers are opaque): items[i] fills
// layout.cells[i] (a source must have that cell's image size). Each item's source is read once, top to bottom, as the atlas rows reach it.
//
// AtlasTexels::data is for maps whose values are not colours (normal, metallic-roughness and
// occlusion maps): every value is kept as it is (8-bit samples copied, others scaled to 8 bits,
// never sRGB-encoded, whatever colour space the source declares), alpha is dropped, and the atlas
// is RGB declared linear; a solid item's colour is written as given.
enum class AtlasTexels { colour, data };
Result<std::unique_ptr<ImageSource>> make_atlas_source(std::vector<AtlasItem> items, AtlasLayout layout,
                                                       AtlasTexels texels = AtlasTexels::colour);

// `source` resampled to width x height (a map of another size than the colour texture whose cell it
// shares): on each axis, the mean of the texels an output texel covers when shrinking, bilinear
// when growing, edges clamped. Samples become 32-bit floats in the source's colour space, with its
// channels and alpha. The source is read whole on the first read (at most 2^24 texels, both sizes).
Result<std::unique_ptr<ImageSource>> make_resized_source(std::unique_ptr<ImageSource> source, std::uint32_t width,
                                                         std::uint32_t height);

}  // namespace tessera::storage
