// The HTTP request handler (server/src/http_handler.*), transport-free: small stores in a scratch
// directory, a ServerContext made by hand, and requests handed straight to the handler. Also the
// PNG encoder, checked by inflating and unfiltering its IDAT back to the decoded tile.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <unistd.h>
#include <zlib.h>

#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "http/common.hpp"
#include "http/web_image.hpp"
#include "http_handler.hpp"
#include "log.hpp"
#include "metrics.hpp"
#include "tessera/storage/png_encode.hpp"
#include "prometheus_text.hpp"
#include "server_context.hpp"
#include "store_registry.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/layers.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/store_writer.hpp"
#include "test_util.hpp"
#include "tile_cache.hpp"
#include "tile_fetcher.hpp"

// After the protobuf headers: OpenImageIO defines bswap_16 only, which misleads protobuf's port.h.
#include <OpenImageIO/imageio.h>

using namespace tessera;
using namespace tessera::server;
using tessera::Codec;
using storage::ColourSpace;
using storage::SampleType;
using storage::StoreSpec;
using tessera::TileKey;
using tessera::TileKind;
using tessera::test::ScratchDir;

namespace {

std::string hex16(std::uint64_t v) {
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(v));
    return buf;
}

std::vector<std::uint8_t> random_bytes(std::size_t n, std::uint32_t seed) {
    std::vector<std::uint8_t> v(n);
    std::mt19937 rng(seed);
    for (auto& b : v) b = static_cast<std::uint8_t>(rng());
    return v;
}

// Smooth texels (JPEG-friendly): a gradient plus a little noise.
std::vector<std::uint8_t> smooth_bytes(std::size_t n, std::uint32_t seed) {
    std::vector<std::uint8_t> v(n);
    std::mt19937 rng(seed);
    for (std::size_t i = 0; i < n; ++i) v[i] = static_cast<std::uint8_t>((i / 7 + rng() % 8) & 0xff);
    return v;
}

StoreSpec spec_of(std::uint32_t w, std::uint32_t h, std::uint32_t payload, std::uint32_t border, std::uint32_t channels,
                  SampleType st, ColourSpace cs, Codec codec, bool alpha = false) {
    StoreSpec s;
    s.width = w;
    s.height = h;
    s.tile_payload = payload;
    s.border = border;
    s.channels = channels;
    s.sample_type = st;
    s.colour_space = cs;
    s.codec = codec;
    s.has_alpha = alpha;
    return s;
}

enum class Make { present, uniform, absent };

// Writes a store with every tile of every level: `kind` decides each tile's kind; present tiles
// are distinct texels encoded in the store's codec, uniform tiles the texel {7, 7, ...}.
void write_store(const std::string& path, const StoreSpec& spec,
                 const std::function<Make(const TileKey&)>& kind = {}) {
    auto w = storage::StoreWriter::create(path, spec);
    ASSERT_TRUE(w.ok()) << w.error().message;
    const storage::StoreInfo info = storage::store_info(spec);
    std::uint32_t seed = 1;
    for (std::uint32_t l = 0; l < info.level_count(); ++l)
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                const TileKey k{l, x, y};
                const Make m = kind ? kind(k) : Make::present;
                if (m == Make::absent) continue;
                if (m == Make::uniform) {
                    const std::vector<std::uint8_t> value(info.texel_bytes(), 7);
                    ASSERT_TRUE((*w)->add_uniform(k, value).ok());
                    continue;
                }
                const auto texels = spec.codec == Codec::jpeg ? smooth_bytes(info.tile_bytes(), seed++)
                                                              : random_bytes(info.tile_bytes(), seed++);
                auto payload = storage::encode_tile(info, texels, {});
                ASSERT_TRUE(payload.ok()) << payload.error().message;
                ASSERT_TRUE((*w)->add_present(k, *payload).ok());
            }
    ASSERT_TRUE((*w)->finish().ok());
}

// A server context over a scratch directory of stores, made by hand.
class HandlerTest : public ::testing::Test {
protected:
    void SetUp() override {
        // rgb: 40x30, tiles 16 (payload 12, border 2), 3 levels; level 0 tile (2,2) uniform,
        // (3,2) absent.
        write_store(dir_.file("rgb.tsr"), spec_of(40, 30, 12, 2, 3, SampleType::u8, ColourSpace::srgb, Codec::raw),
                    [](const TileKey& k) {
                        if (k.level == 0 && k.x == 2 && k.y == 2) return Make::uniform;
                        if (k.level == 0 && k.x == 3 && k.y == 2) return Make::absent;
                        return Make::present;
                    });
        write_store(dir_.file("photo.tsr"), spec_of(30, 20, 16, 4, 3, SampleType::u8, ColourSpace::srgb, Codec::jpeg));
        write_store(dir_.file("grey.tsr"), spec_of(16, 16, 16, 0, 1, SampleType::u8, ColourSpace::linear, Codec::jpeg));
        write_store(dir_.file("heights.tsr"), spec_of(20, 20, 12, 2, 1, SampleType::u16, ColourSpace::linear, Codec::zstd));
        write_store(dir_.file("greya.tsr"), spec_of(8, 8, 8, 0, 2, SampleType::u8, ColourSpace::srgb, Codec::zstd, true));
        write_store(dir_.file("rgba16.tsr"), spec_of(8, 8, 4, 2, 4, SampleType::u16, ColourSpace::linear, Codec::raw, true));
        write_store(dir_.file("floats.tsr"), spec_of(8, 8, 8, 0, 1, SampleType::f32, ColourSpace::linear, Codec::raw));
        config_.store_dirs = {dir_.path().string()};
        config_.http_max_age = 60;
        config_.cache_bytes = 1 << 20;
    }

    // Opens the registry and builds the context (after the test has arranged its files).
    void start() {
        null_fd_ = ::open("/dev/null", O_WRONLY | O_CLOEXEC);
        log_ = std::make_unique<Logger>(LogFormat::text, LogLevel::error, null_fd_);
        metrics_ = std::make_unique<MetricsRegistry>();
        stores_ = std::make_unique<StoreRegistry>(config_.store_files, config_.store_dirs, *log_, *metrics_);
        ASSERT_TRUE(stores_->open().ok());
        cache_ = std::make_unique<TileCache>(config_.cache_bytes);
        fetcher_ = std::make_unique<TileFetcher>(*cache_, *metrics_, *log_, decoded_bytes_);
        ctx_.reset(new ServerContext{config_, *log_, *metrics_, *stores_, *fetcher_});
        ctx_->ready = true;
        handler_ = std::make_unique<HttpHandler>(*ctx_);
    }

    void TearDown() override {
        handler_.reset();
        ctx_.reset();
        fetcher_.reset();  // before the registry: they remove their gauge callbacks from it
        cache_.reset();
        stores_.reset();
        metrics_.reset();
        log_.reset();
        if (null_fd_ >= 0) ::close(null_fd_);
    }

    HttpResponse get(std::string_view target, std::string_view if_none_match = {}, std::string_view auth = {},
                     std::string_view method = "GET") {
        if (!handler_) start();
        HttpRequestView req;
        req.method = method;
        req.target = target;
        req.authorization = auth;
        req.if_none_match = if_none_match;
        return handler_->handle_http_request(req);
    }

    // A GET of `target` whose request `adjust` changes first (the headers get() does not take).
    HttpResponse get_with(std::string_view target, const std::function<void(HttpRequestView&)>& adjust) {
        if (!handler_) start();
        HttpRequestView req;
        req.method = "GET";
        req.target = target;
        adjust(req);
        return handler_->handle_http_request(req);
    }

    std::shared_ptr<storage::StoreReader> reader(const std::string& name) {
        auto r = storage::StoreReader::open(dir_.file(name + ".tsr"));
        EXPECT_TRUE(r.ok());
        return r.ok() ? *r : nullptr;
    }

    ScratchDir dir_;
    ServerConfig config_;
    std::size_t decoded_bytes_ = 0;  // the fetcher's cache of tiles decoded for web images
    int null_fd_ = -1;
    std::unique_ptr<Logger> log_;
    std::unique_ptr<MetricsRegistry> metrics_;
    std::unique_ptr<StoreRegistry> stores_;
    std::unique_ptr<TileCache> cache_;
    std::unique_ptr<TileFetcher> fetcher_;
    std::unique_ptr<ServerContext> ctx_;
    std::unique_ptr<HttpHandler> handler_;
};

std::string body_of(const std::vector<std::uint8_t>& v) { return std::string(v.begin(), v.end()); }

// ---- PNG decoding, for the checks: chunks, CRCs, inflate, unfilter -------------------------

struct Png {
    std::uint32_t width = 0, height = 0;
    unsigned bit_depth = 0, colour_type = 0, compression = 0, filter = 0, interlace = 0;
    std::vector<std::string> chunks;         // types in file order
    std::map<std::string, std::string> data;  // first chunk of each type (IDAT: all concatenated)
    std::vector<std::uint8_t> pixels;        // unfiltered; 16-bit samples converted to little-endian
};

std::uint32_t be32(const std::uint8_t* p) {
    return (std::uint32_t(p[0]) << 24) | (std::uint32_t(p[1]) << 16) | (std::uint32_t(p[2]) << 8) | p[3];
}

int paeth(int a, int b, int c) {
    const int p = a + b - c, pa = std::abs(p - a), pb = std::abs(p - b), pc = std::abs(p - c);
    if (pa <= pb && pa <= pc) return a;
    return pb <= pc ? b : c;
}

