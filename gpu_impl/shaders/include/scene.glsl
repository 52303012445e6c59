// The scene as the GPU sees it (gpu_impl/scene_buffers.py uploads it): indexed triangles with
// per-triangle and per-vertex records, and materials (Lambertian or glossy: bsdf.glsl) whose textures are sampled here, in
// the shader, with Mitsuba's convention so GL and the references agree texel for texel.

struct Material {
    vec4 albedo;     // rgb; used when the material has no texture
    vec4 emission;   // rgb radiance, front side only
    uvec4 texture;   // first texel, width, height, flags (MATERIAL_*)
    vec4 to_uv_u;    // the mesh's uv to texture space (Mitsuba's to_uv): u' = dot(to_uv_u.xyz, (u, v, 1))
    vec4 to_uv_v;    // v' = dot(to_uv_v.xyz, (u, v, 1))
    uvec4 gloss;     // BSDF_*, MICROFACET_*, the coat's first transmittance texel, nonlinear (bsdf.glsl)
    vec4 specular;   // rgb: specular reflectance; w: roughness alpha
    vec4 eta;        // rgb: index of refraction (a plastic's coat: all alike); w: the coat's internal reflectance
    vec4 k;          // rgb: a conductor's extinction coefficient
};

struct Triangle {
    float normal_x, normal_y, normal_z;  // unit geometric normal, counter-clockwise front
    uint material_flags;                 // material index | TRIANGLE_SMOOTH | TRIANGLE_SOLID
};

// Scalars, not vec3s: std430 would pad each vec3 to 16 bytes.
struct Vertex {
    float x, y, z;     // position relative to the bundle centre
    float nx, ny, nz;  // normal; zero where a mesh has none
    float u, v;
    float r, g, b;     // linear reflectance, where the material reflects vertex colours
};
// The flags MATERIAL_TEXTURED, MATERIAL_TWOSIDED, TRIANGLE_SMOOTH, TRIANGLE_SOLID, TRIANGLE_CUT, the
// mask TRIANGLE_MATERIAL and MAX_SPLAT_CUTS come from gpu_impl/layout.py.

layout(std430, binding = BINDING_MATERIALS) readonly buffer Materials { Material materials[]; };
layout(std430, binding = BINDING_TRIANGLES) readonly buffer Triangles { Triangle triangles[]; };

#if defined TRIANGLE_TEXELS
// The splat builders and the lookups (common.glsl) read the triangles' corners and normals as
// texels (below, SPLAT_SHAPES: what the texels hold), the same words as the storage buffers hold.
uniform usampler2D triangle_texels;

ivec2 record_texel(uint i) {
    return ivec2(i % uint(TEXEL_ROW), i / uint(TEXEL_ROW));
}

uvec4 triangle_texel(uint t, uint i) {
    return texelFetch(triangle_texels, record_texel(uint(TEXELS_PER_TRIANGLE) * t + i), 0);
}
#endif

vec3 triangle_normal(uint t) {
#if defined TRIANGLE_TEXELS
    return uintBitsToFloat(triangle_texel(t, 3u).xyz);
#else
    return vec3(triangles[t].normal_x, triangles[t].normal_y, triangles[t].normal_z);
#endif
}

uint triangle_material(uint t) {
    return triangles[t].material_flags & TRIANGLE_MATERIAL;
}

bool triangle_smooth(uint t) {
    return (triangles[t].material_flags & TRIANGLE_SMOOTH) != 0u;
}

// Whether the triangle bounds a solid: every edge of its connected surface is shared by two
// triangles (gpu_impl/scene_buffers.py: solid_triangles).
bool triangle_solid(uint t) {
    return (triangles[t].material_flags & TRIANGLE_SOLID) != 0u;
}

// Whether lines cut the triangle's splats: its own sharp edges or its flat neighbours'
// (gpu_impl/scene_buffers.py: splat_shapes; all clear until splats ask).
bool triangle_cut(uint t) {
    return (triangles[t].material_flags & TRIANGLE_CUT) != 0u;
}

bool material_twosided(uint m) {
    return (materials[m].texture.w & MATERIAL_TWOSIDED) != 0u;
}

