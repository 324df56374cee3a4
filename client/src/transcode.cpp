#include "transcode.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <bit>
#include <condition_variable>
#include <cstring>
#include <iterator>
#include <map>
#include <mutex>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "tessera/half_float.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/layers.hpp"

namespace tessera::client {

using storage::ColourSpace;
using storage::SampleType;
using storage::StoreInfo;

// ------------------------------------------------------------------------------------ Scratch

struct Scratch::Impl {
    std::unique_ptr<std::uint8_t[]> samples;  // decompressed zstd tile (never zero-filled)
    std::unique_ptr<std::uint8_t[]> rgba;     // RGBA8 page before block encoding, or decoded blocks
    std::vector<std::uint8_t> blocks;          // a block tile unpacked
    std::size_t rgba_size = 0;
    std::size_t samples_size = 0;

    Impl() = default;
    Impl(const Impl&) = delete;
    Impl& operator=(const Impl&) = delete;
    std::uint8_t* rgba_buffer(std::size_t n) {  // a decoded RGBA8 page waiting for block encoding
        if (rgba_size < n) {
            rgba = std::make_unique_for_overwrite<std::uint8_t[]>(n);
            rgba_size = n;
        }
        return rgba.get();
    }
    std::uint8_t* sample_buffer(std::size_t n) {
        if (samples_size < n) {
            samples = std::make_unique_for_overwrite<std::uint8_t[]>(n);
            samples_size = n;
        }
        return samples.get();
    }
};

Scratch::Scratch() : impl_(std::make_unique<Impl>()) {}
Scratch::~Scratch() = default;
Scratch::Scratch(Scratch&&) noexcept = default;
Scratch& Scratch::operator=(Scratch&&) noexcept = default;

// ---------------------------------------------------------------------------- sample conversion
namespace {

// Samples are little-endian in every payload (docs/store-format.md), whatever the host.
inline std::uint16_t load_u16(const std::uint8_t* p) { return static_cast<std::uint16_t>(p[0] | (p[1] << 8)); }
inline std::uint32_t load_u32(const std::uint8_t* p) {
    return std::uint32_t(p[0]) | (std::uint32_t(p[1]) << 8) | (std::uint32_t(p[2]) << 16) | (std::uint32_t(p[3]) << 24);
}

inline std::uint8_t unit_float_to_u8(float f) {
    if (!(f > 0.0f)) return 0;  // also NaN
    if (f >= 1.0f) return 255;
    // float * 255 is exact in double, so this rounds half away from zero exactly like
    // std::lround(v * 255.0).
    return static_cast<std::uint8_t>(static_cast<double>(f) * 255.0 + 0.5);
}

struct LoadU8 {
    static constexpr std::size_t bytes = 1;
    std::uint8_t operator()(const std::uint8_t* p) const { return *p; }
};
struct LoadU16 {
    static constexpr std::size_t bytes = 2;
    // round(v / 257): v = 257k + r rounds up exactly when r >= 129.
    std::uint8_t operator()(const std::uint8_t* p) const { return static_cast<std::uint8_t>((load_u16(p) + 128u) / 257u); }
};
struct LoadF16 {
    static constexpr std::size_t bytes = 2;
    std::uint8_t operator()(const std::uint8_t* p) const { return unit_float_to_u8(half_to_float(load_u16(p))); }
};
struct LoadF32 {
    static constexpr std::size_t bytes = 4;
    std::uint8_t operator()(const std::uint8_t* p) const { return unit_float_to_u8(std::bit_cast<float>(load_u32(p))); }
};

// 8-bit fast paths, whole 32-bit texels at a time (little-endian hosts: byte 0 is the low byte).
constexpr bool kLittleEndian = std::endian::native == std::endian::little;

inline void store_texel(std::uint8_t* dst, std::uint32_t rgba) { std::memcpy(dst, &rgba, 4); }

// RGB8 -> RGBA8, four texels (12 bytes in, 16 out) per step. Returns texels done.
std::size_t rgb8_to_rgba8(const std::uint8_t* src, std::uint8_t* dst, std::size_t n) {
    std::size_t i = 0;
    for (; i + 4 <= n; i += 4, src += 12, dst += 16) {
        std::uint32_t w0, w1, w2;  // r0 g0 b0 r1 | g1 b1 r2 g2 | b2 r3 g3 b3
        std::memcpy(&w0, src, 4);
        std::memcpy(&w1, src + 4, 4);
        std::memcpy(&w2, src + 8, 4);
        store_texel(dst, w0 | 0xFF000000u);
        store_texel(dst + 4, (w0 >> 24) | (w1 << 8) | 0xFF000000u);
        store_texel(dst + 8, (w1 >> 16) | (w2 << 16) | 0xFF000000u);
        store_texel(dst + 12, (w2 >> 8) | 0xFF000000u);
    }
    return i;
}

// n texels of C channels (samples loaded by L) to RGBA8. Writes dst front to back, never reads it.
template <unsigned C, class L>
void convert_texels(const std::uint8_t* src, std::uint8_t* dst, std::size_t n) {
    constexpr std::size_t stride = C * L::bytes;
    const L load;
    if constexpr (C == 4 && L::bytes == 1) {
        std::memcpy(dst, src, n * 4);
    } else if constexpr (kLittleEndian && L::bytes == 1 && C == 1) {
        for (std::size_t i = 0; i < n; ++i) store_texel(dst + 4 * i, src[i] * 0x010101u | 0xFF000000u);
    } else if constexpr (kLittleEndian && L::bytes == 1 && C == 2) {
        for (std::size_t i = 0; i < n; ++i)
            store_texel(dst + 4 * i, src[2 * i] * 0x010101u | (std::uint32_t(src[2 * i + 1]) << 24));
    } else if constexpr (kLittleEndian && L::bytes == 1 && C == 3) {
        const std::size_t done = rgb8_to_rgba8(src, dst, n);
        for (std::size_t i = done; i < n; ++i)
            store_texel(dst + 4 * i, src[3 * i] | (src[3 * i + 1] << 8) | (src[3 * i + 2] << 16) | 0xFF000000u);
    } else {
        for (std::size_t i = 0; i < n; ++i, src += stride, dst += 4) {
            if constexpr (C == 1) {
                const std::uint8_t v = load(src);
                dst[0] = v, dst[1] = v, dst[2] = v, dst[3] = 255;
            } else if constexpr (C == 2) {
                const std::uint8_t v = load(src);
                dst[0] = v, dst[1] = v, dst[2] = v, dst[3] = load(src + L::bytes);
            } else if constexpr (C == 3) {
                dst[0] = load(src), dst[1] = load(src + L::bytes), dst[2] = load(src + 2 * L::bytes), dst[3] = 255;
            } else {
                dst[0] = load(src), dst[1] = load(src + L::bytes), dst[2] = load(src + 2 * L::bytes),
                dst[3] = load(src + 3 * L::bytes);
            }
        }
    }
}

template <class L>
void convert_channels(unsigned channels, const std::uint8_t* src, std::uint8_t* dst, std::size_t n) {
    switch (channels) {
        case 1: return convert_texels<1, L>(src, dst, n);
        case 2: return convert_texels<2, L>(src, dst, n);
        case 3: return convert_texels<3, L>(src, dst, n);
        default: return convert_texels<4, L>(src, dst, n);
    }
}

// Caller checked channels (1..4) and sample type.
void convert_samples(const StoreInfo& info, const std::uint8_t* src, std::uint8_t* dst, std::size_t n) {
    switch (info.sample_type) {
        case SampleType::u8: return convert_channels<LoadU8>(info.channels, src, dst, n);
        case SampleType::u16: return convert_channels<LoadU16>(info.channels, src, dst, n);
        case SampleType::f16: return convert_channels<LoadF16>(info.channels, src, dst, n);
        case SampleType::f32: return convert_channels<LoadF32>(info.channels, src, dst, n);
    }
}

bool known_sample_type(SampleType t) {
    return t == SampleType::u8 || t == SampleType::u16 || t == SampleType::f16 || t == SampleType::f32;
}

}  // namespace

// --------------------------------------------------------------------------- transcode_to_rgba8

Status transcode_to_rgba8(const StoreInfo& info, TileKind kind, Codec codec,
                          std::span<const std::uint8_t> payload, std::span<std::uint8_t> out, Scratch& scratch) {
    if (info.channels < 1 || info.channels > 4) return make_error(Errc::invalid_argument, "store has 1..4 channels");
    if (!known_sample_type(info.sample_type)) return make_error(Errc::invalid_argument, "unknown sample type");
    if (info.tile_size() == 0 || info.tile_size() > 1u << 14)
        return make_error(Errc::invalid_argument, "impossible tile size");
    const std::size_t texels = std::size_t(info.tile_size()) * info.tile_size();
    if (out.size() != texels * kRgba8TexelBytes)
        return make_error(Errc::invalid_argument, "destination is not one RGBA8 page of this store");
    const std::size_t texel_bytes = info.texel_bytes();
    const std::size_t tile_bytes = info.tile_bytes();

    if (kind == TileKind::absent) return make_error(Errc::not_found, "tile is absent");
    if (kind != TileKind::present && kind != TileKind::uniform)
        return make_error(Errc::invalid_argument, "unknown tile kind " + std::to_string(static_cast<int>(kind)));

    if (kind == TileKind::uniform) {
        if (payload.size() != texel_bytes) return make_error(Errc::corrupt, "uniform value has the wrong size");
        std::uint8_t rgba[4];
        convert_samples(info, payload.data(), rgba, 1);
        std::uint32_t pattern;
        std::memcpy(&pattern, rgba, 4);
        std::uint8_t* dst = out.data();
        for (std::size_t i = 0; i < texels; ++i, dst += 4) std::memcpy(dst, &pattern, 4);
        return {};
    }

    Scratch::Impl& s = *scratch.impl_;
    switch (codec) {
        case Codec::raw:
            if (payload.size() != tile_bytes) return make_error(Errc::corrupt, "raw tile has the wrong size");
            convert_samples(info, payload.data(), out.data(), texels);
            return {};
        case Codec::zstd: {
            // Into scratch, never the destination: zstd reads back what it wrote (matches), which
            // would crawl on write-combined staging memory.
            std::uint8_t* buf = s.sample_buffer(tile_bytes);
            if (Status st = storage::decompress_zstd_tile(info, payload, {buf, tile_bytes}); !st) return st;
            convert_samples(info, buf, out.data(), texels);
            return {};
        }
        case Codec::jpeg:  // straight into the destination as RGBA8
            return storage::decode_jpeg_tile(info, payload, out, /*rgba=*/true);
        case Codec::bc1:
        case Codec::bc4:
        case Codec::bc5:
        case Codec::bc7: {
            // Blocks decoded as the GPU samples them, then the store's channels by the rules above
            // (bc4 (v, 0, 0, 255) is grey v; bc5 (v, a, 0, 255) is grey and alpha).
            if (codec != info.codec) return make_error(Errc::corrupt, "block tile in a store of another codec");
            // A store description from elsewhere (a server) is checked as the reader checks a file's.
            if (const std::string misfit = storage::codec_misfit(codec, info.sample_type, info.channels, info.tile_size(), info.border);
                !misfit.empty())
                return make_error(Errc::corrupt, misfit);
            if (Status st = storage::unpack_block_tile(info, payload, s.blocks); !st) return st;
            std::uint8_t* rgba = s.rgba_buffer(texels * kRgba8TexelBytes);
            blocks::decode_page(*block_format_of(*page_format_of(codec)), s.blocks.data(), info.tile_size(), rgba);
            for (std::size_t i = 0; i < texels; ++i) {
                const std::uint8_t* t = rgba + 4 * i;
                std::uint8_t* d = out.data() + 4 * i;
                if (info.channels == 1) d[0] = d[1] = d[2] = t[0], d[3] = 255;
                else if (info.channels == 2) d[0] = d[1] = d[2] = t[0], d[3] = t[1];
                else if (info.channels == 3) d[0] = t[0], d[1] = t[1], d[2] = t[2], d[3] = 255;
                else std::memcpy(d, t, 4);
            }
            return {};
        }
        default:
            return make_error(Errc::invalid_argument, "unknown codec " + std::to_string(static_cast<int>(codec)));
    }
}

// ------------------------------------------------------------------------------- transcode_page

Status check_page_format(const StoreInfo& info, PageFormat format) {
    const auto refuse = [&](std::string_view why) {
        return make_error(Errc::invalid_argument,
                          "page format " + std::string(to_string(format)) + " does not fit this store: " + std::string(why));
    };
    if (info.colour_space == storage::ColourSpace::srgb && !page_format_decodes_srgb(format))
        return refuse(std::string(to_string(format)) + " pages hold data, sampled as stored, and the store's samples are sRGB "
                      "colour, which would show too bright (use rgba8, bc1 or bc7)");
    if (is_block_compressed(format) && info.tile_size() % 4 != 0)
        return refuse("its tiles are " + std::to_string(info.tile_size()) + " texels, not a multiple of 4 (4x4 blocks)");
    switch (format) {
        case PageFormat::rgba8: return {};
        case PageFormat::bc1:
            if (info.has_alpha || info.channels == 2 || info.channels == 4)
                return refuse("it has an alpha channel, which bc1 pages do not keep (use rgba8)");
            return {};
        case PageFormat::bc4:
            if (info.channels != 1) return refuse("bc4 pages hold 1 channel, the store has " + std::to_string(info.channels));
            return {};
        case PageFormat::bc5:
            if (info.channels < 2) return refuse("bc5 pages hold 2 channels, the store has 1");
            return {};
        case PageFormat::bc7: return {};
        case PageFormat::r16:
        case PageFormat::r16f:
        case PageFormat::r32f: {
            const SampleType want = format == PageFormat::r16    ? SampleType::u16
                                    : format == PageFormat::r16f ? SampleType::f16
                                                                 : SampleType::f32;
            if (info.channels != 1 || info.sample_type != want)
                return refuse("it needs 1 channel of " + std::string(to_string(want)) + " samples, the store has " +
                              std::to_string(info.channels) + " of " + std::string(to_string(info.sample_type)));
            return {};
        }
    }
    return make_error(Errc::invalid_argument, "unknown page format " + std::to_string(static_cast<int>(format)));
}

Status check_pool_format(const StoreInfo& info, const PagePoolFormat& pool) {
    const std::size_t layers = storage::layer_count(info);
    if (layers != pool.layer_count())
        return make_error(Errc::invalid_argument, "the store has " + std::to_string(layers) + " layer" +
                                                      (layers == 1 ? "" : "s") + ", the page pool " +
                                                      std::to_string(pool.layer_count()));
    for (std::size_t i = 0; i < layers; ++i) {
        const StoreInfo layer = storage::layer_store_info(info, i);
        const std::string name = info.layered() ? "layer " + info.layers[i].name + ": " : std::string();
        if (Status st = check_page_format(layer, pool.layer_format(i)); !st)
            return make_error(st.error().code, name + st.error().message);
        if (pool.layer_second_level(i) && info.tile_size() % 8 != 0)
            return make_error(Errc::invalid_argument, name + std::string(to_string(pool.layer_format(i))) +
                                                          " pages with a second level need tiles of a multiple of 8 texels");
    }
    return {};
}

Status transcode_pool_page(const StoreInfo& info, TileKind kind, Codec codec, std::span<const std::uint8_t> payload,
                           const PagePoolFormat& pool, std::span<std::uint8_t> out, Scratch& scratch) {
    const std::uint32_t ts = info.tile_size();
    if (out.size() != pool.upload_bytes(ts))
        return make_error(Errc::invalid_argument, "page buffer of " + std::to_string(out.size()) + " bytes, the pool takes " +
                                                      std::to_string(pool.upload_bytes(ts)));
    if (!info.layered()) {
        if (pool.layer_count() != 1) return check_pool_format(info, pool);
        return transcode_page(info, kind, codec, payload, pool.format, out, scratch, pool.layer_second_level(0));
    }
    if (kind == TileKind::absent) return make_error(Errc::not_found, "tile is absent");
    if (kind != TileKind::present || codec != Codec::layers)
        return make_error(Errc::corrupt, "a multi-layer store's tile must be a layer bundle, not a " +
                                             std::string(to_string(kind)) + " " + std::string(to_string(codec)) + " tile");
    if (pool.layer_count() != info.layers.size()) return check_pool_format(info, pool);
    auto parts = storage::split_layers(info, payload);
    if (!parts) return parts.error();
    // One layer's description per call, reusing this thread's copy (no allocation once warm).
    thread_local StoreInfo layer;
    std::size_t at = 0;
    for (std::size_t i = 0; i < parts->size(); ++i) {
        const storage::LayerPart& part = (*parts)[i];
        const storage::LayerInfo& l = info.layers[i];
        if (part.kind == TileKind::absent)
            return make_error(Errc::not_found, "layer " + l.name + " of the tile is absent");
        layer.width = info.width;
        layer.height = info.height;
        layer.tile_payload = info.tile_payload;
        layer.border = info.border;
        layer.channels = l.channels;
        layer.sample_type = l.sample_type;
        layer.colour_space = l.colour_space;
        layer.codec = l.codec;
        layer.has_alpha = l.has_alpha;
        const std::size_t bytes = pool.layer_bytes(i, ts);
        if (Status st = transcode_page(layer, part.kind, l.codec, part.bytes, pool.layer_format(i), out.subspan(at, bytes),
                                       scratch, pool.layer_second_level(i));
            !st)
            return make_error(st.error().code, "layer " + l.name + ": " + st.error().message);
        at += bytes;
    }
    return {};
}

Status transcode_page(const StoreInfo& info, TileKind kind, Codec codec, std::span<const std::uint8_t> payload,
                      PageFormat format, std::span<std::uint8_t> out, Scratch& scratch, bool second_level) {
    if (second_level && !is_block_compressed(format))
        return make_error(Errc::invalid_argument, "a second level is made for block formats only, not " + std::string(to_string(format)));
    if (format == PageFormat::rgba8) return transcode_to_rgba8(info, kind, codec, payload, out, scratch);
    if (Status st = check_page_format(info, format); !st) return st;
    const std::uint32_t size = info.tile_size();
    if (second_level && size % 8 != 0)
        return make_error(Errc::invalid_argument, "a second level of 4x4 blocks needs tiles of a multiple of 8 texels, not " +
                                                      std::to_string(size));
    if (out.size() != page_upload_bytes(format, size, second_level))
        return make_error(Errc::invalid_argument, "destination is not one " + std::string(to_string(format)) + " page of this store");
    Scratch::Impl& s = *scratch.impl_;

    if (kind == TileKind::present && page_format_of(codec) == format && codec == info.codec) {
        // The store holds this format's blocks, and the page's second level after them: unpacked
        // into scratch (zstd reads back what it wrote), then copied.
        if (const std::string misfit = storage::codec_misfit(codec, info.sample_type, info.channels, size, info.border);
            !misfit.empty())
            return make_error(Errc::corrupt, misfit);
        if (Status st = storage::unpack_block_tile(info, payload, s.blocks); !st) return st;
        std::memcpy(out.data(), s.blocks.data(), out.size());
        return {};
    }

    if (is_block_compressed(format)) {
        // Decoded to RGBA8 in scratch (never the destination: the encoder reads it back), then
        // encoded block by block into the destination; the second level from the 2x2 means.
        const std::size_t rgba_bytes = rgba8_page_bytes(info), half_bytes = rgba_bytes / 4;
        std::uint8_t* buffer = s.rgba_buffer(rgba_bytes + (second_level ? half_bytes : 0));
        const std::span<std::uint8_t> rgba(buffer, rgba_bytes);
        if (Status st = transcode_to_rgba8(info, kind, codec, payload, rgba, scratch); !st) return st;
        // A 2-channel store's RGBA8 texel is (v, v, v, a): bc5 takes R and A.
        const blocks::Channels channels{0, info.channels == 2 ? 3u : 1u};
        const auto encode = [&](const std::uint8_t* texels, std::uint32_t side, std::uint8_t* dst) {
            blocks::encode_page(*block_format_of(format), texels, side, dst, blocks::Effort::realtime, channels);
        };
        encode(rgba.data(), size, out.data());
        if (second_level) {
            std::uint8_t* half = buffer + rgba_bytes;
            blocks::half_size_rgba8(rgba.data(), size, info.colour_space == ColourSpace::srgb, half);
            encode(half, size / 2, out.data() + page_bytes(format, size));
        }
        return {};
    }

    // r16, r16f, r32f: the store's samples exactly (check_page_format matched their size).
    if (kind == TileKind::absent) return make_error(Errc::not_found, "tile is absent");
    const std::size_t texel_bytes = info.texel_bytes(), tile_bytes = info.tile_bytes();
    if (kind == TileKind::uniform) {
        if (payload.size() != texel_bytes) return make_error(Errc::corrupt, "uniform value has the wrong size");
        for (std::size_t i = 0; i < out.size(); i += texel_bytes) std::memcpy(out.data() + i, payload.data(), texel_bytes);
        return {};
    }
    if (kind != TileKind::present)
        return make_error(Errc::invalid_argument, "unknown tile kind " + std::to_string(static_cast<int>(kind)));
    switch (codec) {
        case Codec::raw:
            if (payload.size() != tile_bytes) return make_error(Errc::corrupt, "raw tile has the wrong size");
            std::memcpy(out.data(), payload.data(), tile_bytes);
            return {};
        case Codec::zstd: {
            std::uint8_t* buf = s.sample_buffer(tile_bytes);
            if (Status st = storage::decompress_zstd_tile(info, payload, {buf, tile_bytes}); !st) return st;
            std::memcpy(out.data(), buf, tile_bytes);
            return {};
        }
        case Codec::jpeg:
        case Codec::bc1:
        case Codec::bc4:
        case Codec::bc5:
        case Codec::bc7:
            return make_error(Errc::corrupt, std::string(to_string(codec)) + " tiles hold 8-bit samples, not " +
                                                 std::string(to_string(format)));
        case Codec::layers: break;
    }
    return make_error(Errc::invalid_argument, "unknown codec " + std::to_string(static_cast<int>(codec)));
}

// ------------------------------------------------------------------------------- TranscodePool

namespace {

// Queue order: higher priority first, then submission order.
struct QueueOrder {
    std::uint32_t priority = 0;
    std::uint64_t seq = 0;
};
struct QueueOrderLess {
    bool operator()(const QueueOrder& a, const QueueOrder& b) const {
        return a.priority != b.priority ? a.priority > b.priority : a.seq < b.seq;
    }
};

}  // namespace

struct TranscodePool::State {
    mutable std::mutex mutex;
    std::condition_variable work;  // a job was queued, resume() or shutdown()
    std::mutex join_mutex;         // shutdown() joins once

