// Shared by every shader: invocation ids for 1-D compute passes, normal and colour packing, and
// a counter-based random number generator.

// Bidirectional paths (gpu_impl/strategies/bidirectional.py) compile their own variants of the
// path passes; every other program is compiled without.
#ifndef BIDIRECTIONAL
#define BIDIRECTIONAL 0
#endif
// Scenes with a glossy material compile the passes that reflect light with it (bsdf.glsl) their
// own way; every other program is compiled without.
#ifndef GLOSSY
#define GLOSSY 0
#endif

// Programs that look nodes up, with their triangles' shapes, read the triangles (corners, normals,
// cut lines) as texels (scene.glsl: TRIANGLE_TEXELS; the renderer binds them), and those that look
// splat points up read the points as texels too (bundle.glsl: SPLAT_TEXELS; every splat tracer
// keeps them beside the points, gpu_impl/methods/imperfect.py: SplatTracer.point_texels), as the
// splat builders do. llvmpipe loads a storage buffer word by word: atrium's three bounce passes
// with imperfect bundles (K=64, R=128, 96x64, 4 paths a pixel) took 401 ms with storage buffers,
// 317 ms with the points and cut lines as texels, and 298 -> 210 ms in a later run once the
// corners and normals were texels too; over perfect bundles, 244 -> 181 ms with the triangles as
// texels. The images are bitwise the same (atrium, parts, and cornell-box with bidirectional
// paths, either method).
#if defined BUNDLE_LOOKUP && defined SPLAT_SHAPES
#define TRIANGLE_TEXELS
#if NODE_REFERENCE == NODE_SPLAT_POINT && !defined SPLAT_TEXELS
#define SPLAT_TEXELS
#endif
#endif
#if defined SPLAT_TEXELS && !defined TRIANGLE_TEXELS
#define TRIANGLE_TEXELS
#endif

#define PI 3.141592653589793

// The index that points nowhere: the end of a linked list, a path that found no node.
#define NO_NODE 0xFFFFFFFFu

#if defined COMPUTE_SHADER
// A 1-D work item index over a 2-D dispatch (GLContext.dispatch spreads large passes over y).
uint linear_id() {
    return (gl_GlobalInvocationID.y * gl_NumWorkGroups.x) * uint(LOCAL_SIZE) + gl_GlobalInvocationID.x;
}
#endif

// A depth's bits turned so that they order as unsigned integers as the floats do (the high word of
// a node key, bundle_build.glsl), and back.
uint depth_order_bits(float depth) {
    uint bits = floatBitsToUint(depth);
    return bits ^ ((bits & 0x80000000u) != 0u ? 0xFFFFFFFFu : 0x80000000u);
}

float order_bits_depth(uint bits) {
    return uintBitsToFloat(bits ^ ((bits & 0x80000000u) != 0u ? 0x80000000u : 0xFFFFFFFFu));
}

// Octahedral normal encoding in two snorm16 (Cigolle et al., JCGT 2014): under 1e-4 rad of error,
// four bytes. evalkit decodes it with the same formula (gpu_impl/bundles.py: decode_normals).
vec2 sign_not_zero(vec2 v) {
    return vec2(v.x >= 0.0 ? 1.0 : -1.0, v.y >= 0.0 ? 1.0 : -1.0);
}

uint encode_normal(vec3 n) {
    n /= abs(n.x) + abs(n.y) + abs(n.z);
    vec2 e = n.z >= 0.0 ? n.xy : (1.0 - abs(n.yx)) * sign_not_zero(n.xy);
    return packSnorm2x16(e);
}

vec3 decode_normal(uint bits) {
    vec2 e = unpackSnorm2x16(bits);
    vec3 n = vec3(e, 1.0 - abs(e.x) - abs(e.y));
    if (n.z < 0.0) n.xy = (1.0 - abs(n.yx)) * sign_not_zero(n.xy);
    return normalize(n);
}

// pcg4d (Jarzynski and Olano, "Hash functions for GPU rendering", JCGT 2020): four independent
// 32-bit values from four 32-bit keys, so each (item, direction, seed, frame) has its own stream
// and results do not depend on the order work items run in.
uvec4 pcg4d(uvec4 v) {
    v = v * 1664525u + 1013904223u;
    v.x += v.y * v.w; v.y += v.z * v.x; v.z += v.x * v.y; v.w += v.y * v.z;
    v ^= v >> 16u;
    v.x += v.y * v.w; v.y += v.z * v.x; v.z += v.x * v.y; v.w += v.y * v.z;
    return v;
}

// A uniform float in [0, 1) from the top 24 bits (exactly representable, never 1.0).
float unit_float(uint bits) {
    return float(bits >> 8u) * (1.0 / 16777216.0);
}

// Multiple importance sampling of emitters (the power heuristic, Veach 1997) between next-event
// estimation, M emitter samples whose density per solid angle at x is M p_A(y) |x - y|^2 / cos_y,
// and the eye paths' bundle directions, uniform over the hemisphere: the weight of the technique
// of density `own` against `other`. Written as a ratio, so an infinite or zero density gives 0 or 1.
#define BUNDLE_DIRECTION_PDF 0.15915494309189535  // 1 / (2 pi)
float power_heuristic(float own, float other) {
    float r = other / own;
    return 1.0 / (1.0 + r * r);
}

// Bidirectional paths' MIS shares (E, L: lights.glsl) are bounded here: a share grows without
// bound where a density vanishes (a grazing edge), and an infinite one times a zero cosine is NaN.
#define MAX_MIS_SHARE 1e30
