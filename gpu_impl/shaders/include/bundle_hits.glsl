// What a node is, computed where it is needed (an eye path reaching it, the direct light at it, the
// host reading a BundleSet) from its depth, its reference and the scene (scene.glsl, bundle.glsl):
// nodes store nothing else.
//
// Perfect bundles: the node is on its triangle; normal and uv come from the hit's barycentrics.
// Imperfect bundles: the node is on its splat, the disk in its point's triangle's plane. The
// normal is the point's (one per splat); the uv continues the triangle's affine uv map to the hit,
// inside the splat or beyond the triangle's edge, so textures keep their detail inside a splat
// (the poster's per-corner texture coordinates, evaluated exactly).

struct BundleHit {
    uint triangle;
    vec3 position;  // relative to the bundle centre
    vec3 normal;    // shading normal
    vec3 albedo;
};

// A point on triangle t itself (a perfect bundle's node, or where a step walked to: bundle_step.glsl).
BundleHit triangle_hit(vec3 position, uint t) {
    vec3 p0, p1, p2;
    uvec3 v = triangle_corners(t, p0, p1, p2);
    vec2 b = plane_barycentrics(p0, p1 - p0, p2 - p0, position);
    return BundleHit(t, position, shading_normal(t, v, b.x, b.y), material_albedo(triangle_material(t), v, b));
}

BundleHit bundle_hit(vec3 position, uint ref) {
#if NODE_REFERENCE == NODE_SPLAT_POINT
    BundleHit hit;
    hit.position = position;
    hit.triangle = splat_point(ref).x;
    vec3 p0, p1, p2;
    uvec3 v = triangle_corners(hit.triangle, p0, p1, p2);
    vec2 b = plane_barycentrics(p0, p1 - p0, p2 - p0, position);
    vec2 centre = point_barycentrics(ref);
    hit.normal = shading_normal(hit.triangle, v, centre.x, centre.y);
    hit.albedo = material_albedo(triangle_material(hit.triangle), v, b);
    return hit;
#else
    return triangle_hit(position, ref);
#endif
}

#if defined BUNDLE_LOOKUP
// Node `index` of list l (which lies on line `origin` + t d).
BundleHit list_node_hit(vec3 origin, vec3 d, uint index) {
    return bundle_hit(origin + node_depth(index) * d, node_ref(index));
}
#endif

// The triangle a node's reference lies on (a splat: its point's triangle).
uint ref_triangle(uint ref) {
#if NODE_REFERENCE == NODE_SPLAT_POINT
    return splat_point(ref).x;
#else
    return ref;
#endif
}

// Whether a node's surface is smaller than a bundle pixel (h, the lines' spacing): a triangle whose
// longest edge, or a splat whose diameter, is shorter. Lines a pixel apart cannot tell a ray's miss
// of such a triangle or splat from a miss of the surface it is part of (bundle_step.glsl).
bool smaller_than_pixel(uint ref, float h) {
#if NODE_REFERENCE == NODE_SPLAT_POINT
    return 2.0 * splat_radius < h;
#else
    vec3 a, b, c;
    triangle_corners(ref, a, b, c);
    return max(max(dot(b - a, b - a), dot(c - b, c - b)), dot(a - c, a - c)) < h * h;
#endif
}
