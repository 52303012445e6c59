"""The tuner's runs and its answer: the calibration sweep, the refinement that anchors the models
where the decision is made, the check that renders each candidate's optimum, and `tune`, which does
all of it (evalkit/tune/__init__.py says why each step is there)."""

from __future__ import annotations

import itertools
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evalkit.core.atomic import write_text
from evalkit.core.errors import InputError, LimitError
from evalkit.core.exr import read_exr
from evalkit.core.scene import load_scene
from evalkit.metrics.images import RELMSE_EPSILON
from evalkit.pages import is_number
from evalkit.study.executors import read_rows, run_study
from evalkit.study.run import versions
from evalkit.study.spec import make_run, run_id, study_from_dict
from evalkit.tune.models import (
    CALIBRATION_SPP,
    SQUARED_METRICS,
    TUNE_METRICS,
    Candidate,
    axes,
    draws_light_maps,
    fit_model,
    idle_axes,
    unmeasured_axes,
)
from evalkit.tune.optimise import Recommendation, optimise
from evalkit.tune.report import settings_text, write_tune_report
from gpu_impl.registry import KINDS, settings_symbols
from references.mitsuba import load_reference

# The last two calibration runs of each candidate have LONG shares of the calibration time: runs where
# the noise has fallen far enough for the bias terms to show (fitted to short runs alone, the
# error model put cornell-box's 60 s recommendation at half its measured error).
LONG = 3
CALIBRATION_SHARE = 2.0  # the calibration's render time, in budgets (each run renders at least one frame)
# The part of it that the spread runs share; the rest renders each candidate's first optimum, which
# then weighs as much as half the spread runs in the refit: a model of a few terms is least wrong
# where the decision is made, and the error model's bias terms extrapolate badly (atrium's
# holes and overhang grow fast below N = 16384, its 10 s recommendation measured 13x its
# prediction from the spread runs alone).
SPREAD = 0.5
MAX_FRAMES = 100_000  # a calibration run's frame limit: its time budget ends it long before
# A recommendation keeps the budget: a checked optimum measured over it by more than a run's timing
# noise loses to one that kept it, whatever its error (cornell-box's 10 s: bidirectional paths
# predicted at 9.96 s measured 12.9 s, 0.87x the error of eye paths that kept the budget).
BUDGET_TOLERANCE = 0.1
# How many times a checked optimum that overran is rendered again with the frames its measured time
# fits. Once left little room: on lit-room at 2 s the bidirectional checks that count measure
# 1.8-2.1 s (the tolerance ends at 2.2 s), and in one CI run eye paths, with 40x the error of
# bidirectional ones, were recommended, as when every bidirectional optimum overran twice.
RERENDERS = 3
# The seeds of the renders that measure a bias term (`TuneTerms.measured`): two, so that their noise
# is independent and the estimate unbiased (`measure_bias`).
BIAS_SEEDS = 2
# The status prefix of a run whose settings the renderer refused before rendering (`LimitError`);
# its row names the settings at fault in ``limit_settings`` (evalkit/study/run.py).
REFUSED = f"error: {LimitError.__name__}: "


def calibration_grid(candidates: list[Candidate], seconds: float, spp: tuple[int, ...] = CALIBRATION_SPP) -> list[dict]:
    """The calibration sweep's runs (each candidate's `Candidate.calibration`, with the eye paths per
    pixel ``spp`` in turn), each with its share of ``seconds`` as its time budget."""
    runs = {c: c.calibration() for c in candidates}
    shares = {c: [1] * (len(runs[c]) - 2) + [LONG] * 2 for c in candidates}
    unit = seconds / sum(sum(v) for v in shares.values())
    # Counted from the first long run, so that the long runs take the first values of ``spp``.
    return [
        {
            **settings,
            "spp": spp[(i + 2 - len(runs[c])) % len(spp)],
            "time_budget": round(share * unit, 3),
            "frames": MAX_FRAMES,
        }
        for c in candidates
        for i, (settings, share) in enumerate(zip(runs[c], shares[c]))
    ]


