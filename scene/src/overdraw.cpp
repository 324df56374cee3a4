// scene::overdraw_free: whether a depth pre-pass can save the VT pass any work (see scene.hpp).
#include <algorithm>
#include <cmath>

#include "tessera/scene/scene.hpp"

namespace tessera::scene {

namespace {

Vec3d world(const Chunk& c, const Vertex& v) {
    return {c.origin[0] + v.position[0], c.origin[1] + v.position[1], c.origin[2] + v.position[2]};
}
Vec3d sub(const Vec3d& a, const Vec3d& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
Vec3d cross(const Vec3d& a, const Vec3d& b) {
    return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
double dot(const Vec3d& a, const Vec3d& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

}  // namespace

bool overdraw_free(const Scene& scene) {
    // The plane of the first triangle with an area, then every vertex on it and every triangle
    // facing its way. Tolerance: a millionth of the scene's extent.
    const double extent = std::max({scene.bounds_max[0] - scene.bounds_min[0], scene.bounds_max[1] - scene.bounds_min[1],
                                    scene.bounds_max[2] - scene.bounds_min[2], 1.0});
    const double tolerance = extent * 1e-6;
    bool have_plane = false;
    Vec3d normal{0, 0, 0};
    double offset = 0;
    for (const auto& c : scene.chunks) {
        for (std::size_t i = 0; i + 2 < c.indices.size(); i += 3) {
            if (c.indices[i] >= c.vertices.size() || c.indices[i + 1] >= c.vertices.size() ||
                c.indices[i + 2] >= c.vertices.size())
                return false;
            const Vec3d a = world(c, c.vertices[c.indices[i]]);
            const Vec3d n = cross(sub(world(c, c.vertices[c.indices[i + 1]]), a), sub(world(c, c.vertices[c.indices[i + 2]]), a));
            const double len = std::sqrt(dot(n, n));
            if (!(len > 0)) continue;  // degenerate: covers no pixel
            if (!have_plane) {
                normal = {n[0] / len, n[1] / len, n[2] / len};
                offset = dot(normal, a);
                have_plane = true;
            } else if (dot(n, normal) <= 0) {
                return false;  // faces the other way
            }
        }
    }
    if (!have_plane) return true;  // nothing with an area
    for (const auto& c : scene.chunks)
        for (const auto& v : c.vertices)
            if (std::abs(dot(normal, world(c, v)) - offset) > tolerance) return false;
    return true;
}

}  // namespace tessera::scene
