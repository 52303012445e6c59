// The G-buffer samples (gbuffer.glsl stored the visible triangle of each): the camera ray of each
// sample meets its triangle exactly, giving position, shading normal and textured albedo; emission
// seen directly and shadow-mapped direct light go to the direct image, the environment where no
// surface is seen, and the hit becomes the first vertex of the sample's eye paths.

#include "common.glsl"
#include "scene.glsl"
#include "bsdf.glsl"
#include "lights.glsl"
#include "environment.glsl"
#include "paths.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

uniform uint invocations;       // G-buffer samples x paths_per_sample
uniform usampler2D gbuffer;     // primitive id + 1 per sample
uniform ivec2 gbuffer_size;     // W s x H s
uniform uint paths_per_sample;
uniform vec3 camera_origin;     // relative to the bundle centre
uniform mat3 camera_to_world;   // Mitsuba's camera space: +x left, +y up, +z forward
uniform vec2 tan_half_fov;      // along x and y; an orthographic camera's half extent at its plane
uniform bool orthographic;      // rays along camera_to_world's +z from points of its plane
uniform vec2 subpixel;          // this frame's sample position inside each G-buffer pixel, in [0, 1)^2

void main() {
    uint id = linear_id();
    if (id >= invocations) return;
    uint s = id / paths_per_sample;
    ivec2 xy = ivec2(s % uint(gbuffer_size.x), s / uint(gbuffer_size.x));
    vec2 film = (vec2(xy) + subpixel) / vec2(gbuffer_size);  // (0, 0) is the image's top left
    vec2 at = (1.0 - 2.0 * film) * tan_half_fov;
    vec3 eye = orthographic ? camera_origin + camera_to_world * vec3(at, 0.0) : camera_origin;
    vec3 dir = normalize(camera_to_world * (orthographic ? vec3(0.0, 0.0, 1.0) : vec3(at, 1.0)));
    uint visible = texelFetch(gbuffer, xy, 0).r;
    // A sample's paths share its first vertex, so what it sees and what reaches it through shadow maps
    // and connections is the same for each: the first path gathers that once, counted for all of
    // them (the resolve averages over the paths). It was a sample's costliest work, done spp times.
    bool gathers = id % paths_per_sample == 0u;
    float share = gathers ? float(paths_per_sample) : 0.0;
    Path path = Path(vec3(0.0), 0u, vec3(0.0), PATH_ENDED, vec3(0.0), 0u, vec4(0.0));
    vec3 direct = vec3(0.0);
    if (visible == 0u) {
#if ENVIRONMENT != ENVIRONMENT_NONE
        direct = environment(dir);
#endif
    } else {
        uint t = visible - 1u;
        vec3 p0, p1, p2;
        uvec3 v = triangle_corners(t, p0, p1, p2);
        vec3 e1 = p1 - p0, e2 = p2 - p0;
        // Moller-Trumbore: the camera ray meets the triangle's plane at depth, barycentrics (b1, b2).
        vec3 so = eye - p0, pv = cross(dir, e2), qv = cross(so, e1);
        float inv = 1.0 / dot(e1, pv);
        float b1 = dot(so, pv) * inv, b2 = dot(dir, qv) * inv, depth = dot(e2, qv) * inv;
        vec3 n = shading_normal(t, v, b1, b2);
        uint m = triangle_material(t);
        bool front = dot(n, dir) < 0.0;
        if (front || material_twosided(m)) {
            if (front) direct = materials[m].emission.rgb;  // emitters emit from their front only
            else n = -n;
            vec3 albedo = material_albedo(m, v, vec2(b1, b2));
#if SHADOW_LIGHTS && GLOSSY
            if (gathers) direct += light_reflected(eye + depth * dir, n, 0.0, m, albedo, -dir);
#elif SHADOW_LIGHTS
            if (gathers) direct += albedo * INV_PI * light_irradiance(eye + depth * dir, n, 0.0);
#endif
#if BIDIRECTIONAL && GLOSSY
            // Connections from the first eye vertex to light path vertices are indirect light.
            if (gathers) sums[id].indirect.rgb += share * connections(eye + depth * dir, n, 0, 0.0, m, albedo, -dir);
#elif BIDIRECTIONAL
            if (gathers) sums[id].indirect.rgb += share * albedo * INV_PI * connections(eye + depth * dir, n, 0, 0.0);
#endif
            path = Path(eye + depth * dir, encode_normal(n), vec3(1.0), PATH_FROM_CAMERA, albedo,
                        dot(triangle_normal(t), dir) < 0.0 ? t : t | PATH_BACK, vec4(-dir, 0.0));
            atomicAdd(alive_paths, 1u);
        }
        // else: the back of a one-sided surface, black as in Mitsuba; the path ends.
    }
    sums[id].direct.rgb += share * direct;
    paths[id] = path;
#if BIDIRECTIONAL
    path_mis[id] = 0.0;  // no strategy has fewer eye vertices than the G-buffer sample
#endif
}

#endif
