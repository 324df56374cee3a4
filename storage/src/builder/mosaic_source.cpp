// The mosaic manifest: images placed on a canvas of up to 2^32 - 1 texels per side, read as a
// sparse source (tessera/storage/sparse_source.hpp).
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <list>
#include <mutex>
#include <sstream>
#include <unordered_map>

#include "samples.hpp"
#include "tessera/storage/sparse_source.hpp"

namespace tessera::storage {
namespace {

constexpr std::uint32_t kCellShift = 12;  // the image lookup grid: cells of 4096 x 4096 texels

Error bad(const std::string& manifest, const std::string& why) {
    return make_error(Errc::invalid_argument, "mosaic manifest " + manifest + ": " + why);
}

// One channel's "opaque" sample value, native bytes.
void opaque(SampleType t, std::uint8_t* out) {
    switch (t) {
        case SampleType::u8: out[0] = 255; break;
        case SampleType::u16: { const std::uint16_t v = 65535; std::memcpy(out, &v, 2); break; }
        case SampleType::f16: { const std::uint16_t v = build::float_to_half(1.0f); std::memcpy(out, &v, 2); break; }
        case SampleType::f32: { const float v = 1.0f; std::memcpy(out, &v, 4); break; }
    }
}

class MosaicSource final : public SparseSource {
public:
    struct Image {
        std::string path;
        SparseRect rect;
    };

    MosaicSource(SourceInfo info, std::vector<Image> images, std::uint32_t image_channels, std::uint64_t cache_bytes)
        : info_(std::move(info)), images_(std::move(images)), image_channels_(image_channels), cache_bytes_(cache_bytes) {
        for (std::uint32_t i = 0; i < images_.size(); ++i) {
            const SparseRect& r = images_[i].rect;
            rects_.push_back(r);
            if (r.width == 0 || r.height == 0) continue;
            for (std::uint64_t cy = r.y >> kCellShift; cy <= (std::uint64_t(r.y) + r.height - 1) >> kCellShift; ++cy)
                for (std::uint64_t cx = r.x >> kCellShift; cx <= (std::uint64_t(r.x) + r.width - 1) >> kCellShift; ++cx)
                    cells_[(cy << 32) | cx].push_back(i);
        }
    }

    const SourceInfo& info() const override { return info_; }
    const std::vector<SparseRect>& present() const override { return rects_; }

    Status read_region(const SparseRect& r, std::span<std::uint8_t> dst) const override {
        const std::size_t tb = info_.channels * sample_bytes(info_.sample_type);
        if (dst.size() != std::size_t(r.width) * r.height * tb || std::uint64_t(r.x) + r.width > info_.width ||
            std::uint64_t(r.y) + r.height > info_.height)
            return make_error(Errc::invalid_argument, "mosaic: region outside the canvas or buffer of the wrong size");
        std::fill(dst.begin(), dst.end(), std::uint8_t(0));
        if (r.width == 0 || r.height == 0) return {};
        // The images that may meet the region, in manifest order (a later one covers an earlier).
        std::vector<std::uint32_t> found;
        for (std::uint64_t cy = r.y >> kCellShift; cy <= (std::uint64_t(r.y) + r.height - 1) >> kCellShift; ++cy)
            for (std::uint64_t cx = r.x >> kCellShift; cx <= (std::uint64_t(r.x) + r.width - 1) >> kCellShift; ++cx)
                if (auto it = cells_.find((cy << 32) | cx); it != cells_.end()) found.insert(found.end(), it->second.begin(), it->second.end());
        std::sort(found.begin(), found.end());
        found.erase(std::unique(found.begin(), found.end()), found.end());
        for (const std::uint32_t i : found) {
            const SparseRect& im = images_[i].rect;
            const std::uint64_t x0 = std::max<std::uint64_t>(r.x, im.x), x1 = std::min<std::uint64_t>(std::uint64_t(r.x) + r.width, std::uint64_t(im.x) + im.width);
            const std::uint64_t y0 = std::max<std::uint64_t>(r.y, im.y), y1 = std::min<std::uint64_t>(std::uint64_t(r.y) + r.height, std::uint64_t(im.y) + im.height);
            if (x0 >= x1 || y0 >= y1) continue;
            auto texels = image(i);
            if (!texels) return texels.error();
            for (std::uint64_t y = y0; y < y1; ++y)
                std::memcpy(dst.data() + ((y - r.y) * r.width + (x0 - r.x)) * tb,
                            (*texels)->data() + ((y - im.y) * im.width + (x0 - im.x)) * tb, (x1 - x0) * tb);
        }
        return {};
    }

private:
    using Texels = std::shared_ptr<const std::vector<std::uint8_t>>;

