#pragma once
// What an HTTP request means, without any transport: the HTTP server (http_server.cpp) parses
// the request, calls HttpHandler::handle_http_request and writes the response it gets. The tests
// drive the handler directly.
//
// Routes (GET and HEAD; OPTIONS answers CORS preflights; anything else is 405), each API in
// its own file under http/ (http/apis.hpp lists them; docs/server.md describes them):
//   /healthz, /readyz                        probes (no auth, queries ignored)
//   /metrics                                 Prometheus text format 0.0.4
//   /v1/...                                  Tessera's API: stores, metadata and stored tiles
//   /dzi/..., /iiif/..., /xyz/...            Deep Zoom, IIIF Image API 3.0 and XYZ tiles for browsers
//   /, /view/{name}, /static/...             the web viewer (OpenSeadragon) and a list of stores
// Errors are one line: {"error": "..."} (application/json) under /v1/, text/plain elsewhere.
#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

#include "header_value.hpp"
#include "metrics.hpp"
#include "tessera/storage/store_reader.hpp"
#include "server_context.hpp"
#include "work_executor.hpp"

namespace tessera::server {

struct HttpResponse;

struct HttpRequestView {
    std::string_view method;         // "GET", "HEAD", ...
    std::string_view target;         // origin-form: path and optional ?query
    std::string_view authorization;  // Authorization header ("" if none)
    std::string_view if_none_match;  // If-None-Match header(s), comma-joined ("" if none)
    std::string_view accept;         // Accept header: only IIIF's info.json follows it (its
                                     // Content-Type, with Vary: Accept); elsewhere the URL picks
    std::string_view cookie = {};    // Cookie header: a browser's token (tessera_token)
    std::string_view origin = {};    // Origin header: CORS
    std::string_view host = {};      // Host header: absolute URLs in IIIF's info.json
    bool secure = false;             // arrived over TLS
};

// The metric label of a request: a fixed set, never the raw path.
enum class HttpRoute : std::uint8_t {
    healthz, readyz, metrics, stores, store, tile, tile_png,
    dzi_info, dzi_tile, iiif_info, iiif_image, xyz_tile, viewer, preflight, other
};
inline constexpr std::size_t kHttpRouteCount = 15;
std::string_view to_string(HttpRoute r);

// Work a request needs off the event loop: a tile read that missed the RAM cache (a pread, or
// a remote store's origin) or a web image render. An API returns it (HttpResponse::deferred)
// instead of doing it; the transport runs `answer` on its WorkExecutor (docs/server.md,
// "Isolation") and hands the result to HttpHandler::complete. Tests and tools that call
// handle_http_request get it run in place.
struct DeferredAnswer {
    WorkKind kind = WorkKind::read;
    std::shared_ptr<const StoreHandle> store;  // its lane (per-store bound)
    std::size_t memory = 0;                    // renders: estimated peak bytes
    std::function<HttpResponse()> answer;      // owns what it uses; runs on any thread

    // Of the request, for complete(): set by the handler.
    HttpRoute route = HttpRoute::other;
    std::chrono::steady_clock::time_point started{};
    std::string origin;  // CORS
    std::string target;  // logs
    bool head = false;
};

struct HttpResponse {
    unsigned status = 200;
    std::string content_type;  // empty: no Content-Type (304)
    // The full representation, also for HEAD: the transport sends only the headers then, with
    // this body's length as Content-Length.
    std::string body;
    // Besides Content-Type/-Length. Names are string literals (a fixed set); values up to
    // HeaderValue::kInline characters are held in place.
    std::vector<std::pair<std::string_view, HeaderValue>> headers;
    HttpRoute route = HttpRoute::other;
    // Set instead of body when the caller asked to borrow payloads: the stored tile is the body
    // (the transport writes its bytes from the cache; nothing is copied).
    std::shared_ptr<const storage::Tile> payload;
    // Set instead of everything else when the answer needs work off the event loop.
    std::shared_ptr<DeferredAnswer> deferred;

    std::size_t body_size() const { return payload ? payload->bytes.size() : body.size(); }

