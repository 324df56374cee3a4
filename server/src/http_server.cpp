// The HTTP front end on Boost.Beast: config.http_threads event loops, one io_context per thread,
// connections dealt out among them round-robin as they are accepted; a connection's handlers all
// run on its loop's one thread (never concurrently, no strand and no cross-thread wake-ups on the
// hot path; measured faster than one io_context shared by every thread). A session reads one
// request at a time (keep-alive, pipelined requests answered in order), calling the transport-free
// HttpHandler and writing its response.
//
// Bounds: at most config.max_connections sessions; beyond that a connection is answered 503
// "too many connections" (Retry-After: 1) at once, without its request being read, and closed
// (TLS: after the handshake, bounded by kRejectTimeout; then the usual bounded close). A reject
// holds no request buffer and lives a few seconds at most, so every client past the limit gets
// its answer; past kMaxRejectSessions such sessions, a plain connection gets a canned 503 written
// on the spot and a TLS one is closed, so a flood holds no more than that. Request line + headers at most config.max_header_bytes (431); any request body 413
// (GET and HEAD take none); a Transfer-Encoding that does not end in chunked, or one in an
// HTTP/1.0 request, 400 (RFC 9112 6.1, 6.3); a transfer coding besides chunked 501; any other
// malformed request 400. All of these close the connection. config.idle_timeout bounds waiting
// for a request and every read and write.
// GCC 12 warns (-Wtsan) that std::atomic_thread_fence, which Asio's handler fences use, is not
// understood by ThreadSanitizer; Asio's real synchronisation is its mutexes, so the warning is
// noise here, and -Werror would make it fatal in the sanitizer build. Before any include: the
// diagnostic points into <atomic>.
#if defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 12
#pragma GCC diagnostic ignored "-Wtsan"
#endif
#include "http_server.hpp"

#include <pthread.h>
#include <openssl/ssl.h>

#include <array>
#include <atomic>
#include <condition_variable>
#include <fstream>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <type_traits>
#include <unordered_map>
#include <utility>
#include <vector>

#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/ssl.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/strand.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>

#include "http/common.hpp"
#include "http_handler.hpp"
#include "http_response_head.hpp"
#include "tessera/host_port.hpp"
#include "thread_slice.hpp"
#include "work_executor.hpp"

namespace tessera::server {

namespace {

namespace net = boost::asio;
namespace ssl = boost::asio::ssl;
namespace beast = boost::beast;
namespace http = boost::beast::http;
using tcp = boost::asio::ip::tcp;
using error_code = boost::system::error_code;
// A connection's socket names its loop's executor type: no type-erased executor copied and
// destroyed around every operation.
using Socket = net::basic_stream_socket<tcp, net::io_context::executor_type>;
using Clock = std::chrono::steady_clock;

constexpr std::chrono::seconds kLingerTimeout{2};  // reading what a closing client still sends
constexpr std::size_t kLingerBytes = 256 * 1024;
constexpr std::chrono::seconds kRejectTimeout{5};  // an over-limit TLS connection's handshake must come soon
// Reject sessions (each a few KiB and a descriptor, for a few seconds) at most; past it a
// connection is answered (plain) or closed (TLS) on the spot, holding nothing.
constexpr std::size_t kMaxRejectSessions = 1024;

std::string_view sv(beast::string_view s) { return {s.data(), s.size()}; }

// The answer past --max-connections, before its CORS headers (which the caller adds).
HttpResponse too_many_connections() {
    HttpResponse r = http_error_response(503, "too many connections");
    r.headers.emplace_back("Retry-After", "1");
    return r;
}

// The same answer as bytes, for a flood past kMaxRejectSessions, written on the spot without a
// session: the request is never read, so CORS is as to the allowed origin (as a reject
// session's is).
std::string canned_reject(const ServerConfig& config) {
    HttpResponse r = too_many_connections();
    httpapi::add_cors_headers(r, config, config.cors_origin);
    std::string out;
    write_response_head(out, r, 11, false, r.body.size());
    return out + r.body;
}

// RFC 9112 3.2.2: a server must accept a request target in absolute form ("GET http://h/p"), and
// then use its authority as the host, ignoring the Host header. Rewrites such a target to its
// path and query (origin form), `host` to its authority; an empty path is "/" ("http://h?q" is
// "/?q", held in `storage`). False for a fragment, which no request target has.
bool origin_form(std::string_view& target, std::string_view& host, std::string& storage) {
    const auto starts = [&](std::string_view prefix) {
        const std::string_view head = target.substr(0, prefix.size());
        return beast::iequals(beast::string_view(head.data(), head.size()), beast::string_view(prefix.data(), prefix.size()));
    };
    std::size_t scheme = 0;
    if (starts("http://")) scheme = 7;
    else if (starts("https://")) scheme = 8;
    if (scheme == 0) return true;
    const std::string_view rest = target.substr(scheme);
    const std::size_t path = rest.find_first_of("/?#");
    host = rest.substr(0, path);
    if (host.empty()) return false;  // "http://?x": an http URI has a host (RFC 9110 4.2.1)
    if (path == std::string_view::npos) {
        target = "/";
        return true;
    }
    if (rest[path] == '#') return false;
    if (rest[path] == '?') {
        storage = "/";
        storage += rest.substr(path);
        target = storage;
        return true;
    }
    target = rest.substr(path);
    return true;
}

struct SessionBase;

// State the sessions share with the server. Declared before the io_context in the server, so it
// outlives every session (sessions die with the io_context's pending handlers).
struct Shared {
    ServerContext& ctx;
    HttpHandler handler;
    // null: plain HTTP. Replaced whole by reload_tls; a session keeps the context it started
    // with (its own reference), so connections already open are never disturbed.
    std::shared_ptr<ssl::context> tls_;
    mutable std::mutex tls_mutex;
    std::shared_ptr<ssl::context> tls() const {
        std::lock_guard lock(tls_mutex);
        return tls_;
    }
    void set_tls(std::shared_ptr<ssl::context> t) {
        std::lock_guard lock(tls_mutex);
        tls_ = std::move(t);
    }

