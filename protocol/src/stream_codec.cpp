#include "tessera/protocol/stream_codec.hpp"

#include <cstring>

namespace tessera::protocol {

namespace {

enum WireType : std::uint8_t { kVarint = 0, kFixed64 = 1, kLen = 2, kFixed32 = 5 };

constexpr std::uint8_t tag(unsigned field, WireType type) { return static_cast<std::uint8_t>(field << 3 | type); }

void append_fixed64(std::string& out, std::uint64_t v) {
    char b[8];
    for (int i = 0; i < 8; ++i) b[i] = static_cast<char>(v >> (8 * i));
    out.append(b, 8);
}

void append_bytes_field(std::string& out, std::uint8_t t, std::string_view s) {
    out.push_back(static_cast<char>(t));
    append_varint(out, s.size());
    out.append(s);
}

void append_varint_field(std::string& out, std::uint8_t t, std::uint64_t v) {
    if (v == 0) return;  // proto3: zero is the default and is not written
    out.push_back(static_cast<char>(t));
    append_varint(out, v);
}

}  // namespace

void append_varint(std::string& out, std::uint64_t v) {
    char b[10];
    std::size_t n = 0;
    while (v >= 0x80) {
        b[n++] = static_cast<char>(v | 0x80);
        v >>= 7;
    }
    b[n++] = static_cast<char>(v);
    out.append(b, n);
}

std::size_t varint_size(std::uint64_t v) {
    std::size_t n = 1;
    while (v >= 0x80) {
        v >>= 7;
        ++n;
    }
    return n;
}

void append_tile_reply_head(std::string& out, const TileReplyFields& f) {
    // key (TileKey: store = 1, level = 2, x = 3, y = 4)
    const std::size_t key_size = (f.store.empty() ? 0 : 1 + varint_size(f.store.size()) + f.store.size()) +
                                 (f.key.level ? 1 + varint_size(f.key.level) : 0) + (f.key.x ? 1 + varint_size(f.key.x) : 0) +
                                 (f.key.y ? 1 + varint_size(f.key.y) : 0);
    out.push_back(static_cast<char>(tag(1, kLen)));
    append_varint(out, key_size);
    if (!f.store.empty()) append_bytes_field(out, tag(1, kLen), f.store);
    append_varint_field(out, tag(2, kVarint), f.key.level);
    append_varint_field(out, tag(3, kVarint), f.key.x);
    append_varint_field(out, tag(4, kVarint), f.key.y);
    if (f.store_version) {
        out.push_back(static_cast<char>(tag(2, kFixed64)));
        append_fixed64(out, f.store_version);
    }
    append_varint_field(out, tag(3, kVarint), f.frame);
    append_varint_field(out, tag(4, kVarint), static_cast<std::uint64_t>(f.status));
    if (!f.message.empty()) append_bytes_field(out, tag(5, kLen), f.message);
    append_varint_field(out, tag(6, kVarint), static_cast<std::uint64_t>(f.kind));
    append_varint_field(out, tag(7, kVarint), static_cast<std::uint64_t>(f.codec));
    if (f.checksum) {
        out.push_back(static_cast<char>(tag(9, kFixed64)));
        append_fixed64(out, f.checksum);
    }
    append_varint_field(out, tag(10, kVarint), f.server_micros);
    if (f.payload_size) {
        out.push_back(static_cast<char>(tag(8, kLen)));
        append_varint(out, f.payload_size);
    }
}

// A read position over the message's slices; pos counts bytes from the message start.
struct ServerMessageDecoder::Cursor {
    const std::vector<grpc::Slice>& slices;
    std::size_t si = 0, off = 0, pos = 0;

