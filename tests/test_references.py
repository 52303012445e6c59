"""Mitsuba references: the export renders what Mitsuba renders from the original scene, the store
keys, reuses and resumes, the committed CI references are current and right, and the CLI."""

from __future__ import annotations

import json
import os
import shutil
import threading
import time

import numpy as np
import pytest
from conftest import cornell_reference, relmse, run_evalkit

from evalkit.core.cache import CACHE_VARIABLE
from evalkit.core.errors import InputError
from evalkit.core.exr import read_exr
from evalkit.core.lock import folder_lock
from evalkit.core.scene import load_scene
from evalkit.core.scene.builtin import furnace_radiance
from evalkit.core.scene.mitsuba_io import to_mitsuba_dict
from references.mitsuba import (
    COMMITTED_STORE,
    STORE_VARIABLE,
    reference,
    timed_render,
)

# Same seed, same spp, same integrator: only the export can differ (tessellated spheres,
# float32 round-off). relMSE uses eps = 0.01 (conftest.relmse).
EXPORT_RELMSE = 1e-3
CI_REFERENCES = [(scene, bounces) for scene in ("cornell-box", "furnace") for bounces in (1, 3)]


def render(mi, scene_dict, spp=64, seed=7, depth=5):
    scene = mi.load_dict(scene_dict)
    integrator = mi.load_dict({"type": "path", "max_depth": depth, "rr_depth": depth})
    return np.array(mi.render(scene, integrator=integrator, spp=spp, seed=seed))[..., :3]


def small_film(d: dict, size: int = 64) -> dict:
    d["sensor"]["film"].update(width=size, height=size, rfilter={"type": "box"}, component_format="float32")
    return d


def test_export_renders_like_mitsubas_cornell_box(mi, images):
    original = render(mi, small_film(mi.cornell_box()))
    exported = render(mi, to_mitsuba_dict(load_scene("cornell-box"), mi, width=64, height=64))
    assert original.mean() > 0.05
    images.relmse_at_most("export", exported, original, EXPORT_RELMSE)


def test_export_renders_like_mitsuba_for_a_sphere_and_a_ply_mesh(mi, tmp_path, images):
    import trimesh

    trimesh.creation.box(extents=(0.6, 0.6, 0.6)).export(tmp_path / "box.ply")
    (tmp_path / "scene.xml").write_text("""<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="45"/><string name="fov_axis" value="x"/>
    <transform name="to_world"><lookat origin="0, 0.5, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="64"/><integer name="height" value="64"/>
      <rfilter type="box"/><string name="component_format" value="float32"/></film></sensor>
  <shape type="ply" id="box"><string name="filename" value="box.ply"/>
    <transform name="to_world"><translate x="-0.6"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.3, 0.2"/></bsdf></shape>
  <shape type="sphere" id="ball"><point name="center" x="0.6" y="0" z="0"/><float name="radius" value="0.4"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.5, 0.7"/></bsdf></shape>
  <shape type="rectangle" id="floor"><transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/>
    <translate y="-0.4"/></transform><bsdf type="diffuse"/></shape>
  <shape type="rectangle" id="lamp"><transform name="to_world"><rotate x="1" angle="90"/><translate y="2"/></transform>
    <emitter type="area"><rgb name="radiance" value="8"/></emitter></shape>
</scene>
""")
    integrator = mi.load_dict({"type": "path", "max_depth": 5, "rr_depth": 5})
    # The sphere is tessellated (128 x 64), so paths that hit it decorrelate from Mitsuba's: more spp
    # than for the Cornell box bring that noise under the threshold; the tessellation bias is below it.
    spp = 1024
    original = np.array(mi.render(mi.load_file(str(tmp_path / "scene.xml")), integrator=integrator, spp=spp, seed=7))[
        ..., :3
    ]
    exported = render(mi, to_mitsuba_dict(load_scene(str(tmp_path / "scene.xml")), mi), spp=spp)
    assert original.mean() > 0.02
    images.relmse_at_most("export", exported, original, EXPORT_RELMSE)


