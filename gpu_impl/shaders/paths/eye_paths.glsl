// One bounce of every eye path (paths.glsl says how bounces are counted). A path at a vertex
// scatters into a uniformly chosen bundle of the frame: its direction d or -d, whichever lies in
// the hemisphere of the shading normal, is a uniform hemisphere sample (pdf 1 / (2 pi)), so the
// throughput gains f cos / pdf: 2 albedo cos at a diffuse vertex, 2 pi f cos at a glossy one (a
// glossy vertex may choose by its BSDF instead, below). The next vertex is the nearest
// node beyond the vertex on the bundle line through it, found by binary search of the sorted
// list: no ray is traced and no visibility is tested. What the node is (normal, albedo, emission)
// is worked out there (bundle_hits.glsl). The shadow-mapped light it reflects is its precomputed
// irradiance (PRECOMPUTED_IRRADIANCE: irradiance.glsl) or, when that would cost more, evaluated
// here at the hit (the renderer decides per frame).

#define BUNDLE_LOOKUP
// bundle_step.glsl: the triangles across a met triangle's edges (walk_surface), and its smooth surface
#define SPLAT_SHAPES
#if SHADOW_LIGHTS && !LAZY_LIGHTING
#define PRECOMPUTED_IRRADIANCE
#endif
#include "common.glsl"
#include "scene.glsl"
#include "bsdf.glsl"
#include "bundle.glsl"
#include "bundle_hits.glsl"
#include "bundle_step.glsl"
#if LAZY_LIGHTING
#include "lights.glsl"
#endif
#include "environment.glsl"
#include "paths.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

uniform uint invocations;       // G-buffer samples x paths_per_sample

uniform int bounce;             // j: this pass takes every path from vertex j - 1 to vertex j
#if !BIDIRECTIONAL
uniform int bounces;            // B (lights.glsl declares it for bidirectional paths)
#endif
uniform int direction_count;    // K
uniform uint seed;
uniform uint frame;
uniform uint paths_per_sample;  // spp
uniform uint coherent_paths;    // neighbouring G-buffer samples whose paths share each bounce's choice
#if GLOSSY
uniform int bsdf_candidates;    // M: the bundles a glossy vertex weighs by its BSDF (0: a uniform choice)
#endif
#if BIDIRECTIONAL
uniform float light_path_emitter_density;  // V q_emitters / W: light paths' density of an emitter point, over w(y)
uniform float light_path_environment_density;  // V q_environment / (4 pi^2 r^2): of a ray from the environment
#endif
#if EMITTER_SAMPLES || BIDIRECTIONAL
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
    //
    // With coherent_paths > 1, the paths of that many neighbouring G-buffer samples along a row
    // (the same path index of each) take the same random choice at every bounce, as in coherent
    // path tracing (Sadeghi, Chen and Jensen 2009): their vertices lie side by side, so one bundle
    // carries them along neighbouring lines to neighbouring nodes and triangles, and a SIMD batch
    // (8 lanes on llvmpipe, a warp on a GPU) reads what its first lane brought into the cache and
    // walks alike. Each path's choice stays uniform and independent of its other bounces, so each
    // pixel's estimate and its variance are unchanged; neighbouring pixels' errors within a frame
    // are correlated, so the image mean spreads more from frame to frame. That is why it is not
    // the default (docs/results/decisions.toml: coherent-paths).
    uint chooser = id / paths_per_sample / coherent_paths * paths_per_sample + id % paths_per_sample;
    uint r = pcg4d(uvec4(chooser, uint(bounce), seed, frame)).x;
    bool any_bundle = path.bundle == PATH_FROM_CAMERA || direction_count == 1;
    int choices = any_bundle ? direction_count : direction_count - 1;
    int k = min(int(unit_float(r) * float(choices)), choices - 1);
    uint vertex_triangle = path.triangle & ~PATH_BACK;
