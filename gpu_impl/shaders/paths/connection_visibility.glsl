// The visibility of light vertices from receiver points through the light vertices' shadow maps,
// one invocation per (receiver, vertex) pair: how imperfect shadow maps are measured against exact
// ones (evalkit/metrics/light_visibility.py). A pair that cannot connect (either faces away) is -1.

#define SHADOW_LIGHTS 1
#include "common.glsl"
#include "lights.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

struct Receiver {
    vec4 position;  // xyz relative to the bundle centre
    vec4 normal;    // xyz
};
layout(std430, binding = BINDING_RECEIVERS) readonly buffer Receivers { Receiver receivers[]; };
layout(std430, binding = BINDING_VISIBLE) writeonly buffer Visible { float visible[]; };

uniform uint invocations;  // receivers x vertices
uniform int first_vertex;  // the record of vertex 0
uniform int vertex_count;

void main() {
    uint id = linear_id();
    if (id >= invocations) return;
    uint i = id / uint(vertex_count);
    Light light = lights[first_vertex + int(id % uint(vertex_count))];
    vec3 p = receivers[i].position.xyz, n = receivers[i].normal.xyz;
    vec3 v = light.position.xyz - p;
    vec3 to_light = v * inversesqrt(dot(v, v));
    bool faces = dot(-to_light, light.direction.xyz) > 0.0 && dot(n, to_light) > 0.0;
    visible[id] = faces ? light_vertex_visibility(light, p, n, to_light) : -1.0;
}

#endif
