// Direct lighting from point, spot and directional lights through shadow maps, and from the
// frame's light vertices (gpu_impl/lights.py fills the buffers and renders the shadow atlas).
//
// Radiometry follows Mitsuba's emitters, so images compare with its references: a point or spot
// light gives intensity / distance^2 (the spot times Mitsuba's falloff, linear in angle from 1 at
// beam_width to 0 at cutoff_angle), a directional light its irradiance. A light vertex (an emitter
// sample: next-event estimation of emissive triangles, gpu_impl/lights.py: EmitterSamples) is a
// point light whose intensity falls as the cosine to its surface's normal, L_e cos_y / (M p(y)),
// weighted by multiple importance sampling against the bundle direction that could have found the
// emitter; the light visibility unit says how it is seen (LIGHT_VISIBILITY: light_visibility_*.glsl).
//
// Compiled per scene: SHADOW_LIGHTS is 0 without point, spot or directional lights or light
// vertices, and then nothing here exists.

#if SHADOW_LIGHTS

struct Light {
    vec4 position;   // xyz relative to the bundle centre (point, spot); w: LIGHT_*
    vec4 direction;  // xyz: the direction light travels (spot, directional) or the emitter's normal
                     // (emitter sample); w: cos(cutoff)
    vec4 intensity;  // rgb: W/sr (point, spot) or W/m^2 (directional); w: cos(beam width)
    vec4 shape;      // x: cutoff (rad), or M p(y) for an emitter sample, M p(omega) for an environment
                     // sample; y: 1 / (cutoff - beam width) (rad^-1);
                     // z: first shadow view; w: views (1 or 6)
    vec4 paths;      // bidirectional paths' MIS (light_paths.glsl): a point or spot light's density of
                     // starting a light path that reaches a surface, per unit cos / distance^2 (a
                     // directional light's per unit cos), V q p(omega); a light path vertex's
                     // x: L_i, y: its depth
    vec4 surface;    // a light path vertex in a scene with glossy materials (GLOSSY): rgb its diffuse
                     // reflectance, w its material's index
    vec4 incoming;   // such a vertex's xyz: the unit direction back along its light path
};
// Light.position.w is LIGHT_POINT, LIGHT_SPOT, LIGHT_DIRECTIONAL, LIGHT_EMITTER_SAMPLE,
// LIGHT_LIGHT_PATH_VERTEX or LIGHT_ENVIRONMENT_SAMPLE (a directional light for one frame, drawn
// from the environment map: gpu_impl/lights.py: EnvironmentSamples) (gpu_impl/layout.py).

// The shadow atlas is a stack of pages: a tile's y counts down the whole stack, so that its page
// is y / the page's height and a tile is one corner wherever it lies (gpu_impl/lights.py:
// pack_tiles). The texel `at` of the stack as (x, y in its page of `page_height` rows, the page):
ivec3 atlas_texel(ivec2 at, int page_height) {
    return ivec3(at.x, at.y % page_height, at.y / page_height);
}

// One shadow map: a tile of the atlas holding, per texel, the distance from the light to the
// nearest surface (radial for a perspective view, along the light direction for an orthographic
// one), and to the second: the nearest behind it that faces the light (NO_SURFACE where none is).
struct ShadowView {
    mat4 to_clip;    // position relative to the bundle centre -> clip space of this view
    vec4 tile;       // xy: the tile's first texel in the atlas' stack of pages, z: its size in texels, w: see texel_size
    vec4 origin;     // xyz: the light position (perspective) or the plane distances start from
                     // (orthographic); w: 1 perspective, 0 orthographic
    vec4 axis;       // xyz: the light direction (orthographic), the emitter's normal (an emitter
                     // sample's views), else 0; w: 1 / the farthest distance
};

layout(std430, binding = BINDING_LIGHTS) readonly buffer Lights { Light lights[]; };
layout(std430, binding = BINDING_SHADOW_VIEWS) readonly buffer ShadowViews { ShadowView shadow_views[]; };

uniform int light_count;          // the point, spot and directional lights and the emitter samples
uniform int atlas_page_height;
uniform float shadow_bias;        // constant depth bias, in texels
uniform float shadow_slope_bias;  // slope-scaled depth bias, in texels per unit tan(angle to the light)
uniform int shadow_filter;        // PCF: shadow_filter x shadow_filter bilinear taps, one texel apart

