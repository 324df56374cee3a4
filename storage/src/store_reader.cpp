#include "tessera/storage/store_reader.hpp"

#include <xxhash.h>

#include <algorithm>
#include <atomic>
#include <new>
#include <numeric>
#include <stdexcept>

#include "tessera/storage/byte_source.hpp"
#include "format.hpp"
#include "tessera/storage/layers.hpp"

namespace tessera::storage {
namespace {

using namespace format;

std::string key_name(const TileKey& k) {
    return "level " + std::to_string(k.level) + " tile (" + std::to_string(k.x) + "," + std::to_string(k.y) + ")";
}

Error corrupt(std::string msg) { return make_error(Errc::corrupt, std::move(msg)); }

// One index block's entries, read from the file and verified against the block table's checksum.
struct EntryBlock {
    std::uint8_t bytes[kEntryBlockBytes];
};

struct LevelIndex {
    std::uint32_t blocks_x = 0, blocks_y = 0;
    // The block table, read and verified at open: per record its entry block's offset (0: every
    // tile absent) and checksum. Dense: blocks_x * blocks_y records, block (bx, by) at
    // by * blocks_x + bx. Sparse (kHeaderFlagSparseIndex): the non-empty blocks only, their
    // by * blocks_x + bx in `keys`, strictly increasing.
    bool sparse = false;
    std::vector<std::uint64_t> keys, offsets, checksums;
    std::uint64_t data_offset = 0, data_bytes = 0;
    // Entry blocks, read on first use (checked reads, never a mapping: a file changed under the
    // reader gives an error, not a signal). Racing threads may both read a block; one copy wins
    // and the other is freed. corrupt: the block failed its checksum (kept, so it is not re-read).
    std::unique_ptr<std::atomic<const EntryBlock*>[]> blocks;
    std::unique_ptr<std::atomic<bool>[]> corrupt;
    std::size_t count() const { return offsets.size(); }
    // The record of block (bx, by) (in range), or count() when a sparse table has none: empty.
    std::size_t record(std::uint32_t bx, std::uint32_t by) const {
        const std::uint64_t key = std::uint64_t(by) * blocks_x + bx;
        if (!sparse) return std::size_t(key);
        const auto it = std::lower_bound(keys.begin(), keys.end(), key);
        return it != keys.end() && *it == key ? std::size_t(it - keys.begin()) : count();
    }
    std::uint64_t entries_offset(std::size_t r) const { return r < count() ? offsets[r] : 0; }
};

class Reader final : public StoreReader {
public:
    explicit Reader(std::unique_ptr<ByteSource> src) : src_(std::move(src)) {}
    ~Reader() override {
        for (auto& ix : index_)
            for (std::size_t b = 0; ix.blocks && b < ix.count(); ++b) delete ix.blocks[b].load(std::memory_order_relaxed);
    }
    Reader(const Reader&) = delete;
    Reader& operator=(const Reader&) = delete;

