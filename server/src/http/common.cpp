#include "common.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cstdio>

#include <nlohmann/json.hpp>
#include <xxhash.h>

#include "tessera/hex.hpp"
#include "tessera/host_port.hpp"

namespace tessera::server::httpapi {

namespace {

int hex_value(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}


// Characters allowed raw in a request target: RFC 3986 pchar, '/' and '?' ('%' is checked by
// decoding), and '^', which IIIF's size syntax uses unescaped.
bool target_char_ok(char c) {
    const auto u = static_cast<unsigned char>(c);
    if (u <= 0x20 || u >= 0x7f) return false;
    switch (c) {
        case '"': case '<': case '>': case '\\': case '`': case '{': case '|': case '}': case '#':
            return false;
        default:
            return true;
    }
}

// The value of one cookie in a Cookie header ("a=1; b=2"), empty when absent.
std::string_view cookie_value(std::string_view header, std::string_view name) {
    std::size_t i = 0;
    while (i < header.size()) {
        while (i < header.size() && (header[i] == ' ' || header[i] == ';')) ++i;
        const std::size_t end = header.find(';', i);
        const std::string_view pair = header.substr(i, end == std::string_view::npos ? std::string_view::npos : end - i);
        const std::size_t eq = pair.find('=');
        if (eq != std::string_view::npos && pair.substr(0, eq) == name) return pair.substr(eq + 1);
        if (end == std::string_view::npos) break;
        i = end + 1;
    }
    return {};
}

}  // namespace

// Percent-decodes one path segment or query component. Escapes that decode to a control
// character or a non-ASCII byte are refused everywhere. In a path segment so are '/', '.', '\'
// and '%': nothing Tessera serves needs them, and they are how path tricks ("%2e%2e", "a%2fb")
// get past a router. A query value is never a path, and an access token may hold any printable
// ASCII, which URL encoders escape ('/' as %2F): `query` lets those through.
bool percent_decode(std::string_view in, std::string& out, std::string& why, bool query) {
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
        if (d < 0x20 || d >= 0x7f) {
            why = "percent-encoded control or non-ASCII characters are not allowed";
            return false;
        }
        if (!query && (d == '/' || d == '.' || d == '\\' || d == '%')) {
            why = "percent-encoded '/', '.', '\\' or '%' is not allowed in a path";
            return false;
        }
        out += static_cast<char>(d);
        i += 2;
    }
    return true;
}

std::optional<std::string> ParsedRequest::param(std::string_view key, bool* twice) const {
    std::optional<std::string> v;
    for (const auto& [k, value] : query)
        if (k == key) {
            if (v && twice) *twice = true;
            if (!v) v = value;
        }
    return v;
}

std::string ParsedRequest::unknown_params(std::initializer_list<std::string_view> known) const {
    std::string out;
    for (const auto& [k, v] : query) {
        bool ok = false;
        for (auto kn : known) ok = ok || k == kn;
        if (!ok) out += (out.empty() ? "'" : ", '") + k + "'";
    }
    return out;
}

namespace {

// RFC 9110 7.2 / RFC 3986 3.2.2: a Host value is a host (a name of unreserved, sub-delims and
// percent escapes, or a bracketed IP literal) and an optional port (at most 65535). The IIIF API
// writes it into URLs it returns (`id`, Location), so anything else is refused (RFC 9112 3.2:
// 400) rather than echoed into a URL or, as bytes that are not UTF-8, into JSON. Empty is no
// Host at all (HTTP/1.0): the transport puts the address the client reached in its place.
bool host_ok(std::string_view host) {
    if (host.empty()) return true;
    const auto parts = split_host_port(host);
    if (!parts) return false;
    if (parts->bracketed) {
        if (parts->host.size() < 2) return false;
        for (const char c : parts->host)
            if (!std::isxdigit(static_cast<unsigned char>(c)) && c != ':' && c != '.') return false;
    } else {
        if (parts->host.empty()) return false;
        for (const char c : parts->host) {
            const auto u = static_cast<unsigned char>(c);
            if ((u >= 'a' && u <= 'z') || (u >= 'A' && u <= 'Z') || (u >= '0' && u <= '9')) continue;
            if (std::string_view("-._~!$&'()*+,;=%").find(c) == std::string_view::npos) return false;
        }
    }
    return parts->port.empty() || parse_port(parts->port).has_value();  // "HOST:" is allowed (RFC 3986 3.2.3)
}

}  // namespace

