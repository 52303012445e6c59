"""What a registered unit is: a bundle method, a light visibility or a path strategy, each one module
(and its shaders) that declares its name, its own settings with their defaults and ranges, and what
it makes. `gpu_impl.registry` lists the units; nothing else names them.

A unit's settings are a frozen dataclass of `evalkit.core.settings.setting` fields: the command
line makes a flag of each, studies validate run parameters against them, and the render's
provenance records them. `RenderSettings` carries them flat, as ``options``; `settings_of` gives a
unit its own slice, defaults filled in and checked.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol, runtime_checkable

from evalkit.core.settings import RenderSettings, check_settings, declared


@dataclass(frozen=True)
class NoSettings:
    """The settings of a unit that has none of its own."""


@dataclass(frozen=True)
class TuneTerms:
    """What a unit adds to `evalkit.tune`'s models (its package docstring has them all): a tuner
    candidate is a bundle method, a path strategy and a light visibility, and its models have the
    terms of all three.

    ``axes``: the unit's own settings the optimiser varies, with the values it chooses from.
    ``time_terms`` / ``time``: names and per-frame features of the time model's terms beyond the
    shared ones (a constant, the lists K R^2 and the eye paths S); ``error_terms`` / ``error``: the
    error model's beyond the shared bias and noise. Features are functions of a dict of settings
    (directions, resolution, spp, frames and the axes; ``sampler`` too for the error) that work on
    numpy arrays and scalars alike. ``calibration``: the unit's calibration runs, spread so that
    every term changes between them (a candidate's runs are its bundle method's, each with the
    other units' settings taken in turn from theirs). ``measured``: error terms of a bias, each with
    the settings it changes with, measured by renders instead of fitted: renders that differ only
    in those settings (every combination of their axes' values; at one seed the same paths, at two
    seeds independent noise) give what each combination adds to the metric over the render with
    the settings ``unbiased`` (`evalkit.tune.calibration.measure_bias`; by default each setting's
    largest value). A calibration run's noise hides a bias that a close-up of a contact shows (+9 %
    at the smallest exact maps), and no one power of the setting follows it; fitted, such a term
    followed the noise. Only metrics to which a bias adds its square can be measured so
    (`evalkit.tune.models.SQUARED_METRICS`); under the others these settings stay at their defaults.
    """

    axes: dict = field(default_factory=dict)
    time_terms: tuple[str, ...] = ()
    time: Callable = lambda x: []
    error_terms: tuple[str, ...] = ()
    error: Callable = lambda x: []
    calibration: tuple[dict, ...] = ()
    measured: dict = field(default_factory=dict)  # term -> (setting, ...)
    unbiased: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Unit:
    """A registered unit: its ``name`` (what settings, flags and study files say), a line saying
    what it does, the dataclass of its own settings and its terms in the tuner's models."""

    kind: ClassVar[str] = "unit"
    name: str
    summary: str
    settings: type = NoSettings
    tune: TuneTerms = TuneTerms()

    def option_names(self) -> list[str]:
        return [f.name for f in declared(self.settings)]

    def settings_of(self, render: RenderSettings) -> Any:
        """This unit's settings: those ``render`` gives, the others at their defaults; checked."""
        given = dict(render.options)
        mine = self.settings(**{name: given[name] for name in self.option_names() if name in given})
        check_settings(mine)
        return mine

    def describe(self, settings: Any) -> str:
        """The unit and its settings in a few symbols, e.g. 'imperfect N=16384 s=1.8'."""
        short = [
            f"{f.metadata['symbol']}={getattr(settings, f.name)}"
            for f in declared(self.settings)
            if f.metadata["symbol"]
        ]
        return " ".join([self.name, *short])


# What the renderer (gpu_impl/renderer.py, gpu_impl/lights.py) uses of the objects a unit makes:
# every member, so that a new unit knows what it owes. tests/test_units.py checks each registered
# unit's objects against these.


@runtime_checkable
class Tracer(Protocol):
    """What a bundle method's ``tracer(...)`` makes (`gpu_impl.bundles.BundleTracer` is the shared
    core): it builds a frame's bundles on the GPU and says what they cost."""

    defines: dict  # its shader variant's defines (NODE_REFERENCE: what a node's reference is)
    lighting: str  # where node light is computed: "auto", "precomputed" or "lazy"
    irradiance_items: int  # how many precomputed irradiance records (per node or per splat point)
    stats: dict  # the last build's statistics (nodes, memory, pass times)

    def build(self, directions) -> dict:
        """Build the frame's lists for a `DirectionSet`; returns the build's statistics."""

    def memory_limit(self) -> tuple[int, str]:
        """The most it may hold in bytes (the node budget, or the memory free), and that in words."""

    def bind(self) -> None:
        """Bind its buffers for the path passes."""

    def uniforms(self) -> dict:
        """The path passes' uniforms it sets (resolution, radius, splat radius ...)."""

    def params(self) -> dict:
        """Its settings as they went into the build, for provenance."""

    @property
    def gpu_bytes(self) -> int:
        """Bytes it holds on the GPU."""

    @property
    def memory_bytes(self) -> int:
        """Bytes of nodes the last build used."""

    def release(self) -> None:
        """Free its GPU objects."""


