"""Imperfect shadow maps for light vertices (Ritschel et al. 2008, the visibility the imperfect
bundles are modelled on): each light vertex gets one paraboloid map of its front hemisphere, drawn
from ``ism_points`` stratified surface points of its own as disks in their triangles' tangent
planes (as the imperfect bundles' splats are), every vertex's map in one draw
(shaders/lights/imperfect_shadow_maps.glsl), and looked up with the exact maps' filtering and bias
(shaders/include/light_visibility_imperfect.glsl). Their cost grows with the points, not the
triangles: hundreds of light vertices per frame on a scene of 10^5 triangles.

The splat radius is ``ism_splat_scale`` times the radius at which P disks would just cover the
scene's area A once, sqrt(A / (pi P)). Holes (a surface whose splats leave a gap) let light through
where there is none; larger splats close them and widen occluders. ``ism_pull_push`` fills the
holes instead (shaders/lights/ism_pull_push.glsl), the ISM paper's way. `evalkit.metrics.light_visibility`
measures them against exact maps and rays (benchmarks/shadow_maps.py compares pull-push with larger
splats).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import moderngl
import numpy as np

from evalkit.core.settings import setting
from gpu_impl.layout import BINDINGS, LIGHT_VISIBILITY_IMPERFECT
from gpu_impl.lights import Views
from gpu_impl.units import LightVisibility, TuneTerms

DEFAULT_ISM_SIZE = 64
DEFAULT_ISM_POINTS = 4096
# Tangent-plane disks of stratified points leave holes below about 1.5 (light leaking through
# walls) and overhang edges above it (hiding light). Lit-room (studies/bidirectional.toml's
# bidirectional runs, imperfect maps, 8 frames, seeds 0-2), indirect relMSE: 0.069 at 1.0, 0.054
# at 1.3, 0.050 at 1.6, 0.049 at 2.0, and mean ratios at 1.6 as exact maps'
# (docs/results/decisions.toml: ism-splat-scale).
DEFAULT_SPLAT_SCALE = 1.6
MAX_DRAW_VERTICES = 2**31 - 1


@dataclass(frozen=True)
class ImperfectSettings:
    ism_size: int = setting(
        DEFAULT_ISM_SIZE, "texels per side of each light vertex's paraboloid map", minimum=2, unit="texels", symbol="n"
    )
    ism_points: int = setting(
        DEFAULT_ISM_POINTS,
        "surface points splatted into each light vertex's map, a different set per vertex",
        minimum=1,
        symbol="P",
    )
    ism_splat_scale: float = setting(
        DEFAULT_SPLAT_SCALE,
        "splat radius over the radius at which a map's points would just cover the scene",
        positive=True,
    )
    ism_pull_push: bool = setting(
        False, "fill each imperfect shadow map's holes by pull-push (the mean distance of the covered texels around)"
    )


class ImperfectShadowMaps:
    """Each light vertex's paraboloid map (`tiles_per_vertex` 1) in the shadow atlas of
    `gpu_impl.lights.ShadowLights`, splatted from its own points every frame."""

    tiles_per_vertex = 1
    map_size_setting = "ism_size"  # what a limit error names beside the light paths

    def __init__(self, gl, gpu_scene, settings: ImperfectSettings):
        self.gl, self.gpu_scene = gl, gpu_scene
        gpu_scene.splat_facts()  # where splats end and grow (shaders/include/scene.glsl: SplatShape)
        self.map_size, self.points_per_map = settings.ism_size, settings.ism_points
        area = sum(float(m.triangle_areas().sum()) for m in gpu_scene.scene.meshes)
        self.splat_radius = settings.ism_splat_scale * math.sqrt(area / (math.pi * self.points_per_map))
        self.program = gl.program("imperfect_shadow_maps")
        self.program["points_per_map"] = self.points_per_map
        self.program["splat_radius"] = self.splat_radius
        self.vao = gl.vertex_array(self.program, [])
        self.pull_push = PullPush(gl, self.map_size) if settings.ism_pull_push else None

    def defines(self) -> dict:
        return {"LIGHT_VISIBILITY": LIGHT_VISIBILITY_IMPERFECT}

    @property
    def nbytes(self) -> int:
        """What these maps hold beside the shadow atlas: the pull-push pyramids."""
        buffer = None if self.pull_push is None else self.pull_push.buffer
        return 0 if buffer is None else buffer.size

    def check(self, light_vertices: int) -> None:
        """Raises ValueError when ``light_vertices`` maps' points do not fit one draw. The points are
        made in the draw's vertex shader, so they take no memory; a draw counts its vertices in a
        signed 32-bit integer."""
        points = light_vertices * self.points_per_map
        if points > MAX_DRAW_VERTICES:
            raise ValueError(
                f"{light_vertices:,} light vertices x {self.points_per_map:,} points per imperfect shadow map "
                f"= {points:,} points, over the {MAX_DRAW_VERTICES:,} one draw can make; lower --ism-points "
                "or the light vertices"
            )

    def render(self, lights, positions: np.ndarray, normals: np.ndarray, seed: int, frame: int) -> None:
        """The paraboloid views of the vertices at ``positions`` (relative to the bundle centre)
        around their ``normals``, set in the lights' view table, and splatted from this frame's
        points (``seed``, ``frame``)."""
        if not len(positions):
            return
        m = len(positions)
        far = np.linalg.norm(positions, axis=1) + lights.gpu_scene.radius
        views = Views(
            np.broadcast_to(np.eye(4), (m, 4, 4)),
            np.full(m, 2.0 / self.map_size),
            positions,
            np.ones(m, dtype=bool),
            normals,
            far,
        )
        lights.set_views(lights.fixed_views, views, self.map_size)
        lights.upload()
        lights.clear_vertex_tiles()
        lights.gpu_scene.bind()  # the area CDF and the triangles the points are drawn on
        for name in ("LIGHTS", "SHADOW_VIEWS"):  # not the atlas itself: it is being drawn into
            lights.buffers[name].bind_to_storage_buffer(BINDINGS[name])
        self.program["first_vertex_light"] = lights.fixed_lights
        self.program["seed"] = seed & 0xFFFFFFFF
        self.program["frame"] = frame & 0xFFFFFFFF
        self.program["atlas_size"] = lights.page_size
        # A draw per atlas page, of the points of the vertices whose maps lie on it (a run of them).
        pages = lights.view_pages(lights.fixed_views + np.arange(m))
        for page in np.unique(pages):
            first, last = np.searchsorted(pages, page), np.searchsorted(pages, page, side="right")
            self.gl.draw(
                self.vao,
                moderngl.POINTS,
                lights.atlas.framebuffer(page),
                depth_test=True,
                vertices=int(last - first) * self.points_per_map,
                first=int(first) * self.points_per_map,
            )
        if self.pull_push is not None:
            self.pull_push.run(lights, len(positions))

    def release(self) -> None:
        self.vao.release()
        if self.pull_push is not None:
            self.pull_push.release()


class PullPush:
    """Pull-push hole filling of the frame's imperfect shadow maps (shaders/lights/ism_pull_push.glsl): a
    pyramid per map, levels 1.. of ceil(size / 2^l) texels a side down to one texel, in one buffer
    that grows with the light vertices."""

    def __init__(self, gl, map_size: int):
        self.gl = gl
        self.program = gl.program("ism_pull_push")
        self.sizes = [map_size]
        while self.sizes[-1] > 1:
            self.sizes.append((self.sizes[-1] + 1) // 2)
        # Level l's first float in a map's pyramid (level 0 is the atlas itself).
        self.offsets = [0, 0]
        for size in self.sizes[1:-1]:
            self.offsets.append(self.offsets[-1] + size * size)
        self.stride = self.offsets[-1] + self.sizes[-1] ** 2
        self.program["map_stride"] = self.stride
        self.buffer = None

    def run(self, lights, maps: int) -> None:
        """Pull, then push, over the ``maps`` light vertex maps that follow the fixed lights' views."""
        if self.buffer is None or self.buffer.size < 4 * self.stride * maps:
            if self.buffer is not None:
                self.buffer.release()
            self.buffer = self.gl.buffer(reserve=4 * self.stride * maps)
        self.buffer.bind_to_storage_buffer(BINDINGS["ISM_PYRAMID"])
        lights.buffers["SHADOW_VIEWS"].bind_to_storage_buffer(BINDINGS["SHADOW_VIEWS"])
        top = len(self.sizes) - 1
        passes = [(1, level) for level in range(1, top + 1)] + [(0, level) for level in range(top - 1, -1, -1)]
        # Every pass over the maps on one atlas texture, then the next texture's maps.
        pages = lights.view_pages(lights.fixed_views + np.arange(maps))
        for texture, first, last in lights.atlas.texture_pages(pages):
            lights.atlas.bind_images(texture, facing=False)
            self.program["first_view"] = lights.fixed_views + first
            self.program["first_page"] = texture * lights.atlas.per_texture
            for pull, level in passes:
                around = [max(0, min(top, level + i)) for i in (-1, 0, 1)]
                self.program["pull"] = pull
                self.program["level"] = level
                self.program["sizes"] = tuple(self.sizes[i] for i in around)
                self.program["offsets"] = tuple(self.offsets[i] for i in around)
                self.gl.dispatch(self.program, (last - first) * self.sizes[level] ** 2)

    def release(self) -> None:
        if self.buffer is not None:
            self.buffer.release()


