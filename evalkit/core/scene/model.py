"""The in-memory scene's types: triangles only, float64 on the host, recentred.

Every importer (built-in, Mitsuba XML/dict, mesh files) ends in `evalkit.core.scene.assemble`,
which validates the input, removes degenerate triangles (and counts them), and recentres the
geometry, so the GPU side, the Mitsuba export and the Embree side all see exactly one description
of the scene.

Conventions (the same as Mitsuba's, so the export is a plain copy):
- positions are in scene space: world space minus `Scene.origin` (float64), so float32 uploads keep
  their precision however far from the world origin the scene was modelled;
- a texture is linear RGB, float32 (H, W, 3), looked up as Mitsuba's ``bitmap`` texture: the mesh's
  uv through the material's ``to_uv``, then texel row ``v*H`` and column ``u*W``, wrapped by its
  ``wrap_mode`` and filtered by its ``filter_type`` (`evalkit.core.scene.colour.sample_texture`);
- the camera looks along its local +z with +y up, as Mitsuba's ``perspective`` sensor does;
- area emission leaves the front side of a triangle only (counter-clockwise winding); a material
  that is not ``twosided`` reflects nothing from its back side.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field, replace

import numpy as np

RGB = tuple[float, float, float]

WRAP_MODES = ("repeat", "mirror", "clamp")  # Mitsuba's bitmap texture's wrap_mode
FILTER_TYPES = ("bilinear", "nearest")  # and its filter_type
LOOKUP = (WRAP_MODES[0], FILTER_TYPES[0])  # the default wrap mode and filter
LIGHT_KINDS = ("point", "spot", "directional", "constant", "envmap")
ENVIRONMENT_KINDS = ("constant", "envmap")
FOV_AXES = ("x", "y")


@dataclass(frozen=True)
class Gloss:
    """A glossy BSDF, as Mitsuba's ``roughconductor`` or ``roughplastic`` with the same parameters
    (evalkit/core/bsdf.py evaluates it, gpu_impl/shaders/include/bsdf.glsl on the GPU).

    ``alpha`` is the isotropic roughness of a Beckmann or GGX ``distribution``. A conductor has a
    complex index of refraction ``eta`` + i ``k`` per channel; a plastic the coat's relative index
    ``eta`` (all channels alike), ``nonlinear``, and Mitsuba's tables of the coat
    (``transmittance`` at cosines i / 63, ``internal_reflectance``: evalkit/core/bsdf.py:
    rough_plastic_tables); its diffuse base is the material's albedo or texture.
    """

    kind: str  # "roughconductor" or "roughplastic"
    distribution: str
    alpha: float
    eta: RGB
    k: RGB = (0.0, 0.0, 0.0)
    specular_reflectance: RGB = (1.0, 1.0, 1.0)
    nonlinear: bool = False
    transmittance: tuple[float, ...] = ()
    internal_reflectance: float = 0.0


@dataclass(frozen=True, eq=False)
class Material:
    """A material: Lambertian, or glossy where ``gloss`` says so; optionally emissive.

    ``albedo`` (a plastic's diffuse base; black for a conductor) is used where ``texture`` is None;
    with a texture it holds the texture's mean (for reports). A texture is looked up through
    ``to_uv`` (3x3 affine map from the mesh's uv to texture space, None for the identity),
    ``wrap_mode`` and ``filter_type``, as Mitsuba's. ``source_bsdf`` names what the file asked for,
    and ``approximated`` says whether the import approximated it (a smooth plastic or conductor
    made rough, a principled or glTF material mapped to the nearest gloss, another BSDF treated as
    diffuse, a procedural texture baked). With ``vertex_colors`` the diffuse reflectance is each
    mesh's own `Mesh.colors`, interpolated over every triangle as Mitsuba's ``mesh_attribute``
    texture of ``vertex_color`` interpolates it; ``albedo`` then holds their mean (for reports).
    """

    name: str
    albedo: RGB = (0.5, 0.5, 0.5)
    texture: np.ndarray | None = None  # (H, W, 3) float32, linear
    emission: RGB = (0.0, 0.0, 0.0)  # area-light radiance, front side only
    twosided: bool = False
    source_bsdf: str = "diffuse"
    approximated: bool = False
    to_uv: np.ndarray | None = None  # (3, 3) float64
    wrap_mode: str = "repeat"
    filter_type: str = "bilinear"
    gloss: Gloss | None = None
    vertex_colors: bool = False

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
    the geometric normal, as Mitsuba does without vertex normals); uvs (V, 2) float64 or None;
    colors (V, 3) float64 linear reflectance per vertex, where its material has ``vertex_colors``
    (face colours are vertex colours of unshared corners).
    """

    name: str
    positions: np.ndarray
    faces: np.ndarray
    material: int
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None
    motion: Motion | None = None  # rigid animation; None for static geometry
    colors: np.ndarray | None = None

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


CAMERA_KINDS = ("perspective", "orthographic")  # Mitsuba's sensors of the same names


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole perspective camera, or an orthographic one, as Mitsuba's sensors of those names.

    ``to_world`` (4x4 float64) maps camera space (looking along +z, +y up) to scene space. ``fov``
    is in degrees along ``fov_axis`` ('x' or 'y'). An orthographic camera has no fov: its rays
    start at camera-space points (x, y, 0), x from 1 to -1 across the film and y from 1 / aspect to
    -1 / aspect down it, through ``to_world``, whose scale sets how much it sees.
    """

    to_world: np.ndarray
    fov: float
    fov_axis: str
    width: int
    height: int
    near_clip: float = 1e-3
    far_clip: float = 1e4
    kind: str = "perspective"

    @property
    def orthographic(self) -> bool:
        return self.kind == "orthographic"

    @property
    def position(self) -> np.ndarray:
        return self.to_world[:3, 3]

    def film_size(self, width: int | None = None, height: int | None = None) -> tuple[int, int]:
        """The image size asked for: both sides as given; one side, with the other following the
        camera's aspect so that the framing stays; neither, the camera's own."""
        if width and height:
            return int(width), int(height)
        if width:
            return int(width), max(1, round(width * self.height / self.width))
        if height:
            return max(1, round(height * self.width / self.height)), int(height)
        return self.width, self.height

    def frame(self, centre: np.ndarray, width: int, height: int) -> dict:
        """The camera relative to ``centre`` for a ``width`` x ``height`` film: origin, to_world
        (3x3, Mitsuba's camera space: +x left, +y up, +z forward), the film's half extent along x
        and y in camera space at unit depth (perspective: the tans of the half field of view) or at
        the camera plane (orthographic: 1 and 1 / aspect), near, far and whether it is orthographic."""
        aspect = width / height
        if self.orthographic:
            tan_half = (1.0, 1.0 / aspect)
        else:
            t = math.tan(math.radians(self.fov) / 2.0)
            tan_half = (t, t / aspect) if self.fov_axis == "x" else (t * aspect, t)
        return {
            "origin": self.to_world[:3, 3] - centre,
            "to_world": self.to_world[:3, :3],
            "tan_half": tan_half,
            "near": self.near_clip,
            "far": self.far_clip,
            "orthographic": self.orthographic,
        }


def camera_rays(frame: dict, film: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The camera rays of a `Camera.frame` through film positions (N, 2) in [0, 1]^2 ((0, 0) the
    image's top left): origins and directions (N, 3), as shaders/paths/primary.glsl makes them; the
    directions are not normalized (a perspective ray's reaches the film at unit depth)."""
    tx, ty = frame["tan_half"]
    local = np.stack([(1.0 - 2.0 * film[:, 0]) * tx, (1.0 - 2.0 * film[:, 1]) * ty, np.zeros(len(film))], axis=1)
    if frame["orthographic"]:
        origins = frame["origin"] + local @ frame["to_world"].T
        directions = np.broadcast_to(frame["to_world"][:, 2], origins.shape)
    else:
        origins = np.broadcast_to(frame["origin"], local.shape)
        directions = (local + [0.0, 0.0, 1.0]) @ frame["to_world"].T
    return origins, directions


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
    glossy: bool = False  # a material has a `Gloss`
    vertex_colors: bool = False  # a material reflects its meshes' vertex colours

    @property
    def varying_reflectance(self) -> bool:
        """A surface's reflectance varies over it (a texture or vertex colours): what the shaders'
        TEXTURES variant compiles in."""
        return self.textures or self.vertex_colors


@dataclass(frozen=True, eq=False)
class SceneArrays:
    """All triangles of a scene in one indexed array set; a triangle's index here is its primitive id
    everywhere (GL bundles, Embree, BundleSet.prim_id): meshes in order, faces in order.

    positions (V, 3), normals (V, 3) (zero rows where the mesh has none), uvs (V, 2), colors (V, 3)
    (zero rows where the mesh has none) float64;
    faces (T, 3) int64; tri_material (T,) int64; tri_normal (T, 3) unit geometric normals
    (counter-clockwise front); tri_smooth (T,) bool, whether the shading normal interpolates
    ``normals`` (else it is ``tri_normal``); tri_area (T,) float64.
    """

    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    colors: np.ndarray
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
        positions, normals, uvs, colors, faces, material, smooth = [], [], [], [], [], [], []
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
            colors.append(np.zeros_like(p) if mesh.colors is None else mesh.colors)
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
            np.concatenate(colors),
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
            glossy=any(m.gloss is not None for m in mats),
            vertex_colors=any(m.vertex_colors for m in mats),
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
            if m.colors is not None:
                put(m.colors)
        for mat in self.materials:
            put(mat.albedo, mat.texture, mat.emission, mat.twosided)
            if mat.gloss is not None:  # diffuse scenes keep the hashes of their stored references
                put(mat.gloss)
            # The default lookup leaves the hashes of stored references as they were.
            if mat.texture is not None and (mat.to_uv is not None or (mat.wrap_mode, mat.filter_type) != LOOKUP):
                put(mat.to_uv, mat.wrap_mode, mat.filter_type)
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
        if c.orthographic:  # a perspective camera keeps the hashes of stored references
            put(c.kind)
        return h.hexdigest()
