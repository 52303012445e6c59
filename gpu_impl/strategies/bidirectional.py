"""Bidirectional paths over ray bundles: eye paths as the eye strategy makes them, and each frame V
light paths from the lights over the same bundles (shaders/paths/light_paths.glsl), whose vertices every
eye vertex connects to through their shadow maps (the light visibility unit's: exact or imperfect).
The poster's future work, after Tokuyoshi and Ogaki's bidirectional path tracing via rasterization
(I3D 2012); docs/method.md ("Bidirectional paths") derives it.

Every strategy that can make a path is weighted by multiple importance sampling (the power
heuristic): the eye path hitting an emitter, next-event estimation (emitter samples and the
shadow-mapped lights: the light vertices of depth 0), and a connection from each eye vertex to
each light path vertex of depth 1..B. Strategies differ only in where the path is split, so a
strategy's weight is 1 / sum_j (p_j / p_s)^2 over the densities p_j per area of the whole path;
the eye paths carry the eye side's share of that sum (paths.glsl: path_mis) and the light path
vertices the light side's (lights.glsl: Light.paths), and each connection completes it from its own
edge. Nothing is clamped. Light paths are not connected to the camera (light tracing), which would
need a visibility test per vertex; no strategy here stands in for it, and its paths are found by the
others.

A light path starts at a source drawn by power (the emitters together, each point, spot and
directional light, the environment), stratified over the V paths: an emitter point by emitted power
as next-event estimation draws them; a point or spot light's direction uniform over its sphere or
cone; a directional light's ray through a uniform point of the disk its shadow view covers; the
environment's ray along a bundle direction (uniform over the sphere) through a uniform point of the
frame's disk (a source's paths stratified over these too). Its first surface comes from the bundles
(an emitter, the environment) or from the light's shadow map read as a reflective shadow map (a
fixed light), its later ones from the bundles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from evalkit.core.scene.model import ENVIRONMENT_KINDS
from evalkit.core.settings import setting
from gpu_impl.context import set_uniforms
from gpu_impl.layout import BINDINGS, LIGHT_PATH_START, LIGHT_PATH_VERTEX, NO_TRIANGLE
from gpu_impl.lights import EmitterSamples, LightVertices
from gpu_impl.strategies.eye import EyePaths, EyeSettings, peaked_environment
from gpu_impl.units import PathStrategy, TuneTerms

DEFAULT_LIGHT_PATHS = 32


@dataclass(frozen=True)
class BidirectionalSettings(EyeSettings):
    """The eye strategy's settings (the same declarations: one flag), and the light paths."""

    light_paths: int = setting(
        DEFAULT_LIGHT_PATHS,
        "light paths started at the lights per frame; each leaves up to B vertices that every eye vertex connects to",
        minimum=0,
        symbol="V",
    )


