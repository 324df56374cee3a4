#pragma once
// The builder's workers: a fixed set of threads owned by one build, a bounded queue of tasks
// (submit blocks when it is full: back-pressure on the thread producing tiles), and a fork-join
// parallel_for in which the calling thread works too.
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace tessera::storage::build {

class ThreadPool {
public:
    ThreadPool(unsigned threads, std::size_t queue_bound);
    ~ThreadPool();  // waits for queued work, then joins
    ThreadPool(const ThreadPool&) = delete;
    ThreadPool& operator=(const ThreadPool&) = delete;

    unsigned size() const { return static_cast<unsigned>(workers_.size()); }

    // Queues a task; blocks while the queue holds queue_bound tasks.
    void submit(std::function<void()> task);
    // Blocks until every submitted task has finished.
    void wait_idle();
    // Runs fn(begin, end) over [0, n) in chunks of `grain`, on the pool and the calling thread;
    // returns when all chunks are done. Jumps ahead of queued tasks.
    void parallel_for(std::size_t n, std::size_t grain, const std::function<void(std::size_t, std::size_t)>& fn);

private:
    void run();
    std::mutex mu_;
    std::condition_variable work_cv_, space_cv_, idle_cv_;
    std::deque<std::function<void()>> queue_;
    std::size_t bound_;
    std::size_t busy_ = 0;
    bool stop_ = false;
    std::vector<std::thread> workers_;
};

}  // namespace tessera::storage::build