    std::atomic<bool> draining{false};
    std::atomic<bool> stopped{false};
    std::atomic<std::size_t> connections{0};  // admitted sessions
    std::atomic<std::size_t> rejects{0};      // sessions answering 503 past max_connections

    // busy: requests read and not yet answered. Counted without a lock (every request passes
    // here twice, from every loop); the mutex only pairs the last one's wake-up with wait_idle.
    std::mutex idle_mutex;
    std::condition_variable idle_cv;
    std::atomic<std::size_t> busy{0};

    std::mutex sessions_mutex;  // every live session, to drain or close them
    std::condition_variable sessions_cv;
    std::unordered_map<const SessionBase*, std::weak_ptr<SessionBase>> sessions;

    // Reads and renders, off the loops. After the handler: destroyed (stopped) before it.
    WorkExecutor executor;

    // What a connection past kMaxRejectSessions is sent (plain HTTP), and its body's size.
    const std::string canned_reject;
    const std::size_t canned_reject_body;

    explicit Shared(ServerContext& c)
        : ctx(c), handler(c), executor(work_limits(c.config), c.metrics),
          canned_reject(tessera::server::canned_reject(c.config)),
          canned_reject_body(too_many_connections().body.size()) {}

    static WorkLimits work_limits(const ServerConfig& config) {
        WorkLimits l;
        l.threads = std::max(1u, config.work_threads);
        l.store_inflight = std::max<std::size_t>(1, config.store_inflight);
        l.store_queue = std::max<std::size_t>(1, config.store_queue);
        l.render_concurrency =
            config.render_concurrency ? config.render_concurrency : std::max(1u, std::thread::hardware_concurrency());
        l.render_queue = std::max<std::size_t>(1, config.render_queue);
        l.render_memory = config.render_memory_bytes;
        return l;
    }

    bool closing_connections() const { return draining.load() || stopped.load() || ctx.draining.load(); }
    void request_begin() { busy.fetch_add(1, std::memory_order_relaxed); }
    void request_end() {
        if (busy.fetch_sub(1, std::memory_order_acq_rel) != 1) return;
        std::lock_guard lock(idle_mutex);
        idle_cv.notify_all();
    }
};

struct SessionBase : std::enable_shared_from_this<SessionBase> {
    virtual ~SessionBase() = default;
    virtual void start() = 0;
    virtual void post_drain() = 0;  // close now if waiting for a request; else after the response
    virtual void post_close() = 0;  // close now
};

template <bool Tls>
class Session final : public SessionBase {
    using Stream = std::conditional_t<Tls, beast::ssl_stream<Socket>, Socket>;
    enum class State { handshake, reading, busy, closing, closed };

public:
    Session(Shared& shared, Socket&& socket, bool reject)
        : shared_(shared),
          tls_(Tls ? shared.tls() : nullptr),
          stream_(make_stream(tls_, std::move(socket))),
          timer_(tcp().get_executor()),
          reject_(reject) {
        (reject_ ? shared_.rejects : shared_.connections).fetch_add(1);
    }
    ~Session() override {
        if (in_request_) shared_.request_end();
        (reject_ ? shared_.rejects : shared_.connections).fetch_sub(1);
        std::lock_guard lock(shared_.sessions_mutex);
        shared_.sessions.erase(static_cast<const SessionBase*>(this));
        shared_.sessions_cv.notify_all();
    }

