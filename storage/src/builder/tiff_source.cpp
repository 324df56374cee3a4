// TIFF sources read directly with libtiff: the common container for huge images (BigTIFF,
// tiled or stripped), read in strips with little memory and no heavyweight dependencies.
// JPEG-compressed YCbCr is read as RGB (libjpeg converts it), and strips of 1-, 2- or 4-bit grey
// are expanded to 8 bits. Layouts this reader does not handle (planar, palette, other YCbCr, CMYK,
// tiles of fewer than 8 bits) are reported as unsupported so the caller falls back to OpenImageIO.
// Tiles and strips with no bytes (GDAL's SPARSE_OK) read as zeros.
#include <tiffio.h>

#include <algorithm>
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
    // `bits`: 1, 2 or 4 for packed grey (expanded to 8 bits; `white_is_zero` inverts), else 0.
    TiffSource(TIFF* tif, SourceInfo info, bool associated, unsigned bits = 0, bool white_is_zero = false)
        : tif_(tif), info_(std::move(info)), associated_(associated), bits_(bits), white_is_zero_(white_is_zero) {
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
            const std::size_t packed = bits_ ? (std::size_t(info_.width) * bits_ + 7) / 8 : row;
            if (std::size_t(TIFFScanlineSize64(tif_)) != packed) return make_error(Errc::corrupt, info_.description + ": bad scanline size");
            if (bits_) packed_.resize(packed);
            for (std::uint32_t y = y0; y < y0 + count; ++y) {
                std::uint8_t* out = dst + std::size_t(y - y0) * row;
                if (TIFFGetStrileByteCount(tif_, TIFFComputeStrip(tif_, y, 0)) == 0) {  // a strip with no data: samples 0
                    std::memset(out, bits_ && white_is_zero_ ? 255 : 0, row);
                    continue;
                }
                if (TIFFReadScanline(tif_, bits_ ? packed_.data() : out, y, 0) < 0) return failure();
                if (bits_) expand_bits(out);
            }
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
                    if (TIFFGetStrileByteCount(tif_, TIFFComputeTile(tif_, x, b0, 0, 0)) == 0)  // a tile with no data
                        std::fill(tile_.begin(), tile_.end(), std::uint8_t{0});
                    else if (TIFFReadTile(tif_, tile_.data(), x, b0, 0, 0) < 0)
                        return failure();
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

    // packed_ (bits_ per texel, first texel in the high bits) to one byte per texel at dst.
    void expand_bits(std::uint8_t* dst) const {
        const unsigned mask = (1u << bits_) - 1;
        for (std::uint32_t x = 0; x < info_.width; ++x) {
            const std::size_t bit = std::size_t(x) * bits_;
            const unsigned v = (packed_[bit / 8] >> (8 - bits_ - bit % 8)) & mask;
            const unsigned grey = v * 255u / mask;
            dst[x] = static_cast<std::uint8_t>(white_is_zero_ ? 255u - grey : grey);
        }
    }

    Status failure() const {
        return make_error(Errc::corrupt, info_.description + ": " + (tiff_error_text.empty() ? "read failed" : tiff_error_text));
    }
    TIFF* tif_;
    SourceInfo info_;
    bool associated_;  // ExtraSamples says associated alpha: made straight as read
    unsigned bits_ = 0;
    bool white_is_zero_ = false;
    std::vector<std::uint8_t> packed_;
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
    std::uint16_t compression = COMPRESSION_NONE;
    TIFFGetFieldDefaulted(tif, TIFFTAG_COMPRESSION, &compression);
    // Grey with extra bands, the last not marked alpha, is multi-band data (GDAL writes 2- and
    // 4-band rasters of other than 8-bit RGBA so: blue, green, red, near-infrared), not grey and
    // alpha or RGBA: read as such, a band of data would weight the mips and decide which tiles
    // --sparse drops. Checked before any layout is left to OpenImageIO (planar bands, 16-bit
    // signed samples), which would take the last band as alpha too. An RGB file's unspecified
    // fourth band stays alpha, as libtiff reads it.
    if ((spp == 2 || spp == 4) && (photo == PHOTOMETRIC_MINISBLACK || photo == PHOTOMETRIC_MINISWHITE)) {
        std::uint16_t bands_extra = 0;
        std::uint16_t* bands_kind = nullptr;
        if (TIFFGetField(tif, TIFFTAG_EXTRASAMPLES, &bands_extra, &bands_kind) && bands_extra >= 1 && bands_kind &&
            bands_kind[bands_extra - 1] == EXTRASAMPLE_UNSPECIFIED) {
            TIFFClose(tif);
            return make_error(Errc::invalid_argument,
                              path + " has " + std::to_string(spp) +
                                  " bands, grey and extra samples, and the last is not marked alpha (ExtraSamples "
                                  "unspecified): it is multi-band data, not " +
                                  (spp == 2 ? "grey and alpha. Pick the band to show (`gdal_translate -b 1 IN OUT.tif`) or "
                                              "mark the second alpha (`gdal_translate -co ALPHA=YES IN OUT.tif`)"
                                            : "RGBA. Pick the bands to show first, e.g. `gdal_translate -b 3 -b 2 -b 1 -co "
                                              "PHOTOMETRIC=RGB IN OUT.tif`"));
        }
    }
    // JPEG-compressed YCbCr: libjpeg hands out RGB, with the orientation left to the caller
    // (OpenImageIO reads it through libtiff's RGBA interface, which flips it part of the way).
    if (photo == PHOTOMETRIC_YCBCR && compression == COMPRESSION_JPEG && spp == 3 && bps == 8 && planar == PLANARCONFIG_CONTIG &&
        TIFFSetField(tif, TIFFTAG_JPEGCOLORMODE, JPEGCOLORMODE_RGB))
        photo = PHOTOMETRIC_RGB;
    // Packed grey of 1, 2 or 4 bits in strips (Pillow writes 1-bit TIFFs with no BitsPerSample,
    // which OpenImageIO reads as 8 bits): expanded to 8.
    unsigned bits = 0;
    if ((bps == 1 || bps == 2 || bps == 4) && spp == 1 && fmt == SAMPLEFORMAT_UINT && !TIFFIsTiled(tif) &&
        (photo == PHOTOMETRIC_MINISBLACK || photo == PHOTOMETRIC_MINISWHITE)) {
        bits = bps;
        bps = 8;
    }
    SourceInfo info;
    info.description = path + " (TIFF)";
    info.width = w;
    info.height = h;
    info.channels = spp;
    const bool layout_ok = planar == PLANARCONFIG_CONTIG && spp >= 1 && spp <= 4 &&
                           (photo == PHOTOMETRIC_MINISBLACK || photo == PHOTOMETRIC_RGB || (bits && photo == PHOTOMETRIC_MINISWHITE)) &&
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
    if (info.has_alpha && TIFFGetField(tif, TIFFTAG_EXTRASAMPLES, &extra_count, &extra) && extra_count >= 1 && extra) {
        associated = extra[extra_count - 1] == EXTRASAMPLE_ASSOCALPHA;
    }
    if (associated) info.description = path + " (TIFF, associated alpha made straight)";
    std::uint16_t orientation = ORIENTATION_TOPLEFT;
    if (TIFFGetField(tif, TIFFTAG_ORIENTATION, &orientation) && orientation >= 1 && orientation <= 8)
        info.orientation = orientation;
    info.colour_space = (info.sample_type == SampleType::u8 || info.sample_type == SampleType::u16) ? ColourSpace::srgb
                                                                                                     : ColourSpace::linear;
    return std::unique_ptr<ImageSource>(new TiffSource(tif, std::move(info), associated, bits, photo == PHOTOMETRIC_MINISWHITE));
}

}  // namespace tessera::storage
