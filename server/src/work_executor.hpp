#pragma once
// Where the HTTP front end's slow work runs, off its event loops: tile reads that miss the RAM
// cache (a pread, or range requests to a remote store's origin) and web image renders (decode,
// resample, encode). The loops only parse, route and write; whatever would make them wait comes
// here (docs/server.md, "Isolation").
//
// Admission is decided at once, never by waiting:
// - Each store has a lane: at most `store_inflight` of its jobs run at once and `store_queue`
//   wait. A store whose origin is slow fills its own lane and is refused (503) when the lane is
//   full; it never holds the workers or the queue places that other stores' jobs need.
// - Reads go ahead of renders: they have their own `threads` workers, each taking the oldest read
//   of the next lane in turn; renders run on `render_concurrency` workers of their own, at a
//   lower CPU priority (nice 5), so a flood of renders never holds a read or an event loop.
// - A render is admitted against `render_queue` (waiting) and `render_memory`, the bytes its
//   estimate says the renders running and waiting may hold; one store's renders wait in at most
//   half its lane and three quarters of `render_queue`.
// - A job whose deadline passes while it waits is taken out and answered (expired) within
//   kExpiryTick (the expiry thread sleeps while nothing waits); a running job's remote reads end
//   at its deadline (storage::ReadDeadlineScope).
//
// Owner: the HTTP server. Threads: `threads` read workers, `render_concurrency` render workers
// and one expiry thread, owned here; nothing
// grows with the number of requests beyond the bounds above.
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "metrics.hpp"

namespace tessera::server {

enum class WorkKind : std::uint8_t { read, render };
std::string_view to_string(WorkKind k);

struct WorkLimits {
    unsigned threads = 32;             // read workers (reads wait on I/O, so more than cores)
    std::size_t store_inflight = 8;    // one store's jobs running at once
    std::size_t store_queue = 64;      // one store's jobs waiting
    unsigned render_concurrency = 2;   // render workers: renders running at once
    std::size_t render_queue = 64;      // renders waiting
    std::size_t render_memory = std::size_t(160) << 20;  // estimated bytes of renders admitted
};

// Why a job was refused (admitted: it was not).
enum class Admission : std::uint8_t { admitted, store_full, render_busy, render_memory, render_too_large, stopped };
std::string_view to_string(Admission a);

struct WorkJob {
    WorkKind kind = WorkKind::read;
    std::string store;        // its lane
    std::size_t memory = 0;   // renders: the estimate admission charges
    std::chrono::steady_clock::time_point deadline = std::chrono::steady_clock::time_point::max();
    // Called exactly once: on a worker with started = true (within a ReadDeadlineScope of the
    // deadline), or with started = false when the deadline passed before it could start or the
    // executor stopped (on the expiry thread or the stopping one). Must not throw.
    std::function<void(bool started)> run;
    std::chrono::steady_clock::time_point admitted_at{};  // set by submit
};

class WorkExecutor {
public:
    static constexpr std::chrono::milliseconds kExpiryTick{50};

    WorkExecutor(const WorkLimits& limits, MetricsRegistry& metrics);
    ~WorkExecutor();  // stop()
    WorkExecutor(const WorkExecutor&) = delete;
    WorkExecutor& operator=(const WorkExecutor&) = delete;

    // Queues the job, or refuses it at once (the job is then dropped, not run).
    Admission submit(WorkJob job);
    // Jobs waiting run with started = false; running ones finish; the threads are joined.
    void stop();

    const WorkLimits& limits() const { return limits_; }

    struct Stats {
        std::size_t queued_reads = 0, queued_renders = 0, running_reads = 0, running_renders = 0;
        std::size_t render_memory = 0;  // estimated bytes of renders admitted (running or waiting)
    };
    Stats stats() const;

private:
    struct Lane;
    struct KindMetrics {
        Histogram* wait = nullptr;
        Counter* expired = nullptr;
        Counter* rejected[6] = {};
    };

    Lane& lane(const std::string& store);  // made on first use; takes mu_ itself
    bool pick_locked(WorkKind kind, WorkJob& job, Lane*& lane);
    void worker(WorkKind kind);
    void expiry();
    void account_done_locked(Lane& lane, const WorkJob& job);

    const WorkLimits limits_;
    MetricsRegistry& metrics_;
    KindMetrics kind_metrics_[2];

    mutable std::mutex mu_;
    std::condition_variable work_cv_;    // read workers
    std::condition_variable render_cv_;  // render workers
    std::condition_variable expiry_cv_;
    bool expiry_asleep_ = false;  // the expiry thread waits for a job to queue (nothing to watch)
    bool stopping_ = false;
    std::map<std::string, std::unique_ptr<Lane>> lanes_;  // one per store ever asked for
    std::vector<Lane*> order_;                            // round robin over lanes
    std::size_t next_lane_ = 0;
    Stats stats_;
    std::vector<std::thread> workers_;
    std::thread expiry_thread_;
};

}  // namespace tessera::server
