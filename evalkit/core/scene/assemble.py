"""Assembling a `Scene` from what an importer read: every check that a renderer would otherwise
get wrong silently, degenerate triangles removed and counted, the geometry recentred in float64;
and the camera and light a file without them gets."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from evalkit.core.errors import InputError
from evalkit.core.scene.model import (
    CAMERA_KINDS,
    FILTER_TYPES,
    FOV_AXES,
    LIGHT_KINDS,
    WRAP_MODES,
    Camera,
    Light,
    Material,
    Mesh,
    Scene,
)

# Embree silently ignores primitives with coordinates above about 1.8e18 (docs/platform.md).
MAX_COORDINATE = 1e18
# A triangle is degenerate when its area is below this fraction of its longest edge squared: the
# sine of its largest angle is then at float64 round-off level and no rasterizer or ray tracer can
# agree on what it covers (llvmpipe drops such triangles silently).
DEGENERATE_RELATIVE_AREA = 1e-12


def look_at(origin, target, up) -> np.ndarray:
    """Camera-to-world matrix looking from ``origin`` at ``target`` (Mitsuba's ``look_at``)."""
    origin, target, up = (np.asarray(v, dtype=np.float64) for v in (origin, target, up))
    d = target - origin
    d /= np.linalg.norm(d)
    left = np.cross(up, d)
    left /= np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, origin
    return m


def default_camera(lo: np.ndarray, hi: np.ndarray, width: int = 512, height: int = 512) -> Camera:
    """A camera that frames the box [lo, hi] from the front-right, above; used when a file has none."""
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-30)
    fov = 45.0
    view = np.array([0.45, 0.35, 1.0]) / np.linalg.norm([0.45, 0.35, 1.0])
    distance = radius / math.sin(math.radians(fov / 2)) * 1.05
    to_world = look_at(centre + distance * view, centre, [0.0, 1.0, 0.0])
    return Camera(to_world, fov, "y", width, height, near_clip=distance * 1e-4, far_clip=distance * 4)


def default_sun() -> Light:
    """The light used when a mesh file brings none: a sun from above and behind the default camera."""
    d = np.array([-0.3, -1.0, -0.5])
    return Light("directional", (3.0, 3.0, 3.0), direction=d / np.linalg.norm(d))


def assemble(
    name: str,
    source: str,
    meshes: list[Mesh],
    materials: list[Material],
    lights: list[Light],
    camera: Camera | None,
    warnings: list[str] | None = None,
) -> Scene:
    """Validate and recentre importer output into a `Scene`.

    Positions, light positions and the camera are in world space here. Raises `InputError` naming
    ``source`` for anything a renderer would silently drop or get wrong: NaN/Inf or huge
    coordinates, out-of-range indices, no geometry, emitters with zero area, bad cameras or lights.
    """
    warnings = list(warnings or [])
    if not meshes:
        raise InputError(source, "the scene has no triangle geometry")
    clean: list[Mesh] = []
    removed = 0
    for mesh in meshes:
        mesh = _validate_mesh(source, mesh, len(materials))
        keep = _nondegenerate(mesh)
        removed += int((~keep).sum())
        if keep.any():
            clean.append(_unit_normals(source, mesh if keep.all() else _subset_faces(mesh, keep)))
        else:
            warnings.append(f"mesh '{mesh.name}' has only degenerate triangles and was removed")
    if removed:
        warnings.append(f"{removed} degenerate triangle(s) (zero area or collinear) removed")
    if not clean:
        raise InputError(source, f"the scene has no triangle geometry ({removed} triangles, all degenerate)")

    clean = _vertex_colors(source, clean, materials, warnings)
    for i, mat in enumerate(materials):
        _check_finite(source, f"material '{mat.name}' albedo", mat.albedo)
        _check_finite(source, f"material '{mat.name}' emission", mat.emission)
        _check_not_negative(source, f"material '{mat.name}' albedo", mat.albedo)
        _check_not_negative(source, f"material '{mat.name}' emission", mat.emission)
        if mat.texture is not None:
            _check_finite(source, f"material '{mat.name}' texture", mat.texture)
            _check_not_negative(source, f"material '{mat.name}' texture", mat.texture)
            if mat.to_uv is not None:
                _check_finite(source, f"material '{mat.name}' to_uv", mat.to_uv)
            if mat.wrap_mode not in WRAP_MODES or mat.filter_type not in FILTER_TYPES:
                raise InputError(
                    source,
                    f"material '{mat.name}': texture wrap mode '{mat.wrap_mode}' / filter '{mat.filter_type}' "
                    f"is not one of {WRAP_MODES} / {FILTER_TYPES}",
                )
        if mat.emissive and any(m.material == i for m in meshes):
            area = sum(float(m.triangle_areas().sum()) for m in clean if m.material == i)
            if not area > 0.0:
                raise InputError(source, f"emitter '{mat.name}' has zero area: no triangle of it emits any light")
    for light in lights:
        _validate_light(source, light)

    lo = np.min([m.positions.min(axis=0) for m in clean], axis=0)
    hi = np.max([m.positions.max(axis=0) for m in clean], axis=0)
    origin = 0.5 * (lo + hi)
    if camera is None:
        camera = default_camera(lo, hi)
        warnings.append("no camera in the input; a default camera framing the scene is used")
    _validate_camera(source, camera)

    recentred = [
        replace(
            m,
            positions=m.positions - origin,
            motion=None if m.motion is None else replace(m.motion, pivot=tuple(np.asarray(m.motion.pivot) - origin)),
        )
        for m in clean
    ]
    moved_lights = [
        replace(light, position=None if light.position is None else light.position - origin) for light in lights
    ]
    cam_to_world = camera.to_world.copy()
    cam_to_world[:3, 3] -= origin
    return Scene(
        name=name,
        source=source,
        meshes=recentred,
        materials=list(materials),
        lights=moved_lights,
        camera=replace(camera, to_world=cam_to_world),
        origin=origin,
        warnings=warnings,
        degenerate_removed=removed,
    )


