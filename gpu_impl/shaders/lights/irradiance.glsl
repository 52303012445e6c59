// The shadow-mapped light (lights.glsl) reaching every splat point of imperfect bundles, at the
// point with the splat's normal: the light of every node its splat makes, on the front and, for a
// two-sided material, the back. The renderer runs it only when that costs less than lighting each
// path's hits where they land (gpu_impl/renderer.py); the eye paths multiply it by the albedo they
// find at the hit. Perfect bundles' hits are lit where each ray lands, which no node's light could
// follow.

#define NODE_REFERENCE NODE_SPLAT_POINT
#define BUNDLE_LOOKUP
#define PRECOMPUTED_IRRADIANCE
#include "common.glsl"
#include "scene.glsl"
#include "bundle.glsl"
#include "bundle_hits.glsl"
#include "lights.glsl"
#include "paths.glsl"

#if defined COMPUTE_SHADER
#if !SHADOW_LIGHTS
#error "irradiance.glsl without SHADOW_LIGHTS: no shadow-mapped light reaches anything, the pass is skipped"
#endif

layout(local_size_x = LOCAL_SIZE) in;

uniform uint invocations;  // K N points

void store_irradiance(uint item, vec3 position, vec3 normal, uint triangle) {
    vec3 front = light_irradiance(position, normal, 0.0);
    uint i = irradiance_index(item, 0u);
    irradiance[i] = front.r;
    irradiance[i + 1u] = front.g;
    irradiance[i + 2u] = front.b;
#if NODE_SIDES == 2
    vec3 back = material_twosided(triangle_material(triangle)) ? light_irradiance(position, -normal, 0.0) : vec3(0.0);
    i = irradiance_index(item, 1u);
    irradiance[i] = back.r;
    irradiance[i + 1u] = back.g;
    irradiance[i + 2u] = back.b;
#endif
}

void main() {
    uint id = linear_id();
    if (id >= invocations) return;
    SplatSource s = splat_source(id);
    store_irradiance(id, s.centre, shading_normal(s.triangle, s.vertices, s.b.x, s.b.y), s.triangle);
}

#endif
