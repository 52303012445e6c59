"""Import fidelity: how far the toolkit's reading of a Mitsuba XML file is from the file itself.

Both scenes are rendered by Mitsuba's own path integrator with one sensor (the imported camera's,
put back in the file's world space: a box pixel filter, a float32 film), the same bounce count, and
the same seed per chunk, so the check measures the import alone and none of the bundles' error:

- the original is the file as Mitsuba loads it (its instances, analytic shapes, textures, BSDFs);
- the imported scene is `evalkit.core.scene.load_scene`'s, exported back
  (`evalkit.core.scene.mitsuba_io.to_mitsuba_dict`): what the bundles and the references render.

Per image (direct, indirect, total) it reports the imported image mean over the original's per
channel with its 95 % interval (`render_ratio`, chunks paired: they share their seeds), relMSE, and
the per-pixel z-test's share of pixels outside (Sidak-corrected, as Mitsuba's render tests), with
the approximations the import made; and how far the imported camera's rays are from the file's
sensor's (`camera_agreement`). An OBJ or PLY file is compared with Mitsuba's own reading of it as
geometry alone (`_mesh_file_scenes`). The verdict (`_verdict`) is passed, failed, or inconclusive
where the samples cannot tell a difference from their noise.
"""

from __future__ import annotations

import os
import time
from dataclasses import replace

import numpy as np

from evalkit.core import VERSION, cache
from evalkit.core.errors import InputError
from evalkit.core.mitsuba_env import mitsuba
from evalkit.core.scene import Light, Material, load_scene
from evalkit.core.scene.mitsuba_io import load_mitsuba_original, sensor_dict, to_mitsuba_dict
from evalkit.core.settings import IMAGES, RenderSettings
from evalkit.metrics.confidence import mean_ratio, render_ratio, z_test
from evalkit.metrics.images import relmse
from gpu_impl.api import render
from references.mitsuba import chunk_images, chunk_seed, path_integrators

TOLERANCE = 0.01  # the image mean, per channel
VERDICTS = {"passed": "passed", "failed": "FAILED", "inconclusive": "inconclusive"}  # as the summary says them
Z_SHARE = 0.9975  # pixels that must pass the z-test: Mitsuba's own render tests' share
# The fewest chunks whose per-pixel variances the z-test's normal law holds for at that share: an
# exact import passed 99.97 % at 8 (64 spp) and 96.56 % at 2 (16 spp), a PLY-and-OBJ scene.
Z_CHUNKS = 8
DEFAULT_WIDTH = 96


