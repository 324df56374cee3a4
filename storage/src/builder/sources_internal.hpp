#pragma once
// Image sources behind open_image_source(): TIFF through libtiff, everything else through the
// OpenImageIO plugin (a separate module, loaded on first use: Debian's OpenImageIO pulls in ~260
// shared libraries and ~100 MiB of resident memory, which no store that does not need it should pay).
#include <memory>
#include <string>

#include "tessera/storage/image_source.hpp"

namespace tessera::storage {

bool looks_like_tiff(const std::string& path);
// unsupported: a TIFF layout this reader leaves to OpenImageIO.
Result<std::unique_ptr<ImageSource>> open_tiff_source(const std::string& path);

// Through the OpenImageIO plugin (loaded on demand).
Result<std::unique_ptr<ImageSource>> open_oiio_source(const std::string& path);

// `stored` as it is meant to be seen: its info().orientation (EXIF/TIFF, 2..8) undone; orientation 1
// is returned as is. Errors name the input when a turn would not fit in memory.
Result<std::unique_ptr<ImageSource>> make_upright_source(std::unique_ptr<ImageSource> stored);

}  // namespace tessera::storage
