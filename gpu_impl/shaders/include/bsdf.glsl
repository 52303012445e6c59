// Glossy BSDFs, as Mitsuba 3 evaluates them (evalkit/core/bsdf.py is the Python mirror, and says
// what each term is): a rough conductor, and a rough plastic, a Lambertian base under a rough
// dielectric coat. Both have a Beckmann or GGX distribution of microfacet normals with Smith's
// separable masking. Compiled only for scenes that have a glossy material (GLOSSY); a diffuse
// scene's shaders are the same text as before there were glossy ones.
//
// Directions are unit vectors from the surface point: wi toward the viewer (the way the path came),
// wo toward the light (the way it goes on). Cosines are taken to the shading normal n.

#if GLOSSY

float microfacet_d(uint distribution, float alpha, float cos_h) {
    float c2 = cos_h * cos_h, s2 = max(1.0 - c2, 0.0), a2 = alpha * alpha;
    float d = distribution == MICROFACET_BECKMANN ? exp(-s2 / a2 / c2) / (PI * a2 * c2 * c2)
                                                   : 1.0 / (PI * a2 * (s2 / a2 + c2) * (s2 / a2 + c2));
    // As Mitsuba: a density whose product with the cosine underflows is none.
    return cos_h > 0.0 && d * cos_h > 1e-20 ? d : 0.0;
}

// Smith's masking of direction v (cos_v to the normal) for microfacet normal h (v_dot_h = v . h);
// Beckmann's by Walter et al.'s rational approximation, as Mitsuba's (under 0.35 % off).
float smith_g1(uint distribution, float alpha, float cos_v, float v_dot_h) {
    if (v_dot_h * cos_v <= 0.0) return 0.0;  // the back of a microfacet is not seen from the front
    float xy_alpha_2 = alpha * alpha * max(1.0 - cos_v * cos_v, 0.0);
    if (xy_alpha_2 == 0.0) return 1.0;
    float tan_alpha_2 = xy_alpha_2 / (cos_v * cos_v);
    if (distribution == MICROFACET_GGX) return 2.0 / (1.0 + sqrt(1.0 + tan_alpha_2));
    float a = inversesqrt(tan_alpha_2);
    return a >= 1.6 ? 1.0 : (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a);
}

// The unpolarised Fresnel reflectance of a dielectric of relative index eta, seen from outside.
float fresnel_dielectric(float cos_i, float eta) {
    cos_i = abs(cos_i);
    float cos_t2 = 1.0 - (1.0 - cos_i * cos_i) / (eta * eta);
    if (cos_t2 <= 0.0 || cos_i == 0.0) return 1.0;
    float cos_t = sqrt(cos_t2);
    float a_s = (cos_i - eta * cos_t) / (cos_i + eta * cos_t), a_p = (cos_t - eta * cos_i) / (cos_t + eta * cos_i);
    return 0.5 * (a_s * a_s + a_p * a_p);
}

// The unpolarised Fresnel reflectance of a conductor of complex index eta + i k, per channel.
vec3 fresnel_conductor(float cos_i, vec3 eta, vec3 k) {
    float c2 = cos_i * cos_i, s2 = 1.0 - c2;
    vec3 t1 = eta * eta - k * k - s2;
    vec3 a2b2 = sqrt(max(t1 * t1 + 4.0 * k * k * eta * eta, 0.0));
    vec3 a = sqrt(max(0.5 * (a2b2 + t1), 0.0));
    vec3 term1 = a2b2 + c2, term2 = 2.0 * abs(cos_i) * a;
    vec3 r_s = (term1 - term2) / (term1 + term2);
    vec3 term3 = a2b2 * c2 + s2 * s2, term4 = term2 * s2;
    return 0.5 * (r_s + r_s * (term3 - term4) / (term3 + term4));
}

// The plastic coat's transmittance at incidence cos, from its 64-entry table at cosines i / 63
// (one value a texel, from texel `first`), interpolated as Mitsuba interpolates it.
float coat_transmittance(uint first, float cos_theta) {
    float x = clamp(cos_theta, 0.0, 1.0) * 63.0;
    uint i = min(uint(x), 62u);
    float t0 = texels[3u * (first + i)], t1 = texels[3u * (first + i + 1u)];
    return t0 + (x - float(i)) * (t1 - t0);
}

// f(wi, wo) cos(wo) of material m with diffuse reflectance albedo (its texel, where textured).
vec3 bsdf_cos(uint m, vec3 albedo, vec3 n, vec3 wi, vec3 wo) {
    float cos_i = dot(n, wi), cos_o = dot(n, wo);
    if (cos_i <= 0.0 || cos_o <= 0.0) return vec3(0.0);
    uvec4 gloss = materials[m].gloss;
    if (gloss.x == BSDF_DIFFUSE) return albedo * (cos_o / PI);
    vec3 h = normalize(wi + wo);
    float alpha = materials[m].specular.w, i_dot_h = dot(wi, h);
    float lobe = microfacet_d(gloss.y, alpha, dot(n, h)) * smith_g1(gloss.y, alpha, cos_i, i_dot_h)
               * smith_g1(gloss.y, alpha, cos_o, dot(wo, h)) / (4.0 * cos_i);
    vec3 specular = materials[m].specular.rgb;
    if (gloss.x == BSDF_ROUGH_CONDUCTOR) {
        return lobe * fresnel_conductor(i_dot_h, materials[m].eta.rgb, materials[m].k.rgb) * specular;
    }
    float eta = materials[m].eta.x, internal = materials[m].eta.w;
    vec3 base = albedo / (1.0 - (gloss.w != 0u ? albedo * internal : vec3(internal)));
    float through = coat_transmittance(gloss.z, cos_i) * coat_transmittance(gloss.z, cos_o);
    return lobe * fresnel_dielectric(i_dot_h, eta) * specular + base * (through * cos_o / (PI * eta * eta));
}

#endif
