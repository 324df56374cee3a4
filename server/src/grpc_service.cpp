#include "grpc_service.hpp"

#include <mutex>

#include <atomic>
#include <climits>
#include <utility>

#include <google/protobuf/io/coded_stream.h>
#include <google/protobuf/wire_format_lite.h>
#include <grpcpp/alarm.h>
#include <grpcpp/support/proto_buffer_reader.h>

#include "auth.hpp"
#include "grpc_handoff.hpp"
#include "reply_buffer.hpp"
#include "tessera/protocol/wire.hpp"
#include "tessera/storage/store_scene.hpp"

namespace tessera::server {

namespace {

using Clock = std::chrono::steady_clock;

constexpr std::size_t kKeepBatchBytes = 256 * 1024;
// Nor one of more requests: a parsed batch keeps its cleared requests for reuse, about 56 bytes
// each whatever they took on the wire.
constexpr int kKeepBatchRequests = 4096;

// What a batch holds, read from its wire bytes without parsing it.
struct BatchShape {
    bool ok = true;  // well-formed as far as the walk goes (else parsing reports it)
    std::uint64_t frame = 0;
    std::uint32_t revision = 0;
    std::size_t stores = 0, requests = 0;
};

BatchShape batch_shape(grpc::ByteBuffer& buf) {
    using google::protobuf::internal::WireFormatLite;
    BatchShape s;
    grpc::ProtoBufferReader reader(&buf);
    google::protobuf::io::CodedInputStream in(&reader);
    for (std::uint32_t tag; (tag = in.ReadTag()) != 0;) {
        const int field = WireFormatLite::GetTagFieldNumber(tag);
        const bool varint = WireFormatLite::GetTagWireType(tag) == WireFormatLite::WIRETYPE_VARINT;
        std::uint64_t value = 0;
        if (varint && (field == 1 || field == 5)) {
            if (!in.ReadVarint64(&value)) return BatchShape{.ok = false};
            if (field == 1) s.frame = value;
            else s.revision = static_cast<std::uint32_t>(std::min<std::uint64_t>(value, UINT32_MAX));
            continue;
        }
        if (field == 2) ++s.stores;
        else if (field == 3) ++s.requests;
        if (!WireFormatLite::SkipField(&in, tag)) return BatchShape{.ok = false};
    }
    return s;
}

// Connects the scheduler (which may outlive a stream's reactor by a few microseconds on an I/O
// thread) to the reactor: the reactor detaches itself in OnDone, under the link's lock.
class StreamReactor;
class ReactorLink final : public ViewerSink {
public:
    explicit ReactorLink(StreamReactor* r) : reactor_(r) {}
    void on_outbox_ready() override;
    void on_hold_over(bool fired);  // the timer of a held batch fired (or was cancelled)
    void detach() {
        std::lock_guard lock(mu_);
        reactor_ = nullptr;
    }

private:
    // Recursive: applying a held batch (on_hold_over) queues its ack, which calls on_outbox_ready
    // on the same thread.
    std::recursive_mutex mu_;
    StreamReactor* reactor_;
};

// Raw messages both ways: batches are parsed here, replies are encoded by hand (reply_buffer.hpp)
// so payloads go out as slices of the cached tiles.
class StreamReactor final : public grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer> {
public:
    StreamReactor(ServerContext& ctx, Scheduler& scheduler, grpc::CallbackServerContext* context, bool authorized,
                  Counter* viewers_refused)
        : ctx_(ctx), scheduler_(scheduler), peer_(context->peer()) {
        // Until the handler returns the reactor is not bound: Start*/Finish here only queue their
        // operation in the reactor (gRPC issues them at binding), so the handoff comes after them.
        if (!authorized) {
            finished_ = true;
            Finish(grpc::Status(grpc::StatusCode::UNAUTHENTICATED, "missing or wrong bearer token"));
            handoff_to_grpc(this);
            return;
        }
        link_ = std::make_shared<ReactorLink>(this);
        auto id = scheduler_.add_viewer(link_);
        if (!id) {
            viewers_refused->inc();
            finished_ = true;
            const bool draining = scheduler_.draining();
            Finish(grpc::Status(
                draining ? grpc::StatusCode::UNAVAILABLE : grpc::StatusCode::RESOURCE_EXHAUSTED,
                draining ? "the server is shutting down"
                         : "too many viewers (limit " + std::to_string(ctx_.config.max_viewers) + "); retry later"));
            handoff_to_grpc(this);
            return;
        }
        id_ = *id;
        ctx_.log.debug("viewer connected", {{"viewer", id_}, {"peer", peer_}});
        StartRead(&read_buf_);
        handoff_to_grpc(this);
    }

