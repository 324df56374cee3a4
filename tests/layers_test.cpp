// Multi-layer stores (docs/store-format.md, "Layers"): the bundle of a tile's layers, the layered
// file format (writer, reader, a damaged layer table), the layered builder from procedural layers
// and from image files, and `tessera build --layer`, `inspect` and `verify` on layered stores.
#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>
#include <xxhash.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <set>
#include <string>
#include <vector>

#include "format.hpp"
#include "procedural_layers.hpp"
#include "procedural_terrain.hpp"
#include "reference_pyramid.hpp"
#include "sources_internal.hpp"
#include "tessera/storage/builder.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/layers.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/store_writer.hpp"
#include "tessera/storage/verify.hpp"
#include "test_util.hpp"

using namespace tessera;
using namespace tessera::storage;
using tessera::test::RefImage;
using tessera::test::ScratchDir;

namespace {

namespace fs = std::filesystem;

std::vector<std::uint8_t> bytes_of(std::initializer_list<int> v) {
    std::vector<std::uint8_t> out;
    for (int b : v) out.push_back(static_cast<std::uint8_t>(b));
    return out;
}

// Three layers: RGB u8 (JPEG), two channels u8 (zstd), one channel u16 (zstd).
StoreInfo three_layer_info() {
    StoreInfo info;
    info.width = info.height = 300;
    info.tile_payload = 56;
    info.border = 4;
    info.codec = Codec::layers;
    info.layers = {LayerInfo{"colour", 3, SampleType::u8, ColourSpace::srgb, Codec::jpeg},
                   LayerInfo{"normal", 2, SampleType::u8, ColourSpace::linear, Codec::zstd},
                   LayerInfo{"height", 1, SampleType::u16, ColourSpace::linear, Codec::zstd}};
    info.channels = 3;
    info.levels = level_geometry(info.width, info.height, info.tile_payload);
    return info;
}

// A bundle table record: kind, three zero bytes, length (u32 little-endian).
void put_record(std::vector<std::uint8_t>& b, std::size_t i, int kind, std::uint32_t length) {
    b[i * 8] = static_cast<std::uint8_t>(kind);
    b[i * 8 + 1] = b[i * 8 + 2] = b[i * 8 + 3] = 0;
    std::memcpy(b.data() + i * 8 + 4, &length, 4);
}

}  // namespace

// ---- bundles -------------------------------------------------------------------------------------

TEST(LayerBundle, SplitUndoesJoin) {
    const StoreInfo info = three_layer_info();
    const auto colour = bytes_of({1, 2, 3, 4, 5});
    const auto height = bytes_of({0x34, 0x12});  // one u16 texel: a uniform part
    const std::vector<LayerPart> parts = {{TileKind::present, colour}, {TileKind::absent, {}}, {TileKind::uniform, height}};
    const std::vector<std::uint8_t> bundle = join_layers(parts);
    ASSERT_EQ(bundle.size(), 3 * 8 + colour.size() + height.size());
    // The table: one 8-byte record per layer, then the parts in layer order.
    EXPECT_EQ(bundle[0], 1);
    EXPECT_EQ(bundle[8], 0);
    EXPECT_EQ(bundle[16], 2);
    EXPECT_EQ(bundle[4], 5);
    EXPECT_EQ(bundle[20], 2);
    auto split = split_layers(info, bundle);
    ASSERT_TRUE(split.ok()) << split.error().message;
    ASSERT_EQ(split->size(), 3u);
    for (std::size_t i = 0; i < 3; ++i) {
        EXPECT_EQ((*split)[i].kind, parts[i].kind) << i;
        EXPECT_TRUE(std::equal((*split)[i].bytes.begin(), (*split)[i].bytes.end(), parts[i].bytes.begin(), parts[i].bytes.end())) << i;
    }
    // A part as a tile decodes with its layer's description: the uniform u16 height.
    std::vector<std::uint8_t> texels;
    const StoreInfo height_info = layer_store_info(info, 2);
    EXPECT_EQ(height_info.codec, Codec::zstd);
    EXPECT_EQ(height_info.sample_type, SampleType::u16);
    EXPECT_FALSE(height_info.layered());
    ASSERT_TRUE(decode_tile(height_info, layer_tile({0, 1, 2}, (*split)[2]), texels).ok());
    ASSERT_EQ(texels.size(), height_info.tile_bytes());
    EXPECT_EQ(texels[0], 0x34);
    EXPECT_EQ(texels[texels.size() - 1], 0x12);
    EXPECT_EQ(decode_tile(layer_store_info(info, 1), layer_tile({0, 1, 2}, (*split)[1]), texels).error().code, Errc::not_found);
    // A single-layer store is its own layer 0.
    StoreInfo single = info;
    single.layers.clear();
    single.codec = Codec::zstd;
    EXPECT_EQ(layer_count(single), 1u);
    EXPECT_EQ(layer_store_info(single, 0).codec, Codec::zstd);
    EXPECT_EQ(split_layers(single, bundle).error().code, Errc::invalid_argument);
}

TEST(LayerBundle, CorruptBundlesAreRefused) {
    const StoreInfo info = three_layer_info();
    const std::vector<std::uint8_t> good =
        join_layers(std::vector<LayerPart>{{TileKind::present, bytes_of({9, 9, 9})}, {TileKind::uniform, bytes_of({7, 8})},
                                           {TileKind::present, bytes_of({1})}});
    ASSERT_TRUE(split_layers(info, good).ok());
    auto refused = [&](std::vector<std::uint8_t> b, const std::string& what) {
        auto r = split_layers(info, b);
        ASSERT_FALSE(r.ok()) << what;
        EXPECT_EQ(r.error().code, Errc::corrupt) << what;
        EXPECT_FALSE(r.error().message.empty());
    };
    refused({}, "empty");
    refused(std::vector<std::uint8_t>(good.begin(), good.begin() + 23), "table cut short");
    for (std::size_t cut = 24; cut < good.size(); ++cut)
        refused(std::vector<std::uint8_t>(good.begin(), good.begin() + std::ptrdiff_t(cut)), "cut to " + std::to_string(cut));
    auto b = good;
    b[0] = 3;
    refused(b, "unknown kind");
    b = good;
    b[9] = 1;
    refused(b, "non-zero pad byte");
    b = good;
    put_record(b, 2, 1, 1000);
    refused(b, "length past the end");
    b = good;
    put_record(b, 2, 1, 0xffffffffu);
    refused(b, "length that wraps");
    b = good;
    b.push_back(0);
    refused(b, "a trailing byte");
    b = good;
    put_record(b, 1, 2, 3);  // a u8 x 2 texel is 2 bytes
    put_record(b, 2, 1, 0);
    refused(b, "uniform part of the wrong size");
    b = good;
    put_record(b, 0, 0, 3);
    refused(b, "absent part with bytes");
    b = good;
    put_record(b, 0, 1, 0);
    put_record(b, 1, 2, 5);
    refused(b, "present part without bytes");
}

