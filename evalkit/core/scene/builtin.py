"""Built-in scenes.

- ``cornell-box`` is ``mi.cornell_box()`` itself, read through the Mitsuba importer.
- ``glossy-box`` is cornell-box with a rough plastic floor and a rough copper sphere in place of
  its tall box (GGX, roughness `GLOSSY_ALPHA`); ``glossy-box-0.3`` is the same at roughness 0.3.
- ``furnace`` is a closed cube of one diffuse, emissive material seen from inside. Every surface
  has the same outgoing radiance, so each bounce adds a known amount (`furnace_radiance`).
- ``atrium-animated`` is ``atrium`` with a ball circling the courtyard (`Motion`), the poster's
  animated scene; render it at a ``time``, or with a time step per frame.
- ``atrium`` is procedural and Sponza-like: two storeys of column arcades with arches around an
  open courtyard, hanging cloth, textured floor and cloth, a sun and a point light. It has over
  250k triangles, because the cost gap between perfect and imperfect bundles only shows on large
  scenes. It is generated deterministically in about a second.
- ``atrium-dense`` is ``atrium`` with every triangle split into 9 in its own plane: the same
  surfaces in 2.4 M triangles, where perfect bundles pay for every triangle and imperfect ones
  only for their points.
- ``parts`` is a tray of small diffuse parts, smooth-shaded (vertex normals), packed with narrow
  crevices between them and contacts where they rest on the tray, lit only by an environment map
  (a sky with a bright lobe around the sun): fine geometry under environment light, where a bundle pixel is as wide as
  the gaps.
- ``lit-room`` is a closed room lit only indirectly: a narrow spot light by the floor aims at the
  ceiling, so everything but a small patch of the ceiling gets its light after a bounce. Eye paths
  find that patch by chance; paths that start at the light (bidirectional) do not need to.
"""

from __future__ import annotations

import contextlib
import functools
import math

import numpy as np

from evalkit.core.mitsuba_env import mitsuba
from evalkit.core.scene.assemble import assemble, look_at
from evalkit.core.scene.colour import srgb_to_linear
from evalkit.core.scene.mitsuba_io import load_mitsuba_dict
from evalkit.core.scene.model import Camera, Light, Material, Mesh, Motion, Scene
from evalkit.core.scene.tessellate import box, subdivide, surface, unit_disk, unit_sphere

FURNACE_ALBEDO = 0.5
FURNACE_EMISSION = 1.0
GLOSSY_ALPHA = 0.1


def cornell_box() -> Scene:
    mi = mitsuba()
    return load_mitsuba_dict(mi.cornell_box(), name="cornell-box", source="cornell-box")


def glossy_box(alpha: float = GLOSSY_ALPHA) -> Scene:
    """cornell-box with a rough plastic floor and, in place of the tall box, a rough copper
    sphere: both GGX of roughness ``alpha``, read through the Mitsuba importer like cornell-box."""
    mi = mitsuba()
    d = mi.cornell_box()
    white = d["white"]["reflectance"]
    d["floor"]["bsdf"] = {"type": "roughplastic", "distribution": "ggx", "alpha": alpha, "diffuse_reflectance": white}
    d["large-box"] = {
        "type": "sphere",
        "center": [-0.33, -0.65, -0.28],
        "radius": 0.35,
        "bsdf": {"type": "roughconductor", "distribution": "ggx", "alpha": alpha, "material": "Cu"},
    }
    name = "glossy-box" if alpha == GLOSSY_ALPHA else f"glossy-box-{alpha:g}"
    return load_mitsuba_dict(d, name=name, source=name)


# Built-in scenes made at a roughness given after their name: "glossy-box-0.3".
ROUGHNESS_SCENES = {"glossy-box": glossy_box}


def builtin_scene(spec: str):
    """The maker of built-in scene ``spec`` (a name of `BUILTIN_SCENES`, or of `ROUGHNESS_SCENES`
    followed by "-" and a roughness in (0, 1]), or None."""
    if spec in BUILTIN_SCENES:
        return BUILTIN_SCENES[spec]
    name, _, alpha = spec.rpartition("-")
    if name in ROUGHNESS_SCENES:
        with contextlib.suppress(ValueError):
            if 0.0 < float(alpha) <= 1.0:
                return functools.partial(ROUGHNESS_SCENES[name], float(alpha))
    return None