    void OnReadDone(bool ok) override {
        reaction_from_grpc(this);
        if (!ok) {  // the viewer half-closed (or left): finish once its admitted work is sent
            if (!apply_held(true)) return;  // its last batch is applied, held or not
            std::unique_lock lock(mu_);
            read_closed_ = true;
            maybe_finish_locked(lock);
            return;
        }
        const auto received = Clock::now();
        // Over the limits: refused from its wire bytes, never parsed.
        const BatchShape shape = batch_shape(read_buf_);
        if (auto refusal = shape.ok ? scheduler_.oversized(shape.requests, shape.stores) : std::nullopt) {
            read_buf_.Clear();
            multi_.store(shape.revision >= 1, std::memory_order_relaxed);
            scheduler_.refuse_batch(id_, shape.frame, shape.requests, refusal->first, std::move(refusal->second));
            continue_reading();
            return;
        }
        // The newest batch waits in the hold slot; an older one still there was never applied and
        // never will be (the newer lists everything the viewer still wants). Its ack is queued
        // under the slot's lock (so before anything of the newer one), and the stream woken after
        // it: waking takes the link's lock, which the hold timer takes before the slot's.
        std::shared_ptr<ViewerSink> wake;
        {
            std::lock_guard hold(hold_mu_);
            if (held_) wake = scheduler_.batch_superseded(id_, held_shape_.frame, held_shape_.requests);
            held_buf_.Swap(&read_buf_);
            held_shape_ = shape;
            held_received_ = received;
            held_ = true;
        }
        if (wake) wake->on_outbox_ready();
        read_buf_.Clear();
        if (!apply_held(false)) return;
        continue_reading();
    }

    // Applies the held batch if the scheduler says it is due (or `force`); otherwise sets the
    // timer for when it will be. One thread applies at a time, oldest first, so a newer batch
    // is never overtaken by an older one. False: the batch was malformed and the stream ends.
    bool apply_held(bool force) {
        {
            std::lock_guard hold(hold_mu_);
            if (applying_) {  // that thread looks at the slot again before it stops
                force_ = force_ || force;
                return true;
            }
            applying_ = true;
            force_ = force_ || force;
        }
        for (bool applied = false;; applied = true) {
            Clock::time_point received{};
            {
                std::unique_lock hold(hold_mu_);
                const auto now = Clock::now();
                Clock::time_point retry_at{};
                const bool forced = std::exchange(force_, false) && held_;
                if (!held_ || (!forced && !scheduler_.batch_due(id_, held_shape_.requests, now, retry_at))) {
                    if (held_) arm_timer_locked(retry_at);
                    applying_ = false;
                    hold.unlock();
                    // A viewer that closed its side meanwhile finishes once what was applied is
                    // sent (maybe_finish_locked waits for the slot).
                    if (applied) kick();
                    return true;
                }
                apply_buf_.Swap(&held_buf_);
                held_buf_.Clear();
                held_ = false;
                received = held_received_;
            }
            if (Clock::now() - received > std::chrono::milliseconds(1)) scheduler_.batch_held();
            const std::size_t wire_bytes = apply_buf_.Length();
            if (!grpc::SerializationTraits<v1::TileBatch>::Deserialize(&apply_buf_, &batch_).ok()) {
                {
                    std::lock_guard hold(hold_mu_);
                    applying_ = false;
                }
                std::unique_lock lock(mu_);
                broken_ = true;
                finish_locked(lock, grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "malformed TileBatch"));
                return false;
            }
            multi_.store(batch_.protocol_revision() >= 1, std::memory_order_relaxed);
            scheduler_.submit(id_, batch_, received);
            // The parsed batch is reused for the next one (its allocations with it), unless it was
            // large: then it is freed, so an idle stream does not keep a --max-message batch alive.
            if (wire_bytes > kKeepBatchBytes || batch_.requests_size() > kKeepBatchRequests) v1::TileBatch().Swap(&batch_);
        }
    }

