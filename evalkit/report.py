"""The HTML report of a study: what was run and how (command, versions, reduced sizes), the results
table, plots, the bias/variance split over seeds, the hole model, each shown run's images beside
their reference and error maps in the HDR viewer (evalkit/viewer), and the warnings the scenes
raised. Everything it shows is in the study folder: report.html, plots/*.png, viewer/*.js (the
images as half floats), results.csv."""

from __future__ import annotations

import functools
import hashlib
import html
import json
import math
import os
from pathlib import Path

import numpy as np

from evalkit.core.atomic import write_text
from evalkit.core.exr import read_exr
from evalkit.figures import REPORT_EXPOSURE, error_map_vmax, pyplot, save_figure
from evalkit.metrics.hole_model import DEFAULT_NODE_COST, analyse, hole_rate_model
from evalkit.metrics.images import bias_variance
from evalkit.pages import format_value, is_number, page, results_table_html, table_html
from evalkit.study.spec import PARAMETERS, Study, parameters, run_id
from evalkit.thresholds import DEFAULT_THRESHOLDS, load_thresholds
from evalkit.viewer import group_html, image_data
from references.mitsuba import Reference, load_reference

IMAGE_CAP = 12


@functools.lru_cache(maxsize=8)
def stored_reference(entry: str) -> Reference:
    """A finished store entry, read once however many runs of a report share it (an entry never
    changes once its manifest is written)."""
    return load_reference(entry)


def varying(runs: list[dict]) -> list[str]:
    """The run parameters that take more than one value over ``runs`` (a study's runs, or rows; a
    setting a run's units do not have counts as a value of its own)."""
    return [k for k in PARAMETERS if len({json.dumps(r.get(k)) for r in runs}) > 1]


def metric_columns(rows: list[dict]) -> list[str]:
    params = set(PARAMETERS) | {"run_id", "status", "scene_hash", "warnings", "reference", "gl_renderer"}
    return [
        k
        for k in dict.fromkeys(k for r in rows for k in r)
        if k not in params and not k.startswith(("version_", "hole_rate_slope"))
    ]


def pareto_front(rows: list[dict], x: str, y: str) -> list[dict]:
    """Rows no other row beats in both x and y (lower is better in both)."""
    points = sorted((r for r in rows if is_number(r.get(x)) and is_number(r.get(y))), key=lambda r: (r[x], r[y]))
    front, best = [], math.inf
    for r in points:
        if r[y] < best:
            front.append(r)
            best = r[y]
    return front


def setting_id(row: dict) -> str:
    """The run's id without its seed: runs that differ only in the seed share it."""
    return run_id({k: v for k, v in parameters(row).items() if k != "seed"})


def setting_points(rows: list[dict], x: str, y: str) -> list[tuple[dict, float, float, int]]:
    """Each setting's first row, median ``x`` and mean ``y`` over its seeds, and how many seeds."""
    groups: dict[str, list[dict]] = {}
    for r in rows:
        if is_number(r.get(x)) and is_number(r.get(y)) and r[x] > 0 and r[y] > 0:
            groups.setdefault(setting_id(r), []).append(r)
    return [
        (g[0], float(np.median([r[x] for r in g])), float(np.mean([r[y] for r in g])), len(g)) for g in groups.values()
    ]


def loglog_at(points: list[tuple[float, float]], tx: float) -> float | None:
    """y at ``tx`` on the line through ``points`` (x ascending), linear in log x and log y; None
    outside their range of x (no extrapolation)."""
    if not points or not points[0][0] <= tx <= points[-1][0]:
        return None
    lx, ly = np.log([p[0] for p in points]), np.log([p[1] for p in points])
    return float(np.exp(np.interp(math.log(tx), lx, ly)))