// SCENE_MATERIALS_ONLY leaves out the vertex and texel buffers, for passes that need only the
// per-triangle records (a compute shader may use at most 16 storage blocks).
#if !defined SCENE_MATERIALS_ONLY
layout(std430, binding = BINDING_VERTICES) readonly buffer Vertices { Vertex vertices[]; };
layout(std430, binding = BINDING_INDICES) readonly buffer Indices { uint indices[]; };
layout(std430, binding = BINDING_TEXELS) readonly buffer Texels { float texels[]; };  // linear rgb

uvec3 triangle_vertices(uint t) {
#if defined TRIANGLE_TEXELS
    return uvec3(triangle_texel(t, 0u).w, triangle_texel(t, 1u).w, triangle_texel(t, 2u).w);
#else
    return uvec3(indices[3u * t], indices[3u * t + 1u], indices[3u * t + 2u]);
#endif
}
vec3 vertex_position(uint i) { return vec3(vertices[i].x, vertices[i].y, vertices[i].z); }

// Triangle t's corners; returns its vertices' indices, which the same reads hold.
uvec3 triangle_corners(uint t, out vec3 p0, out vec3 p1, out vec3 p2) {
#if defined TRIANGLE_TEXELS
    uvec4 c0 = triangle_texel(t, 0u), c1 = triangle_texel(t, 1u), c2 = triangle_texel(t, 2u);
    p0 = uintBitsToFloat(c0.xyz);
    p1 = uintBitsToFloat(c1.xyz);
    p2 = uintBitsToFloat(c2.xyz);
    return uvec3(c0.w, c1.w, c2.w);
#else
    uvec3 v = triangle_vertices(t);
    p0 = vertex_position(v.x);
    p1 = vertex_position(v.y);
    p2 = vertex_position(v.z);
    return v;
#endif
}
vec3 vertex_normal(uint i) { return vec3(vertices[i].nx, vertices[i].ny, vertices[i].nz); }
vec2 vertex_uv(uint i) { return vec2(vertices[i].u, vertices[i].v); }

// The shading normal at barycentrics (b1, b2): interpolated vertex normals, or the geometric
// normal for a mesh without them (as Mitsuba shades).
vec3 shading_normal(uint t, uvec3 v, float b1, float b2) {
    if (!triangle_smooth(t)) return triangle_normal(t);
    vec3 n0 = vertex_normal(v.x);
    return normalize(n0 + b1 * (vertex_normal(v.y) - n0) + b2 * (vertex_normal(v.z) - n0));
}

vec2 surface_uv(uvec3 v, float b1, float b2) {
    vec2 uv0 = vertex_uv(v.x);
    return uv0 + b1 * (vertex_uv(v.y) - uv0) + b2 * (vertex_uv(v.z) - uv0);
}

vec3 vertex_color(uint i) { return vec3(vertices[i].r, vertices[i].g, vertices[i].b); }

// The barycentrics (b1, b2) of p projected onto the plane of the triangle with corner p0 and
// edges e1, e2: outside [0, 1] beyond the triangle, so a splat that overhangs its triangle
// continues the triangle's affine uv map.
vec2 plane_barycentrics(vec3 p0, vec3 e1, vec3 e2, vec3 p) {
    vec3 q = p - p0;
    float a = dot(e1, e1), b = dot(e1, e2), c = dot(e2, e2);
    return vec2(c * dot(q, e1) - b * dot(q, e2), a * dot(q, e2) - b * dot(q, e1)) / (a * c - b * b);
}

// Whether barycentrics b lie in their triangle, up to 1e-4 of round-off.
bool inside_triangle(vec2 b) {
    return min(min(b.x, b.y), 1.0 - b.x - b.y) >= -1e-4;
}

