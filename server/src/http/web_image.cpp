#include "web_image.hpp"

#include <turbojpeg.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>

#include "tessera/storage/codec.hpp"
#include "tessera/storage/layers.hpp"
#include "tessera/storage/png_encode.hpp"

namespace tessera::server::httpapi {

namespace {

using storage::SampleType;

// One stored tile as web texels (T x T x look.channels); an absent tile (or layer) is zeros.
// 8-bit samples shown as they are decode straight into `out`; others go through `samples`.
bool decode_web_tile(const StoreHandle& store, const WebLook& look, const storage::Tile& t, std::vector<std::uint8_t>& out,
                     std::vector<std::uint8_t>& samples, WebFailure& failure) {
    const storage::StoreInfo& info = store.info();
    const std::uint32_t T = info.tile_size();
    const std::size_t n = std::size_t(T) * T;
    const auto zeros = [&] {
        out.assign(n * look.channels, 0);
        return true;
    };
    if (t.kind == TileKind::absent) return zeros();
    storage::Tile part_tile;
    const storage::Tile* tile = &t;
    if (info.layered()) {
        auto parts = storage::split_layers(info, t.bytes);
        if (!parts) {
            failure = {500, "tile bundle does not split into the store's layers: " + parts.error().message};
            return false;
        }
        const storage::LayerPart& p = (*parts)[look.layer];
        if (p.kind == TileKind::absent) return zeros();
        part_tile = storage::layer_tile(t.key, p);
        tile = &part_tile;
    }
    const std::uint32_t c = look.info.channels;
    const bool wide = look.info.sample_type == SampleType::u16;
    const bool direct = !wide && c == look.channels;
    if (const Status s = storage::decode_tile(look.info, *tile, direct ? out : samples); !s.ok()) {
        failure = {500, "tile does not decode: " + s.error().message};
        return false;
    }
    if (direct) return true;
    // 16-bit samples scaled to 8 bits; two channels without alpha (normals, say) show as red
    // and green, blue 0.
    out.assign(n * look.channels, 0);
    for (std::size_t i = 0; i < n; ++i) {
        for (std::uint32_t k = 0; k < c; ++k) {
            std::uint8_t v;
            if (wide) {
                std::uint16_t s16;
                std::memcpy(&s16, &samples[(i * c + k) * 2], 2);
                v = static_cast<std::uint8_t>((unsigned(s16) * 255u + 32767u) / 65535u);
            } else {
                v = samples[i * c + k];
            }
            out[i * look.channels + k] = v;
        }
    }
    return true;
}

// Decode buffers a render reuses: a worker thread keeps those of renders a few small tiles wide,
// so a web tile allocates (and the kernel zeroes) no tile-sized buffer per request; a wider
// render's, or one of large tiles, are its own and freed with it. What a thread keeps, which the
// render budget no longer counts, is so at most kKept tiles and one samples buffer, each at most
// kKeptBytes / kKept.
class TileScratch {
public:
    // tile_bytes: one decoded tile and its samples, at most.
    TileScratch(std::size_t tiles, std::size_t tile_bytes) : own_(tiles > kKept || tile_bytes > kKeptBytes / kKept) {
        if (own_) tiles_.resize(tiles);
        else if (kept().tiles.size() < tiles) kept().tiles.resize(tiles);
    }
    std::vector<std::uint8_t>& tile(std::size_t i) { return own_ ? tiles_[i] : kept().tiles[i]; }
    std::vector<std::uint8_t>& samples() { return own_ ? samples_ : kept().samples; }

private:
    static constexpr std::size_t kKept = 4;
    static constexpr std::size_t kKeptBytes = std::size_t(4) << 20;
    struct Kept {
        std::vector<std::vector<std::uint8_t>> tiles;
        std::vector<std::uint8_t> samples;
    };
    static Kept& kept() {
        thread_local Kept k;
        return k;
    }
    bool own_;
    std::vector<std::vector<std::uint8_t>> tiles_;
    std::vector<std::uint8_t> samples_;
};

// Which source texels (and how much of each) make one output texel along one axis.
struct Tap {
    std::uint32_t src;
    float weight;
};
// Output texel i covers [off + i s, off + (i + 1) s) of the n source texels, s = span / m: the
// window may start and end inside a texel (a crop not aligned to the level's texels).
std::vector<std::vector<Tap>> taps_for(std::uint32_t n, std::uint32_t m, double off, double span) {
    std::vector<std::vector<Tap>> taps(m);
    const double s = span / double(m);
    for (std::uint32_t i = 0; i < m; ++i) {
        if (s >= 1.0) {  // area: the source span, each texel by its overlap
            const double a = off + i * s, b = std::min(double(n), off + (i + 1) * s);
            for (auto j = std::uint32_t(std::max(0.0, a)); j < n && double(j) < b; ++j) {
                const double w = std::min(b, double(j) + 1) - std::max(a, double(j));
                if (w > 1e-9) taps[i].push_back({j, float(w / (b - a))});
            }
            if (taps[i].empty()) taps[i].push_back({std::min(n - 1, std::uint32_t(std::max(0.0, a))), 1.0f});
        } else {  // bilinear between texel centres, clamped at the edges
            const double c = std::clamp(off + (i + 0.5) * s - 0.5, 0.0, double(n - 1));
            const auto j0 = std::uint32_t(c);
            const float f = float(c - j0);
            taps[i].push_back({j0, 1.0f - f});
            if (f > 0 && j0 + 1 < n) taps[i].push_back({j0 + 1, f});
        }
    }
    return taps;
}

// Area resampling of rows fed in order: each source row is resampled horizontally at once, then
// added into the output rows it covers; an output row is finished when its last source row has
// come. Memory: the output and a few rows of floats. Colour is weighted by alpha.
class Resampler {
public:
    Resampler(std::uint32_t src_w, std::uint32_t src_h, std::uint32_t out_w, std::uint32_t out_h, std::uint32_t channels,
              bool alpha, const SourceWindow& win)
        : out_w_(out_w), c_(channels), alpha_(alpha), h_taps_(taps_for(src_w, out_w, win.x, win.w)), inverse_(src_h),
          last_(out_h, 0) {
        const auto v = taps_for(src_h, out_h, win.y, win.h);
        for (std::uint32_t i = 0; i < out_h; ++i)
            for (const Tap& t : v[i]) {
                inverse_[t.src].push_back({i, t.weight});
                last_[i] = std::max(last_[i], t.src);
            }
        out_.width = out_w;
        out_.height = out_h;
        out_.channels = channels;
        out_.texels.assign(std::size_t(out_w) * out_h * channels, 0);
        row_.resize(std::size_t(out_w) * channels);
    }

