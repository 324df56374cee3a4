#include "interrupt.hpp"

#include <pthread.h>
#include <unistd.h>

#include <csignal>
#include <mutex>
#include <thread>

#include "tessera/storage/output_file.hpp"

namespace tessera::tools {

void remove_temp_files_on_interrupt() {
    static std::once_flag once;
    std::call_once(once, [] {
        sigset_t set;
        sigemptyset(&set);
        for (int sig : {SIGINT, SIGTERM, SIGHUP}) {
            struct sigaction old {};
            // A signal ignored from the start (nohup, a background job's SIGINT) stays ignored.
            if (::sigaction(sig, nullptr, &old) == 0 && old.sa_handler == SIG_IGN) continue;
            sigaddset(&set, sig);
        }
        // Blocked here and so in every thread started later: only the waiting thread takes them.
        // Waiting in a thread rather than in a handler lets the cleanup lock and free as usual.
        if (::pthread_sigmask(SIG_BLOCK, &set, nullptr) != 0) return;
        std::thread([set] {
            int sig = 0;
            while (::sigwait(&set, &sig) != 0) {
            }
            storage::remove_temp_paths_for_exit();
            // End as the signal's default action would, so the parent sees what killed us.
            std::signal(sig, SIG_DFL);
            sigset_t one;
            sigemptyset(&one);
            sigaddset(&one, sig);
            ::pthread_sigmask(SIG_UNBLOCK, &one, nullptr);
            std::raise(sig);
            ::_exit(128 + sig);
        }).detach();
    });
}

}  // namespace tessera::tools