    void start() override {
        net::dispatch(stream_.get_executor(), [self = self()] {
            if constexpr (Tls) {
                self->state_ = State::handshake;
                self->set_deadline(self->read_timeout());
                self->stream_.async_handshake(ssl::stream_base::server, [self](const error_code& ec) {
                    if (ec) return self->close();
                    self->first_step();
                });
            } else {
                self->first_step();
            }
        });
    }

    void post_drain() override {
        net::post(stream_.get_executor(), [self = self()] {
            // Waiting for a request with nothing of one received yet: idle, close it. Otherwise
            // the response in progress goes out with Connection: close.
            const bool idle = self->state_ == State::handshake ||
                              (self->state_ == State::reading && self->buffer_.size() == 0 &&
                               (!self->parser_ || !self->parser_->got_some()));
            if (idle) self->close();
        });
    }
    void post_close() override {
        net::post(stream_.get_executor(), [self = self()] { self->close(); });
    }

private:
    static Stream make_stream(const std::shared_ptr<ssl::context>& tls, Socket&& socket) {
        if constexpr (Tls) return Stream(std::move(socket), *tls);
        else return Stream(std::move(socket));
    }
    std::shared_ptr<Session> self() { return std::static_pointer_cast<Session>(shared_from_this()); }
    Socket& tcp() {
        if constexpr (Tls) return stream_.next_layer();
        else return stream_;
    }

    // Timeouts. Every wait (handshake, request, write, linger) has a deadline; moving it is a
    // store, not a timer operation, so the hot path touches no timer queue. One timer per
    // connection wakes at the earliest deadline it may have to enforce: it closes the connection
    // if the deadline has passed, and otherwise sleeps until the current one. Closing the socket
    // ends whatever operation was waiting (operation_aborted).
    void set_deadline(Clock::duration d) {
        deadline_ = Clock::now() + d;
        if (deadline_ < timer_at_) arm_timer(deadline_);
    }
    void arm_timer(Clock::time_point at) {
        timer_at_ = at;
        timer_.expires_at(at);  // cancels a wait already pending: its handler sees operation_aborted
        timer_.async_wait([self = self()](const error_code& ec) {
            if (ec || self->state_ == State::closed) return;
            if (Clock::now() >= self->deadline_) return self->close();
            self->arm_timer(self->deadline_);
        });
    }
    std::chrono::steady_clock::duration read_timeout() const {
        const std::chrono::steady_clock::duration idle = shared_.ctx.config.idle_timeout;
        return reject_ ? std::min<std::chrono::steady_clock::duration>(idle, kRejectTimeout) : idle;
    }

    // The address this connection reached, as a Host value ("127.0.0.1:8080", "[::1]:8080"):
    // the authority of a request that names none, for the URLs IIIF answers with.
    std::string_view reached_address() {
        if (reached_.empty()) {
            error_code ec;
            const tcp::endpoint ep = tcp().local_endpoint(ec);
            if (ec) return reached_;
            if (ep.address().is_v6()) {
                auto v6 = ep.address().to_v6();
                v6.scope_id(0);  // a zone ("%eth0") is not part of a URL's host
                reached_ = "[" + v6.to_string() + "]:" + std::to_string(ep.port());
            } else {
                reached_ = ep.address().to_string() + ":" + std::to_string(ep.port());
            }
        }
        return reached_;
    }

    void first_step() {
        if (reject_) send_reject();
        else do_read();
    }

    void do_read() {
        if (state_ == State::closed || state_ == State::closing) return;
        if (shared_.closing_connections() && requests_ > 0) return graceful_close();
        state_ = State::reading;
        parser_.emplace();
        parser_->header_limit(static_cast<std::uint32_t>(std::min<std::size_t>(shared_.ctx.config.max_header_bytes, UINT32_MAX)));
        // No request takes a body: one is refused (413) as soon as its header says so.
        parser_->body_limit(0);
        set_deadline(read_timeout());
        parse_buffered();
    }

    // The request is parsed from what the connection has already sent (pipelined requests) and
    // read as it comes: Beast's parser fed directly, as http::async_read would feed it, without
    // its composed operation around every read.
    void parse_buffered() {
        while (buffer_.size() > 0 && !parser_->is_done()) {
            error_code ec;
            const std::size_t used = parser_->put(buffer_.data(), ec);
            buffer_.consume(used);
            if (ec == http::error::need_more) break;
            if (ec) return on_read(ec);
            if (used == 0) break;
        }
        if (parser_->is_done()) return on_read({});
        read_more();
    }

    void read_more() {
        // As Beast reads: at least 512 bytes of room, at most 64 KiB a read. The parser's header
        // limit bounds how far the buffer grows.
        const std::size_t room = std::min<std::size_t>(std::max<std::size_t>(512, buffer_.capacity() - buffer_.size()), 65536);
        stream_.async_read_some(buffer_.prepare(room), [self = self()](const error_code& ec, std::size_t n) {
            self->buffer_.commit(n);
            if (self->state_ == State::closed) return;
            if (ec == net::error::eof) {
                // A request cut short is partial_message; none begun is the end of the stream.
                if (!self->parser_->got_some()) return self->on_read(http::error::end_of_stream);
                error_code e;
                self->parser_->put_eof(e);
                return self->on_read(e);
            }
            if (ec) return self->on_read(ec);
            self->parse_buffered();
        });
    }

