#include "tessera/storage/byte_source.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

namespace tessera::storage {
namespace {

class FileSource final : public ByteSource {
public:
    FileSource(int fd, std::uint64_t size, timespec mtime) : fd_(fd), size_(size), mtime_(mtime) {}
    ~FileSource() override { ::close(fd_); }
    FileSource(const FileSource&) = delete;
    FileSource& operator=(const FileSource&) = delete;

    std::uint64_t size() const override { return size_; }

    Status read(std::uint64_t offset, std::uint64_t length, std::uint8_t* dst) const override {
        if (offset > size_ || length > size_ - offset)
            return make_error(Errc::corrupt, "read past end of file (truncated store?)");
        std::uint64_t done = 0;
        while (done < length) {
            ssize_t n = ::pread(fd_, dst + done, length - done, static_cast<off_t>(offset + done));
            if (n < 0) {
                if (errno == EINTR) continue;
                return make_error(Errc::io_error, std::string("read failed: ") + std::strerror(errno));
            }
            if (n == 0) return make_error(Errc::corrupt, "unexpected end of file (truncated store?)");
            done += static_cast<std::uint64_t>(n);
        }
        return {};
    }

    bool changed() const override {
        struct stat st {};
        if (::fstat(fd_, &st) != 0) return true;
        return static_cast<std::uint64_t>(st.st_size) != size_ || st.st_mtim.tv_sec != mtime_.tv_sec ||
               st.st_mtim.tv_nsec != mtime_.tv_nsec;
    }

private:
    int fd_;
    std::uint64_t size_;
    timespec mtime_;  // at open
};

class MemorySource final : public ByteSource {
public:
    explicit MemorySource(std::vector<std::uint8_t> bytes) : bytes_(std::move(bytes)) {}
    std::uint64_t size() const override { return bytes_.size(); }
    Status read(std::uint64_t offset, std::uint64_t length, std::uint8_t* dst) const override {
        if (offset > bytes_.size() || length > bytes_.size() - offset)
            return make_error(Errc::corrupt, "read past end of buffer (truncated store?)");
        if (length > 0) std::memcpy(dst, bytes_.data() + offset, length);
        return {};
    }
private:
    std::vector<std::uint8_t> bytes_;
};

}  // namespace

Result<std::unique_ptr<ByteSource>> open_file_source(const std::string& path) {
    // O_NONBLOCK: opening a FIFO for reading would wait for a writer (regular files ignore it).
    int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
    if (fd < 0) {
        int e = errno;
        return make_error(e == ENOENT ? Errc::not_found : Errc::io_error,
                          "cannot open '" + path + "': " + std::strerror(e));
    }
    struct stat st {};
    if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
        ::close(fd);
        return make_error(Errc::invalid_argument, "'" + path + "' is not a regular file");
    }
    return std::unique_ptr<ByteSource>(new FileSource(fd, static_cast<std::uint64_t>(st.st_size), st.st_mtim));
}

std::unique_ptr<ByteSource> memory_source(std::vector<std::uint8_t> bytes) {
    return std::make_unique<MemorySource>(std::move(bytes));
}

namespace {
thread_local std::chrono::steady_clock::time_point t_read_deadline = std::chrono::steady_clock::time_point::max();
}

std::chrono::steady_clock::time_point read_deadline() { return t_read_deadline; }

ReadDeadlineScope::ReadDeadlineScope(std::chrono::steady_clock::time_point deadline) : outer_(t_read_deadline) {
    t_read_deadline = std::min(outer_, deadline);
}

ReadDeadlineScope::~ReadDeadlineScope() { t_read_deadline = outer_; }

}  // namespace tessera::storage
