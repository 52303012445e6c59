"""The tuner's models of render time and error (evalkit/tune/__init__.py gives them) and their fit
to calibration rows with Dr.Jit's automatic differentiation. A candidate is a choice of units (a
bundle method, a path strategy, a light visibility); each unit adds its own terms
(`gpu_impl.units.TuneTerms`), the shared ones are here."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from evalkit.core.errors import InputError
from evalkit.core.settings import IMAGES
from evalkit.metrics.fitting import drjit, gradient_descent
from evalkit.metrics.images import METRICS
from evalkit.pages import is_number
from gpu_impl.registry import KINDS

TUNE_METRICS = tuple(f"{image}_{metric}" for image in IMAGES for metric in METRICS)
# The settings every candidate's recommendation is chosen from (every combination is evaluated);
# each unit adds its own axes (`axes`). No fewer than 8 directions: a path never takes the bundle
# it arrived along, and at K = 4 that is a bias no term of the error model has (an open stage's
# indirect light -13 %, docs/results/decisions.toml: no-return-bundle); atrium's 10 s recommendation at K = 4 measured
# twice its prediction.
GRID = {
    "directions": [8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256],
    "resolution": [32, 48, 64, 96, 128, 192, 256],
    "spp": [1, 2, 4, 8, 16, 32, 64, 128],
}
# The eye paths per pixel per frame of the calibration runs, taken in turn (a cycle of 4 against the
# bundle methods' 10 or 13 runs and the light paths' 3, so that no two settings move together); the
# last two runs, the long ones, take the first two. Atrium's eye paths win or lose against
# bidirectional paths by this setting alone (docs/results/decisions.toml: eye-paths-a-frame); `evalkit tune --spp tune`
# tunes it.
CALIBRATION_SPP = (4, 32, 1, 16)
# The terms every candidate's models have: a render's once-only cost, a frame's cost outside the
# bundles and the paths, the lists K R^2 and the eye paths S (time); the O(1/R) bias, the paths'
# variance and what a frame's K shared directions add, which more paths in the same frame do not
# take away (error).
TIME_TERMS = ("t_once", "t0", "t_lists", "t_paths")
ERROR_TERMS = ("b", "v", "w")
# The metrics that are a mean of squared per-pixel errors, to which a bias adds its square, so that
# renders can measure it (`gpu_impl.units.TuneTerms.measured`); under the others (SMAPE, FLIP,
# Delta E) the settings of the measured terms stay at their defaults (`unmeasured_axes`).
SQUARED_METRICS = ("mse", "relmse")


@dataclass(frozen=True)
class Candidate:
    """What the tuner models and recommends between: one unit of each kind, by name (the defaults
    unless given)."""

    method: str = KINDS["method"].default.name
    strategy: str = KINDS["strategy"].default.name
    light_visibility: str = KINDS["light_visibility"].default.name

    @classmethod
    def of(cls, settings: dict) -> Candidate:
        """The candidate of a run's settings or row (an absent unit: the default)."""
        return cls(**{f.name: settings.get(f.name) or getattr(cls, f.name) for f in fields(cls)})

    def settings(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def name(self) -> str:
        """'perfect', or 'perfect strategy=bidirectional' and so on: the method and each other unit
        that is not the default."""
        others = [f"{k}={v}" for k, v in self.settings().items() if k != "method" and v != getattr(Candidate, k)]
        return " ".join([self.method, *others])

    @property
    def units(self) -> list:
        return [KINDS[k][v] for k, v in self.settings().items()]

    @property
    def tunes(self) -> list:
        return [unit.tune for unit in self.units]

    def calibration(self) -> list[dict]:
        """The calibration runs: the bundle method's, each with the other units' settings taken in
        turn from their runs."""
        own = [t.calibration for t in self.tunes if t.calibration]
        count = max((len(c) for c in own), default=0)
        return [{**self.settings(), **{k: v for c in own for k, v in c[i % len(c)].items()}} for i in range(count)]


def axes(candidate: Candidate, pinned: dict | None = None) -> dict:
    """The settings the optimiser varies for ``candidate``, with their grids; a ``pinned`` setting
    (the eye paths per pixel, unless ``--spp tune``) has its one value."""
    grid = {**GRID, **{a: v for t in candidate.tunes for a, v in t.axes.items()}}
    return {**grid, **{a: [v] for a, v in (pinned or {}).items()}}


def draws_light_maps(candidate: Candidate, emitters: bool) -> bool:
    """Whether ``candidate``'s renders draw a light vertex's map: those of light paths, or the
    emitter samples of a scene with emissive triangles (``emitters``)."""
    return emitters or KINDS["strategy"][candidate.strategy].light_vertices


def idle_axes(candidate: Candidate, emitters: bool) -> dict:
    """The light visibility's axes at their defaults where ``candidate`` renders no light vertex
    (`draws_light_maps`): eye paths in a scene without emissive triangles, whose images nothing of
    the maps changes. Tuned there, they would follow the fit's noise (atrium's eye paths were
    recommended maps of 256 texels that they never draw)."""
    if draws_light_maps(candidate, emitters):
        return {}
    unit = KINDS["light_visibility"][candidate.light_visibility]
    return {a: getattr(unit.settings(), a) for a in unit.tune.axes}


def unmeasured_axes(candidate: Candidate, metric: str) -> dict:
    """The settings of ``candidate``'s measured bias terms at their defaults where renders cannot
    measure them under ``metric`` (not a mean of squares: `SQUARED_METRICS`)."""
    if metric.split("_", 1)[1] in SQUARED_METRICS:
        return {}
    return {
        s: getattr(unit.settings(), s)
        for unit in candidate.units
        for settings in unit.tune.measured.values()
        for s in settings
    }


def term_names(candidate: Candidate, kind: str, measured: dict | None = None) -> tuple[str, ...]:
    """The terms of ``candidate``'s time or error model; the error model's end with the bias terms
    ``measured`` (`Model.measured`)."""
    if kind == "time":
        return (*TIME_TERMS, *(n for t in candidate.tunes for n in t.time_terms))
    return (*ERROR_TERMS, *(n for t in candidate.tunes for n in t.error_terms), *(measured or {}))


def time_features(candidate: Candidate, x: dict) -> list:
    """The time model's terms without their constants, for settings ``x`` (directions, resolution,
    eye paths per pixel, frames and the candidate's axes; numpy arrays or scalars)."""
    K, R, S, F = x["directions"], x["resolution"], x["spp"], x["frames"]
    lists = K * R * R * 1e-6
    return [F * 0.0 + 1.0, F, F * lists, F * S / 16.0, *(f for t in candidate.tunes for f in t.time(x))]


def error_features(candidate: Candidate, x: dict) -> list:
    """The error model's terms without their constants."""
    K, R, S, F = x["directions"], x["resolution"], x["spp"], x["frames"]
    return [
        (64.0 / R) * (64.0 / R),
        16.0 / (F * S),
        1.0 / (F * K),
        *(f for t in candidate.tunes for f in t.error(x)),
    ]


def measured_bias(table: dict, x: dict):
    """A measured bias term (`Model.measured`) at settings ``x`` (numpy arrays or scalars):
    interpolated multilinearly in the logarithms of its settings between the values measured, and
    held at the nearest value measured beyond them."""
    grid = [np.log(np.asarray(v, dtype=np.float64)) for v in table["values"]]
    at = np.broadcast_arrays(*(np.log(np.asarray(x[s], dtype=np.float64)) for s in table["settings"]))
    points = np.stack([np.clip(a, g[0], g[-1]) for a, g in zip(at, grid)], axis=-1)
    interpolate = RegularGridInterpolator(grid, np.asarray(table["bias"], dtype=np.float64))
    return interpolate(points.reshape(-1, len(grid))).reshape(at[0].shape)


@dataclass
class Model:
    """Positive constants of a sum of terms, fitted to rows; `predict` evaluates it."""

    candidate: Candidate
    kind: str  # "time" (seconds for F frames) or "error"
    constants: dict
    residuals: list  # log(predicted / measured) per calibration row
    sampler: str = "stratified"
    warning: str = ""  # what the fit could not tell from its rows
    # Error terms measured, not fitted (`TuneTerms.measured`): term -> {"settings", "values" (each
    # setting's), "bias" (what each combination adds to the metric, an array over the values)}; the
    # term's constant is 1.
    measured: dict = field(default_factory=dict)

    def terms(self, x: dict) -> list:
        # Only the candidate's own settings: a row of eye paths still records the light paths' setting,
        # and the exact maps' texels count the light paths' vertices where there are any.
        x = {k: v for k, v in x.items() if k in axes(self.candidate) or k == "frames"}
        if self.kind == "time":
            return time_features(self.candidate, x)
        features = error_features(self.candidate, {"sampler": self.sampler, **x})
        return features + [measured_bias(table, x) for table in self.measured.values()]

    @property
    def names(self) -> tuple[str, ...]:
        return term_names(self.candidate, self.kind, self.measured)

    def predict(self, x: dict):
        """Seconds for ``x["frames"]`` frames (time) or the metric after them (error), at settings
        ``x`` (the candidate's axes; numpy arrays or scalars)."""
        terms = self.terms({"frames": 1.0, **x})
        return sum(self.constants[n] * t for n, t in zip(self.names, terms))

    def rms_residual(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.residuals)))) if self.residuals else float("nan")