    void on_read(const error_code& ec) {
        if (state_ == State::closed) return;
        // body_limit comes once the whole header is parsed: the framing is checked first, so a
        // bad Transfer-Encoding is 400 whether or not a body follows.
        if (!ec || ec == http::error::body_limit) {
            const bool head = parser_->get().method() == http::verb::head;
            if (auto bad = bad_transfer_encoding(parser_->get(), parser_->chunked()))
                return write_error(bad->first, bad->second, head);
            if (ec) return write_error(413, "request body not accepted (GET and HEAD take none)", head);
        }
        if (ec) {
            if (ec == http::error::end_of_stream) return graceful_close();
            if (ec == http::error::header_limit) return write_error(431, "request header fields too large");
            const error_code any_http_error = http::error::bad_method;
            if (ec.category() == any_http_error.category() && ec != http::error::partial_message)
                return write_error(400, "malformed request: " + ec.message());
            return close();  // timeout, reset, TLS error, aborted by close()
        }
        const auto& req = parser_->get();
        // RFC 9112 3.2: an HTTP/1.1 request without Host, or any with two, is 400.
        const auto hosts = req.equal_range(http::field::host);
        const auto host_fields = std::distance(hosts.first, hosts.second);
        if (host_fields != 1 && (host_fields > 1 || req.version() >= 11))
            return write_error(400, host_fields > 1 ? "more than one Host header" : "an HTTP/1.1 request needs a Host header",
                               req.method() == http::verb::head);
        ++requests_;
        begin_request();
        std::string if_none_match;
        const auto range = req.equal_range(http::field::if_none_match);
        for (auto it = range.first; it != range.second; ++it) {
            if (!if_none_match.empty()) if_none_match += ", ";
            if_none_match.append(it->value().data(), it->value().size());
        }
        std::string_view target = sv(req.target()), host = host_fields == 1 ? sv(hosts.first->value()) : std::string_view();
        std::string origin_target;  // an absolute-form target with an empty path, rewritten
        if (!origin_form(target, host, origin_target)) return write_error(400, "malformed absolute-form request target");
        if (host.empty()) host = reached_address();  // HTTP/1.0 without Host: what it connected to
        const HttpRequestView view{sv(req.method_string()), target, sv(req[http::field::authorization]),
                                   if_none_match,         sv(req[http::field::accept]), sv(req[http::field::cookie]),
                                   sv(req[http::field::origin]), host, Tls};
        HttpResponse r;
        try {
            r = shared_.handler.start(view, /*borrow_payload=*/true);
        } catch (const std::exception& e) {
            // The handler catches its own errors; this is only allocation failure and the like.
            shared_.ctx.log.error("http handler threw", {{"error", e.what()}});
            r = http_error_response(500, "internal error");
        }
        const unsigned version = req.version();
        const bool head = req.method() == http::verb::head;
        const bool keep_alive = req.keep_alive() && !shared_.closing_connections();
        if (r.deferred) return run_deferred(std::move(r.deferred), version, head, keep_alive);
        send(std::move(r), version, head, keep_alive);
    }

