// scene.vert: every pass (depth pre-pass, VT, feedback, reference) draws the scene with this
// vertex shader, so their depths agree exactly (invariant gl_Position): the VT pass tests
// GL_LEQUAL against the pre-pass depth and shades each visible pixel once.
//
// Rendering is camera-relative: u_chunk_offset = float(chunk.origin - camera.position), computed
// in double on the CPU; u_view_projection holds the rotation and projection only.
//
// It also forwards, as flat varyings, what the fragment shaders read per draw, per texture and
// per frame (vt_sample.glsl, "Inputs"): a uniform read in a fragment shader costs a software
// rasterizer a lane-by-lane load each time, a flat input one load per block of pixels. Outputs a
// program's fragment shader does not read are dropped at link time, with their uniforms.
layout(location = 0) in vec3 a_position;  // world units, relative to the chunk origin
layout(location = 1) in vec2 a_texel;     // level-0 texels, relative to the chunk's texel origin
layout(location = 2) in vec3 a_normal;    // world frame; (0, 0, 0) where the scene has none

uniform mat4 u_view_projection;
uniform vec3 u_chunk_offset;
// Per draw: the chunk's page frame (VT passes) or its texel origin (the reference renderer).
uniform ivec2 u_chunk_page;
uniform vec2 u_chunk_base;
uniform vec4 u_chunk_bounds;
uniform uvec2 u_texel_origin;
// The chunk's texel origin minus the frame's (a whole number): the frame of a terrain chunk
// follows the camera, so v_local is small where texels are large on screen (scene_draw.cpp).
uniform vec2 u_texel_shift;
uniform int u_blend;  // 1: a blended chunk (SceneGeometry::Chunks)
// Per texture and per frame.
uniform uint u_levels;
uniform vec2 u_texture_size;
uniform int u_table_column;
uniform int u_table_last_row;
uniform float u_bias;

out vec2 v_local;  // level-0 texels from the texel frame's origin
out float v_w;  // clip w (eye depth): the feedback pass's exact derivatives need it
out vec3 v_normal;  // material.glsl's lighting
out vec3 v_eye;     // position relative to the camera (world units): material.glsl's view vector
flat out ivec2 vt_chunk_page;
flat out vec2 vt_chunk_base;
flat out vec4 vt_chunk_bounds;
flat out uvec2 vt_texel_origin;
flat out int vt_blend;
flat out uint vt_levels;
flat out vec2 vt_texture_size;
flat out int vt_table_column;
flat out int vt_table_last_row;
flat out float vt_bias;
invariant gl_Position;

void main() {
    v_local = a_texel + u_texel_shift;
    vt_chunk_page = u_chunk_page;
    vt_chunk_base = u_chunk_base;
    vt_chunk_bounds = u_chunk_bounds;
    vt_texel_origin = u_texel_origin;
    vt_blend = u_blend;
    vt_levels = u_levels;
    vt_texture_size = u_texture_size;
    vt_table_column = u_table_column;
    vt_table_last_row = u_table_last_row;
    vt_bias = u_bias;
    v_eye = a_position + u_chunk_offset;
    v_normal = a_normal;
    gl_Position = u_view_projection * vec4(v_eye, 1.0);
    v_w = gl_Position.w;
}
