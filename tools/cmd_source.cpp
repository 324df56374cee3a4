// tessera source SPEC -o IMAGE: writes a source (e.g. the procedural terrain) to an image file,
// strip by strip, so other tools (libvips, image viewers) can read exactly what the builder reads.
// tessera source scene:gallery -o DIR: writes the sample OBJ scene (gallery_scene.hpp).
#include <fmt/format.h>

#include <thread>

#include "commands.hpp"
#include "gallery_scene.hpp"
#include "interrupt.hpp"
#include "progress.hpp"
#include "tessera/storage/image_source.hpp"
#include "tessera/storage/output_file.hpp"

namespace tessera::tools {

Command add_source(CLI::App& app) {
    struct Args {
        std::string spec, output;
        bool quiet = false;
    };
    auto a = std::make_shared<Args>();
    CLI::App* c = app.add_subcommand("source", "Write a build source (e.g. procedural:terrain:SIZE) to an image file");
    c->add_option("source", a->spec, "procedural:terrain:SIZE, an image file, or scene:gallery (a sample OBJ scene)")->required();
    c->add_option("-o,--output", a->output,
                  "Image file to write; the format follows the extension (.tif, .png, .exr ...). For scene:gallery, a new folder")
        ->required();
    c->add_flag("-q,--quiet", a->quiet, "No progress bar");
    return [a]() -> int {
        remove_temp_files_on_interrupt();  // before any thread is started
        if (a->spec.rfind("scene:", 0) == 0) {
            if (a->spec != "scene:gallery") throw Failure("unknown scene '" + a->spec + "' (expected scene:gallery)", 2);
            StderrCapture library_messages;
            const Status st = write_gallery_scene(a->output);
            const std::string messages = library_messages.release();
            if (!st) throw Failure(st.error().message);
            std::fputs(messages.c_str(), stderr);
            if (!a->quiet) fmt::print("wrote the gallery scene to {} (gallery.obj, gallery.mtl, textures/)\n", a->output);
            return 0;
        }
        // Before any work: the image is renamed into place, which would replace a device or a link.
        if (Status st = storage::check_output_file(a->output); !st) throw Failure(st.error().message, 2);
        ProgressBar bar("source", !a->quiet);
        StderrCapture library_messages;  // libpng prints its own copy of errors we report (see cmd_build.cpp)
        auto src = storage::open_image_source(a->spec);
        if (!src) throw Failure(src.error().message);
        const storage::SourceInfo& si = (*src)->info();
        const unsigned threads = std::max(1u, std::thread::hardware_concurrency());
        // A small fork-join over std::thread is enough here: one strip at a time.
        const storage::ParallelFor parallel = [threads](std::size_t n, const std::function<void(std::size_t, std::size_t)>& fn) {
            std::vector<std::thread> ts;
            const std::size_t per = (n + threads - 1) / threads;
            for (std::size_t b = 0; b < n; b += per) ts.emplace_back([&fn, b, e = std::min(n, b + per)] { fn(b, e); });
            for (auto& t : ts) t.join();
        };
        // write_image writes a temporary file and renames it into place once it is whole.
        const Status st = storage::write_image(a->output, **src, parallel, [&](std::uint32_t rows) {
            bar.update(double(rows) / si.height, fmt::format("rows {}/{}", rows, si.height));
        });
        bar.finish();
        const std::string messages = library_messages.release();
        if (!st) throw Failure(st.error().message);
        std::fputs(messages.c_str(), stderr);
        if (!a->quiet) fmt::print("wrote {} ({}x{}, {} channels)\n", a->output, si.width, si.height, si.channels);
        return 0;
    };
}

}  // namespace tessera::tools
