// Light vertices seen through exact shadow maps (gpu_impl/visibility/exact.py): each vertex's cube
// of six views in the shadow atlas, rasterized from the triangles, looked up as a point light's
// are (lights.glsl: shadow_view_of, shadow_visibility).

float light_vertex_visibility(Light light, vec3 p, vec3 n, vec3 to_light) {
    return shadow_visibility(shadow_view_of(light, p), p, n, to_light);
}