def check_scene(
    path: str,
    bounces: int = 1,
    spp: int = 64,
    chunks: int = 8,
    width: int | None = DEFAULT_WIDTH,
    height: int | None = None,
    seed: int = 0,
    tolerance: float = TOLERANCE,
    variant: str | None = None,
    bundles: RenderSettings | None = None,
    progress=None,
) -> dict:
    """Renders the Mitsuba file at ``path`` and the toolkit's import of it with Mitsuba (``spp``
    samples per pixel in ``chunks`` chunks) and compares them (module docstring). With ``bundles``
    (render settings; the film's size and the bounces are the check's), the import is rendered with
    ray bundles too, and each image's mean over the original's Mitsuba render is reported with its
    95 % interval (``bundles`` in the result: the toolkit against the file, end to end). Returns
    the figures, the settings and versions that made them, and ``passed`` (the import's fidelity);
    the result is stored in the user cache under the imported scene's content, where `fidelity_of`
    finds it."""
    mesh_file = str(path).lower().endswith(MESH_FILES)
    if not (mesh_file or str(path).lower().endswith(".xml")):
        raise InputError(str(path), "the import check compares a Mitsuba XML, OBJ or PLY file with its import")
    if chunks < 2 or spp % chunks:
        raise InputError(str(path), f"{chunks} chunks must be at least 2 and divide spp={spp}")
    progress = progress or (lambda line: None)
    start = time.perf_counter()
    scene = loaded = load_scene(path)
    per_chunk = spp // chunks
    if mesh_file:  # in scene space, with the import's camera: the file has none
        mi = mitsuba(variant)
        scene = geometry_only(scene)  # what the bundles render too, for like to be compared with like
        original, imported = _mesh_file_scenes(mi, scene, str(path), per_chunk, width, height)
        sensor = mi.load_dict(sensor_dict(scene.camera, mi, per_chunk, width, height))
        camera = None
    else:
        mi, original = load_mitsuba_original(path, variant)
        sensor = mi.load_dict(sensor_dict(scene.camera, mi, per_chunk, width, height, offset=scene.origin))
        camera = camera_agreement(mi, original, scene)
        imported = mi.load_dict(to_mitsuba_dict(scene, mi, spp=per_chunk, width=width, height=height))
    integrators = path_integrators(mi, bounces)
    runs = {"original": [], "imported": []}
    for chunk in range(chunks):
        s = chunk_seed(seed, chunk)
        runs["original"].append(chunk_images(mi, original, integrators, bounces, s, sensor=sensor))
        runs["imported"].append(chunk_images(mi, imported, integrators, bounces, s))
        progress(f"chunk {chunk + 1}/{chunks}: {per_chunk} spp of both, {time.perf_counter() - start:.1f} s")
    a, b = np.stack(runs["imported"]), np.stack(runs["original"])  # (C, 3 images, H, W, 3)
    if not (b.any() or a.any()):
        raise InputError(str(path), "Mitsuba renders the file and its import black: no light reaches the sensor")
    images, originals = {}, {}
    for i, name in enumerate(IMAGES):
        test, ref = a[:, i].mean(axis=0), b[:, i].mean(axis=0)
        test_var, ref_var = a[:, i].var(axis=0, ddof=1) / chunks, b[:, i].var(axis=0, ddof=1) / chunks
        originals[name] = (ref, ref_var)
        ratio = render_ratio(a[:, i].mean(axis=(1, 2)), b[:, i].mean(axis=(1, 2)))
        z = z_test(test, test_var, ref, ref_var)
        images[name] = {
            "ratio": [_channel(row, b[:, i, ..., c], a[:, i, ..., c]) for c, row in enumerate(ratio["per_channel"])],
            "relmse": relmse(test, ref).value,
            "z_outside_share": z["outside_share"],
            "z_tested": z["tested"],
        }
    if bundles is not None:
        h, w = test.shape[:2]
        settings = replace(bundles, width=w, height=h, bounces=bounces)
        rendered_by = render(scene, settings)
        rendered = {
            name: _interval(mean_ratio(rendered_by.frame_means[name], *originals[name])["all"]) for name in IMAGES
        }
        bundle_check = {"settings": rendered_by.params, "ratio": rendered, "warnings": rendered_by.warnings}
    total = images["total"]
    z_ok = not total["z_outside_share"] > 1.0 - Z_SHARE  # NaN (nothing tested: a black image) passes
    verdict = _verdict(total["ratio"], tolerance, z_ok, camera is None or camera["within"], chunks)
    result = {
        "scene": loaded.name,
        "source": str(path),
        "scene_hash": loaded.content_hash(),
        "settings": {"bounces": bounces, "spp": spp, "chunks": chunks, "seed": seed, "size": list(test.shape[1::-1])},
        "tolerance": tolerance,
        "z_share": Z_SHARE,
        "images": images,
        "compared": "geometry" if mesh_file else "scene",
        "approximations": list(loaded.warnings),
        "camera": camera,
        "verdict": verdict,
        "passed": verdict == "passed",
        "bundles": bundle_check if bundles is not None else None,
        "mitsuba": mi.__version__,
        "variant": mi.variant(),
        "evalkit": VERSION,
        "seconds": round(time.perf_counter() - start, 3),
    }
    cache.store("facts", _key(result["scene_hash"]), result)
    return result


