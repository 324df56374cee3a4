#pragma once
// Which pages a set of camera paths over the flat `terrain` scene ever wants (docs/visibility.md):
// the CPU feedback (cpu_feedback.hpp) of every frame along each path, at a fixed frame rate. Used
// by `tessera build --visibility` (level-0 tiles no path wants are written absent) and by
// bench/skip_report (the share of a store a path touches).
//
// Sampling: frames at t = 0, 1/fps, 2/fps, ... up to and including the path's duration; the
// feedback target is view / 8 per side, rounded up (1280x720 -> 160x90, what the renderer uses);
// LoD bias 0, the default LoD rule. Deterministic: the same inputs give the same pages.
#include <cstdint>
#include <string>
#include <vector>

#include "tessera/result.hpp"
#include "tessera/scene/cpu_feedback.hpp"
#include "tessera/scene/path.hpp"
#include "tessera/scene/scene.hpp"

namespace tessera::scene {

struct VisibilityOptions {
    std::uint32_t view_width = 1280, view_height = 720;
    double fps = 30;
    // Prefetch margin for the level-0 mask: the 8 neighbours of each wanted level-0 page are
    // marked too (a camera slightly off the sampled path, or between two samples, still finds
    // its finest tiles).
    bool neighbours = true;
};

// Per level, one flag per page (row-major tiles_x * tiles_y of that level of `vt`).
struct PageSet {
    std::vector<std::uint32_t> tiles_x, tiles_y;
    std::vector<std::vector<std::uint8_t>> wanted;

    bool contains(std::uint32_t level, std::uint32_t x, std::uint32_t y) const {
        return level < wanted.size() && x < tiles_x[level] && y < tiles_y[level] &&
               wanted[level][std::size_t(y) * tiles_x[level] + x] != 0;
    }
    std::uint64_t count(std::uint32_t level) const;
    std::uint64_t total(std::uint32_t level) const { return std::uint64_t(tiles_x[level]) * tiles_y[level]; }
};

// The pages wanted by every sampled frame of every path (exactly cpu_feedback's ids, no margin).
PageSet pages_wanted(const std::vector<CameraPath>& paths, const VtGeometry& vt, const VisibilityOptions& options);

// The level-0 mask of `tessera build --visibility`: the level-0 pages of pages_wanted(), plus
// their 8 neighbours when options.neighbours. Only level 0: a coarser page wanted needs no
// level-0 tile, and coarser levels are never dropped.
PageSet level0_mask(const std::vector<CameraPath>& paths, const VtGeometry& vt, const VisibilityOptions& options);

// The terrain scene of a vt_width x vt_height virtual texture (the flat plane `tessera view` and
// `tessera loadtest` use for it), and the paths of a `--visibility` list: comma-separated names
// of built-in paths or path files. Errors name the item at fault.
Result<Scene> visibility_terrain(std::uint32_t vt_width, std::uint32_t vt_height);
Result<std::vector<CameraPath>> parse_path_list(const std::string& list, const Scene& scene);

}  // namespace tessera::scene
