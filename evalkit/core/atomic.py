"""Files that appear whole or not at all.

A process killed mid-write (SIGKILL, a power cut, a full disk) leaves a half-written file that a
later run would trust: a manifest that makes a reference store entry look finished, an EXR cut
short. Every output is written to a temporary name in its own folder, flushed to disk, then
renamed over the final name (a rename within a file system is atomic); a write that fails
removes its temporary file. A process killed mid-write cannot remove it: the next writer of the
folder, holding its lock (evalkit/core/lock.py), removes what is left (`remove_temporaries`).
"""

from __future__ import annotations

import contextlib
import os
import re
from pathlib import Path

# `atomic_path`'s temporary names: .<stem>.<pid>.tmp<suffix>
TEMPORARY = re.compile(r"^\..+\.\d+\.tmp(\.[^.]+)*$")


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


def remove_temporaries(folder: str | os.PathLike) -> int:
    """Remove the temporaries killed writers left directly in ``folder`` (only its writer may
    call this, under the folder's lock); returns how many."""
    stale = [p for p in Path(folder).iterdir() if p.is_file() and TEMPORARY.match(p.name)]
    for path in stale:
        path.unlink(missing_ok=True)
    return len(stale)