// The distance of a texel without a surface (FLT_MAX: a cleared texel, a hole of an imperfect map).
#define NO_SURFACE uintBitsToFloat(0x7F7FFFFFu)
// What the raster pass leaves in the second channel where the first surface bounds a solid, until
// shadow_second_surface.glsl replaces it (shadow_maps.glsl).
#define SOLID_FIRST_SURFACE 0.0

// The slope term grows without bound as light grazes a surface; past this tangent (about 84
// degrees) the bias stops growing, and cos(angle) < 0.1 leaves little light to mis-shadow.
#define MAX_SHADOW_SLOPE 10.0
// A second surface bounds the bias only where half its gap from the first exceeds this share of
// how far the receiver's own surface moves in depth across a texel (texel x slope): a closer one
// cannot be told from the receiver's own surface by a tap a texel away (lit_tap). Measured with
// exact maps of frame 0's light vertices against Embree rays (camera-seen receivers, light weighted
// by each connection's geometry term, maps of 256 texels; docs/results/decisions.toml: second-surfaces):
// - atrium, light hidden: 0.51 % at 0, 0.28 % at 0.25, 0.22 % with no bound (a wall there has a
//   second layer facing the light 0.0036 behind it, a 30th of a texel at a distance of 12);
// - cornell-box's ceiling above its light, light leaked over the true light: 0.42 at 0 and 0.25,
//   4.7 at 0.5, 45.5 with no bound.
#define SECOND_SURFACE_MARGIN 0.25

float light_distance(ShadowView view, vec3 p) {
    return view.origin.w > 0.5 ? distance(p, view.origin.xyz) : dot(p - view.origin.xyz, view.axis.xyz);
}

// The world-space size of one shadow texel at p: tile.w is 2 tan(fov / 2) / size for a
// perspective view (times the distance) and 2 radius / size for an orthographic one.
float texel_size(ShadowView view, float dist) {
    return view.tile.w * (view.origin.w > 0.5 ? dist : 1.0);
}

#if !defined SHADOW_MAP_RASTER

// The pages are the layers of ATLAS_TEXTURES texture arrays of atlas_pages_per_texture pages each
// (a driver caps one texture's bytes: gpu_impl/lights.py: AtlasTextures); RG32F distances: the
// first surface, the second. One texture is read through one sampler; more, through an array
// (gpu_impl/layout.py: MAX_ATLAS_TEXTURES says what that costs).
#if ATLAS_TEXTURES == 1
uniform sampler2DArray shadow_atlas;
#else
uniform sampler2DArray shadow_atlas[ATLAS_TEXTURES];
uniform int atlas_pages_per_texture;
uniform int atlas_textures;  // how many of them there are: the loops below run no further
#endif

// A tile's place in the atlas' textures: its corner in its page (xy), the page's layer in its
// texture (z) and the texture (w). Found once a lookup, not once a tap: llvmpipe divides integers
// lane by lane, and dividing at every tap made its shadow lookups 1.6 times as slow.
ivec4 atlas_place(ivec2 corner) {
    ivec3 at = atlas_texel(corner, atlas_page_height);
#if ATLAS_TEXTURES == 1
    return ivec4(at, 0);
#else
    int texture_index = at.z / atlas_pages_per_texture;
    return ivec4(at.xy, at.z - texture_index * atlas_pages_per_texture, texture_index);
#endif
}

// The first and second surfaces at `texel` of the tile at `place` (atlas_place). An array of
// samplers is indexed only by a dynamically uniform expression, so the loop's counter picks the
// texture; it runs to atlas_textures, not ATLAS_TEXTURES: llvmpipe runs every branch under
// masks, so every texture the loop passes costs a fetch.
vec2 atlas_surfaces(ivec4 place, ivec2 texel) {
    ivec3 at = ivec3(place.xy + texel, place.z);
#if ATLAS_TEXTURES == 1
    return texelFetch(shadow_atlas, at, 0).rg;
#else
    for (int i = 0; i < atlas_textures; i++) {
        if (i == place.w) return texelFetch(shadow_atlas[i], at, 0).rg;
    }
    return vec2(NO_SURFACE);
#endif
}