def fit_model(
    candidate: Candidate,
    kind: str,
    rows: list[dict],
    metric: str | None = None,
    sampler: str = "stratified",
    measured: dict | None = None,
) -> Model:
    """Fit the time model (to ``wall_s``) or the error model (to ``metric``) of ``candidate`` to its
    rows of calibration runs (their frames: ``frames_rendered``), by Dr.Jit AD on the squared log
    residuals; the error terms ``measured`` (`Model.measured`) are kept as measured."""
    measured = measured or {}
    fixed = dict.fromkeys(measured, 1.0)
    names = term_names(candidate, kind, measured)
    target_key = "wall_s" if kind == "time" else metric
    rows = [r for r in rows if Candidate.of(r) == candidate and is_number(r.get(target_key))]
    if len(rows) < len(names):
        raise InputError(
            "tune",
            f"{len(rows)} usable {candidate.name} calibration rows for the {kind} model; "
            f"it needs at least {len(names)}",
        )
    x = {a: np.array([float(r[a]) for r in rows]) for a in axes(candidate)}
    x["frames"] = F = np.array([float(r["frames_rendered"]) for r in rows])
    target = np.array([float(r[target_key]) for r in rows])
    weight = np.array([float(r.get("weight", 1.0)) for r in rows])
    if np.any(target <= 0):
        raise InputError(
            "tune", f"a {candidate.name} calibration row has {target_key} <= 0; the {kind} model needs positive values"
        )
    skeleton = Model(candidate, kind, dict.fromkeys(names, 1.0), [], sampler, measured=measured)
    features = [np.broadcast_to(np.asarray(t, dtype=np.float64), target.shape) for t in skeleton.terms(x)]
    # A render's once-only cost cannot be told from a frame's when every row rendered as many
    # frames (a budget so short that each calibration run rendered one): it is then counted per
    # frame, which over-predicts a longer render rather than under-predicting it.
    warning = ""
    fitted = list(names)
    if kind == "time" and np.all(F[0] == F):
        fitted.remove("t_once")
        warning = (
            f"every {candidate.name} calibration run rendered {F[0]:g} frame(s), so the time model counts the "
            "once-per-render cost per frame and over-predicts longer renders; a larger --calibration-share or budget "
            "separates them"
        )
    known = sum((fixed[name] * f for name, f in zip(names, features) if name in fixed), np.zeros_like(target))
    fitted = [name for name in fitted if name not in fixed]
    features = [f for name, f in zip(names, features) if name in fitted]
    log_target = np.log(target)
    # A start where every term carries an equal share of the mean target.
    start = [float(np.log(np.mean(target) / len(fitted) / max(np.mean(f), 1e-30))) for f in features]
    _, Float = drjit()
    # Converted once: converting them in every step made it 16x slower (10 s a fit).
    features_ = [Float(f) for f in features]
    known_, weight_, log_target_ = Float(known), Float(weight), Float(log_target)
    total_weight = float(weight.sum())

    def loss(dr, *log_constants):
        predicted = sum(dr.exp(c) * f for c, f in zip(log_constants, features_)) + known_
        return dr.sum(weight_ * dr.square(dr.log(predicted) - log_target_)) / total_weight

    log_constants = dict(zip(fitted, gradient_descent(loss, start, steps=3000, rate=0.05)))
    constants = {
        name: math.exp(log_constants[name]) if name in log_constants else fixed.get(name, 0.0) for name in names
    }
    model = Model(candidate, kind, constants, [], sampler, warning, measured)
    model.residuals = [float(v) for v in np.log(model.predict(x) / target)]
    return model
