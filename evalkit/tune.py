"""`evalkit tune`: the bundle settings with the least predicted error for a time budget, from
models of time and error fitted to a short calibration sweep of the scene, checked by a render.

For a scene, an image (width x height, B bounces, S eye paths per pixel per frame) and a budget of
T seconds of render time, the settings are the method, K directions, R lines per side, for
imperfect bundles N points and splat scale s, and F frames. Each model is fitted per scene and
method, to the rows of a calibration study (`evalkit.study`, so its runs are cached in the output
folder and a second call with the same budget runs nothing new):

**Time** of F frames (seconds; `wall_s` of a row), every constant positive:

    perfect    t = t_once + F (t0 + t_lists K R^2 + t_dirs K)
    imperfect  t = t_once + F (t0 + t_lists K R^2 + t_points K N + t_nodes K R^2 s^2)

t_once is what a render does once (a static scene's shadow maps, reading the images back); t0 what
a frame does that does not depend on the bundles (G-buffer, emitter samples, the bounce passes at
this image size); K R^2 are the lists, K the per-direction draw (perfect), K N the splat points and
K R^2 s^2 the splat nodes (a splat covers about s^2 A / (4 r^2) R^2 / N lines).

**Error** (the chosen metric, e.g. relMSE of the indirect image against the Mitsuba reference):

    perfect    E = b (64 / R)^2 + (v + w / K) / F
    imperfect  E = the same + h exp(-c s^q) + g s^2 (16384 / N)

b (64 / R)^2 is the squared O(1/R) bias of the line a path takes (docs/MEASURED_FACTS.md); v / F
the paths' variance; w / (F K) what a frame's K shared directions add (the directions study); h
the holes of the splat points, with the hole model's shape for their sampler (c, q:
studies/hole_vs_splat.toml); g s^2 / N the splats' overhang, which grows with their radius squared.

Both fits minimise the squared log residuals by gradient descent with Dr.Jit's automatic
differentiation (`evalkit.metrics.fitting`). The calibration costs about ``calibration_share`` times
the budget: each of its runs renders frames until its share of that time is spent (the renderer's
``time_budget``), at least one, so a larger budget calibrates with more frames, where the bias
terms it must then predict show through the noise. Half of that time goes to runs spread over the
settings; the other half renders each method's first optimum, which then anchors the refit
(`SPREAD`). The optimisation takes, per method, the frames that fill the budget,
F = (T - t_once) / (time per frame), and minimises log E over log K, log R, log N and s (each
mapped from an unbounded variable onto its range), by gradient descent on the same Dr.Jit models;
the optimum is rounded to the settings grid below and its neighbours on the grid are checked (the
rounded setting with the least predicted error within the budget wins). The check renders each
method's optimum and measures its time and error; the recommendation is the one with the least
measured error (without the check: the least predicted error). Between methods the choice is left
to the measurement because the models' residuals are as large as the predicted differences: at
atrium's 10 s the perfect optimum was predicted 6 % better than the imperfect one and measured
26 % worse.
"""

from __future__ import annotations

import html
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evalkit.core.errors import InputError
from evalkit.metrics.fitting import drjit, gradient_descent
from evalkit.metrics.images import METRICS
from evalkit.report import is_number
from evalkit.study.executors import read_rows, run_study
from evalkit.study.run import versions
from evalkit.study.spec import study_from_dict

