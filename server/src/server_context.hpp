#pragma once
// What the front ends (gRPC service, HTTP server) share: configuration, logs, metrics, the
// stores and the tile reader. Owned by the Server; outlives both front ends.
#include <atomic>
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
};

}  // namespace tessera::server
