"""The multi-bounce renderer over ray bundles: one frame loop that the registered units plug into.

One frame is: a new `DirectionSet` (a fresh random rotation and grid jitter) and its bundles (the
bundle method's tracer), shadow maps of the point, spot and directional lights (once for a static
scene), the path strategy's light vertices with their shadow maps (the light visibility unit), the
direct light the bundles' nodes or points reflect (or lazily at path hits), the G-buffer with
direct light at its samples, the strategy's bounce passes, and the resolve into images. Frames
accumulate, so the images converge as frames grow; a seed fixes every random choice, and a render
is bitwise repeatable.

Images are split by bounce count as Mitsuba's path integrator's ``max_depth`` splits them: direct
(max_depth 2: emission seen directly, and light after one reflection, from shadow-mapped lights,
from emitters by next-event estimation and through the bundles, and from the environment reached
through the bundles) and indirect (max_depth B + 2 minus max_depth 2), so they compare with
`references.mitsuba.reference` images directly.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path

import moderngl
import numpy as np

from evalkit.core import VERSION
from evalkit.core.atomic import write_text
from evalkit.core.bundleset import DirectionSet
from evalkit.core.display import fields_html, image_html
from evalkit.core.errors import InputError, LimitError
from evalkit.core.exr import write_exr
from evalkit.core.scene import Scene
from evalkit.core.settings import IMAGES, RenderSettings
from gpu_impl.bundles import CAPACITY_SLACK, NodeBudgetExceeded
from gpu_impl.context import GLContext, format_bytes, set_uniforms
from gpu_impl.layout import BINDINGS, LOCAL_SIZE, PATH, PATH_SUMS, TEXEL_UNITS
from gpu_impl.lights import ShadowLights
from gpu_impl.registry import resolve
from gpu_impl.scene_buffers import GpuScene
from gpu_impl.timing import PassTimer

GBUFFER_UNIT = 0  # a texture unit; the lights' atlas takes those from lights.ATLAS_UNIT on


@dataclass
class RenderResult:
    """Images (H, W, 3) float32, the per-pass timings, statistics and the parameters (provenance).

    The frames are independent estimates of the images, so their spread says how noisy the images
    are: ``variances`` holds each image's per-pixel variance of the mean (H, W, 3; None after a
    single frame), ``frame_means`` each frame's image mean per channel (F, 3), which the confidence
    of the image mean needs (`evalkit.metrics.confidence`: within a frame the pixels are correlated).
    """

    images: dict[str, np.ndarray]
    timings: dict
    stats: dict
    params: dict
    warnings: list[str] = field(default_factory=list)
    variances: dict[str, np.ndarray] | None = None
    frame_means: dict[str, np.ndarray] = field(default_factory=dict)

    def _repr_html_(self) -> str:
        """In a notebook: the images (tonemapped, exposure 0) and what made them."""
        p = self.params
        pictures = "".join(
            image_html(image, f"{name}, mean {tuple(round(float(m), 4) for m in image.reshape(-1, 3).mean(0))}")
            for name, image in self.images.items()
        )
        fields = {
            "bundles": f"{p.get('method')}, K={p.get('directions')}, R={p.get('resolution')}",
            "image": f"{p.get('width')}x{p.get('height')}, {p.get('bounces')} bounce(s), seed {p.get('seed')}",
            "frames": f"{p.get('frames_rendered')}, {p.get('paths_per_pixel')} paths per pixel",
            "wall s": self.timings.get("wall_s"),
            "nodes per frame": f"{self.stats.get('nodes_median', 0):,} (median)",
            **{f"warning {i + 1}": w for i, w in enumerate(self.warnings)},
        }
        return f"<div>{pictures}</div>" + fields_html("RenderResult", fields)


class Renderer:
    """Renders one scene with one set of `RenderSettings` on one GL context, frame after frame,
    with the bundle method, path strategy and light visibility the settings name
    (`gpu_impl.registry`). For one render, `gpu_impl.api.render` does all of it in one call; keep
    a Renderer for calls that share its state.

    It uploads the scene and owns that upload, its bundle tracer, its lights and every buffer and
    texture of its passes; `release` (or leaving a ``with`` block) frees them all.
    """

    def __init__(self, gl: GLContext, scene: Scene, settings: RenderSettings):
        self.resolved = resolve(settings)
        settings = self.settings = self.resolved.settings
        self.gl, self.scene = gl, scene
        cam = scene.camera
        self.width, self.height = cam.film_size(settings.width, settings.height)
        s = settings.supersampling
        self.gbuffer_size = (self.width * s, self.height * s)
        self.paths = self.gbuffer_size[0] * self.gbuffer_size[1] * settings.spp
        if self.paths >= 2**32 // 2:
            raise LimitError(f"{self.paths:,} eye paths per frame exceed the 32-bit path index", ("spp",))
        # An animated scene is posed at time + f * time_step in frame f (frame_time), inside one
        # bundle frame that holds every pose. Nothing is kept per frame: a render may ask for more
        # frames than memory holds and stop at its time budget.
        self.frames_rendered = 0  # set by render()
        self.moving = scene.animated and settings.time_step != 0.0
        first = scene.at(self.frame_time(0))
        sphere = None
        if self.moving:
            sphere = enclosing_sphere([scene.at(self.frame_time(f)) for f in range(settings.frames)])
        self.gpu_scene = GpuScene(gl, first, sphere=sphere)
        units, own = self.resolved.units, self.resolved.unit_settings
        self.tracer = units["method"].tracer(gl, self.gpu_scene, settings)
        # The paths' lookups walk across met triangles' edges (shaders/include/bundle_step.glsl:
        # walk_surface), reading the triangles across them, which come with the splats' facts.
        self.gpu_scene.splat_facts()
        # A static scene seen along the same directions every frame has the same bundles and the
        # same irradiance at their nodes or points: both are made once.
        self.reuse_bundles = not settings.rotate_directions and not self.moving
        self.strategy = units["strategy"].paths(self, own["strategy"])
        visibility = units["light_visibility"].maps(gl, self.gpu_scene, own["light_visibility"])
        self.lights = ShadowLights(
            gl,
            self.gpu_scene,
            settings,
            visibility,
            self.strategy.light_vertices_per_frame,
            self.strategy.path_vertices_per_frame,
            self.strategy.environment_samples_per_frame,
            self.strategy.environment_map_size,
        )
        self.warnings = list(scene.warnings) + self.strategy.warnings
        features = self.gpu_scene.features
        if features.glossy and self.tracer.lighting == "precomputed":
            glossy = ", ".join(m.name for m in scene.materials if m.gloss is not None)
            raise InputError(
                scene.source,
                f"glossy materials ({glossy}) reflect light by direction, which precomputed irradiance "
                "cannot hold: use --lighting lazy or auto",
            )
        # Light precomputed per node or splat point is irradiance: what a diffuse surface reflects.
        self.lazy_lighting_only = self.strategy.lazy_lighting_only or features.glossy
        # Shader variants from the scene's features: no shadow-map lookups without such lights, no
        # environment lookups without one, a node's back-side radiance only with two-sided materials.
        self.defines = {
            **self.lights.defines(),
            **self.strategy.defines(),
            "NODE_SIDES": 2 if features.twosided else 1,
            "TEXTURES": int(features.varying_reflectance),
            "GLOSSY": int(features.glossy),
            **self.tracer.defines,
        }
        # The last bounce pass only collects emission and environment light; without either it adds nothing.
        self.steps = settings.bounces + (1 if features.emitters or features.environment else 0)
        self.gbuffer = gl.texture(self.gbuffer_size, 1, dtype="u4")
        self.gbuffer_depth = gl.depth_renderbuffer(self.gbuffer_size)
        self.gbuffer_fbo = gl.framebuffer([self.gbuffer], self.gbuffer_depth)
        self.gbuffer_program = gl.program("gbuffer")
        self.gbuffer_vao = self.gpu_scene.vertex_array(self.gbuffer_program)
        d = self.defines
        primary = (
            "SHADOW_LIGHTS",
            "ENVIRONMENT",
            "TEXTURES",
            "LIGHT_VISIBILITY",
            "BIDIRECTIONAL",
            "ATLAS_TEXTURES",
            "GLOSSY",
        )
        self.programs = {
            "primary": gl.program("primary", **{k: d[k] for k in primary}),
            **self.strategy.programs(d),
            "resolve_images": gl.program("resolve_images"),
        }
        if d["SHADOW_LIGHTS"] and self.tracer.lighting != "lazy" and not self.lazy_lighting_only:
            irradiance = ("SHADOW_LIGHTS", "NODE_SIDES", "TEXTURES", "LIGHT_VISIBILITY", "ATLAS_TEXTURES")
            self.programs["irradiance"] = gl.program("irradiance", **{k: d[k] for k in irradiance})
        self.buffers = {
            "PATHS": gl.buffer(reserve=PATH.itemsize * self.paths),
            "PATH_SUMS": gl.buffer(reserve=PATH_SUMS.itemsize * self.paths),
            "IMAGES": gl.buffer(reserve=2 * 16 * self.width * self.height),  # vec4 direct, then indirect
            # Welford's sum of squared deviations of the frames' pixel values: direct, indirect, total.
            "IMAGE_M2": gl.buffer(reserve=3 * 16 * self.width * self.height),
            # Each workgroup's sum of this frame's pixel values: direct, then indirect.
            "FRAME_SUMS": gl.buffer(reserve=2 * 16 * math.ceil(self.width * self.height / LOCAL_SIZE)),
            "IRRADIANCE": gl.buffer(reserve=4),
            "ALIVE_PATHS": gl.buffer(reserve=4),
        }
        self.irradiance_of = None  # the build whose irradiance the buffer holds (bundles reused: reused too)
        self._posed_at = self.frame_time(0)  # the pose on the GPU
        self.camera = scene.camera.frame(self.gpu_scene.centre, self.width, self.height)
        # Uniforms that stay the same for every frame, set once.
        fixed = {
            "radius": self.gpu_scene.radius,
            "resolution": settings.resolution,
            "bounces": settings.bounces,
            "direction_count": settings.directions,
            "seed": settings.seed,
            "self_hit_bias": settings.self_hit_bias,
            "image_size": (self.width, self.height),
            "supersampling": s,
            "paths_per_sample": settings.spp,
            "coherent_paths": settings.coherent_paths,
            "gbuffer": GBUFFER_UNIT,
            "gbuffer_size": self.gbuffer_size,
            "camera_origin": tuple(self.camera["origin"]),
            "camera_to_world": tuple(self.camera["to_world"].T.ravel()),
            "tan_half_fov": tuple(self.camera["tan_half"]),
            "orthographic": self.camera["orthographic"],
            "triangle_texels": TEXEL_UNITS["triangle_texels"],
            **self.strategy.uniforms(),
        }
        for program in self.programs.values():
            set_uniforms(program, {**self.tracer.uniforms(), **fixed})
            self.lights.set_uniforms(program)

    # -- frames --------------------------------------------------------------------------

    def frame_time(self, f: int) -> float:
        """The time frame ``f`` poses the scene at (seconds)."""
        return self.settings.time + f * self.settings.time_step

    def render(self, progress=None) -> RenderResult:
        """All frames; ``progress`` (optional) gets one line per frame."""
        st = self.settings
        start = time.perf_counter()
        self.gl.fill(self.buffers["PATH_SUMS"])
        frames, bundle_stats, frame_s, self.frame_sums = [], [], [], []
        self.skipped_bounces = 0
        self.lighting_used: list[str] = []
        for f in range(st.frames):
            frame_start = time.perf_counter()
            timer = PassTimer(self.gl)
            if self.moving and (f > 0 or self._posed_at != self.frame_time(0)):
                self.gpu_scene.pose(self.scene.at(self.frame_time(f)))
            self._posed_at = self.frame_time(f)
            reused = self.reuse_bundles and f > 0
            if reused:
                gpu_ms = dict.fromkeys(self.tracer.stats["gpu_ms"], 0.0)
                stats = {**self.tracer.stats, "gpu_ms": gpu_ms, "overflow_reruns": 0}
            else:
                directions = DirectionSet.make(
                    st.directions, seed=st.seed, frame=f if st.rotate_directions else 0, jitter=True
                )
                stats = self.tracer.build(directions)
            bundle_stats.append(stats)
            self._frame(f, timer, shadow_maps=f == 0 or self.moving, build=0 if reused else f)
            passes = {
                "bundles": _sum_ms(stats["gpu_ms"].values()),
                **{f"bundles.{k}": v for k, v in stats["gpu_ms"].items()},
                **timer.milliseconds(),
            }
            frames.append(passes)
            # The pass timer's read waits for the frame's GPU work, so this is the frame's time.
            # The first frame (shadow maps) is left out of the estimate of the next once others exist.
            frame_s.append(time.perf_counter() - frame_start)
            next_frame = float(np.median(frame_s[1:] or frame_s))
            if progress is not None:
                frame_ms = _sum_ms(v for k, v in passes.items() if "." not in k)
                progress(
                    f"frame {f + 1}/{st.frames}: {stats['nodes']:,} nodes, {frame_ms:.1f} ms, "
                    f"about {next_frame * (st.frames - f - 1):.0f} s left"
                )
            if st.time_budget and time.perf_counter() - start + next_frame > st.time_budget:
                break
        self.frames_rendered = len(frames)
        images, variances = self._read_images()
        pixels = self.width * self.height
        frame_means = {"direct": np.array([s[0] for s in self.frame_sums]) / pixels}
        frame_means["indirect"] = np.array([s[1] for s in self.frame_sums]) / pixels
        frame_means["total"] = frame_means["direct"] + frame_means["indirect"]
        wall = time.perf_counter() - start
        names = dict.fromkeys(k for fr in frames for k in fr)
        timings = {
            "method": timer.method,
            "median_ms": {name: _median([fr.get(name) for fr in frames]) for name in names},
            "frames_ms": frames,
            "wall_s": wall,
        }
        # A frame's time: every pass, but static scenes render their shadow maps once, not per frame.
        once = set() if self.moving else {"shadow_maps"}
        timings["median_ms"]["frame"] = _median(
            [_sum_ms(v for k, v in fr.items() if "." not in k and k not in once) for fr in frames]
        )
        nodes = [s["nodes"] for s in bundle_stats]
        lighting = {
            mode: self.lighting_used.count(mode) for mode in ("precomputed", "lazy") if mode in self.lighting_used
        }
        stats = {
            "nodes_median": int(np.median(nodes)),
            "nodes_max": int(max(nodes)),
            "overflow_reruns": sum(s["overflow_reruns"] for s in bundle_stats),
            "max_list_length": max(s["max_list_length"] for s in bundle_stats),
            "paths_per_frame": self.paths,
            "bounce_passes": self.steps,
            "bounce_passes_skipped": self.skipped_bounces,
            "bundles_reused": len(frames) - 1 if self.reuse_bundles else 0,
            "lighting_frames": lighting,
            "gpu_bytes": self.gpu_bytes,
            **self.strategy.stats(),
        }
        params, warnings = self.params(), list(self.warnings)
        return RenderResult(images, timings, stats, params, warnings, variances, frame_means)

    def _frame(self, frame: int, timer: PassTimer, shadow_maps: bool, build: int) -> None:
        """One frame's passes on the bundles of frame ``build`` (this one, or 0 when reused)."""
        st = self.settings
        if shadow_maps:
            with timer.measure("shadow_maps"):
                self.lights.render_shadow_maps()
        if self.strategy.environment_samples_per_frame:
            with timer.measure("environment_samples"):
                self.lights.set_environment_samples(*self.strategy.environment_samples.frame_samples(st.seed, frame))
            self.irradiance_of = None  # lit by this frame's environment samples
        if self.strategy.light_vertices_per_frame or self.strategy.path_vertices_per_frame:
            with timer.measure("emitter_samples" if not self.strategy.path_vertices_per_frame else "light_paths"):
                self.lights.set_light_vertices(self.strategy.light_vertices(st.seed, frame), st.seed, frame)
            self.irradiance_of = None  # lit by this frame's light vertices
        self.bind()
        with timer.measure("gbuffer"):
            self._gbuffer(frame)
        alive = self._alive_paths()
        lazy = False
        if self.defines["SHADOW_LIGHTS"]:
            lazy = self._lighting(alive, build)
            self.lighting_used.append("lazy" if lazy else "precomputed")
            if not lazy and self.irradiance_of != build:
                with timer.measure("irradiance"):
                    self.buffers["IRRADIANCE"].bind_to_storage_buffer(BINDINGS["IRRADIANCE"])
                    self.gl.dispatch(self.programs["irradiance"], self.tracer.irradiance_items)
                self.irradiance_of = build
        for j in range(1, self.steps + 1):
            # Once every path has ended (throughput zero, or nothing hit), the passes left add nothing.
            if st.stop_early and (alive if j == 1 else self._alive_paths()) == 0:
                self.skipped_bounces += self.steps - j + 1
                break
            self.buffers["ALIVE_PATHS"].write(b"\0\0\0\0")
            with timer.measure(f"bounce_{j}"):
                self.strategy.bounce(j, frame, lazy)
        with timer.measure("resolve"):
            resolve_images = self.programs["resolve_images"]
            resolve_images["sample_weight"] = 1.0 / (st.supersampling**2 * st.spp * (frame + 1))
            resolve_images["frame"] = frame & 0xFFFFFFFF
            self.gl.dispatch(resolve_images, self.width * self.height)
        sums = self.gl.read(self.buffers["FRAME_SUMS"], np.float32).reshape(-1, 2, 4)
        self.frame_sums.append(sums[..., :3].astype(np.float64).sum(axis=0))  # direct, indirect

    def _lighting(self, alive: int, build: int) -> bool:
        """True to light each path's hits where they land, False to precompute the irradiance of
        every splat point: whichever costs fewer light evaluations this frame (the alive paths at
        most once per bounce, against the items; nothing when the bundles' irradiance is already
        there), unless the method's ``lighting`` says. Perfect bundles' hits are lit where the ray
        lands, which no node's light can follow (precomputed per node, cornell-box's indirect light
        was +2.7 % at R = 64 against +0.4 %). Precomputed irradiance counts against the node
        budget; in "auto" a frame it does not fit in is lit lazily."""
        mode = self.tracer.lighting
        if mode == "lazy" or self.lazy_lighting_only:
            return True
        items = self.tracer.irradiance_items
        needed = 12 * self.defines["NODE_SIDES"] * items
        limit, words = self.tracer.memory_limit()
        if self.tracer.memory_bytes + needed > limit:
            if mode == "precomputed":
                raise NodeBudgetExceeded(
                    self.scene.name,
                    f"precomputed irradiance for {items:,} splat points needs "
                    f"{format_bytes(needed)} beside the bundles' {format_bytes(self.tracer.memory_bytes)}, "
                    f"over {words}; raise --node-budget or use --lighting lazy",
                )
            return True
        if mode == "auto" and self.irradiance_of != build and alive * self.settings.bounces < items:
            return True
        if self.buffers["IRRADIANCE"].size < needed:
            self.buffers["IRRADIANCE"].release()
            self.buffers["IRRADIANCE"] = self.gl.buffer(reserve=int(needed * CAPACITY_SLACK))
            self.irradiance_of = None
        return False

    def _gbuffer(self, frame: int) -> None:
        """Rasterize the camera view (this frame's sub-pixel jitter), then the PRIMARY pass."""
        st = self.settings
        subpixel = np.random.default_rng([st.seed, frame, 1]).random(2)
        self.gbuffer_fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self.gbuffer_program["to_clip"] = tuple(gbuffer_projection(self.camera, self.gbuffer_size, subpixel).T.ravel())
        self.gl.draw(self.gbuffer_vao, moderngl.TRIANGLES, self.gbuffer_fbo, depth_test=True)
        program = self.programs["primary"]
        program["subpixel"] = tuple(subpixel)
        self.buffers["ALIVE_PATHS"].write(b"\0\0\0\0")
        self.gl.dispatch(program, self.paths)

    def _alive_paths(self) -> int:
        return int(self.gl.read(self.buffers["ALIVE_PATHS"], np.uint32, 1)[0])

    def bind(self) -> None:
        """Every buffer and texture the frame's compute passes read, at their bindings."""
        self.tracer.bind()
        # The lookups read the triangles as texels (shaders/include/common.glsl: TRIANGLE_TEXELS).
        self.gpu_scene.triangle_texels().use(TEXEL_UNITS["triangle_texels"])
        for name, buffer in self.buffers.items():
            buffer.bind_to_storage_buffer(BINDINGS[name])
        self.lights.bind()
        self.strategy.bind()
        self.gbuffer.use(GBUFFER_UNIT)

    def _read_images(self) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray] | None]:
        """The images, and their per-pixel variances of the mean (None after one frame)."""
        shape = (self.height, self.width, 4)
        raw = self.gl.read(self.buffers["IMAGES"], np.float32).reshape(2, *shape)
        direct, indirect = raw[0, ..., :3].copy(), raw[1, ..., :3].copy()
        images = {"direct": direct, "indirect": indirect, "total": direct + indirect}
        frames = self.frames_rendered
        if frames < 2:
            return images, None
        m2 = self.gl.read(self.buffers["IMAGE_M2"], np.float32).reshape(3, *shape)[..., :3]
        variances = {name: m2[i] / (frames * (frames - 1)) for i, name in enumerate(IMAGES)}
        return images, variances

    # -- provenance ----------------------------------------------------------------------

    def params(self) -> dict:
        """Every setting of the render (the units' at their defaults where not given), what it
        derived, the shader variant and the GL device."""
        st = self.settings
        return {
            "evalkit": VERSION,
            "scene": self.scene.name,
            "scene_source": self.scene.source,
            "scene_hash": self.scene.content_hash(),
            "posed_scene_hash": self.scene.at(st.time).content_hash() if self.scene.animated else None,
            **self.resolved.params(),
            "width": self.width,
            "height": self.height,
            **self.tracer.params(),
            "frames_rendered": self.frames_rendered,
            "paths_per_pixel": st.supersampling**2 * st.spp * self.frames_rendered,
            "shader_variant": self.defines,
            "gl": self.gl.info,
        }

    @property
    def gpu_bytes(self) -> int:
        own = sum(b.size for b in self.buffers.values())
        gbuffer = self.gbuffer_size[0] * self.gbuffer_size[1] * 8
        return own + gbuffer + self.tracer.gpu_bytes + self.lights.nbytes + self.strategy.nbytes

    def release(self) -> None:
        for buffer in self.buffers.values():
            buffer.release()
        self.buffers.clear()
        self.gbuffer_vao.release()
        self.gbuffer_fbo.release()
        self.gbuffer.release()
        self.gbuffer_depth.release()
        self.lights.release()
        self.strategy.release()
        self.tracer.release()
        self.gpu_scene.release()

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


