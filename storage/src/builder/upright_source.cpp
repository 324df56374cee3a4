// make_upright_source() (sources_internal.hpp): a photo stored sideways or mirrored (EXIF/TIFF
// orientation 2..8, as cameras and phones write them) served as it is meant to be seen, the way
// every viewer shows it. A mirror of each row streams; the other orientations read rows bottom up
// or turn columns into rows, so the stored image is read whole first.
#include <cstring>
#include <string>
#include <vector>

#include "sources_internal.hpp"

namespace tessera::storage {
namespace {

// Past this a turn is refused rather than held in memory: such images come from cameras, and a
// tool that streams the turn (vips autorot) makes an upright file first.
constexpr std::uint64_t kMaxWholeBytes = std::uint64_t(2) << 30;

class UprightSource final : public ImageSource {
public:
    explicit UprightSource(std::unique_ptr<ImageSource> stored) : stored_(std::move(stored)) {
        const SourceInfo& s = stored_->info();
        info_ = s;
        info_.orientation = 1;
        if (s.orientation >= 5) std::swap(info_.width, info_.height);  // 5..8 turn by a quarter
        info_.description = s.description + " turned upright (orientation " + std::to_string(s.orientation) + ")";
        texel_ = s.channels * sample_bytes(s.sample_type);
    }
    const SourceInfo& info() const override { return info_; }

    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const ParallelFor& parallel) override {
        const SourceInfo& s = stored_->info();
        const std::uint32_t W = s.width, H = s.height, o = s.orientation;
        if (o == 2) {  // left-right mirror: each row on its own, as it comes
            TESSERA_TRY(stored_->read_rows(y0, count, dst, parallel));
            std::vector<std::uint8_t> row(std::size_t(W) * texel_);
            for (std::uint32_t k = 0; k < count; ++k) {
                std::uint8_t* r = dst + std::size_t(k) * W * texel_;
                std::memcpy(row.data(), r, row.size());
                for (std::uint32_t x = 0; x < W; ++x) std::memcpy(r + std::size_t(x) * texel_, row.data() + std::size_t(W - 1 - x) * texel_, texel_);
            }
            return {};
        }
        if (whole_.empty()) {
            whole_.resize(std::size_t(W) * H * texel_);
            TESSERA_TRY(stored_->read_rows(0, H, whole_.data(), parallel));
        }
        const std::uint32_t w = info_.width;
        parallel(count, [&](std::size_t b, std::size_t e) {
            for (std::size_t k = b; k < e; ++k) {
                const std::uint32_t y = y0 + std::uint32_t(k);
                std::uint8_t* out = dst + k * std::size_t(w) * texel_;
                for (std::uint32_t x = 0; x < w; ++x) {
                    // (sx, sy): the stored texel shown at (x, y).
                    std::uint32_t sx = x, sy = y;
                    switch (o) {
                        case 3: sx = W - 1 - x; sy = H - 1 - y; break;
                        case 4: sy = H - 1 - y; break;
                        case 5: sx = y; sy = x; break;
                        case 6: sx = y; sy = H - 1 - x; break;
                        case 7: sx = W - 1 - y; sy = H - 1 - x; break;
                        case 8: sx = W - 1 - y; sy = x; break;
                        default: break;
                    }
                    std::memcpy(out + std::size_t(x) * texel_, whole_.data() + (std::size_t(sy) * W + sx) * texel_, texel_);
                }
            }
        });
        if (y0 + count >= info_.height) std::vector<std::uint8_t>().swap(whole_);  // strips come once each, in order
        return {};
    }

private:
    std::unique_ptr<ImageSource> stored_;
    SourceInfo info_;
    std::size_t texel_ = 0;
    std::vector<std::uint8_t> whole_;
};

}  // namespace

Result<std::unique_ptr<ImageSource>> make_upright_source(std::unique_ptr<ImageSource> stored) {
    const SourceInfo& s = stored->info();
    if (s.orientation <= 1 || s.orientation > 8) return stored;
    const std::uint64_t bytes = std::uint64_t(s.width) * s.height * s.channels * sample_bytes(s.sample_type);
    if (s.orientation != 2 && bytes > kMaxWholeBytes)
        return make_error(Errc::unsupported, s.description + " is stored turned (orientation " + std::to_string(s.orientation) +
                                                 ") and too large (" + std::to_string(bytes >> 20) +
                                                 " MiB) to turn in memory; make an upright copy first, e.g. vips autorot");
    return std::unique_ptr<ImageSource>(new UprightSource(std::move(stored)));
}

}  // namespace tessera::storage
