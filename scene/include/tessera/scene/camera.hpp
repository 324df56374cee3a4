#pragma once
// A camera in double precision. Rendering is camera-relative: the renderer subtracts the camera
// position from each chunk's origin on the CPU, in double, so float vertex positions stay small
// however large the world (a 2^24-texel terrain is 2^24 world units wide).
//
// Conventions: right-handed, +Z up (terrain is the plane z = 0, x and y along the texture's
// x and y). yaw: radians, 0 looks along +X, pi/2 along +Y. pitch: radians, 0 horizontal,
// negative looks down. fov_y: vertical field of view, radians.
#include <array>
#include <optional>

namespace tessera::scene {

using Vec3d = std::array<double, 3>;
using Mat4f = std::array<float, 16>;  // column-major, as OpenGL wants it

struct Camera {
    Vec3d position{0, 0, 0};
    double yaw = 0;
    double pitch = 0;
    double fov_y = 1.0471975511965976;  // 60 degrees
    double near_plane = 0.1;            // world units
    double far_plane = 1.0e7;

    Vec3d forward() const;  // unit view direction
    Vec3d right() const;    // unit, horizontal
    Vec3d up() const;       // unit, completes the frame
};

// View matrix of the camera moved to the origin (rotation only: translate positions by
// `chunk_origin - camera.position` first), and a perspective projection (GL clip space, depth
// -1..1) for an aspect ratio width/height.
Mat4f view_rotation(const Camera& c);
Mat4f projection(const Camera& c, double aspect);
Mat4f multiply(const Mat4f& a, const Mat4f& b);  // a * b

// `origin - camera_position` in double, then rounded once to float: the translation a chunk's
// vertices get (exact to float rounding of the small difference, however large the coordinates).
std::array<float, 3> camera_relative(const Vec3d& origin, const Vec3d& camera_position);
// Clip coordinates (x, y, z, w) of a world point, all in double and camera-relative: the same
// transform as projection * view_rotation * (world - position). NDC = xyz / w (w > 0 in front).
std::array<double, 4> world_to_clip(const Camera& c, double aspect, const Vec3d& world);

// The camera `ahead` seconds after `now`, moving on as it moved from `before` (at time t0) to
// `now` (at t1): position, yaw (the short way round) and pitch extrapolated linearly, pitch kept
// within +-90 degrees, the rest of `now`. Nothing when t1 <= t0 or the camera did not move.
std::optional<Camera> extrapolate(const Camera& before, double t0, const Camera& now, double t1, double ahead);

}  // namespace tessera::scene
