"""Perfect and imperfect ray bundles on the GPU, read back as a `BundleSet`.

One build is a handful of passes and two GPU-CPU round-trips, whatever K is:

1. ``points`` (imperfect only): N surface points per direction (shaders/splat_points.glsl);
2. ``lists``: one instanced draw per atlas of R x R tiles appends every node to its pixel's
   linked list (shaders/perfect_bundles.glsl or imperfect_bundles.glsl);
   round-trip 1 reads the node counter: past the buffer's capacity, the pass is re-run with a
   buffer that fits (or `NodeBudgetExceeded` says how much was needed);
3. ``resolve``: list lengths, a GPU prefix sum, and a sort of each list into CSR order
   (shaders/resolve_lists.glsl, prefix_sum.glsl); round-trip 2 reads the statistics.

The sorted CSR (``OFFSETS``, ``SORTED_NODE``, ``SORTED_DEPTH``) stays on the GPU for the renderer,
which keeps each node's direct radiance in an array parallel to ``SORTED_NODE`` (CSR order).
"""

from __future__ import annotations

import math
import time

import moderngl
import numpy as np

from evalkit.core.bundleset import SPLAT_PRIM_ID, BundleSet, DirectionSet, bundle_params
from evalkit.core.errors import InputError
from gpu_impl.context import LOCAL_SIZE, GLContext, PassTimer, set_uniforms
from gpu_impl.layout import BINDINGS, BUNDLE_FRAME, COUNTERS, SPLAT_BIT
from gpu_impl.scene_buffers import GpuScene

METHODS = ("perfect", "imperfect")
# Bytes per node: depth, prim, normal (4 each), albedo (8) and link (4) while lists are built,
# then the sorted node index and depth (4 each).
LIST_NODE_BYTES = 24
SORTED_NODE_BYTES = 8
NODE_BYTES = LIST_NODE_BYTES + SORTED_NODE_BYTES
# The poster used a 1 GB node buffer. Our nodes take NODE_BYTES = 32 bytes, and imperfect atrium
# bundles at the default splat scale need 34.5 M of them (1.1 GB), so the default is 2 GiB.
DEFAULT_NODE_BUDGET = 2 << 30
# Splat radius in units of sqrt(A / (pi N)), the radius at which N disks cover area A once. With
# independent uniform points a surface point is missed by all of them with probability
# exp(-splat_scale^2) (docs/MEASURED_FACTS.md); the stratified points leave fewer holes than that.
DEFAULT_SPLAT_SCALE = 2.0
# How much the node buffer grows past a measured count, so the next frame's rotated directions
# (a slightly different count) rarely need a re-run.
CAPACITY_SLACK = 1.125
SCAN_BLOCK = 4 * LOCAL_SIZE  # shaders/prefix_sum.glsl


class NodeBudgetExceeded(InputError):
    """The bundles need more node memory than the budget allows."""


