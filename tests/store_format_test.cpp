// The store format through the writer and reader: round trips, kinds of tiles, batch coalescing,
// and corruption anywhere in the file always detected.
#include <gtest/gtest.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <random>

#include <xxhash.h>

#include "tessera/storage/byte_source.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/store_writer.hpp"
#include "tessera/storage/verify.hpp"
#include "test_util.hpp"

using namespace tessera;
using namespace tessera::storage;
using tessera::test::ScratchDir;

namespace {

StoreSpec raw_spec(std::uint32_t w, std::uint32_t h, std::uint32_t payload, std::uint32_t border) {
    StoreSpec s;
    s.width = w;
    s.height = h;
    s.tile_payload = payload;
    s.border = border;
    s.channels = 1;
    s.sample_type = SampleType::u8;
    s.colour_space = ColourSpace::linear;
    s.codec = Codec::raw;
    return s;
}

// Distinct, recognisable bytes for a tile.
std::vector<std::uint8_t> tile_bytes(std::size_t n, std::uint32_t seed) {
    std::vector<std::uint8_t> v(n);
    std::mt19937 rng(seed);
    for (auto& b : v) b = static_cast<std::uint8_t>(rng());
    return v;
}

// A small store: 3 levels; at level 0 some tiles present, one uniform, one duplicate, some absent.
struct SmallStore {
    std::string path;
    std::size_t tile_bytes = 0;
};

SmallStore write_small_store(const ScratchDir& d) {
    const StoreSpec spec = raw_spec(40, 30, 12, 2);  // tiles 16x16; level 0 is 4x3 tiles
    auto w = StoreWriter::create(d.file("small.tsr"), spec);
    EXPECT_TRUE(w.ok());
    const std::size_t n = 16 * 16;
    for (std::uint32_t y = 0; y < 3; ++y)
        for (std::uint32_t x = 0; x < 4; ++x) {
            if (x == 3 && y == 2) continue;  // absent
            if (x == 2 && y == 2) {
                const std::uint8_t v = 7;
                EXPECT_TRUE((*w)->add_uniform({0, x, y}, std::span(&v, 1)).ok());
                continue;
            }
            const std::uint32_t seed = (x == 1 && y == 2) ? 0 : y * 4 + x;  // (1,2) duplicates (0,0)
            EXPECT_TRUE((*w)->add_present({0, x, y}, tile_bytes(n, seed)).ok());
        }
    for (std::uint32_t y = 0; y < 2; ++y)
        for (std::uint32_t x = 0; x < 2; ++x) EXPECT_TRUE((*w)->add_present({1, x, y}, tile_bytes(n, 100 + y * 2 + x)).ok());
    EXPECT_TRUE((*w)->add_present({2, 0, 0}, tile_bytes(n, 200)).ok());
    EXPECT_TRUE((*w)->finish().ok());
    return {d.file("small.tsr"), n};
}

}  // namespace

TEST(StoreFormat, RoundTripWithAllKindsOfTiles) {
    ScratchDir d;
    const SmallStore s = write_small_store(d);
    auto r = StoreReader::open(s.path);
    ASSERT_TRUE(r.ok()) << r.error().message;
    const StoreInfo& info = (*r)->info();
    EXPECT_EQ(info.width, 40u);
    EXPECT_EQ(info.height, 30u);
    EXPECT_EQ(info.tile_size(), 16u);
    ASSERT_EQ(info.level_count(), 3u);
    EXPECT_EQ(info.levels[0].tiles_x, 4u);
    EXPECT_EQ(info.levels[0].tiles_y, 3u);
    EXPECT_EQ(info.levels[0].present, 10u);
    EXPECT_EQ(info.levels[0].uniform, 1u);
    EXPECT_EQ(info.levels[0].absent, 1u);
    EXPECT_EQ(info.levels[0].deduplicated, 1u);
    EXPECT_EQ(info.levels[0].payload_bytes, 9 * s.tile_bytes);  // the duplicate costs nothing
    for (std::uint32_t y = 0; y < 3; ++y)
        for (std::uint32_t x = 0; x < 4; ++x) {
            auto t = (*r)->read_tile({0, x, y});
            ASSERT_TRUE(t.ok()) << t.error().message;
            if (x == 3 && y == 2) {
                EXPECT_EQ(t->kind, TileKind::absent);
            } else if (x == 2 && y == 2) {
                EXPECT_EQ(t->kind, TileKind::uniform);
                std::vector<std::uint8_t> dec;
                ASSERT_TRUE(decode_tile(info, *t, dec).ok());
                EXPECT_EQ(dec, std::vector<std::uint8_t>(s.tile_bytes, 7));
            } else {
                EXPECT_EQ(t->kind, TileKind::present);
                EXPECT_EQ(t->bytes, tile_bytes(s.tile_bytes, (x == 1 && y == 2) ? 0 : y * 4 + x));
                EXPECT_EQ(t->deduplicated, x == 1 && y == 2);
            }
        }
    EXPECT_EQ((*r)->read_tile({2, 0, 0})->bytes, tile_bytes(s.tile_bytes, 200));
    EXPECT_EQ((*r)->read_tile({0, 4, 0}).error().code, Errc::out_of_range);
    EXPECT_EQ((*r)->read_tile({3, 0, 0}).error().code, Errc::out_of_range);
    EXPECT_TRUE(verify_store(**r).ok());
}

