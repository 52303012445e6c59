// Building ray bundles (gpu_impl/bundles.py): the build counters (COUNTER_* slots of
// gpu_impl/layout.py), the per-pixel linked lists the raster passes append nodes to
// (LINKED_LISTS), and the lists' exact-size slot ranges that the compute splatter scatters into
// and the resolve sorts (and merges) into (SLOT_LISTS).

layout(std430, binding = BINDING_COUNTERS) buffer Counters { uint counters[]; };

// A splat seen nearly edge-on covers no line centre (its ellipse has no width); one exactly
// edge-on has no depth plane. Both splatters skip it.
#define MIN_COS 1e-7

#if defined LINKED_LISTS && !defined NODE_KEYS
#define NODE_KEYS  // a linked node is a key too
#endif

#if defined NODE_KEYS
// A node as one 64-bit key that sorts as (depth, reference) does: the depth's order bits
// (common.glsl) in the high word, then the reference with FACING_BIT in the low word. Sorting and
// moving one key per node costs half what a depth and a reference apart cost. The raster passes
// append keys too: one store per fragment and one load per node in the resolve, where a depth
// and a reference apart cost two of each (llvmpipe runs every storage access lane by lane; at
// K = 256, R = 256 on cornell-box the sort pass took a fifth less time, docs/results/decisions.toml: int64-keys).
uint64_t node_key(float depth, uint ref) {
    return (uint64_t(depth_order_bits(depth)) << 32) | uint64_t(ref);
}

float key_depth(uint64_t key) {
    return order_bits_depth(uint(key >> 32));
}

uint key_ref(uint64_t key) {
    return uint(key);
}
#endif

#if defined LINKED_LISTS
layout(std430, binding = BINDING_HEADS) buffer Heads { uint heads[]; };
layout(std430, binding = BINDING_NEXT) buffer Next { uint node_next[]; };
layout(std430, binding = BINDING_LIST_KEYS) buffer ListKeys { uint64_t list_keys[]; };

uniform uint capacity;  // nodes the linked-list buffers hold

#if !defined COMPUTE_SHADER
// Append a node to a list. The counter always counts, but a node is written (and linked) only
// when its slot exists: linking first would corrupt the list. The host reads the counter and
// re-runs the pass with a buffer that fits, so no node is ever lost.
void append_node(uint list, float depth, uint ref) {
    uint index = atomicAdd(counters[COUNTER_NODES], 1u);
    if (index >= capacity) return;
    list_keys[index] = node_key(depth, ref);
    node_next[index] = atomicExchange(heads[list], index);
}
#endif
#endif

#if defined SLOT_LISTS
// List l's slots are nodes[list_offsets[l] .. list_offsets[l + 1]] (exact sizes from the lists'
// counts and a prefix sum), each a node key. list_counts[l] is the list's count, then (the compute
// splatter) the scatter's cursor from the list's end down to its start, then, after the resolve,
// the length of the sorted (and merged) list at the front of its slots, which the eye paths read
// (bundle.glsl).
layout(std430, binding = BINDING_LIST_OFFSETS) buffer ListOffsets { uint list_offsets[]; };
layout(std430, binding = BINDING_NODES) buffer Nodes { uint64_t nodes[]; };
layout(std430, binding = BINDING_LIST_COUNTS) buffer ListCounts { uint list_counts[]; };
#endif

#if defined SPLAT_LINE_RECORDS
// The lines each splat covers, from the compute splatter's count pass to its scatter pass
// (splat_lists.glsl says what each word holds).
struct SplatLines {
    uint box;
    uint mask_low, mask_high;
    float depth, depth_x, depth_y;  // the depth plane (bundle.glsl: depth_plane)
};
layout(std430, binding = BINDING_SPLAT_LINES) buffer SplatLineRecords { SplatLines splat_lines[]; };
// The splats whose lines the count pass could not keep, COUNTER_FOUND_AGAIN of them: the scatter
// finds their lines again in a pass over just these.
layout(std430, binding = BINDING_SPLATS_FOUND_AGAIN) buffer SplatsFoundAgain { uint found_again[]; };
#endif

#if defined SPLAT_QUEUE
// Every splat once, in two runs (splat_points.glsl: queue_splat): from the front, the
// COUNTER_PLAIN_SPLATS that no line cuts; from the back, the COUNTER_CUT_SPLATS cut ones. The count
// pass runs a program of its own over each (splat_lists.glsl: PLAIN_SPLATS).
layout(std430, binding = BINDING_SPLAT_QUEUE) buffer SplatQueue { uint splat_queue[]; };
#endif
