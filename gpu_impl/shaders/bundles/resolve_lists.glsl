// From the lists a build made to the resolved lists the eye paths read (bundle.glsl): list l's
// nodes sorted at the front of its slot range, list_offsets[l] .. list_offsets[l] +
// list_counts[l]. Each pass runs one invocation per list:
//
//   COUNT_LISTS    linked lists: each list's length into list_counts[] (the prefix sum makes the
//                  slot ranges from them);
//   SORT_LISTS     perfect bundles: linked lists sorted into their slot ranges (nothing merged);
//   MERGE_LISTS    imperfect bundles: each list sorted and its redundant nodes merged, written to
//                  the front of its slot range, its merged length to list_counts[]. The list comes
//                  from the linked lists (FROM_LINKED_LISTS: the raster splatter) or is the slot
//                  range itself, as the compute splatter scattered it. The merged-away nodes' slots
//                  stay unused: moving the lists together would cost a second prefix sum and a
//                  copy of every node, a fifth of the build (benchmarks/bundles.py), for memory
//                  the unmerged lists needed anyway.
//
// A sort or merge is up to four passes (bundles.py: BundleTracer.sort_lists). The first
// (QUEUE_GROUPS) queues the groups of LIST_GROUP consecutive lists that hold a node in
// list_groups[]: over half of atrium's lists are empty, and llvmpipe runs the code of a branch
// that no lane of a SIMD batch takes, so a batch of empty lists cost what a batch of full ones did
// (docs/results/decisions.toml: resolve-list-groups). The second runs over every list of those
// groups and sorts those of up to SHORT_LIST nodes, most of them, in a short program; it
// queues the longer ones in long_lists[], those of up to MEDIUM_LIST nodes from its front and the
// rest from its back, and a pass over each queue (MEDIUM_LISTS, LONG_LISTS) sorts them with a
// network of its size. One program with every list length's code cost its length for every list
// on a CPU rasterizer: at K = 256, R = 256 on cornell-box
// (lists of up to 6 nodes) the sort took 4.8 s a build, 1.7 s with the short program alone
// (docs/results/decisions.toml: two-resolve-programs). The same held for the lists of 9 to 16
// nodes, four in five of those longer than 8 on atrium, sorted by the 32 keys' program.
//
// Lists are sorted by depth, then by reference (node keys, bundle_build.glsl): equal node sets
// give equal lists, whatever order the rasterizer's threads or the scatter's atomics put them in.
//
// Merging (merge_tolerance >= 0): overlapping splats of one plane each put a node on the lines
// they share, at one depth up to float32 rounding. A run of nodes facing the same way along the
// line (FACING_BIT) within merge_tolerance of the run's first node is one surface crossing and
// keeps one node, the run's middle one (its median depth).
// Surfaces facing opposite ways (a thin slab's two sides) are never merged. The nodes kept are
// counted in stripes (STRIPE_KEPT, gpu_impl/layout.py: STRIPED_COUNTERS); perfect bundles count
// coincident duplicates, which are all kept, in COUNTER_REDUNDANT.

#extension GL_ARB_gpu_shader_int64 : require
#include "common.glsl"
#if defined COUNT_LISTS || defined SORT_LISTS || defined FROM_LINKED_LISTS
#define LINKED_LISTS
#endif
#define SLOT_LISTS
#define NODE_KEYS
#include "bundle_build.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

uniform uint invocations;  // K R^2 lists; the queued groups' lists; the queued lists
uniform uint list_count;   // K R^2

// The groups of LIST_GROUP lists that hold a node, COUNTER_LIST_GROUPS of them (QUEUE_GROUPS).
layout(std430, binding = BINDING_LIST_GROUPS) buffer ListGroups { uint list_groups[]; };

#if defined COUNT_LISTS

void main() {
    uint list = linear_id();
    if (list >= invocations) return;
    uint length = 0u;
    for (uint n = heads[list]; n != NO_NODE; n = node_next[n]) length++;
    list_counts[list] = length;
    if (list == 0u) list_counts[invocations] = 0u;  // the scan turns it into the node count
}

#elif defined QUEUE_GROUPS

// Group `group`'s lists queued if one holds a node; else each left with no node: the compute
// splatter's cursor, at the list's start after the scatter, set to 0 (the merge's count) and, off
// it, counted a mismatch as the merge counts it.
void main() {
    uint group = linear_id();
    if (group >= invocations) return;
    uint first = group * uint(LIST_GROUP), end = min(first + uint(LIST_GROUP), list_count);
    if (list_offsets[end] > list_offsets[first]) {
        list_groups[atomicAdd(counters[COUNTER_LIST_GROUPS], 1u)] = group;
        return;
    }
#if defined MERGE_LISTS && !defined FROM_LINKED_LISTS
    for (uint list = first; list < end; list++) {
        if (list_counts[list] != list_offsets[list]) atomicAdd(counters[COUNTER_MISMATCH], 1u);
        list_counts[list] = 0u;
    }
#endif
}

