#pragma once
// Wire vocabulary shared by the server and the client: store names, and conversions between the
// store's types (tessera::storage) and the generated protobuf messages (tessera.v1).
#include <cstdint>
#include <string>
#include <string_view>

#include "tessera.pb.h"
#include "tessera/storage/types.hpp"

namespace tessera::protocol {

// A store is named by its file name without ".tsr". Names are identifiers, never paths:
// 1..128 characters of [A-Za-z0-9_.-], starting with a letter, digit or '_', no "..".
constexpr std::size_t kMaxStoreNameLength = 128;
bool valid_store_name(std::string_view name);

// The store name of a file name ("terrain.tsr" -> "terrain"); empty when it is not a .tsr file
// or the name is not valid.
std::string store_name_of_file(std::string_view file_name);

v1::SampleType to_proto(storage::SampleType t);
v1::ColourSpace to_proto(storage::ColourSpace c);
v1::Codec to_proto(storage::Codec c);
v1::TileKind to_proto(storage::TileKind k);
storage::SampleType from_proto(v1::SampleType t);
storage::ColourSpace from_proto(v1::ColourSpace c);
storage::Codec from_proto(v1::Codec c);  // CODEC_UNIFORM/NONE map to raw (check kind first)

// Everything about a store a client needs, as a message.
v1::StoreMetadata to_proto(std::string_view name, const storage::StoreInfo& info);
// The reverse (geometry and codec; counts copied, store_id = version). Used by clients.
storage::StoreInfo from_proto(const v1::StoreMetadata& m);

std::string_view to_string(v1::TileStatus s);

// Packs a key into 64 bits for hashing and maps: level (6 bits) | y (29 bits) | x (29 bits).
// Levels < 64 and coordinates < 2^29 tiles per axis (2^37 texels at P = 256) fit.
constexpr std::uint64_t pack_key(std::uint32_t level, std::uint32_t x, std::uint32_t y) {
    return (std::uint64_t(level) << 58) | (std::uint64_t(y & 0x1FFFFFFFu) << 29) | (x & 0x1FFFFFFFu);
}

}  // namespace tessera::protocol