TEST(StoreFormat, CoarseLevelsFirstAndMortonOrderWithinALevel) {
    ScratchDir d;
    const SmallStore s = write_small_store(d);
    auto r = StoreReader::open(s.path);
    ASSERT_TRUE(r.ok());
    auto off = [&](std::uint32_t l, std::uint32_t x, std::uint32_t y) { return (*r)->locate({l, x, y})->offset; };
    EXPECT_LT(off(2, 0, 0), off(1, 0, 0));
    EXPECT_LT(off(1, 1, 1), off(0, 0, 0));
    // Morton: (0,0) (1,0) (0,1) (1,1) (2,0) (3,0) (2,1) (3,1) (0,2) ...
    EXPECT_LT(off(0, 0, 0), off(0, 1, 0));
    EXPECT_LT(off(0, 1, 0), off(0, 0, 1));
    EXPECT_LT(off(0, 0, 1), off(0, 1, 1));
    EXPECT_LT(off(0, 1, 1), off(0, 2, 0));
    EXPECT_LT(off(0, 3, 1), off(0, 0, 2));
}

TEST(StoreFormat, BatchReadsCoalesceAdjacentTiles) {
    ScratchDir d;
    const SmallStore s = write_small_store(d);
    auto r = StoreReader::open(s.path);
    ASSERT_TRUE(r.ok());
    // A Morton quad is contiguous: four tiles, one read; order of results follows the request.
    const std::vector<TileKey> quad = {{0, 1, 1}, {0, 0, 0}, {0, 0, 1}, {0, 1, 0}};
    BatchStats stats;
    auto res = (*r)->read_tiles(quad, &stats);
    EXPECT_EQ(stats.reads, 1u);
    EXPECT_EQ(stats.bytes, 4 * s.tile_bytes);
    for (std::size_t i = 0; i < quad.size(); ++i) {
        ASSERT_TRUE(res[i].ok());
        EXPECT_EQ(res[i]->key, quad[i]);
        EXPECT_EQ(res[i]->bytes, tile_bytes(s.tile_bytes, quad[i].y * 4 + quad[i].x));
    }
    // Mixed batch: out-of-range, absent, uniform and present keys each get their own answer.
    const std::vector<TileKey> mixed = {{0, 9, 9}, {0, 3, 2}, {0, 2, 2}, {2, 0, 0}, {0, 1, 2}};
    res = (*r)->read_tiles(mixed, nullptr);
    EXPECT_EQ(res[0].error().code, Errc::out_of_range);
    EXPECT_EQ(res[1]->kind, TileKind::absent);
    EXPECT_EQ(res[2]->kind, TileKind::uniform);
    EXPECT_EQ(res[3]->bytes, tile_bytes(s.tile_bytes, 200));
    EXPECT_EQ(res[4]->bytes, tile_bytes(s.tile_bytes, 0));
}

// Any single flipped byte anywhere in the file is caught by verify, and a flipped payload byte
// makes the reader refuse that tile.
TEST(StoreFormat, EveryFlippedByteIsDetected) {
    ScratchDir d;
    const SmallStore s = write_small_store(d);
    const std::vector<std::uint8_t> good = test::read_file(s.path);
    auto clean = StoreReader::open_memory(good);
    ASSERT_TRUE(clean.ok());
    // Which tiles own which payload bytes.
    std::vector<std::pair<TileKey, TileLocation>> payloads;
    for (std::uint32_t l = 0; l < 3; ++l)
        for (std::uint32_t y = 0; y < (*clean)->info().levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < (*clean)->info().levels[l].tiles_x; ++x) {
                auto loc = (*clean)->locate({l, x, y});
                if (loc->kind == TileKind::present) payloads.emplace_back(TileKey{l, x, y}, *loc);
            }
    std::size_t undetected = 0;
    for (std::size_t pos = 0; pos < good.size(); ++pos) {
        std::vector<std::uint8_t> bad = good;
        bad[pos] ^= 0x5a;
        auto r = StoreReader::open_memory(std::move(bad));
        if (!r.ok()) continue;  // refused at open: detected
        if (verify_store(**r).ok()) {
            ++undetected;
            ADD_FAILURE() << "flip at byte " << pos << " of " << good.size() << " not detected";
        }
        for (const auto& [key, loc] : payloads)
            if (pos >= loc.offset && pos < loc.offset + loc.length) {
                auto t = (*r)->read_tile(key);
                EXPECT_FALSE(t.ok()) << "tile read despite a flipped payload byte at " << pos;
                if (!t.ok()) {
                    EXPECT_EQ(t.error().code, Errc::corrupt);
                }
            }
    }
    EXPECT_EQ(undetected, 0u);
}

