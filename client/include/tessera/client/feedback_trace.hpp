#pragma once
// A recorded feedback trace: the feedback buffers a viewer rendered, frame by frame, so the load
// tester can replay a real viewer's request sets without GL (`tessera view --trace FILE`,
// `tessera loadtest --trace FILE`). Format (little-endian; docs/client.md):
//
//   header   "TSRTRACE" (8 bytes), u32 version (1), u32 reserved (0)
//   frame*   u64 frame, f64 time_s, f32 bias, u32 width, u32 height,
//            u32 compressed bytes, u64 checksum (XXH3-64 of the fields before it,
//            seeded with XXH3-64 of the uncompressed ids),
//            zstd(width*height u64 feedback ids, row 0 at the top)
//
// The writer writes to a hidden temporary file beside the target and renames it on close(), so
// a killed viewer never leaves a half trace; the reader checks every frame's checksum.
#include <cstdint>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "tessera/client/page.hpp"
#include "tessera/result.hpp"

namespace tessera::client {

struct TraceFrame {
    std::uint64_t frame = 0;
    double time_s = 0;
    float bias = 0;
    std::uint32_t width = 0, height = 0;
    std::vector<FeedbackId> ids;
};

class TraceWriter {
public:
    static Result<std::unique_ptr<TraceWriter>> create(const std::string& path);
    ~TraceWriter();  // without close(): the temporary file is removed
    Status write(const TraceFrame& frame);
    Status close();  // flush and rename into place
    std::uint64_t frames() const { return frames_; }

private:
    TraceWriter() = default;
    std::string path_, temp_;
    std::FILE* file_ = nullptr;
    std::uint64_t frames_ = 0;
    std::vector<std::uint8_t> buffer_;
};

class TraceReader {
public:
    static Result<std::unique_ptr<TraceReader>> open(const std::string& path);
    ~TraceReader();
    // The next frame into `out`; false at the end. Errors: truncated or corrupt frames.
    Result<bool> next(TraceFrame& out);
    Status rewind();

private:
    TraceReader() = default;
    std::string path_;
    std::FILE* file_ = nullptr;
    std::uint64_t size_ = 0;  // the file's, at open
    std::vector<std::uint8_t> buffer_;
};

// Reads a whole trace (loadtest: every viewer replays it).
Result<std::vector<TraceFrame>> read_trace(const std::string& path);

}  // namespace tessera::client
