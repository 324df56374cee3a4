// TileStreamClient: the gRPC StreamTiles connection shared by the viewer and the load tester.
//
// Threads (all owned by Impl, bounded, joined before Impl is destroyed):
//   - the session thread (one per client, for its whole life): connects, opens the stream, then
//     is the stream's reader (blocking Read loop); when the stream ends it takes the final status,
//     backs off and reconnects. It is the only thread that creates or destroys a ClientContext.
//   - the writer thread (at most one, per open stream, owned and joined by the session thread):
//     waits for a batch newer than the last one it wrote on this stream and for the last one's
//     ack (or 250 ms: kAckWait), writes it, and half-closes (WritesDone) when the client closes.
//     Waiting for the ack paces the viewer by the server: a server that is behind holds large
//     batches (docs/protocol.md, "Held batches"), so the viewer does not build and send lists
//     60 times a second that the server would only replace unread.
// Queues (all owned by Impl, guarded by mu_):
//   - the outgoing "queue" is one slot: the newest batch. send_batch replaces it; the writer sends
//     it once per stream. Bound: one batch.
//   - the incoming queue holds replies and acks not yet polled. Bound: max_buffered_bytes (plus at
//     most one message): the reader waits before each Read while the buffer is over the bound,
//     which stops reading and lets gRPC flow control push back to the server.
#include "tessera/client/net/tile_stream_client.hpp"

#include <xxhash.h>

#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <climits>
#include <condition_variable>
#include <deque>
#include <limits>
#include <mutex>
#include <random>
#include <string_view>
#include <thread>
#include <unordered_map>
#include <utility>
#include <variant>

#include "tessera.grpc.pb.h"
#include "tessera/protocol/stream_codec.hpp"
#include "tessera/protocol/wire.hpp"

