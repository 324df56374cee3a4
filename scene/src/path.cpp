// Camera paths: keyframes, their text format (docs/paths.md), interpolation and the built-ins.
#include "tessera/scene/path.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <numbers>
#include <sstream>

namespace tessera::scene {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180.0;

std::string fmt_double(double v) {
    char buf[40];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    return buf;
}

bool parse_number(std::string_view s, double& out) {
    if (!s.empty() && s.front() == '+') s.remove_prefix(1);
    if (s.empty()) return false;
    auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
    return ec == std::errc() && p == s.data() + s.size();
}

std::vector<std::string_view> split_ws(std::string_view line) {
    std::vector<std::string_view> out;
    std::size_t i = 0;
    while (i < line.size()) {
        while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
        std::size_t j = i;
        while (j < line.size() && line[j] != ' ' && line[j] != '\t') ++j;
        if (j > i) out.push_back(line.substr(i, j - i));
        i = j;
    }
    return out;
}

// Interpolation between keyframes: Catmull-Rom (as a cubic Hermite spline whose tangents are the
// central differences over time, so unevenly spaced keys keep a continuous velocity).
Vec3d tangent(const std::vector<Keyframe>& k, std::size_t i) {
    const std::size_t a = i == 0 ? 0 : i - 1, b = std::min(i + 1, k.size() - 1);
    const double dt = k[b].time - k[a].time;
    Vec3d m{};
    for (int d = 0; d < 3; ++d) m[d] = (k[b].position[d] - k[a].position[d]) / dt;
    return m;
}

// The scene's box, checked.
struct Box {
    double x0, y0, z0, x1, y1, z1;
    double wx() const { return x1 - x0; }
    double wy() const { return y1 - y0; }
    double cx() const { return 0.5 * (x0 + x1); }
    double cy() const { return 0.5 * (y0 + y1); }
    double size() const { return std::max(wx(), wy()); }
    double diagonal() const { return std::sqrt(wx() * wx() + wy() * wy() + (z1 - z0) * (z1 - z0)); }
};

// Samples an analytic camera motion every `dt` seconds over [0, duration] (and at the end).
using Motion = std::function<Keyframe(double t)>;
std::vector<Keyframe> sample(const Motion& m, double duration, double dt) {
    std::vector<Keyframe> keys;
    const int n = static_cast<int>(std::ceil(duration / dt - 1e-9));
    for (int i = 0; i <= n; ++i) {
        const double t = std::min(duration, i * dt);
        Keyframe k = m(t);
        k.time = t;
        keys.push_back(k);
    }
    return keys;
}

// Heading of a motion's velocity at t (central difference of the position).
double heading(const std::function<Vec3d(double)>& pos, double t) {
    const double e = 1e-3;
    const Vec3d a = pos(t - e), b = pos(t + e);
    return std::atan2(b[1] - a[1], b[0] - a[0]);
}

// Unwraps `yaw` to within pi of `previous`, so consecutive keys never take the long way round.
double unwrap(double yaw, double previous) { return previous + std::remainder(yaw - previous, 2 * kPi); }

// A finite scene (an OBJ site or object, not the endless-looking terrain) ends at its box: a path
// that looks along its way or at the horizon from inside the box sees mostly what lies beyond. So
// over a finite scene the paths look down more steeply and towards the centre.
struct Framing {
    bool finite = false;
};

// flyover: low over the ground (2% of the scene's size above its top), weaving along three tenths
// of a turn around the centre, looking ahead and a little around, for 20 seconds. Over a finite
// scene it looks 45 degrees inwards of its way and 45 degrees down.
std::vector<Keyframe> flyover(const Box& b, Framing framing) {
    const double T = 20.0, S = b.size();
    auto pos = [&b, S, T](double t) -> Vec3d {
        const double theta = -0.6 * kPi + (t / T) * 0.6 * kPi;
        const double r = 1.0 + 0.18 * std::sin(2 * kPi * 2.0 * t / T);
        const double h = b.z1 + 0.02 * S * (1.0 + 0.25 * std::sin(2 * kPi * 1.5 * t / T));
        return {b.cx() + 0.28 * b.wx() * r * std::cos(theta), b.cy() + 0.28 * b.wy() * r * std::sin(theta), h};
    };
    double prev = 0;
    auto keys = sample(
        [&](double t) {
            Keyframe k;
            k.position = pos(t);
            const double inward = framing.finite ? 0.25 * kPi : 0.0;  // the centre lies a quarter turn to the left
            k.yaw = unwrap(heading(pos, t) + inward + 0.35 * std::sin(2 * kPi * 1.3 * t / T), prev);
            prev = k.yaw;
            k.pitch = (framing.finite ? -0.8 : -0.3) + 0.08 * std::sin(2 * kPi * 0.9 * t / T);
            return k;
        },
        T, 0.5);
    return keys;
}

// dive: from straight above, so high that the whole texture covers a sixteenth of the view's height
// (its last level, one page, is what a view that far wants), an orbit that spirals down to a few
// units above the ground (the height falls exponentially, so every level of the texture is the
// wanted one for a while), tilting from straight down to 35 degrees below the horizon; 27 s of
// descent, then 3 s of orbit at the bottom.
std::vector<Keyframe> dive(const Box& b, double fov_y, Framing framing) {
    const double Td = 27.0, T = 30.0, S = b.size();
    // Above the ground; over a finite scene from where it fills the view instead (its few levels
    // are all wanted on the way down anyway).
    const double top = (framing.finite ? 0.5 : 16.0) * (0.5 * S) / std::tan(fov_y / 2.0);
    const double bottom = std::min(4.0, 0.002 * S);
    const double ratio = bottom / top;
    auto keys = sample(
        [&](double t) {
            const double u = std::min(t / Td, 1.0);
            const double s = 1.0 - (1.0 - u) * (1.0 - u);  // eases out: no kink where the descent ends
            const double above = top * std::pow(ratio, s);
            const double pitch = -0.5 * kPi + 55.0 * kDeg * s;
            const double yaw = 0.3 + 3.0 * kPi * t / Td;  // a turn and a half during the descent, on after
            const double rho = pitch <= -0.5 * kPi ? 0.0 : above / std::tan(-pitch);  // looks at the centre
            Keyframe k;
            k.position = {b.cx() - rho * std::cos(yaw), b.cy() - rho * std::sin(yaw), b.z1 + above};
            k.yaw = yaw;
            k.pitch = pitch;
            return k;
        },
        T, 0.25);
    return keys;
}

// whip: low (1% of the size above the top), drifting across the centre, turning 180 degrees in a
// quarter of a second every 1.5 s, always the same way: the view swaps wholesale (cache stress).
std::vector<Keyframe> whip(const Box& b, Framing framing) {
    const double T = 12.0, S = b.size(), hold = 1.25, turn = 0.25;
    auto pos = [&b, S, T](double t) -> Vec3d {
        return {b.cx() + b.wx() * (-0.15 + 0.3 * t / T), b.cy() + b.wy() * 0.05 * std::sin(2 * kPi * t / T), b.z1 + 0.01 * S};
    };
    std::vector<Keyframe> keys;
    double yaw = 0.25 * kPi;
    auto add = [&](double t) {
        Keyframe k;
        k.time = t;
        k.position = pos(t);
        k.yaw = yaw;
        k.pitch = (framing.finite ? -45.0 : -20.0) * kDeg;
        keys.push_back(k);
    };
    double t = 0;
    while (t + hold + turn <= T + 1e-9) {
        for (int i = 0; i < 5; ++i) add(t + hold * i / 5.0);  // hold
        for (int i = 0; i < 3; ++i) {                          // turn in three 60-degree steps
            add(t + hold + turn * i / 3.0);
            yaw += kPi / 3.0;
        }
        t += hold + turn;
    }
    add(t);
    if (t < T) {
        t = T;
        add(t);
    }
    return keys;
}

// walk: eye height (1.7 units, or 35% of the scene's height if that is more) above the scene's
// floor, an ellipse around the centre (30% of the extent, at most 40 eye heights), looking about;
// 40 seconds.
std::vector<Keyframe> walk(const Box& b, Framing framing) {
    const double T = 40.0;
    // 1.7 units (or 35% of the height), but at most a tenth of the scene's size: a model a few
    // units across is walked at its own scale.
    const double eye = std::min(std::max(1.7, 0.35 * (b.z1 - b.z0)), 0.1 * b.size());
    const double rx = std::min(0.3 * b.wx(), 40.0 * eye), ry = std::min(0.3 * b.wy(), 40.0 * eye);
    auto pos = [&b, eye, rx, ry, T](double t) -> Vec3d {
        const double theta = -0.5 * kPi + 2 * kPi * t / T;
        return {b.cx() + rx * std::cos(theta), b.cy() + ry * std::sin(theta), b.z0 + eye};
    };
    double prev = 0;
    return sample(
        [&](double t) {
            Keyframe k;
            k.position = pos(t);
            k.yaw = unwrap(heading(pos, t) + 0.35 * std::sin(2 * kPi * t / 9.0), prev);
            prev = k.yaw;
            k.pitch = (framing.finite ? -0.32 : -0.08) + 0.05 * std::sin(2 * kPi * t / 13.0);
            return k;
        },
        T, 0.5);
}

// orbit: around the scene, looking at the centre of its box from 30 degrees above, one turn in 30
// s; it starts where the box's larger side spans the view's width and moves in to 40% of that
// distance and back out twice per turn, so both the whole scene and its detail are seen, but never
// closer than a quarter beyond where its line of sight leaves the box (a compact object, a cube,
// would otherwise be entered). The default for OBJ scenes (a site, a building, a room seen from
// outside).
std::vector<Keyframe> orbit(const Box& b, double fov_y) {
    const double T = 30.0, elevation = 35.0 * kDeg;
    const Vec3d c{b.cx(), b.cy(), 0.5 * (b.z0 + b.z1)};
    // Where the box's larger side spans a 16:9 view's width (its corners may leave the frame; a
    // flat site then fills most of it).
    const double half_width_fov = std::atan(std::tan(0.5 * fov_y) * 16.0 / 9.0);
    const double framed = std::max(0.5 * std::max(b.size(), b.z1 - b.z0) / std::tan(half_width_fov) + 0.5 * (b.z1 - b.z0), 1e-3);
    return sample(
        [&](double t) {
            const double yaw = 0.25 * kPi + 2 * kPi * t / T;  // view direction; the camera sits opposite
            // Where the line from the centre towards the camera leaves the box.
            const double u[3] = {std::abs(std::cos(elevation) * std::cos(yaw)), std::abs(std::cos(elevation) * std::sin(yaw)),
                                 std::sin(elevation)};
            const double half[3] = {0.5 * b.wx(), 0.5 * b.wy(), 0.5 * (b.z1 - b.z0)};
            double leaves = INFINITY;
            for (int k = 0; k < 3; ++k)
                if (u[k] > 1e-9) leaves = std::min(leaves, half[k] / u[k]);
            const double d = std::max(framed * (0.7 + 0.3 * std::cos(2 * kPi * 2.0 * t / T)), 1.25 * leaves);
            Keyframe k;
            k.position = {c[0] - d * std::cos(elevation) * std::cos(yaw), c[1] - d * std::cos(elevation) * std::sin(yaw),
                          c[2] + d * std::sin(elevation)};
            k.yaw = yaw;
            k.pitch = -elevation;
            return k;
        },
        T, 0.25);
}

}  // namespace

