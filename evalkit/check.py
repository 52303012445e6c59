"""`evalkit check`: run the declared accuracy cases (`evalkit.thresholds`) and compare each with
its threshold; a table, JUnit XML, and `calibrate` to set or review a threshold over seeds.

On failure the case's folder keeps the test image, the reference and the error maps (EXR and PNG),
so a person can look.
"""

from __future__ import annotations

import html
import os
import shutil
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evalkit.core.atomic import atomic_path, write_text
from evalkit.core.display import fields_html
from evalkit.core.errors import InputError
from evalkit.core.exr import write_exr
from evalkit.figures import error_map_png
from evalkit.pages import page
from evalkit.report import run_viewers
from evalkit.study.artefacts import prepare_artefacts
from evalkit.study.run import execute_run
from evalkit.thresholds import Case
from references.mitsuba import load_reference


@dataclass
class Outcome:
    case: Case
    passed: bool
    values: list[float]
    message: str
    seconds: float
    folder: Path
    rows: list[dict] = field(default_factory=list)


def evaluate(case: Case, out: str | os.PathLike) -> Outcome:
    """Run a case and compare it with its threshold; on failure, keep what a person needs to look."""
    folder = Path(out) / case.name
    folder.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    prepare_artefacts(case.runs, case.measure, folder, progress=lambda line: None)
    rows = [execute_run(run, case.measure, str(folder)) for run in case.runs]
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
        message = (
            f"{case.metric} over {case.sweep} = {sweep_values}: {', '.join(f'{v:.4g}' for v in values)} "
            f"(each at most {1 + case.tolerance:g} x the one before)"
        )
    if not passed:
        message = "FAILED: " + message
        _keep_for_inspection(case, rows, folder, message)
    return Outcome(case, passed, values, message, seconds, folder, rows)


def _keep_for_inspection(case: Case, rows: list[dict], folder: Path, message: str) -> None:
    """Beside each run's test images: the reference and the error maps as EXR and PNG, and
    report.html with them in the image viewer."""
    viewers = [
        part
        for row in rows
        if row.get("reference")
        for part in run_viewers(folder, row, case.measure["images"], f"{row['method']}, seed {row['seed']}")
    ]
    parts = [f"<h1>evalkit check: {html.escape(case.name)}</h1><p>{html.escape(message)}</p>"]
    parts.append(f"<p>why: {html.escape(case.why)}<br>calibration: {html.escape(case.calibration)}</p>")
    write_text(folder / "report.html", page(f"evalkit check: {case.name}", parts + viewers))
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
    suite = ET.Element(
        "testsuite",
        name="evalkit-check",
        tests=str(len(outcomes)),
        failures=str(sum(not o.passed for o in outcomes)),
        time=f"{sum(o.seconds for o in outcomes):.3f}",
    )
    for o in outcomes:
        case = ET.SubElement(suite, "testcase", classname="evalkit.check", name=o.case.name, time=f"{o.seconds:.3f}")
        if not o.passed:
            failure = ET.SubElement(case, "failure", message=o.message)
            look = o.folder / "report.html"
            failure.text = f"{o.message}\nwhy: {o.case.why}\ncalibration: {o.case.calibration}\nlook at: {look}"
        ET.SubElement(case, "system-out").text = o.message
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        ET.ElementTree(suite).write(tmp, encoding="utf-8", xml_declaration=True)


class Spread(dict):
    """`calibrate`'s figures, which a notebook shows as a table."""

    def _repr_html_(self) -> str:
        figures = {k: self[k] for k in ("mean", "std", "min", "max")}
        per_seed = {f"seed {s}": v for s, v in zip(self["seeds"], self["values"])}
        return fields_html(f"{self['case']} over {len(self['seeds'])} seeds", {**figures, **per_seed})


def calibrate(case: Case, seeds: list[int], out: str | os.PathLike) -> Spread:
    """The case's value over ``seeds`` (for a 'falls' case: the largest step ratio), to set or
    review its threshold: mean, standard deviation, min and max."""
    values = []
    for seed in seeds:
        seeded = Case(
            **{**case.__dict__, "runs": [{**r, "seed": seed} for r in case.runs], "name": f"{case.name}-seed{seed}"}
        )
        o = evaluate(seeded, out)
        if not o.values:
            raise InputError(case.name, f"calibration run failed: {o.message}")
        values.append(max(b / a for a, b in zip(o.values, o.values[1:])) if case.kind == "falls" else o.values[0])
    v = np.array(values)
    return Spread(
        {
            "case": case.name,
            "seeds": seeds,
            "values": values,
            "mean": float(v.mean()),
            "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
            "min": float(v.min()),
            "max": float(v.max()),
        }
    )