IMAGES = ("direct", "indirect", "total")
TUNE_METRICS = tuple(f"{image}_{metric}" for image in IMAGES for metric in METRICS)
METHODS = ("perfect", "imperfect")
# The settings the recommendation is rounded to (and their ranges for the optimisation). No
# fewer than 8 directions: a path never takes the bundle it arrived along, and at K = 4 that is a
# bias no term of the error model has (an open stage's indirect light -13 %,
# docs/MEASURED_FACTS.md); atrium's 10 s recommendation at K = 4 measured twice its prediction.
GRID = {
    "directions": [8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256],
    "resolution": [32, 48, 64, 96, 128, 192, 256],
    "points": [1024, 2048, 4096, 8192, 16384, 32768, 65536],
    "splat_scale": [1.2, 1.4, 1.6, 1.8, 2.0, 2.2, 2.4, 2.6],
}
# The hole model's shape per sampler, P(hole) ~ exp(-c s^q) (studies/hole_vs_splat.toml on
# cornell-box, docs/MEASURED_FACTS.md).
HOLE_SHAPE = {"stratified": (1.26, 2.42), "random": (0.99, 1.95)}
# The calibration sweep: (K, R) for perfect bundles and (K, R, N, s) for imperfect ones, spread
# over the grid so that every term of both models changes between rows. The last two of each
# method have LONG shares of the calibration time: runs where the noise has fallen far enough for
# the bias terms to show (fitted to short runs alone, the error model put cornell-box's 60 s
# recommendation at half its measured error).
CALIBRATION = {
    "perfect": [(8, 64), (32, 64), (8, 128), (32, 128), (16, 96), (64, 128), (8, 192), (16, 256), (16, 128), (32, 64)],
    "imperfect": [
        (8, 64, 4096, 1.8),
        (32, 128, 16384, 1.8),
        (32, 64, 16384, 1.4),
        (8, 128, 4096, 2.4),
        (16, 96, 8192, 1.8),
        (32, 128, 4096, 2.2),
        (16, 64, 16384, 2.4),
        (64, 128, 16384, 1.6),
        (8, 96, 65536, 2.2),
        (16, 64, 32768, 1.6),
        (8, 192, 32768, 2.0),
        (16, 128, 65536, 1.8),
        (32, 64, 8192, 2.0),
    ],
}
LONG = 3  # the share of each method's last two calibration runs, in units of the others'
CALIBRATION_SHARE = 2.0  # the calibration's render time, in budgets (each run renders at least one frame)
# The part of it that the spread runs share; the rest renders each method's first optimum, which
# then weighs as much as half the spread runs in the refit: a model of a few terms is least wrong
# where the decision is made, and the error model's bias terms extrapolate badly (atrium's
# holes and overhang grow fast below N = 16384, its 10 s recommendation measured 13x its
# prediction from the spread runs alone).
SPREAD = 0.5
MAX_FRAMES = 100_000  # a calibration run's frame limit: its time budget ends it long before
TIME_TERMS = {
    "perfect": ("t_once", "t0", "t_lists", "t_dirs"),
    "imperfect": ("t_once", "t0", "t_lists", "t_points", "t_nodes"),
}
ERROR_TERMS = {"perfect": ("b", "v", "w"), "imperfect": ("b", "v", "w", "h", "g")}


def time_features(method: str, K, R, N, s, F) -> list:
    """The time model's terms without their constants (works on numpy arrays and Dr.Jit floats)."""
    lists = K * R * R * 1e-6
    per_frame = (
        [F, F * lists, F * K * 1e-3] if method == "perfect" else [F, F * lists, F * K * N * 1e-6, F * lists * s * s]
    )
    return [F * 0.0 + 1.0, *per_frame]


def error_features(method: str, K, R, N, s, F, xp=np, sampler: str = "stratified") -> list:
    """The error model's terms without their constants; ``xp`` (numpy or drjit) gives exp and log."""
    terms = [(64.0 / R) * (64.0 / R), 1.0 / F, 1.0 / (F * K)]
    if method == "imperfect":
        c, q = HOLE_SHAPE[sampler]
        terms += [xp.exp(-c * xp.exp(q * xp.log(s))), s * s * 16384.0 / N]
    return terms


@dataclass
class Model:
    """Positive constants of a sum of terms, fitted to rows; `predict` evaluates it."""

    method: str
    kind: str  # "time" (seconds for F frames) or "error"
    constants: dict
    residuals: list  # log(predicted / measured) per calibration row
    sampler: str = "stratified"
    warning: str = ""  # what the fit could not tell from its rows

    def terms(self, K, R, N, s, F=1.0, xp=np) -> list:
        if self.kind == "time":
            return time_features(self.method, K, R, N, s, F)
        return error_features(self.method, K, R, N, s, F, xp, self.sampler)

    def predict(self, K, R, N=16384, s=1.8, F=1.0, xp=np):
        """Seconds for F frames (time) or the metric after F frames (error); numpy or Dr.Jit (``xp``) arrays."""
        values = list(self.constants.values())
        return sum(c * t for c, t in zip(values, self.terms(K, R, N, s, F, xp)))

    def rms_residual(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.residuals)))) if self.residuals else float("nan")


