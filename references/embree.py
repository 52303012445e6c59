"""Exact visibility with Embree: every intersection along every bundle line, and first hits.

embreex has no filter callbacks, so all hits along a line are found by re-casting: after a hit at
depth ``t`` the line is cast again from ``t + epsilon``. The offset is the crux:

- below the float32 error of a hit (a few ulps of the coordinates) a re-cast can find the same
  surface again, or never advance;
- above the gap between two surfaces it skips the second one.

Coordinates are float32 relative to the bounding-sphere centre, so every ray origin and hit lies
within 2r of the origin (r the padded frame radius) and its error is a few ulps of 2r. The offset
is `RECAST_ULPS` such ulps, ``epsilon = RECAST_ULPS * 2r * 2**-23`` (about 3.8e-6 r): the same for
every point of the scene and proportional to its size, so the exact lists do not change with
scale or position. Surfaces closer than ``epsilon`` along a line (coincident triangles) are one
node, and a line crosses a triangle's plane once, so a primitive found twice in a row is dropped
as the same crossing. Depths are then recomputed in float64 from the triangle's plane, so they are
exact to float64 round-off, not to Embree's float32 ``t``.

Embree runs in robust (watertight) mode, so a line through a shared edge or vertex is never lost
between the triangles that share it. ``run()`` releases the GIL, so directions are traced on a
thread pool, a few directions per task.
"""

from __future__ import annotations

import importlib.metadata
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from evalkit.core.bundleset import FRAME_PADDING, BundleSet, DirectionSet, bundle_params, lines_origins
from evalkit.core.scene import Scene
from evalkit.core.scene.colour import sample_texture

RECAST_ULPS = 16
LINES_PER_TASK = 1 << 18
# Below this |cos| between a line and a triangle's plane normal, the float64 plane depth is no
# better conditioned than Embree's own t, which is kept.
PLANE_DEPTH_MIN_COS = 1e-6


@dataclass(frozen=True)
class Hits:
    """Surface hits with their attributes (N hits, scene space, float64 unless stated).

    depth (N,) along the ray or line; point (N, 3); prim_id (N,) int32 (-1: no hit); normal (N, 3)
    unit shading normal; geometric_normal (N, 3) unit, counter-clockwise front; albedo (N, 3),
    textures sampled; emission (N, 3); material (N,) int32 (-1: no hit).
    """

    depth: np.ndarray
    point: np.ndarray
    prim_id: np.ndarray
    normal: np.ndarray
    geometric_normal: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    material: np.ndarray


