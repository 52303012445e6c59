"""Embree exact bundles against GL perfect bundles, side by side in one run, on the same lines.

    python benchmarks/exact_bundles.py [--scenes atrium] [--directions 256] [--resolution 128]
                                       [--repeats 3] [--seed 0] [--threads N]

Exact: wall time of `ExactTracer.bundles` (every core, re-casting, attributes and sorting
included; the BVH and coincidence layers are built once, outside the timing, and reported apart).
Hits per second per core = exact nodes / wall time / threads. GL perfect: the build's GPU pass
times (on llvmpipe: host time around glFinish) plus the read-back into a BundleSet, since the
exact builder's time includes producing its BundleSet. Medians over the repeats, interleaved.
Prints a table; the last line is one JSON object with every figure.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

from evalkit.core.bundleset import DirectionSet
from evalkit.core.scene import load_scene
from evalkit.core.settings import RenderSettings
from evalkit.metrics.bundles import compare_bundles
from gpu_impl.api import bundle_tracer
from gpu_impl.context import GLContext
from gpu_impl.scene_buffers import GpuScene
from references.embree import ExactTracer

TARGET_HITS_PER_CORE = 2e6  # the target, hits per second per core


def measure_scene(
    gl: GLContext, name: str, *, directions: int, resolution: int, repeats: int, seed: int, threads: int
) -> dict:
    scene = load_scene(name)
    ds = DirectionSet.make(directions, seed=seed)
    start = time.perf_counter()
    exact_tracer = ExactTracer(scene, threads=threads)
    prepare_s = time.perf_counter() - start
    gpu_scene = GpuScene(gl, scene)
    # The default method: perfect bundles, which exact bundles are the ground truth of.
    settings = RenderSettings(directions=directions, resolution=resolution, node_budget=16 << 30)
    gl_tracer = bundle_tracer(gl, gpu_scene, settings)
    exact_s, gl_s = [], []
    for _ in range(repeats):
        start = time.perf_counter()
        exact = exact_tracer.bundles(ds, resolution)
        exact_s.append(time.perf_counter() - start)
        start = time.perf_counter()
        gl_tracer.build(ds)
        perfect = gl_tracer.read()
        gl_s.append(time.perf_counter() - start)
    gl_tracer.release()
    gpu_scene.release()
    agreement = compare_bundles(perfect, exact)["agreement"]
    e, g = statistics.median(exact_s), statistics.median(gl_s)
    return {
        "scene": name,
        "triangles": scene.triangle_count,
        "directions": directions,
        "resolution": resolution,
        "threads": exact_tracer.threads,
        "exact_nodes": exact.node_count,
        "casts": exact.stats["casts"],
        "coincidence_layers": exact.params["coincidence_layers"],
        "prepare_s": prepare_s,
        "exact_s": e,
        "gl_perfect_s": g,
        "exact_over_gl": e / g,
        "hits_per_s_per_core": exact.node_count / e / exact_tracer.threads,
        "casts_per_s_per_core": exact.stats["casts"] / e / exact_tracer.threads,
        "perfect_agreement": agreement,
        "gl_renderer": gl.info["renderer"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["atrium"])
    parser.add_argument("--directions", type=int, default=256)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=os.cpu_count())
    args = parser.parse_args()
    with GLContext() as gl:
        rows = [
            measure_scene(
                gl,
                name,
                directions=args.directions,
                resolution=args.resolution,
                repeats=args.repeats,
                seed=args.seed,
                threads=args.threads,
            )
            for name in args.scenes
        ]
    print(
        f"exact (Embree) vs GL perfect bundles, K={args.directions} R={args.resolution}, medians of {args.repeats}, "
        f"GL: {rows[0]['gl_renderer']}"
    )
    print(
        f"{'scene':12}{'nodes':>12}{'threads':>8}{'prep s':>8}{'exact s':>9}{'GL s':>8}{'exact/GL':>10}"
        f"{'Mhit/s/core':>13}{'agreement':>11}"
    )
    for r in rows:
        print(
            f"{r['scene']:12}{r['exact_nodes']:>12,}{r['threads']:>8}{r['prepare_s']:>8.2f}{r['exact_s']:>9.2f}"
            f"{r['gl_perfect_s']:>8.2f}{r['exact_over_gl']:>10.2f}{r['hits_per_s_per_core'] / 1e6:>13.2f}"
            f"{r['perfect_agreement']:>11.4%}"
        )
    met = all(r["hits_per_s_per_core"] >= TARGET_HITS_PER_CORE for r in rows)
    print(f"target {TARGET_HITS_PER_CORE / 1e6:.0f} M hits/s per core: {'met' if met else 'NOT met'}")
    print(json.dumps({"benchmark": "exact_bundles", "target_hits_per_s_per_core": TARGET_HITS_PER_CORE, "rows": rows}))


if __name__ == "__main__":
    main()