def fit_model(
    method: str, kind: str, rows: list[dict], metric: str | None = None, sampler: str = "stratified"
) -> Model:
    """Fit the time model (to ``wall_s``) or the error model (to ``metric``) of ``method`` to rows of
    calibration runs (their frames: ``frames_rendered``), by Dr.Jit AD on the squared log residuals."""
    names = (TIME_TERMS if kind == "time" else ERROR_TERMS)[method]
    target_key = "wall_s" if kind == "time" else metric
    rows = [r for r in rows if r.get("method") == method and is_number(r.get(target_key))]
    if len(rows) < len(names):
        raise InputError(
            "tune", f"{len(rows)} usable {method} calibration rows for the {kind} model; it needs at least {len(names)}"
        )
    K, R, N, s = (np.array([float(r[k]) for r in rows]) for k in ("directions", "resolution", "points", "splat_scale"))
    F = np.array([float(r["frames_rendered"]) for r in rows])
    target = np.array([float(r[target_key]) for r in rows])
    weight = np.array([float(r.get("weight", 1.0)) for r in rows])
    if np.any(target <= 0):
        raise InputError(
            "tune", f"a {method} calibration row has {target_key} <= 0; the {kind} model needs positive values"
        )
    skeleton = Model(method, kind, dict.fromkeys(names, 1.0), [], sampler)
    features = [np.broadcast_to(np.asarray(t, dtype=np.float64), target.shape) for t in skeleton.terms(K, R, N, s, F)]
    # A render's once-only cost cannot be told from a frame's when every row rendered as many
    # frames (a budget so short that each calibration run rendered one): it is then counted per
    # frame, which over-predicts a longer render rather than under-predicting it.
    warning = ""
    fitted = list(names)
    if kind == "time" and np.all(F[0] == F):
        fitted.remove("t_once")
        warning = (
            f"every {method} calibration run rendered {F[0]:g} frame(s), so the time model counts the once-per-render "
            f"cost per frame and over-predicts longer renders; a larger --calibration-share or budget separates them"
        )
    features = [f for name, f in zip(names, features) if name in fitted]
    log_target = np.log(target)
    # A start where every term carries an equal share of the mean target.
    start = [float(np.log(np.mean(target) / len(fitted) / max(np.mean(f), 1e-30))) for f in features]
    _, Float = drjit()

    def loss(dr, *log_constants):
        predicted = sum(dr.exp(c) * Float(f) for c, f in zip(log_constants, features))
        return dr.sum(Float(weight) * dr.square(dr.log(predicted) - Float(log_target))) / float(weight.sum())

    log_constants = dict(zip(fitted, gradient_descent(loss, start, steps=1500, rate=0.05)))
    constants = {name: math.exp(log_constants[name]) if name in log_constants else 0.0 for name in names}
    model = Model(method, kind, constants, [], sampler, warning)
    model.residuals = [float(v) for v in np.log(model.predict(K, R, N, s, F) / target)]
    return model


@dataclass
class Recommendation:
    method: str
    settings: dict  # directions, resolution, frames (and points, splat_scale)
    predicted_time_s: float
    predicted_error: float

    def as_dict(self) -> dict:
        return {
            "method": self.method,
            **self.settings,
            "predicted_time_s": self.predicted_time_s,
            "predicted_error": self.predicted_error,
        }


