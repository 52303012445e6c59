// Shadow maps: the scene drawn into the tile of the atlas of each shadow view, storing the distance
// from the light to the nearest surface. Every view of a pass is one indirect multi-draw: a command
// per run of clusters a view sees, its base instance the view's index (in_view), so that a pass of
// hundreds of views (a frame's light vertices' cube maps) costs the GL one call, not a viewport,
// a clear and a draw per view. The vertex shader puts each view's clip space onto its tile of the
// atlas-wide viewport, and clip distances cut its triangles at the view's sides, as the viewport's
// clip volume did when each view had its own. The depth test keeps the nearest;
// the stored distance is linear (radial or along the light), so the lookup in lights.glsl compares
// distances in scene units and its bias is in scene units too. The depth test runs on the same
// linear distance (gl_FragDepth), not on the projection's hyperbolic depth, which a point light's
// tiny near plane would leave with too little precision to order nearby surfaces far away.
//
// Beside the nearest surface, each texel keeps the two nearest surfaces that face the light, by
// atomics in the same pass; shadow_second_surface.glsl then takes the nearest of them behind the
// first surface as the texel's second surface, which bounds the lookups' depth bias (lights.glsl:
// lit_tap). Only a surface facing the light can receive it: a far side, where a ray grazing an
// object's silhouette leaves it a hair behind where it entered, would shrink the bias of the near
// side's own points to that hair. Facing goes by the triangle's winding, as Mitsuba's normals do,
// for two-sided materials too: a two-sided panel has no second surface of its own, and one whose
// winding turns it away from the light keeps the full bias. A first surface that bounds a solid
// (scene.glsl: triangle_solid) has no second surface either: what lies just behind it is inside
// the solid, such as the floor running on under a box that rests on it, whose nearness would
// shadow the box's foot and the floor around it. So where every triangle bounds a solid (a closed
// room), SECOND_SURFACES is 0 and none of this is done.

#define SHADOW_MAP_RASTER
#define SHADOW_LIGHTS 1
#include "common.glsl"
#include "lights.glsl"
#define SCENE_MATERIALS_ONLY
#include "scene.glsl"

uniform vec2 atlas_size;  // a page's, in texels
uniform int atlas_page;   // the page this draw's views lie on (the framebuffer's layer)

#if defined VERTEX_SHADER

layout(location = 0) in vec3 in_position;  // relative to the bundle centre
// On the triangle's provoking vertex (scene_buffers.py): gl_PrimitiveID would count from each
// cluster's draw (gpu_impl/lights.py draws the clusters a view sees).
layout(location = 1) in uint in_triangle;
layout(location = 2) in uint in_view;  // per instance: the draw command's base instance
out vec3 v_position;
flat out int v_view;
flat out uint v_triangle;
// How far the point lies in front of the plane across the view's axis (below), from the vertices:
// interpolated, it keeps the sign of a triangle that lies wholly behind, as a point interpolated
// a hair from the view's origin would not (gpu_impl/lights.py culls such triangles by that sign).
out float v_front;

out float gl_ClipDistance[4];

void main() {
    ShadowView view = shadow_views[in_view];
    v_position = in_position;
    v_triangle = in_triangle;
    v_view = int(in_view);
    v_front = dot(in_position - view.origin.xyz, view.axis.xyz);
    vec4 clip = view.to_clip * vec4(in_position, 1.0);
    gl_ClipDistance[0] = clip.w + clip.x;
    gl_ClipDistance[1] = clip.w - clip.x;
    gl_ClipDistance[2] = clip.w + clip.y;
    gl_ClipDistance[3] = clip.w - clip.y;
    // The view's [-1, 1] in x and y onto its tile's texels of the page's [-1, 1].
    vec2 corner = vec2(atlas_texel(ivec2(view.tile.xy), int(atlas_size.y)).xy);
    vec2 scale = view.tile.z / atlas_size, offset = (2.0 * corner + view.tile.z) / atlas_size - 1.0;
    gl_Position = vec4(clip.xy * scale + clip.w * offset, clip.zw);
}

#elif defined FRAGMENT_SHADER

in vec3 v_position;
flat in uint v_triangle;
flat in int v_view;
in float v_front;
layout(location = 0) out vec2 out_distance;  // the first surface; the second comes after
// The triangle seen + 1, where the atlas has a second attachment for it: the fixed lights' maps read
// as reflective shadow maps, where light paths start (light_paths.glsl).
layout(location = 1) out uint out_triangle;
// Distances as uint bits (a non-negative float orders as its bits do); cleared to NO_SURFACE's.
#if SECOND_SURFACES
layout(r32ui, binding = FACING_IMAGE_NEAREST) uniform coherent uimage2DArray facing_nearest;
layout(r32ui, binding = FACING_IMAGE_NEXT) uniform coherent uimage2DArray facing_next;
#endif

void main() {
    ShadowView view = shadow_views[v_view];
    // An emitter sample's views (axis: its emitter's normal) keep only what lies in front of the
    // emitter: its own surface, seen almost edge-on from just in front of it, would fill the texels
    // at its horizon with tiny distances and shadow the light that leaves it at grazing angles.
    // So do a light vertex's views (axis: its surface's normal).
    if (view.origin.w > 0.5 && any(notEqual(view.axis.xyz, vec3(0.0))) && v_front <= 0.0) discard;
    float dist = light_distance(view, v_position);
    uint t = v_triangle;
    out_distance = vec2(dist, SECOND_SURFACES != 0 && triangle_solid(t) ? SOLID_FIRST_SURFACE : NO_SURFACE);
    gl_FragDepth = clamp(dist * view.axis.w, 0.0, 1.0);
    out_triangle = t + 1u;
#if SECOND_SURFACES
    // The late depth test (gl_FragDepth) runs this for every fragment, nearest or not. Of the new
    // distance and the nearest it meets, the larger goes on to the next: every distance but the
    // least reaches `facing_next` once, in any order, so that ends as the second least.
    vec3 to_light = view.origin.w > 0.5 ? view.origin.xyz - v_position : -view.axis.xyz;
    if (dot(triangle_normal(t), to_light) > 0.0) {
        ivec3 at = ivec3(ivec2(gl_FragCoord.xy), atlas_page);
        uint bits = floatBitsToUint(dist);
        imageAtomicMin(facing_next, at, max(bits, imageAtomicMin(facing_nearest, at, bits)));
    }
#endif
}

#endif
