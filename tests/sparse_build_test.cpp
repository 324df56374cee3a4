// The tile-driven sparse build (docs/store-format.md, "Sparse stores"): a mosaic manifest's
// images placed on a canvas become the store a dense `--sparse` build of the whole composite
// would make, tile for tile, byte for byte; on a 2^24 canvas only the tiles near the images are
// made and the index follows them; a bad manifest is a clear error that leaves nothing behind.
#include <gtest/gtest.h>

#include <chrono>
#include <cstring>
#include <fstream>

#include "tessera/storage/builder.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/png_encode.hpp"
#include "tessera/storage/sparse_source.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/verify.hpp"
#include "test_util.hpp"

using namespace tessera;
using namespace tessera::storage;
using tessera::test::ScratchDir;

namespace {

struct Image {
    std::uint32_t width = 0, height = 0, channels = 0;
    std::vector<std::uint8_t> texels;
};

// A recognisable u8 image: each texel's bytes from its position and the seed; alpha (when
// `channels` is 4) varies and is 0 in a stripe, so transparent texels occur inside an image too.
Image pattern(std::uint32_t w, std::uint32_t h, std::uint32_t channels, std::uint32_t seed, bool uniform = false) {
    Image im{w, h, channels, std::vector<std::uint8_t>(std::size_t(w) * h * channels)};
    for (std::uint32_t y = 0; y < h; ++y)
        for (std::uint32_t x = 0; x < w; ++x)
            for (std::uint32_t c = 0; c < channels; ++c) {
                std::uint8_t v = uniform ? std::uint8_t(40 + 50 * c) : std::uint8_t((x * 7 + y * 13 + c * 61 + seed * 29) ^ (x >> 3));
                if (c == 3 && !uniform) v = (x % 37 < 3) ? 0 : std::uint8_t(128 + (y & 127));
                im.texels[(std::size_t(y) * w + x) * channels + c] = v;
            }
    return im;
}

void write_png(const std::string& path, const Image& im) {
    PngImage p;
    p.width = im.width;
    p.height = im.height;
    p.channels = im.channels;
    p.colour_space = ColourSpace::srgb;
    p.texels = im.texels;
    auto bytes = encode_png(p);
    ASSERT_TRUE(bytes.ok()) << bytes.error().message;
    test::write_file(path, *bytes);
}

struct Placed {
    std::string name;
    Image image;
    std::uint32_t x = 0, y = 0;
};

void write_manifest(const std::string& path, std::uint64_t w, std::uint64_t h, const std::vector<Placed>& images) {
    std::ofstream f(path);
    f << "{\"width\": " << w << ", \"height\": " << h << ", \"images\": [";
    for (std::size_t i = 0; i < images.size(); ++i)
        f << (i ? ", " : "") << "{\"path\": \"" << images[i].name << "\", \"x\": " << images[i].x << ", \"y\": " << images[i].y << "}";
    f << "]}\n";
}

BuildOptions small_tiles() {
    BuildOptions o;
    o.tile_size = 64;  // 56-texel payloads: several tiles and levels on a small canvas
    o.border = 4;
    o.threads = 2;
    return o;
}

}  // namespace

