// vt_sample.glsl: the virtual-texture sampling function, the one include every VT shader uses
// (docs/client.md, "One frame, end to end", steps 1 and 2; docs/renderer.md, "Sampling").
//
// The including shader is assembled by the renderer as
//     #version 450 core
//     #define VT_FILTER <VT_BILINEAR | VT_TRILINEAR | VT_ANISOTROPIC>
//     #define VT_TILE_SIZE, VT_BORDER, VT_MAX_ANISOTROPY, VT_ATLAS_SIZE, VT_NO_DATA_COLOUR
//     [#define VT_SPARSE_TABLE 1]   (vt.frag for two-level page tables: see vt_entry)
//     [#define VT_ATLAS_RECT 1]     (RGBA8 pages, one level: a rectangle atlas in texel coordinates)
//     [#define VT_FADE 1]           (blending in: each atlas cell's weight, see vt_fade_weight)
//     [#define VT_FADE_ENCODED 1]   (with VT_FADE on an sRGB target: blends mix encoded colours)
//     [#define VT_LAYERS n]         (n more layers sampled beside the colour: vt_layer_atlas)
//     [#define VT_LIT 1]            (the terrain lit by its normal layer, layer texels [0]: vt_lit)
//     [#define VT_MATERIAL 1, VT_NORMAL_MAP k, ...] (a glTF material's maps: material.glsl)
//     <this file> <the shader>
// (detail::vt_shader_defines). It is drawn with scene.vert, which forwards the per-draw,
// per-texture and per-frame values as flat varyings (see "Inputs").
//
// Conventions
// - Texel coordinates: the level-0 texel coordinate of a fragment is `origin + local`, where
//   `origin` is the chunk's integer texel origin and `local` a small interpolated float offset.
//   The shader sees the origin as its page frame (vt_chunk_*, see "Addressing"). Never one float
//   UV over the whole virtual texture.
// - Level L has ceil(size / 2^L) texels per side; the continuous level-L coordinate of level-0
//   coordinate t is t / 2^L (texel i of level L covers [i, i + 1), centre i + 0.5), as GL mips.
// - The LoD rule is tessera/scene/lod.hpp, line for line (vt_lod, vt_wanted_level).
// - Page-table entry as the renderer uploads it (tessera/client/page_table_layout.hpp's, with the slot
//   replaced by its atlas cell): bit 31 valid, bits 24..28 resident level R, bits 0..11 atlas
//   column, bits 12..23 atlas row; R > L: fallback to the ancestor at level R. 0: nothing resident.
// - The physical atlas is a grid of tile_size squares; a page's texel (i, j) (border included,
//   rows top to bottom) is atlas texel (column * ts + i, row * ts + j).

#define VT_BILINEAR 0
#define VT_TRILINEAR 1
#define VT_ANISOTROPIC 2
#ifndef VT_FILTER
#error "VT_FILTER must be defined"
#endif

#if !defined(VT_TILE_SIZE) || !defined(VT_BORDER) || !defined(VT_MAX_ANISOTROPY) || !defined(VT_ATLAS_SIZE) || !defined(VT_NO_DATA_COLOUR)
#error "the renderer-wide constants must be defined (detail::vt_shader_defines)"
#endif

// ---------------------------------------------------------------------------------------------
// Inputs. Three kinds, by how often they change (docs/renderer.md, "What a lookup costs"):
// - Renderer-wide constants are compiled in: one tile size, border and anisotropy serve every
//   texture (add_texture checks), and the atlas never changes size. Constant folding also saves
//   a GPU the conversions and multiplies.
// - Values of the draw (the chunk's page frame), the texture (its levels and table layout) and
//   the frame (the bias) come as flat varyings that scene.vert copies from its uniforms: a
//   software rasterizer loads a uniform in a fragment shader lane by lane, bounds-checked, at
//   every read, but a flat input once per block of pixels.
// - The page table and the atlas are textures (or, two-level, storage buffers).
const uint vt_tile_size = VT_TILE_SIZE;                 // P + 2B: atlas cell size
const uint vt_border = VT_BORDER;                       // B: border texels on each side of a page
const uint vt_payload = VT_TILE_SIZE - 2u * VT_BORDER;  // P: texels a page covers per side
const float vt_inv_payload = 1.0 / float(vt_payload);
const float vt_max_anisotropy = VT_MAX_ANISOTROPY;      // 1..8 (anisotropic filter)
const vec4 vt_no_data_colour = VT_NO_DATA_COLOUR;       // entry 0: nothing resident on the path

