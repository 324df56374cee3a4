#pragma once
// A small blocking HTTP/1.1 client for remote stores (Boost.Beast over Asio, TLS through OpenSSL):
// keep-alive connections to one origin, at most `max_connections` requests at once (callers
// beyond wait), a deadline per request. Retries are the caller's (remote_source.cpp), which knows
// which answers are worth retrying.
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "host_resolver.hpp"
#include "tessera/result.hpp"

namespace tessera::storage::remote {

struct Origin {
    bool tls = false;
    std::string host;  // name or address, as in the URL
    std::string port;  // "80", "443" or the URL's
};

struct HttpResponse {
    unsigned status = 0;
    std::map<std::string, std::string> headers;  // names lower case
    std::string body;
    std::string header(const std::string& lower_name) const {
        auto it = headers.find(lower_name);
        return it == headers.end() ? std::string() : it->second;
    }
};

// A URL or request target as errors and logs show it: without its query, which may carry a
// credential (a signed URL, an access token, an Azure SAS): "https://h/s.tsr?..." for
// "https://h/s.tsr?sig=SECRET".
inline std::string without_query(const std::string& url) {
    const auto q = url.find_first_of("?#");
    return q == std::string::npos ? url : url.substr(0, q) + "?...";
}

class HttpClient {
public:
    // ca_file: PEM roots for TLS ("" = the system's). lookup: how the host's addresses are found
    // (tests give a slow one); each lookup runs apart, so a request waits for it only until its
    // deadline (host_resolver.hpp).
    HttpClient(Origin origin, unsigned max_connections, std::chrono::milliseconds timeout, std::string ca_file,
               HostResolver::Lookup lookup = {});
    ~HttpClient();
    HttpClient(const HttpClient&) = delete;
    HttpClient& operator=(const HttpClient&) = delete;

    // One request (no body); a transport failure (connect, TLS, timeout, a broken answer) is an
    // error with code io_error, an HTTP status of any value a response. Bodies above `max_body`
    // bytes are an error. `deadline` bounds the whole request, the wait for a free connection
    // included (each step also within the client's timeout); past it the request fails.
    using Deadline = std::chrono::steady_clock::time_point;
    Result<HttpResponse> request(const std::string& method, const std::string& target,
                                 const std::vector<std::pair<std::string, std::string>>& headers, std::uint64_t max_body,
                                 Deadline deadline = Deadline::max());

    // Ends the requests in progress at once (they fail) and fails every later one: for a server
    // that is stopping and will not wait for a slow origin. Thread-safe; for good.
    void cancel();
    bool cancelled() const { return cancelled_.load(std::memory_order_relaxed); }

    const Origin& origin() const { return origin_; }
    std::string host_header() const;  // "host" or "host:port" when the port is not the default

private:
    struct Connection;
    std::unique_ptr<Connection> take(Deadline deadline);  // null when the deadline passed first
    void give_back(std::unique_ptr<Connection> c);

    Origin origin_;
    unsigned max_connections_;
    std::chrono::milliseconds timeout_;
    std::string ca_file_;
    HostResolver resolver_;
    std::uint16_t port_ = 0;  // origin_.port as a number (0: not one; requests fail)
    std::mutex m_;
    std::condition_variable cv_;
    unsigned busy_ = 0;
    std::vector<std::unique_ptr<Connection>> idle_;
    std::vector<Connection*> active_;  // taken by a request now (cancel() reaches them)
    std::atomic<bool> cancelled_{false};
};

}  // namespace tessera::storage::remote