    // Image i's texels (with alpha), read whole on first use; the least recently used go when the
    // cache is over its budget (the one in use always stays).
    Result<Texels> image(std::uint32_t i) const {
        std::lock_guard lock(mu_);
        for (auto it = lru_.begin(); it != lru_.end(); ++it)
            if (it->first == i) {
                lru_.splice(lru_.begin(), lru_, it);
                return it->second;
            }
        const Image& im = images_[i];
        const std::string name = "mosaic image " + std::to_string(i) + " (" + im.path + ")";
        auto src = open_image_source(im.path);
        if (!src) return make_error(src.error().code, name + ": " + src.error().message);
        const SourceInfo& si = (*src)->info();
        if (si.width != im.rect.width || si.height != im.rect.height || si.channels != image_channels_ || si.sample_type != info_.sample_type)
            return make_error(Errc::invalid_argument, name + " changed since the manifest was opened");
        const std::size_t sb = sample_bytes(si.sample_type), in_tb = si.channels * sb, tb = info_.channels * sb;
        std::vector<std::uint8_t> rows(std::size_t(si.width) * std::min<std::uint32_t>(64, si.height) * in_tb);
        auto out = std::make_shared<std::vector<std::uint8_t>>(std::size_t(si.width) * si.height * tb);
        const ParallelFor serial = [](std::size_t n, const std::function<void(std::size_t, std::size_t)>& fn) { fn(0, n); };
        std::uint8_t one[4];
        opaque(info_.sample_type, one);
        for (std::uint32_t y = 0; y < si.height; y += 64) {
            const std::uint32_t count = std::min<std::uint32_t>(64, si.height - y);
            if (Status st = (*src)->read_rows(y, count, rows.data(), serial); !st)
                return make_error(st.error().code, name + ": " + st.error().message);
            std::uint8_t* o = out->data() + std::size_t(y) * si.width * tb;
            if (in_tb == tb) {
                std::memcpy(o, rows.data(), std::size_t(count) * si.width * tb);
                continue;
            }
            for (std::size_t t = 0; t < std::size_t(count) * si.width; ++t, o += tb) {  // alpha added: opaque
                std::memcpy(o, rows.data() + t * in_tb, in_tb);
                std::memcpy(o + in_tb, one, sb);
            }
        }
        cached_ += out->size();
        lru_.emplace_front(i, out);
        while (cached_ > cache_bytes_ && lru_.size() > 1) {
            cached_ -= lru_.back().second->size();
            lru_.pop_back();
        }
        return Texels(out);
    }

