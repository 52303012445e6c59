"""The shared core of every bundle method's builder: ray bundles on the GPU, read back as a `BundleSet`.

A node is 8 bytes on the GPU: its depth along the bundle direction and a reference, a triangle or
a splat point (``NODE_REFERENCE``, shaders/include/bundle.glsl); shaders/include/bundle_hits.glsl computes the rest
where it is needed. A build is a few passes and four GPU-CPU round-trips (the compute splatter
five), whatever K is:

- ``lists``: the method's builder (`BundleTracer.build_lists`) puts every node of every line
  somewhere: appended to per-pixel linked lists by the rasterizer (`LinkedListTracer`, with a
  re-run past the buffer's capacity), or straight into exact-size slot ranges (the compute
  splatter, gpu_impl/methods/imperfect.py); round-trip 1 reads how many there are.
- ``resolve``: each list sorted (and, for splats, its redundant nodes merged) at the front of its
  slot range (shaders/bundles/resolve_lists.glsl): the groups of lists that hold a node queued
  (round-trip 2 reads how many), their short lists, then the medium and the long ones that pass
  queued (round-trip 3); round-trip 4 reads the statistics.

The resolved lists (``LIST_OFFSETS``, ``LIST_COUNTS``, ``NODES``) stay on the GPU for the renderer.
The builders live with their methods (gpu_impl/methods/); `gpu_impl.registry` finds them.
"""

from __future__ import annotations

import math
import time
from typing import ClassVar

import moderngl
import numpy as np

from evalkit.core.bundleset import SPLAT_PRIM_ID, BundleSet, DirectionSet, bundle_params
from evalkit.core.errors import InputError, LimitError
from evalkit.core.settings import RenderSettings
from gpu_impl.context import MEMORY_HEADROOM, GLContext, format_bytes, set_uniforms
from gpu_impl.layout import (
    BINDINGS,
    BUNDLE_FRAME,
    COUNTER_STRIPES,
    COUNTER_WORDS,
    COUNTERS,
    FACING_BIT,
    LINKED_NODE,
    LINKED_NODE_BYTES,
    LIST_GROUP,
    LOCAL_SIZE,
    MAX_DIRECTIONS,
    NODE,
    NODE_TRIANGLE,
    SCAN_PER_THREAD,
    SHORT_LIST,
    SORT_NETWORK,
    SPLAT_BIT,
    STRIPE_WORDS,
    STRIPED_COUNTERS,
)
from gpu_impl.scene_buffers import GpuScene
from gpu_impl.timing import PassTimer

# How much a buffer grows past a measured count, so the next frame's rotated directions (a
# slightly different count) rarely need it to grow again.
CAPACITY_SLACK = 1.125
# The frames' uniform block is always its whole size, MAX_DIRECTIONS frames (shaders/include/bundle.glsl).
FRAMES_BYTES = BUNDLE_FRAME.itemsize * MAX_DIRECTIONS
SCAN_BLOCK = SCAN_PER_THREAD * LOCAL_SIZE  # values one workgroup of shaders/bundles/prefix_sum.glsl scans


class NodeBudgetExceeded(InputError):
    """The bundles need more node memory than the budget allows."""