#if GLOSSY
    uint vertex_material = triangle_material(vertex_triangle);
    vec3 wi = path.incoming.xyz;
    vec3 weight = vec3(-1.0);  // f cos / the choice's density, once known
    if (bsdf_candidates > 0 && materials[vertex_material].gloss.x != BSDF_DIFFUSE) {
        // Resampled importance sampling (Talbot et al. 2005): M of the bundles, from a random one
        // on, are candidates, uniform on the hemisphere and independent of each other (the frame's
        // directions are), each weighed by its f cos; one is kept with probability proportional
        // to that, by a weighted reservoir. With target p^ = the mean of f cos's channels, the
        // estimate f cos / p^ x (1/M) sum_j p^_j / (1 / (2 pi)) is unbiased (docs/method.md).
        int candidates = min(bsdf_candidates, choices);
        float total = 0.0, kept = 0.0;
        vec3 kept_f = vec3(0.0);
        int start = k;
        for (int j = 0; j < candidates; j++) {
            int b = start + j < choices ? start + j : start + j - choices;
            if (!any_bundle && b >= int(path.bundle)) b++;
            vec3 d = frames[b].d.xyz;
            vec3 fj = bsdf_cos(vertex_material, path.albedo, n, wi, dot(d, n) >= 0.0 ? d : -d);
            float target = (fj.r + fj.g + fj.b) / 3.0;
            total += target;
            uint u = pcg4d(uvec4(chooser, uint(bounce), seed, frame + uint(j + 1) * 0x9E3779B9u)).y;
            if (target > 0.0 && unit_float(u) * total < target) {
                k = b;
                kept = target;
                kept_f = fj;
            }
        }
        weight = kept > 0.0 ? kept_f * (2.0 * PI * total / (kept * float(candidates))) : vec3(0.0);
    } else if (!any_bundle && k >= int(path.bundle)) {
        k++;
    }
#else
    if (!any_bundle && k >= int(path.bundle)) k++;
#endif
    BundleFrame f = frames[k];
    float c = dot(f.d.xyz, n);
    bool forward = c >= 0.0;                  // follow +d, else -d
    vec3 omega = forward ? f.d.xyz : -f.d.xyz;
    float cos_theta = abs(c);
#if GLOSSY
    // A uniform choice: f cos / pdf with pdf = 1 / (2 pi), the BSDF from the way the path came to omega.
    if (weight.x < 0.0) weight = bsdf_cos(vertex_material, path.albedo, n, wi, omega) * (2.0 * PI);
    vec3 throughput = path.throughput * weight;
#else
    vec3 throughput = path.throughput * (2.0 * cos_theta) * path.albedo;
#endif

    vec3 ng = triangle_normal(vertex_triangle) * ((path.triangle & PATH_BACK) != 0u ? -1.0 : 1.0);
    BundleStep step = bundle_step(k, forward, path.position, ng, vertex_triangle);
    bool leaves = step.leaves;
    uint hit = step.hit;
    BundleHit node = step.node;
    vec3 node_geometric = step.geometric;

#if BIDIRECTIONAL
    // This vertex's and the next one's share of the MIS sum (paths.glsl: path_mis), from the two
    // densities of the edge between them: by the eye path (a = pdf cos_y / t^2, of the next
    // vertex) and by a light path (b = pdf cos_theta / t^2, of this one), both by bundle
    // directions. E' = (1 + b^2 E) / a^2, written without the 1 / t^2 that vertices a round-off
    // apart would make infinite (inf / inf gave NaN pixels), and bounded (0 x inf is NaN too).
    float eye_mis = path_mis[id], next_mis = 0.0, t2 = 1.0, cos_y_eye = 0.0;
    if (hit != NO_NODE) {
        vec3 edge = node.position - path.position;
        t2 = dot(edge, edge);
        cos_y_eye = abs(dot(node.normal, omega));
        float a = BUNDLE_DIRECTION_PDF * cos_y_eye, b = BUNDLE_DIRECTION_PDF * cos_theta;
        next_mis = min((t2 * t2 + b * b * eye_mis) / max(a * a, 1e-30), MAX_MIS_SHARE);
    }
