"""Studies: the grid, rows with every parameter and metric, resume (after a torn row too), one
study per folder, the Dask executor, the report, and bad study files."""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import tomllib
from pathlib import Path

import pytest
from conftest import run_evalkit
from PIL import Image
from test_bundles import edge_gain

from evalkit.core.errors import InputError
from evalkit.core.lock import LOCK_NAME, folder_lock
from evalkit.core.scene import load_scene
from evalkit.demo import DEMO_STUDY
from evalkit.figures import teaser
from evalkit.report import findings, matched_time_rows, versus_rows
from evalkit.study.executors import run_study
from evalkit.study.spec import RUN_DEFAULTS, load_study, run_id, study_from_dict

# Tiny runs: 32x32, K=4 directions of R=32 lines, one frame; references of 64 spp in the study's
# own store (the committed ones are 128x128).
TINY = {
    "name": "tiny",
    "defaults": {
        "scene": "cornell-box",
        "bounces": 1,
        "directions": 4,
        "resolution": 32,
        "points": 1024,
        "width": 32,
        "height": 32,
        "frames": 2,  # two frames or more: their spread is the image's noise
        "spp": 2,
    },
    "grid": [{"method": ["perfect", "imperfect"], "seed": [0, 1]}, {"method": "mitsuba", "spp": 4, "seed": [0, 1]}],
    "measure": {
        "bundles": True,
        "images": ["indirect"],
        "metrics": ["relmse", "flip"],
        "reference_spp": 64,
        "eye_vertices": 256,
    },
    "plot": [
        {"x": "wall_s", "y": "indirect_relmse", "group": "method", "log": "xy", "pareto": True, "versus": "method"}
    ],
}


def test_the_shipped_studies_load():
    for path in sorted(Path(__file__).parents[1].glob("studies/*.toml")):
        assert load_study(path).runs, path


def test_grids_expand_to_the_union_of_their_products():
    study = study_from_dict(TINY)
    assert len(study.runs) == 6
    assert {(r["method"], r["seed"]) for r in study.runs} == {
        (m, s) for m in ("perfect", "imperfect", "mitsuba") for s in (0, 1)
    }
    assert all(r["resolution"] == 32 and r["scene"] == "cornell-box" for r in study.runs)
    assert len({run_id(r) for r in study.runs}) == 6


@pytest.mark.parametrize(
    "spec, problem",
    [
        ({"grid": [{"method": ["raytraced"]}]}, "method 'raytraced' is not one of"),
        ({"grid": [{"directions": [0]}]}, "directions must be at least 1, got 0"),
        ({"grid": [{"splat_scale": [0.0]}]}, "splat_scale must be positive and finite, got 0.0"),
        ({"grid": [{"frames": [2.5]}]}, "frames = 2.5 must be a whole number"),
        ({"grid": [{"stop_early": [1]}]}, "stop_early = 1 must be true or false"),
        ({"grid": [{"colour": [1]}]}, "unknown run parameter"),
        ({"measure": {"metrics": ["psnr"]}}, "unknown psnr"),
        ({"measure": {"image": ["total"]}}, r"unknown key\(s\) image; known: bundles, render, images, metrics, "),
        ({"plots": []}, "unknown key"),
        ({"plot": [{"x": "wall_s"}]}, "needs x and y"),
        ({"plot": [{"x": "wall_s", "y": "indirect_relmse", "versus": "stratgy"}]}, "versus names a run parameter"),
        # A file's structure of the wrong type: each was a traceback or taken without a word.
        ({"title": 5}, "title = 5 must be a string"),
        ({"grid": 5}, r"grid = 5 must be a table or an array of tables \(\[\[grid\]\]\)"),
        ({"grid": ["perfect"]}, "must be a table or an array of tables"),
        ({"grid": []}, r"grid = \[\] declares no runs"),
        ({"plot": [5]}, "must be an array of tables"),
        ({"plot": [{"x": "wall_s", "y": []}]}, "x names a column and y one or more"),
        ({"report": 5}, r"\[report\] must be a table"),
        ({"measure": {"metrics": "relmse"}}, r"\[measure\] metrics = 'relmse' must be an array of names"),
        ({"measure": {"render": 3}}, r"\[measure\] render = 3 must be true or false"),
        ({"measure": {"reference_spp": True}}, "reference_spp = True must be a whole number"),
    ],
)
def test_bad_studies_are_refused_with_the_problem_named(spec, problem):
    with pytest.raises(InputError, match=problem):
        study_from_dict(spec)