def furnace_radiance(max_depth: int) -> float:
    """Radiance of every furnace pixel for Mitsuba's path ``max_depth`` (1: emission seen directly,
    2: plus direct lighting, k + 2: plus k indirect bounces): Le * sum_{j < max_depth} albedo^j."""
    return FURNACE_EMISSION * sum(FURNACE_ALBEDO**j for j in range(max_depth))


def furnace() -> Scene:
    """The inside of the cube [-1, 1]^3, each face split 4x4, all emitting and reflecting."""
    positions, faces = box(np.array([-1.0] * 3), np.array([1.0] * 3), subdivisions=4, inward=True)
    material = Material("furnace", albedo=(FURNACE_ALBEDO,) * 3, emission=(FURNACE_EMISSION,) * 3)
    camera = Camera(look_at([0, 0, 0], [0, 0, -1], [0, 1, 0]), fov=90.0, fov_axis="x", width=128, height=128)
    return assemble("furnace", "furnace", [Mesh("enclosure", positions, faces, 0)], [material], [], camera)


def lit_room() -> Scene:
    """A 6 x 3 x 6 room seen from inside, two boxes on its floor, and a spot light of a 12 degree
    cone by the foot of the wall behind the camera, aimed at the ceiling above it: the patch it
    lights is out of view, so every pixel but a few is lit indirectly."""
    walls = box(np.array([-3.0, 0.0, -3.0]), np.array([3.0, 3.0, 3.0]), subdivisions=6, inward=True)
    tall = box(np.array([-1.9, 0.0, -1.6]), np.array([-0.9, 1.6, -0.6]), subdivisions=2)
    low = box(np.array([0.6, 0.0, -0.4]), np.array([1.6, 0.7, 0.6]), subdivisions=2)
    materials = [
        Material("walls", albedo=(0.75, 0.75, 0.72)),
        Material("tall", albedo=(0.7, 0.25, 0.2)),
        Material("low", albedo=(0.2, 0.35, 0.7)),
    ]
    meshes = [Mesh("walls", *walls, 0), Mesh("tall", *tall, 1), Mesh("low", *low, 2)]
    aim = np.array([0.2, 1.0, 0.1])
    spot = Light(
        "spot",
        (2400.0, 2400.0, 2400.0),
        position=np.array([1.8, 0.2, 2.5]),
        direction=aim / np.linalg.norm(aim),
        cutoff_angle=12.0,
        beam_width=9.0,
    )
    camera = Camera(
        look_at([0.0, 1.4, 2.9], [0.0, 1.0, -3.0], [0.0, 1.0, 0.0]), fov=70.0, fov_axis="x", width=128, height=96
    )
    return assemble("lit-room", "lit-room", meshes, materials, [spot], camera)


# --- atrium ---------------------------------------------------------------------------------------

_STOREY_HEIGHT = 5.5
_SPRING = 3.4  # column top (arch springline) above the storey floor
_SPANDREL_TOP = 5.0
_COLUMN_RADIUS = 0.35
_HALF_LENGTH, _HALF_WIDTH = 10.0, 6.0  # the column lines around the courtyard
_OUTER_X, _OUTER_Z = 14.0, 10.0
_LONG_COLUMNS = np.linspace(-_HALF_LENGTH, _HALF_LENGTH, 9)
_SHORT_COLUMNS = np.linspace(-_HALF_WIDTH, _HALF_WIDTH, 5)
_COLUMN_SEGMENTS = (48, 24)  # around, along
_ARCH_SEGMENTS = 48
_CLOTH_SEGMENTS = (112, 72)  # down, across
# atrium-animated: a ball rolling around the courtyard, one turn in 12 s.
_BALL_RADIUS, _BALL_ORBIT, _BALL_DEGREES_PER_SECOND = 0.8, 3.5, 30.0


