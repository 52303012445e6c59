// A BundleSet's per-node attributes for the host (BundleTracer.read): each node of the resolved
// lists expanded by bundle_hits.glsl, as an eye path reaching it sees it, at its slot. Only
// read-back runs it.

#define BUNDLE_LOOKUP
#include "common.glsl"
#include "scene.glsl"
#include "bundle.glsl"
#include "bundle_hits.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

// Per node: the encoded shading normal, the albedo as three half floats, and the triangle (with
// SPLAT_BIT for a splat's).
layout(std430, binding = BINDING_NODE_ATTRIBUTES) writeonly buffer NodeAttributes { uvec4 attributes[]; };

uniform uint invocations;  // K R^2 lists

void main() {
    uint list = linear_id();
    if (list >= invocations) return;
    int k = list_direction(list);
    vec3 origin = line_origin(k, list_pixel(list)), d = frames[k].d.xyz;
    for (uint i = list_first(list); i < list_end(list); i++) {
        BundleHit hit = list_node_hit(origin, d, i);
        uint prim = NODE_REFERENCE == NODE_SPLAT_POINT ? hit.triangle | SPLAT_BIT : hit.triangle;
        attributes[i] = uvec4(encode_normal(hit.normal), packHalf2x16(hit.albedo.rg), packHalf2x16(vec2(hit.albedo.b, 0.0)), prim);
    }
}

#endif
