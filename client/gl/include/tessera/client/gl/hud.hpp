#pragma once
// Hud: the windowed viewer's live statistics, lines of text drawn over the top-left corner of the
// framebuffer on a translucent panel. A built-in 5x7 pixel font (printable ASCII; lower case is
// shown as upper case, characters without a glyph as '?'), so it needs no font files.
#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <string>

#include "tessera/result.hpp"

namespace tessera::client::gl {

class Hud {
public:
    // Cell geometry in font pixels: a 5x7 glyph, one blank column to its right and one blank row
    // above and below it.
    static constexpr int kCellWidth = 6;
    static constexpr int kCellHeight = 9;
    static constexpr int kMargin = 4;        // framebuffer pixels from the corner to the panel
    static constexpr int kMaxColumns = 96;   // longer lines are cut
    static constexpr int kMaxLines = 24;     // further lines are dropped

    // Needs a current GL 4.5 core context (GlContext); draws with that context only.
    static Result<std::unique_ptr<Hud>> create();
    virtual ~Hud() = default;

    // Draws `lines` into the framebuffer bound to GL_DRAW_FRAMEBUFFER (fb_width x fb_height pixels),
    // each font pixel `scale` x `scale` framebuffer pixels. The panel's top-left corner is at
    // (kMargin, kMargin) from the top-left of the framebuffer. Leaves depth test and blending off.
    virtual void draw(std::span<const std::string> lines, int fb_width, int fb_height, int scale = 2) = 0;
};

// Glyph of `c`: 7 rows top to bottom, 5 bits each, bit 4 the leftmost column.
std::array<std::uint8_t, 7> hud_glyph(char c);

}  // namespace tessera::client::gl