def atrium(animated: bool = False) -> Scene:
    """The atrium; ``animated`` adds the poster's moving object: a blue ball circling the
    courtyard (``atrium-animated``)."""
    parts: dict[str, list] = {"stone": [], "column": [], "floor": [], "cloth": []}
    flat: list = []  # boxes: flat-shaded stone
    for storey in range(2):
        base = storey * _STOREY_HEIGHT
        for x in _LONG_COLUMNS:
            for z in (-_HALF_WIDTH, _HALF_WIDTH):
                _column(parts["column"], flat, x, z, base)
        for z in _SHORT_COLUMNS[1:-1]:
            for x in (-_HALF_LENGTH, _HALF_LENGTH):
                _column(parts["column"], flat, x, z, base)
        for z in (-_HALF_WIDTH, _HALF_WIDTH):
            for a, b in zip(_LONG_COLUMNS[:-1], _LONG_COLUMNS[1:]):
                _arch(parts["stone"], a, b, z, base, along_x=True)
        for x in (-_HALF_LENGTH, _HALF_LENGTH):
            for a, b in zip(_SHORT_COLUMNS[:-1], _SHORT_COLUMNS[1:]):
                _arch(parts["stone"], a, b, x, base, along_x=False)
        top = base + _SPANDREL_TOP
        inner = _HALF_WIDTH - _COLUMN_RADIUS
        for s in (-1, 1):  # the gallery ceiling / floor slab above this storey, as a ring of boxes
            flat.append(
                box(
                    np.array([-_OUTER_X, top, min(s * inner, s * _OUTER_Z)]),
                    np.array([_OUTER_X, top + 0.5, max(s * inner, s * _OUTER_Z)]),
                )
            )
            xi = _HALF_LENGTH - _COLUMN_RADIUS
            flat.append(
                box(
                    np.array([min(s * xi, s * _OUTER_X), top, -inner]),
                    np.array([max(s * xi, s * _OUTER_X), top + 0.5, inner]),
                )
            )
    height = 2 * _STOREY_HEIGHT
    for s in (-1, 1):  # outer walls
        flat.append(
            box(
                np.array([-_OUTER_X - 0.3, 0.0, s * _OUTER_Z - 0.15]),
                np.array([_OUTER_X + 0.3, height, s * _OUTER_Z + 0.15]),
            )
        )
        flat.append(
            box(np.array([s * _OUTER_X - 0.15, 0.0, -_OUTER_Z]), np.array([s * _OUTER_X + 0.15, height, _OUTER_Z]))
        )
    # Ground: one textured quad under courtyard and galleries; uv repeats the tile texture.
    g = np.array(
        [[-_OUTER_X, 0, -_OUTER_Z], [_OUTER_X, 0, -_OUTER_Z], [_OUTER_X, 0, _OUTER_Z], [-_OUTER_X, 0, _OUTER_Z]], float
    )
    parts["floor"].append((g, np.array([[0, 2, 1], [0, 3, 2]]), np.tile([0.0, 1.0, 0.0], (4, 1)), g[:, [0, 2]] / 2.0))
    # Curtains hang in the upper gallery behind the arches of one long side.
    for a, b in zip(_LONG_COLUMNS[:-1], _LONG_COLUMNS[1:]):
        _cloth(parts["cloth"], a + 0.45, b - 0.45, _HALF_WIDTH + 0.75, _STOREY_HEIGHT + _SPANDREL_TOP - 0.1, 3.8)

    rng = np.random.default_rng(7)
    materials = [
        Material("sandstone", albedo=(0.62, 0.55, 0.44), twosided=True),
        Material("column", albedo=(0.70, 0.66, 0.58), twosided=True),
        _textured("floor-tiles", _tile_texture(rng)),
        _textured("curtain", _stripe_texture()),
    ]
    meshes = [Mesh("walls-and-slabs", *_merge(flat), material=0)]
    for key, material in (("stone", 0), ("column", 1), ("floor", 2), ("cloth", 3)):
        p, f, n, uv = _merge(parts[key])
        meshes.append(Mesh(key, p, f, material=material, normals=n, uvs=uv))
    if animated:
        materials.append(Material("ball", albedo=(0.15, 0.3, 0.65), twosided=False))
        p, f, n, uv = unit_sphere((64, 32))
        centre = np.array([_BALL_ORBIT, _BALL_RADIUS + 0.05, 0.0])
        meshes.append(
            Mesh(
                "ball",
                p * _BALL_RADIUS + centre,
                f,
                material=len(materials) - 1,
                normals=n,
                uvs=uv,
                motion=Motion(pivot=(0.0, 0.0, 0.0), axis=(0.0, 1.0, 0.0), degrees_per_second=_BALL_DEGREES_PER_SECOND),
            )
        )
    sun = np.array([0.35, -1.0, 0.25])
    lights = [
        Light("directional", (6.0, 5.6, 5.0), direction=sun / np.linalg.norm(sun)),
        Light("point", (60.0, 45.0, 30.0), position=np.array([-12.0, 3.0, -8.0])),
    ]
    camera = Camera(
        look_at([-8.5, 1.7, -1.5], [6.0, 4.6, 1.5], [0, 1, 0]),
        fov=75.0,
        fov_axis="x",
        width=960,
        height=512,
        near_clip=0.01,
        far_clip=100.0,
    )
    name = "atrium-animated" if animated else "atrium"
    return assemble(name, name, meshes, materials, lights, camera)