flat in uint vt_levels;             // levels of the virtual texture (the last one is one page)
flat in vec2 vt_texture_size;       // its level-0 texels (integers, exact below 2^24)
flat in float vt_bias;              // LoD bias (0 in the reference renderer)
// Where level L's entries start in vt_page_table (PageTable::dense_level_origin): level 0 at
// (0, 0), level L >= 1 at (vt_table_column, (L - 1) + U - (U >> (L - 1))), U = vt_table_last_row.
flat in int vt_table_column;        // level 0's pages per row
flat in int vt_table_last_row;      // level 0's pages per column - 1
// The drawn chunk's page frame (SceneGeometry::set_page_layout):
flat in ivec2 vt_chunk_page;        // the level-0 page holding the chunk's texel origin
flat in vec2 vt_chunk_base;         // that origin's position in the page: an integer below P
flat in vec4 vt_chunk_bounds;       // the texture's texels relative to the page's start: xy min, zw max

#ifdef VT_SPARSE_TABLE
// Two-level page table (textures whose dense table does not fit; PageTable, "Storage, sparse"):
// per level a directory of 32x32-entry blocks (block slot + 1, 0: unallocated) and the pool of
// allocated blocks. An unallocated block of level L defers to level L + 5 (the one page its
// region lies under), so a lookup walks up at most ceil(levels / 5) directory entries.
layout(std430, binding = 1) readonly buffer VtDirectory { uint vt_directory[]; };
layout(std430, binding = 2) readonly buffer VtBlocks { uint vt_blocks[]; };
uniform uint vt_dir_offset[32];     // level L's first directory entry
uniform uint vt_dir_width[32];      // level L's blocks per row
#else
uniform usampler2D vt_page_table;   // R32UI: every level of the texture's page table, packed
#endif
#ifdef VT_ATLAS_RECT
uniform sampler2DRect vt_atlas;     // the physical pages (RGBA8 or SRGB8_ALPHA8), GL_LINEAR; texel coordinates
#else
// Block-compressed pages (a 2D texture, one level for bilinear), and trilinear and anisotropic:
// two levels, the pages and below them each page's 2x2 means (RGBA8: its parent level's texels
// over the page), GL_LINEAR_MIPMAP_LINEAR: one page-table fetch and one textureLod give both
// levels of a trilinear lookup.
uniform sampler2D vt_atlas;
const vec2 vt_inv_atlas_size = 1.0 / VT_ATLAS_SIZE;  // 1 / the atlas's level-0 size, texels
#endif
#ifdef VT_LAYERS
// A multi-layer pool drawn with more layers than the colour: VT_LAYERS of them (a normal layer
// lighting the terrain, or a glTF material's maps), each an atlas with layer 0's grid, so the same
// coordinates, read wherever vt_atlas is with the same weights (vt_sample's VtSample.layers).
uniform sampler2D vt_layer_atlas[VT_LAYERS];
vec4 vt_layer_texels[VT_LAYERS];  // what the last vt_sample_entry read from them
#endif
#ifdef VT_LIT
// Layer 0's colour lit by a normal layer's filtered texel: Lambert under a fixed sun, in the
// texture's frame (x along u, y along v, z out of the surface); the normal's x and y are the
// texel's red and alpha mapped from [0, 1] to [-1, 1] (a 2-channel store's two samples in every
// page format), z implied. The VT pass and the reference renderer light alike.
vec3 vt_lit(vec3 colour, vec4 normal_texel) {
    vec2 nxy = vec2(normal_texel.r, normal_texel.a) * 2.0 - 1.0;
    vec3 n = vec3(nxy, sqrt(max(1.0 - dot(nxy, nxy), 0.0)));
    const vec3 sun = normalize(vec3(-0.5, -0.4, 0.75));
    return colour * (0.35 + 0.65 * max(dot(n, sun), 0.0));
}
#endif
uniform uint vt_texture_id;         // for the feedback id (feedback.frag: 1/N of the pixels)
#ifdef VT_ALPHA_TEST
// Cut-outs (RendererConfig::alpha_test): a pixel whose filtered alpha is below this is discarded
// by the depth pre-pass, the VT pass and the feedback pass (what real-time VT renderers do for
// foliage: no sorting, and the depth is that of what shows).
const float vt_alpha_cutoff = 0.5;
#endif
#ifdef VT_FADE
// Blending in (docs/renderer.md, "Blending in"): one weight per atlas cell (R8, the atlas's grid),
// 0 in the first frame that draws the cell's page, 1 once it has faded in. Bilinear and trilinear
// lookups blend the page with what was drawn before it arrived (vt_sample_entry); the anisotropic
// taps blend its second level (its parent level over it) in with weight 1 - w (1 - f), f the
// filter's own fraction (vt_faded_fraction).
uniform sampler2D vt_fade;
#define VT_FADE_CHAIN 4  // fading ancestors a blend follows (vt_sample_entry)

