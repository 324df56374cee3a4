// vt.frag: the VT pass. Samples the virtual texture and counts, per frame, fallback pixels
// (docs/viewer.md, "Measures": the sampled page is coarser than the level wanted, without and with
// the bias); the renderer counts the textured pixels with an occlusion query around this pass.
// Early fragment tests against the pre-pass depth (GL_LEQUAL), so hidden fragments neither shade
// nor count. An empty entry (nothing resident) counts as fallback. Only fallback pixels touch the
// counters: they are rare once a view has loaded, and an atomic per fragment on one address is what
// a software rasterizer's threads would serialise on. One atomic, not one per measure: the pixel
// adds to the counter of its kind (fallback against the unbiased level only, the biased only, or
// both), and the renderer sums kinds when it reads them back. A SIMD rasterizer pays for each
// atomic statement whether or not a lane takes it.
layout(early_fragment_tests) in;

#include "vt_sample.glsl"
#ifdef VT_MATERIAL
#include "material.glsl"
#endif

in vec2 v_local;
flat in int vt_blend;  // a blended chunk (scene.vert)

layout(std430, binding = 0) buffer VtCounters {
    // [u + 2 b]: pixels that fall back against the unbiased level (u = 1), the biased level
    // (b = 1), or both. [0] is unused: the occlusion query counts the textured pixels.
    uint fallback[4];
} vt_counters;

layout(location = 0) out vec4 o_colour;

void main() {
    VtSample s = vt_sample(v_local);
#ifdef VT_MATERIAL
    MatFrame frame = mat_frame(v_local);  // derivatives: before the alpha test's discard
#endif
    o_colour = s.colour;
#ifdef VT_ALPHA_TEST
    // Cut-outs: the pre-pass discarded this pixel too, and left the depth of what lies behind,
    // which draws here at GL_LEQUAL; what is kept is opaque. A blended chunk (drawn after the
    // others, far to near, blending by its alpha) keeps its alpha instead.
    if (vt_blend == 0) {
        if (s.colour.a < vt_alpha_cutoff) discard;
        o_colour.a = 1.0;
    }
#endif
#ifdef VT_LIT
    o_colour.rgb = vt_lit(s.colour.rgb, s.layers[0]);
#endif
#ifdef VT_MATERIAL
    o_colour.rgb = mat_shade(frame, s.colour.rgb, s.layers);
#endif
    int kind = int(s.resident > s.wanted_unbiased) + 2 * int(s.resident > s.wanted);
    if (kind != 0) atomicAdd(vt_counters.fallback[kind], 1u);
}
