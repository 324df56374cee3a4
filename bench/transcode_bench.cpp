// Transcode throughput against libjpeg-turbo's own decode speed, the transcode ceiling
// (docs/benchmarks.md). Loads every present tile of a JPEG store (and optionally a zstd store) into
// memory, then times, on the same tiles, interleaved over several rounds:
//   libjpeg RGB    tjDecompress2 to RGB, one thread: libjpeg-turbo's own speed, the ceiling
//   libjpeg RGBA   tjDecompress2 to RGBA, one thread (the same decode, our output format)
//   transcode      client::transcode_to_rgba8, one thread
//   pool xN        client::TranscodePool with N workers, end to end (submit, decode, poll)
// and for zstd: ZSTD_decompressDCtx alone (the ceiling), transcode (decompress + RGBA8 expand),
// and the pool; for a block-codec store (--blocks: `tessera build --codec bc1|bc4|bc5|bc7`): zstd
// alone (the ceiling), the client's unpack of a page and its second level into its own pool format
// (transcode_page: no decode, no encode) and the decode to RGBA8. Every decode writes into a ring of page-sized staging slots (as an upload ring),
// not one hot buffer. Prints a table; JSON with --json FILE. Target: transcode >= 0.9x libjpeg RGB.
//
//   tessera build procedural:terrain:4096 --codec jpeg -o terrain-jpeg.tsr
//   tessera build procedural:terrain:4096 --codec zstd -o terrain-zstd.tsr
//   tessera build procedural:terrain:4096 --codec bc7 -o terrain-bc7.tsr
//   transcode_bench --jpeg terrain-jpeg.tsr --zstd terrain-zstd.tsr [--blocks terrain-bc7.tsr] [--rounds 7] [--json out.json]
#include <turbojpeg.h>
#include <zstd.h>

#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "block_decode.hpp"
#include "transcode.hpp"
#include "tessera/storage/store_reader.hpp"

using namespace tessera;
using Clock = std::chrono::steady_clock;

namespace {

struct Corpus {
    std::string path;
    std::shared_ptr<const storage::StoreInfo> info;
    std::vector<std::shared_ptr<const std::vector<std::uint8_t>>> payloads;
    std::uint64_t payload_bytes = 0;
    std::size_t texels_per_tile() const { return std::size_t(info->tile_size()) * info->tile_size(); }
};

bool load(const std::string& path, Corpus& c) {
    auto reader = storage::StoreReader::open(path);
    if (!reader) {
        std::fprintf(stderr, "%s: %s\n", path.c_str(), reader.error().message.c_str());
        return false;
    }
    const storage::StoreInfo& info = (*reader)->info();
    c.path = path;
    c.info = std::make_shared<const storage::StoreInfo>(info);
    for (std::uint32_t l = 0; l < info.level_count(); ++l) {
        std::vector<tessera::TileKey> keys;
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) keys.push_back({l, x, y});
        for (auto& t : (*reader)->read_tiles(keys)) {
            if (!t) {
                std::fprintf(stderr, "%s: %s\n", path.c_str(), t.error().message.c_str());
                return false;
            }
            if (t->kind != tessera::TileKind::present) continue;  // uniform/absent: nothing to decode
            c.payload_bytes += t->bytes.size();
            c.payloads.push_back(std::make_shared<const std::vector<std::uint8_t>>(std::move(t->bytes)));
        }
    }
    return !c.payloads.empty();
}

// Page-sized staging slots, reused round robin (like an upload ring: not one cache-hot buffer).
struct Ring {
    static constexpr std::size_t kSlots = 32;
    std::size_t slot_bytes;
    std::vector<std::uint8_t> memory;
    explicit Ring(std::size_t bytes) : slot_bytes(bytes), memory(kSlots * bytes, 0) {}
    std::span<std::uint8_t> slot(std::size_t i) { return {memory.data() + (i % kSlots) * slot_bytes, slot_bytes}; }
};

// Wall time, and CPU time (of the calling thread for one-thread passes, of the whole process
// for pool passes: workers plus the polling thread). CPU time is what "throughput per thread"
// means on a shared machine: time other processes take from us does not count against a pass.
struct Timing {
    double wall = -1;  // negative: a decode failed
    double cpu = -1;
};

