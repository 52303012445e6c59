"""Studies: a declarative grid of runs (scenes x methods x parameters x seeds), one row of results
per run, resumable, run locally in parallel or on a Dask cluster, ending in an HTML report.

A study file (TOML; studies/*.toml are examples)::

    name = "directions"
    title = "Error against K and R"
    reduced = "what was made smaller than the paper, and why"   # stated in the report
    [defaults]              # every run's parameters, below the grid's
    scene = "cornell-box"
    bounces = 1
    [[grid]]                # each [[grid]] is a cartesian product; the runs of all grids are joined
    method = ["perfect", "imperfect"]
    directions = [8, 16, 32]
    seed = [0, 1]
    [measure]
    bundles = true          # bundle metrics against Embree exact bundles (perfect, imperfect)
    render = true           # render images (timings); false: bundle metrics only
    images = ["indirect"]   # image metrics of these images against the Mitsuba reference
    reference_spp = 4096
    [hole_model]            # fit the coverage model to the imperfect rows (optional)
    node_cost = 0.01
    [[plot]]                # plots in the report
    x = "splat_scale"
    y = ["hole_rate", "redundant_rate"]
    group = "points"
    log = "xy"

Methods: ``perfect`` and ``imperfect`` (GL bundles; rendered with `gpu_impl.renderer.Renderer`
when images are measured) and ``mitsuba`` (Mitsuba 3 at ``spp``, timed). A run's row holds every
parameter, the metric values (``<image>_<metric>`` and the bundle metrics), timings, versions,
its seed and its status. Rows are appended to ``results.jsonl`` as runs finish; a second start
skips the rows already there (resume) and retries failed ones. ``results.csv`` is the same table.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import itertools
import json
import os
import platform
import sys
import time
import tomllib
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evalkit.errors import InputError

METHODS = ("perfect", "imperfect", "mitsuba")
# Parameters a run may set, with their defaults (the renderer's where it has one).
RUN_DEFAULTS = {
    "scene": "cornell-box",
    "method": "perfect",
    "bounces": 1,
    "directions": 32,
    "resolution": 128,
    "points": 16384,
    "splat_scale": 2.0,
    "width": 128,
    "height": 128,
    "supersampling": 1,
    "spp": 1,
    "frames": 8,
    "seed": 0,
}
MEASURE_DEFAULTS = {"bundles": False, "render": True, "images": ["indirect"], "metrics": ["mse", "relmse", "smape", "flip", "delta_e2000"],
                    "reference_spp": 4096, "reference_seed": 0, "eye_vertices": 4096}
TOP_KEYS = {"name", "title", "description", "reduced", "defaults", "grid", "measure", "hole_model", "plot", "report"}
VERSIONED = ("raybundle-evalkit", "mitsuba", "drjit", "moderngl", "numpy", "embreex", "flip-evaluator", "colour-science")


@dataclass
class Study:
    name: str
    path: Path | None
    title: str
    description: str
    reduced: str
    runs: list[dict]
    measure: dict
    hole_model: dict | None = None
    plots: list[dict] = field(default_factory=list)
    report: dict = field(default_factory=dict)


def read_toml(path: Path, what: str) -> dict:
    """A TOML file's tables; a missing or malformed file is an `InputError` naming it."""
    if not path.is_file():
        raise InputError(str(path), f"no such {what} file")
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise InputError(str(path), f"malformed TOML: {e}") from None


def load_study(path: str | os.PathLike) -> Study:
    """Parse and check a study file; every problem is an `InputError` naming the file."""
    return study_from_dict(read_toml(Path(path), "study"), Path(path))


def study_from_dict(spec: dict, path: Path | None = None) -> Study:
    where = str(path or "study")
    unknown = set(spec) - TOP_KEYS
    if unknown:
        raise InputError(where, f"unknown key(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(TOP_KEYS))}")
    defaults = {**RUN_DEFAULTS, **_table(spec, "defaults", where)}
    grids = spec.get("grid", [{}])
    if isinstance(grids, dict):
        grids = [grids]
    runs, seen = [], set()
    for grid in grids:
        axes = {k: v if isinstance(v, list) else [v] for k, v in grid.items()}
        for values in itertools.product(*axes.values()):
            run = {**defaults, **dict(zip(axes, values))}
            check_run(run, where)
            key = run_id(run)
            if key not in seen:
                seen.add(key)
                runs.append(run)
    measure = {**MEASURE_DEFAULTS, **_table(spec, "measure", where)}
    if set(measure) - set(MEASURE_DEFAULTS):
        raise InputError(where, f"[measure]: unknown key(s) {', '.join(sorted(set(measure) - set(MEASURE_DEFAULTS)))}")
    from evalkit.metrics.images import METRICS

    bad = set(measure["metrics"]) - set(METRICS)
    if bad:
        raise InputError(where, f"[measure] metrics: unknown {', '.join(sorted(bad))}; known: {', '.join(METRICS)}")
    bad = set(measure["images"]) - {"direct", "indirect", "total"}
    if bad:
        raise InputError(where, f"[measure] images: unknown {', '.join(sorted(bad))}; known: direct, indirect, total")
    plots = spec.get("plot", [])
    for p in plots:
        if "x" not in p or "y" not in p:
            raise InputError(where, f"a [[plot]] needs x and y, got {sorted(p)}")
    name = spec.get("name") or (path.stem if path else "study")
    return Study(name, path, spec.get("title", name), spec.get("description", ""), spec.get("reduced", ""), runs, measure,
                 spec.get("hole_model"), plots, spec.get("report", {}))


