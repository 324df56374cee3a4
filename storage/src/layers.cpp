#include "tessera/storage/layers.hpp"

#include <cstring>
#include <string>

namespace tessera::storage {

namespace {
// A bundle starts with one 8-byte record per layer: u8 kind, 3 zero bytes, u32 length (little
// endian); then the parts' bytes, in layer order, with no gaps.
constexpr std::size_t kPartRecordBytes = 8;

std::uint32_t load_u32(const std::uint8_t* p) {
    return std::uint32_t(p[0]) | std::uint32_t(p[1]) << 8 | std::uint32_t(p[2]) << 16 | std::uint32_t(p[3]) << 24;
}
}  // namespace

std::string layer_name_misfit(std::string_view name) {
    if (name.empty()) return "a layer name cannot be empty";
    if (name.size() > kMaxLayerNameBytes)
        return "layer name '" + std::string(name) + "' is longer than " + std::to_string(kMaxLayerNameBytes) + " bytes";
    for (char c : name)
        if (!((c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' || c == '-'))
            return "layer name '" + std::string(name) + "' may only hold a-z, 0-9, '_' and '-'";
    return {};
}

std::string layers_misfit(std::span<const LayerInfo> layers, std::uint32_t tile_size, std::uint32_t border) {
    if (layers.size() < kMinLayers || layers.size() > kMaxLayers)
        return "a layered store has " + std::to_string(kMinLayers) + " to " + std::to_string(kMaxLayers) + " layers, not " +
               std::to_string(layers.size());
    for (std::size_t i = 0; i < layers.size(); ++i) {
        const LayerInfo& l = layers[i];
        if (std::string why = layer_name_misfit(l.name); !why.empty()) return why;
        for (std::size_t j = 0; j < i; ++j)
            if (layers[j].name == l.name) return "two layers are named '" + l.name + "'";
        const std::string what = "layer '" + l.name + "'";
        if (l.channels < 1 || l.channels > 4) return what + " has " + std::to_string(l.channels) + " channels (1 to 4)";
        if (static_cast<unsigned>(l.sample_type) > static_cast<unsigned>(SampleType::f32) ||
            static_cast<unsigned>(l.colour_space) > static_cast<unsigned>(ColourSpace::srgb))
            return what + " has an unknown sample type or colour space";
        if (l.has_alpha && l.channels != 2 && l.channels != 4) return what + ": alpha needs 2 or 4 channels";
        if (l.codec == Codec::layers) return what + " has codec layers: a layer's parts are in a texel codec";
        if (std::string misfit = codec_misfit(l.codec, l.sample_type, l.channels, tile_size, border); !misfit.empty())
            return what + ": " + misfit;
    }
    return {};
}

StoreInfo layer_store_info(const StoreInfo& info, std::size_t layer) {
    StoreInfo out = info;
    out.layers.clear();
    if (!info.layered()) return out;
    const LayerInfo& l = info.layers.at(layer);
    out.channels = l.channels;
    out.sample_type = l.sample_type;
    out.colour_space = l.colour_space;
    out.codec = l.codec;
    out.has_alpha = l.has_alpha;
    return out;
}

Result<std::vector<LayerPart>> split_layers(const StoreInfo& info, std::span<const std::uint8_t> bundle) {
    const std::size_t n = info.layers.size();
    if (n == 0) return Error{Errc::invalid_argument, "not a multi-layer store"};
    const std::size_t table = n * kPartRecordBytes;
    if (bundle.size() < table)
        return Error{Errc::corrupt, "layer bundle of " + std::to_string(bundle.size()) + " bytes cannot hold " +
                                        std::to_string(n) + " layers"};
    std::vector<LayerPart> parts(n);
    std::size_t at = table;
    for (std::size_t i = 0; i < n; ++i) {
        const std::uint8_t* rec = bundle.data() + i * kPartRecordBytes;
        const std::uint32_t length = load_u32(rec + 4);
        if (rec[1] != 0 || rec[2] != 0 || rec[3] != 0 || rec[0] > 2)
            return Error{Errc::corrupt, "layer bundle: bad record for layer " + info.layers[i].name};
        const auto kind = static_cast<TileKind>(rec[0]);
        const std::size_t texel = info.layers[i].channels * sample_bytes(info.layers[i].sample_type);
        const bool fits = kind == TileKind::absent    ? length == 0
                          : kind == TileKind::uniform ? length == texel
                                                      : length > 0;
        if (!fits || length > bundle.size() - at)
            return Error{Errc::corrupt, "layer bundle: layer " + info.layers[i].name + " says " + std::string(to_string(kind)) +
                                            " with " + std::to_string(length) + " bytes"};
        parts[i] = LayerPart{kind, bundle.subspan(at, length)};
        at += length;
    }
    if (at != bundle.size())
        return Error{Errc::corrupt, "layer bundle: " + std::to_string(bundle.size() - at) + " bytes after the last layer"};
    return parts;
}

Tile layer_tile(const TileKey& key, const LayerPart& part) {
    Tile t;
    t.key = key;
    t.kind = part.kind;
    t.bytes.assign(part.bytes.begin(), part.bytes.end());
    return t;
}

std::vector<std::uint8_t> join_layers(std::span<const LayerPart> parts) {
    std::size_t total = parts.size() * kPartRecordBytes;
    for (const LayerPart& p : parts) total += p.bytes.size();
    std::vector<std::uint8_t> out(total, 0);
    std::size_t at = parts.size() * kPartRecordBytes;
    for (std::size_t i = 0; i < parts.size(); ++i) {
        std::uint8_t* rec = out.data() + i * kPartRecordBytes;
        rec[0] = static_cast<std::uint8_t>(parts[i].kind);
        const auto len = static_cast<std::uint32_t>(parts[i].bytes.size());
        for (int b = 0; b < 4; ++b) rec[4 + b] = static_cast<std::uint8_t>(len >> (8 * b));
        if (!parts[i].bytes.empty()) std::memcpy(out.data() + at, parts[i].bytes.data(), parts[i].bytes.size());
        at += parts[i].bytes.size();
    }
    return out;
}

}  // namespace tessera::storage
