// reference.frag: the reference renderer (docs/viewer.md, "Measures"): the same LoD rule and filter
// as the VT (vt_sample.glsl's vt_lod / vt_wanted_level / taps), no bias, sampling an ordinary
// mipmapped GL texture with textureLod, so bilinear and trilinear pick exactly the VT's levels.
#include "vt_sample.glsl"

in vec2 v_local;
flat in uvec2 vt_texel_origin;          // the chunk's (scene.vert)
uniform sampler2D ref_texture;          // GL_LINEAR_MIPMAP_LINEAR, clamp to edge
#ifdef VT_LIT
uniform sampler2D ref_normals;          // the normal layer, the same way: lit as the VT pass lights
#endif
const vec2 ref_size = REF_TEXTURE_SIZE;  // level-0 texels (compiled in, as the VT's constants)

layout(location = 0) out vec4 o_colour;

#ifdef REF_SECOND_LEVELS
// A block-format atlas holds under each page of level L its own second level (ref_second's mip
// L), and trilinear blends level L with that rather than with level L + 1.
uniform sampler2D ref_second;
#ifdef VT_LIT
uniform sampler2D ref_normal_second;
#endif
vec4 ref_blend(sampler2D fine, sampler2D second, vec2 texel, float lod) {
    float lc = vt_clamped_lod(lod);
    float l = floor(lc);
    vec4 c = textureLod(fine, texel / ref_size, l);
    return lc > l ? mix(c, textureLod(second, texel / ref_size, l), lc - l) : c;
}
vec4 ref_trilinear(vec2 texel, float lod) { return ref_blend(ref_texture, ref_second, texel, lod); }
#ifdef VT_LIT
vec4 ref_normal_trilinear(vec2 texel, float lod) { return ref_blend(ref_normals, ref_normal_second, texel, lod); }
#endif
#else
vec4 ref_trilinear(vec2 texel, float lod) { return textureLod(ref_texture, texel / ref_size, vt_clamped_lod(lod)); }
#ifdef VT_LIT
vec4 ref_normal_trilinear(vec2 texel, float lod) { return textureLod(ref_normals, texel / ref_size, vt_clamped_lod(lod)); }
#endif
#endif

void main() {
    vec2 dx = dFdx(v_local), dy = dFdy(v_local);
    float lod = vt_lod(dx, dy);
    vec2 texel = vec2(vt_texel_origin) + v_local;
#if VT_FILTER == VT_BILINEAR
    o_colour = textureLod(ref_texture, texel / ref_size, float(vt_wanted_level(lod)));
#ifdef VT_LIT
    o_colour.rgb = vt_lit(o_colour.rgb, textureLod(ref_normals, texel / ref_size, float(vt_wanted_level(lod))));
#endif
#elif VT_FILTER == VT_TRILINEAR
    o_colour = ref_trilinear(texel, lod);
#ifdef VT_LIT
    o_colour.rgb = vt_lit(o_colour.rgb, ref_normal_trilinear(texel, lod));
#endif
#else
    vec2 axis;
    float count;
    vt_aniso_taps(dx, dy, vt_clamped_lod(lod), axis, count);
    vec4 sum = vec4(0.0);
    for (int i = 0; i < int(count); ++i) sum += ref_trilinear(texel + vt_tap_offset(axis, count, i), lod);
    o_colour = sum / count;
#ifdef VT_LIT
    vec4 nsum = vec4(0.0);
    for (int i = 0; i < int(count); ++i) nsum += ref_normal_trilinear(texel + vt_tap_offset(axis, count, i), lod);
    o_colour.rgb = vt_lit(o_colour.rgb, nsum / count);
#endif
#endif
#ifdef VT_ALPHA_TEST
    if (o_colour.a < vt_alpha_cutoff) discard;  // cut-outs, as the VT pass
    o_colour.a = 1.0;
#endif
}
