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
// The flags MATERIAL_TEXTURED, MATERIAL_TWOSIDED, TRIANGLE_SMOOTH, TRIANGLE_SOLID, the mask TRIANGLE_MATERIAL
// and TRIANGLE_SHARP_SHIFT come from gpu_impl/layout.py.

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

// The triangle's sharp edges, bit e for edge e from corner e to corner e + 1 (gpu_impl/scene_buffers.py:
// sharp_edges; all clear until splats ask for them).
uint triangle_sharp_edges(uint t) {
    return (triangles[t].material_flags >> TRIANGLE_SHARP_SHIFT) & 7u;
}

// A splat (imperfect bundles', imperfect shadow maps') ends at its triangle's sharp edges: reaching
// over a convex crease or a boundary, a flat disk would stand out into empty space, and lines
// passing there would find a surface that is not there (docs/MEASURED_FACTS.md, "Splats end at
// sharp edges"). A point of the triangle's plane with barycentrics b lies inside edge 0 (corners 0
// to 1) where b2 >= 0, inside edge 1 where 1 - b1 - b2 >= 0 and inside edge 2 where b1 >= 0, up to
// round-off.
bool inside_sharp_edges(uint sharp, vec2 b) {
    const float tolerance = -1e-4;
    return ((sharp & 1u) == 0u || b.y >= tolerance) && ((sharp & 2u) == 0u || 1.0 - b.x - b.y >= tolerance) &&
           ((sharp & 4u) == 0u || b.x >= tolerance);
}

// The heights of a triangle with edges e1, e2 over its sharp edges, edge e (corner e to e + 1) in
// component e, and 3.4e38 over the others: a point's distance from edge e is its barycentric
// weight of the corner opposite (b2, 1 - b1 - b2, b1) times that height.
vec3 sharp_edge_heights(uint sharp, vec3 e1, vec3 e2) {
    float twice_area = length(cross(e1, e2));
    vec3 heights = twice_area / vec3(length(e1), length(e2 - e1), length(e2));
    return mix(heights, vec3(3.4e38), equal(sharp & uvec3(1u, 2u, 4u), uvec3(0u)));
}

// The radius of a splat of radius r, centred at barycentrics b of a triangle with the given
// heights over its sharp edges (sharp_edge_heights), that keeps the area pi r^2 of its disk where
// those edges cut it. A point stands for its share of the surface; cut down to half a disk at an
// edge, the splats would cover a line's crossing near the edge half as often as elsewhere, and
// light would leak along every crease (docs/MEASURED_FACTS.md, "Cut splats keep their area"). The
// disk grows along the edge instead: radius R keeps pi R^2 less a segment of
// R^2 (acos t - t sqrt(1 - t^2)), t = d / R, for each sharp edge at distance d < R (a few
// fixed-point steps; the kept area changes slowly with R). Overlapping segments (at a corner) are
// counted twice, which the cap of 2 r (a quarter disk's area) bounds.
float sharp_splat_radius(float r, vec3 heights, vec2 b) {
    vec3 cut = max(vec3(b.y, 1.0 - b.x - b.y, b.x), 0.0) * heights;
    if (min(min(cut.x, cut.y), cut.z) >= r) return r;
    float R = r;
    for (int i = 0; i < 4; i++) {
        vec3 t = clamp(cut / R, 0.0, 1.0);
        vec3 segments = acos(t) - t * sqrt(1.0 - t * t);
        R = r * sqrt(PI / max(PI - segments.x - segments.y - segments.z, 0.25 * PI));
    }
    return R;
}

// Whether a point of a splat's plane at barycentrics b, within the splat's radius, lies in the
// splat: inside the triangle's sharp edges and, where it lies beyond the disk's radius before it
// grew (beyond_disk), inside the triangle. The part grown at a sharp edge stays on the triangle,
// so it adds coverage of the surface itself and never reaches over its smooth edges onto a
// curved neighbour's offset surface.
bool inside_splat(uint sharp, vec2 b, bool beyond_disk) {
    return inside_sharp_edges(beyond_disk ? 7u : sharp, b);
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
