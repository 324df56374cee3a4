#pragma once
// The request scheduler behind StreamTiles. Each viewer's pending set is replaced by every batch
// it sends (superseded requests are dropped before any I/O, or, if already read, before they are
// sent). While no other viewer waits, the first tiles of a batch that are in the RAM cache are
// answered at once on the stream's thread (no hand-off to an I/O thread: see submit()). A pool of
// I/O threads serves the rest of the pending requests of all viewers: fairly between viewers
// (the least-served viewer goes next, within a small slack in which the higher priority wins),
// highest priority first within a viewer, a chunk at a time so that tiles adjacent in the file
// are read together. Replies wait in a per-viewer outbox bounded in bytes: a viewer that does not
// read stops being served (gRPC flow control), so it bounds its own memory, not the server's.
//
// Re-listed tiles: a tile handed to the transport stays in the viewer's sent set while every
// batch since lists it (it is on its way); such a tile is not sent again (BatchAck.already_sent),
// for at most config.resend_after. A batch that no longer lists it clears it, so a tile listed
// again after that is served again.
//
// Owner: the Server. Threads: io_threads workers, owned here. Every queue is bounded: pending
// by max_pending (over all viewers) and max_batch (per viewer), outboxes by viewer_buffer_bytes
// and each viewer's share of total_buffer_bytes, in-flight reads by kMaxChunksInFlight chunks per viewer.
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "server_context.hpp"
#include "tessera.pb.h"

namespace tessera::server {

using Clock = std::chrono::steady_clock;

// Where the scheduler tells a viewer's stream that its outbox has something to write.
// Called from I/O threads, never with the scheduler's lock held.
class ViewerSink {
public:
    virtual ~ViewerSink() = default;
    virtual void on_outbox_ready() = 0;
};

// One message on its way to a viewer: an ack or an error reply found in submit() (message), or
// a tile taken from the RAM cache or read from its store (is_tile: the reply's fields, the
// payload by reference to the cached tile, never copied; the stream encodes it, see
// grpc_service.cpp).
struct OutMessage {
    v1::ServerMessage message{};     // !is_tile
    std::size_t bytes = 0;           // charged to the outbox
    Clock::time_point received{};    // batch arrival (tiles), for latency
    std::shared_ptr<const StoreHandle> store;  // tiles: per-store accounting
    std::uint64_t packed_key = 0;
    bool is_tile = false;
    // is_tile:
    TileKey key;
    std::uint64_t frame = 0;
    TileStatus status = TileStatus::ok;
    std::string error{};             // when status is not ok
    TileKind kind = TileKind::absent;
    Codec codec = Codec::raw;        // the store's codec (the wire's codec: protocol::reply_codec)
    std::shared_ptr<const storage::Tile> tile{};  // status TILE_OK: payload and checksum
    std::uint32_t server_micros = 0;            // set when taken from the outbox
    bool left_in_flight = false;  // taken into the sent set (revision 1): in_flight already cleared

