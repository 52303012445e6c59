"""Imperfect shadow maps against exact ones for the same light vertices, side by side in one run:
what a frame's maps cost and the share of connections whose visibility differs, from exact maps and
from Embree rays (the truth both approximate), over map sizes and points per map; then, at the
default size and points, pull-push hole filling against larger splats (the splat scales given).

    python benchmarks/shadow_maps.py [--scene atrium] [--vertices 256] [--receivers 2048]
                                     [--exact-sizes 256] [--sizes 32 64 128]
                                     [--points 1024 4096 16384]
                                     [--splat-scales 1.0 1.6 2.5] [--repeats 3] [--record JSON]

The light vertices are the first ``--vertices`` that frame 0's light paths leave (B=2, perfect
bundles K=32 R=128); the receivers are surface points the camera sees. Times are medians over the
repeats after a warm-up, host time around glFinish. "hidden" and "leaked" split the changed
connections: seen through exact maps (of the default size) but not through the others, and the
reverse. "light leaked" and "light hidden" are each map's own against the rays, weighted by what
each connection carries (`evalkit.metrics.light_visibility.light_shares`). Prints a table; the
last line is one JSON object with every figure, which ``--record`` also saves with the command and
versions (the documentation's results page "Shadow maps against rays" is made from it).
"""

from __future__ import annotations

import argparse
import json

from evalkit.core.scene import load_scene
from evalkit.core.settings import RenderSettings
from evalkit.metrics.light_visibility import (
    camera_points,
    changed_shares,
    differing_share,
    frame_light_vertices,
    light_shares,
    measure,
    traced_visibility,
)
from evalkit.records import write_record
from gpu_impl.context import GLContext
from gpu_impl.registry import METHODS, resolve
from gpu_impl.visibility import exact
from gpu_impl.visibility import imperfect as imperfect_maps

