// The atlas (atlas.hpp): shelf packing of aligned cells, and a source that composes the images
// strip by strip, each read once from top to bottom.
#include "tessera/storage/atlas.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numeric>
#include <string>

#include "samples.hpp"

namespace tessera::storage {
namespace {

std::uint64_t round_up(std::uint64_t v, std::uint64_t a) { return (v + a - 1) / a * a; }
bool is_pow2(std::uint32_t v) { return v && !(v & (v - 1)); }

// Shelf packing into `width`: returns the height, fills positions (in `order`).
std::uint64_t shelf_pack(const std::vector<AtlasCell>& cells, const std::vector<std::size_t>& order, std::uint64_t width,
                         std::vector<std::pair<std::uint64_t, std::uint64_t>>* pos) {
    std::uint64_t x = 0, shelf_y = 0, shelf_h = 0;
    for (std::size_t i : order) {
        const AtlasCell& c = cells[i];
        if (x + c.cell_width > width) {
            shelf_y += shelf_h;
            x = 0;
            shelf_h = 0;
        }
        if (pos) (*pos)[i] = {x, shelf_y};
        x += c.cell_width;
        shelf_h = std::max<std::uint64_t>(shelf_h, c.cell_height);
    }
    return shelf_y + shelf_h;
}

// One image's rows, converted to RGB8 or RGBA8 (`channels`, the atlas's), read a strip at a time
// as the atlas rows move down.
class ItemReader {
public:
    ItemReader(AtlasItem item, const AtlasCell& cell, std::uint32_t channels, AtlasTexels texels)
        : item_(std::move(item)), cell_(cell), channels_(channels), data_(texels == AtlasTexels::data) {}

    // Row r (0 <= r < height) as the atlas's texels; rows are asked for in non-decreasing order,
    // except for a wrapping item, which is read whole on first use (its padding needs rows from
    // both ends).
    Result<const std::uint8_t*> row(std::uint32_t r, const ParallelFor& parallel) {
        const std::size_t out_row = std::size_t(cell_.width) * channels_;
        if (!item_.source) {
            if (strip_.empty()) {
                strip_.resize(out_row);
                for (std::size_t i = 0; i < out_row; i += channels_) {
                    std::memcpy(strip_.data() + i, item_.colour.data(), 3);
                    if (channels_ == 4) strip_[i + 3] = 255;
                }
            }
            return strip_.data();
        }
        while (r >= first_ + count_) {
            const SourceInfo& si = item_.source->info();
            const std::uint32_t n = item_.wrap ? cell_.height - next_ : std::min(kStrip, cell_.height - next_);
            const std::size_t sb = sample_bytes(si.sample_type), in_row = std::size_t(si.width) * si.channels * sb;
            raw_.resize(in_row * n);
            strip_.resize(out_row * n);
            TESSERA_TRY(item_.source->read_rows(next_, n, raw_.data(), parallel));
            for (std::uint32_t y = 0; y < n; ++y) convert(raw_.data() + y * in_row, strip_.data() + y * out_row, si);
            first_ = next_;
            count_ = n;
            next_ += n;
        }
        return strip_.data() + std::size_t(r - first_) * out_row;
    }

    // Frees the buffers once the atlas rows have passed the cell.
    void release() {
        if (!done_) {
            std::vector<std::uint8_t>().swap(raw_);
            std::vector<std::uint8_t>().swap(strip_);
            item_.source.reset();
            done_ = true;
        }
    }
    const AtlasCell& cell() const { return cell_; }
    bool wraps() const { return item_.wrap && item_.source; }
    // Whether an image has alpha: its source says so, with 2 or 4 channels.
    static bool has_alpha(const SourceInfo& si) { return si.has_alpha && (si.channels == 2 || si.channels == 4); }

private:
    static constexpr std::uint32_t kStrip = 64;