def optimise(time_model: Model, error_model: Model, budget: float) -> Recommendation:
    """The least predicted error within ``budget`` seconds for one method: gradient descent over
    the continuous settings (frames filling the budget), then the grid around the optimum."""
    method = time_model.method
    axes = ["directions", "resolution"] + (["points", "splat_scale"] if method == "imperfect" else [])
    t_once = time_model.constants["t_once"]

    def frame_time(K, R, N, s):
        return time_model.predict(K, R, N, s, 1.0) - t_once

    cheapest = float(
        time_model.predict(GRID["directions"][0], GRID["resolution"][0], GRID["points"][0], GRID["splat_scale"][0], 1)
    )
    if budget < cheapest:
        raise InputError(
            "tune",
            f"a budget of {budget:g} s is below the cheapest {method} setting (K={GRID['directions'][0]}, "
            f"R={GRID['resolution'][0]}, 1 frame: {cheapest:.3g} s predicted); give at least {cheapest:.3g} s",
        )
    _, Float = drjit()
    lo = {a: GRID[a][0] for a in axes}
    hi = {a: GRID[a][-1] for a in axes}
    logarithmic = {"directions", "resolution", "points"}

    def settings_of(dr_, u: list) -> dict:
        out = {}
        for a, x in zip(axes, u):
            t = 1.0 / (1.0 + dr_.exp(-x))
            if a in logarithmic:
                out[a] = dr_.exp(math.log(lo[a]) + (math.log(hi[a]) - math.log(lo[a])) * t)
            else:
                out[a] = lo[a] + (hi[a] - lo[a]) * t
        return out

    def loss(dr_, *u):
        x = settings_of(dr_, list(u))
        K, R = x["directions"], x["resolution"]
        N, s = x.get("points", Float(16384.0)), x.get("splat_scale", Float(1.8))
        F = (budget - t_once) / frame_time(K, R, N, s)
        return dr_.log(error_model.predict(K, R, N, s, F, xp=dr_))

    u = gradient_descent(loss, [0.0] * len(axes), steps=600, rate=0.05)
    continuous = {a: float(v) for a, v in settings_of(np, u).items()}
    best = None
    for candidate in _neighbours(continuous, axes):
        K, R = candidate["directions"], candidate["resolution"]
        N, s = candidate.get("points", 16384), candidate.get("splat_scale", 1.8)
        frames = int((budget - t_once) // float(frame_time(K, R, N, s)))
        if frames < 1:
            continue
        error = float(error_model.predict(K, R, N, s, frames))
        if best is None or error < best.predicted_error:
            best = Recommendation(
                method, {**candidate, "frames": frames}, float(time_model.predict(K, R, N, s, frames)), error
            )
    if best is None:  # the continuous optimum's neighbours all cost over a frame of the budget
        raise InputError("tune", f"no {method} setting near the optimum fits {budget:g} s; give a larger budget")
    return best


def _neighbours(continuous: dict, axes: list[str]) -> list[dict]:
    """Every combination of the two grid values around each continuous setting and the next one
    out on either side."""
    choices = []
    for a in axes:
        grid = GRID[a]
        i = int(np.searchsorted(grid, continuous[a]))
        choices.append(sorted({grid[j] for j in range(i - 2, i + 2) if 0 <= j < len(grid)}))
    combos = [{}]
    for a, values in zip(axes, choices):
        combos = [{**c, a: v} for c in combos for v in values]
    return combos


def calibration_grid(methods: tuple[str, ...], seconds: float) -> list[dict]:
    """The calibration sweep's runs, each with its share of ``seconds`` as its time budget."""
    shares = {m: [1] * (len(CALIBRATION[m]) - 2) + [LONG] * 2 for m in methods}
    unit = seconds / sum(sum(v) for v in shares.values())
    grid = []
    for method in methods:
        keys = (
            ("directions", "resolution")
            if method == "perfect"
            else ("directions", "resolution", "points", "splat_scale")
        )
        for values, share in zip(CALIBRATION[method], shares[method]):
            grid.append(
                {
                    "method": method,
                    **dict(zip(keys, values)),
                    "time_budget": round(share * unit, 3),
                    "frames": MAX_FRAMES,
                }
            )
    return grid


@dataclass
class TunerStudies:
    """The tuner's runs of one scene and image: each set of them a study (`evalkit.study`, cached) in
    its own folder under ``out``, all measured against one reference (rendered once into
    ``out``/references unless the committed store has it)."""

    defaults: dict  # scene, seed and the image
    metric: str  # IMAGE_METRIC
    reference_spp: int
    out: Path
    progress: object = print

    def run(self, name: str, grid: list[dict]) -> list[dict]:
        """The rows of the runs ``grid`` (in ``out``/``name``); a failed run is an error naming the folder."""
        image, metric = self.metric.split("_", 1)
        study = study_from_dict(
            {
                "name": f"tune_{name}",
                "title": f"evalkit tune: {name} runs of {self.defaults['scene']}",
                "defaults": self.defaults,
                "grid": grid,
                "measure": {
                    "images": [image],
                    "metrics": [metric],
                    "reference_spp": self.reference_spp,
                    "reference_store": str(self.out / "references"),
                },
            }
        )
        rows = run_study(study, self.out / name, progress=self.progress, command=" ".join(sys.argv))
        failed = [r for r in rows if r["status"] != "ok"]
        if failed:
            raise InputError(
                str(self.out / name), f"{len(failed)} of the tuner's runs failed, first: {failed[0]['status']}"
            )
        return rows


def tune(
    scene: str,
    budget: float,
    method: str = "both",
    metric: str = "indirect_relmse",
    out: str | Path | None = None,
    width: int = 128,
    height: int = 128,
    bounces: int = 3,
    spp: int = 16,
    reference_spp: int = 16384,
    seed: int = 0,
    calibration_share: float = CALIBRATION_SHARE,
    check: bool = True,
    grid: str | Path | None = None,
    progress=print,
) -> dict:
    """Recommend settings for ``scene`` within ``budget`` seconds of render time, predicted by models
    fitted to a calibration sweep of about ``calibration_share`` x ``budget`` seconds of render time,
    and (``check``) measure the recommendation; ``grid``: a study's folder to compare it with
    (`compare_with_grid`). Returns everything `evalkit tune --json` prints; writes ``tune.json``
    and ``report.html`` to ``out``."""
    if not (isinstance(budget, (int, float)) and math.isfinite(budget) and budget > 0):
        raise InputError("tune", f"the budget must be a positive number of seconds, got {budget}")
    if metric not in TUNE_METRICS:
        raise InputError("tune", f"unknown metric {metric!r}; known: {', '.join(TUNE_METRICS)}")
    if method not in (*METHODS, "both"):
        raise InputError("tune", f"method must be perfect, imperfect or both, got {method!r}")
    if not (isinstance(calibration_share, (int, float)) and math.isfinite(calibration_share) and calibration_share > 0):
        raise InputError("tune", f"the calibration share must be a positive number of budgets, got {calibration_share}")
    if grid is not None and not (Path(grid) / "results.jsonl").is_file():
        raise InputError(
            str(grid), "no results.jsonl: run the grid study first (evalkit study studies/tune_check.toml)"
        )
    methods = METHODS if method == "both" else (method,)
    out = Path(out or f"out/tune/{Path(scene).stem}")
    image = {"width": width, "height": height, "bounces": bounces, "spp": spp}
    start = time.perf_counter()
    studies = TunerStudies({"scene": scene, "seed": seed, **image}, metric, reference_spp, out, progress)
    seconds = calibration_share * budget
    rows = studies.run("calibration", calibration_grid(methods, SPREAD * seconds))
    models = {m: _fit(m, rows, metric) for m in methods}
    first = {m: optimise(models[m]["time"], models[m]["error"], budget) for m in methods}
    share = round((1 - SPREAD) * seconds / len(methods), 3)
    anchors = studies.run(
        "refinement",
        [{**c.settings, "method": m, "frames": MAX_FRAMES, "time_budget": share} for m, c in first.items()],
    )
    rows += [{**r, "weight": len(CALIBRATION[r["method"]]) / 2} for r in anchors]
    models = {m: _fit(m, rows, metric) for m in methods}
    candidates = [optimise(models[m]["time"], models[m]["error"], budget) for m in methods]
    measured = {}
    if check:
        # Every method's candidate is rendered and the least measured error wins: between methods
        # the models' residuals (0.1-0.3 in log) are as large as the predicted differences.
        checked = studies.run("check", [{"method": c.method, **c.settings} for c in candidates])
        measured = {
            r["method"]: {"time_s": float(r["wall_s"]), "error": float(r[metric]), "run_id": r["run_id"]}
            for r in checked
        }
        best = min(candidates, key=lambda c: measured[c.method]["error"])
    else:
        best = min(candidates, key=lambda c: c.predicted_error)
    result = {
        "scene": scene,
        "budget_s": budget,
        "metric": metric,
        "method": method,
        "image": image,
        "seed": seed,
        "reference_spp": reference_spp,
        "recommended": {"method": best.method, **best.settings, **image},
        "predicted": {"time_s": best.predicted_time_s, "error": best.predicted_error},
        "chosen_by": "measured error" if check else "predicted error",
        "candidates": [{**c.as_dict(), **({"measured": measured[c.method]} if check else {})} for c in candidates],
        **({"measured": measured[best.method]} if check else {}),
        "models": {
            m: {
                kind: {
                    "constants": models[m][kind].constants,
                    "residuals": models[m][kind].residuals,
                    "rms_log_residual": models[m][kind].rms_residual(),
                }
                for kind in ("time", "error")
            }
            for m in methods
        },
        "first_optimum": [c.as_dict() for c in first.values()],
        "warnings": [model.warning for m in methods for model in models[m].values() if model.warning],
        "calibration": {
            "runs": len(rows),
            "share": calibration_share,
            "render_s": sum(float(r["wall_s"]) for r in rows),
            "run_s": sum(float(r["run_s"]) for r in rows),
            "folders": [str(out / "calibration"), str(out / "refinement")],
        },
        "versions": versions(),
    }
    if grid is not None:
        result["grid"] = compare_with_grid(result, Path(grid))
    result["tune_s"] = time.perf_counter() - start
    result["report"] = str(out / "report.html")
    out.mkdir(parents=True, exist_ok=True)
    (out / "tune.json").write_text(json.dumps(result, indent=2) + "\n")
    write_tune_report(result, rows, models, out / "report.html")
    return result


def _fit(method: str, rows: list[dict], metric: str) -> dict:
    return {"time": fit_model(method, "time", rows), "error": fit_model(method, "error", rows, metric)}


def compare_with_grid(result: dict, folder: Path) -> dict:
    """The best run of a grid study (studies/tune_check.toml) of the tuner's scene and image within
    its budget (a ``time_budget`` run of that budget), beside the recommendation's measured error."""
    metric, budget = result["metric"], result["budget_s"]
    rows = read_rows(folder)
    if not rows:
        raise InputError(
            str(folder), "no results.jsonl rows: run the grid study first (evalkit study studies/tune_check.toml)"
        )
    same = [
        r
        for r in rows
        if r["status"] == "ok"
        and Path(r["scene"]).stem == Path(result["scene"]).stem
        and r.get("time_budget") == budget
        and all(r.get(k) == v for k, v in result["image"].items())
        and is_number(r.get(metric))
        and r["wall_s"] <= budget
    ]
    if not same:
        image = result["image"]
        raise InputError(
            str(folder),
            f"no run of {result['scene']} at {image['width']}x{image['height']}, {image['bounces']} bounces, "
            f"{image['spp']} spp with time_budget = {budget:g} measured {metric} within it",
        )
    best = min(same, key=lambda r: r[metric])
    keys = ("method", "directions", "resolution", "frames_rendered") + (
        ("points", "splat_scale") if best["method"] == "imperfect" else ()
    )
    out = {
        "folder": str(folder),
        "runs": len(same),
        "best": {**{k: best[k] for k in keys}, "time_s": best["wall_s"], "error": best[metric]},
    }
    if "measured" in result:
        out["ratio"] = result["measured"]["error"] / best[metric]
    return out


def write_tune_report(result: dict, rows: list[dict], models: dict, path: Path) -> None:
    """report.html: predicted error-versus-time fronts beside the measured rows and the check, the
    fitted constants and their residuals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metric, budget = result["metric"], result["budget_s"]
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    # Nine budgets a factor 2 apart: each is a whole optimisation (about 0.1 s).
    budgets = np.geomspace(budget / 16, budget * 16, 9)
    for i, (method, m) in enumerate(models.items()):
        colour = f"C{i}"
        front = []
        for b in budgets:
            try:
                front.append((b, optimise(m["time"], m["error"], float(b)).predicted_error))
            except InputError:
                continue
        if front:
            ax.plot(*zip(*front), "-", color=colour, label=f"{method}: predicted front")
        mine = [r for r in rows if r["method"] == method]
        ax.plot(
            [r["wall_s"] for r in mine],
            [r[metric] for r in mine],
            "o",
            color=colour,
            mfc="none",
            label=f"{method}: calibration runs",
        )
        for c in (c for c in result["candidates"] if c["method"] == method):
            ax.plot(
                [c["predicted_time_s"]],
                [c["predicted_error"]],
                "*",
                color=colour,
                ms=11,
                label=f"{method} optimum: predicted",
            )
            if "measured" in c:
                ax.plot(
                    [c["measured"]["time_s"]],
                    [c["measured"]["error"]],
                    "X",
                    color=colour,
                    ms=9,
                    label=f"{method} optimum: measured",
                )
    ax.axvline(budget, color="grey", lw=0.8, ls=":")
    ax.set(
        xscale="log",
        yscale="log",
        xlabel="render time (s)",
        ylabel=metric,
        title=f"{result['scene']}: {metric} against time",
    )
    ax.legend(fontsize=7)
    fig.tight_layout()
    png = path.with_suffix(".png")
    fig.savefig(png, dpi=110)
    plt.close(fig)
    rec, calibration = result["recommended"], result["calibration"]
    grid = result.get("grid")
    lines = [
        "<!doctype html><meta charset='utf-8'><title>evalkit tune</title>",
        "<style>body{font-family:sans-serif;max-width:60em;margin:2em auto}td,th{padding:2px 8px;text-align:right}</style>",
        f"<h1>evalkit tune: {html.escape(result['scene'])}, {budget:g} s</h1>",
        f"<p>Metric {html.escape(metric)}; image {rec['width']}x{rec['height']}, {rec['bounces']} bounces, {rec['spp']} paths per pixel per frame; "
        f"calibration: {calibration['runs']} runs, {calibration['render_s']:.1f} s of render time ({calibration['render_s'] / budget:.2f}x "
        f"the budget; asked for {calibration['share']:g}x), {calibration['run_s']:.1f} s with loading and measuring, "
        f"cached in {html.escape(' and '.join(calibration['folders']))}.</p>",
        "<h2>Recommendation</h2><table><tr><th>setting</th><th>value</th></tr>",
        *[f"<tr><td>{html.escape(k)}</td><td>{v}</td></tr>" for k, v in rec.items()],
        f"</table><p>Each method's optimum, chosen between by {html.escape(result['chosen_by'])}:</p>",
        "<table><tr><th>candidate</th><th>predicted time (s)</th><th>predicted error</th><th>measured time (s)</th><th>measured error</th></tr>",
        *[
            f"<tr><td>{html.escape(settings_text(c))}</td><td>{c['predicted_time_s']:.3g}</td><td>{c['predicted_error']:.4g}</td>"
            + (
                f"<td>{c['measured']['time_s']:.3g}</td><td>{c['measured']['error']:.4g}</td>"
                if "measured" in c
                else "<td></td><td></td>"
            )
            + "</tr>"
            for c in result["candidates"]
        ],
        *(
            [
                f"<tr><td>best of {grid['runs']} grid runs: {html.escape(settings_text(grid['best']))}</td><td></td><td></td>"
                f"<td>{grid['best']['time_s']:.3g}</td><td>{grid['best']['error']:.4g}</td></tr>"
            ]
            if grid
            else []
        ),
        f"</table><p><img src='{png.name}'></p><h2>Fitted models</h2>",
        *[f"<p><b>Warning</b>: {html.escape(w)}</p>" for w in result["warnings"]],
    ]
    for method, m in result["models"].items():
        for kind, fitted in m.items():
            constants = ", ".join(f"{k} = {v:.4g}" for k, v in fitted["constants"].items())
            residuals = ", ".join(f"{v:+.2f}" for v in fitted["residuals"])
            lines.append(
                f"<p><b>{method} {kind}</b>: {constants}; log residuals per run {residuals} "
                f"(rms {fitted['rms_log_residual']:.2f})</p>"
            )
    path.write_text("\n".join(lines) + "\n")


def settings_text(settings: dict) -> str:
    """'perfect K=8 R=256 F=22' and so on, from a candidate's or a grid row's settings."""
    short = {
        "directions": "K",
        "resolution": "R",
        "points": "N",
        "splat_scale": "s",
        "frames": "F",
        "frames_rendered": "F",
    }
    return " ".join([settings["method"], *(f"{short[k]}={v}" for k, v in settings.items() if k in short)])