def test_store_keys_reuses_and_resumes(tmp_path):
    scene = load_scene("furnace")
    args = dict(bounces=1, spp=8, width=16, height=16, seed=3, chunks=4)
    straight = reference(scene, store=tmp_path / "a", progress=lambda line: None, **args)
    assert not straight.reused
    again = reference(scene, store=tmp_path / "a", progress=lambda line: None, **args)
    assert again.reused and again.path == straight.path
    other = reference(scene, store=tmp_path / "a", progress=lambda line: None, **{**args, "spp": 12, "chunks": 4})
    assert other.path != straight.path

    seen = []

    def interrupt(line):
        seen.append(line)
        if len(seen) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        reference(scene, store=tmp_path / "b", progress=interrupt, **args)
    lines = []
    resumed = reference(scene, store=tmp_path / "b", progress=lines.append, **args)
    assert lines[0].startswith("resuming") and "chunk 3 of 4" in lines[0]
    for name in ("direct", "indirect", "total"):
        assert np.array_equal(resumed.images[name], straight.images[name])
        assert np.array_equal(resumed.variances[name], straight.variances[name])
    assert np.allclose(straight.images["indirect"], straight.images["total"] - straight.images["direct"], atol=1e-6)


def test_a_store_entry_has_one_writer_and_a_waiting_process_reuses_its_work(tmp_path):
    scene = load_scene("furnace")
    args = dict(bounces=1, spp=8, width=16, height=16, seed=3, chunks=4)
    finished = reference(scene, store=tmp_path / "done", progress=lambda line: None, **args)
    entry = tmp_path / "shared" / finished.path.relative_to(tmp_path / "done")
    with folder_lock(entry, "reference render"):  # another process rendering this entry
        with pytest.raises(InputError, match="another reference render is writing here .*--wait"):
            reference(scene, store=tmp_path / "shared", progress=lambda line: None, **args)
        r = run_evalkit(
            "reference", "furnace", "--spp", "8", "--chunks", "4", "--width", "16", "--height", "16", "--seed", "3",
            "--store", str(tmp_path / "shared"), "--out", str(tmp_path / "out"),
        )  # fmt: skip
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert "another reference render is writing here" in r.stderr
    assert not (entry / "manifest.json").exists()

    # With wait, the second process blocks until the first finishes, then reuses its entry.
    def first_finishes(held):
        with folder_lock(entry, "reference render"):
            held.set()
            time.sleep(0.5)
            shutil.copytree(finished.path, entry, dirs_exist_ok=True)

    held = threading.Event()
    writer = threading.Thread(target=first_finishes, args=(held,))
    writer.start()
    held.wait()
    lines = []
    waited = reference(scene, store=tmp_path / "shared", progress=lines.append, wait=True, **args)
    writer.join()
    assert waited.reused and any(line.startswith(f"waiting for {entry}") for line in lines), lines
    assert np.array_equal(waited.images["indirect"], finished.images["indirect"])


