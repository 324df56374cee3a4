// vt.frag: the VT pass. Samples the virtual texture and counts, per frame, textured pixels and
// fallback pixels (design.md "Measures": the sampled page is coarser than the level wanted,
// without and with the bias). Early fragment tests against the pre-pass depth (GL_LEQUAL), so
// hidden fragments neither shade nor count. An empty entry (nothing resident) counts as fallback.
layout(early_fragment_tests) in;

#include "vt_sample.glsl"

in vec2 v_local;
uniform uvec2 u_texel_origin;  // the chunk's level-0 texel origin

layout(std430, binding = 0) buffer VtCounters {
    uint textured;
    uint fallback_unbiased;
    uint fallback_biased;
    uint reserved;
} vt_counters;

layout(location = 0) out vec4 o_colour;

void main() {
    VtSample s = vt_sample(u_texel_origin, v_local);
    o_colour = s.colour;
    atomicAdd(vt_counters.textured, 1u);
    if (s.resident > s.wanted_unbiased) atomicAdd(vt_counters.fallback_unbiased, 1u);
    if (s.resident > s.wanted) atomicAdd(vt_counters.fallback_biased, 1u);
}