    Status parse() {
        const std::uint64_t fsize = src_->size();
        if (fsize < kHeaderBytes) return corrupt("file too small for a store header (" + std::to_string(fsize) + " bytes)");
        std::uint8_t h[kHeaderBytes];
        TESSERA_TRY(src_->read(0, kHeaderBytes, h));
        if (std::memcmp(h, kMagic.data(), kMagic.size()) != 0) return corrupt("not a Tessera store (bad magic)");
        info_.version_major = load<std::uint16_t>(h, header::version_major);
        info_.version_minor = load<std::uint16_t>(h, header::version_minor);
        if (info_.version_major != kVersionMajor)
            return make_error(Errc::unsupported, "store format version " + std::to_string(info_.version_major) + "." +
                                                     std::to_string(info_.version_minor) + " is not supported (this reader: " +
                                                     std::to_string(kVersionMajor) + ".x)");
        if (XXH3_64bits(h, header::header_checksum) != load<std::uint64_t>(h, header::header_checksum))
            return corrupt("header checksum mismatch");
        if (info_.version_minor > kVersionMinorNewest)
            return make_error(Errc::unsupported, "store format version " + std::to_string(info_.version_major) + "." +
                                                     std::to_string(info_.version_minor) + " is newer than this reader (" +
                                                     std::to_string(kVersionMajor) + "." + std::to_string(kVersionMinorNewest) + ")");
        if (load<std::uint32_t>(h, header::header_bytes) != kHeaderBytes) return corrupt("bad header size");
        const std::uint64_t declared_size = load<std::uint64_t>(h, header::file_size);
        if (declared_size != fsize)
            return corrupt("file is " + std::to_string(fsize) + " bytes but the header says " +
                           std::to_string(declared_size) + " (truncated or extended)");
        info_.file_size = fsize;
        info_.width = load<std::uint32_t>(h, header::width);
        info_.height = load<std::uint32_t>(h, header::height);
        info_.tile_payload = load<std::uint32_t>(h, header::tile_payload);
        info_.border = load<std::uint16_t>(h, header::border);
        info_.channels = h[header::channels];
        const std::uint8_t st = h[header::sample_type], cs = h[header::colour_space], codec = h[header::codec];
        const std::uint32_t level_count = h[header::level_count];
        if (info_.width == 0 || info_.height == 0 || info_.tile_payload == 0) return corrupt("zero image or tile size");
        if (std::uint64_t(info_.tile_payload) + 2ull * info_.border > kMaxTileSize) return corrupt("tile size too large");
        if (info_.channels < 1 || info_.channels > 4) return corrupt("bad channel count");
        if (st > 3 || cs > 1 || codec > static_cast<std::uint8_t>(Codec::layers)) return corrupt("bad sample type, colour space or codec");
        if (h[header::block_shift] != kBlockShift) return corrupt("bad index block size");
        info_.sample_type = static_cast<SampleType>(st);
        info_.colour_space = static_cast<ColourSpace>(cs);
        info_.codec = static_cast<Codec>(codec);
        // A layered store (format 1.1) says so twice: codec 7 and a layer count; the layers' codecs
        // are checked with the layer table below.
        const std::uint32_t layer_count = h[header::layer_count];
        if ((info_.codec == Codec::layers) != (layer_count != 0))
            return corrupt("codec " + std::to_string(codec) + " with a layer count of " + std::to_string(layer_count));
        if (info_.codec == Codec::layers) {
            if (layer_count < kMinLayers || layer_count > kMaxLayers)
                return corrupt("layer count " + std::to_string(layer_count) + " (a layered store has " +
                               std::to_string(kMinLayers) + " to " + std::to_string(kMaxLayers) + ")");
            if (info_.version_minor < kVersionMinorLayers)
                return corrupt("a layered store in format " + std::to_string(info_.version_major) + "." +
                               std::to_string(info_.version_minor) + " (layers need 1." +
                               std::to_string(kVersionMinorLayers) + ")");
        } else if (const std::string misfit = codec_misfit(info_.codec, info_.sample_type, info_.channels, info_.tile_size(), info_.border);
                   !misfit.empty()) {
            return corrupt("codec does not fit the samples: " + misfit);
        }
        info_.has_alpha = (h[header::flags] & kHeaderFlagAlpha) != 0;
        const bool sparse_index = (h[header::flags] & kHeaderFlagSparseIndex) != 0;
        if (sparse_index && (info_.version_minor < kVersionMinorSparseIndex || info_.codec == Codec::layers))
            return corrupt("a sparse index in format " + std::to_string(info_.version_major) + "." + std::to_string(info_.version_minor) +
                           (info_.codec == Codec::layers ? " on a layered store" : ""));
        if (info_.has_alpha && info_.channels != 2 && info_.channels != 4) return corrupt("alpha flag on a 1- or 3-channel store");
        info_.store_id = load<std::uint64_t>(h, header::store_id);

        auto levels = level_geometry(info_.width, info_.height, info_.tile_payload);
        if (levels.size() != level_count || level_count > kMaxLevels) return corrupt("level count does not match geometry");

        data_offset_ = load<std::uint64_t>(h, header::data_offset);
        info_.data_offset = data_offset_;
        const std::uint64_t lt_off = load<std::uint64_t>(h, header::level_table_offset);
        const std::uint64_t lt_bytes = load<std::uint32_t>(h, header::level_table_bytes);
        palette_count_ = load<std::uint32_t>(h, header::palette_count);
        const std::uint64_t pal_off = load<std::uint64_t>(h, header::palette_offset);
        if (data_offset_ < kHeaderBytes || data_offset_ > fsize) return corrupt("bad data offset");
        if (lt_bytes != std::uint64_t(level_count) * kLevelRecordBytes) return corrupt("bad level table size");
        auto inside_index = [&](std::uint64_t off, std::uint64_t len) {
            return off >= kHeaderBytes && off <= data_offset_ && len <= data_offset_ - off;
        };
        if (!inside_index(lt_off, lt_bytes)) return corrupt("level table outside the index region");
        if (palette_count_ > kMaxPaletteValues || !inside_index(pal_off, std::uint64_t(palette_count_) * kPaletteValueBytes))
            return corrupt("palette outside the index region");

        // The level table and the palette are copied (small), then verified.
        std::vector<std::uint8_t> level_table(lt_bytes);
        TESSERA_TRY(src_->read(lt_off, lt_bytes, level_table.data()));
        if (XXH3_64bits(level_table.data(), lt_bytes) != load<std::uint64_t>(h, header::level_table_checksum))
            return corrupt("level table checksum mismatch");
        if (layer_count != 0) TESSERA_TRY(parse_layers(h, lt_off + lt_bytes, layer_count, inside_index));
        palette_.resize(std::size_t(palette_count_) * kPaletteValueBytes);
        TESSERA_TRY(src_->read(pal_off, palette_.size(), palette_.data()));
        if (XXH3_64bits(palette_.data(), palette_.size()) != load<std::uint64_t>(h, header::palette_checksum))
            return corrupt("palette checksum mismatch");

        index_.resize(level_count);
        std::uint64_t block_table_bytes = 0;
        bool blocks_in_order = true;  // every level's entry blocks in record order, none overlapping
        std::uint64_t next_block = 0;
        for (std::uint32_t l = 0; l < level_count; ++l) {
            const std::uint8_t* r = level_table.data() + std::size_t(l) * kLevelRecordBytes;
            LevelInfo& li = levels[l];
            if (load<std::uint32_t>(r, level::width) != li.width || load<std::uint32_t>(r, level::height) != li.height ||
                load<std::uint32_t>(r, level::tiles_x) != li.tiles_x || load<std::uint32_t>(r, level::tiles_y) != li.tiles_y)
                return corrupt("level " + std::to_string(l) + " record does not match geometry");
            LevelIndex& ix = index_[l];
            ix.blocks_x = load<std::uint32_t>(r, level::blocks_x);
            ix.blocks_y = load<std::uint32_t>(r, level::blocks_y);
            if (ix.blocks_x != ceil_div(li.tiles_x, kBlockSide) || ix.blocks_y != ceil_div(li.tiles_y, kBlockSide))
                return corrupt("level " + std::to_string(l) + " block counts do not match geometry");
            const std::uint64_t bt_off = load<std::uint64_t>(r, level::block_table_offset);
            const std::uint64_t records = sparse_index ? load<std::uint64_t>(r, level::block_records) : std::uint64_t(ix.blocks_x) * ix.blocks_y;
            if (sparse_index && records > std::uint64_t(ix.blocks_x) * ix.blocks_y)
                return corrupt("level " + std::to_string(l) + " lists more blocks than it has");
            if (!sparse_index && load<std::uint64_t>(r, level::block_records) != 0)
                return corrupt("level " + std::to_string(l) + " has a block count in a dense index");
            const std::size_t rec_bytes = sparse_index ? kSparseBlockRecordBytes : kBlockRecordBytes;
            const std::uint64_t bt_bytes = records * rec_bytes;
            if (!inside_index(bt_off, bt_bytes)) return corrupt("level " + std::to_string(l) + " block table outside the index");
            // Block tables are held from open: more than a reader holds is refused before any of
            // it is allocated (a crafted header, or a remote origin that reports a huge size).
            block_table_bytes += bt_bytes;
            if (block_table_bytes > kMaxBlockTableBytes)
                return make_error(Errc::unsupported, "block tables of " + std::to_string(block_table_bytes >> 20) +
                                                         " MiB or more are larger than this reader holds (" +
                                                         std::to_string(kMaxBlockTableBytes >> 20) + " MiB)");
            std::vector<std::uint8_t> table(bt_bytes);
            TESSERA_TRY(src_->read(bt_off, bt_bytes, table.data()));
            if (XXH3_64bits(table.data(), bt_bytes) != load<std::uint64_t>(r, level::block_table_checksum))
                return corrupt("level " + std::to_string(l) + " block table checksum mismatch");
            ix.sparse = sparse_index;
            li.sparse_block_table = sparse_index;
            li.index_bytes = bt_bytes;  // and the entry blocks, below
            ix.offsets.resize(records);
            ix.checksums.resize(records);
            if (sparse_index) ix.keys.resize(records);
            for (std::size_t b = 0; b < records; ++b) {
                const std::uint8_t* rec = table.data() + b * rec_bytes;
                if (sparse_index) {
                    const std::uint32_t bx = load<std::uint32_t>(rec, 0), by = load<std::uint32_t>(rec, 4);
                    if (bx >= ix.blocks_x || by >= ix.blocks_y)
                        return corrupt("level " + std::to_string(l) + " block record " + std::to_string(b) + " is outside the level");
                    ix.keys[b] = std::uint64_t(by) * ix.blocks_x + bx;
                    if (b > 0 && ix.keys[b] <= ix.keys[b - 1])
                        return corrupt("level " + std::to_string(l) + " block records are not in order");
                    rec += 8;
                }
                ix.offsets[b] = load<std::uint64_t>(rec, 0);
                ix.checksums[b] = load<std::uint64_t>(rec, 8);
                if (sparse_index && ix.offsets[b] == 0)
                    return corrupt("level " + std::to_string(l) + " lists an empty block");
            }
            ix.data_offset = load<std::uint64_t>(r, level::data_offset);
            ix.data_bytes = load<std::uint64_t>(r, level::data_bytes);
            if (ix.data_offset < data_offset_ || ix.data_offset > fsize || ix.data_bytes > fsize - ix.data_offset)
                return corrupt("level " + std::to_string(l) + " data range outside the file");
            li.present = load<std::uint64_t>(r, level::present);
            li.uniform = load<std::uint64_t>(r, level::uniform);
            li.absent = load<std::uint64_t>(r, level::absent);
            li.deduplicated = load<std::uint64_t>(r, level::deduplicated);
            li.payload_bytes = ix.data_bytes;
            li.payload_offset = ix.data_offset;
            const std::uint64_t ntiles = std::uint64_t(li.tiles_x) * li.tiles_y;
            if (li.present > ntiles || li.uniform > ntiles || li.absent > ntiles || li.deduplicated > li.present ||
                li.present + li.uniform + li.absent != ntiles)
                return corrupt("level " + std::to_string(l) + " tile counts do not add up");
            if (info_.layered() && li.uniform != 0) return corrupt("level " + std::to_string(l) + " of a layered store has uniform tiles");
            const std::size_t nblocks = ix.count();
            ix.blocks = std::make_unique<std::atomic<const EntryBlock*>[]>(nblocks);
            ix.corrupt = std::make_unique<std::atomic<bool>[]>(nblocks);
            for (std::size_t b = 0; b < nblocks; ++b) {
                ix.blocks[b].store(nullptr, std::memory_order_relaxed);
                ix.corrupt[b].store(false, std::memory_order_relaxed);
                const std::uint64_t eo = ix.offsets[b];
                if (eo != 0 && !inside_index(eo, kEntryBlockBytes))
                    return corrupt("level " + std::to_string(l) + " index block " + std::to_string(b) + " outside the index");
                if (eo != 0) {
                    li.index_bytes += kEntryBlockBytes;
                    if (eo < next_block) blocks_in_order = false;
                    next_block = eo + kEntryBlockBytes;
                }
            }
        }
        // Each entry block is held once read, per record: records sharing or overlapping blocks
        // would make a small file cost memory by the index's record count, not its size. The
        // writer lays them out in record order, each after the last, which needs no memory to
        // check; any other order is checked sorted.
        if (!blocks_in_order) {
            std::vector<std::uint64_t> at;
            for (const LevelIndex& lx : index_)
                for (const std::uint64_t eo : lx.offsets)
                    if (eo != 0) at.push_back(eo);
            std::sort(at.begin(), at.end());
            for (std::size_t i = 1; i < at.size(); ++i)
                if (at[i] - at[i - 1] < kEntryBlockBytes) return corrupt("index entry blocks overlap");
        }
        info_.levels = std::move(levels);
        max_payload_ = info_.tile_bytes() * 2 + 65536;  // no codec expands a tile beyond this
        if (info_.layered()) {  // a bundle: its table, then each layer's part, bounded likewise
            max_payload_ = 0;
            for (std::size_t i = 0; i < info_.layers.size(); ++i)
                max_payload_ += 8 + layer_store_info(info_, i).tile_bytes() * 2 + 65536;
        }
        return {};
    }