TEST(StoreFormat, EveryTruncationIsRefusedAtOpen) {
    ScratchDir d;
    const SmallStore s = write_small_store(d);
    const std::vector<std::uint8_t> good = test::read_file(s.path);
    for (std::size_t len = 0; len < good.size(); len += 1 + len / 64) {
        auto r = StoreReader::open_memory(std::vector<std::uint8_t>(good.begin(), good.begin() + std::ptrdiff_t(len)));
        ASSERT_FALSE(r.ok()) << "truncated to " << len;
        EXPECT_EQ(r.error().code, Errc::corrupt);
    }
    // The same through a file.
    test::write_file(d.file("cut.tsr"), std::vector<std::uint8_t>(good.begin(), good.end() - 1));
    auto r = StoreReader::open(d.file("cut.tsr"));
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find("truncated"), std::string::npos) << r.error().message;
}

TEST(StoreFormat, NewerMajorVersionIsUnsupportedNotCorrupt) {
    ScratchDir d;
    const SmallStore s = write_small_store(d);
    std::vector<std::uint8_t> bytes = test::read_file(s.path);
    bytes[8] = 2;  // version_major
    auto r = StoreReader::open_memory(bytes);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, Errc::unsupported);
}

TEST(StoreFormat, WriterRejectsBadKeysAndDuplicatesAndLeavesNothingBehind) {
    ScratchDir d;
    {
        auto w = StoreWriter::create(d.file("x.tsr"), raw_spec(40, 30, 12, 2));
        ASSERT_TRUE(w.ok());
        EXPECT_EQ((*w)->add_present({0, 4, 0}, tile_bytes(256, 1)).error().code, Errc::out_of_range);
        EXPECT_EQ((*w)->add_present({5, 0, 0}, tile_bytes(256, 1)).error().code, Errc::out_of_range);
        const std::uint8_t two[2] = {1, 2};
        EXPECT_FALSE((*w)->add_uniform({0, 0, 0}, two).ok());
        ASSERT_TRUE((*w)->add_present({0, 0, 0}, tile_bytes(256, 1)).ok());
        ASSERT_TRUE((*w)->add_present({0, 0, 0}, tile_bytes(256, 2)).ok());
        EXPECT_FALSE((*w)->finish().ok());  // duplicate key
    }
    EXPECT_TRUE(d.entries().empty()) << d.entries().front();
    {
        auto w = StoreWriter::create(d.file("y.tsr"), raw_spec(40, 30, 12, 2));
        ASSERT_TRUE(w.ok());
        ASSERT_TRUE((*w)->add_present({0, 0, 0}, tile_bytes(256, 1)).ok());
        // destroyed without finish()
    }
    EXPECT_TRUE(d.entries().empty());
    EXPECT_FALSE(StoreWriter::create(d.file("no/such/dir/z.tsr"), raw_spec(40, 30, 12, 2)).ok());
    StoreSpec bad = raw_spec(40, 30, 12, 2);
    bad.codec = Codec::jpeg;
    bad.channels = 4;
    EXPECT_FALSE(StoreWriter::create(d.file("j.tsr"), bad).ok());
    EXPECT_FALSE(StoreWriter::create(d.file("z.tsr"), raw_spec(0, 30, 12, 2)).ok());
}

// A store with millions of tile slots (mostly uniform or absent) opens without reading its
// index; tiles anywhere read back right.
TEST(StoreFormat, MillionsOfTilesOpenLazily) {
    ScratchDir d;
    StoreSpec spec = raw_spec(2048 * 64, 1024 * 64, 60, 2);  // level 0: 2048 x 1024 tiles
    auto w = StoreWriter::create(d.file("big.tsr"), spec);
    ASSERT_TRUE(w.ok());
    std::uint64_t added = 0;
    for (std::uint32_t y = 0; y < 1024; ++y)
        for (std::uint32_t x = 0; x < 1024; ++x)
            if ((x + y) % 3 != 0) {
                const std::uint8_t v = static_cast<std::uint8_t>(x ^ y);
                ASSERT_TRUE((*w)->add_uniform({0, x, y}, std::span(&v, 1)).ok());
                ++added;
            }
    ASSERT_TRUE((*w)->add_present({0, 2047, 1023}, tile_bytes(64 * 64, 9)).ok());
    ASSERT_TRUE((*w)->finish().ok());
    auto r = StoreReader::open(d.file("big.tsr"));
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_EQ((*r)->info().levels[0].uniform, added);
    EXPECT_EQ((*r)->read_tile({0, 1000, 501})->kind, TileKind::uniform);
    EXPECT_EQ((*r)->read_tile({0, 1000, 501})->bytes, std::vector<std::uint8_t>{static_cast<std::uint8_t>(1000 ^ 501)});
    EXPECT_EQ((*r)->read_tile({0, 999, 0})->kind, TileKind::absent);
    EXPECT_EQ((*r)->read_tile({0, 2047, 1023})->bytes, tile_bytes(64 * 64, 9));
    EXPECT_EQ((*r)->read_tile({1, 0, 0})->kind, TileKind::absent);
}

