#pragma once
// What an HTTP request means, without any transport: the HTTP server (http_server.cpp) parses
// the request, calls HttpHandler::handle_http_request and writes the response it gets. The tests
// drive the handler directly.
//
// Routes (GET and HEAD only; anything else is 405 with Allow: GET, HEAD):
//   /healthz                                 200 "ok\n" (no auth)
//   /readyz                                  200 when ready and not draining, else 503 (no auth)
//   /metrics                                 Prometheus text format 0.0.4
//   /v1/stores                               {"stores": [summary, ...]} (JSON)
//   /v1/stores/{name}                        store metadata with per-level geometry (JSON)
//   /v1/stores/{name}/tiles/{level}/{x}/{y}  the stored payload; ?format=png decodes it to PNG;
//                                            ?v=<version> pins the store version (immutable)
// Errors are one line: text/plain outside /v1/, {"error": "..."} (application/json) under /v1/.
#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

#include "metrics.hpp"
#include "tessera/storage/store_reader.hpp"
#include "server_context.hpp"

namespace tessera::server {

struct HttpRequestView {
    std::string_view method;         // "GET", "HEAD", ...
    std::string_view target;         // origin-form: path and optional ?query
    std::string_view authorization;  // Authorization header ("" if none)
    std::string_view if_none_match;  // If-None-Match header(s), comma-joined ("" if none)
    std::string_view accept;         // Accept header; not used for negotiation (the URL picks the
                                     // representation, so caches need no Vary)
};

// The metric label of a request: a fixed set, never the raw path.
enum class HttpRoute : std::uint8_t { healthz, readyz, metrics, stores, store, tile, tile_png, other };
inline constexpr std::size_t kHttpRouteCount = 8;
std::string_view to_string(HttpRoute r);

struct HttpResponse {
    unsigned status = 200;
    std::string content_type;  // empty: no Content-Type (304)
    // The full representation, also for HEAD: the transport sends only the headers then, with
    // this body's length as Content-Length.
    std::string body;
    std::vector<std::pair<std::string, std::string>> headers;  // besides Content-Type/-Length
    HttpRoute route = HttpRoute::other;
    // Set instead of body when the caller asked to borrow payloads: the stored tile is the body
    // (the transport writes its bytes from the cache; nothing is copied).
    std::shared_ptr<const storage::Tile> payload;

    std::size_t body_size() const { return payload ? payload->bytes.size() : body.size(); }

    // First header with this name (case-insensitive), nullptr when absent.
    const std::string* header(std::string_view name) const;
};

// A one-line error response from the transport itself (malformed request, too many
// connections, ...): text/plain, Cache-Control: no-store, Server header.
HttpResponse http_error_response(unsigned status, std::string_view message);

class HttpHandler {
public:
    // Registers the HTTP metrics in ctx.metrics (idempotent: two handlers on one registry share them).
    explicit HttpHandler(ServerContext& ctx);
    HttpHandler(const HttpHandler&) = delete;
    HttpHandler& operator=(const HttpHandler&) = delete;

    // Thread-safe; blocking only for the tile read (TileFetcher: RAM cache, else one pread).
    // borrow_payload: a stored tile's payload comes as HttpResponse::payload, not copied into body.
    HttpResponse handle_http_request(const HttpRequestView& req, bool borrow_payload = false);

    // Counts a response the transport produced on its own (route "other").
    void record_transport_response(unsigned status, std::size_t body_bytes);

    // Tile requests being served right now (bounded by config.max_http_inflight: beyond it, 503).
    std::size_t tiles_in_flight() const { return tiles_in_flight_.load(std::memory_order_relaxed); }

private:
    HttpResponse route(const HttpRequestView& req, HttpRoute& route, bool borrow_payload);
    // layer: ?layer=NAME, the layer of a multi-layer store that format=png shows.
    HttpResponse tile(const HttpRequestView& req, std::string_view name, std::string_view level,
                      std::string_view x, std::string_view y, bool png, const std::optional<std::string>& layer,
                      bool has_version, std::uint64_t version, bool borrow_payload);
    void record(HttpRoute route, unsigned status, std::size_t body_bytes, double seconds);
    Counter& requests_counter(HttpRoute route, unsigned status);
    Counter& tiles_served_counter(const std::string& store);

    ServerContext& ctx_;
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
