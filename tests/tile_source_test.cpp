// The local store source: reads .tsr files directly, highest priority first, and a new request
// set replaces the old one (requests not in it are not served).
#include <gtest/gtest.h>

#include <set>
#include <thread>

#include "tessera/client/tile_source.hpp"
#include "tessera/storage/store_reader.hpp"
#include "test_util.hpp"

namespace {

using namespace std::chrono_literals;
using namespace tessera::client;

class LocalSource : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        dir_ = new tessera::test::ScratchDir();
        path_ = dir_->file("t.tsr");
        auto r = tessera::test::run_tessera("build procedural:terrain:2000 --codec zstd --quiet -o " + path_);
        ASSERT_EQ(r.exit_code, 0) << r.out;
    }
    static void TearDownTestSuite() { delete dir_; }
    static std::vector<SourceTile> collect(TileSource& s, std::size_t n) {
        std::vector<SourceTile> out;
        for (int i = 0; i < 500 && out.size() < n; ++i) {
            s.poll(out);
            if (out.size() < n) std::this_thread::sleep_for(2ms);
        }
        return out;
    }
    static tessera::test::ScratchDir* dir_;
    static std::string path_;
};
tessera::test::ScratchDir* LocalSource::dir_ = nullptr;
std::string LocalSource::path_;

TEST_F(LocalSource, ServesTheStoredBytesHighestPriorityFirst) {
    auto reader = tessera::storage::StoreReader::open(path_);
    ASSERT_TRUE(reader.ok());
    auto src = make_local_store_source(1, 64);
    auto info = src->bind(3, path_);
    ASSERT_TRUE(info.ok()) << info.error().message;
    EXPECT_EQ(info->store_id, (*reader)->info().store_id);
    std::vector<SourceRequest> reqs;
    for (std::uint32_t i = 0; i < 8; ++i) reqs.push_back({PageKey{3, 0, i, 0}, float(i)});
    src->set_requests(1, reqs);
    const auto got = collect(*src, reqs.size());
    ASSERT_EQ(got.size(), reqs.size());
    for (const auto& t : got) {
        EXPECT_EQ(t.status, tessera::TileStatus::ok) << t.message;
        EXPECT_EQ(t.page.texture, 3);
        auto expect = (*reader)->read_tile({0, t.page.x, 0});
        ASSERT_TRUE(expect.ok());
        EXPECT_EQ(t.data.payload, expect->bytes);
        EXPECT_EQ(t.data.checksum, expect->checksum);
        EXPECT_EQ(t.store_version, (*reader)->info().store_id);
    }
    // One reader, all requests queued before it started: highest priority first (x = 7 first).
    EXPECT_EQ(got.front().page.x, 7u);
}

TEST_F(LocalSource, ANewRequestSetReplacesTheOld) {
    auto src = make_local_store_source(1, 2);  // a tiny buffer: most of the first set waits
    ASSERT_TRUE(src->bind(0, path_).ok());
    std::vector<SourceRequest> first, second;
    for (std::uint32_t i = 0; i < 9; ++i) first.push_back({PageKey{0, 0, i, 1}, 1.0f});
    for (std::uint32_t i = 0; i < 9; ++i) second.push_back({PageKey{0, 0, i, 5}, 1.0f});
    src->set_requests(1, first);
    std::this_thread::sleep_for(50ms);  // the buffer fills, the reader waits
    src->set_requests(2, second);
    const auto got = collect(*src, second.size());
    std::size_t stale = 0, fresh = 0;
    for (const auto& t : got) (t.page.y == 1 ? stale : fresh)++;
    EXPECT_EQ(fresh, second.size());
    EXPECT_EQ(stale, 0u) << "tiles of the superseded set were delivered";
    std::vector<SourceTile> more;
    std::this_thread::sleep_for(50ms);
    src->poll(more);
    EXPECT_TRUE(more.empty());
}

TEST_F(LocalSource, MissingStoreAndUnboundTexture) {
    auto src = make_local_store_source();
    EXPECT_FALSE(src->bind(0, dir_->file("missing.tsr")).ok());
    const SourceRequest r{PageKey{9, 0, 0, 0}, 1.0f};
    src->set_requests(1, std::span<const SourceRequest>(&r, 1));
    const auto got = collect(*src, 1);
    ASSERT_EQ(got.size(), 1u);
    EXPECT_NE(got[0].status, tessera::TileStatus::ok);
    EXPECT_FALSE(got[0].message.empty());
}

}  // namespace
