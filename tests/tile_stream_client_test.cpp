// TileStreamClient against an in-process fake TileService (gRPC sync server on 127.0.0.1:0): replies
// and their fields, newest-batch-wins, reconnect with resend, checksum verification, auth metadata,
// prompt destruction, the bounded receive buffer, TLS, retry after RESOURCE_EXHAUSTED, unary calls.
#include "tessera/client/net/tile_stream_client.hpp"

#include <gtest/gtest.h>
#include <xxhash.h>

#include <grpcpp/grpcpp.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "tessera.grpc.pb.h"

namespace tessera::client {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using Stream = grpc::ServerReaderWriter<v1::ServerMessage, v1::TileBatch>;

// A self-signed certificate for "localhost" (EC P-256, valid to 2126), only for these tests.
constexpr const char* kTestCert = R"(-----BEGIN CERTIFICATE-----
MIIBljCCATugAwIBAgIUV5DpTLAY0TzFH0PSPYizOUHEljIwCgYIKoZIzj0EAwIw
FDESMBAGA1UEAwwJbG9jYWxob3N0MCAXDTI2MTEyMTExNDUzMloYDzIxMjYxMDI4
MTE0NTMyWjAUMRIwEAYDVQQDDAlsb2NhbGhvc3QwWTATBgcqhkjOPQIBBggqhkjO
PQMBBwNCAAR68RnFLfIheeFuJ/MvHqVmLmAcYuWzATVhuzHkNmMBlsuE7P3dogen
sAktihdIXn2+IHsgkbuptk4UMWtYpIexo2kwZzAdBgNVHQ4EFgQUKIHqdR+0k1Sg
MkNbAi8cNxGoYoowHwYDVR0jBBgwFoAUKIHqdR+0k1SgMkNbAi8cNxGoYoowDwYD
VR0TAQH/BAUwAwEB/zAUBgNVHREEDTALgglsb2NhbGhvc3QwCgYIKoZIzj0EAwID
SQAwRgIhAIgdohmMFq8sDyNXnRcQNtjXgL6+FVaCKmsCXeTXTl2pAiEAsJ0HNIV5
Kt0SqU1ioBZ9+ppGOIQjHBmSBVobrjg2Do0=
-----END CERTIFICATE-----
)";
constexpr const char* kTestKey = R"(-----BEGIN PRIVATE KEY-----
MIGHAgEAMBMGByqGSM49AgEGCCqGSM49AwEHBG0wawIBAQQg29vFvTMtLvGp4LNs
K7c25kHNdJCwitnVFHbKTAIVnnChRANCAAR68RnFLfIheeFuJ/MvHqVmLmAcYuWz
ATVhuzHkNmMBlsuE7P3dogensAktihdIXn2+IHsgkbuptk4UMWtYpIex
-----END PRIVATE KEY-----
)";

std::vector<std::uint8_t> make_payload(std::uint32_t level, std::uint32_t x, std::uint32_t y, std::size_t size) {
    std::vector<std::uint8_t> p(size);
    for (std::size_t i = 0; i < size; ++i) p[i] = static_cast<std::uint8_t>(i * 31 + x + y * 7 + level);
    return p;
}

v1::ServerMessage make_tile(const v1::TileBatch& batch, const v1::TileRequest& r, std::size_t payload_size) {
    v1::ServerMessage msg;
    v1::TileReply* t = msg.mutable_tile();
    t->mutable_key()->set_store(batch.stores(static_cast<int>(r.store())));
    t->mutable_key()->set_level(r.level());
    t->mutable_key()->set_x(r.x());
    t->mutable_key()->set_y(r.y());
    t->set_store_version(0x1234567890abcdefULL);
    t->set_frame(batch.frame());
    t->set_status(v1::TILE_OK);
    t->set_kind(v1::KIND_PRESENT);
    t->set_codec(v1::CODEC_RAW);
    const auto payload = make_payload(r.level(), r.x(), r.y(), payload_size);
    t->set_payload(payload.data(), payload.size());
    t->set_checksum(XXH3_64bits(payload.data(), payload.size()));
    t->set_server_micros(77);
    return msg;
}

// Answers each batch with an ack, then one 100-byte tile per request.
bool default_respond(const v1::TileBatch& batch, Stream& stream) {
    v1::ServerMessage ack;
    ack.mutable_ack()->set_frame(batch.frame());
    ack.mutable_ack()->set_admitted(static_cast<std::uint32_t>(batch.requests_size()));
    ack.mutable_ack()->set_cancelled(3);
    if (!stream.Write(ack)) return false;
    for (const v1::TileRequest& r : batch.requests())
        if (!stream.Write(make_tile(batch, r, 100))) return false;
    return true;
}

