// The HTTP side's executor (server/src/work_executor.hpp): a store's lane bounds its own jobs and
// refuses at once past its queue, a slow lane never holds another store's jobs, renders are
// admitted against their memory budget and queue, waiting jobs expire at their deadline, and
// stop() answers every waiting job.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <thread>
#include <vector>

#include "metrics.hpp"
#include "tessera/storage/byte_source.hpp"
#include "work_executor.hpp"

using namespace tessera::server;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

namespace {

// A gate jobs wait at until the test opens it.
struct Gate {
    std::mutex m;
    std::condition_variable cv;
    bool open = false;
    int waiting = 0;
    void wait() {
        std::unique_lock lock(m);
        ++waiting;
        cv.notify_all();
        cv.wait(lock, [&] { return open; });
    }
    void release() {
        std::lock_guard lock(m);
        open = true;
        cv.notify_all();
    }
    bool wait_for_waiting(int n, std::chrono::milliseconds t) {
        std::unique_lock lock(m);
        return cv.wait_for(lock, t, [&] { return waiting >= n; });
    }
};

// Opens the gate when the test ends, even on a failed assertion (the executor's workers must
// finish before it is destroyed).
struct Release {
    Gate& gate;
    ~Release() { gate.release(); }
};

// Waits (5 s at most) until `done` holds; the assertions after it say whether it did.
template <class Pred>
void eventually(Pred done) {
    const auto t0 = Clock::now();
    while (!done() && Clock::now() - t0 < 5s) std::this_thread::sleep_for(100us);
}

WorkJob job(WorkKind kind, const std::string& store, std::function<void(bool)> run,
            Clock::time_point deadline = Clock::now() + 10s, std::size_t memory = 0) {
    WorkJob j;
    j.kind = kind;
    j.store = store;
    j.run = std::move(run);
    j.deadline = deadline;
    j.memory = memory;
    return j;
}

}  // namespace

TEST(WorkExecutor, ASlowStoreFillsOnlyItsOwnLane) {
    MetricsRegistry metrics;
    WorkLimits limits;
    limits.threads = 4;
    limits.store_inflight = 2;
    limits.store_queue = 3;
    Gate slow;
    WorkExecutor ex(limits, metrics);
    std::atomic<int> slow_started{0};
    const Release release{slow};
    // 2 run (the lane's bound), 3 wait, the 6th is refused at once.
    auto slow_job = [&] {
        return job(WorkKind::read, "slow", [&](bool started) {
            if (started) ++slow_started, slow.wait();
        });
    };
    for (int i = 0; i < 2; ++i) ASSERT_EQ(ex.submit(slow_job()), Admission::admitted);
    ASSERT_TRUE(slow.wait_for_waiting(2, 5s));
    for (int i = 0; i < 3; ++i) ASSERT_EQ(ex.submit(slow_job()), Admission::admitted);
    EXPECT_EQ(ex.submit(job(WorkKind::read, "slow", [](bool) { ADD_FAILURE() << "a refused job ran"; })),
              Admission::store_full);
    EXPECT_EQ(slow_started.load(), 2);

    // Another store's jobs run at once on the workers the slow lane does not hold.
    std::atomic<int> fast_done{0};
    const auto t0 = Clock::now();
    for (int i = 0; i < 20; ++i) {  // one after another (the fast lane has its own bound of 3 waiting)
        ASSERT_EQ(ex.submit(job(WorkKind::read, "fast", [&](bool started) { fast_done += started ? 1 : 0; })),
                  Admission::admitted);
        eventually([&] { return fast_done.load() >= i + 1; });
    }
    EXPECT_EQ(fast_done.load(), 20);
    EXPECT_LT(Clock::now() - t0, 1s);
    EXPECT_EQ(slow_started.load(), 2);  // the slow lane still at its bound
    slow.release();
    eventually([&] { return slow_started.load() >= 5; });
    EXPECT_EQ(slow_started.load(), 5);
    const std::string text = metrics.render();
    EXPECT_NE(text.find("tessera_store_work_rejected_total{store=\"slow\"} 1"), std::string::npos) << text;
    EXPECT_NE(text.find("tessera_work_rejected_total{kind=\"read\",reason=\"store_full\"} 1"), std::string::npos);
}

TEST(WorkExecutor, WaitingJobsExpireAtTheirDeadlineAndRunningOnesSeeIt) {
    MetricsRegistry metrics;
    WorkLimits limits;
    limits.threads = 1;
    limits.store_inflight = 1;
    Gate gate;
    WorkExecutor ex(limits, metrics);
    const Release release{gate};
    Clock::time_point seen_deadline{};
    const auto deadline = Clock::now() + 200ms;
    ASSERT_EQ(ex.submit(job(WorkKind::read, "s", [&](bool) {
                  seen_deadline = tessera::storage::read_deadline();
                  gate.wait();
              }, deadline)),
              Admission::admitted);
    ASSERT_TRUE(gate.wait_for_waiting(1, 5s));
    EXPECT_EQ(seen_deadline, deadline);  // a running job's reads carry its deadline
    std::atomic<int> expired{0};
    std::atomic<long long> expired_late_ms{-1};
    const auto d2 = Clock::now() + 300ms;
    ASSERT_EQ(ex.submit(job(WorkKind::read, "s", [&](bool started) {
                  if (!started) {
                      ++expired;
                      expired_late_ms = std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - d2).count();
                  }
              }, d2)),
              Admission::admitted);
    eventually([&] { return expired.load() > 0; });
    EXPECT_EQ(expired.load(), 1);
    EXPECT_GE(expired_late_ms.load(), 0);
    EXPECT_LE(expired_late_ms.load(), 500);  // within the expiry tick, with room for a loaded machine
    gate.release();
    EXPECT_NE(metrics.render().find("tessera_store_work_expired_total{store=\"s\"} 1"), std::string::npos);
}