// Decodes what encode_png writes (and any non-interlaced grey/GA/RGB/RGBA PNG); failures are
// gtest failures and an empty result.
Png decode_png(const std::string& file) {
    Png png;
    const auto* p = reinterpret_cast<const std::uint8_t*>(file.data());
    static const std::uint8_t sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    if (file.size() < 8 || std::memcmp(p, sig, 8) != 0) {
        ADD_FAILURE() << "no PNG signature";
        return {};
    }
    std::string idat;
    for (std::size_t at = 8; at < file.size();) {
        if (at + 12 > file.size()) {
            ADD_FAILURE() << "truncated chunk";
            return {};
        }
        const std::uint32_t len = be32(p + at);
        const std::string type(file.data() + at + 4, 4);
        if (at + 12 + len > file.size()) {
            ADD_FAILURE() << "chunk " << type << " overruns the file";
            return {};
        }
        const std::uint32_t crc = be32(p + at + 8 + len);
        EXPECT_EQ(crc, static_cast<std::uint32_t>(crc32(crc32(0, nullptr, 0), p + at + 4, len + 4))) << "CRC of " << type;
        const std::string body(file.data() + at + 8, len);
        png.chunks.push_back(type);
        if (type == "IDAT") idat += body;
        else if (!png.data.count(type)) png.data[type] = body;
        at += 12 + len;
    }
    if (png.chunks.empty() || png.chunks.front() != "IHDR" || png.chunks.back() != "IEND") {
        ADD_FAILURE() << "IHDR must come first and IEND last";
        return {};
    }
    const auto* ih = reinterpret_cast<const std::uint8_t*>(png.data["IHDR"].data());
    EXPECT_EQ(png.data["IHDR"].size(), 13u);
    png.width = be32(ih);
    png.height = be32(ih + 4);
    png.bit_depth = ih[8];
    png.colour_type = ih[9];
    png.compression = ih[10];
    png.filter = ih[11];
    png.interlace = ih[12];
    const unsigned channels = png.colour_type == 0 ? 1 : png.colour_type == 4 ? 2 : png.colour_type == 2 ? 3 : 4;
    const std::size_t bpp = channels * png.bit_depth / 8;
    const std::size_t row = png.width * bpp;
    std::vector<std::uint8_t> raw((row + 1) * png.height);
    uLongf raw_len = static_cast<uLongf>(raw.size());
    const int zr = uncompress(raw.data(), &raw_len, reinterpret_cast<const Bytef*>(idat.data()), static_cast<uLong>(idat.size()));
    if (zr != Z_OK || raw_len != raw.size()) {
        ADD_FAILURE() << "IDAT does not inflate to " << raw.size() << " bytes (zlib " << zr << ", " << raw_len << ")";
        return {};
    }
    png.pixels.assign(row * png.height, 0);
    for (std::size_t y = 0; y < png.height; ++y) {
        const std::uint8_t ft = raw[y * (row + 1)];
        const std::uint8_t* in = raw.data() + y * (row + 1) + 1;
        std::uint8_t* out = png.pixels.data() + y * row;
        const std::uint8_t* up = y ? out - row : nullptr;
        for (std::size_t i = 0; i < row; ++i) {
            const int a = i >= bpp ? out[i - bpp] : 0, b = up ? up[i] : 0, c = (up && i >= bpp) ? up[i - bpp] : 0;
            int pred = 0;
            switch (ft) {
                case 0: pred = 0; break;
                case 1: pred = a; break;
                case 2: pred = b; break;
                case 3: pred = (a + b) / 2; break;
                case 4: pred = paeth(a, b, c); break;
                default: ADD_FAILURE() << "filter type " << int(ft); return {};
            }
            out[i] = static_cast<std::uint8_t>(in[i] + pred);
        }
    }
    if (png.bit_depth == 16)
        for (std::size_t i = 0; i + 1 < png.pixels.size(); i += 2) std::swap(png.pixels[i], png.pixels[i + 1]);
    return png;
}

}  // namespace

// ---- Tiles: bytes, headers, ETags --------------------------------------------------------------

TEST_F(HandlerTest, TileBytesAreTheStoredPayload) {
    auto r = reader("rgb");
    const auto& info = r->info();
    for (std::uint32_t l = 0; l < info.level_count(); ++l)
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                const auto tile = r->read_tile({l, x, y});
                ASSERT_TRUE(tile.ok());
                const std::string target = "/v1/stores/rgb/tiles/" + std::to_string(l) + "/" + std::to_string(x) + "/" + std::to_string(y);
                const HttpResponse res = get(target);
                SCOPED_TRACE(target);
                if (tile->kind == TileKind::absent) {
                    EXPECT_EQ(res.status, 404u);
                    EXPECT_NE(res.body.find("tile absent in a sparse store"), std::string::npos) << res.body;
                    continue;
                }
                ASSERT_EQ(res.status, 200u) << res.body;
                EXPECT_EQ(res.route, HttpRoute::tile);
                EXPECT_EQ(res.body, body_of(tile->bytes));
                EXPECT_EQ(res.content_type, "application/octet-stream");
                ASSERT_NE(res.header("X-Tessera-Checksum"), nullptr);
                EXPECT_EQ(*res.header("X-Tessera-Checksum"), hex16(tile->checksum));
                EXPECT_EQ(*res.header("X-Tessera-Store-Version"), hex16(info.store_id));
                EXPECT_EQ(*res.header("X-Tessera-Kind"), tile->kind == TileKind::uniform ? "uniform" : "present");
                EXPECT_EQ(*res.header("X-Tessera-Codec"), tile->kind == TileKind::uniform ? "uniform" : "raw");
                EXPECT_EQ(*res.header("ETag"), "\"" + hex16(info.store_id) + "-" + hex16(tile->checksum) + "\"");
                EXPECT_EQ(*res.header("Cache-Control"), "public, max-age=60");
                EXPECT_EQ(*res.header("Server"), "tessera/0.1");
            }
    // The uniform tile's body is its one texel.
    EXPECT_EQ(get("/v1/stores/rgb/tiles/0/2/2").body, std::string(3, '\x07'));
}

TEST_F(HandlerTest, ContentTypesFollowTheCodec) {
    EXPECT_EQ(get("/v1/stores/photo/tiles/0/0/0").content_type, "image/jpeg");
    EXPECT_EQ(*get("/v1/stores/photo/tiles/0/0/0").header("X-Tessera-Codec"), "jpeg");
    EXPECT_EQ(get("/v1/stores/heights/tiles/0/0/0").content_type, "application/zstd");
    EXPECT_EQ(*get("/v1/stores/heights/tiles/0/0/0").header("X-Tessera-Codec"), "zstd");
    EXPECT_EQ(get("/v1/stores/rgb/tiles/0/0/0").content_type, "application/octet-stream");
    EXPECT_EQ(get("/v1/stores/rgb/tiles/0/2/2").content_type, "application/octet-stream");  // uniform
    EXPECT_EQ(get("/v1/stores/rgb/tiles/0/0/0?format=png").content_type, "image/png");
    // JPEG payloads really are JPEG (SOI marker).
    const std::string jpeg = get("/v1/stores/photo/tiles/0/0/0").body;
    ASSERT_GE(jpeg.size(), 2u);
    EXPECT_EQ(static_cast<unsigned char>(jpeg[0]), 0xFF);
    EXPECT_EQ(static_cast<unsigned char>(jpeg[1]), 0xD8);
}

TEST_F(HandlerTest, IfNoneMatchAnswers304) {
    const HttpResponse first = get("/v1/stores/rgb/tiles/1/1/0");
    ASSERT_EQ(first.status, 200u);
    const std::string etag = first.header("ETag")->str();
    ASSERT_EQ(etag.size(), 2u + 16 + 1 + 16);

    auto expect_304 = [&](std::string_view inm) {
        SCOPED_TRACE(std::string(inm));
        const HttpResponse r = get("/v1/stores/rgb/tiles/1/1/0", inm);
        EXPECT_EQ(r.status, 304u);
        EXPECT_TRUE(r.body.empty());
        ASSERT_NE(r.header("ETag"), nullptr);
        EXPECT_EQ(*r.header("ETag"), etag);
        ASSERT_NE(r.header("Cache-Control"), nullptr);
        EXPECT_EQ(*r.header("Cache-Control"), "public, max-age=60");
    };
    expect_304(etag);
    expect_304("*");
    expect_304("W/" + etag);                       // weak comparison
    expect_304("\"other\", W/\"x\", " + etag);     // a list
    expect_304("\"other\",W/" + etag);

    EXPECT_EQ(get("/v1/stores/rgb/tiles/1/1/0", "\"other\"").status, 200u);
    EXPECT_EQ(get("/v1/stores/rgb/tiles/1/0/0", etag).status, 200u);         // another tile's ETag
    EXPECT_EQ(get("/v1/stores/rgb/tiles/1/1/0?format=png", etag).status, 200u);  // another representation
    // No current representation: '*' does not match an absent tile.
    EXPECT_EQ(get("/v1/stores/rgb/tiles/0/3/2", "*").status, 404u);

    // The PNG has its own ETag, with a -png suffix inside the quotes.
    const HttpResponse png = get("/v1/stores/rgb/tiles/1/1/0?format=png");
    ASSERT_EQ(png.status, 200u);
    EXPECT_EQ(*png.header("ETag"), etag.substr(0, etag.size() - 1) + "-png\"");
    EXPECT_EQ(get("/v1/stores/rgb/tiles/1/1/0?format=png", *png.header("ETag")).status, 304u);
    // Uniform tiles too.
    const HttpResponse uni = get("/v1/stores/rgb/tiles/0/2/2");
    EXPECT_EQ(get("/v1/stores/rgb/tiles/0/2/2", *uni.header("ETag")).status, 304u);
}

TEST_F(HandlerTest, VersionedUrlsAreImmutable) {
    const std::string version = hex16(reader("rgb")->info().store_id);
    const HttpResponse r = get("/v1/stores/rgb/tiles/0/0/0?v=" + version);
    ASSERT_EQ(r.status, 200u);
    EXPECT_EQ(*r.header("Cache-Control"), "public, max-age=31536000, immutable");
    // Either case of hex, and with format.
    std::string upper = version;
    for (auto& c : upper) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
    EXPECT_EQ(get("/v1/stores/rgb/tiles/0/0/0?format=png&v=" + upper).status, 200u);
    // Another version is not served: 404 naming both.
    const std::string other = hex16(reader("rgb")->info().store_id ^ 1);
    const HttpResponse stale = get("/v1/stores/rgb/tiles/0/0/0?v=" + other);
    EXPECT_EQ(stale.status, 404u);
    EXPECT_NE(stale.body.find(other), std::string::npos) << stale.body;
    EXPECT_NE(stale.body.find(version), std::string::npos) << stale.body;
    EXPECT_EQ(*stale.header("Cache-Control"), "no-store");
}

TEST_F(HandlerTest, HeadGivesTheSameHeadersAndLength) {
    const HttpResponse g = get("/v1/stores/rgb/tiles/0/1/1");
    const HttpResponse h = get("/v1/stores/rgb/tiles/0/1/1", {}, {}, "HEAD");
    EXPECT_EQ(h.status, 200u);
    EXPECT_EQ(h.body.size(), g.body.size());  // the transport sends only the headers
    EXPECT_EQ(*h.header("ETag"), *g.header("ETag"));
    EXPECT_EQ(h.content_type, g.content_type);
}

// ---- PNG ------------------------------------------------------------------------------------------

