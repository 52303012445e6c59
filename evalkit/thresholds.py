"""Declared accuracy thresholds: the table (TOML) that `evalkit check`, the test suite and study
reports read. evalkit/thresholds.toml is the toolkit's own.

A case is one run of a study (its ``run`` parameters as a study's grid gives them, its ``measure`` over the
study's) and one metric column of the run's row, with:

- ``kind`` "max" (the value must not exceed ``threshold``), "min" (must not fall below it), or
  "falls": ``sweep`` names one parameter and its values, and the metric must not rise from one
  value to the next by more than a factor (1 + ``tolerance``): monotone within noise;
- ``why`` (why this number) and ``calibration`` (what was measured, over which seeds, and the
  margin), which the table and the report print beside the result.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

from evalkit.core.errors import InputError
from evalkit.study.spec import make_run, measure_settings, read_toml

DEFAULT_THRESHOLDS = Path(__file__).with_name("thresholds.toml")
KINDS = ("max", "min", "falls")
CASE_KEYS = {"name", "metric", "kind", "threshold", "tolerance", "why", "calibration", "run", "measure", "sweep"}


@dataclass
class Case:
    name: str
    metric: str
    kind: str
    threshold: float | None
    tolerance: float | None
    why: str
    calibration: str
    runs: list[dict]
    measure: dict
    sweep: str | None = None


def load_thresholds(path: str | os.PathLike = DEFAULT_THRESHOLDS) -> list[Case]:
    path = Path(path)
    spec = read_toml(path, "thresholds")
    cases = []
    tables = spec.get("case", [])
    if not isinstance(tables, list) or not all(isinstance(c, dict) for c in tables):
        raise InputError(str(path), f"case = {tables!r} must be an array of tables ([[case]])")
    for i, c in enumerate(tables):
        where = f"{path}: case {i + 1} ({c.get('name', 'unnamed')})"
        unknown = set(c) - CASE_KEYS
        if unknown:
            raise InputError(
                where, f"unknown key(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(CASE_KEYS))}"
            )
        missing = {"name", "metric", "kind", "why", "calibration"} - set(c)
        if missing:
            raise InputError(where, f"missing {', '.join(sorted(missing))}")
        for key in ("name", "metric", "kind", "why", "calibration"):
            if not isinstance(c[key], str):
                raise InputError(where, f"{key} = {c[key]!r} must be a string")
        for key in ("run", "measure"):
            if not isinstance(c.get(key, {}), dict):
                raise InputError(where, f"{key} = {c[key]!r} must be a table")
        if c["kind"] not in KINDS:
            raise InputError(where, f"kind '{c['kind']}' is not one of {', '.join(KINDS)}")
        if c["kind"] == "falls":
            if not isinstance(c.get("sweep"), dict) or len(c["sweep"]) != 1 or "tolerance" not in c:
                raise InputError(
                    where,
                    "a 'falls' case needs tolerance and a sweep of one parameter, e.g. sweep = {directions = [8, 32]}",
                )
            if not isinstance(next(iter(c["sweep"].values())), list):
                raise InputError(where, f"sweep = {c['sweep']!r} must give its parameter an array of values")
        elif "threshold" not in c:
            raise InputError(where, "needs a threshold")
        limit = "tolerance" if c["kind"] == "falls" else "threshold"
        if isinstance(c[limit], bool) or not isinstance(c[limit], int | float) or not math.isfinite(c[limit]):
            raise InputError(where, f"{limit} = {c[limit]!r} must be a finite number")
        base = c.get("run", {})
        sweep = next(iter(c["sweep"])) if c["kind"] == "falls" else None
        given = [{**base, sweep: v} for v in c["sweep"][sweep]] if sweep else [base]
        runs = [make_run(run, {}, where) for run in given]
        measure = measure_settings(c.get("measure", {}), where)
        cases.append(
            Case(
                c["name"],
                c["metric"],
                c["kind"],
                c.get("threshold"),
                c.get("tolerance"),
                c["why"],
                c["calibration"],
                runs,
                measure,
                sweep,
            )
        )
    if not cases:
        raise InputError(str(path), "no [[case]] tables")
    return cases
