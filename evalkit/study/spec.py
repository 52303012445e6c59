"""The study file: a declarative grid of runs, and the checks that refuse a bad one.

A study file (TOML; studies/*.toml are examples)::

    name = "directions"
    title = "Error against K and R"
    reduced = "what was made smaller than the paper, and why"   # stated in the report
    [defaults]              # every run's parameters, below the grid's
    scene = "cornell-box"
    bounces = 1
    [[grid]]                # each [[grid]] is a cartesian product; the runs of all grids are joined
    method = ["perfect", "imperfect"]
    directions = [8, 16, 32]
    seed = [0, 1]
    [measure]
    bundles = true          # bundle metrics against Embree exact bundles (perfect, imperfect)
    render = true           # render images (timings); false: bundle metrics only
    images = ["indirect"]   # image metrics of these images against the Mitsuba reference
    reference_spp = 4096
    reference_store = "out/references"  # where references not in the committed store are rendered
                                        # (default: the study folder's references/)
    [hole_model]            # fit the coverage model to the imperfect rows (optional)
    node_cost = 0.01
    [[plot]]                # plots in the report
    x = "splat_scale"
    y = ["hole_rate", "redundant_rate"]
    group = "points"
    log = "xy"
    [[plot]]                # error against time
    x = "wall_s"
    y = "indirect_relmse"
    pareto = true           # the Pareto front, and each setting against Mitsuba at matched x
    versus = "strategy"     # each strategy's Pareto front against the others' at matched x

Methods: the registered bundle methods (`gpu_impl.registry.METHODS`; rendered with
`gpu_impl.renderer.Renderer` when images are measured) and ``mitsuba`` (Mitsuba 3 at ``spp``,
timed). A run sets the scene, the method and any `RenderSettings` field or setting of its units
(``points`` of imperfect bundles, say); what it leaves out takes the renderer's own default
(`RUN_DEFAULTS`, and each unit's). A row holds every setting that applies to its run and none that
does not: a unit's setting in ``[defaults]`` goes to the runs whose units have it, and one a grid
gives a run whose units do not have it is an error. ``width`` and ``height`` left out are the
scene camera's.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path

from evalkit.core.errors import InputError
from evalkit.core.settings import RenderSettings
from evalkit.metrics.images import METRICS
from gpu_impl.registry import METHODS, all_units, resolve

# Methods a study runs that are not bundle methods: the Mitsuba reference renderer, timed.
REFERENCE_METHODS = ("mitsuba",)
# The parameters every run has: the scene and every RenderSettings field, with the renderer's
# defaults (Mitsuba runs use scene, bounces, spp, width, height and seed of them).
RUN_DEFAULTS = {"scene": "cornell-box", **{f.name: f.default for f in fields(RenderSettings) if f.name != "options"}}
# ... and the settings of the registered units, which a run has when its units do.
UNIT_SETTINGS = tuple(dict.fromkeys(name for unit in all_units() for name in unit.option_names()))
PARAMETERS = (*RUN_DEFAULTS, *UNIT_SETTINGS)
MEASURE_DEFAULTS = {
    "bundles": False,
    "render": True,
    "images": ["indirect"],
    "metrics": list(METRICS),
    "reference_spp": 4096,
    "reference_seed": 0,
    "eye_vertices": 4096,
    "reference_store": "",
}
TOP_KEYS = {"name", "title", "description", "reduced", "defaults", "grid", "measure", "hole_model", "plot", "report"}
TEXT_KEYS = ("name", "title", "description", "reduced")


@dataclass
class Study:
    name: str
    path: Path | None
    title: str
    description: str
    reduced: str
    runs: list[dict]
    measure: dict
    hole_model: dict | None = None
    plots: list[dict] = field(default_factory=list)
    report: dict = field(default_factory=dict)


def read_toml(path: Path, what: str) -> dict:
    """A TOML file's tables; a missing or malformed file is an `InputError` naming it."""
    if not path.is_file():
        raise InputError(str(path), f"no such {what} file")
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise InputError(str(path), f"malformed TOML: {e}") from None


def load_study(path: str | os.PathLike) -> Study:
    """Parse and check a study file; every problem is an `InputError` naming the file."""
    return study_from_dict(read_toml(Path(path), "study"), Path(path))


