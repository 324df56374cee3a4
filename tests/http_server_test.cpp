// The HTTP transport (server/src/http_server.cpp) in-process on 127.0.0.1:0, with a Beast client:
// keep-alive and pipelining, HEAD, connection and header limits, request bodies and transfer
// codings, malformed requests, idle timeout, TLS with a self-signed certificate made by the
// openssl CLI (tools/setup.sh installs it; without it the TLS tests fail), responses of every
// route at sizes around TLS's 16 KiB record, draining and stopping.
// GCC 12 warns (-Wtsan) that std::atomic_thread_fence, which Asio's handler fences use, is not
// understood by ThreadSanitizer; Asio's real synchronisation is its mutexes, so the warning is
// noise here, and -Werror would make it fatal in the sanitizer build. Before any include: the
// diagnostic points into <atomic>.
#if defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 12
#pragma GCC diagnostic ignored "-Wtsan"
#endif
#include <fcntl.h>
#include <sys/resource.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <sstream>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <boost/asio/connect.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/ssl.hpp>
#include <boost/asio/write.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>

#include "http_handler.hpp"
#include "http_server.hpp"
#include "log.hpp"
#include "metrics.hpp"
#include "prometheus_text.hpp"
#include "server_context.hpp"
#include "store_registry.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/store_writer.hpp"
#include "server_process.hpp"
#include "test_util.hpp"
#include "tile_cache.hpp"
#include "tile_fetcher.hpp"

using namespace tessera;
using namespace tessera::server;
using tessera::test::ScratchDir;

namespace net = boost::asio;
namespace ssl = boost::asio::ssl;
namespace beast = boost::beast;
namespace http = boost::beast::http;
using tcp = boost::asio::ip::tcp;
using error_code = boost::system::error_code;

namespace {

constexpr auto kTimeout = std::chrono::seconds(5);

// A Beast client whose every operation is bounded in time (async under the hood, so a server
// bug fails the test instead of hanging it).
template <bool Tls>
class Client {
public:
    using Stream = std::conditional_t<Tls, beast::ssl_stream<beast::tcp_stream>, beast::tcp_stream>;
    using Response = http::response<http::string_body>;

    explicit Client(ssl::context* tls = nullptr) : stream_(make(ioc_, tls)) {}

    error_code connect(std::uint16_t port) {
        const tcp::endpoint ep(net::ip::make_address("127.0.0.1"), port);
        error_code ec = run([&](auto done) { tcp().async_connect(ep, [done](const error_code& e) { done(e, 0); }); });
        if (ec) return ec;
        if constexpr (Tls) {
            SSL_set_tlsext_host_name(stream_.native_handle(), "localhost");
            ec = run([&](auto done) {
                stream_.async_handshake(ssl::stream_base::client, [done](const error_code& e) { done(e, 0); });
            });
        }
        return ec;
    }

    error_code write_raw(const std::string& bytes) {
        return run([&](auto done) { net::async_write(stream_, net::buffer(bytes), done); });
    }

    error_code send(http::verb verb, const std::string& target,
                    const std::vector<std::pair<std::string, std::string>>& headers = {}) {
        http::request<http::empty_body> req{verb, target, 11};
        req.set(http::field::host, "localhost");
        for (const auto& [k, v] : headers) req.set(k, v);
        return run([&](auto done) { http::async_write(stream_, req, done); });
    }

    // Reads one response; for a HEAD response pass head = true (no body follows its Content-Length).
    error_code read(Response& out, bool head = false) {
        http::response_parser<http::string_body> parser;
        parser.body_limit(64u << 20);
        if (head) parser.skip(true);
        const error_code ec = run([&](auto done) { http::async_read(stream_, buffer_, parser, done); });
        if (!ec) out = parser.release();
        return ec;
    }

    std::optional<Response> request(http::verb verb, const std::string& target,
                                    const std::vector<std::pair<std::string, std::string>>& headers = {}) {
        if (send(verb, target, headers)) return std::nullopt;
        Response res;
        if (read(res, verb == http::verb::head)) return std::nullopt;
        return res;
    }

    // True when the server has closed the connection (a read gets EOF or a reset).
    bool closed_by_peer() {
        char byte;
        const error_code ec = run([&](auto done) { tcp().socket().async_read_some(net::buffer(&byte, 1), done); });
        return ec && ec != net::error::timed_out;
    }

    beast::tcp_stream& tcp() {
        if constexpr (Tls) return stream_.next_layer();
        else return stream_;
    }

private:
    static Stream make(net::io_context& ioc, ssl::context* tls) {
        if constexpr (Tls) return Stream(ioc, *tls);
        else return Stream(ioc);
    }

    template <class Start>
    error_code run(Start&& start) {
        error_code result;
        bool done = false;
        start([&](const error_code& ec, std::size_t) {
            result = ec;
            done = true;
        });
        ioc_.restart();
        ioc_.run_for(kTimeout);
        if (!done) {
            tcp().socket().close();  // the operation completes with operation_aborted
            ioc_.restart();
            ioc_.run();
            return net::error::timed_out;
        }
        return result;
    }

    net::io_context ioc_;
    Stream stream_;
    beast::flat_buffer buffer_;
};

using PlainClient = Client<false>;
using TlsClient = Client<true>;

std::string hex16(std::uint64_t v) {
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(v));
    return buf;
}

// A zstd store whose level-0 tiles (x, 0) have payloads of exactly sizes[x] bytes: the tile's
// zstd frame (all-zero texels) and a zstd skippable frame padding it to size, so the payloads
// still decode (zstd passes over skippable frames). Returns the payloads. Tiles are 352^2 RGBA:
// a reader refuses payloads over twice the decoded tile (+ 64 KiB), and this one takes 1 MiB.
std::vector<std::string> write_sized_store(const std::string& path, const std::vector<std::size_t>& sizes) {
    storage::StoreSpec spec;
    spec.width = 348 * static_cast<std::uint32_t>(sizes.size());
    spec.height = 348;
    spec.tile_payload = 348;
    spec.border = 2;
    spec.channels = 4;
    spec.sample_type = storage::SampleType::u8;
    spec.colour_space = storage::ColourSpace::srgb;
    spec.codec = tessera::Codec::zstd;
    auto w = storage::StoreWriter::create(path, spec);
    EXPECT_TRUE(w.ok());
    if (!w.ok()) return {};
    const storage::StoreInfo info = storage::store_info(spec);
    const std::vector<std::uint8_t> zeros(info.tile_bytes());
    const auto frame = storage::encode_tile(info, zeros, {});
    EXPECT_TRUE(frame.ok());
    if (!frame.ok()) return {};
    std::mt19937 rng(11);
    std::vector<std::string> payloads;
    for (std::uint32_t x = 0; x < sizes.size(); ++x) {
        std::string p(frame->begin(), frame->end());
        EXPECT_GE(sizes[x], p.size() + 8) << "too small for a zstd frame and a skippable frame";
        const auto pad = static_cast<std::uint32_t>(sizes[x] - p.size() - 8);
        for (std::uint32_t v : {0x184D2A50u, pad})
            for (int i = 0; i < 4; ++i) p.push_back(static_cast<char>(v >> (8 * i)));
        for (std::uint32_t i = 0; i < pad; ++i) p.push_back(static_cast<char>(rng()));
        EXPECT_EQ(p.size(), sizes[x]);
        EXPECT_TRUE((*w)->add_present({0, x, 0}, {reinterpret_cast<const std::uint8_t*>(p.data()), p.size()}).ok());
        payloads.push_back(std::move(p));
    }
    EXPECT_TRUE((*w)->finish().ok());
    return payloads;
}