// ---- the file format -----------------------------------------------------------------------------

namespace {

StoreSpec three_layer_spec() {
    const StoreInfo info = three_layer_info();
    StoreSpec spec;
    spec.width = info.width;
    spec.height = info.height;
    spec.tile_payload = info.tile_payload;
    spec.border = info.border;
    spec.channels = 3;
    spec.sample_type = SampleType::u8;
    spec.colour_space = ColourSpace::srgb;
    spec.codec = Codec::layers;
    spec.layers = info.layers;
    return spec;
}

std::vector<std::uint8_t> pattern(std::size_t n, std::uint32_t seed) {
    std::vector<std::uint8_t> v(n);
    for (std::size_t i = 0; i < n; ++i) v[i] = static_cast<std::uint8_t>((i * 131 + seed * 7 + (i >> 5)) & 0xff);
    return v;
}

// Valid parts for a tile of the three-layer store: the colour layer a JPEG of a gradient, the
// others zstd frames of patterns.
struct TileParts {
    std::vector<std::uint8_t> colour, normal, height;
};
TileParts encode_parts(const StoreInfo& info, std::uint32_t seed) {
    TileParts p;
    EncodeOptions enc;
    p.colour = *encode_tile(layer_store_info(info, 0), pattern(layer_store_info(info, 0).tile_bytes(), seed), enc);
    p.normal = *encode_tile(layer_store_info(info, 1), pattern(layer_store_info(info, 1).tile_bytes(), seed + 1), enc);
    p.height = *encode_tile(layer_store_info(info, 2), pattern(layer_store_info(info, 2).tile_bytes(), seed + 2), enc);
    return p;
}

struct WrittenStore {
    std::string path;
    std::vector<std::uint8_t> bundle_a, bundle_b;  // a: every kind of part; b: stored twice (deduplicated)
};

WrittenStore write_layered_store(const ScratchDir& d) {
    const StoreSpec spec = three_layer_spec();
    const StoreInfo info = store_info(spec);
    WrittenStore w;
    w.path = d.file("layers.tsr");
    auto writer = StoreWriter::create(w.path, spec);
    EXPECT_TRUE(writer.ok()) << writer.error().message;
    const TileParts p1 = encode_parts(info, 1), p2 = encode_parts(info, 2);
    const auto normal_value = bytes_of({128, 128});
    w.bundle_a = join_layers(std::vector<LayerPart>{
        {TileKind::present, p1.colour}, {TileKind::uniform, normal_value}, {TileKind::absent, {}}});
    w.bundle_b = join_layers(std::vector<LayerPart>{
        {TileKind::present, p2.colour}, {TileKind::present, p2.normal}, {TileKind::present, p2.height}});
    EXPECT_TRUE((*writer)->add_present({0, 0, 0}, w.bundle_a).ok());
    EXPECT_TRUE((*writer)->add_present({0, 1, 0}, w.bundle_b).ok());
    EXPECT_TRUE((*writer)->add_present({0, 2, 3}, w.bundle_b).ok());  // identical: stored once
    EXPECT_TRUE((*writer)->add_present({3, 0, 0}, w.bundle_b).ok());
    EXPECT_TRUE((*writer)->finish().ok());
    return w;
}

}  // namespace

TEST(LayerStore, WrittenAndReadBack) {
    ScratchDir d;
    const WrittenStore w = write_layered_store(d);
    const std::vector<std::uint8_t> file = test::read_file(w.path);
    namespace F = format;
    EXPECT_EQ(F::load<std::uint16_t>(file.data(), F::header::version_minor), 1u) << "a layered store is format 1.1";
    EXPECT_EQ(file[F::header::codec], 7);
    EXPECT_EQ(file[F::header::layer_count], 3);

    auto reader = StoreReader::open(w.path);
    ASSERT_TRUE(reader.ok()) << reader.error().message;
    const StoreInfo& info = (*reader)->info();
    EXPECT_EQ(info.version_major, 1u);
    EXPECT_EQ(info.version_minor, 1u);
    EXPECT_EQ(info.codec, Codec::layers);
    ASSERT_EQ(info.layers.size(), 3u);
    const StoreInfo want = three_layer_info();
    for (std::size_t i = 0; i < 3; ++i) {
        EXPECT_EQ(info.layers[i].name, want.layers[i].name);
        EXPECT_EQ(info.layers[i].channels, want.layers[i].channels);
        EXPECT_EQ(info.layers[i].sample_type, want.layers[i].sample_type);
        EXPECT_EQ(info.layers[i].colour_space, want.layers[i].colour_space);
        EXPECT_EQ(info.layers[i].codec, want.layers[i].codec);
        EXPECT_EQ(info.layers[i].has_alpha, want.layers[i].has_alpha);
    }
    // The header repeats layer 0's samples.
    EXPECT_EQ(info.channels, 3u);
    EXPECT_EQ(info.sample_type, SampleType::u8);
    EXPECT_EQ(info.colour_space, ColourSpace::srgb);
    // Bytes per layer: over the stored bundles, the deduplicated one counted once.
    auto parts_a = split_layers(info, w.bundle_a), parts_b = split_layers(info, w.bundle_b);
    ASSERT_TRUE(parts_a.ok() && parts_b.ok());
    for (std::size_t i = 0; i < 3; ++i)
        EXPECT_EQ(info.layers[i].payload_bytes, (*parts_a)[i].bytes.size() + (*parts_b)[i].bytes.size()) << i;
    std::uint64_t payload = 0;
    for (const auto& l : info.levels) payload += l.payload_bytes;
    EXPECT_EQ(payload, w.bundle_a.size() + w.bundle_b.size());
    EXPECT_EQ(info.levels[0].present, 3u);
    EXPECT_EQ(info.levels[0].deduplicated, 2u) << "bundle b is stored first in level 3 (coarse levels first)";
    EXPECT_EQ(info.levels[3].deduplicated, 0u);
    EXPECT_EQ(info.levels[0].uniform, 0u);

    auto a = (*reader)->read_tile({0, 0, 0});
    ASSERT_TRUE(a.ok());
    EXPECT_EQ(a->kind, TileKind::present);
    EXPECT_EQ(a->bytes, w.bundle_a);
    for (const TileKey k : {TileKey{0, 1, 0}, TileKey{0, 2, 3}, TileKey{3, 0, 0}}) {
        auto b = (*reader)->read_tile(k);
        ASSERT_TRUE(b.ok());
        EXPECT_EQ(b->bytes, w.bundle_b);
    }
    auto absent = (*reader)->read_tile({0, 4, 4});
    ASSERT_TRUE(absent.ok());
    EXPECT_EQ(absent->kind, TileKind::absent);

    VerifyOptions vo;
    vo.decode = true;
    const VerifyReport rep = verify_store(**reader, vo);
    EXPECT_TRUE(rep.ok()) << (rep.problems.empty() ? "" : rep.problems.front());
    EXPECT_EQ(rep.payloads_checked, 4u);

    // A single-layer store stays format 1.0 with the new header fields zero.
    StoreSpec single = three_layer_spec();
    single.layers.clear();
    single.codec = Codec::zstd;
    auto sw = StoreWriter::create(d.file("single.tsr"), single);
    ASSERT_TRUE(sw.ok());
    ASSERT_TRUE((*sw)->add_uniform({0, 0, 0}, bytes_of({1, 2, 3})).ok());
    ASSERT_TRUE((*sw)->finish().ok());
    const auto sb = test::read_file(d.file("single.tsr"));
    EXPECT_EQ(F::load<std::uint16_t>(sb.data(), F::header::version_minor), 0u);
    EXPECT_EQ(sb[F::header::layer_count], 0);
    EXPECT_EQ(F::load<std::uint64_t>(sb.data(), F::header::layer_table_checksum), 0u);
    auto sr = StoreReader::open(d.file("single.tsr"));
    ASSERT_TRUE(sr.ok());
    EXPECT_FALSE((*sr)->info().layered());
}

