// Server: wires the parts together and owns them, in this order (destroyed in reverse):
// logger, metrics, stores, cache, fetcher, context, scheduler, gRPC service and server, HTTP
// server, and the watch thread that rescans the stores.
#include <pthread.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/security/server_credentials.h>
#include <grpcpp/security/tls_certificate_provider.h>
#include <grpcpp/security/tls_credentials_options.h>

#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/x509.h>
#include <sys/stat.h>

#include <algorithm>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <system_error>
#include <thread>

#include "grpc_service.hpp"
#include "http_server.hpp"
#include "log.hpp"
#include "metrics.hpp"
#include "scheduler.hpp"
#include "server_context.hpp"
#include "store_registry.hpp"
#include "tessera/host_port.hpp"
#include "tessera/server/server.hpp"
#include "tessera/storage/remote_source.hpp"
#include "tile_cache.hpp"
#include "tile_fetcher.hpp"

namespace tessera::server {

namespace {

RemoteStores remote_stores(const ServerConfig& config) {
    storage::RemoteOptions o;
    o.ca_file = config.remote_ca_file;
    o.max_concurrency = std::max(1u, config.remote_concurrency);
    return RemoteStores{[o](const std::string& location) { return storage::open_remote_source(location, o); },
                        [o](const std::string& location) { return storage::remote_version(location, o); }};
}

// Remote reads wait on the network, not the CPU: with a remote store, gRPC readers left at "all
// cores" become at least kRemoteThreads, so a 50 ms round trip does not cap the server at
// cores / 50 ms reads. HTTP loops never read (their reads run on the executor's workers:
// docs/server.md, "Isolation").
constexpr unsigned kRemoteThreads = 16;
// How often gRPC's TLS credentials look at the certificate and key files for a renewal.
constexpr unsigned kTlsRefreshSeconds = 2;
ServerConfig effective(ServerConfig c) {
    const bool remote = std::any_of(c.store_files.begin(), c.store_files.end(), [](const std::string& s) {
        return s.starts_with("s3://") || s.starts_with("http://") || s.starts_with("https://");
    });
    if (remote) {
        const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
        if (c.io_threads == 0) c.io_threads = std::max(cores, kRemoteThreads);
    }
    return c;
}

Result<std::string> read_text_file(const std::string& path, const char* what) {
    std::ifstream in(path, std::ios::binary);
    if (!in) return Error{Errc::io_error, std::string("cannot read ") + what + " " + path};
    std::ostringstream ss;
    ss << in.rdbuf();
    return ss.str();
}

// Whether `key_pem` is the private key of the first certificate in `cert_pem`.
Status check_key_pair(const std::string& cert_pem, const std::string& key_pem, const ServerConfig& c) {
    BIO* cb = BIO_new_mem_buf(cert_pem.data(), int(cert_pem.size()));
    BIO* kb = BIO_new_mem_buf(key_pem.data(), int(key_pem.size()));
    X509* cert = cb ? PEM_read_bio_X509(cb, nullptr, nullptr, nullptr) : nullptr;
    EVP_PKEY* key = kb ? PEM_read_bio_PrivateKey(kb, nullptr, nullptr, nullptr) : nullptr;
    const bool ok = cert && key && X509_check_private_key(cert, key) == 1;
    EVP_PKEY_free(key);
    X509_free(cert);
    BIO_free(kb);
    BIO_free(cb);
    ERR_clear_error();
    if (!cert) return Error{Errc::invalid_argument, "no PEM certificate in TLS certificate " + c.tls_cert_file};
    if (!key) return Error{Errc::invalid_argument, "no PEM private key in TLS key " + c.tls_key_file};
    if (!ok)
        return Error{Errc::invalid_argument,
                     "TLS key '" + c.tls_key_file + "' does not match the certificate '" + c.tls_cert_file + "'"};
    return {};
}

// Why the PEM certificate is not valid now ("expired on Jan  1 00:00:00 2021 GMT", "not valid
// before ..."), or "" when it is (or cannot be read: check_key_pair says so). TLS clients refuse
// such a certificate; the server serves it all the same (a clock may be wrong) and says so.
std::string certificate_out_of_date(const std::string& cert_pem) {
    BIO* cb = BIO_new_mem_buf(cert_pem.data(), int(cert_pem.size()));
    X509* cert = cb ? PEM_read_bio_X509(cb, nullptr, nullptr, nullptr) : nullptr;
    std::string why;
    auto text = [](const ASN1_TIME* t) {
        std::string s;
        if (BIO* out = BIO_new(BIO_s_mem())) {
            if (ASN1_TIME_print(out, t) == 1) {
                char* data = nullptr;
                const long n = BIO_get_mem_data(out, &data);
                if (n > 0 && data) s.assign(data, std::size_t(n));
            }
            BIO_free(out);
        }
        return s;
    };
    if (cert && X509_cmp_current_time(X509_get0_notAfter(cert)) < 0) why = "expired on " + text(X509_get0_notAfter(cert));
    else if (cert && X509_cmp_current_time(X509_get0_notBefore(cert)) > 0) why = "not valid before " + text(X509_get0_notBefore(cert));
    X509_free(cert);
    BIO_free(cb);
    ERR_clear_error();
    return why;
}

// HOST:PORT with a port in 0..65535 (0: any); HOST may be a bracketed IPv6 literal.
Status check_address(const std::string& address, const char* flag) {
    const auto parts = split_host_port(address);
    if (!parts || !parts->has_port || (parts->host.empty() && !parts->bracketed) || !parse_port(parts->port))
        return Error{Errc::invalid_argument, std::string(flag) + " " + address + ": expected HOST:PORT with a port 0-65535"};
    return Status();
}

Status validate(const ServerConfig& c) {
    if (!c.grpc_address.empty()) TESSERA_TRY(check_address(c.grpc_address, "--grpc"));
    if (!c.http_address.empty()) TESSERA_TRY(check_address(c.http_address, "--http"));
    if (c.store_files.empty() && c.store_dirs.empty())
        return Error{Errc::invalid_argument, "nothing to serve: give --store FILE or --store-dir DIR"};
    if (c.grpc_address.empty() && c.http_address.empty())
        return Error{Errc::invalid_argument, "both gRPC and HTTP are off: give --grpc or --http an address"};
    if (c.tls_cert_file.empty() != c.tls_key_file.empty())
        return Error{Errc::invalid_argument, "TLS needs both --tls-cert and --tls-key"};
    for (const std::size_t limit : {c.max_viewers, c.max_batch, c.max_pending, c.max_connections, c.max_http_inflight})
        if (limit == 0 || limit > kMaxLimit)
            return Error{Errc::invalid_argument, "limits (--max-*) must be 1.." + std::to_string(kMaxLimit)};
    if (c.viewer_buffer_bytes < 64 * 1024 || c.total_buffer_bytes < c.viewer_buffer_bytes)
        return Error{Errc::invalid_argument, "--viewer-buffer must be at least 64KiB and at most --total-buffer"};
    if (c.max_message_bytes < 1024) return Error{Errc::invalid_argument, "--max-message must be at least 1KiB"};
    if (c.grpc_message_bytes < 1024 || c.grpc_message_bytes > (64u << 20))
        return Error{Errc::invalid_argument, "--reply-message must be between 1KiB and 64MiB"};
    if (c.max_header_bytes < 1024) return Error{Errc::invalid_argument, "--max-header must be at least 1KiB"};
    for (const auto& [n, flag] : {std::pair{c.io_threads, "--io-threads"}, std::pair{c.http_threads, "--http-threads"},
                                  std::pair{c.work_threads, "--work-threads"}, std::pair{c.render_concurrency, "--render-concurrency"}})
        if (n > kMaxThreads)
            return Error{Errc::invalid_argument, std::string(flag) + " must be at most " + std::to_string(kMaxThreads) + ", got " +
                                                     std::to_string(n)};
    return Status();
}

class ServerImpl final : public Server {
public:
    explicit ServerImpl(const ServerConfig& config)
        : config_(effective(config)),
          log_(config.log_json ? LogFormat::json : LogFormat::text, config.log_debug ? LogLevel::debug : config.log_quiet ? LogLevel::warn : LogLevel::info),
          stores_(config.store_files, config.store_dirs, log_, metrics_, remote_stores(config)),
          cache_(config.cache_bytes),
          fetcher_(cache_, metrics_, log_, config_.web_decoded_bytes),
          ctx_{config_, log_, metrics_, stores_, fetcher_} {}

