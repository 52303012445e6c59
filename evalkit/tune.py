"""`evalkit tune`: the bundle settings with the least predicted error for a time budget, from
models of time and error fitted to a short calibration sweep of the scene, checked by a render.

For a scene, an image (width x height, B bounces, S eye paths per pixel per frame) and a budget of
T seconds of render time, the settings are the method, K directions, R lines per side, for
imperfect bundles N points and splat scale s, and F frames. Each model is fitted per scene and
method, to the rows of a calibration study (`evalkit.study`, so its runs are cached in the output
folder and a second call for another budget runs nothing new):

**Time** per frame (seconds; `wall_s / frames` of a row), every constant positive:

    perfect    t = t0 + t_lists K R^2 + t_dirs K
    imperfect  t = t0 + t_lists K R^2 + t_points K N + t_nodes K R^2 s^2

t0 is what does not depend on the bundles (G-buffer, shadow maps, the bounce passes at this image
size); K R^2 are the lists, K the per-direction draw (perfect), K N the splat points and K R^2 s^2
the splat nodes (a splat covers about s^2 A / (4 r^2) R^2 / N lines).

**Error** (the chosen metric, e.g. relMSE of the indirect image against the Mitsuba reference):

    perfect    E = b (64 / R)^2 + (v + w / K) / F
    imperfect  E = the same + h exp(-c s^q) + g s^2 (16384 / N)

b (64 / R)^2 is the squared O(1/R) bias of the line a path takes (docs/MEASURED_FACTS.md); v / F
the paths' variance; w / (F K) what a frame's K shared directions add (the directions study); h
the holes of the splat points, with the hole model's shape for their sampler (c, q:
studies/hole_vs_splat.toml); g s^2 / N the splats' overhang, which grows with their radius squared.

Both fits minimise the squared log residuals by gradient descent with Dr.Jit's automatic
differentiation (`evalkit.metrics.fitting`). The optimisation then takes, per method, F = T / t
and minimises log E over log K, log R, log N and s (each mapped from an unbounded variable onto
its range), by gradient descent on the same Dr.Jit models; the optimum is rounded to the
settings grid below and its neighbours on the grid are checked (the rounded setting with the
least predicted error within the budget wins). The check renders the recommendation and
measures its time and error.
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
from evalkit.study.executors import run_study
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
# The calibration sweep: (K, R, F) for perfect bundles and (K, R, N, s, F) for imperfect ones,
# spread so that every term of both models changes between rows, and two runs of 32 frames each,
# where the noise has fallen far enough for the bias terms to show: fitted to short runs alone,
# the error model put cornell-box's 60 s recommendation at half its measured error.
CALIBRATION = {
    "perfect": [(8, 64, 2), (32, 64, 8), (8, 128, 8), (32, 128, 2), (16, 96, 4), (64, 128, 4), (16, 128, 32), (32, 64, 32)],
    "imperfect": [(8, 64, 4096, 1.8, 2), (32, 128, 16384, 1.8, 8), (32, 64, 16384, 1.4, 4), (8, 128, 4096, 2.4, 8),
                  (16, 96, 8192, 1.8, 4), (32, 128, 4096, 2.2, 2), (16, 64, 16384, 2.4, 8), (64, 128, 16384, 1.6, 4),
                  (16, 128, 16384, 1.8, 32), (32, 64, 8192, 2.0, 32)],
}
TIME_TERMS = {"perfect": ("t0", "t_lists", "t_dirs"), "imperfect": ("t0", "t_lists", "t_points", "t_nodes")}
ERROR_TERMS = {"perfect": ("b", "v", "w"), "imperfect": ("b", "v", "w", "h", "g")}


def time_features(method: str, K, R, N, s) -> list:
    """The time model's terms without their constants (works on numpy arrays and Dr.Jit floats)."""
    lists = K * R * R * 1e-6
    if method == "perfect":
        return [K * 0.0 + 1.0, lists, K * 1e-3]
    return [K * 0.0 + 1.0, lists, K * N * 1e-6, lists * s * s]


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
    kind: str  # "time" (seconds per frame) or "error"
    constants: dict
    residuals: list  # log(predicted / measured) per calibration row
    sampler: str = "stratified"

    def terms(self, K, R, N, s, F=1.0, xp=np) -> list:
        if self.kind == "time":
            return time_features(self.method, K, R, N, s)
        return error_features(self.method, K, R, N, s, F, xp, self.sampler)

    def predict(self, K, R, N=16384, s=1.8, F=1.0, xp=np):
        """Seconds per frame (time) or the metric (error); numpy or Dr.Jit (``xp``) arrays."""
        values = list(self.constants.values())
        return sum(c * t for c, t in zip(values, self.terms(K, R, N, s, F, xp)))

    def rms_residual(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.residuals)))) if self.residuals else float("nan")