// The shadow view of light l that p falls in: a cube light (6 views) picks its face by the major
// axis of p - position, in the order +x, -x, +y, -y, +z, -z (gpu_impl/lights.py).
int shadow_view_of(Light light, vec3 p) {
    int first = int(light.shape.z);
    if (light.shape.w < 1.5) return first;
    vec3 v = p - light.position.xyz, a = abs(v);
    if (a.x >= a.y && a.x >= a.z) return first + (v.x >= 0.0 ? 0 : 1);
    if (a.y >= a.z) return first + (v.y >= 0.0 ? 2 : 3);
    return first + (v.z >= 0.0 ? 4 : 5);
}

// The tangent of the angle between a surface of normal n and the direction to_light, bounded.
float surface_slope(vec3 n, vec3 to_light) {
    float cos_l = clamp(dot(n, to_light), 1e-4, 1.0);
    return min(sqrt(1.0 - cos_l * cos_l) / cos_l, MAX_SHADOW_SLOPE);
}

// The depth bias in texels for a surface of slope `slope`: constant and slope-scaled.
float depth_bias_texels(float slope) {
    return shadow_bias + shadow_slope_bias * slope;
}

// Whether a tap lets the light through to a point at `dist`: the tap's first surface is not nearer
// than the point, give or take the depth bias. The bias never reaches past the middle between the
// first surface and its second, the nearest behind it that faces the light (a midpoint shadow map,
// after Woo 1992), where the gap is wider than `resolved` x 2 (SECOND_SURFACE_MARGIN): a point on
// the ceiling above a light that hangs a hair under it is in shadow however wide the bias is.
float lit_tap(ivec4 place, ivec2 texel, float dist, float bias, float resolved) {
    vec2 surfaces = atlas_surfaces(place, texel);
    float half_gap = 0.5 * (surfaces.y - surfaces.x);
    return surfaces.x >= dist - (half_gap > resolved ? min(bias, half_gap) : bias) ? 1.0 : 0.0;
}

// Percentage-closer filtering around ndc (the tile's [-1, 1]^2) of a shadow view: the share of the
// taps that let the light through to a point at `dist` with depth bias `bias` (lit_tap).
float filtered_visibility(ShadowView view, vec2 ndc, float dist, float bias, float resolved) {
    int size = int(view.tile.z);
    ivec4 place = atlas_place(ivec2(view.tile.xy));
    // Texel coordinates in the tile with texel centres at integers.
    vec2 st = (ndc * 0.5 + 0.5) * view.tile.z - 0.5 - 0.5 * float(shadow_filter - 1);
    float lit = 0.0;
    for (int j = 0; j < shadow_filter; j++) {
        for (int i = 0; i < shadow_filter; i++) {
            vec2 s = st + vec2(i, j);
            vec2 base = floor(s), w = s - base;
            ivec2 t0 = clamp(ivec2(base), ivec2(0), ivec2(size - 1)), t1 = clamp(ivec2(base) + 1, ivec2(0), ivec2(size - 1));
            float l00 = lit_tap(place, t0, dist, bias, resolved);
            float l10 = lit_tap(place, ivec2(t1.x, t0.y), dist, bias, resolved);
            float l01 = lit_tap(place, ivec2(t0.x, t1.y), dist, bias, resolved);
            float l11 = lit_tap(place, t1, dist, bias, resolved);
            lit += mix(mix(l00, l10, w.x), mix(l01, l11, w.x), w.y);
        }
    }
    return lit / float(shadow_filter * shadow_filter);
}

// The fraction of the light that reaches p (normal n, unit vector to the light to_light):
// percentage-closer filtering of the shadow map with a slope-scaled bias. Stored distances more
// than the bias nearer to the light than p shadow it.
float shadow_visibility(int view_index, vec3 p, vec3 n, vec3 to_light) {
    ShadowView view = shadow_views[view_index];
    vec4 clip = view.to_clip * vec4(p, 1.0);
    if (clip.w <= 0.0) return 1.0;
    vec2 ndc = clip.xy / clip.w;
    if (any(greaterThan(abs(ndc), vec2(1.0)))) return 1.0;  // outside this view: a spot's cone has no light there
    float dist = light_distance(view, p);
    float texel = texel_size(view, dist), slope = surface_slope(n, to_light);
    return filtered_visibility(view, ndc, dist, texel * depth_bias_texels(slope), SECOND_SURFACE_MARGIN * texel * slope);
}