def test_bad_study_files_end_in_one_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("name = [unclosed\n")
    with pytest.raises(InputError, match="bad.toml: malformed TOML"):
        load_study(bad)
    r = run_evalkit("study", str(tmp_path / "missing.toml"))
    assert r.returncode == 2 and r.stderr.strip() == f"evalkit: error: {tmp_path / 'missing.toml'}: no such study file"
    missing_scene = tmp_path / "scene.toml"
    missing_scene.write_text('[defaults]\nscene = "no-such-scene.obj"\n[measure]\nimages = []\nrender = false\n')
    r = run_evalkit("study", str(missing_scene), "--out", str(tmp_path / "out"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "no-such-scene.obj" in r.stderr


@pytest.fixture(scope="module")
def tiny_study(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny")
    lines = []
    rows = run_study(study_from_dict(TINY), out, progress=lines.append, command="pytest tiny")
    return out, rows, lines


def test_a_study_writes_one_row_per_run_with_parameters_metrics_timings_and_versions(tiny_study):
    out, rows, _ = tiny_study
    assert [r["status"] for r in rows] == ["ok"] * 6
    with open(out / "results.csv") as f:
        table = list(csv.DictReader(f))
    assert len(table) == 6
    for row in table:
        for column in (
            "run_id",
            "scene",
            "method",
            "seed",
            "directions",
            "resolution",
            "indirect_relmse",
            "indirect_flip",
            "wall_s",
            "version_mitsuba",
            "version_raybundle-evalkit",
            "scene_hash",
            "reference",
        ):
            assert row[column] != "", column
        assert float(row["indirect_relmse"]) > 0
    bundles = [r for r in rows if r["method"] != "mitsuba"]
    assert all(r["hole_rate"] < 1e-3 for r in bundles if r["method"] == "perfect")
    # Splats overlap; the nodes they put on one line for one surface are merged into one.
    assert all(
        r["raw_nodes"] >= r["test_nodes"] and r["redundant_rate"] < 0.05 for r in bundles if r["method"] == "imperfect"
    )
    assert all(0 <= r["next_hit_error_rate"] <= 1 and r["next_hit_lookups"] > 100 for r in bundles)
    # A bundle row says how sure its image mean is (a Mitsuba row has no frames to tell).
    for r in bundles:
        assert r["indirect_mean_ratio_lo"] < r["indirect_mean_ratio"] < r["indirect_mean_ratio_hi"]
        assert 0 <= r["indirect_z_outside"] <= 1
        assert r["leak_rate"] + r["offset_rate"] + r["coincident_rate"] == pytest.approx(r["hole_rate"])
    # Different seeds give different images.
    perfect = [r for r in rows if r["method"] == "perfect"]
    assert perfect[0]["indirect_relmse"] != perfect[1]["indirect_relmse"]


def test_the_report_shows_tables_plots_images_and_the_bias_variance_split(tiny_study):
    out, rows, _ = tiny_study
    report = (out / "report.html").read_text()
    for text in (
        "Results",
        "Pareto front",
        "Bias and variance over seeds",
        "Images",
        "pytest tiny",
        "mitsuba 3.9.1",
        "Scene warnings",
    ):
        assert text in report, text
    assert (out / "plots" / "plot0.png").stat().st_size > 1000
    # Each method's front against the other's, with only the settings that tell their rows apart:
    # the imperfect rows' one number of points is implied by their method.
    versus = report[report.index("method against method at matched wall_s") :]
    versus = versus[: versus.index("</table>")]
    assert "<th>against</th>" in versus and "<th>seed</th>" not in versus and "<th>points</th>" not in versus
    # The answer first, the full table after it, how it was made last.
    order = ["What the study found", "Pareto front", "Images", "<h2>Results", "How it was made"]
    assert [report.index(text) for text in order] == sorted(report.index(text) for text in order)
    assert "scene cornell-box: the least indirect_relmse, " in report and "class='ek-table" in report
    # Without plots, what the study found is each measured image metric run by run.
    spec = {**TINY, "plot": [], "grid": [{"method": ["perfect", "imperfect"], "seed": 0}]}
    seed0 = [r for r in rows if r["seed"] == 0 and r["method"] != "mitsuba"]
    found = findings(study_from_dict(spec), seed0, seed0)
    perfect, imperfect = (f"{r['indirect_relmse']:.4g}" for r in seed0)
    assert found[1] == f"indirect_relmse: method=perfect: {perfect}; method=imperfect: {imperfect}."
    # Each shown run's image, its error maps and the reference, as half floats for the viewer.
    assert len(list((out / "viewer").glob("*.js"))) >= 4 and "class='ek-viewer'" in report
    assert json.loads((out / "study.json").read_text())["versions"]["drjit"] == "1.5.0"


def test_a_misspelled_plot_column_is_named_with_the_columns_there_are(tiny_study, tmp_path):
    out, rows, _ = tiny_study
    shutil.copytree(out, tmp_path / "copy")
    lines = []
    spec = {**TINY, "plot": [{"x": "wall_s", "y": "hole_rat", "group": "method"}]}
    run_study(study_from_dict(spec), tmp_path / "copy", progress=lines.append)
    (warning,) = [line for line in lines if "[[plot]] 1" in line]
    assert "no column hole_rat in the results; the columns are " in warning and "hole_rate" in warning
    assert "<b>Not drawn:</b> [[plot]] 1: no column hole_rat" in (tmp_path / "copy" / "report.html").read_text()


def test_a_second_start_resumes_and_recomputes_nothing(tiny_study):
    out, rows, _ = tiny_study
    lines = []
    again = run_study(study_from_dict(TINY), out, progress=lines.append)
    assert "6 finished before, 0 to run" in lines[0]
    assert again == rows
    assert len((out / "results.jsonl").read_text().splitlines()) == 6


def test_a_torn_last_row_is_dropped_with_a_warning_and_its_run_runs_again(tiny_study, tmp_path):
    # What a run killed mid-write leaves: part of its row and no newline.
    out, rows, _ = tiny_study
    torn = tmp_path / "torn"
    shutil.copytree(out, torn)  # the finished runs' folders too: the report reads their images
    whole = (out / "results.jsonl").read_text().splitlines()
    (torn / "results.jsonl").write_text("\n".join(whole[:4]) + "\n" + whole[4][: len(whole[4]) // 2])
    lines = []
    again = run_study(study_from_dict(TINY), torn, progress=lines.append)
    assert any("torn row" in line and "results.jsonl" in line for line in lines), lines
    assert "4 finished before, 2 to run" in next(line for line in lines if "finished before" in line)
    written = [json.loads(line) for line in (torn / "results.jsonl").read_text().splitlines()]
    assert sorted(r["run_id"] for r in written) == sorted(r["run_id"] for r in rows)  # none twice
    assert [r["run_id"] for r in again] == [r["run_id"] for r in rows]


def test_a_second_study_on_a_folder_in_use_refuses_in_one_line(tmp_path):
    study = tmp_path / "study.toml"
    study.write_text('[defaults]\nscene = "cornell-box"\n[measure]\nimages = []\nrender = false\n')
    with folder_lock(tmp_path / "out", "study"):
        r = run_evalkit("study", str(study), "--out", str(tmp_path / "out"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"another study is writing here (pid {os.getpid()} on " in r.stderr and "--wait" in r.stderr
    assert not (tmp_path / "out" / "results.jsonl").exists()


def test_a_lock_left_by_a_killed_study_is_taken_over_with_a_warning(tmp_path):
    # The kernel drops a flock when its process dies; the holder's line stays in the file.
    (tmp_path / LOCK_NAME).write_text("pid 999999 on elsewhere since 2026-01-01 00:00:00: evalkit study x\n")
    lines = []
    with folder_lock(tmp_path, "study", progress=lines.append):
        assert str(os.getpid()) in (tmp_path / LOCK_NAME).read_text()
    assert len(lines) == 1 and "took over" in lines[0] and "pid 999999 on elsewhere" in lines[0]
    assert (tmp_path / LOCK_NAME).read_text() == ""  # released: the next holder has nothing to warn of


def test_the_dask_executor_gives_the_same_rows_as_the_local_one(tiny_study, tmp_path):
    out, rows, _ = tiny_study
    spec = {
        **TINY,
        "grid": [{"method": ["perfect", "mitsuba"], "seed": 1}],
        "measure": {**TINY["measure"], "bundles": False},
    }
    dask_rows = run_study(study_from_dict(spec), tmp_path, workers=2, executor="dask", progress=lambda line: None)
    local = {r["run_id"]: r for r in run_study(study_from_dict(spec), tmp_path / "local", progress=lambda line: None)}
    assert [r["status"] for r in dask_rows] == ["ok", "ok"]
    for row in dask_rows:
        assert row["indirect_relmse"] == local[row["run_id"]]["indirect_relmse"]  # bitwise: same seed, same image


@pytest.mark.long
def test_the_demo_renders_compares_and_reports(tmp_path):
    figure = tmp_path / "teaser.png"
    r = run_evalkit("demo", "--out", str(tmp_path / "demo"), "--figure", str(figure))
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[-2] == f"report      {tmp_path / 'demo' / 'report.html'}" and lines[-1] == f"figure      {figure}"
    assert lines[-4].split()[0] == "perfect" and lines[-3].split()[0] == "imperfect"
    assert Image.open(figure).size == (1040, 300)  # the README's picture: four panels
    with open(tmp_path / "demo" / "results.csv") as f:
        rows = {row["method"]: row for row in csv.DictReader(f)}
    # The committed 16384-spp reference; 512 paths per pixel put the indirect relMSE near 0.09.
    assert "b3_128x128_spp16384_seed0" in rows["perfect"]["reference"]
    for row in rows.values():
        assert float(row["indirect_relmse"]) < 0.2
        assert float(row["total_delta_e2000"]) > 0
    assert float(rows["perfect"]["hole_rate"]) < 1e-3 < float(rows["imperfect"]["hole_rate"])
    assert "Images" in (tmp_path / "demo" / "report.html").read_text()


@pytest.mark.long
def test_the_demo_study_at_two_frames_runs_every_stage_and_draws_the_figure(tmp_path):
    # The demo's own study (evalkit/demo.toml) with 2 frames of 4 paths per pixel in place of 32 of
    # 16: the same scene, bundles, Embree comparison, committed reference, report and figure, in
    # the time the default suite allows (the full demo is the long test above).
    with open(DEMO_STUDY, "rb") as f:
        spec = tomllib.load(f)
    spec["defaults"].update(frames=2, spp=4)
    rows = {r["method"]: r for r in run_study(study_from_dict(spec), tmp_path / "demo", progress=lambda line: None)}
    assert set(rows) == {"perfect", "imperfect"}
    for row in rows.values():
        assert "b3_128x128_spp16384_seed0" in row["reference"]
        assert math.isfinite(float(row["indirect_relmse"])) and float(row["total_delta_e2000"]) > 0
    assert float(rows["perfect"]["hole_rate"]) < 1e-3 < float(rows["imperfect"]["hole_rate"])
    assert "Images" in (tmp_path / "demo" / "report.html").read_text()
    teaser(list(rows.values()), tmp_path / "demo", tmp_path / "teaser.png")
    assert Image.open(tmp_path / "teaser.png").size == (1040, 300)


def test_runs_build_imperfect_bundles_with_their_own_sampler(tmp_path):
    spec = {
        "defaults": {
            "scene": "cornell-box",
            "method": "imperfect",
            "directions": 4,
            "resolution": 64,
            "points": 4096,
            "splat_scale": 1.5,
        },
        "grid": [{"sampler": ["random", "stratified"]}],
        "measure": {"bundles": True, "render": False, "images": [], "eye_vertices": 256},
    }
    rows = {r["sampler"]: r for r in run_study(study_from_dict(spec), tmp_path, progress=lambda line: None)}
    # Independent points leave about exp(-1.5^2) = 0.105 of the crossings uncovered; stratified ones
    # far fewer. Either way a crossing yields 1.5^2 raw nodes, and what cut splats gain at sharp
    # edges (`edge_gain`).
    assert rows["random"]["hole_rate"] == pytest.approx(0.105, rel=0.2)
    assert rows["stratified"]["hole_rate"] < 0.5 * rows["random"]["hole_rate"]
    scene = load_scene("cornell-box")
    for r in rows.values():
        assert r["nodes_per_crossing"] == pytest.approx(1.5**2 * (1 + edge_gain(scene, r["splat_radius"])), rel=0.05)


def test_matched_time_compares_each_bundle_setting_with_mitsuba_at_the_same_time():
    def row(scene, method, wall_s, error, seed, **kw):
        return {
            **RUN_DEFAULTS,
            "scene": scene,
            "method": method,
            "seed": seed,
            "wall_s": wall_s,
            "total_relmse": error,
            **kw,
        }

    # Mitsuba's error falls as 1 / time: 1 at 1 s, 0.25 at 4 s, so 0.5 at 2 s in log-log.
    rows = [row("a", "mitsuba", 1.0, 1.0, s, spp=4) for s in (0, 1)] + [
        row("a", "mitsuba", 4.0, 0.25, s, spp=16) for s in (0, 1)
    ]
    rows += [row("a", "perfect", 2.0, e, s, frames=2) for s, e in ((0, 0.2), (1, 0.4))]  # mean 0.3
    rows += [row("a", "perfect", 9.0, 0.1, 0, frames=8)]  # beyond Mitsuba's times
    rows += [row("b", "perfect", 2.0, 0.3, 0)]  # no Mitsuba in scene b
    matched = matched_time_rows(rows, "wall_s", "total_relmse")
    assert [(r["scene"], r["frames"]) for r in matched] == [("a", 2), ("a", 8)]
    assert matched[0]["seeds"] == 2 and matched[0]["total_relmse"] == pytest.approx(0.3)
    assert matched[0]["mitsuba_total_relmse"] == pytest.approx(0.5)
    assert matched[0]["ratio"] == pytest.approx(0.6) and matched[0]["more_accurate"] == "bundles"
    assert "ratio" not in matched[1] and matched[1]["more_accurate"].startswith("not compared: wall_s outside")


def test_strategies_are_compared_at_matched_time_each_at_its_own_best_settings():
    def row(strategy, spp, frames, wall_s, error, seed=0):
        return {
            **RUN_DEFAULTS,
            "scene": "a",
            "strategy": strategy,
            "spp": spp,
            "frames": frames,
            "seed": seed,
            "wall_s": wall_s,
            "indirect_relmse": error,
        }

    # Eye paths: 4 paths a frame are off their front (8 frames of 16 paths are faster and better);
    # 16 paths: 0.4 at 1 s and 0.1 at 4 s, so 0.2 at 2 s in log-log.
    rows = [row("eye", 4, 8, 3.0, 0.5), row("eye", 16, 2, 1.0, 0.4), row("eye", 16, 8, 4.0, 0.1)]
    # Bidirectional paths: 0.1 at 2 s (two seeds, 0.05 and 0.15), and 0.09 at 8 s, beyond eye's front.
    rows += [row("bidirectional", 4, 2, 2.0, e, seed) for seed, e in ((0, 0.05), (1, 0.15))]
    rows += [row("bidirectional", 4, 8, 8.0, 0.09)]
    rows += [row(None, 1, 1, 2.0, 0.01) | {"method": "mitsuba"}]  # not a strategy: left out
    compared = {
        (r["strategy"], r["spp"], r["frames"]): r
        for r in versus_rows(rows, "wall_s", "indirect_relmse", "strategy", ["spp", "frames"])
    }
    assert set(compared) == {("eye", 16, 2), ("eye", 16, 8), ("bidirectional", 4, 2), ("bidirectional", 4, 8)}
    first = compared[("bidirectional", 4, 2)]
    assert first["seeds"] == 2 and first["indirect_relmse"] == pytest.approx(0.1)
    assert first["against"] == "eye" and first["against_indirect_relmse"] == pytest.approx(0.2)
    assert first["ratio"] == pytest.approx(0.5) and first["more_accurate"] == "bidirectional"
    assert compared[("bidirectional", 4, 8)]["more_accurate"].startswith("not compared: wall_s outside eye's front")
    # Eye paths' 16-path setting at 4 s, halfway in log x from bidirectional paths' 2 s to their 8 s:
    # their front there is 0.1 x 0.9^(1/2).
    last = compared[("eye", 16, 8)]
    assert last["ratio"] == pytest.approx(1.0 / math.sqrt(0.9))
    assert last["more_accurate"] == "bidirectional"
