#include "tessera/protocol/wire.hpp"

namespace tessera::protocol {

namespace {
bool name_char(char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' || c == '-' ||
           c == '.';
}
}  // namespace

bool valid_store_name(std::string_view name) {
    if (name.empty() || name.size() > kMaxStoreNameLength) return false;
    if (name.front() == '.' || name.front() == '-') return false;
    for (char c : name)
        if (!name_char(c)) return false;
    return name.find("..") == std::string_view::npos;
}

std::string store_name_of_file(std::string_view file_name) {
    constexpr std::string_view ext = ".tsr";
    if (file_name.size() <= ext.size() || !file_name.ends_with(ext)) return {};
    std::string_view stem = file_name.substr(0, file_name.size() - ext.size());
    return valid_store_name(stem) ? std::string(stem) : std::string();
}

v1::SampleType to_proto(storage::SampleType t) {
    switch (t) {
        case storage::SampleType::u8: return v1::SAMPLE_U8;
        case storage::SampleType::u16: return v1::SAMPLE_U16;
        case storage::SampleType::f16: return v1::SAMPLE_F16;
        case storage::SampleType::f32: return v1::SAMPLE_F32;
    }
    return v1::SAMPLE_U8;
}
v1::ColourSpace to_proto(storage::ColourSpace c) {
    return c == storage::ColourSpace::srgb ? v1::COLOUR_SRGB : v1::COLOUR_LINEAR;
}
v1::Codec to_proto(Codec c) {
    switch (c) {
        case Codec::raw: return v1::CODEC_RAW;
        case Codec::zstd: return v1::CODEC_ZSTD;
        case Codec::jpeg: return v1::CODEC_JPEG;
        case Codec::bc1: return v1::CODEC_BC1;
        case Codec::bc4: return v1::CODEC_BC4;
        case Codec::bc5: return v1::CODEC_BC5;
        case Codec::bc7: return v1::CODEC_BC7;
        case Codec::layers: return v1::CODEC_LAYERS;
    }
    return v1::CODEC_RAW;
}
v1::TileKind to_proto(TileKind k) {
    switch (k) {
        case TileKind::absent: return v1::KIND_ABSENT;
        case TileKind::present: return v1::KIND_PRESENT;
        case TileKind::uniform: return v1::KIND_UNIFORM;
    }
    return v1::KIND_ABSENT;
}
storage::SampleType from_proto(v1::SampleType t) {
    switch (t) {
        case v1::SAMPLE_U16: return storage::SampleType::u16;
        case v1::SAMPLE_F16: return storage::SampleType::f16;
        case v1::SAMPLE_F32: return storage::SampleType::f32;
        default: return storage::SampleType::u8;
    }
}
storage::ColourSpace from_proto(v1::ColourSpace c) {
    return c == v1::COLOUR_SRGB ? storage::ColourSpace::srgb : storage::ColourSpace::linear;
}
Codec from_proto(v1::Codec c) {
    switch (c) {
        case v1::CODEC_ZSTD: return Codec::zstd;
        case v1::CODEC_JPEG: return Codec::jpeg;
        case v1::CODEC_BC1: return Codec::bc1;
        case v1::CODEC_BC4: return Codec::bc4;
        case v1::CODEC_BC5: return Codec::bc5;
        case v1::CODEC_BC7: return Codec::bc7;
        case v1::CODEC_LAYERS: return Codec::layers;
        default: return Codec::raw;
    }
}

v1::StoreMetadata to_proto(std::string_view name, const storage::StoreInfo& info) {
    v1::StoreMetadata m;
    m.set_name(std::string(name));
    m.set_version(info.store_id);
    m.set_width(info.width);
    m.set_height(info.height);
    m.set_tile_payload(info.tile_payload);
    m.set_border(info.border);
    m.set_channels(info.channels);
    m.set_sample_type(to_proto(info.sample_type));
    m.set_colour_space(to_proto(info.colour_space));
    m.set_codec(to_proto(info.codec));
    m.set_has_alpha(info.has_alpha);
    for (const auto& l : info.levels) {
        auto* lm = m.add_levels();
        lm->set_width(l.width);
        lm->set_height(l.height);
        lm->set_tiles_x(l.tiles_x);
        lm->set_tiles_y(l.tiles_y);
        lm->set_present(l.present);
        lm->set_uniform(l.uniform);
        lm->set_absent(l.absent);
    }
    m.set_file_size(info.file_size);
    m.set_format_major(info.version_major);
    m.set_format_minor(info.version_minor);
    for (const auto& l : info.layers) {
        auto* lm = m.add_layers();
        lm->set_name(l.name);
        lm->set_channels(l.channels);
        lm->set_sample_type(to_proto(l.sample_type));
        lm->set_colour_space(to_proto(l.colour_space));
        lm->set_codec(to_proto(l.codec));
        lm->set_has_alpha(l.has_alpha);
        lm->set_payload_bytes(l.payload_bytes);
    }
    return m;
}

storage::StoreInfo from_proto(const v1::StoreMetadata& m) {
    storage::StoreInfo info;
    info.width = m.width();
    info.height = m.height();
    info.tile_payload = m.tile_payload();
    info.border = m.border();
    info.channels = m.channels();
    info.sample_type = from_proto(m.sample_type());
    info.colour_space = from_proto(m.colour_space());
    info.codec = from_proto(m.codec());
    info.has_alpha = m.has_alpha();
    info.version_major = static_cast<std::uint16_t>(m.format_major());
    info.version_minor = static_cast<std::uint16_t>(m.format_minor());
    info.store_id = m.version();
    info.file_size = m.file_size();
    for (const auto& lm : m.levels()) {
        storage::LevelInfo l;
        l.width = lm.width();
        l.height = lm.height();
        l.tiles_x = lm.tiles_x();
        l.tiles_y = lm.tiles_y();
        l.present = lm.present();
        l.uniform = lm.uniform();
        l.absent = lm.absent();
        info.levels.push_back(l);
    }
    for (const auto& lm : m.layers()) {
        storage::LayerInfo l;
        l.name = lm.name();
        l.channels = lm.channels();
        l.sample_type = from_proto(lm.sample_type());
        l.colour_space = from_proto(lm.colour_space());
        l.codec = from_proto(lm.codec());
        l.has_alpha = lm.has_alpha();
        l.payload_bytes = lm.payload_bytes();
        info.layers.push_back(std::move(l));
    }
    return info;
}

TileKind from_proto(v1::TileKind k) {
    switch (k) {
        case v1::KIND_PRESENT: return TileKind::present;
        case v1::KIND_UNIFORM: return TileKind::uniform;
        default: return TileKind::absent;
    }
}

TileKind reply_kind(v1::TileKind k, v1::Codec c) {
    if (c == v1::CODEC_UNIFORM && k != v1::KIND_ABSENT) return TileKind::uniform;
    return from_proto(k);
}

v1::TileStatus to_proto(TileStatus s) {
    switch (s) {
        case TileStatus::ok: return v1::TILE_OK;
        case TileStatus::not_found: return v1::TILE_NOT_FOUND;
        case TileStatus::out_of_range: return v1::TILE_OUT_OF_RANGE;
        case TileStatus::invalid_argument: return v1::TILE_INVALID_ARGUMENT;
        case TileStatus::resource_exhausted: return v1::TILE_RESOURCE_EXHAUSTED;
        case TileStatus::deadline_exceeded: return v1::TILE_DEADLINE_EXCEEDED;
        case TileStatus::data_loss: return v1::TILE_DATA_LOSS;
        case TileStatus::unavailable: return v1::TILE_UNAVAILABLE;
        case TileStatus::internal: return v1::TILE_INTERNAL;
    }
    return v1::TILE_INTERNAL;
}

TileStatus from_proto(v1::TileStatus s) {
    switch (s) {
        case v1::TILE_OK: return TileStatus::ok;
        case v1::TILE_NOT_FOUND: return TileStatus::not_found;
        case v1::TILE_OUT_OF_RANGE: return TileStatus::out_of_range;
        case v1::TILE_INVALID_ARGUMENT: return TileStatus::invalid_argument;
        case v1::TILE_RESOURCE_EXHAUSTED: return TileStatus::resource_exhausted;
        case v1::TILE_DEADLINE_EXCEEDED: return TileStatus::deadline_exceeded;
        case v1::TILE_DATA_LOSS: return TileStatus::data_loss;
        case v1::TILE_UNAVAILABLE: return TileStatus::unavailable;
        default: return TileStatus::internal;
    }
}

v1::Codec reply_codec(TileStatus status, TileKind kind, Codec codec) {
    if (status != TileStatus::ok) return v1::CODEC_NONE;
    switch (kind) {
        case TileKind::present: return to_proto(codec);
        case TileKind::uniform: return v1::CODEC_UNIFORM;
        case TileKind::absent: break;
    }
    return v1::CODEC_NONE;
}

}  // namespace tessera::protocol
