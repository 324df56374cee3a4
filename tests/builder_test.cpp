// The builder against an independent reference pyramid: exact for lossless codecs, PSNR for JPEG;
// borders; sparse, uniform and deduplicated tiles; determinism; image file inputs; bounded memory.
#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <random>
#include <set>

#include "reference_pyramid.hpp"
#include "tessera/storage/builder.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/verify.hpp"
#include "test_util.hpp"

using namespace tessera;
using namespace tessera::storage;
using tessera::test::RefImage;
using tessera::test::ScratchDir;

namespace {

// A source over an image in memory.
class MemorySource final : public ImageSource {
public:
    MemorySource(RefImage im, ColourSpace cs, bool alpha) : im_(std::move(im)) {
        info_.width = im_.width;
        info_.height = im_.height;
        info_.channels = im_.channels;
        info_.sample_type = im_.type;
        info_.colour_space = cs;
        info_.has_alpha = alpha;
        info_.description = "memory image";
    }
    const SourceInfo& info() const override { return info_; }
    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const ParallelFor&) override {
        const std::size_t row = std::size_t(im_.width) * im_.texel_bytes();
        std::memcpy(dst, im_.bytes.data() + y0 * row, count * row);
        return {};
    }

private:
    RefImage im_;
    SourceInfo info_;
};

template <class T>
void set(RefImage& im, std::size_t i, T v) {
    std::memcpy(im.bytes.data() + i * sizeof(T), &v, sizeof(T));
}

RefImage make_image(std::uint32_t w, std::uint32_t h, std::uint32_t c, SampleType t) {
    RefImage im;
    im.width = w;
    im.height = h;
    im.channels = c;
    im.type = t;
    im.bytes.resize(std::size_t(w) * h * im.texel_bytes());
    return im;
}

// Smooth gradients plus noise: every level has structure, nothing is uniform by accident.
RefImage test_pattern(std::uint32_t w, std::uint32_t h, std::uint32_t c, SampleType t, std::uint32_t seed) {
    RefImage im = make_image(w, h, c, t);
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> noise(0.0f, 1.0f);
    for (std::uint32_t y = 0; y < h; ++y)
        for (std::uint32_t x = 0; x < w; ++x)
            for (std::uint32_t ch = 0; ch < c; ++ch) {
                const float base = 0.5f + 0.4f * std::sin(float(x) * (0.013f + 0.007f * ch) + float(y) * 0.021f);
                const float v = std::clamp(0.8f * base + 0.2f * noise(rng), 0.0f, 1.0f);
                const std::size_t i = (std::size_t(y) * w + x) * c + ch;
                switch (t) {
                    case SampleType::u8: set<std::uint8_t>(im, i, static_cast<std::uint8_t>(v * 255.0f + 0.5f)); break;
                    case SampleType::u16: set<std::uint16_t>(im, i, static_cast<std::uint16_t>(v * 65535.0f + 0.5f)); break;
                    case SampleType::f16: {
                        // Exactly representable halves: multiples of 1/1024 in [0, 1].
                        const float q = std::round(v * 1024.0f) / 1024.0f;
                        std::uint32_t bits;
                        std::memcpy(&bits, &q, 4);
                        std::uint16_t hbits = 0;
                        if (q != 0.0f) hbits = static_cast<std::uint16_t>((((bits >> 23) & 0xff) - 112) << 10 | ((bits >> 13) & 0x3ff));
                        set<std::uint16_t>(im, i, hbits);
                        break;
                    }
                    case SampleType::f32: set<float>(im, i, v * 4.0f - 1.0f); break;  // HDR-ish, negative too
                }
            }
    return im;
}

struct Built {
    std::shared_ptr<StoreReader> reader;
    std::vector<RefImage> ref;
};

Built build_and_reference(const RefImage& im, ColourSpace cs, bool alpha, const BuildOptions& opt, const std::string& out) {
    MemorySource src(im, cs, alpha);
    auto r = build_store(src, out, opt);
    EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message);
    auto reader = StoreReader::open(out);
    EXPECT_TRUE(reader.ok());
    Built b;
    b.reader = reader.ok() ? *reader : nullptr;
    b.ref = test::reference_pyramid(im, cs, alpha, opt.tile_size - 2 * opt.border);
    return b;
}

// Every tile of every level decodes to exactly the reference tile.
void expect_exact(const Built& b) {
    ASSERT_TRUE(b.reader);
    const StoreInfo& info = b.reader->info();
    ASSERT_EQ(info.level_count(), b.ref.size());
    std::vector<std::uint8_t> decoded;
    std::size_t tiles = 0;
    for (std::uint32_t l = 0; l < info.level_count(); ++l)
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                auto t = b.reader->read_tile({l, x, y});
                ASSERT_TRUE(t.ok()) << t.error().message;
                ASSERT_TRUE(decode_tile(info, *t, decoded).ok());
                const auto ref = test::reference_tile(b.ref[l], info.tile_payload, info.border, x, y);
                ASSERT_EQ(decoded.size(), ref.size());
                if (decoded != ref) {
                    std::size_t i = 0;
                    while (decoded[i] == ref[i]) ++i;
                    FAIL() << "level " << l << " tile (" << x << "," << y << ") differs at byte " << i << ": "
                           << int(decoded[i]) << " vs reference " << int(ref[i]);
                }
                ++tiles;
            }
    EXPECT_GT(tiles, 1u);
}

BuildOptions small_tiles(Codec codec) {
    BuildOptions o;
    o.tile_size = 64;
    o.border = 4;
    o.codec = codec;
    o.threads = 2;
    return o;
}

}  // namespace

TEST(Builder, ZstdRgb8SrgbOddSizeMatchesReference) {
    ScratchDir d;
    expect_exact(build_and_reference(test_pattern(501, 347, 3, SampleType::u8, 1), ColourSpace::srgb, false,
                                     small_tiles(Codec::zstd), d.file("a.tsr")));
}

TEST(Builder, RawRgba8WithAlphaMatchesReference) {
    ScratchDir d;
    RefImage im = test_pattern(300, 200, 4, SampleType::u8, 2);
    // Punch transparent and half-transparent holes so alpha weighting matters.
    for (std::uint32_t y = 0; y < 200; ++y)
        for (std::uint32_t x = 0; x < 300; ++x) {
            std::uint8_t& a = im.bytes[(std::size_t(y) * 300 + x) * 4 + 3];
            if ((x / 7 + y / 5) % 3 == 0) a = 0;
            else if ((x + y) % 4 == 0) a = 77;
        }
    expect_exact(build_and_reference(im, ColourSpace::srgb, true, small_tiles(Codec::raw), d.file("a.tsr")));
}

TEST(Builder, ZstdGrey16LinearMatchesReference) {
    ScratchDir d;
    expect_exact(build_and_reference(test_pattern(257, 300, 1, SampleType::u16, 3), ColourSpace::linear, false,
                                     small_tiles(Codec::zstd), d.file("a.tsr")));
}

TEST(Builder, ZstdRgb16SrgbMatchesReference) {
    ScratchDir d;
    expect_exact(build_and_reference(test_pattern(130, 140, 3, SampleType::u16, 4), ColourSpace::srgb, false,
                                     small_tiles(Codec::zstd), d.file("a.tsr")));
}

TEST(Builder, ZstdFloat32LinearMatchesReference) {
    ScratchDir d;
    expect_exact(build_and_reference(test_pattern(200, 133, 3, SampleType::f32, 5), ColourSpace::linear, false,
                                     small_tiles(Codec::zstd), d.file("a.tsr")));
}

TEST(Builder, ZstdHalfGreyAlphaMatchesReference) {
    ScratchDir d;
    expect_exact(build_and_reference(test_pattern(150, 170, 2, SampleType::f16, 6), ColourSpace::linear, true,
                                     small_tiles(Codec::zstd), d.file("a.tsr")));
}

