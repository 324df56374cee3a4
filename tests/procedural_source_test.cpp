// The on-demand procedural source (procedural:coords:...): its specs and their errors, and the
// tiles it serves: every texel, borders and the edge overhang included, is coords_texel of its
// clamped level coordinates, at the far corner of a 2^24 - 1 texture as anywhere else.
#include <gtest/gtest.h>

#include <xxhash.h>

#include <algorithm>
#include <random>
#include <thread>

#include "procedural_source.hpp"
#include "transcode.hpp"

namespace {

using namespace std::chrono_literals;
using namespace tessera::client;

std::vector<SourceTile> collect(TileSource& s, std::size_t n) {
    std::vector<SourceTile> out;
    for (int i = 0; i < 1000 && out.size() < n; ++i) {
        s.poll(out);
        if (out.size() < n) std::this_thread::sleep_for(2ms);
    }
    return out;
}

TEST(ProceduralSource, SpecsGiveStoreGeometry) {
    auto big = procedural_store_info("procedural:coords:16777216");
    ASSERT_TRUE(big.ok()) << big.error().message;
    EXPECT_EQ(big->width, 1u << 24);
    EXPECT_EQ(big->height, 1u << 24);
    EXPECT_EQ(big->tile_size(), 256u);
    EXPECT_EQ(big->tile_payload, 248u);
    EXPECT_EQ(big->levels[0].tiles_x, 67'651u);
    EXPECT_EQ(big->level_count(), 18u);
    EXPECT_EQ(big->levels.back().tiles_x, 1u);
    EXPECT_EQ(big->channels, 4u);
    EXPECT_EQ(big->codec, tessera::Codec::raw);

    auto tiled = procedural_store_info("procedural:coords:12345679:1024:8");
    ASSERT_TRUE(tiled.ok()) << tiled.error().message;
    EXPECT_EQ(tiled->tile_payload, 1008u);
    EXPECT_EQ(tiled->border, 8u);
    EXPECT_EQ(tiled->levels[0].tiles_x, 12'248u);  // ceil(12,345,679 / 1008)
    // The version follows the geometry: the defaults spelled out are the same texture.
    auto spelled = procedural_store_info("procedural:coords:16777216:256:4");
    ASSERT_TRUE(spelled.ok());
    EXPECT_EQ(spelled->store_id, big->store_id);
    EXPECT_NE(tiled->store_id, big->store_id);

    auto one = procedural_store_info("procedural:coords:1:64:0");
    ASSERT_TRUE(one.ok()) << one.error().message;
    EXPECT_EQ(one->level_count(), 1u);
}

TEST(ProceduralSource, BadSpecsAreClearErrors) {
    const std::pair<const char*, const char*> bad[] = {
        {"procedural:coords:0", "size must be 1 to 16777216"},
        {"procedural:coords:16777217", "size must be 1 to 16777216"},
        {"procedural:coords:99999999999999999999999", "is not a number"},
        {"procedural:coords:", "is not a number"},
        {"procedural:coords:4k", "is not a number"},
        {"procedural:coords:4096:100", "power of two from 64 to 1024"},
        {"procedural:coords:4096:2048", "power of two from 64 to 1024"},
        {"procedural:coords:4096:32", "power of two from 64 to 1024"},
        {"procedural:coords:4096:256:3", "border must be even and at most 64"},
        {"procedural:coords:4096:256:66", "border must be even and at most 64"},
        {"procedural:coords:4096:256:4:1", "too many fields"},
        {"procedural:terrain:4096", "procedural:terrain is a build input"},
        {"terrain.tsr", "is not a procedural texture"},
    };
    auto src = make_procedural_source(1);
    for (const auto& [spec, why] : bad) {
        auto info = procedural_store_info(spec);
        ASSERT_FALSE(info.ok()) << spec;
        EXPECT_EQ(info.error().code, tessera::Errc::invalid_argument) << spec;
        EXPECT_NE(info.error().message.find(why), std::string::npos) << spec << ": " << info.error().message;
        EXPECT_NE(info.error().message.find(spec), std::string::npos) << "names the spec: " << info.error().message;
        auto bound = src->bind(0, spec);
        ASSERT_FALSE(bound.ok()) << spec;
        EXPECT_EQ(bound.error().message, info.error().message);
    }
}

TEST(ProceduralSource, TexelsTellLevelsAndPositionsApart) {
    // Neighbours, the same place one level up, and the same low bits 4096 texels away all differ.
    std::mt19937 rng(6);
    std::uniform_int_distribution<std::uint32_t> coord(0, (1u << 24) - 1);
    int same = 0;
    for (int i = 0; i < 20000; ++i) {
        const std::uint32_t x = coord(rng), y = coord(rng), level = i % 18;
        const auto t = coords_texel(level, x, y);
        EXPECT_EQ(t[3], 255);
        same += t == coords_texel(level, x ^ 1, y);
        same += t == coords_texel(level, x, y ^ 1);
        same += t == coords_texel(level + 1, x, y);
        same += t == coords_texel(level, x ^ 4096, y);
        same += t == coords_texel(level, x, y ^ 4096);
    }
    // Within 4096-texel regions never; across regions only on a 2^-24 hash collision.
    EXPECT_EQ(same, 0);
}

TEST(ProceduralSource, ServesTheFormulaWithClampedBordersAtTheFarCorner) {
    const std::string spec = "procedural:coords:16777215:64:4";
    auto src = make_procedural_source(2, 16);
    auto info = src->bind(5, spec);
    ASSERT_TRUE(info.ok()) << info.error().message;
    const std::uint32_t levels = info->level_count(), P = info->tile_payload, B = info->border;
    ASSERT_EQ(levels, 20u);  // ceil((2^24 - 1) / 56) = 299,594 pages per side
    std::vector<SourceRequest> reqs;
    for (const std::uint32_t level : {0u, 1u, 7u, levels - 2, levels - 1}) {
        const auto& l = info->levels[level];
        reqs.push_back({PageKey{5, std::uint8_t(level), l.tiles_x - 1, l.tiles_y - 1}, float(level)});  // the far corner
        reqs.push_back({PageKey{5, std::uint8_t(level), l.tiles_x / 2, 0}, float(level)});              // the top edge
    }
    src->set_requests(1, reqs);
    const auto got = collect(*src, reqs.size());
    ASSERT_EQ(got.size(), reqs.size());
    std::vector<std::uint8_t> rgba(rgba8_page_bytes(*info));
    Scratch scratch;
    std::size_t clamped = 0;
    for (const auto& t : got) {
        SCOPED_TRACE(testing::Message() << "tile (" << int(t.page.level) << ", " << t.page.x << ", " << t.page.y << ")");
        ASSERT_EQ(t.status, tessera::TileStatus::ok) << t.message;
        EXPECT_EQ(t.page.texture, 5);
        EXPECT_EQ(t.store_version, info->store_id);
        EXPECT_EQ(t.data.kind, tessera::TileKind::present);
        EXPECT_EQ(t.data.codec, tessera::Codec::raw);
        EXPECT_EQ(t.data.checksum, XXH3_64bits(t.data.payload.data(), t.data.payload.size()));
        ASSERT_EQ(t.data.payload.size(), info->tile_bytes());
        const auto& l = info->levels[t.page.level];
        std::size_t wrong = 0;
        for (std::uint32_t j = 0; j < info->tile_size(); ++j)
            for (std::uint32_t i = 0; i < info->tile_size(); ++i) {
                const std::int64_t x = std::int64_t(t.page.x) * P - B + i, y = std::int64_t(t.page.y) * P - B + j;
                const auto cx = std::clamp<std::int64_t>(x, 0, l.width - 1), cy = std::clamp<std::int64_t>(y, 0, l.height - 1);
                clamped += cx != x || cy != y;
                const auto want = coords_texel(t.page.level, std::uint32_t(cx), std::uint32_t(cy));
                wrong += !std::equal(want.begin(), want.end(), t.data.payload.begin() + (std::ptrdiff_t(j) * info->tile_size() + i) * 4);
            }
        EXPECT_EQ(wrong, 0u);
        // What the runtime makes of it: the same bytes (RGBA8 in, RGBA8 out).
        ASSERT_TRUE(transcode_to_rgba8(*info, t.data.kind, t.data.codec, t.data.payload, rgba, scratch).ok());
        EXPECT_EQ(rgba, t.data.payload);
    }
    EXPECT_GT(clamped, 0u) << "borders past the edges were exercised";
}

TEST(ProceduralSource, OutsideTheTextureAndUnboundTexturesAreErrors) {
    auto src = make_procedural_source(1);
    auto info = src->bind(0, "procedural:coords:1000");
    ASSERT_TRUE(info.ok()) << info.error().message;
    const std::vector<SourceRequest> reqs = {{PageKey{0, 0, info->levels[0].tiles_x, 0}, 3},
                                             {PageKey{0, std::uint8_t(info->level_count()), 0, 0}, 2},
                                             {PageKey{1, 0, 0, 0}, 1}};
    src->set_requests(1, reqs);
    const auto got = collect(*src, reqs.size());
    ASSERT_EQ(got.size(), reqs.size());
    for (const auto& t : got) {
        EXPECT_EQ(t.status, t.page.texture == 1 ? tessera::TileStatus::not_found : tessera::TileStatus::out_of_range) << t.message;
        EXPECT_FALSE(t.message.empty());
        EXPECT_TRUE(t.data.payload.empty());
    }
}

}  // namespace