float vt_fade_weight(uint e) { return texelFetch(vt_fade, ivec2(int(e & 0xFFFu), int((e >> 12) & 0xFFFu)), 0).r; }

// The space the bilinear and trilinear blends mix in. A target with the sRGB curve shows the
// encoded value: a blend in linear light would move it unevenly (a fade towards a dark texel keeps
// most of its visible change for its last steps: 0.11 of the way in linear light is 0.37 of it
// encoded), so with VT_FADE_ENCODED (set for sRGB targets) the blend mixes encoded colours and
// each step of the fade moves what is seen by the same amount. Alpha mixes as it is.
#ifdef VT_FADE_ENCODED
vec4 vt_fade_space(vec4 c) {
    vec3 x = max(c.rgb, vec3(0.0));
    return vec4(mix(x * 12.92, 1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), x)), c.a);
}
vec4 vt_from_fade_space(vec4 c) {
    vec3 x = max(c.rgb, vec3(0.0));
    return vec4(mix(x / 12.92, pow((x + 0.055) / 1.055, vec3(2.4)), step(vec3(0.04045), x)), c.a);
}
#else
vec4 vt_fade_space(vec4 c) { return c; }
vec4 vt_from_fade_space(vec4 c) { return c; }
#endif

// The second level's weight in an anisotropic tap of entry e's cell whose filter blends with
// `fraction`: all of it when the page arrives, the filter's own blend once it has faded in.
float vt_faded_fraction(uint e, float fraction) { return 1.0 - vt_fade_weight(e) * (1.0 - fraction); }
#endif

// ---------------------------------------------------------------------------------------------
// The LoD rule (tessera/scene/lod.hpp). dx, dy: derivatives of the level-0 texel coordinate per
// pixel of the main colour target.
float vt_lod(vec2 dx, vec2 dy) {
    float rho_x = sqrt(dx.x * dx.x + dx.y * dx.y);
    float rho_y = sqrt(dy.x * dy.x + dy.y * dy.y);
    float major = max(rho_x, rho_y), minor = min(rho_x, rho_y);
#if VT_FILTER == VT_ANISOTROPIC
    return log2(max(minor, major / vt_max_anisotropy));
#else
    return log2(major);
#endif
}

// The level a pixel wants for `lod` (bias included): bilinear floor(lod + 0.5), trilinear and
// anisotropic floor(lod) (the finer of the two lookups), clamped to [0, levels - 1]; NaN and -inf
// give 0, +inf the last level.
int vt_wanted_level(float lod) {
    int last = int(vt_levels) - 1;
    if (isnan(lod)) return 0;
#if VT_FILTER == VT_BILINEAR
    float l = floor(lod + 0.5);
#else
    float l = floor(lod);
#endif
    if (!(l > 0.0)) return 0;
    if (l >= float(last)) return last;
    return int(l);
}

// lod clamped to [0, levels - 1] (NaN: 0): what trilinear blends with (GL's textureLod(lambda)).
float vt_clamped_lod(float lod) {
    if (isnan(lod)) return 0.0;
    return clamp(lod, 0.0, float(vt_levels - 1u));
}

// Anisotropic taps: `count` taps along `axis` (the major derivative, level-0 texels), tap i at
// offset ((i + 0.5) / count - 0.5) * axis; count = ceil(major / 2^lod) in [1, max_anisotropy],
// with lod the clamped, biased lod the taps are sampled at.
void vt_aniso_taps(vec2 dx, vec2 dy, float clamped_lod, out vec2 axis, out float count) {
    float rho_x = sqrt(dx.x * dx.x + dx.y * dx.y);
    float rho_y = sqrt(dy.x * dy.x + dy.y * dy.y);
    axis = rho_x >= rho_y ? dx : dy;
    float n = ceil(max(rho_x, rho_y) / exp2(clamped_lod));
    count = (isnan(n) || n < 1.0) ? 1.0 : min(n, vt_max_anisotropy);
}

vec2 vt_tap_offset(vec2 axis, float count, int i) { return ((float(i) + 0.5) / count - 0.5) * axis; }

