"""`evalkit scene check`: the file as Mitsuba loads it against the toolkit's import of it, both
rendered by Mitsuba. The corpus (tests/data/import_corpus) holds one scene per imported feature."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
import trimesh
from conftest import run_evalkit

from evalkit.core.scene import load_scene
from evalkit.core.settings import RenderSettings
from evalkit.fidelity import _verdict, check_scene, fidelity_of, summary_line

CORPUS = Path(__file__).parent / "data" / "import_corpus"
# The check's samples and chunks per corpus scene (default 32 in 4). Its z-test takes each pixel's
# variance from the spread of its chunk means: 4 give a heavy-tailed estimate, and the sharp
# highlights of glossy.xml put 0.27 % of its pixels outside at 32 spp in 4 chunks (the file and the
# import alike: 0.999 of each other and every pixel within at 256 spp in 16).
CHECK_SAMPLES = {"glossy": (128, 16)}


@pytest.mark.parametrize("name", sorted(p.stem for p in CORPUS.glob("*.xml")))
def test_every_corpus_scene_imports_within_one_percent_and_its_bundle_render_matches_the_file(name):
    # Measured (64 spp in 8 chunks, 48 px wide; perfect bundles K=32, R=128, 32 frames), the bundle
    # render's image means over Mitsuba's render of the file, direct / indirect / total:
    # instances 0.9966 [0.985, 1.009] / 0.9915 [0.911, 1.072] / 0.9964 [0.983, 1.010]; textures
    # 0.9997 [0.985, 1.015] / 1.0329 [0.968, 1.098] / 1.0005 [0.986, 1.015]; lights 0.9919 [0.940,
    # 1.044] / 0.9809 [0.909, 1.052] / 0.9916 [0.940, 1.043]. Bound: within 2 % or its interval.
    bundles = RenderSettings(method="perfect", directions=32, resolution=128, frames=16, seed=0)
    spp, chunks = CHECK_SAMPLES.get(name, (32, 4))
    result = check_scene(str(CORPUS / f"{name}.xml"), spp=spp, chunks=chunks, width=48, bundles=bundles)
    assert result["passed"], result["images"]["total"]
    for image in result["images"].values():
        for row in image["ratio"]:
            assert abs(row["ratio"] - 1.0) <= 0.01 or row["lo"] <= 1.0 <= row["hi"], row
    assert not result["approximations"], result["approximations"]
    for row in result["bundles"]["ratio"].values():
        assert abs(row["ratio"] - 1.0) <= 0.02 or row["lo"] <= 1.0 <= row["hi"], result["bundles"]["ratio"]


def test_an_approximated_bsdf_fails_the_check_and_scene_info_and_renders_say_so(tmp_path):
    # A blend of a conductor and a diffuse BSDF flattened to a diffuse albedo: the check measures
    # what that does to the image.
    scene = (
        (CORPUS / "lights.xml")
        .read_text()
        .replace(
            '<bsdf type="diffuse" id="grey"><rgb name="reflectance" value="0.6, 0.6, 0.6"/></bsdf>',
            '<bsdf type="blendbsdf" id="grey"><float name="weight" value="0.7"/><bsdf type="conductor">'
            '<string name="material" value="Cu"/></bsdf><bsdf type="diffuse"/></bsdf>',
        )
    )
    path = tmp_path / "metal.xml"
    path.write_text(scene)
    (tmp_path / "sky.exr").write_bytes((CORPUS / "sky.exr").read_bytes())
    run = run_evalkit("scene", "check", str(path), "--spp", "16", "--chunks", "4", "--width", "32", "--json")
    assert run.returncode == 1, run.stderr
    result = json.loads(run.stdout.strip().splitlines()[-1])
    assert not result["passed"] and any("BlendBSDF" in w for w in result["approximations"])
    assert "import fidelity FAILED" in run.stdout
    assert fidelity_of(load_scene(str(path)))["passed"] is False  # cached for scene info and renders
    info = run_evalkit("scene", "info", str(path))
    assert "import fidelity FAILED" in info.stdout, info.stdout
    out = tmp_path / "render"
    run_evalkit(
        "render", str(path), "--method", "perfect", "--directions", "4", "--resolution", "16", "--width", "8",
        "--frames", "1", "--out", str(out),
    )  # fmt: skip
    timings = json.loads((out / "timings.json").read_text())
    assert timings["stats"]["import_fidelity"]["passed"] is False
    assert any("import fidelity FAILED" in w for w in timings["warnings"])


# A floor and a cube under one point light; the camera's direction is substituted.
ONE_LIGHT = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0, 1.5, 4" target="{target}" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="24"/></film></sensor>
  <shape type="rectangle"><transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.6, 0.6"/></bsdf></shape>
  <shape type="cube"><transform name="to_world"><scale value="0.5"/><translate y="0.5"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf></shape>
  <emitter type="point"><point name="position" x="1" y="2.5" z="1"/>
    <rgb name="intensity" value="{intensity}"/></emitter>
</scene>
"""