std::string metadata(const grpc::ServerContext& ctx, const std::string& key) {
    auto it = ctx.client_metadata().find(key);
    return it == ctx.client_metadata().end() ? std::string() : std::string(it->second.data(), it->second.size());
}

class FakeTileService final : public v1::TileService::Service {
public:
    // Set before the server starts. on_open: a non-OK status ends a new stream at once with it.
    // respond: called on the stream's handler thread for each batch; false ends the stream.
    std::function<grpc::Status(int stream_number)> on_open;
    std::function<bool(const v1::TileBatch&, Stream&)> respond = default_respond;

    grpc::Status StreamTiles(grpc::ServerContext* ctx, Stream* stream) override {
        int number = 0;
        {
            std::lock_guard lk(mu_);
            number = ++streams_;
            auth_ = metadata(*ctx, "authorization");
        }
        cv_.notify_all();
        if (on_open) {
            grpc::Status st = on_open(number);
            if (!st.ok()) return st;
        }
        v1::TileBatch batch;
        while (stream->Read(&batch)) {
            {
                std::lock_guard lk(mu_);
                batches_.push_back(batch);
            }
            cv_.notify_all();
            if (!respond(batch, *stream)) break;
        }
        return grpc::Status::OK;
    }

    grpc::Status ListStores(grpc::ServerContext* ctx, const v1::ListStoresRequest*, v1::ListStoresReply* reply) override {
        record_unary(*ctx);
        reply->add_stores()->set_name("alpha");
        reply->add_stores()->set_name("beta");
        return grpc::Status::OK;
    }

    grpc::Status GetStore(grpc::ServerContext* ctx, const v1::GetStoreRequest* request, v1::StoreMetadata* reply) override {
        record_unary(*ctx);
        if (request->name() != "alpha") return {grpc::StatusCode::NOT_FOUND, "no store named " + request->name()};
        reply->set_name("alpha");
        reply->set_width(4096);
        reply->set_version(99);
        return grpc::Status::OK;
    }

    grpc::Status GetStats(grpc::ServerContext* ctx, const v1::GetStatsRequest*, v1::ServerStats* reply) override {
        record_unary(*ctx);
        reply->set_viewers(1);
        reply->set_tiles_sent(12345);
        return grpc::Status::OK;
    }

    // Waits until pred() (called under the lock) holds; false on timeout.
    template <class Pred>
    bool wait(Pred pred, std::chrono::milliseconds timeout = 10s) {
        std::unique_lock lk(mu_);
        return cv_.wait_for(lk, timeout, [&] { return pred(); });
    }
    bool wait_for_frame(std::uint64_t frame, std::chrono::milliseconds timeout = 10s) {
        return wait([&] { return !batches_.empty() && batches_.back().frame() == frame; }, timeout);
    }
    std::vector<v1::TileBatch> batches() const {
        std::lock_guard lk(mu_);
        return batches_;
    }
    std::string auth() const {
        std::lock_guard lk(mu_);
        return auth_;
    }
    std::string unary_auth() const {
        std::lock_guard lk(mu_);
        return unary_auth_;
    }
    int streams() const {
        std::lock_guard lk(mu_);
        return streams_;
    }

private:
    void record_unary(const grpc::ServerContext& ctx) {
        std::lock_guard lk(mu_);
        unary_auth_ = metadata(ctx, "authorization");
    }

    mutable std::mutex mu_;
    std::condition_variable cv_;
    std::vector<v1::TileBatch> batches_;
    std::string auth_;
    std::string unary_auth_;
    int streams_ = 0;
};

// A gRPC sync server on 127.0.0.1 (port 0: any free port) serving one FakeTileService.
class FakeServer {
public:
    explicit FakeServer(FakeTileService& service, int port = 0,
                        std::shared_ptr<grpc::ServerCredentials> creds = grpc::InsecureServerCredentials()) {
        grpc::ServerBuilder builder;
        builder.AddListeningPort("127.0.0.1:" + std::to_string(port), creds, &port_);
        builder.RegisterService(&service);
        server_ = builder.BuildAndStart();
    }
    ~FakeServer() { stop(); }
    FakeServer(const FakeServer&) = delete;
    FakeServer& operator=(const FakeServer&) = delete;

    bool ok() const { return server_ != nullptr && port_ > 0; }
    int port() const { return port_; }
    std::string target() const { return "127.0.0.1:" + std::to_string(port_); }
    // Cancels every call at once and waits for the handlers to return.
    void stop() {
        if (!server_) return;
        server_->Shutdown(std::chrono::system_clock::now());
        server_->Wait();
        server_.reset();
    }

private:
    int port_ = 0;
    std::unique_ptr<grpc::Server> server_;
};

