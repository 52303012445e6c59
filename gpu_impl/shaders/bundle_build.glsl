// Building ray bundles (gpu_impl/bundles.py): the build counters (COUNTER_* slots of
// gpu_impl/layout.py), the per-pixel linked lists the raster passes append nodes to
// (LINKED_LISTS), and the raw lists in exact-size CSR that the compute splatter scatters into and
// the resolve sorts and merges (RAW_LISTS).

layout(std430, binding = BINDING_COUNTERS) buffer Counters { uint counters[]; };

#if defined LINKED_LISTS
layout(std430, binding = BINDING_HEADS) buffer Heads { uint heads[]; };
layout(std430, binding = BINDING_NEXT) buffer Next { uint node_next[]; };
layout(std430, binding = BINDING_LIST_DEPTH) buffer ListDepth { float list_depth[]; };
layout(std430, binding = BINDING_LIST_REF) buffer ListRef { uint list_ref[]; };

uniform uint capacity;  // nodes the linked-list buffers hold

#if !defined COMPUTE_SHADER
// Append a node to a list. The counter always counts, but a node is written (and linked) only
// when its slot exists: linking first would corrupt the list. The host reads the counter and
// re-runs the pass with a buffer that fits, so no node is ever lost.
void append_node(uint list, float depth, uint ref) {
    uint index = atomicAdd(counters[COUNTER_NODES], 1u);
    if (index >= capacity) return;
    list_depth[index] = depth;
    list_ref[index] = ref;
    node_next[index] = atomicExchange(heads[list], index);
}
#endif
#endif

#if defined RAW_LISTS
// List l's raw nodes are raw_nodes[raw_offsets[l] .. raw_offsets[l + 1]] (exact sizes from a count
// pass and a prefix sum), each a node key. list_counts[l] is the count pass's count, then the
// scatter's cursor (from the list's end down to its start), then, after the merge, the list's
// merged length.
layout(std430, binding = BINDING_RAW_OFFSETS) buffer RawOffsets { uint raw_offsets[]; };
layout(std430, binding = BINDING_RAW_NODES) buffer RawNodes { uint64_t raw_nodes[]; };
layout(std430, binding = BINDING_LIST_COUNTS) buffer ListCounts { uint list_counts[]; };
#endif

#if defined NODE_KEYS
// A node as one 64-bit key that sorts as (depth, reference) does: the depth's bits turned so that
// they order as the floats do (high word), then the reference with FACING_BIT (low word). Sorting
// and moving one key per node costs half what a depth and a reference apart cost.
uint64_t node_key(float depth, uint ref) {
    uint bits = floatBitsToUint(depth);
    bits ^= (bits & 0x80000000u) != 0u ? 0xFFFFFFFFu : 0x80000000u;
    return (uint64_t(bits) << 32) | uint64_t(ref);
}

float key_depth(uint64_t key) {
    uint bits = uint(key >> 32);
    bits ^= (bits & 0x80000000u) != 0u ? 0x80000000u : 0xFFFFFFFFu;
    return uintBitsToFloat(bits);
}

uint key_ref(uint64_t key) {
    return uint(key);
}
#endif
