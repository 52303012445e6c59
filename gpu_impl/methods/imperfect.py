"""Imperfect ray bundles (the poster's point splats): each direction draws its own seeded set of N
points on the surfaces, each a disk of radius ``splat_scale * sqrt(A / (pi N))`` (or
``splat_radius``) in its source triangle's plane, and the nodes are where bundle lines cross the
disks. A splat ends at its triangle's sharp edges (convex creases and boundaries:
`evalkit.core.scene.edges.sharp_edges`) and at those of the triangle's neighbours in its plane
(`splat_cuts`), where a disk would stand out into empty space, and grows there, on its own triangle,
until a crossing at the edge is covered as often as one inside the face (shaders/include/scene.glsl:
sharp_splat_radius, inside_splat).

- ``points``: N points per direction (shaders/bundles/splat_points.glsl), stratified along a space-filling
  curve or independent (``sampler``), each with its splat's radius. They are drawn by area, but
  every smooth surface has at least `SURFACE_LEAST_POINTS` points' share
  (gpu_impl/scene_buffers.py: surface_area_cdf), and A is the area so weighted.
- ``lists``, compute splatter (the default): every splat counts the lines it covers (the points pass
  queues the splats that no line cuts apart from the cut ones, and a round-trip reads how many: each
  run has a count program of its own), a prefix sum makes exact-size slot ranges, round-trip 1
  reads their total, and every splat writes its nodes
  (shaders/bundles/splat_lists.glsl): no linked list, no re-run. The count pass leaves each splat's lines
  behind (`SPLAT_LINES`, an 8 x 8 box, with their depth plane) so the scatter neither searches for
  them again nor reads the point; the few splats larger than that box are queued, and a pass over
  just those finds their lines again.
- ``lists``, raster splatter: the poster's splats drawn by the rasterizer as triangles with a
  circular cut-out into linked lists (shaders/bundles/imperfect_bundles.glsl).
- ``resolve``: each list sorted and its redundant nodes (one surface crossing covered by several
  splats) merged in place, at the front of its range (shaders/bundles/resolve_lists.glsl).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import moderngl
import numpy as np

from evalkit.core.errors import LimitError
from evalkit.core.scene.edges import FLAT_DEGREES, SPLAT_CREASE_DEGREES, SPLAT_GROWTH
from evalkit.core.settings import DEPTH_TOLERANCE, setting
from gpu_impl.bundles import BundleTracer, LinkedListTracer
from gpu_impl.layout import (
    COUNTERS,
    NODE_SPLAT_POINT,
    SAMPLERS,
    SPLAT_LINES,
    SPLAT_LINES_MAX_RESOLUTION,
    SPLAT_POINT,
    TEXEL_UNITS,
)
from gpu_impl.scene_buffers import SURFACE_LEAST_POINTS, surface_area_cdf
from gpu_impl.units import BundleMethod, TuneTerms

SPLATTERS = ("compute", "raster")
# Splat radius in units of sqrt(A / (pi N)), the radius at which N disks cover area A once. With
# independent uniform points a surface point is missed by all of them with probability
# exp(-splat_scale^2); the stratified points leave far fewer holes, exp(-1.25 s^2.4) on cornell-box.
# 1.8 is the hole model's recommendation for stratified points (studies/hole_vs_splat.toml, the
# recorded run docs/results/data/hole_vs_splat.json: 1.77 on cornell-box, 1.94 on atrium whose
# curved-surface floor of holes no splat size removes), at 3.2 nodes per crossing against 4 for
# the old default 2.
DEFAULT_SPLAT_SCALE = 1.8
# Where the shadow-mapped light splat nodes reflect is computed: "precomputed" once per splat point
# (at its centre, up to a splat radius from a hit: cornell-box, K=256, R=128, indirect light +0.3 %
# over lazy light), "lazy" where each path lands, "auto" whichever costs fewer light evaluations
# in the frame (the renderer decides; shaders/lights/irradiance.glsl, eye_paths.glsl).
LIGHTING = ("auto", "precomputed", "lazy")
# The hole model's shape per sampler, P(hole) ~ exp(-c s^q) (studies/hole_vs_splat.toml on
# cornell-box): the tuner's hole term. Fitted to an earlier run; the recorded run's fits
# (docs/results/data/hole_vs_splat.json, "hole_model") are within 5 % of these.
HOLE_SHAPE = {"stratified": (1.26, 2.42), "random": (0.99, 1.95)}


@dataclass(frozen=True)
class ImperfectSettings:
    points: int = setting(16384, "points per direction", minimum=1, symbol="N")
    splat_scale: float = setting(
        DEFAULT_SPLAT_SCALE, "splat radius in units of sqrt(A / (pi N))", positive=True, symbol="s"
    )
    splat_radius: float | None = setting(
        None, "absolute splat radius in scene units (overrides splat_scale)", positive=True
    )
    sampler: str = setting(
        "stratified", "the points: stratified along a space-filling curve, or independent", choices=tuple(SAMPLERS)
    )
    splatter: str = setting(
        "compute", "splats found by a compute pass (exact-size lists) or drawn by the rasterizer", choices=SPLATTERS
    )
    merge: bool = setting(True, "merge the nodes of one surface crossing that several splats make")
    lighting: str = setting(
        "lazy",
        "splat points' shadow-mapped light: lazy at each path's hit, precomputed per point at its centre (a splat "
        "centre may lie where no hit does, as in a crevice, and its light is biased there), or auto per frame, "
        "whichever evaluates less (lazy with glossy materials, whose reflected light depends on direction)",
        choices=LIGHTING,
    )


class SplatTracer(BundleTracer):
    """What both splatters share: the points (and their copy as texels), their radius, the merge."""

    node_reference = NODE_SPLAT_POINT
    raw_nodes_are = "splat nodes before merging"
    # Per point, whatever the node count: the point and its copy as a texel.
    point_bytes = 2 * SPLAT_POINT.itemsize

    def __init__(self, gl, gpu_scene, settings, **hooks):
        # Its own settings first: the shared constructor checks the fixed memory, points included.
        own = METHOD.settings_of(settings)
        self.N, self.sampler, self.splatter, self.merge = own.points, own.sampler, own.splatter, own.merge
        self.lighting = own.lighting
        if 3 * settings.directions * self.N >= 2**31:
            raise LimitError(
                f"K={settings.directions}, N={self.N} exceed the 32-bit point indices", ("directions", "points")
            )
        # The points' CDF: area, with a share for every small surface (scene_buffers.py:
        # surface_area_cdf), which makes the points `point_density` times as many as the area
        # alone would. The unit of splat_scale: the radius at which N disks cover the weighted
        # area once, as they do the surfaces that kept their area's share.
        # The surfaces come with where splats end and grow (GpuScene.splat_facts: SPLAT_SHAPES).
        cdf, guide, self.point_density = surface_area_cdf(
            gpu_scene.arrays, gpu_scene.surfaces(), self.N, gpu_scene.curve_order
        )
        unit = math.sqrt(self.point_density * gpu_scene.arrays.tri_area.sum() / (math.pi * self.N))
        self.splat_radius = own.splat_radius if own.splat_radius is not None else own.splat_scale * unit
        self.splat_scale = self.splat_radius / unit
        if not (self.splat_radius > 0 and math.isfinite(self.splat_radius)):
            raise ValueError(f"the splat radius must be positive and finite, got {self.splat_radius}")
        super().__init__(gl, gpu_scene, settings, **hooks)
        self.buffers["SPLAT_CDF"] = self.gl.buffer(cdf.tobytes())
        self.buffers["SPLAT_CDF_GUIDE"] = self.gl.buffer(guide.tobytes())
        # The points as texels too, which the passes that read many of them load far faster than
        # a storage buffer on llvmpipe (shaders/include/bundle.glsl: SPLAT_TEXELS): copied from
        # POINTS after the points pass, so POINTS holds whole rows of them (triangle 0 for a
        # warm-up draw).
        self.point_texels = gl.record_texture(self.K * self.N, 4, "u4", "splat points", ("directions", "points"))
        self.gl.fill(self._ensure("POINTS", SPLAT_POINT.itemsize * self.point_texels.width * self.point_texels.height))

    points_are = "splat points and their texels"

    def describe(self) -> str:
        return f"imperfect bundles (K={self.K}, R={self.R}, N={self.N})"

    @property
    def fixed_bytes(self) -> int:
        return super().fixed_bytes + self.point_bytes * self.K * self.N

    @property
    def fixed_items(self) -> str:
        return f"{self.K * self.N:,} {self.points_are} and the lists' offsets and groups"

    @property
    def irradiance_items(self) -> int:
        """Precomputed node light is stored per splat point: every node a splat makes shares it."""
        return self.K * self.N

    def uniforms(self) -> dict:
        return {
            **super().uniforms(),
            "points_per_direction": self.N,
            "splat_radius": self.splat_radius,
            **TEXEL_UNITS,
        }

    @property
    def memory_bytes(self) -> int:
        texels = getattr(self, "point_texels", None)  # made after the shared constructor's checks
        return super().memory_bytes + (0 if texels is None else SPLAT_POINT.itemsize * texels.width * texels.height)

    def bind(self) -> None:
        super().bind()
        # Every pass that reads splat points reads them, and their triangles, as texels
        # (shaders/include/common.glsl: TRIANGLE_TEXELS, SPLAT_TEXELS).
        self.gpu_scene.triangle_texels().use(TEXEL_UNITS["triangle_texels"])
        self.point_texels.use(TEXEL_UNITS["point_texels"])

    def release(self) -> None:
        super().release()
        self.point_texels.release()

    @property
    def merge_tolerance(self) -> float:
        """How far apart in depth two nodes of one line may be and still be merged as one surface
        (shaders/bundles/resolve_lists.glsl): the depth tolerance under which the bundle metrics call two
        nodes one surface (`DEPTH_TOLERANCE` of the frame radius), so merging removes what they
        count redundant; negative (nothing merges) without merging. Splats of one plane cross a
        line at one depth; a wider tolerance (a splat radius) also merged a corner's two walls
        where one's splats overhang the other, trading holes for fewer nodes: measured on
        cornell-box (K=32, N=16384, s=1.5), 4.6 % holes against 3.6 %."""
        return DEPTH_TOLERANCE * self.gpu_scene.radius if self.merge else -1.0

    # The points pass's own defines (the compute splatter queues the splats for its count pass).
    points_defines: ClassVar[dict] = {}

    def points_program(self):
        return self.gl.program("splat_points", SAMPLER=SAMPLERS[self.sampler], **self.points_defines)

    def build_lists(self, directions, timer) -> tuple[int, int]:
        self.gl.fill(self.buffers["LIST_COUNTS"])
        self.bind()
        with timer.measure("points"):
            shader = self.points_program()
            seed, frame = directions.seed & 0xFFFFFFFF, directions.frame & 0xFFFFFFFF
            self._uniforms(shader, triangle_count=self.gpu_scene.triangle_count, seed=seed, frame=frame)
            self.gl.dispatch(shader, self.K * self.N)
            self.point_texels.write(self.buffers["POINTS"])
        return self.splat_lists(timer)

    def splat_lists(self, timer) -> tuple[int, int]:
        """Every splat's nodes into the lists; returns (re-runs, nodes written)."""
        raise NotImplementedError

    # shaders/bundles/resolve_lists.glsl's merge variant: where the splatter left each list.
    merge_defines: ClassVar[dict]

    def resolve_lists(self) -> None:
        self.sort_lists({"merge_tolerance": self.merge_tolerance}, **self.merge_defines)

    def covered_nodes(self, counters: np.ndarray, raw: int) -> int | None:
        """Every line a splat covers: without merging, one node each (None: not counted)."""
        return raw

    def build_stats(self, counters: np.ndarray, raw: int) -> dict:
        nodes = int(counters[COUNTERS["KEPT"]])
        return {
            "nodes": nodes,
            "covered_nodes": self.covered_nodes(counters, raw),
            "redundant_nodes": raw - nodes,
            "redundant_tolerance": self.merge_tolerance if self.merge else 0.0,
            "merged": self.merge,
            "sampler": self.sampler,
            "splatter": self.splatter,
        }

    def params(self) -> dict:
        return {
            "points": self.N,
            "splat_scale": self.splat_scale,
            "splat_radius": self.splat_radius,
            "sampler": self.sampler,
            "splatter": self.splatter,
            "merged": self.merge,
            "crease_degrees": SPLAT_CREASE_DEGREES,
            # how cut splats grow (shaders/include/scene.glsl: sharp_splat_radius; edges.py: SPLAT_GROWTH)
            "splat_growth": SPLAT_GROWTH,
            "flat_degrees": FLAT_DEGREES,  # cut by flat neighbours' sharp edges too (edges.splat_cuts)
            # every smooth surface has this many points' share (scene_buffers.py: surface_weights)
            "surface_least_points": SURFACE_LEAST_POINTS,
            "point_density": self.point_density,
        }

    def read_points(self) -> np.ndarray:
        """The last build's splat points (K N,) as `SPLAT_POINT` records."""
        return self.gl.read(self.buffers["POINTS"], SPLAT_POINT, self.K * self.N)

    def splat_fields(self, refs: np.ndarray) -> dict:
        # Each node's splat point: its triangle and its centre, worked out once per point (a node
        # list holds each point about twice) and then gathered per node.
        points = self.read_points()
        return {
            "splat_triangle": points["triangle"][refs].astype(np.int32),
            "splat_centre": splat_centres(points, self.gpu_scene.arrays)[refs],
        }