class BundleTracer:
    """Builds one bundle method's bundles of one uploaded scene (`GpuScene`, which its maker owns)
    with one GL context: the list layout, the buffers and the node budget, the prefix sums, the
    resolve and the read-back. A method's builder subclasses it (gpu_impl/methods/) and supplies
    `build_lists` and the resolve's passes.

    Buffers are kept and grown across `build` calls (frames), so a frame costs only its passes;
    `release` (or leaving a ``with`` block) frees every GL object the tracer made.

    ``settings`` gives K directions and R lines per side (the list layout), the node budget
    (bytes: everything the tracer holds for nodes, the lists and what they are built from; a build
    that needs more raises `NodeBudgetExceeded` with the amount needed) and the method's own
    settings. The hooks, which a builder without a use for them ignores: ``textures`` (None: ask
    the scene) picks the read-back's variant with or without texture fetches; ``count_covered``
    also counts the lines splats cover before merging (stats ``covered_nodes``; studies of the
    splat size ask for it, at some cost); ``initial_capacity`` (nodes) overrides the first guess
    of linked lists' size (tests use it to force a re-run); ``max_atlas_size`` caps the raster
    atlas's side in pixels (default: the GL viewport limit; past it, directions are drawn in
    several draws).
    """

    # How the shaders read a node's reference (bundle.glsl): NODE_TRIANGLE or NODE_SPLAT_POINT.
    node_reference: ClassVar[int] = NODE_TRIANGLE
    # What the nodes counted before the resolve are, for messages.
    raw_nodes_are: ClassVar[str] = "nodes"

    def __init__(
        self,
        gl: GLContext,
        gpu_scene: GpuScene,
        settings: RenderSettings,
        textures: bool | None = None,
        count_covered: bool = False,
        initial_capacity: int | None = None,
        max_atlas_size: int | None = None,
    ):
        self.gl, self.gpu_scene, self.settings = gl, gpu_scene, settings
        self.count_covered, self.initial_capacity, self.max_atlas_size = count_covered, initial_capacity, max_atlas_size
        self.K, self.R = settings.directions, settings.resolution
        for name, value in (("directions", self.K), ("resolution", self.R)):
            if value < 1:
                raise ValueError(f"{name} must be at least 1, got {value}")
        if self.K > MAX_DIRECTIONS:
            raise LimitError(
                f"K={self.K} directions exceed the {MAX_DIRECTIONS} a frame holds (their frames are one uniform "
                "block of 64 KiB, shaders/include/bundle.glsl); render more frames instead",
                ("directions",),
            )
        self.node_budget = int(settings.node_budget)
        self.list_count = self.K * self.R * self.R
        if self.list_count >= 2**32 - 1:
            raise LimitError(f"K={self.K}, R={self.R} exceed the 32-bit list indices", ("directions", "resolution"))
        # 0: the shader variant without texture fetches or vertex colours, for scenes with neither.
        self.textures = int(gpu_scene.features.varying_reflectance if textures is None else textures)
        self.defines = {"NODE_REFERENCE": self.node_reference}
        self.buffers: dict = {}
        self._scan_sums: list = []
        self._check_budget(self.fixed_bytes, self.fixed_items)  # before anything is allocated
        lists = 4 * (self.list_count + 1)
        self._ensure("FRAMES", FRAMES_BYTES)
        self._ensure("COUNTERS", 4 * COUNTER_WORDS)
        self._ensure("LIST_OFFSETS", lists)
        self._ensure("LIST_COUNTS", lists)
        self._ensure("LIST_GROUPS", 4 * self.group_count)
        self.directions: DirectionSet | None = None
        self.stats: dict = {}

    def _compile(self) -> None:
        """Compile every compute pass now, not inside the first timed build: a dispatch over no
        items makes the driver build its code (llvmpipe does that at the first dispatch). The
        builders call it last in their constructors."""
        self.bind()
        for program in self.compute_programs():
            self._uniforms(program)
            self.gl.dispatch(program, 0)

    # -- what a method supplies ----------------------------------------------------------

    def compute_programs(self) -> list:
        """The compute passes a build runs (the prefix sum aside)."""
        raise NotImplementedError

    def build_lists(self, directions: DirectionSet, timer: PassTimer) -> tuple[int, int]:
        """Every node of every line into the lists; returns (re-runs, nodes written)."""
        raise NotImplementedError

    def resolve_lists(self) -> None:
        """Each list sorted (and merged) into its slot range."""
        raise NotImplementedError

    def build_stats(self, counters: np.ndarray, raw: int) -> dict:
        """The method's statistics of a build from the counters: nodes, redundant_nodes, ..."""
        raise NotImplementedError

    def describe(self) -> str:
        """The method and its settings in a few symbols, for messages: 'perfect bundles (K=8, R=64)'."""
        return f"bundles (K={self.K}, R={self.R})"

    # Where the shadow-mapped light its nodes reflect is computed ("lazy": where each path lands;
    # a method whose nodes can carry light computed once per frame says how, `irradiance_items`).
    lighting: str = "lazy"

    @property
    def irradiance_items(self) -> int:
        """The items precomputed node light is stored per (shaders/lights/irradiance.glsl): none for a
        method whose light is computed where each path lands."""
        return 0

    @property
    def fixed_bytes(self) -> int:
        """What the tracer holds whatever the node count: frames and the per-list arrays."""
        return FRAMES_BYTES + 4 * (self.list_count + 1) * 2 + 4 * self.group_count

    @property
    def group_count(self) -> int:
        """The groups of `LIST_GROUP` consecutive lists the resolve queues (sort_lists)."""
        return math.ceil(self.list_count / LIST_GROUP)

    @property
    def fixed_items(self) -> str:
        """What `fixed_bytes` holds, in words."""
        return f"the frames and the {self.list_count:,} lists' counts, offsets and groups"

    # -- memory --------------------------------------------------------------------------

    @property
    def memory_bytes(self) -> int:
        """Everything the tracer holds for nodes now, which the node budget caps."""
        held = sum(b.size for name, b in self.buffers.items() if name != "COUNTERS")
        return held + sum(b.size for b in self._scan_sums)

    @property
    def gpu_bytes(self) -> int:
        """Every buffer this tracer holds plus the scene's."""
        return sum(b.size for b in self.buffers.values()) + sum(b.size for b in self._scan_sums) + self.gpu_scene.nbytes

    def _ensure(self, name: str, nbytes: int):
        """Buffer ``name`` with room for at least ``nbytes`` (its contents are not kept when it grows)."""
        self._check_buffer(nbytes, name)
        buffer = self.buffers.get(name)
        if buffer is None or buffer.size < nbytes:
            if buffer is not None:
                buffer.release()
            buffer = self.buffers[name] = self.gl.buffer(reserve=max(4, int(nbytes)))
        return buffer

    def memory_limit(self) -> tuple[int, str]:
        """The most the tracer may hold: the node budget, or less where the memory the machine (or
        the GPU) has free beside what the tracer holds is less (so a build that does not fit is
        an error, not a kill). Returns (bytes, the limit in words)."""
        budget = (self.node_budget, f"the node budget of {format_bytes(self.node_budget)}")
        room = self.gl.free_memory()
        if room is None:
            return budget
        held = self.memory_bytes
        machine = held + int(room[0] * MEMORY_HEADROOM)
        if machine >= self.node_budget:
            return budget
        free = f"{format_bytes(room[0])} free by {room[1]}"
        return machine, f"what fits in memory ({format_bytes(held)} held and half of the {free})"

    def _check_budget(self, needed: int, what: str) -> None:
        limit, words = self.memory_limit()
        if needed > limit:
            lower = "lower K, R, N or the splat size"
            advice = f"raise --node-budget to at least {format_bytes(needed)} or {lower}"
            raise NodeBudgetExceeded(
                self.gpu_scene.scene.name,
                f"{self.describe()} need {format_bytes(needed)} for {what}, over {words}; "
                + (advice if limit == self.node_budget else lower),
            )

    def _check_buffer(self, nbytes: int, name: str) -> None:
        """One buffer past the largest a shader can index would be indexed past its end."""
        largest = self.gl.max_storage_bytes
        if nbytes > largest:
            raise NodeBudgetExceeded(
                self.gpu_scene.scene.name,
                f"{self.describe()} need {format_bytes(nbytes)} in one buffer ({name}), over the largest a "
                f"shader can index here ({format_bytes(largest)}); lower K, R, N or the splat size",
            )

    def _grow(self, names: tuple[str, ...], node_bytes: int, nodes: int, what: str) -> None:
        """Grow the per-node buffers ``names`` to ``nodes`` nodes (plus slack while the budget
        allows), or raise `NodeBudgetExceeded` with the memory all of it needs."""
        current = sum(self.buffers[n].size for n in names if n in self.buffers)
        if current >= node_bytes * nodes:
            return
        others = self.memory_bytes - current
        self._check_budget(others + node_bytes * nodes, f"{nodes:,} {what} and what else the build holds")
        for name in names:
            self._check_buffer(node_bytes // len(names) * nodes, name)
        fits = min(
            (self.memory_limit()[0] - others) // node_bytes, self.gl.max_storage_bytes // (node_bytes // len(names))
        )
        # Room for every node, checked above, whatever the free memory says a moment later (the
        # passes write all of them); the slack only where it fits.
        slack = max(nodes, min(int(nodes * CAPACITY_SLACK), fits))
        for name in names:
            self._ensure(name, node_bytes // len(names) * slack)

    # -- the passes ----------------------------------------------------------------------

    def bind(self) -> None:
        self.gpu_scene.bind()
        for name, buffer in self.buffers.items():
            if name == "FRAMES":
                buffer.bind_to_uniform_block(BINDINGS[name])
            else:
                buffer.bind_to_storage_buffer(BINDINGS[name])

    def _uniforms(self, program, **overrides) -> None:
        """Set the bundle programs' uniforms (those a variant compiled away are skipped)."""
        set_uniforms(program, {**self.uniforms(), **overrides})

    def uniforms(self) -> dict:
        return {"radius": self.gpu_scene.radius, "resolution": self.R, "direction_base": 0}

    def build(self, directions: DirectionSet) -> dict:
        """Build the bundles of one frame's `DirectionSet` on the GPU; returns the statistics."""
        if directions.count != self.K:
            raise ValueError(f"this tracer was made for {self.K} directions, got {directions.count}")
        start = time.perf_counter()
        timer = PassTimer(self.gl)
        self.buffers["FRAMES"].write(_frames(directions).tobytes())
        self.gl.fill(self.buffers["COUNTERS"])
        reruns, raw = self.build_lists(directions, timer)
        with timer.measure("resolve"):
            self.resolve_lists()
        counters = self.read_counters()
        self.directions = directions
        stats = self.build_stats(counters, raw)
        self.stats = {
            **stats,
            "raw_nodes": raw,
            "max_list_length": int(counters[COUNTERS["MAX_LENGTH"]]),
            "overflow_reruns": reruns,
            "node_bytes": stats["nodes"] * NODE.itemsize,
            "memory_bytes": self.memory_bytes,
            "gpu_bytes": self.gpu_bytes,
            "gpu_ms": timer.milliseconds(),
            "gpu_timing": timer.method,
            "wall_ms": (time.perf_counter() - start) * 1e3,
        }
        return self.stats

    def read_counters(self) -> np.ndarray:
        """The build counters (layout.py: COUNTERS), KEPT summed over its stripes and MAX_LENGTH
        the largest of its stripes (layout.py: STRIPED_COUNTERS)."""
        words = self.gl.read(self.buffers["COUNTERS"], np.uint32, COUNTER_WORDS).astype(np.int64)
        counters = words[: len(COUNTERS)].copy()
        stripes = words[STRIPE_WORDS:].reshape(COUNTER_STRIPES, STRIPE_WORDS)
        counters[COUNTERS["KEPT"]] = stripes[:, STRIPED_COUNTERS.index("KEPT")].sum()
        counters[COUNTERS["MAX_LENGTH"]] = stripes[:, STRIPED_COUNTERS.index("MAX_LENGTH")].max()
        return counters

    def _scan_lists(self) -> int:
        """The lists' slot ranges: LIST_OFFSETS, the exclusive prefix sum of the per-list counts
        in LIST_COUNTS (L + 1 entries), and the node buffer grown to fit. Returns the total (one
        round-trip)."""
        offsets = self.buffers["LIST_OFFSETS"]
        self.gl.copy_buffer(offsets, self.buffers["LIST_COUNTS"], 4 * (self.list_count + 1))
        self._prefix_sum(offsets, self.list_count + 1, level=0)
        total = int(self.gl.read(offsets, np.uint32, 1, first=self.list_count)[0])
        # shaders/bundles/resolve_lists.glsl reads a short list's slots up to its sorting network's size,
        # past the list's end: the node buffer keeps that many slots beyond the last list.
        self._grow(("NODES",), NODE.itemsize, total + SORT_NETWORK, self.raw_nodes_are)
        # The resolve's queues of lists longer than SHORT_LIST: each holds more than that many nodes.
        self._grow(("LONG_LISTS",), 4, total // (SHORT_LIST + 1) + 1, "long lists queued")
        self.bind()
        return total

    def sort_programs(self, **defines) -> tuple:
        """shaders/bundles/resolve_lists.glsl's four passes of a sort (or merge: ``defines``)."""
        passes = ({"QUEUE_GROUPS": True}, {}, {"MEDIUM_LISTS": True}, {"LONG_LISTS": True})
        return tuple(self.gl.program("resolve_lists", **defines, **extra) for extra in passes)

    def sort_lists(self, uniforms: dict | None = None, **defines) -> None:
        """Each list sorted (or merged, ``defines``) into its slot range: a pass queues the groups
        of lists that hold a node (round-trip 2 reads how many), a pass over their lists sorts the
        short ones and queues the rest, the medium and the long apart, then a pass over each queue
        (round-trip 3)."""
        gl = self.gl
        groups, short, medium, long = programs = self.sort_programs(**defines)
        for program in programs:
            set_uniforms(program, {**(uniforms or {}), "list_count": self.list_count})
        gl.dispatch(groups, self.group_count)
        queued = int(gl.read(self.buffers["COUNTERS"], np.uint32, 1, first=COUNTERS["LIST_GROUPS"])[0])
        gl.dispatch(short, queued * LIST_GROUP)
        assert COUNTERS["MEDIUM_LISTS"] == COUNTERS["LONG_LISTS"] + 1  # one read
        longs, mediums = (int(n) for n in gl.read(self.buffers["COUNTERS"], np.uint32, 2, first=COUNTERS["LONG_LISTS"]))
        if mediums:
            gl.dispatch(medium, mediums)
        if longs:
            gl.dispatch(long, longs)

    def _prefix_sum(self, values, count: int, level: int) -> None:
        """Exclusive prefix sum of ``count`` uints of ``values`` in place (shaders/bundles/prefix_sum.glsl)."""
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

    # -- readback ------------------------------------------------------------------------

    def node_refs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The last build's lists as a CSR: offsets (L + 1,) int64, depth (M,) float32 and
        reference (M,) uint32 (a triangle, or a splat point), and each node's slot (M,) int64 in
        the GPU's node buffer (where the resolve left it)."""
        if self.directions is None:
            raise RuntimeError("node_refs() before build()")
        b, L = self.buffers, self.list_count
        first = self.gl.read(b["LIST_OFFSETS"], np.uint32, L).astype(np.int64)
        counts = self.gl.read(b["LIST_COUNTS"], np.uint32, L).astype(np.int64)
        offsets = np.concatenate([[0], np.cumsum(counts)])
        slots = np.repeat(first - offsets[:-1], counts) + np.arange(offsets[-1])
        used = int(first[-1] + counts[-1]) if L else 0
        keys = self.gl.read(b["NODES"], np.uint32, NODE.itemsize // 4 * used).reshape(-1, 2)[slots]
        return offsets, order_bits_depth(keys[:, 1]), keys[:, 0] & ~FACING_BIT, slots

    def params(self) -> dict:
        """The method's own settings, as the read-back's provenance records them."""
        return {}

    def read(self) -> BundleSet:
        """The last build as a `BundleSet` (host memory): the nodes with the attributes an eye path
        sees at them (shaders/bundles/expand_nodes.glsl)."""
        offsets, depth, refs, slots = self.node_refs()
        used = int(slots[-1]) + 1 if len(slots) else 0
        attributes = self.gl.buffer(reserve=16 * max(used, 1))
        try:
            attributes.bind_to_storage_buffer(BINDINGS["NODE_ATTRIBUTES"])
            self.bind()
            expand = self.gl.program("expand_nodes", TEXTURES=self.textures, **self.defines)
            self._uniforms(expand)
            self.gl.dispatch(expand, self.list_count)
            words = self.gl.read(attributes, np.uint32, 4 * used).reshape(used, 4)[slots]
        finally:
            attributes.release()
        prim = words[:, 3]
        triangle = (prim & ~np.uint32(SPLAT_BIT)).astype(np.int64)
        arrays, materials = self.gpu_scene.arrays, self.gpu_scene.scene.materials
        material = arrays.tri_material[triangle].astype(np.int32)
        emission = np.array([m.emission for m in materials], dtype=np.float32).reshape(-1, 3)[material]
        albedo = np.ascontiguousarray(words[:, 1:3]).view(np.float16)[:, :3].astype(np.float32)
        ds = self.directions
        method = self.settings.method
        params = {
            **bundle_params(self.gpu_scene.scene, method, ds, self.R),
            "node_budget": self.node_budget,
            "gl": self.gl.info,
            **self.params(),
        }
        return BundleSet(
            method=method,
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
            **self.splat_fields(refs),
        )

    def splat_fields(self, refs: np.ndarray) -> dict:
        """`BundleSet`'s splat fields for nodes with references ``refs`` (none without splats)."""
        return {}

    def release(self) -> None:
        """Free every GL object this tracer made (not the scene upload: its maker owns that)."""
        for obj in [*self.buffers.values(), *self._scan_sums]:
            obj.release()
        self.buffers.clear()
        self._scan_sums.clear()

    def __enter__(self) -> BundleTracer:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


class LinkedListTracer(BundleTracer):
    """A builder whose raster pass appends every node to its pixel's linked list (perfect bundles,
    the poster's raster splats): one draw per atlas of R x R tiles, and past the buffer's capacity
    the pass runs again with a buffer that fits. Then list lengths, a prefix sum into exact-size
    slot ranges, and the method's sort or merge of each list into its range.
    """

    raster_program: ClassVar[str]  # shaders/<raster_program>.glsl draws the nodes

    def __init__(self, gl: GLContext, gpu_scene: GpuScene, settings: RenderSettings, **hooks):
        super().__init__(gl, gpu_scene, settings, **hooks)
        self.capacity = 0  # nodes the linked lists hold (their buffers are made below)
        self._layout(self.max_atlas_size)
        self.framebuffer = gl.empty_framebuffer(self.atlas_size)
        self.vertex_arrays: dict = {}  # by NULL_FRAGMENT: the node pass's and the raw-raster baseline's

    def _make_lists(self) -> None:
        """The linked-list buffers at their first size and the raster pass compiled; the builders
        call it once their own buffers exist (the first guess leaves room for them)."""
        self._ensure("HEADS", 4 * self.list_count)
        self._grow_linked(self.initial_capacity if self.initial_capacity is not None else self.predicted_nodes())
        self._raster(null_fragment=False)

    def _layout(self, max_atlas_size: int | None) -> None:
        """The atlas: as square as possible, split into several draws only past the GL limit."""
        max_dim = min(self.gl.limit("GL_MAX_VIEWPORT_DIMS"))
        max_dim = min(max_dim, max_atlas_size or max_dim)
        tiles = max_dim // self.R
        if tiles < 1:
            raise LimitError(f"bundle resolution {self.R} exceeds the GL viewport limit {max_dim}", ("resolution",))
        self.tiles_per_row = min(math.ceil(math.sqrt(self.K)), tiles)
        rows = min(math.ceil(self.K / self.tiles_per_row), tiles)
        self.directions_per_draw = self.tiles_per_row * rows
        self.atlas_size = (self.tiles_per_row * self.R, rows * self.R)

    def predicted_nodes(self, overlap: float = 1.0) -> int:
        """A first guess of the linked lists' size, from the scene's depth complexity (the mean
        number of surfaces a line through the bounding sphere crosses) and ``overlap``, the mean
        number of nodes one surface crossing makes."""
        lines = self.list_count * math.pi / 4  # the lines that meet the sphere
        return int(lines * self.gpu_scene.features.depth_complexity * overlap * 1.25) + 1024

    @property
    def fixed_bytes(self) -> int:
        return super().fixed_bytes + 4 * self.list_count  # the list heads

    def uniforms(self) -> dict:
        values = {"tiles_per_row": self.tiles_per_row, "atlas_size": self.atlas_size, "capacity": self.capacity}
        return {**super().uniforms(), **values}

    def _grow_linked(self, nodes: int) -> None:
        """Linked-list buffers for ``nodes`` nodes (a guess, or a measured count)."""
        nodes = max(1, nodes)
        # Never more than fits: a first guess over the machine's memory would be touched, and
        # killed for, as the raster pass fills it; an overflowing pass is counted and refused.
        budget_nodes = max(1, (self.memory_limit()[0] - self.fixed_bytes) // LINKED_NODE_BYTES)
        widest = max(dtype.itemsize for dtype, _ in LINKED_NODE.values())
        self.capacity = min(nodes, budget_nodes, self.gl.max_storage_bytes // widest)
        for dtype, name in LINKED_NODE.values():
            size = dtype.itemsize * self.capacity
            if name in self.buffers and self.buffers[name].size != size:
                self.buffers.pop(name).release()
            self._ensure(name, size)

    def vertex_array(self, program):
        """The raster pass's vertex array for ``program``."""
        raise NotImplementedError

    def draw(self, vao, base: int, count: int) -> None:
        """Draw directions base .. base + count - 1 into the atlas."""
        raise NotImplementedError

    def _raster(self, null_fragment: bool) -> tuple:
        """The raster program of the linked-list pass (or of the raw-raster baseline: an empty
        fragment shader) and its vertex array, made on first use. The first use also draws one
        triangle with nothing to write to, so the driver compiles the shader variant here and not
        inside the first timed pass (llvmpipe's first timer query around a compiling draw reports an
        invalid 2^32 - 1 ns)."""
        variant = {"NULL_FRAGMENT": True} if null_fragment else {}
        program = self.gl.program(self.raster_program, **variant)
        if null_fragment not in self.vertex_arrays:
            vao = self.vertex_arrays[null_fragment] = self.vertex_array(program)
            self.bind()
            self._uniforms(program, capacity=0)
            self.gl.draw(vao, moderngl.TRIANGLES, self.framebuffer, depth_test=False, vertices=3, instances=1)
            self.gl.finish()
        return program, self.vertex_arrays[null_fragment]

    def _draw_lists(self, null_fragment: bool) -> None:
        """Every direction's nodes, appended to the pixel lists: one draw per atlas."""
        program, vao = self._raster(null_fragment)
        self.gl.fill(self.buffers["HEADS"], 0xFFFFFFFF)
        for base in range(0, self.K, self.directions_per_draw):
            self._uniforms(program, direction_base=base)
            self.draw(vao, base, min(self.directions_per_draw, self.K - base))

    def linked_lists(self, timer: PassTimer) -> tuple[int, int]:
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
            self.gl.fill(self.buffers["COUNTERS"])
            with timer.measure("lists"):
                self._draw_lists(null_fragment=False)
            nodes = int(self.gl.read(self.buffers["COUNTERS"], np.uint32, 1)[0])
            if nodes <= self.capacity:
                return reruns, nodes
            self._check_budget(self.fixed_bytes + nodes * LINKED_NODE_BYTES, f"{nodes:,} nodes in linked lists")
            for dtype, name in LINKED_NODE.values():
                self._check_buffer(dtype.itemsize * nodes, name)
            self._grow_linked(max(nodes, int(nodes * CAPACITY_SLACK)))
            self.bind()
            reruns += 1

    def count_lists(self) -> None:
        """List lengths into LIST_COUNTS, and the slot ranges they sort or merge into."""
        self.gl.dispatch(self.gl.program("resolve_lists", COUNT_LISTS=True), self.list_count)
        self._scan_lists()

    def raw_raster(self, directions: DirectionSet) -> float:
        """The raw-raster baseline: this build's raster geometry drawn with an empty fragment
        shader. Returns its GPU time in ms (benchmarks/bundles.py)."""
        self.buffers["FRAMES"].write(_frames(directions).tobytes())
        self.bind()
        timer = PassTimer(self.gl)
        with timer.measure("raw"):
            self._draw_lists(null_fragment=True)
        return timer.milliseconds()["raw"]

    def release(self) -> None:
        for vao in self.vertex_arrays.values():
            vao.release()
        self.vertex_arrays.clear()
        if self.framebuffer is not None:
            self.framebuffer.release()
            self.framebuffer = None
        super().release()


def _frames(directions: DirectionSet) -> np.ndarray:
    """The per-direction frames as shaders/include/bundle.glsl's BundleFrame array (K,)."""
    frames = np.zeros(directions.count, dtype=BUNDLE_FRAME)
    frames["u"][:, :3], frames["u"][:, 3] = directions.axis_u, directions.jitter[:, 0]
    frames["v"][:, :3], frames["v"][:, 3] = directions.axis_v, directions.jitter[:, 1]
    frames["d"][:, :3] = directions.directions
    return frames


def order_bits_depth(bits: np.ndarray) -> np.ndarray:
    """Depths from their order bits, a node key's high word (shaders/include/common.glsl)."""
    sign = np.uint32(0x80000000)
    return np.where(bits & sign, bits ^ sign, ~bits).astype(np.uint32).view(np.float32)


def decode_normals(packed: np.ndarray) -> np.ndarray:
    """Octahedral snorm16x2 normals (shaders/include/common.glsl: encode_normal) to unit (M, 3) float32."""
    e = np.clip(packed.astype(np.uint32).view(np.int16).reshape(-1, 2).astype(np.float64) / 32767.0, -1.0, 1.0)
    x, y = e[:, 0], e[:, 1]
    z = 1.0 - np.abs(x) - np.abs(y)
    # Below the equator the octahedron is folded: (1 - |y|, 1 - |x|) with the signs of x and y.
    back = z < 0.0
    x, y = (np.where(back, (1.0 - np.abs(b)) * np.where(a >= 0.0, 1.0, -1.0), a) for a, b in ((x, y), (y, x)))
    length = np.sqrt(x * x + y * y + z * z)
    return np.stack([x / length, y / length, z / length], axis=1).astype(np.float32)
