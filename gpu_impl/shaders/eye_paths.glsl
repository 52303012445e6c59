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

    // The next vertex: where the ray from the vertex along omega meets the frame's bundle. No line
    // passes through the vertex; the four around it (R x R lines, h = 2 radius / R apart) pass up
    // to a pixel beside it, and each meets surfaces the ray may or may not. Each line offers the
    // first node beyond the vertex whose plane the ray reaches, and the ray's own point on that
    // plane; the ray lands on the nearest of them that lies on its node's surface (inside its
    // triangle, or within its splat). A point on a surface another line meets nearer is behind
    // that surface (the far wall beside a block), so all four are looked at. Where no point lies
    // on its surface (the ray passes between the surfaces the lines meet, or they are triangles
    // smaller than a pixel), the line on the vertex's open side (its geometric normal's, per grid
    // axis) decides, as one line did before. One line's node taken where it lies put the next vertex half a pixel off on
    // average, towards the open side, and lost the light of lines passing beside a concave edge:
    // +2 % and -1 % of cornell-box's and the furnace's indirect light at R = 64
    // (docs/MEASURED_FACTS.md).
    vec3 x = path.position;
    vec3 ng = decode_normal(path.geometric);
    float cg = dot(ng, f.d.xyz);
    // With a shading normal, omega may point below the geometric surface: the path would enter it.
    bool leaves = forward ? cg > 0.0 : cg < 0.0;
    vec2 grid = bundle_grid_position(f, x);
    ivec2 corner = ivec2(floor(grid));
    // The open side's line: of the four, the one offset from the vertex towards its normal.
    vec2 above = vec2(dot(ng, f.u.xyz), dot(ng, f.v.xyz));
    int open_side = (above.x >= 0.0 && grid.x > floor(grid.x) ? 1 : 0) + (above.y >= 0.0 && grid.y > floor(grid.y) ? 2 : 0);
    // Nodes up to the vertex's depth along a line are behind it; so are those up to where the line
    // crosses the vertex's tangent plane, should it cross ahead (a line below that plane). A
    // further self-hit bias of self_hit_bias h covers float32 depths: occluders nearer than that
    // to the vertex are missed.
    float bias = self_hit_bias * 2.0 * radius / float(resolution);
    uint hit = NO_NODE, open_hit = NO_NODE;
    vec3 open_origin = vec3(0.0);
    float hit_t = 0.0;
    for (int i = 0; i < 4 && leaves; i++) {
        int c = i == 0 ? open_side : (i <= open_side ? i - 1 : i);  // the open side first, then the others
        ivec2 pixel = corner + ivec2(c & 1, c >> 1);
        if (any(lessThan(pixel, ivec2(0))) || any(greaterThanEqual(pixel, ivec2(resolution)))) continue;
        uint list = pixel_list(k, pixel);
        vec3 origin = line_origin(k, pixel);
        float depth = dot(x - origin, f.d.xyz);
        float crossing = depth + dot(ng, x - (origin + depth * f.d.xyz)) / cg;
        float bound = forward ? max(depth, crossing) + bias : min(depth, crossing) - bias;
        // The nearest node beyond the bound along omega: a binary search of the sorted depths.
        uint first = list_first(list), last = list_end(list);
        uint lo = first, hi = last;
        while (lo < hi) {
            uint mid = (lo + hi) / 2u;
            if (forward ? node_depth(mid) <= bound : node_depth(mid) < bound) lo = mid + 1u; else hi = mid;
        }
        uint node = forward ? (lo < last ? lo : NO_NODE) : (lo > first ? lo - 1u : NO_NODE);
        // A node whose plane the ray cannot reach (the plane lies behind the vertex, or through
        // it) is on the line only because the line passes beside the vertex: the next one is
        // taken. Near a concave edge a line may pass behind the other surface (a floor vertex's
        // line behind the wall) and meet its back: the furnace's 1-bounce indirect light at R = 32
        // was 5.7 % short before (tests/test_renderer.py). A splat lies in its triangle's plane.
        // A splat of the vertex's own surface is skipped too: on a curved surface it stands off
        // the vertex and shadowed it (parts scene, N = 65536, R = 256: indirect light 0.23 of
        // Mitsuba's with it, 0.51 without; docs/MEASURED_FACTS.md).
        while (node != NO_NODE) {
            uint ref = node_ref(node);
            vec3 plane_normal = triangle_normal(ref_triangle(ref));
            float gap = dot(plane_normal, origin + node_depth(node) * f.d.xyz - x), along = dot(plane_normal, omega);
            if (gap * along > 0.0 && !own_surface(ref, x, ng)) {
                float t = gap / along;
                // No nearer than the best so far (on its plane, usually): it cannot win.
                if ((hit == NO_NODE || t < hit_t * (1.0 - 1e-5)) && on_node_surface(ref, x + t * omega)) {
                    hit = node;
                    hit_t = t;
                }
                if (c == open_side) {
                    open_hit = node;
                    open_origin = origin;
                }
                break;
            }
            node = forward ? (node + 1u < last ? node + 1u : NO_NODE) : (node > first ? node - 1u : NO_NODE);
        }
    }
    bool on_surface = hit != NO_NODE;
    if (!on_surface) hit = open_hit;
    BundleHit node;
    vec3 node_geometric;
    if (hit != NO_NODE) {
        // The ray's point on the node's surface; off it (the open side's line), the node where it
        // lies: a small curved facet's plane carried to the ray put the vertex inside neighbouring
        // parts (-18 % of the parts scene's indirect light at R = 128).
        vec3 y = on_surface ? x + hit_t * omega : open_origin + node_depth(hit) * f.d.xyz;
        node = bundle_hit(y, node_ref(hit));
        node_geometric = triangle_normal(node.triangle);
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
            // meets the emitter's plane, at distance t (measured on the plane: with a node on a line
            // beside the vertex, near a concave edge, the two strategies' weights did not sum to 1).
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
            vec3 e = irradiance_at(node_ref(hit), front ? 0u : 1u);  // per splat point
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