TEST(SparseBuild, MosaicMakesTheTilesOfADenseSparseBuildOfItsComposite) {
    for (const std::uint32_t channels : {4u, 3u}) {
        SCOPED_TRACE(channels == 4 ? "RGBA images" : "RGB images (the mosaic adds alpha)");
        ScratchDir d;
        constexpr std::uint32_t W = 700, H = 500;
        // Overlapping images (a later one covers an earlier), one in the bottom-right corner (the
        // edge clamp), one large and uniform (uniform tiles inside it).
        const std::vector<Placed> placed = {
            {"a.png", pattern(200, 150, channels, 1), 30, 40},
            {"b.png", pattern(160, 120, channels, 2), 150, 100},
            {"u.png", pattern(200, 200, channels, 3, true), 280, 168},
            {"c.png", pattern(56, 56, channels, 4), 644, 444},
        };
        // The composite: RGBA, transparent (all zero) where no image is.
        std::vector<std::uint8_t> canvas(std::size_t(W) * H * 4, 0);
        for (const Placed& p : placed) {
            write_png(d.file(p.name), p.image);
            for (std::uint32_t y = 0; y < p.image.height; ++y)
                for (std::uint32_t x = 0; x < p.image.width; ++x) {
                    std::uint8_t* o = canvas.data() + ((std::size_t(p.y) + y) * W + p.x + x) * 4;
                    const std::uint8_t* s = p.image.texels.data() + (std::size_t(y) * p.image.width + x) * channels;
                    std::memcpy(o, s, channels);
                    if (channels == 3) o[3] = 255;
                }
        }
        write_png(d.file("composite.png"), Image{W, H, 4, canvas});
        write_manifest(d.file("mosaic.json"), W, H, placed);

        BuildOptions dense_opt = small_tiles();
        dense_opt.sparse = true;
        auto dense = build_store(d.file("composite.png"), d.file("dense.tsr"), dense_opt);
        ASSERT_TRUE(dense.ok()) << dense.error().message;
        std::uint64_t last_done = 0;
        bool monotonic = true;
        auto sparse = build_sparse_store(d.file("mosaic.json"), d.file("sparse.tsr"), small_tiles(), [&](const BuildProgress& p) {
            monotonic = monotonic && p.tiles_done >= last_done && p.tiles_done <= p.tiles_total;
            last_done = p.tiles_done;
        });
        ASSERT_TRUE(sparse.ok()) << sparse.error().message;
        EXPECT_TRUE(monotonic);
        EXPECT_GT(last_done, 0u);

        auto a = StoreReader::open(d.file("dense.tsr"));
        auto b = StoreReader::open(d.file("sparse.tsr"));
        ASSERT_TRUE(a.ok() && b.ok());
        const StoreInfo& ia = (*a)->info();
        const StoreInfo& ib = (*b)->info();
        ASSERT_EQ(ia.level_count(), ib.level_count());
        EXPECT_EQ(ib.channels, 4u);
        EXPECT_TRUE(ib.has_alpha);
        EXPECT_EQ(ib.codec, ia.codec);
        std::uint64_t present = 0, uniform = 0, absent = 0;
        for (std::uint32_t l = 0; l < ia.level_count(); ++l) {
            EXPECT_EQ(ib.levels[l].present, ia.levels[l].present) << "level " << l;
            EXPECT_EQ(ib.levels[l].uniform, ia.levels[l].uniform) << "level " << l;
            for (std::uint32_t y = 0; y < ia.levels[l].tiles_y; ++y)
                for (std::uint32_t x = 0; x < ia.levels[l].tiles_x; ++x) {
                    auto ta = (*a)->read_tile({l, x, y});
                    auto tb = (*b)->read_tile({l, x, y});
                    ASSERT_TRUE(ta.ok() && tb.ok());
                    EXPECT_EQ(tb->kind, ta->kind) << "level " << l << " tile (" << x << "," << y << ")";
                    EXPECT_TRUE(tb->bytes == ta->bytes) << "level " << l << " tile (" << x << "," << y << ")";
                    present += ta->kind == TileKind::present;
                    uniform += ta->kind == TileKind::uniform;
                    absent += ta->kind == TileKind::absent;
                }
        }
        // The comparison means something: every kind of tile occurs.
        EXPECT_GT(present, 0u);
        EXPECT_GT(uniform, 0u);
        EXPECT_GT(absent, 0u);
        EXPECT_TRUE(verify_store(**b).ok());
        const auto left = d.entries();
        EXPECT_EQ(left.size(), placed.size() + 4) << "no spool or core files left behind";
    }
}