def splat_centres(points: np.ndarray, arrays) -> np.ndarray:
    """The centres (P, 3) float64, in scene space, of `SPLAT_POINT` records, as shaders/include/bundle.glsl
    places them: the triangle's first corner plus its two unorm16 barycentrics along its edges."""
    b = np.stack([points["barycentrics"] & 0xFFFF, points["barycentrics"] >> 16], axis=-1) / 65535.0
    corners = arrays.positions[arrays.faces[points["triangle"]]]  # (P, 3 corners, 3)
    p0, p1, p2 = corners[..., 0, :], corners[..., 1, :], corners[..., 2, :]
    return p0 + b[..., :1] * (p1 - p0) + b[..., 1:] * (p2 - p0)


class ComputeSplatTracer(SplatTracer):
    """The compute splatter: count, exact allocation, scatter."""

    # A point, its copy as a texel, its lines, its place in the count pass's queue and among the
    # splats found again.
    point_bytes = 2 * SPLAT_POINT.itemsize + SPLAT_LINES.itemsize + 2 * 4
    points_are = "splat points, their texels and lines"
    points_defines: ClassVar[dict] = {"QUEUE_SPLATS": True}

    def __init__(self, gl, gpu_scene, settings, **hooks):
        if settings.resolution > SPLAT_LINES_MAX_RESOLUTION:
            raise LimitError(
                f"R={settings.resolution} exceeds the {SPLAT_LINES_MAX_RESOLUTION} the compute splatter's line records "
                "hold; use splatter='raster'",
                ("resolution",),
            )
        super().__init__(gl, gpu_scene, settings, **hooks)
        # The count pass's variant: counting the lines splats cover, too, or not.
        self.count_variant = {"COUNT_SPLATS": True, **({"COUNT_COVERED": True} if self.count_covered else {})}
        self._ensure("SPLAT_LINES", SPLAT_LINES.itemsize * self.K * self.N)
        self._ensure("SPLATS_FOUND_AGAIN", 4 * self.K * self.N)
        self._ensure("SPLAT_QUEUE", 4 * self.K * self.N)
        self._compile()

    def compute_programs(self) -> list:
        gl = self.gl
        return [
            self.points_program(),
            gl.program("splat_lists", **self.count_variant, PLAIN_SPLATS=True),
            gl.program("splat_lists", **self.count_variant),
            gl.program("splat_lists", SCATTER_SPLATS=True),
            gl.program("splat_lists", SCATTER_SPLATS=True, FIND_AGAIN=True),
            *self.sort_programs(**self.merge_defines),
        ]

    merge_defines = {"MERGE_LISTS": True}

    def splat_lists(self, timer) -> tuple[int, int]:
        gl = self.gl
        with timer.measure("lists"):
            # The splats that no line cuts, then the cut ones, as the points pass queued them, each
            # run by a program of its own (shaders/bundles/splat_lists.glsl: PLAIN_SPLATS).
            runs = gl.read(self.buffers["COUNTERS"], np.uint32, 2, first=COUNTERS["PLAIN_SPLATS"])
            plain, cut = int(runs[0]), int(runs[1])
            if plain + cut != self.K * self.N:
                raise RuntimeError(
                    f"the points pass queued {plain} + {cut} splats of {self.K * self.N}: a driver whose subgroup "
                    "ballots (GL_ARB_shader_ballot) miscount; use splatter='raster'"
                )
            for first, splats, run in ((0, plain, {"PLAIN_SPLATS": True}), (plain, cut, {})):
                count = gl.program("splat_lists", **self.count_variant, **run)
                self._uniforms(count, nearest_only=self.merge, queue_first=first)
                gl.dispatch(count, splats)
            raw = self._scan_lists()
            # The splats whose lines were beyond their record's box, which the count pass queued:
            # read while the GPU is idle after the scan's own read, not after the scatter.
            found = int(gl.read(self.buffers["COUNTERS"], np.uint32, 1, first=COUNTERS["FOUND_AGAIN"])[0])
            # Every list's end (its next list's offset) as the scatter's cursor, counting down.
            lists = self.buffers["LIST_COUNTS"]
            gl.copy_buffer(lists, self.buffers["LIST_OFFSETS"], 4 * self.list_count, read_offset=4)
            self.bind()
            scatter = gl.program("splat_lists", SCATTER_SPLATS=True)
            self._uniforms(scatter, nearest_only=self.merge)
            gl.dispatch(scatter, self.K * self.N)
            if found:
                again = gl.program("splat_lists", SCATTER_SPLATS=True, FIND_AGAIN=True)
                self._uniforms(again, nearest_only=self.merge)
                gl.dispatch(again, found)
        return 0, raw

    def covered_nodes(self, counters: np.ndarray, raw: int) -> int | None:
        if counters[COUNTERS["MISMATCH"]]:
            raise RuntimeError(
                f"the splat count and scatter passes found {counters[COUNTERS['MISMATCH']]} lines differently: "
                "a driver that rounds the same arithmetic two ways; use splatter='raster'"
            )
        if not self.merge:
            return raw
        return int(counters[COUNTERS["COVERED"]]) if "COUNT_COVERED" in self.count_variant else None

    def build_stats(self, counters: np.ndarray, raw: int) -> dict:
        found_again = int(counters[COUNTERS["FOUND_AGAIN"]])  # splats whose lines were beyond their record
        return {**super().build_stats(counters, raw), "capacity": raw, "splats_found_again": found_again}