TEST(LayerStore, WriterRefusesBadSpecsAndTiles) {
    ScratchDir d;
    auto refused = [&](const StoreSpec& spec, const std::string& expect) {
        const Status st = validate(spec);
        ASSERT_FALSE(st.ok()) << expect;
        EXPECT_EQ(st.error().code, Errc::invalid_argument);
        EXPECT_NE(st.error().message.find(expect), std::string::npos) << st.error().message;
        auto w = StoreWriter::create(d.file("bad.tsr"), spec);
        EXPECT_FALSE(w.ok());
    };
    ASSERT_TRUE(validate(three_layer_spec()).ok());
    StoreSpec s = three_layer_spec();
    s.layers.resize(1);
    refused(s, "2 to 16 layers, not 1");
    s = three_layer_spec();
    while (s.layers.size() < 17) s.layers.push_back(LayerInfo{"l" + std::to_string(s.layers.size()), 1, SampleType::u8, ColourSpace::linear, Codec::zstd});
    refused(s, "not 17");
    s = three_layer_spec();
    s.layers[2].name = "colour";
    refused(s, "two layers are named 'colour'");
    s = three_layer_spec();
    s.layers[1].name = "Normal";
    refused(s, "may only hold");
    s.layers[1].name = "";
    refused(s, "cannot be empty");
    s.layers[1].name = std::string(32, 'n');
    refused(s, "longer than 31");
    s = three_layer_spec();
    s.layers[1].codec = Codec::jpeg;  // two channels
    refused(s, "layer 'normal': JPEG needs");
    s.layers[1].codec = Codec::layers;
    refused(s, "codec layers");
    s = three_layer_spec();
    s.layers[2].channels = 0;
    refused(s, "layer 'height' has 0 channels");
    s = three_layer_spec();
    s.layers[2].has_alpha = true;
    refused(s, "alpha needs 2 or 4 channels");
    s = three_layer_spec();
    s.codec = Codec::zstd;
    refused(s, "codec is 'layers'");
    s = three_layer_spec();
    s.channels = 2;
    refused(s, "first layer's");
    s = three_layer_spec();
    s.layers.clear();
    refused(s, "codec 'layers' needs the store's layers");
    EXPECT_TRUE(d.entries().empty());

    // Tiles: only bundles of the store's layers, with some layer's data; no uniform tiles.
    const StoreSpec spec = three_layer_spec();
    auto w = StoreWriter::create(d.file("l.tsr"), spec);
    ASSERT_TRUE(w.ok());
    const TileParts p = encode_parts(store_info(spec), 5);
    Status st = (*w)->add_present({0, 0, 0}, p.colour);
    EXPECT_EQ(st.error().code, Errc::invalid_argument);
    EXPECT_NE(st.error().message.find("not a bundle"), std::string::npos) << st.error().message;
    st = (*w)->add_present({0, 0, 0}, join_layers(std::vector<LayerPart>(3)));
    EXPECT_EQ(st.error().code, Errc::invalid_argument);
    EXPECT_NE(st.error().message.find("all absent"), std::string::npos) << st.error().message;
    st = (*w)->add_present({0, 0, 0}, join_layers(std::vector<LayerPart>{{TileKind::present, p.colour}, {}}));
    EXPECT_EQ(st.error().code, Errc::invalid_argument) << "two parts for three layers";
    st = (*w)->add_uniform({0, 0, 0}, bytes_of({1, 2, 3}));
    EXPECT_EQ(st.error().code, Errc::invalid_argument);
    EXPECT_NE(st.error().message.find("no uniform tiles"), std::string::npos) << st.error().message;
    w->reset();
    EXPECT_TRUE(d.entries().empty()) << "an unfinished writer leaves nothing";
}

namespace {

// Recomputes the layer table checksum and the header checksum after an edit (so that what is
// checked is the reader's validation of the table, not only the checksums).
void reseal(std::vector<std::uint8_t>& b) {
    namespace F = format;
    const std::uint32_t levels = b[F::header::level_count];
    const std::size_t table = F::kHeaderBytes + levels * F::kLevelRecordBytes;
    const std::size_t n = b[F::header::layer_count];
    if (n > 0 && n <= 16)
        F::store<std::uint64_t>(b.data(), F::header::layer_table_checksum, XXH3_64bits(b.data() + table, n * F::kLayerRecordBytes));
    F::store<std::uint64_t>(b.data(), F::header::header_checksum, XXH3_64bits(b.data(), F::header::header_checksum));
}

}  // namespace