TEST(Builder, ProceduralTerrainZstdMatchesReferenceAndJpegQ90Reaches38dB) {
    ScratchDir d;
    auto src = open_image_source("procedural:terrain:1000");
    ASSERT_TRUE(src.ok());
    RefImage im = make_image(1000, 1000, 3, SampleType::u8);
    ASSERT_TRUE((*src)->read_rows(0, 1000, im.bytes.data(), [](std::size_t n, const auto& fn) { fn(0, n); }).ok());
    BuildOptions lossless;
    lossless.codec = Codec::zstd;
    lossless.threads = 2;
    const Built b = build_and_reference(im, ColourSpace::srgb, false, lossless, d.file("z.tsr"));
    expect_exact(b);

    BuildOptions jpeg;  // defaults: 256 tiles, border 4, JPEG q90
    auto r = build_store("procedural:terrain:1000", d.file("j.tsr"), jpeg);
    ASSERT_TRUE(r.ok()) << r.error().message;
    auto reader = StoreReader::open(d.file("j.tsr"));
    ASSERT_TRUE(reader.ok());
    const StoreInfo& info = (*reader)->info();
    EXPECT_EQ(info.codec, Codec::jpeg);
    double worst = 1e9, sum_sq = 0;
    std::size_t count = 0;
    std::vector<double> level_se(info.level_count(), 0.0), level_n(info.level_count(), 0.0);
    std::vector<std::uint8_t> decoded;
    for (std::uint32_t l = 0; l < info.level_count(); ++l)
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                auto t = (*reader)->read_tile({l, x, y});
                ASSERT_TRUE(t.ok());
                ASSERT_TRUE(decode_tile(info, *t, decoded).ok());
                const auto ref = test::reference_tile(b.ref[l], info.tile_payload, info.border, x, y);
                double se = 0;
                for (std::size_t i = 0; i < ref.size(); ++i) se += (double(decoded[i]) - ref[i]) * (double(decoded[i]) - ref[i]);
                const double mse = se / double(ref.size());
                worst = std::min(worst, 10.0 * std::log10(255.0 * 255.0 / std::max(mse, 1e-12)));
                sum_sq += se;
                count += ref.size();
                level_se[l] += se;
                level_n[l] += double(ref.size());
            }
    const double overall = 10.0 * std::log10(255.0 * 255.0 / (sum_sq / double(count)));
    RecordProperty("jpeg_q90_worst_tile_psnr_db", std::to_string(worst));
    std::printf("JPEG q90: overall PSNR %.2f dB, worst single tile %.2f dB\n", overall, worst);
    EXPECT_GE(overall, 38.0);
    for (std::uint32_t l = 0; l < info.level_count(); ++l) {
        const double psnr = 10.0 * std::log10(255.0 * 255.0 / (level_se[l] / level_n[l]));
        std::printf("  level %u: %.2f dB\n", l, psnr);
        // Coarse levels are dense thumbnails of a detailed image: a little below the finest.
        EXPECT_GE(psnr, 36.0) << "level " << l;
    }
}

TEST(Builder, BordersHoldNeighbourTexelsAtEveryLevel) {
    ScratchDir d;
    BuildOptions o = small_tiles(Codec::zstd);
    o.border = 8;
    auto r = build_store("procedural:terrain:700", d.file("b.tsr"), o);
    ASSERT_TRUE(r.ok()) << r.error().message;
    auto reader = StoreReader::open(d.file("b.tsr"));
    ASSERT_TRUE(reader.ok());
    const StoreInfo& info = (*reader)->info();
    const std::uint32_t P = info.tile_payload, B = info.border, T = info.tile_size();
    const std::size_t tb = info.texel_bytes();
    auto tile = [&](std::uint32_t l, std::uint32_t x, std::uint32_t y) {
        std::vector<std::uint8_t> out;
        auto t = (*reader)->read_tile({l, x, y});
        EXPECT_TRUE(t.ok());
        EXPECT_TRUE(decode_tile(info, *t, out).ok());
        return out;
    };
    auto texel = [&](const std::vector<std::uint8_t>& t, std::uint32_t i, std::uint32_t j) {
        return std::vector<std::uint8_t>(t.begin() + (std::size_t(j) * T + i) * tb, t.begin() + (std::size_t(j) * T + i + 1) * tb);
    };
    std::size_t checked = 0;
    for (std::uint32_t l = 0; l < info.level_count(); ++l) {
        const LevelInfo& L = info.levels[l];
        for (std::uint32_t y = 0; y < L.tiles_y; ++y)
            for (std::uint32_t x = 0; x < L.tiles_x; ++x) {
                const auto t = tile(l, x, y);
                if (x + 1 < L.tiles_x) {  // right border == left interior of the right neighbour
                    const auto n = tile(l, x + 1, y);
                    for (std::uint32_t j = 0; j < T; ++j)
                        for (std::uint32_t i = 0; i < 2 * B; ++i) {
                            // Columns [P, P + 2B) of this tile are columns [0, 2B) of the neighbour.
                            ASSERT_EQ(texel(t, P + i, j), texel(n, i, j)) << "level " << l << " tile " << x << "," << y;
                            ++checked;
                        }
                }
                if (y + 1 < L.tiles_y) {  // bottom border == top interior of the neighbour below
                    const auto n = tile(l, x, y + 1);
                    for (std::uint32_t j = 0; j < 2 * B; ++j)
                        for (std::uint32_t i = 0; i < T; ++i) {
                            ASSERT_EQ(texel(t, i, P + j), texel(n, i, j)) << "level " << l << " tile " << x << "," << y;
                            ++checked;
                        }
                }
                if (x == 0) {  // left image edge: border columns repeat the first image column
                    for (std::uint32_t j = 0; j < T; ++j)
                        for (std::uint32_t i = 0; i < B; ++i) ASSERT_EQ(texel(t, i, j), texel(t, B, j));
                }
                if (y == 0) {
                    for (std::uint32_t j = 0; j < B; ++j)
                        for (std::uint32_t i = 0; i < T; ++i) ASSERT_EQ(texel(t, i, j), texel(t, i, B));
                }
                if (x + 1 == L.tiles_x) {  // right image edge: clamped to the last column
                    const std::uint32_t last = L.width - 1 - x * P + B;
                    for (std::uint32_t j = 0; j < T; ++j)
                        for (std::uint32_t i = last + 1; i < T; ++i) ASSERT_EQ(texel(t, i, j), texel(t, last, j));
                }
            }
    }
    EXPECT_GT(checked, 10000u);
}

TEST(Builder, SparseUniformAndDeduplicatedTiles) {
    ScratchDir d;
    // 4x4 tiles of payload 64: left half transparent (absent with --sparse), top-right quadrant
    // one flat colour (uniform), bottom-right a pattern repeating every tile (deduplicated).
    const std::uint32_t P = 64, N = 4 * P;
    RefImage im = make_image(N, N, 4, SampleType::u8);
    for (std::uint32_t y = 0; y < N; ++y)
        for (std::uint32_t x = 0; x < N; ++x) {
            std::uint8_t* t = &im.bytes[(std::size_t(y) * N + x) * 4];
            if (x < N / 2) {
                t[0] = t[1] = t[2] = t[3] = 0;
            } else if (y < N / 2) {
                t[0] = 200, t[1] = 100, t[2] = 50, t[3] = 255;
            } else {
                t[0] = static_cast<std::uint8_t>((x % P) * 4), t[1] = static_cast<std::uint8_t>((y % P) * 4), t[2] = 9, t[3] = 255;
            }
        }
    BuildOptions o = small_tiles(Codec::zstd);
    o.border = 0;  // with no border, tiles of a periodic pattern are identical
    o.sparse = true;
    MemorySource src(im, ColourSpace::srgb, true);
    auto r = build_store(src, d.file("s.tsr"), o);
    ASSERT_TRUE(r.ok()) << r.error().message;
    auto reader = StoreReader::open(d.file("s.tsr"));
    ASSERT_TRUE(reader.ok());
    const StoreInfo& info = (*reader)->info();
    const LevelInfo& L0 = info.levels[0];
    EXPECT_EQ(L0.absent, 8u);
    // Three of the four top-right tiles are one colour; the one next to the transparent half is too.
    EXPECT_EQ(L0.uniform, 4u);
    EXPECT_EQ(L0.present, 4u);
    EXPECT_EQ(L0.deduplicated, 3u);
    EXPECT_EQ(L0.payload_bytes, (*reader)->read_tile({0, 2, 2})->bytes.size());  // one payload for four tiles
    auto absent = (*reader)->read_tile({0, 0, 0});
    ASSERT_TRUE(absent.ok());
    EXPECT_EQ(absent->kind, TileKind::absent);
    std::vector<std::uint8_t> decoded;
    EXPECT_EQ(decode_tile(info, *absent, decoded).error().code, Errc::not_found);
    auto uni = (*reader)->read_tile({0, 3, 0});
    ASSERT_TRUE(uni.ok());
    EXPECT_EQ(uni->kind, TileKind::uniform);
    EXPECT_EQ(uni->bytes, (std::vector<std::uint8_t>{200, 100, 50, 255}));
    ASSERT_TRUE(decode_tile(info, *uni, decoded).ok());
    EXPECT_EQ(decoded, test::reference_tile(im, P, 0, 3, 0));
    for (std::uint32_t x = 2; x < 4; ++x)
        for (std::uint32_t y = 2; y < 4; ++y) {
            auto t = (*reader)->read_tile({0, x, y});
            ASSERT_TRUE(t.ok());
            EXPECT_EQ(t->kind, TileKind::present);
            ASSERT_TRUE(decode_tile(info, *t, decoded).ok());
            EXPECT_EQ(decoded, test::reference_tile(im, P, 0, x, y));
        }
    // Level 1 (2x2 tiles): the left column stays absent, the rest is data.
    EXPECT_EQ(info.levels[1].absent, 2u);
    EXPECT_TRUE(verify_store(**reader).ok());
}

