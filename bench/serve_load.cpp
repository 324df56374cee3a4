// Load generator for tile servers: gRPC StreamTiles viewers against `tessera serve`, or plain
// HTTP/1.1 GETs against any server (tessera's HTTP front end, nginx serving exported files).
//
// Open model (--rate R > 0): requests are scheduled at fixed times from a start time and never
// wait for replies; a request's latency runs from its *scheduled* time, so a server (or a
// generator) that falls behind shows it as latency instead of silently lowering the offered load
// (no coordinated omission). Closed model (--rate 0): as fast as replies come back, for peak
// throughput.
//
//   HTTP:  --http HOST:PORT --url-file urls.txt [--prefix P] --connections C
//          C keep-alive connections, one request at a time each. Open model: a scheduled request
//          goes out on an idle connection, or waits in the generator until one is free (that wait
//          counts in its latency). Closed: each connection sends the next request as soon as the
//          previous reply is complete.
//   gRPC:  --grpc HOST:PORT --store NAME (--url-file urls.txt | --store-file S.tsr) --viewers V
//          V StreamTiles streams, each on its own connection. Open model: each viewer ticks at
//          --tick-hz (60): every tick it adds rate/tick-hz/V new random tiles to its outstanding
//          set and sends the whole set, oldest first, as one batch (a batch replaces the pending
//          set, so resending everything cancels nothing still wanted). A tile's latency runs from
//          the tick that first asked for it to its arrival. The set is bounded (--max-outstanding);
//          tiles that do not fit are dropped and counted. Closed: the set is topped up to --window
//          whenever half of it has arrived (and at least every tick). A batch due while the
//          previous one is still being written, or while --batches-in-flight (1) batches await
//          their ack, goes out when that write completes or that ack arrives (or 250 ms after the
//          last write), built from the set as it is then; as client/net does (0: no ack wait).
//          The streams are driven asynchronously: --client-threads (1) completion-queue threads
//          and one tick thread. Batches ask for protocol
//          revision --protocol-revision (default 1: several tiles per message; 0: one per message);
//          replies are decoded straight from gRPC's receive slices (tessera/protocol/stream_codec.hpp),
//          payloads counted, not copied.
//
// Tiles are drawn uniformly from every present tile (the URL list, or the store's index) by a
// seeded RNG. Requests scheduled in the first --warmup seconds are sent but not measured.
// Output: a one-line summary, and JSON (stdout, or --json FILE): offered and achieved tiles/s,
// payload MB/s (10^6 bytes), errors, latency percentiles in ms from a log-linear histogram
// (64 buckets per power of two: percentiles are at most 1.6% high).
// --trace FILE (HTTP): a line per measured 200 reply: its scheduled send time (closed loop: its send)
// and latency in µs, and the URL line asked, to tell stalls (tail replies close in time) from slow
// URLs.
#include <arpa/inet.h>
#include <malloc.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/epoll.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/timerfd.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <string_view>
#include <thread>
#include <unordered_map>
#include <vector>

#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>

#include "tessera.grpc.pb.h"
#include "tessera/host_port.hpp"
#include "tessera/protocol/stream_codec.hpp"
#include "tessera/protocol/wire.hpp"
#include "tessera/log_linear_histogram.hpp"
#include "tessera/storage/store_reader.hpp"

namespace {

using Clock = std::chrono::steady_clock;
using Nanos = std::chrono::nanoseconds;
namespace v1 = tessera::v1;

[[noreturn]] void die(const std::string& message) {
    std::fprintf(stderr, "serve_load: %s\n", message.c_str());
    std::exit(1);
}

// ---- Latency histogram ------------------------------------------------------------------------

// Nanoseconds, log-linear (tessera/log_linear_histogram.hpp): exact below 128 ns, above that 64
// buckets per power of two. A bucket spans at most 1/64 of its lowest value; percentiles report
// the bucket's highest value (as HdrHistogram does), so they are never low and at most 1.6% high
// (0.8% from the bucket's middle).
class LatencyHistogram : public tessera::LogLinearHistogram<6, 64> {
public:
    // The smallest bucket bound that at least q of the values are under (q in [0, 1]).
    std::uint64_t percentile(double q) const {
        if (count() == 0) return 0;
        return std::min(bucket_high(quantile_bucket(q)), max());
    }
};

// ---- Options ----------------------------------------------------------------------------------

struct Options {
    std::string grpc, http, store, url_file, store_file, prefix, json_path, trace_path;
    double rate = 0;          // tiles/s offered; 0: closed loop
    double duration = 10;     // measured seconds
    double warmup = 1;        // unmeasured seconds before
    double drain = 5;         // open model: wait this long for late replies after the end
    unsigned connections = 64;
    unsigned viewers = 4;
    unsigned client_threads = 1;         // gRPC: completion-queue threads driving the viewers
    double tick_hz = 60;
    std::size_t window = 512;            // gRPC closed loop: outstanding tiles per viewer
    std::size_t max_outstanding = 4096;  // gRPC open model: bound of a viewer's outstanding set
    std::size_t batches_in_flight = 1;   // gRPC: batches written and not yet acked (0: no bound)
    std::uint32_t protocol_revision = tessera::protocol::kProtocolRevision;
    std::uint64_t seed = 1;
};

void usage() {
    std::fprintf(stderr,
                 "usage: serve_load (--http HOST:PORT --url-file FILE [--prefix P] [--connections C]\n"
                 "                  | --grpc HOST:PORT --store NAME (--url-file FILE | --store-file S.tsr) [--viewers V]\n"
                 "                    [--tick-hz HZ] [--window W] [--max-outstanding N] [--batches-in-flight B] [--protocol-revision R]\n"
                 "                    [--client-threads T])\n"
                 "                  [--rate TILES_PER_S (0: closed loop)] [--duration S] [--warmup S] [--drain S]\n"
                 "                  [--seed N] [--json FILE] [--trace FILE (HTTP: one line per measured reply)]\n");
}

Options parse(int argc, char** argv) {
    Options o;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto value = [&]() -> std::string {
            if (i + 1 >= argc) die("missing value for " + a);
            return argv[++i];
        };
        auto number = [&]() -> double {
            const std::string v = value();
            char* end = nullptr;
            const double d = std::strtod(v.c_str(), &end);
            if (end == v.c_str() || *end || !std::isfinite(d) || d < 0) die("bad number for " + a + ": " + v);
            return d;
        };
        if (a == "--grpc") o.grpc = value();
        else if (a == "--http") o.http = value();
        else if (a == "--store") o.store = value();
        else if (a == "--url-file") o.url_file = value();
        else if (a == "--store-file") o.store_file = value();
        else if (a == "--prefix") o.prefix = value();
        else if (a == "--json") o.json_path = value();
        else if (a == "--trace") o.trace_path = value();
        else if (a == "--rate") o.rate = number();
        else if (a == "--duration") o.duration = number();
        else if (a == "--warmup") o.warmup = number();
        else if (a == "--drain") o.drain = number();
        else if (a == "--connections") o.connections = unsigned(number());
        else if (a == "--viewers") o.viewers = unsigned(number());
        else if (a == "--client-threads") o.client_threads = unsigned(number());
        else if (a == "--tick-hz") o.tick_hz = number();
        else if (a == "--window") o.window = std::size_t(number());
        else if (a == "--max-outstanding") o.max_outstanding = std::size_t(number());
        else if (a == "--batches-in-flight") o.batches_in_flight = std::size_t(number());
        else if (a == "--seed") o.seed = std::uint64_t(number());
        else if (a == "--protocol-revision") o.protocol_revision = std::uint32_t(number());
        else if (a == "-h" || a == "--help") { usage(); std::exit(0); }
        else { usage(); die("unknown option " + a); }
    }
    if (o.grpc.empty() == o.http.empty()) { usage(); die("give exactly one of --grpc and --http"); }
    if (!o.http.empty() && o.url_file.empty()) die("--http needs --url-file");
    if (!o.grpc.empty() && o.store.empty()) die("--grpc needs --store NAME");
    if (!o.grpc.empty() && o.url_file.empty() && o.store_file.empty()) die("--grpc needs --url-file or --store-file");
    if (o.duration <= 0) die("--duration must be > 0");
    if (o.connections == 0 || o.viewers == 0 || o.client_threads == 0 || o.tick_hz <= 0 || o.window == 0 || o.max_outstanding == 0)
        die("--connections, --viewers, --client-threads, --tick-hz, --window and --max-outstanding must be > 0");
    return o;
}

