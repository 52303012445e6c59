"""Eye paths with next-event estimation (the poster's strategy): every path starts at a G-buffer
sample (shaders/paths/primary.glsl) and each bounce takes a bundle of the frame, chosen uniformly (at a
glossy vertex, by its BSDF among ``bsdf_candidates`` of them), and its next node
(shaders/paths/eye_paths.glsl), with no visibility test. Emissive triangles are found two ways,
weighted by multiple importance sampling: by the paths hitting them, and by next-event estimation
through ``light_samples`` points drawn on them per frame (`gpu_impl.lights.EmitterSamples`), the
frame's light vertices, whose visibility the light visibility unit makes. An environment map is
found the same two ways: by the paths leaving the scene, and through ``environment_samples``
directions drawn from it per frame (`gpu_impl.lights.EnvironmentSamples`), each a directional light
with its own shadow map.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evalkit.core.settings import setting
from gpu_impl.layout import BINDINGS
from gpu_impl.lights import EmitterSamples, EnvironmentSamples, LightVertices
from gpu_impl.units import PathStrategy

# Measured on cornell-box (B=3, K=32, R=128, 128x128, 32 frames x 16 paths): indirect relMSE
# 0.0017 for M = 4, 8 and 16 alike, at 345, 430 and 680 ms a frame; direct relMSE 0.0003 at M=4,
# 0.0002 from 8 on.
DEFAULT_LIGHT_SAMPLES = 8


# An environment map with a sun holds much of its power in a few texels, which a frame's K bundle
# directions almost never meet; drawn from the map, every frame's samples hold it.
DEFAULT_ENVIRONMENT_SAMPLES = 8
DEFAULT_ENVIRONMENT_MAP_SIZE = 512
# The bundles a glossy vertex weighs by its BSDF to choose its next one (resampled importance
# sampling, shaders/paths/eye_paths.glsl); each costs a BSDF evaluation.
DEFAULT_BSDF_CANDIDATES = 32


@dataclass(frozen=True)
class EyeSettings:
    light_samples: int = setting(
        DEFAULT_LIGHT_SAMPLES, "points drawn on the emitters per frame for next-event estimation (0: none)", minimum=0
    )
    environment_samples: int = setting(
        DEFAULT_ENVIRONMENT_SAMPLES,
        "directions drawn from an environment map per frame for next-event estimation, each a "
        "directional light with a shadow map of its own (0: none)",
        minimum=0,
    )
    environment_map_size: int = setting(
        DEFAULT_ENVIRONMENT_MAP_SIZE,
        "texels per side of each environment sample's shadow map",
        minimum=8,
        unit="texels",
    )
    bsdf_candidates: int = setting(
        DEFAULT_BSDF_CANDIDATES,
        "bundles a glossy vertex weighs by its BSDF to choose the next one, by resampled importance "
        "sampling (0: a uniform choice, as at diffuse vertices)",
        minimum=0,
    )


# A quarter of an environment map's power in a part of the sky that the frames' bundle directions
# are expected to meet fewer times than this makes its light heavy-tailed noise: an unbiased
# estimate whose frame-to-frame spread says little until they do.
PEAK_SHARE, PEAK_LEAST_HITS = 0.25, 20.0


def peaked_environment(envmap, directions: int) -> list[str]:
    """A warning when ``directions`` bundle directions in all (K x frames) are expected to meet the
    brightest part of ``envmap`` holding `PEAK_SHARE` of its power fewer than `PEAK_LEAST_HITS`
    times (a direction and its opposite each land in solid angle W with probability W / 4 pi)."""
    solid = EnvironmentSamples(envmap, 1).peak(PEAK_SHARE)
    hits = directions * solid / (2.0 * np.pi)
    if hits >= PEAK_LEAST_HITS:
        return []
    return [
        f"the environment map holds {100 * PEAK_SHARE:.0f} % of its power in {100 * solid / (4 * np.pi):.3g} % "
        f"of the sphere, which the render's {directions:,} bundle directions are expected to meet {hits:.2g} "
        "times: its light is heavy-tailed noise and the images' intervals understate it; environment samples "
        "(eye paths' --environment-samples) sample it every frame"
    ]


def _emits(light) -> bool:
    return bool(np.any(light.envmap > 0) and max(light.intensity) > 0)


class EyePaths:
    """The eye strategy of one renderer: its light vertices per frame and its bounce passes."""

    def __init__(self, renderer, settings: EyeSettings):
        self.renderer = renderer
        scene = renderer.gpu_scene
        emitters = scene.features.emitters
        self.emitter_samples = (
            EmitterSamples(scene.scene, settings.light_samples) if emitters and settings.light_samples else None
        )
        # An environment map that emits: a black one has nothing to sample.
        envmap = next((light for light in scene.scene.lights if light.kind == "envmap" and _emits(light)), None)
        self.environment_samples = (
            EnvironmentSamples(envmap, settings.environment_samples)
            if envmap is not None and settings.environment_samples
            else None
        )
        self.environment_map_size = settings.environment_map_size
        self.bsdf_candidates = settings.bsdf_candidates
        self.pdf_buffer = (
            None
            if self.environment_samples is None
            else renderer.gl.buffer(self.environment_samples.pdf.astype(np.float32).tobytes())
        )
        self.warnings = []
        if envmap is not None and self.environment_samples is None:
            self.warnings += peaked_environment(envmap, renderer.settings.directions * renderer.settings.frames)
        if emitters and not settings.light_samples:
            self.warnings.append(
                "next-event estimation is off (light_samples = 0): emissive triangles light only the "
                "paths that hit them, so images of small emitters converge slowly"
            )

    path_vertices_per_frame = 0  # light path vertices (the bidirectional strategy's)
    lazy_lighting_only = False

    @property
    def light_vertices_per_frame(self) -> int:
        return 0 if self.emitter_samples is None else self.emitter_samples.count

    @property
    def environment_samples_per_frame(self) -> int:
        return 0 if self.environment_samples is None else self.environment_samples.count

    def light_vertices(self, seed: int, frame: int) -> LightVertices:
        """This frame's emitter samples (only called when there are some)."""
        self.emitter_samples = self.emitter_samples.posed(self.renderer.gpu_scene.scene)
        return self.emitter_samples.frame_lights(seed, frame)

    def defines(self) -> dict:
        return {
            "EMITTER_SAMPLES": int(self.emitter_samples is not None),
            "ENVIRONMENT_SAMPLES": int(self.environment_samples is not None),
            "BIDIRECTIONAL": 0,
        }

    def bind(self) -> None:
        """Bind the strategy's own buffers: the environment map's sampling density."""
        if self.pdf_buffer is not None:
            self.pdf_buffer.bind_to_storage_buffer(BINDINGS["ENVIRONMENT_PDF"])

    def stats(self) -> dict:
        """The strategy's own statistics of the render (none)."""
        return {}

    @property
    def nbytes(self) -> int:
        return 0 if self.pdf_buffer is None else self.pdf_buffer.size

    def release(self) -> None:
        """Free the strategy's own buffers."""
        if self.pdf_buffer is not None:
            self.pdf_buffer.release()

    def uniforms(self) -> dict:
        values = {"bsdf_candidates": self.bsdf_candidates}
        if self.emitter_samples is not None:
            values["emitter_sample_density"] = self.emitter_samples.density_scale
        if self.environment_samples is not None:
            values["environment_sample_count"] = float(self.environment_samples.count)
        return values

    def programs(self, defines: dict) -> dict:
        """The bounce pass's programs: lazy light (with shadow-mapped lights), and without any or
        from the splat points' precomputed light."""
        gl = self.renderer.gl
        programs = {}
        if defines["SHADOW_LIGHTS"]:  # lit where each path lands, and (splat points) from precomputed light
            programs["eye_paths_lazy"] = gl.program("eye_paths", **defines, LAZY_LIGHTING=1)
        if not defines["SHADOW_LIGHTS"] or (
            self.renderer.tracer.lighting != "lazy" and not self.renderer.lazy_lighting_only
        ):
            programs["eye_paths"] = gl.program("eye_paths", **defines, LAZY_LIGHTING=0)
        return programs

    def bounce(self, j: int, frame: int, lazy: bool) -> None:
        """Every path from vertex j - 1 to vertex j."""
        program = self.renderer.programs["eye_paths_lazy" if lazy else "eye_paths"]
        program["bounce"] = j
        program["frame"] = frame & 0xFFFFFFFF
        self.renderer.gl.dispatch(program, self.renderer.paths)


STRATEGY = PathStrategy(
    name="eye",
    summary="eye paths over the frame's bundles, with next-event estimation to emitter samples",
    settings=EyeSettings,
    paths=EyePaths,
)
