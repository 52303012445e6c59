"""The user cache (evalkit/core/cache.py): an imported scene is kept until anything its import
reads changes, a damaged entry is made again, and EVALKIT_CACHE=off keeps nothing."""

from __future__ import annotations

import os

import pytest
import trimesh

import evalkit.core.scene as scenes
from evalkit.core import cache
from evalkit.core.scene import load_scene


@pytest.fixture
def counted(monkeypatch, tmp_path):
    """Imports counted, in a cache of the test's own."""
    monkeypatch.setenv("EVALKIT_CACHE", str(tmp_path / "cache"))
    calls = []
    real = scenes.load_mitsuba_file
    monkeypatch.setattr(scenes, "load_mitsuba_file", lambda path: calls.append(path) or real(path))
    return calls


def mitsuba_scene(folder, filename="box.ply"):
    trimesh.creation.box().export(folder / "box.ply")
    path = folder / "scene.xml"
    path.write_text(
        '<scene version="3.0.0"><shape type="ply"><string name="filename" value="' + filename + '"/></shape>'
        '<emitter type="constant"/></scene>'
    )
    return path


def test_a_scene_is_imported_once_until_a_file_it_reads_changes(counted, tmp_path):
    path = mitsuba_scene(tmp_path)
    first = load_scene(path)
    second = load_scene(path)
    assert len(counted) == 1 and second.content_hash() == first.content_hash()
    assert second.source == str(path) and second.warnings == first.warnings

    trimesh.creation.box(extents=(1, 2, 3)).export(tmp_path / "box.ply")  # the mesh it names
    os.utime(tmp_path / "box.ply", ns=(1, 1))
    changed = load_scene(path)
    assert len(counted) == 2 and changed.content_hash() != first.content_hash()
    path.write_text(path.read_text().replace('"constant"/>', '"constant"><rgb name="radiance" value="2"/></emitter>'))
    load_scene(path)
    load_scene(path)
    assert len(counted) == 3

    copy = tmp_path / "copy"
    copy.mkdir()
    (copy / "scene.xml").write_bytes(path.read_bytes())
    (copy / "box.ply").write_bytes((tmp_path / "box.ply").read_bytes())
    assert load_scene(copy / "scene.xml").source == str(copy / "scene.xml")  # its own entry: its own path
    assert len(counted) == 4


def test_a_damaged_entry_is_imported_again_and_off_keeps_nothing(counted, tmp_path, monkeypatch):
    path = mitsuba_scene(tmp_path)
    load_scene(path)
    (entry,) = (tmp_path / "cache" / "scenes").iterdir()
    entry.write_bytes(entry.read_bytes()[:100])  # cut short by something other than the toolkit
    assert load_scene(path).triangle_count == 12 and len(counted) == 2
    monkeypatch.setenv("EVALKIT_CACHE", "off")
    load_scene(path)
    load_scene(path)
    assert len(counted) == 4


def test_a_file_name_the_key_cannot_resolve_is_not_cached(tmp_path):
    path = mitsuba_scene(tmp_path, filename="$mesh")
    assert cache.scene_key(str(path), builtin=False) is None
    assert cache.scene_key(str(mitsuba_scene(tmp_path)), builtin=False) is not None
