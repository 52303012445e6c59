"""Materials described by metallic-roughness parameters (glTF's, Mitsuba's ``principled``) as the
`Gloss` nearest them: the mapping both importers share."""

from __future__ import annotations

import numpy as np

from evalkit.core.bsdf import MIN_ALPHA, rough_plastic_tables
from evalkit.core.scene.model import Gloss


def metallic_roughness(base, metallic: float, roughness: float, ior: float = 1.5) -> tuple[Gloss, str]:
    """The `Gloss` nearest a metallic-roughness material (glTF's, Mitsuba's ``principled``), and
    what it changes, in words: GGX of alpha = roughness^2 (both specifications' meaning); a metal
    (metallic at least 1/2) as a rough conductor whose Fresnel reflectance head-on is the base
    colour (a real index, (1 + sqrt F0) / (1 - sqrt F0), in place of Schlick's approximation); a
    dielectric as a rough plastic of index ``ior`` over the base colour (a coated base, not an
    uncoated diffuse term)."""
    alpha = max(roughness * roughness, MIN_ALPHA)
    notes = [f"GGX alpha = roughness^2 = {alpha:.4g}"]
    if 0.0 < metallic < 1.0:
        notes.append(f"metallic {metallic:g} is taken as {int(metallic >= 0.5)}")
    if metallic >= 0.5:
        f0 = np.sqrt(np.clip(np.asarray(base, dtype=np.float64), 0.0, 0.998))
        eta = tuple(float(x) for x in (1.0 + f0) / (1.0 - f0))
        what = "a rough conductor with the exact Fresnel of its base colour's reflectance in place of Schlick's"
        return Gloss("roughconductor", "ggx", alpha, eta), f"{what}; " + "; ".join(notes)
    table, internal = rough_plastic_tables("ggx", alpha, ior)
    gloss = Gloss("roughplastic", "ggx", alpha, (ior,) * 3, transmittance=table, internal_reflectance=internal)
    what = f"a rough plastic of index {ior:.4g} over its base colour (a coated base, not an uncoated diffuse term)"
    return gloss, f"{what}; " + "; ".join(notes)
