"""Imperfect shadow maps measured against exact ones, for the same light vertices: what each costs a
frame, the share of connections whose visibility differs (a light vertex that one calls visible
from a receiver point and the other hidden), and how far each is from the truth, Embree rays. The
light vertices are those a frame's light paths leave (`gpu_impl.strategies.bidirectional`); the
receivers are surface points the camera sees (the first eye vertices). benchmarks/shadow_maps.py
runs it on atrium; tests/test_bidirectional.py on a small scene.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from evalkit.core.bundleset import DirectionSet
from evalkit.core.scene import Scene
from evalkit.core.scene.model import camera_rays
from evalkit.core.settings import RenderSettings
from gpu_impl.context import GLContext, set_uniforms
from gpu_impl.layout import BINDINGS
from gpu_impl.lights import LightVertices, ShadowLights
from gpu_impl.registry import resolve
from gpu_impl.renderer import Renderer
from gpu_impl.scene_buffers import GpuScene
from gpu_impl.timing import median_ms
from references.embree import ExactTracer

# A connection is visible where its filtered visibility is at least this.
VISIBLE = 0.5


def frame_light_vertices(gl: GLContext, scene: Scene, settings: RenderSettings, count: int) -> LightVertices:
    """The first ``count`` light path vertices of frame 0 of a bidirectional render with ``settings``
    (fewer where its light paths leave fewer)."""
    with Renderer(gl, scene, settings) as renderer:
        renderer.tracer.build(DirectionSet.make(settings.directions, seed=settings.seed, frame=0, jitter=True))
        renderer.lights.render_shadow_maps()
        vertices = renderer.strategy.light_vertices(settings.seed, 0)
    depth = vertices.depths > 0
    return LightVertices(*(column[depth][:count] for column in vertices))


def camera_points(scene: Scene, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Receivers where connections start: up to ``count`` surface points the camera sees, through
    uniformly drawn film positions (by Embree rays), and their shading normals turned to the camera."""
    camera = scene.camera.frame(np.zeros(3), *scene.camera.film_size(None, None))
    film = np.random.default_rng([seed, 4]).random((count, 2))
    origins, directions = camera_rays(camera, film)
    hits = ExactTracer(scene).next_hit(origins, directions)
    seen = hits.prim_id >= 0
    normals = hits.normal[seen] * -np.sign(np.einsum("ij,ij->i", hits.normal[seen], directions[seen]))[:, None]
    return hits.point[seen], normals


def measure(
    gl: GLContext,
    scene: Scene,
    settings: RenderSettings,
    vertices: LightVertices,
    receivers: tuple[np.ndarray, np.ndarray],
    repeats: int = 1,
) -> dict:
    """The light vertices' maps of the light visibility ``settings`` names: the median time to make
    them (ms, after one warm-up) and the visibility of every (receiver, vertex) pair (R, V: -1 where
    they do not face each other)."""
    count = len(vertices.positions)
    with vertex_shadow_maps(gl, scene, settings, count) as lights:
        ms = median_ms(gl, lambda: lights.set_light_vertices(vertices, settings.seed, 0), repeats)
        positions, normals = receivers
        records = np.zeros((len(positions), 2, 4), dtype=np.float32)
        records[:, 0, :3] = positions - lights.gpu_scene.centre
        records[:, 1, :3] = normals
        defines = {**lights.visibility.defines(), "ATLAS_TEXTURES": lights.atlas_textures}
        program = gl.program("connection_visibility", **defines)
        lights.set_uniforms(program)
        set_uniforms(program, {"first_vertex": lights.fixed_lights, "vertex_count": count})
        receiver_buffer = gl.buffer(records.tobytes())
        visible = gl.buffer(reserve=4 * len(positions) * count)
        receiver_buffer.bind_to_storage_buffer(BINDINGS["RECEIVERS"])
        visible.bind_to_storage_buffer(BINDINGS["VISIBLE"])
        lights.bind()
        gl.dispatch(program, len(positions) * count)
        result = np.frombuffer(visible.read(), dtype=np.float32).reshape(len(positions), count).copy()
        receiver_buffer.release()
        visible.release()
    return {"ms": ms, "visibility": result}


