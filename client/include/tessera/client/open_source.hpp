#pragma once
// Opening a tile source from what a user types (docs/client.md, "Sources"), with the link
// options every application needs. One place for what the viewer, the load tester, the benchmarks
// and an embedding program would otherwise each parse:
//   FILE.tsr                   a local store file
//   grpc://TARGET/NAME         store NAME on a server; TARGET is HOST:PORT, a replica list
//                              (IP:PORT,IP:PORT,...) or a gRPC target
//   grpcs://TARGET/NAME        the same over TLS
//   TARGET/NAME                as grpc://, when no file of that name exists
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include "tessera/client/emulated_source.hpp"
#include "tessera/client/tile_source.hpp"
#include "tessera/result.hpp"

namespace tessera::client {

struct SourceUrl {
    bool remote = false;
    bool tls = false;    // grpcs://
    std::string target;  // remote: the server (TARGET)
    std::string store;   // remote: NAME; local: the store file
};

// Errors (invalid_argument), each naming the spec: a local spec that is no file, a remote one
// without a store name, or whose server is no gRPC target (check_grpc_target).
Result<SourceUrl> parse_source_url(std::string_view spec);

// A server as gRPC takes it: HOST:PORT, replicas as HOST:PORT,HOST:PORT,... or dns:///NAME:PORT;
// every entry with a port from 1 to 65535 (gRPC would take 112407 as 46871). The error says
// which entry is wrong.
Status check_grpc_target(std::string_view target);

struct SourceOptions {
    std::string auth_token;     // remote: sent as a bearer token when non-empty
    std::string tls_roots_pem;  // grpcs://: the roots to verify the server against (PEM text)
    EmulatedLink link;          // latency, jitter, bandwidth added to any source; all zero: none
    std::uint64_t link_seed = 1;
    unsigned local_threads = 2;  // reader threads of a local store
};

struct OpenedSource {
    std::unique_ptr<TileSource> source;
    std::string store;  // the name to bind (TileSource::bind): the store file, or NAME
};

// Errors (invalid_argument): grpcs:// without roots, a negative link figure.
Result<OpenedSource> open_source(const SourceUrl& url, const SourceOptions& options);

}  // namespace tessera::client