def _check_finite(source: str, what: str, value) -> None:
    a = np.asarray(value, dtype=np.float64)
    if not np.isfinite(a).all():
        raise InputError(source, f"{what} contains NaN or Inf")


def _check_not_negative(source: str, what: str, value) -> None:
    # Negative light is no light the renderers or Mitsuba agree on: an emitter with it was taken
    # for none, without a word.
    a = np.asarray(value, dtype=np.float64)
    if a.size and a.min() < 0:
        raise InputError(source, f"{what} is negative (down to {a.min():.4g})")


def _validate_mesh(source: str, mesh: Mesh, n_materials: int) -> Mesh:
    where = f"mesh '{mesh.name}'"
    p = np.asarray(mesh.positions, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(source, f"{where}: positions have shape {p.shape}, expected (V, 3)")
    f = np.asarray(mesh.faces)
    if f.size == 0 or p.shape[0] == 0:
        raise InputError(source, f"{where} is empty ({p.shape[0]} vertices, {f.size // 3} faces)")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise InputError(source, f"{where}: faces have shape {f.shape} and type {f.dtype}, expected (F, 3) integers")
    bad = ~np.isfinite(p).all(axis=1)
    if bad.any():
        raise InputError(
            source,
            f"{where}: {int(bad.sum())} vertices have NaN or Inf coordinates (first: vertex {int(np.argmax(bad))})",
        )
    if np.abs(p).max() > MAX_COORDINATE:
        raise InputError(
            source, f"{where}: coordinates reach {np.abs(p).max():.3g}, beyond the supported {MAX_COORDINATE:.0e}"
        )
    if f.min() < 0 or f.max() >= p.shape[0]:
        worst = int(f.min()) if f.min() < 0 else int(f.max())
        raise InputError(source, f"{where}: face index {worst} is out of range for {p.shape[0]} vertices")
    if not 0 <= mesh.material < n_materials:
        raise InputError(source, f"{where}: material index {mesh.material} is out of range")
    normals, uvs = mesh.normals, mesh.uvs
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != p.shape:
            raise InputError(source, f"{where}: {normals.shape[0]} normals for {p.shape[0]} vertices")
    if uvs is not None:
        uvs = np.asarray(uvs, dtype=np.float64)
        if uvs.shape != (p.shape[0], 2):
            raise InputError(source, f"{where}: uvs have shape {uvs.shape}, expected ({p.shape[0]}, 2)")
        if not np.isfinite(uvs).all():
            raise InputError(source, f"{where}: uvs contain NaN or Inf")
    colors = mesh.colors
    if colors is not None:
        colors = np.asarray(colors, dtype=np.float64)
        if colors.shape != p.shape:
            raise InputError(source, f"{where}: vertex colours have shape {colors.shape}, expected {p.shape}")
        if not np.isfinite(colors).all():
            raise InputError(source, f"{where}: vertex colours contain NaN or Inf")
    return replace(mesh, positions=p, faces=f.astype(np.int64), normals=normals, uvs=uvs, colors=colors)


def face_colors_at_corners(positions, faces, normals, uvs, face_colors):
    """A mesh whose faces have colours as one whose vertices have them: every corner its own
    vertex with its face's colour (faces still meet where their corners do: edges weld by
    position). Returns (positions, faces, normals, uvs, vertex colours)."""

    def corners(a):
        return None if a is None else a[faces].reshape(-1, a.shape[1])

    corner_faces = np.arange(3 * len(faces)).reshape(-1, 3)
    return corners(positions), corner_faces, corners(normals), corners(uvs), np.repeat(face_colors, 3, axis=0)


def _vertex_colors(source: str, meshes: list[Mesh], materials: list[Material], warnings: list[str]) -> list[Mesh]:
    """Checks that vertex colours and the materials that reflect them go together, and clamps
    colours to [0, 1] (a reflectance above 1 makes light), saying how many were clamped."""
    out = []
    for mesh in meshes:
        mat = materials[mesh.material]
        where = f"mesh '{mesh.name}'"
        if mat.vertex_colors and mesh.colors is None:
            raise InputError(source, f"{where}: material '{mat.name}' reflects vertex colours and the mesh has none")
        if mat.vertex_colors and mat.texture is not None:
            raise InputError(source, f"{where}: vertex colours and a texture on one material are not supported")
        if mesh.colors is not None and not mat.vertex_colors:
            mesh = replace(mesh, colors=None)  # colours no material reflects: not part of the scene
        elif mesh.colors is not None:
            outside = int(((mesh.colors < 0.0) | (mesh.colors > 1.0)).any(axis=1).sum())
            if outside:
                warnings.append(f"{where}: {outside} vertex colour(s) outside [0, 1] clamped (a reflectance)")
                mesh = replace(mesh, colors=np.clip(mesh.colors, 0.0, 1.0))
        out.append(mesh)
    return out


def _unit_normals(source: str, mesh: Mesh) -> Mesh:
    """Normalised shading normals; checked after degenerate removal, whose normals may be NaN."""
    if mesh.normals is None:
        return mesh
    length = np.linalg.norm(mesh.normals, axis=1)
    if not (np.isfinite(length).all() and (length > 0).all()):
        raise InputError(source, f"mesh '{mesh.name}': vertex normals contain NaN, Inf or zero vectors")
    return replace(mesh, normals=mesh.normals / length[:, None])


def _nondegenerate(mesh: Mesh) -> np.ndarray:
    p = mesh.positions[mesh.faces]
    e0, e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 1], p[:, 0] - p[:, 2]
    twice_area = np.linalg.norm(np.cross(e0, -e2), axis=1)
    longest_sq = np.max([np.einsum("ij,ij->i", e, e) for e in (e0, e1, e2)], axis=0)
    return twice_area > 2.0 * DEGENERATE_RELATIVE_AREA * longest_sq