    void convert(const std::uint8_t* in, std::uint8_t* out, const SourceInfo& si) const {
        const std::size_t sb = sample_bytes(si.sample_type), texel = si.channels * sb;
        const int colour_channels = si.channels >= 3 ? 3 : 1;  // grey (+ alpha) or RGB (+ alpha)
        const bool plain = si.sample_type == SampleType::u8 && (data_ || si.colour_space == ColourSpace::srgb);
        const bool alpha = has_alpha(si) && !item_.opaque && !data_;
        for (std::uint32_t x = 0; x < si.width; ++x, in += texel, out += channels_) {
            if (channels_ == 4) {  // alpha is linear: scaled, never sRGB-encoded; opaque without one
                const std::uint8_t* s = in + (si.channels - 1) * sb;
                double a = alpha ? build::sample_value(s, si.sample_type) : 1.0;
                if (!(a > 0)) a = 0;  // also NaN
                if (a > 1) a = 1;
                out[3] = alpha && si.sample_type == SampleType::u8 ? *s : static_cast<std::uint8_t>(std::lround(a * 255.0));
            }
            for (int c = 0; c < 3; ++c) {
                const std::uint8_t* s = in + (colour_channels == 3 ? c : 0) * sb;
                if (plain) {
                    out[c] = *s;
                    continue;
                }
                double v = build::sample_value(s, si.sample_type);
                if (!(v > 0)) v = 0;  // also NaN
                if (v > 1) v = 1;
                if (si.colour_space == ColourSpace::linear && !data_) v = build::linear_to_srgb(v);
                out[c] = static_cast<std::uint8_t>(std::lround(v * 255.0));
            }
        }
    }

    AtlasItem item_;
    AtlasCell cell_;
    std::uint32_t channels_ = 3;
    bool data_ = false;  // AtlasTexels::data: values as they are
    std::vector<std::uint8_t> raw_, strip_;
    std::uint32_t first_ = 0, count_ = 0, next_ = 0;
    bool done_ = false;
};

class AtlasSource final : public ImageSource {
public:
    AtlasSource(std::vector<ItemReader> items, const AtlasLayout& layout, std::uint32_t channels, AtlasTexels texels)
        : items_(std::move(items)) {
        info_.width = layout.width;
        info_.height = layout.height;
        info_.channels = channels;
        info_.has_alpha = channels == 4;
        info_.sample_type = SampleType::u8;
        info_.colour_space = texels == AtlasTexels::data ? ColourSpace::linear : ColourSpace::srgb;
        info_.description = std::string(texels == AtlasTexels::data ? "data " : "") + "atlas of " + std::to_string(items_.size()) + " images (" + std::to_string(layout.width) + "x" +
                            std::to_string(layout.height) + ")";
        order_.resize(items_.size());
        std::iota(order_.begin(), order_.end(), std::size_t(0));
        std::stable_sort(order_.begin(), order_.end(),
                         [this](std::size_t a, std::size_t b) { return items_[a].cell().cell_y < items_[b].cell().cell_y; });
    }
    const SourceInfo& info() const override { return info_; }

    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const ParallelFor& parallel) override {
        const std::size_t n = info_.channels, row_bytes = std::size_t(info_.width) * n;
        std::memset(dst, 0, row_bytes * count);  // black where no cell is, and opaque
        if (n == 4)
            for (std::size_t i = 3; i < row_bytes * count; i += 4) dst[i] = 255;
        for (std::uint32_t k = 0; k < count; ++k) {
            const std::uint32_t y = y0 + k;
            std::uint8_t* out = dst + k * row_bytes;
            // Cells are sorted by top; skip those entirely above, stop at the first below.
            while (first_active_ < order_.size()) {
                const AtlasCell& c = items_[order_[first_active_]].cell();
                if (c.cell_y + c.cell_height > y) break;
                items_[order_[first_active_]].release();
                ++first_active_;
            }
            for (std::size_t o = first_active_; o < order_.size(); ++o) {
                ItemReader& item = items_[order_[o]];
                const AtlasCell& c = item.cell();
                if (c.cell_y > y) break;
                if (y >= c.cell_y + c.cell_height) {  // an earlier, shorter cell already passed
                    item.release();
                    continue;
                }
                // Padding: the image's edge repeated (clamp), or for a repeating texture the image
                // continued around (wrap), as GL_REPEAT would sample it.
                const bool wrap = item.wraps();
                const std::int64_t dy = std::int64_t(y) - c.y, h = c.height, w = c.width;
                const std::uint32_t r = static_cast<std::uint32_t>(wrap ? ((dy % h) + h) % h : std::clamp<std::int64_t>(dy, 0, h - 1));
                auto src = item.row(r, parallel);
                if (!src) return src.error();
                const std::uint8_t* s = *src;
                std::uint8_t* d = out + std::size_t(c.cell_x) * n;
                const std::uint32_t left = c.x - c.cell_x, right = c.cell_x + c.cell_width - (c.x + c.width);
                for (std::uint32_t i = 0; i < left; ++i, d += n) {
                    const std::int64_t sx = wrap ? (((std::int64_t(i) - left) % w) + w) % w : 0;
                    std::memcpy(d, s + sx * n, n);
                }
                std::memcpy(d, s, std::size_t(c.width) * n);
                d += std::size_t(c.width) * n;
                for (std::uint32_t i = 0; i < right; ++i, d += n) {
                    const std::int64_t sx = wrap ? std::int64_t(i) % w : w - 1;
                    std::memcpy(d, s + sx * n, n);
                }
            }
        }
        return {};
    }

private:
    SourceInfo info_;
    std::vector<ItemReader> items_;
    std::vector<std::size_t> order_;  // items by cell top
    std::size_t first_active_ = 0;
};

}  // namespace

