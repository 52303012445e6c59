// benchmarks/gl_loads.py: each invocation sums LOADS records at hashed indices, read one way per
// variant (SOURCE), and writes the sum so that nothing is compiled away. The records are vec4s
// (a float each for SOURCE_STORAGE_FLOAT); RECORDS is a power of two.

layout(local_size_x = 256) in;
layout(std430, binding = 1) writeonly buffer Sums { float sums[]; };

#if SOURCE == SOURCE_STORAGE_VEC4
layout(std430, binding = 0) readonly buffer Records { vec4 records[]; };
#elif SOURCE == SOURCE_STORAGE_FLOAT
layout(std430, binding = 0) readonly buffer Records { float records[]; };
#elif SOURCE == SOURCE_UNIFORM_VEC4
layout(std140, binding = 0) uniform Records { vec4 records[RECORDS]; };
#elif SOURCE == SOURCE_TEXTURE_VEC4
uniform sampler2D records;  // RGBA32F, 1024 texels a row
#endif

// A 32-bit integer hash (Chris Wellons' lowbias32): indices with no pattern the caches could follow.
uint hash(uint x) {
    x ^= x >> 16; x *= 0x7feb352du; x ^= x >> 15; x *= 0x846ca68bu; x ^= x >> 16;
    return x;
}

void main() {
    uint id = gl_GlobalInvocationID.x;
    vec4 sum = vec4(0.0);
    for (uint k = 0u; k < LOADS; k++) {
        uint i = hash(id * LOADS + k) & (RECORDS - 1u);
#if SOURCE == SOURCE_STORAGE_VEC4 || SOURCE == SOURCE_UNIFORM_VEC4
        sum += records[i];
#elif SOURCE == SOURCE_STORAGE_FLOAT
        sum.x += records[i];
#elif SOURCE == SOURCE_TEXTURE_VEC4
        sum += texelFetch(records, ivec2(i & 1023u, i >> 10u), 0);
#else
        sum.x += float(i);
#endif
    }
    sums[id] = sum.x + sum.y + sum.z + sum.w;
}
