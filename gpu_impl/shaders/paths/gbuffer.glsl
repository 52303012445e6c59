// Primary visibility: the camera view rasterized at the supersampled resolution, storing the
// visible triangle per sample (its index + 1; 0 where no surface is seen). Position, normal, uv and
// albedo are not interpolated here: primary.glsl intersects each sample's camera ray with its
// triangle, exact to float32, as the bundle passes do for their lines.

#if defined VERTEX_SHADER

layout(location = 0) in vec3 in_position;  // relative to the bundle centre
layout(location = 1) in uint in_triangle;  // on the triangle's provoking vertex (scene_buffers.py)
uniform mat4 to_clip;                      // camera projection with this frame's sub-pixel jitter
flat out uint v_triangle;

void main() {
    v_triangle = in_triangle;
    gl_Position = to_clip * vec4(in_position, 1.0);
}

#elif defined FRAGMENT_SHADER

flat in uint v_triangle;
layout(location = 0) out uint out_prim;

void main() {
    out_prim = v_triangle + 1u;
}

#endif