Result<AtlasLayout> pack_atlas(std::span<const AtlasImageSize> sizes, const AtlasPackOptions& o) {
    if (!is_pow2(o.alignment) || o.alignment > 4096)
        return make_error(Errc::invalid_argument, "atlas alignment must be a power of two up to 4096, got " + std::to_string(o.alignment));
    if (o.padding > 4096) return make_error(Errc::invalid_argument, "atlas padding must be at most 4096, got " + std::to_string(o.padding));
    if (sizes.empty()) return make_error(Errc::invalid_argument, "an atlas needs at least one image");
    AtlasLayout layout;
    layout.cells.resize(sizes.size());
    std::uint64_t area = 0, max_w = 0;
    for (std::size_t i = 0; i < sizes.size(); ++i) {
        if (sizes[i].width == 0 || sizes[i].height == 0)
            return make_error(Errc::invalid_argument, "atlas image " + std::to_string(i) + " has zero size");
        const std::uint64_t cw = round_up(std::uint64_t(sizes[i].width) + 2ull * o.padding, o.alignment);
        const std::uint64_t ch = round_up(std::uint64_t(sizes[i].height) + 2ull * o.padding, o.alignment);
        if (cw > kMaxAtlasSide || ch > kMaxAtlasSide)
            return make_error(Errc::out_of_range, "atlas image " + std::to_string(i) + " is too large for an atlas");
        AtlasCell& c = layout.cells[i];
        c.width = sizes[i].width;
        c.height = sizes[i].height;
        c.cell_width = static_cast<std::uint32_t>(cw);
        c.cell_height = static_cast<std::uint32_t>(ch);
        area += cw * ch;
        max_w = std::max(max_w, cw);
    }
    std::vector<std::size_t> order(sizes.size());
    std::iota(order.begin(), order.end(), std::size_t(0));
    std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
        const AtlasCell &ca = layout.cells[a], &cb = layout.cells[b];
        return ca.cell_height != cb.cell_height ? ca.cell_height > cb.cell_height : ca.cell_width > cb.cell_width;
    });
    // Candidate widths around the square root of the area; keep the smallest atlas (then the squarest).
    const double side = std::sqrt(double(area));
    std::uint64_t best_w = 0, best_h = 0;
    for (double f : {0.8, 0.9, 1.0, 1.1, 1.25, 1.5, 2.0}) {
        const std::uint64_t w = std::max(max_w, round_up(static_cast<std::uint64_t>(std::ceil(side * f)), o.alignment));
        const std::uint64_t h = shelf_pack(layout.cells, order, w, nullptr);
        const auto better = [&] {
            if (best_w == 0) return true;
            if (w * h != best_w * best_h) return w * h < best_w * best_h;
            return std::max(w, h) < std::max(best_w, best_h);
        };
        if (better()) {
            best_w = w;
            best_h = h;
        }
    }
    if (best_w > kMaxAtlasSide || best_h > kMaxAtlasSide)
        return make_error(Errc::out_of_range, "the atlas would be " + std::to_string(best_w) + "x" + std::to_string(best_h) +
                                                  " texels, more than " + std::to_string(kMaxAtlasSide) + " per side");
    std::vector<std::pair<std::uint64_t, std::uint64_t>> pos(sizes.size());
    shelf_pack(layout.cells, order, best_w, &pos);
    for (std::size_t i = 0; i < sizes.size(); ++i) {
        AtlasCell& c = layout.cells[i];
        c.cell_x = static_cast<std::uint32_t>(pos[i].first);
        c.cell_y = static_cast<std::uint32_t>(pos[i].second);
        c.x = c.cell_x + o.padding;
        c.y = c.cell_y + o.padding;
    }
    layout.width = static_cast<std::uint32_t>(best_w);
    layout.height = static_cast<std::uint32_t>(best_h);
    return layout;
}

