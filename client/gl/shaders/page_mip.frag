// page_mip.frag: a texel of a cell's second level is the level-(L+1) texel over it: the mean of
// its 2x2 level-L texels, edge-clamped like the store's builder (storage/src/builder/mip_reducer),
// and clamped to the level at the texture's edges, where the page's border holds copies of the
// edge texel rather than its neighbours. For an sRGB atlas texelFetch decodes and the sRGB target
// encodes, so the mean is taken in linear light, as the builder takes it.
uniform sampler2D pm_pages;  // the atlas's level 0 (a view of it)
uniform int pm_tile_size;    // texels per cell side at level 0 (even)

flat in ivec2 v_cell;
flat in ivec2 v_origin;  // even: page * P - B
flat in ivec2 v_size;

layout(location = 0) out vec4 o_colour;

void main() {
    ivec2 j = ivec2(gl_FragCoord.xy) - v_cell * (pm_tile_size / 2);    // texel in the cell's second level
    ivec2 k = clamp(v_origin / 2 + j, ivec2(0), (v_size + 1) / 2 - 1);  // the level-(L+1) texel
    ivec2 a = 2 * k, b = min(a + 1, v_size - 1);                        // its level-L texels
    ivec2 at = v_cell * pm_tile_size - v_origin;                        // atlas texel of level-L texel (0, 0)
    vec4 sum = texelFetch(pm_pages, at + a, 0) + texelFetch(pm_pages, at + ivec2(b.x, a.y), 0) +
               texelFetch(pm_pages, at + ivec2(a.x, b.y), 0) + texelFetch(pm_pages, at + b, 0);
    o_colour = 0.25 * sum;
}