    void on_hold_over(bool fired) {
        {
            std::lock_guard hold(hold_mu_);
            timer_set_ = false;
        }
        if (fired) apply_held(false);
    }

    // The next batch is read, unless the viewer sends batches but does not read replies: then
    // it stops being read too.
    void continue_reading() {
        std::lock_guard lock(mu_);
        if (finished_) return;
        if (scheduler_.outbox_full(id_)) {
            read_paused_ = true;
        } else {
            handoff_to_grpc(this);
            StartRead(&read_buf_);
        }
    }

    void OnWriteDone(bool ok) override {
        reaction_from_grpc(this);
        const bool full = scheduler_.messages_written(id_, current_, ok);
        current_.clear();  // releases the tiles
        {
            std::unique_lock lock(mu_);
            writing_ = false;
            if (!ok || broken_) {  // broken_: cancelled while this write was in flight
                broken_ = true;
                finish_locked(lock, grpc::Status(grpc::StatusCode::CANCELLED, "the viewer went away"));
                return;
            }
            if (read_paused_ && !read_closed_ && !finished_ && !full) {
                read_paused_ = false;
                handoff_to_grpc(this);
                StartRead(&read_buf_);
            }
        }
        // Tiles went out: the pending set may now be small enough for a held batch.
        bool held;
        {
            std::lock_guard hold(hold_mu_);
            held = held_;
        }
        if (held && !apply_held(false)) return;
        kick();
    }

    void OnCancel() override {
        reaction_from_grpc(this);
        std::unique_lock lock(mu_);
        broken_ = true;
        finish_locked(lock, grpc::Status::CANCELLED);
    }

    void OnDone() override {
        reaction_from_grpc(this);
        if (link_) link_->detach();
        if (id_) scheduler_.remove_viewer(id_);
        ctx_.log.debug("viewer disconnected", {{"viewer", id_}, {"peer", peer_}});
        delete this;
    }

    // Start the next write if none is running; finish when there is nothing left to do.
    void kick() {
        std::unique_lock lock(mu_);
        if (finished_ || writing_ || broken_) return;
        // Revision 1: every reply ready now goes out in one message (natural batching, no waiting).
        const bool multi = multi_.load(std::memory_order_relaxed);
        if (scheduler_.next_messages(id_, current_, multi ? ctx_.config.grpc_message_bytes : 0)) {
            writing_ = true;
            encode_replies(current_, multi, write_buf_, scratch_);
            handoff_to_grpc(this);
            StartWrite(&write_buf_);
            return;
        }
        maybe_finish_locked(lock);
    }

private:
    // One timer at a time; a fired one is replaced (gRPC keeps its state alive until its callback
    // returns, so this is safe from within that callback too). The callback holds the link, which
    // the reactor detaches in OnDone: a timer that fires after the stream ended does nothing.
    void arm_timer_locked(Clock::time_point at) {
        if (timer_set_ || !link_) return;
        timer_set_ = true;
        timer_ = std::make_unique<grpc::Alarm>();
        handoff_to_grpc(link_.get());
        const auto wait = std::max(at - Clock::now(), Clock::duration(std::chrono::microseconds(100)));
        timer_->Set(std::chrono::system_clock::now() + std::chrono::duration_cast<std::chrono::system_clock::duration>(wait),
                    [link = link_](bool ok) {
                        reaction_from_grpc(link.get());
                        link->on_hold_over(ok);  // ok false: cancelled (the stream ended, or shutdown)
                    });
    }