    // The answer needs a read or a render: it runs on the executor, and its response comes back
    // to this connection's loop. The loop goes on serving other connections meanwhile; this one
    // waits (it reads its next request only after this answer is written). Work that finds it
    // needs more of another kind (a render after a read) comes back as a follow-up, admitted on
    // its own, under the same deadline.
    void run_deferred(std::shared_ptr<DeferredAnswer> d, unsigned version, bool head, bool keep_alive,
                      std::optional<Clock::time_point> deadline = std::nullopt) {
        if (!deadline) deadline = Clock::now() + shared_.ctx.config.request_timeout;
        // The connection waits for the answer, which comes by the request's deadline (504 then):
        // the idle deadline set for reading this request must not close it meanwhile.
        set_deadline(*deadline - Clock::now() + shared_.ctx.config.idle_timeout);
        WorkJob job;
        job.kind = d->kind;
        job.store = d->store ? d->store->name : std::string();
        job.memory = d->memory;
        job.deadline = *deadline;
        job.run = [self = self(), d, version, head, keep_alive, deadline = *deadline](bool started) mutable {
            HttpHandler& handler = self->shared_.handler;
            HttpResponse r;
            try {
                if (!started) {
                    r = handler.expired(*d);
                } else {
                    HttpResponse answered;
                    try {
                        answered = d->answer();
                    } catch (const std::exception& e) {
                        self->shared_.ctx.log.error("http work failed", {{"target", d->target}, {"error", e.what()}});
                        answered = HttpResponse{};
                        answered.status = 500;
                        answered.content_type = "text/plain; charset=utf-8";
                        answered.body = "internal error\n";
                        answered.headers.emplace_back("Cache-Control", "no-store");
                    }
                    if (answered.deferred) {  // a follow-up: submitted from the connection's loop
                        auto next = handler.follow_up(*d, std::move(answered));
                        auto executor = self->stream_.get_executor();
                        net::post(executor, [self = std::move(self), next = std::move(next), version, head, keep_alive,
                                             deadline]() mutable {
                            self->run_deferred(std::move(next), version, head, keep_alive, deadline);
                        });
                        return;
                    }
                    r = handler.complete(*d, std::move(answered));
                }
                // The session goes with the response to its own loop: this job keeps no reference,
                // so a session never ends on a worker thread.
                auto executor = self->stream_.get_executor();
                net::post(executor, [self = std::move(self), r = std::move(r), version, head, keep_alive]() mutable {
                    self->send(std::move(r), version, head, keep_alive);
                });
            } catch (...) {
                // No memory for the answer or the post: the session ends with its loop.
            }
        };
        const Admission a = shared_.executor.submit(std::move(job));
        if (a != Admission::admitted) send(shared_.handler.refused(*d, a), version, head, keep_alive);
    }

    // RFC 9112 6.1 and 6.3: a request's Transfer-Encoding must end in chunked (else its length
    // cannot be known: 400, or the rest would be read as the next request), is faulty framing in
    // HTTP/1.0 (400), and chunked is the only coding served (others: 501). nullopt: acceptable.
    static std::optional<std::pair<unsigned, std::string>> bad_transfer_encoding(
        const http::request<http::string_body>& req, bool chunked_last) {
        const auto range = req.equal_range(http::field::transfer_encoding);
        if (range.first == range.second) return std::nullopt;
        if (req.version() < 11) return std::pair{400u, std::string("Transfer-Encoding in an HTTP/1.0 request")};
        if (!chunked_last) return std::pair{400u, std::string("Transfer-Encoding must end in chunked")};
        for (auto it = range.first; it != range.second; ++it)
            for (const auto coding : http::token_list{it->value()})
                if (!beast::iequals(coding, "chunked"))
                    return std::pair{501u, "transfer coding '" + std::string(sv(coding)) + "' not implemented (only chunked)"};
        return std::nullopt;
    }

    // Over the connection limit: answered at once, the request (if any) never parsed, only
    // drained by the close. A reject costs a small session for a few seconds at most.
    void send_reject() {
        begin_request();
        HttpResponse r = too_many_connections();
        shared_.handler.finish_transport_response(r, false, std::nullopt);
        send(std::move(r), 11, false, false);
    }

    // A response the transport makes itself (the request could not be parsed or is refused as
    // framed): sent, then closed. head: the request is known to be a HEAD (no body then).
    void write_error(unsigned status, const std::string& message, bool head = false) {
        begin_request();
        HttpResponse r = http_error_response(status, message);
        // The Origin header, when the request's header was read whole.
        std::optional<std::string_view> origin;
        if (parser_ && parser_->is_header_done()) origin = sv(parser_->get()[http::field::origin]);
        shared_.handler.finish_transport_response(r, head, origin);
        send(std::move(r), 11, head, false);
    }

    void begin_request() {
        if (!in_request_) shared_.request_begin();
        in_request_ = true;
        state_ = State::busy;
    }
    void end_request() {
        if (in_request_) shared_.request_end();
        in_request_ = false;
    }

    // The body is written from where it lies (held_: the response's string, or the cached tile
    // itself for stored payloads), in one gather write with the hand-written head: no copy into
    // a body, no per-header allocation.
    //
    // The two buffers go as a buffers_cat, not a std::array of two. For a two-element std::array,
    // Asio's async_write hands the stream an empty first buffer once the head is written; Beast's
    // ssl_stream (a flat_stream) sends a first buffer alone when the next one would take the write
    // past 16 KiB: here 0 bytes, which async_write takes for the end of the write. Over TLS every
    // body over 16 KiB was dropped and the next response followed the head. Asio's general path,
    // which buffers_cat takes, skips consumed buffers.
    void send(HttpResponse r, unsigned version, bool head, bool keep_alive) {
        held_ = std::move(r);
        const bool bodiless = bodiless_status(held_.status);
        const std::size_t length = held_.body_size();
        write_response_head(head_, held_, version, keep_alive, length);
        net::const_buffer body;
        if (!head && !bodiless && length > 0)
            body = held_.payload ? net::buffer(held_.payload->bytes.data(), length) : net::buffer(held_.body);
        set_deadline(shared_.ctx.config.idle_timeout);
        net::async_write(stream_, beast::buffers_cat(net::buffer(head_), body),
                         [self = self(), keep_alive](const error_code& ec, std::size_t) { self->after_write(ec, keep_alive); });
    }