// ---------------------------------------------------------------------------------------------
// Addressing. Every chunk carries the level-0 page its integer texel origin lies in (the chunk's
// page) and the origin's position in that page (base, an integer below P). A fragment's level-0
// position relative to that page's start is then q0 = base + local: one float add of numbers below
// P + chunk side. One division by P of that small number gives the fragment's level-0 page page0
// and its position in it, in0. At level L, with page0 = a * 2^L + b (b = page0 & (2^L - 1)), the
// level-L page is a and the position in it (b * P + in0) / 2^L, rounded to a float's 24 bits
// relative to b * P < 2^L * P, i.e. to 2^-15 of a level-L texel at P = 248 at any level. Only
// per-chunk flat inputs and compiled-in constants (no uniform and no array indexed per pixel: a
// software rasterizer gathers those lane by lane), signed integers and floats (its unsigned
// conversions are emulated, its integer division runs lane by lane): docs/renderer.md, "What a
// lookup costs".

// 2^-n, exactly, for -126 <= n <= 126 (built from the exponent bits: ldexp is lowered to far more).
float vt_exp2_neg(int n) { return intBitsToFloat((127 - n) << 23); }

struct VtPos {
    ivec2 page;     // level-L page
    vec2 in_page;   // position inside it, level-L texels in [0, P] (P only at a level's far edge)
};

// p at level L + d: the page is p.page >> d and the position in it
// ((p.page & (2^d - 1)) * P + p.in_page) / 2^d (nested floor divisions), with no second division.
VtPos vt_ancestor_position(VtPos p, int d) {
    VtPos a;
    a.page = p.page >> d;
    a.in_page = (vec2(p.page & ((1 << d) - 1)) * float(vt_payload) + p.in_page) * vt_exp2_neg(d);
    return a;
}

// The centres of level `level`'s edge texels, in that level's texels from the start of `page`: xy
// the first, zw the last (beyond any page but the first and the last). Lookups clamp to them, as
// GL_CLAMP_TO_EDGE does at every level, so no bilinear footprint reads the tile border outside
// the texture: it holds copies of the edge texels, which a block format encodes in blocks of their
// own and decodes differently from the edge. (Levels round up: ceil is the level's size.) Exact:
// integers below 2^24, and halves relative to the page.
vec4 vt_centre_bounds(ivec2 page, int level) {
    vec2 size = ceil(vt_texture_size * vt_exp2_neg(level));
    vec2 start = vec2(page) * float(vt_payload);
    // Relative to the page first: near 2^24 a half is not a float, a small offset is.
    precise vec2 to_end = size - start;
    return vec4(0.5 - start, to_end - 0.5);
}

// The centres of the next coarser level's edge texels, in level-`level` texels from the start of
// `page` (level L + 1 has ceil(size / 2) texels, so its last centre is 2 * that - 1 here: for an
// odd size, past the level's own last centre). Where a trilinear lookup of a block atlas reads
// its coarser level (vt_trilinear_texel). Never empty: a level of one texel gives 1 and 1.
vec4 vt_coarse_bounds(ivec2 page, int level) {
    vec2 size = ceil(vt_texture_size * vt_exp2_neg(level + 1));
    vec2 start = vec2(page) * float(vt_payload);
    precise vec2 to_end = 2.0 * size - start;
    return vec4(1.0 - start, to_end - 1.0);
}

// The level-L position of the fragment at `local` (level-0 texels from the chunk's origin),
// clamped to the texture's extent with the far bound 1/256 of a level-0 texel inside
// the edge. Worked out at level 0 first, which needs no level and so runs beside the LoD
// arithmetic: the page (one division by P, the float quotient one off at most at a page edge,
// which the range check of the remainder corrects; q - k * P is exact) and the position in it.
// Level L then follows without a second division, as an ancestor position: the page by a shift
// (always the level-L page over the clamped level-0 one, so never past the texture's last page),
// the position by one multiply-add. That sum may round up to exactly P at the far edge of a level
// (within 2^-16 of a level-L texel, as any position at level L): the footprint is then the edge
// texel and its copy in the tile border. (A GPU has time to spare for the LoD chain; a software
// rasterizer runs these instructions one after the other, and a shorter chain is cheaper.)
VtPos vt_level_position_in_texture(vec2 local, int level) {
    vec2 q0 = clamp(vt_chunk_base + local, vt_chunk_bounds.xy, vt_chunk_bounds.zw - 1.0 / 256.0);
    float payload = float(vt_payload);
    vec2 k = floor(q0 * vt_inv_payload);
    vec2 r = q0 - k * payload;
    vec2 fix = vec2(greaterThanEqual(r, vec2(payload))) - vec2(lessThan(r, vec2(0.0)));
    VtPos p0;
    p0.page = vt_chunk_page + ivec2(k + fix);
    p0.in_page = r - fix * payload;
    return vt_ancestor_position(p0, level);
}