// ---- Results ----------------------------------------------------------------------------------

struct Results {
    std::uint64_t sent = 0;        // measured requests sent (HTTP) or asked for (gRPC)
    std::uint64_t ok = 0;          // measured tiles received (first arrival)
    std::uint64_t bytes = 0;       // their payload bytes
    std::uint64_t errors = 0;      // non-200 / non-OK replies, broken connections
    std::uint64_t lost = 0;        // open model: no reply before the drain timeout
    std::uint64_t dropped = 0;     // gRPC: not asked for because the outstanding set was full
    std::uint64_t duplicates = 0;  // gRPC: tiles received again (re-listed while on the wire)
    std::uint64_t batches = 0;     // gRPC: batches sent
    std::uint64_t batch_requests = 0;  // gRPC: requests listed in those batches
    std::map<std::string, std::uint64_t> error_kinds;
    double seconds = 0;            // the window achieved rates are over
    LatencyHistogram latency;
    LatencyHistogram server_latency;  // gRPC: TileReply.server_micros (latest batch listing it -> transport)
    LatencyHistogram tick_late;       // gRPC: how late the generator ran each tick (its own share of latency)
};

std::string json_escape(const std::string& s) {
    std::string out;
    for (char c : s) {
        if (c == '"' || c == '\\') out += '\\';
        if (static_cast<unsigned char>(c) < 0x20) continue;
        out += c;
    }
    return out;
}

void report(const Options& o, const Results& r) {
    const bool grpc = !o.grpc.empty();
    const double tps = r.seconds > 0 ? double(r.ok) / r.seconds : 0;
    const double mbps = r.seconds > 0 ? double(r.bytes) / r.seconds / 1e6 : 0;
    auto ms = [](std::uint64_t ns) { return double(ns) / 1e6; };
    const auto& h = r.latency;
    const auto& sh = r.server_latency;  // empty for HTTP
    char line[512];
    std::snprintf(line, sizeof line,
                  "%s %s offered %s: %.0f tiles/s, %.1f MB/s, errors %" PRIu64 ", lost %" PRIu64
                  ", latency ms p50 %.3f p90 %.3f p99 %.3f p99.9 %.3f max %.3f",
                  grpc ? "grpc" : "http", grpc ? o.grpc.c_str() : o.http.c_str(),
                  o.rate > 0 ? (std::to_string(std::llround(o.rate)) + "/s").c_str() : "closed-loop", tps, mbps,
                  r.errors, r.lost, ms(h.percentile(0.5)), ms(h.percentile(0.9)), ms(h.percentile(0.99)),
                  ms(h.percentile(0.999)), ms(h.max()));
    std::printf("%s", line);
    if (grpc)
        std::printf(" (dropped %" PRIu64 ", duplicates %" PRIu64 ", %.0f requests/batch; server_micros p50 %.3f p99 %.3f ms)",
                    r.dropped, r.duplicates, r.batches ? double(r.batch_requests) / double(r.batches) : 0.0,
                    ms(r.server_latency.percentile(0.5)), ms(r.server_latency.percentile(0.99)));
    if (grpc)
        std::printf(" (ticks late p50 %.3f p99 %.3f ms)", ms(r.tick_late.percentile(0.5)), ms(r.tick_late.percentile(0.99)));
    std::printf("\n");

    std::string kinds;
    for (const auto& [k, n] : r.error_kinds)
        kinds += (kinds.empty() ? "" : ",") + std::string("\"") + json_escape(k) + "\":" + std::to_string(n);
    char buf[4096];
    std::snprintf(
        buf, sizeof buf,
        "{\"protocol\":\"%s\",\"target\":\"%s\",\"model\":\"%s\",\"offered_tiles_per_s\":%.1f,"
        "\"connections\":%u,\"viewers\":%u,\"tick_hz\":%.1f,\"window\":%zu,\"duration_s\":%.3f,\"warmup_s\":%.3f,"
        "\"seconds\":%.3f,\"sent\":%" PRIu64 ",\"tiles\":%" PRIu64 ",\"bytes\":%" PRIu64
        ",\"tiles_per_s\":%.1f,\"mb_per_s\":%.2f,\"errors\":%" PRIu64 ",\"lost\":%" PRIu64 ",\"dropped\":%" PRIu64
        ",\"duplicates\":%" PRIu64 ",\"batches\":%" PRIu64 ",\"batch_requests\":%" PRIu64
        ",\"error_kinds\":{%s},\"latency_ms\":{\"count\":%" PRIu64
        ",\"mean\":%.4f,\"p50\":%.4f,\"p90\":%.4f,\"p99\":%.4f,\"p99_9\":%.4f,\"max\":%.4f},"
        "\"server_latency_ms\":{\"count\":%" PRIu64 ",\"p50\":%.4f,\"p90\":%.4f,\"p99\":%.4f,\"p99_9\":%.4f,\"max\":%.4f},"
        "\"tick_late_ms\":{\"p50\":%.4f,\"p99\":%.4f,\"max\":%.4f},"
        "\"histogram\":\"log-linear, 64 buckets per power of two; percentiles are bucket upper bounds (<= 1.6%% high)\"}",
        grpc ? "grpc" : "http", json_escape(grpc ? o.grpc : o.http).c_str(), o.rate > 0 ? "open" : "closed", o.rate,
        grpc ? 0u : o.connections, grpc ? o.viewers : 0u, grpc ? o.tick_hz : 0.0, grpc ? o.window : std::size_t(0),
        o.duration, o.warmup, r.seconds, r.sent, r.ok, r.bytes, tps, mbps, r.errors, r.lost, r.dropped, r.duplicates,
        r.batches, r.batch_requests, kinds.c_str(), h.count(), ms(std::uint64_t(h.mean())), ms(h.percentile(0.5)),
        ms(h.percentile(0.9)), ms(h.percentile(0.99)), ms(h.percentile(0.999)), ms(h.max()), sh.count(),
        ms(sh.percentile(0.5)), ms(sh.percentile(0.9)), ms(sh.percentile(0.99)), ms(sh.percentile(0.999)), ms(sh.max()),
        ms(r.tick_late.percentile(0.5)), ms(r.tick_late.percentile(0.99)), ms(r.tick_late.max()));
    if (o.json_path.empty()) {
        std::printf("%s\n", buf);
    } else {
        std::ofstream f(o.json_path, std::ios::trunc);
        f << buf << '\n';
        if (!f) die("cannot write " + o.json_path);
    }
}

