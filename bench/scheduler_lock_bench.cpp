// How long Scheduler::submit of big batches holds the scheduler's lock, as another thread taking
// the same lock sees it (stats(), every 50 us): what every stream's write and every I/O thread
// waits for while a viewer sends batches of 16 384 requests back to back. Measures and prints.
//   scheduler_lock_bench STORE.tsr [ROUNDS]
#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <thread>
#include <vector>

#include "log.hpp"
#include "metrics.hpp"
#include "scheduler.hpp"
#include "server_context.hpp"
#include "store_registry.hpp"
#include "tile_cache.hpp"
#include "tile_fetcher.hpp"

using namespace tessera::server;

int main(int argc, char** argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: scheduler_lock_bench STORE.tsr [ROUNDS]\n");
        return 2;
    }
    const int rounds = argc > 2 ? std::max(1, std::atoi(argv[2])) : 40;
    ServerConfig config;
    config.store_files = {argv[1]};
    config.io_threads = 1;
    config.max_batch = 16384;
    const int devnull = ::open("/dev/null", O_WRONLY | O_CLOEXEC);
    Logger log(LogFormat::json, LogLevel::error, devnull);
    MetricsRegistry metrics;
    StoreRegistry stores(config.store_files, config.store_dirs, log, metrics);
    if (const tessera::Status st = stores.open(); !st) {
        std::fprintf(stderr, "scheduler_lock_bench: %s\n", st.error().message.c_str());
        return 1;
    }
    TileCache cache(0);
    TileFetcher fetcher(cache, metrics, log);
    ServerContext ctx{config, log, metrics, stores, fetcher};
    ctx.ready = true;
    Scheduler sched(ctx);
    const auto id = sched.add_viewer(nullptr);  // never reads: its outbox fills, then it is not served
    const auto store = stores.list().front();
    const auto& level = store->info().levels[0];
    std::mt19937 rng(1);
    std::vector<tessera::v1::TileBatch> batches(8);
    for (auto& b : batches) {
        b.add_stores(store->name);
        b.set_protocol_revision(1);
        for (int i = 0; i < 16384; ++i) {
            auto* r = b.add_requests();
            r->set_level(0);
            r->set_x(rng() % level.tiles_x);
            r->set_y(rng() % level.tiles_y);
            r->set_priority(float(rng() % 1000));
        }
    }
    std::atomic<bool> stop{false};
    std::vector<double> waits_us;
    std::thread prober([&] {
        while (!stop) {
            const auto t0 = std::chrono::steady_clock::now();
            (void)sched.stats();
            waits_us.push_back(std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count());
            std::this_thread::sleep_for(std::chrono::microseconds(50));
        }
    });
    const auto t0 = std::chrono::steady_clock::now();
    int n = 0;
    for (int round = 0; round < rounds; ++round)
        for (const auto& b : batches) {
            sched.submit(*id, b);
            ++n;
        }
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / n;
    stop = true;
    prober.join();
    std::sort(waits_us.begin(), waits_us.end());
    const auto q = [&](double p) { return waits_us[std::min(waits_us.size() - 1, std::size_t(p * double(waits_us.size())))]; };
    std::printf("submit of 16384 requests: %.2f ms each; another thread's wait for the lock: p50 %.1f us, p99 %.1f us, "
                "max %.1f us (%zu waits)\n",
                ms, q(0.5), q(0.99), waits_us.back(), waits_us.size());
    sched.remove_viewer(*id);
    ::close(devnull);
    return 0;
}
