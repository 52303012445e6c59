"""evalkit tune: its time and error models recover known constants from synthetic rows, the
optimisation finds the grid's best setting within the budget, and bad input is one line."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from conftest import run_evalkit
from evalkit.core.errors import InputError
from evalkit.tune import GRID, Model, fit_model, optimise

TIME = {"perfect": {"t0": 0.05, "t_lists": 0.3, "t_dirs": 2.0},
        "imperfect": {"t0": 0.05, "t_lists": 0.2, "t_points": 0.02, "t_nodes": 0.1}}
ERROR = {"perfect": {"b": 0.004, "v": 0.05, "w": 0.5},
         "imperfect": {"b": 0.004, "v": 0.05, "w": 0.5, "h": 0.3, "g": 0.002}}


def synthetic_rows(method: str) -> list[dict]:
    """Rows as calibration runs would give them, from the models with known constants."""
    time_model, error_model = Model(method, "time", TIME[method], []), Model(method, "error", ERROR[method], [])
    splats = [(4096, 1.4), (16384, 1.8), (8192, 2.4)] if method == "imperfect" else [(16384, 1.8)]
    rows = []
    for K, R, F, (N, s) in itertools.product((8, 16, 32, 64), (64, 96, 128), (1, 4, 16), splats):
        rows.append({"method": method, "directions": K, "resolution": R, "points": N, "splat_scale": s, "frames": F,
                     "wall_s": float(time_model.predict(K, R, N, s)) * F, "indirect_relmse": float(error_model.predict(K, R, N, s, F))})
    return rows


@pytest.mark.parametrize("method", ["perfect", "imperfect"])
def test_fits_recover_known_time_and_error_constants(method):
    rows = synthetic_rows(method)
    time_model = fit_model(method, "time", rows)
    error_model = fit_model(method, "error", rows, "indirect_relmse")
    for fitted, true in ((time_model.constants, TIME[method]), (error_model.constants, ERROR[method])):
        assert fitted.keys() == true.keys()
        for name, value in true.items():
            assert fitted[name] == pytest.approx(value, rel=0.01), name
    assert time_model.rms_residual() < 1e-3 and error_model.rms_residual() < 1e-3


@pytest.mark.parametrize("method, budget", [("perfect", 10.0), ("perfect", 60.0), ("imperfect", 10.0)])
def test_optimisation_finds_the_best_grid_setting_within_the_budget(method, budget):
    time_model, error_model = Model(method, "time", TIME[method], []), Model(method, "error", ERROR[method], [])
    found = optimise(time_model, error_model, budget)
    axes = ["directions", "resolution"] + (["points", "splat_scale"] if method == "imperfect" else [])
    best = np.inf
    for values in itertools.product(*(GRID[a] for a in axes)):
        x = dict(zip(axes, values))
        N, s = x.get("points", 16384), x.get("splat_scale", 1.8)
        frames = int(budget // float(time_model.predict(x["directions"], x["resolution"], N, s)))
        if frames >= 1:
            best = min(best, float(error_model.predict(x["directions"], x["resolution"], N, s, frames)))
    assert found.predicted_time_s <= budget and found.settings["frames"] >= 1
    assert found.predicted_error <= 1.001 * best


def test_a_budget_below_the_cheapest_setting_says_what_is_possible():
    time_model, error_model = Model("perfect", "time", TIME["perfect"], []), Model("perfect", "error", ERROR["perfect"], [])
    # The cheapest: K=8, R=32, one frame: 0.05 + 0.3 * 8 * 32^2 * 1e-6 + 2.0 * 8 * 1e-3 = 0.0685 s.
    with pytest.raises(InputError, match=r"a budget of 0.01 s is below the cheapest perfect setting \(K=8, R=32, 1 frame: "
                                         r"0.0685 s predicted\); give at least 0.0685 s"):
        optimise(time_model, error_model, 0.01)


@pytest.mark.parametrize("args, said", [
    (["--budget", "0"], "the budget must be a positive number of seconds, got 0.0"),
    (["--budget", "10", "--metric", "indirect_psnr"], "unknown metric 'indirect_psnr'; known: direct_mse"),
    (["--budget", "10", "--method", "mitsuba"], "method must be perfect, imperfect or both, got 'mitsuba'"),
])
def test_bad_tune_input_is_one_line(tmp_path, args, said):
    r = run_evalkit("tune", "cornell-box", *args, "--out", str(tmp_path))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and said in r.stderr and "Traceback" not in r.stderr
