#include "http_handler.hpp"

#include <array>
#include <charconv>
#include <exception>
#include <memory>
#include <optional>

#include <nlohmann/json.hpp>

#include "auth.hpp"
#include "tessera/hex.hpp"
#include "tessera/protocol/wire.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/layers.hpp"
#include "tessera/storage/png_encode.hpp"
#include "tessera/storage/store_json.hpp"

namespace tessera::server {

namespace {

constexpr std::string_view kServer = "tessera/0.1";
constexpr std::string_view kTextPlain = "text/plain; charset=utf-8";
constexpr std::string_view kJson = "application/json";
constexpr std::string_view kMetricsType = "text/plain; version=0.0.4; charset=utf-8";
constexpr unsigned kImmutableMaxAge = 31536000;  // a year: a versioned URL never changes

bool iequals(std::string_view a, std::string_view b) {
    if (a.size() != b.size()) return false;
    for (std::size_t i = 0; i < a.size(); ++i) {
        char x = a[i], y = b[i];
        if (x >= 'A' && x <= 'Z') x = static_cast<char>(x - 'A' + 'a');
        if (y >= 'A' && y <= 'Z') y = static_cast<char>(y - 'A' + 'a');
        if (x != y) return false;
    }
    return true;
}

// Error bodies: one line. JSON under /v1/ (API clients), text elsewhere.
HttpResponse error(unsigned status, std::string_view message, bool json) {
    HttpResponse r;
    r.status = status;
    if (json) {
        r.content_type = kJson;
        r.body = nlohmann::json{{"error", message}}.dump() + "\n";
    } else {
        r.content_type = kTextPlain;
        r.body = std::string(message) + "\n";
    }
    r.headers.emplace_back("Cache-Control", "no-store");
    return r;
}

HttpResponse text(unsigned status, std::string body) {
    HttpResponse r;
    r.status = status;
    r.content_type = kTextPlain;
    r.body = std::move(body);
    r.headers.emplace_back("Cache-Control", "no-store");
    return r;
}

HttpResponse json_response(const nlohmann::json& j) {
    HttpResponse r;
    r.status = 200;
    r.content_type = kJson;
    r.body = j.dump() + "\n";
    // Metadata changes when a store is replaced: clients revalidate (tile URLs carry ?v= instead).
    r.headers.emplace_back("Cache-Control", "no-cache");
    return r;
}

// A strict tile coordinate: decimal digits only, no sign, no leading zeros (one URL per tile, so
// caches are not split), at most 2^32 - 1.
std::optional<std::uint32_t> parse_u32(std::string_view s) {
    if (s.empty() || s.size() > 10) return std::nullopt;
    if (s.size() > 1 && s.front() == '0') return std::nullopt;
    for (char c : s)
        if (c < '0' || c > '9') return std::nullopt;
    std::uint64_t v = 0;
    for (char c : s) v = v * 10 + std::uint64_t(c - '0');
    if (v > 0xFFFFFFFFull) return std::nullopt;
    return static_cast<std::uint32_t>(v);
}

// ?v=: 1 to 16 hex digits (either case).
std::optional<std::uint64_t> parse_version(std::string_view s) {
    if (s.empty() || s.size() > 16) return std::nullopt;
    std::uint64_t v = 0;
    const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v, 16);
    if (ec != std::errc() || p != s.data() + s.size()) return std::nullopt;
    return v;
}

int hex_value(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

// Percent-decodes one path segment or query component. Escapes that decode to '/', '.', '\',
// '%', a control character or a non-ASCII byte are refused: nothing Tessera serves needs them,
// and they are how path tricks ("%2e%2e", "a%2fb") get past a router.
bool percent_decode(std::string_view in, std::string& out, std::string& why) {
    out.clear();
    for (std::size_t i = 0; i < in.size(); ++i) {
        const char c = in[i];
        if (c != '%') {
            out += c;
            continue;
        }
        if (i + 2 >= in.size()) {
            why = "truncated percent-escape";
            return false;
        }
        const int hi = hex_value(in[i + 1]), lo = hex_value(in[i + 2]);
        if (hi < 0 || lo < 0) {
            why = "malformed percent-escape";
            return false;
        }
        const auto d = static_cast<unsigned char>(hi * 16 + lo);
        if (d == '/' || d == '.' || d == '\\' || d == '%' || d < 0x20 || d >= 0x7f) {
            why = "percent-encoded '/', '.', '\\', '%', control or non-ASCII characters are not allowed";
            return false;
        }
        out += static_cast<char>(d);
        i += 2;
    }
    return true;
}

// Characters allowed raw in a request target (RFC 3986 pchar, '/' and '?'; '%' checked by decoding).
bool target_char_ok(char c) {
    const auto u = static_cast<unsigned char>(c);
    if (u <= 0x20 || u >= 0x7f) return false;
    switch (c) {
        case '"': case '<': case '>': case '\\': case '^': case '`': case '{': case '|': case '}': case '#':
            return false;
        default:
            return true;
    }
}

// If-None-Match with weak comparison (RFC 9110 13.1.2): "*" matches any current representation;
// otherwise a comma-separated list of entity tags, each maybe W/-prefixed, matching when its
// opaque tag equals ours. Malformed members are skipped.
bool if_none_match_matches(std::string_view header, std::string_view etag_quoted) {
    std::string_view ours = etag_quoted;
    std::size_t i = 0;
    while (i < header.size()) {
        while (i < header.size() && (header[i] == ' ' || header[i] == '\t' || header[i] == ',')) ++i;
        if (i >= header.size()) break;
        if (header[i] == '*') return true;
        if (header.compare(i, 2, "W/") == 0) i += 2;
        if (i < header.size() && header[i] == '"') {
            const std::size_t close = header.find('"', i + 1);
            if (close == std::string_view::npos) return false;
            if (header.substr(i, close - i + 1) == ours) return true;
            i = close + 1;
        } else {
            // Not an entity tag: skip to the next comma.
            const std::size_t comma = header.find(',', i);
            if (comma == std::string_view::npos) break;
            i = comma + 1;
        }
    }
    return false;
}

std::string_view content_type_of(Codec c) {
    switch (c) {
        case Codec::jpeg: return "image/jpeg";
        case Codec::zstd:
        case Codec::bc1:
        case Codec::bc4:
        case Codec::bc5:
        case Codec::bc7: return "application/zstd";
        case Codec::raw: return "application/octet-stream";
        case Codec::layers: return "application/x-tessera-layers";
    }
    return "application/octet-stream";
}

// The store's description (storage::store_json), and where the API serves it and its tiles.
nlohmann::json store_entry(const StoreHandle& h) {
    nlohmann::json j = storage::store_json(h.name, h.info());
    const std::string url = "/v1/stores/" + h.name;
    j["url"] = url;
    j["tiles"] = url + "/tiles/{level}/{x}/{y}?v=" + hex16(h.version);
    return j;
}

// Decrements the tile in-flight count when a tile request ends, however it ends.
struct InflightGuard {
    std::atomic<std::size_t>& n;
    ~InflightGuard() { n.fetch_sub(1, std::memory_order_relaxed); }
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
        case HttpRoute::other: return "other";
    }
    return "other";
}

const std::string* HttpResponse::header(std::string_view name) const {
    for (const auto& [k, v] : headers)
        if (iequals(k, name)) return &v;
    return nullptr;
}

HttpResponse http_error_response(unsigned status, std::string_view message) {
    HttpResponse r = error(status, message, false);
    r.headers.emplace_back("Server", std::string(kServer));
    return r;
}

HttpHandler::HttpHandler(ServerContext& ctx) : ctx_(ctx), requests_(kHttpRouteCount * kStatusSlots) {
    for (auto& c : requests_) c.store(nullptr, std::memory_order_relaxed);
    for (std::size_t r = 0; r < kHttpRouteCount; ++r) {
        const std::string route(to_string(static_cast<HttpRoute>(r)));
        duration_[r] = &ctx_.metrics.histogram("tessera_http_request_duration_seconds",
                                               "HTTP request handling time (request parsed -> response built)",
                                               {{"route", route}}, latency_buckets_seconds());
        response_bytes_[r] = &ctx_.metrics.counter("tessera_http_response_bytes_total",
                                                   "HTTP response body bytes sent (HEAD: none)", {{"route", route}});
    }
}

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

void HttpHandler::record(HttpRoute route, unsigned status, std::size_t body_bytes, double seconds) {
    const auto r = static_cast<std::size_t>(route);
    requests_counter(route, status).inc();
    duration_[r]->observe(seconds);
    if (body_bytes) response_bytes_[r]->inc(body_bytes);
}

void HttpHandler::record_transport_response(unsigned status, std::size_t body_bytes) {
    record(HttpRoute::other, status, body_bytes, 0.0);
}

HttpResponse HttpHandler::handle_http_request(const HttpRequestView& req, bool borrow_payload) {
    const auto t0 = std::chrono::steady_clock::now();
    HttpRoute route_label = HttpRoute::other;
    HttpResponse res;
    try {
        res = route(req, route_label, borrow_payload);
    } catch (const std::exception& e) {
        ctx_.log.error("http handler failed", {{"target", req.target}, {"error", e.what()}});
        res = error(500, "internal error", req.target.starts_with("/v1/"));
    }
    res.route = route_label;
    res.headers.emplace_back("Server", std::string(kServer));
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    record(route_label, res.status, req.method == "HEAD" ? 0 : res.body_size(), seconds);
    if (res.status >= 500 && res.status != 503)
        ctx_.log.warn("http request failed", {{"target", req.target}, {"status", res.status}, {"body", res.body}});
    else if (ctx_.log.enabled(LogLevel::debug))
        ctx_.log.debug("http request", {{"method", req.method}, {"target", req.target}, {"status", res.status},
                                        {"bytes", static_cast<std::uint64_t>(res.body_size())}, {"seconds", seconds}});
    return res;
}

HttpResponse HttpHandler::route(const HttpRequestView& req, HttpRoute& route_label, bool borrow_payload) {
    // Split off the query; the path must be origin-form.
    const std::size_t q = req.target.find('?');
    const std::string_view raw_path = req.target.substr(0, q);
    const std::string_view raw_query = q == std::string_view::npos ? std::string_view() : req.target.substr(q + 1);
    const bool api = raw_path.starts_with("/v1/") || raw_path == "/v1";

    if (raw_path == "/healthz") route_label = HttpRoute::healthz;
    else if (raw_path == "/readyz") route_label = HttpRoute::readyz;
    else if (raw_path == "/metrics") route_label = HttpRoute::metrics;
    else if (raw_path == "/v1/stores") route_label = HttpRoute::stores;

    if (req.method != "GET" && req.method != "HEAD") {
        HttpResponse r = error(405, "method " + std::string(req.method) + " not allowed: use GET or HEAD", api);
        r.headers.emplace_back("Allow", "GET, HEAD");
        return r;
    }
    // Probes never need a token (and ignore any query: a probe must not fail on a parameter).
    if (route_label == HttpRoute::healthz) return text(200, "ok\n");
    if (route_label == HttpRoute::readyz) {
        if (ctx_.draining.load()) return text(503, "draining\n");
        if (!ctx_.ready.load()) return text(503, "not ready\n");
        return text(200, "ready\n");
    }
    if (!authorized(req.authorization, *ctx_.auth_token())) {
        HttpResponse r = error(401, "missing or wrong bearer token", api);
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

    // Everything else is parsed strictly.
    if (raw_path.empty() || raw_path.front() != '/')
        return error(400, "request target must be an absolute path", api);
    for (char c : req.target)
        if (!target_char_ok(c)) return error(400, "request target has a character that must be percent-encoded", api);

    std::vector<std::string> seg;
    std::string why;
    if (raw_path != "/") {
        std::size_t start = 1;
        while (true) {
            const std::size_t slash = raw_path.find('/', start);
            const std::string_view s = raw_path.substr(start, slash == std::string_view::npos ? std::string_view::npos : slash - start);
            if (s.empty()) return error(400, "empty path segment", api);
            if (s == "." || s == "..") return error(400, "dot segments are not allowed in paths", api);
            std::string decoded;
            if (!percent_decode(s, decoded, why)) return error(400, "bad path: " + why, api);
            seg.push_back(std::move(decoded));
            if (slash == std::string_view::npos) break;
            start = slash + 1;
        }
    }

    // Query: only `format` (png), `v` (store version, hex) and `layer` (which layer of a
    // multi-layer store a PNG shows) are known, each at most once.
    std::optional<std::string> format;
    std::optional<std::uint64_t> version;
    std::optional<std::string> layer;
    {
        std::size_t start = 0;
        while (start <= raw_query.size() && !raw_query.empty()) {
            const std::size_t amp = raw_query.find('&', start);
            const std::string_view pair = raw_query.substr(start, amp == std::string_view::npos ? std::string_view::npos : amp - start);
            if (!pair.empty()) {
                const std::size_t eq = pair.find('=');
                std::string key, value;
                if (!percent_decode(pair.substr(0, eq), key, why) ||
                    !percent_decode(eq == std::string_view::npos ? std::string_view() : pair.substr(eq + 1), value, why))
                    return error(400, "bad query: " + why, api);
                if (key == "format") {
                    if (format) return error(400, "query parameter 'format' given twice", api);
                    if (value != "png") return error(400, "unknown format '" + value + "': the only format is png", api);
                    format = value;
                } else if (key == "v") {
                    if (version) return error(400, "query parameter 'v' given twice", api);
                    version = parse_version(value);
                    if (!version) return error(400, "query parameter 'v' must be the store version in hex", api);
                } else if (key == "layer") {
                    if (layer) return error(400, "query parameter 'layer' given twice", api);
                    layer = value;
                } else {
                    return error(400, "unknown query parameter '" + key + "' (known: format, v, layer)", api);
                }
            }
            if (amp == std::string_view::npos) break;
            start = amp + 1;
        }
    }

    if (seg.size() < 2 || seg[0] != "v1" || seg[1] != "stores") {
        route_label = HttpRoute::other;
        return error(404, "no such route: " + std::string(raw_path), api);
    }
    if (seg.size() == 2) {
        route_label = HttpRoute::stores;
        if (format || version || layer) return error(400, "query parameters 'format', 'v' and 'layer' apply to tiles only", api);
        nlohmann::json list = nlohmann::json::array();
        for (const auto& h : ctx_.stores.list()) list.push_back(store_entry(*h));
        return json_response(nlohmann::json{{"stores", std::move(list)}});
    }
    const std::string& name = seg[2];
    if (seg.size() == 3) {
        route_label = HttpRoute::store;
        if (!protocol::valid_store_name(name)) return error(400, "invalid store name", api);
        if (format || version || layer) return error(400, "query parameters 'format', 'v' and 'layer' apply to tiles only", api);
        const auto h = ctx_.stores.find(name);
        if (!h) return error(404, "unknown store '" + name + "'", api);
        return json_response(store_entry(*h));
    }
    if (seg[3] != "tiles") {
        route_label = HttpRoute::other;
        return error(404, "no such route: " + std::string(raw_path), api);
    }
    route_label = format ? HttpRoute::tile_png : HttpRoute::tile;
    if (seg.size() != 7) return error(400, "a tile URL is /v1/stores/{name}/tiles/{level}/{x}/{y}", api);
    return tile(req, name, seg[4], seg[5], seg[6], format.has_value(), layer, version.has_value(), version.value_or(0),
                borrow_payload);
}

HttpResponse HttpHandler::tile(const HttpRequestView& req, std::string_view name, std::string_view level_s,
                               std::string_view x_s, std::string_view y_s, bool png,
                               const std::optional<std::string>& layer_name, bool has_version,
                               std::uint64_t want_version, bool borrow_payload) {
    constexpr bool api = true;
    if (!protocol::valid_store_name(name)) return error(400, "invalid store name", api);
    if (layer_name && !png)
        return error(400, "query parameter 'layer' picks the layer format=png shows; the stored payload holds every layer", api);
    const auto level = parse_u32(level_s), x = parse_u32(x_s), y = parse_u32(y_s);
    if (!level || !x || !y)
        return error(400, "level, x and y must be decimal integers below 2^32 (digits only, no leading zeros)", api);

    // Bound the tile requests served at once (config.max_http_inflight).
    const std::size_t now = tiles_in_flight_.fetch_add(1, std::memory_order_relaxed) + 1;
    InflightGuard guard{tiles_in_flight_};
    if (now > ctx_.config.max_http_inflight) {
        HttpResponse r = error(503, "too many tile requests in flight; retry", api);
        r.headers.emplace_back("Retry-After", "1");
        return r;
    }

    const std::shared_ptr<const StoreHandle> h = ctx_.stores.find(name);
    if (!h) return error(404, "unknown store '" + std::string(name) + "'", api);
    const storage::StoreInfo& info = h->info();
    if (h->metrics.requests) h->metrics.requests->inc();
    const std::string version_hex = hex16(h->version);

    // A pinned version that is not the one served: 404, not 409 or a redirect. The URL names a
    // representation this server does not have (versions are content hashes; an old one is gone
    // for good unless the same file comes back). The client refetches the store metadata and
    // uses the new version; caches may not keep this answer (no-store, as every error).
    if (has_version && want_version != h->version)
        return error(404, "store version " + hex16(want_version) + " is not served (current " + version_hex + ")", api);

    if (*level >= info.level_count())
        return error(404, "level " + std::to_string(*level) + " out of range: the store has levels 0.." +
                              std::to_string(info.level_count() - 1), api);
    const storage::LevelInfo& li = info.levels[*level];
    if (*x >= li.tiles_x || *y >= li.tiles_y)
        return error(404, "tile (" + std::to_string(*x) + ", " + std::to_string(*y) + ") out of range at level " +
                              std::to_string(*level) + ": x in 0.." + std::to_string(li.tiles_x - 1) +
                              ", y in 0.." + std::to_string(li.tiles_y - 1), api);
    // A multi-layer store's PNG shows one layer: ?layer=NAME, else layer 0.
    std::size_t layer = 0;
    if (layer_name) {
        if (!info.layered()) return error(400, "store '" + std::string(name) + "' has no layers", api);
        while (layer < info.layers.size() && info.layers[layer].name != *layer_name) ++layer;
        if (layer == info.layers.size()) {
            std::string names;
            for (const auto& l : info.layers) names += (names.empty() ? "" : ", ") + l.name;
            return error(400, "unknown layer '" + *layer_name + "': store '" + std::string(name) + "' has layers " + names, api);
        }
    }
    const storage::StoreInfo shown = png && info.layered() ? storage::layer_store_info(info, layer) : storage::StoreInfo{};
    const storage::StoreInfo& png_info = info.layered() ? shown : info;
    if (png && (png_info.sample_type == storage::SampleType::f16 || png_info.sample_type == storage::SampleType::f32))
        return error(406, "format=png is not available for " + std::string(storage::to_string(png_info.sample_type)) +
                              (info.layered() ? " layers" : " stores") + " (PNG has no float samples); fetch the stored payload",
                     api);
    const std::string png_tag = !png ? "" : info.layered() ? "-png-" + info.layers[layer].name : "-png";

    const std::string cache_control = has_version
        ? "public, max-age=" + std::to_string(kImmutableMaxAge) + ", immutable"
        : "public, max-age=" + std::to_string(ctx_.config.http_max_age);
    const TileKey key{*level, *x, *y};
    auto etag_of = [&](std::uint64_t checksum) {
        return "\"" + version_hex + "-" + hex16(checksum) + png_tag + "\"";
    };
    auto common_headers = [&](HttpResponse& r, TileKind kind, std::string_view codec) {
        r.headers.emplace_back("Cache-Control", cache_control);
        r.headers.emplace_back("X-Tessera-Store-Version", version_hex);
        r.headers.emplace_back("X-Tessera-Kind", std::string(tessera::to_string(kind)));
        if (!codec.empty()) r.headers.emplace_back("X-Tessera-Codec", std::string(codec));
    };
    auto not_modified = [&](TileKind kind, const std::string& etag) {
        HttpResponse r;
        r.status = 304;
        r.headers.emplace_back("ETag", etag);
        common_headers(r, kind, {});
        return r;
    };

    // Revalidation from the index alone (the entry holds the payload's checksum): a 304 costs
    // no payload read. An entry that locates but whose payload is corrupt still answers 304 here;
    // the client holds bytes that passed the checksum when they were served.
    if (!req.if_none_match.empty()) {
        const auto loc = h->reader->locate(key);
        if (loc.ok() && loc->kind != TileKind::absent) {
            const std::string etag = etag_of(loc->checksum);
            if (if_none_match_matches(req.if_none_match, etag)) return not_modified(loc->kind, etag);
        }
    }

    const FetchedTile fetched = ctx_.fetcher.fetch_one(*h, key);
    switch (fetched.status) {
        case TileStatus::ok: break;
        case TileStatus::data_loss: return error(500, "tile failed its checksum", api);
        case TileStatus::not_found: return error(404, "unknown store '" + std::string(name) + "'", api);
        case TileStatus::out_of_range: return error(404, "tile out of range: " + fetched.message, api);
        case TileStatus::resource_exhausted:
        case TileStatus::unavailable:
        case TileStatus::deadline_exceeded: {
            HttpResponse r = error(503, "tile unavailable: " + fetched.message, api);
            r.headers.emplace_back("Retry-After", "1");
            return r;
        }
        default: return error(500, "tile read failed: " + fetched.message, api);
    }
    if (!fetched.tile) return error(500, "tile read failed: no tile returned", api);
    const storage::Tile& t = *fetched.tile;
    if (t.kind == TileKind::absent) {
        // A definite answer for this store version, so it is cacheable like a tile.
        HttpResponse r = error(404, "tile absent in a sparse store", api);
        r.headers.clear();
        common_headers(r, TileKind::absent, {});
        return r;
    }

    const std::string etag = etag_of(t.checksum);
    if (!req.if_none_match.empty() && if_none_match_matches(req.if_none_match, etag)) return not_modified(t.kind, etag);

    HttpResponse r;
    r.status = 200;
    r.headers.emplace_back("ETag", etag);
    if (png) {
        // A bundle's part of the shown layer, as a tile of that layer.
        storage::Tile part;
        const storage::Tile* decoded = &t;
        TileKind kind = t.kind;
        if (info.layered()) {
            auto parts = storage::split_layers(info, t.bytes);
            if (!parts) return error(500, "tile bundle does not split into the store's layers: " + parts.error().message, api);
            const storage::LayerPart& p = (*parts)[layer];
            if (p.kind == TileKind::absent) {
                // As definite (and as cacheable) as an absent tile.
                HttpResponse a = error(404, "layer '" + info.layers[layer].name + "' of this tile is absent", api);
                a.headers.clear();
                common_headers(a, TileKind::absent, {});
                a.headers.emplace_back("X-Tessera-Layer", info.layers[layer].name);
                return a;
            }
            part = storage::layer_tile(t.key, p);
            decoded = &part;
            kind = p.kind;
            r.headers.emplace_back("X-Tessera-Layer", info.layers[layer].name);
        }
        std::vector<std::uint8_t> texels;
        if (const Status s = storage::decode_tile(png_info, *decoded, texels); !s.ok())
            return error(500, "tile does not decode: " + s.error().message, api);
        auto encoded = storage::encode_tile_png(png_info, texels);
        if (!encoded.ok())
            return error(encoded.error().code == Errc::unsupported ? 406 : 500, encoded.error().message, api);
        r.content_type = "image/png";
        r.body.assign(reinterpret_cast<const char*>(encoded->data()), encoded->size());
        common_headers(r, kind, "png");
    } else {
        r.content_type = t.kind == TileKind::uniform ? "application/octet-stream" : std::string(content_type_of(info.codec));
        if (borrow_payload) r.payload = fetched.tile;
        else r.body.assign(reinterpret_cast<const char*>(t.bytes.data()), t.bytes.size());
        common_headers(r, t.kind, t.kind == TileKind::uniform ? "uniform" : tessera::to_string(info.codec));
        r.headers.emplace_back("X-Tessera-Checksum", hex16(t.checksum));
    }
    if (req.method != "HEAD") {
        tiles_served_counter(h->name).inc();
        if (h->metrics.tiles_sent) h->metrics.tiles_sent->inc();
        if (h->metrics.bytes_sent) h->metrics.bytes_sent->inc(r.body_size());
    }
    return r;
}

HttpResponse handle_http_request(ServerContext& ctx, const HttpRequestView& req) {
    HttpHandler handler(ctx);
    return handler.handle_http_request(req);
}

}  // namespace tessera::server