TEST(LayerStore, DamagedLayerTableIsCorruptNeverACrash) {
    ScratchDir d;
    const WrittenStore w = write_layered_store(d);
    const std::vector<std::uint8_t> good = test::read_file(w.path);
    namespace F = format;
    const std::size_t table = F::kHeaderBytes + good[F::header::level_count] * F::kLevelRecordBytes;
    const std::size_t table_end = table + 3 * F::kLayerRecordBytes;
    ASSERT_LE(table_end, F::load<std::uint64_t>(good.data(), F::header::palette_offset));
    auto expect_corrupt = [&](const std::vector<std::uint8_t>& b, const std::string& what, const std::string& says = "") {
        auto r = StoreReader::open_memory(b);
        ASSERT_FALSE(r.ok()) << what;
        EXPECT_EQ(r.error().code, Errc::corrupt) << what << ": " << r.error().message;
        if (!says.empty()) {
            EXPECT_NE(r.error().message.find(says), std::string::npos) << what << ": " << r.error().message;
        }
    };
    // Any flipped bit of the table, and of the header fields that describe it: the checksums.
    for (std::size_t pos = table; pos < table_end; ++pos)
        for (int bit = 0; bit < 8; bit += 3) {
            auto b = good;
            b[pos] ^= static_cast<std::uint8_t>(1u << bit);
            expect_corrupt(b, "byte " + std::to_string(pos), "layer table checksum");
        }
    for (std::size_t pos : {std::size_t(F::header::layer_count), std::size_t(F::header::layer_table_checksum)}) {
        auto b = good;
        b[pos] ^= 1;
        expect_corrupt(b, "header byte " + std::to_string(pos), "header checksum");
    }

    // Damage the checksums cannot see (they are recomputed): each breaks a rule of the format.
    auto edit = [&](auto change, const std::string& what, const std::string& says) {
        auto b = good;
        change(b.data() + table);
        reseal(b);
        expect_corrupt(b, what, says);
    };
    const std::size_t R = F::kLayerRecordBytes;
    edit([](std::uint8_t* t) { std::memcpy(t + 64, "colour\0", 7); }, "duplicate name", "two layers are named 'colour'");
    edit([](std::uint8_t* t) { t[0] = 'C'; }, "bad character", "may only hold");
    edit([](std::uint8_t* t) { std::memset(t, 'a', 32); }, "name without NUL", "NUL padded");
    edit([](std::uint8_t* t) { t[10] = 'x'; }, "bytes after the NUL", "NUL padded");
    edit([](std::uint8_t* t) { std::memset(t, 0, 32); }, "empty name", "cannot be empty");
    edit([R](std::uint8_t* t) { t[R + 35] = 7; }, "layer codec 'layers'", "codec layers");
    edit([R](std::uint8_t* t) { t[R + 35] = 9; }, "unknown layer codec", "bad sample type, colour space or codec");
    edit([R](std::uint8_t* t) { t[R + 35] = 2; }, "JPEG for two channels", "JPEG needs");
    edit([R](std::uint8_t* t) { t[2 * R + 32] = 0; }, "no channels", "0 channels");
    edit([R](std::uint8_t* t) { t[2 * R + 33] = 4; }, "bad sample type", "bad sample type");
    edit([R](std::uint8_t* t) { t[2 * R + 36] = 1; }, "alpha on one channel", "alpha needs");
    edit([](std::uint8_t* t) { t[34] = 0; }, "header not layer 0's", "first layer's");
    edit([R](std::uint8_t* t) { t[R + 47] = 0x40; }, "payload bytes past the data", "exceed the data section");
    for (int count : {0, 1, 17, 255}) {
        auto b = good;
        b[F::header::layer_count] = static_cast<std::uint8_t>(count);
        reseal(b);
        expect_corrupt(b, "layer count " + std::to_string(count));
    }
    {
        auto b = good;
        b[F::header::codec] = 1;  // zstd, with a layer count
        reseal(b);
        expect_corrupt(b, "single-layer codec with a layer count", "layer count");
    }
    {
        auto b = good;
        F::store<std::uint16_t>(b.data(), F::header::version_minor, 0);
        reseal(b);
        expect_corrupt(b, "format 1.0 claiming layers", "need 1.1");
    }
    // The sound file still opens (the helpers changed copies).
    EXPECT_TRUE(StoreReader::open_memory(good).ok());
}

// ---- the builder ---------------------------------------------------------------------------------

namespace {

BuildOptions small_build() {
    BuildOptions o;
    o.tile_size = 128;
    o.border = 4;
    o.threads = 2;
    return o;
}

// Every tile of a single-layer store, as read.
std::vector<Tile> all_tiles(const StoreReader& r) {
    std::vector<Tile> out;
    const StoreInfo& info = r.info();
    for (std::uint32_t l = 0; l < info.level_count(); ++l)
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                auto t = r.read_tile({l, x, y});
                EXPECT_TRUE(t.ok());
                out.push_back(t.ok() ? *t : Tile{});
            }
    return out;
}

// Each layer of `layered` holds exactly the tiles of the single-layer store built from its input
// with the same options: the same kinds and the same payload bytes.
void expect_layers_match_single_builds(const StoreReader& layered, const std::vector<std::string>& singles) {
    const StoreInfo& info = layered.info();
    ASSERT_EQ(info.layers.size(), singles.size());
    const std::vector<Tile> bundles = all_tiles(layered);
    for (std::size_t i = 0; i < singles.size(); ++i) {
        auto single = StoreReader::open(singles[i]);
        ASSERT_TRUE(single.ok());
        const StoreInfo& si = (*single)->info();
        EXPECT_EQ(si.codec, info.layers[i].codec);
        EXPECT_EQ(si.channels, info.layers[i].channels);
        EXPECT_EQ(si.sample_type, info.layers[i].sample_type);
        EXPECT_EQ(si.colour_space, info.layers[i].colour_space);
        const std::vector<Tile> tiles = all_tiles(**single);
        ASSERT_EQ(tiles.size(), bundles.size());
        for (std::size_t t = 0; t < tiles.size(); ++t) {
            if (bundles[t].kind == TileKind::absent) {
                EXPECT_EQ(tiles[t].kind, TileKind::absent);
                continue;
            }
            auto parts = split_layers(info, bundles[t].bytes);
            ASSERT_TRUE(parts.ok()) << parts.error().message;
            const LayerPart& p = (*parts)[i];
            EXPECT_EQ(p.kind, tiles[t].kind) << "layer " << i << " tile " << t;
            EXPECT_TRUE(std::equal(p.bytes.begin(), p.bytes.end(), tiles[t].bytes.begin(), tiles[t].bytes.end()))
                << "layer " << info.layers[i].name << ", tile " << t << " differs from the single-layer build";
        }
    }
}

RefImage read_source(const std::string& spec) {
    auto src = open_image_source(spec);
    EXPECT_TRUE(src.ok());
    RefImage im;
    if (!src.ok()) return im;
    const SourceInfo& si = (*src)->info();
    im.width = si.width;
    im.height = si.height;
    im.channels = si.channels;
    im.type = si.sample_type;
    im.bytes.resize(std::size_t(im.width) * im.height * im.texel_bytes());
    // Strips of 64 rows, as the builder reads them (the normal source keeps heights across strips).
    for (std::uint32_t y = 0; y < si.height; y += 64)
        EXPECT_TRUE((*src)
                        ->read_rows(y, std::min(64u, si.height - y), im.bytes.data() + std::size_t(y) * si.width * im.texel_bytes(),
                                    [](std::size_t n, const auto& fn) { fn(0, n); })
                        .ok());
    return im;
}

std::uint16_t u16_at(const RefImage& im, std::size_t i) {
    std::uint16_t v;
    std::memcpy(&v, im.bytes.data() + 2 * i, 2);
    return v;
}

}  // namespace