    void maybe_finish_locked(std::unique_lock<std::recursive_mutex>& lock) {
        if (finished_ || writing_) return;
        {
            // A batch held or being applied is the viewer's too: it is applied (and sent) first.
            // (The slot's lock under the reactor's: nothing takes them the other way round.)
            std::lock_guard hold(hold_mu_);
            if (held_ || applying_) return;
        }
        const bool draining = scheduler_.draining();
        if ((read_closed_ || draining) && scheduler_.viewer_idle(id_))
            finish_locked(lock, draining && !read_closed_
                                    ? grpc::Status(grpc::StatusCode::UNAVAILABLE, "the server is shutting down")
                                    : grpc::Status::OK);
    }
    void finish_locked(std::unique_lock<std::recursive_mutex>&, const grpc::Status& status) {
        if (finished_ || writing_) return;  // a running write finishes first (OnWriteDone)
        finished_ = true;
        handoff_to_grpc(this);
        Finish(status);
    }

    ServerContext& ctx_;
    Scheduler& scheduler_;
    std::string peer_;
    std::shared_ptr<ReactorLink> link_;
    Scheduler::ViewerId id_ = 0;
    grpc::ByteBuffer read_buf_;  // only touched by the read path (one read at a time)
    // The hold slot (Scheduler::batch_due): the newest batch read and not yet applied.
    std::mutex hold_mu_;
    grpc::ByteBuffer held_buf_;
    BatchShape held_shape_;
    Clock::time_point held_received_{};
    // force_: apply what is held whether due or not (the viewer closed its side).
    bool held_ = false, applying_ = false, timer_set_ = false, force_ = false;
    std::unique_ptr<grpc::Alarm> timer_;
    // Only touched by the thread applying (applying_).
    grpc::ByteBuffer apply_buf_;
    v1::TileBatch batch_;
    std::atomic<bool> multi_{false};  // the latest batch's protocol_revision >= 1
    std::vector<OutMessage> current_;  // only touched by the write path (one write at a time)
    grpc::ByteBuffer write_buf_;
    std::string scratch_;
    // Recursive: Start* calls are made under it, and gRPC may run a reaction inline on the
    // calling thread when an operation completes at once.
    std::recursive_mutex mu_;
    bool writing_ = false, finished_ = false, read_closed_ = false, read_paused_ = false, broken_ = false;
};

void ReactorLink::on_outbox_ready() {
    std::lock_guard lock(mu_);
    if (reactor_) reactor_->kick();
}

void ReactorLink::on_hold_over(bool fired) {
    std::lock_guard lock(mu_);
    if (reactor_) reactor_->on_hold_over(fired);
}

}  // namespace

GrpcService::GrpcService(ServerContext& ctx, Scheduler& scheduler) : ctx_(ctx), scheduler_(scheduler) {
    unauthenticated_ = &ctx.metrics.counter("tessera_grpc_unauthenticated_total", "gRPC calls refused: bad bearer token");
    viewers_refused_ = &ctx.metrics.counter("tessera_grpc_viewers_refused_total",
                                            "StreamTiles calls refused: too many viewers, or draining");
}

bool GrpcService::authorized(grpc::CallbackServerContext* context) const {
    const auto token = ctx_.auth_token();
    if (token->empty()) return true;
    const auto& md = context->client_metadata();
    auto it = md.find("authorization");
    if (it == md.end() || !server::authorized(std::string_view(it->second.data(), it->second.size()), *token)) {
        unauthenticated_->inc();
        return false;
    }
    return true;
}

namespace {
grpc::ServerUnaryReactor* finish(grpc::CallbackServerContext* context, const grpc::Status& status) {
    auto* r = context->DefaultReactor();
    r->Finish(status);
    return r;
}
const grpc::Status kUnauthenticated(grpc::StatusCode::UNAUTHENTICATED, "missing or wrong bearer token");
}  // namespace

grpc::ServerUnaryReactor* GrpcService::ListStores(grpc::CallbackServerContext* context, const v1::ListStoresRequest*,
                                                  v1::ListStoresReply* reply) {
    if (!authorized(context)) return finish(context, kUnauthenticated);
    for (const auto& h : ctx_.stores.list()) {
        auto* m = reply->add_stores();
        *m = protocol::to_proto(h->name, h->info());
        m->set_has_scene(h->has_scene.load(std::memory_order_relaxed));
    }
    return finish(context, grpc::Status::OK);
}

