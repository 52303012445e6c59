"""Shadow-mapped lights and the environment on the GPU (shaders/lights.glsl, shadow_maps.glsl).

Point, spot and directional lights get shadow maps in one atlas: a directional light one
orthographic view fitted to the bounding sphere, a spot light one perspective view over its cone
(six when the cone is wider than a cube face), a point light six cube faces. Each cube face is
widened by two texels so that filtering near a face's edge reads rendered texels.

Emissive triangles are lit by next-event estimation: each frame draws ``light_samples`` points on
them (`EmitterSamples`), each a point light whose intensity falls as the cosine to the emitter's
normal, with cube shadow maps of its own size (faces wholly behind the emitter are not drawn). The
environment needs no shadow maps: the eye paths reach it.
"""

from __future__ import annotations

import math

import moderngl
import numpy as np

from evalkit.core.scene.model import Light
from gpu_impl.context import GLContext, set_uniforms
from gpu_impl.layout import BINDINGS, ENVIRONMENT_KINDS, LIGHT, LIGHT_KINDS, SHADOW_VIEW
from gpu_impl.scene_buffers import GpuScene

# A spot light whose cone half-angle is within this of 90 degrees cannot use one perspective view.
MAX_SPOT_VIEW_DEGREES = 60.0
CUBE_FACES = ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1))  # lights.glsl: shadow_view_of
GUARD_TEXELS = 2
# Next-event estimation's defaults (RenderSettings.light_samples, light_sample_map_size). Measured on
# cornell-box (B=3, K=32, R=128, 128x128, 32 frames x 16 paths): indirect relMSE 0.0017 for M = 4,
# 8 and 16 alike, at 345, 430 and 680 ms a frame; direct relMSE 0.0003 at M=4, 0.0002 from 8 on.
# Maps of 128 and 256 texels gave the same errors there; 256 keeps contact shadows of larger scenes.
DEFAULT_LIGHT_SAMPLES = 8
DEFAULT_LIGHT_SAMPLE_MAP_SIZE = 256
# An emitter sample sits this far (times the bounding radius) in front of its triangle, so that its
# own surface lies behind it and its shadow views leave that surface out (shaders/shadow_maps.glsl).
EMITTER_OFFSET = 1e-5


