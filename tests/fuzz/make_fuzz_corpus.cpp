// make_fuzz_corpus DIR: writes a few small, valid stores into DIR as the fuzzers' seeds: every
// codec, sample type and channel count family, with present, uniform, absent and deduplicated
// tiles, one level and several, and a multi-layer store.
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "tessera/storage/codec.hpp"
#include "tessera/storage/layers.hpp"
#include "tessera/storage/store_writer.hpp"

namespace {

using namespace tessera;
using namespace tessera::storage;

Status write_store(const std::string& path, const StoreSpec& spec, unsigned seed, bool all_absent) {
    auto created = StoreWriter::create(path, spec);
    if (!created) return created.error();
    StoreWriter& w = **created;
    const StoreInfo info = store_info(spec);
    EncodeOptions enc;
    enc.jpeg_quality = 75;
    std::vector<std::uint8_t> texels(info.tile_bytes());
    for (std::uint32_t l = 0; l < info.level_count() && !all_absent; ++l) {
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y) {
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                const TileKey key{l, x, y};
                // The last level is always present, so every store has a payload to decode.
                const unsigned kind = l + 1 == info.level_count() ? 2 : (x + 2 * y + l + seed) % 5;
                if (kind == 0) continue;  // absent
                if (kind == 1) {
                    const std::vector<std::uint8_t> value(info.texel_bytes(), static_cast<std::uint8_t>(17 * (x + y) + seed));
                    TESSERA_TRY(w.add_uniform(key, value));
                    continue;
                }
                // kind 4 tiles all share one pattern: their payloads are deduplicated.
                for (std::size_t i = 0; i < texels.size(); ++i)
                    texels[i] = static_cast<std::uint8_t>(kind == 4 ? (i * 7 + seed) : (i * 3 + x * 31 + y * 57 + l * 101 + seed) ^ (i >> 7));
                auto payload = encode_tile(info, texels, enc);
                if (!payload) return payload.error();
                TESSERA_TRY(w.add_present(key, *payload));
            }
        }
    }
    return w.finish();
}

// A multi-layer store: grey u8 JPEG, RGBA u8 zstd, grey u16 raw; its bundles mix present, uniform
// and absent parts, some tiles are absent, two bundles are identical.
Status write_layered_store(const std::string& path) {
    StoreSpec spec;
    spec.width = 40;
    spec.height = 30;
    spec.tile_payload = 16;
    spec.border = 2;
    spec.codec = Codec::layers;
    spec.layers = {LayerInfo{"grey", 1, SampleType::u8, ColourSpace::srgb, Codec::jpeg},
                   LayerInfo{"rgba", 4, SampleType::u8, ColourSpace::srgb, Codec::zstd, true},
                   LayerInfo{"height", 1, SampleType::u16, ColourSpace::linear, Codec::raw}};
    spec.channels = 1;
    spec.sample_type = SampleType::u8;
    spec.colour_space = ColourSpace::srgb;
    auto created = StoreWriter::create(path, spec);
    if (!created) return created.error();
    const StoreInfo info = store_info(spec);
    EncodeOptions enc;
    enc.jpeg_quality = 75;
    for (std::uint32_t l = 0; l < info.level_count(); ++l)
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                const unsigned v = (x + 2 * y + l) % 4;
                if (v == 0 && l + 1 < info.level_count()) continue;  // absent in every layer
                std::vector<std::vector<std::uint8_t>> bytes(3);
                std::vector<LayerPart> parts(3);
                for (std::size_t i = 0; i < 3; ++i) {
                    const StoreInfo li = layer_store_info(info, i);
                    const unsigned kind = (v + i) % 3;  // 0 absent, 1 uniform, 2 present
                    if (kind == 1) {
                        bytes[i].assign(li.texel_bytes(), static_cast<std::uint8_t>(v == 3 ? 40 + i : 9 * x + i));
                    } else if (kind == 2) {
                        std::vector<std::uint8_t> texels(li.tile_bytes());
                        for (std::size_t k = 0; k < texels.size(); ++k) texels[k] = static_cast<std::uint8_t>(k * 5 + i * 3 + (v == 3 ? 0 : x));
                        auto payload = encode_tile(li, texels, enc);
                        if (!payload) return payload.error();
                        bytes[i] = std::move(*payload);
                    }
                    parts[i] = LayerPart{kind == 0 ? TileKind::absent : kind == 1 ? TileKind::uniform : TileKind::present, bytes[i]};
                }
                TESSERA_TRY((*created)->add_present({l, x, y}, join_layers(parts)));
            }
    return (*created)->finish();
}

