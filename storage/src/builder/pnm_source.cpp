// Binary PGM and PPM (P5, P6) read directly: OpenImageIO 2.4's PNM reader rescales 16-bit
// samples through floats and loses the lowest bit of about half of them. Rows are read where they
// lie in the file, so a file of any size streams. ASCII PNM, bitmaps (P4) and PAM are left to
// OpenImageIO.
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <vector>

#include "sources_internal.hpp"

namespace tessera::storage {
namespace {

class PnmSource final : public ImageSource {
public:
    PnmSource(std::FILE* f, SourceInfo info, long data_offset, std::uint32_t maxval)
        : f_(f), info_(std::move(info)), offset_(data_offset), maxval_(maxval) {}
    ~PnmSource() override { std::fclose(f_); }
    PnmSource(const PnmSource&) = delete;
    PnmSource& operator=(const PnmSource&) = delete;
    const SourceInfo& info() const override { return info_; }

    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const ParallelFor&) override {
        if (count == 0) return {};
        const std::size_t samples = std::size_t(info_.width) * info_.channels * count;
        const std::size_t file_bytes = samples * (maxval_ > 255 ? 2 : 1);
        const std::size_t row_bytes = file_bytes / count;
        raw_.resize(file_bytes);
        if (std::fseek(f_, offset_ + long(std::size_t(y0) * row_bytes), SEEK_SET) != 0 || std::fread(raw_.data(), 1, file_bytes, f_) != file_bytes)
            return make_error(Errc::corrupt, info_.description + ": the file ends before row " + std::to_string(y0 + count) +
                                                 (std::ferror(f_) ? std::string(" (") + std::strerror(errno) + ")" : std::string()));
        // Big-endian in the file; a maxval other than 255 or 65535 is scaled to the full range.
        for (std::size_t i = 0; i < samples; ++i) {
            const std::uint32_t v = maxval_ > 255 ? std::uint32_t(raw_[2 * i]) << 8 | raw_[2 * i + 1] : raw_[i];
            if (v > maxval_) return make_error(Errc::corrupt, info_.description + ": a sample is above the maxval " + std::to_string(maxval_));
            if (maxval_ > 255) {
                const std::uint16_t out = maxval_ == 65535 ? std::uint16_t(v) : std::uint16_t((v * 65535u + maxval_ / 2) / maxval_);
                std::memcpy(dst + 2 * i, &out, 2);
            } else {
                dst[i] = maxval_ == 255 ? std::uint8_t(v) : std::uint8_t((v * 255u + maxval_ / 2) / maxval_);
            }
        }
        return {};
    }

private:
    std::FILE* f_;
    SourceInfo info_;
    long offset_;
    std::uint32_t maxval_;
    std::vector<std::uint8_t> raw_;
};

// The next header number, skipping whitespace and # comments; -1 if there is none.
long long header_number(std::FILE* f) {
    int c = std::fgetc(f);
    for (;;) {
        while (c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\v' || c == '\f') c = std::fgetc(f);
        if (c != '#') break;
        while (c != '\n' && c != EOF) c = std::fgetc(f);
    }
    if (c < '0' || c > '9') return -1;
    long long v = 0;
    while (c >= '0' && c <= '9') {
        v = v * 10 + (c - '0');
        if (v > (1ll << 32)) return -1;
        c = std::fgetc(f);
    }
    // One whitespace character ends a number (the last one's is the last header byte); a comment
    // may follow a number at once, as netpbm reads it, and runs to the end of its line.
    if (c == '#') {
        while (c != '\n' && c != EOF) c = std::fgetc(f);
        return c == '\n' ? v : -1;
    }
    return (c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\v' || c == '\f') ? v : -1;
}

}  // namespace

bool looks_like_binary_pnm(const std::string& path) {
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (!f) return false;
    char m[2] = {};
    const bool ok = std::fread(m, 1, 2, f) == 2;
    std::fclose(f);
    return ok && m[0] == 'P' && (m[1] == '5' || m[1] == '6');
}

Result<std::unique_ptr<ImageSource>> open_pnm_source(const std::string& path) {
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (!f) return make_error(Errc::io_error, "cannot open '" + path + "': " + std::strerror(errno));
    char m[2];
    SourceInfo info;
    const bool magic = std::fread(m, 1, 2, f) == 2 && m[0] == 'P' && (m[1] == '5' || m[1] == '6');
    const long long w = magic ? header_number(f) : -1, h = w > 0 ? header_number(f) : -1, maxval = h > 0 ? header_number(f) : -1;
    info.description = path + (magic && m[1] == '5' ? " (PGM)" : " (PPM)");
    if (!magic || w <= 0 || h <= 0 || maxval <= 0 || maxval > 65535 || w > (1ll << 31) || h > (1ll << 31)) {
        std::fclose(f);
        return make_error(Errc::corrupt, info.description + ": not a valid binary PNM header (width, height, maxval 1 to 65535)");
    }
    info.width = std::uint32_t(w);
    info.height = std::uint32_t(h);
    info.channels = m[1] == '5' ? 1 : 3;
    info.sample_type = maxval > 255 ? SampleType::u16 : SampleType::u8;
    info.colour_space = ColourSpace::srgb;
    const long offset = std::ftell(f);
    return std::unique_ptr<ImageSource>(new PnmSource(f, std::move(info), offset, std::uint32_t(maxval)));
}

}  // namespace tessera::storage
