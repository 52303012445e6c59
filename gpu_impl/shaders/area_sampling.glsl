// Surface points drawn in proportion to area: the scene's area CDF over its triangles (in the
// order the scene upload gives them, along a space-filling curve: gpu_impl/scene_buffers.py),
// inverted by a guided binary search. The imperfect bundles' splat points (splat_points.glsl) and
// the imperfect shadow maps' points (imperfect_shadow_maps.glsl) are drawn with it.

// Per curve position: the inclusive area CDF (float bits, last = 1) and the triangle there; and a
// guide to it: the answer for u lies between entries cdf_guide[b] and cdf_guide[b + 1], b = u G.
layout(std430, binding = BINDING_AREA_CDF) readonly buffer AreaCdf { uvec2 area_cdf[]; };
layout(std430, binding = BINDING_CDF_GUIDE) readonly buffer CdfGuide { uint cdf_guide[]; };

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
