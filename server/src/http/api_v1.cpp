// Tessera's own API under /v1/: the list of stores, a store's metadata, and its tiles as stored
// (or decoded to PNG). docs/protocol.md, "HTTP".
#include <nlohmann/json.hpp>

#include "apis.hpp"
#include "tessera/hex.hpp"
#include "tessera/protocol/wire.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/layers.hpp"
#include "tessera/storage/png_encode.hpp"
#include "tessera/storage/store_json.hpp"

namespace tessera::server::httpapi {

namespace {

std::string_view content_type_of(Codec c) {
    switch (c) {
        case Codec::jpeg: return "image/jpeg";
        case Codec::zstd:
        case Codec::bc1:
        case Codec::bc4:
        case Codec::bc5:
        case Codec::bc7: return "application/zstd";
        case Codec::raw: return "application/octet-stream";
        case Codec::layers: return "application/x-tessera-layers";
    }
    return "application/octet-stream";
}

// The store's description (storage::store_json), and where the API serves it and its tiles.
nlohmann::json store_entry(const StoreHandle& h, const std::string& prefix) {
    nlohmann::json j = storage::store_json(h.name, h.info());
    const std::string url = prefix + "/v1/stores/" + h.name;
    j["url"] = url;
    j["tiles"] = url + "/tiles/{level}/{x}/{y}?v=" + hex16(h.version);
    j["scene"] = h.has_scene.load(std::memory_order_relaxed);  // an atlas OBJ travels with it (gRPC GetStoreScene)
    return j;
}

// A tile's answer once the request is validated: everything it needs held by value, so that it
// can run on the event loop (a RAM cache hit) or on the executor (a read, a PNG).
struct TileAnswer {
    HttpHandler* handler = nullptr;
    std::shared_ptr<const StoreHandle> h;
    std::string name;
    TileKey key;
    bool png = false;
    std::size_t layer = 0;
    // Values held in place (HeaderValue): a RAM cache hit's answer allocates no header.
    HeaderValue version_hex, cache;
    std::string png_tag, if_none_match;
    bool head = false, borrow_payload = false;

    // "VERSION-CHECKSUM[PNG_TAG]", quoted.
    HeaderValue etag_of(std::uint64_t checksum) const {
        char buf[2 + 16 + 1 + 16];
        char* p = buf;
        *p++ = '"';
        const std::string_view v = version_hex;
        p = std::copy(v.begin(), v.end(), p);
        *p++ = '-';
        p = hex16_to(p, checksum);
        if (png_tag.empty()) {
            *p++ = '"';
            return HeaderValue(std::string_view(buf, std::size_t(p - buf)));
        }
        return HeaderValue(std::string(buf, p) + png_tag + "\"");
    }
    static HeaderValue hex_value(std::uint64_t v) {
        char buf[16];
        return HeaderValue(std::string_view(buf, std::size_t(hex16_to(buf, v) - buf)));
    }
    void common_headers(HttpResponse& r, TileKind kind, std::string_view codec) const {
        r.headers.emplace_back("Cache-Control", cache);
        r.headers.emplace_back("X-Tessera-Store-Version", version_hex);
        r.headers.emplace_back("X-Tessera-Kind", tessera::to_string(kind));
        if (!codec.empty()) r.headers.emplace_back("X-Tessera-Codec", codec);
    }
    HttpResponse not_modified(TileKind kind, const HeaderValue& etag) const {
        HttpResponse r;
        r.status = 304;
        r.headers.emplace_back("ETag", etag);
        common_headers(r, kind, {});
        return r;
    }