@contextmanager
def vertex_shadow_maps(gl: GLContext, scene: Scene, settings: RenderSettings, count: int):
    """The `ShadowLights` of ``scene`` with places for ``count`` light vertices, whose maps the light
    visibility ``settings`` names makes; nothing drawn yet. Its GL objects and the uploaded scene
    (``lights.gpu_scene``) are released after."""
    resolved = resolve(settings)
    gpu_scene = GpuScene(gl, scene)
    maps = resolved.units["light_visibility"].maps(gl, gpu_scene, resolved.unit_settings["light_visibility"])
    lights = ShadowLights(gl, gpu_scene, resolved.settings, maps, 0, count)
    try:
        yield lights
    finally:
        lights.release()  # and the maps
        gpu_scene.release()


def differing_share(exact: np.ndarray, other: np.ndarray) -> float:
    """The share of connecting pairs (those facing each other in ``exact``: -1 marks the others)
    whose visibility differs."""
    return sum(changed_shares(exact, other))


def changed_shares(exact: np.ndarray, other: np.ndarray) -> tuple[float, float]:
    """The differing pairs' shares of the connecting pairs, split: (hidden, leaked), seen in
    ``exact`` but not in ``other``, and the reverse."""
    pairs = exact >= 0.0
    if not pairs.any():
        return 0.0, 0.0
    seen, seen_other = (exact >= VISIBLE)[pairs], (other >= VISIBLE)[pairs]
    return float((seen & ~seen_other).mean()), float((~seen & seen_other).mean())


def light_shares(
    visibility: np.ndarray, truth: np.ndarray, vertices: LightVertices, receivers: tuple[np.ndarray, np.ndarray]
) -> tuple[float, float]:
    """The light that maps' ``visibility`` lets through where the rays' ``truth`` is blocked, and
    the light it hides where the rays get through: (leaked, hidden), each over the light the rays
    let through, every pair weighted by its geometry term cos_x cos_y / d^2 (what a connection
    carries), over the pairs facing each other (``visibility`` >= 0). Shares of pairs
    (`changed_shares`) count a grazing connection as much as a head-on one; this weighs them by
    the light they carry."""
    positions, normals = receivers
    d = vertices.positions[None, :, :] - positions[:, None, :]
    d2 = np.einsum("rvk,rvk->rv", d, d)
    u = d / np.sqrt(d2)[..., None]
    weight = (
        np.clip(np.einsum("rvk,rk->rv", u, normals), 0.0, None)
        * np.clip(-np.einsum("rvk,vk->rv", u, vertices.normals), 0.0, None)
        / d2
        * (visibility >= 0.0)
    )
    seen, true = visibility >= VISIBLE, truth >= VISIBLE
    total = float((weight * true).sum())
    if total == 0.0:
        return 0.0, 0.0
    return float((weight * (seen & ~true)).sum()) / total, float((weight * (~seen & true)).sum()) / total


def traced_visibility(scene: Scene, vertices: LightVertices, receivers: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The true visibility of every (receiver, vertex) pair, by Embree rays (references.embree), as
    1 or 0: what both kinds of shadow maps approximate. Rays leave each end a millionth of the
    scene's radius off its surface."""
    tracer = ExactTracer(scene)
    positions, normals = receivers
    offset = 1e-6 * tracer.radius
    origins = np.repeat(positions + offset * normals, len(vertices.positions), axis=0)
    ends = np.tile(vertices.positions + offset * vertices.normals, (len(positions), 1))
    hits = tracer.next_hit(origins, ends - origins, t_max=1.0 - 1e-6)
    return (hits.prim_id < 0).astype(np.float32).reshape(len(positions), len(vertices.positions))
