// Ray bundles: the orthographic frames of the K directions, the atlas that draws them all in one
// call, the splat points of imperfect bundles, and the sorted lists the eye paths read.
//
// A node is 8 bytes: its depth along the bundle direction d and a reference, the triangle
// (perfect bundles) or the splat point (imperfect ones); NODE_REFERENCE says which. What an eye
// path needs at a node (position, normals, albedo, emission) is computed where a path reaches it
// (bundle_hits.glsl), so nothing else is stored per node. List l holds nodes list_first(l) ..
// list_end(l) - 1, sorted by depth (then reference).
//
// Passes that read the sorted lists define BUNDLE_LOOKUP (a compute shader may use at most 16
// storage blocks, so each include declares only what its passes use).

#if !defined NODE_REFERENCE
#error "bundle.glsl needs NODE_REFERENCE (NODE_TRIANGLE or NODE_SPLAT_POINT): how node references are read"
#endif

struct BundleFrame {
    vec4 u;  // xyz: axis u, w: grid jitter along u in pixels
    vec4 v;  // xyz: axis v, w: grid jitter along v in pixels
    vec4 d;  // xyz: the direction
};

// A uniform block, not a storage buffer: llvmpipe loads a storage buffer's values lane by lane (a
// vec4 about ten times the time of a uniform block's, benchmarks/gl_loads.py), and every fragment
// of the lists pass reads its direction's frame: that pass took 1.2 to 1.7 times as long with
// storage (docs/results/decisions.toml: storage-vs-uniform).
// The block is always MAX_DIRECTIONS frames long (bundles.py sizes the buffer so).
layout(std140, binding = BINDING_FRAMES) uniform Frames { BundleFrame frames[MAX_DIRECTIONS]; };

#if NODE_REFERENCE == NODE_SPLAT_POINT
// A surface point of imperfect bundles: its triangle and barycentrics (b1, b2) as two unorm16, so
// the point follows its triangle when the geometry moves, its splat's radius: splat_radius, grown
// where lines cut the disk (scene.glsl: sharp_splat_radius), and which of its triangle's cut lines
// lie within that radius (scene.glsl: lines_within), worked out once where the point is made.
// Points k N .. (k + 1) N - 1 are direction k's (splat_points.glsl makes them).
struct SplatPoint {
    uint triangle;
    uint barycentrics;
    float radius;
    uint cut_lines;
};
uniform uint points_per_direction;  // N
uniform float splat_radius;         // in scene units
#if defined SPLAT_POINTS_WRITE
layout(std430, binding = BINDING_POINTS) writeonly buffer Points { SplatPoint points[]; };
#else
layout(std430, binding = BINDING_POINTS) readonly buffer Points { SplatPoint points[]; };

#if defined SPLAT_TEXELS
// The splat builders and lookups read the points as texels (common.glsl: SPLAT_TEXELS), copied
// from the storage buffer the points pass wrote.
uniform usampler2D point_texels;

uvec4 splat_point(uint point) {
    return texelFetch(point_texels, record_texel(point), 0);
}
#else
uvec4 splat_point(uint point) {
    SplatPoint p = points[point];
    return uvec4(p.triangle, p.barycentrics, floatBitsToUint(p.radius), p.cut_lines);
}
#endif

vec2 point_barycentrics(uint point) {
    return unpackUnorm2x16(splat_point(point).y);
}

// A splat point on its source triangle (scene.glsl): the triangle, its vertex indices, its first
// corner p0 and edges e1, e2 from it, the point's barycentrics b and the point p0 + b.x e1 + b.y e2, the
// splat's centre, its radius and the cut lines within it. Every pass that places a splat takes it from here, so they
// agree bitwise.
struct SplatSource {
    uint triangle;
    uvec3 vertices;
    vec3 p0;
    vec3 e1;
    vec3 e2;
    vec2 b;
    vec3 centre;
    float radius;
    uint cut_lines;
};