def _table(spec: dict, key: str, where: str) -> dict:
    value = spec.get(key, {})
    if not isinstance(value, dict):
        raise InputError(where, f"[{key}] must be a table")
    return value


def check_run(run: dict, where: str) -> None:
    unknown = set(run) - set(RUN_DEFAULTS)
    if unknown:
        raise InputError(where, f"unknown run parameter(s) {', '.join(sorted(unknown))}; known: {', '.join(RUN_DEFAULTS)}")
    if run["method"] not in METHODS:
        raise InputError(where, f"method '{run['method']}' is not one of {', '.join(METHODS)}")
    for name, value in run.items():
        if name in ("scene", "method"):
            continue
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not np.isfinite(value):
            raise InputError(where, f"{name} = {value!r} is not a finite number")
        if name not in ("seed", "bounces") and value <= 0:
            raise InputError(where, f"{name} = {value} must be positive")


def run_id(run: dict) -> str:
    """A stable id of a run's parameters (the resume key)."""
    return hashlib.sha256(json.dumps(run, sort_keys=True).encode()).hexdigest()[:12]


def versions() -> dict:
    out = {"python": platform.python_version()}
    for package in VERSIONED:
        try:
            out[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            out[package] = None
    return out


# -- running --------------------------------------------------------------------------------------

def prepare(study: Study, out: Path, progress=print) -> None:
    """What runs share, made once before they start (and before any worker does): the Mitsuba
    references and the exact bundles."""
    from evalkit.scene import load_scene

    scenes, made = {}, set()
    for run in study.runs:
        scene = scenes.setdefault(run["scene"], load_scene(run["scene"]))
        ref_key = ("reference", run["scene"], run["bounces"], run["width"], run["height"])
        if study.measure["images"] and ref_key not in made:
            made.add(ref_key)
            reference_for(scene, run, study.measure, out, progress)
        exact_key = ("exact", run["scene"], run["directions"], run["resolution"], run["seed"])
        if study.measure["bundles"] and run["method"] != "mitsuba" and exact_key not in made:
            made.add(exact_key)
            exact_bundles(scene, run, out)


def reference_for(scene, run: dict, measure: dict, out: Path, progress=print):
    """The committed reference when the store has it, else one rendered into the study's store."""
    from references.mitsuba import DEFAULT_STORE, load_reference, reference, store_entry

    args = dict(bounces=int(run["bounces"]), spp=int(measure["reference_spp"]), width=int(run["width"]),
                height=int(run["height"]), seed=int(measure["reference_seed"]))
    committed = store_entry(scene.name, scene.content_hash(), store=DEFAULT_STORE, **args)
    if (committed / "manifest.json").is_file():
        return load_reference(committed)
    return reference(scene, **args, store=out / "references", progress=lambda line: progress(f"reference {scene.name}: {line}"))


def exact_bundles(scene, run: dict, out: Path):
    """Embree's exact bundles on the run's lines (frame 0 of its seed), cached in the study folder."""
    from evalkit.bundleset import BundleSet, DirectionSet

    path = out / "cache" / f"exact-{scene.name}-{scene.content_hash()[:12]}-K{run['directions']}-R{run['resolution']}-seed{run['seed']}.npz"
    if path.is_file():
        return BundleSet.load(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    directions = DirectionSet.make(int(run["directions"]), seed=int(run["seed"]))
    bundles = exact_tracer(scene).bundles(directions, int(run["resolution"]))
    tmp = path.with_suffix(".tmp.npz")
    bundles.save(tmp)
    os.replace(tmp, path)
    return bundles


_TRACERS: dict = {}


def exact_tracer(scene):
    """One Embree scene per scene and process: its BVH is built once, not once per run."""
    from references.embree import ExactTracer

    key = scene.content_hash()
    if key not in _TRACERS:
        _TRACERS[key] = ExactTracer(scene)
    return _TRACERS[key]


_GL = None


def _gl():
    """One GL context per process, made at its first GL run."""
    global _GL
    if _GL is None:
        from gpu_impl.context import GLContext

        _GL = GLContext()
    return _GL


def run_case(run: dict, measure: dict, out: str) -> dict:
    """One run: its row of parameters, metrics, timings and versions. A failure is a row with
    ``status`` 'error: ...' (the traceback goes to the run's folder), never an exception."""
    out = Path(out)
    key = run_id(run)
    folder = out / "runs" / key
    folder.mkdir(parents=True, exist_ok=True)
    row = {"run_id": key, **run, "status": "ok", **{f"version_{k}": v for k, v in versions().items()}}
    start = time.perf_counter()
    try:
        row.update(_measure(run, measure, out, folder))
    except Exception as e:  # noqa: BLE001 -- a study reports a failed run and goes on
        (folder / "error.txt").write_text(traceback.format_exc())
        row["status"] = f"error: {type(e).__name__}: {e}".splitlines()[0]
    row["run_s"] = round(time.perf_counter() - start, 3)
    return row


def _measure(run: dict, measure: dict, out: Path, folder: Path) -> dict:
    from evalkit.exr import write_exr
    from evalkit.metrics.images import compare_images
    from evalkit.scene import load_scene

    scene = load_scene(run["scene"])
    row = {"scene_hash": scene.content_hash(), "warnings": " | ".join(scene.warnings)}
    if measure["bundles"] and run["method"] != "mitsuba":
        row.update(_bundle_metrics(scene, run, measure, out))
    if not measure["render"]:
        return row
    if run["method"] == "mitsuba":
        from references.mitsuba import timed_render

        images, seconds, info = timed_render(scene, int(run["bounces"]), int(run["spp"]), int(run["width"]), int(run["height"]),
                                             int(run["seed"]))
        row.update({"wall_s": seconds, "paths_per_pixel": int(run["spp"]), "gl_renderer": None})
        provenance = {**run, **info}
    else:
        images, timings, provenance = _render(scene, run)
        row.update(timings)
    if not measure["images"]:
        return row
    ref = reference_for(scene, run, measure, out, progress=lambda line: None)
    row["reference"] = str(ref.path)
    for name in measure["images"]:
        write_exr(folder / f"{name}.exr", images[name].astype(np.float32), {**provenance, "image": name})
        metrics = compare_images(images[name], ref.images[name], measure["metrics"], f"{run['method']} {name}", f"reference {name}")
        # The relative error of the image's mean: bias that noise cannot hide (light lost to holes,
        # or gained from splats overhanging an emitter).
        row[f"{name}_mean_error"] = float(images[name].mean() / max(float(ref.images[name].mean()), 1e-30) - 1.0)
        for metric in metrics.values():
            row[f"{name}_{metric.name}"] = metric.value
            if metric.name in ("relmse", "flip"):
                np.save(folder / f"{name}_{metric.name}_map.npy", metric.map.astype(np.float32))
    return row


def _render(scene, run: dict) -> tuple[dict, dict, dict]:
    from gpu_impl.renderer import Renderer, RenderSettings

    settings = RenderSettings(**{k: run[k] for k in ("method", "bounces", "directions", "resolution", "points", "splat_scale",
                                                     "width", "height", "supersampling", "spp", "frames", "seed")})
    gl = _gl()
    renderer = Renderer(gl, scene, settings)
    try:
        result = renderer.render()
    finally:
        renderer.release()
    t = result.timings
    timings = {"wall_s": t["wall_s"], "paths_per_pixel": result.params["paths_per_pixel"],
               "nodes_per_frame": result.stats["nodes_median"], "gl_renderer": gl.info["renderer"],
               **{f"ms_{k}": v for k, v in t["median_ms"].items() if "." not in k}}
    return result.images, timings, {**result.params, "warnings": result.warnings}


def _bundle_metrics(scene, run: dict, measure: dict, out: Path) -> dict:
    from evalkit.bundleset import DirectionSet
    from evalkit.metrics.bundles import compare_bundles, eye_vertices, next_hit_errors
    from gpu_impl.bundles import BundleTracer

    exact = exact_bundles(scene, run, out)
    tracer = BundleTracer(_gl(), scene, run["method"], directions=int(run["directions"]), resolution=int(run["resolution"]),
                          points=int(run["points"]), splat_scale=float(run["splat_scale"]))
    try:
        directions = DirectionSet.make(int(run["directions"]), seed=int(run["seed"]))
        tracer.build(directions)  # warm-up: the first build compiles and sizes the buffers
        stats = tracer.build(directions)
        bundles = tracer.read()
    finally:
        tracer.release()
    r = compare_bundles(bundles, exact)
    embree = exact_tracer(scene)
    vertices = eye_vertices(scene, embree, int(measure["eye_vertices"]), seed=int(run["seed"]))
    hit = next_hit_errors(bundles, embree, vertices, seed=int(run["seed"]))
    floor = next_hit_errors(exact, embree, vertices, seed=int(run["seed"]))
    row = {k: r[k] for k in ("exact_nodes", "test_nodes", "agreement", "hole_rate", "spurious_rate", "redundant_rate",
                             "same_prim_rate")}
    row["depth_error_rms"] = r["depth_error"]["rms"]
    row["worst_direction_hole_rate"] = max(r["per_direction"]["hole_rate"])
    for i, rate in enumerate(r["per_slope"]["hole_rate"]):
        row[f"hole_rate_slope{i}"] = rate
    row.update({"next_hit_error_rate": hit["error_rate"], "next_hit_exact_floor": floor["error_rate"],
                "next_hit_false_miss_rate": hit["false_miss_rate"], "next_hit_wrong_surface_rate": hit["wrong_surface_rate"],
                "next_hit_lookups": hit["lookups"], "build_ms": sum(v for v in stats["gpu_ms"].values() if v is not None),
                "build_wall_ms": stats["wall_ms"], "splat_radius": tracer.splat_radius if run["method"] == "imperfect" else None})
    return row


def read_rows(out: Path) -> list[dict]:
    path = out / "results.jsonl"
    if not path.is_file():
        return []
    rows = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if line.strip():
            try:
                rows.append(json.loads(line))
            except ValueError:
                raise InputError(str(path), f"line {n} is not JSON (a run cut off mid-write?); delete that line to resume") from None
    return rows


def write_csv(rows: list[dict], path: Path) -> None:
    import csv

    columns = list(dict.fromkeys(k for row in rows for k in row))
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, columns)
        writer.writeheader()
        writer.writerows(rows)


def run_study(study: Study, out: str | os.PathLike, workers: int = 1, executor: str = "local", scheduler: str | None = None,
              progress=print, command: str | None = None) -> list[dict]:
    """Run every run not finished yet, append its row, then write results.csv and the report.
    Returns every row (finished earlier or now), in the study's order."""
    from evalkit.report import write_report

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    done = {r["run_id"]: r for r in read_rows(out) if r.get("status") == "ok"}
    todo = [r for r in study.runs if run_id(r) not in done]
    progress(f"{study.name}: {len(study.runs)} runs, {len(done)} finished before, {len(todo)} to run "
             f"({executor}, {workers} worker(s)) into {out}")
    prepare(study, out, progress)
    with open(out / "results.jsonl", "a") as log:
        for row in _execute(todo, study.measure, out, workers, executor, scheduler):
            log.write(json.dumps(row, default=_json_default) + "\n")
            log.flush()
            done[row["run_id"]] = row
            if row["status"] != "ok":
                progress(f"run {row['run_id']} failed: {row['status']} (see {out / 'runs' / row['run_id'] / 'error.txt'})")
    rows = [done[run_id(r)] for r in study.runs]
    failed = [r for r in rows if r["status"] != "ok"]
    write_csv(rows, out / "results.csv")
    meta = {"study": study.name, "file": str(study.path) if study.path else None, "command": command or " ".join(sys.argv),
            "versions": versions(), "executor": executor, "workers": workers, "finished": time.strftime("%Y-%m-%d %H:%M:%S")}
    (out / "study.json").write_text(json.dumps(meta, indent=2) + "\n")
    write_report(study, rows, out, meta, failed)
    return rows


def _execute(todo: list[dict], measure: dict, out: Path, workers: int, executor: str, scheduler: str | None):
    """Rows of the runs as they finish, with a progress bar."""
    from tqdm import tqdm

    bar = tqdm(total=len(todo), unit="run", file=sys.stderr, disable=not todo)
    try:
        if executor == "dask":
            yield from _dask(todo, measure, out, workers, scheduler, bar)
        elif workers > 1:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor, as_completed

            # spawn, not fork: a forked child would inherit the parent's GL and LLVM state.
            with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
                futures = [pool.submit(run_case, run, measure, str(out)) for run in todo]
                for future in as_completed(futures):
                    bar.update()
                    yield future.result()
        else:
            for run in todo:
                row = run_case(run, measure, str(out))
                bar.update()
                yield row
    finally:
        bar.close()


def _dask(todo, measure, out, workers, scheduler, bar):
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None if scheduler else LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                                  dashboard_address=None)
    try:
        with Client(scheduler or cluster) as client:
            futures = [client.submit(run_case, run, measure, str(out), pure=False) for run in todo]
            for future in as_completed(futures):
                bar.update()
                yield future.result()
    finally:
        if cluster is not None:
            cluster.close()


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON")