Result<std::unique_ptr<ImageSource>> make_atlas_source(std::vector<AtlasItem> items, AtlasLayout layout, AtlasTexels texels) {
    if (items.size() != layout.cells.size())
        return make_error(Errc::invalid_argument, "atlas: " + std::to_string(items.size()) + " images for " +
                                                      std::to_string(layout.cells.size()) + " cells");
    // RGBA when any image has alpha (cut-outs), RGB otherwise.
    std::uint32_t channels = 3;
    for (const auto& item : items)
        if (texels == AtlasTexels::colour && item.source && !item.opaque && ItemReader::has_alpha(item.source->info())) channels = 4;
    std::vector<ItemReader> readers;
    readers.reserve(items.size());
    for (std::size_t i = 0; i < items.size(); ++i) {
        const AtlasCell& c = layout.cells[i];
        if (items[i].source) {
            const SourceInfo& si = items[i].source->info();
            if (si.width != c.width || si.height != c.height)
                return make_error(Errc::invalid_argument, "atlas: " + si.description + " is " + std::to_string(si.width) + "x" +
                                                              std::to_string(si.height) + ", its cell expects " +
                                                              std::to_string(c.width) + "x" + std::to_string(c.height));
            if (si.channels < 1 || si.channels > 4)
                return make_error(Errc::unsupported, "atlas: " + si.description + " has " + std::to_string(si.channels) + " channels");
        }
        if (std::uint64_t(c.cell_x) + c.cell_width > layout.width || std::uint64_t(c.cell_y) + c.cell_height > layout.height ||
            c.x < c.cell_x || c.y < c.cell_y || std::uint64_t(c.x) + c.width > std::uint64_t(c.cell_x) + c.cell_width ||
            std::uint64_t(c.y) + c.height > std::uint64_t(c.cell_y) + c.cell_height || c.width == 0 || c.height == 0)
            return make_error(Errc::invalid_argument, "atlas: cell " + std::to_string(i) + " is inconsistent");
        readers.emplace_back(std::move(items[i]), c, channels, texels);
    }
    return std::unique_ptr<ImageSource>(new AtlasSource(std::move(readers), layout, channels, texels));
}

}  // namespace tessera::storage
