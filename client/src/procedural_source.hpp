#pragma once
// A TileSource that makes tiles on demand from a formula instead of reading a store, so a virtual
// texture of up to 2^24 texels per side (storage::kMaxProceduralSize) streams through the whole
// runtime with no file: a 2^24 store cannot be built (the builder reads every source row), and
// procedural:terrain (`tessera build`) only renders whole rows.
//
// Store spec (what bind() takes):  procedural:coords:SIZE[:TILE_SIZE[:BORDER]]
//   SIZE       texels per side, 1 .. 2^24 (square)
//   TILE_SIZE  stored texels per side, a power of two from 64 to 1024 (default 256)
//   BORDER     texels of the neighbours on each side, even, at most TILE_SIZE / 4 (default 4)
// The geometry is a store's (storage::level_geometry): RGBA8, linear, raw codec; borders and the
// part of an edge tile past the level's edge repeat the edge texel, as the builder does. Anything
// else is an invalid_argument error that names the spec and the rule.
//
// The "coords" pattern: texel (x, y) of level L is coords_texel(L, x, y), a function of its own
// level and coordinates only. Levels are not filtered from each other (level L is the formula at
// level-L coordinates), so it is a pattern for exactness tests and streaming benchmarks, not a mip
// pyramid to look at.
#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

#include "tessera/client/tile_source.hpp"
#include "tessera/result.hpp"
#include "tessera/storage/coords_pattern.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::client {

// The pattern's texels (tessera/storage/coords_pattern.hpp): the store builder's sparse source
// makes the same tiles.
using storage::coords_texel;

// The geometry a spec describes (StoreInfo as bind() returns it), or invalid_argument.
Result<storage::StoreInfo> procedural_store_info(const std::string& spec);

// Makes tiles of procedural:coords:... textures. `threads` workers serve the newest request set,
// highest priority first; at most `max_buffered` made tiles wait to be polled.
std::unique_ptr<TileSource> make_procedural_source(unsigned threads = 1, std::size_t max_buffered = 64);

}  // namespace tessera::client