// A sparse index (format 1.2): 2048 x 2048 texels in 16-texel tiles, three tiles present, so its
// block tables list three non-empty blocks of 9 x 9 (a store of a few hundred kilobytes).
Status write_sparse_store(const std::string& path) {
    StoreSpec spec;
    spec.width = spec.height = 2048;
    spec.tile_payload = 12;
    spec.border = 2;
    spec.channels = 4;
    spec.sample_type = SampleType::u8;
    spec.colour_space = ColourSpace::srgb;
    spec.codec = Codec::zstd;
    spec.sparse_index = true;
    auto created = StoreWriter::create(path, spec);
    if (!created) return created.error();
    const StoreInfo info = store_info(spec);
    std::vector<std::uint8_t> texels(info.tile_bytes());
    for (std::size_t i = 0; i < texels.size(); ++i) texels[i] = static_cast<std::uint8_t>(i * 13 + (i >> 6));
    auto payload = encode_tile(info, texels, {});
    if (!payload) return payload.error();
    for (const TileKey key : {TileKey{0, 0, 0}, TileKey{0, 170, 3}, TileKey{2, 40, 42}}) TESSERA_TRY((*created)->add_present(key, *payload));
    return (*created)->finish();
}

StoreSpec make_spec(std::uint32_t w, std::uint32_t h, std::uint32_t payload, std::uint32_t border, std::uint32_t channels,
               SampleType st, Codec codec, bool alpha = false) {
    StoreSpec s;
    s.width = w;
    s.height = h;
    s.tile_payload = payload;
    s.border = border;
    s.channels = channels;
    s.sample_type = st;
    s.colour_space = st == SampleType::u8 ? ColourSpace::srgb : ColourSpace::linear;
    s.codec = codec;
    s.has_alpha = alpha;
    return s;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: make_fuzz_corpus DIR\n");
        return 2;
    }
    const std::string dir = argv[1];
    struct Seed {
        const char* name;
        StoreSpec spec;
        bool all_absent = false;  // no entry blocks at all: a store of a few hundred bytes
    };
    const Seed seeds[] = {
        {"raw-grey-u8-1level.tsr", make_spec(12, 9, 16, 2, 1, SampleType::u8, Codec::raw)},
        {"raw-grey-f32-3levels.tsr", make_spec(40, 30, 12, 2, 1, SampleType::f32, Codec::raw)},
        {"zstd-rgba-u8-2levels.tsr", make_spec(30, 20, 16, 4, 4, SampleType::u8, Codec::zstd, true)},
        {"zstd-greyalpha-u16-1level.tsr", make_spec(20, 20, 24, 4, 2, SampleType::u16, Codec::zstd, true)},
        {"zstd-rgb-f16-3levels.tsr", make_spec(50, 33, 14, 1, 3, SampleType::f16, Codec::zstd)},
        {"jpeg-rgb-u8-2levels.tsr", make_spec(40, 24, 24, 4, 3, SampleType::u8, Codec::jpeg)},
        {"jpeg-grey-u8-1level.tsr", make_spec(16, 16, 16, 0, 1, SampleType::u8, Codec::jpeg)},
        {"empty-rgb-u8-4levels.tsr", make_spec(100, 70, 12, 2, 3, SampleType::u8, Codec::jpeg), true},
        {"empty-rgba-f32-1level.tsr", make_spec(5, 3, 8, 0, 4, SampleType::f32, Codec::raw, true), true},
    };
    unsigned n = 0;
    for (const Seed& s : seeds) {
        const std::string path = dir + "/" + s.name;
        if (Status st = write_store(path, s.spec, n++, s.all_absent); !st) {
            std::fprintf(stderr, "make_fuzz_corpus: %s: %s\n", path.c_str(), st.error().message.c_str());
            return 1;
        }
    }
    if (Status st = write_layered_store(dir + "/layers-grey-rgba-u16-2levels.tsr"); !st) {
        std::fprintf(stderr, "make_fuzz_corpus: layered store: %s\n", st.error().message.c_str());
        return 1;
    }
    ++n;
    if (Status st = write_sparse_store(dir + "/sparse-index-rgba-u8.tsr"); !st) {
        std::fprintf(stderr, "make_fuzz_corpus: sparse store: %s\n", st.error().message.c_str());
        return 1;
    }
    ++n;
    std::printf("make_fuzz_corpus: wrote %u stores to %s\n", n, dir.c_str());
    return 0;
}