    // The layer table of a layered store (directly after the level table), verified and read into
    // info_.layers: everything in it must be something the writer could have written.
    template <class InsideIndex>
    Status parse_layers(const std::uint8_t* h, std::uint64_t off, std::uint32_t count, const InsideIndex& inside_index) {
        const std::uint64_t bytes = std::uint64_t(count) * kLayerRecordBytes;
        if (!inside_index(off, bytes)) return corrupt("layer table outside the index region");
        std::vector<std::uint8_t> table(bytes);
        TESSERA_TRY(src_->read(off, bytes, table.data()));
        if (XXH3_64bits(table.data(), bytes) != load<std::uint64_t>(h, header::layer_table_checksum))
            return corrupt("layer table checksum mismatch");
        std::uint64_t layer_bytes = 0;
        for (std::uint32_t i = 0; i < count; ++i) {
            const std::uint8_t* r = table.data() + std::size_t(i) * kLayerRecordBytes;
            const auto* name = reinterpret_cast<const char*>(r + layer::name);
            const std::size_t len = strnlen(name, layer::name_bytes);
            if (len == layer::name_bytes || std::any_of(r + layer::name + len, r + layer::name + layer::name_bytes,
                                                        [](std::uint8_t c) { return c != 0; }))
                return corrupt("layer " + std::to_string(i) + " name is not 1 to 31 bytes, NUL padded");
            LayerInfo l;
            l.name.assign(name, len);
            l.channels = r[layer::channels];
            if (r[layer::sample_type] > 3 || r[layer::colour_space] > 1 || r[layer::codec] > static_cast<std::uint8_t>(Codec::layers))
                return corrupt("layer " + std::to_string(i) + " has a bad sample type, colour space or codec");
            l.sample_type = static_cast<SampleType>(r[layer::sample_type]);
            l.colour_space = static_cast<ColourSpace>(r[layer::colour_space]);
            l.codec = static_cast<Codec>(r[layer::codec]);
            l.has_alpha = (r[layer::flags] & kHeaderFlagAlpha) != 0;
            l.payload_bytes = load<std::uint64_t>(r, layer::payload_bytes);
            if (l.payload_bytes > info_.file_size - data_offset_ || layer_bytes > info_.file_size - data_offset_ - l.payload_bytes)
                return corrupt("layer payload bytes exceed the data section");
            layer_bytes += l.payload_bytes;
            info_.layers.push_back(std::move(l));
        }
        if (const std::string why = layers_misfit(info_.layers, info_.tile_size(), info_.border); !why.empty())
            return corrupt("layer table: " + why);
        const LayerInfo& l0 = info_.layers.front();
        if (info_.channels != l0.channels || info_.sample_type != l0.sample_type || info_.colour_space != l0.colour_space ||
            info_.has_alpha != l0.has_alpha)
            return corrupt("header samples are not the first layer's");
        if (palette_count_ != 0) return corrupt("a layered store has a palette");
        return {};
    }

