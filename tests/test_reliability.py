"""Outputs that appear whole or not at all (evalkit/core/atomic.py): a write cut off by a full disk
leaves neither a partial file nor its temporary, and a file it replaces keeps its old content; the
CLI checks output paths before it renders and ends a full disk in one line."""

from __future__ import annotations

import errno
import os
import re
import subprocess

import numpy as np
import pytest
from conftest import run_evalkit

from evalkit.cli import main
from evalkit.core import atomic
from evalkit.core.exr import read_exr, write_exr

TINY_RENDER = ["cornell-box", "--method", "perfect", "--directions", "4", "--resolution", "32"]
TINY_RENDER += ["--width", "32", "--height", "32", "--frames", "2"]


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


@pytest.mark.parametrize(
    "out, problem",
    [
        ("file", "exists and is not a folder"),
        ("file/render", "cannot be made: .*file is a file, not a folder"),
    ],
)
def test_an_output_path_that_cannot_be_written_is_refused_before_rendering(tmp_path, out, problem):
    (tmp_path / "file").write_text("a user's file\n")
    r = run_evalkit("render", *TINY_RENDER, "--out", str(tmp_path / out))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.stderr.startswith(f"evalkit: error: {tmp_path / out}: ") and re.search(problem, r.stderr)
    assert "rendered" not in r.stdout and (tmp_path / "file").read_text() == "a user's file\n"


@pytest.fixture
def small_disk(tmp_path):
    """A 48 KiB tmpfs where this machine lets the tests mount one, else None."""
    disk = tmp_path / "disk"
    disk.mkdir()
    try:
        mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=48k", "tmpfs", str(disk)], capture_output=True)
    except OSError:  # no mount command
        mounted = None
    if mounted is None or mounted.returncode:
        yield None
        return
    try:
        yield disk
    finally:
        subprocess.run(["umount", str(disk)], check=True)


def test_a_disk_that_fills_during_a_render_ends_in_one_line_and_leaves_only_whole_files(
    tmp_path, small_disk, monkeypatch, capsys
):
    if small_disk is not None:  # six 32x32 EXRs do not fit in 48 KiB
        out = small_disk / "render"
        r = run_evalkit("render", *TINY_RENDER, "--out", str(out))
        code, stderr = r.returncode, r.stderr
    else:  # no mount here: the third write finds the disk full
        out, writes = tmp_path / "render", []
        real_fsync = atomic.os.fsync

        def fsync_until_full(fd):
            writes.append(fd)
            if len(writes) > 2:
                disk_full()
            real_fsync(fd)

        monkeypatch.setattr(atomic.os, "fsync", fsync_until_full)
        code, stderr = main(["render", *TINY_RENDER, "--out", str(out)]), capsys.readouterr().err
    assert code == 1 and len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr, stderr
    assert "No space left on device" in stderr
    left = sorted(p.name for p in out.iterdir())
    assert left and not any(name.endswith((".tmp.exr", ".tmp.json")) or name.startswith(".") for name in left), left
    assert "timings.json" not in left  # the record of a finished render is written last
    for name in left:
        read_exr(out / name)  # what is there is whole
