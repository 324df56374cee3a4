#include "byte_source.hpp"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace tessera::storage {
namespace {

class FileSource final : public ByteSource {
public:
    FileSource(int fd, std::uint64_t size) : fd_(fd), size_(size) {}
    ~FileSource() override {
        if (map_ != nullptr) ::munmap(map_, map_len_);
        ::close(fd_);
    }
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

    Result<const std::uint8_t*> map_prefix(std::uint64_t length) override {
        if (length > size_) return make_error(Errc::corrupt, "index extends past end of file");
        if (length == 0) return static_cast<const std::uint8_t*>(nullptr);
        void* p = ::mmap(nullptr, length, PROT_READ, MAP_SHARED, fd_, 0);
        if (p == MAP_FAILED) return make_error(Errc::io_error, std::string("mmap failed: ") + std::strerror(errno));
        map_ = p;
        map_len_ = length;
        return static_cast<const std::uint8_t*>(p);
    }

private:
    int fd_;
    std::uint64_t size_;
    void* map_ = nullptr;
    std::size_t map_len_ = 0;
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
    Result<const std::uint8_t*> map_prefix(std::uint64_t length) override {
        if (length > bytes_.size()) return make_error(Errc::corrupt, "index extends past end of buffer");
        return static_cast<const std::uint8_t*>(bytes_.data());
    }

private:
    std::vector<std::uint8_t> bytes_;
};

}  // namespace

Result<std::unique_ptr<ByteSource>> open_file_source(const std::string& path) {
    int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
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
    return std::unique_ptr<ByteSource>(new FileSource(fd, static_cast<std::uint64_t>(st.st_size)));
}

std::unique_ptr<ByteSource> memory_source(std::vector<std::uint8_t> bytes) {
    return std::make_unique<MemorySource>(std::move(bytes));
}

}  // namespace tessera::storage