template <class Pred>
bool eventually(Pred pred, std::chrono::milliseconds timeout = 10s) {
    const auto deadline = Clock::now() + timeout;
    while (!pred()) {
        if (Clock::now() >= deadline) return false;
        std::this_thread::sleep_for(2ms);
    }
    return true;
}

TileStreamOptions fast_options(const std::string& target) {
    TileStreamOptions o;
    o.target = target;
    o.backoff_initial = 20ms;
    o.backoff_max = 200ms;
    o.connect_timeout = 500ms;
    o.seed = 7;
    return o;
}

std::vector<TileRequest> requests(std::uint64_t frame, int n) {
    std::vector<TileRequest> out;
    for (int i = 0; i < n; ++i)
        out.push_back({i % 2 == 0 ? "alpha" : "beta", static_cast<std::uint32_t>(frame % 8),
                       static_cast<std::uint32_t>(i), static_cast<std::uint32_t>(i + 1), float(n - i)});
    return out;
}

// Polls until `count` tiles have arrived (or the timeout passes).
std::vector<ReceivedTile> collect(TileStreamClient& client, std::size_t count, std::vector<BatchAckInfo>* acks = nullptr,
                                  std::chrono::milliseconds timeout = 10s) {
    std::vector<ReceivedTile> tiles;
    const auto deadline = Clock::now() + timeout;
    while (tiles.size() < count && Clock::now() < deadline) {
        client.wait_for_data(50ms);
        client.poll(tiles, acks);
    }
    return tiles;
}

// Destroys the client; returns how long that took.
long destroy_ms(std::unique_ptr<TileStreamClient>& client) {
    const auto t0 = Clock::now();
    client.reset();
    return static_cast<long>(std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - t0).count());
}

// A port nothing listens on: bound by a fake server, then released.
int unused_port() {
    FakeTileService service;
    FakeServer server(service);
    return server.port();
}

// (a) A batch goes out; its ack and every tile come back with the fields the server set.
TEST(TileStreamClient, BatchRepliesArriveWithTheirFields) {
    FakeTileService service;
    FakeServer server(service);
    ASSERT_TRUE(server.ok());
    auto client = TileStreamClient::create(fast_options(server.target()));
    client->send_batch(5, requests(5, 6), 250ms);

    std::vector<BatchAckInfo> acks;
    auto tiles = collect(*client, 6, &acks);
    ASSERT_EQ(tiles.size(), 6u) << client->last_error();
    ASSERT_EQ(acks.size(), 1u);
    EXPECT_EQ(acks[0].frame, 5u);
    EXPECT_EQ(acks[0].status, tessera::TileStatus::ok);
    EXPECT_EQ(acks[0].admitted, 6u);
    EXPECT_EQ(acks[0].cancelled, 3u);

    const auto batches = service.batches();
    ASSERT_EQ(batches.size(), 1u);
    EXPECT_EQ(batches[0].frame(), 5u);
    EXPECT_EQ(batches[0].deadline_ms(), 250u);
    ASSERT_EQ(batches[0].stores_size(), 2);  // store names are sent once, by index
    EXPECT_EQ(batches[0].stores(0), "alpha");
    EXPECT_EQ(batches[0].stores(1), "beta");
    ASSERT_EQ(batches[0].requests_size(), 6);
    EXPECT_EQ(batches[0].requests(1).store(), 1u);
    EXPECT_FLOAT_EQ(batches[0].requests(1).priority(), 5.0f);

    const auto before = Clock::now();
    for (std::size_t i = 0; i < tiles.size(); ++i) {
        const ReceivedTile& t = tiles[i];
        EXPECT_EQ(t.store, i % 2 == 0 ? "alpha" : "beta");
        EXPECT_EQ(t.key.level, 5u);
        EXPECT_EQ(t.key.x, i);
        EXPECT_EQ(t.key.y, i + 1);
        EXPECT_EQ(t.store_version, 0x1234567890abcdefULL);
        EXPECT_EQ(t.frame, 5u);
        EXPECT_EQ(t.status, tessera::TileStatus::ok);
        EXPECT_TRUE(t.message.empty());
        EXPECT_EQ(t.data.kind, tessera::TileKind::present);
        EXPECT_EQ(t.data.codec, tessera::Codec::raw);
        EXPECT_EQ(t.data.payload, make_payload(5, t.key.x, t.key.y, 100));
        EXPECT_EQ(t.data.checksum, XXH3_64bits(t.data.payload.data(), t.data.payload.size()));
        EXPECT_EQ(t.server_micros, 77u);
        EXPECT_LE(t.received, before);
    }
    EXPECT_EQ(client->state(), ConnectionState::connected);
    // The writer counts a batch once Write returns, which may be after the replies arrive.
    EXPECT_TRUE(eventually([&] { return client->stats().batches_sent == 1; }));
    const auto stats = client->stats();
    EXPECT_EQ(stats.connects, 1u);
    EXPECT_EQ(stats.reconnects, 0u);
    EXPECT_EQ(stats.batches_sent, 1u);
    EXPECT_EQ(stats.acks_received, 1u);
    EXPECT_EQ(stats.tiles_received, 6u);
    EXPECT_EQ(stats.bytes_received, 600u);
    EXPECT_EQ(stats.checksum_failures, 0u);
    EXPECT_EQ(stats.buffered_items, 0u);
    EXPECT_EQ(stats.buffered_bytes, 0u);
}

