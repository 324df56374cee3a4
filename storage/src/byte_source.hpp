#pragma once
// Where a reader's bytes come from: a file (read with pread, never mapped: a file truncated or
// rewritten under a reader must give errors, not SIGBUS) or a buffer in memory. Stores are meant
// to be replaced by rename; a file changed in place anyway is noticed by changed().
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
};

Result<std::unique_ptr<ByteSource>> open_file_source(const std::string& path);
std::unique_ptr<ByteSource> memory_source(std::vector<std::uint8_t> bytes);

}  // namespace tessera::storage
