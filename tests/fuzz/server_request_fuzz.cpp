// libFuzzer target: the server's request handling without a transport. HTTP requests go to
// HttpHandler::handle_http_request, decoded tile batches to the Scheduler (its I/O thread reads
// the tiles), and every answer is checked against what was written to the stores and against
// the documented semantics (auth, ETag/304, strict URLs, batch acks, cancellation of superseded
// requests, DATA_LOSS for a corrupted tile, queues empty after a drain). Input format:
// server_fuzz_common.hpp.
//
// The process-wide fixture (made on first use): two stores written into a scratch directory
// (deleted again once the registries have opened them: the readers keep their descriptors),
// and two server contexts over them, each with its own metrics, cache, fetcher, scheduler (one
// I/O thread) and HTTP handler:
//   context 0: no auth, max_batch 64, max_pending 256, viewer buffer 64 KiB, 256 KiB cache;
//   context 1: auth token "t0k", max_batch 48, max_pending 12, viewer buffer 16 KiB, no cache.
//
// Debian's libprotobuf and libgrpc are not instrumented; they raised no false ASan, UBSan or ODR
// reports in the runs so far, so run_fuzzers.cmake passes no sanitizer options. Each input takes
// about a millisecond; SERVER_REQUEST_FUZZ_VERBOSE=1 prints what an input does.
#include <fcntl.h>
#include <unistd.h>
#include <xxhash.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include <google/protobuf/stubs/logging.h>
#include <nlohmann/json.hpp>

#include "http_handler.hpp"
#include "log.hpp"
#include "metrics.hpp"
#include "prometheus_text.hpp"
#include "scheduler.hpp"
#include "server_context.hpp"
#include "server_fuzz_common.hpp"
#include "store_registry.hpp"
#include "tessera/protocol/wire.hpp"
#include "tile_cache.hpp"
#include "tile_fetcher.hpp"

namespace {

using namespace tessera;
using namespace tessera::server;
using tessera::fuzz::ExpectedStore;
using tessera::fuzz::ExpectedTile;
using tessera::TileKey;
using tessera::TileKind;

#define FUZZ_CHECK(cond)                                                                               \
    do {                                                                                               \
        if (!(cond)) {                                                                                 \
            std::fprintf(stderr, "server_request_fuzz: check failed at line %d: %s\n", __LINE__, #cond); \
            std::abort();                                                                              \
        }                                                                                              \
    } while (0)

constexpr std::string_view kToken = "t0k";
constexpr auto kDrainLimit = std::chrono::seconds(5);  // far below libFuzzer's -timeout
constexpr unsigned kMetricsParseEvery = 64;             // parse_prometheus_text is slow-ish

std::string hex16(std::uint64_t v) {
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(v));
    return std::string(buf, 16);
}

// ---- fixture -----------------------------------------------------------------------------------

// One server context. Members are destroyed in reverse order: the handler and the scheduler
// (whose thread uses the rest) first, the metrics registry they all register in last.
struct Instance {
    ServerConfig config;
    Logger log;
    MetricsRegistry metrics;
    std::unique_ptr<StoreRegistry> stores;
    std::unique_ptr<TileCache> cache;
    std::unique_ptr<TileFetcher> fetcher;
    std::unique_ptr<ServerContext> ctx;
    std::unique_ptr<Scheduler> scheduler;
    std::unique_ptr<HttpHandler> http;

    Instance(ServerConfig c, int log_fd) : config(std::move(c)), log(LogFormat::json, LogLevel::debug, log_fd) {
        stores = std::make_unique<StoreRegistry>(config.store_files, config.store_dirs, log, metrics);
        const Status st = stores->open();
        if (!st) {
            std::fprintf(stderr, "server_request_fuzz: opening the stores: %s\n", st.error().message.c_str());
            std::abort();
        }
        FUZZ_CHECK(stores->list().size() == 2);
        cache = std::make_unique<TileCache>(config.cache_bytes);
        fetcher = std::make_unique<TileFetcher>(*cache, metrics, log);
        ctx.reset(new ServerContext{config, log, metrics, *stores, *fetcher});
        ctx->ready = true;
        scheduler = std::make_unique<Scheduler>(*ctx);
        http = std::make_unique<HttpHandler>(*ctx);
    }
};

struct Fixture {
    std::vector<ExpectedStore> expected;  // "a", "b"
    int devnull = -1;
    std::unique_ptr<Instance> inst[2];

