// Sparse stores: a source with data in a few regions of a texture too large to stream row by row
// (planet-scale imagery is mostly ocean or no data). Only the present tiles are made, encoded and
// written; build time and memory follow them, not the texture's area.
#include <algorithm>
#include <charconv>
#include <chrono>
#include <set>
#include <string_view>
#include <thread>
#include <utility>

#include "pyramid_builder.hpp"
#include "tessera/storage/builder.hpp"
#include "tessera/storage/coords_pattern.hpp"
#include "tessera/storage/image_source.hpp"
#include "tessera/storage/store_writer.hpp"
#include "thread_pool.hpp"

namespace tessera::storage {
namespace {

constexpr std::string_view kCoordsSparse = "procedural:coords-sparse:";
// Present around each anchor: this many level texels on each side, at every level.
constexpr std::int64_t kWindow = 256;

// The present tiles of each level of procedural:coords-sparse: windows of 2 kWindow level texels
// around the level's four corners and its centre. Each window holds the next finer level's
// windows over it, so every present tile's parent is present.
std::vector<std::vector<TileKey>> coords_sparse_tiles(const StoreInfo& info) {
    std::vector<std::vector<TileKey>> tiles(info.level_count());
    for (std::uint32_t l = 0; l < info.level_count(); ++l) {
        const LevelInfo& L = info.levels[l];
        const std::int64_t w = L.width, h = L.height, P = info.tile_payload;
        const std::pair<std::int64_t, std::int64_t> anchors[] = {{0, 0}, {w - 1, 0}, {0, h - 1}, {w - 1, h - 1}, {w / 2, h / 2}};
        std::set<std::pair<std::uint32_t, std::uint32_t>> keys;  // (y, x): row-major order
        for (const auto& [ax, ay] : anchors) {
            const auto first = [&](std::int64_t a, std::int64_t n) { return std::clamp<std::int64_t>(a - kWindow, 0, n - 1) / P; };
            const auto last = [&](std::int64_t a, std::int64_t n) { return std::clamp<std::int64_t>(a + kWindow, 0, n - 1) / P; };
            for (std::int64_t ty = first(ay, h); ty <= last(ay, h); ++ty)
                for (std::int64_t tx = first(ax, w); tx <= last(ax, w); ++tx) keys.emplace(std::uint32_t(ty), std::uint32_t(tx));
        }
        for (const auto& [y, x] : keys) tiles[l].push_back(TileKey{l, x, y});
    }
    return tiles;
}

}  // namespace

bool is_sparse_input(const std::string& input) { return input.rfind(kCoordsSparse, 0) == 0; }

Result<BuildSummary> build_sparse_store(const std::string& input, const std::string& output, const BuildOptions& opt,
                                        const BuildProgressFn& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    TESSERA_TRY(validate(opt));
    const std::string usage = " (expected procedural:coords-sparse:SIZE, SIZE 1 to " + std::to_string(kMaxProceduralSize) + ")";
    if (!is_sparse_input(input)) return make_error(Errc::invalid_argument, "'" + input + "' is not a sparse source" + usage);
    const std::string_view digits = std::string_view(input).substr(kCoordsSparse.size());
    std::uint64_t size = 0;
    const auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), size);
    if (digits.empty() || ec != std::errc() || end != digits.data() + digits.size() || size < 1 || size > kMaxProceduralSize)
        return make_error(Errc::invalid_argument, "'" + input + "': bad size" + usage);
    if (opt.keep || opt.sparse)
        return make_error(Errc::invalid_argument, "--visibility and --sparse do not apply to a sparse source (its absent tiles are its own)");

    StoreSpec spec;
    spec.width = spec.height = std::uint32_t(size);
    spec.tile_payload = opt.tile_size - 2 * opt.border;
    spec.border = opt.border;
    spec.channels = 4;
    spec.sample_type = SampleType::u8;
    spec.colour_space = opt.colour_space.value_or(ColourSpace::linear);
    spec.codec = opt.codec.value_or(Codec::zstd);
    spec.sparse_index = true;  // block tables of the few non-empty blocks: the index follows the present tiles
    if (const std::string misfit = codec_misfit(spec.codec, spec.sample_type, spec.channels, opt.tile_size, opt.border); !misfit.empty())
        return make_error(Errc::invalid_argument, "--codec " + std::string(to_string(spec.codec)) + ": " + misfit +
                                                      "; the coords pattern is 4 channels of u8 (use --codec zstd)");
    TESSERA_TRY(validate(spec));
    const StoreInfo store = store_info(spec);
    const auto tiles = coords_sparse_tiles(store);

    auto writer = StoreWriter::create(output, spec);
    if (!writer) return writer.error();
    const EncodeOptions enc = build::encode_options(opt);
    const unsigned threads = opt.threads ? opt.threads : std::max(1u, std::thread::hardware_concurrency());
    build::FirstError error;
    BuildProgress prog;
    for (const auto& l : tiles) prog.tiles_total += l.size();
    std::atomic<std::uint64_t> done{0};
    {
        build::ThreadPool pool(threads, 2 * threads + 2);
        for (const auto& level : tiles)
            for (const TileKey& key : level) {
                if (error.failed()) break;
                pool.submit([&, key] {
                    if (error.failed()) return;
                    std::vector<std::uint8_t> texels(std::size_t(store.tile_size()) * store.tile_size() * 4);
                    coords_tile(store, key, texels);
                    auto payload = encode_tile(store, texels, enc);
                    Status st = payload ? (*writer)->add_present(key, *payload) : Status(payload.error());
                    if (!st) error.set(st.error());
                    done.fetch_add(1, std::memory_order_relaxed);
                });
                if (const std::uint64_t now = done.load(std::memory_order_relaxed); progress && now >= prog.tiles_done + 64) {
                    prog.tiles_done = now;
                    progress(prog);
                }
            }
        pool.wait_idle();
    }
    if (error.failed()) return error.get();  // the writer's destructor removes its temporary files
    prog.tiles_done = done.load();
    prog.rows_total = prog.rows_done = 0;
    const std::uint64_t texels = std::uint64_t(tiles[0].size()) * store.tile_payload * store.tile_payload;  // at most
    return build::finish_build(**writer, output, prog, progress, texels, {}, 0, t0);
}

}  // namespace tessera::storage
