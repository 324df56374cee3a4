#pragma once
// Every output file is written beside its path under a temporary name and renamed into place, and
// a rename replaces whatever sits at the path. So only a regular file (or nothing) may be there:
// renaming over /dev/null, a FIFO or a symbolic link would destroy it rather than write to it.
#include <string>

#include "tessera/result.hpp"

namespace tessera::storage {

// invalid_argument when `path` exists and is not a regular file: a directory, a device, a FIFO, a
// socket, or a symbolic link (not followed; the message says to name the file itself). Nothing
// there yet, or a parent that is missing (the write reports it), passes.
Status check_output_file(const std::string& path);

}  // namespace tessera::storage