class BidirectionalPaths(EyePaths):
    """The bidirectional strategy of one renderer: the eye strategy's passes with every strategy's
    MIS weights, and the frame's light paths, whose vertices join the frame's light vertices."""

    def __init__(self, renderer, settings: BidirectionalSettings):
        super().__init__(renderer, settings)
        self.light_paths = settings.light_paths
        self.bounces = renderer.settings.bounces
        self.sources = LightSources(renderer.gpu_scene, self.light_paths)
        # No light path without a source that emits.
        self.path_vertices_per_frame = self.light_paths * self.bounces if self.sources.powers.sum() > 0 else 0
        if not self.path_vertices_per_frame and self.light_paths:
            self.warnings.append(
                "bidirectional paths: no light that light paths could start at, so these are eye paths"
            )
        if self.path_vertices_per_frame and self.environment_samples is not None:
            # Their MIS weights hold the bundle direction alone, not the environment's light paths.
            self.environment_samples = None
            self.pdf_buffer.release()
            self.pdf_buffer = None
            self.warnings.append(
                "bidirectional paths draw no environment samples: the environment is found by the eye "
                "paths and by its light paths (environment_samples is for eye paths)"
            )
            envmap = next(light for light in renderer.gpu_scene.scene.lights if light.kind == "envmap")
            self.warnings += peaked_environment(envmap, renderer.settings.directions * renderer.settings.frames)
        self.buffers = {}  # made with the first frame, once the lights have checked that the maps fit
        self.vertex_counts = []

    lazy_lighting_only = True  # connections depend on the eye path (its MIS share), so no light is precomputed

    def defines(self) -> dict:
        # Without light paths (a scene with no light) the eye strategy is all there is.
        return {**super().defines(), "BIDIRECTIONAL": int(self.path_vertices_per_frame > 0)}

    def uniforms(self) -> dict:
        emitters = self.sources.emitter_probability * self.light_paths
        samples = 0 if self.emitter_samples is None else self.emitter_samples.count
        total = self.sources.emitters.total if self.sources.emitters is not None else 1.0
        return {
            "bsdf_candidates": self.bsdf_candidates,
            "emitter_sample_density": samples / total,
            "light_path_emitter_density": emitters / total,
            "light_path_emitter_ratio": emitters / samples if samples else 0.0,
            "light_path_environment_density": self.sources.environment_density,
            "light_path_first": self.renderer.lights.fixed_lights + samples,
        }

    def programs(self, defines: dict) -> dict:
        gl = self.renderer.gl
        programs = {}
        if defines["SHADOW_LIGHTS"]:
            programs["eye_paths_lazy"] = gl.program("eye_paths", **defines, LAZY_LIGHTING=1)
        else:  # nothing to light or connect to
            programs["eye_paths"] = gl.program("eye_paths", **defines, LAZY_LIGHTING=0)
        if self.path_vertices_per_frame:
            keep = (
                "TEXTURES", "NODE_SIDES", "NODE_REFERENCE", "LIGHT_VISIBILITY", "ENVIRONMENT", "ATLAS_TEXTURES",
                "GLOSSY",
            )  # fmt: skip
            programs["light_paths"] = gl.program("light_paths", BIDIRECTIONAL=1, **{k: defines[k] for k in keep})
        return programs

    def light_vertices(self, seed: int, frame: int) -> LightVertices:
        """This frame's emitter samples, then the vertices its light paths left."""
        renderer = self.renderer
        if not self.buffers:
            # The fixed lights' densities never change; the records keep them for every upload.
            renderer.lights.set_light_path_densities(self.sources.path_densities())
            gl = renderer.gl
            self.buffers = {
                "LIGHT_PATH_STARTS": gl.buffer(reserve=max(LIGHT_PATH_START.itemsize * self.light_paths, 4)),
                "LIGHT_PATH_VERTICES": gl.buffer(
                    reserve=max(LIGHT_PATH_VERTEX.itemsize * self.path_vertices_per_frame, 4)
                ),
                "PATH_MIS": gl.buffer(reserve=4 * renderer.paths),
            }
        parts = []
        if self.emitter_samples is not None:
            samples = super().light_vertices(seed, frame)
            n = len(samples.positions)
            none = {"surfaces": np.zeros((n, 4)), "incoming": np.zeros((n, 3))}  # an emitter sample is no surface
            parts.append(samples._replace(depths=np.zeros(n), mis=np.zeros(n), **none))
        count = 0
        if self.path_vertices_per_frame:
            paths = self._trace(seed, frame)
            count = len(paths.positions)
            parts.append(paths)
        self.vertex_counts.append(count)
        for program in renderer.programs.values():
            set_uniforms(program, {"light_path_vertices": count})
        return LightVertices(*(np.concatenate(column) for column in zip(*parts)))

    def _trace(self, seed: int, frame: int) -> LightVertices:
        """Run the frame's light paths on the GPU; their vertices, in scene space."""
        renderer = self.renderer
        starts = self.sources.starts(seed, frame, self.emitter_samples)
        self.buffers["LIGHT_PATH_STARTS"].write(starts.tobytes())
        renderer.bind()
        for name, buffer in self.buffers.items():
            buffer.bind_to_storage_buffer(BINDINGS[name])
        renderer.lights.bind_triangles()
        program = renderer.programs["light_paths"]
        program["frame"] = frame & 0xFFFFFFFF
        renderer.gl.dispatch(program, self.light_paths)
        records = renderer.gl.read(self.buffers["LIGHT_PATH_VERTICES"], LIGHT_PATH_VERTEX)
        records = records[: self.path_vertices_per_frame]
        # A vertex that sends nothing (a black surface) needs no shadow map.
        found = records[(records["position"][:, 3] > 0.0) & (records["intensity"][:, :3].max(axis=1) > 0.0)]
        centre = renderer.gpu_scene.centre
        return LightVertices(
            positions=found["position"][:, :3].astype(np.float64) + centre,
            normals=found["normal"][:, :3].astype(np.float64),
            intensities=found["intensity"][:, :3].astype(np.float64),
            densities=np.zeros(len(found)),
            depths=found["position"][:, 3].astype(np.float64),
            mis=found["normal"][:, 3].astype(np.float64),
            surfaces=found["surface"].astype(np.float64),
            incoming=found["incoming"][:, :3].astype(np.float64),
        )

    def bind(self) -> None:
        if self.buffers:  # none before the first frame's light paths (and none without light sources)
            self.buffers["PATH_MIS"].bind_to_storage_buffer(BINDINGS["PATH_MIS"])

    def stats(self) -> dict:
        """What the frames' light paths left: light path vertices per frame (median)."""
        return {"light_path_vertices_median": int(np.median(self.vertex_counts)) if self.vertex_counts else 0}

    @property
    def nbytes(self) -> int:
        return sum(b.size for b in self.buffers.values())

    def release(self) -> None:
        for buffer in self.buffers.values():
            buffer.release()
        self.buffers.clear()


