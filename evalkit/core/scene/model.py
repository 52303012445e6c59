"""The in-memory scene: triangles only, float64 on the host, recentred.

Every importer (built-in, Mitsuba XML/dict, mesh files) ends in `assemble`, which validates the
input, removes degenerate triangles (and counts them), and recentres the geometry, so the GPU side,
the Mitsuba export and the Embree side all see exactly one description of the scene.

Conventions (the same as Mitsuba's, so the export is a plain copy):
- positions are in scene space: world space minus `Scene.origin` (float64), so float32 uploads keep
  their precision however far from the world origin the scene was modelled;
- a texture is linear RGB, float32 (H, W, 3); uv (u, v) looks up texel row ``v*H`` and column
  ``u*W``, with repeat wrapping and bilinear filtering;
- the camera looks along its local +z with +y up, as Mitsuba's ``perspective`` sensor does;
- area emission leaves the front side of a triangle only (counter-clockwise winding); a material
  that is not ``twosided`` reflects nothing from its back side.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field, replace

import numpy as np

from evalkit.core.errors import InputError

RGB = tuple[float, float, float]

LIGHT_KINDS = ("point", "spot", "directional", "constant", "envmap")
ENVIRONMENT_KINDS = ("constant", "envmap")
FOV_AXES = ("x", "y")

# Embree silently ignores primitives with coordinates above about 1.8e18 (docs/MEASURED_FACTS.md).
MAX_COORDINATE = 1e18
# A triangle is degenerate when its area is below this fraction of its longest edge squared: the
# sine of its largest angle is then at float64 round-off level and no rasterizer or ray tracer can
# agree on what it covers (llvmpipe drops such triangles silently).
DEGENERATE_RELATIVE_AREA = 1e-12


def rgb(value) -> RGB:
    """Any scalar or 3-vector as an rgb tuple of floats."""
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.size != 3:
        raise ValueError(f"expected a scalar or an rgb triple, got {a.size} values")
    return (float(a[0]), float(a[1]), float(a[2]))


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function inverted: 8-bit texture values (scaled to [0, 1]) to linear."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup with repeat wrapping at uv (N, 2), Mitsuba's convention: texel (row, col)
    has its centre at ((row + 0.5) / H, (col + 0.5) / W) in (v, u). Returns (N, 3) float64."""
    h, w = texture.shape[:2]
    x = np.asarray(uv[:, 0], dtype=np.float64) * w - 0.5
    y = np.asarray(uv[:, 1], dtype=np.float64) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    t = texture.astype(np.float64)

    def at(yy, xx):
        return t[np.mod(yy, h), np.mod(xx, w)]

    return (1 - fy) * ((1 - fx) * at(y0, x0) + fx * at(y0, x0 + 1)) + fy * (
        (1 - fx) * at(y0 + 1, x0) + fx * at(y0 + 1, x0 + 1)
    )


@dataclass(frozen=True, eq=False)
class Material:
    """A diffuse material, optionally emissive.

    ``albedo`` is used where ``texture`` is None; with a texture it holds the texture's mean (for
    reports). ``source_bsdf`` names what the file asked for, and ``approximated`` says whether
    treating it as diffuse is an approximation (a plastic or a conductor, say).
    """

    name: str
    albedo: RGB = (0.5, 0.5, 0.5)
    texture: np.ndarray | None = None  # (H, W, 3) float32, linear
    emission: RGB = (0.0, 0.0, 0.0)  # area-light radiance, front side only
    twosided: bool = False
    source_bsdf: str = "diffuse"
    approximated: bool = False

    @property
    def emissive(self) -> bool:
        return max(self.emission) > 0.0


