#include "store_registry.hpp"

#include <sys/stat.h>

#include <algorithm>
#include <filesystem>
#include <map>
#include <system_error>

#include "tessera/protocol/wire.hpp"
#include "tessera/storage/store_scene.hpp"

namespace tessera::server {

namespace fs = std::filesystem;

namespace {

struct FileIdentity {
    std::uint64_t device = 0, inode = 0, size = 0;
    std::int64_t mtime_ns = 0;
    friend bool operator==(const FileIdentity&, const FileIdentity&) = default;
};

bool identify(const std::string& path, FileIdentity& id) {
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) return false;
    id.device = st.st_dev;
    id.inode = st.st_ino;
    id.size = static_cast<std::uint64_t>(st.st_size);
    id.mtime_ns = std::int64_t(st.st_mtim.tv_sec) * 1'000'000'000 + st.st_mtim.tv_nsec;
    return true;
}

FileIdentity identity_of(const StoreHandle& h) { return {h.device, h.inode, h.size, h.mtime_ns}; }

}  // namespace

StoreRegistry::StoreRegistry(std::vector<std::string> files, std::vector<std::string> dirs, Logger& log,
                             MetricsRegistry& metrics, RemoteStores remote)
    : files_(std::move(files)),
      dirs_(std::move(dirs)),
      remote_(std::move(remote)),
      log_(log),
      metrics_(metrics),
      stores_(std::make_shared<const std::vector<std::shared_ptr<const StoreHandle>>>()) {
    reloads_ = &metrics_.counter("tessera_store_reloads_total", "Store rescans (start, SIGHUP, watch)");
    metrics_.gauge_callback("tessera_stores", "Stores being served", {}, [this] { return double(list().size()); });
}

StoreRegistry::~StoreRegistry() { metrics_.remove_callbacks("tessera_stores"); }

StoreMetrics StoreRegistry::metrics_for(const std::string& name) {
    const Labels labels{{"store", name}};
    StoreMetrics m;
    m.tiles_sent = &metrics_.counter("tessera_store_tiles_sent_total", "Tiles sent, per store", labels);
    m.bytes_sent = &metrics_.counter("tessera_store_bytes_sent_total", "Tile payload bytes sent, per store", labels);
    m.data_loss = &metrics_.counter("tessera_store_data_loss_total",
                                    "Tiles that failed their checksum and were not served", labels);
    m.requests = &metrics_.counter("tessera_store_requests_total", "Tile requests received, per store", labels);
    return m;
}

Status StoreRegistry::open() {
    Status first_error = Status();
    scan(true, &first_error);
    return first_error;
}

ReloadReport StoreRegistry::reload() { return scan(false, nullptr); }

namespace {

// A location as logs and errors show it: a remote one without its query, which may hold a
// credential (a signed URL, an Azure SAS), as the remote source's own errors show it.
std::string shown(const std::string& location) {
    if (!location.starts_with("s3://") && !location.starts_with("http://") && !location.starts_with("https://")) return location;
    const auto q = location.find_first_of("?#");
    return q == std::string::npos ? location : location.substr(0, q) + "?...";
}

}  // namespace

bool StoreRegistry::is_remote(const std::string& location) {
    return location.starts_with("s3://") || location.starts_with("http://") || location.starts_with("https://");
}

// A remote store: unchanged while its version (ETag, one HEAD) is the one it was opened at;
// otherwise opened again as a new version. While the remote cannot be reached, the version
// already open keeps serving.
void StoreRegistry::scan_remote(const std::string& name, const std::string& location, const std::shared_ptr<const StoreHandle>& prev,
                                bool first, std::vector<std::shared_ptr<const StoreHandle>>& next, ReloadReport& report,
                                const std::function<void(Error)>& fail) {
    if (!remote_.open || !remote_.version) {
        fail(Error{Errc::unsupported, "store " + shown(location) + ": remote stores are not available in this program"});
        ++report.failed;
        return;
    }
    if (prev && prev->path == location && !prev->stale.load()) {
        auto v = remote_.version(location);
        if (!v && v.error().code == Errc::not_found) {  // deleted: dropped, as a vanished file
            ++report.removed;
            log_.info("store removed", {{"store", name}, {"path", shown(location)}});
            return;
        }
        if (!v) {
            if (!first) log_.warn("remote store unreachable; serving the version already open", {{"store", name}, {"error", v.error().message}});
            next.push_back(prev);
            return;
        }
        if (*v == prev->remote_version) {
            next.push_back(prev);
            return;
        }
    }
    auto src = remote_.open(location);
    std::string version = src ? (*src)->version() : std::string();
    auto reader = src ? storage::StoreReader::open_source(std::move(*src), shown(location))
                      : Result<std::shared_ptr<storage::StoreReader>>(src.error());
    if (!reader) {
        fail(Error{reader.error().code, "store " + name + " (" + shown(location) + "): " + reader.error().message});
        ++report.failed;
        if (prev) next.push_back(prev);
        return;
    }
    auto h = new_handle(name, location, std::move(*reader));
    h->remote_version = version;
    announce(*h, prev != nullptr, report);
    next.push_back(std::move(h));
}

