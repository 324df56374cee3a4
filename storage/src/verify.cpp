#include "tessera/storage/verify.hpp"

#include <algorithm>

#include "tessera/hex.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/layers.hpp"
#include "format.hpp"

namespace tessera::storage {

VerifyReport verify_store(const StoreReader& reader, const VerifyOptions& options) {
    VerifyReport rep;
    auto problem = [&](std::string s) {
        ++rep.problem_count;
        if (rep.problems.size() < options.max_problems) rep.problems.push_back(std::move(s));
    };
    const StoreInfo& info = reader.info();
    std::vector<StoreInfo> layer_info;
    std::vector<std::uint64_t> layer_bytes;
    std::vector<std::uint8_t> part_texels;
    // A bundle's parts: the store's layers, not all absent; each decoded when asked.
    auto check_bundle = [&](const Tile& t, const std::string& name) {
        auto parts = split_layers(info, t.bytes);
        if (!parts) {
            problem(name + ": " + parts.error().message);
            return;
        }
        bool any = false;
        for (std::size_t i = 0; i < parts->size(); ++i) {
            const LayerPart& p = (*parts)[i];
            if (!t.deduplicated) layer_bytes[i] += p.bytes.size();
            if (p.kind == TileKind::absent) continue;
            any = true;
            if (!options.decode) continue;
            if (Status st = decode_tile(layer_info[i], layer_tile(t.key, p), part_texels); !st)
                problem(name + ", layer " + info.layers[i].name + ": " + st.error().message);
        }
        if (!any) problem(name + ": a bundle with no layer's data (such a tile is absent)");
    };
    std::uint64_t total = 0;
    for (const auto& l : info.levels) total += std::uint64_t(l.tiles_x) * l.tiles_y;

    // The store id is the index's content hash: caches (the server's, a viewer's disk cache) key
    // tiles by it, so an index changed after writing must not keep the old id.
    if (auto h = reader.index_hash(); !h)
        problem("index: " + h.error().message);
    else if (*h != info.store_id)
        problem("header: store id " + hex16(info.store_id) + " is not the index's hash (" + hex16(*h) +
                "): the index was changed after the store was written");

    // Distinct payload ranges, to check that the data section is exactly covered.
    std::vector<std::pair<std::uint64_t, std::uint64_t>> ranges;
    std::vector<std::uint8_t> decoded;
    std::uint64_t done = 0;
    // A layered store: every bundle must split into the store's layers, and each layer's bytes
    // (over the payloads stored, a deduplicated one once) must be what the layer table says.
    for (std::size_t i = 0; i < info.layers.size(); ++i) layer_info.push_back(layer_store_info(info, i));
    layer_bytes.assign(info.layers.size(), 0);
    for (std::uint32_t lv = 0; lv < info.level_count(); ++lv) {
        const LevelInfo& L = info.levels[lv];
        std::uint64_t present = 0, uniform = 0, absent = 0, dedup = 0;
        std::vector<TileKey> batch;
        auto flush = [&] {
            auto results = reader.read_tiles(batch);
            for (std::size_t i = 0; i < results.size(); ++i) {
                const TileKey& k = batch[i];
                const std::string name = "level " + std::to_string(k.level) + " tile (" + std::to_string(k.x) + "," +
                                         std::to_string(k.y) + ")";
                if (!results[i]) {
                    problem(name + ": " + results[i].error().message);
                    continue;
                }
                ++rep.payloads_checked;
                rep.bytes_checked += results[i]->bytes.size();
                if (info.layered()) {
                    check_bundle(*results[i], name);
                } else if (options.decode) {
                    Status st = decode_tile(info, *results[i], decoded);
                    if (!st) problem(name + ": " + st.error().message);
                }
            }
            batch.clear();
        };
        // Walk the blocks that hold data (the empty ones, all their tiles absent, cost nothing:
        // a sparse level may have 2^50 of them), tiles in Morton order within a block: that
        // follows the file layout, so batches coalesce into few reads, and memory stays bounded
        // whatever the geometry claims.
        constexpr std::uint32_t S = StoreReader::kIndexBlockSide;
        std::vector<TileKey> keys;
        const std::uint64_t level_tiles = std::uint64_t(L.tiles_x) * L.tiles_y;
        std::uint64_t in_data_blocks = 0;
        for (const auto& [bx, by] : reader.data_blocks(lv)) {
            in_data_blocks += std::uint64_t(std::min(S, L.tiles_x - bx * S)) * std::min(S, L.tiles_y - by * S);
            keys.clear();
            for (std::uint32_t y = by * S; y < std::min(L.tiles_y, (by + 1) * S); ++y)
                for (std::uint32_t x = bx * S; x < std::min(L.tiles_x, (bx + 1) * S); ++x) keys.push_back({lv, x, y});
            std::sort(keys.begin(), keys.end(), [](const TileKey& a, const TileKey& b) {
                return format::morton(a.x, a.y) < format::morton(b.x, b.y);
            });
            for (const TileKey& k : keys) {
                ++rep.tiles_checked;
                auto loc = reader.locate(k);
                if (!loc) {
                    problem("level " + std::to_string(k.level) + " tile (" + std::to_string(k.x) + "," + std::to_string(k.y) +
                            "): " + loc.error().message);
                    continue;
                }
                switch (loc->kind) {
                    case TileKind::absent: ++absent; break;
                    case TileKind::uniform: ++uniform; batch.push_back(k); break;
                    case TileKind::present:
                        ++present;
                        if (loc->deduplicated) {
                            ++dedup;
                        } else {
                            ranges.emplace_back(loc->offset, loc->offset + loc->length);
                            // A payload first stored here lies in the level's data range.
                            if (loc->offset < L.payload_offset || loc->offset + loc->length > L.payload_offset + L.payload_bytes)
                                problem("level " + std::to_string(k.level) + " tile (" + std::to_string(k.x) + "," +
                                        std::to_string(k.y) + "): payload outside the level's data range");
                        }
                        batch.push_back(k);
                        break;
                }
                if (batch.size() >= 256) flush();
                if (options.progress && (++done & 1023) == 0) options.progress(done, total);
            }
        }
        // Every tile outside those blocks is absent.
        absent += level_tiles - in_data_blocks;
        rep.tiles_checked += level_tiles - in_data_blocks;
        done += level_tiles - in_data_blocks;
        flush();
        if (present != L.present || uniform != L.uniform || absent != L.absent || dedup != L.deduplicated)
            problem("level " + std::to_string(lv) + ": tile counts in the level table do not match the index");
    }
    if (options.progress) options.progress(total, total);
    // (Only when every bundle was read: a missing one would make every layer's sum short.)
    const bool all_read = rep.problem_count == 0;
    for (std::size_t i = 0; i < info.layers.size() && all_read; ++i)
        if (layer_bytes[i] != info.layers[i].payload_bytes)
            problem("layer " + info.layers[i].name + ": the layer table says " + std::to_string(info.layers[i].payload_bytes) +
                    " payload bytes, the bundles hold " + std::to_string(layer_bytes[i]));

    // Every data byte, from the index's end (data_offset) to the file's, belongs to exactly one
    // stored payload, and the levels' data ranges add up to them.
    std::sort(ranges.begin(), ranges.end());
    std::uint64_t level_bytes = 0;
    for (const auto& l : info.levels) level_bytes += l.payload_bytes;
    std::uint64_t expect = info.data_offset;
    if (expect == 0 || expect > info.file_size) expect = info.file_size - level_bytes;  // not from a reader
    else if (info.file_size - expect != level_bytes)
        problem("data section: " + std::to_string(info.file_size - expect) + " bytes, the levels' payloads " +
                std::to_string(level_bytes));
    for (const auto& [b, e] : ranges) {
        if (b != expect) {
            problem("data section: " + std::string(b < expect ? "overlapping payloads" : "unreferenced bytes") +
                    " at offset " + std::to_string(std::min(b, expect)));
            break;
        }
        expect = e;
    }
    if (rep.problem_count == 0 && expect != info.file_size) problem("data section: unreferenced bytes at the end");
    return rep;
}

}  // namespace tessera::storage
