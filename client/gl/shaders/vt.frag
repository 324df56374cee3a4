// vt.frag: the VT pass. Samples the virtual texture and counts, per frame, fallback pixels
// (design.md "Measures": the sampled page is coarser than the level wanted, without and with the
// bias); the renderer counts the textured pixels with an occlusion query around this pass. Early
// fragment tests against the pre-pass depth (GL_LEQUAL), so hidden fragments neither shade nor
// count. An empty entry (nothing resident) counts as fallback. Only fallback pixels touch the
// counters: they are rare once a view has loaded, and an atomic per fragment on one address is
// what a software rasterizer's threads would serialise on.
layout(early_fragment_tests) in;

#include "vt_sample.glsl"

in vec2 v_local;

layout(std430, binding = 0) buffer VtCounters {
    uint textured;  // unused: the occlusion query counts these
    uint fallback_unbiased;
    uint fallback_biased;
    uint reserved;
} vt_counters;

layout(location = 0) out vec4 o_colour;

void main() {
    VtSample s = vt_sample(v_local);
    o_colour = s.colour;
    if (s.resident > s.wanted_unbiased) atomicAdd(vt_counters.fallback_unbiased, 1u);
    if (s.resident > s.wanted) atomicAdd(vt_counters.fallback_biased, 1u);
}
