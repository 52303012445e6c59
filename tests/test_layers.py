"""The import structure (docs/ARCHITECTURE.md): one-way layers and no module cycles, counting the
imports inside functions too, read from the source with `ast`.

- `evalkit.core` imports nothing of the project outside itself;
- `gpu_impl` and `references` import only `evalkit.core` (and themselves);
- the upper modules of evalkit import downward, and no module imports itself back through others;
- an import of a project module inside a function must say why on its line or the line above
  (``# deferred: ...``): the only reason allowed is to defer a heavy optional dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
PACKAGES = ("evalkit", "gpu_impl", "references")
DEFERRED = "# deferred:"


def project_modules() -> dict[str, Path]:
    """Module name -> file, for every module of the three packages."""
    modules = {}
    for package in PACKAGES:
        for path in (REPO / package).rglob("*.py"):
            parts = path.relative_to(REPO).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def imports_of(path: Path, modules: dict[str, Path]) -> list[tuple[str, int, bool]]:
    """(imported project module, line, inside a function) for every import statement of a file.
    ``from a.b import c`` imports module a.b.c when that is a module, else a.b."""
    tree = ast.parse(path.read_text())
    found = []

    def visit(node, in_function: bool):
        for child in ast.iter_child_nodes(node):
            inside = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                found.extend((a.name, child.lineno, inside) for a in child.names if a.name in modules)
            elif isinstance(child, ast.ImportFrom) and child.level == 0 and child.module in modules:
                for a in child.names:
                    sub = f"{child.module}.{a.name}"
                    found.append((sub if sub in modules else child.module, child.lineno, inside))
            visit(child, inside)

    visit(tree, False)
    return found


def layer(module: str) -> str:
    if module == "evalkit.core" or module.startswith("evalkit.core."):
        return "core"
    return module.split(".")[0] if not module.startswith("evalkit") else "evalkit"


ALLOWED = {
    "core": {"core"},
    "gpu_impl": {"core", "gpu_impl"},
    "references": {"core", "references"},
    "evalkit": {"core", "gpu_impl", "references", "evalkit"},
}


def graph() -> tuple[dict[str, set[str]], list[str]]:
    modules = project_modules()
    edges, undeclared = {m: set() for m in modules}, []
    for module, path in modules.items():
        lines = path.read_text().splitlines()
        for target, line, inside in imports_of(path, modules):
            edges[module].add(target)
            if inside and not any(DEFERRED in lines[i] for i in (line - 1, line - 2) if i >= 0):
                undeclared.append(f"{path.relative_to(REPO)}:{line} imports {target} inside a function")
    return edges, undeclared


def test_layers_import_downward_only():
    edges, _ = graph()
    wrong = [
        f"{m} ({layer(m)}) imports {t} ({layer(t)})"
        for m, targets in edges.items()
        for t in targets
        if layer(t) not in ALLOWED[layer(m)]
    ]
    assert not wrong, "\n".join(wrong)


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components: each of more than one module (or a module
    importing itself) is a cycle."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def connect(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges[v]:
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in edges[v]:
                found.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            connect(v)
    return found


def test_no_module_import_cycles():
    edges, _ = graph()
    assert not cycles(edges)


def test_imports_inside_functions_say_why():
    _, undeclared = graph()
    assert not undeclared, (
        "\n".join(undeclared) + f"\n(a deferred import needs a '{DEFERRED} <heavy dependency>' comment)"
    )


def test_the_checks_see_what_they_check():
    # The walker must find the imports the rules are about: the renderer's import of the scene
    # model, and one inside a function when there is one.
    modules = project_modules()
    assert "evalkit.core.scene" in {t for t, _, _ in imports_of(modules["gpu_impl.renderer"], modules)}
    source = REPO / "tests" / "data" / "layers_probe.py"
    found = imports_of(source, {**modules, "layers_probe": source})
    assert ("gpu_impl.bundles", 4, True) in found and ("evalkit.core.errors", 1, False) in found
    # A cycle the code once had, hidden in imports inside functions: check -> report -> study -> report.
    assert cycles({"check": {"report"}, "report": {"study", "check"}, "study": {"report"}, "cli": {"check"}}) == [
        ["check", "report", "study"]
    ]


# -- the registry (gpu_impl/registry.py): units are named by their own modules only ---------------


def string_constants(path: Path) -> list[tuple[str, int]]:
    """Every string constant of a file that is not a docstring, with its line."""
    tree = ast.parse(path.read_text())
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    return [
        (node.value, node.lineno)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings
    ]


def python_files_outside(*excluded: str) -> list[Path]:
    files = [p for d in (*PACKAGES, "benchmarks") for p in (REPO / d).rglob("*.py")]
    return [p for p in files if not any(p.relative_to(REPO).as_posix().startswith(e) for e in excluded)]


def test_no_module_but_its_own_names_a_bundle_method():
    # Adding a method is its module and one registration: nothing else may branch on its name.
    from gpu_impl.registry import METHODS

    # The imperfect shadow maps (a light visibility) share the imperfect bundles' name; their own
    # module declares it.
    found = [
        f"{path.relative_to(REPO)}:{line}: {value!r}"
        for path in python_files_outside("gpu_impl/methods/", "gpu_impl/visibility/imperfect.py")
        for value, line in string_constants(path)
        if value in METHODS.names
    ]
    assert not found, "\n".join(found)


def test_the_renderer_is_made_in_one_place_outside_the_gpu_side():
    # Everything else renders through the one-call API (gpu_impl/api.py).
    made = [
        f"{path.relative_to(REPO)}:{n}"
        for path in python_files_outside("gpu_impl/")
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if "Renderer(" in line
    ]
    assert len(made) <= 1, made