    const StoreInfo& info() const override { return info_; }

    bool index_block_empty(std::uint32_t level, std::uint32_t bx, std::uint32_t by) const override {
        if (level >= index_.size() || bx >= index_[level].blocks_x || by >= index_[level].blocks_y) return true;
        const LevelIndex& ix = index_[level];
        return ix.entries_offset(ix.record(bx, by)) == 0;
    }

    std::vector<std::pair<std::uint32_t, std::uint32_t>> data_blocks(std::uint32_t level) const override {
        std::vector<std::pair<std::uint32_t, std::uint32_t>> out;
        if (level >= index_.size()) return out;
        const LevelIndex& ix = index_[level];
        for (std::size_t r = 0; r < ix.count(); ++r) {
            if (ix.offsets[r] == 0) continue;
            const std::uint64_t key = ix.sparse ? ix.keys[r] : r;
            out.emplace_back(std::uint32_t(key % ix.blocks_x), std::uint32_t(key / ix.blocks_x));
        }
        return out;
    }

    Result<TileLocation> locate(const TileKey& key) const override {
        if (!info_.contains(key))
            return make_error(Errc::out_of_range, key_name(key) + " is outside the store");
        const LevelIndex& ix = index_[key.level];
        const std::size_t b = ix.record(key.x >> kBlockShift, key.y >> kBlockShift);
        const std::uint64_t eo = ix.entries_offset(b);
        if (eo == 0) return TileLocation{};  // a block with no data at all
        auto block = entry_block(ix, b, eo);
        if (!block) return make_error(block.error().code, "index block of " + key_name(key) + " " + block.error().message);
        const std::size_t e = (std::size_t(key.y & (kBlockSide - 1)) << kBlockShift) + (key.x & (kBlockSide - 1));
        const std::uint8_t* p = (*block)->bytes + e * kEntryBytes;
        TileLocation loc;
        const std::uint8_t kind = p[entry::kind];
        loc.offset = load<std::uint64_t>(p, entry::offset);
        loc.length = load<std::uint32_t>(p, entry::length);
        loc.checksum = load<std::uint64_t>(p, entry::checksum);
        loc.deduplicated = (p[entry::flags] & kEntryFlagDeduplicated) != 0;
        // docs/store-format.md: a reader refuses an entry with fields it should not have.
        if (load<std::uint16_t>(p, entry::reserved) != 0 || (p[entry::flags] & ~kEntryFlagDeduplicated) != 0 ||
            (kind != 1 && p[entry::flags] != 0))
            return corrupt("index entry of " + key_name(key) + " has reserved bits or flags set");
        switch (kind) {
            case 0:
                loc.kind = TileKind::absent;
                if (loc.offset != 0 || loc.length != 0 || loc.checksum != 0)
                    return corrupt("index entry of absent " + key_name(key) + " is not empty");
                break;
            case 1:
                loc.kind = TileKind::present;
                if (loc.length == 0 || loc.length > max_payload_ || loc.offset < data_offset_ ||
                    loc.offset > info_.file_size || loc.length > info_.file_size - loc.offset)
                    return corrupt("index entry of " + key_name(key) + " points outside the data");
                break;
            case 2:
                loc.kind = TileKind::uniform;
                if (info_.layered()) return corrupt("index entry of " + key_name(key) + " is uniform in a layered store");
                if (loc.offset >= palette_count_ || loc.length != 0)
                    return corrupt("index entry of uniform " + key_name(key) + " has a bad palette index");
                break;
            default:
                return corrupt("index entry of " + key_name(key) + " has unknown kind " + std::to_string(kind));
        }
        return loc;
    }

