"""Fuzzing the importers: random bytes and mutated valid OBJ, PLY, glTF, GLB and Mitsuba XML files.
Every outcome must be a loaded scene or the one-line `InputError` naming the file; anything else
(another exception, a hang past HANG_SECONDS) fails. CI runs a derandomized, bounded number of
examples; `make fuzz` (HYPOTHESIS_PROFILE=fuzz) runs thousands of fresh ones."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from evalkit.core.errors import InputError
from evalkit.core.scene import Scene, load_scene

HANG_SECONDS = 20
CI_EXAMPLES = 30
FORMATS = ("obj", "ply", "gltf", "glb", "xml")

XML_SEED = b"""<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, 1, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film></sensor>
  <bsdf type="diffuse" id="grey"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf>
  <shape type="rectangle"><ref id="grey"/></shape>
  <shape type="sphere"><point name="center" x="0" y="0.5" z="0"/><float name="radius" value="0.3"/>
    <emitter type="area"><rgb name="radiance" value="2, 2, 2"/></emitter></shape>
  <emitter type="point"><point name="position" x="0" y="2" z="0"/><rgb name="intensity" value="1, 1, 1"/></emitter>
</scene>
"""


def seed_file(ext: str) -> bytes:
    """A small valid file of each format: a box (and a quad)."""
    if ext == "xml":
        return XML_SEED
    box = trimesh.creation.box(extents=(1, 2, 3))
    if ext == "gltf":  # one file: the buffer embedded as a data URI
        return trimesh.exchange.gltf.export_gltf(trimesh.Scene(box), embed_buffers=True)["model.gltf"]
    data = box.export(file_type=ext, **({"encoding": "ascii"} if ext == "ply" else {}))
    return data if isinstance(data, bytes) else data.encode()


SEEDS = {ext: seed_file(ext) for ext in FORMATS}

edits = st.lists(
    st.tuples(
        st.sampled_from(["insert", "delete", "replace", "duplicate"]),
        st.floats(0, 1),
        st.binary(min_size=1, max_size=12),
    ),
    min_size=1,
    max_size=8,
)


def mutate(data: bytes, ops) -> bytes:
    for op, where, chunk in ops:
        i = int(where * len(data))
        if op == "insert":
            data = data[:i] + chunk + data[i:]
        elif op == "delete":
            data = data[:i] + data[i + len(chunk) :]
        elif op == "replace":
            data = data[:i] + chunk + data[i + len(chunk) :]
        else:  # a run of the file repeated, as truncated or concatenated writes leave
            data = data[:i] + data[i : i + 64] + data[i:]
    return data


@pytest.fixture(autouse=True)
def no_cache(monkeypatch):
    monkeypatch.setenv("EVALKIT_CACHE", "off")  # every example imported, none kept


def load_or_one_line_error(path) -> Scene | None:
    def hang(signum, frame):
        raise TimeoutError(f"loading {path} took over {HANG_SECONDS} s")

    previous = signal.signal(signal.SIGALRM, hang)
    signal.alarm(HANG_SECONDS)
    try:
        scene = load_scene(path)
    except InputError as e:
        message = str(e)
        assert message.startswith(str(path)) and "\n" not in message, message
        return None
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    assert isinstance(scene, Scene) and scene.triangle_count > 0
    assert all(np.isfinite(m.positions).all() for m in scene.meshes)
    return scene


def examples():
    return settings(
        max_examples=int(os.environ.get("FUZZ_EXAMPLES", CI_EXAMPLES)),
        suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    )


@pytest.mark.parametrize("ext", FORMATS)
def test_the_seed_files_load(tmp_path, ext):
    path = tmp_path / f"seed.{ext}"
    path.write_bytes(SEEDS[ext])
    assert load_or_one_line_error(path) is not None


@pytest.mark.parametrize("ext", FORMATS)
def test_mutated_files_load_or_fail_in_one_line(tmp_path, ext):
    @examples()
    @given(ops=edits)
    def check(ops):
        path = tmp_path / f"mutated.{ext}"
        path.write_bytes(mutate(SEEDS[ext], ops))
        load_or_one_line_error(path)

    check()


@pytest.mark.parametrize("ext", FORMATS)
def test_random_bytes_load_or_fail_in_one_line(tmp_path, ext):
    @examples()
    @given(data=st.binary(max_size=4096))
    def check(data):
        path = tmp_path / f"random.{ext}"
        path.write_bytes(data)
        load_or_one_line_error(path)

    check()