// Protocol revision 1: the client asks for it, and several tiles in one message (ServerMessage.tiles)
// come out as separate tiles, in order, each with its own bytes; an old-style single tile still works.
TEST(TileStreamClient, SeveralTilesPerMessageAreSplit) {
    FakeTileService service;
    service.respond = [](const v1::TileBatch& batch, Stream& stream) {
        v1::ServerMessage ack;
        ack.mutable_ack()->set_frame(batch.frame());
        if (!stream.Write(ack)) return false;
        v1::ServerMessage many;
        for (int i = 0; i + 1 < batch.requests_size(); ++i)
            *many.mutable_tiles()->add_tiles() = make_tile(batch, batch.requests(i), 1000 + std::size_t(i) * 37).tile();
        if (!stream.Write(many)) return false;
        const auto& last = batch.requests(batch.requests_size() - 1);
        return stream.Write(make_tile(batch, last, 1000 + std::size_t(batch.requests_size() - 1) * 37));
    };
    FakeServer server(service);
    ASSERT_TRUE(server.ok());
    auto client = TileStreamClient::create(fast_options(server.target()));
    client->send_batch(3, requests(3, 7));
    auto tiles = collect(*client, 7);
    ASSERT_EQ(tiles.size(), 7u) << client->last_error();
    ASSERT_EQ(service.batches().size(), 1u);
    EXPECT_EQ(service.batches()[0].protocol_revision(), 1u);
    for (std::size_t i = 0; i < tiles.size(); ++i) {
        EXPECT_EQ(tiles[i].key.x, i);
        EXPECT_EQ(tiles[i].key.y, i + 1);
        EXPECT_EQ(tiles[i].store, i % 2 == 0 ? "alpha" : "beta");
        EXPECT_EQ(tiles[i].status, tessera::TileStatus::ok);
        EXPECT_EQ(tiles[i].data.payload, make_payload(3, tiles[i].key.x, tiles[i].key.y, 1000 + i * 37));
        EXPECT_EQ(tiles[i].server_micros, 77u);
    }
    EXPECT_EQ(client->stats().tiles_received, 7u);
    EXPECT_EQ(client->stats().checksum_failures, 0u);
}

// poll() honours max, keeps arrival order, and drops acks when none are wanted.
TEST(TileStreamClient, PollMovesAtMostMaxInArrivalOrder) {
    FakeTileService service;
    FakeServer server(service);
    ASSERT_TRUE(server.ok());
    auto client = TileStreamClient::create(fast_options(server.target()));
    client->send_batch(1, requests(1, 4));
    ASSERT_TRUE(eventually([&] { return client->stats().buffered_items == 5; }));  // ack + 4 tiles
    std::vector<ReceivedTile> tiles;
    std::vector<BatchAckInfo> acks;
    EXPECT_EQ(client->poll(tiles, &acks, 1), 1u);  // the ack comes first
    EXPECT_EQ(acks.size(), 1u);
    EXPECT_TRUE(tiles.empty());
    EXPECT_EQ(client->poll(tiles, &acks, 2), 2u);
    ASSERT_EQ(tiles.size(), 2u);
    EXPECT_EQ(tiles[0].key.x, 0u);
    EXPECT_EQ(tiles[1].key.x, 1u);
    EXPECT_EQ(client->poll(tiles), 2u);
    EXPECT_EQ(client->poll(tiles), 0u);
    EXPECT_FALSE(client->wait_for_data(10ms));

    client->send_batch(2, requests(2, 1));
    ASSERT_TRUE(eventually([&] { return client->stats().buffered_items == 2; }));
    tiles.clear();
    EXPECT_EQ(client->poll(tiles), 1u);  // the ack is discarded uncounted
    EXPECT_EQ(tiles.size(), 1u);
    EXPECT_EQ(client->stats().buffered_bytes, 0u);
}