// The same, clamped to the level's edge-texel centres (vt_centre_bounds): where a lookup reads.
VtPos vt_level_position(vec2 local, int level) {
    VtPos p = vt_level_position_in_texture(local, level);
    vec4 b = vt_centre_bounds(p.page, level);
    p.in_page = clamp(p.in_page, b.xy, b.zw);
    return p;
}

// The page-table entry of `page` at `level`.
uint vt_entry(ivec2 page, int level) {
#ifdef VT_SPARSE_TABLE
    uvec2 pg = uvec2(page);
    uint lv = uint(level);
    for (int step = 0; step < 7; ++step) {  // 7 * 5 > 32 levels; the coarse levels always hold a block
        uvec2 b = pg >> 5u;
        uint d = vt_directory[vt_dir_offset[lv] + b.y * vt_dir_width[lv] + b.x];
        if (d != 0u) return vt_blocks[(d - 1u) * 1024u + ((pg.y & 31u) << 5u) + (pg.x & 31u)];
        lv += 5u;
        pg = b;
        if (lv >= vt_levels) break;
    }
    return 0u;
#else
    int up = max(level - 1, 0);  // level 0 gives row U - U = 0
    ivec2 origin = ivec2(min(level, 1) * vt_table_column, up + vt_table_last_row - (vt_table_last_row >> up));
    return texelFetch(vt_page_table, origin + page, 0).r;
#endif
}

// Where entry e's page starts in the atlas: its cell plus the border, atlas texels.
vec2 vt_cell_origin(uint e) {
    return vec2(ivec2(int(e & 0xFFFu), int((e >> 12) & 0xFFFu))) * float(vt_tile_size) + float(vt_border);
}

// One lookup at level L: one page-table fetch (vt_lookup_at; vt_sample_entry takes an entry
// already fetched), one sample (bilinear, or trilinear from the atlas's two levels). A fallback
// entry points at the nearest resident ancestor R = L + d, whose position is
// vt_ancestor_position's. Straight-line code, no branches: a SIMD rasterizer runs both sides of a
// divergent branch. The entry names the page's atlas cell (column, row): no division to place
// it. resident: the level sampled, 32 when nothing is resident (the no-data colour).
// fraction: trilinear's weight of the next coarser level, which the atlas's second level holds for
// every resident page; a fallback samples its ancestor at its own level only (both trilinear levels
// would fall back to it). Ignored by the bilinear filter.
#if VT_FILTER != VT_BILINEAR
#ifdef VT_BLOCK_EDGES
// A trilinear lookup of a block atlas at `coord` (atlas texels), whose coarser level is read at
// `coarse` instead where the two differ: at the texture's edges, where the page's second-level
// border holds its own blocks of the edge texels (docs/renderer.md, "Page formats").
vec4 vt_trilinear_texel(sampler2D atlas, vec2 coord, vec2 coarse, float fraction) {
    if (fraction == 0.0 || coarse == coord) return textureLod(atlas, coord * vt_inv_atlas_size, fraction);
    return mix(textureLod(atlas, coord * vt_inv_atlas_size, 0.0), textureLod(atlas, coarse * vt_inv_atlas_size, 1.0), fraction);
}
#else
vec4 vt_trilinear_texel(sampler2D atlas, vec2 coord, vec2 coarse, float fraction) {
    return textureLod(atlas, coord * vt_inv_atlas_size, fraction);
}
#endif
#endif

// One lookup of entry e as described above; under VT_LAYERS also the other layers' texels.
vec4 vt_sample_entry_once(VtPos p, int level, uint e, float fraction) {
    int r = int((e >> 24) & 31u);
    vec2 in_page = vt_ancestor_position(p, max(r - level, 0)).in_page;
    vec2 cell = vt_cell_origin(e);
#if VT_FILTER != VT_BILINEAR
    // The coarser level read at its own edge-texel centres. (A fallback samples its ancestor's
    // level only, f = 0: `coarse` is then unused.)
    vec4 b = vt_coarse_bounds(p.page, level);
    vec2 coarse = cell + clamp(in_page, b.xy, b.zw);
    float f = r > level ? 0.0 : fraction;
#endif
#ifdef VT_ATLAS_RECT
    vec4 c = texture(vt_atlas, cell + in_page);
#elif VT_FILTER == VT_BILINEAR
    vec4 c = textureLod(vt_atlas, (cell + in_page) * vt_inv_atlas_size, 0.0);
#else
    vec4 c = vt_trilinear_texel(vt_atlas, cell + in_page, coarse, f);
#endif
    bool valid = (e >> 31) != 0u;
#ifdef VT_LAYERS
    for (int k = 0; k < VT_LAYERS; ++k) {
#if VT_FILTER == VT_BILINEAR
        vec4 t = textureLod(vt_layer_atlas[k], (cell + in_page) * vt_inv_atlas_size, 0.0);
#else
        vec4 t = vt_trilinear_texel(vt_layer_atlas[k], cell + in_page, coarse, f);
#endif
        vt_layer_texels[k] = valid ? t : vt_no_data_colour;
    }
#endif
    return valid ? c : vt_no_data_colour;
}

