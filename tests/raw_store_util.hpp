#pragma once
// A small raw RGB store for server tests that read it through a source of their own (a gate, an
// origin that does not answer): every tile present, each filled with one value.
#include <cstdint>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "tessera/storage/codec.hpp"
#include "tessera/storage/store_writer.hpp"
#include "test_util.hpp"

namespace tessera::test {

// A `size` x `size` RGB raw store with tiles of `tile` texels, written in `dir`; its bytes. Tile
// (l, x, y) holds the value l * 50 + y * row + x in every sample.
inline std::vector<std::uint8_t> raw_store_bytes(const ScratchDir& dir, std::uint32_t size, std::uint32_t tile, std::uint32_t row) {
    storage::StoreSpec s;
    s.width = s.height = size;
    s.tile_payload = tile;
    s.channels = 3;
    s.codec = Codec::raw;
    const std::string path = dir.file("s.tsr");
    auto w = storage::StoreWriter::create(path, s);
    EXPECT_TRUE(w.ok());
    const storage::StoreInfo info = storage::store_info(s);
    for (std::uint32_t l = 0; l < info.level_count(); ++l)
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                std::vector<std::uint8_t> texels(info.tile_bytes(), static_cast<std::uint8_t>(l * 50 + y * row + x));
                auto payload = storage::encode_tile(info, texels, {});
                EXPECT_TRUE((*w)->add_present({l, x, y}, *payload).ok());
            }
    EXPECT_TRUE((*w)->finish().ok());
    return read_file(path);
}

}  // namespace tessera::test
