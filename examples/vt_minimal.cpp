// The smallest program that embeds Tessera's client: it opens a store on a Tessera server over
// gRPC, streams its pages into the OpenGL renderer and draws a terrain textured with it along a
// camera path, in its own frame loop. It uses the installed public headers only.
//
//   vt_minimal grpc://HOST:PORT/STORE [--frames N] [--size WxH] [--reference STORE.tsr] [--save FRAME.png]
//
// Each frame: render with the runtime's LoD bias, hand the feedback that came back to the
// runtime (which requests, decodes and uploads pages into the renderer), repeat. After the path,
// the last view is held until every page it needs is resident. Prints one JSON line: frames,
// the fallback of the last frame (pixels drawn from a coarser level than wanted) and, with
// --reference (the same store as a local file), PSNR against the reference renderer.
// Exit status: 0, or 1 with a message on stderr.
#include <chrono>
#include <cmath>
#include <fstream>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "tessera/client/gl/context.hpp"
#include "tessera/client/gl/frame_loop.hpp"
#include "tessera/client/gl/reference_renderer.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "tessera/client/measures.hpp"
#include "tessera/client/open_source.hpp"
#include "tessera/client/runtime.hpp"
#include "tessera/scene/path.hpp"
#include "tessera/scene/scene.hpp"
#include "tessera/client/tile_source.hpp"
#include "tessera/storage/png_encode.hpp"

namespace client = tessera::client;
namespace gl = tessera::client::gl;
namespace scene = tessera::scene;

namespace {

[[noreturn]] void fail(const std::string& message) {
    std::fprintf(stderr, "vt_minimal: %s\n", message.c_str());
    std::exit(1);
}

struct Options {
    std::string url, reference, save;  // url: grpc://HOST:PORT/STORE
    int frames = 120;
    std::uint32_t width = 320, height = 180;
};

constexpr const char* kUsage =
    "usage: vt_minimal grpc://HOST:PORT/STORE [--frames N] [--size WxH] [--reference STORE.tsr] [--save FRAME.png]";

Options parse(int argc, char** argv) {
    Options o;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto value = [&] {
            if (i + 1 >= argc) fail("missing value for " + a);
            return std::string(argv[++i]);
        };
        if (a == "--frames") {
            o.frames = std::atoi(value().c_str());
        } else if (a == "--size") {
            const std::string v = value();
            if (std::sscanf(v.c_str(), "%ux%u", &o.width, &o.height) != 2 || !o.width || !o.height)
                fail("--size: expected WxH, got '" + v + "'");
        } else if (a == "--reference") {
            o.reference = value();
        } else if (a == "--save") {
            o.save = value();
        } else if (a.rfind("grpc://", 0) == 0 && o.url.empty()) {
            o.url = a;
        } else {
            fail(kUsage);
        }
    }
    if (o.url.empty()) fail(kUsage);
    if (o.frames < 1) fail("--frames must be >= 1");
    return o;
}

template <typename T>
T take(tessera::Result<T> r, const char* what) {
    if (!r) fail(std::string(what) + ": " + r.error().message);
    return std::move(*r);
}

}  // namespace

int main(int argc, char** argv) {
    const Options o = parse(argc, argv);

    // 1. A GL context (EGL, no display needed) and the page source: the server's tile stream.
    auto context = take(gl::GlContext::create_headless(), "GL context");
    auto opened = take(client::open_source(take(client::parse_source_url(o.url), "store"), {}), "source");
    auto source = std::move(opened.source);
    const auto info = take(source->bind(0, opened.store), "store");

    // 2. The renderer: the page pool, page tables and VT passes, sized for this store's pages.
    gl::RendererConfig rc;
    rc.width = o.width;
    rc.height = o.height;
    rc.tile_size = info.tile_size();
    rc.border = info.border;
    rc.srgb = info.colour_space == tessera::storage::ColourSpace::srgb;
    rc.pool_slots = 256;
    auto renderer = take(gl::VtRenderer::create(rc), "renderer");

    // 3. The runtime: it turns feedback into requests, decodes what arrives and uploads it into
    //    the renderer (a PageUploader), a bounded number of pages per frame.
    client::RuntimeConfig cfg;
    cfg.residency.pool_slots = rc.pool_slots;
    cfg.transcode_threads = 1;
    auto runtime = take(client::Runtime::create(cfg, *renderer, &renderer->page_staging()), "runtime");
    const auto texture = take(runtime->add_texture(*source, opened.store), "texture");
    if (auto st = renderer->add_texture(texture, *runtime->texture_info(texture)); !st) fail(st.error().message);

    // 4. A scene: a flat terrain one world unit per texel, and a camera path over it.
    scene::TerrainOptions terrain;
    terrain.vt_width = info.width;
    terrain.vt_height = info.height;
    const auto world = take(scene::make_terrain(terrain), "terrain");
    if (auto st = renderer->set_scene(world, texture); !st) fail(st.error().message);
    const auto path = take(scene::CameraPath::builtin("flyover", world), "camera path");

    // 5. The frame loop (FrameLoop): render at the runtime's bias, hand the runtime the newest
    //    feedback (it comes back some frames late; a frame without it still uploads arrivals).
    gl::FrameLoop loop(*renderer, *runtime);
    std::uint32_t resident = 0;
    const double step = path.duration() / double(o.frames);
    for (int i = 0; i < o.frames; ++i) resident = loop.step(path.at(step * i)).stats->pages_resident;

    // 6. Hold the last view until what it needs is resident (at most 30 s): a settled frame has
    //    no fallback, nothing in flight and no bias.
    const scene::Camera final_view = path.at(step * (o.frames - 1));
    const gl::Settled held = loop.settle(final_view, std::chrono::seconds(30));
    resident = runtime->frame_without_feedback().pages_resident;
    const gl::FrameCounters& last = held.counters;
    const int extra = int(held.frames);
    const double fallback = last.textured_pixels ? double(last.fallback_unbiased) / double(last.textured_pixels) : 1.0;
    const auto image = renderer->read_color();
    if (!o.save.empty()) {  // the last frame as the renderer drew it (RGBA8, rows top to bottom)
        const auto png = take(tessera::storage::encode_png({o.width, o.height, 4, tessera::storage::SampleType::u8,
                                                            tessera::storage::ColourSpace::srgb, image}),
                              "PNG");
        std::ofstream(o.save, std::ios::binary).write(reinterpret_cast<const char*>(png.data()), std::streamsize(png.size()));
    }

    // 7. Optional: the same view from the reference renderer (a plain mipmapped texture).
    double psnr = -1;
    int max_error = -1;
    if (!o.reference.empty()) {
        const auto levels = take(client::decode_store_levels(o.reference), "reference store");
        auto reference = take(gl::ReferenceRenderer::create(rc, levels), "reference renderer");
        if (auto st = reference->set_scene(world); !st) fail(st.error().message);
        reference->render(final_view);
        const auto e = client::compare_images(image, reference->read_color(), rc.width, rc.height);
        psnr = std::isinf(e.psnr) ? 99.0 : e.psnr;
        max_error = e.max_error;
    }
    std::printf("{\"frames\":%d,\"settle_frames\":%d,\"textured_pixels\":%llu,\"fallback\":%.6f,\"lod_bias\":%.3f,"
                "\"resident_pages\":%u,\"psnr_db\":%.2f,\"max_error\":%d,\"gl_errors\":%llu}\n",
                o.frames, extra, static_cast<unsigned long long>(last.textured_pixels), fallback, runtime->lod_bias(),
                resident, psnr, max_error,
                static_cast<unsigned long long>(renderer->stats().gl_errors));
    return 0;
}
