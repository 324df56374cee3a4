// vt_sample.glsl: the virtual-texture sampling function, the one include every VT shader uses
// (design.md, "One frame, end to end", steps 1 and 2; docs/renderer.md).
//
// The including shader is assembled by the renderer as
//     #version 450 core
//     #define VT_FILTER <VT_BILINEAR | VT_TRILINEAR | VT_ANISOTROPIC>
//     [#define VT_SPARSE_TABLE 1]   (vt.frag for two-level page tables: see vt_entry)
//     <this file> <the shader>
//
// Conventions
// - Texel coordinates: the level-0 texel coordinate of a fragment is `origin + local`, where
//   `origin` is the chunk's integer texel origin (a uniform) and `local` a small interpolated float
//   offset. Never one float UV over the whole virtual texture.
// - Level L has ceil(size / 2^L) texels per side; the continuous level-L coordinate of level-0
//   coordinate t is t / 2^L (texel i of level L covers [i, i + 1), centre i + 0.5), as GL mips.
// - The LoD rule is tessera/scene/lod.hpp, line for line (vt_lod, vt_wanted_level).
// - Page-table entry (tessera/client/page_table.hpp): bit 31 valid, bits 24..28 resident level R,
//   bits 0..23 slot; R > L: fallback to the ancestor at level R. 0: nothing resident.
// - The physical atlas is a grid of tile_size squares, vt_atlas_columns per row; a page's texel
//   (i, j) (border included, rows top to bottom) is atlas texel (col * ts + i, row * ts + j).