    void after_write(const error_code& ec, bool keep_alive) {
        end_request();
        held_ = HttpResponse{};
        if (state_ == State::closed) return;
        if (ec) return close();
        if (!keep_alive) return graceful_close();
        do_read();
    }

    // TLS: close_notify (bounded). Plain: stop sending, then read and drop what the client still
    // sends until it closes (bounded), so that unread request bytes do not make the kernel reset
    // the connection before the client has read our response.
    void graceful_close() {
        if (state_ == State::closed || state_ == State::closing) return;
        state_ = State::closing;
        set_deadline(kLingerTimeout);
        if constexpr (Tls) {
            stream_.async_shutdown([self = self()](const error_code&) { self->close(); });
        } else {
            error_code ec;
            tcp().shutdown(tcp::socket::shutdown_send, ec);
            if (ec) return close();
            linger();
        }
    }
    void linger() {
        tcp().async_read_some(net::buffer(linger_buf_), [self = self()](const error_code& ec, std::size_t n) {
            self->lingered_ += n;
            if (ec || self->lingered_ > kLingerBytes || self->state_ == State::closed) return self->close();
            self->linger();
        });
    }

    void close() {
        if (state_ == State::closed) return;
        state_ = State::closed;
        error_code ec;
        tcp().shutdown(tcp::socket::shutdown_both, ec);
        tcp().close(ec);  // pending operations complete with operation_aborted
        timer_.cancel();
    }

    Shared& shared_;
    std::shared_ptr<ssl::context> tls_;  // the context this session's TLS stream was made from
    Stream stream_;
    net::basic_waitable_timer<Clock, net::wait_traits<Clock>, net::io_context::executor_type> timer_;
    std::string reached_;  // reached_address(), once asked
    Clock::time_point deadline_ = Clock::time_point::max();
    Clock::time_point timer_at_ = Clock::time_point::max();  // when the timer wakes next
    const bool reject_;
    State state_ = State::reading;
    bool in_request_ = false;
    std::uint64_t requests_ = 0;
    beast::flat_buffer buffer_;
    std::optional<http::request_parser<http::string_body>> parser_;
    std::string head_;   // the response head being written (capacity reused)
    HttpResponse held_;  // owns the body bytes until the write completes
    std::array<char, 4096> linger_buf_{};
    std::size_t lingered_ = 0;
};

Result<tcp::endpoint> resolve_endpoint(const std::string& address, net::io_context& ioc) {
    if (address.empty()) return make_error(Errc::invalid_argument, "HTTP address is empty");
    const auto parts = split_host_port(address);
    if (!parts || !parts->has_port)
        return make_error(Errc::invalid_argument, "HTTP address '" + address + "': expected HOST:PORT or [IPV6]:PORT");
    const std::string host(parts->host), port(parts->port);
    if (!parts->bracketed && host.find(':') != std::string::npos)
        return make_error(Errc::invalid_argument, "HTTP address '" + address + "': an IPv6 address needs brackets, [ADDR]:PORT");
    if (host.empty()) return make_error(Errc::invalid_argument, "HTTP address '" + address + "': missing host");
    const auto port_value = parse_port(port);
    if (!port_value) return make_error(Errc::invalid_argument, "HTTP address '" + address + "': port must be 0..65535");

    error_code ec;
    const net::ip::address ip = net::ip::make_address(host, ec);
    if (!ec) return tcp::endpoint(ip, *port_value);
    tcp::resolver resolver(ioc);
    const auto results = resolver.resolve(host, port, ec);
    if (ec || results.empty())
        return make_error(Errc::io_error, "HTTP address '" + address + "': cannot resolve '" + host + "': " +
                                              (ec ? ec.message() : std::string("no addresses")));
    return results.begin()->endpoint();
}

bool readable(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    return f.good();
}

Result<std::shared_ptr<ssl::context>> make_tls_context(const ServerConfig& config) {
    if (config.tls_cert_file.empty() != config.tls_key_file.empty())
        return make_error(Errc::invalid_argument, "TLS needs both a certificate and a key file");
    if (!readable(config.tls_cert_file))
        return make_error(Errc::io_error, "cannot read TLS certificate '" + config.tls_cert_file + "'");
    if (!readable(config.tls_key_file))
        return make_error(Errc::io_error, "cannot read TLS key '" + config.tls_key_file + "'");
    auto tls = std::make_shared<ssl::context>(ssl::context::tls_server);
    error_code ec;
    tls->set_options(ssl::context::default_workarounds | ssl::context::no_sslv2 | ssl::context::no_sslv3 |
                         ssl::context::no_tlsv1 | ssl::context::no_tlsv1_1 | ssl::context::single_dh_use,
                     ec);
    if (ec) return make_error(Errc::io_error, "TLS options: " + ec.message());
    SSL_CTX_set_min_proto_version(tls->native_handle(), TLS1_2_VERSION);
    tls->use_certificate_chain_file(config.tls_cert_file, ec);
    if (ec)
        return make_error(Errc::io_error, "cannot load TLS certificate '" + config.tls_cert_file + "': " + ec.message());
    tls->use_private_key_file(config.tls_key_file, ssl::context::pem, ec);
    if (ec) return make_error(Errc::io_error, "cannot load TLS key '" + config.tls_key_file + "': " + ec.message());
    if (SSL_CTX_check_private_key(tls->native_handle()) != 1)
        return make_error(Errc::invalid_argument, "TLS key '" + config.tls_key_file + "' does not match the certificate '" +
                                                      config.tls_cert_file + "'");
    return tls;
}

using Loops = std::vector<std::unique_ptr<net::io_context>>;
using WorkGuard = net::executor_work_guard<net::io_context::executor_type>;

class HttpServerImpl final : public HttpServer {
public:
    explicit HttpServerImpl(ServerContext& ctx, unsigned threads)
        : shared_(ctx),
          iocs_(make_loops(threads)),
          accept_strand_(net::make_strand(*iocs_.front())),
          acceptor_(accept_strand_),
          retry_timer_(accept_strand_),
          thread_count_(threads) {
        work_.reserve(iocs_.size());
        for (auto& ioc : iocs_) work_.emplace_back(net::make_work_guard(*ioc));
    }