def matched_time_rows(rows: list[dict], x: str, y: str, shown: tuple[str, ...] = ()) -> list[dict]:
    """Each bundle setting (the mean of ``y`` and median of ``x`` over its seeds) beside Mitsuba's
    ``y`` at the same ``x`` in the same scene: Mitsuba's seed means interpolated linearly in log x
    and log y. A setting outside Mitsuba's range of x is not compared (no extrapolation). ``ratio``
    below 1 means the bundles are the more accurate at matched time. ``shown``: more setting
    columns to name each by (a unit's setting the study varies)."""
    points = setting_points(rows, x, y)
    result = []
    for first, tx, ty, seeds in points:
        mitsuba = sorted(
            (px, py) for f, px, py, _ in points if f["scene"] == first["scene"] and f["method"] == "mitsuba"
        )
        if first["method"] == "mitsuba" or len(mitsuba) < 2:
            continue
        row = {k: first.get(k) for k in ("scene", "method", "frames", "spp", "directions", "resolution", *shown)}
        row.update({"seeds": seeds, x: tx, y: ty})
        at = loglog_at(mitsuba, tx)
        if at is not None:
            row[f"mitsuba_{y}"] = at
            row["ratio"] = ty / at
            row["more_accurate"] = "bundles" if row["ratio"] < 1 else "mitsuba"
        else:
            row["more_accurate"] = f"not compared: {x} outside Mitsuba's {mitsuba[0][0]:.3g} to {mitsuba[-1][0]:.3g}"
        result.append(row)
    return sorted(result, key=lambda r: (r["scene"], r["method"], r[x]))


def chosen_settings(rows: list[dict], varying: list[str]) -> tuple[str, ...]:
    """The settings in ``varying``, beyond scene, method, frames, spp, directions and seed, that some
    scene's bundle runs take more than one value of (a unit's setting that is only there or not
    is no choice)."""
    named = ("scene", "method", "frames", "spp", "directions", "seed")
    bundles = [r for r in rows if r["method"] != "mitsuba"]

    def chosen(k: str) -> bool:
        scenes = {r["scene"] for r in bundles}
        return any(len({repr(r[k]) for r in bundles if r["scene"] == s and r.get(k) is not None}) > 1 for s in scenes)

    return tuple(k for k in varying if k not in named and chosen(k))


def best_at_matched_time(rows: list[dict], x: str, y: str, shown: tuple[str, ...] = ()) -> dict[str, dict]:
    """Per scene, the bundle setting with the least ratio of ``y`` to Mitsuba's at the same ``x``
    (`matched_time_rows`, among the settings it compares)."""
    best: dict[str, dict] = {}
    for r in matched_time_rows(rows, x, y, shown):
        if r.get("ratio") is not None and (r["scene"] not in best or r["ratio"] < best[r["scene"]]["ratio"]):
            best[r["scene"]] = r
    return best


def matched_time_verdict(best: dict[str, dict], x: str, y: str) -> str:
    """One sentence of `best_at_matched_time`: the scenes where the bundles' best setting is the
    more accurate at matched ``x``, and those where Mitsuba is."""
    won = [s for s, r in best.items() if r["ratio"] < 1]
    lost = [s for s, r in best.items() if r["ratio"] >= 1]
    return (
        f"The bundles' best setting is the more accurate at matched {x} on {', '.join(won) or 'no scene'}; "
        f"Mitsuba is on {', '.join(lost) or 'no scene'} (this machine; ratio = the bundles' {y} over Mitsuba's)."
    )


def judged_y(spec: dict) -> str:
    """The measure a [[plot]]'s verdicts judge: its ``y``, or the first of several."""
    return spec["y"] if isinstance(spec["y"], str) else spec["y"][0]