TEST(Builder, TwoBuildsAreByteIdenticalWhateverTheThreadCount) {
    ScratchDir d;
    for (Codec c : {Codec::jpeg, Codec::zstd}) {
        BuildOptions a;
        a.codec = c;
        a.tile_size = 128;
        a.threads = 1;
        BuildOptions b = a;
        b.threads = 2;
        ASSERT_TRUE(build_store("procedural:terrain:1500", d.file("1.tsr"), a).ok());
        ASSERT_TRUE(build_store("procedural:terrain:1500", d.file("2.tsr"), b).ok());
        const auto x = test::read_file(d.file("1.tsr")), y = test::read_file(d.file("2.tsr"));
        EXPECT_GT(x.size(), 10000u);
        EXPECT_TRUE(x == y) << "codec " << to_string(c);
    }
}

namespace {
// Writes `im` with OpenImageIO (scanline, or tiled when tile > 0).
void write_image(const std::string& path, const RefImage& im, int tile = 0) {
    static const OIIO::TypeDesc types[] = {OIIO::TypeDesc::UINT8, OIIO::TypeDesc::UINT16, OIIO::TypeDesc::HALF, OIIO::TypeDesc::FLOAT};
    auto out = OIIO::ImageOutput::create(path);
    ASSERT_TRUE(out);
    OIIO::ImageSpec spec(int(im.width), int(im.height), int(im.channels), types[int(im.type)]);
    if (tile) spec.tile_width = spec.tile_height = tile;
    ASSERT_TRUE(out->open(path, spec)) << out->geterror();
    ASSERT_TRUE(out->write_image(types[int(im.type)], im.bytes.data())) << out->geterror();
    ASSERT_TRUE(out->close());
}
}  // namespace

TEST(Builder, ImageFileInputsMatchTheInMemoryBuild) {
    ScratchDir d;
    const RefImage rgb = test_pattern(333, 250, 3, SampleType::u8, 7);
    write_image(d.file("in.png"), rgb);
    write_image(d.file("in.tif"), rgb);
    write_image(d.file("tiled.tif"), rgb, 64);
    BuildOptions o = small_tiles(Codec::zstd);
    MemorySource mem(rgb, ColourSpace::srgb, false);
    ASSERT_TRUE(build_store(mem, d.file("mem.tsr"), o).ok());
    const auto expect = test::read_file(d.file("mem.tsr"));
    for (const char* name : {"in.png", "in.tif", "tiled.tif"}) {
        auto r = build_store(d.file(name), d.file("f.tsr"), o);
        ASSERT_TRUE(r.ok()) << name << ": " << r.error().message;
        EXPECT_TRUE(test::read_file(d.file("f.tsr")) == expect) << name;
    }
    // Float EXR: linear, zstd by default.
    const RefImage hdr = test_pattern(120, 90, 3, SampleType::f32, 8);
    write_image(d.file("in.exr"), hdr);
    BuildOptions def;
    def.tile_size = 64;
    auto r = build_store(d.file("in.exr"), d.file("e.tsr"), def);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_EQ(r->info.codec, Codec::zstd);
    EXPECT_EQ(r->info.sample_type, SampleType::f32);
    EXPECT_EQ(r->info.colour_space, ColourSpace::linear);
    auto reader = StoreReader::open(d.file("e.tsr"));
    ASSERT_TRUE(reader.ok());
    Built b{*reader, test::reference_pyramid(hdr, ColourSpace::linear, false, 56)};
    expect_exact(b);
}

// A 16384^2 RGB source is 768 MiB; the streaming builder (the real `tessera` binary) must stay
// far below that. Under AddressSanitizer resident memory means something else: the build still
// runs, the bound is not checked.
// Peak resident memory (MiB) of `tessera ARGS...`, or -1 when it did not exit 0.
double tessera_peak_mib(const std::vector<std::string>& args) {
    std::vector<char*> argv{const_cast<char*>("tessera")};
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    const pid_t pid = ::fork();
    if (pid < 0) return -1;
    if (pid == 0) {
        ::execv(TESSERA_BINARY, argv.data());
        ::_exit(127);
    }
    int status = 0;
    struct rusage ru {};
    if (::wait4(pid, &status, 0, &ru) != pid || !WIFEXITED(status) || WEXITSTATUS(status) != 0) return -1;
    return double(ru.ru_maxrss) / 1024.0;
}

TEST(Builder, MemoryStaysBoundedOnALargeSource) {
    ScratchDir d;
    const std::string out = d.file("big.tsr");
    // The binary alone (its ~300 shared libraries: OpenImageIO and what it links, gRPC, GL) is
    // resident before any work; the bound is on what the build adds to that.
    const double baseline_mib = tessera_peak_mib({"--version"});
    ASSERT_GT(baseline_mib, 0);
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
        ::execl(TESSERA_BINARY, "tessera", "build", "procedural:terrain:16384", "-o", out.c_str(), "--codec", "zstd",
                "--zstd-level", "1", "--threads", "2", "--quiet", static_cast<char*>(nullptr));
        ::_exit(127);
    }
    int status = 0;
    struct rusage ru {};
    ASSERT_EQ(::wait4(pid, &status, 0, &ru), pid);
    ASSERT_TRUE(WIFEXITED(status));
    ASSERT_EQ(WEXITSTATUS(status), 0);
    const double peak_mib = double(ru.ru_maxrss) / 1024.0;
    std::printf("peak RSS building 16384^2: %.0f MiB, of which %.0f MiB is the binary at rest (the source is 768 MiB)\n",
                peak_mib, baseline_mib);
#if !defined(__SANITIZE_ADDRESS__)
    EXPECT_LT(peak_mib - baseline_mib, 96.0);
#endif
    auto r = StoreReader::open(out);
    ASSERT_TRUE(r.ok());
    EXPECT_EQ((*r)->info().width, 16384u);
}

// Straight and associated alpha from files other tools wrote (ImageMagick, oiiotool): tiles hold
// straight alpha (docs/store-format.md, "Alpha"); a straight file comes back texel for texel, an
// associated one made straight (re-associating gives the file's texel), and mips weight by alpha
// once, as the reference does.
namespace {

// Runs a shell command; the test fails with its output when it does not exit 0.
::testing::AssertionResult run_tool(const std::string& cmd) {
    const int rc = std::system((cmd + " > /dev/null 2>&1").c_str());
    if (rc == 0) return ::testing::AssertionSuccess();
    return ::testing::AssertionFailure() << "'" << cmd << "' exited " << rc;
}

// The file's samples as stored, alpha untouched (OpenImageIO told to keep straight alpha straight;
// associated files come as they are).
RefImage read_file_samples(const std::string& path) {
    RefImage im;
    OIIO::ImageSpec config;
    config.attribute("oiio:UnassociatedAlpha", 1);
    auto in = OIIO::ImageInput::open(path, &config);
    EXPECT_TRUE(in) << path;
    if (!in) return im;
    const OIIO::ImageSpec& s = in->spec();
    im.width = std::uint32_t(s.width);
    im.height = std::uint32_t(s.height);
    im.channels = std::uint32_t(s.nchannels);
    OIIO::TypeDesc type = OIIO::TypeDesc::UINT8;
    switch (s.format.basetype) {
        case OIIO::TypeDesc::UINT16: im.type = SampleType::u16; type = OIIO::TypeDesc::UINT16; break;
        case OIIO::TypeDesc::HALF: im.type = SampleType::f16; type = OIIO::TypeDesc::HALF; break;
        case OIIO::TypeDesc::FLOAT: im.type = SampleType::f32; type = OIIO::TypeDesc::FLOAT; break;
        default: break;
    }
    im.bytes.resize(std::size_t(im.width) * im.height * im.texel_bytes());
    EXPECT_TRUE(in->read_image(0, 0, 0, int(im.channels), type, im.bytes.data())) << in->geterror();
    return im;
}

// An RGBA pattern whose alpha spans 0 (with colour under it), 1, 220 and 255, and whose first
// texel is grey 52 at alpha 220 (a premultiplying reader returns 44 there).
RefImage alpha_pattern(std::uint32_t w, std::uint32_t h, SampleType t) {
    RefImage im = make_image(w, h, 4, t);
    static const std::uint32_t alphas[] = {220, 0, 1, 64, 128, 220, 255, 255, 17};
    for (std::uint32_t y = 0; y < h; ++y)
        for (std::uint32_t x = 0; x < w; ++x) {
            std::uint32_t v[4] = {(x * 7 + y * 3) % 256, (x * 2 + y * 11 + 40) % 256, (200 + x * 5 + y) % 256,
                                  alphas[(x / 3 + y / 5) % 9]};
            if (x == 0 && y == 0) v[0] = v[1] = v[2] = 52;
            for (int c = 0; c < 4; ++c) {
                const std::size_t i = (std::size_t(y) * w + x) * 4 + c;
                if (t == SampleType::u8) set<std::uint8_t>(im, i, std::uint8_t(v[c]));
                else set<std::uint16_t>(im, i, std::uint16_t(v[c] * 257 + (c < 3 ? x % 200 : 0)));
            }
        }
    return im;
}

void write_raw(const std::string& path, const RefImage& im) {
    std::FILE* f = std::fopen(path.c_str(), "wb");
    ASSERT_TRUE(f);
    ASSERT_EQ(std::fwrite(im.bytes.data(), 1, im.bytes.size(), f), im.bytes.size());
    std::fclose(f);
}

// Straight from associated file samples, by the documented rule (docs/store-format.md, "Alpha"),
// checking on the way that re-associating the straight texel gives the file's texel back.
RefImage made_straight(const RefImage& file) {
    RefImage out = file;
    const std::size_t texels = std::size_t(file.width) * file.height;
    for (std::size_t i = 0; i < texels; ++i) {
        if (file.type == SampleType::f32) {
            const auto* p = reinterpret_cast<const float*>(file.bytes.data()) + i * 4;
            auto* s = reinterpret_cast<float*>(out.bytes.data()) + i * 4;
            for (int c = 0; c < 3; ++c) s[c] = p[3] > 0.0f ? p[c] / p[3] : 0.0f;
            continue;
        }
        if (file.type == SampleType::f16) {
            const auto* p = reinterpret_cast<const std::uint16_t*>(file.bytes.data()) + i * 4;
            auto* s = reinterpret_cast<std::uint16_t*>(out.bytes.data()) + i * 4;
            const float a = test::from_half(p[3]);
            for (int c = 0; c < 3; ++c) s[c] = test::to_half(a > 0.0f ? test::from_half(p[c]) / a : 0.0f);
            continue;
        }
        const std::uint64_t maxv = file.type == SampleType::u8 ? 255 : 65535;
        auto get = [&](const RefImage& im, std::size_t k) -> std::uint64_t {
            return im.type == SampleType::u8 ? im.bytes[k] : reinterpret_cast<const std::uint16_t*>(im.bytes.data())[k];
        };
        const std::uint64_t a = get(file, i * 4 + 3);
        for (int c = 0; c < 3; ++c) {
            const std::uint64_t p = get(file, i * 4 + c);
            const std::uint64_t s = a == 0 ? 0 : std::min(maxv, (p * maxv + a / 2) / a);
            if (a > 0) {
                EXPECT_EQ((s * a + maxv / 2) / maxv, p) << "texel " << i << " does not re-associate";
            }
            if (file.type == SampleType::u8) out.bytes[i * 4 + c] = std::uint8_t(s);
            else reinterpret_cast<std::uint16_t*>(out.bytes.data())[i * 4 + c] = std::uint16_t(s);
        }
    }
    return out;
}

}  // namespace

