// Imperfect shadow maps (Ritschel et al. 2008): every light vertex of the frame gets one small
// paraboloid map of its front hemisphere (paraboloid.glsl) in its tile of the shadow atlas, drawn
// in one pass from its own few surface points: point m P + j belongs to vertex m, drawn in
// proportion to area with its own seed (area_sampling.glsl), so each vertex sees a different
// sparse sample of the scene and their errors do not repeat from vertex to vertex. Each point is
// a disk splat (a round point sprite) sized to the radius its share of the surface would have,
// storing its distance from the vertex; the depth test keeps the nearest. Lookups:
// light_visibility_imperfect.glsl.

#define SHADOW_MAP_RASTER
#define SHADOW_LIGHTS 1
#include "common.glsl"
#include "scene.glsl"
#include "lights.glsl"
#include "area_sampling.glsl"
#include "paraboloid.glsl"

uniform int first_vertex_light;  // the record of light vertex 0
uniform uint points_per_map;     // P
uniform uint seed;
uniform uint frame;
uniform float splat_radius;      // in scene units
uniform vec2 atlas_size;         // in texels

#if defined VERTEX_SHADER

flat out vec4 v_tile;      // the tile's texels: first x, y, then one past the last
flat out float v_distance;

void main() {
    uint id = uint(gl_VertexID), m = id / points_per_map, j = id % points_per_map;
    ShadowView view = shadow_views[int(lights[first_vertex_light + int(m)].shape.z)];
    uvec4 r = pcg4d(uvec4(j, m, seed, frame));
    uint triangle = area_cdf[curve_position(unit_float(r.x))].y;
    float sq = sqrt(unit_float(r.y)), w = unit_float(r.z);  // uniform on the triangle
    uvec3 v = triangle_vertices(triangle);
    vec3 p0 = vertex_position(v.x);
    vec3 p = p0 + sq * (1.0 - w) * (vertex_position(v.y) - p0) + sq * w * (vertex_position(v.z) - p0);
    vec3 d = p - view.origin.xyz;
    float dist = length(d);
    vec3 local = paraboloid_local(view.axis.xyz, d / max(dist, 1e-30));
    v_tile = vec4(view.tile.xy, view.tile.xy + view.tile.z);
    v_distance = dist;
    gl_PointSize = 1.0;
    // Points behind the vertex are never looked up. Nor are those within a splat radius of its
    // tangent plane: its own surface's splats, which stand up to a radius off the surface where
    // the map sees them edge-on, and would shadow every direction near its horizon.
    if (local.z * dist <= splat_radius) {
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // outside the clip volume
        return;
    }
    vec2 texel = view.tile.xy + (paraboloid_position(local) * 0.5 + 0.5) * view.tile.z;
    gl_Position = vec4(texel / atlas_size * 2.0 - 1.0, clamp(dist * view.axis.w, 0.0, 1.0) * 2.0 - 1.0, 1.0);
    // A disk of radius r at distance dist spans 2 r / (dist (1 + cos theta)) of the map's [-1, 1].
    gl_PointSize = clamp(splat_radius * view.tile.z / (dist * (1.0 + local.z)), 1.0, 64.0);
}

#elif defined FRAGMENT_SHADER

flat in vec4 v_tile;
flat in float v_distance;
layout(location = 0) out float out_distance;

void main() {
    // A splat near its tile's edge must not spill into the neighbouring vertex's map.
    if (any(lessThan(gl_FragCoord.xy, v_tile.xy)) || any(greaterThanEqual(gl_FragCoord.xy, v_tile.zw))) discard;
    vec2 c = gl_PointCoord - 0.5;
    if (dot(c, c) > 0.25) discard;  // round splats
    out_distance = v_distance;
}

#endif
