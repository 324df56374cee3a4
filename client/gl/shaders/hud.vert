// hud.vert: the HUD panel, one quad (a triangle strip of 4 vertices, no attributes).
uniform vec4 u_rect;  // x0, y0, x1, y1 in normalised device coordinates

void main() {
    vec2 corner = vec2(gl_VertexID & 1, gl_VertexID >> 1);
    gl_Position = vec4(mix(u_rect.xy, u_rect.zw, corner), 0.0, 1.0);
}
