#pragma once
// Where a build's texels come from: an image file (anything OpenImageIO reads), the procedural
// demo terrain, or an application's own implementation. Sources are read top to bottom in strips,
// so no image ever has to be in memory whole.
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "tessera/result.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::storage {

struct SourceInfo {
    std::uint32_t width = 0;
    std::uint32_t height = 0;
    std::uint32_t channels = 0;  // 1..4
    SampleType sample_type = SampleType::u8;
    ColourSpace colour_space = ColourSpace::srgb;
    bool has_alpha = false;      // last channel is alpha
    // The file's EXIF/TIFF orientation (1..8, 1 = stored upright). open_image_source() returns
    // upright sources, so outside the readers this is always 1.
    std::uint32_t orientation = 1;
    std::string description;     // for messages: file name and format
};

// Splits [0, n) into chunks and runs them on the build's threads.
using ParallelFor = std::function<void(std::size_t n, const std::function<void(std::size_t, std::size_t)>& fn)>;

class ImageSource {
public:
    virtual ~ImageSource() = default;
    virtual const SourceInfo& info() const = 0;
    // Fills rows [y0, y0 + count): width * channels samples per row, tightly packed, native
    // sample type. Strips are requested in order, top to bottom, each exactly once.
    virtual Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const ParallelFor& parallel) = 0;
};

// "procedural:terrain:SIZE" or a path to an image file. Errors name the input.
Result<std::unique_ptr<ImageSource>> open_image_source(const std::string& spec);

// Writes `source` to an image file whose format follows the extension (.tif, .png, .exr ...),
// strip by strip, through OpenImageIO. `progress` gets the rows written so far. The file is
// written beside `path` under a temporary name, synced and renamed into place only when whole: on
// any error (a full disk among them) nothing is left at `path` or beside it.
Status write_image(const std::string& path, ImageSource& source, const ParallelFor& parallel,
                   const std::function<void(std::uint32_t rows_done)>& progress = {});

// The largest procedural size (texels per side).
inline constexpr std::uint64_t kMaxProceduralSize = std::uint64_t(1) << 24;

}  // namespace tessera::storage
