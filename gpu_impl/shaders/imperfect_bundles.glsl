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
// Everything else is constant over a splat and handed over flat, so a fragment reads no memory
// except a texture's texels: llvmpipe runs a few hundred million splat fragments per frame.
flat out vec3 v_depth_plane;      // depth at bundle pixel centre (x, y): dot(v_depth_plane, (1, x, y))
flat out uint v_normal;           // encoded
flat out vec3 v_albedo;           // of an untextured material
flat out uint v_textured;         // the material when textured, else NO_MATERIAL
flat out uint v_prim;
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

    int k = int(splat / points_per_direction);
    BundleFrame f = frames[k];
    // Where the line of bundle pixel centre (x, y) meets the splat's plane dot(n, p) = w: the
    // line's origin is s u + t v - r d with s = r (2 (x + jitter_u) / R - 1) (bundle.glsl), so
    // the depth (w - dot(n, origin)) / dot(n, d) is affine in (x, y). Exact to float32, where a
    // depth interpolated between the corners would carry their snapping to the raster grid.
    float nu = dot(n, f.u.xyz), nv = dot(n, f.v.xyz), nd = dot(n, f.d.xyz), R = float(resolution);
    v_depth_plane = vec3(dot(n, center) + radius * (nu * (1.0 - 2.0 * f.u.w / R) + nv * (1.0 - 2.0 * f.v.w / R) + nd),
                         -2.0 * radius * nu / R, -2.0 * radius * nv / R) / nd;
    v_normal = encode_normal(shading_normal(t, i, b1, b2));
    uint m = triangle_material(t);
    v_albedo = materials[m].albedo.rgb;
    v_textured = (materials[m].texture.w & MATERIAL_TEXTURED) != 0u ? m : NO_MATERIAL;
    v_prim = t | SPLAT_BIT;
    v_direction = k;
    gl_Position = bundle_clip_position(k, p);
}

#elif defined FRAGMENT_SHADER

in vec2 v_disk;
in vec2 v_uv;
flat in vec3 v_depth_plane;
flat in uint v_normal;
flat in vec3 v_albedo;
flat in uint v_textured;
flat in uint v_prim;
flat in int v_direction;

void main() {
#if !defined NULL_FRAGMENT
    if (dot(v_disk, v_disk) > 1.0) return;  // the circular cut-out
    ivec2 pixel = fragment_pixel(v_direction);
    if (pixel.x < 0) return;
    float depth = dot(v_depth_plane, vec3(1.0, vec2(pixel) + 0.5));
    vec3 albedo = v_textured == NO_MATERIAL ? v_albedo : material_albedo(v_textured, v_uv);
    append_node(pixel_list(v_direction, pixel), depth, v_prim, v_normal, albedo);
#endif
}

#endif
