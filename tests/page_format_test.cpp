// Page formats: sizes, which stores take which format, BC1 pages checked by an independent decoder
// (libsquish) and BC4/BC5 pages by the format's definition against the RGBA8 page, and the exact
// 16-bit and float formats.
#include <gtest/gtest.h>
#include <squish.h>

#include <cmath>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "tessera/storage/builder.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/store_writer.hpp"
#include "test_util.hpp"
#include "block_decode.hpp"
#include "transcode.hpp"

namespace {

using namespace tessera;
using namespace tessera::client;
using storage::SampleType;
using test::ScratchDir;
using storage::StoreInfo;

// PSNR of `got` against `want` over the channels listed (8-bit values, same texel stride).
double psnr(const std::vector<std::uint8_t>& want, const std::vector<std::uint8_t>& got, std::size_t stride,
            std::initializer_list<std::size_t> channels) {
    double se = 0;
    std::size_t n = 0;
    for (std::size_t i = 0; i + stride <= want.size(); i += stride)
        for (std::size_t c : channels) {
            const double d = double(want[i + c]) - double(got[i + c]);
            se += d * d;
            ++n;
        }
    if (se == 0) return 99.0;
    return 10.0 * std::log10(255.0 * 255.0 / (se / double(n)));
}

// libsquish's decode of a page of BC1 blocks into RGBA8.
std::vector<std::uint8_t> squish_decode(const std::vector<std::uint8_t>& blocks, std::uint32_t size, int flags) {
    std::vector<std::uint8_t> rgba(std::size_t(size) * size * 4, 0);
    squish::DecompressImage(rgba.data(), int(size), int(size), blocks.data(), flags);
    return rgba;
}

// BC4 blocks decoded by the format's definition (Direct3D 10 / ARB_texture_compression_rgtc):
// libsquish 1.15 encodes BC4 and BC5 but does not decode them. `stride` and `channel` place the
// decoded value into an RGBA8 page; BC5 is a BC4 block for channel 0 followed by one for channel 1.
void decode_bc4_page(const std::vector<std::uint8_t>& blocks, std::size_t first, std::size_t block_stride,
                     std::uint32_t size, std::vector<std::uint8_t>& rgba, unsigned channel) {
    std::size_t b = first;
    for (std::uint32_t by = 0; by < size; by += 4)
        for (std::uint32_t bx = 0; bx < size; bx += 4, b += block_stride) {
            const int r0 = blocks[b], r1 = blocks[b + 1];
            double pal[8] = {double(r0), double(r1)};
            if (r0 > r1) {
                for (int i = 2; i < 8; ++i) pal[i] = ((8 - i) * r0 + (i - 1) * r1) / 7.0;
            } else {
                for (int i = 2; i < 6; ++i) pal[i] = ((6 - i) * r0 + (i - 1) * r1) / 5.0;
                pal[6] = 0;
                pal[7] = 255;
            }
            std::uint64_t bits = 0;
            for (int i = 0; i < 6; ++i) bits |= std::uint64_t(blocks[b + 2 + i]) << (8 * i);
            for (int j = 0; j < 16; ++j) {
                const std::size_t x = bx + j % 4, y = by + j / 4;
                rgba[(y * size + x) * 4 + channel] = static_cast<std::uint8_t>(std::lround(pal[(bits >> (3 * j)) & 7]));
            }
        }
}

// Data (linear) unless `colour` says sRGB: bc4, bc5 and the exact formats hold data.
StoreInfo info_of(std::uint32_t channels, SampleType t, std::uint32_t tile_size = 256, bool alpha = false,
                  storage::ColourSpace colour = storage::ColourSpace::linear) {
    storage::StoreSpec s;
    s.colour_space = colour;
    s.width = s.height = tile_size * 2;
    s.tile_payload = tile_size - 8;
    s.border = 4;
    s.channels = channels;
    s.sample_type = t;
    s.has_alpha = alpha;
    s.codec = Codec::raw;
    return storage::store_info(s);
}

TEST(PageFormat, NamesAndSizes) {
    for (auto f : {PageFormat::rgba8, PageFormat::bc1, PageFormat::bc4, PageFormat::bc5, PageFormat::bc7, PageFormat::r16,
                   PageFormat::r16f, PageFormat::r32f})
        EXPECT_EQ(parse_page_format(to_string(f)), f);
    EXPECT_EQ(parse_page_format("bc7x"), std::nullopt);
    EXPECT_EQ(page_bytes(PageFormat::rgba8, 256), 262144u);
    EXPECT_EQ(page_bytes(PageFormat::bc1, 256), 32768u);  // 8x the pages of RGBA8 in the same bytes
    EXPECT_EQ(page_bytes(PageFormat::bc4, 256), 32768u);
    EXPECT_EQ(page_bytes(PageFormat::bc5, 256), 65536u);
    EXPECT_EQ(page_bytes(PageFormat::bc7, 256), 65536u);
    EXPECT_EQ(page_bytes(PageFormat::r16, 256), 131072u);
    EXPECT_EQ(page_bytes(PageFormat::r32f, 256), 262144u);
}

TEST(PageFormat, StoresThatCannotTakeAFormatGetAClearError) {
    const auto refused = [](const StoreInfo& info, PageFormat f, const std::string& words) {
        const Status st = check_page_format(info, f);
        ASSERT_FALSE(st.ok()) << to_string(f);
        EXPECT_EQ(st.error().code, Errc::invalid_argument);
        EXPECT_NE(st.error().message.find(std::string(to_string(f))), std::string::npos) << st.error().message;
        EXPECT_NE(st.error().message.find(words), std::string::npos) << st.error().message;
    };
    refused(info_of(4, SampleType::u8, 256, true), PageFormat::bc1, "alpha");
    refused(info_of(3, SampleType::u8), PageFormat::bc4, "1 channel");
    refused(info_of(1, SampleType::u8), PageFormat::bc5, "2 channels");
    refused(info_of(1, SampleType::u8), PageFormat::r16, "u16");
    refused(info_of(1, SampleType::u16), PageFormat::r16f, "f16");
    refused(info_of(3, SampleType::f32), PageFormat::r32f, "1 channel");
    refused(info_of(3, SampleType::u8, 66), PageFormat::bc1, "multiple of 4");
    // sRGB colour in a format the GPU samples as stored would be encoded twice on its way to the
    // screen: a grey photo's 134 shown as 192.
    const auto srgb = storage::ColourSpace::srgb;
    refused(info_of(1, SampleType::u8, 256, false, srgb), PageFormat::bc4, "sRGB");
    refused(info_of(2, SampleType::u8, 256, true, srgb), PageFormat::bc5, "sRGB");
    refused(info_of(1, SampleType::u16, 256, false, srgb), PageFormat::r16, "sRGB");
    for (const auto f : {PageFormat::rgba8, PageFormat::bc1, PageFormat::bc7})
        EXPECT_TRUE(check_page_format(info_of(3, SampleType::u8, 256, false, srgb), f).ok()) << to_string(f);
    EXPECT_TRUE(check_page_format(info_of(3, SampleType::u8), PageFormat::bc1).ok());
    EXPECT_TRUE(check_page_format(info_of(1, SampleType::u16), PageFormat::bc4).ok());
    EXPECT_TRUE(check_page_format(info_of(2, SampleType::u8, 256, true), PageFormat::bc5).ok());
    EXPECT_TRUE(check_page_format(info_of(4, SampleType::u8, 256, true), PageFormat::rgba8).ok());

    // A destination of the wrong size is refused, never overrun.
    Scratch scratch;
    const StoreInfo rgb = info_of(3, SampleType::u8);
    std::vector<std::uint8_t> payload(rgb.tile_bytes(), 7), out(page_bytes(PageFormat::bc1, 256) - 8);
    const Status st = transcode_page(rgb, TileKind::present, Codec::raw, payload, PageFormat::bc1, out, scratch);
    ASSERT_FALSE(st.ok());
    EXPECT_EQ(st.error().code, Errc::invalid_argument);
}

// Every level-0 tile of the demo terrain (built as JPEG, as `tessera build` does by default) as a
// BC1 page: libsquish decodes it to within 32 dB of the RGBA8 page.
TEST(PageFormat, Bc1PagesOfTheTerrainDecodeCloseToRgba8) {
    ScratchDir dir;
    storage::BuildOptions o;
    o.threads = 2;
    auto built = storage::build_store("procedural:terrain:1000", dir.file("t.tsr"), o);
    ASSERT_TRUE(built.ok()) << built.error().message;
    auto reader = storage::StoreReader::open(dir.file("t.tsr"));
    ASSERT_TRUE(reader.ok());
    const StoreInfo& info = (*reader)->info();
    Scratch scratch;
    const std::uint32_t size = info.tile_size();
    std::vector<std::uint8_t> rgba(page_bytes(PageFormat::rgba8, size)), bc1(page_bytes(PageFormat::bc1, size));
    double worst = 99;
    for (std::uint32_t y = 0; y < info.levels[0].tiles_y; ++y)
        for (std::uint32_t x = 0; x < info.levels[0].tiles_x; ++x) {
            auto tile = (*reader)->read_tile({0, x, y});
            ASSERT_TRUE(tile.ok());
            ASSERT_TRUE(transcode_page(info, tile->kind, info.codec, tile->bytes, PageFormat::rgba8, rgba, scratch).ok());
            const Status st = transcode_page(info, tile->kind, info.codec, tile->bytes, PageFormat::bc1, bc1, scratch);
            ASSERT_TRUE(st.ok()) << st.error().message;
            worst = std::min(worst, psnr(rgba, squish_decode(bc1, size, squish::kDxt1), 4, {0, 1, 2}));
        }
    EXPECT_GE(worst, 32.0) << "worst tile's BC1 PSNR against its RGBA8 page";
    RecordProperty("bc1_worst_tile_psnr_db", std::to_string(worst));
}

// A smooth grey tile (a height map's preview) as BC4 and a two-channel tile as BC5.
TEST(PageFormat, Bc4AndBc5KeepTheirChannels) {
    Scratch scratch;
    const std::uint32_t size = 256;
    std::mt19937 rng(3);
    std::vector<std::uint8_t> grey(std::size_t(size) * size), two(std::size_t(size) * size * 2);
    for (std::uint32_t y = 0; y < size; ++y)
        for (std::uint32_t x = 0; x < size; ++x) {
            const double h = 127.5 + 80 * std::sin(x * 0.05) * std::cos(y * 0.03) + 20 * std::sin((x + y) * 0.2);
            grey[y * size + x] = static_cast<std::uint8_t>(std::lround(h) + int(rng() % 3) - 1);
            two[2 * (y * size + x)] = static_cast<std::uint8_t>(128 + 100 * std::sin(x * 0.04));
            two[2 * (y * size + x) + 1] = static_cast<std::uint8_t>(128 + 100 * std::cos(y * 0.04));
        }
    const StoreInfo g = info_of(1, SampleType::u8, size);
    std::vector<std::uint8_t> rgba(page_bytes(PageFormat::rgba8, size)), bc4(page_bytes(PageFormat::bc4, size));
    ASSERT_TRUE(transcode_page(g, TileKind::present, Codec::raw, grey, PageFormat::rgba8, rgba, scratch).ok());
    ASSERT_TRUE(transcode_page(g, TileKind::present, Codec::raw, grey, PageFormat::bc4, bc4, scratch).ok());
    std::vector<std::uint8_t> decoded(rgba.size(), 0);
    decode_bc4_page(bc4, 0, 8, size, decoded, 0);
    const double p4 = psnr(rgba, decoded, 4, {0});
    EXPECT_GE(p4, 40.0);

    const StoreInfo va = info_of(2, SampleType::u8, size, true);
    std::vector<std::uint8_t> bc5(page_bytes(PageFormat::bc5, size));
    ASSERT_TRUE(transcode_page(va, TileKind::present, Codec::raw, two, PageFormat::rgba8, rgba, scratch).ok());
    ASSERT_TRUE(transcode_page(va, TileKind::present, Codec::raw, two, PageFormat::bc5, bc5, scratch).ok());
    // BC5 channel 0 is the value (RGBA8's R), channel 1 the alpha (RGBA8's A).
    std::fill(decoded.begin(), decoded.end(), 0);
    decode_bc4_page(bc5, 0, 16, size, decoded, 0);
    decode_bc4_page(bc5, 8, 16, size, decoded, 1);
    std::vector<std::uint8_t> want(decoded.size());
    for (std::size_t i = 0; i < want.size(); i += 4) {
        want[i] = rgba[i];
        want[i + 1] = rgba[i + 3];
    }
    EXPECT_GE(psnr(want, decoded, 4, {0, 1}), 40.0);
}

// 16-bit and float stores reach their page formats without losing a bit: the page is the stored
// samples, for raw, zstd and uniform tiles.
TEST(PageFormat, SixteenBitAndFloatPagesAreTheStoredSamplesExactly) {
    Scratch scratch;
    std::mt19937 rng(5);
    for (auto [type, format] : {std::pair{SampleType::u16, PageFormat::r16}, std::pair{SampleType::f16, PageFormat::r16f},
                                std::pair{SampleType::f32, PageFormat::r32f}}) {
        const StoreInfo info = info_of(1, type);
        std::vector<std::uint8_t> samples(info.tile_bytes());
        for (auto& b : samples) b = static_cast<std::uint8_t>(rng());
        std::vector<std::uint8_t> out(page_bytes(format, info.tile_size()));
        ASSERT_EQ(out.size(), samples.size());
        ASSERT_TRUE(transcode_page(info, TileKind::present, Codec::raw, samples, format, out, scratch).ok());
        EXPECT_EQ(out, samples) << to_string(format) << " raw";

        std::fill(out.begin(), out.end(), 0);
        StoreInfo zinfo = info;
        zinfo.codec = Codec::zstd;
        const auto z = storage::encode_tile(zinfo, samples, {});
        ASSERT_TRUE(z.ok());
        ASSERT_TRUE(transcode_page(zinfo, TileKind::present, Codec::zstd, *z, format, out, scratch).ok());
        EXPECT_EQ(out, samples) << to_string(format) << " zstd";

        const std::vector<std::uint8_t> value(samples.begin(), samples.begin() + std::ptrdiff_t(info.texel_bytes()));
        ASSERT_TRUE(transcode_page(info, TileKind::uniform, Codec::raw, value, format, out, scratch).ok());
        for (std::size_t i = 0; i < out.size(); i += value.size())
            ASSERT_EQ(std::memcmp(out.data() + i, value.data(), value.size()), 0) << to_string(format) << " uniform";

        const Status jpeg = transcode_page(info, TileKind::present, Codec::jpeg, samples, format, out, scratch);
        EXPECT_FALSE(jpeg.ok());
    }
}

}  // namespace