// SPLAT_SHAPES: the passes that cut splats (imperfect bundles' points and builders, imperfect
// shadow maps) read each triangle's cut lines, and the paths' steps (bundle_step.glsl) its cut
// lines, its smooth surface and the triangles across its edges, perfect bundles' too; the others
// leave the buffer out (a compute pass may use at most 16 storage blocks).
#if defined SPLAT_SHAPES
// One array of 32-bit words (gpu_impl/scene_buffers.py: splat_facts): word t, where triangle t's
// cut lines start (up to where the next triangle's start, or, past the last, word T: where the
// lines end); after these, three words a line, the bits of (l1, l2, l0): l1 b1 + l2 b2 + l0 is
// the distance of the point at barycentrics b from the line, positive on the surface's side
// (evalkit/core/scene/edges.py: splat_cuts). Each triangle's smooth surface
// (evalkit/core/scene/edges.py: smooth_surfaces) and the triangles across its three edges
// (triangle_neighbours) only the paths' steps read, as texels.
layout(std430, binding = BINDING_SPLAT_SHAPES) readonly buffer SplatShapes { uint splat_shapes[]; };

#if defined TRIANGLE_TEXELS
// llvmpipe loads a storage buffer lane by lane, each word on its own, and a texel at once, in a
// fraction of the time (benchmarks/gl_loads.py); the splat builders load little else, so they,
// and the passes that look nodes up (common.glsl), read the triangles (corners, normals, cut
// lines), and the splat points (bundle.glsl: SPLAT_TEXELS), as texels
// (gpu_impl/layout.py: TEXEL_ROW; gpu_impl/scene_buffers.py: GpuScene.triangle_texels): the same
// words as the storage buffers hold, so the same arithmetic. Per triangle TEXELS_PER_TRIANGLE
// texels: its corners, each with its vertex index, its normal with the texel of its first cut
// line (past the last triangle, one more record: where the last one's lines end), then the
// triangles across its three edges with its smooth surface; the cut lines follow, a texel each.

uint cut_lines_start(uint t) {
    return triangle_texel(t, 3u).w;
}

vec3 cut_line_at(uint start, uint i) {
    return uintBitsToFloat(texelFetch(triangle_texels, record_texel(start + i), 0).xyz);
}

// All of triangle t's cut lines, bit i for its line i.
uint triangle_cut_lines(uint t) {
    return (1u << (cut_lines_start(t + 1u) - cut_lines_start(t))) - 1u;
}
#else
uint cut_lines_start(uint t) {
    return splat_shapes[t];
}

vec3 cut_line_at(uint start, uint i) {
    uint word = start + 3u * i;
    return uintBitsToFloat(uvec3(splat_shapes[word], splat_shapes[word + 1u], splat_shapes[word + 2u]));
}

// All of triangle t's cut lines, bit i for its line i.
uint triangle_cut_lines(uint t) {
    uint first = splat_shapes[t], end = splat_shapes[t + 1u];
    return triangle_cut(t) ? (1u << ((end - first) / 3u)) - 1u : 0u;
}
#endif

#if defined TRIANGLE_TEXELS
// Triangle t's smooth surface: triangles joined across edges that bend less than the crease angle.
// Texels, as are the triangles across its edges, which a lookup's walk reads at every hop: from
// the storage buffer the bounce passes took longer (docs/results/decisions.toml: walk-by-distance).
uint triangle_surface(uint t) {
    return triangle_texel(t, 4u).w;
}

// The triangle across triangle t's edge e (from corner e to corner e + 1), NO_TRIANGLE where there
// is none, with TRIANGLE_TURNED set where its normal must be turned to agree with t's.
uint triangle_across(uint t, uint e) {
    return triangle_texel(t, 4u)[e];
}
#endif

// The lines that cut a splat (imperfect bundles', imperfect shadow maps'): of the sharp edges of
// its triangle and of the triangle's flat neighbours, those nearer its centre than its radius (the
// others cannot cut it, and most splats meet none: `cut` false, and they skip every test;
// bundle.glsl's SplatPoint keeps which, lines_within). Reaching over a convex crease or a
// boundary, a flat disk would stand out into empty space, and lines passing there would find a
// surface that is not there (docs/results/decisions.toml: splats-end-at-sharp-edges; reaching past
// a neighbour's, it stands out as well ("Cut by their neighbours' edges too"). The MAX_SPLAT_CUTS
// = 6 lines are the columns of two matrices, (l1, l2, l0) each, so that vec3(b, 1) * lines gives
// three distances at once, with a slack for round-off (1e-4 of the line's change per unit of
// barycentrics) beside them: no loop over an array, which a CPU rasterizer keeps in memory. A
// column no line fills is (0, 0, 3.4e38), which no point is beyond.
#if MAX_SPLAT_CUTS != 6
#error "SplatShape holds 6 lines (evalkit/core/scene/edges.py: MAX_SPLAT_CUTS)"
#endif
struct SplatShape {
    bool cut;
    mat3 lines_a, lines_b;
    vec3 slack_a, slack_b;
};