// ---- Tile lists -------------------------------------------------------------------------------

std::vector<std::string> read_urls(const std::string& path) {
    std::ifstream in(path);
    if (!in) die("cannot read " + path);
    std::vector<std::string> urls;
    for (std::string line; std::getline(in, line);)
        if (!line.empty() && line[0] == '/') urls.push_back(line);
    if (urls.empty()) die(path + " lists no URL paths");
    return urls;
}

using Key = tessera::TileKey;

// The last three path components of each URL: .../{level}/{x}/{y}.
std::vector<Key> keys_from_urls(const std::vector<std::string>& urls) {
    std::vector<Key> keys;
    for (const auto& u : urls) {
        std::uint32_t v[3];
        std::size_t end = u.size();
        for (int i = 2; i >= 0; --i) {
            const std::size_t slash = u.rfind('/', end - 1);
            if (slash == std::string::npos || slash + 1 >= end) die("not a tile URL: " + u);
            v[i] = std::uint32_t(std::stoul(u.substr(slash + 1, end - slash - 1)));
            end = slash;
        }
        keys.push_back({v[0], v[1], v[2]});
    }
    return keys;
}

std::vector<Key> keys_from_store(const std::string& path) {
    auto r = tessera::storage::StoreReader::open(path);
    if (!r) die(path + ": " + r.error().message);
    std::vector<Key> keys;
    const auto& info = (*r)->info();
    for (std::uint32_t l = 0; l < info.level_count(); ++l)
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                auto loc = (*r)->locate({l, x, y});
                if (loc && loc->kind == tessera::TileKind::present) keys.push_back({l, x, y});
            }
    if (keys.empty()) die(path + " has no present tiles");
    return keys;
}

// ---- HTTP: one epoll thread, C keep-alive connections -----------------------------------------

std::pair<std::string, std::string> host_and_port(const std::string& hp) {
    const auto parts = tessera::split_host_port(hp);
    if (!parts || parts->host.empty() || !tessera::parse_port(parts->port)) die("expected HOST:PORT, got " + hp);
    return {std::string(parts->host), std::string(parts->port)};
}

class HttpLoad {
public:
    HttpLoad(const Options& o, std::vector<std::string> urls) : o_(o), urls_(std::move(urls)), rng_(o.seed) {
        const auto [host, port] = host_and_port(o.http);
        addrinfo hints{};
        hints.ai_family = AF_UNSPEC;
        hints.ai_socktype = SOCK_STREAM;
        addrinfo* res = nullptr;
        if (int e = getaddrinfo(host.c_str(), port.c_str(), &hints, &res); e != 0 || !res)
            die("cannot resolve " + o.http + ": " + gai_strerror(e));
        std::memcpy(&addr_, res->ai_addr, res->ai_addrlen);
        addr_len_ = res->ai_addrlen;
        family_ = res->ai_family;
        freeaddrinfo(res);
        host_header_ = o.http;
        requests_.reserve(urls_.size());
        for (const auto& u : urls_)
            requests_.push_back("GET " + o.prefix + u + " HTTP/1.1\r\nHost: " + host_header_ + "\r\n\r\n");
    }

    Results run() {
        if (!o_.trace_path.empty()) {
            trace_.open(o_.trace_path, std::ios::trunc);
            if (!trace_) die("cannot write " + o_.trace_path);
        }
        epfd_ = epoll_create1(EPOLL_CLOEXEC);
        timerfd_ = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC);
        if (epfd_ < 0 || timerfd_ < 0) die("epoll/timerfd: " + std::string(std::strerror(errno)));
        add_fd(timerfd_, EPOLLIN, kTimerTag);
        conns_.resize(o_.connections);
        for (std::size_t i = 0; i < conns_.size(); ++i) {
            conns_[i].index = i;
            connect_conn(conns_[i]);
        }
        const bool open = o_.rate > 0;
        start_ = Clock::now() + std::chrono::milliseconds(50);
        measure_start_ = start_ + to_nanos(o_.warmup);
        end_ = measure_start_ + to_nanos(o_.duration);
        if (trace_.is_open())
            trace_ << "# sent_us (scheduled; closed loop: sent) latency_us url_line (0-based), one line per measured 200 reply; start "
                   << std::chrono::duration_cast<Nanos>(start_.time_since_epoch()).count() << " ns (CLOCK_MONOTONIC)\n";
        total_ = open ? std::uint64_t(std::floor((o_.warmup + o_.duration) * o_.rate)) : 0;
        first_measured_ = open ? std::uint64_t(std::ceil(o_.warmup * o_.rate)) : 0;
        for (auto& c : conns_) idle_.push_back(c.index);

