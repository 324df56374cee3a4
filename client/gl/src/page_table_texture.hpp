#pragma once
// The virtual textures' page tables on the GPU, mirroring the runtime's PageTables
// (tessera/client/page_table_layout.hpp) with each entry's slot replaced by its atlas cell.
//
// Dense: every level in one R32UI texture, level 0 at (0, 0), levels 1.. stacked in a column to
// its right (PageTableLayout::dense_level_origin: closed-form, so the shader computes it; level sizes
// round up, so they are no mip chain), updated by rectangles. Two-level (sparse CPU tables;
// vt_sample.glsl's VT_SPARSE_TABLE), for tables too large for that packing: a directory per level
// (block slot + 1, 0: unallocated) and a pool of 32x32-entry blocks, both SSBOs, updated by blocks.
#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <unordered_map>
#include <vector>

#include "gl_util.hpp"
#include "page_atlas.hpp"
#include "staging.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::client::gl::detail {

// A virtual texture's geometry and its page table.
struct VirtualTexture {
    TextureId id = 0;
    std::uint32_t levels = 0, payload = 0, border = 0;
    std::vector<std::int32_t> origin;      // 2 per level: table texel of the level's entry (0, 0)
    std::vector<std::uint32_t> pages;      // 2 per level: tiles_x, tiles_y
    std::vector<std::uint32_t> texels;     // 2 per level: width, height
    std::uint32_t table_width = 0, table_height = 0;
    Texture table;  // dense
    bool sparse = false;
    std::vector<std::uint32_t> dir_offset, dir_width;  // per level
    Buffer directory, blocks;
    std::unordered_map<std::uint64_t, std::uint32_t> block_slot;  // (level, bx, by) -> pool slot
    std::vector<std::uint32_t> free_blocks;

    // The dense table on texture unit 0, or the two-level one on SSBO bindings 1 and 2.
    void bind() const;
};

// What a page-table upload did (the renderer counts them).
enum class TableUpload { uploaded, unchanged, malformed };

class PageTableTextures {
public:
    PageTableTextures(StagingRing& staging, const PageAtlas& atlas) : staging_(staging), atlas_(atlas) {}
    // The GPU's limits, and the pool the two-level tables' block pools are sized for.
    void init(std::uint32_t pool_slots, std::uint32_t tile_size, std::uint32_t border, std::uint32_t max_texture,
              GLint64 max_ssbo);

    // Creates (or replaces) `texture`'s table for the geometry of `info`: dense when
    // PageTableLayout::dense_packing_fits, else two-level. On error the old one stays.
    Status add(TextureId texture, const storage::StoreInfo& info);
    const VirtualTexture* find(TextureId texture) const;
    // Where `page` lies in its texture; nothing for an unknown texture or level.
    std::optional<PagePlace> place(const PageKey& page) const;

    // A w x h rectangle of a dense table's level.
    TableUpload upload_rect(TextureId texture, std::uint8_t level, std::uint32_t x0, std::uint32_t y0, std::uint32_t w,
                            std::uint32_t h, std::span<const std::uint32_t> entries);
    // A block of a sparse table, or its release (`entries` empty).
    TableUpload upload_block(TextureId texture, std::uint8_t level, std::uint32_t bx, std::uint32_t by,
                             std::span<const std::uint32_t> entries);

private:
    Status make_two_level(VirtualTexture& t);
    // The entries as the GPU holds them; valid until the next call.
    std::span<const std::uint32_t> gpu_entries(std::span<const std::uint32_t> entries);

    StagingRing& staging_;
    const PageAtlas& atlas_;
    std::uint32_t pool_slots_ = 0, tile_size_ = 0, border_ = 0, max_texture_ = 0;
    GLint64 max_ssbo_ = 0;
    std::map<TextureId, VirtualTexture> textures_;
    std::vector<std::uint32_t> gpu_entries_;  // gpu_entries' scratch
};

}  // namespace tessera::client::gl::detail