    Fixture() {
        // Quiet protobuf: it logs an error for every string field that is not UTF-8 when parsing.
        google::protobuf::SetLogHandler(nullptr);
        // Logs at debug level (so the logging code runs) to /dev/null.
        devnull = ::open("/dev/null", O_WRONLY | O_CLOEXEC);
        FUZZ_CHECK(devnull >= 0);
        std::string dir = (std::filesystem::temp_directory_path() / "tessera-server-fuzz-XXXXXX").string();
        FUZZ_CHECK(::mkdtemp(dir.data()) != nullptr);
        const std::string err = fuzz::write_server_fuzz_stores(dir, expected);
        if (!err.empty()) {
            std::fprintf(stderr, "server_request_fuzz: writing the stores: %s\n", err.c_str());
            std::abort();
        }
        ServerConfig c0;
        c0.store_dirs = {dir};
        c0.io_threads = 1;  // one reader: the order of replies is exact (check_stream relies on it)
        c0.max_batch = 64;
        c0.max_pending = 256;
        c0.viewer_buffer_bytes = 64 << 10;
        c0.total_buffer_bytes = 1 << 20;
        c0.cache_bytes = 256 << 10;
        c0.max_viewers = 4;
        c0.resend_after = std::chrono::hours(1);  // re-listed tiles: never a time-out within one input
        ServerConfig c1 = c0;
        c1.auth_token = std::string(kToken);
        c1.max_batch = 48;
        c1.max_pending = 12;
        c1.viewer_buffer_bytes = 16 << 10;
        c1.total_buffer_bytes = 24 << 10;
        c1.cache_bytes = 0;
        c1.http_max_age = 0;
        inst[0] = std::make_unique<Instance>(c0, devnull);
        inst[1] = std::make_unique<Instance>(c1, devnull);
        std::error_code ec;
        std::filesystem::remove_all(dir, ec);  // the readers hold their files open
    }
    ~Fixture() {
        inst[1].reset();
        inst[0].reset();
        if (devnull >= 0) ::close(devnull);
    }