// A one-tile raw RGBA store of random texels (incompressible: its PNG is a little larger than
// side^2 * 4 bytes).
void write_noise_store(const std::string& path, std::uint32_t side) {
    storage::StoreSpec spec;
    spec.width = side - 4;
    spec.height = side - 4;
    spec.tile_payload = side - 4;
    spec.border = 2;
    spec.channels = 4;
    spec.has_alpha = true;
    spec.sample_type = storage::SampleType::u8;
    spec.colour_space = storage::ColourSpace::srgb;
    spec.codec = tessera::Codec::raw;
    auto w = storage::StoreWriter::create(path, spec);
    ASSERT_TRUE(w.ok());
    std::mt19937 rng(side);
    std::vector<std::uint8_t> texels(storage::store_info(spec).tile_bytes());
    for (auto& b : texels) b = static_cast<std::uint8_t>(rng());
    ASSERT_TRUE((*w)->add_present({0, 0, 0}, texels).ok());
    ASSERT_TRUE((*w)->finish().ok());
}

class HttpServerTest : public ::testing::Test {
protected:
    void SetUp() override {
        storage::StoreSpec spec;
        spec.width = 40;
        spec.height = 30;
        spec.tile_payload = 12;
        spec.border = 2;
        spec.channels = 3;
        spec.sample_type = storage::SampleType::u8;
        spec.colour_space = storage::ColourSpace::srgb;
        spec.codec = tessera::Codec::raw;
        auto w = storage::StoreWriter::create(dir_.file("rgb.tsr"), spec);
        ASSERT_TRUE(w.ok());
        const storage::StoreInfo info = storage::store_info(spec);
        std::mt19937 rng(7);
        for (std::uint32_t l = 0; l < info.level_count(); ++l)
            for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
                for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                    std::vector<std::uint8_t> texels(info.tile_bytes());
                    for (auto& b : texels) b = static_cast<std::uint8_t>(rng());
                    ASSERT_TRUE((*w)->add_present({l, x, y}, texels).ok());
                }
        ASSERT_TRUE((*w)->finish().ok());
        config_.store_dirs = {dir_.path().string()};
        config_.http_address = "127.0.0.1:0";
        config_.http_threads = 2;
    }

    // Builds the context and starts the HTTP server; the test has set config_ first.
    Result<std::unique_ptr<HttpServer>> start_server() {
        reset_context();
        null_fd_ = ::open("/dev/null", O_WRONLY | O_CLOEXEC);
        log_ = std::make_unique<Logger>(LogFormat::text, LogLevel::error, null_fd_);
        metrics_ = std::make_unique<MetricsRegistry>();
        stores_ = std::make_unique<StoreRegistry>(config_.store_files, config_.store_dirs, *log_, *metrics_);
        EXPECT_TRUE(stores_->open().ok());
        cache_ = std::make_unique<TileCache>(config_.cache_bytes);
        fetcher_ = std::make_unique<TileFetcher>(*cache_, *metrics_, *log_);
        ctx_.reset(new ServerContext{config_, *log_, *metrics_, *stores_, *fetcher_});
        ctx_->ready = true;
        return HttpServer::start(*ctx_);
    }

    void start() {
        auto s = start_server();
        ASSERT_TRUE(s.ok()) << s.error().message;
        server_ = std::move(s.value());
        ASSERT_NE(server_->port(), 0);
    }

    void TearDown() override { reset_context(); }

    // Sends `request` as it is on a new connection of `c` and reads one response into `r`.
    void exchange(PlainClient& c, const std::string& request, PlainClient::Response& r) {
        ASSERT_FALSE(c.connect(server_->port()));
        ASSERT_FALSE(c.write_raw(request));
        ASSERT_FALSE(c.read(r));
    }

    void reset_context() {
        server_.reset();
        ctx_.reset();
        fetcher_.reset();  // before the registry: they remove their gauge callbacks from it
        cache_.reset();
        stores_.reset();
        metrics_.reset();
        log_.reset();
        if (null_fd_ >= 0) ::close(null_fd_);
        null_fd_ = -1;
    }

    std::string tile_bytes(std::uint32_t l, std::uint32_t x, std::uint32_t y) {
        auto r = storage::StoreReader::open(dir_.file("rgb.tsr"));
        EXPECT_TRUE(r.ok());
        const auto t = (*r)->read_tile({l, x, y});
        return std::string(t->bytes.begin(), t->bytes.end());
    }

    ::testing::AssertionResult make_certificate(std::string& cert, std::string& key) {
        return tessera::test::make_test_certificate(dir_, cert, key);
    }

    // A client TLS context that trusts exactly the certificate made above.
    static ssl::context client_tls(const std::string& cert) {
        ssl::context tls(ssl::context::tls_client);
        tls.load_verify_file(cert);
        tls.set_verify_mode(ssl::verify_peer);
        tls.set_verify_callback(ssl::host_name_verification("localhost"));
        return tls;
    }

    // One request of the route/size matrix and what must come back.
    struct RouteCase {
        std::string target;
        bool head = false;
        std::vector<std::pair<std::string, std::string>> headers;
        unsigned status = 200;
        std::string body;  // the exact body expected (HEAD: the GET's, whose length is Content-Length)
        std::function<void(const std::string&)> check_body;  // instead of body, for /metrics
    };

    // Stores that give every route bodies on both sides of 16 KiB (TLS's record size and Beast's
    // flat_stream limit): stored tiles of exact sizes, PNGs from ~1 KB to ~1 MB, a store listing
    // over 16 KiB (64 stores), /metrics over 16 KiB (padding series), 0-byte bodies (304, HEAD).
    // Call before start(); add_metrics_padding() after.
    void write_route_stores() {
        sized_payloads_ = write_sized_store(dir_.file("sizes.tsr"), kSizes);
        write_noise_store(dir_.file("noise64.tsr"), 64);
        write_noise_store(dir_.file("noise512.tsr"), 512);
        for (int i = 0; i < 60; ++i)
            std::filesystem::copy_file(dir_.file("rgb.tsr"), dir_.file("listing-padding-" + std::to_string(i) + ".tsr"));
    }
    void add_metrics_padding() {
        for (int i = 0; i < 2000; ++i)
            metrics_->counter("tessera_test_padding_total", "Padding for a large /metrics", {{"i", std::to_string(i)}});
    }

    // The expected answers come from the handler itself (no transport): the transport must
    // deliver exactly those bytes.
    std::vector<RouteCase> route_cases() {
        auto direct = [&](const std::string& target, std::string_view if_none_match = {}) {
            return handle_http_request(*ctx_, HttpRequestView{"GET", target, "", if_none_match, ""});
        };
        std::vector<RouteCase> cases;
        auto add = [&](const std::string& target) {
            const HttpResponse r = direct(target);
            EXPECT_EQ(r.status, 200u) << target;
            cases.push_back({target, false, {}, r.status, r.body, {}});
            cases.push_back({"/healthz", false, {}, 200, "ok\n", {}});  // right behind each, pipelined
        };
        for (std::size_t x = 0; x < kSizes.size(); ++x) {
            const std::string target = "/v1/stores/sizes/tiles/0/" + std::to_string(x) + "/0";
            EXPECT_TRUE(direct(target).body == sized_payloads_[x]) << target;
            add(target);
        }
        for (const char* png : {"/v1/stores/rgb/tiles/0/0/0?format=png", "/v1/stores/sizes/tiles/0/4/0?format=png",
                                "/v1/stores/noise64/tiles/0/0/0?format=png", "/v1/stores/noise512/tiles/0/0/0?format=png"})
            add(png);
        add("/v1/stores");
        add("/v1/stores/sizes");
        add("/v1/stores/noise512/tiles/0/0/0");  // 1 MiB raw
        add("/readyz");
        // Bodiless: a 304 revalidation and a HEAD (Content-Length of the GET, nothing after it).
        const std::string big = "/v1/stores/sizes/tiles/0/" + std::to_string(kSizes.size() - 1) + "/0";
        const HttpResponse full = direct(big);
        const auto* etag = full.header("ETag");
        EXPECT_TRUE(etag);
        cases.push_back({big, false, {{"If-None-Match", etag ? etag->str() : ""}}, 304, "", {}});
        cases.push_back({big, true, {}, 200, full.body, {}});
        cases.push_back({"/healthz", false, {}, 200, "ok\n", {}});
        cases.push_back({"/metrics", false, {}, 200, "", [](const std::string& body) {
                             EXPECT_GT(body.size(), 16u * 1024);
                             const auto p = test::parse_prometheus_text(body);
                             ASSERT_TRUE(p.ok()) << p.error;
                             EXPECT_EQ(p.value("tessera_test_padding_total", {{"i", "1999"}}), 0.0);
                         }});
        cases.push_back({"/healthz", false, {}, 200, "ok\n", {}});
        // The sizes the matrix is about are really there.
        std::set<std::size_t> sizes;
        for (const auto& c : cases) sizes.insert(c.body.size());
        for (std::size_t n : {std::size_t(0), std::size_t(16383), std::size_t(16384), std::size_t(16385)})
            EXPECT_TRUE(sizes.count(n)) << n;
        EXPECT_GT(*sizes.rbegin(), std::size_t(1) << 20);
        std::size_t over = 0;  // non-tile routes over 16 KiB: PNG, listing
        for (const auto& c : cases) over += c.target.find("format=png") != std::string::npos && c.body.size() > 16384;
        EXPECT_GE(over, 2u);
        for (const auto& c : cases)
            if (c.target == "/v1/stores") {
                EXPECT_GT(c.body.size(), 16384u);
            }
        return cases;
    }

    // Sends every case on one keep-alive connection, one at a time or all written at once, and
    // checks every response in order, byte for byte.
    template <bool Tls>
    void check_route_cases(Client<Tls>& c, const std::vector<RouteCase>& cases, bool pipelined) {
        auto request_text = [](const RouteCase& rc) {
            std::string t = std::string(rc.head ? "HEAD " : "GET ") + rc.target + " HTTP/1.1\r\nHost: localhost\r\n";
            for (const auto& [k, v] : rc.headers) t += k + ": " + v + "\r\n";
            return t + "\r\n";
        };
        if (pipelined) {
            std::string all;
            for (const auto& rc : cases) all += request_text(rc);
            ASSERT_FALSE(c.write_raw(all));
        }
        for (std::size_t i = 0; i < cases.size(); ++i) {
            const RouteCase& rc = cases[i];
            SCOPED_TRACE(std::to_string(i) + ": " + (rc.head ? "HEAD " : "GET ") + rc.target +
                         (pipelined ? " (pipelined)" : ""));
            if (!pipelined) {
                ASSERT_FALSE(c.write_raw(request_text(rc)));
            }
            typename Client<Tls>::Response r;
            ASSERT_FALSE(c.read(r, rc.head));
            ASSERT_EQ(r.result_int(), rc.status) << r.body().substr(0, 200);
            EXPECT_TRUE(r.keep_alive());
            if (rc.head || rc.status == 304) {
                EXPECT_TRUE(r.body().empty());
                if (rc.head) {
                    EXPECT_EQ(r[http::field::content_length], std::to_string(rc.body.size()));
                }
            } else if (rc.check_body) {
                EXPECT_EQ(r[http::field::content_length], std::to_string(r.body().size()));
                rc.check_body(r.body());
            } else {
                EXPECT_EQ(r[http::field::content_length], std::to_string(rc.body.size()));
                ASSERT_EQ(r.body().size(), rc.body.size());
                EXPECT_TRUE(r.body() == rc.body) << "body differs";
            }
        }
    }

    // Stored-tile payload sizes: tiny, around head + body = 16 KiB, around body = 16 KiB, 1 MiB.
    const std::vector<std::size_t> kSizes{100, 16000, 16100, 16383, 16384, 16385, (std::size_t(1) << 20) + 3};
    std::vector<std::string> sized_payloads_;

    ScratchDir dir_;
    ServerConfig config_;
    int null_fd_ = -1;
    std::unique_ptr<Logger> log_;
    std::unique_ptr<MetricsRegistry> metrics_;
    std::unique_ptr<StoreRegistry> stores_;
    std::unique_ptr<TileCache> cache_;
    std::unique_ptr<TileFetcher> fetcher_;
    std::unique_ptr<ServerContext> ctx_;
    std::unique_ptr<HttpServer> server_;
};

}  // namespace