def test_a_channel_black_in_the_file_and_its_import_passes_and_is_printed_as_such(tmp_path):
    # A red light leaves green and blue black in both renders: nothing to compare there, and the
    # check said so by failing to print its summary (a None ratio formatted as a number).
    path = tmp_path / "red.xml"
    path.write_text(ONE_LIGHT.format(target="0, 0.5, 0", intensity="8, 0, 0"))
    run = run_evalkit("scene", "check", str(path), "--spp", "8", "--chunks", "2", "--json")
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout.strip().splitlines()[-1])
    red, green, blue = result["images"]["total"]["ratio"]
    assert red["black"] is None and abs(red["ratio"] - 1.0) <= 0.01
    assert green["black"] == blue["black"] == "both"
    assert "import fidelity passed: total image mean over Mitsuba's own load (r, g, b) 1.0" in run.stdout
    assert "black in both, black in both" in run.stdout


def test_a_sensor_that_sees_no_light_is_refused_in_one_line(tmp_path):
    # Looking away from everything: both renders are black, and a check of nothing would pass.
    path = tmp_path / "away.xml"
    path.write_text(ONE_LIGHT.format(target="0, 1.5, 8", intensity="8, 8, 8"))
    run = run_evalkit("scene", "check", str(path), "--spp", "8", "--chunks", "2")
    assert run.returncode != 0 and "Traceback" not in run.stderr
    assert run.stderr.strip() == (
        f"evalkit: error: {path}: Mitsuba renders the file and its import black: no light reaches the sensor"
    )


def _row(ratio, lo, hi):
    return {"ratio": ratio, "lo": lo, "hi": hi, "black": None}


