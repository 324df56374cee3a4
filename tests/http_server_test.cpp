// The HTTP transport (server/src/http_server.cpp) in-process on 127.0.0.1:0, with a Beast client:
// keep-alive and pipelining, HEAD, connection and header limits, malformed requests, idle
// timeout, TLS with a self-signed certificate made by the openssl CLI, draining and stopping.
// GCC 12 warns (-Wtsan) that std::atomic_thread_fence, which Asio's handler fences use, is not
// understood by ThreadSanitizer; Asio's real synchronisation is its mutexes, so the warning is
// noise here, and -Werror would make it fatal in the sanitizer build. Before any include: the
// diagnostic points into <atomic>.
#if defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 12
#pragma GCC diagnostic ignored "-Wtsan"
#endif
#include <fcntl.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <memory>
#include <optional>
#include <random>
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

#include "http_server.hpp"
#include "log.hpp"
#include "metrics.hpp"
#include "prometheus_text.hpp"
#include "server_context.hpp"
#include "store_registry.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/store_writer.hpp"
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
        spec.codec = storage::Codec::raw;
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

    // Generates a self-signed P-256 certificate for localhost with the openssl CLI.
    bool make_certificate(std::string& cert, std::string& key) {
        cert = dir_.file("cert.pem");
        key = dir_.file("key.pem");
        const std::string cmd = "openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes "
                                "-subj /CN=localhost -addext subjectAltName=DNS:localhost,IP:127.0.0.1 -days 1 "
                                "-keyout " + key + " -out " + cert + " >/dev/null 2>&1";
        return std::system(cmd.c_str()) == 0;
    }

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
    {
        // A small body on a GET is read and ignored.
        PlainClient c;
        ASSERT_FALSE(c.connect(server_->port()));
        ASSERT_FALSE(c.write_raw("GET /healthz HTTP/1.1\r\nHost: x\r\nContent-Length: 5\r\n\r\nhello"));
        PlainClient::Response r;
        ASSERT_FALSE(c.read(r));
        EXPECT_EQ(r.result_int(), 200);
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
    EXPECT_EQ((*r)[http::field::allow], "GET, HEAD");
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
    if (!make_certificate(cert, key)) GTEST_SKIP() << "openssl CLI not available";
    config_.tls_cert_file = cert;
    config_.tls_key_file = key;
    start();

    ssl::context tls(ssl::context::tls_client);
    tls.load_verify_file(cert);
    tls.set_verify_mode(ssl::verify_peer);
    tls.set_verify_callback(ssl::host_name_verification("localhost"));
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
    if (!make_certificate(cert, key)) GTEST_SKIP() << "openssl CLI not available";
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
    if (!s.ok()) GTEST_SKIP() << "no IPv6 loopback here: " << s.error().message;
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
    EXPECT_EQ((*v)[http::field::cache_control], "public, max-age=31536000, immutable");
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
            for (int i = 0; i < 40; ++i) {
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