#elif defined SORT_LISTS || defined MERGE_LISTS

// Lists of up to NETWORK nodes are sorted in registers by a sorting network (Batcher's odd-even
// merge sort: every index a constant, so nothing is addressed indirectly, which a CPU rasterizer
// runs many times faster); its first 19 compare-exchanges sort 8 keys (the first pass's network),
// the first 63 sort 16 (the medium lists'), all 191 sort 32 (the long lists'). Longer lists (a
// deep stack of surfaces, heavily overlapping splats) are insertion-sorted in place, in global
// memory, by the long lists' pass.
#if SHORT_LIST != 8 || MEDIUM_LIST != 16 || SORT_NETWORK != 32
#error "the sorting networks below are written out for 8, 16 and 32 keys (gpu_impl/layout.py)"
#endif
#if defined LONG_LISTS
#define NETWORK uint(SORT_NETWORK)
#elif defined MEDIUM_LISTS
#define NETWORK uint(MEDIUM_LIST)
#else
#define NETWORK uint(SHORT_LIST)
#endif
#if defined MEDIUM_LISTS || defined LONG_LISTS
#define QUEUED_LISTS  // a pass over the lists the first one queued
#endif
uint64_t key[NETWORK];
#define PADDING 0xFFFFFFFFFFFFFFFFul  // sorts last

// The first pass's queues of the lists it leaves to the others: the medium lists from the front,
// counted in COUNTER_MEDIUM_LISTS, the long ones from the back, counted in COUNTER_LONG_LISTS.
layout(std430, binding = BINDING_LONG_LISTS) buffer LongLists { uint long_lists[]; };
#define LONG_QUEUE(i) long_lists[uint(long_lists.length()) - 1u - (i)]

// M(i) for i = 0 .. NETWORK - 1 (and backwards), written out so that every index is a constant, in
// blocks of 8, 8 and 16.
#define NODES_0(M) M(0u) M(1u) M(2u) M(3u) M(4u) M(5u) M(6u) M(7u)
#define NODES_8(M) M(8u) M(9u) M(10u) M(11u) M(12u) M(13u) M(14u) M(15u)
#define NODES_16(M) M(16u) M(17u) M(18u) M(19u) M(20u) M(21u) M(22u) M(23u) M(24u) M(25u) M(26u) M(27u) M(28u) M(29u) M(30u) M(31u)
#define NODES_8_BACKWARDS(M) M(15u) M(14u) M(13u) M(12u) M(11u) M(10u) M(9u) M(8u)
#define NODES_0_BACKWARDS(M) M(7u) M(6u) M(5u) M(4u) M(3u) M(2u) M(1u) M(0u)
#if defined LONG_LISTS
#define FOR_NODES(M) NODES_0(M) NODES_8(M) NODES_16(M)
#define FOR_NODES_BACKWARDS(M) M(31u) M(30u) M(29u) M(28u) M(27u) M(26u) M(25u) M(24u) M(23u) M(22u) \
    M(21u) M(20u) M(19u) M(18u) M(17u) M(16u) NODES_8_BACKWARDS(M) NODES_0_BACKWARDS(M)
#elif defined MEDIUM_LISTS
#define FOR_NODES(M) NODES_0(M) NODES_8(M)
#define FOR_NODES_BACKWARDS(M) NODES_8_BACKWARDS(M) NODES_0_BACKWARDS(M)
#else
#define FOR_NODES(M) NODES_0(M)
#define FOR_NODES_BACKWARDS(M) NODES_0_BACKWARDS(M)
#endif

#define CE(a, b) { uint64_t lower = min(key[a], key[b]); key[b] = max(key[a], key[b]); key[a] = lower; }

