// Ray bundles: the orthographic frames of the K directions, the atlas that draws them all in one
// call, and the per-pixel linked lists that the raster passes append nodes to.
//
// A node is stored as structure-of-arrays (one buffer per field): the eye-path lookup's binary
// search then reads only depths, and no single buffer grows past a driver's storage block limit
// as quickly. List building costs 24 bytes per node, the sorted CSR index 8 more.
//
// The eye-path passes define BUNDLE_LOOKUP: they read the sorted lists and the node fields, and
// leave out the list-building buffers (a compute shader may use at most 16 storage blocks).

struct BundleFrame {
    vec4 u;  // xyz: axis u, w: grid jitter along u in pixels
    vec4 v;  // xyz: axis v, w: grid jitter along v in pixels
    vec4 d;  // xyz: the direction
};

layout(std430, binding = BINDING_FRAMES) readonly buffer Frames { BundleFrame frames[]; };
layout(std430, binding = BINDING_NODE_PRIM) buffer NodePrim { uint node_prim[]; };
layout(std430, binding = BINDING_NODE_NORMAL) buffer NodeNormal { uint node_normal[]; };
layout(std430, binding = BINDING_NODE_ALBEDO) buffer NodeAlbedo { uvec2 node_albedo[]; };
#if defined BUNDLE_LOOKUP
// The sorted CSR (resolve_lists.glsl): list l holds sorted_node[offsets[l] .. offsets[l + 1]).
layout(std430, binding = BINDING_OFFSETS) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = BINDING_SORTED_NODE) readonly buffer SortedNode { uint sorted_node[]; };
layout(std430, binding = BINDING_SORTED_DEPTH) readonly buffer SortedDepth { float sorted_depth[]; };
#else
layout(std430, binding = BINDING_COUNTERS) buffer Counters { uint counters[]; };
layout(std430, binding = BINDING_HEADS) buffer Heads { uint heads[]; };
layout(std430, binding = BINDING_NEXT) buffer Next { uint node_next[]; };
layout(std430, binding = BINDING_NODE_DEPTH) buffer NodeDepth { float node_depth[]; };
#endif

#define NO_NODE 0xFFFFFFFFu
#define NO_MATERIAL 0xFFFFFFFFu
// SPLAT_BIT (node_prim: a splat of triangle prim & ~SPLAT_BIT) and COUNTER_* (the counters' slots)
// come from gpu_impl/layout.py, as every constant the Python side shares.

uniform float radius;           // the frame radius (bounding sphere, padded)
uniform int resolution;         // R
uniform int tiles_per_row;      // atlas layout of this draw's directions
uniform int direction_base;     // the first direction of this draw
uniform vec2 atlas_size;        // in pixels
uniform uint capacity;          // nodes the list buffers hold

ivec2 tile_origin(int k) {
    int slot = k - direction_base;
    return ivec2(slot % tiles_per_row, slot / tiles_per_row) * resolution;
}

// Position p (relative to the bundle centre) in bundle k: its clip position in the atlas tile of k.
// Bundle pixel (i, j) has its centre on line (i, j) of the BundleSet (evalkit/core/bundleset.py), so
// rasterizing at pixel centres finds exactly the surfaces on those lines. Geometry never leaves
// its tile: it lies inside the bounding sphere, whose projection is the tile's inscribed disk. z
// is 0, so nothing is depth-clipped.
vec4 bundle_clip_position(int k, vec3 p) {
    BundleFrame f = frames[k];
    vec2 st = vec2(dot(p, f.u.xyz), dot(p, f.v.xyz)) / radius;
    vec2 pixel = (st * 0.5 + 0.5) * float(resolution) - vec2(f.u.w, f.v.w);
    return vec4((vec2(tile_origin(k)) + pixel) / atlas_size * 2.0 - 1.0, 0.0, 1.0);
}

#if defined FRAGMENT_SHADER
// This fragment's bundle pixel, or (-1, -1) for a pixel centre beyond the R x R grid (a line the
// bundle does not have; only round-off at the sphere's rim gets there).
ivec2 fragment_pixel(int k) {
    ivec2 pixel = ivec2(gl_FragCoord.xy) - tile_origin(k);
    if (any(lessThan(pixel, ivec2(0))) || any(greaterThanEqual(pixel, ivec2(resolution)))) return ivec2(-1);
    return pixel;
}

#endif

uint pixel_list(int k, ivec2 pixel) {
    return uint((k * resolution + pixel.y) * resolution + pixel.x);
}

// The origin (depth 0, relative to the bundle centre) of the line of bundle pixel `pixel`.
vec3 line_origin(int k, ivec2 pixel) {
    BundleFrame f = frames[k];
    vec2 st = ((vec2(pixel) + 0.5 + vec2(f.u.w, f.v.w)) / float(resolution) * 2.0 - 1.0) * radius;
    return st.x * f.u.xyz + st.y * f.v.xyz - radius * f.d.xyz;
}

vec3 unpack_albedo(uvec2 bits) {
    return vec3(unpackHalf2x16(bits.x), unpackHalf2x16(bits.y).x);
}

#if !defined BUNDLE_LOOKUP
// Append a node to a list. The counter always counts, but a node is written (and linked) only
// when its slot exists: linking first would corrupt the list. The host reads the counter and
// re-runs the pass with a buffer that fits, so no node is ever lost.
void append_node(uint list, float depth, uint prim, uint normal, vec3 albedo) {
    uint index = atomicAdd(counters[COUNTER_NODES], 1u);
    if (index >= capacity) return;
    node_depth[index] = depth;
    node_prim[index] = prim;
    node_normal[index] = normal;
    node_albedo[index] = uvec2(packHalf2x16(albedo.rg), packHalf2x16(vec2(albedo.b, 0.0)));
    node_next[index] = atomicExchange(heads[list], index);
}
#endif
