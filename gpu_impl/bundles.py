"""Perfect and imperfect ray bundles on the GPU, read back as a `BundleSet`.

A node is 8 bytes on the GPU: its depth along the bundle direction and a reference, the triangle
(perfect bundles) or the splat point (imperfect bundles); shaders/bundle_hits.glsl computes the
rest where it is needed. One build is a few passes and two GPU-CPU round-trips, whatever K is:

- **perfect**: ``lists``: one instanced draw per atlas of R x R tiles appends every node to its
  pixel's linked list (shaders/perfect_bundles.glsl); round-trip 1 reads the node counter, and past
  the buffer's capacity the pass runs again with a buffer that fits. ``resolve``: list lengths, a
  prefix sum into exact-size slot ranges, and each list sorted into its range
  (shaders/resolve_lists.glsl); round-trip 2 reads the statistics.
- **imperfect**, compute splatter (the default): ``points``: N points per direction
  (shaders/splat_points.glsl). ``lists``: every splat counts the lines it covers, a prefix sum makes
  exact-size slot ranges, round-trip 1 reads their total, and every splat writes its nodes
  (shaders/splat_lists.glsl): no linked list, no re-run. ``resolve``: each list sorted and its
  redundant nodes merged in place, at the front of its range; round-trip 2 reads the statistics.
- **imperfect**, raster splatter (``splatter="raster"``): the poster's splats drawn by the
  rasterizer into linked lists (shaders/imperfect_bundles.glsl), then list lengths, a prefix sum
  and the same merge.

The resolved lists (``LIST_OFFSETS``, ``LIST_COUNTS``, ``NODES``) stay on the GPU for the renderer.
"""

from __future__ import annotations

import math
import time

import moderngl
import numpy as np

from evalkit.core.bundleset import SPLAT_PRIM_ID, BundleSet, DirectionSet, bundle_params
from evalkit.core.errors import InputError
from gpu_impl.context import LOCAL_SIZE, GLContext, PassTimer, set_uniforms
from gpu_impl.layout import BINDINGS, BUNDLE_FRAME, COUNTERS, FACING_BIT, METHODS, SAMPLERS, SPLAT_BIT, SPLAT_POINT
from gpu_impl.scene_buffers import GpuScene

SPLATTERS = ("compute", "raster")
# Bytes per node: one 64-bit key, depth and reference (shaders/bundle_build.glsl), a slot of a
# list's range; while linked lists are built, depth, reference and link.
NODE_BYTES = 8
LINKED_NODE_BYTES = 12
# The compute splatter's record of the lines a splat covers, from its count pass to its scatter.
SPLAT_LINES_BYTES = 16
# The poster used a 1 GB node buffer; the default leaves room for the largest settings it used.
DEFAULT_NODE_BUDGET = 2 << 30
# Splat radius in units of sqrt(A / (pi N)), the radius at which N disks cover area A once. With
# independent uniform points a surface point is missed by all of them with probability
# exp(-splat_scale^2); the stratified points leave far fewer holes, exp(-1.25 s^2.4) on cornell-box.
# 1.8 is the hole model's recommendation for stratified points (studies/hole_vs_splat.toml: 1.81
# on cornell-box, 1.94 on atrium whose curved-surface floor of holes no splat size removes), at
# 3.2 nodes per crossing against 4 for the old default 2 (docs/MEASURED_FACTS.md).
DEFAULT_SPLAT_SCALE = 1.8
DEFAULT_SAMPLER = "stratified"
# Nodes of one line closer than this (times the frame radius) are one surface: the depth tolerance
# of the bundle metrics (evalkit/metrics/bundles.py), about a hundred float32 ulps of a depth.
MERGE_TOLERANCE = 1e-4
# How much a buffer grows past a measured count, so the next frame's rotated directions (a
# slightly different count) rarely need it to grow again.
CAPACITY_SLACK = 1.125
SCAN_BLOCK = 16 * LOCAL_SIZE  # shaders/prefix_sum.glsl
# shaders/resolve_lists.glsl reads a short list's slots up to its sorting network's size (32), past
# the list's end: the node buffer keeps that many slots beyond the last list.
SLACK_NODES = 32


class NodeBudgetExceeded(InputError):
    """The bundles need more node memory than the budget allows."""