TEST(LayerBuild, ProceduralColourNormalHeight) {
    ScratchDir d;
    const std::vector<LayerInput> layers = {{"colour", "procedural:terrain:512", Codec::jpeg},
                                            {"normal", "procedural:terrain-normal:512", Codec::bc5},
                                            {"height", "procedural:terrain-height:512", Codec::zstd}};
    std::uint64_t progress_calls = 0, last_rows = 0;
    BuildProgress last;
    auto r = build_layered_store(layers, d.file("terrain.tsr"), small_build(), [&](const BuildProgress& p) {
        ++progress_calls;
        EXPECT_GE(p.rows_done, last_rows);
        last_rows = p.rows_done;
        last = p;
    });
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_GT(progress_calls, 3u);
    EXPECT_EQ(last.rows_total, 3u * 512);
    EXPECT_EQ(last_rows, 3u * 512);
    const StoreInfo& info = r->info;
    EXPECT_EQ(info.codec, Codec::layers);
    ASSERT_EQ(info.layers.size(), 3u);
    EXPECT_EQ(info.layers[0].codec, Codec::jpeg);
    EXPECT_EQ(info.layers[1].codec, Codec::bc5);
    EXPECT_EQ(info.layers[1].channels, 2u);
    EXPECT_EQ(info.layers[1].colour_space, ColourSpace::linear);
    EXPECT_EQ(info.layers[2].codec, Codec::zstd);
    EXPECT_EQ(info.layers[2].sample_type, SampleType::u16);
    EXPECT_EQ(info.layers[2].colour_space, ColourSpace::linear);
    EXPECT_EQ(info.tile_size(), 128u);
    for (const LayerInfo& l : info.layers) EXPECT_GT(l.payload_bytes, 0u) << l.name;

    auto reader = StoreReader::open(d.file("terrain.tsr"));
    ASSERT_TRUE(reader.ok());
    VerifyOptions vo;
    vo.decode = true;
    const VerifyReport rep = verify_store(**reader, vo);
    EXPECT_TRUE(rep.ok()) << (rep.problems.empty() ? "" : rep.problems.front());
    EXPECT_EQ(rep.tiles_checked, 25u + 9 + 4 + 1);

    // Each layer is what a single-layer build of its input makes, byte for byte.
    std::vector<std::string> singles;
    for (const LayerInput& l : layers) {
        BuildOptions o = small_build();
        o.codec = l.codec;
        singles.push_back(d.file(l.name + ".tsr"));
        auto s = build_store(l.input, singles.back(), o);
        ASSERT_TRUE(s.ok()) << s.error().message;
    }
    expect_layers_match_single_builds(**reader, singles);

    // The height layer's level 0 is the source's samples exactly.
    const RefImage height = read_source("procedural:terrain-height:512");
    std::vector<std::uint8_t> texels;
    const StoreInfo hinfo = layer_store_info(info, 2);
    for (std::uint32_t y = 0; y < info.levels[0].tiles_y; ++y)
        for (std::uint32_t x = 0; x < info.levels[0].tiles_x; ++x) {
            auto t = (*reader)->read_tile({0, x, y});
            ASSERT_TRUE(t.ok());
            auto parts = split_layers(info, t->bytes);
            ASSERT_TRUE(parts.ok());
            ASSERT_TRUE(decode_tile(hinfo, layer_tile(t->key, (*parts)[2]), texels).ok());
            EXPECT_EQ(texels, test::reference_tile(height, info.tile_payload, info.border, x, y)) << x << "," << y;
        }
}

// The normals are the height field's, at the level-0 texel spacing, under the documented relief;
// and they are the relief the colour's hill shading shows (lit from the north-west).
TEST(LayerBuild, TerrainNormalsFollowTheHeightField) {
    const std::uint32_t N = 512;
    const RefImage normal = read_source("procedural:terrain-normal:" + std::to_string(N));
    const RefImage height = read_source("procedural:terrain-height:" + std::to_string(N));
    const RefImage colour = read_source("procedural:terrain:" + std::to_string(N));
    ASSERT_EQ(normal.channels, 2u);
    ASSERT_EQ(normal.type, SampleType::u8);
    ASSERT_EQ(height.channels, 1u);
    ASSERT_EQ(height.type, SampleType::u16);
    const double scale = double(N) * tessera::storage::kTerrainReliefPerSize;  // texels of height per unit of the field
    auto h = [&](std::int64_t x, std::int64_t y) {
        x = std::clamp<std::int64_t>(x, 0, N - 1);
        y = std::clamp<std::int64_t>(y, 0, N - 1);
        return (double(u16_at(height, std::size_t(y) * N + std::size_t(x))) / 65535.0) * 2.0 - 1.0;
    };
    // The shading is a local effect on top of the colour ramp (sea dark, snow bright): compare each
    // texel with the mean of the 7 x 7 texels around it, for the brightness and for the facing.
    auto local = [&](const std::vector<double>& v, std::int64_t x, std::int64_t y) {
        double sum = 0;
        int count = 0;
        for (std::int64_t j = std::max<std::int64_t>(y - 3, 0); j <= std::min<std::int64_t>(y + 3, N - 1); ++j)
            for (std::int64_t i = std::max<std::int64_t>(x - 3, 0); i <= std::min<std::int64_t>(x + 3, N - 1); ++i, ++count)
                sum += v[std::size_t(j) * N + std::size_t(i)];
        return v[std::size_t(y) * N + std::size_t(x)] - sum / count;
    };
    // Correlation of facing the light (in the north-west: -x, -y), with the normal's y taken as
    // `y_sign` times the image's row direction, against the colour's brightness.
    auto correlation = [&](double y_sign) {
        std::vector<double> facing(std::size_t(N) * N), bright(std::size_t(N) * N);
        for (std::size_t i = 0; i < facing.size(); ++i) {
            facing[i] = -((normal.bytes[2 * i] / 127.5 - 1) + y_sign * (normal.bytes[2 * i + 1] / 127.5 - 1));
            bright[i] = double(colour.bytes[3 * i]) + colour.bytes[3 * i + 1] + colour.bytes[3 * i + 2];
        }
        double sxy = 0, sxx = 0, syy = 0, sx = 0, sy = 0, n = 0;
        for (std::int64_t y = 0; y < N; ++y)
            for (std::int64_t x = 0; x < N; ++x) {
                const double f = local(facing, x, y), c = local(bright, x, y);
                sx += f, sy += c, sxx += f * f, syy += c * c, sxy += f * c, n += 1;
            }
        return (sxy / n - (sx / n) * (sy / n)) / std::sqrt((sxx / n - (sx / n) * (sx / n)) * (syy / n - (sy / n) * (sy / n)));
    };
    double worst = 0, sum_slope = 0;
    std::size_t n = 0;
    for (std::int64_t y = 0; y < N; ++y)
        for (std::int64_t x = 0; x < N; ++x) {
            const std::int64_t l = std::max<std::int64_t>(x - 1, 0), r = std::min<std::int64_t>(x + 1, N - 1);
            const std::int64_t u = std::max<std::int64_t>(y - 1, 0), b = std::min<std::int64_t>(y + 1, N - 1);
            const double gx = (h(r, y) - h(l, y)) * scale / double(r - l), gy = (h(x, b) - h(x, u)) * scale / double(b - u);
            const double len = std::sqrt(gx * gx + gy * gy + 1);
            const std::size_t i = std::size_t(y) * N + std::size_t(x);
            const double nx = normal.bytes[2 * i] / 127.5 - 1, ny = normal.bytes[2 * i + 1] / 127.5 - 1;
            worst = std::max({worst, std::abs(nx + gx / len), std::abs(ny + gy / len)});
            EXPECT_LE(nx * nx + ny * ny, 1.0 + 2.0 / 127.5) << x << "," << y;
            sum_slope += std::sqrt(gx * gx + gy * gy);
            ++n;
        }
    // The u16 heights round the field the normals were made from: a little slack over one u8 step.
    EXPECT_LT(worst, 2.5 / 127.5) << "normals do not follow the height layer";
    const double mean_slope = sum_slope / double(n);
    std::printf("mean slope %.3f, worst normal difference %.4f\n", mean_slope, worst);
    EXPECT_GT(mean_slope, 0.05) << "a relief too flat to show";
    EXPECT_LT(mean_slope, 2.0) << "a relief too steep to show";
    const double corr = correlation(1), flipped = correlation(-1);
    std::printf("correlation of facing the light and the colour's brightness: %.3f (normal y upwards: %.3f)\n", corr, flipped);
    EXPECT_GT(corr, 0.2) << "the normals do not show the relief the colour is shaded with";
    EXPECT_LT(std::abs(flipped), 0.1) << "with y upwards the normals would show it too: the test tells nothing";
}

