// Sparse stores: a source with data in a few regions of a texture too large to stream row by row
// (planet-scale imagery is mostly ocean or no data). Only the tiles that meet the data are made,
// encoded and written; build time and memory follow them, not the texture's area.
//
// Two kinds of sparse source:
//  - a SparseSource (tessera/storage/sparse_source.hpp: a mosaic manifest, or an application's
//    own): level 0 comes from the source, region by region; every coarser level is reduced from
//    the level below with the dense builder's MipReducer, tile by tile ("the tile-driven build"
//    below), so the store holds the same tiles a dense `--sparse` build of the whole canvas would;
//  - the test pattern procedural:coords-sparse, which defines every level itself (coords_texel at
//    level-L coordinates, so a viewer's texel at any level can be checked exactly).
#include <algorithm>
#include <charconv>
#include <chrono>
#include <cstring>
#include <memory>
#include <mutex>
#include <set>
#include <string_view>
#include <thread>
#include <unordered_map>
#include <utility>

#include "mip_reducer.hpp"
#include "pyramid_builder.hpp"
#include "sources_internal.hpp"
#include "tessera/storage/builder.hpp"
#include "tessera/storage/coords_pattern.hpp"
#include "tessera/storage/image_source.hpp"
#include "tessera/storage/sparse_source.hpp"
#include "tessera/storage/store_writer.hpp"
#include "temp_file.hpp"
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

bool is_mosaic(const std::string& input) { return input.size() > 5 && input.compare(input.size() - 5, 5, ".json") == 0; }

Result<BuildSummary> build_coords_sparse(const std::string& input, const std::string& output, const BuildOptions& opt,
                                         const BuildProgressFn& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    const std::string usage = " (expected procedural:coords-sparse:SIZE, SIZE 1 to " + std::to_string(kMaxProceduralSize) + ")";
    const std::string_view digits = std::string_view(input).substr(kCoordsSparse.size());
    std::uint64_t size = 0;
    const auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), size);
    if (digits.empty() || ec != std::errc() || end != digits.data() + digits.size() || size < 1 || size > kMaxProceduralSize)
        return make_error(Errc::invalid_argument, "'" + input + "': bad size" + usage);
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

}  // namespace

