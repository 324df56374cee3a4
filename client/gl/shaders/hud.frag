// hud.frag: HUD text. Each fragment finds its character cell, the character in the text grid and
// the glyph bit of its font pixel: lit pixels are text, the rest the translucent panel.
uniform usampler2D u_text;  // R8UI, one texel per cell: the character code (32..126)
uniform usampler2D u_font;  // R8UI, 7 x 95: row r of glyph c - 32 at (r, c - 32), bit 4 leftmost
uniform ivec2 u_origin;     // the panel's top-left corner, framebuffer pixels from the top-left
uniform int u_fb_height;
uniform int u_scale;
uniform vec4 u_text_colour;
uniform vec4 u_panel_colour;

layout(location = 0) out vec4 o_colour;

void main() {
    ivec2 p = ivec2(int(gl_FragCoord.x), u_fb_height - 1 - int(gl_FragCoord.y)) - u_origin;
    ivec2 font_px = p / u_scale;  // font pixels from the panel corner (never negative here)
    ivec2 cell = font_px / ivec2(6, 9);
    ivec2 in_cell = font_px - cell * ivec2(6, 9);
    uint code = texelFetch(u_text, cell, 0).r;
    bool lit = false;
    if (code >= 32u && in_cell.x < 5 && in_cell.y >= 1 && in_cell.y <= 7) {
        uint bits = texelFetch(u_font, ivec2(in_cell.y - 1, int(code) - 32), 0).r;
        lit = ((bits >> uint(4 - in_cell.x)) & 1u) != 0u;
    }
    o_colour = lit ? u_text_colour : u_panel_colour;
}
