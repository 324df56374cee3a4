// The `terrain` scene: the virtual texture on a ground plane, cut into chunks with double-precision
// origins and integer texel origins, optionally displaced by a height field (a store's height
// layer) or a smooth deterministic height function.
#include <algorithm>
#include <cmath>
#include <numbers>

#include "tessera/scene/scene.hpp"

namespace tessera::scene {
namespace {

// Beyond this many vertices the scene would not fit any GPU buffer sensibly (2^26 vertices are
// 1.25 GiB of Vertex): a caller with a huge texture must choose larger chunks.
constexpr std::uint64_t kMaxVertices = std::uint64_t(1) << 26;

}  // namespace

double terrain_height(const TerrainOptions& o, double x, double y) {
    if (o.displacement == 0) return 0;
    if (o.heights) {
        const HeightField& f = *o.heights;
        // Sample (i, j) sits at the centre of its cell: grid position x / cell - 0.5.
        const double cx = f.texels_per_sample > 0 ? f.texels_per_sample : std::max(1.0, double(o.vt_width)) / f.width;
        const double cy = f.texels_per_sample > 0 ? f.texels_per_sample : std::max(1.0, double(o.vt_height)) / f.height;
        const double gx = std::clamp(x / cx - 0.5, 0.0, double(f.width - 1));
        const double gy = std::clamp(y / cy - 0.5, 0.0, double(f.height - 1));
        const auto x0 = static_cast<std::uint32_t>(gx), y0 = static_cast<std::uint32_t>(gy);
        const std::uint32_t x1 = std::min(x0 + 1, f.width - 1), y1 = std::min(y0 + 1, f.height - 1);
        const double fx = gx - x0, fy = gy - y0;
        const auto at = [&](std::uint32_t i, std::uint32_t j) { return double(f.samples[std::size_t(j) * f.width + i]); };
        const double top = at(x0, y0) + (at(x1, y0) - at(x0, y0)) * fx;
        const double bottom = at(x0, y1) + (at(x1, y1) - at(x0, y1)) * fx;
        return o.displacement * (top + (bottom - top) * fy);
    }
    // A few products of sines with wavelengths proportional to the terrain's size; the weights sum
    // to 1 and each term lies in [-1, 1], so the height stays within [0, displacement].
    const double size = std::max({1.0, double(o.vt_width), double(o.vt_height)});
    constexpr double two_pi = 2.0 * std::numbers::pi;
    struct Wave {
        double wavelength, weight, phase_x, phase_y;
    };
    static constexpr Wave waves[] = {
        {1.0 / 2.7, 0.45, 0.3, 1.1}, {1.0 / 6.3, 0.27, 2.0, 0.4}, {1.0 / 14.9, 0.17, 4.1, 2.9}, {1.0 / 37.1, 0.11, 1.7, 5.3}};
    double s = 0;
    for (const Wave& w : waves) {
        const double k = two_pi / (w.wavelength * size);
        s += w.weight * std::sin(k * x + w.phase_x) * std::cos(k * 0.83 * y + w.phase_y);
    }
    return o.displacement * (0.5 + 0.5 * s);
}

Result<Scene> make_terrain(const TerrainOptions& o) {
    if (o.vt_width == 0 || o.vt_height == 0) return make_error(Errc::invalid_argument, "terrain: the virtual texture has zero size");
    if (o.chunk_texels == 0) return make_error(Errc::invalid_argument, "terrain: chunk_texels must be at least 1");
    if (o.quads_per_chunk == 0) return make_error(Errc::invalid_argument, "terrain: quads_per_chunk must be at least 1");
    if (!std::isfinite(o.displacement) || o.displacement < 0)
        return make_error(Errc::invalid_argument, "terrain: displacement must be finite and not negative");
    if (o.heights && (o.heights->width == 0 || o.heights->height == 0 ||
                      o.heights->samples.size() != std::size_t(o.heights->width) * o.heights->height))
        return make_error(Errc::invalid_argument, "terrain: the height field has no samples or not width x height of them");
    if (o.heights && !std::all_of(o.heights->samples.begin(), o.heights->samples.end(), [](float v) { return std::isfinite(v); }))
        return make_error(Errc::invalid_argument, "terrain: the height field holds a NaN or an infinity");
    const std::uint64_t cx_count = (std::uint64_t(o.vt_width) + o.chunk_texels - 1) / o.chunk_texels;
    const std::uint64_t cy_count = (std::uint64_t(o.vt_height) + o.chunk_texels - 1) / o.chunk_texels;
    const std::uint64_t q = o.quads_per_chunk;
    if (cx_count * cy_count * (q + 1) * (q + 1) > kMaxVertices)
        return make_error(Errc::resource_exhausted,
                          "terrain: " + std::to_string(cx_count * cy_count) + " chunks of " + std::to_string((q + 1) * (q + 1)) +
                              " vertices are too many; choose a larger chunk_texels (or fewer quads_per_chunk)");

    Scene scene;
    scene.name = "terrain";
    scene.vt_width = o.vt_width;
    scene.vt_height = o.vt_height;
    scene.chunks.reserve(cx_count * cy_count);
    scene.chunk_pitch = double(o.chunk_texels);
    scene.bounds_min[0] = scene.bounds_min[1] = scene.bounds_min[2] = INFINITY;
    scene.bounds_max[0] = scene.bounds_max[1] = scene.bounds_max[2] = -INFINITY;
    const std::uint32_t n = static_cast<std::uint32_t>(q) + 1;
    for (std::uint64_t cy = 0; cy < cy_count; ++cy) {
        for (std::uint64_t cx = 0; cx < cx_count; ++cx) {
            Chunk c;
            const std::uint64_t x0 = cx * o.chunk_texels, y0 = cy * o.chunk_texels;
            const double sx = double(std::min<std::uint64_t>(o.chunk_texels, o.vt_width - x0));
            const double sy = double(std::min<std::uint64_t>(o.chunk_texels, o.vt_height - y0));
            c.origin = {double(x0), double(y0), 0.0};
            c.texel_origin[0] = static_cast<std::uint32_t>(x0);
            c.texel_origin[1] = static_cast<std::uint32_t>(y0);
            c.vertices.reserve(std::size_t(n) * n);
            double zmin = INFINITY, zmax = -INFINITY;
            for (std::uint32_t j = 0; j < n; ++j) {
                // The last row and column land exactly on the chunk's edge (no rounding gaps).
                const double ly = j == q ? sy : sy * j / double(q);
                for (std::uint32_t i = 0; i < n; ++i) {
                    const double lx = i == q ? sx : sx * i / double(q);
                    const double z = terrain_height(o, c.origin[0] + lx, c.origin[1] + ly);
                    zmin = std::min(zmin, z);
                    zmax = std::max(zmax, z);
                    Vertex v{};
                    v.position[0] = static_cast<float>(lx);
                    v.position[1] = static_cast<float>(ly);
                    v.position[2] = static_cast<float>(z);
                    v.texel[0] = static_cast<float>(lx);  // texel (u, v) of world (x, y) is (x, y)
                    v.texel[1] = static_cast<float>(ly);
                    c.vertices.push_back(v);
                }
            }
            c.indices.reserve(std::size_t(q) * q * 6);
            for (std::uint32_t j = 0; j < q; ++j)
                for (std::uint32_t i = 0; i < q; ++i) {
                    const std::uint32_t a = j * n + i, b = a + 1, d = a + n, e = d + 1;
                    // Counter-clockwise seen from +Z: (i, j) -> (i+1, j) -> (i+1, j+1), then -> (i, j+1).
                    c.indices.insert(c.indices.end(), {a, b, e, a, e, d});
                }
            c.grid_quads = static_cast<std::uint32_t>(q);
            c.grid_quad_size[0] = sx / double(q);
            c.grid_quad_size[1] = sy / double(q);
            c.grid_chunk[0] = static_cast<std::int64_t>(cx);
            c.grid_chunk[1] = static_cast<std::int64_t>(cy);
            c.bounds_min[0] = c.origin[0];
            c.bounds_min[1] = c.origin[1];
            c.bounds_min[2] = zmin;
            c.bounds_max[0] = c.origin[0] + sx;
            c.bounds_max[1] = c.origin[1] + sy;
            c.bounds_max[2] = zmax;
            for (int k = 0; k < 3; ++k) {
                scene.bounds_min[k] = std::min(scene.bounds_min[k], c.bounds_min[k]);
                scene.bounds_max[k] = std::max(scene.bounds_max[k], c.bounds_max[k]);
            }
            scene.chunks.push_back(std::move(c));
        }
    }
    return scene;
}

}  // namespace tessera::scene
