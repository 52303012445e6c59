"""Shadow-mapped lights and the environment on the GPU (shaders/include/lights.glsl, shadow_maps.glsl).

Point, spot and directional lights (the fixed lights) get shadow maps in one atlas (a stack of
pages, the layers of a texture array, as many as its tiles need: `pack_tiles`): a directional
light one orthographic view fitted to the bounding sphere, a spot light one perspective view over
its cone (six when the cone is wider than a cube face), a point light six cube faces. Each cube
face is widened by two texels so that filtering near a face's edge reads rendered texels. A view
draws only the clusters of triangles (runs of the scene's order) whose boxes reach into it
(`view_clusters`): a cube face sees a sixth of the space around its light. Every view of a pass
is drawn by one indirect multi-draw per atlas page (shaders/lights/shadow_maps.glsl).

Light vertices are points that light the scene for one frame, each a point light whose intensity
falls as the cosine to its surface's normal: the path strategy says which (the eye paths' emitter
samples, `EmitterSamples`: next-event estimation of emissive triangles), and the light visibility
unit makes their shadow maps (gpu_impl/visibility/). The environment needs no shadow maps: the
paths reach it.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import moderngl
import numpy as np

from evalkit.core.errors import LimitError
from evalkit.core.scene.model import Light
from evalkit.core.settings import RenderSettings
from gpu_impl.context import MEMORY_HEADROOM, GLContext, LayerTargets, format_bytes, set_uniforms
from gpu_impl.layout import (
    BINDINGS,
    ENVIRONMENT_KINDS,
    FACING_IMAGE_UNITS,
    LIGHT,
    LIGHT_KINDS,
    MAX_ATLAS_TEXTURES,
    SHADOW_VIEW,
)
from gpu_impl.scene_buffers import CLUSTER_TRIANGLES, GpuScene

# A spot light whose cone half-angle is within this of 90 degrees cannot use one perspective view.
MAX_SPOT_VIEW_DEGREES = 60.0
CUBE_FACES = (
    (1, 0, 0),
    (-1, 0, 0),
    (0, 1, 0),
    (0, -1, 0),
    (0, 0, 1),
    (0, 0, -1),
)  # lights.glsl: shadow_view_of
GUARD_TEXELS = 2
# Texture units: the atlas' texture arrays from ATLAS_UNIT on, then the fixed lights' seen
# triangles' (light paths; the renderer's G-buffer takes unit 0).
ATLAS_UNIT = 1
TRIANGLES_UNIT = ATLAS_UNIT + MAX_ATLAS_TEXTURES
# The distance of a texel without a surface (shaders/include/lights.glsl: NO_SURFACE), and its bits.
NO_SURFACE = float(np.finfo(np.float32).max)
NO_SURFACE_BITS = int(np.float32(NO_SURFACE).view(np.uint32))
# A light vertex sits this far (times the bounding radius) in front of its surface, so that the
# surface lies behind it and its shadow views leave that surface out (shaders/lights/shadow_maps.glsl).
LIGHT_VERTEX_OFFSET = 1e-5
# An indirect draw of indexed triangles (glMultiDrawElementsIndirect), and how many views' clusters
# are culled in one batch of arrays.
DRAW_COMMAND = np.dtype(
    [("count", "<u4"), ("instances", "<u4"), ("first", "<u4"), ("base_vertex", "<i4"), ("base_instance", "<u4")]
)
VIEWS_PER_CULL = 64


class LightVertices(NamedTuple):
    """A frame's light vertices, in scene space: positions and unit surface normals (M, 3), the
    intensity each sends along its normal (M, 3; it falls as the cosine away from it), and the
    density of having drawn each, M p(y) (M,), which multiple importance sampling needs. Light
    path vertices (strategies/bidirectional.py) have a ``depth`` of 1 or more and their light side's
    MIS share ``mis`` (lights.glsl: Light.paths); emitter samples have depth 0."""

    positions: np.ndarray
    normals: np.ndarray
    intensities: np.ndarray
    densities: np.ndarray
    depths: np.ndarray | None = None
    mis: np.ndarray | None = None
    surfaces: np.ndarray | None = None  # light path vertices with glossy materials: albedo and material (M, 4)
    incoming: np.ndarray | None = None  # and the unit direction back along the path (M, 3)


class EmitterSamples:
    """Points on the emissive triangles for next-event estimation, drawn afresh every frame.

    A point y is drawn with probability density p(y) = w(y) / W over the emitters' area, where w is
    the mean of the emitted radiance's channels and W = sum(w A) over the emissive triangles (by
    emitted power), stratified over that power: sample i takes the power quantile (i + u_i) / M.
    Light from y reaches x as L_e cos_y cos_x / |x - y|^2 V(x, y), so the estimate over M samples is
    a sum of point lights of intensity L_e cos_y / (M p(y)): `frame_lights` gives them as the
    frame's `LightVertices`.
    """

    def __init__(self, scene, count: int):
        """``scene`` must have emitters (the importers refuse emitters of zero area)."""
        self.scene, self.count = scene, int(count)
        emissive = [scene.materials[m.material].emissive for m in scene.meshes]
        emitters = [m for m, e in zip(scene.meshes, emissive) if e]
        self.triangles = np.concatenate([m.positions[m.faces] for m in emitters])
        # Each emissive triangle's index among the scene's (`Scene.arrays` order): what a light path
        # from it records as the triangle it starts on (light_paths.glsl).
        first = np.cumsum([0] + [len(m.faces) for m in scene.meshes])
        self.scene_triangles = np.concatenate(
            [first[i] + np.arange(len(m.faces)) for i, m in enumerate(scene.meshes) if emissive[i]]
        )
        self.face_normals = _face_normals(self.triangles)
        # Vertex normals per corner where the mesh has them (Mitsuba's emitters use the shading normal).
        self.corner_normals = (
            None
            if all(m.normals is None for m in emitters)
            else np.concatenate(
                [
                    _face_normals(m.positions[m.faces])[:, None, :].repeat(3, axis=1)
                    if m.normals is None
                    else m.normals[m.faces]
                    for m in emitters
                ]
            )
        )
        self.radiance = np.concatenate(
            [
                np.broadcast_to(
                    np.asarray(scene.materials[m.material].emission, dtype=np.float64),
                    (len(m.faces), 3),
                )
                for m in emitters
            ]
        )
        self.weights = self.radiance.mean(axis=1)
        power = self.weights * np.concatenate([m.triangle_areas() for m in emitters])
        self.total = float(power.sum())  # W in p(y) = w(y) / W
        self.cdf = np.cumsum(power) / self.total

    def posed(self, scene) -> EmitterSamples:
        """These samples for ``scene``: the same object, or new ones where the scene was posed
        since (its emitters may have moved)."""
        return self if scene is self.scene else EmitterSamples(scene, self.count)

    @property
    def density_scale(self) -> float:
        """M / W: M p(y) = density_scale w(y), what the eye paths' MIS weights need (eye_paths.glsl)."""
        return self.count / self.total

    def frame_lights(self, seed: int, frame: int) -> LightVertices:
        """This frame's samples: positions, unit normals and intensities per unit cos, (M, 3) each,
        and the densities M p(y), (M,)."""
        rng = np.random.default_rng([seed, frame, 2])
        t, positions, normals = self.draw(rng, (np.arange(self.count) + rng.random(self.count)) / self.count)
        densities = self.density_scale * self.weights[t]
        return LightVertices(positions, normals, self.radiance[t] / densities[:, None], densities)

    def draw(self, rng: np.random.Generator, u: np.ndarray):
        """Points at the power quantiles ``u``, uniform within their triangles: the triangles'
        indices, the points and their unit shading normals."""
        n = len(u)
        t = np.minimum(np.searchsorted(self.cdf, u, side="right"), len(self.cdf) - 1)
        r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
        b = np.stack([1.0 - r1, r1 * (1.0 - r2), r1 * r2], axis=1)  # uniform over the triangle
        tri = self.triangles[t]
        positions = np.einsum("mk,mkj->mj", b, tri)
        if self.corner_normals is None:
            normals = self.face_normals[t]
        else:
            normals = np.einsum("mk,mkj->mj", b, self.corner_normals[t])
            normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        return t, positions, normals