def versus_rows(rows: list[dict], x: str, y: str, versus: str, shown: list[str]) -> list[dict]:
    """Each value of the run parameter ``versus`` (the path strategy, say) given its best settings,
    against each other value given theirs, per scene: every setting on a value's Pareto front (mean
    ``y`` over seeds against median ``x``; every other setting of that value is slower or less
    accurate) beside the other value's front at the same ``x``, interpolated in log-log between its
    settings (outside its range of x, not compared: ``ratio`` None). ``ratio`` below 1: this value
    is the more accurate at matched x. Fronts, not single settings, so that neither side is judged at a
    setting that suits only the other (a number of paths per frame, say). ``shown``: the setting
    columns to print."""
    settings = [
        {**first, x: tx, y: ty, "seeds": seeds}
        for first, tx, ty, seeds in setting_points(rows, x, y)
        if first["method"] != "mitsuba" and first.get(versus) is not None
    ]
    result = []
    for scene in dict.fromkeys(r["scene"] for r in settings):
        here = [r for r in settings if r["scene"] == scene]
        fronts = {
            v: pareto_front([r for r in here if r[versus] == v], x, y) for v in dict.fromkeys(r[versus] for r in here)
        }
        for value, front in fronts.items():
            for setting in front:
                for other, their in fronts.items():
                    if other == value:
                        continue
                    at = loglog_at([(r[x], r[y]) for r in their], setting[x])
                    if at is None:
                        verdict = f"not compared: {x} outside {other}'s front, {their[0][x]:.3g} to {their[-1][x]:.3g}"
                    else:
                        verdict = value if setting[y] < at else other
                    result.append(
                        {
                            "scene": scene,
                            versus: value,
                            **{k: setting.get(k) for k in shown},
                            "seeds": setting["seeds"],
                            x: setting[x],
                            y: setting[y],
                            "against": other,
                            f"against_{y}": at,
                            "ratio": None if at is None else setting[y] / at,
                            "more_accurate": verdict,
                        }
                    )
    return result


def versus_verdicts(compared: list[dict], x: str, y: str, versus: str) -> list[str]:
    """One sentence per scene and pair of values of `versus_rows`: how many settings on one value's
    Pareto front beat the other's front at matched ``x``."""
    lines = []
    for scene, value, other in dict.fromkeys((r["scene"], r[versus], r["against"]) for r in compared):
        ratios = [
            r["ratio"]
            for r in compared
            if (r["scene"], r[versus], r["against"]) == (scene, value, other) and r["ratio"] is not None
        ]
        if ratios:
            lines.append(
                f"{scene}, at matched {x}: {sum(q < 1 for q in ratios)} of {len(ratios)} settings on {versus} "
                f"{value}'s Pareto front have less {y} than {other}'s front (ratios {format_value(min(ratios))} "
                f"to {format_value(max(ratios))}; below 1: {value} is the more accurate)."
            )
    return lines


def plot(rows: list[dict], spec: dict, path: Path) -> str:
    """One figure per [[plot]]: y against x, a line per ``group`` value (``group`` names one run
    parameter or a list of them), a panel per ``facet`` (default: scene); ``log`` = "x", "y" or
    "xy"; ``pareto`` draws the front of x and the first y."""
    plt = pyplot()

    ys = spec["y"] if isinstance(spec["y"], list) else [spec["y"]]
    facet = spec.get("facet", "scene")
    group = spec.get("group") or []
    group = [group] if isinstance(group, str) else list(group)
    facets = list(dict.fromkeys(r.get(facet) for r in rows))
    fig, axes = plt.subplots(1, len(facets), figsize=(5.2 * len(facets), 4), squeeze=False)
    methods = list(dict.fromkeys(r["method"] for r in rows))
    for ax, fv in zip(axes[0], facets):
        sub = [r for r in rows if r.get(facet) == fv]
        series = list(dict.fromkeys((r["method"], tuple(r.get(k) for k in group)) for r in sub))
        for y in ys:
            for method, g in series:
                members = [
                    r
                    for r in sub
                    if r["method"] == method
                    and tuple(r.get(k) for k in group) == g
                    and is_number(r.get(y))
                    and (r[y] > 0 or "y" not in spec.get("log", ""))
                ]
                parts = [y] if len(ys) > 1 else []
                parts += [method] if len(methods) > 1 else []
                # A setting the series' method does not have is None in its rows: not in the label.
                parts += [f"{k}={v}" for k, v in zip(group, g) if k != "method" and v is not None]
                label = ", ".join(parts) or y
                if spec["x"] in PARAMETERS and members and all(spec["x"] not in r for r in members):
                    # A method without the swept setting (a splat parameter, say) is a baseline across it.
                    for r in members:
                        ax.axhline(r[y], color="k", ls="--", lw=1, label=f"{label} (baseline)")
                    continue
                pts = sorted((r[spec["x"]], r[y]) for r in members if is_number(r.get(spec["x"])))
                if pts:
                    ax.plot(*zip(*pts), marker="o", label=label)
        if spec.get("pareto"):
            front = pareto_front(sub, spec["x"], ys[0])
            ax.step(
                [r[spec["x"]] for r in front],
                [r[ys[0]] for r in front],
                where="post",
                color="k",
                lw=2,
                alpha=0.4,
                label="Pareto front",
            )
        if "x" in spec.get("log", ""):
            ax.set_xscale("log")
        if "y" in spec.get("log", ""):
            ax.set_yscale("log")
        ax.set_xlabel(spec["x"])
        ax.set_ylabel(", ".join(ys))
        ax.set_title(f"{facet} = {fv}")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return spec.get("title") or f"{', '.join(ys)} against {spec['x']}"


