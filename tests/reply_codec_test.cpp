// The hand-written StreamTiles reply coding, in-process: encode_replies (server/src/reply_buffer.*)
// against protobuf's own parser and OutMessage::to_proto, and ServerMessageDecoder
// (tessera/protocol/stream_codec.hpp) against protobuf's serializer, over cut-up receive buffers.
#include <gtest/gtest.h>

#include <google/protobuf/util/message_differencer.h>

#include <algorithm>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "reply_buffer.hpp"
#include "scheduler.hpp"
#include "store_registry.hpp"
#include "tessera.pb.h"
#include "tessera/protocol/stream_codec.hpp"
#include "tessera/protocol/wire.hpp"

namespace {

using namespace tessera;
using namespace tessera::server;
namespace v1 = tessera::v1;
using google::protobuf::util::MessageDifferencer;

std::string flatten(const grpc::ByteBuffer& b) {
    std::vector<grpc::Slice> slices;
    EXPECT_TRUE(b.Dump(&slices).ok());
    std::string s;
    for (const auto& sl : slices) s.append(reinterpret_cast<const char*>(sl.begin()), sl.size());
    return s;
}

// The same bytes, cut into slices at the given points (as gRPC may hand a message over).
grpc::ByteBuffer cut(const std::string& bytes, std::vector<std::size_t> points) {
    std::sort(points.begin(), points.end());
    std::vector<grpc::Slice> slices;
    std::size_t from = 0;
    for (std::size_t p : points) {
        if (p <= from || p >= bytes.size()) continue;
        slices.emplace_back(bytes.data() + from, p - from);
        from = p;
    }
    slices.emplace_back(bytes.data() + from, bytes.size() - from);
    return grpc::ByteBuffer(slices.data(), slices.size());
}

struct Maker {
    std::mt19937_64 rng{7};
    std::shared_ptr<StoreHandle> store = [] {
        auto s = std::make_shared<StoreHandle>();
        s->name = "terrain";
        s->version = 0xfedcba9876543210ull;
        return s;
    }();