def atrium_animated() -> Scene:
    return atrium(animated=True)


# atrium-dense: each triangle split into DENSE_SPLIT^2 in its own plane.
DENSE_SPLIT = 3


def atrium_dense() -> Scene:
    scene = atrium()
    meshes = []
    for m in scene.meshes:
        p, f, n, uv = subdivide(m.positions, m.faces, m.normals, m.uvs, DENSE_SPLIT)
        meshes.append(Mesh(m.name, p, f, material=m.material, normals=n, uvs=uv))
    return assemble("atrium-dense", "atrium-dense", meshes, scene.materials, scene.lights, scene.camera)


# --- parts ----------------------------------------------------------------------------------------

# 24 x 24 parts 0.3 apart: pegs of radius 0.135 leave 0.03 gaps, a third of a bundle pixel at R = 128
# (the scene's bounding radius is about 4.4, so a pixel is 0.07 wide at R = 128).
_PARTS_GRID = 24
_PARTS_PITCH = 0.3
_PEG_RADIUS = 0.135


def parts() -> Scene:
    """Pegs (smooth cylinders with flat caps), balls and lying rods on a tray with a rim, under a
    sky map; deterministic."""
    rng = np.random.default_rng(11)
    kinds = {"peg": [], "ball": [], "rod": []}
    half = 0.5 * (_PARTS_GRID - 1) * _PARTS_PITCH
    for i in range(_PARTS_GRID):
        for j in range(_PARTS_GRID):
            x, z = -half + i * _PARTS_PITCH, -half + j * _PARTS_PITCH
            pick = rng.random()
            if pick < 0.6:
                kinds["peg"].append(_peg(x, z, rng.uniform(0.15, 0.55)))
            elif pick < 0.85:
                kinds["ball"].append(_ball(x, z, rng.uniform(0.11, _PEG_RADIUS)))
            else:
                kinds["rod"].append(_rod(x, z, rng.uniform(0, math.pi)))
    materials = [
        Material("tray", albedo=(0.55, 0.55, 0.5)),
        Material("peg", albedo=(0.7, 0.3, 0.2)),
        Material("ball", albedo=(0.2, 0.45, 0.7), twosided=True),
        Material("rod", albedo=(0.75, 0.7, 0.3)),
    ]
    edge = half + 0.3
    tray = [box(np.array([-edge, -0.3, -edge]), np.array([edge, 0.0, edge]), subdivisions=8)]
    for lo, hi in (((-edge, 0.0, -edge), (edge, 0.25, -edge + 0.1)), ((-edge, 0.0, edge - 0.1), (edge, 0.25, edge))):
        tray.append(box(np.array(lo), np.array(hi), subdivisions=4))
    meshes = [Mesh("tray", *_merge(tray)[:2], material=0)]
    for m, name in enumerate(("peg", "ball", "rod"), start=1):
        p, f, n, uv = _merge(kinds[name])
        meshes.append(Mesh(name, p, f, material=m, normals=n, uvs=uv))
    sky = Light("envmap", (1.0, 1.0, 1.0), envmap=_sky_map(), to_world=np.eye(4))
    camera = Camera(
        look_at([2.6, 3.4, 4.0], [0.0, 0.1, 0.0], [0.0, 1.0, 0.0]), fov=40.0, fov_axis="x", width=128, height=96
    )
    return assemble("parts", "parts", meshes, materials, [sky], camera)