def bias_variance_rows(study: Study, rows: list[dict], out: Path) -> list[dict]:
    """Per group of runs that differ only in the seed (two seeds or more): the bias/variance split
    of each measured image's relMSE."""
    groups: dict[str, list[dict]] = {}
    for r in rows:
        if r.get("status") == "ok" and r.get("reference"):
            groups.setdefault(setting_id(r), []).append(r)
    result = []
    for members in groups.values():
        if len(members) < 2:
            continue
        ref = stored_reference(members[0]["reference"])
        for image in study.measure["images"]:
            stack = [read_exr(out / "runs" / m["run_id"] / f"{image}.exr")[0] for m in members]
            bv = bias_variance(stack, ref.images[image], ref.variances[image])
            entry = {k: members[0].get(k) for k in varying(study.runs) if k != "seed"}
            entry.update({"image": image, **{k: v for k, v in bv.items() if k != "per_seed_relmse"}})
            result.append(entry)
    return result


def findings(study: Study, ok: list[dict], rows: list[dict]) -> list[str]:
    """A few sentences of what the rows say: how many runs finished; per [[plot]] and panel, the
    runs with the least y and the least x; with ``pareto``, how the bundle settings compare with
    Mitsuba at matched x. A study without plots: each measured image metric, run by run (the
    least, where there are more than six runs)."""
    failed = len(rows) - len(ok)
    lines = [f"{len(ok)} of {len(rows)} runs finished" + (f"; {failed} failed (listed below)." if failed else ".")]
    # A run is named by the parameters that vary and that every run has (a unit's own settings
    # would name every imperfect run at length beside a perfect one).
    shown = [k for k in varying(study.runs) if all(k in r for r in ok)]

    def described(row: dict) -> str:
        return ", ".join(f"{k}={row[k]}" for k in shown) or row["run_id"]

    for spec in study.plots:
        x, y = spec["x"], judged_y(spec)
        facet = spec.get("facet", "scene")
        usable = [r for r in ok if is_number(r.get(x)) and is_number(r.get(y))]
        for panel in dict.fromkeys(r.get(facet) for r in usable):
            members = [r for r in usable if r.get(facet) == panel]
            best, quickest = min(members, key=lambda r: r[y]), min(members, key=lambda r: r[x])
            lines.append(
                f"{facet} {panel}: the least {y}, {format_value(best[y])}, at {x} {format_value(best[x])} "
                f"({described(best)}); the least {x}, {format_value(quickest[x])}, with {y} "
                f"{format_value(quickest[y])} ({described(quickest)})."
            )
        ratios = [m["ratio"] for m in matched_time_rows(ok, x, y) if "ratio" in m] if spec.get("pareto") else []
        if ratios:
            lines.append(
                f"At matched {x}, {sum(r < 1 for r in ratios)} of {len(ratios)} bundle settings have less {y} than "
                f"Mitsuba (ratios {format_value(min(ratios))} to {format_value(max(ratios))}; below 1: the bundles "
                "are the more accurate)."
            )
            lines.append(matched_time_verdict(best_at_matched_time(ok, x, y), x, y))
        versus = spec.get("versus")
        if versus:
            lines += versus_verdicts(versus_rows(ok, x, y, versus, []), x, y, versus)
    columns = [] if study.plots else [f"{i}_{m}" for i in study.measure["images"] for m in study.measure["metrics"]]
    for column in columns:
        usable = [r for r in ok if is_number(r.get(column))]
        if usable:
            best = min(usable, key=lambda r: r[column])
            each = "; ".join(f"{described(r)}: {format_value(r[column])}" for r in usable)
            least = f"the least {format_value(best[column])} ({described(best)})"
            lines.append(f"{column}: {each if len(usable) <= 6 else least}.")
    return lines