    Result<std::vector<std::uint8_t>> palette_value(std::uint64_t index) const override {
        if (index >= palette_count_) return make_error(Errc::out_of_range, "palette index out of range");
        const std::uint8_t* v = palette_.data() + index * kPaletteValueBytes;
        return std::vector<std::uint8_t>(v, v + info_.texel_bytes());
    }

    Result<Tile> read_tile(const TileKey& key) const override {
        auto r = read_tiles(std::span<const TileKey>(&key, 1), nullptr);
        return std::move(r.front());
    }

    std::vector<Result<Tile>> read_tiles(std::span<const TileKey> keys, BatchStats* stats) const override {
        std::vector<Result<Tile>> out;
        out.reserve(keys.size());
        std::vector<std::size_t> pending;  // indices of present tiles whose payload must be read
        std::vector<TileLocation> locs(keys.size());
        for (std::size_t i = 0; i < keys.size(); ++i) {
            auto loc = locate(keys[i]);
            if (!loc) {
                out.emplace_back(loc.error());
                continue;
            }
            locs[i] = *loc;
            Tile t;
            t.key = keys[i];
            t.kind = loc->kind;
            t.deduplicated = loc->deduplicated;
            t.checksum = loc->checksum;
            if (loc->kind == TileKind::uniform) {
                auto v = palette_value(loc->offset);
                if (!v) {
                    out.emplace_back(v.error());
                    continue;
                }
                t.bytes = std::move(*v);
                if (XXH3_64bits(t.bytes.data(), t.bytes.size()) != t.checksum) {
                    out.emplace_back(corrupt("uniform value of " + key_name(keys[i]) + " fails its checksum"));
                    continue;
                }
            } else if (loc->kind == TileKind::present) {
                pending.push_back(i);
            }
            out.emplace_back(std::move(t));
        }
        // Coalesce: sort the wanted payloads by offset and read runs that are (nearly) contiguous.
        std::sort(pending.begin(), pending.end(), [&](std::size_t a, std::size_t b) { return locs[a].offset < locs[b].offset; });
        std::vector<std::uint8_t> buf;
        for (std::size_t i = 0; i < pending.size();) {
            const std::uint64_t start = locs[pending[i]].offset;
            std::uint64_t end = start + locs[pending[i]].length;
            std::size_t j = i + 1;
            while (j < pending.size()) {
                const TileLocation& n = locs[pending[j]];
                const std::uint64_t n_end = std::max(end, n.offset + n.length);
                if (n.offset > end + kCoalesceGapBytes || n_end - start > kMaxCoalescedBytes) break;
                end = n_end;
                ++j;
            }
            buf.resize(end - start);
            Status st = src_->read(start, end - start, buf.data());
            if (stats) {
                stats->reads += 1;
                stats->bytes += end - start;
            }
            for (std::size_t k = i; k < j; ++k) {
                const std::size_t idx = pending[k];
                const TileLocation& l = locs[idx];
                if (!st.ok()) {
                    out[idx] = st.error();
                    continue;
                }
                const std::uint8_t* p = buf.data() + (l.offset - start);
                if (XXH3_64bits(p, l.length) != l.checksum) {
                    out[idx] = corrupt("payload of " + key_name(keys[idx]) + " fails its checksum");
                    continue;
                }
                out[idx].value().bytes.assign(p, p + l.length);
            }
            i = j;
        }
        return out;
    }

