#include "thread_slice.hpp"

#include <sched.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <cstdint>
#include <cstring>

namespace tessera::server {

namespace {

// glibc 2.36 has no wrapper; the layout is the kernel's (include/uapi/linux/sched/types.h).
struct SchedAttr {
    std::uint32_t size;
    std::uint32_t sched_policy;
    std::uint64_t sched_flags;
    std::int32_t sched_nice;
    std::uint32_t sched_priority;
    std::uint64_t sched_runtime;
    std::uint64_t sched_deadline;
    std::uint64_t sched_period;
    std::uint32_t sched_util_min;
    std::uint32_t sched_util_max;
};

}  // namespace

bool request_short_slice(std::chrono::microseconds slice) {
    if (slice.count() <= 0) return false;
#if defined(SYS_sched_setattr) && defined(SYS_sched_getattr)
    SchedAttr attr;
    std::memset(&attr, 0, sizeof attr);
    if (syscall(SYS_sched_getattr, 0, &attr, sizeof attr, 0) != 0) return false;
    // Only the fair classes have slices to shorten; a real-time thread is left alone.
    if (attr.sched_policy != SCHED_OTHER && attr.sched_policy != SCHED_BATCH) return false;
    attr.size = sizeof attr;
    attr.sched_flags = 0;
    const auto wanted = static_cast<std::uint64_t>(std::chrono::nanoseconds(slice).count());
    attr.sched_runtime = wanted;
    if (syscall(SYS_sched_setattr, 0, &attr, 0) != 0) return false;
    // Kernels before 6.12 accept the call and ignore the runtime of a fair thread: read it back.
    SchedAttr now;
    std::memset(&now, 0, sizeof now);
    return syscall(SYS_sched_getattr, 0, &now, sizeof now, 0) == 0 && now.sched_runtime == wanted;
#else
    return false;
#endif
}

}  // namespace tessera::server
