// reference.frag: the reference renderer (docs/viewer.md, "Measures"): the same LoD rule and filter
// as the VT (vt_sample.glsl's vt_lod / vt_wanted_level / taps), no bias, sampling an ordinary
// mipmapped GL texture with textureLod, so bilinear and trilinear pick exactly the VT's levels.
// With more layers (VT_LAYERS: the terrain's normals, a glTF material's maps) each is an ordinary
// texture of its own, read at the same places with the same weights, and lit as the VT pass lights.
#include "vt_sample.glsl"
#ifdef VT_MATERIAL
#include "material.glsl"
#endif

in vec2 v_local;
flat in uvec2 vt_texel_origin;          // the chunk's (scene.vert)
flat in int vt_blend;                   // a blended chunk (scene.vert)
uniform sampler2D ref_texture;          // GL_LINEAR_MIPMAP_LINEAR, clamp to edge
#ifdef VT_LAYERS
uniform sampler2D ref_layers[VT_LAYERS];  // the other layers' levels, the same way
#endif
const vec2 ref_size = REF_TEXTURE_SIZE;  // level-0 texels (compiled in, as the VT's constants)

layout(location = 0) out vec4 o_colour;

#ifdef REF_SECOND_LEVELS
// A block-format atlas holds under each page of level L its own second level (ref_second's mip
// L), and trilinear blends level L with that rather than with level L + 1.
uniform sampler2D ref_second;
#ifdef VT_LAYERS
uniform sampler2D ref_layer_seconds[VT_LAYERS];
#endif
vec4 ref_blend(sampler2D fine, sampler2D second, vec2 texel, float lod) {
    float lc = vt_clamped_lod(lod);
    float l = floor(lc);
    vec4 c = textureLod(fine, texel / ref_size, l);
    return lc > l ? mix(c, textureLod(second, texel / ref_size, l), lc - l) : c;
}
vec4 ref_trilinear(vec2 texel, float lod) { return ref_blend(ref_texture, ref_second, texel, lod); }
#ifdef VT_LAYERS
vec4 ref_layer_trilinear(int k, vec2 texel, float lod) { return ref_blend(ref_layers[k], ref_layer_seconds[k], texel, lod); }
#endif
#else
vec4 ref_trilinear(vec2 texel, float lod) { return textureLod(ref_texture, texel / ref_size, vt_clamped_lod(lod)); }
#ifdef VT_LAYERS
vec4 ref_layer_trilinear(int k, vec2 texel, float lod) { return textureLod(ref_layers[k], texel / ref_size, vt_clamped_lod(lod)); }
#endif
#endif

void main() {
    vec2 dx = dFdx(v_local), dy = dFdy(v_local);
    float lod = vt_lod(dx, dy);
    vec2 texel = vec2(vt_texel_origin) + v_local;
#ifdef VT_MATERIAL
    MatFrame frame = mat_frame(v_local);  // derivatives: before the alpha test's discard
#endif
#ifdef VT_LAYERS
    vec4 layers[VT_LAYERS];
#endif
#if VT_FILTER == VT_BILINEAR
    float level = float(vt_wanted_level(lod));
    o_colour = textureLod(ref_texture, texel / ref_size, level);
#ifdef VT_LAYERS
    for (int k = 0; k < VT_LAYERS; ++k) layers[k] = textureLod(ref_layers[k], texel / ref_size, level);
#endif
#elif VT_FILTER == VT_TRILINEAR
    o_colour = ref_trilinear(texel, lod);
#ifdef VT_LAYERS
    for (int k = 0; k < VT_LAYERS; ++k) layers[k] = ref_layer_trilinear(k, texel, lod);
#endif
#else
    vec2 axis;
    float count;
    vt_aniso_taps(dx, dy, vt_clamped_lod(lod), axis, count);
    vec4 sum = vec4(0.0);
    for (int i = 0; i < int(count); ++i) sum += ref_trilinear(texel + vt_tap_offset(axis, count, i), lod);
    o_colour = sum / count;
#ifdef VT_LAYERS
    for (int k = 0; k < VT_LAYERS; ++k) {
        vec4 layer_sum = vec4(0.0);
        for (int i = 0; i < int(count); ++i) layer_sum += ref_layer_trilinear(k, texel + vt_tap_offset(axis, count, i), lod);
        layers[k] = layer_sum / count;
    }
#endif
#endif
#ifdef VT_ALPHA_TEST
    if (vt_blend == 0) {  // cut-outs, as the VT pass; a blended chunk keeps its alpha
        if (o_colour.a < vt_alpha_cutoff) discard;
        o_colour.a = 1.0;
    }
#endif
#ifdef VT_LIT
    o_colour.rgb = vt_lit(o_colour.rgb, layers[0]);
#endif
#ifdef VT_MATERIAL
    o_colour.rgb = mat_shade(frame, o_colour.rgb, layers);
#endif
}
