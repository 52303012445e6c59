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
    vec4 shape;      // x: cutoff (rad), or M p(y) for an emitter sample; y: 1 / (cutoff - beam width) (rad^-1);
                     // z: first shadow view; w: views (1 or 6)
};
// Light.position.w is LIGHT_POINT, LIGHT_SPOT, LIGHT_DIRECTIONAL or LIGHT_EMITTER_SAMPLE (gpu_impl/layout.py).

// One shadow map: a tile of the atlas holding, per texel, the distance from the light to the
// nearest surface (radial for a perspective view, along the light direction for an orthographic one).
struct ShadowView {
    mat4 to_clip;    // position relative to the bundle centre -> clip space of this view
    vec4 tile;       // xy: the tile's first texel in the atlas, z: its size in texels, w: see texel_size
    vec4 origin;     // xyz: the light position (perspective) or the plane distances start from
                     // (orthographic); w: 1 perspective, 0 orthographic
    vec4 axis;       // xyz: the light direction (orthographic), the emitter's normal (an emitter
                     // sample's views), else 0; w: 1 / the farthest distance
};

layout(std430, binding = BINDING_LIGHTS) readonly buffer Lights { Light lights[]; };
layout(std430, binding = BINDING_SHADOW_VIEWS) readonly buffer ShadowViews { ShadowView shadow_views[]; };

uniform int light_count;
uniform sampler2D shadow_atlas;   // R32F light distances
uniform float shadow_bias;        // constant depth bias, in texels
uniform float shadow_slope_bias;  // slope-scaled depth bias, in texels per unit tan(angle to the light)
uniform int shadow_filter;        // PCF: shadow_filter x shadow_filter bilinear taps, one texel apart

// The slope term grows without bound as light grazes a surface; past this tangent (about 84
// degrees) the bias stops growing, and cos(angle) < 0.1 leaves little light to mis-shadow.
#define MAX_SHADOW_SLOPE 10.0

float light_distance(ShadowView view, vec3 p) {
    return view.origin.w > 0.5 ? distance(p, view.origin.xyz) : dot(p - view.origin.xyz, view.axis.xyz);
}

// The world-space size of one shadow texel at p: tile.w is 2 tan(fov / 2) / size for a
// perspective view (times the distance) and 2 radius / size for an orthographic one.
float texel_size(ShadowView view, float dist) {
    return view.tile.w * (view.origin.w > 0.5 ? dist : 1.0);
}

#if !defined SHADOW_MAP_RASTER

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
    float cos_l = clamp(dot(n, to_light), 1e-4, 1.0);
    float slope = min(sqrt(1.0 - cos_l * cos_l) / cos_l, MAX_SHADOW_SLOPE);
    float reference = dist - texel_size(view, dist) * (shadow_bias + shadow_slope_bias * slope);
    int size = int(view.tile.z);
    ivec2 origin = ivec2(view.tile.xy);
    // Texel coordinates in the tile with texel centres at integers.
    vec2 st = (ndc * 0.5 + 0.5) * view.tile.z - 0.5 - 0.5 * float(shadow_filter - 1);
    float lit = 0.0;
    for (int j = 0; j < shadow_filter; j++) {
        for (int i = 0; i < shadow_filter; i++) {
            vec2 s = st + vec2(i, j);
            vec2 base = floor(s), w = s - base;
            ivec2 t0 = clamp(ivec2(base), ivec2(0), ivec2(size - 1)), t1 = clamp(ivec2(base) + 1, ivec2(0), ivec2(size - 1));
            float l00 = texelFetch(shadow_atlas, origin + t0, 0).r >= reference ? 1.0 : 0.0;
            float l10 = texelFetch(shadow_atlas, origin + ivec2(t1.x, t0.y), 0).r >= reference ? 1.0 : 0.0;
            float l01 = texelFetch(shadow_atlas, origin + ivec2(t0.x, t1.y), 0).r >= reference ? 1.0 : 0.0;
            float l11 = texelFetch(shadow_atlas, origin + t1, 0).r >= reference ? 1.0 : 0.0;
            lit += mix(mix(l00, l10, w.x), mix(l01, l11, w.x), w.y);
        }
    }
    return lit / float(shadow_filter * shadow_filter);
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
#else
#error "LIGHT_VISIBILITY names no light visibility (gpu_impl/layout.py: LIGHT_VISIBILITY_*)"
#endif

// Irradiance at p on the side its normal n faces, from every shadow-mapped light.
vec3 light_irradiance(vec3 p, vec3 n) {
    vec3 e = vec3(0.0);
    for (int l = 0; l < light_count; l++) {
        Light light = lights[l];
        vec3 to_light;
        vec3 arriving;
        if (light.position.w == LIGHT_DIRECTIONAL) {
            to_light = -light.direction.xyz;
            arriving = light.intensity.rgb;
        } else {
            vec3 v = light.position.xyz - p;
            float d2 = dot(v, v);
            to_light = v * inversesqrt(d2);
            float cos_out = dot(-to_light, light.direction.xyz);
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
        e += arriving * (cos_theta * visible);
    }
    return e;
}

#endif  // !SHADOW_MAP_RASTER
#endif  // SHADOW_LIGHTS
