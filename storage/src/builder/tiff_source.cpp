// TIFF sources read directly with libtiff: the common container for huge images (BigTIFF,
// tiled or stripped), read in strips with little memory and no heavyweight dependencies.
// Layouts this reader does not handle (planar, palette, YCbCr, CMYK, odd bit depths) are
// reported as unsupported so the caller falls back to OpenImageIO.
#include <tiffio.h>

#include <cstdarg>
#include <cstdio>
#include <cstring>

#include "sources_internal.hpp"
#include "straight_alpha.hpp"

namespace tessera::storage {
namespace {

thread_local std::string tiff_error_text;

void tiff_error(const char* module, const char* fmt, va_list ap) {
    char buf[512];
    std::vsnprintf(buf, sizeof buf, fmt, ap);
    tiff_error_text = (module ? std::string(module) + ": " : std::string()) + buf;
}

class TiffSource final : public ImageSource {
public:
    TiffSource(TIFF* tif, SourceInfo info, bool associated) : tif_(tif), info_(std::move(info)), associated_(associated) {
        tiled_ = TIFFIsTiled(tif_) != 0;
        if (tiled_) {
            TIFFGetField(tif_, TIFFTAG_TILEWIDTH, &tw_);
            TIFFGetField(tif_, TIFFTAG_TILELENGTH, &th_);
        }
    }
    ~TiffSource() override { TIFFClose(tif_); }
    TiffSource(const TiffSource&) = delete;
    TiffSource& operator=(const TiffSource&) = delete;

    const SourceInfo& info() const override { return info_; }

    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const ParallelFor&) override {
        Status st = read_file_rows(y0, count, dst);
        if (st && associated_) build::make_alpha_straight(dst, std::size_t(info_.width) * count, info_);
        return st;
    }

private:
    // The file's own samples (alpha as the file holds it).
    Status read_file_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst) {
        const std::size_t texel = std::size_t(info_.channels) * sample_bytes(info_.sample_type);
        const std::size_t row = std::size_t(info_.width) * texel;
        tiff_error_text.clear();
        if (!tiled_) {
            if (std::size_t(TIFFScanlineSize64(tif_)) != row) return make_error(Errc::corrupt, info_.description + ": bad scanline size");
            for (std::uint32_t y = y0; y < y0 + count; ++y)
                if (TIFFReadScanline(tif_, dst + std::size_t(y - y0) * row, y, 0) < 0) return failure();
            return {};
        }
        // Tiled: decode one band of tiles at a time and copy out the wanted rows.
        const std::size_t tile_row = std::size_t(tw_) * texel;
        if (std::size_t(TIFFTileSize64(tif_)) != tile_row * th_) return make_error(Errc::corrupt, info_.description + ": bad tile size");
        tile_.resize(tile_row * th_);
        for (std::uint32_t y = y0; y < y0 + count;) {
            const std::uint32_t band = y / th_;
            if (!band_valid_ || band != band_index_) {
                const std::uint32_t b0 = band * th_, rows = std::min(th_, info_.height - b0);
                band_.resize(row * rows);
                for (std::uint32_t x = 0; x < info_.width; x += tw_) {
                    if (TIFFReadTile(tif_, tile_.data(), x, b0, 0, 0) < 0) return failure();
                    const std::size_t n = std::size_t(std::min(tw_, info_.width - x)) * texel;
                    for (std::uint32_t j = 0; j < rows; ++j)
                        std::memcpy(band_.data() + j * row + std::size_t(x) * texel, tile_.data() + j * tile_row, n);
                }
                band_index_ = band;
                band_valid_ = true;
            }
            const std::uint32_t end = std::min(y0 + count, (band + 1) * th_);
            std::memcpy(dst + std::size_t(y - y0) * row, band_.data() + std::size_t(y - band * th_) * row, row * (end - y));
            y = end;
        }
        return {};
    }

    Status failure() const {
        return make_error(Errc::corrupt, info_.description + ": " + (tiff_error_text.empty() ? "read failed" : tiff_error_text));
    }
    TIFF* tif_;
    SourceInfo info_;
    bool associated_;  // ExtraSamples says associated alpha: made straight as read
    bool tiled_ = false;
    std::uint32_t tw_ = 0, th_ = 0;
    std::vector<std::uint8_t> tile_, band_;
    std::uint32_t band_index_ = 0;
    bool band_valid_ = false;
};

}  // namespace