# -- camera ---------------------------------------------------------------------------------


def enclosing_sphere(scenes: list[Scene]) -> tuple[np.ndarray, float]:
    """A sphere around every pose of an animated scene (centred on the union of their bounds)."""
    lo = np.min([s.bounds()[0] for s in scenes], axis=0)
    hi = np.max([s.bounds()[1] for s in scenes], axis=0)
    centre = 0.5 * (lo + hi)
    return centre, max(float(np.linalg.norm(m.positions - centre, axis=1).max()) for s in scenes for m in s.meshes)


def gbuffer_projection(cam: dict, size: tuple[int, int], subpixel: np.ndarray) -> np.ndarray:
    """Clip-space matrix of positions relative to the bundle centre, for a G-buffer of ``size``
    whose pixel (x, y) (y from the image's top) covers film position ((x, y) + subpixel) / size
    at its centre, where eye_paths.glsl (PRIMARY) sends that sample's camera ray."""
    to_camera = np.linalg.inv(
        np.block([[cam["to_world"], cam["origin"][:, None]], [np.zeros((1, 3)), np.ones((1, 1))]])
    )
    tx, ty = cam["tan_half"]
    w, h = size
    n, f = cam["near"], cam["far"]
    if cam["orthographic"]:
        # film u = 1/2 - x / (2 tan_x) at any depth z (camera space, the plane's units), z from 0.
        return (
            np.array(
                [
                    [-1.0 / tx, 0.0, 0.0, (1.0 - 2.0 * subpixel[0]) / w],
                    [0.0, -1.0 / ty, 0.0, (1.0 - 2.0 * subpixel[1]) / h],
                    [0.0, 0.0, 2.0 / f, -1.0],
                    [0.0, 0.0, 0.0, 1.0],
                ]
            )
            @ to_camera
        )
    # film u = 1/2 - x / (2 z tan_x) and v = 1/2 - y / (2 z tan_y); the rasterizer samples pixel
    # centres, so pixel x's centre x + 1/2 must sit at u w = x + subpixel_x.
    proj = np.array(
        [
            [-1.0 / tx, 0.0, (1.0 - 2.0 * subpixel[0]) / w, 0.0],
            [0.0, -1.0 / ty, (1.0 - 2.0 * subpixel[1]) / h, 0.0],
            [0.0, 0.0, (f + n) / (f - n), -2.0 * f * n / (f - n)],
            [0.0, 0.0, 1.0, 0.0],
        ]
    )
    return proj @ to_camera