def fit_model(method: str, kind: str, rows: list[dict], metric: str | None = None, sampler: str = "stratified") -> Model:
    """Fit the time model (to ``wall_s / frames``) or the error model (to ``metric``) of ``method``
    to rows of calibration runs, by Dr.Jit AD on the squared log residuals."""
    names = (TIME_TERMS if kind == "time" else ERROR_TERMS)[method]
    target_key = "wall_s" if kind == "time" else metric
    rows = [r for r in rows if r.get("method") == method and is_number(r.get(target_key))]
    if len(rows) < len(names):
        raise InputError("tune", f"{len(rows)} usable {method} calibration rows for the {kind} model; it needs at least {len(names)}")
    K, R, N, s, F = (np.array([float(r[k]) for r in rows]) for k in ("directions", "resolution", "points", "splat_scale", "frames"))
    target = np.array([float(r[target_key]) for r in rows]) / (F if kind == "time" else 1.0)
    if np.any(target <= 0):
        raise InputError("tune", f"a {method} calibration row has {target_key} <= 0; the {kind} model needs positive values")
    skeleton = Model(method, kind, dict.fromkeys(names, 1.0), [], sampler)
    features = [np.broadcast_to(np.asarray(t, dtype=np.float64), target.shape) for t in skeleton.terms(K, R, N, s, F)]
    log_target = np.log(target)
    # A start where every term carries an equal share of the mean target.
    start = [float(np.log(np.mean(target) / len(names) / max(np.mean(f), 1e-30))) for f in features]
    _, Float = drjit()

    def loss(dr, *log_constants):
        predicted = sum(dr.exp(c) * Float(f) for c, f in zip(log_constants, features))
        return dr.mean(dr.square(dr.log(predicted) - Float(log_target)))

    log_constants = gradient_descent(loss, start, steps=1500, rate=0.05)
    constants = {name: math.exp(c) for name, c in zip(names, log_constants)}
    model = Model(method, kind, constants, [], sampler)
    model.residuals = [float(v) for v in np.log(model.predict(K, R, N, s, F) / target)]
    return model


@dataclass
class Recommendation:
    method: str
    settings: dict  # directions, resolution, frames (and points, splat_scale)
    predicted_time_s: float
    predicted_error: float


