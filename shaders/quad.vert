#version 330
// The benchmark's floor: one textured quad over the whole target.
in vec2 in_corner;  // -1..1
out vec2 v_uv;

void main() {
    gl_Position = vec4(in_corner, 0.0, 1.0);
    v_uv = vec2(in_corner.x, -in_corner.y) * 0.5 + 0.5;
}
