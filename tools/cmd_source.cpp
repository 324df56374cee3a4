// tessera source SPEC -o IMAGE: writes a source (e.g. the procedural terrain) to an image file,
// strip by strip, so other tools (libvips, image viewers) can read exactly what the builder reads.
#include <OpenImageIO/imageio.h>
#include <fmt/format.h>
#include <unistd.h>

#include <filesystem>
#include <thread>

#include "commands.hpp"
#include "progress.hpp"
#include "tessera/storage/image_source.hpp"

namespace tessera::tools {

Command add_source(CLI::App& app) {
    struct Args {
        std::string spec, output;
        bool quiet = false;
    };
    auto a = std::make_shared<Args>();
    CLI::App* c = app.add_subcommand("source", "Write a build source (e.g. procedural:terrain:SIZE) to an image file");
    c->add_option("source", a->spec, "procedural:terrain:SIZE or an image file")->required();
    c->add_option("-o,--output", a->output, "Image file to write; the format follows the extension (.tif, .png, .exr ...)")
        ->required();
    c->add_flag("-q,--quiet", a->quiet, "No progress bar");
    return [a]() -> int {
        auto src = storage::open_image_source(a->spec);
        if (!src) throw Failure(src.error().message);
        const storage::SourceInfo& si = (*src)->info();
        namespace fs = std::filesystem;
        const fs::path out(a->output);
        const fs::path tmp = (out.has_parent_path() ? out.parent_path() : fs::path(".")) /
                             fmt::format(".tmp-{}-{}", ::getpid(), out.filename().string());
        auto output = OIIO::ImageOutput::create(a->output);
        if (!output) throw Failure(fmt::format("cannot write '{}': {}", a->output, OIIO::geterror()));
        static const OIIO::TypeDesc types[] = {OIIO::TypeDesc::UINT8, OIIO::TypeDesc::UINT16, OIIO::TypeDesc::HALF,
                                               OIIO::TypeDesc::FLOAT};
        const OIIO::TypeDesc type = types[static_cast<int>(si.sample_type)];
        OIIO::ImageSpec spec(int(si.width), int(si.height), int(si.channels), type);
        if (si.has_alpha) spec.alpha_channel = int(si.channels) - 1;
        spec.attribute("oiio:ColorSpace", si.colour_space == storage::ColourSpace::srgb ? "sRGB" : "Linear");
        spec.attribute("compression", "none");
        if (!output->open(tmp.string(), spec)) throw Failure(fmt::format("cannot write '{}': {}", a->output, output->geterror()));
        auto cleanup = [&] {
            output->close();
            std::error_code ec;
            fs::remove(tmp, ec);
        };
        const std::size_t row = std::size_t(si.width) * si.channels * storage::sample_bytes(si.sample_type);
        const std::uint32_t strip = 256;
        std::vector<std::uint8_t> buf(row * strip);
        const unsigned threads = std::max(1u, std::thread::hardware_concurrency());
        // A small fork-join over std::thread is enough here: one strip at a time.
        const storage::ParallelFor parallel = [threads](std::size_t n, const std::function<void(std::size_t, std::size_t)>& fn) {
            std::vector<std::thread> ts;
            const std::size_t per = (n + threads - 1) / threads;
            for (std::size_t b = 0; b < n; b += per) ts.emplace_back([&fn, b, e = std::min(n, b + per)] { fn(b, e); });
            for (auto& t : ts) t.join();
        };
        ProgressBar bar("source", !a->quiet);
        for (std::uint32_t y = 0; y < si.height; y += strip) {
            const std::uint32_t n = std::min(strip, si.height - y);
            if (Status st = (*src)->read_rows(y, n, buf.data(), parallel); !st) {
                cleanup();
                throw Failure(st.error().message);
            }
            if (!output->write_scanlines(int(y), int(y + n), 0, type, buf.data())) {
                const std::string err = output->geterror();
                cleanup();
                throw Failure(fmt::format("cannot write '{}': {}", a->output, err));
            }
            bar.update(double(y + n) / si.height, fmt::format("rows {}/{}", y + n, si.height));
        }
        bar.finish();
        if (!output->close()) {
            const std::string err = output->geterror();
            cleanup();
            throw Failure(fmt::format("cannot write '{}': {}", a->output, err));
        }
        std::error_code ec;
        fs::rename(tmp, out, ec);
        if (ec) {
            fs::remove(tmp, ec);
            throw Failure(fmt::format("cannot rename into '{}'", a->output));
        }
        if (!a->quiet) fmt::print("wrote {} ({}x{}, {} channels)\n", a->output, si.width, si.height, si.channels);
        return 0;
    };
}

}  // namespace tessera::tools
