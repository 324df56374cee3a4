// Feedback traces (`tessera view --trace`, replayed by the load tester): round trip, atomic write,
// and every kind of damage is an error, never wrong ids.
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>

#include <sys/resource.h>

#include "tessera/client/feedback_trace.hpp"
#include "test_util.hpp"

namespace {

using namespace tessera::client;
namespace fs = std::filesystem;

TraceFrame frame(std::uint64_t n, std::uint32_t w, std::uint32_t h, std::mt19937_64& rng) {
    TraceFrame f;
    f.frame = n;
    f.time_s = double(n) / 60.0;
    f.bias = 0.25f * float(n % 4);
    f.width = w;
    f.height = h;
    f.ids.resize(std::size_t(w) * h);
    for (auto& id : f.ids)
        id = rng() % 5 == 0 ? kNoPage : pack_feedback(PageKey{1, std::uint8_t(rng() % 20), std::uint32_t(rng() % 5000),
                                                                  std::uint32_t(rng() % 5000)});
    return f;
}

TEST(FeedbackTrace, RoundTripsExactly) {
    tessera::test::ScratchDir dir;
    std::mt19937_64 rng(7);
    std::vector<TraceFrame> frames;
    for (int i = 0; i < 5; ++i) frames.push_back(frame(i, 160, 90, rng));
    frames.push_back(frame(99, 1, 1, rng));
    auto w = TraceWriter::create(dir.file("t.trace"));
    ASSERT_TRUE(w.ok());
    for (const auto& f : frames) ASSERT_TRUE((*w)->write(f).ok());
    EXPECT_FALSE(fs::exists(dir.file("t.trace"))) << "visible before close";
    ASSERT_TRUE((*w)->close().ok());
    auto back = read_trace(dir.file("t.trace"));
    ASSERT_TRUE(back.ok()) << back.error().message;
    ASSERT_EQ(back->size(), frames.size());
    for (std::size_t i = 0; i < frames.size(); ++i) {
        EXPECT_EQ((*back)[i].frame, frames[i].frame);
        EXPECT_EQ((*back)[i].time_s, frames[i].time_s);
        EXPECT_EQ((*back)[i].bias, frames[i].bias);
        EXPECT_EQ((*back)[i].width, frames[i].width);
        EXPECT_EQ((*back)[i].ids, frames[i].ids);
    }
}

TEST(FeedbackTrace, AnAbandonedWriterLeavesNothing) {
    tessera::test::ScratchDir dir;
    std::mt19937_64 rng(1);
    {
        auto w = TraceWriter::create(dir.file("t.trace"));
        ASSERT_TRUE(w.ok());
        ASSERT_TRUE((*w)->write(frame(0, 8, 8, rng)).ok());
    }
    EXPECT_TRUE(fs::is_empty(dir.path()));
    EXPECT_FALSE(TraceWriter::create(dir.path()).ok()) << "a directory is not a trace file";
}

TEST(FeedbackTrace, DamageIsAnErrorNeverWrongIds) {
    tessera::test::ScratchDir dir;
    std::mt19937_64 rng(3);
    auto w = TraceWriter::create(dir.file("t.trace"));
    ASSERT_TRUE(w.ok());
    for (int i = 0; i < 3; ++i) ASSERT_TRUE((*w)->write(frame(i, 32, 16, rng)).ok());
    ASSERT_TRUE((*w)->close().ok());
    std::ifstream in(dir.file("t.trace"), std::ios::binary);
    const std::string good((std::istreambuf_iterator<char>(in)), {});
    auto write = [&](const std::string& bytes) {
        std::ofstream(dir.file("bad.trace"), std::ios::binary) << bytes;
        return read_trace(dir.file("bad.trace"));
    };
    // Every flipped byte past the header, and every truncation point past the header, is an error
    // (a truncation exactly between frames reads as a shorter trace, which is sound).
    std::size_t errors = 0, cut_frames = 0;
    for (std::size_t i = 16; i < good.size(); i += 7) {
        std::string bad = good;
        bad[i] = char(bad[i] ^ 0x5A);
        auto r = write(bad);
        if (!r.ok()) ++errors;
        else ADD_FAILURE() << "flip at " << i << " was not detected";
    }
    EXPECT_GT(errors, 10u);
    for (std::size_t n = 16; n < good.size(); n += 13) {
        auto r = write(good.substr(0, n));
        if (r.ok()) {
            ++cut_frames;
            EXPECT_LT(r->size(), 3u);
        }
    }
    EXPECT_LE(cut_frames, 2u) << "only cuts exactly between frames read as sound";
    EXPECT_FALSE(write("").ok());
    EXPECT_FALSE(write("TSRTRACE").ok());
    EXPECT_FALSE(write(good.substr(0, 16)).ok()) << "no frames";
    EXPECT_FALSE(write("not a trace at all, just text").ok());
    EXPECT_FALSE(read_trace(dir.file("missing.trace")).ok());
}

// A frame's header fields cannot make the reader allocate what the file does not hold: a
// compressed size past the file's end, sides larger than any feedback buffer, or a size whose
// ids the zstd frame does not hold, each an error before any buffer is sized from it (a compressed
// size of 2^32 - 1 made the reader take 4.2 GB, 16384x16384 2.1 GB).
TEST(FeedbackTrace, HeaderFieldsCannotSizeTheReader) {
    tessera::test::ScratchDir dir;
    std::mt19937_64 rng(9);
    auto w = TraceWriter::create(dir.file("t.trace"));
    ASSERT_TRUE(w.ok());
    ASSERT_TRUE((*w)->write(frame(0, 32, 16, rng)).ok());
    EXPECT_FALSE((*w)->write(frame(1, 8193, 1, rng)).ok()) << "wider than any feedback buffer";
    ASSERT_TRUE((*w)->close().ok());
    std::ifstream in(dir.file("t.trace"), std::ios::binary);
    const std::string good((std::istreambuf_iterator<char>(in)), {});
    // The first frame's header after the file's 16 bytes: frame u64, time f64, bias f32, then
    // width, height and the compressed size, u32 each.
    constexpr std::size_t kWidth = 16 + 20, kHeight = kWidth + 4, kCompressed = kHeight + 4;
    auto patched = [&](std::size_t at, std::uint32_t v) {
        std::string bad = good;
        std::memcpy(bad.data() + at, &v, 4);
        std::ofstream(dir.file("bad.trace"), std::ios::binary) << bad;
        return read_trace(dir.file("bad.trace"));
    };
    const auto peak_kib = [] {
        rusage u{};
        ::getrusage(RUSAGE_SELF, &u);
        return u.ru_maxrss;
    };
    const long before = peak_kib();
    auto r = patched(kCompressed, 0xFFFFFFFFu);
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find("truncated"), std::string::npos) << r.error().message;
    r = patched(kWidth, 16384);
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find("bad size"), std::string::npos) << r.error().message;
    std::string big = good;
    const std::uint32_t side = 8192;
    std::memcpy(big.data() + kWidth, &side, 4);
    std::memcpy(big.data() + kHeight, &side, 4);
    std::ofstream(dir.file("big.trace"), std::ios::binary) << big;
    r = read_trace(dir.file("big.trace"));
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find("corrupt data"), std::string::npos) << r.error().message;
    EXPECT_LT(peak_kib() - before, 64 * 1024) << "KiB of peak resident memory taken by reading damaged headers";
}

}  // namespace