    bool file_changed() const override { return src_->changed(); }
    void cancel_reads() const override { src_->cancel(); }

    Result<std::uint64_t> index_hash() const override {
        // In pieces: a sparse store's index may be a gigabyte.
        constexpr std::uint64_t kPiece = 1u << 20;
        std::unique_ptr<XXH3_state_t, decltype(&XXH3_freeState)> state(XXH3_createState(), &XXH3_freeState);
        if (!state || XXH3_64bits_reset(state.get()) == XXH_ERROR) return make_error(Errc::resource_exhausted, "no memory to hash the index");
        std::vector<std::uint8_t> piece(static_cast<std::size_t>(std::min(kPiece, data_offset_ - kHeaderBytes)));
        for (std::uint64_t at = kHeaderBytes; at < data_offset_; at += kPiece) {
            const std::uint64_t n = std::min(kPiece, data_offset_ - at);
            if (Status st = src_->read(at, n, piece.data()); !st)
                return make_error(st.error().code, "the index cannot be read: " + st.error().message);
            XXH3_64bits_update(state.get(), piece.data(), static_cast<std::size_t>(n));
        }
        return static_cast<std::uint64_t>(XXH3_64bits_digest(state.get()));
    }

private:
    // Entry block b of a level (at file offset eo), read and verified on first use.
    Result<const EntryBlock*> entry_block(const LevelIndex& ix, std::size_t b, std::uint64_t eo) const {
        if (const EntryBlock* got = ix.blocks[b].load(std::memory_order_acquire)) return got;
        if (ix.corrupt[b].load(std::memory_order_relaxed)) return corrupt("fails its checksum");
        std::unique_ptr<EntryBlock> fresh(new EntryBlock);  // not value-initialized: read() fills it
        if (Status st = src_->read(eo, kEntryBlockBytes, fresh->bytes); !st)
            return make_error(st.error().code, "cannot be read: " + st.error().message);
        if (XXH3_64bits(fresh->bytes, kEntryBlockBytes) != ix.checksums[b]) {
            ix.corrupt[b].store(true, std::memory_order_relaxed);
            return corrupt("fails its checksum");
        }
        const EntryBlock* expected = nullptr;
        if (ix.blocks[b].compare_exchange_strong(expected, fresh.get(), std::memory_order_acq_rel))
            return fresh.release();
        return expected;  // another thread published the same block first
    }

