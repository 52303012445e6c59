"""The command line as a user meets it: `doctor`, `scene info`, and bad input ending in exit 2
with one line on stderr and no traceback."""

from __future__ import annotations

import json
import os
import re

import pytest
from conftest import run_evalkit

from evalkit import doctor
from evalkit.core.mitsuba_env import find_libllvm, llvm_major


def last_json(stdout: str) -> dict:
    return json.loads(stdout.strip().splitlines()[-1])


def test_doctor_reports_gl_mitsuba_llvm_and_embree():
    done = run_evalkit("doctor", "--json")
    report = last_json(done.stdout)
    assert done.returncode == 0, done.stdout + done.stderr
    assert report["gl"]["version_code"] >= 450
    assert report["mitsuba"]["variant"] == "llvm_ad_rgb"
    assert report["mitsuba"]["llvm_version"].startswith("19.")
    assert report["embree"]["embree"].startswith("4.")
    assert "GL " in done.stdout and "Mitsuba " in done.stdout and "Embree " in done.stdout


def test_doctor_survives_a_probe_that_aborts(monkeypatch):
    # An LLVM that Dr.Jit cannot use aborts the process; the doctor must report it, not die.

    monkeypatch.setattr(doctor.sys, "executable", os.path.join(os.path.dirname(__file__), "data", "abort.sh"))
    result = doctor.run_probe("mitsuba")
    assert not result["ok"] and "killed by signal 6" in result["problem"]
    assert "libllvm19" in result["fix"]


def test_libllvm_choice_prefers_19_and_never_15_or_16(tmp_path):
    for name in ("libLLVM-14.so.1", "libLLVM-15.so.1", "libLLVM-16.so", "libLLVM.so.19.1", "libLLVM-20.so"):
        (tmp_path / name).write_text("")
    pattern = (str(tmp_path / "libLLVM*.so*"),)
    assert os.path.basename(find_libllvm(pattern)) == "libLLVM.so.19.1"
    (tmp_path / "libLLVM.so.19.1").unlink()
    assert llvm_major(find_libllvm(pattern)) == 20
    (tmp_path / "libLLVM-20.so").unlink()
    assert find_libllvm(pattern) is None


@pytest.mark.parametrize(
    "name, min_triangles", [("cornell-box", 36), ("furnace", 192), ("atrium", 250_000), ("lit-room", 500)]
)
def test_scene_info_builtin(name, min_triangles):
    done = run_evalkit("scene", "info", name, "--json")
    assert done.returncode == 0, done.stderr
    info = last_json(done.stdout)
    assert info["triangles"] >= min_triangles and info["name"] == name
    assert "features" in info and "depth_complexity" in info["features"]
    assert f"{info['triangles']:,}" in done.stdout
    assert f"resolution  R >= {info['resolution']['recommended']}:" in done.stdout


def test_scene_info_gltf_with_warnings(tmp_path):
    import trimesh

    trimesh.creation.icosphere().export(tmp_path / "ball.gltf")
    done = run_evalkit("scene", "info", str(tmp_path / "ball.gltf"), "--json")
    assert done.returncode == 0, done.stderr
    info = last_json(done.stdout)
    assert info["triangles"] == 1280
    assert any("default sun" in w for w in info["warnings"])
    assert "warning     no emissive material" in done.stdout


BAD_INPUTS = {
    "nan.obj": ("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n", "NaN or Inf"),
    "range.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "line 4: face v index 9"),
    "empty.obj": ("", "empty"),
    "garbage.ply": ("\x00\x01garbage", "cannot be read|no triangle geometry"),
    "bad.xml": ("<scene><shape>\n</scene>", "malformed XML"),
    "nogeometry.xml": ('<scene version="3.0.0"><emitter type="constant"/></scene>', "no triangle geometry"),
    "zeroarea.xml": (
        '<scene version="3.0.0"><shape type="rectangle"/><shape type="rectangle">'
        '<emitter type="area"/><transform name="to_world"><scale value="0"/></transform></shape></scene>',
        "zero area",
    ),
    "missing.obj": (None, "file not found"),
}


@pytest.mark.parametrize("name", sorted(BAD_INPUTS))
def test_bad_input_is_one_line_exit_2_no_traceback(tmp_path, name):
    content, message = BAD_INPUTS[name]
    path = tmp_path / name
    if content is not None:
        path.write_text(content)
    done = run_evalkit("scene", "info", str(path))
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr
    assert lines[0].startswith(f"evalkit: error: {path}: ")
    assert re.search(message, lines[0]), lines[0]


def test_verbose_shows_the_traceback(tmp_path):
    done = run_evalkit("--verbose", "scene", "info", str(tmp_path / "missing.obj"))
    assert done.returncode == 2 and "Traceback" in done.stderr