def bias_runs(candidate: Candidate, idle: dict, spp: int, seed: int) -> list[tuple[str, dict, list[dict]]]:
    """Per error term of ``candidate`` that renders measure (`TuneTerms.measured`; not those of its
    ``idle`` settings): the term, its table to fill (`Model.measured`: its settings and their
    values) and its runs, for each of `BIAS_SEEDS` seeds from ``seed``: the candidate's first
    calibration run with ``spp`` paths at every combination of the settings' values, then with the
    settings ``unbiased`` where the unit gives them (otherwise the last combination, every setting
    at its largest value, is the one compared with). The first seed's runs render one frame, the
    next seed's two: beside calibration runs that render one frame each (a short budget), that lets
    the time model tell the once-per-render cost from a frame's."""
    sweeps = []
    base = {**candidate.calibration()[0], "spp": spp, "time_budget": 0.0}
    for unit in candidate.units:
        for term, settings in unit.tune.measured.items():
            if any(s in idle for s in settings):
                continue
            values = [axes(candidate)[s] for s in settings]
            runs = [{**base, **dict(zip(settings, v))} for v in itertools.product(*values)]
            if unit.tune.unbiased:  # another unit's run: without this one's settings
                runs.append({**{k: v for k, v in base.items() if k not in unit.option_names()}, **unit.tune.unbiased})
            runs = [{**run, "seed": seed + i, "frames": i + 1} for i in range(BIAS_SEEDS) for run in runs]
            sweeps.append((term, {"settings": list(settings), "values": values}, runs))
    return sweeps


def measure_bias(images: list[list[np.ndarray]], reference: np.ndarray, metric: str) -> list[float]:
    """What each render's settings add to the metric over those of the last render, once the noise
    has gone: from renders at two seeds (``images[i][j]``: seed i, setting j, the one compared with
    last; the metric's image). At one seed the renders take the same paths, so their difference D
    from the last render is the difference of their biases plus what noise the settings themselves
    add; E = the last render - ``reference`` is its bias plus noise. The metric then grows by
    D^2 + 2 D E in the limit, and D1 D2 + D1 E2 + D2 E1, with seeds 1 and 2 independent, is an
    unbiased estimate of it (normalised as the metric is). Settings whose bias cancels another (a
    leak brightening an image that is too dark) are given no credit: at least 0."""
    name = metric.split("_", 1)[1]
    ref = reference.astype(np.float64)
    norm = np.square(ref) + RELMSE_EPSILON if name == "relmse" else 1.0
    (a1, a2) = ([im.astype(np.float64) for im in seed] for seed in images)
    e1, e2 = a1[-1] - ref, a2[-1] - ref
    grows = []
    for m1, m2 in zip(a1, a2):
        d1, d2 = m1 - a1[-1], m2 - a2[-1]
        grows.append(max(0.0, float(np.mean((d1 * d2 + d1 * e2 + d2 * e1) / norm))))
    return grows


@dataclass
class TunerStudies:
    """The tuner's runs of one scene and image: each set of them a study (`evalkit.study`, cached) in
    its own folder under ``out``, all measured against one reference (rendered once into
    ``out``/references unless the committed store has it)."""

    defaults: dict  # scene, seed, the image and the pinned settings
    metric: str  # IMAGE_METRIC
    reference_spp: int
    out: Path
    progress: object = print

    def run(self, name: str, grid: list[dict], refusals: bool = False) -> list[dict]:
        """The rows of the runs ``grid`` (in ``out``/``name``), one per run in its order (runs whose
        settings are the same once their defaults are filled in are rendered once and share a row); a
        failed run is an error naming the folder, except, with ``refusals``, one whose settings the
        renderer refused (a row with ``limit_settings``)."""
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
        failed = [r for r in rows if r["status"] != "ok" and not (refusals and "limit_settings" in r)]
        if failed:
            raise InputError(
                str(self.out / name), f"{len(failed)} of the tuner's runs failed, first: {failed[0]['status']}"
            )
        by_id = {r["run_id"]: r for r in rows}
        return [by_id[run_id(make_run(run, self.defaults, name))] for run in grid]


