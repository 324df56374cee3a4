// scene.vert: every pass (depth pre-pass, VT, feedback, reference) draws the scene with this
// vertex shader, so their depths agree exactly (invariant gl_Position): the VT pass tests
// GL_LEQUAL against the pre-pass depth and shades each visible pixel once.
//
// Rendering is camera-relative: u_chunk_offset = float(chunk.origin - camera.position), computed
// in double on the CPU; u_view_projection holds the rotation and projection only.
layout(location = 0) in vec3 a_position;  // world units, relative to the chunk origin
layout(location = 1) in vec2 a_texel;     // level-0 texels, relative to the chunk's texel origin

uniform mat4 u_view_projection;
uniform vec3 u_chunk_offset;

out vec2 v_local;
out float v_w;  // clip w (eye depth): the feedback pass's exact derivatives need it
invariant gl_Position;

void main() {
    v_local = a_texel;
    gl_Position = u_view_projection * vec4(a_position + u_chunk_offset, 1.0);
    v_w = gl_Position.w;
}
