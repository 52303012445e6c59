"""Notebooks run as a kernel runs them, without one: the code cells in order in one namespace, each
cell's last expression shown through its ``_repr_html_``. The documentation's tutorials are
notebooks run so when the site is built (docs/hooks.py), outputs and pictures in the page; the
tests run them the same way."""

from __future__ import annotations

import ast
import html
import json
import os
import shlex
import subprocess
import sys
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import NamedTuple

from evalkit.core import VERSION
from gpu_impl.context import default_context


class Cell(NamedTuple):
    """A cell: its kind ("markdown" or "code"), its source, and what a code cell shows (HTML; None
    where its last statement is not an expression)."""

    kind: str
    source: str
    shown: str | None = None


class Shell(NamedTuple):
    """A command run as a terminal runs it (`shell`): shown as the command, what it printed and its
    exit status."""

    command: list[str]
    output: str
    returncode: int

    def _repr_html_(self) -> str:
        text = f"$ {shlex.join(self.command)}\n{self.output.rstrip()}\n(exit status {self.returncode})"
        return f"<pre>{html.escape(text)}</pre>"


def shell(*command: str) -> Shell:
    """Run ``command`` (``evalkit`` is this environment's) in the current directory: what a
    tutorial shows of a command line, as a CI job would run it."""
    path = f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"
    run = subprocess.run(command, capture_output=True, text=True, env={**os.environ, "PATH": path})
    return Shell(list(command), run.stdout + run.stderr, run.returncode)


class RunNotebook(NamedTuple):
    cells: list[Cell]
    namespace: dict


def run_notebook(path: str | os.PathLike) -> RunNotebook:
    """Every cell of the notebook at ``path``, run in the current directory (what a cell writes
    goes there); the namespace the cells left."""
    source = Path(path)
    namespace: dict = {}
    cells = []
    for cell in json.loads(source.read_text())["cells"]:
        text = "".join(cell["source"])
        if cell["cell_type"] != "code":
            cells.append(Cell(cell["cell_type"], text))
            continue
        tree = ast.parse(text)
        last = tree.body.pop() if tree.body and isinstance(tree.body[-1], ast.Expr) else None
        exec(compile(tree, source.name, "exec"), namespace)
        shown = None
        if last is not None:
            value = eval(compile(ast.Expression(last.value), source.name, "eval"), namespace)
            shown = value._repr_html_() if hasattr(value, "_repr_html_") else f"<pre>{html.escape(repr(value))}</pre>"
        cells.append(Cell("code", text, shown))
    return RunNotebook(cells, namespace)


def notebook_markdown(path: str | os.PathLike, repository: str | os.PathLike) -> str:
    """The notebook at ``path`` as a page, run now in a folder of its own: its Markdown cells, its
    code, each code cell's output, and what ran it (the notebook named from ``repository``)."""
    path = Path(path).resolve()
    here = os.getcwd()
    with tempfile.TemporaryDirectory() as folder:
        os.chdir(folder)
        try:
            run = run_notebook(path)
        finally:
            os.chdir(here)
    parts = []
    for cell in run.cells:
        if cell.kind == "markdown":
            parts.append(cell.source)
        elif cell.kind == "code":
            parts.append(f"```python\n{cell.source}\n```")
            if cell.shown is not None:
                # One line of HTML in a block of its own: Markdown passes it through as it is.
                parts.append(f'<div class="ek-output">{" ".join(cell.shown.splitlines())}</div>')
    gl = default_context().info  # the context the cells rendered with
    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    parts.append(
        f"*Run when this page was built: `{path.relative_to(Path(repository).resolve())}`, "
        f"evalkit {VERSION}, {gl['renderer']}, {when}.*"
    )
    return "\n\n".join(parts) + "\n"
