"""One run of a study, measured into one row: every parameter, the metric values
(``<image>_<metric>`` and the bundle metrics), timings, versions, its seed and its status.

A run never raises: a failure is a row whose ``status`` says what went wrong, with the traceback
in the run's folder, so a study reports it and goes on.
"""

from __future__ import annotations

import importlib.metadata
import platform
import shutil
import time
import traceback
from pathlib import Path

import numpy as np

from evalkit.core import VERSION
from evalkit.core.atomic import atomic_path, write_text
from evalkit.core.bundleset import DirectionSet
from evalkit.core.errors import LimitError
from evalkit.core.exr import write_exr
from evalkit.core.scene import Scene, load_scene
from evalkit.metrics.bundles import (
    compare_bundles,
    eye_vertices,
    next_hit_errors,
    scene_surfaces,
    wrong_lookups_per_path,
)
from evalkit.metrics.confidence import confidence
from evalkit.metrics.images import compare_images
from evalkit.study.artefacts import exact_bundles, exact_tracer, film_size, reference_for
from evalkit.study.spec import render_settings, run_id
from gpu_impl.api import bundle_tracer, render
from gpu_impl.context import default_context
from gpu_impl.scene_buffers import GpuScene
from references.mitsuba import timed_render

VERSIONED = (
    "mitsuba",
    "drjit",
    "moderngl",
    "numpy",
    "embreex",
    "flip-evaluator",
    "colour-science",
)