TEST_F(HandlerTest, PngDecodesToTheDecodedTileExactly) {
    struct Case {
        std::string store;
        unsigned colour_type, bit_depth;
        bool srgb;
    };
    const std::vector<Case> cases = {
        {"rgb", 2, 8, true},      {"photo", 2, 8, true},  {"grey", 0, 8, false},
        {"heights", 0, 16, false}, {"greya", 4, 8, true}, {"rgba16", 6, 16, false},
    };
    for (const Case& c : cases) {
        SCOPED_TRACE(c.store);
        auto r = reader(c.store);
        const auto& info = r->info();
        for (std::uint32_t l = 0; l < info.level_count(); ++l)
            for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
                for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                    const std::string target = "/v1/stores/" + c.store + "/tiles/" + std::to_string(l) + "/" +
                                               std::to_string(x) + "/" + std::to_string(y) + "?format=png";
                    SCOPED_TRACE(target);
                    const auto tile = r->read_tile({l, x, y});
                    ASSERT_TRUE(tile.ok());
                    if (tile->kind == TileKind::absent) continue;
                    std::vector<std::uint8_t> decoded;
                    ASSERT_TRUE(storage::decode_tile(info, *tile, decoded).ok());
                    const HttpResponse res = get(target);
                    ASSERT_EQ(res.status, 200u) << res.body;
                    EXPECT_EQ(res.route, HttpRoute::tile_png);
                    EXPECT_EQ(res.content_type, "image/png");
                    const Png png = decode_png(res.body);
                    EXPECT_EQ(png.width, info.tile_size());
                    EXPECT_EQ(png.height, info.tile_size());
                    EXPECT_EQ(png.colour_type, c.colour_type);
                    EXPECT_EQ(png.bit_depth, c.bit_depth);
                    EXPECT_EQ(png.compression, 0u);
                    EXPECT_EQ(png.filter, 0u);
                    EXPECT_EQ(png.interlace, 0u);
                    if (c.srgb) {
                        EXPECT_EQ(png.data.count("sRGB"), 1u);
                        EXPECT_EQ(png.data.count("gAMA"), 0u);
                    } else {
                        ASSERT_EQ(png.data.count("gAMA"), 1u);
                        EXPECT_EQ(be32(reinterpret_cast<const std::uint8_t*>(png.data.at("gAMA").data())), 100000u);
                        EXPECT_EQ(png.data.count("sRGB"), 0u);
                    }
                    EXPECT_EQ(png.pixels, decoded);
                }
    }
}

// An independent decoder (libpng, through OpenImageIO) reads the same texels back.
TEST_F(HandlerTest, PngReadsBackWithLibpng) {
    for (const char* store : {"rgb", "heights", "greya", "rgba16"}) {
        SCOPED_TRACE(store);
        auto r = reader(store);
        const auto& info = r->info();
        const auto tile = r->read_tile({0, 0, 0});
        ASSERT_TRUE(tile.ok());
        std::vector<std::uint8_t> decoded;
        ASSERT_TRUE(storage::decode_tile(info, *tile, decoded).ok());
        const HttpResponse res = get(std::string("/v1/stores/") + store + "/tiles/0/0/0?format=png");
        ASSERT_EQ(res.status, 200u);
        const std::string path = dir_.file(std::string(store) + ".png");
        tessera::test::write_file(path, std::vector<std::uint8_t>(res.body.begin(), res.body.end()));
        OIIO::ImageSpec config;
        config.attribute("oiio:UnassociatedAlpha", 1);  // PNG alpha is straight; keep it so
        auto in = OIIO::ImageInput::open(path, &config);
        ASSERT_TRUE(in) << OIIO::geterror();
        const OIIO::ImageSpec& spec = in->spec();
        EXPECT_EQ(spec.width, int(info.tile_size()));
        EXPECT_EQ(spec.height, int(info.tile_size()));
        EXPECT_EQ(spec.nchannels, int(info.channels));
        EXPECT_EQ(spec.format, info.sample_type == SampleType::u16 ? OIIO::TypeDesc::UINT16 : OIIO::TypeDesc::UINT8);
        std::vector<std::uint8_t> pixels(decoded.size());
        ASSERT_TRUE(in->read_image(0, 0, 0, spec.nchannels, spec.format, pixels.data()));
        EXPECT_EQ(pixels, decoded);
    }
}

TEST(PngEncode, RefusesFloatsAndWrongSizes) {
    storage::StoreInfo info = storage::store_info(spec_of(8, 8, 8, 0, 1, SampleType::f32, ColourSpace::linear, Codec::raw));
    std::vector<std::uint8_t> texels(info.tile_bytes());
    auto r = storage::encode_tile_png(info, texels);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, Errc::unsupported);
    EXPECT_NE(r.error().message.find("f32"), std::string::npos) << r.error().message;
    info.sample_type = SampleType::f16;
    EXPECT_EQ(storage::encode_tile_png(info, std::vector<std::uint8_t>(info.tile_bytes())).error().code, Errc::unsupported);
    info.sample_type = SampleType::u8;
    EXPECT_EQ(storage::encode_tile_png(info, std::vector<std::uint8_t>(info.tile_bytes() - 1)).error().code, Errc::invalid_argument);
    EXPECT_TRUE(storage::encode_tile_png(info, std::vector<std::uint8_t>(info.tile_bytes())).ok());
}

TEST_F(HandlerTest, FloatStoresHaveNoPng) {
    const HttpResponse r = get("/v1/stores/floats/tiles/0/0/0?format=png");
    EXPECT_EQ(r.status, 406u);
    EXPECT_NE(r.body.find("f32"), std::string::npos) << r.body;
    EXPECT_EQ(get("/v1/stores/floats/tiles/0/0/0").status, 200u);  // the stored payload is fine
}

// A multi-layer store: the tile route serves the bundle as stored; ?format=png shows one layer,
// ?layer=NAME (default: the first), each with its own ETag.
TEST_F(HandlerTest, LayeredStoreBundlesAndOnePngPerLayer) {
    StoreSpec spec = spec_of(40, 30, 12, 2, 3, SampleType::u8, ColourSpace::srgb, Codec::layers);
    spec.layers = {storage::LayerInfo{"colour", 3, SampleType::u8, ColourSpace::srgb, Codec::raw},
                   storage::LayerInfo{"normal", 2, SampleType::u8, ColourSpace::linear, Codec::zstd},
                   storage::LayerInfo{"height", 1, SampleType::u16, ColourSpace::linear, Codec::zstd},
                   storage::LayerInfo{"depth", 1, SampleType::f32, ColourSpace::linear, Codec::raw}};
    const storage::StoreInfo info = storage::store_info(spec);
    {
        // Level 0 tile (1,0): normal absent, height uniform; (2,0): absent; the rest all present.
        auto w = storage::StoreWriter::create(dir_.file("layers.tsr"), spec);
        ASSERT_TRUE(w.ok()) << w.error().message;
        std::uint32_t seed = 1;
        for (std::uint32_t l = 0; l < info.level_count(); ++l)
            for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
                for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                    if (l == 0 && x == 2 && y == 0) continue;
                    std::vector<std::vector<std::uint8_t>> bytes(4);
                    std::vector<storage::LayerPart> parts(4);
                    for (std::size_t i = 0; i < 4; ++i) {
                        const storage::StoreInfo li = storage::layer_store_info(info, i);
                        if (l == 0 && x == 1 && y == 0 && i == 1) continue;  // absent
                        if (l == 0 && x == 1 && y == 0 && i == 2) {
                            bytes[i] = {0x34, 0x12};
                            parts[i] = {TileKind::uniform, bytes[i]};
                            continue;
                        }
                        auto payload = storage::encode_tile(li, random_bytes(li.tile_bytes(), seed++), {});
                        ASSERT_TRUE(payload.ok()) << payload.error().message;
                        bytes[i] = std::move(*payload);
                        parts[i] = {TileKind::present, bytes[i]};
                    }
                    ASSERT_TRUE((*w)->add_present({l, x, y}, storage::join_layers(parts)).ok());
                }
        ASSERT_TRUE((*w)->finish().ok());
    }
    auto r = reader("layers");
    ASSERT_TRUE(r);
    const std::string base = "/v1/stores/layers/tiles/0/";

    // The stored bundle, as it is.
    const auto stored = r->read_tile({0, 0, 0});
    ASSERT_TRUE(stored.ok());
    HttpResponse res = get(base + "0/0");
    ASSERT_EQ(res.status, 200u) << res.body;
    EXPECT_EQ(res.content_type, "application/x-tessera-layers");
    EXPECT_EQ(*res.header("X-Tessera-Codec"), "layers");
    EXPECT_EQ(res.body, body_of(stored->bytes));

    // One PNG per layer: the part decoded with its layer's description.
    auto parts = storage::split_layers(r->info(), stored->bytes);
    ASSERT_TRUE(parts.ok());
    std::set<std::string> etags;
    for (std::size_t i = 0; i < 3; ++i) {
        const std::string& name = info.layers[i].name;
        SCOPED_TRACE(name);
        std::vector<std::uint8_t> decoded;
        ASSERT_TRUE(storage::decode_tile(storage::layer_store_info(r->info(), i), storage::layer_tile({0, 0, 0}, (*parts)[i]), decoded).ok());
        res = get(base + "0/0?format=png&layer=" + name);
        ASSERT_EQ(res.status, 200u) << res.body;
        EXPECT_EQ(res.content_type, "image/png");
        EXPECT_EQ(*res.header("X-Tessera-Layer"), name);
        EXPECT_EQ(decode_png(res.body).pixels, decoded);
        const std::string etag = res.header("ETag")->str();
        EXPECT_NE(etag.find("-png-" + name + "\""), std::string::npos) << etag;
        EXPECT_TRUE(etags.insert(etag).second);
        EXPECT_EQ(get(base + "0/0?layer=" + name + "&format=png", etag).status, 304u);
        if (i == 0) {
            const HttpResponse plain = get(base + "0/0?format=png");  // the first layer by default
            ASSERT_EQ(plain.status, 200u);
            EXPECT_EQ(*plain.header("ETag"), etag);
            EXPECT_EQ(plain.body, res.body);
        } else {
            EXPECT_EQ(get(base + "0/0?format=png&layer=colour", etag).status, 200u) << "another layer's ETag";
        }
    }
    // A uniform part is a PNG of one value; an absent part is a definite 404.
    res = get(base + "1/0?format=png&layer=height");
    ASSERT_EQ(res.status, 200u) << res.body;
    EXPECT_EQ(*res.header("X-Tessera-Kind"), "uniform");
    const Png uniform = decode_png(res.body);
    ASSERT_EQ(uniform.pixels.size(), std::size_t(info.tile_size()) * info.tile_size() * 2);
    EXPECT_EQ(uniform.pixels[0], 0x34);
    EXPECT_EQ(uniform.pixels[1], 0x12);
    res = get(base + "1/0?format=png&layer=normal");
    EXPECT_EQ(res.status, 404u);
    EXPECT_NE(res.body.find("layer 'normal' of this tile is absent"), std::string::npos) << res.body;
    EXPECT_NE(res.header("Cache-Control")->view().find("max-age"), std::string::npos);
    EXPECT_EQ(get(base + "2/0").status, 404u);

    // What a layer cannot be.
    res = get(base + "0/0?format=png&layer=nosuch");
    EXPECT_EQ(res.status, 400u);
    EXPECT_NE(res.body.find("unknown layer 'nosuch'"), std::string::npos) << res.body;
    EXPECT_NE(res.body.find("colour, normal, height, depth"), std::string::npos) << res.body;
    res = get(base + "0/0?format=png&layer=depth");
    EXPECT_EQ(res.status, 406u);
    EXPECT_NE(res.body.find("f32"), std::string::npos) << res.body;
    res = get(base + "0/0?layer=normal");
    EXPECT_EQ(res.status, 400u);
    EXPECT_NE(res.body.find("format=png"), std::string::npos) << res.body;
    EXPECT_EQ(get(base + "0/0?format=png&layer=normal&layer=height").status, 400u);
    res = get("/v1/stores/rgb/tiles/0/0/0?format=png&layer=colour");
    EXPECT_EQ(res.status, 400u);
    EXPECT_NE(res.body.find("has no layers"), std::string::npos) << res.body;
    EXPECT_EQ(get("/v1/stores/layers?layer=colour").status, 400u);

    // The description lists the layers.
    res = get("/v1/stores/layers");
    ASSERT_EQ(res.status, 200u);
    const auto j = nlohmann::json::parse(res.body);
    EXPECT_EQ(j.at("codec"), "layers");
    ASSERT_EQ(j.at("layers").size(), 4u);
    EXPECT_EQ(j.at("layers")[2].at("name"), "height");
    EXPECT_EQ(j.at("layers")[2].at("sample_type"), "u16");
    EXPECT_GT(j.at("layers")[2].at("payload_bytes").get<std::uint64_t>(), 0u);
}