def _peg(x: float, z: float, height: float) -> tuple:
    """A cylinder of `_PEG_RADIUS` standing on the tray: a smooth side and a flat cap."""
    r = _PEG_RADIUS

    def side(u, v):  # u: around, v: up (front: outward)
        a = 2 * math.pi * u
        return np.stack([x + r * np.cos(a), v * height, z - r * np.sin(a)], -1)

    p, f, n, uv = unit_disk(16)  # in z = 0 facing +z: turned to face +y at the top
    cap = (p[:, [0, 2, 1]] * [r, 1.0, -r] + [x, height, z], f, np.tile([0.0, 1.0, 0.0], (len(p), 1)), uv)
    return _merge([surface(side, 16, 4), cap])


def _ball(x: float, z: float, radius: float) -> tuple:
    p, f, n, uv = unit_sphere((16, 8))
    return p * radius + np.array([x, radius, z]), f, n, uv


def _rod(x: float, z: float, angle: float) -> tuple:
    """A rod lying on the tray across its cell, smooth-shaded."""
    r, length = 0.05, 0.26
    axis = np.array([math.cos(angle), 0.0, math.sin(angle)])
    side = np.cross(axis, [0.0, 1.0, 0.0])

    def shape(u, v):  # u: around, v: along (front: outward)
        t = (v - 0.5) * length
        a = 2 * math.pi * u
        return (
            np.array([x, r, z])
            + t[..., None] * axis
            + r * (np.cos(a)[..., None] * side + np.sin(a)[..., None] * [0, 1, 0])
        )

    return surface(shape, 12, 4)


def _sky_map(height: int = 64, width: int = 128) -> np.ndarray:
    """A lat-long sky (Mitsuba's convention: rows from +y down to -y): blue above, brighter at the
    horizon, a dim ground below, and a bright lobe around a high sun."""
    theta = (np.arange(height) / (height - 1)) * math.pi  # from the zenith
    phi = (np.arange(width) + 0.5) / width * 2 * math.pi
    t, ph = np.meshgrid(theta, phi, indexing="ij")
    up = np.cos(t)[..., None]
    sky = np.where(up > 0, np.array([0.35, 0.55, 1.0]) * (0.6 + 0.8 * (1 - up)), np.array([0.25, 0.22, 0.2]))
    direction = np.stack([np.sin(t) * np.cos(ph), np.cos(t), np.sin(t) * np.sin(ph)], -1)
    sun = np.array([0.5, 0.75, 0.43])
    sun /= np.linalg.norm(sun)
    # A broad bright lobe, not a sun disk: bundle paths find the environment only by pointing at it.
    sky = sky + 4.0 * np.maximum(direction @ sun, 0.0)[..., None] ** 8 * np.array([1.0, 0.95, 0.85])
    return sky.astype(np.float32)


def _textured(name: str, texture: np.ndarray) -> Material:
    mean = texture.reshape(-1, 3).mean(axis=0)
    return Material(name, albedo=tuple(float(x) for x in mean), texture=texture, twosided=True)


def _column(out: list, flat: list, x: float, z: float, base: float) -> None:
    r = _COLUMN_RADIUS

    def shaft(u, v):  # u: around, v: up; a slight entasis (swelling) like classical columns
        radius = r * (1.0 + 0.06 * np.sin(math.pi * v))
        return np.stack(
            [
                x + radius * np.cos(2 * math.pi * u),
                base + 0.3 + v * (_SPRING - 0.6),
                z - radius * np.sin(2 * math.pi * u),
            ],
            -1,
        )

    out.append(surface(shaft, *_COLUMN_SEGMENTS))
    for y0 in (base, base + _SPRING - 0.3):  # plinth and capital
        flat.append(box(np.array([x - 0.5, y0, z - 0.5]), np.array([x + 0.5, y0 + 0.3, z + 0.5])))
    # The pier between neighbouring arches' spandrels, above the capital.
    flat.append(box(np.array([x - r, base + _SPRING, z - r]), np.array([x + r, base + _SPANDREL_TOP, z + r])))


