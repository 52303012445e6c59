"""Every registered unit against the contract the renderer relies on (gpu_impl/units.py: Tracer,
ShadowMaps, Paths), parametrized over the registries: a new unit is tested by registering it."""

from __future__ import annotations

import importlib.metadata
import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import render_with

import evalkit
from evalkit.core.bundleset import DirectionSet
from evalkit.core.scene import load_scene
from evalkit.core.settings import RenderSettings
from evalkit.study.run import versions
from gpu_impl.api import trace_bundles
from gpu_impl.registry import KINDS, LIGHT_VISIBILITIES, METHODS, STRATEGIES
from gpu_impl.renderer import Renderer
from gpu_impl.units import Paths, ShadowMaps, Tracer

UNITS = [(kind, unit.name) for kind, registry in KINDS.items() for unit in registry]


def check_unit(gl, kind: str, name: str, **options) -> str:
    """Render cornell-box with the unit ``name`` of ``kind`` (a RenderSettings field) and check the
    objects it makes against the contract; its tracer's description. cornell-box has an emitter, so
    every strategy has light vertices whose maps every visibility draws."""
    settings = RenderSettings(
        **{kind: name}, bounces=1, directions=4, resolution=32, width=16, height=16, frames=2, light_samples=2,
        options=tuple(options.items()),
    )  # fmt: skip
    with Renderer(gl, load_scene("cornell-box"), settings) as renderer:
        assert isinstance(renderer.tracer, Tracer), type(renderer.tracer)
        assert isinstance(renderer.lights.visibility, ShadowMaps), type(renderer.lights.visibility)
        assert isinstance(renderer.strategy, Paths), type(renderer.strategy)
        result = renderer.render()
        described = renderer.tracer.describe()
    assert result.params[kind] == name and all(result.params[k] == v for k, v in options.items())
    assert all(image.mean() > 0 for image in result.images.values())
    return described


@pytest.mark.parametrize("kind, name", UNITS, ids=[f"{k}-{n}" for k, n in UNITS])
def test_every_registered_unit_makes_what_the_renderer_uses_and_renders(gl, kind, name):
    check_unit(gl, kind, name)


# The recipe's registration (docs/ARCHITECTURE.md, "Adding a unit"): the toy's import and its name in
# the line that registers its kind, made to gpu_impl/registry.py's source before anything reads it.
TOY = """
import importlib.util, json, sys
from pathlib import Path
sys.path.insert(0, {tests!r})
import gpu_impl
path = Path(gpu_impl.__file__).with_name("registry.py")
line = 'METHODS = Registry("bundle method", perfect.METHOD, imperfect.METHOD)'
source = path.read_text()
assert source.count(line) == 1, "the registration line moved: update the recipe and this test"
source = source.replace(line, "import toy_method\\n" + line[:-1] + ", toy_method.METHOD)")
spec = importlib.util.spec_from_file_location("gpu_impl.registry", path)
sys.modules[spec.name] = registry = importlib.util.module_from_spec(spec)
exec(compile(source, str(path), "exec"), registry.__dict__)

from evalkit.cli import main
from evalkit.reference_docs import settings_markdown
from gpu_impl.context import default_context
from test_units import check_unit

code = main(["render", "cornell-box", "--method", "toy", "--toy-tag", "3", "--bounces", "1", "--directions", "4",
             "--resolution", "32", "--width", "16", "--height", "16", "--frames", "2", "--out", {out!r}])
with default_context() as gl:
    described = check_unit(gl, "method", "toy", toy_tag=5)
page = settings_markdown()
listed = {{"listed": "### `toy`" in page, "setting": "| `toy_tag` |" in page}}
print(json.dumps({{"code": code, "described": described, **listed}}))
"""


def test_a_toy_unit_is_its_module_and_one_registration_line(tmp_path):
    script = TOY.format(tests=str(Path(__file__).parent), out=str(tmp_path / "toy"))
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    found = json.loads(run.stdout.splitlines()[-1])
    assert found == {"code": 0, "described": "toy bundles 5 (K=4, R=32)", "listed": True, "setting": True}
    params = json.loads((tmp_path / "toy" / "timings.json").read_text())["params"]
    assert params["method"] == "toy" and params["toy_tag"] == 3


def test_the_registries_name_each_kind_once_and_list_their_defaults_first():
    assert set(KINDS.values()) == {METHODS, STRATEGIES, LIGHT_VISIBILITIES}
    for registry in KINDS.values():
        assert registry.default is next(iter(registry)) and len(set(registry.names)) == len(registry.names)


def test_render_with_drops_what_a_unit_does_not_declare(gl):
    # A setting of one unit given to a render of another is left out, not an error (studies give
    # every run the grid's settings).
    result = render_with(gl, load_scene("cornell-box"), method=METHODS.default.name, points=1024, frames=1,
                         directions=2, resolution=16, width=8, height=8)  # fmt: skip
    assert "points" not in result.params


def test_a_checkout_run_without_installing_records_the_toolkit_s_version(gl, monkeypatch):
    """Run from a checkout that was never `pip install`ed (a GPU machine given the sources and its
    own Python), renders, bundles and records take the toolkit's version from its package: read
    from the installed metadata, every render stopped with PackageNotFoundError."""
    installed = importlib.metadata.version("raybundle-evalkit")
    real = importlib.metadata.version

    def version(name):
        if name == "raybundle-evalkit":
            raise importlib.metadata.PackageNotFoundError(name)
        return real(name)

    monkeypatch.setattr(importlib.metadata, "version", version)
    result = render_with(gl, load_scene("furnace"), width=8, height=8, frames=1, directions=4, resolution=16)
    bundles = trace_bundles(load_scene("furnace"), DirectionSet.make(2, seed=0), RenderSettings(resolution=16), gl=gl)
    assert result.params["evalkit"] == bundles.params["evalkit"] == versions()["raybundle-evalkit"] == installed
    assert evalkit.__version__ == installed  # the package's version is the one pip installs