class EmitterSamples:
    """Points on the emissive triangles for next-event estimation, drawn afresh every frame.

    A point y is drawn with probability density p(y) = w(y) / W over the emitters' area, where w is
    the mean of the emitted radiance's channels and W = sum(w A) over the emissive triangles (by
    emitted power), stratified over that power: sample i takes the power quantile (i + u_i) / M.
    Light from y reaches x as L_e cos_y cos_x / |x - y|^2 V(x, y), so the estimate over M samples is
    a sum of point lights of intensity L_e cos_y / (M p(y)): `frame_lights` gives their positions,
    normals and that intensity (per unit cos_y), all in scene space.
    """

    def __init__(self, scene, count: int):
        """``scene`` must have emitters (the importers refuse emitters of zero area)."""
        self.scene, self.count = scene, int(count)
        emitters = [m for m in scene.meshes if scene.materials[m.material].emissive]
        self.triangles = np.concatenate([m.positions[m.faces] for m in emitters])
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
                np.broadcast_to(np.asarray(scene.materials[m.material].emission, dtype=np.float64), (len(m.faces), 3))
                for m in emitters
            ]
        )
        self.weights = self.radiance.mean(axis=1)
        power = self.weights * np.concatenate([m.triangle_areas() for m in emitters])
        self.total = float(power.sum())  # W in p(y) = w(y) / W
        self.cdf = np.cumsum(power) / self.total

    @property
    def density_scale(self) -> float:
        """M / W: M p(y) = density_scale w(y), what the eye paths' MIS weights need (eye_paths.glsl)."""
        return self.count / self.total

    def frame_lights(self, seed: int, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """This frame's samples: positions, unit normals and intensities per unit cos, (M, 3) each,
        and the densities M p(y), (M,)."""
        rng = np.random.default_rng([seed, frame, 2])
        u = (np.arange(self.count) + rng.random(self.count)) / self.count
        t = np.minimum(np.searchsorted(self.cdf, u, side="right"), len(self.cdf) - 1)
        r1, r2 = np.sqrt(rng.random(self.count)), rng.random(self.count)
        b = np.stack([1.0 - r1, r1 * (1.0 - r2), r1 * r2], axis=1)  # uniform over the triangle
        tri = self.triangles[t]
        positions = np.einsum("mk,mkj->mj", b, tri)
        if self.corner_normals is None:
            normals = _face_normals(tri)
        else:
            normals = np.einsum("mk,mkj->mj", b, self.corner_normals[t])
            normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        densities = self.density_scale * self.weights[t]
        return positions, normals, self.radiance[t] / densities[:, None], densities


def _face_normals(triangles: np.ndarray) -> np.ndarray:
    n = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def pack_tiles(sizes: list[int], max_side: int) -> tuple[list[tuple[int, int]], tuple[int, int]]:
    """Square tiles of the given sides (largest first) packed row by row into one atlas: the tiles'
    corners and the atlas size."""
    side = max(max(sizes), 1 << math.ceil(math.log2(math.sqrt(sum(s * s for s in sizes)))))
    corners, x, y, row = [], 0, 0, 0
    for s in sizes:
        if x + s > side:
            x, y, row = 0, y + row, 0
        corners.append((x, y))
        x, row = x + s, max(row, s)
    size = (side, y + row)
    if max(size) > max_side:
        raise ValueError(
            f"{len(sizes)} shadow views ({sum(s * s for s in sizes):,} texels) exceed the GL texture "
            f"limit {max_side}; lower the shadow map sizes or the light samples"
        )
    return corners, size


def _faces_front(face: tuple, normal: np.ndarray) -> bool:
    """Whether any direction of the cube face around axis ``face`` leaves the front of a surface with
    this normal: the others are never looked up. A face spans tan 45 degrees widened by the guard
    texels, at most 1 + 2 GUARD_TEXELS / 8 for the smallest map."""
    a = np.asarray(face, dtype=np.float64)
    return float(a @ normal) + float(np.abs(normal).sum() - abs(a @ normal)) * (1.0 + 2.0 * GUARD_TEXELS / 8) > 0.0


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


class ShadowLights:
    """The scene's point, spot and directional lights and its emitter samples, with their shadow
    atlas, and its environment.

    Parameters: ``map_size`` texels per shadow view side; ``bias`` and ``slope_bias`` the depth
    bias in texels (constant, and per unit tangent of the angle to the light); ``filter`` the PCF
    kernel side in bilinear taps (1: one bilinear 2x2 lookup); ``light_samples`` the emitter
    samples per frame (0: no next-event estimation, the paths find emitters by hitting them) and
    ``sample_map_size`` their shadow views' side.
    """

    def __init__(
        self,
        gl: GLContext,
        gpu_scene: GpuScene,
        map_size: int = 1024,
        bias: float = 1.0,
        slope_bias: float = 2.0,
        filter: int = 1,
        light_samples: int = 0,
        sample_map_size: int = 256,
    ):
        if map_size < 8 or sample_map_size < 8 or filter < 1 or light_samples < 0:
            raise ValueError(
                f"need shadow map sizes >= 8, a filter >= 1 and light samples >= 0, got {map_size}, "
                f"{sample_map_size}, {filter} and {light_samples}"
            )
        self.gl, self.gpu_scene = gl, gpu_scene
        self.map_size, self.bias, self.slope_bias, self.filter = (
            int(map_size),
            float(bias),
            float(slope_bias),
            int(filter),
        )
        self.sample_map_size = int(sample_map_size)
        lights = [light for light in gpu_scene.scene.lights if light.kind in LIGHT_KINDS]
        environments = [light for light in gpu_scene.scene.lights if light.kind in ("constant", "envmap")]
        self.environment = environments[0] if environments else None
        self.emitter_samples = (
            EmitterSamples(gpu_scene.scene, light_samples) if gpu_scene.features.emitters and light_samples else None
        )
        samples = 0 if self.emitter_samples is None else self.emitter_samples.count
        self.count = len(lights) + samples
        records, views = [], []
        for light in lights:
            first = len(views)
            views += self._views(light)
            records.append(self._record(light, first, len(views) - first))
        # The emitter samples' lights and views (6 each, redrawn every frame) follow these.
        self.fixed_lights, self.fixed_views = len(records), len(views)
        self.buffers = {}
        self.atlas = self.framebuffer = None
        if self.count:
            sizes = [self.map_size] * len(views) + [self.sample_map_size] * (6 * samples)
            self.tiles, atlas_size = pack_tiles(sizes, gl.limit("GL_MAX_TEXTURE_SIZE"))
            self.view_records = np.zeros(len(sizes), dtype=SHADOW_VIEW)
            for i, view in enumerate(views):
                self._set_view(i, view, self.map_size)
            self.records = np.zeros(self.count, dtype=LIGHT)
            for i, record in enumerate(records):
                self.records[i] = record
            self.buffers["LIGHTS"] = gl.buffer(self.records.tobytes())
            self.buffers["SHADOW_VIEWS"] = gl.buffer(self.view_records.tobytes())
            self.atlas = gl.texture(atlas_size, 1, dtype="f4")
            self.depth = gl.depth_renderbuffer(self.atlas.size)
            self.framebuffer = gl.framebuffer([self.atlas], self.depth)
            self.program = gl.program("shadow_maps")
            self.vao = gpu_scene.vertex_array(self.program)

    def _set_view(self, i: int, view: tuple, size: int) -> None:
        to_clip, texel, origin, perspective_view, axis, far = view
        self.view_records["to_clip"][i] = to_clip.T  # GLSL matrices are column-major
        self.view_records["tile"][i] = (*self.tiles[i], size, texel)
        self.view_records["origin"][i] = (*origin, 1.0 if perspective_view else 0.0)
        self.view_records["axis"][i] = (*axis, 1.0 / far)

    def sample_emitters(self, seed: int, frame: int) -> None:
        """Draw this frame's emitter samples and render their shadow maps (nothing without them)."""
        if self.emitter_samples is None:
            return
        if self.emitter_samples.scene is not self.gpu_scene.scene:  # posed since: the emitters may have moved
            self.emitter_samples = EmitterSamples(self.gpu_scene.scene, self.emitter_samples.count)
        positions, normals, intensities, densities = self.emitter_samples.frame_lights(seed, frame)
        r = self.gpu_scene.radius
        positions = positions - self.gpu_scene.centre + EMITTER_OFFSET * r * normals
        drawn = []
        for m, (position, normal, intensity, density) in enumerate(zip(positions, normals, intensities, densities)):
            first = self.fixed_views + 6 * m
            far = float(np.linalg.norm(position)) + r
            # The emitter's normal as the views' axis: shaders/shadow_maps.glsl keeps only what is in front.
            for f, view in enumerate(self._cube_views(position, far, self.sample_map_size, axis=normal)):
                self._set_view(first + f, view, self.sample_map_size)
                if _faces_front(CUBE_FACES[f], normal):
                    drawn.append(first + f)
            kind = LIGHT_KINDS["emitter_sample"]
            self.records[self.fixed_lights + m] = (
                (*position, kind),
                (*normal, 0.0),
                (*intensity, 0.0),
                (density, 0.0, first, 6),
            )
        self.buffers["LIGHTS"].write(self.records.tobytes())
        self.buffers["SHADOW_VIEWS"].write(self.view_records.tobytes())
        self._draw(drawn, clear=True)

    # -- views ---------------------------------------------------------------------------

    def _views(self, light: Light) -> list:
        """(to_clip, texel size term, origin, perspective?, axis, farthest distance) per shadow view."""
        centre, r = self.gpu_scene.centre, self.gpu_scene.radius
        s = self.map_size
        if light.kind == "directional":
            d = np.asarray(light.direction, dtype=np.float64)
            eye = -r * d  # relative to the bundle centre: the plane distances start from
            to_clip = orthographic(r, 0.0, 2.0 * r) @ look_at_view(eye, d)
            return [(to_clip, 2.0 * r / s, eye, False, d, 2.0 * r)]
        position = np.asarray(light.position, dtype=np.float64) - centre
        far = np.linalg.norm(position) + r
        near = max(far * 1e-5, 1e-30)
        if light.kind == "spot" and light.cutoff_angle <= MAX_SPOT_VIEW_DEGREES:
            tan_half = math.tan(math.radians(light.cutoff_angle)) * (1.0 + 2.0 * GUARD_TEXELS / s)
            to_clip = perspective(tan_half, near, far) @ look_at_view(
                position, np.asarray(light.direction, dtype=np.float64)
            )
            return [(to_clip, 2.0 * tan_half / s, position, True, np.zeros(3), far)]
        return self._cube_views(position, far, s)

    @staticmethod
    def _cube_views(position: np.ndarray, far: float, size: int, axis: np.ndarray | None = None) -> list:
        near = max(far * 1e-5, 1e-30)
        tan_half = 1.0 + 2.0 * GUARD_TEXELS / size
        axis = np.zeros(3) if axis is None else axis
        return [
            (
                perspective(tan_half, near, far) @ look_at_view(position, np.array(face, dtype=np.float64)),
                2.0 * tan_half / size,
                position,
                True,
                axis,
                far,
            )
            for face in CUBE_FACES
        ]

    def _record(self, light: Light, first_view: int, views: int) -> tuple:
        """The light's `LIGHT` record (shaders/lights.glsl: Light)."""
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
        )

    # -- passes --------------------------------------------------------------------------

    def render_shadow_maps(self) -> None:
        """Draw the scene into the tile of every shadow view of the point, spot and directional lights."""
        if self.framebuffer is None:
            return
        self._draw(range(self.fixed_views), clear=False)

    def _draw(self, views, clear: bool) -> None:
        """Draw the scene into the given views' tiles; ``clear``: clear only those tiles first,
        else the whole atlas (the first draw)."""
        if not views:
            return
        self.gpu_scene.bind()
        self.buffers["SHADOW_VIEWS"].bind_to_storage_buffer(BINDINGS["SHADOW_VIEWS"])
        far = np.finfo(np.float32).max
        if not clear:
            self.framebuffer.clear(red=far, depth=1.0)
        for i in views:
            x, y, size, _ = self.view_records["tile"][i]
            self.framebuffer.viewport = (int(x), int(y), int(size), int(size))
            if clear:
                self.framebuffer.clear(red=far, depth=1.0, viewport=self.framebuffer.viewport)
            self.program["view_index"] = i
            self.gl.draw(self.vao, moderngl.TRIANGLES, self.framebuffer, depth_test=True)

    def defines(self) -> dict:
        return {
            "SHADOW_LIGHTS": int(self.count > 0),
            "EMITTER_SAMPLES": int(self.emitter_samples is not None),
            "ENVIRONMENT": ENVIRONMENT_KINDS[None if self.environment is None else self.environment.kind],
        }

    def bind(self, atlas_unit: int) -> None:
        """Bind the light buffers and the shadow atlas (at texture unit ``atlas_unit``)."""
        for name, buffer in self.buffers.items():
            buffer.bind_to_storage_buffer(BINDINGS[name])
        if self.atlas is not None:
            self.atlas.use(atlas_unit)

    def set_uniforms(self, program, atlas_unit: int) -> None:
        """Set ``program``'s lighting and environment uniforms (those it has); they never change."""
        values = {
            "light_count": self.count,
            "shadow_bias": self.bias,
            "shadow_slope_bias": self.slope_bias,
            "shadow_filter": self.filter,
            "shadow_atlas": atlas_unit,
        }
        if self.emitter_samples is not None:
            values["emitter_sample_density"] = self.emitter_samples.density_scale
        env = self.environment
        if env is not None:
            values["environment_radiance"] = tuple(env.intensity)  # the radiance, or the map's scale
            if env.kind == "envmap":
                values["envmap_size"] = (env.envmap.shape[1], env.envmap.shape[0])
                values["envmap_first"] = self.gpu_scene.envmap_first
                to_local = np.linalg.inv(np.asarray(env.to_world, dtype=np.float64)[:3, :3])
                values["environment_to_local"] = tuple(to_local.T.ravel())  # column-major
        set_uniforms(program, values)

    @property
    def nbytes(self) -> int:
        atlas = 0 if self.atlas is None else self.atlas.size[0] * self.atlas.size[1] * 8  # R32F + depth
        return sum(b.size for b in self.buffers.values()) + atlas

    def release(self) -> None:
        for buffer in self.buffers.values():
            buffer.release()
        self.buffers.clear()
        if self.framebuffer is not None:
            self.vao.release()
            self.framebuffer.release()
            self.atlas.release()
            self.depth.release()
