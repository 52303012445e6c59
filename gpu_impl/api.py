"""One call for one job: `render` a scene, `trace_bundles` of one direction set, each with its GL
objects made and released inside (the process's GL context unless one is given: making one is
slow). `gpu_impl.renderer.Renderer` and the tracers (`bundle_tracer`) stay for callers that keep
state between calls (frames of an animation, builds of many direction sets).
"""

from __future__ import annotations

import os

from evalkit.core.bundleset import BundleSet, DirectionSet
from evalkit.core.scene import Scene, load_scene
from evalkit.core.settings import RenderSettings
from gpu_impl.bundles import BundleTracer
from gpu_impl.context import GLContext, default_context
from gpu_impl.registry import resolve
from gpu_impl.renderer import Renderer, RenderResult
from gpu_impl.scene_buffers import GpuScene


def render(
    scene: Scene | str | os.PathLike,
    settings: RenderSettings | None = None,
    gl: GLContext | None = None,
    progress=None,
) -> RenderResult:
    """Render ``scene`` (a `Scene`, a built-in name or a scene file) with ``settings`` (default:
    `RenderSettings()`): direct, indirect and total images, timings, statistics and provenance.
    ``progress`` (optional) gets one line per frame."""
    scene = scene if isinstance(scene, Scene) else load_scene(scene)
    with Renderer(gl or default_context(), scene, settings or RenderSettings()) as renderer:
        return renderer.render(progress)


def bundle_tracer(gl: GLContext, gpu_scene: GpuScene, settings: RenderSettings, **extra) -> BundleTracer:
    """The tracer of the bundle method ``settings`` names, for an uploaded scene; ``extra``: the
    tracers' hooks (count_covered, initial_capacity, max_atlas_size, textures)."""
    resolved = resolve(settings)
    return resolved.method.tracer(gl, gpu_scene, resolved.settings, **extra)


def trace_bundles(
    scene: Scene | str | os.PathLike,
    directions: DirectionSet,
    settings: RenderSettings | None = None,
    gl: GLContext | None = None,
    **extra,
) -> BundleSet:
    """The bundles of one `DirectionSet`, made once with the method ``settings`` names (its K is
    the direction set's): the scene uploaded, its bundles built and read back, and every GL object
    released. The build's statistics are in the result's ``stats``."""
    scene = scene if isinstance(scene, Scene) else load_scene(scene)
    settings = RenderSettings(**{**(settings or RenderSettings()).flat(), "directions": directions.count})
    gl = gl or default_context()
    with GpuScene(gl, scene) as gpu_scene, bundle_tracer(gl, gpu_scene, settings, **extra) as tracer:
        tracer.build(directions)
        return tracer.read()
