// build_layered_store(): several sources of one size become one store whose tiles are bundles of
// every layer's part. One pyramid per layer, all fed in step on one pool; a joiner collects each
// tile's parts as the pyramids finish them and writes the bundle once every layer has given its.
#include <algorithm>
#include <chrono>
#include <memory>
#include <mutex>
#include <thread>
#include <unordered_map>

#include "pyramid_builder.hpp"
#include "sources_internal.hpp"
#include "tessera/storage/builder.hpp"
#include "tessera/storage/layers.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/store_writer.hpp"
#include "thread_pool.hpp"

namespace tessera::storage {
namespace {

using build::FirstError;
using build::PyramidBuilder;
using build::ThreadPool;

// Holds the parts of tiles that some layers have finished and others not yet. The pyramids are fed
// the same strips in step, so a tile's parts arrive close together and few tiles wait here.
class BundleJoiner {
public:
    BundleJoiner(std::size_t layers, StoreWriter& writer) : layers_(layers), writer_(writer) {}

    Status put(const TileKey& key, std::size_t layer, TileKind kind, std::vector<std::uint8_t> bytes) {
        Pending done;
        {
            std::lock_guard lock(mu_);
            Pending& p = pending_[pack_key(key)];
            if (p.parts.empty()) p.parts.resize(layers_);
            if (p.parts[layer].has_value())
                return make_error(Errc::invalid_argument, "internal error: a layer gave a tile twice");
            p.parts[layer] = Part{kind, std::move(bytes)};
            if (++p.count < layers_) return {};
            done = std::move(p);
            pending_.erase(pack_key(key));
        }
        std::vector<LayerPart> parts;
        bool any = false;
        for (const auto& p : done.parts) {
            parts.push_back(LayerPart{p->kind, p->bytes});
            any = any || p->kind != TileKind::absent;
        }
        if (!any) return {};  // absent in every layer: an absent tile
        return writer_.add_present(key, join_layers(parts));
    }

