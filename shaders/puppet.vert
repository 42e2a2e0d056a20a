#version 330
// Places each mesh vertex from its rest position plus this frame's displacement.
// Texture coordinates come from the rest position only, so the portrait's pixels ride
// along with their triangles.
uniform vec2 u_image_size;   // portrait size, pixels
uniform vec2 u_target_size;  // framebuffer size, pixels
uniform vec2 u_scale;        // portrait pixels -> framebuffer pixels
uniform vec2 u_shift;        // framebuffer pixels, added after scaling

in vec2 in_rest;       // rest position, portrait pixels (origin top-left, y down)
in vec2 in_offset;     // displacement this frame, portrait pixels
in vec3 in_mouth;      // mouth-interior coordinates (see puppet/rig.py MOUTH_COORDS)

out vec2 v_uv;
out vec3 v_mouth;      // used by mouth.frag only

void main() {
    vec2 pixel = (in_rest + in_offset) * u_scale + u_shift;
    vec2 ndc = pixel / u_target_size * 2.0 - 1.0;
    gl_Position = vec4(ndc.x, -ndc.y, 0.0, 1.0);
    v_uv = in_rest / u_image_size;
    v_mouth = in_mouth;
}
