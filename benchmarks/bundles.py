"""Bundle build speed, measured side by side in one run: perfect bundles, imperfect bundles, and a
raw-raster baseline (the perfect bundles' geometry and vertex work with an empty fragment shader;
also the splats' own, for reference).

    python benchmarks/bundles.py [--scenes atrium cornell-box] [--directions 256] [--resolution 128]
                                 [--points 16384] [--splat-scale 2.0] [--repeats 3] [--seed 0]

Times are per build, medians over the repeats, from the per-pass GPU timers of `BundleTracer`
(on llvmpipe: host time around glFinish). Runs are interleaved so drift hits every column alike.
Prints a table; the last line is one JSON object with every figure.
"""

from __future__ import annotations

import argparse
import json
import statistics

from evalkit.core.bundleset import DirectionSet
from evalkit.core.scene import load_scene
from gpu_impl.bundles import DEFAULT_SPLAT_SCALE, BundleTracer
from gpu_impl.context import GLContext
from gpu_impl.scene_buffers import GpuScene

# The targets: imperfect builds >= 6x faster than perfect ones on atrium (the poster:
# 161 ms vs 27 ms), and perfect bundles cost <= 2x the raw raster.
TARGET_SPEEDUP = 6.0
TARGET_PERFECT_OVER_RAW = 2.0


def build_ms(stats: dict) -> float:
    return sum(stats["gpu_ms"].values())


def measure_scene(gl: GLContext, name: str, *, directions: int, resolution: int, points: int, splat_scale: float,
                  repeats: int, seed: int) -> dict:
    scene = GpuScene(gl, load_scene(name))
    ds = DirectionSet.make(directions, seed=seed)
    common = dict(directions=directions, resolution=resolution, points=points, splat_scale=splat_scale, node_budget=16 << 30)
    tracers = {method: BundleTracer(gl, scene, method, **common) for method in ("perfect", "imperfect")}
    times: dict[str, list[float]] = {"perfect": [], "imperfect": [], "raw": [], "raw_splats": []}
    passes: dict[str, list[dict]] = {"perfect": [], "imperfect": []}
    stats = {}
    for _ in range(repeats):
        for method, tracer in tracers.items():
            stats[method] = tracer.build(ds)
            times[method].append(build_ms(stats[method]))
            passes[method].append(stats[method]["gpu_ms"])
        times["raw"].append(tracers["perfect"].raw_raster(ds))
        times["raw_splats"].append(tracers["imperfect"].raw_raster(ds))
    for tracer in tracers.values():
        tracer.release()
    scene.release()
    median = {k: statistics.median(v) for k, v in times.items()}
    return {
        "triangles": scene.triangle_count,
        "median_ms": median,
        "passes_median_ms": {m: {p: statistics.median(r[p] for r in passes[m]) for p in passes[m][0]} for m in passes},
        "perfect_over_imperfect": median["perfect"] / median["imperfect"],
        "perfect_over_raw": median["perfect"] / median["raw"],
        "imperfect_over_raw_splats": median["imperfect"] / median["raw_splats"],
        "nodes": {m: stats[m]["nodes"] for m in stats},
        "redundant_nodes": {m: stats[m]["redundant_nodes"] for m in stats},
        "node_bytes": {m: stats[m]["node_bytes"] for m in stats},
        "splat_radius": tracers["imperfect"].splat_radius,
    }


def run(*, scenes: list[str], directions: int, resolution: int, points: int, splat_scale: float, repeats: int,
        seed: int) -> dict:
    with GLContext() as gl:
        device = gl.info
        results = {name: measure_scene(gl, name, directions=directions, resolution=resolution, points=points,
                                       splat_scale=splat_scale, repeats=repeats, seed=seed) for name in scenes}
    targets = {}
    if "atrium" in results:
        targets["atrium_imperfect_speedup_ge_6"] = results["atrium"]["perfect_over_imperfect"] >= TARGET_SPEEDUP
    for name, r in results.items():
        targets[f"{name}_perfect_le_2x_raw"] = r["perfect_over_raw"] <= TARGET_PERFECT_OVER_RAW
    return {"benchmark": "bundles", "device": device["renderer"], "gl_version": device["version"],
            "timing": "host time around glFinish (llvmpipe)" if "llvmpipe" in device["renderer"] else "GL timer queries",
            "directions": directions, "resolution": resolution, "points": points, "splat_scale": splat_scale,
            "repeats": repeats, "seed": seed, "scenes": results, "targets_met": targets}


def print_table(report: dict) -> None:
    print(f"bundle builds on {report['device']}: K={report['directions']} R={report['resolution']} "
          f"N={report['points']} splat scale {report['splat_scale']}, median of {report['repeats']} ({report['timing']})")
    header = f"{'scene':<12} {'tris':>8} {'perfect ms':>11} {'imperfect ms':>13} {'raw ms':>9} {'raw splat ms':>13} " \
             f"{'perf/imperf':>11} {'perf/raw':>9} {'nodes perf':>11} {'nodes imperf':>13}"
    print(header)
    print("-" * len(header))
    for name, r in report["scenes"].items():
        m = r["median_ms"]
        print(f"{name:<12} {r['triangles']:>8,} {m['perfect']:>11.1f} {m['imperfect']:>13.1f} {m['raw']:>9.1f} "
              f"{m['raw_splats']:>13.1f} {r['perfect_over_imperfect']:>11.2f} {r['perfect_over_raw']:>9.2f} "
              f"{r['nodes']['perfect']:>11,} {r['nodes']['imperfect']:>13,}")
    for name, r in report["scenes"].items():
        for method, p in r["passes_median_ms"].items():
            print(f"  {name} {method} passes: " + ", ".join(f"{k} {v:.1f} ms" for k, v in p.items()))
    for target, met in report["targets_met"].items():
        print(f"target {target}: {'met' if met else 'NOT met'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["atrium", "cornell-box"])
    parser.add_argument("--directions", type=int, default=256)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--points", type=int, default=16384)
    parser.add_argument("--splat-scale", type=float, default=DEFAULT_SPLAT_SCALE)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    report = run(scenes=args.scenes, directions=args.directions, resolution=args.resolution, points=args.points,
                 splat_scale=args.splat_scale, repeats=args.repeats, seed=args.seed)
    print_table(report)
    print(json.dumps(report))


if __name__ == "__main__":
    main()