TEST(SparseBuild, MosaicAtTheFarCornersOfATwoToTheTwentyFourCanvas) {
    ScratchDir d;
    constexpr std::uint32_t S = 1u << 24, N = 64;
    std::vector<Placed> placed = {
        {"tl.png", pattern(N, N, 4, 1), 0, 0},         {"tr.png", pattern(N, N, 4, 2), S - N, 0},
        {"bl.png", pattern(N, N, 4, 3), 0, S - N},     {"br.png", pattern(N, N, 4, 4), S - N, S - N},
        {"c.png", pattern(N, N, 4, 5), S / 2 - N / 2, S / 2 - N / 2},
    };
    for (const Placed& p : placed) write_png(d.file(p.name), p.image);
    write_manifest(d.file("planet.json"), S, S, placed);
    BuildOptions opt;
    opt.threads = 2;
    const auto t0 = std::chrono::steady_clock::now();
    auto built = build_sparse_store(d.file("planet.json"), d.file("planet.tsr"), opt);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    ASSERT_TRUE(built.ok()) << built.error().message;
    auto r = StoreReader::open(d.file("planet.tsr"));
    ASSERT_TRUE(r.ok()) << r.error().message;
    const StoreInfo& info = (*r)->info();
    ASSERT_EQ(info.width, S);
    EXPECT_EQ(info.version_minor, 2u) << "a sparse index";
    EXPECT_TRUE(info.levels[0].sparse_block_table);
    std::uint64_t present = 0, index = 0;
    for (std::uint32_t lv = 0; lv < info.level_count(); ++lv) {
        const LevelInfo& l = info.levels[lv];
        present += l.present + l.uniform;
        index += l.index_bytes;
        // The images (64 texels, 2^6) are reduced into every level down to level 6; coarser
        // levels average them with ever more transparent canvas, and their alpha rounds to 0
        // within a few more levels, as in a dense build.
        if (lv <= 6) {
            EXPECT_GE(l.present + l.uniform, 5u) << "level " << lv;
        }
    }
    EXPECT_EQ(info.levels.back().present + info.levels.back().uniform, 0u);
    // Level 0: the five images' tiles: top-left 1; top-right and bottom-left 2 (the last tile
    // column and row are 16 texels wide), bottom-right 4, the centre 4 (it straddles tile
    // corners); an index block each.
    EXPECT_EQ(info.levels[0].present + info.levels[0].uniform, 13u);
    EXPECT_EQ(info.levels[0].index_bytes, 5 * (98304 + 24));
    EXPECT_LT(present, 200u);
    EXPECT_LT(index, present * (98304 + 24));
    std::printf("  2^24 mosaic: %llu tiles in %.2f s, file %llu bytes, index %llu bytes\n", static_cast<unsigned long long>(present),
                seconds, static_cast<unsigned long long>(info.file_size), static_cast<unsigned long long>(index));
    // The corner tiles hold the images' texels at their places (payload texel (i, j) of tile
    // (tx, ty) is level texel (tx P + i, ty P + j), at offset B in the tile).
    const std::uint32_t P = info.tile_payload, B = info.border, T = info.tile_size();
    for (const Placed& p : placed) {
        const std::uint32_t tx = p.x / P, ty = p.y / P;
        auto t = (*r)->read_tile({0, tx, ty});
        ASSERT_TRUE(t.ok() && t->kind == TileKind::present) << p.name;
        std::vector<std::uint8_t> texels;
        ASSERT_TRUE(decode_tile(info, *t, texels).ok());
        std::size_t checked = 0, wrong = 0;
        for (std::uint32_t y = p.y; y < p.y + N && y < (ty + 1) * P; ++y)
            for (std::uint32_t x = p.x; x < p.x + N && x < (tx + 1) * P; ++x, ++checked) {
                const std::uint8_t* got = texels.data() + (std::size_t(y - ty * P + B) * T + (x - tx * P + B)) * 4;
                const std::uint8_t* want = p.image.texels.data() + (std::size_t(y - p.y) * N + (x - p.x)) * 4;
                wrong += std::memcmp(got, want, 4) != 0;
            }
        EXPECT_GT(checked, 0u);
        EXPECT_EQ(wrong, 0u) << p.name << " of " << checked;
    }
    EXPECT_EQ((*r)->read_tile({0, 1000, 1000})->kind, TileKind::absent);
    EXPECT_TRUE(verify_store(**r).ok());
}

// The widest canvas the format allows, 2^32 - 1 texels a side, with an image at each end of its
// diagonal: a mosaic is a sparse source, so its index follows the data and is not refused for
// the dense block tables such a canvas would need (several GiB).
TEST(SparseBuild, MosaicOnTheWidestCanvas) {
    ScratchDir d;
    constexpr std::uint32_t S = 0xFFFFFFFFu, N = 64;
    const std::vector<Placed> placed = {{"tl.png", pattern(N, N, 4, 1), 0, 0}, {"br.png", pattern(N, N, 4, 2), S - N, S - N}};
    for (const Placed& p : placed) write_png(d.file(p.name), p.image);
    write_manifest(d.file("widest.json"), S, S, placed);
    BuildOptions opt;
    opt.threads = 2;
    auto built = build_sparse_store(d.file("widest.json"), d.file("widest.tsr"), opt);
    ASSERT_TRUE(built.ok()) << built.error().message;
    auto r = StoreReader::open(d.file("widest.tsr"));
    ASSERT_TRUE(r.ok()) << r.error().message;
    const StoreInfo& info = (*r)->info();
    EXPECT_EQ(info.width, S);
    EXPECT_EQ(info.height, S);
    EXPECT_TRUE(info.levels[0].sparse_block_table);
    const std::uint32_t P = info.tile_payload;
    EXPECT_EQ((*r)->read_tile({0, 0, 0})->kind, TileKind::present);
    EXPECT_EQ((*r)->read_tile({0, (S - 1) / P, (S - 1) / P})->kind, TileKind::present);
    EXPECT_EQ((*r)->read_tile({0, 12345, 67890})->kind, TileKind::absent);
    EXPECT_LT(info.file_size, 64u << 20);
    EXPECT_TRUE(verify_store(**r).ok());
}