TEST(Builder, AlphaFromOtherToolsIsStoredStraightAndWeightedOnce) {
    ScratchDir d;
    const std::string im = "convert-im6.q16";  // ImageMagick 6 (Debian's imagemagick package)
    const RefImage rgba8 = alpha_pattern(150, 110, SampleType::u8), rgba16 = alpha_pattern(150, 110, SampleType::u16);
    write_raw(d.file("in8.rgba"), rgba8);
    write_raw(d.file("in16.rgba"), rgba16);
    // Grey + alpha (PNG colour type 4): the pattern's red as grey, written as RGBA with R = G = B.
    RefImage grey_alpha = make_image(150, 110, 2, SampleType::u8), grey_rgba = rgba8;
    for (std::size_t i = 0; i < std::size_t(150) * 110; ++i) {
        grey_alpha.bytes[i * 2] = grey_rgba.bytes[i * 4 + 1] = grey_rgba.bytes[i * 4 + 2] = rgba8.bytes[i * 4];
        grey_alpha.bytes[i * 2 + 1] = rgba8.bytes[i * 4 + 3];
    }
    write_raw(d.file("grey.rgba"), grey_rgba);
    const std::string raw8 = " -size 150x110 -depth 8 rgba:" + d.file("in8.rgba");
    const std::string raw16 = " -size 150x110 -depth 16 -endian LSB rgba:" + d.file("in16.rgba");
    // Straight alpha: PNG (OpenImageIO's reader), TIFF with unassociated ExtraSamples (Tessera's own
    // TIFF reader; planar, OpenImageIO's), 16-bit PNG.
    ASSERT_TRUE(run_tool(im + raw8 + " " + d.file("straight.png")));
    ASSERT_TRUE(run_tool(im + raw8 + " -define tiff:alpha=unassociated " + d.file("straight.tif")));
    ASSERT_TRUE(run_tool(im + raw8 + " -define tiff:alpha=unassociated -interlace plane " + d.file("straight_planar.tif")));
    ASSERT_TRUE(run_tool(im + raw16 + " " + d.file("straight16.png")));
    ASSERT_TRUE(run_tool(im + " -size 150x110 -depth 8 rgba:" + d.file("grey.rgba") + " -type GrayscaleAlpha " + d.file("grey_alpha.png")));
    // Associated alpha: TIFF with ExtraSamples = 1 (both readers), OpenEXR half written by oiiotool.
    ASSERT_TRUE(run_tool(im + raw8 + " -define tiff:alpha=associated " + d.file("assoc.tif")));
    ASSERT_TRUE(run_tool(im + raw8 + " -define tiff:alpha=associated -interlace plane " + d.file("assoc_planar.tif")));
    ASSERT_TRUE(run_tool("oiiotool " + d.file("straight.png") + " -d half -o " + d.file("assoc.exr")));
    // Float TIFF with associated alpha and 16-bit TIFF with unassociated alpha (Tessera's TIFF reader).
    ASSERT_TRUE(run_tool("oiiotool " + d.file("straight.png") + " -d float -o " + d.file("assoc_f32.tif")));
    ASSERT_TRUE(run_tool("oiiotool --iconfig oiio:UnassociatedAlpha 1 " + d.file("straight16.png") + " -o " + d.file("straight16.tif")));
    // Straight alpha in a 32-bit BMP, and in a lossless WebP that keeps the colour under alpha 0
    // (Google's own encoder).
    ASSERT_TRUE(run_tool(im + raw8 + " BMP:" + d.file("straight.bmp")));
    ASSERT_TRUE(run_tool("cwebp -quiet -lossless -exact " + d.file("straight.png") + " -o " + d.file("straight.webp")));

    struct Case {
        const char* file;
        bool associated;
        const RefImage* original;  // the straight texels a straight file must give back
    };
    const Case cases[] = {{"straight.png", false, &rgba8},  {"straight.tif", false, &rgba8}, {"straight_planar.tif", false, &rgba8},
                          {"straight16.png", false, &rgba16}, {"grey_alpha.png", false, &grey_alpha}, {"assoc.tif", true, nullptr},   {"assoc_planar.tif", true, nullptr},
                          {"assoc.exr", true, nullptr},   {"assoc_f32.tif", true, nullptr}, {"straight16.tif", false, &rgba16},
                          {"straight.bmp", false, &rgba8}, {"straight.webp", false, &rgba8}};
    for (const Case& c : cases) {
        SCOPED_TRACE(c.file);
        // OpenImageIO's WebP reader premultiplies whatever it is asked, so it cannot say what the
        // file holds; the lossless file holds the texels given.
        const bool webp = std::string(c.file).find(".webp") != std::string::npos;
        const RefImage file = webp ? *c.original : read_file_samples(d.file(c.file));
        ASSERT_EQ(file.channels, c.original ? c.original->channels : 4u);
        if (c.original) {
            ASSERT_TRUE(file.bytes == c.original->bytes) << "the tool did not write the texels given";
        }
        const RefImage straight = c.associated ? made_straight(file) : file;
        BuildOptions o = small_tiles(Codec::zstd);
        auto r = build_store(d.file(c.file), d.file("a.tsr"), o);
        ASSERT_TRUE(r.ok()) << r.error().message;
        EXPECT_TRUE(r->info.has_alpha);
        auto reader = StoreReader::open(d.file("a.tsr"));
        ASSERT_TRUE(reader.ok());
        const ColourSpace cs = (*reader)->info().colour_space;
        const bool floats = file.type == SampleType::f16 || file.type == SampleType::f32;
        EXPECT_EQ(cs, floats ? ColourSpace::linear : ColourSpace::srgb);
        expect_exact(Built{*reader, test::reference_pyramid(straight, cs, true, o.tile_size - 2 * o.border)});
        if (!c.associated && file.type == SampleType::u8) {  // the texel of interest: grey 52 at alpha 220
            auto t = (*reader)->read_tile({0, 0, 0});
            std::vector<std::uint8_t> decoded;
            ASSERT_TRUE(t.ok() && decode_tile((*reader)->info(), *t, decoded).ok());
            const std::size_t at = (std::size_t(o.border) * o.tile_size + o.border) * file.channels;
            EXPECT_EQ(int(decoded[at]), 52);
            EXPECT_EQ(int(decoded[at + file.channels - 1]), 220);
        }
    }
}

namespace {
// Tile (x, y) of `level`, decoded: tile_size rows of tile_size texels, borders included.
std::vector<std::uint8_t> tile_texels(StoreReader& reader, std::uint32_t level, std::uint32_t x, std::uint32_t y) {
    auto t = reader.read_tile({level, x, y});
    std::vector<std::uint8_t> decoded;
    EXPECT_TRUE(t.ok() && decode_tile(reader.info(), *t, decoded).ok());
    return decoded;
}
}  // namespace

