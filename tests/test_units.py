"""Every registered unit against the contract the renderer relies on (gpu_impl/units.py: Tracer,
ShadowMaps, Paths), parametrized over the registries: a new unit is tested by registering it."""

from __future__ import annotations

import pytest
from conftest import render_with

from evalkit.core.scene import load_scene
from evalkit.core.settings import RenderSettings
from gpu_impl.registry import KINDS, LIGHT_VISIBILITIES, METHODS, STRATEGIES
from gpu_impl.renderer import Renderer
from gpu_impl.units import Paths, ShadowMaps, Tracer

UNITS = [(kind, unit.name) for kind, registry in KINDS.items() for unit in registry]


@pytest.mark.parametrize("kind, name", UNITS, ids=[f"{k}-{n}" for k, n in UNITS])
def test_every_registered_unit_makes_what_the_renderer_uses_and_renders(gl, kind, name):
    # cornell-box has an emitter, so every strategy has light vertices whose maps every visibility draws.
    settings = RenderSettings(
        **{kind: name}, bounces=1, directions=4, resolution=32, width=16, height=16, frames=2, light_samples=2
    )
    scene = load_scene("cornell-box")
    with Renderer(gl, scene, settings) as renderer:
        assert isinstance(renderer.tracer, Tracer), type(renderer.tracer)
        assert isinstance(renderer.lights.visibility, ShadowMaps), type(renderer.lights.visibility)
        assert isinstance(renderer.strategy, Paths), type(renderer.strategy)
        result = renderer.render()
    assert result.params[kind] == name
    assert all(image.mean() > 0 for image in result.images.values())


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
