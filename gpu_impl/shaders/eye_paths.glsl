// One bounce of every eye path (paths.glsl says how bounces are counted). A path at a diffuse
// vertex scatters into a uniformly chosen bundle of the frame: its direction d or -d, whichever
// lies in the hemisphere of the shading normal, is a uniform hemisphere sample (pdf 1 / (2 pi)),
// so the throughput gains albedo / pi * cos / pdf = 2 albedo cos. The next vertex is the nearest
// node beyond the vertex on the bundle line through it, found by binary search of the sorted
// list: no ray is traced and no visibility is tested. What the node is (normal, albedo, emission)
// is worked out there (bundle_hits.glsl). The shadow-mapped light it reflects is its precomputed
// irradiance (PRECOMPUTED_IRRADIANCE: irradiance.glsl) or, when that would cost more, evaluated
// here at the hit (the renderer decides per frame).

#define BUNDLE_LOOKUP
#if SHADOW_LIGHTS && !LAZY_LIGHTING
#define PRECOMPUTED_IRRADIANCE
#endif
#include "common.glsl"
#include "scene.glsl"
#include "bundle.glsl"
#include "bundle_hits.glsl"
#if LAZY_LIGHTING
#include "lights.glsl"
#endif
#include "environment.glsl"
#include "paths.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

uniform uint invocations;       // G-buffer samples x paths_per_sample

uniform int bounce;             // j: this pass takes every path from vertex j - 1 to vertex j
uniform int bounces;            // B
uniform int direction_count;    // K
uniform uint seed;
uniform uint frame;
uniform float self_hit_bias;    // in bundle pixels, see below
#if EMITTER_SAMPLES
uniform float emitter_sample_density;  // M / W: M p(y) = emitter_sample_density * emitter_weight (gpu_impl/lights.py)
// w(y) of EmitterSamples: the mean of the emitted radiance's channels.
float emitter_weight(uint m) {
    vec3 e = materials[m].emission.rgb;
    return (e.r + e.g + e.b) / 3.0;
}
#endif

#if defined PRECOMPUTED_IRRADIANCE
vec3 irradiance_at(uint item, uint side) {
    uint i = irradiance_index(item, side);
    return vec3(irradiance[i], irradiance[i + 1u], irradiance[i + 2u]);
}
#endif