class RasterSplatTracer(LinkedListTracer, SplatTracer):
    """The poster's splats: triangles in each splat's tangent plane with per-corner uvs and a
    circular cut-out, drawn by the rasterizer into linked lists, then merged."""

    raster_program = "imperfect_bundles"

    def __init__(self, gl, gpu_scene, settings, **hooks):
        super().__init__(gl, gpu_scene, settings, **hooks)  # every line a splat covers is a node here
        self._make_lists()
        self._compile()

    def predicted_nodes(self, overlap: float = 1.0) -> int:
        return super().predicted_nodes(max(1.0, self.splat_scale**2))

    def compute_programs(self) -> list:
        return [
            self.points_program(),
            self.gl.program("resolve_lists", COUNT_LISTS=True),
            *self.sort_programs(**self.merge_defines),
        ]

    merge_defines = {"MERGE_LISTS": True, "FROM_LINKED_LISTS": True}

    def vertex_array(self, program):
        return self.gl.vertex_array(program, [])

    def draw(self, vao, base: int, count: int) -> None:
        vertices, first = 3 * self.N * count, 3 * self.N * base
        self.gl.draw(vao, moderngl.TRIANGLES, self.framebuffer, depth_test=False, vertices=vertices, first=first)

    def splat_lists(self, timer) -> tuple[int, int]:
        return self.linked_lists(timer)

    def resolve_lists(self) -> None:
        self.count_lists()
        super().resolve_lists()

    def build_stats(self, counters: np.ndarray, raw: int) -> dict:
        return {**super().build_stats(counters, raw), "capacity": self.capacity}


