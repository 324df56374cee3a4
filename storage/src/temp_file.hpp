#pragma once
// A file created beside its final destination under a hidden temporary name, removed on
// destruction unless committed by an atomic rename. This is how every output is written: a crash
// or an error never leaves a half-written file at the destination.
#include <cstdint>
#include <span>
#include <string>

#include "tessera/result.hpp"

namespace tessera::storage {

class TempFile {
public:
    // Creates "<dir>/.<name>.<tag>-<pid>-<n>" next to `final_path`.
    static Result<TempFile> create_beside(const std::string& final_path, const std::string& tag);

    TempFile(TempFile&& o) noexcept;
    TempFile& operator=(TempFile&& o) noexcept;
    TempFile(const TempFile&) = delete;
    TempFile& operator=(const TempFile&) = delete;
    ~TempFile();

    int fd() const { return fd_; }
    const std::string& path() const { return path_; }

    Status pwrite_all(std::uint64_t offset, std::span<const std::uint8_t> bytes) const;
    Status pread_all(std::uint64_t offset, std::span<std::uint8_t> bytes) const;
    // fsync, close, rename over `final_path`, fsync the directory; any failure before the rename
    // is an error (the destructor then removes the file). The file then belongs to final_path.
    Status commit(const std::string& final_path);

private:
    TempFile(int fd, std::string path) : fd_(fd), path_(std::move(path)) {}
    void discard();
    int fd_ = -1;
    std::string path_;
};

}  // namespace tessera::storage
