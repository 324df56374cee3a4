#include "tessera/storage/codec.hpp"

#include <turbojpeg.h>
#define ZSTD_STATIC_LINKING_ONLY  // ZSTD_c_literalCompressionMode (block tiles)
#include <zstd.h>

#include <cstring>
#include <memory>
#include <string>

#include "tessera/blocks/bc7.hpp"
#include "tessera/blocks/blocks.hpp"

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
// libjpeg-turbo 2.1 leaves a handle whose tjDecompressHeader3() failed unusable: every later
// header read on it fails too ("Bogus marker length", "Bogus Huffman table definition"). So a
// failed decode gets this thread a fresh handle.
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

// ------------------------------------------------------------------------------ block codecs
// A block tile is one zstd frame: the tile's 4x4 blocks, then the blocks of its 2x2 means (the
// page's second level for trilinear filtering). Texels go to blocks through RGBA8 as the client's
// transcode threads lay them out, so both routes make the same second level: 1 channel (v, v, v,
// 255), 2 channels (v, v, v, a) with bc5's channels R and A, 3 (r, g, b, 255), 4 as they are.

blocks::BlockFormat block_format(Codec c) {
    switch (c) {
        case Codec::bc4: return blocks::BlockFormat::bc4;
        case Codec::bc5: return blocks::BlockFormat::bc5;
        case Codec::bc7: return blocks::BlockFormat::bc7;
        default: return blocks::BlockFormat::bc1;
    }
}

constexpr blocks::Channels kBlockChannels2{0, 3};  // (v, v, v, a): grey and alpha

std::size_t block_tile_bytes(const StoreInfo& info) {
    const auto f = block_format(info.codec);
    return blocks::page_block_bytes(f, info.tile_size()) + blocks::page_block_bytes(f, info.tile_size() / 2);
}

void texels_to_rgba8(const std::uint8_t* src, unsigned channels, std::size_t n, std::uint8_t* dst) {
    for (std::size_t i = 0; i < n; ++i, src += channels, dst += 4) {
        switch (channels) {
            case 1: dst[0] = dst[1] = dst[2] = src[0], dst[3] = 255; break;
            case 2: dst[0] = dst[1] = dst[2] = src[0], dst[3] = src[1]; break;
            case 3: dst[0] = src[0], dst[1] = src[1], dst[2] = src[2], dst[3] = 255; break;
            default: std::memcpy(dst, src, 4); break;
        }
    }
}

// Decoded blocks (as the GPU returns them: bc4 (v, 0, 0, 255), bc5 (v, a, 0, 255)) to texels.
void decoded_blocks_to_texels(const std::uint8_t* rgba, unsigned channels, std::size_t n, std::uint8_t* dst) {
    for (std::size_t i = 0; i < n; ++i, rgba += 4, dst += channels) {
        switch (channels) {
            case 1: dst[0] = rgba[0]; break;
            case 2: dst[0] = rgba[0], dst[1] = rgba[1]; break;
            case 3: dst[0] = rgba[0], dst[1] = rgba[1], dst[2] = rgba[2]; break;
            default: std::memcpy(dst, rgba, 4); break;
        }
    }
}

Result<std::vector<std::uint8_t>> encode_block_tile(const StoreInfo& info, std::span<const std::uint8_t> texels,
                                                    const EncodeOptions& options) {
    const std::uint32_t side = info.tile_size(), half = side / 2;
    const auto f = block_format(info.codec);
    const blocks::Channels channels = info.channels == 2 ? kBlockChannels2 : blocks::Channels{};
    std::vector<std::uint8_t> rgba(std::size_t(side) * side * 4), half_rgba(std::size_t(half) * half * 4);
    texels_to_rgba8(texels.data(), info.channels, std::size_t(side) * side, rgba.data());
    blocks::half_size_rgba8(rgba.data(), side, info.colour_space == ColourSpace::srgb, half_rgba.data());
    std::vector<std::uint8_t> raw(block_tile_bytes(info));
    const auto encode = [&](const std::uint8_t* page, std::uint32_t size, std::uint8_t* out) {
        if (f == blocks::BlockFormat::bc7) {
            blocks::Bc7Options bc7;
            bc7.effort = options.bc7_effort;
            blocks::encode_bc7(page, size, out, bc7);
        } else {
            blocks::encode_page(f, page, size, out, blocks::Effort::best, channels);
        }
    };
    encode(rgba.data(), side, raw.data());
    encode(half_rgba.data(), half, raw.data() + blocks::page_block_bytes(f, side));
    // Literals stay uncompressed: blocks are near-random bytes that Huffman coding shrinks by a few
    // percent at the cost of halving the client's unpack speed (docs/benchmarks.md); repeated
    // blocks are still found as matches.
    thread_local ZstdCCtx ctx;
    ZSTD_CCtx_reset(ctx.c, ZSTD_reset_parameters);
    ZSTD_CCtx_setParameter(ctx.c, ZSTD_c_compressionLevel, options.zstd_level);
    ZSTD_CCtx_setParameter(ctx.c, ZSTD_c_literalCompressionMode, ZSTD_ps_disable);
    std::vector<std::uint8_t> out(ZSTD_compressBound(raw.size()));
    const std::size_t r = ZSTD_compress2(ctx.c, out.data(), out.size(), raw.data(), raw.size());
    if (ZSTD_isError(r)) return make_error(Errc::io_error, std::string("zstd: ") + ZSTD_getErrorName(r));
    out.resize(r);
    return out;
}

}  // namespace