    std::size_t payload_size() const { return is_tile && tile && kind != TileKind::absent ? tile->bytes.size() : 0; }
    // The whole reply as a protobuf message, payload copied (tests and tools; the stream does not).
    v1::ServerMessage to_proto() const;
};

struct SchedulerStats {
    std::uint32_t viewers = 0;
    std::uint64_t pending = 0, in_flight = 0;
    std::uint64_t batches = 0, requests = 0, tiles_sent = 0, bytes_sent = 0;
    std::uint64_t cancelled = 0, refused = 0, invalid = 0, deadline_exceeded = 0, data_loss = 0;
    std::uint64_t expired_dropped = 0;  // expired requests of stalled viewers dropped unanswered
    std::uint64_t outbox_bytes = 0;
};

class Scheduler {
public:
    using ViewerId = std::uint64_t;
    // Requests taken per dispatch. Every dispatch costs a round of the lock, a hand-off to the
    // stream and often a wake-up, so chunks are large (48 rather than 16: 7-22 % less server CPU
    // per tile at peak, docs/benchmarks.md, "Larger chunks"); a chunk takes requests of remote
    // stores only among its first kRemoteChunk, so a slow origin's reads, bounded in chunks, hold
    // no more tiles than with chunks of 16.
    static constexpr std::size_t kChunk = 48;
    static constexpr std::size_t kRemoteChunk = 16;
    static constexpr unsigned kMaxChunksInFlight = 2;      // per viewer
    static constexpr std::uint64_t kFairnessSlack = 16;    // tiles of service a priority may jump
    static constexpr std::size_t kInlineTiles = 32;        // cache hits answered in submit()
    // Pending requests a worker looks through for ones it may take past a remote store's bound.
    static constexpr std::size_t kRemoteScan = 1024;
    // What one batch can make the server hold is bounded by constants, not by what it carries:
    // a batch listing more stores, or a name longer than any store name can be
    // (protocol::kMaxStoreNameLength bytes), is refused whole with one small ack; at most
    // kMaxErrorReplies requests of a batch get an error reply of their own (the rest are counted
    // in the ack). docs/protocol.md, "Limits".
    static constexpr std::size_t kMaxBatchStores = 64;
    static constexpr std::size_t kMaxErrorReplies = 256;

    explicit Scheduler(ServerContext& ctx);
    ~Scheduler();
    Scheduler(const Scheduler&) = delete;
    Scheduler& operator=(const Scheduler&) = delete;

    // A new stream. nullopt when max_viewers streams are open (or draining).
    std::optional<ViewerId> add_viewer(std::shared_ptr<ViewerSink> sink);
    void remove_viewer(ViewerId id);

    // One batch from a viewer: validates it, replaces the pending set, queues the ack (and error
    // replies) in the outbox. Wakes the I/O threads.
    // `received`: when the batch arrived (its deadline and its tiles' latency count from then).
    void submit(ViewerId id, const v1::TileBatch& batch, Clock::time_point received = Clock::now());
    // Whether a batch of `requests` requests from this viewer is applied now (submit) or held:
    // held while the viewer's pending set is large and its last batch was applied less than
    // config.batch_hold ago (then `retry_at` is when it is due at the latest). A held batch is
    // replaced by the viewer's next one unread (batch_superseded). Small batches, and any batch
    // of a viewer whose pending set is small, are due at once. See docs/protocol.md, "Held
    // batches": without it, a viewer that lists its whole wanted set every frame makes an
    // overloaded server spend its time re-reading lists instead of serving them.
    static constexpr std::size_t kHoldAbove = 256;
    bool batch_due(ViewerId id, std::size_t requests, Clock::time_point now, Clock::time_point& retry_at) const;
    // A held batch replaced by a newer one before it was applied: acked as superseded. Returns
    // the viewer's sink, which the caller wakes (on_outbox_ready) once it holds no lock of its
    // own: the ack is queued where it is called, in order with the viewer's other batches.
    [[nodiscard]] std::shared_ptr<ViewerSink> batch_superseded(ViewerId id, std::uint64_t frame, std::size_t requests);
    // A batch that waited before it was applied (counted).
    void batch_held();
    // A batch over the limits (more than kMaxBatchStores stores or config.max_batch requests):
    // the status and message of its refusal, else nullopt. The stream counts a batch's entries
    // on the wire first and refuses it with refuse_batch without parsing it (an empty request
    // is 2 bytes on the wire, over 50 once parsed).
    std::optional<std::pair<TileStatus, std::string>> oversized(std::size_t requests, std::size_t stores) const;
    void refuse_batch(ViewerId id, std::uint64_t frame, std::size_t requests, TileStatus status, std::string message);

