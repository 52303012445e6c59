// The second surface of each texel of a run of views' tiles of the shadow atlas (tiles of one size:
// one dispatch for all of them), after the raster pass (shadow_maps.glsl) kept its two nearest
// surfaces that face the light: the nearer of them that lies behind the texel's first surface, into
// the atlas' second channel (lights.glsl: lit_tap). The two are cleared for the tile's next draw
// here, so that no pass of its own clears them.

#define SHADOW_MAP_RASTER
#define SHADOW_LIGHTS 1
#include "common.glsl"
#include "lights.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;
layout(rg32f, binding = 0) uniform image2DArray atlas;
layout(r32ui, binding = FACING_IMAGE_NEAREST) uniform uimage2DArray facing_nearest;
layout(r32ui, binding = FACING_IMAGE_NEXT) uniform uimage2DArray facing_next;

uniform uint invocations;  // the tiles' texels
uniform int first_view;    // the run's first view
uniform int width;         // its tiles' side in texels
uniform int first_page;    // the first page of the atlas texture bound (its tiles' texture)

// Distances within this share of each other are one surface: the first surface itself where it
// faces the light, or coplanar and doubled geometry, which must not shrink the bias to nothing.
#define SAME_SURFACE 1e-4

void main() {
    uint id = linear_id();
    if (id >= invocations) return;
    int texels = width * width, texel = int(id) % texels;
    ivec2 corner = ivec2(shadow_views[first_view + int(id) / texels].tile.xy);
    ivec3 at = atlas_texel(corner + ivec2(texel % width, texel / width), imageSize(atlas).y) - ivec3(0, 0, first_page);
    vec2 drawn = imageLoad(atlas, at).rg;
    float first = drawn.x;
    float behind = first * (1.0 + SAME_SURFACE);
    float nearest = uintBitsToFloat(imageLoad(facing_nearest, at).r);
    float second = nearest > behind ? nearest : uintBitsToFloat(imageLoad(facing_next, at).r);
    bool none = drawn.y == SOLID_FIRST_SURFACE || second <= behind;
    imageStore(atlas, at, vec4(first, none ? NO_SURFACE : second, 0.0, 0.0));
    imageStore(facing_nearest, at, uvec4(floatBitsToUint(NO_SURFACE)));
    imageStore(facing_next, at, uvec4(floatBitsToUint(NO_SURFACE)));
}

#endif