// ---- the tile-driven build of a SparseSource ------------------------------------------------------
//
// Level by level, finest first. A level's tiles whose payload square meets the data (the present
// rectangles, scaled to the level) get their payload texels, the "core" (P x P): at level 0 read
// from the source, at level L+1 reduced from the four children's cores by the MipReducer (a
// missing child is transparent). Cores with any non-zero alpha are kept in a spool file (only an
// index of them in memory). Then every tile whose bordered square meets the data is cut from the
// cores of itself and its eight neighbours (clamped at the level's edges, as the dense builder
// cuts), classified as the dense builder does (alpha 0 everywhere: absent; one value: uniform;
// else present), encoded and written. Memory: a few tiles per thread and the index of two levels'
// cores; disk: two levels' cores.
namespace {

std::uint64_t xy_key(std::uint64_t x, std::uint64_t y) { return (y << 32) | x; }

// Tiles of a level (row-major keys, sorted, unique) whose texels [tx P - m, tx P + P + m) x (same
// in y) meet a present rectangle scaled to the level: m = 0, the payload; m = B, the whole tile.
std::vector<std::uint64_t> tiles_meeting(const std::vector<SparseRect>& rects, std::uint32_t level, const LevelInfo& geo,
                                         std::uint32_t P, std::uint32_t m) {
    std::vector<std::uint64_t> keys;
    for (const SparseRect& r : rects) {
        if (r.width == 0 || r.height == 0) continue;
        const std::uint64_t s = std::uint64_t(1) << level;
        const std::uint64_t x0 = r.x >> level, x1 = (std::uint64_t(r.x) + r.width + s - 1) >> level;  // level texels [x0, x1)
        const std::uint64_t y0 = r.y >> level, y1 = (std::uint64_t(r.y) + r.height + s - 1) >> level;
        const std::uint64_t tx0 = x0 > m ? (x0 - m) / P : 0, tx1 = std::min<std::uint64_t>(geo.tiles_x - 1, (x1 - 1 + m) / P);
        const std::uint64_t ty0 = y0 > m ? (y0 - m) / P : 0, ty1 = std::min<std::uint64_t>(geo.tiles_y - 1, (y1 - 1 + m) / P);
        for (std::uint64_t ty = ty0; ty <= ty1; ++ty)
            for (std::uint64_t tx = tx0; tx <= tx1; ++tx) keys.push_back(xy_key(tx, ty));
    }
    std::sort(keys.begin(), keys.end());
    keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
    return keys;
}

// One level's cores with data, in a spool file beside the output.
class Cores {
public:
    static Result<Cores> create(const std::string& output, std::size_t core_bytes) {
        auto f = TempFile::create_beside(output, "cores");
        if (!f) return f.error();
        return Cores(std::move(*f), core_bytes);
    }
    // Stores core `slot` (distinct slots from any threads).
    Status put(std::uint64_t key, std::uint64_t slot, std::span<const std::uint8_t> core) {
        TESSERA_TRY(file_.pwrite_all(slot * core_bytes_, core));
        std::lock_guard lock(*mu_);
        slots_.emplace(key, slot);
        return {};
    }
    // Core `key` into `out`; false (and `out` untouched) when the tile has no data.
    Result<bool> get(std::uint64_t key, std::span<std::uint8_t> out) const {
        const auto it = slots_.find(key);
        if (it == slots_.end()) return false;
        TESSERA_TRY(file_.pread_all(it->second * core_bytes_, out));
        return true;
    }
    std::size_t size() const { return slots_.size(); }

private:
    Cores(TempFile f, std::size_t core_bytes) : file_(std::move(f)), core_bytes_(core_bytes) {}
    TempFile file_;
    std::size_t core_bytes_;
    std::unique_ptr<std::mutex> mu_ = std::make_unique<std::mutex>();  // (movable)
    std::unordered_map<std::uint64_t, std::uint64_t> slots_;
};

bool any_alpha(std::span<const std::uint8_t> texels, std::size_t tb, std::size_t sb) {
    for (std::size_t i = tb - sb; i < texels.size(); i += tb)
        for (std::size_t k = 0; k < sb; ++k)
            if (texels[i + k] != 0) return true;
    return false;
}

}  // namespace

