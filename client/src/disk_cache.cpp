// The client's disk tile cache: see disk_cache.hpp for the layout, the entry format and the
// guarantees.
//
// Concurrency. Three kinds of threads touch the cache:
//  - callers of get() (any number): read an entry's file without any lock, then take `mu` to
//    update the LRU (or, for a corrupt entry, to delete it);
//  - callers of put()/drop_other_versions()/flush(): take `qmu` only (never `mu`, never I/O), so
//    they cannot be held up by the disk;
//  - the writer thread: the scan at open, writes, evictions and version drops.
// Every change to the set of entry files (rename into place, unlink) happens with `mu` held, and
// file contents are written only to temporary files, so a reader holding `mu` sees a consistent
// picture: an open descriptor whose file still has a link (st_nlink > 0) is the current entry.
// That is what lets get() add an entry it found on disk to the index (during the scan at open)
// without resurrecting one the writer has just evicted or replaced.
#include "disk_cache.hpp"

#include <dirent.h>
#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <sys/uio.h>
#include <unistd.h>
#include <xxhash.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <filesystem>
#include <list>
#include <mutex>
#include <system_error>
#include <thread>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include "tessera/hex.hpp"

namespace tessera::client {

namespace {

constexpr char kMagic[4] = {'T', 'S', 'R', 'C'};
// 2: kind and codec are tessera/tile.hpp's TileKind and Codec (1 stored the wire's codec numbers).
constexpr std::uint16_t kFormatVersion = 2;
constexpr std::size_t kFixedHeader = 48;  // up to the store name
constexpr std::size_t kMaxStoreName = 200;
constexpr std::size_t kMaxPendingTouches = 1 << 16;
constexpr std::uint64_t kMaxEntryBytes = std::uint64_t{1} << 31;  // sanity bound on a file's size
constexpr const char* kTempMarker = ".tmp-";
constexpr const char* kLockName = ".lock";

std::size_t header_size(std::size_t name_len) { return kFixedHeader + name_len + 8; }

void put_le(std::uint8_t* p, std::uint64_t v, int bytes) {
    for (int i = 0; i < bytes; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
std::uint64_t get_le(const std::uint8_t* p, int bytes) {
    std::uint64_t v = 0;
    for (int i = 0; i < bytes; ++i) v |= std::uint64_t{p[i]} << (8 * i);
    return v;
}

std::vector<std::uint8_t> encode_header(const TileId& id, const TileData& t, std::uint64_t payload_checksum) {
    const std::size_t n = id.store.size();
    std::vector<std::uint8_t> h(header_size(n), 0);
    std::memcpy(h.data(), kMagic, 4);
    put_le(&h[4], kFormatVersion, 2);
    put_le(&h[6], h.size(), 2);
    h[8] = static_cast<std::uint8_t>(t.kind);
    h[9] = static_cast<std::uint8_t>(t.codec);
    h[10] = static_cast<std::uint8_t>(id.tile.level);
    h[11] = static_cast<std::uint8_t>(n);
    put_le(&h[12], id.tile.x, 4);
    put_le(&h[16], id.tile.y, 4);
    put_le(&h[20], 0, 4);
    put_le(&h[24], id.version, 8);
    put_le(&h[32], t.payload.size(), 8);
    put_le(&h[40], payload_checksum, 8);
    std::memcpy(&h[kFixedHeader], id.store.data(), n);
    put_le(&h[kFixedHeader + n], XXH3_64bits(h.data(), kFixedHeader + n), 8);
    return h;
}

bool parse_hex16(std::string_view s, std::uint64_t& out) {
    if (s.size() != 16) return false;
    std::uint64_t v = 0;
    for (char c : s) {
        int d;
        if (c >= '0' && c <= '9') d = c - '0';
        else if (c >= 'a' && c <= 'f') d = c - 'a' + 10;
        else return false;
        v = (v << 4) | static_cast<std::uint64_t>(d);
    }
    out = v;
    return true;
}

// Canonical decimal only ("0", "17"; not "017" or "+1"), so one key has exactly one file name.
template <class T>
bool parse_dec(std::string_view s, T& out) {
    if (s.empty() || (s.size() > 1 && s[0] == '0')) return false;
    auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
    return ec == std::errc() && p == s.data() + s.size();
}

// "<x>_<y>.tile"
bool parse_tile_name(std::string_view name, std::uint32_t& x, std::uint32_t& y) {
    constexpr std::string_view kExt = ".tile";
    if (name.size() <= kExt.size() || name.substr(name.size() - kExt.size()) != kExt) return false;
    name.remove_suffix(kExt.size());
    const auto us = name.find('_');
    if (us == std::string_view::npos) return false;
    return parse_dec(name.substr(0, us), x) && parse_dec(name.substr(us + 1), y);
}

struct Fd {
    int fd = -1;
    explicit Fd(int f = -1) : fd(f) {}
    Fd(const Fd&) = delete;
    Fd& operator=(const Fd&) = delete;
    ~Fd() {
        if (fd >= 0) ::close(fd);
    }
};

// Reads exactly n bytes at `off`: n on success, fewer at end of file, -1 on error.
ssize_t pread_full(int fd, void* buf, std::size_t n, off_t off) {
    std::size_t got = 0;
    while (got < n) {
        const ssize_t r = ::pread(fd, static_cast<char*>(buf) + got, n - got, off + static_cast<off_t>(got));
        if (r < 0) {
            if (errno == EINTR) continue;
            return -1;
        }
        if (r == 0) break;
        got += static_cast<std::size_t>(r);
    }
    return static_cast<ssize_t>(got);
}

bool write_all(int fd, const std::uint8_t* a, std::size_t na, const std::uint8_t* b, std::size_t nb) {
    while (na + nb > 0) {
        iovec iov[2];
        int cnt = 0;
        if (na > 0) iov[cnt++] = iovec{const_cast<std::uint8_t*>(a), na};
        if (nb > 0) iov[cnt++] = iovec{const_cast<std::uint8_t*>(b), nb};
        const ssize_t w = ::writev(fd, iov, cnt);
        if (w < 0) {
            if (errno == EINTR) continue;
            return false;
        }
        auto done = static_cast<std::size_t>(w);
        const std::size_t from_a = std::min(done, na);
        a += from_a;
        na -= from_a;
        done -= from_a;
        b += done;
        nb -= done;
    }
    return true;
}

struct DirEntry {
    std::string name;
    unsigned char type;  // DT_*
};

// Entries of the directory `name` under `parent_fd` (AT_FDCWD: a path); empty when it cannot be
// opened. Collected first, so the caller may delete while it goes through them.
std::vector<DirEntry> list_dir(int parent_fd, const std::string& name) {
    std::vector<DirEntry> out;
    const int fd = ::openat(parent_fd, name.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
    if (fd < 0) return out;
    DIR* d = ::fdopendir(fd);
    if (!d) {
        ::close(fd);
        return out;
    }
    while (const dirent* e = ::readdir(d)) {
        const std::string_view n = e->d_name;
        if (n == "." || n == "..") continue;
        unsigned char type = e->d_type;
        if (type == DT_UNKNOWN) {
            struct stat st {};
            if (::fstatat(fd, e->d_name, &st, AT_SYMLINK_NOFOLLOW) == 0) {
                type = S_ISDIR(st.st_mode) ? DT_DIR : S_ISREG(st.st_mode) ? DT_REG : DT_UNKNOWN;
            }
        }
        out.push_back(DirEntry{std::string(n), type});
    }
    ::closedir(d);
    return out;
}

enum class ReadOutcome { ok, corrupt, io_error };

}  // namespace

bool DiskTileCache::valid_store_name(std::string_view name) {
    if (name.empty() || name.size() > kMaxStoreName || name[0] == '.') return false;
    if (name.find("..") != std::string_view::npos) return false;
    for (char c : name) {
        const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' ||
                        c == '.' || c == '-';
        if (!ok) return false;
    }
    return true;
}

struct DiskTileCache::Impl {
    std::string dir;
    DiskCacheOptions opt;
    int lock_fd = -1;
    pid_t pid = 0;

    // ---- index: guarded by mu -----------------------------------------------------------------
    struct Entry {
        std::uint64_t size = 0;
        std::list<TileId>::iterator lru;
    };
    mutable std::mutex mu;
    std::list<TileId> lru;  // front: most recently used
    std::unordered_map<TileId, Entry, TileIdHash> index;
    std::uint64_t bytes = 0;
    bool scanning = true;                                  // the index is still incomplete
    std::unordered_set<TileId, TileIdHash> scan_deleted;   // deleted by get() while scanning
    std::unordered_set<TileId, TileIdHash> touches;        // hits whose mtime is to be updated

    // ---- queue: guarded by qmu ----------------------------------------------------------------
    struct Task {
        bool drop = false;  // drop_other_versions(id.store, id.version) rather than a write
        TileId id;
        std::shared_ptr<const TileData> tile;
        std::uint64_t cost = 0;
    };
    mutable std::mutex qmu;
    std::condition_variable work_cv;  // the writer waits for work
    std::condition_variable done_cv;  // flush() waits for the writer
    std::deque<Task> queue;
    std::uint64_t queued_bytes = 0;    // writes queued or being written
    std::uint64_t queued_writes = 0;
    std::uint64_t enqueued = 0;        // tasks ever queued
    std::uint64_t done = 0;            // tasks finished (in queue order)
    bool scan_done = false;
    bool writer_exited = false;
    bool stop = false;
    std::atomic<bool> stop_flag{false};  // read by the scan and drops without qmu

    std::atomic<std::uint64_t> hits{0}, misses{0}, corrupt{0}, writes{0}, write_drops{0}, rejected{0},
        write_errors{0}, evictions{0}, dropped_versions{0}, temps_removed{0};

    std::uint64_t temp_seq = 0;  // writer only
    std::thread writer;

    // ------------------------------------------------------------------------------------------
    // What an entry costs the disk: its blocks, not its length (a 62-byte record of an absent
    // tile takes a 4 KiB block; counted by length, a 64 KiB budget of such records took 14x that on disk).
    static std::uint64_t disk_usage(const struct stat& st) {
        return std::max<std::uint64_t>(static_cast<std::uint64_t>(st.st_size), static_cast<std::uint64_t>(st.st_blocks) * 512u);
    }

    std::string store_dir(std::string_view store) const {
        std::string p = dir;
        p += '/';
        p += store;
        return p;
    }
    std::string level_dir(const TileId& id) const {
        return store_dir(id.store) + '/' + hex16(id.version) + '/' + std::to_string(id.tile.level);
    }
    std::string entry_path(const TileId& id) const {
        return level_dir(id) + '/' + std::to_string(id.tile.x) + '_' + std::to_string(id.tile.y) + ".tile";
    }

    ReadOutcome read_entry(int fd, const struct stat& st, const TileId& id, TileData& out) const {
        const std::size_t hs = header_size(id.store.size());
        const auto size = static_cast<std::uint64_t>(st.st_size);
        // The payload buffer is only allocated once the header (checksum included) is sound.
        if (!S_ISREG(st.st_mode) || size < hs || size > kMaxEntryBytes) return ReadOutcome::corrupt;
        std::vector<std::uint8_t> h(hs);
        const ssize_t got = pread_full(fd, h.data(), hs, 0);
        if (got < 0) return ReadOutcome::io_error;
        if (static_cast<std::size_t>(got) != hs) return ReadOutcome::corrupt;
        const std::size_t n = id.store.size();
        if (std::memcmp(h.data(), kMagic, 4) != 0 || get_le(&h[4], 2) != kFormatVersion || get_le(&h[6], 2) != hs ||
            h[11] != n || get_le(&h[kFixedHeader + n], 8) != XXH3_64bits(h.data(), kFixedHeader + n)) {
            return ReadOutcome::corrupt;
        }
        // A sound header for another key (a misplaced file) is just as unusable.
        if (h[10] != id.tile.level || get_le(&h[12], 4) != id.tile.x || get_le(&h[16], 4) != id.tile.y || get_le(&h[20], 4) != 0 ||
            get_le(&h[24], 8) != id.version || std::memcmp(&h[kFixedHeader], id.store.data(), n) != 0) {
            return ReadOutcome::corrupt;
        }
        const std::uint64_t len = get_le(&h[32], 8);
        if (len != size - hs) return ReadOutcome::corrupt;
        if (h[8] > static_cast<std::uint8_t>(TileKind::uniform) || h[9] > static_cast<std::uint8_t>(Codec::layers))
            return ReadOutcome::corrupt;
        out.kind = static_cast<TileKind>(h[8]);
        out.codec = static_cast<Codec>(h[9]);
        out.checksum = get_le(&h[40], 8);
        out.payload.resize(len);
        const ssize_t pgot = pread_full(fd, out.payload.data(), len, static_cast<off_t>(hs));
        if (pgot < 0) return ReadOutcome::io_error;
        if (static_cast<std::uint64_t>(pgot) != len) return ReadOutcome::corrupt;
        // An absent tile as sources send it: no payload, checksum 0 (write_entry).
        const bool absent_zero = out.kind == TileKind::absent && out.payload.empty() && out.checksum == 0;
        if (XXH3_64bits(out.payload.data(), out.payload.size()) != out.checksum && !absent_zero) return ReadOutcome::corrupt;
        return ReadOutcome::ok;
    }

    // mu held.
    void erase_entry_locked(const TileId& id) {
        auto it = index.find(id);
        if (it == index.end()) return;
        bytes -= it->second.size;
        lru.erase(it->second.lru);
        index.erase(it);
    }

    // mu held.
    void insert_front_locked(const TileId& id, std::uint64_t size) {
        auto it = index.find(id);
        if (it != index.end()) {
            bytes -= it->second.size;
            it->second.size = size;
            bytes += size;
            lru.splice(lru.begin(), lru, it->second.lru);
            return;
        }
        lru.push_front(id);
        try {
            index.emplace(id, Entry{size, lru.begin()});
        } catch (...) {
            lru.pop_front();
            throw;
        }
        bytes += size;
    }

    // mu held. Deletes least recently used entries until within the budget.
    void evict_locked() {
        if (scanning) return;  // sizes not all known yet; the scan's end evicts
        while (bytes > opt.byte_budget && !lru.empty()) {
            const TileId& victim = lru.back();
            ::unlink(entry_path(victim).c_str());  // ENOENT: already gone, same result
            auto it = index.find(victim);
            bytes -= it->second.size;
            index.erase(it);
            lru.pop_back();
            ++evictions;
        }
    }

    void note_hit(const TileId& id, int fd) {
        std::lock_guard lock(mu);
        auto it = index.find(id);
        if (it != index.end()) {
            lru.splice(lru.begin(), lru, it->second.lru);
        } else {
            // Not yet known (the scan is still running): add it, unless the file was unlinked or
            // replaced since we opened it (then it is no longer the entry).
            struct stat now {};
            if (::fstat(fd, &now) == 0 && now.st_nlink > 0) {
                insert_front_locked(id, disk_usage(now));
                scan_deleted.erase(id);
            }
        }
        if (touches.size() < kMaxPendingTouches) touches.insert(id);
    }

    // Deletes a corrupt entry, unless the writer has already replaced it with a new file.
    void remove_corrupt(const TileId& id, const std::string& path, const struct stat& seen) {
        std::lock_guard lock(mu);
        struct stat cur {};
        const bool present = ::stat(path.c_str(), &cur) == 0;
        const bool same = present && cur.st_ino == seen.st_ino && cur.st_dev == seen.st_dev;
        if (same) ::unlink(path.c_str());
        if (same || !present) {
            erase_entry_locked(id);
            if (scanning) scan_deleted.insert(id);
        }
    }

    void apply_touches() {
        std::unordered_set<TileId, TileIdHash> batch;
        {
            std::lock_guard lock(mu);
            batch.swap(touches);
        }
        for (const TileId& id : batch) ::utimensat(AT_FDCWD, entry_path(id).c_str(), nullptr, 0);  // ENOENT: evicted
    }

    // ---- writer thread ------------------------------------------------------------------------

    void run() {
        const bool scanned = scan();
        {
            std::lock_guard lock(qmu);
            scan_done = true;
        }
        done_cv.notify_all();
        auto last_touch = std::chrono::steady_clock::now();
        for (;;) {
            Task task;
            {
                std::unique_lock lock(qmu);
                work_cv.wait_until(lock, last_touch + opt.touch_interval, [&] { return stop || !queue.empty(); });
                if (stop && (queue.empty() || !opt.drain_on_close || !scanned)) {
                    // Close: drop whatever is left (nothing when draining after a full scan).
                    for (const Task& t : queue) {
                        if (!t.drop) ++write_drops;
                    }
                    done += queue.size();
                    queue.clear();
                    queued_bytes = 0;
                    queued_writes = 0;
                    break;
                }
                if (!queue.empty()) {
                    task = std::move(queue.front());
                    queue.pop_front();
                }
            }
            if (task.tile || task.drop) {
                if (task.drop) {
                    drop_versions(task.id.store, task.id.version);
                } else {
                    write_entry(task.id, *task.tile);
                }
                {
                    std::lock_guard lock(qmu);
                    if (!task.drop) {
                        queued_bytes -= task.cost;
                        --queued_writes;
                    }
                    ++done;
                }
                done_cv.notify_all();
            }
            if (std::chrono::steady_clock::now() - last_touch >= opt.touch_interval) {
                apply_touches();
                last_touch = std::chrono::steady_clock::now();
            }
        }
        {
            std::lock_guard lock(qmu);
            writer_exited = true;
        }
        done_cv.notify_all();
    }

    void make_dirs(const TileId& id) {
        std::string p = store_dir(id.store);
        ::mkdir(p.c_str(), 0755);
        p += '/';
        p += hex16(id.version);
        ::mkdir(p.c_str(), 0755);
        p += '/';
        p += std::to_string(id.tile.level);
        ::mkdir(p.c_str(), 0755);
    }

    void sync_dir(const std::string& path) {
        Fd d(::open(path.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC));
        if (d.fd >= 0) ::fsync(d.fd);
    }

    void write_entry(const TileId& id, const TileData& tile) {
        if (opt.before_write_for_testing) opt.before_write_for_testing(id);
        const std::uint64_t sum = XXH3_64bits(tile.payload.data(), tile.payload.size());
        // An absent tile as servers and stores send it has no payload and checksum 0, not the
        // empty payload's hash: kept as it is, so a sparse store's absent pages are remembered
        // across runs too.
        const bool absent_zero = tile.kind == TileKind::absent && tile.payload.empty() && tile.checksum == 0;
        if (sum != tile.checksum && !absent_zero) {
            ++rejected;
            return;
        }
        const std::vector<std::uint8_t> header = encode_header(id, tile, tile.checksum);
        const std::string final_path = entry_path(id);
        const std::string tmp = final_path + kTempMarker + std::to_string(pid) + '-' + std::to_string(temp_seq++);
        int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
        if (fd < 0 && errno == ENOENT) {
            make_dirs(id);
            fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
        }
        if (fd < 0) {
            ++write_errors;
            return;
        }
        bool ok = write_all(fd, header.data(), header.size(), tile.payload.data(), tile.payload.size());
        if (ok && opt.fsync) ok = ::fdatasync(fd) == 0;
        struct stat written {};
        std::uint64_t usage = header.size() + tile.payload.size();
        if (ok && ::fstat(fd, &written) == 0) usage = std::max(usage, disk_usage(written));
        if (::close(fd) != 0) ok = false;
        if (!ok) {
            ::unlink(tmp.c_str());
            ++write_errors;
            return;
        }
        {
            std::lock_guard lock(mu);
            if (::rename(tmp.c_str(), final_path.c_str()) != 0) {
                ::unlink(tmp.c_str());
                ++write_errors;
                return;
            }
            insert_front_locked(id, usage);
            ++writes;
            evict_locked();
        }
        if (opt.fsync) sync_dir(level_dir(id));
    }

    // Learns every entry's size and mtime, deletes crash leftovers, then enforces the budget.
    // False when abandoned (the cache is closing).
    bool scan() {
        struct Found {
            TileId id;
            std::uint64_t size;
            timespec mtime;
        };
        std::vector<Found> found;
        bool aborted = false;
        const Fd root(::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC));
        if (root.fd >= 0) {
            for (const DirEntry& s : list_dir(root.fd, ".")) {
                if (s.type != DT_DIR || !valid_store_name(s.name)) continue;
                const Fd sfd(::openat(root.fd, s.name.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC));
                if (sfd.fd < 0) continue;
                for (const DirEntry& v : list_dir(sfd.fd, ".")) {
                    std::uint64_t version = 0;
                    if (v.type != DT_DIR || !parse_hex16(v.name, version)) continue;
                    const Fd vfd(::openat(sfd.fd, v.name.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC));
                    if (vfd.fd < 0) continue;
                    for (const DirEntry& l : list_dir(vfd.fd, ".")) {
                        unsigned level = 0;
                        if (l.type != DT_DIR || !parse_dec(l.name, level) || level > 255) continue;
                        const Fd lfd(
                            ::openat(vfd.fd, l.name.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC));
                        if (lfd.fd < 0) continue;
                        std::size_t kept = 0;
                        for (const DirEntry& f : list_dir(lfd.fd, ".")) {
                            if (stop_flag.load(std::memory_order_relaxed)) {
                                aborted = true;
                                break;
                            }
                            if (f.name.find(kTempMarker) != std::string::npos) {
                                if (::unlinkat(lfd.fd, f.name.c_str(), 0) == 0) ++temps_removed;
                                continue;
                            }
                            ++kept;
                            std::uint32_t x = 0, y = 0;
                            if (!parse_tile_name(f.name, x, y)) continue;
                            struct stat st {};
                            if (::fstatat(lfd.fd, f.name.c_str(), &st, AT_SYMLINK_NOFOLLOW) != 0 ||
                                !S_ISREG(st.st_mode)) {
                                continue;
                            }
                            found.push_back(Found{TileId{s.name, version, {level, x, y}}, disk_usage(st), st.st_mtim});
                        }
                        if (aborted) break;
                        if (kept == 0) ::unlinkat(vfd.fd, l.name.c_str(), AT_REMOVEDIR);
                    }
                    if (aborted) break;
                    ::unlinkat(sfd.fd, v.name.c_str(), AT_REMOVEDIR);  // ENOTEMPTY unless empty
                }
                if (aborted) break;
                ::unlinkat(root.fd, s.name.c_str(), AT_REMOVEDIR);
            }
        }
        // Newest first, so that appending in this order leaves the oldest at the LRU's tail.
        std::sort(found.begin(), found.end(), [](const Found& a, const Found& b) {
            if (a.mtime.tv_sec != b.mtime.tv_sec) return a.mtime.tv_sec > b.mtime.tv_sec;
            return a.mtime.tv_nsec > b.mtime.tv_nsec;
        });
        std::lock_guard lock(mu);
        if (!aborted) {
            for (Found& f : found) {
                if (index.count(f.id) != 0 || scan_deleted.count(f.id) != 0) continue;  // get() got there first
                lru.push_back(f.id);
                index.emplace(std::move(f.id), Entry{f.size, std::prev(lru.end())});
                bytes += f.size;
            }
        }
        scan_deleted.clear();
        if (aborted) return false;
        scanning = false;
        evict_locked();
        return true;
    }

    void drop_versions(const std::string& store, std::uint64_t keep) {
        const std::string sdir = store_dir(store);
        const Fd sfd(::open(sdir.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC));
        if (sfd.fd < 0) return;
        for (const DirEntry& v : list_dir(sfd.fd, ".")) {
            std::uint64_t version = 0;
            if (v.type != DT_DIR || !parse_hex16(v.name, version) || version == keep) continue;
            const Fd vfd(::openat(sfd.fd, v.name.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC));
            if (vfd.fd < 0) continue;
            for (const DirEntry& l : list_dir(vfd.fd, ".")) {
                unsigned level = 0;
                if (l.type != DT_DIR || !parse_dec(l.name, level) || level > 255) continue;
                const Fd lfd(::openat(vfd.fd, l.name.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC));
                if (lfd.fd < 0) continue;
                for (const DirEntry& f : list_dir(lfd.fd, ".")) {
                    if (stop_flag.load(std::memory_order_relaxed)) return;  // abandoned; never served anyway
                    std::uint32_t x = 0, y = 0;
                    if (parse_tile_name(f.name, x, y)) {
                        std::lock_guard lock(mu);
                        if (::unlinkat(lfd.fd, f.name.c_str(), 0) == 0) ++dropped_versions;
                        erase_entry_locked(TileId{store, version, {level, x, y}});
                    } else if (f.name.find(kTempMarker) != std::string::npos) {
                        ::unlinkat(lfd.fd, f.name.c_str(), 0);
                    }
                }
                ::unlinkat(vfd.fd, l.name.c_str(), AT_REMOVEDIR);
            }
            ::unlinkat(sfd.fd, v.name.c_str(), AT_REMOVEDIR);
        }
    }
};

// ---- public interface -----------------------------------------------------------------------------

DiskTileCache::DiskTileCache(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

Result<std::unique_ptr<DiskTileCache>> DiskTileCache::open(std::string dir, std::uint64_t byte_budget) {
    DiskCacheOptions opt;
    opt.byte_budget = byte_budget;
    return open(std::move(dir), std::move(opt));
}

Result<std::unique_ptr<DiskTileCache>> DiskTileCache::open(std::string dir, DiskCacheOptions options) {
    if (dir.empty()) return make_error(Errc::invalid_argument, "disk cache: empty directory");
    if (options.byte_budget == 0) return make_error(Errc::invalid_argument, "disk cache: byte budget is 0");
    if (options.max_queue_entries == 0) return make_error(Errc::invalid_argument, "disk cache: max_queue_entries is 0");
    if (options.touch_interval.count() <= 0) options.touch_interval = std::chrono::milliseconds(1);
    std::error_code ec;
    std::filesystem::create_directories(dir, ec);
    if (ec) return make_error(Errc::io_error, "disk cache: cannot create " + dir + ": " + ec.message());

    const std::string lock_path = dir + '/' + kLockName;
    const int lock_fd = ::open(lock_path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (lock_fd < 0) return make_error(Errc::io_error, "disk cache: cannot open " + lock_path + ": " + std::strerror(errno));
    if (::flock(lock_fd, LOCK_EX | LOCK_NB) != 0) {
        const int err = errno;
        ::close(lock_fd);
        if (err == EWOULDBLOCK) {
            return make_error(Errc::resource_exhausted, "disk cache: " + dir + " is in use by another cache");
        }
        return make_error(Errc::io_error, "disk cache: cannot lock " + lock_path + ": " + std::strerror(err));
    }

    auto impl = std::make_unique<Impl>();
    impl->dir = std::move(dir);
    impl->opt = std::move(options);
    impl->lock_fd = lock_fd;
    impl->pid = ::getpid();
    try {
        impl->writer = std::thread([p = impl.get()] { p->run(); });
    } catch (const std::system_error& e) {
        ::close(lock_fd);
        return make_error(Errc::resource_exhausted, std::string("disk cache: cannot start writer: ") + e.what());
    }
    return std::unique_ptr<DiskTileCache>(new DiskTileCache(std::move(impl)));
}

DiskTileCache::~DiskTileCache() {
    if (!impl_) return;
    {
        std::lock_guard lock(impl_->qmu);
        impl_->stop = true;
    }
    impl_->stop_flag = true;
    impl_->work_cv.notify_all();
    if (impl_->writer.joinable()) impl_->writer.join();
    impl_->apply_touches();
    if (impl_->lock_fd >= 0) ::close(impl_->lock_fd);
}

Result<std::optional<TileData>> DiskTileCache::get(const TileId& id) {
    Impl& m = *impl_;
    if (!valid_store_name(id.store)) {
        return make_error(Errc::invalid_argument, "disk cache: invalid store name '" + id.store + "'");
    }
    const std::string path = m.entry_path(id);
    // O_NONBLOCK: a FIFO put in an entry's place would block the open until a writer came (and
    // every lookup queued behind it); read_entry refuses anything but a regular file.
    const Fd fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK));
    if (fd.fd < 0) {
        const int err = errno;
        ++m.misses;
        if (err == ENOENT || err == ENOTDIR) return std::optional<TileData>{};
        return make_error(Errc::io_error, "disk cache: cannot open " + path + ": " + std::strerror(err));
    }
    struct stat st {};
    if (::fstat(fd.fd, &st) != 0) {
        ++m.misses;
        return make_error(Errc::io_error, "disk cache: cannot stat " + path + ": " + std::strerror(errno));
    }
    TileData tile;
    switch (m.read_entry(fd.fd, st, id, tile)) {
        case ReadOutcome::ok:
            m.note_hit(id, fd.fd);
            ++m.hits;
            return std::optional<TileData>(std::move(tile));
        case ReadOutcome::corrupt:
            m.remove_corrupt(id, path, st);
            ++m.corrupt;
            ++m.misses;
            return std::optional<TileData>{};
        case ReadOutcome::io_error:
            break;
    }
    ++m.misses;
    return make_error(Errc::io_error, "disk cache: cannot read " + path + ": " + std::strerror(errno));
}

bool DiskTileCache::put(const TileId& id, const TileData& tile) {
    {
        // Skip the copy when the put would be dropped anyway (checked again under the lock below).
        std::lock_guard lock(impl_->qmu);
        if (impl_->queued_writes + 1 > impl_->opt.max_queue_entries ||
            impl_->queued_bytes + header_size(id.store.size()) + tile.payload.size() > impl_->opt.max_queue_bytes) {
            ++impl_->write_drops;
            return false;
        }
    }
    return put(id, std::make_shared<const TileData>(tile));
}

bool DiskTileCache::put(const TileId& id, std::shared_ptr<const TileData> tile) {
    Impl& m = *impl_;
    if (!tile || !valid_store_name(id.store)) {
        ++m.rejected;
        return false;
    }
    const std::uint64_t cost = header_size(id.store.size()) + tile->payload.size();
    // On disk it takes whole blocks (4 KiB on common file systems): an entry whose blocks exceed
    // the budget would be written only to be evicted at once.
    constexpr std::uint64_t kBlock = 4096;
    if ((cost + kBlock - 1) / kBlock * kBlock > m.opt.byte_budget) {
        ++m.rejected;
        return false;
    }
    {
        std::lock_guard lock(m.qmu);
        if (m.stop || m.queued_writes + 1 > m.opt.max_queue_entries || m.queued_bytes + cost > m.opt.max_queue_bytes) {
            ++m.write_drops;
            return false;
        }
        m.queue.push_back(Impl::Task{false, id, std::move(tile), cost});
        m.queued_bytes += cost;
        ++m.queued_writes;
        ++m.enqueued;
    }
    m.work_cv.notify_one();
    return true;
}

void DiskTileCache::drop_other_versions(std::string store, std::uint64_t version) {
    Impl& m = *impl_;
    if (!valid_store_name(store)) return;
    {
        std::lock_guard lock(m.qmu);
        if (m.stop) return;
        m.queue.push_back(Impl::Task{true, TileId{std::move(store), version, {}}, nullptr, 0});
        ++m.enqueued;
    }
    m.work_cv.notify_one();
}

void DiskTileCache::flush() {
    Impl& m = *impl_;
    {
        std::unique_lock lock(m.qmu);
        const std::uint64_t target = m.enqueued;
        m.done_cv.wait(lock, [&] { return m.writer_exited || (m.scan_done && m.done >= target); });
    }
    m.apply_touches();
}

DiskCacheStats DiskTileCache::stats() const {
    const Impl& m = *impl_;
    DiskCacheStats s;
    s.hits = m.hits;
    s.misses = m.misses;
    s.corrupt = m.corrupt;
    s.writes = m.writes;
    s.write_drops = m.write_drops;
    s.rejected = m.rejected;
    s.write_errors = m.write_errors;
    s.evictions = m.evictions;
    s.dropped_versions = m.dropped_versions;
    s.temp_files_removed = m.temps_removed;
    {
        std::lock_guard lock(m.mu);
        s.bytes = m.bytes;
        s.entries = m.index.size();
    }
    {
        std::lock_guard lock(m.qmu);
        s.queued_entries = m.queued_writes;
        s.queued_bytes = m.queued_bytes;
        s.scan_complete = m.scan_done;
    }
    return s;
}

const std::string& DiskTileCache::dir() const { return impl_->dir; }
std::uint64_t DiskTileCache::byte_budget() const { return impl_->opt.byte_budget; }
std::string DiskTileCache::entry_path(const TileId& id) const { return impl_->entry_path(id); }

}  // namespace tessera::client