def optimise(time_model: Model, error_model: Model, budget: float) -> Recommendation:
    """The least predicted error within ``budget`` seconds for one method: gradient descent over
    the continuous settings (frames filling the budget), then the grid around the optimum."""
    method = time_model.method
    axes = ["directions", "resolution"] + (["points", "splat_scale"] if method == "imperfect" else [])
    cheapest = float(time_model.predict(GRID["directions"][0], GRID["resolution"][0], GRID["points"][0], GRID["splat_scale"][0]))
    if budget < cheapest:
        raise InputError("tune", f"a budget of {budget:g} s is below the cheapest {method} setting (K={GRID['directions'][0]}, "
                                 f"R={GRID['resolution'][0]}, 1 frame: {cheapest:.3g} s predicted); give at least {cheapest:.3g} s")
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
        F = budget / time_model.predict(K, R, N, s)
        return dr_.log(error_model.predict(K, R, N, s, F, xp=dr_))

    u = gradient_descent(loss, [0.0] * len(axes), steps=600, rate=0.05)
    continuous = {a: float(v) for a, v in settings_of(np, u).items()}
    best = None
    for candidate in _neighbours(continuous, axes):
        K, R = candidate["directions"], candidate["resolution"]
        N, s = candidate.get("points", 16384), candidate.get("splat_scale", 1.8)
        per_frame = float(time_model.predict(K, R, N, s))
        frames = int(budget // per_frame)
        if frames < 1:
            continue
        error = float(error_model.predict(K, R, N, s, frames))
        if best is None or error < best.predicted_error:
            best = Recommendation(method, {**candidate, "frames": frames}, frames * per_frame, error)
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


def calibration_study(scene: str, image: dict, metric: str, reference_spp: int, seed: int, methods: tuple[str, ...]):
    """The calibration sweep as a study (`evalkit.study`): its runs are cached where it runs."""
    grids = []
    for method in methods:
        for values in CALIBRATION[method]:
            keys = ("directions", "resolution", "frames") if method == "perfect" else \
                   ("directions", "resolution", "points", "splat_scale", "frames")
            grids.append({"method": method, **dict(zip(keys, values))})
    return study_from_dict({
        "name": "tune_calibration", "title": f"evalkit tune: calibration sweep of {scene}",
        "description": "Runs spread over K, R, N, splat scale and frames; the tuner fits its time and error models to them.",
        "defaults": {"scene": scene, "seed": seed, **image},
        "grid": grids,
        "measure": _measure(metric, reference_spp),
    })


def _measure(metric: str, reference_spp: int) -> dict:
    """The [measure] table of the tuner's studies: ``metric`` (IMAGE_METRIC) of one image."""
    image_name, metric_name = metric.split("_", 1)
    return {"images": [image_name], "metrics": [metric_name], "reference_spp": reference_spp}


def tune(scene: str, budget: float, method: str = "both", metric: str = "indirect_relmse", out: str | Path | None = None,
         width: int = 128, height: int = 128, bounces: int = 3, spp: int = 16, reference_spp: int = 16384, seed: int = 0,
         check: bool = True, progress=print) -> dict:
    """Recommend settings for ``scene`` within ``budget`` seconds of render time, predicted by models
    fitted to a calibration sweep, and (``check``) measure the recommendation. Returns everything
    `evalkit tune --json` prints; writes ``tune.json`` and ``report.html`` to ``out``."""
    if not (isinstance(budget, (int, float)) and math.isfinite(budget) and budget > 0):
        raise InputError("tune", f"the budget must be a positive number of seconds, got {budget}")
    if metric not in TUNE_METRICS:
        raise InputError("tune", f"unknown metric {metric!r}; known: {', '.join(TUNE_METRICS)}")
    if method not in (*METHODS, "both"):
        raise InputError("tune", f"method must be perfect, imperfect or both, got {method!r}")
    methods = METHODS if method == "both" else (method,)
    out = Path(out or f"out/tune/{Path(scene).stem}")
    image = {"width": width, "height": height, "bounces": bounces, "spp": spp}
    start = time.perf_counter()
    study = calibration_study(scene, image, metric, reference_spp, seed, methods)
    rows = run_study(study, out / "calibration", progress=progress, command=" ".join(sys.argv))
    calibration_s = sum(float(r.get("run_s") or 0.0) for r in rows)
    failed = [r for r in rows if r["status"] != "ok"]
    if failed:
        raise InputError(str(out / "calibration"), f"{len(failed)} calibration run(s) failed, first: {failed[0]['status']}")
    models = {m: {"time": fit_model(m, "time", rows), "error": fit_model(m, "error", rows, metric)} for m in methods}
    candidates = [optimise(models[m]["time"], models[m]["error"], budget) for m in methods]
    best = min(candidates, key=lambda c: c.predicted_error)
    result = {
        "scene": scene, "budget_s": budget, "metric": metric, "method": method, "image": image, "seed": seed,
        "reference_spp": reference_spp,
        "recommended": {"method": best.method, **best.settings, **image},
        "predicted": {"time_s": best.predicted_time_s, "error": best.predicted_error},
        "candidates": [{"method": c.method, **c.settings, "predicted_time_s": c.predicted_time_s, "predicted_error": c.predicted_error}
                       for c in candidates],
        "models": {m: {kind: {"constants": models[m][kind].constants, "residuals": models[m][kind].residuals,
                              "rms_log_residual": models[m][kind].rms_residual()} for kind in ("time", "error")} for m in methods},
        "calibration": {"runs": len(rows), "seconds": calibration_s, "folder": str(out / "calibration"),
                        "share_of_budget": calibration_s / budget},
        "versions": versions(),
    }
    if check:
        result["measured"] = _check(best, image, scene, metric, reference_spp, seed, out, progress)
    result["tune_s"] = time.perf_counter() - start
    result["report"] = str(out / "report.html")
    out.mkdir(parents=True, exist_ok=True)
    (out / "tune.json").write_text(json.dumps(result, indent=2) + "\n")
    write_tune_report(result, rows, models, out / "report.html")
    return result


def _check(best: Recommendation, image: dict, scene: str, metric: str, reference_spp: int, seed: int, out: Path, progress) -> dict:
    """Render the recommendation (a one-run study, cached like the calibration's) and measure it."""
    study = study_from_dict({
        "name": "tune_check", "title": f"evalkit tune: the recommendation for {scene}",
        "defaults": {"scene": scene, "seed": seed, **image, "method": best.method, **best.settings},
        "measure": _measure(metric, reference_spp),
    })
    (row,) = run_study(study, out / "check", progress=progress, command=" ".join(sys.argv))
    if row["status"] != "ok":
        raise InputError(str(out / "check"), f"the check run failed: {row['status']}")
    return {"time_s": float(row["wall_s"]), "error": float(row[metric]), "run_id": row["run_id"]}


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
        ax.plot([r["wall_s"] for r in mine], [r[metric] for r in mine], "o", color=colour, mfc="none", label=f"{method}: calibration runs")
    ax.plot([result["predicted"]["time_s"]], [result["predicted"]["error"]], "k*", ms=11, label="recommended: predicted")
    if "measured" in result:
        ax.plot([result["measured"]["time_s"]], [result["measured"]["error"]], "kX", ms=9, label="recommended: measured")
    ax.axvline(budget, color="grey", lw=0.8, ls=":")
    ax.set(xscale="log", yscale="log", xlabel="render time (s)", ylabel=metric, title=f"{result['scene']}: {metric} against time")
    ax.legend(fontsize=7)
    fig.tight_layout()
    png = path.with_suffix(".png")
    fig.savefig(png, dpi=110)
    plt.close(fig)
    rec = result["recommended"]
    measured = result.get("measured")
    lines = [
        "<!doctype html><meta charset='utf-8'><title>evalkit tune</title>",
        "<style>body{font-family:sans-serif;max-width:60em;margin:2em auto}td,th{padding:2px 8px;text-align:right}</style>",
        f"<h1>evalkit tune: {html.escape(result['scene'])}, {budget:g} s</h1>",
        f"<p>Metric {html.escape(metric)}; image {rec['width']}x{rec['height']}, {rec['bounces']} bounces, {rec['spp']} paths per pixel per frame; "
        f"calibration: {result['calibration']['runs']} runs, {result['calibration']['seconds']:.1f} s "
        f"({result['calibration']['share_of_budget']:.1f}x the budget, cached in {html.escape(result['calibration']['folder'])}).</p>",
        "<h2>Recommendation</h2><table><tr><th>setting</th><th>value</th></tr>",
        *[f"<tr><td>{html.escape(k)}</td><td>{v}</td></tr>" for k, v in rec.items()],
        "</table><table><tr><th></th><th>time (s)</th><th>error</th></tr>",
        f"<tr><td>predicted</td><td>{result['predicted']['time_s']:.3g}</td><td>{result['predicted']['error']:.4g}</td></tr>",
        *([f"<tr><td>measured</td><td>{measured['time_s']:.3g}</td><td>{measured['error']:.4g}</td></tr>"] if measured else []),
        f"</table><p><img src='{png.name}'></p><h2>Fitted models</h2>",
    ]
    for method, m in result["models"].items():
        for kind, fitted in m.items():
            constants = ", ".join(f"{k} = {v:.4g}" for k, v in fitted["constants"].items())
            residuals = ", ".join(f"{v:+.2f}" for v in fitted["residuals"])
            lines.append(f"<p><b>{method} {kind}</b>: {constants}; log residuals per run {residuals} "
                         f"(rms {fitted['rms_log_residual']:.2f})</p>")
    path.write_text("\n".join(lines) + "\n")
