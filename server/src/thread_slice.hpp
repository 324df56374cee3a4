#pragma once

#include <chrono>

namespace tessera::server {

// Asks the kernel's fair scheduler for a short time slice for the calling thread (EEVDF, Linux
// 6.12 and later: sched_attr.sched_runtime of a SCHED_OTHER thread). A thread with a shorter
// slice gets an earlier virtual deadline, so when it wakes (a request arrived, a read finished)
// it preempts a thread that has been running a longer slice instead of waiting for that slice
// to end: an HTTP event loop gets to a request in tens of microseconds rather than a
// millisecond or more on a busy machine. Its CPU share is unchanged (the policy and nice
// value stay). A kernel without the feature ignores it or refuses it; either way the thread
// runs as before. docs/server.md, "Short slices".
// Returns whether the kernel took it (read back). A zero slice does nothing. The kernel keeps a
// slice within 0.1–100 ms.
bool request_short_slice(std::chrono::microseconds slice);

}  // namespace tessera::server
