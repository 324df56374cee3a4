#include "thread_pool.hpp"

#include <algorithm>
#include <atomic>
#include <memory>

namespace tessera::storage::build {

ThreadPool::ThreadPool(unsigned threads, std::size_t queue_bound) : bound_(std::max<std::size_t>(queue_bound, 1)) {
    threads = std::max(threads, 1u);
    workers_.reserve(threads);
    for (unsigned i = 0; i < threads; ++i) workers_.emplace_back([this] { run(); });
}

ThreadPool::~ThreadPool() {
    {
        std::unique_lock lock(mu_);
        idle_cv_.wait(lock, [&] { return queue_.empty() && busy_ == 0; });
        stop_ = true;
    }
    work_cv_.notify_all();
    for (auto& t : workers_) t.join();
}

void ThreadPool::submit(std::function<void()> task) {
    std::unique_lock lock(mu_);
    space_cv_.wait(lock, [&] { return queue_.size() < bound_; });
    queue_.push_back(std::move(task));
    lock.unlock();
    work_cv_.notify_one();
}

void ThreadPool::wait_idle() {
    std::unique_lock lock(mu_);
    idle_cv_.wait(lock, [&] { return queue_.empty() && busy_ == 0; });
}

void ThreadPool::run() {
    for (;;) {
        std::function<void()> task;
        {
            std::unique_lock lock(mu_);
            work_cv_.wait(lock, [&] { return stop_ || !queue_.empty(); });
            if (queue_.empty()) return;  // stop_ and drained
            task = std::move(queue_.front());
            queue_.pop_front();
            ++busy_;
        }
        space_cv_.notify_one();
        task();
        {
            std::lock_guard lock(mu_);
            --busy_;
            if (queue_.empty() && busy_ == 0) idle_cv_.notify_all();
        }
    }
}

void ThreadPool::parallel_for(std::size_t n, std::size_t grain, const std::function<void(std::size_t, std::size_t)>& fn) {
    if (n == 0) return;
    grain = std::max<std::size_t>(grain, 1);
    const std::size_t chunks = (n + grain - 1) / grain;
    if (chunks == 1) {
        fn(0, n);
        return;
    }
    struct Shared {
        std::atomic<std::size_t> next{0};
        std::size_t done = 0;  // guarded by m
        std::mutex m;
        std::condition_variable cv;
    };
    auto shared = std::make_shared<Shared>();
    // Helpers and the caller claim chunks from one counter; a helper that starts late finds none
    // and returns at once, so the caller never waits for queued-but-unstarted helpers.
    auto work = [shared, &fn, n, grain, chunks] {
        std::size_t mine = 0;
        for (std::size_t c; (c = shared->next.fetch_add(1)) < chunks; ++mine) fn(c * grain, std::min(n, (c + 1) * grain));
        if (mine) {
            std::lock_guard lock(shared->m);
            shared->done += mine;
            if (shared->done == chunks) shared->cv.notify_all();
        }
    };
    const std::size_t helpers = std::min<std::size_t>(workers_.size(), chunks - 1);
    {
        std::lock_guard lock(mu_);
        for (std::size_t i = 0; i < helpers; ++i) queue_.push_front(work);
    }
    work_cv_.notify_all();
    work();
    std::unique_lock lock(shared->m);
    shared->cv.wait(lock, [&] { return shared->done == chunks; });
}

}  // namespace tessera::storage::build