// A sparse index (format 1.2, docs/store-format.md "Sparse stores"): a store whose block tables
// would be mostly empty lists only its non-empty blocks. It reads back as written, and a reader
// refuses a table out of order, out of range, repeating a block, listing an empty one or claiming
// more blocks than the level has, with an error even when every checksum is made to match.
namespace {

template <class T>
T load_at(const std::vector<std::uint8_t>& b, std::size_t off) {
    T v;
    std::memcpy(&v, b.data() + off, sizeof v);
    return v;
}
template <class T>
void store_at(std::vector<std::uint8_t>& b, std::size_t off, T v) {
    std::memcpy(b.data() + off, &v, sizeof v);
}

// Makes the checksums over level `l`'s block table, the level table and the header match again.
void reseal(std::vector<std::uint8_t>& b, std::uint32_t l, std::uint64_t table_bytes) {
    const std::uint64_t lt = load_at<std::uint64_t>(b, 40), rec = lt + std::uint64_t(l) * 96;
    const std::uint64_t bt = load_at<std::uint64_t>(b, std::size_t(rec) + 24);
    store_at<std::uint64_t>(b, std::size_t(rec) + 32, XXH3_64bits(b.data() + bt, table_bytes));
    store_at<std::uint64_t>(b, 96, XXH3_64bits(b.data() + lt, std::size_t(b[30]) * 96));
    store_at<std::uint64_t>(b, 120, XXH3_64bits(b.data(), 120));
}

}  // namespace

// Geometries whose dense index no reader would hold (block tables over kMaxBlockTableBytes) are
// refused when the writer is created, with the reason; finish() used to throw std::bad_alloc for
// the first (an index region of about 2^54 bytes) and write a 1 GiB file the reader refuses for
// the second. The same geometry with a sparse index is fine.
TEST(StoreFormat, GeometriesNoReaderWouldHoldAreRefused) {
    ScratchDir d;
    for (const auto& [w, h] : {std::pair{0xffffffffu, 0xffffffffu}, std::pair{0xffffffffu, 1u}}) {
        SCOPED_TRACE(std::to_string(w) + " x " + std::to_string(h));
        StoreSpec spec = raw_spec(w, h, 2, 0);
        const Status v = validate(spec);
        ASSERT_FALSE(v.ok());
        EXPECT_EQ(v.error().code, Errc::invalid_argument);
        EXPECT_NE(v.error().message.find("block tables"), std::string::npos) << v.error().message;
        auto writer = StoreWriter::create(d.file("huge.tsr"), spec);
        ASSERT_FALSE(writer.ok());
        EXPECT_FALSE(std::filesystem::exists(d.file("huge.tsr")));

        spec.sparse_index = true;
        auto sparse = StoreWriter::create(d.file("sparse.tsr"), spec);
        ASSERT_TRUE(sparse.ok()) << sparse.error().message;
        ASSERT_TRUE((*sparse)->add_present({0, 5, 0}, tile_bytes(4, 1)).ok());
        ASSERT_TRUE((*sparse)->finish().ok());
        auto r = StoreReader::open(d.file("sparse.tsr"));
        ASSERT_TRUE(r.ok()) << r.error().message;
        EXPECT_EQ((*r)->read_tile({0, 5, 0})->bytes, tile_bytes(4, 1));
    }
}

// verify walks the blocks that hold data: a sparse store of 2^31 x 2^31 one-texel tiles (2^50
// blocks at level 0) with three tiles is checked in moments, every tile counted, and a damaged
// tile in it is still found.
TEST(StoreFormat, VerifyOfAHugeSparseStoreVisitsOnlyItsData) {
    ScratchDir d;
    StoreSpec spec = raw_spec(0x80000000u, 0x80000000u, 1, 0);
    spec.sparse_index = true;
    const TileKey keys[] = {{0, 0, 0}, {0, 0x7fffffffu, 0x7fffffffu}, {5, 12345, 67}};
    {
        auto w = StoreWriter::create(d.file("vast.tsr"), spec);
        ASSERT_TRUE(w.ok()) << w.error().message;
        for (std::size_t i = 0; i < std::size(keys); ++i) ASSERT_TRUE((*w)->add_present(keys[i], tile_bytes(1, std::uint32_t(i))).ok());
        ASSERT_TRUE((*w)->finish().ok());
    }
    auto r = StoreReader::open(d.file("vast.tsr"));
    ASSERT_TRUE(r.ok()) << r.error().message;
    const auto t0 = std::chrono::steady_clock::now();
    const VerifyReport rep = verify_store(**r);
    EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(20));
    EXPECT_TRUE(rep.ok()) << (rep.problems.empty() ? std::string() : rep.problems.front());
    EXPECT_EQ(rep.payloads_checked, 3u);
    std::uint64_t tiles = 0;
    for (const auto& l : (*r)->info().levels) tiles += std::uint64_t(l.tiles_x) * l.tiles_y;
    EXPECT_EQ(rep.tiles_checked, tiles);
    EXPECT_EQ((*r)->data_blocks(0).size(), 2u);

    // The far corner's payload damaged: found.
    std::vector<std::uint8_t> b = test::read_file(d.file("vast.tsr"));
    const auto loc = (*r)->locate(keys[1]);
    ASSERT_TRUE(loc.ok());
    b[loc->offset] ^= 0xff;
    auto damaged = StoreReader::open_memory(b);
    ASSERT_TRUE(damaged.ok());
    EXPECT_FALSE(verify_store(**damaged).ok());
}

