"""The settings of a render, the one settings type of the whole project (the command line, studies,
the tuner, the thresholds and the GPU side), and the way every setting is declared.

A setting is a dataclass field made by `setting`: its default, a line of help, and the values it
may take. `RenderSettings` declares the settings every render has; each registered unit (a bundle
method, a light visibility, a path strategy: `gpu_impl.units`) declares its own in a frozen
dataclass of the same kind, so that one `check_settings` validates both and the command line
makes its flags from both. `RenderSettings` names the units it renders with (None: the registry's
default) and carries the settings given for them as ``options``; the registry
(`gpu_impl.registry.resolve`) checks those against the units and fills in their defaults.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, dataclass, field, fields
from typing import Any

# The images a render and a reference make: Mitsuba's path integrator at max_depth 2 (direct), at
# B + 2 (total), and their difference (indirect).
IMAGES = ("direct", "indirect", "total")
# Nodes of one bundle line closer than this (times the bundle frame's radius) are one surface: the
# depth tolerance of the bundle metrics and of the imperfect bundles' merge, about a hundred
# float32 ulps of a depth.
DEPTH_TOLERANCE = 1e-4
# The poster used a 1 GB node buffer; the default leaves room for the largest settings it used.
DEFAULT_NODE_BUDGET = 2 << 30
# The poster's configuration (docs/ARCHITECTURE.md); --bounces picks 1 or 3.
PRESETS = {
    "paper": {"width": 1920, "height": 1024, "supersampling": 2, "resolution": 128, "directions": 256, "points": 16384},
}


def setting(
    default: Any,
    help: str,
    *,
    minimum: float | None = None,
    maximum: float | None = None,
    positive: bool = False,
    choices: tuple | None = None,
    finite: bool = True,
    symbol: str | None = None,
    unit: str = "",
) -> Any:
    """A declared setting: a dataclass field with its default and, for `check_settings` and the
    command line, its ``help``, the least and largest values it may take (``minimum``,
    ``maximum``, inclusive; ``positive``: above 0), its ``choices``, whether it must be finite, its
    ``symbol`` in short descriptions (K, R, N, s) and the ``unit`` its messages give."""
    metadata = {"help": help, "minimum": minimum, "maximum": maximum, "positive": positive, "choices": choices}
    return field(default=default, metadata={**metadata, "finite": finite, "symbol": symbol, "unit": unit})


def declared(settings_type) -> list:
    """The fields of a settings dataclass that `setting` declared."""
    return [f for f in fields(settings_type) if "help" in f.metadata]


def check_value(f, value: Any) -> None:
    """Raises ValueError naming the setting when ``value`` is of the wrong type or out of range."""
    kind, m = f.type, f.metadata  # the annotation as text: 'int', 'float | None', 'str', 'bool' ...
    unit = f" {m['unit']}" if m["unit"] else ""
    if value is None:
        if kind.endswith("| None"):
            return
        raise ValueError(f"{f.name} must be set")
    if kind.startswith("bool"):
        if not isinstance(value, bool):
            raise ValueError(f"{f.name} = {value!r} must be true or false")
        return
    if kind.startswith("str"):
        if not isinstance(value, str):
            raise ValueError(f"{f.name} = {value!r} must be a string")
    elif isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{f.name} = {value!r} is not a finite number")
    elif kind.startswith("int") and not isinstance(value, int):
        raise ValueError(f"{f.name} = {value!r} must be a whole number")
    elif m["positive"] and not (value > 0 and math.isfinite(value)):
        raise ValueError(f"{f.name} must be positive and finite, got {value}")
    elif kind.startswith("float") and m["minimum"] == 0 and not (value >= 0 and math.isfinite(value)):
        raise ValueError(f"{f.name} must be non-negative and finite{unit}, got {value}")
    elif m["finite"] and not math.isfinite(value):
        raise ValueError(f"{f.name} must be finite, got {value}")
    elif m["minimum"] is not None and value < m["minimum"]:
        raise ValueError(f"{f.name} must be at least {m['minimum']}{unit}, got {value}")
    elif m["maximum"] is not None and value > m["maximum"]:
        raise ValueError(f"{f.name} must be at most {m['maximum']}{unit}, got {value}")
    if m["choices"] is not None and value not in m["choices"]:
        raise ValueError(f"{f.name} must be one of {', '.join(map(str, m['choices']))}, got {value!r}")


def check_settings(settings) -> None:
    """Raises ValueError naming the first declared setting of ``settings`` that is out of range."""
    for f in declared(type(settings)):
        check_value(f, getattr(settings, f.name))


@dataclass(frozen=True, init=False)
class RenderSettings:
    """Everything that changes a render.

    Construct it flat, as the command line and study files give it: ``RenderSettings(method=
    "imperfect", points=4096, frames=8)``. Names that are not fields below are settings of the
    chosen units (``points`` of imperfect bundles, say) and go to ``options``; `dataclasses.replace`
    works the same way. ``spp`` is eye paths per G-buffer sample per frame, so a pixel averages
    ``supersampling^2 * spp * frames`` paths. ``time_budget`` > 0 (seconds) ends the render
    before ``frames`` once the next frame would not fit in it (at least one frame). ``width`` and
    ``height`` default to the scene camera's. ``self_hit_bias`` is in bundle pixels
    (gpu_impl/shaders/paths/eye_paths.glsl); the shadow biases are in shadow-map texels
    (gpu_impl/shaders/include/lights.glsl).
    """

    method: str | None = setting(None, "the bundle method (default: the first registered)")
    strategy: str | None = setting(None, "how paths are made (default: the first registered)")
    light_visibility: str | None = setting(None, "how light vertices see the scene (default: the first registered)")
    bounces: int = setting(1, "indirect bounces on top of direct", minimum=0)
    directions: int = setting(256, "bundle directions per frame", minimum=1, symbol="K")
    resolution: int = setting(128, "R x R lines per bundle", minimum=1, symbol="R")
    width: int | None = setting(None, "image width (default: the scene camera's)", minimum=1)
    height: int | None = setting(None, "image height (default: the scene camera's)", minimum=1)
    supersampling: int = setting(1, "S x S G-buffer samples per pixel", minimum=1)
    spp: int = setting(1, "eye paths per G-buffer sample per frame", minimum=1, symbol="spp")
    coherent_paths: int = setting(
        1,
        "neighbouring G-buffer samples whose eye paths take the same random bundle each bounce: faster bounces, "
        "a noisier image mean (1: each its own)",
        minimum=1,
    )
    frames: int = setting(1, "frames to accumulate, each with new directions", minimum=1, symbol="F")
    time_budget: float = setting(
        0.0,
        "stop before the frames once the next frame would not fit in these seconds (0: no budget)",
        minimum=0,
        unit="seconds",
    )
    # The shaders hash it as a 32-bit word: a larger seed would repeat a smaller one's GPU samples.
    seed: int = setting(0, "the seed of every random choice", minimum=0, maximum=2**32 - 1)
    time: float = setting(0.0, "animated scenes: the time (s) of the first frame")
    time_step: float = setting(0.0, "animated scenes: seconds between frames (0: every frame at time, accumulating)")
    self_hit_bias: float = setting(0.05, "nodes within this many bundle pixels beyond a vertex are skipped", minimum=0)
    rotate_directions: bool = setting(
        True, "new directions every frame (false: frame 0's; a static scene builds its bundles once)"
    )
    stop_early: bool = setting(True, "skip the bounce passes left once every path has ended")
    shadow_map_size: int = setting(
        1024, "texels per side of the point, spot and directional lights' maps", minimum=8, unit="texels"
    )
    shadow_filter: int = setting(1, "PCF kernel of F x F bilinear taps", minimum=1)
    shadow_bias: float = setting(1.0, "constant shadow depth bias, in texels", minimum=0)
    shadow_slope_bias: float = setting(2.0, "slope-scaled shadow depth bias, in texels", minimum=0)
    node_budget: int = setting(
        DEFAULT_NODE_BUDGET,
        "the most memory for nodes, what they are built from and their precomputed light; never more than "
        "half of what the machine (llvmpipe) or the GPU has free",
        minimum=1,
        unit="byte",
    )
    # The chosen units' own settings as given, (name, value) pairs sorted by name.
    options: tuple = ()

    def __init__(self, **values: Any):
        names = {f.name for f in fields(self) if f.name != "options"}
        options = dict(values.pop("options", ()))
        for f in fields(self):
            if f.name != "options":
                object.__setattr__(self, f.name, f.default if f.default is not MISSING else None)
        for name, value in values.items():
            if name in names:
                object.__setattr__(self, name, value)
            else:
                options[name] = value
        object.__setattr__(self, "options", tuple(sorted(options.items())))

    def option(self, name: str, default: Any = None) -> Any:
        """The unit setting ``name`` as given, or ``default``."""
        return dict(self.options).get(name, default)

    def flat(self) -> dict:
        """Every field and every given option in one dict, as the constructor takes them."""
        return {**{f.name: getattr(self, f.name) for f in fields(self) if f.name != "options"}, **dict(self.options)}

    def validate(self) -> None:
        """Raises ValueError naming the first field out of range (the units' options are checked
        against the units by `gpu_impl.registry.resolve`)."""
        check_settings(self)
