// The direct light every bundle node reflects toward either side of its surface, computed once
// per frame with the shadow maps (lights.glsl), so an eye path that reaches the node reads it
// instead of testing visibility again. Run only when the scene has shadow-mapped lights.

#define BUNDLE_LOOKUP
#define SCENE_MATERIALS_ONLY
#include "common.glsl"
#include "scene.glsl"
#include "bundle.glsl"
#include "lights.glsl"
#include "paths.glsl"

#if defined COMPUTE_SHADER
#if !SHADOW_LIGHTS
#error "node_radiance.glsl without SHADOW_LIGHTS: nodes reflect no shadow-mapped light, the pass is skipped"
#endif

layout(local_size_x = LOCAL_SIZE) in;

uniform uint invocations;  // K R^2 lists

void store_radiance(uint index, uint side, vec3 value) {
    uint i = radiance_index(index, side);
    node_radiance[i] = value.r;
    node_radiance[i + 1u] = value.g;
    node_radiance[i + 2u] = value.b;
}

// One list per invocation: its nodes share the line, so the line origin is computed once.
void main() {
    uint list = linear_id();
    if (list >= invocations) return;
    uint first = offsets[list], last = offsets[list + 1u];
    if (first == last) return;
    uint per_bundle = uint(resolution * resolution);
    int k = int(list / per_bundle);
    uint cell = list % per_bundle;
    ivec2 pixel = ivec2(cell % uint(resolution), cell / uint(resolution));
    vec3 o = line_origin(k, pixel), d = frames[k].d.xyz;
    for (uint i = first; i < last; i++) {
        uint node = sorted_node[i];
        vec3 p = o + sorted_depth[i] * d;
        vec3 n = decode_normal(node_normal[node]);
        vec3 brdf = unpack_albedo(node_albedo[node]) * INV_PI;
        store_radiance(i, 0u, brdf * light_irradiance(p, n));
#if NODE_SIDES == 2
        bool twosided = material_twosided(triangle_material(node_prim[node] & ~SPLAT_BIT));
        store_radiance(i, 1u, twosided ? brdf * light_irradiance(p, -n) : vec3(0.0));
#endif
    }
}

#endif