namespace {

// The block decoder the reference images use (block_decode.hpp) agrees with libsquish on BC1,
// and a page's second level (transcode_page's second_level) is its 2x2 means, block-encoded:
// linear-light means for an sRGB store, plain means for a linear one.
TEST(PageFormat, SecondLevelIsTheBlockEncodedTwoByTwoMeans) {
    Scratch scratch;
    const std::uint32_t size = 256, half = size / 2;
    std::mt19937 rng(11);
    std::vector<std::uint8_t> rgb(std::size_t(size) * size * 3);
    for (std::uint32_t y = 0; y < size; ++y)
        for (std::uint32_t x = 0; x < size; ++x)
            for (int c = 0; c < 3; ++c)
                rgb[(std::size_t(y) * size + x) * 3 + std::size_t(c)] =
                    static_cast<std::uint8_t>(128 + 90 * std::sin(x * 0.03 + c) * std::cos(y * 0.02) + int(rng() % 9) - 4);
    for (const bool srgb : {true, false}) {
        StoreInfo info = info_of(3, SampleType::u8, size);
        info.colour_space = srgb ? storage::ColourSpace::srgb : storage::ColourSpace::linear;
        std::vector<std::uint8_t> rgba(page_bytes(PageFormat::rgba8, size));
        std::vector<std::uint8_t> both(page_upload_bytes(PageFormat::bc1, size, true));
        ASSERT_TRUE(transcode_page(info, TileKind::present, Codec::raw, rgb, PageFormat::rgba8, rgba, scratch).ok());
        const Status st = transcode_page(info, TileKind::present, Codec::raw, rgb, PageFormat::bc1, both, scratch, true);
        ASSERT_TRUE(st.ok()) << st.error().message;

        // Level 0: our decoder and libsquish's read the same blocks alike.
        const std::vector<std::uint8_t> level0(both.begin(), both.begin() + std::ptrdiff_t(page_bytes(PageFormat::bc1, size)));
        std::vector<std::uint8_t> ours(rgba.size());
        ASSERT_TRUE(decode_block_page(PageFormat::bc1, level0.data(), size, ours.data()));
        EXPECT_GE(psnr(ours, squish_decode(level0, size, squish::kDxt1), 4, {0, 1, 2}), 48.0);

        // Level 1: close to the 2x2 means of the RGBA8 page, taken as the store's builder does.
        std::vector<std::uint8_t> means(std::size_t(half) * half * 4);
        const auto lin = [](int v) { const double s = v / 255.0; return s <= 0.04045 ? s / 12.92 : std::pow((s + 0.055) / 1.055, 2.4); };
        const auto enc = [](double l) { return l <= 0.0031308 ? l * 12.92 : 1.055 * std::pow(l, 1 / 2.4) - 0.055; };
        for (std::uint32_t y = 0; y < half; ++y)
            for (std::uint32_t x = 0; x < half; ++x)
                for (int c = 0; c < 4; ++c) {
                    const auto at = [&](std::uint32_t xx, std::uint32_t yy) { return int(rgba[(std::size_t(yy) * size + xx) * 4 + std::size_t(c)]); };
                    const int a = at(2 * x, 2 * y), b = at(2 * x + 1, 2 * y), d = at(2 * x, 2 * y + 1), e = at(2 * x + 1, 2 * y + 1);
                    const double m = srgb && c < 3 ? 255 * enc((lin(a) + lin(b) + lin(d) + lin(e)) / 4) : (a + b + d + e) / 4.0;
                    means[(std::size_t(y) * half + x) * 4 + std::size_t(c)] = static_cast<std::uint8_t>(std::lround(m));
                }
        std::vector<std::uint8_t> level1(std::size_t(half) * half * 4);
        ASSERT_TRUE(decode_block_page(PageFormat::bc1, both.data() + page_bytes(PageFormat::bc1, size), half, level1.data()));
        EXPECT_GE(psnr(level1, means, 4, {0, 1, 2}), 32.0) << (srgb ? "sRGB" : "linear");
    }
    // The second level is for block formats with tiles a multiple of 8 only.
    const StoreInfo odd = info_of(3, SampleType::u8, 260);
    std::vector<std::uint8_t> payload(odd.tile_bytes()), out(page_upload_bytes(PageFormat::bc1, 260, true));
    EXPECT_FALSE(transcode_page(odd, TileKind::present, Codec::raw, payload, PageFormat::bc1, out, scratch, true).ok());
    std::vector<std::uint8_t> rgba_out(page_bytes(PageFormat::rgba8, 256));
    EXPECT_FALSE(transcode_page(info_of(3, SampleType::u8), TileKind::present, Codec::raw,
                                std::vector<std::uint8_t>(info_of(3, SampleType::u8).tile_bytes()), PageFormat::rgba8, rgba_out,
                                scratch, true)
                     .ok());
}

// A store built with a block codec (blocks made by the builder, quality first): a pool of that
// format gets the stored blocks and second level as they are, an RGBA8 pool their decode, and the
// blocks are close to a lossless build of the same source.
TEST(PageFormat, BlockCodecStoresReachThePoolAsStored) {
    ScratchDir dir;
    storage::BuildOptions o;
    o.threads = 2;
    o.codec = Codec::zstd;
    ASSERT_TRUE(storage::build_store("procedural:terrain:480", dir.file("lossless.tsr"), o).ok());
    auto lossless = storage::StoreReader::open(dir.file("lossless.tsr"));
    ASSERT_TRUE(lossless.ok());
    struct Case {
        Codec codec;
        PageFormat format;
        double min_psnr;  // decoded blocks against the lossless page, worst tile
    };
    for (const Case c : {Case{Codec::bc1, PageFormat::bc1, 29.0}, Case{Codec::bc7, PageFormat::bc7, 40.0}}) {
        SCOPED_TRACE(std::string(to_string(c.codec)));
        o.codec = c.codec;
        const std::string path = dir.file(std::string(to_string(c.codec)) + ".tsr");
        auto built = storage::build_store("procedural:terrain:480", path, o);
        ASSERT_TRUE(built.ok()) << built.error().message;
        auto reader = storage::StoreReader::open(path);
        ASSERT_TRUE(reader.ok());
        const StoreInfo& info = (*reader)->info();
        ASSERT_EQ(info.codec, c.codec);
        const std::uint32_t size = info.tile_size();
        Scratch scratch;
        std::vector<std::uint8_t> blocks, pool(page_upload_bytes(c.format, size, true)), rgba(page_bytes(PageFormat::rgba8, size)),
            decoded(rgba.size()), want(rgba.size());
        double worst = 99;
        for (std::uint32_t level = 0; level < info.level_count(); ++level)
            for (std::uint32_t y = 0; y < info.levels[level].tiles_y; ++y)
                for (std::uint32_t x = 0; x < info.levels[level].tiles_x; ++x) {
                    auto tile = (*reader)->read_tile({level, x, y});
                    ASSERT_TRUE(tile.ok());
                    ASSERT_EQ(tile->kind, TileKind::present);
                    ASSERT_TRUE(storage::unpack_block_tile(info, tile->bytes, blocks).ok());
                    ASSERT_TRUE(transcode_page(info, tile->kind, info.codec, tile->bytes, c.format, pool, scratch, true).ok());
                    EXPECT_EQ(pool, blocks) << "tile " << level << "/" << x << "/" << y;
                    ASSERT_TRUE(transcode_to_rgba8(info, tile->kind, info.codec, tile->bytes, rgba, scratch).ok());
                    ASSERT_TRUE(decode_block_page(c.format, blocks.data(), size, decoded.data()));
                    EXPECT_EQ(rgba, decoded) << "tile " << level << "/" << x << "/" << y;
                    auto source = (*lossless)->read_tile({level, x, y});
                    ASSERT_TRUE(source.ok());
                    const StoreInfo& li = (*lossless)->info();
                    ASSERT_TRUE(transcode_to_rgba8(li, source->kind, li.codec, source->bytes, want, scratch).ok());
                    worst = std::min(worst, psnr(want, decoded, 4, {0, 1, 2}));
                }
        EXPECT_GE(worst, c.min_psnr);
        RecordProperty(std::string(to_string(c.codec)) + "_worst_tile_psnr_db", std::to_string(worst));
        if (c.codec == Codec::bc1) {  // an independent decoder reads the builder's blocks alike
            auto tile = (*reader)->read_tile({0, 0, 0});
            ASSERT_TRUE(tile.ok() && storage::unpack_block_tile(info, tile->bytes, blocks).ok());
            blocks.resize(page_bytes(PageFormat::bc1, size));
            ASSERT_TRUE(decode_block_page(PageFormat::bc1, blocks.data(), size, decoded.data()));
            EXPECT_GE(psnr(decoded, squish_decode(blocks, size, squish::kDxt1), 4, {0, 1, 2}), 48.0);
        }
    }
}

}  // namespace