    void push(std::uint32_t y, const std::uint8_t* src) {
        std::fill(row_.begin(), row_.end(), 0.0f);
        for (std::uint32_t i = 0; i < out_w_; ++i)
            for (const Tap& t : h_taps_[i]) {
                const std::uint8_t* p = src + std::size_t(t.src) * c_;
                const float a = alpha_ ? p[c_ - 1] * t.weight : t.weight;
                float* o = &row_[std::size_t(i) * c_];
                for (std::uint32_t k = 0; k + (alpha_ ? 1 : 0) < c_; ++k) o[k] += p[k] * a;
                if (alpha_) o[c_ - 1] += a;
            }
        for (const Tap& t : inverse_[y]) {
            auto& acc = active_[t.src];
            if (acc.empty()) acc.assign(row_.size(), 0.0f);
            for (std::size_t k = 0; k < row_.size(); ++k) acc[k] += row_[k] * t.weight;
            if (last_[t.src] == y) finish(t.src, acc), active_.erase(t.src);
        }
    }
    WebImage take() { return std::move(out_); }

private:
    void finish(std::uint32_t oy, const std::vector<float>& acc) {
        std::uint8_t* o = &out_.texels[std::size_t(oy) * out_w_ * c_];
        for (std::uint32_t i = 0; i < out_w_; ++i) {
            const float* a = &acc[std::size_t(i) * c_];
            const float alpha = alpha_ ? a[c_ - 1] : 1.0f;
            for (std::uint32_t k = 0; k < c_; ++k) {
                float v = a[k];
                if (alpha_ && k + 1 < c_) v = alpha > 1e-6f ? v / alpha : 0.0f;
                o[std::size_t(i) * c_ + k] = static_cast<std::uint8_t>(std::clamp(std::lround(v), 0L, 255L));
            }
        }
    }

