#pragma once
// The C entry points of the OpenImageIO plugin module (libtessera_oiio.so). Both sides are built
// from this tree by the same compiler, so C++ types cross the boundary by pointer.
#include <string>

#include "tessera/storage/image_source.hpp"

namespace tessera::storage {
struct ImageWriteRequest {
    const std::string* path;           // output file; the format follows the extension; errors name it
    const std::string* temp_path;      // where the bytes go: a temporary file beside `path`, open as temp_fd
    int temp_fd;
    ImageSource* source;               // rows to write, top to bottom
    const ParallelFor* parallel;
    void (*progress)(void* ctx, std::uint32_t rows_done);
    void* progress_ctx;
};
}  // namespace tessera::storage

extern "C" {
// Returns a new source, or nullptr with *code (an Errc value) and *error set.
using tessera_oiio_open_fn = tessera::storage::ImageSource* (*)(const char* path, int* code, std::string* error);
// Writes the source to a file; returns false with *error set.
using tessera_oiio_write_fn = bool (*)(const tessera::storage::ImageWriteRequest* request, std::string* error);
}