        std::vector<epoll_event> events(256);
        bool sending = true;
        Clock::time_point drain_deadline{};
        for (;;) {
            const auto now = Clock::now();
            if (open) {
                dispatch_due(now);
                if (next_ >= total_ && sending) {
                    sending = false;
                    drain_deadline = std::max(now, end_) + to_nanos(o_.drain);
                }
                if (!sending && (busy_ == 0 || now >= drain_deadline)) break;
                // Wake at the next scheduled send (only useful while a connection is idle), or at
                // the drain deadline.
                if (sending && !idle_.empty()) arm(scheduled(next_));
                else if (!sending) arm(drain_deadline);
            } else {
                if (now < start_) {
                    arm(start_);
                } else {
                    if (sending) {
                        while (!idle_.empty() && now < end_) send_on(pop_idle(), now, now >= measure_start_);
                        if (now >= end_) {
                            sending = false;
                            drain_deadline = now + to_nanos(o_.drain);
                        }
                    }
                    if (!sending && (busy_ == 0 || now >= drain_deadline)) break;
                    arm(sending ? end_ : drain_deadline);
                }
            }
            const int n = epoll_wait(epfd_, events.data(), int(events.size()), -1);
            if (n < 0) {
                if (errno == EINTR) continue;
                die("epoll_wait: " + std::string(std::strerror(errno)));
            }
            for (int i = 0; i < n; ++i) {
                const auto tag = events[std::size_t(i)].data.u64;
                if (tag == kTimerTag) {
                    std::uint64_t expirations;
                    [[maybe_unused]] auto rd = ::read(timerfd_, &expirations, sizeof expirations);
                    continue;
                }
                Conn& c = conns_[tag];
                if (events[std::size_t(i)].events & EPOLLOUT) flush(c);
                if (events[std::size_t(i)].events & (EPOLLIN | EPOLLERR | EPOLLHUP)) read_conn(c);
            }
        }
        if (trace_.is_open()) {
            trace_.close();
            if (!trace_) die("cannot write " + o_.trace_path);
        }
        // Anything still outstanding never got a reply.
        for (auto& c : conns_)
            if (c.busy && c.measured) ++results_.lost;
        if (open) {
            results_.lost += (total_ > next_ ? total_ - std::max(next_, first_measured_) : 0);
            const auto last = std::max(last_completion_, end_);
            results_.seconds = std::chrono::duration<double>(last - measure_start_).count();
        } else {
            results_.seconds = o_.duration;
        }
        for (auto& c : conns_)
            if (c.fd >= 0) ::close(c.fd);
        ::close(timerfd_);
        ::close(epfd_);
        return results_;
    }

