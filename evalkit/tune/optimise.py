"""The least predicted error within a time budget, for one candidate: every setting of its grid,
each with the frames that fill the budget."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evalkit.core.errors import InputError
from evalkit.tune.models import Candidate, Model, axes
from gpu_impl.registry import settings_symbols


@dataclass
class Recommendation:
    candidate: Candidate
    settings: dict  # directions, resolution, spp, frames and the candidate's own axes
    predicted_time_s: float
    predicted_error: float

    def as_dict(self) -> dict:
        return {
            **self.candidate.settings(),
            **self.settings,
            "predicted_time_s": self.predicted_time_s,
            "predicted_error": self.predicted_error,
        }


def optimise(
    time_model: Model, error_model: Model, budget: float, pinned: dict | None = None, refused: tuple = ()
) -> Recommendation:
    """The least predicted error within ``budget`` seconds for one candidate, over every setting of
    its grid (a ``pinned`` setting keeps its value; none at or above the values of settings the
    renderer ``refused``, since every axis only adds to what a render holds), each with the
    whole frames that fill the budget. The grids are small (at most a few hundred thousand
    settings, evaluated as arrays in milliseconds), so the search is exhaustive: a continuous
    optimum rounded to the grid misses where whole frames matter (two frames against seven)."""
    candidate = time_model.candidate
    grid = axes(candidate, pinned)
    t_once = time_model.constants["t_once"]
    mesh = np.meshgrid(*(np.asarray(v, dtype=np.float64) for v in grid.values()), indexing="ij")
    x = {a: m.ravel() for a, m in zip(grid, mesh)}
    frame_s = time_model.predict({**x, "frames": 1.0}) - t_once
    frames = np.floor((budget - t_once) / frame_s)
    if not np.any(frames >= 1):
        cheapest = {a: values[0] for a, values in grid.items()}
        least = float(time_model.predict({**cheapest, "frames": 1}))
        symbols = settings_symbols()
        setting = ", ".join(f"{symbols.get(a, a)}={v}" for a, v in cheapest.items())
        raise InputError(
            "tune",
            f"a budget of {budget:g} s is below the cheapest {candidate.name} setting ({setting}, 1 frame: "
            f"{least:.3g} s predicted); give at least {least:.3g} s",
        )
    possible = frames >= 1
    for setting in refused:
        possible &= ~np.all([x[a] >= v for a, v in setting.items()], axis=0)
    if not np.any(possible):
        raise InputError("tune", f"the renderer refused every {candidate.name} setting that fits {budget:g} s")
    error = np.where(possible, error_model.predict({**x, "frames": np.maximum(frames, 1)}), np.inf)
    i = int(np.argmin(error))
    best = {a: values[np.unravel_index(i, mesh[0].shape)[j]] for j, (a, values) in enumerate(grid.items())}
    best["frames"] = int(frames[i])
    return Recommendation(candidate, best, float(time_model.predict(best)), float(error[i]))
