// tessera build INPUT -o STORE.tsr
// tessera build --layer NAME[:CODEC]=INPUT --layer ... -o STORE.tsr   (a multi-layer store)
// tessera build --atlas SCENE.obj|SCENE.gltf|SCENE.glb -o ATLAS.tsr [--obj-out ATLAS.obj]
#include <fmt/format.h>

#include <cstdio>
#include <filesystem>

#include "atlas_build.hpp"
#include "commands.hpp"
#include "interrupt.hpp"
#include "progress.hpp"
#include "store_summary.hpp"
#include "tessera/scene/visibility.hpp"
#include "tessera/storage/builder.hpp"
#include "tessera/storage/layers.hpp"
#include "tessera/storage/output_file.hpp"
#include "tessera/storage/store_writer.hpp"

namespace tessera::tools {

namespace {

// --layer NAME[:CODEC]=INPUT. The name ends at the first ':' or '=', so INPUT may hold both.
storage::LayerInput parse_layer(const std::string& spec) {
    const std::size_t eq = spec.find('=');
    if (eq == std::string::npos || eq + 1 == spec.size())
        throw Failure(fmt::format("--layer takes NAME[:CODEC]=INPUT, got '{}'", spec), 2);
    const std::string head = spec.substr(0, eq);
    storage::LayerInput layer;
    layer.input = spec.substr(eq + 1);
    const std::size_t colon = head.find(':');
    layer.name = head.substr(0, colon);
    if (const std::string why = storage::layer_name_misfit(layer.name); !why.empty())
        throw Failure(fmt::format("--layer '{}': {}", spec, why), 2);
    if (colon != std::string::npos) {
        const std::string codec = head.substr(colon + 1);
        const auto c = parse_codec(codec);
        if (!c || *c == Codec::layers)
            throw Failure(fmt::format("--layer '{}': unknown codec '{}' (jpeg, zstd, raw, bc1, bc4, bc5 or bc7)", spec, codec), 2);
        layer.codec = c;
    }
    return layer;
}

// The build command's options, as read from its flags.
struct BuildArgs {
    std::string input, output, codec, chroma, colour_space = "auto", atlas, obj_out, up = "auto";
    std::vector<std::string> layers;
    std::string visibility, visibility_view = "1280x720";
    double visibility_fps = 30;
    storage::BuildOptions opt;
    storage::AtlasPackOptions pack;
    bool quiet = false;
    bool visibility_options_given = false;  // --visibility-view or --visibility-fps
};

// Checks the options against each other and builds the store (or the atlas, or the layers).
int run_build(BuildArgs& a) {
    storage::BuildOptions& opt = a.opt;
    if (!a.codec.empty()) opt.codec = parse_codec(a.codec);
    if (!a.chroma.empty()) opt.chroma = a.chroma == "420" ? storage::Chroma::s420 : storage::Chroma::s444;
    if (a.colour_space == "srgb") opt.colour_space = storage::ColourSpace::srgb;
    if (a.colour_space == "linear") opt.colour_space = storage::ColourSpace::linear;
    if (Status st = storage::validate(opt); !st) throw Failure(st.error().message, 2);
    std::vector<storage::LayerInput> layers;
    for (const std::string& spec : a.layers) layers.push_back(parse_layer(spec));
    if (!layers.empty()) {
        if (!a.input.empty()) throw Failure("give either an input image or --layer NAME=INPUT layers, not both", 2);
        if (!a.atlas.empty()) throw Failure("--atlas builds a single-layer store; it does not take --layer", 2);
        if (!a.codec.empty())
            throw Failure("--codec applies to single-layer builds; give each layer's codec as --layer NAME:CODEC=INPUT", 2);
        if (layers.size() < storage::kMinLayers || layers.size() > storage::kMaxLayers)
            throw Failure(fmt::format("a multi-layer store has {} to {} layers; --layer was given {} time(s)",
                                      storage::kMinLayers, storage::kMaxLayers, layers.size()), 2);
        for (std::size_t i = 0; i < layers.size(); ++i)
            for (std::size_t j = 0; j < i; ++j)
                if (layers[i].name == layers[j].name) throw Failure(fmt::format("two layers are named '{}'", layers[i].name), 2);
    }
    if (a.atlas.empty() && a.input.empty() && layers.empty())
        throw Failure("an input image, --layer NAME=INPUT layers or --atlas SCENE (.obj, .gltf, .glb) is required", 2);
    if (!a.atlas.empty() && !a.input.empty())
        throw Failure("give either an input image or --atlas SCENE, not both", 2);
    if (a.atlas.empty() && !a.obj_out.empty()) throw Failure("--obj-out needs --atlas", 2);
    if (!a.atlas.empty() && (a.pack.alignment == 0 || (a.pack.alignment & (a.pack.alignment - 1)) != 0 ||
                              a.pack.alignment > 4096))
        throw Failure(fmt::format("--atlas-align must be a power of two up to 4096, got {}", a.pack.alignment), 2);
    if (!a.atlas.empty() && a.pack.padding > 4096)
        throw Failure(fmt::format("--atlas-padding must be at most 4096, got {}", a.pack.padding), 2);
    if (!a.atlas.empty() && a.obj_out.empty())
        a.obj_out = std::filesystem::path(a.output).replace_extension(".obj").string();
    // Before any work: the outputs are renamed into place, which would replace a device or a link.
    for (const std::string& path : {a.output, a.obj_out})
        if (Status st = storage::check_output_file(path); !st) throw Failure(st.error().message, 2);

    const bool visibility_given =
        a.visibility_options_given;
    if (visibility_given && a.visibility.empty())
        throw Failure("--visibility-view and --visibility-fps need --visibility PATHS", 2);
    if (!a.visibility.empty() && !a.atlas.empty())
        throw Failure("--visibility works on the terrain scene of an image source, not with --atlas", 2);
    scene::VisibilityOptions vis;
    if (!a.visibility.empty()) {
        unsigned w = 0, h = 0;
        char x = 0, extra = 0;
        if (std::sscanf(a.visibility_view.c_str(), "%u%c%u%c", &w, &x, &h, &extra) != 3 || x != 'x' || w == 0 ||
            h == 0 || w > 16384 || h > 16384)
            throw Failure(fmt::format("--visibility-view must be WxH (1 to 16384 each), got '{}'", a.visibility_view), 2);
        if (!(a.visibility_fps > 0) || a.visibility_fps > 1000)
            throw Failure(fmt::format("--visibility-fps must be above 0 and at most 1000, got {}", a.visibility_fps), 2);
        vis.view_width = w;
        vis.view_height = h;
        vis.fps = a.visibility_fps;
    }

    ProgressBar bar("build", !a.quiet);
    StderrCapture library_messages;
    const auto on_progress = [&](const storage::BuildProgress& p) {
        if (p.writing) {
            bar.set_label("write");
            bar.update(p.bytes_total ? double(p.bytes_written) / double(p.bytes_total) : 1.0,
                       human_bytes(p.bytes_written) + " / " + human_bytes(p.bytes_total));
        } else if (p.rows_total == 0) {  // a sparse source: tiles, no rows
            bar.update(p.tiles_total ? double(p.tiles_done) / double(p.tiles_total) : 0.0,
                       fmt::format("tiles {}/{}", p.tiles_done, p.tiles_total));
        } else {
            bar.update(p.rows_total ? double(p.rows_done) / double(p.rows_total) : 0.0,
                       fmt::format("rows {}/{}  tiles {}/{}", p.rows_done, p.rows_total, p.tiles_done, p.tiles_total));
        }
    };
    if (!a.atlas.empty()) {
        const scene::UpAxis up = a.up == "y" ? scene::UpAxis::y : a.up == "z" ? scene::UpAxis::z : scene::UpAxis::automatic;
        auto result = build_atlas(a.atlas, a.output, a.obj_out, opt, a.pack, on_progress, up);
        bar.finish();
        const std::string messages = library_messages.release();
        if (!result) throw Failure(result.error().message);
        std::fputs(messages.c_str(), stderr);
        for (const std::string& w : result->warnings) fmt::print(stderr, "warning: {}\n", w);
        if (!a.quiet) {
            const auto& s = *result;
            fmt::print("built {} from {} images of {} ({} triangles) in {}\n", a.output, s.images, a.atlas, s.triangles,
                       human_seconds(s.build.seconds));
            fmt::print("up axis {} ({}; the scene spans {:.4g} x {:.4g} x {:.4g} in x, y, z)\n", s.up == scene::UpAxis::z ? "z" : "y",
                       a.up == "auto" ? "auto, --up to choose" : "--up", s.extent[0], s.extent[1], s.extent[2]);
            if (s.repeating_images > 0)
                fmt::print("{} repeating textures (padding wraps around); {} triangles are pieces cut at their repeats\n",
                           s.repeating_images, s.repeat_pieces);
            if (!s.layers.empty())
                fmt::print("material layers {} ({} maps; docs/atlas.md, \"Material layers\")\n", fmt::join(s.layers, ", "), s.maps);
            fmt::print("wrote {} (texture coordinates in the atlas, v down)\n", a.obj_out);
            print_store_summary(a.output, s.build.info);
        }
        return 0;
    }
    if (layers.empty() && storage::is_sparse_input(a.input)) {
        if (!a.visibility.empty()) throw Failure("--visibility does not apply to a sparse source (its absent tiles are its own)", 2);
        auto result = storage::build_sparse_store(a.input, a.output, opt, on_progress);
        bar.finish();
        const std::string messages = library_messages.release();
        if (!result) throw Failure(result.error().message, result.error().code == Errc::invalid_argument ? 2 : 1);
        std::fputs(messages.c_str(), stderr);
        if (!a.quiet) {
            std::uint64_t present = 0, total = 0;
            for (const auto& l : result->info.levels) {
                present += l.present + l.uniform;
                total += std::uint64_t(l.tiles_x) * l.tiles_y;
            }
            fmt::print("built {} in {}: {} present tiles of {} ({:.2g}%), the rest absent\n", a.output,
                       human_seconds(result->seconds), present, total, 100.0 * double(present) / double(total));
            print_store_summary(a.output, result->info);
        }
        return 0;
    }
    if (layers.empty()) {
        if (Status st = storage::check_output_is_not_input(a.input, a.output); !st) throw Failure(st.error().message, 2);
    }
    // A layered build opens its inputs itself; the first one is opened here too when its size
    // is needed first (--visibility).
    auto source = layers.empty() || !a.visibility.empty() ? storage::open_image_source(layers.empty() ? a.input : layers[0].input)
                                                            : Result<std::unique_ptr<storage::ImageSource>>(nullptr);
    if (!source) throw Failure((layers.empty() ? "" : "layer '" + layers[0].name + "': ") + source.error().message);
    scene::PageSet mask;
    if (!a.visibility.empty()) {
        // The level-0 pages the paths want over the flat terrain of the source's size (plus
        // their 8 neighbours); every other level-0 tile is written absent.
        const auto& si = (*source)->info();
        storage::StoreSpec spec;
        spec.width = si.width;
        spec.height = si.height;
        spec.tile_payload = opt.tile_size - 2 * opt.border;
        spec.border = opt.border;
        const storage::StoreInfo geo = storage::store_info(spec);
        auto terrain = scene::visibility_terrain(si.width, si.height);
        if (!terrain) throw Failure(terrain.error().message);
        auto paths = scene::parse_path_list(a.visibility, *terrain);
        if (!paths) throw Failure("--visibility " + paths.error().message, 2);
        mask = scene::level0_mask(*paths, scene::VtGeometry{si.width, si.height, spec.tile_payload, geo.level_count()}, vis);
        opt.keep = [&mask](std::uint32_t level, std::uint32_t x, std::uint32_t y) {
            return level != 0 || mask.contains(0, x, y);
        };
    }
    if (!layers.empty()) source = Result<std::unique_ptr<storage::ImageSource>>(nullptr);
    auto result = layers.empty() ? storage::build_store(**source, a.output, opt, on_progress)
                                 : storage::build_layered_store(layers, a.output, opt, on_progress);
    opt.keep = {};  // it refers to `mask`
    bar.finish();
    const std::string messages = library_messages.release();
    if (!result) throw Failure(result.error().message);  // it already holds the libraries' own report
    std::fputs(messages.c_str(), stderr);
    if (!a.quiet) {
        const auto& s = *result;
        fmt::print("built {} in {} ({:.1f} MP/s)\n", a.output, human_seconds(s.seconds),
                   double(s.source_texels) / 1e6 / std::max(s.seconds, 1e-9));
        print_store_summary(a.output, s.info);
        if (!s.tiles_dropped.empty()) {
            const std::uint64_t total = mask.total(0), dropped = s.tiles_dropped[0];
            fmt::print("visibility ({}, {}x{} at {} fps): level-0 tiles kept {} of {} ({:.1f}%), dropped {}; saved {}\n",
                       a.visibility, vis.view_width, vis.view_height, vis.fps, total - dropped, total,
                       total ? 100.0 * double(total - dropped) / double(total) : 0.0, dropped, human_bytes(s.bytes_dropped));
        }
    }
    return 0;
}

}  // namespace

Command add_build(CLI::App& app) {
    auto a = std::make_shared<BuildArgs>();
    CLI::App* c = app.add_subcommand("build", "Build a tile store from an image or a procedural source");
    c->add_option("input", a->input,
                  "Image file (anything OpenImageIO reads), procedural:terrain[-height|-normal]:SIZE (not with --atlas or --layer), or a sparse source (docs/store-format.md, \"Sparse stores\"): a mosaic manifest FILE.json (images placed on a canvas of up to 2^32-1 texels per side) or the test pattern procedural:coords-sparse:SIZE (up to 16777216)");
    c->add_option("-o,--output", a->output, "Store file to write (.tsr)")->required();
    c->add_option("--layer", a->layers,
                  "A layer of a multi-layer store, NAME[:CODEC]=INPUT (instead of INPUT; 2 to 16 of them, all of one size): "
                  "NAME is 1-31 of a-z 0-9 _ -, CODEC as --codec (default: jpeg for 8-bit grey/RGB, zstd otherwise), "
                  "INPUT an image or procedural:terrain[-height|-normal]:SIZE; the other flags apply to every layer")
        ->allow_extra_args(false);
    c->add_option("--tile-size", a->opt.tile_size, "Stored tile size in texels: payload + 2 x border (power of two, 64-1024)")
        ->capture_default_str();
    c->add_option("--border", a->opt.border, "Texels of the neighbouring tiles stored on each side (even)")->capture_default_str();
    c->add_option("--codec", a->codec,
                  "Tile codec: jpeg, zstd or raw, or GPU blocks made here, quality first, and kept with zstd: bc1 (RGB), "
                  "bc4 (grey), bc5 (two channels), bc7 (RGB or RGBA) (default: jpeg for 8-bit grey/RGB, zstd otherwise)")
        ->check(CLI::IsMember({"jpeg", "zstd", "raw", "bc1", "bc4", "bc5", "bc7"}));
    c->add_option("--quality", a->opt.quality, "JPEG quality (1-100)")->capture_default_str();
    c->add_option("--chroma", a->chroma, "JPEG chroma subsampling: 420 or 444 (default: 444 at quality >= 90, else 420)")
        ->check(CLI::IsMember({"420", "444"}));
    c->add_option("--zstd-level", a->opt.zstd_level, "zstd compression level (1-19)")->capture_default_str();
    c->add_option("--bc7-effort", a->opt.bc7_effort,
                  "--codec bc7: encoder search, 0 (fastest, ~3x effort 2's speed, ~1 dB less) to 3 (slowest)")
        ->capture_default_str();
    c->add_option("--threads", a->opt.threads, "Worker threads (0: all cores)")->capture_default_str();
    c->add_option("--colour-space,--color-space", a->colour_space, "Colour space of the samples: auto, srgb or linear")
        ->check(CLI::IsMember({"auto", "srgb", "linear"}))
        ->capture_default_str();
    c->add_flag("--sparse", a->opt.sparse, "Store tiles whose alpha is zero everywhere as absent (needs an alpha channel)");
    c->add_option("--visibility", a->visibility,
                  "Drop the level-0 tiles these camera paths never want over the flat terrain (comma-separated built-in "
                  "path names or path files; terrain-like sources only); see docs/visibility.md");
    c->add_option("--visibility-view", a->visibility_view, "With --visibility: the view the paths are sampled at, WxH")
        ->capture_default_str();
    c->add_option("--visibility-fps", a->visibility_fps, "With --visibility: frames sampled per second of path")
        ->capture_default_str();
    c->add_flag("-q,--quiet", a->quiet, "No progress bar and no summary");
    c->add_option("--atlas", a->atlas,
                  "Pack the colour textures of this scene's materials (OBJ, or glTF 2.0 .gltf/.glb) into one store (instead of INPUT); "
                  "a glTF scene's normal, metallic-roughness, occlusion and emissive maps go into layers of their own; see docs/atlas.md");
    c->add_option("--obj-out", a->obj_out,
                  "With --atlas: the scene written as OBJ, texture coordinates in the atlas (default: the store's name with .obj)");
    c->add_option("--atlas-align", a->pack.alignment, "With --atlas: cells start at and span multiples of this (power of two)")
        ->capture_default_str();
    c->add_option("--atlas-padding", a->pack.padding, "With --atlas: texels of edge replication around each texture")
        ->capture_default_str();
    c->add_option("--up", a->up, "With --atlas: the scene's up axis, y (the OBJ and glTF convention), z (SketchUp, CAD) or auto "
                                 "(glTF: y; OBJ: z when the scene is flatter along z than y)")
        ->check(CLI::IsMember({"auto", "y", "z"}))
        ->capture_default_str();

    return [a, c]() -> int {
        remove_temp_files_on_interrupt();  // before the build starts any thread
        a->visibility_options_given = c->get_option("--visibility-view")->count() + c->get_option("--visibility-fps")->count() > 0;
        return run_build(*a);
    };
}

}  // namespace tessera::tools
