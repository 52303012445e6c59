// Light paths over the frame's bundles (gpu_impl/strategies/bidirectional.py): one invocation per
// light path, from its start (the host drew the source by power, and the point on an emitter) to
// up to B vertices on surfaces, each written with what a connection needs. No ray is traced:
//
// - From an emitter point the path leaves along a uniformly chosen bundle direction (the side in
//   the emitter's hemisphere, density 1 / (2 pi)), the frame's paths spread over the bundles, to
//   the next node, as eye paths do (bundle_step.glsl).
// - From the environment it enters along a bundle direction (uniform over the sphere: the bundle
//   spread as above, either way along it), through a point uniform on the frame's disk, and meets
//   its first surface over the bundles too: the path is an eye path of the reverse direction that
//   starts outside the scene.
// - From a point or spot light it leaves along a direction drawn from the light (uniform over the
//   sphere, or over the spot's cone), and from a directional light through a point drawn uniformly
//   on the disk the light's shadow view covers. The first surface is the light's shadow map read
//   as a reflective shadow map: the triangle its texel saw (shadow_maps.glsl), met exactly by the
//   ray. The texel stands for the ray, as a bundle pixel stands for a ray.
// - These directions and disk points, and the environment's disk points, come from the start's
//   point of the unit square, which the host stratifies over each source's paths.
// - Every later vertex takes a uniformly chosen bundle of the frame, but not the one it arrived
//   along, and its next node.
//
// A vertex y_i (depth d = n - i, on a path that started at z_n) is stored as a point light whose
// intensity falls as the cosine to its normal: alpha_i albedo / pi, with alpha_i the light path's
// throughput (flux over density) arriving there. With glossy materials (GLOSSY) it sends light by
// its BSDF instead: it is stored with alpha_i, its material and the direction back along the path,
// and each connection evaluates it (lights.glsl); a glossy vertex's throughput gains f cos / pdf.
// Its MIS share (lights.glsl) is
//   L_{n-1} = (e_n^2 + a_n^2) / (b_n b_{n-1})^2   (an emitter start; a delta light: a_n = 0, e_n = 1)
//   L_i = (1 + a_{i+1}^2 L_{i+1}) / b_i^2
// with b the light side's densities per area (b_n: V q p_A of the start), a the eye side's of the
// vertex before (by a bundle direction: cos / (2 pi t^2)), e_n next-event estimation's. A ray from
// the environment or a directional light starts at a direction, not a point: there b_n b_{n-1} is
// V q p(omega) p(disk point) cos_{n-1} and a_n the eye path's density of that direction (1 / (2 pi)
// for the environment, which eye paths reach; 0 for a directional light, which they cannot).

#define BUNDLE_LOOKUP
// bundle_step.glsl: the triangles across a met triangle's edges (walk_surface), and its smooth surface
#define SPLAT_SHAPES
#define SHADOW_LIGHTS 1
#include "common.glsl"
#include "scene.glsl"
#include "bsdf.glsl"
#include "bundle.glsl"
#include "bundle_hits.glsl"
#include "bundle_step.glsl"
#include "lights.glsl"
#include "light_path_records.glsl"
#include "environment.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

#define INV_PI 0.3183098861837907

uniform uint invocations;       // V
#if ATLAS_TEXTURES == 1  // the triangle + 1 each shadow texel saw, in the atlas' textures (lights.glsl)
uniform usampler2DArray shadow_triangles;
#else
uniform usampler2DArray shadow_triangles[ATLAS_TEXTURES];
#endif
uniform int direction_count;    // K
uniform uint seed;
uniform uint frame;

// LightPathStart.position.w of the sources that are not fixed lights (strategies/bidirectional.py).
#define FROM_EMITTERS -1
#define FROM_ENVIRONMENT -2

struct Surface {
    bool found;
    vec3 position, normal, geometric, albedo;  // normals on the side the path arrives at
    uint triangle;
};

