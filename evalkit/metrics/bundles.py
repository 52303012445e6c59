"""Bundle metrics: a `BundleSet` (GL perfect or imperfect) against the exact one (Embree) on the
same lines.

Every test node is assigned to the nearest exact node of its own list (same bundle, same pixel)
when that node is within the depth tolerance. Then:

- exact nodes of one list closer together than the tolerance form a cluster of multiplicity m
  (coincident surfaces: a box standing on a floor is two surfaces at one depth); the m nearest
  test nodes assigned to a cluster are matched;
- an exact node left unmatched is a **hole** (the test misses a surface);
- a test node assigned to no exact node is **spurious** (it reports a surface that is not there);
- test nodes assigned beyond a cluster's multiplicity are **redundant** (the same surface reported
  twice in one pixel, as overlapping splats do);
- the **depth error** of a matched test node is its distance to the nearest exact node.

So test nodes = matched + redundant + spurious, and exact nodes = matched + holes. Node agreement
is matched / exact nodes. The tolerance is relative to the frame radius, so the numbers do not
change with the scene's scale.
"""

from __future__ import annotations

import numpy as np

from evalkit.bundleset import BundleSet

# GL perfect depths are float32 along lines centred on the bounding sphere: about 1e-6 of the
# radius. 1e-4 leaves a wide margin and still separates surfaces 1e-4 r apart.
DEFAULT_DEPTH_TOLERANCE = 1e-4


def frame_mismatch(test: BundleSet, exact: BundleSet) -> str | None:
    """None when both sets use the same lines, else what differs."""
    a, b = test.directions, exact.directions
    if a.count != b.count or test.resolution != exact.resolution:
        return f"K={a.count}, R={test.resolution} against K={b.count}, R={exact.resolution}"
    if not (np.allclose(a.directions, b.directions, rtol=0, atol=1e-12) and np.allclose(a.jitter, b.jitter, rtol=0, atol=1e-12)):
        return f"different direction sets (seed {a.seed} frame {a.frame} against seed {b.seed} frame {b.frame}, or jitter)"
    scale = max(exact.radius, 1e-300)
    if abs(test.radius - exact.radius) > 1e-9 * scale or np.abs(test.centre - exact.centre).max() > 1e-9 * scale:
        return "different bundle frames (bounding sphere centre or radius): not the same scene?"
    return None


