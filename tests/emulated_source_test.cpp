// The emulated link (tessera/client/emulated_source.hpp): requests pass through; replies arrive
// no earlier than latency (+ jitter, bounded), serialized by the bandwidth cap.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <deque>
#include <mutex>
#include <thread>

#include "tessera/client/emulated_source.hpp"

using namespace tessera::client;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

namespace {

// Answers every request at once with a tile of `payload_bytes` bytes.
class InstantSource final : public TileSource {
public:
    explicit InstantSource(std::size_t payload_bytes, std::uint64_t* sets) : bytes_(payload_bytes), sets_(sets) {}
    tessera::Result<tessera::storage::StoreInfo> bind(TextureId, const std::string&) override {
        return tessera::storage::StoreInfo{};
    }
    void set_requests(std::uint64_t, std::span<const SourceRequest> requests) override {
        ++*sets_;
        for (const auto& r : requests) {
            SourceTile t;
            t.page = r.page;
            t.data.payload.assign(bytes_, 7);
            t.received = Clock::now();
            ready_.push_back(std::move(t));
        }
    }
    std::size_t poll(std::vector<SourceTile>& out, std::size_t max) override {
        std::size_t n = 0;
        while (n < max && !ready_.empty()) {
            out.push_back(std::move(ready_.front()));
            ready_.pop_front();
            ++n;
        }
        return n;
    }
    bool available() const override { return true; }
    std::string describe() const override { return "instant"; }

private:
    std::size_t bytes_;
    std::uint64_t* sets_;
    std::deque<SourceTile> ready_;
};

std::vector<SourceRequest> requests(std::uint32_t n) {
    std::vector<SourceRequest> r;
    for (std::uint32_t i = 0; i < n; ++i) r.push_back(SourceRequest{PageKey{0, 0, i, 0}, 1.0f});
    return r;
}

// Polls until `n` tiles came or `limit` passed; returns them with the poll time of each.
std::vector<std::pair<SourceTile, Clock::time_point>> collect(TileSource& s, std::size_t n,
                                                               std::chrono::milliseconds limit) {
    std::vector<std::pair<SourceTile, Clock::time_point>> got;
    const auto end = Clock::now() + limit;
    std::vector<SourceTile> buf;
    while (got.size() < n && Clock::now() < end) {
        buf.clear();
        s.poll(buf, SIZE_MAX);
        const auto now = Clock::now();
        for (auto& t : buf) got.emplace_back(std::move(t), now);
        std::this_thread::sleep_for(500us);
    }
    return got;
}

}  // namespace

TEST(EmulatedSource, AddsLatency) {
    std::uint64_t sets = 0;
    auto s = make_emulated_source(std::make_unique<InstantSource>(100, &sets), EmulatedLink{30ms, 0us, 0}, 1);
    const auto reqs = requests(3);
    // The inner source stamps its tiles during set_requests: [t0, t1] holds that stamp, so the
    // link's delivery time is checked to within that call's duration, with no scheduling slack.
    const auto t0 = Clock::now();
    s->set_requests(1, reqs);
    const auto t1 = Clock::now();
    EXPECT_EQ(sets, 1u);  // forwarded at once
    std::vector<SourceTile> none;
    EXPECT_EQ(s->poll(none, SIZE_MAX), 0u);  // nothing before the latency
    auto got = collect(*s, 3, 2000ms);
    ASSERT_EQ(got.size(), 3u);
    for (const auto& [t, at] : got) {
        EXPECT_GE(at - t0, 30ms);
        EXPECT_GE(t.received - t0, 30ms);
        EXPECT_LE(t.received - t1, 30ms);
        EXPECT_EQ(t.data.payload.size(), 100u);
    }
    EXPECT_EQ(s->describe(), "instant over an emulated link (latency 30 ms, jitter 0 ms, unlimited bandwidth)");
    auto capped = make_emulated_source(std::make_unique<InstantSource>(100, &sets), EmulatedLink{2500us, 500us, 2e7}, 1);
    EXPECT_EQ(capped->describe(), "instant over an emulated link (latency 2.5 ms, jitter 0.5 ms, 20 Mbit/s)");
}