// The triangle + 1 seen at `texel` of the tile at `place` (lights.glsl: atlas_surfaces).
uint seen_triangle(ivec4 place, ivec2 texel) {
    ivec3 at = ivec3(place.xy + texel, place.z);
#if ATLAS_TEXTURES == 1
    return texelFetch(shadow_triangles, at, 0).r;
#else
    for (int i = 0; i < atlas_textures; i++) {
        if (i == place.w) return texelFetch(shadow_triangles[i], at, 0).r;
    }
    return 0u;
#endif
}

// The first surface along the ray from origin along omega, from light l's shadow map.
Surface reflective_shadow_map(Light light, vec3 origin, vec3 omega) {
    Surface s = Surface(false, vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0), NO_TRIANGLE);
    ShadowView view = shadow_views[shadow_view_of(light, origin + omega)];
    vec4 clip = view.to_clip * vec4(origin + omega, 1.0);
    if (clip.w <= 0.0) return s;
    vec2 ndc = clip.xy / clip.w;
    if (any(greaterThan(abs(ndc), vec2(1.0)))) return s;
    int size = int(view.tile.z);
    ivec2 texel = clamp(ivec2((ndc * 0.5 + 0.5) * view.tile.z), ivec2(0), ivec2(size - 1));
    ivec4 place = atlas_place(ivec2(view.tile.xy));
    uint seen = seen_triangle(place, texel);
    if (seen == 0u || atlas_surfaces(place, texel).x * view.axis.w >= 1.0) return s;  // nothing there
    uint t = seen - 1u;
    vec3 p0, p1, p2;
    uvec3 v = triangle_corners(t, p0, p1, p2);
    vec3 e1 = p1 - p0, e2 = p2 - p0;
    vec3 so = origin - p0, pv = cross(omega, e2), qv = cross(so, e1);
    float det = dot(e1, pv);
    if (det == 0.0) return s;
    float inv = 1.0 / det;
    float b1 = dot(so, pv) * inv, b2 = dot(omega, qv) * inv, depth = dot(e2, qv) * inv;
    if (depth <= 0.0) return s;
    vec3 n = shading_normal(t, v, b1, b2), g = triangle_normal(t);
    uint m = triangle_material(t);
    if (dot(n, omega) >= 0.0) {
        if (!material_twosided(m)) return s;  // the back of a one-sided surface absorbs it
        n = -n;
    }
    s.found = true;
    s.position = origin + depth * omega;
    s.normal = n;
    s.geometric = dot(g, omega) < 0.0 ? g : -g;
    s.albedo = material_albedo(m, v, vec2(b1, b2));
    s.triangle = t;
    return s;
}

// Where a step over the bundles along omega lands: nothing where it leaves the scene, or meets the
// back of a one-sided surface (which absorbs it).
Surface landed(BundleStep step, vec3 omega) {
    Surface none = Surface(false, vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0), NO_TRIANGLE);
    if (!step.leaves || step.hit == NO_NODE) return none;
    vec3 n = step.node.normal, g = step.geometric;
    if (dot(n, omega) >= 0.0) {
        if (!material_twosided(triangle_material(step.node.triangle))) return none;
        n = -n;
    }
    return Surface(true, step.node.position, n, dot(g, omega) < 0.0 ? g : -g, step.node.albedo, step.node.triangle);
}

// A unit vector around axis a at cos_theta from it and azimuth phi.
vec3 around(vec3 a, float cos_theta, float phi) {
    vec3 helper = abs(a.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0);
    vec3 t = normalize(cross(a, helper)), b = cross(a, t);
    float sin_theta = sqrt(max(1.0 - cos_theta * cos_theta, 0.0));
    return sin_theta * cos(phi) * t + sin_theta * sin(phi) * b + cos_theta * a;
}

