#pragma once
// Layers to go with the procedural terrain's colour (procedural:terrain:SIZE), made from the very
// height field its colours show, for multi-layer stores (tessera build --layer):
//   procedural:terrain-height:SIZE  1 channel u16, linear: the height field, [-1, 1] -> 0..65535
//   procedural:terrain-normal:SIZE  2 channels u8, linear: the unit surface normal's x and y,
//                                   [-1, 1] -> 0..255 (z = sqrt(1 - x^2 - y^2), facing up)
// Both stream rows like the colour source: memory is bounded by the width, not the area.
#include <cstdint>
#include <memory>

#include "tessera/storage/builder.hpp"  // kTerrainReliefPerSize: the relief the normals assume
#include "tessera/storage/image_source.hpp"

namespace tessera::storage::build {

std::unique_ptr<ImageSource> make_terrain_height_source(std::uint32_t size);
std::unique_ptr<ImageSource> make_terrain_normal_source(std::uint32_t size);

// The samples those sources hold, from heights (exposed for tests).
std::uint16_t terrain_height_sample(float h);
std::uint8_t terrain_normal_sample(float component);  // [-1, 1] -> 0..255

}  // namespace tessera::storage::build
