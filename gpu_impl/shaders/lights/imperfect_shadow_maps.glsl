// Imperfect shadow maps (Ritschel et al. 2008): every light vertex of the frame gets one small
// paraboloid map of its front hemisphere (paraboloid.glsl) in its tile of the shadow atlas, drawn
// in one pass from its own few surface points: point m P + j belongs to vertex m, drawn in
// proportion to area and stratified, with its own seed and shift (area_sampling.glsl:
// stratified_point, as the imperfect bundles' points are), so each vertex sees a different
// sparse sample of the scene and their errors do not repeat from vertex to vertex. Each point is
// a disk in its triangle's tangent plane, of the radius its share of the surface would have, as
// the imperfect bundles' splats are: a point sprite covers the disk's widest extent, and each
// fragment meets the disk's plane along its own direction, is cut out beyond the radius and beyond
// the lines that cut it (scene.glsl: SplatShape; the disk grown where they cut it, as the
// bundles' splats are), and stores that distance from the vertex; the depth test keeps the
// nearest. A disk facing the vertex instead would stand a radius off its surface wherever the map
// sees it at a grazing angle (a floor between the vertex and a receiver): atrium, 64 light
// vertices, 1024 receivers, 4096 points a map: 11.1 % of connections hidden that exact maps see,
// 6.8 % with tangent-plane disks (docs/results/decisions.toml: imperfect-shadow-maps).
// Lookups: light_visibility_imperfect.glsl.

#define SHADOW_MAP_RASTER
#define SHADOW_LIGHTS 1
#define SPLAT_SHAPES
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
uniform vec2 atlas_size;         // a page's, in texels

#if defined VERTEX_SHADER

flat out vec4 v_tile;      // the tile's texels: first x, y, then one past the last
flat out vec3 v_centre;    // the disk's centre relative to the vertex
flat out vec3 v_normal;    // its plane's normal
flat out vec3 v_axis;      // the map's axis (the vertex's normal)
flat out float v_far;      // 1 / the map's farthest distance
flat out uint v_cut;       // the splat's shape (scene.glsl: SplatShape), member by member
flat out mat3 v_lines_a, v_lines_b;
flat out vec3 v_slack_a, v_slack_b;
flat out float v_radius;   // the disk's radius, grown where lines cut it (scene.glsl: sharp_splat_radius)
flat out vec2 v_b;         // the point's barycentrics
flat out mat2x3 v_dual;    // an offset in the plane dotted with these: its barycentrics' change
                           // (scene.glsl's plane_barycentrics solved once per point, not per fragment)