    std::uint32_t out_w_, c_;
    bool alpha_;
    std::vector<std::vector<Tap>> h_taps_;
    std::vector<std::vector<Tap>> inverse_;  // per source row: (output row, weight)
    std::vector<std::uint32_t> last_;        // per output row: its last source row
    std::map<std::uint32_t, std::vector<float>> active_;
    std::vector<float> row_;
    WebImage out_;
};

}  // namespace

// The status a failed tile read answers with.
WebFailure fetch_failure(const FetchedTile& f) {
    switch (f.status) {
        case TileStatus::data_loss: return {500, "tile failed its checksum"};
        case TileStatus::not_found: return {404, "store not found"};
        case TileStatus::out_of_range: return {404, "tile out of range: " + f.message};
        case TileStatus::deadline_exceeded: return {504, "tile unavailable: " + f.message};
        case TileStatus::resource_exhausted:
        case TileStatus::unavailable: return {503, "tile unavailable: " + f.message};
        default: return {500, "tile read failed: " + f.message};
    }
}

WebLook web_look(const storage::StoreInfo& info) {
    WebLook look;
    look.info = info.layered() ? storage::layer_store_info(info, 0) : info;
    const auto& l = look.info;
    if (l.sample_type == SampleType::f16 || l.sample_type == SampleType::f32)
        look.refused = std::string("a store of ") + std::string(storage::to_string(l.sample_type)) +
                       " samples has no web view (browsers show 8-bit images); read it through /v1";
    look.has_alpha = l.has_alpha;
    look.channels = l.channels == 2 && !l.has_alpha ? 3 : l.channels;
    look.default_format = info.codec == Codec::jpeg && !look.has_alpha ? "jpg" : "png";
    return look;
}

std::size_t render_memory(const storage::StoreInfo& info, const WebLook& look, std::uint32_t region_w,
                          std::uint32_t out_w, std::uint32_t out_h) {
    const std::size_t T = info.tile_size(), P = std::max<std::uint32_t>(1, info.tile_payload);
    const std::size_t tiles_in_a_row = region_w / P + 2;
    const std::size_t source = tiles_in_a_row * T * T * (look.channels + look.info.texel_bytes());
    const std::size_t out = std::size_t(out_w) * out_h * 4;  // RGBA at most, alpha added for padding
    const std::size_t rows = std::size_t(out_w) * 4 * sizeof(float) * 8;
    return source + rows + 3 * out + (64 << 10);
}

std::uint32_t scaled_size(std::uint32_t size, std::uint32_t k) {
    for (std::uint32_t i = 0; i < k && size > 1; ++i) size = (size + 1) / 2;
    return size;
}

std::optional<WebImage> render_region(TileFetcher& fetcher, const StoreHandle& store, const WebLook& look,
                                      const Region& r, std::uint32_t out_w, std::uint32_t out_h, WebFailure& failure,
                                      std::optional<SourceWindow> window) {
    const storage::StoreInfo& info = store.info();
    const std::uint32_t P = info.tile_payload, B = info.border, T = info.tile_size(), c = look.channels;
    if (r.level >= info.level_count() || r.w == 0 || r.h == 0 || out_w == 0 || out_h == 0 ||
        r.x + std::uint64_t(r.w) > info.levels[r.level].width || r.y + std::uint64_t(r.h) > info.levels[r.level].height) {
        failure = {400, "region outside the image"};
        return std::nullopt;
    }
    const bool copy = !window && out_w == r.w && out_h == r.h;
    WebImage out;
    std::optional<Resampler> resampler;
    if (copy) {
        out.width = out_w, out.height = out_h, out.channels = c;
        out.texels.assign(std::size_t(out_w) * out_h * c, 0);
    } else {
        resampler.emplace(r.w, r.h, out_w, out_h, c, look.has_alpha,
                          window.value_or(SourceWindow{0, 0, double(r.w), double(r.h)}));
    }
    const std::uint32_t tx0 = r.x / P, tx1 = (r.x + r.w - 1) / P, ty0 = r.y / P, ty1 = (r.y + r.h - 1) / P;
    std::vector<TileKey> keys;
    std::vector<FetchedTile> fetched;
    TileScratch tiles(tx1 - tx0 + 1, std::size_t(T) * T * (c + look.info.texel_bytes()));
    std::vector<std::uint8_t> row(copy ? 0 : std::size_t(r.w) * c);
    // Only a web tile's stored tiles (a few) are kept decoded: a large render, which sweeps many
    // once, uses those kept but does not push the viewers' working set out.
    const bool web_tile = std::uint64_t(tx1 - tx0 + 1) * (ty1 - ty0 + 1) <= 4;
    std::vector<std::shared_ptr<const storage::Tile>> held(tx1 - tx0 + 1);  // decoded tiles from the cache, this row
    std::vector<const std::uint8_t*> texels(tx1 - tx0 + 1);                 // each tile's texels, T x T x c
    for (std::uint32_t ty = ty0; ty <= ty1; ++ty) {
        keys.clear();
        for (std::uint32_t tx = tx0; tx <= tx1; ++tx) keys.push_back(TileKey{r.level, tx, ty});
        fetched.clear();
        fetcher.fetch(store, keys, fetched);
        for (std::size_t i = 0; i < keys.size(); ++i) {
            if (fetched[i].status != TileStatus::ok || !fetched[i].tile) {
                failure = fetch_failure(fetched[i]);
                return std::nullopt;
            }
            // A stored tile decoded before is taken as decoded (its bytes are the texels); one
            // decoded now is kept for the next request.
            const bool look_up = fetched[i].tile->kind == TileKind::present && fetcher.keeps_decoded();
            held[i] = look_up ? fetcher.decoded(store, keys[i], std::uint32_t(look.layer)) : nullptr;
            if (held[i]) {
                texels[i] = held[i]->bytes.data();
                continue;
            }
            std::vector<std::uint8_t>& decoded = tiles.tile(i);
            if (!decode_web_tile(store, look, *fetched[i].tile, decoded, tiles.samples(), failure)) return std::nullopt;
            texels[i] = decoded.data();
            if (look_up && web_tile) fetcher.keep_decoded(store, keys[i], std::uint32_t(look.layer), decoded);
        }
        const auto [y0, y1] = tile_span(r.y, r.h, ty, P);
        for (std::uint32_t y = y0; y < y1; ++y) {
            std::uint8_t* dst = copy ? &out.texels[std::size_t(y - r.y) * r.w * c] : row.data();
            for (std::uint32_t tx = tx0; tx <= tx1; ++tx) {
                const auto [x0, x1] = tile_span(r.x, r.w, tx, P);
                const std::uint8_t* src = texels[tx - tx0] + (std::size_t(y - ty * P + B) * T + (x0 - tx * P + B)) * c;
                std::memcpy(dst + std::size_t(x0 - r.x) * c, src, std::size_t(x1 - x0) * c);
            }
            if (!copy) resampler->push(y - r.y, row.data());
        }
    }
    return copy ? std::move(out) : resampler->take();
}

TileSpan tile_span(std::uint32_t start, std::uint32_t length, std::uint32_t tile, std::uint32_t payload) {
    const std::uint64_t b = std::max<std::uint64_t>(start, std::uint64_t(tile) * payload);
    const std::uint64_t e = std::min<std::uint64_t>(std::uint64_t(start) + length, (std::uint64_t(tile) + 1) * payload);
    return e > b ? TileSpan{std::uint32_t(b), std::uint32_t(e)} : TileSpan{std::uint32_t(b), std::uint32_t(b)};
}

std::optional<WebImage> render_scaled(TileFetcher& fetcher, const StoreHandle& store, const WebLook& look,
                                      std::uint32_t k, std::uint32_t x, std::uint32_t y, std::uint32_t w,
                                      std::uint32_t h, WebFailure& failure) {
    const storage::StoreInfo& info = store.info();
    if (k < info.level_count()) return render_region(fetcher, store, look, Region{k, x, y, w, h}, w, h, failure);
    // Past the coarsest level (one tile): area-average that level down.
    const std::uint32_t last = info.level_count() - 1, d = std::min<std::uint32_t>(k - last, 31);
    const auto& li = info.levels[last];
    const auto scale = [&](std::uint32_t v, std::uint32_t limit) {
        return std::uint32_t(std::min<std::uint64_t>(std::uint64_t(v) << d, limit));
    };
    const std::uint32_t sx = scale(x, li.width - 1), sy = scale(y, li.height - 1);
    const std::uint32_t ex = std::max(sx + 1, scale(x + w, li.width)), ey = std::max(sy + 1, scale(y + h, li.height));
    return render_region(fetcher, store, look, Region{last, sx, sy, ex - sx, ey - sy}, w, h, failure);
}

WebImage to_grey(const WebImage& in) {
    if (in.channels <= 2) return in;
    WebImage out;
    out.width = in.width, out.height = in.height, out.channels = in.channels == 4 ? 2 : 1;
    const std::size_t n = std::size_t(in.width) * in.height;
    out.texels.resize(n * out.channels);
    for (std::size_t i = 0; i < n; ++i) {
        const std::uint8_t* p = &in.texels[i * in.channels];
        out.texels[i * out.channels] =
            static_cast<std::uint8_t>(std::lround(0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]));
        if (in.channels == 4) out.texels[i * out.channels + 1] = p[3];
    }
    return out;
}

