#include "tessera/storage/coords_pattern.hpp"

#include <algorithm>

namespace tessera::storage {

void coords_tile(const StoreInfo& info, const TileKey& key, std::span<std::uint8_t> out) {
    const auto& level = info.levels[key.level];
    const std::uint32_t size = info.tile_size(), P = info.tile_payload, B = info.border;
    // Tile texel i covers level texel x0 + i, clamped to the level (borders, edge tiles).
    const std::int64_t x0 = std::int64_t(key.x) * P - B, y0 = std::int64_t(key.y) * P - B;
    std::uint8_t* p = out.data();
    for (std::uint32_t j = 0; j < size; ++j) {
        const auto y = static_cast<std::uint32_t>(std::clamp<std::int64_t>(y0 + j, 0, std::int64_t(level.height) - 1));
        for (std::uint32_t i = 0; i < size; ++i, p += 4) {
            const auto x = static_cast<std::uint32_t>(std::clamp<std::int64_t>(x0 + i, 0, std::int64_t(level.width) - 1));
            const auto texel = coords_texel(key.level, x, y);
            std::copy(texel.begin(), texel.end(), p);
        }
    }
}

}  // namespace tessera::storage