namespace tessera::client {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

const char* to_string(ConnectionState s) {
    switch (s) {
        case ConnectionState::connecting: return "connecting";
        case ConnectionState::connected: return "connected";
        case ConnectionState::backing_off: return "backing_off";
        case ConnectionState::closed: return "closed";
    }
    return "unknown";
}

namespace {

constexpr std::size_t kMaxReceiveMessageBytes = std::size_t(64) << 20;
constexpr const char* kStreamTilesMethod = "/tessera.v1.TileService/StreamTiles";
using RawStream = grpc::ClientReaderWriter<v1::TileBatch, grpc::ByteBuffer>;
// A server whose process stalls (stopped, swapped out, wedged) keeps its TCP connection open and
// sends nothing: only an unanswered HTTP/2 ping tells. Pinged every 6 s and dropped 4 s after a
// ping goes unanswered, a stream on a stalled server ends within 10 s, is counted down and moves
// to a live replica (it took 40 s). Servers accept a ping every 4 s (server.cpp).
constexpr int kKeepaliveTimeMs = 6000;
constexpr int kKeepaliveTimeoutMs = 4000;
// How often a connection attempt looks at closing_ while it waits for the channel.
constexpr milliseconds kConnectPollSlice{50};
// How long destruction lets a live stream's writer half-close before cancelling the call.
constexpr milliseconds kCloseGrace{100};
constexpr milliseconds kMaxUnaryTimeout{std::chrono::hours(24 * 365)};

const char* status_code_name(grpc::StatusCode code) {
    switch (code) {
        case grpc::StatusCode::OK: return "OK";
        case grpc::StatusCode::CANCELLED: return "CANCELLED";
        case grpc::StatusCode::UNKNOWN: return "UNKNOWN";
        case grpc::StatusCode::INVALID_ARGUMENT: return "INVALID_ARGUMENT";
        case grpc::StatusCode::DEADLINE_EXCEEDED: return "DEADLINE_EXCEEDED";
        case grpc::StatusCode::NOT_FOUND: return "NOT_FOUND";
        case grpc::StatusCode::ALREADY_EXISTS: return "ALREADY_EXISTS";
        case grpc::StatusCode::PERMISSION_DENIED: return "PERMISSION_DENIED";
        case grpc::StatusCode::RESOURCE_EXHAUSTED: return "RESOURCE_EXHAUSTED";
        case grpc::StatusCode::FAILED_PRECONDITION: return "FAILED_PRECONDITION";
        case grpc::StatusCode::ABORTED: return "ABORTED";
        case grpc::StatusCode::OUT_OF_RANGE: return "OUT_OF_RANGE";
        case grpc::StatusCode::UNIMPLEMENTED: return "UNIMPLEMENTED";
        case grpc::StatusCode::INTERNAL: return "INTERNAL";
        case grpc::StatusCode::UNAVAILABLE: return "UNAVAILABLE";
        case grpc::StatusCode::DATA_LOSS: return "DATA_LOSS";
        case grpc::StatusCode::UNAUTHENTICATED: return "UNAUTHENTICATED";
        default: return "UNKNOWN_STATUS";
    }
}

std::string describe(const grpc::Status& status) {
    std::string out = status_code_name(status.error_code());
    if (!status.error_message().empty()) {
        out += ": ";
        out += status.error_message();
    }
    return out;
}

Errc errc_of(grpc::StatusCode code) {
    switch (code) {
        case grpc::StatusCode::NOT_FOUND: return Errc::not_found;
        case grpc::StatusCode::INVALID_ARGUMENT:
        case grpc::StatusCode::FAILED_PRECONDITION:
        case grpc::StatusCode::ALREADY_EXISTS:
        case grpc::StatusCode::UNAUTHENTICATED:   // the caller's credentials are out of contract
        case grpc::StatusCode::PERMISSION_DENIED: return Errc::invalid_argument;
        case grpc::StatusCode::OUT_OF_RANGE: return Errc::out_of_range;
        case grpc::StatusCode::RESOURCE_EXHAUSTED: return Errc::resource_exhausted;
        case grpc::StatusCode::CANCELLED: return Errc::cancelled;
        case grpc::StatusCode::UNIMPLEMENTED: return Errc::unsupported;
        case grpc::StatusCode::DATA_LOSS: return Errc::corrupt;
        default: return Errc::io_error;  // UNAVAILABLE, DEADLINE_EXCEEDED, ABORTED, INTERNAL, UNKNOWN
    }
}

Error to_error(const grpc::Status& status) { return make_error(errc_of(status.error_code()), describe(status)); }

int clamp_ms(milliseconds d) {
    return static_cast<int>(std::clamp<milliseconds::rep>(d.count(), 1, std::numeric_limits<int>::max()));
}

// One polled item: a tile or an ack, with the bytes it is accounted for in the buffer.
struct Item {
    std::variant<ReceivedTile, BatchAckInfo> body;
    std::size_t bytes = 0;
    std::uint64_t stream = 0;  // the stream it came on (replies_polled_ counts the current one's)
};

std::size_t accounted_bytes(const ReceivedTile& t) {
    return sizeof(Item) + t.data.payload.size() + t.store.size() + t.message.size();
}
std::size_t accounted_bytes(const BatchAckInfo& a) { return sizeof(Item) + a.message.size(); }

// One reply of a received message; the payload is copied once, from gRPC's receive slices.
ReceivedTile decode(const protocol::ServerMessageDecoder& d, std::size_t i, Clock::time_point received) {
    const protocol::DecodedTile& r = d.tile(i);
    ReceivedTile t;
    t.store = r.store;
    t.key = r.key;
    t.store_version = r.store_version;
    t.frame = r.frame;
    t.status = protocol::from_proto(r.status);
    t.message = r.message;
    t.data.kind = protocol::reply_kind(r.kind, r.codec);
    t.data.codec = protocol::from_proto(r.codec);
    if (r.payload_size) {
        t.data.payload.resize(r.payload_size);
        d.copy_payload(i, t.data.payload.data());
    }
    t.data.checksum = r.checksum;
    t.server_micros = r.server_micros;
    t.received = received;
    return t;
}

BatchAckInfo decode(v1::BatchAck& a) {
    BatchAckInfo info;
    info.frame = a.frame();
    info.status = protocol::from_proto(a.status());
    info.message = std::move(*a.mutable_message());
    info.admitted = a.admitted();
    info.refused = a.refused();
    info.invalid = a.invalid();
    info.already_queued = a.already_queued();
    info.cancelled = a.cancelled();
    info.superseded = a.superseded();
    return info;
}

}  // namespace

namespace {

// "a:1,b:2" (IP addresses) -> "ipv4:a:1,b:2" (or ipv6:), gRPC's syntax for a fixed list; anything
// else (host:port, a target with a scheme) as it is.
std::string grpc_target(const std::string& target) {
    if (target.find(',') == std::string::npos || target.find(':') == std::string::npos || target.find("://") != std::string::npos ||
        target.starts_with("ipv4:") || target.starts_with("ipv6:"))
        return target;
    return (target.front() == '[' ? "ipv6:" : "ipv4:") + target;
}

}  // namespace

class TileStreamClient::Impl {
public:
    explicit Impl(TileStreamOptions options) : opts_(std::move(options)) {
        if (opts_.backoff_initial.count() < 1) opts_.backoff_initial = milliseconds(1);
        if (opts_.backoff_max < opts_.backoff_initial) opts_.backoff_max = opts_.backoff_initial;
        if (opts_.connect_timeout.count() < 1) opts_.connect_timeout = milliseconds(1);
        rng_.seed(opts_.seed != 0 ? opts_.seed : (std::uint64_t(std::random_device{}()) << 32) ^ std::random_device{}());

        grpc::ChannelArguments args;
        args.SetMaxReceiveMessageSize(static_cast<int>(kMaxReceiveMessageBytes));
        args.SetInt(GRPC_ARG_KEEPALIVE_TIME_MS, kKeepaliveTimeMs);
        args.SetInt(GRPC_ARG_KEEPALIVE_TIMEOUT_MS, kKeepaliveTimeoutMs);
        // The channel reconnects on its own too; keep its backoff within ours so a server that comes
        // back is found within backoff_max.
        args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, clamp_ms(opts_.backoff_initial));
        args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, clamp_ms(opts_.backoff_max));
        // One connection per client (a load tester's simulated viewers must not share one).
        args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
        // Several servers (a list, or a name with several addresses): each new stream goes to the
        // next ready one, so a stream cut by a dead server resumes on a live one.
        args.SetLoadBalancingPolicyName("round_robin");
        std::shared_ptr<grpc::ChannelCredentials> creds;
        if (!opts_.tls_root_certs_pem.empty()) {
            grpc::SslCredentialsOptions ssl;
            ssl.pem_root_certs = opts_.tls_root_certs_pem;
            creds = grpc::SslCredentials(ssl);
            if (!opts_.tls_server_name.empty()) args.SetSslTargetNameOverride(opts_.tls_server_name);
        } else {
            creds = grpc::InsecureChannelCredentials();
        }
        channel_ = grpc::CreateCustomChannel(grpc_target(opts_.target), creds, args);
        stub_ = v1::TileService::NewStub(channel_);
        session_ = std::thread([this] { run_session(); });
    }

    ~Impl() { close(); }
    Impl(const Impl&) = delete;
    Impl& operator=(const Impl&) = delete;

    void send_batch(std::uint64_t frame, std::vector<TileRequest>& requests, milliseconds deadline) {
        auto batch = std::make_shared<v1::TileBatch>();
        batch->set_frame(frame);
        batch->set_protocol_revision(protocol::kProtocolRevision);  // several tiles per message
        batch->set_deadline_ms(static_cast<std::uint32_t>(
            std::clamp<milliseconds::rep>(deadline.count(), 0, std::numeric_limits<std::uint32_t>::max())));
        std::unordered_map<std::string_view, std::uint32_t> store_index;
        batch->mutable_requests()->Reserve(static_cast<int>(std::min<std::size_t>(requests.size(), INT_MAX)));
        for (const TileRequest& r : requests) {
            auto it = store_index.find(r.store);
            if (it == store_index.end()) {
                auto index = static_cast<std::uint32_t>(batch->stores_size());
                batch->add_stores(r.store);
                it = store_index.emplace(std::string_view(r.store), index).first;
            }
            v1::TileRequest* out = batch->add_requests();
            out->set_store(it->second);
            out->set_level(r.key.level);
            out->set_x(r.key.x);
            out->set_y(r.key.y);
            out->set_priority(r.priority);
        }
        {
            std::lock_guard lk(mu_);
            // What the application has taken so far: the server tells tiles still on their way (on
            // the wire, or here unpolled, which the application lists again) from tiles asked for
            // again after they arrived.
            batch->set_replies_received(replies_polled_);
            if (batch_ && written_gen_ != batch_gen_) ++stats_.batches_superseded;
            batch_ = std::move(batch);
            ++batch_gen_;
        }
        batch_cv_.notify_all();
    }

    std::size_t poll(std::vector<ReceivedTile>& tiles, std::vector<BatchAckInfo>* acks, std::size_t max) {
        std::size_t moved = 0;
        {
            std::lock_guard lk(mu_);
            while (moved < max && !queue_.empty()) {
                Item& item = queue_.front();
                buffered_bytes_ -= item.bytes;
                if (auto* tile = std::get_if<ReceivedTile>(&item.body)) {
                    tiles.push_back(std::move(*tile));
                    ++moved;
                    if (item.stream == stream_gen_) ++replies_polled_;
                } else if (acks != nullptr) {
                    acks->push_back(std::move(std::get<BatchAckInfo>(item.body)));
                    ++moved;
                }
                queue_.pop_front();
            }
        }
        space_cv_.notify_all();
        return moved;
    }

    bool wait_for_data(milliseconds timeout) {
        std::unique_lock lk(mu_);
        data_cv_.wait_for(lk, timeout, [&] { return !queue_.empty() || closing_; });
        return !queue_.empty();
    }

    ConnectionState state() const {
        std::lock_guard lk(mu_);
        return state_;
    }

    std::string last_error() const {
        std::lock_guard lk(mu_);
        return last_error_;
    }

    TileStreamStats stats() const {
        std::lock_guard lk(mu_);
        TileStreamStats s = stats_;
        s.buffered_items = queue_.size();
        s.buffered_bytes = buffered_bytes_;
        return s;
    }

    template <class Request, class Reply, class Call>
    Result<Reply> unary(const Request& request, milliseconds timeout, Call call) {
        grpc::ClientContext ctx;
        prepare(ctx);
        // gRPC deadlines are system_clock; clamp so a huge timeout cannot overflow.
        ctx.set_deadline(std::chrono::system_clock::now() + std::clamp(timeout, milliseconds(0), kMaxUnaryTimeout));
        Reply reply;
        grpc::Status status = (stub_.get()->*call)(&ctx, request, &reply);
        if (!status.ok()) return to_error(status);
        return reply;
    }

