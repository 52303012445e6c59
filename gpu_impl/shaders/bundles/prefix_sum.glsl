// Exclusive prefix sum of uints in place, in blocks of PER_THREAD * LOCAL_SIZE values: SCAN_BLOCKS scans
// each block and writes its total to block_sums; the host scans block_sums the same way
// (recursively) and ADD_BLOCK_OFFSETS adds each block's offset. This turns list lengths into
// list offsets on the GPU, with no round-trip.

#include "common.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

layout(std430, binding = BINDING_SCAN_DATA) buffer ScanData { uint values[]; };
layout(std430, binding = BINDING_SCAN_SUMS) buffer ScanSums { uint block_sums[]; };

uniform uint count;  // values to scan

// SCAN_PER_THREAD (16, gpu_impl/layout.py) values per invocation: a CPU rasterizer pays for every
// workgroup barrier, and blocks of 4096 values need a quarter of the barriers blocks of 1024 did
// (4.19 M list counts: 14 ms, was 36).
#define PER_THREAD SCAN_PER_THREAD
#define BLOCK (PER_THREAD * uint(LOCAL_SIZE))

uint block_index() {
    return gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
}

#if defined SCAN_BLOCKS

shared uint partial[LOCAL_SIZE];

void main() {
    uint base = block_index() * BLOCK + gl_LocalInvocationID.x * PER_THREAD;
    uint v[PER_THREAD];
    uint total = 0u;
    for (uint j = 0u; j < PER_THREAD; j++) {
        v[j] = base + j < count ? values[base + j] : 0u;
        total += v[j];
    }
    partial[gl_LocalInvocationID.x] = total;
    barrier();
    // Hillis-Steele inclusive scan of the per-thread totals.
    for (uint offset = 1u; offset < LOCAL_SIZE; offset <<= 1u) {
        uint add = gl_LocalInvocationID.x >= offset ? partial[gl_LocalInvocationID.x - offset] : 0u;
        barrier();
        partial[gl_LocalInvocationID.x] += add;
        barrier();
    }
    uint running = partial[gl_LocalInvocationID.x] - total;
    for (uint j = 0u; j < PER_THREAD; j++) {
        if (base + j < count) values[base + j] = running;
        running += v[j];
    }
    if (gl_LocalInvocationID.x == LOCAL_SIZE - 1u) block_sums[block_index()] = partial[LOCAL_SIZE - 1u];
}

#elif defined ADD_BLOCK_OFFSETS

void main() {
    uint i = linear_id();
    if (i < count) values[i] += block_sums[i / BLOCK];
}

#endif
#endif