    // Off the loop: a 304 from the index alone, else the tile read (cache, then the store).
    HttpResponse read() const {
        constexpr bool api = true;
        // Bound the tile requests served at once (config.max_http_inflight).
        const TileSlot slot = handler->tile_slot();
        if (!slot.ok()) return retry_later("too many tile requests in flight; retry", api);
        // Revalidation from the index alone (the entry holds the payload's checksum): a 304 costs
        // no payload read. An entry that locates but whose payload is corrupt still answers 304
        // here; the client holds bytes that passed the checksum when they were served.
        if (!if_none_match.empty()) {
            const auto loc = h->reader->locate(key);
            if (loc.ok() && loc->kind != TileKind::absent) {
                const HeaderValue etag = etag_of(loc->checksum);
                if (if_none_match_matches(if_none_match, etag)) return not_modified(loc->kind, etag);
            }
        }
        return with(handler->context().fetcher.fetch_one(*h, key));
    }

    HttpResponse with(const FetchedTile& fetched) const {
        constexpr bool api = true;
        const storage::StoreInfo& info = h->info();
        switch (fetched.status) {
            case TileStatus::ok: break;
            case TileStatus::data_loss: return error(500, "tile failed its checksum", api);
            case TileStatus::not_found: return error(404, "unknown store '" + name + "'", api);
            case TileStatus::out_of_range: return error(404, "tile out of range: " + fetched.message, api);
            case TileStatus::deadline_exceeded: return error(504, "tile unavailable: " + fetched.message, api);
            case TileStatus::resource_exhausted:
            case TileStatus::unavailable: return retry_later("tile unavailable: " + fetched.message, api);
            default: return error(500, "tile read failed: " + fetched.message, api);
        }
        if (!fetched.tile) return error(500, "tile read failed: no tile returned", api);
        const storage::Tile& t = *fetched.tile;
        if (t.kind == TileKind::absent) {
            // A definite answer for this store version, so it is cacheable like a tile.
            HttpResponse r = error(404, "tile absent in a sparse store", api);
            r.headers.clear();
            common_headers(r, TileKind::absent, {});
            return r;
        }

        const HeaderValue etag = etag_of(t.checksum);
        if (!if_none_match.empty() && if_none_match_matches(if_none_match, etag)) return not_modified(t.kind, etag);

        HttpResponse r;
        r.status = 200;
        r.headers.reserve(8);  // these, CORS and Server: one allocation
        r.headers.emplace_back("ETag", etag);
        if (png) {
            const storage::StoreInfo shown = info.layered() ? storage::layer_store_info(info, layer) : storage::StoreInfo{};
            const storage::StoreInfo& png_info = info.layered() ? shown : info;
            // A bundle's part of the shown layer, as a tile of that layer.
            storage::Tile part;
            const storage::Tile* decoded = &t;
            TileKind kind = t.kind;
            if (info.layered()) {
                auto parts = storage::split_layers(info, t.bytes);
                if (!parts) return error(500, "tile bundle does not split into the store's layers: " + parts.error().message, api);
                const storage::LayerPart& p = (*parts)[layer];
                if (p.kind == TileKind::absent) {
                    // As definite (and as cacheable) as an absent tile.
                    HttpResponse a = error(404, "layer '" + info.layers[layer].name + "' of this tile is absent", api);
                    a.headers.clear();
                    common_headers(a, TileKind::absent, {});
                    a.headers.emplace_back("X-Tessera-Layer", info.layers[layer].name);
                    return a;
                }
                part = storage::layer_tile(t.key, p);
                decoded = &part;
                kind = p.kind;
                r.headers.emplace_back("X-Tessera-Layer", info.layers[layer].name);
            }
            std::vector<std::uint8_t> texels;
            if (const Status s = storage::decode_tile(png_info, *decoded, texels); !s.ok())
                return error(500, "tile does not decode: " + s.error().message, api);
            auto encoded = storage::encode_tile_png(png_info, texels);
            if (!encoded.ok())
                return error(encoded.error().code == Errc::unsupported ? 406 : 500, encoded.error().message, api);
            r.content_type = "image/png";
            r.body.assign(reinterpret_cast<const char*>(encoded->data()), encoded->size());
            common_headers(r, kind, "png");
        } else {
            r.content_type = t.kind == TileKind::uniform ? "application/octet-stream" : std::string(content_type_of(info.codec));
            if (borrow_payload) r.payload = fetched.tile;
            else r.body.assign(reinterpret_cast<const char*>(t.bytes.data()), t.bytes.size());
            common_headers(r, t.kind, t.kind == TileKind::uniform ? "uniform" : tessera::to_string(info.codec));
            r.headers.emplace_back("X-Tessera-Checksum", hex_value(t.checksum));
        }
        if (!head) handler->count_served(*h, r.body_size());
        return r;
    }
};

HttpResponse tile(HttpHandler& handler, const HttpRequestView& req, std::string_view name, std::string_view level_s,
                  std::string_view x_s, std::string_view y_s, bool png, const std::optional<std::string>& layer_name,
                  bool has_version, std::uint64_t want_version, bool borrow_payload) {
    ServerContext& ctx_ = handler.context();
    constexpr bool api = true;
    if (!protocol::valid_store_name(name)) return error(400, "invalid store name", api);
    if (layer_name && !png)
        return error(400, "query parameter 'layer' picks the layer format=png shows; the stored payload holds every layer", api);
    const auto level = parse_u32(level_s), x = parse_u32(x_s), y = parse_u32(y_s);
    if (!level || !x || !y)
        return error(400, "level, x and y must be decimal integers below 2^32 (digits only, no leading zeros)", api);

    const std::shared_ptr<const StoreHandle> h = ctx_.stores.find(name);
    if (!h) return error(404, "unknown store '" + std::string(name) + "'", api);
    const storage::StoreInfo& info = h->info();
    if (h->metrics.requests) h->metrics.requests->inc();
    const HeaderValue version_hex = TileAnswer::hex_value(h->version);

    // A pinned version that is not the one served: 404, not 409 or a redirect. The URL names a
    // representation this server does not have (versions are content hashes; an old one is gone
    // for good unless the same file comes back). The client refetches the store metadata and
    // uses the new version; caches may not keep this answer (no-store, as every error).
    if (has_version && want_version != h->version)
        return error(404, "store version " + hex16(want_version) + " is not served (current " + version_hex.str() + ")", api);

    if (*level >= info.level_count())
        return error(404, "level " + std::to_string(*level) + " out of range: the store has levels 0.." +
                              std::to_string(info.level_count() - 1), api);
    const storage::LevelInfo& li = info.levels[*level];
    if (*x >= li.tiles_x || *y >= li.tiles_y)
        return error(404, "tile (" + std::to_string(*x) + ", " + std::to_string(*y) + ") out of range at level " +
                              std::to_string(*level) + ": x in 0.." + std::to_string(li.tiles_x - 1) +
                              ", y in 0.." + std::to_string(li.tiles_y - 1), api);
    // A multi-layer store's PNG shows one layer: ?layer=NAME, else layer 0.
    std::size_t layer = 0;
    if (layer_name) {
        if (!info.layered()) return error(400, "store '" + std::string(name) + "' has no layers", api);
        while (layer < info.layers.size() && info.layers[layer].name != *layer_name) ++layer;
        if (layer == info.layers.size()) {
            std::string names;
            for (const auto& l : info.layers) names += (names.empty() ? "" : ", ") + l.name;
            return error(400, "unknown layer '" + *layer_name + "': store '" + std::string(name) + "' has layers " + names, api);
        }
    }
    const storage::StoreInfo shown = png && info.layered() ? storage::layer_store_info(info, layer) : storage::StoreInfo{};
    const storage::StoreInfo& png_info = info.layered() ? shown : info;
    if (png && (png_info.sample_type == storage::SampleType::f16 || png_info.sample_type == storage::SampleType::f32))
        return error(406, "format=png is not available for " + std::string(storage::to_string(png_info.sample_type)) +
                              (info.layered() ? " layers" : " stores") + " (PNG has no float samples); fetch the stored payload",
                     api);

    TileAnswer a;  // on the stack: a RAM cache hit is answered here without allocating it
    a.handler = &handler;
    a.h = h;
    a.name = std::string(name);
    a.key = TileKey{*level, *x, *y};
    a.png = png;
    a.layer = layer;
    a.version_hex = version_hex;
    a.png_tag = !png ? "" : info.layered() ? "-png-" + info.layers[layer].name : "-png";
    a.cache = cache_control(ctx_, has_version);
    a.if_none_match = std::string(req.if_none_match);
    a.head = req.method == "HEAD";
    a.borrow_payload = borrow_payload;

    // A stored payload the RAM cache holds is answered on the loop; anything else (a read, a
    // PNG to encode) goes to the executor.
    if (!png) {
        if (auto hit = ctx_.fetcher.cached(*h, a.key)) {
            const TileSlot slot = handler.tile_slot();
            if (!slot.ok()) return retry_later("too many tile requests in flight; retry", api);
            FetchedTile f;
            f.tile = std::move(hit);
            return a.with(f);
        }
        return defer(WorkKind::read, h, 0, [a = std::make_shared<const TileAnswer>(std::move(a))] { return a->read(); });
    }
    // A PNG: one tile decoded (samples) and encoded (about as large again), twice for a bundle.
    const std::size_t T = info.tile_size();
    const std::size_t memory = T * T * std::max<std::size_t>(1, png_info.channels) * 4 * 3;
    return defer(WorkKind::render, h, memory, [a = std::make_shared<const TileAnswer>(std::move(a))] { return a->read(); });
}

}  // namespace

HttpResponse api_v1(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route_label, bool borrow_payload) {
    constexpr bool api = true;
    ServerContext& ctx = handler.context();
    const auto& seg = req.segments;
    // Query: only `format` (png), `v` (store version, hex) and `layer` (which layer of a
    // multi-layer store a PNG shows) are known, each at most once.
    if (const std::string unknown = req.unknown_params({"format", "v", "layer"}); !unknown.empty())
        return error(400, "unknown query parameter " + unknown + " (known: format, v, layer)", api);
    bool twice = false;
    const std::optional<std::string> format = req.param("format", &twice);
    const std::optional<std::string> version_s = req.param("v", &twice);
    const std::optional<std::string> layer = req.param("layer", &twice);
    if (twice) return error(400, "a query parameter is given twice", api);
    if (format && *format != "png") return error(400, "unknown format '" + *format + "': the only format is png", api);
    std::optional<std::uint64_t> version;
    if (version_s) {
        version = parse_version(*version_s);
        if (!version) return error(400, "query parameter 'v' must be the store version in hex", api);
    }

    if (seg.size() < 2 || seg[1] != "stores") {
        route_label = HttpRoute::other;
        return error(404, "no such route: " + std::string(req.path), api);
    }
    if (seg.size() == 2) {
        route_label = HttpRoute::stores;
        if (format || version || layer) return error(400, "query parameters 'format', 'v' and 'layer' apply to tiles only", api);
        nlohmann::json list = nlohmann::json::array();
        for (const auto& h : ctx.stores.list()) list.push_back(store_entry(*h, public_path(ctx.config.public_url)));
        return json_response(nlohmann::json{{"stores", std::move(list)}});
    }
    const std::string& name = seg[2];
    if (seg.size() == 3) {
        route_label = HttpRoute::store;
        if (!protocol::valid_store_name(name)) return error(400, "invalid store name", api);
        if (format || version || layer) return error(400, "query parameters 'format', 'v' and 'layer' apply to tiles only", api);
        const auto h = ctx.stores.find(name);
        if (!h) return error(404, "unknown store '" + name + "'", api);
        return json_response(store_entry(*h, public_path(ctx.config.public_url)));
    }
    if (seg[3] != "tiles") {
        route_label = HttpRoute::other;
        return error(404, "no such route: " + std::string(req.path), api);
    }
    route_label = format ? HttpRoute::tile_png : HttpRoute::tile;
    if (seg.size() != 7) return error(400, "a tile URL is /v1/stores/{name}/tiles/{level}/{x}/{y}", api);
    return tile(handler, *req.raw, name, seg[4], seg[5], seg[6], format.has_value(), layer, version.has_value(),
                version.value_or(0), borrow_payload);
}

}  // namespace tessera::server::httpapi
