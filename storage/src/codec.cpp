#include "tessera/storage/codec.hpp"

#include <turbojpeg.h>
#include <zstd.h>

#include <cstring>
#include <memory>
#include <string>

namespace tessera::storage {
namespace {

// libjpeg-turbo handles are not thread-safe but are reusable: one per thread and direction.
struct TjHandle {
    tjhandle h = nullptr;
    explicit TjHandle(bool compress) : h(compress ? tjInitCompress() : tjInitDecompress()) {}
    ~TjHandle() {
        if (h) tjDestroy(h);
    }
    TjHandle(const TjHandle&) = delete;
    TjHandle& operator=(const TjHandle&) = delete;
};

tjhandle compressor() {
    thread_local TjHandle t(true);
    return t.h;
}
TjHandle& decompressor_handle() {
    thread_local TjHandle t(false);
    return t;
}
tjhandle decompressor() { return decompressor_handle().h; }
// libjpeg-turbo 2.1 leaves a decompressor unusable after some header errors ("Bogus marker
// length" on every later tile): a failed decode gets this thread a fresh handle.
void reset_decompressor() {
    auto& t = decompressor_handle();
    if (t.h) tjDestroy(t.h);
    t.h = tjInitDecompress();
}

struct ZstdCCtx {
    ZSTD_CCtx* c = ZSTD_createCCtx();
    ~ZstdCCtx() { ZSTD_freeCCtx(c); }
    ZstdCCtx() = default;
    ZstdCCtx(const ZstdCCtx&) = delete;
    ZstdCCtx& operator=(const ZstdCCtx&) = delete;
};
struct ZstdDCtx {
    ZSTD_DCtx* d = ZSTD_createDCtx();
    ~ZstdDCtx() { ZSTD_freeDCtx(d); }
    ZstdDCtx() = default;
    ZstdDCtx(const ZstdDCtx&) = delete;
    ZstdDCtx& operator=(const ZstdDCtx&) = delete;
};

}  // namespace

Result<std::vector<std::uint8_t>> encode_tile(const StoreInfo& info, std::span<const std::uint8_t> texels,
                                              const EncodeOptions& options) {
    const std::size_t n = info.tile_bytes();
    if (texels.size() != n) return make_error(Errc::invalid_argument, "tile texel buffer has the wrong size");
    switch (info.codec) {
        case Codec::raw:
            return std::vector<std::uint8_t>(texels.begin(), texels.end());
        case Codec::zstd: {
            thread_local ZstdCCtx ctx;
            std::vector<std::uint8_t> out(ZSTD_compressBound(n));
            const std::size_t r = ZSTD_compressCCtx(ctx.c, out.data(), out.size(), texels.data(), n, options.zstd_level);
            if (ZSTD_isError(r)) return make_error(Errc::io_error, std::string("zstd: ") + ZSTD_getErrorName(r));
            out.resize(r);
            return out;
        }
        case Codec::jpeg: {
            if (info.sample_type != SampleType::u8 || (info.channels != 1 && info.channels != 3))
                return make_error(Errc::unsupported, "JPEG needs 8-bit samples with 1 or 3 channels");
            const int side = static_cast<int>(info.tile_size());
            const int pf = info.channels == 1 ? TJPF_GRAY : TJPF_RGB;
            const int samp = info.channels == 1 ? TJSAMP_GRAY : (options.chroma == Chroma::s420 ? TJSAMP_420 : TJSAMP_444);
            unsigned char* buf = nullptr;
            unsigned long size = 0;
            if (tjCompress2(compressor(), texels.data(), side, 0, side, pf, &buf, &size, samp, options.jpeg_quality,
                            TJFLAG_ACCURATEDCT) != 0) {
                std::string msg = std::string("JPEG encode failed: ") + tjGetErrorStr2(compressor());
                tjFree(buf);
                return make_error(Errc::io_error, msg);
            }
            std::vector<std::uint8_t> out(buf, buf + size);
            tjFree(buf);
            return out;
        }
    }
    return make_error(Errc::unsupported, "unknown codec");
}

Status decode_tile(const StoreInfo& info, const Tile& tile, std::vector<std::uint8_t>& out) {
    const std::size_t n = info.tile_bytes();
    const std::size_t texel = info.texel_bytes();
    if (tile.kind == TileKind::absent) return make_error(Errc::not_found, "tile is absent");
    if (tile.kind == TileKind::uniform) {
        if (tile.bytes.size() != texel) return make_error(Errc::corrupt, "uniform value has the wrong size");
        out.resize(n);
        for (std::size_t i = 0; i < n; i += texel) std::memcpy(out.data() + i, tile.bytes.data(), texel);
        return {};
    }
    switch (info.codec) {
        case Codec::raw:
            if (tile.bytes.size() != n) return make_error(Errc::corrupt, "raw tile has the wrong size");
            out = tile.bytes;
            return {};
        case Codec::zstd: {
            const unsigned long long content = ZSTD_getFrameContentSize(tile.bytes.data(), tile.bytes.size());
            if (content != n) return make_error(Errc::corrupt, "zstd tile does not hold exactly one tile");
            thread_local ZstdDCtx ctx;
            out.resize(n);
            const std::size_t r = ZSTD_decompressDCtx(ctx.d, out.data(), n, tile.bytes.data(), tile.bytes.size());
            if (ZSTD_isError(r) || r != n) return make_error(Errc::corrupt, "zstd tile does not decode");
            return {};
        }
        case Codec::jpeg: {
            if (info.sample_type != SampleType::u8 || (info.channels != 1 && info.channels != 3))
                return make_error(Errc::corrupt, "JPEG tiles need 8-bit samples with 1 or 3 channels");
            int w = 0, h = 0, samp = 0, cs = 0;
            tjhandle d = decompressor();
            if (tjDecompressHeader3(d, tile.bytes.data(), tile.bytes.size(), &w, &h, &samp, &cs) != 0) {
                auto e = make_error(Errc::corrupt, std::string("JPEG tile header: ") + tjGetErrorStr2(d));
                reset_decompressor();
                return e;
            }
            const int side = static_cast<int>(info.tile_size());
            if (w != side || h != side) return make_error(Errc::corrupt, "JPEG tile has the wrong dimensions");
            if ((info.channels == 1) != (samp == TJSAMP_GRAY)) return make_error(Errc::corrupt, "JPEG tile has the wrong channel count");
            out.resize(n);
            const int pf = info.channels == 1 ? TJPF_GRAY : TJPF_RGB;
            if (tjDecompress2(d, tile.bytes.data(), tile.bytes.size(), out.data(), side, 0, side, pf, TJFLAG_ACCURATEDCT) != 0) {
                auto e = make_error(Errc::corrupt, std::string("JPEG tile does not decode: ") + tjGetErrorStr2(d));
                reset_decompressor();
                return e;
            }
            return {};
        }
    }
    return make_error(Errc::unsupported, "unknown codec");
}

}  // namespace tessera::storage
