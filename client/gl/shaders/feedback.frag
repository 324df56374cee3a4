// feedback.frag: the feedback pass at 1/N resolution, depth-tested against its own depth buffer.
// Writes the packed id of the page the fragment wants (same LoD math as the VT pass, bias
// included; derivatives per main-target pixel, see below).
#include "vt_sample.glsl"

in vec2 v_local;
flat in int vt_blend;  // a blended chunk (scene.vert)
in float v_w;  // perspective-correct, so exact at the pixel centre (clipped triangles included)
// One main-target pixel in feedback pixels: (fb_width / width, fb_height / height), i.e. 1/N.
uniform vec2 vt_main_pixel;

layout(location = 0) out uvec2 o_id;

void main() {
    // Derivatives per main-target pixel at this pixel's centre: forward differences one main
    // pixel right and one main pixel down, exactly as scene::cpu_feedback takes them. (dFdx of
    // the texel coordinate at 1/N resolution differences across N main pixels: under perspective
    // that is off by whole levels near the horizon.) local / w and 1 / w are linear in screen
    // space, so their screen derivatives are exact, and local anywhere near the pixel is
    // (q + dq) / (r + dr).
    vec3 p = vec3(v_local, 1.0) / v_w;
    vec3 px = dFdx(p), py = dFdy(p);
    vec2 centre = v_local;
    vec3 right = p + px * vt_main_pixel.x, down = p - py * vt_main_pixel.y;
    vec2 dx = right.xy / right.z - centre;
    vec2 dy = down.xy / down.z - centre;
#ifdef VT_ALPHA_TEST
    // A blended chunk shows what lies behind it too: it asks for its pages from every other
    // pixel only, and what lies behind (drawn before it, its depth written) from the rest.
    if (vt_blend != 0 && ((int(gl_FragCoord.x) + int(gl_FragCoord.y)) & 1) == 0) discard;
    // Cut-outs: a pixel the main pass discards asks for nothing; what lies behind it (drawn with
    // its own depth, the discarded fragment having written none) asks for its pages. The alpha is
    // that of the wanted level's page (or the resident ancestor the main pass would sample).
    uint resident;
    if (vt_blend == 0 && vt_lookup(v_local, vt_wanted_level(vt_lod(dx, dy) + vt_bias), resident).a < vt_alpha_cutoff) discard;
#endif
    o_id = vt_feedback(v_local, dx, dy);
}
