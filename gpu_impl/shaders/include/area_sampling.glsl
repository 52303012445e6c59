// Surface points drawn in proportion to area: the scene's area CDF over its triangles (in the
// order the scene upload gives them, along a space-filling curve: gpu_impl/scene_buffers.py),
// inverted by a guided binary search. The imperfect bundles' splat points (splat_points.glsl) and
// the imperfect shadow maps' points (imperfect_shadow_maps.glsl) are drawn with it.
//
// Stratified points (`stratified_point`) take u = (i + xi) / N, shifted per point set, so every
// stretch of the curve gets its share of points within one. Within a triangle the same u carries
// on down a curve that halves the triangle again and again (each half has half the area), so the
// points of a large triangle are stratified in 2D too: fewer holes for the same splat size.

// Per curve position: the inclusive area CDF (float bits, last = 1) and the triangle there; and a
// guide to it: the answer for u lies between entries cdf_guide[b] and cdf_guide[b + 1], b = u G.
// SPLAT_CDF: the imperfect bundles' own, where every smooth surface has at least two points' share
// and its triangles lie in one run (gpu_impl/scene_buffers.py: surface_area_cdf); else the scene's.
#if defined SPLAT_CDF
layout(std430, binding = BINDING_SPLAT_CDF) readonly buffer AreaCdf { uvec2 area_cdf[]; };
layout(std430, binding = BINDING_SPLAT_CDF_GUIDE) readonly buffer CdfGuide { uint cdf_guide[]; };
#else
layout(std430, binding = BINDING_AREA_CDF) readonly buffer AreaCdf { uvec2 area_cdf[]; };
layout(std430, binding = BINDING_CDF_GUIDE) readonly buffer CdfGuide { uint cdf_guide[]; };
#endif

float cdf_at(uint i) {
    return uintBitsToFloat(area_cdf[i].x);
}

// The first curve position whose inclusive CDF exceeds u (its triangle: area_cdf[position].y).
uint curve_position(float u) {
    uint bucket = min(uint(u * float(cdf_guide.length() - 1)), uint(cdf_guide.length()) - 2u);
    uint lo = cdf_guide[bucket], hi = cdf_guide[bucket + 1u];
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (cdf_at(mid) > u) hi = mid; else lo = mid + 1u;
    }
    return lo;
}

#define CURVE_LEVELS 16  // 2^16 cells per triangle: as fine as the unorm16 barycentrics

// The triangle at ``u`` of the area CDF and the barycentrics (b1, b2) of the point there: where u
// falls inside the triangle's stretch of the CDF, down the halving curve (a sub-triangle (apex,
// start, end) is split at the middle of start-end into (middle, start, apex) then (middle, apex,
// end), two halves of equal area that the curve runs through in turn), then uniform in the last
// cell by ``xi``.
vec2 stratified_point(float u, vec2 xi, out uint triangle) {
    uint lo = curve_position(u);
    triangle = area_cdf[lo].y;
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
    float a = xi.x, c = xi.y;
    if (a + c > 1.0) { a = 1.0 - a; c = 1.0 - c; }
    return apex + a * (start - apex) + c * (end - apex);
}