    SourceInfo info_;
    std::vector<Image> images_;
    std::vector<SparseRect> rects_;
    std::uint32_t image_channels_;
    std::uint64_t cache_bytes_;
    std::unordered_map<std::uint64_t, std::vector<std::uint32_t>> cells_;  // (cy << 32 | cx) -> images meeting the cell
    mutable std::mutex mu_;
    mutable std::list<std::pair<std::uint32_t, Texels>> lru_;
    mutable std::uint64_t cached_ = 0;
};

// A JSON unsigned integer field of `o`, at most `max`.
Result<std::uint64_t> field(const nlohmann::json& o, const char* name, std::uint64_t max, const std::string& manifest,
                            const std::string& where) {
    const auto it = o.find(name);
    if (it == o.end()) return bad(manifest, where + "has no \"" + name + "\"");
    if (!it->is_number_unsigned() || it->get<std::uint64_t>() > max)
        return bad(manifest, where + "\"" + name + "\" must be an integer from 0 to " + std::to_string(max) + ", got " + it->dump());
    return it->get<std::uint64_t>();
}

}  // namespace

Result<std::unique_ptr<SparseSource>> open_mosaic_source(const std::string& manifest, std::uint64_t cache_bytes) {
    std::ifstream in(manifest, std::ios::binary);
    if (!in) return make_error(Errc::not_found, "mosaic manifest " + manifest + ": cannot be read");
    std::stringstream text;
    text << in.rdbuf();
    const nlohmann::json j = nlohmann::json::parse(text.str(), nullptr, /*allow_exceptions=*/false);
    if (j.is_discarded()) return bad(manifest, "not valid JSON");
    if (!j.is_object()) return bad(manifest, "not a JSON object");
    constexpr std::uint64_t kMaxSide = 0xffffffffull;
    auto width = field(j, "width", kMaxSide, manifest, "");
    if (!width) return width.error();
    auto height = field(j, "height", kMaxSide, manifest, "");
    if (!height) return height.error();
    if (*width == 0 || *height == 0) return bad(manifest, "the canvas is empty (width and height must be at least 1)");
    const auto images = j.find("images");
    if (images == j.end() || !images->is_array() || images->empty())
        return bad(manifest, "\"images\" must be a non-empty array of {\"path\", \"x\", \"y\"}");

    const std::filesystem::path dir = std::filesystem::path(manifest).parent_path();
    std::vector<MosaicSource::Image> placed;
    SourceInfo first;
    for (std::size_t i = 0; i < images->size(); ++i) {
        const nlohmann::json& e = (*images)[i];
        const std::string where = "image " + std::to_string(i) + ": ";
        if (!e.is_object()) return bad(manifest, where + "not a JSON object");
        const auto p = e.find("path");
        if (p == e.end() || !p->is_string() || p->get<std::string>().empty()) return bad(manifest, where + "\"path\" must be a file name");
        auto x = field(e, "x", kMaxSide, manifest, where);
        if (!x) return x.error();
        auto y = field(e, "y", kMaxSide, manifest, where);
        if (!y) return y.error();
        std::filesystem::path path = p->get<std::string>();
        if (path.is_relative()) path = dir / path;
        auto src = open_image_source(path.string());
        if (!src) return make_error(src.error().code, "mosaic manifest " + manifest + ": " + where + src.error().message);
        const SourceInfo& si = (*src)->info();
        if (*x + si.width > *width || *y + si.height > *height)
            return bad(manifest, where + path.string() + " (" + std::to_string(si.width) + " x " + std::to_string(si.height) + " at " +
                                     std::to_string(*x) + ", " + std::to_string(*y) + ") does not fit the " + std::to_string(*width) +
                                     " x " + std::to_string(*height) + " canvas");
        if (i == 0) {
            first = si;
            if (!si.has_alpha && (si.channels == 2 || si.channels == 4))
                return bad(manifest, where + path.string() + " has " + std::to_string(si.channels) +
                                         " channels and none of them is alpha (a mosaic adds alpha to grey or RGB)");
        } else if (si.channels != first.channels || si.has_alpha != first.has_alpha || si.sample_type != first.sample_type ||
                   si.colour_space != first.colour_space) {
            return bad(manifest, where + path.string() + " (" + si.description + ") does not have image 0's channels, sample type "
                                     "and colour space (" + first.description + ")");
        }
        placed.push_back({path.string(), SparseRect{std::uint32_t(*x), std::uint32_t(*y), si.width, si.height}});
    }
    SourceInfo info = first;
    info.width = static_cast<std::uint32_t>(*width);
    info.height = static_cast<std::uint32_t>(*height);
    info.channels = first.has_alpha ? first.channels : first.channels + 1;
    info.has_alpha = true;
    info.description = "mosaic " + manifest + " (" + std::to_string(placed.size()) + " images)";
    return std::unique_ptr<SparseSource>(new MosaicSource(std::move(info), std::move(placed), first.channels, cache_bytes));
}

}  // namespace tessera::storage
