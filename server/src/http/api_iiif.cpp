// IIIF Image API 3.0 (https://iiif.io/api/image/3.0/), compliance level 2:
//   /iiif/{name}                                         303 to its info.json
//   /iiif/{name}/info.json                               the image information
//   /iiif/{name}/{region}/{size}/{rotation}/{quality}.{format}
// region: full, square, x,y,w,h, pct:x,y,w,h; size: max, w,, ,h, pct:n, w,h, !w,h, each with ^
// to allow upscaling; rotation: 0, 90, 180, 270, each with ! to mirror first; quality: default,
// color, gray; format: jpg, png. Tiles have no overlap, so every tile is cut from the interior
// of a stored tile; any other request is assembled from the pyramid level just finer than the
// output (docs/server.md, "Browsers").
#include <algorithm>
#include <cctype>
#include <cmath>
#include <tuple>

#include <nlohmann/json.hpp>

#include "apis.hpp"
#include "tessera/hex.hpp"

namespace tessera::server::httpapi {

namespace {

// Outputs are at most this many texels per side: a request's memory and work are bounded.
constexpr std::uint32_t kMaxSide = 4096;
constexpr std::uint64_t kMaxArea = std::uint64_t(4096) * 2048;

struct Rect {
    std::uint32_t x = 0, y = 0, w = 0, h = 0;
};

// Non-negative decimal with an optional fraction ("12", "12.5"); nullopt otherwise.
std::optional<double> parse_decimal(std::string_view s) {
    if (s.empty() || s.size() > 24) return std::nullopt;
    double v = 0, scale = 0;
    bool digits = false;
    for (char c : s) {
        if (c >= '0' && c <= '9') {
            digits = true;
            if (scale == 0) v = v * 10 + (c - '0');
            else v += (c - '0') * scale, scale /= 10;
        } else if (c == '.' && scale == 0) {
            scale = 0.1;
        } else {
            return std::nullopt;
        }
    }
    return digits ? std::optional(v) : std::nullopt;
}

std::vector<std::string_view> split(std::string_view s, char sep) {
    std::vector<std::string_view> out;
    std::size_t start = 0;
    while (true) {
        const std::size_t i = s.find(sep, start);
        out.push_back(s.substr(start, i == std::string_view::npos ? std::string_view::npos : i - start));
        if (i == std::string_view::npos) return out;
        start = i + 1;
    }
}

// The region in full-size texels, clipped to the image. Sets `why` (400) when invalid.
std::optional<Rect> parse_region(std::string_view s, std::uint32_t W, std::uint32_t H, std::string& why) {
    if (s == "full") return Rect{0, 0, W, H};
    if (s == "square") {
        const std::uint32_t side = std::min(W, H);
        return Rect{(W - side) / 2, (H - side) / 2, side, side};
    }
    const bool pct = s.starts_with("pct:");
    const auto parts = split(pct ? s.substr(4) : s, ',');
    if (parts.size() != 4) {
        why = "region must be full, square, x,y,w,h or pct:x,y,w,h";
        return std::nullopt;
    }
    double v[4];
    for (int i = 0; i < 4; ++i) {
        std::optional<double> d;
        if (pct) d = parse_decimal(parts[i]);
        else if (const auto u = parse_u32(parts[i])) d = double(*u);
        if (!d) {
            why = pct ? "region percentages must be non-negative decimals" : "region x,y,w,h must be non-negative integers";
            return std::nullopt;
        }
        v[i] = *d;
    }
    if (pct) {  // to the nearest texel; a start inside the image stays inside it (99.99% of 3000: 2999)
        const double x = v[0] * W / 100.0, y = v[1] * H / 100.0;
        v[0] = x < W ? std::min(std::round(x), W - 1.0) : x, v[2] = std::round(v[2] * W / 100.0);
        v[1] = y < H ? std::min(std::round(y), H - 1.0) : y, v[3] = std::round(v[3] * H / 100.0);
    }
    if (v[2] <= 0 || v[3] <= 0 || v[0] >= W || v[1] >= H) {
        why = "region is empty or outside the image";
        return std::nullopt;
    }
    Rect r;
    r.x = std::uint32_t(v[0]), r.y = std::uint32_t(v[1]);
    r.w = std::uint32_t(std::min(v[2], double(W - r.x)));
    r.h = std::uint32_t(std::min(v[3], double(H - r.y)));
    return r;
}

// The region's sides scaled by f, rounded to nearest as w, and ,h round (so the side f was
// taken from comes out exact), or down where rounding would pass the area limit.
std::pair<double, double> scaled_sides(double rw, double rh, double f) {
    const double w = std::round(rw * f), h = std::round(rh * f);
    if (w * h <= double(kMaxArea)) return {w, h};
    return {std::floor(rw * f + 1e-9), std::floor(rh * f + 1e-9)};
}

// The output size for a region. Sets `why` (400) when invalid or over the limits.
std::optional<std::pair<std::uint32_t, std::uint32_t>> parse_size(std::string_view s, const Rect& r, std::string& why) {
    const bool up = s.starts_with("^");
    if (up) s.remove_prefix(1);
    double w = 0, h = 0;
    const double rw = r.w, rh = r.h;
    if (s == "max") {
        const double f = std::min({1.0, kMaxSide / rw, kMaxSide / rh, std::sqrt(double(kMaxArea) / (rw * rh))});
        const double g = up ? std::min({kMaxSide / rw, kMaxSide / rh, std::sqrt(double(kMaxArea) / (rw * rh))}) : f;
        std::tie(w, h) = scaled_sides(rw, rh, g);
        w = std::max(1.0, w), h = std::max(1.0, h);
    } else if (s.starts_with("pct:")) {
        const auto p = parse_decimal(s.substr(4));
        if (!p || *p <= 0) {
            why = "size pct:n needs a positive number";
            return std::nullopt;
        }
        if (!up && *p > 100) {
            why = "size pct:n over 100 upscales: ask with ^pct:n";
            return std::nullopt;
        }
        w = std::round(rw * *p / 100.0), h = std::round(rh * *p / 100.0);
    } else {
        const bool confined = s.starts_with("!");
        if (confined) s.remove_prefix(1);
        const auto parts = split(s, ',');
        if (parts.size() != 2 || (parts[0].empty() && parts[1].empty()) || (confined && (parts[0].empty() || parts[1].empty()))) {
            why = "size must be max, w,, ,h, pct:n, w,h or !w,h (each may start with ^)";
            return std::nullopt;
        }
        const auto pw = parts[0].empty() ? std::optional<std::uint32_t>(0) : parse_u32(parts[0]);
        const auto ph = parts[1].empty() ? std::optional<std::uint32_t>(0) : parse_u32(parts[1]);
        if (!pw || !ph || (!parts[0].empty() && *pw == 0) || (!parts[1].empty() && *ph == 0)) {
            why = "size width and height must be positive integers";
            return std::nullopt;
        }
        if (confined) {
            // The largest size within w, h, the server's limits (IIIF 3.0, 4.2: "not larger than
            // ... w or h, or server-imposed limits") and, without ^, the region.
            const double f = std::min({up ? *pw / rw : std::min(1.0, *pw / rw), *ph / rh, kMaxSide / rw, kMaxSide / rh,
                                       std::sqrt(double(kMaxArea) / (rw * rh))});
            std::tie(w, h) = scaled_sides(rw, rh, f);
        } else if (parts[1].empty()) {
            w = *pw, h = std::round(rh * *pw / rw);
        } else if (parts[0].empty()) {
            h = *ph, w = std::round(rw * *ph / rh);
        } else {
            w = *pw, h = *ph;
        }
    }
    // IIIF 3.0, 4.2: "If the resulting height or width is zero, then the server should return a
    // 400 (Bad Request) status code." (max keeps at least one texel a side: it names no size.)
    if (w < 1 || h < 1) {
        why = "size is zero texels wide or high for this region";
        return std::nullopt;
    }
    if (!up && (w > rw || h > rh)) {
        why = "size is larger than the region: ask with ^ to upscale";
        return std::nullopt;
    }
    if (w > kMaxSide || h > kMaxSide || w * h > double(kMaxArea)) {
        why = "size over the limits: at most " + std::to_string(kMaxSide) + " texels a side and " +
              std::to_string(kMaxArea) + " in all (info.json: maxWidth, maxHeight, maxArea)";
        return std::nullopt;
    }
    return std::pair{std::uint32_t(w), std::uint32_t(h)};
}

// Whether an Accept header (RFC 9110 12.5.1) names `type` with a quality above 0.
bool accepts(std::string_view accept, std::string_view type) {
    for (const std::string_view range : split(accept, ',')) {
        const std::size_t semi = range.find(';');
        std::string_view name = range.substr(0, semi);
        while (!name.empty() && (name.front() == ' ' || name.front() == '\t')) name.remove_prefix(1);
        while (!name.empty() && (name.back() == ' ' || name.back() == '\t')) name.remove_suffix(1);
        if (name.size() != type.size() || !std::equal(name.begin(), name.end(), type.begin(), [](char a, char b) {
                return std::tolower(static_cast<unsigned char>(a)) == b;
            }))
            continue;
        double q = 1;
        for (std::size_t at = semi; at != std::string_view::npos;) {
            const std::size_t next = range.find(';', at + 1);
            std::string_view p = range.substr(at + 1, next == std::string_view::npos ? std::string_view::npos : next - at - 1);
            while (!p.empty() && (p.front() == ' ' || p.front() == '\t')) p.remove_prefix(1);
            if (p.size() > 2 && (p[0] == 'q' || p[0] == 'Q') && p[1] == '=') q = parse_decimal(p.substr(2)).value_or(1);
            at = next;
        }
        return q > 0;
    }
    return false;
}

// Where this image service is, as clients reach it: config.public_url, else the Host they used.
std::string base_url(HttpHandler& handler, const HttpRequestView& req) {
    const std::string& configured = handler.context().config.public_url;
    if (!configured.empty()) return public_base(configured);
    const std::string host = req.host.empty() ? handler.context().config.http_address : std::string(req.host);
    return std::string(req.secure ? "https://" : "http://") + host;
}

// What admission charges a render of a region `region_w` texels wide at w x h: the texels read
// stay within about 4x the output's (the level chosen reads at most 2x per axis past it).
std::size_t render_charge(const storage::StoreInfo& info, const WebLook& look, std::uint32_t region_w, std::uint32_t w,
                          std::uint32_t h) {
    return render_memory(info, look, std::min<std::uint32_t>(region_w, 4 * w + 2), w, h);
}

// The image information. `sizes` and `tiles` list only what this server renders within one
// render's memory (`render_budget`, --render-memory): a viewer asks for what they advertise, and a
// size that cannot fit is refused (400) however idle the server is.
nlohmann::json info_json(const StoreHandle& h, const WebLook& look, const std::string& id, std::size_t render_budget) {
    const storage::StoreInfo& info = h.info();
    const auto fits = [&](std::uint32_t region_w, std::uint32_t w, std::uint32_t hh) {
        return render_charge(info, look, region_w, w, hh) <= render_budget;
    };
    nlohmann::json factors = nlohmann::json::array(), sizes = nlohmann::json::array();
    for (std::uint32_t k = 0; k < info.level_count(); ++k) factors.push_back(std::uint64_t(1) << k);
    for (std::uint32_t k = info.level_count(); k-- > 0;) {
        const auto& l = info.levels[k];
        if (l.width <= kMaxSide && l.height <= kMaxSide && std::uint64_t(l.width) * l.height <= kMaxArea &&
            fits(info.width, l.width, l.height))
            sizes.push_back({{"width", l.width}, {"height", l.height}});
    }
    // The dearest tile: a full one at a scale factor of 4 or more (its source charged 4x its width).
    const std::uint32_t p = info.tile_payload;
    nlohmann::json tiles = nlohmann::json::array();
    if (fits(info.width, std::min(p, info.width), std::min(p, info.height)))
        tiles.push_back({{"width", p}, {"height", p}, {"scaleFactors", factors}});
    nlohmann::json j = {{"@context", "http://iiif.io/api/image/3/context.json"},
            {"id", id},
            {"type", "ImageService3"},
            {"protocol", "http://iiif.io/api/image"},
            {"profile", "level2"},
            {"width", info.width},
            {"height", info.height},
            {"maxWidth", kMaxSide},
            {"maxHeight", kMaxSide},
            {"maxArea", kMaxArea},
            {"extraQualities", {"color", "gray"}},
            {"extraFeatures", {"mirroring", "sizeUpscaling"}}};
    if (!sizes.empty()) j["sizes"] = std::move(sizes);  // IIIF: present only with at least one size
    if (!tiles.empty()) j["tiles"] = std::move(tiles);
    return j;
}

}  // namespace

HttpResponse api_iiif(HttpHandler& handler, const ParsedRequest& req, HttpRoute& route, bool) {
    const auto& seg = req.segments;
    if (seg.size() < 2) return error(404, "an IIIF URL is /iiif/{name}/info.json or /iiif/{name}/{region}/{size}/{rotation}/{quality}.{format}", false);
    if (!req.query.empty()) return error(400, "IIIF requests take no query parameters", false);
    HttpResponse failed;
    const auto store = find_web_store(handler, seg[1], failed);
    if (seg.size() == 2 || (seg.size() == 3 && seg[2] == "info.json")) route = HttpRoute::iiif_info;
    else route = HttpRoute::iiif_image;
    if (!store) return failed;
    const StoreHandle& h = *store->handle;
    const std::string id = base_url(handler, *req.raw) + "/iiif/" + h.name;
    if (seg.size() == 2) {  // the base URI: to its image information
        HttpResponse r;
        r.status = 303;
        r.headers.emplace_back("Location", id + "/info.json");
        r.headers.emplace_back("Cache-Control", "no-cache");
        return r;
    }
    if (seg.size() == 3) {
        if (seg[2] != "info.json") return error(404, "no such IIIF resource: " + seg[2], false);
        const bool ld = accepts(req.raw->accept, "application/ld+json");
        HttpResponse r = json_response(info_json(h, store->look, id, handler.context().config.render_memory_bytes), ld ? "application/ld+json;profile=\"http://iiif.io/api/image/3/context.json\""
                                                            : "application/json");
        r.headers.emplace_back("Vary", "Accept");  // the Content-Type follows it
        r.headers.emplace_back("Link", "<http://iiif.io/api/image/3/level2.json>;rel=\"profile\"");
        r.headers.emplace_back("X-Tessera-Store-Version", hex16(h.version));
        return r;
    }
    if (seg.size() != 6)
        return error(400, "an IIIF image request is /iiif/{name}/{region}/{size}/{rotation}/{quality}.{format}", false);
    const storage::StoreInfo& info = h.info();
    std::string why;
    const auto region = parse_region(seg[2], info.width, info.height, why);
    if (!region) return error(400, why, false);
    const auto size = parse_size(seg[3], *region, why);
    if (!size) return error(400, why, false);
    std::string_view rot = seg[4];
    const bool mirrored = rot.starts_with("!");
    if (mirrored) rot.remove_prefix(1);
    auto degrees = parse_decimal(rot);
    if (!degrees || *degrees > 360) return error(400, "rotation must be a number of degrees from 0 to 360, maybe after !", false);
    if (*degrees == 360) degrees = 0.0;  // a whole turn
    if (std::fmod(*degrees, 90.0) != 0) return error(501, "only rotations by multiples of 90 degrees are supported", false);
    const std::size_t dot = seg[5].rfind('.');
    if (dot == std::string::npos) return error(400, "quality and format: {quality}.{format}", false);
    const std::string quality = seg[5].substr(0, dot), format = seg[5].substr(dot + 1);
    if (quality == "bitonal") return error(501, "quality bitonal is not supported (default, color, gray)", false);
    if (quality != "default" && quality != "color" && quality != "gray")
        return error(400, "quality must be default, color, gray or bitonal", false);
    if (format == "tif" || format == "gif" || format == "jp2" || format == "pdf" || format == "webp")
        return error(501, "format " + format + " is not supported (jpg, png)", false);
    if (format != "jpg" && format != "png") return error(400, "format must be jpg or png", false);

    std::uint32_t ow = size->first, oh = size->second;
    const WebLook& shown = store->look;
    const auto reg = *region;
    const auto memory_for = [&](std::uint32_t w, std::uint32_t hh) { return render_charge(info, shown, reg.w, w, hh); };
    // A render needing more than --render-memory would be refused however idle the server is.
    // `max` and `!w,h` name the largest size the server can give (IIIF 3.0, 4.2: within its
    // limits), so they shrink to what the budget holds; an exact size that cannot fit is a 400
    // (as one past maxArea is), not a 503 to retry forever.
    const std::size_t budget = handler.context().config.render_memory_bytes;
    if (memory_for(ow, oh) > budget) {
        std::string_view spec = seg[3];
        if (spec.starts_with("^")) spec.remove_prefix(1);
        if (spec == "max" || spec.starts_with("!")) {
            // The largest scale of the size asked that fits (memory grows with the size).
            const double w0 = ow, h0 = oh;
            const auto at = [&](double f) {
                return std::pair{std::max(1u, std::uint32_t(std::round(w0 * f))), std::max(1u, std::uint32_t(std::round(h0 * f)))};
            };
            double lo = 0, hi = 1;
            for (int i = 0; i < 40; ++i) {
                const double mid = (lo + hi) / 2;
                const auto [mw, mh] = at(mid);
                (memory_for(mw, mh) <= budget ? lo : hi) = mid;
            }
            std::tie(ow, oh) = at(lo);
        }
        if (memory_for(ow, oh) > budget)
            return error(400, "size " + std::to_string(ow) + "x" + std::to_string(oh) +
                                  " needs more memory than this server renders at once (--render-memory); ask a smaller size",
                         false);
    }
    const WebAnswer answer{"iiif-" + std::to_string(region->x) + "," + std::to_string(region->y) + "," +
                               std::to_string(region->w) + "," + std::to_string(region->h) + "-" + std::to_string(ow) +
                               "," + std::to_string(oh) + "-" + (mirrored ? "!" : "") + std::to_string(int(*degrees)) +
                               "-" + quality + "." + format,
                           format, false};
    const std::shared_ptr<const StoreHandle> hs = store->handle;
    TileFetcher* fetcher = &handler.context().fetcher;
    const WebLook look = store->look;
    const double deg = *degrees;
    const std::size_t memory = memory_for(ow, oh);
    auto render = [fetcher, hs, look, reg, ow, oh, deg, mirrored, quality](WebFailure& failure) -> std::optional<WebImage> {
        const storage::StoreInfo& si = hs->info();
        // The coarsest level that still has the output's resolution along both axes' larger
        // reduction: the texels read stay within about 4x the output's (a stretched size is
        // upsampled along its other axis), whatever region and size are asked for.
        const double scale = std::max(double(reg.w) / ow, double(reg.h) / oh);
        std::uint32_t k = 0;
        while (k + 1 < si.level_count() && double(std::uint64_t(2) << k) <= scale + 1e-9) ++k;
        const auto& lk = si.levels[k];
        const double f = double(std::uint64_t(1) << k);
        // The level-k texels the region touches, and where in them it starts and ends.
        const double fx0 = reg.x / f, fy0 = reg.y / f;
        // Where the region ends, exactly: a level rounds its size up, and its last texel, which
        // covers less of the image than the others, weighs only for what it covers.
        const double fx1 = std::min((double(reg.x) + reg.w) / f, double(lk.width));
        const double fy1 = std::min((double(reg.y) + reg.h) / f, double(lk.height));
        const auto x0 = std::uint32_t(fx0), y0 = std::uint32_t(fy0);
        const std::uint32_t x1 = std::max(x0 + 1, std::uint32_t(std::ceil(fx1 - 1e-9)));
        const std::uint32_t y1 = std::max(y0 + 1, std::uint32_t(std::ceil(fy1 - 1e-9)));
        const bool aligned = fx0 == x0 && fy0 == y0 && fx1 == x1 && fy1 == y1;
        auto image = render_region(*fetcher, *hs, look, Region{k, x0, y0, x1 - x0, y1 - y0}, ow, oh,
                                   failure,
                                   aligned ? std::nullopt
                                           : std::optional(SourceWindow{fx0 - x0, fy0 - y0, fx1 - fx0, fy1 - fy0}));
        if (!image) return image;
        if (quality == "gray") *image = to_grey(*image);
        if (mirrored) *image = mirror(*image);
        return rotate_quarters(*image, unsigned(deg / 90));
    };
    return web_image_response(handler, *req.raw, hs, answer, memory, render);
}

}  // namespace tessera::server::httpapi
