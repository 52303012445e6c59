"""The one error type users see: it names the input and the problem, in one line."""

from __future__ import annotations

import os


class InputError(Exception):
    """Bad user input (a file, a scene name, a parameter).

    The CLI prints ``evalkit: error: <source>: <problem>`` and exits with code 2, without a
    traceback. ``source`` is the file or name the problem is in.
    """

    def __init__(self, source: str | os.PathLike, problem: str):
        self.source = str(source)
        self.problem = " ".join(str(problem).split())  # one line, whatever the library said
        super().__init__(f"{self.source}: {self.problem}")


class LimitError(ValueError):
    """Settings past what the renderer's index types or the GL context hold (a shadow atlas past
    half the free memory, more eye paths than a 32-bit index counts, ...): refused before anything is
    rendered. ``settings`` names the render settings whose values went past it, so that a caller
    that chooses settings (`evalkit tune`) can leave out those values and any larger ones."""

    def __init__(self, problem: str, settings: tuple[str, ...]):
        super().__init__(problem)
        self.settings = settings


def check_output(path: str | os.PathLike, folder: bool) -> None:
    """Raise `InputError` now if ``path`` cannot become an output folder (``folder``) or file:
    checked before any work, so that a render is not lost to a path that was never writable."""
    path = os.path.abspath(path)
    if os.path.exists(path):
        if folder and not os.path.isdir(path):
            raise InputError(path, "exists and is not a folder; outputs go into a folder (give another --out)")
        if not folder and os.path.isdir(path):
            raise InputError(path, "is a folder; the output is a file (give a file name)")
        if not os.access(path if folder else os.path.dirname(path), os.W_OK):
            raise InputError(path, "is not writable")
        return
    parent = os.path.dirname(path)
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise InputError(path, f"cannot be made: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK):
        raise InputError(path, f"cannot be made: {parent} is not writable")
