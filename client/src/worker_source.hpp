#pragma once
// The request machinery shared by the in-process tile sources (a .tsr file read directly, tiles
// made on demand): a few worker threads serve the newest request set, highest priority first, and
// a derived class only says how one tile is made (produce()). Owner of its threads; its queues:
// the request set (replaced whole, bounded by what the runtime asks for) and the output buffer
// (max_buffered tiles; beyond it the workers pause).
#include <algorithm>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <thread>
#include <unordered_set>
#include <vector>

#include "tessera/client/tile_source.hpp"

namespace tessera::client::detail {

class WorkerSource : public TileSource {
public:
    void set_requests(std::uint64_t, std::span<const SourceRequest> requests) override {
        std::lock_guard lock(mu_);
        pending_.assign(requests.begin(), requests.end());
        // Ascending priority: the next one is at the back. Already made or being made: skip.
        std::stable_sort(pending_.begin(), pending_.end(),
                         [](const SourceRequest& a, const SourceRequest& b) { return a.priority < b.priority; });
        std::erase_if(pending_, [&](const SourceRequest& r) { return in_flight_.contains(r.page); });
        wanted_.clear();
        for (const auto& r : requests) wanted_.insert(r.page);
        // Made but not yet polled, and no longer wanted: dropped.
        std::erase_if(out_, [&](const SourceTile& t) {
            if (wanted_.contains(t.page)) return false;
            in_flight_.erase(t.page);
            return true;
        });
        cv_.notify_all();
    }

    std::size_t poll(std::vector<SourceTile>& out, std::size_t max) override {
        std::lock_guard lock(mu_);
        std::size_t n = 0;
        while (n < max && !out_.empty()) {
            in_flight_.erase(out_.front().page);
            out.push_back(std::move(out_.front()));
            out_.pop_front();
            ++n;
        }
        if (n) cv_.notify_all();
        return n;
    }

protected:
    explicit WorkerSource(std::size_t max_buffered) : max_buffered_(std::max<std::size_t>(1, max_buffered)) {}
    // The derived class starts the workers once it is fully built, and stops them in its own
    // destructor (produce() must not run on a half-destroyed object).
    void start(unsigned threads) {
        for (unsigned i = 0; i < std::max(1u, threads); ++i) workers_.emplace_back([this] { work(); });
    }
    void stop() {
        {
            std::lock_guard lock(mu_);
            stop_ = true;
        }
        cv_.notify_all();
        for (auto& t : workers_) t.join();
        workers_.clear();
    }
    // Fills `t` (page already set) on a worker thread, without the queue lock: status ok and the
    // tile's data, or an error status and message. May run concurrently.
    virtual void produce(SourceTile& t) = 0;

private:
    void work() {
        for (;;) {
            SourceRequest r;
            {
                std::unique_lock lock(mu_);
                cv_.wait(lock, [&] { return stop_ || (!pending_.empty() && out_.size() < max_buffered_); });
                if (stop_) return;
                r = pending_.back();
                pending_.pop_back();
                in_flight_.insert(r.page);
            }
            SourceTile t;
            t.page = r.page;
            produce(t);
            t.received = std::chrono::steady_clock::now();
            std::lock_guard lock(mu_);
            if (!wanted_.contains(t.page)) {
                in_flight_.erase(t.page);  // superseded while it was made
                continue;
            }
            out_.push_back(std::move(t));
        }
    }

    const std::size_t max_buffered_;
    std::mutex mu_;
    std::condition_variable cv_;
    bool stop_ = false;
    std::vector<SourceRequest> pending_;
    std::unordered_set<PageKey, PageKeyHash> wanted_;
    std::unordered_set<PageKey, PageKeyHash> in_flight_;  // being made or waiting in out_
    std::deque<SourceTile> out_;
    std::vector<std::thread> workers_;
};

}  // namespace tessera::client::detail
