// Camera paths: the text format (parse, round trip, errors with line numbers), interpolation, and
// the built-ins (in bounds, above the ground, continuous, doing what their names promise).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <set>

#include "tessera/scene/cpu_feedback.hpp"
#include "tessera/scene/path.hpp"
#include "test_util.hpp"

namespace {

using namespace tessera::scene;
constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180;

const char* kExample = R"(# tessera camera path v1
fov 60
# time_s   x        y        z       yaw_deg  pitch_deg
0.0        1000     2000     150     45       -20
2.5        1800     2400     120     60       -15

5          2000     3000     100     90       -10   # trailing comment
)";

std::string error_of(std::string_view text) {
    auto p = CameraPath::parse(text, "test.path");
    return p.ok() ? std::string("(no error)") : p.error().message;
}

Scene terrain_scene(double w, double h) {
    Scene s;
    s.name = "terrain";
    s.vt_width = static_cast<std::uint32_t>(w);
    s.vt_height = static_cast<std::uint32_t>(h);
    s.bounds_max[0] = w;
    s.bounds_max[1] = h;
    return s;
}

TEST(Path, ParsesTheDocumentedFormat) {
    auto p = CameraPath::parse(kExample, "example");
    ASSERT_TRUE(p.ok()) << p.error().message;
    ASSERT_EQ(p->keyframes().size(), 3u);
    EXPECT_EQ(p->duration(), 5.0);
    EXPECT_NEAR(p->fov_y(), 60 * kDeg, 1e-15);
    const Keyframe& k = p->keyframes()[1];
    EXPECT_EQ(k.time, 2.5);
    EXPECT_EQ(k.position[0], 1800);
    EXPECT_EQ(k.position[1], 2400);
    EXPECT_EQ(k.position[2], 120);
    EXPECT_NEAR(k.yaw, 60 * kDeg, 1e-15);
    EXPECT_NEAR(k.pitch, -15 * kDeg, 1e-15);
    // At a keyframe the camera is exactly there; beyond the ends it is clamped.
    const Camera c = p->at(2.5);
    EXPECT_NEAR(c.position[0], 1800, 1e-9);
    EXPECT_NEAR(c.yaw, 60 * kDeg, 1e-12);
    EXPECT_NEAR(c.fov_y, 60 * kDeg, 1e-15);
    EXPECT_NEAR(p->at(-3).position[0], 1000, 1e-9);
    EXPECT_NEAR(p->at(99).position[1], 3000, 1e-9);
    EXPECT_NEAR(p->at(std::nan("")).position[0], 1000, 1e-9);
}

TEST(Path, RoundTripsThroughText) {
    auto scene = terrain_scene(16384, 16384);
    for (const std::string& name : CameraPath::builtin_names()) {
        auto p = CameraPath::builtin(name, scene);
        ASSERT_TRUE(p.ok()) << name;
        auto q = CameraPath::parse(p->to_text(), name);
        ASSERT_TRUE(q.ok()) << name << ": " << q.error().message;
        ASSERT_EQ(q->keyframes().size(), p->keyframes().size());
        EXPECT_NEAR(q->fov_y(), p->fov_y(), 1e-12);
        for (std::size_t i = 0; i < p->keyframes().size(); ++i) {
            const Keyframe &a = p->keyframes()[i], &b = q->keyframes()[i];
            EXPECT_EQ(a.time, b.time);
            for (int d = 0; d < 3; ++d) EXPECT_EQ(a.position[d], b.position[d]);
            EXPECT_NEAR(a.yaw, b.yaw, 1e-12);
            EXPECT_NEAR(a.pitch, b.pitch, 1e-12);
        }
        for (double t = 0; t <= p->duration(); t += 0.37) {
            const Camera ca = p->at(t), cb = q->at(t);
            for (int d = 0; d < 3; ++d) EXPECT_NEAR(ca.position[d], cb.position[d], 1e-6);
        }
    }
    // And through a file.
    tessera::test::ScratchDir dir;
    auto p = CameraPath::parse(kExample, "example");
    ASSERT_TRUE(p.ok());
    const std::string text = p->to_text();
    tessera::test::write_file(dir.file("a.path"), std::vector<std::uint8_t>(text.begin(), text.end()));
    auto loaded = CameraPath::load(dir.file("a.path"));
    ASSERT_TRUE(loaded.ok()) << loaded.error().message;
    EXPECT_EQ(loaded->keyframes().size(), 3u);
    auto missing = CameraPath::load(dir.file("nosuch.path"));
    ASSERT_FALSE(missing.ok());
    EXPECT_NE(missing.error().message.find("nosuch.path"), std::string::npos);
}

