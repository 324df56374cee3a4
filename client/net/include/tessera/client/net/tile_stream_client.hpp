#pragma once
// TileStreamClient: one viewer's gRPC connection to a Tessera server, shared by the viewer and the
// load tester. It connects in the background, sends request batches (each replaces the last),
// receives tiles and acks into a bounded buffer the caller polls, and reconnects with
// exponential backoff (full jitter) whenever the stream ends. Nothing here blocks on the network
// except the unary helpers, which take a timeout. See docs/protocol.md for the wire protocol.
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "tessera/result.hpp"
#include "tessera/storage/types.hpp"
#include "tessera/tile.hpp"

namespace tessera::v1 {
class ServerStats;  // tessera.proto's message: include "tessera.pb.h" to use server_stats()
}

namespace tessera::client {

struct TileStreamOptions {
    // host:port; several servers as a list "10.0.0.1:50051,10.0.0.2:50051" (IP addresses), or
    // any gRPC target ("dns:///tiles.example:50051", whose every address is a server). Streams
    // are spread over the servers (round robin) and a stream whose server dies reconnects to
    // another, re-sending its wanted set.
    std::string target;
    std::string auth_token;          // sent as "authorization: Bearer <token>" when non-empty
    std::string tls_root_certs_pem;  // non-empty: TLS, verifying the server against these roots
    std::string tls_server_name;     // override for the TLS name check (tests: "localhost")
    // Reconnect backoff: exponential with full jitter (uniform in [0, min(max, initial * 2^n)]).
    // The channel's own subchannel backoff uses the same bounds.
    std::chrono::milliseconds backoff_initial{100};
    std::chrono::milliseconds backoff_max{5000};
    // How long one connection attempt waits for the channel to become ready before backing off.
    std::chrono::milliseconds connect_timeout{5000};
    // Received replies not yet polled (payload and strings plus a fixed per-item overhead). Beyond
    // it, reading pauses and gRPC flow control pushes back to the server. The buffer can exceed
    // the bound by at most one message.
    std::size_t max_buffered_bytes = std::size_t(64) << 20;
    std::uint64_t seed = 0;  // jitter RNG seed (0: random)
};

struct TileRequest {
    std::string store;
    TileKey key;
    float priority = 0.0f;  // higher is served first; must be finite
};

// A TileReply decoded into plain C++.
struct ReceivedTile {
    std::string store;
    TileKey key;
    std::uint64_t store_version = 0;
    std::uint64_t frame = 0;
    TileStatus status = TileStatus::ok;
    std::string message;  // set when status is not ok
    // data.payload is verified against data.checksum (XXH3-64) when status is ok and it is
    // non-empty; a mismatch is delivered as data_loss "checksum mismatch in transit" with the
    // payload cleared. data.codec means something for present tiles only.
    TileData data;
    std::uint32_t server_micros = 0;
    std::chrono::steady_clock::time_point received;  // when the client read it off the stream
};

// A BatchAck: the server's answer to one batch, sent before any of that batch's tiles.
struct BatchAckInfo {
    std::uint64_t frame = 0;
    TileStatus status = TileStatus::ok;
    std::string message;
    std::uint32_t admitted = 0;
    std::uint32_t refused = 0;
    std::uint32_t invalid = 0;
    std::uint32_t already_queued = 0;
    std::uint32_t cancelled = 0;
    // The server replaced this batch with a newer one before applying it (docs/protocol.md,
    // "Held batches"); the newer one has its own ack.
    bool superseded = false;
};

// A store as the server describes it (StoreMetadata): info.store_id is its version.
struct RemoteStore {
    std::string name;
    storage::StoreInfo info;
    bool has_scene = false;  // a scene travels with the store (get_scene)
};

enum class ConnectionState { connecting, connected, backing_off, closed };
const char* to_string(ConnectionState s);

struct TileStreamStats {
    std::uint64_t connects = 0;            // streams opened
    std::uint64_t reconnects = 0;          // streams opened after the first
    std::uint64_t connect_failures = 0;    // attempts where the channel did not become ready in time
    std::uint64_t stream_errors = 0;       // streams that ended while the client was not closing
    // Of those, streams the server ended with RESOURCE_EXHAUSTED: it refused the viewer (more
    // than its --max-viewers streams) or a message over its limit.
    std::uint64_t streams_refused = 0;
    std::uint64_t backoffs = 0;            // times the client entered backing_off
    std::uint64_t batches_sent = 0;        // batches written to a stream (resends included)
    std::uint64_t batches_superseded = 0;  // batches replaced by a newer one before being written
    std::uint64_t acks_received = 0;
    std::uint64_t tiles_received = 0;
    std::uint64_t bytes_received = 0;      // tile payload bytes
    std::uint64_t checksum_failures = 0;   // payloads that failed XXH3-64 (delivered as DATA_LOSS)
    std::size_t buffered_items = 0;        // tiles and acks waiting to be polled
    std::size_t buffered_bytes = 0;        // their accounted size (see max_buffered_bytes)
    std::size_t peak_buffered_bytes = 0;
};

class TileStreamClient {
public:
    // Starts connecting in the background; never blocks.
    static std::unique_ptr<TileStreamClient> create(TileStreamOptions options);
    ~TileStreamClient();  // cancels the call and joins the threads; prompt even when unreachable
    TileStreamClient(const TileStreamClient&) = delete;
    TileStreamClient& operator=(const TileStreamClient&) = delete;

    // Replaces the request set. Never blocks on the network: if a batch is waiting to be written,
    // it is replaced by this one (only the newest matters). After a reconnect the newest batch is
    // sent again. deadline 0: the server's default.
    void send_batch(std::uint64_t frame, std::vector<TileRequest> requests,
                    std::chrono::milliseconds deadline = {});

    // Non-blocking: moves up to `max` received items, in arrival order, into `tiles` and `acks`
    // (appending); returns how many were moved. With acks == nullptr acks are discarded uncounted.
    std::size_t poll(std::vector<ReceivedTile>& tiles, std::vector<BatchAckInfo>* acks = nullptr,
                     std::size_t max = SIZE_MAX);
    // Waits up to `timeout` for something to poll; true when there is.
    bool wait_for_data(std::chrono::milliseconds timeout);

    ConnectionState state() const;
    std::string last_error() const;  // the last stream error ("UNAVAILABLE: message"), or empty
    TileStreamStats stats() const;

    // Unary calls with a timeout. Errors: not_found (no such store), io_error (unreachable,
    // deadline, server failure), resource_exhausted, invalid_argument (bad request or credentials),
    // unsupported (server lacks the call); messages carry the gRPC status name.
    Result<std::vector<RemoteStore>> list_stores(std::chrono::milliseconds timeout);
    Result<RemoteStore> get_store(const std::string& name, std::chrono::milliseconds timeout);
    // The scene that travels with a store (an atlas OBJ's text, docs/atlas.md), read a piece at a
    // time, each piece with `timeout`; not_found when the store has none. A store replaced while
    // its scene is read fails (io_error): the scene would not match the store bound before.
    Result<std::string> get_scene(const std::string& name, std::uint64_t store_version, std::chrono::milliseconds timeout);
    Result<v1::ServerStats> server_stats(std::chrono::milliseconds timeout);  // needs tessera.pb.h

    class Impl;

private:
    explicit TileStreamClient(std::unique_ptr<Impl> impl);
    std::unique_ptr<Impl> impl_;
};

}  // namespace tessera::client
