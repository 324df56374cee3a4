#pragma once
// Whole-store verification: the index, every checksum, the data layout, optionally every decode.
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "tessera/storage/store_reader.hpp"

namespace tessera::storage {

struct VerifyOptions {
    bool decode = false;          // also decode every tile (slower; catches codec-level damage)
    std::size_t max_problems = 1000;  // stop listing after this many (the count keeps going)
    std::function<void(std::uint64_t done, std::uint64_t total)> progress;
};

struct VerifyReport {
    std::uint64_t tiles_checked = 0;
    std::uint64_t payloads_checked = 0;
    std::uint64_t bytes_checked = 0;
    std::uint64_t problem_count = 0;
    std::vector<std::string> problems;  // one line each, naming the tile
    bool ok() const { return problem_count == 0; }
};

VerifyReport verify_store(const StoreReader& reader, const VerifyOptions& options = {});

}  // namespace tessera::storage