    ~HttpServerImpl() override { stop(); }

    Status reload_tls() override {
        if (!shared_.tls()) return {};
        auto tls = make_tls_context(shared_.ctx.config);
        if (!tls.ok()) return tls.error();  // the old certificate stays in force
        shared_.set_tls(std::move(tls.value()));
        return {};
    }

    Status open() {
        const ServerConfig& config = shared_.ctx.config;
        if (!config.tls_cert_file.empty() || !config.tls_key_file.empty()) {
            auto tls = make_tls_context(config);
            if (!tls.ok()) return tls.error();
            shared_.set_tls(std::move(tls.value()));
        }
        auto ep = resolve_endpoint(config.http_address, *iocs_.front());
        if (!ep.ok()) return ep.error();
        error_code ec;
        acceptor_.open(ep->protocol(), ec);
        if (!ec) acceptor_.set_option(net::socket_base::reuse_address(true), ec);
        if (!ec) acceptor_.bind(*ep, ec);
        if (!ec) acceptor_.listen(net::socket_base::max_listen_connections, ec);
        if (ec) return make_error(Errc::io_error, "cannot listen on HTTP address '" + config.http_address + "': " + ec.message());
        port_ = acceptor_.local_endpoint(ec).port();

        shared_.ctx.metrics.gauge_callback("tessera_http_connections", "Open HTTP connections (admitted)", {},
                                           [s = &shared_] { return static_cast<double>(s->connections.load()); });
        gauge_registered_ = true;

        net::dispatch(accept_strand_, [this] { do_accept(); });
        for (unsigned i = 0; i < thread_count_; ++i) threads_.emplace_back([this, i] { run(*iocs_[i]); });
        shared_.ctx.log.info("http listening", {{"address", config.http_address}, {"port", static_cast<unsigned>(port_)},
                                                {"tls", shared_.tls() != nullptr}, {"threads", thread_count_}});
        return {};
    }

    std::uint16_t port() const override { return port_; }

    void begin_drain() override {
        if (shared_.draining.exchange(true) || shared_.stopped.load()) return;
        close_acceptor();
        for (auto& s : live_sessions()) s->post_drain();
    }

    bool wait_idle(std::chrono::milliseconds timeout) override {
        std::unique_lock lock(shared_.idle_mutex);
        return shared_.idle_cv.wait_for(lock, timeout, [&] { return shared_.busy == 0; });
    }

    void stop() override {
        if (shared_.stopped.exchange(true)) return;
        if (!threads_.empty()) {
            close_acceptor();
            for (auto& s : live_sessions()) s->post_close();
            // Let the closes run (sockets closed, sessions released), briefly; then stop.
            std::unique_lock lock(shared_.sessions_mutex);
            shared_.sessions_cv.wait_for(lock, std::chrono::seconds(2), [&] { return shared_.sessions.empty(); });
        }
        // Waiting work is answered (its sessions are closed: nothing is written); running work
        // is waited for: its remote reads end by its deadline, a render or a local read when done.
        shared_.executor.stop();
        work_.clear();
        for (auto& ioc : iocs_) ioc->stop();
        for (auto& t : threads_)
            if (t.joinable()) t.join();
        threads_.clear();
        if (gauge_registered_) shared_.ctx.metrics.remove_callbacks("tessera_http_connections");
        gauge_registered_ = false;
    }

private:
    static Loops make_loops(unsigned n) {
        Loops loops;
        // Concurrency hint 1: each loop is run by one thread (other threads still post to it).
        for (unsigned i = 0; i < n; ++i) loops.push_back(std::make_unique<net::io_context>(1));
        return loops;
    }

