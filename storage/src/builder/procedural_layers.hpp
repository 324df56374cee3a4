#pragma once
// Layers to go with the procedural terrain's colour (procedural:terrain:SIZE), made from the very
// height field its colours show, for multi-layer stores (tessera build --layer):
//   procedural:terrain-height:SIZE  1 channel u16, linear: the height field, [-1, 1] -> 0..65535
//   procedural:terrain-normal:SIZE  2 channels u8, linear: the unit surface normal's x and y,
//                                   [-1, 1] -> 0..255 (z = sqrt(1 - x^2 - y^2), facing up)
// Both stream rows like the colour source: memory is bounded by the width, not the area.
#include <cstdint>
#include <memory>

#include "tessera/storage/image_source.hpp"

namespace tessera::storage::build {

// The relief the normals assume: a height h (the field's value, in [-1, 1]) stands
// h * size * kTerrainReliefPerSize level-0 texels above the sea, so the full range of the height
// layer (0 to 65535) spans 2 * size * kTerrainReliefPerSize texels. Relative to the size, so that
// the terrain's slopes look the same at any size (its coarse octaves scale with the size).
inline constexpr float kTerrainReliefPerSize = 0.0625f;

std::unique_ptr<ImageSource> make_terrain_height_source(std::uint32_t size);
std::unique_ptr<ImageSource> make_terrain_normal_source(std::uint32_t size);

// The samples those sources hold, from heights (exposed for tests).
std::uint16_t terrain_height_sample(float h);
std::uint8_t terrain_normal_sample(float component);  // [-1, 1] -> 0..255

}  // namespace tessera::storage::build