def column_groups(columns: list[str]) -> dict[str, list[str]]:
    """The results table's columns by kind: settings, bundle metrics, image metrics, timings."""
    groups: dict[str, list[str]] = {"settings": [], "bundle metrics": [], "image metrics": [], "timings": []}
    for c in columns:
        if c == "run_id" or c in PARAMETERS:
            groups["settings"].append(c)
        elif c.startswith("ms_") or c.endswith(("_s", "_ms")):
            groups["timings"].append(c)
        elif c.split("_")[0] in ("direct", "indirect", "total"):
            groups["image metrics"].append(c)
        else:
            groups["bundle metrics"].append(c)
    return groups


def run_viewers(out: Path, row: dict, images: list[str], label: str, page_folder: Path | None = None) -> list[str]:
    """One viewer per measured image of a run (its folder ``out/runs/<run_id>``): the test image,
    its reference and the relMSE and FLIP maps, their data under ``out/viewer/``, for a page in
    ``page_folder`` (default ``out``)."""
    prefix = os.path.relpath(out, page_folder or out)
    ref = stored_reference(row["reference"])
    ref_key = hashlib.sha256(str(row["reference"]).encode()).hexdigest()[:12]
    viewers = []
    for image in images:
        test = read_exr(out / "runs" / row["run_id"] / f"{image}.exr")[0]
        # A finished reference never changes: its data, shared by runs, is written once.
        viewed = [
            {"name": f"{row['run_id']}-{image}", "label": f"{row['method']} {image}"},
            {"name": f"ref-{ref_key}-{image}", "label": f"reference {image}", "immutable": True},
        ]
        pixels = [test, ref.images[image]]
        for metric in ("relmse", "flip"):
            path = out / "runs" / row["run_id"] / f"{image}_{metric}_map.npy"
            if path.is_file():
                values = np.load(path)
                caption = f"{metric} map ({metric} {format_value(row.get(f'{image}_{metric}'))})"
                name = f"{row['run_id']}-{image}-{metric}"
                viewed.append({"name": name, "label": caption, "vmax": error_map_vmax(values)})
                pixels.append(values)
        for entry, values in zip(viewed, pixels):
            src = image_data(out, entry["name"], values, entry.get("immutable", False))
            entry["src"] = src if prefix == "." else f"{prefix}/{src}"
        size = (test.shape[1], test.shape[0])
        viewers.append(group_html(viewed, size, exposure=REPORT_EXPOSURE, caption=f"{label}: {image}"))
    return viewers


def plot_columns(spec: dict) -> list[str]:
    """The result columns a [[plot]] draws from."""
    named = [spec["x"], spec["y"], spec.get("group") or [], spec.get("facet", "scene")]
    return [c for item in named for c in ([item] if isinstance(item, str) else item)]