TEST_F(HttpServerTest, KeepAliveServesTwoRequestsOnOneConnection) {
    start();
    PlainClient c;
    ASSERT_FALSE(c.connect(server_->port()));
    auto a = c.request(http::verb::get, "/healthz");
    ASSERT_TRUE(a);
    EXPECT_EQ(a->result_int(), 200);
    EXPECT_EQ(a->body(), "ok\n");
    EXPECT_TRUE(a->keep_alive());
    EXPECT_EQ((*a)[http::field::server], "tessera/0.1");
    auto b = c.request(http::verb::get, "/v1/stores/rgb/tiles/0/1/1");
    ASSERT_TRUE(b);
    EXPECT_EQ(b->result_int(), 200);
    EXPECT_EQ(b->body(), tile_bytes(0, 1, 1));
    EXPECT_EQ((*b)[http::field::content_type], "application/octet-stream");
    EXPECT_EQ((*b)[http::field::content_length], std::to_string(tile_bytes(0, 1, 1).size()));
    EXPECT_FALSE((*b)[http::field::etag].empty());
    // Revalidation on the same connection: 304, no body.
    auto nm = c.request(http::verb::get, "/v1/stores/rgb/tiles/0/1/1",
                        {{"If-None-Match", std::string((*b)[http::field::etag])}});
    ASSERT_TRUE(nm);
    EXPECT_EQ(nm->result_int(), 304);
    EXPECT_TRUE(nm->body().empty());
    // HEAD: the GET's headers and Content-Length, no body.
    auto h = c.request(http::verb::head, "/v1/stores/rgb/tiles/0/1/1");
    ASSERT_TRUE(h);
    EXPECT_EQ(h->result_int(), 200);
    EXPECT_EQ((*h)[http::field::content_length], std::to_string(tile_bytes(0, 1, 1).size()));
    EXPECT_TRUE(h->body().empty());
    // Still usable after the HEAD.
    auto j = c.request(http::verb::get, "/v1/stores");
    ASSERT_TRUE(j);
    EXPECT_EQ(j->result_int(), 200);
    EXPECT_EQ((*j)[http::field::content_type], "application/json");
}

