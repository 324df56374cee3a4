#pragma once
// Wire vocabulary shared by the server and the client: store names, and the one place where the
// tile vocabulary (tessera/tile.hpp) and the store's types (tessera::storage) are converted to and
// from the generated protobuf messages (tessera.v1).
#include <cstdint>
#include <string>
#include <string_view>

#include "tessera.pb.h"
#include "tessera/storage/types.hpp"
#include "tessera/tile.hpp"

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
v1::Codec to_proto(Codec c);
v1::TileKind to_proto(TileKind k);
storage::SampleType from_proto(v1::SampleType t);
storage::ColourSpace from_proto(v1::ColourSpace c);
Codec from_proto(v1::Codec c);  // CODEC_UNIFORM/NONE map to raw (check kind first)
TileKind from_proto(v1::TileKind k);
// The kind of a TileReply: its kind, except that CODEC_UNIFORM alone also makes a tile uniform.
TileKind reply_kind(v1::TileKind k, v1::Codec c);
v1::TileStatus to_proto(TileStatus s);
TileStatus from_proto(v1::TileStatus s);  // values this build does not know map to internal

// The codec a TileReply names: the store's codec for a present tile, CODEC_UNIFORM for a uniform
// one, CODEC_NONE when there is no payload (absent, or an error status).
v1::Codec reply_codec(TileStatus status, TileKind kind, Codec codec);

// Everything about a store a client needs, as a message.
v1::StoreMetadata to_proto(std::string_view name, const storage::StoreInfo& info);
// The reverse (geometry and codec; counts copied, store_id = version). Used by clients.
storage::StoreInfo from_proto(const v1::StoreMetadata& m);


}  // namespace tessera::protocol