    ~ServerImpl() override {
        shutdown();
        if (!identity_dir_.empty()) {
            std::error_code ec;
            std::filesystem::remove_all(identity_dir_, ec);
        }
    }

    Status start() {
        TESSERA_TRY(stores_.open());
        scheduler_ = std::make_unique<Scheduler>(ctx_);
        if (!config_.grpc_address.empty()) TESSERA_TRY(start_grpc());
        if (!config_.http_address.empty()) {
            auto http = HttpServer::start(ctx_);
            if (!http) return http.error();
            http_ = std::move(*http);
        }
        // Remote stores' requests (process totals; 0 without remote stores).
        metrics_.gauge_callback("tessera_remote_requests", "HTTP requests to remote stores (HEAD and range GET, retries included)", {},
                                [] { return double(storage::remote_counters().requests.load()); });
        metrics_.gauge_callback("tessera_remote_retries", "Of them, retries after a failure or a 5xx/408/429", {},
                                [] { return double(storage::remote_counters().retries.load()); });
        metrics_.gauge_callback("tessera_remote_read_bytes", "Bytes received by range GETs from remote stores", {},
                                [] { return double(storage::remote_counters().bytes.load()); });
        metrics_.gauge_callback("tessera_remote_failures", "Remote reads that failed after every try", {},
                                [] { return double(storage::remote_counters().failures.load()); });
        metrics_.gauge_callback("tessera_uptime_seconds", "Seconds since the server started", {}, [this] {
            return std::chrono::duration<double>(std::chrono::steady_clock::now() - ctx_.started).count();
        });
        if (config_.watch_interval.count() > 0) watcher_ = std::thread([this] { watch(); });
        ctx_.ready = true;
        log_.info("listening", {{"grpc", grpc_port_ ? host_of(config_.grpc_address) + ":" + std::to_string(grpc_port_) : std::string()},
                                {"http", http_ ? host_of(config_.http_address) + ":" + std::to_string(http_->port()) : std::string()},
                                {"stores", static_cast<unsigned long>(stores_.list().size())},
                                {"tls", !config_.tls_cert_file.empty()},
                                {"auth", !config_.auth_token.empty()}});
        warn_if_certificate_out_of_date();
        return Status();
    }

