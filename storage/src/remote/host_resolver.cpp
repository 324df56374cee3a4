#include "host_resolver.hpp"

#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <condition_variable>
#include <mutex>
#include <optional>
#include <thread>

namespace tessera::storage::remote {

struct HostResolver::State {
    std::mutex m;
    std::condition_variable cv;
    bool running = false;           // a lookup's thread is out (at most one)
    std::uint64_t finished = 0;     // lookups finished so far
    std::optional<Result<std::vector<std::string>>> last;
    std::chrono::steady_clock::time_point last_at;
};

HostResolver::HostResolver(std::string host, std::string port, Lookup lookup)
    : host_(std::move(host)), port_(std::move(port)), lookup_(std::move(lookup)), state_(std::make_shared<State>()) {}

HostResolver::~HostResolver() = default;

Result<std::vector<std::string>> HostResolver::system_lookup(const std::string& host, const std::string& port) {
    boost::asio::io_context ioc;
    boost::asio::ip::tcp::resolver resolver(ioc);
    boost::system::error_code ec;
    const auto results = resolver.resolve(host, port, ec);
    if (ec) return make_error(Errc::io_error, "cannot resolve " + host + ": " + ec.message());
    std::vector<std::string> out;
    for (const auto& r : results) out.push_back(r.endpoint().address().to_string());
    if (out.empty()) return make_error(Errc::io_error, "cannot resolve " + host + ": no addresses");
    return out;
}

Result<std::vector<std::string>> HostResolver::addresses(std::chrono::steady_clock::time_point until) {
    State& s = *state_;
    std::unique_lock lock(s.m);
    const auto now = std::chrono::steady_clock::now();
    if (s.last && s.last->ok() && now - s.last_at < kKeep) return *s.last;
    const std::uint64_t seen = s.finished;
    if (!s.running) {
        s.running = true;
        // Detached: getaddrinfo cannot be interrupted, and a client being destroyed must not wait
        // for it. The thread holds the state it reports to; at most one runs per origin.
        std::thread([state = state_, lookup = lookup_, host = host_, port = port_] {
            auto r = lookup(host, port);
            std::lock_guard done(state->m);
            state->last = std::move(r);
            state->last_at = std::chrono::steady_clock::now();
            state->running = false;
            ++state->finished;
            state->cv.notify_all();
        }).detach();
    }
    if (!s.cv.wait_until(lock, until, [&] { return s.finished != seen; }))
        return make_error(Errc::io_error, "cannot resolve " + host_ + " before the read's deadline (the lookup goes on)");
    return *s.last;
}

}  // namespace tessera::storage::remote
