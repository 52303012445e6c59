// The surface points of imperfect bundles: N per direction, a different seeded set for each
// direction and frame (as imperfect shadow maps use a different point set per map). A point is a
// triangle and barycentrics, so it follows its triangle if the geometry moves. Triangles are chosen
// in proportion to their area by inverting the area CDF (its entries in the order the scene upload
// gives them: triangles sorted along a space-filling curve, gpu_impl/scene_buffers.py).
//
// SAMPLER picks how (gpu_impl/layout.py: SAMPLERS):
// - SAMPLER_RANDOM: independent uniform points (a Poisson process over the surface, the textbook
//   model of splat coverage: a hole wherever no centre lies within the splat radius).
// - SAMPLER_STRATIFIED: u = (i + xi) / N, shifted per direction, so every stretch of the curve gets
//   its share of points within one. Within a triangle the same u carries on down a curve that
//   halves the triangle again and again (each half has half the area), so the points of a large
//   triangle are stratified in 2D too. Fewer holes for the same splat size, so fewer nodes.

#define NODE_REFERENCE NODE_SPLAT_POINT
#define SPLAT_POINTS_WRITE
#include "common.glsl"
#include "bundle.glsl"
#include "area_sampling.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

uniform uint invocations;     // K * N
uniform uint triangle_count;
uniform uint seed;
uniform uint frame;

#define CURVE_LEVELS 16  // 2^16 cells per triangle: as fine as the unorm16 barycentrics

void main() {
    uint id = linear_id();
    if (id >= invocations) return;
    uint k = id / points_per_direction, i = id % points_per_direction;
    uvec4 r = pcg4d(uvec4(i, k, seed, frame));
#if SAMPLER == SAMPLER_STRATIFIED
    float shift = unit_float(pcg4d(uvec4(0xFFFFFFFFu, k, seed, frame)).x);
    float u = fract((float(i) + unit_float(r.x)) / float(points_per_direction) + shift);
#else
    float u = unit_float(r.x);
#endif
    uint lo = curve_position(u);
    uint triangle = area_cdf[lo].y;
#if SAMPLER == SAMPLER_STRATIFIED
    // Where u falls inside this triangle's stretch of the CDF, down the halving curve: a
    // sub-triangle (apex, start, end) is split at the middle of start-end into (middle, start,
    // apex) then (middle, apex, end), two halves of equal area that the curve runs through in
    // turn. Corners are barycentrics (b1, b2) of the triangle.
    float below = lo > 0u ? cdf_at(lo - 1u) : 0.0;
    float s = clamp((u - below) / max(cdf_at(lo) - below, 1e-30), 0.0, 1.0);
    vec2 apex = vec2(0.0), start = vec2(1.0, 0.0), end = vec2(0.0, 1.0);
    for (int level = 0; level < CURVE_LEVELS; level++) {
        vec2 middle = 0.5 * (start + end);
        s *= 2.0;
        if (s < 1.0) {
            end = apex; apex = middle;
        } else {
            s -= 1.0;
            start = apex; apex = middle;
        }
    }
    // A uniform point in the last cell.
    float a = unit_float(r.y), c = unit_float(r.z);
    if (a + c > 1.0) { a = 1.0 - a; c = 1.0 - c; }
    vec2 b = apex + a * (start - apex) + c * (end - apex);
#else
    // Uniform on the triangle: b1 + b2 <= 1 with density 2.
    float sq = sqrt(unit_float(r.y)), w = unit_float(r.z);
    vec2 b = vec2(sq * (1.0 - w), sq * w);
#endif
    points[id] = SplatPoint(triangle, packUnorm2x16(b));
}

#endif