# LightPathStart.position.w of the sources that are not fixed lights (light_paths.glsl).
FROM_EMITTERS, FROM_ENVIRONMENT = -1.0, -2.0


class LightSources:
    """Where light paths start, drawn by power: each point (4 pi I), spot (2 pi (1 - cos cutoff) I:
    an upper bound of its power) and directional light (pi r^2 E over the disk of the bounding
    sphere), the emitters together (emitted power pi W) and the environment (4 pi L pi r^2 through
    that disk, L its radiance's mean over the sphere), I, E and L the means of their channels."""

    def __init__(self, gpu_scene, light_paths: int):
        scene, r = gpu_scene.scene, gpu_scene.radius
        self.gpu_scene, self.light_paths = gpu_scene, light_paths
        fixed = [light for light in scene.lights if light.kind in ("point", "spot", "directional")]
        powers, self.direction_pdfs = [], []
        for light in fixed:
            mean = float(np.mean(light.intensity))
            if light.kind == "point":
                solid_angle = 4.0 * math.pi
            elif light.kind == "spot":
                solid_angle = 2.0 * math.pi * (1.0 - math.cos(math.radians(light.cutoff_angle or 90.0)))
            else:
                solid_angle = math.pi * r * r  # an area: the disk the light's rays cross
            powers.append(mean * solid_angle)
            self.direction_pdfs.append(1.0 / solid_angle)
        self.ids = list(range(len(fixed)))
        self.emitters = (
            EmitterSamples(scene, light_paths)
            if any(scene.materials[m.material].emissive for m in scene.meshes)
            else None
        )
        if self.emitters is not None:
            powers.append(math.pi * self.emitters.total)
            self.ids.append(FROM_EMITTERS)
        environment = next((light for light in scene.lights if light.kind in ENVIRONMENT_KINDS), None)
        # Its paths' rays: a direction uniform over the sphere and a point uniform on the disk.
        rays = 4.0 * math.pi * math.pi * r * r
        if environment is not None:
            powers.append(mean_radiance(environment) * rays)
            self.ids.append(FROM_ENVIRONMENT)
        self.powers = np.asarray(powers, dtype=np.float64)
        total = self.powers.sum()
        self.probabilities = self.powers / total if total > 0 else self.powers
        self.cdf = np.cumsum(self.probabilities)
        q = dict(zip(self.ids, self.probabilities))
        self.emitter_probability = float(q.get(FROM_EMITTERS, 0.0))
        # V q p(omega) p(point): the density of an environment path's ray (b_n b_{n-1} per unit cos).
        self.environment_density = light_paths * float(q.get(FROM_ENVIRONMENT, 0.0)) / rays

    def path_densities(self) -> np.ndarray:
        """Each fixed light's density of starting a light path along a direction (or through a point
        of its disk): V q p(omega), Light.paths.x (lights.glsl)."""
        return self.light_paths * self.probabilities[: len(self.direction_pdfs)] * np.asarray(self.direction_pdfs)

    def starts(self, seed: int, frame: int, emitter_samples: EmitterSamples | None) -> np.ndarray:
        """The frame's V light path starts (`LIGHT_PATH_START` records), stratified over the
        sources' power, and each fixed light's and the environment's over the unit square their
        starts are drawn from."""
        v = self.light_paths
        rng = np.random.default_rng([seed, frame, 3])
        u = (np.arange(v) + rng.random(v)) / v
        source = np.minimum(np.searchsorted(self.cdf, u, side="right"), len(self.cdf) - 1)
        records = np.zeros(v, dtype=LIGHT_PATH_START)
        records["triangle"] = NO_TRIANGLE
        records["position"][:, 3] = np.asarray(self.ids, dtype=np.float64)[source]
        records["normal"][records["position"][:, 3] == FROM_ENVIRONMENT, 3] = self.environment_density
        on_emitters = records["position"][:, 3] == FROM_EMITTERS
        if on_emitters.any():
            e = self.emitters = self.emitters.posed(self.gpu_scene.scene)
            n = int(on_emitters.sum())
            triangles, positions, normals = e.draw(rng, (np.arange(n) + rng.random(n)) / n)
            p_area = e.weights[triangles] / e.total
            samples = 0 if emitter_samples is None else emitter_samples.count
            records["position"][on_emitters, :3] = positions - self.gpu_scene.centre
            records["normal"][on_emitters, :3] = normals
            records["normal"][on_emitters, 3] = v * self.emitter_probability * p_area
            records["radiance"][on_emitters, :3] = e.radiance[triangles]
            records["radiance"][on_emitters, 3] = samples * p_area
            records["geometric"][on_emitters, :3] = e.face_normals[triangles]
            records["triangle"][on_emitters] = e.scene_triangles[triangles]
        # A fixed light's or the environment's paths start from points of the unit square stratified
        # over them: the first coordinate is where a path's stratum of u falls within its source's
        # share of [0, 1), the second the radical inverse of its rank among the source's paths,
        # shifted at random. Each point is still uniform, so the densities stay V q p. Independent
        # points put a frame's few sun paths on the same part of atrium and left its frame means
        # scattered by 37 % (docs/results/decisions.toml: fixed-light-starts).
        first = np.concatenate([[0.0], self.cdf[:-1]])[source]
        records["square_point"][:, 0] = np.clip((u - first) / self.probabilities[source], 0.0, 1.0)
        rank = np.arange(v) - np.searchsorted(source, source)  # a source's paths are consecutive
        records["square_point"][:, 1] = (radical_inverse(rank) + rng.random(len(self.cdf))[source]) % 1.0
        return records


