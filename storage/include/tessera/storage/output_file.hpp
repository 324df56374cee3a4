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

// The name every temporary file or folder of `final_path` gets: beside it, hidden, tagged, and
// unique in the process (".NAME.TAG-PID-N"), so two writers of one path never meet. Only a name:
// the caller tracks it (below) and creates it.
std::string temp_path_beside(const std::string& final_path, const std::string& tag);

// Temporary files and folders being written, process-wide, so that a command interrupted by a
// signal can remove them before it dies (tools/interrupt.cpp). Track a path before creating it;
// untrack it once it is renamed into place or removed.
void track_temp_path(const std::string& path);
void untrack_temp_path(const std::string& path);
// Removes every tracked path (a folder with its contents) and keeps the registry locked for good,
// so no thread can create or commit a temporary file afterwards: for a process about to die.
void remove_temp_paths_for_exit();

}  // namespace tessera::storage