void main() {
    uint id = uint(gl_VertexID), m = id / points_per_map, j = id % points_per_map;
    ShadowView view = shadow_views[int(lights[first_vertex_light + int(m)].shape.z)];
    uvec4 r = pcg4d(uvec4(j, m, seed, frame));
    float shift = unit_float(pcg4d(uvec4(0xFFFFFFFFu, m, seed, frame)).x);
    float u = fract((float(j) + unit_float(r.x)) / float(points_per_map) + shift);
    uint triangle;
    vec2 b = stratified_point(u, vec2(unit_float(r.y), unit_float(r.z)), triangle);
    vec3 p0, p1, p2;
    triangle_corners(triangle, p0, p1, p2);
    vec3 e1 = p1 - p0, e2 = p2 - p0;
    vec3 p = p0 + b.x * e1 + b.y * e2;
    vec3 d = p - view.origin.xyz;
    float dist = length(d);
    vec3 local = paraboloid_local(view.axis.xyz, d / max(dist, 1e-30));
    vec2 corner = vec2(atlas_texel(ivec2(view.tile.xy), int(atlas_size.y)).xy);  // in its page
    v_tile = vec4(corner, corner + view.tile.z);
    v_centre = d;
    v_normal = normalize(cross(e1, e2));
    SplatShape shape = splat_shape(triangle, triangle_cut_lines(triangle));
    v_radius = sharp_splat_radius(splat_radius, shape, b);
    // The shape of the splat of that radius: the lines within it. Handed on to every fragment; a
    // map's few points have disks wider than most triangles, and fragments reading their lines
    // again cost the maps more than the inputs do.
    if (shape.cut) shape = splat_shape(triangle, lines_within(shape, b, v_radius));
    v_cut = shape.cut ? 1u : 0u;
    v_lines_a = shape.lines_a;
    v_lines_b = shape.lines_b;
    v_slack_a = shape.slack_a;
    v_slack_b = shape.slack_b;
    v_b = b;
    float a11 = dot(e1, e1), a12 = dot(e1, e2), a22 = dot(e2, e2), det = a11 * a22 - a12 * a12;
    v_dual = mat2x3((a22 * e1 - a12 * e2) / det, (a11 * e2 - a12 * e1) / det);
    v_axis = view.axis.xyz;
    v_far = view.axis.w;
    gl_PointSize = 1.0;
    // Points behind the vertex are never looked up. Nor are those within a splat radius of its
    // tangent plane: its own surface's splats, which stand up to a radius off the surface where
    // the map sees them edge-on, and would shadow every direction near its horizon.
    if (local.z * dist <= v_radius) {
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // outside the clip volume
        return;
    }
    vec2 texel = corner + (paraboloid_position(local) * 0.5 + 0.5) * view.tile.z;
    gl_Position = vec4(texel / atlas_size * 2.0 - 1.0, clamp(dist * view.axis.w, 0.0, 1.0) * 2.0 - 1.0, 1.0);
    // A disk of radius r at distance dist spans at most 2 asin(r / dist) radians, and a radian at
    // angle theta 1 / (1 + cos theta) of the map's [-1, 1]; a texel more for the scale's change
    // across the sprite and for coverage at texel centres.
    float angle = asin(min(v_radius / dist, 1.0));
    gl_PointSize = clamp(angle * view.tile.z / (1.0 + local.z) + 2.0, 1.0, 64.0);
}

#elif defined FRAGMENT_SHADER

flat in vec4 v_tile;
flat in vec3 v_centre;
flat in vec3 v_normal;
flat in vec3 v_axis;
flat in float v_far;
flat in uint v_cut;
flat in mat3 v_lines_a, v_lines_b;
flat in vec3 v_slack_a, v_slack_b;
flat in float v_radius;
flat in vec2 v_b;
flat in mat2x3 v_dual;
layout(location = 0) out vec2 out_distance;  // no second surface (lights.glsl: lit_tap)

void main() {
    // A splat near its tile's edge must not spill into the neighbouring vertex's map.
    if (any(lessThan(gl_FragCoord.xy, v_tile.xy)) || any(greaterThanEqual(gl_FragCoord.xy, v_tile.zw))) discard;
    vec2 q = (gl_FragCoord.xy - v_tile.xy) / (v_tile.z - v_tile.x) * 2.0 - 1.0;
    if (dot(q, q) > 1.0) discard;  // outside the hemisphere
    vec3 direction = paraboloid_direction(v_axis, q);
    float facing = dot(direction, v_normal);
    float t = dot(v_centre, v_normal) / facing;
    // The disk seen edge-on, behind the vertex, or missed: its plane met beyond its radius.
    if (abs(facing) < 1e-6 || !(t > 0.0)) discard;
    vec3 offset = t * direction - v_centre;
    float d2 = dot(offset, offset);
    if (d2 > v_radius * v_radius) discard;
    vec2 b = v_b + vec2(dot(offset, v_dual[0]), dot(offset, v_dual[1]));
    SplatShape shape = SplatShape(true, v_lines_a, v_lines_b, v_slack_a, v_slack_b);
    if (v_cut != 0u && !inside_splat(shape, b, d2 > splat_radius * splat_radius))
        discard;
    out_distance = vec2(t, NO_SURFACE);
    gl_FragDepth = clamp(t * v_far, 0.0, 1.0);
}

#endif