Result<BuildSummary> build_sparse_store(const SparseSource& source, const std::string& output, const BuildOptions& opt,
                                        const BuildProgressFn& progress) {
    const auto t0 = std::chrono::steady_clock::now();
    TESSERA_TRY(validate(opt));
    if (opt.keep || opt.sparse)
        return make_error(Errc::invalid_argument, "--visibility and --sparse do not apply to a sparse source (its absent tiles are its own)");
    const SourceInfo& si = source.info();
    if (!si.has_alpha || (si.channels != 2 && si.channels != 4))
        return make_error(Errc::invalid_argument, si.description + ": a sparse source needs an alpha channel (its absent texels are transparent)");
    for (const SparseRect& r : source.present())
        if (std::uint64_t(r.x) + r.width > si.width || std::uint64_t(r.y) + r.height > si.height)
            return make_error(Errc::invalid_argument, si.description + ": a present rectangle lies outside the canvas");

    // Block tables of the non-empty blocks only: the index follows the data, so a canvas of any
    // size the format allows (2^32 - 1 a side) is not refused for the dense tables it would need.
    auto made_spec = build::store_spec(si, opt, /*sparse_index=*/true);  // has_alpha: checked above
    if (!made_spec) return made_spec.error();
    const StoreSpec spec = *made_spec;
    const StoreInfo store = store_info(spec);
    const std::uint32_t P = store.tile_payload, B = store.border, T = store.tile_size();
    const std::size_t sb = sample_bytes(store.sample_type), tb = store.texel_bytes(), core_bytes = std::size_t(P) * P * tb;
    const std::uint32_t nlevels = store.level_count();

    // Every level's tiles to cut (the progress total), computed once: proportional to the data.
    std::vector<std::vector<std::uint64_t>> emit(nlevels);
    BuildProgress prog;
    for (std::uint32_t l = 0; l < nlevels; ++l) {
        emit[l] = tiles_meeting(source.present(), l, store.levels[l], P, B);
        prog.tiles_total += emit[l].size();
    }
    std::uint64_t texels = 0;
    for (const SparseRect& r : source.present()) texels += std::uint64_t(r.width) * r.height;

    auto writer = StoreWriter::create(output, spec);
    if (!writer) return writer.error();
    const EncodeOptions enc = build::encode_options(opt);
    const build::MipReducer reducer(store.channels, store.sample_type, store.colour_space, true);
    const unsigned threads = opt.threads ? opt.threads : std::max(1u, std::thread::hardware_concurrency());
    build::FirstError error;
    std::atomic<std::uint64_t> done{0};
    auto report = [&] {
        if (!progress) return;
        prog.tiles_done = done.load(std::memory_order_relaxed);
        progress(prog);
    };
    {
        build::ThreadPool pool(threads, 2 * threads + 2);
        std::unique_ptr<Cores> cores;  // the current level's
        for (std::uint32_t l = 0; l < nlevels && !error.failed(); ++l) {
            const LevelInfo& geo = store.levels[l];
            auto made = Cores::create(output, core_bytes);
            if (!made) return made.error();
            Cores next = std::move(*made);
            // 1. This level's cores: from the source (level 0) or from the children's cores.
            const std::vector<std::uint64_t> core_keys = tiles_meeting(source.present(), l, geo, P, 0);
            for (std::size_t slot = 0; slot < core_keys.size() && !error.failed(); ++slot)
                pool.submit([&, slot] {
                    if (error.failed()) return;
                    const std::uint32_t tx = std::uint32_t(core_keys[slot]), ty = std::uint32_t(core_keys[slot] >> 32);
                    const std::uint32_t cw = std::min(P, geo.width - tx * P), ch = std::min(P, geo.height - ty * P);
                    std::vector<std::uint8_t> core(core_bytes, 0);
                    if (l == 0) {
                        std::vector<std::uint8_t> region(std::size_t(cw) * ch * tb);
                        if (Status st = source.read_region(SparseRect{tx * P, ty * P, cw, ch}, region); !st) return error.set(st.error());
                        for (std::uint32_t j = 0; j < ch; ++j)
                            std::memcpy(core.data() + std::size_t(j) * P * tb, region.data() + std::size_t(j) * cw * tb, std::size_t(cw) * tb);
                    } else {
                        // The four children's cores side by side (2P x 2P, transparent where absent).
                        const LevelInfo& below = store.levels[l - 1];
                        std::vector<std::uint8_t> quad(4 * core_bytes, 0), child(core_bytes);
                        for (std::uint32_t q = 0; q < 4; ++q) {
                            const std::uint64_t cx = 2ull * tx + (q & 1), cy = 2ull * ty + (q >> 1);
                            auto got = cores->get(xy_key(cx, cy), child);
                            if (!got) return error.set(got.error());
                            if (!*got) continue;
                            for (std::uint32_t j = 0; j < P; ++j)
                                std::memcpy(quad.data() + (std::size_t((q >> 1) * P + j) * 2 * P + (q & 1) * P) * tb,
                                            child.data() + std::size_t(j) * P * tb, std::size_t(P) * tb);
                        }
                        // Rows 2y and 2y + 1 of the level below (clamped to it), as the dense builder reduces.
                        const std::uint32_t in_w = std::min(2 * P, below.width - 2 * tx * P);
                        for (std::uint32_t j = 0; j < ch; ++j) {
                            const std::uint32_t y0 = 2 * (ty * P + j), y1 = std::min(y0 + 1, below.height - 1);
                            const std::uint8_t* r0 = quad.data() + std::size_t(y0 - 2 * ty * P) * 2 * P * tb;
                            const std::uint8_t* r1 = quad.data() + std::size_t(y1 - 2 * ty * P) * 2 * P * tb;
                            reducer.reduce(r0, r1, in_w, core.data() + std::size_t(j) * P * tb);
                        }
                    }
                    if (!any_alpha(core, tb, sb)) return;  // transparent: as if absent
                    if (Status st = next.put(core_keys[slot], slot, core); !st) error.set(st.error());
                });
            pool.wait_idle();
            cores.reset();  // the level below's spool goes
            cores = std::make_unique<Cores>(std::move(next));
            if (error.failed()) break;
            // 2. This level's tiles, cut from the cores of each tile and its neighbours.
            for (const std::uint64_t key : emit[l]) {
                if (error.failed()) break;
                pool.submit([&, key] {
                    if (error.failed()) return;
                    const std::uint32_t tx = std::uint32_t(key), ty = std::uint32_t(key >> 32);
                    std::vector<std::uint8_t> near(9 * core_bytes);
                    bool have[9];
                    for (std::int64_t dy = -1; dy <= 1; ++dy)
                        for (std::int64_t dx = -1; dx <= 1; ++dx) {
                            const std::int64_t nx = std::int64_t(tx) + dx, ny = std::int64_t(ty) + dy;
                            const std::size_t k = std::size_t((dy + 1) * 3 + (dx + 1));
                            have[k] = false;
                            if (nx < 0 || ny < 0 || nx >= geo.tiles_x || ny >= geo.tiles_y) continue;
                            auto got = cores->get(xy_key(std::uint64_t(nx), std::uint64_t(ny)),
                                                  std::span<std::uint8_t>(near.data() + k * core_bytes, core_bytes));
                            if (!got) return error.set(got.error());
                            have[k] = *got;
                        }
                    std::vector<std::uint8_t> tile(store.tile_bytes(), 0);
                    const std::int64_t w = geo.width, h = geo.height;
                    for (std::uint32_t j = 0; j < T; ++j) {
                        const std::int64_t gy = std::clamp<std::int64_t>(std::int64_t(ty) * P - B + j, 0, h - 1);
                        const std::int64_t ky = gy / P - ty + 1;  // 0..2: the neighbour row
                        for (std::uint32_t i = 0; i < T; ++i) {
                            const std::int64_t gx = std::clamp<std::int64_t>(std::int64_t(tx) * P - B + i, 0, w - 1);
                            const std::size_t k = std::size_t(ky * 3 + (gx / P - tx + 1));
                            if (!have[k]) continue;  // transparent
                            std::memcpy(tile.data() + (std::size_t(j) * T + i) * tb,
                                        near.data() + k * core_bytes + (std::size_t(gy % P) * P + std::size_t(gx % P)) * tb, tb);
                        }
                    }
                    const TileKey tk{l, tx, ty};
                    Status st;
                    if (build::tile_alpha_all_zero(store, tile)) {
                        // absent, as a dense --sparse build makes it
                    } else if (build::tile_all_equal(tile, tb)) {
                        st = (*writer)->add_uniform(tk, std::span<const std::uint8_t>(tile.data(), tb));
                    } else {
                        auto payload = encode_tile(store, tile, enc);
                        st = payload ? (*writer)->add_present(tk, *payload) : Status(payload.error());
                    }
                    if (!st) error.set(st.error());
                    done.fetch_add(1, std::memory_order_relaxed);
                });
                if ((done.load(std::memory_order_relaxed) & 255) == 0) report();
            }
            pool.wait_idle();
            report();
        }
    }
    if (error.failed()) return error.get();  // the writer's destructor removes its temporary files
    prog.tiles_done = done.load();
    return build::finish_build(**writer, output, prog, progress, texels, {}, 0, t0);
}

bool is_sparse_input(const std::string& input) { return input.rfind(kCoordsSparse, 0) == 0 || is_mosaic(input); }

Result<BuildSummary> build_sparse_store(const std::string& input, const std::string& output, const BuildOptions& opt,
                                        const BuildProgressFn& progress) {
    TESSERA_TRY(validate(opt));
    if (opt.keep || opt.sparse)
        return make_error(Errc::invalid_argument, "--visibility and --sparse do not apply to a sparse source (its absent tiles are its own)");
    if (input.rfind(kCoordsSparse, 0) == 0) return build_coords_sparse(input, output, opt, progress);
    if (!is_mosaic(input))
        return make_error(Errc::invalid_argument, "'" + input + "' is not a sparse source (expected procedural:coords-sparse:SIZE "
                                                  "or a mosaic manifest, FILE.json)");
    TESSERA_TRY(check_output_is_not_input(input, output));
    auto source = open_mosaic_source(input);
    if (!source) return source.error();
    return build_sparse_store(**source, output, opt, progress);
}

}  // namespace tessera::storage
