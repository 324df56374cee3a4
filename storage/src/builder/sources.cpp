// open_image_source(): the procedural demo terrain, TIFF files through libtiff, other image files
// through the OpenImageIO plugin.
#include <algorithm>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <iterator>
#include <utility>

#include "procedural_layers.hpp"
#include "procedural_terrain.hpp"
#include "sources_internal.hpp"
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

Result<std::unique_ptr<ImageSource>> open_procedural(const std::string& spec) {
    // procedural:terrain:SIZE, and the terrain's layers procedural:terrain-height:SIZE and
    // procedural:terrain-normal:SIZE
    enum class Kind { colour, height, normal };
    static constexpr std::pair<const char*, Kind> kKinds[] = {
        {"procedural:terrain:", Kind::colour},
        {"procedural:terrain-height:", Kind::height},
        {"procedural:terrain-normal:", Kind::normal},
    };
    const auto* kind = std::find_if(std::begin(kKinds), std::end(kKinds), [&](const auto& k) { return spec.rfind(k.first, 0) == 0; });
    if (kind == std::end(kKinds))
        return make_error(Errc::invalid_argument, "unknown procedural source '" + spec +
                                                      "' (expected procedural:terrain:SIZE, procedural:terrain-height:SIZE "
                                                      "or procedural:terrain-normal:SIZE)");
    const std::string num = spec.substr(std::strlen(kind->first));
    std::uint64_t size = 0;
    auto [p, ec] = std::from_chars(num.data(), num.data() + num.size(), size);
    if (num.empty() || ec != std::errc() || p != num.data() + num.size())
        return make_error(Errc::invalid_argument, "procedural size '" + num + "' is not a number");
    if (size < 1 || size > kMaxProceduralSize)
        return make_error(Errc::invalid_argument,
                          "procedural size must be 1 to " + std::to_string(kMaxProceduralSize) + ", got " + num);
    const auto side = static_cast<std::uint32_t>(size);
    switch (kind->second) {
        case Kind::height: return build::make_terrain_height_source(side);
        case Kind::normal: return build::make_terrain_normal_source(side);
        case Kind::colour: break;
    }
    return std::unique_ptr<ImageSource>(new ProceduralSource(side));
}

}  // namespace

Status check_output_is_not_input(const std::string& input, const std::string& output) {
    std::error_code ec;
    if (std::filesystem::equivalent(input, output, ec))
        return make_error(Errc::invalid_argument, "output '" + output + "' is the input '" + input + "'; choose another output path");
    return {};
}

Result<std::unique_ptr<ImageSource>> open_image_source(const std::string& spec) {
    if (spec.rfind("procedural:", 0) == 0) return open_procedural(spec);
    if (spec.empty()) return make_error(Errc::invalid_argument, "no input given");
    std::error_code ec;
    if (!std::filesystem::exists(spec, ec)) return make_error(Errc::not_found, "input '" + spec + "' does not exist");
    if (std::filesystem::is_directory(spec, ec)) return make_error(Errc::invalid_argument, "input '" + spec + "' is a directory");
    // A FIFO would block the reader until some writer came; a device or socket never ends.
    if (!std::filesystem::is_regular_file(spec, ec))
        return make_error(Errc::invalid_argument, "input '" + spec + "' is not a regular file (a FIFO, socket or device)");
    if (looks_like_tiff(spec)) {
        auto tiff = open_tiff_source(spec);
        if (!tiff.ok() && tiff.error().code != Errc::unsupported) return tiff;
        if (tiff.ok()) return make_upright_source(std::move(tiff).value());
    }
    if (looks_like_binary_pnm(spec)) {
        auto pnm = open_pnm_source(spec);
        if (!pnm.ok()) return pnm;
        return std::move(pnm).value();
    }
    auto source = open_oiio_source(spec);
    if (!source.ok()) return source;
    return make_upright_source(std::move(source).value());
}

}  // namespace tessera::storage
