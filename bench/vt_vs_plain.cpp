// VT frame time against plain texturing of the same scene (docs/benchmarks.md, "Renderer").
//
// The peer is the reference renderer: the same terrain, camera path and filter drawn from one
// ordinary mipmapped GL texture. The VT frame is the whole VT frame: feedback pass (1/8), depth
// pre-pass where the scene needs one, and the VT pass with its fallback counters. Every page is
// resident first (a loading pass over the path with a pool that holds the whole store), so the
// comparison is of rendering, not streaming. Frames alternate VT / plain on the same camera, each
// ended with glFinish, so drift on this shared machine hits both alike. Reports wall time and
// process CPU time (rasterizer threads included) per frame. Prints a table and writes JSON.
//
//   vt_vs_plain STORE.tsr [--size 640x360] [--frames 240] [--displacement H] [--filter NAME] [--json FILE]
//
// --displacement: terrain with hills of that height (texels) instead of the flat plane, so the VT
// frame draws a heightfield where hills hide hills (front to back, so still without a depth
// pre-pass: docs/renderer.md).
// --filter: only that filter (bilinear, trilinear or anisotropic) instead of all three.
// --fade-ms: also two VT renderers with blending in (RuntimeConfig::fade_ms), drawn on the same
// camera, their pages loaded the same way: one whose pages have faded in (what blending costs a
// frame where nothing fades), and one whose clock stands still halfway through the fade of every
// page (what it costs while every pixel fades, both levels of every lookup read: the worst case).
// Reports their frame times against the VT's without blending.
//
// Besides wall and CPU time, each frame's GPU time (a GL_TIME_ELAPSED query around its draw):
// on a GPU the wall time of a small frame is mostly driver round trips, the GPU time is the
// shading work itself.
#include <epoxy/gl.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <string>
#include <ctime>
#include <vector>

#include "tessera/client/gl/context.hpp"
#include "tessera/client/gl/frame_loop.hpp"
#include "tessera/client/gl/reference_renderer.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "tessera/client/measures.hpp"
#include "tessera/client/runtime.hpp"
#include "tessera/client/tile_source.hpp"
#include "tessera/scene/path.hpp"
#include "tessera/scene/scene.hpp"

namespace {

using namespace tessera;
using Clock = std::chrono::steady_clock;

// CPU time of the whole process (llvmpipe's rasterizer threads included), in ms: a software
// renderer's cost per frame that other jobs on a shared machine disturb far less than wall time.
double cpu_ms() {
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return double(ts.tv_sec) * 1e3 + double(ts.tv_nsec) * 1e-6;
}

// GPU time of the commands issued between begin() and end_ms() (GL_TIME_ELAPSED), waited for.
class GpuTimer {
  public:
    GpuTimer() { glGenQueries(1, &query_); }
    ~GpuTimer() { glDeleteQueries(1, &query_); }
    GpuTimer(const GpuTimer&) = delete;
    GpuTimer& operator=(const GpuTimer&) = delete;
    void begin() { glBeginQuery(GL_TIME_ELAPSED, query_); }
    double end_ms() {
        glEndQuery(GL_TIME_ELAPSED);
        GLuint64 ns = 0;
        glGetQueryObjectui64v(query_, GL_QUERY_RESULT, &ns);
        return double(ns) * 1e-6;
    }

  private:
    GLuint query_ = 0;
};

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.empty() ? 0 : v[v.size() / 2];
}
double mean(const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x;
    return v.empty() ? 0 : s / double(v.size());
}