vec4 vt_sample_entry(VtPos p, int level, uint e, float fraction, out uint resident) {
    vec4 c = vt_sample_entry_once(p, level, e, fraction);
    bool valid = (e >> 31) != 0u;
    int r = int((e >> 24) & 31u);
#ifdef VT_FADE
    // Blending in: a cell below full weight w shows mix(before, now, w), `before` being what the
    // pixel drew until its page arrived: the nearest resident ancestor above the page, which the
    // entry one level up names, sampled as that fallback was (at its own level). An ancestor
    // still fading was itself drawn blended with the ancestor above it: `before` follows that
    // chain (up to VT_FADE_CHAIN ancestors; parent and child often arrive a frame or two apart).
    // The root page has nothing above it and shows at once.
    // Nothing resident above (the ancestor arrives later, or never was): at once, too.
    float w = vt_fade_weight(e);
    int up = max(r, level) + 1;
    if (valid && w < 1.0 && up < int(vt_levels)) {
        VtPos q = vt_ancestor_position(p, up - level);
        uint ea = vt_entry(q.page, up);
        if ((ea >> 31) != 0u) {
#ifdef VT_LAYERS
            vec4 layers_now[VT_LAYERS] = vt_layer_texels;
            vec4 layers_before[VT_LAYERS];
            for (int k = 0; k < VT_LAYERS; ++k) layers_before[k] = vec4(0.0);
#endif
            vec4 before = vec4(0.0);
            float rest = 1.0;  // the weight of the chain not yet accounted for
            for (int i = 0; i < VT_FADE_CHAIN; ++i) {
                vec4 s = vt_fade_space(vt_sample_entry_once(q, up, ea, 0.0));
#ifdef VT_LAYERS
                vec4 layers_s[VT_LAYERS] = vt_layer_texels;  // the other layers, blended with the same weights
#endif
                float wa = vt_fade_weight(ea);
                int ua = max(int((ea >> 24) & 31u), up) + 1;
                uint next = 0u;
                VtPos qn = q;
                if (wa < 1.0 && ua < int(vt_levels) && i + 1 < VT_FADE_CHAIN) {
                    qn = vt_ancestor_position(p, ua - level);
                    next = vt_entry(qn.page, ua);
                }
                if ((next >> 31) == 0u) {
                    before += rest * s;
#ifdef VT_LAYERS
                    for (int k = 0; k < VT_LAYERS; ++k) layers_before[k] += rest * layers_s[k];
#endif
                    break;
                }
                before += rest * wa * s;
#ifdef VT_LAYERS
                for (int k = 0; k < VT_LAYERS; ++k) layers_before[k] += rest * wa * layers_s[k];
#endif
                rest *= 1.0 - wa;
                q = qn;
                up = ua;
                ea = next;
            }
            c = vt_from_fade_space(mix(before, vt_fade_space(c), w));
#ifdef VT_LAYERS
            for (int k = 0; k < VT_LAYERS; ++k) vt_layer_texels[k] = mix(layers_before[k], layers_now[k], w);
#endif
        }
    }
#endif
    resident = valid ? uint(r) : 32u;
    return c;
}

vec4 vt_lookup_at(VtPos p, int level, float fraction, out uint resident) {
    return vt_sample_entry(p, level, vt_entry(p.page, level), fraction, resident);
}

vec4 vt_lookup(vec2 local, int level, out uint resident) {
    return vt_lookup_at(vt_level_position(local, level), level, 0.0, resident);
}

// Trilinear: levels floor(lod) and floor(lod) + 1 blended by the fraction of the clamped lod, in
// one lookup: the finer level's page and, in the atlas's second level, its 2x2 means, which are
// the coarser level's texels over it. resident: the level sampled. At the last level the fraction
// is 0.
vec4 vt_trilinear(vec2 local, float lod, out uint resident) {
    float lc = vt_clamped_lod(lod);
    int l0 = int(lc);
    return vt_lookup_at(vt_level_position(local, l0), l0, lc - float(l0), resident);
}