TEST_F(HttpServerTest, PipelinedRequestsAreAnsweredInOrder) {
    start();
    PlainClient c;
    ASSERT_FALSE(c.connect(server_->port()));
    ASSERT_FALSE(c.write_raw("GET /v1/stores/rgb/tiles/0/0/0 HTTP/1.1\r\nHost: x\r\n\r\n"
                             "GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n"
                             "GET /v1/stores/rgb/tiles/1/1/1 HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"));
    PlainClient::Response r1, r2, r3;
    ASSERT_FALSE(c.read(r1));
    ASSERT_FALSE(c.read(r2));
    ASSERT_FALSE(c.read(r3));
    EXPECT_EQ(r1.body(), tile_bytes(0, 0, 0));
    EXPECT_EQ(r2.body(), "ok\n");
    EXPECT_EQ(r3.body(), tile_bytes(1, 1, 1));
    EXPECT_FALSE(r3.keep_alive());
    EXPECT_TRUE(c.closed_by_peer());
}

TEST_F(HttpServerTest, ConnectionsBeyondTheLimitGet503) {
    config_.max_connections = 3;
    start();
    std::vector<std::unique_ptr<PlainClient>> held;
    for (int i = 0; i < 3; ++i) {
        held.push_back(std::make_unique<PlainClient>());
        ASSERT_FALSE(held.back()->connect(server_->port()));
        auto r = held.back()->request(http::verb::get, "/healthz");  // admitted: the session exists
        ASSERT_TRUE(r);
        EXPECT_EQ(r->result_int(), 200);
    }
    {
        const auto p = test::parse_prometheus_text(metrics_->render());
        ASSERT_TRUE(p.ok()) << p.error;
        EXPECT_EQ(p.value("tessera_http_connections"), 3.0);
    }
    PlainClient extra;
    ASSERT_FALSE(extra.connect(server_->port()));
    auto r = extra.request(http::verb::get, "/healthz");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->result_int(), 503);
    EXPECT_EQ(r->body(), "too many connections\n");
    EXPECT_EQ((*r)[http::field::retry_after], "1");
    EXPECT_FALSE(r->keep_alive());
    EXPECT_TRUE(extra.closed_by_peer());

    // The held connections still work; once one goes, a new one is admitted.
    auto again = held[0]->request(http::verb::get, "/healthz");
    ASSERT_TRUE(again);
    EXPECT_EQ(again->result_int(), 200);
    held.pop_back();
    bool admitted = false;
    for (int attempt = 0; attempt < 100 && !admitted; ++attempt) {
        PlainClient c;
        ASSERT_FALSE(c.connect(server_->port()));
        auto res = c.request(http::verb::get, "/healthz");
        admitted = res && res->result_int() == 200;
        if (!admitted) std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    EXPECT_TRUE(admitted);
}

TEST_F(HttpServerTest, OversizedHeadersBodiesAndGarbageAreRefused) {
    config_.max_header_bytes = 4096;
    start();
    {
        PlainClient c;
        ASSERT_FALSE(c.connect(server_->port()));
        ASSERT_FALSE(c.send(http::verb::get, "/healthz", {{"X-Padding", std::string(8000, 'a')}}));
        PlainClient::Response r;
        ASSERT_FALSE(c.read(r));
        EXPECT_TRUE(r.result_int() == 431 || r.result_int() == 400) << r.result_int();
        EXPECT_FALSE(r.keep_alive());
        EXPECT_TRUE(c.closed_by_peer());
    }
    {
        // A long target counts against the same limit.
        PlainClient c;
        ASSERT_FALSE(c.connect(server_->port()));
        ASSERT_FALSE(c.send(http::verb::get, "/" + std::string(6000, 'x')));
        PlainClient::Response r;
        ASSERT_FALSE(c.read(r));
        EXPECT_TRUE(r.result_int() == 431 || r.result_int() == 414 || r.result_int() == 400) << r.result_int();
    }
    {
        PlainClient c;
        ASSERT_FALSE(c.connect(server_->port()));
        ASSERT_FALSE(c.write_raw("GET /healthz HTTP/1.1\r\nHost: x\r\nContent-Length: 100000\r\n\r\n" + std::string(100000, 'b')));
        PlainClient::Response r;
        ASSERT_FALSE(c.read(r));
        EXPECT_EQ(r.result_int(), 413);
    }
    {
        PlainClient c;
        ASSERT_FALSE(c.connect(server_->port()));
        ASSERT_FALSE(c.write_raw("THIS IS NOT HTTP\r\n\r\n"));
        PlainClient::Response r;
        ASSERT_FALSE(c.read(r));
        EXPECT_EQ(r.result_int(), 400);
        EXPECT_TRUE(c.closed_by_peer());
    }
    // The server is fine afterwards, and counted what it refused.
    PlainClient c;
    ASSERT_FALSE(c.connect(server_->port()));
    auto m = c.request(http::verb::get, "/metrics");
    ASSERT_TRUE(m);
    const auto p = test::parse_prometheus_text(m->body());
    ASSERT_TRUE(p.ok()) << p.error;
    EXPECT_EQ(p.value("tessera_http_requests_total", {{"route", "other"}, {"code", "413"}}), 1.0);
}

TEST_F(HttpServerTest, MethodsOtherThanGetAndHeadAre405) {
    start();
    PlainClient c;
    ASSERT_FALSE(c.connect(server_->port()));
    auto r = c.request(http::verb::post, "/v1/stores");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->result_int(), 405);
    EXPECT_EQ((*r)[http::field::allow], "GET, HEAD, OPTIONS");
}

