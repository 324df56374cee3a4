// The web viewer: / lists the stores, /view/{name} shows one in OpenSeadragon over the Deep Zoom
// endpoint, /static/... serves OpenSeadragon itself, built into the server (http/web_assets.hpp):
// the browser fetches nothing from anywhere else.
#include <xxhash.h>

#include "apis.hpp"
#include "http/web_assets.hpp"
#include "tessera/hex.hpp"
#include "tessera/protocol/wire.hpp"

namespace tessera::server::httpapi {

namespace {

constexpr std::string_view kHtml = "text/html; charset=utf-8";
constexpr std::string_view kOsd = "openseadragon/openseadragon.min.js";

HttpResponse html(unsigned status, std::string body) {
    HttpResponse r;
    r.status = status;
    r.content_type = kHtml;
    r.body = std::move(body);
    r.headers.emplace_back("Cache-Control", "no-cache");
    // The page runs only its own script and OpenSeadragon, both from this server.
    r.headers.emplace_back("Content-Security-Policy",
                           "default-src 'self'; script-src 'self' 'unsafe-inline'; style-src 'self' 'unsafe-inline'; "
                           "img-src 'self' data: blob:; connect-src 'self'");
    return r;
}

const WebAsset* find_asset(std::string_view path) {
    for (std::size_t i = 0; i < kWebAssetCount; ++i)
        if (kWebAssets[i].path == path) return &kWebAssets[i];
    return nullptr;
}

// What the page tells its user about how the samples are shown (web_look).
std::string shown_as(const storage::StoreInfo& info, const WebLook& look) {
    std::string note;
    if (info.layered()) note += "layer '" + info.layers[0].name + "' of " + std::to_string(info.layers.size()) + "; ";
    if (look.info.sample_type == storage::SampleType::u16) note += "16-bit samples shown at 8 bits; ";
    if (look.info.channels == 2 && !look.info.has_alpha) note += "two channels shown as red and green; ";
    if (look.info.colour_space == storage::ColourSpace::linear) note += "linear samples shown as they are; ";
    if (!note.empty()) note.resize(note.size() - 2);
    return note;
}

const char* const kPageStyle =
    "html,body{margin:0;height:100%;background:#16181b;color:#d8dadd;font:14px system-ui,sans-serif}"
    "a{color:#8cb4ff}#viewer{position:absolute;inset:0}"
    "#bar{position:absolute;left:8px;bottom:8px;z-index:2;background:rgba(0,0,0,.65);padding:5px 9px;border-radius:4px}"
    "table{border-collapse:collapse;margin:16px}td,th{padding:4px 12px;text-align:left;border-bottom:1px solid #333}";

}  // namespace

HttpResponse viewer_index(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route, bool) {
    route = HttpRoute::viewer;
    if (!req.query.empty()) return error(400, "the store list takes no query parameters", false);
    // Behind a proxy serving the server under a path (--public-url), links start with it.
    const std::string at = public_path(handler.context().config.public_url);
    std::string rows;
    for (const auto& h : handler.context().stores.list()) {
        const storage::StoreInfo& info = h->info();
        const WebLook look = web_look(info);
        rows += "<tr><td>" + (look.refused.empty() ? "<a href=\"" + at + "/view/" + h->name + "\">" + h->name + "</a>" : h->name) +
                "</td><td>" + std::to_string(info.width) + " &times; " + std::to_string(info.height) + "</td><td>" +
                std::string(tessera::to_string(info.codec)) + "</td><td>" +
                (look.refused.empty() ? "<a href=\"" + at + "/dzi/" + h->name + ".dzi\">DZI</a> &middot; <a href=\"" + at + "/iiif/" + h->name +
                                            "/info.json\">IIIF</a> &middot; <a href=\"" + at + "/v1/stores/" + h->name + "\">JSON</a>"
                                      : "no web view: " + look.refused) +
                "</td></tr>\n";
    }
    return html(200, std::string("<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>Tessera</title><style>") +
                         kPageStyle + "</style></head><body><table><tr><th>store</th><th>size</th><th>codec</th><th>web</th></tr>\n" +
                         rows + "</table></body></html>\n");
}

HttpResponse viewer_page(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route, bool) {
    route = HttpRoute::viewer;
    if (req.segments.size() != 2) return error(404, "a viewer URL is /view/{name}", false);
    if (!req.query.empty()) return error(400, "the viewer takes no query parameters besides access_token", false);
    HttpResponse failed;
    const auto store = find_web_store(handler, req.segments[1], failed);
    if (!store) {
        if (failed.status == 406) failed.status = 415;  // the store exists, but browsers cannot show its samples
        return failed;
    }
    if (!find_asset(kOsd))
        return error(503, "this server was built without the web viewer's OpenSeadragon: run tools/setup.sh (it installs "
                          "server/web's npm package) and rebuild",
                     false);
    const StoreHandle& h = *store->handle;
    const storage::StoreInfo& info = h.info();
    const std::string name = h.name;  // [A-Za-z0-9_.-]: safe in HTML and JavaScript strings
    const std::string note = shown_as(info, store->look);
    const std::string at = public_path(handler.context().config.public_url);  // as in viewer_index
    return html(200, "<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>" + name +
                         " - Tessera</title><style>" + kPageStyle +
                         "</style></head><body><div id=\"viewer\"></div><div id=\"bar\"><a href=\"" + at + "/\">stores</a> &middot; " +
                         name + " &middot; " + std::to_string(info.width) + " &times; " + std::to_string(info.height) +
                         (note.empty() ? "" : " &middot; " + note) +
                         " <span id=\"state\"></span></div>\n"
                         "<script src=\"" + at + "/static/openseadragon/openseadragon.min.js\"></script>\n<script>\n"
                         "const tessera = window.tessera = {opened: false, fullyLoaded: false, error: null};\n"
                         "const state = document.getElementById('state');\n"
                         "const viewer = tessera.viewer = OpenSeadragon({\n"
                         "  id: 'viewer', prefixUrl: '" + at + "/static/openseadragon/images/',\n"
                         "  tileSources: '" + at + "/dzi/" + name + ".dzi?v=" + hex16(h.version) + "',\n"
                         "  showNavigator: true, maxZoomPixelRatio: 4, visibilityRatio: 0.5, immediateRender: false\n"
                         "});\n"
                         "viewer.addHandler('open', () => {\n"
                         "  tessera.opened = true;\n"
                         "  const item = viewer.world.getItemAt(0);\n"
                         "  const show = loaded => { tessera.fullyLoaded = loaded; state.textContent = loaded ? '' : '\\u00b7 loading'; };\n"
                         "  item.addHandler('fully-loaded-change', e => show(e.fullyLoaded));\n"
                         "  show(item.getFullyLoaded());\n"
                         "});\n"
                         "viewer.addHandler('open-failed', e => { tessera.error = e.message; state.textContent = '\\u00b7 ' + e.message; });\n"
                         "</script></body></html>\n");
}

HttpResponse viewer_static(HttpHandler&, const ParsedRequest& req, HttpRoute& route, bool) {
    route = HttpRoute::viewer;
    std::string path;
    for (std::size_t i = 1; i < req.segments.size(); ++i) path += (i > 1 ? "/" : "") + req.segments[i];
    const WebAsset* a = find_asset(path);
    if (!a) return error(404, "no such file: /static/" + path, false);
    const std::string etag = "\"" + hex16(XXH3_64bits(a->data, a->size)) + "\"";
    HttpResponse r;
    r.headers.emplace_back("ETag", etag);
    r.headers.emplace_back("Cache-Control", "public, max-age=86400");  // OpenSeadragon: the same for everyone
    if (!req.raw->if_none_match.empty() && if_none_match_matches(req.raw->if_none_match, etag)) {
        r.status = 304;
        return r;
    }
    r.content_type = a->content_type;
    r.body.assign(reinterpret_cast<const char*>(a->data), a->size);
    return r;
}

}  // namespace tessera::server::httpapi
