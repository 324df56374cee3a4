#pragma once

// ThreadSanitizer cannot see the ordering gRPC itself provides: Debian's libgrpc (and the Abseil
// mutexes inside it) are not instrumented. gRPC's contract for a callback reactor is that each
// reaction (OnReadDone, OnWriteDone, OnCancel, OnDone) runs after the Start*/Finish call that
// caused it, possibly on another thread. The reactor states that edge to the sanitizer: it
// releases itself before handing an operation to gRPC (in its constructor, after queueing them:
// an unbound reactor's operations are issued when gRPC binds it) and acquires itself when a
// reaction starts. Races between the reactor and Tessera's own threads stay visible; in other builds these
// are no-ops. docs/reliability.md, "Sanitizers", says what else is assumed of gRPC.

#if defined(__SANITIZE_THREAD__)
extern "C" void __tsan_acquire(void* addr);
extern "C" void __tsan_release(void* addr);
#endif

namespace tessera::server {

inline void handoff_to_grpc([[maybe_unused]] void* reactor) {
#if defined(__SANITIZE_THREAD__)
    __tsan_release(reactor);
#endif
}

inline void reaction_from_grpc([[maybe_unused]] void* reactor) {
#if defined(__SANITIZE_THREAD__)
    __tsan_acquire(reactor);
#endif
}

}  // namespace tessera::server