// ---- Bad input, table-driven --------------------------------------------------------------------

TEST_F(HandlerTest, EveryBadInputGetsItsStatus) {
    const std::uint64_t version = reader("rgb")->info().store_id;
    const std::vector<std::pair<std::string, unsigned>> table = {
        {"/v1/stores/rgb/tiles/0/0/0", 200},
        {"/v1/stores/rgb/tiles/2/0/0", 200},
        // malformed numbers
        {"/v1/stores/rgb/tiles/+0/0/0", 400},
        {"/v1/stores/rgb/tiles/-1/0/0", 400},
        {"/v1/stores/rgb/tiles/0/-0/0", 400},
        {"/v1/stores/rgb/tiles/0/a/0", 400},
        {"/v1/stores/rgb/tiles/0/0x1/0", 400},
        {"/v1/stores/rgb/tiles/0/1.0/0", 400},
        {"/v1/stores/rgb/tiles/0/ 1/0", 400},
        {"/v1/stores/rgb/tiles/00/0/0", 400},
        {"/v1/stores/rgb/tiles/0/0/4294967296", 400},
        {"/v1/stores/rgb/tiles/0/0/18446744073709551617", 400},
        {"/v1/stores/rgb/tiles/0/0/99999999999", 400},
        // empty and extra segments
        {"/v1/stores/rgb/tiles/0//0", 400},
        {"/v1/stores/rgb/tiles//0/0", 400},
        {"/v1/stores/rgb/tiles/0/0/0/", 400},
        {"/v1/stores/rgb/tiles/0/0/0/1", 400},
        {"/v1/stores/rgb/tiles/0/0", 400},
        {"/v1/stores/rgb/tiles", 400},
        {"/v1//stores/rgb", 400},
        {"/v1/stores/", 400},
        // dot segments, percent-encoded slashes and dots, bad escapes
        {"/v1/stores/../tiles/0/0/0", 400},
        {"/v1/stores/./rgb", 400},
        {"/v1/stores/rgb/tiles/0/0/0/..", 400},
        {"/v1/stores/%2e%2e/tiles/0/0/0", 400},
        {"/v1/stores/%2E%2E", 400},
        {"/v1/stores/a%2fb/tiles/0/0/0", 400},
        {"/v1/stores/rgb%2Ftiles/0/0/0", 400},
        {"/v1/stores/rgb/tiles/0/0/0%", 400},
        {"/v1/stores/rgb/tiles/0/0/0%4", 400},
        {"/v1/stores/rgb/tiles/0/0/%zz", 400},
        {"/v1/stores/rgb/tiles/0/0/%00", 400},
        {"/v1/stores/r%67b/tiles/0/0/0", 200},  // an escaped letter is just the letter
        // characters that must be encoded, fragments, relative targets
        {"/v1/stores/rgb/tiles/0/0/0#x", 400},
        {"/v1/stores/r b", 400},
        {"/v1/stores/r\"b", 400},
        {"v1/stores/rgb", 400},
        {"*", 400},
        {"http://example.com/v1/stores/rgb", 400},
        // invalid store names
        {"/v1/stores/..", 400},
        {"/v1/stores/a..b", 400},
        {"/v1/stores/.hidden", 400},
        {"/v1/stores/-x", 400},
        {"/v1/stores/a:b/tiles/0/0/0", 400},
        {"/v1/stores/" + std::string(129, 'a'), 400},
        // query
        {"/v1/stores/rgb/tiles/0/0/0?", 200},
        {"/v1/stores/rgb/tiles/0/0/0?format=png", 200},
        {"/v1/stores/rgb/tiles/0/0/0?foo=1", 400},
        {"/v1/stores/rgb/tiles/0/0/0?format=png&x", 400},
        {"/v1/stores/rgb/tiles/0/0/0?format=jpeg", 400},
        {"/v1/stores/rgb/tiles/0/0/0?format=", 400},
        {"/v1/stores/rgb/tiles/0/0/0?format=png&format=png", 400},
        {"/v1/stores/rgb/tiles/0/0/0?v=", 400},
        {"/v1/stores/rgb/tiles/0/0/0?v=xyz", 400},
        {"/v1/stores/rgb/tiles/0/0/0?v=-1", 400},
        {"/v1/stores/rgb/tiles/0/0/0?v=00000000000000000", 400},
        {"/v1/stores/rgb/tiles/0/0/0?v=" + hex16(version) + "&v=" + hex16(version), 400},
        {"/v1/stores/rgb/tiles/0/0/0?v=" + hex16(version), 200},
        {"/v1/stores/rgb/tiles/0/0/0?v=" + hex16(version ^ 0x10), 404},
        {"/v1/stores?format=png", 400},
        {"/v1/stores/rgb?v=1", 400},
        // unknown things
        {"/v1/stores/nosuch", 404},
        {"/v1/stores/nosuch/tiles/0/0/0", 404},
        {"/v1/stores/rgb/other", 404},
        {"/v1/other", 404},
        {"/", 200},  // the viewer's list of stores
        {"/nope", 404},
        // out of range
        {"/v1/stores/rgb/tiles/3/0/0", 404},
        {"/v1/stores/rgb/tiles/4294967295/0/0", 404},
        {"/v1/stores/rgb/tiles/0/4/0", 404},
        {"/v1/stores/rgb/tiles/0/0/3", 404},
        {"/v1/stores/rgb/tiles/2/1/0", 404},
        {"/v1/stores/rgb/tiles/0/0/4294967295", 404},
        {"/v1/stores/rgb/tiles/0/3/2", 404},  // absent
        // probes ignore queries
        {"/healthz?x=1", 200},
        {"/v1/stores", 200},
        {"/v1/stores/rgb", 200},
        {"/metrics", 200},
    };
    for (const auto& [target, status] : table) {
        const HttpResponse r = get(target);
        EXPECT_EQ(r.status, status) << target << " -> " << r.body;
        if (status >= 400) {
            // One line, ending in a newline; JSON under /v1/.
            ASSERT_FALSE(r.body.empty()) << target;
            EXPECT_EQ(r.body.back(), '\n') << target;
            EXPECT_EQ(r.body.find('\n'), r.body.size() - 1) << target;
            if (target.starts_with("/v1/")) {
                EXPECT_EQ(r.content_type, "application/json") << target;
                const auto j = nlohmann::json::parse(r.body, nullptr, false);
                ASSERT_FALSE(j.is_discarded()) << target << ": " << r.body;
                EXPECT_TRUE(j.contains("error") && j["error"].is_string()) << target;
            }
        }
    }
}

TEST_F(HandlerTest, OutOfRangeMessagesGiveTheValidRange) {
    const HttpResponse l = get("/v1/stores/rgb/tiles/3/0/0");
    EXPECT_NE(l.body.find("0..2"), std::string::npos) << l.body;
    const HttpResponse x = get("/v1/stores/rgb/tiles/0/4/0");
    EXPECT_NE(x.body.find("0..3"), std::string::npos) << x.body;
    EXPECT_NE(x.body.find("0..2"), std::string::npos) << x.body;
}

TEST_F(HandlerTest, OnlyGetAndHeadAndPreflights) {
    for (const char* m : {"POST", "PUT", "DELETE", "PATCH", "BREW"}) {
        SCOPED_TRACE(m);
        const HttpResponse r = get("/v1/stores/rgb/tiles/0/0/0", {}, {}, m);
        EXPECT_EQ(r.status, 405u);
        ASSERT_NE(r.header("Allow"), nullptr);
        EXPECT_EQ(*r.header("Allow"), "GET, HEAD, OPTIONS");
    }
    EXPECT_EQ(get("/healthz", {}, {}, "POST").status, 405u);
    // OPTIONS: what may be asked, answered without a body and without auth.
    const HttpResponse o = get("/v1/stores/rgb/tiles/0/0/0", {}, {}, "OPTIONS");
    EXPECT_EQ(o.status, 204u);
    ASSERT_NE(o.header("Allow"), nullptr);
    EXPECT_EQ(*o.header("Allow"), "GET, HEAD, OPTIONS");
    EXPECT_TRUE(o.body.empty());
}

// ---- Probes, metadata, metrics -----------------------------------------------------------------

TEST_F(HandlerTest, HealthAndReadiness) {
    start();
    EXPECT_EQ(get("/healthz").status, 200u);
    EXPECT_EQ(get("/healthz").body, "ok\n");
    EXPECT_EQ(get("/readyz").status, 200u);
    ctx_->ready = false;
    EXPECT_EQ(get("/readyz").status, 503u);
    ctx_->ready = true;
    ctx_->draining = true;
    EXPECT_EQ(get("/readyz").status, 503u);
    EXPECT_EQ(get("/healthz").status, 200u);
    // Draining stops new connections, not requests: tiles are still served.
    EXPECT_EQ(get("/v1/stores/rgb/tiles/0/0/0").status, 200u);
}