    OutMessage tile(tessera::TileKind kind, std::size_t size, std::uint32_t level, std::uint32_t x, std::uint32_t y) {
        OutMessage m;
        m.is_tile = true;
        m.store = store;
        m.key = {level, x, y};
        m.frame = rng() >> (rng() % 64);
        m.status = tessera::TileStatus::ok;
        m.kind = kind;
        m.codec = tessera::Codec::jpeg;  // the store's codec; the reply names it for present tiles only
        auto t = std::make_shared<storage::Tile>();
        t->kind = kind;
        t->bytes.resize(size);
        for (auto& b : t->bytes) b = static_cast<std::uint8_t>(rng());
        t->checksum = rng();
        m.tile = std::move(t);
        m.server_micros = static_cast<std::uint32_t>(rng() % 100000);
        return m;
    }
    OutMessage read_error(tessera::TileStatus status, std::string text) {
        OutMessage m;
        m.is_tile = true;
        m.store = store;
        m.key = {3, 1, 2};
        m.frame = 9;
        m.status = status;
        m.error = std::move(text);
        return m;
    }
    // An error found in submit(): a ready-made protobuf TileReply.
    OutMessage submit_error() {
        OutMessage m;
        auto* t = m.message.mutable_tile();
        t->mutable_key()->set_store("nope");
        t->mutable_key()->set_level(4);
        t->set_status(v1::TILE_NOT_FOUND);
        t->set_message("no store named nope");
        t->set_codec(v1::CODEC_NONE);
        t->set_frame(12);
        return m;
    }
};

std::vector<OutMessage> mixed(Maker& mk) {
    std::vector<OutMessage> msgs;
    msgs.push_back(mk.tile(tessera::TileKind::present, 15000, 2, 17, 300));
    msgs.push_back(mk.tile(tessera::TileKind::uniform, 4, 0, 0, 0));   // zero key fields: omitted
    msgs.push_back(mk.tile(tessera::TileKind::absent, 0, 5, 1, 1));    // no payload at all
    msgs.push_back(mk.read_error(tessera::TileStatus::deadline_exceeded, "not started before its deadline"));
    msgs.push_back(mk.submit_error());
    msgs.push_back(mk.tile(tessera::TileKind::present, 1, 1, 0, 1));
    msgs.push_back(mk.tile(tessera::TileKind::present, 200000, 30, 0xFFFFFFFFu, 128));  // multi-byte lengths
    return msgs;
}

TEST(ReplyCodec, SeveralRepliesParseAsTheSameTileReplies) {
    Maker mk;
    const auto msgs = mixed(mk);
    grpc::ByteBuffer buf;
    std::string scratch;
    encode_replies(msgs, /*multi=*/true, buf, scratch);
    // Payloads go in as their own slices, not copied into the head.
    std::vector<grpc::Slice> slices;
    ASSERT_TRUE(buf.Dump(&slices).ok());
    EXPECT_GT(slices.size(), 4u);
    bool found = false;
    for (const auto& s : slices)
        found = found || reinterpret_cast<const std::uint8_t*>(s.begin()) == msgs[0].tile->bytes.data();
    EXPECT_TRUE(found) << "the first payload was copied";

    v1::ServerMessage parsed;
    ASSERT_TRUE(parsed.ParseFromString(flatten(buf)));
    ASSERT_TRUE(parsed.has_tiles());
    ASSERT_EQ(parsed.tiles().tiles_size(), static_cast<int>(msgs.size()));
    for (std::size_t i = 0; i < msgs.size(); ++i) {
        const v1::ServerMessage want = msgs[i].to_proto();
        ASSERT_TRUE(want.has_tile());
        EXPECT_TRUE(MessageDifferencer::Equals(parsed.tiles().tiles(int(i)), want.tile()))
            << "reply " << i << ":\n" << parsed.tiles().tiles(int(i)).ShortDebugString().substr(0, 400) << "\nwant:\n"
            << want.tile().ShortDebugString().substr(0, 400);
    }
    // The tiles' bytes, exactly.
    EXPECT_EQ(parsed.tiles().tiles(0).payload(),
              std::string(msgs[0].tile->bytes.begin(), msgs[0].tile->bytes.end()));
    EXPECT_EQ(parsed.tiles().tiles(6).payload().size(), 200000u);
}

TEST(ReplyCodec, OneReplyPerMessageForRevisionZero) {
    Maker mk;
    const auto msgs = mixed(mk);
    for (std::size_t i = 0; i < msgs.size(); ++i) {
        grpc::ByteBuffer buf;
        std::string scratch;
        encode_replies({msgs[i]}, /*multi=*/false, buf, scratch);
        v1::ServerMessage parsed;
        ASSERT_TRUE(parsed.ParseFromString(flatten(buf)));
        ASSERT_TRUE(parsed.has_tile()) << i;
        EXPECT_TRUE(MessageDifferencer::Equals(parsed, msgs[i].to_proto())) << "reply " << i;
    }
    OutMessage ack;
    ack.message.mutable_ack()->set_frame(5);
    ack.message.mutable_ack()->set_admitted(3);
    ack.message.mutable_ack()->set_already_sent(2);
    grpc::ByteBuffer buf;
    std::string scratch;
    encode_replies({ack}, true, buf, scratch);
    v1::ServerMessage parsed;
    ASSERT_TRUE(parsed.ParseFromString(flatten(buf)));
    EXPECT_TRUE(MessageDifferencer::Equals(parsed, ack.message));
}

void expect_decoded(const protocol::ServerMessageDecoder& d, std::size_t i, const v1::TileReply& want) {
    const auto& t = d.tile(i);
    EXPECT_EQ(t.store, want.key().store());
    EXPECT_EQ(t.key.level, want.key().level());
    EXPECT_EQ(t.key.x, want.key().x());
    EXPECT_EQ(t.key.y, want.key().y());
    EXPECT_EQ(t.store_version, want.store_version());
    EXPECT_EQ(t.frame, want.frame());
    EXPECT_EQ(t.status, want.status());
    EXPECT_EQ(t.message, want.message());
    EXPECT_EQ(t.kind, want.kind());
    EXPECT_EQ(t.codec, want.codec());
    EXPECT_EQ(t.checksum, want.checksum());
    EXPECT_EQ(t.server_micros, want.server_micros());
    ASSERT_EQ(t.payload_size, want.payload().size());
    std::string payload(t.payload_size, '\0');
    d.copy_payload(i, payload.data());
    EXPECT_EQ(payload, want.payload());
}

TEST(ReplyCodec, DecoderReadsProtobufsOwnEncodingOverAnySlicing) {
    Maker mk;
    const auto msgs = mixed(mk);
    v1::ServerMessage many;
    for (const auto& m : msgs) *many.mutable_tiles()->add_tiles() = m.to_proto().tile();
    const std::string bytes = many.SerializeAsString();
    std::mt19937_64 rng(3);
    protocol::ServerMessageDecoder d;  // reused: stale state from one message must not leak into the next
    for (int round = 0; round < 20; ++round) {
        std::vector<std::size_t> points;
        for (int k = 0; k < round * 3; ++k) points.push_back(rng() % bytes.size());
        if (round == 1) for (std::size_t p = 1; p < 300; ++p) points.push_back(p);  // byte by byte: varints split
        ASSERT_TRUE(d.decode(cut(bytes, points))) << round;
        ASSERT_EQ(d.kind(), protocol::ServerMessageDecoder::Kind::tiles);
        ASSERT_EQ(d.tile_count(), msgs.size());
        for (std::size_t i = 0; i < msgs.size(); ++i) expect_decoded(d, i, many.tiles().tiles(int(i)));
    }
    // A single tile (revision 0) and an ack, on the same decoder.
    const v1::ServerMessage one = msgs[0].to_proto();
    ASSERT_TRUE(d.decode(cut(one.SerializeAsString(), {3, 40, 9000})));
    ASSERT_EQ(d.kind(), protocol::ServerMessageDecoder::Kind::tiles);
    ASSERT_EQ(d.tile_count(), 1u);
    expect_decoded(d, 0, one.tile());
    v1::ServerMessage ack;
    ack.mutable_ack()->set_frame(8);
    ack.mutable_ack()->set_already_sent(4);
    ASSERT_TRUE(d.decode(cut(ack.SerializeAsString(), {})));
    ASSERT_EQ(d.kind(), protocol::ServerMessageDecoder::Kind::ack);
    EXPECT_EQ(d.ack().frame(), 8u);
    EXPECT_EQ(d.ack().already_sent(), 4u);
}

TEST(ReplyCodec, DecoderReadsTheServersEncoding) {
    Maker mk;
    const auto msgs = mixed(mk);
    grpc::ByteBuffer buf;
    std::string scratch;
    encode_replies(msgs, true, buf, scratch);
    protocol::ServerMessageDecoder d;
    ASSERT_TRUE(d.decode(buf));
    ASSERT_EQ(d.tile_count(), msgs.size());
    for (std::size_t i = 0; i < msgs.size(); ++i) expect_decoded(d, i, msgs[i].to_proto().tile());
}

TEST(ReplyCodec, DecoderRejectsTruncatedMessages) {
    Maker mk;
    const auto msgs = mixed(mk);
    v1::ServerMessage many;
    for (const auto& m : msgs) *many.mutable_tiles()->add_tiles() = m.to_proto().tile();
    const std::string bytes = many.SerializeAsString();
    protocol::ServerMessageDecoder d;
    for (std::size_t n : {std::size_t(1), std::size_t(2), std::size_t(7), bytes.size() / 2, bytes.size() - 1}) {
        const std::string part = bytes.substr(0, n);
        EXPECT_FALSE(d.decode(cut(part, {n / 3}))) << "truncated to " << n << " bytes";
    }
}

// The wire's enums and the tile vocabulary convert both ways, and a reply's codec and kind read as
// the client must: CODEC_UNIFORM alone makes a tile uniform; the codec a reply names follows from
// status, kind and the store's codec.
TEST(ReplyCodec, CodecUniformMakesAUniformTile) {
    EXPECT_EQ(protocol::reply_kind(v1::KIND_PRESENT, v1::CODEC_UNIFORM), TileKind::uniform);
    EXPECT_EQ(protocol::reply_kind(v1::KIND_UNIFORM, v1::CODEC_UNIFORM), TileKind::uniform);
    EXPECT_EQ(protocol::reply_kind(v1::KIND_PRESENT, v1::CODEC_JPEG), TileKind::present);
    EXPECT_EQ(protocol::reply_kind(v1::KIND_ABSENT, v1::CODEC_UNIFORM), TileKind::absent);
    EXPECT_EQ(protocol::reply_codec(TileStatus::ok, TileKind::present, Codec::zstd), v1::CODEC_ZSTD);
    EXPECT_EQ(protocol::reply_codec(TileStatus::ok, TileKind::uniform, Codec::zstd), v1::CODEC_UNIFORM);
    EXPECT_EQ(protocol::reply_codec(TileStatus::ok, TileKind::absent, Codec::zstd), v1::CODEC_NONE);
    EXPECT_EQ(protocol::reply_codec(TileStatus::data_loss, TileKind::present, Codec::zstd), v1::CODEC_NONE);
    for (int s = 0; s <= 8; ++s) {
        const auto status = static_cast<TileStatus>(s);
        EXPECT_EQ(protocol::from_proto(protocol::to_proto(status)), status) << to_string(status);
        EXPECT_EQ(int(protocol::to_proto(status)), s) << "tessera.proto's TileStatus values";
    }
    EXPECT_EQ(protocol::from_proto(static_cast<v1::TileStatus>(99)), TileStatus::internal);
    for (auto c : {Codec::raw, Codec::zstd, Codec::jpeg}) EXPECT_EQ(protocol::from_proto(protocol::to_proto(c)), c);
    for (auto k : {TileKind::absent, TileKind::present, TileKind::uniform})
        EXPECT_EQ(protocol::from_proto(protocol::to_proto(k)), k);
    for (auto c : {Codec::bc1, Codec::bc4, Codec::bc5, Codec::bc7, Codec::layers})
        EXPECT_EQ(protocol::from_proto(protocol::to_proto(c)), c) << to_string(c);
    EXPECT_EQ(protocol::to_proto(Codec::layers), v1::CODEC_LAYERS);
    EXPECT_EQ(protocol::reply_codec(TileStatus::ok, TileKind::present, Codec::layers), v1::CODEC_LAYERS);
}

// A multi-layer store's description crosses the wire with every layer's fields, in order; a
// single-layer store's has no layers.
TEST(ReplyCodec, StoreMetadataCarriesLayers) {
    namespace storage = tessera::storage;
    storage::StoreInfo info;
    info.width = 1000;
    info.height = 700;
    info.tile_payload = 120;
    info.border = 4;
    info.codec = Codec::layers;
    info.channels = 4;
    info.has_alpha = true;
    info.version_major = 1;
    info.version_minor = 1;
    info.levels = storage::level_geometry(info.width, info.height, info.tile_payload);
    info.layers = {storage::LayerInfo{"albedo", 4, storage::SampleType::u8, storage::ColourSpace::srgb, Codec::bc7, true},
                   storage::LayerInfo{"normal", 2, storage::SampleType::u8, storage::ColourSpace::linear, Codec::bc5},
                   storage::LayerInfo{"height", 1, storage::SampleType::f32, storage::ColourSpace::linear, Codec::zstd}};
    for (std::size_t i = 0; i < info.layers.size(); ++i) info.layers[i].payload_bytes = 1000003 * (i + 1);
    const v1::StoreMetadata m = protocol::to_proto("t", info);
    EXPECT_EQ(m.codec(), v1::CODEC_LAYERS);
    ASSERT_EQ(m.layers_size(), 3);
    EXPECT_EQ(m.layers(2).sample_type(), v1::SAMPLE_F32);
    const storage::StoreInfo back = protocol::from_proto(m);
    EXPECT_EQ(back.codec, Codec::layers);
    EXPECT_EQ(back.version_minor, 1u);
    ASSERT_EQ(back.layers.size(), info.layers.size());
    for (std::size_t i = 0; i < info.layers.size(); ++i) {
        SCOPED_TRACE(info.layers[i].name);
        EXPECT_EQ(back.layers[i].name, info.layers[i].name);
        EXPECT_EQ(back.layers[i].channels, info.layers[i].channels);
        EXPECT_EQ(back.layers[i].sample_type, info.layers[i].sample_type);
        EXPECT_EQ(back.layers[i].colour_space, info.layers[i].colour_space);
        EXPECT_EQ(back.layers[i].codec, info.layers[i].codec);
        EXPECT_EQ(back.layers[i].has_alpha, info.layers[i].has_alpha);
        EXPECT_EQ(back.layers[i].payload_bytes, info.layers[i].payload_bytes);
    }
    info.layers.clear();
    info.codec = Codec::jpeg;
    EXPECT_EQ(protocol::to_proto("t", info).layers_size(), 0);
    EXPECT_TRUE(protocol::from_proto(protocol::to_proto("t", info)).layers.empty());
}

}  // namespace
