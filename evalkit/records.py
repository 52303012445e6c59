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

from evalkit.study.run import versions


def write_record(path: str | os.PathLike, report: dict, argv: list[str] | None = None) -> Path:
    """``report`` with ``record`` (the command line, the UTC date and the package versions) into
    ``path`` as indented JSON; returns the path."""
    argv = sys.argv if argv is None else argv
    script = os.path.relpath(argv[0]) if os.path.exists(argv[0]) else argv[0]
    record = {
        "command": "python " + shlex.join([script, *argv[1:]]),
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d"),
        "versions": versions(),
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"record": record, **report}, indent=1) + "\n")
    return path


def read_record(path: str | os.PathLike) -> dict:
    """A saved report; refuses one without its command and versions."""
    data = json.loads(Path(path).read_text())
    if not {"command", "versions"} <= set(data.get("record", {})):
        raise ValueError(f"{path}: not a results record (no record.command and record.versions)")
    return data
