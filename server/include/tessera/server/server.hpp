#pragma once
// The Tessera tile server: hosts .tsr stores and serves them to viewers over gRPC (streaming,
// prioritized, fair, cancellable) and to everything else over HTTP. See docs/server.md.
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "tessera/result.hpp"

namespace tessera::server {

// The most threads of one kind (io_threads, http_threads, work_threads, render_concurrency): far
// above what helps, well below what exhausts a machine's threads or address space.
inline constexpr unsigned kMaxThreads = 1024;
// The most any count limit (--max-viewers, --max-batch, --max-pending, --max-connections,
// --max-http-inflight) may be: beyond it a limit is no limit.
inline constexpr std::size_t kMaxLimit = std::size_t(1) << 20;

struct ServerConfig {
    // Stores: single files, and directories whose *.tsr files are all served. A store is named by
    // its file name without ".tsr"; files whose names are not identifiers are skipped (logged).
    // A store file may be remote: s3://BUCKET/KEY.tsr or http(s)://HOST/PATH.tsr
    // (tessera/storage/remote_source.hpp; its ETag is its version, checked at every rescan).
    std::vector<std::string> store_files;
    std::string remote_ca_file;          // PEM roots for https:// stores ("": the system's)
    unsigned remote_concurrency = 8;     // range requests in flight per remote store
    std::vector<std::string> store_dirs;
    // Rescan the directories and files this often (0: only on SIGHUP / reload()).
    std::chrono::milliseconds watch_interval{2000};

    std::string grpc_address = "127.0.0.1:50051";  // HOST:PORT; port 0 picks one; empty: no gRPC
    std::string http_address = "127.0.0.1:8080";   // HOST:PORT; port 0 picks one; empty: no HTTP

    std::string tls_cert_file;  // PEM; with tls_key_file, both gRPC and HTTP are TLS only
    std::string tls_key_file;
    std::string auth_token;     // non-empty: every request needs "authorization: Bearer <token>"
                                // (HTTP /healthz and /readyz excepted)

    std::size_t cache_bytes = std::size_t(256) << 20;  // RAM tile cache; 0 disables it
    unsigned io_threads = 0;    // tile readers; 0: hardware threads; at most kMaxThreads
    unsigned http_threads = 0;  // HTTP event loops; 0: hardware threads; at most kMaxThreads
    // The time slice the HTTP event loops ask of the kernel's fair scheduler, so that a loop
    // woken by a request preempts longer-running work instead of waiting for its slice to end
    // (docs/server.md, "Short slices"; Linux 6.12+, ignored elsewhere). 0: the kernel's default.
    std::chrono::microseconds http_loop_slice{100};

    // Bounds. Beyond them new work is refused (RESOURCE_EXHAUSTED / 503); admitted work goes on.
    std::size_t max_viewers = 256;          // concurrent StreamTiles calls (each limit: 1..kMaxLimit)
    std::size_t max_batch = 16384;          // requests in one TileBatch
    std::size_t max_pending = 1u << 20;     // admitted, unread requests over all viewers
    std::size_t max_message_bytes = 4u << 20;   // largest gRPC message accepted
    std::size_t max_connections = 1024;     // concurrent HTTP connections
    std::size_t max_header_bytes = 8192;    // HTTP request line + headers
    std::size_t max_http_inflight = 4096;   // HTTP tile requests being served at once
    std::size_t viewer_buffer_bytes = std::size_t(4) << 20;  // replies read but not yet sent, per viewer
    std::size_t total_buffer_bytes = std::size_t(512) << 20; // the same over all viewers

    // HTTP isolation (docs/server.md, "Isolation"): the event loops only parse, route and write;
    // tile reads that miss the RAM cache and web renders run on `work_threads` workers. Each
    // store has its own lane (`store_inflight` running, `store_queue` waiting: beyond, 503), reads
    // go before renders, and renders are admitted against `render_concurrency` (0: hardware
    // threads), `render_queue` and `render_memory` (their estimated peak bytes): beyond, 503.
    unsigned work_threads = 32;
    std::size_t store_inflight = 8;
    std::size_t store_queue = 64;
    unsigned render_concurrency = 0;
    std::size_t render_queue = 64;
    std::size_t render_memory_bytes = std::size_t(160) << 20;