int fail(const std::string& what) {
    std::fprintf(stderr, "vt_vs_plain: %s\n", what.c_str());
    return 1;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 2)
        return fail("usage: vt_vs_plain STORE.tsr [--size WxH] [--frames N] [--displacement H] [--filter NAME] [--fade-ms MS] "
                    "[--json FILE]");
    std::string store = argv[1], json, only;
    unsigned w = 640, h = 360, frames = 240;
    double displacement = 0;
    float fade_ms = 0;
    for (int i = 2; i + 1 < argc; i += 2) {
        if (!std::strcmp(argv[i], "--size")) std::sscanf(argv[i + 1], "%ux%u", &w, &h);
        else if (!std::strcmp(argv[i], "--frames")) frames = unsigned(std::atoi(argv[i + 1]));
        else if (!std::strcmp(argv[i], "--json")) json = argv[i + 1];
        else if (!std::strcmp(argv[i], "--displacement")) displacement = std::atof(argv[i + 1]);
        else if (!std::strcmp(argv[i], "--filter")) only = argv[i + 1];
        else if (!std::strcmp(argv[i], "--fade-ms")) fade_ms = float(std::atof(argv[i + 1]));
        else return fail(std::string("unknown flag ") + argv[i]);
    }
    auto ctx = client::gl::GlContext::create_headless();
    if (!ctx) return fail(ctx.error().message);
    (*ctx)->make_current();
    auto levels = client::decode_store_levels(store);
    if (!levels) return fail(levels.error().message);

    std::string out_json = "{\"store\": \"" + store + "\", \"size\": \"" + std::to_string(w) + "x" + std::to_string(h) +
                           "\", \"displacement\": " + std::to_string(displacement) + ", \"renderer\": \"" + (*ctx)->renderer() +
                           "\", \"filters\": [";
    std::printf("VT frame vs plain texturing, %ux%u, %u frames of flyover, terrain displacement %g, %s\n", w, h, frames,
                displacement, (*ctx)->renderer().c_str());
    std::printf("%-12s %10s %10s %10s %8s %10s %10s %8s %10s %10s %8s\n", "filter", "VT mean", "VT median", "plain med.",
                "ratio", "VT CPU", "plain CPU", "ratio", "VT GPU", "plain GPU", "ratio");
    const client::gl::Filter filters[] = {client::gl::Filter::bilinear, client::gl::Filter::trilinear,
                                          client::gl::Filter::anisotropic};
    const char* names[] = {"bilinear", "trilinear", "anisotropic"};
    if (!only.empty() && only != "bilinear" && only != "trilinear" && only != "anisotropic")
        return fail("--filter must be bilinear, trilinear or anisotropic, not " + only);
    bool first = true;
    for (int fi = 0; fi < 3; ++fi) {
        if (!only.empty() && only != names[fi]) continue;
        auto source = client::make_local_store_source(2);
        auto info = source->bind(0, store);
        if (!info) return fail(info.error().message);
        std::uint32_t pages = 0;
        for (const auto& l : info->levels) pages += l.tiles_x * l.tiles_y;
        client::gl::RendererConfig rc;
        rc.width = w;
        rc.height = h;
        rc.filter = filters[fi];
        rc.pool_slots = pages + 16;  // the whole store fits: every page resident
        rc.tile_size = info->tile_size();
        rc.border = info->border;
        rc.srgb = info->colour_space == storage::ColourSpace::srgb;
        auto ref = client::gl::ReferenceRenderer::create(rc, *levels);
        if (!ref) return fail(ref.error().message);
        scene::TerrainOptions t;
        t.vt_width = info->width;
        t.vt_height = info->height;
        t.displacement = displacement;
        auto sc = scene::make_terrain(t);
        if (!sc) return fail(sc.error().message);
        if (auto st = (*ref)->set_scene(*sc); !st.ok()) return fail(st.error().message);
        auto path = scene::CameraPath::builtin("flyover", *sc);
        if (!path) return fail(path.error().message);
        const auto cam_at = [&](unsigned f) { return path->at(path->duration() * f / std::max(frames - 1, 1u)); };

        // A VT renderer with its runtime, every frame's pages resident (a loading pass).
        struct Vt {
            std::unique_ptr<client::gl::VtRenderer> renderer;
            std::unique_ptr<client::Runtime> runtime;
        };
        const auto make_vt = [&](float fade, bool frozen) -> tessera::Result<Vt> {
            auto vt = client::gl::VtRenderer::create(rc);
            if (!vt) return vt.error();
            client::RuntimeConfig cfg;
            cfg.residency.pool_slots = rc.pool_slots;
            cfg.upload_pages_per_frame = 256;
            cfg.upload_bytes_per_frame = 256u << 20;
            cfg.fade_ms = fade;
            auto rt = client::Runtime::create(cfg, **vt, &(*vt)->page_staging());
            if (!rt) return rt.error();
            auto tex = (*rt)->add_texture(*source, store);
            if (!tex) return tex.error();
            if (auto st = (*vt)->add_texture(*tex, *info); !st.ok()) return st.error();
            if (auto st = (*vt)->set_scene(*sc, *tex); !st.ok()) return st.error();
            client::gl::FrameLoop loop(**vt, **rt);
            for (unsigned f = 0; f < frames; ++f)
                for (int k = 0; k < 40; ++k) {
                    if (frozen) (*rt)->set_time(0);
                    loop.step(cam_at(f));
                    if ((*rt)->in_flight() == 0 && k > 3) break;
                }
            if (fade > 0 && !frozen) {  // every page at full weight: one frame past the longest fade
                (*rt)->set_time(1e6);
                (*rt)->frame_without_feedback();
                (*vt)->render(cam_at(frames - 1), 0);
            }
            if (frozen) {  // every page at half weight: the clock half a fade after their arrival
                (*rt)->set_time(fade / 2000.0);
                (*rt)->frame_without_feedback();
            }
            std::vector<client::gl::FrameCounters> counters;
            (*vt)->finish(&counters, nullptr);
            return Vt{std::move(*vt), std::move(*rt)};
        };
        auto plain_vt = make_vt(0, false);
        if (!plain_vt) return fail(plain_vt.error().message);
        tessera::Result<Vt> faded_vt = Vt{}, fading_vt = Vt{};
        if (fade_ms > 0) faded_vt = make_vt(fade_ms, false), fading_vt = make_vt(fade_ms, true);
        if (!faded_vt) return fail(faded_vt.error().message);
        if (!fading_vt) return fail(fading_vt.error().message);
        auto* vt = &plain_vt->renderer;
        auto* rt = &plain_vt->runtime;
        std::vector<client::gl::FrameCounters> counters;
        std::vector<double> fade_ms_frames[2], fade_cpu[2], fade_gpu[2];  // faded in, fading
        GpuTimer gpu_timer;

        std::vector<double> vt_ms, plain_ms, vt_cpu, plain_cpu, vt_gpu, plain_gpu;
        for (unsigned f = 0; f < frames; ++f) {
            const auto cam = cam_at(f);
            const double c0 = cpu_ms();
            auto t0 = Clock::now();
            gpu_timer.begin();
            (*vt)->render(cam, 0);
            vt_gpu.push_back(gpu_timer.end_ms());
            glFinish();
            auto t1 = Clock::now();
            const double c1 = cpu_ms();
            gpu_timer.begin();
            (*ref)->render(cam);
            plain_gpu.push_back(gpu_timer.end_ms());
            glFinish();
            auto t2 = Clock::now();
            const double c2 = cpu_ms();
            (*rt)->frame_without_feedback();  // keeps the readback rings moving, uploads nothing
            for (int k = 0; k < 2 && fade_ms > 0; ++k) {
                Vt& v = k == 0 ? *faded_vt : *fading_vt;
                const double c3 = cpu_ms();
                const auto t3 = Clock::now();
                gpu_timer.begin();
                v.renderer->render(cam, 0);
                fade_gpu[k].push_back(gpu_timer.end_ms());
                glFinish();
                fade_ms_frames[k].push_back(std::chrono::duration<double, std::milli>(Clock::now() - t3).count());
                fade_cpu[k].push_back(cpu_ms() - c3);
                if (k == 1) v.runtime->set_time(fade_ms / 2000.0);  // the clock stands still: every page at half weight
                v.runtime->frame_without_feedback();
                counters.clear();
                v.renderer->poll_counters(counters);
            }
            vt_ms.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
            plain_ms.push_back(std::chrono::duration<double, std::milli>(t2 - t1).count());
            vt_cpu.push_back(c1 - c0);
            plain_cpu.push_back(c2 - c1);
            counters.clear();
            (*vt)->poll_counters(counters);
        }
        const double ratio = median(vt_ms) / median(plain_ms);
        const double cpu_ratio = median(vt_cpu) / median(plain_cpu);
        const double gpu_ratio = median(vt_gpu) / std::max(median(plain_gpu), 1e-6);
        std::printf("%-12s %10.2f %10.2f %10.2f %7.2fx %10.2f %10.2f %7.2fx %10.3f %10.3f %7.2fx\n", names[fi], mean(vt_ms),
                    median(vt_ms), median(plain_ms), ratio, median(vt_cpu), median(plain_cpu), cpu_ratio, median(vt_gpu),
                    median(plain_gpu), gpu_ratio);
        std::string fade_json;
        for (int k = 0; k < 2 && fade_ms > 0; ++k) {
            const char* what = k == 0 ? "faded_in" : "all_fading";
            const double fr = median(fade_ms_frames[k]) / median(vt_ms), fc = median(fade_cpu[k]) / median(vt_cpu);
            const double fg = median(fade_gpu[k]) / std::max(median(vt_gpu), 1e-6);
            std::printf("%-12s %10.2f %10.2f %10s %7.3fx %10.2f %10s %7.3fx %10.3f %10s %7.3fx  (--fade-ms %g, %s, against the "
                        "VT without)\n",
                        k == 0 ? "  + fade" : "  + fading", mean(fade_ms_frames[k]), median(fade_ms_frames[k]), "", fr,
                        median(fade_cpu[k]), "", fc, median(fade_gpu[k]), "", fg, fade_ms,
                        k == 0 ? "every page faded in" : "every page fading");
            char fb[480];
            std::snprintf(fb, sizeof fb,
                          ", \"fade_ms\": %g, \"%s_vt_median_ms\": %.3f, \"%s_vs_vt_median\": %.4f, \"%s_vt_cpu_median_ms\": "
                          "%.3f, \"%s_vs_vt_cpu_median\": %.4f, \"%s_vt_gpu_median_ms\": %.4f, \"%s_vs_vt_gpu_median\": %.4f",
                          fade_ms, what, median(fade_ms_frames[k]), what, fr, what, median(fade_cpu[k]), what, fc, what,
                          median(fade_gpu[k]), what, fg);
            fade_json += fb;
        }
        char buf[1024];
        std::snprintf(buf, sizeof buf,
                      "%s{\"filter\": \"%s\", \"vt_mean_ms\": %.3f, \"vt_median_ms\": %.3f, \"plain_mean_ms\": %.3f, "
                      "\"plain_median_ms\": %.3f, \"ratio_median\": %.3f, \"vt_cpu_median_ms\": %.3f, "
                      "\"plain_cpu_median_ms\": %.3f, \"cpu_ratio_median\": %.3f, \"vt_gpu_median_ms\": %.4f, "
                      "\"plain_gpu_median_ms\": %.4f, \"gpu_ratio_median\": %.3f%s}",
                      first ? "" : ", ", names[fi], mean(vt_ms), median(vt_ms), mean(plain_ms), median(plain_ms), ratio,
                      median(vt_cpu), median(plain_cpu), cpu_ratio, median(vt_gpu), median(plain_gpu), gpu_ratio,
                      fade_json.c_str());
        out_json += buf;
        first = false;
    }
    out_json += "]}\n";
    if (!json.empty()) std::ofstream(json) << out_json;
    return 0;
}
