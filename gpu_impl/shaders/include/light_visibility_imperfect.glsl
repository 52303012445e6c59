// Light vertices seen through imperfect shadow maps (gpu_impl/visibility/imperfect.py): each
// vertex's one paraboloid map of its front hemisphere, splatted from its own few points
// (imperfect_shadow_maps.glsl), looked up with the point lights' filtering and slope-scaled bias.
// (Moving the receiver off its surface by a texel and a splat radius instead, with a constant
// bias, changed 22.4 % of atrium's and 5.9 % of lit-room's connections against 22.0 % and 5.4 %
// here: benchmarks/shadow_maps.py.)

#include "paraboloid.glsl"

float light_vertex_visibility(Light light, vec3 p, vec3 n, vec3 to_light) {
    ShadowView view = shadow_views[int(light.shape.z)];
    vec3 v = p - view.origin.xyz;
    float dist = length(v);
    vec3 local = paraboloid_local(view.axis.xyz, v / dist);
    if (local.z <= 0.0) return 0.0;  // behind the vertex: it sends no light there
    // One texel spans 2 (1 + cos theta) / size radians at angle theta (tile.w = 2 / size).
    float texel = view.tile.w * (1.0 + local.z) * dist;
    return filtered_visibility(view, paraboloid_position(local), dist, texel * depth_bias_texels(surface_slope(n, to_light)), 0.0);
}
