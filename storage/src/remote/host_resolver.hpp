#pragma once
// A host name's addresses for an HTTP client, within a request's deadline. getaddrinfo cannot be
// cancelled and may wait seconds on a slow or unreachable DNS server, so no request thread calls
// it: one lookup per origin at a time in the whole process runs on a thread of its own, requests
// wait for it only until their deadline, and its answer is kept for a minute (and served while a
// newer one is looked up), so most requests never wait at all.
#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "tessera/result.hpp"

namespace tessera::storage::remote {

class HostResolver {
public:
    // Numeric addresses ("192.0.2.1", "::1") of `host`; an error when it has none.
    using Lookup = std::function<Result<std::vector<std::string>>(const std::string& host, const std::string& port)>;
    // The system's resolver (getaddrinfo).
    static Result<std::vector<std::string>> system_lookup(const std::string& host, const std::string& port);

    static constexpr std::chrono::seconds kKeep{60};  // how long an answer is reused

    // No `lookup`: the system's, shared per origin across the process; a caller's own (a test's)
    // is this resolver's alone.
    HostResolver(std::string host, std::string port, Lookup lookup = {});
    ~HostResolver();
    HostResolver(const HostResolver&) = delete;
    HostResolver& operator=(const HostResolver&) = delete;

    // The addresses, from the kept answer or a lookup (started now unless one runs already);
    // io_error when none came before `until`. A lookup outliving its waiters finishes on its own
    // thread and is kept for the next request.
    Result<std::vector<std::string>> addresses(std::chrono::steady_clock::time_point until);
    // No connection could be made to the addresses: the next addresses() starts a new lookup
    // (and serves these until it answers).
    void distrust();

    struct State;  // per origin, shared by its resolvers (host_resolver.cpp)

private:
    std::string host_, port_;
    Lookup lookup_;
    std::shared_ptr<State> state_;  // shared with a running lookup, which may outlive this
};

}  // namespace tessera::storage::remote
