"""Files that appear whole or not at all.

A process killed mid-write (SIGKILL, a power cut, a full disk) leaves a half-written file that a
later run would trust: a manifest that makes a reference store entry look finished, an EXR cut
short. Every output is written to a temporary name in its own folder, flushed to disk, then
renamed over the final name (a rename within a file system is atomic); a write that fails
removes its temporary file.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """A temporary path beside ``path`` (same suffix, for writers that go by it) to write to; it
    becomes ``path`` when the body returns, and is removed when the body raises."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_text(path: str | os.PathLike, text: str) -> None:
    """``Path(path).write_text(text)``, whole or not at all."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
