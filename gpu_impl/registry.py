"""Every registered unit: the bundle methods, light visibilities and path strategies the toolkit has.

Adding one is its module (with its shaders, tests and docs) and its entry here; the command line,
study validation, the report, the render's provenance and the tuner all read these registries.
The first unit of each kind is the default.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from evalkit.core.settings import RenderSettings, check_value, declared
from gpu_impl.methods import imperfect, perfect
from gpu_impl.strategies import bidirectional, eye
from gpu_impl.units import Registry, Unit
from gpu_impl.visibility import exact
from gpu_impl.visibility import imperfect as imperfect_shadow_maps

METHODS = Registry("bundle method", perfect.METHOD, imperfect.METHOD)
LIGHT_VISIBILITIES = Registry("light visibility", exact.VISIBILITY, imperfect_shadow_maps.VISIBILITY)
STRATEGIES = Registry("path strategy", eye.STRATEGY, bidirectional.STRATEGY)

# The RenderSettings field that names the unit of each kind.
KINDS = {"method": METHODS, "strategy": STRATEGIES, "light_visibility": LIGHT_VISIBILITIES}


def all_units() -> list[Unit]:
    return [unit for registry in KINDS.values() for unit in registry]


def owners(option: str) -> list[Unit]:
    """The units that declare the setting ``option``."""
    return [unit for unit in all_units() if option in unit.option_names()]


@dataclass(frozen=True)
class Resolved:
    """`RenderSettings` checked against the units it names: ``settings`` with every unit named and
    only those units' options, ``units`` and their own ``unit_settings`` by RenderSettings field
    (method, strategy, light_visibility)."""

    settings: RenderSettings
    units: dict
    unit_settings: dict

    @property
    def method(self):
        return self.units["method"]

    def params(self) -> dict:
        """Every setting of the render, the units' with their defaults filled in: its provenance."""
        flat = {k: v for k, v in self.settings.flat().items() if k not in dict(self.settings.options)}
        for field, unit in self.units.items():
            own = self.unit_settings[field]
            flat.update({f.name: getattr(own, f.name) for f in declared(unit.settings)})
        return flat

    def describe(self) -> str:
        """'imperfect N=16384 s=1.8' and the like: the method and its settings' symbols."""
        return self.method.describe(self.unit_settings["method"])


def resolve(settings: RenderSettings, inapplicable: str = "error") -> Resolved:
    """``settings`` checked: every field in range, every unit registered, every option a setting of
    one of the chosen units and in its range. An option of another unit raises ValueError naming
    both (``inapplicable="drop"``: it is left out instead, as a study's defaults or a preset are
    where they do not apply). Raises ValueError with one line naming the setting."""
    settings.validate()
    for name, value in settings.options:  # a value is checked against its declaration first
        for unit in owners(name):
            check_value(next(f for f in declared(unit.settings) if f.name == name), value)
    units = {field: registry[getattr(settings, field)] for field, registry in KINDS.items()}
    known = {name for unit in units.values() for name in unit.option_names()}
    foreign = [name for name, _ in settings.options if name not in known]
    if foreign and inapplicable == "error":
        name = foreign[0]
        chosen = ", ".join(f"{u.name} {u.kind}" for u in units.values())
        others = owners(name)
        if others:
            whose = " and ".join(f"the {u.name} {u.kind}" for u in others)
            raise ValueError(f"{name} is a setting of {whose}, not of this render's units ({chosen})")
        every = sorted({n for u in all_units() for n in u.option_names()})
        raise ValueError(f"unknown setting {name!r}; the units' settings are {', '.join(every)}")
    options = tuple((k, v) for k, v in settings.options if k in known)
    names = {field: unit.name for field, unit in units.items()}
    settings = replace(settings, **names, options=options)
    return Resolved(settings, units, {field: unit.settings_of(settings) for field, unit in units.items()})


def settings_symbols() -> dict[str, str]:
    """Each setting's symbol in short descriptions (directions K, resolution R, points N, ...)."""
    fields = [*declared(RenderSettings), *(f for unit in all_units() for f in declared(unit.settings))]
    return {f.name: f.metadata["symbol"] for f in fields if f.metadata["symbol"]}
