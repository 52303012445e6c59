"""Measured results as data: a benchmark's JSON report saved with the command and the versions
that made it (``--record PATH``), which the documentation's results pages are generated from
(evalkit/results_docs.py). A number in the docs comes from such a file, never typed by hand."""

from __future__ import annotations

import datetime
import json
import os
import shlex
import sys
from pathlib import Path

from evalkit.core.atomic import write_text
from evalkit.study.run import versions


def write_record(path: str | os.PathLike, report: dict, command: str | None = None) -> Path:
    """``report`` with ``record`` (the command line, the UTC date and the package versions) into
    ``path`` as indented JSON; returns the path. ``command``: by default this process's, a script
    run by Python."""
    if command is None:
        script = os.path.relpath(sys.argv[0]) if os.path.exists(sys.argv[0]) else sys.argv[0]
        command = "python " + shlex.join([script, *sys.argv[1:]])
    record = {
        "command": command,
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d"),
        "versions": versions(),
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, json.dumps({"record": record, **report}, indent=1) + "\n")  # whole or not at all
    return path


def study_record(study, rows: list[dict], out: str | os.PathLike) -> dict:
    """A study's results as a report for `write_record`: its name, title, description and what
    was reduced, the run parameters that vary, every row's scalar values, its plots' specifications
    (the results page draws them), the columns its report shows when the study names them
    (``[report] columns``), and the hole model's fits when its report made them (``hole_model.json``
    in ``out``)."""
    keys = dict.fromkeys(k for run in study.runs for k in run)
    varying = [k for k in keys if len({repr(run.get(k)) for run in study.runs}) > 1]
    scalar = (str, int, float, bool, type(None))
    report = {
        "study": study.name,
        "title": study.title,
        "description": study.description,
        "reduced": study.reduced,
        "varying": varying,
        "rows": [{k: v for k, v in row.items() if isinstance(v, scalar)} for row in rows],
        "plots": study.plots,
    }
    if study.report.get("columns"):
        report["columns"] = study.report["columns"]
    fits = Path(out) / "hole_model.json"
    if fits.is_file():
        report["hole_model"] = json.loads(fits.read_text())
    return report


def read_record(path: str | os.PathLike) -> dict:
    """A saved report; refuses one without its command and versions."""
    data = json.loads(Path(path).read_text())
    if not {"command", "versions"} <= set(data.get("record", {})):
        raise ValueError(f"{path}: not a results record (no record.command and record.versions)")
    return data