#if VT_FILTER == VT_ANISOTROPIC
// The entries of the 2x2 block of level-`level` pages from `corner`, in textureGather's order:
// (0, 1), (1, 1), (1, 0), (0, 0) from the corner. One gather (dense table) instead of four fetches:
// a software rasterizer pays a fetch's addressing per call. Entries past the level's edge are
// whatever the (edge-clamped) table holds there; the anisotropic taps never use them.
uvec4 vt_entries_2x2(ivec2 corner, int level) {
#ifdef VT_SPARSE_TABLE
    // The block may reach one page past the texture's edges (no tap reads there), where the
    // directory has no entries: read the edge page instead.
    ivec2 c0 = max(corner, ivec2(0));
    vec2 next_start = vec2(((corner + 1) << level) - vt_chunk_page) * float(vt_payload);  // level-0 texels
    ivec2 c1 = mix(c0, corner + 1, lessThan(next_start, vt_chunk_bounds.zw));
    return uvec4(vt_entry(ivec2(c0.x, c1.y), level), vt_entry(c1, level), vt_entry(ivec2(c1.x, c0.y), level),
                 vt_entry(c0, level));
#else
    int up = max(level - 1, 0);
    ivec2 origin = ivec2(min(level, 1) * vt_table_column, up + vt_table_last_row - (vt_table_last_row >> up));
    // The texel corner shared by the block's four entries: the gather footprint is exactly them.
    return textureGather(vt_page_table, vec2(origin + corner + 1) / vec2(textureSize(vt_page_table, 0)));
#endif
}

// Where a tap in one page of the block samples: atlas position (before normalising) =
// t * map.x + map.yz for t in level-L texels from the block's corner page, lod map.w; weight 0 for
// an empty entry (the no-data colour). The same as vt_sample_entry's, worked out once per entry
// instead of once per tap.
struct VtTapMap {
    vec4 map;
    float weight;
};

VtTapMap vt_tap_map(uint e, ivec2 corner, ivec2 offset, int level, float fraction) {
    int r = int((e >> 24) & 31u);
    int d = max(r - level, 0);
    float s = vt_exp2_neg(d);
    float payload = float(vt_payload);
    // vt_ancestor_position of page corner + offset with t - offset * P in it.
    vec2 base = (vec2((corner + offset) & ((1 << d) - 1)) - vec2(offset)) * (payload * s);
    VtTapMap m;
#ifdef VT_FADE
    // (A fallback's taps read its second level with the edge bounds of level `level`: only while
    // it fades in, and only at the texture's edges, where they differ.)
    // (The root has no second level to fade from: it shows at once.)
    float f = r > level ? 0.0 : fraction;
    m.map = vec4(s, vt_cell_origin(e) + base, r + 1 < int(vt_levels) ? vt_faded_fraction(e, f) : f);
#else
    m.map = vec4(s, vt_cell_origin(e) + base, r > level ? 0.0 : fraction);
#endif
    m.weight = (e >> 31) != 0u ? 1.0 : 0.0;
    return m;
}
#endif

// What vt_sample returns.
struct VtSample {
    vec4 colour;
    uint wanted;           // wanted level with the bias (what the feedback requests)
    uint wanted_unbiased;  // wanted level without the bias
    uint resident;         // resident level sampled for the wanted page (32: none)
#ifdef VT_LAYERS
    vec4 layers[VT_LAYERS];  // the other layers at the same place, filtered the same way
#endif
};

