// Image sources: files through OpenImageIO (scanline or tiled, read in strips) and the procedural
// demo terrain.
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <charconv>
#include <cstring>
#include <filesystem>

#include "procedural_terrain.hpp"
#include "tessera/storage/image_source.hpp"

namespace tessera::storage {
namespace {

class ProceduralSource final : public ImageSource {
public:
    explicit ProceduralSource(std::uint32_t size) : terrain_(size) {
        info_.width = info_.height = size;
        info_.channels = 3;
        info_.sample_type = SampleType::u8;
        info_.colour_space = ColourSpace::srgb;
        info_.description = "procedural terrain " + std::to_string(size) + "x" + std::to_string(size);
    }
    const SourceInfo& info() const override { return info_; }
    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const ParallelFor& parallel) override {
        const std::size_t row = std::size_t(info_.width) * 3;
        parallel(count, [&](std::size_t b, std::size_t e) {
            for (std::size_t i = b; i < e; ++i) terrain_.render_row(y0 + i, dst + i * row);
        });
        return {};
    }

private:
    SourceInfo info_;
    build::ProceduralTerrain terrain_;
};

class OiioSource final : public ImageSource {
public:
    OiioSource(std::unique_ptr<OIIO::ImageInput> in, SourceInfo info, OIIO::TypeDesc type)
        : in_(std::move(in)), info_(std::move(info)), type_(type) {}
    ~OiioSource() override { in_->close(); }
    const SourceInfo& info() const override { return info_; }

    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const ParallelFor&) override {
        const OIIO::ImageSpec& s = in_->spec();
        const std::size_t row = std::size_t(info_.width) * info_.channels * sample_bytes(info_.sample_type);
        if (s.tile_width == 0) {
            if (!in_->read_scanlines(0, 0, s.y + int(y0), s.y + int(y0 + count), 0, 0, int(info_.channels), type_, dst))
                return failure();
            return {};
        }
        // Tiled file: read whole bands of tiles and copy the wanted rows out of them.
        const std::uint32_t th = static_cast<std::uint32_t>(s.tile_height);
        for (std::uint32_t y = y0; y < y0 + count;) {
            const std::uint32_t band = y / th;
            if (band != band_index_ || band_.empty()) {
                const std::uint32_t b0 = band * th, b1 = std::min(info_.height, b0 + th);
                band_.resize(row * (b1 - b0));
                if (!in_->read_tiles(0, 0, s.x, s.x + int(info_.width), s.y + int(b0), s.y + int(b1), s.z, s.z + 1, 0,
                                     int(info_.channels), type_, band_.data()))
                    return failure();
                band_index_ = band;
            }
            const std::uint32_t in_band_end = std::min(y0 + count, (band + 1) * th);
            std::memcpy(dst + std::size_t(y - y0) * row, band_.data() + std::size_t(y - band * th) * row, row * (in_band_end - y));
            y = in_band_end;
        }
        return {};
    }

private:
    Status failure() {
        std::string msg = in_->geterror();
        if (msg.empty()) msg = "read failed";
        std::replace(msg.begin(), msg.end(), '\n', ' ');
        return make_error(Errc::corrupt, info_.description + ": " + msg);
    }
    std::unique_ptr<OIIO::ImageInput> in_;
    SourceInfo info_;
    OIIO::TypeDesc type_;
    std::vector<std::uint8_t> band_;
    std::uint32_t band_index_ = 0;
};

Result<std::unique_ptr<ImageSource>> open_procedural(const std::string& spec) {
    // procedural:terrain:SIZE
    const std::string prefix = "procedural:terrain:";
    if (spec.rfind(prefix, 0) != 0)
        return make_error(Errc::invalid_argument, "unknown procedural source '" + spec + "' (expected procedural:terrain:SIZE)");
    const std::string num = spec.substr(prefix.size());
    std::uint64_t size = 0;
    auto [p, ec] = std::from_chars(num.data(), num.data() + num.size(), size);
    if (num.empty() || ec != std::errc() || p != num.data() + num.size())
        return make_error(Errc::invalid_argument, "procedural size '" + num + "' is not a number");
    if (size < 1 || size > kMaxProceduralSize)
        return make_error(Errc::invalid_argument,
                          "procedural size must be 1 to " + std::to_string(kMaxProceduralSize) + ", got " + num);
    return std::unique_ptr<ImageSource>(new ProceduralSource(static_cast<std::uint32_t>(size)));
}

std::string oiio_error(std::string msg) {
    if (msg.empty()) msg = OIIO::geterror();
    std::replace(msg.begin(), msg.end(), '\n', ' ');
    return msg;
}

Result<std::unique_ptr<ImageSource>> open_file(const std::string& path) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) return make_error(Errc::not_found, "input '" + path + "' does not exist");
    if (std::filesystem::is_directory(path, ec)) return make_error(Errc::invalid_argument, "input '" + path + "' is a directory");
    auto in = OIIO::ImageInput::open(path);
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
        case OIIO::TypeDesc::INT8: info.sample_type = SampleType::u8; type = OIIO::TypeDesc::UINT8; break;
        case OIIO::TypeDesc::INT16: info.sample_type = SampleType::u16; type = OIIO::TypeDesc::UINT16; break;
        default: info.sample_type = SampleType::f32; type = OIIO::TypeDesc::FLOAT; break;
    }
    info.has_alpha = (info.channels == 2 || info.channels == 4) && (s.alpha_channel == s.nchannels - 1 || s.alpha_channel < 0);
    if (s.alpha_channel < 0 && info.channels == 2) info.has_alpha = true;  // grey + alpha by convention
    if (s.alpha_channel < 0 && info.channels == 4) info.has_alpha = true;  // RGBA by convention
    const std::string cs = s.get_string_attribute("oiio:ColorSpace");
    if (cs == "sRGB" || cs == "srgb" || cs == "srgb_rec709_scene") info.colour_space = ColourSpace::srgb;
    else if (cs == "Linear" || cs == "linear" || cs == "lin_srgb" || cs == "scene_linear") info.colour_space = ColourSpace::linear;
    else
        info.colour_space = (info.sample_type == SampleType::u8 || info.sample_type == SampleType::u16) ? ColourSpace::srgb
                                                                                                         : ColourSpace::linear;
    return std::unique_ptr<ImageSource>(new OiioSource(std::move(in), std::move(info), type));
}

}  // namespace

Result<std::unique_ptr<ImageSource>> open_image_source(const std::string& spec) {
    if (spec.rfind("procedural:", 0) == 0) return open_procedural(spec);
    if (spec.empty()) return make_error(Errc::invalid_argument, "no input given");
    return open_file(spec);
}

}  // namespace tessera::storage
