#pragma once
// Blending in (docs/renderer.md, "Blending in"): each atlas cell's weight, 0 in the first frame
// that shows a page just uploaded into it and 1 once the page has faded in, kept in an R8 texture
// of the atlas's grid that vt_sample.glsl reads (vt_fade); and the LoD bias a frame draws with,
// which follows the requested one by at most one level per fade time, so that a bias step does
// not change the whole screen at once. Updated per frame: only the cells fading, only the rows
// holding them, never the page tables.
#include <cstdint>
#include <vector>

#include "gl_util.hpp"
#include "tessera/client/page.hpp"

namespace tessera::client::gl::detail {

class PageFade {
public:
    // An atlas of columns x rows cells (slot s in column s % columns, row s / columns); fade_ms 0: off.
    Status init(std::uint32_t columns, std::uint32_t rows, float fade_ms);
    bool enabled() const { return fade_s_ > 0; }

    // A page was uploaded into `slot` since the last frame: it starts at weight 0 in the next one.
    void arrived(SlotId slot);
    // The next frame is drawn at `now` (seconds, never decreasing) with `requested_bias`: brings
    // the weights to `now`, uploads the rows that changed, and returns the bias to draw with.
    float frame(double now, float requested_bias);

    GLuint texture() const { return texture_.get(); }
    std::size_t fading() const { return fading_.size(); }  // cells below full weight

private:
    struct Fading {
        SlotId slot;
        double start;  // seconds; < 0: starts in the next frame
    };

    double fade_s_ = 0;
    std::uint32_t columns_ = 1, rows_ = 0;
    Texture texture_;
    std::vector<std::uint8_t> weights_;  // the texture's texels, row by row
    std::vector<Fading> fading_;
    std::vector<std::uint32_t> fading_index_;  // per cell: its place in fading_ + 1, 0: not fading
    bool have_bias_ = false;
    float bias_ = 0;
    double last_ = 0;
};

}  // namespace tessera::client::gl::detail