// A GIF's transparent colour is alpha: OpenImageIO's reader names an alpha channel it does not
// index, and the store must still know it (a transparent texel must not come out black and opaque).
TEST(Builder, GifTransparencyIsAlpha) {
    ScratchDir d;
    // 128x128 (three levels in 64-texel tiles): even columns red and opaque, odd columns transparent.
    RefImage im = make_image(128, 128, 4, SampleType::u8);
    for (std::size_t i = 0; i < std::size_t(128) * 128; ++i)
        if ((i % 128) % 2 == 0) im.bytes[i * 4] = im.bytes[i * 4 + 3] = 255;
    write_raw(d.file("in.rgba"), im);
    ASSERT_TRUE(run_tool("convert-im6.q16 -size 128x128 -depth 8 rgba:" + d.file("in.rgba") + " " + d.file("in.gif")));
    BuildOptions o = small_tiles(Codec::zstd);
    auto r = build_store(d.file("in.gif"), d.file("a.tsr"), o);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_TRUE(r->info.has_alpha);
    auto reader = StoreReader::open(d.file("a.tsr"));
    ASSERT_TRUE(reader.ok());
    const StoreInfo& info = (*reader)->info();
    ASSERT_EQ(info.channels, 4u);
    ASSERT_GE(info.level_count(), 2u);
    const std::uint32_t tile = info.tile_size(), b = info.border;
    for (std::uint32_t level = 0; level < 2; ++level) {
        SCOPED_TRACE("level " + std::to_string(level));
        const std::vector<std::uint8_t> t = tile_texels(**reader, level, 0, 0);
        const std::uint32_t side = std::min<std::uint32_t>(info.levels[level].width, info.tile_payload);
        for (std::uint32_t y = 0; y < side; ++y)
            for (std::uint32_t x = 0; x < side; ++x) {
                const std::uint8_t* p = t.data() + (std::size_t(y + b) * tile + x + b) * 4;
                const bool opaque = level == 0 && x % 2 == 0;
                // Level 1: two red opaque texels and two transparent ones, weighted by alpha.
                const int alpha = level == 0 ? (opaque ? 255 : 0) : 128;
                ASSERT_EQ(int(p[3]), alpha) << "texel " << x << "," << y;
                if (alpha > 0) {
                    ASSERT_EQ(int(p[0]), 255) << "texel " << x << "," << y;
                    ASSERT_EQ(int(p[1]), 0);
                    ASSERT_EQ(int(p[2]), 0);
                }
            }
    }
}

// Signed 16-bit samples (a DEM's heights, as GDAL writes them) keep their values, negatives too, as
// floats; 32-bit integers are refused by name rather than rounded.
TEST(Builder, SignedIntegerSamplesKeepTheirValues) {
    ScratchDir d;
    const std::int32_t values[8] = {-32768, -1000, -1, 0, 1, 1234, 32000, 32767};
    RefImage raw = make_image(8, 1, 1, SampleType::u16);
    for (int i = 0; i < 8; ++i) set<std::uint16_t>(raw, std::size_t(i), std::uint16_t(values[i] + 32768));
    write_raw(d.file("in.gray"), raw);
    // ImageMagick reads the raw samples as signed with their bias removed: stored value = raw - 32768.
    ASSERT_TRUE(run_tool("convert-im6.q16 -size 8x1 -depth 16 -endian LSB -define quantum:format=signed gray:" + d.file("in.gray") +
                         " -define quantum:format=signed " + d.file("dem.tif")));
    {  // the tool wrote the values given (read as the file's own signed samples)
        auto in = OIIO::ImageInput::open(d.file("dem.tif"));
        ASSERT_TRUE(in);
        ASSERT_EQ(in->spec().format, OIIO::TypeDesc::INT16);
        std::int16_t file[8];
        ASSERT_TRUE(in->read_image(0, 0, 0, 1, OIIO::TypeDesc::INT16, file));
        for (int i = 0; i < 8; ++i) ASSERT_EQ(file[i], values[i]) << "the tool did not write the samples given";
    }
    BuildOptions o = small_tiles(Codec::zstd);
    auto r = build_store(d.file("dem.tif"), d.file("a.tsr"), o);
    ASSERT_TRUE(r.ok()) << r.error().message;
    auto reader = StoreReader::open(d.file("a.tsr"));
    ASSERT_TRUE(reader.ok());
    const StoreInfo& info = (*reader)->info();
    ASSERT_EQ(info.sample_type, SampleType::f32);
    ASSERT_EQ(info.channels, 1u);
    const std::vector<std::uint8_t> t = tile_texels(**reader, 0, 0, 0);
    for (int i = 0; i < 8; ++i) {
        float v;
        std::memcpy(&v, t.data() + (std::size_t(info.border) * info.tile_size() + info.border + i) * 4, 4);
        EXPECT_EQ(v, float(values[i])) << "sample " << i;
    }

    ASSERT_TRUE(run_tool("oiiotool " + d.file("dem.tif") + " -d uint32 -o " + d.file("u32.tif")));
    auto refused = build_store(d.file("u32.tif"), d.file("b.tsr"), o);
    ASSERT_FALSE(refused.ok());
    EXPECT_EQ(refused.error().code, Errc::unsupported);
    EXPECT_NE(refused.error().message.find("uint"), std::string::npos) << refused.error().message;
    EXPECT_FALSE(std::filesystem::exists(d.file("b.tsr")));

    // Signed samples with alpha: refused by name (alpha would not be 0 to 1 as floats).
    write_raw(d.file("ga.raw"), make_image(2, 1, 4, SampleType::u16));
    ASSERT_TRUE(run_tool("convert-im6.q16 -size 2x1 -depth 16 -endian LSB -define quantum:format=signed rgba:" + d.file("ga.raw") +
                         " -define quantum:format=signed " + d.file("alpha.tif")));
    auto with_alpha = build_store(d.file("alpha.tif"), d.file("c.tsr"), o);
    ASSERT_FALSE(with_alpha.ok());
    EXPECT_EQ(with_alpha.error().code, Errc::unsupported);
    EXPECT_NE(with_alpha.error().message.find("signed samples with an alpha channel"), std::string::npos) << with_alpha.error().message;
}

// TIFF layouts ImageMagick writes that the builder reads a few rows at a time: doubles in
// compressed strips (OpenImageIO 2.4 returned zeros for a strip read in part: the store was black
// and verified) and separate planes in compressed strips (libtiff refused a strip read in part).
// Each builds the store its whole-image conversion by oiiotool builds; CIELab is refused by name.
TEST(Builder, TiffStripsAndPlanesFromImageMagickAreReadWhole) {
    ScratchDir d;
    const std::string im = "convert-im6.q16 ";
    ASSERT_TRUE(run_tool(im + "-size 300x200 plasma:fractal -seed 3 -depth 16 PNG48:" + d.file("src16.png")));
    ASSERT_TRUE(run_tool(im + d.file("src16.png") + " -depth 8 " + d.file("src8.png")));
    ASSERT_TRUE(run_tool(im + d.file("src16.png") + " -define quantum:format=floating-point -depth 64 -compress zip "
                              "-define tiff:rows-per-strip=80 " + d.file("double.tif")));
    ASSERT_TRUE(run_tool(im + d.file("src8.png") + " -interlace plane -compress zip -define tiff:rows-per-strip=200 " +
                         d.file("planar.tif")));
    // The references: the same samples converted whole by oiiotool (float; interleaved 8-bit).
    ASSERT_TRUE(run_tool("oiiotool " + d.file("double.tif") + " -d float -o " + d.file("double_ref.tif")));
    ASSERT_TRUE(run_tool("oiiotool " + d.file("planar.tif") + " -o " + d.file("planar_ref.png")));
    {
        auto in = OIIO::ImageInput::open(d.file("double.tif"));
        ASSERT_TRUE(in);
        ASSERT_EQ(in->spec().format, OIIO::TypeDesc::DOUBLE) << "the tool did not write doubles";
        ASSERT_EQ(in->spec().get_int_attribute("tiff:RowsPerStrip"), 80);
        auto planar = OIIO::ImageInput::open(d.file("planar.tif"));
        ASSERT_TRUE(planar);
        ASSERT_EQ(planar->spec().get_int_attribute("tiff:PlanarConfiguration"), 2) << "the tool did not write planes";
    }
    BuildOptions o = small_tiles(Codec::zstd);
    for (const auto& [file, ref] : {std::pair{"double.tif", "double_ref.tif"}, std::pair{"planar.tif", "planar_ref.png"}}) {
        auto r = build_store(d.file(file), d.file("a.tsr"), o);
        ASSERT_TRUE(r.ok()) << file << ": " << r.error().message;
        auto e = build_store(d.file(ref), d.file("b.tsr"), o);
        ASSERT_TRUE(e.ok()) << ref << ": " << e.error().message;
        EXPECT_TRUE(test::read_file(d.file("a.tsr")) == test::read_file(d.file("b.tsr"))) << file;
        auto reader = StoreReader::open(d.file("a.tsr"));
        ASSERT_TRUE(reader.ok());
        EXPECT_EQ((*reader)->info().levels[0].present, (*reader)->info().levels[0].tiles_x * (*reader)->info().levels[0].tiles_y)
            << file << ": a plasma has no uniform tile";
    }

    ASSERT_TRUE(run_tool(im + d.file("src8.png") + " -colorspace Lab " + d.file("lab.tif")));
    auto lab = build_store(d.file("lab.tif"), d.file("c.tsr"), o);
    ASSERT_FALSE(lab.ok());
    EXPECT_EQ(lab.error().code, Errc::unsupported);
    EXPECT_NE(lab.error().message.find("CIELab"), std::string::npos) << lab.error().message;
    EXPECT_FALSE(std::filesystem::exists(d.file("c.tsr")));
}

