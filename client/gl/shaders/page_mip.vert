// page_mip.vert: one quad per atlas cell whose second level is to be made (page_mips.cpp), drawn
// into the atlas's second level; no attributes: the cells come from a storage buffer.
struct PageMipCell {
    ivec4 cell_origin;  // xy: atlas cell (column, row); zw: level-L texel of the cell's texel (0, 0)
    ivec4 level_size;   // xy: level L's size in texels
};
layout(std430, binding = 3) readonly buffer PageMipCells { PageMipCell pm_cells[]; };
uniform vec2 pm_cell_ndc;  // one cell in normalised device coordinates: 2 / (columns, rows)

flat out ivec2 v_cell;
flat out ivec2 v_origin;
flat out ivec2 v_size;

void main() {
    PageMipCell c = pm_cells[gl_InstanceID];
    v_cell = c.cell_origin.xy;
    v_origin = c.cell_origin.zw;
    v_size = c.level_size.xy;
    vec2 corner = vec2(gl_VertexID & 1, gl_VertexID >> 1);
    gl_Position = vec4((vec2(v_cell) + corner) * pm_cell_ndc - 1.0, 0.0, 1.0);
}