double cpu_seconds(clockid_t clock) {
    timespec ts{};
    clock_gettime(clock, &ts);
    return double(ts.tv_sec) + double(ts.tv_nsec) * 1e-9;
}

class Stopwatch {
public:
    explicit Stopwatch(clockid_t cpu_clock) : clock_(cpu_clock), wall0_(Clock::now()), cpu0_(cpu_seconds(cpu_clock)) {}
    Timing stop(bool ok) const {
        const double cpu = cpu_seconds(clock_) - cpu0_;
        const double wall = std::chrono::duration<double>(Clock::now() - wall0_).count();
        return ok ? Timing{wall, cpu} : Timing{};
    }

private:
    clockid_t clock_;
    Clock::time_point wall0_;
    double cpu0_;
};

// One pass over all tiles.
using Pass = std::function<Timing()>;

Timing pass_tj(const Corpus& c, Ring& ring, int pf) {
    tjhandle d = tjInitDecompress();
    const int side = static_cast<int>(c.info->tile_size());
    const Stopwatch watch(CLOCK_THREAD_CPUTIME_ID);
    bool ok = true;
    for (std::size_t i = 0; i < c.payloads.size(); ++i) {
        const auto& p = *c.payloads[i];
        ok &= tjDecompress2(d, p.data(), static_cast<unsigned long>(p.size()), ring.slot(i).data(), side, 0, side, pf,
                            TJFLAG_ACCURATEDCT) == 0;
    }
    const Timing t = watch.stop(ok);
    tjDestroy(d);
    return t;
}

// Bytes a zstd payload of the store decompresses to: the tile's samples, or a block tile's blocks
// and its second level's.
// The block format a store's pages take on the client-transcode route: BC4 for one channel of
// data, BC1 otherwise (sRGB colour, grey included, needs a format the GPU decodes from sRGB).
client::PageFormat client_block_format(const storage::StoreInfo& info) {
    return info.channels == 1 && info.colour_space != storage::ColourSpace::srgb ? client::PageFormat::bc4
                                                                                   : client::PageFormat::bc1;
}

std::size_t unpacked_bytes(const storage::StoreInfo& info) {
    const auto f = client::page_format_of(info.codec);
    return f ? client::page_upload_bytes(*f, info.tile_size(), true) : info.tile_bytes();
}

Timing pass_zstd_only(const Corpus& c, Ring& ring) {
    ZSTD_DCtx* d = ZSTD_createDCtx();
    const std::size_t n = unpacked_bytes(*c.info);
    const Stopwatch watch(CLOCK_THREAD_CPUTIME_ID);
    bool ok = true;
    for (std::size_t i = 0; i < c.payloads.size(); ++i) {
        const auto& p = *c.payloads[i];
        ok &= ZSTD_decompressDCtx(d, ring.slot(i).data(), n, p.data(), p.size()) == n;
    }
    const Timing t = watch.stop(ok);
    ZSTD_freeDCtx(d);
    return t;
}

Timing pass_transcode(const Corpus& c, Ring& ring) {
    client::Scratch scratch;
    const Codec codec = c.info->codec;
    const Stopwatch watch(CLOCK_THREAD_CPUTIME_ID);
    bool ok = true;
    for (std::size_t i = 0; i < c.payloads.size(); ++i)
        ok &= client::transcode_to_rgba8(*c.info, TileKind::present, codec, *c.payloads[i], ring.slot(i), scratch)
                  .ok();
    return watch.stop(ok);
}

// Decode and encode into a compressed page format (the client-transcode route): the ring slots
// are RGBA8-sized, larger than any block page.
Timing pass_transcode_to(const Corpus& c, Ring& ring, client::PageFormat format, bool second_level = false) {
    client::Scratch scratch;
    const Codec codec = c.info->codec;
    const std::size_t bytes = client::page_upload_bytes(format, c.info->tile_size(), second_level);
    const Stopwatch watch(CLOCK_THREAD_CPUTIME_ID);
    bool ok = true;
    for (std::size_t i = 0; i < c.payloads.size(); ++i)
        ok &= client::transcode_page(*c.info, TileKind::present, codec, *c.payloads[i], format, ring.slot(i).first(bytes),
                                     scratch, second_level)
                  .ok();
    return watch.stop(ok);
}

