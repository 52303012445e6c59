// Perfect ray bundles: every triangle, drawn once per direction with instancing into an atlas of
// R x R tiles, appends a node at each bundle pixel centre it covers (Tokuyoshi and Ogaki's
// per-pixel linked lists). One draw call covers as many directions as the atlas holds.
//
// The rasterizer only decides coverage. Depth, barycentrics, normal and uv are computed in the
// fragment shader by intersecting the pixel's line with the triangle, so they are exact to float32
// (interpolated varyings carry the rasterizer's vertex snapping, up to 2^-9 pixel times the
// slope), and no varying needs setting up for the many triangles that cover no pixel centre.
//
// NULL_FRAGMENT builds the raw-raster baseline of benchmarks/bundles.py: the same geometry and
// vertex work with an empty fragment shader.

#include "common.glsl"
#include "scene.glsl"
#include "bundle.glsl"

#if defined VERTEX_SHADER

layout(location = 0) in vec3 in_position;  // relative to the bundle centre

flat out int v_direction;

void main() {
    v_direction = direction_base + gl_InstanceID;
    gl_Position = bundle_clip_position(v_direction, in_position);
}

#elif defined FRAGMENT_SHADER

flat in int v_direction;

void main() {
#if !defined NULL_FRAGMENT
    int k = v_direction;
    ivec2 pixel = fragment_pixel(k);
    if (pixel.x < 0) return;
    // gl_PrimitiveID restarts with each instance, so it is the triangle's index in the scene.
    uint prim = uint(gl_PrimitiveID);
    uvec3 v = triangle_vertices(prim);
    vec3 p0 = vertex_position(v.x), e1 = vertex_position(v.y) - p0, e2 = vertex_position(v.z) - p0;
    vec3 d = frames[k].d.xyz;
    // Moller-Trumbore: the line o + t d meets the triangle at barycentrics (b1, b2), depth t.
    vec3 o = line_origin(k, pixel);
    vec3 s = o - p0, pv = cross(d, e2), qv = cross(s, e1);
    float inv = 1.0 / dot(e1, pv);
    float b1 = dot(s, pv) * inv, b2 = dot(d, qv) * inv, depth = dot(e2, qv) * inv;
    vec3 albedo = material_albedo(triangle_material(prim), surface_uv(v, b1, b2));
    append_node(pixel_list(k, pixel), depth, prim, encode_normal(shading_normal(prim, v, b1, b2)), albedo);
#endif
}

#endif