    void settle() {
        while (si < slices.size() && off == slices[si].size()) {
            ++si;
            off = 0;
        }
    }
    bool byte(std::uint8_t& b) {
        settle();
        if (si == slices.size()) return false;
        b = slices[si].begin()[off++];
        ++pos;
        return true;
    }
    bool varint(std::uint64_t& v) {
        v = 0;
        for (int shift = 0; shift < 70; shift += 7) {
            std::uint8_t b;
            if (!byte(b)) return false;
            v |= std::uint64_t(b & 0x7F) << shift;
            if (!(b & 0x80)) return true;
        }
        return false;
    }
    bool fixed(std::uint64_t& v, int bytes) {
        v = 0;
        for (int i = 0; i < bytes; ++i) {
            std::uint8_t b;
            if (!byte(b)) return false;
            v |= std::uint64_t(b) << (8 * i);
        }
        return true;
    }
    bool skip(std::size_t n) {
        while (n) {
            settle();
            if (si == slices.size()) return false;
            const std::size_t k = std::min(n, slices[si].size() - off);
            off += k;
            pos += k;
            n -= k;
        }
        return true;
    }
    bool copy(std::size_t n, char* dst) {
        while (n) {
            settle();
            if (si == slices.size()) return false;
            const std::size_t k = std::min(n, slices[si].size() - off);
            std::memcpy(dst, slices[si].begin() + off, k);
            dst += k;
            off += k;
            pos += k;
            n -= k;
        }
        return true;
    }
    bool string(std::size_t n, std::string& out) {
        out.resize(n);
        return copy(n, out.data());
    }
    // Skips a field of this wire type (the tag already read).
    bool skip_field(std::uint8_t type) {
        std::uint64_t v;
        switch (type) {
            case kVarint: return varint(v);
            case kFixed64: return skip(8);
            case kLen: return varint(v) && skip(v);
            case kFixed32: return skip(4);
            default: return false;
        }
    }
};

bool ServerMessageDecoder::parse_tile(Cursor& c, std::size_t end, DecodedTile& t) {
    t.store.clear();
    t.message.clear();
    t.key = {};
    t.store_version = t.frame = t.checksum = 0;
    t.status = v1::TILE_OK;
    t.kind = v1::KIND_ABSENT;
    t.codec = v1::CODEC_RAW;
    t.server_micros = 0;
    t.payload_size = 0;
    while (c.pos < end) {
        std::uint64_t key, v;
        if (!c.varint(key)) return false;
        const auto field = key >> 3;
        const auto type = static_cast<std::uint8_t>(key & 7);
        if (type == kLen) {
            if (!c.varint(v) || v > end - c.pos) return false;
            if (field == 1) {  // key
                const std::size_t key_end = c.pos + v;
                while (c.pos < key_end) {
                    std::uint64_t k2, v2;
                    if (!c.varint(k2)) return false;
                    if ((k2 & 7) == kLen) {
                        if (!c.varint(v2) || v2 > key_end - c.pos) return false;
                        if ((k2 >> 3) == 1) {
                            if (!c.string(v2, t.store)) return false;
                        } else if (!c.skip(v2)) {
                            return false;
                        }
                    } else if ((k2 & 7) == kVarint) {
                        if (!c.varint(v2)) return false;
                        if ((k2 >> 3) == 2) t.key.level = static_cast<std::uint32_t>(v2);
                        else if ((k2 >> 3) == 3) t.key.x = static_cast<std::uint32_t>(v2);
                        else if ((k2 >> 3) == 4) t.key.y = static_cast<std::uint32_t>(v2);
                    } else if (!c.skip_field(static_cast<std::uint8_t>(k2 & 7))) {
                        return false;
                    }
                }
                if (c.pos != key_end) return false;
            } else if (field == 5) {
                if (!c.string(v, t.message)) return false;
            } else if (field == 8) {
                c.settle();
                t.payload_size = v;
                t.payload_slice = c.si;
                t.payload_offset = c.off;
                if (!c.skip(v)) return false;
            } else if (!c.skip(v)) {
                return false;
            }
        } else if (type == kVarint) {
            if (!c.varint(v)) return false;
            switch (field) {
                case 3: t.frame = v; break;
                case 4: t.status = static_cast<v1::TileStatus>(v); break;
                case 6: t.kind = static_cast<v1::TileKind>(v); break;
                case 7: t.codec = static_cast<v1::Codec>(v); break;
                case 10: t.server_micros = static_cast<std::uint32_t>(v); break;
                default: break;
            }
        } else if (type == kFixed64) {
            if (!c.fixed(v, 8)) return false;
            if (field == 2) t.store_version = v;
            else if (field == 9) t.checksum = v;
        } else if (!c.skip_field(type)) {
            return false;
        }
    }
    return c.pos == end;
}

bool ServerMessageDecoder::decode(const grpc::ByteBuffer& buffer) {
    slices_.clear();
    count_ = 0;
    kind_ = Kind::none;
    if (!buffer.Dump(&slices_).ok()) return false;
    std::size_t total = 0;
    for (const auto& s : slices_) total += s.size();
    Cursor c{slices_};
    auto next_tile = [&]() -> DecodedTile& {
        if (count_ == tiles_.size()) tiles_.emplace_back();
        return tiles_[count_++];
    };
    while (c.pos < total) {
        std::uint64_t key, len;
        if (!c.varint(key)) return false;
        const auto type = static_cast<std::uint8_t>(key & 7);
        if (type != kLen) {
            if (!c.skip_field(type)) return false;
            continue;
        }
        if (!c.varint(len) || len > total - c.pos) return false;
        const std::size_t end = c.pos + len;
        // A oneof: the last body wins, as in protobuf.
        switch (key >> 3) {
            case 1:
                count_ = 0;
                kind_ = Kind::tiles;
                if (!parse_tile(c, end, next_tile())) return false;
                break;
            case 2:
                count_ = 0;
                kind_ = Kind::ack;
                if (!c.string(len, scratch_) || !ack_.ParseFromString(scratch_)) return false;
                break;
            case 3:
                count_ = 0;
                kind_ = Kind::tiles;
                while (c.pos < end) {
                    std::uint64_t k2, l2;
                    if (!c.varint(k2)) return false;
                    if (k2 != kTileRepliesTileTag) {
                        if (!c.skip_field(static_cast<std::uint8_t>(k2 & 7))) return false;
                        continue;
                    }
                    if (!c.varint(l2) || l2 > end - c.pos) return false;
                    if (!parse_tile(c, c.pos + l2, next_tile())) return false;
                }
                if (c.pos != end) return false;
                break;
            default:
                if (!c.skip(len)) return false;
                break;
        }
    }
    return true;
}

void ServerMessageDecoder::copy_payload(std::size_t i, void* dst) const {
    const DecodedTile& t = tiles_[i];
    Cursor c{slices_, t.payload_slice, t.payload_offset, 0};
    c.copy(t.payload_size, static_cast<char*>(dst));
}

}  // namespace tessera::protocol