Result<CameraPath> CameraPath::from_keyframes(std::vector<Keyframe> keys, double fov_y) {
    if (keys.size() < 2)
        return make_error(Errc::invalid_argument, "a camera path needs at least two keyframes, got " + std::to_string(keys.size()));
    if (!std::isfinite(fov_y) || fov_y <= 0 || fov_y >= kPi)
        return make_error(Errc::invalid_argument, "field of view must be between 0 and 180 degrees");
    double reach = 0, lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (std::size_t i = 0; i < keys.size(); ++i) {
        const Keyframe& k = keys[i];
        if (!std::isfinite(k.time) || !std::isfinite(k.position[0]) || !std::isfinite(k.position[1]) ||
            !std::isfinite(k.position[2]) || !std::isfinite(k.yaw) || !std::isfinite(k.pitch))
            return make_error(Errc::invalid_argument, "keyframe " + std::to_string(i) + " has a value that is not finite");
        if (i > 0 && !(k.time > keys[i - 1].time))
            return make_error(Errc::invalid_argument, "keyframe " + std::to_string(i) + ": time " + fmt_double(k.time) +
                                                          " does not increase (previous " + fmt_double(keys[i - 1].time) + ")");
        if (std::abs(k.pitch) > 0.5 * kPi + 1e-12)
            return make_error(Errc::invalid_argument, "keyframe " + std::to_string(i) + ": pitch beyond 90 degrees");
        reach = std::max(reach, std::abs(k.position[2]));
        for (int d = 0; d < 2; ++d) {
            lo[d] = std::min(lo[d], k.position[d]);
            hi[d] = std::max(hi[d], k.position[d]);
        }
    }
    CameraPath p;
    p.keys_ = std::move(keys);
    p.fov_y_ = fov_y;
    p.far_ = std::max({Camera{}.far_plane, 4.0 * reach + 2.0 * (hi[0] - lo[0]) + 2.0 * (hi[1] - lo[1])});
    return p;
}

