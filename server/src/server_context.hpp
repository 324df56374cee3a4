#pragma once
// What the front ends (gRPC service, HTTP server) share: configuration, logs, metrics, the
// stores and the tile reader. Owned by the Server; outlives both front ends.
#include <atomic>
#include <string>
#include <mutex>
#include <memory>
#include <chrono>

#include "log.hpp"
#include "metrics.hpp"
#include "store_registry.hpp"
#include "tessera/server/server.hpp"
#include "tile_fetcher.hpp"

namespace tessera::server {

struct ServerContext {
    const ServerConfig& config;
    Logger& log;
    MetricsRegistry& metrics;
    StoreRegistry& stores;
    TileFetcher& fetcher;
    std::chrono::steady_clock::time_point started = std::chrono::steady_clock::now();
    std::atomic<bool> ready{false};     // stores loaded, ports bound (/readyz)
    std::atomic<bool> draining{false};  // SIGTERM received: refuse new work (/readyz fails)

    // The bearer token every request needs ("" none): config.auth_token until replaced by a
    // reload (Server::set_auth_token), read per request without a lock.
    std::shared_ptr<const std::string> auth_token() const {
        auto t = token_.load(std::memory_order_acquire);
        if (t && (token_set_.load(std::memory_order_acquire) || *t == config.auth_token)) return t;
        // config.auth_token, kept as a shared copy (made again if the config changed under it).
        auto fresh = std::make_shared<const std::string>(config.auth_token);
        token_.compare_exchange_strong(t, fresh, std::memory_order_acq_rel);
        return token_set_.load(std::memory_order_acquire) ? token_.load(std::memory_order_acquire) : fresh;
    }
    // No token is asked for (none configured, none set since): answered without loading the
    // shared token, which every request would otherwise pass between threads.
    bool open_access() const { return !token_set_.load(std::memory_order_acquire) && config.auth_token.empty(); }
    void set_auth_token(std::string token) {
        // The flag first: a reader that sees the new token also sees that it was set, so it
        // never swaps it back for the config's.
        token_set_.store(true, std::memory_order_release);
        token_.store(std::make_shared<const std::string>(std::move(token)), std::memory_order_release);
    }

    // (Public so that the context stays an aggregate; use the two functions above.)
    mutable std::atomic<std::shared_ptr<const std::string>> token_{};
    std::atomic<bool> token_set_{false};  // set_auth_token was called: token_ wins over the config
};

}  // namespace tessera::server
