#include "tessera/storage/store_writer.hpp"

#include <xxhash.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <map>
#include <mutex>
#include <unordered_map>

#include "format.hpp"
#include "temp_file.hpp"
#include "tessera/storage/layers.hpp"

namespace tessera::storage {
namespace {

using namespace format;

struct Record {
    std::uint32_t x = 0, y = 0;
    TileKind kind = TileKind::absent;
    std::uint64_t spool_offset = 0;  // present
    std::uint32_t length = 0;        // present
    std::uint32_t parts = 0;         // present, layered store: index of its part sizes in part_bytes_
    std::uint64_t checksum = 0;      // XXH3-64 of payload or value
    XXH128_hash_t hash{};            // present: identity for deduplication
    std::array<std::uint8_t, kPaletteValueBytes> value{};  // uniform
};

struct Hash128Hasher {
    std::size_t operator()(const XXH128_hash_t& h) const { return static_cast<std::size_t>(h.low64 ^ h.high64); }
};
struct Hash128Eq {
    bool operator()(const XXH128_hash_t& a, const XXH128_hash_t& b) const { return XXH128_isEqual(a, b) != 0; }
};

// Appends bytes to a file through a large buffer (the final store is written sequentially).
class SequentialWriter {
public:
    explicit SequentialWriter(const TempFile& f) : f_(f) { buf_.reserve(kBuf); }
    Status write(std::span<const std::uint8_t> b) {
        if (buf_.size() + b.size() > kBuf) TESSERA_TRY(flush());
        if (b.size() >= kBuf) {
            TESSERA_TRY(f_.pwrite_all(pos_, b));
            pos_ += b.size();
            return {};
        }
        buf_.insert(buf_.end(), b.begin(), b.end());
        return {};
    }
    Status flush() {
        if (buf_.empty()) return {};
        TESSERA_TRY(f_.pwrite_all(pos_, buf_));
        pos_ += buf_.size();
        buf_.clear();
        return {};
    }
    std::uint64_t position() const { return pos_ + buf_.size(); }

private:
    static constexpr std::size_t kBuf = 8u << 20;
    const TempFile& f_;
    std::vector<std::uint8_t> buf_;
    std::uint64_t pos_ = 0;
};

class Writer final : public StoreWriter {
public:
    Writer(std::string path, const StoreSpec& spec, TempFile out, TempFile spool)
        : path_(std::move(path)), spec_(spec), info_(store_info(spec)), out_(std::move(out)), spool_(std::move(spool)) {
        levels_ = info_.levels;
        records_.resize(levels_.size());
        texel_bytes_ = spec.channels * sample_bytes(spec.sample_type);
    }

    Status check_key(const TileKey& key) const {
        if (key.level >= levels_.size() || key.x >= levels_[key.level].tiles_x || key.y >= levels_[key.level].tiles_y)
            return make_error(Errc::out_of_range, "tile key outside the store geometry");
        if (finished_) return make_error(Errc::invalid_argument, "store already finished");
        return {};
    }

    Status add_present(const TileKey& key, std::span<const std::uint8_t> payload) override {
        TESSERA_TRY(check_key(key));
        if (payload.empty() || payload.size() > 0xffffffffu)
            return make_error(Errc::invalid_argument, "tile payload must be 1 byte to 4 GiB");
        // A layered store's payload must be a bundle of its layers: checked here, where the caller
        // can still be told, rather than by every reader.
        std::vector<std::uint32_t> sizes;
        if (info_.layered()) {
            auto parts = split_layers(info_, payload);
            if (!parts) return make_error(Errc::invalid_argument, "tile payload is not a bundle of the store's layers: " + parts.error().message);
            bool any = false;
            for (const LayerPart& p : *parts) {
                sizes.push_back(static_cast<std::uint32_t>(p.bytes.size()));
                any = any || p.kind != TileKind::absent;
            }
            if (!any)
                return make_error(Errc::invalid_argument,
                                  "a bundle whose layers are all absent is an absent tile: leave it out");
        }
        Record r;
        r.x = key.x;
        r.y = key.y;
        r.kind = TileKind::present;
        r.length = static_cast<std::uint32_t>(payload.size());
        r.checksum = XXH3_64bits(payload.data(), payload.size());
        r.hash = XXH3_128bits(payload.data(), payload.size());
        r.spool_offset = spool_end_.fetch_add(payload.size());
        TESSERA_TRY(spool_.pwrite_all(r.spool_offset, payload));
        std::lock_guard lock(mu_);
        if (info_.layered()) {
            r.parts = static_cast<std::uint32_t>(part_bytes_.size() / info_.layers.size());
            part_bytes_.insert(part_bytes_.end(), sizes.begin(), sizes.end());
        }
        records_[key.level].push_back(r);
        return {};
    }