class BundleTracer:
    """Builds perfect or imperfect bundles of one uploaded scene (`GpuScene`, which its maker owns)
    with one GL context.

    Buffers are kept and grown across `build` calls (frames), so a frame costs only its passes;
    `release` (or leaving a ``with`` block) frees every GL object the tracer made. ``node_budget`` (bytes) caps the node memory (`NODE_BYTES` per
    node); a build that needs more raises `NodeBudgetExceeded` with the amount needed.

    Parameters: ``directions`` K and ``resolution`` R fix the buffer layout. Imperfect bundles use
    ``points`` N per direction, of radius ``splat_radius`` (scene units) or, by default,
    ``splat_scale * sqrt(A / (pi N))``. ``initial_capacity`` (nodes) overrides the first guess
    of the node count (tests use it to force an overflow). ``max_atlas_size`` caps the atlas side
    in pixels (default: the GL viewport limit); past it, directions are drawn in several draws.
    """

    def __init__(self, gl: GLContext, gpu_scene: GpuScene, method: str = "perfect", *, directions: int = 256,
                 resolution: int = 128, points: int = 16384, splat_scale: float = DEFAULT_SPLAT_SCALE,
                 splat_radius: float | None = None, node_budget: int = DEFAULT_NODE_BUDGET,
                 initial_capacity: int | None = None, max_atlas_size: int | None = None, textures: bool | None = None):
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        for name, value in (("directions", directions), ("resolution", resolution), ("points", points)):
            if value < 1:
                raise ValueError(f"{name} must be at least 1, got {value}")
        self.gl = gl
        self.gpu_scene = gpu_scene
        self.method = method
        self.K, self.R, self.N = directions, resolution, points
        # The radius at which N disks cover the scene's area once: the unit of splat_scale.
        unit = math.sqrt(gpu_scene.arrays.tri_area.sum() / (math.pi * points))
        self.splat_radius = splat_radius if splat_radius is not None else splat_scale * unit
        self.splat_scale = self.splat_radius / unit
        if not (self.splat_radius > 0 and math.isfinite(self.splat_radius)):
            raise ValueError(f"the splat radius must be positive and finite, got {self.splat_radius}")
        self.node_budget = int(node_budget)
        self.list_count = self.K * self.R * self.R
        if self.list_count >= 2**32 - 1 or (method == "imperfect" and 3 * self.K * self.N >= 2**31):
            raise ValueError(f"K={self.K}, R={self.R}, N={self.N} exceed the 32-bit list and vertex indices")
        self._layout(max_atlas_size)
        # 0: the shader variant without texture fetches, for scenes without textures (None: ask the scene).
        self.textures = int(gpu_scene.features.textures if textures is None else textures)
        self.framebuffer = gl.empty_framebuffer(self.atlas_size)
        self.vertex_arrays: dict = {}  # by NULL_FRAGMENT: the node pass's and the raw-raster baseline's
        self.buffers = {
            "FRAMES": gl.buffer(reserve=BUNDLE_FRAME.itemsize * self.K),
            "COUNTERS": gl.buffer(reserve=4 * len(COUNTERS)),
            "HEADS": gl.buffer(reserve=4 * self.list_count),
            "OFFSETS": gl.buffer(reserve=4 * (self.list_count + 1)),
        }
        if method == "imperfect":
            self.buffers["POINTS"] = gl.buffer(reserve=16 * self.K * self.N)  # uvec4: triangle, b1, b2, -
            self.buffers["POINTS"].clear()  # triangle 0 for the warm-up draw, before any points exist
        self.capacity = 0
        self.sorted_capacity = 0
        self._scan_sums: list = []
        self._grow(initial_capacity if initial_capacity is not None else self.predicted_nodes())
        self.directions: DirectionSet | None = None
        self.stats: dict = {}
        self._raster(null_fragment=False)

    def _raster(self, null_fragment: bool) -> tuple:
        """The raster program of the node pass (or of the raw-raster baseline: an empty fragment
        shader) and its vertex array, made on first use. The first use also draws one triangle
        with nothing to write to, so the driver compiles the shader variant here and not inside
        the first timed pass (llvmpipe's first timer query around a compiling draw reports an
        invalid 2^32 - 1 ns)."""
        variant = {"NULL_FRAGMENT": True} if null_fragment else {}
        program = self.gl.program(f"{self.method}_bundles", TEXTURES=self.textures, **variant)
        if null_fragment not in self.vertex_arrays:
            vao = self.gpu_scene.vertex_array(program) if self.method == "perfect" else self.gl.vertex_array(program, [])
            self.vertex_arrays[null_fragment] = vao
            self.bind()
            self._common_uniforms(program, capacity=0, direction_base=0)
            self.gl.draw(vao, moderngl.TRIANGLES, self.framebuffer, depth_test=False, vertices=3, instances=1)
            self.gl.finish()
        return program, self.vertex_arrays[null_fragment]

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
        """A first guess of the node count, from the scene's depth complexity (the mean number of
        surfaces a line through the bounding sphere crosses) and, for splats, the mean number of
        splats covering a surface point."""
        lines = self.list_count * math.pi / 4  # the lines that meet the sphere
        overlap = max(1.0, self.splat_scale**2) if self.method == "imperfect" else 1.0
        return int(lines * self.gpu_scene.features.depth_complexity * overlap * 1.25) + 1024

    @property
    def budget_nodes(self) -> int:
        by_driver = self.gl.max_storage_bytes // 8  # the widest per-node array holds 8 bytes
        return min(self.node_budget // NODE_BYTES, by_driver)

    def _grow(self, nodes: int) -> None:
        """List buffers for at least ``nodes`` nodes (within the budget); the contents are not kept."""
        if min(nodes, self.budget_nodes) > self.capacity:
            self._resize(nodes)

    def _resize(self, nodes: int) -> None:
        nodes = max(1, min(nodes, self.budget_nodes))
        for name, width in (("NEXT", 4), ("NODE_DEPTH", 4), ("NODE_PRIM", 4), ("NODE_NORMAL", 4), ("NODE_ALBEDO", 8)):
            if name in self.buffers:
                self.buffers[name].release()
            self.buffers[name] = self.gl.buffer(reserve=width * nodes)
        self.capacity = nodes

    def _grow_sorted(self, nodes: int) -> None:
        if nodes <= self.sorted_capacity:
            return
        for name in ("SORTED_NODE", "SORTED_DEPTH"):
            if name in self.buffers:
                self.buffers[name].release()
            self.buffers[name] = self.gl.buffer(reserve=4 * max(1, nodes))
        self.sorted_capacity = nodes

    def _check_budget(self, nodes: int) -> None:
        if nodes > self.budget_nodes:
            need = nodes * NODE_BYTES
            scene = self.gpu_scene.scene.name
            raise NodeBudgetExceeded(
                scene, f"{self.method} bundles (K={self.K}, R={self.R}) need {nodes:,} nodes = {format_bytes(need)}, "
                       f"over the node budget of {format_bytes(self.budget_nodes * NODE_BYTES)}; raise --node-budget "
                       f"to at least {format_bytes(need)} or lower K, R or the splat size")

    @property
    def gpu_bytes(self) -> int:
        """Every buffer this tracer holds (nodes, lists, points) plus the scene's."""
        return sum(b.size for b in self.buffers.values()) + self.gpu_scene.nbytes

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
        # Size the node buffers from the last frame's measured count: a first guess far too
        # large (a scene of thin walls has less depth complexity than its bounds suggest) is given back.
        last = self.stats.get("nodes")
        if last is not None and self.capacity > 2 * CAPACITY_SLACK * last:
            self._resize(int(last * CAPACITY_SLACK) + 1)
        self.bind()

        if self.method == "imperfect":
            with timer.measure("points"):
                self._sample_points(directions)

        reruns = 0
        while True:
            with timer.measure("lists"):
                self._draw_lists(null_fragment=False)
            nodes = int(np.frombuffer(self.buffers["COUNTERS"].read(4 * len(COUNTERS)), dtype=np.uint32)[COUNTERS["NODES"]])
            if nodes <= self.capacity:
                break
            self._check_budget(nodes)
            self._grow(max(nodes, int(nodes * CAPACITY_SLACK)))
            self.bind()
            reruns += 1

        self._grow_sorted(nodes)
        self.bind()
        with timer.measure("resolve"):
            self._resolve()
        counters = np.frombuffer(self.buffers["COUNTERS"].read(4 * len(COUNTERS)), dtype=np.uint32)
        self.directions = directions
        gpu_ms = timer.milliseconds()
        self.stats = {
            "nodes": nodes,
            "redundant_nodes": int(counters[COUNTERS["REDUNDANT"]]),
            "redundant_tolerance": self.redundant_tolerance,
            "max_list_length": int(counters[COUNTERS["MAX_LENGTH"]]),
            "capacity": self.capacity,
            "overflow_reruns": reruns,
            "node_bytes": nodes * NODE_BYTES,
            "gpu_bytes": self.gpu_bytes,
            "gpu_ms": gpu_ms,
            "gpu_timing": timer.method,
            "wall_ms": (time.perf_counter() - start) * 1e3,
        }
        return self.stats

    @property
    def redundant_tolerance(self) -> float:
        """Depth gap under which a node repeats its predecessor's surface: a splat radius for
        splats (tangent splats of one surface cross a line within about that of each other), and
        0 for triangles (only coincident duplicates)."""
        return self.splat_radius if self.method == "imperfect" else 0.0

    def _common_uniforms(self, program, **overrides) -> None:
        """Set the raster programs' uniforms (those a variant compiled away are skipped)."""
        values = {"radius": self.gpu_scene.radius, "resolution": self.R, "tiles_per_row": self.tiles_per_row,
                  "atlas_size": self.atlas_size, "capacity": self.capacity, "points_per_direction": self.N,
                  "splat_radius": self.splat_radius, **overrides}
        set_uniforms(program, values)

    def _sample_points(self, directions: DirectionSet) -> None:
        shader = self.gl.program("splat_points")
        shader["points_per_direction"] = self.N
        shader["triangle_count"] = self.gpu_scene.triangle_count
        shader["seed"] = directions.seed & 0xFFFFFFFF
        shader["frame"] = directions.frame & 0xFFFFFFFF
        self.gl.dispatch(shader, self.K * self.N)

    def _draw_lists(self, null_fragment: bool) -> None:
        """Every direction's nodes, appended to the pixel lists: one draw per atlas."""
        program, vao = self._raster(null_fragment)
        self.buffers["HEADS"].clear(chunk=b"\xff\xff\xff\xff")
        self.buffers["COUNTERS"].clear()
        for base in range(0, self.K, self.directions_per_draw):
            count = min(self.directions_per_draw, self.K - base)
            self._common_uniforms(program, direction_base=base)
            if self.method == "perfect":
                self.gl.draw(vao, moderngl.TRIANGLES, self.framebuffer, depth_test=False, instances=count)
            else:
                self.gl.draw(vao, moderngl.TRIANGLES, self.framebuffer, depth_test=False, vertices=3 * self.N * count,
                             first=3 * self.N * base)

    def raw_raster(self, directions: DirectionSet) -> float:
        """The raw-raster baseline: this build's geometry drawn with an empty fragment shader.
        Returns its GPU time in ms (benchmarks/bundles.py)."""
        self.buffers["FRAMES"].write(_frames(directions).tobytes())
        self.bind()
        timer = PassTimer(self.gl)
        with timer.measure("raw"):
            self._draw_lists(null_fragment=True)
        return timer.milliseconds()["raw"]

    def _resolve(self) -> None:
        gl = self.gl
        count = gl.program("resolve_lists", COUNT_LISTS=True)
        gl.dispatch(count, self.list_count)
        self._prefix_sum(self.buffers["OFFSETS"], self.list_count + 1, level=0)
        self.buffers["OFFSETS"].bind_to_storage_buffer(BINDINGS["OFFSETS"])
        sort = gl.program("resolve_lists", SORT_LISTS=True)
        sort["redundant_tolerance"] = self.redundant_tolerance
        gl.dispatch(sort, self.list_count)

    def _prefix_sum(self, values, count: int, level: int) -> None:
        """Exclusive prefix sum of ``count`` uints of ``values`` in place (shaders/prefix_sum.glsl)."""
        gl = self.gl
        blocks = math.ceil(count / SCAN_BLOCK)
        if len(self._scan_sums) <= level:
            self._scan_sums.append(gl.buffer(reserve=4 * max(blocks, 1)))
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

    # -- readback ------------------------------------------------------------------------

    def read(self) -> BundleSet:
        """The last build as a `BundleSet` (host memory)."""
        if self.directions is None:
            raise RuntimeError("read() before build()")
        nodes = self.stats["nodes"]
        b = self.buffers
        offsets = np.frombuffer(b["OFFSETS"].read(4 * (self.list_count + 1)), dtype=np.uint32).astype(np.int64)
        order = np.frombuffer(b["SORTED_NODE"].read(4 * nodes), dtype=np.uint32)

        def column(name, words):
            raw = np.frombuffer(b[name].read(4 * words * nodes), dtype=np.uint32).reshape(nodes, words)
            return raw[order].reshape(-1) if words == 1 else raw[order]

        prim = column("NODE_PRIM", 1)
        triangle = (prim & ~np.uint32(SPLAT_BIT)).astype(np.int64)
        arrays, materials = self.gpu_scene.arrays, self.gpu_scene.scene.materials
        material = arrays.tri_material[triangle].astype(np.int32)
        emission = np.array([m.emission for m in materials], dtype=np.float32).reshape(-1, 3)[material]
        albedo = np.ascontiguousarray(column("NODE_ALBEDO", 2)).view(np.float16)[:, :3].astype(np.float32)
        ds = self.directions
        params = {**bundle_params(self.gpu_scene.scene, self.method, ds, self.R), "node_budget": self.node_budget, "gl": self.gl.info}
        if self.method == "imperfect":
            params.update(points=self.N, splat_scale=self.splat_scale, splat_radius=self.splat_radius)
        return BundleSet(
            method=self.method, directions=ds, centre=self.gpu_scene.centre.copy(), radius=self.gpu_scene.radius,
            resolution=self.R, offsets=offsets, depth=column("NODE_DEPTH", 1).view(np.float32),
            normal=decode_normals(column("NODE_NORMAL", 1)), albedo=albedo, emission=emission,
            prim_id=np.where(prim & SPLAT_BIT, SPLAT_PRIM_ID, triangle).astype(np.int32), material=material,
            params=params, stats=dict(self.stats))

    def release(self) -> None:
        """Free every GL object this tracer made (not the scene upload: its maker owns that)."""
        for obj in [*self.buffers.values(), *self._scan_sums, *self.vertex_arrays.values(), self.framebuffer]:
            obj.release()
        self.buffers.clear()
        self._scan_sums.clear()
        self.vertex_arrays.clear()

    def __enter__(self) -> "BundleTracer":
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def trace_bundles(gl: GLContext, scene, directions: DirectionSet, method: str = "perfect", **tracer_args) -> BundleSet:
    """The bundles of one `DirectionSet`, made once: ``scene`` (a `Scene`) uploaded, its bundles
    built and read back, and every GL object released. ``tracer_args`` go to `BundleTracer`; the
    build's statistics are in the result's ``stats``."""
    with GpuScene(gl, scene) as gpu_scene, BundleTracer(gl, gpu_scene, method, directions=directions.count,
                                                        **tracer_args) as tracer:
        tracer.build(directions)
        return tracer.read()


def _frames(directions: DirectionSet) -> np.ndarray:
    """The per-direction frames as shaders/bundle.glsl's BundleFrame array (K,)."""
    frames = np.zeros(directions.count, dtype=BUNDLE_FRAME)
    frames["u"][:, :3], frames["u"][:, 3] = directions.axis_u, directions.jitter[:, 0]
    frames["v"][:, :3], frames["v"][:, 3] = directions.axis_v, directions.jitter[:, 1]
    frames["d"][:, :3] = directions.directions
    return frames


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
