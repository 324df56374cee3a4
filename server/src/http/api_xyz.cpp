// XYZ tiles for Leaflet and OpenLayers in a plain (non-geographic) projection:
// /xyz/{name}/{z}/{x}/{y}.{jpg|png}. Zoom 0 is the store's coarsest level (the whole image in
// one tile); each zoom doubles until the finest level at zoom level_count - 1. Tiles are the
// store's tile payload square (tile_payload texels: set the client's tileSize to it), cut from
// the interior of the stored tiles; past the image's right and bottom edges they are transparent
// (PNG) or black (JPEG), so every tile has the full size clients assume.
#include "apis.hpp"
#include "tessera/hex.hpp"

namespace tessera::server::httpapi {

HttpResponse api_xyz(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route, bool) {
    const auto& seg = req.segments;
    if (seg.size() != 5) return error(404, "an XYZ tile URL is /xyz/{name}/{z}/{x}/{y}.{jpg|png}", false);
    route = HttpRoute::xyz_tile;
    std::optional<std::uint64_t> version;
    HttpResponse failed;
    if (!pinned_version(req, version, failed)) return failed;
    const auto store = find_web_store(handler, seg[1], failed);
    if (!store) return failed;
    const StoreHandle& h = *store->handle;
    if (version && *version != h.version) return error(404, "store version " + hex16(*version) + " is not served", false);
    const storage::StoreInfo& info = h.info();
    const std::size_t dot = seg[4].rfind('.');
    std::string format = dot == std::string::npos ? "" : seg[4].substr(dot + 1);
    if (format == "jpeg") format = "jpg";
    const auto z = parse_u32(seg[2]), x = parse_u32(seg[3]);
    const auto y = parse_u32(std::string_view(seg[4]).substr(0, dot));  // the whole leaf when there is no '.'
    if (!z || !x || !y) return error(400, "z, x and y must be decimal integers (no leading zeros)", false);
    if (format != "jpg" && format != "png") return error(400, "an XYZ tile is .jpg or .png", false);
    const std::uint32_t max_zoom = info.level_count() - 1;
    if (*z > max_zoom) return error(404, "zoom " + std::to_string(*z) + " out of range: 0.." + std::to_string(max_zoom), false);
    const std::uint32_t k = max_zoom - *z;
    const auto& l = info.levels[k];
    if (*x >= l.tiles_x || *y >= l.tiles_y)
        return error(404, "tile (" + std::to_string(*x) + ", " + std::to_string(*y) + ") out of range at zoom " +
                              std::to_string(*z) + ": x in 0.." + std::to_string(l.tiles_x - 1) + ", y in 0.." +
                              std::to_string(l.tiles_y - 1), false);
    const std::uint32_t P = info.tile_payload, x0 = *x * P, y0 = *y * P;
    const std::uint32_t w = std::min(P, l.width - x0), hgt = std::min(P, l.height - y0);
    const WebAnswer answer{"xyz-" + std::to_string(*z) + "-" + std::to_string(*x) + "-" + std::to_string(*y) + "." + format,
                           format, version.has_value()};
    const std::shared_ptr<const StoreHandle> hs = store->handle;
    TileFetcher* fetcher = &handler.context().fetcher;
    const WebLook look = store->look;
    const bool png = format == "png";
    auto render = [fetcher, hs, look, k, x0, y0, w, hgt, P, png](WebFailure& failure) -> std::optional<WebImage> {
        auto image = render_region(*fetcher, *hs, look, Region{k, x0, y0, w, hgt}, w, hgt, failure);
        if (!image) return image;
        if (png && (w < P || hgt < P)) *image = with_alpha(*image);  // transparent past the edges
        return pad_to(*image, P, P);
    };
    return web_image_response(handler, *req.raw, hs, answer, render_memory(info, look, w, P, P), render);
}

}  // namespace tessera::server::httpapi