// docs/store-format.md, "Index": a reader refuses an entry with fields it should not have, even
// with every checksum made to match: reserved bits, flags other than deduplicated, a flag on a
// tile that is not present, a checksum on an absent tile.
TEST(StoreFormat, EntriesWithFieldsTheyShouldNotHaveAreRefused) {
    ScratchDir d;
    const std::vector<std::uint8_t> good = test::read_file(write_small_store(d).path);
    const std::uint64_t rec0 = load_at<std::uint64_t>(good, 40);
    const std::uint64_t bt = load_at<std::uint64_t>(good, std::size_t(rec0) + 24);
    const std::uint64_t eb = load_at<std::uint64_t>(good, std::size_t(bt));
    auto entry = [&](std::uint32_t x, std::uint32_t y) { return std::size_t(eb + (std::uint64_t(y) * 64 + x) * 24); };
    struct Case {
        const char* what;
        TileKey key;
        std::size_t field;
        std::uint64_t value;
        std::size_t bytes;
    };
    const Case cases[] = {
        {"reserved bits of a present tile", {0, 0, 0}, 14, 1, 2},
        {"an unknown flag of a present tile", {0, 1, 0}, 13, 2, 1},
        {"the deduplicated flag on a uniform tile", {0, 2, 2}, 13, 1, 1},
        {"a checksum on an absent tile", {0, 3, 2}, 16, 0x1234, 8},
    };
    for (const Case& c : cases) {
        SCOPED_TRACE(c.what);
        std::vector<std::uint8_t> b = good;
        std::memcpy(b.data() + entry(c.key.x, c.key.y) + c.field, &c.value, c.bytes);
        store_at<std::uint64_t>(b, std::size_t(bt) + 8, XXH3_64bits(b.data() + eb, 98304));
        reseal(b, 0, 16);
        auto r = StoreReader::open_memory(b);
        ASSERT_TRUE(r.ok()) << r.error().message;
        auto t = (*r)->read_tile(c.key);
        ASSERT_FALSE(t.ok());
        EXPECT_EQ(t.error().code, Errc::corrupt) << t.error().message;
        EXPECT_FALSE(verify_store(**r).ok());
        EXPECT_TRUE((*r)->read_tile({0, 0, 1}).ok()) << "the rest of the store reads";
    }
}

// verify checks the data section against the index's end (data_offset) and each level's data
// range: bytes no tile references after the index, or levels whose ranges are swapped, are
// problems even with every checksum made to match.
TEST(StoreFormat, VerifyChecksTheDataSectionAndTheLevelsRanges) {
    ScratchDir d;
    {
        auto w = StoreWriter::create(d.file("flat.tsr"), raw_spec(40, 30, 12, 2));
        ASSERT_TRUE(w.ok());
        const std::uint8_t v = 7;
        ASSERT_TRUE((*w)->add_uniform({0, 1, 1}, std::span(&v, 1)).ok());
        ASSERT_TRUE((*w)->finish().ok());
    }
    std::vector<std::uint8_t> flat = test::read_file(d.file("flat.tsr"));
    ASSERT_TRUE(verify_store(**StoreReader::open_memory(flat)).ok());
    flat.resize(flat.size() + 4096, 0x5a);  // bytes no tile references
    store_at<std::uint64_t>(flat, 80, flat.size());
    store_at<std::uint64_t>(flat, 120, XXH3_64bits(flat.data(), 120));
    auto padded = StoreReader::open_memory(flat);
    ASSERT_TRUE(padded.ok()) << padded.error().message;
    const VerifyReport pr = verify_store(**padded);
    EXPECT_FALSE(pr.ok());
    EXPECT_FALSE(pr.problems.empty() || pr.problems.front().find("data section") == std::string::npos)
        << (pr.problems.empty() ? std::string() : pr.problems.front());

    // Levels 0 and 2 with each other's data range.
    std::vector<std::uint8_t> b = test::read_file(write_small_store(d).path);
    ASSERT_TRUE(verify_store(**StoreReader::open_memory(b)).ok());
    const std::size_t lt = std::size_t(load_at<std::uint64_t>(b, 40)), r0 = lt, r2 = lt + 2 * 96;
    for (const std::size_t f : {40, 48}) {
        const std::uint64_t a = load_at<std::uint64_t>(b, r0 + f), c = load_at<std::uint64_t>(b, r2 + f);
        store_at<std::uint64_t>(b, r0 + f, c);
        store_at<std::uint64_t>(b, r2 + f, a);
    }
    store_at<std::uint64_t>(b, 96, XXH3_64bits(b.data() + lt, std::size_t(b[30]) * 96));
    store_at<std::uint64_t>(b, 120, XXH3_64bits(b.data(), 120));
    auto swapped = StoreReader::open_memory(b);
    ASSERT_TRUE(swapped.ok()) << swapped.error().message;
    const VerifyReport sr = verify_store(**swapped);
    EXPECT_FALSE(sr.ok());
    bool named = false, id = false;
    for (const auto& p : sr.problems) {
        named |= p.find("outside the level's data range") != std::string::npos;
        id |= p.find("store id") != std::string::npos;
    }
    EXPECT_TRUE(named);
    EXPECT_TRUE(id) << "the level table changed, the store id did not";
}

