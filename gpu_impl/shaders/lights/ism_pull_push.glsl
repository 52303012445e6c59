// Pull-push hole filling of the imperfect shadow maps (Ritschel et al. 2008, after Marroquim et al.
// 2007), an option (gpu_impl/visibility/imperfect.py: ism_pull_push). A map splatted from a few
// points has holes: texels no splat covered, which keep the cleared "nothing there" distance and
// let light through a surface. Pull builds a pyramid per map, each texel the mean distance of its
// covered children (none covered: a hole there too); push then fills every hole, from the
// coarsest level down, with its parent's distance. Covered texels are never changed.
//
// One pass per level and direction, over every light vertex's map at once (map m is the tile of
// shadow view first_view + m). Level 0 is the map in the atlas; levels 1.. live in `pyramid`,
// per map: level l is ceil(size / 2^l) texels a side, at `level_offset` within the map's
// `map_stride` floats.

#define SHADOW_MAP_RASTER
#define SHADOW_LIGHTS 1
#include "common.glsl"
#include "lights.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;
layout(rg32f, binding = 0) uniform image2DArray atlas;
layout(std430, binding = BINDING_ISM_PYRAMID) buffer Pyramid { float pyramid[]; };

uniform uint invocations;   // maps x texels of this level
uniform int first_view;     // the shadow view of map 0
uniform int first_page;     // the first page of the atlas texture bound (the maps' texture)
uniform int pull;           // 1: pull into this level from the one below; 0: push into it from the one above
uniform int level;          // l
uniform ivec3 sizes;        // texels a side of levels l - 1, l and l + 1
uniform ivec3 offsets;      // where levels l - 1, l and l + 1 start in a map's pyramid (level 0: unused)
uniform uint map_stride;    // floats of one map's pyramid

// The atlas is cleared to the largest float, NO_SURFACE (gpu_impl/visibility/imperfect.py): a hole
// is that, and a distance past HOLE is one.
#define HOLE 3.0e38

// Texel xy of map m's tile in the atlas.
ivec3 map_texel(uint m, ivec2 xy) {
    return atlas_texel(ivec2(shadow_views[first_view + int(m)].tile.xy) + xy, imageSize(atlas).y) - ivec3(0, 0, first_page);
}

float texel_at(uint m, int l, int size, int offset, ivec2 xy) {
    if (l == 0) return imageLoad(atlas, map_texel(m, xy)).r;
    return pyramid[m * map_stride + uint(offset + xy.y * size + xy.x)];
}

void store(uint m, int l, int size, int offset, ivec2 xy, float value) {
    if (l == 0) imageStore(atlas, map_texel(m, xy), vec4(value, NO_SURFACE, 0.0, 0.0));
    else pyramid[m * map_stride + uint(offset + xy.y * size + xy.x)] = value;
}

void main() {
    uint id = linear_id();
    if (id >= invocations) return;
    uint texels = uint(sizes.y * sizes.y), m = id / texels, i = id % texels;
    ivec2 xy = ivec2(int(i) % sizes.y, int(i) / sizes.y);
    if (pull == 1) {
        float sum = 0.0, covered = 0.0;
        for (int c = 0; c < 4; c++) {
            ivec2 child = 2 * xy + ivec2(c & 1, c >> 1);
            if (any(greaterThanEqual(child, ivec2(sizes.x)))) continue;
            float d = texel_at(m, level - 1, sizes.x, offsets.x, child);
            if (d < HOLE) {
                sum += d;
                covered += 1.0;
            }
        }
        store(m, level, sizes.y, offsets.y, xy, covered > 0.0 ? sum / covered : NO_SURFACE);
    } else if (texel_at(m, level, sizes.y, offsets.y, xy) >= HOLE) {
        float parent = texel_at(m, level + 1, sizes.z, offsets.z, xy / 2);
        if (parent < HOLE) store(m, level, sizes.y, offsets.y, xy, parent);
    }
}

#endif
