#pragma once
// Files built into the server for its web viewer: OpenSeadragon's script, images and licence,
// from the npm package tools/setup.sh installs under server/web (cmake/embed_files.cmake).
#include <cstddef>
#include <string_view>

namespace tessera::server::httpapi {

struct WebAsset {
    std::string_view path;          // under /static/, e.g. "openseadragon/openseadragon.min.js"
    std::string_view content_type;
    const unsigned char* data;
    std::size_t size;
};
extern const WebAsset kWebAssets[];
extern const std::size_t kWebAssetCount;  // 0 when the package was not installed at build time

}  // namespace tessera::server::httpapi