// The store id is the index's content hash, which caches key tiles by: verify recomputes it, so
// an id that is not the index's (an index edited after writing, every checksum made to match)
// is a problem, where open alone cannot tell.
TEST(StoreFormat, VerifyRecomputesTheStoreId) {
    ScratchDir d;
    std::vector<std::uint8_t> b = test::read_file(write_small_store(d).path);
    auto good = StoreReader::open_memory(b);
    ASSERT_TRUE(good.ok());
    ASSERT_TRUE((*good)->index_hash().ok());
    EXPECT_EQ(*(*good)->index_hash(), (*good)->info().store_id);
    ASSERT_TRUE(verify_store(**good).ok());

    store_at<std::uint64_t>(b, 88, load_at<std::uint64_t>(b, 88) ^ 1);
    store_at<std::uint64_t>(b, 120, XXH3_64bits(b.data(), 120));
    auto changed = StoreReader::open_memory(b);
    ASSERT_TRUE(changed.ok()) << changed.error().message;
    const VerifyReport rep = verify_store(**changed);
    ASSERT_EQ(rep.problem_count, 1u);
    EXPECT_NE(rep.problems.front().find("store id"), std::string::npos) << rep.problems.front();
}

// Two block records naming the same entry block, every checksum made to match: each record's
// block is held once read, so a file of many such records would cost memory by its record count
// (about 6 000 times its size). The reader refuses the overlap when it opens the store.
TEST(StoreFormat, SharedEntryBlocksAreRefused) {
    ScratchDir d;
    const std::size_t n = 16 * 16;
    {
        auto w = StoreWriter::create(d.file("two.tsr"), raw_spec(12 * 128, 12 * 64, 12, 2));  // 2 x 1 blocks at level 0
        ASSERT_TRUE(w.ok());
        ASSERT_TRUE((*w)->add_present({0, 0, 0}, tile_bytes(n, 1)).ok());
        ASSERT_TRUE((*w)->add_present({0, 64, 0}, tile_bytes(n, 2)).ok());
        ASSERT_TRUE((*w)->finish().ok());
    }
    std::vector<std::uint8_t> b = test::read_file(d.file("two.tsr"));
    ASSERT_TRUE(StoreReader::open_memory(b).ok());
    const std::uint64_t rec0 = load_at<std::uint64_t>(b, 40);
    const std::uint64_t bt = load_at<std::uint64_t>(b, std::size_t(rec0) + 24);
    ASSERT_EQ(load_at<std::uint32_t>(b, std::size_t(rec0) + 16), 2u);  // blocks_x
    const std::uint64_t first = load_at<std::uint64_t>(b, std::size_t(bt)), second = load_at<std::uint64_t>(b, std::size_t(bt) + 16);
    ASSERT_NE(first, 0u);
    ASSERT_NE(second, 0u);
    for (const std::uint64_t at : {first, first + 24 * 64}) {  // the same block, then one overlapping it
        std::vector<std::uint8_t> c = b;
        store_at<std::uint64_t>(c, std::size_t(bt) + 16, at);
        store_at<std::uint64_t>(c, std::size_t(bt) + 24, XXH3_64bits(c.data() + at, 98304));
        reseal(c, 0, 2 * 16);
        auto r = StoreReader::open_memory(c);
        ASSERT_FALSE(r.ok()) << "entry block at " << at;
        EXPECT_EQ(r.error().code, Errc::corrupt);
        EXPECT_NE(r.error().message.find("entry blocks overlap"), std::string::npos) << r.error().message;
    }
}