def write_report(study: Study, rows: list[dict], out: Path, meta: dict, failed: list[dict], progress=print) -> Path:
    """report.html: the answer first (what the study found, its plots with their Pareto and
    matched-time tables), then the bias/variance split, the hole model and the images, the full
    results table, and last how it was made (command, versions, metric definitions)."""
    ok = [r for r in rows if r.get("status") == "ok"]
    parts = [
        f"<h1>{html.escape(study.title)}</h1>",
        f"<p>{html.escape(study.description)}</p>" if study.description else "",
        "<h2>What the study found</h2><ul>"
        + "".join(f"<li>{html.escape(s)}</li>" for s in findings(study, ok, rows))
        + "</ul>",
    ]
    for i, spec in enumerate(study.plots):
        missing = [c for c in plot_columns(spec) if ok and not any(c in r for r in ok)]
        if missing:  # a misspelled column would draw an empty plot
            known = ", ".join(sorted({c for r in ok for c in r}))
            problem = f"[[plot]] {i + 1}: no column {', '.join(missing)} in the results; the columns are {known}"
            progress(f"warning: {study.path or study.name}: {problem}")
            parts.append(f"<h2>Plot {i + 1}</h2><p><b>Not drawn:</b> {html.escape(problem)}</p>")
            continue
        title = plot(ok, spec, out / "plots" / f"plot{i}.png")
        parts.append(f"<h2>{html.escape(title)}</h2><img src='plots/plot{i}.png'>")
        if spec.get("pareto"):
            ys = spec["y"] if isinstance(spec["y"], list) else [spec["y"]]
            facet = spec.get("facet", "scene")
            front = [
                r
                for fv in dict.fromkeys(r.get(facet) for r in ok)
                for r in pareto_front([r for r in ok if r.get(facet) == fv], spec["x"], ys[0])
            ]
            parts.append(
                "<p>Pareto front per panel (no run is both faster and more accurate):</p>"
                + table_html(front, ["run_id", *varying(study.runs), spec["x"], ys[0]])
            )
            matched = matched_time_rows(ok, spec["x"], ys[0])
            if matched:
                parts.append(
                    f"<p>At matched {html.escape(spec['x'])}: each bundle setting's mean {html.escape(ys[0])} over "
                    f"its seeds beside Mitsuba's, interpolated in log-log between Mitsuba's settings of the same "
                    f"scene (ratio below 1: the bundles are the more accurate).</p>"
                    + table_html(matched, list(dict.fromkeys(k for r in matched for k in r)))
                )
            versus = spec.get("versus")
            shown = [k for k in varying(study.runs) if k not in ("scene", "seed", versus)]
            compared = versus_rows(ok, spec["x"], ys[0], versus, shown) if versus else []
            if compared:
                # Only the settings that tell the fronts' rows apart: one with a single value wherever
                # a row has it (a unit's own setting, say) is implied by the row's units.
                same = [k for k in shown if len({json.dumps(r[k]) for r in compared if r[k] is not None}) < 2]
                parts.append(
                    f"<p>{html.escape(versus)} against {html.escape(versus)} at matched {html.escape(spec['x'])}: "
                    f"each setting on one {html.escape(versus)}'s Pareto front (the mean {html.escape(ys[0])} over its "
                    f"seeds against the median {html.escape(spec['x'])}) beside the other's front at the same "
                    f"{html.escape(spec['x'])}, interpolated in log-log; each side is judged at its own best settings "
                    "(ratio below 1: the first is the more accurate).</p>"
                    + table_html(compared, [k for k in dict.fromkeys(k for r in compared for k in r) if k not in same])
                )

    bv = bias_variance_rows(study, ok, out)
    if bv:
        parts.append(
            "<h2>Bias and variance over seeds</h2><p>relMSE per seed (mean, std, range), split into variance "
            "(mean over pixels of the seeds' variance, weighted as relMSE) and bias^2 (the seeds' mean image "
            "against the reference, less the noise of both; can be slightly negative when the bias is below the "
            "noise). "
            "Celarek et al., CGF 2019.</p>"
            + table_html(bv, [*[k for k in bv[0] if k not in ("seeds", "epsilon")], "seeds"])
        )

    if study.hole_model is not None:
        parts.append(_hole_model_section(study, ok, out))

    shown = [r for r in ok if r.get("reference") and r.get("seed") == min(x.get("seed", 0) for x in ok)][
        : study.report.get("images", IMAGE_CAP)
    ]
    if shown:
        parts.append(
            "<h2>Images</h2><p>Per run: the test image, the reference and the relMSE and FLIP maps (magma, 0 to "
            "the 99th percentile), in one viewer with HDR values: keys 1-9 or Left/Right switch images, Space "
            "flips back, E / Shift+E change the exposure, + / - / 0 zoom (the wheel zooms at the cursor, drag "
            "pans); the table lists every image's value at the cursor.</p>"
        )
        for r in shown:
            label = ", ".join(f"{k}={r[k]}" for k in varying(study.runs) if k in r)
            parts += run_viewers(out, r, study.measure["images"], label)
        if len(ok) > len(shown):
            parts.append(
                f"<p>{len(shown)} of {len(ok)} runs shown "
                f"(the first seed, at most {study.report.get('images', IMAGE_CAP)}).</p>"
            )

    if failed:
        parts.append("<h2>Failed runs</h2>" + table_html(failed, ["run_id", *varying(study.runs), "status"]))
    columns = study.report.get("columns") or ["run_id", *varying(study.runs), *metric_columns(ok)]
    columns = [c for c in columns if any(c in r for r in ok)]
    parts.append(
        "<h2>Results</h2><p>One row per run; click a column's name to sort by it, a group's name to hide or "
        "show its columns. A setting a run's method does not have is left empty. Every column of every run "
        "is in <a href='results.csv'>results.csv</a>.</p>"
        + results_table_html(ok, column_groups(columns), collapsed=("timings",))
    )
    parts.append(_thresholds_section({r["scene"] for r in rows}))

    warnings = sorted({(r["scene"], w) for r in ok for w in (r.get("warnings") or "").split(" | ") if w})
    parts.append(
        "<h2>Scene warnings</h2>"
        + (
            "<ul>" + "".join(f"<li>{html.escape(s)}: {html.escape(w)}</li>" for s, w in warnings) + "</ul>"
            if warnings
            else "<p>None: no scene needed an approximation.</p>"
        )
    )
    parts.append(
        "<h2>How it was made</h2>"
        + (f"<p><b>Reduced sizes:</b> {html.escape(study.reduced)}</p>" if study.reduced else "")
        + f"<p><b>Command:</b> <code>{html.escape(meta['command'])}</code><br><b>Finished:</b> {meta['finished']}, "
        f"{len(ok)} of {len(rows)} runs ok ({meta['executor']}, {meta['workers']} worker(s))</p>"
        "<p><b>Versions:</b> "
        + ", ".join(f"{html.escape(k)} {html.escape(str(v))}" for k, v in meta["versions"].items())
        + (f", GL {html.escape(str(ok[0].get('gl_renderer')))}" if ok and ok[0].get("gl_renderer") else "")
        + "</p>"
        f"<p>Metric definitions: relMSE = mean (t - r)^2 / (r^2 + 0.01); SMAPE = mean |t - r| / (|t| + |r| + 0.01); "
        f"FLIP is HDR-FLIP at 67 ppd; Delta E 2000 after exposure {REPORT_EXPOSURE:g} and clipping to [0, 1]. "
        f"Bundle rates are against Embree's exact bundles on the same lines (evalkit/metrics/bundles.py). "
        f"The viewers open at exposure {REPORT_EXPOSURE:g}, sRGB.</p>"
    )
    path = out / "report.html"
    write_text(path, page(study.title, parts))
    return path


