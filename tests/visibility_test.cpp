// `tessera build --visibility` (docs/visibility.md): the level-0 tiles a set of camera paths never
// wants over the flat terrain are written absent, nothing else changes.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>

#include "tessera/scene/cpu_feedback.hpp"
#include "tessera/scene/path.hpp"
#include "tessera/scene/visibility.hpp"
#include "tessera/storage/store_reader.hpp"
#include "test_util.hpp"

namespace {

using tessera::test::run_tessera;
using tessera::test::ScratchDir;
namespace st = tessera::storage;
namespace sc = tessera::scene;

// Low over one corner of a 2048 x 2048 terrain, looking along +x: wants a few level-0 pages only.
constexpr const char* kPath =
    "# tessera camera path v1\n"
    "fov 60\n"
    "0.0  200 300 60  0 -25\n"
    "1.0  500 400 60  10 -25\n";

std::string read_all(const std::string& f) {
    std::ifstream in(f, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), {}};
}

class Visibility : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        dir_ = new ScratchDir();
        path_file_ = dir_->file("corner.path");
        std::ofstream(path_file_) << kPath;
        full_ = dir_->file("full.tsr");
        auto r = run_tessera("build procedural:terrain:2048 --tile-size 128 --quiet -o " + full_);
        ASSERT_EQ(r.exit_code, 0) << r.out;
    }
    static void TearDownTestSuite() { delete dir_; }
    static ScratchDir* dir_;
    static std::string path_file_, full_;
};
ScratchDir* Visibility::dir_ = nullptr;
std::string Visibility::path_file_, Visibility::full_;

TEST_F(Visibility, KeepsExactlyTheWantedLevel0PagesAndTheirNeighbours) {
    const std::string out = dir_->file("vis.tsr");
    auto r = run_tessera("build procedural:terrain:2048 --tile-size 128 -o " + out + " --visibility " + path_file_ +
                         " --visibility-view 320x180 --visibility-fps 10");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_NE(r.out.find("level-0 tiles kept"), std::string::npos) << r.out;

    auto full = st::StoreReader::open(full_);
    auto vis = st::StoreReader::open(out);
    ASSERT_TRUE(full.ok() && vis.ok());
    const auto& info = (*vis)->info();

    // Expected, independently: cpu_feedback of every frame (t = 0, 0.1, ..., 1.0), 320x180 view,
    // 40x23 feedback, level-0 pages and their 8 neighbours.
    auto path = sc::CameraPath::parse(kPath, "corner");
    ASSERT_TRUE(path.ok());
    const sc::VtGeometry geo{info.width, info.height, info.tile_payload, info.level_count()};
    sc::CpuFeedbackParams p;
    p.main_width = 320;
    p.main_height = 180;
    p.fb_width = 40;
    p.fb_height = 23;
    std::set<std::pair<std::int64_t, std::int64_t>> wanted;
    std::vector<tessera::FeedbackId> ids;
    for (int f = 0; f <= 10; ++f) {
        sc::cpu_feedback(path->at(f / 10.0), geo, p, ids);
        for (auto id : ids) {
            if (id == tessera::kNoPage) continue;
            const auto k = tessera::unpack_feedback(id);
            if (k.level != 0) continue;
            for (int dy = -1; dy <= 1; ++dy)
                for (int dx = -1; dx <= 1; ++dx) wanted.emplace(std::int64_t(k.x) + dx, std::int64_t(k.y) + dy);
        }
    }
    ASSERT_FALSE(wanted.empty());

    std::uint64_t kept = 0, dropped = 0;
    for (std::uint32_t l = 0; l < info.level_count(); ++l) {
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                auto a = (*full)->read_tile({l, x, y});
                auto b = (*vis)->read_tile({l, x, y});
                ASSERT_TRUE(a.ok() && b.ok());
                const bool keep = l != 0 || wanted.contains({x, y});
                if (keep) {
                    EXPECT_EQ(a->kind, b->kind) << l << " " << x << " " << y;
                    EXPECT_EQ(a->bytes, b->bytes) << l << " " << x << " " << y;
                    kept += l == 0;
                } else {
                    EXPECT_EQ(b->kind, tessera::TileKind::absent) << x << " " << y;
                    ++dropped;
                }
            }
    }
    EXPECT_GT(kept, 0u);
    EXPECT_GT(dropped, kept) << "the path sees a corner only";
    EXPECT_NE(r.out.find("dropped " + std::to_string(dropped)), std::string::npos) << r.out;

    // The library's mask is the same set.
    auto paths = sc::parse_path_list(path_file_, *sc::visibility_terrain(2048, 2048));
    ASSERT_TRUE(paths.ok()) << paths.error().message;
    sc::VisibilityOptions vo;
    vo.view_width = 320;
    vo.view_height = 180;
    vo.fps = 10;
    const auto mask = sc::level0_mask(*paths, geo, vo);
    EXPECT_EQ(mask.count(0), kept);

    // Deterministic: a second build is byte-identical (store ids come from the content).
    const std::string again = dir_->file("vis2.tsr");
    r = run_tessera("build procedural:terrain:2048 --tile-size 128 --quiet -o " + again + " --visibility " + path_file_ +
                    " --visibility-view 320x180 --visibility-fps 10 --threads 3");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_TRUE(read_all(out) == read_all(again)) << "two builds differ";
}

TEST_F(Visibility, BuiltinPathsAndLists) {
    const std::string out = dir_->file("flyover.tsr");
    auto r = run_tessera("build procedural:terrain:2048 --tile-size 128 -o " + out + " --visibility flyover," + path_file_ +
                         " --visibility-fps 2");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_NE(r.out.find("level-0 tiles kept"), std::string::npos) << r.out;
}

TEST_F(Visibility, BadValuesAreClearErrorsAndLeaveNothing) {
    const std::string out = dir_->file("bad.tsr");
    const std::string base = "build procedural:terrain:2048 --tile-size 128 --quiet -o " + out + " ";
    struct Case {
        std::string args, message;
    };
    for (const Case& c : std::vector<Case>{
             {"--visibility nosuch", "'nosuch' is neither a built-in path"},
             {"--visibility flyover,", "empty path name"},
             {"--visibility " + dir_->file("missing.path"), "neither a built-in path"},
             {"--visibility flyover --visibility-fps 0", "--visibility-fps must be above 0"},
             {"--visibility flyover --visibility-view 12", "--visibility-view must be WxH"},
             {"--visibility flyover --visibility-view 0x10", "--visibility-view must be WxH"},
             {"--visibility-fps 10", "need --visibility"},
         }) {
        auto r = run_tessera(base + c.args);
        EXPECT_EQ(r.exit_code, 2) << c.args << "\n" << r.out;
        EXPECT_NE(r.out.find(c.message), std::string::npos) << c.args << "\n" << r.out;
        EXPECT_FALSE(std::filesystem::exists(out)) << c.args;
    }
    // A malformed path file: its own error, naming the file.
    const std::string broken = dir_->file("broken.path");
    std::ofstream(broken) << "0.0 1 2 3 4\n";
    auto r = run_tessera(base + "--visibility " + broken);
    EXPECT_EQ(r.exit_code, 2) << r.out;
    EXPECT_NE(r.out.find("broken.path"), std::string::npos) << r.out;
    EXPECT_FALSE(std::filesystem::exists(out));
}

}  // namespace
