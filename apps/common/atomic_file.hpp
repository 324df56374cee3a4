#pragma once
// Output files the tools write whole or not at all: the content goes to a hidden temporary file
// beside the target, which is renamed over it only once every byte is written. A failure removes
// the temporary file and throws Failure naming the path, so a reader never sees half a file.
#include <functional>
#include <ostream>
#include <string>

namespace tessera::tools {

void write_file_atomically(const std::string& path, const std::function<void(std::ostream&)>& write);

}  // namespace tessera::tools
