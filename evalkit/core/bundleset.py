"""Direction sets and `BundleSet`, the one type every bundle builder produces.

A ray bundle is a set of parallel lines: for direction ``d`` (unit) and its orthographic frame
``(u, v)``, bundle pixel ``(i, j)`` of an R x R grid is the line through

    o(i, j) = centre + s_i u + t_j v - radius d,   s_i = radius (2 (i + 0.5 + jitter_u) / R - 1)
                                                   t_j = radius (2 (j + 0.5 + jitter_v) / R - 1)

running along ``+d``. ``radius`` is the scene's bounding-sphere radius (padded by `FRAME_PADDING`),
so every line crosses the whole scene and a node's ``depth`` (its distance from ``o`` along ``d``)
lies in [0, 2 radius]. One list serves both ``+d`` and ``-d``.

GL perfect bundles, GL imperfect bundles and Embree exact bundles are all `BundleSet`s, built from
the same `DirectionSet`, so one comparison serves all of them. Lists are stored as CSR: list
``(k * R + j) * R + i`` holds nodes ``offsets[l]:offsets[l + 1]``, sorted by depth, then by
primitive id, then by the remaining fields, so equal inputs give equal arrays whatever order the
nodes were produced in.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field

import numpy as np

from evalkit.core import VERSION
from evalkit.core.atomic import atomic_path
from evalkit.core.display import bars_html, fields_html
from evalkit.core.errors import InputError

# The frame's radius is the bounding sphere's times this, so that round-off in the projection
# never puts a vertex on the sphere outside its bundle's tile.
FRAME_PADDING = 1.0 + 1e-6
SPLAT_PRIM_ID = -1  # a node made by a point splat has no single triangle
FORMAT_VERSION = 2  # 2: the splat nodes' triangle and centre


def orthonormal_frames(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Right-handed frames (u, v) with u x v = d for unit vectors d (K, 3), without a singularity
    (Duff et al., "Building an orthonormal basis, revisited", JCGT 2017)."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    sign = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    u = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=1)
    v = np.stack([b, sign + y * y * a, -y], axis=1)
    return u, v


@dataclass(frozen=True, eq=False)
class DirectionSet:
    """K bundle directions for one frame, drawn independently and uniformly over the sphere, each
    with its orthographic frame and a grid jitter in bundle pixels (|jitter| <= 0.5).

    Independent, not an evenly spread set: an eye path's next bundle is any of the frame's others
    (shaders/paths/eye_paths.glsl), and only independent directions make that next direction independent
    of the last, as a path tracer's are. An evenly spread set (spherical Fibonacci points under a
    random rotation) has no pair of directions closer than its spacing, so with the last bundle
    excluded paths turned back towards the surface they came from too rarely: +2.3 % indirect
    light under a constant sky at K = 16, -0.6 % on cornell-box at K = 32, B = 3
    (docs/results/decisions.toml: no-return-bundle).

    directions, axis_u, axis_v: (K, 3) float64, unit, right-handed (u x v = d).
    jitter: (K, 2) float64, the shift of the grid along (u, v) in pixels.
    """

    directions: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    jitter: np.ndarray
    seed: int
    frame: int

    @staticmethod
    def make(count: int, seed: int = 0, frame: int = 0, jitter: bool = True) -> DirectionSet:
        """The frame's directions; the same (count, seed, frame, jitter) always gives the same set."""
        if count < 1:
            raise ValueError(f"a direction set needs at least one direction, got {count}")
        rng = np.random.default_rng([seed, frame])
        z, phi = 1.0 - 2.0 * rng.random(count), 2.0 * math.pi * rng.random(count)
        r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
        u, v = orthonormal_frames(d)
        shift = rng.uniform(-0.5, 0.5, (count, 2)) if jitter else np.zeros((count, 2))
        return DirectionSet(d, u, v, shift, int(seed), int(frame))

    @property
    def count(self) -> int:
        return len(self.directions)

    def same_as(self, other: DirectionSet) -> bool:
        """Whether both sets hold the same directions and grid jitter, so the same lines."""
        return (
            self.count == other.count
            and np.allclose(self.directions, other.directions, rtol=0, atol=1e-12)
            and np.allclose(self.jitter, other.jitter, rtol=0, atol=1e-12)
        )


def line_origins(directions: DirectionSet, k: int, centre: np.ndarray, radius: float, resolution: int) -> np.ndarray:
    """Origins (R*R, 3) float64 of bundle k's lines, in list order (row j, then column i); see the
    module docstring."""
    R = resolution
    return lines_origins(directions, k * R * R + np.arange(R * R), centre, radius, R)