// A browser's CORS preflight over the real transport: its headers reach the handler, and the
// answer (204, no body) keeps the connection usable for the request that follows.
TEST_F(HttpServerTest, CorsPreflightAndOriginHeaders) {
    start();
    PlainClient c;
    ASSERT_FALSE(c.connect(server_->port()));
    auto p = c.request(http::verb::options, "/v1/stores",
                       {{"Origin", "https://viewer.example"}, {"Access-Control-Request-Method", "GET"}});
    ASSERT_TRUE(p);
    EXPECT_EQ(p->result_int(), 204);
    EXPECT_EQ((*p)[http::field::access_control_allow_origin], "*");
    EXPECT_NE(std::string((*p)[http::field::access_control_allow_headers]).find("Authorization"), std::string::npos);
    auto r = c.request(http::verb::get, "/v1/stores", {{"Origin", "https://viewer.example"}});
    ASSERT_TRUE(r);
    EXPECT_EQ(r->result_int(), 200);
    EXPECT_EQ((*r)[http::field::access_control_allow_origin], "*");
    auto plain = c.request(http::verb::get, "/v1/stores");  // no Origin: no CORS headers
    ASSERT_TRUE(plain);
    EXPECT_EQ((*plain)[http::field::access_control_allow_origin], "");
}

// Answers the transport makes itself carry CORS headers as every other answer does, so a page's
// script can read them: a 413 to a request that came with an Origin, and the 503 past the
// connection limit (its request never read) with its Retry-After exposed.
TEST_F(HttpServerTest, TransportAnswersCarryCors) {
    config_.max_connections = 1;
    start();
    PlainClient held;
    ASSERT_FALSE(held.connect(server_->port()));
    ASSERT_TRUE(held.request(http::verb::get, "/healthz"));
    PlainClient extra;
    ASSERT_FALSE(extra.connect(server_->port()));
    auto r = extra.request(http::verb::get, "/v1/stores", {{"Origin", "https://viewer.example"}});
    ASSERT_TRUE(r);
    EXPECT_EQ(r->result_int(), 503);
    EXPECT_EQ((*r)[http::field::access_control_allow_origin], "*");
    EXPECT_NE(std::string((*r)[http::field::access_control_expose_headers]).find("Retry-After"), std::string::npos);

    ASSERT_FALSE(held.write_raw("GET /v1/stores HTTP/1.1\r\nHost: x\r\nOrigin: https://viewer.example\r\n"
                                "Content-Length: 5\r\n\r\nhello"));
    PlainClient::Response refused;
    ASSERT_FALSE(held.read(refused));
    EXPECT_EQ(refused.result_int(), 413);
    EXPECT_EQ(refused[http::field::access_control_allow_origin], "*");
}

// RFC 9112 3.2.2: a server must accept a request target in absolute form, its authority taking
// the Host header's place.
TEST_F(HttpServerTest, AbsoluteFormTargetsAreServed) {
    start();
    PlainClient c;
    ASSERT_FALSE(c.connect(server_->port()));
    for (const std::string target : {"http://127.0.0.1/healthz", "HTTP://tiles.example:8080/v1/stores", "http://h"}) {
        SCOPED_TRACE(target);
        ASSERT_FALSE(c.write_raw("GET " + target + " HTTP/1.1\r\nHost: other\r\n\r\n"));
        PlainClient::Response r;
        ASSERT_FALSE(c.read(r));
        EXPECT_EQ(r.result_int(), 200);
    }
    // An empty path with a query is "/" with it: the same answer as the origin form.
    ASSERT_FALSE(c.write_raw("GET /?access_token=x HTTP/1.1\r\nHost: h\r\n\r\n"));
    PlainClient::Response origin;
    ASSERT_FALSE(c.read(origin));
    ASSERT_FALSE(c.write_raw("GET http://h?access_token=x HTTP/1.1\r\nHost: other\r\n\r\n"));
    PlainClient::Response absolute;
    ASSERT_FALSE(c.read(absolute));
    EXPECT_EQ(absolute.result_int(), origin.result_int());
    EXPECT_EQ(absolute.body(), origin.body());
    // A fragment belongs to no request target, and an http URI has a host.
    for (const std::string target : {"http://h#x", "http://?x", "http:///healthz"}) {
        SCOPED_TRACE(target);
        PlainClient bad;
        ASSERT_FALSE(bad.connect(server_->port()));
        ASSERT_FALSE(bad.write_raw("GET " + target + " HTTP/1.1\r\nHost: h\r\n\r\n"));
        PlainClient::Response r;
        ASSERT_FALSE(bad.read(r));
        EXPECT_EQ(r.result_int(), 400);
    }
}

TEST_F(HttpServerTest, IdleConnectionsTimeOut) {
    config_.idle_timeout = std::chrono::milliseconds(200);
    start();
    PlainClient c;
    ASSERT_FALSE(c.connect(server_->port()));
    auto r = c.request(http::verb::get, "/healthz");
    ASSERT_TRUE(r);
    const auto t0 = std::chrono::steady_clock::now();
    EXPECT_TRUE(c.closed_by_peer());
    EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(3));
}

TEST_F(HttpServerTest, ServesOverTls) {
    std::string cert, key;
    ASSERT_TRUE(make_certificate(cert, key));
    config_.tls_cert_file = cert;
    config_.tls_key_file = key;
    start();

    ssl::context tls = client_tls(cert);
    TlsClient c(&tls);
    ASSERT_FALSE(c.connect(server_->port()));
    auto r = c.request(http::verb::get, "/healthz");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->result_int(), 200);
    EXPECT_EQ(r->body(), "ok\n");
    auto t = c.request(http::verb::get, "/v1/stores/rgb/tiles/2/0/0");  // keep-alive over TLS
    ASSERT_TRUE(t);
    EXPECT_EQ(t->body(), tile_bytes(2, 0, 0));

    // Plain HTTP to the TLS port gets no HTTP answer.
    PlainClient plain;
    ASSERT_FALSE(plain.connect(server_->port()));
    PlainClient::Response pr;
    const bool answered = !plain.send(http::verb::get, "/healthz") && !plain.read(pr) && pr.result_int() == 200;
    EXPECT_FALSE(answered);

    // A client that trusts nothing fails the handshake.
    ssl::context strict(ssl::context::tls_client);
    strict.set_verify_mode(ssl::verify_peer);
    TlsClient bad(&strict);
    EXPECT_TRUE(bad.connect(server_->port()));
}

