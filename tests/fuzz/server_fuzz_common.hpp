#pragma once
// Shared by server_request_fuzz and make_server_fuzz_corpus: the two stores the fuzzer serves
// (written the same way by both, so the seeds can name real tiles and the real store versions)
// and the fuzzer's input format.
//
// Input format. Byte 0 is a set of flags:
//   bit 0      mode: 0 = one HTTP request, 1 = tile batches through the scheduler
//   bit 1      context: 0 = no auth, roomy limits; 1 = auth token "t0k", tight limits, no cache
//   HTTP mode:
//   bit 2      replace the Authorization header by the valid "Bearer t0k"
//   rest       method '\n' target '\n' authorization '\n' if-none-match '\n' accept
//              (missing fields are empty; the last field takes everything after its '\n')
//   batch mode:
//   bits 2-3   v: 1 + v % 3 batches
//   bit 4      two viewers (batch i goes to viewer i % 2) instead of one
//   bits 5-7   messages each viewer reads between two submits: 0, 1, 2, 4, 8, 16, 64, all ready
//   rest       batches: all but the last are a little-endian u16 length and that many bytes;
//              the last takes the rest. Each is a serialized tessera.v1.TileBatch, or, when it
//              does not parse, records of 10 bytes (see raw_record below).
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include "tessera/storage/codec.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/store_writer.hpp"

namespace tessera::fuzz {

// ---- input format ------------------------------------------------------------------------------

namespace flag {
constexpr std::uint8_t batch_mode = 1u << 0;
constexpr std::uint8_t auth_context = 1u << 1;
constexpr std::uint8_t valid_token = 1u << 2;  // HTTP
constexpr unsigned batches_shift = 2;          // batch mode, 2 bits
constexpr std::uint8_t two_viewers = 1u << 4;  // batch mode
constexpr unsigned reads_shift = 5;            // batch mode, 3 bits
}  // namespace flag

// Raw records (the fallback for bytes that are not a TileBatch), 10 bytes each:
//   [0] store index % 5 into {"a", "b", "nope", "../x"} (4: an index outside the list)
//   [1] level: < 0xf0: level % 5, else the byte itself
//   [2..3] x (LE): < 0xf000: x % 7, else the value itself
//   [4..5] y (LE): < 0xf000: y % 5, else the value itself
//   [6..9] priority, a float's bytes (LE)
constexpr std::size_t kRawRecordBytes = 10;
inline const char* const kRawStores[] = {"a", "b", "nope", "../x"};

inline std::string http_input(std::uint8_t flags, const std::string& method, const std::string& target,
                              const std::string& authorization = "", const std::string& if_none_match = "",
                              const std::string& accept = "") {
    std::string s(1, static_cast<char>(flags & ~flag::batch_mode));
    s += method + "\n" + target + "\n" + authorization + "\n" + if_none_match + "\n" + accept;
    return s;
}

inline std::string batch_input(std::uint8_t flags, const std::vector<std::string>& batches) {
    std::string s(1, static_cast<char>(flags | flag::batch_mode));
    for (std::size_t i = 0; i < batches.size(); ++i) {
        if (i + 1 < batches.size()) {
            const auto n = static_cast<std::uint16_t>(batches[i].size());
            s += static_cast<char>(n & 0xff);
            s += static_cast<char>(n >> 8);
        }
        s += batches[i];
    }
    return s;
}

inline std::string raw_record(std::uint8_t store, std::uint8_t level, std::uint16_t x, std::uint16_t y, float priority) {
    std::string r(kRawRecordBytes, '\0');
    r[0] = static_cast<char>(store);
    r[1] = static_cast<char>(level);
    r[2] = static_cast<char>(x & 0xff);
    r[3] = static_cast<char>(x >> 8);
    r[4] = static_cast<char>(y & 0xff);
    r[5] = static_cast<char>(y >> 8);
    std::memcpy(r.data() + 6, &priority, 4);
    return r;
}

// ---- the stores --------------------------------------------------------------------------------

struct ExpectedTile {
    tessera::TileKind kind = tessera::TileKind::absent;
    std::vector<std::uint8_t> bytes;  // present: the payload as written; uniform: the value
    bool corrupt = false;             // a payload byte was flipped after writing: never served
};

struct ExpectedStore {
    std::string name;
    storage::StoreInfo info;
    std::uint64_t version = 0;  // StoreInfo::store_id, read back after writing
    std::map<std::uint64_t, ExpectedTile> tiles;  // by pack(key); every tile of every level