Result<CameraPath> CameraPath::parse(std::string_view text, const std::string& name) {
    std::vector<Keyframe> keys;
    double fov_deg = 60.0;
    bool fov_seen = false;
    std::size_t line_no = 0, last_line = 0;
    auto fail = [&](const std::string& what) { return make_error(Errc::invalid_argument, name + ":" + std::to_string(line_no) + ": " + what); };
    while (!text.empty()) {
        const std::size_t nl = text.find('\n');
        std::string_view line = text.substr(0, nl);
        text = nl == std::string_view::npos ? std::string_view() : text.substr(nl + 1);
        ++line_no;
        if (const std::size_t hash = line.find('#'); hash != std::string_view::npos) line = line.substr(0, hash);
        if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
        const auto tokens = split_ws(line);
        if (tokens.empty()) continue;
        last_line = line_no;
        double first = 0;
        if (tokens[0] == "fov") {
            if (fov_seen) return fail("fov given twice");
            if (tokens.size() != 2) return fail("fov takes one number (degrees)");
            if (!parse_number(tokens[1], fov_deg)) return fail("'" + std::string(tokens[1]) + "' is not a number");
            if (!(fov_deg > 0 && fov_deg < 180)) return fail("fov must be between 0 and 180 degrees, got " + std::string(tokens[1]));
            fov_seen = true;
            continue;
        }
        if (!parse_number(tokens[0], first)) {
            const char c = tokens[0][0];
            if ((c >= '0' && c <= '9') || c == '-' || c == '+' || c == '.')
                return fail("'" + std::string(tokens[0]) + "' is not a number");
            return fail("unknown directive '" + std::string(tokens[0]) + "' (expected fov or a keyframe)");
        }
        if (tokens.size() != 6)
            return fail("a keyframe is 6 numbers (time x y z yaw_deg pitch_deg), got " + std::to_string(tokens.size()));
        double v[6];
        for (std::size_t i = 0; i < 6; ++i) {
            if (!parse_number(tokens[i], v[i])) return fail("'" + std::string(tokens[i]) + "' is not a number");
            if (!std::isfinite(v[i])) return fail("'" + std::string(tokens[i]) + "' is not finite");
        }
        if (!keys.empty() && !(v[0] > keys.back().time))
            return fail("time " + std::string(tokens[0]) + " does not increase (previous keyframe at " + fmt_double(keys.back().time) + ")");
        if (std::abs(v[5]) > 90 + 1e-9) return fail("pitch " + std::string(tokens[5]) + " is beyond +-90 degrees");
        Keyframe k;
        k.time = v[0];
        k.position = {v[1], v[2], v[3]};
        k.yaw = v[4] * kDeg;
        k.pitch = std::clamp(v[5] * kDeg, -0.5 * kPi, 0.5 * kPi);
        keys.push_back(k);
    }
    if (keys.size() < 2) {
        line_no = last_line;
        return make_error(Errc::invalid_argument, name + ":" + std::to_string(line_no) + ": a camera path needs at least two keyframes, found " +
                                                      std::to_string(keys.size()));
    }
    return from_keyframes(std::move(keys), fov_deg * kDeg);
}

