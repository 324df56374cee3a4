// Feedback traces: see feedback_trace.hpp for the format.
#include "tessera/client/feedback_trace.hpp"

#include <sys/stat.h>
#include <unistd.h>
#include <xxhash.h>
#include <zstd.h>

#include <cstring>
#include <filesystem>

#include "tessera/storage/output_file.hpp"

namespace tessera::client {
namespace {

constexpr char kMagic[8] = {'T', 'S', 'R', 'T', 'R', 'A', 'C', 'E'};
constexpr std::uint32_t kVersion = 1;
// Feedback buffers are at most the viewer's largest image (8192 a side, --feedback-scale 1): a
// bound against garbage, which would otherwise size the reader's buffers (2^16 a side: 16 GiB).
constexpr std::uint32_t kMaxSide = 8192;

template <class T>
void put(std::vector<std::uint8_t>& out, T v) {
    const auto* p = reinterpret_cast<const std::uint8_t*>(&v);
    out.insert(out.end(), p, p + sizeof(T));
}
template <class T>
bool get(std::FILE* f, T& v) {
    return std::fread(&v, sizeof(T), 1, f) == 1;
}

// Covers the frame's fields as well as its ids: a damaged frame number or bias is caught too.
std::uint64_t checksum(const std::vector<std::uint8_t>& fields, const std::vector<FeedbackId>& ids) {
    return XXH3_64bits_withSeed(fields.data(), fields.size(), XXH3_64bits(ids.data(), ids.size() * sizeof(FeedbackId)));
}

}  // namespace

Result<std::unique_ptr<TraceWriter>> TraceWriter::create(const std::string& path) {
    namespace fs = std::filesystem;
    std::unique_ptr<TraceWriter> w(new TraceWriter());
    w->path_ = path;
    const fs::path p(path);
    w->temp_ = storage::temp_path_beside(path, "tmp");
    std::error_code ec;
    if (fs::is_directory(p, ec)) return make_error(Errc::invalid_argument, "trace: '" + path + "' is a directory");
    storage::track_temp_path(w->temp_);  // an interrupted command removes it (tools/interrupt.hpp)
    w->file_ = std::fopen(w->temp_.c_str(), "wb");
    if (!w->file_) return make_error(Errc::io_error, "trace: cannot write '" + path + "': " + std::strerror(errno));
    std::vector<std::uint8_t> head(kMagic, kMagic + 8);
    put(head, kVersion);
    put(head, std::uint32_t{0});
    if (std::fwrite(head.data(), 1, head.size(), w->file_) != head.size())
        return make_error(Errc::io_error, "trace: write failed: " + path);
    return w;
}

TraceWriter::~TraceWriter() {
    if (file_) {
        std::fclose(file_);
        std::error_code ec;
        std::filesystem::remove(temp_, ec);
    }
    if (!temp_.empty()) storage::untrack_temp_path(temp_);
}

Status TraceWriter::write(const TraceFrame& f) {
    if (!file_) return make_error(Errc::invalid_argument, "trace: writer is closed");
    if (f.ids.size() != std::size_t(f.width) * f.height)
        return make_error(Errc::invalid_argument, "trace: frame ids do not match its size");
    if (f.width == 0 || f.height == 0 || f.width > kMaxSide || f.height > kMaxSide)
        return make_error(Errc::invalid_argument, "trace: a frame of " + std::to_string(f.width) + "x" +
                                                      std::to_string(f.height) + " (each side 1.." + std::to_string(kMaxSide) + ")");
    const std::size_t raw = f.ids.size() * sizeof(FeedbackId);
    buffer_.resize(ZSTD_compressBound(raw));
    const std::size_t n = ZSTD_compress(buffer_.data(), buffer_.size(), f.ids.data(), raw, 1);
    if (ZSTD_isError(n)) return make_error(Errc::io_error, std::string("trace: zstd: ") + ZSTD_getErrorName(n));
    std::vector<std::uint8_t> head;
    put(head, f.frame);
    put(head, f.time_s);
    put(head, f.bias);
    put(head, f.width);
    put(head, f.height);
    put(head, static_cast<std::uint32_t>(n));
    put(head, checksum(head, f.ids));
    if (std::fwrite(head.data(), 1, head.size(), file_) != head.size() || std::fwrite(buffer_.data(), 1, n, file_) != n)
        return make_error(Errc::io_error, "trace: write failed: " + path_);
    ++frames_;
    return {};
}

Status TraceWriter::close() {
    if (!file_) return make_error(Errc::invalid_argument, "trace: writer is closed");
    const bool ok = std::fflush(file_) == 0 && ::fsync(::fileno(file_)) == 0;
    std::fclose(file_);
    file_ = nullptr;
    std::error_code ec;
    if (!ok) {
        std::filesystem::remove(temp_, ec);
        return make_error(Errc::io_error, "trace: write failed: " + path_);
    }
    std::filesystem::rename(temp_, path_, ec);
    if (ec) {
        std::filesystem::remove(temp_, ec);
        return make_error(Errc::io_error, "trace: cannot rename into '" + path_ + "'");
    }
    return {};
}

Result<std::unique_ptr<TraceReader>> TraceReader::open(const std::string& path) {
    std::unique_ptr<TraceReader> r(new TraceReader());
    r->path_ = path;
    r->file_ = std::fopen(path.c_str(), "rb");
    if (!r->file_) return make_error(Errc::not_found, "trace: cannot open '" + path + "': " + std::strerror(errno));
    struct stat file_stat {};
    if (::fstat(::fileno(r->file_), &file_stat) != 0 || !S_ISREG(file_stat.st_mode))
        return make_error(Errc::invalid_argument, "trace: '" + path + "' is not a regular file");
    r->size_ = std::uint64_t(file_stat.st_size);
    if (auto st = r->rewind(); !st.ok()) return st.error();
    return r;
}

TraceReader::~TraceReader() {
    if (file_) std::fclose(file_);
}

Status TraceReader::rewind() {
    std::rewind(file_);
    char magic[8];
    std::uint32_t version = 0, reserved = 0;
    if (std::fread(magic, 1, 8, file_) != 8 || std::memcmp(magic, kMagic, 8) != 0)
        return make_error(Errc::invalid_argument, "trace: '" + path_ + "' is not a Tessera feedback trace");
    if (!get(file_, version) || !get(file_, reserved) || version != kVersion)
        return make_error(Errc::invalid_argument, "trace: '" + path_ + "': unsupported version " + std::to_string(version));
    return {};
}

Result<bool> TraceReader::next(TraceFrame& f) {
    if (!get(file_, f.frame)) return false;  // clean end
    std::uint32_t n = 0;
    std::uint64_t sum = 0;
    const auto bad = [&](const std::string& what) {
        return make_error(Errc::corrupt, "trace: '" + path_ + "' frame " + std::to_string(f.frame) + ": " + what);
    };
    if (!get(file_, f.time_s) || !get(file_, f.bias) || !get(file_, f.width) || !get(file_, f.height) || !get(file_, n) ||
        !get(file_, sum))
        return bad("truncated");
    if (f.width == 0 || f.height == 0 || f.width > kMaxSide || f.height > kMaxSide) return bad("bad size");
    // Nothing is sized from a field the file cannot back: the compressed bytes must be in the
    // file, and the zstd frame must say it holds exactly the frame's ids.
    const long at = std::ftell(file_);
    if (at < 0 || std::uint64_t(at) > size_ || n > size_ - std::uint64_t(at)) return bad("truncated");
    buffer_.resize(n);
    if (std::fread(buffer_.data(), 1, n, file_) != n) return bad("truncated");
    const std::size_t raw = std::size_t(f.width) * f.height * sizeof(FeedbackId);
    if (ZSTD_getFrameContentSize(buffer_.data(), n) != raw) return bad("corrupt data");
    f.ids.resize(std::size_t(f.width) * f.height);
    const std::size_t got = ZSTD_decompress(f.ids.data(), raw, buffer_.data(), n);
    if (ZSTD_isError(got) || got != raw) return bad("corrupt data");
    std::vector<std::uint8_t> fields;
    put(fields, f.frame);
    put(fields, f.time_s);
    put(fields, f.bias);
    put(fields, f.width);
    put(fields, f.height);
    put(fields, n);
    if (tessera::client::checksum(fields, f.ids) != sum) return bad("checksum mismatch");
    return true;
}

Result<std::vector<TraceFrame>> read_trace(const std::string& path) {
    auto r = TraceReader::open(path);
    if (!r) return r.error();
    std::vector<TraceFrame> frames;
    for (;;) {
        TraceFrame f;
        auto more = (*r)->next(f);
        if (!more) return more.error();
        if (!*more) break;
        frames.push_back(std::move(f));
    }
    if (frames.empty()) return make_error(Errc::invalid_argument, "trace: '" + path + "' has no frames");
    return frames;
}

}  // namespace tessera::client
