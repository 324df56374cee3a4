#pragma once
// The transcode pool (docs/client.md, "One frame, end to end", step 6): stored tile payloads (JPEG
// via libjpeg-turbo, zstd, raw, uniform) become GPU-ready pages, written straight into the caller's
// upload staging memory.
//
// Output: one page in a PageFormat (tessera/client/page.hpp), tile_size()^2 texels (border
// included), row-major, no row padding. transcode_to_rgba8 makes RGBA8 pages; transcode_page makes
// any format: BC1/BC4/BC5 by encoding the RGBA8 page on this thread (block_encode.hpp), R16,
// R16F and R32F by copying a 1-channel store's samples exactly.
//
// RGBA8 conversion
// Conversion rules (samples to 8 bits, then channels to RGBA):
//   u8        as is
//   u16       round(v / 257)                       (exact: 0 -> 0, 65535 -> 255)
//   f16, f32  round(clamp(v, 0, 1) * 255); NaN -> 0
//   1 channel (v)        -> (v, v, v, 255)
//   2 channels (v, a)    -> (v, v, v, a)           (read as grey + alpha, whatever has_alpha says)
//   3 channels (r, g, b) -> (r, g, b, 255)
//   4 channels           -> as is
// Float and 16-bit data textures (heights) lose precision in RGBA8: the r16, r16f and r32f page
// formats keep them exactly. The RGBA8 result equals storage::decode_tile's output
// converted with these rules, byte for byte (tests/transcode_test.cpp holds that reference).
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <thread>
#include <vector>

#include "tessera/blocks/blocks.hpp"
#include "tessera/client/page.hpp"
#include "tessera/client/upload.hpp"
#include "tessera/result.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::client {

constexpr std::size_t kRgba8TexelBytes = 4;
// Bytes of one RGBA8 page of `info`'s tiles.
inline std::size_t rgba8_page_bytes(const storage::StoreInfo& info) {
    return std::size_t(info.tile_size()) * info.tile_size() * kRgba8TexelBytes;
}

// The block format of a block-compressed page format.
constexpr std::optional<blocks::BlockFormat> block_format_of(PageFormat f) {
    switch (f) {
        case PageFormat::bc1: return blocks::BlockFormat::bc1;
        case PageFormat::bc4: return blocks::BlockFormat::bc4;
        case PageFormat::bc5: return blocks::BlockFormat::bc5;
        case PageFormat::bc7: return blocks::BlockFormat::bc7;
        default: return std::nullopt;
    }
}

class Scratch;
Status transcode_to_rgba8(const storage::StoreInfo& info, TileKind kind, Codec codec,
                          std::span<const std::uint8_t> payload, std::span<std::uint8_t> out, Scratch& scratch);

// Per-thread decoder state: the sample and page buffers, created on first use and reused, so a
// warmed-up Scratch decodes without allocating (the JPEG handle and zstd context are the store
// decoder's own, one per thread: tessera/storage/codec.hpp).
// Not thread-safe: one per thread.
class Scratch {
public:
    Scratch();
    ~Scratch();
    Scratch(Scratch&&) noexcept;
    Scratch& operator=(Scratch&&) noexcept;
    Scratch(const Scratch&) = delete;
    Scratch& operator=(const Scratch&) = delete;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
    friend Status transcode_to_rgba8(const storage::StoreInfo&, TileKind, Codec,
                                     std::span<const std::uint8_t>, std::span<std::uint8_t>, Scratch&);
    friend Status transcode_page(const storage::StoreInfo&, TileKind, Codec, std::span<const std::uint8_t>, PageFormat,
                                 std::span<std::uint8_t>, Scratch&, bool);
};

// Decodes one tile payload into `out` (exactly rgba8_page_bytes(info) bytes).
//   kind: absent is an error (not_found); uniform: the payload is one texel value
//     (info.texel_bytes() bytes) and every texel gets it.
//   codec: the payload's format for a present tile (normally info.codec).
// Errors: invalid_argument (bad `out` size, unknown kind/codec, impossible geometry), corrupt
// (payload that does not decode to exactly one tile of this store), not_found (absent). On error
// the contents of `out` are unspecified (it may be partly written): never use them.
// `out` is only written, row by row in order (zstd decompresses into scratch first, since its
// match copies read back what they wrote), so write-combined mapped GL memory is a fair target.
Status transcode_to_rgba8(const storage::StoreInfo& info, TileKind kind, Codec codec,
                          std::span<const std::uint8_t> payload, std::span<std::uint8_t> out, Scratch& scratch);

// Whether `info`'s pages can take `format`, and if not, why (invalid_argument, naming the format):
//   rgba8        every store
//   bc1          no alpha channel (BC1 is opaque here); tile_size a multiple of 4
//   bc4          1 channel; tile_size a multiple of 4
//   bc5          2 channels (value, alpha) or the first two of 3-4; tile_size a multiple of 4
//   r16/r16f/r32f  1 channel of u16 / f16 / f32 samples
Status check_page_format(const storage::StoreInfo& info, PageFormat format);

// Decodes one tile payload into `out` (exactly page_upload_bytes(format, info.tile_size(),
// second_level) bytes) in `format`. `second_level` (block formats only, tile size a multiple of
// 8): the page's 2x2 means follow it, encoded the same way, for an atlas's second level.
// Errors: those of check_page_format and transcode_to_rgba8.
Status transcode_page(const storage::StoreInfo& info, TileKind kind, Codec codec, std::span<const std::uint8_t> payload,
                      PageFormat format, std::span<std::uint8_t> out, Scratch& scratch, bool second_level = false);

