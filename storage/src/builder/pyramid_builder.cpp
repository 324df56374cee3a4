#include "pyramid_builder.hpp"

#include "tessera/storage/store_reader.hpp"

#include <algorithm>
#include <cstring>
#include <memory>
#include <string>

namespace tessera::storage::build {

void FirstError::set(Error e) {
    std::lock_guard lock(mu_);
    if (!error_) error_ = std::move(e);
    failed_.store(true, std::memory_order_relaxed);
}

Error FirstError::get() const {
    std::lock_guard lock(mu_);
    return *error_;
}

const std::uint8_t* PyramidBuilder::Level::row(std::uint32_t y) const {
    for (const Chunk& c : chunks)
        if (y >= c.first && y < c.first + c.count) return c.data.data() + std::size_t(y - c.first) * row_bytes;
    return nullptr;  // unreachable by construction: rows are dropped only when no longer needed
}

PyramidBuilder::PyramidBuilder(const StoreInfo& store, const BuildOptions& opt, const EncodeOptions& enc, TileSink& sink,
                               ThreadPool& pool, FirstError& error)
    : store_(store), opt_(opt), enc_(enc), sink_(sink), pool_(pool), error_(error),
      reducer_(store.channels, store.sample_type, store.colour_space, store.has_alpha), dropped_(store.levels.size()) {
    levels_.resize(store.levels.size());
    for (std::size_t l = 0; l < levels_.size(); ++l) {
        levels_[l].index = static_cast<std::uint32_t>(l);
        levels_[l].geo = store.levels[l];
        levels_[l].row_bytes = std::size_t(store.levels[l].width) * store.texel_bytes();
    }
}

void PyramidBuilder::push(std::uint32_t l, Chunk chunk) {
    Level& L = levels_[l];
    L.received += chunk.count;
    L.chunks.push_back(std::move(chunk));
    if (l + 1 < levels_.size()) downsample(L);
    const std::uint32_t P = store_.tile_payload, B = store_.border;
    while (L.next_tile_row < L.geo.tiles_y &&
           L.received >= std::min<std::uint64_t>(std::uint64_t(L.next_tile_row + 1) * P + B, L.geo.height)) {
        emit_tile_row(L, L.next_tile_row);
        ++L.next_tile_row;
    }
    // Drop the rows neither a future tile row nor a future mip row will read.
    std::int64_t keep = L.received;
    if (L.next_tile_row < L.geo.tiles_y) keep = std::min<std::int64_t>(keep, std::int64_t(L.next_tile_row) * P - B);
    if (l + 1 < levels_.size()) keep = std::min<std::int64_t>(keep, std::int64_t(L.next_down_row) * 2);
    while (!L.chunks.empty() && std::int64_t(L.chunks.front().first + L.chunks.front().count) <= keep) L.chunks.pop_front();
}

bool PyramidBuilder::complete() const {
    for (const Level& L : levels_)
        if (L.received != L.geo.height || L.next_tile_row != L.geo.tiles_y) return false;
    return true;
}

void PyramidBuilder::downsample(Level& L) {
    Level& N = levels_[L.index + 1];
    std::uint32_t end = L.next_down_row;
    while (end < N.geo.height && (2 * end + 1 < L.received || (L.received == L.geo.height && 2 * end < L.received))) ++end;
    if (end == L.next_down_row) return;
    Chunk out;
    out.first = L.next_down_row;
    out.count = end - L.next_down_row;
    out.data.resize(std::size_t(out.count) * N.row_bytes);
    pool_.parallel_for(out.count, 4, [&](std::size_t b, std::size_t e) {
        for (std::size_t i = b; i < e; ++i) {
            const std::uint32_t y = out.first + static_cast<std::uint32_t>(i);
            const std::uint8_t* r0 = L.row(2 * y);
            const std::uint8_t* r1 = L.row(std::min(2 * y + 1, L.geo.height - 1));
            reducer_.reduce(r0, r1, L.geo.width, out.data.data() + i * N.row_bytes);
        }
    });
    L.next_down_row = end;
    push(N.index, std::move(out));
}

void PyramidBuilder::emit_tile_row(const Level& L, std::uint32_t ty) {
    const std::uint32_t P = store_.tile_payload, B = store_.border, T = store_.tile_size();
    const std::size_t tb = store_.texel_bytes();
    const std::int64_t w = L.geo.width, h = L.geo.height;
    for (std::uint32_t tx = 0; tx < L.geo.tiles_x; ++tx) {
        if (error_.failed()) return;
        auto tile = std::make_shared<std::vector<std::uint8_t>>(store_.tile_bytes());
        const std::int64_t x0 = std::int64_t(tx) * P - B;
        // Columns [x0, x0 + T) split into a clamped left run, a copied middle, a clamped right run.
        const std::int64_t mid_b = std::clamp<std::int64_t>(x0, 0, w), mid_e = std::clamp<std::int64_t>(x0 + T, 0, w);
        for (std::uint32_t j = 0; j < T; ++j) {
            const std::int64_t sy = std::clamp<std::int64_t>(std::int64_t(ty) * P - B + j, 0, h - 1);
            const std::uint8_t* src = L.row(static_cast<std::uint32_t>(sy));
            std::uint8_t* dst = tile->data() + std::size_t(j) * T * tb;
            std::int64_t x = x0;
            for (; x < mid_b; ++x, dst += tb) std::memcpy(dst, src, tb);
            if (mid_e > mid_b) {
                std::memcpy(dst, src + mid_b * tb, std::size_t(mid_e - mid_b) * tb);
                dst += std::size_t(mid_e - mid_b) * tb;
                x = mid_e;
            }
            for (; x < x0 + T; ++x, dst += tb) std::memcpy(dst, src + (w - 1) * tb, tb);
        }
        const TileKey key{L.index, tx, ty};
        pool_.submit([this, key, tile] { finish_tile(key, *tile); });
    }
}

// Worker side: classify (absent / uniform / present), encode, hand to the sink.
void PyramidBuilder::finish_tile(const TileKey& key, const std::vector<std::uint8_t>& t) {
    if (error_.failed()) return;
    const std::size_t tb = store_.texel_bytes();
    Status st;
    if (opt_.keep && !opt_.keep(key.level, key.x, key.y)) {
        // dropped by the caller's mask: absent; its encoded size is what it saves
        if (!(opt_.sparse && store_.has_alpha && alpha_all_zero(t)) && !all_equal(t, tb)) {
            auto payload = encode_tile(store_, t, enc_);
            if (!payload) st = payload.error();
            else bytes_dropped_.fetch_add(payload->size(), std::memory_order_relaxed);
        }
        dropped_[key.level].fetch_add(1, std::memory_order_relaxed);
        if (st) st = sink_.absent(key);
    } else if (opt_.sparse && store_.has_alpha && alpha_all_zero(t)) {
        st = sink_.absent(key);
    } else if (all_equal(t, tb)) {
        st = sink_.uniform(key, std::span<const std::uint8_t>(t.data(), tb));
    } else {
        auto payload = encode_tile(store_, t, enc_);
        if (!payload) st = payload.error();
        else st = sink_.present(key, std::move(*payload));
    }
    if (!st) error_.set(st.error());
    tiles_done_.fetch_add(1, std::memory_order_relaxed);
}

bool PyramidBuilder::all_equal(const std::vector<std::uint8_t>& t, std::size_t tb) { return tile_all_equal(t, tb); }

bool PyramidBuilder::alpha_all_zero(const std::vector<std::uint8_t>& t) const { return tile_alpha_all_zero(store_, t); }

bool tile_all_equal(std::span<const std::uint8_t> t, std::size_t tb) {
    for (std::size_t i = tb; i < t.size(); i += tb)
        if (std::memcmp(t.data(), t.data() + i, tb) != 0) return false;
    return true;
}

bool tile_alpha_all_zero(const StoreInfo& store, std::span<const std::uint8_t> t) {
    const std::size_t sb = sample_bytes(store.sample_type), tb = store.texel_bytes();
    for (std::size_t i = tb - sb; i < t.size(); i += tb)
        for (std::size_t k = 0; k < sb; ++k)
            if (t[i + k] != 0) return false;  // +0 only; any other bits mean coverage
    return true;
}

EncodeOptions encode_options(const BuildOptions& opt) {
    EncodeOptions enc;
    enc.jpeg_quality = opt.quality;
    enc.chroma = opt.chroma.value_or(opt.quality >= 90 ? Chroma::s444 : Chroma::s420);
    enc.zstd_level = opt.zstd_level;
    enc.bc7_effort = opt.bc7_effort;
    return enc;
}

Codec default_codec(const SourceInfo& si) {
    return si.sample_type == SampleType::u8 && (si.channels == 1 || si.channels == 3) ? Codec::jpeg : Codec::zstd;
}

Result<StoreSpec> store_spec(const SourceInfo& si, const BuildOptions& opt, bool sparse_index) {
    StoreSpec spec;
    spec.sparse_index = sparse_index;  // before validate: a dense index's size is bounded, a sparse one's is not
    spec.width = si.width;
    spec.height = si.height;
    spec.tile_payload = opt.tile_size - 2 * opt.border;
    spec.border = opt.border;
    spec.channels = si.channels;
    spec.sample_type = si.sample_type;
    spec.colour_space = opt.colour_space.value_or(si.colour_space);
    spec.has_alpha = si.has_alpha;
    spec.codec = opt.codec.value_or(default_codec(si));
    if (const std::string misfit = codec_misfit(spec.codec, si.sample_type, si.channels, opt.tile_size, opt.border);
        !misfit.empty())
        return make_error(Errc::invalid_argument, "--codec " + std::string(to_string(spec.codec)) + ": " + misfit + "; " +
                                                      si.description + " has " + std::to_string(si.channels) + " channels of " +
                                                      std::string(to_string(si.sample_type)) + " (use --codec zstd)");
    TESSERA_TRY(validate(spec));
    return spec;
}

void stream_sources(std::span<ImageSource* const> sources, std::span<PyramidBuilder* const> pyramids, ThreadPool& pool,
                    FirstError& error, const std::function<void(std::uint64_t rows_done)>& on_strip) {
    const ParallelFor parallel = [&pool](std::size_t n, const std::function<void(std::size_t, std::size_t)>& fn) {
        pool.parallel_for(n, 1, fn);
    };
    // Small strips keep the rows held per level near the minimum (one tile row plus borders).
    const std::uint32_t strip = 64;
    const std::uint32_t height = sources.front()->info().height;
    std::uint64_t rows_done = 0;
    for (std::uint32_t y = 0; y < height && !error.failed(); y += strip) {
        for (std::size_t s = 0; s < sources.size() && !error.failed(); ++s) {
            Chunk c;
            c.first = y;
            c.count = std::min(strip, height - y);
            c.data.resize(std::size_t(c.count) * pyramids[s]->row_bytes0());
            Status st = sources[s]->read_rows(y, c.count, c.data.data(), parallel);
            if (!st) {
                error.set(st.error());
                break;
            }
            rows_done += c.count;
            pyramids[s]->push(0, std::move(c));
        }
        if (on_strip && !error.failed()) on_strip(rows_done);
    }
    pool.wait_idle();
    if (!error.failed())
        for (const PyramidBuilder* p : pyramids)
            if (!p->complete()) {
                error.set(make_error(Errc::io_error, "internal error: pyramid incomplete"));
                break;
            }
}

Result<BuildSummary> finish_build(StoreWriter& writer, const std::string& output, BuildProgress& prog,
                                  const BuildProgressFn& progress, std::uint64_t source_texels,
                                  std::vector<std::uint64_t> tiles_dropped, std::uint64_t bytes_dropped,
                                  std::chrono::steady_clock::time_point started) {
    prog.writing = true;
    TESSERA_TRY(writer.finish([&](std::uint64_t done, std::uint64_t total) {
        if (!progress) return;
        prog.bytes_written = done;
        prog.bytes_total = total;
        progress(prog);
    }));
    auto reader = StoreReader::open(output);
    if (!reader) return reader.error();
    BuildSummary summary;
    summary.info = (*reader)->info();
    summary.source_texels = source_texels;
    summary.tiles_dropped = std::move(tiles_dropped);
    summary.bytes_dropped = bytes_dropped;
    summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
    return summary;
}

}  // namespace tessera::storage::build