def tune(
    scene: str,
    budget: float,
    method: str = "both",
    strategy: str | None = None,
    light_visibility: str | None = None,
    metric: str = "indirect_relmse",
    out: str | Path | None = None,
    width: int = 128,
    height: int = 128,
    bounces: int = 3,
    spp: int | None = 16,
    reference_spp: int = 16384,
    seed: int = 0,
    calibration_share: float = CALIBRATION_SHARE,
    check: bool = True,
    grid: str | Path | None = None,
    pin: dict | None = None,
    progress=print,
) -> dict:
    """Recommend settings for ``scene`` within ``budget`` seconds of render time, predicted by models
    fitted to a calibration sweep of about ``calibration_share`` x ``budget`` seconds of render time,
    among the candidates of ``method``, ``strategy`` and ``light_visibility`` (each a registered
    unit's name, or "both" for every registered one; the strategy and light visibility default to
    the default units), with ``spp`` eye paths per pixel per frame (None: tuned as well:
    on atrium and cornell-box no better than 16, and worse at short budgets, docs/reference/studies.md),
    and (``check``) measure the recommendation; ``grid``: a study's folder to compare it with
    (`compare_with_grid`); ``pin``: settings the optimiser keeps at the values given (`pins`).
    Returns everything `evalkit tune --json` prints; writes ``tune.json`` and ``report.html`` to
    ``out``."""
    if not (isinstance(budget, (int, float)) and math.isfinite(budget) and budget > 0):
        raise InputError("tune", f"the budget must be a positive number of seconds, got {budget}")
    if metric not in TUNE_METRICS:
        raise InputError("tune", f"unknown metric {metric!r}; known: {', '.join(TUNE_METRICS)}")
    choices = {"method": method, "strategy": strategy, "light_visibility": light_visibility}
    for field, name in choices.items():
        registry = KINDS[field]
        if name not in (*registry.names, "both", None):
            raise InputError("tune", f"{field} must be {', '.join(registry.names)} or both, got {name!r}")
    if not (isinstance(calibration_share, (int, float)) and math.isfinite(calibration_share) and calibration_share > 0):
        raise InputError("tune", f"the calibration share must be a positive number of budgets, got {calibration_share}")
    if grid is not None and not (Path(grid) / "results.jsonl").is_file():
        raise InputError(
            str(grid), "no results.jsonl: run the grid study first (evalkit study studies/tune_check.toml)"
        )
    names = {f: KINDS[f].names if n == "both" else (n or KINDS[f].default.name,) for f, n in choices.items()}
    emitters = load_scene(scene).features().emitters
    # Candidates that differ only in a light visibility their renders never use are one: the first.
    unique = {}
    for units in itertools.product(*names.values()):
        c = Candidate(**dict(zip(names, units)))
        unique.setdefault((c.method, c.strategy, draws_light_maps(c, emitters) and c.light_visibility), c)
    candidates = list(unique.values())
    out = Path(out or f"out/tune/{Path(scene).stem}")
    image = {"width": width, "height": height, "bounces": bounces}
    pinned = {**({} if spp is None else {"spp": spp}), **pins(scene, candidates, pin or {})}
    idle = {c: idle_axes(c, emitters) for c in candidates}
    unmeasured = {
        c: {a: v for a, v in unmeasured_axes(c, metric).items() if a not in {**idle[c], **pinned}} for c in candidates
    }
    start = time.perf_counter()
    studies = TunerStudies({"scene": scene, "seed": seed, **image}, metric, reference_spp, out, progress)
    seconds = calibration_share * budget
    rows = studies.run(
        "calibration", calibration_grid(candidates, SPREAD * seconds, CALIBRATION_SPP if spp is None else (spp,))
    )
    # The bias terms that renders measure, where the metric adds a bias as its square.
    biases = {c: {} for c in candidates}
    bias_spp = CALIBRATION_SPP[0] if spp is None else spp
    image_name, metric_kind = metric.split("_", 1)
    sweeps = []
    if metric_kind in SQUARED_METRICS:
        sweeps = [(c, *sweep) for c in candidates for sweep in bias_runs(c, idle[c], bias_spp, seed)]
    if sweeps:
        bias_rows = studies.run("bias", [run for *_, runs in sweeps for run in runs])  # in the order given
        reference = load_reference(bias_rows[0]["reference"]).images[image_name]  # every run's, one scene and image
        remaining = iter(bias_rows)
        for c, term, table, runs in sweeps:
            rows_of = [next(remaining) for _ in runs]
            images = [read_exr(out / "bias" / "runs" / r["run_id"] / f"{image_name}.exr")[0] for r in rows_of]
            n = len(runs) // BIAS_SEEDS
            grows = measure_bias([images[i * n : (i + 1) * n] for i in range(BIAS_SEEDS)], reference, metric)
            shape = [len(v) for v in table["values"]]
            bias = np.reshape(grows[: int(np.prod(shape))], shape)  # without the unbiased render's own 0
            biases[c][term] = {**table, "bias": bias.tolist(), "runs": [r["run_id"] for r in rows_of]}
        # Ordinary calibration rows as well, each once (an unbiased render is another candidate's,
        # and may be one of its own bias runs).
        rows += list({r["run_id"]: r for r in bias_rows}.values())
    models = {c: _fit(c, rows, metric, biases[c]) for c in candidates}
    refused = {c: [] for c in candidates}  # (setting, the renderer's reason)

    def optimum(c: Candidate) -> Recommendation:
        return optimise(
            models[c]["time"],
            models[c]["error"],
            budget,
            {**pinned, **idle[c], **unmeasured[c]},
            tuple(s for s, _ in refused[c]),
        )

    share = round((1 - SPREAD) * seconds / len(candidates), 3)
    first, anchors = _rendered_optima(
        studies,
        "refinement",
        [optimum(c) for c in candidates],
        lambda o: {**o.candidate.settings(), **o.settings, "frames": MAX_FRAMES, "time_budget": share},
        optimum,
        refused,
    )
    rows += [{**r, "weight": len(Candidate.of(r).calibration()) / 2} for r in anchors]
    models = {c: _fit(c, rows, metric, biases[c]) for c in candidates}
    optima = [optimum(c) for c in candidates]
    measured, overran = {}, []
    if check:
        # Every candidate's optimum is rendered and the least measured error within the budget wins:
        # between candidates the models' residuals (0.1-0.3 in log) are as large as the predicted
        # differences.
        def check_run(o: Recommendation) -> dict:
            return {**o.candidate.settings(), **o.settings}

        optima, checked = _rendered_optima(studies, "check", optima, check_run, optimum, refused)
        optima, checked, overran = _rerendered_within_budget(studies, optima, checked, check_run, models, budget)
        measured = {
            Candidate.of(r): {"time_s": float(r["wall_s"]), "error": float(r[metric]), "run_id": r["run_id"]}
            for r in checked
        }
        kept = [o for o in optima if measured[o.candidate]["time_s"] <= budget * (1 + BUDGET_TOLERANCE)]
        best = min(kept or optima, key=lambda o: measured[o.candidate]["error"])
        overran += [
            f"{o.candidate.name} measured {measured[o.candidate]['time_s']:.3g} s, over the budget of {budget:g} s"
            + (": not recommended" if kept else " (every candidate did: the least error of them is recommended)")
            for o in optima
            if o not in kept
        ]
    else:
        best = min(optima, key=lambda o: o.predicted_error)
    result = {
        "scene": scene,
        "budget_s": budget,
        "metric": metric,
        **{field: name for field, name in choices.items() if name is not None},
        "image": image,
        "pinned": pinned,
        # Settings left at their defaults because nothing in the candidate's renders uses them.
        "idle": {c.name: idle[c] for c in candidates if idle[c]},
        # Settings left at their defaults because the metric is not one that renders can measure
        # their bias under (`models.unmeasured_axes`).
        "unmeasured": {c.name: unmeasured[c] for c in candidates if unmeasured[c]},
        # Bias terms measured by renders instead of fitted (`TuneTerms.measured`).
        "measured_bias": {c.name: biases[c] for c in candidates if biases[c]},
        "seed": seed,
        "reference_spp": reference_spp,
        "recommended": {**best.candidate.settings(), **best.settings, **image},
        "predicted": {"time_s": best.predicted_time_s, "error": best.predicted_error},
        "chosen_by": "measured error within the budget" if check else "predicted error",
        "candidates": [{**o.as_dict(), **({"measured": measured[o.candidate]} if check else {})} for o in optima],
        **({"measured": measured[best.candidate]} if check else {}),
        "models": {
            c.name: {
                kind: {
                    "constants": models[c][kind].constants,
                    "residuals": models[c][kind].residuals,
                    "rms_log_residual": models[c][kind].rms_residual(),
                }
                for kind in ("time", "error")
            }
            for c in candidates
        },
        "first_optimum": [o.as_dict() for o in first],
        "refused": [
            {"candidate": c.name, **setting, "reason": reason} for c in candidates for setting, reason in refused[c]
        ],
        "warnings": [model.warning for c in candidates for model in models[c].values() if model.warning]
        + [
            f"the renderer refused {settings_text({**c.settings(), **setting})} ({reason}): the next best was taken"
            for c in candidates
            for setting, reason in refused[c]
        ]
        + [
            f"{c.name}: {', '.join(f'{k}={v}' for k, v in unmeasured[c].items())} kept at the default: renders measure "
            f"the bias of these settings only under {' and '.join(SQUARED_METRICS)}, not {metric_kind}"
            for c in candidates
            if unmeasured[c]
        ]
        + overran,
        "calibration": {
            "runs": len(rows),
            "share": calibration_share,
            "render_s": sum(float(r["wall_s"]) for r in rows),
            "run_s": sum(float(r["run_s"]) for r in rows),
            "folders": [str(out / n) for n in ("calibration", *(("bias",) if sweeps else ()), "refinement")],
        },
        "versions": versions(),
    }
    if grid is not None:
        result["grid"] = compare_with_grid(result, Path(grid))
    result["tune_s"] = time.perf_counter() - start
    result["report"] = str(out / "report.html")
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / "tune.json", json.dumps(result, indent=2) + "\n")
    write_tune_report(result, rows, models, out / "report.html")
    return result