TEST_F(HandlerTest, StoreListAndMetadata) {
    const HttpResponse list = get("/v1/stores");
    ASSERT_EQ(list.status, 200u);
    EXPECT_EQ(list.content_type, "application/json");
    const auto j = nlohmann::json::parse(list.body);
    ASSERT_TRUE(j["stores"].is_array());
    std::vector<std::string> names;
    for (const auto& s : j["stores"]) names.push_back(s["name"]);
    EXPECT_EQ(names, (std::vector<std::string>{"floats", "grey", "greya", "heights", "photo", "rgb", "rgba16"}));
    const auto info = reader("rgb")->info();
    const auto& rgb = j["stores"][5];
    EXPECT_EQ(rgb["version"], hex16(info.store_id));
    EXPECT_EQ(rgb["width"], 40);
    EXPECT_EQ(rgb["height"], 30);
    EXPECT_EQ(rgb["tile_payload"], 12);
    EXPECT_EQ(rgb["border"], 2);
    EXPECT_EQ(rgb["channels"], 3);
    EXPECT_EQ(rgb["sample_type"], "u8");
    EXPECT_EQ(rgb["colour_space"], "srgb");
    EXPECT_EQ(rgb["codec"], "raw");
    EXPECT_EQ(rgb["levels"], 3);
    EXPECT_EQ(rgb["url"], "/v1/stores/rgb");
    EXPECT_EQ(j["stores"][3]["codec"], "zstd");
    EXPECT_EQ(j["stores"][3]["sample_type"], "u16");
    EXPECT_EQ(j["stores"][3]["colour_space"], "linear");

    const HttpResponse meta = get("/v1/stores/rgb");
    ASSERT_EQ(meta.status, 200u);
    const auto m = nlohmann::json::parse(meta.body);
    EXPECT_EQ(m["name"], "rgb");
    EXPECT_EQ(m["version"], hex16(info.store_id));
    EXPECT_EQ(m["file_size"], info.file_size);
    ASSERT_EQ(m["level_info"].size(), 3u);
    for (std::size_t l = 0; l < 3; ++l) {
        EXPECT_EQ(m["level_info"][l]["width"], info.levels[l].width);
        EXPECT_EQ(m["level_info"][l]["height"], info.levels[l].height);
        EXPECT_EQ(m["level_info"][l]["tiles_x"], info.levels[l].tiles_x);
        EXPECT_EQ(m["level_info"][l]["tiles_y"], info.levels[l].tiles_y);
        EXPECT_EQ(m["level_info"][l]["present"], info.levels[l].present);
        EXPECT_EQ(m["level_info"][l]["uniform"], info.levels[l].uniform);
        EXPECT_EQ(m["level_info"][l]["absent"], info.levels[l].absent);
    }
    EXPECT_EQ(m["level_info"][0]["absent"], 1);
    EXPECT_EQ(m["level_info"][0]["uniform"], 1);
    // One description of a store: the list holds the same object.
    EXPECT_EQ(m, rgb);
    EXPECT_EQ(get("/v1/stores/nosuch").status, 404u);
}

TEST_F(HandlerTest, MetricsParseAndCountByFixedRoutes) {
    get("/healthz");
    get("/v1/stores");
    get("/v1/stores/rgb");
    get("/v1/stores/rgb/tiles/0/0/0");
    get("/v1/stores/rgb/tiles/0/0/0?format=png");
    get("/v1/stores/rgb/tiles/0/0/0", {}, {}, "HEAD");
    get("/v1/stores/%2e%2e/tiles/0/0/0");
    get("/some/random/path/123");
    const HttpResponse res = get("/metrics");
    ASSERT_EQ(res.status, 200u);
    EXPECT_EQ(res.content_type, "text/plain; version=0.0.4; charset=utf-8");
    const auto p = tessera::test::parse_prometheus_text(res.body);
    ASSERT_TRUE(p.ok()) << p.error;
    EXPECT_EQ(p.value("tessera_http_requests_total", {{"route", "tile"}, {"code", "200"}}), 2.0);  // GET + HEAD
    EXPECT_EQ(p.value("tessera_http_requests_total", {{"route", "tile_png"}, {"code", "200"}}), 1.0);
    EXPECT_EQ(p.value("tessera_http_requests_total", {{"route", "healthz"}, {"code", "200"}}), 1.0);
    EXPECT_EQ(p.value("tessera_http_requests_total", {{"route", "stores"}, {"code", "200"}}), 1.0);
    EXPECT_EQ(p.value("tessera_http_requests_total", {{"route", "store"}, {"code", "200"}}), 1.0);
    EXPECT_EQ(p.value("tessera_http_requests_total", {{"route", "other"}, {"code", "404"}}), 1.0);
    EXPECT_EQ(p.value("tessera_tiles_served_total", {{"store", "rgb"}, {"protocol", "http"}}), 2.0);  // HEAD not counted
    EXPECT_EQ(p.types.at("tessera_http_request_duration_seconds"), "histogram");
    EXPECT_EQ(p.value("tessera_http_request_duration_seconds_count", {{"route", "tile"}}), 2.0);
    EXPECT_EQ(p.value("tessera_http_response_bytes_total", {{"route", "tile"}}),
              double(reader("rgb")->read_tile({0, 0, 0})->bytes.size()));
    // The route label is a fixed set: no raw path ever becomes a label value.
    const std::set<std::string> routes = {"healthz", "readyz", "metrics", "stores", "store", "tile", "tile_png", "other"};
    for (const auto* s : p.all("tessera_http_requests_total")) EXPECT_EQ(routes.count(s->labels.at("route")), 1u) << s->labels.at("route");
    EXPECT_EQ(res.body.find("random"), std::string::npos);
}

// ---- Auth -------------------------------------------------------------------------------------------

TEST_F(HandlerTest, BearerTokenWhenConfigured) {
    // Off: no header needed.
    EXPECT_EQ(get("/v1/stores").status, 200u);
    config_.auth_token = "s3cret-token";
    EXPECT_EQ(get("/healthz").status, 200u);
    EXPECT_EQ(get("/readyz").status, 200u);
    for (const char* target : {"/metrics", "/v1/stores", "/v1/stores/rgb", "/v1/stores/rgb/tiles/0/0/0", "/nope",
                               "/v1/stores/%2e%2e"}) {
        SCOPED_TRACE(target);
        const HttpResponse no = get(target);
        EXPECT_EQ(no.status, 401u);
        ASSERT_NE(no.header("WWW-Authenticate"), nullptr);
        EXPECT_EQ(*no.header("WWW-Authenticate"), "Bearer");
        EXPECT_EQ(get(target, {}, "Bearer wrong-token").status, 401u);
        EXPECT_EQ(get(target, {}, "Bearer s3cret-token-and-more").status, 401u);
        EXPECT_EQ(get(target, {}, "Basic s3cret-token").status, 401u);
        EXPECT_NE(get(target, {}, "Bearer s3cret-token").status, 401u);
        EXPECT_NE(get(target, {}, "bearer   s3cret-token").status, 401u);
    }
    EXPECT_EQ(get("/v1/stores/rgb/tiles/0/0/0", {}, "Bearer s3cret-token").status, 200u);
    // The 401 body never carries the tile.
    EXPECT_EQ(get("/v1/stores/rgb/tiles/0/0/0").body.find(body_of(reader("rgb")->read_tile({0, 0, 0})->bytes)),
              std::string::npos);
}

// ?access_token= as URL encoders write it: a token may hold any printable ASCII, and
// encodeURIComponent, URLSearchParams and Python's urlencode escape '/' and '%'. Paths still refuse
// those escapes. The browser's cookie is set only from a query token that is itself right.
TEST_F(HandlerTest, QueryTokenAsUrlEncodersWriteIt) {
    config_.auth_token = "a/b.c%d";
    EXPECT_EQ(get("/v1/stores?access_token=a%2Fb%2Ec%25d").status, 200u);
    EXPECT_EQ(get("/v1/stores?access_token=a/b.c%25d").status, 200u);
    EXPECT_EQ(get("/v1/stores?access_token=a%2Fb.c%25e").status, 401u);
    EXPECT_EQ(get("/v1/stores/a%2fb", {}, "Bearer a/b.c%d").status, 400u);
    EXPECT_EQ(get("/v1/stores?access_token=a%01b", {}, "Bearer a/b.c%d").status, 400u);

    const HttpResponse set = get("/view/rgb?access_token=a%2Fb.c%25d");
    ASSERT_EQ(set.status, 200u);
    ASSERT_NE(set.header("Set-Cookie"), nullptr);
    EXPECT_EQ(std::string_view(*set.header("Set-Cookie")).substr(0, 23), "tessera_token=a/b.c%d; ");
    // The header lets it in; the query's wrong token must not become the browser's cookie.
    const HttpResponse kept = get("/view/rgb?access_token=wrong", {}, "Bearer a/b.c%d");
    ASSERT_EQ(kept.status, 200u);
    EXPECT_EQ(kept.header("Set-Cookie"), nullptr);
}

// IIIF Image API 3.0, 4.2: !w,h and ^!w,h are confined by the server's limits too (a wide image
// asked for at more than maxWidth is answered at the largest size allowed, not refused); a size
// that rounds to zero texels is 400; pct:n over 100 upscales and needs ^.
TEST_F(HandlerTest, IiifSizesWithinLimitsAndNeverZero) {
    write_store(dir_.file("wide.tsr"), spec_of(5000, 300, 256, 0, 1, SampleType::u8, ColourSpace::linear, Codec::jpeg));
    for (const char* size : {"!6000,6000", "^!9000,9000", "!4096,4096"}) {
        SCOPED_TRACE(size);
        const HttpResponse r = get(std::string("/iiif/wide/full/") + size + "/0/default.png");
        ASSERT_EQ(r.status, 200u) << r.body;
        const Png png = decode_png(r.body);
        EXPECT_EQ(png.width, 4096u);
        EXPECT_EQ(png.height, 246u);  // round(300 * 4096 / 5000 = 245.76), as 4096, gives
    }
    const HttpResponse exact = get("/iiif/wide/full/4096,/0/default.png");
    ASSERT_EQ(exact.status, 200u) << exact.body;
    EXPECT_EQ(decode_png(exact.body).height, 246u);
    EXPECT_EQ(get("/iiif/wide/full/6000,/0/default.png").status, 400u);  // asked for exactly: over the limit
    for (const char* path : {"/iiif/rgb/0,0,40,1/10,/0/default.png", "/iiif/rgb/full/pct:0.001/0/default.png",
                             "/iiif/rgb/0,0,1,30/,10/0/default.png", "/iiif/rgb/0,0,40,1/!10,10/0/default.png",
                             "/iiif/rgb/full/pct:100.4/0/default.png"}) {
        SCOPED_TRACE(path);
        EXPECT_EQ(get(path).status, 400u);
    }
    const HttpResponse up = get("/iiif/rgb/full/^pct:150/0/default.png");
    ASSERT_EQ(up.status, 200u) << up.body;
    EXPECT_EQ(decode_png(up.body).width, 60u);
}

