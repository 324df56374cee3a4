#pragma once
// Images for browsers, cut from a store's pyramid: the tiles and regions that the Deep Zoom,
// IIIF and XYZ endpoints serve (docs/server.md, "Browsers"). Stored tiles carry a border and
// overlap their neighbours; web tiles are crops of them, and any other region is assembled from
// the pyramid level just finer than asked and area-averaged down (work per request bounded by
// its output size: at most about 4x the output's texels are decoded).
#include <cstdint>
#include <list>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "../store_registry.hpp"
#include "../tile_fetcher.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::server::httpapi {

// 8-bit texels for a browser: 1 (grey), 2 (grey + alpha), 3 (RGB) or 4 (RGBA, alpha straight).
struct WebImage {
    std::uint32_t width = 0, height = 0, channels = 0;
    std::vector<std::uint8_t> texels;  // rows top to bottom, interleaved
};

// How a store's samples are shown: layer 0 of a layered store; 8-bit samples as they are; 16-bit
// scaled to 8 bits; two channels without alpha as red and green. Float samples cannot be shown
// (`refused` says why). Also the format a web tile uses by default: JPEG for JPEG stores, PNG
// otherwise (lossless stays lossless; alpha kept).
struct WebLook {
    storage::StoreInfo info;  // of the layer shown
    std::size_t layer = 0;
    std::uint32_t channels = 0;  // of the WebImage
    bool has_alpha = false;
    std::string refused;  // non-empty: this store has no web view
    std::string default_format;  // "jpg" or "png"
};
WebLook web_look(const storage::StoreInfo& info);

// A failure with its HTTP status (404 out of range, 500 unreadable tile, 503 try again).
struct WebFailure {
    unsigned status = 500;
    std::string message;
};

// The status and message a failed tile read answers with.
WebFailure fetch_failure(const FetchedTile& f);

// The texels [x, x + w) x [y, y + h) of pyramid level `level` (in that level's texels, inside
// it), scaled to out_w x out_h: a copy when the sizes match, area-averaging (alpha-weighted)
// when smaller, bilinear when larger. Absent tiles of a sparse store are transparent black.
struct Region {
    std::uint32_t level = 0, x = 0, y = 0, w = 0, h = 0;
};
// `window`: the part of the region the output shows, in region texels, when it starts or ends
// inside a texel (a crop finer than the level's texels); default the whole region.
struct SourceWindow {
    double x = 0, y = 0, w = 0, h = 0;
};
std::optional<WebImage> render_region(TileFetcher& fetcher, const StoreHandle& store, const WebLook& look,
                                      const Region& region, std::uint32_t out_w, std::uint32_t out_h,
                                      WebFailure& failure, std::optional<SourceWindow> window = std::nullopt);

// The whole image at scale 1/2^k for any k (levels past the store's coarsest are area-averaged
// from it): the rectangle of level-k texels [x, x + w) x [y, y + h) rendered at its own size.
std::optional<WebImage> render_scaled(TileFetcher& fetcher, const StoreHandle& store, const WebLook& look,
                                      std::uint32_t k, std::uint32_t x, std::uint32_t y, std::uint32_t w,
                                      std::uint32_t h, WebFailure& failure);

// About the peak bytes a render holds: one row of source tiles decoded (texels and samples),
// the resampler's rows, the output image and the two copies post-processing and encoding make.
// What admission charges a render against --render-memory.
std::size_t render_memory(const storage::StoreInfo& info, const WebLook& look, std::uint32_t region_w,
                          std::uint32_t out_w, std::uint32_t out_h);

// The texels [begin, end) of the range [start, start + length) that tile `tile` holds (tiles of
// `payload` texels), in 64-bit arithmetic: a canvas may be 2^32 - 1 texels wide, and the end of
// its last tile is past 2^32. Empty (begin == end) when the tile holds none of them.
struct TileSpan {
    std::uint32_t begin = 0, end = 0;
};
TileSpan tile_span(std::uint32_t start, std::uint32_t length, std::uint32_t tile, std::uint32_t payload);

// Width or height of the image at scale 1/2^k, as the store's levels round: ceil(size / 2^k).
std::uint32_t scaled_size(std::uint32_t size, std::uint32_t k);

// Post-processing for IIIF: grey (Rec. 709 luma), a quarter turn clockwise n times, mirroring.
WebImage to_grey(const WebImage& image);
WebImage rotate_quarters(const WebImage& image, unsigned quarters);
WebImage mirror(const WebImage& image);
// The same texels with an opaque alpha channel added (grey -> grey + alpha, RGB -> RGBA).
WebImage with_alpha(const WebImage& image);
// Pastes `image` at the top left of a width x height canvas of zeros (transparent or black).
WebImage pad_to(const WebImage& image, std::uint32_t width, std::uint32_t height);

// Encodes to "jpg" (quality 90, alpha dropped) or "png". nullopt with `failure` set on error.
std::optional<std::string> encode_web(const WebImage& image, std::string_view format, WebFailure& failure);

// Encoded web tiles by URL and store version, least recently used first out, bounded in bytes
// (config.web_cache_bytes; 0: off). Thread-safe.
class WebTileCache {
public:
    explicit WebTileCache(std::size_t capacity_bytes) : capacity_(capacity_bytes) {}
    std::shared_ptr<const std::string> find(const std::string& key);
    void insert(const std::string& key, std::shared_ptr<const std::string> body);
    std::size_t bytes() const;

private:
    struct Entry {
        std::string key;
        std::shared_ptr<const std::string> body;
    };
    const std::size_t capacity_;
    mutable std::mutex mutex_;
    std::list<Entry> lru_;  // front: most recent
    std::unordered_map<std::string, std::list<Entry>::iterator> index_;
    std::size_t bytes_ = 0;
};

}  // namespace tessera::server::httpapi