void sort_network() {
    CE(0, 1) CE(2, 3) CE(0, 2) CE(1, 3) CE(1, 2) CE(4, 5) CE(6, 7) CE(4, 6) CE(5, 7) CE(5, 6)
    CE(0, 4) CE(2, 6) CE(2, 4) CE(1, 5) CE(3, 7) CE(3, 5) CE(1, 2) CE(3, 4) CE(5, 6)
#if defined QUEUED_LISTS
    {
        CE(8, 9) CE(10, 11) CE(8, 10) CE(9, 11) CE(9, 10) CE(12, 13) CE(14, 15) CE(12, 14) CE(13, 15) CE(13, 14)
        CE(8, 12) CE(10, 14) CE(10, 12) CE(9, 13) CE(11, 15) CE(11, 13) CE(9, 10) CE(11, 12) CE(13, 14) CE(0, 8)
        CE(4, 12) CE(4, 8) CE(2, 10) CE(6, 14) CE(6, 10) CE(2, 4) CE(6, 8) CE(10, 12) CE(1, 9) CE(5, 13)
        CE(5, 9) CE(3, 11) CE(7, 15) CE(7, 11) CE(3, 5) CE(7, 9) CE(11, 13) CE(1, 2) CE(3, 4) CE(5, 6)
        CE(7, 8) CE(9, 10) CE(11, 12) CE(13, 14)
    }
#endif
#if defined LONG_LISTS
    {
        CE(16, 17) CE(18, 19) CE(16, 18) CE(17, 19) CE(17, 18) CE(20, 21) CE(22, 23) CE(20, 22) CE(21, 23) CE(21, 22)
        CE(16, 20) CE(18, 22) CE(18, 20) CE(17, 21) CE(19, 23) CE(19, 21) CE(17, 18) CE(19, 20) CE(21, 22) CE(24, 25)
        CE(26, 27) CE(24, 26) CE(25, 27) CE(25, 26) CE(28, 29) CE(30, 31) CE(28, 30) CE(29, 31) CE(29, 30) CE(24, 28)
        CE(26, 30) CE(26, 28) CE(25, 29) CE(27, 31) CE(27, 29) CE(25, 26) CE(27, 28) CE(29, 30) CE(16, 24) CE(20, 28)
        CE(20, 24) CE(18, 26) CE(22, 30) CE(22, 26) CE(18, 20) CE(22, 24) CE(26, 28) CE(17, 25) CE(21, 29) CE(21, 25)
        CE(19, 27) CE(23, 31) CE(23, 27) CE(19, 21) CE(23, 25) CE(27, 29) CE(17, 18) CE(19, 20) CE(21, 22) CE(23, 24)
        CE(25, 26) CE(27, 28) CE(29, 30) CE(0, 16) CE(8, 24) CE(8, 16) CE(4, 20) CE(12, 28) CE(12, 20) CE(4, 8)
        CE(12, 16) CE(20, 24) CE(2, 18) CE(10, 26) CE(10, 18) CE(6, 22) CE(14, 30) CE(14, 22) CE(6, 10) CE(14, 18)
        CE(22, 26) CE(2, 4) CE(6, 8) CE(10, 12) CE(14, 16) CE(18, 20) CE(22, 24) CE(26, 28) CE(1, 17) CE(9, 25)
        CE(9, 17) CE(5, 21) CE(13, 29) CE(13, 21) CE(5, 9) CE(13, 17) CE(21, 25) CE(3, 19) CE(11, 27) CE(11, 19)
        CE(7, 23) CE(15, 31) CE(15, 23) CE(7, 11) CE(15, 19) CE(23, 27) CE(3, 5) CE(7, 9) CE(11, 13) CE(15, 17)
        CE(19, 21) CE(23, 25) CE(27, 29) CE(1, 2) CE(3, 4) CE(5, 6) CE(7, 8) CE(9, 10) CE(11, 12) CE(13, 14)
        CE(15, 16) CE(17, 18) CE(19, 20) CE(21, 22) CE(23, 24) CE(25, 26) CE(27, 28) CE(29, 30)
    }
#endif
}

#if defined MERGE_LISTS
uniform float merge_tolerance;  // in scene units; negative: merge nothing

// Whether `next` starts a new run after a run that started with `start`.
bool starts_run(uint64_t next, uint64_t start) {
    return merge_tolerance < 0.0 || ((key_ref(next) ^ key_ref(start)) & FACING_BIT) != 0u
        || key_depth(next) - key_depth(start) > merge_tolerance;
}
#endif

// Insert `k` into the sorted keys at first .. first + count, in global memory.
void insert_global(uint first, uint count, uint64_t k) {
    uint j = count;
    for (; j > 0u && k < nodes[first + j - 1u]; j--) nodes[first + j] = nodes[first + j - 1u];
    nodes[first + j] = k;
}