Result<CameraPath> CameraPath::load(const std::string& file) {
    std::ifstream f(file, std::ios::binary);
    if (!f) return make_error(Errc::not_found, "cannot open camera path '" + file + "'");
    std::ostringstream ss;
    ss << f.rdbuf();
    if (f.bad()) return make_error(Errc::io_error, "cannot read camera path '" + file + "'");
    return parse(ss.str(), file);
}

std::vector<std::string> CameraPath::builtin_names() { return {"auto", "flyover", "dive", "whip", "walk", "orbit"}; }

Result<CameraPath> CameraPath::builtin(const std::string& name, const Scene& scene) {
    const Box b{scene.bounds_min[0], scene.bounds_min[1], scene.bounds_min[2],
                scene.bounds_max[0], scene.bounds_max[1], scene.bounds_max[2]};
    for (double v : {b.x0, b.y0, b.z0, b.x1, b.y1, b.z1})
        if (!std::isfinite(v)) return make_error(Errc::invalid_argument, "scene '" + scene.name + "' has no bounds");
    // auto: the terrain's flyover; around any other scene (a finite site or object), the orbit.
    const std::string chosen = name != "auto" ? name : scene.name == "terrain" ? "flyover" : "orbit";
    // The paths over a site need its ground to have an area; the orbit only a size (an upright
    // panel, a painting or a facade, is flat in one horizontal axis).
    const bool has_extent = chosen == "orbit" ? std::max({b.wx(), b.wy(), b.z1 - b.z0}) > 0 && b.wx() >= 0 && b.wy() >= 0 && b.z1 >= b.z0
                                              : b.wx() > 0 && b.wy() > 0 && b.z1 >= b.z0;
    if (!has_extent) return make_error(Errc::invalid_argument, "scene '" + scene.name + "' has an empty extent");
    const double fov = Camera{}.fov_y;
    std::vector<Keyframe> keys;
    const Framing framing{scene.name != "terrain"};
    if (chosen == "flyover") keys = flyover(b, framing);
    else if (chosen == "dive") keys = dive(b, fov, framing);
    else if (chosen == "whip") keys = whip(b, framing);
    else if (chosen == "walk") keys = walk(b, framing);
    else if (chosen == "orbit") keys = orbit(b, fov);
    else return make_error(Errc::invalid_argument, "unknown camera path '" + name + "' (built-ins: auto, flyover, dive, whip, walk, orbit)");
    auto p = from_keyframes(std::move(keys), fov);
    if (!p) return p;
    p->far_ = std::max(p->far_, 4.0 * b.diagonal());
    return p;
}

