// Imperfect ray bundles (the poster's point splats): each direction draws its own N surface points
// (splat_points.glsl) as small triangles in the tangent plane of the point's source triangle,
// with uvs computed at each corner so textures keep their detail inside a splat, and the fragment
// shader cuts the inscribed circle out of the triangle, so overlapping splats add fewer redundant
// nodes. Nodes have the perfect bundles' format; prim carries SPLAT_BIT.

#include "common.glsl"
#include "scene.glsl"
#include "bundle.glsl"

layout(std430, binding = BINDING_POINTS) readonly buffer Points { uvec4 points[]; };  // triangle, b1, b2, -

uniform uint points_per_direction;  // N
uniform float splat_radius;

#if defined VERTEX_SHADER

out vec2 v_disk;  // position in the splat in units of its radius: the cut-out keeps |v_disk| <= 1
out vec2 v_uv;
flat out vec3 v_normal;
flat out uint v_triangle;
flat out int v_direction;

void main() {
    uint splat = uint(gl_VertexID) / 3u;
    uint corner = uint(gl_VertexID) % 3u;
    uvec4 point = points[splat];
    uint t = point.x;
    float b1 = uintBitsToFloat(point.y), b2 = uintBitsToFloat(point.z);
    uvec3 i = triangle_vertices(t);
    vec3 p0 = vertex_position(i.x), e1 = vertex_position(i.y) - p0, e2 = vertex_position(i.z) - p0;
    vec3 center = p0 + b1 * e1 + b2 * e2;
    vec3 n = triangle_normal(t);
    vec3 tangent = normalize(e1);
    vec3 bitangent = cross(n, tangent);

    // The equilateral triangle around the unit disk has its corners at distance 2.
    float angle = 2.0943951023931953 * float(corner);
    v_disk = 2.0 * vec2(cos(angle), sin(angle));
    vec3 p = center + splat_radius * (v_disk.x * tangent + v_disk.y * bitangent);

    // The corner's barycentrics in the source triangle's plane (outside [0, 1] in general), so its
    // uv continues the triangle's affine uv map.
    vec3 q = p - p0;
    float a = dot(e1, e1), b = dot(e1, e2), c = dot(e2, e2);
    vec2 beta = vec2(c * dot(q, e1) - b * dot(q, e2), a * dot(q, e2) - b * dot(q, e1)) / (a * c - b * b);
    v_uv = surface_uv(i, beta.x, beta.y);
    v_normal = shading_normal(t, i, b1, b2);
    v_triangle = t;
    v_direction = int(splat / points_per_direction);
    gl_Position = bundle_clip_position(v_direction, p);
}

#elif defined FRAGMENT_SHADER

in vec2 v_disk;
in vec2 v_uv;
flat in vec3 v_normal;
flat in uint v_triangle;
flat in int v_direction;

void main() {
#if !defined NULL_FRAGMENT
    if (dot(v_disk, v_disk) > 1.0) return;  // the circular cut-out
    int k = v_direction;
    ivec2 pixel = fragment_pixel(k);
    if (pixel.x < 0) return;
    // The depth where the pixel's line meets the splat's plane (its triangle's), exact to float32
    // rather than interpolated from snapped corners.
    vec3 n = triangle_normal(v_triangle), d = frames[k].d.xyz;
    float depth = dot(vertex_position(triangle_vertices(v_triangle).x) - line_origin(k, pixel), n) / dot(d, n);
    append_node(pixel_list(k, pixel), depth, v_triangle | SPLAT_BIT, v_normal, material_albedo(triangle_material(v_triangle), v_uv));
#endif
}

#endif