void main() {
#if defined LONG_LISTS
    if (linear_id() >= invocations) return;
    uint list = LONG_QUEUE(linear_id());
#elif defined MEDIUM_LISTS
    if (linear_id() >= invocations) return;
    uint list = long_lists[linear_id()];
#else
    if (linear_id() >= invocations) return;
    uint list = list_groups[linear_id() / uint(LIST_GROUP)] * uint(LIST_GROUP) + linear_id() % uint(LIST_GROUP);
    if (list >= list_count) return;
#endif
    uint first = list_offsets[list], length = list_offsets[list + 1u] - first;
#if defined MERGE_LISTS && !defined FROM_LINKED_LISTS && !defined QUEUED_LISTS
    if (list_counts[list] != first) atomicAdd(counters[COUNTER_MISMATCH], 1u);  // the scatter's cursor is off the list's start
#endif
#if !defined QUEUED_LISTS
    if (length > NETWORK) {
        if (length > uint(MEDIUM_LIST)) LONG_QUEUE(atomicAdd(counters[COUNTER_LONG_LISTS], 1u)) = list;
        else long_lists[atomicAdd(counters[COUNTER_MEDIUM_LISTS], 1u)] = list;
        return;
    }
#endif
    uint kept = length, redundant = 0u;
    if (length == 0u) {
    } else if (length <= NETWORK) {
        // Load (padding sorts last), sort in registers.
#if defined LINKED_LISTS
        uint n = heads[list];
#define LOAD(i) { bool here = i < length; key[i] = here ? list_keys[n] : PADDING; if (here) n = node_next[n]; }
#else
#define LOAD(i) { key[i] = i < length ? nodes[first + i] : PADDING; }
#endif
        FOR_NODES(LOAD)
        sort_network();
#if defined SORT_LISTS
        uint64_t previous = key[0];
#define STORE(i) if (i < length) { if (i > 0u && key_depth(key[i]) == key_depth(previous)) redundant++; previous = key[i]; nodes[first + i] = key[i]; }
        FOR_NODES(STORE)  // counting coincident duplicates, all kept
#else
        // Runs (see the top) and each run's middle node, with constant indices only: the nodes
        // that start a run (a bit each), then backwards the middle of each run, then those written.
        uint starts = 1u;
        uint64_t start = key[0];
#define RUN_START(i) if (i > 0u && i < length && starts_run(key[i], start)) { starts |= 1u << i; start = key[i]; }
        FOR_NODES(RUN_START)
        uint middles = 0u, end = length - 1u;
#define MIDDLE(i) if (i < length) { if (i + 1u < length && (starts & (2u << i)) != 0u) end = i; \
            if (i == (uint(findMSB(starts & (0xFFFFFFFFu >> (31u - i)))) + end) / 2u) middles |= 1u << i; }
        FOR_NODES_BACKWARDS(MIDDLE)
        kept = 0u;
#define KEEP(i) if ((middles & (1u << i)) != 0u) { nodes[first + kept] = key[i]; kept++; }
        FOR_NODES(KEEP)
#endif
    }
#if defined LONG_LISTS
    else {
        // Longer than the network: sorted in place, in global memory.
#if defined LINKED_LISTS
        uint n = heads[list];
        for (uint i = 0u; i < length; i++, n = node_next[n]) insert_global(first, i, list_keys[n]);
#else
        for (uint i = 1u; i < length; i++) insert_global(first, i, nodes[first + i]);
#endif
#if defined SORT_LISTS
        for (uint i = 1u; i < length; i++) if (key_depth(nodes[first + i]) == key_depth(nodes[first + i - 1u])) redundant++;
#else
        // Each run's middle node to the front; the write index never passes the read index.
        kept = 0u;
        uint start = 0u;
        for (uint i = 1u; i <= length; i++) {
            if (i == length || starts_run(nodes[first + i], nodes[first + start])) {
                uint64_t middle = nodes[first + (start + i - 1u) / 2u];
                nodes[first + kept] = middle;
                kept++;
                start = i;
            }
        }
#endif
    }
#endif
    // Few atomics: a CPU rasterizer runs one per invocation. The kept count and the longest list
    // are striped by workgroup (gpu_impl/layout.py: STRIPED_COUNTERS), so CPU threads do not take
    // turns at one cache line.
    uint stripe = uint(STRIPE_WORDS) * (1u + gl_WorkGroupID.x % uint(COUNTER_STRIPES));
#if defined MERGE_LISTS
    list_counts[list] = kept;
    if (kept > 0u) atomicAdd(counters[stripe + uint(STRIPE_KEPT)], kept);
#else
    if (redundant > 0u) atomicAdd(counters[COUNTER_REDUNDANT], redundant);
#endif
    uint longest = stripe + uint(STRIPE_MAX_LENGTH);
    if (kept > counters[longest]) atomicMax(counters[longest], kept);
}

#endif
#endif