def pins(scene: str, candidates: list[Candidate], pin: dict) -> dict:
    """``pin`` (settings by name or symbol: ``M``, ``light_sample_map_size``) by name, each a
    setting that the optimiser chooses for one of ``candidates`` (not the eye paths per pixel,
    which ``spp`` gives) and valid for it; an `InputError` naming the setting otherwise. The
    calibration still varies a pinned setting: the models need its terms."""
    names = {symbol: name for name, symbol in settings_symbols().items()}
    known = sorted({a for c in candidates for a in axes(c)} - {"spp"})
    pinned = {}
    for key, value in pin.items():
        name = names.get(key, key)
        having = [c for c in candidates if name in known and name in axes(c)]
        if not having:
            raise InputError(
                "tune",
                f"--pin {key}: not a setting chosen for {', '.join(c.name for c in candidates)}; "
                f"known: {', '.join(known)} (or their symbols; the eye paths per pixel: --spp)",
            )
        make_run({**having[0].settings(), name: value}, {"scene": scene}, f"tune --pin {key}={value}")
        pinned[name] = value
    return pinned


def _rendered_optima(studies: TunerStudies, name: str, optima: list, run, optimum, refused: dict) -> tuple[list, list]:
    """The candidates' ``optima`` rendered (each as ``run(optimum)``) in the tuner's study ``name``.
    Where the renderer refuses one (a `LimitError`: a shadow atlas past half the free memory, say),
    the values of the settings at fault join ``refused`` and the candidate's next best,
    ``optimum(candidate)``, is rendered instead. Returns the optima rendered and their rows."""
    while True:
        rows = studies.run(name, [run(o) for o in optima], refusals=True)  # in the order of the runs
        faults = [(o, r) for o, r in zip(optima, rows) if "limit_settings" in r]
        if not faults:
            return optima, rows
        for o, row in faults:
            reason = row["status"].removeprefix(REFUSED)
            setting = {a: o.settings[a] for a in row["limit_settings"] if a in o.settings}
            if not setting:  # past a limit that no setting the tuner varies moves
                raise InputError(studies.out / name, f"{o.candidate.name}: {reason}")
            refused[o.candidate].append((setting, reason))
        optima = [optimum(o.candidate) if "limit_settings" in r else o for o, r in zip(optima, rows)]


