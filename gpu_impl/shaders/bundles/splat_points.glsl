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

#if defined QUEUE_SPLATS
#extension GL_ARB_gpu_shader_int64 : require
#extension GL_ARB_shader_ballot : require
#define SPLAT_QUEUE
#endif
#define NODE_REFERENCE NODE_SPLAT_POINT
#define SPLAT_SHAPES
#define SPLAT_POINTS_WRITE
#define SPLAT_CDF
#define SPLAT_TEXELS
#include "common.glsl"
#include "scene.glsl"
#include "bundle.glsl"
#include "area_sampling.glsl"
#if defined QUEUE_SPLATS
#include "bundle_build.glsl"
#endif

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

uniform uint invocations;     // K * N
uniform uint triangle_count;
uniform uint seed;
uniform uint frame;

#if defined QUEUE_SPLATS
// Splat `id` (none where `point` is false) into splat_queue[] (bundle_build.glsl), from the front
// if no line cuts it, else from the back, for the compute splatter's count pass, which runs a
// program of its own over each run (splat_lists.glsl: PLAIN_SPLATS). A SIMD batch's (subgroup's)
// lanes take the slots of their rank among its lanes of their run, the batches theirs within the
// workgroup's, and the workgroup its own with one atomic per run. An atomic on one address for
// every batch took back nearly all that the count pass saved on llvmpipe (two CPU threads taking
// turns at its cache line; docs/results/decisions.toml: plain-splats).
// Called where every invocation of the workgroup is (it holds barriers).
shared uint group_plain, group_cut;  // the workgroup's splats of each run, then its first slot

void queue_splat(uint id, bool point, bool cut) {
    uvec2 plain_lanes = unpackUint2x32(ballotARB(point && !cut)), cut_lanes = unpackUint2x32(ballotARB(point && cut));
    bool leader = readFirstInvocationARB(gl_SubGroupInvocationARB) == gl_SubGroupInvocationARB;
    if (gl_LocalInvocationIndex == 0u) {
        group_plain = 0u;
        group_cut = 0u;
    }
    barrier();
    uint plain_base = 0u, cut_base = 0u;
    if (leader) {
        plain_base = atomicAdd(group_plain, bitCount(plain_lanes.x) + bitCount(plain_lanes.y));
        cut_base = atomicAdd(group_cut, bitCount(cut_lanes.x) + bitCount(cut_lanes.y));
    }
    plain_base = readFirstInvocationARB(plain_base);
    cut_base = readFirstInvocationARB(cut_base);
    barrier();
    if (gl_LocalInvocationIndex == 0u) {
        group_plain = atomicAdd(counters[COUNTER_PLAIN_SPLATS], group_plain);
        group_cut = atomicAdd(counters[COUNTER_CUT_SPLATS], group_cut);
    }
    barrier();
    plain_base += group_plain;
    cut_base += group_cut;
    uvec2 below = unpackUint2x32(gl_SubGroupLtMaskARB), lanes = cut ? cut_lanes : plain_lanes;
    uint rank = bitCount(lanes.x & below.x) + bitCount(lanes.y & below.y);
    if (point) splat_queue[cut ? invocations - 1u - (cut_base + rank) : plain_base + rank] = id;
}
#endif

// Point `id`'s triangle, barycentrics, radius and cut lines into points[]; returns its cut lines.
uint make_point(uint id) {
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
    uint lines = shape.cut ? lines_within(shape, b_stored, point_radius) : 0u;
    points[id] = SplatPoint(triangle, stored, point_radius, lines);
    return lines;
}

void main() {
    uint id = linear_id();
    bool point = id < invocations;
    uint cut_lines = 0u;
    if (point) cut_lines = make_point(id);
#if defined QUEUE_SPLATS
    queue_splat(id, point, cut_lines != 0u);
#endif
}

#endif
