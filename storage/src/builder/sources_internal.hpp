#pragma once
// Image sources behind open_image_source(): TIFF through libtiff, binary PGM/PPM by hand, everything else through the
// OpenImageIO plugin (a separate module, loaded on first use: Debian's OpenImageIO pulls in ~260
// shared libraries and ~100 MiB of resident memory, which no store that does not need it should pay).
#include <cstdint>
#include <memory>
#include <string>

#include "tessera/storage/image_source.hpp"

namespace tessera::storage {

bool looks_like_tiff(const std::string& path);
// unsupported: a TIFF layout this reader leaves to OpenImageIO.
Result<std::unique_ptr<ImageSource>> open_tiff_source(const std::string& path);

// Binary PGM and PPM (P5, P6), 8 or 16 bits, exactly as stored.
bool looks_like_binary_pnm(const std::string& path);
Result<std::unique_ptr<ImageSource>> open_pnm_source(const std::string& path);

// Through the OpenImageIO plugin (loaded on demand).
Result<std::unique_ptr<ImageSource>> open_oiio_source(const std::string& path);

// `stored` as it is meant to be seen: its info().orientation (EXIF/TIFF, 2..8) undone; orientation 1
// is returned as is. A turn (3..8) holds the stored image whole while its strips are read; the
// images held so, in the whole process, may take set_turned_image_budget() bytes together (2 GiB
// by default). Each source takes its share at its first read and gives it back once its last
// strip is read or it is destroyed; one larger than the whole budget is refused when opened.
// Errors (unsupported) name the input when its turn would not fit.
Result<std::unique_ptr<ImageSource>> make_upright_source(std::unique_ptr<ImageSource> stored);
// Sets the bytes the turned images held at once may take together; returns the previous limit.
std::uint64_t set_turned_image_budget(std::uint64_t bytes);

}  // namespace tessera::storage
