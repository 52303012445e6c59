"""The least predicted error within a time budget, for one candidate: gradient descent over the
continuous settings with the frames filling the budget, then the grid around the optimum."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from evalkit.core.errors import InputError
from evalkit.metrics.fitting import drjit, gradient_descent
from evalkit.tune.models import Candidate, Model, axes, log_axes
from gpu_impl.registry import settings_symbols


@dataclass
class Recommendation:
    candidate: Candidate
    settings: dict  # directions, resolution, frames and the candidate's own axes
    predicted_time_s: float
    predicted_error: float

    def as_dict(self) -> dict:
        return {
            **self.candidate.settings(),
            **self.settings,
            "predicted_time_s": self.predicted_time_s,
            "predicted_error": self.predicted_error,
        }


def optimise(time_model: Model, error_model: Model, budget: float) -> Recommendation:
    """The least predicted error within ``budget`` seconds for one candidate: gradient descent over
    the continuous settings (frames filling the budget), then the grid around the optimum."""
    candidate = time_model.candidate
    grid = axes(candidate)
    names = list(grid)
    t_once = time_model.constants["t_once"]

    def frame_time(x: dict):
        return time_model.predict({**x, "frames": 1.0}) - t_once

    cheapest_settings = {a: values[0] for a, values in grid.items()}
    cheapest = float(time_model.predict({**cheapest_settings, "frames": 1}))
    if budget < cheapest:
        symbols = settings_symbols()
        setting = ", ".join(f"{symbols.get(a, a)}={v}" for a, v in cheapest_settings.items())
        raise InputError(
            "tune",
            f"a budget of {budget:g} s is below the cheapest {candidate.name} setting ({setting}, 1 frame: "
            f"{cheapest:.3g} s predicted); give at least {cheapest:.3g} s",
        )
    _, Float = drjit()
    lo = {a: values[0] for a, values in grid.items()}
    hi = {a: values[-1] for a, values in grid.items()}
    logarithmic = log_axes(candidate)

    def settings_of(dr_, u: list) -> dict:
        out = {}
        for a, x in zip(names, u):
            t = 1.0 / (1.0 + dr_.exp(-x))
            if a in logarithmic:
                out[a] = dr_.exp(math.log(lo[a]) + (math.log(hi[a]) - math.log(lo[a])) * t)
            else:
                out[a] = lo[a] + (hi[a] - lo[a]) * t
        return out

    def loss(dr_, *u):
        x = settings_of(dr_, list(u))
        F = (budget - t_once) / frame_time(x)
        return dr_.log(error_model.predict({**x, "frames": F}, xp=dr_))

    u = gradient_descent(loss, [0.0] * len(names), steps=600, rate=0.05)
    continuous = {a: float(v) for a, v in settings_of(np, u).items()}
    best = None
    for setting in _neighbours(continuous, grid):
        frames = int((budget - t_once) // float(frame_time(setting)))
        if frames < 1:
            continue
        x = {**setting, "frames": frames}
        error = float(error_model.predict(x))
        if best is None or error < best.predicted_error:
            best = Recommendation(candidate, x, float(time_model.predict(x)), error)
    if best is None:  # the continuous optimum's neighbours all cost over a frame of the budget
        raise InputError(
            "tune", f"no {candidate.name} setting near the optimum fits {budget:g} s; give a larger budget"
        )
    return best


def _neighbours(continuous: dict, grid: dict) -> list[dict]:
    """Every combination of the two grid values around each continuous setting and the next one
    out on either side."""
    choices = []
    for a, values in grid.items():
        i = int(np.searchsorted(values, continuous[a]))
        choices.append(sorted({values[j] for j in range(i - 2, i + 2) if 0 <= j < len(values)}))
    combos = [{}]
    for a, values in zip(grid, choices):
        combos = [{**c, a: v} for c in combos for v in values]
    return combos
