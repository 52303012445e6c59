"""Faults as a long study meets them, in real processes: SIGKILL at random points and resume, two
studies started on one folder, and an EGL that cannot start.

The killed study must end with exactly the rows of an uninterrupted one (none lost, none twice,
none torn) and bitwise the same metrics: every output is written whole (evalkit/core/atomic.py),
a torn last row is dropped and rerun, references resume from their last chunk, and one process
writes a folder or a store entry at a time (evalkit/core/lock.py)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import REPO, run_evalkit

# Tiny runs (two methods times SEEDS) and their reference, rendered into the study's own store so
# that kills land in it too.
STUDY = """
name = "faults"
[defaults]
scene = "cornell-box"
bounces = 1
directions = 4
resolution = 32
points = 1024
width = 32
height = 32
frames = 2
spp = 2
[[grid]]
method = ["perfect", "imperfect"]
seed = SEEDS
[measure]
bundles = false
images = ["indirect"]
metrics = ["relmse", "smape"]
reference_spp = 64
"""
# What a row holds that differs between two runs of the same settings: times, and the reference's
# path (each study has its own store).
VARYING = ("wall_s", "run_s", "reference")


def write_study(folder, runs: int):
    study = folder / f"faults{runs}.toml"
    study.write_text(STUDY.replace("SEEDS", str(list(range(runs // 2)))))
    return study


def start_study(study, out, *extra) -> subprocess.Popen:
    command = [sys.executable, "-m", "evalkit.cli", "study", str(study), "--out", str(out), *extra]
    return subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def rows_of(out) -> list[dict]:
    """Every line of results.jsonl, parsed: a torn or damaged line fails here."""
    return [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]


def metrics(row: dict) -> dict:
    return {k: v for k, v in row.items() if k not in VARYING and not k.startswith("ms_")}


def straight_run(study, out) -> tuple[list[dict], float, float]:
    """The study run straight through: (rows, its seconds, the seconds of a rerun with nothing
    left to run: start-up, report and exit)."""
    start = time.perf_counter()
    first = run_evalkit("study", str(study), "--out", str(out))
    seconds = time.perf_counter() - start
    assert first.returncode == 0, first.stderr
    start = time.perf_counter()
    assert run_evalkit("study", str(study), "--out", str(out)).returncode == 0
    return rows_of(out), seconds, time.perf_counter() - start


@pytest.fixture(scope="module")
def six_runs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("faults")
    study = write_study(folder, 6)
    return study, *straight_run(study, folder / "straight")


def test_a_second_study_on_a_running_folder_refuses_or_waits(six_runs, tmp_path):
    study, rows, *_ = six_runs
    out = tmp_path / "out"
    first = start_study(study, out)
    while not (out / ".evalkit.lock").is_file() or not (out / ".evalkit.lock").read_text():
        assert first.poll() is None, first.communicate()
        time.sleep(0.02)
    waiting = start_study(study, out, "--wait")
    second = run_evalkit("study", str(study), "--out", str(out))
    _, first_err = first.communicate(timeout=600)
    waited_out, waited_err = waiting.communicate(timeout=600)
    assert first.returncode == 0, first_err
    assert second.returncode == 2 and len(second.stderr.strip().splitlines()) == 1, second.stderr
    assert "another study is writing here (pid" in second.stderr and "--wait" in second.stderr
    assert waiting.returncode == 0, waited_err
    assert "waiting for" in waited_out and "6 finished before, 0 to run" in waited_out
    check_same_rows(out, rows)  # nobody ran a run twice


def kill_and_resume(study, out, kills: int, seed: int, rerun_s: float, run_s: float) -> int:
    """Start the study and SIGKILL it ``kills`` times, each at a uniform random time up to its
    start-up and two runs' work, so that the kill points spread over the whole study; then let it
    finish. Returns the kills that landed before the process had finished."""
    rng = np.random.default_rng(seed)
    landed = 0
    for at in rng.uniform(0.0, rerun_s + 2 * run_s, kills):
        process = start_study(study, out)
        try:
            process.wait(timeout=at)
        except subprocess.TimeoutExpired:
            os.kill(process.pid, signal.SIGKILL)
            landed += 1
        process.communicate()
    finish = start_study(study, out)
    _, err = finish.communicate(timeout=600)
    assert finish.returncode == 0, err
    return landed


def check_same_rows(out, rows):
    resumed = rows_of(out)
    assert len(resumed) == len({r["run_id"] for r in resumed}), "a run written twice"
    assert sorted(r["run_id"] for r in resumed) == sorted(r["run_id"] for r in rows), "a run lost"
    straight = {r["run_id"]: metrics(r) for r in rows}
    for row in resumed:
        assert metrics(row) == straight[row["run_id"]], row["run_id"]  # bitwise: same seeds, same images
    assert not [p for p in out.rglob("*") if ".tmp" in p.name], "a temporary file left behind"


def test_a_study_killed_at_random_points_resumes_to_the_same_rows(six_runs, tmp_path):
    study, rows, seconds, rerun_s = six_runs
    landed = kill_and_resume(study, tmp_path / "killed", 4, 0, rerun_s, (seconds - rerun_s) / len(rows))
    assert landed >= 3
    check_same_rows(tmp_path / "killed", rows)


@pytest.mark.slow
def test_a_study_killed_at_24_random_points_resumes_to_the_same_rows(tmp_path):
    study = write_study(tmp_path, 24)
    rows, seconds, rerun_s = straight_run(study, tmp_path / "straight")
    landed = kill_and_resume(study, tmp_path / "killed", 24, 1, rerun_s, (seconds - rerun_s) / len(rows))
    print(f"{landed} of 24 kills landed before their process finished")
    assert landed >= 20
    check_same_rows(tmp_path / "killed", rows)


@pytest.mark.parametrize(
    "environment, problem",
    [
        ({"EVALKIT_GL_DEVICE": "7"}, "EGL device 7: no OpenGL 4.5 context"),
        ({"EVALKIT_GL_DEVICE": "gpu1"}, "EVALKIT_GL_DEVICE: 'gpu1' is not an EGL device index"),
        ({"__EGL_VENDOR_LIBRARY_FILENAMES": "/nonexistent.json", "EGL_PLATFORM": "surfaceless"}, "no OpenGL 4.5"),
    ],
)
def test_an_egl_that_cannot_start_is_one_line_naming_the_device(tmp_path, environment, problem):
    # A device index past the machine's, one that is not a number, and no EGL vendor library at
    # all (what a display-only or missing driver looks like to libglvnd).
    r = run_evalkit(
        "render", "cornell-box", "--method", "perfect", "--out", str(tmp_path), env={**os.environ, **environment}
    )
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert problem in r.stderr and not list(tmp_path.iterdir())
