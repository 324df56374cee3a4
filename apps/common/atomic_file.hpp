#pragma once
// Output files the tools write whole or not at all: the content goes to a hidden temporary file
// beside the target, which is renamed over it only once every byte is written. A failure removes
// the temporary file and throws Failure naming the path, so a reader never sees half a file.
#include <functional>
#include <ostream>
#include <string>

namespace tessera::tools {

void write_file_atomically(const std::string& path, const std::function<void(std::ostream&)>& write);

// Throws the Failure write_file_atomically would throw for `path` for want of a place to write
// (no such directory, no permission, not a regular file), by creating and removing its
// temporary file: a long run checks its outputs before it starts, not after.
void check_writable(const std::string& path);

}  // namespace tessera::tools
