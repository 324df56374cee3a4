// tessera build INPUT -o STORE.tsr
#include <fmt/format.h>

#include "commands.hpp"
#include "progress.hpp"
#include "store_summary.hpp"
#include "tessera/storage/builder.hpp"

namespace tessera::tools {

Command add_build(CLI::App& app) {
    struct Args {
        std::string input, output, codec, chroma, colour_space = "auto";
        storage::BuildOptions opt;
        bool quiet = false;
    };
    auto a = std::make_shared<Args>();
    CLI::App* c = app.add_subcommand("build", "Build a tile store from an image or a procedural source");
    c->add_option("input", a->input, "Image file (anything OpenImageIO reads) or procedural:terrain:SIZE")->required();
    c->add_option("-o,--output", a->output, "Store file to write (.tsr)")->required();
    c->add_option("--tile-size", a->opt.tile_size, "Stored tile size in texels: payload + 2 x border (power of two, 64-1024)")
        ->capture_default_str();
    c->add_option("--border", a->opt.border, "Texels of the neighbouring tiles stored on each side (even)")->capture_default_str();
    c->add_option("--codec", a->codec, "Tile codec: jpeg, zstd or raw (default: jpeg for 8-bit grey/RGB, zstd otherwise)")
        ->check(CLI::IsMember({"jpeg", "zstd", "raw"}));
    c->add_option("--quality", a->opt.quality, "JPEG quality (1-100)")->capture_default_str();
    c->add_option("--chroma", a->chroma, "JPEG chroma subsampling: 420 or 444 (default: 444 at quality >= 90, else 420)")
        ->check(CLI::IsMember({"420", "444"}));
    c->add_option("--zstd-level", a->opt.zstd_level, "zstd compression level (1-19)")->capture_default_str();
    c->add_option("--threads", a->opt.threads, "Worker threads (0: all cores)")->capture_default_str();
    c->add_option("--colour-space,--color-space", a->colour_space, "Colour space of the samples: auto, srgb or linear")
        ->check(CLI::IsMember({"auto", "srgb", "linear"}))
        ->capture_default_str();
    c->add_flag("--sparse", a->opt.sparse, "Store tiles whose alpha is zero everywhere as absent (needs an alpha channel)");
    c->add_flag("-q,--quiet", a->quiet, "No progress bar and no summary");

    return [a]() -> int {
        storage::BuildOptions& opt = a->opt;
        if (!a->codec.empty()) opt.codec = storage::parse_codec(a->codec);
        if (!a->chroma.empty()) opt.chroma = a->chroma == "420" ? storage::Chroma::s420 : storage::Chroma::s444;
        if (a->colour_space == "srgb") opt.colour_space = storage::ColourSpace::srgb;
        if (a->colour_space == "linear") opt.colour_space = storage::ColourSpace::linear;
        if (Status st = storage::validate(opt); !st) throw Failure(st.error().message, 2);

        ProgressBar bar("build", !a->quiet);
        StderrCapture library_messages;
        auto result = storage::build_store(a->input, a->output, opt, [&](const storage::BuildProgress& p) {
            if (p.writing) {
                bar.set_label("write");
                bar.update(p.bytes_total ? double(p.bytes_written) / double(p.bytes_total) : 1.0,
                           human_bytes(p.bytes_written) + " / " + human_bytes(p.bytes_total));
            } else {
                bar.update(p.rows_total ? double(p.rows_done) / double(p.rows_total) : 0.0,
                           fmt::format("rows {}/{}  tiles {}/{}", p.rows_done, p.rows_total, p.tiles_done, p.tiles_total));
            }
        });
        bar.finish();
        const std::string messages = library_messages.release();
        if (!result) throw Failure(result.error().message);  // it already holds the libraries' own report
        std::fputs(messages.c_str(), stderr);
        if (!a->quiet) {
            const auto& s = *result;
            fmt::print("built {} in {} ({:.1f} MP/s)\n", a->output, human_seconds(s.seconds),
                       double(s.source_texels) / 1e6 / std::max(s.seconds, 1e-9));
            print_store_summary(a->output, s.info);
        }
        return 0;
    };
}

}  // namespace tessera::tools
