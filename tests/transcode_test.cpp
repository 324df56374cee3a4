// The transcode pool: transcode_to_rgba8 against the store's reference decoder (storage::decode_tile
// plus the documented RGBA8 conversion, written out independently here), corrupt payloads, and
// the pool's queueing contract (exactly-once completion, bounds, dropping, priority, shutdown).
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "transcode.hpp"
#include "tessera/storage/builder.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/image_source.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/store_writer.hpp"
#include "test_util.hpp"

namespace tessera::client {
namespace {

using tessera::Codec;
using storage::SampleType;
using storage::StoreInfo;
using storage::Tile;
using tessera::TileKind;

static_assert(std::endian::native == std::endian::little, "the reference below reads floats in host order");

// ------------------------------------------------------------------ reference RGBA8 conversion
// Independent of the implementation: doubles, std::ldexp for halves, std::lround for rounding.

double half_value(std::uint16_t h) {
    const int sign = (h >> 15) & 1, exp = (h >> 10) & 31, mant = h & 1023;
    double v;
    if (exp == 0)
        v = std::ldexp(double(mant), -24);
    else if (exp == 31)
        v = mant ? std::nan("") : INFINITY;
    else
        v = std::ldexp(double(1024 + mant), exp - 25);
    return sign ? -v : v;
}

std::uint8_t unit_to_u8(double v) {
    if (std::isnan(v)) return 0;
    return static_cast<std::uint8_t>(std::lround(std::clamp(v, 0.0, 1.0) * 255.0));
}

std::uint8_t reference_sample(SampleType t, const std::uint8_t* p) {
    switch (t) {
        case SampleType::u8: return *p;
        case SampleType::u16: return static_cast<std::uint8_t>(std::lround((p[0] | (p[1] << 8)) / 257.0));
        case SampleType::f16: return unit_to_u8(half_value(static_cast<std::uint16_t>(p[0] | (p[1] << 8))));
        case SampleType::f32: {
            float f;
            std::memcpy(&f, p, 4);
            return unit_to_u8(f);
        }
    }
    return 0;
}

// decode_tile's output (tile_bytes()) to RGBA8 with the rules of transcode.hpp.
std::vector<std::uint8_t> reference_rgba8(const StoreInfo& info, const std::vector<std::uint8_t>& decoded) {
    const std::size_t sb = storage::sample_bytes(info.sample_type);
    const std::size_t n = std::size_t(info.tile_size()) * info.tile_size();
    std::vector<std::uint8_t> out(n * 4);
    for (std::size_t i = 0; i < n; ++i) {
        std::uint8_t c[4];
        for (unsigned k = 0; k < info.channels; ++k)
            c[k] = reference_sample(info.sample_type, decoded.data() + (i * info.channels + k) * sb);
        std::uint8_t* o = out.data() + i * 4;
        switch (info.channels) {
            case 1: o[0] = o[1] = o[2] = c[0], o[3] = 255; break;
            case 2: o[0] = o[1] = o[2] = c[0], o[3] = c[1]; break;
            case 3: o[0] = c[0], o[1] = c[1], o[2] = c[2], o[3] = 255; break;
            default: std::memcpy(o, c, 4);
        }
    }
    return out;
}



// storage::decode_tile on a thread of its own. Its thread-local libjpeg-turbo handle is unusable
// after a JPEG whose header fails to parse (libjpeg-turbo 2.1: every later header read on that
// handle fails), so after a damaged tile it would reject good ones; a fresh thread has a fresh handle.
Status reference_decode(const StoreInfo& info, const Tile& tile, std::vector<std::uint8_t>& out) {
    Status status;
    std::thread([&] { status = storage::decode_tile(info, tile, out); }).join();
    return status;
}

// Transcodes `tile` and checks it against the reference; also checks both agree on failure.
// Returns true when the tile decoded (and matched).
bool expect_matches_reference(const StoreInfo& info, const Tile& tile, Scratch& scratch, const std::string& what) {
    std::vector<std::uint8_t> decoded;
    const Status ref = reference_decode(info, tile, decoded);
    std::vector<std::uint8_t> out(rgba8_page_bytes(info), 0xCD);
    const Status got = transcode_to_rgba8(info, tile.kind, info.codec, tile.bytes, out, scratch);
    EXPECT_EQ(ref.ok(), got.ok()) << what << ": reference " << (ref.ok() ? "ok" : ref.error().message)
                                  << ", transcode " << (got.ok() ? "ok" : got.error().message);
    if (!ref.ok() || !got.ok()) return false;
    const std::vector<std::uint8_t> want = reference_rgba8(info, decoded);
    if (want != out) {
        std::size_t i = 0;
        while (want[i] == out[i]) ++i;
        ADD_FAILURE() << what << ": first difference at byte " << i << " (texel " << i / 4 << ", channel " << i % 4
                      << "): want " << int(want[i]) << ", got " << int(out[i]);
        return false;
    }
    return true;
}

// ----------------------------------------------------------------------- synthetic tiles

std::uint32_t hash32(std::uint32_t x) {
    x ^= x >> 16, x *= 0x7feb352du, x ^= x >> 15, x *= 0x846ca68bu, x ^= x >> 16;
    return x;
}

StoreInfo make_info(std::uint32_t channels, SampleType t, Codec codec, bool alpha = false, std::uint32_t payload = 120,
                    std::uint32_t border = 4) {
    storage::StoreSpec spec;
    spec.width = spec.height = 1000;
    spec.tile_payload = payload;
    spec.border = border;
    spec.channels = channels;
    spec.sample_type = t;
    spec.codec = codec;
    spec.has_alpha = alpha;
    EXPECT_TRUE(storage::validate(spec).ok());
    return storage::store_info(spec);
}

// Texels of one tile: an image-like pattern (gradients plus a little noise, so JPEG has work to
// do) for 8-bit, random bits for 16-bit (every rounding case), and for floats values in and out of
// [0, 1] plus NaN, infinities, negative zero and (f16) subnormals.
std::vector<std::uint8_t> synthetic_texels(const StoreInfo& info, std::uint32_t seed) {
    const std::uint32_t side = info.tile_size();
    const std::size_t samples = std::size_t(side) * side * info.channels;
    std::vector<std::uint8_t> out(info.tile_bytes());
    std::mt19937 rng(seed);
    for (std::size_t i = 0; i < samples; ++i) {
        const std::uint32_t texel = static_cast<std::uint32_t>(i / info.channels);
        const std::uint32_t x = texel % side, y = texel / side, c = static_cast<std::uint32_t>(i % info.channels);
        switch (info.sample_type) {
            case SampleType::u8:
                out[i] = static_cast<std::uint8_t>((x * (c + 1) + y * (3 - c % 3) + (hash32(seed ^ std::uint32_t(i)) & 15)) & 255);
                break;
            case SampleType::u16: {
                const std::uint16_t v = static_cast<std::uint16_t>(rng());
                out[2 * i] = static_cast<std::uint8_t>(v), out[2 * i + 1] = static_cast<std::uint8_t>(v >> 8);
                break;
            }
            case SampleType::f16: {
                const std::uint16_t v = static_cast<std::uint16_t>(rng());
                out[2 * i] = static_cast<std::uint8_t>(v), out[2 * i + 1] = static_cast<std::uint8_t>(v >> 8);
                break;
            }
            case SampleType::f32: {
                float f;
                switch (rng() % 16) {
                    case 0: f = std::nanf(""); break;
                    case 1: f = INFINITY; break;
                    case 2: f = -INFINITY; break;
                    case 3: f = -0.0f; break;
                    case 4: f = static_cast<float>(rng() % 256) / 255.0f; break;          // exact levels
                    case 5: f = (static_cast<float>(rng() % 255) + 0.5f) / 255.0f; break;  // near ties
                    default: f = std::uniform_real_distribution<float>(-0.25f, 1.25f)(rng);
                }
                std::memcpy(out.data() + 4 * i, &f, 4);
                break;
            }
        }
    }
    return out;
}

Tile encode_present(const StoreInfo& info, const std::vector<std::uint8_t>& texels,
                    const storage::EncodeOptions& options = {}) {
    auto enc = storage::encode_tile(info, texels, options);
    EXPECT_TRUE(enc.ok()) << (enc.ok() ? "" : enc.error().message);
    Tile t;
    t.kind = TileKind::present;
    if (enc.ok()) t.bytes = std::move(enc.value());
    return t;
}

struct Format {
    std::uint32_t channels;
    SampleType type;
    bool alpha;
    const char* name;
};
const Format kFormats[] = {
    {1, SampleType::u8, false, "grey u8"},   {2, SampleType::u8, true, "grey+alpha u8"},
    {3, SampleType::u8, false, "RGB u8"},    {4, SampleType::u8, true, "RGBA u8"},
    {1, SampleType::u16, false, "grey u16"}, {2, SampleType::u16, true, "grey+alpha u16"},
    {3, SampleType::u16, false, "RGB u16"},  {4, SampleType::u16, true, "RGBA u16"},
    {1, SampleType::f16, false, "grey f16"}, {3, SampleType::f16, false, "RGB f16"},
    {4, SampleType::f16, true, "RGBA f16"},  {1, SampleType::f32, false, "grey f32"},
    {2, SampleType::f32, false, "2ch f32"},  {3, SampleType::f32, false, "RGB f32"},
    {4, SampleType::f32, true, "RGBA f32"},
};

// ------------------------------------------------------------------ transcode_to_rgba8 tests

TEST(TranscodeTile, ZstdAndRawEveryFormatMatchReference) {
    Scratch scratch;
    for (const Format& f : kFormats) {
        for (Codec codec : {Codec::zstd, Codec::raw}) {
            // 128^2 texels, and 129^2 (not a multiple of the 4-texel fast paths: the tail too).
            for (std::uint32_t payload : {120u, 121u}) {
                const StoreInfo info = make_info(f.channels, f.type, codec, f.alpha, payload);
                for (std::uint32_t seed = 1; seed <= 2; ++seed) {
                    const Tile tile = encode_present(info, synthetic_texels(info, seed));
                    EXPECT_TRUE(expect_matches_reference(info, tile, scratch,
                                                         std::string(f.name) + " " +
                                                             std::string(tessera::to_string(codec)) + " side " +
                                                             std::to_string(info.tile_size())));
                }
            }
        }
    }
}

TEST(TranscodeTile, JpegRgbAndGreyMatchReference) {
    Scratch scratch;
    for (std::uint32_t channels : {1u, 3u}) {
        const StoreInfo info = make_info(channels, SampleType::u8, Codec::jpeg);
        for (storage::Chroma chroma : {storage::Chroma::s444, storage::Chroma::s420}) {
            for (int quality : {50, 90, 100}) {
                storage::EncodeOptions o;
                o.chroma = chroma;
                o.jpeg_quality = quality;
                const Tile tile = encode_present(info, synthetic_texels(info, static_cast<std::uint32_t>(quality)), o);
                EXPECT_TRUE(expect_matches_reference(
                    info, tile, scratch,
                    "JPEG " + std::to_string(channels) + "ch q" + std::to_string(quality) +
                        (chroma == storage::Chroma::s420 ? " 4:2:0" : " 4:4:4")));
            }
        }
    }
}

TEST(TranscodeTile, GreyJpegExpandsToOpaqueGrey) {
    // libjpeg-turbo converts grey to RGBA itself: check the expansion and alpha directly too.
    const StoreInfo info = make_info(1, SampleType::u8, Codec::jpeg);
    const Tile tile = encode_present(info, synthetic_texels(info, 7));
    std::vector<std::uint8_t> grey;
    ASSERT_TRUE(reference_decode(info, tile, grey).ok());
    std::vector<std::uint8_t> out(rgba8_page_bytes(info));
    Scratch scratch;
    ASSERT_TRUE(transcode_to_rgba8(info, TileKind::present, Codec::jpeg, tile.bytes, out, scratch).ok());
    for (std::size_t i = 0; i < grey.size(); ++i) {
        ASSERT_EQ(out[4 * i], grey[i]) << i;
        ASSERT_EQ(out[4 * i + 1], grey[i]) << i;
        ASSERT_EQ(out[4 * i + 2], grey[i]) << i;
        ASSERT_EQ(out[4 * i + 3], 255) << i;
    }
}

TEST(TranscodeTile, UniformEveryFormatMatchesReference) {
    Scratch scratch;
    std::mt19937 rng(3);
    for (const Format& f : kFormats) {
        const StoreInfo info = make_info(f.channels, f.type, Codec::zstd, f.alpha);
        for (int rep = 0; rep < 8; ++rep) {
            Tile tile;
            tile.kind = TileKind::uniform;
            const std::vector<std::uint8_t> texels = synthetic_texels(info, static_cast<std::uint32_t>(rng()));
            tile.bytes.assign(texels.begin(), texels.begin() + static_cast<std::ptrdiff_t>(info.texel_bytes()));
            EXPECT_TRUE(expect_matches_reference(info, tile, scratch, std::string("uniform ") + f.name));
        }
    }
    // A uniform tile of a JPEG store: the value, never a JPEG decode. (A reply whose codec alone
    // says uniform is read as a uniform tile: ReplyCodec.CodecUniformMakesAUniformTile.)
    const StoreInfo info = make_info(3, SampleType::u8, Codec::jpeg);
    const std::uint8_t value[3] = {10, 20, 30};
    std::vector<std::uint8_t> out(rgba8_page_bytes(info));
    ASSERT_TRUE(transcode_to_rgba8(info, TileKind::uniform, Codec::jpeg, value, out, scratch).ok());
    for (std::size_t i = 0; i < out.size(); i += 4) {
        ASSERT_EQ(out[i], 10);
        ASSERT_EQ(out[i + 1], 20);
        ASSERT_EQ(out[i + 2], 30);
        ASSERT_EQ(out[i + 3], 255);
    }
}

TEST(TranscodeTile, ConversionEdgeValues) {
    Scratch scratch;
    std::vector<std::uint8_t> out;
    auto one_texel_store = [](std::uint32_t channels, SampleType t) { return make_info(channels, t, Codec::raw, false, 2, 0); };
    auto first_texel = [&](const StoreInfo& info, const std::vector<std::uint8_t>& value) {
        out.assign(rgba8_page_bytes(info), 0);
        EXPECT_TRUE(transcode_to_rgba8(info, TileKind::uniform, Codec::raw, value, out, scratch).ok());
        return std::vector<std::uint8_t>(out.begin(), out.begin() + 4);
    };
    using V = std::vector<std::uint8_t>;
    const StoreInfo u16 = one_texel_store(1, SampleType::u16);
    EXPECT_EQ(first_texel(u16, {0x00, 0x00}), (V{0, 0, 0, 255}));
    EXPECT_EQ(first_texel(u16, {0xFF, 0xFF}), (V{255, 255, 255, 255}));
    EXPECT_EQ(first_texel(u16, {128, 0}), (V{0, 0, 0, 255}));    // 128 / 257 = 0.498
    EXPECT_EQ(first_texel(u16, {129, 0}), (V{1, 1, 1, 255}));    // 129 / 257 = 0.502
    EXPECT_EQ(first_texel(u16, {0x01, 0x01}), (V{1, 1, 1, 255}));  // 257
    const StoreInfo f32 = one_texel_store(2, SampleType::f32);
    auto f32_pair = [](float a, float b) {
        V v(8);
        std::memcpy(v.data(), &a, 4);
        std::memcpy(v.data() + 4, &b, 4);
        return v;
    };
    EXPECT_EQ(first_texel(f32, f32_pair(0.5f, 1.0f)), (V{128, 128, 128, 255}));  // 127.5 rounds up
    EXPECT_EQ(first_texel(f32, f32_pair(-3.0f, 7.0f)), (V{0, 0, 0, 255}));
    EXPECT_EQ(first_texel(f32, f32_pair(std::nanf(""), INFINITY)), (V{0, 0, 0, 255}));
    const StoreInfo f16 = one_texel_store(1, SampleType::f16);
    EXPECT_EQ(first_texel(f16, {0x00, 0x38}), (V{128, 128, 128, 255}));  // 0x3800 = 0.5
    EXPECT_EQ(first_texel(f16, {0x00, 0x3C}), (V{255, 255, 255, 255}));  // 1.0
    EXPECT_EQ(first_texel(f16, {0x00, 0xBC}), (V{0, 0, 0, 255}));        // -1.0
    EXPECT_EQ(first_texel(f16, {0x01, 0x7E}), (V{0, 0, 0, 255}));        // NaN
}

TEST(TranscodeTile, CorruptPayloadsAreErrors) {
    Scratch scratch;
    const StoreInfo rgb = make_info(3, SampleType::u8, Codec::jpeg);
    const Tile jpeg = encode_present(rgb, synthetic_texels(rgb, 1));
    std::vector<std::uint8_t> out(rgba8_page_bytes(rgb));
    auto run = [&](const StoreInfo& info, TileKind kind, Codec codec, std::span<const std::uint8_t> payload) {
        out.assign(rgba8_page_bytes(info), 0);
        return transcode_to_rgba8(info, kind, codec, payload, out, scratch);
    };
    auto expect_error = [](const Status& s, Errc code, const char* what) {
        ASSERT_FALSE(s.ok()) << what;
        EXPECT_EQ(s.error().code, code) << what << ": " << s.error().message;
        EXPECT_FALSE(s.error().message.empty()) << what;
    };

    const std::span<const std::uint8_t> j(jpeg.bytes);
    expect_error(run(rgb, TileKind::present, Codec::jpeg, {}), Errc::corrupt, "empty JPEG");
    expect_error(run(rgb, TileKind::present, Codec::jpeg, j.first(j.size() / 2)), Errc::corrupt, "truncated JPEG");
    expect_error(run(rgb, TileKind::present, Codec::jpeg, j.first(100)), Errc::corrupt, "JPEG header only");
    std::vector<std::uint8_t> garbage(5000);
    std::mt19937 rng(5);
    for (auto& b : garbage) b = static_cast<std::uint8_t>(rng());
    expect_error(run(rgb, TileKind::present, Codec::jpeg, garbage), Errc::corrupt, "garbage JPEG");
    // A JPEG of another tile size, and a grey JPEG in an RGB store.
    const StoreInfo small = make_info(3, SampleType::u8, Codec::jpeg, false, 56, 4);
    const Tile small_tile = encode_present(small, synthetic_texels(small, 2));
    expect_error(run(rgb, TileKind::present, Codec::jpeg, small_tile.bytes), Errc::corrupt, "JPEG of wrong size");
    const StoreInfo grey = make_info(1, SampleType::u8, Codec::jpeg);
    const Tile grey_tile = encode_present(grey, synthetic_texels(grey, 3));
    expect_error(run(rgb, TileKind::present, Codec::jpeg, grey_tile.bytes), Errc::corrupt, "grey JPEG in RGB store");
    expect_error(run(grey, TileKind::present, Codec::jpeg, jpeg.bytes), Errc::corrupt, "RGB JPEG in grey store");
    expect_error(run(make_info(3, SampleType::u16, Codec::zstd), TileKind::present, Codec::jpeg, jpeg.bytes),
                 Errc::corrupt, "JPEG in a 16-bit store");

    const StoreInfo z = make_info(4, SampleType::u16, Codec::zstd, true);
    const Tile zt = encode_present(z, synthetic_texels(z, 4));
    const std::span<const std::uint8_t> zs(zt.bytes);
    expect_error(run(z, TileKind::present, Codec::zstd, {}), Errc::corrupt, "empty zstd");
    expect_error(run(z, TileKind::present, Codec::zstd, zs.first(zs.size() / 2)), Errc::corrupt, "truncated zstd");
    expect_error(run(z, TileKind::present, Codec::zstd, garbage), Errc::corrupt, "garbage zstd");
    const StoreInfo z3 = make_info(3, SampleType::u16, Codec::zstd);
    expect_error(run(z3, TileKind::present, Codec::zstd, zt.bytes), Errc::corrupt, "zstd of another tile size");

    expect_error(run(z, TileKind::present, Codec::raw, garbage), Errc::corrupt, "raw of wrong size");
    expect_error(run(z, TileKind::uniform, Codec::raw, garbage), Errc::corrupt, "uniform of wrong size");
    expect_error(run(z, TileKind::absent, Codec::raw, {}), Errc::not_found, "absent");
    expect_error(run(z, static_cast<TileKind>(9), Codec::zstd, zt.bytes), Errc::invalid_argument, "unknown kind");
    expect_error(run(z, TileKind::present, static_cast<Codec>(7), zt.bytes), Errc::invalid_argument, "unknown codec");
    expect_error(run(z, TileKind::present, static_cast<Codec>(99), zt.bytes), Errc::invalid_argument, "codec 99");
    expect_error(run(z, TileKind::present, Codec::bc4, zt.bytes), Errc::corrupt, "blocks in a zstd store");
    // A block store's description that no reader would accept (a server's, say): tiles not whole
    // 4x4 blocks of a page and its second level.
    StoreInfo odd_blocks = make_info(3, SampleType::u8, Codec::bc1);
    odd_blocks.tile_payload = 50;
    expect_error(run(odd_blocks, TileKind::present, Codec::bc1, zt.bytes), Errc::corrupt, "bc1 tiles of 58 texels");

    std::vector<std::uint8_t> short_out(rgba8_page_bytes(rgb) - 4);
    const Status s = transcode_to_rgba8(rgb, TileKind::present, Codec::jpeg, jpeg.bytes, short_out, scratch);
    expect_error(s, Errc::invalid_argument, "destination too small");
}

TEST(TranscodeTile, DamagedPayloadsAgreeWithReference) {
    // Bytes flipped anywhere: whatever the store's decoder says (error, or a decode), transcode says
    // the same, and when both decode the pixels still match.
    Scratch scratch;
    std::mt19937 rng(11);
    struct Case {
        StoreInfo info;
        storage::EncodeOptions options;
    };
    storage::EncodeOptions s420;
    s420.chroma = storage::Chroma::s420;
    const Case cases[] = {{make_info(3, SampleType::u8, Codec::jpeg), {}},
                          {make_info(3, SampleType::u8, Codec::jpeg), s420},
                          {make_info(1, SampleType::u8, Codec::jpeg), {}},
                          {make_info(4, SampleType::u8, Codec::zstd, true), {}},
                          {make_info(1, SampleType::f32, Codec::zstd), {}}};
    int decoded = 0, failed = 0;
    for (const Case& c : cases) {
        const Tile good = encode_present(c.info, synthetic_texels(c.info, 9), c.options);
        for (int rep = 0; rep < 60; ++rep) {
            Tile bad = good;
            const int flips = 1 + static_cast<int>(rng() % 4);
            for (int k = 0; k < flips; ++k) bad.bytes[rng() % bad.bytes.size()] ^= static_cast<std::uint8_t>(1 + rng() % 255);
            if (rng() % 4 == 0) bad.bytes.resize(rng() % bad.bytes.size());
            if (expect_matches_reference(c.info, bad, scratch, "damaged " + std::to_string(rep)))
                ++decoded;
            else
                ++failed;
        }
    }
    EXPECT_GT(failed, 0);
    std::printf("damaged payloads: %d decoded (same as reference), %d rejected by both\n", decoded, failed);
}

TEST(TranscodeTile, DamagedJpegDoesNotSpoilTheScratch) {
    // One Scratch (as one pool worker) sees damaged JPEGs between good ones: every good one still
    // decodes, identical to a fresh decode.
    const StoreInfo info = make_info(3, SampleType::u8, Codec::jpeg);
    const Tile good = encode_present(info, synthetic_texels(info, 5));
    std::vector<std::uint8_t> want(rgba8_page_bytes(info)), got(rgba8_page_bytes(info));
    Scratch fresh, scratch;
    ASSERT_TRUE(transcode_to_rgba8(info, TileKind::present, Codec::jpeg, good.bytes, want, fresh).ok());
    std::mt19937 rng(11);
    int header_failures = 0;
    for (int rep = 0; rep < 400; ++rep) {
        std::vector<std::uint8_t> bad = good.bytes;
        bad[rng() % 700] ^= static_cast<std::uint8_t>(1 + rng() % 255);  // in or near the headers
        const Status s = transcode_to_rgba8(info, TileKind::present, Codec::jpeg, bad, got, scratch);
        if (!s.ok() && s.error().message.find("header") != std::string::npos) ++header_failures;
        std::fill(got.begin(), got.end(), 0);
        const Status g = transcode_to_rgba8(info, TileKind::present, Codec::jpeg, good.bytes, got, scratch);
        ASSERT_TRUE(g.ok()) << "good tile after damaged one " << rep << ": " << g.error().message;
        ASSERT_TRUE(got == want) << rep;
    }
    EXPECT_GT(header_failures, 0);
}

// ------------------------------------------------------------------- real stores (builder)

// A build source with a constant region (so the builder stores uniform tiles) beside a textured one.
class PatternSource : public storage::ImageSource {
public:
    PatternSource(std::uint32_t w, std::uint32_t h, std::uint32_t channels, SampleType t, bool alpha) {
        info_.width = w, info_.height = h, info_.channels = channels, info_.sample_type = t, info_.has_alpha = alpha;
        info_.colour_space = storage::ColourSpace::linear;
        info_.description = "test pattern";
    }
    const storage::SourceInfo& info() const override { return info_; }
    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const storage::ParallelFor&) override {
        const std::size_t sb = storage::sample_bytes(info_.sample_type);
        for (std::uint32_t y = y0; y < y0 + count; ++y)
            for (std::uint32_t x = 0; x < info_.width; ++x)
                for (std::uint32_t c = 0; c < info_.channels; ++c) {
                    const bool flat = x < info_.width / 2;
                    const double v = flat ? 0.25 + 0.2 * c
                                          : 0.5 + 0.45 * std::sin(x * 0.05 + c) * std::cos(y * 0.07) +
                                                0.1 * ((hash32(x * 7919 + y * 104729 + c) & 255) / 255.0 - 0.5);
                    write(dst, v, sb);
                    dst += sb;
                }
        return {};
    }

private:
    void write(std::uint8_t* p, double v, std::size_t) const {
        switch (info_.sample_type) {
            case SampleType::u8: *p = static_cast<std::uint8_t>(std::clamp(v, 0.0, 1.0) * 255 + 0.5); break;
            case SampleType::u16: {
                const auto u = static_cast<std::uint16_t>(std::clamp(v, 0.0, 1.0) * 65535 + 0.5);
                p[0] = static_cast<std::uint8_t>(u), p[1] = static_cast<std::uint8_t>(u >> 8);
                break;
            }
            case SampleType::f16: {  // normal halves only: sign 0, truncated mantissa
                const std::uint32_t b = std::bit_cast<std::uint32_t>(static_cast<float>(v));
                const std::uint32_t e = (b >> 23) & 255;
                const std::uint16_t h = e < 113 ? 0 : static_cast<std::uint16_t>(((e - 112) << 10) | ((b >> 13) & 1023));
                p[0] = static_cast<std::uint8_t>(h), p[1] = static_cast<std::uint8_t>(h >> 8);
                break;
            }
            case SampleType::f32: {
                const float f = static_cast<float>(v * 1.2 - 0.1);  // a little outside [0, 1]
                std::memcpy(p, &f, 4);
                break;
            }
        }
    }
    storage::SourceInfo info_;
};

struct BuiltStore {
    std::string name;
    std::shared_ptr<storage::StoreReader> reader;
};

// Stores built once for the whole test program.
const std::vector<BuiltStore>& built_stores() {
    static test::ScratchDir dir;
    static const std::vector<BuiltStore> stores = [] {
        std::vector<BuiltStore> out;
        auto add = [&](const std::string& name, const Result<storage::BuildSummary>& r) {
            EXPECT_TRUE(r.ok()) << name << ": " << (r.ok() ? "" : r.error().message);
            if (!r.ok()) return;
            auto reader = storage::StoreReader::open(dir.file(name + ".tsr"));
            EXPECT_TRUE(reader.ok());
            if (reader.ok()) out.push_back({name, reader.value()});
        };
        storage::BuildOptions o;
        o.threads = 2;
        o.codec = Codec::jpeg;  // 4:4:4 at q90
        add("terrain-jpeg444", storage::build_store("procedural:terrain:1000", dir.file("terrain-jpeg444.tsr"), o));
        o.quality = 80;         // 4:2:0 below q90
        add("terrain-jpeg420", storage::build_store("procedural:terrain:1000", dir.file("terrain-jpeg420.tsr"), o));
        o.quality = 90;
        o.codec = Codec::zstd;
        add("terrain-zstd", storage::build_store("procedural:terrain:1000", dir.file("terrain-zstd.tsr"), o));
        o.codec = Codec::raw;
        add("terrain-raw", storage::build_store("procedural:terrain:1000", dir.file("terrain-raw.tsr"), o));
        struct P {
            const char* name;
            std::uint32_t channels;
            SampleType type;
            bool alpha;
            std::optional<Codec> codec;
        };
        const P patterns[] = {{"grey-jpeg", 1, SampleType::u8, false, Codec::jpeg},
                              {"grey-zstd", 1, SampleType::u8, false, Codec::zstd},
                              {"ga-zstd", 2, SampleType::u8, true, std::nullopt},
                              {"rgba-zstd", 4, SampleType::u8, true, std::nullopt},
                              {"rgb16-zstd", 3, SampleType::u16, false, std::nullopt},
                              {"grey16-raw", 1, SampleType::u16, false, Codec::raw},
                              {"rgb-half-zstd", 3, SampleType::f16, false, std::nullopt},
                              {"grey-f32-zstd", 1, SampleType::f32, false, std::nullopt},
                              {"rgba-f32-zstd", 4, SampleType::f32, true, std::nullopt}};
        for (const P& p : patterns) {
            PatternSource src(700, 450, p.channels, p.type, p.alpha);
            storage::BuildOptions po;
            po.threads = 2;
            po.tile_size = 128;
            po.codec = p.codec;
            add(p.name, storage::build_store(src, dir.file(std::string(p.name) + ".tsr"), po));
        }
        return out;
    }();
    return stores;
}

TEST(TranscodeTile, EveryTileOfBuiltStoresMatchesReference) {
    Scratch scratch;
    const auto& stores = built_stores();
    ASSERT_EQ(stores.size(), 13u);
    for (const BuiltStore& s : stores) {
        const StoreInfo& info = s.reader->info();
        std::size_t present = 0, uniform = 0;
        for (std::uint32_t level = 0; level < info.level_count(); ++level)
            for (std::uint32_t y = 0; y < info.levels[level].tiles_y; ++y)
                for (std::uint32_t x = 0; x < info.levels[level].tiles_x; ++x) {
                    auto tile = s.reader->read_tile({level, x, y});
                    ASSERT_TRUE(tile.ok());
                    if (tile->kind == TileKind::absent) continue;
                    (tile->kind == TileKind::uniform ? uniform : present)++;
                    EXPECT_TRUE(expect_matches_reference(info, *tile, scratch,
                                                         s.name + " tile " + std::to_string(level) + "/" +
                                                             std::to_string(x) + "/" + std::to_string(y)));
                }
        EXPECT_GT(present, 0u) << s.name;
        if (s.name.find("terrain") == std::string::npos) {
            EXPECT_GT(uniform, 0u) << s.name << " has no uniform tile";
        }
    }
}

// ------------------------------------------------------------------------------ the pool

struct TestPage {
    std::shared_ptr<const StoreInfo> info;
    TileKind kind = TileKind::absent;
    Codec codec = Codec::raw;
    std::shared_ptr<const std::vector<std::uint8_t>> payload;
    std::vector<std::uint8_t> expected;  // reference RGBA8
};

// Pages of the terrain JPEG and zstd stores and one uniform page, with their reference output.
const std::vector<TestPage>& test_pages() {
    static const std::vector<TestPage> pages = [] {
        std::vector<TestPage> out;
        for (const BuiltStore& s : built_stores()) {
            if (s.name != "terrain-jpeg444" && s.name != "terrain-zstd" && s.name != "grey-zstd") continue;
            auto info = std::make_shared<const StoreInfo>(s.reader->info());
            for (std::uint32_t y = 0; y < 2; ++y)
                for (std::uint32_t x = 0; x < 3; ++x) {
                    auto tile = s.reader->read_tile({0, x, y});
                    if (!tile.ok() || tile->kind == TileKind::absent) continue;
                    std::vector<std::uint8_t> decoded;
                    EXPECT_TRUE(reference_decode(*info, *tile, decoded).ok());
                    TestPage p;
                    p.info = info;
                    p.kind = tile->kind;
                    p.codec = info->codec;
                    p.payload = std::make_shared<const std::vector<std::uint8_t>>(tile->bytes);
                    p.expected = reference_rgba8(*info, decoded);
                    out.push_back(std::move(p));
                }
        }
        return out;
    }();
    return pages;
}

constexpr std::uint8_t kSentinel = 0xA5;

// Staging memory for the tests: one page-sized slot per ticket, filled with a sentinel.
struct Staging {
    std::vector<std::vector<std::uint8_t>> slots;
    std::span<std::uint8_t> slot(std::size_t i, std::size_t bytes) {
        if (slots.size() <= i) slots.resize(i + 1);
        slots[i].assign(bytes, kSentinel);
        return slots[i];
    }
    bool untouched(std::size_t i) const {
        return std::all_of(slots[i].begin(), slots[i].end(), [](std::uint8_t b) { return b == kSentinel; });
    }
};

TranscodeJob make_job(const TestPage& p, PageKey key, std::uint64_t ticket, std::span<std::uint8_t> dst,
                      std::uint32_t priority = 0) {
    TranscodeJob j;
    j.key = key;
    j.ticket = ticket;
    j.info = p.info;
    j.kind = p.kind;
    j.codec = p.codec;
    j.payload = p.payload;
    j.destination = dst;
    j.priority = priority;
    return j;
}

PageKey key_of(std::uint64_t i) { return PageKey{1, 0, static_cast<std::uint32_t>(i), 7}; }

// Polls until `n` results arrived in total (or gives up after a generous time).
void poll_until(TranscodePool& pool, std::vector<TranscodeResult>& results, std::size_t n) {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
    while (results.size() < n && std::chrono::steady_clock::now() < deadline) {
        if (pool.poll(results) == 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    ASSERT_EQ(results.size(), n);
}

TEST(TranscodePool, EveryJobCompletesExactlyOnceWithReferenceOutput) {
    const auto& pages = test_pages();
    ASSERT_GE(pages.size(), 10u);
    TranscodePoolOptions o;
    o.threads = 3;
    o.capacity = 16;
    TranscodePool pool(o);
    EXPECT_EQ(pool.threads(), 3u);
    constexpr std::size_t kJobs = 600;
    Staging staging;
    // Slots are reused once their result is polled, as an upload ring would.
    std::vector<std::size_t> free_slots;
    for (std::size_t i = 0; i < o.capacity; ++i) free_slots.push_back(i);
    std::map<std::uint64_t, std::size_t> slot_of;  // ticket -> slot
    std::vector<int> seen(kJobs, 0);
    std::vector<TranscodeResult> results;
    std::size_t next = 0, done = 0;
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
    while (done < kJobs && std::chrono::steady_clock::now() < deadline) {
        while (next < kJobs && !free_slots.empty()) {
            const TestPage& p = pages[next % pages.size()];
            const std::size_t slot = free_slots.back();
            ASSERT_TRUE(pool.submit(make_job(p, key_of(next), next, staging.slot(slot, p.expected.size()))));
            free_slots.pop_back();
            slot_of[next] = slot;
            ++next;
        }
        results.clear();
        if (pool.poll(results) == 0) std::this_thread::sleep_for(std::chrono::microseconds(200));
        for (const TranscodeResult& r : results) {
            ASSERT_LT(r.ticket, kJobs);
            ++seen[r.ticket];
            EXPECT_TRUE(r.status.ok()) << r.status.error().message;
            EXPECT_FALSE(r.dropped);
            EXPECT_EQ(r.key, key_of(r.ticket));
            const std::size_t slot = slot_of.at(r.ticket);
            EXPECT_TRUE(staging.slots[slot] == pages[r.ticket % pages.size()].expected) << "ticket " << r.ticket;
            free_slots.push_back(slot);
            slot_of.erase(r.ticket);
            ++done;
        }
    }
    EXPECT_EQ(done, kJobs);
    EXPECT_TRUE(std::all_of(seen.begin(), seen.end(), [](int n) { return n == 1; }));
    const TranscodePoolStats s = pool.stats();
    EXPECT_EQ(s.submitted, kJobs);
    EXPECT_EQ(s.decoded, kJobs);
    EXPECT_EQ(s.failed + s.dropped + s.queued + s.running + s.completed, 0u);
}

TEST(TranscodePool, BoundedQueueRejectsWhenFullWithoutBlocking) {
    const auto& pages = test_pages();
    TranscodePoolOptions o;
    o.threads = 2;
    o.capacity = 4;
    o.start_paused = true;
    TranscodePool pool(o);
    Staging staging;
    for (std::uint64_t i = 0; i < 4; ++i)
        ASSERT_TRUE(pool.submit(make_job(pages[0], key_of(i), i, staging.slot(i, pages[0].expected.size()))));
    std::vector<std::uint8_t> spare(pages[0].expected.size(), kSentinel);
    EXPECT_FALSE(pool.submit(make_job(pages[0], key_of(4), 4, spare)));
    EXPECT_EQ(pool.stats().rejected, 1u);
    EXPECT_EQ(pool.stats().queued, 4u);
    pool.resume();
    // Finished but not yet polled results still count against the bound (their staging is in use).
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (pool.stats().completed < 4 && std::chrono::steady_clock::now() < deadline)
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    ASSERT_EQ(pool.stats().completed, 4u);
    EXPECT_FALSE(pool.submit(make_job(pages[0], key_of(4), 4, spare)));
    std::vector<TranscodeResult> results;
    EXPECT_EQ(pool.poll(results), 4u);
    EXPECT_TRUE(pool.submit(make_job(pages[0], key_of(4), 4, spare)));
    poll_until(pool, results, 5);
    EXPECT_TRUE(spare == pages[0].expected);
    EXPECT_EQ(pool.stats().rejected, 2u);
}

TEST(TranscodePool, CancelledAndUnwantedJobsAreDroppedAndNeverWritten) {
    const auto& pages = test_pages();
    TranscodePoolOptions o;
    o.threads = 2;
    o.capacity = 64;
    o.start_paused = true;
    TranscodePool pool(o);
    Staging staging;
    constexpr std::uint64_t kJobs = 40;
    for (std::uint64_t i = 0; i < kJobs; ++i) {
        const TestPage& p = pages[i % pages.size()];
        ASSERT_TRUE(pool.submit(make_job(p, key_of(i % 20), i, staging.slot(i, p.expected.size()))));
    }
    // cancel(): both jobs of key 3 (tickets 3 and 23).
    EXPECT_EQ(pool.cancel(key_of(3)), 2u);
    EXPECT_EQ(pool.cancel(key_of(3)), 0u);
    EXPECT_EQ(pool.cancel(PageKey{9, 9, 9, 9}), 0u);
    // The next frame wants only even keys.
    const std::size_t unwanted = pool.retain_only([](const PageKey& k) { return k.x % 2 == 0; });
    EXPECT_EQ(unwanted, 18u);  // odd keys but 3: 9 keys x 2 tickets
    // Re-prioritise, dropping key 0 as well.
    const std::size_t gone = pool.update_queued([](const PageKey& k, std::uint32_t) -> std::optional<std::uint32_t> {
        if (k.x == 0) return std::nullopt;
        return k.x;
    });
    EXPECT_EQ(gone, 2u);
    // Dropped results are available at once, before any decoding.
    std::vector<TranscodeResult> results;
    EXPECT_EQ(pool.poll(results), 22u);
    pool.resume();
    poll_until(pool, results, kJobs);

    std::set<std::uint64_t> tickets;
    for (const TranscodeResult& r : results) {
        EXPECT_TRUE(tickets.insert(r.ticket).second) << "ticket " << r.ticket << " completed twice";
        const bool should_drop = r.key.x % 2 == 1 || r.key.x == 0;
        EXPECT_EQ(r.dropped, should_drop) << r.ticket;
        if (r.dropped) {
            ASSERT_FALSE(r.status.ok());
            EXPECT_EQ(r.status.error().code, Errc::cancelled);
            EXPECT_TRUE(staging.untouched(r.ticket)) << "dropped job " << r.ticket << " wrote its destination";
        } else {
            EXPECT_TRUE(r.status.ok());
            EXPECT_TRUE(staging.slots[r.ticket] == pages[r.ticket % pages.size()].expected) << r.ticket;
        }
    }
    EXPECT_EQ(tickets.size(), kJobs);
    const TranscodePoolStats s = pool.stats();
    EXPECT_EQ(s.dropped, 22u);
    EXPECT_EQ(s.decoded, kJobs - 22);
}

TEST(TranscodePool, OneThreadTakesHighestPriorityFirst) {
    const auto& pages = test_pages();
    TranscodePoolOptions o;
    o.threads = 1;
    o.capacity = 32;
    o.start_paused = true;
    TranscodePool pool(o);
    Staging staging;
    const std::uint32_t priorities[] = {1, 5, 3, 5, 0, 9, 3, 7, 1, 9};
    for (std::uint64_t i = 0; i < std::size(priorities); ++i)
        ASSERT_TRUE(pool.submit(make_job(pages[0], key_of(i), i, staging.slot(i, pages[0].expected.size()), priorities[i])));
    // Re-prioritised while queued: ticket 4 (priority 0) jumps to the front; ticket 7 (priority 7)
    // drops to 2, below both 3s and above the 1s. Ties keep submission order.
    pool.update_queued([](const PageKey& k, std::uint32_t p) -> std::optional<std::uint32_t> {
        if (k.x == 4) return 100;
        if (k.x == 7) return 2;
        return p;
    });
    pool.resume();
    std::vector<TranscodeResult> results;
    poll_until(pool, results, std::size(priorities));
    std::vector<std::uint64_t> order;
    for (const auto& r : results) order.push_back(r.ticket);
    EXPECT_EQ(order, (std::vector<std::uint64_t>{4, 5, 9, 1, 3, 2, 6, 7, 0, 8}));
}

TEST(TranscodePool, UpdateQueuedThatThrowsLosesNoJob) {
    const auto& pages = test_pages();
    TranscodePool pool(TranscodePoolOptions{1, 16, true});
    Staging staging;
    for (std::uint64_t i = 0; i < 8; ++i)
        ASSERT_TRUE(pool.submit(make_job(pages[0], key_of(i), i, staging.slot(i, pages[0].expected.size()), 1)));
    int calls = 0;
    EXPECT_THROW(pool.update_queued([&](const PageKey&, std::uint32_t) -> std::optional<std::uint32_t> {
        if (++calls == 5) throw std::runtime_error("callback failed");
        return 7;  // moves the job (re-prioritised) before the throw
    }),
                 std::runtime_error);
    EXPECT_EQ(pool.stats().queued, 8u);
    pool.resume();
    std::vector<TranscodeResult> results;
    poll_until(pool, results, 8);
    std::set<std::uint64_t> tickets;
    for (const auto& r : results) {
        EXPECT_TRUE(r.status.ok());
        tickets.insert(r.ticket);
    }
    EXPECT_EQ(tickets.size(), 8u);
}

TEST(TranscodePool, BadJobsCompleteWithAnError) {
    const auto& pages = test_pages();
    TranscodePool pool(TranscodePoolOptions{1, 8, false});
    Staging staging;
    TranscodeJob no_info = make_job(pages[0], key_of(0), 0, staging.slot(0, pages[0].expected.size()));
    no_info.info.reset();
    TranscodeJob no_payload = make_job(pages[0], key_of(1), 1, staging.slot(1, pages[0].expected.size()));
    no_payload.payload.reset();
    TranscodeJob small_dst = make_job(pages[0], key_of(2), 2, staging.slot(2, 64));
    ASSERT_TRUE(pool.submit(std::move(no_info)));
    ASSERT_TRUE(pool.submit(std::move(no_payload)));
    ASSERT_TRUE(pool.submit(std::move(small_dst)));
    std::vector<TranscodeResult> results;
    poll_until(pool, results, 3);
    for (const auto& r : results) {
        EXPECT_FALSE(r.status.ok()) << r.ticket;
        EXPECT_FALSE(r.dropped);
    }
    EXPECT_EQ(pool.stats().failed, 3u);
}

TEST(TranscodePool, ShutdownDropsQueuedJobsPromptly) {
    const auto& pages = test_pages();
    const std::size_t bytes = pages[0].expected.size();
    // One destination per job (uninitialised: only the pages a decode touches are ever committed).
    auto destinations = [&](std::size_t n) {
        std::vector<std::unique_ptr<std::uint8_t[]>> d;
        for (std::size_t i = 0; i < n; ++i) d.emplace_back(new std::uint8_t[bytes]);
        return d;
    };
    {
        // Paused: nothing is decoded, everything queued is dropped and still reported.
        constexpr std::size_t kJobs = 3000;
        std::vector<std::uint8_t> never_written(bytes, kSentinel);
        TranscodePool pool(TranscodePoolOptions{2, kJobs, true});
        for (std::size_t i = 0; i < kJobs; ++i) ASSERT_TRUE(pool.submit(make_job(pages[0], key_of(i), i, never_written)));
        pool.shutdown();
        pool.shutdown();  // idempotent
        EXPECT_FALSE(pool.submit(make_job(pages[0], key_of(0), 0, never_written)));
        std::vector<TranscodeResult> results;
        EXPECT_EQ(pool.poll(results), kJobs);
        EXPECT_TRUE(std::all_of(results.begin(), results.end(), [](const auto& r) { return r.dropped; }));
        EXPECT_EQ(pool.stats().decoded, 0u);
        EXPECT_TRUE(std::all_of(never_written.begin(), never_written.end(), [](std::uint8_t b) { return b == kSentinel; }));
    }
    {
        // Running: shutdown waits only for the tiles being decoded when it is called (at most one
        // per thread), not for the queue.
        constexpr std::size_t kJobs = 400;
        auto dst = destinations(kJobs);
        TranscodePool pool(TranscodePoolOptions{2, kJobs, true});
        for (std::size_t i = 0; i < kJobs; ++i)
            ASSERT_TRUE(pool.submit(make_job(pages[0], key_of(i), i, std::span<std::uint8_t>(dst[i].get(), bytes))));
        pool.resume();
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
        const auto t0 = std::chrono::steady_clock::now();
        pool.shutdown();
        const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
        const TranscodePoolStats s = pool.stats();
        EXPECT_EQ(s.decoded + s.dropped, kJobs);
        EXPECT_GT(s.dropped, 0u);
        EXPECT_EQ(s.running + s.queued, 0u);
        std::printf("shutdown with %llu queued: %.2f ms (%llu decoded before)\n",
                    static_cast<unsigned long long>(s.dropped), ms, static_cast<unsigned long long>(s.decoded));
    }
    {
        // Destroyed with work queued and results unpolled: no hang, no leak.
        constexpr std::size_t kJobs = 100;
        auto dst = destinations(kJobs);
        TranscodePool pool(TranscodePoolOptions{2, kJobs, false});
        for (std::size_t i = 0; i < kJobs; ++i)
            ASSERT_TRUE(pool.submit(make_job(pages[0], key_of(i), i, std::span<std::uint8_t>(dst[i].get(), bytes))));
    }
}

TEST(TranscodePool, ConcurrentSubmitCancelPollStress) {
    // Submitter, canceller and poller on three threads (for ThreadSanitizer): every job still
    // completes exactly once and dropped jobs never write.
    const auto& pages = test_pages();
    TranscodePool pool(TranscodePoolOptions{2, 32, false});
    constexpr std::uint64_t kJobs = 800;
    const std::size_t bytes = pages[0].expected.size();
    std::vector<std::vector<std::uint8_t>> slots(kJobs);
    for (auto& s : slots) s.assign(bytes, kSentinel);
    std::atomic<bool> submitting{true};
    std::atomic<std::uint64_t> submitted{0};
    std::thread submitter([&] {
        for (std::uint64_t i = 0; i < kJobs;) {
            const TestPage& p = pages[i % pages.size()];
            if (p.expected.size() != bytes) {
                slots[i].assign(p.expected.size(), kSentinel);
            }
            if (pool.submit(make_job(p, key_of(i), i, slots[i], static_cast<std::uint32_t>(i % 5)))) {
                ++i;
                submitted.store(i);
            } else {
                std::this_thread::yield();
            }
        }
        submitting = false;
    });
    std::thread canceller([&] {
        std::mt19937 rng(1);
        while (submitting) {
            const std::uint64_t hi = submitted.load();
            if (hi > 0) (void)pool.cancel(key_of(rng() % hi));
            (void)pool.retain_only([&](const PageKey& k) { return k.x % 13 != 5; });
            std::this_thread::yield();
        }
    });
    std::vector<TranscodeResult> results;
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
    while (results.size() < kJobs && std::chrono::steady_clock::now() < deadline) {
        if (pool.poll(results) == 0) std::this_thread::yield();
    }
    submitter.join();
    canceller.join();
    ASSERT_EQ(results.size(), kJobs);
    std::vector<int> seen(kJobs, 0);
    std::size_t dropped = 0;
    for (const auto& r : results) {
        ++seen[r.ticket];
        const auto& s = slots[r.ticket];
        if (r.dropped) {
            ++dropped;
            EXPECT_TRUE(std::all_of(s.begin(), s.end(), [](std::uint8_t b) { return b == kSentinel; })) << r.ticket;
        } else {
            EXPECT_TRUE(r.status.ok());
            EXPECT_TRUE(s == pages[r.ticket % pages.size()].expected) << r.ticket;
        }
    }
    EXPECT_TRUE(std::all_of(seen.begin(), seen.end(), [](int n) { return n == 1; }));
    EXPECT_EQ(pool.stats().dropped, dropped);
}

}  // namespace
}  // namespace tessera::client
