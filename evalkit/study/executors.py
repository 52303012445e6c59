"""Every run of a study: those not finished yet run here (one after another, in local processes,
or on a Dask cluster), each appends its row to ``results.jsonl`` as it finishes, and at the end come
``results.csv``, ``study.json`` and ``report.html``.

A second start skips the rows already there (resume) and retries failed ones. One study writes to
a folder at a time (`evalkit.core.lock`). A run killed mid-write leaves a torn last line: it is
dropped with a warning, and that run runs again.
"""

from __future__ import annotations

import csv
import json
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np
from tqdm import tqdm

from evalkit.core.atomic import atomic_path, remove_temporaries, write_text
from evalkit.core.errors import InputError
from evalkit.core.lock import folder_lock
from evalkit.pages import results_table_html
from evalkit.report import column_groups, metric_columns, varying, write_report
from evalkit.study.artefacts import prepare_artefacts
from evalkit.study.run import execute_run, versions
from evalkit.study.spec import Study, run_id


class StudyRows(list):
    """`run_study`'s rows (a list of dicts), which a notebook shows as the report's results table
    (settings, bundle metrics, image metrics and timings; a setting a run's method lacks left empty)."""

    def _repr_html_(self) -> str:
        ok = [r for r in self if r.get("status") == "ok"]
        columns = ["run_id", *varying(ok), *metric_columns(ok)]
        return f"<b>{len(ok)} of {len(self)} runs ok</b>" + results_table_html(ok, column_groups(columns))


def run_study(
    study: Study,
    out: str | os.PathLike,
    workers: int = 1,
    executor: str = "local",
    scheduler: str | None = None,
    progress=print,
    command: str | None = None,
    wait: bool = False,
) -> StudyRows:
    """Run every run not finished yet, append its row, then write results.csv and the report.
    Returns every row (finished earlier or now), in the study's order. Another study writing to
    ``out`` is an `InputError`, or with ``wait`` waited for."""
    with folder_lock(out, "study", wait=wait, progress=progress):
        return _run_study(study, Path(out), workers, executor, scheduler, progress, command)


def _run_study(study, out: Path, workers, executor, scheduler, progress, command) -> list[dict]:
    for folder in (out / "cache", out / "viewer"):  # the study's own; runs/<id> start empty
        if folder.is_dir():
            remove_temporaries(folder)
    done = {r["run_id"]: r for r in read_rows(out, progress) if r.get("status") == "ok"}
    todo = [r for r in study.runs if run_id(r) not in done]
    progress(
        f"{study.name}: {len(study.runs)} runs, {len(done)} finished before, {len(todo)} to run "
        f"({executor}, {workers} worker(s)) into {out}"
    )
    prepare_artefacts(study.runs, study.measure, out, progress)
    with open(out / "results.jsonl", "a") as log:
        for row in _execute(todo, study.measure, out, workers, executor, scheduler):
            log.write(json.dumps(row, default=_json_default) + "\n")
            log.flush()
            os.fsync(log.fileno())  # a finished run survives a power cut
            done[row["run_id"]] = row
            if row["status"] != "ok":
                progress(
                    f"run {row['run_id']} failed: {row['status']} (see {out / 'runs' / row['run_id'] / 'error.txt'})"
                )
    rows = [done[run_id(r)] for r in study.runs]
    failed = [r for r in rows if r["status"] != "ok"]
    write_csv(rows, out / "results.csv")
    meta = {
        "study": study.name,
        "file": str(study.path) if study.path else None,
        "command": command or " ".join(sys.argv),
        "versions": versions(),
        "executor": executor,
        "workers": workers,
        "finished": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    write_text(out / "study.json", json.dumps(meta, indent=2) + "\n")
    write_report(study, rows, out, meta, failed, progress)
    return StudyRows(rows)


def read_rows(out: Path, progress=print) -> list[dict]:
    """The rows of ``out/results.jsonl``. Every row is written with its newline in one write, so
    text after the last newline is what a process killed mid-write leaves: it is cut from the
    file with a warning, and its run runs again. A line that is not JSON before that is damage no
    crash explains: an error."""
    path = out / "results.jsonl"
    if not path.is_file():
        return []
    whole, newline, torn = path.read_bytes().rpartition(b"\n")
    if torn.strip():
        progress(
            f"warning: {path}: its last line is a torn row (a run cut off mid-write); dropped, that run runs again"
        )
        with open(path, "r+b") as f:
            f.truncate(len(whole + newline))
    rows = []
    for n, line in enumerate(whole.split(b"\n"), 1):
        if line.strip():
            try:
                rows.append(json.loads(line))
            except ValueError:
                raise InputError(
                    path, f"line {n} is not JSON (the file was edited?); delete that line to resume"
                ) from None
    return rows


def write_csv(rows: list[dict], path: Path) -> None:
    columns = list(dict.fromkeys(k for row in rows for k in row))
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, columns)
        writer.writeheader()
        writer.writerows(rows)


def _execute(todo: list[dict], measure: dict, out: Path, workers: int, executor: str, scheduler: str | None):
    """Rows of the runs as they finish, with a progress bar."""
    # One progress line with the time left, on a terminal; a log (no terminal) keeps the summary.
    bar = tqdm(total=len(todo), unit="run", file=sys.stderr, disable=not todo or not sys.stderr.isatty())
    try:
        if executor == "dask":
            yield from _dask(todo, measure, out, workers, scheduler, bar)
        elif workers > 1:
            # spawn, not fork: a forked child would inherit the parent's GL and LLVM state.
            with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
                futures = [pool.submit(execute_run, run, measure, str(out)) for run in todo]
                for future in as_completed(futures):
                    bar.update()
                    yield future.result()
        else:
            for run in todo:
                row = execute_run(run, measure, str(out))
                bar.update()
                yield row
    finally:
        bar.close()


def _dask(todo, measure, out, workers, scheduler, bar):
    from dask.distributed import Client, LocalCluster
    from dask.distributed import as_completed as dask_completed

    cluster = (
        None
        if scheduler
        else LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    )
    try:
        with Client(scheduler or cluster) as client:
            futures = [client.submit(execute_run, run, measure, str(out), pure=False) for run in todo]
            for future in dask_completed(futures):
                bar.update()
                yield future.result()
    finally:
        if cluster is not None:
            cluster.close()


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON")