    void warn_if_certificate_out_of_date() {
        if (config_.tls_cert_file.empty()) return;
        const auto cert = read_text_file(config_.tls_cert_file, "TLS certificate");
        if (!cert) return;
        if (const std::string why = certificate_out_of_date(*cert); !why.empty())
            log_.warn("TLS certificate is out of date; clients will refuse it", {{"path", config_.tls_cert_file}, {"why", why}});
    }

    std::uint16_t grpc_port() const override { return static_cast<std::uint16_t>(grpc_port_); }
    std::uint16_t http_port() const override { return http_ ? http_->port() : 0; }

    void set_auth_token(const std::string& token) override {
        ctx_.set_auth_token(token);
        log_.info("auth token replaced", {{"auth", !token.empty()}});
    }

    void log_error(std::string_view event, std::string_view error) override { log_.error(event, {{"error", error}}); }
    void log_warning(std::string_view event, std::string_view key, std::string_view value) override {
        log_.warn(event, {{key, value}});
    }

    Status reload_tls() override {
        if (config_.tls_cert_file.empty()) return {};
        // The pair is checked (and gRPC's copy written) first: a broken renewal changes nothing.
        Status s = identity_file_.empty() ? check_key_pair_files() : publish_identity();
        if (s.ok() && http_) s = http_->reload_tls();
        if (!s.ok()) {
            log_.error("TLS certificate not reloaded; the old one stays", {{"error", s.error().message}});
            return s;
        }
        log_.info("TLS certificate reloaded", {{"http", http_ != nullptr}, {"grpc_within_s", kTlsRefreshSeconds}});
        warn_if_certificate_out_of_date();
        return {};
    }

    void reload() override {
        const auto r = stores_.reload();
        log_.info("reload", {{"added", r.added}, {"replaced", r.replaced}, {"removed", r.removed}, {"failed", r.failed}});
    }