namespace {

// Writes `im` with OpenImageIO (PNG here: another program's encoder, not Tessera's).
void write_image(const std::string& path, const RefImage& im) {
    static const OIIO::TypeDesc types[] = {OIIO::TypeDesc::UINT8, OIIO::TypeDesc::UINT16, OIIO::TypeDesc::HALF, OIIO::TypeDesc::FLOAT};
    auto out = OIIO::ImageOutput::create(path);
    ASSERT_TRUE(out);
    OIIO::ImageSpec spec(int(im.width), int(im.height), int(im.channels), types[int(im.type)]);
    if (im.channels == 2 || im.channels == 4) spec.alpha_channel = int(im.channels) - 1;
    ASSERT_TRUE(out->open(path, spec)) << out->geterror();
    ASSERT_TRUE(out->write_image(types[int(im.type)], im.bytes.data())) << out->geterror();
    ASSERT_TRUE(out->close());
}

RefImage image(std::uint32_t w, std::uint32_t h, std::uint32_t c, SampleType t) {
    RefImage im;
    im.width = w;
    im.height = h;
    im.channels = c;
    im.type = t;
    im.bytes.resize(std::size_t(w) * h * im.texel_bytes());
    return im;
}

}  // namespace

// A photo stored turned is held whole while its strips are read, and a layered build reads its
// layers side by side: the process-wide budget for turned images bounds their sum. A build that
// would pass it fails at its first strip, and every source gives its share back.
TEST(LayerBuild, TurnedLayersShareOneMemoryBudget) {
    ScratchDir d;
    const int W = 200, H = 120;  // as stored; shown 120 x 200 (orientation 6: turned a quarter)
    std::vector<std::uint8_t> texels(std::size_t(W) * H * 3);
    for (std::size_t i = 0; i < texels.size(); ++i) texels[i] = static_cast<std::uint8_t>(i * 7 % 251);
    for (const char* name : {"a.tif", "b.tif"}) {
        auto out = OIIO::ImageOutput::create(d.file(name));
        ASSERT_TRUE(out);
        OIIO::ImageSpec spec(W, H, 3, OIIO::TypeDesc::UINT8);
        spec.attribute("Orientation", 6);
        ASSERT_TRUE(out->open(d.file(name), spec)) << out->geterror();
        ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, texels.data())) << out->geterror();
        ASSERT_TRUE(out->close());
    }
    const std::uint64_t one = std::uint64_t(W) * H * 3;
    struct Restore {
        std::uint64_t old;
        ~Restore() { set_turned_image_budget(old); }
    } restore{set_turned_image_budget(one + one / 2)};

    BuildOptions o = small_build();
    o.tile_size = 64;
    const std::vector<LayerInput> layers = {{"a", d.file("a.tif"), {}}, {"b", d.file("b.tif"), {}}};
    auto refused = build_layered_store(layers, d.file("both.tsr"), o);
    ASSERT_FALSE(refused.ok());
    EXPECT_EQ(refused.error().code, Errc::unsupported);
    const std::string& why = refused.error().message;
    EXPECT_NE(why.find("b.tif"), std::string::npos) << why;
    EXPECT_NE(why.find("orientation 6"), std::string::npos) << why;
    EXPECT_NE(why.find("vips autorot"), std::string::npos) << why;
    EXPECT_FALSE(std::filesystem::exists(d.file("both.tsr")));

    // One at a time fits, build after build: the refused build and each of these gave back
    // what they took.
    for (int i = 0; i < 3; ++i) {
        auto single = build_store(d.file("a.tif"), d.file("a.tsr"), o);
        ASSERT_TRUE(single.ok()) << single.error().message;
        EXPECT_EQ(single->info.width, std::uint32_t(H));
        EXPECT_EQ(single->info.height, std::uint32_t(W));
    }
    // With room for both, the same layered build is made, upright.
    set_turned_image_budget(2 * one);
    auto built = build_layered_store(layers, d.file("both.tsr"), o);
    ASSERT_TRUE(built.ok()) << built.error().message;
    EXPECT_EQ(built->info.width, std::uint32_t(H));
    EXPECT_EQ(built->info.height, std::uint32_t(W));
}

