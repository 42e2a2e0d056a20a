#version 330
// The inside of the mouth, drawn over the mouth triangles when the lips part: upper teeth under the upper lip, the tongue rising from the lower lip, a dark cavity
// between, darker toward the corners. Within about a pixel of the lips the interior fades
// into the portrait's own lip edge, so the opening has a smooth rim without multisampling.
uniform sampler2D u_texture;
uniform vec3 u_cavity;
uniform vec3 u_teeth;
uniform vec3 u_tongue;

in vec2 v_uv;
in vec3 v_mouth;   // across (0..1), below the upper lip (0 on it), above the lower lip (0 on it)
out vec4 f_color;

void main() {
    vec4 portrait = texture(u_texture, v_uv);
    float below_upper = v_mouth.y;
    float above_lower = v_mouth.z;
    float depth = below_upper / max(below_upper + above_lower, 1e-4);  // 0 upper lip .. 1 lower lip
    float across = abs(v_mouth.x * 2.0 - 1.0);                         // 0 middle .. 1 corners
    float teeth = (1.0 - smoothstep(0.20, 0.30, depth)) * (1.0 - smoothstep(0.55, 0.85, across));
    float tongue = smoothstep(0.62, 0.90, depth) * (1.0 - smoothstep(0.45, 0.80, across));
    vec3 color = u_cavity * (1.0 - 0.5 * across);
    color = mix(color, u_tongue, tongue);
    color = mix(color, u_teeth, teeth);
    // Distance to the nearer lip in pixels: each coordinate is linear and zero on its lip.
    float rim = min(below_upper / max(fwidth(below_upper), 1e-6), above_lower / max(fwidth(above_lower), 1e-6));
    float inside = clamp(rim, 0.0, 1.0);
    f_color = mix(portrait, vec4(color, 1.0), inside);
}
