"""The scene model and its importers. `load_scene` takes a built-in name or a file path."""

from __future__ import annotations

import functools
import os

from evalkit.core import cache
from evalkit.core.errors import InputError
from evalkit.core.scene.assemble import assemble
from evalkit.core.scene.builtin import BUILTIN_SCENES, ROUGHNESS_SCENES, builtin_scene
from evalkit.core.scene.mesh_import import load_mesh_file
from evalkit.core.scene.mitsuba_io import load_mitsuba_file
from evalkit.core.scene.model import Camera, Light, Material, Mesh, Motion, Scene, SceneFeatures

MITSUBA_EXTENSIONS = (".xml",)
MESH_EXTENSIONS = (".obj", ".ply", ".gltf", ".glb")


def builtin_names() -> list[str]:
    """The built-in scenes' names, and the form of those made at a roughness."""
    return sorted(BUILTIN_SCENES) + [f"{name}-ALPHA" for name in ROUGHNESS_SCENES]


def load_scene(spec: str | os.PathLike) -> Scene:
    """A built-in scene by name (`builtin_names`), a Mitsuba XML file, or an OBJ/PLY/glTF/GLB file;
    from the user cache when nothing it reads has changed since (`evalkit.core.cache`)."""
    spec = os.fspath(spec)
    ext = os.path.splitext(spec)[1].lower()
    make = builtin_scene(spec)
    builtin = make is not None
    if not builtin and ext in MITSUBA_EXTENSIONS:
        make = functools.partial(load_mitsuba_file, spec)
    elif not builtin and ext in MESH_EXTENSIONS:
        make = functools.partial(load_mesh_file, spec)
    if make is not None:
        # A file that is not there has no key: its importer says so in one line.
        key = cache.scene_key(spec, builtin) if builtin or os.path.isfile(spec) else None
        scene = cache.load("scenes", key) if key else None
        if scene is None:
            scene = make()
            if key:
                cache.store("scenes", key, scene)
        return scene
    if not os.path.exists(spec):
        raise InputError(spec, f"not a built-in scene ({', '.join(builtin_names())}) and no such file")
    raise InputError(
        spec, f"unsupported file type '{ext}' (expected {', '.join(MITSUBA_EXTENSIONS + MESH_EXTENSIONS)})"
    )


__all__ = [
    "Camera",
    "Light",
    "Material",
    "Mesh",
    "Motion",
    "Scene",
    "SceneFeatures",
    "assemble",
    "builtin_names",
    "load_scene",
]