TEST(LayerBuild, ImageFilesRgbAndSixteenBitHeightmap) {
    ScratchDir d;
    const std::uint32_t W = 333, H = 250;
    RefImage rgb = image(W, H, 3, SampleType::u8), hm = image(W, H, 1, SampleType::u16);
    for (std::uint32_t y = 0; y < H; ++y)
        for (std::uint32_t x = 0; x < W; ++x) {
            const std::size_t i = std::size_t(y) * W + x;
            rgb.bytes[3 * i] = static_cast<std::uint8_t>(x * 255 / W);
            rgb.bytes[3 * i + 1] = static_cast<std::uint8_t>(y * 255 / H);
            rgb.bytes[3 * i + 2] = static_cast<std::uint8_t>(128 + 100 * std::sin(double(x + y) * 0.05));
            // A flat quarter (uniform height parts beside present colour), full-range detail elsewhere.
            const std::uint16_t v = x < W / 2 && y < H / 2 ? 40000
                                                           : static_cast<std::uint16_t>((x * 7919u + y * 104729u + x * y) & 0xffff);
            std::memcpy(hm.bytes.data() + 2 * i, &v, 2);
        }
    write_image(d.file("colour.png"), rgb);
    write_image(d.file("height.png"), hm);
    BuildOptions o = small_build();
    o.tile_size = 64;
    const std::vector<LayerInput> layers = {{"albedo", d.file("colour.png"), {}}, {"height", d.file("height.png"), {}}};
    auto r = build_layered_store(layers, d.file("img.tsr"), o);
    ASSERT_TRUE(r.ok()) << r.error().message;
    const StoreInfo& info = r->info;
    EXPECT_EQ(info.layers[0].codec, Codec::jpeg) << "the default for 8-bit RGB";
    EXPECT_EQ(info.layers[1].codec, Codec::zstd) << "the default for 16-bit grey";
    EXPECT_EQ(info.layers[1].sample_type, SampleType::u16);

    auto reader = StoreReader::open(d.file("img.tsr"));
    ASSERT_TRUE(reader.ok());
    const StoreInfo hinfo = layer_store_info(info, 1), cinfo = layer_store_info(info, 0);
    std::vector<std::uint8_t> texels;
    std::size_t uniform_parts = 0;
    double se = 0, count = 0;
    for (std::uint32_t y = 0; y < info.levels[0].tiles_y; ++y)
        for (std::uint32_t x = 0; x < info.levels[0].tiles_x; ++x) {
            auto t = (*reader)->read_tile({0, x, y});
            ASSERT_TRUE(t.ok());
            auto parts = split_layers(info, t->bytes);
            ASSERT_TRUE(parts.ok());
            EXPECT_EQ((*parts)[0].kind, TileKind::present);
            uniform_parts += (*parts)[1].kind == TileKind::uniform;
            ASSERT_TRUE(decode_tile(hinfo, layer_tile(t->key, (*parts)[1]), texels).ok());
            EXPECT_EQ(texels, test::reference_tile(hm, info.tile_payload, info.border, x, y))
                << "height tile " << x << "," << y << " is not the PNG's samples";
            ASSERT_TRUE(decode_tile(cinfo, layer_tile(t->key, (*parts)[0]), texels).ok());
            const auto ref = test::reference_tile(rgb, info.tile_payload, info.border, x, y);
            for (std::size_t i = 0; i < ref.size(); ++i) se += (double(texels[i]) - ref[i]) * (double(texels[i]) - ref[i]);
            count += double(ref.size());
        }
    EXPECT_GE(uniform_parts, 2u) << "the flat quarter's height parts are uniform";
    EXPECT_GT(10 * std::log10(255.0 * 255.0 / (se / count)), 38.0) << "the colour layer's JPEG";
    VerifyOptions vo;
    vo.decode = true;
    EXPECT_TRUE(verify_store(**reader, vo).ok());
}

TEST(LayerBuild, MismatchedSizesFailNamingBothAndLeaveNothing) {
    ScratchDir d;
    auto r = build_layered_store(std::vector<LayerInput>{{"colour", "procedural:terrain:512", {}},
                                                         {"height", "procedural:terrain-height:256", {}}},
                                 d.file("out.tsr"), small_build());
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, Errc::invalid_argument);
    const std::string& m = r.error().message;
    for (const char* s : {"'height'", "256x256", "'colour'", "512x512"}) EXPECT_NE(m.find(s), std::string::npos) << m;
    EXPECT_TRUE(d.entries().empty()) << "left behind: " << d.entries().front();
}

TEST(LayerBuild, BadLayerListsAreRefusedBeforeAnyWork) {
    ScratchDir d;
    auto refused = [&](std::vector<LayerInput> layers, const std::string& says, BuildOptions o = small_build()) {
        auto r = build_layered_store(layers, d.file("out.tsr"), o);
        ASSERT_FALSE(r.ok()) << says;
        EXPECT_NE(r.error().message.find(says), std::string::npos) << r.error().message;
        EXPECT_TRUE(d.entries().empty());
    };
    const LayerInput c{"colour", "procedural:terrain:256", {}}, h{"height", "procedural:terrain-height:256", {}};
    refused({c}, "2 to 16 layers, not 1");
    refused({c, LayerInput{"colour", h.input, {}}}, "two layers are named 'colour'");
    refused({c, LayerInput{"Height", h.input, {}}}, "may only hold");
    refused({c, LayerInput{"height", h.input, Codec::jpeg}}, "layer 'height', codec jpeg: JPEG needs");
    refused({c, LayerInput{"normal", "procedural:terrain-normal:256", Codec::bc4}}, "layer 'normal', codec bc4");
    refused({c, LayerInput{"height", d.file("nosuch.png"), {}}}, "layer 'height': ");
    refused({c, LayerInput{"height", "procedural:terrain-hight:256", {}}}, "layer 'height': unknown procedural source");
    BuildOptions with_codec = small_build();
    with_codec.codec = Codec::zstd;
    refused({c, h}, "--layer NAME:CODEC=INPUT", with_codec);
    BuildOptions sparse = small_build();
    sparse.sparse = true;
    refused({c, h}, "--sparse needs a layer with an alpha channel", sparse);
}

TEST(LayerBuild, SameBytesWhateverTheThreadCount) {
    ScratchDir d;
    const std::vector<LayerInput> layers = {{"colour", "procedural:terrain:700", {}}, {"normal", "procedural:terrain-normal:700", {}},
                                            {"height", "procedural:terrain-height:700", {}}};
    BuildOptions one = small_build(), many = small_build();
    one.threads = 1;
    many.threads = 3;
    ASSERT_TRUE(build_layered_store(layers, d.file("1.tsr"), one).ok());
    ASSERT_TRUE(build_layered_store(layers, d.file("2.tsr"), many).ok());
    const auto a = test::read_file(d.file("1.tsr")), b = test::read_file(d.file("2.tsr"));
    EXPECT_GT(a.size(), 100000u);
    EXPECT_TRUE(a == b);
}

// --sparse: a layer with alpha makes absent parts where it is transparent; a tile absent in every
// layer is absent.
TEST(LayerBuild, SparsePartsAndAbsentTiles) {
    ScratchDir d;
    const std::uint32_t N = 256;  // 4 x 4 tiles of 64
    RefImage a = image(N, N, 4, SampleType::u8), b = image(N, N, 2, SampleType::u8);
    for (std::uint32_t y = 0; y < N; ++y)
        for (std::uint32_t x = 0; x < N; ++x) {
            const std::size_t i = std::size_t(y) * N + x;
            const bool left = x < N / 2, top = y < N / 2;
            a.bytes[4 * i] = static_cast<std::uint8_t>(x), a.bytes[4 * i + 1] = static_cast<std::uint8_t>(y), a.bytes[4 * i + 2] = 7;
            a.bytes[4 * i + 3] = left ? 0 : 255;
            b.bytes[2 * i] = static_cast<std::uint8_t>(x ^ y);
            b.bytes[2 * i + 1] = left || top ? 0 : 255;
        }
    write_image(d.file("a.png"), a);
    write_image(d.file("b.png"), b);
    BuildOptions o = small_build();
    o.tile_size = 64;
    o.border = 0;
    o.sparse = true;
    auto r = build_layered_store(std::vector<LayerInput>{{"a", d.file("a.png"), Codec::zstd}, {"b", d.file("b.png"), {}}},
                                 d.file("s.tsr"), o);
    ASSERT_TRUE(r.ok()) << r.error().message;
    auto reader = StoreReader::open(d.file("s.tsr"));
    ASSERT_TRUE(reader.ok());
    const StoreInfo& info = (*reader)->info();
    EXPECT_EQ(info.levels[0].absent, 8u) << "the left half: transparent in both layers";
    EXPECT_EQ(info.levels[0].present, 8u);
    for (std::uint32_t y = 0; y < 4; ++y)
        for (std::uint32_t x = 2; x < 4; ++x) {
            auto t = (*reader)->read_tile({0, x, y});
            ASSERT_TRUE(t.ok());
            auto parts = split_layers(info, t->bytes);
            ASSERT_TRUE(parts.ok());
            EXPECT_EQ((*parts)[0].kind, TileKind::present);
            EXPECT_EQ((*parts)[1].kind, y < 2 ? TileKind::absent : TileKind::present) << x << "," << y;
        }
    EXPECT_TRUE(verify_store(**reader).ok());
}