std::shared_ptr<const StoreHandle> GrpcService::find_store(grpc::CallbackServerContext* context, const std::string& name,
                                                             grpc::Status& refusal) const {
    if (!authorized(context)) {
        refusal = kUnauthenticated;
        return nullptr;
    }
    if (!protocol::valid_store_name(name)) {
        refusal = grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "store names are identifiers ([A-Za-z0-9_.-], no '..'), not paths");
        return nullptr;
    }
    auto h = ctx_.stores.find(name);
    if (!h) refusal = grpc::Status(grpc::StatusCode::NOT_FOUND, "no store named '" + name + "'");
    return h;
}

grpc::ServerUnaryReactor* GrpcService::GetStore(grpc::CallbackServerContext* context, const v1::GetStoreRequest* request,
                                                v1::StoreMetadata* reply) {
    grpc::Status refusal;
    auto h = find_store(context, request->name(), refusal);
    if (!h) return finish(context, refusal);
    *reply = protocol::to_proto(h->name, h->info());
    reply->set_has_scene(h->has_scene.load(std::memory_order_relaxed));
    return finish(context, grpc::Status::OK);
}

grpc::ServerUnaryReactor* GrpcService::GetStoreScene(grpc::CallbackServerContext* context, const v1::GetStoreSceneRequest* request,
                                                     v1::StoreScenePiece* reply) {
    grpc::Status refusal;
    auto h = find_store(context, request->name(), refusal);
    if (!h) return finish(context, refusal);
    const auto path = h->scene_path();
    if (!path) return finish(context, grpc::Status(grpc::StatusCode::NOT_FOUND, "store '" + request->name() + "' has no scene"));
    constexpr std::uint64_t kPiece = 1u << 20;
    auto piece = storage::read_scene_bytes(*path, request->offset(), kPiece);
    if (!piece) return finish(context, grpc::Status(grpc::StatusCode::UNAVAILABLE, piece.error().message));
    reply->set_data(std::move(piece->data));
    reply->set_total_size(piece->total);
    reply->set_version(h->version);
    return finish(context, grpc::Status::OK);
}

grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer>* GrpcService::StreamTiles(
    grpc::CallbackServerContext* context) {
    return new StreamReactor(ctx_, scheduler_, context, authorized(context), viewers_refused_);
}

grpc::ServerUnaryReactor* GrpcService::GetStats(grpc::CallbackServerContext* context, const v1::GetStatsRequest*,
                                                v1::ServerStats* reply) {
    if (!authorized(context)) return finish(context, kUnauthenticated);
    const auto s = scheduler_.stats();
    const auto c = ctx_.fetcher.cache().stats();
    reply->set_uptime_seconds(std::chrono::duration<double>(std::chrono::steady_clock::now() - ctx_.started).count());
    reply->set_viewers(s.viewers);
    reply->set_pending(s.pending);
    reply->set_in_flight(s.in_flight);
    reply->set_batches(s.batches);
    reply->set_requests(s.requests);
    reply->set_tiles_sent(s.tiles_sent);
    reply->set_bytes_sent(s.bytes_sent);
    reply->set_cancelled(s.cancelled);
    reply->set_refused(s.refused);
    reply->set_invalid(s.invalid);
    reply->set_deadline_exceeded(s.deadline_exceeded);
    reply->set_data_loss(s.data_loss);
    reply->set_cache_hits(c.hits);
    reply->set_cache_misses(c.misses);
    reply->set_cache_bytes(c.bytes);
    reply->set_reads(ctx_.fetcher.reads());
    reply->set_tiles_read(ctx_.fetcher.tiles_read());
    reply->set_store_reloads(ctx_.stores.reloads());
    for (const auto& h : ctx_.stores.list()) {
        auto* st = reply->add_stores();
        st->set_name(h->name);
        st->set_version(h->version);
        st->set_tiles_sent(h->metrics.tiles_sent->value());
        st->set_bytes_sent(h->metrics.bytes_sent->value());
        st->set_data_loss(h->metrics.data_loss->value());
    }
    return finish(context, grpc::Status::OK);
}

}  // namespace tessera::server
