#pragma once
// The atlas's second level for the trilinear and anisotropic filters (vt_sample.glsl): under each
// resident page, its 2x2 means, i.e. the next coarser level's texels over the page (the page's
// border included, halved: the 4-texel border leaves 2, enough for a bilinear footprint). With it
// one page-table fetch and one textureLod give both levels of a trilinear lookup, and the coarser
// level is exact even where the parent page is not resident.
//
// The stored coarser level where it is resident: when a page's parent page is in the atlas, the
// quarter of the parent's tile over the page (with a 2-texel border) is copied into the page's
// second level (copy_from_parent), so trilinear blends exactly the store's two levels, as the
// reference does (for lossy codecs the 2x2 means differ from the separately encoded next level
// by its coding error). Otherwise, until the parent arrives, the 2x2 means stand in for it,
// made on the GPU in stream order after the page's upload: mark() the cells uploaded, run() once
// a frame before the frame's draws; one instanced draw, nothing waits. The pending list is bounded
// by the atlas's cells (a cell marked twice is drawn once, for its last page). At the texture's
// edges the coarser texels are clamped to the level (page_mip.frag), so the second level matches
// the store's next level there too.
#include <cstdint>
#include <vector>

#include "gl_util.hpp"
#include "tessera/result.hpp"

namespace tessera::client::gl::detail {

class PageMipPass {
public:
    PageMipPass() = default;
    // atlas: a 2-level GL_TEXTURE_2D of columns x rows cells of tile_size texels (even).
    Status init(GLuint atlas, GLenum format, std::uint32_t columns, std::uint32_t rows, std::uint32_t tile_size, bool srgb);

    // The cell now holds the page whose texel (0, 0) (border included) is level-L texel
    // (origin_x, origin_y), of a level of level_width x level_height texels. A page of unknown
    // place: origin (0, 0) and a level too large to clamp.
    void mark(std::uint32_t column, std::uint32_t row, std::int32_t origin_x, std::int32_t origin_y,
              std::uint32_t level_width, std::uint32_t level_height);
    // The cell's second level is the stored coarser level instead: copies the half-tile of the
    // parent page's cell that lies over it (parent_x, parent_y: level-0 atlas texels of that
    // half-tile's corner) and drops a pending mark of the cell. In stream order: the parent's
    // upload must have been issued.
    void copy_from_parent(std::uint32_t column, std::uint32_t row, std::uint32_t parent_x, std::uint32_t parent_y);
    // Draws the second level of every marked cell; leaves the draw framebuffer unbound (0).
    void run();
    std::uint64_t cells_made() const { return made_; }
    std::uint64_t cells_copied() const { return copied_; }

private:
    Program program_;
    Texture level0_;  // a view of the atlas's level 0: the draw samples it while writing level 1
    Framebuffer fbo_;
    GLuint atlas_ = 0;
    std::uint32_t tile_size_ = 0;
    VertexArray vao_;
    Buffer cells_;
    struct Cell {  // page_mip.vert's PageMipCell
        std::int32_t column, row, origin_x, origin_y, width, height, unused[2];
    };
    std::vector<Cell> pending_;
    std::vector<std::int32_t> pending_index_;  // per cell: its index in pending_, -1 if none
    std::uint32_t columns_ = 0, rows_ = 0, width_ = 0, height_ = 0;
    bool srgb_ = false;
    std::uint64_t made_ = 0, copied_ = 0;
};

}  // namespace tessera::client::gl::detail
