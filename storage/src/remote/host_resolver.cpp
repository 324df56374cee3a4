#include "host_resolver.hpp"

#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <condition_variable>
#include <map>
#include <mutex>
#include <optional>
#include <system_error>
#include <thread>

namespace tessera::storage::remote {

// One per (host, port) in the process, shared by every client of that origin (a store's reads,
// the watcher's version probes): so at most one lookup thread per origin, and one kept answer.
struct HostResolver::State {
    std::mutex m;
    std::condition_variable cv;
    bool running = false;        // a lookup's thread is out (at most one)
    std::uint64_t finished = 0;  // lookups finished so far
    std::optional<Result<std::vector<std::string>>> last;
    std::optional<std::vector<std::string>> last_good;  // the newest successful answer
    std::chrono::steady_clock::time_point last_good_at;
};

namespace {

std::shared_ptr<HostResolver::State> shared_state(const std::string& host, const std::string& port, bool shared) {
    if (!shared) return std::make_shared<HostResolver::State>();
    static std::mutex m;
    static std::map<std::string, std::weak_ptr<HostResolver::State>> states;
    std::lock_guard lock(m);
    std::erase_if(states, [](const auto& e) { return e.second.expired(); });
    auto& slot = states[host + '\n' + port];
    auto s = slot.lock();
    if (!s) slot = s = std::make_shared<HostResolver::State>();
    return s;
}

}  // namespace

HostResolver::HostResolver(std::string host, std::string port, Lookup lookup)
    : host_(std::move(host)), port_(std::move(port)) {
    const bool system = !lookup;
    lookup_ = system ? Lookup(system_lookup) : std::move(lookup);
    state_ = shared_state(host_, port_, system);
}

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

void HostResolver::distrust() {
    std::lock_guard lock(state_->m);
    state_->last_good_at = {};
}

Result<std::vector<std::string>> HostResolver::addresses(std::chrono::steady_clock::time_point until) {
    State& s = *state_;
    std::unique_lock lock(s.m);
    const auto now = std::chrono::steady_clock::now();
    const bool fresh = s.last_good && now - s.last_good_at < kKeep;
    if (fresh) return *s.last_good;
    const std::uint64_t seen = s.finished;
    if (!s.running) {
        // Detached: getaddrinfo cannot be interrupted, and a client being destroyed must not wait
        // for it. The thread holds the state it reports to.
        try {
            std::thread([state = state_, lookup = lookup_, host = host_, port = port_] {
                auto r = lookup(host, port);
                std::lock_guard done(state->m);
                if (r.ok()) {
                    state->last_good = r.value();
                    state->last_good_at = std::chrono::steady_clock::now();
                }
                state->last = std::move(r);
                state->running = false;
                ++state->finished;
                state->cv.notify_all();
            }).detach();
            s.running = true;
        } catch (const std::system_error& e) {
            if (!s.last_good) return make_error(Errc::io_error, "cannot resolve " + host_ + ": no thread for the lookup (" + e.what() + ")");
        }
    }
    // An answer older than kKeep still serves while the new lookup runs: addresses rarely move,
    // and a slow DNS server then delays no request at all.
    if (s.last_good) return *s.last_good;
    if (!s.cv.wait_until(lock, until, [&] { return s.finished != seen; }))
        return make_error(Errc::io_error, "cannot resolve " + host_ + " before the read's deadline (the lookup goes on)");
    return *s.last;
}

}  // namespace tessera::storage::remote
