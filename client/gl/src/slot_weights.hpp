#pragma once
// Blend weights (docs/renderer.md, "Blending in"): each atlas cell's weight, as the runtime's page
// cache sets it (PageUploader::set_slot_weights; docs/client.md, "A slot's life"), kept in an R8
// texture of the atlas's grid that vt_sample.glsl reads (vt_fade). The weights only change here;
// when and how fast they move is the page cache's. Uploaded once per frame: only the rows that
// changed, never the page tables.
#include <cstdint>
#include <span>
#include <vector>

#include "gl_util.hpp"
#include "tessera/client/upload.hpp"

namespace tessera::client::gl::detail {

class SlotWeights {
public:
    // An atlas of columns x rows cells (slot s in column s % columns, row s / columns), all at 255.
    Status init(std::uint32_t columns, std::uint32_t rows);
    // Returns how many entries were ignored (a slot outside the atlas).
    std::size_t set(std::span<const SlotWeight> weights);
    // Uploads the rows changed since the last call (before a frame is drawn).
    void upload();

    GLuint texture() const { return texture_.get(); }
    // Cells below full weight: blending in, fading out or kept.
    std::size_t below_full() const { return below_full_; }

private:
    std::uint32_t columns_ = 1, rows_ = 0;
    Texture texture_;
    std::vector<std::uint8_t> weights_;  // the texture's texels, row by row
    std::size_t below_full_ = 0;
    std::uint32_t first_row_ = ~0u, last_row_ = 0;  // rows changed since the last upload
};

}  // namespace tessera::client::gl::detail
