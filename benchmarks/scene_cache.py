"""A second command on a large scene against the first: `evalkit scene info` on a 2-million-triangle
Mitsuba scene with an empty user cache (import, Embree's resolution probes) and then with the cache
that first command left (evalkit/core/cache.py), side by side in one run.

The scene is the built-in `parts` tray with every triangle split into 25 (2.3 M triangles), written
as a Mitsuba XML file with binary PLY meshes and an EXR environment map, as a user's scene would
be.

    python benchmarks/scene_cache.py [--repeats 3] [--split 5]

Wall times of the whole command (a child process each, as a user runs it), medians over the
repeats, each cold run with a fresh cache. Prints a table; the last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from evalkit.core.exr import write_exr
from evalkit.core.scene import load_scene
from evalkit.core.scene.tessellate import subdivide

REPO = Path(__file__).resolve().parent.parent


def write_mitsuba_scene(folder: Path, split: int) -> tuple[Path, int]:
    """The parts scene, each triangle split into split^2, as folder/parts.xml; returns it and its
    triangle count."""
    scene = load_scene("parts")
    shapes, triangles = [], 0
    for mesh in scene.meshes:
        p, f, n, _ = subdivide(mesh.positions, mesh.faces, mesh.normals, mesh.uvs, split)
        triangles += len(f)
        ply = trimesh.Trimesh(p, f, vertex_normals=n, process=False)
        ply.export(folder / f"{mesh.name}.ply", encoding="binary")
        material = scene.materials[mesh.material]
        bsdf = f'<bsdf type="diffuse"><rgb name="reflectance" value="{", ".join(map(str, material.albedo))}"/></bsdf>'
        if material.twosided:
            bsdf = f'<bsdf type="twosided">{bsdf}</bsdf>'
        shapes.append(f'<shape type="ply"><string name="filename" value="{mesh.name}.ply"/>{bsdf}</shape>')
    (sky,) = scene.lights
    write_exr(folder / "sky.exr", sky.envmap, {})
    cam = scene.camera
    matrix = " ".join(f"{x:.9g}" for x in cam.to_world.reshape(-1))
    path = folder / "parts.xml"
    path.write_text(
        '<scene version="3.0.0">\n'
        f'<sensor type="perspective"><float name="fov" value="{cam.fov}"/>'
        f'<string name="fov_axis" value="{cam.fov_axis}"/>'
        f'<transform name="to_world"><matrix value="{matrix}"/></transform>'
        f'<film type="hdrfilm"><integer name="width" value="{cam.width}"/>'
        f'<integer name="height" value="{cam.height}"/></film></sensor>\n'
        + "\n".join(shapes)
        + '\n<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>\n</scene>\n'
    )
    return path, triangles


def import_scene(path: Path, cache: Path) -> float:
    """`load_scene` alone, in a child process (Mitsuba's import, or the cached scene)."""
    start = time.perf_counter()
    code = f"from evalkit.core.scene import load_scene; load_scene({str(path)!r})"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=REPO, env={**os.environ, "EVALKIT_CACHE": str(cache)})
    return time.perf_counter() - start


def scene_info(path: Path, cache: Path) -> float:
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "evalkit.cli", "scene", "info", str(path)],
        check=True,
        capture_output=True,
        cwd=REPO,
        env={**os.environ, "EVALKIT_CACHE": str(cache)},
    )
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--split", type=int, default=5, help="each triangle into split^2 (default 5: 2.3 M)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        path, triangles = write_mitsuba_scene(folder, args.split)
        cold, warm, cold_import, warm_import = [], [], [], []
        for repeat in range(args.repeats):
            cache = folder / f"cache{repeat}"
            cold.append(scene_info(path, cache))
            warm.append(scene_info(path, cache))
            cold_import.append(import_scene(path, folder / f"import{repeat}"))
            warm_import.append(import_scene(path, folder / f"import{repeat}"))
        size = sum(f.stat().st_size for f in (folder / "cache0").rglob("*") if f.is_file())
    first, second = statistics.median(cold), statistics.median(warm)
    imported, cached = statistics.median(cold_import), statistics.median(warm_import)
    print(f"A Mitsuba scene of {triangles:,} triangles, median of {args.repeats}, wall s of the whole process")
    print(f"{'':28}{'first':>8}{'second':>8}{'ratio':>8}")
    print(f"{'evalkit scene info':28}{first:8.2f}{second:8.2f}{second / first:8.3f}")
    print(f"{'load_scene alone':28}{imported:8.2f}{cached:8.2f}{cached / imported:8.3f}")
    print(f"cache size {size / 2**20:.1f} MiB")
    print(
        json.dumps(
            {
                "triangles": triangles,
                "first_s": round(first, 3),
                "second_s": round(second, 3),
                "ratio": round(second / first, 4),
                "import_first_s": round(imported, 3),
                "import_second_s": round(cached, 3),
                "import_ratio": round(cached / imported, 4),
                "cache_mib": round(size / 2**20, 1),
                "first_all_s": [round(x, 3) for x in cold],
                "second_all_s": [round(x, 3) for x in warm],
                "numpy": np.__version__,
            }
        )
    )


if __name__ == "__main__":
    main()
