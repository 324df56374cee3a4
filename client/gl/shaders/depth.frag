// depth.frag: the depth pre-pass of the VT pass (no colour). With cut-outs (VT_ALPHA_TEST) it
// samples the virtual texture as the VT pass does (same derivatives, same pages, so the same
// alpha) and discards where the VT pass discards: a cut-out's hole keeps the depth of what lies
// behind it, which the VT pass then draws.
#ifdef VT_ALPHA_TEST
#include "vt_sample.glsl"

in vec2 v_local;

void main() {
    if (vt_sample(v_local).colour.a < vt_alpha_cutoff) discard;
}
#else
void main() {}
#endif