std::string public_base(std::string_view public_url) {
    std::string_view base = public_url.substr(0, public_url.find_first_of("?#"));
    const std::size_t scheme = base.find("://");
    const std::size_t keep = scheme == std::string_view::npos ? 0 : scheme + 3;  // "http://" itself stays
    while (base.size() > keep && base.back() == '/') base.remove_suffix(1);
    return std::string(base);
}

std::string public_path(std::string_view public_url) {
    const std::string base = public_base(public_url);
    const std::size_t scheme = base.find("://");
    if (scheme == std::string::npos) return {};
    const std::size_t slash = base.find('/', scheme + 3);
    return slash == std::string::npos ? std::string() : base.substr(slash);
}

bool parse_request(const HttpRequestView& req, ParsedRequest& out, std::string& token, std::string& error) {
    const std::size_t q = req.target.find('?');
    const std::string_view raw_path = req.target.substr(0, q);
    const std::string_view raw_query = q == std::string_view::npos ? std::string_view() : req.target.substr(q + 1);
    out.raw = &req;
    out.path = raw_path;
    out.json_errors = raw_path.starts_with("/v1/") || raw_path == "/v1";
    if (raw_path.empty() || raw_path.front() != '/') {
        error = "request target must be an absolute path";
        return false;
    }
    for (char c : req.target)
        if (!target_char_ok(c)) {
            error = "request target has a character that must be percent-encoded";
            return false;
        }
    if (!host_ok(req.host)) {
        error = "Host header is not a host and port";
        return false;
    }
    std::string why;
    out.segments.reserve(8);  // /v1/stores/{name}/tiles/{level}/{x}/{y}: one allocation
    if (raw_path != "/") {
        std::size_t start = 1;
        while (true) {
            const std::size_t slash = raw_path.find('/', start);
            const std::string_view s =
                raw_path.substr(start, slash == std::string_view::npos ? std::string_view::npos : slash - start);
            if (s.empty()) {
                error = "empty path segment";
                return false;
            }
            if (s == "." || s == "..") {
                error = "dot segments are not allowed in paths";
                return false;
            }
            std::string decoded;
            if (!percent_decode(s, decoded, why)) {
                error = "bad path: " + why;
                return false;
            }
            out.segments.push_back(std::move(decoded));
            if (slash == std::string_view::npos) break;
            start = slash + 1;
        }
    }
    std::size_t start = 0;
    while (!raw_query.empty() && start <= raw_query.size()) {
        const std::size_t amp = raw_query.find('&', start);
        const std::string_view pair =
            raw_query.substr(start, amp == std::string_view::npos ? std::string_view::npos : amp - start);
        if (!pair.empty()) {
            const std::size_t eq = pair.find('=');
            std::string key, value;
            if (!percent_decode(pair.substr(0, eq), key, why, true) ||
                !percent_decode(eq == std::string_view::npos ? std::string_view() : pair.substr(eq + 1), value, why, true)) {
                error = "bad query: " + why;
                return false;
            }
            if (key == "access_token") {
                if (!token.empty()) {
                    error = "query parameter 'access_token' given twice";
                    return false;
                }
                token = std::move(value);
            } else {
                out.query.emplace_back(std::move(key), std::move(value));
            }
        }
        if (amp == std::string_view::npos) break;
        start = amp + 1;
    }
    return true;
}

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

HttpResponse json_response(const nlohmann::json& j, std::string_view content_type) {
    HttpResponse r;
    r.status = 200;
    r.content_type = content_type;
    r.body = j.dump() + "\n";
    // Metadata changes when a store is replaced: clients revalidate (tile URLs carry ?v= instead).
    r.headers.emplace_back("Cache-Control", "no-cache");
    return r;
}

HttpResponse retry_later(std::string_view message, bool json) {
    HttpResponse r = error(503, message, json);
    r.headers.emplace_back("Retry-After", "1");
    return r;
}

HttpResponse defer(WorkKind kind, std::shared_ptr<const StoreHandle> store, std::size_t memory,
                   std::function<HttpResponse()> answer) {
    HttpResponse r;
    r.deferred = std::make_shared<DeferredAnswer>();
    r.deferred->kind = kind;
    r.deferred->store = std::move(store);
    r.deferred->memory = memory;
    r.deferred->answer = std::move(answer);
    return r;
}