WebImage rotate_quarters(const WebImage& in, unsigned quarters) {
    quarters %= 4;
    if (quarters == 0) return in;
    WebImage out;
    out.channels = in.channels;
    out.width = quarters == 2 ? in.width : in.height;
    out.height = quarters == 2 ? in.height : in.width;
    out.texels.resize(in.texels.size());
    const std::uint32_t c = in.channels;
    for (std::uint32_t y = 0; y < in.height; ++y)
        for (std::uint32_t x = 0; x < in.width; ++x) {
            std::uint32_t ox, oy;  // clockwise
            if (quarters == 1) ox = in.height - 1 - y, oy = x;
            else if (quarters == 2) ox = in.width - 1 - x, oy = in.height - 1 - y;
            else ox = y, oy = in.width - 1 - x;
            std::memcpy(&out.texels[(std::size_t(oy) * out.width + ox) * c], &in.texels[(std::size_t(y) * in.width + x) * c], c);
        }
    return out;
}

WebImage mirror(const WebImage& in) {
    WebImage out = in;
    const std::uint32_t c = in.channels;
    for (std::uint32_t y = 0; y < in.height; ++y)
        for (std::uint32_t x = 0; x < in.width; ++x)
            std::memcpy(&out.texels[(std::size_t(y) * in.width + (in.width - 1 - x)) * c],
                        &in.texels[(std::size_t(y) * in.width + x) * c], c);
    return out;
}

