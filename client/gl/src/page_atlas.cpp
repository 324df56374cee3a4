#include "page_atlas.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <utility>

namespace tessera::client::gl::detail {

namespace {

std::string gl_renderer_name() {
    const auto* r = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
    return r ? r : "unknown renderer";
}

// The atlas's GL internal format for the configured page format.
GLenum internal_format(const RendererConfig& c) {
    switch (c.page_format) {
        case PageFormat::bc1: return c.srgb ? GL_COMPRESSED_SRGB_S3TC_DXT1_EXT : GL_COMPRESSED_RGB_S3TC_DXT1_EXT;
        case PageFormat::bc4: return GL_COMPRESSED_RED_RGTC1;  // data, not colour: never sRGB
        case PageFormat::bc5: return GL_COMPRESSED_RG_RGTC2;
        case PageFormat::bc7: return c.srgb ? GL_COMPRESSED_SRGB_ALPHA_BPTC_UNORM : GL_COMPRESSED_RGBA_BPTC_UNORM;
        case PageFormat::r16: return GL_R16;  // heights and other data: exact, never sRGB
        case PageFormat::r16f: return GL_R16F;
        case PageFormat::r32f: return GL_R32F;
        default: return c.srgb ? GL_SRGB8_ALPHA8 : GL_RGBA8;
    }
}

// The client-side format and type of an uncompressed page's texels.
std::pair<GLenum, GLenum> upload_format(PageFormat f) {
    switch (f) {
        case PageFormat::r16: return {GL_RED, GL_UNSIGNED_SHORT};
        case PageFormat::r16f: return {GL_RED, GL_HALF_FLOAT};
        case PageFormat::r32f: return {GL_RED, GL_FLOAT};
        default: return {GL_RGBA, GL_UNSIGNED_BYTE};
    }
}

}  // namespace

// RGTC (bc4, bc5) is core since GL 3.0 and BPTC (bc7) since 4.2; S3TC (bc1) is an extension, and
// its sRGB form another.
Status check_page_format_support(const RendererConfig& c) {
    const auto refuse = [&](std::string why) {
        return Status(Error{Errc::unsupported, fmt::format("renderer: page format {}: {}", to_string(c.page_format), why)});
    };
    switch (c.page_format) {
        case PageFormat::rgba8: return {};
        case PageFormat::bc1:
            if (!epoxy_has_gl_extension("GL_EXT_texture_compression_s3tc"))
                return refuse("this GL lacks GL_EXT_texture_compression_s3tc (" + gl_renderer_name() + ")");
            if (c.srgb && !epoxy_has_gl_extension("GL_EXT_texture_sRGB") &&
                !epoxy_has_gl_extension("GL_EXT_texture_compression_s3tc_srgb"))
                return refuse("this GL has no sRGB S3TC format (GL_EXT_texture_sRGB) (" + gl_renderer_name() + ")");
            break;
        case PageFormat::bc4:
        case PageFormat::bc5: break;
        case PageFormat::bc7:
            if (!epoxy_has_gl_extension("GL_ARB_texture_compression_bptc") && epoxy_gl_version() < 42)
                return refuse("this GL has no BPTC formats (GL 4.2 or GL_ARB_texture_compression_bptc) (" + gl_renderer_name() + ")");
            break;
        case PageFormat::r16:
        case PageFormat::r16f:
        case PageFormat::r32f: return {};  // core formats, colour-renderable (the page-mip pass draws into them)
        default: return refuse("the renderer's atlas does not hold it");
    }
    if (c.tile_size % 4 != 0) return refuse(fmt::format("tiles of {} texels are not whole 4x4 blocks", c.tile_size));
    if (c.has_second_level() && c.tile_size % 8 != 0)
        return refuse(fmt::format("the second level of tiles of {} texels is not whole 4x4 blocks (a multiple of 8)", c.tile_size));
    return {};
}

Status PageAtlas::init(const RendererConfig& c, std::uint32_t max_texture) {
    format_ = c.page_format;
    pool_slots_ = c.pool_slots;
    tile_size_ = c.tile_size;
    border_ = c.border;
    const std::uint32_t per_row_max = max_texture / c.tile_size;
    columns_ = std::max<std::uint32_t>(1, static_cast<std::uint32_t>(std::ceil(std::sqrt(double(c.pool_slots)))));
    columns_ = std::min({columns_, std::max<std::uint32_t>(per_row_max, 1), kMaxCells});
    const std::uint32_t rows = (c.pool_slots + columns_ - 1) / columns_;
    if (rows > kMaxCells)
        return Error{Errc::resource_exhausted, fmt::format("renderer: a pool of {} slots needs {} atlas rows of {} cells; the "
                                                           "GPU page-table entry holds at most {} (fewer slots)",
                                                           c.pool_slots, rows, columns_, kMaxCells)};
    width_ = columns_ * c.tile_size;
    height_ = rows * c.tile_size;
    if (per_row_max == 0 || width_ > max_texture || height_ > max_texture)
        return Error{Errc::resource_exhausted,
                     fmt::format("renderer: a pool of {} slots of {}^2 texels needs a {}x{} atlas; the GPU's largest "
                                 "texture is {}^2 (fewer slots or smaller tiles)",
                                 c.pool_slots, c.tile_size, width_, height_, max_texture)};
    // RGBA8 with one level: a rectangle texture, which the shader samples in texel coordinates
    // (no normalisation, no mip level to select): fewer instructions per lookup on a software
    // rasterizer. Block formats cannot live in a rectangle texture: always 2D.
    // A multi-layer pool's atlases are all 2D: the shader samples two of them with one coordinate.
    const bool two_levels = c.has_second_level();
    const bool blocks = is_block_compressed(c.page_format);
    internal_format_ = internal_format(c);
    texture_ = make_texture(two_levels || blocks || !c.more_layers.empty() ? GL_TEXTURE_2D : GL_TEXTURE_RECTANGLE);
    // One- and two-channel formats read as RGBA8 pages of such stores do (transcode.hpp): (v, v, v, 1)
    // and (v, v, v, a), so every format of a layer shows the same picture and a normal layer's
    // two samples are red and alpha whatever its format.
    if (c.page_format == PageFormat::bc4 || c.page_format == PageFormat::r16 || c.page_format == PageFormat::r16f ||
        c.page_format == PageFormat::r32f) {
        const GLint grey[4] = {GL_RED, GL_RED, GL_RED, GL_ONE};
        glTextureParameteriv(texture_.get(), GL_TEXTURE_SWIZZLE_RGBA, grey);
    } else if (c.page_format == PageFormat::bc5) {
        const GLint grey_alpha[4] = {GL_RED, GL_RED, GL_RED, GL_GREEN};
        glTextureParameteriv(texture_.get(), GL_TEXTURE_SWIZZLE_RGBA, grey_alpha);
    }
    glTextureStorage2D(texture_.get(), two_levels ? 2 : 1, internal_format_, GLsizei(width_), GLsizei(height_));
    glTextureParameteri(texture_.get(), GL_TEXTURE_MIN_FILTER, two_levels ? GL_LINEAR_MIPMAP_LINEAR : GL_LINEAR);
    glTextureParameteri(texture_.get(), GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    glTextureParameteri(texture_.get(), GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTextureParameteri(texture_.get(), GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    if (!blocks) {  // compressed textures cannot be cleared; only mapped cells are ever sampled
        const std::uint8_t zero[4] = {0, 0, 0, 0};
        glClearTexImage(texture_.get(), 0, GL_RGBA, GL_UNSIGNED_BYTE, zero);
        if (two_levels) {
            glClearTexImage(texture_.get(), 1, GL_RGBA, GL_UNSIGNED_BYTE, zero);
            TESSERA_TRY(mips_.init(texture_.get(), internal_format_, columns_, rows, c.tile_size,
                                   c.srgb && c.page_format == PageFormat::rgba8));
        }
    }
    page_mips_ = two_levels && !blocks;
    second_level_uploads_ = two_levels && blocks;
    if (auto e = take_gl_errors("page atlas"); !e.empty())
        return Error{Errc::resource_exhausted, fmt::format("renderer: {}x{} atlas: {}", width_, height_, e)};
    return Status();
}

bool PageAtlas::upload_page(SlotId slot, const PageKey& page, std::span<const std::uint8_t> data, std::uint32_t tile_size,
                            const std::optional<PagePlace>& place) {
    if (tile_size != tile_size_ || slot >= pool_slots_ ||
        data.size() != page_upload_bytes(format_, tile_size, second_level_uploads_))
        return false;
    const auto x = GLint((slot % columns_) * tile_size), y = GLint((slot / columns_) * tile_size);
    const auto side = GLsizei(tile_size);
    if (!is_block_compressed(format_)) {
        const auto [format, type] = upload_format(format_);
        staging_.upload_image(texture_.get(), x, y, side, side, format, type, data.data(), data.size());
        if (page_mips_) place_page_mip(slot, page, place);
    } else {
        const std::size_t level0 = page_bytes(format_, tile_size);
        staging_.upload_blocks(texture_.get(), 0, x, y, side, internal_format_, data.first(level0));
        if (second_level_uploads_)
            staging_.upload_blocks(texture_.get(), 1, x / 2, y / 2, side / 2, internal_format_, data.subspan(level0));
    }
    return true;
}

void PageAtlas::make_page_mips() {
    if (page_mips_) mips_.run();
}

std::pair<std::uint32_t, std::uint32_t> PageAtlas::parent_quarter(const PageKey& child, SlotId parent_slot) const {
    const std::uint32_t ts = tile_size_, P = ts - 2 * border_, B = border_;
    return {(parent_slot % columns_) * ts + (child.x & 1) * (P / 2) + B / 2,
            (parent_slot / columns_) * ts + (child.y & 1) * (P / 2) + B / 2};
}

void PageAtlas::place_page_mip(SlotId slot, const PageKey& page, const std::optional<PagePlace>& place) {
    if (slot_pages_.size() != pool_slots_) slot_pages_.assign(pool_slots_, PageKey{0xFFFF, 31, 0, 0});
    PageKey& old = slot_pages_[slot];
    if (auto it = page_slots_.find(old); it != page_slots_.end() && it->second == slot) page_slots_.erase(it);
    old = page;
    page_slots_[page] = slot;
    const bool known = place.has_value();
    const bool last = known && std::uint32_t(page.level) + 1 >= place->levels;  // blends nothing coarser
    if (!last) {
        if (auto p = page_slots_.find(page.parent()); known && p != page_slots_.end()) {
            const auto [x, y] = parent_quarter(page, p->second);
            mips_.copy_from_parent(slot % columns_, slot / columns_, x, y);
        } else {
            // The cell's 2x2 means, clamped at the texture's edges; a page of a texture not added
            // is halved as it is.
            const PagePlace at = place.value_or(PagePlace{0, 0, 0, UINT32_MAX, UINT32_MAX});
            mips_.mark(slot % columns_, slot / columns_, at.origin_x, at.origin_y, at.level_width, at.level_height);
        }
    }
    if (!known || page.level == 0) return;
    for (std::uint32_t k = 0; k < 4; ++k) {
        const PageKey child{page.texture, std::uint8_t(page.level - 1), 2 * page.x + (k & 1), 2 * page.y + (k >> 1)};
        if (auto c = page_slots_.find(child); c != page_slots_.end()) {
            const auto [x, y] = parent_quarter(child, slot);
            mips_.copy_from_parent(c->second % columns_, c->second / columns_, x, y);
        }
    }
}

std::vector<std::uint8_t> PageAtlas::read_page(SlotId slot) const {
    if (slot >= pool_slots_ || is_block_compressed(format_)) return {};
    const auto [format, type] = upload_format(format_);
    std::vector<std::uint8_t> out(page_bytes(format_, tile_size_));
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    glBindBuffer(GL_PIXEL_PACK_BUFFER, 0);
    const auto ts = GLsizei(tile_size_);
    glGetTextureSubImage(texture_.get(), 0, GLint((slot % columns_) * tile_size_), GLint((slot / columns_) * tile_size_), 0,
                         ts, ts, 1, format, type, GLsizei(out.size()), out.data());
    return out;
}

}  // namespace tessera::client::gl::detail