class EnvironmentSamples:
    """Directions drawn from an environment map in proportion to its radiance, for next-event
    estimation of the environment: each a directional light with a shadow map of its own for one
    frame (`ShadowLights.set_environment_samples`), weighted by multiple importance sampling against
    the bundle direction that could have found the environment (lights.glsl, eye_paths.glsl).

    The map's cells are its texel intervals in (u, v): W columns [i / W, (i + 1) / W) and H - 1 rows
    between texel rows j / (H - 1) and (j + 1) / (H - 1) (Mitsuba's texel positions, environment.glsl).
    A cell is drawn in proportion to L_c dw_c, L_c the largest radiance (channels' mean) its
    bilinear lookups read and dw_c its solid angle, and a direction uniformly in solid angle within
    it, so p(w) = L_c / sum(L dw) per solid angle: nonzero wherever the map's radiance is, and as
    peaked as its sun. A sample w carries irradiance L(w) / (M p(w)) across its direction.
    """

    def __init__(self, light: Light, count: int):
        self.count = int(count)
        radiance = np.asarray(light.envmap, dtype=np.float64) * np.asarray(light.intensity)
        h, w = radiance.shape[:2]
        lum = radiance.mean(axis=2)
        # Columns i - 1, i and i + 1 and rows j and j + 1 reach into cell (j, i).
        columns = np.maximum(lum, np.maximum(np.roll(lum, 1, axis=1), np.roll(lum, -1, axis=1)))
        cells = np.maximum(columns[:-1], columns[1:])  # (H - 1, W)
        self.cos_rows = np.cos(np.pi * np.arange(h) / (h - 1))
        solid = 2.0 * np.pi / w * (self.cos_rows[:-1] - self.cos_rows[1:])  # (H - 1,)
        power = cells * solid[:, None]
        total = float(power.sum())
        if not total > 0.0:
            raise ValueError("an environment map without radiance has nothing to sample")
        self.pdf = cells / total  # per solid angle, per cell (H - 1, W)
        self.cdf = np.cumsum(power.ravel()) / total
        self.cell_power, self.cell_solid_angle = power.ravel() / total, np.repeat(solid, w)
        self.radiance = radiance
        self.to_world = np.asarray(light.to_world, dtype=np.float64)[:3, :3]

    def peak(self, share: float) -> float:
        """The solid angle (sr) of the map's brightest cells that hold ``share`` of its power."""
        order = np.argsort(self.cell_power / self.cell_solid_angle)[::-1]
        held = np.searchsorted(np.cumsum(self.cell_power[order]), share) + 1
        return float(self.cell_solid_angle[order[:held]].sum())

    def frame_samples(self, seed: int, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """This frame's M directions toward the environment (M, 3), stratified over its power, the
        irradiance each carries, L(w) / (M p(w)) (M, 3), and the densities M p(w) (M,)."""
        m, (h, w) = self.count, self.pdf.shape
        rng = np.random.default_rng([seed, frame, 3])
        cell = np.minimum(np.searchsorted(self.cdf, (np.arange(m) + rng.random(m)) / m, side="right"), h * w - 1)
        j, i = np.divmod(cell, w)
        u = (i + rng.random(m)) / w
        cos_theta = self.cos_rows[j] - rng.random(m) * (self.cos_rows[j] - self.cos_rows[j + 1])
        sin_theta = np.sqrt(np.maximum(1.0 - cos_theta * cos_theta, 0.0))
        phi = 2.0 * np.pi * u
        local = np.stack([sin_theta * np.sin(phi), cos_theta, -sin_theta * np.cos(phi)], axis=1)
        directions = local @ self.to_world.T
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        densities = m * self.pdf[j, i]
        radiance = self.lookup(u, np.arccos(np.clip(cos_theta, -1.0, 1.0)) / np.pi)
        return directions, radiance / densities[:, None], densities

    def lookup(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The map's radiance at (u, v) as environment.glsl reads it: bilinear, columns centred at
        (i + 0.5) / W and wrapped, rows at j / (H - 1)."""
        h, w = self.radiance.shape[:2]
        x, y = u * w - 0.5, v * (h - 1)
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
        c0, c1 = np.mod(x0, w), np.mod(x0 + 1, w)
        r0, r1 = np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)
        t = self.radiance
        return (1 - fy) * ((1 - fx) * t[r0, c0] + fx * t[r0, c1]) + fy * ((1 - fx) * t[r1, c0] + fx * t[r1, c1])


def _face_normals(triangles: np.ndarray) -> np.ndarray:
    n = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


class Atlas(NamedTuple):
    """Where `pack_tiles` put the tiles: each tile's corner (x, y), the page size (width, height)
    and how many pages. The atlas is a stack of pages, the layers of a texture array, and a tile's
    y counts down the whole stack: its page is y // height (shaders/include/lights.glsl: atlas_texel)."""

    corners: list[tuple[int, int]]
    page: tuple[int, int]
    pages: int


def pack_tiles(sizes: list[int], max_side: int, new_rows: tuple[int, ...] = (), max_pages: int = 1) -> Atlas:
    """Square tiles of the given sides packed row by row into pages of at most ``max_side`` texels
    a side: one page where they fit one, else as few square pages as leave the least unused (of
    sides ``max_side``, its half and its quarter), at most ``max_pages``. ``new_rows``: indices of
    tiles that start a row, so that the tiles from each on fill rows of their own (one clear
    covers them)."""
    largest = max(sizes)
    if largest > max_side:
        raise LimitError(f"a shadow map of {largest} texels a side exceeds the GL texture limit {max_side}", ())
    side = max(largest, 1 << math.ceil(math.log2(math.sqrt(sum(s * s for s in sizes)))))
    if side <= max_side:
        corners, height = _pack_rows(sizes, side, new_rows)
        if height <= max_side:
            return Atlas(corners, (side, height), 1)
    best = None
    for side in (max_side, max_side // 2, max_side // 4):
        if side >= largest:
            corners, height = _pack_rows(sizes, side, new_rows, page=side)
            pages = -(-height // side)
            if best is None or pages * side * side < best.pages * best.page[0] ** 2:
                best = Atlas(corners, (side, side), pages)
    if best.pages > max_pages:
        raise LimitError(
            f"{len(sizes)} shadow views ({sum(s * s for s in sizes):,} texels) need {best.pages} atlas pages of "
            f"{best.page[0]} texels a side, over the GL's {max_pages}; lower the shadow map sizes, the light "
            "samples or the light paths",
            ("light_paths",),
        )
    return best


def _pack_rows(
    sizes: list[int], side: int, new_rows: tuple[int, ...], page: int | None = None
) -> tuple[list[tuple[int, int]], int]:
    """Tiles in rows ``side`` texels wide; a tile that would run past the bottom of its page of
    ``page`` rows starts the next page. The corners and the rows used."""
    corners, x, y, row = [], 0, 0, 0
    for i, s in enumerate(sizes):
        if x + s > side or (i in new_rows and x > 0):
            x, y, row = 0, y + row, 0
        if page is not None and y % page + s > page:
            x, y, row = 0, (y // page + 1) * page, 0
        corners.append((x, y))
        x, row = x + s, max(row, s)
    return corners, y + row


class Views(NamedTuple):
    """N shadow views (lights.glsl: ShadowView): their clip matrices (N, 4, 4; acting on column
    vectors of positions relative to the bundle centre), texel size terms (N,), origins (N, 3),
    whether each is perspective (N,), axes (N, 3) and farthest distances (N,)."""

    to_clip: np.ndarray
    texel: np.ndarray
    origin: np.ndarray
    perspective: np.ndarray
    axis: np.ndarray
    far: np.ndarray


def cube_views(positions: np.ndarray, far: np.ndarray, size: int, axes: np.ndarray | None = None) -> Views:
    """The six views of a cube map at each of ``positions`` (M, 3; relative to the bundle centre),
    seeing as far as ``far`` (M,): 6 M views, each cube's in the order of `CUBE_FACES`, each
    widened by `GUARD_TEXELS`. ``axes``: the surface normals of light vertices (M, 3;
    shaders/lights/shadow_maps.glsl keeps only what lies in front of them), else none."""
    positions, far = np.atleast_2d(positions).astype(np.float64), np.atleast_1d(far).astype(np.float64)
    m = len(positions)
    tan_half = 1.0 + 2.0 * GUARD_TEXELS / size
    projection = np.stack([perspective(tan_half, max(f * 1e-5, 1e-30), f) for f in far])  # (M, 4, 4)
    faces = np.stack([look_at_view(np.zeros(3), np.array(face, dtype=np.float64)) for face in CUBE_FACES])
    views = np.broadcast_to(faces, (m, 6, 4, 4)).copy()
    views[:, :, :3, 3] = -np.einsum("fij,mj->mfi", faces[:, :3, :3], positions)
    axes = np.zeros((m, 3)) if axes is None else axes
    return Views(
        np.einsum("mij,mfjk->mfik", projection, views).reshape(6 * m, 4, 4),
        np.full(6 * m, 2.0 * tan_half / size),
        positions.repeat(6, axis=0),
        np.ones(6 * m, dtype=bool),
        axes.repeat(6, axis=0),
        far.repeat(6),
    )


def view_clusters(
    to_clip: np.ndarray, origin: np.ndarray, axis: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> np.ndarray:
    """Per view (N) and cluster box (C; corners ``lo`` and ``hi``), whether any of the box lies
    inside the view's clip volume (``to_clip``: (N, 4, 4), acting on column vectors) and, for a
    perspective view with an axis (``origin`` and ``axis``: (N, 4) as in `SHADOW_VIEW`), in front
    of the plane through the origin across the axis, which shaders/lights/shadow_maps.glsl keeps. GL
    clips away every triangle of a box that lies outside the clip volume, and the shader discards
    every fragment of a triangle wholly behind the plane, so drawing only the boxes that reach in
    leaves the map as it was, bit for bit. (N, C) booleans."""
    m = to_clip.astype(np.float64)
    # The clip volume's six planes (Gribb and Hartmann): w +- x, w +- y, w +- z >= 0.
    planes = np.concatenate([m[:, 3:4] + m[:, :3], m[:, 3:4] - m[:, :3]], axis=1)  # (N, 6, 4)
    axes = axis[:, :3].astype(np.float64)
    cut = (origin[:, 3] > 0.5) & np.any(axes != 0.0, axis=1)
    front = np.zeros((len(m), 1, 4))
    front[:, 0, :3] = axes
    front[:, 0, 3] = -np.einsum("ij,ij->i", axes, origin[:, :3])
    front[~cut] = (0.0, 0.0, 0.0, 1.0)  # a plane every point is in front of
    planes = np.concatenate([planes, front], axis=1)
    centre, half = (lo + hi) / 2.0, (hi - lo) / 2.0
    seen = np.ones((len(m), len(lo)), dtype=bool)
    for plane in planes.transpose(1, 0, 2):  # a plane at a time: (N, C) arrays, not (N, 7, C)
        # The most any point of the box gets from the plane: at the corner its normal points to.
        seen &= plane[:, :3] @ centre.T + np.abs(plane[:, :3]) @ half.T + plane[:, 3:] >= 0.0
    return seen


def single_view(to_clip, texel, origin, perspective_view, axis, far) -> Views:
    """One shadow view as `Views`."""
    return Views(
        to_clip[None], np.array([texel]), origin[None], np.array([perspective_view]), axis[None], np.array([far])
    )


def look_at_view(eye: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """World-to-view matrix (OpenGL convention: the view looks along -z) from eye along forward."""
    f = forward / np.linalg.norm(forward)
    helper = np.eye(3)[int(np.argmin(np.abs(f)))]
    right = np.cross(f, helper)
    right /= np.linalg.norm(right)
    up = np.cross(right, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = right, up, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def perspective(tan_half: float, near: float, far: float) -> np.ndarray:
    m = np.zeros((4, 4))
    m[0, 0] = m[1, 1] = 1.0 / tan_half
    m[2, 2] = -(far + near) / (far - near)
    m[2, 3] = -2.0 * far * near / (far - near)
    m[3, 2] = -1.0
    return m


def orthographic(half: float, near: float, far: float) -> np.ndarray:
    m = np.eye(4)
    m[0, 0] = m[1, 1] = 1.0 / half
    m[2, 2] = -2.0 / (far - near)
    m[2, 3] = -(far + near) / (far - near)
    return m


class AtlasTextures:
    """The shadow atlas' GL textures: its pages in texture arrays of ``per_texture`` pages each, as
    many as the driver allocates in one texture (it may cap one texture's bytes below its size
    limits: llvmpipe at about 1.3 GiB), at most ``most`` (the shaders read one texture through a
    sampler, more through an array of `MAX_ATLAS_TEXTURES`). Per array: the distances (RG32F:
    the first surface, the second), the triangle each texel saw (R32UI; with light paths), the
    two nearest surfaces facing the light (R32UI each; where second surfaces are kept:
    shaders/lights/shadow_maps.glsl) and a framebuffer per page (`LayerTargets`)."""

    def __init__(self, gl: GLContext, atlas: Atlas, triangles: bool, facing: bool, most: int):
        self.page, self.pages = atlas.page, atlas.pages
        per = refused = atlas.pages  # the pages in one texture, tried; the fewest the driver refused
        nbytes = _atlas_bytes(atlas.pages, atlas.page, triangles, facing)
        while True:
            count = -(-atlas.pages // per)
            if count > most:
                raise LimitError(
                    f"the shadow atlas' {atlas.pages} pages of {atlas.page[0]} x {atlas.page[1]} texels need more "
                    f"textures than the shaders read ({most}): the GL driver allocates no texture "
                    f"of {refused} pages; lower the light samples, the light paths or their maps' size",
                    ("light_paths",),
                )
            sizes = [min(per, atlas.pages - i * per) for i in range(count)]
            made = gl.allocate(functools.partial(self._make, gl, atlas.page, sizes, triangles, facing), nbytes)
            if made is not None:
                break
            if per == 1:
                raise LimitError(
                    f"the GL driver cannot allocate one shadow atlas page of {atlas.page[0]} x {atlas.page[1]} "
                    "texels; lower the shadow map sizes, the light samples or the light paths",
                    ("light_paths",),
                )
            refused, per = per, -(-per // 2)
        self.per_texture, self.arrays = per, made

    @staticmethod
    def _make(gl: GLContext, size: tuple[int, int], sizes: list[int], triangles: bool, facing: bool) -> list:
        """A `PageArrays` per texture of ``sizes`` pages."""
        made = []
        for pages in sizes:
            distances = gl.texture_array(size, pages, 2, "f4")
            seen = gl.texture_array(size, pages, 1, "u4") if triangles else None
            facing_pair = tuple(gl.texture_array(size, pages, 1, "u4") for _ in FACING_IMAGE_UNITS) if facing else ()
            targets = gl.layer_targets([distances, *([seen] if triangles else [])])
            made.append(PageArrays(distances, seen, facing_pair, targets))
        for texture in (t for arrays in made for t in arrays.facing):
            gl.fill_texture(texture, NO_SURFACE_BITS)  # then kept so by the second-surface pass
        return made

    def locate(self, page: int) -> tuple[int, int]:
        """(texture, layer) of atlas page ``page``."""
        return divmod(int(page), self.per_texture)

    def framebuffer(self, page: int):
        texture, layer = self.locate(page)
        return self.arrays[texture].targets.framebuffers[layer]

    def clear(self, page: int, viewport: tuple[int, int, int, int]) -> None:
        """``viewport`` of ``page``: no surface, no triangle, the farthest depth."""
        texture, layer = self.locate(page)
        self.arrays[texture].targets.clear(layer, viewport, [(NO_SURFACE, NO_SURFACE), 0])

    def texture_pages(self, pages: np.ndarray) -> list[tuple[int, int, int]]:
        """The runs of ``pages`` (non-decreasing) on one texture: (texture, first index, end index)."""
        textures = np.asarray(pages, dtype=np.int64) // self.per_texture
        return [
            (int(t), int(np.searchsorted(textures, t)), int(np.searchsorted(textures, t, side="right")))
            for t in np.unique(textures)
        ]

    def bind_images(self, texture: int, facing: bool = True) -> None:
        """Texture ``texture``'s distances at image unit 0 and (``facing``) its facing surfaces at theirs."""
        arrays = self.arrays[texture]
        arrays.distances.bind_to_image(0, read=True, write=True)
        for image, unit in zip(arrays.facing if facing else (), FACING_IMAGE_UNITS):
            image.bind_to_image(unit, read=True, write=True)

    def read(self, channels: int = 2) -> np.ndarray:
        """The distances (``channels`` 2: first surface, second) or, with ``channels`` 1, the
        triangles, of every page stacked: (pages x height, width, channels)."""
        width, height = self.page
        parts = [(a.distances, np.float32) if channels == 2 else (a.triangles, np.uint32) for a in self.arrays]
        return np.concatenate([np.frombuffer(t.read(), dtype=d).reshape(-1, width, channels) for t, d in parts])

    @property
    def has_facing(self) -> bool:
        return bool(self.arrays[0].facing)

    def release(self) -> None:
        for arrays in self.arrays:
            arrays.release()


class PageArrays(NamedTuple):
    """One texture's worth of atlas pages (`AtlasTextures`)."""

    distances: moderngl.TextureArray
    triangles: moderngl.TextureArray | None
    facing: tuple
    targets: LayerTargets

    def release(self) -> None:
        self.targets.release()
        for texture in (self.distances, self.triangles, *self.facing):
            if texture is not None:
                texture.release()


class ShadowLights:
    """The scene's fixed lights (point, spot and directional) and the frame's light vertices, with
    their shadow atlas, and the scene's environment.

    ``settings`` gives the fixed lights' maps (``shadow_map_size`` texels a side), the depth bias
    in texels (``shadow_bias``, and ``shadow_slope_bias`` per unit tangent of the angle to the
    light) and the PCF kernel (``shadow_filter`` bilinear taps a side; 1: one bilinear 2x2
    lookup). ``visibility`` (a light visibility unit's maps, gpu_impl/visibility/) makes the light
    vertices' shadow maps; ``light_vertices`` is how many emitter samples there are each frame, and
    ``path_vertices`` the most light path vertices (bidirectional paths), whose records follow.
    With light path vertices, the atlas keeps the triangle each texel saw too: the fixed lights'
    maps are where light paths start (shaders/paths/light_paths.glsl).
    """

    def __init__(
        self,
        gl: GLContext,
        gpu_scene: GpuScene,
        settings: RenderSettings,
        visibility,
        light_vertices: int,
        path_vertices: int = 0,
        environment_samples: int = 0,
        environment_map_size: int = 0,
    ):
        self.gl, self.gpu_scene, self.visibility = gl, gpu_scene, visibility
        self.map_size, self.filter = settings.shadow_map_size, settings.shadow_filter
        self.bias, self.slope_bias = settings.shadow_bias, settings.shadow_slope_bias
        lights = [light for light in gpu_scene.scene.lights if light.kind in LIGHT_KINDS]
        environments = [light for light in gpu_scene.scene.lights if light.kind in ("constant", "envmap")]
        self.environment = environments[0] if environments else None
        self.light_vertices = light_vertices + path_vertices
        # The lights light_irradiance loops over (lights.glsl): the fixed lights, the environment
        # samples, the emitter samples.
        self.count = len(lights) + environment_samples + light_vertices
        self.records_count = records_count = self.count + path_vertices
        records, views = [], []
        for light in lights:
            view = self._views(light)
            records.append(self._record(light, sum(len(v.texel) for v in views), len(view.texel)))
            views.append(view)
        fixed = Views(*(np.concatenate(field) for field in zip(*views))) if views else None
        # The environment samples' records and views (directional, redrawn every frame) follow the
        # fixed lights' (drawn once for a static scene), then the light vertices' (every frame).
        self.static_lights, self.static_views = len(records), 0 if fixed is None else len(fixed.texel)
        self.environment_map_size = environment_map_size
        self.fixed_lights = self.static_lights + environment_samples
        self.fixed_views = self.static_views + environment_samples
        self.buffers = {}
        self.atlas = None
        visibility.check(self.light_vertices)
        if records_count:
            per_vertex = visibility.tiles_per_vertex
            side = gl.limit("GL_MAX_TEXTURE_SIZE")
            # Only light paths' vertices outgrow one texture; other lights' shaders read one.
            most = MAX_ATLAS_TEXTURES if path_vertices else 1
            max_pages = gl.limit("GL_MAX_ARRAY_TEXTURE_LAYERS") * most
            texels = (
                self.map_size**2 * self.static_views
                + environment_map_size**2 * environment_samples
                + visibility.map_size**2 * per_vertex * self.light_vertices
            )
            if texels > max_pages * side**2:  # before a list of every tile is made
                raise LimitError(
                    f"{self.light_vertices:,} light vertices' shadow maps ({texels:,} texels) exceed the GL's "
                    f"{max_pages} texture layers of {side} texels a side; lower the light samples, the light paths "
                    "or their maps' size",
                    ("light_paths", visibility.map_size_setting),
                )
            sizes = (
                [self.map_size] * self.static_views
                + [environment_map_size] * environment_samples
                + [visibility.map_size] * (per_vertex * self.light_vertices)
            )
            new_rows = (self.static_views, self.fixed_views)
            atlas = pack_tiles(sizes, side, new_rows=new_rows, max_pages=max_pages)
            # Each texel's two nearest surfaces that face the light, which the raster pass keeps
            # and `second_surfaces` reads and clears again (shaders/lights/shadow_second_surface.glsl);
            # a scene whose every triangle bounds a solid has no second surfaces to keep.
            facing = not gpu_scene.solids().all()
            self._check_memory(atlas, bool(path_vertices), facing, visibility.map_size_setting)
            self.atlas = AtlasTextures(gl, atlas, bool(path_vertices), facing, most)  # or a LimitError, before the rest
            self.tiles = np.array(atlas.corners, dtype=np.float64).reshape(-1, 2)
            self.page_size, self.pages = atlas.page, atlas.pages
            # The environment samples' tiles and the light vertices' fill rows of their own
            # (`set_environment_samples`, `clear_vertex_tiles`); rows count down the stack of pages.
            self.rows = atlas.pages * atlas.page[1]
            self.vertex_row = int(self.tiles[self.fixed_views, 1]) if self.light_vertices else self.rows
            self.environment_row = int(self.tiles[self.static_views, 1]) if environment_samples else self.vertex_row
            self.view_records = np.zeros(len(sizes), dtype=SHADOW_VIEW)
            if fixed is not None:
                self.set_views(0, fixed, self.map_size)
            self.records = np.zeros(records_count, dtype=LIGHT)
            for i, record in enumerate(records):
                self.records[i] = record
            self.buffers["LIGHTS"] = gl.buffer(self.records.tobytes())
            self.buffers["SHADOW_VIEWS"] = gl.buffer(self.view_records.tobytes())
            self.second_surfaces = gl.program("shadow_second_surface") if facing else None
            self.program = gl.program("shadow_maps", SECOND_SURFACES=int(self.second_surfaces is not None))
            # Each view's index, an instanced attribute that a draw command's base instance picks.
            self.view_indices = gl.buffer(np.arange(len(sizes), dtype=np.uint32).tobytes())
            self.vao = gpu_scene.vertex_array(self.program, (self.view_indices, "1u/i", "in_view"))
            self.commands = None  # `draw`'s indirect draw commands, grown as needed

    def set_views(self, first: int, views: Views, size: int) -> None:
        """Shadow views ``first`` on of the atlas, in tiles ``size`` texels a side."""
        rows = slice(first, first + len(views.texel))
        records = self.view_records[rows]
        records["to_clip"] = views.to_clip.transpose(0, 2, 1)  # GLSL matrices are column-major
        records["tile"] = np.column_stack([self.tiles[rows], np.full(len(views.texel), size), views.texel])
        records["origin"] = np.column_stack([views.origin, views.perspective])
        records["axis"] = np.column_stack([views.axis, 1.0 / views.far])
        self.view_records[rows] = records

    def set_environment_samples(self, directions: np.ndarray, irradiance: np.ndarray, densities: np.ndarray) -> None:
        """This frame's environment samples (`EnvironmentSamples.frame_samples`): directional lights
        toward ``directions`` of ``irradiance`` and MIS densities ``densities`` (Light.shape.x), their
        records after the fixed lights' and their maps drawn."""
        first, count = self.static_lights, len(directions)
        views = [
            self._views(Light("directional", (0.0, 0.0, 0.0), direction=-d), self.environment_map_size)
            for d in directions
        ]
        records = np.zeros(count, dtype=LIGHT)
        records["position"][:, 3] = LIGHT_KINDS["environment_sample"]
        records["direction"][:, :3] = -directions
        records["intensity"][:, :3] = irradiance
        records["shape"] = np.column_stack(
            [densities, np.zeros(count), self.static_views + np.arange(count), np.ones(count)]
        )
        self.records[first : first + count] = records
        self.set_views(self.static_views, Views(*(np.concatenate(f) for f in zip(*views))), self.environment_map_size)
        self.upload()
        self.clear_rows(self.environment_row, self.vertex_row)
        self.draw(range(self.static_views, self.fixed_views))

    def set_light_path_densities(self, densities: np.ndarray) -> None:
        """Each fixed light's density of starting a light path (Light.paths.x, lights.glsl)."""
        self.records["paths"][: self.fixed_lights, 0] = densities
        self.upload()

    def set_light_vertices(self, vertices: LightVertices, seed: int, frame: int) -> None:
        """This frame's light vertices (emitter samples, then light path vertices): their records
        after the fixed lights', and their shadow maps, which the light visibility makes (imperfect
        maps draw their points with ``seed`` and ``frame``)."""
        if len(vertices.positions) > self.light_vertices:
            raise ValueError(f"{len(vertices.positions)} light vertices for {self.light_vertices} places")
        r = self.gpu_scene.radius
        positions = vertices.positions - self.gpu_scene.centre + LIGHT_VERTEX_OFFSET * r * vertices.normals
        per_vertex = self.visibility.tiles_per_vertex
        count = len(positions)
        depths = np.zeros(count) if vertices.depths is None else vertices.depths
        mis = np.zeros(count) if vertices.mis is None else vertices.mis
        kinds = np.where(depths == 0, LIGHT_KINDS["emitter_sample"], LIGHT_KINDS["light_path_vertex"])
        records = np.zeros(count, dtype=LIGHT)
        records["position"] = np.column_stack([positions, kinds])
        records["direction"][:, :3] = vertices.normals
        records["intensity"][:, :3] = vertices.intensities
        first_views = self.fixed_views + per_vertex * np.arange(count)
        records["shape"] = np.column_stack(
            [vertices.densities, np.zeros(count), first_views, np.full(count, per_vertex)]
        )
        records["paths"][:, :2] = np.column_stack([mis, depths])
        if vertices.surfaces is not None:
            records["surface"] = vertices.surfaces
            records["incoming"][:, :3] = vertices.incoming
        self.records[self.fixed_lights : self.fixed_lights + count] = records
        self.visibility.render(self, positions, vertices.normals, seed, frame)

    def upload(self) -> None:
        """The light records and the view table to the GPU."""
        self.buffers["LIGHTS"].write(self.records.tobytes())
        self.buffers["SHADOW_VIEWS"].write(self.view_records.tobytes())

    # -- views ---------------------------------------------------------------------------

    def _views(self, light: Light, size: int | None = None) -> Views:
        """The light's shadow views, ``size`` texels a side (default: the fixed lights')."""
        centre, r = self.gpu_scene.centre, self.gpu_scene.radius
        s = size or self.map_size
        if light.kind == "directional":
            d = np.asarray(light.direction, dtype=np.float64)
            eye = -r * d  # relative to the bundle centre: the plane distances start from
            to_clip = orthographic(r, 0.0, 2.0 * r) @ look_at_view(eye, d)
            return single_view(to_clip, 2.0 * r / s, eye, False, d, 2.0 * r)
        position = np.asarray(light.position, dtype=np.float64) - centre
        far = np.linalg.norm(position) + r
        near = max(far * 1e-5, 1e-30)
        if light.kind == "spot" and light.cutoff_angle <= MAX_SPOT_VIEW_DEGREES:
            tan_half = math.tan(math.radians(light.cutoff_angle)) * (1.0 + 2.0 * GUARD_TEXELS / s)
            to_clip = perspective(tan_half, near, far) @ look_at_view(
                position, np.asarray(light.direction, dtype=np.float64)
            )
            return single_view(to_clip, 2.0 * tan_half / s, position, True, np.zeros(3), far)
        return cube_views(position, far, s)

    def _record(self, light: Light, first_view: int, views: int) -> tuple:
        """The light's `LIGHT` record (shaders/include/lights.glsl: Light)."""
        kind = LIGHT_KINDS[light.kind]
        position = np.zeros(3) if light.position is None else np.asarray(light.position) - self.gpu_scene.centre
        direction = np.zeros(3) if light.direction is None else np.asarray(light.direction, dtype=np.float64)
        cutoff = math.radians(light.cutoff_angle or 90.0)
        beam = math.radians(light.beam_width if light.beam_width is not None else 0.75 * (light.cutoff_angle or 90.0))
        beam = min(beam, cutoff)
        inv_transition = 1.0 / (cutoff - beam) if cutoff > beam else 0.0
        return (
            (*position, kind),
            (*direction, math.cos(cutoff)),
            (*light.intensity, math.cos(beam)),
            (cutoff, inv_transition, first_view, views),
            (0.0, 0.0, 0.0, 0.0),
            (0.0, 0.0, 0.0, 0.0),  # surface and incoming: a light path vertex's (`set_light_vertices`)
            (0.0, 0.0, 0.0, 0.0),
        )

    # -- passes --------------------------------------------------------------------------

    def render_shadow_maps(self) -> None:
        """Draw the scene into the tile of every shadow view of the point, spot and directional lights."""
        if self.atlas is None:
            return
        self.clear_rows(0, self.rows)  # the whole atlas: a triangle texel is read only where a distance is
        self.draw(range(self.static_views))

    def clear_vertex_tiles(self) -> None:
        """Clear the light vertices' tiles for their next draw: the atlas' rows from `vertex_row` on."""
        self.clear_rows(self.vertex_row, self.rows)

    def clear_rows(self, first: int, end: int) -> None:
        """Clear the atlas' rows ``first`` to ``end`` (counted down the stack of pages) to no surface."""
        width, height = self.page_size
        for page in range(first // height, -(-end // height)):
            lo, hi = max(first - page * height, 0), min(end - page * height, height)
            self.atlas.clear(page, (0, lo, width, hi - lo))

    def view_pages(self, views) -> np.ndarray:
        """The atlas page each of ``views`` lies on."""
        return self.view_records["tile"][np.asarray(views, dtype=np.int64), 1].astype(np.int64) // self.page_size[1]

    def read_atlas(self, channels: int = 2) -> np.ndarray:
        """`AtlasTextures.read` (tests, benchmarks)."""
        return self.atlas.read(channels)

    def draw(self, views) -> None:
        """Draw the scene into the given views' tiles (cleared before; in increasing order) in one
        indirect multi-draw per atlas page, then find their texels' second surfaces."""
        views = np.asarray(views, dtype=np.int64)
        if not len(views):
            return
        self.gpu_scene.bind()
        self.buffers["SHADOW_VIEWS"].bind_to_storage_buffer(BINDINGS["SHADOW_VIEWS"])
        commands = self.draw_commands(views)
        if self.commands is None or self.commands.size < commands.nbytes:
            if self.commands is not None:
                self.commands.release()
            self.commands = self.gl.buffer(reserve=max(commands.nbytes, 2 * DRAW_COMMAND.itemsize))
        self.commands.write(commands.tobytes())
        # Per draw: the context caches one program per variant for every atlas it draws into.
        self.program["atlas_size"] = self.page_size
        # The commands follow the views, so each page's are a run, and each texture's a run of pages.
        pages = self.view_pages(commands["base_instance"])
        for texture, lo, hi in self.atlas.texture_pages(pages):
            if self.atlas.has_facing:
                self.atlas.bind_images(texture)
            for page in np.unique(pages[lo:hi]):
                first, last = np.searchsorted(pages, page), np.searchsorted(pages, page, side="right")
                set_uniforms(self.program, {"atlas_page": int(page) % self.atlas.per_texture})  # its layer
                self.gl.draw(
                    self.vao,
                    moderngl.TRIANGLES,
                    self.atlas.framebuffer(page),
                    depth_test=True,
                    commands=(self.commands, last - first, first),
                    clip_distances=4,
                )
        if self.second_surfaces is None:
            return
        # One dispatch per run of tiles of one size and one texture from the first view to the
        # last: the views between that were not drawn have nothing to find.
        lo, hi = int(views.min()), int(views.max()) + 1
        sizes = self.view_records["tile"][lo:hi, 2].astype(np.int64)
        textures = self.view_pages(range(lo, hi)) // self.atlas.per_texture
        starts = [lo, *(lo + 1 + np.nonzero((np.diff(sizes) != 0) | (np.diff(textures) != 0))[0]), hi]
        for start, end in zip(starts[:-1], starts[1:]):
            width, texture = int(sizes[start - lo]), int(textures[start - lo])
            self.atlas.bind_images(texture)
            values = {"first_view": start, "width": width, "first_page": texture * self.atlas.per_texture}
            set_uniforms(self.second_surfaces, values)
            self.gl.dispatch(self.second_surfaces, (end - start) * width * width)

    def draw_commands(self, views) -> np.ndarray:
        """Indirect draw commands (`DRAW_COMMAND`) of the triangles each view can see, a command per
        run of consecutive clusters whose boxes reach into the view (`view_clusters`), whose base
        instance is the view (shaders/lights/shadow_maps.glsl: in_view)."""
        lo, hi = self.gpu_scene.cluster_bounds()
        triangles = self.gpu_scene.triangle_count
        views = np.asarray(views, dtype=np.int64)
        commands = []
        for chunk in range(0, len(views), VIEWS_PER_CULL):
            part = self.view_records[views[chunk : chunk + VIEWS_PER_CULL]]
            seen = view_clusters(part["to_clip"].transpose(0, 2, 1), part["origin"], part["axis"], lo, hi)
            # The runs of seen clusters of all the chunk's views at once: rows padded with a cluster
            # that no view sees, so that no run goes on from one view's row into the next.
            padded = np.zeros((len(seen), seen.shape[1] + 1), dtype=np.int8)
            padded[:, :-1] = seen
            edges = np.diff(np.concatenate([[0], padded.ravel()]))
            starts, ends = np.nonzero(edges > 0)[0], np.nonzero(edges < 0)[0]
            row = starts // padded.shape[1]
            first = (starts - row * padded.shape[1]) * CLUSTER_TRIANGLES
            last = np.minimum((ends - row * padded.shape[1]) * CLUSTER_TRIANGLES, triangles)
            command = np.zeros(len(starts), dtype=DRAW_COMMAND)
            command["count"], command["instances"], command["first"] = 3 * (last - first), 1, 3 * first
            command["base_instance"] = views[chunk + row]
            commands.append(command)
        return np.concatenate(commands)

    def defines(self) -> dict:
        return {
            "SHADOW_LIGHTS": int(self.records_count > 0),
            "ATLAS_TEXTURES": self.atlas_textures,
            **self.visibility.defines(),
            "ENVIRONMENT": ENVIRONMENT_KINDS[None if self.environment is None else self.environment.kind],
        }

    def bind(self) -> None:
        """Bind the light buffers and the shadow atlas' textures (from texture unit `ATLAS_UNIT`)."""
        for name, buffer in self.buffers.items():
            buffer.bind_to_storage_buffer(BINDINGS[name])
        if self.atlas is not None:
            for i, arrays in enumerate(self.atlas.arrays):
                arrays.distances.use(ATLAS_UNIT + i)

    def bind_triangles(self) -> None:
        """Bind the triangles the fixed lights' maps saw (for light paths), from `TRIANGLES_UNIT`."""
        for i, arrays in enumerate(self.atlas.arrays):
            arrays.triangles.use(TRIANGLES_UNIT + i)

    @property
    def atlas_textures(self) -> int:
        """The ATLAS_TEXTURES the shaders are compiled with: 1, read through one sampler, or
        `MAX_ATLAS_TEXTURES`, through an array of samplers, where the atlas takes more textures."""
        return 1 if self.atlas is None or len(self.atlas.arrays) == 1 else MAX_ATLAS_TEXTURES

    def _units(self, first: int):
        """The texture units of the atlas' samplers from ``first`` on: one, or an array's."""
        count = self.atlas_textures
        return first if count == 1 else tuple(range(first, first + count))

    def set_uniforms(self, program) -> None:
        """Set ``program``'s lighting and environment uniforms (those it has); they never change."""
        values = {
            "light_count": self.count,
            "shadow_bias": self.bias,
            "shadow_slope_bias": self.slope_bias,
            "shadow_filter": self.filter,
            "shadow_atlas": self._units(ATLAS_UNIT),
            "shadow_triangles": self._units(TRIANGLES_UNIT),
            "atlas_pages_per_texture": 1 if self.atlas is None else self.atlas.per_texture,
            "atlas_textures": 0 if self.atlas is None else len(self.atlas.arrays),
            "atlas_page_height": 1 if self.atlas is None else self.page_size[1],
        }
        env = self.environment
        if env is not None:
            values["environment_radiance"] = tuple(env.intensity)  # the radiance, or the map's scale
            if env.kind == "envmap":
                values["envmap_size"] = (env.envmap.shape[1], env.envmap.shape[0])
                values["envmap_first"] = self.gpu_scene.envmap_first
                to_local = np.linalg.inv(np.asarray(env.to_world, dtype=np.float64)[:3, :3])
                values["environment_to_local"] = tuple(to_local.T.ravel())  # column-major
        set_uniforms(program, values)

    def _check_memory(self, atlas: Atlas, triangles: bool, facing: bool, map_size_setting: str) -> None:
        """Refuse an atlas past half the memory free now (the bundles' headroom), before it is made."""
        room = self.gl.free_memory()
        needed = _atlas_bytes(atlas.pages, atlas.page, triangles, facing)
        if room is not None and needed > room[0] * MEMORY_HEADROOM:
            raise LimitError(
                f"{self.light_vertices:,} light vertices' shadow maps need {format_bytes(needed)} in {atlas.pages} "
                f"atlas pages, over half of the {format_bytes(room[0])} free by {room[1]}; lower the light samples, "
                "the light paths or their maps' size",
                ("light_paths", map_size_setting),
            )

    @property
    def nbytes(self) -> int:
        if self.atlas is None:
            return sum(b.size for b in self.buffers.values()) + self.visibility.nbytes
        arrays = self.atlas.arrays[0]
        atlas = _atlas_bytes(self.pages, self.page_size, arrays.triangles is not None, bool(arrays.facing))
        views = self.view_indices.size
        return sum(b.size for b in self.buffers.values()) + views + atlas + self.visibility.nbytes

    def release(self) -> None:
        for buffer in self.buffers.values():
            buffer.release()
        self.buffers.clear()
        self.visibility.release()
        if self.atlas is not None:
            self.vao.release()
            self.view_indices.release()
            self.atlas.release()
            if self.commands is not None:
                self.commands.release()


def _atlas_bytes(pages: int, page: tuple[int, int], triangles: bool, facing: bool) -> int:
    """The bytes of an atlas of ``pages`` pages of ``page`` texels. A texel: RG32F distances and
    24-bit depth (stored in 32), the triangle seen (R32UI, with light paths) and two facing surfaces
    (R32UI each, where not every triangle bounds a solid)."""
    return pages * page[0] * page[1] * (12 + 4 * triangles + 8 * facing)