def _time(x: dict) -> list:
    # t_ism_points: the maps' points, P per light vertex (V light paths; the 8 emitter samples of eye
    # paths); t_ism_texels: clearing and filtering their texels. Atrium, 256 light vertices: 240 ms
    # at 64 texels and 4096 points, 891 ms at 16384 points, 307 ms at 128 texels
    # (docs/results/decisions.toml: imperfect-vs-culled-exact): the points' cost is linear in them,
    # the texels' about a tenth of it.
    P, size, vertices = x["ism_points"], x["ism_size"], x.get("light_paths", 8) / 8.0
    return [x["frames"] * vertices * P / 4096.0, x["frames"] * vertices * (size / 64.0) ** 2]


VISIBILITY = LightVisibility(
    name="imperfect",
    summary="imperfect shadow maps: a paraboloid map per light vertex, splatted from its own surface points",
    settings=ImperfectSettings,
    maps=ImperfectShadowMaps,
    tune=TuneTerms(
        axes={"ism_points": [1024, 4096, 16384, 65536], "ism_size": [32, 64, 128]},
        time_terms=("t_ism_points", "t_ism_texels"),
        time=_time,
        # A cycle of 5 against the bundle methods' 10 or 13 runs, the light paths' 3 and the eye
        # paths' 4, in which the points take four values and the size three.
        calibration=tuple(
            {"ism_points": p, "ism_size": n} for p, n in ((1024, 64), (16384, 32), (4096, 128), (65536, 64), (4096, 32))
        ),
        # i(P, n): what the maps change of the image against exact maps for the same light
        # vertices. It is no product of the two: more texels lower the light leaked through the
        # slope-scaled bias and leave more of a map uncovered by P points (atrium's changed
        # connections at 4096 points: 21.8 % at 64 texels, 24.5 % at 128; at 65536 points 10.7 and
        # 8.4 %: docs/results/decisions.toml: imperfect-vs-culled-exact), so renders measure every
        # combination, against exact maps.
        measured={"i": ("ism_points", "ism_size")},
        unbiased={"light_visibility": "exact"},
    ),
)