def _arch(out: list, a: float, b: float, across: float, base: float, along_x: bool) -> None:
    """A semicircular arch between columns at a and b on a side, with its two spandrel walls."""
    centre, radius = 0.5 * (a + b), 0.5 * (b - a) - _COLUMN_RADIUS
    spring, top, half_depth = base + _SPRING, base + _SPANDREL_TOP, _COLUMN_RADIUS

    def place(t, y, w):  # side coordinate t, height y, depth offset w -> world
        return np.stack([t, y, across + w] if along_x else [across + w, y, t], -1)

    def intrados(u, v):
        theta = math.pi * (1.0 - u)
        return place(centre + radius * np.cos(theta), spring + radius * np.sin(theta), half_depth * (2 * v - 1))

    out.append(surface(intrados, _ARCH_SEGMENTS, 4))
    for w in (-half_depth, half_depth):

        def spandrel(u, v, w=w):
            theta = math.pi * (1.0 - u)
            t = centre + radius * np.cos(theta)
            y = spring + radius * np.sin(theta)
            return place(t, y + v * (top - y), w + 0 * u)

        out.append(surface(spandrel, _ARCH_SEGMENTS, 1))


def _cloth(out: list, t0: float, t1: float, depth: float, top: float, length: float) -> None:
    def drape(u, v):  # u: down, v: across; folds deepen toward the hem
        t = t0 + v * (t1 - t0)
        fold = 0.12 * np.sin(2 * math.pi * 5 * v) * (0.35 + 0.65 * u)
        sway = 0.25 * u * u
        return np.stack([t, top - u * length, depth + fold + sway], -1)

    out.append(surface(drape, *_CLOTH_SEGMENTS))


def _merge(parts: list) -> tuple:
    """Concatenate (positions, faces, ...) tuples into one, offsetting the face indices."""
    offsets = np.cumsum([0] + [len(part[0]) for part in parts[:-1]])
    merged = [np.concatenate(field) for field in zip(*parts)]
    merged[1] = np.concatenate([part[1] + o for part, o in zip(parts, offsets)])
    return tuple(merged)


def _tile_texture(rng: np.random.Generator, size: int = 512, tiles: int = 8) -> np.ndarray:
    """Stone floor tiles with mortar joints; each tile's tone varies (seeded)."""
    cell = size // tiles
    tone = rng.uniform(0.8, 1.15, (tiles, tiles))
    i = np.arange(size)
    img = np.repeat(np.repeat(tone, cell, 0), cell, 1)[..., None] * np.array([0.72, 0.64, 0.52])
    img = img * (1 + 0.06 * rng.standard_normal((size, size, 1)))
    joint = i % cell < 3
    img[joint, :] = [0.35, 0.33, 0.30]
    img[:, joint] = [0.35, 0.33, 0.30]
    return srgb_to_linear(np.clip(img, 0, 1)).astype(np.float32)


def _stripe_texture(size: int = 256) -> np.ndarray:
    """Curtain fabric: deep red with gold stripes, in sRGB then linearised."""
    u = (np.arange(size) + 0.5) / size
    stripe = (np.sin(2 * math.pi * 6 * u) > 0.85)[None, :, None]
    img = np.where(stripe, np.array([0.85, 0.68, 0.25]), np.array([0.62, 0.10, 0.09]))
    img = np.broadcast_to(img, (size, size, 3))
    return srgb_to_linear(img).astype(np.float32)


BUILTIN_SCENES = {
    "cornell-box": cornell_box,
    "glossy-box": glossy_box,
    "furnace": furnace,
    "atrium": atrium,
    "atrium-animated": atrium_animated,
    "atrium-dense": atrium_dense,
    "parts": parts,
    "lit-room": lit_room,
}
