// Deep Zoom (DZI): /dzi/{name}.dzi describes the image, /dzi/{name}_files/{level}/{x}_{y}.{ext}
// are its tiles. DZI numbers levels from 1x1 (level 0) up to the full image (level
// ceil(log2(max(width, height)))), each half the next rounded up, as Tessera's levels are; a tile
// carries `Overlap` texels of its neighbours on each side except at the image's edges. Tessera's
// tiles are cut the same way with the border as the overlap, so a tile away from the edges is
// the stored tile itself: a JPEG store's interior tiles go out as stored, never re-encoded. Edge
// tiles are cropped, and levels smaller than the store's coarsest are area-averaged from it.
#include <nlohmann/json.hpp>

#include "apis.hpp"
#include "tessera/hex.hpp"

namespace tessera::server::httpapi {

namespace {

std::uint32_t dzi_max_level(const storage::StoreInfo& info) {
    const std::uint32_t side = std::max(info.width, info.height);
    std::uint32_t m = 0;
    while ((std::uint64_t(1) << m) < side) ++m;
    return m;
}

bool strip_suffix(std::string_view s, std::string_view suffix, std::string& out) {
    if (s.size() <= suffix.size() || !s.ends_with(suffix)) return false;
    out = std::string(s.substr(0, s.size() - suffix.size()));
    return true;
}

std::string dzi_xml(const storage::StoreInfo& info, const WebLook& look) {
    return "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
           "<Image xmlns=\"http://schemas.microsoft.com/deepzoom/2008\" TileSize=\"" +
           std::to_string(info.tile_payload) + "\" Overlap=\"" + std::to_string(info.border) + "\" Format=\"" +
           look.default_format + "\"><Size Width=\"" + std::to_string(info.width) + "\" Height=\"" +
           std::to_string(info.height) + "\"/></Image>\n";
}

}  // namespace

HttpResponse api_dzi(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route, bool borrow_payload) {
    const auto& seg = req.segments;
    std::string name;
    std::optional<std::uint64_t> version;
    HttpResponse failed;
    if (!pinned_version(req, version, failed)) return failed;

    if (seg.size() == 2 && strip_suffix(seg[1], ".dzi", name)) {
        route = HttpRoute::dzi_info;
        const auto store = find_web_store(handler, name, failed);
        if (!store) return failed;
        if (version && *version != store->handle->version)
            return error(404, "store version " + hex16(*version) + " is not served", false);
        HttpResponse r;
        r.content_type = "application/xml";
        r.body = dzi_xml(store->handle->info(), store->look);
        r.headers.emplace_back("Cache-Control", "no-cache");
        r.headers.emplace_back("X-Tessera-Store-Version", hex16(store->handle->version));
        return r;
    }
    if (seg.size() != 4 || !strip_suffix(seg[1], "_files", name))
        return error(404, "a Deep Zoom URL is /dzi/{name}.dzi or /dzi/{name}_files/{level}/{x}_{y}.{jpg|png}", false);
    route = HttpRoute::dzi_tile;
    const auto store = find_web_store(handler, name, failed);
    if (!store) return failed;
    const StoreHandle& h = *store->handle;
    if (version && *version != h.version) return error(404, "store version " + hex16(*version) + " is not served", false);
    const storage::StoreInfo& info = h.info();

    // {x}_{y}.{ext}
    const std::string& leaf = seg[3];
    const std::size_t us = leaf.find('_'), dot = leaf.rfind('.');
    if (us == std::string::npos || dot == std::string::npos || dot < us)
        return error(400, "a Deep Zoom tile is {x}_{y}.{jpg|png}", false);
    const auto level = parse_u32(seg[2]), x = parse_u32(std::string_view(leaf).substr(0, us)),
               y = parse_u32(std::string_view(leaf).substr(us + 1, dot - us - 1));
    std::string format = leaf.substr(dot + 1);
    if (format == "jpeg") format = "jpg";
    if (!level || !x || !y) return error(400, "level, x and y must be decimal integers (no leading zeros)", false);
    if (format != "jpg" && format != "png") return error(400, "a Deep Zoom tile is .jpg or .png, not ." + format, false);
    const std::uint32_t max_level = dzi_max_level(info);
    if (*level > max_level)
        return error(404, "level " + std::to_string(*level) + " out of range: levels 0.." + std::to_string(max_level), false);
    const std::uint32_t k = max_level - *level;  // the level's scale is 1 / 2^k
    const std::uint32_t w = scaled_size(info.width, k), hgt = scaled_size(info.height, k);
    const std::uint32_t P = info.tile_payload, O = info.border;
    const std::uint32_t cols = (w + P - 1) / P, rows = (hgt + P - 1) / P;
    if (*x >= cols || *y >= rows)
        return error(404, "tile (" + std::to_string(*x) + ", " + std::to_string(*y) + ") out of range at level " +
                              std::to_string(*level) + ": x in 0.." + std::to_string(cols - 1) + ", y in 0.." +
                              std::to_string(rows - 1), false);
    const auto span = [&](std::uint32_t i, std::uint32_t size, std::uint32_t& lo, std::uint32_t& hi) {
        lo = i * P > O ? i * P - O : 0;
        hi = std::min<std::uint64_t>(std::uint64_t(i + 1) * P + O, size);
    };
    std::uint32_t x0, x1, y0, y1;
    span(*x, w, x0, x1);
    span(*y, hgt, y0, y1);

    const WebAnswer answer{"dzi-" + std::to_string(*level) + "-" + std::to_string(*x) + "_" + std::to_string(*y) + "." + format,
                           format, version.has_value()};
    const std::shared_ptr<const StoreHandle> hs = store->handle;
    TileFetcher* fetcher = &handler.context().fetcher;
    const WebLook look = store->look;
    const std::uint32_t rw = x1 - x0, rh = y1 - y0;
    auto render = [fetcher, hs, look, k, x0, y0, rw, rh](WebFailure& failure) {
        return render_scaled(*fetcher, *hs, look, k, x0, y0, rw, rh, failure);
    };
    const std::size_t memory = render_memory(info, look, rw, rw, rh);

    // Away from the edges, the stored tile is the answer: as stored when the codec is the format.
    const bool whole = *x > 0 && *y > 0 && x1 - x0 == info.tile_size() && y1 - y0 == info.tile_size() &&
                       k < info.level_count();
    if (whole && format == "jpg" && info.codec == Codec::jpeg) {
        HttpHandler* hp = &handler;
        const bool head = req.raw->method == "HEAD";
        const bool pinned = version.has_value();
        const std::string if_none_match(req.raw->if_none_match);
        const TileKey key{k, *x, *y};
        // The stored tile's answer, or nullopt when it has to be rendered (uniform or absent). A
        // failed read is the answer too: the render would read the same tile and its neighbours
        // again, nine reads (with their retries) against a store that is failing.
        auto stored = [hp, hs, head, pinned, if_none_match, borrow_payload](const FetchedTile& f) -> std::optional<HttpResponse> {
            if (f.status != TileStatus::ok) return failure_response(fetch_failure(f));
            if (!f.tile || f.tile->kind != TileKind::present) return std::nullopt;
            const WebAnswer as_stored{"s" + hex16(f.tile->checksum) + ".jpg", "jpg", pinned};
            if (!if_none_match.empty() && if_none_match_matches(if_none_match, web_etag(*hs, as_stored)))
                return web_body_response(*hp, head, *hs, as_stored, nullptr);
            HttpResponse r = web_body_response(*hp, head, *hs, as_stored, nullptr);  // its headers, as a 304
            r.status = 200;
            r.content_type = "image/jpeg";
            if (borrow_payload) r.payload = f.tile;
            else r.body.assign(reinterpret_cast<const char*>(f.tile->bytes.data()), f.tile->bytes.size());
            if (!head) hp->count_served(*hs, r.body_size());
            return r;
        };
        if (auto hit = fetcher->cached(*hs, key)) {
            FetchedTile f;
            f.tile = std::move(hit);
            if (auto r = stored(f)) return std::move(*r);
        } else {
            // Not in RAM: the read (and, rarely, a render after it) off the loop.
            return defer(WorkKind::read, hs, 0, [hp, fetcher, hs, key, stored, answer, memory, render, head, if_none_match]() {
                {
                    const TileSlot slot = hp->tile_slot();  // the render below takes its own
                    if (!slot.ok()) return retry_later("too many tile requests in flight; retry", false);
                    if (auto r = stored(fetcher->fetch_one(*hs, key))) return std::move(*r);
                }
                HttpRequestView plain;
                plain.method = head ? "HEAD" : "GET";
                plain.if_none_match = if_none_match;
                // A small render runs here, on this read worker; a bigger one goes back to the
                // executor as a follow-up, admitted against the render budget like any render.
                HttpResponse r = web_image_response(*hp, plain, hs, answer, memory, render);
                if (r.deferred && r.deferred->kind == WorkKind::render) return r;
                return answer_in_place(std::move(r));
            });
        }
    }
    return web_image_response(handler, *req.raw, hs, answer, memory, render);
}

}  // namespace tessera::server::httpapi