    std::unique_ptr<ByteSource> src_;
    StoreInfo info_;
    std::vector<std::uint8_t> palette_;
    std::uint32_t palette_count_ = 0;
    std::uint64_t data_offset_ = 0;
    std::uint64_t max_payload_ = 0;
    std::vector<LevelIndex> index_;
};

Result<std::shared_ptr<StoreReader>> finish_open(std::unique_ptr<ByteSource> src) {
    auto r = std::make_shared<Reader>(std::move(src));
    // Opening runs on a server's reload thread too: an index that does not fit in memory is an
    // error for this store, never an exception that ends the process.
    try {
        Status st = r->parse();
        if (!st) return st.error();
    } catch (const std::bad_alloc&) {
        return make_error(Errc::resource_exhausted, "not enough memory for the store's index");
    } catch (const std::length_error&) {
        return make_error(Errc::resource_exhausted, "not enough memory for the store's index");
    }
    return std::shared_ptr<StoreReader>(std::move(r));
}

}  // namespace

Result<std::shared_ptr<StoreReader>> StoreReader::open(const std::string& path) {
    auto src = open_file_source(path);
    if (!src) return src.error();
    auto r = finish_open(std::move(*src));
    if (!r) return make_error(r.error().code, path + ": " + r.error().message);
    return r;
}

Result<std::shared_ptr<StoreReader>> StoreReader::open_memory(std::vector<std::uint8_t> bytes) {
    return finish_open(memory_source(std::move(bytes)));
}

Result<std::shared_ptr<StoreReader>> StoreReader::open_source(std::unique_ptr<ByteSource> source, const std::string& name) {
    if (!source) return make_error(Errc::invalid_argument, name + ": no byte source");
    auto r = finish_open(std::move(source));
    if (!r) return make_error(r.error().code, name + ": " + r.error().message);
    return r;
}

}  // namespace tessera::storage
