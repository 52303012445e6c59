"""Declared accuracy thresholds, checked: `evalkit check THRESHOLDS.toml` and the test suite read
the same table (evalkit/thresholds.toml is the toolkit's own).

A case is one run of `evalkit.study` (its ``run`` parameters over `RUN_DEFAULTS`, its ``measure``
over the study's) and one metric column of the run's row, with:

- ``kind`` "max" (the value must not exceed ``threshold``), "min" (must not fall below it), or
  "falls": ``sweep`` names one parameter and its values, and the metric must not rise from one
  value to the next by more than a factor (1 + ``tolerance``): monotone within noise;
- ``why`` (why this number) and ``calibration`` (what was measured, over which seeds, and the
  margin), which the table and the report print beside the result.

On failure the case's folder keeps the test image, the reference and the error maps (EXR and PNG),
so a person can look.
"""

from __future__ import annotations

import os
import shutil
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evalkit.errors import InputError
from evalkit.study import MEASURE_DEFAULTS, RUN_DEFAULTS, Study, check_run, prepare, read_toml, run_case

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


@dataclass
class Outcome:
    case: Case
    passed: bool
    values: list[float]
    message: str
    seconds: float
    folder: Path
    rows: list[dict] = field(default_factory=list)


def load_thresholds(path: str | os.PathLike = DEFAULT_THRESHOLDS) -> list[Case]:
    path = Path(path)
    spec = read_toml(path, "thresholds")
    cases = []
    for i, c in enumerate(spec.get("case", [])):
        where = f"{path}: case {i + 1} ({c.get('name', 'unnamed')})"
        unknown = set(c) - CASE_KEYS
        if unknown:
            raise InputError(where, f"unknown key(s) {', '.join(sorted(unknown))}")
        missing = {"name", "metric", "kind", "why", "calibration"} - set(c)
        if missing:
            raise InputError(where, f"missing {', '.join(sorted(missing))}")
        if c["kind"] not in KINDS:
            raise InputError(where, f"kind '{c['kind']}' is not one of {', '.join(KINDS)}")
        if c["kind"] == "falls":
            if not isinstance(c.get("sweep"), dict) or len(c["sweep"]) != 1 or "tolerance" not in c:
                raise InputError(where, "a 'falls' case needs tolerance and a sweep of one parameter, e.g. sweep = {directions = [8, 32]}")
        elif "threshold" not in c:
            raise InputError(where, "needs a threshold")
        base = {**RUN_DEFAULTS, **c.get("run", {})}
        sweep = next(iter(c["sweep"])) if c["kind"] == "falls" else None
        runs = [{**base, sweep: v} for v in c["sweep"][sweep]] if sweep else [base]
        for run in runs:
            check_run(run, where)
        measure = {**MEASURE_DEFAULTS, **c.get("measure", {})}
        if set(measure) - set(MEASURE_DEFAULTS):
            raise InputError(where, f"[measure]: unknown key(s) {', '.join(sorted(set(measure) - set(MEASURE_DEFAULTS)))}")
        cases.append(Case(c["name"], c["metric"], c["kind"], c.get("threshold"), c.get("tolerance"), c["why"],
                          c["calibration"], runs, measure, sweep))
    if not cases:
        raise InputError(str(path), "no [[case]] tables")
    return cases


def evaluate(case: Case, out: str | os.PathLike) -> Outcome:
    """Run a case and compare it with its threshold; on failure, keep what a person needs to look."""
    folder = Path(out) / case.name
    folder.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    prepare(Study(case.name, None, case.name, "", "", case.runs, case.measure), folder, progress=lambda line: None)
    rows = [run_case(run, case.measure, str(folder)) for run in case.runs]
    seconds = time.perf_counter() - start
    bad = [r for r in rows if r["status"] != "ok"]
    if bad:
        return Outcome(case, False, [], f"run failed: {bad[0]['status']}", seconds, folder, rows)
    if any(case.metric not in r or r[case.metric] is None for r in rows):
        return Outcome(case, False, [], f"the runs have no '{case.metric}' column", seconds, folder, rows)
    values = [float(r[case.metric]) for r in rows]
    if case.kind == "max":
        passed, message = values[0] <= case.threshold, f"{case.metric} {values[0]:.6g} <= {case.threshold:g}"
    elif case.kind == "min":
        passed, message = values[0] >= case.threshold, f"{case.metric} {values[0]:.6g} >= {case.threshold:g}"
    else:
        passed = all(b <= a * (1 + case.tolerance) for a, b in zip(values, values[1:]))
        sweep_values = [r[case.sweep] for r in rows]
        message = (f"{case.metric} over {case.sweep} = {sweep_values}: {', '.join(f'{v:.4g}' for v in values)} "
                   f"(each at most {1 + case.tolerance:g} x the one before)")
    if not passed:
        message = "FAILED: " + message
        _keep_for_inspection(rows, folder)
    return Outcome(case, passed, values, message, seconds, folder, rows)


def _keep_for_inspection(rows: list[dict], folder: Path) -> None:
    """Beside each run's test images: the reference and the error maps as EXR and PNG."""
    from evalkit.exr import write_exr
    from evalkit.report import error_map_png
    from references.mitsuba import load_reference

    for row in rows:
        run = folder / "runs" / row["run_id"]
        if not row.get("reference"):
            continue
        ref = load_reference(row["reference"])
        for exr in run.glob("*.exr"):
            image = exr.stem
            if image in ref.images:
                shutil.copy2(ref.path / ref.manifest["files"][image], run / f"{image}_reference.exr")
        for path in run.glob("*_map.npy"):
            values = np.load(path)
            write_exr(path.with_suffix(".exr"), np.repeat(values[..., None], 3, axis=2), {"map": path.stem})
            error_map_png(values, path.with_suffix(".png"))


def junit_xml(outcomes: list[Outcome], path: str | os.PathLike) -> None:
    suite = ET.Element("testsuite", name="evalkit-check", tests=str(len(outcomes)),
                       failures=str(sum(not o.passed for o in outcomes)), time=f"{sum(o.seconds for o in outcomes):.3f}")
    for o in outcomes:
        case = ET.SubElement(suite, "testcase", classname="evalkit.check", name=o.case.name, time=f"{o.seconds:.3f}")
        if not o.passed:
            failure = ET.SubElement(case, "failure", message=o.message)
            failure.text = f"{o.message}\nwhy: {o.case.why}\ncalibration: {o.case.calibration}\nlook at: {o.folder}"
        ET.SubElement(case, "system-out").text = o.message
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    ET.ElementTree(suite).write(path, encoding="utf-8", xml_declaration=True)


def calibrate(case: Case, seeds: list[int], out: str | os.PathLike) -> dict:
    """The case's value over ``seeds`` (for a 'falls' case: the largest step ratio), to set or
    review its threshold: mean, standard deviation, min and max."""
    values = []
    for seed in seeds:
        seeded = Case(**{**case.__dict__, "runs": [{**r, "seed": seed} for r in case.runs], "name": f"{case.name}-seed{seed}"})
        o = evaluate(seeded, out)
        if not o.values:
            raise InputError(case.name, f"calibration run failed: {o.message}")
        values.append(max(b / a for a, b in zip(o.values, o.values[1:])) if case.kind == "falls" else o.values[0])
    v = np.array(values)
    return {"case": case.name, "seeds": seeds, "values": values, "mean": float(v.mean()),
            "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0, "min": float(v.min()), "max": float(v.max())}
