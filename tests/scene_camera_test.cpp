// The double-precision camera: its frame, projection, and camera-relative math that stays exact
// for positions around 2^24.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "tessera/scene/camera.hpp"

namespace {

using namespace tessera::scene;
constexpr double kPi = std::numbers::pi;

double dot(const Vec3d& a, const Vec3d& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
Vec3d cross(const Vec3d& a, const Vec3d& b) {
    return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
Vec3d add(const Vec3d& a, const Vec3d& b, double s = 1) { return {a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2]}; }

std::array<double, 3> ndc(const Camera& c, double aspect, const Vec3d& p) {
    const auto clip = world_to_clip(c, aspect, p);
    return {clip[0] / clip[3], clip[1] / clip[3], clip[2] / clip[3]};
}

TEST(Camera, FrameConventions) {
    Camera c;
    auto near = [](const Vec3d& a, const Vec3d& b) {
        for (int i = 0; i < 3; ++i)
            if (std::abs(a[i] - b[i]) > 1e-12) return false;
        return true;
    };
    EXPECT_TRUE(near(c.forward(), {1, 0, 0}));
    EXPECT_TRUE(near(c.right(), {0, -1, 0}));
    EXPECT_TRUE(near(c.up(), {0, 0, 1}));
    c.yaw = kPi / 2;
    EXPECT_TRUE(near(c.forward(), {0, 1, 0}));
    c.pitch = -kPi / 2;  // straight down: right stays horizontal, up points along the yaw
    EXPECT_TRUE(near(c.forward(), {0, 0, -1}));
    EXPECT_TRUE(near(c.right(), {1, 0, 0}));
    EXPECT_TRUE(near(c.up(), {0, 1, 0}));
    for (double yaw : {-2.0, 0.3, 1.7, 3.0})
        for (double pitch : {-1.5, -0.4, 0.0, 0.9}) {
            c.yaw = yaw;
            c.pitch = pitch;
            const Vec3d f = c.forward(), r = c.right(), u = c.up();
            EXPECT_NEAR(dot(f, f), 1, 1e-12);
            EXPECT_NEAR(dot(r, r), 1, 1e-12);
            EXPECT_NEAR(dot(u, u), 1, 1e-12);
            EXPECT_NEAR(dot(f, r), 0, 1e-12);
            EXPECT_NEAR(dot(f, u), 0, 1e-12);
            EXPECT_NEAR(r[2], 0, 1e-15);
            EXPECT_TRUE(near(cross(r, f), u));  // right-handed
        }
}

TEST(Camera, PointStraightAheadProjectsToTheCentre) {
    Camera c;
    c.position = {100, 200, 50};
    c.yaw = 0.7;
    c.pitch = -0.3;
    const double aspect = 16.0 / 9.0;
    const auto centre = ndc(c, aspect, add(c.position, c.forward(), 25.0));
    EXPECT_NEAR(centre[0], 0, 1e-12);
    EXPECT_NEAR(centre[1], 0, 1e-12);
    EXPECT_GT(centre[2], -1);
    EXPECT_LT(centre[2], 1);
    // Right of the view is +x, above is +y; behind the camera w < 0.
    EXPECT_GT(ndc(c, aspect, add(add(c.position, c.forward(), 25.0), c.right(), 1.0))[0], 0);
    EXPECT_GT(ndc(c, aspect, add(add(c.position, c.forward(), 25.0), c.up(), 1.0))[1], 0);
    EXPECT_LT(world_to_clip(c, aspect, add(c.position, c.forward(), -5.0))[3], 0);
    // The view's edges: half the vertical field of view up lands on y = 1.
    const double t = std::tan(c.fov_y / 2);
    const auto top = ndc(c, aspect, add(add(c.position, c.forward(), 10.0), c.up(), 10.0 * t));
    EXPECT_NEAR(top[1], 1, 1e-12);
    const auto side = ndc(c, aspect, add(add(c.position, c.forward(), 10.0), c.right(), 10.0 * t * aspect));
    EXPECT_NEAR(side[0], 1, 1e-12);
    // Depth: the near plane maps to -1, the far plane to +1.
    EXPECT_NEAR(ndc(c, aspect, add(c.position, c.forward(), c.near_plane))[2], -1, 1e-9);
    EXPECT_NEAR(ndc(c, aspect, add(c.position, c.forward(), c.far_plane))[2], 1, 1e-9);
}

TEST(Camera, FloatMatricesAgreeWithTheDoubleTransform) {
    Camera c;
    c.position = {5000, -300, 120};
    c.yaw = -2.1;
    c.pitch = -0.6;
    c.near_plane = 1;
    c.far_plane = 1e5;
    const double aspect = 1.5;
    const Mat4f m = multiply(projection(c, aspect), view_rotation(c));
    for (const Vec3d p : {Vec3d{4000, -1200, 0}, Vec3d{4700, -900, 30}, Vec3d{4500, 100, 0}}) {
        const auto rel = camera_relative(p, c.position);
        float clip[4];
        for (int row = 0; row < 4; ++row)
            clip[row] = m[0 * 4 + row] * rel[0] + m[1 * 4 + row] * rel[1] + m[2 * 4 + row] * rel[2] + m[3 * 4 + row];
        const auto ref = world_to_clip(c, aspect, p);
        for (int k = 0; k < 4; ++k) EXPECT_NEAR(clip[k], ref[k], 1e-3 * (1 + std::abs(ref[k]))) << k;
    }
    // multiply is a * b (column-major): identity is neutral.
    Mat4f id{};
    id[0] = id[5] = id[10] = id[15] = 1;
    EXPECT_EQ(multiply(m, id), m);
    EXPECT_EQ(multiply(id, m), m);
}

TEST(Camera, CameraRelativeMathIsExactAround2To24) {
    const double big = 16777216.0;  // 2^24: floats here are 2 units apart
    Camera c;
    c.position = {big + 0.25, big - 3.5, 100.0};
    c.yaw = 1.0;
    c.pitch = -0.5;
    // A chunk origin near the camera: the translation is exact in float.
    const auto rel = camera_relative({big + 64.0, big, 0.0}, c.position);
    EXPECT_EQ(rel[0], 63.75f);
    EXPECT_EQ(rel[1], 3.5f);
    EXPECT_EQ(rel[2], -100.0f);
    // Naive float world positions would have lost the quarter: this is what the design avoids.
    EXPECT_NE(static_cast<float>(big + 64.0) - static_cast<float>(big + 0.25), 63.75f);
    // A point straight ahead still projects to the exact centre.
    const Vec3d ahead = add(c.position, c.forward(), 40.0);
    const auto clip = world_to_clip(c, 16.0 / 9.0, ahead);
    EXPECT_NEAR(clip[0] / clip[3], 0, 1e-9);
    EXPECT_NEAR(clip[1] / clip[3], 0, 1e-9);
    // One unit to the right moves the projection by the same amount as at the origin.
    Camera o = c;
    o.position = {0.25, -3.5, 100.0};
    const auto a = world_to_clip(c, 1.0, add(ahead, c.right(), 1.0));
    const auto b = world_to_clip(o, 1.0, add(add(o.position, o.forward(), 40.0), o.right(), 1.0));
    EXPECT_NEAR(a[0] / a[3], b[0] / b[3], 1e-9);
}

}  // namespace

// Motion prefetch's prediction: linear in position, yaw (the short way across +-pi) and pitch,
// scaled by how far ahead over how long the last step took; nothing for a still camera.
TEST(Camera, ExtrapolateContinuesTheLastMotion) {
    using tessera::scene::Camera;
    using tessera::scene::extrapolate;
    Camera a, b;
    a.position = {100, 200, 50};
    b.position = {110, 190, 52};
    a.yaw = std::numbers::pi - 0.1;  // turning left across +-pi
    b.yaw = -std::numbers::pi + 0.1;
    a.pitch = -0.30;
    b.pitch = -0.25;
    const auto c = extrapolate(a, 1.0, b, 1.5, 1.0);  // two steps of 0.5 s ahead
    ASSERT_TRUE(c.has_value());
    EXPECT_NEAR(c->position[0], 130, 1e-9);
    EXPECT_NEAR(c->position[1], 170, 1e-9);
    EXPECT_NEAR(c->position[2], 56, 1e-9);
    EXPECT_NEAR(c->yaw, -std::numbers::pi + 0.5, 1e-9);  // +0.2 per step, not -6.08
    EXPECT_NEAR(c->pitch, -0.15, 1e-9);
    EXPECT_EQ(c->fov_y, b.fov_y);

    b.pitch = -1.5;
    a.pitch = -1.3;
    EXPECT_NEAR(extrapolate(a, 0, b, 0.1, 1.0)->pitch, -std::numbers::pi / 2, 1e-12) << "never past straight down";
    EXPECT_FALSE(extrapolate(b, 0, b, 0.1, 1.0).has_value()) << "a still camera predicts nothing";
    EXPECT_FALSE(extrapolate(a, 0.2, b, 0.1, 1.0).has_value()) << "time must move forward";
}
