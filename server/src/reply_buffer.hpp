#pragma once
// Encodes what Scheduler::next_messages took from a viewer's outbox into one gRPC message, by
// hand (tessera/protocol/stream_codec.hpp): the fields of each reply go into one small buffer,
// and each payload goes in as a slice that references the cached tile (it holds the tile alive
// until gRPC has written it), so tile bytes are never copied in user space.
#include <string>
#include <vector>

#include <grpcpp/support/byte_buffer.h>

#include "scheduler.hpp"

namespace tessera::server {

// multi: the viewer reads protocol revision 1 (ServerMessage.tiles); then every message in msgs
// that is not an ack goes into one TileReplies. Otherwise msgs holds one message. scratch is
// reused between calls.
void encode_replies(const std::vector<OutMessage>& msgs, bool multi, grpc::ByteBuffer& out, std::string& scratch);

}  // namespace tessera::server
