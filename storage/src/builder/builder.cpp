#include "tessera/storage/builder.hpp"

#include <algorithm>
#include <chrono>
#include <memory>
#include <thread>

#include "pyramid_builder.hpp"
#include "sources_internal.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/store_writer.hpp"
#include "thread_pool.hpp"

namespace tessera::storage {
namespace {

using build::FirstError;
using build::PyramidBuilder;
using build::ThreadPool;

// A single-layer build's tiles go straight to the store writer; absent tiles are not written.
class WriterSink final : public build::TileSink {
public:
    explicit WriterSink(StoreWriter& w) : w_(w) {}
    Status present(const TileKey& key, std::vector<std::uint8_t> payload) override { return w_.add_present(key, payload); }
    Status uniform(const TileKey& key, std::span<const std::uint8_t> value) override { return w_.add_uniform(key, value); }
    Status absent(const TileKey&) override { return {}; }

private:
    StoreWriter& w_;
};

bool is_pow2(std::uint32_t v) { return v && !(v & (v - 1)); }

}  // namespace

Status validate(const BuildOptions& o) {
    if (!is_pow2(o.tile_size) || o.tile_size < 64 || o.tile_size > 1024)
        return make_error(Errc::invalid_argument, "--tile-size must be a power of two from 64 to 1024, got " + std::to_string(o.tile_size));
    if (o.border % 2 != 0)
        return make_error(Errc::invalid_argument, "--border must be even, got " + std::to_string(o.border));
    if (o.border > o.tile_size / 4)
        return make_error(Errc::invalid_argument, "--border must be at most a quarter of the tile size (" +
                                                      std::to_string(o.tile_size / 4) + "), got " + std::to_string(o.border));
    if (o.quality < 1 || o.quality > 100)
        return make_error(Errc::invalid_argument, "--quality must be 1 to 100, got " + std::to_string(o.quality));
    if (o.bc7_effort < 0 || o.bc7_effort > 3)
        return make_error(Errc::invalid_argument, "--bc7-effort must be 0 to 3, got " + std::to_string(o.bc7_effort));
    if (o.zstd_level < 1 || o.zstd_level > 19)
        return make_error(Errc::invalid_argument, "--zstd-level must be 1 to 19, got " + std::to_string(o.zstd_level));
    if (o.threads > 1024) return make_error(Errc::invalid_argument, "--threads must be at most 1024");
    return {};
}

Result<BuildSummary> build_store(ImageSource& source, const std::string& output, const BuildOptions& opt,
                                 const BuildProgressFn& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    TESSERA_TRY(validate(opt));
    const SourceInfo& si = source.info();
    if (opt.sparse && !si.has_alpha)
        return make_error(Errc::invalid_argument, "--sparse needs a source with an alpha channel; " + si.description + " has none");

    auto made_spec = build::store_spec(si, opt);
    if (!made_spec) return made_spec.error();
    const StoreSpec spec = *made_spec;

    const StoreInfo store = store_info(spec);

    const EncodeOptions enc = build::encode_options(opt);

    auto writer = StoreWriter::create(output, spec);
    if (!writer) return writer.error();

    const unsigned threads = opt.threads ? opt.threads : std::max(1u, std::thread::hardware_concurrency());
    FirstError error;
    BuildProgress prog;
    for (const auto& l : store.levels) prog.tiles_total += std::uint64_t(l.tiles_x) * l.tiles_y;
    prog.rows_total = si.height;
    std::vector<std::uint64_t> dropped;
    std::uint64_t bytes_dropped = 0;
    {
        ThreadPool pool(threads, 2 * threads + 2);
        WriterSink sink(**writer);
        PyramidBuilder pyramid(store, opt, enc, sink, pool, error);
        ImageSource* const sources[] = {&source};
        PyramidBuilder* const pyramids[] = {&pyramid};
        build::stream_sources(sources, pyramids, pool, error, [&](std::uint64_t rows_done) {
            if (!progress) return;
            prog.rows_done = rows_done;
            prog.tiles_done = pyramid.tiles_done();
            progress(prog);
        });
        prog.tiles_done = pyramid.tiles_done();
        if (opt.keep) {
            for (std::size_t l = 0; l < store.levels.size(); ++l) dropped.push_back(pyramid.tiles_dropped(l));
            bytes_dropped = pyramid.bytes_dropped();
        }
    }
    if (error.failed()) return error.get();  // the writer's destructor removes its temporary files

    return build::finish_build(**writer, output, prog, progress, std::uint64_t(si.width) * si.height, std::move(dropped),
                               bytes_dropped, t0);
}

Result<BuildSummary> build_store(const std::string& input, const std::string& output, const BuildOptions& opt,
                                 const BuildProgressFn& progress) {
    TESSERA_TRY(validate(opt));
    TESSERA_TRY(check_output_is_not_input(input, output));
    auto source = open_image_source(input);
    if (!source) return source.error();
    return build_store(**source, output, opt, progress);
}

}  // namespace tessera::storage