// A batch says how many tile replies the application has polled, not how many the client holds:
// tiles received but not yet polled are still on their way to the application, which lists them
// again, and the server must not send them twice (docs/protocol.md, "Re-listed tiles").
TEST(TileStreamClient, RepliesReceivedCountsWhatWasPolled) {
    FakeTileService service;
    FakeServer server(service);
    ASSERT_TRUE(server.ok());
    auto client = TileStreamClient::create(fast_options(server.target()));
    client->send_batch(1, requests(1, 4));
    ASSERT_TRUE(eventually([&] { return client->stats().buffered_items == 5; }));  // ack + 4 tiles, unpolled
    client->send_batch(2, requests(1, 4));
    ASSERT_TRUE(eventually([&] { return service.batches().size() == 2; }));
    EXPECT_EQ(service.batches()[1].replies_received(), 0u) << "tiles not yet polled were counted as read";
    ASSERT_TRUE(eventually([&] { return client->stats().buffered_items == 10; }));
    std::vector<ReceivedTile> tiles;
    std::vector<BatchAckInfo> acks;
    EXPECT_EQ(client->poll(tiles, &acks, 4), 4u);  // the first ack and three tiles
    client->send_batch(3, requests(1, 4));
    ASSERT_TRUE(eventually([&] { return service.batches().size() == 3; }));
    EXPECT_EQ(service.batches()[2].replies_received(), 3u);
}

// (b) Two batches in quick succession: the server sees the newest (maybe the first too, never after).
TEST(TileStreamClient, NewestBatchWins) {
    FakeTileService service;
    FakeServer server(service);
    ASSERT_TRUE(server.ok());
    auto client = TileStreamClient::create(fast_options(server.target()));
    client->send_batch(1, requests(1, 3));
    client->send_batch(2, requests(2, 2));
    ASSERT_TRUE(service.wait_for_frame(2)) << client->last_error();
    const auto batches = service.batches();
    ASSERT_LE(batches.size(), 2u);
    EXPECT_EQ(batches.back().frame(), 2u);
    EXPECT_EQ(batches.back().requests_size(), 2);
    if (batches.size() == 2) {
        EXPECT_EQ(batches[0].frame(), 1u);
    } else {
        EXPECT_EQ(client->stats().batches_superseded, 1u);  // sent before the stream opened
    }

    // Once connected, a burst still ends with the newest.
    ASSERT_TRUE(eventually([&] { return client->state() == ConnectionState::connected; }));
    for (std::uint64_t f = 3; f <= 50; ++f) client->send_batch(f, requests(f, 2));
    ASSERT_TRUE(service.wait_for_frame(50)) << client->last_error();
    std::uint64_t prev = 0;
    for (const auto& b : service.batches()) {
        EXPECT_GT(b.frame(), prev);  // never an older batch after a newer one
        prev = b.frame();
    }
}

// The next batch goes out once the last one is acknowledged, or 250 ms after it was written: a
// server that holds batches while it is behind paces the viewer (docs/protocol.md, "Held
// batches"), and a server that never acks still gets the newest batch four times a second.
TEST(TileStreamClient, TheNextBatchWaitsForTheLastOnesAck) {
    FakeTileService service;
    std::atomic<bool> acking{false};
    service.respond = [&](const v1::TileBatch& batch, Stream& stream) {
        return !acking.load() || default_respond(batch, stream);
    };
    FakeServer server(service);
    ASSERT_TRUE(server.ok());
    auto client = TileStreamClient::create(fast_options(server.target()));
    ASSERT_TRUE(eventually([&] { return client->state() == ConnectionState::connected; }));
    // 60 batches over 600 ms, none acknowledged: the first, then one per 250 ms.
    for (std::uint64_t f = 1; f <= 60; ++f) {
        client->send_batch(f, requests(f, 2));
        std::this_thread::sleep_for(10ms);
    }
    const std::size_t unacked = service.batches().size();
    EXPECT_GE(unacked, 2u);
    EXPECT_LE(unacked, 5u) << "batches went out without waiting for the previous one's ack";
    ASSERT_TRUE(service.wait_for_frame(60, 2s)) << "the newest batch never went out";

    // Acknowledged at once: each batch goes out as it comes.
    acking = true;
    client->send_batch(61, requests(61, 2));  // its ack lets the next go at once
    ASSERT_TRUE(service.wait_for_frame(61, 2s));
    const std::size_t before = service.batches().size();
    std::vector<ReceivedTile> tiles;
    for (std::uint64_t f = 62; f <= 81; ++f) {
        client->send_batch(f, requests(f, 2));
        std::this_thread::sleep_for(10ms);
        client->poll(tiles, nullptr, 1000);  // as a viewer does every frame: the acks are read
    }
    ASSERT_TRUE(service.wait_for_frame(81, 2s));
    EXPECT_GE(service.batches().size() - before, 15u) << "acknowledged batches were held back";
}

