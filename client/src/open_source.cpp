#include "tessera/client/open_source.hpp"

#include <filesystem>

#include "tessera/host_port.hpp"

namespace tessera::client {

namespace {

bool starts_with(std::string_view s, std::string_view prefix) { return s.substr(0, prefix.size()) == prefix; }

}  // namespace

Status check_grpc_target(std::string_view target) {
    const std::string all = target.find(',') == std::string_view::npos ? std::string() : "'" + std::string(target) + "': ";
    if (target.empty()) return Error{Errc::invalid_argument, "no server address (HOST:PORT)"};
    for (std::size_t start = 0;;) {
        const std::size_t comma = target.find(',', start);
        const std::string_view entry = target.substr(start, comma == std::string_view::npos ? std::string_view::npos : comma - start);
        const auto parts = split_host_port(entry);
        const auto port = parts && parts->has_port ? parse_port(parts->port) : std::nullopt;
        if (!port || *port == 0 || (parts->host.empty() && !parts->bracketed))
            return Error{Errc::invalid_argument, all + "'" + std::string(entry) + "' is not HOST:PORT with a port from 1 to 65535"};
        if (comma == std::string_view::npos) return Status();
        start = comma + 1;
    }
}

Result<SourceUrl> parse_source_url(std::string_view spec) {
    namespace fs = std::filesystem;
    SourceUrl url;
    std::string_view rest = spec;
    std::error_code ec;
    if (starts_with(rest, "grpc://")) {
        rest.remove_prefix(7);
        url.remote = true;
    } else if (starts_with(rest, "grpcs://")) {
        rest.remove_prefix(8);
        url.remote = url.tls = true;
    } else if (!fs::exists(fs::path(std::string(spec)), ec) && rest.find(':') != std::string_view::npos &&
               rest.find('/') != std::string_view::npos && !rest.ends_with(".tsr")) {
        url.remote = true;  // TARGET/NAME
    }
    const std::string quoted = "'" + std::string(spec) + "'";
    if (!url.remote) {
        if (!fs::is_regular_file(fs::path(std::string(spec)), ec))
            return Error{Errc::invalid_argument, quoted + ": no such store file (or use grpc://HOST:PORT/NAME)"};
        url.store = std::string(spec);
        return url;
    }
    const auto slash = rest.find('/');
    if (slash == std::string_view::npos || slash == 0 || slash + 1 == rest.size())
        return Error{Errc::invalid_argument, quoted + ": a server store is HOST:PORT/NAME"};
    url.target = std::string(rest.substr(0, slash));
    url.store = std::string(rest.substr(slash + 1));
    if (url.target.find(':') == std::string::npos)
        return Error{Errc::invalid_argument, quoted + ": the server address needs a port (HOST:PORT/NAME)"};
    if (Status st = check_grpc_target(url.target); !st) return st.error();
    return url;
}

Result<OpenedSource> open_source(const SourceUrl& url, const SourceOptions& options) {
    const EmulatedLink& link = options.link;
    if (link.latency.count() < 0 || link.jitter.count() < 0 || link.bandwidth_bits_per_s < 0)
        return Error{Errc::invalid_argument, "the emulated link's latency, jitter and bandwidth must be >= 0"};
    OpenedSource out;
    out.store = url.store;
    if (url.remote) {
        if (url.tls && options.tls_roots_pem.empty())
            return Error{Errc::invalid_argument, "grpcs://" + url.target + ": TLS needs the roots to verify the server against"};
        TileStreamOptions so;
        so.target = url.target;
        so.auth_token = options.auth_token;
        if (url.tls) so.tls_root_certs_pem = options.tls_roots_pem;
        out.source = make_grpc_source(so);
    } else {
        out.source = make_local_store_source(options.local_threads);
    }
    if (link.latency.count() > 0 || link.jitter.count() > 0 || link.bandwidth_bits_per_s > 0)
        out.source = make_emulated_source(std::move(out.source), link, options.link_seed);
    return out;
}

}  // namespace tessera::client
