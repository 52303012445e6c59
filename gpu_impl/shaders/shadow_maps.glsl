// Shadow maps: the scene drawn once per shadow view into its tile of the atlas (the viewport),
// storing the distance from the light to the nearest surface. The depth test keeps the nearest;
// the stored distance is linear (radial or along the light), so the lookup in lights.glsl compares
// distances in scene units and its bias is in scene units too. The depth test runs on the same
// linear distance (gl_FragDepth), not on the projection's hyperbolic depth, which a point light's
// tiny near plane would leave with too little precision to order nearby surfaces far away.

#define SHADOW_MAP_RASTER
#define SHADOW_LIGHTS 1
#include "lights.glsl"

uniform int view_index;

#if defined VERTEX_SHADER

layout(location = 0) in vec3 in_position;  // relative to the bundle centre
out vec3 v_position;

void main() {
    v_position = in_position;
    gl_Position = shadow_views[view_index].to_clip * vec4(in_position, 1.0);
}

#elif defined FRAGMENT_SHADER

in vec3 v_position;
layout(location = 0) out float out_distance;
// The triangle seen + 1, where the atlas has a second attachment for it: the fixed lights' maps read
// as reflective shadow maps, where light paths start (light_paths.glsl).
layout(location = 1) out uint out_triangle;

void main() {
    ShadowView view = shadow_views[view_index];
    // An emitter sample's views (axis: its emitter's normal) keep only what lies in front of the
    // emitter: its own surface, seen almost edge-on from just in front of it, would fill the texels
    // at its horizon with tiny distances and shadow the light that leaves it at grazing angles.
    if (view.origin.w > 0.5 && any(notEqual(view.axis.xyz, vec3(0.0))) && dot(v_position - view.origin.xyz, view.axis.xyz) <= 0.0) discard;
    out_distance = light_distance(view, v_position);
    gl_FragDepth = clamp(out_distance * view.axis.w, 0.0, 1.0);
    out_triangle = uint(gl_PrimitiveID) + 1u;
}

#endif