TEST(StoreFormat, SparseIndexReadsBackAndRefusesBadTables) {
    ScratchDir d;
    StoreSpec spec = raw_spec(16384, 16384, 12, 2);  // 1366 x 1366 tiles, 22 x 22 blocks at level 0
    spec.sparse_index = true;
    const std::size_t n = 16 * 16;
    const TileKey keys[] = {{0, 0, 0}, {0, 1365, 7}, {0, 700, 1365}, {3, 20, 20}};
    {
        auto w = StoreWriter::create(d.file("sparse.tsr"), spec);
        ASSERT_TRUE(w.ok());
        for (std::size_t i = 0; i < std::size(keys); ++i) ASSERT_TRUE((*w)->add_present(keys[i], tile_bytes(n, std::uint32_t(i))).ok());
        ASSERT_TRUE((*w)->finish().ok());
    }
    const std::vector<std::uint8_t> good = test::read_file(d.file("sparse.tsr"));
    auto r = StoreReader::open_memory(good);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_EQ((*r)->info().version_minor, 2u);
    {
        // The same tiles without asking for a sparse index: format 1.0, readable by older readers.
        auto w = StoreWriter::create(d.file("dense.tsr"), raw_spec(16384, 16384, 12, 2));
        ASSERT_TRUE(w.ok());
        for (std::size_t i = 0; i < std::size(keys); ++i) ASSERT_TRUE((*w)->add_present(keys[i], tile_bytes(n, std::uint32_t(i))).ok());
        ASSERT_TRUE((*w)->finish().ok());
        auto dense = StoreReader::open(d.file("dense.tsr"));
        ASSERT_TRUE(dense.ok()) << dense.error().message;
        EXPECT_EQ((*dense)->info().version_minor, 0u);
        EXPECT_EQ((*dense)->read_tile(keys[1])->bytes, tile_bytes(n, 1));
    }
    EXPECT_LT(good.size(), std::size_t(1) << 20) << "the index follows the present tiles";
    for (std::size_t i = 0; i < std::size(keys); ++i) {
        auto t = (*r)->read_tile(keys[i]);
        ASSERT_TRUE(t.ok()) << t.error().message;
        EXPECT_EQ(t->bytes, tile_bytes(n, std::uint32_t(i)));
    }
    EXPECT_EQ((*r)->locate({0, 1, 0})->kind, TileKind::absent);
    EXPECT_EQ((*r)->locate({0, 1365, 1365})->kind, TileKind::absent);
    EXPECT_FALSE((*r)->index_block_empty(0, 21, 0));  // (1365, 7)
    EXPECT_TRUE((*r)->index_block_empty(0, 21, 21));
    EXPECT_TRUE(verify_store(**r).ok());

    // Level 0's table: three records of 24 bytes, (bx, by) (0, 0), (21, 0), (10, 21).
    const std::uint64_t rec0 = load_at<std::uint64_t>(good, 40);
    const std::size_t bt = std::size_t(load_at<std::uint64_t>(good, std::size_t(rec0) + 24));
    ASSERT_EQ(load_at<std::uint64_t>(good, std::size_t(rec0) + 88), 3u);
    ASSERT_EQ(load_at<std::uint32_t>(good, bt + 24), 21u);
    // Each case must be refused by its own rule (the message says which), not by a checksum.
    const auto refused = [&](std::vector<std::uint8_t> bad, std::uint64_t table_bytes, const char* what, const char* rule) {
        reseal(bad, 0, table_bytes);
        auto o = StoreReader::open_memory(std::move(bad));
        ASSERT_FALSE(o.ok()) << what;
        EXPECT_EQ(o.error().code, Errc::corrupt) << what;
        EXPECT_NE(o.error().message.find(rule), std::string::npos) << what << ": " << o.error().message;
        std::printf("  %s: %s\n", what, o.error().message.c_str());
    };
    {
        auto bad = good;  // records 0 and 1 swapped
        std::swap_ranges(bad.begin() + std::ptrdiff_t(bt), bad.begin() + std::ptrdiff_t(bt + 24), bad.begin() + std::ptrdiff_t(bt + 24));
        refused(bad, 72, "out of order", "not in order");
    }
    {
        auto bad = good;
        store_at<std::uint32_t>(bad, bt + 24, 22);  // bx past the level
        refused(bad, 72, "outside the level", "outside the level");
    }
    {
        auto bad = good;
        std::copy_n(good.begin() + std::ptrdiff_t(bt), 24, bad.begin() + std::ptrdiff_t(bt + 24));  // block (0, 0) twice
        refused(bad, 72, "repeated", "not in order");
    }
    {
        auto bad = good;
        store_at<std::uint64_t>(bad, bt + 8, 0);  // an empty block listed
        refused(bad, 72, "empty block listed", "lists an empty block");
    }
    {
        auto bad = good;
        store_at<std::uint64_t>(bad, std::size_t(rec0) + 88, 22u * 22u + 1);  // more records than blocks
        refused(bad, 72, "too many records", "more blocks than it has");
    }
    // Every flipped byte of the header, level table and block tables is refused at open or by verify.
    std::size_t first_entry_block = good.size();
    for (std::uint32_t l = 0; l < good[30]; ++l) {
        const std::size_t rec = std::size_t(rec0) + std::size_t(l) * 96;
        const std::size_t table = std::size_t(load_at<std::uint64_t>(good, rec + 24));
        for (std::uint64_t k = 0; k < load_at<std::uint64_t>(good, rec + 88); ++k)
            first_entry_block = std::min(first_entry_block, std::size_t(load_at<std::uint64_t>(good, table + k * 24 + 8)));
    }
    std::size_t undetected = 0;
    for (std::size_t pos = 0; pos < first_entry_block; ++pos) {
        auto bad = good;
        bad[pos] ^= 0x5a;
        auto o = StoreReader::open_memory(std::move(bad));
        if (o.ok() && verify_store(**o).ok()) ++undetected;
    }
    EXPECT_EQ(undetected, 0u) << "of " << first_entry_block << " index bytes";
}