// A level rounds its size up; its last texel covers less of the image than the others and must
// weigh only for what it covers. A 6x3 image, rows black, black, white: level 1 (3x2) is a black
// row and a white one that stands for the image's last row alone. Asked at 3x1 or 6x1, which read
// level 1, every texel is the image's average, a third white (85), not half (128).
TEST_F(HandlerTest, IiifRegionsToTheEdgeWeighTheLastTexelForWhatItCovers) {
    const StoreSpec spec = spec_of(6, 3, 2, 0, 1, SampleType::u8, ColourSpace::linear, Codec::raw);
    const storage::StoreInfo info = storage::store_info(spec);
    ASSERT_GE(info.level_count(), 2u);
    ASSERT_EQ(info.levels[1].height, 2u);
    {
        auto w = storage::StoreWriter::create(dir_.file("rows.tsr"), spec);
        ASSERT_TRUE(w.ok()) << w.error().message;
        const std::uint32_t side = info.tile_size();
        for (std::uint32_t l = 0; l < info.level_count(); ++l) {
            // The builder's rule: a missing edge texel repeats the last one, so each level's last
            // row is white (the image's last row) and the others black; a level one row high is
            // what the mip filter made of the two above it.
            const auto& L = info.levels[l];
            const auto texel = [&](std::uint32_t y) -> std::uint8_t {
                if (L.height == 1) return 128;
                return std::min(y, L.height - 1) == L.height - 1 ? 255 : 0;
            };
            for (std::uint32_t ty = 0; ty < L.tiles_y; ++ty)
                for (std::uint32_t tx = 0; tx < L.tiles_x; ++tx) {
                    std::vector<std::uint8_t> texels(std::size_t(side) * side);
                    for (std::uint32_t y = 0; y < side; ++y)
                        for (std::uint32_t x = 0; x < side; ++x) texels[std::size_t(y) * side + x] = texel(ty * side + y);
                    auto payload = storage::encode_tile(info, texels, {});
                    ASSERT_TRUE(payload.ok()) << payload.error().message;
                    ASSERT_TRUE((*w)->add_present(TileKey{l, tx, ty}, *payload).ok());
                }
        }
        ASSERT_TRUE((*w)->finish().ok());
    }
    for (const char* size : {"3,1", "6,1"}) {  // both read level 1: its rows over image rows [0, 2) and [2, 3)
        SCOPED_TRACE(size);
        const HttpResponse r = get(std::string("/iiif/rows/full/") + size + "/0/default.png");
        ASSERT_EQ(r.status, 200u) << r.body;
        const Png png = decode_png(r.body);
        ASSERT_EQ(png.height, 1u);
        ASSERT_EQ(png.colour_type, 0u);  // grey
        for (std::uint32_t x = 0; x < png.width; ++x) EXPECT_NEAR(int(png.pixels[x]), 85, 1) << "texel " << x;
    }
}

// A canvas 2^32 - 1 texels wide: its last tile ends past 2^32. The part of a tile a region covers
// is worked out in 64 bits (a 32-bit end wrapped, and the render copied a whole tile's row into a
// region a few texels wide, past its buffer).
TEST_F(HandlerTest, RegionsAtTheEdgeOfTheWidestCanvas) {
    constexpr std::uint32_t P = 12;
    using httpapi::tile_span;
    using httpapi::TileSpan;
    const TileSpan last = tile_span(0xFFFFFFF0u, 0xF, 0xFFFFFFFFu / P, P);  // the last tile holds 3 texels
    EXPECT_EQ(last.begin, 0xFFFFFFFCu);
    EXPECT_EQ(last.end, 0xFFFFFFFFu);
    const TileSpan before = tile_span(0xFFFFFFF0u, 0xF, 0xFFFFFFFFu / P - 1, P);
    EXPECT_EQ(before.begin, 0xFFFFFFF0u);
    EXPECT_EQ(before.end, 0xFFFFFFFCu);
    EXPECT_EQ(tile_span(5, 10, 3, P).begin, tile_span(5, 10, 3, P).end);  // no texel of the range in tile 3

    // End to end: a sparse store of that width, its last level-0 tile present; the region over
    // the last 5 texels of its first row comes back as those texels.
    StoreSpec spec = spec_of(0xFFFFFFFFu, 12, P, 2, 3, SampleType::u8, ColourSpace::srgb, Codec::raw);
    spec.sparse_index = true;
    const storage::StoreInfo info = storage::store_info(spec);
    const std::vector<std::uint8_t> texels = random_bytes(info.tile_bytes(), 5);
    {
        auto w = storage::StoreWriter::create(dir_.file("vast.tsr"), spec);
        ASSERT_TRUE(w.ok()) << w.error().message;
        auto payload = storage::encode_tile(info, texels, {});
        ASSERT_TRUE(payload.ok());
        ASSERT_TRUE((*w)->add_present({0, info.levels[0].tiles_x - 1, 0}, *payload).ok());
        ASSERT_TRUE((*w)->finish().ok());
    }
    const HttpResponse r = get("/iiif/vast/4294967290,0,5,12/max/0/default.png");
    ASSERT_EQ(r.status, 200u) << r.body;
    const Png png = decode_png(r.body);
    ASSERT_EQ(png.width, 5u);
    ASSERT_EQ(png.height, 12u);
    const std::size_t c = png.colour_type == 6 ? 4 : 3, T = info.tile_size();
    for (std::uint32_t y = 0; y < 12; ++y)
        for (std::uint32_t x = 0; x < 5; ++x) {
            const std::uint32_t cx = 0xFFFFFFFAu + x;  // canvas texel
            const std::uint8_t* px = &png.pixels[(std::size_t(y) * 5 + x) * c];
            if (cx < 0xFFFFFFFCu) {  // in the absent tile before the last: transparent black (or black)
                EXPECT_EQ(px[0] + px[1] + px[2], 0) << x << "," << y;
                continue;
            }
            const std::uint8_t* want = &texels[((std::size_t(y) + 2) * T + (cx - 0xFFFFFFFCu) + 2) * 3];
            EXPECT_EQ(std::vector<std::uint8_t>(px, px + 3), std::vector<std::uint8_t>(want, want + 3)) << x << "," << y;
        }
}

// A DZI tile served as stored whose read fails is answered with that failure: it is not tried
// again as a render, which would read the tile and its eight neighbours (with their retries,
// against a remote store) only to fail the same way.
TEST_F(HandlerTest, AFailedDziReadIsNotRetriedAsARender) {
    write_store(dir_.file("dz.tsr"), spec_of(64, 64, 16, 4, 3, SampleType::u8, ColourSpace::srgb, Codec::jpeg));
    {
        auto r = reader("dz");
        const auto loc = r->locate({0, 1, 1});
        ASSERT_TRUE(loc.ok());
        ASSERT_EQ(loc->kind, TileKind::present);
        std::fstream f(dir_.file("dz.tsr"), std::ios::in | std::ios::out | std::ios::binary);
        f.seekp(std::streamoff(loc->offset + loc->length / 2));
        f.put('\x5a');
    }
    const HttpResponse r = get("/dzi/dz_files/6/1_1.jpg");
    EXPECT_EQ(r.status, 500u) << r.body;
    EXPECT_NE(r.body.find("checksum"), std::string::npos) << r.body;
    EXPECT_EQ(fetcher_->reads(), 1u) << "the failed tile was read again for a render";
}

// With tiles kept decoded, a web tile cut again from the same stored tiles is made from the
// decoded texels, and is the same image, byte for byte, as the one made by decoding them. A
// large render uses what is kept but keeps nothing itself (it would sweep the viewers' tiles out).
TEST_F(HandlerTest, WebTilesFromDecodedTilesAreTheSame) {
    config_.web_cache_bytes = 0;  // every request renders
    decoded_bytes_ = 8 << 20;
    write_store(dir_.file("wide.tsr"), spec_of(400, 240, 60, 4, 3, SampleType::u8, ColourSpace::srgb, Codec::jpeg));
    for (const char* path : {"/iiif/wide/60,60,60,60/max/0/default.jpg", "/iiif/wide/50,20,40,30/40,/90/default.png",
                             "/iiif/wide/120,0,100,100/50,/0/default.png"}) {
        SCOPED_TRACE(path);
        const HttpResponse first = get(path);
        ASSERT_EQ(first.status, 200u) << first.body;
        const std::uint64_t hits = fetcher_->decoded_hits();
        const HttpResponse again = get(path);
        ASSERT_EQ(again.status, 200u) << again.body;
        EXPECT_GT(fetcher_->decoded_hits(), hits) << "the second render found no tile decoded";
        EXPECT_EQ(again.body, first.body);
    }
    // The whole image at level 0 (28 stored tiles): nothing of it is kept.
    ASSERT_EQ(get("/iiif/wide/0,0,400,240/max/0/default.png").status, 200u);
    const std::uint64_t hits = fetcher_->decoded_hits();
    ASSERT_EQ(get("/iiif/wide/300,180,60,60/max/0/default.png").status, 200u);
    EXPECT_EQ(fetcher_->decoded_hits(), hits) << "a large render kept its tiles decoded";
}

// IIIF 3.0, 4.3: rotation runs "from 0 up to 360" (360 is a whole turn); 4.1: a pct: region that
// starts inside the image is served (99% of 40 is texel 39.6: it starts at 39, not rounded out
// of the image to 40).
TEST_F(HandlerTest, IiifWholeTurnsAndPercentRegionsAtTheEdge) {
    const HttpResponse none = get("/iiif/rgb/full/max/0/default.png");
    ASSERT_EQ(none.status, 200u) << none.body;
    for (const char* rotation : {"360", "360.0"}) {
        const HttpResponse turned = get(std::string("/iiif/rgb/full/max/") + rotation + "/default.png");
        ASSERT_EQ(turned.status, 200u) << rotation << ": " << turned.body;
        EXPECT_EQ(turned.body, none.body) << rotation;
    }
    EXPECT_EQ(get("/iiif/rgb/full/max/360.5/default.png").status, 400u);
    const HttpResponse corner = get("/iiif/rgb/pct:99,99,50,50/max/0/default.png");
    ASSERT_EQ(corner.status, 200u) << corner.body;
    const Png png = decode_png(corner.body);
    EXPECT_EQ(png.width, 1u);  // texel 39 to the right edge (40)
    EXPECT_EQ(png.height, 1u);  // texel 29 to the bottom (30)
    EXPECT_EQ(get("/iiif/rgb/pct:100,0,10,10/max/0/default.png").status, 400u);  // starts at the edge: empty
}

