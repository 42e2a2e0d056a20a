#version 330
// Layer 0: the portrait (a premultiplied-alpha texture). Layer 1: the inside of the mouth,
// painted from mouth-interior coordinates: upper teeth under the upper lip, the tongue
// rising from the lower lip, a dark cavity between, darker toward the corners.
uniform sampler2D u_texture;
uniform int u_layer;
uniform vec3 u_cavity;
uniform vec3 u_teeth;
uniform vec3 u_tongue;

in vec2 v_uv;
in vec2 v_mouth;
out vec4 f_color;

void main() {
    if (u_layer == 0) {
        f_color = texture(u_texture, v_uv);
        return;
    }
    float across = abs(v_mouth.x * 2.0 - 1.0);          // 0 at the middle, 1 at the corners
    float teeth = (1.0 - smoothstep(0.20, 0.30, v_mouth.y)) * (1.0 - smoothstep(0.55, 0.85, across));
    float tongue = smoothstep(0.62, 0.90, v_mouth.y) * (1.0 - smoothstep(0.45, 0.80, across));
    vec3 color = u_cavity * (1.0 - 0.5 * across);
    color = mix(color, u_tongue, tongue);
    color = mix(color, u_teeth, teeth);
    f_color = vec4(color, 1.0);
}