    void shutdown() override {
        std::lock_guard lock(shutdown_mutex_);
        if (shut_down_) return;
        shut_down_ = true;
        const auto t0 = std::chrono::steady_clock::now();
        const auto deadline = t0 + config_.drain_timeout;
        log_.info("draining", {{"timeout_ms", static_cast<long long>(config_.drain_timeout.count())}});
        ctx_.draining = true;
        {
            std::lock_guard wl(watch_mutex_);
            stop_watch_ = true;
        }
        watch_cv_.notify_all();
        if (watcher_.joinable()) watcher_.join();
        if (http_) http_->begin_drain();
        if (scheduler_) scheduler_->begin_drain();
        // Streams finish once their admitted requests are sent; HTTP requests being served finish.
        while (scheduler_ && scheduler_->stats().viewers > 0 && std::chrono::steady_clock::now() < deadline)
            std::this_thread::sleep_for(std::chrono::milliseconds(5));
        const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
        if (http_) http_->wait_idle(std::max(left, std::chrono::milliseconds(0)));
        // The drain is over: what still waits on a remote store's origin is cut, not waited for
        // (HTTP jobs and gRPC reads would otherwise hold the stop until their own deadlines).
        for (const auto& h : stores_.list()) h->reader->cancel_reads();
        const auto s = scheduler_ ? scheduler_->stats() : SchedulerStats{};
        if (grpc_server_) grpc_server_->Shutdown(std::chrono::system_clock::now() + std::chrono::milliseconds(200));
        if (http_) http_->stop();
        scheduler_.reset();
        log_.info("stopped", {{"drain_ms", static_cast<long long>(std::chrono::duration_cast<std::chrono::milliseconds>(
                                               std::chrono::steady_clock::now() - t0).count())},
                              {"viewers_cut", s.viewers}, {"tiles_sent", s.tiles_sent}});
        metrics_.remove_callbacks("tessera_uptime_seconds");
    }

private:
    static std::string host_of(const std::string& address) {
        const auto parts = split_host_port(address);
        return parts ? std::string(parts->host) : address;
    }

    // Checks that --tls-key is the key of --tls-cert and writes both, as one file, where gRPC's
    // file watcher reads them (a private directory, the file renamed into place whole).
    Status check_key_pair_files() const {
        auto cert = read_text_file(config_.tls_cert_file, "TLS certificate");
        if (!cert) return cert.error();
        auto key = read_text_file(config_.tls_key_file, "TLS key");
        if (!key) return key.error();
        return check_key_pair(*cert, *key, config_);
    }

    Status publish_identity() {
        auto cert = read_text_file(config_.tls_cert_file, "TLS certificate");
        if (!cert) return cert.error();
        auto key = read_text_file(config_.tls_key_file, "TLS key");
        if (!key) return key.error();
        if (const Status st = check_key_pair(*cert, *key, config_); !st.ok()) return st;
        if (identity_dir_.empty()) {
            // systemd's RuntimeDirectory= when there is one (a tmpfs, removed with the service),
            // else the temporary directory.
            const char* runtime = std::getenv("RUNTIME_DIRECTORY");
            const std::filesystem::path base =
                runtime && *runtime ? std::filesystem::path(runtime) : std::filesystem::temp_directory_path();
            std::string dir = (base / "tessera-tls-XXXXXX").string();
            if (!::mkdtemp(dir.data())) return Error{Errc::io_error, "cannot make a private directory for the TLS identity"};
            identity_dir_ = dir;
            identity_file_ = dir + "/identity.pem";
        }
        const std::string tmp = identity_file_ + ".new";
        {
            std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
            ::chmod(tmp.c_str(), 0600);
            out << *key << "\n" << *cert;
            if (!out.flush()) return Error{Errc::io_error, "cannot write the TLS identity copy " + tmp};
        }
        if (std::rename(tmp.c_str(), identity_file_.c_str()) != 0)
            return Error{Errc::io_error, "cannot replace the TLS identity copy " + identity_file_};
        return {};
    }

