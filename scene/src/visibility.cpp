#include "tessera/scene/visibility.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "tessera/page_key.hpp"

namespace tessera::scene {

std::uint64_t PageSet::count(std::uint32_t level) const {
    if (level >= wanted.size()) return 0;
    return static_cast<std::uint64_t>(std::count(wanted[level].begin(), wanted[level].end(), std::uint8_t{1}));
}

namespace {

PageSet empty_set(const VtGeometry& vt) {
    PageSet s;
    const std::uint32_t levels = std::clamp<std::uint32_t>(vt.levels, 1, kMaxLevels);
    for (std::uint32_t l = 0; l < levels; ++l) {
        const std::uint64_t w = (std::uint64_t(vt.width) + (std::uint64_t(1) << l) - 1) >> l;
        const std::uint64_t h = (std::uint64_t(vt.height) + (std::uint64_t(1) << l) - 1) >> l;
        const auto tx = static_cast<std::uint32_t>(std::max<std::uint64_t>(1, (w + vt.tile_payload - 1) / vt.tile_payload));
        const auto ty = static_cast<std::uint32_t>(std::max<std::uint64_t>(1, (h + vt.tile_payload - 1) / vt.tile_payload));
        s.tiles_x.push_back(tx);
        s.tiles_y.push_back(ty);
        s.wanted.emplace_back(std::size_t(tx) * ty, std::uint8_t{0});
    }
    return s;
}

}  // namespace

PageSet pages_wanted(const std::vector<CameraPath>& paths, const VtGeometry& vt, const VisibilityOptions& o) {
    PageSet s = empty_set(vt);
    if (vt.tile_payload == 0 || o.view_width == 0 || o.view_height == 0 || !(o.fps > 0)) return s;
    CpuFeedbackParams params;
    params.main_width = o.view_width;
    params.main_height = o.view_height;
    params.fb_width = (o.view_width + 7) / 8;
    params.fb_height = (o.view_height + 7) / 8;
    std::vector<FeedbackId> ids;
    for (const CameraPath& path : paths) {
        const double d = path.duration();
        const auto frames = static_cast<std::uint64_t>(std::floor(d * o.fps + 1e-9));
        for (std::uint64_t f = 0; f <= frames; ++f) {
            cpu_feedback(path.at(std::min(d, double(f) / o.fps)), vt, params, ids);
            for (const FeedbackId id : ids) {
                if (id == kNoPage) continue;
                const PageKey k = unpack_feedback(id);
                if (k.level < s.wanted.size() && k.x < s.tiles_x[k.level] && k.y < s.tiles_y[k.level])
                    s.wanted[k.level][std::size_t(k.y) * s.tiles_x[k.level] + k.x] = 1;
            }
        }
    }
    return s;
}

PageSet level0_mask(const std::vector<CameraPath>& paths, const VtGeometry& vt, const VisibilityOptions& o) {
    const PageSet all = pages_wanted(paths, vt, o);
    PageSet m = empty_set(vt);
    const std::int64_t tx = m.tiles_x[0], ty = m.tiles_y[0];
    const int r = o.neighbours ? 1 : 0;
    for (std::int64_t y = 0; y < ty; ++y)
        for (std::int64_t x = 0; x < tx; ++x) {
            if (!all.wanted[0][std::size_t(y * tx + x)]) continue;
            for (std::int64_t dy = -r; dy <= r; ++dy)
                for (std::int64_t dx = -r; dx <= r; ++dx) {
                    const std::int64_t nx = x + dx, ny = y + dy;
                    if (nx >= 0 && ny >= 0 && nx < tx && ny < ty) m.wanted[0][std::size_t(ny * tx + nx)] = 1;
                }
        }
    return m;
}

Result<Scene> visibility_terrain(std::uint32_t vt_width, std::uint32_t vt_height) {
    TerrainOptions t;
    t.vt_width = vt_width;
    t.vt_height = vt_height;
    // As `tessera view` and `tessera loadtest`: at most 64 chunks per side.
    while (std::max(vt_width, vt_height) / t.chunk_texels > 64) t.chunk_texels *= 2;
    return make_terrain(t);
}

Result<std::vector<CameraPath>> parse_path_list(const std::string& list, const Scene& scene) {
    std::vector<CameraPath> out;
    const auto names = CameraPath::builtin_names();
    std::size_t start = 0;
    while (true) {
        const std::size_t comma = list.find(',', start);
        const std::string item = list.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
        if (item.empty())
            return make_error(Errc::invalid_argument,
                              "'" + list + "': an empty path name (give built-in path names or path files, comma-separated)");
        if (std::find(names.begin(), names.end(), item) != names.end()) {
            auto p = CameraPath::builtin(item, scene);
            if (!p) return make_error(Errc::invalid_argument, "'" + item + "': " + p.error().message);
            out.push_back(std::move(*p));
        } else {
            std::error_code ec;
            if (!std::filesystem::is_regular_file(item, ec)) {
                std::string known;
                for (const auto& n : names) known += (known.empty() ? "" : ", ") + n;
                return make_error(Errc::invalid_argument,
                                  "'" + item + "' is neither a built-in path (" + known + ") nor a path file");
            }
            auto p = CameraPath::load(item);
            if (!p) return make_error(Errc::invalid_argument, p.error().message);
            out.push_back(std::move(*p));
        }
        if (comma == std::string::npos) break;
        start = comma + 1;
    }
    return out;
}

}  // namespace tessera::scene