    std::size_t waiting() const {
        std::lock_guard lock(mu_);
        return pending_.size();
    }

private:
    struct Part {
        TileKind kind = TileKind::absent;
        std::vector<std::uint8_t> bytes;
    };
    struct Pending {
        std::vector<std::optional<Part>> parts;  // per layer, once given
        std::size_t count = 0;
    };
    const std::size_t layers_;
    StoreWriter& writer_;
    mutable std::mutex mu_;
    std::unordered_map<std::uint64_t, Pending> pending_;  // by pack_key
};

// One layer's pyramid hands its tiles to the joiner.
class LayerSink final : public build::TileSink {
public:
    LayerSink(BundleJoiner& joiner, std::size_t layer) : joiner_(joiner), layer_(layer) {}
    Status present(const TileKey& key, std::vector<std::uint8_t> payload) override {
        return joiner_.put(key, layer_, TileKind::present, std::move(payload));
    }
    Status uniform(const TileKey& key, std::span<const std::uint8_t> value) override {
        return joiner_.put(key, layer_, TileKind::uniform, std::vector<std::uint8_t>(value.begin(), value.end()));
    }
    Status absent(const TileKey& key) override { return joiner_.put(key, layer_, TileKind::absent, {}); }

private:
    BundleJoiner& joiner_;
    std::size_t layer_;
};

std::string size_text(const SourceInfo& si) { return std::to_string(si.width) + "x" + std::to_string(si.height); }

}  // namespace

Result<BuildSummary> build_layered_store(std::span<const LayerInput> layers, const std::string& output,
                                         const BuildOptions& opt, const BuildProgressFn& progress) {
    TESSERA_TRY(validate(opt));
    if (opt.codec)
        return make_error(Errc::invalid_argument,
                          "--codec applies to single-layer builds; give each layer's codec as --layer NAME:CODEC=INPUT");
    // Names first: nothing is opened for a build that cannot be made.
    {
        std::vector<LayerInfo> named;
        for (const LayerInput& l : layers) named.push_back(LayerInfo{l.name, 1, SampleType::u8, ColourSpace::linear, Codec::raw});
        if (const std::string why = layers_misfit(named, opt.tile_size, opt.border); !why.empty())
            return make_error(Errc::invalid_argument, why);
    }
    for (const LayerInput& l : layers) TESSERA_TRY(check_output_is_not_input(l.input, output));
    std::vector<LayerSource> sources;
    for (const LayerInput& l : layers) {
        auto s = open_image_source(l.input);
        if (!s) return make_error(s.error().code, "layer '" + l.name + "': " + s.error().message);
        sources.push_back(LayerSource{l.name, std::move(*s), l.codec});
    }
    return build_layered_store(std::move(sources), output, opt, progress);
}

Result<BuildSummary> build_layered_store(std::vector<LayerSource> layers, const std::string& output, const BuildOptions& opt,
                                         const BuildProgressFn& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    TESSERA_TRY(validate(opt));
    if (opt.codec)
        return make_error(Errc::invalid_argument, "a layered build takes each layer's codec, not one for the store");
    {
        std::vector<LayerInfo> named;
        for (const LayerSource& l : layers) named.push_back(LayerInfo{l.name, 1, SampleType::u8, ColourSpace::linear, Codec::raw});
        if (const std::string why = layers_misfit(named, opt.tile_size, opt.border); !why.empty())
            return make_error(Errc::invalid_argument, why);
    }
    for (const LayerSource& l : layers)
        if (!l.source) return make_error(Errc::invalid_argument, "layer '" + l.name + "': no source");
    std::vector<std::unique_ptr<ImageSource>> sources;
    for (LayerSource& l : layers) sources.push_back(std::move(l.source));
    const SourceInfo& first = sources.front()->info();
    for (std::size_t i = 1; i < sources.size(); ++i) {
        const SourceInfo& si = sources[i]->info();
        if (si.width != first.width || si.height != first.height)
            return make_error(Errc::invalid_argument, "layer '" + layers[i].name + "' (" + si.description + ") is " +
                                                          size_text(si) + " but layer '" + layers[0].name + "' (" +
                                                          first.description + ") is " + size_text(first) +
                                                          ": every layer must have the same size");
    }

    StoreSpec spec;
    spec.width = first.width;
    spec.height = first.height;
    spec.tile_payload = opt.tile_size - 2 * opt.border;
    spec.border = opt.border;
    spec.codec = Codec::layers;
    bool any_alpha = false;
    for (std::size_t i = 0; i < layers.size(); ++i) {
        const SourceInfo& si = sources[i]->info();
        LayerInfo l;
        l.name = layers[i].name;
        l.channels = si.channels;
        l.sample_type = si.sample_type;
        l.colour_space = opt.colour_space.value_or(si.colour_space);
        l.has_alpha = si.has_alpha;
        l.codec = layers[i].codec.value_or(build::default_codec(si));
        if (l.codec == Codec::layers)
            return make_error(Errc::invalid_argument, "layer '" + l.name + "': codec 'layers' is not a codec for texels");
        if (const std::string misfit = codec_misfit(l.codec, si.sample_type, si.channels, opt.tile_size, opt.border); !misfit.empty())
            return make_error(Errc::invalid_argument, "layer '" + l.name + "', codec " + std::string(to_string(l.codec)) + ": " +
                                                          misfit + "; " + si.description + " has " + std::to_string(si.channels) +
                                                          " channels of " + std::string(to_string(si.sample_type)) +
                                                          " (use --layer " + l.name + ":zstd=...)");
        any_alpha = any_alpha || si.has_alpha;
        spec.layers.push_back(std::move(l));
    }
    if (opt.sparse && !any_alpha)
        return make_error(Errc::invalid_argument, "--sparse needs a layer with an alpha channel; no layer has one");
    const LayerInfo& l0 = spec.layers.front();
    spec.channels = l0.channels;
    spec.sample_type = l0.sample_type;
    spec.colour_space = l0.colour_space;
    spec.has_alpha = l0.has_alpha;
    TESSERA_TRY(validate(spec));

    const StoreInfo store = store_info(spec);
    std::vector<StoreInfo> layer_info;
    for (std::size_t i = 0; i < layers.size(); ++i) layer_info.push_back(layer_store_info(store, i));
    const EncodeOptions enc = build::encode_options(opt);

    auto writer = StoreWriter::create(output, spec);
    if (!writer) return writer.error();

    const unsigned threads = opt.threads ? opt.threads : std::max(1u, std::thread::hardware_concurrency());
    FirstError error;
    BuildProgress prog;
    for (const auto& l : store.levels) prog.tiles_total += std::uint64_t(l.tiles_x) * l.tiles_y * layers.size();
    prog.rows_total = std::uint64_t(first.height) * layers.size();
    std::vector<std::uint64_t> dropped;
    std::uint64_t bytes_dropped = 0;
    {
        ThreadPool pool(threads, 2 * threads + 2);
        BundleJoiner joiner(layers.size(), **writer);
        std::vector<std::unique_ptr<LayerSink>> sinks;
        std::vector<std::unique_ptr<PyramidBuilder>> pyramids;
        std::vector<ImageSource*> source_ptrs;
        std::vector<PyramidBuilder*> pyramid_ptrs;
        for (std::size_t i = 0; i < layers.size(); ++i) {
            // sparse drops a layer's tiles by that layer's alpha; layers without alpha ignore it
            sinks.push_back(std::make_unique<LayerSink>(joiner, i));
            pyramids.push_back(std::make_unique<PyramidBuilder>(layer_info[i], opt, enc, *sinks.back(), pool, error));
            source_ptrs.push_back(sources[i].get());
            pyramid_ptrs.push_back(pyramids.back().get());
        }
        auto tiles_done = [&] {
            std::uint64_t n = 0;
            for (const auto& p : pyramids) n += p->tiles_done();
            return n;
        };
        build::stream_sources(source_ptrs, pyramid_ptrs, pool, error, [&](std::uint64_t rows_done) {
            if (!progress) return;
            prog.rows_done = rows_done;
            prog.tiles_done = tiles_done();
            progress(prog);
        });
        prog.tiles_done = tiles_done();
        if (!error.failed() && joiner.waiting() != 0)
            error.set(make_error(Errc::io_error, "internal error: tiles with parts of only some layers"));
        if (opt.keep) {  // the same tiles are dropped in every layer: count them once, bytes in all
            for (std::size_t l = 0; l < store.levels.size(); ++l) dropped.push_back(pyramids.front()->tiles_dropped(l));
            for (const auto& p : pyramids) bytes_dropped += p->bytes_dropped();
        }
    }
    if (error.failed()) return error.get();  // the writer's destructor removes its temporary files

    return build::finish_build(**writer, output, prog, progress, std::uint64_t(first.width) * first.height * layers.size(),
                               std::move(dropped), bytes_dropped, t0);
}

}  // namespace tessera::storage