def compare_bundles(test: BundleSet, exact: BundleSet, depth_tolerance: float = DEFAULT_DEPTH_TOLERANCE) -> dict:
    """Hole, spurious and redundant nodes and depth errors of ``test`` against ``exact``, in
    aggregate and per direction (see the module docstring). ``depth_tolerance`` is in units of the
    frame radius. Raises ValueError when the two sets do not share their lines."""
    problem = frame_mismatch(test, exact)
    if problem:
        raise ValueError(f"the bundle sets are not on the same lines: {problem}")
    tau = depth_tolerance * exact.radius
    e_list, t_list = exact.node_lists(), test.node_lists()
    e_depth, t_depth = exact.depth.astype(np.float64), test.depth.astype(np.float64)
    # One sorted key per node: list index, then depth. The span keeps lists apart; float64 keeps
    # key round-off (about 1e-16 of K R^2 spans) far below the tolerance.
    low = min(e_depth.min(initial=0.0), t_depth.min(initial=0.0)) - 2 * tau
    span = max(e_depth.max(initial=0.0), t_depth.max(initial=0.0)) - low + 4 * tau
    e_key = e_list * span + (e_depth - low)
    t_key = t_list * span + (t_depth - low)
    assigned = np.full(len(t_key), -1, np.int64)
    error = np.full(len(t_key), np.inf)
    pos = np.searchsorted(e_key, t_key)
    for candidate in (pos - 1, pos):
        ok = (candidate >= 0) & (candidate < len(e_key))
        c = np.where(ok, candidate, 0)
        gap = np.where(ok & (e_list[c] == t_list), np.abs(e_depth[c] - t_depth), np.inf) if len(e_key) else np.full(len(t_key), np.inf)
        closer = (gap <= tau) & (gap < error)
        assigned[closer], error[closer] = c[closer], gap[closer]

    # Exact nodes closer than the tolerance (coincident surfaces, a box standing on a floor) are
    # one cluster of multiplicity m: it is matched by up to m test nodes, nearest first.
    starts = np.ones(len(e_key), bool)
    starts[1:] = (e_list[1:] != e_list[:-1]) | (e_depth[1:] - e_depth[:-1] > tau)
    cluster = np.cumsum(starts) - 1
    multiplicity = np.bincount(cluster)
    spurious_node = assigned < 0
    ok = np.nonzero(~spurious_node)[0]
    t_cluster = cluster[assigned[ok]]
    order = np.lexsort((error[ok], t_cluster))
    ok, t_cluster = ok[order], t_cluster[order]
    first_of_cluster = np.searchsorted(t_cluster, t_cluster, side="left")
    rank = np.arange(len(ok)) - first_of_cluster
    is_match = rank < multiplicity[t_cluster]
    matched_test = ok[is_match]
    redundant_node = np.zeros(len(t_key), bool)
    redundant_node[ok[~is_match]] = True
    matched_per_cluster = np.minimum(np.bincount(t_cluster, minlength=len(multiplicity)), multiplicity)
    hole_per_cluster = multiplicity - matched_per_cluster
    relative_error = error[matched_test] / exact.radius if len(matched_test) else np.zeros(1)
    # A matched perfect node should come from one of its cluster's triangles.
    prim_span = int(max(exact.prim_id.max(initial=0), test.prim_id.max(initial=0))) + 2
    e_pairs = cluster * prim_span + (exact.prim_id + 1)
    same_prim = np.isin(cluster[assigned[matched_test]] * prim_span + (test.prim_id[matched_test] + 1), e_pairs)

    R2 = exact.resolution**2
    K = exact.directions.count
    e_dir, t_dir = e_list // R2, t_list // R2

    def per_direction(mask, direction):
        return np.bincount(direction[mask], minlength=K)

    exact_k, test_k = np.bincount(e_dir, minlength=K), np.bincount(t_dir, minlength=K)
    holes_k = np.bincount(e_dir[starts], weights=hole_per_cluster, minlength=K).astype(np.int64)
    spurious_k = per_direction(spurious_node, t_dir)
    redundant_k = per_direction(redundant_node, t_dir)
    n_exact, n_test = len(e_key), len(t_key)
    holes, spurious, redundant = int(hole_per_cluster.sum()), int(spurious_node.sum()), int(redundant_node.sum())
    return {
        "test_method": test.method,
        "exact_method": exact.method,
        "directions": K,
        "resolution": exact.resolution,
        "depth_tolerance": depth_tolerance,
        "depth_tolerance_absolute": tau,
        "radius": exact.radius,
        "exact_nodes": n_exact,
        "test_nodes": n_test,
        "matched": int(matched_per_cluster.sum()),
        "holes": holes,
        "spurious": spurious,
        "redundant": redundant,
        "agreement": 1.0 - holes / max(n_exact, 1),
        "hole_rate": holes / max(n_exact, 1),
        "spurious_rate": spurious / max(n_test, 1),
        "redundant_rate": redundant / max(n_test, 1),
        "same_prim_rate": float(same_prim.mean()) if len(same_prim) else 1.0,
        "depth_error": {  # of matched test nodes, in units of the frame radius
            "mean": float(relative_error.mean()),
            "rms": float(np.sqrt(np.mean(relative_error**2))),
            "p99": float(np.quantile(relative_error, 0.99)),
            "max": float(relative_error.max()),
        },
        "per_direction": {
            "exact_nodes": exact_k.tolist(),
            "test_nodes": test_k.tolist(),
            "hole_rate": (holes_k / np.maximum(exact_k, 1)).tolist(),
            "spurious_rate": (spurious_k / np.maximum(test_k, 1)).tolist(),
            "redundant_rate": (redundant_k / np.maximum(test_k, 1)).tolist(),
        },
    }