def lines_origins(
    directions: DirectionSet, lines: np.ndarray, centre: np.ndarray, radius: float, resolution: int
) -> np.ndarray:
    """Origins (N, 3) float64 of the given lines (list indices k R^2 + j R + i: bundle k, row j,
    column i)."""
    R = resolution
    k, pixel = np.divmod(np.asarray(lines, dtype=np.int64), R * R)
    j, i = np.divmod(pixel, R)
    s = radius * (2.0 * (i + 0.5 + directions.jitter[k, 0]) / R - 1.0)
    t = radius * (2.0 * (j + 0.5 + directions.jitter[k, 1]) / R - 1.0)
    return (
        centre
        + s[:, None] * directions.axis_u[k]
        + t[:, None] * directions.axis_v[k]
        - radius * directions.directions[k]
    )


def bundle_params(scene, method: str, directions: DirectionSet, resolution: int) -> dict:
    """The provenance every builder records in `BundleSet.params` (builders add their own)."""
    return {
        "evalkit": VERSION,
        "scene": scene.name,
        "scene_source": scene.source,  # what `load_scene` reads it from
        "scene_hash": scene.content_hash(),
        "method": method,
        "directions": directions.count,
        "resolution": int(resolution),
        "seed": directions.seed,
        "frame": directions.frame,
        "jitter": bool(np.any(directions.jitter != 0)),
    }