TEST(Path, ErrorsNameTheFileAndLine) {
    // Non-increasing time on line 3.
    std::string e = error_of("0 0 0 10 0 0\n1 0 0 10 0 0\n1 5 5 10 0 0\n");
    EXPECT_NE(e.find("test.path:3:"), std::string::npos) << e;
    EXPECT_NE(e.find("does not increase"), std::string::npos) << e;
    e = error_of("0 0 0 10 0 0\n\n# c\n-1 0 0 10 0 0\n");
    EXPECT_NE(e.find("test.path:4:"), std::string::npos) << e;
    // Too few keyframes.
    e = error_of("# only one\n0 0 0 10 0 0\n");
    EXPECT_NE(e.find("test.path:"), std::string::npos) << e;
    EXPECT_NE(e.find("at least two"), std::string::npos) << e;
    e = error_of("");
    EXPECT_NE(e.find("at least two"), std::string::npos) << e;
    // Bad numbers.
    e = error_of("0 0 0 10 0 0\n1 0 abc 10 0 0\n");
    EXPECT_NE(e.find("test.path:2:"), std::string::npos) << e;
    EXPECT_NE(e.find("'abc' is not a number"), std::string::npos) << e;
    e = error_of("0 0 0 10 0 0\n1.5x 0 0 10 0 0\n");
    EXPECT_NE(e.find("test.path:2:"), std::string::npos) << e;
    e = error_of("0 0 0 10 0 0\n1 0 0 inf 0 0\n");
    EXPECT_NE(e.find("test.path:2:"), std::string::npos) << e;
    e = error_of("0 0 0 10 0 0\n1 0 0 10 0\n");  // five numbers
    EXPECT_NE(e.find("test.path:2:"), std::string::npos) << e;
    EXPECT_NE(e.find("6 numbers"), std::string::npos) << e;
    e = error_of("0 0 0 10 0 0\n1 0 0 10 0 91\n");  // pitch beyond 90 degrees
    EXPECT_NE(e.find("test.path:2:"), std::string::npos) << e;
    // Unknown directive.
    e = error_of("fov 60\nspeed 3\n0 0 0 10 0 0\n1 0 0 10 0 0\n");
    EXPECT_NE(e.find("test.path:2:"), std::string::npos) << e;
    EXPECT_NE(e.find("unknown directive 'speed'"), std::string::npos) << e;
    // fov out of range, or twice.
    EXPECT_NE(error_of("fov 180\n0 0 0 10 0 0\n1 0 0 10 0 0\n").find("test.path:1:"), std::string::npos);
    EXPECT_NE(error_of("fov 50\nfov 60\n0 0 0 10 0 0\n1 0 0 10 0 0\n").find("test.path:2:"), std::string::npos);
    // Windows line ends are fine.
    EXPECT_TRUE(CameraPath::parse("fov 45\r\n0 0 0 10 0 0\r\n1 0 0 10 0 0\r\n", "crlf").ok());
    // from_keyframes checks the same rules.
    EXPECT_FALSE(CameraPath::from_keyframes({Keyframe{}}, 1.0).ok());
    EXPECT_FALSE(CameraPath::from_keyframes({Keyframe{1.0}, Keyframe{1.0}}, 1.0).ok());
    EXPECT_FALSE(CameraPath::from_keyframes({Keyframe{0.0}, Keyframe{1.0}}, 0.0).ok());
}