# How far the import's camera may be from the file's: its rays' directions (degrees: a thousandth
# of a degree is a few thousandths of a pixel of a 96-pixel film over 50 degrees) and origins (in
# bounding radii). The same camera gives the same rays to float32 round-off.
CAMERA_ANGLE_DEGREES = 1e-3
CAMERA_OFFSET = 1e-5
CAMERA_GRID = 9  # film positions a side


def camera_agreement(mi, original, scene) -> dict | None:
    """The rays of the file's own sensor against those of the imported camera (in the file's
    world space, on the same film) at a grid of film positions through the lens's centre: the
    largest angle between two directions (degrees), the largest distance between two origins (in
    bounding radii), and whether both are within `CAMERA_ANGLE_DEGREES` and `CAMERA_OFFSET`. The
    renders share the imported camera, so this is what checks the camera itself. None where the
    file has no sensor (the toolkit then frames the scene with a camera of its own, and says so)."""
    if not original.sensors():
        return None
    own = mi.load_dict(sensor_dict(scene.camera, mi, 1, None, None, offset=scene.origin))
    g = (np.arange(CAMERA_GRID) + 0.5) / CAMERA_GRID
    u, v = (a.ravel() for a in np.meshgrid(g, g))

    def rays(sensor):
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(u, v), mi.Point2f(0.5, 0.5))
        return (np.array(x, dtype=np.float64).reshape(3, -1).T for x in (ray.o, ray.d))

    (o0, d0), (o1, d1) = rays(original.sensors()[0]), rays(own)
    angle = float(np.degrees(2.0 * np.arcsin(np.clip(np.linalg.norm(d0 - d1, axis=1) / 2.0, 0.0, 1.0))).max())
    offset = float(np.linalg.norm(o0 - o1, axis=1).max()) / scene.bounding_sphere()[1]
    within = angle <= CAMERA_ANGLE_DEGREES and offset <= CAMERA_OFFSET
    return {"angle_degrees": angle, "offset": offset, "within": within}


# A mesh file's check: Mitsuba reads an OBJ's or PLY's geometry and normals, but no MTL, and a
# PLY's colours as raw 8-bit codes, so the file and the import are compared as geometry alone: one
# two-sided grey diffuse BSDF on both, under a constant sky.
MESH_FILES = (".obj", ".ply")


def geometry_only(scene):
    """``scene`` with one two-sided grey diffuse material and a constant sky: what a mesh file's
    check compares (`MESH_FILES`)."""
    return replace(
        scene,
        meshes=[replace(m, material=0, colors=None) for m in scene.meshes],
        materials=[Material("grey", (0.5, 0.5, 0.5), twosided=True)],
        lights=[Light("constant", (1.0, 1.0, 1.0))],
    )


def _mesh_file_scenes(mi, geometry, path: str, spp: int, width: int | None, height: int | None):
    """(the file as Mitsuba's obj or ply plugin loads it, moved into the import's scene space, with
    the BSDF and sky of ``geometry``; ``geometry`` exported). A file without normals is
    flat-shaded by the toolkit and given face normals in Mitsuba, which would interpolate normals
    of its own."""
    (grey,), (sky,) = geometry.materials, geometry.lights
    reflectance = {"type": "rgb", "value": grey.albedo}
    original = {
        "type": "scene",
        "file": {
            "type": os.path.splitext(path)[1].lower().lstrip("."),
            "filename": os.path.abspath(path),
            "face_normals": all(m.normals is None for m in geometry.meshes),
            "to_world": mi.ScalarTransform4f().translate((-geometry.origin).tolist()),
            "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": reflectance}},
        },
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": sky.intensity}},
    }
    return mi.load_dict(original), mi.load_dict(to_mitsuba_dict(geometry, mi, spp=spp, width=width, height=height))


