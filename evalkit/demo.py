"""`evalkit demo`, the main job: the study in demo.toml (perfect and imperfect bundles on
cornell-box against Mitsuba and Embree, every metric, the report) and the summary table it prints."""

from __future__ import annotations

import os
from pathlib import Path

from evalkit.study.executors import run_study
from evalkit.study.spec import load_study

DEMO_STUDY = Path(__file__).with_name("demo.toml")
# The summary: a column of the results table and its format, per column.
SUMMARY = [
    ("method", "{}"),
    ("indirect_relmse", "{:.4g}"),
    ("indirect_flip", "{:.4g}"),
    ("total_relmse", "{:.4g}"),
    ("total_delta_e2000", "{:.3g}"),
    ("hole_rate", "{:.3%}"),
    ("redundant_rate", "{:.1%}"),
    ("next_hit_error_rate", "{:.2%}"),
    ("wall_s", "{:.1f}"),
]


def run_demo(out: str | os.PathLike, command: str | None = None) -> list[dict]:
    """Run (or resume) the demo study into ``out``; returns its rows."""
    return run_study(load_study(DEMO_STUDY), out, command=command)


def summary_lines(rows: list[dict]) -> list[str]:
    """The table `evalkit demo` prints: one header line, then one line per run."""
    lines = [" ".join(f"{name:>20}" for name, _ in SUMMARY)]
    for r in rows:
        lines.append(
            " ".join(f"{fmt.format(r[name]) if r.get(name) is not None else '-':>20}" for name, fmt in SUMMARY)
        )
    return lines
