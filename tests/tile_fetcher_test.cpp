// The server's tile fetcher: however many requests miss a tile at once, it is read once (the
// others join the read in flight), each gets the tile, and a counter says how many reads that saved.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <thread>
#include <vector>

#include "log.hpp"
#include "metrics.hpp"
#include "store_registry.hpp"
#include "tessera/storage/byte_source.hpp"
#include "tessera/storage/store_reader.hpp"
#include "raw_store_util.hpp"
#include "test_util.hpp"
#include "tile_cache.hpp"
#include "tile_fetcher.hpp"

using namespace tessera;
using namespace tessera::server;
using namespace std::chrono_literals;

namespace {

// A store in memory whose reads past its index wait at a gate the test opens: a slow disk.
class GatedSource final : public storage::ByteSource {
public:
    GatedSource(std::vector<std::uint8_t> bytes, std::uint64_t gate_from) : bytes_(std::move(bytes)), gate_from_(gate_from) {}
    std::uint64_t size() const override { return bytes_.size(); }
    Status read(std::uint64_t offset, std::uint64_t length, std::uint8_t* dst) const override {
        if (offset + length > bytes_.size()) return make_error(Errc::corrupt, "past the end");
        if (offset >= gate_from_) {
            reads_waiting_.fetch_add(1);
            std::unique_lock lock(m_);
            cv_.wait(lock, [&] { return open_; });
        }
        std::copy_n(bytes_.begin() + std::ptrdiff_t(offset), length, dst);
        return {};
    }
    void close_gate() {
        std::lock_guard lock(m_);
        open_ = false;
    }
    void open_gate() {
        {
            std::lock_guard lock(m_);
            open_ = true;
        }
        cv_.notify_all();
    }
    int reads_waiting() const { return reads_waiting_.load(); }

private:
    std::vector<std::uint8_t> bytes_;
    std::uint64_t gate_from_;
    mutable std::mutex m_;
    mutable std::condition_variable cv_;
    bool open_ = true;
    mutable std::atomic<int> reads_waiting_{0};
};

// A 64x64 RGB raw store, tiles of 16, every tile present; its bytes.
std::vector<std::uint8_t> small_store(const test::ScratchDir& dir) { return test::raw_store_bytes(dir, 64, 16, 4); }

// A fetcher over the small store read through a gate (closed by the test), with its own log,
// metrics and cache of `cache_bytes`.
struct GatedFetcher {
    explicit GatedFetcher(std::size_t cache_bytes) : cache(cache_bytes) {
        bytes = small_store(dir);
        const std::uint64_t payloads = (*storage::StoreReader::open_memory(bytes))->locate({0, 0, 0})->offset;  // the index lies before
        auto source = std::make_unique<GatedSource>(bytes, payloads);
        gate = source.get();
        auto reader = storage::StoreReader::open_source(std::move(source), "gated");
        EXPECT_TRUE(reader.ok());
        store.name = "gated";
        store.reader = *reader;
        store.version = (*reader)->info().store_id;
        store.metrics.data_loss = &metrics.counter("test_data_loss_total", "test");
    }
    ~GatedFetcher() { ::close(null_fd); }
    // Waits (up to 10 s) until `n` reads are held at the gate.
    bool reads_at_gate(int n) {
        for (auto until = std::chrono::steady_clock::now() + 10s; gate->reads_waiting() < n && std::chrono::steady_clock::now() < until;)
            std::this_thread::sleep_for(1ms);
        return gate->reads_waiting() >= n;
    }

    test::ScratchDir dir;
    std::vector<std::uint8_t> bytes;
    GatedSource* gate = nullptr;
    int null_fd = ::open("/dev/null", O_WRONLY | O_CLOEXEC);
    Logger log{LogFormat::text, LogLevel::error, null_fd};
    MetricsRegistry metrics;
    TileCache cache;
    TileFetcher fetcher{cache, metrics, log};
    StoreHandle store;
};

}  // namespace

TEST(TileFetcher, ConcurrentMissesOfOneTileReadItOnce) {
    GatedFetcher g(1 << 20);
    auto [fetcher, store, gate] = std::tie(g.fetcher, g.store, g.gate);
    constexpr int kViewers = 8;
    gate->close_gate();
    std::vector<FetchedTile> got(kViewers);
    std::vector<std::thread> viewers;
    viewers.emplace_back([&] { got[0] = fetcher.fetch_one(store, {0, 1, 2}); });
    // The first read is at the gate before the others miss the same tile.
    ASSERT_TRUE(g.reads_at_gate(1));
    ASSERT_EQ(gate->reads_waiting(), 1);
    for (int v = 1; v < kViewers; ++v) viewers.emplace_back([&, v] { got[v] = fetcher.fetch_one(store, {0, 1, 2}); });
    // They join it: each counts as a saved read once answered; none reaches the gate itself.
    for (auto until = std::chrono::steady_clock::now() + 2s; std::chrono::steady_clock::now() < until;)
        std::this_thread::sleep_for(5ms);
    EXPECT_EQ(gate->reads_waiting(), 1) << "a second read of the same tile went to the store";
    gate->open_gate();
    for (auto& t : viewers) t.join();

    EXPECT_EQ(fetcher.tiles_read(), 1u);
    EXPECT_EQ(fetcher.reads_saved(), std::uint64_t(kViewers - 1));
    for (int v = 0; v < kViewers; ++v) {
        ASSERT_EQ(got[v].status, TileStatus::ok) << got[v].message;
        ASSERT_TRUE(got[v].tile);
        EXPECT_EQ(got[v].tile->bytes, got[0].tile->bytes);
    }
    // Later misses of other tiles read as before; a hit reads nothing.
    EXPECT_EQ(fetcher.fetch_one(store, {0, 1, 2}).status, TileStatus::ok);
    EXPECT_EQ(fetcher.tiles_read(), 1u);
    EXPECT_EQ(fetcher.fetch_one(store, {0, 3, 3}).status, TileStatus::ok);
    EXPECT_EQ(fetcher.tiles_read(), 2u);
    EXPECT_EQ(fetcher.reads_saved(), std::uint64_t(kViewers - 1));
}

TEST(TileFetcher, ABatchJoinsTheReadsInFlightAndLeadsTheRest) {
    GatedFetcher g(0);  // no cache: only the flights can save reads
    auto [fetcher, store, gate] = std::tie(g.fetcher, g.store, g.gate);
    gate->close_gate();
    FetchedTile first;
    std::thread a([&] { first = fetcher.fetch_one(store, {0, 2, 2}); });
    ASSERT_TRUE(g.reads_at_gate(1));
    // A batch of three: (2,2) is in flight, (0,0) and (3,0) are not (and (0,0) twice).
    const std::vector<TileKey> keys{{0, 0, 0}, {0, 2, 2}, {0, 3, 0}, {0, 0, 0}};
    std::vector<FetchedTile> out;
    std::thread b([&] { fetcher.fetch(store, keys, out); });
    g.reads_at_gate(2);
    gate->open_gate();
    a.join();
    b.join();
    ASSERT_EQ(out.size(), keys.size());
    for (const auto& f : out) ASSERT_EQ(f.status, TileStatus::ok) << f.message;
    EXPECT_EQ(out[1].tile->bytes, first.tile->bytes);
    EXPECT_EQ(out[0].tile->bytes, out[3].tile->bytes);
    EXPECT_EQ(fetcher.tiles_read(), 3u);  // (2,2) once, (0,0) once, (3,0) once
    EXPECT_EQ(fetcher.reads_saved(), 2u);
}
