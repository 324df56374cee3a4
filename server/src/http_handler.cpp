// The router: parses a request once, answers probes, preflights and auth, and hands the rest to
// the API its first path segment names (the route table below; http/apis.hpp lists the APIs).
// Also the HTTP metrics every route shares.
#include "http_handler.hpp"

#include <algorithm>
#include <array>
#include <exception>

#include "auth.hpp"
#include "http/apis.hpp"
#include "http/common.hpp"
#include "http/web_image.hpp"

namespace tessera::server {

namespace {

constexpr std::string_view kMetricsType = "text/plain; version=0.0.4; charset=utf-8";

struct Route {
    std::string_view first_segment;
    httpapi::ApiFn answer;
};
// Each API's own paths start with its first segment; "/" alone is the viewer's list of stores.
constexpr std::array kRoutes{
    Route{"v1", &httpapi::api_v1},       Route{"dzi", &httpapi::api_dzi},       Route{"iiif", &httpapi::api_iiif},
    Route{"xyz", &httpapi::api_xyz},     Route{"view", &httpapi::viewer_page}, Route{"static", &httpapi::viewer_static},
};

}  // namespace

std::string_view to_string(HttpRoute r) {
    switch (r) {
        case HttpRoute::healthz: return "healthz";
        case HttpRoute::readyz: return "readyz";
        case HttpRoute::metrics: return "metrics";
        case HttpRoute::stores: return "stores";
        case HttpRoute::store: return "store";
        case HttpRoute::tile: return "tile";
        case HttpRoute::tile_png: return "tile_png";
        case HttpRoute::dzi_info: return "dzi_info";
        case HttpRoute::dzi_tile: return "dzi_tile";
        case HttpRoute::iiif_info: return "iiif_info";
        case HttpRoute::iiif_image: return "iiif_image";
        case HttpRoute::xyz_tile: return "xyz_tile";
        case HttpRoute::viewer: return "viewer";
        case HttpRoute::preflight: return "preflight";
        case HttpRoute::other: return "other";
    }
    return "other";
}

const HeaderValue* HttpResponse::header(std::string_view name) const {
    for (const auto& [k, v] : headers)
        if (httpapi::iequals(k, name)) return &v;
    return nullptr;
}

HttpResponse http_error_response(unsigned status, std::string_view message) {
    HttpResponse r = httpapi::error(status, message, false);
    r.headers.emplace_back("Server", std::string(httpapi::kServer));
    return r;
}

namespace {
constexpr const char* kWebEncodedBytes = "tessera_web_encoded_bytes";
}  // namespace

HttpHandler::HttpHandler(ServerContext& ctx)
    : ctx_(ctx),
      web_cache_(std::make_unique<httpapi::WebTileCache>(ctx.config.web_cache_bytes)),
      requests_(kHttpRouteCount * kStatusSlots) {
    for (auto& c : requests_) c.store(nullptr, std::memory_order_relaxed);
    // What the encoded web cache holds (its decoded sibling's gauge is the tile fetcher's).
    ctx_.metrics.gauge_callback(kWebEncodedBytes, "Bytes held by the RAM cache of encoded web images (--web-cache)", {},
                                [cache = web_cache_.get()] { return double(cache->bytes()); });
    for (std::size_t r = 0; r < kHttpRouteCount; ++r) {
        const std::string route(to_string(static_cast<HttpRoute>(r)));
        duration_[r] = &ctx_.metrics.histogram("tessera_http_request_duration_seconds",
                                               "HTTP request handling time (request parsed -> response built)",
                                               {{"route", route}}, latency_buckets_seconds());
        response_bytes_[r] = &ctx_.metrics.counter("tessera_http_response_bytes_total",
                                                   "HTTP response body bytes sent (HEAD: none)", {{"route", route}});
    }
}

HttpHandler::~HttpHandler() { ctx_.metrics.remove_callbacks(kWebEncodedBytes); }

Counter& HttpHandler::requests_counter(HttpRoute route, unsigned status) {
    const unsigned slot = status < kStatusSlots ? status : 0;
    auto& cell = requests_[static_cast<std::size_t>(route) * kStatusSlots + slot];
    Counter* c = cell.load(std::memory_order_acquire);
    if (!c) {
        // Registration is idempotent, so two threads racing here get the same counter.
        c = &ctx_.metrics.counter("tessera_http_requests_total", "HTTP requests answered, by route and status code",
                                  {{"route", std::string(to_string(route))}, {"code", std::to_string(status)}});
        cell.store(c, std::memory_order_release);
    }
    return *c;
}

Counter& HttpHandler::tiles_served_counter(const std::string& store) {
    std::lock_guard lock(tiles_served_mutex_);
    auto it = tiles_served_.find(store);
    if (it != tiles_served_.end()) return *it->second;
    Counter& c = ctx_.metrics.counter("tessera_tiles_served_total", "Tiles served, by store and protocol",
                                      {{"store", store}, {"protocol", "http"}});
    tiles_served_.emplace(store, &c);
    return c;
}

void HttpHandler::count_served(const StoreHandle& store, std::size_t bytes) {
    Counter* served = store.http_tiles_served.load(std::memory_order_acquire);
    if (!served) {
        served = &tiles_served_counter(store.name);
        store.http_tiles_served.store(served, std::memory_order_release);
    }
    served->inc();
    if (store.metrics.tiles_sent) store.metrics.tiles_sent->inc();
    if (store.metrics.bytes_sent) store.metrics.bytes_sent->inc(bytes);
}

void HttpHandler::record(HttpRoute route, unsigned status, std::size_t body_bytes, double seconds) {
    const auto r = static_cast<std::size_t>(route);
    requests_counter(route, status).inc();
    duration_[r]->observe(seconds);
    if (body_bytes) response_bytes_[r]->inc(body_bytes);
}

void HttpHandler::record_transport_response(unsigned status, std::size_t body_bytes) {
    record(HttpRoute::other, status, body_bytes, 0.0);
}

void HttpHandler::finish_transport_response(HttpResponse& r, bool head, std::optional<std::string_view> origin) {
    const ServerConfig& config = ctx_.config;
    httpapi::add_cors_headers(r, config, origin ? *origin : std::string_view(config.cors_origin));
    record_transport_response(r.status, head ? 0 : r.body.size());
}

namespace {

// The target as logs may hold it: an access_token's value replaced (logs outlive secrets). Keys
// are compared decoded, as the query parser reads them: "access%5Ftoken" is the token too.
std::string loggable_target(std::string_view target) {
    const std::size_t q = target.find('?');
    if (q == std::string_view::npos) return std::string(target);
    std::string out(target.substr(0, q + 1));
    const std::string_view query = target.substr(q + 1);
    for (std::size_t start = 0; start <= query.size();) {
        const std::size_t amp = std::min(query.find('&', start), query.size());
        const std::string_view param = query.substr(start, amp - start);
        const std::size_t eq = param.find('=');
        const std::string_view raw_key = param.substr(0, eq);
        std::string key, why;
        const bool token = eq != std::string_view::npos && httpapi::percent_decode(raw_key, key, why, true) && key == "access_token";
        out += token ? std::string(raw_key) + "=REDACTED" : std::string(param);
        if (amp >= query.size()) break;
        out += '&';
        start = amp + 1;
    }
    return out;
}

}  // namespace

HttpResponse HttpHandler::handle_http_request(const HttpRequestView& req, bool borrow_payload) {
    HttpResponse res = start(req, borrow_payload);
    if (!res.deferred) return res;
    std::shared_ptr<DeferredAnswer> d = std::move(res.deferred);
    for (;;) {
        HttpResponse answered;
        try {
            answered = d->answer();
        } catch (const std::exception& e) {
            ctx_.log.error("http handler failed", {{"target", d->target}, {"error", e.what()}});
            answered = httpapi::error(500, "internal error", d->target.starts_with("/v1/"));
        }
        if (!answered.deferred) return complete(*d, std::move(answered));
        d = follow_up(*d, std::move(answered));
    }
}

HttpResponse HttpHandler::start(const HttpRequestView& req, bool borrow_payload) {
    const auto t0 = std::chrono::steady_clock::now();
    HttpRoute route_label = HttpRoute::other;
    HttpResponse res;
    try {
        res = route(req, route_label, borrow_payload);
    } catch (const std::exception& e) {
        ctx_.log.error("http handler failed", {{"target", loggable_target(req.target)}, {"error", e.what()}});
        res = httpapi::error(500, "internal error", req.target.starts_with("/v1/"));
    }
    if (res.deferred) {
        DeferredAnswer& d = *res.deferred;
        d.route = route_label;
        d.started = t0;
        d.origin = std::string(req.origin);
        d.target = loggable_target(req.target);
        d.head = req.method == "HEAD";
        return res;
    }
    return finish(std::move(res), route_label, req.origin, req.target, req.method == "HEAD", t0);
}

HttpResponse HttpHandler::complete(const DeferredAnswer& d, HttpResponse r) {
    return finish(std::move(r), d.route, d.origin, d.target, d.head, d.started);
}

std::shared_ptr<DeferredAnswer> HttpHandler::follow_up(const DeferredAnswer& d, HttpResponse r) {
    std::shared_ptr<DeferredAnswer> next = std::move(r.deferred);
    next->route = d.route;
    next->started = d.started;
    next->origin = d.origin;
    next->target = d.target;
    next->head = d.head;
    return next;
}

HttpResponse HttpHandler::refused(const DeferredAnswer& d, Admission why) {
    std::string message;
    switch (why) {
        case Admission::store_full: message = "too many requests for this store are waiting; retry"; break;
        case Admission::render_busy: message = "too many images are being rendered; retry"; break;
        case Admission::render_memory: message = "the memory for rendering images is in use; retry"; break;
        case Admission::render_too_large: {
            // Never fits, however idle the server: waiting cannot help (IIIF sizes that can
            // shrink were shrunk before admission; a DZI or XYZ tile's size is fixed).
            HttpResponse r = httpapi::error(
                500, "this image needs more memory to render than this server's --render-memory allows; its operator must raise it",
                d.target.starts_with("/v1/"));
            return complete(d, std::move(r));
        }
        default: message = "the server is stopping"; break;
    }
    HttpResponse r = httpapi::retry_later(message, d.target.starts_with("/v1/"));
    return complete(d, std::move(r));
}

HttpResponse HttpHandler::expired(const DeferredAnswer& d) {
    HttpResponse r = httpapi::error(504, "the request's deadline passed before it could be answered",
                                    d.target.starts_with("/v1/"));
    return complete(d, std::move(r));
}

HttpResponse HttpHandler::finish(HttpResponse res, HttpRoute route_label, std::string_view origin, std::string_view target,
                                 bool head, std::chrono::steady_clock::time_point t0) {
    res.route = route_label;
    if (route_label != HttpRoute::preflight) httpapi::add_cors_headers(res, ctx_.config, origin);
    res.headers.emplace_back("Server", std::string(httpapi::kServer));
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    record(route_label, res.status, head ? 0 : res.body_size(), seconds);
    if (res.status >= 500 && res.status != 503 && res.status != 504)
        ctx_.log.warn("http request failed", {{"target", loggable_target(target)}, {"status", res.status}, {"body", res.body}});
    else if (ctx_.log.enabled(LogLevel::debug))
        ctx_.log.debug("http request", {{"target", loggable_target(target)}, {"status", res.status},
                                        {"bytes", static_cast<std::uint64_t>(res.body_size())}, {"seconds", seconds}});
    return res;
}

HttpResponse HttpHandler::route(const HttpRequestView& req, HttpRoute& route_label, bool borrow_payload) {
    const std::string_view raw_path = req.target.substr(0, req.target.find('?'));
    const bool api = raw_path.starts_with("/v1/") || raw_path == "/v1";

    if (raw_path == "/healthz") route_label = HttpRoute::healthz;
    else if (raw_path == "/readyz") route_label = HttpRoute::readyz;
    else if (raw_path == "/metrics") route_label = HttpRoute::metrics;
    else if (raw_path == "/v1/stores") route_label = HttpRoute::stores;

    // A browser's CORS preflight (or a plain OPTIONS): what may be asked, no auth (browsers send
    // no credentials with a preflight).
    if (req.method == "OPTIONS") {
        route_label = HttpRoute::preflight;
        return httpapi::preflight(ctx_.config, req);
    }
    if (req.method != "GET" && req.method != "HEAD") {
        HttpResponse r = httpapi::error(405, "method " + std::string(req.method) + " not allowed: use GET or HEAD", api);
        r.headers.emplace_back("Allow", "GET, HEAD, OPTIONS");
        return r;
    }
    // Probes never need a token (and ignore any query: a probe must not fail on a parameter).
    if (route_label == HttpRoute::healthz) return httpapi::text(200, "ok\n");
    if (route_label == HttpRoute::readyz) {
        if (ctx_.draining.load()) return httpapi::text(503, "draining\n");
        if (!ctx_.ready.load()) return httpapi::text(503, "not ready\n");
        return httpapi::text(200, "ready\n");
    }

    // Everything else is parsed strictly, then needs the token (header, ?access_token= or cookie).
    httpapi::ParsedRequest parsed;
    std::string query_token, why;
    const bool well_formed = httpapi::parse_request(req, parsed, query_token, why);
    if (!ctx_.open_access() && !authorized(httpapi::request_token(req, query_token), *ctx_.auth_token())) {
        HttpResponse r = httpapi::error(401, "missing or wrong bearer token", api);
        r.headers.emplace_back("WWW-Authenticate", "Bearer");
        return r;
    }
    if (route_label == HttpRoute::metrics) {
        HttpResponse r;
        r.content_type = kMetricsType;
        r.body = ctx_.metrics.render();
        r.headers.emplace_back("Cache-Control", "no-store");
        return r;
    }
    if (!well_formed) return httpapi::error(400, why, api);
    HttpResponse res;
    if (parsed.segments.empty()) {
        route_label = HttpRoute::viewer;
        res = httpapi::viewer_index(*this, parsed, route_label, borrow_payload);
    } else {
        const auto r = std::find_if(kRoutes.begin(), kRoutes.end(),
                                    [&](const Route& x) { return parsed.segments.front() == x.first_segment; });
        if (r == kRoutes.end()) return httpapi::error(404, "no such route: " + std::string(raw_path), api);
        res = r->answer(*this, parsed, route_label, borrow_payload);
    }
    // Documents revalidate by their bytes (a tile's ETag is its stored checksum; these have none).
    if (route_label == HttpRoute::stores || route_label == HttpRoute::store || route_label == HttpRoute::dzi_info ||
        route_label == HttpRoute::iiif_info)
        httpapi::validate_document(res, req.if_none_match);
    // A browser that came to a page with ?access_token= keeps the token as a cookie for the
    // page's own requests (docs/server.md, "Browsers"): only when a token is required and it
    // was right (the query's token itself: an Authorization header, which request_token
    // prefers, may be what let the request in), and only a token that cannot smuggle cookie
    // attributes.
    const bool cookie_safe = query_token.find_first_of(";, \t\"\\") == std::string::npos;
    if (!query_token.empty() && cookie_safe && !ctx_.auth_token()->empty() && route_label == HttpRoute::viewer &&
        res.status == 200 && authorized("Bearer " + query_token, *ctx_.auth_token()))
        res.headers.emplace_back("Set-Cookie", "tessera_token=" + query_token + "; Path=/; HttpOnly; SameSite=Strict" +
                                                   (req.secure ? "; Secure" : ""));
    return res;
}

HttpResponse handle_http_request(ServerContext& ctx, const HttpRequestView& req) {
    HttpHandler handler(ctx);
    return handler.handle_http_request(req);
}

}  // namespace tessera::server
