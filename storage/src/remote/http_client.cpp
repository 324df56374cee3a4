#include "http_client.hpp"

#include <openssl/ssl.h>

#include <algorithm>
#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/ssl.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>
#include <cctype>
#include <optional>

#include "tessera/host_port.hpp"

namespace tessera::storage::remote {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace ssl = asio::ssl;
using tcp = asio::ip::tcp;
using error_code = boost::system::error_code;

struct HttpClient::Connection {
    asio::io_context ioc;
    std::optional<ssl::context> tls;
    std::optional<beast::tcp_stream> plain;
    std::optional<beast::ssl_stream<beast::tcp_stream>> secure;
    beast::flat_buffer buffer;
    bool open = false;

    beast::tcp_stream& lowest() { return secure ? beast::get_lowest_layer(*secure) : *plain; }
    void close() {
        error_code ignored;
        if (secure || plain) lowest().socket().close(ignored);
        secure.reset();
        plain.reset();
        buffer.clear();
        open = false;
    }
    // Runs one asynchronous operation to completion on this connection's own loop.
    template <class Start>
    error_code run(Start start) {
        error_code result = asio::error::would_block;
        start([&result](error_code ec, auto&&...) { result = ec; });
        ioc.restart();
        ioc.run();
        return result;
    }
};

HttpClient::HttpClient(Origin origin, unsigned max_connections, std::chrono::milliseconds timeout, std::string ca_file,
                       HostResolver::Lookup lookup)
    : origin_(std::move(origin)),
      max_connections_(std::max(1u, max_connections)),
      timeout_(timeout),
      ca_file_(std::move(ca_file)),
      resolver_(origin_.host, origin_.port, std::move(lookup)) {
    if (const auto port = parse_port(origin_.port); port && *port > 0) port_ = *port;
}

HttpClient::~HttpClient() = default;

std::string HttpClient::host_header() const {
    const bool default_port = (origin_.tls && origin_.port == "443") || (!origin_.tls && origin_.port == "80");
    const bool v6 = origin_.host.find(':') != std::string::npos;
    const std::string host = v6 ? "[" + origin_.host + "]" : origin_.host;
    return default_port ? host : host + ":" + origin_.port;
}

std::unique_ptr<HttpClient::Connection> HttpClient::take(Deadline deadline) {
    std::unique_lock lock(m_);
    if (!cv_.wait_until(lock, deadline, [&] { return busy_ < max_connections_ || cancelled(); }) || cancelled())
        return nullptr;
    ++busy_;
    std::unique_ptr<Connection> c;
    if (!idle_.empty()) {
        c = std::move(idle_.back());
        idle_.pop_back();
    } else {
        c = std::make_unique<Connection>();
    }
    active_.push_back(c.get());
    return c;
}

void HttpClient::give_back(std::unique_ptr<Connection> c) {
    {
        std::lock_guard lock(m_);
        --busy_;
        std::erase(active_, c.get());
        if (c && c->open && !cancelled()) idle_.push_back(std::move(c));
    }
    cv_.notify_one();
}

void HttpClient::cancel() {
    std::lock_guard lock(m_);
    cancelled_.store(true, std::memory_order_relaxed);
    // Each connection runs its operations on its own io_context, in the requesting thread: the
    // cancel is posted there (it runs before, or ends, the operation under way).
    for (Connection* c : active_)
        asio::post(c->ioc, [c] {
            if (c->plain || c->secure) c->lowest().cancel();
        });
    cv_.notify_all();  // requests waiting for a connection give up
}

Result<HttpResponse> HttpClient::request(const std::string& method, const std::string& target,
                                         const std::vector<std::pair<std::string, std::string>>& headers, std::uint64_t max_body,
                                         Deadline deadline) {
    const std::string where = (origin_.tls ? "https://" : "http://") + host_header();
    std::unique_ptr<Connection> c = take(deadline);
    const auto cancelled_error = [&] { return Error{Errc::cancelled, where + ": reads cancelled (the server is stopping)"}; };
    if (!c && cancelled()) return cancelled_error();
    if (!c) return Error{Errc::io_error, where + ": no connection free before the read's deadline"};
    struct Return {
        HttpClient& client;
        std::unique_ptr<Connection>& c;
        ~Return() { client.give_back(std::move(c)); }
    } give_back_on_exit{*this, c};
    // Each step within the client's timeout and what is left of the deadline.
    const auto step_time = [&]() -> std::chrono::steady_clock::duration {
        if (deadline == Deadline::max()) return timeout_;
        const auto left = deadline - std::chrono::steady_clock::now();
        return std::max<std::chrono::steady_clock::duration>(std::min<std::chrono::steady_clock::duration>(timeout_, left),
                                                             std::chrono::milliseconds(1));
    };
    auto fail = [&](const std::string& what, const error_code& ec) -> Error {
        c->close();
        return Error{Errc::io_error, where + ": " + what + ": " + ec.message()};
    };

    for (int attempt = 0;; ++attempt) {
        if (cancelled()) {
            c->close();
            return cancelled_error();
        }
        const bool reused = c->open;
        if (!c->open) {
            // The addresses within this step's time: a slow DNS server holds no request past it.
            auto addresses = resolver_.addresses(std::chrono::steady_clock::now() + step_time());
            if (!addresses) {
                c->close();
                return Error{Errc::io_error, where + ": " + addresses.error().message};
            }
            std::vector<tcp::endpoint> endpoints;
            for (const std::string& a : *addresses) {
                error_code bad;
                const auto ip = asio::ip::make_address(a, bad);
                if (!bad) endpoints.emplace_back(ip, port_);
            }
            if (endpoints.empty() || port_ == 0) {
                c->close();
                return Error{Errc::io_error, where + ": " + origin_.host + " has no usable address"};
            }
            error_code ec;
            if (origin_.tls) {
                if (!c->tls) {
                    c->tls.emplace(ssl::context::tls_client);
                    c->tls->set_options(ssl::context::default_workarounds | ssl::context::no_sslv2 | ssl::context::no_sslv3 |
                                        ssl::context::no_tlsv1 | ssl::context::no_tlsv1_1);
                    error_code e;
                    if (ca_file_.empty()) c->tls->set_default_verify_paths(e);
                    else c->tls->load_verify_file(ca_file_, e);
                    if (e) return fail("TLS roots" + (ca_file_.empty() ? std::string() : " " + ca_file_), e);
                    c->tls->set_verify_mode(ssl::verify_peer);
                }
                c->secure.emplace(c->ioc, *c->tls);
                if (!SSL_set_tlsext_host_name(c->secure->native_handle(), origin_.host.c_str()))
                    return fail("TLS server name", error_code(static_cast<int>(::ERR_get_error()), asio::error::get_ssl_category()));
                c->secure->set_verify_callback(ssl::host_name_verification(origin_.host));
            } else {
                c->plain.emplace(c->ioc);
            }
            c->lowest().expires_after(step_time());
            ec = c->run([&](auto handler) { c->lowest().async_connect(endpoints, handler); });
            if (ec) {
                resolver_.distrust();  // the origin may have moved: look it up again
                return fail("cannot connect", ec);
            }
            if (origin_.tls) {
                c->lowest().expires_after(step_time());
                ec = c->run([&](auto handler) { c->secure->async_handshake(ssl::stream_base::client, handler); });
                if (ec) return fail("TLS handshake", ec);
            }
            c->open = true;
        }

        http::request<http::empty_body> req{http::string_to_verb(method), target, 11};
        req.set(http::field::host, host_header());
        req.set(http::field::user_agent, "tessera");
        for (const auto& [k, v] : headers) req.set(k, v);
        http::response_parser<http::string_body> parser;
        parser.body_limit(max_body);
        if (method == "HEAD") parser.skip(true);
        c->lowest().expires_after(step_time());
        error_code ec = c->secure ? c->run([&](auto handler) { http::async_write(*c->secure, req, handler); })
                                  : c->run([&](auto handler) { http::async_write(*c->plain, req, handler); });
        if (!ec) {
            c->lowest().expires_after(step_time());
            ec = c->secure ? c->run([&](auto handler) { http::async_read(*c->secure, c->buffer, parser, handler); })
                           : c->run([&](auto handler) { http::async_read(*c->plain, c->buffer, parser, handler); });
        }
        if (ec && cancelled()) {
            c->close();
            return cancelled_error();
        }
        if (ec) {
            // A kept-alive connection the server closed meanwhile: once more on a fresh one.
            if (reused && attempt == 0 && ec != beast::error::timeout && ec != http::error::body_limit) {
                c->close();
                continue;
            }
            return fail(ec == http::error::body_limit ? "answer larger than expected" : method + " " + without_query(target), ec);
        }
        auto res = parser.release();
        if (res.result_int() < 200) {  // an interim answer (100, 103): its final one would follow on this connection
            c->close();
            return Error{Errc::io_error, where + ": interim answer " + std::to_string(res.result_int()) + " to " + method + " " +
                                             without_query(target)};
        }
        HttpResponse out;
        out.status = res.result_int();
        for (const auto& f : res) {
            std::string name(f.name_string());
            std::transform(name.begin(), name.end(), name.begin(), [](unsigned char ch) { return char(std::tolower(ch)); });
            out.headers[name] = std::string(f.value());
        }
        out.body = std::move(res.body());
        if (!res.keep_alive()) c->close();
        return out;
    }
}

}  // namespace tessera::storage::remote