// Photos stored sideways or mirrored (EXIF/TIFF orientation, as cameras write them) are built as
// every viewer shows them: the same texels as ImageMagick's -auto-orient gives.
TEST(Builder, OrientedPhotosAreBuiltUpright) {
    ScratchDir d;
    const RefImage im = test_pattern(150, 110, 3, SampleType::u8, 7);
    write_raw(d.file("in.rgb"), im);
    const std::string raw = "convert-im6.q16 -size 150x110 -depth 8 rgb:" + d.file("in.rgb");
    static const char* kOrient[] = {"TopLeft", "TopRight", "BottomRight", "BottomLeft", "LeftTop", "RightTop", "RightBottom", "LeftBottom"};
    BuildOptions o = small_tiles(Codec::zstd);
    for (int k = 0; k < 8; ++k) {
        SCOPED_TRACE(kOrient[k]);
        // TIFF: Tessera's own TIFF reader, texel exact.
        const std::string tif = d.file(std::string("o") + char('1' + k) + ".tif"), up = d.file("upright.tif");
        ASSERT_TRUE(run_tool(raw + " -orient " + kOrient[k] + " " + tif));
        ASSERT_TRUE(run_tool("convert-im6.q16 " + tif + " -auto-orient -orient TopLeft " + up));
        const RefImage upright = read_file_samples(up);
        ASSERT_EQ(upright.width, k >= 4 ? 110u : 150u);
        auto r = build_store(tif, d.file("a.tsr"), o);
        ASSERT_TRUE(r.ok()) << r.error().message;
        EXPECT_EQ(r->info.width, upright.width);
        auto reader = StoreReader::open(d.file("a.tsr"));
        ASSERT_TRUE(reader.ok());
        expect_exact(Built{*reader, test::reference_pyramid(upright, ColourSpace::srgb, false, o.tile_size - 2 * o.border)});
    }
    // JPEG with an EXIF orientation (OpenImageIO's reader; ImageMagick 6 writes no EXIF of its
    // own, so oiiotool tags it): turned a quarter, level 0 matches ImageMagick's upright decode to
    // within a step (the two decoders may round differently).
    ASSERT_TRUE(run_tool(raw + " " + d.file("in.png")));
    ASSERT_TRUE(run_tool("oiiotool " + d.file("in.png") + " --orientation 6 --quality 95 -o " + d.file("o6.jpg")));
    ASSERT_TRUE(run_tool("convert-im6.q16 " + d.file("o6.jpg") + " -auto-orient " + d.file("o6_upright.png")));
    const RefImage upright = read_file_samples(d.file("o6_upright.png"));
    ASSERT_EQ(upright.width, 110u);
    ASSERT_EQ(upright.height, 150u);
    auto r = build_store(d.file("o6.jpg"), d.file("j.tsr"), o);
    ASSERT_TRUE(r.ok()) << r.error().message;
    auto reader = StoreReader::open(d.file("j.tsr"));
    ASSERT_TRUE(reader.ok());
    const StoreInfo& info = (*reader)->info();
    ASSERT_EQ(info.levels[0].width, 110u);
    ASSERT_EQ(info.levels[0].height, 150u);
    int worst = 0;
    for (std::uint32_t ty = 0; ty < info.levels[0].tiles_y; ++ty)
        for (std::uint32_t tx = 0; tx < info.levels[0].tiles_x; ++tx) {
            const std::vector<std::uint8_t> t = tile_texels(**reader, 0, tx, ty);
            for (std::uint32_t y = 0; y < info.tile_payload; ++y)
                for (std::uint32_t x = 0; x < info.tile_payload; ++x) {
                    const std::uint32_t gx = tx * info.tile_payload + x, gy = ty * info.tile_payload + y;
                    if (gx >= 110 || gy >= 150) continue;
                    for (int c = 0; c < 3; ++c) {
                        const int got = t[(std::size_t(y + info.border) * info.tile_size() + x + info.border) * 3 + c];
                        const int want = upright.bytes[(std::size_t(gy) * 110 + gx) * 3 + c];
                        worst = std::max(worst, std::abs(got - want));
                    }
                }
        }
    EXPECT_LE(worst, 2);
}

namespace {
// The largest difference between level 0 of a u8 store and `want` (same size and channels).
int worst_level0_difference(StoreReader& reader, const RefImage& want) {
    const StoreInfo& info = reader.info();
    EXPECT_EQ(info.levels[0].width, want.width);
    EXPECT_EQ(info.levels[0].height, want.height);
    if (info.levels[0].width != want.width || info.levels[0].height != want.height) return 255;
    int worst = 0;
    for (std::uint32_t ty = 0; ty < info.levels[0].tiles_y; ++ty)
        for (std::uint32_t tx = 0; tx < info.levels[0].tiles_x; ++tx) {
            const std::vector<std::uint8_t> t = tile_texels(reader, 0, tx, ty);
            for (std::uint32_t y = 0; y < info.tile_payload; ++y)
                for (std::uint32_t x = 0; x < info.tile_payload; ++x) {
                    const std::uint32_t gx = tx * info.tile_payload + x, gy = ty * info.tile_payload + y;
                    if (gx >= want.width || gy >= want.height) continue;
                    for (std::uint32_t c = 0; c < want.channels; ++c) {
                        const int got = t[(std::size_t(y + info.border) * info.tile_size() + x + info.border) * want.channels + c];
                        const int expected = want.bytes[(std::size_t(gy) * want.width + gx) * want.channels + c];
                        worst = std::max(worst, std::abs(got - expected));
                    }
                }
        }
    return worst;
}

// A little-endian, uncompressed, one-channel TIFF written by hand: strips of `rows_per_strip`
// rows, `bits` per sample (1: packed, first texel in the high bit), BitsPerSample left out when
// `tag_bits` is false (as Pillow writes 1-bit files), and the strips in `empty` given no bytes
// (as GDAL writes with SPARSE_OK).
std::vector<std::uint8_t> handmade_grey_tiff(std::uint32_t w, std::uint32_t h, unsigned bits, bool tag_bits, std::uint32_t rows_per_strip,
                                             const std::vector<std::uint8_t>& packed_rows, const std::set<std::uint32_t>& empty) {
    const std::uint32_t strips = (h + rows_per_strip - 1) / rows_per_strip, row_bytes = (w * bits + 7) / 8;
    std::vector<std::uint8_t> out = {'I', 'I', 42, 0, 0, 0, 0, 0};
    auto u16 = [&](std::uint16_t v) { out.push_back(std::uint8_t(v)), out.push_back(std::uint8_t(v >> 8)); };
    auto u32 = [&](std::uint32_t v) { for (int k = 0; k < 4; ++k) out.push_back(std::uint8_t(v >> (8 * k))); };
    std::vector<std::uint32_t> offsets(strips), counts(strips);
    for (std::uint32_t s = 0; s < strips; ++s) {
        const std::uint32_t rows = std::min(rows_per_strip, h - s * rows_per_strip);
        if (empty.count(s)) continue;
        offsets[s] = std::uint32_t(out.size());
        counts[s] = rows * row_bytes;
        out.insert(out.end(), packed_rows.begin() + std::ptrdiff_t(s * rows_per_strip * row_bytes),
                   packed_rows.begin() + std::ptrdiff_t((s * rows_per_strip + rows) * row_bytes));
    }
    const std::uint32_t offsets_at = std::uint32_t(out.size());
    for (std::uint32_t v : offsets) u32(v);
    const std::uint32_t counts_at = std::uint32_t(out.size());
    for (std::uint32_t v : counts) u32(v);
    if (out.size() % 2) out.push_back(0);
    const std::uint32_t ifd = std::uint32_t(out.size());
    for (int k = 0; k < 4; ++k) out[4 + std::size_t(k)] = std::uint8_t(ifd >> (8 * k));
    struct Entry { std::uint16_t tag, type; std::uint32_t count, value; };
    std::vector<Entry> entries = {{256, 4, 1, w}, {257, 4, 1, h}};
    if (tag_bits) entries.push_back({258, 3, 1, bits});
    entries.push_back({259, 3, 1, 1});
    entries.push_back({262, 3, 1, 1});  // min-is-black
    entries.push_back({273, 4, strips, strips == 1 ? offsets[0] : offsets_at});
    entries.push_back({277, 3, 1, 1});
    entries.push_back({278, 4, 1, rows_per_strip});
    entries.push_back({279, 4, strips, strips == 1 ? counts[0] : counts_at});
    u16(std::uint16_t(entries.size()));
    for (const Entry& e : entries) {
        u16(e.tag), u16(e.type), u32(e.count);
        if (e.type == 3 && e.count == 1) u16(std::uint16_t(e.value)), u16(0);
        else u32(e.value);
    }
    u32(0);
    return out;
}
}  // namespace

