#pragma once
// The physical page atlas: the pool's pages in one texture, a near-square grid of tile_size cells
// (slot s in column s % columns, row s / columns), in the configured page format. Pages arrive
// through the staging ring; with two levels (RendererConfig::has_second_level) each cell's second level
// holds the page's next coarser level: rendered on the GPU for uncompressed pages (page_mips.hpp),
// uploaded with the page for block formats, which cannot be rendered into.
#include <algorithm>
#include <cstdint>
#include <optional>
#include <span>
#include <unordered_map>
#include <utility>
#include <vector>

#include "gl_util.hpp"
#include "page_mips.hpp"
#include "staging.hpp"
#include "tessera/client/gl/renderer.hpp"

namespace tessera::client::gl::detail {

// Whether this GL can hold the configured page format, and if not, why, naming the format (a
// missing format must be an error, never a black image).
Status check_page_format_support(const RendererConfig& c);

// Where a page lies in its virtual texture, for its second level: the texture's level count, and
// the page's texel (0, 0), border included, in a level of level_width x level_height texels.
struct PagePlace {
    std::uint32_t levels = 0;
    std::int32_t origin_x = 0, origin_y = 0;
    std::uint32_t level_width = 0, level_height = 0;
};

class PageAtlas {
public:
    explicit PageAtlas(StagingRing& staging) : staging_(staging) {}

    // Creates the texture for config's pool (pool_slots, tile_size, border, filter, page_format,
    // srgb). Errors: a grid over `max_texture` per side, or over the GPU entry's cell fields.
    Status init(const RendererConfig& c, std::uint32_t max_texture);

    // Uploads, or false for a malformed page (wrong tile size, slot or byte count). `place`: where
    // the page lies, when its texture is known (the second level is clamped at its edges).
    bool upload_page(SlotId slot, const PageKey& page, std::span<const std::uint8_t> data, std::uint32_t tile_size,
                     const std::optional<PagePlace>& place);
    // The second levels of this frame's uploads; before the frame's draws, in stream order.
    void make_page_mips();
    // Level 0 of `slot`'s cell in the page format; empty for block formats. Waits.
    std::vector<std::uint8_t> read_page(SlotId slot) const;

    PagePoolFormat pool_format() const { return {format_, second_level_uploads_, {}}; }
    GLuint texture() const { return texture_.get(); }
    std::uint32_t width() const { return width_; }
    std::uint32_t height() const { return height_; }
    // The slot's cell as a GPU page-table entry names it (vt_sample.glsl's vt_cell_origin): column
    // in bits 0..11, row in bits 12..23, so the shader places a page without a division.
    std::uint32_t cell_code(SlotId slot) const { return (slot % columns_) | ((slot / columns_) << 12); }
    // The grid: cells per row, and rows.
    std::uint32_t columns() const { return columns_; }
    std::uint32_t rows() const { return height_ / std::max<std::uint32_t>(tile_size_, 1); }

private:
    static constexpr std::uint32_t kMaxCells = 4096;  // per side: 12 bits each in a GPU entry

    // The second level of the cell `slot` now holding `page`: the parent page's texels over it
    // when the parent is in the atlas, else its 2x2 means; and the page's own texels into the
    // second level of its children in the atlas.
    void place_page_mip(SlotId slot, const PageKey& page, const std::optional<PagePlace>& place);
    // Level-0 atlas texel of the corner of the quarter of `parent_slot`'s tile over `child`.
    std::pair<std::uint32_t, std::uint32_t> parent_quarter(const PageKey& child, SlotId parent_slot) const;

    StagingRing& staging_;
    Texture texture_;
    GLenum internal_format_ = GL_RGBA8;
    PageFormat format_ = PageFormat::rgba8;
    std::uint32_t pool_slots_ = 0, tile_size_ = 0, border_ = 0;
    std::uint32_t columns_ = 1, width_ = 0, height_ = 0;
    bool page_mips_ = false;             // two levels, uncompressed: the second level made on the GPU
    bool second_level_uploads_ = false;  // two levels, block formats: uploaded with each page
    PageMipPass mips_;
    // Which page each cell holds, and back, for place_page_mip: a cache of the runtime's
    // residency, which owns the slot assignment but which PageUploader gives no view of; learned
    // from upload_page (only with page_mips_). A slot's old page stays named until the slot is
    // overwritten: its texels are still there.
    std::vector<PageKey> slot_pages_;
    std::unordered_map<PageKey, SlotId, PageKeyHash> page_slots_;
};

}  // namespace tessera::client::gl::detail
