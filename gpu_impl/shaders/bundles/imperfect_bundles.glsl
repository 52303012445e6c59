// Imperfect ray bundles drawn by the rasterizer (the poster's point splats; --splatter raster):
// each direction draws its own N surface points (splat_points.glsl) as small triangles in the
// tangent plane of the point's source triangle, and the fragment shader cuts the inscribed circle
// out of the triangle, so overlapping splats add fewer redundant nodes, and the lines that cut the
// splat off the circle (scene.glsl: SplatShape; the circle grown where they cut it). A
// node is its depth and the point (bundle.glsl), with FACING_BIT set when the splat faces along +d
// (the merge in resolve_lists.glsl keeps surfaces facing either way apart). splat_lists.glsl
// finds the same nodes without the rasterizer (--splatter compute, the default).

#define NODE_REFERENCE NODE_SPLAT_POINT
#define SPLAT_SHAPES
#define LINKED_LISTS
#extension GL_ARB_gpu_shader_int64 : require
#include "common.glsl"
#include "scene.glsl"
#include "bundle.glsl"
#include "bundle_build.glsl"

#if defined VERTEX_SHADER

// Constant over a splat, handed over flat, so a fragment reads no memory. A fragment works out
// its line's disk coordinates and barycentrics from its pixel's offset from the splat centre, as
// the compute splatter does: values interpolated between the corners would carry their snapping
// to the raster grid (1/256 pixel, over |cos| of the plane's slope on the plane), enough to put
// nodes past a sharp edge that cuts the splat.
flat out vec2 v_centre_pixel;   // the splat centre in the pixel grid (bundle.glsl: bundle_grid_position)
flat out vec2 v_b;              // the centre's barycentrics in its triangle's plane
flat out mat2 v_to_barycentrics;  // a pixel offset's barycentric offset
flat out mat2 v_to_disk;        // a barycentric offset's position in the splat, in units of its radius
flat out vec3 v_depth_plane;  // depth at bundle pixel (i, j): dot(v_depth_plane, (1, i, j))
flat out uint v_ref;          // the point | FACING_BIT
flat out int v_direction;
flat out uint v_cut;  // the splat's shape (scene.glsl: SplatShape), member by member
flat out mat3 v_lines_a, v_lines_b;
flat out vec3 v_slack_a, v_slack_b;
flat out float v_disk_limit;  // |disk|^2 beyond which a splat grown at sharp edges keeps to its triangle

void main() {
    uint splat = uint(gl_VertexID) / 3u;
    uint corner = uint(gl_VertexID) % 3u;
    SplatSource s = splat_source(splat);
    vec3 center = s.centre;
    vec3 n = triangle_normal(s.triangle);
    vec3 tangent = normalize(s.e1);
    vec3 bitangent = cross(n, tangent);
    int k = int(splat / points_per_direction);
    BundleFrame f = frames[k];
    float nd = dot(n, f.d.xyz);

    // The equilateral triangle around the unit disk has its corners at distance 2; 1 % more
    // keeps the lines at the disk's rim inside it after the corners snap.
    float angle = 2.0943951023931953 * float(corner);
    vec3 p = center + 2.02 * s.radius * (cos(angle) * tangent + sin(angle) * bitangent);
    // A splat seen nearly edge-on covers no line centre, as in the compute splatter; one exactly
    // edge-on has no depth plane. Its triangle has no area.
    if (abs(nd) < MIN_COS) p = center;
    v_centre_pixel = bundle_grid_position(f, center);
    v_b = s.b;
    v_to_barycentrics = inverse(grid_edges(f, s.e1, s.e2));
    v_to_disk = mat2(dot(s.e1, tangent), dot(s.e1, bitangent), dot(s.e2, tangent), dot(s.e2, bitangent)) / s.radius;
    SplatShape shape = splat_shape(s.triangle, s.cut_lines);
    v_cut = shape.cut ? 1u : 0u;
    v_lines_a = shape.lines_a;
    v_lines_b = shape.lines_b;
    v_slack_a = shape.slack_a;
    v_slack_b = shape.slack_b;
    v_disk_limit = (splat_radius / s.radius) * (splat_radius / s.radius);
    v_depth_plane = depth_plane(f, n, dot(n, center));
    v_ref = splat | (nd > 0.0 ? FACING_BIT : 0u);
    v_direction = k;
    gl_Position = bundle_clip_position(k, p);
}

#elif defined FRAGMENT_SHADER

flat in vec2 v_centre_pixel;
flat in vec2 v_b;
flat in mat2 v_to_barycentrics;
flat in mat2 v_to_disk;
flat in vec3 v_depth_plane;
flat in uint v_ref;
flat in int v_direction;
flat in uint v_cut;
flat in mat3 v_lines_a, v_lines_b;
flat in vec3 v_slack_a, v_slack_b;
flat in float v_disk_limit;

void main() {
#if !defined NULL_FRAGMENT
    ivec2 pixel = fragment_pixel(v_direction);
    if (pixel.x < 0) return;
    vec2 db = v_to_barycentrics * (vec2(pixel) - v_centre_pixel);
    vec2 disk = v_to_disk * db;
    if (dot(disk, disk) > 1.0) return;  // the circular cut-out
    SplatShape shape = SplatShape(true, v_lines_a, v_lines_b, v_slack_a, v_slack_b);
    if (v_cut != 0u && !inside_splat(shape, v_b + db, dot(disk, disk) > v_disk_limit)) return;
    append_node(pixel_list(v_direction, pixel), dot(v_depth_plane, vec3(1.0, vec2(pixel))), v_ref);
#endif
}

#endif