// TIFFs other tools write that OpenImageIO 2.4 gets wrong, read by Tessera's own TIFF reader:
// JPEG-compressed YCbCr as libtiff-tools' tiffcp writes it (OpenImageIO flips it through libtiff's
// RGBA interface and then reports the orientation too, so a turned file came out mirrored, and a
// file cut short built with exit 0 and stale rows); 1-bit grey without BitsPerSample (Pillow:
// OpenImageIO read the packed bits as bytes); strips with no bytes (GDAL's SPARSE_OK: zeros).
TEST(Builder, TiffsOpenImageIoMisreadsAreReadRight) {
    ScratchDir d;
    const RefImage im = test_pattern(150, 110, 3, SampleType::u8, 7);
    write_raw(d.file("in.rgb"), im);
    ASSERT_TRUE(run_tool("convert-im6.q16 -size 150x110 -depth 8 rgb:" + d.file("in.rgb") + " -compress none " + d.file("plain.tif")));
    ASSERT_TRUE(run_tool("tiffcp -c jpeg:95 -r 16 " + d.file("plain.tif") + " " + d.file("ycc.tif")));
    ASSERT_TRUE(run_tool("tiffinfo " + d.file("ycc.tif") + " | grep -q 'Photometric Interpretation: YCbCr'")) << "tiffcp wrote no YCbCr";
    // The reference: ImageMagick's decode of the file as stored (orientation 1: no flips), turned.
    ASSERT_TRUE(run_tool("convert-im6.q16 " + d.file("ycc.tif") + " " + d.file("ycc_ref.png")));
    BuildOptions o = small_tiles(Codec::zstd);
    for (const auto& [orientation, turn] : {std::pair{1, ""}, std::pair{3, "-rotate 180"}, std::pair{6, "-rotate 90"}, std::pair{8, "-rotate 270"}}) {
        SCOPED_TRACE("orientation " + std::to_string(orientation));
        const std::string tif = d.file("ycc" + std::to_string(orientation) + ".tif"), ref = d.file("ref.png");
        ASSERT_TRUE(run_tool("cp " + d.file("ycc.tif") + " " + tif + " && tiffset -s 274 " + std::to_string(orientation) + " " + tif));
        ASSERT_TRUE(run_tool("convert-im6.q16 " + d.file("ycc_ref.png") + " " + turn + " " + ref));
        auto r = build_store(tif, d.file("a.tsr"), o);
        ASSERT_TRUE(r.ok()) << r.error().message;
        auto reader = StoreReader::open(d.file("a.tsr"));
        ASSERT_TRUE(reader.ok());
        EXPECT_LE(worst_level0_difference(**reader, read_file_samples(ref)), 3);  // two JPEG decoders
    }
    // A strip cut short (its offset moved to 10 bytes before the end; tiffcp writes the IFD
    // last, so cutting the file would cut the IFD instead): an error naming the file, no store.
    auto bytes = test::read_file(d.file("ycc.tif"));
    ASSERT_TRUE(bytes.size() > 8 && bytes[0] == 'I' && bytes[1] == 'I') << "a little-endian TIFF";
    auto u16 = [&](std::size_t at) { return std::uint32_t(bytes[at] | bytes[at + 1] << 8); };
    auto u32 = [&](std::size_t at) { return u16(at) | u16(at + 2) << 16; };
    const std::size_t ifd = u32(4);
    bool patched = false;
    for (std::uint32_t e = 0; e < u16(ifd); ++e) {
        const std::size_t at = ifd + 2 + 12 * std::size_t(e);
        if (u16(at) != 273 || u16(at + 2) != 4 || u32(at + 4) < 2) continue;  // StripOffsets, LONG, several
        const std::size_t middle = u32(at + 8) + 4 * (u32(at + 4) / 2);
        const std::uint32_t near_end = std::uint32_t(bytes.size() - 10);
        for (int k = 0; k < 4; ++k) bytes[middle + std::size_t(k)] = std::uint8_t(near_end >> (8 * k));
        patched = true;
    }
    ASSERT_TRUE(patched) << "no StripOffsets of several strips";
    test::write_file(d.file("cut.tif"), bytes);
    auto cut = build_store(d.file("cut.tif"), d.file("cut.tsr"), o);
    ASSERT_FALSE(cut.ok());
    EXPECT_NE(cut.error().message.find("cut.tif"), std::string::npos) << cut.error().message;
    EXPECT_FALSE(std::filesystem::exists(d.file("cut.tsr")));

    // 1-bit grey, 40x20 checks of 4 texels, no BitsPerSample; the bottom strip of an 8-bit file
    // with no bytes.
    const std::uint32_t w = 40, h = 20;
    std::vector<std::uint8_t> packed((w + 7) / 8 * h, 0), grey(std::size_t(w) * h);
    RefImage checks{w, h, 1, SampleType::u8, {}};
    checks.bytes.resize(std::size_t(w) * h);
    for (std::uint32_t y = 0; y < h; ++y)
        for (std::uint32_t x = 0; x < w; ++x) {
            const bool on = (x / 4 + y / 4) % 2 == 1;
            if (on) packed[y * ((w + 7) / 8) + x / 8] |= std::uint8_t(0x80 >> (x % 8));
            checks.bytes[std::size_t(y) * w + x] = on ? 255 : 0;
            grey[std::size_t(y) * w + x] = std::uint8_t(x * 5 + y);
        }
    test::write_file(d.file("bits.tif"), handmade_grey_tiff(w, h, 1, false, 8, packed, {}));
    auto bits = build_store(d.file("bits.tif"), d.file("bits.tsr"), o);
    ASSERT_TRUE(bits.ok()) << bits.error().message;
    auto bits_reader = StoreReader::open(d.file("bits.tsr"));
    ASSERT_TRUE(bits_reader.ok());
    EXPECT_EQ(worst_level0_difference(**bits_reader, checks), 0);

    test::write_file(d.file("sparse.tif"), handmade_grey_tiff(w, h, 8, true, 8, grey, {2}));
    RefImage sparse{w, h, 1, SampleType::u8, grey};
    std::fill(sparse.bytes.begin() + std::ptrdiff_t(16 * w), sparse.bytes.end(), std::uint8_t{0});
    auto sp = build_store(d.file("sparse.tif"), d.file("sparse.tsr"), o);
    ASSERT_TRUE(sp.ok()) << sp.error().message;
    auto sparse_reader = StoreReader::open(d.file("sparse.tsr"));
    ASSERT_TRUE(sparse_reader.ok());
    EXPECT_EQ(worst_level0_difference(**sparse_reader, sparse), 0);
}

// Grey with extra bands, the last not marked alpha (GDAL's 2- and 4-band rasters other than 8-bit
// RGBA: min-is-black, ExtraSamples unspecified) is multi-band data: refused by name, not
// built with a band of data as alpha. Marked alpha, or RGB with an unspecified fourth band (as
// libtiff reads it), the last band is alpha.
TEST(Builder, TiffBandsNotMarkedAlphaAreRefused) {
    ScratchDir d;
    const std::string ramp = " -alpha set -channel A -fx 'i/w' +channel ";
    auto im = [&](const std::string& args, const std::string& out) {
        return run_tool("convert-im6.q16 -size 40x20 " + args + " " + d.file(out));
    };
    ASSERT_TRUE(im("xc:gray50" + ramp + "-define tiff:alpha=unspecified", "la_unspecified.tif"));
    ASSERT_TRUE(im("xc:gray50" + ramp + "-define tiff:alpha=unassociated", "la_alpha.tif"));
    ASSERT_TRUE(im("xc:red" + ramp + "-depth 8 -define tiff:alpha=unspecified", "rgba_unspecified.tif"));
    // Four bands of grey and three unspecified extras, as GDAL writes a 4-band UInt16 raster.
    ASSERT_TRUE(run_tool("cp " + d.file("rgba_unspecified.tif") + " " + d.file("bands4.tif") + " && tiffset -s 262 1 " +
                         d.file("bands4.tif")));
    ASSERT_TRUE(run_tool("tiffinfo " + d.file("bands4.tif") + " 2>/dev/null | grep -q 'Extra Samples: 3<unspecified'"));
    // The same bands planar (GDAL's INTERLEAVE=BAND): a layout left to OpenImageIO, refused all the same.
    ASSERT_TRUE(run_tool("tiffcp -p separate " + d.file("bands4.tif") + " " + d.file("bands4_planar.tif")));
    const BuildOptions o = small_tiles(Codec::zstd);
    for (const auto& [file, hint] : {std::pair{"la_unspecified.tif", "gdal_translate -b 1 "}, std::pair{"bands4.tif", "-b 3 -b 2 -b 1"},
                                     std::pair{"bands4_planar.tif", "-b 3 -b 2 -b 1"}}) {
        SCOPED_TRACE(file);
        const auto r = build_store(d.file(file), d.file("refused.tsr"), o);
        ASSERT_FALSE(r.ok());
        EXPECT_EQ(r.error().code, Errc::invalid_argument);
        EXPECT_NE(r.error().message.find(file), std::string::npos) << r.error().message;
        EXPECT_NE(r.error().message.find("the last is not marked alpha"), std::string::npos) << r.error().message;
        EXPECT_NE(r.error().message.find(hint), std::string::npos) << r.error().message;
        EXPECT_FALSE(std::filesystem::exists(d.file("refused.tsr")));
    }
    for (const char* file : {"la_alpha.tif", "rgba_unspecified.tif"}) {
        SCOPED_TRACE(file);
        const auto r = build_store(d.file(file), d.file("ok.tsr"), o);
        ASSERT_TRUE(r.ok()) << r.error().message;
        auto reader = StoreReader::open(d.file("ok.tsr"));
        ASSERT_TRUE(reader.ok());
        EXPECT_TRUE((*reader)->info().has_alpha) << file;
    }
}