HeaderValue cache_control(const ServerContext& ctx, bool immutable) {
    // Built in place (every tile answer has one), without printf.
    const std::string_view scope = ctx.open_access() || ctx.auth_token()->empty() ? "public, max-age=" : "private, max-age=";
    char buf[64];
    char* p = std::copy(scope.begin(), scope.end(), buf);
    const auto age = immutable ? static_cast<long long>(kImmutableMaxAge) : static_cast<long long>(ctx.config.http_max_age);
    p = std::to_chars(p, buf + 40, age).ptr;  // 17 + at most 20 characters
    if (immutable) {
        constexpr std::string_view tail = ", immutable";
        p = std::copy(tail.begin(), tail.end(), p);
    }
    return HeaderValue(std::string_view(buf, std::size_t(p - buf)));
}

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

std::optional<std::uint64_t> parse_version(std::string_view s) {
    if (s.empty() || s.size() > 16) return std::nullopt;
    std::uint64_t v = 0;
    const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v, 16);
    if (ec != std::errc() || p != s.data() + s.size()) return std::nullopt;
    return v;
}

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

void validate_document(HttpResponse& r, std::string_view if_none_match) {
    if (r.status != 200 || r.payload || r.deferred) return;
    for (const auto& h : r.headers)
        if (h.first == "ETag") return;
    // The type seeds the hash: info.json's body is the same under either type Accept picks.
    const std::uint64_t type_hash = XXH3_64bits(r.content_type.data(), r.content_type.size());
    const std::string etag = "\"" + hex16(XXH3_64bits_withSeed(r.body.data(), r.body.size(), type_hash)) + "\"";
    r.headers.emplace_back("ETag", etag);
    if (!if_none_match.empty() && if_none_match_matches(if_none_match, etag)) {
        r.status = 304;
        r.content_type.clear();
        r.body.clear();
    }
}

bool if_none_match_matches(std::string_view header, std::string_view etag_quoted) {
    std::size_t i = 0;
    while (i < header.size()) {
        while (i < header.size() && (header[i] == ' ' || header[i] == '\t' || header[i] == ',')) ++i;
        if (i >= header.size()) break;
        if (header[i] == '*') return true;
        if (header.compare(i, 2, "W/") == 0) i += 2;
        if (i < header.size() && header[i] == '"') {
            const std::size_t close = header.find('"', i + 1);
            if (close == std::string_view::npos) return false;
            if (header.substr(i, close - i + 1) == etag_quoted) return true;
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

std::string request_token(const HttpRequestView& req, const std::string& query_token) {
    if (!req.authorization.empty()) return std::string(req.authorization);
    if (!query_token.empty()) return "Bearer " + query_token;
    const std::string_view c = cookie_value(req.cookie, "tessera_token");
    if (!c.empty()) return "Bearer " + std::string(c);
    return {};
}

void add_cors_headers(HttpResponse& r, const ServerConfig& config, std::string_view origin) {
    if (config.cors_origin.empty()) return;
    // One allowed origin: the answer depends on the Origin header, so caches must key on it.
    if (config.cors_origin != "*") r.headers.emplace_back("Vary", "Origin");
    if (origin.empty() || (config.cors_origin != "*" && origin != config.cors_origin)) return;
    r.headers.emplace_back("Access-Control-Allow-Origin", config.cors_origin);
    // The headers a script may read besides the safelisted ones.
    r.headers.emplace_back("Access-Control-Expose-Headers",
                           "ETag, Retry-After, X-Tessera-Store-Version, X-Tessera-Kind, X-Tessera-Codec, "
                           "X-Tessera-Checksum, X-Tessera-Layer");
}

HttpResponse preflight(const ServerConfig& config, const HttpRequestView& req) {
    HttpResponse r;
    r.status = 204;
    r.headers.emplace_back("Allow", "GET, HEAD, OPTIONS");
    if (!config.cors_origin.empty() && config.cors_origin != "*") r.headers.emplace_back("Vary", "Origin");
    if (!config.cors_origin.empty() && !req.origin.empty() &&
        (config.cors_origin == "*" || req.origin == config.cors_origin)) {
        r.headers.emplace_back("Access-Control-Allow-Origin", config.cors_origin);
        r.headers.emplace_back("Access-Control-Allow-Methods", "GET, HEAD, OPTIONS");
        // Authorization is never covered by a wildcard: named.
        r.headers.emplace_back("Access-Control-Allow-Headers", "Authorization, If-None-Match");
        r.headers.emplace_back("Access-Control-Max-Age", "86400");
    }
    r.headers.emplace_back("Cache-Control", "no-store");
    return r;
}

}  // namespace tessera::server::httpapi