TEST(Path, InterpolationIsLinearForTwoKeysAndTakesTheShortArc) {
    Keyframe a, b;
    a.time = 0;
    a.position = {0, 0, 10};
    a.yaw = 170 * kDeg;
    b.time = 2;
    b.position = {100, -50, 30};
    b.yaw = -170 * kDeg;
    b.pitch = -0.5;
    auto p = CameraPath::from_keyframes({a, b}, 1.0);
    ASSERT_TRUE(p.ok());
    const Camera m = p->at(1.0);
    EXPECT_NEAR(m.position[0], 50, 1e-9);
    EXPECT_NEAR(m.position[1], -25, 1e-9);
    EXPECT_NEAR(m.position[2], 20, 1e-9);
    EXPECT_NEAR(m.pitch, -0.25, 1e-12);
    // 170 -> -170 degrees passes through 180, not through 0.
    EXPECT_NEAR(std::abs(std::remainder(m.yaw, 2 * kPi)), kPi, 1e-9);
    EXPECT_EQ(p->builtin_names().size(), 6u);
}

// Samples a path at `hz`; checks bounds, height and continuity, and returns the cameras.
std::vector<Camera> walk_through(const CameraPath& p, const Scene& s, double hz, double ground) {
    std::vector<Camera> cams;
    for (int i = 0;; ++i) {
        const double t = std::min(p.duration(), i / hz);
        cams.push_back(p.at(t));
        if (t >= p.duration()) break;
    }
    const double size = std::max(s.bounds_max[0] - s.bounds_min[0], s.bounds_max[1] - s.bounds_min[1]);
    std::vector<double> steps;
    for (std::size_t i = 0; i < cams.size(); ++i) {
        const Camera& c = cams[i];
        EXPECT_GE(c.position[0], s.bounds_min[0]);
        EXPECT_LE(c.position[0], s.bounds_max[0]);
        EXPECT_GE(c.position[1], s.bounds_min[1]);
        EXPECT_LE(c.position[1], s.bounds_max[1]);
        EXPECT_GT(c.position[2], ground);
        EXPECT_GE(c.pitch, -kPi / 2);
        EXPECT_LE(c.pitch, kPi / 2);
        EXPECT_LT(c.near_plane, c.position[2] - ground);
        if (i > 0) {
            const Camera& b = cams[i - 1];
            steps.push_back(std::hypot(c.position[0] - b.position[0], c.position[1] - b.position[1], c.position[2] - b.position[2]));
            // No orientation jumps: even the whip turns 180 degrees over a quarter of a second.
            EXPECT_LT(std::abs(std::remainder(c.yaw - b.yaw, 2 * kPi)), 0.3 * 60 / hz) << "at t=" << i / hz;
            EXPECT_LT(std::abs(c.pitch - b.pitch), 0.1) << "at t=" << i / hz;
        }
    }
    // No position jumps: each step is in line with its neighbours (the speed changes smoothly).
    for (std::size_t i = 1; i + 1 < steps.size(); ++i)
        EXPECT_LE(steps[i], 2.0 * std::max(steps[i - 1], steps[i + 1]) + 1e-6 * size) << "at step " << i;
    return cams;
}