    void run(net::io_context& ioc) {
        pthread_setname_np(pthread_self(), "http-loop");
        request_short_slice(shared_.ctx.config.http_loop_slice);
        for (;;) {
            try {
                ioc.run();
                return;
            } catch (const std::exception& e) {
                shared_.ctx.log.error("http event loop error", {{"error", e.what()}});
            }
        }
    }

    // On the acceptor's strand, waiting (bounded) so that once begin_drain/stop return the port
    // refuses connections.
    void close_acceptor() {
        auto done = std::make_shared<std::promise<void>>();
        auto fut = done->get_future();
        net::post(accept_strand_, [this, done] {
            error_code ec;
            acceptor_.close(ec);
            retry_timer_.cancel();
            done->set_value();
        });
        fut.wait_for(std::chrono::seconds(2));
    }

    std::vector<std::shared_ptr<SessionBase>> live_sessions() {
        std::vector<std::shared_ptr<SessionBase>> out;
        std::lock_guard lock(shared_.sessions_mutex);
        for (auto& [k, w] : shared_.sessions)
            if (auto s = w.lock()) out.push_back(std::move(s));
        return out;
    }

    void do_accept() {
        if (!acceptor_.is_open()) return;
        // The next loop in turn owns the connection; its executor is the loop's (one thread: no strand).
        net::io_context& loop = *iocs_[next_loop_++ % iocs_.size()];
        acceptor_.async_accept(loop.get_executor(), [this](const error_code& ec, Socket socket) {
            on_accept(ec, std::move(socket));
        });
    }

    void on_accept(const error_code& ec, Socket socket) {
        if (ec == net::error::operation_aborted || !acceptor_.is_open()) return;
        if (ec) {
            // Out of file descriptors and the like: back off a little instead of spinning.
            shared_.ctx.log.warn("http accept failed", {{"error", ec.message()}});
            retry_timer_.expires_after(std::chrono::milliseconds(50));
            retry_timer_.async_wait([this](const error_code& e) {
                if (!e) do_accept();
            });
            return;
        }
        error_code ignored;
        socket.set_option(tcp::no_delay(true), ignored);
        const bool reject = shared_.connections.load() >= shared_.ctx.config.max_connections;
        if (reject && shared_.rejects.load() >= kMaxRejectSessions) {
            // A flood past the limit: no session at all. Plain HTTP still gets its 503, written
            // into the new socket's empty send buffer without waiting; TLS cannot answer without
            // a handshake, so it is closed.
            if (!shared_.tls()) {
                socket.non_blocking(true, ignored);
                socket.write_some(net::buffer(shared_.canned_reject), ignored);
                socket.shutdown(tcp::socket::shutdown_send, ignored);
            }
            shared_.handler.record_transport_response(503, shared_.canned_reject_body);
            socket.close(ignored);
            return do_accept();
        }
        std::shared_ptr<SessionBase> s;
        if (shared_.tls()) s = std::make_shared<Session<true>>(shared_, std::move(socket), reject);
        else s = std::make_shared<Session<false>>(shared_, std::move(socket), reject);
        {
            std::lock_guard lock(shared_.sessions_mutex);
            shared_.sessions.emplace(s.get(), s);
        }
        s->start();
        do_accept();
    }

    // Destruction order matters: the io_contexts (whose pending handlers own the sessions) go
    // before the shared state the sessions use; the acceptor and timer before the io_contexts.
    Shared shared_;
    Loops iocs_;
    std::vector<WorkGuard> work_;
    net::strand<net::io_context::executor_type> accept_strand_;
    tcp::acceptor acceptor_;
    net::steady_timer retry_timer_;
    unsigned thread_count_;
    std::size_t next_loop_ = 0;  // accept strand only
    std::uint16_t port_ = 0;
    bool gauge_registered_ = false;
    std::vector<std::thread> threads_;
};

}  // namespace

Result<std::unique_ptr<HttpServer>> HttpServer::start(ServerContext& ctx) {
    unsigned threads = ctx.config.http_threads;
    if (threads == 0) threads = std::max(1u, std::thread::hardware_concurrency());
    auto server = std::make_unique<HttpServerImpl>(ctx, threads);
    if (Status s = server->open(); !s.ok()) return s.error();
    return std::unique_ptr<HttpServer>(std::move(server));
}

}  // namespace tessera::server