// A render that needs more than --render-memory would be refused however idle the server is: max
// and !w,h shrink to what the budget holds (the largest size this server can give), and an exact
// size that cannot fit is a 400, not a 503 to be retried for ever.
TEST_F(HandlerTest, IiifSizesShrinkToTheRenderBudget) {
    config_.render_memory_bytes = 4 << 20;
    write_store(dir_.file("big.tsr"), spec_of(1000, 600, 248, 4, 3, SampleType::u8, ColourSpace::srgb, Codec::jpeg));
    std::vector<std::pair<std::uint32_t, std::uint32_t>> sizes;
    for (const char* size : {"max", "!1000,1000", "^max"}) {
        SCOPED_TRACE(size);
        const HttpResponse r = get(std::string("/iiif/big/full/") + size + "/0/default.png");
        ASSERT_EQ(r.status, 200u) << r.body;
        const Png png = decode_png(r.body);
        EXPECT_LT(png.width, 1000u);
        EXPECT_GT(png.width, 100u);
        EXPECT_NEAR(double(png.height), png.width * 0.6, 1.0);
        sizes.emplace_back(png.width, png.height);
    }
    // The largest that fits, whichever size it shrank from (^max starts larger than max).
    EXPECT_EQ(sizes[1], sizes[0]);
    EXPECT_EQ(sizes[2], sizes[0]);
    EXPECT_EQ(get("/iiif/big/full/" + std::to_string(sizes[0].first) + ",/0/default.png").status, 200u);
    const HttpResponse exact = get("/iiif/big/full/1000,600/0/default.png");
    EXPECT_EQ(exact.status, 400u) << exact.body;
    EXPECT_NE(exact.body.find("--render-memory"), std::string::npos) << exact.body;
    EXPECT_EQ(exact.header("Retry-After"), nullptr);
    EXPECT_EQ(get("/iiif/big/0,0,248,248/248,/0/default.png").status, 200u);  // a web tile fits

    // info.json advertises only what renders within the budget: every size and tile it lists
    // is served; the full size, which is not, is not listed.
    const HttpResponse info = get("/iiif/big/info.json");
    ASSERT_EQ(info.status, 200u) << info.body;
    const auto j = nlohmann::json::parse(info.body);
    ASSERT_FALSE(j["sizes"].empty());
    for (const auto& sz : j["sizes"]) {
        const std::string w = std::to_string(sz["width"].get<int>()), h = std::to_string(sz["height"].get<int>());
        EXPECT_NE(w + "x" + h, "1000x600");
        EXPECT_EQ(get("/iiif/big/full/" + w + "," + h + "/0/default.png").status, 200u) << w << "x" << h;
    }
    ASSERT_TRUE(j.contains("tiles"));
    const int t = j["tiles"][0]["width"].get<int>();
    for (const auto& f : j["tiles"][0]["scaleFactors"]) {
        const int span = t * f.get<int>();
        const std::string region = "0,0," + std::to_string(std::min(span, 1000)) + "," + std::to_string(std::min(span, 600));
        const int out_w = (std::min(span, 1000) + f.get<int>() - 1) / f.get<int>();
        EXPECT_EQ(get("/iiif/big/" + region + "/" + std::to_string(out_w) + ",/0/default.png").status, 200u) << region;
    }
}

// With a budget too small for one web tile, info.json lists no tiles (a viewer then asks for
// whole images, which shrink to the budget) rather than tiles that are all refused.
TEST_F(HandlerTest, IiifInfoListsNoTileThatCannotRender) {
    const StoreSpec spec = spec_of(1000, 600, 248, 4, 3, SampleType::u8, ColourSpace::srgb, Codec::jpeg);
    const storage::StoreInfo si = storage::store_info(spec);
    // One byte short of what a full web tile read from 4x its width is charged.
    config_.render_memory_bytes = httpapi::render_memory(si, httpapi::web_look(si), 4 * 248 + 2, 248, 248) - 1;
    ASSERT_LT(httpapi::render_memory(si, httpapi::web_look(si), 1000, 125, 75), config_.render_memory_bytes);
    write_store(dir_.file("big.tsr"), spec);
    const HttpResponse info = get("/iiif/big/info.json");
    ASSERT_EQ(info.status, 200u) << info.body;
    const auto j = nlohmann::json::parse(info.body);
    EXPECT_FALSE(j.contains("tiles")) << info.body;
    for (const auto& sz : j["sizes"]) {  // what it lists renders
        const std::string w = std::to_string(sz["width"].get<int>()), h = std::to_string(sz["height"].get<int>());
        EXPECT_EQ(get("/iiif/big/full/" + w + "," + h + "/0/default.png").status, 200u) << w << "x" << h;
    }
    EXPECT_FALSE(j["sizes"].empty()) << info.body;
    EXPECT_EQ(get("/iiif/big/full/max/0/default.png").status, 200u);
}

// IIIF's info.json picks its Content-Type from Accept (JSON-LD when asked for with a quality
// above 0), so caches must key on it: Vary: Accept.
TEST_F(HandlerTest, IiifInfoFollowsAcceptAndSaysSo) {
    auto info = [&](std::string_view accept) {
        return get_with("/iiif/rgb/info.json", [&](HttpRequestView& req) { req.accept = accept; });
    };
    const std::pair<std::string_view, bool> cases[] = {
        {"", false},
        {"application/json", false},
        {"application/ld+json", true},
        {"application/ld+json;profile=\"http://iiif.io/api/image/3/context.json\"", true},
        {"text/html, Application/LD+JSON; q=0.5", true},
        {"application/ld+json;q=0, application/json", false},
        {"application/ld+json; q=0.0", false},
    };
    for (const auto& [accept, ld] : cases) {
        SCOPED_TRACE(accept);
        const HttpResponse r = info(accept);
        ASSERT_EQ(r.status, 200u);
        EXPECT_EQ(r.content_type.starts_with("application/ld+json"), ld) << r.content_type;
        bool vary_accept = false;
        for (const auto& [name, value] : r.headers) vary_accept |= name == "Vary" && std::string_view(value) == "Accept";
        EXPECT_TRUE(vary_accept);
    }
}

// The documents the server writes revalidate like tiles: an ETag of their bytes (and type: the
// two forms of info.json differ), and If-None-Match naming it, or *, gets a 304 without a body.
TEST_F(HandlerTest, DocumentsRevalidate) {
    for (const std::string target : {"/v1/stores", "/v1/stores/rgb", "/iiif/rgb/info.json", "/dzi/rgb.dzi"}) {
        SCOPED_TRACE(target);
        const HttpResponse first = get(target);
        ASSERT_EQ(first.status, 200u);
        const HeaderValue* etag = first.header("ETag");
        ASSERT_NE(etag, nullptr);
        const std::string tag(*etag);
        EXPECT_EQ(get(target).header("ETag") ? std::string(*get(target).header("ETag")) : "", tag) << "the same bytes, the same tag";
        for (const std::string& inm : {tag, "W/" + tag, "\"other\", " + tag, std::string("*")}) {
            const HttpResponse again = get(target, inm);
            EXPECT_EQ(again.status, 304u) << inm;
            EXPECT_TRUE(again.body.empty());
            ASSERT_NE(again.header("ETag"), nullptr);
            EXPECT_EQ(std::string(*again.header("ETag")), tag);
        }
        EXPECT_EQ(get(target, "\"other\"").status, 200u);
    }
    const HttpResponse ld = get_with("/iiif/rgb/info.json", [](HttpRequestView& req) { req.accept = "application/ld+json"; });
    ASSERT_EQ(ld.status, 200u);
    ASSERT_NE(ld.header("ETag"), nullptr);
    EXPECT_NE(std::string(*ld.header("ETag")), std::string(*get("/iiif/rgb/info.json").header("ETag")));
}

// RFC 9112 3.2: a Host that is not a host and port is 400; IIIF's info.json would write it into
// its id (a value that is not UTF-8 made it fail as a 500).
TEST_F(HandlerTest, HostHeaderMustBeAHost) {
    auto info = [&](std::string_view host) {
        return get_with("/iiif/rgb/info.json", [&](HttpRequestView& req) { req.host = host; });
    };
    for (const std::string_view bad : {std::string_view("\xff"), std::string_view("a b"), std::string_view("h/x"),
                                       std::string_view("h\"x"), std::string_view("h<x>"), std::string_view(":80"),
                                       std::string_view("a:99999"), std::string_view("a:8x"), std::string_view("[zz]:1"),
                                       std::string_view("[::1"), std::string_view("[::1]x"), std::string_view("a:b:c")}) {
        const HttpResponse r = info(bad);
        EXPECT_EQ(r.status, 400u) << bad;
    }
    const HttpResponse ok = info("tiles.example.org:8080");
    ASSERT_EQ(ok.status, 200u) << ok.body;
    EXPECT_NE(ok.body.find("\"http://tiles.example.org:8080/iiif/rgb\""), std::string::npos) << ok.body;
    EXPECT_EQ(info("[::1]:8080").status, 200u);
    EXPECT_EQ(info("[::1]").status, 200u);
    EXPECT_EQ(info("192.0.2.7:65535").status, 200u);
    EXPECT_EQ(info("").status, 200u);  // HTTP/1.0 sends none: the server's own address
}

// Behind a proxy that serves the server under a path (--public-url https://example.org/tiles/),
// every URL an answer carries reaches it: IIIF ids are absolute, and the store JSON's url and
// tiles and the web pages' links start with the path.
TEST_F(HandlerTest, PublicUrlWithAPathPrefixesTheUrlsAnswersCarry) {
    EXPECT_EQ(httpapi::public_path("https://example.org"), "");
    EXPECT_EQ(httpapi::public_path("https://example.org/"), "");
    EXPECT_EQ(httpapi::public_path("https://example.org/a/b/"), "/a/b");
    EXPECT_EQ(httpapi::public_path(""), "");
    // One normal form for both: every trailing slash, any query or fragment dropped.
    EXPECT_EQ(httpapi::public_base("https://example.org/tiles//"), "https://example.org/tiles");
    EXPECT_EQ(httpapi::public_base("https://example.org/?x#y"), "https://example.org");
    EXPECT_EQ(httpapi::public_path("https://example.org/tiles//?x"), "/tiles");
    config_.public_url = "https://example.org/tiles//";
    const HttpResponse store = get("/v1/stores/rgb");
    ASSERT_EQ(store.status, 200u) << store.body;
    const auto j = nlohmann::json::parse(store.body);
    EXPECT_EQ(j["url"], "/tiles/v1/stores/rgb");
    EXPECT_TRUE(j["tiles"].get<std::string>().starts_with("/tiles/v1/stores/rgb/tiles/{level}/{x}/{y}?v=")) << j["tiles"];
    const HttpResponse info = get("/iiif/rgb/info.json");
    ASSERT_EQ(info.status, 200u) << info.body;
    EXPECT_EQ(nlohmann::json::parse(info.body)["id"], "https://example.org/tiles/iiif/rgb");
    const HttpResponse index = get("/");
    ASSERT_EQ(index.status, 200u) << index.body;
    EXPECT_NE(index.body.find("href=\"/tiles/view/rgb\""), std::string::npos) << index.body;
    EXPECT_NE(index.body.find("href=\"/tiles/v1/stores/rgb\""), std::string::npos) << index.body;
    for (const char* outside : {"href=\"/view", "href=\"/dzi", "href=\"/iiif", "href=\"/v1"})
        EXPECT_EQ(index.body.find(outside), std::string::npos) << outside << ": " << index.body;
    const HttpResponse page = get("/view/rgb");
    ASSERT_EQ(page.status, 200u) << page.body;
    EXPECT_NE(page.body.find("'/tiles/dzi/rgb.dzi?v="), std::string::npos) << page.body;
    EXPECT_NE(page.body.find("\"/tiles/static/openseadragon/openseadragon.min.js\""), std::string::npos) << page.body;
    EXPECT_EQ(page.body.find("\"/static"), std::string::npos) << page.body;
    EXPECT_EQ(page.body.find("'/static"), std::string::npos) << page.body;
}