// Mitsuba's spot falloff (src/emitters/spot.cpp): 1 inside the beam width, then linear in angle
// down to 0 at the cutoff.
float spot_falloff(Light light, float cos_theta) {
    if (cos_theta <= light.direction.w) return 0.0;
    if (cos_theta >= light.intensity.w) return 1.0;
    return (light.shape.x - acos(cos_theta)) * light.shape.y;
}

#if LIGHT_VISIBILITY == LIGHT_VISIBILITY_EXACT
#include "light_visibility_exact.glsl"
#elif LIGHT_VISIBILITY == LIGHT_VISIBILITY_IMPERFECT
#include "light_visibility_imperfect.glsl"
#else
#error "LIGHT_VISIBILITY names no light visibility (gpu_impl/layout.py: LIGHT_VISIBILITY_*)"
#endif

#if BIDIRECTIONAL
// Multiple importance sampling over every strategy that makes a path (strategies/bidirectional.py
// derives it): a strategy's weight is 1 / the sum over all strategies of (their density / its
// density)^2. The eye vertex carries the eye side's share of that sum as `eye_mis` (E_j), a light
// path vertex the light side's (Light.paths.x, L_i); each completes it with the densities of the
// connecting edge. Bundle directions have density 1 / (2 pi) per solid angle on either side.
uniform float light_path_emitter_ratio;  // V q_emitters / M: light paths' density of an emitter point over the emitter samples'
uniform int light_path_first;            // the light path vertices' records follow the light_count lights
uniform int light_path_vertices;         // how many there are this frame
uniform int bounces;                     // B: a connection from eye vertex j to a vertex of depth d is bounce j + d
#endif