# The targets: at the defaults, a frame's imperfect maps cost at most a tenth of exact ones
# and change at most 2 % of connections.
TARGET_COST_RATIO, TARGET_DIFFERING = 0.1, 0.02


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="atrium")
    parser.add_argument("--vertices", type=int, default=256)
    parser.add_argument("--receivers", type=int, default=2048)
    parser.add_argument("--exact-sizes", type=int, nargs="+", default=[exact.DEFAULT_MAP_SIZE])
    parser.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128])
    parser.add_argument("--points", type=int, nargs="+", default=[1024, 4096, 16384])
    parser.add_argument("--splat-scales", type=float, nargs="+", default=[1.0, 1.6, 2.5])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--record", metavar="JSON", help="also save the report with its command and versions there")
    args = parser.parse_args()

    scene = load_scene(args.scene)
    base = dict(
        method=METHODS.default.name, strategy="bidirectional", directions=32, resolution=128, bounces=2, frames=1
    )
    gl = GLContext()
    paths = args.vertices
    while True:  # light paths that leave the scene leave fewer vertices: more paths until there are enough
        # (the light paths do not depend on the maps; imperfect ones leave room for more vertices)
        settings = RenderSettings(
            **base, seed=args.seed, light_paths=paths, light_visibility=imperfect_maps.VISIBILITY.name
        )
        settings = resolve(settings, "drop").settings
        vertices = frame_light_vertices(gl, scene, settings, args.vertices)
        if len(vertices.positions) >= args.vertices or paths >= 16 * args.vertices:
            break
        paths *= 2
    receivers = camera_points(scene, args.receivers, args.seed)
    truth = traced_visibility(scene, vertices, receivers)

    def run(visibility: str, **options) -> dict:
        s = resolve(
            RenderSettings(**base, seed=args.seed, light_paths=paths, light_visibility=visibility, **options), "drop"
        )
        return measure(gl, scene, s.settings, vertices, receivers, args.repeats)

    def against_rays(result: dict) -> dict:
        leaked, hidden = light_shares(result["visibility"], truth, vertices, receivers)
        return {
            "differ_rays": differing_share(result["visibility"], truth),
            "light_leaked_rays": leaked,
            "light_hidden_rays": hidden,
        }

    exact_maps = run(exact.VISIBILITY.name)
    rows = []
    for size in sorted(set(args.exact_sizes) | {exact.DEFAULT_MAP_SIZE}):
        r = exact_maps if size == exact.DEFAULT_MAP_SIZE else run(exact.VISIBILITY.name, light_sample_map_size=size)
        hidden, leaked = changed_shares(exact_maps["visibility"], r["visibility"])
        rows.append(
            {
                "maps": exact.VISIBILITY.name,
                "size": size,
                "points": None,
                "ms": r["ms"],
                "differ_exact": hidden + leaked,
                "hidden": hidden,
                "leaked": leaked,
                **against_rays(r),
            }
        )
    defaults = imperfect_maps.ImperfectSettings()
    configs = sorted({(s, p) for s in args.sizes for p in args.points} | {(defaults.ism_size, defaults.ism_points)})
    configs = [(size, points, defaults.ism_splat_scale, False) for size, points in configs]
    configs += [
        (defaults.ism_size, defaults.ism_points, scale, pull_push)
        for scale in args.splat_scales
        for pull_push in (False, True)
        if (scale, pull_push) != (defaults.ism_splat_scale, False)
    ]
    for size, points, scale, pull_push in configs:
        r = run(
            imperfect_maps.VISIBILITY.name,
            ism_size=size,
            ism_points=points,
            ism_splat_scale=scale,
            ism_pull_push=pull_push,
        )
        hidden, leaked = changed_shares(exact_maps["visibility"], r["visibility"])
        rows.append(
            {
                "maps": imperfect_maps.VISIBILITY.name,
                "size": size,
                "points": points,
                "splat_scale": scale,
                "pull_push": pull_push,
                "ms": r["ms"],
                "differ_exact": differing_share(exact_maps["visibility"], r["visibility"]),
                "hidden": hidden,
                "leaked": leaked,
                **against_rays(r),
            }
        )
    gl.release()

    print(
        f"{args.scene}: {len(vertices.positions)} light vertices ({paths} light paths), "
        f"{len(receivers[0])} receivers, {args.repeats} repeats"
    )
    print(
        f"{'maps':<10}{'size':>6}{'points':>8}{'scale':>7}{'pull-push':>11}{'ms':>10}{'/ exact':>9}"
        f"{'differ':>9}{'hidden':>9}{'leaked':>9}{'vs rays':>9}{'light leaked':>14}{'light hidden':>14}"
    )
    for r in rows:
        print(
            f"{r['maps']:<10}{r['size']:>6}{r['points'] or '':>8}{r.get('splat_scale', ''):>7}"
            f"{('on' if r.get('pull_push') else 'off') if r['points'] else '':>11}{r['ms']:>10.1f}"
            f"{r['ms'] / exact_maps['ms']:>9.3f}{100 * r['differ_exact']:>8.1f}%{100 * r['hidden']:>8.1f}%"
            f"{100 * r['leaked']:>8.1f}%{100 * r['differ_rays']:>8.1f}%"
            f"{100 * r['light_leaked_rays']:>13.3f}%{100 * r['light_hidden_rays']:>13.3f}%"
        )
    default = next(
        r
        for r in rows
        if (r["size"], r["points"], r.get("splat_scale"), r.get("pull_push"))
        == (defaults.ism_size, defaults.ism_points, defaults.ism_splat_scale, False)
    )
    summary = {
        "benchmark": "shadow_maps",
        "scene": args.scene,
        "light_vertices": len(vertices.positions),
        "light_paths": paths,
        "receivers": len(receivers[0]),
        "repeats": args.repeats,
        "rows": rows,
        "exact_ms": exact_maps["ms"],  # the default exact maps', which the ratios divide by
        "default_cost_ratio": default["ms"] / exact_maps["ms"],
        "default_differing": default["differ_exact"],
        "targets": {"cost_ratio": TARGET_COST_RATIO, "differing": TARGET_DIFFERING},
    }
    if args.record:
        write_record(args.record, summary)
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