Status unpack_block_tile(const StoreInfo& info, std::span<const std::uint8_t> payload, std::vector<std::uint8_t>& out) {
    if (!is_block_codec(info.codec)) return make_error(Errc::invalid_argument, "not a block-codec store");
    const std::size_t n = block_tile_bytes(info);
    if (ZSTD_getFrameContentSize(payload.data(), payload.size()) != n)
        return make_error(Errc::corrupt, std::string(to_string(info.codec)) + " tile does not hold exactly one tile's blocks");
    thread_local ZstdDCtx ctx;
    out.resize(n);
    const std::size_t r = ZSTD_decompressDCtx(ctx.d, out.data(), n, payload.data(), payload.size());
    if (ZSTD_isError(r) || r != n) return make_error(Errc::corrupt, std::string(to_string(info.codec)) + " tile does not decode");
    return {};
}

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
        case Codec::bc1:
        case Codec::bc4:
        case Codec::bc5:
        case Codec::bc7: {
            if (const std::string misfit = codec_misfit(info.codec, info.sample_type, info.channels, info.tile_size(), info.border);
                !misfit.empty())
                return make_error(Errc::unsupported, misfit);
            return encode_block_tile(info, texels, options);
        }
        case Codec::layers:
            return make_error(Errc::invalid_argument,
                              "a multi-layer store's tile is a bundle: encode each layer's part (storage/layers.hpp)");
    }
    return make_error(Errc::unsupported, "unknown codec");
}

Status decompress_zstd_tile(const StoreInfo& info, std::span<const std::uint8_t> payload, std::span<std::uint8_t> out) {
    const std::size_t n = info.tile_bytes();
    if (out.size() != n) return make_error(Errc::invalid_argument, "destination is not one tile of this store");
    if (ZSTD_getFrameContentSize(payload.data(), payload.size()) != n)
        return make_error(Errc::corrupt, "zstd tile does not hold exactly one tile");
    thread_local ZstdDCtx ctx;
    if (!ctx.d) return make_error(Errc::resource_exhausted, "cannot create a zstd context");
    const std::size_t r = ZSTD_decompressDCtx(ctx.d, out.data(), n, payload.data(), payload.size());
    if (ZSTD_isError(r) || r != n) return make_error(Errc::corrupt, "zstd tile does not decode");
    return {};
}

Status decode_jpeg_tile(const StoreInfo& info, std::span<const std::uint8_t> payload, std::span<std::uint8_t> out,
                        bool rgba) {
    if (info.sample_type != SampleType::u8 || (info.channels != 1 && info.channels != 3))
        return make_error(Errc::corrupt, "JPEG tiles need 8-bit samples with 1 or 3 channels");
    const int side = static_cast<int>(info.tile_size());
    const std::size_t texels = std::size_t(info.tile_size()) * info.tile_size();
    if (out.size() != (rgba ? texels * 4 : info.tile_bytes()))
        return make_error(Errc::invalid_argument, "destination is not one tile of this store");
    if (payload.empty()) return make_error(Errc::corrupt, "JPEG tile is empty");
    tjhandle d = decompressor();
    if (!d) return make_error(Errc::resource_exhausted, "cannot create a JPEG decompressor");
    int w = 0, h = 0, samp = 0, cs = 0;
    if (tjDecompressHeader3(d, payload.data(), static_cast<unsigned long>(payload.size()), &w, &h, &samp, &cs) != 0) {
        auto e = make_error(Errc::corrupt, std::string("JPEG tile header: ") + tjGetErrorStr2(d));
        reset_decompressor();
        return e;
    }
    if (w != side || h != side) return make_error(Errc::corrupt, "JPEG tile has the wrong dimensions");
    if ((info.channels == 1) != (samp == TJSAMP_GRAY)) return make_error(Errc::corrupt, "JPEG tile has the wrong channel count");
    // RGBA: libjpeg-turbo expands grey to (v, v, v) and writes alpha 255 itself, with the same
    // IDCT and upsampling, so the colour channels are those of the store's own layout.
    const int pf = rgba ? TJPF_RGBA : info.channels == 1 ? TJPF_GRAY : TJPF_RGB;
    const int pitch = side * (rgba ? 4 : static_cast<int>(info.channels));
    if (tjDecompress2(d, payload.data(), static_cast<unsigned long>(payload.size()), out.data(), side, pitch, side, pf,
                      TJFLAG_ACCURATEDCT) != 0) {
        auto e = make_error(Errc::corrupt, std::string("JPEG tile does not decode: ") + tjGetErrorStr2(d));
        reset_decompressor();
        return e;
    }
    return {};
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
        case Codec::zstd:
            out.resize(n);
            return decompress_zstd_tile(info, tile.bytes, out);
        case Codec::jpeg:
            out.resize(n);
            return decode_jpeg_tile(info, tile.bytes, out);
        case Codec::bc1:
        case Codec::bc4:
        case Codec::bc5:
        case Codec::bc7: {
            if (!codec_misfit(info.codec, info.sample_type, info.channels, info.tile_size(), info.border).empty())
                return make_error(Errc::corrupt, "block codec does not fit the store's samples");
            thread_local std::vector<std::uint8_t> blocks, rgba;
            if (Status st = unpack_block_tile(info, tile.bytes, blocks); !st) return st;
            const std::size_t texels = std::size_t(info.tile_size()) * info.tile_size();
            rgba.resize(texels * 4);
            blocks::decode_page(block_format(info.codec), blocks.data(), info.tile_size(), rgba.data());
            out.resize(n);
            decoded_blocks_to_texels(rgba.data(), info.channels, texels, out.data());
            return {};
        }
        case Codec::layers:
            return make_error(Errc::invalid_argument,
                              "a multi-layer store's tile is a bundle: decode each layer's part (storage/layers.hpp)");
    }
    return make_error(Errc::unsupported, "unknown codec");
}

}  // namespace tessera::storage
