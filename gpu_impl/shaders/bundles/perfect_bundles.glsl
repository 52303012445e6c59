// Perfect ray bundles: every triangle, drawn once per direction with instancing into an atlas of
// R x R tiles, appends a node at each bundle pixel centre it covers (Tokuyoshi and Ogaki's
// per-pixel linked lists). One draw call covers as many directions as the atlas holds.
//
// The rasterizer only decides coverage. The depth is computed in the fragment shader where the
// pixel's line meets the triangle's plane, so it is exact to float32 (interpolated varyings carry
// the rasterizer's vertex snapping, up to 2^-9 pixel times the slope), and no varying needs setting
// up for the many triangles that cover no pixel centre. The triangle comes from its provoking vertex
// (a flat attribute: llvmpipe sets up gl_PrimitiveID at about twice the cost) and the direction
// from the atlas tile (no varying at all). A node is its depth and the triangle, with FACING_BIT
// set while the lists are built when the triangle faces along +d.
//
// NULL_FRAGMENT builds the raw-raster baseline of benchmarks/bundles.py: the same geometry and
// vertex work with an empty fragment shader.

#define NODE_REFERENCE NODE_TRIANGLE
#define LINKED_LISTS
#extension GL_ARB_gpu_shader_int64 : require
#include "common.glsl"
#include "scene.glsl"
#include "bundle.glsl"
#include "bundle_build.glsl"

#if defined VERTEX_SHADER

layout(location = 0) in vec3 in_position;  // relative to the bundle centre
layout(location = 1) in uint in_triangle;  // on the triangle's provoking vertex (scene_buffers.py)

flat out uint v_triangle;

void main() {
    v_triangle = in_triangle;
    gl_Position = bundle_clip_position(direction_base + gl_InstanceID, in_position);
}

#elif defined FRAGMENT_SHADER

flat in uint v_triangle;

void main() {
#if !defined NULL_FRAGMENT
    // The direction is the atlas tile the fragment is in: no varying to set up per triangle.
    ivec2 tile = ivec2(gl_FragCoord.xy) / resolution;
    int k = direction_base + tile.y * tiles_per_row + tile.x;
    ivec2 pixel = fragment_pixel(k);
    if (pixel.x < 0) return;
    uint prim = v_triangle;
    vec3 n = triangle_normal(prim);
    BundleFrame f = frames[k];
    vec3 plane = depth_plane(f, n, dot(n, vertex_position(indices[3u * prim])));
    append_node(pixel_list(k, pixel), dot(plane, vec3(1.0, vec2(pixel))), prim | (dot(n, f.d.xyz) > 0.0 ? FACING_BIT : 0u));
#endif
}

#endif