// (c) The server goes away: the client backs off, finds the new server on the same port, and
// resends its newest batch there.
TEST(TileStreamClient, ReconnectsAndResendsTheNewestBatch) {
    FakeTileService first;
    auto server = std::make_unique<FakeServer>(first);
    ASSERT_TRUE(server->ok());
    const int port = server->port();
    auto client = TileStreamClient::create(fast_options(server->target()));
    client->send_batch(7, requests(7, 3));
    ASSERT_EQ(collect(*client, 3).size(), 3u) << client->last_error();
    ASSERT_TRUE(first.wait_for_frame(7));

    server->stop();
    ASSERT_TRUE(eventually([&] {
        const auto s = client->stats();
        return s.stream_errors >= 1 && s.backoffs >= 1 && client->state() != ConnectionState::connected;
    })) << to_string(client->state());
    EXPECT_FALSE(client->last_error().empty());
    std::this_thread::sleep_for(300ms);  // a few failed attempts while nothing listens
    EXPECT_NE(client->state(), ConnectionState::connected);
    EXPECT_EQ(client->stats().reconnects, 0u);

    FakeTileService second;
    server = std::make_unique<FakeServer>(second, port);
    ASSERT_TRUE(server->ok());
    ASSERT_TRUE(second.wait_for_frame(7)) << client->last_error();  // resent without a new send_batch
    EXPECT_EQ(second.batches().size(), 1u);
    auto tiles = collect(*client, 3);
    ASSERT_EQ(tiles.size(), 3u);
    EXPECT_EQ(tiles[0].frame, 7u);
    EXPECT_EQ(client->state(), ConnectionState::connected);
    EXPECT_TRUE(eventually([&] { return client->stats().batches_sent == 2; }));
    const auto stats = client->stats();
    EXPECT_EQ(stats.connects, 2u);
    EXPECT_EQ(stats.reconnects, 1u);
    EXPECT_EQ(stats.batches_sent, 2u);

    client->send_batch(8, requests(8, 1));
    EXPECT_TRUE(second.wait_for_frame(8));
}

// A server that is full (RESOURCE_EXHAUSTED) or draining (UNAVAILABLE) is retried with backoff.
TEST(TileStreamClient, RetriesRefusedStreams) {
    FakeTileService service;
    service.on_open = [](int n) {
        if (n == 1) return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED, "too many viewers");
        if (n == 2) return grpc::Status(grpc::StatusCode::UNAVAILABLE, "draining");
        return grpc::Status::OK;
    };
    FakeServer server(service);
    ASSERT_TRUE(server.ok());
    auto client = TileStreamClient::create(fast_options(server.target()));
    client->send_batch(3, requests(3, 2));
    ASSERT_EQ(collect(*client, 2).size(), 2u) << client->last_error();
    EXPECT_EQ(service.streams(), 3);
    const auto stats = client->stats();
    EXPECT_EQ(stats.stream_errors, 2u);
    EXPECT_EQ(stats.backoffs, 2u);
    EXPECT_EQ(client->last_error(), "UNAVAILABLE: draining");
}