def tracer(gl, gpu_scene, settings, **hooks) -> SplatTracer:
    """The builder of the chosen splatter."""
    compute = METHOD.settings_of(settings).splatter == "compute"
    return (ComputeSplatTracer if compute else RasterSplatTracer)(gl, gpu_scene, settings, **hooks)


def _time(x: dict) -> list:
    K, R, N, s, F = x["directions"], x["resolution"], x["points"], x["splat_scale"], x["frames"]
    lists = K * R * R * 1e-6
    return [F * K * N * 1e-6, F * lists * s * s]  # t_points: the splat points; t_nodes: the splat nodes


def _error(x: dict) -> list:
    s, N = x["splat_scale"], x["points"]
    c, q = HOLE_SHAPE[x["sampler"]]
    # h: the splat points' holes, with the hole model's shape; g: their overhang, growing with the radius squared.
    return [np.exp(-c * s**q), s * s * 16384.0 / N]


METHOD = BundleMethod(
    name="imperfect",
    summary="point splats in their triangles' tangent planes, a new point set per direction (the poster's method)",
    settings=ImperfectSettings,
    tracer=tracer,
    tune=TuneTerms(
        axes={
            "points": [1024, 2048, 4096, 8192, 16384, 32768, 65536],
            "splat_scale": [1.2, 1.4, 1.6, 1.8, 2.0, 2.2, 2.4, 2.6],
        },
        time_terms=("t_points", "t_nodes"),
        time=_time,
        error_terms=("h", "g"),
        error=_error,
        # (K, R, N, s), spread so that every term of the models changes between runs; the last two run longest.
        calibration=tuple(
            {"directions": k, "resolution": r, "points": n, "splat_scale": s}
            for k, r, n, s in [
                (8, 64, 4096, 1.8),
                (32, 128, 16384, 1.8),
                (32, 64, 16384, 1.4),
                (8, 128, 4096, 2.4),
                (16, 96, 8192, 1.8),
                (32, 128, 4096, 2.2),
                (16, 64, 16384, 2.4),
                (64, 128, 16384, 1.6),
                (8, 96, 65536, 2.2),
                (16, 64, 32768, 1.6),
                (8, 192, 32768, 2.0),
                (16, 128, 65536, 1.8),
                (32, 64, 8192, 2.0),
            ]
        ),
    ),
)