@dataclass(frozen=True)
class Motion:
    """A rigid motion over time: at time t (seconds) a point x moves to
    ``pivot + R(axis, degrees_per_second * t) (x - pivot) + velocity * t``."""

    pivot: tuple[float, float, float]
    axis: tuple[float, float, float] = (0.0, 1.0, 0.0)
    degrees_per_second: float = 0.0
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def rotation(self, time: float) -> np.ndarray:
        a = np.asarray(self.axis, dtype=np.float64)
        a = a / np.linalg.norm(a)
        angle = math.radians(self.degrees_per_second * time)
        k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
        return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)  # Rodrigues

    def apply(self, mesh: Mesh, time: float) -> Mesh:
        """The mesh posed at ``time``, without a motion (a static snapshot)."""
        r = self.rotation(time)
        pivot = np.asarray(self.pivot, dtype=np.float64)
        positions = (mesh.positions - pivot) @ r.T + pivot + np.asarray(self.velocity, dtype=np.float64) * time
        normals = None if mesh.normals is None else mesh.normals @ r.T
        return replace(mesh, positions=positions, normals=normals, motion=None)


@dataclass(frozen=True, eq=False)
class Mesh:
    """One triangle mesh with a single material.

    positions (V, 3) float64 in scene space; faces (F, 3) int64 vertex indices, counter-clockwise
    seen from the front; normals (V, 3) float64 unit shading normals or None (flat shading with
    the geometric normal, as Mitsuba does without vertex normals); uvs (V, 2) float64 or None.
    """

    name: str
    positions: np.ndarray
    faces: np.ndarray
    material: int
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None
    motion: Motion | None = None  # rigid animation; None for static geometry

    def triangle_areas(self) -> np.ndarray:
        p = self.positions[self.faces]
        return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


