"""What skipping work a scene does not need saves, each skip against the unskipped path, side by
side in one run:

- texture variant: reading bundles of a scene without textures (expanding the slim nodes into
  normals, albedos and emission) with the shader variant that has no texture fetch (TEXTURES 0)
  against the one that has it; the eye-path shaders choose their variant by the same rule;
- early bounce stop: a render whose paths all end at the first bounce (black diffuse surfaces
  around an emitter) with the bounce passes skipped once no path is alive, against running all B;
- bundle reuse: frames with fixed directions on a static scene (bundles and node direct light made
  once) against rotating directions (both built every frame); this one changes the result, so its
  relMSE against the committed Mitsuba reference is printed beside the time;
- node buffer sizing: node buffers made for a fixed 1 GiB, then sized from the first frame's
  measured count (the first guess from the depth complexity is printed too).

    python benchmarks/skip.py [--repeats 5] [--frames 8]

Times are medians over the repeats, runs interleaved. Prints a table; the last line is one JSON
object with every figure.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from dataclasses import replace

import numpy as np

from evalkit.core.bundleset import DirectionSet
from evalkit.core.scene import load_scene
from evalkit.core.settings import RenderSettings
from evalkit.metrics.images import relmse
from gpu_impl.api import bundle_tracer, render
from gpu_impl.context import GLContext
from gpu_impl.layout import NODE
from gpu_impl.scene_buffers import GpuScene
from references.mitsuba import COMMITTED_STORE, load_reference, store_entry


def texture_variant(gl, repeats: int) -> dict:
    ds = DirectionSet.make(64, seed=0)
    with GpuScene(gl, load_scene("cornell-box")) as scene:  # no textures
        lists = RenderSettings(directions=64, resolution=128)  # perfect bundles, the default method
        tracers = {t: bundle_tracer(gl, scene, lists, textures=t) for t in (False, True)}
        for tracer in tracers.values():
            tracer.build(ds)
        times, lists = {t: [] for t in tracers}, {}
        for _ in range(repeats):
            for t, tracer in tracers.items():
                start = time.perf_counter()
                lists[t] = tracer.read()
                times[t].append((time.perf_counter() - start) * 1e3)
        for tracer in tracers.values():
            tracer.release()
    same = all(
        np.array_equal(getattr(lists[False], n), getattr(lists[True], n)) for n in ("offsets", *lists[True].NODE_FIELDS)
    )
    skipped, full = statistics.median(times[False]), statistics.median(times[True])
    return {
        "what": "reading perfect bundles, cornell-box K=64 R=128",
        "skipped_ms": skipped,
        "unskipped_ms": full,
        "saving": full / skipped,
        "result_change": "none: the same lists, bitwise" if same else "THE LISTS DIFFER",
    }


def black_scene():
    """cornell-box with every non-emissive surface black: every path ends at its first bounce."""
    scene = load_scene("cornell-box")
    materials = [m if m.emissive else replace(m, albedo=(0.0, 0.0, 0.0)) for m in scene.materials]
    return replace(scene, materials=materials)


def early_stop(gl, repeats: int, frames: int) -> dict:
    scene = black_scene()
    base = RenderSettings(bounces=8, directions=32, resolution=128, width=128, height=128, frames=frames, spp=4)
    times, images, skipped = {s: [] for s in (True, False)}, {}, 0
    for _ in range(repeats):
        for stop in times:
            result = render(scene, replace(base, stop_early=stop), gl=gl)
            times[stop].append(sum(v for k, v in result.timings["median_ms"].items() if k.startswith("bounce_")) or 0.0)
            images[stop] = result.images["total"]
            skipped = max(skipped, result.stats["bounce_passes_skipped"])
    on, off = statistics.median(times[True]), statistics.median(times[False])
    return {
        "what": "bounce passes per frame, black cornell-box, B=8",
        "skipped_ms": on,
        "unskipped_ms": off,
        "saving": off / max(on, 1e-9),
        "passes_skipped_per_frame": skipped / frames,
        "result_change": f"max |difference| {float(np.abs(images[True] - images[False]).max()):.3g}",
    }


def bundle_reuse(gl, repeats: int, frames: int) -> dict:
    scene = load_scene("cornell-box")
    ref = load_reference(store_entry(scene.name, scene.content_hash(), 3, 16384, 128, 128, 0, COMMITTED_STORE))
    base = RenderSettings(bounces=3, directions=32, resolution=128, width=128, height=128, frames=frames, spp=16)
    times, errors = {r: [] for r in (False, True)}, {r: [] for r in (False, True)}
    for seed in range(repeats):
        for rotate in times:
            result = render(scene, replace(base, rotate_directions=rotate, seed=seed), gl=gl)
            times[rotate].append(result.timings["wall_s"] * 1e3 / frames)
            errors[rotate].append(relmse(result.images["indirect"], ref.images["indirect"]).value)
    reuse, rotate = statistics.median(times[False]), statistics.median(times[True])
    return {
        "what": f"frame, cornell-box K=32 R=128 B=3, {frames} frames",
        "skipped_ms": reuse,
        "unskipped_ms": rotate,
        "saving": rotate / reuse,
        "result_change": f"indirect relMSE {statistics.median(errors[False]):.4g} (fixed) vs "
        f"{statistics.median(errors[True]):.4g} (rotating), medians over seeds 0..{repeats - 1}",
    }


def node_capacity(gl) -> dict:
    """Node buffers made for a fixed 1 GiB (as if sized without a measurement), then sized from
    the first frame's count; the first guess from the depth complexity is printed beside them."""
    fixed = (1 << 30) // NODE.itemsize
    with (
        GpuScene(gl, load_scene("atrium")) as scene,
        bundle_tracer(gl, scene, RenderSettings(directions=32, resolution=128), initial_capacity=fixed) as tracer,
    ):
        guess = tracer.predicted_nodes()
        for f in range(2):
            tracer.build(DirectionSet.make(32, seed=0, frame=f))
        after, nodes = tracer.capacity, tracer.stats["nodes"]
    return {
        "what": "node capacity, atrium K=32 R=128",
        "fixed_1gib_nodes": fixed,
        "after_first_frame_nodes": after,
        "first_guess_nodes": guess,
        "measured_nodes": nodes,
        "saving": fixed / after,
        "result_change": "none",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--frames", type=int, default=8)
    args = parser.parse_args()
    with GLContext() as gl:
        results = {
            "texture_variant": texture_variant(gl, args.repeats),
            "early_bounce_stop": early_stop(gl, args.repeats, args.frames),
            "bundle_reuse": bundle_reuse(gl, args.repeats, args.frames),
            "node_capacity": node_capacity(gl),
        }
        renderer = gl.info["renderer"]
    print(f"GL: {renderer}; medians of {args.repeats} repeats")
    print(f"{'skip':20}{'skipped':>14}{'unskipped':>14}{'saving':>9}  measured on / result change")
    for name, r in results.items():
        if name == "node_capacity":
            print(
                f"{name:20}{r['after_first_frame_nodes']:>14,}{r['fixed_1gib_nodes']:>14,}{r['saving']:>8.2f}x  "
                f"nodes (sized from the last frame / a fixed 1 GiB); {r['what']}, {r['measured_nodes']:,} measured, "
                f"first guess {r['first_guess_nodes']:,}"
            )
        else:
            print(
                f"{name:20}{r['skipped_ms']:>11.1f} ms{r['unskipped_ms']:>11.1f} ms{r['saving']:>8.2f}x  "
                f"{r['what']}; {r['result_change']}"
            )
    print(json.dumps({"gl_renderer": renderer, "repeats": args.repeats, **results}))


if __name__ == "__main__":
    main()
