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
        if (auto t = token_.load(std::memory_order_acquire)) return t;
        std::shared_ptr<const std::string> expected;
        auto initial = std::make_shared<const std::string>(config.auth_token);
        // Only the first reader's copy is kept; a reload's token is never overwritten by it.
        token_.compare_exchange_strong(expected, initial, std::memory_order_acq_rel);
        return token_.load(std::memory_order_acquire);
    }
    void set_auth_token(std::string token) { token_.store(std::make_shared<const std::string>(std::move(token))); }

    // (Public so that the context stays an aggregate; use the two functions above.)
    mutable std::atomic<std::shared_ptr<const std::string>> token_{};
};

}  // namespace tessera::server