TEST(WorkExecutor, RendersAreAdmittedAgainstMemoryAndQueue) {
    MetricsRegistry metrics;
    WorkLimits limits;
    limits.threads = 2;
    limits.render_concurrency = 1;
    limits.render_queue = 2;
    limits.render_memory = 100;
    limits.store_inflight = 8;
    limits.store_queue = 64;
    Gate gate;
    WorkExecutor ex(limits, metrics);
    const Release release{gate};
    EXPECT_EQ(ex.submit(job(WorkKind::render, "a", [&](bool) { gate.wait(); }, Clock::now() + 10s, 101)),
              Admission::render_too_large);
    ASSERT_EQ(ex.submit(job(WorkKind::render, "a", [&](bool) { gate.wait(); }, Clock::now() + 10s, 60)),
              Admission::admitted);
    ASSERT_TRUE(gate.wait_for_waiting(1, 5s));
    EXPECT_EQ(ex.submit(job(WorkKind::render, "b", [](bool) {}, Clock::now() + 10s, 50)), Admission::render_memory);
    ASSERT_EQ(ex.submit(job(WorkKind::render, "b", [&](bool) { gate.wait(); }, Clock::now() + 10s, 20)),
              Admission::admitted);
    ASSERT_EQ(ex.submit(job(WorkKind::render, "b", [&](bool) { gate.wait(); }, Clock::now() + 10s, 10)),
              Admission::admitted);
    EXPECT_EQ(ex.submit(job(WorkKind::render, "c", [](bool) {}, Clock::now() + 10s, 1)), Admission::render_busy);
    EXPECT_EQ(ex.stats().render_memory, 90u);
    // Reads do not wait for renders: they have their own workers.
    std::atomic<bool> read_ran{false};
    ASSERT_EQ(ex.submit(job(WorkKind::read, "a", [&](bool started) { read_ran = started; })), Admission::admitted);
    eventually([&] { return read_ran.load(); });
    EXPECT_TRUE(read_ran.load());
    gate.release();
    eventually([&] { return ex.stats().render_memory == 0; });
    EXPECT_EQ(ex.stats().render_memory, 0u);
}

// One store's renders wait in at most half its lane and three quarters of the render queue: its
// own reads and other stores' renders are still admitted (renders had filled the lane, so the
// store's reads were refused, and the render queue, so every other store's were).
TEST(WorkExecutor, OneStoresRendersLeaveRoomForItsReadsAndOtherStores) {
    MetricsRegistry metrics;
    WorkLimits limits;
    limits.threads = 1;
    limits.render_concurrency = 1;
    limits.store_inflight = 8;
    limits.store_queue = 4;
    limits.render_queue = 4;
    Gate gate;
    WorkExecutor ex(limits, metrics);
    const Release release{gate};
    ASSERT_EQ(ex.submit(job(WorkKind::render, "a", [&](bool) { gate.wait(); })), Admission::admitted);
    ASSERT_TRUE(gate.wait_for_waiting(1, 5s));  // running; the next ones wait
    std::vector<Admission> more;
    for (int i = 0; i < 4; ++i) more.push_back(ex.submit(job(WorkKind::render, "a", [](bool) {})));
    EXPECT_EQ(more, (std::vector<Admission>{Admission::admitted, Admission::admitted, Admission::store_full,
                                            Admission::store_full}));
    EXPECT_EQ(ex.submit(job(WorkKind::read, "a", [](bool) {})), Admission::admitted);
    EXPECT_EQ(ex.submit(job(WorkKind::render, "b", [](bool) {})), Admission::admitted);
}

TEST(WorkExecutor, StopAnswersEveryWaitingJob) {
    MetricsRegistry metrics;
    WorkLimits limits;
    limits.threads = 1;
    limits.store_inflight = 1;
    Gate gate;
    auto ex = std::make_unique<WorkExecutor>(limits, metrics);
    const Release release{gate};
    ASSERT_EQ(ex->submit(job(WorkKind::read, "s", [&](bool) { gate.wait(); })), Admission::admitted);
    ASSERT_TRUE(gate.wait_for_waiting(1, 5s));
    std::atomic<int> not_started{0};
    for (int i = 0; i < 5; ++i)
        ASSERT_EQ(ex->submit(job(WorkKind::read, "s", [&](bool started) { not_started += started ? 0 : 1; })),
                  Admission::admitted);
    std::thread releaser([&] {
        std::this_thread::sleep_for(100ms);
        gate.release();
    });
    ex->stop();
    releaser.join();
    EXPECT_EQ(not_started.load(), 5);
    EXPECT_EQ(ex->submit(job(WorkKind::read, "s", [](bool) {})), Admission::stopped);
}