def versions() -> dict:
    """The versions of Python and of every package a row's numbers depend on."""
    out = {"python": platform.python_version(), "raybundle-evalkit": VERSION}
    for package in VERSIONED:
        try:
            out[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            out[package] = None
    return out


def execute_run(run: dict, measure: dict, out: str) -> dict:
    """One run: its row of parameters, metrics, timings and versions. A failure is a row with
    ``status`` 'error: ...' (the traceback goes to the run's folder), never an exception."""
    out = Path(out)
    key = run_id(run)
    folder = out / "runs" / key
    # A run without its row starts from an empty folder: nothing a killed attempt left survives.
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    row = {"run_id": key, **run, "status": "ok", **{f"version_{k}": v for k, v in versions().items()}}
    start = time.perf_counter()
    try:
        row.update(_measure(run, measure, out, folder))
    except Exception as e:  # noqa: BLE001 -- a study reports a failed run and goes on
        write_text(folder / "error.txt", traceback.format_exc())
        row["status"] = f"error: {type(e).__name__}: {e}".splitlines()[0]
        if isinstance(e, LimitError):  # the settings at fault, for a caller that chooses them
            row["limit_settings"] = list(e.settings)
    row["run_s"] = round(time.perf_counter() - start, 3)
    return row


def _measure(run: dict, measure: dict, out: Path, folder: Path) -> dict:
    scene = load_scene(run["scene"])
    row = {"scene_hash": scene.content_hash(), "warnings": " | ".join(scene.warnings)}
    if measure["bundles"] and run["method"] != "mitsuba":
        row.update(_bundle_metrics(scene, run, measure, out))
    if not measure["render"]:
        return row
    result = None  # a bundle render: its frames say how noisy its images are
    if run["method"] == "mitsuba":
        images, seconds, info = timed_render(
            scene, int(run["bounces"]), int(run["spp"]), *film_size(scene, run), int(run["seed"])
        )
        row.update({"wall_s": seconds, "paths_per_pixel": int(run["spp"]), "gl_renderer": None})
        provenance = {**run, **info}
    else:
        result, timings = _render(scene, run)
        images, provenance = result.images, {**result.params, "warnings": result.warnings}
        row.update(timings)
    if not measure["images"]:
        return row
    ref = reference_for(scene, run, measure, out, progress=lambda line: None)
    row["reference"] = str(ref.path)
    for name in measure["images"]:
        write_exr(folder / f"{name}.exr", images[name].astype(np.float32), {**provenance, "image": name})
        metrics = compare_images(
            images[name], ref.images[name], measure["metrics"], f"{run['method']} {name}", f"reference {name}"
        )
        # The relative error of the image's mean: bias that noise cannot hide (light lost to holes,
        # or gained from splats overhanging an emitter).
        row[f"{name}_mean_error"] = float(images[name].mean() / max(float(ref.images[name].mean()), 1e-30) - 1.0)
        if result is not None:
            row.update(_confidence(name, result, ref))
        for metric in metrics.values():
            row[f"{name}_{metric.name}"] = metric.value
            if metric.name in ("relmse", "flip"):
                with atomic_path(folder / f"{name}_{metric.name}_map.npy") as tmp:
                    np.save(tmp, metric.map.astype(np.float32))
    return row


def _confidence(name: str, result, ref) -> dict:
    """How sure the comparison of one image is: the ratio of its mean to the reference's with the
    95 % interval, and the share of pixels the z-test finds outside the noise
    (`evalkit.metrics.confidence`)."""
    variance = None if result.variances is None else result.variances[name]
    c = confidence(result.images[name], variance, result.frame_means[name], ref.images[name], ref.variances[name])
    ratio = c["mean_ratio"]["all"]
    row = {
        f"{name}_mean_ratio": ratio["ratio"],
        f"{name}_mean_ratio_lo": ratio["lo"],
        f"{name}_mean_ratio_hi": ratio["hi"],
    }
    if "z_test" in c:
        row[f"{name}_z_outside"] = c["z_test"]["outside_share"]
    return row


def _render(scene: Scene, run: dict):
    """The run's render and its row's timings."""
    result = render(scene, render_settings(run))
    t = result.timings
    timings = {
        "wall_s": t["wall_s"],
        "frames_rendered": result.params["frames_rendered"],
        "paths_per_pixel": result.params["paths_per_pixel"],
        "nodes_per_frame": result.stats["nodes_median"],
        "gl_renderer": result.params["gl"]["renderer"],
        **{f"ms_{k}": v for k, v in t["median_ms"].items() if "." not in k},
    }
    return result, timings


def _bundle_metrics(scene: Scene, run: dict, measure: dict, out: Path) -> dict:
    exact = exact_bundles(scene, run, out)
    gl = default_context()
    with (
        GpuScene(gl, scene) as gpu_scene,
        bundle_tracer(gl, gpu_scene, render_settings(run), count_covered=True) as tracer,
    ):
        directions = DirectionSet.make(int(run["directions"]), seed=int(run["seed"]))
        tracer.build(directions)  # warm-up: the first build compiles and sizes the buffers
        stats = tracer.build(directions)
        bundles = tracer.read()
        splat_radius = tracer.params().get("splat_radius")
    r = compare_bundles(bundles, exact, surfaces=scene_surfaces(scene))
    embree = exact_tracer(scene)
    # The vertices of every depth a path of the run's bounces looks up from (`resolution_advice`).
    depths = int(run["bounces"]) + 1
    vertices = eye_vertices(scene, embree, int(measure["eye_vertices"]), seed=int(run["seed"]), depths=depths)
    hit = next_hit_errors(bundles, embree, vertices, seed=int(run["seed"]))
    floor = next_hit_errors(exact, embree, vertices, seed=int(run["seed"]))
    row = {
        k: r[k]
        for k in (
            "exact_nodes",
            "test_nodes",
            "agreement",
            "hole_rate",
            "leak_rate",
            "offset_rate",
            "coincident_rate",
            "spurious_rate",
            "spurious_per_crossing",
            "redundant_rate",
            "same_prim_rate",
        )
    }
    # Per exact crossing: the lines splats cover (the nodes without merging: what the splat size
    # costs), and the nodes written before and kept after merging.
    row["raw_nodes"] = stats["raw_nodes"]
    row["nodes_per_crossing"] = stats["covered_nodes"] / max(r["exact_nodes"], 1)
    row["written_nodes_per_crossing"] = stats["raw_nodes"] / max(r["exact_nodes"], 1)
    row["kept_nodes_per_crossing"] = r["test_nodes"] / max(r["exact_nodes"], 1)
    row["depth_error_rms"] = r["depth_error"]["rms"]
    # How far offset surfaces lie from the crossing, in splat radii (imperfect bundles).
    row["offset_splat_radii_p50"] = r["offset_depth"]["splat_radii_p50"]
    row["offset_splat_radii_p90"] = r["offset_depth"]["splat_radii_p90"]
    row["worst_direction_hole_rate"] = max(r["per_direction"]["hole_rate"])
    for i, rate in enumerate(r["per_slope"]["hole_rate"]):
        row[f"hole_rate_slope{i}"] = rate
    row.update(
        {
            "next_hit_error_rate": hit["error_rate"],
            "next_hit_exact_floor": floor["error_rate"],
            "wrong_lookups_per_path": wrong_lookups_per_path(floor),
            "next_hit_false_miss_rate": hit["false_miss_rate"],
            "next_hit_wrong_surface_rate": hit["wrong_surface_rate"],
            "next_hit_lookups": hit["lookups"],
            "build_ms": sum(v for v in stats["gpu_ms"].values() if v is not None),
            "build_wall_ms": stats["wall_ms"],
            "splat_radius": splat_radius,
        }
    )
    return row