class BundleTracer:
    """Builds perfect or imperfect bundles of one uploaded scene (`GpuScene`, which its maker owns)
    with one GL context.

    Buffers are kept and grown across `build` calls (frames), so a frame costs only its passes;
    `release` (or leaving a ``with`` block) frees every GL object the tracer made.

    Parameters: ``directions`` K and ``resolution`` R fix the list layout. Imperfect bundles use
    ``points`` N per direction from ``sampler`` ('stratified' or 'random', shaders/splat_points.glsl),
    of radius ``splat_radius`` (scene units) or, by default, ``splat_scale * sqrt(A / (pi N))``,
    found by ``splatter`` ('compute' or 'raster'); ``merge`` (default on) merges the redundant nodes
    of one surface (shaders/resolve_lists.glsl). ``node_budget`` (bytes) caps everything the
    tracer holds for nodes: the CSR, the lists and points it is built from; a build that needs more
    raises `NodeBudgetExceeded` with the amount needed. ``count_covered`` also counts the lines the
    compute splatter's splats cover before merging (stats ``covered_nodes``; studies of the splat
    size ask for it, at some cost). ``initial_capacity`` (nodes) overrides the
    first guess of the linked lists' size (tests use it to force a re-run); ``max_atlas_size``
    caps the atlas side in pixels (default: the GL viewport limit); past it, directions are drawn
    in several draws.
    """

    def __init__(
        self,
        gl: GLContext,
        gpu_scene: GpuScene,
        method: str = "perfect",
        *,
        directions: int = 256,
        resolution: int = 128,
        points: int = 16384,
        splat_scale: float = DEFAULT_SPLAT_SCALE,
        splat_radius: float | None = None,
        sampler: str = DEFAULT_SAMPLER,
        splatter: str = "compute",
        merge: bool = True,
        node_budget: int = DEFAULT_NODE_BUDGET,
        initial_capacity: int | None = None,
        max_atlas_size: int | None = None,
        textures: bool | None = None,
        count_covered: bool = False,
    ):
        if method not in METHODS:
            raise ValueError(f"method must be one of {tuple(METHODS)}, got {method!r}")
        if sampler not in SAMPLERS or splatter not in SPLATTERS:
            raise ValueError(
                f"sampler must be one of {tuple(SAMPLERS)} and splatter one of {SPLATTERS}, got {sampler!r}, {splatter!r}"
            )
        for name, value in (("directions", directions), ("resolution", resolution), ("points", points)):
            if value < 1:
                raise ValueError(f"{name} must be at least 1, got {value}")
        self.gl = gl
        self.gpu_scene = gpu_scene
        self.method = method
        self.K, self.R, self.N = directions, resolution, points
        self.sampler, self.splatter, self.merge = sampler, splatter, bool(merge) and method == "imperfect"
        # The count pass's variant: counting the lines splats cover, too, or not.
        self.count_variant = {"COUNT_SPLATS": True, **({"COUNT_COVERED": True} if count_covered else {})}
        # The radius at which N disks cover the scene's area once: the unit of splat_scale.
        unit = math.sqrt(gpu_scene.arrays.tri_area.sum() / (math.pi * points))
        self.splat_radius = splat_radius if splat_radius is not None else splat_scale * unit
        self.splat_scale = self.splat_radius / unit
        if not (self.splat_radius > 0 and math.isfinite(self.splat_radius)):
            raise ValueError(f"the splat radius must be positive and finite, got {self.splat_radius}")
        self.node_budget = int(node_budget)
        self.list_count = self.K * self.R * self.R
        if self.list_count >= 2**32 - 1 or (method == "imperfect" and 3 * self.K * self.N >= 2**31):
            raise ValueError(f"K={self.K}, R={self.R}, N={self.N} exceed the 32-bit list and point indices")
        self.linked = method == "perfect" or splatter == "raster"
        self.capacity = 0  # nodes the linked lists hold (their buffers are made below)
        self._layout(max_atlas_size)
        # 0: the shader variant without texture fetches, for scenes without textures (None: ask the scene).
        self.textures = int(gpu_scene.features.textures if textures is None else textures)
        self.defines = {"BUNDLE_METHOD": METHODS[method]}
        self.buffers: dict = {}
        self._scan_sums: list = []
        self.framebuffer = gl.empty_framebuffer(self.atlas_size) if self.linked else None
        self.vertex_arrays: dict = {}  # by NULL_FRAGMENT: the node pass's and the raw-raster baseline's
        lists = 4 * (self.list_count + 1)
        self._ensure("FRAMES", BUNDLE_FRAME.itemsize * self.K)
        self._ensure("COUNTERS", 4 * len(COUNTERS))
        self._ensure("LIST_OFFSETS", lists)
        self._ensure("LIST_COUNTS", lists)
        if method == "imperfect":
            self._check_budget(
                self.fixed_bytes,
                what=f"{self.K * self.N:,} splat points{'' if self.linked else ', their lines'} and the list offsets",
            )
            self._ensure("POINTS", SPLAT_POINT.itemsize * self.K * self.N).clear()  # triangle 0 for a warm-up draw
        if method == "imperfect" and not self.linked:
            self._ensure("SPLAT_LINES", SPLAT_LINES_BYTES * self.K * self.N)
        if self.linked:
            self._ensure("HEADS", 4 * self.list_count)
            self._grow_linked(initial_capacity if initial_capacity is not None else self.predicted_nodes())
            self._raster(null_fragment=False)
        # Compile every compute pass now, not inside the first timed build: a dispatch over no
        # items makes the driver build its code (llvmpipe does that at the first dispatch).
        self.bind()
        for program in self._compute_programs():
            self._uniforms(program)
            gl.dispatch(program, 0)
        self.directions: DirectionSet | None = None
        self.stats: dict = {}

    def _compute_programs(self) -> list:
        """The compute passes a build of this tracer runs (the prefix sum aside)."""
        gl = self.gl
        if self.method == "perfect":
            return [gl.program("resolve_lists", COUNT_LISTS=True), gl.program("resolve_lists", SORT_LISTS=True)]
        passes = [gl.program("splat_points", SAMPLER=SAMPLERS[self.sampler])]
        if self.linked:
            return passes + [
                gl.program("resolve_lists", COUNT_LISTS=True),
                gl.program("resolve_lists", MERGE_LISTS=True, FROM_LINKED_LISTS=True),
            ]
        return passes + [
            gl.program("splat_lists", **self.count_variant),
            gl.program("splat_lists", SCATTER_SPLATS=True),
            gl.program("resolve_lists", MERGE_LISTS=True),
        ]

    # -- layout and memory ---------------------------------------------------------------

    def _layout(self, max_atlas_size: int | None) -> None:
        """The atlas: as square as possible, split into several draws only past the GL limit."""
        max_dim = min(self.gl.limit("GL_MAX_VIEWPORT_DIMS"))
        max_dim = min(max_dim, max_atlas_size or max_dim)
        tiles = max_dim // self.R
        if tiles < 1:
            raise ValueError(f"bundle resolution {self.R} exceeds the GL viewport limit {max_dim}")
        self.tiles_per_row = min(math.ceil(math.sqrt(self.K)), tiles)
        rows = min(math.ceil(self.K / self.tiles_per_row), tiles)
        self.directions_per_draw = self.tiles_per_row * rows
        self.atlas_size = (self.tiles_per_row * self.R, rows * self.R)

    def predicted_nodes(self) -> int:
        """A first guess of the linked lists' size, from the scene's depth complexity (the mean
        number of surfaces a line through the bounding sphere crosses) and, for splats, the mean
        number of splats covering a surface point."""
        lines = self.list_count * math.pi / 4  # the lines that meet the sphere
        overlap = max(1.0, self.splat_scale**2) if self.method == "imperfect" else 1.0
        return int(lines * self.gpu_scene.features.depth_complexity * overlap * 1.25) + 1024

    @property
    def fixed_bytes(self) -> int:
        """What the tracer holds whatever the node count: frames, the per-list arrays, the points
        and (compute splatter) their lines."""
        per_list = 4 * (self.list_count + 1) * 2 + (4 * self.list_count if self.linked else 0)
        per_point = SPLAT_POINT.itemsize + (0 if self.linked else SPLAT_LINES_BYTES)
        points = per_point * self.K * self.N if self.method == "imperfect" else 0
        return BUNDLE_FRAME.itemsize * self.K + per_list + points

    @property
    def memory_bytes(self) -> int:
        """Everything the tracer holds for nodes now, which the node budget caps."""
        return sum(b.size for name, b in self.buffers.items() if name != "COUNTERS") + sum(
            b.size for b in self._scan_sums
        )

    def _ensure(self, name: str, nbytes: int):
        """Buffer ``name`` with room for at least ``nbytes`` (its contents are not kept when it grows)."""
        buffer = self.buffers.get(name)
        if buffer is None or buffer.size < nbytes:
            if buffer is not None:
                buffer.release()
            buffer = self.buffers[name] = self.gl.buffer(reserve=max(4, int(nbytes)))
        return buffer

    def _check_budget(self, needed: int, what: str) -> None:
        if needed > self.node_budget:
            raise NodeBudgetExceeded(
                self.gpu_scene.scene.name,
                f"{self.method} bundles (K={self.K}, R={self.R}{f', N={self.N}' if self.method == 'imperfect' else ''}) "
                f"need {format_bytes(needed)} for {what}, over the node budget of {format_bytes(self.node_budget)}; "
                f"raise --node-budget to at least {format_bytes(needed)} or lower K, R, N or the splat size",
            )

    def _grow(self, names: tuple[str, ...], node_bytes: int, nodes: int, what: str) -> None:
        """Grow the per-node buffers ``names`` to ``nodes`` nodes (plus slack while the budget
        allows), or raise `NodeBudgetExceeded` with the memory all of it needs."""
        current = sum(self.buffers[n].size for n in names if n in self.buffers)
        if current >= node_bytes * nodes:
            return
        others = self.memory_bytes - current
        self._check_budget(others + node_bytes * nodes, f"{nodes:,} {what} and what else the build holds")
        slack = min(int(nodes * CAPACITY_SLACK), (self.node_budget - others) // node_bytes)
        for name in names:
            self._ensure(name, node_bytes // len(names) * slack)

    def _grow_linked(self, nodes: int) -> None:
        """Linked-list buffers for ``nodes`` nodes (a guess, or a measured count)."""
        nodes = max(1, nodes)
        budget_nodes = max(1, (self.node_budget - self.fixed_bytes) // LINKED_NODE_BYTES)
        self.capacity = min(nodes, budget_nodes, self.gl.max_storage_bytes // 4)
        for name in ("NEXT", "LIST_DEPTH", "LIST_REF"):
            if name in self.buffers and self.buffers[name].size != 4 * self.capacity:
                self.buffers.pop(name).release()
            self._ensure(name, 4 * self.capacity)

    # -- the passes ----------------------------------------------------------------------

    def bind(self) -> None:
        self.gpu_scene.bind()
        for name, buffer in self.buffers.items():
            buffer.bind_to_storage_buffer(BINDINGS[name])

    def build(self, directions: DirectionSet) -> dict:
        """Build the bundles of one frame's `DirectionSet` on the GPU; returns the statistics."""
        if directions.count != self.K:
            raise ValueError(f"this tracer was made for {self.K} directions, got {directions.count}")
        start = time.perf_counter()
        timer = PassTimer(self.gl)
        self.buffers["FRAMES"].write(_frames(directions).tobytes())
        self.buffers["COUNTERS"].clear()
        if self.method == "imperfect":
            self.buffers["LIST_COUNTS"].clear()
        self.bind()
        if self.method == "imperfect":
            with timer.measure("points"):
                self._sample_points(directions)
        if self.linked:
            reruns, raw = self._linked_lists(timer)
        else:
            with timer.measure("lists"):
                reruns, raw = 0, self._splat_lists()
        with timer.measure("resolve"):
            self._resolve()
        counters = np.frombuffer(self.buffers["COUNTERS"].read(4 * len(COUNTERS)), dtype=np.uint32)
        nodes = int(counters[COUNTERS["KEPT"]]) if self.method == "imperfect" else raw
        if counters[COUNTERS["MISMATCH"]]:
            raise RuntimeError(
                f"the splat count and scatter passes found {counters[COUNTERS['MISMATCH']]} lines differently: "
                "a driver that rounds the same arithmetic two ways; use splatter='raster'"
            )
        self.directions = directions
        self.stats = {
            "nodes": nodes,
            "raw_nodes": raw,
            # Every line a splat or a triangle covers: without merging, one node each (None: not counted).
            "covered_nodes": raw
            if self.linked or not self.merge
            else int(counters[COUNTERS["COVERED"]])
            if "COUNT_COVERED" in self.count_variant
            else None,
            "redundant_nodes": raw - nodes if self.method == "imperfect" else int(counters[COUNTERS["REDUNDANT"]]),
            "redundant_tolerance": self.merge_tolerance if self.merge else 0.0,
            "merged": self.merge,
            "max_list_length": int(counters[COUNTERS["MAX_LENGTH"]]),
            "capacity": self.capacity if self.linked else raw,
            "overflow_reruns": reruns,
            "node_bytes": nodes * NODE_BYTES,
            "memory_bytes": self.memory_bytes,
            "gpu_bytes": self.gpu_bytes,
            "gpu_ms": timer.milliseconds(),
            "gpu_timing": timer.method,
            "wall_ms": (time.perf_counter() - start) * 1e3,
        }
        if self.method == "imperfect":
            self.stats.update(sampler=self.sampler, splatter=self.splatter)
        return self.stats

    @property
    def merge_tolerance(self) -> float:
        """How far apart in depth two nodes of one line may be and still be merged as one surface
        (shaders/resolve_lists.glsl): the depth tolerance under which the bundle metrics call two
        nodes one surface (`MERGE_TOLERANCE` of the frame radius), so merging removes what they
        count redundant; negative (nothing merges) without merging. Splats of one plane cross a
        line at one depth; a wider tolerance (a splat radius) also merged a corner's two walls
        where one's splats overhang the other, trading holes for fewer nodes: measured on
        cornell-box (K=32, N=16384, s=1.5), 4.6 % holes against 3.6 %."""
        return MERGE_TOLERANCE * self.gpu_scene.radius if self.merge else -1.0

    @property
    def gpu_bytes(self) -> int:
        """Every buffer this tracer holds plus the scene's."""
        return sum(b.size for b in self.buffers.values()) + sum(b.size for b in self._scan_sums) + self.gpu_scene.nbytes

    def _uniforms(self, program, **overrides) -> None:
        """Set the bundle programs' uniforms (those a variant compiled away are skipped)."""
        values = {
            "radius": self.gpu_scene.radius,
            "resolution": self.R,
            "tiles_per_row": self.tiles_per_row,
            "atlas_size": self.atlas_size,
            "capacity": self.capacity,
            "points_per_direction": self.N,
            "splat_radius": self.splat_radius,
            "direction_base": 0,
            **overrides,
        }
        set_uniforms(program, values)

    def _sample_points(self, directions: DirectionSet) -> None:
        shader = self.gl.program("splat_points", SAMPLER=SAMPLERS[self.sampler])
        self._uniforms(
            shader,
            triangle_count=self.gpu_scene.triangle_count,
            seed=directions.seed & 0xFFFFFFFF,
            frame=directions.frame & 0xFFFFFFFF,
        )
        self.gl.dispatch(shader, self.K * self.N)

    def _raster(self, null_fragment: bool) -> tuple:
        """The raster program of the linked-list pass (or of the raw-raster baseline: an empty
        fragment shader) and its vertex array, made on first use. The first use also draws one
        triangle with nothing to write to, so the driver compiles the shader variant here and not
        inside the first timed pass (llvmpipe's first timer query around a compiling draw reports an
        invalid 2^32 - 1 ns)."""
        variant = {"NULL_FRAGMENT": True} if null_fragment else {}
        program = self.gl.program(f"{self.method}_bundles", **variant)
        if null_fragment not in self.vertex_arrays:
            vao = (
                self.gpu_scene.vertex_array(program) if self.method == "perfect" else self.gl.vertex_array(program, [])
            )
            self.vertex_arrays[null_fragment] = vao
            self.bind()
            self._uniforms(program, capacity=0)
            self.gl.draw(vao, moderngl.TRIANGLES, self._atlas_framebuffer(), depth_test=False, vertices=3, instances=1)
            self.gl.finish()
        return program, self.vertex_arrays[null_fragment]

    def _atlas_framebuffer(self):
        if self.framebuffer is None:  # the compute splatter's raw-raster baseline
            self.framebuffer = self.gl.empty_framebuffer(self.atlas_size)
        return self.framebuffer

    def _draw_lists(self, null_fragment: bool) -> None:
        """Every direction's nodes, appended to the pixel lists: one draw per atlas."""
        program, vao = self._raster(null_fragment)
        self.buffers["HEADS"].clear(chunk=b"\xff\xff\xff\xff")
        for base in range(0, self.K, self.directions_per_draw):
            count = min(self.directions_per_draw, self.K - base)
            self._uniforms(program, direction_base=base)
            if self.method == "perfect":
                self.gl.draw(vao, moderngl.TRIANGLES, self._atlas_framebuffer(), depth_test=False, instances=count)
            else:
                self.gl.draw(
                    vao,
                    moderngl.TRIANGLES,
                    self._atlas_framebuffer(),
                    depth_test=False,
                    vertices=3 * self.N * count,
                    first=3 * self.N * base,
                )

    def _linked_lists(self, timer: PassTimer) -> tuple[int, int]:
        """The raster pass into linked lists, run again with buffers that fit until every node has
        a slot. Returns the re-runs and the node count."""
        # Size the buffers from the last frame's count: a first guess far too large (a scene of
        # thin walls has less depth complexity than its bounds suggest) is given back.
        last = self.stats.get("raw_nodes")
        if last is not None and self.capacity > 2 * CAPACITY_SLACK * last:
            self._grow_linked(int(last * CAPACITY_SLACK) + 1)
            self.bind()
        reruns = 0
        while True:
            self.buffers["COUNTERS"].clear()
            with timer.measure("lists"):
                self._draw_lists(null_fragment=False)
            nodes = int(np.frombuffer(self.buffers["COUNTERS"].read(4), dtype=np.uint32)[0])
            if nodes <= self.capacity:
                return reruns, nodes
            self._check_budget(self.fixed_bytes + nodes * LINKED_NODE_BYTES, f"{nodes:,} nodes in linked lists")
            self._grow_linked(max(nodes, int(nodes * CAPACITY_SLACK)))
            self.bind()
            reruns += 1

    def _splat_lists(self) -> int:
        """The compute splatter: count, exact allocation, scatter. Returns the raw node count."""
        gl = self.gl
        count = gl.program("splat_lists", **self.count_variant)
        self._uniforms(count, nearest_only=self.merge)
        gl.dispatch(count, self.K * self.N)
        raw = self._scan_lists()
        # Every list's end (its next list's offset) as the scatter's cursor, counting down.
        self.gl.copy_buffer(
            self.buffers["LIST_COUNTS"], self.buffers["LIST_OFFSETS"], 4 * self.list_count, read_offset=4
        )
        self.bind()
        scatter = gl.program("splat_lists", SCATTER_SPLATS=True)
        self._uniforms(scatter, nearest_only=self.merge)
        gl.dispatch(scatter, self.K * self.N)
        return raw

    def _scan_lists(self) -> int:
        """The lists' slot ranges: LIST_OFFSETS, the exclusive prefix sum of the per-list counts
        in LIST_COUNTS (L + 1 entries), and the node buffer grown to fit. Returns the total (one
        round-trip)."""
        offsets = self.buffers["LIST_OFFSETS"]
        self.gl.copy_buffer(offsets, self.buffers["LIST_COUNTS"], 4 * (self.list_count + 1))
        self._prefix_sum(offsets, self.list_count + 1, level=0)
        total = int(np.frombuffer(offsets.read(4, offset=4 * self.list_count), dtype=np.uint32)[0])
        what = "nodes" if self.method == "perfect" else "splat nodes before merging"
        self._grow(("NODES",), NODE_BYTES, total + SLACK_NODES, what)
        self.bind()
        return total

    def _resolve(self) -> None:
        """The build's lists sorted (and merged) into their slot ranges (shaders/resolve_lists.glsl)."""
        gl = self.gl
        if self.linked:  # list lengths, into the slot ranges the lists sort (perfect) or merge (raster splats) into
            gl.dispatch(gl.program("resolve_lists", COUNT_LISTS=True), self.list_count)
            self._scan_lists()
        if self.method == "perfect":
            gl.dispatch(gl.program("resolve_lists", SORT_LISTS=True), self.list_count)
            return
        merge = gl.program("resolve_lists", MERGE_LISTS=True, **({"FROM_LINKED_LISTS": True} if self.linked else {}))
        merge["merge_tolerance"] = self.merge_tolerance
        gl.dispatch(merge, self.list_count)

    def _prefix_sum(self, values, count: int, level: int) -> None:
        """Exclusive prefix sum of ``count`` uints of ``values`` in place (shaders/prefix_sum.glsl)."""
        gl = self.gl
        blocks = math.ceil(count / SCAN_BLOCK)
        if len(self._scan_sums) <= level:
            self._scan_sums.append(gl.buffer(reserve=4 * max(blocks, 1)))
        elif self._scan_sums[level].size < 4 * blocks:
            self._scan_sums[level].release()
            self._scan_sums[level] = gl.buffer(reserve=4 * blocks)
        sums = self._scan_sums[level]
        values.bind_to_storage_buffer(BINDINGS["SCAN_DATA"])
        sums.bind_to_storage_buffer(BINDINGS["SCAN_SUMS"])
        scan = gl.program("prefix_sum", SCAN_BLOCKS=True)
        scan["count"] = count
        gl.run_groups(scan, blocks)
        if blocks > 1:
            self._prefix_sum(sums, blocks, level + 1)
            values.bind_to_storage_buffer(BINDINGS["SCAN_DATA"])
            sums.bind_to_storage_buffer(BINDINGS["SCAN_SUMS"])
            add = gl.program("prefix_sum", ADD_BLOCK_OFFSETS=True)
            add["count"] = count
            gl.dispatch(add, count)

    def raw_raster(self, directions: DirectionSet) -> float:
        """The raw-raster baseline: this build's raster geometry (triangles, or the last build's
        splats) drawn with an empty fragment shader. Returns its GPU time in ms
        (benchmarks/bundles.py)."""
        self.buffers["FRAMES"].write(_frames(directions).tobytes())
        self._ensure("HEADS", 4 * self.list_count)
        self.bind()
        timer = PassTimer(self.gl)
        with timer.measure("raw"):
            self._draw_lists(null_fragment=True)
        return timer.milliseconds()["raw"]

    # -- readback ------------------------------------------------------------------------

    def node_refs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The last build's lists as a CSR: offsets (L + 1,) int64, depth (M,) float32 and
        reference (M,) uint32 (a triangle, or a splat point), and each node's slot (M,) int64 in
        the GPU's node buffer (where the resolve left it)."""
        if self.directions is None:
            raise RuntimeError("node_refs() before build()")
        b, L = self.buffers, self.list_count
        first = np.frombuffer(b["LIST_OFFSETS"].read(4 * L), dtype=np.uint32).astype(np.int64)
        counts = np.frombuffer(b["LIST_COUNTS"].read(4 * L), dtype=np.uint32).astype(np.int64)
        offsets = np.concatenate([[0], np.cumsum(counts)])
        slots = np.repeat(first - offsets[:-1], counts) + np.arange(offsets[-1])
        keys = np.frombuffer(b["NODES"].read(8 * (int(first[-1] + counts[-1]) if L else 0)), dtype=np.uint32).reshape(
            -1, 2
        )[slots]
        return offsets, order_bits_depth(keys[:, 1]), keys[:, 0] & ~FACING_BIT, slots

    def read_points(self) -> np.ndarray:
        """The last build's splat points (K N,) as `SPLAT_POINT` records."""
        return np.frombuffer(
            self.buffers["POINTS"].read(SPLAT_POINT.itemsize * self.K * self.N), dtype=SPLAT_POINT
        ).copy()

    def read(self) -> BundleSet:
        """The last build as a `BundleSet` (host memory): the nodes with the attributes an eye path
        sees at them (shaders/expand_nodes.glsl)."""
        offsets, depth, _, slots = self.node_refs()
        used = int(slots[-1]) + 1 if len(slots) else 0
        attributes = self.gl.buffer(reserve=16 * max(used, 1))
        try:
            attributes.bind_to_storage_buffer(BINDINGS["NODE_ATTRIBUTES"])
            self.bind()
            expand = self.gl.program("expand_nodes", TEXTURES=self.textures, **self.defines)
            self._uniforms(expand)
            self.gl.dispatch(expand, self.list_count)
            words = np.frombuffer(attributes.read(16 * used), dtype=np.uint32).reshape(used, 4)[slots]
        finally:
            attributes.release()
        prim = words[:, 3]
        triangle = (prim & ~np.uint32(SPLAT_BIT)).astype(np.int64)
        arrays, materials = self.gpu_scene.arrays, self.gpu_scene.scene.materials
        material = arrays.tri_material[triangle].astype(np.int32)
        emission = np.array([m.emission for m in materials], dtype=np.float32).reshape(-1, 3)[material]
        albedo = np.ascontiguousarray(words[:, 1:3]).view(np.float16)[:, :3].astype(np.float32)
        ds = self.directions
        params = {
            **bundle_params(self.gpu_scene.scene, self.method, ds, self.R),
            "node_budget": self.node_budget,
            "gl": self.gl.info,
        }
        if self.method == "imperfect":
            params.update(
                points=self.N,
                splat_scale=self.splat_scale,
                splat_radius=self.splat_radius,
                sampler=self.sampler,
                splatter=self.splatter,
                merged=self.merge,
            )
        return BundleSet(
            method=self.method,
            directions=ds,
            centre=self.gpu_scene.centre.copy(),
            radius=self.gpu_scene.radius,
            resolution=self.R,
            offsets=offsets,
            depth=depth,
            normal=decode_normals(words[:, 0]),
            albedo=albedo,
            emission=emission,
            prim_id=np.where(prim & SPLAT_BIT, SPLAT_PRIM_ID, triangle).astype(np.int32),
            material=material,
            params=params,
            stats=dict(self.stats),
        )

    def release(self) -> None:
        """Free every GL object this tracer made (not the scene upload: its maker owns that)."""
        objects = [*self.buffers.values(), *self._scan_sums, *self.vertex_arrays.values()]
        for obj in objects + ([self.framebuffer] if self.framebuffer is not None else []):
            obj.release()
        self.buffers.clear()
        self._scan_sums.clear()
        self.vertex_arrays.clear()
        self.framebuffer = None

    def __enter__(self) -> "BundleTracer":
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def trace_bundles(gl: GLContext, scene, directions: DirectionSet, method: str = "perfect", **tracer_args) -> BundleSet:
    """The bundles of one `DirectionSet`, made once: ``scene`` (a `Scene`) uploaded, its bundles
    built and read back, and every GL object released. ``tracer_args`` go to `BundleTracer`; the
    build's statistics are in the result's ``stats``."""
    with (
        GpuScene(gl, scene) as gpu_scene,
        BundleTracer(gl, gpu_scene, method, directions=directions.count, **tracer_args) as tracer,
    ):
        tracer.build(directions)
        return tracer.read()


def _frames(directions: DirectionSet) -> np.ndarray:
    """The per-direction frames as shaders/bundle.glsl's BundleFrame array (K,)."""
    frames = np.zeros(directions.count, dtype=BUNDLE_FRAME)
    frames["u"][:, :3], frames["u"][:, 3] = directions.axis_u, directions.jitter[:, 0]
    frames["v"][:, :3], frames["v"][:, 3] = directions.axis_v, directions.jitter[:, 1]
    frames["d"][:, :3] = directions.directions
    return frames


def order_bits_depth(bits: np.ndarray) -> np.ndarray:
    """Depths from their order bits, a node key's high word (shaders/common.glsl)."""
    sign = np.uint32(0x80000000)
    return np.where(bits & sign, bits ^ sign, ~bits).astype(np.uint32).view(np.float32)


def decode_normals(packed: np.ndarray) -> np.ndarray:
    """Octahedral snorm16x2 normals (shaders/common.glsl: encode_normal) to unit (M, 3) float32."""
    e = np.clip(packed.astype(np.uint32).view(np.int16).reshape(-1, 2).astype(np.float64) / 32767.0, -1.0, 1.0)
    n = np.stack([e[:, 0], e[:, 1], 1.0 - np.abs(e[:, 0]) - np.abs(e[:, 1])], axis=1)
    back = n[:, 2] < 0
    sign = np.where(e[back] >= 0.0, 1.0, -1.0)
    n[back, :2] = (1.0 - np.abs(e[back][:, ::-1])) * sign
    return (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(np.float32)


def format_bytes(n: int) -> str:
    for unit, size in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.2f} {unit}"
    return f"{n} B"
