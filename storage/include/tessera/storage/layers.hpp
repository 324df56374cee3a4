#pragma once
// Multi-layer stores (docs/store-format.md, "Layers"): a tile of a layered store is one bundle
// holding each layer's part in its layer's own codec, so a page's layers travel, are cached and are
// made resident together. These functions split a bundle into its parts and make one.
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>
#include "tessera/result.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::storage {

// A layered store has 2 to 16 layers, named by 1 to 31 bytes of [a-z0-9_-].
inline constexpr std::size_t kMinLayers = 2;
inline constexpr std::size_t kMaxLayers = 16;
inline constexpr std::size_t kMaxLayerNameBytes = 31;

// Why `name` cannot name a layer; empty when it can.
std::string layer_name_misfit(std::string_view name);

// Why these layers cannot make a store with this tile geometry (count, names, duplicate names,
// channels, alpha, a codec that is `layers` or does not fit the layer's samples); empty when they
// can. The writer refuses such a spec, the reader such a file, with this message.
std::string layers_misfit(std::span<const LayerInfo> layers, std::uint32_t tile_size, std::uint32_t border);

// One layer's part of a bundle: present (a payload in the layer's codec), uniform (one texel
// value of the layer's samples) or absent (no bytes; a viewer shows the parent page).
struct LayerPart {
    TileKind kind = TileKind::absent;
    std::span<const std::uint8_t> bytes;
};

// Layer `layer` of a layered store described as a single-layer store: the store's geometry with
// the layer's samples and codec. decode_tile() and the client's transcoder take it for that
// layer's parts. A single-layer store's only layer (layer 0) is the store itself.
StoreInfo layer_store_info(const StoreInfo& info, std::size_t layer);

// The number of layers a store's tiles hold: info.layers.size(), or 1 for a single-layer store.
inline std::size_t layer_count(const StoreInfo& info) { return info.layered() ? info.layers.size() : 1; }

// Splits a bundle into exactly info.layers.size() parts (views into `bundle`). Corrupt when the
// bundle's table does not match the store's layers, or its lengths do not add up to its size.
Result<std::vector<LayerPart>> split_layers(const StoreInfo& info, std::span<const std::uint8_t> bundle);

// One part as a Tile (for decode_tile with layer_store_info()).
Tile layer_tile(const TileKey& key, const LayerPart& part);

// The bundle of `parts`, in layer order (the builder's side of split_layers).
std::vector<std::uint8_t> join_layers(std::span<const LayerPart> parts);

}  // namespace tessera::storage
