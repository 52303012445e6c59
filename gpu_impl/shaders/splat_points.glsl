// The surface points of imperfect bundles: N per direction, a different seeded set for each
// direction and frame. A point is a triangle index and barycentrics, so it follows the triangle
// if the geometry moves. Triangles are chosen in proportion to their area by inverting the area
// CDF at a stratified u = (i + xi) / N: every triangle gets its expected share of points within one,
// which leaves fewer holes than independent draws at the same N.

#include "common.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

layout(std430, binding = BINDING_AREA_CDF) readonly buffer AreaCdf { float area_cdf[]; };  // inclusive, last = 1
layout(std430, binding = BINDING_POINTS) writeonly buffer Points { uvec4 points[]; };

uniform uint invocations;           // K * N
uniform uint points_per_direction;  // N
uniform uint triangle_count;
uniform uint seed;
uniform uint frame;

void main() {
    uint id = linear_id();
    if (id >= invocations) return;
    uint k = id / points_per_direction, i = id % points_per_direction;
    uvec4 r = pcg4d(uvec4(i, k, seed, frame));
    float u = (float(i) + unit_float(r.x)) / float(points_per_direction);
    // The first triangle whose inclusive CDF exceeds u.
    uint lo = 0u, hi = triangle_count - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (area_cdf[mid] > u) hi = mid; else lo = mid + 1u;
    }
    // Uniform on the triangle: b1 + b2 <= 1 with density 2.
    float s = sqrt(unit_float(r.y)), w = unit_float(r.z);
    points[id] = uvec4(lo, floatBitsToUint(s * (1.0 - w)), floatBitsToUint(s * w), 0u);
}

#endif
