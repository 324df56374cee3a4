#pragma once
// What the atlas build's tests share: reading a store's level-0 texels and an image file, listing a
// folder, and the shape of a failed command.
#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <filesystem>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "tessera/storage/codec.hpp"
#include "tessera/storage/layers.hpp"
#include "tessera/storage/store_reader.hpp"
#include "test_util.hpp"

namespace tessera::test {

inline std::string q(const std::string& s) { return "'" + s + "'"; }

inline std::set<std::string> entries(const std::filesystem::path& dir) {
    std::set<std::string> out;
    for (const auto& e : std::filesystem::directory_iterator(dir)) out.insert(e.path().filename().string());
    return out;
}

// A failed command: non-zero exit (not a crash), one line "tessera: error: ...".
inline void expect_one_line_error(const RunResult& r) {
    EXPECT_NE(r.exit_code, 0) << r.out;
    EXPECT_LT(r.exit_code, 128) << r.out;
    EXPECT_EQ(r.out.rfind("tessera: error: ", 0), 0u) << r.out;
    EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 1) << r.out;
}

// An image file's first three channels as 8-bit RGB, read by OpenImageIO (not by Tessera's own
// writers): empty if it cannot be read.
struct Rgb8Image {
    int width = 0, height = 0;
    std::vector<std::uint8_t> rgb;
    std::array<std::uint8_t, 3> at(int x, int y) const {
        const std::size_t i = (std::size_t(y) * width + x) * 3;
        return {rgb[i], rgb[i + 1], rgb[i + 2]};
    }
};

inline Rgb8Image read_png(const std::string& path) {
    Rgb8Image img;
    auto in = OIIO::ImageInput::open(path);
    if (!in) return img;
    img.width = in->spec().width;
    img.height = in->spec().height;
    img.rgb.resize(std::size_t(img.width) * img.height * 3);
    in->read_image(0, 0, 0, 3, OIIO::TypeDesc::UINT8, img.rgb.data());
    in->close();
    return img;
}

// Level-0 texels of an 8-bit store, tile by tile (decoded once each): the first three channels;
// of a multi-layer store, those of one layer.
class AtlasTexels {
public:
    explicit AtlasTexels(std::shared_ptr<storage::StoreReader> r, std::size_t layer = 0)
        : reader_(std::move(r)), layer_(layer), info_(storage::layer_store_info(reader_->info(), layer)) {}
    const storage::StoreInfo& info() const { return info_; }
    std::array<std::uint8_t, 3> at(std::uint32_t x, std::uint32_t y) {
        const storage::StoreInfo& s = info_;
        const std::uint32_t P = s.tile_payload, B = s.border, T = s.tile_size();
        const TileKey key{0, x / P, y / P};
        auto& tile = tiles_[{key.x, key.y}];
        if (tile.empty()) {
            auto t = reader_->read_tile(key);
            EXPECT_TRUE(t.ok());
            if (!t.ok()) return {};
            storage::Tile part = *t;
            if (reader_->info().layered() && t->kind == TileKind::present) {
                auto parts = storage::split_layers(reader_->info(), t->bytes);
                EXPECT_TRUE(parts.ok());
                if (!parts.ok() || layer_ >= parts->size()) return {};
                part = storage::layer_tile(key, (*parts)[layer_]);
            }
            EXPECT_TRUE(storage::decode_tile(s, part, tile).ok());
        }
        const std::size_t i = ((std::size_t(y % P) + B) * T + (x % P) + B) * s.channels;
        if (i + 2 >= tile.size()) return {};
        return {tile[i], tile[i + 1], tile[i + 2]};
    }

private:
    std::shared_ptr<storage::StoreReader> reader_;
    std::size_t layer_ = 0;
    storage::StoreInfo info_;
    std::map<std::pair<std::uint32_t, std::uint32_t>, std::vector<std::uint8_t>> tiles_;
};

}  // namespace tessera::test
