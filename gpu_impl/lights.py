"""Shadow-mapped lights and the environment on the GPU (shaders/lights.glsl, shadow_maps.glsl).

Point, spot and directional lights get shadow maps in one atlas: a directional light one
orthographic view fitted to the bounding sphere, a spot light one perspective view over its cone
(six when the cone is wider than a cube face), a point light six cube faces. Each cube face is
widened by two texels so that filtering near a face's edge reads rendered texels.

Emissive triangles and the environment need no shadow maps: the eye paths reach them.
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
    """The scene's point, spot and directional lights with their shadow atlas, and its environment.

    Parameters: ``map_size`` texels per shadow view side; ``bias`` and ``slope_bias`` the depth
    bias in texels (constant, and per unit tangent of the angle to the light); ``filter`` the PCF
    kernel side in bilinear taps (1: one bilinear 2x2 lookup).
    """

    def __init__(self, gl: GLContext, gpu_scene: GpuScene, map_size: int = 1024, bias: float = 1.0,
                 slope_bias: float = 2.0, filter: int = 1):
        if map_size < 8 or filter < 1:
            raise ValueError(f"need a shadow map size >= 8 and a filter >= 1, got {map_size} and {filter}")
        self.gl, self.gpu_scene = gl, gpu_scene
        self.map_size, self.bias, self.slope_bias, self.filter = int(map_size), float(bias), float(slope_bias), int(filter)
        lights = [light for light in gpu_scene.scene.lights if light.kind in LIGHT_KINDS]
        environments = [light for light in gpu_scene.scene.lights if light.kind in ("constant", "envmap")]
        self.environment = environments[0] if environments else None
        self.count = len(lights)
        records, views = [], []
        for light in lights:
            first = len(views)
            views += self._views(light)
            records.append(self._record(light, first, len(views) - first))
        self.views = views
        self.buffers = {}
        self.atlas = self.framebuffer = None
        if lights:
            cols = math.ceil(math.sqrt(len(views)))
            rows = math.ceil(len(views) / cols)
            max_side = gl.limit("GL_MAX_TEXTURE_SIZE")
            if max(cols, rows) * self.map_size > max_side:
                raise ValueError(f"{len(views)} shadow views of {self.map_size}^2 texels exceed the GL texture limit {max_side}")
            view_records = np.zeros(len(views), dtype=SHADOW_VIEW)
            for i, (to_clip, texel, origin, perspective_view, axis, far) in enumerate(views):
                view_records["to_clip"][i] = to_clip.T  # GLSL matrices are column-major
                view_records["tile"][i] = ((i % cols) * self.map_size, (i // cols) * self.map_size, self.map_size, texel)
                view_records["origin"][i] = (*origin, 1.0 if perspective_view else 0.0)
                view_records["axis"][i] = (*axis, 1.0 / far)
            self.buffers["LIGHTS"] = gl.buffer(np.array(records, dtype=LIGHT).tobytes())
            self.buffers["SHADOW_VIEWS"] = gl.buffer(view_records.tobytes())
            self.atlas = gl.texture((cols * self.map_size, rows * self.map_size), 1, dtype="f4")
            self.depth = gl.depth_renderbuffer(self.atlas.size)
            self.framebuffer = gl.framebuffer([self.atlas], self.depth)
            self.program = gl.program("shadow_maps")
            self.vao = gpu_scene.vertex_array(self.program)

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
            to_clip = perspective(tan_half, near, far) @ look_at_view(position, np.asarray(light.direction, dtype=np.float64))
            return [(to_clip, 2.0 * tan_half / s, position, True, np.zeros(3), far)]
        tan_half = 1.0 + 2.0 * GUARD_TEXELS / s
        return [(perspective(tan_half, near, far) @ look_at_view(position, np.array(face, dtype=np.float64)),
                 2.0 * tan_half / s, position, True, np.zeros(3), far) for face in CUBE_FACES]

    def _record(self, light: Light, first_view: int, views: int) -> tuple:
        """The light's `LIGHT` record (shaders/lights.glsl: Light)."""
        kind = LIGHT_KINDS[light.kind]
        position = np.zeros(3) if light.position is None else np.asarray(light.position) - self.gpu_scene.centre
        direction = np.zeros(3) if light.direction is None else np.asarray(light.direction, dtype=np.float64)
        cutoff = math.radians(light.cutoff_angle or 90.0)
        beam = math.radians(light.beam_width if light.beam_width is not None else 0.75 * (light.cutoff_angle or 90.0))
        beam = min(beam, cutoff)
        inv_transition = 1.0 / (cutoff - beam) if cutoff > beam else 0.0
        return ((*position, kind), (*direction, math.cos(cutoff)), (*light.intensity, math.cos(beam)),
                (cutoff, inv_transition, first_view, views))

    # -- passes --------------------------------------------------------------------------

    def render_shadow_maps(self) -> None:
        """Draw the scene into every shadow view's tile."""
        if self.framebuffer is None:
            return
        self.gpu_scene.bind()
        self.buffers["SHADOW_VIEWS"].bind_to_storage_buffer(BINDINGS["SHADOW_VIEWS"])
        self.framebuffer.clear(red=np.finfo(np.float32).max, depth=1.0)
        s = self.map_size
        cols = self.atlas.size[0] // s
        for i in range(len(self.views)):
            self.framebuffer.viewport = ((i % cols) * s, (i // cols) * s, s, s)
            self.program["view_index"] = i
            self.gl.draw(self.vao, moderngl.TRIANGLES, self.framebuffer, depth_test=True)

    def defines(self) -> dict:
        return {"SHADOW_LIGHTS": int(self.count > 0),
                "ENVIRONMENT": ENVIRONMENT_KINDS[None if self.environment is None else self.environment.kind]}

    def bind(self, atlas_unit: int) -> None:
        """Bind the light buffers and the shadow atlas (at texture unit ``atlas_unit``)."""
        for name, buffer in self.buffers.items():
            buffer.bind_to_storage_buffer(BINDINGS[name])
        if self.atlas is not None:
            self.atlas.use(atlas_unit)

    def set_uniforms(self, program, atlas_unit: int) -> None:
        """Set ``program``'s lighting and environment uniforms (those it has); they never change."""
        values = {"light_count": self.count, "shadow_bias": self.bias, "shadow_slope_bias": self.slope_bias,
                  "shadow_filter": self.filter, "shadow_atlas": atlas_unit}
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
