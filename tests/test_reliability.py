"""Outputs that appear whole or not at all (evalkit/core/atomic.py): a write cut off by a full disk
leaves neither a partial file nor its temporary, and a file it replaces keeps its old content."""

from __future__ import annotations

import errno
import os

import numpy as np
import pytest

from evalkit.core import atomic
from evalkit.core.exr import read_exr, write_exr


def disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_text_write_cut_off_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    path = tmp_path / "manifest.json"
    atomic.write_text(path, '{"old": true}\n')
    monkeypatch.setattr(atomic.os, "fsync", disk_full)
    with pytest.raises(OSError, match="No space left"):
        atomic.write_text(path, '{"new": true}\n')
    assert path.read_text() == '{"old": true}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["manifest.json"]


def test_an_exr_cut_off_by_a_full_disk_is_never_left_behind(tmp_path, monkeypatch):
    import OpenEXR

    def half_then_full(self, path):
        with open(path, "wb") as f:
            f.write(b"\x76\x2f\x31\x01" + b"\0" * 64)  # an EXR's magic number and no more
        disk_full()

    monkeypatch.setattr(OpenEXR.File, "write", half_then_full)
    with pytest.raises(OSError, match="No space left"):
        write_exr(tmp_path / "direct.exr", np.ones((4, 4, 3)), {})
    assert list(tmp_path.iterdir()) == []


def test_whole_writes_read_back(tmp_path):
    image = np.random.default_rng(0).random((4, 5, 3)).astype(np.float32)
    write_exr(tmp_path / "a.exr", image, {"seed": 0})
    assert np.array_equal(read_exr(tmp_path / "a.exr")[0], image)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr"]
