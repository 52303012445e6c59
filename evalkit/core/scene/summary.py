"""A scene described for people and JSON: what `evalkit scene info` prints."""

from __future__ import annotations

from evalkit.core.scene.model import Gloss, Light, Scene


def scene_summary(scene: Scene) -> dict:
    """A JSON-ready description of ``scene``, as `evalkit scene info` prints it."""
    lo, hi = scene.bounds()
    centre, radius = scene.bounding_sphere()
    f = scene.features()
    used = sorted({m.material for m in scene.meshes})
    return {
        "name": scene.name,
        "source": scene.source,
        "content_hash": scene.content_hash(),
        "triangles": scene.triangle_count,
        "meshes": len(scene.meshes),
        "degenerate_removed": scene.degenerate_removed,
        "origin": scene.origin.tolist(),
        "bounds": {"min": (lo + scene.origin).tolist(), "max": (hi + scene.origin).tolist()},
        "bounding_radius": radius,
        "surface_area": scene.surface_area(),
        "materials": [
            {
                "name": scene.materials[i].name,
                "albedo": list(scene.materials[i].albedo),
                "texture": None if scene.materials[i].texture is None else list(scene.materials[i].texture.shape[:2]),
                "vertex_colors": scene.materials[i].vertex_colors,
                "emission": list(scene.materials[i].emission),
                "twosided": scene.materials[i].twosided,
                "source_bsdf": scene.materials[i].source_bsdf,
                "approximated": scene.materials[i].approximated,
                "bsdf": _bsdf_summary(scene.materials[i].gloss),
            }
            for i in used
        ],
        "lights": [_light_summary(light) for light in scene.lights],
        "camera": {
            "position": (scene.camera.position + scene.origin).tolist(),
            "fov": scene.camera.fov,
            "fov_axis": scene.camera.fov_axis,
            "width": scene.camera.width,
            "height": scene.camera.height,
        },
        "features": {
            "triangle_count": f.triangle_count,
            "textures": f.textures,
            "emitters": f.emitters,
            "environment": f.environment,
            "light_types": list(f.light_types),
            "depth_complexity": f.depth_complexity,
            "twosided": f.twosided,
            "approximated_bsdfs": list(f.approximated_bsdfs),
            "glossy": f.glossy,
            "vertex_colors": f.vertex_colors,
        },
        "warnings": list(scene.warnings),
    }


def _light_summary(light: Light) -> dict:
    d = {"kind": light.kind, "intensity": list(light.intensity)}
    if light.direction is not None:
        d["direction"] = light.direction.tolist()
    if light.kind == "spot":
        d["cutoff_angle"], d["beam_width"] = light.cutoff_angle, light.beam_width
    if light.envmap is not None:
        d["envmap"] = list(light.envmap.shape[:2])
    return d


def _bsdf_summary(gloss: Gloss | None) -> dict:
    """The BSDF and its parameters (Lambertian: its albedo, above)."""
    if gloss is None:
        return {"type": "diffuse"}
    d = {"type": gloss.kind, "distribution": gloss.distribution, "alpha": gloss.alpha}
    d["specular_reflectance"] = list(gloss.specular_reflectance)
    if gloss.kind == "roughconductor":
        return {**d, "eta": list(gloss.eta), "k": list(gloss.k)}
    return {**d, "int_ior / ext_ior": gloss.eta[0], "nonlinear": gloss.nonlinear}
