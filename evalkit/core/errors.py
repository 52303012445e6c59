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
