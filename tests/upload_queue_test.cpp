// UploadQueue (budgets, priority order, capacity, drop_if), FakeUploader, and the stats types
// (histogram quantiles, JSON, CSV).
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "tessera/client/stats.hpp"
#include "tessera/client/fakes/uploaders.hpp"
#include "tessera/client/upload.hpp"

namespace tc = tessera::client;

namespace {

tc::ReadyPage page(float priority, std::uint64_t ticket, std::uint32_t bytes = 1024, std::uint32_t x = 0) {
    tc::ReadyPage p;
    p.key = tc::PageKey{1, 0, x, 0};
    p.slot = static_cast<tc::SlotId>(ticket);
    p.priority = priority;
    p.ticket = ticket;
    p.bytes = bytes;
    return p;
}

std::vector<std::uint64_t> tickets(const std::vector<tc::ReadyPage>& v) {
    std::vector<std::uint64_t> t;
    for (const auto& p : v) t.push_back(p.ticket);
    return t;
}

// --- UploadQueue ---

TEST(UploadQueue, HighestPriorityFirstTiesByTicket) {
    tc::UploadQueue q(100, 1 << 30, 100);
    const float prios[] = {1, 5, 3, 5, 0.5f, 3, 9};
    for (std::uint64_t i = 0; i < 7; ++i) ASSERT_TRUE(q.push(page(prios[i], i)));
    std::vector<tc::ReadyPage> out;
    EXPECT_EQ(q.take_frame(out), 7u);
    EXPECT_EQ(tickets(out), (std::vector<std::uint64_t>{6, 1, 3, 2, 5, 0, 4}));
    EXPECT_TRUE(q.empty());
}

TEST(UploadQueue, PageBudgetPerFrameRestStays) {
    tc::UploadQueue q(3, 1 << 30, 100);
    for (std::uint64_t i = 0; i < 8; ++i) q.push(page(static_cast<float>(i), i));
    std::vector<tc::ReadyPage> out;
    EXPECT_EQ(q.take_frame(out), 3u);
    EXPECT_EQ(tickets(out), (std::vector<std::uint64_t>{7, 6, 5}));
    EXPECT_EQ(q.size(), 5u);
    // take_frame appends.
    EXPECT_EQ(q.take_frame(out), 3u);
    EXPECT_EQ(tickets(out), (std::vector<std::uint64_t>{7, 6, 5, 4, 3, 2}));
    out.clear();
    EXPECT_EQ(q.take_frame(out), 2u);
    EXPECT_EQ(q.take_frame(out), 0u);
}

TEST(UploadQueue, ByteBudgetStopsAtTheFirstPageThatDoesNotFit) {
    tc::UploadQueue q(100, 10000, 100);
    q.push(page(9, 0, 4000));
    q.push(page(8, 1, 4000));
    q.push(page(7, 2, 4000));  // would make 12000: stops here...
    q.push(page(6, 3, 1000));  // ...even though this one would fit: the order is strict
    std::vector<tc::ReadyPage> out;
    EXPECT_EQ(q.take_frame(out), 2u);
    EXPECT_EQ(tickets(out), (std::vector<std::uint64_t>{0, 1}));
    EXPECT_EQ(q.queued_bytes(), 5000u);
    out.clear();
    EXPECT_EQ(q.take_frame(out), 2u);
    EXPECT_EQ(tickets(out), (std::vector<std::uint64_t>{2, 3}));
    EXPECT_EQ(q.queued_bytes(), 0u);
}

TEST(UploadQueue, OversizedPageStillGoesAloneSoNothingBlocks) {
    tc::UploadQueue q(100, 1000, 100);
    q.push(page(9, 0, 5000));
    q.push(page(1, 1, 500));
    std::vector<tc::ReadyPage> out;
    EXPECT_EQ(q.take_frame(out), 1u);
    EXPECT_EQ(out[0].ticket, 0u);
    EXPECT_EQ(q.take_frame(out), 1u);
    EXPECT_EQ(out[1].ticket, 1u);
}

TEST(UploadQueue, ZeroPageBudgetTakesNothing) {
    tc::UploadQueue q(0, 1000, 10);
    q.push(page(1, 0));
    std::vector<tc::ReadyPage> out;
    EXPECT_EQ(q.take_frame(out), 0u);
    EXPECT_EQ(q.size(), 1u);
}

TEST(UploadQueue, CapacityBoundLeavesTheRejectedPageIntact) {
    tc::UploadQueue q(10, 1 << 20, 3);
    for (std::uint64_t i = 0; i < 3; ++i) EXPECT_TRUE(q.push(page(1, i)));
    const std::uint8_t pixels[4] = {1, 2, 3, 4};
    tc::ReadyPage extra = page(100, 99, 4);
    extra.data = pixels;
    EXPECT_FALSE(q.push(std::move(extra)));
    EXPECT_EQ(extra.ticket, 99u);  // NOLINT(bugprone-use-after-move): push leaves it untouched
    EXPECT_EQ(extra.data.data(), pixels);
    EXPECT_EQ(q.size(), 3u);
    EXPECT_EQ(q.capacity(), 3u);
    std::vector<tc::ReadyPage> out;
    q.take_frame(out);
    EXPECT_TRUE(q.push(std::move(extra)));
}

TEST(UploadQueue, DropIfRemovesStalePagesAndKeepsOrder) {
    tc::UploadQueue q(100, 1 << 30, 100);
    for (std::uint64_t i = 0; i < 20; ++i)
        q.push(page(static_cast<float>((i * 7) % 20), i, 100, static_cast<std::uint32_t>(i)));
    // Cancelled: pages with even x.
    EXPECT_EQ(q.drop_if([](const tc::ReadyPage& p) { return p.key.x % 2 == 0; }), 10u);
    EXPECT_EQ(q.size(), 10u);
    EXPECT_EQ(q.queued_bytes(), 1000u);
    EXPECT_EQ(q.drop_if([](const tc::ReadyPage&) { return false; }), 0u);
    std::vector<tc::ReadyPage> out;
    q.take_frame(out);
    ASSERT_EQ(out.size(), 10u);
    for (std::size_t i = 0; i < out.size(); ++i) {
        EXPECT_EQ(out[i].key.x % 2, 1u);
        if (i) {
            EXPECT_GE(out[i - 1].priority, out[i].priority);
        }
    }
}

TEST(UploadQueue, NanPriorityGoesLast) {
    tc::UploadQueue q(100, 1 << 30, 100);
    q.push(page(std::numeric_limits<float>::quiet_NaN(), 0));
    q.push(page(-5, 1));
    q.push(page(3, 2));
    std::vector<tc::ReadyPage> out;
    q.take_frame(out);
    EXPECT_EQ(tickets(out), (std::vector<std::uint64_t>{2, 1, 0}));
}

TEST(UploadQueue, ManyRandomPagesComeOutSorted) {
    tc::UploadQueue q(64, 64 * 1024, 5000);
    std::uint64_t s = 42;
    for (std::uint64_t i = 0; i < 5000; ++i) {
        s = s * 6364136223846793005ull + 1442695040888963407ull;
        ASSERT_TRUE(q.push(page(static_cast<float>(s >> 54), i, 1024)));
    }
    EXPECT_FALSE(q.push(page(1, 9999)));
    std::vector<tc::ReadyPage> all;
    std::size_t frames = 0;
    while (!q.empty()) {
        std::vector<tc::ReadyPage> out;
        const std::size_t n = q.take_frame(out);
        ASSERT_GT(n, 0u);
        ASSERT_LE(n, 64u);
        all.insert(all.end(), out.begin(), out.end());
        ++frames;
    }
    EXPECT_EQ(frames, 5000u / 64 + 1);
    EXPECT_TRUE(std::is_sorted(all.begin(), all.end(), [](const tc::ReadyPage& a, const tc::ReadyPage& b) {
        return a.priority != b.priority ? a.priority > b.priority : a.ticket < b.ticket;
    }));
}

// --- FakeUploader ---

TEST(FakeUploader, RecordsCallsInOrderWithCopies) {
    tc::FakeUploader up;
    tc::PageUploader& renderer = up;
    std::vector<std::uint8_t> rgba(2 * 2 * 4, 7);
    renderer.upload_page(5, tc::PageKey{1, 2, 3, 4}, rgba, 2);
    rgba.assign(rgba.size(), 0);  // the call copied: the record keeps the old bytes
    const std::uint32_t entries[6] = {1, 2, 3, 4, 5, 6};
    renderer.upload_page_table(3, 2, 10, 20, 3, 2, entries);
    renderer.upload_page(6, tc::PageKey{}, std::span<const std::uint8_t>(rgba.data(), 3), 2);  // malformed

    ASSERT_EQ(up.pages().size(), 2u);
    ASSERT_EQ(up.tables().size(), 1u);
    EXPECT_EQ(up.pages()[0].seq, 0u);
    EXPECT_EQ(up.pages()[0].slot, 5u);
    EXPECT_EQ(up.pages()[0].tile_size, 2u);
    EXPECT_EQ(up.pages()[0].data, std::vector<std::uint8_t>(16, 7));
    const auto& t = up.tables()[0];
    EXPECT_EQ(t.seq, 1u);
    EXPECT_EQ(t.texture, 3u);
    EXPECT_EQ(t.level, 2u);
    EXPECT_EQ(t.x0, 10u);
    EXPECT_EQ(t.y0, 20u);
    EXPECT_EQ(t.w, 3u);
    EXPECT_EQ(t.h, 2u);
    EXPECT_EQ(t.entries, (std::vector<std::uint32_t>{1, 2, 3, 4, 5, 6}));
    EXPECT_EQ(up.pages()[1].seq, 2u);
    EXPECT_EQ(up.malformed(), 1u);
    up.clear();
    EXPECT_TRUE(up.pages().empty());
    EXPECT_EQ(up.malformed(), 0u);
}

TEST(FakeUploader, AFrameFromTheQueue) {
    // What the render thread does each frame: take the budget, upload each page, then map it.
    tc::UploadQueue q(2, 1 << 20, 16);
    std::vector<std::uint8_t> staging(3 * 4 * 4 * 4);
    for (std::uint32_t i = 0; i < 3; ++i) {
        std::fill(staging.begin() + i * 64, staging.begin() + (i + 1) * 64, static_cast<std::uint8_t>(i + 1));
        tc::ReadyPage p = page(static_cast<float>(i), i, 64, i);
        p.data = std::span<const std::uint8_t>(staging.data() + i * 64, 64);
        q.push(std::move(p));
    }
    tc::FakeUploader up;
    std::vector<tc::ReadyPage> out;
    q.take_frame(out);
    for (const auto& p : out) {
        up.upload_page(p.slot, p.key, p.data, 4);
        const std::uint32_t entry = p.slot;
        up.upload_page_table(p.key.texture, p.key.level, p.key.x, p.key.y, 1, 1, std::span(&entry, 1));
    }
    ASSERT_EQ(up.pages().size(), 2u);
    EXPECT_EQ(up.pages()[0].slot, 2u);
    EXPECT_EQ(up.pages()[0].data[0], 3);
    EXPECT_EQ(up.pages()[1].slot, 1u);
    EXPECT_LT(up.pages()[0].seq, up.tables()[0].seq);  // data before the mapping
    EXPECT_EQ(up.malformed(), 0u);
    EXPECT_EQ(q.size(), 1u);
}

// --- stats ---

TEST(LatencyHistogram, BucketsCoverEveryValueOnce) {
    using H = tc::LatencyHistogram;
    EXPECT_EQ(H::bucket_of(0), 0u);
    EXPECT_EQ(H::bucket_of(15), 15u);
    EXPECT_EQ(H::bucket_of(16), 16u);
    EXPECT_EQ(H::bucket_of(~std::uint64_t{0}), H::kBuckets - 1);
    for (std::size_t b = 0; b + 1 < H::kBuckets; ++b) {
        ASSERT_EQ(H::bucket_low(b) + H::bucket_width(b), H::bucket_low(b + 1)) << b;
        ASSERT_EQ(H::bucket_of(H::bucket_low(b)), b);
        ASSERT_EQ(H::bucket_of(H::bucket_low(b + 1) - 1), b);
        ASSERT_LE(H::bucket_width(b) * 16, std::max<std::uint64_t>(H::bucket_low(b), 16));
    }
}

TEST(LatencyHistogram, QuantilesWithinBucketError) {
    tc::LatencyHistogram h;
    EXPECT_EQ(h.quantile(0.5), 0.0);
    // 1..10000 ms, uniformly: p50 = 5000, p99 = 9900.
    for (int i = 1; i <= 10000; ++i) h.record_ms(i);
    EXPECT_EQ(h.count(), 10000u);
    EXPECT_NEAR(h.mean_ms(), 5000.5, 1e-9);
    EXPECT_NEAR(h.quantile(0.5), 5000, 5000 * 0.032);
    EXPECT_NEAR(h.quantile(0.99), 9900, 9900 * 0.032);
    EXPECT_EQ(h.quantile(0), 1.0);
    EXPECT_EQ(h.quantile(1), 10000.0);
    EXPECT_EQ(h.min_ms(), 1.0);
    EXPECT_EQ(h.max_ms(), 10000.0);
    // Exact below 16 us.
    tc::LatencyHistogram small;
    for (int i = 0; i < 10; ++i) small.record(std::chrono::microseconds(7));
    EXPECT_EQ(small.quantile(0.5), 0.007);
}

TEST(LatencyHistogram, MergeEqualsRecordingTogether) {
    tc::LatencyHistogram a, b, both;
    for (int i = 0; i < 1000; ++i) {
        const double ms = 0.05 * i * i;
        (i % 3 ? a : b).record_ms(ms);
        both.record_ms(ms);
    }
    a.merge(b);
    EXPECT_EQ(a.count(), both.count());
    EXPECT_EQ(a.quantile(0.9), both.quantile(0.9));
    EXPECT_EQ(a.min_ms(), both.min_ms());
    EXPECT_EQ(a.max_ms(), both.max_ms());
    a.reset();
    EXPECT_EQ(a.count(), 0u);
}

TEST(Stats, FrameJsonAndCsv) {
    tc::FrameStats f;
    f.frame = 12;
    f.pages_wanted = 300;
    f.pages_resident = 250;
    f.pages_requested = 40;
    f.pages_arrived = 30;
    f.pages_uploaded = 16;
    f.pages_evicted = 16;
    f.pages_rescued = 2;
    f.ram_hits[0] = 5;
    f.disk_hits[2] = 3;
    f.network[1] = 22;
    f.bytes_received = 123456;
    f.bytes_uploaded = 16 * 65536;
    f.lod_bias = 0.25f;
    f.fallback_estimate = 0.5f;
    EXPECT_EQ(f.to_json(),
              "{\"frame\":12,\"pages\":{\"wanted\":300,\"resident\":250,\"requested\":40,\"arrived\":30,"
              "\"uploaded\":16,\"evicted\":16,\"rescued\":2},\"hits\":{\"ram\":[5,0,0],\"disk\":[0,0,3],\"network\":[0,22,0]},"
              "\"bytes\":{\"received\":123456,\"uploaded\":1048576},\"lod_bias\":0.25,\"fallback_estimate\":0.5}");
    const std::string header = tc::FrameStats::csv_header();
    const std::string row = f.csv_row();
    EXPECT_EQ(std::count(header.begin(), header.end(), ','), std::count(row.begin(), row.end(), ','));
    EXPECT_EQ(row, "12,300,250,40,30,16,16,5,3,22,123456,1048576,0.25,0.5,2");
    f.fallback_estimate = std::numeric_limits<float>::quiet_NaN();
    EXPECT_NE(f.to_json().find("\"fallback_estimate\":null"), std::string::npos);
    EXPECT_NE(tc::FrameStats{}.to_json().find("\"ram\":[]"), std::string::npos);
}

TEST(Stats, SummaryAcrossFrames) {
    tc::StatsSummary s;
    for (int i = 0; i < 4; ++i) {
        tc::FrameStats f;
        f.pages_wanted = 100 * (i + 1);
        f.pages_requested = 10;
        f.pages_rescued = std::uint32_t(i);
        f.network[3] = 2;
        f.bytes_received = 1000;
        f.lod_bias = 0.25f * i;
        s.add_frame(f);
    }
    for (int i = 1; i <= 100; ++i) s.record_latency(std::chrono::milliseconds(i));
    EXPECT_EQ(s.frames(), 4u);
    EXPECT_EQ(s.pages_requested(), 40u);
    EXPECT_EQ(s.pages_rescued(), 6u);
    EXPECT_EQ(s.network()[3], 8u);
    EXPECT_EQ(s.bytes_received(), 4000u);
    EXPECT_DOUBLE_EQ(s.mean_pages_wanted(), 250.0);
    EXPECT_FLOAT_EQ(s.max_lod_bias(), 0.75f);
    EXPECT_FLOAT_EQ(s.last_lod_bias(), 0.75f);
    EXPECT_DOUBLE_EQ(s.mean_lod_bias(), 0.375);
    EXPECT_NEAR(s.latency().quantile(0.5), 50, 50 * 0.032);
    const std::string j = s.to_json();
    EXPECT_EQ(j.front(), '{');
    EXPECT_EQ(j.back(), '}');
    EXPECT_NE(j.find("\"frames\":4"), std::string::npos);
    EXPECT_NE(j.find("\"network\":[0,0,0,8]"), std::string::npos);
    EXPECT_NE(j.find("\"rescued\":6"), std::string::npos);
    EXPECT_NE(j.find("\"latency_ms\":{\"count\":100,\"mean\":50.5,"), std::string::npos);
    EXPECT_NE(j.find("\"max\":100}"), std::string::npos);
    s.reset();
    EXPECT_EQ(s.frames(), 0u);
    EXPECT_EQ(s.latency().count(), 0u);
}

}  // namespace
