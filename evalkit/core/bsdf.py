"""Glossy BSDFs, as Mitsuba 3 evaluates them: the Python mirror of gpu_impl/shaders/include/bsdf.glsl.

A `Gloss` (evalkit/core/scene/model.py) makes a material Mitsuba's ``roughconductor`` or
``roughplastic``; a material without one is Lambertian. Both use a microfacet distribution D
(Beckmann or GGX, isotropic roughness alpha) with Smith's separable masking G = G1(wi) G1(wo).
With wi the direction toward the viewer, wo toward the light, h = (wi + wo) / |wi + wo| and cosines
to the shading normal, `eval_bsdf` returns f(wi, wo) cos(wo), as Mitsuba's ``BSDF.eval`` does:

- rough conductor: D(h) G F_c(wi . h) / (4 cos wi), F_c the unpolarised Fresnel reflectance of
  a conductor of complex index eta + i k, times the specular reflectance;
- rough plastic: the coat's F(wi . h) D G / (4 cos wi) (F of a dielectric of index eta), times the
  specular reflectance, plus the diffuse base seen through it,
  rho / (1 - R) T(cos wi) T(cos wo) cos(wo) / (pi eta^2), with rho the diffuse reflectance
  (rho R in place of R when ``nonlinear``). T is the coat's transmittance by incidence and R its
  internal reflectance, integrals Mitsuba tabulates per material (64 cosines, read by linear
  interpolation); `rough_plastic_tables` reads Mitsuba's own.

Both are one-sided (zero unless cos wi > 0 and cos wo > 0), as in Mitsuba.
"""

from __future__ import annotations

import numpy as np

from evalkit.core.mitsuba_env import mitsuba

# Mitsuba's roughplastic tabulates the coat's transmittance at this many cosines, 0 to 1.
TRANSMITTANCE_RESOLUTION = 64
# Mitsuba clamps roughness to at least this (its microfacet distribution), and so do the importers.
MIN_ALPHA = 1e-4