// A signed URL (an Azure SAS, a CDN token) names its store by its path, and its query, a
// credential, never reaches an error or a log line.
TEST(StoreRegistrySigned, AUrlsQueryIsNeitherItsNameNorShown) {
    tessera::test::ScratchDir d;
    const std::string log_file = d.file("log");
    const int fd = ::open(log_file.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    ASSERT_GE(fd, 0);
    {
        Logger log(LogFormat::json, LogLevel::debug, fd);
        MetricsRegistry metrics;
        StoreRegistry stores({"https://tiles.example/maps/terrain.tsr?sv=2024&sig=SECRET"}, {}, log, metrics);
        const Status st = stores.open();  // no remote stores in this program: refused, by name
        ASSERT_FALSE(st.ok());
        EXPECT_EQ(st.error().message.find("SECRET"), std::string::npos) << st.error().message;
        EXPECT_NE(st.error().message.find("terrain.tsr?..."), std::string::npos) << st.error().message;
        EXPECT_EQ(st.error().message.find("the name must be"), std::string::npos) << "named by its path: " << st.error().message;
    }
    ::close(fd);
    std::ifstream in(log_file);
    const std::string logged((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_EQ(logged.find("SECRET"), std::string::npos) << logged;
}

// A file in a store directory whose name is no store name is skipped with a warning when it
// appears, at the first scan or a later one, and not again at every rescan while it stays.
TEST(StoreRegistryDir, ABadlyNamedFileIsWarnedAboutWhenItAppears) {
    tessera::test::ScratchDir d;
    const std::string dir = d.file("stores");
    std::filesystem::create_directories(dir);
    const std::string log_file = d.file("log");
    const int fd = ::open(log_file.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    ASSERT_GE(fd, 0);
    const auto warnings = [&] {
        std::ifstream in(log_file);
        const std::string logged((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
        std::size_t n = 0;
        for (std::size_t at = 0; (at = logged.find("its name is not an identifier", at)) != std::string::npos; ++at) ++n;
        return n;
    };
    {
        Logger log(LogFormat::json, LogLevel::info, fd);
        MetricsRegistry metrics;
        StoreRegistry stores({}, {dir}, log, metrics);
        ASSERT_TRUE(stores.open().ok());
        EXPECT_EQ(warnings(), 0u);
        std::ofstream(dir + "/bad name.tsr") << "x";
        stores.reload();
        EXPECT_EQ(warnings(), 1u) << "a file that appears after the first scan is warned about";
        stores.reload();
        stores.reload();
        EXPECT_EQ(warnings(), 1u) << "and only once while it stays";
        std::filesystem::remove(dir + "/bad name.tsr");
        stores.reload();
        std::ofstream(dir + "/bad name.tsr") << "x";
        stores.reload();
        EXPECT_EQ(warnings(), 2u) << "gone and back: warned again";
    }
    ::close(fd);
}

// A store directory that cannot be listed (moved away, unreadable, a network glitch) keeps its
// stores as they were opened, where every one of them was dropped at once (and /readyz stayed
// 200 over an empty server); the error is logged when it appears, not at every rescan; a
// directory listed again is rescanned as usual.
TEST(StoreRegistryDir, AnUnlistableDirectoryKeepsItsStores) {
    tessera::test::ScratchDir d;
    const std::string dir = d.file("stores");
    std::filesystem::create_directories(dir);
    write_store(dir + "/t.tsr", spec_of(8, 8, 8, 0, 1, SampleType::u8, ColourSpace::linear, Codec::raw));
    const std::string log_file = d.file("log");
    const int fd = ::open(log_file.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    ASSERT_GE(fd, 0);
    const auto count = [&](const std::string& what) {
        std::ifstream in(log_file);
        const std::string logged((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
        std::size_t n = 0;
        for (std::size_t at = 0; (at = logged.find(what, at)) != std::string::npos; ++at) ++n;
        return n;
    };
    {
        Logger log(LogFormat::json, LogLevel::info, fd);
        MetricsRegistry metrics;
        StoreRegistry stores({"/nonexistent-dir-for-this-test/x.tsr"}, {dir}, log, metrics);
        (void)stores.open();  // the missing --store file: an error, logged
        ASSERT_NE(stores.find("t"), nullptr);
        std::filesystem::rename(dir, dir + "-moved");
        for (int i = 0; i < 3; ++i) stores.reload();
        EXPECT_NE(stores.find("t"), nullptr) << "kept while its directory cannot be listed";
        EXPECT_EQ(count("cannot read store directory"), 1u) << "logged once";
        EXPECT_EQ(count("x.tsr does not exist"), 1u) << "logged once";
        EXPECT_EQ(count("store removed"), 0u);
        std::filesystem::create_directories(dir);  // listed again, empty: the store goes
        stores.reload();
        EXPECT_EQ(stores.find("t"), nullptr);
        EXPECT_EQ(count("store removed"), 1u);
    }
    ::close(fd);
}

// Two --store locations that give one name: refused, naming both (the last one used to win in
// silence, and a client asking for the name got whichever that was).
TEST(StoreRegistryDir, TwoStoresOfOneNameAreRefused) {
    tessera::test::ScratchDir d;
    std::filesystem::create_directories(d.file("www"));
    write_store(d.file("t.tsr"), spec_of(8, 8, 8, 0, 1, SampleType::u8, ColourSpace::linear, Codec::raw));
    std::filesystem::copy_file(d.file("t.tsr"), d.file("www/t.tsr"));
    const int fd = ::open("/dev/null", O_WRONLY | O_CLOEXEC);
    ASSERT_GE(fd, 0);
    Status st;
    {
        Logger log(LogFormat::json, LogLevel::info, fd);
        MetricsRegistry metrics;
        StoreRegistry stores({d.file("t.tsr"), d.file("www/t.tsr")}, {}, log, metrics);
        st = stores.open();
        StoreRegistry twice({d.file("t.tsr"), d.file("t.tsr")}, {}, log, metrics);  // one location twice: one store
        const Status same = twice.open();
        EXPECT_TRUE(same.ok()) << same.error().message;
        EXPECT_EQ(twice.list().size(), 1u);
    }
    ::close(fd);
    ASSERT_FALSE(st.ok());
    EXPECT_NE(st.error().message.find("two stores named 't'"), std::string::npos) << st.error().message;
    EXPECT_NE(st.error().message.find(d.file("www/t.tsr")), std::string::npos) << st.error().message;
}

// ---- Corruption -------------------------------------------------------------------------------------

TEST_F(HandlerTest, CorruptTileIs500AndNeverItsBytes) {
    // Flip one payload byte of rgb (1,1,1) on disk.
    const auto r = reader("rgb");
    const auto loc = r->locate({1, 1, 1});
    ASSERT_TRUE(loc.ok());
    ASSERT_EQ(loc->kind, TileKind::present);
    const std::vector<std::uint8_t> good = r->read_tile({1, 1, 1})->bytes;
    {
        std::fstream f(dir_.file("rgb.tsr"), std::ios::in | std::ios::out | std::ios::binary);
        f.seekp(static_cast<std::streamoff>(loc->offset + 5));
        const char bad = static_cast<char>(good[5] ^ 0x5a);
        f.write(&bad, 1);
    }
    std::vector<std::uint8_t> corrupted = good;
    corrupted[5] ^= 0x5a;
    for (const char* suffix : {"", "?format=png"}) {
        SCOPED_TRACE(suffix);
        const HttpResponse res = get(std::string("/v1/stores/rgb/tiles/1/1/1") + suffix);
        EXPECT_EQ(res.status, 500u);
        EXPECT_NE(res.body.find("tile failed its checksum"), std::string::npos) << res.body;
        EXPECT_LT(res.body.size(), 200u);
        EXPECT_EQ(res.body.find(body_of(corrupted).substr(0, 32)), std::string::npos);
        EXPECT_EQ(res.body.find(body_of(good).substr(0, 32)), std::string::npos);
        EXPECT_EQ(res.header("ETag"), nullptr);
    }
    // Its neighbours are fine.
    EXPECT_EQ(get("/v1/stores/rgb/tiles/1/0/1").status, 200u);
    const auto p = tessera::test::parse_prometheus_text(get("/metrics").body);
    ASSERT_TRUE(p.ok()) << p.error;
    EXPECT_EQ(p.value("tessera_http_requests_total", {{"route", "tile"}, {"code", "500"}}), 1.0);
}

// The encoded web cache's bytes are a gauge: 0, then what a web image put in it.
TEST_F(HandlerTest, EncodedWebCacheBytesAreAGauge) {
    auto bytes = [&] {
        const auto p = tessera::test::parse_prometheus_text(get("/metrics").body);
        EXPECT_TRUE(p.ok()) << p.error;
        return p.value("tessera_web_encoded_bytes", {});
    };
    EXPECT_EQ(bytes(), 0.0);
    const HttpResponse img = get("/iiif/rgb/full/max/0/default.png");
    ASSERT_EQ(img.status, 200u) << img.body;
    // Its charge: the image and its key (the store version and what was asked).
    EXPECT_GT(bytes(), double(img.body.size()));
    EXPECT_LT(bytes(), double(img.body.size() + 512));
}

// ---- Bounds -----------------------------------------------------------------------------------------

TEST_F(HandlerTest, InflightBoundGives503) {
    config_.max_http_inflight = 0;  // nothing may be in flight: every tile request is refused
    const HttpResponse r = get("/v1/stores/rgb/tiles/0/0/0");
    EXPECT_EQ(r.status, 503u);
    ASSERT_NE(r.header("Retry-After"), nullptr);
    EXPECT_EQ(get("/v1/stores").status, 200u);  // only tiles are bounded
    EXPECT_EQ(handler_->tiles_in_flight(), 0u);
    config_.max_http_inflight = 1;
    EXPECT_EQ(get("/v1/stores/rgb/tiles/0/0/0").status, 200u);
}

TEST_F(HandlerTest, FreeFunctionMatchesTheClass) {
    start();
    HttpRequestView req;
    req.method = "GET";
    req.target = "/v1/stores/rgb/tiles/0/0/0";
    const HttpResponse a = handle_http_request(*ctx_, req);
    const HttpResponse b = handler_->handle_http_request(req);
    EXPECT_EQ(a.status, 200u);
    EXPECT_EQ(a.body, b.body);
}