def test_a_store_entry_without_a_whole_manifest_is_not_trusted(tmp_path):
    scene = load_scene("furnace")
    args = dict(bounces=1, spp=8, width=16, height=16, seed=3, chunks=4)
    whole = reference(scene, store=tmp_path, progress=lambda line: None, **args)
    manifest = whole.path / "manifest.json"
    text = manifest.read_text()
    manifest.unlink()  # killed after its images, before its manifest: rendered again
    again = reference(scene, store=tmp_path, progress=lambda line: None, **args)
    assert not again.reused and manifest.read_text() == text.replace(
        f'"render_s": {whole.manifest["render_s"]}', f'"render_s": {again.manifest["render_s"]}'
    )
    manifest.write_text(text[: len(text) // 2])  # torn by something other than the toolkit: one line
    with pytest.raises(InputError, match=r"manifest.json: malformed JSON"):
        reference(scene, store=tmp_path, progress=lambda line: None, **args)


@pytest.mark.parametrize("name,bounces", CI_REFERENCES)
def test_committed_ci_references_are_current(name, bounces):
    scene = load_scene(name)
    ref = reference(
        scene,
        bounces=bounces,
        spp=16384,
        width=128,
        height=128,
        store=COMMITTED_STORE,
        progress=lambda line: pytest.fail(f"the committed reference is stale and would be re-rendered: {line}"),
    )
    assert ref.reused and ref.manifest["scene_hash"] == scene.content_hash()
    image, provenance = read_exr(ref.path / "indirect.exr")
    assert np.array_equal(image, ref.images["indirect"])
    for key in ("spp", "seed", "bounces", "mitsuba", "variant", "scene_hash"):
        assert provenance[key] == ref.manifest[key]
    for name_, img in ref.images.items():
        assert img.shape == (128, 128, 3) and np.isfinite(img).all() and (ref.variances[name_] >= 0).all()


@pytest.mark.parametrize("bounces", [1, 3])
def test_furnace_references_equal_the_analytic_radiance(bounces):
    ref = reference(load_scene("furnace"), bounces=bounces, spp=16384, width=128, height=128, progress=pytest.fail)
    expected = {"direct": furnace_radiance(2), "total": furnace_radiance(bounces + 2)}
    expected["indirect"] = expected["total"] - expected["direct"]
    for name, value in expected.items():
        z = np.abs(ref.images[name] - value) / np.sqrt(ref.variances[name])
        # With 32 chunks the variance is itself estimated; 5 sigma still leaves a wide margin.
        assert np.mean(z < 5) >= 0.999, (name, np.mean(z < 5))
        assert abs(ref.images[name].mean() - value) < 1e-3 * value


def test_cli_reference_writes_images_and_manifest(tmp_path):
    r = run_evalkit(
        "reference",
        "furnace",
        "--bounces",
        "1",
        "--spp",
        "8",
        "--width",
        "8",
        "--height",
        "8",
        "--chunks",
        "4",
        "--store",
        str(tmp_path / "store"),
        "--out",
        str(tmp_path / "out"),
        "--json",
    )
    assert r.returncode == 0, r.stderr
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert result["spp"] == 8 and not result["reused"] and "chunk 4/4" not in r.stdout  # no terminal: no counters
    names = {p.name for p in (tmp_path / "out").iterdir()}
    assert names == {f"{n}{s}.exr" for n in ("direct", "indirect", "total") for s in ("", "_variance")} | {
        "manifest.json"
    }
    bad = run_evalkit(
        "reference",
        "furnace",
        "--spp",
        "10",
        "--chunks",
        "4",
        "--store",
        str(tmp_path / "store"),
        "--out",
        str(tmp_path / "out2"),
    )
    assert bad.returncode == 2 and "divide spp=10" in bad.stderr and bad.stderr.count("\n") == 1


def test_references_of_other_scenes_go_to_the_user_cache_never_the_checkout(tmp_path):
    args = ["reference", "furnace", "--spp", "8", "--chunks", "4", "--width", "8", "--height", "8"]
    env = {k: v for k, v in os.environ.items() if k not in (STORE_VARIABLE, CACHE_VARIABLE)}
    cached = run_evalkit(*args, "--out", str(tmp_path / "a"), env={**env, "XDG_CACHE_HOME": str(tmp_path / "cache")})
    assert cached.returncode == 0, cached.stderr
    assert f"store       {tmp_path / 'cache' / 'evalkit' / 'references' / 'furnace-'}" in cached.stdout
    chosen = run_evalkit(*args, "--out", str(tmp_path / "b"), env={**env, STORE_VARIABLE: str(tmp_path / "mine")})
    assert f"store       {tmp_path / 'mine' / 'furnace-'}" in chosen.stdout
    assert not list(COMMITTED_STORE.rglob("*8x8*"))  # nothing new in the checkout
    # The committed CI references are still found first.
    committed = run_evalkit(
        "reference", "furnace", "--spp", "16384", "--width", "128", "--height", "128", "--out", str(tmp_path / "c"),
        env={**env, STORE_VARIABLE: str(tmp_path / "mine")},
    )  # fmt: skip
    assert f"store       {COMMITTED_STORE}" in committed.stdout and "(reused)" in committed.stdout


def test_timed_renders_use_their_sample_count(mi):
    """`timed_render` (error against time in studies): more samples, less error, more time; a
    1-spp warm-up must not leave the sampler at 1 spp."""

    scene, ref = cornell_reference(1)
    errors, seconds = [], []
    for spp in (2, 32):
        images, s, info = timed_render(scene, 1, spp, 128, 128, seed=0)
        errors.append(relmse(images["total"], ref.images["total"]))
        seconds.append(s)
    # 16x the samples: the error falls about 16x (asserted: more than 6x).
    assert errors[1] < errors[0] / 6, errors
    assert seconds[1] > seconds[0] and info["mitsuba"] == mi.__version__