def _hole_model_section(study: Study, rows: list[dict], out: Path) -> str:
    plt = pyplot()

    node_cost = float(study.hole_model.get("node_cost", DEFAULT_NODE_COST))
    # The rows of a method with splats: those that have a splat scale.
    splats = [r for r in rows if is_number(r.get("splat_scale")) and is_number(r.get("leak_rate"))]
    fits = analyse(splats, node_cost)
    write_text(out / "hole_model.json", json.dumps(fits, indent=2) + "\n")
    if not fits:
        return "<h2>Hole model</h2><p>Not fitted: it needs runs with splats at two splat scales or more.</p>"
    panels = sorted({(f["scene"], f["sampler"]) for f in fits})
    fig, axes = plt.subplots(2, len(panels), figsize=(5.2 * len(panels), 8), squeeze=False)
    for column, (scene, sampler) in enumerate(panels):
        ax, cost_ax = axes[0][column], axes[1][column]
        for f in fits:
            if (f["scene"], f["sampler"]) != (scene, sampler) or f["points"] == "all":
                continue
            mine = sorted(
                (
                    r
                    for r in splats
                    if r["scene"] == scene and r.get("sampler", "random") == sampler and int(r["points"]) == f["points"]
                ),
                key=lambda r: r["splat_scale"],
            )
            holes = [max(r["leak_rate"], 1 / r["exact_nodes"]) for r in mine]
            scales = [r["splat_scale"] for r in mine]
            line = ax.plot(scales, holes, "o", label=f"leaks, N={f['points']}")[0]
            # Beside them the holes: leaks, offsets and coincident holes together.
            ax.plot(
                scales, [r["hole_rate"] for r in mine], "x", color=line.get_color(), label=f"holes, N={f['points']}"
            )
            s = np.linspace(mine[0]["splat_scale"], mine[-1]["splat_scale"], 100)
            ax.plot(
                s,
                hole_rate_model(s**2, f["c"], f["h0"], f["q"]),
                "-",
                color=line.get_color(),
                label=f"{f['h0']:.2g} + {1 - f['h0']:.2g} exp(-{f['c']:.3g} s^{f['q']:.2g})",
            )
            ax.axvline(f["splat_scale"], color=line.get_color(), ls=":", lw=1)
            cost_ax.plot(
                [r["nodes_per_crossing"] for r in mine], holes, "o-", color=line.get_color(), label=f"N={f['points']}"
            )
        ax.set_yscale("log")
        ax.set_xlabel("splat scale s (radius / sqrt(A / (pi N)))")
        ax.set_ylabel("leak rate (holes: x)")
        ax.set_title(f"{scene}, {sampler} points: measured, the model, (dotted) the recommended s", fontsize=9)
        cost_ax.set_yscale("log")
        cost_ax.set_xlabel("nodes per surface crossing before merging")
        cost_ax.set_ylabel("leak rate")
        cost_ax.set_title(f"{scene}, {sampler} points: holes against what they cost", fontsize=9)
        for a in (ax, cost_ax):
            a.grid(True, which="both", alpha=0.3)
            a.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, out / "plots" / "hole_model.png")
    plt.close(fig)
    columns = [
        "scene",
        "sampler",
        "points",
        "c",
        "q",
        "h0",
        "c_nodes",
        "samples",
        "median_ratio_error",
        "max_ratio_error",
        "max_abs_error",
        "splat_scale",
        "searched",
        "predicted_hole_rate",
        "predicted_cost",
        "measured_best_scale",
        "nearest_grid_scale",
        "regret",
    ]
    return (
        "<h2>Hole model</h2><p>P(leak) = h0 + (1 - h0) exp(-c s^q) and nodes per surface crossing before merging "
        "= c_n s^2, fitted per scene, sampler and point count in log space with Dr.Jit AD (independent points, "
        "ideally: c = c_n = 1, q = 2, h0 = 0; stratified points leave fewer leaks, q > 2). A leak is a line that "
        "crosses a surface and finds no node of it; the holes (crosses) count offsets too, surfaces found within a "
        "splat's reach but beyond the depth tolerance, where a splat lies in a neighbouring triangle's plane "
        "(evalkit/metrics/bundles.py). Ratio errors are |ln(predicted / measured)| of the leak rate. "
        f"The recommended splat scale minimises leak rate + {node_cost:g} x nodes per crossing (gradient descent with "
        "Dr.Jit AD; a direct search beside it as a check); regret is the measured cost at the grid scale nearest the "
        "recommendation over the measured best cost, less 1. Below each fit, the leak rate against the nodes per "
        "crossing it costs.</p>"
        "<img src='plots/hole_model.png'>" + table_html(fits, columns)
    )


def _thresholds_section(scenes: set[str]) -> str:
    """The declared accuracy thresholds of these scenes, as `evalkit check` and the tests read them."""
    cases = [c for c in load_thresholds(DEFAULT_THRESHOLDS) if c.runs[0]["scene"] in scenes]
    if not cases:
        return ""
    rows = [
        {
            "case": c.name,
            "metric": c.metric,
            "kind": c.kind,
            "threshold": c.threshold if c.kind != "falls" else f"x{1 + c.tolerance:g} per step over {c.sweep}",
            "why": c.why,
            "calibration": c.calibration,
        }
        for c in cases
    ]
    return (
        "<h2>Declared accuracy thresholds</h2><p>From evalkit/thresholds.toml, which <code>evalkit check</code> and "
        "the test suite run; the runs above are not these cases unless their parameters match.</p>"
        + table_html(rows, ["case", "metric", "kind", "threshold", "why", "calibration"])
    )
