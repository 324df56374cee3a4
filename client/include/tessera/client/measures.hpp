#pragma once
// Measures of rendered frames, GL-free (docs/viewer.md, "Measures"): a store's levels decoded as a
// GPU samples them (for the reference renderers), PSNR and max error between two frames, and
// popping between consecutive frames.
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "tessera/client/page.hpp"
#include "tessera/result.hpp"

namespace tessera::client {

// One level of an image: RGBA8 texels, rows top to bottom.
struct ImageLevel {
    std::uint32_t width = 0, height = 0;
    std::vector<std::uint8_t> rgba8;
};

// Decodes every tile interior of a store into RGBA8 levels (for the reference renderers). Errors: a
// store too large (level 0 over max_side texels per side), unreadable or undecodable tiles.
// Absent tiles (sparse stores) decode as transparent black. `format` (rgba8 or a block format):
// each tile as a page of that format holds it, block formats decoded back as a GPU samples them
// (the same texels as a VtRenderer atlas of that format, which reads bc4 as (r, r, r, 1) and bc5
// as (r, r, r, g)). `layer`: which layer of a multi-layer store (0 for any other store).
Result<std::vector<ImageLevel>> decode_store_levels(const std::string& store_path, std::uint32_t max_side = 16384,
                                                                  PageFormat format = PageFormat::rgba8, std::uint32_t layer = 0);
// The second level a block-format atlas holds under each page (the page's 2x2 means encoded
// again, or a block-codec store's stored blocks of it), decoded as a GPU samples them and laid out
// as a level: one per store level but the last, each the size of the next level. Errors: those of
// decode_store_levels; a format that is not a block format, tiles not a multiple of 8 texels.
Result<std::vector<ImageLevel>> decode_store_second_levels(const std::string& store_path, std::uint32_t max_side,
                                                                         PageFormat format, std::uint32_t layer = 0);

// PSNR (dB, over RGB, 8-bit) and max absolute error of two RGBA8 images of equal size, over the
// pixels where `mask` (optional: width*height bytes, one per pixel, non-zero = count) is set.
// PSNR is +inf when equal (MSE over the counted pixels' R, G and B).
struct ImageError {
    double psnr = 0;
    int max_error = 0;
    std::uint64_t pixels = 0;
};
// Images of the wrong size compare as maximally different (psnr 0, max_error 255, pixels 0).
ImageError compare_images(std::span<const std::uint8_t> a, std::span<const std::uint8_t> b, std::uint32_t width,
                          std::uint32_t height, std::span<const std::uint8_t> mask = {});

// Popping between two consecutive frames (docs/viewer.md, "Measures"): a pixel pops when its change
// from `before` to `after` differs from the reference renderer's change over the same two camera
// poses (`ref_before`, `ref_after`) by more than `threshold` in R, G or B, i.e. a change that the
// camera's motion does not explain (a page arriving or leaving, a LoD bias step). Counted over the
// pixels the reference covers in both frames (alpha non-zero); `largest`: the largest such
// difference among them, popping or not. Images of the wrong size count nothing.
struct PopCount {
    std::uint64_t pixels = 0;  // covered in both reference frames
    std::uint64_t popped = 0;
    int largest = 0;
    double rate() const { return pixels ? double(popped) / double(pixels) : 0.0; }
};
PopCount count_pops(std::span<const std::uint8_t> before, std::span<const std::uint8_t> after, std::span<const std::uint8_t> ref_before,
                    std::span<const std::uint8_t> ref_after, std::uint32_t width, std::uint32_t height, int threshold = 16);

}  // namespace tessera::client