@pytest.mark.parametrize(
    ("rows", "verdict"),
    [
        ([_row(1.004, 0.99, 1.02)] * 3, "passed"),
        # 64 spp of a scene whose import is exact (256 spp: 0.9999 [0.9965, 1.0033]) read as FAILED
        ([_row(1.0106, 0.9962, 1.0249), _row(1.0096, 0.9952, 1.0240), _row(1.0108, 0.9970, 1.0247)], "inconclusive"),
        ([_row(1.004, 0.99, 1.02), _row(1.03, 1.01, 1.05), _row(1.0, 0.99, 1.01)], "failed"),
    ],
)
def test_a_difference_within_noise_of_1_is_inconclusive_not_failed(rows, verdict):
    assert _verdict(rows, 0.01, z_ok=True, camera_ok=True, chunks=8) == verdict
    # On variances from enough chunks, pixels beyond their noise fail the check alone; from too
    # few, the z-test's heavy tails cannot (an exact import: 96.56 % of pixels passed at 2 chunks).
    assert _verdict(rows, 0.01, z_ok=False, camera_ok=True, chunks=8) == "failed"
    assert _verdict(rows, 0.01, z_ok=False, camera_ok=True, chunks=2) == (
        "failed" if verdict == "failed" else "inconclusive"
    )
    assert _verdict(rows, 0.01, z_ok=True, camera_ok=False, chunks=8) == "failed"
    result = {
        "verdict": verdict,
        "passed": verdict == "passed",
        "images": {"total": {"ratio": rows, "z_outside_share": 0.0}},
        "settings": {"spp": 64, "bounces": 2, "chunks": 8},
        "tolerance": 0.01,
    }
    line = summary_line(result)
    assert line.startswith(f"import fidelity {'FAILED' if verdict == 'failed' else verdict}: ")
    assert ("check again with --spp 256" in line) == (verdict == "inconclusive")
    few = {**result, "verdict": "inconclusive", "settings": {"spp": 16, "bounces": 2, "chunks": 2}}
    few["images"] = {"total": {"ratio": rows, "z_outside_share": 0.03}}
    assert summary_line(few).endswith("the z-test's variances come from 2 chunks: check again with --chunks 8")


def test_a_camera_imported_wrong_fails_the_check(monkeypatch):
    # Both renders use the imported camera, so only comparing the rays with the file's own sensor's
    # sees a camera imported wrong (as an orthographic sensor once became a default perspective one).
    import evalkit.fidelity as fidelity

    read = fidelity.load_scene

    def wider(path):
        scene = read(path)
        return replace(scene, camera=replace(scene.camera, fov=scene.camera.fov * 1.01))

    exact = check_scene(str(CORPUS / "lights.xml"), spp=8, chunks=2, width=24)
    assert exact["camera"]["within"] and exact["passed"]
    monkeypatch.setattr(fidelity, "load_scene", wider)
    result = check_scene(str(CORPUS / "lights.xml"), spp=8, chunks=2, width=24)
    assert not result["camera"]["within"] and result["camera"]["angle_degrees"] > 0.1
    assert result["verdict"] == "failed" and not result["passed"]
    assert "the camera's rays part from the file's by up to" in summary_line(result)


def test_a_mesh_files_geometry_is_checked_against_mitsubas_own_reading(tmp_path, monkeypatch):
    # "For OBJ/PLY, compare against Mitsuba loading the same file directly": Mitsuba reads no MTL
    # and a PLY's colours as raw codes, so the two are compared grey under a sky, as geometry.
    import evalkit.fidelity as fidelity

    (tmp_path / "m.mtl").write_text("newmtl lamp\nKd 0 0 0\nKe 5 5 5\n")
    box = trimesh.creation.box()
    (tmp_path / "box.obj").write_text(
        "mtllib m.mtl\n"
        + "".join(f"v {x} {y} {z}\n" for x, y, z in box.vertices)
        + "usemtl lamp\n"
        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in box.faces)
    )
    run = run_evalkit("scene", "check", str(tmp_path / "box.obj"), "--spp", "16", "--chunks", "8", "--json")
    assert run.returncode == 0, run.stdout + run.stderr
    result = json.loads(run.stdout.strip().splitlines()[-1])
    assert result["compared"] == "geometry" and result["camera"] is None and result["passed"]
    assert "compared    geometry and normals alone" in run.stdout
    assert fidelity_of(load_scene(tmp_path / "box.obj"))["compared"] == "geometry"  # found by info and renders
    read = fidelity.load_scene

    def wider(path):  # an import that read the box 5 % wide
        scene = read(path)
        return replace(scene, meshes=[replace(m, positions=m.positions * [1.05, 1.0, 1.0]) for m in scene.meshes])

    monkeypatch.setattr(fidelity, "load_scene", wider)
    wrong = check_scene(str(tmp_path / "box.obj"), spp=16, chunks=8, width=48)
    assert wrong["verdict"] == "failed", wrong["images"]["total"]
