#pragma once
// The HTTP APIs, one file each, and what they share with the router (http_handler.cpp):
//   api_v1.cpp    /v1/stores, /v1/stores/{name}, /v1/stores/{name}/tiles/{level}/{x}/{y}
//   api_dzi.cpp   /dzi/{name}.dzi, /dzi/{name}_files/{level}/{x}_{y}.{jpg|png}
//   api_iiif.cpp  /iiif/{name}/info.json, /iiif/{name}/{region}/{size}/{rotation}/{quality}.{format}
//   api_xyz.cpp   /xyz/{name}/{z}/{x}/{y}.{jpg|png}
//   viewer.cpp    /, /view/{name}, /static/... (the web viewer and its OpenSeadragon)
// docs/server.md describes each.
#include <string>

#include "../http_handler.hpp"
#include "common.hpp"
#include "web_image.hpp"

namespace tessera::server::httpapi {

// An API answers the requests whose first path segment is its own. It sets `route` (the metric
// label) as soon as it knows which of its routes the request is for.
using ApiFn = HttpResponse (*)(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route, bool borrow_payload);

HttpResponse api_v1(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route, bool borrow_payload);
HttpResponse api_dzi(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route, bool borrow_payload);
HttpResponse api_iiif(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route, bool borrow_payload);
HttpResponse api_xyz(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route, bool borrow_payload);
HttpResponse viewer_index(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route, bool borrow_payload);
HttpResponse viewer_page(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route, bool borrow_payload);
HttpResponse viewer_static(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route, bool borrow_payload);

// A web image answer, shared by the DZI, IIIF and XYZ routes: the encoded image under an ETag
// made of the store version and `variant` (what was asked, so each URL has its own tag),
// cached in the handler's web tile cache, 304 on a matching If-None-Match, and the tile
// counters counted. `render` makes the image when it is not cached.
struct WebAnswer {
    std::string variant;     // e.g. "dzi-3-1_2.jpg": unique per representation within a store version
    std::string format;      // "jpg" or "png"
    bool immutable = false;  // the URL pins the store version
};
// `render` runs off the event loop (a deferred answer, charged `memory` bytes), so it must own
// what it uses: capture by value.
// A web image cut from a few stored tiles (a DZI, IIIF or XYZ tile: estimated at most
// kWebTileWorkBytes) is read work, bounded like a tile read and not held behind renders; anything
// bigger is a render, admitted against the render budget (docs/server.md, "Isolation").
inline constexpr std::size_t kWebTileWorkBytes = std::size_t(4) << 20;
inline WorkKind web_work_kind(std::size_t memory) {
    return memory <= kWebTileWorkBytes ? WorkKind::read : WorkKind::render;
}

// A web image's failure as the answer: 503 with Retry-After when it may pass, else the error.
inline HttpResponse failure_response(const WebFailure& failure) {
    if (failure.status == 503) return retry_later(failure.message, false);
    return error(failure.status, failure.message, false);
}

template <class Render>
HttpResponse web_image_response(HttpHandler& handler, const HttpRequestView& req, std::shared_ptr<const StoreHandle> store,
                                 const WebAnswer& answer, std::size_t memory, Render render);

// The response itself when `r` is deferred (in work already running off the loop).
HttpResponse answer_in_place(HttpResponse r);

// The store a web route names, or the error to answer: 400 for an invalid name, 404 unknown,
// 406 for samples a browser cannot show.
struct WebStore {
    std::shared_ptr<const StoreHandle> handle;
    WebLook look;
};
std::optional<WebStore> find_web_store(HttpHandler& handler, const std::string& name, HttpResponse& error_response);

// The one query parameter DZI and XYZ URLs take, ?v={version} (a store version pinned, as in
// /v1). False, with the 400 to answer in `failed`, for anything else.
bool pinned_version(const ParsedRequest& req, std::optional<std::uint64_t>& version, HttpResponse& failed);

// The encoded body behind an ETag: what web_image_response serves once it has the bytes.
HttpResponse web_body_response(HttpHandler& handler, bool head, const StoreHandle& store, const WebAnswer& answer,
                               std::shared_ptr<const std::string> body);
std::string web_etag(const StoreHandle& store, const WebAnswer& answer);
std::string web_cache_key(const StoreHandle& store, const WebAnswer& answer);

template <class Render>
HttpResponse web_image_response(HttpHandler& handler, const HttpRequestView& req, std::shared_ptr<const StoreHandle> store,
                                const WebAnswer& answer, std::size_t memory, Render render) {
    const bool head = req.method == "HEAD";
    const std::string etag = web_etag(*store, answer);
    if (!req.if_none_match.empty() && if_none_match_matches(req.if_none_match, etag))
        return web_body_response(handler, head, *store, answer, nullptr);
    const std::string key = web_cache_key(*store, answer);
    if (std::shared_ptr<const std::string> body = handler.web_cache().find(key))
        return web_body_response(handler, head, *store, answer, std::move(body));
    HttpHandler* hp = &handler;
    return defer(web_work_kind(memory), store, memory, [hp, store, answer, key, head, render]() -> HttpResponse {
        TileSlot slot = hp->tile_slot();
        if (!slot.ok()) return retry_later("too many tile requests in flight; retry", false);
        WebFailure failure;
        std::optional<WebImage> image = render(failure);
        if (!image) return failure_response(failure);
        std::optional<std::string> encoded = encode_web(*image, answer.format, failure);
        image.reset();
        if (!encoded) return error(failure.status, failure.message, false);
        auto body = std::make_shared<const std::string>(std::move(*encoded));
        hp->web_cache().insert(key, body);
        return web_body_response(*hp, head, *store, answer, std::move(body));
    });
}

}  // namespace tessera::server::httpapi
