#include "work_executor.hpp"

#include <pthread.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <utility>

#include "tessera/storage/byte_source.hpp"

namespace tessera::server {

using Clock = std::chrono::steady_clock;

std::string_view to_string(WorkKind k) { return k == WorkKind::read ? "read" : "render"; }

std::string_view to_string(Admission a) {
    switch (a) {
        case Admission::admitted: return "admitted";
        case Admission::store_full: return "store_full";
        case Admission::render_busy: return "render_busy";
        case Admission::render_memory: return "render_memory";
        case Admission::render_too_large: return "render_too_large";
        case Admission::stopped: return "stopped";
    }
    return "stopped";
}

namespace {
constexpr std::size_t kAdmissions = 6;
constexpr int kRenderNice = 5;
constexpr const char* kQueuedName = "tessera_work_queued";
constexpr const char* kRunningName = "tessera_work_running";
constexpr const char* kMemoryName = "tessera_work_render_memory_bytes";
constexpr const char* kStoreQueuedName = "tessera_store_work_queued";
constexpr const char* kStoreRunningName = "tessera_store_work_running";
}  // namespace

struct WorkExecutor::Lane {
    std::string store;
    std::deque<WorkJob> reads, renders;
    std::size_t running = 0;          // reads and renders
    std::size_t running_renders = 0;
    Counter* rejected = nullptr;
    Counter* expired = nullptr;
    Histogram* wait = nullptr;
    std::size_t queued() const { return reads.size() + renders.size(); }
};

WorkExecutor::WorkExecutor(const WorkLimits& limits, MetricsRegistry& metrics) : limits_(limits), metrics_(metrics) {
    for (WorkKind k : {WorkKind::read, WorkKind::render}) {
        KindMetrics& km = kind_metrics_[static_cast<int>(k)];
        const std::string kind(to_string(k));
        km.wait = &metrics.histogram("tessera_work_wait_seconds", "Time HTTP work waited for a worker, by kind",
                                     {{"kind", kind}}, latency_buckets_seconds());
        km.expired = &metrics.counter("tessera_work_expired_total",
                                      "HTTP work whose request deadline passed before it started (answered 504)",
                                      {{"kind", kind}});
        for (std::size_t a = 1; a < kAdmissions; ++a)
            km.rejected[a] = &metrics.counter("tessera_work_rejected_total",
                                              "HTTP work refused at admission (answered 503), by kind and reason",
                                              {{"kind", kind}, {"reason", std::string(to_string(static_cast<Admission>(a)))}});
        metrics.gauge_callback(kQueuedName, "HTTP work waiting for a worker, by kind", {{"kind", kind}}, [this, k] {
            std::lock_guard lock(mu_);
            return double(k == WorkKind::read ? stats_.queued_reads : stats_.queued_renders);
        });
        metrics.gauge_callback(kRunningName, "HTTP work running on a worker, by kind", {{"kind", kind}}, [this, k] {
            std::lock_guard lock(mu_);
            return double(k == WorkKind::read ? stats_.running_reads : stats_.running_renders);
        });
    }
    metrics.gauge_callback(kMemoryName, "Estimated bytes of the web renders admitted (running or waiting)", {}, [this] {
        std::lock_guard lock(mu_);
        return double(stats_.render_memory);
    });
    try {
        for (unsigned i = 0; i < std::max(1u, limits_.threads); ++i) workers_.emplace_back([this] { worker(WorkKind::read); });
        for (unsigned i = 0; i < std::max(1u, limits_.render_concurrency); ++i)
            workers_.emplace_back([this] { worker(WorkKind::render); });
        expiry_thread_ = std::thread([this] { expiry(); });
    } catch (...) {  // no thread left (a joinable std::thread destroyed ends the process); Server::start reports it
        stop();
        for (const char* name : {kQueuedName, kRunningName, kMemoryName, kStoreQueuedName, kStoreRunningName})
            metrics_.remove_callbacks(name);
        throw;
    }
}

WorkExecutor::~WorkExecutor() {
    stop();
    for (const char* name : {kQueuedName, kRunningName, kMemoryName, kStoreQueuedName, kStoreRunningName})
        metrics_.remove_callbacks(name);
}

// The registry's render() runs gauge callbacks (which take mu_) under its own lock, so metrics
// are registered here without mu_ held: no lock order to invert.
WorkExecutor::Lane& WorkExecutor::lane(const std::string& store) {
    {
        std::lock_guard lock(mu_);
        if (auto it = lanes_.find(store); it != lanes_.end()) return *it->second;
    }
    auto fresh = std::make_unique<Lane>();
    fresh->store = store;
    const Labels labels{{"store", store}};
    fresh->rejected = &metrics_.counter("tessera_store_work_rejected_total",
                                        "HTTP work of a store refused because its lane was full (503)", labels);
    fresh->expired = &metrics_.counter("tessera_store_work_expired_total",
                                       "HTTP work of a store whose deadline passed before it started (504)", labels);
    fresh->wait = &metrics_.histogram("tessera_store_work_wait_seconds", "Time a store's HTTP work waited for a worker",
                                      labels, latency_buckets_seconds());
    Lane* l = nullptr;
    bool inserted = false;
    {
        std::lock_guard lock(mu_);
        auto [it, added] = lanes_.try_emplace(store, std::move(fresh));
        l = it->second.get();
        inserted = added;
        if (added) order_.push_back(l);
    }
    if (inserted) {  // lanes live as long as the executor
        metrics_.gauge_callback(kStoreQueuedName, "HTTP work of a store waiting for a worker", labels, [this, l] {
            std::lock_guard lock(mu_);
            return double(l->queued());
        });
        metrics_.gauge_callback(kStoreRunningName, "HTTP work of a store running", labels, [this, l] {
            std::lock_guard lock(mu_);
            return double(l->running);
        });
    }
    return *l;
}

Admission WorkExecutor::submit(WorkJob job) {
    Admission verdict = Admission::admitted;
    bool wake_expiry = false;
    const WorkKind job_kind = job.kind;
    Lane& lane = this->lane(job.store);
    {
        std::lock_guard lock(mu_);
        if (stopping_) {
            verdict = Admission::stopped;
        } else {
            // One store's renders wait in at most half its lane (its reads keep the rest) and
            // three quarters of the render queue (other stores' renders keep the rest).
            const std::size_t lane_render_queue = std::max<std::size_t>(
                1, std::min(limits_.store_queue / 2, limits_.render_queue - limits_.render_queue / 4));
            if (lane.queued() >= limits_.store_queue ||
                (job.kind == WorkKind::render && lane.renders.size() >= lane_render_queue)) {
                verdict = Admission::store_full;
                lane.rejected->inc();
            } else if (job.kind == WorkKind::render) {
                if (job.memory > limits_.render_memory) verdict = Admission::render_too_large;
                else if (stats_.queued_renders >= limits_.render_queue) verdict = Admission::render_busy;
                else if (stats_.render_memory + job.memory > limits_.render_memory) verdict = Admission::render_memory;
            }
            if (verdict == Admission::admitted) {
                job.admitted_at = Clock::now();
                if (job.kind == WorkKind::render) {
                    stats_.render_memory += job.memory;
                    ++stats_.queued_renders;
                    lane.renders.push_back(std::move(job));
                } else {
                    ++stats_.queued_reads;
                    lane.reads.push_back(std::move(job));
                }
                wake_expiry = std::exchange(expiry_asleep_, false);
            }
        }
        if (verdict != Admission::admitted)
            kind_metrics_[static_cast<int>(job.kind)].rejected[static_cast<std::size_t>(verdict)]->inc();
    }
    if (verdict == Admission::admitted) (job_kind == WorkKind::read ? work_cv_ : render_cv_).notify_one();
    if (wake_expiry) expiry_cv_.notify_one();
    return verdict;
}

// The next job a worker of its kind may start: lanes in turn, each within its own bound.
bool WorkExecutor::pick_locked(WorkKind kind, WorkJob& job, Lane*& picked) {
    const std::size_t n = order_.size();
    const bool reads = kind == WorkKind::read;
    // One store's renders never take every render worker: a store whose reads are slow would
    // hold them all until the deadline.
    // Nor its lane's every place: its reads go on beside its renders.
    const std::size_t lane_renders = std::max<std::size_t>(
        1, std::min<std::size_t>(limits_.render_concurrency / 2, limits_.store_inflight > 1 ? limits_.store_inflight - 1 : 1));
    for (std::size_t i = 0; i < n; ++i) {
        Lane& lane = *order_[(next_lane_ + i) % n];
        auto& q = reads ? lane.reads : lane.renders;
        if (q.empty() || lane.running >= limits_.store_inflight) continue;
        if (!reads && lane.running_renders >= lane_renders) continue;
        job = std::move(q.front());
        q.pop_front();
        ++lane.running;
        if (reads) --stats_.queued_reads, ++stats_.running_reads;
        else --stats_.queued_renders, ++stats_.running_renders, ++lane.running_renders;
        next_lane_ = (next_lane_ + i + 1) % n;
        picked = &lane;
        return true;
    }
    return false;
}

void WorkExecutor::account_done_locked(Lane& lane, const WorkJob& job) {
    --lane.running;
    if (job.kind == WorkKind::render) {
        --stats_.running_renders;
        --lane.running_renders;
        stats_.render_memory -= job.memory;
    } else {
        --stats_.running_reads;
    }
}

void WorkExecutor::worker(WorkKind kind) {
    pthread_setname_np(pthread_self(), kind == WorkKind::read ? "work-read" : "work-render");
    if (kind == WorkKind::render) {
        // Renders are CPU work that can wait; the event loops and reads cannot. A lower priority
        // (nice 5: a third of a default thread's CPU share under contention) keeps the loops'
        // latency when renders fill every core.
        setpriority(PRIO_PROCESS, static_cast<id_t>(gettid()), kRenderNice);
    }
    for (;;) {
        WorkJob job;
        Lane* lane = nullptr;
        {
            std::unique_lock lock(mu_);
            auto& cv = kind == WorkKind::read ? work_cv_ : render_cv_;
            cv.wait(lock, [&] { return stopping_ || pick_locked(kind, job, lane); });
            if (!lane) return;  // stopping, nothing picked
        }
        const double waited = std::chrono::duration<double>(Clock::now() - job.admitted_at).count();
        kind_metrics_[static_cast<int>(job.kind)].wait->observe(waited);
        lane->wait->observe(waited);
        {
            const storage::ReadDeadlineScope scope(job.deadline);
            job.run(true);
        }
        bool reads_waiting, renders_waiting;
        {
            std::lock_guard lock(mu_);
            account_done_locked(*lane, job);
            reads_waiting = stats_.queued_reads > 0;
            renders_waiting = stats_.queued_renders > 0;
        }
        // This worker picks again before it sleeps; a place freed in the lane may also let a
        // worker of the other kind start.
        if (kind == WorkKind::render && reads_waiting) work_cv_.notify_one();
        if (kind == WorkKind::read && renders_waiting) render_cv_.notify_one();
    }
}

void WorkExecutor::expiry() {
    pthread_setname_np(pthread_self(), "work-expiry");
    std::vector<WorkJob> expired;
    for (;;) {
        {
            std::unique_lock lock(mu_);
            // Nothing queued, nothing can expire: sleep until a job queues (submit wakes this
            // thread once per such sleep), not a wake-up every tick on an idle server.
            if (stats_.queued_reads + stats_.queued_renders == 0) {
                expiry_asleep_ = true;
                expiry_cv_.wait(lock, [&] { return stopping_ || !expiry_asleep_; });
                expiry_asleep_ = false;
            }
            expiry_cv_.wait_for(lock, kExpiryTick, [&] { return stopping_; });
            if (stopping_) return;
            const auto now = Clock::now();
            for (Lane* lane : order_)
                for (auto* q : {&lane->reads, &lane->renders}) {
                    const bool render = q == &lane->renders;
                    for (auto it = q->begin(); it != q->end();) {
                        if (it->deadline > now) {
                            ++it;
                            continue;
                        }
                        lane->expired->inc();
                        kind_metrics_[render ? 1 : 0].expired->inc();
                        if (render) --stats_.queued_renders, stats_.render_memory -= it->memory;
                        else --stats_.queued_reads;
                        expired.push_back(std::move(*it));
                        it = q->erase(it);
                    }
                }
        }
        for (auto& job : expired) job.run(false);
        expired.clear();
    }
}

void WorkExecutor::stop() {
    std::vector<WorkJob> left;
    {
        std::lock_guard lock(mu_);
        if (stopping_) return;
        stopping_ = true;
        for (Lane* lane : order_) {
            for (auto* q : {&lane->reads, &lane->renders})
                for (auto& job : *q) left.push_back(std::move(job));
            lane->reads.clear();
            lane->renders.clear();
        }
        stats_.queued_reads = stats_.queued_renders = 0;
    }
    work_cv_.notify_all();
    render_cv_.notify_all();
    expiry_cv_.notify_all();
    for (auto& job : left) job.run(false);
    for (auto& t : workers_)
        if (t.joinable()) t.join();
    if (expiry_thread_.joinable()) expiry_thread_.join();
    std::lock_guard lock(mu_);
    stats_.render_memory = 0;
}

WorkExecutor::Stats WorkExecutor::stats() const {
    std::lock_guard lock(mu_);
    return stats_;
}

}  // namespace tessera::server
