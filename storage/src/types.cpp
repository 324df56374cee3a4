#include "tessera/storage/types.hpp"

namespace tessera::storage {

std::string codec_misfit(Codec codec, SampleType sample_type, std::uint32_t channels, std::uint32_t tile_size,
                         std::uint32_t border) {
    const std::string name(to_string(codec));
    switch (codec) {
        case Codec::raw:
        case Codec::zstd: return {};
        case Codec::jpeg:
            if (sample_type != SampleType::u8 || (channels != 1 && channels != 3))
                return "JPEG needs 8-bit samples with 1 or 3 channels";
            return {};
        case Codec::bc1:
        case Codec::bc4:
        case Codec::bc5:
        case Codec::bc7: {
            if (sample_type != SampleType::u8) return name + " needs 8-bit samples";
            const bool fits = codec == Codec::bc1   ? channels == 3
                              : codec == Codec::bc4 ? channels == 1
                              : codec == Codec::bc5 ? channels == 2
                                                    : channels == 3 || channels == 4;
            if (!fits)
                return name + " holds " +
                       (codec == Codec::bc1   ? "3 channels (RGB, no alpha)"
                        : codec == Codec::bc4 ? "1 channel"
                        : codec == Codec::bc5 ? "2 channels"
                                              : "3 or 4 channels") +
                       ", not " + std::to_string(channels);
            if (tile_size % 8 != 0 || border % 4 != 0)
                return name + " needs tiles of a multiple of 8 texels and borders of a multiple of 4, not " +
                       std::to_string(tile_size) + " and " + std::to_string(border);
            return {};
        }
        case Codec::layers: return "layers is a multi-layer store's bundle of tiles, not a codec for texels";
    }
    return "unknown codec " + std::to_string(static_cast<int>(codec));
}

std::size_t sample_bytes(SampleType t) {
    switch (t) {
        case SampleType::u8: return 1;
        case SampleType::u16: return 2;
        case SampleType::f16: return 2;
        case SampleType::f32: return 4;
    }
    return 0;
}

std::string_view to_string(SampleType t) {
    switch (t) {
        case SampleType::u8: return "u8";
        case SampleType::u16: return "u16";
        case SampleType::f16: return "f16";
        case SampleType::f32: return "f32";
    }
    return "?";
}

std::string_view to_string(ColourSpace c) { return c == ColourSpace::srgb ? "srgb" : "linear"; }

std::vector<LevelInfo> level_geometry(std::uint32_t width, std::uint32_t height, std::uint32_t tile_payload) {
    std::vector<LevelInfo> levels;
    if (width == 0 || height == 0 || tile_payload == 0) return levels;
    std::uint64_t w = width, h = height;
    for (;;) {
        LevelInfo l;
        l.width = static_cast<std::uint32_t>(w);
        l.height = static_cast<std::uint32_t>(h);
        l.tiles_x = static_cast<std::uint32_t>((w + tile_payload - 1) / tile_payload);
        l.tiles_y = static_cast<std::uint32_t>((h + tile_payload - 1) / tile_payload);
        levels.push_back(l);
        if (w <= tile_payload && h <= tile_payload) break;
        w = (w + 1) / 2;
        h = (h + 1) / 2;
    }
    return levels;
}

}  // namespace tessera::storage