@dataclass(frozen=True, eq=False)
class Light:
    """A light that is not a triangle.

    ``intensity`` is in the units of the matching Mitsuba emitter: radiant intensity (W/sr) for
    ``point`` and ``spot``, irradiance (W/m^2) for ``directional``, radiance for ``constant``, and
    a scale factor for ``envmap``. ``direction`` is the direction light travels (unit). Spot angles
    are in degrees. ``envmap`` is a linear (H, W, 3) float32 lat-long map and ``to_world`` its
    4x4 orientation, both as Mitsuba's ``envmap`` plugin reads them.
    """

    kind: str
    intensity: RGB
    position: np.ndarray | None = None
    direction: np.ndarray | None = None
    cutoff_angle: float | None = None
    beam_width: float | None = None
    envmap: np.ndarray | None = None
    to_world: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole perspective camera.

    ``to_world`` (4x4 float64) maps camera space (looking along +z, +y up) to scene space. ``fov``
    is in degrees along ``fov_axis`` ('x' or 'y').
    """

    to_world: np.ndarray
    fov: float
    fov_axis: str
    width: int
    height: int
    near_clip: float = 1e-3
    far_clip: float = 1e4

    @property
    def position(self) -> np.ndarray:
        return self.to_world[:3, 3]

    def frame(self, centre: np.ndarray, width: int, height: int) -> dict:
        """The camera relative to ``centre`` for a ``width`` x ``height`` film: origin, to_world
        (3x3, Mitsuba's camera space: +x left, +y up, +z forward), tan of the half field of view
        along x and y, near and far."""
        aspect = width / height
        t = math.tan(math.radians(self.fov) / 2.0)
        tan_half = (t, t / aspect) if self.fov_axis == "x" else (t * aspect, t)
        return {
            "origin": self.to_world[:3, 3] - centre,
            "to_world": self.to_world[:3, :3],
            "tan_half": tan_half,
            "near": self.near_clip,
            "far": self.far_clip,
        }


@dataclass(frozen=True)
class SceneFeatures:
    """What a scene uses, so later stages can skip the work it does not need."""

    triangle_count: int
    textures: bool
    emitters: bool  # emissive triangles
    environment: str | None  # 'constant', 'envmap' or None
    light_types: tuple[str, ...]  # sorted; 'area' stands for emissive triangles
    depth_complexity: float  # mean surfaces crossed by a line through the bounding sphere
    twosided: bool
    approximated_bsdfs: tuple[str, ...]


@dataclass(frozen=True, eq=False)
class SceneArrays:
    """All triangles of a scene in one indexed array set; a triangle's index here is its primitive id
    everywhere (GL bundles, Embree, BundleSet.prim_id): meshes in order, faces in order.

    positions (V, 3), normals (V, 3) (zero rows where the mesh has none), uvs (V, 2) float64;
    faces (T, 3) int64; tri_material (T,) int64; tri_normal (T, 3) unit geometric normals
    (counter-clockwise front); tri_smooth (T,) bool, whether the shading normal interpolates
    ``normals`` (else it is ``tri_normal``); tri_area (T,) float64.
    """

    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    faces: np.ndarray
    tri_material: np.ndarray
    tri_normal: np.ndarray
    tri_smooth: np.ndarray
    tri_area: np.ndarray


@dataclass(eq=False)
class Scene:
    """A validated, recentred scene. Build one with `assemble`, not directly."""

    name: str
    source: str
    meshes: list[Mesh]
    materials: list[Material]
    lights: list[Light]
    camera: Camera
    origin: np.ndarray  # world position of the scene-space origin, float64 (3,)
    warnings: list[str] = field(default_factory=list)
    degenerate_removed: int = 0

    @property
    def triangle_count(self) -> int:
        return int(sum(len(m.faces) for m in self.meshes))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo = np.min([m.positions.min(axis=0) for m in self.meshes], axis=0)
        hi = np.max([m.positions.max(axis=0) for m in self.meshes], axis=0)
        return lo, hi

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """Centre (the bounds' centre) and radius enclosing every vertex, in scene space."""
        lo, hi = self.bounds()
        centre = 0.5 * (lo + hi)
        radius = max(float(np.linalg.norm(m.positions - centre, axis=1).max()) for m in self.meshes)
        return centre, radius

    def arrays(self) -> SceneArrays:
        """The scene's triangles as one `SceneArrays` (see there for the primitive ids)."""
        positions, normals, uvs, faces, material, smooth = [], [], [], [], [], []
        base = 0
        for mesh in self.meshes:
            p, f, n, uv = mesh.positions, mesh.faces, mesh.normals, mesh.uvs
            if uv is None and self.materials[mesh.material].texture is not None:
                # Mitsuba's uv on a mesh without texcoords is the barycentric (b1, b2): per-corner
                # values, so the vertices cannot be shared.
                p, f = p[f].reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3)
                n = None if n is None else n[mesh.faces].reshape(-1, 3)
                uv = np.tile([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], (len(f), 1))
            positions.append(p)
            normals.append(np.zeros_like(p) if n is None else n)
            uvs.append(np.zeros((len(p), 2)) if uv is None else uv)
            faces.append(f + base)
            material.append(np.full(len(f), mesh.material, dtype=np.int64))
            smooth.append(np.full(len(f), n is not None))
            base += len(p)
        positions = np.concatenate(positions)
        faces = np.concatenate(faces)
        tri = positions[faces]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        twice_area = np.linalg.norm(cross, axis=1)
        return SceneArrays(
            positions,
            np.concatenate(normals),
            np.concatenate(uvs),
            faces,
            np.concatenate(material),
            cross / twice_area[:, None],
            np.concatenate(smooth),
            0.5 * twice_area,
        )

    @property
    def animated(self) -> bool:
        return any(m.motion is not None for m in self.meshes)

    def at(self, time: float) -> Scene:
        """The scene posed at ``time`` (seconds) as a static scene; itself when nothing moves."""
        if not self.animated:
            return self
        return replace(self, meshes=[m if m.motion is None else m.motion.apply(m, time) for m in self.meshes])

    def surface_area(self) -> float:
        return float(sum(m.triangle_areas().sum() for m in self.meshes))

    def features(self) -> SceneFeatures:
        used = {m.material for m in self.meshes}
        mats = [self.materials[i] for i in sorted(used)]
        kinds = {light.kind for light in self.lights}
        if any(m.emissive for m in mats):
            kinds.add("area")
        env = [light.kind for light in self.lights if light.kind in ENVIRONMENT_KINDS]
        _, radius = self.bounding_sphere()
        # Cauchy-Crofton: a surface of area A is crossed on average 2A / S(K) times by isotropic
        # random lines meeting a convex body K; with K the bounding sphere, S(K) = 4 pi r^2.
        depth = self.surface_area() / (2.0 * math.pi * radius * radius) if radius > 0 else 0.0
        return SceneFeatures(
            triangle_count=self.triangle_count,
            textures=any(m.texture is not None for m in mats),
            emitters=any(m.emissive for m in mats),
            environment=env[0] if env else None,
            light_types=tuple(sorted(kinds)),
            depth_complexity=depth,
            twosided=any(m.twosided for m in mats),
            approximated_bsdfs=tuple(sorted({f"{m.name} ({m.source_bsdf})" for m in mats if m.approximated})),
        )

    def content_hash(self) -> str:
        """SHA-256 of everything that changes an image: geometry, materials, lights and camera."""
        h = hashlib.sha256()

        def put(*items):
            for x in items:
                if x is None:
                    h.update(b"\x00none")
                elif isinstance(x, np.ndarray):
                    a = np.ascontiguousarray(x)
                    h.update(f"{a.dtype.str}{a.shape}".encode())
                    h.update(a.tobytes())
                else:
                    h.update(repr(x).encode())

        put(self.origin)
        for m in self.meshes:
            put(m.positions, m.faces.astype(np.int64), m.normals, m.uvs, m.material)
            if m.motion is not None:  # static scenes keep the hashes their stored references have
                put(m.motion)
        for mat in self.materials:
            put(mat.albedo, mat.texture, mat.emission, mat.twosided)
        for light in self.lights:
            put(
                light.kind,
                light.intensity,
                light.position,
                light.direction,
                light.cutoff_angle,
                light.beam_width,
                light.envmap,
                light.to_world,
            )
        c = self.camera
        put(c.to_world, c.fov, c.fov_axis, c.width, c.height, c.near_clip, c.far_clip)
        return h.hexdigest()

    def summary(self) -> dict:
        """A JSON-ready description, as `evalkit scene info` prints it."""
        lo, hi = self.bounds()
        centre, radius = self.bounding_sphere()
        f = self.features()
        used = sorted({m.material for m in self.meshes})
        return {
            "name": self.name,
            "source": self.source,
            "content_hash": self.content_hash(),
            "triangles": self.triangle_count,
            "meshes": len(self.meshes),
            "degenerate_removed": self.degenerate_removed,
            "origin": self.origin.tolist(),
            "bounds": {"min": (lo + self.origin).tolist(), "max": (hi + self.origin).tolist()},
            "bounding_radius": radius,
            "surface_area": self.surface_area(),
            "materials": [
                {
                    "name": self.materials[i].name,
                    "albedo": list(self.materials[i].albedo),
                    "texture": None if self.materials[i].texture is None else list(self.materials[i].texture.shape[:2]),
                    "emission": list(self.materials[i].emission),
                    "twosided": self.materials[i].twosided,
                    "source_bsdf": self.materials[i].source_bsdf,
                    "approximated": self.materials[i].approximated,
                }
                for i in used
            ],
            "lights": [_light_summary(light) for light in self.lights],
            "camera": {
                "position": (self.camera.position + self.origin).tolist(),
                "fov": self.camera.fov,
                "fov_axis": self.camera.fov_axis,
                "width": self.camera.width,
                "height": self.camera.height,
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
            },
            "warnings": list(self.warnings),
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

    for i, mat in enumerate(materials):
        _check_finite(source, f"material '{mat.name}' albedo", mat.albedo)
        _check_finite(source, f"material '{mat.name}' emission", mat.emission)
        if mat.texture is not None:
            _check_finite(source, f"material '{mat.name}' texture", mat.texture)
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
    return Mesh(mesh.name, p, f.astype(np.int64), mesh.material, normals, uvs, mesh.motion)


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

    return Mesh(
        mesh.name,
        mesh.positions[used],
        inverse.reshape(-1, 3),
        mesh.material,
        pick(mesh.normals),
        pick(mesh.uvs),
        mesh.motion,
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
    if camera.fov_axis not in FOV_AXES:
        raise InputError(source, f"camera fov axis '{camera.fov_axis}' is not one of {FOV_AXES}")
    if not 0 < camera.fov < 180:
        raise InputError(source, f"camera fov {camera.fov} is outside (0, 180) degrees")
    if camera.width < 1 or camera.height < 1:
        raise InputError(source, f"camera resolution {camera.width}x{camera.height} is empty")
    _check_finite(source, "camera transform", camera.to_world)