TEST(Path, BuiltinsOnATerrain) {
    const Scene s = terrain_scene(16384, 16384);
    // flyover: low (a few hundred units), turning, about 20 s.
    auto fly = CameraPath::builtin("flyover", s);
    ASSERT_TRUE(fly.ok()) << fly.error().message;
    EXPECT_NEAR(fly->duration(), 20, 5);
    double yaw_lo = 1e9, yaw_hi = -1e9;
    for (const Camera& c : walk_through(*fly, s, 60, 0)) {
        EXPECT_GT(c.position[2], 100);
        EXPECT_LT(c.position[2], 1000);
        EXPECT_LT(c.pitch, 0);
        yaw_lo = std::min(yaw_lo, c.yaw);
        yaw_hi = std::max(yaw_hi, c.yaw);
    }
    EXPECT_GT(yaw_hi - yaw_lo, 1.0);  // it turns
    // dive: from the whole texture in view down to a few units above the ground.
    auto dive = CameraPath::builtin("dive", s);
    ASSERT_TRUE(dive.ok());
    const auto dcams = walk_through(*dive, s, 60, 0);
    const Camera first = dcams.front(), last = dcams.back();
    for (const Vec3d corner : {Vec3d{0, 0, 0}, Vec3d{16384, 0, 0}, Vec3d{0, 16384, 0}, Vec3d{16384, 16384, 0}}) {
        const auto clip = world_to_clip(first, 16.0 / 9.0, corner);
        ASSERT_GT(clip[3], 0);
        EXPECT_LE(std::abs(clip[0] / clip[3]), 1.0);
        EXPECT_LE(std::abs(clip[1] / clip[3]), 1.0);
        EXPECT_LE(clip[2] / clip[3], 1.0);  // inside the far plane
    }
    EXPECT_LT(last.position[2], 10);
    EXPECT_GT(last.position[2], 1);
    // whip: low, with 180-degree turns within a third of a second.
    auto whip = CameraPath::builtin("whip", s);
    ASSERT_TRUE(whip.ok());
    const auto wcams = walk_through(*whip, s, 60, 0);
    int fast_turns = 0;
    std::size_t last_turn = 0;
    for (std::size_t i = 20; i < wcams.size(); ++i) {  // yaw turned over the last third of a second
        double turned = 0;
        for (std::size_t k = i - 20; k < i; ++k) turned += std::remainder(wcams[k + 1].yaw - wcams[k].yaw, 2 * kPi);
        if (std::abs(turned) > 0.9 * kPi && (fast_turns == 0 || i > last_turn + 40)) {
            ++fast_turns;
            last_turn = i;
        }
    }
    EXPECT_GE(fast_turns, 4);
    for (const Camera& c : wcams) EXPECT_LT(c.position[2], 500);
    // walk works on any scene: eye height above the floor.
    auto walk = CameraPath::builtin("walk", s);
    ASSERT_TRUE(walk.ok());
    for (const Camera& c : walk_through(*walk, s, 30, 0)) EXPECT_NEAR(c.position[2], 1.7, 1e-9);
    // auto is the flyover on the terrain.
    auto automatic = CameraPath::builtin("auto", s);
    ASSERT_TRUE(automatic.ok());
    auto flyover = CameraPath::builtin("flyover", s);
    ASSERT_TRUE(flyover.ok());
    EXPECT_EQ(automatic->to_text(), flyover->to_text());
    // Unknown name.
    auto bad = CameraPath::builtin("spiral", s);
    ASSERT_FALSE(bad.ok());
    EXPECT_NE(bad.error().message.find("flyover"), std::string::npos);
    // An empty scene has no bounds to build from.
    EXPECT_FALSE(CameraPath::builtin("flyover", Scene{}).ok());
}

TEST(Path, WalkThroughARoom) {
    Scene room;  // the gallery: 20 x 12, walls 4 high (Z up)
    room.name = "atlas";
    room.bounds_min[0] = -10;
    room.bounds_min[1] = -6;
    room.bounds_max[0] = 10;
    room.bounds_max[1] = 6;
    room.bounds_max[2] = 4;
    auto walk = CameraPath::builtin("walk", room);
    ASSERT_TRUE(walk.ok());
    EXPECT_GE(walk->duration(), 20);
    for (const Camera& c : walk_through(*walk, room, 30, 0)) {
        EXPECT_NEAR(c.position[2], 1.7, 1e-9);
        // Inside the walls with room to spare, and around the middle (where the boxes stand).
        EXPECT_LT(std::abs(c.position[0]), 8.0);
        EXPECT_LT(std::abs(c.position[1]), 4.8);
        EXPECT_GT(std::hypot(c.position[0] / 6.0, c.position[1] / 3.6), 0.9);
    }
}

