// The OpenImageIO plugin (libtessera_oiio.so): image files in and out through OpenImageIO.
// Loaded on demand by oiio_plugin.cpp; see sources_internal.hpp for why it is a separate module.
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <webp/decode.h>

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <mutex>
#include <filesystem>
#include <fstream>
#include <iterator>

#include "oiio_plugin_abi.hpp"
#include "straight_alpha.hpp"

namespace tessera::storage {
namespace {

class OiioSource final : public ImageSource {
public:
    // type: the samples as read from the file; signed integers are widened to the f32 of info,
    // doubles narrowed to it. band_rows: rows read at once and kept (0: read as asked).
    OiioSource(std::unique_ptr<OIIO::ImageInput> in, SourceInfo info, OIIO::TypeDesc type, bool associated,
               std::uint32_t band_rows)
        : in_(std::move(in)), info_(std::move(info)), type_(type), associated_(associated), band_rows_(band_rows) {}
    ~OiioSource() override { in_->close(); }
    const SourceInfo& info() const override { return info_; }

    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const ParallelFor&) override {
        const std::size_t samples = std::size_t(info_.width) * count * info_.channels;
        Status st;
        if (type_ == OIIO::TypeDesc::DOUBLE) {
            // Read as the file's own doubles and narrowed here: OpenImageIO 2.4 converting a TIFF's
            // doubles to float while reading part of a strip returns zeros, with no error.
            wide_.resize(samples * sizeof(double));
            st = read_file_rows(y0, count, wide_.data());
            for (std::size_t i = 0; st && i < samples; ++i) {
                double v;
                std::memcpy(&v, wide_.data() + i * sizeof v, sizeof v);
                const float f = float(v);
                std::memcpy(dst + i * sizeof f, &f, sizeof f);
            }
        } else {
            st = read_file_rows(y0, count, dst);
        }
        if (st && type_ == OIIO::TypeDesc::INT16) widen<std::int16_t>(dst, samples);
        if (st && type_ == OIIO::TypeDesc::INT8) widen<std::int8_t>(dst, samples);
        if (st && associated_) build::make_alpha_straight(dst, std::size_t(info_.width) * count, info_);
        return st;
    }

private:
    // Signed integer samples (heights, say) as the floats of the same values, in place: the file's
    // samples fill the front of dst, and each float lands at or after the sample it comes from.
    template <class Signed>
    static void widen(std::uint8_t* dst, std::size_t samples) {
        for (std::size_t i = samples; i-- > 0;) {
            Signed v;
            std::memcpy(&v, dst + i * sizeof(Signed), sizeof v);
            const float f = float(v);
            std::memcpy(dst + i * sizeof(float), &f, sizeof f);
        }
    }

    // The file's own samples (alpha as the file holds it), packed in type_.
    Status read_file_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst) {
        const OIIO::ImageSpec& s = in_->spec();
        const std::size_t row = std::size_t(info_.width) * info_.channels * type_.size();
        if (band_rows_ == 0) {
            if (!in_->read_scanlines(0, 0, s.y + int(y0), s.y + int(y0 + count), 0, 0, int(info_.channels), type_, dst) ||
                in_->has_error())
                return failure();
            return {};
        }
        // Read whole bands (of tiles, or of strips that cannot be read in part) and copy the
        // wanted rows out of them.
        const std::uint32_t th = band_rows_;
        for (std::uint32_t y = y0; y < y0 + count;) {
            const std::uint32_t band = y / th;
            if (band != band_index_ || band_.empty()) {
                const std::uint32_t b0 = band * th, b1 = std::min(info_.height, b0 + th);
                band_.resize(row * (b1 - b0));
                const bool read =
                    s.tile_width > 0
                        ? in_->read_tiles(0, 0, s.x, s.x + int(info_.width), s.y + int(b0), s.y + int(b1), s.z, s.z + 1, 0,
                                          int(info_.channels), type_, band_.data())
                        : in_->read_scanlines(0, 0, s.y + int(b0), s.y + int(b1), 0, 0, int(info_.channels), type_,
                                              band_.data());
                if (!read || in_->has_error()) return failure();
                band_index_ = band;
            }
            const std::uint32_t in_band_end = std::min(y0 + count, (band + 1) * th);
            std::memcpy(dst + std::size_t(y - y0) * row, band_.data() + std::size_t(y - band * th) * row, row * (in_band_end - y));
            y = in_band_end;
        }
        return {};
    }