private:
    static constexpr std::uint64_t kTimerTag = ~std::uint64_t(0);

    struct Conn {
        std::size_t index = 0;
        int fd = -1;
        bool busy = false, measured = false, in_body = false, close_after = false;
        Clock::time_point origin{};  // latency origin: scheduled (open) or actual (closed) send time
        std::string out;             // unsent request bytes
        std::size_t out_off = 0;
        std::string head;            // response head being assembled
        std::uint64_t body_left = 0, body_bytes = 0;
        std::size_t url = 0;         // index of the URL asked
        int status = 0;
        bool want_out = false;
    };

    static Nanos to_nanos(double seconds) { return Nanos(std::int64_t(seconds * 1e9)); }
    Clock::time_point scheduled(std::uint64_t i) const {
        return start_ + Nanos(std::int64_t(double(i) * 1e9 / o_.rate));
    }

    void add_fd(int fd, std::uint32_t events, std::uint64_t tag) {
        epoll_event ev{};
        ev.events = events;
        ev.data.u64 = tag;
        if (epoll_ctl(epfd_, EPOLL_CTL_ADD, fd, &ev) != 0) die("epoll_ctl: " + std::string(std::strerror(errno)));
    }
    void arm(Clock::time_point t) {
        itimerspec spec{};
        const auto ns = std::chrono::duration_cast<Nanos>(t.time_since_epoch()).count();
        // steady_clock is CLOCK_MONOTONIC on Linux.
        spec.it_value.tv_sec = std::max<std::int64_t>(0, ns / 1000000000);
        spec.it_value.tv_nsec = std::max<std::int64_t>(0, ns % 1000000000);
        if (spec.it_value.tv_sec == 0 && spec.it_value.tv_nsec == 0) spec.it_value.tv_nsec = 1;
        timerfd_settime(timerfd_, TFD_TIMER_ABSTIME, &spec, nullptr);
    }

    void connect_conn(Conn& c) {
        c.fd = ::socket(family_, SOCK_STREAM | SOCK_CLOEXEC, 0);
        if (c.fd < 0) die("socket: " + std::string(std::strerror(errno)));
        if (::connect(c.fd, reinterpret_cast<const sockaddr*>(&addr_), addr_len_) != 0)
            die("cannot connect to " + o_.http + ": " + std::strerror(errno));
        const int one = 1;
        setsockopt(c.fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        fcntl(c.fd, F_SETFL, fcntl(c.fd, F_GETFL) | O_NONBLOCK);
        add_fd(c.fd, EPOLLIN, c.index);
        c.want_out = false;
        c.head.clear();
        c.in_body = false;
        c.close_after = false;
    }
    void reconnect(Conn& c) {
        epoll_ctl(epfd_, EPOLL_CTL_DEL, c.fd, nullptr);
        ::close(c.fd);
        connect_conn(c);
    }

    std::size_t pop_idle() {
        const std::size_t i = idle_.back();
        idle_.pop_back();
        return i;
    }

    // Open model: every request whose time has come goes out on an idle connection; the rest wait.
    void dispatch_due(Clock::time_point now) {
        while (next_ < total_ && !idle_.empty()) {
            const auto t = scheduled(next_);
            if (t > now) break;
            send_on(pop_idle(), t, next_ >= first_measured_);
            ++next_;
        }
    }

    void send_on(std::size_t index, Clock::time_point origin, bool measured) {
        Conn& c = conns_[index];
        c.busy = true;
        c.measured = measured;
        c.origin = origin;
        c.status = 0;
        c.body_bytes = 0;
        ++busy_;
        if (measured) ++results_.sent;
        c.url = pick_(rng_);
        c.out = requests_[c.url];
        c.out_off = 0;
        flush(c);
    }

    void flush(Conn& c) {
        while (c.out_off < c.out.size()) {
            const ssize_t n = ::send(c.fd, c.out.data() + c.out_off, c.out.size() - c.out_off, MSG_NOSIGNAL);
            if (n > 0) {
                c.out_off += std::size_t(n);
                continue;
            }
            if (n < 0 && errno == EINTR) continue;
            if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
                if (!c.want_out) set_events(c, EPOLLIN | EPOLLOUT, true);
                return;
            }
            fail(c, "send failed");
            return;
        }
        if (c.want_out) set_events(c, EPOLLIN, false);
    }
    void set_events(Conn& c, std::uint32_t events, bool want_out) {
        epoll_event ev{};
        ev.events = events;
        ev.data.u64 = c.index;
        epoll_ctl(epfd_, EPOLL_CTL_MOD, c.fd, &ev);
        c.want_out = want_out;
    }

    void read_conn(Conn& c) {
        for (;;) {
            const ssize_t n = ::recv(c.fd, buf_, sizeof buf_, 0);
            if (n > 0) {
                if (!consume(c, buf_, std::size_t(n))) return;
                if (std::size_t(n) < sizeof buf_) return;
                continue;
            }
            if (n < 0 && errno == EINTR) continue;
            if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) return;
            // EOF or error: the server closed the connection.
            if (c.busy) fail(c, n == 0 ? "connection closed by server" : "recv failed");
            else reconnect(c);
            return;
        }
    }

    // Feeds received bytes to the response parser. False when the connection was replaced.
    bool consume(Conn& c, const char* p, std::size_t n) {
        while (n > 0) {
            if (!c.busy) {
                fail(c, "bytes received with no request outstanding");
                return false;
            }
            if (c.in_body) {
                const std::size_t take = std::size_t(std::min<std::uint64_t>(c.body_left, n));
                c.body_left -= take;
                c.body_bytes += take;
                p += take;
                n -= take;
                if (c.body_left == 0 && !complete(c)) return false;
                continue;
            }
            const std::size_t old = c.head.size();
            c.head.append(p, std::min<std::size_t>(n, 8192));
            const auto pos = c.head.find("\r\n\r\n", old >= 3 ? old - 3 : 0);
            if (pos == std::string::npos) {
                if (c.head.size() > 16384) {
                    fail(c, "response head too large");
                    return false;
                }
                return true;
            }
            const std::size_t used = pos + 4 - old;
            p += used;
            n -= used;
            if (!parse_head(c, std::string_view(c.head).substr(0, pos + 2))) {
                fail(c, "malformed response head");
                return false;
            }
            c.head.clear();
            c.in_body = true;
            if (c.body_left == 0 && !complete(c)) return false;
        }
        return true;
    }

    static bool iequals_prefix(std::string_view line, std::string_view name) {
        if (line.size() < name.size()) return false;
        for (std::size_t i = 0; i < name.size(); ++i)
            if (std::tolower(static_cast<unsigned char>(line[i])) != name[i]) return false;
        return true;
    }
    bool parse_head(Conn& c, std::string_view head) {
        // Status line: HTTP/1.x NNN ...
        if (head.size() < 12 || head.substr(0, 7) != "HTTP/1.") return false;
        c.status = std::atoi(std::string(head.substr(9, 3)).c_str());
        c.close_after = head.substr(0, 8) == "HTTP/1.0";
        bool have_length = false;
        std::size_t start = head.find("\r\n") + 2;
        while (start < head.size()) {
            const std::size_t eol = head.find("\r\n", start);
            const std::string_view line = head.substr(start, eol - start);
            start = eol + 2;
            if (iequals_prefix(line, "content-length:")) {
                c.body_left = std::strtoull(std::string(line.substr(15)).c_str(), nullptr, 10);
                have_length = true;
            } else if (iequals_prefix(line, "connection:")) {
                std::string v(line.substr(11));
                for (auto& ch : v) ch = char(std::tolower(static_cast<unsigned char>(ch)));
                if (v.find("close") != std::string::npos) c.close_after = true;
                if (v.find("keep-alive") != std::string::npos) c.close_after = false;
            } else if (iequals_prefix(line, "transfer-encoding:")) {
                return false;  // tiles are sent with a Content-Length by both servers
            }
        }
        if (!have_length) c.body_left = 0;
        return have_length || c.status == 204 || c.status == 304;
    }

    // One response is complete. False when the connection was replaced.
    bool complete(Conn& c) {
        const auto now = Clock::now();
        c.busy = false;
        c.in_body = false;
        --busy_;
        const bool open = o_.rate > 0;
        const bool counted = open ? c.measured : (now >= measure_start_ && now <= end_);
        if (counted) {
            if (c.status == 200) {
                ++results_.ok;
                results_.bytes += c.body_bytes;
                results_.latency.record(std::uint64_t(std::chrono::duration_cast<Nanos>(now - c.origin).count()));
                if (trace_.is_open()) trace_ << std::chrono::duration_cast<Nanos>(c.origin - start_).count() / 1000 << ' '
                                   << std::chrono::duration_cast<Nanos>(now - c.origin).count() / 1000 << ' ' << c.url << '\n';
                if (open) last_completion_ = std::max(last_completion_, now);
            } else {
                ++results_.errors;
                ++results_.error_kinds["http_" + std::to_string(c.status)];
            }
        }
        bool replaced = false;
        if (c.close_after) {
            reconnect(c);
            replaced = true;
        }
        next_request(c, now);
        return !replaced;
    }

    void fail(Conn& c, const char* why) {
        const auto now = Clock::now();
        const bool was_busy = c.busy;
        if (c.busy) {
            c.busy = false;
            --busy_;
            if (c.measured || (o_.rate <= 0 && now >= measure_start_ && now <= end_)) {
                ++results_.errors;
                ++results_.error_kinds[why];
            }
        }
        if (++failures_ > 1000) die(std::string("too many connection failures; last: ") + why);
        reconnect(c);
        if (was_busy) next_request(c, now);  // an idle connection is in idle_ already
    }

    // The connection is free: the next request goes on it (closed), or the oldest waiting one (open).
    void next_request(Conn& c, Clock::time_point now) {
        if (o_.rate > 0) {
            if (next_ < total_ && scheduled(next_) <= now) {
                send_on(c.index, scheduled(next_), next_ >= first_measured_);
                ++next_;
            } else {
                idle_.push_back(c.index);
            }
        } else if (now < end_) {
            send_on(c.index, now, now >= measure_start_);
        } else {
            idle_.push_back(c.index);
        }
    }

    const Options& o_;
    std::vector<std::string> urls_, requests_;
    std::mt19937_64 rng_;
    std::uniform_int_distribution<std::size_t> pick_{0, urls_.size() - 1};
    sockaddr_storage addr_{};
    socklen_t addr_len_ = 0;
    int family_ = AF_INET;
    std::string host_header_;
    int epfd_ = -1, timerfd_ = -1;
    std::vector<Conn> conns_;
    std::vector<std::size_t> idle_;
    std::size_t busy_ = 0;
    std::uint64_t next_ = 0, total_ = 0, first_measured_ = 0, failures_ = 0;
    Clock::time_point start_{}, measure_start_{}, end_{}, last_completion_{};
    Results results_;
    std::ofstream trace_;  // --trace
    char buf_[256 * 1024];
};