TEST_F(HttpServerTest, BadTlsFilesFailStart) {
    std::string cert, key;
    ASSERT_TRUE(make_certificate(cert, key));
    config_.tls_cert_file = dir_.file("missing.pem");
    config_.tls_key_file = key;
    auto s = start_server();
    ASSERT_FALSE(s.ok());
    EXPECT_EQ(s.error().code, Errc::io_error);
    EXPECT_NE(s.error().message.find("missing.pem"), std::string::npos) << s.error().message;

    // Not PEM.
    tessera::test::write_file(dir_.file("junk.pem"), {'n', 'o', 'p', 'e', '\n'});
    config_.tls_cert_file = dir_.file("junk.pem");
    auto j = start_server();
    ASSERT_FALSE(j.ok());
    EXPECT_EQ(j.error().code, Errc::io_error);

    // Only one of the two.
    config_.tls_cert_file = cert;
    config_.tls_key_file.clear();
    auto one = start_server();
    ASSERT_FALSE(one.ok());
    EXPECT_EQ(one.error().code, Errc::invalid_argument);
}

TEST_F(HttpServerTest, BadAddressesFailStart) {
    for (const char* address : {"nonsense", "127.0.0.1:", "127.0.0.1:99999", "127.0.0.1:http", ":8080", "::1:80",
                                "[::1", "[::1]80"}) {
        SCOPED_TRACE(address);
        config_.http_address = address;
        auto s = start_server();
        ASSERT_FALSE(s.ok());
        EXPECT_EQ(s.error().code, Errc::invalid_argument) << s.error().message;
    }
    // A port already taken.
    config_.http_address = "127.0.0.1:0";
    start();
    config_.http_address = "127.0.0.1:" + std::to_string(server_->port());
    ServerContext other{config_, *log_, *metrics_, *stores_, *fetcher_};
    auto taken = HttpServer::start(other);
    ASSERT_FALSE(taken.ok());
    EXPECT_EQ(taken.error().code, Errc::io_error);
}

TEST_F(HttpServerTest, Ipv6LiteralInBrackets) {
    config_.http_address = "[::1]:0";
    auto s = start_server();
    if (!s.ok()) {
        // A host without IPv6 (a container with it disabled): the literal must still have been
        // parsed, so what fails is the bind (io_error), not the address (invalid_argument).
        // That is checked, not skipped; connecting over ::1 is checked where IPv6 exists.
        EXPECT_EQ(s.error().code, Errc::io_error) << s.error().message;
        EXPECT_NE(s.error().message.find("[::1]:0"), std::string::npos) << s.error().message;
        return;
    }
    server_ = std::move(s.value());
    net::io_context ioc;
    tcp::socket sock(ioc);
    error_code ec;
    sock.connect(tcp::endpoint(net::ip::make_address("::1"), server_->port()), ec);
    EXPECT_FALSE(ec) << ec.message();
}

TEST_F(HttpServerTest, DrainClosesTheListenerAndIdleConnections) {
    start();
    const std::uint16_t port = server_->port();
    PlainClient idle;
    ASSERT_FALSE(idle.connect(port));
    auto r = idle.request(http::verb::get, "/healthz");
    ASSERT_TRUE(r);
    EXPECT_TRUE(r->keep_alive());

    server_->begin_drain();
    EXPECT_TRUE(server_->wait_idle(std::chrono::seconds(5)));
    // New connections are refused.
    PlainClient late;
    EXPECT_TRUE(late.connect(port));
    // The idle keep-alive connection was closed.
    EXPECT_TRUE(idle.closed_by_peer());
    server_->stop();
    server_->stop();  // idempotent
}

TEST_F(HttpServerTest, DrainLetsTheRequestInProgressFinishWithConnectionClose) {
    start();
    PlainClient c;
    ASSERT_FALSE(c.connect(server_->port()));
    // Half a request: the session is mid-request, not idle, when the drain starts.
    ASSERT_FALSE(c.write_raw("GET /v1/stores/rgb/tiles/0/0/0 HTTP/1.1\r\nHost: x\r\n"));
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    server_->begin_drain();
    ASSERT_FALSE(c.write_raw("\r\n"));
    PlainClient::Response res;
    ASSERT_FALSE(c.read(res));
    EXPECT_EQ(res.result_int(), 200);
    EXPECT_EQ(res.body(), tile_bytes(0, 0, 0));
    EXPECT_FALSE(res.keep_alive());
    EXPECT_TRUE(c.closed_by_peer());
    EXPECT_TRUE(server_->wait_idle(std::chrono::seconds(5)));
}

TEST_F(HttpServerTest, StopClosesEverythingPromptly) {
    start();
    std::vector<std::unique_ptr<PlainClient>> clients;
    for (int i = 0; i < 4; ++i) {
        clients.push_back(std::make_unique<PlainClient>());
        ASSERT_FALSE(clients.back()->connect(server_->port()));
        ASSERT_TRUE(clients.back()->request(http::verb::get, "/healthz"));
    }
    const auto t0 = std::chrono::steady_clock::now();
    server_->stop();
    EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(3));
    for (auto& c : clients) EXPECT_TRUE(c->closed_by_peer());
    server_.reset();
}

TEST_F(HttpServerTest, AuthOverTheWire) {
    config_.auth_token = "tok";
    start();
    PlainClient c;
    ASSERT_FALSE(c.connect(server_->port()));
    auto no = c.request(http::verb::get, "/v1/stores");
    ASSERT_TRUE(no);
    EXPECT_EQ(no->result_int(), 401);
    EXPECT_EQ((*no)[http::field::www_authenticate], "Bearer");
    auto yes = c.request(http::verb::get, "/v1/stores", {{"Authorization", "Bearer tok"}});
    ASSERT_TRUE(yes);
    EXPECT_EQ(yes->result_int(), 200);
    auto probe = c.request(http::verb::get, "/readyz");
    ASSERT_TRUE(probe);
    EXPECT_EQ(probe->result_int(), 200);
    // Versioned tile URLs over the wire.
    auto st = storage::StoreReader::open(dir_.file("rgb.tsr"));
    ASSERT_TRUE(st.ok());
    auto v = c.request(http::verb::get, "/v1/stores/rgb/tiles/0/0/0?v=" + hex16((*st)->info().store_id),
                       {{"Authorization", "Bearer tok"}});
    ASSERT_TRUE(v);
    EXPECT_EQ(v->result_int(), 200);
    // A token's answer is private: a shared cache must not hand it to someone without the token.
    EXPECT_EQ((*v)[http::field::cache_control], "private, max-age=31536000, immutable");
}

