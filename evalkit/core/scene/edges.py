"""What a triangle soup's edges say about its surfaces: which triangles bound a solid, and which
edges are sharp, where splats (imperfect bundles', imperfect shadow maps') must end. Corners are
welded within a ten-millionth of the scene's extent first: a seam's copies of a corner differ by
rounding."""

from __future__ import annotations

import math

import numpy as np

# Two triangles meeting at an edge whose normals part by more than this are a crease between two
# smooth surfaces (smooth_surfaces): tessellated curved surfaces part by less (atrium's columns by
# 7.5 degrees, a 16-sided cylinder by 22.5), and a column is one surface.
CREASE_DEGREES = 30.0
# A splat in its triangle's plane that reaches over a convex edge, where the neighbour bends away
# by theta, stands off the neighbour by up to r sin(theta): lines beside a small part's outline meet
# it where the part is not. Splats end at convex edges of more than this (sharp_edges, splat_cuts;
# docs/results/decisions.toml: convex-edges-10-degrees), which cuts a 16-sided
# cylinder's facets (22.5 degrees) but not atrium's columns' (7.5): a facet narrower than a splat,
# cut on both sides, keeps too few points to cover it (atrium at N = 16384, splat scale 2.5: leaks
# 0.41 % at 10 degrees, 4.8 % at 5).
SPLAT_CREASE_DEGREES = 10.0
# Two triangles across an edge whose normals part by less than this lie in one plane to a splat,
# whose sharp edges cut the splats of both (flat_neighbours, splat_cuts): over a splat's radius r
# one stands off the other's plane by at most r sin(0.5 degrees) < r / 100.
FLAT_DEGREES = 0.5
# The most lines that cut one triangle's splats (splat_cuts): k sharp edges of its own and two of
# each of its 3 - k flat neighbours.
MAX_SPLAT_CUTS = 6
# A splat whose cylinder holds a path's vertex stands for the vertex's own surface where the two
# normals part by less than 60 degrees (shaders/include/bundle_step.glsl: own_surface). A wall's splat
# beside a ceiling vertex is perpendicular to it: with "more than 90 degrees apart" instead, float
# round-off of the two normals let it pass at concave corners, and lookups left cornell-box there
# (docs/results/decisions.toml: own-surface-behind-tangent-plane).
OWN_SPLAT_COS = 0.5


def _edges(positions: np.ndarray, faces: np.ndarray):
    """The triangles that keep an area after welding (K,), their welded corners (K, 3), the id of
    each one's edge e, from corner e to corner e + 1 (K, 3), how many triangles share each id, and
    the edges' slots (3 t + e) in the order of their ids."""
    extent = float(np.ptp(positions, axis=0).max()) if len(positions) else 1.0
    welded = _runs(*np.round(positions / (1e-7 * (extent or 1.0))).T)[0]
    corners = welded.reshape(-1)[faces]
    kept = np.flatnonzero((corners != np.roll(corners, 1, axis=1)).all(axis=1))
    corners = corners[kept]
    ends = np.stack([corners, np.roll(corners, -1, axis=1)], axis=2).reshape(-1, 2)
    key = ends.min(axis=1).astype(np.int64) * (int(welded.max(initial=0)) + 1) + ends.max(axis=1)
    edge, shared, order = _runs(key)
    return kept, corners, edge.reshape(-1, 3), shared, order


def _runs(*keys: np.ndarray):
    """Ids of the distinct rows of ``keys`` (columns, the first the most significant), numbered in
    their sorted order as `np.unique` numbers them; how many rows share each id; and the rows in the
    order of their ids (equal rows in their own order). One stable sort, where `np.unique` of rows
    sorts them as records, several times as slowly."""
    order = np.lexsort(keys[::-1])
    if not len(order):
        return np.zeros(0, np.int64), np.zeros(0, np.int64), order
    ordered = [k[order] for k in keys]
    new = np.ones(len(order), bool)
    new[1:] = np.any([k[1:] != k[:-1] for k in ordered], axis=0)
    ids = np.empty(len(order), np.int64)
    ids[order] = np.cumsum(new) - 1
    return ids, np.diff(np.append(np.flatnonzero(new), len(order))), order


