#pragma once
// Camera paths: keyframes in time, interpolated (Catmull-Rom for position, shortest-arc linear
// for yaw and pitch). A path file is text (docs/paths.md):
//
//     # tessera camera path v1          <- comments start with '#'; blank lines are ignored
//     fov 60                            <- optional: vertical field of view, degrees (default 60)
//     # time_s   x        y        z       yaw_deg  pitch_deg
//     0.0        1000     2000     150     45       -20
//     2.5        1800     2400     120     60       -15
//
// Times strictly increase; at least two keyframes. Errors name the file, line and what is wrong.
// Built-in paths are made for a scene's bounds: flyover (low, turning), dive (an orbit that spirals
// down to the ground through every level), whip (fast 180-degree turns: cache stress), walk (eye
// height through an atlas scene), orbit (around the scene looking at it, from framing the whole
// box to close up); auto is flyover for the terrain and orbit for any other scene.
#include <string>
#include <string_view>
#include <vector>

#include "tessera/result.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/scene/scene.hpp"

namespace tessera::scene {

struct Keyframe {
    double time = 0;  // seconds
    Vec3d position{0, 0, 0};
    double yaw = 0, pitch = 0;  // radians
};

class CameraPath {
public:
    static Result<CameraPath> from_keyframes(std::vector<Keyframe> keys, double fov_y);
    static Result<CameraPath> load(const std::string& file);
    static Result<CameraPath> parse(std::string_view text, const std::string& name_for_errors);
    // "auto", "flyover", "dive", "whip", "walk", "orbit" for `scene` (its bounds); error for an unknown name.
    static Result<CameraPath> builtin(const std::string& name, const Scene& scene);
    static std::vector<std::string> builtin_names();
    // What a --path option names (`tessera view`, `bench`, `demo`, `loadtest`): a built-in path
    // (builtin_names()) for `scene`, else a path file (load); error when it is neither.
    static Result<CameraPath> builtin_or_file(const std::string& name_or_file, const Scene& scene);

    double duration() const;            // last keyframe time
    Camera at(double time) const;       // clamped to [0, duration]
    std::string to_text() const;        // the file format above (round-trips through parse)
    const std::vector<Keyframe>& keyframes() const { return keys_; }

    double fov_y() const { return fov_y_; }

private:
    std::vector<Keyframe> keys_;
    double fov_y_ = 1.0471975511965976;
    double far_ = 1.0e7;  // far plane of at(): covers the keyframes' reach (and the scene, for built-ins)
};

}  // namespace tessera::scene