    // Stream side. next_messages moves the next outbox messages into out (cleared first; false:
    // none): an ack alone, or the replies at the front, as many as fit in max_bytes (at least
    // one), all under one lock. While messages are out, the viewer's writer is busy;
    // messages_written ends it and says whether the outbox is still full.
    bool next_messages(ViewerId id, std::vector<OutMessage>& out, std::size_t max_bytes);
    // Returns whether the stream should stop reading batches (see outbox_full).
    bool messages_written(ViewerId id, const std::vector<OutMessage>& msgs, bool ok);
    // One message at a time (tests).
    bool next_message(ViewerId id, OutMessage& out);
    void message_written(ViewerId id, const OutMessage& msg, bool ok);
    // The stream stops reading batches while this holds: the viewer's outbox is at its limit,
    // --viewer-buffer or its share of --total-buffer (the total over the viewers connected),
    // whichever is smaller (acks and error replies are charged like tiles, so a viewer that sends
    // without reading stops being read instead of growing the server).
    bool outbox_full(ViewerId id) const;
    // Nothing pending, being read or waiting to be written for this viewer.
    bool viewer_idle(ViewerId id) const;

    // SIGTERM: new batches are answered UNAVAILABLE; admitted requests are still served.
    void begin_drain();
    bool draining() const;
    SchedulerStats stats() const;

private:
    struct Pending;
    struct Viewer;
    struct FullKey {
        const StoreHandle* store;
        std::uint64_t packed;
        friend bool operator==(const FullKey&, const FullKey&) = default;
    };
    struct FullKeyHash {
        std::size_t operator()(const FullKey& k) const noexcept;
    };

    void worker();
    std::shared_ptr<ViewerSink> ack_only(ViewerId id, std::size_t requests, Counter& outcome, v1::BatchAck ack);
    Viewer* pick_locked();
    bool eligible_locked(const Viewer& v) const;
    bool full_locked(const Viewer& v) const;
    std::uint64_t outbox_limit_locked() const;
    void push_locked(Viewer& v, OutMessage msg);
    void written_locked(Viewer& v, const OutMessage& msg, bool& wake_workers);
    void account_written(const OutMessage& msg, bool ok);
    void notify(std::vector<std::shared_ptr<ViewerSink>>& sinks);
    void serve_cached_locked(Viewer& v);
    void reclaim_expired_locked(const Viewer& asking, Clock::time_point now);
    bool remote_room_locked(const StoreHandle& store) const;
    void take_chunk_locked(Viewer& v, Clock::time_point now, std::vector<Pending>& chunk,
                           std::vector<const StoreHandle*>& remotes);
    void unblock_locked(Clock::time_point now, bool all);
    Clock::time_point earliest_unblock_locked() const;
    static OutMessage tile_reply(const Pending& p);

    ServerContext& ctx_;
    mutable std::mutex mu_;
    std::condition_variable work_cv_;
    bool stopping_ = false;
    bool draining_ = false;
    ViewerId next_id_ = 1;
    std::unordered_map<ViewerId, std::unique_ptr<Viewer>> viewers_;
    std::uint64_t total_pending_ = 0;
    std::uint64_t total_in_flight_ = 0;
    std::uint64_t total_outbox_bytes_ = 0;
    std::uint64_t virtual_time_ = 0;  // service level of the least-served active viewer
    // Chunks reading each remote store now, and in all (see remote_room_locked).
    std::unordered_map<const StoreHandle*, std::size_t> remote_reading_;
    std::size_t remote_reading_total_ = 0;
    std::size_t blocked_viewers_ = 0;  // viewers with remote_blocked_until set
    std::vector<Pending> skipped_;     // take_chunk_locked's scratch

    // Metrics (owned by ctx_.metrics).
    Counter *batches_, *requests_, *tiles_sent_, *bytes_sent_, *cancelled_, *refused_, *invalid_,
        *deadline_exceeded_, *expired_dropped_, *data_loss_, *batches_refused_, *inline_served_,
        *batches_superseded_, *batches_held_;
    Histogram* latency_;
    Histogram* batch_size_;

    unsigned io_threads_ = 0;  // set before the workers start
    std::vector<std::thread> workers_;

    // Stops and joins the workers, removes the gauges: the destructor, and a constructor that
    // could not start every worker.
    void stop_workers();
};

}  // namespace tessera::server