def _rerendered_within_budget(
    studies: TunerStudies, optima: list, checked: list, run, models: dict, budget: float
) -> tuple[list, list, list[str]]:
    """The checked ``optima`` (rows ``checked``, each rendered as ``run(optimum)``), where one that
    overran the budget (beyond `BUDGET_TOLERANCE`) is rendered again with the frames that its
    measured time fits, up to `RERENDERS` times while it overruns; with the rows and a line for
    each. The time model's residuals are 0.1-0.3 in log, and a candidate with several times less
    error should not lose to a timing miss (atrium, 15 s, S=16: eye paths measured 19.0 s, with
    4.3x less error than the bidirectional paths recommended instead)."""
    notes = []
    for _ in range(RERENDERS):
        again = {}
        for o, r in zip(optima, checked):
            seconds, frames = float(r["wall_s"]), o.settings["frames"]
            fits = int(frames * budget / seconds)  # the once-per-render cost counted per frame: on the safe side
            if seconds > budget * (1 + BUDGET_TOLERANCE) and 1 <= fits < frames:
                x = {**o.settings, "frames": fits}
                time_model, error_model = models[o.candidate]["time"], models[o.candidate]["error"]
                again[o.candidate] = Recommendation(
                    o.candidate, x, float(time_model.predict(x)), float(error_model.predict(x))
                )
                notes.append(
                    f"{o.candidate.name} measured {seconds:.3g} s with {frames} frames, over the budget of "
                    f"{budget:g} s: rendered again with {fits}"
                )
        if not again:
            break
        optima = [again.get(o.candidate, o) for o in optima]
        checked = studies.run("check", [run(o) for o in optima])
    return optima, checked, notes


def _fit(candidate: Candidate, rows: list[dict], metric: str, biases: dict) -> dict:
    return {
        "time": fit_model(candidate, "time", rows),
        "error": fit_model(candidate, "error", rows, metric, measured=biases),
    }


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
        and all(r.get(k) == v for k, v in {**result["image"], **result["pinned"]}.items())
        and is_number(r.get(metric))
        and r["wall_s"] <= budget
    ]
    if not same:
        image = result["image"]
        paths = f"{result['pinned']['spp']} spp" if "spp" in result["pinned"] else "any spp"
        raise InputError(
            str(folder),
            f"no run of {result['scene']} at {image['width']}x{image['height']}, {image['bounces']} bounces, "
            f"{paths} with time_budget = {budget:g} measured {metric} within it",
        )
    best = min(same, key=lambda r: r[metric])
    candidate = Candidate.of(best)
    settings = {**candidate.settings(), **{k: best[k] for k in (*axes(candidate), "frames_rendered")}}
    out = {
        "folder": str(folder),
        "runs": len(same),
        "best": {**settings, "time_s": best["wall_s"], "error": best[metric]},
    }
    if "measured" in result:
        out["ratio"] = result["measured"]["error"] / best[metric]
    return out
