// decode_store_levels, compare_images and count_pops (tessera/client/measures.hpp).
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "tessera/client/measures.hpp"
#include "block_decode.hpp"
#include "transcode.hpp"
#include "tessera/storage/layers.hpp"
#include "tessera/storage/store_reader.hpp"

namespace tessera::client {

namespace {

// Both public functions: `second` selects each page's first level (every level of the store) or
// the second level an atlas of `format` holds under it (levels 0 .. count - 2, half their size).
Result<std::vector<ImageLevel>> decode_levels(const std::string& store_path, std::uint32_t max_side, PageFormat format,
                                                           std::uint32_t layer, bool second) {
    auto opened = storage::StoreReader::open(store_path);
    if (!opened) return opened.error();
    const auto& reader = **opened;
    const auto& store_info = reader.info();
    if (layer >= storage::layer_count(store_info))
        return Error{Errc::invalid_argument, fmt::format("{}: no layer {} (it has {})", store_path, layer, storage::layer_count(store_info))};
    // One layer's description: a layered store's tiles are bundles, each layer's part decoded alone.
    const storage::StoreInfo info = storage::layer_store_info(store_info, layer);
    if (info.width > max_side || info.height > max_side)
        return Error{Errc::resource_exhausted, fmt::format("{}: {}x{} texels, over {} per side for a reference texture", store_path,
                                                           info.width, info.height, max_side)};
    const std::uint32_t P = info.tile_payload, B = info.border, ts = info.tile_size();
    if (Status st = check_page_format(info, format); !st) return Error{st.error().code, store_path + ": " + st.error().message};
    if (format != PageFormat::rgba8 && !is_block_compressed(format))
        return Error{Errc::invalid_argument, fmt::format("{}: reference levels of {} pages are not made", store_path, to_string(format))};
    if (second && (!is_block_compressed(format) || ts % 8 != 0 || B % 2 != 0))
        return Error{Errc::invalid_argument,
                     fmt::format("{}: second levels are made for block formats with tiles a multiple of 8 texels and an even border",
                                 store_path)};
    // A second level is the page at half size: its tile, interior and border halve.
    const std::uint32_t side = second ? ts / 2 : ts, payload = second ? P / 2 : P, border = second ? B / 2 : B;
    std::vector<std::uint8_t> page(std::size_t(side) * side * 4), blocks(page_upload_bytes(format, ts, second));
    Scratch scratch;
    std::vector<ImageLevel> out;
    for (std::uint32_t l = 0; l + (second ? 1 : 0) < info.level_count(); ++l) {
        const auto& li = info.levels[l];
        const std::uint32_t level_w = second ? (li.width + 1) / 2 : li.width, level_h = second ? (li.height + 1) / 2 : li.height;
        ImageLevel level;
        level.width = level_w;
        level.height = level_h;
        level.rgba8.assign(std::size_t(level_w) * level_h * 4, 0);
        for (std::uint32_t ty = 0; ty < li.tiles_y; ++ty) {
            std::vector<TileKey> keys;
            for (std::uint32_t tx = 0; tx < li.tiles_x; ++tx) keys.push_back(TileKey{l, tx, ty});
            auto tiles = reader.read_tiles(keys);
            for (std::uint32_t tx = 0; tx < li.tiles_x; ++tx) {
                auto& t = tiles[tx];
                if (!t) return Error{t.error().code, fmt::format("{}: tile {}/{}/{}: {}", store_path, l, tx, ty, t.error().message)};
                if (t->kind == TileKind::absent) continue;  // transparent black
                TileKind kind = t->kind;
                std::span<const std::uint8_t> bytes = t->bytes;
                if (store_info.layered()) {
                    auto parts = storage::split_layers(store_info, t->bytes);
                    if (!parts) return Error{parts.error().code, fmt::format("{}: tile {}/{}/{}: {}", store_path, l, tx, ty, parts.error().message)};
                    kind = (*parts)[layer].kind;
                    bytes = (*parts)[layer].bytes;
                    if (kind == TileKind::absent) continue;
                }
                Status st = format == PageFormat::rgba8 ? transcode_to_rgba8(info, kind, info.codec, bytes, page, scratch)
                                                        : transcode_page(info, kind, info.codec, bytes, format, blocks, scratch, second);
                if (!st) return Error{st.error().code, fmt::format("{}: tile {}/{}/{}: {}", store_path, l, tx, ty, st.error().message)};
                // Block pages: decoded back as the GPU samples them, so the reference holds the
                // atlas's texels (the second level's blocks follow the page's).
                if (format != PageFormat::rgba8) {
                    decode_block_page(format, blocks.data() + (second ? page_bytes(format, ts) : 0), side, page.data());
                    // The atlas reads bc4 as (r, r, r, 1) and bc5 as (r, r, r, g) (page_atlas.cpp).
                    if (format == PageFormat::bc4 || format == PageFormat::bc5)
                        for (std::size_t i = 0; i < page.size(); i += 4) {
                            page[i + 3] = format == PageFormat::bc5 ? page[i + 1] : 255;
                            page[i + 1] = page[i + 2] = page[i];
                        }
                }
                // The interior [B, B + P) of the tile is level texels [tx * P, (tx + 1) * P).
                const std::uint32_t x0 = tx * payload, y0 = ty * payload;
                const std::uint32_t w = std::min(payload, level_w - x0), h = std::min(payload, level_h - y0);
                for (std::uint32_t y = 0; y < h; ++y)
                    std::memcpy(level.rgba8.data() + (std::size_t(y0 + y) * level_w + x0) * 4,
                                page.data() + (std::size_t(border + y) * side + border) * 4, std::size_t(w) * 4);
            }
        }
        out.push_back(std::move(level));
    }
    return out;
}

}  // namespace

Result<std::vector<ImageLevel>> decode_store_levels(const std::string& store_path, std::uint32_t max_side,
                                                                  PageFormat format, std::uint32_t layer) {
    return decode_levels(store_path, max_side, format, layer, false);
}

Result<std::vector<ImageLevel>> decode_store_second_levels(const std::string& store_path, std::uint32_t max_side,
                                                                         PageFormat format, std::uint32_t layer) {
    return decode_levels(store_path, max_side, format, layer, true);
}

ImageError compare_images(std::span<const std::uint8_t> a, std::span<const std::uint8_t> b, std::uint32_t width,
                          std::uint32_t height, std::span<const std::uint8_t> mask) {
    const std::size_t n = std::size_t(width) * height;
    ImageError e;
    if (a.size() != n * 4 || b.size() != n * 4 || (!mask.empty() && mask.size() != n)) {
        e.psnr = 0;
        e.max_error = 255;
        return e;
    }
    std::uint64_t sum_sq = 0;
    for (std::size_t i = 0; i < n; ++i) {
        if (!mask.empty() && mask[i] == 0) continue;
        ++e.pixels;
        for (int c = 0; c < 3; ++c) {
            const int d = std::abs(int(a[i * 4 + c]) - int(b[i * 4 + c]));
            e.max_error = std::max(e.max_error, d);
            sum_sq += std::uint64_t(d * d);
        }
    }
    if (e.pixels == 0 || sum_sq == 0) {
        e.psnr = std::numeric_limits<double>::infinity();
        return e;
    }
    const double mse = double(sum_sq) / double(e.pixels * 3);
    e.psnr = 10.0 * std::log10(255.0 * 255.0 / mse);
    return e;
}

PopCount count_pops(std::span<const std::uint8_t> before, std::span<const std::uint8_t> after, std::span<const std::uint8_t> ref_before,
                    std::span<const std::uint8_t> ref_after, std::uint32_t width, std::uint32_t height, int threshold) {
    const std::size_t n = std::size_t(width) * height;
    PopCount c;
    if (before.size() != n * 4 || after.size() != n * 4 || ref_before.size() != n * 4 || ref_after.size() != n * 4) return c;
    for (std::size_t i = 0; i < n; ++i) {
        if (ref_before[i * 4 + 3] == 0 || ref_after[i * 4 + 3] == 0) continue;
        ++c.pixels;
        int d = 0;
        for (std::size_t ch = 0; ch < 3; ++ch) {
            const int vt = int(after[i * 4 + ch]) - int(before[i * 4 + ch]);
            const int ref = int(ref_after[i * 4 + ch]) - int(ref_before[i * 4 + ch]);
            d = std::max(d, std::abs(vt - ref));
        }
        c.largest = std::max(c.largest, d);
        if (d > threshold) ++c.popped;
    }
    return c;
}

}  // namespace tessera::client