// Irradiance at p on the side its normal n faces, from every shadow-mapped light: the point, spot
// and directional lights and the emitter samples (light vertices of depth 0). eye_mis: the eye
// vertex's share of the MIS sum (bidirectional paths; 0 at the G-buffer sample), else unused.
// With glossy materials, the light reflected toward wi by material m of diffuse reflectance albedo:
// each light's f(wi, to_light) cos (bsdf.glsl) in place of its cosine.
#if GLOSSY
vec3 light_reflected(vec3 p, vec3 n, float eye_mis, uint m, vec3 albedo, vec3 wi) {
#else
vec3 light_irradiance(vec3 p, vec3 n, float eye_mis) {
#endif
    vec3 e = vec3(0.0);
    for (int l = 0; l < light_count; l++) {
        Light light = lights[l];
        vec3 to_light;
        vec3 arriving;
        float d2 = 1.0, cos_out = 1.0;
        if (light.position.w == LIGHT_DIRECTIONAL) {
            to_light = -light.direction.xyz;
            arriving = light.intensity.rgb;
        } else if (light.position.w == LIGHT_ENVIRONMENT_SAMPLE) {
            // A direction drawn from the environment map: L / (M p), weighted against the bundle
            // direction that could have found it (eye_paths.glsl).
            to_light = -light.direction.xyz;
            arriving = light.intensity.rgb * power_heuristic(light.shape.x, BUNDLE_DIRECTION_PDF);
        } else {
            vec3 v = light.position.xyz - p;
            d2 = dot(v, v);
            to_light = v * inversesqrt(d2);
            cos_out = dot(-to_light, light.direction.xyz);
            float falloff = light.position.w == LIGHT_SPOT ? spot_falloff(light, cos_out)
                          : light.position.w == LIGHT_EMITTER_SAMPLE
                          ? (cos_out > 0.0 ? cos_out * power_heuristic(light.shape.x * d2 / cos_out, BUNDLE_DIRECTION_PDF) : 0.0)
                          : 1.0;
            arriving = light.intensity.rgb * (falloff / d2);
        }
        float cos_theta = dot(n, to_light);
        if (cos_theta <= 0.0 || all(equal(arriving, vec3(0.0)))) continue;
        float visible = light.position.w == LIGHT_EMITTER_SAMPLE ? light_vertex_visibility(light, p, n, to_light)
                                                                  : shadow_visibility(shadow_view_of(light, p), p, n, to_light);
#if BIDIRECTIONAL
        // The light paths could have made this path too: from this light straight to p, then a
        // connection from p's predecessor on the eye path (eye_mis). An emitter sample's weight
        // above already holds the eye path hitting the emitter; it is redone with every term.
        // Each weight is written times d^4, so a vanishing distance gives 0, not inf x 0.
        if (light.position.w == LIGHT_EMITTER_SAMPLE) {
            // arriving = I cos_out pow / d^2, pow = 1 / (1 + (pdf cos_out / (M p_A d^2))^2): undone.
            arriving = light.intensity.rgb * cos_out;
            float hit = BUNDLE_DIRECTION_PDF * cos_out / light.shape.x;
            float by_light_paths = light_path_emitter_ratio * BUNDLE_DIRECTION_PDF * cos_theta;
            arriving *= d2 / max(d2 * d2 + hit * hit + by_light_paths * by_light_paths * eye_mis, 1e-30);
        } else {
            float by_light_paths = light.paths.x * cos_theta;
            arriving *= d2 * d2 / max(d2 * d2 + by_light_paths * by_light_paths * eye_mis, 1e-30);
        }
#endif
#if GLOSSY
        e += arriving * bsdf_cos(m, albedo, n, wi, to_light) * visible;
#else
        e += arriving * (cos_theta * visible);
#endif
    }
    return e;
}

#if BIDIRECTIONAL
// Irradiance at eye vertex `eye_vertex` (p, normal n) from the frame's light path vertices: the
// connections, each weighted against every other strategy for its path. With glossy materials,
// the light they reflect toward wi by material m of diffuse reflectance albedo: each end's
// f cos (bsdf.glsl) in place of its cosine, the light vertex's intensity being its path's
// throughput (light_paths.glsl).
#if GLOSSY
vec3 connections(vec3 p, vec3 n, int eye_vertex, float eye_mis, uint m, vec3 albedo, vec3 wi) {
#else
vec3 connections(vec3 p, vec3 n, int eye_vertex, float eye_mis) {
#endif
    vec3 e = vec3(0.0);
    for (int l = light_path_first; l < light_path_first + light_path_vertices; l++) {
        Light light = lights[l];
        if (eye_vertex + int(light.paths.y) > bounces) continue;
        vec3 v = light.position.xyz - p;
        float d2 = dot(v, v);
        vec3 to_light = v * inversesqrt(d2);
        float cos_out = dot(-to_light, light.direction.xyz), cos_theta = dot(n, to_light);
        if (cos_out <= 0.0 || cos_theta <= 0.0) continue;
        // Each side's density of the other's vertex by a bundle direction, times d^2: the
        // strategies with one more eye vertex (light side) and one more light vertex (eye side).
        // The weight 1 / (1 + (b/d^2)^2 E + (a/d^2)^2 L) and the geometry term cos cos / d^2 are
        // taken together, so a light vertex a round-off from p adds 0, not inf x 0.
        float eye_side = BUNDLE_DIRECTION_PDF * cos_theta, light_side = BUNDLE_DIRECTION_PDF * cos_out;
#if GLOSSY
        float mis_d2 = d2 / max(d2 * d2 + eye_side * eye_side * eye_mis + light_side * light_side * light.paths.x, 1e-30);
        vec3 light_end = bsdf_cos(uint(light.surface.w), light.surface.rgb, light.direction.xyz, light.incoming.xyz, -to_light);
        vec3 eye_end = bsdf_cos(m, albedo, n, wi, to_light);
        e += light.intensity.rgb * light_end * eye_end * mis_d2 * light_vertex_visibility(light, p, n, to_light);
#else
        float weighted = cos_out * cos_theta * d2 / max(d2 * d2 + eye_side * eye_side * eye_mis + light_side * light_side * light.paths.x, 1e-30);
        e += light.intensity.rgb * weighted * light_vertex_visibility(light, p, n, to_light);
#endif
    }
    return e;
}
#endif

#endif  // !SHADOW_MAP_RASTER
#endif  // SHADOW_LIGHTS