TEST(Path, DiveNeedsEveryLevel) {
    // A 16384^2 texture of 248-texel pages has 8 levels; the dive must want each at some point.
    const Scene s = terrain_scene(16384, 16384);
    auto dive = CameraPath::builtin("dive", s);
    ASSERT_TRUE(dive.ok());
    const VtGeometry vt{16384, 16384, 248, 8};
    CpuFeedbackParams params;
    params.main_width = 1280;
    params.main_height = 720;
    params.fb_width = 160;
    params.fb_height = 90;
    std::vector<tessera::FeedbackId> fb;
    std::set<int> levels;
    for (double t = 0; t <= dive->duration(); t += 0.25) {
        cpu_feedback(dive->at(t), vt, params, fb);
        for (auto id : fb)
            if (id != tessera::kNoPage) levels.insert(tessera::unpack_feedback(id).level);
    }
    EXPECT_EQ(levels.size(), 8u);
    EXPECT_EQ(*levels.begin(), 0);
    EXPECT_EQ(*levels.rbegin(), 7);
}

}  // namespace

// orbit (auto's choice for any scene but the terrain): starts where the box's larger side spans the
// view's width, always looks at its centre, comes in to 40% of that distance.
TEST(Path, OrbitFramesAnObjScene) {
    Scene s;
    s.name = "atlas";
    s.bounds_min[0] = -70, s.bounds_min[1] = -55, s.bounds_min[2] = -6;
    s.bounds_max[0] = 75, s.bounds_max[1] = 86, s.bounds_max[2] = 18;
    auto automatic = CameraPath::builtin("auto", s);
    auto orbit = CameraPath::builtin("orbit", s);
    ASSERT_TRUE(automatic.ok() && orbit.ok());
    EXPECT_EQ(automatic->to_text(), orbit->to_text());
    const double cx = 2.5, cy = 15.5, cz = 6;
    double nearest = 1e30, first = 0;
    for (double t = 0; t <= orbit->duration(); t += 0.1) {
        const Camera c = orbit->at(t);
        const double dx = cx - c.position[0], dy = cy - c.position[1], dz = cz - c.position[2];
        const double d = std::sqrt(dx * dx + dy * dy + dz * dz);
        nearest = std::min(nearest, d);
        // Looking at the centre: the view direction is the direction to it.
        const double vx = std::cos(c.pitch) * std::cos(c.yaw), vy = std::cos(c.pitch) * std::sin(c.yaw), vz = std::sin(c.pitch);
        EXPECT_NEAR((vx * dx + vy * dy + vz * dz) / d, 1.0, 1e-3) << "t " << t;
        if (t == 0) {
            first = d;
            // The larger side (145) spans the width at 16:9: half of it over the half-width angle's tangent.
            const double half_width = std::atan(std::tan(c.fov_y / 2) * 16.0 / 9.0);
            EXPECT_NEAR(d, 72.5 / std::tan(half_width) + 12.0, 1e-6);
        }
    }
    EXPECT_NEAR(nearest, 0.4 * first, 0.01 * first);
}

