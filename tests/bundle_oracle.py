"""Exact bundles by brute force in float64, for small scenes: every line against every triangle.
An oracle independent of GL and of Embree, for the analytic tests of the bundle builders."""

from __future__ import annotations

import numpy as np

from evalkit.core.bundleset import BundleSet
from evalkit.core.scene import Scene


def exact_lists(scene: Scene, template: BundleSet) -> list[list[np.ndarray]]:
    """Per bundle k, per line (list order), the sorted (depth, prim) hits as an (n, 2) array, on
    the lines of ``template`` (its directions, centre, radius and resolution)."""
    a = scene.arrays()
    tri = a.positions[a.faces]
    p0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    out = []
    for k in range(template.directions.count):
        d = template.directions.directions[k]
        origins = template.line_origins(k)
        # Moller-Trumbore for all lines x triangles.
        pvec = np.cross(d, e2)  # (T, 3)
        det = np.einsum("ij,ij->i", e1, pvec)  # (T,)
        ok = np.abs(det) > 1e-300
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tvec = origins[:, None, :] - p0[None]  # (L, T, 3)
        u = np.einsum("ltj,tj->lt", tvec, pvec) * inv
        qvec = np.cross(tvec, e1[None])
        v = np.einsum("j,ltj->lt", d, qvec) * inv
        t = np.einsum("tj,ltj->lt", e2, qvec) * inv
        hit = ok[None] & (u >= 0) & (v >= 0) & (u + v <= 1)
        lists = []
        for line in range(len(origins)):
            prims = np.nonzero(hit[line])[0]
            depths = t[line, prims]
            order = np.lexsort((prims, depths))
            lists.append(np.stack([depths[order], prims[order]], axis=1))
        out.append(lists)
    return out


def agreement(test: BundleSet, exact: list[list[np.ndarray]], depth_tolerance: float) -> dict:
    """Exact nodes matched by a test node of the same list within ``depth_tolerance`` (greedy in
    depth order), test nodes with no exact node, and the matched pairs' primitive agreement;
    ``crossings`` lists every exact node as (direction, line, depth, matched)."""
    R2 = test.resolution**2
    matched = spurious = total = same_prim = 0
    crossings = []
    for k, lists in enumerate(exact):
        for line, ref in enumerate(lists):
            lo, hi = test.offsets[k * R2 + line], test.offsets[k * R2 + line + 1]
            depth, prim = test.depth[lo:hi].astype(np.float64), test.prim_id[lo:hi]
            used = np.zeros(hi - lo, dtype=bool)
            total += len(ref)
            for r_depth, r_prim in ref:
                free = np.nonzero(~used & (np.abs(depth - r_depth) <= depth_tolerance))[0]
                crossings.append((k, line, r_depth, len(free) > 0))
                if len(free):
                    j = free[np.argmin(np.abs(depth[free] - r_depth))]
                    used[j] = True
                    matched += 1
                    same_prim += int(prim[j] == r_prim)
            spurious += int((~used).sum())
    return {
        "exact_nodes": total,
        "matched": matched,
        "spurious": spurious,
        "agreement": matched / max(total, 1),
        "same_prim": same_prim / max(matched, 1),
        "crossings": np.array(crossings, dtype=np.float64).reshape(-1, 4),
    }