class ExactTracer:
    """An Embree scene of a `Scene`'s triangles (`Scene.arrays` order, so primitive ids agree with
    the GL bundles). Building the BVH takes about a second per million triangles; reuse the tracer.
    """

    def __init__(self, scene: Scene, threads: int | None = None):
        from embreex import mesh_construction, rtcore_scene

        self.scene = scene
        self.arrays = a = scene.arrays()
        centre, radius = scene.bounding_sphere()
        self.centre = centre
        self.radius = radius * FRAME_PADDING
        self.epsilon = RECAST_ULPS * 2.0 * self.radius * 2.0**-23
        self.threads = max(1, threads or os.cpu_count() or 1)
        local = a.positions - centre
        local32 = local.astype(np.float32)
        # Embree reports one of two coincident triangles and the re-cast steps past the other, so
        # coincident triangles go to separate Embree scenes (layers) and each layer is traced alone.
        self.coincident_pairs = coincident_pairs(local, a.faces, a.tri_normal, self.epsilon)
        layer = coincidence_layers(self.coincident_pairs, len(a.faces))
        self._layers = []
        for i in range(int(layer.max()) + 1 if len(layer) else 0):
            ids = np.nonzero(layer == i)[0].astype(np.int32)
            embree = rtcore_scene.EmbreeScene(robust=True)
            mesh_construction.TriangleMesh(embree, local32, a.faces[ids].astype(np.int32))
            corners = local[a.faces[ids]].reshape(-1, 3)
            pad = 2.0 * self.epsilon
            self._layers.append((embree, ids, corners.min(axis=0) - pad, corners.max(axis=0) + pad))
        # n . (p0 - centre): plane depths are computed from centre-relative origins.
        self._plane_offset = np.einsum("ij,ij->i", a.tri_normal, local[a.faces[:, 0]])
        self._emission = np.array([m.emission for m in scene.materials], dtype=np.float64).reshape(-1, 3)
        self._albedo = np.array([m.albedo for m in scene.materials], dtype=np.float64).reshape(-1, 3)
        self._textured = [i for i, m in enumerate(scene.materials) if m.texture is not None]
        self._vertex_colored = [i for i, m in enumerate(scene.materials) if m.vertex_colors]

    # --- first hits ----------------------------------------------------------------------------

    def next_hit(self, origins: np.ndarray, directions: np.ndarray, t_max: float | np.ndarray = np.inf) -> Hits:
        """The first surface hit along each ray ``origins + t directions``, 0 < t <= t_max.

        origins (N, 3), directions (N, 3) float64 scene space (directions need not be unit; depth
        is then in their units). Rays that hit nothing have prim_id -1, depth inf and zeros.
        """
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        length = np.linalg.norm(directions, axis=1)
        unit = directions / np.where(length > 0, length, 1.0)[:, None]
        far = np.broadcast_to(np.minimum(np.asarray(t_max, dtype=np.float64) * length, 1e30), length.shape)
        chunks = np.array_split(np.arange(len(origins)), self.threads)
        with ThreadPoolExecutor(self.threads) as pool:
            parts = list(pool.map(lambda idx: self._cast(origins[idx] - self.centre, unit[idx], far[idx]), chunks))
        t, prim, b = (np.concatenate(x) for x in zip(*parts))
        hit = np.nonzero(prim >= 0)[0]
        n = len(origins)
        depth, point = np.full(n, np.inf), np.zeros((n, 3))
        depth[hit] = t[hit] / length[hit]
        point[hit] = origins[hit] + t[hit, None] * unit[hit]
        normal, geometric, albedo, emission = (np.zeros((n, 3)) for _ in range(4))
        material = np.full(n, -1, np.int32)
        normal[hit], geometric[hit], albedo[hit], emission[hit], material[hit] = self._surface(
            prim[hit], b[hit, 0], b[hit, 1]
        )
        return Hits(depth, point, prim, normal, geometric, albedo, emission, material)

    def _cast(self, origins_local: np.ndarray, unit: np.ndarray, far: np.ndarray):
        """The nearest hit over all layers: (t float64, prim int32, (b1, b2) float64) per ray, t
        from the float64 plane depth, so coincident surfaces in two layers compare exactly."""
        t, prim = np.full(len(origins_local), np.inf), np.full(len(origins_local), -1, np.int32)
        bary = np.zeros((len(origins_local), 2))
        for layer in range(len(self._layers)):
            embree_t, lp, u, v = self._cast_layer(layer, origins_local, unit, far)
            hit = np.nonzero(lp >= 0)[0]
            lt = np.full(len(lp), np.inf)
            lt[hit] = self._plane_depth(origins_local[hit], unit[hit], lp[hit], embree_t[hit].astype(np.float64))
            closer = lt < t
            t[closer], prim[closer], bary[closer] = lt[closer], lp[closer], np.stack([u, v], axis=1)[closer]
        return t, prim, bary

    def _cast_layer(self, layer: int, origins_local: np.ndarray, unit: np.ndarray, far: np.ndarray):
        """One Embree query on one layer: float32 (t, b1, b2) and the global prim (-1: no hit) per
        ray; t in unit lengths."""
        embree, ids = self._layers[layer][:2]
        r = embree.run(
            origins_local.astype(np.float32, copy=False),
            unit.astype(np.float32, copy=False),
            dists=far.astype(np.float32, copy=False),
            output=1,
        )
        prim = r["primID"]
        prim = np.where(prim >= 0, ids[np.maximum(prim, 0)], -1).astype(np.int32)
        return r["tfar"], prim, r["u"], r["v"]

    def _plane_depth(self, origins_local, unit, prim, t_embree):
        """Distance along ``unit`` from centre-relative origins to the plane of triangle ``prim``, in float64."""
        n = self.arrays.tri_normal[prim]
        cos = np.einsum("ij,ij->i", unit, n)
        ok = np.abs(cos) > PLANE_DEPTH_MIN_COS
        plane = (self._plane_offset[prim] - np.einsum("ij,ij->i", origins_local, n)) / np.where(ok, cos, 1.0)
        return np.where(ok, plane, t_embree)

    def _surface(self, prim: np.ndarray, b1: np.ndarray, b2: np.ndarray):
        """(shading normal, geometric normal, albedo, emission, material) of hits on triangles
        ``prim`` (N,) (all valid) at barycentrics (b1, b2), as the GL bundles compute them."""
        a = self.arrays
        material = a.tri_material[prim]
        geometric = a.tri_normal[prim]
        normal = geometric.copy()
        smooth = np.nonzero(a.tri_smooth[prim])[0]
        if len(smooth):
            n = self._interpolate(a.normals, prim[smooth], b1[smooth], b2[smooth])
            length = np.linalg.norm(n, axis=1, keepdims=True)
            normal[smooth] = np.where(length > 0, n / np.where(length > 0, length, 1.0), geometric[smooth])
        albedo = self._albedo[material]
        for m in self._textured:
            sel = np.nonzero(material == m)[0]
            if len(sel):
                mat = self.scene.materials[m]
                uv = self._interpolate(a.uvs, prim[sel], b1[sel], b2[sel])
                albedo[sel] = sample_texture(mat.texture, uv, mat.to_uv, mat.wrap_mode, mat.filter_type)
        for m in self._vertex_colored:
            sel = np.nonzero(material == m)[0]
            if len(sel):
                albedo[sel] = np.clip(self._interpolate(a.colors, prim[sel], b1[sel], b2[sel]), 0.0, 1.0)
        return normal, geometric, albedo, self._emission[material], material

    def _interpolate(self, values: np.ndarray, prim: np.ndarray, b1: np.ndarray, b2: np.ndarray) -> np.ndarray:
        v = self.arrays.faces[prim]
        v0 = values[v[:, 0]]
        return v0 + b1[:, None] * (values[v[:, 1]] - v0) + b2[:, None] * (values[v[:, 2]] - v0)

    # --- every hit along bundle lines ----------------------------------------------------------

    def bundles(self, directions: DirectionSet, resolution: int, lines: np.ndarray | None = None) -> BundleSet:
        """Exact bundles on the lines of ``directions`` at ``resolution``: the lines the GL
        `BundleTracer` rasterizes (`BundleSet.line_origins`). ``lines``: only these (list indices
        k R^2 + j R + i), the others left empty: what a lookup of a few points reads
        (`evalkit.metrics.bundles.lookup_lines`), at a fraction of the cost."""
        start = time.perf_counter()
        list_count = directions.count * resolution**2
        if lines is None:
            # Tasks of several directions: numpy's per-call cost, not Embree, bounds small tasks.
            per_task = resolution**2 * max(
                1, min(LINES_PER_TASK // resolution**2, -(-directions.count // self.threads))
            )
            tasks = [np.arange(first, min(first + per_task, list_count)) for first in range(0, list_count, per_task)]
        else:
            lines = np.unique(np.asarray(lines, dtype=np.int64))
            tasks = np.array_split(lines, max(1, min(self.threads, -(-len(lines) // 1024))))
        with ThreadPoolExecutor(self.threads) as pool:
            parts = list(pool.map(lambda task: self._trace_lines(directions, resolution, task), tasks))
        nodes = {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}
        casts = int(sum(p["casts"].sum() for p in parts))
        offsets = np.zeros(list_count + 1, np.int64)
        np.cumsum(np.bincount(nodes.pop("list"), minlength=list_count), out=offsets[1:])
        params = {
            **bundle_params(self.scene, "exact", directions, resolution),
            "embreex": importlib.metadata.version("embreex"),
            "recast_epsilon": self.epsilon,
            "recast_ulps": RECAST_ULPS,
            "threads": self.threads,
            "coincidence_layers": len(self._layers),
            "coincident_pairs": len(self.coincident_pairs),
        }
        if lines is not None:
            params["lines_traced"] = int(len(lines))  # of the list_count lines; the rest are left empty
        lengths = np.diff(offsets)
        stats = {
            "nodes": int(offsets[-1]),
            "casts": casts,
            "max_list_length": int(lengths.max()) if len(lengths) else 0,
            "wall_s": time.perf_counter() - start,
            "threads": self.threads,
        }
        return BundleSet(
            "exact",
            directions,
            self.centre.copy(),
            self.radius,
            int(resolution),
            offsets,
            depth=nodes["depth"],
            normal=nodes["normal"],
            albedo=nodes["albedo"],
            emission=nodes["emission"],
            prim_id=nodes["prim_id"],
            material=nodes["material"],
            params=params,
            stats=stats,
        )

    @staticmethod
    def _lines_meeting_box(origins, unit, lo, hi):
        """Indices of the lines that meet the box [lo, hi] (slab test) and the float32 depth at
        which each enters it (0 if it starts inside)."""
        enter, leave = np.zeros(len(origins)), np.full(len(origins), np.inf)
        for axis in range(3):
            o, d = origins[:, axis], unit[:, axis]
            inv = 1.0 / np.where(d == 0.0, 1e-300, d)
            t0, t1 = (lo[axis] - o) * inv, (hi[axis] - o) * inv
            enter = np.maximum(enter, np.minimum(t0, t1))
            leave = np.minimum(leave, np.maximum(t0, t1))
        active = np.nonzero(leave >= enter)[0]
        return active, enter[active].astype(np.float32)

    def _trace_lines(self, directions: DirectionSet, resolution: int, lines: np.ndarray) -> dict:
        """Every hit on ``lines`` (list indices, increasing), sorted as a BundleSet stores them:
        node arrays plus "list" (each node's list index) and "casts" (Embree rays cast)."""
        origins = lines_origins(directions, lines, np.zeros(3), self.radius, resolution)  # centre-relative
        unit = directions.directions[lines // resolution**2]
        # The re-cast loop runs in float32, as Embree does: a re-cast origin is off by about one ulp
        # of 2r, far below the offset; final depths are recomputed in float64.
        origins32, unit32 = origins.astype(np.float32), unit.astype(np.float32)
        line, depth, prim, b1, b2 = (
            [np.zeros(0, dtype)] for dtype in (np.int64, np.float32, np.int32, np.float32, np.float32)
        )
        casts = 0
        for layer, (_, _, lo, hi) in enumerate(self._layers):
            active, at = self._lines_meeting_box(origins, unit, lo, hi)
            last = np.full(len(active), -1, np.int32)
            while len(active):
                o, d = origins32[active], unit32[active]
                t, p, u, v = self._cast_layer(layer, o + at[:, None] * d, d, np.float32(2.0 * self.radius) - at)
                casts += len(active)
                got = p >= 0
                active, at, last, t, p, u, v = (x[got] for x in (active, at, last, t, p, u, v))
                hit_depth = at + t
                new = p != last  # a line meets a triangle's plane once: a repeat is the same crossing
                for out, x in ((line, active), (depth, hit_depth), (prim, p), (b1, u), (b2, v)):
                    out.append(x[new])
                last = p
                at = hit_depth + np.float32(self.epsilon)
        line, depth, prim, b1, b2 = (np.concatenate(x) for x in (line, depth, prim, b1, b2))
        depth = self._plane_depth(origins[line], unit[line], prim, depth.astype(np.float64))
        # Each layer's hits come out line by line in depth order, so a stable sort by line leaves
        # only lines with hits from several layers (coincident surfaces) to sort by depth.
        order = np.argsort(line, kind="stable")
        line, depth, prim, b1, b2 = line[order], depth[order].astype(np.float32), prim[order], b1[order], b2[order]
        same = line[1:] == line[:-1]
        unsorted = same & ((depth[1:] < depth[:-1]) | ((depth[1:] == depth[:-1]) & (prim[1:] < prim[:-1])))
        if unsorted.any():
            sel = np.nonzero(np.isin(line, line[1:][unsorted]))[0]
            sub = sel[np.lexsort((prim[sel], depth[sel], line[sel]))]
            depth[sel], prim[sel], b1[sel], b2[sel] = depth[sub], prim[sub], b1[sub], b2[sub]
        normal, _, albedo, emission, material = self._surface(prim, b1.astype(np.float64), b2.astype(np.float64))
        return {
            "list": lines[line],
            "depth": depth,
            "normal": normal.astype(np.float32),
            "albedo": albedo.astype(np.float32),
            "emission": emission.astype(np.float32),
            "prim_id": prim,
            "material": material.astype(np.int32),
            "casts": np.array([casts]),
        }


# Candidate pairs tested at a time (`_overlapping`): the tests' temporaries then stay in the cache.
PAIR_BLOCK = 1 << 16


def coincident_pairs(positions_local, faces, normals, tolerance):
    """Pairs (P, 2) int64 (sorted, smaller id first) of triangles that lie in one plane within
    ``tolerance`` and whose interiors overlap by more than ``tolerance``: coincident surfaces, such
    as a box standing on a floor. Triangles that only share an edge are not pairs.

    positions_local (V, 3) float64 around the origin; faces (T, 3); normals (T, 3) unit.
    """
    n = normals
    p = positions_local[faces]  # (T, 3, 3)
    offset = np.einsum("ij,ij->i", n, p[:, 0])
    # A sign-free plane key: n n^T (scaled to lengths) and the plane's point closest to the origin.
    scale = np.abs(positions_local).max()
    outer = (n[:, :, None] * n[:, None, :])[:, np.triu_indices(3)[0], np.triu_indices(3)[1]] * scale
    feature = np.c_[outer, offset[:, None] * n] / (8.0 * tolerance)
    mix = np.random.default_rng(0).integers(1, 2**62, 9) | 1
    boxes = p.min(axis=1), p.max(axis=1)  # each triangle's bounds, found once for every candidate pair
    pairs, tested = [], None
    # Two bin grids half a bin apart, so two planes within tolerance share a bin in at least one;
    # the second tests only the pairs the first did not (most pairs share a bin in both). Neither
    # has a bin edge at 0, where an axis-aligned plane's features lie: round-off would split its
    # triangles over two bins, and the second grid test half of its pairs again.
    for shift in (0.25, 0.75):
        key = (np.floor(feature + shift).astype(np.int64) * mix).sum(axis=1)
        _, group, count = np.unique(key, return_inverse=True, return_counts=True)
        pairs.append(_overlapping_in_groups(p, n, boxes, group, count, scale, tolerance, tested))
        tested = group
    return np.unique(np.concatenate(pairs), axis=0)


def _overlapping_in_groups(p, n, boxes, group, count, scale, tolerance, tested=None):
    """The coincident pairs among triangles that share a plane bin (``group``), but for those that
    share one in ``tested`` (another grouping, already tested); ``boxes``: the triangles' lower and
    upper corners."""
    pairs_in = count[group] > 1
    if tested is not None:  # only bins whose triangles the other grouping split hold untested pairs
        some = np.empty(len(count), np.int64)
        some[group] = tested
        split = np.zeros(len(count), bool)
        split[group[tested != some[group]]] = True
        pairs_in &= split[group]
    candidates = np.nonzero(pairs_in)[0]
    if len(candidates) == 0:
        return np.zeros((0, 2), np.int64)
    # The plane's two world axes across its normal's largest (the group's first triangle's, so
    # that every triangle of a group uses the same), u and v.
    g = group[candidates]
    _, lead, of_group = np.unique(g, return_index=True, return_inverse=True)
    major = np.argmax(np.abs(n[candidates[lead]]), axis=1)[of_group]
    u_axis, v_axis = (major + 1) % 3, (major + 2) % 3
    box_lo, box_hi = boxes
    lo, hi = box_lo[candidates, u_axis], box_hi[candidates, u_axis]
    v_lo, v_hi = box_lo[candidates, v_axis] - tolerance, box_hi[candidates, v_axis] + tolerance
    # Rows across v about a triangle high, a triangle in each row its box reaches: a sweep along
    # u within rows pairs a triangle with those beside it, not with every one of a large plane
    # whose u it shares (16 M pairs on 2.4 M triangles, swept along u alone). Rows are made
    # higher while triangles would take more than 4 rows each on average.
    h = max(float(np.median(np.maximum(hi - lo, v_hi - v_lo))), tolerance) or 1.0
    while True:
        r_lo, r_hi = np.floor(v_lo / h).astype(np.int64), np.floor(v_hi / h).astype(np.int64)
        rows = r_hi - r_lo + 1
        if rows.sum() <= 4 * len(candidates):
            break
        h *= 2.0
    copy = np.repeat(np.arange(len(candidates)), rows)
    row = r_lo[copy] + np.arange(len(copy)) - np.repeat(np.cumsum(rows) - rows, rows)
    # Sort by row (of a group), then u; number the rows in that order and sweep along u within each.
    order = np.lexsort((lo[copy], row, g[copy]))
    copy, row = copy[order], row[order]
    changes = (np.diff(row) != 0) | (np.diff(g[copy]) != 0)
    segment = np.concatenate([[0], np.cumsum(changes)])
    span = 4.0 * scale + 1.0
    key_lo = segment * span + lo[copy]
    key_hi = segment * span + hi[copy]
    end = np.searchsorted(key_lo, key_hi - tolerance, side="left")
    first = np.arange(len(copy))
    width = np.maximum(end - first - 1, 0)
    i = np.repeat(first, width)
    j = i + 1 + (np.arange(width.sum()) - np.repeat(np.cumsum(width) - width, width))
    # A pair once: in the first row both reach.
    once = row[i] == np.maximum(r_lo[copy[i]], r_lo[copy[j]])
    a, b = candidates[copy[i[once]]], candidates[copy[j[once]]]
    if tested is not None:
        untested = tested[a] != tested[b]
        a, b = a[untested], b[untested]
    # In blocks: on 2.4 M triangles, the tests on all 5 M pairs at once spent their time moving
    # arrays of every pair through memory.
    parts = [
        _overlapping(p, n, boxes, a[s : s + PAIR_BLOCK], b[s : s + PAIR_BLOCK], tolerance)
        for s in range(0, len(a), PAIR_BLOCK)
    ]
    return np.concatenate(parts) if parts else np.zeros((0, 2), np.int64)


def _overlapping(p, n, boxes, a, b, tolerance):
    """The pairs (a, b) of triangles that overlap in one plane (sorted, smaller id first)."""
    box_lo, box_hi = boxes
    # Full bounding boxes overlap, then the separating axis test in the plane.
    box = np.all((box_hi[a] >= box_lo[b] - tolerance) & (box_hi[b] >= box_lo[a] - tolerance), axis=1)
    a, b = a[box], b[box]
    # Most such pairs in a tessellated plane only touch, at a shared edge or corner, and have a
    # separating line along an edge where they overlap by 0. Found first in 2-D, on the plane's
    # projection onto the coordinate plane across its normal's largest axis: an affine map, which
    # keeps triangles that touch touching, and costs a third of the test below.
    major = np.argmax(np.abs(n[a]), axis=1)[:, None]
    corners = np.arange(3)[None, :]
    (ax, ay), (bx, by) = (
        (p[t[:, None], corners, (major + 1) % 3], p[t[:, None], corners, (major + 2) % 3]) for t in (a, b)
    )  # (M, 3) each: the corners' two coordinates
    apart = np.zeros(len(a), bool)
    for x, y in ((ax, ay), (bx, by)):
        for e in range(3):
            ex, ey = (x[:, (e + 1) % 3] - x[:, e])[:, None], (y[:, (e + 1) % 3] - y[:, e])[:, None]
            pa, pb = ay * ex - ax * ey, by * ex - bx * ey  # along (-ey, ex), across the edge
            apart |= np.minimum(_largest(pa), _largest(pb)) - np.maximum(_least(pa), _least(pb)) <= 0.0
    a, b = a[~apart], b[~apart]
    # Same plane (a hashed bin may hold others), then the separating axis test in that plane.
    overlap = np.all(np.abs(np.einsum("ikj,ij->ik", p[b] - p[a, :1], n[a])) <= tolerance, axis=1)
    for t in (a, b):
        for e in range(3):
            edge = p[t, (e + 1) % 3] - p[t, e]
            ax = np.cross(n[a], edge)
            ax /= np.linalg.norm(ax, axis=1, keepdims=True) + 1e-300
            pa = np.einsum("ikj,ij->ik", p[a], ax)
            pb = np.einsum("ikj,ij->ik", p[b], ax)
            overlap &= np.minimum(pa.max(1), pb.max(1)) - np.maximum(pa.min(1), pb.min(1)) > tolerance
    return np.sort(np.stack([a[overlap], b[overlap]], axis=1), axis=1)


def _largest(x: np.ndarray) -> np.ndarray:
    """Each row's largest of three (N, 3): faster than a reduction over so short an axis."""
    return np.maximum(np.maximum(x[:, 0], x[:, 1]), x[:, 2])


def _least(x: np.ndarray) -> np.ndarray:
    return np.minimum(np.minimum(x[:, 0], x[:, 1]), x[:, 2])


def coincidence_layers(pairs: np.ndarray, triangle_count: int) -> np.ndarray:
    """A layer index per triangle (T,) int64 such that no coincident pair shares a layer (greedy
    colouring; almost every triangle is in layer 0)."""
    layer = np.zeros(triangle_count, np.int64)
    neighbours: dict[int, list[int]] = {}
    for a, b in pairs.tolist():
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    for t in sorted(neighbours):
        taken = {int(layer[u]) for u in neighbours[t] if u < t}
        layer[t] = next(i for i in range(len(taken) + 1) if i not in taken)
    return layer