// End to end through the pool: the caller keeps `capacity` jobs in flight (one staging slot
// each), polls completions and reuses their slots, as the runtime's upload loop would.
Timing pass_pool(const Corpus& c, Ring& ring, unsigned threads) {
    client::TranscodePool pool(client::TranscodePoolOptions{threads, Ring::kSlots, false});
    const Codec codec = c.info->codec;
    std::vector<std::size_t> free_slots;
    for (std::size_t s = 0; s < Ring::kSlots; ++s) free_slots.push_back(s);
    std::vector<client::TranscodeResult> results;
    results.reserve(Ring::kSlots);
    const std::size_t n = c.payloads.size();
    std::size_t next = 0, done = 0;
    bool ok = true;
    const Stopwatch watch(CLOCK_PROCESS_CPUTIME_ID);
    while (done < n) {
        while (next < n && !free_slots.empty()) {
            client::TranscodeJob job;
            job.key = client::PageKey{0, 0, static_cast<std::uint32_t>(next), 0};
            job.ticket = free_slots.back();
            job.info = c.info;
            job.kind = TileKind::present;
            job.codec = codec;
            job.payload = c.payloads[next];
            job.destination = ring.slot(free_slots.back());
            if (!pool.submit(std::move(job))) break;
            free_slots.pop_back();
            ++next;
        }
        results.clear();
        if (pool.poll(results) == 0) {
            std::this_thread::sleep_for(std::chrono::milliseconds(1));  // a poller (the render thread: once a frame), not a spinner
            continue;
        }
        for (const auto& r : results) {
            ok &= r.status.ok();
            free_slots.push_back(static_cast<std::size_t>(r.ticket));
            ++done;
        }
    }
    return watch.stop(ok);
}

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    const std::size_t m = v.size() / 2;
    return v.size() % 2 ? v[m] : 0.5 * (v[m - 1] + v[m]);
}

struct Row {
    std::string name;
    unsigned threads = 1;
    std::vector<Timing> timings;  // one per round
};

struct Suite {
    std::string label;
    const Corpus* corpus;
    std::vector<Row> rows;
    std::vector<Pass> passes;
    std::string ceiling;  // row name of the ceiling
    std::string subject;  // row name compared against it
};

// What the block format costs in quality: every tile's block page, decoded as a GPU does
// (block_decode.hpp), against its RGBA8 page, over the colour channels (bc4: the first). PSNR of
// all tiles' texels together and of the worst tile.
struct BlockQuality {
    client::PageFormat format = client::PageFormat::bc1;
    double psnr_db = 0, worst_tile_db = 0;
};
BlockQuality block_quality(const Corpus& c, client::PageFormat format) {
    BlockQuality q;
    q.format = format;
    const std::uint32_t size = c.info->tile_size();
    client::Scratch scratch;
    std::vector<std::uint8_t> rgba(client::rgba8_page_bytes(*c.info)), blocks(client::page_bytes(format, size)),
        decoded(rgba.size());
    const int channels = format == client::PageFormat::bc1 ? 3 : 1;
    double sum_sq = 0, worst = 1e9;
    std::uint64_t samples = 0;
    for (const auto& p : c.payloads) {
        if (!client::transcode_page(*c.info, TileKind::present, c.info->codec, *p, client::PageFormat::rgba8, rgba, scratch) ||
            !client::transcode_page(*c.info, TileKind::present, c.info->codec, *p, format, blocks, scratch) ||
            !client::decode_block_page(format, blocks.data(), size, decoded.data()))
            return {};
        double tile_sq = 0;
        for (std::size_t i = 0; i < rgba.size(); i += 4)
            for (int ch = 0; ch < channels; ++ch) {
                const double d = double(rgba[i + std::size_t(ch)]) - double(decoded[i + std::size_t(ch)]);
                tile_sq += d * d;
            }
        const std::uint64_t n = std::uint64_t(size) * size * std::uint64_t(channels);
        worst = std::min(worst, tile_sq > 0 ? 10 * std::log10(255.0 * 255.0 * double(n) / tile_sq) : 99.0);
        sum_sq += tile_sq;
        samples += n;
    }
    q.psnr_db = sum_sq > 0 ? 10 * std::log10(255.0 * 255.0 * double(samples) / sum_sq) : 99.0;
    q.worst_tile_db = worst;
    return q;
}

