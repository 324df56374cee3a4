// tessera serve: host .tsr stores over gRPC (viewers) and HTTP (everything else).
#include <signal.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>
#include <sstream>
#include <thread>

#include "cli_options.hpp"
#include "commands.hpp"
#include "config_file.hpp"
#include "service_notify.hpp"
#include "tessera/server/server.hpp"

namespace tessera::tools {

namespace {

// How long past --drain-timeout a stop may take before the process exits regardless.
constexpr std::chrono::milliseconds kStopGrace{1500};

struct ServeArgs {
    server::ServerConfig config;
    std::string auth_token_file;
    std::string config_file;  // --config, reread on SIGHUP only to say what a restart would change
    ConfigFile config_at_start;
    std::vector<std::string> config_keys_overridden;  // options given on the command line, which wins
    std::vector<std::string> config_keys;             // every long option name of serve
    std::string log_format = "json";
    std::string log_level = "info";
    long long watch_ms = 2000, timeout_ms = 5000, batch_hold_ms = 100, drain_ms = 10000, idle_ms = 60000, slice_us = 100;
    std::size_t cache_bytes = std::size_t(256) << 20;
    std::size_t viewer_buffer = std::size_t(4) << 20, total_buffer = std::size_t(512) << 20;
    std::size_t max_message = std::size_t(4) << 20;
};

std::string read_token(const std::string& path) {
    std::ifstream in(path);
    if (!in) throw Failure("cannot read the auth token file " + path);
    std::stringstream ss;
    ss << in.rdbuf();
    std::string t = ss.str();
    while (!t.empty() && (t.back() == '\n' || t.back() == '\r' || t.back() == ' ' || t.back() == '\t')) t.pop_back();
    std::size_t start = t.find_first_not_of(" \t\r\n");
    t = start == std::string::npos ? std::string() : t.substr(start);
    if (t.empty()) throw Failure("the auth token file " + path + " is empty");
    for (char ch : t)
        if (ch <= ' ' || ch > '~') throw Failure("the auth token in " + path + " must be printable ASCII without spaces");
    return t;
}

// A reload does not reapply --config (its options size the threads, ports and buffers the server
// started with). When the file changed since the start, the log says so and names the keys, so
// a reload is not taken for an applied change.
void warn_if_config_changed(const ServeArgs& a, server::Server& srv) {
    ConfigFile now;
    try {
        now = read_config_file(a.config_file);
    } catch (const ConfigFileError& e) {
        srv.log_error("config file unreadable at reload; the server goes on as started", e.what());
        return;
    }
    // A key no option has would stop the restart (exit 2): said now, with its line.
    for (const ConfigEntry& e : now.entries) {
        if (e.key == "config" || e.key == "help" ||
            std::find(a.config_keys.begin(), a.config_keys.end(), e.key) == a.config_keys.end()) {
            srv.log_error("config file changed and a restart would refuse it; the server goes on as started",
                          now.where(e) + ": unknown option '" + e.key + "'");
            return;
        }
    }
    std::string keys;
    for (const std::string& key : changed_keys(a.config_at_start, now)) {
        if (std::find(a.config_keys_overridden.begin(), a.config_keys_overridden.end(), key) !=
            a.config_keys_overridden.end())
            continue;
        keys += (keys.empty() ? "" : ",") + key;
    }
    if (!keys.empty())
        srv.log_warning("config file changed; a reload does not reread it, restart to apply", "keys", keys);
}

int run_serve(ServeArgs& a) {
    auto& c = a.config;
    c.watch_interval = std::chrono::milliseconds(a.watch_ms);
    c.request_timeout = std::chrono::milliseconds(a.timeout_ms);
    c.batch_hold = std::chrono::milliseconds(a.batch_hold_ms);
    c.drain_timeout = std::chrono::milliseconds(a.drain_ms);
    c.idle_timeout = std::chrono::milliseconds(a.idle_ms);
    if (a.slice_us != 0 && a.slice_us < 100) throw Failure("--http-loop-slice-us must be 0 or 100..100000 (the kernel's bounds)");
    c.http_loop_slice = std::chrono::microseconds(a.slice_us);
    c.cache_bytes = a.cache_bytes;
    c.viewer_buffer_bytes = a.viewer_buffer;
    c.total_buffer_bytes = a.total_buffer;
    c.max_message_bytes = a.max_message;
    c.log_json = a.log_format == "json";
    c.log_debug = a.log_level == "debug";
    if (!a.auth_token_file.empty()) c.auth_token = read_token(a.auth_token_file);

    // Signals are taken by this thread with sigwait; every thread the server starts inherits
    // the mask, so none of them is interrupted.
    sigset_t signals;
    sigemptyset(&signals);
    sigaddset(&signals, SIGTERM);
    sigaddset(&signals, SIGINT);
    sigaddset(&signals, SIGHUP);
    pthread_sigmask(SIG_BLOCK, &signals, nullptr);
    signal(SIGPIPE, SIG_IGN);

    auto started = server::Server::start(c);
    if (!started) throw Failure(started.error().message);
    std::unique_ptr<server::Server> srv = std::move(*started);
    // Stores open, ports listening: a Type=notify unit is started now (and /readyz says 200).
    notify_service_manager("READY=1\nSTATUS=serving");
    for (;;) {
        int sig = 0;
        if (sigwait(&signals, &sig) != 0) continue;
        if (sig == SIGHUP) {
            notify_service_manager("RELOADING=1\n" + monotonic_usec_field());
            if (!a.config_file.empty()) warn_if_config_changed(a, *srv);
            srv->reload();
            (void)srv->reload_tls();  // a renewed certificate; an error is logged and the old one stays
            // The token file again (a rotated secret): a file that cannot be read or is empty keeps
            // the token in force.
            if (!a.auth_token_file.empty()) {
                try {
                    srv->set_auth_token(read_token(a.auth_token_file));
                } catch (const Failure& f) {
                    srv->log_error("auth token not reloaded; the old one stays", f.what());
                }
            }
            notify_service_manager("READY=1\nSTATUS=serving");
            continue;
        }
        notify_service_manager("STOPPING=1");
        // SIGTERM or SIGINT: drain, then exit 0. A watchdog bounds the whole stop: whatever the
        // streams or the transport are doing, the process is gone within --drain-timeout plus
        // kStopGrace (an orchestrator's kill deadline is set from the drain timeout).
        std::mutex m;
        std::condition_variable cv;
        bool stopped = false;
        std::thread watchdog([&] {
            std::unique_lock lock(m);
            if (cv.wait_for(lock, c.drain_timeout + kStopGrace, [&] { return stopped; })) return;
            const long long ms = c.drain_timeout.count();
            // The server's log is gone with it: the line is written here, in the log's own form
            // (docs/server.md, "Logs": ts to the second is enough for the last line).
            const std::time_t now = std::time(nullptr);
            std::tm tm{};
            gmtime_r(&now, &tm);
            char ts[32];
            std::strftime(ts, sizeof ts, "%Y-%m-%dT%H:%M:%SZ", &tm);
            if (c.log_json)
                std::fprintf(stderr, "{\"ts\":\"%s\",\"level\":\"error\",\"msg\":\"stop overran the drain timeout; exiting now\","
                                     "\"drain_timeout_ms\":%lld}\n", ts, ms);
            else
                std::fprintf(stderr, "%s error stop overran the drain timeout; exiting now drain_timeout_ms=%lld\n", ts, ms);
            std::fflush(stderr);
            std::_Exit(1);
        });
        srv->shutdown();
        srv.reset();
        {
            std::lock_guard lock(m);
            stopped = true;
        }
        cv.notify_all();
        watchdog.join();
        return 0;
    }
}

}  // namespace

Command add_serve(CLI::App& app) {
    auto a = std::make_shared<ServeArgs>();
    auto& c = a->config;
    auto* s = app.add_subcommand("serve", "Serve tile stores over gRPC (streaming viewers) and HTTP");
    s->set_config("--config", "", "Read options from a file (key = value lines named like the long options)")->type_name("FILE");
    s->add_option("--store", c.store_files,
                  "A store to serve (repeatable): a file, s3://BUCKET/KEY.tsr or http(s)://HOST/PATH.tsr (range requests; "
                  "S3 credentials and endpoint from the AWS_* environment, docs/server.md); named by its file name without .tsr");
    s->add_option("--store-dir", c.store_dirs, "Serve every *.tsr file in this directory (repeatable)");
    s->add_option("--remote-ca", c.remote_ca_file, "PEM roots to verify https:// and S3 stores (default: the system's)");
    s->add_option("--remote-concurrency", c.remote_concurrency, "Range requests in flight per remote store")->capture_default_str();
    s->add_option("--grpc", c.grpc_address, "gRPC listen address HOST:PORT (port 0: any; \"\": off)")->capture_default_str();
    s->add_option("--http", c.http_address, "HTTP listen address HOST:PORT (port 0: any; \"\": off)")->capture_default_str();
    s->add_option("--tls-cert", c.tls_cert_file, "PEM certificate chain: serve gRPC and HTTP over TLS only");
    s->add_option("--tls-key", c.tls_key_file, "PEM private key for --tls-cert");
    s->add_option("--auth-token-file", a->auth_token_file,
                  "Require \"authorization: Bearer <token>\" with the token in this file (not /healthz, /readyz)");
    add_bytes_option(*s, "--cache-size", a->cache_bytes, "RAM tile cache budget, e.g. 256MiB (0: off)");
    s->add_option("--io-threads", c.io_threads,
                  "Tile reader threads, at most 1024 (0: all cores; at least 16 with a remote store)")
        ->capture_default_str()->check(CLI::Range(0u, server::kMaxThreads));
    s->add_option("--http-threads", c.http_threads,
                  "HTTP event-loop threads, at most 1024 (0: all cores); they never read or render (--work-threads do)")
        ->capture_default_str()->check(CLI::Range(0u, server::kMaxThreads));
    s->add_option("--http-loop-slice-us", a->slice_us,
                  "Time slice, us, the HTTP event loops ask of the kernel (Linux 6.12+: a loop woken by a request "
                  "preempts longer-running work; 0: the kernel's default)")
        ->capture_default_str()->check(CLI::Range(0LL, 100000LL));
    // The limits have upper bounds too: "-1" (or a typo of many digits) would otherwise become
    // the largest size_t, which is no limit at all.
    s->add_option("--max-viewers", c.max_viewers, "Concurrent StreamTiles calls, 1..1048576; beyond: RESOURCE_EXHAUSTED")
        ->capture_default_str()->check(CLI::Range(std::size_t{1}, server::kMaxLimit));
    s->add_option("--max-batch", c.max_batch, "Requests in one batch, 1..1048576; a larger batch is refused whole")
        ->capture_default_str()->check(CLI::Range(std::size_t{1}, server::kMaxLimit));
    s->add_option("--max-pending", c.max_pending,
                  "Admitted requests waiting over all viewers, 1..1048576; beyond: RESOURCE_EXHAUSTED")
        ->capture_default_str()->check(CLI::Range(std::size_t{1}, server::kMaxLimit));
    s->add_option("--batch-hold", a->batch_hold_ms,
                  "While a viewer has more than 256 requests pending, hold its next large batch up to this long, ms "
                  "(a newer batch replaces it unread; 0: apply every batch as it arrives)")
        ->capture_default_str()->check(CLI::Range(0LL, 60000LL));
    add_bytes_option(*s, "--max-message", a->max_message, "Largest gRPC message accepted, e.g. 4MiB");
    add_bytes_option(*s, "--reply-message", c.grpc_message_bytes,
                     "Tile replies packed into one gRPC message up to this size (revision 1 viewers), e.g. 64KiB");
    s->add_option("--max-connections", c.max_connections, "Concurrent HTTP connections, 1..1048576; beyond: 503")
        ->capture_default_str()->check(CLI::Range(std::size_t{1}, server::kMaxLimit));
    add_bytes_option(*s, "--max-header", c.max_header_bytes, "Largest HTTP request head, e.g. 8KiB; beyond: 431");
    s->add_option("--max-http-inflight", c.max_http_inflight, "HTTP tile requests served at once, 1..1048576; beyond: 503")
        ->capture_default_str()->check(CLI::Range(std::size_t{1}, server::kMaxLimit));
    add_bytes_option(*s, "--viewer-buffer", a->viewer_buffer, "Replies read but unsent, per viewer (flow control), e.g. 4MiB");
    add_bytes_option(*s, "--total-buffer", a->total_buffer, "The same over all viewers, e.g. 512MiB");
    s->add_option("--request-timeout", a->timeout_ms,
                  "Deadline of a request, ms: a gRPC batch's default, and every HTTP request that needs a read or a render "
                  "(past it: 504)")
        ->capture_default_str()->check(CLI::Range(1LL, 3600000LL));
    s->add_option("--work-threads", c.work_threads, "HTTP workers for tile reads and web renders (off the event loops)")
        ->capture_default_str()->check(CLI::Range(1u, server::kMaxThreads));
    s->add_option("--store-inflight", c.store_inflight, "HTTP reads and renders of one store running at once")
        ->capture_default_str()->check(CLI::Range(std::size_t(1), std::size_t(1024)));
    s->add_option("--store-queue", c.store_queue, "HTTP reads and renders of one store waiting; beyond: 503")
        ->capture_default_str()->check(CLI::Range(std::size_t(1), std::size_t(1) << 20));
    s->add_option("--render-concurrency", c.render_concurrency, "Web renders (DZI/IIIF/XYZ, PNG tiles) at once (0: hardware threads)")
        ->capture_default_str()->check(CLI::Range(0u, server::kMaxThreads));
    s->add_option("--render-queue", c.render_queue, "Web renders waiting; beyond: 503")
        ->capture_default_str()->check(CLI::Range(std::size_t(1), std::size_t(1) << 16));
    add_bytes_option(*s, "--render-memory", c.render_memory_bytes,
                     "Estimated peak memory of the web renders admitted, e.g. 160MiB; beyond: 503");
    s->add_option("--watch-interval", a->watch_ms, "Rescan stores this often, ms (0: only on SIGHUP)")
        ->capture_default_str()->check(CLI::Range(0LL, 86400000LL));
    s->add_option("--idle-timeout", a->idle_ms, "Close idle HTTP keep-alive connections after this many ms")
        ->capture_default_str()->check(CLI::Range(100LL, 86400000LL));
    s->add_option("--drain-timeout", a->drain_ms, "On SIGTERM, wait at most this long for in-flight work, ms")
        ->capture_default_str()->check(CLI::Range(0LL, 3600000LL));
    s->add_option("--http-max-age", c.http_max_age, "Cache-Control max-age of tiles, s (URLs with ?v=VERSION: a year)")
        ->capture_default_str();
    s->add_option("--cors-origin", c.cors_origin,
                  "Origin whose web pages may read responses (Access-Control-Allow-Origin): * for any, one origin, or \"\" "
                  "for none")
        ->capture_default_str();
    s->add_option("--public-url", c.public_url,
                  "URL clients reach this server at, e.g. https://tiles.example.org or https://example.org/tiles behind a proxy "
                  "(IIIF ids, and the path the store JSON's url and tiles and the viewer's links start with; default: the "
                  "request's Host)")
        ->check(CLI::Validator(
            [](std::string& v) -> std::string {
                // Written into JSON, HTML and JavaScript: a URL, with nothing that could end a string there.
                const bool scheme = v.rfind("http://", 0) == 0 || v.rfind("https://", 0) == 0;
                const bool plain = v.find_first_of(" \t\"'<>\\`") == std::string::npos;
                return v.empty() || (scheme && plain && v.size() > v.find("://") + 3) ? std::string()
                                                                                        : "'" + v + "' is not an http:// or https:// URL";
            },
            "URL", "public URL"));
    add_bytes_option(*s, "--web-cache", c.web_cache_bytes, "RAM for encoded DZI/IIIF/XYZ images, e.g. 64MiB (0: off)");
    add_bytes_option(*s, "--web-decoded-cache", c.web_decoded_bytes,
                     "RAM for stored tiles decoded for web images, e.g. 128MiB (0: off)");
    s->add_option("--log-format", a->log_format, "Log lines: json or text")->capture_default_str()
        ->check(CLI::IsMember({"json", "text"}));
    s->add_option("--log-level", a->log_level, "info or debug")->capture_default_str()
        ->check(CLI::IsMember({"info", "debug"}));
    s->footer(
        "Signals: SIGHUP rescans the stores and rereads --auth-token-file, --tls-cert and --tls-key (not --config: a\n"
        "changed one is logged; restart for it); SIGTERM/SIGINT stop accepting, finish admitted work\n"
        "(up to --drain-timeout) and exit 0. Logs go to stderr, one line each: a JSON object (--log-format json) or text\n"
        "(--log-format text).");
    // --config is applied here (Debian 12's CLI11 2.1 reads config files only for the main app,
    // and its reader names no line): keys are long option names, top level or under [serve]; the
    // command line wins; an error names the file and line.
    s->parse_complete_callback([s, a] {
        CLI::Option* cfg = s->get_config_ptr();
        if (cfg == nullptr || cfg->count() == 0) return;
        a->config_file = cfg->as<std::string>();
        try {
            a->config_at_start = read_config_file(a->config_file);
        } catch (const ConfigFileError& e) {
            throw CLI::ValidationError("--config", e.what());
        }
        const ConfigFile& file = a->config_at_start;
        // What the command line sets (it wins over the file, now and after a restart), and every
        // key a file may hold (a reload checks a changed file against them).
        for (const CLI::Option* opt : s->get_options()) {
            for (const std::string& name : opt->get_lnames()) {
                a->config_keys.push_back(name);
                if (opt->count() > 0) a->config_keys_overridden.push_back(name);
            }
        }
        for (const ConfigEntry& entry : file.entries) {
            CLI::Option* opt = s->get_option_no_throw("--" + entry.key);
            if (opt == nullptr || opt == cfg || opt == s->get_help_ptr())
                throw CLI::ValidationError("--config", file.where(entry) + ": unknown option '" + entry.key + "'");
            if (entry.values.size() > 1 && opt->get_items_expected_max() <= 1)
                throw CLI::ValidationError("--config", file.where(entry) + ": '" + entry.key + "' takes one value, the file gives " +
                                                           std::to_string(entry.values.size()) +
                                                           (entry.last_line != entry.line ? " (again on line " + std::to_string(entry.last_line) + ")" : ""));
            if (opt->count() > 0) continue;
            try {
                opt->add_result(entry.values);
                opt->run_callback();
            } catch (const CLI::Error& e) {
                std::string what = e.what();
                if (what.rfind(": ", 0) == 0) what.erase(0, 2);
                throw CLI::ValidationError("--config", file.where(entry) + ": " + entry.key + ": " + what);
            }
        }
    });
    return [a] { return run_serve(*a); };
}

}  // namespace tessera::tools