    Status add_uniform(const TileKey& key, std::span<const std::uint8_t> value) override {
        TESSERA_TRY(check_key(key));
        if (info_.layered())
            return make_error(Errc::invalid_argument,
                              "a layered store has no uniform tiles: add a bundle whose uniform layers are uniform parts");
        if (value.size() != texel_bytes_) return make_error(Errc::invalid_argument, "uniform value must be one texel");
        Record r;
        r.x = key.x;
        r.y = key.y;
        r.kind = TileKind::uniform;
        std::copy(value.begin(), value.end(), r.value.begin());
        r.checksum = XXH3_64bits(value.data(), value.size());
        std::lock_guard lock(mu_);
        records_[key.level].push_back(r);
        return {};
    }

    Status finish(const Progress& progress) override;

private:
    std::string path_;
    StoreSpec spec_;
    StoreInfo info_;
    TempFile out_;
    TempFile spool_;
    std::vector<LevelInfo> levels_;
    std::size_t texel_bytes_ = 0;
    std::mutex mu_;
    std::vector<std::vector<Record>> records_;  // per level
    std::vector<std::uint32_t> part_bytes_;     // layered store: each present record's part sizes, layer by layer
    std::atomic<std::uint64_t> spool_end_{0};
    std::atomic<bool> finished_{false};
};

Status Writer::finish(const Progress& progress) {
    std::lock_guard lock(mu_);
    if (finished_.exchange(true)) return make_error(Errc::invalid_argument, "store already finished");
    const std::uint32_t nlevels = static_cast<std::uint32_t>(levels_.size());

    // 1. Order: coarse levels first, Morton order within a level. Reject duplicate keys.
    for (std::uint32_t l = 0; l < nlevels; ++l) {
        auto& recs = records_[l];
        std::sort(recs.begin(), recs.end(), [](const Record& a, const Record& b) { return morton(a.x, a.y) < morton(b.x, b.y); });
        for (std::size_t i = 1; i < recs.size(); ++i)
            if (recs[i].x == recs[i - 1].x && recs[i].y == recs[i - 1].y)
                return make_error(Errc::invalid_argument, "tile (" + std::to_string(recs[i].x) + "," + std::to_string(recs[i].y) +
                                                              ") of level " + std::to_string(l) + " was added twice");
    }

    // 2. Assign data offsets relative to the data section (deduplicating payloads) and palette
    //    indices, in final file order.
    struct Placement {
        std::uint64_t data_pos = 0;  // relative to data start (present) or palette index (uniform)
        bool dedup = false;
    };
    std::vector<std::vector<Placement>> place(nlevels);
    std::unordered_map<XXH128_hash_t, std::vector<std::pair<std::uint32_t, std::uint32_t>>, Hash128Hasher, Hash128Eq> seen;
    std::map<std::array<std::uint8_t, kPaletteValueBytes>, std::uint32_t> palette_index;
    std::vector<std::array<std::uint8_t, kPaletteValueBytes>> palette;
    std::vector<std::pair<std::uint32_t, std::uint32_t>> copy_order;  // (level, record) of stored payloads
    std::vector<std::uint64_t> level_data_start(nlevels, 0), level_data_bytes(nlevels, 0);
    std::uint64_t data_cursor = 0;
    std::vector<std::uint8_t> a, b;
    for (std::uint32_t li = nlevels; li-- > 0;) {
        auto& recs = records_[li];
        place[li].resize(recs.size());
        level_data_start[li] = data_cursor;
        for (std::uint32_t i = 0; i < recs.size(); ++i) {
            const Record& r = recs[i];
            if (r.kind == TileKind::uniform) {
                auto [it, inserted] = palette_index.try_emplace(r.value, static_cast<std::uint32_t>(palette.size()));
                if (inserted) palette.push_back(r.value);
                place[li][i].data_pos = it->second;
                continue;
            }
            // Identical payloads are stored once; the hash finds candidates, the bytes decide.
            auto& candidates = seen[r.hash];
            bool found = false;
            for (auto [cl, ci] : candidates) {
                const Record& o = records_[cl][ci];
                if (o.length != r.length) continue;
                a.resize(r.length);
                b.resize(r.length);
                TESSERA_TRY(spool_.pread_all(r.spool_offset, a));
                TESSERA_TRY(spool_.pread_all(o.spool_offset, b));
                if (a == b) {
                    place[li][i] = Placement{place[cl][ci].data_pos, true};
                    found = true;
                    break;
                }
            }
            if (found) continue;
            candidates.emplace_back(li, i);
            place[li][i].data_pos = data_cursor;
            data_cursor += r.length;
            copy_order.emplace_back(li, i);
        }
        level_data_bytes[li] = data_cursor - level_data_start[li];
    }
    // Refused here, before anything is written: a store past the limit would be unreadable, and
    // it would replace whatever is at the output.
    if (palette.size() > kMaxPaletteValues)
        return make_error(Errc::invalid_argument, std::to_string(palette.size()) + " distinct uniform tile values; a store holds at most " +
                                                      std::to_string(kMaxPaletteValues) + " (add the rest as present tiles)");

    // 3. Index region layout: header | level table | palette | per level: block table, entry blocks.
    std::uint64_t pos = kHeaderBytes;
    const std::uint64_t level_table_offset = pos;
    pos += std::uint64_t(nlevels) * kLevelRecordBytes;
    const std::uint64_t layer_table_offset = pos;  // layered stores only: directly after the level table
    const std::size_t nlayers = spec_.layers.size();
    pos += nlayers * kLayerRecordBytes;
    const std::uint64_t palette_offset = pos;
    pos += palette.size() * kPaletteValueBytes;
    const std::uint64_t index_offset = pos;
    // Per level, the non-empty blocks (key by * bx + bx, sorted) and their entry blocks' offsets:
    // memory follows the present tiles, not the level's area.
    struct LevelBlocks {
        std::uint32_t bx = 0, by = 0;
        std::uint64_t table_offset = 0;
        std::vector<std::uint64_t> keys;     // non-empty blocks, increasing
        std::vector<std::uint64_t> offsets;  // their entry blocks
        std::uint64_t entries_offset(std::uint64_t key) const {
            return offsets[std::size_t(std::lower_bound(keys.begin(), keys.end(), key) - keys.begin())];
        }
    };
    const bool sparse_index = spec_.sparse_index && spec_.layers.empty();
    std::vector<LevelBlocks> lb(nlevels);
    for (std::uint32_t l = 0; l < nlevels; ++l) {
        LevelBlocks& L = lb[l];
        L.bx = ceil_div(levels_[l].tiles_x, kBlockSide);
        L.by = ceil_div(levels_[l].tiles_y, kBlockSide);
        for (const Record& r : records_[l]) L.keys.push_back(std::uint64_t(r.y >> kBlockShift) * L.bx + (r.x >> kBlockShift));
        std::sort(L.keys.begin(), L.keys.end());
        L.keys.erase(std::unique(L.keys.begin(), L.keys.end()), L.keys.end());
        L.table_offset = pos;
        pos += sparse_index ? L.keys.size() * kSparseBlockRecordBytes : std::uint64_t(L.bx) * L.by * kBlockRecordBytes;
        L.offsets.resize(L.keys.size());
        for (auto& off : L.offsets) {  // entry blocks in block order, after the level's table
            off = pos;
            pos += kEntryBlockBytes;
        }
    }
    const std::uint64_t data_offset = pos;
    const std::uint64_t file_size = data_offset + data_cursor;

    // Sparse block tables follow the tiles; readers hold them whole, so they are bounded like
    // dense ones (validate). The index region is held whole while it is written.
    if (sparse_index) {
        std::uint64_t table_bytes = 0;
        for (const LevelBlocks& L : lb) table_bytes += L.keys.size() * kSparseBlockRecordBytes;
        if (table_bytes > kMaxBlockTableBytes)
            return make_error(Errc::invalid_argument, "the store's block tables would take " + std::to_string(table_bytes >> 20) +
                                                          " MiB, more than readers hold (" +
                                                          std::to_string(kMaxBlockTableBytes >> 20) + " MiB)");
    }
    std::vector<std::uint8_t> idx;
    try {
        idx.assign(data_offset, 0);
    } catch (const std::bad_alloc&) {
        return make_error(Errc::resource_exhausted, "no memory for the store's index (" + std::to_string(data_offset >> 20) + " MiB)");
    }
    std::uint8_t* base = idx.data();
    for (std::size_t p = 0; p < palette.size(); ++p)
        std::copy(palette[p].begin(), palette[p].end(), base + palette_offset + p * kPaletteValueBytes);
    for (std::uint32_t l = 0; l < nlevels; ++l) {
        LevelBlocks& L = lb[l];
        LevelInfo& info = levels_[l];
        info.present = info.uniform = info.deduplicated = 0;
        for (std::size_t i = 0; i < records_[l].size(); ++i) {
            const Record& r = records_[l][i];
            const std::uint64_t eo = L.entries_offset(std::uint64_t(r.y >> kBlockShift) * L.bx + (r.x >> kBlockShift));
            std::uint8_t* e = base + eo + (((std::size_t(r.y) & (kBlockSide - 1)) << kBlockShift) + (r.x & (kBlockSide - 1))) * kEntryBytes;
            e[entry::kind] = static_cast<std::uint8_t>(r.kind);
            store<std::uint64_t>(e, entry::checksum, r.checksum);
            if (r.kind == TileKind::present) {
                store<std::uint64_t>(e, entry::offset, data_offset + place[l][i].data_pos);
                store<std::uint32_t>(e, entry::length, r.length);
                if (place[l][i].dedup) e[entry::flags] = kEntryFlagDeduplicated;
                ++info.present;
                info.deduplicated += place[l][i].dedup ? 1 : 0;
            } else {
                store<std::uint64_t>(e, entry::offset, place[l][i].data_pos);
                ++info.uniform;
            }
        }
        info.absent = std::uint64_t(info.tiles_x) * info.tiles_y - info.present - info.uniform;
        std::uint8_t* rec = base + L.table_offset;
        const auto put = [&](std::uint64_t eo) {
            store<std::uint64_t>(rec, 0, eo);
            store<std::uint64_t>(rec, 8, eo ? XXH3_64bits(base + eo, kEntryBlockBytes) : 0);
            rec += kBlockRecordBytes;
        };
        if (sparse_index) {
            for (std::size_t k = 0; k < L.keys.size(); ++k) {
                store<std::uint32_t>(rec, 0, std::uint32_t(L.keys[k] % L.bx));
                store<std::uint32_t>(rec, 4, std::uint32_t(L.keys[k] / L.bx));
                rec += 8;
                put(L.offsets[k]);
            }
        } else {
            std::size_t k = 0;  // the next non-empty block
            for (std::uint64_t key = 0; key < std::uint64_t(L.bx) * L.by; ++key) {
                const bool full = k < L.keys.size() && L.keys[k] == key;
                put(full ? L.offsets[k++] : 0);
            }
        }
        const std::uint64_t table_bytes = std::uint64_t(rec - (base + L.table_offset));
        std::uint8_t* r = base + level_table_offset + std::size_t(l) * kLevelRecordBytes;
        store<std::uint32_t>(r, level::width, info.width);
        store<std::uint32_t>(r, level::height, info.height);
        store<std::uint32_t>(r, level::tiles_x, info.tiles_x);
        store<std::uint32_t>(r, level::tiles_y, info.tiles_y);
        store<std::uint32_t>(r, level::blocks_x, L.bx);
        store<std::uint32_t>(r, level::blocks_y, L.by);
        store<std::uint64_t>(r, level::block_table_offset, L.table_offset);
        store<std::uint64_t>(r, level::block_table_checksum, XXH3_64bits(base + L.table_offset, table_bytes));
        if (sparse_index) store<std::uint64_t>(r, level::block_records, L.keys.size());
        store<std::uint64_t>(r, level::data_offset, data_offset + level_data_start[l]);
        store<std::uint64_t>(r, level::data_bytes, level_data_bytes[l]);
        store<std::uint64_t>(r, level::present, info.present);
        store<std::uint64_t>(r, level::uniform, info.uniform);
        store<std::uint64_t>(r, level::absent, info.absent);
        store<std::uint64_t>(r, level::deduplicated, info.deduplicated);
    }

    // Layer table: each layer's bytes summed over the payloads stored (a deduplicated bundle once).
    if (nlayers > 0) {
        std::vector<std::uint64_t> layer_bytes(nlayers, 0);
        for (auto [l, i] : copy_order) {
            const Record& r = records_[l][i];
            for (std::size_t k = 0; k < nlayers; ++k) layer_bytes[k] += part_bytes_[std::size_t(r.parts) * nlayers + k];
        }
        for (std::size_t k = 0; k < nlayers; ++k) {
            const LayerInfo& li = spec_.layers[k];
            std::uint8_t* rec = base + layer_table_offset + k * kLayerRecordBytes;
            std::copy(li.name.begin(), li.name.end(), rec + layer::name);
            rec[layer::channels] = static_cast<std::uint8_t>(li.channels);
            rec[layer::sample_type] = static_cast<std::uint8_t>(li.sample_type);
            rec[layer::colour_space] = static_cast<std::uint8_t>(li.colour_space);
            rec[layer::codec] = static_cast<std::uint8_t>(li.codec);
            rec[layer::flags] = li.has_alpha ? kHeaderFlagAlpha : 0;
            store<std::uint64_t>(rec, layer::payload_bytes, layer_bytes[k]);
        }
        base[header::layer_count] = static_cast<std::uint8_t>(nlayers);
        store<std::uint64_t>(base, header::layer_table_checksum, XXH3_64bits(base + layer_table_offset, nlayers * kLayerRecordBytes));
    }

    std::copy(kMagic.begin(), kMagic.end(), base + header::magic);
    store<std::uint16_t>(base, header::version_major, kVersionMajor);
    store<std::uint16_t>(base, header::version_minor,
                         nlayers > 0 ? kVersionMinorLayers : sparse_index ? kVersionMinorSparseIndex : kVersionMinor);
    store<std::uint32_t>(base, header::header_bytes, kHeaderBytes);
    store<std::uint32_t>(base, header::width, spec_.width);
    store<std::uint32_t>(base, header::height, spec_.height);
    store<std::uint32_t>(base, header::tile_payload, spec_.tile_payload);
    store<std::uint16_t>(base, header::border, static_cast<std::uint16_t>(spec_.border));
    base[header::level_count] = static_cast<std::uint8_t>(nlevels);
    base[header::channels] = static_cast<std::uint8_t>(spec_.channels);
    base[header::sample_type] = static_cast<std::uint8_t>(spec_.sample_type);
    base[header::colour_space] = static_cast<std::uint8_t>(spec_.colour_space);
    base[header::codec] = static_cast<std::uint8_t>(spec_.codec);
    base[header::flags] = std::uint8_t((spec_.has_alpha ? kHeaderFlagAlpha : 0) | (sparse_index ? kHeaderFlagSparseIndex : 0));
    base[header::block_shift] = kBlockShift;
    store<std::uint64_t>(base, header::level_table_offset, level_table_offset);
    store<std::uint32_t>(base, header::level_table_bytes, static_cast<std::uint32_t>(nlevels * kLevelRecordBytes));
    store<std::uint32_t>(base, header::palette_count, static_cast<std::uint32_t>(palette.size()));
    store<std::uint64_t>(base, header::palette_offset, palette_offset);
    store<std::uint64_t>(base, header::index_offset, index_offset);
    store<std::uint64_t>(base, header::data_offset, data_offset);
    store<std::uint64_t>(base, header::file_size, file_size);
    store<std::uint64_t>(base, header::level_table_checksum, XXH3_64bits(base + level_table_offset, nlevels * kLevelRecordBytes));
    store<std::uint64_t>(base, header::palette_checksum, XXH3_64bits(base + palette_offset, palette.size() * kPaletteValueBytes));
    store<std::uint64_t>(base, header::store_id, XXH3_64bits(base + kHeaderBytes, data_offset - kHeaderBytes));
    store<std::uint64_t>(base, header::header_checksum, XXH3_64bits(base, header::header_checksum));

    // 4. Write: index region, then the distinct payloads in layout order, copied from the spool.
    SequentialWriter w(out_);
    TESSERA_TRY(w.write(idx));
    std::vector<std::uint8_t> buf;
    std::uint64_t copied = 0;
    for (auto [l, i] : copy_order) {
        const Record& r = records_[l][i];
        buf.resize(r.length);
        TESSERA_TRY(spool_.pread_all(r.spool_offset, buf));
        TESSERA_TRY(w.write(buf));
        copied += r.length;
        if (progress && (copied & ~((1ull << 24) - 1)) != ((copied - r.length) & ~((1ull << 24) - 1)))
            progress(copied, data_cursor);
    }
    TESSERA_TRY(w.flush());
    if (w.position() != file_size) return make_error(Errc::io_error, "internal error: store size mismatch");
    if (progress) progress(data_cursor, data_cursor);
    return out_.commit(path_);
}

}  // namespace

Status validate(const StoreSpec& s) {
    if (s.width == 0 || s.height == 0) return make_error(Errc::invalid_argument, "image width and height must be at least 1");
    const std::uint64_t tile = std::uint64_t(s.tile_payload) + 2ull * s.border;
    if (s.tile_payload == 0 || tile > kMaxTileSize)
        return make_error(Errc::invalid_argument, "tile size must be between 1 and " + std::to_string(kMaxTileSize));
    if (s.border > 0xffff) return make_error(Errc::invalid_argument, "border too large");
    if (s.channels < 1 || s.channels > 4) return make_error(Errc::invalid_argument, "channels must be 1 to 4");
    if (s.has_alpha && s.channels != 2 && s.channels != 4)
        return make_error(Errc::invalid_argument, "alpha needs 2 or 4 channels");
    const std::vector<LevelInfo> levels = level_geometry(s.width, s.height, s.tile_payload);
    if (levels.size() > kMaxLevels)
        return make_error(Errc::invalid_argument, "image too large for the tile size (more than 32 levels)");
    // A dense index holds a record for every block of every level, and readers hold the block
    // tables whole (kMaxBlockTableBytes): a store no reader would open is not written.
    if (!s.sparse_index || !s.layers.empty()) {
        std::uint64_t table_bytes = 0;
        for (const LevelInfo& l : levels)
            table_bytes += std::uint64_t(ceil_div(l.tiles_x, kBlockSide)) * ceil_div(l.tiles_y, kBlockSide) * kBlockRecordBytes;
        if (table_bytes > kMaxBlockTableBytes)
            return make_error(Errc::invalid_argument, "image too large for the tile size: its index's block tables would take " +
                                                          std::to_string(table_bytes >> 20) + " MiB, more than readers hold (" +
                                                          std::to_string(kMaxBlockTableBytes >> 20) +
                                                          " MiB); use larger tiles, or a sparse index for a sparse source");
    }
    if (!s.layers.empty()) {
        if (const std::string why = layers_misfit(s.layers, static_cast<std::uint32_t>(tile), s.border); !why.empty())
            return make_error(Errc::invalid_argument, why);
        const LayerInfo& l0 = s.layers.front();
        if (s.codec != Codec::layers || s.channels != l0.channels || s.sample_type != l0.sample_type ||
            s.colour_space != l0.colour_space || s.has_alpha != l0.has_alpha)
            return make_error(Errc::invalid_argument, "a layered store's codec is 'layers' and its channels, samples, "
                                                      "colour space and alpha are its first layer's");
        return {};
    }
    if (s.codec == Codec::layers) return make_error(Errc::invalid_argument, "codec 'layers' needs the store's layers");
    if (const std::string misfit = codec_misfit(s.codec, s.sample_type, s.channels, static_cast<std::uint32_t>(tile), s.border);
        !misfit.empty())
        return make_error(Errc::invalid_argument, misfit + " (use --codec zstd)");
    return {};
}

StoreInfo store_info(const StoreSpec& spec) {
    StoreInfo info;
    info.width = spec.width;
    info.height = spec.height;
    info.tile_payload = spec.tile_payload;
    info.border = spec.border;
    info.channels = spec.channels;
    info.sample_type = spec.sample_type;
    info.colour_space = spec.colour_space;
    info.codec = spec.codec;
    info.has_alpha = spec.has_alpha;
    info.levels = level_geometry(spec.width, spec.height, spec.tile_payload);
    info.layers = spec.layers;
    return info;
}

Result<std::unique_ptr<StoreWriter>> StoreWriter::create(const std::string& path, const StoreSpec& spec) {
    TESSERA_TRY(validate(spec));
    auto out = TempFile::create_beside(path, "tmp");
    if (!out) return out.error();
    auto spool = TempFile::create_beside(path, "spool");
    if (!spool) return spool.error();
    return std::unique_ptr<StoreWriter>(new Writer(path, spec, std::move(*out), std::move(*spool)));
}

}  // namespace tessera::storage