    // First header with this name (case-insensitive), nullptr when absent.
    const HeaderValue* header(std::string_view name) const;
};

// A one-line error response from the transport itself (malformed request, too many
// connections, ...): text/plain, Cache-Control: no-store, Server header.
HttpResponse http_error_response(unsigned status, std::string_view message);

namespace httpapi {
class WebTileCache;
}

// A place among the tile requests served at once (config.max_http_inflight); ok() false when
// there was none (answer 503). Released when it goes out of scope.
class TileSlot {
public:
    TileSlot(std::atomic<std::size_t>& n, std::size_t limit) : n_(n), ok_(n.fetch_add(1, std::memory_order_relaxed) < limit) {}
    ~TileSlot() { n_.fetch_sub(1, std::memory_order_relaxed); }
    TileSlot(const TileSlot&) = delete;
    TileSlot& operator=(const TileSlot&) = delete;
    bool ok() const { return ok_; }

private:
    std::atomic<std::size_t>& n_;
    bool ok_;
};

class HttpHandler {
public:
    // Registers the HTTP metrics in ctx.metrics (idempotent: two handlers on one registry share them).
    explicit HttpHandler(ServerContext& ctx);
    HttpHandler(const HttpHandler&) = delete;
    HttpHandler& operator=(const HttpHandler&) = delete;

    // Thread-safe. Runs any deferred work in place (blocking for its reads and renders): for
    // tests and tools. borrow_payload: a stored tile's payload comes as HttpResponse::payload,
    // not copied into body.
    HttpResponse handle_http_request(const HttpRequestView& req, bool borrow_payload = false);

    // For a transport with an executor: the response, or one whose `deferred` is set (nothing
    // of it waited for I/O or heavy work). The transport then runs deferred->answer() off its
    // loop and sends complete(*deferred, result), or sends refused() / expired().
    HttpResponse start(const HttpRequestView& req, bool borrow_payload);
    HttpResponse complete(const DeferredAnswer& d, HttpResponse r);
    // An answer that is itself deferred (work of another kind found to be needed, e.g. a render
    // after a read): its work, as part of d's request. The transport admits it on its own.
    std::shared_ptr<DeferredAnswer> follow_up(const DeferredAnswer& d, HttpResponse r);
    // 503 + Retry-After: the executor refused the work (a store's lane or the render budget full).
    HttpResponse refused(const DeferredAnswer& d, Admission why);
    // 504: the request's deadline (--request-timeout) passed before its work could finish.
    HttpResponse expired(const DeferredAnswer& d);

    // Counts a response the transport produced on its own (route "other").
    void record_transport_response(unsigned status, std::size_t body_bytes);
    // A response the transport makes itself (a malformed request, one over the connection limit):
    // CORS headers as every response gets them, then counted. origin: the request's Origin
    // header; nullopt when it is not known (the request was never read, or not its whole header):
    // answered as to the allowed origin, so a page's script can still read the 503 and its
    // Retry-After. head: no body will be sent.
    void finish_transport_response(HttpResponse& r, bool head, std::optional<std::string_view> origin);

    // Tile requests being served right now (bounded by config.max_http_inflight: beyond it, 503).
    std::size_t tiles_in_flight() const { return tiles_in_flight_.load(std::memory_order_relaxed); }

    // For the APIs (http/apis.hpp).
    ServerContext& context() { return ctx_; }
    TileSlot tile_slot() { return TileSlot(tiles_in_flight_, ctx_.config.max_http_inflight); }
    httpapi::WebTileCache& web_cache() { return *web_cache_; }
    // Counts a tile (or web image) served from `store`, `bytes` long.
    void count_served(const StoreHandle& store, std::size_t bytes);

    ~HttpHandler();

private:
    HttpResponse route(const HttpRequestView& req, HttpRoute& route, bool borrow_payload);
    // CORS, Server header, metrics and logs: what every answer gets once it is made.
    HttpResponse finish(HttpResponse res, HttpRoute route, std::string_view origin, std::string_view target, bool head,
                        std::chrono::steady_clock::time_point started);
    void record(HttpRoute route, unsigned status, std::size_t body_bytes, double seconds);
    Counter& requests_counter(HttpRoute route, unsigned status);
    Counter& tiles_served_counter(const std::string& store);

    ServerContext& ctx_;
    std::unique_ptr<httpapi::WebTileCache> web_cache_;
    // tessera_http_requests_total{route, code}: registered on first use of each pair.
    static constexpr std::size_t kStatusSlots = 600;
    std::vector<std::atomic<Counter*>> requests_;  // kHttpRouteCount x kStatusSlots
    Histogram* duration_[kHttpRouteCount] = {};
    Counter* response_bytes_[kHttpRouteCount] = {};
    std::mutex tiles_served_mutex_;
    std::unordered_map<std::string, Counter*> tiles_served_;  // tessera_tiles_served_total by store
    std::atomic<std::size_t> tiles_in_flight_{0};
};

// Convenience for one-off calls (tests, tools): a handler made for this call only. Servers keep
// one HttpHandler for their lifetime instead.
HttpResponse handle_http_request(ServerContext& ctx, const HttpRequestView& req);

}  // namespace tessera::server