    Status start_grpc() {
        std::shared_ptr<grpc::ServerCredentials> creds;
        if (!config_.tls_cert_file.empty()) {
            // gRPC watches a private copy of the key and certificate, one file replaced whole and
            // only once the pair is checked (publish_identity): a renewal reaches new connections
            // within kTlsRefreshSeconds of SIGHUP, and a broken one never reaches them.
            if (const Status st = publish_identity(); !st.ok()) return st;
            auto provider = std::make_shared<grpc::experimental::FileWatcherCertificateProvider>(
                identity_file_, identity_file_, kTlsRefreshSeconds);
            grpc::experimental::TlsServerCredentialsOptions tls(provider);
            tls.watch_identity_key_cert_pairs();
            creds = grpc::experimental::TlsServerCredentials(tls);
        } else {
            creds = grpc::InsecureServerCredentials();
        }
        service_ = std::make_unique<GrpcService>(ctx_, *scheduler_);
        grpc::ServerBuilder builder;
        builder.AddListeningPort(config_.grpc_address, creds, &grpc_port_);
        builder.RegisterService(service_.get());
        builder.SetMaxReceiveMessageSize(static_cast<int>(config_.max_message_bytes));
        builder.SetMaxSendMessageSize(64 << 20);
        builder.AddChannelArgument(GRPC_ARG_MAX_CONCURRENT_STREAMS, static_cast<int>(std::min<std::size_t>(
                                                                        config_.max_viewers + 64, 1u << 20)));
        builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_PERMIT_WITHOUT_CALLS, 1);
        // gRPC sets SO_REUSEPORT by default: a second server on a port in use would start and
        // share it, viewers landing on either. Bound alone, it fails as the HTTP port does.
        builder.AddChannelArgument(GRPC_ARG_ALLOW_REUSEPORT, 0);
        // Viewers ping every 6 s to find a stalled server (tile_stream_client.cpp): accepted
        // with room to spare, so no ping counts as abuse (too_many_pings closes the connection).
        builder.AddChannelArgument(GRPC_ARG_HTTP2_MIN_RECV_PING_INTERVAL_WITHOUT_DATA_MS, 4000);
        grpc_server_ = builder.BuildAndStart();
        if (!grpc_server_ || grpc_port_ == 0)
            return Error{Errc::io_error, "cannot listen for gRPC on " + config_.grpc_address +
                                             " (address in use, or not a HOST:PORT this machine has)"};
        return Status();
    }

    void watch() {
        pthread_setname_np(pthread_self(), "store-watch");
        std::unique_lock lock(watch_mutex_);
        while (!watch_cv_.wait_for(lock, config_.watch_interval, [this] { return stop_watch_; })) {
            lock.unlock();
            stores_.reload();
            lock.lock();
        }
    }

    ServerConfig config_;
    Logger log_;
    MetricsRegistry metrics_;
    StoreRegistry stores_;
    TileCache cache_;
    TileFetcher fetcher_;
    ServerContext ctx_;
    std::unique_ptr<Scheduler> scheduler_;
    std::unique_ptr<GrpcService> service_;
    std::unique_ptr<grpc::Server> grpc_server_;
    int grpc_port_ = 0;
    std::unique_ptr<HttpServer> http_;
    std::string identity_dir_, identity_file_;  // gRPC's copy of the TLS key and certificate

    std::mutex watch_mutex_;
    std::condition_variable watch_cv_;
    bool stop_watch_ = false;
    std::thread watcher_;

    std::mutex shutdown_mutex_;
    bool shut_down_ = false;
};

}  // namespace

Result<std::unique_ptr<Server>> Server::start(const ServerConfig& config) {
    // Why it did not start goes into the log too, in its format: a collector reading the JSON
    // lines would otherwise see a shutdown and no error.
    auto failed = [&](Error e) -> Error {
        Logger(config.log_json ? LogFormat::json : LogFormat::text, LogLevel::info).error("start failed", {{"error", e.message}});
        return e;
    };
    if (Status v = validate(config); !v) return failed(v.error());
    auto server = std::make_unique<ServerImpl>(config);
    try {
        if (auto s = server->start(); !s) {
            server.reset();  // its own lines (draining, stopped) first, then why
            return failed(s.error());
        }
    } catch (const std::system_error& e) {  // a thread that could not start (the others are stopped)
        server.reset();
        return failed(Error{Errc::io_error, std::string("cannot start the server's threads: ") + e.what() +
                                                " (fewer --io-threads, --http-threads, --work-threads or --render-concurrency, "
                                                "or a higher ulimit -u / -v)"});
    }
    return std::unique_ptr<Server>(std::move(server));
}

}  // namespace tessera::server
