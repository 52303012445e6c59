"""The tuner's report: predicted error-versus-time fronts beside the measured runs and the check,
the fitted constants and their residuals."""

from __future__ import annotations

import html
import itertools
from pathlib import Path

import numpy as np

from evalkit.core.atomic import write_text
from evalkit.core.errors import InputError
from evalkit.figures import pyplot, save_figure
from evalkit.pages import page
from evalkit.report import run_viewers
from evalkit.study.executors import read_rows
from evalkit.tune.models import Candidate
from evalkit.tune.optimise import optimise
from gpu_impl.registry import settings_symbols


def write_tune_report(result: dict, rows: list[dict], models: dict, path: Path) -> None:
    """report.html: predicted error-versus-time fronts beside the measured rows and the check, the
    fitted constants and their residuals."""
    plt = pyplot()
    metric, budget = result["metric"], result["budget_s"]
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    # Nine budgets a factor 2 apart: each is a whole optimisation (about 0.1 s).
    budgets = np.geomspace(budget / 16, budget * 16, 9)
    for i, (candidate, m) in enumerate(models.items()):
        colour, name = f"C{i}", candidate.name
        front = []
        for b in budgets:
            try:
                front.append((b, optimise(m["time"], m["error"], float(b)).predicted_error))
            except InputError:
                continue
        if front:
            ax.plot(*zip(*front), "-", color=colour, label=f"{name}: predicted front")
        mine = [r for r in rows if Candidate.of(r) == candidate]
        ax.plot(
            [r["wall_s"] for r in mine],
            [r[metric] for r in mine],
            "o",
            color=colour,
            mfc="none",
            label=f"{name}: calibration runs",
        )
        for c in (c for c in result["candidates"] if Candidate.of(c) == candidate):
            ax.plot(
                [c["predicted_time_s"]],
                [c["predicted_error"]],
                "*",
                color=colour,
                ms=11,
                label=f"{name} optimum: predicted",
            )
            if "measured" in c:
                ax.plot(
                    [c["measured"]["time_s"]],
                    [c["measured"]["error"]],
                    "X",
                    color=colour,
                    ms=9,
                    label=f"{name} optimum: measured",
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
    save_figure(fig, png, dpi=110)
    plt.close(fig)
    rec, calibration = result["recommended"], result["calibration"]
    grid = result.get("grid")
    render_s = calibration["render_s"]
    parts = [
        f"<h1>evalkit tune: {html.escape(result['scene'])}, {budget:g} s</h1>",
        f"<p>Metric {html.escape(metric)}; image {rec['width']}x{rec['height']}, {rec['bounces']} bounces, "
        f"{rec['spp']} paths per pixel per frame ({'given' if 'spp' in result['pinned'] else 'tuned'}); "
        f"calibration: {calibration['runs']} runs, {render_s:.1f} s of "
        f"render time ({render_s / budget:.2f}x the budget; asked for {calibration['share']:g}x), "
        f"{calibration['run_s']:.1f} s with loading and measuring, "
        f"cached in {html.escape(' and '.join(calibration['folders']))}.</p>",
        *[
            f"<p>{html.escape(name)}: the bias term {term} measured by renders with the same paths that differ only "
            f"in {html.escape(', '.join(table['settings']))} (runs {html.escape(', '.join(table['runs']))}): "
            + html.escape(bias_text(table))
            + ".</p>"
            for name, terms in result.get("measured_bias", {}).items()
            for term, table in terms.items()
        ],
        *[
            f"<p>{html.escape(name)}: {html.escape(', '.join(f'{k}={v}' for k, v in idle.items()))} left at the "
            "default, as its renders draw no light vertex's map (no emissive triangles, no light paths).</p>"
            for name, idle in result.get("idle", {}).items()
        ],
        "<h2>Recommendation</h2><table><tr><th>setting</th><th>value</th></tr>",
        *[f"<tr><td>{html.escape(k)}</td><td>{v}</td></tr>" for k, v in rec.items()],
        f"</table><p>Each candidate's optimum, chosen between by {html.escape(result['chosen_by'])}:</p>",
        "<table><tr><th>candidate</th><th>predicted time (s)</th><th>predicted error</th>"
        "<th>measured time (s)</th><th>measured error</th></tr>",
        *[
            f"<tr><td>{html.escape(settings_text(c))}</td><td>{c['predicted_time_s']:.3g}</td>"
            f"<td>{c['predicted_error']:.4g}</td>"
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
                f"<tr><td>best of {grid['runs']} grid runs: {html.escape(settings_text(grid['best']))}</td>"
                "<td></td><td></td>"
                f"<td>{grid['best']['time_s']:.3g}</td><td>{grid['best']['error']:.4g}</td></tr>"
            ]
            if grid
            else []
        ),
        f"</table><p><img src='{png.name}'></p>",
        *_check_viewers(result, path.parent),
        "<h2>Fitted models</h2>",
        *[f"<p><b>Warning</b>: {html.escape(w)}</p>" for w in result["warnings"]],
    ]
    for name, m in result["models"].items():
        for kind, fitted in m.items():
            constants = ", ".join(f"{k} = {v:.4g}" for k, v in fitted["constants"].items())
            residuals = ", ".join(f"{v:+.2f}" for v in fitted["residuals"])
            parts.append(
                f"<p><b>{html.escape(name)} {kind}</b>: {constants}; log residuals per run {residuals} "
                f"(rms {fitted['rms_log_residual']:.2f})</p>"
            )
    write_text(path, page(f"evalkit tune: {result['scene']}", parts))


def _check_viewers(result: dict, folder: Path) -> list[str]:
    """The checked renders in the image viewer, beside the reference and error maps (their runs
    are in the check study's folder)."""
    if "measured" not in result:
        return []
    check = folder / "check"
    rows = {r["run_id"]: r for r in read_rows(check, progress=lambda line: None)}
    image = result["metric"].split("_", 1)[0]
    parts = ["<h2>The checked renders</h2>"]
    for candidate in result["candidates"]:
        row = rows[candidate["measured"]["run_id"]]
        parts += run_viewers(check, row, [image], settings_text(candidate), page_folder=folder)
    return parts


def bias_text(table: dict) -> str:
    """'light_sample_map_size 32: 0.0123, 64: 0.00102, ...' or '(ism_points, ism_size) (1024, 32):
    0.0123, ...': a measured bias term (`Model.measured`) at each value of its settings."""
    names, values = table["settings"], table["values"]
    bias = np.ravel(table["bias"])
    if len(names) == 1:
        return f"{names[0]} " + ", ".join(f"{v}: {b:.3g}" for v, b in zip(values[0], bias))
    combinations = (", ".join(map(str, c)) for c in itertools.product(*values))
    return f"({', '.join(names)}) " + ", ".join(f"({c}): {b:.3g}" for c, b in zip(combinations, bias))


def settings_text(settings: dict) -> str:
    """'perfect K=8 R=256 F=22', 'perfect strategy=bidirectional V=32 K=8 R=128 F=10' and so on, from
    a candidate's or a grid row's settings."""
    short = {**settings_symbols(), "frames_rendered": "F"}
    symbols = [f"{short[k]}={v}" for k, v in settings.items() if k in short]
    return " ".join([Candidate.of(settings).name, *symbols])
