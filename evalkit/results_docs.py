"""The documentation site's results pages, generated at build time from the committed data files
in docs/results/data/ (benchmark reports saved with ``--record``: evalkit/records.py), so every
number on them comes from a file that says which command and versions made it (docs/hooks.py puts
them in the site)."""

from __future__ import annotations

import base64
import html
import math
import re
import tempfile
import tomllib
from collections.abc import Callable
from pathlib import Path

from evalkit.core.bsdf import lobe_directions
from evalkit.core.scene import load_scene
from evalkit.records import read_record
from evalkit.report import (
    best_at_matched_time,
    chosen_settings,
    judged_y,
    matched_time_verdict,
    plot,
    versus_rows,
    versus_verdicts,
)


def _table(header: list[str], rows: list[list]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---:" if i else "---" for i in range(len(header))) + "|"]
    return lines + ["| " + " | ".join(str(v) for v in row) + " |" for row in rows]


def _heading(title: str, intro: str, data: dict, source: str) -> list[str]:
    """A results page's title, what it measures, and where its data came from: the file, the
    command and versions that wrote it, and the device for a benchmark that names one."""
    record = data["record"]
    versions = ", ".join(f"{k} {v}" for k, v in record["versions"].items() if v)
    device = (
        f"on {data['device']} (OpenGL {data['gl_version']}; times are {data['timing']}). " if "device" in data else ""
    )
    return [
        f"# {title}",
        "",
        intro,
        "",
        f"Data: `{source}`, written on {record['date']} by",
        "",
        f"    {record['command']}",
        "",
        f"{device}Versions: {versions}.",
        "",
    ]


def _met(ok: bool) -> str:
    return "yes" if ok else "**no**"


def _value(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return "-" if v is None else str(v)


# A study page's columns after the parameters that vary: the measures a row has, in this order.
STUDY_MEASURES = (
    "hole_rate", "leak_rate", "redundant_rate", "nodes_per_crossing", "next_hit_error_rate",
    "indirect_relmse", "indirect_flip", "total_relmse", "total_z_outside", "indirect_z_outside", "build_ms",
    "wall_s",
)  # fmt: skip


# The images whose mean over the reference's, with its interval, a study page shows where its rows
# have it (the renders of several frames: evalkit/study/run.py).
MEAN_RATIO_IMAGES = ("total", "direct", "indirect")


# The hole model's fits as a study page shows them: per group, P(hole) = h0 + (1 - h0) exp(-c s^q) and the
# splat scale the model recommends (evalkit/metrics/hole_model.py has every column).
HOLE_FIT_COLUMNS = (
    "scene", "sampler", "points", "samples", "c", "q", "h0", "median_ratio_error", "splat_scale",
    "predicted_hole_rate", "predicted_nodes_per_crossing", "measured_best_scale",
)  # fmt: skip


def study_markdown(data: dict, source: str) -> str:
    """A study's rows (`evalkit study FILE --record`): its plots, its parameters that vary and its
    measures (or the columns the study names), and the hole model's fits where the study made them."""
    rows = [r for r in data["rows"] if r.get("status") == "ok"]
    intro = f"{data['description']}\n\nReduced from the paper: {data['reduced']}"
    lines = _heading(data["title"], intro, data, source)
    failed = len(data["rows"]) - len(rows)
    if failed:
        lines += [f"{failed} of {len(data['rows'])} runs failed and are not shown.", ""]
    for spec in data.get("plots", []):
        lines += _plot_markdown(rows, spec)
        if spec.get("pareto"):
            lines += _matched_time_markdown(rows, spec, data["varying"])
        if spec.get("versus"):
            lines += _versus_markdown(rows, spec, data["varying"])
    lines += _lobe_markdown(rows, data["varying"])
    fits = data.get("hole_model")
    if fits:
        keys = [k for k in HOLE_FIT_COLUMNS if k in fits[0]]
        lines += ["## The hole model's fits", ""]
        lines += _table(keys, [[_value(f.get(k)) for k in keys] for f in fits]) + [""]
    ratios = [image for image in MEAN_RATIO_IMAGES if any(f"{image}_mean_ratio" in r for r in rows)]
    if data.get("columns"):  # the study's own choice ([report] columns); a mean ratio gets its interval
        named = [c for c in data["columns"] if any(c in r for r in rows)]
        ratios = [image for image in ratios if f"{image}_mean_ratio" in named]
        columns = [c for c in named if c not in {f"{image}_mean_ratio" for image in MEAN_RATIO_IMAGES}]
    else:
        measures = [m for m in STUDY_MEASURES if any(m in r for r in rows)]
        columns = [*data["varying"], *measures]
    header = [*columns, *(f"{image} mean / reference [95 %]" for image in ratios)]
    table = [[*(_value(r.get(c)) for c in columns), *(_mean_ratio(r, image) for image in ratios)] for r in rows]
    lines += ["## Runs", ""] + _table(header, table)
    return "\n".join(lines) + "\n"


def _matched_time_markdown(rows: list[dict], spec: dict, varying: list[str]) -> list[str]:
    """Per scene, the bundle setting with the least ``y`` against Mitsuba's at the same ``x`` (a
    [[plot]] with ``pareto``: evalkit/report.py: matched_time_rows), and which is the more accurate."""
    x, y = spec["x"], judged_y(spec)
    shown = chosen_settings(rows, varying)
    best = best_at_matched_time(rows, x, y, shown)
    if not best:
        return []
    setting = ["method", "directions", *shown, "frames"]
    header = ["scene", *setting, x, y, f"Mitsuba's {y} at that {x}", "ratio", "more accurate"]
    table = [
        [r["scene"], *(_value(r.get(k)) for k in setting), _value(r[x]), _value(r[y]), _value(r[f"mitsuba_{y}"]),
         _value(r["ratio"]), r["more_accurate"]]
        for r in best.values()
    ]  # fmt: skip
    return [f"### At matched {x}", "", matched_time_verdict(best, x, y), "", *_table(header, table), ""]


def _versus_markdown(rows: list[dict], spec: dict, varying: list[str]) -> list[str]:
    """Each value of a [[plot]]'s ``versus`` parameter at its best settings against the others' at
    the same ``x`` (evalkit/report.py: versus_rows): per scene and value, how many settings of its
    Pareto front beat the other's front, and every such setting."""
    x, y, versus = spec["x"], judged_y(spec), spec["versus"]
    shown = [k for k in ("method", "directions", "spp", "frames", *chosen_settings(rows, varying)) if k != versus]
    compared = versus_rows(rows, x, y, versus, shown)
    if not compared:
        return []
    verdicts = [f"- {line}" for line in versus_verdicts(compared, x, y, versus)]
    lines = [f"### Each {versus} at its best settings against the other at matched {x}", "", *verdicts]
    header = ["scene", versus, *shown, "seeds", x, y, "against", f"its {y} at that {x}", "ratio", "more accurate"]
    table = [
        [r["scene"], r[versus], *(_value(r.get(k)) for k in shown), r["seeds"], _value(r[x]), _value(r[y]),
         r["against"], _value(r[f"against_{y}"]), _value(r["ratio"]), r["more_accurate"]]
        for r in compared
    ]  # fmt: skip
    return [*lines, "", *_table(header, table), ""]


def _lobe_markdown(rows: list[dict], varying: list[str]) -> list[str]:
    """Where a study renders a glossy scene at several K with all else the same: K_lobe of the
    scene's narrowest GGX lobe (`evalkit.core.bsdf.lobe_directions`) beside the indirect relMSE
    measured at each K, the mean over seeds; one row per setting of the other parameters that vary."""
    others = [k for k in varying if k not in ("scene", "directions", "seed")]
    lines = {}  # (scene, setting) -> {K: [relMSE per seed]}
    for r in rows:
        if r.get("method") != "mitsuba" and None not in (r.get("directions"), r.get("indirect_relmse")):
            key = (r["scene"], tuple(r.get(k) for k in others))
            lines.setdefault(key, {}).setdefault(r["directions"], []).append(r["indirect_relmse"])
    lines = {key: by_k for key, by_k in lines.items() if len(by_k) > 1}
    alphas = {}
    for scene in {scene for scene, _ in lines}:
        glossy = [m.gloss.alpha for m in load_scene(scene).materials if m.gloss and m.gloss.distribution == "ggx"]
        if glossy:
            alphas[scene] = min(glossy)
    lines = {key: by_k for key, by_k in lines.items() if key[0] in alphas}
    if not lines:
        return []
    shown = [i for i, k in enumerate(others) if len({setting[i] for _, setting in lines}) > 1 or k == "frames"]
    ks = sorted({k for by_k in lines.values() for k in by_k})
    table = [
        [scene, *(_value(setting[i]) for i in shown), f"{alphas[scene]:.3g}", math.ceil(lobe_directions(alphas[scene])),
         *(_value(sum(by_k[k]) / len(by_k[k])) if k in by_k else "-" for k in ks)]
        for (scene, setting), by_k in sorted(lines.items(), key=lambda item: alphas[item[0][0]])
    ]  # fmt: skip
    header = ["scene", *(others[i] for i in shown), "alpha", "K_lobe", *(f"indirect relMSE, K = {k}" for k in ks)]
    intro = (
        "K_lobe is the number of directions a frame needs before one is expected within the cone that holds "
        "half of the scene's narrowest GGX lobe ([the method](../method.md#choosing-a-bundle-by-the-bsdf)); "
        "below it a frame expects less than one direction in the lobe, and the error at the same frame "
        "count shows what that costs."
    )
    return ["### Directions a frame needs", "", intro, "", *_table(header, table), ""]


def _mean_ratio(row: dict, image: str) -> str:
    """The image's mean over the reference's with its 95 % interval (evalkit.metrics.confidence;
    a render of one frame has none)."""
    ratio, lo, hi = (row.get(f"{image}_mean_ratio{end}") for end in ("", "_lo", "_hi"))
    if ratio is None:
        return "-"
    return f"{ratio:.4f} " + ("(one frame: no interval)" if lo is None else f"[{lo:.4f}, {hi:.4f}]")


def _plot_markdown(rows: list[dict], spec: dict) -> list[str]:
    """A study's [[plot]] drawn from its recorded rows as its report draws it, in the page itself
    (a PNG in a data URI: the site opens from the file system)."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "plot.png"
        title = plot(rows, spec, path)
        data = base64.b64encode(path.read_bytes()).decode("ascii")
    return [f"## {title}", "", f'<img alt="{html.escape(title)}" src="data:image/png;base64,{data}">', ""]


def _ms(v: float) -> str:
    return f"{v:.1f}"


def bundles_markdown(data: dict, source: str) -> str:
    """benchmarks/bundles.py: perfect against imperfect bundle builds, side by side."""
    lines = _heading(
        "Bundle build speed",
        f"One bundle build per row, K = {data['directions']} directions of R = {data['resolution']} lines a side, "
        f"imperfect bundles from N = {data['points']} {data['sampler']} points per direction at splat scale "
        f"s = {data['splat_scale']}; median of {data['repeats']} builds after a warm-up, each repeat's builds back to "
        "back (*each repeat*: the ratio of each pair, how far the machine's noise moves it; a speed-up target is met "
        "when every repeat's ratio meets it). *raw* is the perfect bundles' geometry drawn with an empty fragment "
        "shader: what the rasterizer costs before any list is written.",
        data,
        source,
    )
    # The methods as the benchmark names them: the reference first, the one it is divided by second.
    methods = list(next(iter(data["scenes"].values()))["nodes"])
    first, second = methods[:2]
    rows = []
    for name, r in data["scenes"].items():
        m = r["median_ms"]
        rows.append(
            [name, f"{r['triangles']:,}", *(_ms(m[k]) for k in methods), _ms(m["raw"]),
             f"{r[f'{first}_over_{second}']:.2f}",
             ", ".join(f"{x:.2f}" for x in r.get(f"{first}_over_{second}_per_repeat", [])) or "-",
             f"{r[f'{first}_over_raw']:.2f}",
             *(f"{r['nodes'][k]:,}" for k in methods)]
        )  # fmt: skip
    header = ["scene", "triangles", *(f"{k} ms" for k in methods), "raw ms", f"{first} / {second}", "each repeat",
              f"{first} / raw",
              *(f"nodes {k}" for k in methods)]  # fmt: skip
    lines += _table(header, rows) + ["", "## Passes", ""]
    pass_rows = []
    for name, r in data["scenes"].items():
        for method, passes in r["passes_median_ms"].items():
            pass_rows.append([name, method, ", ".join(f"{p} {_ms(v)}" for p, v in passes.items())])
        for method in methods:  # nodes merged away after writing (splats)
            if r["raw_nodes"][method] != r["nodes"][method]:
                nodes = f"{r['raw_nodes'][method]:,} written, {r['nodes'][method]:,} kept"
                pass_rows.append([name, f"{method} nodes", nodes])
    lines += _table(["scene", "method", "ms per pass"], pass_rows)
    lines += ["", "## Targets", ""]
    lines += _table(["target", "met"], [[t, _met(ok)] for t, ok in data["targets_met"].items()])
    return "\n".join(lines) + "\n"


def poster_table_markdown(data: dict, source: str) -> str:
    """benchmarks/poster_table.py: the poster's per-frame pass times, perfect and imperfect, 1 and 3 bounces."""
    size = f"{data['width']} x {data['height']}, {data['supersampling']} x {data['supersampling']} supersampling"
    reduced = "" if data["full_preset"] else " (reduced from the poster's 1920 x 1024 with 2 x 2 supersampling)"
    lines = _heading(
        "The poster's table",
        f"Per-frame pass times of eye paths on `{data['scene']}` at {size}{reduced}, with the poster's bundles "
        f"(K = {data['directions']}, R = {data['resolution']}, N = {data['points']}); medians over {data['frames']} "
        "frames of one render.",
        data,
        source,
    )
    configs = list(data["results"])
    passes = [p for p in data["results"][configs[-1]]["median_ms"] if p != "frame"]
    rows = [[p, *(("-" if (v := data["results"][c]["median_ms"].get(p)) is None else _ms(v)) for c in configs)]
            for p in [*passes, "frame"]]  # fmt: skip
    rows.append(["others (frame - bundles)", *(_ms(data["results"][c]["others_ms"]) for c in configs)])
    rows.append(["nodes per frame", *(f"{data['results'][c]['nodes']:,}" for c in configs)])
    lines += _table(["pass (ms)", *configs], rows)
    # The configurations are "METHOD B=BOUNCES", the reference method first.
    first, second = dict.fromkeys(c.split()[0] for c in configs)
    ratio = f"{first}_over_{second}"
    poster = data["poster_ms"]
    lines += [
        "",
        f"{first.capitalize()} over {second} bundle build: {data[f'{ratio}_bundles']:.2f}x (the poster: "
        f"{poster[f'{first} bundles'] / poster[f'{second} bundles']:.2f}x); the 3-bounce frame: "
        f"{data[f'{ratio}_frame']['3']:.2f}x; with the {second} build free, at most "
        f"{data[f'{ratio}_frame_free_build']['3']:.2f}x (its other passes alone).",
        "",
        "The poster's figures (Radeon HD 6990, full preset): "
        + ", ".join(f"{k} {v:g} ms" for k, v in poster.items())
        + ".",
        "",
        "## Targets",
        "",
    ]
    lines += _table(["target", "met"], [[t, _met(ok)] for t, ok in data["targets_met"].items()])
    return "\n".join(lines) + "\n"


def coherent_paths_markdown(data: dict, source: str) -> str:
    """benchmarks/coherent_paths.py: eye paths choosing their bundles alone or in groups, side by side."""
    lines = _heading(
        "Coherent paths",
        f"Eye paths on `{data['scene']}` at {data['width']} x {data['height']}, B = {data['bounces']}, with the "
        f"poster's bundles (K = {data['directions']}, R = {data['resolution']}, N = {data['points']}), over "
        f"{data['frames']} frames, when each path chooses its bundle alone (T = 1) and when the paths of T "
        "neighbouring samples share the choice ([coherent paths](../method.md#coherent-paths)). *pixel variance* "
        "is one frame's, averaged over the indirect image; *frame spread* is the standard deviation of the frames' "
        "indirect image means.",
        data,
        source,
    )
    rows = [
        [name, _ms(r["bounces_ms"]), _ms(r["frame_ms"]), f"{r['indirect_mean']:.5f}", f"{r['pixel_variance']:.3e}",
         f"{r['frame_mean_sd']:.3e}"]
        for name, r in data["results"].items()
    ]  # fmt: skip
    header = ["configuration", "bounce passes ms", "frame ms", "indirect mean", "pixel variance", "frame spread"]
    lines += _table(header, rows) + [""]
    names = [k.replace("_over_", " / ").replace("_", " ") for k in next(iter(data["ratios"].values()))]
    lines += _table(["method", *names],
                    [[m, *(f"{v:.2f}" for v in r.values())] for m, r in data["ratios"].items()])  # fmt: skip
    # The configurations are "METHOD T=TILES", the reference method first, as on the poster's table.
    first, second = dict.fromkeys(c.split()[0] for c in data["results"])
    lines += ["", f"{first.capitalize()} over {second} frame time:", ""]
    frame = data[f"{first}_over_{second}_frame"]
    lines += _table(["coherent_paths", "ratio"], [[t, f"{v:.2f}x"] for t, v in frame.items()])
    return "\n".join(lines) + "\n"


def resolution_probe_markdown(data: dict, source: str) -> str:
    """benchmarks/resolution_probe.py: the resolution probe's time by stage, per scene."""
    lines = _heading(
        "The resolution probe's speed",
        "What `evalkit scene info` takes to advise a bundle resolution R for a scene it has not probed before "
        "(the advice is then kept in the user cache): the exact tracer (Embree's scene, and the coincident "
        "triangles it keeps in layers apart) and the lookups of 1000 eye vertices at each R tried, with the "
        "triangles' neighbours their walks cross, for one bounce (two lookups a path). "
        f"Median of {data['repeats']} probe(s) per scene, each of a scene loaded afresh. "
        f"The target: {data['target_s']:g} s for a scene of 2 M triangles.",
        data,
        source,
    )
    rows = [
        [r["scene"], f"{r['triangles']:,}", f"{r['coincident_pairs']:,}", f"{r['tracer_s']:.1f}",
         f"{r['advice_s']:.1f}", f"{r['probe_s']:.1f}", f"R >= {r['recommended']}",
         ", ".join(f"{100 * e:.2g} % at {R}" for R, e in r["wrong_lookups_per_path"].items())]
        for r in data["rows"]
    ]  # fmt: skip
    header = ["scene", "triangles", "coincident pairs", "tracer s", "advice s", "probe s", "advice",
              "wrong next hits per path"]  # fmt: skip
    return "\n".join(lines + _table(header, rows)) + "\n"


def _percent(v: float) -> str:
    return f"{100 * v:.2f} %"


def shadow_maps_markdown(data: dict, source: str) -> str:
    """benchmarks/shadow_maps.py: imperfect shadow maps against exact ones and both against Embree rays."""
    exact_ms = data["exact_ms"]  # the default exact maps'
    lines = _heading(
        f"Shadow maps against rays: {data['scene']}",
        f"The visibility of {data['light_vertices']:,} light vertices (frame 0's light paths, {data['light_paths']} "
        f"of them, B = 2, perfect bundles K = 32, R = 128) from {data['receivers']:,} surface points the camera sees, "
        "through exact cube maps and imperfect paraboloid maps, against Embree rays (the truth both approximate). "
        "*changed* is the share of connections whose visibility differs from the default exact maps', split into "
        "*hidden* (seen through exact maps, not through these) and *leaked* (the reverse); *light leaked* and "
        "*light hidden* are each map's own errors against the rays, weighted by the light each connection "
        f"carries. Times: a frame's maps, median of {data['repeats']} after a warm-up.",
        data,
        source,
    )
    rows = []
    for r in data["rows"]:
        imperfect = r["points"] is not None
        rows.append(
            [r["maps"], r["size"], f"{r['points']:,}" if imperfect else "-",
             _value(r.get("splat_scale")) if imperfect else "-",
             ("on" if r.get("pull_push") else "off") if imperfect else "-",
             _ms(r["ms"]), f"{r['ms'] / exact_ms:.3f}", _percent(r["differ_exact"]), _percent(r["hidden"]),
             _percent(r["leaked"]), _percent(r["differ_rays"]), _percent(r["light_leaked_rays"]),
             _percent(r["light_hidden_rays"])]
        )  # fmt: skip
    header = ["maps", "texels", "points", "splat scale", "pull-push", "ms", "/ exact", "changed", "hidden",
              "leaked", "differ from rays", "light leaked", "light hidden"]  # fmt: skip
    targets, cost, differing = data["targets"], data["default_cost_ratio"], data["default_differing"]
    met = [
        [f"imperfect maps at the defaults cost at most {targets['cost_ratio']:g} of exact ones", f"{cost:.3f}",
         _met(cost <= targets["cost_ratio"])],
        [f"and change at most {_percent(targets['differing'])} of connections", _percent(differing),
         _met(differing <= targets["differing"])],
    ]  # fmt: skip
    lines += _table(header, rows) + ["", "## Targets", ""] + _table(["target", "measured", "met"], met)
    return "\n".join(lines) + "\n"


def shadow_map_culling_markdown(data: dict, source: str) -> str:
    """benchmarks/shadow_map_culling.py: shadow maps drawn from the clusters each view sees against every triangle."""
    lines = _heading(
        "Shadow-map culling",
        "Each shadow view draws only the clusters of triangles whose boxes reach into it; against every "
        f"triangle into every view, side by side: exact maps of {data['map_size']} texels, the fixed lights' maps "
        "and frame 0's light vertices' cube maps, medians of "
        f"{data['repeats']}. *in view* is the share of triangles in the clusters drawn over every view of the "
        "atlas; *same bits* says whether the two atlases agree bit for bit.",
        data,
        source,
    )

    def before_after(ms: list[float]) -> str:
        return f"{_ms(ms[0])} -> {_ms(ms[1])}" if any(ms) else "no fixed light"

    rows = [
        [r["scene"], f"{r['triangles']:,}", r["light_vertices"], before_after(r["fixed_ms"]),
         before_after(r["vertex_ms"]), f"{r['vertex_speedup']:.2f}x",
         _percent(r["in_view"]), _met(r["identical"])]
        for r in data["rows"]
    ]  # fmt: skip
    header = ["scene", "triangles", "light vertices", "fixed lights' maps ms (every triangle -> culled)",
              "light vertices' maps ms (every triangle -> culled)", "speed-up", "in view", "same bits"]  # fmt: skip
    return "\n".join(lines + _table(header, rows)) + "\n"


def gl_loads_markdown(data: dict, source: str) -> str:
    """benchmarks/gl_loads.py: what one load costs in a compute shader, by the memory it reads."""
    lines = _heading(
        "Loads by memory kind",
        f"What one load costs in a compute shader: {data['invocations']:,} invocations, each reading "
        f"{data['loads']} records at hashed indices of {data['records']:,} (a vec4 each), from a storage buffer, "
        "a uniform block and an RGBA32F texture (texelFetch), against the same loop without loads; median of "
        f"{data['repeats']} dispatches after a warm-up. Why the bundle frames are a uniform block and the splatter "
        "reads its points and triangles as texels: [platform notes](../platform.md).",
        data,
        source,
    )
    per_load, ms = data["ns_per_load"], data["median_ms"]
    uniform, texture = per_load.get("UNIFORM_VEC4"), per_load["TEXTURE_VEC4"]
    rows = [
        [name.lower(), _ms(ms[name]), "-" if name == "NONE" else f"{per_load[name]:.2f}",
         "-" if name == "NONE" or uniform is None else f"{per_load[name] / uniform:.2f}",
         "-" if name == "NONE" else f"{per_load[name] / texture:.2f}"]
        for name in ms
    ]  # fmt: skip
    return "\n".join(lines + _table(["source", "ms", "ns a load", "/ uniform block", "/ texture"], rows)) + "\n"


def gl_branches_markdown(data: dict, source: str) -> str:
    """benchmarks/gl_branches.py: what the code of a branch costs in a compute shader when no lane takes it."""
    lines = _heading(
        "Branches no lane takes",
        f"What the code of a branch costs in a compute shader when no lane takes it: {data['invocations']:,} "
        f"invocations, each running a block of {data['block_sines']} dependent sines unconditionally, behind an "
        "`if` on a uniform that every lane or no lane takes, and in a loop that runs once, three times or not at "
        "all, tested at its top (for) or at its end (do-while); median of "
        f'{data["repeats"]} dispatches after a warm-up. "/ block" is a case\'s time less the shader without the '
        "block, over the block's. A GPU skips a branch that no lane of a warp takes; what the toolkit does where "
        "a driver does not: [platform notes](../platform.md).",
        data,
        source,
    )
    of_block = data["of_block"]
    rows = [
        [case, _ms(ms), f"{of_block[case]:.2f}" if case in of_block else "-"] for case, ms in data["median_ms"].items()
    ]
    return "\n".join(lines + _table(["case", "ms", "/ block"], rows)) + "\n"


def read_decisions(path: str | Path) -> dict:
    """docs/results/decisions.toml: the design decisions and the measurements behind each, checked:
    every decision has an id (unique), a known topic, a title, what the code does and its evidence,
    and every link to ``#id`` in an evidence names a decision. Raises ValueError naming the file."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise ValueError(f"{path}: {e}") from None
    if not data.get("topics") or not data.get("decision"):
        raise ValueError(f"{path}: no [topics] table or no [[decision]]")
    ids = [d.get("id") for d in data["decision"]]
    for d in data["decision"]:
        missing = [k for k in ("id", "topic", "title", "decision", "evidence") if not d.get(k)]
        if missing:
            raise ValueError(f"{path}: decision {d.get('id') or d.get('title')!r} lacks {', '.join(missing)}")
        if d["topic"] not in data["topics"]:
            topics = ", ".join(data["topics"])
            raise ValueError(f"{path}: decision {d['id']!r} has topic {d['topic']!r}, not one of {topics}")
        for target in re.findall(r"\]\(#([\w-]+)\)", d["evidence"]):
            if target not in ids:
                raise ValueError(f"{path}: decision {d['id']!r} links to #{target}, which no decision has")
    twice = sorted({i for i in ids if ids.count(i) > 1} | (set(ids) & set(data["topics"])))
    if twice:
        raise ValueError(f"{path}: the ids {', '.join(twice)} name more than one decision or topic")
    return data


def decisions_markdown(data: dict, source: str) -> str:
    """The design decisions by topic: what the code does, then what was measured to decide it."""
    record = data["record"]
    versions = ", ".join(f"{k} {v}" for k, v in record["versions"].items())
    lines = [
        "# The measurements behind the design",
        "",
        "Why the toolkit does what it does where a choice was measured: each decision below says what the "
        "code does, then what was measured to decide it, with the command or script that measured it. "
        f"Data: `{source}`, {record['origin']}, on {record['machine']} ({versions}; {record['dates']}). "
        "Unlike the other results pages these numbers were not written by a study or benchmark: each was "
        "measured once, on the code of its day. The studies and benchmarks re-measure what they cover.",
        "",
    ]
    for topic, title in data["topics"].items():
        lines += [f'<a id="{topic}"></a>', "", f"## {title}", ""]
        for d in (d for d in data["decision"] if d["topic"] == topic):
            lines += [f'<a id="{d["id"]}"></a>', "", f"### {d['title']}", "", f"**Decision.** {d['decision']}", ""]
            lines += [d["evidence"].strip(), ""]
    return "\n".join(lines)


# A results page per data file, by the benchmark that wrote it.
PAGES: dict[str, Callable[[dict, str], str]] = {
    "bundles": bundles_markdown,
    "poster_table": poster_table_markdown,
    "coherent_paths": coherent_paths_markdown,
    "resolution_probe": resolution_probe_markdown,
    "shadow_maps": shadow_maps_markdown,
    "shadow_map_culling": shadow_map_culling_markdown,
    "gl_loads": gl_loads_markdown,
    "gl_branches": gl_branches_markdown,
}


def results_pages(folder: str | Path, docs_root: str | Path) -> dict[str, str]:
    """Every data file in ``folder`` (``NAME.json``) as its page ``results/NAME.md``: a study's
    rows, or a benchmark's report by its page maker (`PAGES`); refuses a benchmark without one."""
    pages = {}
    for path in sorted(Path(folder).glob("*.json")):
        data = read_record(path)
        make = study_markdown if "study" in data else PAGES.get(data.get("benchmark"))
        if make is None:
            raise ValueError(f"{path}: no results page for benchmark {data.get('benchmark')!r} ({', '.join(PAGES)})")
        pages[f"results/{path.stem}.md"] = make(data, path.relative_to(Path(docs_root).parent).as_posix())
    return pages
