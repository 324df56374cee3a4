#pragma once
// Commands that write files (build, source, view, loadtest, demo) remove their temporary files
// when interrupted.

namespace tessera::tools {

// From now on SIGINT, SIGTERM and SIGHUP (those not ignored when the process started) remove every
// temporary file and folder in progress (storage::track_temp_path) and then end the process by
// that signal, as its default action would (status 128 + signal). Call it at the start of a
// command, before any thread is started: the signals are blocked in the calling thread and in
// every thread it starts, and one thread of its own waits for them. Not for commands that handle
// these signals themselves (serve).
void remove_temp_files_on_interrupt();

}  // namespace tessera::tools
