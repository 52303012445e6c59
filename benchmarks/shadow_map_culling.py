"""Shadow maps drawn from the clusters each view sees against every triangle into every view, side by
side in one run: the fixed lights' maps and a frame's light vertices' exact cube maps, their times,
the share of triangles in the views' clusters (over every view of the atlas), and whether the two
atlases agree bit for bit.

    python benchmarks/shadow_map_culling.py [--scenes atrium lit-room cornell-box] [--vertices 64]
                                            [--map-size 256] [--repeats 3] [--record JSON]

The light vertices are the first ``--vertices`` that frame 0's light paths leave (B=2, perfect
bundles K=32 R=128). Times are medians over the repeats after a warm-up, host time around glFinish.
"Every triangle" is the same pass with the culling test answering yes for every cluster. Prints a
table; the last line is one JSON object with every figure, which ``--record`` also saves with the
command and versions (the documentation's results page "Shadow-map culling" is made from it).
"""

from __future__ import annotations

import argparse
import json
from unittest import mock

import numpy as np

from evalkit.core.scene import load_scene
from evalkit.core.settings import RenderSettings
from evalkit.metrics.light_visibility import frame_light_vertices, vertex_shadow_maps
from evalkit.records import write_record
from gpu_impl import lights as gpu_lights
from gpu_impl.context import GLContext
from gpu_impl.registry import METHODS, resolve
from gpu_impl.timing import median_ms
from gpu_impl.visibility import exact


def every_cluster(to_clip, origin, axis, lo, hi) -> np.ndarray:
    return np.ones((len(to_clip), len(lo)), dtype=bool)


def measure(gl: GLContext, scene, settings, vertices, repeats: int) -> dict:
    """Times of the fixed lights' maps and of the light vertices' maps, the triangles of the clusters
    that reach into the views over views x triangles, and the atlas' bits (distances, then the
    triangles seen)."""
    with vertex_shadow_maps(gl, scene, settings, len(vertices.positions)) as lights:
        fixed_ms = median_ms(gl, lights.render_shadow_maps, repeats) if lights.fixed_views else 0.0
        vertex_ms = median_ms(gl, lambda: lights.set_light_vertices(vertices, 0, 0), repeats)
        commands = lights.draw_commands(range(len(lights.view_records)))
        in_view = commands["count"].sum() / 3 / (len(lights.view_records) * lights.gpu_scene.triangle_count)
        atlas = lights.read_atlas().view(np.uint32).ravel()
        return {
            "fixed_ms": fixed_ms,
            "vertex_ms": vertex_ms,
            "in_view": float(in_view),
            "bits": np.concatenate([atlas, lights.read_atlas(channels=1).ravel()]),
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="+", default=["atrium", "lit-room", "cornell-box"])
    parser.add_argument("--vertices", type=int, default=64)
    parser.add_argument("--map-size", type=int, default=exact.DEFAULT_MAP_SIZE)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--record", metavar="JSON", help="also save the report with its command and versions there")
    args = parser.parse_args()

    gl = GLContext()
    rows = []
    for name in args.scenes:
        scene = load_scene(name)
        settings = RenderSettings(
            method=METHODS.default.name,
            strategy="bidirectional",
            directions=32,
            resolution=128,
            bounces=2,
            frames=1,
            light_paths=args.vertices,
            light_visibility=exact.VISIBILITY.name,
            light_sample_map_size=args.map_size,
        )
        settings = resolve(settings, "drop").settings
        vertices = frame_light_vertices(gl, scene, settings, args.vertices)
        culled = measure(gl, scene, settings, vertices, args.repeats)
        with mock.patch.object(gpu_lights, "view_clusters", every_cluster):
            every = measure(gl, scene, settings, vertices, args.repeats)
        rows.append(
            {
                "scene": name,
                "triangles": len(scene.arrays().faces),
                "light_vertices": len(vertices.positions),
                "fixed_ms": [every["fixed_ms"], culled["fixed_ms"]],
                "vertex_ms": [every["vertex_ms"], culled["vertex_ms"]],
                "vertex_speedup": every["vertex_ms"] / culled["vertex_ms"],
                "in_view": culled["in_view"],
                "identical": bool(np.array_equal(every["bits"], culled["bits"])),
            }
        )
    gl.release()

    print(f"exact maps of {args.map_size} texels, medians of {args.repeats}; ms: every triangle -> culled")
    print(
        f"{'scene':<13}{'triangles':>11}{'vertices':>10}{'fixed lights ms':>20}{'light vertices ms':>22}"
        f"{'speed-up':>10}{'in view':>9}{'same bits':>11}"
    )
    for r in rows:
        fixed = f"{r['fixed_ms'][0]:.1f} -> {r['fixed_ms'][1]:.1f}"
        vertex = f"{r['vertex_ms'][0]:.1f} -> {r['vertex_ms'][1]:.1f}"
        print(
            f"{r['scene']:<13}{r['triangles']:>11,}{r['light_vertices']:>10}{fixed:>20}{vertex:>22}"
            f"{r['vertex_speedup']:>9.2f}x{100 * r['in_view']:>8.1f}%{'yes' if r['identical'] else 'NO':>11}"
        )
    report = {"benchmark": "shadow_map_culling", "map_size": args.map_size, "repeats": args.repeats, "rows": rows}
    if args.record:
        write_record(args.record, report)
    print(json.dumps(report))


if __name__ == "__main__":
    main()