    static std::uint64_t pack(const tessera::TileKey& k) {
        return (std::uint64_t(k.level) << 48) | (std::uint64_t(k.y) << 24) | k.x;
    }
    // nullptr when the key is outside the store.
    const ExpectedTile* find(const tessera::TileKey& k) const {
        if (!info.contains(k)) return nullptr;
        const auto it = tiles.find(pack(k));
        return it == tiles.end() ? nullptr : &it->second;
    }
};

namespace detail {

inline storage::StoreSpec spec(std::uint32_t w, std::uint32_t h, std::uint32_t payload, std::uint32_t border,
                               std::uint32_t channels, tessera::Codec codec) {
    storage::StoreSpec s;
    s.width = w;
    s.height = h;
    s.tile_payload = payload;
    s.border = border;
    s.channels = channels;
    s.sample_type = storage::SampleType::u8;
    s.colour_space = storage::ColourSpace::srgb;
    s.codec = codec;
    return s;
}

enum class Make { present, uniform, absent, shared };

// Writes one store; `make` picks each tile's kind. Shared tiles all have the same texels (the
// writer stores their payload once).
inline std::string write_one(const std::string& dir, ExpectedStore& out, const storage::StoreSpec& sp,
                             Make (*make)(const tessera::TileKey&)) {
    const std::string path = dir + "/" + out.name + ".tsr";
    auto created = storage::StoreWriter::create(path, sp);
    if (!created) return created.error().message;
    storage::StoreWriter& w = **created;
    out.info = storage::store_info(sp);
    std::vector<std::uint8_t> texels(out.info.tile_bytes());
    unsigned seed = 1;
    for (std::uint32_t l = 0; l < out.info.level_count(); ++l) {
        for (std::uint32_t y = 0; y < out.info.levels[l].tiles_y; ++y) {
            for (std::uint32_t x = 0; x < out.info.levels[l].tiles_x; ++x) {
                const tessera::TileKey key{l, x, y};
                ExpectedTile& e = out.tiles[ExpectedStore::pack(key)];
                const Make m = make(key);
                if (m == Make::absent) continue;
                if (m == Make::uniform) {
                    e.kind = tessera::TileKind::uniform;
                    e.bytes.assign(out.info.texel_bytes(), static_cast<std::uint8_t>(40 + 9 * l + x));
                    if (Status s = w.add_uniform(key, e.bytes); !s) return s.error().message;
                    continue;
                }
                const unsigned salt = m == Make::shared ? 0 : seed++;
                for (std::size_t i = 0; i < texels.size(); ++i)
                    texels[i] = static_cast<std::uint8_t>((i * 7 + salt * 131) ^ (i >> 5) ^ (salt * 17));
                auto payload = storage::encode_tile(out.info, texels, {});
                if (!payload) return payload.error().message;
                e.kind = tessera::TileKind::present;
                e.bytes = *payload;
                if (Status s = w.add_present(key, e.bytes); !s) return s.error().message;
            }
        }
    }
    if (Status s = w.finish(); !s) return s.error().message;
    return {};
}

// Flips a byte in the middle of a present tile's payload in the file.
inline std::string corrupt_tile(const std::string& path, ExpectedStore& store, const tessera::TileKey& key) {
    auto reader = storage::StoreReader::open(path);
    if (!reader) return reader.error().message;
    auto loc = (*reader)->locate(key);
    if (!loc || loc->kind != tessera::TileKind::present) return "corrupt_tile: not a present tile";
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    const auto at = static_cast<std::streamoff>(loc->offset + loc->length / 2);
    char c = 0;
    f.seekg(at);
    f.read(&c, 1);
    c = static_cast<char>(c ^ 0x5a);
    f.seekp(at);
    f.write(&c, 1);
    f.close();
    if (!f) return "corrupt_tile: write failed";
    store.tiles[ExpectedStore::pack(key)].corrupt = true;
    return {};
}

}  // namespace detail

// The corrupted tile (store "b").
inline constexpr tessera::TileKey kCorruptKey{0, 0, 0};

// Writes a.tsr and b.tsr into dir and describes them in `out`. Returns an error message, or ""
//   a: 300 x 200 RGB8, tile payload 56 + border 4 (64 x 64 texels, 12 KiB raw), 4 levels (6x4, 3x2,
//      2x1, 1x1 tiles), raw codec; level 0: (1,1) uniform, (2,1) absent, (3,3) and (4,3) share one
//      payload; level 1: (2,1) uniform; level 2: (1,0) absent; everything else present.
//   b: 20 x 12 grey u8, tile payload 8 + border 2, 3 levels (3x2, 2x1, 1x1), zstd; level 0:
//      (0,0) present with a corrupted payload byte, (1,0) uniform, (2,1) absent.
inline std::string write_server_fuzz_stores(const std::string& dir, std::vector<ExpectedStore>& out) {
    using detail::Make;
    out.clear();
    out.resize(2);
    out[0].name = "a";
    std::string err = detail::write_one(dir, out[0], detail::spec(300, 200, 56, 4, 3, tessera::Codec::raw),
                                        [](const tessera::TileKey& k) {
                                            if (k.level == 0 && k.x == 1 && k.y == 1) return Make::uniform;
                                            if (k.level == 0 && k.x == 2 && k.y == 1) return Make::absent;
                                            if (k.level == 0 && (k.x == 3 || k.x == 4) && k.y == 3) return Make::shared;
                                            if (k.level == 1 && k.x == 2 && k.y == 1) return Make::uniform;
                                            if (k.level == 2 && k.x == 1 && k.y == 0) return Make::absent;
                                            return Make::present;
                                        });
    if (!err.empty()) return "a: " + err;
    out[1].name = "b";
    err = detail::write_one(dir, out[1], detail::spec(20, 12, 8, 2, 1, tessera::Codec::zstd),
                            [](const tessera::TileKey& k) {
                                if (k.level == 0 && k.x == 1 && k.y == 0) return Make::uniform;
                                if (k.level == 0 && k.x == 2 && k.y == 1) return Make::absent;
                                return Make::present;
                            });
    if (!err.empty()) return "b: " + err;
    err = detail::corrupt_tile(dir + "/b.tsr", out[1], kCorruptKey);
    if (!err.empty()) return "b: " + err;

    // Read everything back: the versions, and a check that the description is what a reader sees.
    for (ExpectedStore& s : out) {
        auto reader = storage::StoreReader::open(dir + "/" + s.name + ".tsr");
        if (!reader) return s.name + ": " + reader.error().message;
        s.version = (*reader)->info().store_id;
        s.info = (*reader)->info();
        for (const auto& [packed, e] : s.tiles) {
            const tessera::TileKey key{static_cast<std::uint32_t>(packed >> 48),
                                       static_cast<std::uint32_t>(packed & 0xffffff),
                                       static_cast<std::uint32_t>((packed >> 24) & 0xffffff)};
            auto t = (*reader)->read_tile(key);
            const bool agrees = e.corrupt ? !t.ok() : t.ok() && t->kind == e.kind && t->bytes == e.bytes;
            if (!agrees) {
                char buf[96];
                std::snprintf(buf, sizeof buf, ": tile %u/%u/%u does not read back as written", key.level, key.x, key.y);
                return s.name + buf;
            }
        }
    }
    return {};
}

}  // namespace tessera::fuzz