def fidelity_of(scene) -> dict | None:
    """The last `check_scene` result for ``scene`` (by its content), from the user cache, or None."""
    return cache.load("facts", _key(scene.content_hash()))


def summary_line(result: dict) -> str:
    """The check in one line: the total image's ratios per channel and the z-test's share."""
    total = result["images"]["total"]
    ratios = ", ".join(ratio_text(r, interval=False) for r in total["ratio"])
    verdict = result.get("verdict", "passed" if result["passed"] else "failed")
    spp = result["settings"]["spp"]
    line = (
        f"import fidelity {VERDICTS[verdict]}: total image mean over Mitsuba's own load (r, g, b) {ratios}; "
        f"{100 * (1 - total['z_outside_share']):.2f} % of pixels pass the z-test "
        f"({spp} spp, B={result['settings']['bounces']}, tolerance {100 * result['tolerance']:g} %, "
        "evalkit scene check)"
    )
    camera = result.get("camera")
    if camera and not camera["within"]:
        line += f"; the camera's rays part from the file's by up to {camera['angle_degrees']:.3g} degrees"
    if verdict == "inconclusive":
        chunks = result["settings"]["chunks"]
        if total["z_outside_share"] > 1.0 - Z_SHARE and chunks < Z_CHUNKS:
            line += f"; the z-test's variances come from {chunks} chunks: check again with --chunks {Z_CHUNKS}"
        else:
            line += f"; a channel beyond the tolerance is within noise of 1: check again with --spp {4 * spp}"
    return line


def _key(scene_hash: str) -> str:
    return f"fidelity-{scene_hash}"


def ratio_text(row: dict, interval: bool = True) -> str:
    """A channel's ratio as the check prints it: with its interval, or what a black channel means."""
    if row.get("black"):
        return {"both": "black in both", "original": "black in the file only"}[row["black"]]
    if row["ratio"] is None:
        return "n/a"
    bounds = "" if row["lo"] is None or not interval else f" [{row['lo']:.4f}, {row['hi']:.4f}]"
    return f"{row['ratio']:.4f}{bounds}"


def _channel(row: dict, original: np.ndarray, imported: np.ndarray) -> dict:
    """A channel's ratio row; where the file renders it black, ``black`` says whether the import
    does too ("both": nothing to compare, it passes) or not ("original": light the file has not)."""
    black = None if original.any() else ("original" if imported.any() else "both")
    return {**_interval(row), "black": black}


def _interval(row: dict) -> dict:
    return {
        k: (None if row.get(k) is None or not np.isfinite(row[k]) else float(row[k])) for k in ("ratio", "lo", "hi")
    }


def _verdict(rows: list[dict], tolerance: float, z_ok: bool, camera_ok: bool, chunks: int) -> str:
    """ "passed" when every channel's ratio is within ``tolerance``, the z-test passes and the
    camera's rays are the file's; "failed" where the camera differs, a channel is beyond the
    tolerance with a 95 % interval that excludes 1, or the z-test fails on variances from at least
    `Z_CHUNKS` chunks; else "inconclusive": the samples cannot tell a difference from their noise
    (a channel beyond the tolerance whose interval holds 1, or a z-test on variances from too few
    chunks, whose heavy tails put an exact import's pixels outside: 3 % of them at 2 chunks)."""
    beyond = [r for r in rows if not _within(r, tolerance)]
    noisy = all(r["lo"] is not None and r["lo"] <= 1.0 <= r["hi"] for r in beyond)
    if not camera_ok or not noisy or (not z_ok and chunks >= Z_CHUNKS):
        return "failed"
    return "passed" if z_ok and not beyond else "inconclusive"


def _within(row: dict, tolerance: float) -> bool:
    if row.get("black"):
        return row["black"] == "both"
    return row["ratio"] is not None and abs(row["ratio"] - 1.0) <= tolerance