@runtime_checkable
class ShadowMaps(Protocol):
    """What a light visibility's ``maps(...)`` makes: the shadow maps of a frame's light vertices,
    drawn into `gpu_impl.lights.ShadowLights`' atlas after its fixed lights' views."""

    tiles_per_vertex: int  # atlas tiles per light vertex (6 cube faces, 1 paraboloid map ...)
    map_size: int  # texels per tile side
    map_size_setting: str  # the setting that gives map_size (named in limit errors)
    nbytes: int  # bytes it holds beside the atlas

    def defines(self) -> dict:
        """Its shader variant's defines (LIGHT_VISIBILITY)."""

    def check(self, light_vertices: int) -> None:
        """Raise a `LimitError` when this many light vertices cannot be drawn."""

    def render(self, lights, positions, normals, seed: int, frame: int) -> None:
        """Draw the vertices' maps into ``lights``' atlas (positions relative to the bundle centre)."""

    def release(self) -> None:
        """Free its GPU objects."""


@runtime_checkable
class Paths(Protocol):
    """What a path strategy's ``paths(...)`` makes: a frame's light vertices and bounce passes."""

    warnings: list  # what the render's outputs should say about it
    lazy_lighting_only: bool  # whether node light must be computed where each path lands
    light_vertices_per_frame: int  # emitter samples per frame
    path_vertices_per_frame: int  # light path vertices per frame (bidirectional paths)
    environment_samples_per_frame: int  # directions drawn from an environment map per frame
    environment_map_size: int  # texels per side of each environment sample's shadow map
    environment_samples: Any  # the `EnvironmentSamples` (None without)
    nbytes: int  # bytes it holds on the GPU

    def light_vertices(self, seed: int, frame: int):
        """The frame's `LightVertices` (only called when it has some)."""

    def defines(self) -> dict:
        """Its shader variants' defines (EMITTER_SAMPLES, ENVIRONMENT_SAMPLES, BIDIRECTIONAL)."""

    def uniforms(self) -> dict:
        """The bounce passes' uniforms it sets."""

    def programs(self, defines: dict) -> dict:
        """Its bounce passes' programs, by name."""

    def bind(self) -> None:
        """Bind its own buffers."""

    def bounce(self, j: int, frame: int, lazy: bool) -> None:
        """Every path from vertex j - 1 to vertex j."""

    def stats(self) -> dict:
        """Its own statistics of the render."""

    def release(self) -> None:
        """Free its GPU objects."""


@dataclass(frozen=True)
class BundleMethod(Unit):
    """A way to build ray bundles on the GPU. ``tracer(gl, gpu_scene, render_settings, **extra)``
    makes its `Tracer` (``extra``: the tracer's test and study hooks)."""

    kind: ClassVar[str] = "bundle method"
    tracer: Callable = None


@dataclass(frozen=True)
class LightVisibility(Unit):
    """How light vertices (emitter samples, light-path vertices) see the scene: shadow maps of one
    kind. ``maps(gl, gpu_scene, its_settings)`` makes the `ShadowMaps` that draw them each frame
    (`gpu_impl.visibility`)."""

    kind: ClassVar[str] = "light visibility"
    maps: Callable = None


@dataclass(frozen=True)
class PathStrategy(Unit):
    """How a frame's paths are made and weighted. ``paths(renderer, its_settings)`` makes the `Paths`
    that run them each frame (`gpu_impl.strategies`); ``light_vertices``: whether they start at the
    lights, so that every scene's frames have light vertices and their maps (otherwise only the
    emitter samples of emissive triangles have them)."""

    kind: ClassVar[str] = "path strategy"
    paths: Callable = None
    light_vertices: bool = False


class Registry:
    """The registered units of one kind, by name, in the order registered: the first is the default."""

    def __init__(self, kind: str, *units: Unit):
        if not units:
            raise ValueError(f"no {kind} registered")
        self.kind = kind
        self.units = {u.name: u for u in units}
        if len(self.units) != len(units):
            raise ValueError(f"two {kind}s share a name: {[u.name for u in units]}")

    @property
    def default(self) -> Unit:
        return next(iter(self.units.values()))

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.units)

    def __iter__(self):
        return iter(self.units.values())

    def __getitem__(self, name: str | None) -> Unit:
        """The unit called ``name`` (None: the default); ValueError naming the known ones."""
        if name is None:
            return self.default
        if name not in self.units:
            raise ValueError(f"{self.kind} must be one of {', '.join(self.units)}, got {name!r}")
        return self.units[name]