// A block-codec store's tiles, decoded as a GPU samples them, against the same tiles of a lossless
// build of the same source (--reference): the build-time route's quality. Colour channels.
std::optional<BlockQuality> stored_block_quality(const std::string& path, const std::string& reference) {
    auto a = storage::StoreReader::open(path);
    auto b = storage::StoreReader::open(reference);
    if (!a || !b) return std::nullopt;
    const storage::StoreInfo &ia = (*a)->info(), &ib = (*b)->info();
    if (ia.width != ib.width || ia.height != ib.height || ia.tile_size() != ib.tile_size() || ia.border != ib.border) {
        std::fprintf(stderr, "%s and %s differ in geometry\n", path.c_str(), reference.c_str());
        return std::nullopt;
    }
    client::Scratch scratch;
    std::vector<std::uint8_t> pa(client::rgba8_page_bytes(ia)), pb(pa.size());
    const int channels = ia.channels == 1 ? 1 : 3;
    double sum_sq = 0, worst = 99;
    std::uint64_t samples = 0;
    for (std::uint32_t l = 0; l < ia.level_count(); ++l)
        for (std::uint32_t y = 0; y < ia.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < ia.levels[l].tiles_x; ++x) {
                auto ta = (*a)->read_tile({l, x, y});
                auto tb = (*b)->read_tile({l, x, y});
                if (!ta || !tb) return std::nullopt;
                if (ta->kind == TileKind::absent || tb->kind == TileKind::absent) continue;
                if (!client::transcode_to_rgba8(ia, ta->kind, ia.codec, ta->bytes, pa, scratch) ||
                    !client::transcode_to_rgba8(ib, tb->kind, ib.codec, tb->bytes, pb, scratch))
                    return std::nullopt;
                double tile_sq = 0;
                for (std::size_t i = 0; i < pa.size(); i += 4)
                    for (int ch = 0; ch < channels; ++ch) {
                        const double d = double(pa[i + std::size_t(ch)]) - double(pb[i + std::size_t(ch)]);
                        tile_sq += d * d;
                    }
                const std::uint64_t n = std::uint64_t(pa.size() / 4) * std::uint64_t(channels);
                worst = std::min(worst, tile_sq > 0 ? 10 * std::log10(255.0 * 255.0 * double(n) / tile_sq) : 99.0);
                sum_sq += tile_sq;
                samples += n;
            }
    BlockQuality q;
    q.format = *client::page_format_of(ia.codec);
    q.psnr_db = sum_sq > 0 ? 10 * std::log10(255.0 * 255.0 * double(samples) / sum_sq) : 99.0;
    q.worst_tile_db = worst;
    return q;
}

std::string json_number(double v) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.6g", v);
    return buf;
}

std::string cpu_model() {
    std::ifstream f("/proc/cpuinfo");
    std::string line;
    while (std::getline(f, line))
        if (line.rfind("model name", 0) == 0) {
            const auto colon = line.find(':');
            return colon == std::string::npos ? line : line.substr(colon + 2);
        }
    return "unknown";
}

}  // namespace

