#pragma once
// Client tile caches, second level: the disk cache (docs/client.md, "One frame, end to end", steps
// 4 and 6). It persists across runs, is bounded in bytes, is keyed by store name *and* store
// version (a rebuilt store never serves old tiles), and never returns a corrupt tile: every entry
// carries a checksummed header and the payload's XXH3-64, and is written to a temporary file and
// renamed into place, so a crash or kill -9 at any moment leaves either the old entry, the new one
// or none. Whatever fails verification on read (bit rot, truncation, a power cut with fsync off, a
// file copied under the wrong name) is deleted, counted and reported as a miss, so the caller
// refetches it.
//
// Layout (one file per tile):
//   DIR/.lock                                   flock()ed by the open cache (one owner per DIR)
//   DIR/<store>/<version: 16 hex>/<level>/<x>_<y>.tile
//   DIR/<store>/<version>/<level>/<x>_<y>.tile.tmp-<pid>-<n>   a write in progress (or a crash's
//                                                               leftover, deleted at open)
// Entry file: a header, then the payload. Header (little-endian):
//   0  "TSRC"          4  format version (u16, 2)   6  header size H (u16, 56 + n)
//   8  kind (u8)       9  codec (u8)                10 level (u8)     11 store name length n (u8)
//      (kind and codec: TileKind and Codec of tessera/tile.hpp; codec is the store's)
//   12 x (u32)         16 y (u32)                   20 reserved (u32, 0)
//   24 store version (u64)      32 payload length (u64)      40 payload XXH3-64 (u64)
//   48 store name (n bytes)     48+n XXH3-64 of header bytes [0, 48+n) (u64)
// A read checks the magic, format, every key field against the key asked for, the file size,
// the header checksum and the payload checksum.
//
// Threads: get() runs on the caller's thread (any number at once). put() only queues: one writer
// thread owned by the cache writes, evicts and deletes; the queue is bounded in entries and bytes
// and a put that does not fit is dropped and counted, so put() never blocks on I/O.
//
// Budget: the disk space of the entries: each file's allocated blocks, or its length where that
// is more (headers included; directories not counted). After the
// scan at open and after every write, least recently used entries are deleted until the sum is
// within the budget. Recency: the in-memory LRU during a run; across runs, file mtime (a hit
// updates the mtime lazily, batched on the writer thread every touch_interval and at flush/close).
//
// Open: a background scan (on the writer thread) learns the entries' sizes and mtimes, deletes
// temporary files left by a crash and enforces the budget; open() itself returns at once. get()
// is correct while the scan runs (it reads the entry's file directly); writes wait for the scan
// (puts queue up meanwhile, within the queue bounds).
//
// Entries written by another format version, like any entry failing verification, are deleted on
// read and refetched. Files in DIR that do not follow the layout are left alone and not counted.
//
// One process, one cache per directory: open() takes an exclusive flock on DIR/.lock and fails
// (Errc::resource_exhausted) while another DiskTileCache holds it. (A child forked while the
// cache is open inherits the lock until it closes the descriptor or exits.)
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "ram_cache.hpp"
#include "tessera/result.hpp"

namespace tessera::client {

struct DiskCacheOptions {
    std::uint64_t byte_budget = std::uint64_t{1} << 30;  // > 0
    // Bounds of the write queue; a put beyond either is dropped (counted in write_drops). The
    // entry being written counts until it is done.
    std::uint64_t max_queue_bytes = std::uint64_t{64} << 20;
    std::size_t max_queue_entries = 1024;  // > 0
    // fsync each entry (and its directory) before/after the rename. Off by default: the rename is
    // atomic either way, so a killed process never leaves a torn entry; fsync only adds
    // durability against power loss, where unsynced entries may come back corrupt and are then
    // detected and deleted on read.
    bool fsync = false;
    // How often hits' mtime updates are written (also at flush() and close).
    std::chrono::milliseconds touch_interval{2000};
    // At destruction: true writes every queued put first (bounded by the queue limits); false
    // drops them (counted in write_drops). Either way the writer thread is joined.
    bool drain_on_close = true;
    // Test hook: called on the writer thread before each entry is written (may block to stall
    // the writer).
    std::function<void(const TileId&)> before_write_for_testing;
};

struct DiskCacheStats {
    std::uint64_t hits = 0;
    std::uint64_t misses = 0;        // includes corrupt entries and read errors
    std::uint64_t corrupt = 0;       // entries that failed verification (deleted)
    std::uint64_t writes = 0;        // entries written
    std::uint64_t write_drops = 0;   // puts dropped: queue full, or still queued at a non-draining close
    std::uint64_t rejected = 0;      // puts refused: bad store name, too large for the budget,
                                     // payload not matching its checksum
    std::uint64_t write_errors = 0;  // writes the OS refused (ENOSPC, EACCES, ...)
    std::uint64_t bytes = 0;         // disk space of the known entries (blocks, see Budget)
    std::uint64_t entries = 0;
    std::uint64_t evictions = 0;     // entries deleted to keep within the budget
    std::uint64_t dropped_versions = 0;  // entries deleted by drop_other_versions
    std::uint64_t temp_files_removed = 0;  // crash leftovers deleted by the scan at open
    std::uint64_t queued_entries = 0;
    std::uint64_t queued_bytes = 0;
    bool scan_complete = false;
};

class DiskTileCache {
public:
    static Result<std::unique_ptr<DiskTileCache>> open(std::string dir, std::uint64_t byte_budget);
    static Result<std::unique_ptr<DiskTileCache>> open(std::string dir, DiskCacheOptions options);

    // Drains (or drops, per options.drain_on_close) the queue, writes pending mtime updates and
    // joins the writer thread. A scan or drop_other_versions still running is abandoned (the next
    // open scans again; abandoned old versions are never served and age out under the budget);
    // when the scan is abandoned, queued puts are dropped rather than written past a budget
    // that could not be checked.
    ~DiskTileCache();
    DiskTileCache(const DiskTileCache&) = delete;
    DiskTileCache& operator=(const DiskTileCache&) = delete;

    // The entry, or nullopt when there is none or it failed verification (then it is deleted and
    // counted in `corrupt`). Errors: invalid_argument (store name not valid), io_error (the OS
    // refused to read an existing entry, e.g. EACCES or EIO).
    Result<std::optional<TileData>> get(const TileId& id);

    // Queues the entry for the writer thread and returns at once: true when queued, false when
    // dropped (queue full: write_drops) or refused at once (bad store name: rejected). The
    // payload's checksum is verified on the writer thread; a mismatch is refused, not written.
    bool put(const TileId& id, const TileData& tile);
    bool put(const TileId& id, std::shared_ptr<const TileData> tile);  // no payload copy

    // Deletes, in the background (in queue order), every version of `store` other than `version`.
    void drop_other_versions(std::string store, std::uint64_t version);

    // Blocks until the open scan is done, everything queued before this call (puts and drops)
    // is done, and pending mtime updates are written. For tests and orderly shutdown.
    void flush();

    DiskCacheStats stats() const;
    const std::string& dir() const;
    std::uint64_t byte_budget() const;
    // Where `id`'s entry lives (whether or not it exists). `id.store` must be valid.
    std::string entry_path(const TileId& id) const;

    // Store names usable as a directory: 1..200 characters of [A-Za-z0-9_.-], not starting with
    // '.' (no hidden names, no "." or ".."), and no ".." anywhere.
    static bool valid_store_name(std::string_view name);

private:
    struct Impl;
    explicit DiskTileCache(std::unique_ptr<Impl> impl);
    std::unique_ptr<Impl> impl_;
};

}  // namespace tessera::client
