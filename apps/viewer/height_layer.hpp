#pragma once
// The terrain's heights from a multi-layer store's `height` layer (docs/viewer.md, "Layers"): one
// level of it, fetched through the viewer's own tile source (a server or a file) before streaming
// starts, so that the ground the texture lies on is the ground its normals were made for.
#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>

#include "tessera/scene/scene.hpp"
#include "tessera/client/tile_source.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::tools {

// The layer that displaces the terrain: the one named "height" with one channel, if any.
std::optional<std::size_t> height_layer(const storage::StoreInfo& info);

struct HeightLayerRead {
    std::shared_ptr<const scene::HeightField> field;
    std::uint32_t level = 0;  // the store level read
    std::size_t tiles = 0;
};

// Reads layer `layer` of texture `texture` (bound to `source`) at the coarsest level at least
// `samples_across` samples wide (or level 0), every tile of it, within `timeout`. Samples become
// [0, 1]: u8 / 255, u16 / 65535, floats spread from their minimum to their maximum. Absent tiles
// read as 0. Tiles the server asks to retry (unavailable, overloaded, past their deadline) are
// asked for again. Leaves the source with no requests. Errors: a tile the source cannot deliver
// (its message), a part that does not decode, the timeout.
Result<HeightLayerRead> read_height_layer(client::TileSource& source, client::TextureId texture, const storage::StoreInfo& info,
                                          std::size_t layer, std::uint32_t samples_across,
                                          std::chrono::milliseconds timeout = std::chrono::seconds(30));

}  // namespace tessera::tools