void main() {
    uint id = linear_id();
    if (id >= invocations) return;
    Path path = paths[id];
    if (path.bundle == PATH_ENDED) return;
    vec3 n = decode_normal(path.normal);
    // Any bundle but the one the path arrived along: that line leads straight back to the surface
    // the path came from (the reverse of its last segment), which a path tracer's independent
    // directions never do. Taking it in 1 of K bounces put that surface's light in place of the
    // hemisphere's: -3 % of the indirect light of an open stage under a constant sky at K = 16
    // (tests/test_renderer.py). The frame's other directions are independent of the last one
    // (evalkit/core/bundleset.py: DirectionSet), so the next direction is too.
    uint r = pcg4d(uvec4(id, uint(bounce), seed, frame)).x;
    bool any_bundle = path.bundle == PATH_FROM_CAMERA || direction_count == 1;
    int choices = any_bundle ? direction_count : direction_count - 1;
    int k = min(int(unit_float(r) * float(choices)), choices - 1);
    if (!any_bundle && k >= int(path.bundle)) k++;
    BundleFrame f = frames[k];
    float c = dot(f.d.xyz, n);
    bool forward = c >= 0.0;                  // follow +d, else -d
    vec3 omega = forward ? f.d.xyz : -f.d.xyz;
    float cos_theta = abs(c);
    vec3 throughput = path.throughput * (2.0 * cos_theta) * path.albedo;

    // The vertex's line. Lines pass up to a bundle pixel h = 2 radius / R beside the vertex. Of
    // the lines around it, the one taken is the nearest whose offset from the vertex points to
    // the side of its tangent plane the path leaves to (the geometric normal's side, per grid
    // axis). A line offset below the plane would cross it ahead of the vertex and, near a concave
    // edge (a wall meeting the floor), could pass outside the edge and miss the wall: light lost
    // in O(h) of every such edge, 4 % of a closed furnace's indirect light at R = 64.
    vec3 ng = decode_normal(path.geometric);
    float cg = dot(ng, f.d.xyz);
    // With a shading normal, omega may point below the geometric surface: the path would enter it.
    bool leaves = forward ? cg > 0.0 : cg < 0.0;
    float R = float(resolution);
    vec2 grid = (vec2(dot(path.position, f.u.xyz), dot(path.position, f.v.xyz)) / radius * 0.5 + 0.5) * R - vec2(f.u.w, f.v.w) - 0.5;
    vec2 above = vec2(dot(ng, f.u.xyz), dot(ng, f.v.xyz));
    ivec2 pixel = ivec2(above.x >= 0.0 ? ceil(grid.x) : floor(grid.x), above.y >= 0.0 ? ceil(grid.y) : floor(grid.y));
    pixel = clamp(pixel, ivec2(0), ivec2(resolution - 1));
    uint list = pixel_list(k, pixel);
    vec3 origin = line_origin(k, pixel);

    // Nodes up to the vertex's depth along the line are behind it; so are those up to where the
    // line crosses the vertex's tangent plane, should it cross ahead (only at the grid's border,
    // where no line above the plane is left). A further self-hit bias of self_hit_bias h skips
    // surfaces that curve within a bundle pixel of the vertex and covers float32 depths;
    // occluders nearer than that to the vertex are missed.
    float depth = dot(path.position - origin, f.d.xyz);
    float crossing = depth + dot(ng, path.position - (origin + depth * f.d.xyz)) / (leaves ? cg : 1.0);
    float bias = self_hit_bias * 2.0 * radius / R;
    float bound = forward ? max(depth, crossing) + bias : min(depth, crossing) - bias;

    // The nearest node beyond the bound along omega: a binary search of the sorted depths.
    uint first = list_first(list), last = list_end(list);
    uint lo = first, hi = last;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (forward ? node_depth(mid) <= bound : node_depth(mid) < bound) lo = mid + 1u; else hi = mid;
    }
    uint hit = forward ? (lo < last ? lo : NO_NODE) : (lo > first ? lo - 1u : NO_NODE);

    // A node whose plane a ray from the vertex along omega cannot reach (the plane lies behind the
    // vertex, or through it) is on the line only because the line passes beside the vertex: it is
    // skipped. Near a concave edge the line, above the vertex's own plane, may still pass behind
    // the other surface (a floor vertex's line behind the wall) and meet that surface's back, which
    // ended the path: the furnace's 1-bounce indirect light at R = 32 was 5.7 % short, 1.3 % now
    // (tests/test_renderer.py). The test holds for any planar primitive, and a splat lies in its
    // triangle's plane.
    BundleHit node;
    vec3 node_geometric;
    while (hit != NO_NODE) {
        node = list_node_hit(origin, f.d.xyz, hit);
        node_geometric = triangle_normal(node.triangle);
        if (dot(node_geometric, node.position - path.position) * dot(node_geometric, omega) > 0.0) break;
        hit = forward ? (hit + 1u < last ? hit + 1u : NO_NODE) : (hit > first ? hit - 1u : NO_NODE);
    }

    vec3 emitted = vec3(0.0);   // bounce j - 1
    vec3 reflected = vec3(0.0); // bounce j
    bool alive = bounce <= bounces && any(greaterThan(throughput, vec3(0.0)));
    if (!leaves) {
        alive = false;
    } else if (hit == NO_NODE) {
#if ENVIRONMENT != ENVIRONMENT_NONE
        emitted = throughput * environment(omega);
#endif
        alive = false;
    } else {
        vec3 nn = node.normal;
        uint m = triangle_material(node.triangle);
        bool front = dot(nn, omega) < 0.0;
        if (front) {
            emitted = throughput * materials[m].emission.rgb;
#if EMITTER_SAMPLES
            // Next-event estimation could have found this emitter too: multiple importance sampling.
            // Its density for omega is that of the point where the ray from the vertex along omega
            // meets the emitter's plane, at distance t. The node lies on a line up to a bundle pixel
            // beside the vertex: near a concave edge its distance differs from t many times over, and
            // with it the two strategies' weights did not sum to 1: the furnace with 8 emitter samples
            // lost 1.4 % of its indirect light, 0.7 % now (tests/test_renderer.py).
            float t = dot(node_geometric, node.position - path.position) / dot(node_geometric, omega);
            float cos_y = max(dot(node.normal, -omega), 0.0);
            emitted *= power_heuristic(BUNDLE_DIRECTION_PDF, emitter_sample_density * emitter_weight(m) * t * t / cos_y);
#endif
        } else if (!material_twosided(m)) {
            alive = false;  // the back of a one-sided surface blocks the path
        } else {
            nn = -nn;
        }
        if (alive) {
#if SHADOW_LIGHTS
#if LAZY_LIGHTING
            vec3 e = light_irradiance(node.position, nn);
#else
            // Per node (perfect bundles) or per splat point (imperfect).
            vec3 e = irradiance_at(NODE_REFERENCE == NODE_SPLAT_POINT ? node_ref(hit) : hit, front ? 0u : 1u);
#endif
            reflected = throughput * node.albedo * INV_PI * e;
#endif
            path.position = node.position;
            path.normal = encode_normal(nn);
            path.geometric = encode_normal(dot(node_geometric, omega) < 0.0 ? node_geometric : -node_geometric);
            path.albedo = node.albedo;
        }
    }
    if (bounce == 1) sums[id].direct.rgb += emitted; else sums[id].indirect.rgb += emitted;
    sums[id].indirect.rgb += reflected;
    path.throughput = throughput;
    path.bundle = alive ? uint(k) : PATH_ENDED;
    if (alive) atomicAdd(alive_paths, 1u);
    paths[id] = path;
}

#endif
