"""The scene model and its importers. `load_scene` takes a built-in name or a file path."""

from __future__ import annotations

import os

from evalkit.core import cache
from evalkit.core.errors import InputError
from evalkit.core.scene.assemble import assemble
from evalkit.core.scene.builtin import BUILTIN_SCENES
from evalkit.core.scene.mesh_import import load_mesh_file
from evalkit.core.scene.mitsuba_io import load_mitsuba_file
from evalkit.core.scene.model import Camera, Light, Material, Mesh, Motion, Scene, SceneFeatures

MITSUBA_EXTENSIONS = (".xml",)
MESH_EXTENSIONS = (".obj", ".ply", ".gltf", ".glb")


def builtin_names() -> list[str]:
    return sorted(BUILTIN_SCENES)


def load_scene(spec: str | os.PathLike) -> Scene:
    """A built-in scene by name (`builtin_names`), a Mitsuba XML file, or an OBJ/PLY/glTF/GLB file;
    from the user cache when nothing it reads has changed since (`evalkit.core.cache`)."""
    spec = os.fspath(spec)
    ext = os.path.splitext(spec)[1].lower()
    if spec in BUILTIN_SCENES:
        importer = BUILTIN_SCENES[spec]
    elif ext in MITSUBA_EXTENSIONS + MESH_EXTENSIONS and os.path.isfile(spec):
        importer = load_mitsuba_file if ext in MITSUBA_EXTENSIONS else load_mesh_file
    elif ext in MITSUBA_EXTENSIONS:
        return load_mitsuba_file(spec)  # its one-line error
    elif ext in MESH_EXTENSIONS:
        return load_mesh_file(spec)
    else:
        importer = None
    if importer is not None:
        key = cache.scene_key(spec, builtin=spec in BUILTIN_SCENES)
        scene = cache.load("scenes", key) if key else None
        if scene is None:
            scene = importer(spec) if spec not in BUILTIN_SCENES else importer()
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