// (d) A payload that does not match its checksum is delivered as DATA_LOSS, payload dropped.
TEST(TileStreamClient, ChecksumMismatchIsDataLoss) {
    FakeTileService service;
    service.respond = [](const v1::TileBatch& batch, Stream& stream) {
        for (const v1::TileRequest& r : batch.requests()) {
            v1::ServerMessage msg = make_tile(batch, r, 64);
            if (r.x() == 1) msg.mutable_tile()->set_checksum(msg.tile().checksum() ^ 1);
            if (r.x() == 2) {  // an error reply: no payload, nothing to verify
                msg.mutable_tile()->clear_payload();
                msg.mutable_tile()->set_checksum(0);
                msg.mutable_tile()->set_status(v1::TILE_OUT_OF_RANGE);
                msg.mutable_tile()->set_message("outside the store");
            }
            if (!stream.Write(msg)) return false;
        }
        return true;
    };
    FakeServer server(service);
    ASSERT_TRUE(server.ok());
    auto client = TileStreamClient::create(fast_options(server.target()));
    client->send_batch(1, requests(1, 3));
    auto tiles = collect(*client, 3);
    ASSERT_EQ(tiles.size(), 3u) << client->last_error();
    EXPECT_EQ(tiles[0].status, tessera::TileStatus::ok);
    EXPECT_EQ(tiles[0].data.payload.size(), 64u);
    EXPECT_EQ(tiles[1].status, tessera::TileStatus::data_loss);
    EXPECT_EQ(tiles[1].message, "checksum mismatch in transit");
    EXPECT_TRUE(tiles[1].data.payload.empty());
    EXPECT_EQ(tiles[1].key.x, 1u);
    EXPECT_EQ(tiles[2].status, tessera::TileStatus::out_of_range);
    EXPECT_EQ(tiles[2].message, "outside the store");
    EXPECT_EQ(client->stats().checksum_failures, 1u);
}

// (e) The auth token reaches the server as a bearer token, on the stream and on unary calls.
TEST(TileStreamClient, AuthTokenIsSentAsBearer) {
    FakeTileService service;
    FakeServer server(service);
    ASSERT_TRUE(server.ok());
    auto options = fast_options(server.target());
    options.auth_token = "s3cret-token";
    auto client = TileStreamClient::create(options);
    client->send_batch(1, requests(1, 1));
    ASSERT_TRUE(service.wait_for_frame(1)) << client->last_error();
    EXPECT_EQ(service.auth(), "Bearer s3cret-token");
    ASSERT_TRUE(client->list_stores(5s).ok());
    EXPECT_EQ(service.unary_auth(), "Bearer s3cret-token");

    auto anonymous = TileStreamClient::create(fast_options(server.target()));
    anonymous->send_batch(2, requests(2, 1));
    ASSERT_TRUE(service.wait_for_frame(2));
    EXPECT_EQ(service.auth(), "");
}

// (f) Destruction is prompt while the server is down: connecting, backing off, or mid-stream.
TEST(TileStreamClient, DestructionIsPromptWhenTheServerIsDown) {
    const int port = unused_port();
    {
        auto client = TileStreamClient::create(fast_options("127.0.0.1:" + std::to_string(port)));
        client->send_batch(1, requests(1, 2));
        std::this_thread::sleep_for(150ms);
        EXPECT_NE(client->state(), ConnectionState::connected);
        EXPECT_LT(destroy_ms(client), 1000);
    }
    {
        auto options = fast_options("127.0.0.1:" + std::to_string(port));
        options.connect_timeout = 50ms;
        options.backoff_initial = options.backoff_max = 30s;
        auto client = TileStreamClient::create(options);
        ASSERT_TRUE(eventually([&] { return client->state() == ConnectionState::backing_off; }));
        EXPECT_LT(destroy_ms(client), 1000);
    }
    {
        // The default connect timeout (5 s) must not hold destruction up either.
        TileStreamOptions options;
        options.target = "127.0.0.1:" + std::to_string(port);
        auto client = TileStreamClient::create(options);
        std::this_thread::sleep_for(100ms);
        EXPECT_LT(destroy_ms(client), 1000);
    }
    {
        // Connected, the server never answers and never reads past the first batch.
        FakeTileService service;
        service.respond = [](const v1::TileBatch&, Stream&) {
            std::this_thread::sleep_for(1500ms);
            return true;
        };
        FakeServer server(service);
        ASSERT_TRUE(server.ok());
        auto client = TileStreamClient::create(fast_options(server.target()));
        client->send_batch(1, requests(1, 2));
        ASSERT_TRUE(service.wait_for_frame(1));
        EXPECT_LT(destroy_ms(client), 1000);
    }
}

