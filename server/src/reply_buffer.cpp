#include "reply_buffer.hpp"

#include <grpcpp/support/slice.h>

#include <memory>

#include "tessera/protocol/stream_codec.hpp"
#include "tessera/protocol/wire.hpp"

namespace tessera::server {

namespace {

void release_tile(void* p) { delete static_cast<std::shared_ptr<const storage::Tile>*>(p); }
void release_string(void* p) { delete static_cast<std::string*>(p); }

// A reply's encoding up to its payload bytes (all of it for error replies and acks).
void append_head(std::string& out, const OutMessage& m) {
    if (!m.is_tile) {
        m.message.has_tile() ? m.message.tile().AppendToString(&out) : m.message.AppendToString(&out);
        return;
    }
    protocol::TileReplyFields f;
    f.store = m.store->name;
    f.key = m.key;
    f.store_version = m.store->version;
    f.frame = m.frame;
    f.status = protocol::to_proto(m.status);
    f.message = m.error;
    f.kind = protocol::to_proto(m.kind);
    f.codec = protocol::reply_codec(m.status, m.kind, m.codec);
    f.checksum = m.tile ? m.tile->checksum : 0;
    f.server_micros = m.server_micros;
    f.payload_size = m.payload_size();
    protocol::append_tile_reply_head(out, f);
}

}  // namespace

void encode_replies(const std::vector<OutMessage>& msgs, bool multi, grpc::ByteBuffer& out, std::string& scratch) {
    const bool ack = msgs.size() == 1 && !msgs.front().is_tile && msgs.front().message.has_ack();
    if (ack) {
        std::string s = msgs.front().message.SerializeAsString();
        grpc::Slice slice(s);
        out = grpc::ByteBuffer(&slice, 1);
        return;
    }
    if (!multi && msgs.size() != 1) return encode_replies({msgs.front()}, false, out, scratch);

    // Each reply's head into scratch; then the message: prefixes and heads into one buffer.
    scratch.clear();
    std::vector<std::size_t> ends(msgs.size());
    std::size_t body = 0;  // TileReplies' (or the one TileReply's) encoded size
    for (std::size_t i = 0; i < msgs.size(); ++i) {
        append_head(scratch, msgs[i]);
        ends[i] = scratch.size();
        const std::size_t reply = ends[i] - (i ? ends[i - 1] : 0) + msgs[i].payload_size();
        body += multi ? 1 + protocol::varint_size(reply) + reply : reply;
    }
    auto* head = new std::string();
    head->reserve(scratch.size() + 8 + msgs.size() * 6);
    head->push_back(static_cast<char>(multi ? protocol::kServerMessageTilesTag : protocol::kServerMessageTileTag));
    protocol::append_varint(*head, body);
    // Cut points: where each payload goes between head bytes.
    std::vector<std::size_t> cuts(msgs.size());
    for (std::size_t i = 0; i < msgs.size(); ++i) {
        const std::size_t begin = i ? ends[i - 1] : 0;
        if (multi) {
            head->push_back(static_cast<char>(protocol::kTileRepliesTileTag));
            protocol::append_varint(*head, ends[i] - begin + msgs[i].payload_size());
        }
        head->append(scratch, begin, ends[i] - begin);
        cuts[i] = head->size();
    }
    grpc::Slice whole(head->data(), head->size(), release_string, head);
    std::vector<grpc::Slice> slices;
    slices.reserve(2 * msgs.size() + 1);
    std::size_t from = 0;
    for (std::size_t i = 0; i < msgs.size(); ++i) {
        const std::size_t n = msgs[i].payload_size();
        if (n == 0) continue;
        slices.push_back(whole.sub(from, cuts[i]));
        from = cuts[i];
        const auto& bytes = msgs[i].tile->bytes;
        slices.emplace_back(const_cast<std::uint8_t*>(bytes.data()), n, release_tile,
                            new std::shared_ptr<const storage::Tile>(msgs[i].tile));
    }
    if (from < head->size()) slices.push_back(from == 0 ? whole : whole.sub(from, head->size()));
    out = grpc::ByteBuffer(slices.data(), slices.size());
}

}  // namespace tessera::server
