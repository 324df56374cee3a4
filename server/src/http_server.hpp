#pragma once
// The HTTP front end (Boost.Beast over Asio): store listing and metadata, tiles (stored payload,
// or ?format=png decoded), /metrics, /healthz, /readyz. Optional TLS and bearer-token auth.
// Transport only; what a request means is decided by handle_http_request (http_handler.hpp).
#include <chrono>
#include <cstdint>
#include <memory>

#include "server_context.hpp"
#include "tessera/result.hpp"

namespace tessera::server {

class HttpServer {
public:
    // Binds ctx.config.http_address and starts ctx.config.http_threads event-loop threads
    // (TLS when the config names a certificate and key).
    static Result<std::unique_ptr<HttpServer>> start(ServerContext& ctx);
    virtual ~HttpServer() = default;  // stops and joins
    virtual std::uint16_t port() const = 0;
    // TLS: rereads the certificate and key files for connections accepted from now on (those
    // open keep theirs). On an error the old certificate stays and the error is returned.
    virtual Status reload_tls() = 0;
    // Stop accepting; idle keep-alive connections close; requests being served finish.
    virtual void begin_drain() = 0;
    // True once no request is being served (or the timeout passed: false).
    virtual bool wait_idle(std::chrono::milliseconds timeout) = 0;
    virtual void stop() = 0;
};

}  // namespace tessera::server