private:
    void prepare(grpc::ClientContext& ctx) const {
        if (!opts_.auth_token.empty()) ctx.AddMetadata("authorization", "Bearer " + opts_.auth_token);
    }

    void close() {
        std::unique_lock lk(mu_);
        if (closing_) return;
        closing_ = true;
        state_ = ConnectionState::closed;
        data_cv_.notify_all();
        space_cv_.notify_all();
        batch_cv_.notify_all();
        wake_cv_.notify_all();
        // Let a live stream's writer half-close first (the server sees a clean end), then cancel
        // whatever is still in flight: a blocked Read, a stuck WritesDone, a Finish.
        if (stream_live_) wake_cv_.wait_for(lk, kCloseGrace, [&] { return half_closed_ || !stream_live_; });
        if (ctx_ != nullptr) ctx_->TryCancel();
        lk.unlock();
        if (session_.joinable()) session_.join();
    }

    bool closing() const {
        std::lock_guard lk(mu_);
        return closing_;
    }

    void set_state(ConnectionState s) {
        std::lock_guard lk(mu_);
        if (!closing_) state_ = s;
    }

    // The session thread: connect, stream, back off, forever until close().
    void run_session() {
        unsigned attempt = 0;  // consecutive attempts without a served stream
        while (!closing()) {
            set_state(ConnectionState::connecting);
            if (wait_connected()) {
                if (run_stream()) attempt = 0;
            } else {
                std::lock_guard lk(mu_);
                if (closing_) break;
                ++stats_.connect_failures;
                last_error_ = "UNAVAILABLE: could not connect to " + opts_.target + " within " +
                              std::to_string(opts_.connect_timeout.count()) + " ms";
            }
            std::unique_lock lk(mu_);
            if (closing_) break;
            state_ = ConnectionState::backing_off;
            ++stats_.backoffs;
            const milliseconds delay = backoff_delay(attempt);
            if (attempt < 63) ++attempt;
            wake_cv_.wait_for(lk, delay, [&] { return closing_; });
        }
    }

    // Full jitter: uniform in [0, min(backoff_max, backoff_initial * 2^attempt)].
    milliseconds backoff_delay(unsigned attempt) {
        milliseconds cap = opts_.backoff_initial;
        for (unsigned i = 0; i < attempt && cap < opts_.backoff_max; ++i) cap *= 2;
        cap = std::min(cap, opts_.backoff_max);
        std::uniform_int_distribution<milliseconds::rep> dist(0, cap.count());
        return milliseconds(dist(rng_));
    }

    // Waits (in slices, so close() is noticed) for the channel to be ready; false on timeout or close.
    bool wait_connected() {
        const auto deadline = Clock::now() + opts_.connect_timeout;
        grpc_connectivity_state st = channel_->GetState(/*try_to_connect=*/true);
        while (st != GRPC_CHANNEL_READY) {
            if (closing()) return false;
            const auto now = Clock::now();
            if (now >= deadline) return false;
            const auto slice = std::min(deadline, now + kConnectPollSlice);
            if (channel_->WaitForStateChange(st, std::chrono::system_clock::now() + (slice - now)))
                st = channel_->GetState(/*try_to_connect=*/true);
            else if (st == GRPC_CHANNEL_IDLE || st == GRPC_CHANNEL_TRANSIENT_FAILURE)
                st = channel_->GetState(/*try_to_connect=*/true);
        }
        return true;
    }

    // One stream, from open to Finish. Returns true when the server sent anything on it (the
    // backoff then starts over). Runs on the session thread, which is the stream's reader.
    bool run_stream() {
        auto ctx = std::make_unique<grpc::ClientContext>();
        prepare(*ctx);
        {
            std::lock_guard lk(mu_);
            if (closing_) return false;
            ctx_ = ctx.get();  // close() may TryCancel it from now on
        }
        // Replies are read raw and decoded straight from the receive slices (stream_codec.hpp).
        const grpc::internal::RpcMethod method(kStreamTilesMethod, grpc::internal::RpcMethod::BIDI_STREAMING, channel_);
        std::unique_ptr<RawStream> stream(
            grpc::internal::ClientReaderWriterFactory<v1::TileBatch, grpc::ByteBuffer>::Create(channel_.get(), method,
                                                                                                ctx.get()));
        {
            std::lock_guard lk(mu_);
            if (!closing_) state_ = ConnectionState::connected;
            ++stats_.connects;
            if (stats_.connects > 1) ++stats_.reconnects;
            written_gen_ = 0;  // the newest batch goes out again on this stream
            last_acked_ = true;
            replies_polled_ = 0;
            ++stream_gen_;
            stream_live_ = true;
            read_ended_ = false;
            half_closed_ = false;
        }
        std::thread writer([this, s = stream.get()] { run_writer(*s); });

        bool served = false;
        grpc::ByteBuffer msg;
        for (;;) {
            {
                std::unique_lock lk(mu_);
                space_cv_.wait(lk, [&] { return closing_ || buffered_bytes_ <= opts_.max_buffered_bytes; });
                if (closing_) break;
            }
            if (!stream->Read(&msg)) break;
            served = true;
            deliver(msg, Clock::now());
        }
        {
            std::lock_guard lk(mu_);
            read_ended_ = true;
        }
        batch_cv_.notify_all();
        writer.join();
        const grpc::Status status = stream->Finish();
        stream.reset();
        {
            std::lock_guard lk(mu_);
            ctx_ = nullptr;
            stream_live_ = false;
            if (!closing_) {
                ++stats_.stream_errors;
                if (status.error_code() == grpc::StatusCode::RESOURCE_EXHAUSTED) ++stats_.streams_refused;
                last_error_ = status.ok() ? std::string("OK: the server ended the stream") : describe(status);
            }
        }
        wake_cv_.notify_all();
        return served;
    }

    // The writer thread of one stream: writes each newer batch once, after the previous one's ack
    // (or kAckWait); half-closes on close().
    void run_writer(RawStream& stream) {
        std::unique_lock lk(mu_);
        for (;;) {
            const auto newer = [&] { return batch_ && written_gen_ != batch_gen_; };
            const auto acked = [&] { return last_acked_ || Clock::now() - last_write_ >= kAckWait; };
            while (!(closing_ || read_ended_ || (newer() && acked()))) {
                if (newer()) batch_cv_.wait_until(lk, last_write_ + kAckWait);
                else batch_cv_.wait(lk);
            }
            if (closing_ || read_ended_) break;
            std::shared_ptr<const v1::TileBatch> batch = batch_;
            const std::uint64_t gen = batch_gen_;
            // Before the write: its ack may be read before Write returns.
            last_frame_ = batch->frame();
            last_acked_ = false;
            last_write_ = Clock::now();
            lk.unlock();
            const bool ok = stream.Write(*batch);
            lk.lock();
            if (!ok) return;  // the call is over; Read fails too and Finish has the status
            written_gen_ = gen;
            ++stats_.batches_sent;
        }
        if (!closing_) return;
        lk.unlock();
        stream.WritesDone();
        lk.lock();
        half_closed_ = true;
        wake_cv_.notify_all();
    }

    // Decodes one message (a tile, several tiles, or an ack) and queues its items, under one lock.
    void deliver(const grpc::ByteBuffer& msg, Clock::time_point received) {
        items_.clear();
        std::uint64_t acked_frame = 0;
        std::size_t tiles = 0, payload_bytes = 0, bad_checksums = 0;
        if (!decoder_.decode(msg)) {
            std::lock_guard lk(mu_);
            last_error_ = "INTERNAL: malformed ServerMessage from the server; ignored";
            return;
        }
        if (decoder_.kind() == protocol::ServerMessageDecoder::Kind::tiles) {
            for (std::size_t i = 0; i < decoder_.tile_count(); ++i) {
                ReceivedTile t = decode(decoder_, i, received);
                auto& payload = t.data.payload;
                payload_bytes += payload.size();
                if (t.status == TileStatus::ok && !payload.empty() &&
                    XXH3_64bits(payload.data(), payload.size()) != t.data.checksum) {
                    ++bad_checksums;
                    t.status = TileStatus::data_loss;
                    t.message = "checksum mismatch in transit";
                    payload.clear();
                    payload.shrink_to_fit();
                }
                Item item;
                item.bytes = accounted_bytes(t);
                item.body = std::move(t);
                items_.push_back(std::move(item));
                ++tiles;
            }
        } else if (decoder_.kind() == protocol::ServerMessageDecoder::Kind::ack) {
            BatchAckInfo a = decode(decoder_.mutable_ack());
            acked_frame = a.frame;
            Item item;
            item.bytes = accounted_bytes(a);
            item.body = std::move(a);
            items_.push_back(std::move(item));
        } else {
            return;  // a body this client does not know (a newer server): ignore it
        }
        {
            std::lock_guard lk(mu_);
            if (decoder_.kind() == protocol::ServerMessageDecoder::Kind::tiles) {
                stats_.tiles_received += tiles;
                stats_.bytes_received += payload_bytes;
                stats_.checksum_failures += bad_checksums;
            } else {
                ++stats_.acks_received;
                if (acked_frame == last_frame_) last_acked_ = true;  // a late ack of an earlier batch is not it
            }
            for (auto& item : items_) {
                item.stream = stream_gen_;
                buffered_bytes_ += item.bytes;
                queue_.push_back(std::move(item));
            }
            stats_.peak_buffered_bytes = std::max(stats_.peak_buffered_bytes, buffered_bytes_);
        }
        data_cv_.notify_all();
        if (decoder_.kind() == protocol::ServerMessageDecoder::Kind::ack) batch_cv_.notify_all();  // the writer may go on
    }

    // The longest the writer waits for the previous batch's ack before writing the newest anyway.
    static constexpr std::chrono::milliseconds kAckWait{250};

    TileStreamOptions opts_;
    std::shared_ptr<grpc::Channel> channel_;
    std::unique_ptr<v1::TileService::Stub> stub_;
    std::mt19937_64 rng_;  // session thread only
    protocol::ServerMessageDecoder decoder_;  // session thread only (the reader)
    std::vector<Item> items_;                 // session thread only: one message's items

    mutable std::mutex mu_;
    std::condition_variable data_cv_;   // pollers: the queue became non-empty, or closing
    std::condition_variable space_cv_;  // the reader: the buffer fell under its bound, or closing
    std::condition_variable batch_cv_;  // the writer: a newer batch, the read side ended, or closing
    std::condition_variable wake_cv_;   // backoff sleeps and close()'s grace wait
    bool closing_ = false;
    ConnectionState state_ = ConnectionState::connecting;
    std::string last_error_;
    TileStreamStats stats_;
    std::shared_ptr<const v1::TileBatch> batch_;  // the newest batch (the one-slot outgoing queue)
    std::uint64_t batch_gen_ = 0;                 // bumped by every send_batch
    std::uint64_t written_gen_ = 0;               // the generation written on the current stream
    std::uint64_t last_frame_ = 0;                // the frame of the current stream's last batch written
    bool last_acked_ = true;                      // and whether its ack has been read
    Clock::time_point last_write_{};              // when it was written
    std::uint64_t stream_gen_ = 0;                // bumped by every stream opened
    std::uint64_t replies_polled_ = 0;            // tile replies of the current stream polled
    grpc::ClientContext* ctx_ = nullptr;          // the current stream's context, owned by the session thread
    bool stream_live_ = false;                    // a stream is open (between open and Finish)
    bool read_ended_ = false;                     // the current stream's read side is done
    bool half_closed_ = false;                    // the writer sent WritesDone on the current stream
    std::deque<Item> queue_;                      // received, not yet polled (bounded, see above)
    std::size_t buffered_bytes_ = 0;
    std::thread session_;                         // started last in the constructor, joined by close()
};

