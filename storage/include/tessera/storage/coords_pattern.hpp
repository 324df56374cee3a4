#pragma once
// The "coords" test pattern: every texel of every level says where it is, so a wrong texel, page
// or level shows. The client's on-demand source (procedural:coords) and the builder's sparse
// source (procedural:coords-sparse) make the same tiles from it.
#include <array>
#include <cstdint>
#include <span>

#include "tessera/storage/types.hpp"

namespace tessera::storage {

// RGBA8 texel (x, y) of level `level`: the low 12 bits of x and y (R = x bits 0..7, G = y bits
// 0..7, B = x bits 8..11 | y bits 8..11 << 4) XORed with three bytes hashed from (level, x >> 12,
// y >> 12); alpha 255. Any other texel of any level differs from it (barring a 2^-24 hash
// collision between two 4096-texel regions). Levels are not filtered from each other (level L is
// the formula at level-L coordinates): a pattern for exactness tests, not a mip pyramid to look at.
constexpr std::array<std::uint8_t, 4> coords_texel(std::uint32_t level, std::uint32_t x, std::uint32_t y) {
    // splitmix64 of the (injective) packing of level and region.
    std::uint64_t h = ((std::uint64_t(level) << 48) ^ (std::uint64_t(x >> 12) << 24) ^ std::uint64_t(y >> 12)) +
                      0x9e3779b97f4a7c15ull;
    h = (h ^ (h >> 30)) * 0xbf58476d1ce4e5b9ull;
    h = (h ^ (h >> 27)) * 0x94d049bb133111ebull;
    h ^= h >> 31;
    return {std::uint8_t((x & 255) ^ (h & 255)), std::uint8_t((y & 255) ^ ((h >> 8) & 255)),
            std::uint8_t((((x >> 8) & 15) | (((y >> 8) & 15) << 4)) ^ ((h >> 16) & 255)), 255};
}

// Tile `key` of a store of `info`'s geometry in the coords pattern: tile_size()^2 RGBA8 texels,
// rows top to bottom; borders and the part of an edge tile past the level's edge repeat the edge
// texel, as the builder does. `out` must hold tile_size()^2 * 4 bytes.
void coords_tile(const StoreInfo& info, const TileKey& key, std::span<std::uint8_t> out);

}  // namespace tessera::storage