// The point of the frame's disk across omega (the bundle lines' plane, behind every node) where light
// along omega enters the scene, from point u of the unit square (uniform there: uniform on the disk).
vec3 disk_origin(vec3 omega, vec2 u) {
    vec3 disk = around(omega, 0.0, 2.0 * PI * u.y) * (radius * sqrt(u.x));
    return disk - radius * omega;
}

void main() {
    uint id = linear_id();
    if (id >= invocations) return;
    for (int d = 0; d < bounces; d++) light_path_records[id * uint(bounces) + uint(d)].position.w = 0.0;
    LightPathStart start = starts[id];
    int source = int(start.position.w);
    float b_start = start.normal.w;
    Surface y;
    vec3 alpha;      // the throughput arriving at y
    vec3 incoming;   // the unit direction from y back along the path
    float mis;       // L of y
    int arrived = -1;  // the bundle y was reached along (none from a light's shadow map)
    // Path i leaves along bundle (i + o) mod K, o one random shift per frame: each path's bundle is
    // still uniform and independent of its start, but the frame's paths spread over the bundles
    // instead of doubling up. Paths from a small emitter that take the same bundle land side by
    // side and light the same pixels, so repeats added little: at K = V = 64 on cornell-box this
    // took the frame means' scatter from 21 % to 15 % (docs/results/decisions.toml: light-paths-spread).
    uint o = pcg4d(uvec4(0xFFFFFFFFu, 0xFFFFFFFFu, seed, frame)).x;
    int spread = int((id + o) % uint(direction_count));
    if (source == FROM_EMITTERS) {
        // An emitter point: along a bundle direction in its hemisphere.
        vec3 x = start.position.xyz, n = start.normal.xyz;
        int k = spread;
        BundleFrame f = frames[k];
        bool forward = dot(f.d.xyz, n) >= 0.0;
        vec3 omega = forward ? f.d.xyz : -f.d.xyz;
        // The start's triangle tells the splats of its own surface behind it (bundle_step.glsl:
        // own_surface), which a ray leaving a curved emitter cannot meet.
        y = landed(bundle_step(k, forward, x, start.geometric.xyz, start.triangle), omega);
        if (!y.found) return;
        incoming = -omega;
        vec3 edge = y.position - x;
        float t2 = dot(edge, edge), cos_start = abs(dot(n, omega)), cos_y = abs(dot(y.normal, omega));
        alpha = start.radiance.rgb * cos_start / (b_start * BUNDLE_DIRECTION_PDF);
        // (e^2 + a^2) / (b_n b)^2 with a = pdf cos_start / t^2 and b = pdf cos_y / t^2, times t^4 / t^4.
        float a_start = BUNDLE_DIRECTION_PDF * cos_start, b_y = BUNDLE_DIRECTION_PDF * cos_y;
        float e = start.radiance.w * t2;
        mis = min((e * e + a_start * a_start) / max(b_start * b_start * b_y * b_y, 1e-30), MAX_MIS_SHARE);
        arrived = k;
#if ENVIRONMENT != ENVIRONMENT_NONE
    } else if (source == FROM_ENVIRONMENT) {
        // Into the scene along omega from a point of the frame's disk: the first node beyond it,
        // as a step over the bundles finds it.
        int k = spread;
        bool forward = (pcg4d(uvec4(id, 0xFFFFFFFFu, seed, frame)).z & 1u) == 0u;
        vec3 omega = forward ? frames[k].d.xyz : -frames[k].d.xyz;
        y = landed(bundle_step(k, forward, disk_origin(omega, start.square_point.xy), omega, NO_TRIANGLE), omega);
        if (!y.found) return;
        incoming = -omega;
        alpha = environment(-omega) / b_start;
        // L_{n-1} = a_n^2 / (b_n b_{n-1})^2: the eye path reaches the environment along -omega
        // from y with a = 1 / (2 pi); the environment has no next-event estimation (e_n = 0).
        float b = b_start * abs(dot(y.normal, omega));
        mis = min(BUNDLE_DIRECTION_PDF * BUNDLE_DIRECTION_PDF / max(b * b, 1e-30), MAX_MIS_SHARE);
        arrived = k;
#endif
    } else {
        Light light = lights[source];
        vec3 origin, omega;
        if (light.position.w == LIGHT_DIRECTIONAL) {
            omega = light.direction.xyz;
            origin = disk_origin(omega, start.square_point.xy);
            alpha = light.intensity.rgb / light.paths.x;
        } else {
            origin = light.position.xyz;
            if (light.position.w == LIGHT_SPOT) {
                float cos_theta = 1.0 - start.square_point.x * (1.0 - light.direction.w);
                omega = around(light.direction.xyz, cos_theta, 2.0 * PI * start.square_point.y);
                alpha = light.intensity.rgb * spot_falloff(light, cos_theta);
            } else {
                omega = around(vec3(0.0, 0.0, 1.0), 1.0 - 2.0 * start.square_point.x, 2.0 * PI * start.square_point.y);
                alpha = light.intensity.rgb;
            }
            alpha /= light.paths.x;  // V q p(omega)
        }
        y = reflective_shadow_map(light, origin, omega);
        if (!y.found) return;
        incoming = -omega;
        vec3 edge = y.position - origin;
        float t2 = light.position.w == LIGHT_DIRECTIONAL ? 1.0 : dot(edge, edge);
        float b = light.paths.x * abs(dot(y.normal, omega));  // b_n b_{n-1} t^2
        mis = min(t2 * t2 / max(b * b, 1e-30), MAX_MIS_SHARE);
    }
    for (int d = 1; d <= bounces; d++) {
#if GLOSSY
        light_path_records[id * uint(bounces) + uint(d - 1)] = LightPathVertex(
            vec4(y.position, float(d)), vec4(y.normal, mis), vec4(alpha, 0.0),
            vec4(y.albedo, float(triangle_material(y.triangle))), vec4(incoming, 0.0));
#else
        light_path_records[id * uint(bounces) + uint(d - 1)] = LightPathVertex(
            vec4(y.position, float(d)), vec4(y.normal, mis), vec4(alpha * y.albedo * INV_PI, 0.0), vec4(0.0), vec4(0.0));
#endif
        if (d == bounces) break;
        // On along any bundle but the one it arrived along (eye_paths.glsl says why).
        uint u = pcg4d(uvec4(id, uint(d), seed, frame)).x;
        bool any_bundle = arrived < 0 || direction_count == 1;
        int choices = any_bundle ? direction_count : direction_count - 1;
        int k = min(int(unit_float(u) * float(choices)), choices - 1);
        if (!any_bundle && k >= arrived) k++;
        BundleFrame f = frames[k];
        float c = dot(f.d.xyz, y.normal);
        bool forward = c >= 0.0;
        vec3 omega = forward ? f.d.xyz : -f.d.xyz;
        float cos_y = abs(c);
#if GLOSSY
        alpha *= bsdf_cos(triangle_material(y.triangle), y.albedo, y.normal, incoming, omega) * (2.0 * PI);
#else
        alpha *= 2.0 * cos_y * y.albedo;
#endif
        if (all(equal(alpha, vec3(0.0)))) return;
        Surface next = landed(bundle_step(k, forward, y.position, y.geometric, y.triangle), omega);
        if (!next.found) return;
        vec3 edge = next.position - y.position;
        float t2 = dot(edge, edge), cos_next = abs(dot(next.normal, omega));
        // (1 + a^2 L) / b^2 with a = pdf cos_y / t^2, b = pdf cos_next / t^2, times t^4 / t^4.
        float a = BUNDLE_DIRECTION_PDF * cos_y, b = BUNDLE_DIRECTION_PDF * cos_next;
        mis = min((t2 * t2 + a * a * mis) / max(b * b, 1e-30), MAX_MIS_SHARE);
        y = next;
        incoming = -omega;
        arrived = k;
    }
}

#endif
