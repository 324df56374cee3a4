// The double-precision camera: its frame, the view rotation and the GL projection.
#include "tessera/scene/camera.hpp"

#include <algorithm>
#include <cmath>

namespace tessera::scene {

Vec3d Camera::forward() const {
    const double cp = std::cos(pitch);
    return {cp * std::cos(yaw), cp * std::sin(yaw), std::sin(pitch)};
}

// forward x +Z, normalised: horizontal whatever the pitch (also when looking straight down).
Vec3d Camera::right() const { return {std::sin(yaw), -std::cos(yaw), 0.0}; }

// right x forward.
Vec3d Camera::up() const {
    const double sp = std::sin(pitch), cp = std::cos(pitch);
    return {-sp * std::cos(yaw), -sp * std::sin(yaw), cp};
}

Mat4f view_rotation(const Camera& c) {
    const Vec3d r = c.right(), u = c.up(), f = c.forward();
    // Rows: right, up, -forward (the eye looks down -Z). Column-major storage: m[col * 4 + row].
    Mat4f m{};
    for (int i = 0; i < 3; ++i) {
        m[i * 4 + 0] = static_cast<float>(r[i]);
        m[i * 4 + 1] = static_cast<float>(u[i]);
        m[i * 4 + 2] = static_cast<float>(-f[i]);
    }
    m[15] = 1.0f;
    return m;
}

Mat4f projection(const Camera& c, double aspect) {
    const double f = 1.0 / std::tan(c.fov_y / 2.0), n = c.near_plane, fa = c.far_plane;
    Mat4f m{};
    m[0] = static_cast<float>(f / aspect);
    m[5] = static_cast<float>(f);
    m[10] = static_cast<float>((fa + n) / (n - fa));
    m[11] = -1.0f;
    m[14] = static_cast<float>(2.0 * fa * n / (n - fa));
    return m;
}

Mat4f multiply(const Mat4f& a, const Mat4f& b) {
    Mat4f m{};
    for (int col = 0; col < 4; ++col)
        for (int row = 0; row < 4; ++row) {
            float s = 0;
            for (int k = 0; k < 4; ++k) s += a[k * 4 + row] * b[col * 4 + k];
            m[col * 4 + row] = s;
        }
    return m;
}

std::array<float, 3> camera_relative(const Vec3d& origin, const Vec3d& camera_position) {
    return {static_cast<float>(origin[0] - camera_position[0]), static_cast<float>(origin[1] - camera_position[1]),
            static_cast<float>(origin[2] - camera_position[2])};
}

std::array<double, 4> world_to_clip(const Camera& c, double aspect, const Vec3d& world) {
    const Vec3d d{world[0] - c.position[0], world[1] - c.position[1], world[2] - c.position[2]};
    const Vec3d r = c.right(), u = c.up(), f = c.forward();
    const double ex = r[0] * d[0] + r[1] * d[1] + r[2] * d[2];
    const double ey = u[0] * d[0] + u[1] * d[1] + u[2] * d[2];
    const double ez = -(f[0] * d[0] + f[1] * d[1] + f[2] * d[2]);  // eye space: -Z ahead
    const double t = 1.0 / std::tan(c.fov_y / 2.0), n = c.near_plane, fa = c.far_plane;
    return {t / aspect * ex, t * ey, (fa + n) / (n - fa) * ez + 2.0 * fa * n / (n - fa), -ez};
}

std::optional<Camera> extrapolate(const Camera& before, double t0, const Camera& now, double t1, double ahead) {
    if (!(t1 > t0) || !(ahead > 0)) return std::nullopt;
    const double k = ahead / (t1 - t0);
    constexpr double kPi = 3.14159265358979323846;
    const double dyaw = std::remainder(now.yaw - before.yaw, 2 * kPi);
    const double dpitch = now.pitch - before.pitch;
    const Vec3d dp = {now.position[0] - before.position[0], now.position[1] - before.position[1],
                      now.position[2] - before.position[2]};
    if (dyaw == 0 && dpitch == 0 && dp[0] == 0 && dp[1] == 0 && dp[2] == 0) return std::nullopt;
    Camera c = now;
    for (int i = 0; i < 3; ++i) c.position[std::size_t(i)] += k * dp[std::size_t(i)];
    c.yaw = now.yaw + k * dyaw;
    c.pitch = std::clamp(now.pitch + k * dpitch, -kPi / 2, kPi / 2);
    return c;
}

}  // namespace tessera::scene
