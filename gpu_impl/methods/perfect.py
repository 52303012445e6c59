"""Perfect ray bundles: every triangle drawn once per direction, instanced into an atlas of R x R
tiles (one draw call per atlas), each fragment appending a node to its pixel's linked list
(shaders/bundles/perfect_bundles.glsl), then each list sorted into its slot range
(shaders/bundles/resolve_lists.glsl). The rasterizer only decides coverage: a node's depth is where its
pixel's line meets the triangle's plane, exact to float32.
"""

from __future__ import annotations

import moderngl
import numpy as np

from gpu_impl.bundles import LinkedListTracer
from gpu_impl.layout import COUNTERS, NODE_TRIANGLE
from gpu_impl.units import BundleMethod, TuneTerms


class PerfectTracer(LinkedListTracer):
    """Perfect bundles of one uploaded scene (`gpu_impl.bundles.BundleTracer` says what it holds)."""

    node_reference = NODE_TRIANGLE
    raster_program = "perfect_bundles"

    def __init__(self, gl, gpu_scene, settings, **hooks):
        super().__init__(gl, gpu_scene, settings, **hooks)
        self._make_lists()
        self._compile()

    def describe(self) -> str:
        return f"perfect bundles (K={self.K}, R={self.R})"

    def compute_programs(self) -> list:
        gl = self.gl
        return [gl.program("resolve_lists", COUNT_LISTS=True), *self.sort_programs(SORT_LISTS=True)]

    def vertex_array(self, program):
        return self.gpu_scene.vertex_array(program)

    def draw(self, vao, base: int, count: int) -> None:
        self.gl.draw(vao, moderngl.TRIANGLES, self.framebuffer, depth_test=False, instances=count)

    def build_lists(self, directions, timer) -> tuple[int, int]:
        self.bind()
        return self.linked_lists(timer)

    def resolve_lists(self) -> None:
        self.count_lists()
        self.sort_lists(SORT_LISTS=True)

    def build_stats(self, counters: np.ndarray, raw: int) -> dict:
        # Coincident triangles (a two-sided wall of two faces) put two nodes at one depth: all kept.
        return {
            "nodes": raw,
            "covered_nodes": raw,
            "redundant_nodes": int(counters[COUNTERS["REDUNDANT"]]),
            "redundant_tolerance": 0.0,
            "merged": False,
            "capacity": self.capacity,
        }


def _time(x: dict) -> list:
    return [x["frames"] * x["directions"] * 1e-3]  # t_dirs: a draw per direction


METHOD = BundleMethod(
    name="perfect",
    summary="every triangle rasterized along every direction into per-pixel linked lists",
    tracer=PerfectTracer,
    tune=TuneTerms(
        time_terms=("t_dirs",),
        time=_time,
        # (K, R), spread so that every term of the models changes between runs; the last two run longest.
        calibration=tuple(
            {"directions": k, "resolution": r}
            for k, r in [
                (8, 64),
                (32, 64),
                (8, 128),
                (32, 128),
                (16, 96),
                (64, 128),
                (8, 192),
                (16, 256),
                (16, 128),
                (32, 64),
            ]
        ),
    ),
)