namespace {

// A source as a lying remote origin could be: it claims `size` bytes, holds `head` at offset 0
// and zeros after it.
class ClaimedSizeSource final : public ByteSource {
public:
    ClaimedSizeSource(std::vector<std::uint8_t> head, std::uint64_t size) : head_(std::move(head)), size_(size) {}
    std::uint64_t size() const override { return size_; }
    Status read(std::uint64_t offset, std::uint64_t length, std::uint8_t* dst) const override {
        if (offset > size_ || length > size_ - offset) return make_error(Errc::corrupt, "past the end");
        for (std::uint64_t i = 0; i < length; ++i) dst[i] = offset + i < head_.size() ? head_[offset + i] : 0;
        return {};
    }

private:
    std::vector<std::uint8_t> head_;
    std::uint64_t size_;
};

}  // namespace

// A sound-looking header (all its checksums right) for a 2^32-1 texel square of 2-texel tiles,
// in a file that claims 2^60 bytes: level 0 alone would need a 2^54-byte dense block table. The
// reader refuses it with an error before allocating, as it must on a server's reload thread.
TEST(StoreFormat, HugeClaimedIndexIsRefusedNotAllocated) {
    ScratchDir d;
    std::vector<std::uint8_t> b = test::read_file(write_small_store(d).path);
    b.resize(128);  // the real header: magic and version
    const std::uint64_t size = std::uint64_t(1) << 60;
    const std::uint32_t side = 0xffffffffu, payload = 2;
    std::uint32_t levels = 1;  // docs/store-format.md, "Geometry": halve (rounding up) until one tile
    for (std::uint64_t w = side; w > payload; w = (w + 1) / 2) ++levels;
    store_at<std::uint32_t>(b, 16, side);
    store_at<std::uint32_t>(b, 20, side);
    store_at<std::uint32_t>(b, 24, payload);
    store_at<std::uint16_t>(b, 28, 0);
    b[30] = std::uint8_t(levels);
    b[35] = 0;  // flags: dense index, no alpha
    store_at<std::uint64_t>(b, 40, 128);
    store_at<std::uint32_t>(b, 48, levels * 96);
    store_at<std::uint32_t>(b, 52, 0);
    store_at<std::uint64_t>(b, 56, 128 + levels * 96);
    store_at<std::uint64_t>(b, 64, 128 + levels * 96);
    store_at<std::uint64_t>(b, 72, size);  // data_offset: the whole file is index
    store_at<std::uint64_t>(b, 80, size);
    store_at<std::uint64_t>(b, 104, XXH3_64bits(nullptr, 0));
    b.resize(128 + levels * 96);
    const std::uint64_t tiles = (std::uint64_t(side) + payload - 1) / payload, blocks = (tiles + 63) / 64;
    store_at<std::uint32_t>(b, 128 + 0, side);
    store_at<std::uint32_t>(b, 128 + 4, side);
    store_at<std::uint32_t>(b, 128 + 8, std::uint32_t(tiles));
    store_at<std::uint32_t>(b, 128 + 12, std::uint32_t(tiles));
    store_at<std::uint32_t>(b, 128 + 16, std::uint32_t(blocks));
    store_at<std::uint32_t>(b, 128 + 20, std::uint32_t(blocks));
    store_at<std::uint64_t>(b, 128 + 24, 128 + levels * 96);  // block table right after the level table
    store_at<std::uint64_t>(b, 96, XXH3_64bits(b.data() + 128, levels * 96));
    store_at<std::uint64_t>(b, 120, XXH3_64bits(b.data(), 120));

    auto r = StoreReader::open_source(std::make_unique<ClaimedSizeSource>(b, size), "liar");
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, Errc::unsupported) << r.error().message;
    EXPECT_NE(r.error().message.find("block tables"), std::string::npos) << r.error().message;
}