# -- output ---------------------------------------------------------------------------------


def write_render(result: RenderResult, out: str | os.PathLike) -> list[Path]:
    """direct.exr, indirect.exr and total.exr (float32, provenance and the frames' image means in
    the header), their ``<image>_variance.exr`` (after two frames or more) and timings.json
    (timings, statistics, parameters and warnings) in ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    provenance = {**result.params, "warnings": result.warnings}
    for name in IMAGES:
        path = out / f"{name}.exr"
        frame_means = result.frame_means[name].tolist()
        write_exr(path, result.images[name], {**provenance, "image": name, "frame_means": frame_means})
        written.append(path)
        if result.variances is not None:
            path = out / f"{name}_variance.exr"
            what = "variance of the pixel mean from the spread of the frames' pixel values, per RGB channel"
            write_exr(path, result.variances[name], {**provenance, "image": f"{name}_variance", "variance": what})
            written.append(path)
    path = out / "timings.json"
    record = {"timings": result.timings, "stats": result.stats, "params": result.params, "warnings": result.warnings}
    write_text(path, json.dumps(record, indent=2) + "\n")
    written.append(path)
    return written


def _median(values) -> float | None:
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def _sum_ms(values) -> float | None:
    values = list(values)
    return None if any(v is None for v in values) else float(sum(values))
