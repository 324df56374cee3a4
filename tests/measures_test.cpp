// The viewer's temporal measure (docs/viewer.md, "Measures"): popping is a frame-to-frame change
// the reference renderer does not make over the same two camera poses.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <cstdint>
#include <vector>

#include "server_process.hpp"  // slurp
#include "tessera/client/measures.hpp"
#include "test_util.hpp"


namespace {

using Image = std::vector<std::uint8_t>;

// A w x h RGBA image of one colour, covered (alpha 255) or not (alpha 0).
Image solid(std::uint32_t w, std::uint32_t h, std::uint8_t v, bool covered = true) {
    Image img(std::size_t(w) * h * 4, v);
    for (std::size_t i = 3; i < img.size(); i += 4) img[i] = covered ? 255 : 0;
    return img;
}

void set(Image& img, std::uint32_t w, std::uint32_t x, std::uint32_t y, std::uint8_t r, std::uint8_t g, std::uint8_t b) {
    auto* p = img.data() + (std::size_t(y) * w + x) * 4;
    p[0] = r;
    p[1] = g;
    p[2] = b;
}

TEST(PopMeasure, AChangeTheReferenceAlsoMakesIsNotAPop) {
    const std::uint32_t w = 8, h = 4;
    // The camera moved: every pixel brightened by 40 in both renderers.
    const auto before = solid(w, h, 100), after = solid(w, h, 140);
    const auto c = tessera::client::count_pops(before, after, before, after, w, h);
    EXPECT_EQ(c.pixels, 32u);
    EXPECT_EQ(c.popped, 0u);
    EXPECT_EQ(c.largest, 0);
}

TEST(PopMeasure, AChangeOnlyTheVtMakesIsAPopBeyondTheThreshold) {
    const std::uint32_t w = 8, h = 4;
    const auto ref = solid(w, h, 100);
    auto before = ref, after = ref;
    set(after, w, 2, 1, 100, 130, 100);  // a finer page arrived: one pixel's green jumps by 30
    set(after, w, 5, 3, 110, 100, 100);  // and another's red by 10: under the threshold
    const auto c = tessera::client::count_pops(before, after, ref, ref, w, h, 16);
    EXPECT_EQ(c.pixels, 32u);
    EXPECT_EQ(c.popped, 1u);
    EXPECT_EQ(c.largest, 30);
    EXPECT_DOUBLE_EQ(c.rate(), 1.0 / 32.0);
    // The reference changing the other way doubles the difference.
    auto ref_after = ref;
    set(ref_after, w, 5, 3, 90, 100, 100);
    const auto d = tessera::client::count_pops(before, after, ref, ref_after, w, h, 16);
    EXPECT_EQ(d.popped, 2u);
    EXPECT_EQ(d.largest, 30);
}

TEST(PopMeasure, OnlyPixelsTheReferenceCoversInBothFramesCount) {
    const std::uint32_t w = 4, h = 2;
    auto ref_before = solid(w, h, 0), ref_after = solid(w, h, 0);
    for (std::size_t i = 3; i < ref_before.size(); i += 16) ref_before[i] = 0;  // pixels 0 and 4: sky before
    const auto before = solid(w, h, 0), after = solid(w, h, 200);
    const auto c = tessera::client::count_pops(before, after, ref_before, ref_after, w, h);
    EXPECT_EQ(c.pixels, 6u);
    EXPECT_EQ(c.popped, 6u);
    EXPECT_EQ(c.largest, 200);
    // Wrong sizes count nothing.
    const auto bad = tessera::client::count_pops(before, Image(4), ref_before, ref_after, w, h);
    EXPECT_EQ(bad.pixels, 0u);
    EXPECT_EQ(bad.rate(), 0.0);
}

// `tessera view --psnr-every 1` measures every pair of consecutive frames (and every run, each
// page's time to detail). From an empty pool the
// first pages replace the no-data colour over most of the frame: that pops. With the first view
// loaded before the path starts (the default warm-up) and the path moving slowly, nothing does.
TEST(PopMeasure, TheViewerReportsPoppingWhenPagesArriveOnScreen) {
    using tessera::test::run_tessera;
    tessera::test::ScratchDir dir;
    const std::string store = tessera::test::cached_store("procedural:terrain:512 --tile-size 128", "terrain.tsr");
    const std::string view = "view --store " + store + " --headless --size 96x64 --frames 40 --psnr-every 1 --pool 256 ";
    auto cold = run_tessera(view + "--no-warmup --stats " + dir.file("cold.json"));
    ASSERT_EQ(cold.exit_code, 0) << cold.out;
    EXPECT_NE(cold.out.find("popping       mean "), std::string::npos) << cold.out;
    const auto c = nlohmann::json::parse(tessera::test::slurp(dir.file("cold.json")))["popping"];
    EXPECT_EQ(c["pairs"], 39);
    EXPECT_GT(c["max_rate"].get<double>(), 0.3) << c;
    EXPECT_GE(c["largest"].get<int>(), 100) << c;
    // Time to detail: every page mapped counts, from the frame whose feedback first wanted it.
    EXPECT_NE(cold.out.find("time to detail p50 "), std::string::npos) << cold.out;
    const auto t = nlohmann::json::parse(tessera::test::slurp(dir.file("cold.json")))["summary"]["time_to_detail_frames"];
    const auto uploaded = nlohmann::json::parse(tessera::test::slurp(dir.file("cold.json")))["summary"]["pages"]["uploaded"];
    EXPECT_EQ(t["count"], uploaded) << t;
    EXPECT_GE(t["p50"].get<double>(), 1.0) << t;
    EXPECT_GE(t["max"].get<double>(), t["p50"].get<double>()) << t;

    auto warm = run_tessera(view + "--stats " + dir.file("warm.json"));
    ASSERT_EQ(warm.exit_code, 0) << warm.out;
    const auto w = nlohmann::json::parse(tessera::test::slurp(dir.file("warm.json")))["popping"];
    EXPECT_EQ(w["pairs"], 39);
    EXPECT_LT(w["max_rate"].get<double>(), 0.001) << w;
    // Without the reference there is nothing to compare with: no popping line.
    auto none = run_tessera("view --store " + store + " --headless --size 96x64 --frames 10 --pool 256");
    ASSERT_EQ(none.exit_code, 0) << none.out;
    EXPECT_EQ(none.out.find("popping"), std::string::npos) << none.out;
}

}  // namespace