WebImage with_alpha(const WebImage& in) {
    if (in.channels == 2 || in.channels == 4) return in;
    WebImage out;
    out.width = in.width, out.height = in.height, out.channels = in.channels + 1;
    const std::size_t n = std::size_t(in.width) * in.height;
    out.texels.resize(n * out.channels);
    for (std::size_t i = 0; i < n; ++i) {
        std::memcpy(&out.texels[i * out.channels], &in.texels[i * in.channels], in.channels);
        out.texels[i * out.channels + in.channels] = 255;
    }
    return out;
}

WebImage pad_to(const WebImage& in, std::uint32_t width, std::uint32_t height) {
    if (in.width == width && in.height == height) return in;
    WebImage out;
    out.width = width, out.height = height, out.channels = in.channels;
    out.texels.assign(std::size_t(width) * height * in.channels, 0);
    const std::uint32_t w = std::min(width, in.width), h = std::min(height, in.height);
    for (std::uint32_t y = 0; y < h; ++y)
        std::memcpy(&out.texels[std::size_t(y) * width * in.channels], &in.texels[std::size_t(y) * in.width * in.channels],
                    std::size_t(w) * in.channels);
    return out;
}

std::optional<std::string> encode_web(const WebImage& image, std::string_view format, WebFailure& failure) {
    if (format == "png") {
        storage::PngImage png;
        png.width = image.width, png.height = image.height, png.channels = image.channels;
        png.texels = image.texels;
        auto encoded = storage::encode_png(png);
        if (!encoded) {
            failure = {500, "PNG encoding failed: " + encoded.error().message};
            return std::nullopt;
        }
        return std::string(reinterpret_cast<const char*>(encoded->data()), encoded->size());
    }
    // JPEG: grey or RGB; alpha is dropped (JPEG has none).
    const std::uint32_t c = image.channels;
    std::vector<std::uint8_t> packed;
    const std::uint8_t* src = image.texels.data();
    const bool grey = c <= 2;
    if (c == 2 || c == 4) {
        const std::uint32_t keep = c - 1;
        const std::size_t n = std::size_t(image.width) * image.height;
        packed.resize(n * keep);
        for (std::size_t i = 0; i < n; ++i) std::memcpy(&packed[i * keep], &image.texels[i * c], keep);
        src = packed.data();
    }
    // One encoder per thread, and for images up to a web tile's size its output buffer too: a
    // tile's encode then allocates only the string it returns.
    struct Encoder {
        tjhandle tj = tjInitCompress();
        unsigned char* buf = nullptr;
        unsigned long capacity = 0;
        ~Encoder() {
            tjFree(buf);
            if (tj) tjDestroy(tj);
        }
    };
    thread_local Encoder enc;
    if (!enc.tj) {
        failure = {500, "JPEG encoder could not start"};
        return std::nullopt;
    }
    const int samp = grey ? TJSAMP_GRAY : TJSAMP_444;
    const unsigned long bound = tjBufSize(int(image.width), int(image.height), samp);
    constexpr unsigned long kKeptBuffer = 1 << 20;
    const bool kept = bound <= kKeptBuffer;
    if (kept && enc.capacity < kKeptBuffer) {
        tjFree(enc.buf);
        enc.buf = tjAlloc(int(kKeptBuffer));
        enc.capacity = enc.buf ? kKeptBuffer : 0;
    }
    unsigned char* buf = kept ? enc.buf : nullptr;
    unsigned long size = kept ? enc.capacity : 0;
    const int rc = tjCompress2(enc.tj, src, int(image.width), 0, int(image.height), grey ? TJPF_GRAY : TJPF_RGB, &buf, &size,
                               samp, 90, TJFLAG_FASTDCT | (kept && buf ? TJFLAG_NOREALLOC : 0));
    std::optional<std::string> out;
    if (rc == 0) out.emplace(reinterpret_cast<const char*>(buf), size);
    else failure = {500, std::string("JPEG encoding failed: ") + tjGetErrorStr2(enc.tj)};
    if (buf != enc.buf) tjFree(buf);
    return out;
}

std::shared_ptr<const std::string> WebTileCache::find(const std::string& key) {
    if (capacity_ == 0) return nullptr;
    std::lock_guard lock(mutex_);
    const auto it = index_.find(key);
    if (it == index_.end()) return nullptr;
    lru_.splice(lru_.begin(), lru_, it->second);
    return it->second->body;
}

void WebTileCache::insert(const std::string& key, std::shared_ptr<const std::string> body) {
    const std::size_t size = body->size() + key.size();
    if (capacity_ == 0 || size > capacity_ / 8) return;  // no single entry takes much of the cache
    std::lock_guard lock(mutex_);
    if (index_.count(key)) return;
    lru_.push_front(Entry{key, std::move(body)});
    index_.emplace(key, lru_.begin());
    bytes_ += size;
    while (bytes_ > capacity_ && !lru_.empty()) {
        const Entry& e = lru_.back();
        bytes_ -= e.body->size() + e.key.size();
        index_.erase(e.key);
        lru_.pop_back();
    }
}

std::size_t WebTileCache::bytes() const {
    std::lock_guard lock(mutex_);
    return bytes_;
}

}  // namespace tessera::server::httpapi