    using JobQueue = std::map<QueueOrder, TranscodeJob, QueueOrderLess>;
    JobQueue queue;
    std::vector<TranscodeResult> completed;
    std::size_t running = 0;
    std::uint64_t next_seq = 0;
    bool paused = false;
    bool stopping = false;
    TranscodePoolStats counters;

    std::size_t outstanding() const { return queue.size() + running + completed.size(); }

    // Caller holds `mutex`.
    void drop(const TranscodeJob& job) {
        completed.push_back(TranscodeResult{job.key, job.ticket, make_error(Errc::cancelled, "dropped"), true});
        ++counters.dropped;
    }
    template <class Pred>
    std::size_t drop_if(Pred pred) {
        std::size_t n = 0;
        for (auto it = queue.begin(); it != queue.end();) {
            if (pred(it->second)) {
                drop(it->second);
                it = queue.erase(it);
                ++n;
            } else {
                ++it;
            }
        }
        return n;
    }
};

TranscodePool::TranscodePool(const TranscodePoolOptions& options)
    : capacity_(std::max<std::size_t>(1, options.capacity)), state_(std::make_unique<State>()) {
    unsigned n = options.threads;
    if (n == 0) {
        const unsigned hw = std::thread::hardware_concurrency();
        n = hw > 1 ? hw - 1 : 1;
    }
    state_->paused = options.start_paused;
    state_->completed.reserve(capacity_);
    workers_.reserve(n);
    try {
        for (unsigned i = 0; i < n; ++i) workers_.emplace_back([this] { worker_loop(); });
    } catch (const std::system_error&) {
        // The OS refused a thread: run with those we have; with none, accept nothing (threads() == 0).
        if (workers_.empty()) state_->stopping = true;
    }
}

TranscodePool::~TranscodePool() { shutdown(); }

bool TranscodePool::submit(TranscodeJob job) {
    {
        std::lock_guard lock(state_->mutex);
        if (state_->stopping || state_->outstanding() >= capacity_) {
            ++state_->counters.rejected;
            return false;
        }
        const QueueOrder order{job.priority, state_->next_seq++};
        state_->queue.emplace(order, std::move(job));
        ++state_->counters.submitted;
    }
    state_->work.notify_one();
    return true;
}

std::size_t TranscodePool::cancel(const PageKey& key) {
    std::lock_guard lock(state_->mutex);
    return state_->drop_if([&](const TranscodeJob& j) { return j.key == key; });
}

std::size_t TranscodePool::retain_only(const std::function<bool(const PageKey&)>& wanted) {
    std::lock_guard lock(state_->mutex);
    return state_->drop_if([&](const TranscodeJob& j) { return !wanted(j.key); });
}

std::size_t TranscodePool::update_queued(
    const std::function<std::optional<std::uint32_t>(const PageKey&, std::uint32_t)>& f) {
    std::lock_guard lock(state_->mutex);
    auto& q = state_->queue;
    std::size_t dropped = 0;
    std::vector<State::JobQueue::node_type> moved;
    auto reinsert = [&] {
        for (auto& node : moved) q.insert(std::move(node));
    };
    try {
        for (auto it = q.begin(); it != q.end();) {
            const std::optional<std::uint32_t> p = f(it->second.key, it->first.priority);
            if (!p) {
                state_->drop(it->second);
                it = q.erase(it);
                ++dropped;
            } else if (*p != it->first.priority) {
                auto next = std::next(it);
                auto node = q.extract(it);
                node.key().priority = *p;  // keeps its sequence number: ties stay in submission order
                node.mapped().priority = *p;
                moved.push_back(std::move(node));
                it = next;
            } else {
                ++it;
            }
        }
    } catch (...) {
        reinsert();  // no job may vanish without a result, whatever `f` does
        throw;
    }
    reinsert();
    return dropped;
}

std::size_t TranscodePool::poll(std::vector<TranscodeResult>& out) {
    std::lock_guard lock(state_->mutex);
    auto& c = state_->completed;
    const std::size_t n = c.size();
    out.insert(out.end(), std::make_move_iterator(c.begin()), std::make_move_iterator(c.end()));
    c.clear();  // keeps its capacity: no allocation on the workers' side
    return n;
}

void TranscodePool::pause() {
    std::lock_guard lock(state_->mutex);
    state_->paused = true;
}

void TranscodePool::resume() {
    {
        std::lock_guard lock(state_->mutex);
        state_->paused = false;
    }
    state_->work.notify_all();
}

void TranscodePool::shutdown() {
    std::lock_guard join_lock(state_->join_mutex);
    {
        std::lock_guard lock(state_->mutex);
        state_->stopping = true;
        state_->drop_if([](const TranscodeJob&) { return true; });
    }
    state_->work.notify_all();
    for (auto& t : workers_)
        if (t.joinable()) t.join();
}

TranscodePoolStats TranscodePool::stats() const {
    std::lock_guard lock(state_->mutex);
    TranscodePoolStats s = state_->counters;
    s.queued = state_->queue.size();
    s.running = state_->running;
    s.completed = state_->completed.size();
    return s;
}

void TranscodePool::worker_loop() {
    State& st = *state_;
    Scratch scratch;
    std::unique_lock lock(st.mutex);
    for (;;) {
        st.work.wait(lock, [&] { return st.stopping || (!st.paused && !st.queue.empty()); });
        if (st.stopping) return;  // shutdown() dropped the queue
        auto node = st.queue.extract(st.queue.begin());
        ++st.running;
        lock.unlock();

        const TranscodeJob& job = node.mapped();
        Status status;
        if (!job.info) {
            status = make_error(Errc::invalid_argument, "transcode job without store info");
        } else {
            const std::span<const std::uint8_t> payload =
                job.payload ? std::span<const std::uint8_t>(*job.payload) : std::span<const std::uint8_t>();
            status = transcode_pool_page(*job.info, job.kind, job.codec, payload, job.pool, job.destination, scratch);
        }
        TranscodeResult result{job.key, job.ticket, std::move(status), false};
        node = {};  // releases the payload and info outside the lock

        lock.lock();
        --st.running;
        if (result.status.ok())
            ++st.counters.decoded;
        else
            ++st.counters.failed;
        st.completed.push_back(std::move(result));
    }
}

}  // namespace tessera::client
