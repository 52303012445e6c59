// Linked lists to sorted CSR: COUNT_LISTS measures each list, prefix_sum.glsl turns the lengths
// into offsets, and SORT_LISTS writes each list's node indices and depths in order, sorted by
// depth, then primitive, then the remaining node words. Sorting on every field makes equal node sets give
// equal lists, whatever order the rasterizer's threads appended them in.
//
// SORT_LISTS also counts redundant nodes: a node that follows one facing the same way within
// redundant_tolerance in depth. With splats that is one surface seen through overlapping splats.

#include "common.glsl"
#include "bundle.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

layout(std430, binding = BINDING_OFFSETS) buffer Offsets { uint offsets[]; };  // lengths, then CSR offsets
layout(std430, binding = BINDING_SORTED_NODE) buffer SortedNode { uint sorted_node[]; };
layout(std430, binding = BINDING_SORTED_DEPTH) buffer SortedDepth { float sorted_depth[]; };

uniform uint invocations;  // K * R * R lists
uniform float redundant_tolerance;

#if defined COUNT_LISTS

void main() {
    uint list = linear_id();
    if (list >= invocations) return;
    uint length = 0u;
    for (uint n = heads[list]; n != NO_NODE; n = node_next[n]) length++;
    offsets[list] = length;
    if (list == 0u) offsets[invocations] = 0u;  // the scan turns it into the node count
}

#elif defined SORT_LISTS

// A strict total order on nodes: depth, then primitive, then normal and albedo bits.
bool node_less(uint a, uint b) {
    if (node_depth[a] != node_depth[b]) return node_depth[a] < node_depth[b];
    if (node_prim[a] != node_prim[b]) return node_prim[a] < node_prim[b];
    if (node_normal[a] != node_normal[b]) return node_normal[a] < node_normal[b];
    if (node_albedo[a].x != node_albedo[b].x) return node_albedo[a].x < node_albedo[b].x;
    return node_albedo[a].y < node_albedo[b].y;
}

// node_less with a's depth already at hand: depths decide almost every comparison.
bool node_less_at(float depth_a, uint a, float depth_b, uint b) {
    return depth_a != depth_b ? depth_a < depth_b : node_less(a, b);
}

// Lists up to this long are sorted in private memory; longer ones (rare: a deep stack of
// surfaces or heavily overlapping splats) in their CSR slots in global memory.
#define PRIVATE_LIST 64u

void main() {
    uint list = linear_id();
    if (list >= invocations) return;
    uint first = offsets[list];
    uint length = offsets[list + 1u] - first;
    if (length <= PRIVATE_LIST) {
        float depth[PRIVATE_LIST];
        uint node[PRIVATE_LIST];
        uint n = heads[list];
        for (uint i = 0u; i < length; i++, n = node_next[n]) {
            float d = node_depth[n];
            uint j = i;
            for (; j > 0u && node_less_at(d, n, depth[j - 1u], node[j - 1u]); j--) {
                depth[j] = depth[j - 1u];
                node[j] = node[j - 1u];
            }
            depth[j] = d;
            node[j] = n;
        }
        for (uint i = 0u; i < length; i++) {
            sorted_node[first + i] = node[i];
            sorted_depth[first + i] = depth[i];
        }
    } else {
        uint i = 0u;
        for (uint n = heads[list]; n != NO_NODE; n = node_next[n], i++) {
            float d = node_depth[n];
            uint j = i;
            for (; j > 0u && node_less_at(d, n, sorted_depth[first + j - 1u], sorted_node[first + j - 1u]); j--) {
                sorted_node[first + j] = sorted_node[first + j - 1u];
                sorted_depth[first + j] = sorted_depth[first + j - 1u];
            }
            sorted_node[first + j] = n;
            sorted_depth[first + j] = d;
        }
    }
    uint redundant = 0u;
    for (uint i = 1u; i < length; i++) {
        if (sorted_depth[first + i] - sorted_depth[first + i - 1u] <= redundant_tolerance
            && dot(decode_normal(node_normal[sorted_node[first + i]]),
                   decode_normal(node_normal[sorted_node[first + i - 1u]])) > 0.0) redundant++;
    }
    if (redundant > 0u) atomicAdd(counters[COUNTER_REDUNDANT], redundant);
    atomicMax(counters[COUNTER_MAX_LENGTH], length);
}

#endif
#endif