std::optional<std::string> StoreHandle::scene_path() const {
    if (remote()) return std::nullopt;
    return storage::find_scene_beside(path, version);
}

std::shared_ptr<StoreHandle> StoreRegistry::new_handle(const std::string& name, const std::string& path,
                                                       std::shared_ptr<storage::StoreReader> reader) {
    auto h = std::make_shared<StoreHandle>();
    h->name = name;
    h->path = path;
    h->reader = std::move(reader);
    h->version = h->reader->info().store_id;
    h->metrics = metrics_for(name);
    return h;
}

void StoreRegistry::announce(const StoreHandle& h, bool replaced, ReloadReport& report) {
    char id[24];
    std::snprintf(id, sizeof id, "%016llx", static_cast<unsigned long long>(h.version));
    if (!replaced) {
        ++report.added;
        log_.info("store added", {{"store", h.name}, {"path", shown(h.path)}, {"version", id}, {"etag", h.remote_version},
                                  {"width", h.info().width}, {"height", h.info().height}});
    } else {
        ++report.replaced;
        log_.info("store replaced", {{"store", h.name}, {"path", shown(h.path)}, {"version", id}, {"etag", h.remote_version}});
    }
}

ReloadReport StoreRegistry::scan(bool first, Status* first_error) {
    std::lock_guard scan_lock(reload_mutex_);
    reloads_->inc();
    // An error is logged when it first appears, not again on every rescan while it lasts (a
    // dangling link in a watched directory would log one line every --watch-interval).
    std::set<std::string> errors_now;
    std::function<void(Error)> fail = [&](Error e) {
        if (!reported_errors_.contains(e.message)) log_.error("store scan", {{"error", e.message}});
        errors_now.insert(e.message);
        if (first_error && first_error->ok()) *first_error = std::move(e);
    };

    // What the configuration names now: name -> path. Explicit files win over directory entries.
    std::map<std::string, std::string> wanted;
    std::set<std::string> skipped;
    // Directories this scan could not list whole (permissions, a network file system's glitch,
    // moved away): their stores stay as they are, rather than all being dropped at once.
    std::set<fs::path> unlisted;
    auto folder = [](const fs::path& p) {  // "stores/" and "stores" alike
        fs::path n = p.lexically_normal();
        return n.has_filename() ? n : n.parent_path();
    };
    for (const auto& dir : dirs_) {
        std::error_code ec;
        fs::directory_iterator it(dir, ec), end;
        if (ec) {
            fail(Error{Errc::io_error, "cannot read store directory " + dir + ": " + ec.message() +
                                           " (its stores already open are kept)"});
            unlisted.insert(folder(dir));
            continue;
        }
        for (; it != end; it.increment(ec)) {
            if (ec) break;
            const std::string file = it->path().filename().string();
            if (!file.ends_with(".tsr")) continue;
            const std::string name = protocol::store_name_of_file(file);
            if (name.empty()) {
                const std::string path = it->path().string();
                if (!skipped_files_.contains(path))
                    log_.warn("skipping store file: its name is not an identifier (letters, digits, _ . -)", {{"path", path}});
                skipped.insert(path);
                continue;
            }
            wanted[name] = it->path().string();
        }
        if (ec) {
            fail(Error{Errc::io_error, "cannot list store directory " + dir + " to its end: " + ec.message() +
                                           " (its stores already open are kept)"});
            unlisted.insert(folder(dir));
        }
    }
    std::map<std::string, std::string> named;  // name -> the --store that gave it
    for (const auto& file : files_) {
        // A remote location's name is its last path segment (its query aside), as a file's.
        const std::string path = is_remote(file) ? file.substr(0, file.find_first_of("?#")) : file;
        const std::string leaf = is_remote(file) ? path.substr(path.find_last_of('/') + 1) : fs::path(file).filename().string();
        const std::string name = protocol::store_name_of_file(leaf);
        if (name.empty()) {
            fail(Error{Errc::invalid_argument,
                       "store file " + shown(file) + ": the name must be <identifier>.tsr (letters, digits, _ . -)"});
            continue;
        }
        if (const auto [it, fresh] = named.emplace(name, file); !fresh) {
            if (it->second == file) continue;  // the same location twice (overlapping globs): one store
            // Two --store locations of one name: a client could not say which it means.
            fail(Error{Errc::invalid_argument, "two stores named '" + name + "': " + shown(it->second) + " and " + shown(file) +
                                                   " (a store is named by its file name)"});
            continue;
        }
        wanted[name] = file;
    }
    skipped_files_ = std::move(skipped);

    auto current = [&] {
        std::lock_guard lock(mutex_);
        return stores_;
    }();
    std::map<std::string, std::shared_ptr<const StoreHandle>> old;
    for (const auto& h : *current) old[h->name] = h;

    ReloadReport report;
    auto next = std::make_shared<std::vector<std::shared_ptr<const StoreHandle>>>();
    for (const auto& [name, path] : wanted) {
        const auto prev = old.find(name);
        if (is_remote(path)) {
            scan_remote(name, path, prev == old.end() ? nullptr : prev->second, first, *next, report, fail);
            continue;
        }
        FileIdentity id;
        if (!identify(path, id)) {
            fail(Error{Errc::not_found, "store file " + path + " does not exist or is not a regular file"});
            ++report.failed;
            if (prev != old.end() && !first) {
                // Vanished: drop it (a file given by --store that comes back is picked up again).
                ++report.removed;
                log_.info("store removed", {{"store", name}, {"path", path}});
            }
            continue;
        }
        const bool same_file = prev != old.end() && prev->second->path == path;
        if (same_file && identity_of(*prev->second) == id && !prev->second->stale.load()) {
            next->push_back(prev->second);  // unchanged
            continue;
        }
        // The same inode with a new size or mtime: the old version's bytes may be gone from under
        // it. Unless it opens again to the same size and index (a touch, a backup restoring the
        // time, a copy of the same bytes): then it is the version already served, and nothing is
        // refused while the new handle is made.
        const bool in_place = same_file && prev->second->device == id.device && prev->second->inode == id.inode;
        auto reader = storage::StoreReader::open(path);
        const bool unchanged = in_place && reader && (*reader)->info().store_id == prev->second->version &&
                               id.size == prev->second->size;
        if (unchanged) {
            log_.info("store file touched; its contents are the version served", {{"store", name}, {"path", path}});
        } else if (in_place && !prev->second->stale.exchange(true)) {
            log_.error("store file changed in place; not serving it until it opens as a new version",
                       {{"store", name}, {"path", path}});
        }
        if (!reader) {
            fail(Error{reader.error().code, "store " + name + " (" + path + "): " + reader.error().message});
            ++report.failed;
            // Renamed over: the old file is intact behind its descriptor, keep serving it. Changed
            // in place: keep the stale handle listed, so its requests are answered UNAVAILABLE.
            if (prev != old.end()) next->push_back(prev->second);
            continue;
        }
        auto h = new_handle(name, path, std::move(*reader));
        h->device = id.device;
        h->inode = id.inode;
        h->size = id.size;
        h->mtime_ns = id.mtime_ns;
        if (!unchanged) announce(*h, prev != old.end(), report);
        next->push_back(std::move(h));
    }
    for (const auto& [name, h] : old) {
        if (wanted.contains(name)) continue;
        if (!is_remote(h->path) && unlisted.contains(folder(fs::path(h->path).parent_path()))) {
            next->push_back(h);  // its directory could not be listed: kept, as it is
            continue;
        }
        ++report.removed;
        log_.info("store removed", {{"store", name}, {"path", shown(h->path)}});
    }
    std::sort(next->begin(), next->end(), [](const auto& a, const auto& b) { return a->name < b->name; });
    // Scenes beside the stores, looked up again on every scan (an OBJ may arrive after its store).
    for (const auto& h : *next) h->has_scene.store(h->scene_path().has_value(), std::memory_order_relaxed);
    {
        std::lock_guard lock(mutex_);
        stores_ = std::move(next);
    }
    reported_errors_ = std::move(errors_now);
    if (!first && (report.added || report.replaced || report.removed))
        log_.info("stores reloaded", {{"added", report.added}, {"replaced", report.replaced},
                                      {"removed", report.removed}, {"failed", report.failed}});
    return report;
}

std::shared_ptr<const StoreHandle> StoreRegistry::find(std::string_view name) const {
    if (!protocol::valid_store_name(name)) return nullptr;
    // Searched under the lock (a few comparisons): only the handle found is copied, not the
    // snapshot, whose shared count every request would otherwise pass between threads.
    std::lock_guard lock(mutex_);
    auto it = std::lower_bound(stores_->begin(), stores_->end(), name,
                               [](const auto& h, std::string_view n) { return h->name < n; });
    if (it == stores_->end() || (*it)->name != name) return nullptr;
    return *it;
}

std::vector<std::shared_ptr<const StoreHandle>> StoreRegistry::list() const {
    std::lock_guard lock(mutex_);
    return *stores_;
}

}  // namespace tessera::server
