// The environment that escaped paths see (gpu_impl/lights.py): a constant radiance or a lat-long
// map, in Mitsuba's units and orientation. Compiled per scene: with ENVIRONMENT_NONE nothing here
// exists.

// ENVIRONMENT is one of ENVIRONMENT_NONE, ENVIRONMENT_CONSTANT, ENVIRONMENT_MAP (gpu_impl/layout.py);
// ENVIRONMENT_SAMPLES 1 where the eye paths draw directions from the map (next-event estimation).
#ifndef ENVIRONMENT_SAMPLES
#define ENVIRONMENT_SAMPLES 0
#endif

#if ENVIRONMENT == ENVIRONMENT_MAP
// The map is (H, W, 3) linear rgb in the scene's texel buffer (scene.glsl), from envmap_first on.
uniform uint envmap_first;
uniform ivec2 envmap_size;        // W, H
uniform mat3 environment_to_local;
#endif
#if ENVIRONMENT != ENVIRONMENT_NONE
uniform vec3 environment_radiance;  // the constant's radiance, or the map's scale

#if ENVIRONMENT == ENVIRONMENT_MAP
vec3 envmap_texel(int x, int y) {
    return texel(envmap_first, uint(envmap_size.x), x, y);
}
#endif

// The radiance arriving along -dir from the environment (dir: the direction a path leaves in).
// The lat-long map uses Mitsuba's orientation, u = atan2(x, -z) / (2 pi), v = acos(y) / pi in
// the map's local frame, and Mitsuba's texel positions (docs/results/decisions.toml:
// mitsuba-envmap-texels; the sky pixels of tests/test_renderer.py::test_environment_light_matches_mitsuba):
// column i at u = (i + 0.5) / W, wrapped, but row j at v = j / (H - 1), so the first and last rows
// sit on the poles; bilinear.
#if ENVIRONMENT == ENVIRONMENT_MAP
vec2 environment_uv(vec3 dir) {
    vec3 v = normalize(environment_to_local * dir);
    vec2 uv = vec2(atan(v.x, -v.z) * (0.5 / 3.141592653589793), acos(clamp(v.y, -1.0, 1.0)) / 3.141592653589793);
    uv.x -= floor(uv.x);
    return uv;
}
#endif

vec3 environment(vec3 dir) {
#if ENVIRONMENT == ENVIRONMENT_CONSTANT
    return environment_radiance;
#else
    vec2 uv = environment_uv(dir);
    vec2 p = vec2(uv.x * float(envmap_size.x) - 0.5, uv.y * float(envmap_size.y - 1));
    vec2 f = floor(p), w = p - f;
    int x0 = wrap_texel(int(f.x), envmap_size.x, false, false), x1 = wrap_texel(int(f.x) + 1, envmap_size.x, false, false);
    int y0 = clamp(int(f.y), 0, envmap_size.y - 1), y1 = clamp(int(f.y) + 1, 0, envmap_size.y - 1);
    vec3 c = mix(mix(envmap_texel(x0, y0), envmap_texel(x1, y0), w.x), mix(envmap_texel(x0, y1), envmap_texel(x1, y1), w.x), w.y);
    return environment_radiance * c;
#endif
}

#if ENVIRONMENT_SAMPLES
// Next-event estimation of the environment map (gpu_impl/lights.py: EnvironmentSamples): the
// density per solid angle of each cell of the map, texel columns by the rows between texel rows.
layout(std430, binding = BINDING_ENVIRONMENT_PDF) readonly buffer EnvironmentPdf { float environment_pdf[]; };
uniform float environment_sample_count;  // M

// M p(dir): the environment samples' density of the direction a path leaves in, for MIS.
float environment_sample_density(vec3 dir) {
    vec2 uv = environment_uv(dir);
    int i = min(int(uv.x * float(envmap_size.x)), envmap_size.x - 1);
    int j = min(int(uv.y * float(envmap_size.y - 1)), envmap_size.y - 2);
    return environment_sample_count * environment_pdf[j * envmap_size.x + i];
}
#endif
#endif
