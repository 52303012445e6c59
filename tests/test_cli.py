"""The command line as a user meets it: `doctor`, `scene info`, and bad input ending in exit 2
with one line on stderr and no traceback."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, run_evalkit
from PIL import Image

from evalkit import doctor
from evalkit.cli import ProgressLine
from evalkit.core.display import tonemap
from evalkit.core.exr import read_exr
from evalkit.core.mitsuba_env import find_libllvm, llvm_major
from evalkit.core.scene import load_scene
from evalkit.notebooks import run_notebook, shell


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
    "name, min_triangles",
    [("cornell-box", 36), ("furnace", 192), pytest.param("atrium", 250_000, marks=pytest.mark.long), ("lit-room", 500)],
)
def test_scene_info_builtin(name, min_triangles):
    done = run_evalkit("scene", "info", name, "--json")
    assert done.returncode == 0, done.stderr
    info = last_json(done.stdout)
    assert info["triangles"] >= min_triangles and info["name"] == name
    assert "features" in info and "depth_complexity" in info["features"]
    assert f"{info['triangles']:,}" in done.stdout
    assert f"resolution  R >= {info['resolution']['recommended']} at B=1:" in done.stdout


def test_render_warns_below_the_resolution_scene_info_advised(tmp_path):
    """Once `evalkit scene info` has probed a scene, a render at a smaller R says so, on screen and
    in its files; at the advised R it does not."""
    info = run_evalkit("scene", "info", "cornell-box", "--json")
    assert info.returncode == 0, info.stderr
    advised = last_json(info.stdout)["resolution"]["recommended"]
    quick = ["--method", "perfect", "--directions", "4", "--width", "8", "--height", "8", "--frames", "1"]
    for r in (advised // 2, advised):
        done = run_evalkit("render", "cornell-box", *quick, "--resolution", str(r), "--out", str(tmp_path / str(r)))
        assert done.returncode == 0, done.stderr
        warned = f"R={r} is under what `evalkit scene info --bounces 1` advises for cornell-box, R >= {advised}"
        written = json.loads((tmp_path / str(r) / "timings.json").read_text())["warnings"]
        below = r < advised
        assert (warned in done.stdout) == below and any(warned in w for w in written) == below


def test_scene_info_names_a_glossy_lobe_where_a_diffuse_albedo_would_read_black():
    # A conductor has no diffuse albedo: the line printed "albedo (0, 0, 0)" for it.
    corpus = Path(__file__).parent / "data" / "import_corpus" / "glossy.xml"
    done = run_evalkit("scene", "info", str(corpus))
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stdout.splitlines() if line.startswith("material")]
    assert "roughplastic (ggx, alpha 0.15), index 1.6 over albedo (0.5, 0.45, 0.4)" in lines[0], lines
    conductors = [line for line in lines if "roughconductor (" in line]
    assert len(conductors) == 2 and not any("albedo" in line for line in conductors), lines


def test_scene_info_says_a_material_reflects_vertex_colours():
    corpus = Path(__file__).parent / "data" / "import_corpus" / "vertex_colors.xml"
    done = run_evalkit("scene", "info", str(corpus))
    assert done.returncode == 0, done.stderr
    painted = [line for line in done.stdout.splitlines() if "vertex colours (mean (" in line]
    assert len(painted) == 2 and "vertex_colors=True" in done.stdout, done.stdout


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


@pytest.mark.parametrize(
    "given, size",
    [
        ((None, None), (128, 96)),
        ((48, None), (48, 36)),
        ((None, 48), (64, 48)),
        ((40, 40), (40, 40)),
        ((5, None), (5, 4)),
    ],
)
def test_one_side_of_the_film_keeps_the_cameras_aspect(given, size):
    # lit-room's camera is 128x96: --width 48 alone is 48x36, the same framing.
    assert load_scene("lit-room").camera.film_size(*given) == size


def test_render_and_reference_print_the_same_statistics_and_view_writes_a_png(tmp_path):
    r = run_evalkit("render", "lit-room", "--method", "perfect", "--directions", "4", "--resolution", "32",
                    "--frames", "2", "--width", "48", "--out", str(tmp_path / "render"))  # fmt: skip
    assert r.returncode == 0, r.stderr
    image, _ = read_exr(tmp_path / "render" / "total.exr")
    assert image.shape == (36, 48, 3)
    ref = run_evalkit("reference", "lit-room", "--spp", "8", "--chunks", "4", "--width", "48",
                      "--out", str(tmp_path / "ref"))  # fmt: skip
    assert ref.returncode == 0, ref.stderr
    assert read_exr(tmp_path / "ref" / "total.exr")[0].shape == (36, 48, 3)
    pattern = (
        r"^total       mean \([\d.e+-]+, [\d.e+-]+, [\d.e+-]+\), pixel std. error \([\d.e+-]+, [\d.e+-]+, [\d.e+-]+\)$"
    )
    for out in (r.stdout, ref.stdout):
        assert re.search(pattern, out, re.M), out

    v = run_evalkit("view", str(tmp_path / "render" / "total.exr"), "--exposure", "2", "--png", str(tmp_path / "t.png"))
    assert v.returncode == 0, v.stderr
    assert re.search(pattern, v.stdout, re.M), v.stdout
    png = np.asarray(Image.open(tmp_path / "t.png"))
    assert np.array_equal(png, tonemap(image, 2.0))


def test_progress_is_one_line_on_a_terminal_and_quiet_without_one(monkeypatch, capsys):
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)
    bar = ProgressLine()
    for i in (1, 2, 3):
        bar(f"chunk {i}/3: 2 spp, {i}.0 s, about {3 - i} s left")
    bar("resuming /store/entry at chunk 2 of 3")  # not a counter: a note of its own
    bar.close()
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and out.count("\r\033[Kprogress    chunk") == 3 and "about 0 s left" in out
    assert "note        resuming /store/entry" in out
    quiet = ProgressLine(quiet=True)  # --json
    quiet("frame 1/2: 10 nodes, 1.0 ms, about 1 s left")
    quiet.close()
    assert capsys.readouterr().out == ""


def test_the_readme_python_quick_start_runs(tmp_path):
    # The README's Python block, run as a user pastes it: it cannot rot unnoticed.
    readme = Path(REPO, "README.md").read_text()
    block = re.search(r"## Python\n.*?```python\n(.*?)```", readme, re.S).group(1)
    (tmp_path / "quick_start.py").write_text(block)
    r = subprocess.run([sys.executable, str(tmp_path / "quick_start.py")], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert re.search(r"^\{'relmse': [\d.]+, 'flip': [\d.]+\}$", r.stdout, re.M), r.stdout
    assert re.search(r"^indirect mean / Mitsuba's: [\d.]+, 95 % interval \[[\d.]+, [\d.]+\]$", r.stdout, re.M)


def test_the_notebook_runs_and_its_results_show_themselves(tmp_path, monkeypatch):
    # docs/quick_start.ipynb, cell by cell as a kernel runs it (evalkit.notebooks, which builds the
    # site's tutorial from it): each cell's last expression is shown through its _repr_html_.
    monkeypatch.chdir(tmp_path)
    run = run_notebook(Path(REPO, "docs", "quick_start.ipynb"))
    assert [type(run.namespace[n]).__name__ for n in ("result", "bundles", "rows")] == [
        "RenderResult",
        "BundleSet",
        "StudyRows",
    ]
    shown = [cell.shown for cell in run.cells if cell.shown is not None]
    assert len(shown) == 4 and "data:image/png;base64," in shown[0] and "RenderResult" in shown[0]
    assert "lines by nodes on them" in shown[1] and "hole_rate" in shown[2] and "class='ek-table" in shown[3]


def test_a_tutorials_command_shows_what_it_printed_and_its_exit_status(tmp_path, monkeypatch):
    # evalkit.notebooks.shell: what a tutorial shows of a command, run in the current directory.
    monkeypatch.chdir(tmp_path)
    run = shell(sys.executable, "-c", "import os, sys; print(os.getcwd(), 'a<b'); sys.exit(3)")
    assert run.returncode == 3 and run.output.split() == [str(tmp_path), "a<b"]
    assert run._repr_html_().endswith(f"{tmp_path} a&lt;b\n(exit status 3)</pre>")
    assert shell("evalkit", "--help").returncode == 0  # this environment's evalkit, found on its PATH


def test_a_reader_that_stops_early_ends_the_command_quietly():
    # `evalkit scene info X | head`: the pipe's reader is gone before evalkit writes.
    child = subprocess.Popen(
        [sys.executable, "-m", "evalkit.cli", "scene", "info", "cornell-box"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    child.stdout.close()
    stderr = child.stderr.read()
    assert child.wait(timeout=120) == 128 + signal.SIGPIPE
    assert stderr == ""