// A cut line's slack for round-off: 1e-4 of its change per unit of barycentrics.
float cut_slack(vec3 line) {
    return 1e-4 * max(abs(line.x), abs(line.y));
}

// The shape of a splat of triangle t cut by the triangle's cut lines `lines` (bit i for its line
// i). A splat no line cuts reads nothing.
SplatShape splat_shape(uint t, uint lines) {
    const vec3 none = vec3(0.0, 0.0, 3.4e38);
    SplatShape shape = SplatShape(lines != 0u, mat3(none, none, none), mat3(none, none, none), vec3(0.0), vec3(0.0));
    if (lines == 0u) return shape;
    uint first = cut_lines_start(t);
    for (int i = 0; i < 6; i++) {
        vec3 l = (lines & (1u << uint(i))) != 0u ? cut_line_at(first, uint(i)) : none;
        float slack = cut_slack(l);
        if (i < 3) {
            shape.lines_a[i] = l;
            shape.slack_a[i] = slack;
        } else {
            shape.lines_b[i - 3] = l;
            shape.slack_b[i - 3] = slack;
        }
    }
    return shape;
}

// The radius of a splat of radius r centred at barycentrics b, grown where its shape's lines cut
// it. A point stands for its share of the surface, and a crossing anywhere inside a face finds a
// splat centre within r as often as the disk of radius r around it holds points. At a sharp edge
// only the half of that disk on the face's own side holds any, so splats of radius r, cut there,
// would cover the edge's crossings half as often, and light would leak along every crease
// (docs/results/decisions.toml: splats-end-at-sharp-edges. A half disk of radius sqrt(2) r has
// the full disk's area, and a quarter disk (a corner) of radius 2 r: so a splat within sqrt(2) r
// of one line takes radius sqrt(2) r, and one within sqrt(2) r of two or more takes 2 r. Growing
// a cut splat only until what it keeps has its disk's area (the rule before) left an edge's
// crossings 0.6 of the interior's cover.
float sharp_splat_radius(float r, SplatShape shape, vec2 b) {
    float reach = sqrt(2.0) * r;
    bvec3 near_a = lessThan(vec3(b, 1.0) * shape.lines_a, vec3(reach)), near_b = lessThan(vec3(b, 1.0) * shape.lines_b, vec3(reach));
    int lines = int(near_a.x) + int(near_a.y) + int(near_a.z) + int(near_b.x) + int(near_b.y) + int(near_b.z);
    return lines == 0 ? r : (lines == 1 ? reach : 2.0 * r);
}

// Which of a shape's lines (bit i for column i) lie nearer barycentrics b than `radius`: those
// that can cut a splat of that radius centred there.
uint lines_within(SplatShape shape, vec2 b, float radius) {
    bvec3 a = lessThan(vec3(b, 1.0) * shape.lines_a, vec3(1.001 * radius));
    bvec3 c = lessThan(vec3(b, 1.0) * shape.lines_b, vec3(1.001 * radius));
    return (a.x ? 1u : 0u) | (a.y ? 2u : 0u) | (a.z ? 4u : 0u) | (c.x ? 8u : 0u) | (c.y ? 16u : 0u) | (c.z ? 32u : 0u);
}

// Whether a point of a splat's plane at barycentrics b, within the splat's radius, lies inside
// every line that cuts it, up to round-off.
bool inside_cuts(SplatShape shape, vec2 b) {
    vec3 v = vec3(b, 1.0);
    return all(greaterThanEqual(v * shape.lines_a, -shape.slack_a)) && all(greaterThanEqual(v * shape.lines_b, -shape.slack_b));
}

