// make_upright_source() (sources_internal.hpp): a photo stored sideways or mirrored (EXIF/TIFF
// orientation 2..8, as cameras and phones write them) served as it is meant to be seen, the way
// every viewer shows it. A mirror of each row streams; the other orientations read rows bottom up
// or turn columns into rows, so the stored image is read whole first.
#include <atomic>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "sources_internal.hpp"

namespace tessera::storage {
namespace {

// Turned images held whole at once in this process, bytes together (set_turned_image_budget):
// past it a turn is refused rather than held in memory. A layered build reads its layers side by
// side, so a turned layer each holds its image at the same time: the limit is on their sum.
// Such images come from cameras; a tool that streams the turn (vips autorot) makes an upright
// file first.
constexpr std::uint64_t kDefaultTurnedBytes = std::uint64_t(2) << 30;
std::atomic<std::uint64_t> g_turned_limit{kDefaultTurnedBytes};
std::atomic<std::uint64_t> g_turned_held{0};

bool take_turned(std::uint64_t bytes) {
    std::uint64_t held = g_turned_held.load();
    do {
        if (bytes > g_turned_limit.load() || held > g_turned_limit.load() - bytes) return false;
    } while (!g_turned_held.compare_exchange_weak(held, held + bytes));
    return true;
}
void give_turned(std::uint64_t bytes) { g_turned_held.fetch_sub(bytes); }

std::string size_text(std::uint64_t bytes) {
    char buf[32];
    if (bytes < (std::uint64_t(1) << 20)) std::snprintf(buf, sizeof buf, "%.0f KiB", double(bytes) / 1024);
    else if (bytes < (std::uint64_t(1) << 30)) std::snprintf(buf, sizeof buf, "%.1f MiB", double(bytes) / (1 << 20));
    else std::snprintf(buf, sizeof buf, "%.2f GiB", double(bytes) / (1 << 30));
    return buf;
}

// The error for a turn that does not fit: the input, what it needs, the limit.
std::string too_large(const SourceInfo& s, std::uint64_t bytes) {
    return s.description + " is stored turned (orientation " + std::to_string(s.orientation) + "): turning it takes " +
           size_text(bytes) + " in memory, and the turned images held at once may take " + size_text(g_turned_limit.load()) +
           " together (" + size_text(g_turned_held.load()) + " held now); make upright copies first, e.g. vips autorot";
}


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
    ~UprightSource() override { give_turned(reserved_); }
    UprightSource(const UprightSource&) = delete;
    UprightSource& operator=(const UprightSource&) = delete;
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
            const std::uint64_t bytes = std::uint64_t(W) * H * texel_;
            if (!take_turned(bytes)) return make_error(Errc::unsupported, too_large(s, bytes));
            reserved_ = bytes;
            whole_.resize(bytes);
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
        if (y0 + count >= info_.height) {  // strips come once each, in order
            std::vector<std::uint8_t>().swap(whole_);
            give_turned(reserved_);
            reserved_ = 0;
        }
        return {};
    }

private:
    std::unique_ptr<ImageSource> stored_;
    SourceInfo info_;
    std::size_t texel_ = 0;
    std::uint64_t reserved_ = 0;  // bytes of the turned-image budget this source holds
    std::vector<std::uint8_t> whole_;
};

}  // namespace

std::uint64_t set_turned_image_budget(std::uint64_t bytes) { return g_turned_limit.exchange(bytes); }

Result<std::unique_ptr<ImageSource>> make_upright_source(std::unique_ptr<ImageSource> stored) {
    const SourceInfo& s = stored->info();
    if (s.orientation <= 1 || s.orientation > 8) return stored;
    // An image that could never be held is refused when opened. The budget itself is taken at
    // the first read: an atlas opens all its textures first and reads them one shelf at a time.
    const std::uint64_t bytes = std::uint64_t(s.width) * s.height * s.channels * sample_bytes(s.sample_type);
    if (s.orientation != 2 && bytes > g_turned_limit.load()) return make_error(Errc::unsupported, too_large(s, bytes));
    return std::unique_ptr<ImageSource>(new UprightSource(std::move(stored)));
}

}  // namespace tessera::storage