@dataclass(eq=False)
class BundleSet:
    """K bundles of R x R parallel lines and every node found on them (see the module docstring).

    Per node (M nodes in all): ``depth`` (M,) float32 along d from the line origin; ``normal``
    (M, 3) float32, the unit shading normal; ``albedo`` (M, 3) float32 linear, textures sampled;
    ``emission`` (M, 3) float32, the radiance the surface emits from its front side; ``prim_id`` (M,)
    int32, the scene triangle index (meshes in order) or `SPLAT_PRIM_ID`; ``material`` (M,) int32.
    ``offsets`` (K R R + 1,) int64. ``params`` and ``stats`` are JSON-ready provenance.

    Sets made of splats (imperfect bundles) also hold, per node, ``splat_triangle`` (M,) int32,
    the triangle the splat lies in, and ``splat_centre`` (M, 3) float64, its centre in scene space:
    what an eye path needs to tell whether a point lies on the splat (`node_triangle`,
    evalkit/metrics/bundles.py: `bundle_lookup`). Both are None for triangle nodes' sets.
    """

    method: str
    directions: DirectionSet
    centre: np.ndarray
    radius: float
    resolution: int
    offsets: np.ndarray
    depth: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    prim_id: np.ndarray
    material: np.ndarray
    params: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    splat_triangle: np.ndarray | None = None
    splat_centre: np.ndarray | None = None

    NODE_FIELDS = ("depth", "normal", "albedo", "emission", "prim_id", "material")
    SPLAT_FIELDS = ("splat_triangle", "splat_centre")

    @property
    def has_splats(self) -> bool:
        return self.splat_triangle is not None

    def node_triangle(self) -> np.ndarray:
        """The triangle whose plane each node lies in (M,) int64: its own, or its splat's."""
        own = self.prim_id.astype(np.int64)
        return np.where(own >= 0, own, self.splat_triangle) if self.has_splats else own

    @property
    def node_count(self) -> int:
        return int(self.offsets[-1])

    @property
    def list_count(self) -> int:
        return len(self.offsets) - 1

    def list_lengths(self) -> np.ndarray:
        return np.diff(self.offsets)

    def node_lists(self) -> np.ndarray:
        """The list index of every node, (M,) int64."""
        return np.repeat(np.arange(self.list_count), self.list_lengths())

    def pixel_size(self) -> float:
        return 2.0 * self.radius / self.resolution

    def line_origins(self, k: int) -> np.ndarray:
        """Origins (R*R, 3) float64 of bundle k's lines, in list order (row j, then column i)."""
        return line_origins(self.directions, k, self.centre, self.radius, self.resolution)

    def save(self, path: str | os.PathLike) -> None:
        ds = self.directions
        meta = {
            "format_version": FORMAT_VERSION,
            "method": self.method,
            "radius": self.radius,
            "resolution": self.resolution,
            "seed": ds.seed,
            "frame": ds.frame,
            "params": self.params,
            "stats": self.stats,
        }
        with atomic_path(path) as tmp, open(tmp, "wb") as f:  # a file object: no .npz appended
            np.savez(
                f,
                meta=np.array(json.dumps(meta)),
                centre=self.centre,
                directions=ds.directions,
                axis_u=ds.axis_u,
                axis_v=ds.axis_v,
                jitter=ds.jitter,
                offsets=self.offsets,
                **{name: getattr(self, name) for name in self.NODE_FIELDS},
                **({name: getattr(self, name) for name in self.SPLAT_FIELDS} if self.has_splats else {}),
            )

    @staticmethod
    def load(path: str | os.PathLike) -> BundleSet:
        """Read a `save`d file; a missing, foreign or inconsistent file raises `InputError`."""
        path = os.fspath(path)
        if not os.path.exists(path):
            raise InputError(path, "no such file")
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {name: z[name] for name in z.files}
        except Exception as e:  # zipfile, pickle and format errors alike: not a bundle file
            raise InputError(path, f"not a BundleSet .npz file ({e})") from None
        missing = {
            "meta",
            "centre",
            "directions",
            "axis_u",
            "axis_v",
            "jitter",
            "offsets",
            *BundleSet.NODE_FIELDS,
        } - set(arrays)
        if missing:
            raise InputError(path, f"not a BundleSet file: missing {', '.join(sorted(missing))}")
        meta = json.loads(str(arrays["meta"]))
        # Version 1 differs only in having no splat fields: its exact and perfect sets (study
        # caches) read as they are, and its imperfect ones fail `check` with the reason.
        if meta.get("format_version") not in (1, FORMAT_VERSION):
            raise InputError(path, f"BundleSet format version {meta.get('format_version')} is not {FORMAT_VERSION}")
        ds = DirectionSet(
            arrays["directions"], arrays["axis_u"], arrays["axis_v"], arrays["jitter"], meta["seed"], meta["frame"]
        )
        bundles = BundleSet(
            meta["method"],
            ds,
            arrays["centre"],
            float(meta["radius"]),
            int(meta["resolution"]),
            arrays["offsets"],
            *(arrays[name] for name in BundleSet.NODE_FIELDS),
            params=meta["params"],
            stats=meta["stats"],
            **{name: arrays[name] for name in BundleSet.SPLAT_FIELDS if name in arrays},
        )
        problem = bundles.check()
        if problem:
            raise InputError(path, problem)
        return bundles

    def check(self) -> str | None:
        """None when the set is well formed, else what is wrong (sizes, offsets, ordering, finiteness)."""
        K, R = self.directions.count, self.resolution
        if self.offsets.shape != (K * R * R + 1,):
            return f"offsets has shape {self.offsets.shape}, expected ({K * R * R + 1},) for K={K}, R={R}"
        if self.offsets[0] != 0 or np.any(np.diff(self.offsets) < 0):
            return "offsets do not start at 0 and never decrease"
        m = self.node_count
        for name in self.NODE_FIELDS + (self.SPLAT_FIELDS if self.has_splats else ()):
            if len(getattr(self, name)) != m:
                return f"{name} has {len(getattr(self, name))} entries for {m} nodes"
        if (self.splat_centre is None) != (self.splat_triangle is None):
            return "splat_triangle and splat_centre come together"
        if not self.has_splats and np.any(self.prim_id == SPLAT_PRIM_ID):
            return "splat nodes without their splats' triangles and centres"
        if not (np.isfinite(self.depth).all() and np.isfinite(self.normal).all() and np.isfinite(self.albedo).all()):
            return "node depths, normals or albedos contain NaN or Inf"
        lists = self.node_lists()
        same_list = lists[1:] == lists[:-1]
        if np.any(same_list & (self.depth[1:] < self.depth[:-1])):
            return "a list is not sorted by depth"
        return None

    def _repr_html_(self) -> str:
        """In a notebook: the counts and a histogram of list lengths (nodes per bundle line)."""
        s = self.summary()
        fields = {k: s[k] for k in ("method", "directions", "resolution", "seed", "frame", "nodes", "empty_lists")}
        lengths = np.bincount(self.list_lengths())
        shown = min(len(lengths), 16)  # 0 .. 14 nodes, then the rest together
        labels = [str(n) for n in range(shown - 1)] + [f"{shown - 1}+" if len(lengths) > shown else str(shown - 1)]
        counts = [int(c) for c in lengths[: shown - 1]] + [int(lengths[shown - 1 :].sum())]
        return fields_html("BundleSet", fields) + bars_html("lines by nodes on them", labels, counts)

    def summary(self) -> dict:
        """Counts and provenance, JSON-ready (as `evalkit bundles --json` prints them)."""
        lengths = self.list_lengths()
        return {
            "method": self.method,
            "directions": self.directions.count,
            "resolution": self.resolution,
            "seed": self.directions.seed,
            "frame": self.directions.frame,
            "nodes": self.node_count,
            "empty_lists": int(np.count_nonzero(lengths == 0)),
            "max_list_length": int(lengths.max()) if len(lengths) else 0,
            "params": self.params,
            "stats": self.stats,
        }