std::unique_ptr<TileStreamClient> TileStreamClient::create(TileStreamOptions options) {
    return std::unique_ptr<TileStreamClient>(new TileStreamClient(std::make_unique<Impl>(std::move(options))));
}

TileStreamClient::TileStreamClient(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
TileStreamClient::~TileStreamClient() = default;

void TileStreamClient::send_batch(std::uint64_t frame, std::vector<TileRequest> requests, milliseconds deadline) {
    impl_->send_batch(frame, requests, deadline);
}

std::size_t TileStreamClient::poll(std::vector<ReceivedTile>& tiles, std::vector<BatchAckInfo>* acks, std::size_t max) {
    return impl_->poll(tiles, acks, max);
}

bool TileStreamClient::wait_for_data(milliseconds timeout) { return impl_->wait_for_data(timeout); }
ConnectionState TileStreamClient::state() const { return impl_->state(); }
std::string TileStreamClient::last_error() const { return impl_->last_error(); }
TileStreamStats TileStreamClient::stats() const { return impl_->stats(); }

Result<std::vector<RemoteStore>> TileStreamClient::list_stores(milliseconds timeout) {
    auto reply = impl_->unary<v1::ListStoresRequest, v1::ListStoresReply>(
        v1::ListStoresRequest{}, timeout, &v1::TileService::Stub::ListStores);
    if (!reply.ok()) return reply.error();
    std::vector<RemoteStore> stores;
    stores.reserve(static_cast<std::size_t>(reply->stores_size()));
    for (const auto& m : reply->stores()) stores.push_back(RemoteStore{m.name(), protocol::from_proto(m), m.has_scene()});
    return stores;
}

Result<RemoteStore> TileStreamClient::get_store(const std::string& name, milliseconds timeout) {
    v1::GetStoreRequest request;
    request.set_name(name);
    auto m = impl_->unary<v1::GetStoreRequest, v1::StoreMetadata>(request, timeout, &v1::TileService::Stub::GetStore);
    if (!m.ok()) return m.error();
    return RemoteStore{m->name(), protocol::from_proto(*m), m->has_scene()};
}

Result<std::string> TileStreamClient::get_scene(const std::string& name, std::uint64_t store_version, milliseconds timeout) {
    std::string scene;
    constexpr std::uint64_t kMaxScene = std::uint64_t(1) << 32;  // 4 GiB of OBJ text: not a scene a viewer can hold
    for (;;) {
        v1::GetStoreSceneRequest request;
        request.set_name(name);
        request.set_offset(scene.size());
        auto piece = impl_->unary<v1::GetStoreSceneRequest, v1::StoreScenePiece>(request, timeout, &v1::TileService::Stub::GetStoreScene);
        if (!piece.ok()) return piece.error();
        if (piece->version() != store_version)
            return make_error(Errc::io_error, "store '" + name + "' was replaced while its scene was read");
        if (piece->total_size() > kMaxScene) return make_error(Errc::unsupported, "store '" + name + "': its scene is larger than 4 GiB");
        if (scene.empty()) scene.reserve(piece->total_size());
        scene += piece->data();
        if (scene.size() >= piece->total_size()) break;
        if (piece->data().empty()) return make_error(Errc::io_error, "store '" + name + "': its scene ended early");
    }
    return scene;
}

Result<v1::ServerStats> TileStreamClient::server_stats(milliseconds timeout) {
    return impl_->unary<v1::GetStatsRequest, v1::ServerStats>(v1::GetStatsRequest{}, timeout,
                                                              &v1::TileService::Stub::GetStats);
}

}  // namespace tessera::client
