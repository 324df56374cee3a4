#pragma once
// Where a reader's bytes come from: a file (the index region memory-mapped, payloads read with
// pread) or a buffer in memory. Both are immutable for the reader's lifetime: stores are replaced
// by rename, never rewritten in place.
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
    // Makes [0, length) addressable in memory for the lifetime of the source (the index region).
    virtual Result<const std::uint8_t*> map_prefix(std::uint64_t length) = 0;
};

Result<std::unique_ptr<ByteSource>> open_file_source(const std::string& path);
std::unique_ptr<ByteSource> memory_source(std::vector<std::uint8_t> bytes);

}  // namespace tessera::storage
