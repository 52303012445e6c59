"""One writer per output folder: an advisory lock on ``<folder>/.evalkit.lock``.

The lock is a `fcntl.flock` on that file, which the kernel releases when its process ends, however
it ends (exit, Ctrl-C, SIGKILL), so a lock is never left held by a process that is gone. The file
says who holds it (pid, host, start time, command) so that a second process can say so in its
error. A holder that exits normally empties the file; a file found with a holder's line in it but
no lock on it was left by a process that died, and is taken over with a warning. The new holder
removes the temporary files a killed writer left in the folder (evalkit/core/atomic.py).

Two `evalkit study` processes on one folder would both run its unfinished rows and both append
them: the same run twice in ``results.jsonl``.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket
import sys
import time
from pathlib import Path

from evalkit.core.atomic import remove_temporaries
from evalkit.core.errors import InputError

LOCK_NAME = ".evalkit.lock"


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike, what: str, wait: bool = False, progress=print):
    """Hold ``folder``'s lock for the body. ``what`` names the writer in messages ("study"). A
    lock held by another process raises `InputError` naming it, or with ``wait`` blocks until it
    is released."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_NAME
    with open(path, "a+") as f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(f)
            if not wait:
                raise InputError(
                    folder, f"another {what} is writing here ({holder}); wait for it with --wait, or use another folder"
                ) from None
            progress(f"waiting for {folder}: another {what} is writing here ({holder})")
            fcntl.flock(f, fcntl.LOCK_EX)
        left = _holder(f)
        if left:
            progress(f"warning: {folder}: took over the lock of a {what} that ended without releasing it ({left})")
        if remove_temporaries(folder):  # a killed writer's half-written files, never read
            progress(f"{folder}: removed the temporary files of a {what} that was killed mid-write")
        f.seek(0)
        f.truncate()
        f.write(f"pid {os.getpid()} on {socket.gethostname()} since {time.strftime('%Y-%m-%d %H:%M:%S')}: ")
        f.write(" ".join(sys.argv) + "\n")
        f.flush()
        try:
            yield
        finally:
            f.seek(0)
            f.truncate()
            f.flush()
            fcntl.flock(f, fcntl.LOCK_UN)


def _holder(f) -> str:
    f.seek(0)
    return f.read().strip()