def microfacet_d(distribution: str, alpha: float, cos_h: np.ndarray) -> np.ndarray:
    """The isotropic distribution of microfacet normals at cos(theta_h), per solid angle."""
    c2 = cos_h * cos_h
    s2 = np.maximum(1.0 - c2, 0.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if distribution == "beckmann":
            d = np.exp(-s2 / (alpha * alpha) / c2) / (np.pi * alpha * alpha * c2 * c2)
        else:
            d = 1.0 / (np.pi * alpha * alpha * (s2 / (alpha * alpha) + c2) ** 2)
    return np.where((d * cos_h > 1e-20) & (cos_h > 0.0), d, 0.0)


def smith_g1(distribution: str, alpha: float, cos_v: np.ndarray, v_dot_h: np.ndarray) -> np.ndarray:
    """Smith's masking of direction v (cosine cos_v to the normal) for microfacets h.

    Beckmann uses Walter et al.'s rational approximation, as Mitsuba does (under 0.35 % off)."""
    xy_alpha_2 = alpha * alpha * np.maximum(1.0 - cos_v * cos_v, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        tan_alpha_2 = xy_alpha_2 / (cos_v * cos_v)
        if distribution == "beckmann":
            a = 1.0 / np.sqrt(tan_alpha_2)
            g = np.where(a >= 1.6, 1.0, (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a))
        else:
            g = 2.0 / (1.0 + np.sqrt(1.0 + tan_alpha_2))
    g = np.where(xy_alpha_2 == 0.0, 1.0, g)
    return np.where(v_dot_h * cos_v <= 0.0, 0.0, g)


def fresnel_dielectric(cos_i: np.ndarray, eta: float) -> np.ndarray:
    """The unpolarised reflectance of a dielectric interface of relative index eta, from outside."""
    cos_i = np.abs(cos_i)
    cos_t2 = 1.0 - (1.0 - cos_i * cos_i) / (eta * eta)
    cos_t = np.sqrt(np.maximum(cos_t2, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        a_s = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
        a_p = (cos_t - eta * cos_i) / (cos_t + eta * cos_i)
    r = 0.5 * (a_s * a_s + a_p * a_p)
    return np.where(cos_t2 <= 0.0, 1.0, np.where(cos_i == 0.0, 1.0, r))


def fresnel_conductor(cos_i: np.ndarray, eta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The unpolarised reflectance of a conductor of complex index eta + i k (per channel)."""
    c2 = (cos_i * cos_i)[..., None]
    s2 = 1.0 - c2
    t1 = eta * eta - k * k - s2
    a2b2 = np.sqrt(np.maximum(t1 * t1 + 4.0 * k * k * eta * eta, 0.0))
    a = np.sqrt(np.maximum(0.5 * (a2b2 + t1), 0.0))
    term1 = a2b2 + c2
    term2 = 2.0 * np.abs(cos_i)[..., None] * a
    r_s = (term1 - term2) / (term1 + term2)
    term3 = a2b2 * c2 + s2 * s2
    term4 = term2 * s2
    r_p = r_s * (term3 - term4) / (term3 + term4)
    return 0.5 * (r_s + r_p)


def eval_bsdf(material, n: np.ndarray, wi: np.ndarray, wo: np.ndarray, albedo: np.ndarray | None = None) -> np.ndarray:
    """f(wi, wo) cos(wo) (N, 3) of a `Material` at shading normals n (N, 3) for unit wi, wo (N, 3).

    ``albedo`` (N, 3) is the diffuse reflectance where a texture gives it, else the material's."""
    n, wi, wo = (np.atleast_2d(np.asarray(a, dtype=np.float64)) for a in (n, wi, wo))
    rho = np.broadcast_to(np.asarray(material.albedo if albedo is None else albedo, dtype=np.float64), n.shape)
    cos_i, cos_o = np.sum(n * wi, axis=-1), np.sum(n * wo, axis=-1)
    live = (cos_i > 0.0) & (cos_o > 0.0)
    gloss = material.gloss
    if gloss is None:
        return np.where(live[:, None], rho / np.pi * cos_o[:, None], 0.0)
    h = wi + wo
    h /= np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-30)
    cos_h, i_dot_h = np.sum(n * h, axis=-1), np.sum(wi * h, axis=-1)
    d = microfacet_d(gloss.distribution, gloss.alpha, cos_h)
    g = smith_g1(gloss.distribution, gloss.alpha, cos_i, i_dot_h) * smith_g1(
        gloss.distribution, gloss.alpha, cos_o, np.sum(wo * h, axis=-1)
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        lobe = d * g / (4.0 * cos_i)
    spec = np.asarray(gloss.specular_reflectance, dtype=np.float64)
    if gloss.kind == "roughconductor":
        value = lobe[:, None] * fresnel_conductor(i_dot_h, np.asarray(gloss.eta), np.asarray(gloss.k)) * spec
    else:
        value = (lobe * fresnel_dielectric(i_dot_h, gloss.eta[0]))[:, None] * spec
        t_i, t_o = (transmittance(gloss, c) for c in (cos_i, cos_o))
        r = gloss.internal_reflectance
        base = rho / (1.0 - (rho * r if gloss.nonlinear else r))
        value = value + base * (t_i * t_o * cos_o / (np.pi * gloss.eta[0] ** 2))[:, None]
    return np.where(live[:, None], np.nan_to_num(value), 0.0)


def lobe_directions(alpha: float) -> float:
    """K_lobe: the bundle directions a frame needs before one is expected within the cone holding
    half of a GGX lobe of roughness ``alpha`` (2 arctan alpha about the mirror direction; the
    frame's K directions fall uniformly on a vertex's hemisphere). docs/method.md derives it."""
    return (1.0 + alpha * alpha) / (2.0 * alpha * alpha)


def transmittance(gloss, cos: np.ndarray) -> np.ndarray:
    """The rough plastic coat's transmittance at cos, by Mitsuba's lookup (lerp of 64 entries)."""
    table = np.asarray(gloss.transmittance, dtype=np.float64)
    x = np.clip(cos, 0.0, 1.0) * (TRANSMITTANCE_RESOLUTION - 1)
    i = np.minimum(x.astype(np.int64), TRANSMITTANCE_RESOLUTION - 2)
    return table[i] + (x - i) * (table[i + 1] - table[i])


def rough_plastic_tables(distribution: str, alpha: float, eta: float) -> tuple[tuple[float, ...], float]:
    """Mitsuba's roughplastic integrals for a coat: (its transmittance at cosines i / 63, its
    internal reflectance R), read back from Mitsuba's own ``eval`` so the mirror and the GPU use
    the very numbers the references do.

    With only the diffuse component, Mitsuba's eval at cos wi = cos wo = mu of a white base is
    T(mu)^2 mu / ((1 - R) pi eta^2), linear in the base; a base of 1/2 with ``nonlinear`` gives
    (1 - R) / (1 - R / 2) of half of it."""
    mi = mitsuba()
    previous = mi.variant()
    mi.set_variant("scalar_rgb")  # one direction at a time; the caller's variant comes back below
    try:
        return _probed_tables(mi, distribution, alpha, eta)
    finally:
        mi.set_variant(previous)


def _probed_tables(mi, distribution: str, alpha: float, eta: float) -> tuple[tuple[float, ...], float]:
    def diffuse_eval(nonlinear: bool, rho: float, mu: np.ndarray) -> np.ndarray:
        bsdf = mi.load_dict(
            {
                "type": "roughplastic",
                "distribution": distribution,
                "alpha": alpha,
                "int_ior": eta,
                "ext_ior": 1.0,
                "nonlinear": nonlinear,
                "diffuse_reflectance": {"type": "rgb", "value": [rho] * 3},
            }
        )
        ctx = mi.BSDFContext()
        ctx.component = 1  # the diffuse base alone
        out = []
        for m in mu:
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(float(np.sqrt(1.0 - m * m)), 0.0, float(m))
            wo = mi.Vector3f(-float(np.sqrt(1.0 - m * m)), 0.0, float(m))
            out.append(float(bsdf.eval(ctx, si, wo)[0]))
        return np.array(out)

    mu = np.maximum(np.linspace(0.0, 1.0, TRANSMITTANCE_RESOLUTION), 1e-6)
    white = diffuse_eval(False, 1.0, mu)
    ratio = diffuse_eval(True, 0.5, mu[-1:])[0] / (0.5 * white[-1])
    r = (1.0 - ratio) / (1.0 - ratio / 2.0)  # ratio = (1 - R) / (1 - R / 2)
    scale = 1.0 / ((1.0 - r) * np.pi * eta * eta)
    t = np.sqrt(np.maximum(white / mu / scale, 0.0))
    return tuple(float(x) for x in t), float(r)