    // OIIO reports some damage (a truncated TIFF strip, corrupt JPEG data) only as a pending error
    // message while the read itself "succeeds" with made-up texels, so a pending message fails too.
    Status failure() {
        std::string msg = in_->geterror();
        if (msg.empty()) msg = "read failed";
        std::replace(msg.begin(), msg.end(), '\n', ' ');
        return make_error(Errc::corrupt, info_.description + ": " + msg);
    }
    std::unique_ptr<OIIO::ImageInput> in_;
    SourceInfo info_;
    OIIO::TypeDesc type_;
    bool associated_;  // the file's alpha is associated: made straight as read
    std::uint32_t band_rows_;
    std::vector<std::uint8_t> wide_;  // doubles as read, before they are narrowed
    std::vector<std::uint8_t> band_;
    std::uint32_t band_index_ = 0;
};

// WebP with alpha, decoded by libwebp itself: OpenImageIO's reader multiplies colour by alpha
// whatever it is asked (so a transparent texel's colour would be lost), while the file's alpha is
// straight. A WebP is at most 16383 texels a side, so it is decoded whole, on the first read (a
// mosaic opens every image to learn its size long before it reads any).
class WebpSource final : public ImageSource {
public:
    WebpSource(std::string path, SourceInfo info) : path_(std::move(path)), info_(std::move(info)) {}
    const SourceInfo& info() const override { return info_; }
    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const ParallelFor&) override {
        const std::size_t row = std::size_t(info_.width) * 4;
        if (rgba_.empty()) {
            std::ifstream f(path_, std::ios::binary);
            const std::vector<std::uint8_t> file((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
            if (f.bad() || file.empty()) return make_error(Errc::io_error, info_.description + ": cannot read it");
            rgba_.resize(row * info_.height);
            if (!WebPDecodeRGBAInto(file.data(), file.size(), rgba_.data(), rgba_.size(), int(row)))
                return make_error(Errc::corrupt, info_.description + ": libwebp cannot decode it");
        }
        std::memcpy(dst, rgba_.data() + y0 * row, count * row);
        if (y0 + count >= info_.height) std::vector<std::uint8_t>().swap(rgba_);  // strips come once each, in order
        return {};
    }

private:
    std::string path_;
    SourceInfo info_;
    std::vector<std::uint8_t> rgba_;
};

// The Orientation (EXIF tag 0x0112) of a WebP's EXIF chunk, 1 where there is none: OpenImageIO
// 2.4's WebP reader does not report it, and a phone's photo would be built on its side.
int webp_exif_orientation(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    char riff[12];
    if (!f.read(riff, 12) || std::memcmp(riff, "RIFF", 4) != 0 || std::memcmp(riff + 8, "WEBP", 4) != 0) return 1;
    for (int chunks = 0; chunks < 64; ++chunks) {  // VP8X, ICCP, ANIM, image, ... EXIF: a handful
        unsigned char head[8];
        if (!f.read(reinterpret_cast<char*>(head), 8)) return 1;
        const std::uint32_t size = head[4] | head[5] << 8 | head[6] << 16 | std::uint32_t(head[7]) << 24;
        if (std::memcmp(head, "EXIF", 4) != 0) {
            f.seekg(std::streamoff(size + (size & 1)), std::ios::cur);
            continue;
        }
        if (size < 8 || size > (1u << 20)) return 1;
        std::vector<unsigned char> exif(size);
        if (!f.read(reinterpret_cast<char*>(exif.data()), std::streamsize(size))) return 1;
        std::size_t base = 0;  // some writers keep JPEG's "Exif\0\0" before the TIFF header
        if (size >= 14 && std::memcmp(exif.data(), "Exif\0\0", 6) == 0) base = 6;
        const bool le = exif[base] == 'I' && exif[base + 1] == 'I';
        if (!le && !(exif[base] == 'M' && exif[base + 1] == 'M')) return 1;
        auto u16 = [&](std::size_t at) -> std::uint32_t {
            return at + 2 > exif.size() ? 0 : le ? exif[at] | exif[at + 1] << 8 : exif[at] << 8 | exif[at + 1];
        };
        auto u32 = [&](std::size_t at) -> std::uint32_t { return le ? u16(at) | u16(at + 2) << 16 : u16(at) << 16 | u16(at + 2); };
        const std::size_t ifd = base + u32(base + 4);
        const std::uint32_t entries = u16(ifd);
        for (std::uint32_t e = 0; e < entries && ifd + 2 + 12 * (e + 1) <= exif.size(); ++e) {
            const std::size_t at = ifd + 2 + 12 * e;
            if (u16(at) == 0x0112 && u16(at + 2) == 3) {  // SHORT
                const std::uint32_t v = u16(at + 8);
                return v >= 1 && v <= 8 ? int(v) : 1;
            }
        }
        return 1;
    }
    return 1;
}

// A still WebP with alpha whose size libwebp agrees on, else null (OpenImageIO reads it: an
// animation's first frame, premultiplied).
std::unique_ptr<ImageSource> open_webp_with_alpha(const std::string& path, const SourceInfo& info) {
    std::ifstream f(path, std::ios::binary);
    std::vector<std::uint8_t> head(64 * 1024);
    f.read(reinterpret_cast<char*>(head.data()), std::streamsize(head.size()));
    head.resize(std::size_t(f.gcount()));
    WebPBitstreamFeatures features;
    if (WebPGetFeatures(head.data(), head.size(), &features) != VP8_STATUS_OK || features.has_animation ||
        std::uint32_t(features.width) != info.width || std::uint32_t(features.height) != info.height)
        return nullptr;
    return std::make_unique<WebpSource>(path, info);
}

// Writes to the temporary file's descriptor, remembering the first failure (a full disk) for the
// caller to report after close(), and telling the format writer every write succeeded: libjpeg's
// error handler, for one, ends the process on a failed write, and the PNG writer ignores it.
class FdOutput final : public OIIO::Filesystem::IOProxy {
public:
    FdOutput(int fd, const std::string& path) : IOProxy(path, Write), fd_(fd) {}
    const char* proxytype() const override { return "tessera-fd"; }
    size_t write(const void* buf, size_t size) override {
        pwrite(buf, size, m_pos);
        m_pos += int64_t(size);
        return size;
    }
    size_t pwrite(const void* buf, size_t size, int64_t offset) override {
        std::lock_guard lock(mu_);
        end_ = std::max(end_, offset + int64_t(size));
        const auto* p = static_cast<const std::uint8_t*>(buf);
        for (size_t done = 0; done < size && errno_ == 0;) {
            const ssize_t n = ::pwrite(fd_, p + done, size - done, off_t(offset + int64_t(done)));
            if (n < 0 && errno == EINTR) continue;
            if (n <= 0) errno_ = n < 0 ? errno : EIO;
            else done += size_t(n);
        }
        return size;
    }
    size_t read(void* buf, size_t size) override {
        const size_t n = pread(buf, size, m_pos);
        m_pos += int64_t(n);
        return n;
    }
    size_t pread(void* buf, size_t size, int64_t offset) override {
        const ssize_t n = ::pread(fd_, buf, size, off_t(offset));
        return n < 0 ? 0 : size_t(n);
    }
    size_t size() const override { return size_t(end_); }
    // 0, or the errno of the first write that failed.
    int failed() const {
        std::lock_guard lock(mu_);
        return errno_;
    }

private:
    int fd_;
    mutable std::mutex mu_;
    int64_t end_ = 0;
    int errno_ = 0;
};

std::string oiio_error(std::string msg) {
    if (msg.empty()) msg = OIIO::geterror();
    std::replace(msg.begin(), msg.end(), '\n', ' ');
    return msg;
}

Result<std::unique_ptr<ImageSource>> open_file(const std::string& path) {
    // Keep straight alpha straight (OpenImageIO would associate it on read); files whose alpha is
    // associated (OpenEXR, TIFF ExtraSamples = 1) still come associated and are made straight.
    OIIO::ImageSpec config;
    config.attribute("oiio:UnassociatedAlpha", 1);
    auto in = OIIO::ImageInput::open(path, &config);
    if (!in) return make_error(Errc::unsupported, "cannot read '" + path + "' as an image: " + oiio_error({}));
    const OIIO::ImageSpec& s = in->spec();
    SourceInfo info;
    info.description = path + " (" + in->format_name() + ")";
    if (s.width <= 0 || s.height <= 0) return make_error(Errc::invalid_argument, info.description + " has zero size");
    if (s.depth > 1) return make_error(Errc::unsupported, info.description + " is a volume image");
    if (s.deep) return make_error(Errc::unsupported, info.description + " is a deep image");
    if (s.nchannels < 1 || s.nchannels > 4)
        return make_error(Errc::unsupported, info.description + " has " + std::to_string(s.nchannels) + " channels (1 to 4 supported)");
    info.width = static_cast<std::uint32_t>(s.width);
    info.height = static_cast<std::uint32_t>(s.height);
    info.channels = static_cast<std::uint32_t>(s.nchannels);
    OIIO::TypeDesc type;
    switch (s.format.basetype) {
        case OIIO::TypeDesc::UINT8: info.sample_type = SampleType::u8; type = OIIO::TypeDesc::UINT8; break;
        case OIIO::TypeDesc::UINT16: info.sample_type = SampleType::u16; type = OIIO::TypeDesc::UINT16; break;
        case OIIO::TypeDesc::HALF: info.sample_type = SampleType::f16; type = OIIO::TypeDesc::HALF; break;
        // Signed samples (a DEM's heights) keep their values, as floats: a conversion to unsigned
        // would drop the negatives and scale the rest.
        case OIIO::TypeDesc::INT8: info.sample_type = SampleType::f32; type = OIIO::TypeDesc::INT8; break;
        case OIIO::TypeDesc::INT16: info.sample_type = SampleType::f32; type = OIIO::TypeDesc::INT16; break;
        case OIIO::TypeDesc::FLOAT: info.sample_type = SampleType::f32; type = OIIO::TypeDesc::FLOAT; break;
        case OIIO::TypeDesc::DOUBLE: info.sample_type = SampleType::f32; type = OIIO::TypeDesc::DOUBLE; break;
        default:  // 32- and 64-bit integers: as floats they would lose their low bits or be rescaled
            return make_error(Errc::unsupported, info.description + " has " + std::string(s.format.c_str()) +
                                                     " samples; 8- and 16-bit integers, half and float are supported "
                                                     "(convert it first, e.g. gdal_translate -ot Float32)");
    }
    // A reader may name an alpha channel it does not index (OpenImageIO's GIF reader: alpha_channel
    // = nchannels): the last channel called A is alpha too.
    const bool alpha_named = s.channelnames.size() == std::size_t(s.nchannels) &&
                             (s.channelnames.back() == "A" || s.channelnames.back() == "Alpha");
    const bool alpha_index_valid = s.alpha_channel >= 0 && s.alpha_channel < s.nchannels;
    info.has_alpha = (info.channels == 2 || info.channels == 4) &&
                     (s.alpha_channel == s.nchannels - 1 || !alpha_index_valid || alpha_named);
    // Associated only when OpenImageIO knows the channel as alpha and did not keep it straight.
    // BMP's alpha is straight and its reader returns it as stored, without saying so.
    if ((type == OIIO::TypeDesc::INT8 || type == OIIO::TypeDesc::INT16) && info.has_alpha)
        return make_error(Errc::unsupported, info.description + " has signed samples with an alpha channel "
                                                                "(alpha is 0 to the type's maximum; convert it to unsigned or float first)");
    info.orientation = static_cast<std::uint32_t>(std::clamp(s.get_int_attribute("Orientation", 1), 1, 8));
    const std::string format = in->format_name();
    if (format == "webp" && info.orientation == 1) info.orientation = static_cast<std::uint32_t>(webp_exif_orientation(path));
    // CIELab (and ICC or ITU Lab) TIFFs come as their L, a and b numbers: stored as RGB they would
    // be the wrong colours, so they are refused by name.
    if (const int photometric = s.get_int_attribute("tiff:PhotometricInterpretation", -1);
        format == "tiff" && (photometric == 8 || photometric == 9 || photometric == 10))
        return make_error(Errc::unsupported, info.description + " holds CIELab colour (L*a*b*), which is not converted; convert it "
                                                                "to sRGB first (e.g. vips colourspace IN OUT srgb)");
    // Two kinds of compressed TIFF strips are read a whole strip at a time, within a bound on the
    // memory one strip takes: read a few rows at a time, strips that hold one plane each
    // (PlanarConfiguration 2) fail (libtiff: "does not support random access"), and OpenImageIO
    // 2.4 returns zeros for the doubles of a strip read in part, with no error.
    std::uint32_t band_rows = 0;
    if (format == "tiff" && s.tile_width > 0 && type == OIIO::TypeDesc::DOUBLE)
        return make_error(Errc::unsupported, info.description + " stores doubles in tiles, which OpenImageIO 2.4 reads as zeros; "
                                                                "convert it to float first (e.g. vips cast IN OUT.tif float)");
    if (s.tile_width > 0) {
        band_rows = static_cast<std::uint32_t>(s.tile_height);
    } else if (format == "tiff" && s.get_int_attribute("tiff:Compression", 1) != 1) {
        const bool planes = s.get_int_attribute("tiff:PlanarConfiguration", 1) == 2;
        const auto rows = static_cast<std::uint32_t>(std::clamp(s.get_int_attribute("tiff:RowsPerStrip", 1), 1, s.height));
        const std::uint64_t strip_bytes = std::uint64_t(info.width) * info.channels * type.size() * rows;
        constexpr std::uint64_t kMaxStripBytes = std::uint64_t(1) << 30;
        if (strip_bytes > kMaxStripBytes && (planes || type == OIIO::TypeDesc::DOUBLE))
            return make_error(Errc::unsupported,
                              info.description + (planes ? " stores its channels as separate planes in" : " stores doubles in") + " compressed strips of " +
                                  std::to_string(rows) + " rows (" + std::to_string(strip_bytes >> 20) +
                                  " MiB each, over the 1024 MiB read at once); rewrite it in smaller strips or tiles "
                                  "first (e.g. tiffcp -p contig -r 64 IN OUT)");
        // Other compressed strips read in part fine: they stream a few rows at a time, so that a
        // file of one huge strip is not held whole.
        if ((planes || type == OIIO::TypeDesc::DOUBLE) && rows > 1) band_rows = rows;
    }
    if (format == "webp" && info.has_alpha && info.channels == 4 && type == OIIO::TypeDesc::UINT8) {
        info.colour_space = ColourSpace::srgb;
        if (auto webp = open_webp_with_alpha(path, info)) return webp;
    }
    const bool associated = info.has_alpha && s.alpha_channel == s.nchannels - 1 &&
                            s.get_int_attribute("oiio:UnassociatedAlpha", 0) == 0 && format != "bmp";
    if (associated) info.description.insert(info.description.size() - 1, ", associated alpha made straight");
    const std::string cs = s.get_string_attribute("oiio:ColorSpace");
    if (cs == "sRGB" || cs == "srgb" || cs == "srgb_rec709_scene") info.colour_space = ColourSpace::srgb;
    else if (cs == "Linear" || cs == "linear" || cs == "lin_srgb" || cs == "scene_linear") info.colour_space = ColourSpace::linear;
    else
        info.colour_space = (info.sample_type == SampleType::u8 || info.sample_type == SampleType::u16) ? ColourSpace::srgb
                                                                                                         : ColourSpace::linear;
    return std::unique_ptr<ImageSource>(new OiioSource(std::move(in), std::move(info), type, associated, band_rows));
}

}  // namespace
}  // namespace tessera::storage

