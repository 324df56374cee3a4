#pragma once
// Test helper shared by the rendering tests: where the ray through a pixel meets the ground.
#include <cmath>
#include <cstdint>

#include "tessera/scene/camera.hpp"

namespace tessera::test {

// Where the ray through the centre of pixel (i, j) of a w x h image (row 0 at the top) meets
// z = 0; false when it points up or level.
inline bool pixel_to_ground(const scene::Camera& c, std::uint32_t w, std::uint32_t h, double i, double j, double& x,
                            double& y) {
    const auto f = c.forward(), r = c.right(), u = c.up();
    const double sy = std::tan(c.fov_y / 2.0), sx = sy * double(w) / double(h);
    const double nx = (i + 0.5) / w * 2.0 - 1.0, ny = 1.0 - (j + 0.5) / h * 2.0;
    double d[3];
    for (int k = 0; k < 3; ++k) d[k] = f[k] + nx * sx * r[k] + ny * sy * u[k];
    if (!(d[2] < 0)) return false;
    const double t = -c.position[2] / d[2];
    x = c.position[0] + t * d[0];
    y = c.position[1] + t * d[1];
    return true;
}

}  // namespace tessera::test