    // Default deadline of a request: a gRPC tile request (a batch may set its own) and every
    // HTTP request whose answer needs work off the loop (504 when it passes).
    std::chrono::milliseconds request_timeout{5000};
    // A tile sent to a viewer and listed by every batch since is not sent again for this long
    // (it is still on its way); see docs/protocol.md, "Re-listed tiles".
    std::chrono::milliseconds resend_after{2000};
    // A viewer's batch that arrives while its pending set is large is held, not applied at once:
    // a newer batch replaces it unread, and it is applied when the pending set has shrunk or this
    // long after the viewer's last applied batch (docs/protocol.md, "Held batches"). 0: every
    // batch is applied as it arrives.
    std::chrono::milliseconds batch_hold{100};
    // Replies coalesced into one message (revision 1). 64 KiB, not more: with 256 KiB messages
    // about 1% of tiles reached a gRPC 1.51 client one viewer frame late (docs/benchmarks.md).
    std::size_t grpc_message_bytes = 64u << 10;
    std::chrono::milliseconds idle_timeout{60000};    // HTTP keep-alive idle limit
    std::chrono::milliseconds drain_timeout{10000};   // SIGTERM: longest wait for in-flight work
    unsigned http_max_age = 60;  // Cache-Control max-age for tiles (versioned URLs: a year)
    // Browsers (docs/server.md, "Browsers"): the origins whose pages may read responses ("*":
    // any; one origin; "": no CORS headers), the URL clients reach this server at (IIIF ids;
    // "": the request's Host), and the RAM kept for encoded DZI/IIIF/XYZ images (0: none).
    std::string cors_origin = "*";
    std::string public_url;
    std::size_t web_cache_bytes = std::size_t(64) << 20;
    // RAM for stored tiles decoded for web images (a web tile cut from one is then an encode,
    // not a decode and an encode); 0: off.
    std::size_t web_decoded_bytes = std::size_t(128) << 20;

    bool log_json = true;
    bool log_debug = false;
    bool log_quiet = false;  // warnings and errors only (an embedded server, e.g. `tessera demo`)
};

class Server {
public:
    // Opens the stores, binds the ports and starts serving. Errors: invalid_argument (bad
    // config), io_error (cannot bind, unreadable TLS files), not_found (a --store file missing).
    static Result<std::unique_ptr<Server>> start(const ServerConfig& config);
    virtual ~Server() = default;

    virtual std::uint16_t grpc_port() const = 0;  // 0 when gRPC is off
    virtual std::uint16_t http_port() const = 0;  // 0 when HTTP is off

    // Rescans the store files and directories now (what SIGHUP does).
    virtual void reload() = 0;
    // Rereads --tls-cert and --tls-key (what SIGHUP does): HTTP connections accepted from now on
    // use them; gRPC watches the files itself and switches within a few seconds. Connections
    // already open keep their certificate. On an error the old certificate stays (logged).
    virtual Status reload_tls() = 0;
    // Replaces the bearer token requests need from now on ("": none); streams already open stay.
    virtual void set_auth_token(const std::string& token) = 0;
    // Writes an error event to the server's log, in its format (a reload the caller could not
    // do: a token file that became unreadable).
    virtual void log_error(std::string_view event, std::string_view error) = 0;
    // Writes a warning event with one field `key` = `value` (a config file that changed but is
    // not reread).
    virtual void log_warning(std::string_view event, std::string_view key, std::string_view value) = 0;
    // Graceful stop: refuse new work, finish what was admitted (up to drain_timeout), close.
    virtual void shutdown() = 0;
};

}  // namespace tessera::server