namespace {

// A site: a square ground of side `size` with five boxes on it, placed at `origin` (its ground's
// corner). Triangles in world coordinates, for the coverage ray caster below.
struct Site {
    Scene scene;
    std::vector<std::array<Vec3d, 3>> triangles;
};

Site make_site(double size, const Vec3d& origin) {
    Site s;
    auto quad = [&](const Vec3d& a, const Vec3d& b, const Vec3d& c, const Vec3d& d) {
        s.triangles.push_back({a, b, c});
        s.triangles.push_back({a, c, d});
    };
    auto at = [&](double x, double y, double z) { return Vec3d{origin[0] + x * size, origin[1] + y * size, origin[2] + z * size}; };
    quad(at(0, 0, 0), at(1, 0, 0), at(1, 1, 0), at(0, 1, 0));
    const double boxes[5][4] = {{0.1, 0.1, 0.15, 0.2}, {0.6, 0.2, 0.1, 0.3}, {0.3, 0.6, 0.2, 0.1}, {0.75, 0.7, 0.12, 0.15}, {0.45, 0.4, 0.08, 0.25}};
    for (const auto& b : boxes) {
        const double x0 = b[0], y0 = b[1], x1 = b[0] + b[2], y1 = b[1] + b[2], h = b[3];
        quad(at(x0, y0, h), at(x1, y0, h), at(x1, y1, h), at(x0, y1, h));
        quad(at(x0, y0, 0), at(x1, y0, 0), at(x1, y0, h), at(x0, y0, h));
        quad(at(x1, y0, 0), at(x1, y1, 0), at(x1, y1, h), at(x1, y0, h));
        quad(at(x1, y1, 0), at(x0, y1, 0), at(x0, y1, h), at(x1, y1, h));
        quad(at(x0, y1, 0), at(x0, y0, 0), at(x0, y0, h), at(x0, y1, h));
    }
    s.scene.name = "atlas";
    for (int k = 0; k < 3; ++k) {
        s.scene.bounds_min[k] = origin[k];
        s.scene.bounds_max[k] = origin[k] + (k < 2 ? size : 0.3 * size);
    }
    return s;
}

// Fraction of a 64x36 grid of rays from the camera (16:9) that hit the site.
double coverage(const Camera& c, const Site& s) {
    const Vec3d f = c.forward();
    Vec3d r{f[1], -f[0], 0};  // right: horizontal, perpendicular to the view
    const double rl = std::hypot(r[0], r[1]);
    r = rl > 1e-9 ? Vec3d{r[0] / rl, r[1] / rl, 0} : Vec3d{1, 0, 0};
    const Vec3d u{r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]};
    const double ty = std::tan(c.fov_y / 2), tx = ty * 16.0 / 9.0;
    int hits = 0, total = 0;
    for (int j = 0; j < 36; ++j)
        for (int i = 0; i < 64; ++i) {
            const double x = ((i + 0.5) / 64 * 2 - 1) * tx, y = (1 - (j + 0.5) / 36 * 2) * ty;
            const Vec3d d{f[0] + x * r[0] + y * u[0], f[1] + x * r[1] + y * u[1], f[2] + x * r[2] + y * u[2]};
            ++total;
            for (const auto& t : s.triangles) {  // Moller-Trumbore, in camera-relative coordinates
                Vec3d p0, e1, e2;
                for (int k = 0; k < 3; ++k) {
                    p0[k] = t[0][k] - c.position[k];
                    e1[k] = t[1][k] - t[0][k];
                    e2[k] = t[2][k] - t[0][k];
                }
                const Vec3d pv{d[1] * e2[2] - d[2] * e2[1], d[2] * e2[0] - d[0] * e2[2], d[0] * e2[1] - d[1] * e2[0]};
                const double det = e1[0] * pv[0] + e1[1] * pv[1] + e1[2] * pv[2];
                if (std::abs(det) < 1e-30) continue;
                const Vec3d tv{-p0[0], -p0[1], -p0[2]};
                const double uu = (tv[0] * pv[0] + tv[1] * pv[1] + tv[2] * pv[2]) / det;
                if (uu < 0 || uu > 1) continue;
                const Vec3d qv{tv[1] * e1[2] - tv[2] * e1[1], tv[2] * e1[0] - tv[0] * e1[2], tv[0] * e1[1] - tv[1] * e1[0]};
                const double vv = (d[0] * qv[0] + d[1] * qv[1] + d[2] * qv[2]) / det;
                if (vv < 0 || uu + vv > 1) continue;
                if ((e2[0] * qv[0] + e2[1] * qv[1] + e2[2] * qv[2]) / det > 0) {
                    ++hits;
                    break;
                }
            }
        }
    return double(hits) / total;
}

}  // namespace