SplatSource splat_source(uint point) {
    SplatSource s;
    uvec4 record = splat_point(point);
    s.triangle = record.x;
    vec3 p1, p2;
    s.vertices = triangle_corners(s.triangle, s.p0, p1, p2);
    s.e1 = p1 - s.p0;
    s.e2 = p2 - s.p0;
    s.b = unpackUnorm2x16(record.y);
    s.centre = s.p0 + s.b.x * s.e1 + s.b.y * s.e2;
    s.radius = uintBitsToFloat(record.z);
    s.cut_lines = record.w;
    return s;
}
#endif
#endif

#if defined BUNDLE_LOOKUP
// The resolved lists (resolve_lists.glsl): list l's nodes are at the front of its slot range,
// from list_offsets[l], list_counts[l] of them (imperfect bundles' merged-away nodes leave the
// rest of the range unused). A node is a 64-bit key (bundle_build.glsl) read as two words:
// x the reference with FACING_BIT, y the depth's order bits.
layout(std430, binding = BINDING_LIST_OFFSETS) readonly buffer ListOffsets { uint list_offsets[]; };
layout(std430, binding = BINDING_LIST_COUNTS) readonly buffer ListCounts { uint list_counts[]; };
layout(std430, binding = BINDING_NODES) readonly buffer Nodes { uvec2 nodes[]; };

uint list_first(uint l) {
    return list_offsets[l];
}

uint list_end(uint l) {
    return list_offsets[l] + list_counts[l];
}

float node_depth(uint i) {
    return order_bits_depth(nodes[i].y);
}

uint node_ref(uint i) {
    return nodes[i].x & ~FACING_BIT;
}
#endif

uniform float radius;           // the frame radius (bounding sphere, padded)
uniform int resolution;         // R
uniform int tiles_per_row;      // atlas layout of this draw's directions
uniform int direction_base;     // the first direction of this draw
uniform vec2 atlas_size;        // in pixels

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

// Position p in bundle k's pixel grid, with pixel (i, j)'s centre (its line) at (i, j).
vec2 bundle_grid_position(BundleFrame f, vec3 p) {
    return (vec2(dot(p, f.u.xyz), dot(p, f.v.xyz)) / radius * 0.5 + 0.5) * float(resolution) - vec2(f.u.w, f.v.w) - 0.5;
}

// A triangle's edges e1, e2 from its first corner as bundle f's pixel grid sees them: a point's
// offset db in barycentrics moves it by grid_edges * db pixels. Both splatters take a splat's from
// here, so they find its lines with the same arithmetic.
mat2 grid_edges(BundleFrame f, vec3 e1, vec3 e2) {
    float pixels = 0.5 * float(resolution) / radius;  // per scene unit
    return pixels * mat2(dot(e1, f.u.xyz), dot(e1, f.v.xyz), dot(e2, f.u.xyz), dot(e2, f.v.xyz));
}

// Where the lines of bundle k meet the plane dot(n, p) = w, as depth = dot(plane, (1, i, j)) at
// line (i, j): a line's origin is s u + t v - radius d with s = radius (2 (i + 0.5 + jitter_u) / R
// - 1) (line_origin), so its depth (w - dot(n, origin)) / dot(n, d) is affine in (i, j). Exact to
// float32 at every line, where a depth interpolated between vertices would carry their snapping to
// the raster grid. dot(n, d) must not be 0.
vec3 depth_plane(BundleFrame f, vec3 n, float w) {
    float nu = dot(n, f.u.xyz), nv = dot(n, f.v.xyz), nd = dot(n, f.d.xyz), R = float(resolution);
    return vec3(w + radius * (nu * (1.0 - 2.0 * (0.5 + f.u.w) / R) + nv * (1.0 - 2.0 * (0.5 + f.v.w) / R) + nd),
                -2.0 * radius * nu / R, -2.0 * radius * nv / R) / nd;
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

// List l's direction and pixel.
int list_direction(uint l) {
    return int(l / uint(resolution * resolution));
}

ivec2 list_pixel(uint l) {
    uint cell = l % uint(resolution * resolution);
    return ivec2(cell % uint(resolution), cell / uint(resolution));
}