// Whether a point of a splat's plane at barycentrics b, within the splat's radius, lies in the
// splat: inside its cuts and, where it lies beyond the disk's radius before it grew
// (beyond_disk), inside its triangle. The part grown at the cuts stays on the triangle, so it adds
// coverage of the surface itself and never reaches over a smooth edge onto a curved neighbour's
// offset surface.
bool inside_splat(SplatShape shape, vec2 b, bool beyond_disk) {
    return inside_cuts(shape, b) && (!beyond_disk || inside_triangle(b));
}
#endif

vec3 texel(uint first, uint width, int x, int y) {
    uint i = 3u * (first + uint(y) * width + uint(x));
    return vec3(texels[i], texels[i + 1u], texels[i + 2u]);
}

// A texel index of any sign wrapped into [0, n) as Mitsuba's bitmap texture wraps it: repeat,
// mirror (period 2n, the second half reversed) or clamp. GLSL leaves % undefined for negative
// operands (llvmpipe gives -1 % 9 == 3), so a negative index is folded with non-negative ones only.
int wrap_texel(int i, int n, bool mirror, bool clamped) {
    if (clamped) return clamp(i, 0, n - 1);
    int period = mirror ? 2 * n : n;
    int m = i >= 0 ? i % period : period - 1 - (-(i + 1)) % period;
    return m < n ? m : period - 1 - m;
}

// Material m's diffuse reflectance at barycentrics b of a triangle with vertices v: its vertices'
// colours interpolated (Mitsuba's mesh_attribute texture; clamped to [0, 1], as a splat's b may
// lie beyond its triangle), or Mitsuba's bitmap lookup: the mesh's uv through to_uv, then texel
// (row, col) centred on ((col + 0.5) / W, (row + 0.5) / H), bilinear or nearest, wrapped by
// wrap_texel; the same as evalkit.core.scene.colour.sample_texture. TEXTURES 0 (a scene whose
// reflectance varies over no surface: no textures, no vertex colours) compiles both out.
#ifndef TEXTURES
#define TEXTURES 1
#endif
vec3 material_albedo(uint m, uvec3 v, vec2 b) {
    uvec4 tex = materials[m].texture;
    if (TEXTURES != 0 && (tex.w & MATERIAL_VERTEX_COLORS) != 0u) {
        vec3 c0 = vertex_color(v.x);
        return clamp(c0 + b.x * (vertex_color(v.y) - c0) + b.y * (vertex_color(v.z) - c0), 0.0, 1.0);
    }
    if (TEXTURES == 0 || (tex.w & MATERIAL_TEXTURED) == 0u) return materials[m].albedo.rgb;
    vec2 uv = surface_uv(v, b.x, b.y);
    ivec2 size = ivec2(tex.yz);
    bool mirror = (tex.w & MATERIAL_WRAP_MIRROR) != 0u, clamped = (tex.w & MATERIAL_WRAP_CLAMP) != 0u;
    vec3 uv1 = vec3(uv, 1.0);
    uv = vec2(dot(materials[m].to_uv_u.xyz, uv1), dot(materials[m].to_uv_v.xyz, uv1));
    if ((tex.w & MATERIAL_NEAREST) != 0u) {
        ivec2 i = ivec2(floor(uv * vec2(size)));
        return texel(tex.x, tex.y, wrap_texel(i.x, size.x, mirror, clamped), wrap_texel(i.y, size.y, mirror, clamped));
    }
    vec2 p = uv * vec2(size) - 0.5;
    vec2 f = floor(p);
    vec2 w = p - f;
    ivec2 i0 = ivec2(f);
    int x0 = wrap_texel(i0.x, size.x, mirror, clamped), y0 = wrap_texel(i0.y, size.y, mirror, clamped);
    int x1 = wrap_texel(i0.x + 1, size.x, mirror, clamped), y1 = wrap_texel(i0.y + 1, size.y, mirror, clamped);
    return mix(mix(texel(tex.x, tex.y, x0, y0), texel(tex.x, tex.y, x1, y0), w.x),
               mix(texel(tex.x, tex.y, x0, y1), texel(tex.x, tex.y, x1, y1), w.x), w.y);
}
#endif
