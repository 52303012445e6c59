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

A hole is one of three things, and they mean different things for the light:

- an **offset**: a test node of the same surface lies near the crossing, beyond the tolerance but
  within a splat's reach. A splat is a disk of radius r in its own triangle's plane; on a curved
  or creased surface it stands off the surface by up to r along the surface normal, r / |cos t|
  along a line at angle t to the normal (`OFFSET_REACH_COS` bounds the slope). A node of the
  same surface, left over by the matching (spurious or redundant), within that reach of the
  crossing is the surface, offset: a path still meets it. The same surface is the same smooth
  surface (`smooth_surfaces`: triangles joined across edges that bend by less than a crease; a
  column is one, a thin slab's two sides are two) or the same plane (`COPLANAR_COS`). A node of
  another surface (a wall's splat near the floor) does not make a hole an offset: the line still
  passes through the surface there. Telling them apart needs the scene's triangles
  (``surfaces``); without them the three kinds are not counted. Perfect bundles have no reach
  beyond the tolerance: every hole of theirs is a leak.
- a **leak**: no such node, so a line crosses the surface and finds no node for it: light leaks
  through. Leaks are what the splat size and point count must remove (the hole model fits them).
- a **coincident** hole: in a cluster of surfaces in one plane at one depth (a wall's top under the
  edge of a floor slab), the test node matched there lies in that plane. Merging keeps one node
  per crossing, and to a line the two are one surface: it has its node. The holes a cluster has
  beyond the planes left without a node are coincident.

So test nodes = matched + redundant + spurious, exact nodes = matched + holes, and holes = leaks +
offsets + coincident holes. Node agreement is matched / exact nodes. The spurious rate is per test
node; spurious nodes per exact crossing compares lists of different density (imperfect bundles with
and without merging) on one scale.
The tolerance is relative to the frame radius, so the numbers do not change with the scene's scale.

The rates are also broken down by direction and by **slope**: |cos| between the bundle direction
and the node's surface normal, in `SLOPE_BINS` (0 is grazing, 1 head-on). Holes are counted at
the exact node's surface, spurious and redundant nodes at the test node's.

`next_hit_errors` measures what the renderer sees: from eye vertices, the next hit that a bundle
lookup returns (the rule of shaders/paths/eye_paths.glsl) against an exact Embree ray from the vertex.
"""

from __future__ import annotations

import functools
import math
import weakref

import numpy as np

from evalkit.core.bundleset import BundleSet, DirectionSet
from evalkit.core.display import fields_html
from evalkit.core.scene.edges import (
    FLAT_DEGREES,
    OWN_SPLAT_COS,
    cut_distances,
    edge_pairs,
    plane_barycentrics,
    sharp_splat_radii,
    smooth_surfaces,
    splat_cuts,
    triangle_neighbours,
)
from evalkit.core.scene.model import camera_rays
from evalkit.core.settings import DEPTH_TOLERANCE, RenderSettings

DEFAULT_SELF_HIT_BIAS = RenderSettings().self_hit_bias

# The depth tolerance (evalkit/core/settings.py): GL perfect depths are float32 along lines centred
# on the bounding sphere, about 1e-6 of the radius; 1e-4 leaves a wide margin and still separates
# surfaces 1e-4 r apart.
SLOPE_BINS = (0.0, 0.1, 0.25, 0.5, 0.75, 1.0)
# The least |cos| between a line and a surface the offset reach counts with: at grazing angles a
# splat's reach along the line is capped at ten radii.
OFFSET_REACH_COS = 0.1
# Pieces of one plane that share no edge (a strip laid on a floor, tiles) are separate smooth
# surfaces (`smooth_surfaces`), but a splat of one that covers the other's crossing is that plane:
# nodes whose normals part by less than this are of one surface too.
COPLANAR_COS = math.cos(math.radians(FLAT_DEGREES))


def frame_mismatch(test: BundleSet, exact: BundleSet) -> str | None:
    """None when both sets use the same lines, else what differs."""
    a, b = test.directions, exact.directions
    if a.count != b.count or test.resolution != exact.resolution:
        return f"K={a.count}, R={test.resolution} against K={b.count}, R={exact.resolution}"
    if not a.same_as(b):
        return (
            f"different direction sets (seed {a.seed} frame {a.frame} against seed {b.seed} frame {b.frame}, or jitter)"
        )
    scale = max(exact.radius, 1e-300)
    if abs(test.radius - exact.radius) > 1e-9 * scale or np.abs(test.centre - exact.centre).max() > 1e-9 * scale:
        return "different bundle frames (bounding sphere centre or radius): not the same scene?"
    return None


class BundleComparison(dict):
    """`compare_bundles`' result: a dict (JSON-ready) that a notebook shows as a table."""

    def _repr_html_(self) -> str:
        rates = ("agreement", "hole_rate", "leak_rate", "offset_rate", "spurious_rate", "redundant_rate")
        fields = {
            "bundles": f"{self['test_method']} against {self['exact_method']}, K={self['directions']}, "
            f"R={self['resolution']}",
            "nodes": f"{self['test_nodes']:,} (exact {self['exact_nodes']:,})",
            **{k: self[k] for k in rates},
            "depth error (frame radii)": f"rms {self['depth_error']['rms']:.3g}, max {self['depth_error']['max']:.3g}",
            "depth tolerance": f"{self['depth_tolerance']:g} frame radii",
        }
        return fields_html("Bundle comparison", fields)


def scene_surfaces(scene) -> np.ndarray:
    """`compare_bundles`' ``surfaces`` for a scene: each triangle's smooth surface."""
    arrays = scene.arrays()
    return smooth_surfaces(arrays.positions, arrays.faces, arrays.tri_normal)


def compare_bundles(
    test: BundleSet,
    exact: BundleSet,
    depth_tolerance: float = DEPTH_TOLERANCE,
    surfaces: np.ndarray | None = None,
) -> BundleComparison:
    """Hole, spurious and redundant nodes and depth errors of ``test`` against ``exact``, in
    aggregate and per direction (see the module docstring). ``depth_tolerance`` is in units of the
    frame radius. ``surfaces``: per scene triangle, its smooth surface (`smooth_surfaces`), which
    tells an imperfect set's leaks, offsets and coincident holes apart; without it they are None.
    Raises ValueError when the two sets do not share their lines."""
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
        gap = (
            np.where(ok & (e_list[c] == t_list), np.abs(e_depth[c] - t_depth), np.inf)
            if len(e_key)
            else np.full(len(t_key), np.inf)
        )
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

    def slope_bin(normals, lists):
        cos = np.abs(np.einsum("ij,ij->i", normals.astype(np.float64), exact.directions.directions[lists // R2]))
        return np.clip(np.searchsorted(SLOPE_BINS, cos, side="right") - 1, 0, len(SLOPE_BINS) - 2)

    bins = len(SLOPE_BINS) - 1
    e_slope, t_slope = slope_bin(exact.normal, e_list), slope_bin(test.normal, t_list)
    exact_s, test_s = np.bincount(e_slope, minlength=bins), np.bincount(t_slope, minlength=bins)
    holes_s = np.bincount(e_slope[starts], weights=hole_per_cluster, minlength=bins)

    exact_k, test_k = np.bincount(e_dir, minlength=K), np.bincount(t_dir, minlength=K)
    holes_k = np.bincount(e_dir[starts], weights=hole_per_cluster, minlength=K).astype(np.int64)
    spurious_k = per_direction(spurious_node, t_dir)
    redundant_k = per_direction(redundant_node, t_dir)
    n_exact, n_test = len(e_key), len(t_key)
    holes, spurious, redundant = int(hole_per_cluster.sum()), int(spurious_node.sum()), int(redundant_node.sum())
    splat_radius = test.params.get("splat_radius")
    leaks, offsets, coincident, offset_depth = _hole_kinds(
        test,
        exact,
        tau,
        splat_radius,
        surfaces,
        cluster,
        hole_per_cluster,
        matched_test,
        cluster[assigned[matched_test]],
        spurious_node | redundant_node,
    )
    return BundleComparison(
        {
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
            "spurious_per_crossing": spurious / max(n_exact, 1),
            "redundant_rate": redundant / max(n_test, 1),
            "same_prim_rate": float(same_prim.mean()) if len(same_prim) else 1.0,
            "leaks": leaks,
            "offsets": offsets,
            "coincident": coincident,
            "leak_rate": None if leaks is None else leaks / max(n_exact, 1),
            "offset_rate": None if offsets is None else offsets / max(n_exact, 1),
            "coincident_rate": None if coincident is None else coincident / max(n_exact, 1),
            # How far offset surfaces lie from the exact crossing along the line, in frame radii and
            # (imperfect bundles) splat radii: quantiles over the offsets.
            "offset_depth": {
                "splat_radius": splat_radius,
                **{
                    f"{unit}_{q}": (float(np.quantile(offset_depth / scale, level)) if len(offset_depth) else None)
                    for unit, scale in (("radii", exact.radius), ("splat_radii", splat_radius or np.nan))
                    for q, level in (("p50", 0.5), ("p90", 0.9), ("max", 1.0))
                },
            },
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
            "per_slope": {  # |cos| between direction and surface normal, bins [SLOPE_BINS[i], SLOPE_BINS[i + 1])
                "bins": list(SLOPE_BINS),
                "exact_nodes": exact_s.tolist(),
                "test_nodes": test_s.tolist(),
                "hole_rate": (holes_s / np.maximum(exact_s, 1)).tolist(),
                "spurious_rate": (np.bincount(t_slope[spurious_node], minlength=bins) / np.maximum(test_s, 1)).tolist(),
                "redundant_rate": (
                    np.bincount(t_slope[redundant_node], minlength=bins) / np.maximum(test_s, 1)
                ).tolist(),
            },
        }
    )


def _hole_kinds(
    test, exact, tau, splat_radius, surfaces, cluster, hole_per_cluster, matched, matched_cluster, leftover
):
    """(leaks, offsets, coincident holes, the offsets' depth gaps) of the holes (see the module
    docstring): ``matched`` test nodes and their clusters, ``leftover`` the nodes left over. The
    three counts are None for splats without ``surfaces``."""
    holes = int(hole_per_cluster.sum())
    holed = np.nonzero(hole_per_cluster > 0)[0]
    if not len(holed) or splat_radius is None:
        return holes, 0, 0, np.zeros(0)
    if surfaces is None:
        return None, None, None, np.zeros(0)
    e_node = np.nonzero(hole_per_cluster[cluster] > 0)[0]  # every exact node of a holed cluster
    e_cluster = cluster[e_node]
    e_normal = exact.normal[e_node].astype(np.float64)
    # A cluster of coincident surfaces: the nodes whose plane a matched test node lies in have it,
    # and its real holes are the planes left without one (at most its holes).
    real = hole_per_cluster.copy()
    missing = np.ones(len(e_node), bool)
    size = np.bincount(e_cluster, minlength=len(hole_per_cluster))
    order = np.argsort(matched_cluster, kind="stable")
    by_cluster, matched = matched_cluster[order], matched[order]
    for c in holed[size[holed] > 1]:  # few: most crossings are alone on their line
        nodes = slice(np.searchsorted(e_cluster, c), np.searchsorted(e_cluster, c, "right"))
        found = test.normal[matched[np.searchsorted(by_cluster, c) : np.searchsorted(by_cluster, c, "right")]]
        normals = e_normal[nodes]
        missing[nodes] = ~(normals @ found.T.astype(np.float64) >= COPLANAR_COS).any(axis=1)
        planes, left = 0, normals[missing[nodes]]
        while len(left):
            planes, left = planes + 1, left[left @ left[0] < COPLANAR_COS]
        real[c] = min(real[c], planes)
    coincident = holes - int(real.sum())
    e_node, e_cluster, e_normal = e_node[missing], e_cluster[missing], e_normal[missing]

    R2 = exact.resolution**2
    dirs = exact.directions.directions
    e_list = exact.node_lists()[e_node]
    e_depth = exact.depth[e_node].astype(np.float64)
    e_cos = np.abs(np.einsum("ij,ij->i", e_normal, dirs[e_list // R2]))
    reach = np.maximum(splat_radius / np.maximum(e_cos, OFFSET_REACH_COS), tau)
    t_node = np.nonzero(leftover)[0]
    t_list, t_depth = test.node_lists()[t_node], test.depth[t_node].astype(np.float64)
    # One sorted key per node (lists are sorted, and by depth within), lists kept further apart
    # than any reach.
    low = min(t_depth.min(initial=0.0), e_depth.min(initial=0.0))
    span = max(t_depth.max(initial=0.0), e_depth.max(initial=0.0)) - low + 4 * reach.max(initial=0.0) + 1.0
    t_key, e_key = t_list * span + (t_depth - low), e_list * span + (e_depth - low)
    lo, hi = np.searchsorted(t_key, e_key - reach, "left"), np.searchsorted(t_key, e_key + reach, "right")
    # Every (exact node, test node within its reach) pair: few, as a reach spans a few nodes.
    count = hi - lo
    pair_e = np.repeat(np.arange(len(e_node)), count)
    pair_t = lo[pair_e] + np.arange(len(pair_e)) - np.repeat(np.cumsum(count) - count, count)
    e_surface = surfaces[exact.prim_id[e_node[pair_e]]]
    t_surface = surfaces[test.node_triangle()[t_node[pair_t]]]
    coplanar = np.einsum("ij,ij->i", e_normal[pair_e], test.normal[t_node[pair_t]]) >= COPLANAR_COS
    same = (e_surface == t_surface) | coplanar
    gap = np.full(len(hole_per_cluster), np.inf)  # per cluster: the nearest same-surface node's depth gap
    np.minimum.at(gap, e_cluster[pair_e[same]], np.abs(t_key[pair_t[same]] - e_key[pair_e[same]]))
    covered = np.isfinite(gap[holed]) & (real[holed] > 0)
    offsets = int(np.minimum(real[holed][covered], 1).sum())
    return int(real.sum()) - offsets, offsets, coincident, gap[holed][covered]


# -- next hits from eye vertices ----------------------------------------------------------------

# A lookup agrees with the exact ray when both miss, or both hit the same surface: the bundle's
# hit faces the same way as the ray's (normals within 90 degrees, which tells a thin slab's two
# sides apart) and lies within NEXT_HIT_PIXELS / |cos| bundle pixels of it (the line runs up to
# sqrt(2) pixels beside the vertex, which moves its hit by that over |cos| on the slanted surface
# it meets; curved, tessellated surfaces rule out a same-plane test).
NEXT_HIT_PIXELS = 2.0
NEXT_HIT_MIN_COS = 1e-3


def eye_vertices(
    scene, tracer, count: int, seed: int = 0, width: int | None = None, height: int | None = None, depths: int = 2
) -> dict:
    """Surface points where eye paths look up bundles: the camera's first hits through uniformly
    random film positions, and at each further depth up to ``depths`` as many vertices, one
    cosine-distributed bounce further (fewer where paths leave the scene). A path of B bounces looks
    up bundles from its vertices at depths 1 to B + 1 (the last toward emitters and the sky).
    Returns position, normal (shading, facing the arriving ray) and geometric normal, (M, 3), the
    triangle each lies on and its depth along the path, from 1 (M,)."""
    rng = np.random.default_rng(seed)
    w, h = scene.camera.film_size(width, height)
    cam = scene.camera.frame(np.zeros(3), w, h)
    film = rng.random((count, 2))
    origins, rays = camera_rays(cam, film)
    points, normals, geometric, triangles, depth = [], [], [], [], []
    for d in range(1, depths + 1):
        hits = tracer.next_hit(origins, rays)
        ok = hits.prim_id >= 0
        # Each normal turned to face the arriving ray on its own: a mesh's vertex normals may
        # oppose its winding, and the renderer orients the shading normal by itself
        # (shaders/paths/eye_paths.glsl), so such hits are sampled as paths meet them.
        facing = np.where(np.einsum("ij,ij->i", hits.geometric_normal, rays) > 0, -1.0, 1.0)[:, None]
        shading = np.where(np.einsum("ij,ij->i", hits.normal, rays) > 0, -1.0, 1.0)[:, None]
        ng, ns = (hits.geometric_normal * facing)[ok], (hits.normal * shading)[ok]
        points.append(hits.point[ok]), normals.append(ns), geometric.append(ng), triangles.append(hits.prim_id[ok])
        depth.append(np.full(len(ng), d))
        # The next vertex: a cosine-distributed bounce about the geometric normal.
        t1 = np.cross(ng, np.where(np.abs(ng[:, :1]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]]))
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
        t2 = np.cross(ng, t1)
        u1, u2 = rng.random(len(ng)), rng.random(len(ng))
        r, phi = np.sqrt(u1), 2 * np.pi * u2
        rays = (r * np.cos(phi))[:, None] * t1 + (r * np.sin(phi))[:, None] * t2 + np.sqrt(1 - u1)[:, None] * ng
        origins = hits.point[ok] + tracer.epsilon * ng
    return {
        "position": np.concatenate(points),
        "normal": np.concatenate(normals),
        "geometric": np.concatenate(geometric),
        "triangle": np.concatenate(triangles),
        "depth": np.concatenate(depth),
    }


def bundle_lookup(
    bundles: BundleSet,
    arrays,
    position: np.ndarray,
    normal: np.ndarray,
    geometric: np.ndarray,
    k: np.ndarray,
    self_hit_bias: float = DEFAULT_SELF_HIT_BIAS,
    triangle: np.ndarray | None = None,
) -> dict:
    """The renderer's next-vertex lookup (shaders/paths/eye_paths.glsl) on a `BundleSet`, in float64.

    ``arrays`` is the scene's `SceneArrays` (the triangles' corners and planes); ``triangle``, each
    vertex's triangle (-1 or None: on none), which tells splats of its own surface behind it
    (shaders/include/bundle_step.glsl: own_surface). Per vertex: the
    direction taken (d_k or -d_k, in the shading hemisphere), whether it leaves the geometric
    surface, the node landed on (index into the set's nodes, -1: none), the landing point, and
    whether it lies on the node's surface (the ray's own point on it, or on a triangle a walk from
    the node's reached) or is a node where it lies: the heaviest line's where lines that meet a
    surface smaller than a pixel in front of the ray's point weigh more than half, else the nearest
    line's that meets a surface where the lines' vote says the ray meets one (shaders/include/bundle_step.glsl
    says why and how they vote); and the triangle landed on where it lies on a surface (-1 where
    not). The four lines around the vertex are searched as the shader searches them."""
    ds = bundles.directions
    R, h = bundles.resolution, bundles.pixel_size()
    d, u, v = ds.directions[k], ds.axis_u[k], ds.axis_v[k]
    c = np.einsum("ij,ij->i", d, normal)
    forward = c >= 0
    omega = np.where(forward[:, None], d, -d)
    cg = np.einsum("ij,ij->i", geometric, d)
    leaves = np.where(forward, cg > 0, cg < 0)
    grid = _lookup_grid(ds, bundles.centre, bundles.radius, R, position, k)
    corner = np.floor(grid).astype(np.int64)
    offset = grid - corner
    depths = bundles.depth.astype(np.float64)
    plane = arrays.tri_normal[bundles.node_triangle()]
    splats = _SplatShapes(bundles, arrays) if bundles.has_splats else None
    own_surface = _own_surface_test(splats, plane, h)
    triangle = np.full(len(k), -1) if triangle is None else np.asarray(triangle)
    smaller_than_pixel = _smaller_than_pixel(bundles, arrays)
    walk = _surface_walk(bundles, arrays)
    bias = self_hit_bias * h
    node = np.full(len(k), -1, np.int64)
    point = np.full((len(k), 3), np.nan)
    landed = np.zeros(len(k), bool)
    node_triangle = bundles.node_triangle()
    surface = np.full(len(k), -1, np.int64)
    for i in np.nonzero(leaves)[0]:  # vertices are thousands; each search is a few steps
        x, o, f = position[i], omega[i], forward[i]
        hit = near_hit = hit_triangle = -1
        hit_t, near_distance, near_origin = 0.0, 4.0, None  # near_*: the nearest line meeting a surface
        meet_votes = leave_votes = 0  # the lines' votes (shaders/include/bundle_step.glsl)
        near_voter, near_voter_meets = 4.0, False
        lines, fronts = [], []  # (distance, voter, meets, point at x's depth); (normal, node) met from the front
        blockers, total = [], 0.0  # (weight, t, node, origin) of lines meeting a surface smaller than a pixel
        for c in range(4):
            pixel = corner[i] + (c & 1, c >> 1)
            if pixel.min() < 0 or pixel.max() >= R:
                continue
            st = bundles.radius * (2.0 * (pixel + 0.5 + ds.jitter[k[i]]) / R - 1.0)
            origin = bundles.centre + st[0] * u[i] + st[1] * v[i] - bundles.radius * d[i]
            depth = np.dot(x - origin, d[i])
            crossing = depth + np.dot(geometric[i], x - (origin + depth * d[i])) / cg[i]
            bound = max(depth, crossing) + bias if f else min(depth, crossing) - bias
            lo, hi = bundles.offsets[
                k[i] * R * R + pixel[1] * R + pixel[0] : k[i] * R * R + pixel[1] * R + pixel[0] + 2
            ]
            j = lo + np.searchsorted(depths[lo:hi], bound, side="right" if f else "left")
            # Not a voter: a line under the vertex's tangent plane with no node behind the vertex. A
            # front the ray meets ahead, which the line meets before it crosses that plane, is not
            # one (shaders/include/bundle_step.glsl).
            voter = crossing <= depth if f else crossing >= depth
            for jj in range(lo, j) if f else range(hi - 1, j - 1, -1):
                if voter:
                    break
                along = plane[jj] @ o
                behind = depths[jj] <= depth if f else depths[jj] >= depth
                voter = behind or not (along < 0 and np.dot(plane[jj], origin + depths[jj] * d[i] - x) < 0)
            to_line = np.array([c & 1, c >> 1]) - offset[i]
            distance, meets = to_line @ to_line, False
            weight = (1.0 - abs(to_line[0])) * (1.0 - abs(to_line[1]))
            total += weight
            j = j if f else j - 1
            # The first node whose plane the ray from the vertex reaches.
            while lo <= j < hi:
                gap = np.dot(plane[j], origin + depths[j] * d[i] - x)
                along = np.dot(plane[j], o)
                end = ("outside",)  # or ("met", triangle, distance; -1: the node's own) or ("open",)
                if gap * along > 0 and not own_surface(j, x, geometric[i], triangle[i], x + gap / along * o):
                    t = gap / along
                    end = walk(j, x, o, t, triangle[i], origin + depths[j] * d[i])
                if end[0] != "outside":
                    if end[0] == "met" and (hit < 0 or end[2] < hit_t * (1 - 1e-5)):
                        hit, hit_t, hit_triangle = j, end[2], end[1]
                    if end[0] == "open" and smaller_than_pixel(j):
                        blockers.append((weight, t, j, origin))
                    meets = True
                    if along < 0:
                        fronts.append((plane[j], origin + depths[j] * d[i]))
                    if distance < near_distance:
                        near_hit, near_origin, near_distance = j, origin, distance
                    break
                j = j + 1 if f else j - 1
            lines.append((distance, voter, meets, origin + depth * d[i]))
        for distance, voter, meets, at_vertex in lines:
            # Not a voter either: a line behind the front of a surface another line meets.
            voter = voter and not any(n @ (at_vertex - y) < 0 for n, y in fronts)
            meet_votes, leave_votes = meet_votes + meets, leave_votes + (voter and not meets)
            if (meets or voter) and distance < near_voter:
                near_voter, near_voter_meets = distance, meets
        nearer = [b for b in blockers if b[1] < hit_t * (1 - 1e-3)] if hit >= 0 else []
        if sum(b[0] for b in nearer) > 0.5 * total:  # a surface smaller than a pixel in front
            _, _, j, origin = max(nearer, key=lambda b: b[0])
            node[i], point[i] = j, origin + depths[j] * d[i]
        elif hit >= 0:
            node[i], point[i], landed[i] = hit, x + hit_t * o, True
            surface[i] = hit_triangle if hit_triangle >= 0 else node_triangle[hit]
        elif meet_votes > leave_votes or (meet_votes == leave_votes and near_voter_meets):  # the lines' vote
            node[i], point[i] = near_hit, near_origin + depths[near_hit] * d[i]
    return {
        "omega": omega,
        "leaves": leaves,
        "node": node,
        "point": point,
        "on_surface": landed,
        "triangle": surface,
    }


def _lookup_grid(ds: DirectionSet, centre, radius: float, R: int, position: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Where each of ``position`` (N, 3) projects in bundle k's grid of lines (N, 2): line (i, j)
    at (i, j); the lookup reads the four lines around it."""
    p = position - centre
    return np.stack(
        [
            (np.einsum("ij,ij->i", p, ds.axis_u[k]) / radius * 0.5 + 0.5) * R - ds.jitter[k, 0] - 0.5,
            (np.einsum("ij,ij->i", p, ds.axis_v[k]) / radius * 0.5 + 0.5) * R - ds.jitter[k, 1] - 0.5,
        ],
        axis=1,
    )


def lookup_lines(ds: DirectionSet, centre, radius: float, R: int, position: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The list indices of the lines `bundle_lookup` reads for ``position`` (N, 3) in bundles
    ``k`` (N,): the four around each, those inside the grid."""
    corner = np.floor(_lookup_grid(ds, centre, radius, R, position, k)).astype(np.int64)
    pixels = corner[:, None, :] + np.array([(0, 0), (1, 0), (0, 1), (1, 1)])[None]  # (N, 4, 2)
    inside = np.all((pixels >= 0) & (pixels < R), axis=2)
    lines = np.asarray(k)[:, None] * R * R + pixels[..., 1] * R + pixels[..., 0]
    return lines[inside]


def _in_triangle(b: np.ndarray) -> bool:
    """Whether barycentrics b lie in their triangle, up to 1e-4 of round-off (scene.glsl:
    inside_triangle)."""
    return bool(min(b[0], b[1], 1 - b[0] - b[1]) >= -1e-4)


class _SplatShapes:
    """The splats of an imperfect set as the shaders cut and grow them, per node j: the lines that
    cut its triangle's splats (shaders/include/scene.glsl: SplatShape) and its radius (sharp_splat_radius).
    A set built before splats ended at sharp edges (no ``crease_degrees`` in its params) has no
    lines; one built before cut splats grew (no ``splats_keep_area``) keeps every radius at
    splat_radius; one built before they grew to cover their edges (no ``splat_growth``) grew them
    to keep their disk's area; one built before its triangle's flat neighbours' sharp edges cut it
    too (no ``flat_degrees``) is cut by its own triangle's alone."""

    def __init__(self, bundles: BundleSet, arrays):
        self.radius = float(bundles.params["splat_radius"])
        self.triangles = bundles.node_triangle()
        self.centres = bundles.splat_centre
        self.arrays = arrays
        crease = bundles.params.get("crease_degrees")
        # The edge pairs, found once for the cut lines and the surfaces.
        self.pairs = edge_pairs(arrays.positions, arrays.faces, arrays.tri_normal) if len(arrays.faces) else None
        if crease is not None:
            neighbours = "flat_degrees" in bundles.params
            self.first, self.lines = splat_cuts(
                arrays.positions, arrays.faces, arrays.tri_normal, crease, neighbours, self.pairs
            )
        else:
            self.first, self.lines = np.zeros(len(arrays.faces) + 1, np.int64), np.zeros((0, 3))
        kept_area = bundles.params.get("splats_keep_area")  # the growth recorded before splat_growth
        self.growth = bundles.params.get("splat_growth") or ("keep_area" if kept_area else None)

    @functools.cached_property
    def surfaces(self) -> np.ndarray:
        """Per triangle, its smooth surface: found when a lookup from a vertex on a triangle asks."""
        return smooth_surfaces(self.arrays.positions, self.arrays.faces, self.arrays.tri_normal, pairs=self.pairs)

    def distances(self, j: int, b: np.ndarray) -> np.ndarray:
        """Barycentrics b's distances from the lines that cut node j's splat (inf past the last)."""
        return cut_distances(self.first, self.lines, self.triangles[j : j + 1], b[None])[0]

    def barycentrics(self, j: int, y: np.ndarray) -> np.ndarray:
        """Point y's barycentrics in node j's triangle's plane."""
        p0, p1, p2 = self.arrays.positions[self.arrays.faces[self.triangles[j]]]
        return plane_barycentrics(y[None], p0[None], p1[None], p2[None])[0]

    def splat_radius(self, j: int) -> float:
        """Node j's splat's radius, worked out when a lookup meets it (nodes are millions; the
        lookups meet thousands)."""
        t = self.triangles[j]
        if self.growth is None or self.first[t + 1] == self.first[t]:
            return self.radius
        distances = self.distances(j, self.barycentrics(j, self.centres[j]))
        return float(sharp_splat_radii(self.radius, distances[None], self.growth)[0])


def _own_surface_test(splats: _SplatShapes | None, plane, h: float):
    """Whether the lines around vertex x (geometric normal ng, towards the side the ray leaves, on
    triangle t, -1: none) skip node j, the ray meeting its plane at y (shaders/include/bundle_step.glsl:
    own_surface): x within the splat's cylinder of its radius, across and along its normal, facing
    the same way (normals within 60 degrees, `OWN_SPLAT_COS`), unless it is a splat of another
    smooth surface than t's and y lies in its triangle; or a splat of t's smooth surface whose
    centre lies behind x's tangent plane, within 2 (r + h) of x."""
    if splats is None:
        return lambda j, x, ng, t, y: False

    def skipped(j, x, ng, t, y):
        same = t < 0 or splats.surfaces[splats.triangles[j]] == splats.surfaces[t]
        r = splats.splat_radius(j)
        q = x - splats.centres[j]
        along = q @ plane[j]
        in_cylinder = plane[j] @ ng > OWN_SPLAT_COS and abs(along) <= r and q @ q - along * along <= r * r
        if in_cylinder and (same or not _in_triangle(splats.barycentrics(j, y))):
            return True
        return bool(t >= 0 and same and q @ ng >= 0 and q @ q <= (2 * (r + h)) ** 2)

    return skipped


# What lookups need of a scene's triangles beside the bundles, found once per `SceneArrays`: the
# resolution probe looks the same scene up at every R it tries (on 2.4 M triangles, the edges'
# neighbours took 7.7 s of each 13.7 s probe).
_TRIANGLE_FACTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _triangle_facts(arrays) -> dict:
    """Of ``arrays``' triangles: the neighbour across each edge and whether it turns
    (`triangle_neighbours`: "across", "turned") and each one's longest edge ("longest")."""
    facts = _TRIANGLE_FACTS.get(arrays)
    if facts is None:
        across, turned = triangle_neighbours(arrays.positions, arrays.faces, arrays.tri_normal)
        corners = arrays.positions[arrays.faces]
        longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
        facts = _TRIANGLE_FACTS[arrays] = {"across": across, "turned": turned, "longest": longest}
    return facts


def _smaller_than_pixel(bundles: BundleSet, arrays):
    """Whether node j's surface is smaller than a bundle pixel, as shaders/include/bundle_hits.glsl tells: a
    splat's diameter, or its triangle's longest edge."""
    h = bundles.pixel_size()
    if bundles.has_splats:
        small = 2.0 * float(bundles.params["splat_radius"]) < h
        return lambda j: small
    triangles = bundles.node_triangle()
    small = _triangle_facts(arrays)["longest"] < h  # per triangle, not per node: nodes are many more
    return lambda j: small[triangles[j]]


WALK_REACH, MAX_WALK_HOPS = 2.0, 64  # shaders/include/bundle_step.glsl: how far a walk goes


def _surface_walk(bundles: BundleSet, arrays):
    """Where the ray from x along o meets node j's plane, at distance s (shaders/include/bundle_step.glsl:
    walk_surface): ("met", -1, s) on the node's surface (inside its triangle, a splat's too, up to
    1e-4 of the barycentrics), else, walking across its triangle's edges, ("met", triangle, distance)
    where the ray meets a triangle the walk reaches (across edges within WALK_REACH pixels of the
    line's node ``met``, at most MAX_WALK_HOPS), ("outside",) where it passes an outline
    edge (the triangle across faces the other way along o, or there is none), reaches a plane only
    behind x or the vertex's own triangle ``own``, else ("open",)."""
    triangles = bundles.node_triangle()
    facts = _triangle_facts(arrays)
    across, turned = facts["across"], facts["turned"]

    reach2 = (WALK_REACH * bundles.pixel_size()) ** 2
    positions, faces, normals = arrays.positions, arrays.faces, arrays.tri_normal

    # In Python floats, not numpy: a walk is a few hops of 3-vectors, and numpy's cost per call on
    # arrays so small made walks three quarters of the probe's lookups (plane_barycentrics'
    # formula; its sums' order differs, by about 1e-14).
    def walk(j, x, o, s, own, met):
        x, o, met = x.tolist(), o.tolist(), met.tolist()
        t = triangles[j]
        for hop in range(MAX_WALK_HOPS + 1):
            corners = positions[faces[t]].tolist()
            y = [x[i] + s * o[i] for i in range(3)]
            b = _barycentrics(y, *corners)
            w = (1 - b[0] - b[1], b[0], b[1])
            corner = min(range(3), key=w.__getitem__)
            if w[corner] >= -1e-4:  # inside, up to round-off (`_in_triangle`); at the first, the node itself
                return ("met", t if hop else -1, s)
            # The edge to cross, opposite that corner, must pass within reach of the line's node.
            a, end = corners[(corner + 1) % 3], corners[(corner + 2) % 3]
            e = _sub(end, a)
            along = min(max(_dot(_sub(met, a), e) / max(_dot(e, e), 1e-30), 0.0), 1.0)
            off = [a[i] + along * e[i] - met[i] for i in range(3)]
            if hop == MAX_WALK_HOPS or _dot(off, off) > reach2:
                return ("open",)
            edge = (corner + 1) % 3
            u = int(across[t, edge])
            if u < 0:
                return ("outside",)
            n = normals[u].tolist()
            n_o = _dot(n, o)
            if u == own or ((n_o < 0) != bool(turned[t, edge])) != (_dot(normals[t].tolist(), o) < 0):
                return ("outside",)
            if n_o == 0:
                return ("outside",)
            s = _dot(n, _sub(positions[faces[u, 0]].tolist(), x)) / n_o
            if not math.isfinite(s) or s <= 0:
                return ("outside",)
            t = u

    return walk


def _sub(a: list, b: list) -> list:
    return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]


def _dot(a: list, b: list) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _barycentrics(p: list, p0: list, p1: list, p2: list) -> tuple[float, float]:
    """`plane_barycentrics` of one point, in Python floats."""
    e1, e2, q = _sub(p1, p0), _sub(p2, p0), _sub(p, p0)
    aa, ab, bb = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    det = aa * bb - ab * ab
    q1, q2 = _dot(q, e1), _dot(q, e2)
    return _divide(bb * q1 - ab * q2, det), _divide(aa * q2 - ab * q1, det)


def _divide(a: float, b: float) -> float:
    """a / b, as numpy divides: inf or nan where b is 0 (a degenerate triangle)."""
    if b == 0:
        return math.copysign(math.inf, a) * math.copysign(1.0, b) if a != 0 and not math.isnan(a) else math.nan
    return a / b


def _lookup_directions(K: int, count: int, seed: int) -> np.ndarray:
    """The bundle each of ``count`` vertices looks up in `next_hit_errors`: uniform over K."""
    return np.random.default_rng(seed).integers(0, K, count)


def next_hit_errors(
    bundles: BundleSet, tracer, vertices: dict, seed: int = 0, self_hit_bias: float = DEFAULT_SELF_HIT_BIAS
) -> dict:
    """The next-hit error rate of ``bundles`` from ``vertices`` (see `eye_vertices`): each vertex
    takes a uniformly random bundle direction, as an eye path does; the bundle lookup is compared
    with the exact Embree ray from the vertex along the same direction. Vertices whose direction
    does not leave their surface (shading normals) end their path in the renderer and are not
    counted. Broken down by outcome, by direction and by the slope at the exact hit."""
    K = bundles.directions.count
    k = _lookup_directions(K, len(vertices["position"]), seed)
    look = bundle_lookup(
        bundles,
        tracer.arrays,
        vertices["position"],
        vertices["normal"],
        vertices["geometric"],
        k,
        self_hit_bias,
        vertices.get("triangle"),
    )
    use = np.nonzero(look["leaves"])[0]
    k, omega = k[use], look["omega"][use]
    node, point = look["node"][use], look["point"][use]
    ng = vertices["geometric"][use]
    exact = tracer.next_hit(vertices["position"][use] + tracer.epsilon * ng, omega)
    bundle_hit, exact_hit = node >= 0, exact.prim_id >= 0
    # The landing's side against the exact hit's, like with like: its triangle's geometric normal
    # against the hit's where the ray lands on a surface (a walk's may be another than the node's,
    # across a concave edge too), else the node's shading normal against the hit's (vertex normals
    # may oppose the winding, and a geometric normal against a shading one counted such lookups wrong).
    landed = look["triangle"][use]
    on = landed >= 0
    normal, exact_normal = np.zeros((len(node), 3)), exact.normal.copy()
    normal[bundle_hit] = bundles.normal[node[bundle_hit]]
    normal[on] = tracer.arrays.tri_normal[landed[on]]
    exact_normal[on] = exact.geometric_normal[on]
    facing = bundle_hit & (np.einsum("ij,ij->i", normal, exact_normal) > 0)
    distance = np.linalg.norm(np.nan_to_num(point) - exact.point, axis=1)
    cos = np.abs(np.einsum("ij,ij->i", exact.geometric_normal, omega))
    same = (
        bundle_hit
        & exact_hit
        & facing
        & (distance <= NEXT_HIT_PIXELS * bundles.pixel_size() / np.maximum(cos, NEXT_HIT_MIN_COS))
    )
    agree = (~bundle_hit & ~exact_hit) | same
    false_miss = ~bundle_hit & exact_hit
    false_hit = bundle_hit & ~exact_hit
    wrong_surface = bundle_hit & exact_hit & ~same
    bins = len(SLOPE_BINS) - 1
    slope = np.clip(np.searchsorted(SLOPE_BINS, cos, side="right") - 1, 0, bins - 1)
    n_k = np.bincount(k, minlength=K)
    n_s = np.bincount(slope[exact_hit], minlength=bins)
    n = max(len(use), 1)
    depths = vertices["depth"] if "depth" in vertices else np.ones(len(vertices["position"]), np.int64)
    depth = depths[use]
    n_d = np.bincount(depth, minlength=depths.max(initial=1) + 1)[1:]
    return {
        "vertices": int(len(vertices["position"])),
        "lookups": int(len(use)),
        "pixel_tolerance": NEXT_HIT_PIXELS,
        "self_hit_bias": self_hit_bias,
        "error_rate": float(1.0 - agree.sum() / n),
        "false_miss_rate": float(false_miss.sum() / n),
        "false_hit_rate": float(false_hit.sum() / n),
        # Lookups that found nodes but no ray point on their surfaces (the ray passes between the
        # surfaces the four lines meet): the nearest meeting line's node stands in, up to a pixel off.
        "off_surface_rate": float((bundle_hit & ~look["on_surface"][use]).sum() / n),
        "wrong_surface_rate": float(wrong_surface.sum() / n),
        "per_depth": {
            "vertices": np.bincount(depths)[1:].tolist(),
            "lookups": n_d.tolist(),
            "error_rate": (np.bincount(depth[~agree], minlength=len(n_d) + 1)[1:] / np.maximum(n_d, 1)).tolist(),
        },
        "per_direction": {
            "lookups": n_k.tolist(),
            "error_rate": (np.bincount(k[~agree], minlength=K) / np.maximum(n_k, 1)).tolist(),
        },
        "per_slope": {
            "bins": list(SLOPE_BINS),
            "lookups": n_s.tolist(),
            "error_rate": (np.bincount(slope[exact_hit & ~agree], minlength=bins) / np.maximum(n_s, 1)).tolist(),
        },
    }


# -- choosing the bundle resolution ---------------------------------------------------------------

# The largest share of wrong next hits per lookup (`next_hit_errors` of exact bundles: lines up
# to a bundle pixel beside the ray) at which a scene's image means stopped moving with R, within
# 1 % of Mitsuba's, in the resolution study at one bounce (docs/results/resolution.md).
NEXT_HIT_ERROR_TARGET = 0.01
# A path of B bounces looks up bundles up to B + 1 times (fewer where it leaves the scene), and a
# wrong next hit at any depth misdirects all the light gathered beyond it, so the share of a
# B-bounce path's light that wrong lookups touch is at most their expected number along the path.
# At one bounce a path looks up twice: the advice holds that number, at every bounce count, to
# what two lookups at the target rate give.
WRONG_LOOKUPS_PER_PATH_TARGET = 2 * NEXT_HIT_ERROR_TARGET
PROBE_RESOLUTIONS = (32, 64, 128, 256, 512, 1024, 2048)


def wrong_lookups_per_path(errors: dict) -> float:
    """The expected wrong next hits along an eye path, from `next_hit_errors` of `eye_vertices` of
    every depth a path looks up from: the wrong lookups at every depth over the paths the camera
    starts (its first hits)."""
    depths = errors["per_depth"]
    return float(np.dot(depths["error_rate"], depths["lookups"]) / max(depths["vertices"][0], 1))


def resolution_advice(
    scene, tracer, bounces: int = 1, directions: int = 4, vertices: int = 1000, seed: int = 0
) -> dict:
    """The least bundle resolution R at which eye paths of ``bounces`` bounces, looking up exact
    bundles (Embree, every surface on every line), expect at most `WRONG_LOOKUPS_PER_PATH_TARGET`
    wrong next hits along the way (lookups that miss the surface the ray from the vertex meets, at
    every depth, over the paths the camera starts), doubling R from 32. A bundle pixel larger than the
    geometry's features sends paths past surfaces the ray meets (or onto surfaces it misses),
    whatever the method: no splat size or frame count removes that bias, only R does, and it grows
    with the bounces since every lookup may err. Returns the recommendation (None: not reached by
    the largest R probed), the target, and at each R probed the wrong next hits per path and each
    depth's error rate. `tracer` is the exact tracer (references.embree.ExactTracer) of the scene."""
    points = eye_vertices(scene, tracer, vertices, seed=seed, depths=bounces + 1)
    ds = DirectionSet.make(directions, seed=seed)
    k = _lookup_directions(directions, len(points["position"]), seed)
    per_path, per_depth, recommended = {}, {}, None
    for R in PROBE_RESOLUTIONS:
        # Only the lines the lookups read: the rest would not change a lookup.
        lines = lookup_lines(ds, tracer.centre, tracer.radius, R, points["position"], k)
        errors = next_hit_errors(tracer.bundles(ds, R, lines), tracer, points, seed=seed)
        per_depth[R] = errors["per_depth"]["error_rate"]
        per_path[R] = wrong_lookups_per_path(errors)
        if per_path[R] <= WRONG_LOOKUPS_PER_PATH_TARGET:
            recommended = R
            break
    return {
        "recommended": recommended,
        "bounces": bounces,
        "target": WRONG_LOOKUPS_PER_PATH_TARGET,
        "wrong_lookups_per_path": per_path,
        "error_rate_per_depth": per_depth,
        "directions": directions,
        "vertices": vertices,
        "seed": seed,
    }
