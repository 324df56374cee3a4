// What the browser-facing routes (DZI, IIIF, XYZ) share: finding a store they can show, and
// answering with an encoded image under an ETag, from the web tile cache when it is there.
#include "apis.hpp"
#include "tessera/hex.hpp"
#include "tessera/protocol/wire.hpp"

namespace tessera::server::httpapi {

std::optional<WebStore> find_web_store(HttpHandler& handler, const std::string& name, HttpResponse& error_response) {
    if (!protocol::valid_store_name(name)) {
        error_response = error(400, "invalid store name", false);
        return std::nullopt;
    }
    auto h = handler.context().stores.find(name);
    if (!h) {
        error_response = error(404, "unknown store '" + name + "'", false);
        return std::nullopt;
    }
    WebStore s{h, web_look(h->info())};
    if (!s.look.refused.empty()) {
        error_response = error(406, s.look.refused, false);
        return std::nullopt;
    }
    return s;
}

bool pinned_version(const ParsedRequest& req, std::optional<std::uint64_t>& version, HttpResponse& failed) {
    if (const std::string unknown = req.unknown_params({"v"}); !unknown.empty()) {
        failed = error(400, "unknown query parameter " + unknown + " (known: v)", false);
        return false;
    }
    bool twice = false;
    const auto v = req.param("v", &twice);
    if (twice) {
        failed = error(400, "query parameter 'v' given twice", false);
        return false;
    }
    if (v && !(version = parse_version(*v))) {
        failed = error(400, "query parameter 'v' must be the store version in hex", false);
        return false;
    }
    return true;
}

std::string web_etag(const StoreHandle& store, const WebAnswer& answer) {
    return "\"" + hex16(store.version) + "-" + answer.variant + "\"";
}

std::string web_cache_key(const StoreHandle& store, const WebAnswer& answer) {
    return store.name + "/" + hex16(store.version) + "/" + answer.variant;
}

HttpResponse web_body_response(HttpHandler& handler, bool head, const StoreHandle& store, const WebAnswer& answer,
                               std::shared_ptr<const std::string> body) {
    HttpResponse r;
    r.headers.emplace_back("ETag", web_etag(store, answer));
    r.headers.emplace_back("Cache-Control", cache_control(handler.context(), answer.immutable));
    r.headers.emplace_back("X-Tessera-Store-Version", hex16(store.version));
    if (!body) {
        r.status = 304;
        return r;
    }
    r.status = 200;
    r.content_type = answer.format == "png" ? "image/png" : "image/jpeg";
    r.body = *body;
    if (!head) handler.count_served(store, r.body.size());
    return r;
}

HttpResponse answer_in_place(HttpResponse r) {
    if (!r.deferred) return r;
    return r.deferred->answer();
}

}  // namespace tessera::server::httpapi
