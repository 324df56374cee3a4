#include "scheduler.hpp"

#include <pthread.h>
#include <absl/container/flat_hash_map.h>
#include <absl/container/flat_hash_set.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>

#include "tessera/protocol/wire.hpp"
#include "tessera/storage/byte_source.hpp"

namespace tessera::server {

namespace {

// What a message costs the server while it waits in an outbox: the record itself, the protobuf
// objects and strings it owns, and the payload it keeps alive.
std::size_t message_bytes(const OutMessage& m) {
    std::size_t n = sizeof(OutMessage) + m.error.capacity() + m.payload_size();
    const auto& msg = m.message;
    if (msg.has_tile()) {
        const auto& t = msg.tile();
        n += sizeof(v1::TileReply) + sizeof(v1::TileKey) + t.key().store().capacity() + t.message().capacity() +
             t.payload().capacity();
    } else if (msg.has_ack()) {
        n += sizeof(v1::BatchAck) + msg.ack().message().capacity();
    }
    return n;
}

// A tile reply (read, or an error reply), not an ack.
bool is_reply(const OutMessage& m) { return m.is_tile || m.message.has_tile(); }

}  // namespace

struct Scheduler::Pending {
    float priority = 0;
    std::uint64_t packed = 0;
    TileKey key;
    std::shared_ptr<const StoreHandle> store;
    std::uint64_t frame = 0;
    std::uint64_t generation = 0;  // the viewer's batch counter when it was asked for
    Clock::time_point received{};
    Clock::time_point deadline{};
};

struct Scheduler::Viewer {
    ViewerId id = 0;
    std::shared_ptr<ViewerSink> sink;
    std::uint64_t generation = 0;
    // Pending requests, ascending priority (the next one is at the back). Ties: earlier keys
    // of the batch first.
    std::vector<Pending> pending;
    // Keys of the latest batch: what the viewer still wants. Flat (open-addressing) sets and
    // maps: every batch looks up each of its keys in three of them, and node-based ones spent
    // ~6% of the server's CPU at peak on cache misses and node allocations.
    absl::flat_hash_set<FullKey, FullKeyHash> wanted;
    // Keys being read now, or read and waiting in the outbox.
    absl::flat_hash_set<FullKey, FullKeyHash> in_flight;
    // Keys handed to the transport (TILE_OK): when, and the reply's ordinal on the stream; kept
    // while every batch lists them. Only for viewers that report replies_received (revision 1).
    struct Sent {
        Clock::time_point at;
        std::uint64_t ordinal;
    };
    absl::flat_hash_map<FullKey, Sent, FullKeyHash> sent;
    std::uint64_t replies_taken = 0;  // tile replies handed to the transport on this stream
    bool track_sent = false;
    unsigned chunks_in_flight = 0;
    std::deque<OutMessage> outbox;
    std::uint64_t outbox_bytes = 0;
    bool writing = false;
    std::size_t writing_replies = 0;  // tile replies in the write under way (stats)
    // Set while every request a worker could take waits for room in a remote store's reads:
    // until when at most (the earliest deadline among them). See take_chunk_locked.
    std::optional<Clock::time_point> remote_blocked_until;
    std::uint64_t served = 0;  // tiles dispatched: the fairness clock
    Clock::time_point applied_at{};  // when its latest batch was applied (batch_due)
};

std::size_t Scheduler::FullKeyHash::operator()(const FullKey& k) const noexcept {
    std::uint64_t h = k.packed ^ (reinterpret_cast<std::uintptr_t>(k.store) * 0x9E3779B97F4A7C15ull);
    h ^= h >> 33;
    h *= 0xff51afd7ed558ccdull;
    h ^= h >> 33;
    return static_cast<std::size_t>(h);
}

Scheduler::Scheduler(ServerContext& ctx) : ctx_(ctx) {
    auto& m = ctx.metrics;
    const Labels grpc{{"protocol", "grpc"}};
    batches_ = &m.counter("tessera_grpc_batches_total", "Request batches received on StreamTiles");
    batches_refused_ = &m.counter("tessera_grpc_batches_refused_total",
                                  "Batches refused whole (too large, or the server is draining)");
    batches_superseded_ = &m.counter("tessera_grpc_batches_superseded_total",
                                     "Batches held while their viewer's pending set was large and replaced by its next "
                                     "batch before they were applied");
    batches_held_ = &m.counter("tessera_grpc_batches_held_total",
                               "Batches applied after waiting for their viewer's pending set to shrink");
    requests_ = &m.counter("tessera_grpc_requests_total", "Tile requests received on StreamTiles");
    tiles_sent_ = &m.counter("tessera_tiles_sent_total", "Tile replies with data handed to the transport", grpc);
    bytes_sent_ = &m.counter("tessera_bytes_sent_total", "Tile payload bytes handed to the transport", grpc);
    cancelled_ = &m.counter("tessera_grpc_requests_cancelled_total",
                            "Requests superseded by a newer batch and dropped unsent");
    refused_ = &m.counter("tessera_grpc_requests_refused_total",
                          "Requests refused with RESOURCE_EXHAUSTED (pending queue full)");
    invalid_ = &m.counter("tessera_grpc_requests_invalid_total",
                          "Requests answered with an error (unknown store, out of range, malformed)");
    deadline_exceeded_ = &m.counter("tessera_grpc_requests_deadline_exceeded_total",
                                    "Requests not started before their deadline");
    expired_dropped_ = &m.counter("tessera_grpc_requests_expired_dropped_total",
                                  "Requests past their deadline dropped unanswered: their viewer had stopped reading and "
                                  "--max-pending was needed");
    inline_served_ = &m.counter("tessera_grpc_tiles_inline_total",
                                "Tiles answered from the RAM cache on the stream's thread (no I/O thread woken)");
    data_loss_ = &m.counter("tessera_grpc_data_loss_total", "Requests answered DATA_LOSS (tile failed its checksum)");
    latency_ = &m.histogram("tessera_grpc_tile_latency_seconds",
                            "Tile request received -> reply handed to the transport", {}, latency_buckets_seconds());
    batch_size_ = &m.histogram("tessera_grpc_batch_requests", "Requests per batch", {},
                               {1, 4, 16, 64, 256, 1024, 4096, 16384, 65536});
    m.gauge_callback("tessera_grpc_viewers", "Open StreamTiles calls", {}, [this] { return double(stats().viewers); });
    m.gauge_callback("tessera_queue_pending", "Admitted tile requests not yet read", {},
                     [this] { return double(stats().pending); });
    m.gauge_callback("tessera_queue_in_flight", "Tile requests being read or waiting to be sent", {},
                     [this] { return double(stats().in_flight); });
    m.gauge_callback("tessera_queue_outbox_bytes", "Reply bytes waiting to be sent, all viewers", {},
                     [this] { return double(stats().outbox_bytes); });

    io_threads_ = ctx.config.io_threads ? ctx.config.io_threads : std::max(1u, std::thread::hardware_concurrency());
    try {
        for (unsigned i = 0; i < io_threads_; ++i) workers_.emplace_back([this] { worker(); });
    } catch (...) {  // no thread left (a joinable std::thread destroyed ends the process); Server::start reports it
        stop_workers();
        throw;
    }
}

void Scheduler::stop_workers() {
    {
        std::lock_guard lock(mu_);
        stopping_ = true;
    }
    work_cv_.notify_all();
    for (auto& t : workers_) t.join();
    workers_.clear();
    ctx_.metrics.remove_callbacks("tessera_grpc_viewers");
    ctx_.metrics.remove_callbacks("tessera_queue_pending");
    ctx_.metrics.remove_callbacks("tessera_queue_in_flight");
    ctx_.metrics.remove_callbacks("tessera_queue_outbox_bytes");
}

Scheduler::~Scheduler() { stop_workers(); }

std::optional<Scheduler::ViewerId> Scheduler::add_viewer(std::shared_ptr<ViewerSink> sink) {
    std::lock_guard lock(mu_);
    if (draining_ || viewers_.size() >= ctx_.config.max_viewers) return std::nullopt;
    auto v = std::make_unique<Viewer>();
    v->id = next_id_++;
    v->sink = std::move(sink);
    v->served = virtual_time_;
    const ViewerId id = v->id;
    viewers_.emplace(id, std::move(v));
    return id;
}

void Scheduler::remove_viewer(ViewerId id) {
    {
        std::lock_guard lock(mu_);
        auto it = viewers_.find(id);
        if (it == viewers_.end()) return;
        Viewer& v = *it->second;
        total_pending_ -= v.pending.size();
        total_outbox_bytes_ -= v.outbox_bytes;
        if (v.remote_blocked_until) --blocked_viewers_;
        // In-flight chunks find the viewer gone and drop their replies (and their in-flight count).
        viewers_.erase(it);
    }
    // One viewer fewer: every other viewer's share of --total-buffer grew.
    work_cv_.notify_all();
}

// The reply to a pending request, its payload and status still to be filled in.
OutMessage Scheduler::tile_reply(const Pending& p) {
    return OutMessage{.received = p.received, .store = p.store, .packed_key = p.packed, .is_tile = true, .key = p.key,
                      .frame = p.frame};
}

void Scheduler::push_locked(Viewer& v, OutMessage msg) {
    msg.bytes = message_bytes(msg);
    v.outbox_bytes += msg.bytes;
    total_outbox_bytes_ += msg.bytes;
    v.outbox.push_back(std::move(msg));
}

void Scheduler::notify(std::vector<std::shared_ptr<ViewerSink>>& sinks) {
    for (auto& s : sinks)
        if (s) s->on_outbox_ready();
    sinks.clear();
}

std::optional<std::pair<TileStatus, std::string>> Scheduler::oversized(std::size_t requests, std::size_t stores) const {
    if (stores > kMaxBatchStores)
        return std::pair{TileStatus::invalid_argument, "the batch lists " + std::to_string(stores) + " stores (the limit is " +
                                                           std::to_string(kMaxBatchStores) + "); it was refused whole"};
    if (requests > ctx_.config.max_batch)
        return std::pair{TileStatus::resource_exhausted, "batch of " + std::to_string(requests) +
                                                             " requests exceeds the limit of " +
                                                             std::to_string(ctx_.config.max_batch) + "; it was refused whole"};
    return std::nullopt;
}

// A batch answered by its ack alone: refused whole, or superseded before it was applied.
// Returns the sink to wake.
std::shared_ptr<ViewerSink> Scheduler::ack_only(ViewerId id, std::size_t requests, Counter& outcome, v1::BatchAck ack) {
    batches_->inc();
    requests_->inc(requests);
    batch_size_->observe(double(requests));
    outcome.inc();
    std::shared_ptr<ViewerSink> sink;
    {
        std::lock_guard lock(mu_);
        auto it = viewers_.find(id);
        if (it == viewers_.end()) return nullptr;
        OutMessage m;
        *m.message.mutable_ack() = std::move(ack);
        push_locked(*it->second, std::move(m));
        sink = it->second->sink;
    }
    return sink;
}

void Scheduler::refuse_batch(ViewerId id, std::uint64_t frame, std::size_t requests, TileStatus status, std::string message) {
    v1::BatchAck ack;
    ack.set_frame(frame);
    ack.set_status(protocol::to_proto(status));
    ack.set_message(std::move(message));
    if (auto sink = ack_only(id, requests, *batches_refused_, std::move(ack))) sink->on_outbox_ready();
}

bool Scheduler::batch_due(ViewerId id, std::size_t requests, Clock::time_point now, Clock::time_point& retry_at) const {
    const auto hold = ctx_.config.batch_hold;
    if (hold.count() <= 0 || requests <= kHoldAbove) return true;
    std::lock_guard lock(mu_);
    auto it = viewers_.find(id);
    if (it == viewers_.end()) return true;
    const Viewer& v = *it->second;
    if (v.pending.size() <= kHoldAbove || now - v.applied_at >= hold) return true;
    retry_at = v.applied_at + hold;
    return false;
}

std::shared_ptr<ViewerSink> Scheduler::batch_superseded(ViewerId id, std::uint64_t frame, std::size_t requests) {
    v1::BatchAck ack;
    ack.set_frame(frame);
    ack.set_status(protocol::to_proto(TileStatus::ok));
    ack.set_superseded(true);
    return ack_only(id, requests, *batches_superseded_, std::move(ack));
}

void Scheduler::batch_held() { batches_held_->inc(); }

void Scheduler::submit(ViewerId id, const v1::TileBatch& batch, Clock::time_point received) {
    const auto now = Clock::now();
    batches_->inc();
    requests_->inc(static_cast<std::uint64_t>(batch.requests_size()));
    batch_size_->observe(batch.requests_size());

    // The store list is checked first: a name over the limit refuses the batch once, in a reply
    // of fixed size, instead of being copied into a reply per request.
    std::string bad_list;
    auto too_big = oversized(std::size_t(batch.requests_size()), std::size_t(batch.stores_size()));
    if (too_big && too_big->first == TileStatus::invalid_argument) {
        bad_list = std::move(too_big->second);
        too_big.reset();
    } else {
        for (int i = 0; i < batch.stores_size() && bad_list.empty(); ++i)
            if (batch.stores(i).size() > protocol::kMaxStoreNameLength)
                bad_list = "store name " + std::to_string(i) + " of the batch is " + std::to_string(batch.stores(i).size()) +
                           " bytes long (names are identifiers of at most " +
                           std::to_string(protocol::kMaxStoreNameLength) + " bytes); the batch was refused whole";
    }

    // Resolve the batch's store names once (outside the lock: the registry has its own).
    std::vector<std::shared_ptr<const StoreHandle>> stores;
    if (bad_list.empty()) {
        stores.reserve(static_cast<std::size_t>(batch.stores_size()));
        for (const auto& name : batch.stores()) stores.push_back(ctx_.stores.find(name));
    }

    v1::BatchAck ack;
    ack.set_frame(batch.frame());
    std::vector<OutMessage> errors;
    std::uint32_t unanswered = 0;  // error replies beyond kMaxErrorReplies: counted in the ack only
    auto error_reply = [&](const v1::TileRequest& r, TileStatus status, std::string message) {
        if (errors.size() >= kMaxErrorReplies) {
            ++unanswered;
            return;
        }
        OutMessage m;
        auto* t = m.message.mutable_tile();
        auto* k = t->mutable_key();
        if (r.store() < static_cast<std::uint32_t>(batch.stores_size())) k->set_store(batch.stores(static_cast<int>(r.store())));
        k->set_level(r.level());
        k->set_x(r.x());
        k->set_y(r.y());
        t->set_frame(batch.frame());
        t->set_status(protocol::to_proto(status));
        t->set_message(std::move(message));
        t->set_kind(v1::KIND_ABSENT);
        t->set_codec(protocol::reply_codec(status, TileKind::absent, Codec::raw));
        errors.push_back(std::move(m));
    };

    // Validate, and collect the new wanted set (outside the lock: nothing here is the viewer's).
    const auto deadline =
        received + (batch.deadline_ms() ? std::chrono::milliseconds(batch.deadline_ms()) : ctx_.config.request_timeout);
    static const google::protobuf::RepeatedPtrField<v1::TileRequest> kNone;
    const bool refused_whole = !bad_list.empty() || too_big.has_value();  // below, under the lock
    const auto& requests = refused_whole ? kNone : batch.requests();
    std::vector<Pending> candidates;
    candidates.reserve(static_cast<std::size_t>(requests.size()));
    absl::flat_hash_set<FullKey, FullKeyHash> wanted;
    wanted.reserve(static_cast<std::size_t>(requests.size()));
    std::uint32_t invalid = 0, already = 0, already_sent = 0;
    for (const auto& r : requests) {
        if (r.store() >= static_cast<std::uint32_t>(batch.stores_size())) {
            error_reply(r, TileStatus::invalid_argument, "store index " + std::to_string(r.store()) + " is not in the batch's store list");
            ++invalid;
            continue;
        }
        const auto& store = stores[r.store()];
        if (!store) {  // names are at most kMaxStoreNameLength bytes here (checked above)
            const auto& name = batch.stores(static_cast<int>(r.store()));
            const bool valid = protocol::valid_store_name(name);
            error_reply(r, valid ? TileStatus::not_found : TileStatus::invalid_argument,
                        valid ? "no store named '" + name + "'" : "store names are identifiers ([A-Za-z0-9_.-], no '..')");
            ++invalid;
            continue;
        }
        if (!std::isfinite(r.priority())) {
            error_reply(r, TileStatus::invalid_argument, "priority must be a finite number");
            ++invalid;
            continue;
        }
        store->metrics.requests->inc();
        const TileKey key{r.level(), r.x(), r.y()};
        if (!store->info().contains(key)) {
            const auto& info = store->info();
            char buf[160];
            if (key.level >= info.level_count())
                std::snprintf(buf, sizeof buf, "level %u is out of range (the store has levels 0..%u)", key.level,
                              info.level_count() - 1);
            else
                std::snprintf(buf, sizeof buf, "tile (%u,%u) is out of range at level %u (%u x %u tiles)", key.x,
                              key.y, key.level, info.levels[key.level].tiles_x, info.levels[key.level].tiles_y);
            error_reply(r, TileStatus::out_of_range, buf);
            ++invalid;
            continue;
        }
        const FullKey fk{store.get(), pack_key(key)};
        if (!wanted.insert(fk).second) {
            ++already;  // a duplicate in this batch: sent once
            continue;
        }
        Pending p;
        p.priority = r.priority();
        p.packed = fk.packed;
        p.key = key;
        p.store = store;
        p.frame = batch.frame();
        p.received = received;
        p.deadline = deadline;
        candidates.push_back(std::move(p));
    }
    // Highest priority first (ties in the batch's order). Validation and the sort happen before
    // the lock: for a batch of thousands of requests they would hold every stream and worker.
    std::stable_sort(candidates.begin(), candidates.end(),
                     [](const Pending& a, const Pending& b) { return a.priority > b.priority; });

    std::vector<std::shared_ptr<ViewerSink>> wake;
    std::unique_lock lock(mu_);
    auto vit = viewers_.find(id);
    if (vit == viewers_.end()) return;
    Viewer& v = *vit->second;
    v.applied_at = now;
    v.track_sent = batch.protocol_revision() >= 1;
    if (!v.track_sent) v.sent.clear();

    auto refuse_whole = [&](TileStatus status, std::string message) {
        batches_refused_->inc();
        ack.set_status(protocol::to_proto(status));
        ack.set_message(std::move(message));
        OutMessage m;
        *m.message.mutable_ack() = std::move(ack);
        push_locked(v, std::move(m));
        wake.push_back(v.sink);
        lock.unlock();
        notify(wake);
    };
    if (draining_) return refuse_whole(TileStatus::unavailable, "the server is shutting down; reconnect elsewhere");
    if (!bad_list.empty()) return refuse_whole(TileStatus::invalid_argument, std::move(bad_list));
    if (too_big) return refuse_whole(too_big->first, std::move(too_big->second));

    // What this viewer is already being served: being read or in its outbox (in_flight), or on
    // the wire and not yet read by it (the sent set). Such a request is served once, not again.
    std::vector<Pending> next;
    next.reserve(candidates.size());
    for (Pending& p : candidates) {
        const FullKey fk{p.store.get(), p.packed};
        if (v.in_flight.contains(fk)) {
            ++already;
            continue;
        }
        if (auto s = v.sent.find(fk); s != v.sent.end()) {
            // Still on the wire (the viewer had not read it when it made the batch), and not lost.
            if (s->second.ordinal > batch.replies_received() && now - s->second.at < ctx_.config.resend_after) {
                ++already;  // sent, and listed by every batch since: still on its way
                ++already_sent;
                continue;
            }
            v.sent.erase(s);
        }
        next.push_back(std::move(p));
    }

    // Superseded: old pending requests the new batch does not list, and read replies waiting in
    // the outbox for keys it does not list. Both are dropped unsent.
    std::uint64_t cancelled = 0;
    for (const auto& p : v.pending)
        if (!wanted.contains(FullKey{p.store.get(), p.packed})) ++cancelled;
    for (auto it = v.outbox.begin(); it != v.outbox.end();) {
        if (it->is_tile && !wanted.contains(FullKey{it->store.get(), it->packed_key})) {
            v.outbox_bytes -= it->bytes;
            total_outbox_bytes_ -= it->bytes;
            v.in_flight.erase(FullKey{it->store.get(), it->packed_key});
            ++cancelled;
            it = v.outbox.erase(it);
        } else {
            ++it;
        }
    }

    // Admission: the pending queue over all viewers is bounded; the lowest priorities are refused.
    if (next.size() + total_pending_ - v.pending.size() > ctx_.config.max_pending) reclaim_expired_locked(v, now);
    const std::uint64_t others = total_pending_ - v.pending.size();
    const std::uint64_t room = ctx_.config.max_pending > others ? ctx_.config.max_pending - others : 0;
    std::uint32_t refused = 0;
    if (next.size() > room) {
        for (std::size_t i = room; i < next.size(); ++i) {
            wanted.erase(FullKey{next[i].store.get(), next[i].packed});
            ++refused;
            if (errors.size() >= kMaxErrorReplies) {
                ++unanswered;
                continue;
            }
            OutMessage m;
            auto* t = m.message.mutable_tile();
            t->mutable_key()->set_store(next[i].store->name);
            t->mutable_key()->set_level(next[i].key.level);
            t->mutable_key()->set_x(next[i].key.x);
            t->mutable_key()->set_y(next[i].key.y);
            t->set_frame(batch.frame());
            t->set_status(protocol::to_proto(TileStatus::resource_exhausted));
            t->set_message("the server's request queue is full; retry later");
            t->set_codec(protocol::reply_codec(TileStatus::resource_exhausted, TileKind::absent, Codec::raw));
            errors.push_back(std::move(m));
        }
        next.resize(room);
    }
    std::reverse(next.begin(), next.end());  // ascending: the highest priority at the back
    const std::uint64_t generation = ++v.generation;
    for (auto& p : next) p.generation = generation;

    // A sent tile this batch does not list has arrived (or is no longer wanted): forget it, so
    // that listing it again asks for it again.
    absl::erase_if(v.sent, [&](const auto& e) { return !wanted.contains(e.first); });

    total_pending_ = total_pending_ - v.pending.size() + next.size();
    const bool was_idle = v.pending.empty();
    v.pending = std::move(next);
    if (v.remote_blocked_until) {  // a new set: it may hold requests a worker can take
        v.remote_blocked_until.reset();
        --blocked_viewers_;
    }
    v.wanted = std::move(wanted);
    if (was_idle && !v.pending.empty()) v.served = std::max(v.served, virtual_time_);

    ack.set_status(protocol::to_proto(TileStatus::ok));
    ack.set_admitted(static_cast<std::uint32_t>(v.pending.size()));
    ack.set_refused(refused);
    ack.set_invalid(invalid);
    ack.set_already_queued(already);
    ack.set_already_sent(already_sent);
    ack.set_cancelled(static_cast<std::uint32_t>(cancelled));
    if (unanswered)
        ack.set_message(std::to_string(unanswered) + " invalid or refused requests beyond the first " +
                        std::to_string(kMaxErrorReplies) + " get no reply of their own (counted here)");
    cancelled_->inc(cancelled);
    refused_->inc(refused);
    invalid_->inc(invalid);
    {
        OutMessage m;
        *m.message.mutable_ack() = std::move(ack);
        push_locked(v, std::move(m));
    }
    for (auto& e : errors) push_locked(v, std::move(e));
    serve_cached_locked(v);
    wake.push_back(v.sink);
    // Anything pending may be eligible now (this batch's rest, or another viewer's once this one's
    // dropped replies freed outbox room); when the batch was answered whole and nothing else
    // waits, no reader is woken for nothing.
    const bool for_workers = total_pending_ > 0;
    lock.unlock();
    if (for_workers) work_cv_.notify_all();
    notify(wake);
}

// Other viewers' pending requests past their deadline, dropped with no reply each (counted in
// expired_dropped; their viewers list what they still want in their next batch). A worker
// answers an expired request when it takes it, but a viewer whose outbox is full (it stopped
// reading) is never taken, and its expired requests would hold --max-pending from the viewers
// that read. A viewer's pending requests come from one batch and share its deadline.
void Scheduler::reclaim_expired_locked(const Viewer& asking, Clock::time_point now) {
    for (auto& [id, o] : viewers_) {
        if (o.get() == &asking || o->pending.empty() || o->pending.front().deadline >= now) continue;
        total_pending_ -= o->pending.size();
        expired_dropped_->inc(o->pending.size());
        o->pending.clear();
    }
}

// While no other viewer waits, the first requests of a batch whose tiles are in the RAM cache
// are answered here, on the stream's own thread: no I/O thread is woken and no thread hand-off
// stands between the batch and its replies (each one costs a wake-up and a context switch, and on
// a busy machine a wait for a core). In priority order, up to the first miss and at most
// kInlineTiles (the rest, and every miss, go to the I/O threads as before); never when another
// viewer is eligible, so fairness between viewers is the workers' as before.
void Scheduler::serve_cached_locked(Viewer& v) {
    if (draining_) return;
    for (const auto& [id, other] : viewers_)
        if (other.get() != &v && eligible_locked(*other)) return;
    std::size_t served = 0;
    while (served < kInlineTiles && eligible_locked(v)) {
        const Pending& p = v.pending.back();
        std::shared_ptr<const storage::Tile> tile = ctx_.fetcher.cached(*p.store, p.key);
        if (!tile) break;
        OutMessage r = tile_reply(p);
        r.status = TileStatus::ok;
        r.kind = tile->kind;
        r.codec = p.store->info().codec;
        r.tile = std::move(tile);
        v.in_flight.insert(FullKey{p.store.get(), p.packed});
        v.pending.pop_back();
        push_locked(v, std::move(r));
        ++served;
    }
    total_pending_ -= served;
    v.served += served;
    inline_served_->inc(served);
}

// Each viewer's outbox holds at most --viewer-buffer and its share of --total-buffer: viewers
// that stop reading fill their own shares, never the total that the viewers who read need (a
// shared ceiling let a few streams that never read stop every other viewer's tiles).
std::uint64_t Scheduler::outbox_limit_locked() const {
    const std::uint64_t share = ctx_.config.total_buffer_bytes / std::max<std::size_t>(1, viewers_.size());
    return std::max<std::uint64_t>(1, std::min<std::uint64_t>(ctx_.config.viewer_buffer_bytes, share));
}

bool Scheduler::eligible_locked(const Viewer& v) const {
    return !v.pending.empty() && !v.remote_blocked_until && v.chunks_in_flight < kMaxChunksInFlight &&
           v.outbox_bytes < outbox_limit_locked();
}

bool Scheduler::full_locked(const Viewer& v) const { return v.outbox_bytes >= outbox_limit_locked(); }

Scheduler::Viewer* Scheduler::pick_locked() {
    // Fair between viewers: among those within kFairnessSlack of the least-served eligible viewer,
    // the one whose next request has the highest priority.
    std::uint64_t min_served = UINT64_MAX;
    for (auto& [id, v] : viewers_)
        if (eligible_locked(*v)) min_served = std::min(min_served, v->served);
    if (min_served == UINT64_MAX) return nullptr;
    Viewer* best = nullptr;
    for (auto& [id, v] : viewers_) {
        if (!eligible_locked(*v) || v->served > min_served + kFairnessSlack) continue;
        if (!best || v->pending.back().priority > best->pending.back().priority ||
            (v->pending.back().priority == best->pending.back().priority && v->served < best->served))
            best = v.get();
    }
    virtual_time_ = std::max(virtual_time_, min_served);
    return best;
}

// A remote store's reads hold an I/O thread for as long as its origin takes (up to the
// requests' deadline), so they are bounded: per store by --remote-concurrency (more would only
// wait for its connections), and over all remote stores by what leaves local stores at least
// one thread per core (or half the threads, when there are fewer).
bool Scheduler::remote_room_locked(const StoreHandle& store) const {
    const unsigned threads = io_threads_;
    const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
    const unsigned reserve = threads > 1 ? std::max(1u, std::min(cores, threads / 2)) : 0;
    const std::size_t budget = std::max(1u, threads - reserve);
    const auto it = remote_reading_.find(&store);
    const std::size_t reading = it == remote_reading_.end() ? 0 : it->second;
    return reading < std::max(1u, ctx_.config.remote_concurrency) && remote_reading_total_ < budget;
}

// Up to kChunk of v's pending requests, highest priority first, those of remote stores only
// among the first kRemoteChunk, skipping (they stay pending, in order) those of a remote store
// with no room for another read: the viewer's requests of other stores go ahead of them. An
// expired request is always taken: it is answered without a read.
// Looks at most kRemoteScan requests; when it takes none, the viewer is blocked until a remote
// read ends, a new batch comes, or its earliest skipped request expires.
void Scheduler::take_chunk_locked(Viewer& v, Clock::time_point now, std::vector<Pending>& chunk,
                                  std::vector<const StoreHandle*>& remotes) {
    auto& pend = v.pending;
    std::size_t i = pend.size(), scanned = 0;
    skipped_.clear();
    Clock::time_point earliest_skipped = Clock::time_point::max();
    while (i > 0 && chunk.size() < kChunk && scanned < kRemoteScan) {
        const StoreHandle* st = pend[i - 1].store.get();
        if (st->remote() && chunk.size() >= kRemoteChunk) break;  // it stays pending, in order
        Pending& p = pend[--i];
        ++scanned;
        if (st->remote() && p.deadline >= now && std::find(remotes.begin(), remotes.end(), st) == remotes.end()) {
            if (!remote_room_locked(*st)) {
                earliest_skipped = std::min(earliest_skipped, p.deadline);
                skipped_.push_back(std::move(p));
                continue;
            }
            remotes.push_back(st);
            ++remote_reading_[st];
            ++remote_reading_total_;
        }
        chunk.push_back(std::move(p));
    }
    // pend[0, i) is untouched; the skipped ones go back above it, lowest priority first.
    pend.resize(i);
    for (auto it = skipped_.rbegin(); it != skipped_.rend(); ++it) pend.push_back(std::move(*it));
    if (chunk.empty()) {
        v.remote_blocked_until = earliest_skipped == Clock::time_point::max() ? now : earliest_skipped;
        ++blocked_viewers_;
    }
}

// Unblocks the viewers whose wait is over (all of them: a remote read ended).
void Scheduler::unblock_locked(Clock::time_point now, bool all) {
    for (auto& [id, v] : viewers_)
        if (v->remote_blocked_until && (all || *v->remote_blocked_until <= now)) {
            v->remote_blocked_until.reset();
            --blocked_viewers_;
        }
}

Clock::time_point Scheduler::earliest_unblock_locked() const {
    Clock::time_point t = Clock::time_point::max();
    for (const auto& [id, v] : viewers_)
        if (v->remote_blocked_until) t = std::min(t, *v->remote_blocked_until);
    return t;
}

void Scheduler::worker() {
    pthread_setname_np(pthread_self(), "grpc-io");
    std::vector<Pending> chunk;
    std::vector<OutMessage> replies;
    std::vector<FetchedTile> fetched;
    std::vector<TileKey> keys;
    std::vector<std::size_t> index;
    std::vector<std::shared_ptr<ViewerSink>> wake;
    std::vector<const StoreHandle*> remotes;  // remote stores the chunk reads, each counted once
    for (;;) {
        ViewerId vid = 0;
        remotes.clear();
        {
            std::unique_lock lock(mu_);
            for (;;) {
                if (stopping_) return;
                if (blocked_viewers_ > 0) unblock_locked(Clock::now(), false);
                Viewer* v = pick_locked();
                if (!v) {
                    const auto until = blocked_viewers_ > 0 ? earliest_unblock_locked() : Clock::time_point::max();
                    if (until == Clock::time_point::max()) work_cv_.wait(lock);
                    else work_cv_.wait_until(lock, until);
                    continue;
                }
                chunk.clear();
                take_chunk_locked(*v, Clock::now(), chunk, remotes);
                if (chunk.empty()) continue;  // all it could take waits for a remote store (v is blocked now)
                vid = v->id;
                for (const Pending& p : chunk) v->in_flight.insert(FullKey{p.store.get(), p.packed});
                total_pending_ -= chunk.size();
                total_in_flight_ += chunk.size();
                v->served += chunk.size();
                ++v->chunks_in_flight;
                break;
            }
        }

        // Read: deadlines first, then one fetch per store (cache, then coalesced file reads).
        // Replies hold the cached tile itself: the payload is never copied on its way out.
        const auto now = Clock::now();
        replies.clear();
        replies.resize(chunk.size());
        std::map<const StoreHandle*, std::vector<std::size_t>> by_store;
        std::vector<std::size_t> expired;
        for (std::size_t i = 0; i < chunk.size(); ++i) {
            auto& r = replies[i];
            r = tile_reply(chunk[i]);
            if (chunk[i].deadline < now) {
                r.status = TileStatus::deadline_exceeded;
                r.error = "not started before its deadline";
                deadline_exceeded_->inc();
                expired.push_back(i);
            } else {
                by_store[chunk[i].store.get()].push_back(i);
            }
        }
        // Replies go to the viewer in the chunk's order (priority), except that a remote store's
        // are read last and handed over on their own: a viewer's tiles of local stores never wait
        // for a slow origin's in the same chunk.
        std::vector<std::pair<const StoreHandle*, std::vector<std::size_t>>> groups(by_store.begin(), by_store.end());
        const auto first_remote = std::stable_partition(groups.begin(), groups.end(),
                                                        [](const auto& g) { return !g.first->remote(); });
        const std::size_t local_groups = static_cast<std::size_t>(first_remote - groups.begin());
        // Remote stores in the chunk's order (the first request of each), not the map's.
        std::sort(first_remote, groups.end(), [](const auto& a, const auto& b) { return a.second.front() < b.second.front(); });
        std::size_t handed = 0;
        // Hand over, unless the viewer left or no longer wants the tile; the chunk ends with its last part.
        auto hand_over = [&](std::vector<std::size_t>& members) {
            std::sort(members.begin(), members.end());
            handed += members.size();
            const bool last = handed == chunk.size();
            std::lock_guard lock(mu_);
            total_in_flight_ -= members.size();
            auto it = viewers_.find(vid);
            if (it == viewers_.end()) return;
            Viewer& v = *it->second;
            if (last) --v.chunks_in_flight;
            std::uint64_t dropped = 0;
            for (std::size_t i : members) {
                const FullKey fk{chunk[i].store.get(), chunk[i].packed};
                if (chunk[i].generation != v.generation && !v.wanted.contains(fk)) {
                    v.in_flight.erase(fk);
                    ++dropped;  // superseded while it was being read
                    continue;
                }
                push_locked(v, std::move(replies[i]));
            }
            cancelled_->inc(dropped);
            if (!members.empty() && (wake.empty() || wake.back() != v.sink)) wake.push_back(v.sink);
        };
        std::vector<std::size_t> part = std::move(expired);  // the first hand-over: expired and local replies
        if (local_groups == 0 && !part.empty()) {  // expired replies never wait for an origin
            hand_over(part);
            part.clear();
        }
        for (std::size_t g = 0; g < groups.size(); ++g) {
            auto& [store, members] = groups[g];
            keys.clear();
            Clock::time_point deadline{};
            for (std::size_t i : members) {
                keys.push_back(chunk[i].key);
                deadline = std::max(deadline, chunk[i].deadline);
            }
            {
                // A remote store's reads end at the latest deadline of the requests they serve
                // (worth finishing while any of them wants it; a tile read in time for that one
                // goes to the others too), not at the origin's pace.
                const storage::ReadDeadlineScope scope(deadline);
                ctx_.fetcher.fetch(*store, keys, fetched);
            }
            for (std::size_t j = 0; j < members.size(); ++j) {
                auto& f = fetched[j];
                auto& r = replies[members[j]];
                r.status = f.status;
                if (f.status != TileStatus::ok) {
                    r.error = std::move(f.message);
                    if (f.status == TileStatus::data_loss) data_loss_->inc();
                    continue;
                }
                r.kind = f.tile->kind;
                r.codec = store->info().codec;
                r.tile = std::move(f.tile);
            }
            part.insert(part.end(), members.begin(), members.end());
            if (g + 1 >= local_groups) {  // the local part once all of it is read; then each remote store
                hand_over(part);
                part.clear();
                if (handed < chunk.size()) notify(wake);
            }
        }
        if (!part.empty() || handed < chunk.size()) hand_over(part);
        if (!remotes.empty()) {
            // Those stores' reads are done: viewers waiting for room in them may go on.
            std::lock_guard lock(mu_);
            for (const StoreHandle* st : remotes) {
                if (--remote_reading_[st] == 0) remote_reading_.erase(st);
                --remote_reading_total_;
            }
            unblock_locked(Clock::now(), true);
        }
        // This viewer may be eligible again (chunks in flight went down); with remote room freed,
        // so may others.
        if (remotes.empty()) work_cv_.notify_one();
        else work_cv_.notify_all();
        notify(wake);
    }
}

bool Scheduler::next_messages(ViewerId id, std::vector<OutMessage>& out, std::size_t max_bytes) {
    out.clear();
    std::lock_guard lock(mu_);
    auto it = viewers_.find(id);
    if (it == viewers_.end()) return false;
    Viewer& v = *it->second;
    if (v.writing || v.outbox.empty()) return false;
    const auto now = Clock::now();
    std::size_t bytes = 0;
    // An ack goes alone; replies (read tiles and error replies) go together up to max_bytes.
    const bool ack = v.outbox.front().message.has_ack();
    while (!v.outbox.empty()) {
        OutMessage& m = v.outbox.front();
        if (!out.empty() && (ack || m.message.has_ack() || bytes + m.bytes > max_bytes)) break;
        bytes += m.bytes;
        if (m.is_tile || m.message.has_tile()) ++v.replies_taken;
        if (m.is_tile) {
            const auto us = std::chrono::duration_cast<std::chrono::microseconds>(now - m.received).count();
            m.server_micros = static_cast<std::uint32_t>(std::min<std::int64_t>(us, UINT32_MAX));
            if (m.status == TileStatus::ok && v.track_sent) {
                // On its way: from now on the sent set, not in_flight, keeps a batch that still
                // lists it from asking for it again (revision 0: in_flight until written).
                const FullKey fk{m.store.get(), m.packed_key};
                v.in_flight.erase(fk);
                v.sent.insert_or_assign(fk, Viewer::Sent{now, v.replies_taken});
                m.left_in_flight = true;
            }
        }
        out.push_back(std::move(m));
        v.outbox.pop_front();
    }
    v.writing = true;
    v.writing_replies = std::size_t(std::count_if(out.begin(), out.end(), is_reply));
    return true;
}

void Scheduler::written_locked(Viewer& v, const OutMessage& msg, bool& wake_workers) {
    const bool was_full = full_locked(v);
    v.outbox_bytes -= msg.bytes;
    total_outbox_bytes_ -= msg.bytes;
    if (msg.is_tile && !msg.left_in_flight) v.in_flight.erase(FullKey{msg.store.get(), msg.packed_key});
    wake_workers = wake_workers || was_full;
}

void Scheduler::account_written(const OutMessage& msg, bool ok) {
    if (!ok || !msg.is_tile) return;
    latency_->observe(std::chrono::duration<double>(Clock::now() - msg.received).count());
    if (msg.status == TileStatus::ok && msg.kind != TileKind::absent) {
        const std::size_t n = msg.payload_size();
        tiles_sent_->inc();
        bytes_sent_->inc(n);
        msg.store->metrics.tiles_sent->inc();
        msg.store->metrics.bytes_sent->inc(n);
    }
}

bool Scheduler::messages_written(ViewerId id, const std::vector<OutMessage>& msgs, bool ok) {
    bool wake_workers = false, full = false;
    {
        std::lock_guard lock(mu_);
        auto it = viewers_.find(id);
        if (it != viewers_.end()) {
            Viewer& v = *it->second;
            v.writing = false;
            v.writing_replies = 0;
            for (const auto& m : msgs) written_locked(v, m, wake_workers);
            full = full_locked(v);
        }
    }
    if (wake_workers) work_cv_.notify_all();
    for (const auto& m : msgs) account_written(m, ok);
    return full;
}

bool Scheduler::next_message(ViewerId id, OutMessage& out) {
    std::vector<OutMessage> one;
    if (!next_messages(id, one, 0)) return false;
    out = std::move(one.front());
    return true;
}

void Scheduler::message_written(ViewerId id, const OutMessage& msg, bool ok) {
    bool wake_workers = false;
    {
        std::lock_guard lock(mu_);
        auto it = viewers_.find(id);
        if (it != viewers_.end()) {
            Viewer& v = *it->second;
            v.writing = false;
            v.writing_replies = 0;
            written_locked(v, msg, wake_workers);
        }
    }
    if (wake_workers) work_cv_.notify_all();
    account_written(msg, ok);
}

v1::ServerMessage OutMessage::to_proto() const {
    if (!is_tile) return message;
    v1::ServerMessage m;
    auto* t = m.mutable_tile();
    auto* k = t->mutable_key();
    k->set_store(store->name);
    k->set_level(key.level);
    k->set_x(key.x);
    k->set_y(key.y);
    t->set_store_version(store->version);
    t->set_frame(frame);
    t->set_status(protocol::to_proto(status));
    t->set_message(error);
    t->set_kind(protocol::to_proto(kind));
    t->set_codec(protocol::reply_codec(status, kind, codec));
    if (tile) {
        t->set_checksum(tile->checksum);
        if (kind != TileKind::absent) t->set_payload(tile->bytes.data(), tile->bytes.size());
    }
    t->set_server_micros(server_micros);
    return m;
}

bool Scheduler::outbox_full(ViewerId id) const {
    std::lock_guard lock(mu_);
    auto it = viewers_.find(id);
    return it != viewers_.end() && full_locked(*it->second);
}

bool Scheduler::viewer_idle(ViewerId id) const {
    std::lock_guard lock(mu_);
    auto it = viewers_.find(id);
    if (it == viewers_.end()) return true;
    const Viewer& v = *it->second;
    return v.pending.empty() && v.chunks_in_flight == 0 && v.outbox.empty() && !v.writing;
}

void Scheduler::begin_drain() {
    std::vector<std::shared_ptr<ViewerSink>> wake;
    {
        std::lock_guard lock(mu_);
        draining_ = true;
        for (auto& [id, v] : viewers_) wake.push_back(v->sink);
    }
    notify(wake);  // idle viewers can finish now
}

bool Scheduler::draining() const {
    std::lock_guard lock(mu_);
    return draining_;
}

SchedulerStats Scheduler::stats() const {
    SchedulerStats s;
    {
        std::lock_guard lock(mu_);
        s.viewers = static_cast<std::uint32_t>(viewers_.size());
        s.pending = total_pending_;
        s.in_flight = total_in_flight_;
        // Tile replies waiting to be written or being written (acks are not requests).
        for (const auto& [id, v] : viewers_)
            s.in_flight += std::size_t(std::count_if(v->outbox.begin(), v->outbox.end(), is_reply)) + v->writing_replies;
        s.outbox_bytes = total_outbox_bytes_;
    }
    s.batches = batches_->value();
    s.requests = requests_->value();
    s.tiles_sent = tiles_sent_->value();
    s.bytes_sent = bytes_sent_->value();
    s.cancelled = cancelled_->value();
    s.refused = refused_->value();
    s.invalid = invalid_->value();
    s.deadline_exceeded = deadline_exceeded_->value();
    s.expired_dropped = expired_dropped_->value();
    s.data_loss = data_loss_->value();
    return s;
}

}  // namespace tessera::server
