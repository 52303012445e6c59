"""Coherent eye paths against independent ones, measured side by side in one run: the bounce
passes' time, each pixel's variance and the image mean's frame-to-frame spread, with perfect and
imperfect bundles, when every path chooses its own bundle each bounce (coherent_paths 1, the
default) and when neighbouring G-buffer samples share the choice (32, a warp of a GPU).

    python benchmarks/coherent_paths.py [--scene atrium] [--width 480 --height 256] [--bounces 3]
                                        [--frames 6] [--coherent-paths 1 32] [--seed 0]

    python benchmarks/coherent_paths.py --scene cornell-box --width 64 --height 64 --frames 64

The bundles are the poster's (K=256, R=128, N=16384). Times are medians over the frames (on
llvmpipe: host time around glFinish). The variance is each pixel's variance of the indirect image
over the frames, averaged over the image; the spread is the standard deviation of the frames'
indirect image means. Sharing a choice leaves each pixel's estimate as it was, so its variance
should not change; the frame means of correlated pixels spread more. Prints a table; the last line
is one JSON object with every figure.
"""

from __future__ import annotations

import argparse
import json

from evalkit.core.scene import load_scene
from evalkit.core.settings import PRESETS, RenderSettings
from evalkit.records import write_record
from gpu_impl.api import render
from gpu_impl.context import GLContext
from gpu_impl.methods import imperfect, perfect
from gpu_impl.registry import resolve
from gpu_impl.timing import PassTimer

METHODS = (perfect.METHOD.name, imperfect.METHOD.name)


def measure(gl: GLContext, scene, settings: RenderSettings) -> dict:
    result = render(scene, resolve(settings, inapplicable="drop").settings, gl=gl)
    median = result.timings["median_ms"]
    frame_means = result.frame_means["indirect"].mean(axis=1)  # (F,): each frame's mean over channels
    return {
        "bounces_ms": sum(v for k, v in median.items() if k.startswith("bounce")),
        "frame_ms": median["frame"],
        "indirect_mean": float(result.images["indirect"].mean()),
        "pixel_variance": float(result.variances["indirect"].mean()) * settings.frames,  # of one frame
        "frame_mean_sd": float(frame_means.std(ddof=1)),
    }


def run(*, scene_name: str, width: int, height: int, bounces: int, frames: int, tiles: list[int], seed: int) -> dict:
    scene = load_scene(scene_name)
    base = {**PRESETS["paper"], "width": width, "height": height, "supersampling": 1, "frames": frames, "seed": seed}
    with GLContext() as gl:
        device, timing = gl.info, PassTimer(gl).method
        results = {
            f"{method} T={tile}": measure(
                gl, scene, RenderSettings(**base, method=method, bounces=bounces, coherent_paths=tile)
            )
            for method in METHODS
            for tile in tiles
        }
    first, last = tiles[0], tiles[-1]

    def ratio(method: str, value: str, top: int, bottom: int) -> float:
        return results[f"{method} T={top}"][value] / results[f"{method} T={bottom}"][value]

    ratios = {
        method: {
            f"bounces_T{first}_over_T{last}": ratio(method, "bounces_ms", first, last),
            f"pixel_variance_T{last}_over_T{first}": ratio(method, "pixel_variance", last, first),
            f"frame_mean_sd_T{last}_over_T{first}": ratio(method, "frame_mean_sd", last, first),
        }
        for method in METHODS
    }
    first_method, second_method = METHODS
    frame_ratio = {
        str(tile): results[f"{first_method} T={tile}"]["frame_ms"] / results[f"{second_method} T={tile}"]["frame_ms"]
        for tile in tiles
    }
    return {
        "benchmark": "coherent_paths",
        "scene": scene_name,
        "device": device["renderer"],
        "gl_version": device["version"],
        "timing": timing,
        "width": width,
        "height": height,
        "bounces": bounces,
        "frames": frames,
        "directions": base["directions"],
        "resolution": base["resolution"],
        "points": base["points"],
        "coherent_paths": tiles,
        "seed": seed,
        "results": results,
        "ratios": ratios,
        f"{first_method}_over_{second_method}_frame": frame_ratio,
    }


def print_table(report: dict) -> None:
    print(
        f"coherent paths, {report['scene']} on {report['device']}: {report['width']}x{report['height']}, "
        f"B={report['bounces']}, K={report['directions']} R={report['resolution']} N={report['points']}; "
        f"{report['frames']} frames ({report['timing']})"
    )
    header = f"{'config':<18}{'bounces ms':>12}{'frame ms':>12}{'indirect':>12}{'pixel var':>12}{'frame sd':>12}"
    print(header)
    print("-" * len(header))
    for name, r in report["results"].items():
        print(
            f"{name:<18}{r['bounces_ms']:>12.1f}{r['frame_ms']:>12.1f}{r['indirect_mean']:>12.5f}"
            f"{r['pixel_variance']:>12.3e}{r['frame_mean_sd']:>12.3e}"
        )
    for method, ratios in report["ratios"].items():
        print(f"{method}: " + ", ".join(f"{k} {v:.2f}" for k, v in ratios.items()))
    first, second = METHODS
    for tile, ratio in report[f"{first}_over_{second}_frame"].items():
        print(f"{first} / {second} frame at coherent_paths {tile}: {ratio:.2f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="atrium")
    parser.add_argument("--width", type=int, default=480)
    parser.add_argument("--height", type=int, default=256)
    parser.add_argument("--bounces", type=int, default=3)
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--coherent-paths", type=int, nargs="+", default=[1, 32])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--record", metavar="JSON", help="also save the report with its command and versions there")
    args = parser.parse_args()
    if args.frames < 2:
        parser.error("--frames must be at least 2: the variances are over frames")
    if len(set(args.coherent_paths)) != len(args.coherent_paths) or len(args.coherent_paths) < 2:
        parser.error("--coherent-paths takes two or more different values: the first is compared with the last")
    report = run(
        scene_name=args.scene,
        width=args.width,
        height=args.height,
        bounces=args.bounces,
        frames=args.frames,
        tiles=args.coherent_paths,
        seed=args.seed,
    )
    if args.record:
        write_record(args.record, report)
    print_table(report)
    print(json.dumps(report))


if __name__ == "__main__":
    main()