def _subset_faces(mesh: Mesh, keep: np.ndarray) -> Mesh:
    faces = mesh.faces[keep]
    used, inverse = np.unique(faces, return_inverse=True)

    def pick(a):
        return None if a is None else a[used]

    return replace(
        mesh,
        positions=mesh.positions[used],
        faces=inverse.reshape(-1, 3),
        normals=pick(mesh.normals),
        uvs=pick(mesh.uvs),
        colors=pick(mesh.colors),
    )


def _validate_light(source: str, light: Light) -> None:
    what = f"{light.kind} light"
    if light.kind not in LIGHT_KINDS:
        raise InputError(source, f"unknown light kind '{light.kind}'")
    _check_finite(source, f"{what} intensity", light.intensity)
    if min(light.intensity) < 0:
        raise InputError(source, f"{what} has a negative intensity {light.intensity}")
    if light.kind in ("point", "spot"):
        if light.position is None:
            raise InputError(source, f"{what} has no position")
        _check_finite(source, f"{what} position", light.position)
    no_direction = light.direction is None or not np.isfinite(light.direction).all() or not np.any(light.direction)
    if light.kind in ("spot", "directional") and no_direction:
        raise InputError(source, f"{what} has no valid direction")
    if light.kind == "spot" and not (0 < (light.cutoff_angle or 0) <= 180):
        raise InputError(source, f"spot light cutoff angle {light.cutoff_angle} is outside (0, 180] degrees")
    if light.kind == "envmap":
        if light.envmap is None or light.envmap.ndim != 3 or light.envmap.shape[2] != 3:
            raise InputError(source, "envmap light has no (H, W, 3) image")
        _check_finite(source, "envmap image", light.envmap)


def _validate_camera(source: str, camera: Camera) -> None:
    if camera.kind not in CAMERA_KINDS:
        raise InputError(source, f"camera kind '{camera.kind}' is not one of {CAMERA_KINDS}")
    if camera.fov_axis not in FOV_AXES:
        raise InputError(source, f"camera fov axis '{camera.fov_axis}' is not one of {FOV_AXES}")
    if not camera.orthographic and not 0 < camera.fov < 180:
        raise InputError(source, f"camera fov {camera.fov} is outside (0, 180) degrees")
    if camera.orthographic and not abs(np.linalg.det(camera.to_world[:3, :3])) > 0:
        raise InputError(source, "the orthographic camera's transform is singular: it sees nothing")
    if camera.width < 1 or camera.height < 1:
        raise InputError(source, f"camera resolution {camera.width}x{camera.height} is empty")
    _check_finite(source, "camera transform", camera.to_world)