def study_from_dict(spec: dict, path: Path | None = None) -> Study:
    where = str(path or "study")
    unknown = set(spec) - TOP_KEYS
    if unknown:
        raise InputError(where, f"unknown key(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(TOP_KEYS))}")
    for key in TEXT_KEYS:
        if key in spec and not isinstance(spec[key], str):
            raise InputError(where, f"{key} = {spec[key]!r} must be a string")
    defaults = _table(spec, "defaults", where)
    grids = spec.get("grid", [{}])
    if isinstance(grids, dict):
        grids = [grids]
    if not isinstance(grids, list) or not all(isinstance(grid, dict) for grid in grids):
        raise InputError(where, f"grid = {grids!r} must be a table or an array of tables ([[grid]])")
    if not grids:
        raise InputError(where, "grid = [] declares no runs")
    runs, seen = [], set()
    for grid in grids:
        axes = {k: v if isinstance(v, list) else [v] for k, v in grid.items()}
        for values in itertools.product(*axes.values()):
            run = make_run(dict(zip(axes, values)), defaults, where)
            key = run_id(run)
            if key not in seen:
                seen.add(key)
                runs.append(run)
    measure = measure_settings(_table(spec, "measure", where), where)
    plots = spec.get("plot", [])
    if not isinstance(plots, list) or not all(isinstance(p, dict) for p in plots):
        raise InputError(where, f"plot = {plots!r} must be an array of tables ([[plot]])")
    for p in plots:
        if "x" not in p or "y" not in p:
            raise InputError(where, f"a [[plot]] needs x and y, got {sorted(p)}")
        ys = p["y"] if isinstance(p["y"], list) else [p["y"]]
        if not isinstance(p["x"], str) or not ys or not all(isinstance(y, str) for y in ys):
            raise InputError(where, f"a [[plot]]'s x names a column and y one or more, got {p['x']!r} and {p['y']!r}")
        if "versus" in p and p["versus"] not in PARAMETERS:
            raise InputError(where, f"a [[plot]]'s versus names a run parameter, got {p['versus']!r}")
    name = spec.get("name") or (path.stem if path else "study")
    return Study(
        name,
        path,
        spec.get("title", name),
        spec.get("description", ""),
        spec.get("reduced", ""),
        runs,
        measure,
        _table(spec, "hole_model", where) if "hole_model" in spec else None,
        plots,
        _table(spec, "report", where),
    )


def measure_settings(table: dict, where: str) -> dict:
    """A [measure] table over `MEASURE_DEFAULTS`, checked."""
    measure = {**MEASURE_DEFAULTS, **table}
    if set(measure) - set(MEASURE_DEFAULTS):
        unknown = ", ".join(sorted(set(measure) - set(MEASURE_DEFAULTS)))
        raise InputError(where, f"[measure]: unknown key(s) {unknown}; known: {', '.join(MEASURE_DEFAULTS)}")
    for key, default in MEASURE_DEFAULTS.items():  # each of the default's type (a bool is no number)
        value = measure[key]
        if isinstance(default, list):
            fits, kind = isinstance(value, list) and all(isinstance(v, str) for v in value), "an array of names"
        else:
            fits, kind = (
                type(value) is type(default),
                {bool: "true or false", int: "a whole number"}.get(type(default), "a string"),
            )
        if not fits:
            raise InputError(where, f"[measure] {key} = {value!r} must be {kind}")
    bad = set(measure["metrics"]) - set(METRICS)
    if bad:
        raise InputError(where, f"[measure] metrics: unknown {', '.join(sorted(bad))}; known: {', '.join(METRICS)}")
    bad = set(measure["images"]) - {"direct", "indirect", "total"}
    if bad:
        raise InputError(where, f"[measure] images: unknown {', '.join(sorted(bad))}; known: direct, indirect, total")
    return measure


def _table(spec: dict, key: str, where: str) -> dict:
    value = spec.get(key, {})
    if not isinstance(value, dict):
        raise InputError(where, f"[{key}] must be a table")
    return value


def make_run(given: dict, defaults: dict, where: str) -> dict:
    """A run's parameters: ``given`` over ``defaults`` (a study's [defaults]) over `RUN_DEFAULTS`,
    checked, with every setting of its units filled in and none that does not apply to them. A
    unit's setting from ``defaults`` that does not apply is left out; one in ``given`` is an
    error. Every problem is an `InputError` naming ``where`` and the parameter."""
    run = {**RUN_DEFAULTS, **defaults, **given}
    unknown = [k for k in run if k not in PARAMETERS]
    if unknown:
        known = ", ".join(PARAMETERS)
        raise InputError(where, f"unknown run parameter(s) {', '.join(sorted(unknown))}; known: {known}")
    if not isinstance(run["scene"], str):
        raise InputError(where, f"scene = {run['scene']!r} is not a scene name or path")
    options = [k for k in run if k not in RUN_DEFAULTS]
    try:
        if run["method"] in REFERENCE_METHODS:
            explicit = [k for k in options if k in given]
            if explicit:
                raise ValueError(f"{explicit[0]} is a setting of bundle rendering, not of {run['method']} runs")
            common = {k: run[k] for k in RUN_DEFAULTS}
            render_settings({**common, "method": None}).validate()
            return common
        if run["method"] is not None and run["method"] not in METHODS.names:
            known = ", ".join((*METHODS.names, *REFERENCE_METHODS))
            raise ValueError(f"method '{run['method']}' is not one of {known}")
        applicable = resolve(render_settings({k: run[k] for k in RUN_DEFAULTS})).units.values()
        keep = {name for unit in applicable for name in unit.option_names()} | set(given)
        resolved = resolve(render_settings({k: v for k, v in run.items() if k in RUN_DEFAULTS or k in keep}))
    except ValueError as e:
        raise InputError(where, str(e)) from None
    return {"scene": run["scene"], **resolved.params()}


def parameters(row: dict) -> dict:
    """The run parameters of a study row (the rest are its metrics, timings and provenance)."""
    return {k: row[k] for k in PARAMETERS if k in row}


def render_settings(run: dict) -> RenderSettings:
    """The run's `RenderSettings` (every parameter but the scene; a unit's settings as options)."""
    return RenderSettings(**{k: v for k, v in run.items() if k != "scene"})


def run_id(run: dict) -> str:
    """A stable id of a run's parameters (the resume key)."""
    return hashlib.sha256(json.dumps(run, sort_keys=True).encode()).hexdigest()[:12]