TEST_F(HttpServerTest, ManyClientsAtOnceGetTheRightBytes) {
    config_.http_threads = 4;
    config_.cache_bytes = 4096;  // small: reads and cache churn race each other
    start();
    std::vector<std::string> expected;
    for (std::uint32_t y = 0; y < 3; ++y)
        for (std::uint32_t x = 0; x < 4; ++x) expected.push_back(tile_bytes(0, x, y));
    std::atomic<int> failures{0};
    std::vector<std::thread> threads;
    for (int t = 0; t < 6; ++t)
        threads.emplace_back([&, t] {
            PlainClient c;
            if (c.connect(server_->port())) {
                ++failures;
                return;
            }
            for (int i = 0; i < 60; ++i) {
                const std::uint32_t n = static_cast<std::uint32_t>((i * 7 + t) % 12);
                auto r = c.request(http::verb::get, "/v1/stores/rgb/tiles/0/" + std::to_string(n % 4) + "/" +
                                                        std::to_string(n / 4) + (i % 5 == 0 ? "?format=png" : ""));
                if (!r || r->result_int() != 200 || (i % 5 != 0 && r->body() != expected[n])) ++failures;
            }
        });
    for (auto& th : threads) th.join();
    EXPECT_EQ(failures.load(), 0);
    EXPECT_TRUE(server_->wait_idle(std::chrono::seconds(1)));
}

// Every route's responses arrive whole over TLS, at sizes on both sides of the 16 KiB TLS record
// (and Beast's flat_stream limit): one request at a time and pipelined, on one keep-alive
// connection, each response checked byte for byte before the next is read.
TEST_F(HttpServerTest, TlsResponsesOfEveryRouteAndSizeArriveWhole) {
    std::string cert, key;
    ASSERT_TRUE(make_certificate(cert, key));
    config_.tls_cert_file = cert;
    config_.tls_key_file = key;
    write_route_stores();
    start();
    add_metrics_padding();
    const auto cases = route_cases();
    ssl::context tls = client_tls(cert);
    for (bool pipelined : {false, true}) {
        TlsClient c(&tls);
        ASSERT_FALSE(c.connect(server_->port()));
        check_route_cases(c, cases, pipelined);
    }
}

// The same over plain HTTP (the zero-copy gather write).
TEST_F(HttpServerTest, PlainResponsesOfEveryRouteAndSizeArriveWhole) {
    write_route_stores();
    start();
    add_metrics_padding();
    const auto cases = route_cases();
    for (bool pipelined : {false, true}) {
        PlainClient c;
        ASSERT_FALSE(c.connect(server_->port()));
        check_route_cases(c, cases, pipelined);
    }
}

// RFC 9112 3.2: an HTTP/1.1 request without Host, any request with two, and a Host that is not
// a host and port are 400. An HTTP/1.0 request without one is taken to name the address it
// reached: IIIF writes it into the URLs it answers with, where the configured --http (port 0
// here) is no address to come back to.
TEST_F(HttpServerTest, HostIsRequiredOnceAndDefaultsToTheAddressReached) {
    start();
    const std::string port = std::to_string(server_->port());
    for (const std::string request :
         {"GET /healthz HTTP/1.1\r\n\r\n", "GET /healthz HTTP/1.1\r\nHost: a\r\nHost: b\r\n\r\n",
          "GET /healthz HTTP/1.0\r\nHost: a\r\nHost: a\r\n\r\n", "GET /iiif/rgb HTTP/1.1\r\nHost: :80\r\n\r\n",
          "GET /iiif/rgb HTTP/1.1\r\nHost: a:99999\r\n\r\n", "GET /iiif/rgb HTTP/1.1\r\nHost: [::1\r\n\r\n"}) {
        SCOPED_TRACE(request);
        PlainClient c;
        PlainClient::Response r;
        exchange(c, request, r);
        EXPECT_EQ(r.result_int(), 400) << r.body();
    }
    const auto location = [&](const std::string& request) {
        PlainClient c;
        PlainClient::Response r;
        exchange(c, request, r);
        EXPECT_EQ(r.result_int(), 303) << request << r.body();
        return std::string(r[http::field::location]);
    };
    EXPECT_EQ(location("GET /iiif/rgb HTTP/1.0\r\n\r\n"), "http://127.0.0.1:" + port + "/iiif/rgb/info.json");
    EXPECT_EQ(location("GET /iiif/rgb HTTP/1.1\r\nHost: tiles.example:8080\r\n\r\n"),
              "http://tiles.example:8080/iiif/rgb/info.json");
    EXPECT_EQ(location("GET /iiif/rgb HTTP/1.1\r\nHost: [::1]:8080\r\n\r\n"), "http://[::1]:8080/iiif/rgb/info.json");
    // A HEAD refused for its Host gets the head of the 400 and no body.
    PlainClient c;
    ASSERT_FALSE(c.connect(server_->port()));
    ASSERT_FALSE(c.write_raw("HEAD /healthz HTTP/1.1\r\n\r\n"));
    PlainClient::Response r;
    ASSERT_FALSE(c.read(r, /*head=*/true));
    EXPECT_EQ(r.result_int(), 400);
    EXPECT_TRUE(r.body().empty()) << r.body();
    EXPECT_TRUE(c.closed_by_peer()) << "a body after the head";
}

// docs/protocol.md: a request body is 413 (no route takes one), whatever its size; an empty one
// is no body.
TEST_F(HttpServerTest, AnyRequestBodyIs413) {
    start();
    const std::vector<std::pair<std::string, int>> cases{
        {"GET /healthz HTTP/1.1\r\nHost: x\r\nContent-Length: 5\r\n\r\nhello", 413},
        {"GET /v1/stores/rgb/tiles/0/0/0 HTTP/1.1\r\nHost: x\r\nContent-Length: 1\r\n\r\nx", 413},
        {"GET /healthz HTTP/1.1\r\nHost: x\r\nContent-Length: 65536\r\n\r\n" + std::string(65536, 'b'), 413},
        {"HEAD /healthz HTTP/1.1\r\nHost: x\r\nContent-Length: 3\r\n\r\nabc", 413},
        {"GET /healthz HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n5\r\nhello\r\n0\r\n\r\n", 413},
        {"GET /healthz HTTP/1.1\r\nHost: x\r\nContent-Length: 0\r\n\r\n", 200},
        {"GET /healthz HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n", 200},
    };
    for (const auto& [request, status] : cases) {
        SCOPED_TRACE(request.substr(0, 80));
        PlainClient c;
        ASSERT_FALSE(c.connect(server_->port()));
        ASSERT_FALSE(c.write_raw(request));
        PlainClient::Response r;
        ASSERT_FALSE(c.read(r, request.starts_with("HEAD")));
        EXPECT_EQ(r.result_int(), status) << r.body();
        if (status == 413) {
            EXPECT_FALSE(r.keep_alive());
            EXPECT_TRUE(c.closed_by_peer());
        } else {
            auto again = c.request(http::verb::get, "/healthz");  // the connection stays usable
            ASSERT_TRUE(again);
            EXPECT_EQ(again->result_int(), 200);
        }
    }
}

