#pragma once
// Hand-written wire coding of StreamTiles' ServerMessage, for the hot path on both ends: the
// server writes a tile's fields around a payload it never copies (the payload bytes go out as a
// slice of the cached tile), and clients read replies straight out of gRPC's receive slices
// without parsing them into protobuf objects first. The bytes are ordinary protobuf encoding of
// tessera.proto's messages: any protobuf parser reads what append_tile_reply_head writes, and
// ServerMessageDecoder reads anything a protobuf serializer writes (unknown fields are skipped).
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <grpcpp/support/byte_buffer.h>
#include <grpcpp/support/slice.h>

#include "tessera.pb.h"
#include "tessera/tile.hpp"

namespace tessera::protocol {

// Field tags of ServerMessage's body (field number << 3 | wire type 2).
inline constexpr std::uint8_t kServerMessageTileTag = 0x0A;   // tile = 1
inline constexpr std::uint8_t kServerMessageAckTag = 0x12;    // ack = 2
inline constexpr std::uint8_t kServerMessageTilesTag = 0x1A;  // tiles = 3
inline constexpr std::uint8_t kTileRepliesTileTag = 0x0A;     // TileReplies.tiles = 1

// The protocol revision this code reads and writes (tessera.proto, TileBatch.protocol_revision).
inline constexpr std::uint32_t kProtocolRevision = 1;

void append_varint(std::string& out, std::uint64_t v);
std::size_t varint_size(std::uint64_t v);

// A TileReply's fields, the payload only by its size.
struct TileReplyFields {
    std::string_view store;
    TileKey key;
    std::uint64_t store_version = 0;
    std::uint64_t frame = 0;
    v1::TileStatus status = v1::TILE_OK;
    std::string_view message;
    v1::TileKind kind = v1::KIND_ABSENT;
    v1::Codec codec = v1::CODEC_RAW;
    std::uint64_t checksum = 0;
    std::uint32_t server_micros = 0;
    std::size_t payload_size = 0;
};

// Appends the encoding of a TileReply up to its payload bytes: every field, then (when the
// payload is not empty) the payload's tag and length, last. The TileReply is this plus the
// payload_size payload bytes that follow it.
void append_tile_reply_head(std::string& out, const TileReplyFields& f);

// One tile reply of a received message. The payload stays in the receive slices until copied.
struct DecodedTile {
    std::string store;
    TileKey key;
    std::uint64_t store_version = 0;
    std::uint64_t frame = 0;
    v1::TileStatus status = v1::TILE_OK;
    std::string message;
    v1::TileKind kind = v1::KIND_ABSENT;
    v1::Codec codec = v1::CODEC_RAW;
    std::uint64_t checksum = 0;
    std::uint32_t server_micros = 0;
    std::size_t payload_size = 0;
    // Where the payload starts in the message (slice index and offset).
    std::size_t payload_slice = 0, payload_offset = 0;
};

// Reads ServerMessages from gRPC byte buffers: a tile (revision 0), several tiles (revision 1) or
// an ack. Reuse one decoder per stream: its vectors and strings keep their capacity.
class ServerMessageDecoder {
public:
    enum class Kind { none, tiles, ack };  // none: a body this decoder does not know

    // False when the bytes are not a well-formed ServerMessage.
    bool decode(const grpc::ByteBuffer& buffer);
    Kind kind() const { return kind_; }
    std::size_t tile_count() const { return count_; }
    const DecodedTile& tile(std::size_t i) const { return tiles_[i]; }
    const v1::BatchAck& ack() const { return ack_; }
    v1::BatchAck& mutable_ack() { return ack_; }
    // Copies tile i's payload (payload_size bytes) to dst.
    void copy_payload(std::size_t i, void* dst) const;

private:
    struct Cursor;
    bool parse_tile(Cursor& c, std::size_t end, DecodedTile& t);

    std::vector<grpc::Slice> slices_;
    std::vector<DecodedTile> tiles_;
    std::size_t count_ = 0;
    Kind kind_ = Kind::none;
    v1::BatchAck ack_;
    std::string scratch_;
};

}  // namespace tessera::protocol