// (g) With a tiny buffer bound and a server that floods, the client never buffers more than the
// bound plus one message, and every tile still arrives, in order.
TEST(TileStreamClient, BufferedBytesStayBounded) {
    constexpr int kTiles = 300;
    constexpr std::size_t kPayload = 16 << 10;
    constexpr std::size_t kBound = 40 << 10;
    std::atomic<int> written{0};
    FakeTileService service;
    service.respond = [&](const v1::TileBatch& batch, Stream& stream) {
        v1::TileRequest r;
        for (int i = 0; i < kTiles; ++i) {
            r.set_x(static_cast<std::uint32_t>(i));
            if (!stream.Write(make_tile(batch, r, kPayload))) return false;
            written.fetch_add(1);
        }
        return true;
    };
    FakeServer server(service);
    ASSERT_TRUE(server.ok());
    auto options = fast_options(server.target());
    options.max_buffered_bytes = kBound;
    auto client = TileStreamClient::create(options);
    client->send_batch(1, {{"alpha", 0, 0, 0, 1.0f}});

    // Nobody polls for a while: the reader stops at the bound.
    ASSERT_TRUE(eventually([&] { return client->stats().buffered_bytes > kBound; }));
    std::this_thread::sleep_for(200ms);
    auto stats = client->stats();
    EXPECT_LE(stats.buffered_items, kBound / kPayload + 1);
    EXPECT_LE(stats.peak_buffered_bytes, kBound + kPayload + 1024);

    std::vector<ReceivedTile> tiles;
    const auto deadline = Clock::now() + 20s;
    while (tiles.size() < std::size_t(kTiles) && Clock::now() < deadline) {
        client->wait_for_data(50ms);
        client->poll(tiles, nullptr, 1);
        EXPECT_LE(client->stats().buffered_bytes, kBound + kPayload + 1024);
    }
    ASSERT_EQ(tiles.size(), std::size_t(kTiles));
    for (int i = 0; i < kTiles; ++i) {
        EXPECT_EQ(tiles[i].key.x, std::uint32_t(i));
        EXPECT_EQ(tiles[i].status, tessera::TileStatus::ok);
    }
    stats = client->stats();
    EXPECT_LE(stats.peak_buffered_bytes, kBound + kPayload + 1024);
    EXPECT_GT(stats.peak_buffered_bytes, kBound);
    EXPECT_EQ(stats.bytes_received, kTiles * kPayload);
    // The server counts a tile once its Write returns, which can be after the client has it.
    EXPECT_TRUE(eventually([&] { return written.load() == kTiles; })) << written.load() << " of " << kTiles;
}

// TLS: the client verifies the server against the given roots, with a name override.
TEST(TileStreamClient, ConnectsOverTls) {
    grpc::SslServerCredentialsOptions ssl;
    ssl.pem_key_cert_pairs.push_back({kTestKey, kTestCert});
    FakeTileService service;
    FakeServer server(service, 0, grpc::SslServerCredentials(ssl));
    ASSERT_TRUE(server.ok());
    auto options = fast_options(server.target());
    options.tls_root_certs_pem = kTestCert;
    options.tls_server_name = "localhost";
    auto client = TileStreamClient::create(options);
    client->send_batch(4, requests(4, 2));
    ASSERT_EQ(collect(*client, 2).size(), 2u) << client->last_error();
    ASSERT_TRUE(client->get_store("alpha", 5s).ok());

    // Plaintext against a TLS server never connects.
    auto plain = TileStreamClient::create(fast_options(server.target()));
    plain->send_batch(1, requests(1, 1));
    EXPECT_FALSE(plain->wait_for_data(500ms));
    EXPECT_EQ(plain->stats().connects, 0u);
}

// Unary helpers: results, NOT_FOUND as not_found, an unreachable server as io_error in time.
TEST(TileStreamClient, UnaryCalls) {
    FakeTileService service;
    FakeServer server(service);
    ASSERT_TRUE(server.ok());
    auto client = TileStreamClient::create(fast_options(server.target()));

    auto stores = client->list_stores(5s);
    ASSERT_TRUE(stores.ok()) << stores.error().message;
    ASSERT_EQ(stores->size(), 2u);
    EXPECT_EQ((*stores)[0].name, "alpha");
    EXPECT_EQ((*stores)[1].name, "beta");

    auto alpha = client->get_store("alpha", 5s);
    ASSERT_TRUE(alpha.ok());
    EXPECT_EQ(alpha->info.width, 4096u);
    EXPECT_EQ(alpha->info.store_id, 99u);

    auto missing = client->get_store("nope", 5s);
    ASSERT_FALSE(missing.ok());
    EXPECT_EQ(missing.error().code, Errc::not_found);
    EXPECT_EQ(missing.error().message, "NOT_FOUND: no store named nope");

    auto stats = client->server_stats(5s);
    ASSERT_TRUE(stats.ok());
    EXPECT_EQ(stats->tiles_sent(), 12345u);

    auto down = TileStreamClient::create(fast_options("127.0.0.1:" + std::to_string(unused_port())));
    const auto t0 = Clock::now();
    auto result = down->list_stores(300ms);
    EXPECT_LT(Clock::now() - t0, 2s);
    ASSERT_FALSE(result.ok());
    EXPECT_EQ(result.error().code, Errc::io_error);
    EXPECT_FALSE(result.error().message.empty());
}

}  // namespace
}  // namespace tessera::client