// Any scene, of any size and anywhere: every built-in path keeps at least half of the frame on
// the scene in at least 90% of its frames (sampled at 10 Hz).
TEST(Path, BuiltinsKeepAnObjSceneInView) {
    for (double size : {1.0, 100.0, 1e5}) {
        const Site site = make_site(size, {3.7e5, -2.2e5, 40.0});
        for (const std::string name : {"auto", "flyover", "dive", "whip", "walk", "orbit"}) {
            auto p = CameraPath::builtin(name, site.scene);
            ASSERT_TRUE(p.ok()) << name;
            int frames = 0, framed = 0;
            double worst = 1;
            for (double t = 0; t <= p->duration(); t += 0.1) {
                const double cov = coverage(p->at(t), site);
                ++frames;
                framed += cov >= 0.5;
                worst = std::min(worst, cov);
            }
            std::printf("%-8s site %-6g: %3d of %3d frames at least half on the scene, worst %.2f\n", name.c_str(), size, framed,
                        frames, worst);
            EXPECT_GE(double(framed) / frames, 0.9) << name << " on a site of " << size << ": " << framed << " of " << frames
                                                    << " frames at least half on the scene (worst " << worst << ")";
        }
    }
}

// The orbit around a compact object (a unit cube: glTF samples are often one) stays outside it,
// a quarter beyond its surface along the line of sight at least; it used to pass through it.
TEST(Path, OrbitStaysOutsideACompactObject) {
    tessera::scene::Scene cube;
    cube.name = "atlas";
    cube.vt_width = cube.vt_height = 256;
    for (int k = 0; k < 3; ++k) {
        cube.bounds_min[k] = -0.5;
        cube.bounds_max[k] = 0.5;
    }
    auto p = CameraPath::builtin("orbit", cube);
    ASSERT_TRUE(p.ok()) << p.error().message;
    double nearest = INFINITY;
    for (double t = 0; t <= p->duration(); t += 0.05) {
        const auto c = p->at(t);
        nearest = std::min(nearest, std::max({std::abs(c.position[0]), std::abs(c.position[1]), std::abs(c.position[2])}));
    }
    EXPECT_GT(nearest, 0.6) << "the camera comes within " << nearest << " of the cube's centre (its faces are at 0.5)";
}

// An upright panel (a painting, a facade, a glTF scene of quads standing in a Y-up file) is flat in
// one horizontal axis: the orbit still frames it, from in front of it and behind; the paths over a
// site's ground, which need an area, refuse it by name.
TEST(Path, OrbitFramesAnUprightPanel) {
    tessera::scene::Scene panel;
    panel.name = "atlas";
    panel.vt_width = panel.vt_height = 256;
    panel.bounds_min[0] = 0, panel.bounds_max[0] = 12;
    panel.bounds_min[1] = panel.bounds_max[1] = 0;  // no depth
    panel.bounds_min[2] = 0, panel.bounds_max[2] = 7;
    auto p = CameraPath::builtin("auto", panel);
    ASSERT_TRUE(p.ok()) << p.error().message;
    bool front = false, back = false;
    for (double t = 0; t <= p->duration(); t += 0.5) {
        const auto c = p->at(t);
        for (int k = 0; k < 3; ++k) ASSERT_TRUE(std::isfinite(c.position[k]));
        front |= c.position[1] < -1;
        back |= c.position[1] > 1;
        // Looking at the panel's centre (6, 0, 3.5): its forward vector points there.
        const double to[3] = {6 - c.position[0], 0 - c.position[1], 3.5 - c.position[2]};
        const double len = std::sqrt(to[0] * to[0] + to[1] * to[1] + to[2] * to[2]);
        const auto f = c.forward();
        EXPECT_GT((f[0] * to[0] + f[1] * to[1] + f[2] * to[2]) / len, 0.99) << "at t = " << t;
    }
    EXPECT_TRUE(front && back);
    const auto flyover = CameraPath::builtin("flyover", panel);
    ASSERT_FALSE(flyover.ok());
    EXPECT_NE(flyover.error().message.find("empty extent"), std::string::npos) << flyover.error().message;
}
