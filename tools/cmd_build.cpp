// tessera build INPUT -o STORE.tsr
// tessera build --atlas SCENE.obj -o ATLAS.tsr [--obj-out ATLAS.obj]
#include <fmt/format.h>

#include <filesystem>

#include "atlas_build.hpp"
#include "commands.hpp"
#include "progress.hpp"
#include "store_summary.hpp"
#include "tessera/storage/builder.hpp"

namespace tessera::tools {

Command add_build(CLI::App& app) {
    struct Args {
        std::string input, output, codec, chroma, colour_space = "auto", atlas, obj_out;
        storage::BuildOptions opt;
        storage::AtlasPackOptions pack;
        bool quiet = false;
    };
    auto a = std::make_shared<Args>();
    CLI::App* c = app.add_subcommand("build", "Build a tile store from an image or a procedural source");
    c->add_option("input", a->input, "Image file (anything OpenImageIO reads) or procedural:terrain:SIZE (not with --atlas)");
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
    c->add_option("--atlas", a->atlas,
                  "Pack the textures of this OBJ scene's materials into one store (instead of INPUT); see docs/atlas.md");
    c->add_option("--obj-out", a->obj_out,
                  "With --atlas: the rewritten OBJ, texture coordinates in the atlas (default: the store's name with .obj)");
    c->add_option("--atlas-align", a->pack.alignment, "With --atlas: cells start at and span multiples of this (power of two)")
        ->capture_default_str();
    c->add_option("--atlas-padding", a->pack.padding, "With --atlas: texels of edge replication around each texture")
        ->capture_default_str();

    return [a]() -> int {
        storage::BuildOptions& opt = a->opt;
        if (!a->codec.empty()) opt.codec = storage::parse_codec(a->codec);
        if (!a->chroma.empty()) opt.chroma = a->chroma == "420" ? storage::Chroma::s420 : storage::Chroma::s444;
        if (a->colour_space == "srgb") opt.colour_space = storage::ColourSpace::srgb;
        if (a->colour_space == "linear") opt.colour_space = storage::ColourSpace::linear;
        if (Status st = storage::validate(opt); !st) throw Failure(st.error().message, 2);
        if (a->atlas.empty() && a->input.empty()) throw Failure("an input image (or --atlas SCENE.obj) is required", 2);
        if (!a->atlas.empty() && !a->input.empty())
            throw Failure("give either an input image or --atlas SCENE.obj, not both", 2);
        if (a->atlas.empty() && !a->obj_out.empty()) throw Failure("--obj-out needs --atlas", 2);
        if (!a->atlas.empty() && (a->pack.alignment == 0 || (a->pack.alignment & (a->pack.alignment - 1)) != 0 ||
                                  a->pack.alignment > 4096))
            throw Failure(fmt::format("--atlas-align must be a power of two up to 4096, got {}", a->pack.alignment), 2);
        if (!a->atlas.empty() && a->pack.padding > 4096)
            throw Failure(fmt::format("--atlas-padding must be at most 4096, got {}", a->pack.padding), 2);
        if (!a->atlas.empty() && a->obj_out.empty())
            a->obj_out = std::filesystem::path(a->output).replace_extension(".obj").string();

        ProgressBar bar("build", !a->quiet);
        StderrCapture library_messages;
        const auto on_progress = [&](const storage::BuildProgress& p) {
            if (p.writing) {
                bar.set_label("write");
                bar.update(p.bytes_total ? double(p.bytes_written) / double(p.bytes_total) : 1.0,
                           human_bytes(p.bytes_written) + " / " + human_bytes(p.bytes_total));
            } else {
                bar.update(p.rows_total ? double(p.rows_done) / double(p.rows_total) : 0.0,
                           fmt::format("rows {}/{}  tiles {}/{}", p.rows_done, p.rows_total, p.tiles_done, p.tiles_total));
            }
        };
        if (!a->atlas.empty()) {
            auto result = build_atlas(a->atlas, a->output, a->obj_out, opt, a->pack, on_progress);
            bar.finish();
            const std::string messages = library_messages.release();
            if (!result) throw Failure(result.error().message);
            std::fputs(messages.c_str(), stderr);
            if (!a->quiet) {
                const auto& s = *result;
                fmt::print("built {} from {} images of {} ({} triangles) in {}\n", a->output, s.images, a->atlas, s.triangles,
                           human_seconds(s.build.seconds));
                fmt::print("wrote {} (texture coordinates in the atlas, v down)\n", a->obj_out);
                print_store_summary(a->output, s.build.info);
            }
            return 0;
        }
        auto result = storage::build_store(a->input, a->output, opt, on_progress);
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