Result<CameraPath> CameraPath::builtin_or_file(const std::string& name_or_file, const Scene& scene) {
    const auto names = builtin_names();
    if (std::find(names.begin(), names.end(), name_or_file) != names.end()) return builtin(name_or_file, scene);
    std::error_code ec;
    if (!std::filesystem::exists(name_or_file, ec)) {
        std::string known;
        for (const auto& n : names) known += (known.empty() ? "" : ", ") + n;
        return make_error(Errc::not_found, "'" + name_or_file + "' is neither a built-in camera path (" + known + ") nor a path file");
    }
    return load(name_or_file);
}

double CameraPath::duration() const { return keys_.empty() ? 0.0 : keys_.back().time; }

Camera CameraPath::at(double time) const {
    Camera c;
    c.fov_y = fov_y_;
    c.far_plane = far_;
    if (keys_.empty()) return c;
    const double t = std::isnan(time) ? keys_.front().time : std::clamp(time, keys_.front().time, keys_.back().time);
    // Segment i: [t_i, t_i+1].
    std::size_t i = static_cast<std::size_t>(
        std::upper_bound(keys_.begin(), keys_.end(), t, [](double v, const Keyframe& k) { return v < k.time; }) - keys_.begin());
    i = std::clamp<std::size_t>(i, 1, keys_.size() - 1) - 1;
    const Keyframe& a = keys_[i];
    const Keyframe& b = keys_[i + 1];
    const double h = b.time - a.time, s = (t - a.time) / h;
    const double s2 = s * s, s3 = s2 * s;
    const double h00 = 2 * s3 - 3 * s2 + 1, h10 = s3 - 2 * s2 + s, h01 = -2 * s3 + 3 * s2, h11 = s3 - s2;
    const Vec3d ma = tangent(keys_, i), mb = tangent(keys_, i + 1);
    for (int d = 0; d < 3; ++d) c.position[d] = h00 * a.position[d] + h10 * h * ma[d] + h01 * b.position[d] + h11 * h * mb[d];
    c.yaw = a.yaw + s * std::remainder(b.yaw - a.yaw, 2 * kPi);  // the shorter way round
    c.pitch = a.pitch + s * (b.pitch - a.pitch);
    // Near plane: a thousandth of the height above z = 0 (at least 0.01), so the depth range stays sane.
    c.near_plane = std::max(0.01, 1e-3 * std::abs(c.position[2]));
    return c;
}

std::string CameraPath::to_text() const {
    std::string out = "# tessera camera path v1\n";
    out += "fov " + fmt_double(fov_y_ / kDeg) + "\n";
    out += "# time_s x y z yaw_deg pitch_deg\n";
    for (const Keyframe& k : keys_) {
        out += fmt_double(k.time) + " " + fmt_double(k.position[0]) + " " + fmt_double(k.position[1]) + " " +
               fmt_double(k.position[2]) + " " + fmt_double(k.yaw / kDeg) + " " + fmt_double(k.pitch / kDeg) + "\n";
    }
    return out;
}

}  // namespace tessera::scene