// Samples the virtual texture at origin + local with the configured filter. Call it in uniform
// control flow (it takes derivatives).
VtSample vt_sample(vec2 local) {
    vec2 dx = dFdx(local);
    vec2 dy = dFdy(local);
    float lod0 = vt_lod(dx, dy);
    float lod = lod0 + vt_bias;
    VtSample s;
    int wanted = vt_wanted_level(lod);
    s.wanted = uint(wanted);
    s.wanted_unbiased = uint(vt_wanted_level(lod0));
#if VT_FILTER == VT_BILINEAR
    s.colour = vt_lookup(local, wanted, s.resident);
#ifdef VT_LAYERS
    s.layers = vt_layer_texels;
#endif
#elif VT_FILTER == VT_TRILINEAR
    s.colour = vt_trilinear(local, lod, s.resident);
#ifdef VT_LAYERS
    s.layers = vt_layer_texels;
#endif
#else
    // Anisotropic: count trilinear taps along the major axis, at level l0 = floor(lod) with the
    // atlas's second level for the fraction. The taps lie within 8 level-l0 texels of the centre
    // (count <= 8 taps, under 2 texels apart; at the last level, where that may not hold, the
    // texture is one page), and a page is P >= 2 * max_anisotropy texels wide (the renderer
    // checks): so on each axis they can only cross the page edge nearest the centre. The 2x2
    // pages from `corner` (the centre's page, moved down on the axes where that edge is the lower
    // one) hold every tap; their entries are one gather, issued as soon as the centre is known, and
    // each tap samples with the entry of the page it lies in, falling back as a lookup does: no
    // seams, and one code path. (A SIMD rasterizer such as llvmpipe runs every path of a branch or
    // loop that any lane, or none, takes; at grazing angles one group of pixels spans tens of
    // texels, so some lane is near a page edge more often than not.) Taps are clamped to the
    // texture as vt_level_position clamps.
    float lc = vt_clamped_lod(lod);
    int l0 = int(lc);
    float payload = float(vt_payload);
    VtPos p = vt_level_position_in_texture(local, l0);  // the taps' centre: each tap is clamped
    ivec2 low = ivec2(lessThan(p.in_page, vec2(0.5 * payload)));
    ivec2 corner = p.page - low;
    uvec4 block = vt_entries_2x2(corner, l0);
    uint e = low.y != 0 ? (low.x != 0 ? block.y : block.x) : (low.x != 0 ? block.z : block.w);
    s.resident = (e >> 31) != 0u ? ((e >> 24) & 31u) : 32u;
    // Level-l0 texels from the start of the corner page from here on; the texture's extent there.
    vec2 axis;
    float count;
    vt_aniso_taps(dx, dy, lc, axis, count);
    float scale = vt_exp2_neg(l0);
    vec4 bounds = vt_centre_bounds(corner, l0);  // the edge texels' centres, from the corner page
    vec2 lo = bounds.xy, hi = bounds.zw;
    vec4 coarse_bounds = vt_coarse_bounds(corner, l0);  // the coarser level's, for block atlases
    vec2 step = axis * (scale / count);                                                // between taps
    vec2 first = p.in_page + vec2(low) * payload - step * (0.5 * (count - 1.0));  // tap 0
    float fraction = lc - float(l0);
    VtTapMap m00 = vt_tap_map(block.w, corner, ivec2(0, 0), l0, fraction);
    VtTapMap m10 = vt_tap_map(block.z, corner, ivec2(1, 0), l0, fraction);
    VtTapMap m01 = vt_tap_map(block.x, corner, ivec2(0, 1), l0, fraction);
    VtTapMap m11 = vt_tap_map(block.y, corner, ivec2(1, 1), l0, fraction);
    vec4 sum = vec4(0.0);
#ifdef VT_LAYERS
    vec4 layer_sums[VT_LAYERS];
    for (int k = 0; k < VT_LAYERS; ++k) layer_sums[k] = vec4(0.0);
#endif
    float valid = 0.0;
    for (int i = 0; i < int(count); ++i) {
        vec2 t = clamp(first + step * float(i), lo, hi);
        bvec2 up = greaterThanEqual(t, vec2(payload));
        vec4 a = up.y ? (up.x ? m11.map : m01.map) : (up.x ? m10.map : m00.map);
        float w = up.y ? (up.x ? m11.weight : m01.weight) : (up.x ? m10.weight : m00.weight);
        vec2 coarse = clamp(t, coarse_bounds.xy, coarse_bounds.zw) * a.x + a.yz;  // as vt_sample_entry
        sum += w * vt_trilinear_texel(vt_atlas, t * a.x + a.yz, coarse, a.w);
#ifdef VT_LAYERS
        for (int k = 0; k < VT_LAYERS; ++k) layer_sums[k] += w * vt_trilinear_texel(vt_layer_atlas[k], t * a.x + a.yz, coarse, a.w);
#endif
        valid += w;
    }
    sum += (count - valid) * vt_no_data_colour;
    s.colour = sum / count;
#ifdef VT_LAYERS
    for (int k = 0; k < VT_LAYERS; ++k) s.layers[k] = (layer_sums[k] + (count - valid) * vt_no_data_colour) / count;
#endif
#endif
    return s;
}

// The feedback id of the page `level` wants at origin + local: RG32UI, low word first
// (tessera/page_key.hpp: x 20 bits, y 20, level 5, texture 16).
uvec2 vt_feedback_id(vec2 local, int level) {
    uvec2 page = uvec2(vt_level_position(local, level).page);
    uint lo = (page.x & 0xFFFFFu) | ((page.y & 0xFFFu) << 20);
    uint hi = ((page.y >> 12) & 0xFFu) | ((uint(level) & 31u) << 8) | ((vt_texture_id & 0xFFFFu) << 13);
    return uvec2(lo, hi);
}

// The feedback of this fragment: the page of the wanted level (bias included). dx, dy: the
// derivatives per main-target pixel (feedback.frag measures them).
uvec2 vt_feedback(vec2 local, vec2 dx, vec2 dy) {
    return vt_feedback_id(local, vt_wanted_level(vt_lod(dx, dy) + vt_bias));
}
