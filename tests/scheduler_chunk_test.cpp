// The scheduler's chunks: a worker takes up to Scheduler::kChunk of a viewer's requests at once,
// but requests of a remote store only among the first kRemoteChunk. A slow origin's reads are
// bounded in chunks (--remote-concurrency), so that is what bounds the tiles they hold.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "log.hpp"
#include "metrics.hpp"
#include "scheduler.hpp"
#include "server_context.hpp"
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

// The gate every read of tile bytes waits at while it is closed: an origin that does not answer.
struct Gate {
    std::mutex m;
    std::condition_variable cv;
    bool open = false;
    std::atomic<int> waiting{0};
    void release() {
        {
            std::lock_guard lock(m);
            open = true;
        }
        cv.notify_all();
    }
};

// A store's bytes in memory, standing for a remote object: reads from `payloads` on wait at the gate.
class OriginSource final : public storage::ByteSource {
public:
    OriginSource(std::shared_ptr<const std::vector<std::uint8_t>> bytes, std::uint64_t payloads, std::shared_ptr<Gate> gate)
        : bytes_(std::move(bytes)), payloads_(payloads), gate_(std::move(gate)) {}
    std::uint64_t size() const override { return bytes_->size(); }
    Status read(std::uint64_t offset, std::uint64_t length, std::uint8_t* dst) const override {
        if (offset + length > bytes_->size()) return make_error(Errc::corrupt, "past the end");
        if (offset + length > payloads_) {
            gate_->waiting.fetch_add(1);
            std::unique_lock lock(gate_->m);
            gate_->cv.wait(lock, [&] { return gate_->open; });
        }
        std::copy_n(bytes_->begin() + std::ptrdiff_t(offset), length, dst);
        return {};
    }
    std::string version() const override { return "\"v1\""; }

private:
    std::shared_ptr<const std::vector<std::uint8_t>> bytes_;
    std::uint64_t payloads_;
    std::shared_ptr<Gate> gate_;
};

class NoSink final : public ViewerSink {
public:
    void on_outbox_ready() override {}
};


}  // namespace

// One viewer asks for 48 tiles of a remote store whose origin does not answer, with
// --remote-concurrency 1: the one read that store may have takes 16 of them (kRemoteChunk), not a
// whole chunk of 48; the other 32 stay pending, and the other reader takes none of them.
TEST(SchedulerChunks, ARemoteStoresRequestsFillOnlyTheFirstSixteenOfAChunk) {
    static_assert(Scheduler::kChunk >= 48 && Scheduler::kRemoteChunk == 16);
    test::ScratchDir dir;
    auto bytes = std::make_shared<const std::vector<std::uint8_t>>(test::raw_store_bytes(dir, 128, 16, 8));
    const std::uint64_t payloads = (*storage::StoreReader::open_memory(*bytes))->locate({0, 0, 0})->offset;
    auto gate = std::make_shared<Gate>();
    RemoteStores remote{[&](const std::string&) -> Result<std::unique_ptr<storage::ByteSource>> {
                            return std::unique_ptr<storage::ByteSource>(new OriginSource(bytes, payloads, gate));
                        },
                        [](const std::string&) -> Result<std::string> { return std::string("\"v1\""); }};
    const int null_fd = ::open("/dev/null", O_WRONLY | O_CLOEXEC);
    Logger log(LogFormat::text, LogLevel::error, null_fd);
    MetricsRegistry metrics;
    ServerConfig config;
    config.io_threads = 2;
    config.remote_concurrency = 1;
    config.batch_hold = 0ms;
    StoreRegistry stores({"http://origin.test/s.tsr"}, {}, log, metrics, remote);
    ASSERT_TRUE(stores.open().ok());
    TileCache cache(1 << 20);
    TileFetcher fetcher(cache, metrics, log);
    ServerContext ctx{config, log, metrics, stores, fetcher};
    {
        Scheduler scheduler(ctx);
        const auto viewer = scheduler.add_viewer(std::make_shared<NoSink>());
        ASSERT_TRUE(viewer);
        v1::TileBatch batch;
        batch.set_frame(1);
        batch.add_stores("s");
        for (std::uint32_t i = 0; i < 48; ++i) {
            auto* r = batch.add_requests();
            r->set_store(0);
            r->set_level(0);
            r->set_x(i % 8);
            r->set_y(i / 8);
            r->set_priority(float(100 - i));
        }
        scheduler.submit(*viewer, batch);
        for (auto until = std::chrono::steady_clock::now() + 10s; gate->waiting.load() == 0 && std::chrono::steady_clock::now() < until;)
            std::this_thread::sleep_for(1ms);
        ASSERT_GE(gate->waiting.load(), 1) << "no read reached the origin";
        std::this_thread::sleep_for(200ms);  // time for the other reader to take what it may
        const SchedulerStats s = scheduler.stats();
        EXPECT_EQ(s.in_flight, 16u) << "requests taken into the store's one read";
        EXPECT_EQ(s.pending, 32u);
        gate->release();
        // Then every tile arrives: 48 replies (after the ack) leave the outbox.
        std::vector<OutMessage> out;
        std::size_t tiles = 0;
        for (auto until = std::chrono::steady_clock::now() + 10s; tiles < 48 && std::chrono::steady_clock::now() < until;) {
            if (!scheduler.next_messages(*viewer, out, 1 << 20)) {
                std::this_thread::sleep_for(1ms);
                continue;
            }
            for (const OutMessage& m : out) tiles += m.is_tile && m.status == TileStatus::ok ? 1 : 0;
            scheduler.messages_written(*viewer, out, true);
        }
        EXPECT_EQ(tiles, 48u);
        scheduler.remove_viewer(*viewer);
    }
    ::close(null_fd);
}