// ---- the command line ----------------------------------------------------------------------------

namespace {

std::string q(const std::string& s) { return "'" + s + "'"; }

}  // namespace

TEST(LayerCli, BuildInspectVerify) {
    ScratchDir d;
    const std::string store = d.file("t.tsr");
    const auto r = test::run_tessera("build -q --layer colour=procedural:terrain:512 --layer normal:bc5=procedural:terrain-normal:512 "
                                     "--layer height:zstd=procedural:terrain-height:512 --tile-size 128 -o " + q(store));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_EQ(r.out, "");
    auto reader = StoreReader::open(store);
    ASSERT_TRUE(reader.ok());
    const StoreInfo& info = (*reader)->info();

    const auto table = test::run_tessera("inspect " + q(store));
    ASSERT_EQ(table.exit_code, 0) << table.out;
    EXPECT_NE(table.out.find("format 1.1"), std::string::npos) << table.out;
    EXPECT_NE(table.out.find("3 layers"), std::string::npos) << table.out;
    for (const char* row : {"colour", "normal", "height", "bc5", "u16", "(bundle tables)"})
        EXPECT_NE(table.out.find(row), std::string::npos) << row << "\n" << table.out;

    const auto js = test::run_tessera("inspect --json " + q(store));
    ASSERT_EQ(js.exit_code, 0) << js.out;
    const nlohmann::json j = nlohmann::json::parse(js.out);
    EXPECT_EQ(j.at("codec"), "layers");
    EXPECT_EQ(j.at("format_version"), "1.1");
    const auto& layers = j.at("layers");
    ASSERT_EQ(layers.size(), 3u);
    std::uint64_t parts = 0;
    double share = 0;
    for (std::size_t i = 0; i < 3; ++i) {
        EXPECT_EQ(layers[i].at("name"), info.layers[i].name);
        EXPECT_EQ(layers[i].at("codec"), to_string(info.layers[i].codec));
        EXPECT_EQ(layers[i].at("channels"), info.layers[i].channels);
        EXPECT_EQ(layers[i].at("sample_type"), to_string(info.layers[i].sample_type));
        EXPECT_EQ(layers[i].at("colour_space"), to_string(info.layers[i].colour_space));
        EXPECT_EQ(layers[i].at("payload_bytes").get<std::uint64_t>(), info.layers[i].payload_bytes);
        parts += info.layers[i].payload_bytes;
        share += layers[i].at("payload_share").get<double>();
    }
    // The layers' bytes and the bundles' tables (8 bytes per layer per stored bundle) make the payload.
    std::uint64_t stored = 0;
    for (const auto& l : info.levels) stored += l.present - l.deduplicated;
    EXPECT_EQ(parts + stored * 3 * 8, j.at("totals").at("payload_bytes").get<std::uint64_t>());
    EXPECT_NEAR(share, double(parts) / double(parts + stored * 24), 1e-9);
    // Raw bytes count every layer's samples: 3 + 2 + 2 bytes a texel.
    std::uint64_t texels = 0;
    for (const auto& l : info.levels) texels += std::uint64_t(l.width) * l.height;
    EXPECT_EQ(j.at("totals").at("raw_bytes").get<std::uint64_t>(), texels * 7);

    const auto v = test::run_tessera("verify --decode " + q(store));
    EXPECT_EQ(v.exit_code, 0) << v.out;
    EXPECT_NE(v.out.find("OK"), std::string::npos) << v.out;

    // A damaged part (past the bundle table of the last payload): verify names the tile.
    auto bytes = test::read_file(store);
    bytes[bytes.size() - 100] ^= 0x20;
    test::write_file(d.file("bad.tsr"), bytes);
    const auto bad = test::run_tessera("verify -q " + q(d.file("bad.tsr")));
    EXPECT_EQ(bad.exit_code, 1) << bad.out;
    EXPECT_NE(bad.out.find("level 0 tile"), std::string::npos) << bad.out;
}

TEST(LayerCli, BadLayerFlagsAreOneLineErrors) {
    ScratchDir d;
    const std::string out = " -o " + q(d.file("out.tsr"));
    const std::string c = " --layer colour=procedural:terrain:256", h = " --layer height=procedural:terrain-height:256";
    struct Case {
        std::string args, says;
        int code;
    };
    const std::vector<Case> cases = {
        {c + out, "2 to 16 layers", 2},
        {c + " --layer colour=procedural:terrain-height:256" + out, "two layers are named 'colour'", 2},
        {c + " --layer Height=procedural:terrain-height:256" + out, "may only hold", 2},
        {c + " --layer height:png=procedural:terrain-height:256" + out, "unknown codec 'png'", 2},
        {c + " --layer height:layers=procedural:terrain-height:256" + out, "unknown codec 'layers'", 2},
        {c + " --layer height" + out, "NAME[:CODEC]=INPUT", 2},
        {c + " --layer height=" + out, "NAME[:CODEC]=INPUT", 2},
        {c + h + " --codec zstd" + out, "--layer NAME:CODEC=INPUT", 2},
        {"procedural:terrain:256" + c + h + out, "not both", 2},
        {c + " --layer height:jpeg=procedural:terrain-height:256" + out, "layer 'height', codec jpeg", 1},
        {c + " --layer height=procedural:terrain-height:300" + out, "every layer must have the same size", 1},
    };
    for (const Case& k : cases) {
        SCOPED_TRACE(k.args);
        const auto r = test::run_tessera("build " + k.args);
        EXPECT_EQ(r.exit_code, k.code) << r.out;
        EXPECT_EQ(r.out.rfind("tessera: error: ", 0), 0u) << r.out;
        EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 1) << r.out;
        EXPECT_NE(r.out.find(k.says), std::string::npos) << r.out;
        EXPECT_TRUE(d.entries().empty()) << "left behind";
    }
}
