"""The declared accuracy thresholds (evalkit/thresholds.toml), each case a test; and `evalkit check`
itself: its table, JUnit XML, exit status and what it keeps for a person to look at on failure.
A failing case leaves the test image, the reference and the error maps in out/thresholds/<case>."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import pytest
from conftest import REPO, run_evalkit

from evalkit.check import evaluate
from evalkit.core.errors import InputError
from evalkit.thresholds import DEFAULT_THRESHOLDS, load_thresholds

CASES = load_thresholds(DEFAULT_THRESHOLDS)
ARTIFACTS = os.path.join(REPO, "out", "thresholds")


# The cases that take 10 s or more on 2 cores (sweeps, converged relMSE) run with the long tests
# and in `make check`, which runs every case.
LONG_CASES = {
    "furnace-indirect-error-falls-with-R",
    "cornell-perfect-indirect-relmse",
    "cornell-bidirectional-indirect-relmse",
    "cornell-indirect-error-falls-with-K",
}
assert {c.name for c in CASES} >= LONG_CASES, LONG_CASES


@pytest.mark.parametrize(
    "case", [pytest.param(c, id=c.name, marks=pytest.mark.long if c.name in LONG_CASES else ()) for c in CASES]
)
def test_declared_threshold(case):
    outcome = evaluate(case, ARTIFACTS)
    assert outcome.passed, (
        f"{outcome.message}; why: {case.why}; calibration: {case.calibration}; look at {outcome.folder}"
    )


def test_every_case_says_why_and_how_it_was_calibrated():
    for case in CASES:
        assert len(case.why) > 40 and "TBD" not in case.calibration and "seeds" in case.calibration, case.name


TINY = """
[[case]]
name = "{name}"
metric = "indirect_relmse"
kind = "max"
threshold = {threshold}
why = "a test of evalkit check"
calibration = "none"
measure = {{ images = ["indirect"], metrics = ["relmse", "flip"], reference_spp = 64 }}
[case.run]
scene = "cornell-box"
method = "perfect"
directions = 4
resolution = 32
width = 32
height = 32
frames = 1
spp = 2
"""


def test_check_prints_a_table_writes_junit_and_keeps_failures_for_inspection(tmp_path):
    table = tmp_path / "thresholds.toml"
    table.write_text(TINY.format(name="loose", threshold=1e9) + TINY.format(name="impossible", threshold=1e-12))
    r = run_evalkit("check", str(table), "--out", str(tmp_path / "out"))
    assert r.returncode == 1, r.stderr
    lines = r.stdout.splitlines()
    assert any(line.startswith("loose") and " pass " in line for line in lines)
    assert any(line.startswith("impossible") and "FAIL" in line for line in lines)
    suite = ET.parse(tmp_path / "out" / "junit.xml").getroot()
    assert suite.get("tests") == "2" and suite.get("failures") == "1"
    failed = [c for c in suite.iter("testcase") if c.find("failure") is not None]
    assert [c.get("name") for c in failed] == ["impossible"]
    run = next((tmp_path / "out" / "impossible" / "runs").iterdir())
    for name in (
        "indirect.exr",
        "indirect_reference.exr",
        "indirect_relmse_map.exr",
        "indirect_relmse_map.png",
        "indirect_flip_map.png",
    ):
        assert (run / name).is_file(), name
    report = (tmp_path / "out" / "impossible" / "report.html").read_text()  # the images in the viewer
    assert "FAILED: indirect_relmse" in report and report.count("class='ek-viewer'") == 1
    r = run_evalkit("check", str(table), "--case", "loose", "--out", str(tmp_path / "out2"))
    assert r.returncode == 0 and "1 of 1 cases pass" in r.stdout


def test_bad_threshold_tables_end_in_one_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[[case]]\nname = "x"\nmetric = "hole_rate"\nkind = "below"\nwhy = "w"\ncalibration = "c"\n')
    r = run_evalkit("check", str(bad))
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"evalkit: error: {bad}: case 1 (x): kind 'below' is not one of max, min, falls"
    ]


CASE = 'name = "x"\nmetric = "hole_rate"\nkind = "max"\nthreshold = 0.1\nwhy = "w"\ncalibration = "c"\n'
FALLS = CASE.replace('kind = "max"', 'kind = "falls"').replace("threshold = 0.1", "tolerance = 0.1")


@pytest.mark.parametrize(
    "text, problem",
    [  # each was taken without a word, to fail or crash when checked, or a traceback here
        ("case = 5\n", r"case = 5 must be an array of tables \(\[\[case\]\]\)"),
        ("[[case]]\n" + CASE.replace("threshold = 0.1", 'threshold = "0.1"'), "threshold = '0.1' must be a finite"),
        ("[[case]]\n" + CASE.replace("threshold = 0.1", "threshold = nan"), "threshold = nan must be a finite number"),
        ("[[case]]\n" + CASE.replace('metric = "hole_rate"', "metric = 5"), "metric = 5 must be a string"),
        ("[[case]]\n" + CASE + 'run = "cornell-box"\n', "run = 'cornell-box' must be a table"),
        ("[[case]]\n" + FALLS + "sweep = {directions = 8}\n", "must give its parameter an array of values"),
        ("[[case]]\n" + FALLS.replace("tolerance = 0.1", "tolerance = true") + "sweep = {directions = [8, 32]}\n",
         "tolerance = True must be a finite number"),
    ],
)  # fmt: skip
def test_threshold_tables_of_the_wrong_types_are_refused(tmp_path, text, problem):
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    with pytest.raises(InputError, match=problem):
        load_thresholds(bad)
