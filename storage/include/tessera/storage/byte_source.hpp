#pragma once
// Where a store reader's bytes come from: a file (read with pread, never mapped: a file truncated
// or rewritten under a reader must give errors, not SIGBUS), a buffer in memory, or an
// application's own source (object storage, an HTTP range reader, a test's slow disk), opened with
// StoreReader::open_source. Stores are meant to be replaced by rename; a file changed in place
// anyway is noticed by changed(). read() may be called from several threads at once.
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "tessera/result.hpp"

namespace tessera::storage {

class ByteSource {
public:
    virtual ~ByteSource() = default;
    virtual std::uint64_t size() const = 0;
    // Copies [offset, offset + length) into dst. Fails (corrupt) past the end.
    virtual Status read(std::uint64_t offset, std::uint64_t length, std::uint8_t* dst) const = 0;
    // True when the bytes may no longer be those that were opened (a file whose size or
    // modification time changed since). Costs a system call: ask after a failure, not per read.
    virtual bool changed() const { return false; }
    // The version of the bytes where the source knows one (a remote object's ETag); "" otherwise.
    virtual std::string version() const { return {}; }
    // Ends the reads that wait on a network at once (they fail with Errc::cancelled) and fails
    // every later one: for a server that is stopping. Nothing for local sources (a pread is not
    // interrupted). For good: the source is not read again.
    virtual void cancel() const {}
};

// The deadline of the request this thread is reading for (a server's HTTP request or gRPC
// batch): sources that wait on a network (remote stores) end their requests, retries and
// waits for a connection by then, so work past its deadline is cancelled, not waited on.
// Local files ignore it (a pread is not interrupted). time_point::max() when none is set.
std::chrono::steady_clock::time_point read_deadline();
// Sets read_deadline() for this thread while it lives (the earlier of it and any outer one).
class ReadDeadlineScope {
public:
    explicit ReadDeadlineScope(std::chrono::steady_clock::time_point deadline);
    ~ReadDeadlineScope();
    ReadDeadlineScope(const ReadDeadlineScope&) = delete;
    ReadDeadlineScope& operator=(const ReadDeadlineScope&) = delete;

private:
    std::chrono::steady_clock::time_point outer_;
};

Result<std::unique_ptr<ByteSource>> open_file_source(const std::string& path);
std::unique_ptr<ByteSource> memory_source(std::vector<std::uint8_t> bytes);

}  // namespace tessera::storage