bool looks_like_tiff(const std::string& path) {
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (!f) return false;
    unsigned char m[4] = {};
    const bool ok = std::fread(m, 1, 4, f) == 4;
    std::fclose(f);
    return ok && ((m[0] == 'I' && m[1] == 'I' && (m[2] == 42 || m[2] == 43) && m[3] == 0) ||
                  (m[0] == 'M' && m[1] == 'M' && m[2] == 0 && (m[3] == 42 || m[3] == 43)));
}

Result<std::unique_ptr<ImageSource>> open_tiff_source(const std::string& path) {
    static const bool handlers_set = [] {
        TIFFSetErrorHandler(tiff_error);
        TIFFSetWarningHandler(nullptr);  // warnings about unknown tags are not ours to print
        return true;
    }();
    (void)handlers_set;
    tiff_error_text.clear();
    // "m": no memory mapping; mapped pages of a huge file would count as our resident memory.
    TIFF* tif = TIFFOpen(path.c_str(), "rm");
    if (!tif) return make_error(Errc::corrupt, "cannot read '" + path + "' as TIFF: " + tiff_error_text);
    std::uint32_t w = 0, h = 0;
    std::uint16_t spp = 1, bps = 1, fmt = SAMPLEFORMAT_UINT, planar = PLANARCONFIG_CONTIG, photo = 0;
    TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &w);
    TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &h);
    TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLESPERPIXEL, &spp);
    TIFFGetFieldDefaulted(tif, TIFFTAG_BITSPERSAMPLE, &bps);
    TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLEFORMAT, &fmt);
    TIFFGetFieldDefaulted(tif, TIFFTAG_PLANARCONFIG, &planar);
    TIFFGetField(tif, TIFFTAG_PHOTOMETRIC, &photo);
    SourceInfo info;
    info.description = path + " (TIFF)";
    info.width = w;
    info.height = h;
    info.channels = spp;
    const bool layout_ok = planar == PLANARCONFIG_CONTIG && spp >= 1 && spp <= 4 &&
                           (photo == PHOTOMETRIC_MINISBLACK || photo == PHOTOMETRIC_RGB) &&
                           (photo != PHOTOMETRIC_RGB || spp >= 3);
    if (fmt == SAMPLEFORMAT_UINT && bps == 8) info.sample_type = SampleType::u8;
    else if (fmt == SAMPLEFORMAT_UINT && bps == 16) info.sample_type = SampleType::u16;
    else if (fmt == SAMPLEFORMAT_IEEEFP && bps == 16) info.sample_type = SampleType::f16;
    else if (fmt == SAMPLEFORMAT_IEEEFP && bps == 32) info.sample_type = SampleType::f32;
    else {
        TIFFClose(tif);
        return make_error(Errc::unsupported, "TIFF sample layout needs OpenImageIO");
    }
    if (!layout_ok) {
        TIFFClose(tif);
        return make_error(Errc::unsupported, "TIFF layout needs OpenImageIO");
    }
    if (w == 0 || h == 0) {
        TIFFClose(tif);
        return make_error(Errc::invalid_argument, info.description + " has zero size");
    }
    info.has_alpha = spp == 2 || spp == 4;
    // ExtraSamples: 1 associated alpha, 2 unassociated, 0 unspecified (taken as straight, kept as is).
    bool associated = false;
    std::uint16_t extra_count = 0;
    std::uint16_t* extra = nullptr;
    if (info.has_alpha && TIFFGetField(tif, TIFFTAG_EXTRASAMPLES, &extra_count, &extra) && extra_count >= 1 && extra)
        associated = extra[extra_count - 1] == EXTRASAMPLE_ASSOCALPHA;
    if (associated) info.description = path + " (TIFF, associated alpha made straight)";
    std::uint16_t orientation = ORIENTATION_TOPLEFT;
    if (TIFFGetField(tif, TIFFTAG_ORIENTATION, &orientation) && orientation >= 1 && orientation <= 8)
        info.orientation = orientation;
    info.colour_space = (info.sample_type == SampleType::u8 || info.sample_type == SampleType::u16) ? ColourSpace::srgb
                                                                                                     : ColourSpace::linear;
    return std::unique_ptr<ImageSource>(new TiffSource(tif, std::move(info), associated));
}

}  // namespace tessera::storage
