#pragma once
// Blending in (docs/renderer.md, "Blending in"): each atlas cell's weight, 0 in the first frame
// that shows a page just uploaded into it and 1 once the page has faded in, kept in an R8 texture
// of the atlas's grid that vt_sample.glsl reads (vt_fade), and falling back to 0 for a page that
// leaves (fades out) before its cell is reused; and the LoD bias a frame draws with,
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
    // The page in `slot` leaves: from the next frame its weight falls from where it is to 0 over
    // the fade time; then the slot is given back by take_gone().
    void leaving(SlotId slot);
    // The page leaving `slot` stays after all: from the next frame its weight rises from where it
    // is to 1 over the fade time (from 0 when it had faded out and was not yet taken), and the
    // slot is not given back.
    void kept(SlotId slot);
    // Appends the slots whose page has faded out since the last call.
    void take_gone(std::vector<SlotId>& out);
    // The next frame is drawn at `now` (seconds, never decreasing) with `requested_bias`: brings
    // the weights to `now`, uploads the rows that changed, and returns the bias to draw with.
    float frame(double now, float requested_bias);

    GLuint texture() const { return texture_.get(); }
    // Cells below full weight: fading in or out, or faded out and not yet taken (take_gone): a
    // page at weight 0 is still mapped until the runtime has its slot back, and must be drawn with
    // its weight until then, not at full weight.
    std::size_t fading() const { return fading_.size() + gone_.size(); }

private:
    void start(SlotId slot, bool out);

    struct Fading {
        SlotId slot;
        double start;      // seconds; < 0: starts in the next frame
        double from = 0;   // the weight at `start`
        bool out = false;  // fading out (leaving), else in
    };

    double fade_s_ = 0;
    std::uint32_t columns_ = 1, rows_ = 0;
    Texture texture_;
    std::vector<std::uint8_t> weights_;  // the texture's texels, row by row
    std::vector<Fading> fading_;
    std::vector<std::uint32_t> fading_index_;  // per cell: its place in fading_ + 1, 0: not fading
    std::vector<SlotId> gone_;                 // faded out, not yet taken
    bool have_bias_ = false;
    float bias_ = 0;
    double last_ = 0;
};

}  // namespace tessera::client::gl::detail
