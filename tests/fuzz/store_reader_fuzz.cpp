// libFuzzer target: StoreReader (open_memory, locate, read_tile(s), palette_value), decode_tile and
// verify_store over arbitrary bytes. They must fail with an error value, never crash, leak, hit
// undefined behaviour or return garbage.
//
// Each input runs twice: as given, and with every checksum recomputed over the (mutated) bytes.
// The first run mostly exercises the checksum gates; the second lets mutations of header fields,
// level records, index entries and payloads reach the parsing and reading code behind them.
#include <xxhash.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <span>
#include <vector>

#include "format.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/layers.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/store_writer.hpp"
#include "tessera/storage/verify.hpp"

namespace {

using namespace tessera;
using namespace tessera::storage;

#define FUZZ_CHECK(cond)                                                                 \
    do {                                                                                 \
        if (!(cond)) {                                                                   \
            std::fprintf(stderr, "store_reader_fuzz: check failed at line %d: %s\n", __LINE__, #cond); \
            std::abort();                                                                \
        }                                                                                \
    } while (0)

constexpr std::size_t kMaxKeys = 64;                  // tiles looked up per input
constexpr std::uint64_t kMaxVerifyTiles = 4096;       // verify_store only on stores this small
constexpr std::uint64_t kMaxDecodeBytes = 64u << 20;  // decoded bytes per input, at most
constexpr std::uint64_t kMaxFixupHashBytes = 16u << 20;

bool in_bounds(std::size_t size, std::uint64_t off, std::uint64_t len) { return off <= size && len <= size - off; }

// Recomputes every checksum the format has (payload and uniform-value checksums in the entries,
// entry blocks, block tables, level table, palette, header) and the file size, wherever the
// offsets in the bytes point inside the buffer. Best effort: regions may overlap.
void fix_checksums(std::vector<std::uint8_t>& b) {
    using namespace format;
    if (b.size() < kHeaderBytes) return;
    std::uint8_t* h = b.data();
    const std::size_t size = b.size();
    store<std::uint64_t>(h, header::file_size, size);
    const std::uint32_t channels = h[header::channels];
    const std::uint8_t st = h[header::sample_type];
    const std::size_t texel = channels >= 1 && channels <= 4 && st <= 3 ? channels * sample_bytes(static_cast<SampleType>(st)) : 0;
    const std::uint64_t lt_off = load<std::uint64_t>(h, header::level_table_offset);
    const std::uint64_t levels = h[header::level_count];
    const std::uint64_t pal_off = load<std::uint64_t>(h, header::palette_offset);
    const std::uint64_t pal_count = load<std::uint32_t>(h, header::palette_count);
    const bool palette_ok = in_bounds(size, pal_off, pal_count * kPaletteValueBytes);
    std::uint64_t hash_budget = kMaxFixupHashBytes;
    if (in_bounds(size, lt_off, levels * kLevelRecordBytes)) {
        for (std::uint64_t l = 0; l < levels; ++l) {
            std::uint8_t* r = h + lt_off + l * kLevelRecordBytes;
            const std::uint64_t bt = load<std::uint64_t>(r, level::block_table_offset);
            // A sparse index (flags bit 1) lists block_records records of 24 bytes: (bx, by), then
            // the block record; a dense one every block's 16.
            const bool sparse = (h[header::flags] & kHeaderFlagSparseIndex) != 0;
            const std::size_t rec_bytes = sparse ? kSparseBlockRecordBytes : kBlockRecordBytes;
            const std::uint64_t nb = sparse ? load<std::uint64_t>(r, level::block_records)
                                            : std::uint64_t(load<std::uint32_t>(r, level::blocks_x)) * load<std::uint32_t>(r, level::blocks_y);
            if (nb > size / rec_bytes || !in_bounds(size, bt, nb * rec_bytes)) continue;
            for (std::uint64_t i = 0; i < nb; ++i) {
                std::uint8_t* rec = h + bt + i * rec_bytes + (sparse ? 8 : 0);
                const std::uint64_t eo = load<std::uint64_t>(rec, 0);
                if (eo == 0 || !in_bounds(size, eo, kEntryBlockBytes) || hash_budget < kEntryBlockBytes) continue;
                hash_budget -= kEntryBlockBytes;
                std::uint8_t* blk = h + eo;
                for (std::size_t e = 0; e < kEntriesPerBlock; ++e) {
                    std::uint8_t* en = blk + e * kEntryBytes;
                    const std::uint64_t off = load<std::uint64_t>(en, entry::offset);
                    const std::uint32_t len = load<std::uint32_t>(en, entry::length);
                    if (en[entry::kind] == 1 && in_bounds(size, off, len) && len <= hash_budget) {
                        hash_budget -= len;
                        store<std::uint64_t>(en, entry::checksum, XXH3_64bits(h + off, len));
                    } else if (en[entry::kind] == 2 && palette_ok && off < pal_count && texel != 0) {
                        store<std::uint64_t>(en, entry::checksum, XXH3_64bits(h + pal_off + off * kPaletteValueBytes, texel));
                    }
                }
                store<std::uint64_t>(rec, 8, XXH3_64bits(blk, kEntryBlockBytes));
            }
            store<std::uint64_t>(r, level::block_table_checksum, XXH3_64bits(h + bt, nb * rec_bytes));
        }
        store<std::uint64_t>(h, header::level_table_checksum, XXH3_64bits(h + lt_off, levels * kLevelRecordBytes));
        // A layered store's layer table follows the level table.
        const std::uint64_t layers = h[header::layer_count];
        const std::uint64_t layer_off = lt_off + levels * kLevelRecordBytes;
        if (layers > 0 && in_bounds(size, layer_off, layers * kLayerRecordBytes))
            store<std::uint64_t>(h, header::layer_table_checksum, XXH3_64bits(h + layer_off, layers * kLayerRecordBytes));
    }
    if (palette_ok) store<std::uint64_t>(h, header::palette_checksum, XXH3_64bits(h + pal_off, pal_count * kPaletteValueBytes));
    store<std::uint64_t>(h, header::header_checksum, XXH3_64bits(h, header::header_checksum));
}

// What a reader promises about a store it agreed to open.
void check_info(const StoreInfo& info) {
    FUZZ_CHECK(info.level_count() >= 1 && info.level_count() <= format::kMaxLevels);
    StoreSpec spec;
    spec.width = info.width;
    spec.height = info.height;
    spec.tile_payload = info.tile_payload;
    spec.border = info.border;
    spec.channels = info.channels;
    spec.sample_type = info.sample_type;
    spec.colour_space = info.colour_space;
    spec.codec = info.codec;
    spec.has_alpha = info.has_alpha;
    spec.layers = info.layers;
    FUZZ_CHECK(validate(spec).ok());  // a store that opens is one the writer could have written
    std::uint64_t layer_bytes = 0;
    for (const LayerInfo& l : info.layers) layer_bytes += l.payload_bytes;
    FUZZ_CHECK(layer_bytes <= info.file_size);
    FUZZ_CHECK(info.tile_size() >= 1 && info.tile_size() <= format::kMaxTileSize);
    const auto geometry = level_geometry(info.width, info.height, info.tile_payload);
    FUZZ_CHECK(geometry.size() == info.levels.size());
    for (std::size_t l = 0; l < geometry.size(); ++l) {
        const LevelInfo& L = info.levels[l];
        FUZZ_CHECK(L.width == geometry[l].width && L.height == geometry[l].height);
        FUZZ_CHECK(L.tiles_x == geometry[l].tiles_x && L.tiles_y == geometry[l].tiles_y);
        const std::uint64_t tiles = std::uint64_t(L.tiles_x) * L.tiles_y;
        FUZZ_CHECK(L.present <= tiles && L.uniform <= tiles && L.absent <= tiles);
        FUZZ_CHECK(L.present + L.uniform + L.absent == tiles);
        FUZZ_CHECK(L.deduplicated <= L.present);
        FUZZ_CHECK(L.payload_bytes <= info.file_size);
    }
}

void decode_checked(const StoreInfo& info, const Tile& t);

// Bytes one tile decodes to: every layer's tile in a layered store.
std::uint64_t decoded_bytes(const StoreInfo& info) {
    if (!info.layered()) return info.tile_bytes();
    std::uint64_t n = 0;
    for (std::size_t i = 0; i < info.layers.size(); ++i) n += layer_store_info(info, i).tile_bytes();
    return n;
}

void check_tile(const StoreInfo& info, const TileKey& key, const Result<Tile>& t, std::uint64_t& decode_budget) {
    if (!t) {
        FUZZ_CHECK(!t.error().message.empty());
        return;
    }
    FUZZ_CHECK(t->key == key);
    if (t->kind == TileKind::absent) {
        FUZZ_CHECK(t->bytes.empty());
        return;
    }
    FUZZ_CHECK(XXH3_64bits(t->bytes.data(), t->bytes.size()) == t->checksum);
    if (t->kind == TileKind::uniform) FUZZ_CHECK(t->bytes.size() == info.texel_bytes());
    if (t->kind == TileKind::present) FUZZ_CHECK(!t->bytes.empty());
    if (decoded_bytes(info) > decode_budget) return;
    decode_budget -= decoded_bytes(info);
        decode_checked(info, *t);
}

// Decodes a tile; a layered store's bundle is split and each part decoded with its layer's
// description. The codec libraries are not instrumented, so ASan cannot see them write past the
// buffer: a guard zone behind the tile (resize within capacity keeps it) is checked after.
void decode_checked(const StoreInfo& info, const Tile& t) {
    if (info.layered()) {
        FUZZ_CHECK(t.kind == TileKind::present);  // a layered store has no uniform tiles
        const auto parts = split_layers(info, t.bytes);
        if (!parts) {
            FUZZ_CHECK(parts.error().code == Errc::corrupt && !parts.error().message.empty());
            return;
        }
        FUZZ_CHECK(parts->size() == info.layers.size());
        for (std::size_t i = 0; i < parts->size(); ++i)
            if ((*parts)[i].kind != TileKind::absent) decode_checked(layer_store_info(info, i), layer_tile(t.key, (*parts)[i]));
        return;
    }
    constexpr std::size_t kGuard = 256;
    std::vector<std::uint8_t> out;
    out.reserve(info.tile_bytes() + kGuard);
    std::uint8_t* const guard = out.data() + info.tile_bytes();
    std::fill_n(guard, kGuard, std::uint8_t{0xa5});
    const Status st = decode_tile(info, t, out);
    if (out.data() + info.tile_bytes() == guard)
        FUZZ_CHECK(std::all_of(guard, guard + kGuard, [](std::uint8_t v) { return v == 0xa5; }));
    if (st) FUZZ_CHECK(out.size() == info.tile_bytes());
    else FUZZ_CHECK(!st.error().message.empty());
}

void exercise(std::vector<std::uint8_t> bytes) {
    auto opened = StoreReader::open_memory(std::move(bytes));
    if (!opened) {
        FUZZ_CHECK(!opened.error().message.empty());
        return;
    }
    const StoreReader& reader = **opened;
    const StoreInfo& info = reader.info();
    check_info(info);

    // Keys: corners and middle of every level, out-of-range neighbours, then every tile of the
    // coarsest levels while the cap allows.
    std::vector<TileKey> keys;
    for (std::uint32_t l = 0; l < info.level_count(); ++l) {
        const LevelInfo& L = info.levels[l];
        keys.push_back({l, 0, 0});
        keys.push_back({l, L.tiles_x - 1, L.tiles_y - 1});
        keys.push_back({l, L.tiles_x / 2, L.tiles_y / 2});
        keys.push_back({l, L.tiles_x, 0});
        keys.push_back({l, 0, L.tiles_y});
    }
    keys.push_back({info.level_count(), 0, 0});
    keys.push_back({0xffffffffu, 0xffffffffu, 0xffffffffu});
    if (keys.size() > kMaxKeys) keys.resize(kMaxKeys);
    for (std::uint32_t l = info.level_count(); l-- > 0 && keys.size() < kMaxKeys;)
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y && keys.size() < kMaxKeys; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x && keys.size() < kMaxKeys; ++x) keys.push_back({l, x, y});

    std::uint64_t decode_budget = kMaxDecodeBytes;
    std::vector<Result<Tile>> singles;
    singles.reserve(keys.size());
    for (const TileKey& k : keys) {
        const auto loc = reader.locate(k);
        if (!info.contains(k)) {
            FUZZ_CHECK(!loc.ok() && loc.error().code == Errc::out_of_range);
        } else if (loc) {
            if (loc->kind == TileKind::present) {
                FUZZ_CHECK(loc->length > 0 && loc->offset <= info.file_size && loc->length <= info.file_size - loc->offset);
            } else if (loc->kind == TileKind::uniform) {
                FUZZ_CHECK(reader.palette_value(loc->offset).ok());
            }
        }
        singles.push_back(reader.read_tile(k));
        const Result<Tile>& t = singles.back();
        FUZZ_CHECK(t.ok() == false || loc.ok());
        if (t && loc) {
            FUZZ_CHECK(t->kind == loc->kind);
            if (t->kind == TileKind::present) FUZZ_CHECK(t->bytes.size() == loc->length);
        }
        check_tile(info, k, t, decode_budget);
    }
    (void)reader.palette_value(0);
    FUZZ_CHECK(!reader.palette_value(0xffffffffffffffffull).ok());

    // The batch path (coalesced reads) must agree with the single reads.
    BatchStats stats;
    const auto batch = reader.read_tiles(std::span<const TileKey>(keys), &stats);
    FUZZ_CHECK(batch.size() == keys.size());
    for (std::size_t i = 0; i < keys.size(); ++i) {
        FUZZ_CHECK(batch[i].ok() == singles[i].ok());
        if (batch[i] && singles[i]) {
            FUZZ_CHECK(batch[i]->kind == singles[i]->kind);
            FUZZ_CHECK(batch[i]->bytes == singles[i]->bytes);
        }
    }
    FUZZ_CHECK(stats.bytes <= std::uint64_t(keys.size()) * info.file_size);

    std::uint64_t tiles = 0;
    for (const LevelInfo& L : info.levels) tiles += std::uint64_t(L.tiles_x) * L.tiles_y;
    if (tiles > kMaxVerifyTiles) return;
    VerifyOptions opt;
    opt.max_problems = 3;
    opt.decode = tiles * decoded_bytes(info) <= kMaxDecodeBytes;
    const VerifyReport rep = verify_store(reader, opt);
    FUZZ_CHECK(rep.tiles_checked == tiles);
    FUZZ_CHECK(rep.problems.size() <= opt.max_problems);
    FUZZ_CHECK(rep.problem_count >= rep.problems.size());
    FUZZ_CHECK(rep.ok() == rep.problems.empty());
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    std::vector<std::uint8_t> bytes(data, data + size);
    exercise(bytes);
    fix_checksums(bytes);
    if (!std::equal(bytes.begin(), bytes.end(), data)) exercise(std::move(bytes));
    return 0;
}
