#version 330
// A screen-aligned rectangle given in target fractions from the top-left corner.
uniform vec4 u_rect;  // x, y, width, height: 0..1 of the target, y down
in vec2 in_corner;    // 0..1
out vec2 v_uv;

void main() {
    vec2 position = u_rect.xy + in_corner * u_rect.zw;
    gl_Position = vec4(position.x * 2.0 - 1.0, 1.0 - position.y * 2.0, 0.0, 1.0);
    v_uv = in_corner;
}