// RFC 9112 6.1, 6.3: a request's Transfer-Encoding must end in chunked (400: its length cannot be
// known, and what follows must not be read as another request), is faulty framing in HTTP/1.0
// (400); chunked is the only coding implemented (501 for others before it).
TEST_F(HttpServerTest, TransferCodingsOtherThanChunkedAreRefused) {
    start();
    const std::vector<std::pair<std::string, int>> cases{
        {"GET /healthz HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: gzip\r\n\r\n", 400},
        // Smuggling: without the 400, the "body" would be answered as a second request.
        {"GET /healthz HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: identity\r\n\r\nGET /readyz HTTP/1.1\r\nHost: x\r\n\r\n", 400},
        {"GET /healthz HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked, gzip\r\n\r\n0\r\n\r\n", 400},
        {"GET /healthz HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: gzip\r\nContent-Length: 5\r\n\r\nhello", 400},
        {"GET /healthz HTTP/1.0\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n", 400},
        {"GET /healthz HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: gzip, chunked\r\n\r\n0\r\n\r\n", 501},
        {"GET /healthz HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: gzip\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n", 501},
    };
    for (const auto& [request, status] : cases) {
        SCOPED_TRACE(request);
        PlainClient c;
        PlainClient::Response r;
        exchange(c, request, r);
        EXPECT_EQ(r.result_int(), status) << r.body();
        EXPECT_FALSE(r.keep_alive());
        EXPECT_TRUE(c.closed_by_peer());  // nothing more: no answer to a smuggled request
    }
}

namespace {

// Holds `count` TCP connections to the port that never send a byte.
std::vector<std::unique_ptr<tcp::socket>> silent_connections(net::io_context& ioc, std::uint16_t port, int count) {
    std::vector<std::unique_ptr<tcp::socket>> out;
    for (int i = 0; i < count; ++i) {
        auto s = std::make_unique<tcp::socket>(ioc);
        error_code ec;
        s->connect(tcp::endpoint(net::ip::make_address("127.0.0.1"), port), ec);
        EXPECT_FALSE(ec) << ec.message();
        out.push_back(std::move(s));
    }
    return out;
}

}  // namespace

// Every client past --max-connections is answered 503, however many there are at once: 80
// connections past the limit that never send a request stay open, and the clients after them
// are still answered (and so are the silent ones).
TEST_F(HttpServerTest, EveryConnectionBeyondTheLimitGets503) {
    config_.max_connections = 1;
    start();
    PlainClient admitted;
    ASSERT_FALSE(admitted.connect(server_->port()));
    auto first = admitted.request(http::verb::get, "/healthz");
    ASSERT_TRUE(first);
    ASSERT_EQ(first->result_int(), 200);
    net::io_context ioc;
    const auto silent = silent_connections(ioc, server_->port(), 80);
    for (int i = 0; i < 10; ++i) {
        SCOPED_TRACE(i);
        PlainClient extra;
        ASSERT_FALSE(extra.connect(server_->port()));
        auto r = extra.request(http::verb::get, "/v1/stores/rgb/tiles/0/0/0");
        ASSERT_TRUE(r) << "no answer";
        EXPECT_EQ(r->result_int(), 503);
        EXPECT_EQ((*r)[http::field::retry_after], "1");
        EXPECT_TRUE(extra.closed_by_peer());
    }
    // The silent ones were answered too, without having asked.
    for (std::size_t i = 0; i < silent.size(); i += 20) {
        std::string got(512, '\0');
        error_code ec;
        const std::size_t n = silent[i]->read_some(net::buffer(got), ec);
        EXPECT_EQ(got.substr(0, std::min<std::size_t>(n, 12)), "HTTP/1.1 503") << ec.message();
    }
    auto still = admitted.request(http::verb::get, "/healthz");
    ASSERT_TRUE(still);
    EXPECT_EQ(still->result_int(), 200);
}

// Past the reject sessions' own bound (1 024 pending 503s) a plain connection is answered on the
// spot without a session; that answer carries CORS and Retry-After like a reject session's, so a
// page's script can still read how long to back off.
TEST_F(HttpServerTest, AFloodPastTheRejectSessionsStillGetsCors) {
    constexpr int kSilent = 1100;  // more than the server's 1 024 reject sessions
    rlimit lim{};
    ASSERT_EQ(getrlimit(RLIMIT_NOFILE, &lim), 0);
    const rlim_t need = 2 * kSilent + 256;  // both ends of every connection live in this process
    if (lim.rlim_cur < need) {
        lim.rlim_cur = std::min<rlim_t>(lim.rlim_max, need);
        ASSERT_EQ(setrlimit(RLIMIT_NOFILE, &lim), 0);
    }
    ASSERT_GE(lim.rlim_cur, need) << "this test needs " << need << " file descriptors";
    config_.max_connections = 1;
    start();
    PlainClient admitted;
    ASSERT_FALSE(admitted.connect(server_->port()));
    ASSERT_TRUE(admitted.request(http::verb::get, "/healthz"));
    net::io_context ioc;
    const auto silent = silent_connections(ioc, server_->port(), kSilent);
    tcp::socket late(ioc);
    error_code ec;
    late.connect(tcp::endpoint(net::ip::make_address("127.0.0.1"), server_->port()), ec);
    ASSERT_FALSE(ec) << ec.message();
    std::string answer;
    char buf[1024];
    while (!ec) answer.append(buf, late.read_some(net::buffer(buf), ec));
    EXPECT_EQ(answer.substr(0, 12), "HTTP/1.1 503");
    EXPECT_NE(answer.find("\r\nRetry-After: 1\r\n"), std::string::npos) << answer;
    EXPECT_NE(answer.find("\r\nAccess-Control-Allow-Origin: *\r\n"), std::string::npos) << answer;
    EXPECT_NE(answer.find("Access-Control-Expose-Headers: ETag, Retry-After"), std::string::npos) << answer;
    EXPECT_TRUE(answer.ends_with("\r\n\r\ntoo many connections\n")) << answer;
}

TEST_F(HttpServerTest, EveryTlsConnectionBeyondTheLimitGets503) {
    std::string cert, key;
    ASSERT_TRUE(make_certificate(cert, key));
    config_.tls_cert_file = cert;
    config_.tls_key_file = key;
    config_.max_connections = 1;
    start();
    ssl::context tls = client_tls(cert);
    TlsClient admitted(&tls);
    ASSERT_FALSE(admitted.connect(server_->port()));
    auto first = admitted.request(http::verb::get, "/healthz");
    ASSERT_TRUE(first);
    ASSERT_EQ(first->result_int(), 200);
    net::io_context ioc;
    const auto silent = silent_connections(ioc, server_->port(), 80);  // not even a handshake
    for (int i = 0; i < 10; ++i) {
        SCOPED_TRACE(i);
        TlsClient extra(&tls);
        ASSERT_FALSE(extra.connect(server_->port()));
        auto r = extra.request(http::verb::get, "/healthz");
        ASSERT_TRUE(r) << "no answer";
        EXPECT_EQ(r->result_int(), 503);
        EXPECT_EQ(r->body(), "too many connections\n");
    }
    auto still = admitted.request(http::verb::get, "/healthz");
    ASSERT_TRUE(still);
    EXPECT_EQ(still->result_int(), 200);
}
