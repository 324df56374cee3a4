#pragma once
// What every HTTP API shares: the parsed request (path segments and query, decoded strictly),
// response builders (errors, JSON, text) and the conditional-request and CORS rules. The router
// (http_handler.cpp) parses once; each API (api_*.cpp, viewer.cpp) answers its own paths.
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "../http_handler.hpp"

namespace tessera::server::httpapi {

inline constexpr std::string_view kServer = "tessera/0.1";
inline constexpr std::string_view kTextPlain = "text/plain; charset=utf-8";
inline constexpr std::string_view kJson = "application/json";
inline constexpr unsigned kImmutableMaxAge = 31536000;  // a year: a versioned URL never changes

// A request target split and percent-decoded: "/a/b%20c?x=1" -> {"a", "b c"}, {{"x", "1"}}.
struct ParsedRequest {
    const HttpRequestView* raw = nullptr;
    std::string_view path;                                    // as sent, undecoded
    std::vector<std::string> segments;                        // decoded; "/" gives none
    std::vector<std::pair<std::string, std::string>> query;  // decoded, in order; access_token removed
    bool json_errors = false;                                 // errors as {"error": ...} (under /v1/)

    // The value of a query parameter given once; nullopt if absent. `twice` is set when it is
    // given more than once.
    std::optional<std::string> param(std::string_view key, bool* twice = nullptr) const;
    // The query keys that are not in `known` (an error for the strict APIs), joined for a message.
    std::string unknown_params(std::initializer_list<std::string_view> known) const;
};

// Splits and decodes the target strictly: absolute path, no empty or dot segments, percent-escapes
// that could smuggle '/', '.', '\', '%', controls or non-ASCII refused. Sets `error` (a 400
// message) and returns false when the target is malformed. `access_token` is moved out of the
// query into `token` (a browser cannot always send an Authorization header).
bool parse_request(const HttpRequestView& req, ParsedRequest& out, std::string& token, std::string& error);

// Responses. Every error is one line: JSON ({"error": ...}) for API clients, text elsewhere,
// never cached.
HttpResponse error(unsigned status, std::string_view message, bool json);
HttpResponse text(unsigned status, std::string body);
HttpResponse json_response(const nlohmann::json& j, std::string_view content_type = kJson);
// A 503 that asks the client to come back (Retry-After: 1).
HttpResponse retry_later(std::string_view message, bool json);
// An answer made off the event loop (HttpResponse::deferred): `answer` runs on the executor as
// work of `kind` in `store`'s lane, charged `memory` bytes when it is a render.
HttpResponse defer(WorkKind kind, std::shared_ptr<const StoreHandle> store, std::size_t memory,
                   std::function<HttpResponse()> answer);

// Cache-Control for a cacheable answer: public, or private when the server requires a token (a
// shared cache must not hand a token's answer to someone without it). immutable: the URL pins a
// store version (a year).
HeaderValue cache_control(const ServerContext& ctx, bool immutable);

// --public-url as answers write it: no query or fragment, no trailing '/'
// ("https://example.org/tiles/" -> "https://example.org/tiles"): what absolute URLs (IIIF ids)
// start with.
std::string public_base(std::string_view public_url);
// Its path ("/tiles"; "" when unset or at the root): what root-relative URLs in answers start
// with behind a proxy that serves this server under a path.
std::string public_path(std::string_view public_url);

// A strict decimal: digits only, no sign, no leading zeros (one URL per resource), below 2^32.
std::optional<std::uint32_t> parse_u32(std::string_view s);
// 1 to 16 hex digits.
std::optional<std::uint64_t> parse_version(std::string_view s);
bool iequals(std::string_view a, std::string_view b);

// Percent-decodes one path segment (`query` false) or query component: escapes to control or
// non-ASCII bytes are refused, and in a path '/', '.', '\\' and '%' too. False, with why, when so.
bool percent_decode(std::string_view in, std::string& out, std::string& why, bool query = false);

// If-None-Match with weak comparison (RFC 9110 13.1.2) against our quoted entity tag.
bool if_none_match_matches(std::string_view header, std::string_view etag_quoted);

// A document the server writes (store JSON, info.json, a .dzi): an ETag of its type and bytes,
// and a 304 with its headers and no body when `if_none_match` names it. Only a 200 without an
// ETag of its own is touched.
void validate_document(HttpResponse& r, std::string_view if_none_match);

// The bearer token a request carries: the Authorization header, else ?access_token=, else the
// tessera_token cookie (docs/server.md, "Browsers"). Empty when none.
std::string request_token(const HttpRequestView& req, const std::string& query_token);

// CORS: the headers every response to a cross-origin read carries (config.cors_origin: "*", one
// origin, or "" for none), and the answer to a preflight OPTIONS.
void add_cors_headers(HttpResponse& r, const ServerConfig& config, std::string_view origin);
HttpResponse preflight(const ServerConfig& config, const HttpRequestView& req);

}  // namespace tessera::server::httpapi