int main(int argc, char** argv) {
    std::string jpeg_path, zstd_path, blocks_path, reference_path, json_path;
    int rounds = 7;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto value = [&]() -> std::string { return i + 1 < argc ? argv[++i] : ""; };
        if (a == "--jpeg") jpeg_path = value();
        else if (a == "--zstd") zstd_path = value();
        else if (a == "--blocks") blocks_path = value();
        else if (a == "--reference") reference_path = value();
        else if (a == "--json") json_path = value();
        else if (a == "--rounds") rounds = std::max(1, std::atoi(value().c_str()));
        else {
            std::fprintf(stderr,
                         "usage: transcode_bench --jpeg STORE.tsr [--zstd STORE.tsr] [--blocks STORE.tsr [--reference LOSSLESS.tsr]] [--rounds N] [--json FILE]\n"
                         "  make the stores with: tessera build procedural:terrain:4096 --codec jpeg|zstd|bc7 -o X.tsr\n");
            return 2;
        }
    }
    if (jpeg_path.empty() && zstd_path.empty() && blocks_path.empty()) {
        std::fprintf(stderr, "transcode_bench: give --jpeg, --zstd and/or --blocks (see --help)\n");
        return 2;
    }

    Corpus jpeg, zstd, blocks;
    if (!jpeg_path.empty() && !load(jpeg_path, jpeg)) return 1;
    if (!zstd_path.empty() && !load(zstd_path, zstd)) return 1;
    if (!blocks_path.empty() && !load(blocks_path, blocks)) return 1;

    std::vector<Suite> suites;
    std::vector<std::unique_ptr<Ring>> rings;
    auto add_pool_rows = [&](Suite& s, Ring& ring) {
        for (unsigned t : {1u, 2u}) {
            s.rows.push_back({"pool x" + std::to_string(t), t, {}});
            s.passes.push_back([&c = *s.corpus, &ring, t] { return pass_pool(c, ring, t); });
        }
    };
    if (!jpeg.payloads.empty()) {
        if (jpeg.info->codec != tessera::Codec::jpeg) {
            std::fprintf(stderr, "%s is not a JPEG store\n", jpeg_path.c_str());
            return 1;
        }
        rings.push_back(std::make_unique<Ring>(client::rgba8_page_bytes(*jpeg.info)));
        Ring& ring = *rings.back();
        Suite s{"jpeg", &jpeg, {}, {}, "libjpeg RGB", "transcode"};
        const int rgb_pf = jpeg.info->channels == 1 ? TJPF_GRAY : TJPF_RGB;
        s.rows.push_back({jpeg.info->channels == 1 ? "libjpeg GRAY" : "libjpeg RGB", 1, {}});
        s.ceiling = s.rows.back().name;
        s.passes.push_back([&jpeg, &ring, rgb_pf] { return pass_tj(jpeg, ring, rgb_pf); });
        s.rows.push_back({"libjpeg RGBA", 1, {}});
        s.passes.push_back([&jpeg, &ring] { return pass_tj(jpeg, ring, TJPF_RGBA); });
        s.rows.push_back({"transcode", 1, {}});
        s.passes.push_back([&jpeg, &ring] { return pass_transcode(jpeg, ring); });
        // The block format this store's pages take on the client-transcode route.
        const client::PageFormat bc = client_block_format(*jpeg.info);
        s.rows.push_back({"transcode " + std::string(client::to_string(bc)), 1, {}});
        s.passes.push_back([&jpeg, &ring, bc] { return pass_transcode_to(jpeg, ring, bc); });
        add_pool_rows(s, ring);
        suites.push_back(std::move(s));
    }
    if (!zstd.payloads.empty()) {
        if (zstd.info->codec != tessera::Codec::zstd) {
            std::fprintf(stderr, "%s is not a zstd store\n", zstd_path.c_str());
            return 1;
        }
        rings.push_back(std::make_unique<Ring>(std::max(client::rgba8_page_bytes(*zstd.info), zstd.info->tile_bytes())));
        Ring& ring = *rings.back();
        Suite s{"zstd", &zstd, {}, {}, "zstd only", "transcode"};
        s.rows.push_back({"zstd only", 1, {}});
        s.passes.push_back([&zstd, &ring] { return pass_zstd_only(zstd, ring); });
        s.rows.push_back({"transcode", 1, {}});
        s.passes.push_back([&zstd, &ring] { return pass_transcode(zstd, ring); });
        add_pool_rows(s, ring);
        suites.push_back(std::move(s));
    }
    if (!blocks.payloads.empty()) {
        const auto format = client::page_format_of(blocks.info->codec);
        if (!format) {
            std::fprintf(stderr, "%s is not a block-codec store (tessera build --codec bc1|bc4|bc5|bc7)\n", blocks_path.c_str());
            return 1;
        }
        rings.push_back(std::make_unique<Ring>(std::max(client::rgba8_page_bytes(*blocks.info), unpacked_bytes(*blocks.info))));
        Ring& ring = *rings.back();
        Suite s{std::string(tessera::to_string(blocks.info->codec)), &blocks, {}, {}, "zstd only", "unpack"};
        s.rows.push_back({"zstd only", 1, {}});
        s.passes.push_back([&blocks, &ring] { return pass_zstd_only(blocks, ring); });
        s.rows.push_back({"unpack", 1, {}});  // into the pool's format: the page and its second level
        s.passes.push_back([&blocks, &ring, f = *format] { return pass_transcode_to(blocks, ring, f, true); });
        s.rows.push_back({"decode rgba8", 1, {}});
        s.passes.push_back([&blocks, &ring] { return pass_transcode(blocks, ring); });
        suites.push_back(std::move(s));
    }

    // Warm-up (page faults in the rings, library init), then interleaved rounds; the order of the
    // passes rotates each round so no pass always runs first or after the same neighbour.
    for (auto& s : suites)
        for (auto& p : s.passes)
            if (p().wall < 0) {
                std::fprintf(stderr, "%s: a decode failed\n", s.label.c_str());
                return 1;
            }
    for (int r = 0; r < rounds; ++r)
        for (auto& s : suites) {
            const std::size_t n = s.passes.size();
            for (std::size_t k = 0; k < n; ++k) {
                const std::size_t i = (k + static_cast<std::size_t>(r)) % n;
                const Timing t = s.passes[i]();
                if (t.wall < 0) {
                    std::fprintf(stderr, "%s %s: a decode failed\n", s.label.c_str(), s.rows[i].name.c_str());
                    return 1;
                }
                s.rows[i].timings.push_back(t);
            }
        }

    std::printf("transcode_bench: %s, %u hardware threads, %d rounds (medians), RGBA8 output unless the pass names a block format\n", cpu_model().c_str(),
                std::thread::hardware_concurrency(), rounds);
    std::string json = "{\"cpu\":\"" + cpu_model() + "\",\"hardware_threads\":" +
                       std::to_string(std::thread::hardware_concurrency()) + ",\"rounds\":" + std::to_string(rounds) +
                       ",\"suites\":[";
    for (std::size_t si = 0; si < suites.size(); ++si) {
        const Suite& s = suites[si];
        const Corpus& c = *s.corpus;
        const double tiles = static_cast<double>(c.payloads.size());
        const double mpix = tiles * static_cast<double>(c.texels_per_tile()) / 1e6;
        std::printf("\n%s: %s, %zu tiles of %ux%u, %u ch %s, %.1f MiB of payloads; ceiling: %s\n", s.label.c_str(),
                    c.path.c_str(), c.payloads.size(), c.info->tile_size(), c.info->tile_size(), c.info->channels,
                    std::string(storage::to_string(c.info->sample_type)).c_str(), double(c.payload_bytes) / 1048576.0,
                    s.ceiling.c_str());
        std::printf("  %-15s %7s %8s %8s %7s %8s %9s %9s %9s\n", "pass", "threads", "wall ms", "tiles/s", "MP/s",
                    "CPU ms", "MP/CPU-s", "wall/ceil", "CPU/ceil");
        const Row* ceiling = nullptr;
        for (const Row& r : s.rows)
            if (r.name == s.ceiling) ceiling = &r;
        json += std::string(si ? "," : "") + "{\"codec\":\"" + s.label + "\",\"store\":\"" + c.path +
                "\",\"tiles\":" + std::to_string(c.payloads.size()) + ",\"tile_size\":" +
                std::to_string(c.info->tile_size()) + ",\"megapixels\":" + json_number(mpix) + ",\"ceiling\":\"" +
                s.ceiling + "\",\"passes\":[";
        for (std::size_t ri = 0; ri < s.rows.size(); ++ri) {
            const Row& r = s.rows[ri];
            std::vector<double> wall, cpu, wall_ratio, cpu_ratio;
            for (std::size_t k = 0; k < r.timings.size(); ++k) {
                wall.push_back(r.timings[k].wall);
                cpu.push_back(r.timings[k].cpu);
                // Ratios within a round, then their median: robust to the machine drifting.
                wall_ratio.push_back(ceiling->timings[k].wall / r.timings[k].wall);
                cpu_ratio.push_back(ceiling->timings[k].cpu / r.timings[k].cpu);
            }
            const double w = median(wall), u = median(cpu), wr = median(wall_ratio), ur = median(cpu_ratio);
            std::printf("  %-15s %7u %8.1f %8.0f %7.1f %8.1f %9.1f %8.3fx %8.3fx\n", r.name.c_str(), r.threads, w * 1e3,
                        tiles / w, mpix / w, u * 1e3, mpix / u, wr, ur);
            json += std::string(ri ? "," : "") + "{\"name\":\"" + r.name + "\",\"threads\":" + std::to_string(r.threads) +
                    ",\"wall_s\":" + json_number(w) + ",\"wall_min_s\":" +
                    json_number(*std::min_element(wall.begin(), wall.end())) + ",\"cpu_s\":" + json_number(u) +
                    ",\"tiles_per_s\":" + json_number(tiles / w) + ",\"mpix_per_s\":" + json_number(mpix / w) +
                    ",\"mpix_per_cpu_s\":" + json_number(mpix / u) + ",\"wall_throughput_vs_ceiling\":" +
                    json_number(wr) + ",\"per_thread_vs_ceiling\":" + json_number(ur) + "}";
        }
        json += "]";
        if (const auto bf = client::page_format_of(c.info->codec)) {
            // Bytes of blocks a thread unpacks per CPU second (the page and its second level).
            const Row& unpack = s.rows[1];
            std::vector<double> cpu;
            for (const Timing& t : unpack.timings) cpu.push_back(t.cpu);
            const double gbps = tiles * double(unpacked_bytes(*c.info)) / median(cpu) / 1e9;
            std::printf("  unpack: %.2f GB/s of %s blocks per thread (page and second level)\n", gbps,
                        std::string(client::to_string(*bf)).c_str());
            json += ",\"unpack_gb_per_cpu_s\":" + json_number(gbps);
            if (!reference_path.empty()) {
                const auto q = stored_block_quality(c.path, reference_path);
                if (!q) {
                    std::fprintf(stderr, "--reference %s: cannot compare\n", reference_path.c_str());
                    return 1;
                }
                std::printf("  quality: the stored %s blocks against %s: PSNR %.2f dB over all tiles, worst tile %.2f dB\n",
                            std::string(client::to_string(q->format)).c_str(), reference_path.c_str(), q->psnr_db,
                            q->worst_tile_db);
                json += ",\"block_quality\":{\"format\":\"" + std::string(client::to_string(q->format)) +
                        "\",\"psnr_db\":" + json_number(q->psnr_db) + ",\"worst_tile_psnr_db\":" + json_number(q->worst_tile_db) + "}";
            }
            json += "}";
            continue;
        }
        // Block pages' quality on this store (not for 2-channel stores: no colour block format here).
        if (c.info->channels != 2) {
            const auto bc = client_block_format(*c.info);
            const BlockQuality q = block_quality(c, bc);
            std::printf("  quality: %s pages against the RGBA8 pages: PSNR %.2f dB over all tiles, worst tile %.2f dB\n",
                        std::string(client::to_string(bc)).c_str(), q.psnr_db, q.worst_tile_db);
            json += ",\"block_quality\":{\"format\":\"" + std::string(client::to_string(bc)) +
                    "\",\"psnr_db\":" + json_number(q.psnr_db) + ",\"worst_tile_psnr_db\":" + json_number(q.worst_tile_db) + "}";
        }
        json += "}";
    }
    json += "]}\n";
    std::printf("\nwall/ceil: throughput (wall clock) over the ceiling pass's, on one thread.\n"
                "CPU/ceil: work per CPU second over the ceiling's = throughput per thread (pool: workers + poller).\n"
                "Both are medians of per-round ratios. Target: transcode CPU/ceil >= 0.9 against libjpeg RGB.\n");
    std::printf("%s", json.c_str());
    if (!json_path.empty()) std::ofstream(json_path) << json;
    return 0;
}