using namespace tessera;
using namespace tessera::storage;

extern "C" __attribute__((visibility("default"))) ImageSource* tessera_oiio_open(const char* path, int* code, std::string* error) {
    auto r = open_file(path);
    if (!r) {
        *code = static_cast<int>(r.error().code);
        *error = r.error().message;
        return nullptr;
    }
    return r.value().release();
}

extern "C" __attribute__((visibility("default"))) bool tessera_oiio_write(const ImageWriteRequest* req, std::string* error) {
    const SourceInfo& si = req->source->info();
    namespace fs = std::filesystem;
    const std::string& path = *req->path;
    std::unique_ptr<FdOutput> proxy;  // outlives `out`, which refers to it
    auto out = OIIO::ImageOutput::create(path);
    if (!out) {
        *error = "cannot write '" + path + "': " + oiio_error({});
        return false;
    }
    static const OIIO::TypeDesc types[] = {OIIO::TypeDesc::UINT8, OIIO::TypeDesc::UINT16, OIIO::TypeDesc::HALF, OIIO::TypeDesc::FLOAT};
    const OIIO::TypeDesc type = types[static_cast<int>(si.sample_type)];
    OIIO::ImageSpec spec(int(si.width), int(si.height), int(si.channels), type);
    if (si.has_alpha) {
        spec.alpha_channel = int(si.channels) - 1;
        spec.attribute("oiio:UnassociatedAlpha", 1);  // sources are straight; PNG and TIFF keep it so
    }
    spec.attribute("oiio:ColorSpace", si.colour_space == ColourSpace::srgb ? "sRGB" : "Linear");
    spec.attribute("compression", "none");
    // Through the proxy where the writer takes one: by name, several writers drop write errors (a
    // PNG, WebP, BMP or Targa cut short, exit 0) or end the process (libjpeg). The rest write the
    // temporary file by name (the same file: opening it truncates it) and report their own
    // errors; TIFF must, as OpenImageIO 2.4's TIFF writer through a proxy writes a broken file.
    const std::string format = out->format_name();
    if (format != "tiff" && out->supports("ioproxy")) {
        proxy = std::make_unique<FdOutput>(req->temp_fd, *req->temp_path);
        if (!out->set_ioproxy(proxy.get())) proxy.reset();
    }
    if (!out->open(*req->temp_path, spec)) {
        *error = "cannot write '" + path + "': " + oiio_error(out->geterror());
        return false;
    }
    // A format of integers only (PNG, JPEG ...) would clamp float samples (heights, radiance) to
    // 0..1 without a word: refused, naming the formats that keep them.
    const bool float_source = si.sample_type == SampleType::f16 || si.sample_type == SampleType::f32;
    if (float_source && !out->spec().format.is_floating_point()) {
        out->close();
        *error = "cannot write '" + path + "': " + format + " holds no floating-point samples, and the source's are " +
                 (si.sample_type == SampleType::f16 ? "half" : "float") + " (write .tif or .exr, which keep them)";
        return false;
    }
    const std::size_t row = std::size_t(si.width) * si.channels * sample_bytes(si.sample_type);
    const std::uint32_t strip = 256;
    std::vector<std::uint8_t> buf(row * strip);
    for (std::uint32_t y = 0; y < si.height; y += strip) {
        const std::uint32_t n = std::min(strip, si.height - y);
        if (Status st = req->source->read_rows(y, n, buf.data(), *req->parallel); !st) {
            out->close();
            *error = st.error().message;
            return false;
        }
        if (!out->write_scanlines(int(y), int(y + n), 0, type, buf.data())) {
            *error = "cannot write '" + path + "': " + oiio_error(out->geterror());
            out->close();
            return false;
        }
        if (req->progress) req->progress(req->progress_ctx, y + n);
    }
    if (!out->close()) {
        *error = "cannot write '" + path + "': " + oiio_error(out->geterror());
        return false;
    }
    if (proxy && proxy->failed() != 0) {
        *error = "cannot write '" + path + "': " + std::strerror(proxy->failed());
        return false;
    }
    return true;
}