#endif
    vec3 emitted = vec3(0.0);   // bounce j - 1
    vec3 reflected = vec3(0.0); // bounce j
    bool alive = bounce <= bounces && any(greaterThan(throughput, vec3(0.0)));
    if (!leaves) {
        alive = false;
    } else if (hit == NO_NODE) {
#if ENVIRONMENT != ENVIRONMENT_NONE
        emitted = throughput * environment(omega);
#if ENVIRONMENT_SAMPLES
        // Next-event estimation of the environment could have found this direction too (lights.glsl).
        emitted *= power_heuristic(BUNDLE_DIRECTION_PDF, environment_sample_density(omega));
#endif
#if BIDIRECTIONAL
        // A light path from the environment could have made this path too: along -omega to this
        // vertex, its first surface, then a connection from the one before (eye_mis; none at the
        // G-buffer sample, which light paths do not connect to). Its density b_n b_{n-1} = V q
        // p(omega) p(disk point) cos_theta over the eye path's a_n = 1 / (2 pi) (light_paths.glsl).
        float by_light_paths = light_path_environment_density * cos_theta / BUNDLE_DIRECTION_PDF;
        emitted /= 1.0 + by_light_paths * by_light_paths * eye_mis;
#endif
#endif
        alive = false;
    } else {
        vec3 nn = node.normal;
        uint m = triangle_material(node.triangle);
        bool front = dot(nn, omega) < 0.0;
        if (front) {
            emitted = throughput * materials[m].emission.rgb;
#if EMITTER_SAMPLES && !BIDIRECTIONAL
            // Next-event estimation could have found this emitter too: multiple importance sampling.
            // Its density for omega is that of the point where the ray from the vertex along omega
            // meets the emitter's plane, at distance t (measured on the plane: with a node on a line
            // beside the vertex, near a concave edge, the two strategies' weights did not sum to 1).
            float t = dot(node_geometric, node.position - path.position) / dot(node_geometric, omega);
            float cos_y = max(dot(node.normal, -omega), 0.0);
            emitted *= power_heuristic(BUNDLE_DIRECTION_PDF, emitter_sample_density * emitter_weight(m) * t * t / cos_y);
#endif
#if BIDIRECTIONAL
            // Next-event estimation and the light paths could have found this emitter too
            // (lights.glsl). Over the eye path's density per area a = pdf cos_y / t^2: next-event
            // estimation's e and the light paths' b_n b_{n-1} (b_{n-1} = pdf cos_theta / t^2),
            // all times t^2 / pdf, so no term divides by a vanishing distance.
            float hit = cos_y_eye, by_light_paths = light_path_emitter_density * emitter_weight(m) * cos_theta;
#if EMITTER_SAMPLES
            float nee = emitter_sample_density * emitter_weight(m) * t2 / BUNDLE_DIRECTION_PDF;
#else
            float nee = 0.0;
#endif
            emitted *= hit * hit / max(hit * hit + nee * nee + by_light_paths * by_light_paths * eye_mis, 1e-30);
#endif
        } else if (!material_twosided(m)) {
            alive = false;  // the back of a one-sided surface blocks the path
        } else {
            nn = -nn;
        }
        if (alive) {
#if SHADOW_LIGHTS && GLOSSY && BIDIRECTIONAL
            reflected = throughput * (light_reflected(node.position, nn, next_mis, m, node.albedo, -omega)
                                      + connections(node.position, nn, bounce, next_mis, m, node.albedo, -omega));
#elif SHADOW_LIGHTS && GLOSSY
            reflected = throughput * light_reflected(node.position, nn, 0.0, m, node.albedo, -omega);
#elif SHADOW_LIGHTS
#if LAZY_LIGHTING && BIDIRECTIONAL
            vec3 e = light_irradiance(node.position, nn, next_mis) + connections(node.position, nn, bounce, next_mis);
#elif LAZY_LIGHTING
            vec3 e = light_irradiance(node.position, nn, 0.0);
#else
            vec3 e = irradiance_at(node_ref(hit), front ? 0u : 1u);  // per splat point
#endif
            reflected = throughput * node.albedo * INV_PI * e;
#endif
            path.position = node.position;
            path.normal = encode_normal(nn);
            path.triangle = dot(node_geometric, omega) < 0.0 ? node.triangle : node.triangle | PATH_BACK;
            path.albedo = node.albedo;
            path.incoming = vec4(-omega, 0.0);
        }
    }
    if (bounce == 1) sums[id].direct.rgb += emitted; else sums[id].indirect.rgb += emitted;
    sums[id].indirect.rgb += reflected;
    path.throughput = throughput;
#if BIDIRECTIONAL
    path_mis[id] = next_mis;
#endif
    path.bundle = alive ? uint(k) : PATH_ENDED;
    // Only whether any path is alive matters after a bounce (paths.glsl: alive_paths): a store where
    // no lane has made one yet, not an atomic per path on one word, which llvmpipe runs lane by lane
    // with the two CPU threads taking turns at its cache line.
    if (alive && alive_paths == 0u) alive_paths = 1u;
    paths[id] = path;
}

#endif