TEST(EmulatedSource, JitterIsBounded) {
    std::uint64_t sets = 0;
    auto s = make_emulated_source(std::make_unique<InstantSource>(10, &sets), EmulatedLink{5ms, 20ms, 0}, 42);
    const auto t0 = Clock::now();
    s->set_requests(1, requests(50));
    const auto t1 = Clock::now();  // the inner source's stamps lie in [t0, t1]
    auto got = collect(*s, 50, 2000ms);
    ASSERT_EQ(got.size(), 50u);
    Clock::duration lo = Clock::duration::max(), hi = Clock::duration::min(), sum{};
    for (const auto& [t, at] : got) {
        lo = std::min(lo, t.received - t0);
        hi = std::max(hi, t.received - t1);
        sum += t.received - t0;
        EXPECT_GE(at, t.received);
    }
    // Latency 5 ms plus 0-20 ms uniformly, exactly: nothing before 5 ms, nothing after 25 ms.
    EXPECT_GE(lo, 5ms);
    EXPECT_LE(hi, 5ms + 20ms);
    // 50 uniform draws over 20 ms spread over most of it (a range under 15 ms has probability
    // about 4e-5) and average about 10 ms (the mean's spread 0.8 ms; +-3 ms allowed).
    EXPECT_GE(hi - lo + (t1 - t0), 15ms);
    const auto mean = sum / 50 - 5ms;
    EXPECT_GE(mean, 7ms);
    EXPECT_LE(mean, 13ms + (t1 - t0));
}

TEST(EmulatedSource, BandwidthSerializes) {
    std::uint64_t sets = 0;
    // 10,000-byte tiles (plus framing) at 4 Mbit/s: about 20 ms each; 4 of them about 80 ms.
    auto s = make_emulated_source(std::make_unique<InstantSource>(10000, &sets), EmulatedLink{0us, 0us, 4e6}, 3);
    const auto t0 = Clock::now();
    s->set_requests(1, requests(4));
    auto got = collect(*s, 4, 3000ms);
    ASSERT_EQ(got.size(), 4u);
    std::sort(got.begin(), got.end(), [](const auto& a, const auto& b) { return a.first.received < b.first.received; });
    for (std::size_t i = 0; i < got.size(); ++i) EXPECT_GE(got[i].first.received - t0, (i + 1) * 19ms) << i;
    EXPECT_GE(got.back().second - t0, 76ms);
}

TEST(EmulatedSource, ReplacedRequestsMayStillArrive) {
    std::uint64_t sets = 0;
    auto s = make_emulated_source(std::make_unique<InstantSource>(10, &sets), EmulatedLink{10ms, 0us, 0}, 1);
    s->set_requests(1, requests(2));
    std::vector<SourceTile> buf;
    s->poll(buf, SIZE_MAX);  // into the link
    s->set_requests(2, {});  // replaced by nothing
    EXPECT_EQ(sets, 2u);
    auto got = collect(*s, 2, 2000ms);
    EXPECT_EQ(got.size(), 2u);  // already on the wire
}

TEST(EmulatedSource, NoDelayPassesThrough) {
    std::uint64_t sets = 0;
    auto s = make_emulated_source(std::make_unique<InstantSource>(10, &sets), EmulatedLink{}, 1);
    s->set_requests(1, requests(5));
    std::vector<SourceTile> buf;
    EXPECT_EQ(s->poll(buf, 3), 3u);
    EXPECT_EQ(s->poll(buf, SIZE_MAX), 2u);
}

TEST(EmulatedSource, PagesInTheLinkAreNotReadAgain) {
    // A page already read and travelling is not forwarded again when the next request set still
    // names it (a real server has sent it; the inner source would read it twice).
    std::uint64_t sets = 0;
    auto s = make_emulated_source(std::make_unique<InstantSource>(10, &sets), EmulatedLink{40ms, 0us, 0}, 1);
    s->set_requests(1, requests(3));
    std::vector<SourceTile> buf;
    EXPECT_EQ(s->poll(buf, SIZE_MAX), 0u);  // read, now in the link
    s->set_requests(2, requests(4));         // the same 3 and one more
    auto got = collect(*s, 4, 2000ms);
    ASSERT_EQ(got.size(), 4u);
    EXPECT_EQ(collect(*s, 1, 100ms).size(), 0u) << "no page was delivered twice";
    // Delivered pages are no longer in the link: asking again reads them again.
    s->set_requests(3, requests(2));
    EXPECT_EQ(collect(*s, 2, 2000ms).size(), 2u);
}
