"""What a triangle soup's edges say about its surfaces: which triangles bound a solid, and which
edges are sharp, where splats (imperfect bundles', imperfect shadow maps') must end. Corners are
welded within a ten-millionth of the scene's extent first: a seam's copies of a corner differ by
rounding."""

from __future__ import annotations

import math

import numpy as np

# Two triangles meeting at a convex edge whose normals part by more than this are a crease, not one
# smooth surface (docs/MEASURED_FACTS.md, "Splats end at sharp edges"): tessellated curved
# surfaces part by less (atrium's columns by 7.5 degrees, a 16-sided cylinder by 22.5).
CREASE_DEGREES = 30.0


def _edges(positions: np.ndarray, faces: np.ndarray):
    """The triangles that keep an area after welding (K,), their welded corners (K, 3), the id of
    each one's edge e, from corner e to corner e + 1 (K, 3), and how many triangles share each id."""
    extent = float(np.ptp(positions, axis=0).max()) if len(positions) else 1.0
    _, welded = np.unique(np.round(positions / (1e-7 * (extent or 1.0))), axis=0, return_inverse=True)
    corners = welded.reshape(-1)[faces]
    kept = np.flatnonzero((corners != np.roll(corners, 1, axis=1)).all(axis=1))
    corners = corners[kept]
    ends = np.stack([corners, np.roll(corners, -1, axis=1)], axis=2).reshape(-1, 2)
    key = ends.min(axis=1).astype(np.int64) * (int(welded.max(initial=0)) + 1) + ends.max(axis=1)
    _, edge, shared = np.unique(key, return_inverse=True, return_counts=True)
    return kept, corners, edge.reshape(-1, 3), shared


def solid_triangles(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per triangle, whether it bounds a solid: its connected surface (triangles joined by shared
    edges) is closed, every edge shared by exactly two triangles. A box or a ball resting on a floor
    is one; the floor, a quad light and a room open on one side are not (shaders/shadow_maps.glsl:
    what lies behind a solid's surface is inside it). A triangle that welding collapses (at a UV
    sphere's poles) has no area and no say, and is not one."""
    from scipy.sparse import coo_matrix  # deferred: scipy loads in a second; only solids ask
    from scipy.sparse.csgraph import connected_components  # deferred: as above

    solid = np.zeros(len(faces), dtype=bool)
    if not len(faces):
        return solid
    kept, _, edge, shared = _edges(positions, faces)
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


def sharp_edges(
    positions: np.ndarray, faces: np.ndarray, normals: np.ndarray, crease_degrees: float = CREASE_DEGREES
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
    kept, corners, edge, shared = _edges(positions, faces)
    flat_edge = edge.reshape(-1)
    slot = np.arange(flat_edge.size)
    own = np.zeros((len(kept), 3), dtype=bool)
    own.reshape(-1)[shared[flat_edge] != 2] = True
    # The two sides of every edge shared by two triangles, side by side.
    order = np.argsort(flat_edge, kind="stable")
    pair = order[np.isin(flat_edge[order], np.flatnonzero(shared == 2))].reshape(-1, 2)
    (t0, e0), (t1, e1) = np.divmod(slot[pair[:, 0]], 3), np.divmod(slot[pair[:, 1]], 3)
    i0, i1 = kept[t0], kept[t1]
    n0, n1 = normals[i0], normals[i1]
    consistent = corners[t0, e0] == corners[t1, (e1 + 1) % 3]  # one runs a -> b, the other b -> a
    n1 = np.where(consistent[:, None], n1, -n1)
    bent = np.einsum("ij,ij->i", n0, n1) < math.cos(math.radians(crease_degrees))
    # Convex: the other triangle's far corner lies behind this one's front.
    far = positions[faces[i1, (e1 + 2) % 3]] - positions[faces[i0, e0]]
    convex = np.einsum("ij,ij->i", n0, far) < 0
    crease = bent & (convex | ~consistent)
    own[t0, e0] |= crease
    own[t1, e1] |= crease
    sharp[kept] = own
    return sharp


def plane_barycentrics(p: np.ndarray, p0: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """(M, 2): points p's barycentrics (b1, b2) in the planes of triangles (p0, p1, p2), all (M, 3),
    as shaders/scene.glsl's plane_barycentrics solves them."""
    e1, e2, q = p1 - p0, p2 - p0, p - p0
    dot = lambda x, y: np.einsum("ij,ij->i", x, y)  # noqa: E731
    aa, ab, bb = dot(e1, e1), dot(e1, e2), dot(e2, e2)
    det = aa * bb - ab * ab
    return np.stack([bb * dot(q, e1) - ab * dot(q, e2), aa * dot(q, e2) - ab * dot(q, e1)], axis=1) / det[:, None]


def sharp_splat_radii(r: float, sharp: np.ndarray, b: np.ndarray, e1: np.ndarray, e2: np.ndarray) -> np.ndarray:
    """The radii (M,) of splats of radius ``r`` at barycentrics ``b`` (M, 2) of triangles with edges
    ``e1``, ``e2`` (M, 3) and sharp edges ``sharp`` (M, 3), as shaders/scene.glsl's
    sharp_splat_radius grows them: a splat cut by a sharp edge grows until the part kept has its
    disk's area pi r^2. A disk of radius R loses R^2 (acos t - t sqrt(1 - t^2)), t = d / R, to each
    sharp edge at distance d < R; the kept area is held at a quarter disk at least (R <= 2 r), which
    bounds the corners, where the lost segments overlap and are counted twice. Four fixed-point
    steps, as the shader takes."""
    twice_area = np.linalg.norm(np.cross(e1, e2), axis=1)
    lengths = np.stack([np.linalg.norm(e1, axis=1), np.linalg.norm(e2 - e1, axis=1), np.linalg.norm(e2, axis=1)], 1)
    # Edge e runs from corner e to e + 1, opposite the corner of weight b2, 1 - b1 - b2, b1.
    weights = np.maximum(np.stack([b[:, 1], 1.0 - b[:, 0] - b[:, 1], b[:, 0]], 1), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        cut = np.where(sharp, weights * twice_area[:, None] / lengths, np.inf)
    radius = np.full(len(b), float(r))
    for _ in range(4):
        t = np.clip(cut / radius[:, None], 0.0, 1.0)
        lost = (np.arccos(t) - t * np.sqrt(1.0 - t * t)).sum(axis=1)
        radius = r * np.sqrt(np.pi / np.maximum(np.pi - lost, 0.25 * np.pi))
    return np.where(np.min(cut, axis=1) >= r, float(r), radius)
