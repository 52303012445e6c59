// The surface points of imperfect bundles: N per direction, a different seeded set for each
// direction and frame (as imperfect shadow maps use a different point set per map). A point is a
// triangle and barycentrics, so it follows its triangle if the geometry moves. Triangles are chosen
// in proportion to their area by inverting the bundles' own area CDF, where a smooth surface too
// small for two points' share of the area gets that share, its triangles in one run along a
// space-filling curve (gpu_impl/scene_buffers.py: surface_area_cdf): a surface smaller than a
// splat otherwise has no point in some directions, and lines through it find nothing.
//
// SAMPLER picks how (gpu_impl/layout.py: SAMPLERS):
// - SAMPLER_RANDOM: independent uniform points (a Poisson process over the surface, the textbook
//   model of splat coverage: a hole wherever no centre lies within the splat radius).
// - SAMPLER_STRATIFIED: stratified over the area, a shift per direction (area_sampling.glsl:
//   stratified_point). Fewer holes for the same splat size, so fewer nodes.

#define NODE_REFERENCE NODE_SPLAT_POINT
#define SPLAT_SHAPES
#define SPLAT_POINTS_WRITE
#define SPLAT_CDF
#define SPLAT_TEXELS
#include "common.glsl"
#include "scene.glsl"
#include "bundle.glsl"
#include "area_sampling.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

uniform uint invocations;     // K * N
uniform uint triangle_count;
uniform uint seed;
uniform uint frame;

void main() {
    uint id = linear_id();
    if (id >= invocations) return;
    uint k = id / points_per_direction, i = id % points_per_direction;
    uvec4 r = pcg4d(uvec4(i, k, seed, frame));
#if SAMPLER == SAMPLER_STRATIFIED
    float shift = unit_float(pcg4d(uvec4(0xFFFFFFFFu, k, seed, frame)).x);
    float u = fract((float(i) + unit_float(r.x)) / float(points_per_direction) + shift);
    uint triangle;
    vec2 b = stratified_point(u, vec2(unit_float(r.y), unit_float(r.z)), triangle);
#else
    uint triangle = area_cdf[curve_position(unit_float(r.x))].y;
    // Uniform on the triangle: b1 + b2 <= 1 with density 2.
    float sq = sqrt(unit_float(r.y)), w = unit_float(r.z);
    vec2 b = vec2(sq * (1.0 - w), sq * w);
#endif
    // The radius and the cut lines within it, from the barycentrics as stored, which every pass
    // reads.
    uint stored = packUnorm2x16(b);
    vec2 b_stored = unpackUnorm2x16(stored);
    SplatShape shape = splat_shape(triangle, triangle_cut_lines(triangle));
    float point_radius = sharp_splat_radius(splat_radius, shape, b_stored);
    points[id] = SplatPoint(triangle, stored, point_radius, shape.cut ? lines_within(shape, b_stored, point_radius) : 0u);
}

#endif