// ---- gRPC: V viewers, each a StreamTiles stream on its own connection ---------------------------
//
// Asynchronous: --client-threads threads (default 1), each owning one completion queue and the
// completions of its share of the viewers, and one tick thread that sleeps to each tick's time
// and sends that tick's batches. No thread per stream: a generator with two threads per viewer
// spent the two cores' time switching between them, and that showed up as the server's tail.
// Ticks are not a completion queue's timeouts: those are in whole milliseconds (epoll), which
// would add up to a millisecond to every latency measured from a tick.

class GrpcLoad {
public:
    GrpcLoad(const Options& o, std::vector<Key> keys) : o_(o), keys_(std::move(keys)) {}

    Results run() {
        const bool open = o_.rate > 0;
        const unsigned threads = std::max(1u, std::min(o_.client_threads, o_.viewers));
        queues_.resize(threads);
        for (auto& q : queues_) q = std::make_unique<grpc::CompletionQueue>();
        viewers_.reserve(o_.viewers);
        for (unsigned i = 0; i < o_.viewers; ++i) {
            auto v = std::make_unique<Viewer>();
            v->id = i;
            v->rng.seed(o_.seed * 1000003u + i);
            grpc::ChannelArguments args;
            args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);  // one connection per viewer
            args.SetMaxReceiveMessageSize(64 << 20);
            v->channel = grpc::CreateCustomChannel(o_.grpc, grpc::InsecureChannelCredentials(), args);
            if (!v->channel->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(5)))
                die("cannot connect to " + o_.grpc);
            v->stub = std::make_unique<grpc::GenericStub>(v->channel);
            v->cq = queues_[i % threads].get();
            v->call = v->stub->PrepareCall(&v->context, "/tessera.v1.TileService/StreamTiles", v->cq);
            if (!v->call) die("StreamTiles failed to start");
            v->ops = {Op{v.get(), Op::start}, Op{v.get(), Op::read}, Op{v.get(), Op::write},
                      Op{v.get(), Op::writes_done}, Op{v.get(), Op::finish}};
            viewers_.push_back(std::move(v));
        }
        start_ = Clock::now() + std::chrono::milliseconds(100);
        measure_start_ = start_ + Nanos(std::int64_t(o_.warmup * 1e9));
        end_ = measure_start_ + Nanos(std::int64_t(o_.duration * 1e9));
        drain_deadline_ = end_ + Nanos(std::int64_t(o_.drain * 1e9));
        period_ = 1e9 / o_.tick_hz;
        for (auto& v : viewers_) {
            v->phase = open ? double(v->id) / double(o_.viewers) : 0.0;
            v->next_tick = tick_time(*v, 0);
            v->call->StartCall(&v->ops[Op::start]);
        }

        std::vector<std::thread> pool;
        for (unsigned t = 0; t < threads; ++t) pool.emplace_back([this, t, threads] { loop(t, threads); });
        std::thread ticker([this, open] { tick_clock(open); });
        for (auto& t : pool) t.join();
        stop_.store(true);
        ticker.join();
        for (auto& q : queues_) {  // every Finish has completed: drain what is left (failed writes, an alarm)
            q->Shutdown();
            void* tag = nullptr;
            bool ok = false;
            while (q->Next(&tag, &ok)) {
            }
        }

        Results r;
        Clock::time_point last = end_;
        for (auto& v : viewers_) {
            r.sent += v->r.sent;
            r.ok += v->r.ok;
            r.bytes += v->r.bytes;
            r.errors += v->r.errors;
            r.lost += v->r.lost;
            r.dropped += v->r.dropped;
            r.duplicates += v->r.duplicates;
            r.batches += v->r.batches;
            r.batch_requests += v->r.batch_requests;
            for (const auto& [k, n] : v->r.error_kinds) r.error_kinds[k] += n;
            r.latency.merge(v->r.latency);
            r.server_latency.merge(v->r.server_latency);
            last = std::max(last, v->last_completion);
        }
        r.seconds = open ? std::chrono::duration<double>(last - measure_start_).count() : o_.duration;
        r.tick_late = tick_late_;
        return r;
    }

