#include "tessera/storage/png_encode.hpp"

#include <zlib.h>

#include <array>
#include <cstring>
#include <string>
#include <string_view>

namespace tessera::storage {

namespace {

constexpr std::array<std::uint8_t, 8> kSignature = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};

void put_u32(std::vector<std::uint8_t>& out, std::uint32_t v) {
    out.push_back(static_cast<std::uint8_t>(v >> 24));
    out.push_back(static_cast<std::uint8_t>(v >> 16));
    out.push_back(static_cast<std::uint8_t>(v >> 8));
    out.push_back(static_cast<std::uint8_t>(v));
}

// length, type, data, CRC-32 of type + data.
void put_chunk(std::vector<std::uint8_t>& out, std::string_view type, std::span<const std::uint8_t> data) {
    put_u32(out, static_cast<std::uint32_t>(data.size()));
    const std::size_t type_at = out.size();
    out.insert(out.end(), type.begin(), type.end());
    out.insert(out.end(), data.begin(), data.end());
    uLong crc = crc32(0L, Z_NULL, 0);
    // zlib takes uInt lengths; chunks here are far below 4 GiB (a tile is at most 4096^2 x 8 bytes).
    crc = crc32(crc, out.data() + type_at, static_cast<uInt>(out.size() - type_at));
    put_u32(out, static_cast<std::uint32_t>(crc));
}

}  // namespace

Result<std::vector<std::uint8_t>> encode_png(const PngImage& image) {
    std::size_t sample = 0;
    switch (image.sample_type) {
        case SampleType::u8: sample = 1; break;
        case SampleType::u16: sample = 2; break;
        case SampleType::f16:
        case SampleType::f32:
            return make_error(Errc::unsupported, "PNG has no floating-point samples: this store holds " +
                                                     std::string(to_string(image.sample_type)) +
                                                     " data; fetch the stored payload instead");
    }
    if (image.channels < 1 || image.channels > 4)
        return make_error(Errc::invalid_argument, "PNG needs 1 to 4 channels, the image has " + std::to_string(image.channels));
    const std::uint32_t w = image.width, h = image.height;
    const std::size_t pixel = image.channels * sample;  // bytes per pixel
    const std::size_t row = std::size_t(w) * pixel;
    // PNG sizes are 31-bit; zlib takes a uLong of input, and one IDAT chunk holds under 4 GiB.
    if (w == 0 || h == 0 || w > 0x7fffffffu || h > 0x7fffffffu || double(row + 1) * h > double(0xffffffffu) / 2)
        return make_error(Errc::invalid_argument, "PNG encode: image size " + std::to_string(w) + "x" + std::to_string(h) + " out of range");
    if (image.texels.size() != row * h)
        return make_error(Errc::invalid_argument, "PNG encode: expected " + std::to_string(row * h) +
                                                      " bytes of texels, got " + std::to_string(image.texels.size()));

    // Filtered scanlines: one filter-type byte (1 = Sub) per row, then the row with each byte
    // minus the byte one pixel to its left. 16-bit samples are written big-endian first.
    std::vector<std::uint8_t> raw(std::size_t(h) * (row + 1));
    std::vector<std::uint8_t> be(sample == 2 ? row : 0);
    for (std::uint32_t y = 0; y < h; ++y) {
        const std::uint8_t* src = image.texels.data() + std::size_t(y) * row;
        if (sample == 2) {
            for (std::size_t i = 0; i < row; i += 2) {
                be[i] = src[i + 1];
                be[i + 1] = src[i];
            }
            src = be.data();
        }
        std::uint8_t* dst = raw.data() + std::size_t(y) * (row + 1);
        dst[0] = 1;
        std::memcpy(dst + 1, src, pixel);
        for (std::size_t i = pixel; i < row; ++i) dst[1 + i] = static_cast<std::uint8_t>(src[i] - src[i - pixel]);
    }

    uLongf zlen = compressBound(static_cast<uLong>(raw.size()));
    std::vector<std::uint8_t> z(zlen);
    const int zr = compress2(z.data(), &zlen, raw.data(), static_cast<uLong>(raw.size()), Z_BEST_SPEED);
    if (zr != Z_OK) return make_error(Errc::resource_exhausted, "PNG encode: zlib compress2 failed (" + std::to_string(zr) + ")");
    z.resize(zlen);

    static constexpr std::uint8_t kColourType[5] = {0, 0, 4, 2, 6};  // by channel count
    std::vector<std::uint8_t> out;
    out.reserve(kSignature.size() + 25 + 13 + 16 + z.size() + 12);
    for (std::uint8_t b : kSignature) out.push_back(b);  // (insert() trips a GCC 12 false -Wstringop-overflow)

    std::vector<std::uint8_t> ihdr;
    put_u32(ihdr, w);
    put_u32(ihdr, h);
    ihdr.push_back(static_cast<std::uint8_t>(sample * 8));  // bit depth
    ihdr.push_back(kColourType[image.channels]);
    ihdr.push_back(0);  // compression: deflate
    ihdr.push_back(0);  // filter method 0 (adaptive, five types)
    ihdr.push_back(0);  // no interlace
    put_chunk(out, "IHDR", ihdr);

    if (image.colour_space == ColourSpace::srgb) {
        const std::uint8_t intent = 0;  // perceptual
        put_chunk(out, "sRGB", std::span(&intent, 1));
    } else {
        std::vector<std::uint8_t> gama;
        put_u32(gama, 100000);  // gamma 1.0: the samples are linear
        put_chunk(out, "gAMA", gama);
    }
    put_chunk(out, "IDAT", z);
    put_chunk(out, "IEND", {});
    return out;
}

Result<std::vector<std::uint8_t>> encode_tile_png(const StoreInfo& info, std::span<const std::uint8_t> texels) {
    const std::uint32_t side = info.tile_size();
    return encode_png(PngImage{side, side, info.channels, info.sample_type, info.colour_space, texels});
}

}  // namespace tessera::storage
