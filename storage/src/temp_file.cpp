#include "temp_file.hpp"

#include "tessera/storage/output_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <set>

namespace tessera::storage {
namespace {
std::string errno_text() { return std::strerror(errno); }

struct TempRegistry {
    std::mutex mutex;
    std::multiset<std::string> paths;
};
TempRegistry& registry() {
    static auto* r = new TempRegistry;  // never destroyed: usable by threads still running at exit
    return *r;
}
}  // namespace

void track_temp_path(const std::string& path) {
    TempRegistry& r = registry();
    std::lock_guard lock(r.mutex);
    r.paths.insert(path);
}

void untrack_temp_path(const std::string& path) {
    TempRegistry& r = registry();
    std::lock_guard lock(r.mutex);
    if (auto it = r.paths.find(path); it != r.paths.end()) r.paths.erase(it);
}

void remove_temp_paths_for_exit() {
    TempRegistry& r = registry();
    r.mutex.lock();  // not unlocked: a thread creating or committing a file waits until the process ends
    for (const std::string& p : r.paths) {
        std::error_code ec;
        std::filesystem::remove_all(p, ec);
    }
    r.paths.clear();
}

Status check_output_file(const std::string& path) {
    struct stat st {};
    if (::lstat(path.c_str(), &st) != 0) {
        if (errno == ENOENT || errno == ENOTDIR) return {};  // nothing to replace; creating the file says what is wrong
        return make_error(Errc::io_error, "cannot check output path '" + path + "': " + errno_text());
    }
    if (S_ISREG(st.st_mode)) return {};
    if (S_ISDIR(st.st_mode)) return make_error(Errc::invalid_argument, "output path '" + path + "' is a directory");
    if (S_ISLNK(st.st_mode))
        return make_error(Errc::invalid_argument, "output path '" + path +
                                                      "' is a symbolic link, which writing would replace; name the file itself");
    const char* what = S_ISFIFO(st.st_mode) ? "a FIFO" : S_ISSOCK(st.st_mode) ? "a socket" : "a device";
    return make_error(Errc::invalid_argument, "output path '" + path + "' is " + what +
                                                  ", not a regular file; the output replaces its path whole, so name a file");
}

std::string temp_path_beside(const std::string& final_path, const std::string& tag) {
    static std::atomic<unsigned> counter{0};
    const std::filesystem::path p(final_path);
    const std::filesystem::path dir = p.has_parent_path() ? p.parent_path() : std::filesystem::path(".");
    return (dir / ("." + p.filename().string() + "." + tag + "-" + std::to_string(::getpid()) + "-" +
                   std::to_string(counter.fetch_add(1))))
        .string();
}

Result<TempFile> TempFile::create_beside(const std::string& final_path, const std::string& tag) {
    const std::filesystem::path p(final_path);
    if (p.filename().empty()) return make_error(Errc::invalid_argument, "output path '" + final_path + "' names no file");
    const std::filesystem::path dir = p.has_parent_path() ? p.parent_path() : std::filesystem::path(".");
    TESSERA_TRY(check_output_file(final_path));
    for (int attempt = 0; attempt < 100; ++attempt) {
        const std::string path = temp_path_beside(final_path, tag);
        track_temp_path(path);  // before the file exists: an interrupt never misses it
        int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
        if (fd >= 0) return TempFile(fd, path);
        untrack_temp_path(path);
        if (errno != EEXIST)
            return make_error(Errc::io_error, "cannot write to '" + dir.string() + "': " + errno_text());
    }
    return make_error(Errc::io_error, "cannot create a temporary file in '" + dir.string() + "'");
}

TempFile::TempFile(TempFile&& o) noexcept : fd_(o.fd_), path_(std::move(o.path_)) { o.fd_ = -1; o.path_.clear(); }

TempFile& TempFile::operator=(TempFile&& o) noexcept {
    if (this != &o) {
        discard();
        fd_ = o.fd_;
        path_ = std::move(o.path_);
        o.fd_ = -1;
        o.path_.clear();
    }
    return *this;
}

TempFile::~TempFile() { discard(); }

void TempFile::discard() {
    if (fd_ >= 0) ::close(fd_);
    if (!path_.empty()) {
        ::unlink(path_.c_str());
        untrack_temp_path(path_);
    }
    fd_ = -1;
    path_.clear();
}

Status TempFile::pwrite_all(std::uint64_t offset, std::span<const std::uint8_t> bytes) const {
    std::size_t done = 0;
    while (done < bytes.size()) {
        ssize_t n = ::pwrite(fd_, bytes.data() + done, bytes.size() - done, static_cast<off_t>(offset + done));
        if (n < 0) {
            if (errno == EINTR) continue;
            return make_error(Errc::io_error, "write to '" + path_ + "' failed: " + errno_text());
        }
        done += static_cast<std::size_t>(n);
    }
    return {};
}

Status TempFile::pread_all(std::uint64_t offset, std::span<std::uint8_t> bytes) const {
    std::size_t done = 0;
    while (done < bytes.size()) {
        ssize_t n = ::pread(fd_, bytes.data() + done, bytes.size() - done, static_cast<off_t>(offset + done));
        if (n < 0) {
            if (errno == EINTR) continue;
            return make_error(Errc::io_error, "read from '" + path_ + "' failed: " + errno_text());
        }
        if (n == 0) return make_error(Errc::io_error, "unexpected end of '" + path_ + "'");
        done += static_cast<std::size_t>(n);
    }
    return {};
}

Status TempFile::commit(const std::string& final_path) {
    TESSERA_TRY(check_output_file(final_path));  // something may have appeared there since create_beside
    if (::fsync(fd_) != 0) return make_error(Errc::io_error, "fsync of '" + path_ + "' failed: " + errno_text());
    // close reports write-back errors too (NFS): checked before the file takes the output's place.
    const int closed = ::close(fd_);
    fd_ = -1;
    if (closed != 0) return make_error(Errc::io_error, "closing '" + path_ + "' failed: " + errno_text());
    if (::rename(path_.c_str(), final_path.c_str()) != 0)
        return make_error(Errc::io_error, "cannot rename into '" + final_path + "': " + errno_text());
    untrack_temp_path(path_);
    path_.clear();  // the file is no longer ours to remove
    const std::filesystem::path dir = std::filesystem::path(final_path).has_parent_path()
                                          ? std::filesystem::path(final_path).parent_path()
                                          : std::filesystem::path(".");
    int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (dfd >= 0) {
        ::fsync(dfd);  // makes the rename durable; failure here cannot un-rename, so it is not an error
        ::close(dfd);
    }
    return {};
}

}  // namespace tessera::storage