TEST(SparseBuild, BadManifestsAreClearErrorsAndLeaveNothingBehind) {
    ScratchDir d;
    write_png(d.file("a.png"), pattern(40, 30, 4, 1));
    write_png(d.file("rgb.png"), pattern(40, 30, 3, 2));
    const std::string a = "{\"path\": \"a.png\", \"x\": 0, \"y\": 0}";
    const struct {
        std::string json, needle;
    } cases[] = {
        {"not json", "not valid JSON"},
        {"[1, 2]", "not a JSON object"},
        {"{\"height\": 100, \"images\": [" + a + "]}", "has no \"width\""},
        {"{\"width\": -5, \"height\": 100, \"images\": [" + a + "]}", "\"width\" must be an integer"},
        {"{\"width\": \"big\", \"height\": 100, \"images\": [" + a + "]}", "\"width\" must be an integer"},
        {"{\"width\": 4294967296, \"height\": 100, \"images\": [" + a + "]}", "\"width\" must be an integer"},
        {"{\"width\": 0, \"height\": 100, \"images\": [" + a + "]}", "canvas is empty"},
        {"{\"width\": 100, \"height\": 100}", "\"images\" must be a non-empty array"},
        {"{\"width\": 100, \"height\": 100, \"images\": []}", "\"images\" must be a non-empty array"},
        {"{\"width\": 100, \"height\": 100, \"images\": [{\"x\": 0, \"y\": 0}]}", "image 0: \"path\""},
        {"{\"width\": 100, \"height\": 100, \"images\": [{\"path\": \"a.png\", \"y\": 0}]}", "image 0: has no \"x\""},
        {"{\"width\": 100, \"height\": 100, \"images\": [{\"path\": \"a.png\", \"x\": 61, \"y\": 0}]}", "does not fit the 100 x 100 canvas"},
        {"{\"width\": 100, \"height\": 100, \"images\": [" + a + ", {\"path\": \"missing.png\", \"x\": 0, \"y\": 0}]}", "image 1"},
        {"{\"width\": 100, \"height\": 100, \"images\": [" + a + ", {\"path\": \"rgb.png\", \"x\": 0, \"y\": 0}]}",
         "does not have image 0's channels"},
    };
    for (const auto& c : cases) {
        SCOPED_TRACE(c.json);
        {
            std::ofstream f(d.file("m.json"));
            f << c.json;
        }
        auto r = build_sparse_store(d.file("m.json"), d.file("out.tsr"), small_tiles());
        ASSERT_FALSE(r.ok());
        EXPECT_NE(r.error().message.find(c.needle), std::string::npos) << r.error().message;
        EXPECT_NE(r.error().message.find("m.json"), std::string::npos) << "the message names the manifest: " << r.error().message;
        EXPECT_EQ(d.entries().size(), 3u) << "nothing written beside the output";
    }
    EXPECT_FALSE(build_sparse_store(d.file("none.json"), d.file("out.tsr"), small_tiles()).ok());
    // --sparse and --visibility do not apply.
    BuildOptions o = small_tiles();
    o.sparse = true;
    {
        std::ofstream f(d.file("m.json"));
        f << "{\"width\": 100, \"height\": 100, \"images\": [" << a << "]}";
    }
    EXPECT_FALSE(build_sparse_store(d.file("m.json"), d.file("out.tsr"), o).ok());
    ASSERT_TRUE(build_sparse_store(d.file("m.json"), d.file("out.tsr"), small_tiles()).ok());
}

TEST(SparseBuild, TesseraBuildTakesAMosaicManifest) {
    ScratchDir d;
    write_png(d.file("a.png"), pattern(300, 200, 4, 1));
    write_manifest(d.file("m.json"), 1u << 20, 1u << 19, {{"a.png", Image{}, 5000, 7000}});
    auto r = test::run_tessera("build " + d.file("m.json") + " -o " + d.file("m.tsr") + " --tile-size 128");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_NE(r.out.find("present tiles of"), std::string::npos) << r.out;
    auto i = test::run_tessera("inspect " + d.file("m.tsr"));
    ASSERT_EQ(i.exit_code, 0) << i.out;
    EXPECT_NE(i.out.find("format 1.2"), std::string::npos) << i.out;
    EXPECT_NE(i.out.find("index"), std::string::npos) << i.out;
    auto v = test::run_tessera("verify " + d.file("m.tsr"));
    EXPECT_EQ(v.exit_code, 0) << v.out;
    // A bad manifest: a message and a non-zero exit, no store.
    write_manifest(d.file("bad.json"), 100, 100, {{"a.png", Image{}, 0, 0}});
    auto bad = test::run_tessera("build " + d.file("bad.json") + " -o " + d.file("bad.tsr"));
    EXPECT_NE(bad.exit_code, 0);
    EXPECT_NE(bad.out.find("does not fit"), std::string::npos) << bad.out;
    EXPECT_FALSE(std::filesystem::exists(d.file("bad.tsr")));
}