def radical_inverse(i: np.ndarray) -> np.ndarray:
    """The base-2 radical inverse of each index (van der Corput): its bits mirrored about the point."""
    bits = np.asarray(i, dtype=np.uint64)[:, None] >> np.arange(32, dtype=np.uint64) & np.uint64(1)
    return (bits * 0.5 ** np.arange(1, 33)).sum(axis=1)


def mean_radiance(environment) -> float:
    """The environment's radiance averaged over the sphere and the channels: a lat-long map's rows
    weighted by their solid angle (row j at polar angle pi j / (H - 1), shaders/include/environment.glsl)."""
    scale = float(np.mean(environment.intensity))
    if environment.kind == "constant":
        return scale
    rows = environment.envmap.astype(np.float64).mean(axis=(1, 2))
    weights = np.sin(np.linspace(0.0, math.pi, len(rows))) if len(rows) > 2 else np.ones(len(rows))
    return scale * float(rows @ weights / weights.sum())


def _time(x: dict) -> list:
    # t_light: a frame's V B light vertices, each a shadow map; t_connect: a connection from each
    # of them to every eye vertex (atrium in studies/bidirectional.toml at spp 4, 16, 64: 0.64,
    # 0.79, 1.8 s a frame more than eye paths).
    F, V = x["frames"], x["light_paths"]
    return [F * V * 1e-2, F * V * x["spp"] / 16.0 * 1e-2]


def _error(x: dict) -> list:
    # u: what the connections add, falling with the light paths a frame shares among its pixels.
    return [1.0 / (x["frames"] * x["light_paths"])]


STRATEGY = PathStrategy(
    name="bidirectional",
    summary="eye paths and light paths over the frame's bundles, connected through shadow maps, "
    "every strategy weighted by multiple importance sampling",
    settings=BidirectionalSettings,
    paths=BidirectionalPaths,
    light_vertices=True,
    tune=TuneTerms(
        axes={"light_paths": [8, 16, 32, 64, 128, 256]},
        time_terms=("t_light", "t_connect"),
        time=_time,
        error_terms=("u",),
        error=_error,
        # Taken in turn with the bundle method's runs: a cycle of 3 against their 10 or 13.
        calibration=({"light_paths": 8}, {"light_paths": 64}, {"light_paths": 24}),
    ),
)
