#pragma once
// The stores a server hosts, by name. Files given one by one and *.tsr files in directories are
// opened at start and rescanned on reload(): new files are added, changed files (a different
// inode, size or mtime) are reopened under a new version, and removed files are dropped.
// Lookups hand out shared handles, so a request that started on an old version finishes on it.
//
// A file rewritten in place (same inode: `cp new.tsr served.tsr`, truncation, a stray write) can
// no longer be trusted for the version that was opened from it. Its handle is marked stale: the
// fetcher answers UNAVAILABLE for it (HTTP 503) instead of reading, until a rescan opens the file
// again as a new version. A stale handle is noticed by the rescan, or at once by the fetcher when
// a read fails and the file's size or mtime has changed. docs/server.md, "Replacing a store".
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <mutex>
#include <set>
#include <string>
#include <string_view>
#include <vector>

#include "log.hpp"
#include "metrics.hpp"
#include "tessera/result.hpp"
#include "tessera/storage/byte_source.hpp"
#include "tessera/storage/store_reader.hpp"

namespace tessera::server {

// Counters kept per store name (they survive the store being replaced).
struct StoreMetrics {
    Counter* tiles_sent = nullptr;
    Counter* bytes_sent = nullptr;
    Counter* data_loss = nullptr;
    Counter* requests = nullptr;
};

struct StoreHandle {
    std::string name;
    std::string path;
    std::shared_ptr<storage::StoreReader> reader;
    std::uint64_t version = 0;  // StoreInfo::store_id: content hash of the index
    StoreMetrics metrics;
    // File identity at open time (to notice a replaced file).
    std::uint64_t device = 0, inode = 0, size = 0;
    std::int64_t mtime_ns = 0;
    std::string remote_version;  // a remote store's ETag at open ("" for files)
    // The file changed in place under this version: nothing more is read from it.
    mutable std::atomic<bool> stale{false};
    // tessera_tiles_served_total{store, protocol="http"}, registered on the first HTTP tile and
    // kept here so that later ones take no lock.
    mutable std::atomic<Counter*> http_tiles_served{nullptr};
    const storage::StoreInfo& info() const { return reader->info(); }
    bool remote() const { return !remote_version.empty(); }  // read over the network
    // The scene beside a store file that belongs to this version of it (storage/store_scene.hpp),
    // looked up when asked: the OBJ may be written after the store. None for remote stores.
    std::optional<std::string> scene_path() const;
    // scene_path() as the last scan saw it (what store lists say, without touching the disk).
    mutable std::atomic<bool> has_scene{false};
};

struct ReloadReport {
    unsigned added = 0, replaced = 0, removed = 0, failed = 0;
};

// How the registry reaches stores at s3:// and http(s):// locations (the server passes
// storage/remote_source.hpp's functions; without them such a location is an error).
struct RemoteStores {
    std::function<Result<std::unique_ptr<storage::ByteSource>>(const std::string& location)> open;
    std::function<Result<std::string>(const std::string& location)> version;  // ETag by HEAD
};

class StoreRegistry {
public:
    StoreRegistry(std::vector<std::string> files, std::vector<std::string> dirs, Logger& log,
                  MetricsRegistry& metrics, RemoteStores remote = {});
    ~StoreRegistry();  // removes its gauge callback from the registry
    StoreRegistry(const StoreRegistry&) = delete;
    StoreRegistry& operator=(const StoreRegistry&) = delete;
    // First scan. Errors when a named --store file cannot be opened or a directory is unreadable
    // (later reloads only log such problems and keep serving what they had).
    Status open();
    ReloadReport reload();

    // nullptr for unknown (or invalid) names. Never touches the file system.
    std::shared_ptr<const StoreHandle> find(std::string_view name) const;
    std::vector<std::shared_ptr<const StoreHandle>> list() const;  // sorted by name
    std::uint64_t reloads() const { return reloads_->value(); }      // rescans so far (start, SIGHUP, watch)

private:
    struct Scan;
    ReloadReport scan(bool first, Status* first_error);
    static bool is_remote(const std::string& location);
    void scan_remote(const std::string& name, const std::string& location, const std::shared_ptr<const StoreHandle>& prev, bool first,
                     std::vector<std::shared_ptr<const StoreHandle>>& next, ReloadReport& report, const std::function<void(Error)>& fail);
    StoreMetrics metrics_for(const std::string& name);
    // A handle for a store just opened (file or remote); the caller adds its identity.
    std::shared_ptr<StoreHandle> new_handle(const std::string& name, const std::string& path,
                                            std::shared_ptr<storage::StoreReader> reader);
    // Counts and logs a store added or replaced (with its ETag when it is remote).
    void announce(const StoreHandle& h, bool replaced, ReloadReport& report);

    std::vector<std::string> files_;
    std::vector<std::string> dirs_;
    RemoteStores remote_;
    Logger& log_;
    MetricsRegistry& metrics_;
    Counter* reloads_ = nullptr;
    std::mutex reload_mutex_;  // one scan at a time
    // Files in the store directories skipped for their names at the last scan (under
    // reload_mutex_): each is warned about when it first appears, not at every scan.
    std::set<std::string> skipped_files_;
    std::set<std::string> reported_errors_;  // the last scan's errors: logged when they first appear
    mutable std::mutex mutex_; // guards stores_ (a sorted snapshot, replaced whole)
    std::shared_ptr<const std::vector<std::shared_ptr<const StoreHandle>>> stores_;
};

}  // namespace tessera::server