// A WebP's EXIF orientation (OpenImageIO 2.4's WebP reader does not report it): a lossless WebP
// from cwebp, tagged 6 (and 3) by webpmux, is built as ImageMagick turns the source, texel exact.
TEST(Builder, WebpExifOrientationIsApplied) {
    ScratchDir d;
    const RefImage im = test_pattern(150, 110, 3, SampleType::u8, 5);
    write_raw(d.file("in.rgb"), im);
    ASSERT_TRUE(run_tool("convert-im6.q16 -size 150x110 -depth 8 rgb:" + d.file("in.rgb") + " " + d.file("in.png")));
    ASSERT_TRUE(run_tool("cwebp -quiet -lossless " + d.file("in.png") + " -o " + d.file("in.webp")));
    BuildOptions o = small_tiles(Codec::zstd);
    for (const auto& [orientation, turn] : {std::pair{6, "-rotate 90"}, std::pair{3, "-rotate 180"}}) {
        SCOPED_TRACE("orientation " + std::to_string(orientation));
        // EXIF as a little-endian TIFF header and one IFD entry: Orientation (0x0112), SHORT.
        const std::vector<std::uint8_t> exif = {'I', 'I', 42, 0, 8, 0, 0, 0, 1, 0, 0x12, 0x01, 3, 0, 1, 0, 0, 0,
                                                std::uint8_t(orientation), 0, 0, 0, 0, 0, 0, 0};
        test::write_file(d.file("exif.bin"), exif);
        const std::string tagged = d.file("o" + std::to_string(orientation) + ".webp");
        ASSERT_TRUE(run_tool("webpmux -set exif " + d.file("exif.bin") + " " + d.file("in.webp") + " -o " + tagged + " >/dev/null"));
        ASSERT_TRUE(run_tool("convert-im6.q16 " + d.file("in.png") + " " + turn + " " + d.file("ref.png")));
        auto r = build_store(tagged, d.file("a.tsr"), o);
        ASSERT_TRUE(r.ok()) << r.error().message;
        auto reader = StoreReader::open(d.file("a.tsr"));
        ASSERT_TRUE(reader.ok());
        EXPECT_EQ(worst_level0_difference(**reader, read_file_samples(d.file("ref.png"))), 0);
    }
}

// Binary PGM and PPM as ImageMagick writes them keep every sample: OpenImageIO 2.4's PNM reader
// lost the lowest bit of about half of a 16-bit file's samples. A maxval of 1000 is scaled to
// the full 16 bits; a file cut short is an error.
TEST(Builder, PgmAndPpmKeepEverySample) {
    ScratchDir d;
    BuildOptions o = small_tiles(Codec::zstd);
    for (const auto& [channels, type, ext] : {std::tuple{1u, SampleType::u16, "pgm"}, std::tuple{3u, SampleType::u8, "ppm"},
                                               std::tuple{3u, SampleType::u16, "ppm"}}) {
        SCOPED_TRACE(std::string(ext) + (type == SampleType::u16 ? " 16-bit" : " 8-bit"));
        const RefImage im = test_pattern(150, 110, channels, type, 11);
        write_raw(d.file("in.raw"), im);
        const std::string file = d.file(std::string("in.") + ext);
        ASSERT_TRUE(run_tool(std::string("convert-im6.q16 -endian LSB -size 150x110 -depth ") + (type == SampleType::u16 ? "16 " : "8 ") +
                             (channels == 1 ? "gray:" : "rgb:") + d.file("in.raw") + " " + file));
        auto r = build_store(file, d.file("a.tsr"), o);
        ASSERT_TRUE(r.ok()) << r.error().message;
        auto reader = StoreReader::open(d.file("a.tsr"));
        ASSERT_TRUE(reader.ok());
        expect_exact(Built{*reader, test::reference_pyramid(im, ColourSpace::srgb, false, o.tile_size - 2 * o.border)});
    }
    // maxval 1000: v -> round(v * 65535 / 1000).
    std::string pgm = "P5\n# a comment\n3 1# a comment right after a number, as netpbm allows\n1000\n";
    for (const int v : {0, 500, 1000}) pgm += {char(v >> 8), char(v & 255)};
    test::write_file(d.file("m.pgm"), std::vector<std::uint8_t>(pgm.begin(), pgm.end()));
    auto m = build_store(d.file("m.pgm"), d.file("m.tsr"), o);
    ASSERT_TRUE(m.ok()) << m.error().message;
    auto reader = StoreReader::open(d.file("m.tsr"));
    ASSERT_TRUE(reader.ok());
    const std::vector<std::uint8_t> t = tile_texels(**reader, 0, 0, 0);
    const std::uint32_t b = (*reader)->info().border, ts = (*reader)->info().tile_size();
    for (const auto& [x, want] : {std::pair{0u, 0u}, std::pair{1u, 32768u}, std::pair{2u, 65535u}}) {
        std::uint16_t got = 0;
        std::memcpy(&got, t.data() + (std::size_t(b) * ts + b + x) * 2, 2);
        EXPECT_EQ(got, want) << "texel " << x;
    }
    pgm.resize(pgm.size() - 3);
    test::write_file(d.file("cut.pgm"), std::vector<std::uint8_t>(pgm.begin(), pgm.end()));
    auto cut = build_store(d.file("cut.pgm"), d.file("cut.tsr"), o);
    ASSERT_FALSE(cut.ok());
    EXPECT_NE(cut.error().message.find("cut.pgm"), std::string::npos) << cut.error().message;
    EXPECT_FALSE(std::filesystem::exists(d.file("cut.tsr")));
}

// Building over the input would read it whole and then replace it with the store.
TEST(Builder, RefusesToWriteOverItsInput) {
    ScratchDir d;
    const RefImage im = test_pattern(40, 30, 3, SampleType::u8, 3);
    write_raw(d.file("in.rgb"), im);
    ASSERT_TRUE(run_tool("convert-im6.q16 -size 40x30 -depth 8 rgb:" + d.file("in.rgb") + " " + d.file("in.png")));
    const auto before = std::filesystem::file_size(d.file("in.png"));
    auto r = build_store(d.file("in.png"), d.file("in.png"), small_tiles(Codec::zstd));
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, Errc::invalid_argument);
    EXPECT_EQ(std::filesystem::file_size(d.file("in.png")), before);
    EXPECT_EQ(read_file_samples(d.file("in.png")).bytes, im.bytes);
    // The same for a layer's input (through another name for the same file) and a mosaic manifest.
    std::filesystem::create_hard_link(d.file("in.png"), d.file("same.png"));
    const std::vector<LayerInput> layers = {{"a", d.file("in.png"), {}}, {"b", d.file("in.png"), {}}};
    auto layered = build_layered_store(layers, d.file("same.png"), small_tiles(Codec::zstd));
    ASSERT_FALSE(layered.ok());
    EXPECT_EQ(layered.error().code, Errc::invalid_argument) << layered.error().message;
    EXPECT_EQ(read_file_samples(d.file("in.png")).bytes, im.bytes);
    {
        std::FILE* f = std::fopen(d.file("m.json").c_str(), "w");
        ASSERT_TRUE(f);
        std::fprintf(f, "{\"width\": 40, \"height\": 30, \"images\": [{\"path\": \"in.png\", \"x\": 0, \"y\": 0}]}");
        std::fclose(f);
    }
    auto mosaic = build_sparse_store(d.file("m.json"), d.file("m.json"), small_tiles(Codec::zstd));
    ASSERT_FALSE(mosaic.ok());
    EXPECT_EQ(mosaic.error().code, Errc::invalid_argument) << mosaic.error().message;
    EXPECT_NE(mosaic.error().message.find("is the input"), std::string::npos) << mosaic.error().message;
}