    const ExpectedStore* store(std::string_view name) const {
        for (const auto& s : expected)
            if (s.name == name) return &s;
        return nullptr;
    }
};

Fixture& fixture() {
    static Fixture f;
    return f;
}

// SERVER_REQUEST_FUZZ_VERBOSE=1: a line per response / message on stderr (to see what an input does).
const bool kVerbose = std::getenv("SERVER_REQUEST_FUZZ_VERBOSE") != nullptr;

// A /metrics body (or a registry's render()) must be valid Prometheus text.
void check_metrics_text(const std::string& text) {
    const auto parsed = test::parse_prometheus_text(text);
    if (!parsed.ok()) {
        std::fprintf(stderr, "server_request_fuzz: /metrics does not parse: %s\n", parsed.error.c_str());
        std::abort();
    }
}

// ---- HTTP --------------------------------------------------------------------------------------

// Percent-decoding without the handler's restrictions (it refuses more; a 200 means it decoded).
bool decode(std::string_view in, std::string& out) {
    out.clear();
    auto hex = [](char c) {
        if (c >= '0' && c <= '9') return c - '0';
        if (c >= 'a' && c <= 'f') return c - 'a' + 10;
        if (c >= 'A' && c <= 'F') return c - 'A' + 10;
        return -1;
    };
    for (std::size_t i = 0; i < in.size(); ++i) {
        if (in[i] != '%') {
            out += in[i];
            continue;
        }
        if (i + 2 >= in.size() || hex(in[i + 1]) < 0 || hex(in[i + 2]) < 0) return false;
        out += static_cast<char>(hex(in[i + 1]) * 16 + hex(in[i + 2]));
        i += 2;
    }
    return true;
}

// The decoded path segments of a target ("/v1/stores/a" -> v1, stores, a); nullopt if malformed.
std::optional<std::vector<std::string>> path_segments(std::string_view target) {
    std::string_view path = target.substr(0, target.find('?'));
    if (path.empty() || path.front() != '/') return std::nullopt;
    std::vector<std::string> seg;
    path.remove_prefix(1);
    while (true) {
        const std::size_t slash = path.find('/');
        std::string s;
        if (!decode(path.substr(0, slash), s)) return std::nullopt;
        seg.push_back(std::move(s));
        if (slash == std::string_view::npos) break;
        path.remove_prefix(slash + 1);
    }
    return seg;
}

// A canonical tile coordinate: digits, no leading zero, below 2^32.
std::optional<std::uint32_t> coordinate(const std::string& s) {
    if (s.empty() || s.size() > 10 || (s.size() > 1 && s[0] == '0')) return std::nullopt;
    std::uint64_t v = 0;
    for (char c : s) {
        if (c < '0' || c > '9') return std::nullopt;
        v = v * 10 + std::uint64_t(c - '0');
    }
    if (v > 0xffffffffull) return std::nullopt;
    return static_cast<std::uint32_t>(v);
}

struct TileTarget {
    const ExpectedStore* store = nullptr;
    TileKey key;
    const ExpectedTile* tile = nullptr;  // nullptr: outside the store
};

// What a tile URL the handler accepted names; FUZZ_CHECK fails if the handler accepted a URL
// that is not one canonical tile URL of a served store.
TileTarget accepted_tile_target(const Fixture& fx, std::string_view target) {
    const auto seg = path_segments(target);
    FUZZ_CHECK(seg.has_value());
    FUZZ_CHECK(seg->size() == 7 && (*seg)[0] == "v1" && (*seg)[1] == "stores" && (*seg)[3] == "tiles");
    TileTarget t;
    t.store = fx.store((*seg)[2]);
    FUZZ_CHECK(t.store != nullptr);
    const auto l = coordinate((*seg)[4]), x = coordinate((*seg)[5]), y = coordinate((*seg)[6]);
    FUZZ_CHECK(l && x && y);
    t.key = TileKey{*l, *x, *y};
    t.tile = t.store->find(t.key);
    FUZZ_CHECK(t.tile != nullptr);
    return t;
}

// "Bearer", any case, one or more spaces, the token, nothing else.
bool token_ok(std::string_view auth) {
    if (auth.size() < 7) return false;
    for (std::size_t i = 0; i < 6; ++i)
        if (std::tolower(static_cast<unsigned char>(auth[i])) != "bearer"[i]) return false;
    auth.remove_prefix(6);
    if (auth.front() != ' ') return false;
    while (!auth.empty() && auth.front() == ' ') auth.remove_prefix(1);
    return auth == kToken;
}

// An RFC 9110 token: what an HTTP/1.1 parser (Beast, in http_server.cpp) accepts as a method.
bool is_token(std::string_view s) {
    if (s.empty()) return false;
    for (char c : s) {
        const bool alnum = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9');
        if (!alnum && std::string_view("!#$%&'*+-.^_`|~").find(c) == std::string_view::npos) return false;
    }
    return true;
}

void fuzz_http(const Fixture& fx, std::uint8_t flags, std::string_view rest) {
    const bool auth_ctx = (flags & fuzz::flag::auth_context) != 0;
    Instance& in = *fx.inst[auth_ctx ? 1 : 0];
    std::string_view field[5];
    for (int i = 0; i < 5; ++i) {
        const std::size_t nl = i < 4 ? rest.find('\n') : std::string_view::npos;
        field[i] = rest.substr(0, nl);
        rest = nl == std::string_view::npos ? std::string_view() : rest.substr(nl + 1);
    }
    HttpRequestView req;
    req.method = field[0];
    req.target = field[1];
    req.authorization = (flags & fuzz::flag::valid_token) ? std::string_view("Bearer t0k") : field[2];
    req.if_none_match = field[3];
    req.accept = field[4];
    // A request whose method is not a token never reaches the handler: the transport's parser
    // refuses it (and the handler echoes the method in its 405 body, which as JSON under /v1/
    // cannot hold bytes that are not UTF-8).
    if (!is_token(req.method)) return;

    const HttpResponse res = in.http->handle_http_request(req);
    if (kVerbose)
        std::fprintf(stderr, "http ctx%d %.*s %.*s -> %u %s %zu bytes\n", auth_ctx ? 1 : 0, int(req.method.size()),
                     req.method.data(), int(req.target.size()), req.target.data(), res.status,
                     std::string(to_string(res.route)).c_str(), res.body.size());
    const std::string_view path = req.target.substr(0, req.target.find('?'));
    const bool get_or_head = req.method == "GET" || req.method == "HEAD";
    const bool options = req.method == "OPTIONS";  // a CORS preflight: 204, no auth
    const bool probe = path == "/healthz" || path == "/readyz";
    // A token may come in the query too (access_token=, for browsers); such requests are checked
    // for everything but which token they carry.
    const bool query_token = req.target.find("access_token") != std::string_view::npos;

    FUZZ_CHECK(res.status >= 200 && res.status <= 599);
    FUZZ_CHECK(res.header("Server") != nullptr);
    FUZZ_CHECK((res.status == 405) == !(get_or_head || options));
    if (options) FUZZ_CHECK(res.status == 204 && res.route == HttpRoute::preflight);
    if (res.status == 405) FUZZ_CHECK(res.header("Allow") != nullptr);
    // Single-threaded and ready: never "too many in flight", never "not ready".
    FUZZ_CHECK(res.status != 503);
    // Every store is 8-bit: PNG is always possible.
    FUZZ_CHECK(res.status != 406);

    // Auth: probes never need it; everything else does exactly when the context has a token.
    if (get_or_head && probe) FUZZ_CHECK(res.status == 200);
    const bool needs_token = auth_ctx && get_or_head && !probe;
    if (!query_token) FUZZ_CHECK((res.status == 401) == (needs_token && !token_ok(req.authorization)));
    else FUZZ_CHECK(res.status != 401 || needs_token);
    if (res.status == 401) FUZZ_CHECK(res.header("WWW-Authenticate") != nullptr);

    if (res.status >= 400) {
        FUZZ_CHECK(!res.body.empty() && res.body.back() == '\n');
        FUZZ_CHECK(!res.content_type.empty());
        if (res.content_type == "application/json") {
            const auto j = nlohmann::json::parse(res.body, nullptr, false);
            FUZZ_CHECK(!j.is_discarded() && j.is_object() && j.contains("error") && j["error"].is_string());
        }
    }
    if (res.status == 304) {
        FUZZ_CHECK(!req.if_none_match.empty());
        FUZZ_CHECK(res.body.empty() && res.content_type.empty());
        // Tiles, web images and pages, and the documents (store JSON, info.json, .dzi) revalidate.
        FUZZ_CHECK(res.route == HttpRoute::tile || res.route == HttpRoute::tile_png || res.route == HttpRoute::dzi_tile ||
                   res.route == HttpRoute::iiif_image || res.route == HttpRoute::xyz_tile || res.route == HttpRoute::viewer ||
                   res.route == HttpRoute::stores || res.route == HttpRoute::store || res.route == HttpRoute::dzi_info ||
                   res.route == HttpRoute::iiif_info);
    }
    if (res.route == HttpRoute::other) FUZZ_CHECK(res.status != 200 && res.status != 304);

    // Tiles: the answer agrees with the store.
    if ((res.route == HttpRoute::tile || res.route == HttpRoute::tile_png) && !query_token &&
        (res.status == 200 || res.status == 304 || res.status == 500)) {
        const TileTarget t = accepted_tile_target(fx, req.target);
        const bool png = res.route == HttpRoute::tile_png;
        const std::string version = hex16(t.store->version);
        FUZZ_CHECK(t.tile->kind != TileKind::absent);
        const std::string etag = "\"" + version + "-" + hex16(XXH3_64bits(t.tile->bytes.data(), t.tile->bytes.size())) +
                                 (png ? "-png" : "") + "\"";
        const auto* got_etag = res.header("ETag");
        const auto* got_version = res.header("X-Tessera-Store-Version");
        if (res.status == 500) {
            // The only tile that fails is the corrupted one (DATA_LOSS is a 500).
            FUZZ_CHECK(t.tile->corrupt);
        } else if (res.status == 304) {
            // Revalidation is answered from the index: the corrupted tile's ETag still matches.
            FUZZ_CHECK(got_etag && *got_etag == etag);
            FUZZ_CHECK(req.if_none_match.find('*') != std::string_view::npos ||
                       req.if_none_match.find(etag.substr(1, etag.size() - 2)) != std::string_view::npos);
            FUZZ_CHECK(got_version && *got_version == version);
        } else {
            FUZZ_CHECK(!t.tile->corrupt);
            FUZZ_CHECK(got_etag && *got_etag == etag);
            FUZZ_CHECK(got_version && *got_version == version);
            const auto* kind = res.header("X-Tessera-Kind");
            FUZZ_CHECK(kind && *kind == tessera::to_string(t.tile->kind));
            if (png) {
                FUZZ_CHECK(res.content_type == "image/png");
                FUZZ_CHECK(res.body.size() > 8 && std::memcmp(res.body.data(), "\x89PNG\r\n\x1a\n", 8) == 0);
            } else {
                FUZZ_CHECK(res.body.size() == t.tile->bytes.size() &&
                           std::memcmp(res.body.data(), t.tile->bytes.data(), res.body.size()) == 0);
                const auto* sum = res.header("X-Tessera-Checksum");
                FUZZ_CHECK(sum && *sum == hex16(XXH3_64bits(res.body.data(), res.body.size())));
            }
        }
    } else if (res.route == HttpRoute::dzi_tile || res.route == HttpRoute::iiif_image || res.route == HttpRoute::xyz_tile) {
        // A web image made from the corrupt tile fails as the tile does; nothing else fails.
        FUZZ_CHECK(res.status != 500 || res.body.find("checksum") != std::string::npos);
    } else {
        FUZZ_CHECK(res.status != 500);  // nothing else fails internally
    }
    if (const auto* kind = res.header("X-Tessera-Kind"); kind && *kind == "absent") {
        FUZZ_CHECK(res.status == 404);
        const TileTarget t = accepted_tile_target(fx, req.target);
        FUZZ_CHECK(t.tile->kind == TileKind::absent);
    }

    // Store metadata: only for a served store, by its exact name (never a path: "/", "..").
    if (res.route == HttpRoute::store && res.status == 200) {
        const auto seg = path_segments(req.target);
        FUZZ_CHECK(seg && seg->size() == 3 && (*seg)[0] == "v1" && (*seg)[1] == "stores");
        const std::string& name = (*seg)[2];
        FUZZ_CHECK(name.find('/') == std::string::npos && name.find("..") == std::string::npos);
        const ExpectedStore* s = fx.store(name);
        FUZZ_CHECK(s != nullptr);
        const auto j = nlohmann::json::parse(res.body, nullptr, false);
        FUZZ_CHECK(!j.is_discarded() && j.value("name", "") == name && j.value("version", "") == hex16(s->version));
    }
    if (res.route == HttpRoute::stores && res.status == 200) {
        const auto j = nlohmann::json::parse(res.body, nullptr, false);
        FUZZ_CHECK(!j.is_discarded() && j.contains("stores") && j["stores"].is_array() && j["stores"].size() == 2);
    }
    if (res.route == HttpRoute::healthz && res.status == 200) FUZZ_CHECK(res.body == "ok\n");
    if (res.route == HttpRoute::readyz && res.status == 200) FUZZ_CHECK(res.body == "ready\n");
    if (res.route == HttpRoute::metrics && res.status == 200) {
        static unsigned n = 0;
        if (n++ % kMetricsParseEvery == 0) check_metrics_text(res.body);
    }
}

// ---- batches -----------------------------------------------------------------------------------

// A valid tile of one of the stores: store index in fx.expected, and the packed key.
using FullKey = std::uint64_t;
FullKey full_key(std::size_t store, const TileKey& k) { return (std::uint64_t(store) << 60) | ExpectedStore::pack(k); }

struct ExpectedError {
    v1::TileStatus status;
    std::string store;  // the key the error reply names
    std::uint32_t level, x, y;
};

struct SentBatch {
    v1::TileBatch batch;
    std::size_t viewer = 0;
    std::size_t prefix = 0;        // messages the viewer had read when this was submitted
    bool too_large = false;        // refused whole: more requests than max_batch
    bool bad_store_list = false;   // refused whole: too many stores, or a name no store can have
    std::uint32_t valid = 0;       // requests that pass validation (admitted, refused or already queued)
    std::vector<ExpectedError> invalid;  // error replies, in request order
    std::set<FullKey> valid_keys;
    std::map<FullKey, std::pair<float, std::size_t>> first;  // priority and index of a key's first request
    // Filled in from the stream:
    bool acked_ok = false;
    std::set<FullKey> wanted;  // valid_keys minus the refused ones
};

struct Got {
    bool ack = false;
    bool is_tile = false;  // a read tile (OutMessage::is_tile), not an error reply
    v1::ServerMessage msg;  // payload cleared (checked on arrival)
};

struct ViewerState {
    Scheduler::ViewerId id = 0;
    std::vector<Got> got;
    std::vector<std::size_t> batches;  // indices into the input's SentBatch list, in submit order
};

std::size_t store_index(const Fixture& fx, const std::string& name) {
    for (std::size_t i = 0; i < fx.expected.size(); ++i)
        if (fx.expected[i].name == name) return i;
    return SIZE_MAX;
}

// Builds a batch from raw records (bytes that do not parse as a TileBatch).
v1::TileBatch raw_batch(std::string_view bytes) {
    v1::TileBatch b;
    for (const char* s : fuzz::kRawStores) b.add_stores(s);
    auto u16 = [](const char* p) {
        return static_cast<std::uint16_t>(static_cast<std::uint8_t>(p[0]) | (static_cast<std::uint8_t>(p[1]) << 8));
    };
    for (std::size_t off = 0; off + fuzz::kRawRecordBytes <= bytes.size(); off += fuzz::kRawRecordBytes) {
        const char* p = bytes.data() + off;
        auto* r = b.add_requests();
        r->set_store(static_cast<std::uint8_t>(p[0]) % 5);
        const auto level = static_cast<std::uint8_t>(p[1]);
        r->set_level(level < 0xf0 ? level % 5 : level);
        const std::uint16_t x = u16(p + 2), y = u16(p + 4);
        r->set_x(x < 0xf000 ? x % 7 : x);
        r->set_y(y < 0xf000 ? y % 5 : y);
        float priority;
        std::memcpy(&priority, p + 6, 4);
        r->set_priority(priority);
    }
    return b;
}

// What the scheduler must make of a batch: which requests are invalid, and how.
void classify(const Fixture& fx, const ServerConfig& config, SentBatch& s) {
    const v1::TileBatch& b = s.batch;
    s.too_large = static_cast<std::size_t>(b.requests_size()) > config.max_batch;
    s.bad_store_list = static_cast<std::size_t>(b.stores_size()) > Scheduler::kMaxBatchStores ||
                       std::any_of(b.stores().begin(), b.stores().end(),
                                   [](const std::string& n) { return n.size() > protocol::kMaxStoreNameLength; });
    for (const auto& name : b.stores()) {
        // A name that could be a path is never a valid store name.
        if (name.find('/') != std::string::npos || name.find("..") != std::string::npos || name.empty())
            FUZZ_CHECK(!protocol::valid_store_name(name));
    }
    for (const auto& r : b.requests()) {
        auto invalid = [&](v1::TileStatus st, std::string store) {
            s.invalid.push_back(ExpectedError{st, std::move(store), r.level(), r.x(), r.y()});
        };
        if (r.store() >= static_cast<std::uint32_t>(b.stores_size())) {
            invalid(v1::TILE_INVALID_ARGUMENT, "");
            continue;
        }
        const std::string& name = b.stores(static_cast<int>(r.store()));
        const std::size_t si = store_index(fx, name);
        if (si == SIZE_MAX) {
            invalid(protocol::valid_store_name(name) ? v1::TILE_NOT_FOUND : v1::TILE_INVALID_ARGUMENT, name);
            continue;
        }
        if (!std::isfinite(r.priority())) {
            invalid(v1::TILE_INVALID_ARGUMENT, name);
            continue;
        }
        const TileKey key{r.level(), r.x(), r.y()};
        if (!fx.expected[si].info.contains(key)) {
            invalid(v1::TILE_OUT_OF_RANGE, name);
            continue;
        }
        ++s.valid;
        s.valid_keys.insert(full_key(si, key));
        s.first.emplace(full_key(si, key), std::make_pair(r.priority(), s.first.size()));
    }
}

// Checks one message as it arrives and records it (without its payload).
void receive(const Fixture& fx, ViewerState& v, const OutMessage& m) {
    const v1::ServerMessage msg = m.to_proto();  // read tiles carry their payload by reference
    if (kVerbose) {
        if (msg.has_ack()) {
            const auto& a = msg.ack();
            std::fprintf(stderr, "viewer %llu: ack frame %llu status %d admitted %u refused %u invalid %u already %u cancelled %u\n",
                         static_cast<unsigned long long>(v.id), static_cast<unsigned long long>(a.frame()), a.status(),
                         a.admitted(), a.refused(), a.invalid(), a.already_queued(), a.cancelled());
        } else {
            const auto& t = msg.tile();
            std::fprintf(stderr, "viewer %llu: %s %s/%u/%u/%u frame %llu status %d kind %d %zu bytes\n",
                         static_cast<unsigned long long>(v.id), m.is_tile ? "tile" : "error", t.key().store().c_str(),
                         t.key().level(), t.key().x(), t.key().y(), static_cast<unsigned long long>(t.frame()),
                         t.status(), t.kind(), t.payload().size());
        }
    }
    Got g;
    g.is_tile = m.is_tile;
    g.ack = msg.has_ack();
    FUZZ_CHECK(msg.has_ack() != msg.has_tile());
    FUZZ_CHECK(m.bytes >= 64);
    if (msg.has_tile()) {
        const v1::TileReply& t = msg.tile();
        FUZZ_CHECK(t.has_key());
        if (t.status() == v1::TILE_OK) {
            FUZZ_CHECK(m.is_tile);  // errors found in submit() are never OK
            const std::size_t si = store_index(fx, t.key().store());
            FUZZ_CHECK(si != SIZE_MAX);
            const ExpectedStore& st = fx.expected[si];
            FUZZ_CHECK(t.store_version() == st.version);
            const ExpectedTile* e = st.find(TileKey{t.key().level(), t.key().x(), t.key().y()});
            FUZZ_CHECK(e != nullptr);
            FUZZ_CHECK(!e->corrupt);  // never served
            FUZZ_CHECK(t.kind() == protocol::to_proto(e->kind));
            if (e->kind == TileKind::absent) {
                FUZZ_CHECK(t.codec() == v1::CODEC_NONE && t.payload().empty());
            } else {
                FUZZ_CHECK(t.codec() == (e->kind == TileKind::uniform ? v1::CODEC_UNIFORM : protocol::to_proto(st.info.codec)));
                FUZZ_CHECK(t.payload().size() == e->bytes.size() &&
                           std::memcmp(t.payload().data(), e->bytes.data(), e->bytes.size()) == 0);
                FUZZ_CHECK(t.checksum() == XXH3_64bits(t.payload().data(), t.payload().size()));
            }
            FUZZ_CHECK(t.message().empty());
        } else {
            FUZZ_CHECK(!t.message().empty());
            FUZZ_CHECK(t.payload().empty() && t.codec() == v1::CODEC_NONE);
        }
        if (m.is_tile) {
            // A read tile: OK, DATA_LOSS (the corrupted tile, and only it) or a missed deadline.
            const std::size_t si = store_index(fx, t.key().store());
            FUZZ_CHECK(si != SIZE_MAX);
            const ExpectedTile* e = fx.expected[si].find(TileKey{t.key().level(), t.key().x(), t.key().y()});
            FUZZ_CHECK(e != nullptr);
            FUZZ_CHECK(t.store_version() == fx.expected[si].version);
            if (t.status() == v1::TILE_DATA_LOSS) FUZZ_CHECK(e->corrupt);
            else FUZZ_CHECK(t.status() == v1::TILE_OK || t.status() == v1::TILE_DEADLINE_EXCEEDED);
            FUZZ_CHECK(m.store != nullptr && m.store->name == t.key().store());
        }
    }
    g.msg = msg;
    if (g.msg.has_tile()) g.msg.mutable_tile()->clear_payload();
    v.got.push_back(std::move(g));
}

// Reads up to `limit` messages that are ready now.
void read_ready(const Fixture& fx, Scheduler& sched, ViewerState& v, std::size_t limit) {
    OutMessage m;
    for (std::size_t n = 0; n < limit && sched.next_message(v.id, m); ++n) {
        receive(fx, v, m);
        sched.message_written(v.id, m, true);
    }
}

// Walks one viewer's stream against the batches it sent.
// expired_dropped: the scheduler dropped expired requests of a stalled viewer unanswered in this
// run (docs/protocol.md: the one exception to a reply per admitted request).
void check_stream(const Fixture& fx, std::vector<SentBatch>& sent, ViewerState& v, bool expired_dropped) {
    std::size_t next_ack = 0;
    const SentBatch* current = nullptr;  // the batch whose wanted set is in force
    // Per frame, the last reply's (priority, index in the batch): with one I/O thread a batch's
    // requests are served strictly in order, highest priority first, ties in batch order.
    std::map<std::uint64_t, std::pair<float, std::size_t>> last_served;
    for (std::size_t i = 0; i < v.got.size(); ++i) {
        const Got& g = v.got[i];
        if (g.ack) {
            FUZZ_CHECK(next_ack < v.batches.size());
            SentBatch& b = sent[v.batches[next_ack++]];
            const v1::BatchAck& a = g.msg.ack();
            FUZZ_CHECK(a.frame() == b.batch.frame());
            if (b.too_large || b.bad_store_list) {
                // Refused whole (the store list is checked first); the earlier batch's requests
                // stay in force.
                FUZZ_CHECK(a.status() == (b.bad_store_list ? v1::TILE_INVALID_ARGUMENT : v1::TILE_RESOURCE_EXHAUSTED));
                FUZZ_CHECK(!a.message().empty() && a.message().size() < 512);
                FUZZ_CHECK(a.admitted() == 0 && a.refused() == 0 && a.invalid() == 0 && a.already_queued() == 0);
                continue;
            }
            FUZZ_CHECK(a.status() == v1::TILE_OK);
            FUZZ_CHECK(std::uint64_t(a.admitted()) + a.refused() + a.invalid() + a.already_queued() ==
                       std::uint64_t(b.batch.requests_size()));
            FUZZ_CHECK(a.invalid() == b.invalid.size());
            FUZZ_CHECK(std::uint64_t(a.admitted()) + a.refused() + a.already_queued() == b.valid);
            FUZZ_CHECK(a.admitted() + a.refused() <= b.valid_keys.size());
            // The error replies follow the ack at once: the invalid requests in order, then the refused ones.
            b.wanted = b.valid_keys;
            for (std::uint32_t k = 0; k < a.invalid() + a.refused(); ++k) {
                FUZZ_CHECK(i + 1 < v.got.size());
                const Got& e = v.got[++i];
                FUZZ_CHECK(!e.ack && !e.is_tile);
                const v1::TileReply& t = e.msg.tile();
                FUZZ_CHECK(t.frame() == b.batch.frame());
                FUZZ_CHECK(t.kind() == v1::KIND_ABSENT && t.codec() == v1::CODEC_NONE);
                if (k < a.invalid()) {
                    const ExpectedError& x = b.invalid[k];
                    FUZZ_CHECK(t.status() == x.status);
                    FUZZ_CHECK(t.key().store() == x.store && t.key().level() == x.level && t.key().x() == x.x &&
                               t.key().y() == x.y);
                } else {
                    FUZZ_CHECK(t.status() == v1::TILE_RESOURCE_EXHAUSTED);
                    const std::size_t si = store_index(fx, t.key().store());
                    FUZZ_CHECK(si != SIZE_MAX);
                    const FullKey fk = full_key(si, TileKey{t.key().level(), t.key().x(), t.key().y()});
                    FUZZ_CHECK(b.valid_keys.contains(fk));
                    FUZZ_CHECK(b.wanted.erase(fk) == 1);  // each refused key once
                }
            }
            b.acked_ok = true;
            current = &b;
            continue;
        }
        // A tile reply after the acks that were in force: only for keys the latest batch still
        // wants (superseded keys are cancelled before they are sent), and from a batch acked before it.
        FUZZ_CHECK(g.is_tile);
        const v1::TileReply& t = g.msg.tile();
        const std::size_t si = store_index(fx, t.key().store());
        FUZZ_CHECK(si != SIZE_MAX);
        const FullKey fk = full_key(si, TileKey{t.key().level(), t.key().x(), t.key().y()});
        FUZZ_CHECK(current != nullptr);
        FUZZ_CHECK(current->wanted.contains(fk));
        const SentBatch* asked = nullptr;
        for (std::size_t j = 0; j < next_ack && !asked; ++j) {
            const SentBatch& b = sent[v.batches[j]];
            if (b.acked_ok && b.batch.frame() == t.frame() && b.wanted.contains(fk)) asked = &b;
        }
        FUZZ_CHECK(asked != nullptr);
        const auto order = asked->first.at(fk);
        if (const auto prev = last_served.find(t.frame()); prev != last_served.end())
            FUZZ_CHECK(order.first < prev->second.first ||
                       (order.first == prev->second.first && order.second > prev->second.second));
        last_served[t.frame()] = order;
    }
    FUZZ_CHECK(next_ack == v.batches.size());  // one ack per batch

    // The last batch in force: every key it wants is answered exactly once after it was sent,
    // and nothing else is; except that a tile sent OK while every batch since listed it is not
    // sent again (re-listed tiles, docs/protocol.md): then no reply after the last batch.
    if (current) {
        std::map<FullKey, unsigned> replies;
        for (std::size_t i = current->prefix; i < v.got.size(); ++i) {
            const Got& g = v.got[i];
            if (!g.is_tile) continue;
            const v1::TileReply& t = g.msg.tile();
            ++replies[full_key(store_index(fx, t.key().store()), TileKey{t.key().level(), t.key().x(), t.key().y()})];
        }
        for (const auto& [fk, n] : replies) FUZZ_CHECK(n == 1 && current->wanted.contains(fk));
        std::size_t pos = 0;  // current's place among this viewer's batches
        while (&sent[v.batches[pos]] != current) ++pos;
        for (const FullKey& fk : current->wanted) {
            if (replies.contains(fk)) continue;
            // Where the run of batches listing fk began (batches refused whole change nothing).
            std::size_t start = pos;
            for (std::size_t j = pos; j-- > 0;) {
                const SentBatch& b = sent[v.batches[j]];
                if (b.too_large || b.bad_store_list) continue;
                if (!b.wanted.contains(fk)) break;
                start = j;
            }
            unsigned ok = 0;
            v1::TileStatus last = v1::TILE_INTERNAL;
            for (std::size_t i = sent[v.batches[start]].prefix; i < current->prefix; ++i) {
                const Got& g = v.got[i];
                if (!g.is_tile) continue;
                const v1::TileReply& t = g.msg.tile();
                if (full_key(store_index(fx, t.key().store()), TileKey{t.key().level(), t.key().x(), t.key().y()}) != fk)
                    continue;
                last = t.status();
                if (last == v1::TILE_OK) ++ok;
            }
            if (expired_dropped && ok == 0 && last == v1::TILE_INTERNAL) continue;  // never answered: dropped
            FUZZ_CHECK(ok == 1 && last == v1::TILE_OK);
        }
    }
}

void fuzz_batches(const Fixture& fx, std::uint8_t flags, std::string_view rest) {
    const bool auth_ctx = (flags & fuzz::flag::auth_context) != 0;
    Instance& in = *fx.inst[auth_ctx ? 1 : 0];
    Scheduler& sched = *in.scheduler;
    const unsigned nbatches = 1 + ((flags >> fuzz::flag::batches_shift) & 3u) % 3;
    const std::size_t nviewers = (flags & fuzz::flag::two_viewers) ? 2 : 1;
    static constexpr std::size_t kReads[] = {0, 1, 2, 4, 8, 16, 64, SIZE_MAX};
    const std::size_t reads_between = kReads[(flags >> fuzz::flag::reads_shift) & 7u];

    // Split and decode the batches.
    std::vector<SentBatch> sent;
    for (unsigned i = 0; i < nbatches; ++i) {
        std::string_view part = rest;
        if (i + 1 < nbatches) {
            std::size_t n = 0;
            if (rest.size() >= 2) {
                n = static_cast<std::uint8_t>(rest[0]) | (std::size_t(static_cast<std::uint8_t>(rest[1])) << 8);
                rest.remove_prefix(2);
            } else {
                rest = {};
            }
            n = std::min(n, rest.size());
            part = rest.substr(0, n);
            rest.remove_prefix(n);
        }
        SentBatch s;
        if (!s.batch.ParseFromArray(part.data(), static_cast<int>(part.size()))) s.batch = raw_batch(part);
        // Frames name the batch (the checks match replies to batches by frame).
        s.batch.set_frame((s.batch.frame() & ~std::uint64_t(3)) | i);
        s.viewer = i % nviewers;
        // Re-listed tiles: every batch made before anything arrived (a sent tile is on the wire),
        // and one revision per input (revision 0 viewers get no re-send suppression).
        s.batch.set_replies_received(0);
        if (i > 0) s.batch.set_protocol_revision(sent[0].batch.protocol_revision());
        classify(fx, in.config, s);
        sent.push_back(std::move(s));
    }

    struct NullSink : ViewerSink {
        void on_outbox_ready() override {}
    };
    const std::uint64_t cancelled_before = sched.stats().cancelled;
    const std::uint64_t dropped_before = sched.stats().expired_dropped;
    std::vector<ViewerState> viewers(nviewers);
    for (auto& v : viewers) {
        const auto id = sched.add_viewer(std::make_shared<NullSink>());
        FUZZ_CHECK(id.has_value());
        v.id = *id;
    }
    for (std::size_t i = 0; i < sent.size(); ++i) {
        ViewerState& v = viewers[sent[i].viewer];
        sent[i].prefix = v.got.size();
        v.batches.push_back(i);
        sched.submit(v.id, sent[i].batch);
        if (i + 1 < sent.size())
            for (auto& w : viewers) read_ready(fx, sched, w, reads_between);
    }

    // Drain: read everything until no viewer has anything pending, being read or to be written.
    const auto give_up = std::chrono::steady_clock::now() + kDrainLimit;
    for (unsigned spins = 0;; ++spins) {
        std::size_t before = 0, after = 0;
        for (auto& v : viewers) before += v.got.size();
        for (auto& v : viewers) read_ready(fx, sched, v, SIZE_MAX);
        for (auto& v : viewers) after += v.got.size();
        if (after != before) continue;
        bool idle = true;
        for (auto& v : viewers) idle = idle && sched.viewer_idle(v.id);
        if (idle) break;
        if (std::chrono::steady_clock::now() > give_up) {
            const SchedulerStats st = sched.stats();
            std::fprintf(stderr, "server_request_fuzz: the scheduler did not drain in %lld s (pending %llu, in flight %llu, outbox %llu bytes)\n",
                         static_cast<long long>(kDrainLimit.count()), static_cast<unsigned long long>(st.pending),
                         static_cast<unsigned long long>(st.in_flight), static_cast<unsigned long long>(st.outbox_bytes));
            FUZZ_CHECK(!"drained in time");
        }
        if (spins < 64) std::this_thread::yield();
        else std::this_thread::sleep_for(std::chrono::microseconds(50));
    }
    {
        const SchedulerStats st = sched.stats();
        FUZZ_CHECK(st.pending == 0);
        FUZZ_CHECK(st.in_flight == 0);
        FUZZ_CHECK(st.outbox_bytes == 0);
        FUZZ_CHECK(st.viewers == nviewers);
    }
    const bool expired_dropped = sched.stats().expired_dropped > dropped_before;
    for (auto& v : viewers) check_stream(fx, sent, v, expired_dropped);
    if (kVerbose) {
        std::uint64_t acked = 0;
        for (const auto& v : viewers)
            for (const Got& g : v.got)
                if (g.ack) acked += g.msg.ack().cancelled();
        std::fprintf(stderr, "cancelled: %llu in acks, %llu dropped after the read\n", static_cast<unsigned long long>(acked),
                     static_cast<unsigned long long>(sched.stats().cancelled - cancelled_before - acked));
    }
    for (auto& v : viewers) sched.remove_viewer(v.id);
    const SchedulerStats st = sched.stats();
    FUZZ_CHECK(st.viewers == 0 && st.pending == 0 && st.in_flight == 0 && st.outbox_bytes == 0);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const Fixture& fx = fixture();
    if (size == 0) return 0;
    const std::uint8_t flags = data[0];
    const std::string_view rest(reinterpret_cast<const char*>(data) + 1, size - 1);
    if (flags & fuzz::flag::batch_mode) fuzz_batches(fx, flags, rest);
    else fuzz_http(fx, flags, rest);

    // Now and then: both metrics registries render valid Prometheus text (the gauges read the
    // schedulers, caches and registries).
    static unsigned inputs = 0;
    if (++inputs % 4096 == 1)
        for (const auto& in : fx.inst) check_metrics_text(in->metrics.render());
    return 0;
}
