// The emulated link (emulated_source.hpp): a min-heap of tiles by arrival time.
#include "tessera/client/emulated_source.hpp"

#include <algorithm>
#include <queue>
#include <random>
#include <sstream>
#include <unordered_map>
#include <utility>
#include <vector>

namespace tessera::client {

namespace {

using Clock = std::chrono::steady_clock;

constexpr std::size_t kMaxInLink = 4096;  // tiles waiting in the link, at most

class EmulatedSource final : public TileSource {
public:
    EmulatedSource(std::unique_ptr<TileSource> inner, EmulatedLink link, std::uint64_t seed)
        : inner_(std::move(inner)), link_(link), rng_(seed) {
        if (link_.latency.count() < 0) link_.latency = {};
        if (link_.jitter.count() < 0) link_.jitter = {};
        if (!(link_.bandwidth_bits_per_s > 0)) link_.bandwidth_bits_per_s = 0;
    }

    Result<storage::StoreInfo> bind(TextureId texture, const std::string& store) override {
        return inner_->bind(texture, store);
    }

    // Pages already read and travelling in the link are not asked for again: on a real link the
    // server has sent them, and the inner source would read them a second time.
    void set_requests(std::uint64_t frame, std::span<const SourceRequest> requests) override {
        forward_.clear();
        for (const auto& r : requests)
            if (!in_link_.contains(page_hash_key(r.page))) forward_.push_back(r);
        inner_->set_requests(frame, forward_);
    }

    std::size_t poll(std::vector<SourceTile>& out, std::size_t max) override {
        const auto now = Clock::now();
        // Take what the inner source has, as far as the link holds.
        if (link_q_.size() < kMaxInLink) {
            incoming_.clear();
            inner_->poll(incoming_, kMaxInLink - link_q_.size());
            for (auto& t : incoming_) {
                const Clock::time_point reached = t.received != Clock::time_point{} ? std::min(t.received, now) : now;
                Clock::time_point sent = reached;
                if (link_.bandwidth_bits_per_s > 0) {
                    const double bits = double(t.data.payload.size() + kHeaderBytes) * 8.0;
                    const auto tx = std::chrono::duration_cast<Clock::duration>(
                        std::chrono::duration<double>(bits / link_.bandwidth_bits_per_s));
                    link_free_ = std::max(link_free_, reached) + tx;
                    sent = link_free_;
                }
                Clock::duration jitter{};
                if (link_.jitter.count() > 0) {
                    std::uniform_int_distribution<std::int64_t> d(0, link_.jitter.count());
                    jitter = std::chrono::microseconds(d(rng_));
                }
                t.received = sent + link_.latency + jitter;
                ++in_link_[page_hash_key(t.page)];
                link_q_.push(Held{t.received, seq_++, std::move(t)});
            }
        }
        // Deliver what has arrived.
        std::size_t n = 0;
        while (n < max && !link_q_.empty() && link_q_.top().arrival <= now) {
            out.push_back(std::move(const_cast<Held&>(link_q_.top()).tile));
            link_q_.pop();
            if (auto it = in_link_.find(page_hash_key(out.back().page)); it != in_link_.end() && --it->second == 0)
                in_link_.erase(it);
            ++n;
        }
        return n;
    }

    bool available() const override { return inner_->available(); }
    SourceLink link() const override { return inner_->link(); }
    Result<std::optional<std::string>> scene(const std::string& store) override { return inner_->scene(store); }

    std::string describe() const override {
        // Shortest round-trip text ("150", "0.5", "2.5e+06"), not std::to_string's six decimals.
        auto number = [](double v) {
            std::ostringstream o;
            o << v;
            return o.str();
        };
        std::string s = inner_->describe() + " over an emulated link (latency " + number(link_.latency.count() / 1000.0) +
                        " ms, jitter " + number(link_.jitter.count() / 1000.0) + " ms, ";
        s += link_.bandwidth_bits_per_s > 0 ? number(link_.bandwidth_bits_per_s / 1e6) + " Mbit/s)" : "unlimited bandwidth)";
        return s;
    }

private:
    // Per-tile framing counted against the bandwidth (headers, key, checksum): roughly a gRPC
    // message and a TileReply's fixed fields.
    static constexpr std::size_t kHeaderBytes = 48;

    struct Held {
        Clock::time_point arrival;
        std::uint64_t seq;  // ties: in the order they came
        SourceTile tile;
        bool operator>(const Held& o) const { return arrival != o.arrival ? arrival > o.arrival : seq > o.seq; }
    };

    std::unique_ptr<TileSource> inner_;
    EmulatedLink link_;
    std::mt19937_64 rng_;
    Clock::time_point link_free_{};
    std::uint64_t seq_ = 0;
    std::vector<SourceTile> incoming_;
    std::vector<SourceRequest> forward_;
    std::unordered_map<std::uint64_t, int> in_link_;  // page -> copies in the link
    std::priority_queue<Held, std::vector<Held>, std::greater<>> link_q_;
};

}  // namespace

std::unique_ptr<TileSource> make_emulated_source(std::unique_ptr<TileSource> inner, EmulatedLink link,
                                                 std::uint64_t seed) {
    return std::make_unique<EmulatedSource>(std::move(inner), link, seed);
}

}  // namespace tessera::client