#define VT_BILINEAR 0
#define VT_TRILINEAR 1
#define VT_ANISOTROPIC 2
#ifndef VT_FILTER
#error "VT_FILTER must be defined"
#endif

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
uniform sampler2D vt_atlas;         // the physical pages (RGBA8 or SRGB8_ALPHA8), GL_LINEAR
uniform ivec2 vt_table_origin[32];  // where level L's entries start in vt_page_table
uniform uvec2 vt_level_size[32];    // texels of level L: ceil(size / 2^L)
uniform uint vt_levels;             // levels of the virtual texture (the last one is one page)
uniform uint vt_payload;            // P: texels a page covers per side
uniform float vt_inv_payload;       // 1.0 / P
uniform float vt_inv_atlas_columns; // 1.0 / vt_atlas_columns
uniform uint vt_border;             // B: border texels on each side of a page
uniform uint vt_tile_size;          // P + 2B: atlas cell size
uniform uint vt_atlas_columns;      // atlas cells per row
uniform vec2 vt_atlas_texel;        // 1 / atlas size (texels)
uniform uint vt_texture_id;         // for the feedback id
uniform float vt_max_anisotropy;    // 1..8 (anisotropic filter)
uniform float vt_bias;              // LoD bias (0 in the reference renderer)
uniform vec4 vt_no_data_colour;     // entry 0: nothing resident on the path

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
uint vt_wanted_level(float lod) {
    uint last = vt_levels - 1u;
    if (isnan(lod)) return 0u;
#if VT_FILTER == VT_BILINEAR
    float l = floor(lod + 0.5);
#else
    float l = floor(lod);
#endif
    if (!(l > 0.0)) return 0u;
    if (l >= float(last)) return last;
    return uint(l);
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
// Exact integer page math.
// floor(n / d), exact for n < 2^31, 1 <= d < 2^16 and a quotient below 2^22: the float estimate is
// then within 3 * 2^-24 * (n / d) < 1 of the true quotient, so one correction each way fixes it.
// Callers stay far inside that: pages per side are at most 2^20 (the feedback-id limit), atlas rows
// at most 2^20. Integer division by a uniform has no SIMD instruction: software rasterizers
// (llvmpipe) run it lane by lane, which made it the most expensive part of a lookup.
uvec2 vt_div(uvec2 n, uint d, float inv_d) {
    uvec2 q = uvec2(vec2(n) * inv_d);
    q -= uvec2(greaterThan(q * d, n));
    q += uvec2(lessThanEqual((q + 1u) * d, n));
    return q;
}

ivec2 vt_page_of(ivec2 texel) { return ivec2(vt_div(uvec2(texel), vt_payload, vt_inv_payload)); }

struct VtPos {
    ivec2 texel;  // integer level-L texel
    vec2 frac;    // position inside it, [0, 1]
    ivec2 page;   // the page holding texel (set by vt_clamp)
};

// The level-L position of level-0 coordinate origin + local. The integer part is formed in
// integers: (origin >> L) + floor(((origin & (2^L - 1)) + local) / 2^L); only that small
// remainder is a float, so the result is exact to float precision of a few texels wherever the
// texel lies in a 2^31-texel texture.
VtPos vt_level_position(uvec2 origin, vec2 local, uint level) {
    uvec2 low = origin & uvec2((1u << level) - 1u);
    vec2 q = ldexp(vec2(low) + local, ivec2(-int(level)));  // exact: a power-of-two scale
    vec2 k = floor(q);
    VtPos p;
    p.texel = ivec2(origin >> level) + ivec2(k);
    p.frac = q - k;
    return p;
}

// Clamped to the level's texels [0, size]: outside positions sample the edge (GL_CLAMP_TO_EDGE;
// the tiles' borders are edge-clamped as well).
VtPos vt_clamp(VtPos p, uint level) {
    ivec2 size = ivec2(vt_level_size[level]);
    bvec2 below = lessThan(p.texel, ivec2(0));
    bvec2 above = greaterThanEqual(p.texel, size);
    p.frac = mix(mix(p.frac, vec2(0.0), below), vec2(1.0), above);
    p.texel = clamp(p.texel, ivec2(0), size - 1);
    p.page = vt_page_of(p.texel);
    return p;
}

uint vt_entry(VtPos p, uint level) {
#ifdef VT_SPARSE_TABLE
    uvec2 page = uvec2(p.page);
    for (int step = 0; step < 7; ++step) {  // 7 * 5 > 32 levels; the coarse levels always hold a block
        uvec2 b = page >> 5u;
        uint d = vt_directory[vt_dir_offset[level] + b.y * vt_dir_width[level] + b.x];
        if (d != 0u) return vt_blocks[(d - 1u) * 1024u + ((page.y & 31u) << 5u) + (page.x & 31u)];
        level += 5u;
        page = b;
        if (level >= vt_levels) break;
    }
    return 0u;
#else
    return texelFetch(vt_page_table, vt_table_origin[level] + p.page, 0).r;
#endif
}

// Normalised atlas coordinate of position p (level R) in the page at `slot`: slot origin + border
// + position inside the page; the border makes bilinear footprints at page edges correct.
vec2 vt_physical(VtPos p, uint slot) {
    vec2 in_page = vec2(p.texel - p.page * int(vt_payload)) + p.frac;
    uint row = vt_div(uvec2(slot), vt_atlas_columns, vt_inv_atlas_columns).x;
    uvec2 cell = uvec2(slot - row * vt_atlas_columns, row);
    return (vec2(cell * vt_tile_size + uvec2(vt_border)) + in_page) * vt_atlas_texel;
}

// One bilinear lookup at level L: one page-table fetch (a fallback entry already points at the
// nearest resident ancestor: then the position is recomputed at its level), one bilinear sample.
// resident: the level sampled, 32 when nothing is resident (the no-data colour).
vec4 vt_lookup(uvec2 origin, vec2 local, uint level, out uint resident) {
    VtPos p = vt_clamp(vt_level_position(origin, local, level), level);
    uint e = vt_entry(p, level);
    if ((e >> 31) == 0u) {
        resident = 32u;
        return vt_no_data_colour;
    }
    resident = (e >> 24) & 31u;
    if (resident != level) p = vt_clamp(vt_level_position(origin, local, resident), resident);
    return textureLod(vt_atlas, vt_physical(p, e & 0xFFFFFFu), 0.0);
}

// The resident level the lookup of (origin + local) at `level` would sample (32: none).
uint vt_resident_level(uvec2 origin, vec2 local, uint level) {
    uint e = vt_entry(vt_clamp(vt_level_position(origin, local, level), level), level);
    return (e >> 31) == 0u ? 32u : ((e >> 24) & 31u);
}

// Trilinear: levels floor(lod) and floor(lod) + 1 (each its own page-table fetch), blended by the
// fraction of the clamped lod. resident: of the finer lookup.
vec4 vt_trilinear(uvec2 origin, vec2 local, float lod, out uint resident) {
    float lc = vt_clamped_lod(lod);
    uint l0 = uint(floor(lc));
    vec4 c0 = vt_lookup(origin, local, l0, resident);
    float w = lc - float(l0);
    if (w <= 0.0 || l0 + 1u >= vt_levels) return c0;
    uint r1;
    vec4 c1 = vt_lookup(origin, local, l0 + 1u, r1);
    return mix(c0, c1, w);
}

// What vt_sample returns.
struct VtSample {
    vec4 colour;
    uint wanted;           // wanted level with the bias (what the feedback requests)
    uint wanted_unbiased;  // wanted level without the bias
    uint resident;         // resident level sampled for the wanted page (32: none)
};

// Samples the virtual texture at origin + local with the configured filter. Call it in uniform
// control flow (it takes derivatives).
VtSample vt_sample(uvec2 origin, vec2 local) {
    vec2 dx = dFdx(local);
    vec2 dy = dFdy(local);
    float lod0 = vt_lod(dx, dy);
    float lod = lod0 + vt_bias;
    VtSample s;
    s.wanted = vt_wanted_level(lod);
    s.wanted_unbiased = vt_wanted_level(lod0);
#if VT_FILTER == VT_BILINEAR
    s.colour = vt_lookup(origin, local, s.wanted, s.resident);
#elif VT_FILTER == VT_TRILINEAR
    s.colour = vt_trilinear(origin, local, lod, s.resident);
#else
    // Anisotropic: every tap is a trilinear VT lookup with its own page-table fetches, so taps
    // that cross a page edge read the neighbouring page: no clamping, no seams.
    vec2 axis;
    float count;
    vt_aniso_taps(dx, dy, vt_clamped_lod(lod), axis, count);
    vec4 sum = vec4(0.0);
    for (int i = 0; i < int(count); ++i) {
        uint r;
        sum += vt_trilinear(origin, local + vt_tap_offset(axis, count, i), lod, r);
    }
    s.colour = sum / count;
    s.resident = vt_resident_level(origin, local, s.wanted);
#endif
    return s;
}

// The feedback id of the page `level` wants at origin + local: RG32UI, low word first
// (tessera/client/page.hpp: x 20 bits, y 20, level 5, texture 16).
uvec2 vt_feedback_id(uvec2 origin, vec2 local, uint level) {
    VtPos p = vt_clamp(vt_level_position(origin, local, level), level);
    uvec2 page = uvec2(p.page);
    uint lo = (page.x & 0xFFFFFu) | ((page.y & 0xFFFu) << 20);
    uint hi = ((page.y >> 12) & 0xFFu) | ((level & 31u) << 8) | ((vt_texture_id & 0xFFFFu) << 13);
    return uvec2(lo, hi);
}

// The feedback of this fragment: the page of the wanted level (bias included). dx, dy: the
// derivatives per main-target pixel (feedback.frag measures them).
uvec2 vt_feedback(uvec2 origin, vec2 local, vec2 dx, vec2 dy) {
    return vt_feedback_id(origin, local, vt_wanted_level(vt_lod(dx, dy) + vt_bias));
}