def solid_triangles(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per triangle, whether it bounds a solid: its connected surface (triangles joined by shared
    edges) is closed, every edge shared by exactly two triangles. A box or a ball resting on a floor
    is one; the floor, a quad light and a room open on one side are not (shaders/lights/shadow_maps.glsl:
    what lies behind a solid's surface is inside it). A triangle that welding collapses (at a UV
    sphere's poles) has no area and no say, and is not one."""
    from scipy.sparse import coo_matrix  # deferred: scipy loads in a second; only solids ask
    from scipy.sparse.csgraph import connected_components  # deferred: as above

    solid = np.zeros(len(faces), dtype=bool)
    if not len(faces):
        return solid
    kept, _, edge, shared, _ = _edges(positions, faces)
    if not len(kept):
        return solid
    # Triangles and edges as the nodes of one graph, each triangle joined to its three edges.
    n = len(kept) + len(shared)
    triangle = np.repeat(np.arange(len(kept)), 3)
    graph = coo_matrix((np.ones(len(triangle)), (triangle, len(kept) + edge.reshape(-1))), shape=(n, n))
    _, component = connected_components(graph, directed=False)
    open_components = np.unique(component[len(kept) + np.flatnonzero(shared != 2)])
    solid[kept] = ~np.isin(component[: len(kept)], open_components)
    return solid


def edge_pairs(positions: np.ndarray, faces: np.ndarray, normals: np.ndarray):
    """The edges shared by exactly two triangles, each side as (triangle, edge e from corner e to
    e + 1): sides (t0, e0) and (t1, e1), t indexing `_edges`' kept triangles, with kept, corners and
    shared from `_edges`, the second normal turned to agree with the first where the two
    triangles run the edge the same way (inconsistent), and whether they run it opposite ways.
    The functions below that need them take them as ``pairs``, so that a caller who asks several
    finds them once (2.4 M triangles take about 6 s)."""
    kept, corners, edge, shared, order = _edges(positions, faces)
    pair = order[shared[edge.reshape(-1)[order]] == 2].reshape(-1, 2)
    (t0, e0), (t1, e1) = np.divmod(pair[:, 0], 3), np.divmod(pair[:, 1], 3)
    consistent = corners[t0, e0] == corners[t1, (e1 + 1) % 3]  # one runs a -> b, the other b -> a
    n0, n1 = normals[kept[t0]], normals[kept[t1]]
    n1 = np.where(consistent[:, None], n1, -n1)
    return kept, edge, shared, (t0, e0), (t1, e1), n0, n1, consistent


def triangle_neighbours(positions: np.ndarray, faces: np.ndarray, normals: np.ndarray, pairs=None):
    """Per triangle and edge e (from corner e to corner e + 1), the triangle across it, (T, 3) int64,
    -1 where there is none (a boundary, an edge of more than two, a triangle welding collapses), and
    whether that triangle runs the edge the same way, so that its normal must be turned to agree,
    (T, 3) bool. Lookups walk from a met triangle across these edges to the triangle the ray meets,
    or to an outline the ray passes (shaders/include/bundle_step.glsl: walk_surface)."""
    across = np.full((len(faces), 3), -1, np.int64)
    turned = np.zeros((len(faces), 3), bool)
    if not len(faces):
        return across, turned
    kept, _, _, (t0, e0), (t1, e1), _, _, consistent = pairs or edge_pairs(positions, faces, normals)
    across[kept[t0], e0], across[kept[t1], e1] = kept[t1], kept[t0]
    turned[kept[t0], e0] = turned[kept[t1], e1] = ~consistent
    return across, turned


def sharp_edges(
    positions: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray,
    crease_degrees: float = SPLAT_CREASE_DEGREES,
    pairs=None,
) -> np.ndarray:
    """(T, 3) bool: whether edge e of each triangle (from corner e to corner e + 1) is sharp, so that
    a splat in the triangle's plane must end there: a boundary (no other triangle), an edge of more
    than two, or a convex crease, where the two triangles' normals part by more than
    ``crease_degrees``. A flat splat that reaches over a convex crease or a boundary stands out into
    empty space, where lines find a surface that is not there; over a concave crease it reaches
    into the solid behind the other face, which no line outside sees, and it closes the corner.
    Triangles whose two sides disagree on the edge's direction (normals facing opposite ways) have
    no inside to tell convex by: a crease between them is sharp either way."""
    sharp = np.zeros((len(faces), 3), dtype=bool)
    if not len(faces):
        return sharp
    kept, edge, shared, (t0, e0), (t1, e1), n0, n1, consistent = pairs or edge_pairs(positions, faces, normals)
    own = shared[edge] != 2
    bent = np.einsum("ij,ij->i", n0, n1) < math.cos(math.radians(crease_degrees))
    # Convex: the other triangle's far corner lies behind this one's front.
    i0, i1 = kept[t0], kept[t1]
    far = positions[faces[i1, (e1 + 2) % 3]] - positions[faces[i0, e0]]
    convex = np.einsum("ij,ij->i", n0, far) < 0
    crease = bent & (convex | ~consistent)
    own[t0, e0] |= crease
    own[t1, e1] |= crease
    sharp[kept] = own
    return sharp


def flat_neighbours(positions: np.ndarray, faces: np.ndarray, normals: np.ndarray, pairs=None) -> np.ndarray:
    """(T, 3) int64: per triangle and edge e (corner e to e + 1), the triangle across it when the
    two lie in one plane (normals within `FLAT_DEGREES`, facing the same way), else -1: its surface
    continues the triangle's, and its sharp edges cut the triangle's splats too (`splat_cuts`)."""
    across = np.full((len(faces), 3), -1, dtype=np.int64)
    if not len(faces):
        return across
    kept, _, _, (t0, e0), (t1, e1), n0, n1, consistent = pairs or edge_pairs(positions, faces, normals)
    flat = consistent & (np.einsum("ij,ij->i", n0, n1) > math.cos(math.radians(FLAT_DEGREES)))
    i0, i1 = kept[t0[flat]], kept[t1[flat]]
    across[i0, e0[flat]] = i1
    across[i1, e1[flat]] = i0
    return across


def smooth_surfaces(
    positions: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray,
    crease_degrees: float = CREASE_DEGREES,
    pairs=None,
) -> np.ndarray:
    """(T,) int64: per triangle, the smooth surface it belongs to, the triangles joined across
    edges shared by two whose normals part by less than ``crease_degrees``, convex or concave: a
    column's facets are one surface, a floor and the wall it meets at a right angle two, and so
    are a thin slab's two sides. A triangle that welding collapses is a surface of its own. This is
    what a hole in imperfect bundles is measured against (evalkit/metrics/bundles.py: an offset is
    a splat of the crossing's own surface)."""
    from scipy.sparse import coo_matrix  # deferred: as in solid_triangles
    from scipy.sparse.csgraph import connected_components  # deferred: as above

    surface = np.arange(len(faces), dtype=np.int64)
    if not len(faces):
        return surface
    kept, _, _, (t0, _), (t1, _), n0, n1, _ = pairs or edge_pairs(positions, faces, normals)
    smooth = np.einsum("ij,ij->i", n0, n1) >= math.cos(math.radians(crease_degrees))
    graph = coo_matrix((np.ones(int(smooth.sum())), (t0[smooth], t1[smooth])), shape=(len(kept), len(kept)))
    count, component = connected_components(graph, directed=False)
    collapsed = np.ones(len(faces), bool)
    collapsed[kept] = False
    surface[kept] = component
    surface[collapsed] = count + np.arange(int(collapsed.sum()))
    return surface


def splat_cuts(
    positions: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray,
    crease_degrees: float = SPLAT_CREASE_DEGREES,
    neighbours: bool = True,
    pairs=None,
) -> tuple[np.ndarray, np.ndarray]:
    """The lines that cut each triangle's splats: the sharp edges (`sharp_edges`) of the triangle
    and of its flat neighbours (`flat_neighbours`), a surface's outline near the splat. A splat ends
    at each and grows there (shaders/include/scene.glsl: sharp_splat_radius); a splat on a triangle that only
    touches an outline through its neighbour would otherwise stand out past it, and cover the
    crossings there less often than its neighbour's grown splats do.

    Returns ``first`` (T + 1,): triangle t's lines are ``lines[first[t]:first[t + 1]]``, and
    ``lines`` (L, 3): each line (l1, l2, l0) as an affine function of barycentrics in the triangle's
    plane, l1 b1 + l2 b2 + l0, the signed distance from the line, positive on the surface's side.
    A neighbour's edge whose line cuts through the triangle itself (a notch in a flat outline) is
    left out, and a line that repeats one already listed (an outline along several triangles) is
    listed once. At most `MAX_SPLAT_CUTS` lines cut a triangle's splats: k of its own edges and two
    of each of the 3 - k neighbours'. ``neighbours=False``: the triangle's own sharp edges only (as
    splats were cut before their neighbours' edges cut them too)."""
    if len(faces):
        pairs = pairs or edge_pairs(positions, faces, normals)
    sharp = sharp_edges(positions, faces, normals, crease_degrees, pairs)
    across = flat_neighbours(positions, faces, normals, pairs) if neighbours else np.full((len(faces), 3), -1)
    corners = positions[faces]  # (T, 3, 3)
    p0, e1, e2 = corners[:, 0], corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    # Candidates (triangle t, triangle u, u's edge e): t's own sharp edges, then its flat neighbours'.
    t, e = np.nonzero(sharp)
    t_list, u_list, e_list = [t], [t], [e]
    t, slot = np.nonzero(across >= 0)
    u = across[t, slot]
    for e in range(3):
        cut = sharp[u, e]
        t_list.append(t[cut])
        u_list.append(u[cut])
        e_list.append(np.full(int(cut.sum()), e))
    t, u, e = np.concatenate(t_list), np.concatenate(u_list), np.concatenate(e_list)
    a = corners[u, e]
    along = corners[u, (e + 1) % 3] - a
    inward = np.cross(normals[t], along)
    with np.errstate(divide="ignore", invalid="ignore"):  # a sliver's NaN line cuts nothing: left out below
        inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    # Turned towards the edge's own triangle: its third corner lies on the surface's side.
    side = np.sign(np.einsum("ij,ij->i", corners[u, (e + 2) % 3] - a, inward))
    inward *= np.where(side < 0, -1.0, 1.0)[:, None]
    lines = np.stack(
        [
            np.einsum("ij,ij->i", e1[t], inward),
            np.einsum("ij,ij->i", e2[t], inward),
            np.einsum("ij,ij->i", p0[t] - a, inward),
        ],
        axis=1,
    )
    # Distances of the triangle's own corners: a line that cuts the triangle is a notch's (and a
    # NaN line, of a triangle without a normal, fails the test too).
    at_corners = lines[:, 2:3] + np.stack([np.zeros(len(t)), lines[:, 0], lines[:, 1]], axis=1)
    size = np.linalg.norm(np.stack([e1[t], e2[t]], axis=1), axis=2).max(axis=1)
    keep = at_corners.min(axis=1) >= -1e-6 * size
    t, lines, size = t[keep], lines[keep], size[keep]
    # One line per triangle however many of its neighbours run along it.
    key = np.round(np.column_stack([t, lines / size[:, None] * 1e6])).astype(np.int64)
    _, unique = np.unique(key, axis=0, return_index=True)
    order = unique[np.argsort(t[unique], kind="stable")]
    first = np.searchsorted(t[order], np.arange(len(faces) + 1))
    return first, lines[order]


def cut_distances(first: np.ndarray, lines: np.ndarray, t: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(M, MAX_SPLAT_CUTS): the signed distances of points at barycentrics ``b`` (M, 2) of
    triangles ``t`` (M,) from the lines that cut their splats (`splat_cuts`' ``first``, ``lines``),
    inf past a triangle's last line."""
    distances = np.full((len(t), MAX_SPLAT_CUTS), np.inf)
    count = first[t + 1] - first[t]
    for i in range(MAX_SPLAT_CUTS):
        has = count > i
        line = lines[first[t[has]] + i]
        distances[has, i] = line[:, 0] * b[has, 0] + line[:, 1] * b[has, 1] + line[:, 2]
    return distances


def plane_barycentrics(p: np.ndarray, p0: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """(M, 2): points p's barycentrics (b1, b2) in the planes of triangles (p0, p1, p2), all (M, 3),
    as shaders/include/scene.glsl's plane_barycentrics solves them."""
    e1, e2, q = p1 - p0, p2 - p0, p - p0
    dot = lambda x, y: np.einsum("ij,ij->i", x, y)  # noqa: E731
    aa, ab, bb = dot(e1, e1), dot(e1, e2), dot(e2, e2)
    det = aa * bb - ab * ab
    return np.stack([bb * dot(q, e1) - ab * dot(q, e2), aa * dot(q, e2) - ab * dot(q, e1)], axis=1) / det[:, None]


# How cut splats grow (shaders/include/scene.glsl: sharp_splat_radius), recorded in an imperfect set's
# params: "edge_cover" keeps a crossing at an edge as often covered as one inside a face;
# "keep_area", the rule of sets built before it, grew a splat until it kept its disk's area.
SPLAT_GROWTH = "edge_cover"


def sharp_splat_radii(r: float, distances: np.ndarray, growth: str = SPLAT_GROWTH) -> np.ndarray:
    """The radii (M,) of splats of radius ``r`` whose centres lie ``distances`` (M, K) from the lines
    that cut them (`cut_distances`), as shaders/include/scene.glsl's sharp_splat_radius grows them: a
    crossing at an edge finds splat centres on one side only, so a splat within sqrt(2) r of one
    line takes radius sqrt(2) r (a half disk with the full disk's area) and one within sqrt(2) r of
    two or more takes 2 r (a quarter disk's). ``growth="keep_area"`` is the rule of sets built
    before (`SPLAT_GROWTH`): radius R keeping pi r^2 of its disk, less the segment beyond each line
    within R, at most 2 r, in the shader's four fixed-point steps."""
    if growth == "edge_cover":
        near = (np.asarray(distances) < math.sqrt(2.0) * r).sum(axis=1)
        return np.where(near == 0, float(r), np.where(near == 1, math.sqrt(2.0) * r, 2.0 * r))
    if growth != "keep_area":
        raise ValueError(f"unknown splat growth {growth!r}: 'edge_cover' or 'keep_area'")
    cut = np.maximum(distances, 0.0)
    radius = np.full(len(cut), float(r))
    for _ in range(4):
        t = np.clip(cut / radius[:, None], 0.0, 1.0)
        lost = (np.arccos(t) - t * np.sqrt(1.0 - t * t)).sum(axis=1)
        radius = r * np.sqrt(np.pi / np.maximum(np.pi - lost, 0.25 * np.pi))
    return np.where(np.min(cut, axis=1, initial=np.inf) >= r, float(r), radius)