private:
    struct Viewer;
    struct Op {  // a completion queue tag: which viewer, which operation
        enum Kind { start, read, write, writes_done, finish };
        Viewer* viewer;
        Kind kind;
    };
    struct Wanted {
        Clock::time_point asked;  // the tick that first asked for it: the latency origin
        std::uint64_t seq;        // matches the order_ entry that is current for this key
    };
    struct Viewer {
        unsigned id = 0;
        std::mt19937_64 rng;
        std::shared_ptr<grpc::Channel> channel;
        std::unique_ptr<grpc::GenericStub> stub;
        grpc::ClientContext context;
        grpc::CompletionQueue* cq = nullptr;
        std::unique_ptr<grpc::GenericClientAsyncReaderWriter> call;
        std::mutex mu;  // the tick thread and the viewer's queue thread
        std::array<Op, 5> ops{};
        grpc::ByteBuffer read_buf, write_buf;
        grpc::Status status;
        v1::TileBatch batch;

        std::unordered_map<std::uint64_t, Wanted> outstanding;
        std::deque<std::pair<std::uint64_t, std::uint64_t>> order;  // (key, seq), oldest first
        std::uint64_t next_seq = 0;
        std::uint64_t replies_read = 0;  // tile replies read so far (TileBatch.replies_received)
        std::uint64_t tick = 0, frame = 0, asked_so_far = 0;
        double phase = 0;
        Clock::time_point next_tick{};
        Clock::time_point cancel_at = Clock::time_point::max();  // leaving: cancel if not done by then
        bool started = false, writing = false, want_send = false;
        std::deque<std::uint64_t> unacked;  // frames of the batches written and not yet acked (--batches-in-flight)
        Clock::time_point written_at{};
        bool ticking = true;        // false once the viewer has begun to leave
        bool leaving = false;       // the empty batch is due or out: late tiles are neither counted nor duplicates
        bool goodbye_sent = false;  // the empty batch is written (WritesDone follows)
        bool finishing = false;     // Finish is issued
        bool done = false;          // Finish completed
        Clock::time_point last_completion{};
        Results r;
    };

    static std::uint64_t pack(const Key& k) { return tessera::pack_key(k); }

    Clock::time_point tick_time(const Viewer& v, std::uint64_t tick) const {
        return start_ + Nanos(std::int64_t((double(tick) + v.phase) * period_));
    }

    // Every viewer's ticks, on time: viewers are phase-shifted by period/V (open model), or tick
    // all at once (closed loop). Also cancels a leaving viewer's call the server did not end.
    void tick_clock(bool open) {
        const double step = open ? period_ / double(o_.viewers) : period_;
        prctl(PR_SET_TIMERSLACK, 1UL);  // wake at the tick, not up to 50 us after it
        for (std::uint64_t k = 0; !stop_.load(); ++k) {
            std::this_thread::sleep_until(start_ + Nanos(std::int64_t(double(k) * step)));
            const auto now = Clock::now();
            for (auto& p : viewers_) {
                Viewer& v = *p;
                std::lock_guard lock(v.mu);
                if (v.done) continue;
                while (v.ticking && v.next_tick <= now) on_tick(v, now);
                if (!v.finishing && now >= v.cancel_at) {
                    v.context.TryCancel();  // the server did not end the stream in time
                    v.cancel_at = Clock::time_point::max();
                }
            }
        }
    }

    // One thread: every completion of the viewers on queue `index`, until all of them are done.
    void loop(unsigned index, unsigned threads) {
        grpc::CompletionQueue& cq = *queues_[index];
        std::size_t live = 0;
        for (auto& v : viewers_) live += v->id % threads == index;
        while (live > 0) {
            void* tag = nullptr;
            bool ok = false;
            const auto status =
                cq.AsyncNext(&tag, &ok, std::chrono::system_clock::now() + std::chrono::milliseconds(100));
            if (status == grpc::CompletionQueue::SHUTDOWN) break;
            if (status == grpc::CompletionQueue::TIMEOUT) continue;
            auto* op = static_cast<Op*>(tag);
            Viewer& v = *op->viewer;
            std::lock_guard lock(v.mu);
            const bool was_done = v.done;
            on_event(v, op->kind, ok);
            if (v.done && !was_done) --live;
        }
    }

    void on_event(Viewer& v, Op::Kind kind, bool ok) {
        switch (kind) {
        case Op::start:
            if (!ok) {
                ++v.r.errors;
                ++v.r.error_kinds["stream_start_failed"];
                begin_finish(v);
                return;
            }
            v.started = true;
            v.call->Read(&v.read_buf, &v.ops[Op::read]);
            send(v);
            return;
        case Op::read:
            if (!ok) {  // the server ended the stream (or it broke): collect its status
                begin_finish(v);
                return;
            }
            on_message(v);
            v.call->Read(&v.read_buf, &v.ops[Op::read]);
            return;
        case Op::write:
            v.writing = false;
            if (!ok) {
                if (!v.leaving) {
                    ++v.r.errors;
                    ++v.r.error_kinds["stream_write_failed"];
                }
                v.ticking = false;
                return;  // the read side sees the stream end and finishes it
            }
            if (v.goodbye_sent) {
                v.call->WritesDone(&v.ops[Op::writes_done]);
                return;
            }
            send(v);
            return;
        case Op::writes_done:
            return;
        case Op::finish:
            v.done = true;
            v.ticking = false;
            if (!v.status.ok() && v.status.error_code() != grpc::StatusCode::CANCELLED) {
                ++v.r.errors;
                ++v.r.error_kinds["stream_" + std::to_string(int(v.status.error_code())) + ": " +
                                  v.status.error_message()];
            }
            return;
        }
    }

    void begin_finish(Viewer& v) {
        if (v.finishing) return;
        v.finishing = true;
        v.ticking = false;
        v.call->Finish(&v.status, &v.ops[Op::finish]);
    }

    // Open model: the tiles scheduled up to this tick join the outstanding set, which is sent
    // whole; after the measured ticks, resend what is still outstanding until the drain deadline.
    // Closed loop: top the set up to the window, every tick.
    void on_tick(Viewer& v, Clock::time_point now) {
        const Clock::time_point t = v.next_tick;
        if (t >= measure_start_) tick_late_.record(std::uint64_t(std::chrono::duration_cast<Nanos>(now - t).count()));
        if (o_.rate > 0) {
            const auto total_ticks = std::uint64_t(std::floor((o_.warmup + o_.duration) * o_.tick_hz));
            const auto warm_ticks = std::uint64_t(std::ceil(o_.warmup * o_.tick_hz));
            const double per_viewer = o_.rate / double(o_.viewers);
            if (v.tick < total_ticks) {
                const auto due = std::uint64_t(std::floor(double(v.tick + 1) * per_viewer / o_.tick_hz));
                const bool measured = v.tick >= warm_ticks;
                for (; v.asked_so_far < due; ++v.asked_so_far) {
                    if (v.outstanding.size() >= o_.max_outstanding) {
                        if (measured) ++v.r.dropped;
                        continue;
                    }
                    add_random(v, t, measured);
                }
            } else if (v.outstanding.empty() || now >= drain_deadline_) {
                leave(v);
                return;
            }
        } else {
            if (now >= end_) {
                leave(v);
                return;
            }
            top_up(v, now);
        }
        v.frame = v.tick;
        ++v.tick;
        v.next_tick = tick_time(v, v.tick);
        v.want_send = true;
        send(v);
    }

    void top_up(Viewer& v, Clock::time_point now) {
        while (v.outstanding.size() < o_.window) add_random(v, now, now >= measure_start_);
    }

    // Adds one new random tile (not already outstanding, if a few draws can find one).
    void add_random(Viewer& v, Clock::time_point asked, bool measured) {
        std::uniform_int_distribution<std::size_t> pick(0, keys_.size() - 1);
        for (int attempt = 0; attempt < 8; ++attempt) {
            const Key& k = keys_[pick(v.rng)];
            const std::uint64_t packed = pack(k);
            if (v.outstanding.contains(packed)) continue;
            const std::uint64_t seq = v.next_seq++;
            v.outstanding.emplace(packed, Wanted{asked, seq});
            v.order.emplace_back(packed, seq);
            if (measured) ++v.r.sent;
            return;
        }
        if (measured) {
            ++v.r.dropped;  // the set already holds (nearly) every tile
            ++v.r.error_kinds["merged_with_outstanding"];
        }
    }

    // Writes the whole outstanding set, oldest first, as one batch, if no write is in flight (a
    // batch due meanwhile goes out when the write completes, built from the set as it is then).
    void send(Viewer& v) {
        if (!v.started || v.writing || v.finishing) return;
        // As client/net: the next batch waits for the previous one's ack (a server that holds
        // batches while it is behind thereby paces the viewer), unless no ack came for 250 ms.
        if (o_.batches_in_flight && !v.leaving && v.unacked.size() >= o_.batches_in_flight &&
            Clock::now() - v.written_at < std::chrono::milliseconds(250))
            return;
        if (!v.unacked.empty() && v.unacked.size() >= o_.batches_in_flight) v.unacked.clear();  // waited 250 ms: given up
        if (v.leaving && !v.goodbye_sent) {  // the way a viewer leaves: an empty batch, then a half-close
            v.batch.Clear();
            v.batch.set_frame(~std::uint64_t(0));
            v.goodbye_sent = true;
        } else if (v.want_send && !v.leaving) {
            build_batch(v);
        } else {
            return;
        }
        v.want_send = false;
        bool own = false;
        v.write_buf.Clear();
        if (!grpc::SerializationTraits<v1::TileBatch>::Serialize(v.batch, &v.write_buf, &own).ok())
            die("cannot serialize a TileBatch");
        v.writing = true;
        if (o_.batches_in_flight) v.unacked.push_back(v.batch.frame());
        v.written_at = Clock::now();
        v.call->Write(v.write_buf, &v.ops[Op::write]);
    }

    void build_batch(Viewer& v) {
        v1::TileBatch& batch = v.batch;
        batch.Clear();
        batch.set_frame(v.frame);
        batch.set_protocol_revision(o_.protocol_revision);
        batch.set_replies_received(v.replies_read);
        batch.add_stores(o_.store);
        std::deque<std::pair<std::uint64_t, std::uint64_t>> live;
        for (const auto& [packed, seq] : v.order) {
            auto it = v.outstanding.find(packed);
            if (it == v.outstanding.end() || it->second.seq != seq) continue;  // arrived (or re-added later)
            live.emplace_back(packed, seq);
            auto* r = batch.add_requests();
            r->set_store(0);
            r->set_level(std::uint32_t(packed >> 58));
            r->set_y(std::uint32_t((packed >> 29) & 0x1FFFFFFFu));
            r->set_x(std::uint32_t(packed & 0x1FFFFFFFu));
            r->set_priority(1.0f);
        }
        v.order.swap(live);
        ++v.r.batches;
        v.r.batch_requests += std::uint64_t(batch.requests_size());
    }

    // Ends the stream the way a viewer leaves: an empty batch (cancels whatever is still pending
    // or queued for it), then a half-close; the server finishes the call once it is idle. Only
    // if that takes over two seconds is the call cancelled.
    void leave(Viewer& v) {
        // Open model: what never came is lost. Closed loop: the window's leftovers were not measured.
        for (const auto& [packed, w] : v.outstanding)
            if (o_.rate > 0 && w.asked >= measure_start_) ++v.r.lost;
        v.outstanding.clear();
        v.order.clear();
        v.leaving = true;
        v.ticking = false;
        v.cancel_at = Clock::now() + std::chrono::seconds(2);
        send(v);
    }

    void on_message(Viewer& v) {
        using Kind = tessera::protocol::ServerMessageDecoder::Kind;
        thread_local tessera::protocol::ServerMessageDecoder d;  // keeps its buffers between messages
        if (!d.decode(v.read_buf)) {
            ++v.r.errors;
            ++v.r.error_kinds["malformed_message"];
            return;
        }
        if (d.kind() == Kind::ack) {
            // Refused and invalid requests also come back one by one as tiles with an error
            // status (counted there); a batch refused whole only shows here.
            if (d.ack().status() != v1::TILE_OK) {
                ++v.r.errors;
                ++v.r.error_kinds["batch_" + std::string(to_string(tessera::protocol::from_proto(d.ack().status())))];
            }
            // Acks come in the order batches were written; one of a batch given up on matches nothing.
            if (auto it = std::find(v.unacked.begin(), v.unacked.end(), d.ack().frame()); it != v.unacked.end())
                v.unacked.erase(v.unacked.begin(), it + 1);
            if (v.want_send) send(v);  // it waited for this ack
            return;
        }
        if (d.kind() != Kind::tiles) return;
        const auto now = Clock::now();
        const bool open = o_.rate > 0;
        v.replies_read += d.tile_count();
        for (std::size_t i = 0; i < d.tile_count(); ++i) {
            const auto& t = d.tile(i);
            const std::uint64_t packed = tessera::pack_key(t.key);
            auto it = v.outstanding.find(packed);
            if (it == v.outstanding.end()) {
                if (t.status == v1::TILE_OK && !v.leaving) ++v.r.duplicates;
                continue;
            }
            const auto asked = it->second.asked;
            v.outstanding.erase(it);
            const bool counted = open ? asked >= measure_start_ : (now >= measure_start_ && now <= end_);
            if (!counted) continue;
            if (t.status == v1::TILE_OK && t.kind != v1::KIND_ABSENT) {
                ++v.r.ok;
                v.r.bytes += t.payload_size;
                v.r.latency.record(std::uint64_t(std::chrono::duration_cast<Nanos>(now - asked).count()));
                v.r.server_latency.record(std::uint64_t(t.server_micros) * 1000);
                v.last_completion = std::max(v.last_completion, now);
            } else {
                ++v.r.errors;
                ++v.r.error_kinds[std::string(to_string(tessera::protocol::from_proto(t.status)))];
            }
        }
        // Closed loop: half the window has arrived, so top it up now rather than at the next tick.
        if (!open && !v.leaving && v.outstanding.size() <= o_.window / 2) {
            top_up(v, now);
            v.want_send = true;
            send(v);
        }
    }

    const Options& o_;
    std::vector<Key> keys_;
    std::vector<std::unique_ptr<grpc::CompletionQueue>> queues_;
    std::atomic<bool> stop_{false};
    LatencyHistogram tick_late_;  // only the tick thread records
    std::vector<std::unique_ptr<Viewer>> viewers_;
    Clock::time_point start_{}, measure_start_{}, end_{}, drain_deadline_{};
    double period_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
    // gRPC reads each message into freshly allocated slices of up to 256 KiB. With glibc's
    // defaults the freed memory is trimmed back to the kernel, so the next read page-faults its
    // buffer in again: a quarter of this tool's CPU at peak (perf: exc_page_fault, clear_page,
    // unmap_page_range), which capped the measured gRPC peak at ~130 000 tiles/s instead of the
    // server's. Keep freed memory for reuse, as a lean load generator (wrk) does.
    mallopt(M_MMAP_THRESHOLD, 32 << 20);
    mallopt(M_TRIM_THRESHOLD, 512 << 20);
    const Options o = parse(argc, argv);
    Results r;
    if (!o.http.empty()) {
        r = HttpLoad(o, read_urls(o.url_file)).run();
    } else {
        if (!o.trace_path.empty()) die("--trace is for --http");
        auto keys = o.url_file.empty() ? keys_from_store(o.store_file) : keys_from_urls(read_urls(o.url_file));
        r = GrpcLoad(o, std::move(keys)).run();
    }
    report(o, r);
    return 0;
}