// Whether `info`'s pages fit a pool: as many layers as the store has (one for a single-layer
// store), each layer's samples taking that layer's format (check_page_format), and tiles a
// multiple of 8 texels where a second level is uploaded. Errors name the layer and the format.
Status check_pool_format(const storage::StoreInfo& info, const PagePoolFormat& pool);

// One tile into one upload of `pool` (exactly pool.upload_bytes(info.tile_size()) bytes): a
// single-layer store's page as transcode_page makes it; a multi-layer store's bundle
// (Codec::layers) split, each layer's part transcoded into its layer's format, in layer order.
// An absent part is an error (not_found): the page is made resident with all its layers or not at
// all, so residency and fallback hold for every layer at once.
Status transcode_pool_page(const storage::StoreInfo& info, TileKind kind, Codec codec,
                           std::span<const std::uint8_t> payload, const PagePoolFormat& pool,
                           std::span<std::uint8_t> out, Scratch& scratch);

// ---------------------------------------------------------------------------------------------
// TranscodePool: N owned worker threads, one bounded priority queue of jobs, one bounded queue of
// completions polled by the render-facing thread.
//
// Ownership: the pool never allocates page memory. A job's `destination` is caller-owned staging
// memory (a slot of the upload ring); it must stay valid, and must not be reused or read by the
// caller, from submit() until poll() returns that job's result. Every accepted job produces
// exactly one result: decoded (status ok), failed (status error), or dropped (never decoded, its
// destination never written). The payload and StoreInfo are shared, read-only, and released by
// the pool once the job is finished or dropped.
//
// Bounds: at most `capacity` jobs are between submit() and poll() (queued + decoding + waiting to
// be polled); submit() returns false, without blocking, when that many are outstanding. The
// completion queue therefore never overflows and workers never wait on the poller.
struct TranscodeJob {
    PageKey key;
    std::uint64_t ticket = 0;  // caller's id (e.g. staging slot or request generation), echoed back
    std::shared_ptr<const storage::StoreInfo> info;
    TileKind kind = TileKind::present;
    Codec codec = Codec::raw;
    PagePoolFormat pool;  // what to make (transcode_pool_page)
    std::shared_ptr<const std::vector<std::uint8_t>> payload;
    std::span<std::uint8_t> destination;  // pool.upload_bytes(info->tile_size()) bytes
    std::uint32_t priority = 0;           // higher first; equal priorities in submission order
};

struct TranscodeResult {
    PageKey key;
    std::uint64_t ticket = 0;
    Status status;         // ok: destination holds the page; error: destination unspecified
    bool dropped = false;  // cancelled or unwanted before decoding (status: cancelled); destination untouched
};

struct TranscodePoolOptions {
    unsigned threads = 0;         // 0: hardware_concurrency - 1 (at least 1)
    std::size_t capacity = 256;   // jobs outstanding between submit() and poll(); at least 1
    bool start_paused = false;    // workers take no job until resume() (tests, warm-up)
};

struct TranscodePoolStats {
    std::uint64_t submitted = 0;  // accepted by submit()
    std::uint64_t rejected = 0;   // submit() returned false
    std::uint64_t decoded = 0;    // finished with status ok
    std::uint64_t failed = 0;     // finished with an error
    std::uint64_t dropped = 0;    // cancelled or unwanted before decoding
    std::size_t queued = 0;       // waiting for a worker now
    std::size_t running = 0;      // being decoded now
    std::size_t completed = 0;    // results waiting for poll()
};

class TranscodePool {
public:
    explicit TranscodePool(const TranscodePoolOptions& options = {});
    // shutdown(): prompt (queued jobs are dropped; only the tiles being decoded finish).
    ~TranscodePool();
    TranscodePool(const TranscodePool&) = delete;
    TranscodePool& operator=(const TranscodePool&) = delete;

    // Queues a job. False (and the job is not taken) when `capacity` jobs are outstanding or the
    // pool is shut down. Never blocks on decoding. A job that cannot be decoded (bad geometry,
    // null payload, wrong destination size) is accepted and completes with an error.
    bool submit(TranscodeJob job);

    // Drops queued jobs for `key` (all tickets); returns how many. A job already being decoded is
    // not interrupted: it completes normally.
    std::size_t cancel(const PageKey& key);
    // The runtime's per-frame request set replaces the last one: queued jobs whose key is not
    // wanted any more are dropped before decoding; returns how many. `wanted` runs on the calling
    // thread under the pool's lock: it must be cheap and must not call back into the pool.
    std::size_t retain_only(const std::function<bool(const PageKey&)>& wanted);
    // Same, and re-prioritises what stays: `f` returns the new priority, or nullopt to drop.
    std::size_t update_queued(const std::function<std::optional<std::uint32_t>(const PageKey&, std::uint32_t)>& f);

    // Appends every result waiting (decoded, failed, dropped) to `out`; returns how many. Never
    // waits for a decode: it only takes the pool's lock for the copy. After this, the
    // destinations of the returned jobs are the caller's again.
    std::size_t poll(std::vector<TranscodeResult>& out);

    void pause();   // workers finish their current tile and take no more
    void resume();

    // Stops accepting jobs, drops every queued job (their results stay pollable), lets the
    // running ones finish and joins the workers. Idempotent.
    void shutdown();

    TranscodePoolStats stats() const;
    // Worker threads running: fewer than asked only if the OS refused some; with 0 the pool
    // accepts no job.
    unsigned threads() const { return static_cast<unsigned>(workers_.size()); }
    std::size_t capacity() const { return capacity_; }

private:
    struct State;
    void worker_loop();

    std::size_t capacity_;
    std::unique_ptr<State> state_;
    std::vector<std::thread> workers_;
};

}  // namespace tessera::client
