#pragma once
// The tile vocabulary every part of Tessera shares: which tile (TileKey), what it holds (TileKind,
// Codec, TileData) and how a request for it ended (TileStatus). The store, the server and the
// client all speak it; only protocol/ (tessera/protocol/wire.hpp) converts it to and from the
// wire's protobuf enums. See docs/store-format.md and docs/protocol.md.
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string_view>
#include <vector>

namespace tessera {

// How a present tile's payload is encoded in a store and on the wire. The block codecs hold GPU
// blocks (a zstd frame of the tile's 4x4 blocks, then its half-size level's; docs/store-format.md):
// a client whose page pool has that format uploads them as they are.
//
// `layers` is a multi-layer store's tile: one bundle holding every layer's part, each in its
// layer's own codec (tessera/storage/layers.hpp), so that one request fetches a page's layers.
enum class Codec : std::uint8_t { raw = 0, zstd = 1, jpeg = 2, bc1 = 3, bc4 = 4, bc5 = 5, bc7 = 6, layers = 7 };
constexpr bool is_block_codec(Codec c) { return c == Codec::bc1 || c == Codec::bc4 || c == Codec::bc5 || c == Codec::bc7; }

// What a tile holds. An absent tile (sparse store) has no data: a viewer uses its parent. A
// uniform tile's payload is one texel value that every texel of the tile has.
enum class TileKind : std::uint8_t { absent = 0, present = 1, uniform = 2 };

// How a request for a tile ended. Values follow tessera.proto's TileStatus.
enum class TileStatus : std::uint8_t {
    ok = 0,
    not_found = 1,           // no such store
    out_of_range = 2,        // level/x/y outside the store
    invalid_argument = 3,    // malformed request
    resource_exhausted = 4,  // refused: queues full; retry later
    deadline_exceeded = 5,   // not started before its deadline
    data_loss = 6,           // the tile fails its checksum; never served
    unavailable = 7,         // shutting down, or the store is being reopened; retry
    internal = 8,
};

std::string_view to_string(Codec c);      // "raw", "zstd", "jpeg", "bc1", "bc4", "bc5", "bc7", "layers"
std::string_view to_string(TileKind k);   // "absent", "present", "uniform"
std::string_view to_string(TileStatus s); // "OK", "NOT_FOUND", ... (the gRPC-style names)
std::optional<Codec> parse_codec(std::string_view s);  // also accepts "jpg"

// A tile of one store. Level 0 is the finest level.
struct TileKey {
    std::uint32_t level = 0;
    std::uint32_t x = 0;
    std::uint32_t y = 0;
    friend bool operator==(const TileKey&, const TileKey&) = default;
    TileKey parent() const { return TileKey{level + 1, x >> 1, y >> 1}; }
};

// A key packed into 64 bits for maps: level (6 bits) | y (29 bits) | x (29 bits).
// Levels < 64 and coordinates < 2^29 tiles per axis (2^37 texels at 256-texel tiles) fit.
constexpr std::uint64_t pack_key(const TileKey& k) {
    return (std::uint64_t(k.level) << 58) | (std::uint64_t(k.y & 0x1FFFFFFFu) << 29) | (k.x & 0x1FFFFFFFu);
}

// What a tile holds, as a store read, a reply or a cache entry carries it. `codec` means something
// only for present tiles. `checksum` is XXH3-64 of `payload` as the store holds it (0: none given).
struct TileData {
    TileKind kind = TileKind::absent;
    Codec codec = Codec::raw;
    std::uint64_t checksum = 0;
    std::vector<std::uint8_t> payload;
    friend bool operator==(const TileData&, const TileData&) = default;
};

}  // namespace tessera
