// Primary visibility: the camera view rasterized at the supersampled resolution, storing the
// visible triangle per sample (primitive id + 1; 0 where no surface is seen). Position, normal,
// uv and albedo are not interpolated here: eye_paths.glsl (PRIMARY) intersects each sample's
// camera ray with its triangle, exact to float32, as the bundle passes do for their lines.

#if defined VERTEX_SHADER

layout(location = 0) in vec3 in_position;  // relative to the bundle centre
uniform mat4 to_clip;                      // camera projection with this frame's sub-pixel jitter

void main() {
    gl_Position = to_clip * vec4(in_position, 1.0);
}

#elif defined FRAGMENT_SHADER

layout(location = 0) out uint out_prim;

void main() {
    out_prim = uint(gl_PrimitiveID) + 1u;
}

#endif
