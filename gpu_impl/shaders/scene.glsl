// The scene as the GPU sees it (gpu_impl/scene_buffers.py uploads it): indexed triangles with
// per-triangle and per-vertex records, and diffuse materials whose textures are sampled here, in
// the shader, with Mitsuba's convention so GL and the references agree texel for texel.

struct Material {
    vec4 albedo;     // rgb; used when the material has no texture
    vec4 emission;   // rgb radiance, front side only
    uvec4 texture;   // first texel, width, height, flags (MATERIAL_*)
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
};
// The flags MATERIAL_TEXTURED, MATERIAL_TWOSIDED, TRIANGLE_SMOOTH, TRIANGLE_SOLID, TRIANGLE_CUT, the
// mask TRIANGLE_MATERIAL and MAX_SPLAT_CUTS come from gpu_impl/layout.py.

layout(std430, binding = BINDING_MATERIALS) readonly buffer Materials { Material materials[]; };
layout(std430, binding = BINDING_TRIANGLES) readonly buffer Triangles { Triangle triangles[]; };

vec3 triangle_normal(uint t) {
    return vec3(triangles[t].normal_x, triangles[t].normal_y, triangles[t].normal_z);
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

uvec3 triangle_vertices(uint t) { return uvec3(indices[3u * t], indices[3u * t + 1u], indices[3u * t + 2u]); }
vec3 vertex_position(uint i) { return vec3(vertices[i].x, vertices[i].y, vertices[i].z); }
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

// The barycentrics (b1, b2) of p projected onto the plane of the triangle with corner p0 and
// edges e1, e2: outside [0, 1] beyond the triangle, so a splat that overhangs its triangle
// continues the triangle's affine uv map.
vec2 plane_barycentrics(vec3 p0, vec3 e1, vec3 e2, vec3 p) {
    vec3 q = p - p0;
    float a = dot(e1, e1), b = dot(e1, e2), c = dot(e2, e2);
    return vec2(c * dot(q, e1) - b * dot(q, e2), a * dot(q, e2) - b * dot(q, e1)) / (a * c - b * b);
}

// SPLAT_SHAPES: the passes that cut splats (imperfect bundles' points, builders and steps,
// imperfect shadow maps) read each triangle's flat neighbours and cut lines; the others leave
// their buffers out (a compute pass may use at most 16 storage blocks).
#if defined SPLAT_SHAPES
// One array of 16-byte entries (gpu_impl/scene_buffers.py: splat_shapes), for a pass may use at
// most 16 storage blocks. Entry t, for each triangle and one past the last: x, y, z the far corner
// of the triangle across edge e (corner e to e + 1) if the two lie in one plane, else NO_NEIGHBOUR
// (evalkit/core/scene/edges.py: flat_neighbours); w the entry of its first cut line, up to the
// next triangle's w. A cut line's entry holds the bits of (l1, l2, l0): l1 b1 + l2 b2 + l0 is the
// distance of the point at barycentrics b from the line, positive on the surface's side
// (splat_cuts).
layout(std430, binding = BINDING_SPLAT_SHAPES) readonly buffer SplatShapes { uvec4 splat_shapes[]; };

// What bounds a splat (imperfect bundles', imperfect shadow maps'), worked out once per splat:
// - The lines that cut it: the sharp edges of its triangle and of the triangle's flat neighbours.
//   Reaching over a convex crease or a boundary, a flat disk would stand out into empty space,
//   and lines passing there would find a surface that is not there (docs/MEASURED_FACTS.md,
//   "Splats end at sharp edges"). Column i: (l1, l2, l0), past the last line one no point is
//   beyond.
// - The edges across which a neighbour lies in the plane (bit e) and those neighbours' far corners
//   in the triangle's barycentrics (column e): where the part grown at the cuts may reach.
struct SplatShape {
    vec3 cut[MAX_SPLAT_CUTS];
    uint flat_edges;
    mat3x2 far;
};

SplatShape splat_shape(uint t, vec3 p0, vec3 e1, vec3 e2) {
    SplatShape shape;
    uvec4 entry = splat_shapes[t];
    uint count = splat_shapes[t + 1u].w - entry.w;
    for (uint i = 0u; i < uint(MAX_SPLAT_CUTS); i++) {
        shape.cut[i] = i < count ? uintBitsToFloat(splat_shapes[entry.w + i].xyz) : vec3(0.0, 0.0, 3.4e38);
    }
    shape.flat_edges = 0u;
    shape.far = mat3x2(0.0);
    for (uint e = 0u; e < 3u; e++) {
        uint far = entry[e];
        if (far == NO_NEIGHBOUR) continue;
        shape.flat_edges |= 1u << e;
        shape.far[e] = plane_barycentrics(p0, e1, e2, vertex_position(far));
    }
    return shape;
}

// The radius of a splat of radius r, centred at barycentrics b, that keeps the area pi r^2 of its
// disk where its shape's lines cut it. A point stands for its share of the surface; cut down to
// half a disk at an edge, the splats would cover a line's crossing near the edge half as often as
// elsewhere, and light would leak along every crease (docs/MEASURED_FACTS.md, "Cut splats keep
// their area"). The disk grows along the edge instead: radius R keeps pi R^2 less a segment of
// R^2 (acos t - t sqrt(1 - t^2)), t = d / R, for each line at distance d < R (a few fixed-point
// steps; the kept area changes slowly with R). Overlapping segments (at a corner) are counted
// twice, which the cap of 2 r (a quarter disk's area) bounds.
float sharp_splat_radius(float r, SplatShape shape, vec2 b) {
    float cut[MAX_SPLAT_CUTS];
    float nearest = 3.4e38;
    for (int i = 0; i < MAX_SPLAT_CUTS; i++) {
        cut[i] = max(dot(shape.cut[i], vec3(b, 1.0)), 0.0);
        nearest = min(nearest, cut[i]);
    }
    if (nearest >= r) return r;
    float R = r;
    for (int step = 0; step < 4; step++) {
        float lost = 0.0;
        for (int i = 0; i < MAX_SPLAT_CUTS; i++) {
            float t = clamp(cut[i] / R, 0.0, 1.0);
            lost += acos(t) - t * sqrt(1.0 - t * t);
        }
        R = r * sqrt(PI / max(PI - lost, 0.25 * PI));
    }
    return R;
}

// Whether a point of a splat's plane at barycentrics b, within the splat's radius, lies in the
// splat: on the inner side of every line that cuts it (up to round-off: 1e-4 of the line's rate
// of change per unit of barycentrics) and, where it lies beyond the disk's radius before it grew
// (beyond_disk), on the surface the splat stands for: inside the triangle or inside one of its
// flat neighbours. The part grown at the cuts adds coverage of the surface itself; it never
// reaches over a smooth edge onto a curved neighbour's offset surface.
bool inside_splat(SplatShape shape, vec2 b, bool beyond_disk) {
    for (int i = 0; i < MAX_SPLAT_CUTS; i++) {
        vec3 l = shape.cut[i];
        if (dot(l, vec3(b, 1.0)) < -1e-4 * max(abs(l.x), abs(l.y))) return false;
    }
    vec3 within = vec3(b.y, 1.0 - b.x - b.y, b.x);  // the weight opposite edge e: negative beyond it
    if (!beyond_disk || min(min(within.x, within.y), within.z) >= -1e-4) return true;
    const vec2 corners[3] = vec2[3](vec2(0.0), vec2(1.0, 0.0), vec2(0.0, 1.0));
    for (int e = 0; e < 3; e++) {
        if (within[e] >= 0.0 || (shape.flat_edges & (1u << uint(e))) == 0u) continue;
        // b in the neighbour (corner e, corner e + 1, far corner): its weights of the last two.
        vec2 a = corners[e];
        vec2 w = inverse(mat2(corners[(e + 1) % 3] - a, shape.far[e] - a)) * (b - a);
        if (min(w.x, w.y) >= -1e-4 && w.x + w.y <= 1.0 + 1e-4) return true;
    }
    return false;
}
#endif

vec3 texel(uint first, uint width, int x, int y) {
    uint i = 3u * (first + uint(y) * width + uint(x));
    return vec3(texels[i], texels[i + 1u], texels[i + 2u]);
}

// Bilinear, repeat-wrapped lookup: texel (row, col) is centred on ((col + 0.5) / W, (row + 0.5) / H)
// in (u, v), as Mitsuba's bitmap texture and evalkit.core.scene.model.sample_texture have it.
// TEXTURES 0 (a scene without textures) compiles the texture fetch out.
#ifndef TEXTURES
#define TEXTURES 1
#endif
vec3 material_albedo(uint m, vec2 uv) {
    uvec4 tex = materials[m].texture;
    if (TEXTURES == 0 || (tex.w & MATERIAL_TEXTURED) == 0u) return materials[m].albedo.rgb;
    ivec2 size = ivec2(tex.yz);
    vec2 p = uv * vec2(size) - 0.5;
    vec2 f = floor(p);
    vec2 w = p - f;
    ivec2 i0 = ivec2(f);
    int x0 = ((i0.x % size.x) + size.x) % size.x, y0 = ((i0.y % size.y) + size.y) % size.y;
    int x1 = (x0 + 1) % size.x, y1 = (y0 + 1) % size.y;
    return mix(mix(texel(tex.x, tex.y, x0, y0), texel(tex.x, tex.y, x1, y0), w.x),
               mix(texel(tex.x, tex.y, x0, y1), texel(tex.x, tex.y, x1, y1), w.x), w.y);
}
#endif
